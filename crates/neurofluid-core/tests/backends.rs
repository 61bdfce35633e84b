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
