//! Finite-difference check of d loss / d particle positions in float64 on a tiny case: 9 rays
//! of the reference camera through the reference blob, with the case's weights. The fine depths
//! are held at the autodiff run's values (they are detached in the graph), and a coordinate is
//! only checked when no neighbour list changes within ±ε. ε = 1e-8 (env `FD_EPS` overrides):
//! at 1e-7 the ReLU kinks and the ×512 encodings crossed inside ±ε already cost ~4e-5 on a
//! direction that moves every particle.

use crate::common;

use burn::prelude::*;
use burn::tensor::{DType, TensorData};
use common::*;
use neurofluid_physnerf::{PhysNerf, RayBatch, RenderOutput};
use rand::{Rng, SeedableRng};

struct Setup {
    model: PhysNerf,
    /// The same weights off the autodiff device, for the many forward-only evaluations.
    plain: PhysNerf,
    plain_device: Device,
    rays: RayBatch,
    target: Vec<f64>,
    particles: Vec<f64>,
    device: Device,
}

fn tensor(v: &[f64], shape: [usize; 2], device: &Device) -> Tensor<2> {
    Tensor::from_data(TensorData::new(v.to_vec(), shape), (device, DType::F64))
}

fn loss_of(s: &Setup, out: &RenderOutput) -> Tensor<1> {
    let target = tensor(&s.target, [s.rays.len(), 3], &s.device);
    s.model.loss(out, target).total
}

/// Loss and neighbour fingerprint with fixed fine depths.
fn eval(s: &Setup, particles: &[f64], fine_z: &[f64]) -> (f64, Vec<u32>) {
    let p = tensor(particles, [particles.len() / 3, 3], &s.plain_device);
    let out = s
        .plain
        .render_rays_fixed_fine(&p, &s.rays, fine_z)
        .expect("render");
    let target = tensor(&s.target, [s.rays.len(), 3], &s.plain_device);
    let l = vals(s.plain.loss(&out, target).total)[0];
    let f = out.fine.as_ref().expect("fine pass");
    let mut fp: Vec<u32> = out.coarse.nbr_idx_sum.clone();
    fp.extend(&f.nbr_idx_sum);
    fp.extend(out.coarse.num_nn.iter().chain(&f.num_nn).map(|&n| n as u32));
    (l, fp)
}

#[test]
fn particle_gradients_match_central_differences() {
    let base = neurofluid_core::device::test_device();
    if !neurofluid_core::device::test_device_has_float64() {
        eprintln!("skipped: the device has no F64");
        return;
    }
    let device = base.clone().autodiff();
    let (inputs, _) = case();
    let model = model(&inputs, &device, DType::F64);
    let all = inputs.rays::<f64>();
    // a 3×3 block of pixels around the image centre (the blob)
    let ids: Vec<usize> = (7..10)
        .flat_map(|r| (7..10).map(move |c| r * 16 + c))
        .collect();
    let rays = RayBatch {
        origins: ids.iter().map(|&i| all.origins[i]).collect(),
        dirs: ids.iter().map(|&i| all.dirs[i]).collect(),
    };
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
    let target: Vec<f64> = (0..rays.len() * 3).map(|_| rng.random::<f64>()).collect();
    let particles: Vec<f64> = inputs.particles.iter().flatten().copied().collect();
    let s = Setup {
        plain: model.valid(),
        plain_device: base.clone(),
        model,
        rays,
        target,
        particles,
        device: device.clone(),
    };

    // autodiff
    let n = s.particles.len() / 3;
    let p = tensor(&s.particles, [n, 3], &device).require_grad();
    let out = s.model.render_rays(&p, &s.rays, None).expect("render");
    let fine_z = out.fine.as_ref().expect("fine").z.clone();
    let gated = out.coarse.mask.iter().filter(|&&m| m).count();
    assert!(
        gated > 50,
        "the rays must hit the blob ({gated} gated coarse samples)"
    );
    let grads = loss_of(&s, &out).backward();
    let g = vals(p.grad(&grads).expect("particle gradient"));
    let (_, fp0) = eval(&s, &s.particles, &fine_z);

    // coordinates: the 10 largest gradients and 5 random ones
    let mut order: Vec<usize> = (0..g.len()).collect();
    order.sort_by(|&a, &b| g[b].abs().total_cmp(&g[a].abs()));
    let mut coords: Vec<usize> = order[..10].to_vec();
    coords.extend((0..5).map(|_| rng.random_range(0..g.len())));
    let eps: f64 = std::env::var("FD_EPS")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(1e-8);
    let (mut fd, mut ad) = (Vec::new(), Vec::new());
    for &c in &coords {
        let mut plus = s.particles.clone();
        plus[c] += eps;
        let mut minus = s.particles.clone();
        minus[c] -= eps;
        let ((lp, fpp), (lm, fpm)) = (eval(&s, &plus, &fine_z), eval(&s, &minus, &fine_z));
        if fpp != fp0 || fpm != fp0 {
            eprintln!("coordinate {c}: a neighbour list changes within ±ε, skipped");
            continue;
        }
        fd.push((lp - lm) / (2.0 * eps));
        ad.push(g[c]);
    }
    assert!(
        fd.len() >= 12,
        "only {} coordinates could be checked",
        fd.len()
    );
    let err = rel_norm(&fd, &ad);
    eprintln!("{} coordinates: ‖fd − ad‖/‖ad‖ = {err:.3e}", fd.len());
    assert!(
        err < 1e-5,
        "finite differences disagree: relative error {err}"
    );
    assert!(
        ad.iter().map(|v| v.abs()).fold(0.0, f64::max) > 1e-6,
        "gradient is trivially zero"
    );

    // one random direction moving every particle that influences the loss at once (aligned
    // with the gradient's signs so that the directional derivative has no cancellation)
    let dir: Vec<f64> = g
        .iter()
        .map(|&gi| {
            if gi == 0.0 {
                0.0
            } else {
                gi.signum() * rng.random_range(0.5..1.0)
            }
        })
        .collect();
    let plus: Vec<f64> = s
        .particles
        .iter()
        .zip(&dir)
        .map(|(p, d)| p + eps * d)
        .collect();
    let minus: Vec<f64> = s
        .particles
        .iter()
        .zip(&dir)
        .map(|(p, d)| p - eps * d)
        .collect();
    let ((lp, fpp), (lm, fpm)) = (eval(&s, &plus, &fine_z), eval(&s, &minus, &fine_z));
    if fpp == fp0 && fpm == fp0 {
        let fd_dir = (lp - lm) / (2.0 * eps);
        let ad_dir: f64 = g.iter().zip(&dir).map(|(a, b)| a * b).sum();
        let rel = (fd_dir - ad_dir).abs() / ad_dir.abs();
        eprintln!("random direction: fd {fd_dir:.9e} vs ad {ad_dir:.9e}, rel {rel:.3e}");
        assert!(rel < 1e-5, "directional derivative: relative error {rel}");
    }
}
