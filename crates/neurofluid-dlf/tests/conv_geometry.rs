//! The continuous convolution against a brute-force evaluation of its definition, the two
//! evaluation paths (host inference, autodiff gather/scatter) against each other, the
//! differentiable geometry against finite differences (f64), and the frame rotation.

use crate::common;

use burn::prelude::*;
use burn::tensor::{DType, Distribution};
use common::*;
use neurofluid_dlf::diff_geometry::differentiable_weights;
use neurofluid_dlf::geometry::{ConvGeometry, build_host_geometry};
use neurofluid_dlf::mapping::{filter_coordinates, trilinear_corners, window_poly6};
use neurofluid_dlf::{ContinuousConv, DlfConfig, FILTER_EXTENT, Frame, GeometryMode};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

fn cloud(n: usize, side: f32, seed: u64) -> Vec<[f32; 3]> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    (0..n)
        .map(|_| std::array::from_fn(|_| rng.random_range(0.0..side)))
        .collect()
}

/// out[m] = bias + Σ_{i: |x_i − x_m|² ≤ R², x_i ≠ x_m} window · Σ_c w_c f_i K[cell_c], all pairs.
fn brute_force(
    inputs: &[[f32; 3]],
    outputs: &[[f32; 3]],
    feats: &[f32],
    kernel: &[f32],
    bias: &[f32],
    cin: usize,
    cout: usize,
) -> Vec<f64> {
    let r = 0.5 * FILTER_EXTENT;
    let r2 = r * r;
    let mut out = vec![0f64; outputs.len() * cout];
    for (m, q) in outputs.iter().enumerate() {
        for o in 0..cout {
            out[m * cout + o] = bias[o] as f64;
        }
        for (i, x) in inputs.iter().enumerate() {
            if x == q {
                continue;
            }
            let d = [x[0] - q[0], x[1] - q[1], x[2] - q[2]];
            let d2 = d[0] * d[0] + d[1] * d[1] + d[2] * d[2];
            if d2 > r2 {
                continue;
            }
            let (u, _) = filter_coordinates(d, 2.0 * (1.0 / FILTER_EXTENT));
            let win = window_poly6(d2 / r2) as f64;
            for (cell, w) in trilinear_corners(u) {
                // kernel [z, y, x, cin, cout] flattened: cell = (z·4 + y)·4 + x
                for c in 0..cin {
                    let f = feats[i * cin + c] as f64 * w as f64 * win;
                    for o in 0..cout {
                        out[m * cout + o] +=
                            f * kernel[(cell as usize * cin + c) * cout + o] as f64;
                    }
                }
            }
        }
    }
    out
}

fn check_conv(cin: usize, cout: usize, same_cloud: bool) {
    let device = device();
    let outputs = cloud(300, 0.35, 1);
    let inputs = if same_cloud {
        outputs.clone()
    } else {
        cloud(400, 0.35, 2)
    };
    let conv = ContinuousConv::new(cin, cout, &device);
    let conv = ContinuousConv {
        bias: burn::module::Param::from_tensor(Tensor::random(
            [cout],
            Distribution::Normal(0.0, 1.0),
            &device,
        )),
        ..conv
    };
    let feats = Tensor::<2>::random([inputs.len(), cin], Distribution::Normal(0.0, 1.0), &device);
    let hg = build_host_geometry(&inputs, &outputs, FILTER_EXTENT, true, None);
    assert!(hg.num_pairs() > 1000, "{} pairs", hg.num_pairs());
    let geo = ConvGeometry::new(hg, None, &device);
    let expected = brute_force(
        &inputs,
        &outputs,
        &host_vec(&feats),
        &host1(&conv.kernel.val().reshape([16 * 4 * cin, cout])),
        &host1(&conv.bias.val().unsqueeze_dim::<2>(0)),
        cin,
        cout,
    );
    let expected: Vec<f32> = expected.iter().map(|&v| v as f32).collect();
    // inference (host) path
    let fast = host(&conv.forward(feats.clone(), &geo));
    let e = rel_err(&fast, &expected);
    assert!(e < 2e-6, "host path vs brute force: {e:.2e}");
    // autodiff (gather/scatter) path
    let ad = device.clone().autodiff();
    let conv_ad = ContinuousConv {
        kernel: burn::module::Param::from_tensor(conv.kernel.val().to_device(&ad)),
        bias: burn::module::Param::from_tensor(conv.bias.val().to_device(&ad)),
    };
    let geo_ad = ConvGeometry::new(geo.host.clone().expect("a host geometry"), None, &ad);
    let slow = host(&conv_ad.forward(feats.to_device(&ad), &geo_ad));
    let e = rel_err(&slow, &expected);
    assert!(e < 2e-6, "autodiff path vs brute force: {e:.2e}");
}

