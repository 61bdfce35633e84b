//! `C = A·B` on the host for the dense layers, with SIMD chosen at run time (pulp: AVX2 + FMA
//! where the CPU has them, scalar code otherwise).
//!
//! `B` is packed once into panels two SIMD vectors wide (`[panel][p][width]`, the last one
//! padded with zeros); `A` is read where it lies, row-major or transposed, one element at a time
//! into a broadcast, so no operand is ever gathered element by element (matrixmultiply packs a
//! row-major left operand that way, which cost a quarter of the dense layers' time). Each
//! register tile holds 6 rows × 2 vectors of `C` over the whole reduction, so the sum over `p`
//! runs in index order and the result does not depend on how rows are split between threads.

use pulp::{Arch, Simd, WithSimd};
use rayon::prelude::*;

use crate::real::Real;

/// Rows of `C` per register tile.
const MR: usize = 6;

/// Rows of `C` per cache block: `MC` rows of `A` stay in L2 while the panels of `B` go by.
const MC: usize = 96;

/// A float type with SIMD vectors of pulp's `S` (f32 and f64).
pub trait Lanes: Real {
    /// A vector of `Self`.
    type V<S: Simd>: Copy;
    /// Lanes in [`Lanes::V`].
    fn lanes<S: Simd>() -> usize;
    /// All lanes `x`.
    fn splat<S: Simd>(s: S, x: Self) -> Self::V<S>;
    /// `a·b + c`, fused where the CPU has FMA.
    fn mul_add<S: Simd>(s: S, a: Self::V<S>, b: Self::V<S>, c: Self::V<S>) -> Self::V<S>;
    /// `a + b`.
    fn add_vectors<S: Simd>(s: S, a: Self::V<S>, b: Self::V<S>) -> Self::V<S>;
    /// `v` with negative lanes set to zero (NaN stays NaN).
    fn relu<S: Simd>(s: S, v: Self::V<S>) -> Self::V<S>;
    /// The first `min(lanes, len)` values (the rest zero).
    fn load<S: Simd>(s: S, v: &[Self]) -> Self::V<S>;
    /// Stores the first `min(lanes, len)` lanes.
    fn store<S: Simd>(s: S, dst: &mut [Self], v: Self::V<S>);
    /// `v` as whole vectors (and the rest).
    fn as_vectors<S: Simd>(v: &[Self]) -> (&[Self::V<S>], &[Self]);
}

macro_rules! impl_lanes {
    ($t:ty, $v:ident, $lanes:ident, $splat:ident, $fma:ident, $add:ident, $max:ident, $lt:ident,
     $select:ident,
     $load:ident, $store:ident, $split:ident, $split_mut:ident) => {
        impl Lanes for $t {
            type V<S: Simd> = S::$v;
            #[inline(always)]
            fn lanes<S: Simd>() -> usize {
                S::$lanes
            }
            #[inline(always)]
            fn splat<S: Simd>(s: S, x: Self) -> S::$v {
                s.$splat(x)
            }
            #[inline(always)]
            fn mul_add<S: Simd>(s: S, a: S::$v, b: S::$v, c: S::$v) -> S::$v {
                s.$fma(a, b, c)
            }
            #[inline(always)]
            fn add_vectors<S: Simd>(s: S, a: S::$v, b: S::$v) -> S::$v {
                s.$add(a, b)
            }
            #[inline(always)]
            fn relu<S: Simd>(s: S, v: S::$v) -> S::$v {
                let zero = s.$splat(0.0);
                if S::IS_SCALAR {
                    s.$select(s.$lt(v, zero), zero, v)
                } else {
                    // SSE/AVX `max(0, v)` returns its second operand when either is NaN, and
                    // NEON's and WebAssembly's return NaN: NaN stays NaN, without a blend
                    s.$max(zero, v)
                }
            }
            #[inline(always)]
            fn load<S: Simd>(s: S, v: &[Self]) -> S::$v {
                // a plain load where a whole vector is there (masked ones are slow on some CPUs)
                match S::$split(v).0.first() {
                    Some(&whole) => whole,
                    None => s.$load(v),
                }
            }
            #[inline(always)]
            fn store<S: Simd>(s: S, dst: &mut [Self], v: S::$v) {
                match S::$split_mut(dst) {
                    ([whole, ..], _) => *whole = v,
                    (_, rest) => s.$store(rest, v),
                }
            }
            #[inline(always)]
            fn as_vectors<S: Simd>(v: &[Self]) -> (&[S::$v], &[Self]) {
                S::$split(v)
            }
        }
    };
}

