//! The energy prior (`[joint.terms.energy]`): no DLF step may add mechanical energy to the
//! fluid.
//!
//! A fluid in a closed box, released from rest or thrown, only loses mechanical energy: viscosity
//! and the walls turn it into heat, and nothing inside the box does work on it. The specific
//! energy of a state (per kilogram, every particle of the same mass),
//!
//! E(x, v) = (1/N) Σ_i e_i, e_i = ½ |v_i|² − g · x_i,
//!
//! is therefore non-increasing from frame to frame. Every true sequence measured keeps it so at
//! every frame, and a grounded DLF does not (docs/notebook/benchmarks-history.md, "Issue 34: the
//! energy a rollout gains, and a prior against it"). The image loss does not see that energy;
//! d′ does. The term of one step from (x, v) to (x′, v′) is
//!
//! L = w · max(0, E(x′, v′) − E(x, v)) / (|g| r),
//!
//! the gain in units of lifting every particle by one radius r, so that the weight does not
//! depend on the scene's scale. The start state is held fixed: the step that gains the energy is
//! the one penalised, not the one before it. DLF's own integrator conserves E exactly in free fall
//! (its velocity is the displacement over dt, its position the trapezoid of the two velocities),
//! so the term is zero on a ballistic step and measures only what the network's correction adds.

use burn::prelude::*;
use burn::tensor::activation::relu;
use neurofluid_core::tensors::mean_all;
use serde::{Deserialize, Serialize};

use super::{ParticleTerm, TermContext, TermSettings, Transition, weight_problem};

/// `[joint.terms.energy]`: no DLF step may add mechanical energy to the fluid
/// (`w · max(0, E(x′, v′) − E(x, v)) / (|g| r)`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct EnergySettings {
    /// w, per unit of gain (lifting every particle by one radius; the quick configs: 0.005).
    pub weight: f64,
}

impl TermSettings for EnergySettings {
    fn build(&self, ctx: &TermContext) -> anyhow::Result<Option<Box<dyn ParticleTerm>>> {
        Ok((self.weight > 0.0).then(|| {
            Box::new(EnergyPrior {
                gravity: ctx.pretrained.config.gravity,
                radius: ctx.radius,
                weight: self.weight,
            }) as Box<dyn ParticleTerm>
        }))
    }

    fn problem(&self) -> Option<(&'static str, String)> {
        weight_problem(self.weight)
    }
}

/// The energy prior of a scene's gravity and particle radius.
pub struct EnergyPrior {
    gravity: [f32; 3],
    radius: f32,
    weight: f64,
}

impl ParticleTerm for EnergyPrior {
    fn name(&self) -> &'static str {
        "energy"
    }

    fn loss(&self, step: &Transition) -> Tensor<1> {
        let before = (step.before.0.clone(), step.before.1.clone());
        let after = (step.after.0.clone(), step.after.1.clone());
        energy_gain(before, after, self.gravity, self.radius).mul_scalar(self.weight)
    }
}

/// e_i(x, v) of the states `pos`, `vel` (`[N, 3]` each), `[N]`: each particle's ½|v|² − g·x,
/// for gravity `gravity` (m/s², the scene's frame).
pub fn particle_energies(pos: Tensor<2>, vel: Tensor<2>, gravity: [f32; 3]) -> Tensor<1> {
    let device = pos.device();
    let down: Tensor<2> =
        neurofluid_core::transfer::upload(TensorData::new(gravity.to_vec(), [3, 1]), &device);
    let kinetic = vel.powi_scalar(2).sum_dim(1).mul_scalar(0.5);
    let potential = pos.matmul(down).neg();
    (kinetic + potential).squeeze_dim(1)
}

