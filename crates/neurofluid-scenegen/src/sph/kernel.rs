//! The cubic spline kernel (support radius h) used by the solver and the surface field.

use glam::DVec3;

/// Cubic spline kernel with compact support `h` (W = 0 for |x| ≥ h), normalised in 3-D.
#[derive(Debug, Clone, Copy)]
pub struct CubicKernel {
    h: f64,
    inv_h: f64,
    k: f64,
    l: f64,
}

impl CubicKernel {
    /// A kernel with support radius `h`.
    pub fn new(h: f64) -> Self {
        let h3 = h * h * h;
        Self {
            h,
            inv_h: 1.0 / h,
            k: 8.0 / (std::f64::consts::PI * h3),
            l: 48.0 / (std::f64::consts::PI * h3),
        }
    }

    /// Support radius.
    pub fn support(&self) -> f64 {
        self.h
    }

    /// W(r) for a distance r ≥ 0.
    pub fn w(&self, r: f64) -> f64 {
        let q = r * self.inv_h;
        if q <= 0.5 {
            self.k * (6.0 * q * q * (q - 1.0) + 1.0)
        } else if q < 1.0 {
            let a = 1.0 - q;
            self.k * 2.0 * a * a * a
        } else {
            0.0
        }
    }

    /// ∇W at offset `x` (gradient with respect to the first point).
    pub fn grad(&self, x: DVec3) -> DVec3 {
        let r = x.length();
        let q = r * self.inv_h;
        if r <= 1e-9 || q >= 1.0 {
            return DVec3::ZERO;
        }
        let dwdq = if q <= 0.5 {
            self.l * q * (3.0 * q - 2.0)
        } else {
            let a = 1.0 - q;
            -self.l * a * a
        };
        x * (dwdq * self.inv_h / r)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn integrates_to_one_and_gradient_matches_finite_differences() {
        let k = CubicKernel::new(0.1);
        // midpoint-rule volume integral on a fine lattice
        let n = 60;
        let d = 0.2 / n as f64;
        let mut sum = 0.0;
        for i in 0..n {
            for j in 0..n {
                for l in 0..n {
                    let p = DVec3::new(
                        -0.1 + (i as f64 + 0.5) * d,
                        -0.1 + (j as f64 + 0.5) * d,
                        -0.1 + (l as f64 + 0.5) * d,
                    );
                    sum += k.w(p.length()) * d * d * d;
                }
            }
        }
        assert!((sum - 1.0).abs() < 2e-3, "{sum}");
        for x in [
            DVec3::new(0.01, 0.02, -0.005),
            DVec3::new(0.05, -0.03, 0.04),
        ] {
            let e = 1e-6;
            let fd = DVec3::new(
                (k.w((x + DVec3::X * e).length()) - k.w((x - DVec3::X * e).length())) / (2.0 * e),
                (k.w((x + DVec3::Y * e).length()) - k.w((x - DVec3::Y * e).length())) / (2.0 * e),
                (k.w((x + DVec3::Z * e).length()) - k.w((x - DVec3::Z * e).length())) / (2.0 * e),
            );
            assert!(
                (k.grad(x) - fd).length() < 1e-4 * fd.length().max(1.0),
                "{x}"
            );
        }
    }
}
