//! The geometry as tensor ops: the pair-corner weights computed from position tensors with Burn
//! ops, so gradients flow through positions into the mapping, the trilinear weights and the
//! window. The discrete choices (mapping branches, cells) come from the host geometry, or are
//! found from the values on their device (the geometry in slots on the GPU); either way they are
//! piecewise constant in the positions.

use burn::prelude::*;
use neurofluid_core::rows::{RowIndex, gather_rows};

use crate::geometry::{CORNERS, HostGeometry, search_radius};
use crate::mapping::KERNEL_SIZE;

fn column(v: &[f32], device: &Device, dtype: burn::tensor::DType) -> Tensor<2> {
    neurofluid_core::transfer::upload::<2, burn::tensor::Float, _>(
        TensorData::new(v.to_vec(), [v.len(), 1]),
        device,
    )
    .cast(dtype)
}

fn mask(v: Vec<bool>, device: &Device) -> Tensor<2, Bool> {
    let n = v.len();
    neurofluid_core::transfer::upload(TensorData::new(v, [n, 1]), device)
}

/// Weights `[8P, 1]` of `host`'s pair corners as a function of the input and output positions
/// (`[N_in, 3]`, `[M, 3]`, any float dtype, possibly tracked). Equal to `host.weights` in value.
///
/// `None` when `host` has no pairs: such a conv gives its bias whatever the weights, and empty
/// tensors are left out of the graph (cubecl's `select` overflows on a zero-length index in debug
/// builds).
pub fn differentiable_weights(
    host: &HostGeometry,
    inputs: Tensor<2>,
    outputs: Tensor<2>,
    extent: f32,
) -> Option<Tensor<2>> {
    let p = host.num_pairs();
    if p == 0 {
        return None;
    }
    let device = inputs.device();
    let cols = RowIndex::new(host.pairs.indices.iter().map(|&i| i as usize), &device);
    let rows = RowIndex::new(host.query_of_pair.iter().map(|&i| i as usize), &device);
    let rel = gather_rows(inputs, &cols) - gather_rows(outputs, &rows);
    let (corners, _) = pair_weights(rel, extent, Branches::Host(host));
    Some(corners.reshape([p * CORNERS, 1]))
}

/// Where the mapping's discrete choices come from.
#[derive(Clone, Copy)]
pub enum Branches<'a> {
    /// The host geometry's, pair by pair (its pairs in its order).
    Host(&'a HostGeometry),
    /// Found from the values themselves, on their device (the tests of
    /// [`crate::mapping::ball_to_cube_volume_preserving`] and [`crate::mapping::axis_interp`] as
    /// tensor comparisons).
    Values,
}