impl_lanes!(
    f32,
    f32s,
    F32_LANES,
    splat_f32s,
    mul_add_e_f32s,
    add_f32s,
    max_f32s,
    less_than_f32s,
    select_f32s,
    partial_load_f32s,
    partial_store_f32s,
    as_simd_f32s,
    as_mut_simd_f32s
);
impl_lanes!(
    f64,
    f64s,
    F64_LANES,
    splat_f64s,
    mul_add_e_f64s,
    add_f64s,
    max_f64s,
    less_than_f64s,
    select_f64s,
    partial_load_f64s,
    partial_store_f64s,
    as_simd_f64s,
    as_mut_simd_f64s
);

/// Columns per panel of packed `B` on this CPU (two vectors).
pub fn panel_width<T: Lanes>() -> usize {
    struct Width<T>(std::marker::PhantomData<T>);
    impl<T: Lanes> WithSimd for Width<T> {
        type Output = usize;
        #[inline(always)]
        fn with_simd<S: Simd>(self, _: S) -> usize {
            2 * T::lanes::<S>()
        }
    }
    Arch::new().dispatch(Width::<T>(std::marker::PhantomData))
}

/// `B [k, n]` packed in panels of [`panel_width`] columns.
#[derive(Debug, Clone)]
pub struct PackedB<T> {
    data: Vec<T>,
    k: usize,
    n: usize,
    width: usize,
}

impl<T: Lanes> PackedB<T> {
    /// Packs `B[p, j] = b[p·rs + j·cs]` for `p < k`, `j < n`.
    pub fn new(b: &[T], rs: usize, cs: usize, k: usize, n: usize) -> Self {
        Self::with_width(b, rs, cs, k, n, panel_width::<T>())
    }

    /// [`PackedB::new`] in panels of `width` columns.
    fn with_width(b: &[T], rs: usize, cs: usize, k: usize, n: usize, width: usize) -> Self {
        let panels = n.div_ceil(width);
        let mut data = vec![T::zero(); panels * k * width];
        for (jp, panel) in data.chunks_mut((k * width).max(1)).enumerate() {
            let j0 = jp * width;
            let cols = width.min(n - j0);
            for (p, dst) in panel.chunks_mut(width).enumerate() {
                if cs == 1 {
                    dst[..cols].copy_from_slice(&b[p * rs + j0..][..cols]);
                } else {
                    for (c, d) in dst[..cols].iter_mut().enumerate() {
                        *d = b[p * rs + (j0 + c) * cs];
                    }
                }
            }
        }
        Self { data, k, n, width }
    }
}

/// How `A [rows, k]` lies in memory.
#[derive(Debug, Clone, Copy)]
pub enum LayoutA {
    /// `A[i, p] = a[i·stride + p]` (row-major).
    Rows {
        /// Between rows.
        stride: usize,
    },
    /// `A[i, p] = a[p·stride + i]` (the transpose of a row-major matrix).
    Cols {
        /// Between columns.
        stride: usize,
    },
}

/// What is done with a tile of `A·B` as it is written to `C`.
#[derive(Debug, Clone, Copy)]
pub enum Epilogue<'a, T> {
    /// `C = A·B`.
    Store,
    /// `C += A·B`.
    Add,
    /// `C = A·B + bias[j]`, then ReLU when `relu`.
    Bias {
        /// One value per column of `C`.
        bias: &'a [T],
        /// Whether negative values become zero.
        relu: bool,
    },
}

