//! The host dense layer (`neurofluid_core::dense::linear`: one operation with its own backward
//! pass on flex) against Burn's own `Linear` + activation and Burn's gradients, in float64:
//! outputs and the gradients of the input, the weight and the bias, for both activations,
//! every subset of tracked inputs, sizes that cross the kernels' row splits, and the input
//! given whole or as two column blocks (`linear_of_cat`, the MLP's skip and direction layers),
//! and the accelerators' path with the rows in blocks (`linear_in_row_blocks`).

use burn::module::Param;
use burn::nn::Linear;
use burn::prelude::*;
use burn::tensor::{DType, TensorCreationOptions, TensorData};
use neurofluid_core::dense::{
    Activation, first_rows, linear, linear_in_row_blocks, linear_of_cat, pad_rows, try_host_linear,
};
use neurofluid_core::device::{test_device, test_device_name};
use neurofluid_core::half_matmul::MatmulOperands;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

fn dtype() -> DType {
    if neurofluid_core::device::test_device_has_float64() {
        DType::F64
    } else {
        DType::F32
    }
}

fn tensor<const D: usize>(v: &[f64], shape: [usize; D], device: &Device) -> Tensor<D> {
    Tensor::from_data(
        TensorData::new(v.to_vec(), shape),
        TensorCreationOptions::new(device.clone()).with_dtype(dtype()),
    )
}

fn f64s<const D: usize>(t: Tensor<D>) -> Vec<f64> {
    t.into_data()
        .convert::<f64>()
        .try_to_vec::<f64>()
        .expect("f64 values")
}

fn random(n: usize, rng: &mut ChaCha8Rng) -> Vec<f64> {
    (0..n).map(|_| rng.random_range(-1.0..1.0)).collect()
}

/// One layer's values: input `[m, k]`, weight `[k, n]`, bias `[n]`, loss coefficients `[m, n]`.
struct Case {
    m: usize,
    k: usize,
    n: usize,
    x: Vec<f64>,
    w: Vec<f64>,
    b: Vec<f64>,
    coeff: Vec<f64>,
}

/// Output, then the gradients of x, W and b (empty when untracked).
type Run = (Vec<f64>, [Vec<f64>; 3]);

/// How a case's layer is evaluated.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Path {
    /// Burn's `Linear` and activation.
    Burn,
    /// `linear` on the whole input.
    Host,
    /// `linear_of_cat` on the input's first `k₁` columns and the rest.
    Blocks(usize),
    /// `linear_in_row_blocks` with blocks of this many rows (an accelerator's path).
    RowBlocks(usize),
}

impl Case {
    fn new(m: usize, k: usize, n: usize, seed: u64) -> Self {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        Self {
            m,
            k,
            n,
            x: random(m * k, &mut rng),
            w: random(k * n, &mut rng),
            b: random(n, &mut rng),
            coeff: random(m * n, &mut rng),
        }
    }

    fn run(&self, path: Path, act: Activation, tracked: [bool; 3]) -> Run {
        let ad = test_device().autodiff();
        let track = |t: Tensor<2>, on: bool| if on { t.require_grad() } else { t };
        let x = track(tensor(&self.x, [self.m, self.k], &ad), tracked[0]);
        let k1 = match path {
            Path::Blocks(k1) => k1,
            _ => self.k,
        };
        let columns = |from: usize, to: usize| -> Vec<f64> {
            self.x
                .chunks(self.k)
                .flat_map(|row| row[from..to].to_vec())
                .collect()
        };
        let blocks = (k1 < self.k).then(|| {
            [(0, k1), (k1, self.k)].map(|(from, to)| {
                let v = columns(from, to);
                track(tensor(&v, [self.m, to - from], &ad), tracked[0])
            })
        });
        let weight = track(tensor(&self.w, [self.k, self.n], &ad), tracked[1]);
        let bias = tensor(&self.b, [self.n], &ad);
        let bias = if tracked[2] {
            bias.require_grad()
        } else {
            bias
        };
        let layer = Linear {
            weight: Param::from_tensor(weight.clone()),
            bias: Some(Param::from_tensor(bias.clone())),
        };
        let y = match path {
            Path::Burn => act.apply(layer.forward(x.clone())),
            Path::Host => linear(&layer, x.clone(), act),
            Path::Blocks(_) => {
                let blocks = blocks.clone().expect("two column blocks");
                linear_of_cat(&layer, blocks.to_vec(), act)
            }
            Path::RowBlocks(rows) => {
                linear_in_row_blocks(&layer, x.clone(), act, rows, MatmulOperands::F32)
            }
        };
        let loss = (y.clone() * tensor(&self.coeff, [self.m, self.n], &ad)).sum();
        let grads = loss.backward();
        let g2 = |t: &Tensor<2>| t.grad(&grads).map(f64s).unwrap_or_default();
        let gb = bias.grad(&grads).map(f64s).unwrap_or_default();
        let gx = match &blocks {
            Some([x1, x2]) => {
                // the blocks' gradients side by side, as x's
                let (g1, g2) = (g2(x1), g2(x2));
                if g1.is_empty() {
                    Vec::new()
                } else {
                    g1.chunks(k1)
                        .zip(g2.chunks(self.k - k1))
                        .flat_map(|(a, b)| [a, b].concat())
                        .collect()
                }
            }
            _ => g2(&x),
        };
        (f64s(y), [gx, g2(&weight), gb])
    }
}

