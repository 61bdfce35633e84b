//! The physical scalars of a step as tensors (`neurofluid_dlf::physics`): given the rules'
//! own values, a two-step rollout is the rules' rollout; the gradients of a step's positions
//! and velocities with respect to the gravity scale, the viscosity and the dissipation match
//! central finite differences, on the stored falling cube with the published weights (one step,
//! with the differentiable geometry: the viscosity's pair weights are constants of a step, so a
//! second step would see the first's viscosity move them where autodiff does not), the
//! dissipation in the box's frame and in each body's.

use crate::common;

use burn::prelude::*;
use common::{CaseScene, Scene, device, pretrained};
use neurofluid_dlf::net::{points_tensor, tensor_points};
use neurofluid_dlf::{
    Boundary, DissipationFrame, DlfConfig, DlfNet, GeometryMode, PHYSICS_NAMES, PhysicsValues,
    StepRules,
};

/// Rules with every scalar away from the reference's, so each one acts.
fn rules() -> StepRules {
    StepRules {
        gravity_scale: 1.7,
        viscosity: 0.3,
        dissipation: 0.05,
        ..StepRules::default()
    }
}

/// Two steps from the scene's state; the positions and velocities reached.
fn two_steps(net: &DlfNet, scene: &Scene, b: &Boundary, device: &Device) -> (Tensor<2>, Tensor<2>) {
    let s1 = net.step(
        points_tensor(&scene.pos, device),
        points_tensor(&scene.vel, device),
        b,
    );
    let s2 = net.step(s1.pos, s1.vel, b);
    (s2.pos, s2.vel)
}

#[test]
fn the_rules_values_as_tensors_give_the_rules_step() {
    let device = device();
    let scene = Scene::load("cubedrop2197_dlfwall");
    let net =
        pretrained(&device).with_config(DlfConfig::default().with_rules(rules(), None).unwrap());
    let b = scene.boundary(&net, &device);
    let (p_rules, v_rules) = two_steps(&net, &scene, &b, &device);
    let values = PhysicsValues::of_rules(&rules(), &device);
    let back = values.into_rules(StepRules::default());
    for (a, b) in [
        (back.gravity_scale, 1.7),
        (back.viscosity, 0.3),
        (back.dissipation, 0.05),
    ] {
        assert!((a - b).abs() < 1e-6, "{back:?}");
    }
    let fitted = net.with_physics(Some(values));
    let (p_fit, v_fit) = two_steps(&fitted, &scene, &b, &device);
    for (a, b) in [(p_rules, p_fit), (v_rules, v_fit)] {
        let (a, b) = (tensor_points(&a), tensor_points(&b));
        let worst = a
            .iter()
            .flatten()
            .zip(b.iter().flatten())
            .map(|(x, y)| (x - y).abs() / (1.0 + x.abs()))
            .fold(0.0f32, f32::max);
        assert!(worst < 1e-5, "the steps differ by {worst}");
    }
}

#[test]
fn the_physics_gradients_match_finite_differences() {
    gradients_match_finite_differences(rules());
}

#[test]
fn the_physics_gradients_match_finite_differences_in_the_bodies_frame() {
    gradients_match_finite_differences(StepRules {
        dissipation_frame: DissipationFrame::Body,
        ..rules()
    });
}

/// The gradients of one step's positions and velocities with respect to each scalar under
/// `rules` against central finite differences.
fn gradients_match_finite_differences(rules: StepRules) {
    let device = device().autodiff();
    let mut scene = Scene::load("cubedrop2197_dlfwall");
    // velocities that vary over the cube, so that the viscosity has something to smooth
    let swirl: Vec<[f32; 3]> = scene
        .pos
        .iter()
        .map(|p| [(7.0 * p[1]).sin(), 0.0, 2.0 * p[0] - 1.0])
        .collect();
    for (v, s) in scene.vel.iter_mut().zip(&swirl) {
        v[0] += s[0];
        v[2] += s[2];
    }
    let config = DlfConfig {
        geometry: GeometryMode::Differentiable,
        ..DlfConfig::default()
    };
    let net = pretrained(&device).with_config(config.with_rules(rules, None).unwrap());
    let b = scene.boundary(&net, &device);
    let n = scene.pos.len();
    let one_step = |net: &DlfNet| {
        let s = net.step(
            points_tensor(&scene.pos, &device),
            points_tensor(&scene.vel, &device),
            &b,
        );
        (s.pos, s.vel)
    };
    // loss = 10 Σ a·x + Σ c·v: a fixed direction in the positions reached, and the swirl in
    // the velocities (which the viscosity smooths away)
    let a: Vec<[f32; 3]> = (0..n)
        .map(|i| {
            let s = ((i * 7) % 11) as f32 / 11.0 - 0.5;
            [s, 0.5 - s, 0.3 * s]
        })
        .collect();
    let c = swirl;
    let loss = |pos: Tensor<2>, vel: Tensor<2>| -> Tensor<1> {
        (pos * points_tensor(&a, &device)).sum() * 10.0 + (vel * points_tensor(&c, &device)).sum()
    };
    let at = |values: [f64; 3]| -> f64 {
        let rules = StepRules {
            gravity_scale: values[0],
            viscosity: values[1],
            dissipation: values[2],
            ..rules
        };
        let physics = PhysicsValues::of_rules(&rules, &device);
        let (p, v) = one_step(&net.clone().with_physics(Some(physics)));
        // summed in f64: the differences are small against the sum
        let dot = |x: &[[f32; 3]], w: &[[f32; 3]]| -> f64 {
            x.iter()
                .flatten()
                .zip(w.iter().flatten())
                .map(|(x, w)| f64::from(*x) * f64::from(*w))
                .sum()
        };
        10.0 * dot(&tensor_points(&p), &a) + dot(&tensor_points(&v), &c)
    };
    let base = rules;
    let values = PhysicsValues::of_rules(&base, &device);
    let values = PhysicsValues {
        gravity_scale: values.gravity_scale.require_grad(),
        viscosity: values.viscosity.require_grad(),
        dissipation: values.dissipation.require_grad(),
    };
    let (p, v) = one_step(&net.clone().with_physics(Some(values.clone())));
    let grads = loss(p, v).backward();
    let grad = |t: &Tensor<1>| t.grad(&grads).unwrap().into_scalar::<f64>();
    let autodiff = [
        grad(&values.gravity_scale),
        grad(&values.viscosity),
        grad(&values.dissipation),
    ];
    let x0 = [base.gravity_scale, base.viscosity, base.dissipation];
    for k in 0..3 {
        let h = 1e-2;
        let (mut up, mut down) = (x0, x0);
        up[k] += h;
        down[k] -= h;
        let fd = (at(up) - at(down)) / (2.0 * h);
        eprintln!(
            "∂loss/∂{}: autodiff {}, finite differences {fd}",
            PHYSICS_NAMES[k], autodiff[k]
        );
        assert!(
            (fd - autodiff[k]).abs() <= 5e-3 * fd.abs().max(1e-3),
            "∂loss/∂{}: autodiff {}, finite differences {fd}",
            PHYSICS_NAMES[k],
            autodiff[k]
        );
        assert!(
            fd.abs() > 1e-3,
            "∂loss/∂{} is {fd}: the test cannot tell",
            PHYSICS_NAMES[k]
        );
    }
}
