//! An energy prior for joint training (`joint.energy_weight`): no DLF step may add mechanical
//! energy to the fluid.
//!
//! A fluid in a closed box, released from rest or thrown, only loses mechanical energy: viscosity
//! and the walls turn it into heat, and nothing inside the box does work on it. The specific
//! energy of a state (per kilogram, every particle of the same mass),
//!
//! E(x, v) = (1/N) Σ_i e_i, e_i = ½ |v_i|² − g · x_i,
//!
//! is therefore non-increasing from frame to frame. Every true sequence measured (four scenes of
//! the test bed, HoneyCone, WaterCube) keeps it so at every frame, and a grounded DLF does not:
//! on the built-in HoneyCone the quick settings' rollout gains 0.59 J/kg over t < 50 where the
//! honey comes to rest, and keeps it as fluid lifted where the truth has none (BENCHMARKS.md,
//! "the energy a rollout gains"). The image loss does not see that energy; d′ does.
//!
//! The term of one step from (x, v) to (x′, v′) is
//!
//! L = w · max(0, E(x′, v′) − E(x, v)) / (|g| r),
//!
//! the gain in units of lifting every particle by one radius r, so that the weight does not
//! depend on the scene's scale. The start state is held fixed: the step that gains the energy is
//! the one penalised, not the one before it. DLF's own integrator conserves E exactly in free fall
//! (its velocity is the displacement over dt, its position the trapezoid of the two velocities),
//! so the term is zero on a ballistic step and measures only what the network's correction adds.
//!
//! With `joint.energy_per = "particle"` the term holds each particle's own energy instead,
//! L = w · (1/N) Σ_i max(0, e_i(x′, v′) − e_i(x, v)) / (|g| r): in a viscous fluid no particle
//! gains energy (every particle of every true honey sequence measured only loses it), while a
//! water wave's run-up passes energy from particle to particle, which only the fluid's sum
//! keeps.

use burn::prelude::*;
use burn::tensor::activation::relu;
use neurofluid_core::tensors::mean_all;

use crate::config::EnergyPer;

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
/// `[1]`: max(0, E(after) − E(before)) / (|g| r) per fluid, the mean of each particle's
/// max(0, e_i(after) − e_i(before)) / (|g| r) per particle.
pub fn energy_gain(
    before: (Tensor<2>, Tensor<2>),
    after: (Tensor<2>, Tensor<2>),
    gravity: [f32; 3],
    radius: f32,
    per: EnergyPer,
) -> Tensor<1> {
    let g = gravity
        .iter()
        .map(|c| f64::from(*c).powi(2))
        .sum::<f64>()
        .sqrt();
    let unit = (g * f64::from(radius)).max(f64::MIN_POSITIVE);
    let start = particle_energies(before.0.detach(), before.1.detach(), gravity);
    let end = particle_energies(after.0, after.1, gravity);
    let gain = match per {
        EnergyPer::Fluid => relu(mean_all(end) - mean_all(start)),
        EnergyPer::Particle => mean_all(relu(end - start)),
    };
    gain.mul_scalar(1.0 / unit)
}

/// Per step of a sequence, the energy it gained in both forms (J/kg): index t is the step from
/// frame t − 1 to t; steps 0 and 1 hold 0 (step 1 is the first with a velocity).
#[derive(Debug, Clone, PartialEq)]
pub struct EnergyGains {
    /// max(0, E_t − E_{t−1}): the fluid's.
    pub fluid: Vec<f64>,
    /// The mean of max(0, e_i,t − e_i,t−1): each particle's (particle i the same in every frame).
    pub particle: Vec<f64>,
}