fn max_abs_diff(a: &[f64], b: &[f64]) -> f64 {
    a.iter()
        .zip(b)
        .map(|(a, b)| (a - b).abs())
        .fold(0.0, f64::max)
}

fn check(m: usize, k: usize, n: usize) {
    let tol = if dtype() == DType::F64 { 1e-10 } else { 1e-3 };
    let case = Case::new(m, k, n, (m * 31 + k * 7 + n) as u64);
    for act in [Activation::Relu, Activation::Identity] {
        for tracked in [
            [true, true, true],
            [false, true, true],
            [true, false, false],
            [false, false, true],
        ] {
            // row blocks: one, and about three with the last one padded
            let mut paths = vec![Path::Host, Path::RowBlocks(m), Path::RowBlocks(m / 3 + 1)];
            if k >= 2 {
                paths.push(Path::Blocks(k / 3 + 1));
            }
            let (y_ref, g_ref) = case.run(Path::Burn, act, tracked);
            for path in paths {
                let (y, g) = case.run(path, act, tracked);
                let what = format!("{m}×{k}→{n} {act:?} tracked {tracked:?} {path:?}");
                assert_eq!(y.len(), m * n, "{what}: output size");
                assert!(max_abs_diff(&y, &y_ref) < tol, "{what}: output");
                if act == Activation::Relu && y.len() >= 8 {
                    let zeros = y.iter().filter(|v| **v == 0.0).count();
                    assert!(
                        zeros > 0 && zeros < y.len(),
                        "{what}: the ReLU is exercised"
                    );
                }
                for (i, name) in ["x", "weight", "bias"].iter().enumerate() {
                    assert_eq!(
                        !g[i].is_empty(),
                        tracked[i],
                        "{what}: {name} gradient presence"
                    );
                    assert_eq!(g[i].len(), g_ref[i].len(), "{what}: {name} gradient size");
                    let e = max_abs_diff(&g[i], &g_ref[i]);
                    assert!(
                        e < tol * (m as f64).sqrt(),
                        "{what}: {name} gradient differs by {e:.2e}"
                    );
                }
            }
        }
    }
}

#[test]
fn host_dense_matches_burn_small() {
    check(5, 3, 4);
    check(1, 7, 1);
}

#[test]
fn host_dense_matches_burn_across_row_splits() {
    // 9,000 rows: several forward tasks (1,024 rows) and eight partial sums (1,280 rows), for
    // the matmul kernels and for the narrow heads' dot products.
    check(9000, 19, 33);
    check(9000, 21, 3);
}

