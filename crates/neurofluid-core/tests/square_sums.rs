//! `square_sums::square_sums` on the test device against float64 sums of the same values: one
//! value per input tensor in order, the same bits on every repetition, no read or upload of its
//! own, and on a CPU backend the bits of `sum_all` of each square (the path it replaces).

use burn::prelude::*;
use burn::tensor::{DType, TensorCreationOptions, TensorData};
use neurofluid_core::device::test_device;
use neurofluid_core::square_sums::{MOST_PER_GROUP, count, square_sums};
use neurofluid_core::tensors::sum_all;
use neurofluid_core::transfer::{self, read_together};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// Lengths around the workgroup's 256 units, a DLF conv kernel's 393,216 and more tensors than
/// one kernel binds anywhere (so the groups' boundaries are crossed).
fn lengths() -> Vec<usize> {
    let mut v = vec![1, 3, 255, 256, 257, 511, 65_536, 65_537, 393_216];
    let mut rng = ChaCha8Rng::seed_from_u64(7);
    while v.len() < MOST_PER_GROUP + 9 {
        v.push(rng.random_range(1..5_000));
    }
    v
}

fn inputs(device: &Device) -> (Vec<Vec<f32>>, Vec<Tensor<1>>) {
    let mut rng = ChaCha8Rng::seed_from_u64(3);
    let values: Vec<Vec<f32>> = lengths()
        .into_iter()
        .enumerate()
        // magnitudes from 10⁻⁴ to 10³: a step's gradients differ by orders between parameters
        .map(|(i, n)| {
            let scale = 10f32.powi(i as i32 % 8 - 4);
            (0..n).map(|_| rng.random_range(-scale..scale)).collect()
        })
        .collect();
    let tensors = values
        .iter()
        .map(|v| {
            Tensor::from_data(
                TensorData::new(v.clone(), [v.len()]),
                TensorCreationOptions::new(device.clone()).with_dtype(DType::F32),
            )
        })
        .collect();
    (values, tensors)
}

#[test]
fn one_sum_per_tensor_within_f32_rounding_and_the_same_bits_each_time() {
    let device = test_device();
    let (values, tensors) = inputs(&device);
    let before = transfer::counts();
    let sums = square_sums(tensors.clone());
    let during = transfer::counts();
    assert_eq!(during.reads, before.reads, "no read of its own");
    assert_eq!(during.uploads, before.uploads, "no upload of its own");
    assert_eq!(count(&sums), values.len());
    if !neurofluid_core::device::is_host(&device) {
        // the kernel's groups, not a reduction per tensor
        assert!(
            sums.len() * 2 <= values.len(),
            "{} tensors of sums for {} inputs",
            sums.len(),
            values.len()
        );
    }
    let got = read_together(sums).expect("read");
    assert_eq!(got.len(), values.len());
    for (i, (v, g)) in values.iter().zip(&got).enumerate() {
        let exact: f64 = v.iter().map(|&x| f64::from(x) * f64::from(x)).sum();
        // f32 products and running sums of ≤ n/256 + 8 terms: far inside n·2⁻²⁴ of the sum
        let bound = exact * v.len() as f64 * 2f64.powi(-24) + f64::MIN_POSITIVE;
        assert!(
            (g - exact).abs() <= bound,
            "tensor {i} ({} elements): {g} against {exact}",
            v.len()
        );
    }
    for _ in 0..3 {
        let again = read_together(square_sums(tensors.clone())).expect("read");
        let bits = |v: &[f64]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
        assert_eq!(bits(&again), bits(&got), "the same bits on every run");
    }
}

#[test]
fn on_a_cpu_backend_it_is_sum_all_of_each_square() {
    let device = test_device();
    if !neurofluid_core::device::is_host(&device) {
        return;
    }
    let (_, tensors) = inputs(&device);
    let got = read_together(square_sums(tensors.clone())).expect("read");
    let each: Vec<Tensor<1>> = tensors
        .into_iter()
        .map(|t| sum_all(t.powi_scalar(2)))
        .collect();
    let want = read_together(each).expect("read");
    assert_eq!(got.len(), want.len());
    for (g, w) in got.iter().zip(&want) {
        assert_eq!(g.to_bits(), w.to_bits());
    }
}

#[test]
fn no_tensors_give_no_sums() {
    assert!(square_sums(Vec::new()).is_empty());
}
