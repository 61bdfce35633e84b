//! The energy cap: no particle's mechanical energy per unit mass, e = ½|v|² − g·x, may rise over
//! a step. A viscous fluid's particles only lose energy (none of the honey sequences of the test
//! bed or of the generator gains any, per particle, over their training frames); DLF, trained on
//! water, kicks each honey particle by about 1 J/kg over 49 steps and throws some of them clear of
//! the fluid.
//!
//! A particle whose step would gain energy takes a shorter step along the same displacement:
//! x' = x + s·(x_new − x), v' = s·v_new, with s the largest value in [0, 1] for which
//! e(x', v') ≤ e(x, v). With d = x_new − x, e(x', v') − e(x, v) = A s² + B s − K for
//! A = ½|v_new|², B = −g·d and K = ½|v|², a quadratic that is −K ≤ 0 at s = 0; s is its larger
//! root (or 1). v = (x_new − x)/dt keeps holding. Gradients flow through s.

use burn::prelude::*;

/// Guards the square root and the divisions (squared speeds are ~10⁻²–10 m²/s²).
const EPS: f32 = 1e-12;

/// `(x', v')` from the state `(pos, vel)` and the step's `(pos_new, vel_new)` `[N, 3]`, each
/// particle's step shortened so that its energy does not rise under `gravity` (m/s², same frame).
pub fn cap_particle_energy(
    pos: Tensor<2>,
    vel: Tensor<2>,
    pos_new: Tensor<2>,
    vel_new: Tensor<2>,
    gravity: [f32; 3],
) -> (Tensor<2>, Tensor<2>) {
    let device = pos.device();
    let g: Tensor<2> =
        neurofluid_core::transfer::upload(TensorData::new(gravity.to_vec(), [3, 1]), &device);
    let d = pos_new.clone() - pos;
    let a = vel_new.clone().powi_scalar(2).sum_dim(1).mul_scalar(0.5);
    let k = vel.powi_scalar(2).sum_dim(1).mul_scalar(0.5);
    let b = d.clone().matmul(g).neg();
    let rises = (a.clone() + b.clone() - k.clone()).greater_elem(0.0);
    let root = (b.clone().powi_scalar(2) + a.clone() * k.clone() * 4.0)
        .add_scalar(EPS)
        .sqrt();
    // the larger root in the form that does not cancel: 2K/(B + √D) for B ≥ 0, (√D − B)/2A else
    let when_rising = (k * 2.0) / (b.clone() + root.clone()).clamp_min(EPS);
    let when_falling = (root - b.clone()) / (a * 2.0).clamp_min(EPS);
    let s = when_falling
        .mask_where(b.greater_equal_elem(0.0), when_rising)
        .clamp_max(1.0);
    let n = s.dims()[0];
    let s = s.mask_fill(rises.bool_not(), 1.0).expand([n, 3]);
    // x_new − (1 − s)·d, so that a step left alone (s = 1) is DLF's to the bit
    (pos_new - d * s.clone().neg().add_scalar(1.0), vel_new * s)
}

#[cfg(test)]
mod tests {
    use super::*;
    use neurofluid_core::tensors::{points_tensor, tensor_points};

    const G: [f32; 3] = [0.0, 0.0, -9.81];
    const DT: f64 = 0.02;