fn host_vec(t: &Tensor<2>) -> Vec<f32> {
    host(t)
}

fn host1(t: &Tensor<2>) -> Vec<f32> {
    host(t)
}

fn f64s(t: Tensor<2>) -> Vec<f64> {
    t.to_data().convert::<f64>().try_into_vec::<f64>().unwrap()
}

#[test]
fn conv_matches_brute_force_gather_first() {
    check_conv(4, 32, true);
    check_conv(3, 32, false);
}

#[test]
fn conv_matches_brute_force_kernel_first() {
    check_conv(16, 8, true);
    check_conv(8, 3, false);
}

/// The differentiable weights equal the host weights and their position gradient agrees with
/// central finite differences (float64 where the backend has it).
#[test]
fn differentiable_geometry_matches_finite_differences() {
    let base = device();
    let dtype = if neurofluid_core::device::test_device_has_float64() {
        DType::F64
    } else {
        DType::F32
    };
    let ad = base.clone().autodiff();
    let inputs = cloud(60, 0.2, 3);
    let outputs = cloud(40, 0.2, 4);
    let host_geo = build_host_geometry(&inputs, &outputs, FILTER_EXTENT, true, None);
    let p = host_geo.num_pairs();
    assert!(p > 200, "{p} pairs");
    let to = |pts: &[[f32; 3]], d: &Device| to_tensor(pts, d).cast(dtype);
    // values
    let w = differentiable_weights(
        &host_geo,
        to(&inputs, &base),
        to(&outputs, &base),
        FILTER_EXTENT,
    )
    .expect("the cloud has pairs");
    let e = rel_err(&host(&w), &host_geo.weights);
    assert!(e < 1e-5, "differentiable weights vs host weights: {e:.2e}");
    // gradient of Σ r ⊙ w with respect to both point sets
    let coeff: Vec<f32> = {
        let mut rng = ChaCha8Rng::seed_from_u64(5);
        (0..p * 8).map(|_| rng.random_range(-1.0..1.0)).collect()
    };
    let r = |d: &Device| {
        Tensor::<2>::from_data(TensorData::new(coeff.clone(), [p * 8, 1]), d).cast(dtype)
    };
    let xin = to(&inputs, &ad).require_grad();
    let xout = to(&outputs, &ad).require_grad();
    let loss = (differentiable_weights(&host_geo, xin.clone(), xout.clone(), FILTER_EXTENT)
        .expect("the cloud has pairs")
        * r(&ad))
    .sum();
    let grads = loss.backward();
    let g_in: Vec<f64> = f64s(xin.grad(&grads).unwrap());
    let g_out: Vec<f64> = f64s(xout.grad(&grads).unwrap());
    let eval = |xi: Tensor<2>, xo: Tensor<2>| -> f64 {
        (differentiable_weights(&host_geo, xi, xo, FILTER_EXTENT).expect("the cloud has pairs")
            * r(&base))
        .sum()
        .cast(DType::F64)
        .into_scalar::<f64>()
    };
    let h = if dtype == DType::F64 { 1e-6 } else { 1e-3 };
    let base_in: Vec<f64> = f64s(to(&inputs, &base));
    let base_out: Vec<f64> = f64s(to(&outputs, &base));
    // from_data converts to the default float dtype unless told otherwise
    let tensor64 = |v: Vec<f64>, n: usize| {
        Tensor::<2>::from_data(
            TensorData::new(v, [n, 3]),
            burn::tensor::TensorCreationOptions::new(base.clone()).with_dtype(dtype),
        )
    };
    let mut worst = 0f64;
    let scale = g_in.iter().chain(&g_out).fold(0f64, |m, v| m.max(v.abs()));
    for (which, k) in [(0, 0), (0, 7), (0, 31), (0, 100), (1, 2), (1, 50), (1, 99)] {
        let (x, n, analytic) = if which == 0 {
            (&base_in, inputs.len(), g_in[k])
        } else {
            (&base_out, outputs.len(), g_out[k])
        };
        let mut plus = x.clone();
        plus[k] += h;
        let mut minus = x.clone();
        minus[k] -= h;
        let (fp, fm) = if which == 0 {
            (
                eval(tensor64(plus, n), tensor64(base_out.clone(), outputs.len())),
                eval(
                    tensor64(minus, n),
                    tensor64(base_out.clone(), outputs.len()),
                ),
            )
        } else {
            (
                eval(tensor64(base_in.clone(), inputs.len()), tensor64(plus, n)),
                eval(tensor64(base_in.clone(), inputs.len()), tensor64(minus, n)),
            )
        };
        let fd = (fp - fm) / (2.0 * h);
        worst = worst.max((fd - analytic).abs() / scale);
    }
    let tol = if dtype == DType::F64 { 1e-6 } else { 2e-2 };
    assert!(
        worst < tol,
        "finite differences vs autodiff: {worst:.2e} (dtype {dtype:?})"
    );
    assert!(scale > 0.0);
}

