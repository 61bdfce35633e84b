//! Matmuls with 16-bit operands (`neurofluid_core::half_matmul`) against products and gradients
//! computed in float64 on the host: within the 16-bit type's rounding bound, for operands and
//! output gradients far below f16's smallest normal number and far above its largest, where
//! casting without the scaling loses them; and the dense layer on an accelerator's path with
//! 16-bit operands against the f32 path.

use burn::module::Param;
use burn::nn::Linear;
use burn::prelude::*;
use burn::tensor::{DType, TensorData};
use neurofluid_core::choice::Choice;
use neurofluid_core::dense::{Activation, linear_in_row_blocks};
use neurofluid_core::device::test_device;
use neurofluid_core::half_matmul::{MatmulOperands, half_matmul, scaled_half_matmul};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// The 16-bit operand types the test device has (WGSL, lavapipe's, has no bf16).
fn halves() -> Vec<MatmulOperands> {
    let device = test_device();
    [MatmulOperands::F16, MatmulOperands::Bf16]
        .into_iter()
        .filter(|m| device.supports_dtype(m.half().expect("a 16-bit type")))
        .collect()
}

fn random(n: usize, scale: f64, rng: &mut ChaCha8Rng) -> Vec<f64> {
    (0..n)
        .map(|_| scale * rng.random_range(-1.0..1.0))
        .collect()
}

fn tensor<const D: usize>(v: &[f64], shape: [usize; D], device: &Device) -> Tensor<D> {
    let v: Vec<f32> = v.iter().map(|&x| x as f32).collect();
    Tensor::from_data(TensorData::new(v, shape), device)
}

fn values<const D: usize>(t: Tensor<D>) -> Vec<f64> {
    t.into_data()
        .convert::<f64>()
        .try_to_vec::<f64>()
        .expect("f64 values")
}

/// `a [m, k]·b [k, n]` in float64, and `Σ_k |a||b|` for each entry (the rounding bound's scale).
fn product(a: &[f64], b: &[f64], m: usize, k: usize, n: usize) -> (Vec<f64>, Vec<f64>) {
    let mut c = vec![0.0; m * n];
    let mut s = vec![0.0; m * n];
    for i in 0..m {
        for j in 0..n {
            for l in 0..k {
                c[i * n + j] += a[i * k + l] * b[l * n + j];
                s[i * n + j] += (a[i * k + l] * b[l * n + j]).abs();
            }
        }
    }
    (c, s)
}

fn transpose(a: &[f64], rows: usize, cols: usize) -> Vec<f64> {
    (0..cols * rows)
        .map(|i| a[(i % rows) * cols + i / rows])
        .collect()
}

/// Every entry within `3u·Σ|a||b|` of float64's (u the 16-bit type's unit roundoff: each
/// operand and the output rounded once), with a floor of a millionth of the largest such scale.
fn assert_within(got: &[f64], want: &[f64], scale: &[f64], u: f64, what: &str) {
    assert_eq!(got.len(), want.len(), "{what}: size");
    let floor = 1e-6 * scale.iter().copied().fold(0.0, f64::max);
    for (i, ((g, w), s)) in got.iter().zip(want).zip(scale).enumerate() {
        let bound = 3.0 * u * s + floor;
        assert!(
            (g - w).abs() <= bound,
            "{what}: entry {i} is {g:e}, float64 gives {w:e} (bound {bound:.2e})"
        );
    }
}