/// The energy gain of the step from `before` (held fixed) to `after`, in units of |g|·`radius`,
/// `[1]`: max(0, E(after) − E(before)) / (|g| r).
pub fn energy_gain(
    before: (Tensor<2>, Tensor<2>),
    after: (Tensor<2>, Tensor<2>),
    gravity: [f32; 3],
    radius: f32,
) -> Tensor<1> {
    let g = gravity
        .iter()
        .map(|c| f64::from(*c).powi(2))
        .sum::<f64>()
        .sqrt();
    let unit = (g * f64::from(radius)).max(f64::MIN_POSITIVE);
    let start = particle_energies(before.0.detach(), before.1.detach(), gravity);
    let end = particle_energies(after.0, after.1, gravity);
    relu(mean_all(end) - mean_all(start)).mul_scalar(1.0 / unit)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::stages::views::{points_tensor, scalar, tensor_points};

    const G: [f32; 3] = [0.0, 0.0, -9.81];
    const R: f32 = 0.025;

    fn device() -> Device {
        neurofluid_core::device::cpu().autodiff()
    }

    fn t(v: &[[f32; 3]]) -> Tensor<2> {
        points_tensor(v, &device())
    }

    /// E by hand, in f64: ½|v|² + 9.81·z, averaged.
    fn energy_by_hand(x: &[[f32; 3]], v: &[[f32; 3]]) -> f64 {
        let n = x.len() as f64;
        x.iter()
            .zip(v)
            .map(|(p, u)| {
                let u: [f64; 3] = u.map(f64::from);
                0.5 * (u[0] * u[0] + u[1] * u[1] + u[2] * u[2]) + 9.81 * f64::from(p[2])
            })
            .sum::<f64>()
            / n
    }

    /// The term by hand, in f64: the fluid's gain in units of |g| r.
    fn gain_by_hand(before: (&[[f32; 3]], &[[f32; 3]]), after: (&[[f32; 3]], &[[f32; 3]])) -> f64 {
        let gain = (energy_by_hand(after.0, after.1) - energy_by_hand(before.0, before.1)).max(0.0);
        gain / (9.81 * f64::from(R))
    }

    #[test]
    fn energy_is_kinetic_plus_potential_per_kilogram() {
        let x = [[0.1, 0.2, 0.3], [-0.4, 0.0, 1.2]];
        let v = [[1.0, -2.0, 0.5], [0.0, 0.3, -0.7]];
        let e = particle_energies(t(&x), t(&v), G);
        assert_eq!(e.dims(), [2]);
        let e = e
            .into_data()
            .convert::<f32>()
            .try_into_vec::<f32>()
            .unwrap();
        for i in 0..2 {
            let by_hand = energy_by_hand(&x[i..=i], &v[i..=i]);
            assert!((f64::from(e[i]) - by_hand).abs() < 1e-5, "{i}: {e:?}");
        }
    }

    /// DLF's integrator without a correction (v′ = v + g dt, x′ = x + (v + v′) dt / 2) conserves
    /// E: a ballistic step gains nothing.
    #[test]
    fn a_ballistic_step_gains_nothing() {
        let dt = 0.02f32;
        let x = [[0.1, 0.2, 0.3], [-0.4, 0.0, 1.2], [0.3, -0.1, 0.05]];
        let v = [[1.0, -2.0, 0.5], [0.0, 0.3, -0.7], [0.2, 0.2, 3.0]];
        let v1: Vec<[f32; 3]> = v
            .iter()
            .map(|u| std::array::from_fn(|k| u[k] + G[k] * dt))
            .collect();
        let x1: Vec<[f32; 3]> = x
            .iter()
            .zip(v.iter().zip(&v1))
            .map(|(p, (a, b))| std::array::from_fn(|k| p[k] + (a[k] + b[k]) * dt / 2.0))
            .collect();
        // exact in real arithmetic; f32 rounding of the states leaves ~1e-6 J/kg
        let by_hand = energy_by_hand(&x1, &v1) - energy_by_hand(&x, &v);
        assert!(by_hand.abs() < 1e-5, "{by_hand}");
        let gain = scalar(&energy_gain((t(&x), t(&v)), (t(&x1), t(&v1)), G, R));
        assert!(gain < 1e-3, "{gain}");
    }

    /// Lifting every particle by one radius at rest costs exactly one unit; losing energy costs
    /// nothing; one particle lifted while another sinks as far costs nothing either (the fluid's
    /// energy is what the term holds).
    #[test]
    fn a_lift_by_one_radius_costs_one_and_a_loss_nothing() {
        let x = [[0.1, 0.2, 0.3], [-0.4, 0.0, 1.2]];
        let up: Vec<[f32; 3]> = x.iter().map(|p| [p[0], p[1], p[2] + R]).collect();
        let rest = [[0.0; 3]; 2];
        let lift = scalar(&energy_gain((t(&x), t(&rest)), (t(&up), t(&rest)), G, R));
        assert!((lift - 1.0).abs() < 1e-3, "{lift}");
        let fall = scalar(&energy_gain((t(&up), t(&rest)), (t(&x), t(&rest)), G, R));
        assert_eq!(fall, 0.0);
        let swapped = [[0.1, 0.2, 0.3 + R], [-0.4, 0.0, 1.2 - R]];
        let passed = scalar(&energy_gain(
            (t(&x), t(&rest)),
            (t(&swapped), t(&rest)),
            G,
            R,
        ));
        assert!(passed.abs() < 1e-3, "{passed}");
    }

    /// The gradient with respect to the step's end state equals central differences of the
    /// term computed by hand, and the start state gets none (it is held fixed).
    #[test]
    fn gradient_matches_central_differences() {
        let x0 = [[0.1, 0.2, 0.3], [-0.4, 0.0, 1.2]];
        let v0 = [[0.1, 0.0, 0.0], [0.0, 0.0, 0.1]];
        let x1 = [[0.12, 0.21, 0.28], [-0.41, 0.02, 1.25]];
        let v1 = [[0.1, 0.05, 0.2], [-0.5, 1.0, 2.5]];
        let (px, pv) = (t(&x1).require_grad(), t(&v1).require_grad());
        let start = t(&x0).require_grad();
        let loss = energy_gain((start.clone(), t(&v0)), (px.clone(), pv.clone()), G, R);
        let value = scalar(&loss);
        assert!(value > 1.0, "the step must gain energy: {value}");
        let by_hand = gain_by_hand((&x0, &v0), (&x1, &v1));
        assert!(
            (value - by_hand).abs() < 1e-3 * value,
            "{value} vs {by_hand}"
        );
        let grads = loss.backward();
        let gx = tensor_points(&px.grad(&grads).unwrap());
        let gv = tensor_points(&pv.grad(&grads).unwrap());
        assert!(
            start.grad(&grads).is_none(),
            "the start state is held fixed"
        );
        let h = 1e-3f32;
        for (moved, analytic) in [(0, &gx), (1, &gv)] {
            for i in 0..2 {
                for k in 0..3 {
                    let shifted = |s: f32| {
                        let (mut x, mut v) = (x1, v1);
                        if moved == 0 {
                            x[i][k] += s
                        } else {
                            v[i][k] += s
                        }
                        gain_by_hand((&x0, &v0), (&x, &v))
                    };
                    let fd = (shifted(h) - shifted(-h)) / (2.0 * f64::from(h));
                    let got = f64::from(analytic[i][k]);
                    assert!(
                        (got - fd).abs() < 1e-3 * fd.abs().max(1.0),
                        "{moved} {i} {k}: {got} vs {fd}"
                    );
                }
            }
        }
    }
}