/// With the differentiable geometry the step's values are unchanged and positions get gradients.
#[test]
fn differentiable_geometry_mode_keeps_values_and_gives_position_gradients() {
    let ad = device().autodiff();
    let scene = Scene::load("cubedrop2197_dlfwall");
    let net = pretrained(&ad);
    let net_diff = pretrained(&ad).with_config(DlfConfig {
        geometry: GeometryMode::Differentiable,
        ..DlfConfig::default()
    });
    let boundary = scene.boundary(&net, &ad);
    let pos = to_tensor(&scene.pos[..400], &ad).require_grad();
    let vel = to_tensor(&scene.vel[..400], &ad);
    let (_, a) = net.step_traced(pos.clone(), vel.clone(), &boundary);
    let (_, b) = net_diff.step_traced(pos.clone(), vel, &boundary);
    let e = rel_err(&host(&b.raw_output), &host(&a.raw_output));
    assert!(e < 1e-5, "raw output differs: {e:.2e}");
    let ga = a.raw_output.sum().backward();
    let gb = b.raw_output.sum().backward();
    // Constant geometry: d(raw)/d(pos) is zero (positions only enter through the geometry).
    assert!(
        pos.grad(&ga)
            .is_none_or(|g| g.abs().max().into_scalar::<f32>() == 0.0)
    );
    let g = pos.grad(&gb).expect("position gradient");
    assert!(g.abs().max().into_scalar::<f32>() > 0.0);
}

/// Running a y-up scene rotated into a z-up frame with `Frame::ZUp` gives the rotated result.
#[test]
fn z_up_frame_reproduces_the_y_up_result() {
    let device = device();
    let scene = Scene::load("cubedrop2197_dlfwall");
    let net = pretrained(&device);
    let zup = pretrained(&device).with_config(DlfConfig::z_up());
    // scene (y-up) → z-up: (x, y, z) ↦ (x, −z, y), the inverse of Frame::ZUp's model mapping.
    let f = Frame::ZUp;
    let rot = |p: &[[f32; 3]]| -> Vec<[f32; 3]> { p.iter().map(|&v| f.to_scene(v)).collect() };
    let b_y = scene.boundary(&net, &device);
    let b_z = zup.boundary(&rot(&scene.box_points), &rot(&scene.box_normals), &device);
    let a = net.step(
        to_tensor(&scene.pos, &device),
        to_tensor(&scene.vel, &device),
        &b_y,
    );
    let b = zup.step(
        to_tensor(&rot(&scene.pos), &device),
        to_tensor(&rot(&scene.vel), &device),
        &b_z,
    );
    let expected: Vec<f32> = rot(&neurofluid_dlf::net::tensor_points(&a.pos))
        .into_iter()
        .flatten()
        .collect();
    let e = rel_err(&host(&b.pos), &expected);
    assert!(e < 1e-6, "z-up position differs: {e:.2e}");
    assert_eq!(a.num_fluid_neighbors, b.num_fluid_neighbors);
}