/// The host kernels give the same bits with 1, 2 or 3 threads: every split of the work is fixed
/// by the sizes alone and partial sums are added in order.
#[test]
fn results_do_not_depend_on_the_thread_count() {
    use neurofluid_core::dense::{backward, forward};
    let fill = |len: usize, seed: usize| -> Vec<f32> {
        (0..len)
            .map(|i| ((i * 7919 + seed * 104_729) % 2003) as f32 / 1001.5 - 1.0)
            .collect()
    };
    // wide and narrow outputs, batches below and above the largest partial sum (4,096 rows),
    // the input whole or in two column blocks
    for (m, k, n, k1) in [
        (5000, 40, 48, 40),
        (700, 33, 3, 33),
        (20_000, 16, 20, 16),
        (5000, 40, 48, 15),
        (700, 33, 3, 10),
    ] {
        let (x1, x2) = (fill(m * k1, 1), fill(m * (k - k1), 5));
        let (w, b, dy) = (fill(k * n, 2), fill(n, 3), fill(m * n, 4));
        let mut xs = vec![(x1.as_slice(), k1)];
        if k1 < k {
            xs.push((x2.as_slice(), k - k1));
        }
        let need = vec![true; xs.len() + 2];
        let run = |threads: usize| {
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .expect("a thread pool");
            pool.install(|| {
                let y = forward(&xs, &w, &b, n, Activation::Relu);
                let g = backward(&xs, &w, &y, dy.clone(), n, Activation::Relu, &need);
                (y, g.x, g.w, g.b)
            })
        };
        let one = run(1);
        for threads in [2, 3] {
            assert!(
                run(threads) == one,
                "{m}×{k}→{n} ({k1} + {}) with {threads} threads",
                k - k1
            );
        }
    }
}

/// Plain tensors (no autodiff) agree with Burn too; on the CPU both kinds take the host path.
#[test]
fn plain_tensors_give_burn_s_values() {
    let device = test_device();
    let case = Case::new(300, 17, 9, 4);
    let x = tensor(&case.x, [case.m, case.k], &device);
    let layer = Linear {
        weight: Param::from_tensor(tensor(&case.w, [case.k, case.n], &device)),
        bias: Some(Param::from_tensor(tensor(&case.b, [case.n], &device))),
    };
    for act in [Activation::Relu, Activation::Identity] {
        let y = f64s(linear(&layer, x.clone(), act));
        let y_ref = f64s(act.apply(layer.forward(x.clone())));
        assert!(max_abs_diff(&y, &y_ref) < 1e-10, "{act:?}");
    }
    if test_device_name() == "cpu" {
        let w = layer.weight.val();
        let b = layer.bias.as_ref().expect("bias").val();
        assert!(
            try_host_linear(std::slice::from_ref(&x), &w, &b, Activation::Relu).is_some(),
            "plain flex"
        );
        let ad = device.clone().autodiff();
        let xa = tensor(&case.x, [case.m, case.k], &ad).require_grad();
        let wa = tensor(&case.w, [case.k, case.n], &ad);
        let ba = tensor(&case.b, [case.n], &ad);
        assert!(
            try_host_linear(&[xa.clone(), xa.clone()], &wa, &ba, Activation::Relu).is_none(),
            "columns that do not fit the weight"
        );
        assert!(
            try_host_linear(&[xa], &wa, &ba, Activation::Relu).is_some(),
            "flex, autodiff"
        );
        // A NaN input stays NaN through the ReLU (a diverged run is caught downstream).
        let mut v = case.x.clone();
        v[0] = f64::NAN;
        let y = f64s(linear(
            &layer,
            tensor(&v, [case.m, case.k], &device),
            Activation::Relu,
        ));
        assert!(y[..case.n].iter().all(|v| v.is_nan()));
    }
}

/// Two stacked layers' values: input `[m, k]`, parameters `[k, h]`, `[h]`, `[h, out]`, `[out]`
/// and loss coefficients `[m, out]`.
struct TwoLayers {
    m: usize,
    k: usize,
    h: usize,
    out: usize,
    x: Vec<f64>,
    params: [Vec<f64>; 4],
    coeff: Vec<f64>,
}

impl TwoLayers {
    fn new([m, k, h, out]: [usize; 4], seed: u64) -> Self {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        Self {
            m,
            k,
            h,
            out,
            x: random(m * k, &mut rng),
            params: [
                random(k * h, &mut rng),
                random(h, &mut rng),
                random(h * out, &mut rng),
                random(out, &mut rng),
            ],
            coeff: random(m * out, &mut rng),
        }
    }

