//! `DlfConfig::container`: the walls of a box enforced on DLF's predictions. Checked against
//! what the clamp must do (every particle inside, the ones it did not move untouched, v still the
//! displacement over dt), against finite differences, and on a pretrained rollout through a floor
//! the box particles do not stop.

use crate::common;

use common::{CaseScene, Scene, device, pretrained};
use neurofluid_core::scene::Aabb;
use neurofluid_dlf::DlfConfig;
use neurofluid_dlf::net::{contain, points_tensor, tensor_points};
use neurofluid_dlf::rollout::rollout;

/// The stored falling-cube case with its lowest particles thrown down hard enough to pass the
/// floor in one step.
fn thrown_down() -> (Scene, Aabb) {
    let mut scene = Scene::load("cubedrop2197_dlfwall");
    let floor = scene.pos.iter().map(|p| p[1]).fold(f32::INFINITY, f32::min);
    for (p, v) in scene.pos.iter().zip(scene.vel.iter_mut()) {
        if p[1] < floor + 0.06 {
            v[1] = -40.0;
        }
    }
    let c = Aabb {
        min: scene.box_lo,
        max: scene.box_hi,
    };
    (scene, c)
}

#[test]
fn a_contained_step_keeps_every_particle_inside_and_leaves_the_others_bit_identical() {
    let device = device();
    let (scene, container) = thrown_down();
    let open = pretrained(&device);
    let walled = open.clone().with_config(DlfConfig {
        container: Some(container),
        ..DlfConfig::default()
    });
    let b = scene.boundary(&open, &device);
    let step = |net: &neurofluid_dlf::DlfNet| {
        let o = net.step(
            points_tensor(&scene.pos, &device),
            points_tensor(&scene.vel, &device),
            &b,
        );
        (tensor_points(&o.pos), tensor_points(&o.vel))
    };
    let (p_open, v_open) = step(&open);
    let (p_wall, v_wall) = step(&walled);
    let escaped = p_open.iter().filter(|&&p| !container.contains(p)).count();
    assert!(
        escaped > 0,
        "the thrown particles must pass the floor without the walls"
    );
    let dt = DlfConfig::default().dt;
    for i in 0..p_open.len() {
        assert!(
            container.contains(p_wall[i]),
            "particle {i} at {:?}",
            p_wall[i]
        );
        if container.contains(p_open[i]) {
            assert_eq!(p_wall[i], p_open[i], "particle {i} moved though inside");
            assert_eq!(v_wall[i], v_open[i], "particle {i}'s velocity changed");
        } else {
            assert_eq!(p_wall[i], container.clamp(p_open[i]));
        }
        for a in 0..3 {
            let v = (p_wall[i][a] - scene.pos[i][a]) / dt;
            assert!(
                (v - v_wall[i][a]).abs() <= 1e-3 * (1.0 + v.abs()),
                "particle {i}: v = {} but the move over dt is {v}",
                v_wall[i][a]
            );
        }
    }
}

#[test]
fn the_clamps_gradient_matches_finite_differences() {
    let device = device().autodiff();
    let container = Aabb {
        min: [-1.0, 0.0, -1.0],
        max: [1.0, 2.0, 1.0],
    };
    let dt = 0.02;
    // inside, below the floor, outside two walls at once
    let pos = [[0.2, 0.5, -0.3], [0.1, -0.4, 0.2], [1.3, 0.7, -1.6]];
    let vel = [[0.5, -1.0, 0.2], [0.0, -20.0, 0.1], [3.0, 0.5, -4.0]];
    let a = [[0.3, -0.7, 1.1], [0.9, 0.4, -0.2], [-0.5, 0.8, 0.6]];
    let b = [[-0.6, 0.2, 0.5], [0.1, -0.9, 0.7], [0.4, 0.3, -0.8]];
    let f = |pos: &[[f32; 3]], vel: &[[f32; 3]]| -> f64 {
        let (p, v) = contain(
            points_tensor(pos, &device),
            points_tensor(vel, &device),
            &container,
            dt,
        );
        let (p, v) = (tensor_points(&p), tensor_points(&v));
        (0..3)
            .flat_map(|i| (0..3).map(move |k| (i, k)))
            .map(|(i, k)| f64::from(a[i][k] * p[i][k] + b[i][k] * v[i][k]))
            .sum()
    };
    let p = points_tensor(&pos, &device).require_grad();
    let v = points_tensor(&vel, &device).require_grad();
    let (pc, vc) = contain(p.clone(), v.clone(), &container, dt);
    let loss = (pc * points_tensor(&a, &device)).sum() + (vc * points_tensor(&b, &device)).sum();
    let grads = loss.backward();
    let gp = tensor_points(&p.grad(&grads).unwrap());
    let gv = tensor_points(&v.grad(&grads).unwrap());
    let h = 1e-2;
    for i in 0..3 {
        for k in 0..3 {
            for (x, g, name) in [(&pos, gp[i][k], "position"), (&vel, gv[i][k], "velocity")] {
                let (mut up, mut down) = (*x, *x);
                up[i][k] += h;
                down[i][k] -= h;
                let fd = if name == "position" {
                    (f(&up, &vel) - f(&down, &vel)) / (2.0 * f64::from(h))
                } else {
                    (f(&pos, &up) - f(&pos, &down)) / (2.0 * f64::from(h))
                };
                assert!(
                    (fd - f64::from(g)).abs() <= 1e-2 * (1.0 + fd.abs()),
                    "∂/∂{name}[{i}][{k}]: autodiff {g}, finite differences {fd}"
                );
            }
        }
    }
}

#[test]
fn a_pretrained_rollout_stays_in_a_box_whose_floor_its_box_particles_do_not_hold() {
    let device = device();
    let scene = Scene::load("cubedrop2197_dlfwall");
    // the fluid falls onto the box particles' floor; this container's floor is 0.15 m higher
    let mut container = Aabb {
        min: scene.box_lo,
        max: scene.box_hi,
    };
    container.min[1] += 0.15;
    let lowest = |r: &neurofluid_dlf::rollout::Rollout| {
        r.pos
            .iter()
            .flatten()
            .map(|p| p[1])
            .fold(f32::INFINITY, f32::min)
    };
    let open = pretrained(&device);
    let b = scene.boundary(&open, &device);
    let steps = 40;
    let free = rollout(&open, &scene.pos, &scene.vel, &b, steps, |_| {});
    assert!(
        lowest(&free) < container.min[1],
        "the open rollout must fall below the raised floor"
    );
    let walled = open.with_config(DlfConfig {
        container: Some(container),
        ..DlfConfig::default()
    });
    let r = rollout(&walled, &scene.pos, &scene.vel, &b, steps, |_| {});
    for (t, frame) in r.pos.iter().enumerate().skip(1) {
        for (i, &p) in frame.iter().enumerate() {
            assert!(container.contains(p), "step {t}: particle {i} at {p:?}");
            assert!(p.iter().all(|v| v.is_finite()));
        }
    }
}