    fn energy(x: [f64; 3], v: [f64; 3]) -> f64 {
        let g = G.map(f64::from);
        0.5 * (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]) - (g[0] * x[0] + g[1] * x[1] + g[2] * x[2])
    }

    /// The largest s in [0, 1] with e(x + s·d, s·v_new) ≤ e(x, v), by bisection on the energy
    /// itself (e − e₀ is a convex parabola in s, ≤ 0 at s = 0).
    fn s_by_bisection(x: [f64; 3], v: [f64; 3], x_new: [f64; 3]) -> f64 {
        let e0 = energy(x, v);
        let at = |s: f64| {
            let p = std::array::from_fn(|k| x[k] + s * (x_new[k] - x[k]));
            let u = std::array::from_fn(|k| s * (x_new[k] - x[k]) / DT);
            energy(p, u) - e0
        };
        if at(1.0) <= 0.0 {
            return 1.0;
        }
        let (mut lo, mut hi) = (0.0, 1.0);
        for _ in 0..200 {
            let mid = 0.5 * (lo + hi);
            if at(mid) <= 0.0 { lo = mid } else { hi = mid }
        }
        lo
    }

    type Points = Vec<[f32; 3]>;

    /// States and steps: at rest and pushed sideways (s = 0), thrown up, falling freely, lifted
    /// a little while moving fast, slowed down, and a mix of random ones.
    fn cases() -> (Points, Points, Points) {
        let mut x = vec![
            [0.1, 0.2, 0.3],
            [0.0, 0.0, 0.5],
            [0.3, -0.2, 0.9],
            [0.0, 0.1, 0.2],
        ];
        let mut v = vec![
            [0.0, 0.0, 0.0],
            [0.0, 0.0, 0.5],
            [0.0, 0.0, 0.0],
            [2.0, 0.0, 0.0],
        ];
        let mut d = vec![
            [0.01, 0.0, 0.0],
            [0.0, 0.0, 0.03],
            [0.0, 0.0, -0.5 * 9.81 * 0.0004],
            [0.038, 0.0, 0.002],
        ];
        x.push([0.2, 0.2, 0.2]);
        v.push([1.0, 1.0, 0.0]);
        d.push([0.01, 0.01, 0.0]);
        let mut seed = 7u64;
        let mut next = || {
            seed = seed
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            ((seed >> 33) as f64 / (1u64 << 31) as f64 - 0.5) as f32
        };
        for _ in 0..40 {
            x.push([next(), next(), next() + 0.5]);
            v.push([2.0 * next(), 2.0 * next(), 2.0 * next()]);
            d.push([0.06 * next(), 0.06 * next(), 0.06 * next()]);
        }
        let x_new = x
            .iter()
            .zip(&d)
            .map(|(p, d)| std::array::from_fn(|k| p[k] + d[k]))
            .collect();
        (x, v, x_new)
    }

    fn velocity(x: &[[f32; 3]], x_new: &[[f32; 3]]) -> Vec<[f32; 3]> {
        x.iter()
            .zip(x_new)
            .map(|(a, b)| std::array::from_fn(|k| ((b[k] as f64 - a[k] as f64) / DT) as f32))
            .collect()
    }

    fn capped(x: &[[f32; 3]], v: &[[f32; 3]], x_new: &[[f32; 3]]) -> (Tensor<2>, Tensor<2>) {
        let device = neurofluid_core::device::cpu();
        let t = |p: &[[f32; 3]]| points_tensor(p, &device);
        let v_new = velocity(x, x_new);
        cap_particle_energy(t(x), t(v), t(x_new), t(&v_new), G)
    }

    #[test]
    fn each_step_is_shortened_to_the_largest_that_gains_no_energy() {
        let (x, v, x_new) = cases();
        let (p, u) = capped(&x, &v, &x_new);
        let (p, u) = (tensor_points(&p), tensor_points(&u));
        let f = |a: [f32; 3]| a.map(f64::from);
        let mut shortened = 0;
        for i in 0..x.len() {
            let s = s_by_bisection(f(x[i]), f(v[i]), f(x_new[i]));
            shortened += usize::from(s < 1.0);
            for k in 0..3 {
                let want = f64::from(x[i][k]) + s * (f64::from(x_new[i][k]) - f64::from(x[i][k]));
                assert!(
                    (f64::from(p[i][k]) - want).abs() < 2e-6,
                    "{i} {k}: {:?} vs s {s}",
                    p[i]
                );
                // v = (x' − x)/dt still holds
                let dv = (f64::from(p[i][k]) - f64::from(x[i][k])) / DT;
                assert!(
                    (f64::from(u[i][k]) - dv).abs() < 2e-4,
                    "{i} {k}: {} vs {dv}",
                    u[i][k]
                );
            }
            let gain = energy(f(p[i]), f(u[i])) - energy(f(x[i]), f(v[i]));
            assert!(gain < 1e-4, "particle {i} gains {gain}");
        }
        // at rest and pushed sideways: no step at all
        assert_eq!((p[0], u[0]), (x[0], [0.0; 3]));
        assert!(
            shortened > 5 && shortened < x.len() - 5,
            "{shortened} of {}",
            x.len()
        );
    }

    #[test]
    fn steps_that_gain_nothing_pass_unchanged() {
        let (x, v, x_new) = cases();
        let v_new = velocity(&x, &x_new);
        let (p, u) = capped(&x, &v, &x_new);
        let (p, u) = (tensor_points(&p), tensor_points(&u));
        let f = |a: [f32; 3]| a.map(f64::from);
        for i in 0..x.len() {
            if s_by_bisection(f(x[i]), f(v[i]), f(x_new[i])) == 1.0 {
                assert_eq!((p[i], u[i]), (x_new[i], v_new[i]), "particle {i}");
            }
        }
    }

    #[test]
    fn gradient_matches_central_differences_of_the_bisection() {
        let (x, v, x_new) = cases();
        let device = neurofluid_core::device::cpu().autodiff();
        let t = |p: &[[f32; 3]]| points_tensor(p, &device);
        let n = x.len();
        // a fixed linear read-out of x' and v' (weights w, w/10)
        let w: Vec<[f32; 3]> = (0..n)
            .map(|i| [1.0 + i as f32 * 0.1, -0.5, 0.25 * (i % 3) as f32])
            .collect();
        let moved = t(&x_new).require_grad();
        let v_new = (moved.clone() - t(&x)).div_scalar(DT as f32);
        let (p, u) = cap_particle_energy(t(&x), t(&v), moved.clone(), v_new, G);
        let loss = (p * t(&w)).sum() + (u * t(&w)).sum().div_scalar(10.0);
        let grads = loss.backward();
        let analytic = tensor_points(&moved.grad(&grads).unwrap());
        let f = |a: [f32; 3]| a.map(f64::from);
        let read_out = |i: usize, xn: [f64; 3]| {
            let s = s_by_bisection(f(x[i]), f(v[i]), xn);
            (0..3)
                .map(|k| {
                    let d = xn[k] - f64::from(x[i][k]);
                    let wk = f64::from(w[i][k]);
                    wk * (f64::from(x[i][k]) + s * d) + wk / 10.0 * s * d / DT
                })
                .sum::<f64>()
        };
        let h = 1e-5;
        let mut checked = 0;
        for i in 0..n {
            for k in 0..3 {
                let at = |e: f64| {
                    let mut xn = f(x_new[i]);
                    xn[k] += e;
                    xn
                };
                // where a shift crosses s = 0 or s = 1 the read-out has a kink: no derivative
                let s = [-h, 0.0, h].map(|e| s_by_bisection(f(x[i]), f(v[i]), at(e)));
                if s.iter().any(|&s| s < 1e-6) || s.contains(&1.0) && s.iter().any(|&s| s < 1.0) {
                    continue;
                }
                checked += usize::from(s[1] < 1.0);
                let shifted = |e: f64| read_out(i, at(e));
                let fd = (shifted(h) - shifted(-h)) / (2.0 * h);
                let got = f64::from(analytic[i][k]);
                assert!(
                    (got - fd).abs() < 2e-2 * fd.abs().max(1.0),
                    "particle {i}, axis {k}: {got} vs {fd}"
                );
            }
        }
        assert!(
            checked > 30,
            "{checked} derivatives of shortened steps checked"
        );
    }
}
