//! `tensors::sum_all` and `mean_all` on the test device: the same bits on every repetition (a GPU
//! runs Burn's whole-tensor sum with atomic adds between workgroups, whose order varies), the
//! f64 sum within f32's accumulated rounding, and the gradient of every element exactly 1 (sum)
//! or 1/n (mean), as Burn's own.

use burn::prelude::*;
use burn::tensor::{DType, TensorCreationOptions, TensorData};
use neurofluid_core::device::test_device;
use neurofluid_core::tensors::{mean_all, sum_all};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

fn values(n: usize) -> Vec<f32> {
    let mut rng = ChaCha8Rng::seed_from_u64(3);
    (0..n).map(|_| rng.random_range(-1.0f32..1.0)).collect()
}

fn tensor(v: &[f32], shape: [usize; 2], device: &Device) -> Tensor<2> {
    Tensor::from_data(
        TensorData::new(v.to_vec(), shape),
        TensorCreationOptions::new(device.clone()).with_dtype(DType::F32),
    )
}

fn scalar(t: Tensor<1>) -> f32 {
    t.into_data().try_to_vec::<f32>().expect("f32")[0]
}

#[test]
fn sums_of_every_element_repeat_to_the_bit() {
    let device = test_device();
    // 1,000 × 1,000: far more elements than one workgroup sums
    let v = values(1_000_000);
    let t = tensor(&v, [1000, 1000], &device);
    let exact: f64 = v.iter().map(|&x| f64::from(x)).sum();
    let first = scalar(sum_all(t.clone()));
    let mean = scalar(mean_all(t.clone()));
    for _ in 0..10 {
        assert_eq!(scalar(sum_all(t.clone())).to_bits(), first.to_bits());
        assert_eq!(scalar(mean_all(t.clone())).to_bits(), mean.to_bits());
    }
    // an f32 sum of 10⁶ terms of magnitude ≤ 1: the rounding of the running sums
    let bound = 1e-7 * 1e6_f64.sqrt() * 1000.0;
    assert!(
        (f64::from(first) - exact).abs() < bound,
        "{first} vs {exact}"
    );
    assert!(
        (f64::from(mean) - exact / 1e6).abs() < bound / 1e6,
        "{mean}"
    );
    // Burn's whole-tensor sum of the same tensor, for the record (not asserted: its bits may vary)
    let burn: Vec<u32> = (0..10).map(|_| scalar(t.clone().sum()).to_bits()).collect();
    let distinct = burn.iter().collect::<std::collections::BTreeSet<_>>().len();
    eprintln!("Burn's whole-tensor sum: {distinct} distinct results in 10 (sum_all: 1)");
}

#[test]
fn their_gradients_are_burns() {
    let ad = test_device().autodiff();
    // one block, and several (the last padded)
    for (rows, mean) in [(700, false), (700, true), (70_000, false), (70_000, true)] {
        let v = values(3 * rows);
        let gradient = |reduce: &dyn Fn(Tensor<2>) -> Tensor<1>| -> Vec<f32> {
            let x = tensor(&v, [rows, 3], &ad).require_grad();
            let grads = reduce(x.clone()).backward();
            x.grad(&grads).unwrap().into_data().try_to_vec().unwrap()
        };
        let (ours, burns) = if mean {
            (gradient(&mean_all), gradient(&|x| x.mean()))
        } else {
            (gradient(&sum_all), gradient(&|x| x.sum()))
        };
        assert_eq!(ours, burns, "{rows} rows, mean: {mean}");
    }
}
