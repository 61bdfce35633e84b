//! The fused CPU conv (one autodiff operation with its own backward pass) against the composed
//! Burn path (gather, weight, scatter-add: Burn's own gradients): the output and the gradients of
//! the features, of both point sets through the differentiable weights, and of the kernel, in
//! float64, for both evaluation orders and for every subset of tracked inputs.

use crate::common;

use burn::module::Param;
use burn::prelude::*;
use burn::tensor::{DType, Distribution};
use common::*;
use neurofluid_dlf::diff_geometry::differentiable_weights;
use neurofluid_dlf::fused::try_fused_conv;
use neurofluid_dlf::geometry::{ConvGeometry, HostGeometry, build_host_geometry};
use neurofluid_dlf::mapping::KERNEL_CELLS;
use neurofluid_dlf::{ContinuousConv, FILTER_EXTENT};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

fn cloud(n: usize, side: f32, seed: u64) -> Vec<[f32; 3]> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    (0..n)
        .map(|_| std::array::from_fn(|_| rng.random_range(0.0..side)))
        .collect()
}

fn f64s<const D: usize>(t: Tensor<D>) -> Vec<f64> {
    t.to_data().convert::<f64>().try_into_vec::<f64>().unwrap()
}

fn max_rel(a: &[f64], b: &[f64]) -> f64 {
    assert_eq!(a.len(), b.len());
    let scale = b.iter().fold(1e-300f64, |m, &x| m.max(x.abs()));
    a.iter()
        .zip(b)
        .fold(0f64, |m, (&x, &y)| m.max((x - y).abs()))
        / scale
}

/// Which inputs carry gradients.
#[derive(Clone, Copy, Debug)]
struct Tracked {
    features: bool,
    positions: bool,
    kernel: bool,
}

/// Output and gradients (features, input points, output points, kernel; empty when untracked).
struct Run {
    out: Vec<f64>,
    grads: [Vec<f64>; 4],
}

struct Case {
    inputs: Vec<[f32; 3]>,
    outputs: Vec<[f32; 3]>,
    host: HostGeometry,
    features: Vec<f64>,
    kernel: Vec<f64>,
    coeff: Vec<f64>,
    cin: usize,
    cout: usize,
    dtype: DType,
}

impl Case {
    fn new(cin: usize, cout: usize, same_cloud: bool, dtype: DType) -> Self {
        let mut outputs = cloud(250, 0.3, 11);
        let inputs = if same_cloud {
            outputs.clone()
        } else {
            cloud(320, 0.3, 12)
        };
        // a point with no neighbour (its slots are all padding)
        outputs.push([2.0, 2.0, 2.0]);
        let host = build_host_geometry(&inputs, &outputs, FILTER_EXTENT, true, None);
        assert!(host.num_pairs() > 1000, "{} pairs", host.num_pairs());
        let mut rng = ChaCha8Rng::seed_from_u64(13);
        let mut normal = |n: usize| (0..n).map(|_| rng.random_range(-1.0..1.0)).collect();
        Self {
            features: normal(inputs.len() * cin),
            kernel: normal(KERNEL_CELLS * cin * cout),
            coeff: normal(outputs.len() * cout),
            inputs,
            outputs,
            host,
            cin,
            cout,
            dtype,
        }
    }

    fn tensor<const D: usize>(&self, v: &[f64], shape: [usize; D], device: &Device) -> Tensor<D> {
        Tensor::<D>::from_data(
            TensorData::new(v.to_vec(), shape),
            burn::tensor::TensorCreationOptions::new(device.clone()).with_dtype(self.dtype),
        )
    }

    fn points(&self, p: &[[f32; 3]], device: &Device) -> Tensor<2> {
        to_tensor(p, device).cast(self.dtype)
    }