/// `C [rows, n]` (row-major, rows `c_stride` apart) from `A [rows, k]` and packed `B [k, n]`.
pub fn matmul<T: Lanes>(
    a: &[T],
    layout: LayoutA,
    rows: usize,
    b: &PackedB<T>,
    c: &mut [T],
    c_stride: usize,
    epilogue: Epilogue<'_, T>,
) {
    Arch::new().dispatch(Matmul {
        a,
        layout,
        rows,
        b,
        c,
        c_stride,
        epilogue,
    });
}

/// [`matmul`] with the rows of `C` split between rayon's threads: the same bits as one call
/// (each element is summed by one register tile, whatever the split).
pub fn par_matmul<T: Lanes>(
    a: &[T],
    layout: LayoutA,
    rows: usize,
    b: &PackedB<T>,
    c: &mut [T],
    c_stride: usize,
    epilogue: Epilogue<'_, T>,
) {
    if rows == 0 || b.n == 0 {
        return;
    }
    // about four blocks per thread, whole tiles, at most a cache block
    let threads = rayon::current_num_threads().max(1);
    let block = rows
        .div_ceil(4 * threads)
        .next_multiple_of(MR)
        .clamp(MR, MC);
    let len = c.len().min(rows * c_stride);
    c[..len]
        .par_chunks_mut(block * c_stride)
        .enumerate()
        .for_each(|(t, c)| {
            let i0 = t * block;
            let a = match layout {
                LayoutA::Rows { stride } => &a[i0 * stride..],
                LayoutA::Cols { .. } => &a[i0..],
            };
            matmul(a, layout, block.min(rows - i0), b, c, c_stride, epilogue);
        });
}

struct Matmul<'a, 'e, T> {
    a: &'a [T],
    layout: LayoutA,
    rows: usize,
    b: &'a PackedB<T>,
    c: &'a mut [T],
    c_stride: usize,
    epilogue: Epilogue<'e, T>,
}

impl<T: Lanes> WithSimd for Matmul<'_, '_, T> {
    type Output = ();

    #[inline(always)]
    fn with_simd<S: Simd>(self, s: S) {
        let Matmul {
            a,
            layout,
            rows,
            b,
            c,
            c_stride,
            epilogue,
        } = self;
        let (k, n, width) = (b.k, b.n, b.width);
        assert_eq!(
            width,
            2 * T::lanes::<S>(),
            "B packed for another SIMD width"
        );
        if rows == 0 || n == 0 {
            return;
        }
        if k == 0 {
            // an empty sum: what the epilogue makes of zeros
            for i in 0..rows {
                for j0 in (0..n).step_by(width) {
                    let dst = &mut c[i * c_stride + j0..i * c_stride + n.min(j0 + width)];
                    write_row(s, dst, [T::splat(s, T::zero()); 2], j0, epilogue);
                }
            }
            return;
        }
        for i0 in (0..rows).step_by(MC) {
            let block = MC.min(rows - i0);
            for (jp, panel) in b.data.chunks(k * width).enumerate() {
                let j0 = jp * width;
                let cols = width.min(n - j0);
                let (panel, _) = T::as_vectors::<S>(panel);
                let mut i = i0;
                while i < i0 + block {
                    let mr = MR.min(i0 + block - i);
                    let c_tile = &mut c[i * c_stride..];
                    let at = (s, a, layout, i, k, panel);
                    let out = (c_tile, c_stride, j0, cols, epilogue);
                    match mr {
                        6 => write_tile(s, &sums6(at), out),
                        5 => write_tile(s, &sums::<T, S, 5>(at), out),
                        4 => write_tile(s, &sums::<T, S, 4>(at), out),
                        3 => write_tile(s, &sums::<T, S, 3>(at), out),
                        2 => write_tile(s, &sums::<T, S, 2>(at), out),
                        _ => write_tile(s, &sums::<T, S, 1>(at), out),
                    }
                    i += mr;
                }
            }
        }
    }
}

/// Where a tile's sums come from: the SIMD context, `A` and its layout, the tile's first row,
/// the reduction length and the panel of `B`.
type TileInput<'a, T, S> = (S, &'a [T], LayoutA, usize, usize, &'a [<T as Lanes>::V<S>]);

