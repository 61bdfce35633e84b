//! Depth sampling along rays, on the host: the coarse depths, optional stratified jitter, and
//! deterministic inverse-CDF importance sampling (nerf_pl `sample_pdf`, `det = True`). The
//! fine depths carry no gradient in the reference, so nothing here touches the autodiff graph.

use rand::{Rng, RngCore};

use crate::real::{Real, linspace};

/// Added to the bin weights and used as the denominator floor in [`sample_pdf`].
pub const PDF_EPS: f64 = 1e-5;

/// The `n` coarse depths `z = near·(1 − t) + far·t`, `t = linspace(0, 1, n)` (this formula,
/// not `near + (far − near)·t`), in type T.
pub fn coarse_depths<T: Real>(near: f64, far: f64, n: usize) -> Vec<T> {
    let (near, far) = (T::of(near), T::of(far));
    linspace(T::zero(), T::one(), n)
        .into_iter()
        .map(|t| near * (T::one() - t) + far * t)
        .collect()
}

/// Stratified jitter (NeRF): each depth is drawn uniformly between the midpoints around it
/// (the first and last interval end at the first and last depth). `z` is one ray's depths.
pub fn jitter_depths<T: Real>(z: &[T], rng: &mut dyn RngCore) -> Vec<T> {
    let n = z.len();
    let half = T::of(0.5);
    (0..n)
        .map(|i| {
            let lo = if i == 0 {
                z[0]
            } else {
                half * (z[i - 1] + z[i])
            };
            let hi = if i + 1 == n {
                z[n - 1]
            } else {
                half * (z[i] + z[i + 1])
            };
            lo + (hi - lo) * T::of(rng.random::<f64>())
        })
        .collect()
}

/// Number of entries of the ascending `cdf` that are ≤ u: `searchsorted(cdf, u, right=True)`.
pub fn searchsorted_right<T: Real>(cdf: &[T], u: T) -> usize {
    cdf.partition_point(|&c| c <= u)
}

/// Inverse-CDF sampling of one ray (nerf_pl `sample_pdf`).
///
/// `bins` are the B bin edges (the midpoints of the coarse depths), `weights` the B − 1 bin
/// weights (coarse weights without the first and last sample), `u` the sample positions in
/// [0, 1] (`linspace(0, 1, n)` when deterministic). Returns one depth per u, in u order:
/// `w += 1e-5; pdf = w/Σw; cdf = [0, cumsum(pdf)]; i = searchsorted(cdf, u, right)`,
/// `below = max(i − 1, 0)`, `above = min(i, B − 1)`, `denom = cdf[above] − cdf[below]`
/// (1 where < 1e-5), `z = bins[below] + (u − cdf[below])/denom · (bins[above] − bins[below])`.
pub fn sample_pdf<T: Real>(bins: &[T], weights: &[T], u: &[T]) -> Vec<T> {
    assert_eq!(
        bins.len(),
        weights.len() + 1,
        "sample_pdf: need one more bin edge than weights"
    );
    let eps = T::of(PDF_EPS);
    let w: Vec<T> = weights.iter().map(|&w| w + eps).collect();
    let sum = w.iter().fold(T::zero(), |a, &b| a + b);
    let mut cdf = Vec::with_capacity(bins.len());
    cdf.push(T::zero());
    let mut acc = T::zero();
    for &wi in &w {
        acc = acc + wi / sum;
        cdf.push(acc);
    }
    let last = weights.len();
    u.iter()
        .map(|&u| {
            let ind = searchsorted_right(&cdf, u);
            let below = ind.saturating_sub(1);
            let above = ind.min(last);
            let mut denom = cdf[above] - cdf[below];
            if denom < eps {
                denom = T::one();
            }
            bins[below] + (u - cdf[below]) / denom * (bins[above] - bins[below])
        })
        .collect()
}

/// The midpoints `0.5·(z_k + z_{k+1})` of one ray's depths.
pub fn midpoints<T: Real>(z: &[T]) -> Vec<T> {
    let half = T::of(0.5);
    z.windows(2).map(|w| half * (w[0] + w[1])).collect()
}

/// The u values of the fine sampling: `linspace(0, 1, n)`, or n sorted uniform draws when
/// `rng` is given (stratified mode).
pub fn fine_u<T: Real>(n: usize, rng: Option<&mut dyn RngCore>) -> Vec<T> {
    match rng {
        None => linspace(T::zero(), T::one(), n),
        Some(rng) => {
            let mut u: Vec<T> = (0..n).map(|_| T::of(rng.random::<f64>())).collect();
            u.sort_by(|a, b| a.partial_cmp(b).unwrap_or(std::cmp::Ordering::Equal));
            u
        }
    }
}

/// `sort(cat(a, b))` of one ray's depths.
pub fn merge_sorted<T: Real>(a: &[T], b: &[T]) -> Vec<T> {
    let mut z: Vec<T> = a.iter().chain(b).copied().collect();
    z.sort_by(|x, y| x.partial_cmp(y).unwrap_or(std::cmp::Ordering::Equal));
    z
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn searchsorted_right_counts_entries_at_or_below() {
        let cdf = [0.0f64, 0.25, 0.5, 0.5, 1.0];
        assert_eq!(searchsorted_right(&cdf, -1.0), 0);
        assert_eq!(searchsorted_right(&cdf, 0.0), 1);
        assert_eq!(searchsorted_right(&cdf, 0.3), 2);
        assert_eq!(searchsorted_right(&cdf, 0.5), 4);
        assert_eq!(searchsorted_right(&cdf, 1.0), 5);
    }

    #[test]
    fn uniform_weights_give_uniform_depths() {
        // equal weights: the inverse CDF is the identity map from u to the bin range
        let bins: Vec<f64> = (0..11).map(|i| i as f64).collect();
        let w = vec![0.3; 10];
        let u = linspace(0.0, 1.0, 21);
        let z = sample_pdf(&bins, &w, &u);
        for (zi, ui) in z.iter().zip(&u) {
            assert!((zi - 10.0 * ui).abs() < 1e-9, "{zi} vs {}", 10.0 * ui);
        }
    }

    #[test]
    fn samples_concentrate_in_the_heavy_bin() {
        let bins: Vec<f64> = (0..5).map(|i| i as f64).collect();
        let w = [0.0, 1.0, 0.0, 0.0];
        let z = sample_pdf(&bins, &w, &linspace(0.0, 1.0, 100));
        let inside = z.iter().filter(|&&z| (1.0..=2.0).contains(&z)).count();
        // u = 0 and u = 1 land on the outer edges; everything else in the heavy bin
        assert_eq!(inside, 98, "{inside} of 100 in the heavy bin");
        assert!(z.windows(2).all(|w| w[0] <= w[1]));
    }

    #[test]
    fn coarse_depths_span_near_far() {
        let z = coarse_depths::<f32>(3.0, 5.0, 64);
        assert_eq!(z[0], 3.0);
        assert_eq!(z[63], 5.0);
    }
}