#[test]
fn scaled_products_hold_the_rounding_bound_far_outside_f16s_range() {
    let device = test_device();
    let (m, k, n) = (23, 70, 9);
    let mut rng = ChaCha8Rng::seed_from_u64(3);
    println!("16-bit operand types of the test device: {:?}", halves());
    for (scale_a, scale_b) in [(1.0, 1.0), (1e-7, 3e-6), (2e4, 5e3), (1e-9, 4e3)] {
        let a = random(2 * m * k, scale_a, &mut rng);
        let b = random(k * n, scale_b, &mut rng);
        let mut want = Vec::new();
        let mut scale = Vec::new();
        for half in a.chunks(m * k) {
            let (c, s) = product(half, &b, m, k, n);
            want.extend(c);
            scale.extend(s);
        }
        for operands in halves() {
            let dtype = operands.half().expect("a 16-bit type");
            let got = scaled_half_matmul(
                tensor(&a, [2, m, k], &device),
                tensor(&b, [1, k, n], &device),
                dtype,
            );
            let what = format!("{operands:?}, operands ×{scale_a:e} and ×{scale_b:e}");
            assert_within(&values(got), &want, &scale, operands.unit_roundoff(), &what);
        }
        if !(1e-6..=1e4).contains(&scale_a) {
            // the test's power: f16 operands cast as they are lose these products
            let a16 = tensor(&a, [2, m, k], &device).cast(DType::F16);
            let b16 = tensor(&b, [1, k, n], &device).cast(DType::F16);
            let naive = values(a16.matmul(b16).cast(DType::F32));
            let off = naive
                .iter()
                .zip(&want)
                .zip(&scale)
                .any(|((g, w), s)| !g.is_finite() || (g - w).abs() > 3.0 * 2f64.powi(-11) * s);
            assert!(
                off,
                "unscaled f16 products ×{scale_a:e} are within the bound"
            );
        }
    }
}

/// `z = x·w` through [`half_matmul`] with `x [B, m, k]` and `w [k, n]` tracked, the loss
/// `Σ z ⊙ c` with `c` tiny (as a PhysNeRF step's output gradients): z, dx and dw against float64.
#[test]
fn gradients_hold_the_rounding_bound_with_tiny_output_gradients() {
    let device = test_device().autodiff();
    let (b, m, k, n) = (3, 31, 17, 12);
    let mut rng = ChaCha8Rng::seed_from_u64(7);
    let x = random(b * m * k, 2.0, &mut rng);
    let w = random(k * n, 0.3, &mut rng);
    let c = random(b * m * n, 1e-8, &mut rng);
    for operands in halves() {
        let half = operands.half().expect("a 16-bit type");
        for tracked in [[true, true], [true, false], [false, true]] {
            let track = |t: Tensor<3>, on| if on { t.require_grad() } else { t };
            let xt = track(tensor(&x, [b, m, k], &device), tracked[0]);
            let wt = tensor(&w, [k, n], &device);
            let wt = if tracked[1] { wt.require_grad() } else { wt };
            let z = half_matmul(xt.clone(), wt.clone(), half);
            let grads = (z.clone() * tensor(&c, [b, m, n], &device))
                .sum()
                .backward();
            let u = operands.unit_roundoff();
            let what = format!("{operands:?}, tracked {tracked:?}");
            let wt_t = transpose(&w, k, n);
            let (mut z_want, mut z_scale) = (Vec::new(), Vec::new());
            let (mut dx_want, mut dx_scale) = (Vec::new(), Vec::new());
            let mut dw_want = vec![0.0; k * n];
            let mut dw_scale = vec![0.0; k * n];
            for (xb, cb) in x.chunks(m * k).zip(c.chunks(m * n)) {
                let (zz, zs) = product(xb, &w, m, k, n);
                z_want.extend(zz);
                z_scale.extend(zs);
                let (dx, ds) = product(cb, &wt_t, m, n, k);
                dx_want.extend(dx);
                dx_scale.extend(ds);
                let (dw, ws) = product(&transpose(xb, m, k), cb, k, m, n);
                for i in 0..k * n {
                    dw_want[i] += dw[i];
                    dw_scale[i] += ws[i];
                }
            }
            assert_within(&values(z), &z_want, &z_scale, u, &format!("{what}: z"));
            match xt.grad(&grads) {
                Some(g) => assert_within(&values(g), &dx_want, &dx_scale, u, &what),
                None => assert!(!tracked[0], "{what}: dx missing"),
            }
            match wt.grad(&grads) {
                Some(g) => assert_within(&values(g), &dw_want, &dw_scale, u, &what),
                None => assert!(!tracked[1], "{what}: dw missing"),
            }
        }
    }
}