/// The trilinear corner weights × window `[P, 8]` (z outer, x inner, as
/// [`crate::mapping::trilinear_corners`]) and the lower corners `[P, 3]` (x, y, z, as floats) of
/// relative positions `rel [P, 3]` (neighbour − query), as Burn ops: the mapping's branches as
/// `branches` says, the weights differentiable in `rel` wherever `rel` is tracked.
pub fn pair_weights(rel: Tensor<2>, extent: f32, branches: Branches<'_>) -> (Tensor<2>, Tensor<2>) {
    let [p, _] = rel.dims();
    let device = rel.device();
    let dtype = rel.dtype();
    let radius = search_radius(extent);
    // window on the squared distance
    let r2 = (rel.clone() * rel.clone()).sum_dim(1) / (radius * radius);
    let t = r2.neg() + 1.0;
    let window = (t.clone() * t.clone() * t).clamp(0.0, 1.0);
    let ones = Tensor::<2>::ones([p, 1], (&device, dtype));
    let zeros = Tensor::<2>::zeros([p, 1], (&device, dtype));

    let q = rel * (2.0 * (1.0f32 / extent));
    let x = q.clone().narrow(1, 0, 1);
    let y = q.clone().narrow(1, 1, 1);
    let z = q.narrow(1, 2, 1);
    let sq_xy = x.clone() * x.clone() + y.clone() * y.clone();
    let sq = sq_xy.clone() + z.clone() * z.clone();
    let (zero, cap) = match branches {
        Branches::Host(host) => (
            mask(host.branches.iter().map(|b| b.zero).collect(), &device),
            mask(host.branches.iter().map(|b| b.cap).collect(), &device),
        ),
        Branches::Values => {
            let zero = sq.clone().detach().lower_elem(1e-12);
            let z2 = z.clone().detach();
            let cap = (z2.clone() * z2 * 1.25)
                .greater(sq_xy.clone().detach())
                .bool_and(zero.clone().bool_not());
            (zero, cap)
        }
    };
    let side_ok = cap.clone().bool_or(zero.clone()).bool_not();
    let norm = sq.mask_where(zero.clone(), ones.clone()).sqrt();
    let abs_z = z.clone().abs();
    let s_cap = ((norm.clone() * 3.0) / (norm.clone() + abs_z)).sqrt();
    let s_side = norm.clone() / sq_xy.mask_where(side_ok.bool_not(), ones.clone()).sqrt();
    let s = s_side.mask_where(cap.clone(), s_cap);
    let x1 = (x * s.clone()).mask_where(zero.clone(), zeros.clone());
    let y1 = (y * s).mask_where(zero.clone(), zeros.clone());
    let z1 = (z.clone() * 1.5)
        .mask_where(cap, z.sign() * norm)
        .mask_where(zero, zeros.clone());

    let sq_xy1 = x1.clone() * x1.clone() + y1.clone() * y1.clone();
    let (zero_xy, xdom, sign_x, sign_y) = match branches {
        Branches::Host(host) => {
            let br = &host.branches;
            let column = |v: Vec<f32>| column(&v, &device, dtype);
            (
                mask(br.iter().map(|b| b.zero_xy).collect(), &device),
                mask(br.iter().map(|b| b.x_dominant).collect(), &device),
                column(br.iter().map(|b| b.sign_x).collect()),
                column(br.iter().map(|b| b.sign_y).collect()),
            )
        }
        Branches::Values => {
            let (x1, y1) = (x1.clone().detach(), y1.clone().detach());
            // copysign(1, ·): where a sign of zero would matter, the branch is masked
            let sign = |v: Tensor<2>| {
                ones.clone()
                    .mask_where(v.lower_elem(0.0), ones.clone().neg())
            };
            (
                sq_xy1.clone().detach().lower_elem(1e-12),
                y1.clone().abs().lower_equal(x1.clone().abs()),
                sign(x1),
                sign(y1),
            )
        }
    };
    let x_ok = xdom.clone().bool_and(zero_xy.clone().bool_not());
    let y_ok = xdom.clone().bool_not().bool_and(zero_xy.clone().bool_not());
    let nxy = sq_xy1.mask_where(zero_xy.clone(), ones.clone()).sqrt();
    let four_over_pi = 4.0 / std::f32::consts::PI;
    let safe_x = x1.clone().mask_where(x_ok.bool_not(), ones.clone());
    let safe_y = y1.clone().mask_where(y_ok.bool_not(), ones.clone());
    let tx = sign_x * nxy.clone();
    let ty = sign_y * nxy;
    let x_from_y = ty.clone() * four_over_pi * (x1 / safe_y).atan();
    let y_from_x = tx.clone() * four_over_pi * (y1 / safe_x).atan();
    let x2 = x_from_y
        .mask_where(xdom.clone(), tx)
        .mask_where(zero_xy.clone(), zeros.clone());
    let y2 = ty.mask_where(xdom, y_from_x).mask_where(zero_xy, zeros);

    let k1 = (KERNEL_SIZE - 1) as f32;
    let mut lowers = Vec::with_capacity(3);
    let mut frac = |c: Tensor<2>, axis: usize| {
        let u = (c * 0.5 + 0.5) * k1;
        let lower = match branches {
            Branches::Host(host) => {
                let lower: Vec<f32> = host.lower.iter().map(|l| l[axis] as f32).collect();
                column(&lower, &device, dtype)
            }
            Branches::Values => u.clone().detach().floor().clamp(0.0, k1),
        };
        lowers.push(lower.clone());
        (u - lower).clamp(0.0, 1.0)
    };
    let a = frac(x2, 0);
    let b = frac(y2, 1);
    let c = frac(z1, 2);
    let mut corners = Vec::with_capacity(CORNERS);
    for wz in [c.clone().neg() + 1.0, c] {
        for wy in [b.clone().neg() + 1.0, b.clone()] {
            for wx in [a.clone().neg() + 1.0, a.clone()] {
                corners.push(wx.clone() * wy.clone() * wz.clone());
            }
        }
    }
    (Tensor::cat(corners, 1) * window, Tensor::cat(lowers, 1))
}
