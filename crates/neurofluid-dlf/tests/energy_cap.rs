//! `DlfConfig::cap_particle_energy` on a pretrained rollout: without the cap, DLF's steps raise
//! some particles' mechanical energy (½|v|² − g·x) on the stored falling-cube case; with it no
//! step raises any particle's, the particles the cap leaves alone take DLF's step bit for bit,
//! and v stays the displacement over dt.

use crate::common;

use common::{CaseScene, Scene, device, pretrained};
use neurofluid_dlf::net::{points_tensor, tensor_points};
use neurofluid_dlf::rollout::rollout;
use neurofluid_dlf::{DlfConfig, EnergyCap, StepRules};

fn energy(x: [f32; 3], v: [f32; 3], g: [f32; 3]) -> f64 {
    (0..3)
        .map(|k| 0.5 * f64::from(v[k]).powi(2) - f64::from(g[k]) * f64::from(x[k]))
        .sum()
}

/// The most any particle's energy rises over one step of `r` (J/kg), and how many steps of a
/// particle raise it by more than `tol`.
fn rises(r: &neurofluid_dlf::rollout::Rollout, g: [f32; 3], tol: f64) -> (f64, usize) {
    let mut most = f64::NEG_INFINITY;
    let mut count = 0;
    for t in 1..r.pos.len() {
        for i in 0..r.pos[t].len() {
            let gain =
                energy(r.pos[t][i], r.vel[t][i], g) - energy(r.pos[t - 1][i], r.vel[t - 1][i], g);
            most = most.max(gain);
            count += usize::from(gain > tol);
        }
    }
    (most, count)
}

#[test]
fn no_capped_step_raises_a_particles_energy() {
    let device = device();
    let scene = Scene::load("cubedrop2197_dlfwall");
    let free = pretrained(&device);
    let capped = free.clone().with_config(DlfConfig {
        rules: StepRules {
            energy_cap: EnergyCap::Particle,
            ..StepRules::default()
        },
        ..DlfConfig::default()
    });
    let g = DlfConfig::default().gravity;
    let b = scene.boundary(&free, &device);
    let steps = 30;
    let tol = 1e-4;
    let open = rollout(&free, &scene.pos, &scene.vel, &b, steps, |_| {});
    let (_, raised) = rises(&open, g, tol);
    assert!(
        raised > 100,
        "DLF alone must raise some particles' energy: {raised}"
    );
    let r = rollout(&capped, &scene.pos, &scene.vel, &b, steps, |_| {});
    let (most, raised) = rises(&r, g, tol);
    assert_eq!(raised, 0, "capped: the largest rise is {most} J/kg");
    // one capped step from a state of the capped rollout: the particles it leaves alone move
    // exactly as DLF moves them, and every velocity is the move over dt
    let t = steps / 2;
    let step = |net: &neurofluid_dlf::DlfNet| {
        let o = net.step(
            points_tensor(&r.pos[t], &device),
            points_tensor(&r.vel[t], &device),
            &b,
        );
        (tensor_points(&o.pos), tensor_points(&o.vel))
    };
    let (p_free, v_free) = step(&free);
    let (p_cap, v_cap) = step(&capped);
    let dt = DlfConfig::default().dt;
    let mut alone = 0;
    for i in 0..p_free.len() {
        let e0 = energy(r.pos[t][i], r.vel[t][i], g);
        if energy(p_free[i], v_free[i], g) <= e0 {
            alone += 1;
            assert_eq!((p_cap[i], v_cap[i]), (p_free[i], v_free[i]), "particle {i}");
        }
        for k in 0..3 {
            let v = (p_cap[i][k] - r.pos[t][i][k]) / dt;
            assert!(
                (v - v_cap[i][k]).abs() <= 1e-3 * (1.0 + v.abs()),
                "particle {i}"
            );
        }
    }
    assert!(
        alone > 0 && alone < p_free.len(),
        "{alone} of {} left alone",
        p_free.len()
    );
}