/// The dense layer's accelerator path (rows in blocks, the last one padded) with 16-bit
/// operands against the same path with f32 operands: output and gradients within 16-bit
/// rounding of the largest magnitude each reaches.
#[test]
fn dense_layer_with_16_bit_operands_follows_the_f32_layer() {
    let device = test_device().autodiff();
    let (m, k, n) = (200, 24, 16);
    let mut rng = ChaCha8Rng::seed_from_u64(11);
    let x = random(m * k, 1.0, &mut rng);
    let w = random(k * n, 0.5, &mut rng);
    let bias = random(n, 0.1, &mut rng);
    let c = random(m * n, 1e-7, &mut rng);
    let run = |operands: MatmulOperands| {
        let xt = tensor(&x, [m, k], &device).require_grad();
        let layer = Linear {
            weight: Param::from_tensor(tensor(&w, [k, n], &device).require_grad()),
            bias: Some(Param::from_tensor(
                tensor(&bias, [n], &device).require_grad(),
            )),
        };
        let y = linear_in_row_blocks(&layer, xt.clone(), Activation::Relu, 64, operands);
        let grads = (y.clone() * tensor(&c, [m, n], &device)).sum().backward();
        let g = |t: Tensor<2>| values(t.grad(&grads).expect("a gradient"));
        let bias = layer.bias.as_ref().expect("a bias").val();
        [
            values(y),
            g(xt),
            g(layer.weight.val()),
            values(bias.grad(&grads).expect("a gradient")),
        ]
    };
    let want = run(MatmulOperands::F32);
    for operands in halves() {
        let got = run(operands);
        for (name, (g, w)) in ["y", "dx", "dw", "db"].iter().zip(got.iter().zip(&want)) {
            let largest = w.iter().fold(0.0f64, |a, v| a.max(v.abs()));
            let e = g
                .iter()
                .zip(w)
                .fold(0.0f64, |a, (g, w)| a.max((g - w).abs()));
            // the ReLU's kink may switch an entry whose pre-activation is within rounding of 0
            assert!(
                e <= 20.0 * operands.unit_roundoff() * largest.max(1e-30) * (k as f64).sqrt(),
                "{operands:?} {name}: off by {e:.2e} of {largest:.2e}"
            );
        }
    }
}

#[test]
fn operand_names_round_trip_and_a_wrong_one_is_named() {
    for m in [
        MatmulOperands::F32,
        MatmulOperands::F16,
        MatmulOperands::Bf16,
    ] {
        assert_eq!(MatmulOperands::parse(m.name()), Ok(m));
    }
    let e = MatmulOperands::parse("fp16").unwrap_err();
    assert!(
        e.contains("f32, f16 or bf16") && e.contains("`fp16`"),
        "{e}"
    );
}

/// On wgpu the driver's tensor-core shapes can be listed (lavapipe lists none); off it, `None`
/// where wgpu is not compiled in.
#[test]
fn tensor_core_shapes_are_listed_where_wgpu_is_compiled_in() {
    use neurofluid_core::device::{is_wgpu_name, test_device_name, wgpu_tensor_core_shapes};
    let shapes = wgpu_tensor_core_shapes();
    assert_eq!(shapes.is_some(), cfg!(feature = "wgpu-base"));
    if is_wgpu_name(&test_device_name()) {
        let shapes = shapes.expect("wgpu compiled in");
        println!("tensor-core shapes: {shapes:?}");
        assert!(shapes.iter().all(|s| s.contains('×') && s.contains('→')));
    }
}
