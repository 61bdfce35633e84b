//! Matmuls with 16-bit operands, for the tensor cores of a GPU: the dense layers' products on an
//! accelerator (`neurofluid_core::dense`) with f16 or bf16 operands and f32 accumulation, each
//! operand first divided by its largest magnitude so that it neither overflows nor underflows
//! the 16-bit type, in the forward pass and in the backward pass alike.
//!
//! Why: on NVIDIA's Vulkan driver the tensor cores take f16 or bf16 operands only (no tf32), so
//! cubecl's matmul falls back to its scalar kernel for f32 operands; on an H100 that kernel was
//! 82 % of the PhysNeRF step (docs/notebook/benchmarks-history.md, "Issue 30, second H100 session").
//!
//! Why the scaling: f16 keeps magnitudes from 6·10⁻⁵ (normal) to 65,504; a PhysNeRF step's
//! output gradients are around 10⁻⁶–10⁻⁸, which f16 would flush to zero or keep with a few bits.
//! Burn's own backward of a matmul of f16 tensors multiplies the f16 gradient as it comes, so the
//! backward here is an autodiff operation of its own that scales `dz` by its largest magnitude
//! before it is rounded. The products of operands in [−1, 1] are at most the inner dimension
//! (≤ 65,504: asserted), and are rounded to the 16-bit type once, on output.

use burn::prelude::*;
use burn::tensor::DType;
use serde::{Deserialize, Serialize};

use crate::choice::{Choice, ProcessChoice};

/// The operands' type of the dense layers' matmuls on an accelerator (the experiment's
/// `matmul`). The CPU's host dense layers always compute in the tensors' own type.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum MatmulOperands {
    /// f32 operands (the paper's and PyTorch's default).
    #[default]
    F32,
    /// f16 operands, each scaled by its largest magnitude; f32 accumulation.
    F16,
    /// bf16 operands (f32's range, 8 bits of mantissa), each scaled as f16's; f32 accumulation.
    Bf16,
}

impl MatmulOperands {
    /// The 16-bit type, `None` for f32.
    pub fn half(self) -> Option<DType> {
        match self {
            MatmulOperands::F32 => None,
            MatmulOperands::F16 => Some(DType::F16),
            MatmulOperands::Bf16 => Some(DType::BF16),
        }
    }

    /// The unit roundoff of the operands' type (2⁻²⁴, 2⁻¹¹, 2⁻⁸).
    pub fn unit_roundoff(self) -> f64 {
        match self {
            MatmulOperands::F32 => 2f64.powi(-24),
            MatmulOperands::F16 => 2f64.powi(-11),
            MatmulOperands::Bf16 => 2f64.powi(-8),
        }
    }
}

impl Choice for MatmulOperands {
    const ALL: &'static [Self] = &[Self::F32, Self::F16, Self::Bf16];

    fn name(self) -> &'static str {
        match self {
            MatmulOperands::F32 => "f32",
            MatmulOperands::F16 => "f16",
            MatmulOperands::Bf16 => "bf16",
        }
    }
}

/// The process's choice (f32 unless set).
static OPERANDS: ProcessChoice = ProcessChoice::new();

/// The operands' type of the dense layers' matmuls on an accelerator in this process.
pub fn matmul_operands() -> MatmulOperands {
    OPERANDS.get()
}

/// Sets the operands' type of the dense layers' matmuls on an accelerator for this process (the
/// trainer sets the experiment's `matmul` when it opens a run).
pub fn set_matmul_operands(operands: MatmulOperands) {
    OPERANDS.set(operands);
}

/// The largest inner dimension whose products of operands in [−1, 1] f16 can hold.
const MAX_INNER: usize = 65_504;

/// A tensor divided by its largest magnitude (a tiny positive number for an all-zero tensor),
/// in the 16-bit type, with that magnitude as a one-element tensor of the tensor's own type.
#[derive(Debug, Clone)]
struct Scaled<const D: usize> {
    half: Tensor<D>,
    scale: Tensor<1>,
}

impl<const D: usize> Scaled<D> {
    fn new(t: Tensor<D>, half: DType) -> Self {
        let scale = t.clone().abs().max().clamp_min(f32::MIN_POSITIVE as f64);
        let div = scale.clone().reshape([1; D]);
        Self {
            half: (t / div).cast(half),
            scale,
        }
    }
}

/// `a·b` of scaled operands `a [B, m, k]`, `b [B or 1, k, n]` (16-bit, f32 accumulation),
/// unscaled and returned in `dtype`.
///
/// # Panics
/// When `k` exceeds 65,504 (products in [−k, k] would not fit in f16).
fn product(a: Tensor<3>, sa: Tensor<1>, b: Tensor<3>, sb: Tensor<1>, dtype: DType) -> Tensor<3> {
    let k = a.dims()[2];
    assert!(
        k <= MAX_INNER,
        "a 16-bit matmul's inner dimension {k} exceeds {MAX_INNER}"
    );
    a.matmul(b).cast(dtype) * (sa * sb).reshape([1, 1, 1])
}

/// `a·b` for `a [B, m, k]`, `b [B or 1, k, n]` (untracked) with the operands in `half`, each
/// divided by its largest magnitude, accumulated in f32 and returned in `a`'s type.
///
/// # Panics
/// When `k` exceeds 65,504 (products in [−k, k] would not fit in f16).
pub fn scaled_half_matmul(a: Tensor<3>, b: Tensor<3>, half: DType) -> Tensor<3> {
    let dtype = a.dtype();
    let (a, b) = (Scaled::new(a, half), Scaled::new(b, half));
    product(a.half, a.scale, b.half, b.scale, dtype)
}

