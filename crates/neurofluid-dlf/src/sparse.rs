//! Host kernels of the continuous convolution's sparse part, forward and transposed, over a
//! [`HostGeometry`] with explicit pair-corner weights (`[8P]`, pair-major).
//!
//! With `T[q, cell, i] = Σ_{pairs (q, i)} Σ_{corners with that cell} w` ([`SparseOp`]), the conv
//! is either `G = T·F` (gather, then `G·K`) or `out = T·H` for `H = F·K` (contract). The
//! transposed kernels give the features' (or `H`'s) gradient,
//! scattered into one accumulator per worker, and the weights' gradient, one dot product per
//! pair corner.

use std::ops::Range;

use rayon::prelude::*;

use crate::geometry::{CORNERS, HostGeometry};
use crate::mapping::KERNEL_CELLS;

use neurofluid_core::real::{Real, axpy, dot_in_lanes, par_zeros};

/// The sparse operator `T`: a geometry's pairs and cells with pair-corner weights `[8P]`.
#[derive(Clone, Copy)]
pub struct SparseOp<'a, T> {
    /// Pairs and cells.
    pub host: &'a HostGeometry,
    /// Window × trilinear weight of every pair corner.
    pub weights: &'a [T],
}

impl<'a, T: Real> SparseOp<'a, T> {
    /// The operator of `host` with `weights`.
    pub fn new(host: &'a HostGeometry, weights: &'a [T]) -> Self {
        assert_eq!(
            weights.len(),
            host.cells.len(),
            "one weight per pair corner"
        );
        Self { host, weights }
    }

    /// Calls `f(corner, cell, weight)` for the 8 corners of pair `p`.
    fn corners(&self, p: usize, mut f: impl FnMut(usize, usize, T)) {
        let range = p * CORNERS..(p + 1) * CORNERS;
        for ((c, &cell), &w) in range
            .clone()
            .zip(&self.host.cells[range.clone()])
            .zip(&self.weights[range])
        {
            f(c, cell as usize, w);
        }
    }

    /// `G[r, cell·Cin + c] = Σ_{pairs (q, i)} Σ_corners w · F[i, c]` for the output points
    /// `rows` (`q = rows.start + r`; the result has `rows.len()` rows).
    pub fn gather(&self, features: &[T], cin: usize, rows: Range<usize>) -> Vec<T> {
        let row_len = KERNEL_CELLS * cin;
        let mut g = par_zeros(rows.len() * row_len);
        g.par_chunks_mut(row_len).enumerate().for_each(|(r, row)| {
            for_pairs(self.host, rows.start + r, |p, i| {
                let f = &features[i * cin..(i + 1) * cin];
                self.corners(p, |_, cell, w| {
                    axpy(&mut row[cell * cin..(cell + 1) * cin], w, f)
                });
            });
        });
        g
    }

    /// `out[q, o] = Σ_{pairs (q, i)} Σ_corners w · H[i·64 + cell, o]` for `H = F·K` laid out
    /// `[N·64, Cout]`, over every output point.
    pub fn contract(&self, h: &[T], cout: usize) -> Vec<T> {
        let mut out = vec![T::default(); self.host.num_out * cout];
        out.par_chunks_mut(cout).enumerate().for_each(|(q, row)| {
            for_pairs(self.host, q, |p, i| {
                self.corners(p, |_, cell, w| {
                    let at = i * KERNEL_CELLS + cell;
                    axpy(row, w, &h[at * cout..(at + 1) * cout]);
                });
            });
        });
        out
    }

    /// The transpose of [`Self::gather`] for the chunk of output points `rows`, given `dG` for
    /// those rows: `dF[i, c] += Σ w · dG[q, cell·Cin + c]` into `accumulators` (one `[N·Cin]`
    /// buffer per worker, summed by [`sum_accumulators`]; skipped when empty) and
    /// `dW[p·8 + k] = ⟨dG[q, cell], F[i]⟩` into `d_weights` (`[8P]`, the chunk's pairs written;
    /// skipped when `None`).
    pub fn gather_transpose(
        &self,
        features: &[T],
        d_g: &[T],
        cin: usize,
        rows: Range<usize>,
        accumulators: &mut [Vec<T>],
        d_weights: Option<&mut [T]>,
    ) {
        let row_len = KERNEL_CELLS * cin;
        let first = rows.start;
        transpose_runs(self.host, rows, accumulators, d_weights, |q, acc, dw| {
            let dg = &d_g[(q - first) * row_len..(q - first + 1) * row_len];
            for_pairs(self.host, q, |p, i| {
                self.corners(p, |c, cell, w| {
                    let dg_cell = &dg[cell * cin..(cell + 1) * cin];
                    if let Some(acc) = acc.as_deref_mut() {
                        axpy(&mut acc[i * cin..(i + 1) * cin], w, dg_cell);
                    }
                    if let Some(dw) = dw.as_mut() {
                        dw[c] = dot_in_lanes(dg_cell, &features[i * cin..(i + 1) * cin]);
                    }
                });
            });
        });
    }

