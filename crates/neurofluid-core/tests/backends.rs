//! A small Burn model gives the same output on every CPU backend compiled in, and that output
//! equals the same model evaluated by hand in f64 on the host.

use burn::nn::{Linear, LinearConfig};
use burn::prelude::*;
use burn::tensor::activation::relu;
use neurofluid_core::device::cpu_devices;

#[derive(Module, Debug)]
struct Tiny {
    a: Linear,
    b: Linear,
}

/// The backend's random stream is global: the tests that draw from it take turns.
static DRAWS: std::sync::Mutex<()> = std::sync::Mutex::new(());

const X: [[f32; 3]; 2] = [[0.5, -1.0, 2.0], [1.5, 0.25, -0.75]];

/// Deterministic weights so every backend runs the same model.
fn weights(rows: usize, cols: usize, seed: f32) -> Vec<f32> {
    (0..rows * cols)
        .map(|i| ((i as f32 + seed) * 0.37).sin() * 0.5)
        .collect()
}

fn build(device: &Device) -> Tiny {
    let mut a = LinearConfig::new(3, 4).init(device);
    let mut b = LinearConfig::new(4, 2).init(device);
    a.weight = a
        .weight
        .map(|_| Tensor::from_data(TensorData::new(weights(3, 4, 1.0), [3, 4]), device));
    a.bias = a
        .bias
        .map(|b| b.map(|_| Tensor::from_data(TensorData::new(weights(1, 4, 2.0), [4]), device)));
    b.weight = b
        .weight
        .map(|_| Tensor::from_data(TensorData::new(weights(4, 2, 3.0), [4, 2]), device));
    b.bias = b
        .bias
        .map(|b| b.map(|_| Tensor::from_data(TensorData::new(weights(1, 2, 4.0), [2]), device)));
    Tiny { a, b }
}

fn host() -> Vec<f64> {
    let (wa, ba, wb, bb) = (
        weights(3, 4, 1.0),
        weights(1, 4, 2.0),
        weights(4, 2, 3.0),
        weights(1, 2, 4.0),
    );
    let mut out = Vec::new();
    for x in X {
        let h: Vec<f64> = (0..4)
            .map(|j| {
                (ba[j] as f64
                    + (0..3)
                        .map(|i| x[i] as f64 * wa[i * 4 + j] as f64)
                        .sum::<f64>())
                .max(0.0)
            })
            .collect();
        for k in 0..2 {
            out.push(bb[k] as f64 + (0..4).map(|j| h[j] * wb[j * 2 + k] as f64).sum::<f64>());
        }
    }
    out
}

#[test]
fn every_cpu_backend_computes_the_same_model() {
    let _turn = DRAWS.lock().unwrap_or_else(|e| e.into_inner());
    let expected = host();
    let devices = cpu_devices();
    assert!(!devices.is_empty());
    for (name, device) in devices {
        let model = build(&device);
        let x = Tensor::<2>::from_data(X, &device);
        let y = model.b.forward(relu(model.a.forward(x)));
        let got = y.try_into_vec_as::<f32>().unwrap();
        for (g, e) in got.iter().zip(&expected) {
            assert!(
                (*g as f64 - e).abs() < 1e-5,
                "{name}: {got:?} vs host {expected:?}"
            );
        }
    }
}

/// The gather every particle feature goes through: `select` with repeated indices, and its
/// gradient, which must sum the rows that picked the same input (on `$NEUROFLUID_TEST_DEVICE`).
#[test]
fn select_gradient_sums_repeated_rows() {
    let device = neurofluid_core::device::test_device().autodiff();
    let x = Tensor::<2>::from_data([[1.0f32, 2.0], [3.0, 4.0], [5.0, 6.0]], &device).require_grad();
    let idx = Tensor::<1, Int>::from_data([0i64, 2, 0, 0, 1], &device);
    let w = Tensor::<2>::from_data(
        [
            [1.0f32, 10.0],
            [2.0, 20.0],
            [3.0, 30.0],
            [4.0, 40.0],
            [5.0, 50.0],
        ],
        &device,
    );
    let loss = (x.clone().select(0, idx) * w).sum();
    let grads = loss.backward();
    let g = x.grad(&grads).unwrap().try_into_vec_as::<f32>().unwrap();
    // row 0 is picked by rows 0, 2, 3 of w; row 1 by row 4; row 2 by row 1
    assert_eq!(g, vec![8.0, 80.0, 5.0, 50.0, 2.0, 20.0]);
}

/// A seeded initialisation gives the CPU's draw on `$NEUROFLUID_TEST_DEVICE` (each backend has
/// its own random numbers: on wgpu building there directly gives other weights), the module
/// lives on that device afterwards, and another seed gives other weights.
#[test]
fn seeded_initialisation_is_the_cpus_draw_on_every_device() {
    use neurofluid_core::device::{cpu, init_seeded, test_device};
    let values = |m: &Linear| -> Vec<f32> {
        let mut v = m.weight.val().try_into_vec_as::<f32>().unwrap();
        v.extend(
            m.bias
                .as_ref()
                .unwrap()
                .val()
                .try_into_vec_as::<f32>()
                .unwrap(),
        );
        v
    };
    let build = |d: &Device| Ok::<_, std::convert::Infallible>(LinearConfig::new(5, 7).init(d));
    let _turn = DRAWS.lock().unwrap_or_else(|e| e.into_inner());
    let device = test_device().autodiff();
    let moved = init_seeded(41, &device, build).unwrap();
    assert_eq!(moved.weight.val().device(), device);
    let reference = cpu().autodiff();
    reference.seed(41);
    let on_cpu = build(&reference).unwrap();
    assert_eq!(values(&moved), values(&on_cpu));
    let other = init_seeded(42, &device, build).unwrap();
    assert_ne!(values(&other), values(&on_cpu));
}
