//! The host positional encoding (`neurofluid_core::posenc::posenc`: one operation with its own
//! backward pass on flex) against the same encoding built from Burn's ops and Burn's gradient
//! (f64 where the device has it, f32 too), and the gradient against central finite
//! differences; sizes that cross the row split, inputs large enough for the high frequencies
//! to wrap many times.

use burn::prelude::*;
use burn::tensor::{DType, TensorCreationOptions, TensorData};
use neurofluid_core::device::{test_device, test_device_name};
use neurofluid_core::posenc::{Block, posenc, posenc_cat, posenc_composed, try_host_posenc};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

fn tensor(v: &[f64], shape: [usize; 2], dtype: DType, device: &Device) -> Tensor<2> {
    Tensor::from_data(
        TensorData::new(v.to_vec(), shape),
        TensorCreationOptions::new(device.clone()).with_dtype(dtype),
    )
}

fn f64s(t: Tensor<2>) -> Vec<f64> {
    t.into_data()
        .convert::<f64>()
        .try_to_vec::<f64>()
        .expect("f64 values")
}

/// Output and input gradient of `Σ coeff ⊙ γ(v)` by the host or the composed path.
fn run(
    v: &[f64],
    coeff: &[f64],
    c: usize,
    freqs: usize,
    dtype: DType,
    host: bool,
) -> [Vec<f64>; 2] {
    let ad = test_device().autodiff();
    let rows = v.len() / c;
    let x = tensor(v, [rows, c], dtype, &ad).require_grad();
    let out = if host {
        posenc(x.clone(), freqs)
    } else {
        posenc_composed(vec![(x.clone(), freqs)])
    };
    let width = c * (1 + 2 * freqs);
    let loss = (out.clone() * tensor(coeff, [rows, width], dtype, &ad)).sum();
    let grads = loss.backward();
    [f64s(out), f64s(x.grad(&grads).expect("gradient of v"))]
}

fn random(n: usize, scale: f64, rng: &mut ChaCha8Rng) -> Vec<f64> {
    (0..n).map(|_| rng.random_range(-scale..scale)).collect()
}

/// f32, and f64 where the test device computes it correctly.
fn dtypes() -> Vec<DType> {
    let mut dtypes = vec![DType::F32];
    if neurofluid_core::device::test_device_has_float64() {
        dtypes.push(DType::F64);
    }
    dtypes
}

fn max_abs_diff(a: &[f64], b: &[f64]) -> f64 {
    assert_eq!(a.len(), b.len());
    a.iter().zip(b).fold(0.0, |m, (x, y)| m.max((x - y).abs()))
}

#[test]
fn host_encoding_matches_burns_ops_and_gradient() {
    let dtypes = dtypes();
    let mut rng = ChaCha8Rng::seed_from_u64(5);
    // (rows, channels, frequencies): one row, a row split's edge, several tasks
    for (rows, c, freqs) in [(1, 3, 10), (512, 1, 4), (1300, 3, 6), (700, 2, 0)] {
        let v = random(rows * c, 2.0, &mut rng);
        let coeff = random(rows * c * (1 + 2 * freqs), 1.0, &mut rng);
        for &dtype in &dtypes {
            let host = run(&v, &coeff, c, freqs, dtype, true);
            let composed = run(&v, &coeff, c, freqs, dtype, false);
            // the same sines and cosines; the gradient's terms summed in another order
            let tol = if dtype == DType::F64 { 1e-12 } else { 2e-4 };
            assert_eq!(host[0], composed[0], "{rows}×{c}, L = {freqs}: output");
            let e = max_abs_diff(&host[1], &composed[1]);
            assert!(
                e < tol,
                "{rows}×{c}, L = {freqs}, {dtype:?}: gradient differs by {e:.2e}"
            );
        }
    }
}

#[test]
fn host_gradient_matches_finite_differences() {
    let device = test_device();
    if !neurofluid_core::device::test_device_has_float64() {
        return;
    }
    let mut rng = ChaCha8Rng::seed_from_u64(6);
    let (rows, c, freqs) = (40, 3, 5);
    let v = random(rows * c, 1.5, &mut rng);
    let coeff = random(rows * c * (1 + 2 * freqs), 1.0, &mut rng);
    let [_, grad] = run(&v, &coeff, c, freqs, DType::F64, true);
    let loss = |v: &[f64]| -> f64 {
        let out = f64s(posenc(tensor(v, [rows, c], DType::F64, &device), freqs));
        out.iter().zip(&coeff).map(|(o, k)| o * k).sum()
    };
    let h = 1e-6;
    for i in (0..v.len()).step_by(7) {
        let (mut up, mut down) = (v.clone(), v.clone());
        up[i] += h;
        down[i] -= h;
        let fd = (loss(&up) - loss(&down)) / (2.0 * h);
        assert!(
            (fd - grad[i]).abs() < 1e-6 * (1.0 + fd.abs()),
            "v[{i}]: analytic {} vs finite difference {fd}",
            grad[i]
        );
    }
}

/// On the CPU (flex, plain and with autodiff) the host operation is the one `posenc` takes.
#[test]
fn the_cpu_takes_the_host_path() {
    if test_device_name() != "cpu" {
        return;
    }
    let device = test_device();
    let blocks = [Block {
        channels: 3,
        freqs: 4,
    }];
    let v = tensor(&[0.1, 0.2, 0.3], [1, 3], DType::F32, &device);
    assert!(try_host_posenc(&v, &blocks).is_some());
    let ad = device.autodiff();
    let v = tensor(&[0.1, 0.2, 0.3], [1, 3], DType::F32, &ad).require_grad();
    assert!(try_host_posenc(&v, &blocks).is_some());
    // columns that do not match the blocks: no host operation (the caller's error)
    assert!(
        try_host_posenc(
            &v,
            &[Block {
                channels: 2,
                freqs: 4
            }]
        )
        .is_none()
    );
}