/// Where a tile goes: `C` from the tile's first row, its row stride, the panel's first column,
/// its columns, and the epilogue.
type TileOutput<'a, 'e, T> = (&'a mut [T], usize, usize, usize, Epilogue<'e, T>);

/// The sums of an `R`-row tile (the rows left at the end of a block).
#[inline(always)]
fn sums<T: Lanes, S: Simd, const R: usize>(
    (s, a, layout, i, k, panel): TileInput<'_, T, S>,
) -> [[T::V<S>; 2]; R] {
    let zero = T::splat(s, T::zero());
    let mut acc = [[zero; 2]; R];
    for (p, b) in panel[..2 * k].chunks_exact(2).enumerate() {
        for (r, acc) in acc.iter_mut().enumerate() {
            let x = T::splat(s, a[a_index(layout, i + r, p)]);
            acc[0] = T::mul_add(s, x, b[0], acc[0]);
            acc[1] = T::mul_add(s, x, b[1], acc[1]);
        }
    }
    acc
}

/// Index of `A[i, p]`.
#[inline(always)]
fn a_index(layout: LayoutA, i: usize, p: usize) -> usize {
    match layout {
        LayoutA::Rows { stride } => i * stride + p,
        LayoutA::Cols { stride } => p * stride + i,
    }
}

/// The sums of a full tile of 6 rows, its twelve accumulators named one by one (arrays of
/// them were spilled to the stack in some loops) and iterators without bounds checks.
#[inline(always)]
fn sums6<T: Lanes, S: Simd>((s, a, layout, i, k, panel): TileInput<'_, T, S>) -> [[T::V<S>; 2]; 6] {
    let z = T::splat(s, T::zero());
    let (mut c00, mut c01, mut c10, mut c11, mut c20, mut c21) = (z, z, z, z, z, z);
    let (mut c30, mut c31, mut c40, mut c41, mut c50, mut c51) = (z, z, z, z, z, z);
    let (panel, _) = panel[..2 * k].as_chunks::<2>();
    macro_rules! step {
        ($b:expr, $x0:expr, $x1:expr, $x2:expr, $x3:expr, $x4:expr, $x5:expr) => {{
            let [b0, b1] = *$b;
            macro_rules! row {
                ($x:expr, $c0:ident, $c1:ident) => {{
                    let x = T::splat(s, $x);
                    $c0 = T::mul_add(s, x, b0, $c0);
                    $c1 = T::mul_add(s, x, b1, $c1);
                }};
            }
            row!($x0, c00, c01);
            row!($x1, c10, c11);
            row!($x2, c20, c21);
            row!($x3, c30, c31);
            row!($x4, c40, c41);
            row!($x5, c50, c51);
        }};
    }
    match layout {
        LayoutA::Rows { stride } => {
            let row = |r: usize| &a[(i + r) * stride..][..k];
            let rows = panel
                .iter()
                .zip(row(0))
                .zip(row(1))
                .zip(row(2))
                .zip(row(3))
                .zip(row(4))
                .zip(row(5));
            for ((((((b, &x0), &x1), &x2), &x3), &x4), &x5) in rows {
                step!(b, x0, x1, x2, x3, x4, x5);
            }
        }
        LayoutA::Cols { stride } => {
            for (p, b) in panel.iter().enumerate() {
                let col: &[T; 6] = a[p * stride + i..][..6].try_into().expect("six rows");
                step!(b, col[0], col[1], col[2], col[3], col[4], col[5]);
            }
        }
    }
    [
        [c00, c01],
        [c10, c11],
        [c20, c21],
        [c30, c31],
        [c40, c41],
        [c50, c51],
    ]
}

/// Writes a tile's rows to `C` through the epilogue.
#[inline(always)]
fn write_tile<T: Lanes, S: Simd>(
    s: S,
    acc: &[[T::V<S>; 2]],
    (c, c_stride, j0, cols, epilogue): TileOutput<'_, '_, T>,
) {
    for (r, acc) in acc.iter().enumerate() {
        let dst = &mut c[r * c_stride + j0..][..cols];
        write_row(s, dst, *acc, j0, epilogue);
    }
}