/// `x·w` for `x [B, m, k]` and `w [k, n]` with 16-bit operands ([`scaled_half_matmul`]) in the
/// forward and the backward pass: the gradients `dx = dz·wᵀ` and `dw = Σ_b x_bᵀ·dz_b` are
/// 16-bit matmuls of the scaled `dz` too. On tracked flex and cubecl tensors one autodiff
/// operation; on other tracked backends Burn's casts and matmul (whose backward rounds `dz` to
/// the 16-bit type unscaled).
pub fn half_matmul(x: Tensor<3>, w: Tensor<2>, half: DType) -> Tensor<3> {
    #[cfg(feature = "flex")]
    if let Some(z) = flex_op::tracked(&x, &w, half) {
        return z;
    }
    #[cfg(feature = "gpu")]
    if let Some(z) = cube_op::tracked(&x, &w, half) {
        return z;
    }
    if x.is_require_grad() || w.is_require_grad() {
        let dtype = x.dtype();
        return x
            .cast(half)
            .matmul(w.cast(half).unsqueeze_dim::<3>(0))
            .cast(dtype);
    }
    scaled_half_matmul(x, w.unsqueeze_dim::<3>(0), half)
}

/// The gradients of `x·w` from `dz [B, m, n]`, given the forward pass's scaled operands:
/// `(dx [B, m, k], dw [k, n])`, each when asked; `dz` is scaled once for both.
fn gradients(
    x: &Scaled<3>,
    w: &Scaled<2>,
    dz: Tensor<3>,
    half: DType,
    need: [bool; 2],
) -> (Option<Tensor<3>>, Option<Tensor<2>>) {
    let dtype = dz.dtype();
    let dz = Scaled::new(dz, half);
    let dx = need[0].then(|| {
        let wt = w.half.clone().transpose().unsqueeze_dim::<3>(0);
        let (dzh, dzs) = (dz.half.clone(), dz.scale.clone());
        product(dzh, dzs, wt, w.scale.clone(), dtype)
    });
    let dw = need[1].then(|| {
        let xt = x.half.clone().swap_dims(1, 2);
        product(xt, x.scale.clone(), dz.half, dz.scale, dtype)
            .sum_dim(0)
            .squeeze_dim::<2>(0)
    });
    (dx, dw)
}

/// The autodiff operation on one backend: `$backend` the untracked backend's type, `$name` the
/// module's name. Parents (x, w); the state keeps both as the forward pass scaled them.
macro_rules! half_matmul_op {
    ($name:ident, $backend:ty) => {
        mod $name {
            use super::*;
            use burn::backend::Autodiff;
            use burn::backend::autodiff::checkpoint::base::Checkpointer;
            use burn::backend::autodiff::checkpoint::strategy::NoCheckpointing;
            use burn::backend::autodiff::grads::Gradients;
            use burn::backend::autodiff::ops::{Backward, Ops, OpsKind};

            type Plain = $backend;
            type Tracked = Autodiff<Plain>;

            #[derive(Debug)]
            struct HalfMatmulBackward;

            /// The forward pass's scaled operands (no f32 copy kept).
            #[derive(Debug, Clone)]
            struct State {
                x: Scaled<3>,
                w: Scaled<2>,
                half: DType,
            }

            impl Backward<Plain, 2> for HalfMatmulBackward {
                type State = State;

                fn backward(self, ops: Ops<State, 2>, grads: &mut Gradients, _: &mut Checkpointer) {
                    let dz =
                        Tensor::<3>::from_primitive::<Plain>(grads.consume::<Plain>(&ops.node));
                    let [px, pw] = ops.parents;
                    let s = ops.state;
                    let (dx, dw) = gradients(&s.x, &s.w, dz, s.half, [px.is_some(), pw.is_some()]);
                    if let (Some(node), Some(dx)) = (px, dx) {
                        let p = dx
                            .try_into_primitive::<Plain>()
                            .expect("an untracked tensor");
                        grads.register::<Plain>(node.id, p);
                    }
                    if let (Some(node), Some(dw)) = (pw, dw) {
                        let p = dw
                            .try_into_primitive::<Plain>()
                            .expect("an untracked tensor");
                        grads.register::<Plain>(node.id, p);
                    }
                }
            }

            /// [`super::half_matmul`] of tracked tensors of this backend; `None` otherwise.
            pub fn tracked(x: &Tensor<3>, w: &Tensor<2>, half: DType) -> Option<Tensor<3>> {
                let xa = x.clone().try_into_primitive::<Tracked>().ok()?;
                let wa = w.clone().try_into_primitive::<Tracked>().ok()?;
                let xp = Tensor::<3>::from_primitive::<Plain>(xa.primitive().clone());
                let wp = Tensor::<2>::from_primitive::<Plain>(wa.primitive().clone());
                let dtype = xp.dtype();
                let (xs, ws) = (Scaled::new(xp, half), Scaled::new(wp, half));
                let wh = ws.half.clone().unsqueeze_dim::<3>(0);
                let z = product(
                    xs.half.clone(),
                    xs.scale.clone(),
                    wh,
                    ws.scale.clone(),
                    dtype,
                );
                let z = z
                    .try_into_primitive::<Plain>()
                    .expect("an untracked tensor");
                let out = match HalfMatmulBackward
                    .prepare::<NoCheckpointing>([xa.node(), wa.node()])
                    .compute_bound()
                    .stateful()
                {
                    OpsKind::Tracked(prep) => prep.finish(State { x: xs, w: ws, half }, z),
                    OpsKind::UnTracked(prep) => prep.finish(z),
                };
                Some(Tensor::<3>::from_primitive::<Tracked>(out))
            }
        }
    };
}

#[cfg(feature = "flex")]
half_matmul_op!(flex_op, burn::backend::Flex);
#[cfg(feature = "gpu")]
half_matmul_op!(cube_op, burn::backend::Cube);
