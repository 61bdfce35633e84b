//! `tensors::gather_rows` and `tensors::add_rows` against sums written out on the host: values
//! and gradients, with more rows than 65,535 (Mesa's lavapipe stops a shader loop after 65,535
//! iterations, which once lost the gradient of every later row on wgpu) and with repeated
//! indices. Runs on the device `NEUROFLUID_TEST_DEVICE` names.

use burn::prelude::*;
use burn::tensor::TensorData;
use neurofluid_core::device::test_device;
use neurofluid_core::tensors::{add_rows, gather_rows};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

const ROWS: usize = 70_000;
const N: usize = 50;
const C: usize = 3;

fn f32s(t: Tensor<2>) -> Vec<f32> {
    t.into_data()
        .convert::<f32>()
        .try_to_vec::<f32>()
        .expect("f32")
}

fn random(len: usize, rng: &mut ChaCha8Rng) -> Vec<f32> {
    (0..len).map(|_| rng.random_range(-1.0f32..1.0)).collect()
}

fn case() -> (Vec<i32>, Vec<f32>, Vec<f32>) {
    let mut rng = ChaCha8Rng::seed_from_u64(11);
    let idx = (0..ROWS).map(|_| rng.random_range(0..N as i32)).collect();
    (idx, random(N * C, &mut rng), random(ROWS * C, &mut rng))
}

/// `Σ_r coeff[r] at row idx[r]`, summed in f64.
fn rows_summed(idx: &[i32], coeff: &[f32]) -> Vec<f64> {
    let mut s = vec![0.0f64; N * C];
    for (r, &i) in idx.iter().enumerate() {
        for c in 0..C {
            s[i as usize * C + c] += f64::from(coeff[r * C + c]);
        }
    }
    s
}

fn assert_close(what: &str, got: &[f32], want: &[f64]) {
    assert_eq!(got.len(), want.len(), "{what}: length");
    for (j, (&g, &w)) in got.iter().zip(want).enumerate() {
        assert!(
            (f64::from(g) - w).abs() <= 1e-4 * (1.0 + w.abs()),
            "{what}[{j}]: {g} vs {w}"
        );
    }
}

#[test]
fn gathered_rows_and_their_gradient() {
    let (idx, table, coeff) = case();
    let device = test_device().autodiff();
    let t = Tensor::<2>::from_data(TensorData::new(table.clone(), [N, C]), &device).require_grad();
    let ids = Tensor::<1, Int>::from_data(TensorData::new(idx.clone(), [ROWS]), &device);
    let g = gather_rows(t.clone(), ids);
    let k = Tensor::<2>::from_data(TensorData::new(coeff.clone(), [ROWS, C]), &device);
    let grads = (g.clone() * k).sum().backward();
    let want: Vec<f64> = idx
        .iter()
        .flat_map(|&i| (0..C).map(move |c| i as usize * C + c))
        .map(|j| f64::from(table[j]))
        .collect();
    assert_close("gathered rows", &f32s(g), &want);
    let grad = f32s(t.grad(&grads).expect("gradient of the table"));
    assert_close("gradient", &grad, &rows_summed(&idx, &coeff));
}

#[test]
fn added_rows_and_their_gradient() {
    let (idx, base, values) = case();
    let device = test_device().autodiff();
    let b = Tensor::<2>::from_data(TensorData::new(base.clone(), [N, C]), &device);
    let v =
        Tensor::<2>::from_data(TensorData::new(values.clone(), [ROWS, C]), &device).require_grad();
    let ids = Tensor::<1, Int>::from_data(TensorData::new(idx.clone(), [ROWS]), &device);
    let out = add_rows(b, ids, v.clone());
    let mut want = rows_summed(&idx, &values);
    for (w, &b) in want.iter_mut().zip(&base) {
        *w += f64::from(b);
    }
    assert_close("added rows", &f32s(out.clone()), &want);
    // d Σ k⊙out / d values[r] = k[idx[r]]
    let mut rng = ChaCha8Rng::seed_from_u64(12);
    let k = random(N * C, &mut rng);
    let kt = Tensor::<2>::from_data(TensorData::new(k.clone(), [N, C]), &device);
    let grads = (out * kt).sum().backward();
    let grad = f32s(v.grad(&grads).expect("gradient of the values"));
    let want: Vec<f64> = idx
        .iter()
        .flat_map(|&i| (0..C).map(move |c| i as usize * C + c))
        .map(|j| f64::from(k[j]))
        .collect();
    assert_close("gradient", &grad, &want);
}