/// Writes one row of a tile (columns `j0..j0 + dst.len()`, at most two vectors) through the
/// epilogue. (Plain code, no iterator adaptors: those are not always inlined into the SIMD
/// context, and a call there costs more than the store.)
#[inline(always)]
fn write_row<T: Lanes, S: Simd>(
    s: S,
    dst: &mut [T],
    acc: [T::V<S>; 2],
    j0: usize,
    epilogue: Epilogue<'_, T>,
) {
    let lanes = T::lanes::<S>();
    let (lo, hi) = dst.split_at_mut(lanes.min(dst.len()));
    write_part(s, lo, acc[0], j0, epilogue);
    if !hi.is_empty() {
        write_part(s, hi, acc[1], j0 + lanes, epilogue);
    }
}

/// Writes `v` to `dst` (columns `j0..j0 + dst.len()`, at most one vector) through the epilogue.
#[inline(always)]
fn write_part<T: Lanes, S: Simd>(
    s: S,
    dst: &mut [T],
    v: T::V<S>,
    j0: usize,
    epilogue: Epilogue<'_, T>,
) {
    let out = match epilogue {
        Epilogue::Store => v,
        Epilogue::Add => T::add_vectors(s, v, T::load(s, dst)),
        Epilogue::Bias { bias, relu } => {
            let z = T::add_vectors(s, v, T::load(s, &bias[j0..j0 + dst.len()]));
            if relu { T::relu(s, z) } else { z }
        }
    };
    T::store(s, dst, out);
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A deterministic, irregular fill.
    fn fill<T: Lanes>(len: usize, seed: usize) -> Vec<T> {
        (0..len)
            .map(|i| {
                let v = ((i * 7919 + seed * 104_729) % 1999) as f64 / 999.5 - 1.0;
                T::from_elem(v)
            })
            .collect()
    }

    /// Every layout and epilogue against the sum written out, at sizes around the tile, block
    /// and panel edges.
    fn check<T: Lanes>(tol: f64) {
        let w = panel_width::<T>();
        for &(rows, k, n) in &[
            (1, 1, 1),
            (5, 3, w - 1),
            (6, 7, w),
            (13, 17, w + 3),
            (MC + 7, 33, 3 * w),
            (2 * MC + 1, 64, 2 * w + 1),
            (9, 0, w + 1),
        ] {
            let bias: Vec<T> = fill(n, 3);
            let b: Vec<T> = fill(k * n, 2);
            for transposed_a in [false, true] {
                let a: Vec<T> = fill(rows * k, 1);
                // A[i, p] in both layouts
                let (layout, at): (LayoutA, Box<dyn Fn(usize, usize) -> f64>) = if transposed_a {
                    (
                        LayoutA::Cols { stride: rows },
                        Box::new(|i, p| a[p * rows + i].elem::<f64>()),
                    )
                } else {
                    (
                        LayoutA::Rows { stride: k },
                        Box::new(|i, p| a[i * k + p].elem::<f64>()),
                    )
                };
                let packed = PackedB::new(&b, n, 1, k, n);
                let c0: Vec<T> = fill(rows * n, 4);
                for (e, epilogue) in [
                    Epilogue::Store,
                    Epilogue::Add,
                    Epilogue::Bias {
                        bias: &bias,
                        relu: false,
                    },
                    Epilogue::Bias {
                        bias: &bias,
                        relu: true,
                    },
                ]
                .into_iter()
                .enumerate()
                {
                    let mut c = c0.clone();
                    matmul(&a, layout, rows, &packed, &mut c, n, epilogue);
                    for i in 0..rows {
                        for j in 0..n {
                            let ab: f64 =
                                (0..k).map(|p| at(i, p) * b[p * n + j].elem::<f64>()).sum();
                            let want = match e {
                                0 => ab,
                                1 => ab + c0[i * n + j].elem::<f64>(),
                                2 => ab + bias[j].elem::<f64>(),
                                _ => (ab + bias[j].elem::<f64>()).max(0.0),
                            };
                            let got = c[i * n + j].elem::<f64>();
                            assert!(
                                (got - want).abs() <= tol * (1.0 + want.abs()),
                                "{rows}×{k}×{n} transposed {transposed_a} epilogue {e} \
                                 at ({i}, {j}): {got} vs {want}"
                            );
                        }
                    }
                }
            }
        }
    }

    #[test]
    fn matches_the_written_out_sum_f64() {
        check::<f64>(1e-12);
    }

    #[test]
    fn matches_the_written_out_sum_f32() {
        check::<f32>(1e-5);
    }

    /// The scalar code path (CPUs without AVX2 + FMA) against the written-out sum, NaN kept by
    /// its ReLU.
    #[test]
    fn the_scalar_fallback_matches_the_written_out_sum() {
        let s = pulp::Scalar::new();
        let (rows, k, n) = (13, 9, 7);
        let (a, b, bias): (Vec<f64>, Vec<f64>, Vec<f64>) =
            (fill(rows * k, 1), fill(k * n, 2), fill(n, 3));
        let packed = PackedB::with_width(&b, n, 1, k, n, 2);
        let mut c = vec![0.0; rows * n];
        let epilogue = Epilogue::Bias {
            bias: &bias,
            relu: true,
        };
        Matmul {
            a: &a,
            layout: LayoutA::Rows { stride: k },
            rows,
            b: &packed,
            c: &mut c,
            c_stride: n,
            epilogue,
        }
        .with_simd(s);
        for i in 0..rows {
            for j in 0..n {
                let z: f64 = (0..k).map(|p| a[i * k + p] * b[p * n + j]).sum::<f64>() + bias[j];
                assert!((c[i * n + j] - z.max(0.0)).abs() < 1e-12, "({i}, {j})");
            }
        }
        let packed = PackedB::with_width(&[1.0f32; 3], 3, 1, 1, 3, 2);
        let mut c = vec![0.0f32; 3];
        let bias = [-1.0f32; 3];
        let epilogue = Epilogue::Bias {
            bias: &bias,
            relu: true,
        };
        Matmul {
            a: &[f32::NAN],
            layout: LayoutA::Rows { stride: 1 },
            rows: 1,
            b: &packed,
            c: &mut c,
            c_stride: 3,
            epilogue,
        }
        .with_simd(s);
        assert!(c.iter().all(|v| v.is_nan()), "{c:?}");
    }

    /// `B` read through its strides: packing the transpose of a row-major matrix.
    #[test]
    fn packs_a_transposed_b() {
        let (k, n) = (5, 19);
        let bt: Vec<f64> = fill(n * k, 9); // [n, k] row-major: B = btᵀ
        let packed = PackedB::new(&bt, 1, k, k, n);
        let a: Vec<f64> = fill(3 * k, 8);
        let mut c = vec![0.0; 3 * n];
        matmul(
            &a,
            LayoutA::Rows { stride: k },
            3,
            &packed,
            &mut c,
            n,
            Epilogue::Store,
        );
        for i in 0..3 {
            for j in 0..n {
                let want: f64 = (0..k).map(|p| a[i * k + p] * bt[j * k + p]).sum();
                assert!((c[i * n + j] - want).abs() < 1e-12);
            }
        }
    }

    /// A NaN in `A` reaches `C` through the ReLU.
    #[test]
    fn relu_keeps_nan() {
        let packed = PackedB::new(&[1.0f32; 4], 4, 1, 1, 4);
        let mut c = vec![0.0f32; 4];
        let bias = [-1.0f32; 4];
        matmul(
            &[f32::NAN],
            LayoutA::Rows { stride: 1 },
            1,
            &packed,
            &mut c,
            4,
            Epilogue::Bias {
                bias: &bias,
                relu: true,
            },
        );
        assert!(c.iter().all(|v| v.is_nan()), "{c:?}");
    }
}
