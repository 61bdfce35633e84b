//! Noise on the training rollout's inputs (`joint.input_noise`; issue 71, item 7): before each
//! transition of the joint stage, Gaussian noise of standard deviation σ (m/s) is added to the
//! velocities DLF steps from, as learned simulators are trained for long rollouts
//! (Sanchez-Gonzalez et al. 2020 corrupt the input velocities with a random walk). The next
//! frame's image stays the target, so what is trained (DLF's weights, the fitted scalars) learns
//! to take an error in the state out rather than carry it. The rollout the joint stage already
//! trains on is its own prediction (the pushforward); the noise widens the states it sees.
//!
//! The noise of iteration `step` comes from its own stream of (seed, step), so a run resumed at
//! any step draws what the uninterrupted run drew, with no state in the checkpoint.

use burn::prelude::*;
use neurofluid_core::sampler::Rng;

use neurofluid_core::tensors::points_tensor;

/// `vel` `[N, 3]` with the noise of iteration `step` added (σ in m/s; σ = 0: `vel` itself).
pub fn with_input_noise(vel: Tensor<2>, sigma: f64, seed: u64, step: u64) -> Tensor<2> {
    if sigma == 0.0 {
        return vel;
    }
    let n = vel.dims()[0];
    let noise = points_tensor(&noise_rows(n, sigma, seed, step), &vel.device());
    vel + noise
}

/// The `n` noise vectors of iteration `step`.
fn noise_rows(n: usize, sigma: f64, seed: u64, step: u64) -> Vec<[f32; 3]> {
    let mut rng = Rng::stream(seed, &format!("joint-input-noise/{step}"));
    let mut draw = || (sigma * rng.normal()) as f32;
    (0..n).map(|_| [draw(), draw(), draw()]).collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use neurofluid_core::tensors::tensor_points;

    fn velocities(n: usize) -> Tensor<2> {
        let rows: Vec<[f32; 3]> = (0..n).map(|i| [i as f32 * 0.01, -1.0, 0.5]).collect();
        points_tensor(&rows, &neurofluid_core::device::cpu().autodiff())
    }

    #[test]
    fn no_noise_leaves_the_velocities() {
        let v = velocities(5);
        let out = with_input_noise(v.clone(), 0.0, 10, 3);
        assert_eq!(tensor_points(&out), tensor_points(&v));
    }

    /// The added noise has the asked standard deviation on every axis and no mean (20 000
    /// particles: the sample sd within 2 %), is the same for the same (seed, step) and differs
    /// between steps and seeds.
    #[test]
    fn the_noise_is_sigma_and_fixed_by_seed_and_step() {
        let n = 20_000;
        let sigma = 0.05;
        let v = velocities(n);
        let noisy = tensor_points(&with_input_noise(v.clone(), sigma, 10, 7));
        let clean = tensor_points(&v);
        for axis in 0..3 {
            let d: Vec<f64> = (0..n)
                .map(|i| f64::from(noisy[i][axis] - clean[i][axis]))
                .collect();
            let mean = d.iter().sum::<f64>() / n as f64;
            let sd = (d.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / n as f64).sqrt();
            assert!(
                mean.abs() < 3.0 * sigma / (n as f64).sqrt(),
                "axis {axis}: mean {mean}"
            );
            assert!((sd / sigma - 1.0).abs() < 0.02, "axis {axis}: sd {sd}");
        }
        assert_eq!(noise_rows(50, sigma, 10, 7), noise_rows(50, sigma, 10, 7));
        assert_ne!(noise_rows(50, sigma, 10, 7), noise_rows(50, sigma, 10, 8));
        assert_ne!(noise_rows(50, sigma, 10, 7), noise_rows(50, sigma, 11, 7));
    }
}