/// The energy a sequence of positions `frames` (one frame every `dt` seconds) gains at each
/// step, with each energy taken from the positions alone (velocity (x_t − x_{t−1}) / dt, as
/// DLF's own), both forms from one pass over the frames. What an evaluation reports of each
/// rollout and of the truth: a fluid in a closed box gains none.
pub fn energy_gains(frames: &[Vec<[f32; 3]>], dt: f32, gravity: [f32; 3]) -> EnergyGains {
    let energies = |t: usize| -> Vec<f64> {
        frames[t]
            .iter()
            .zip(&frames[t - 1])
            .map(|(p, q)| {
                (0..3)
                    .map(|k| {
                        let v = f64::from(p[k] - q[k]) / f64::from(dt);
                        0.5 * v * v - f64::from(gravity[k]) * f64::from(p[k])
                    })
                    .sum::<f64>()
            })
            .collect()
    };
    let mean = |e: &[f64]| e.iter().sum::<f64>() / e.len().max(1) as f64;
    // from step 1, the first with a velocity
    let each: Vec<Vec<f64>> = (1..frames.len()).map(energies).collect();
    let start = vec![0.0; frames.len().min(2)];
    let (mut fluid, mut particle) = (start.clone(), start);
    for pair in each.windows(2) {
        let (before, after) = (&pair[0], &pair[1]);
        fluid.push((mean(after) - mean(before)).max(0.0));
        let gained: Vec<f64> = after
            .iter()
            .zip(before)
            .map(|(a, b)| (a - b).max(0.0))
            .collect();
        particle.push(mean(&gained));
    }
    EnergyGains { fluid, particle }
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

    /// The term by hand, in f64: the fluid's gain, or the mean of each particle's.
    fn gain_by_hand(
        before: (&[[f32; 3]], &[[f32; 3]]),
        after: (&[[f32; 3]], &[[f32; 3]]),
        per: EnergyPer,
    ) -> f64 {
        let gain = match per {
            EnergyPer::Fluid => {
                (energy_by_hand(after.0, after.1) - energy_by_hand(before.0, before.1)).max(0.0)
            }
            EnergyPer::Particle => {
                (0..before.0.len())
                    .map(|i| {
                        let one = |s: (&[[f32; 3]], &[[f32; 3]])| {
                            energy_by_hand(&s.0[i..=i], &s.1[i..=i])
                        };
                        (one(after) - one(before)).max(0.0)
                    })
                    .sum::<f64>()
                    / before.0.len() as f64
            }
        };
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
        let gain = scalar(&energy_gain(
            (t(&x), t(&v)),
            (t(&x1), t(&v1)),
            G,
            R,
            EnergyPer::Fluid,
        ));
        assert!(gain < 1e-3, "{gain}");
    }

    /// Lifting every particle by one radius at rest costs exactly one unit; losing energy costs
    /// nothing.
    #[test]
    fn a_lift_by_one_radius_costs_one_and_a_loss_nothing() {
        let x = [[0.1, 0.2, 0.3], [-0.4, 0.0, 1.2]];
        let up: Vec<[f32; 3]> = x.iter().map(|p| [p[0], p[1], p[2] + R]).collect();
        let rest = [[0.0; 3]; 2];
        for per in [EnergyPer::Fluid, EnergyPer::Particle] {
            let lift = scalar(&energy_gain(
                (t(&x), t(&rest)),
                (t(&up), t(&rest)),
                G,
                R,
                per,
            ));
            assert!((lift - 1.0).abs() < 1e-3, "{per:?}: {lift}");
            let fall = scalar(&energy_gain(
                (t(&up), t(&rest)),
                (t(&x), t(&rest)),
                G,
                R,
                per,
            ));
            assert_eq!(fall, 0.0, "{per:?}");
        }
    }

    /// One particle lifted by one radius while another sinks by one: the fluid gains nothing,
    /// each particle's prior charges the lifted one, half a unit over two particles.
    #[test]
    fn energy_passed_between_particles_costs_only_per_particle() {
        let x = [[0.1, 0.2, 0.3], [-0.4, 0.0, 1.2]];
        let moved = [[0.1, 0.2, 0.3 + R], [-0.4, 0.0, 1.2 - R]];
        let rest = [[0.0; 3]; 2];
        let step = |per| {
            scalar(&energy_gain(
                (t(&x), t(&rest)),
                (t(&moved), t(&rest)),
                G,
                R,
                per,
            ))
        };
        assert!(
            step(EnergyPer::Fluid).abs() < 1e-3,
            "{}",
            step(EnergyPer::Fluid)
        );
        let each = step(EnergyPer::Particle);
        assert!((each - 0.5).abs() < 1e-3, "{each}");
    }

    /// The gradient with respect to the step's end state equals central differences of the
    /// term computed by hand, and the start state gets none (it is held fixed).
    #[test]
    fn gradient_matches_central_differences() {
        for per in [EnergyPer::Fluid, EnergyPer::Particle] {
            gradient_matches_central_differences_per(per);
        }
    }

    fn gradient_matches_central_differences_per(per: EnergyPer) {
        let x0 = [[0.1, 0.2, 0.3], [-0.4, 0.0, 1.2]];
        let v0 = [[0.1, 0.0, 0.0], [0.0, 0.0, 0.1]];
        // particle 1 gains, particle 0 loses a little (per particle only 1 is charged)
        let x1 = [[0.12, 0.21, 0.28], [-0.41, 0.02, 1.25]];
        let v1 = [[0.1, 0.05, 0.2], [-0.5, 1.0, 2.5]];
        let (px, pv) = (t(&x1).require_grad(), t(&v1).require_grad());
        let start = t(&x0).require_grad();
        let loss = energy_gain((start.clone(), t(&v0)), (px.clone(), pv.clone()), G, R, per);
        let value = scalar(&loss);
        assert!(value > 1.0, "the step must gain energy: {value}");
        let by_hand = gain_by_hand((&x0, &v0), (&x1, &v1), per);
        assert!(
            (value - by_hand).abs() < 1e-3 * value,
            "{per:?}: {value} vs {by_hand}"
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
                        gain_by_hand((&x0, &v0), (&x, &v), per)
                    };
                    let fd = (shifted(h) - shifted(-h)) / (2.0 * f64::from(h));
                    let got = f64::from(analytic[i][k]);
                    assert!(
                        (got - fd).abs() < 1e-3 * fd.abs().max(1.0),
                        "{per:?} {moved} {i} {k}: {got} vs {fd}"
                    );
                }
            }
        }
    }

    /// A sequence from DLF's integrator alone (free fall, no correction) gains nothing by
    /// `energy_gains`; one whose particles are lifted by one radius at one step gains |g| r there,
    /// the tensor term's unit.
    #[test]
    fn sequence_gains_match_the_definition() {
        let dt = 0.02f32;
        let (mut x, mut v) = (
            vec![[0.1f32, 0.2, 0.3], [0.0, 0.1, 1.0]],
            vec![[0.5f32, 0.0, 1.0]; 2],
        );
        let mut frames = vec![x.clone()];
        for _ in 0..10 {
            for (p, u) in x.iter_mut().zip(v.iter_mut()) {
                let before = *u;
                u[2] += G[2] * dt;
                for k in 0..3 {
                    p[k] += (before[k] + u[k]) * dt / 2.0;
                }
            }
            frames.push(x.clone());
        }
        let both = energy_gains(&frames, dt, G);
        for gains in [&both.fluid, &both.particle] {
            assert_eq!(gains.len(), frames.len());
            assert!(gains.iter().all(|&g| g < 1e-3), "{both:?}");
        }
        // at rest, then every particle lifted by one radius and left there
        let rest = vec![vec![[0.0f32, 0.0, 0.5]; 3]; 3];
        let lifted = vec![[0.0f32, 0.0, 0.5 + R]; 3];
        let frames: Vec<_> = rest.into_iter().chain([lifted.clone(), lifted]).collect();
        let expected = 9.81 * f64::from(R) + 0.5 * (f64::from(R) / f64::from(dt)).powi(2);
        let both = energy_gains(&frames, dt, G);
        for gains in [&both.fluid, &both.particle] {
            // step 3: the lift (potential 9.81 r, kinetic ½ (r/dt)²); step 4: at rest, a loss
            assert!((gains[3] - expected).abs() < 1e-4 * expected, "{gains:?}");
            assert_eq!(gains[4], 0.0);
        }
        // one particle of two lifted while the other sinks by as much, slowly (the sinker loses
        // more potential energy than it gains kinetic): the fluid gains only the kinetic part,
        // each particle's prior the lifted one's whole gain, halved
        let slow = 0.2f32;
        let rest = vec![vec![[0.0f32, 0.0, 0.5], [1.0, 0.0, 0.5]]; 3];
        let swapped = vec![[0.0f32, 0.0, 0.5 + R], [1.0, 0.0, 0.5 - R]];
        let frames: Vec<_> = rest.into_iter().chain([swapped]).collect();
        let kinetic = 0.5 * (f64::from(R) / f64::from(slow)).powi(2);
        let lifted = 9.81 * f64::from(R) + kinetic;
        let gains = energy_gains(&frames, slow, G);
        let (fluid, each) = (&gains.fluid, &gains.particle);
        assert!((fluid[3] - kinetic).abs() < 1e-4 * lifted, "{fluid:?}");
        assert!((each[3] - lifted / 2.0).abs() < 1e-4 * lifted, "{each:?}");
    }
}