    /// The output of `net(layers, x)` and the gradients of x, W1, b1, W2 and b2; the input
    /// stored as `[k, m]` and transposed (strides `[1, m]`) when `transposed`.
    fn run(
        &self,
        transposed: bool,
        net: impl Fn(&[Linear; 2], Tensor<2>) -> Tensor<2>,
    ) -> Vec<Vec<f64>> {
        let (m, k, h, out) = (self.m, self.k, self.h, self.out);
        let ad = test_device().autodiff();
        let (leaf, xin) = if transposed {
            let xt = tensor(&transpose(&self.x, m, k), [k, m], &ad).require_grad();
            (xt.clone(), xt.transpose())
        } else {
            let x = tensor(&self.x, [m, k], &ad).require_grad();
            (x.clone(), x)
        };
        let w: Vec<Tensor<2>> = [(0, [k, h]), (2, [h, out])]
            .iter()
            .map(|&(i, s)| tensor(&self.params[i], s, &ad).require_grad())
            .collect();
        let b: Vec<Tensor<1>> = [(1, h), (3, out)]
            .iter()
            .map(|&(i, s)| tensor(&self.params[i], [s], &ad).require_grad())
            .collect();
        let layers = [0, 1].map(|i| Linear {
            weight: Param::from_tensor(w[i].clone()),
            bias: Some(Param::from_tensor(b[i].clone())),
        });
        let y = net(&layers, xin);
        let loss = (y.clone() * tensor(&self.coeff, [m, out], &ad)).sum();
        let grads = loss.backward();
        let g2 = |t: &Tensor<2>| t.grad(&grads).map(f64s).expect("a gradient");
        let g1 = |t: &Tensor<1>| t.grad(&grads).map(f64s).expect("a gradient");
        vec![
            f64s(y),
            g2(&leaf),
            g2(&w[0]),
            g1(&b[0]),
            g2(&w[1]),
            g1(&b[1]),
        ]
    }
}

/// What [`TwoLayers::run`] returns, by name.
const TWO_LAYER_VALUES: [&str; 6] = ["output", "x", "W1", "b1", "W2", "b2"];

/// Two layers in a row (the second at a width that takes the narrow heads' path or not), the
/// input given transposed (non-contiguous): outputs and every gradient against Burn's.
#[test]
fn stacked_layers_match_burn() {
    let tol = if dtype() == DType::F64 { 1e-9 } else { 1e-3 };
    let (m, k, h) = (5000, 13, 24);
    for out in [7, 40] {
        let case = TwoLayers::new([m, k, h, out], out as u64);
        let run = |host: bool| {
            case.run(true, |layers, x| {
                let apply = |i: usize, t: Tensor<2>, act: Activation| {
                    if host {
                        linear(&layers[i], t, act)
                    } else {
                        act.apply(layers[i].forward(t))
                    }
                };
                apply(1, apply(0, x, Activation::Relu), Activation::Identity)
            })
        };
        let (got, want) = (run(true), run(false));
        for ((name, a), b) in TWO_LAYER_VALUES.iter().zip(&got).zip(&want) {
            assert_eq!(a.len(), b.len(), "{name}");
            let e = max_abs_diff(a, b);
            assert!(
                e < tol * (m as f64).sqrt(),
                "→{out}: {name} differs by {e:.2e}"
            );
        }
    }
}

fn transpose(v: &[f64], rows: usize, cols: usize) -> Vec<f64> {
    let mut t = vec![0.0; v.len()];
    for i in 0..rows {
        for j in 0..cols {
            t[j * rows + i] = v[i * cols + j];
        }
    }
    t
}

/// A network's inputs padded once to whole row blocks (`pad_rows`, what the PhysNeRF MLP does on
/// an accelerator) give the bits of padding each layer's input: the outputs and the gradients of
/// the input and of every weight and bias, for two layers with the rows in blocks of 64 (a last
/// block of 15 rows), the second without an activation.
#[test]
fn padding_a_networks_inputs_once_is_padding_every_layer() {
    let (m, block) = (207, 64);
    let case = TwoLayers::new([m, 9, 16, 5], 31);
    let run = |once: bool| {
        case.run(false, |layers, x| {
            let apply = |i: usize, t: Tensor<2>, act: Activation| {
                linear_in_row_blocks(&layers[i], t, act, block, MatmulOperands::F32)
            };
            if once {
                let (padded, rows) = pad_rows(vec![x], block);
                assert_eq!((rows, padded[0].dims()[0]), (m, 256));
                let h = apply(0, padded[0].clone(), Activation::Relu);
                first_rows(apply(1, h, Activation::Identity), m)
            } else {
                apply(1, apply(0, x, Activation::Relu), Activation::Identity)
            }
        })
    };
    let (once, every) = (run(true), run(false));
    for ((name, a), b) in TWO_LAYER_VALUES.iter().zip(&once).zip(&every) {
        assert_eq!(a, b, "{name}");
    }
}
