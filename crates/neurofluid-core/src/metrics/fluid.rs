//! What a sequence of fluid states does physically, from its positions alone: the mechanical
//! energy it gains per step and its mean kernel density. What the evaluation reports of each
//! rollout and of the truth, and what the joint stage's diagnostics log while it trains: a fluid
//! in a closed box gains no energy, and a viscous one keeps its density.

use crate::neighbors::{PairList, fixed_radius_pairs};

/// Kernel support of [`mean_density`] in particle radii.
pub const SUPPORT_RADII: f32 = 4.0;

/// `W(r) = (1 − r²/h²)³` for the squared distance `r2` and support `h` (0 beyond h).
fn kernel(r2: f64, h: f64) -> f64 {
    let q = 1.0 - r2 / (h * h);
    if q > 0.0 { q * q * q } else { 0.0 }
}

/// Σ_i ρ_i over the pairs `pairs` (each counted from both ends) with support `h`.
fn density_sum(pairs: &PairList, h: f32) -> f64 {
    let h = f64::from(h);
    pairs.dist2.iter().map(|&r2| kernel(f64::from(r2), h)).sum()
}

/// The mean kernel density ρ̄ = (1/N) Σ_i Σ_{j≠i} W(|x_i − x_j|) of `points` with support `h`
/// (every pair within h, each counted from both ends).
pub fn mean_density(points: &[[f32; 3]], h: f32) -> f64 {
    if points.is_empty() {
        return 0.0;
    }
    density_sum(&fixed_radius_pairs(points, points, h, true), h) / points.len() as f64
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

    const G: [f32; 3] = [0.0, 0.0, -9.81];
    const R: f32 = 0.025;

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

    /// Two particles half the support apart: each has one neighbour at W = (1 − ¼)³; beyond the
    /// support, none.
    #[test]
    fn mean_density_is_the_kernel_sum_by_hand() {
        let h = 0.1f32;
        let pair = [[0.0f32, 0.0, 0.0], [0.05, 0.0, 0.0]];
        let w = 0.75f64.powi(3);
        assert!(
            (mean_density(&pair, h) - w).abs() < 1e-6,
            "{}",
            mean_density(&pair, h)
        );
        let apart = [[0.0f32, 0.0, 0.0], [0.2, 0.0, 0.0]];
        assert_eq!(mean_density(&apart, h), 0.0);
        assert_eq!(mean_density(&[], h), 0.0);
    }
}