    /// Σ coeff ⊙ conv(features) by the fused path (`path` = `None`) or the composed path in
    /// chunks of at most `path` neighbour slots, and its gradients.
    fn run(&self, path: Option<usize>, tracked: Tracked) -> Run {
        let ad = device().autodiff();
        let track = |t: Tensor<2>, on: bool| if on { t.require_grad() } else { t };
        let features = track(
            self.tensor(&self.features, [self.inputs.len(), self.cin], &ad),
            tracked.features,
        );
        let xin = track(self.points(&self.inputs, &ad), tracked.positions);
        let xout = track(self.points(&self.outputs, &ad), tracked.positions);
        let weights = differentiable_weights(&self.host, xin.clone(), xout.clone(), FILTER_EXTENT);
        let mut geometry = ConvGeometry::new(self.host.clone(), weights, &ad);
        if let Some(entries) = path {
            geometry = geometry.with_chunk_slots(entries);
        }
        let k = neurofluid_dlf::mapping::KERNEL_SIZE;
        let kernel = self.tensor(&self.kernel, [k, k, k, self.cin, self.cout], &ad);
        let conv = ContinuousConv {
            kernel: Param::from_tensor(kernel),
            bias: Param::from_tensor(Tensor::zeros([self.cout], (&ad, self.dtype))),
        };
        // parameters require gradients unless the module is frozen
        let conv = if tracked.kernel { conv } else { conv.no_grad() };
        let out = match path {
            None => conv.forward(features.clone(), &geometry),
            Some(_) => conv.forward_composed(features.clone(), &geometry),
        };
        let coeff = self.tensor(&self.coeff, [self.outputs.len(), self.cout], &ad);
        let loss = (out.clone() * coeff).sum();
        let grads = loss.backward();
        let grad = |t: &Tensor<2>| t.grad(&grads).map(f64s).unwrap_or_default();
        Run {
            out: f64s(out),
            grads: [
                grad(&features),
                grad(&xin),
                grad(&xout),
                conv.kernel.val().grad(&grads).map(f64s).unwrap_or_default(),
            ],
        }
    }
}

fn check(cin: usize, cout: usize, same_cloud: bool) {
    let dtype = if neurofluid_core::device::test_device_has_float64() {
        DType::F64
    } else {
        DType::F32
    };
    let tol = if dtype == DType::F64 { 1e-10 } else { 1e-4 };
    let case = Case::new(cin, cout, same_cloud, dtype);
    let all = Tracked {
        features: true,
        positions: true,
        kernel: true,
    };
    let subsets = [
        all,
        Tracked {
            features: false,
            positions: false,
            kernel: true,
        },
        Tracked {
            features: true,
            positions: false,
            kernel: false,
        },
        Tracked {
            features: false,
            positions: true,
            kernel: false,
        },
    ];
    // the composed path in one chunk, and in chunks of at most 40 output points
    let widest = case.host.counts().into_iter().max().unwrap_or(1) as usize;
    let one_chunk = case.host.num_out * widest;
    let chunked = 40 * widest;
    for (tracked, entries) in subsets
        .into_iter()
        .flat_map(|t| [(t, one_chunk), (t, chunked)])
    {
        let fused = case.run(None, tracked);
        let composed = case.run(Some(entries), tracked);
        let e = max_rel(&fused.out, &composed.out);
        assert!(
            e < tol,
            "{cin}→{cout} {tracked:?}, {entries} slots per chunk: output differs by {e:.2e}"
        );
        let names = ["features", "input points", "output points", "kernel"];
        let wanted = [
            tracked.features,
            tracked.positions,
            tracked.positions,
            tracked.kernel,
        ];
        for ((name, want), (a, b)) in names
            .iter()
            .zip(wanted)
            .zip(fused.grads.iter().zip(&composed.grads))
        {
            assert_eq!(
                !a.is_empty(),
                want,
                "{name}: gradient presence, {tracked:?}"
            );
            assert_eq!(a.len(), b.len(), "{name}: gradient size");
            if want {
                assert!(
                    b.iter().any(|&v| v != 0.0),
                    "{name}: zero reference gradient"
                );
                let e = max_rel(a, b);
                assert!(
                    e < tol,
                    "{cin}→{cout} {tracked:?}, {entries} slots per chunk: {name} gradient differs by \
                     {e:.2e}"
                );
            }
        }
    }
}

#[test]
fn fused_matches_composed_gather_first() {
    check(4, 32, true);
    check(96, 64, true);
    check(3, 32, false);
    check(288, 72, true);
}

#[test]
fn fused_matches_composed_kernel_first() {
    check(64, 3, true);
    check(16, 2, false);
}

/// On the CPU (flex with autodiff) the fused operation is the one `forward` takes.
#[test]
fn the_cpu_takes_the_fused_path() {
    if neurofluid_core::device::test_device_name() != "cpu" {
        return;
    }
    let ad = device().autodiff();
    let pts = cloud(50, 0.2, 1);
    let host = build_host_geometry(&pts, &pts, FILTER_EXTENT, true, None);
    let geometry = ConvGeometry::new(host, None, &ad);
    let features = Tensor::<2>::random([50, 4], Distribution::Default, &ad).require_grad();
    let kernel = Tensor::<2>::random([KERNEL_CELLS * 4, 8], Distribution::Default, &ad);
    let weights = || geometry.weights_tensor(DType::F32);
    assert!(try_fused_conv(geometry.host(), &features, weights, &kernel).is_some());
}
