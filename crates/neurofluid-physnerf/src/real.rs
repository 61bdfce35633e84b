//! Host-side floating-point type: the renderer does its host arithmetic (sample positions,
//! depths, ball query, importance sampling) in the precision of the particle tensor, so an
//! f64 run reproduces the f64 reference and an f32 run the f32 one.

use burn::tensor::{DType, Element};
use num_traits::Float;

/// f32 or f64, with the matching Burn dtype.
pub trait Real: Float + Element + Send + Sync + std::fmt::Debug + 'static {
    /// The Burn dtype of this type.
    const DTYPE: DType;
    /// Converts from f64 (rounds to nearest for f32).
    fn of(v: f64) -> Self;
    /// Widens to f64.
    fn f64(self) -> f64;
}

impl Real for f32 {
    const DTYPE: DType = DType::F32;
    fn of(v: f64) -> Self {
        v as f32
    }
    fn f64(self) -> f64 {
        self as f64
    }
}

impl Real for f64 {
    const DTYPE: DType = DType::F64;
    fn of(v: f64) -> Self {
        v
    }
    fn f64(self) -> f64 {
        self
    }
}

/// PyTorch's `linspace(start, end, n)` in type T: the first half counts up from `start`, the
/// second half down from `end` (`step = (end − start)/(n − 1)` rounded to T).
pub fn linspace<T: Real>(start: T, end: T, n: usize) -> Vec<T> {
    if n == 0 {
        return Vec::new();
    }
    if n == 1 {
        return vec![start];
    }
    let step = (end - start) / T::of((n - 1) as f64);
    let half = n / 2;
    (0..n)
        .map(|i| {
            if i < half {
                start + step * T::of(i as f64)
            } else {
                end - step * T::of((n - 1 - i) as f64)
            }
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn linspace_hits_both_ends_exactly() {
        let v = linspace(0.0f32, 1.0, 64);
        assert_eq!(v.len(), 64);
        assert_eq!(v[0], 0.0);
        assert_eq!(v[63], 1.0);
        for w in v.windows(2) {
            assert!((w[1] - w[0] - 1.0 / 63.0).abs() < 1e-6);
        }
    }
}