    /// The transpose of [`Self::contract`]: `dH[i·64 + cell, o] += Σ w · dOut[q, o]` into
    /// `accumulators` (one `[N·64·Cout]` buffer per worker; skipped when empty) and
    /// `dW[p·8 + k] = ⟨dOut[q], H[i·64 + cell]⟩` into `d_weights` (needs `h`).
    pub fn contract_transpose(
        &self,
        h: Option<&[T]>,
        d_out: &[T],
        cout: usize,
        accumulators: &mut [Vec<T>],
        d_weights: Option<&mut [T]>,
    ) {
        assert!(
            d_weights.is_none() || h.is_some(),
            "the weights' gradient needs H"
        );
        let rows = 0..self.host.num_out;
        transpose_runs(self.host, rows, accumulators, d_weights, |q, acc, dw| {
            let d = &d_out[q * cout..(q + 1) * cout];
            for_pairs(self.host, q, |p, i| {
                self.corners(p, |c, cell, w| {
                    let at = i * KERNEL_CELLS + cell;
                    if let Some(acc) = acc.as_deref_mut() {
                        axpy(&mut acc[at * cout..(at + 1) * cout], w, d);
                    }
                    if let (Some(dw), Some(h)) = (dw.as_mut(), h) {
                        dw[c] = dot_in_lanes(d, &h[at * cout..(at + 1) * cout]);
                    }
                });
            });
        });
    }
}

/// Sums the workers' accumulators into the first one and returns it.
pub fn sum_accumulators<T: Real>(mut accumulators: Vec<Vec<T>>) -> Vec<T> {
    let mut total = accumulators.swap_remove(0);
    const BLOCK: usize = 1 << 14;
    total
        .par_chunks_mut(BLOCK)
        .enumerate()
        .for_each(|(b, dst)| {
            for acc in &accumulators {
                for (d, &x) in dst.iter_mut().zip(&acc[b * BLOCK..]) {
                    *d += x;
                }
            }
        });
    total
}

/// One zeroed accumulator of `len` per worker thread, or none when `needed` is false.
pub fn accumulators<T: Real>(needed: bool, len: usize) -> Vec<Vec<T>> {
    if !needed {
        return Vec::new();
    }
    (0..rayon::current_num_threads().max(1))
        .map(|_| vec![T::default(); len])
        .collect()
}

/// Calls `f(p, i)` for every pair `p` of output point `q` (input point `i`).
fn for_pairs(host: &HostGeometry, q: usize, mut f: impl FnMut(usize, usize)) {
    let (p0, p1) = (host.pairs.offsets[q], host.pairs.offsets[q + 1]);
    for (p, &i) in (p0..p1).zip(&host.pairs.indices[p0..p1]) {
        f(p, i as usize);
    }
}

/// Runs `f(q, accumulator, d_weights)` over `rows`, split into one run of consecutive output
/// points per accumulator (about equal pair counts), the runs in parallel. `d_weights` is the
/// whole `[8P]` gradient; each run gets the slice of its own pairs, indexed globally.
fn transpose_runs<T: Real>(
    host: &HostGeometry,
    rows: Range<usize>,
    accumulators: &mut [Vec<T>],
    d_weights: Option<&mut [T]>,
    f: impl Fn(usize, &mut Option<&mut [T]>, &mut Option<WeightsWindow<'_, T>>) + Sync,
) {
    let offsets = &host.pairs.offsets;
    let parts = accumulators.len().max(1);
    let (first, last) = (offsets[rows.start], offsets[rows.end]);
    // run boundaries: about equal pair counts
    let mut bounds = vec![rows.start];
    let mut q = rows.start;
    for k in 1..parts {
        let target = first + (last - first) * k / parts;
        while q < rows.end && offsets[q] < target {
            q += 1;
        }
        bounds.push(q);
    }
    bounds.push(rows.end);
    // disjoint windows of d_weights, one per run
    let mut windows: Vec<Option<WeightsWindow<'_, T>>> = Vec::with_capacity(parts);
    match d_weights {
        Some(dw) => {
            let mut rest = &mut dw[first * CORNERS..last * CORNERS];
            let mut base = first * CORNERS;
            for run in bounds.windows(2) {
                let len = (offsets[run[1]] - offsets[run[0]]) * CORNERS;
                let (head, tail) = rest.split_at_mut(len);
                windows.push(Some(WeightsWindow { base, values: head }));
                rest = tail;
                base += len;
            }
        }
        None => windows.resize_with(parts, || None),
    }
    let mut accs: Vec<Option<&mut [T]>> = accumulators
        .iter_mut()
        .map(|a| Some(a.as_mut_slice()))
        .collect();
    accs.resize_with(parts, || None);
    accs.into_par_iter()
        .zip(windows)
        .zip(bounds.par_windows(2))
        .for_each(|((mut acc, mut dw), run)| {
            for q in run[0]..run[1] {
                f(q, &mut acc, &mut dw);
            }
        });
}

/// A run's slice of the `[8P]` weights gradient, indexed by global pair-corner index.
struct WeightsWindow<'a, T> {
    base: usize,
    values: &'a mut [T],
}

impl<T> std::ops::Index<usize> for WeightsWindow<'_, T> {
    type Output = T;
    fn index(&self, c: usize) -> &T {
        &self.values[c - self.base]
    }
}

impl<T> std::ops::IndexMut<usize> for WeightsWindow<'_, T> {
    fn index_mut(&mut self, c: usize) -> &mut T {
        &mut self.values[c - self.base]
    }
}
