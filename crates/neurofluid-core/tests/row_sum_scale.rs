//! The gather's gradient (the fixed-order sum planned on the host) at a DLF step's scale.

use burn::prelude::*;
use neurofluid_core::device::test_device;
use neurofluid_core::rows::{RowIndex, gather_rows};
use neurofluid_core::transfer::{read_vec, upload};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

#[test]
fn the_planned_sum_at_a_dlf_steps_scale() {
    planned_sum(8000, 170_000, 96);
}

#[test]
fn the_planned_sum_of_the_kernel_first_convs_rows() {
    planned_sum(8000, 170_000, 192);
}

fn planned_sum(n: usize, l: usize, c: usize) {
    let mut rng = ChaCha8Rng::seed_from_u64(5);
    let ids: Vec<usize> = (0..l).map(|_| rng.random_range(0..n)).collect();
    let w: Vec<f32> = (0..l * c).map(|_| rng.random_range(-1.0..1.0)).collect();
    let device = test_device().autodiff();
    let f = Tensor::<2>::zeros([n, c], &device).require_grad();
    let idx = RowIndex::new(ids.iter().copied(), &device);
    let wt = upload::<2, burn::tensor::Float, _>(TensorData::new(w.clone(), [l, c]), &device);
    let loss = (gather_rows(f.clone(), &idx) * wt).sum();
    let grads = loss.backward();
    let got = read_vec::<f32, 2, burn::tensor::Float>(f.grad(&grads).unwrap()).unwrap();
    let mut want = vec![0f64; n * c];
    for (r, &i) in ids.iter().enumerate() {
        for k in 0..c {
            want[i * c + k] += w[r * c + k] as f64;
        }
    }
    let worst = got
        .iter()
        .zip(&want)
        .map(|(a, b)| (*a as f64 - b).abs())
        .fold(0f64, f64::max);
    assert!(worst < 1e-4, "largest difference {worst}");
}