/// The encodings of several inputs written into one output (the network inputs e_x, e_d) equal
/// the concatenation of each input's encoding built from Burn's ops: the output, and the
/// gradient of every input.
#[test]
fn concatenated_encodings_match_burns_concatenation() {
    let dtypes = dtypes();
    let mut rng = ChaCha8Rng::seed_from_u64(7);
    // (channels, frequencies) of e_x's blocks: x, σ_p, p_c, v_d with a frequency-less block
    let blocks = [(3, 10), (1, 4), (3, 0), (3, 6)];
    let rows = 1100;
    let width: usize = blocks.iter().map(|&(c, l)| c * (1 + 2 * l)).sum();
    let inputs: Vec<Vec<f64>> = blocks
        .iter()
        .map(|&(c, _)| random(rows * c, 2.0, &mut rng))
        .collect();
    let coeff = random(rows * width, 1.0, &mut rng);
    for dtype in dtypes {
        let run = |host: bool| {
            let ad = test_device().autodiff();
            let xs: Vec<Tensor<2>> = inputs
                .iter()
                .zip(&blocks)
                .map(|(v, &(c, _))| tensor(v, [rows, c], dtype, &ad).require_grad())
                .collect();
            let out = if host {
                posenc_cat(xs.iter().cloned().zip(blocks.map(|b| b.1)).collect())
            } else {
                posenc_composed(xs.iter().cloned().zip(blocks.map(|b| b.1)).collect())
            };
            let loss = (out.clone() * tensor(&coeff, [rows, width], dtype, &ad)).sum();
            let grads = loss.backward();
            let mut values = vec![f64s(out)];
            values.extend(xs.iter().map(|x| f64s(x.grad(&grads).expect("a gradient"))));
            values
        };
        let (host, composed) = (run(true), run(false));
        assert_eq!(host[0], composed[0], "{dtype:?}: output");
        let tol = if dtype == DType::F64 { 1e-12 } else { 2e-4 };
        for (i, (a, b)) in host[1..].iter().zip(&composed[1..]).enumerate() {
            let e = max_abs_diff(a, b);
            assert!(
                e < tol,
                "{dtype:?}: gradient of input {i} differs by {e:.2e}"
            );
        }
    }
}

/// Off the host path each input's encoding is one broadcast expression over constants (scales,
/// slot selectors) uploaded once per device, precision and L: a second encoding copies nothing,
/// with or without autodiff.
#[test]
fn the_composed_encodings_constants_are_uploaded_once() {
    use neurofluid_core::transfer::counts;
    for device in [test_device(), test_device().autodiff()] {
        let v = tensor(&[0.1, -0.2, 0.3, 0.4], [2, 2], DType::F32, &device);
        let encode = || posenc_composed(vec![(v.clone(), 7), (v.clone(), 0), (v.clone(), 3)]);
        let first = encode();
        let before = counts();
        let again = encode();
        let copies = counts().since(before);
        assert_eq!(copies.uploads, 0, "{device:?}: {}", copies.describe());
        assert_eq!(copies.reads, 0, "{device:?}: {}", copies.describe());
        assert_eq!(f64s(first), f64s(again));
    }
}

/// The composed encoding on the test device against the host formula (`posenc::forward`, the
/// standard library's sine and cosine): the same bits on the CPU, within f32 sine accuracy on
/// a GPU, for inputs whose highest frequency wraps many times, with a block without frequencies.
#[test]
fn the_composed_encoding_is_the_host_formula() {
    use neurofluid_core::posenc::forward;
    let mut rng = ChaCha8Rng::seed_from_u64(8);
    let blocks = [(3, 10), (1, 4), (2, 0)];
    let rows = 300;
    let inputs: Vec<Vec<f32>> = blocks
        .iter()
        .map(|&(c, _)| {
            random(rows * c, 2.0, &mut rng)
                .iter()
                .map(|&v| v as f32)
                .collect()
        })
        .collect();
    let device = test_device();
    let out = posenc_composed(
        inputs
            .iter()
            .zip(&blocks)
            .map(|(v, &(c, l))| {
                let v64: Vec<f64> = v.iter().map(|&x| f64::from(x)).collect();
                (tensor(&v64, [rows, c], DType::F32, &device), l)
            })
            .collect(),
    );
    // the host formula on the inputs side by side, row by row
    let side_by_side: Vec<f32> = (0..rows)
        .flat_map(|r| {
            inputs
                .iter()
                .zip(&blocks)
                .flat_map(move |(v, &(c, _))| v[r * c..(r + 1) * c].to_vec())
        })
        .collect();
    let host_blocks = blocks.map(|(channels, freqs)| Block { channels, freqs });
    let want: Vec<f64> = forward(&side_by_side, &host_blocks)
        .into_iter()
        .map(f64::from)
        .collect();
    let got = f64s(out);
    let tol = if test_device_name() == "cpu" {
        0.0
    } else {
        1e-5
    };
    let e = max_abs_diff(&got, &want);
    assert!(e <= tol, "differs from the host formula by {e:.2e}");
}
