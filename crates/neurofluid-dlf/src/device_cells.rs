//! The kernel-cell weights of a chunk's neighbour slots as one GPU kernel (the cubecl backends:
//! wgpu, CUDA), with its own backward pass (the same kernel compiled for the gradient in the
//! relative positions).
//!
//! The same function as [`crate::diff_geometry::pair_weights`] with its branches found from the
//! values, followed by [`crate::geometry::cell_weights`] of the corners times the slots' `real`
//! column: the ball→cube mapping, the clamped trilinear corners, the window, and the corners
//! added into their 64 cells — about a hundred tensor operations per chunk as Burn ops, one
//! thread per slot here. The operations and their order follow the tensor version, so the
//! weights agree with it to rounding. The backward pass recomputes each slot with dual numbers
//! (a value and its derivatives in the slot's three coordinates) and contracts the corners'
//! derivatives with the output gradient of their cells; where the tensor version switches (a
//! mask, a clamp) the derivative is the one Burn's autodiff gives it: the chosen branch's, and
//! through a clamp where `min ≤ v ≤ max`. A padding slot (`real` 0) gets a zero gradient.

use burn::prelude::*;

/// `[S, 64]` kernel-cell weights of slots with relative positions `rel [S, 3]` (neighbour −
/// query, possibly tracked) and `real [S, 1]` (1 for a pair, 0 for padding, untracked), for a
/// filter of `extent`; `None` off the cubecl backends or for a dtype other than f32 (the caller
/// then composes the tensor version).
pub fn slot_cell_weights(rel: &Tensor<2>, real: &Tensor<2>, extent: f32) -> Option<Tensor<2>> {
    #[cfg(feature = "gpu")]
    {
        kernel::slot_cell_weights(rel, real, extent)
    }
    #[cfg(not(feature = "gpu"))]
    {
        let _ = (rel, real, extent);
        None
    }
}

#[cfg(feature = "gpu")]
mod kernel {
    use burn::backend::autodiff::checkpoint::base::Checkpointer;
    use burn::backend::autodiff::checkpoint::strategy::NoCheckpointing;
    use burn::backend::autodiff::grads::Gradients;
    use burn::backend::autodiff::ops::{Backward, Ops, OpsKind};
    use burn::backend::tensor::FloatTensor;
    use burn::backend::{Autodiff, Cube};
    use burn::prelude::Tensor as BurnTensor;
    use burn::tensor::DType;
    use cubecl::calculate_cube_count_elemwise;
    use cubecl::prelude::*;
    use cubecl::server::Handle;
    use neurofluid_core::cube_tensor;

    use crate::geometry::search_radius;
    use crate::mapping::{KERNEL_CELLS, KERNEL_SIZE};

    type Tracked = Autodiff<Cube>;
    type Primitive = FloatTensor<Cube>;

    /// A value and its derivatives in the slot's relative position (x, y, z).
    #[derive(CubeType, Clone, Copy)]
    struct Dual {
        v: f32,
        dx: f32,
        dy: f32,
        dz: f32,
    }

    #[cube]
    fn constant(v: f32) -> Dual {
        Dual {
            v,
            dx: 0.0f32,
            dy: 0.0f32,
            dz: 0.0f32,
        }
    }

    #[cube]
    fn add(a: &Dual, b: &Dual) -> Dual {
        Dual {
            v: a.v + b.v,
            dx: a.dx + b.dx,
            dy: a.dy + b.dy,
            dz: a.dz + b.dz,
        }
    }

    #[cube]
    fn add_scalar(a: &Dual, k: f32) -> Dual {
        Dual {
            v: a.v + k,
            dx: a.dx,
            dy: a.dy,
            dz: a.dz,
        }
    }

    #[cube]
    fn mul(a: &Dual, b: &Dual) -> Dual {
        Dual {
            v: a.v * b.v,
            dx: a.dx * b.v + a.v * b.dx,
            dy: a.dy * b.v + a.v * b.dy,
            dz: a.dz * b.v + a.v * b.dz,
        }
    }

    #[cube]
    fn scale(a: &Dual, k: f32) -> Dual {
        Dual {
            v: a.v * k,
            dx: a.dx * k,
            dy: a.dy * k,
            dz: a.dz * k,
        }
    }

    #[cube]
    fn div_scalar(a: &Dual, k: f32) -> Dual {
        Dual {
            v: a.v / k,
            dx: a.dx / k,
            dy: a.dy / k,
            dz: a.dz / k,
        }
    }

    #[cube]
    fn div(a: &Dual, b: &Dual) -> Dual {
        let q = a.v / b.v;
        Dual {
            v: q,
            dx: (a.dx - q * b.dx) / b.v,
            dy: (a.dy - q * b.dy) / b.v,
            dz: (a.dz - q * b.dz) / b.v,
        }
    }

    /// `v` with `a`'s derivatives times `k`.
    #[cube]
    fn chain(v: f32, a: &Dual, k: f32) -> Dual {
        Dual {
            v,
            dx: a.dx * k,
            dy: a.dy * k,
            dz: a.dz * k,
        }
    }

    #[cube]
    fn sqrt(a: &Dual) -> Dual {
        let s = f32::sqrt(a.v);
        chain(s, a, 0.5f32 / s)
    }

    #[cube]
    fn atan(a: &Dual) -> Dual {
        let v = a.v;
        chain(f32::atan(v), a, 1.0f32 / (v * v + 1.0f32))
    }

    /// The sign of `v`: −1, 0 or 1 (Burn's `sign`).
    #[cube]
    fn sign(v: f32) -> f32 {
        let mut out = 0.0f32;
        if v > 0.0f32 {
            out = 1.0f32;
        }
        if v < 0.0f32 {
            out = -1.0f32;
        }
        out
    }

    /// `|a|`, its derivative `sign(a)` (Burn's).
    #[cube]
    fn abs(a: &Dual) -> Dual {
        chain(f32::abs(a.v), a, sign(a.v))
    }

    /// `b` where `pick`, else `a`.
    #[cube]
    fn pick(pick: bool, a: f32, b: f32) -> f32 {
        let mut out = a;
        if pick {
            out = b;
        }
        out
    }

    /// `b` where `pick`, else `a` (a mask's `mask_where`).
    #[cube]
    fn select(pick: bool, a: &Dual, b: &Dual) -> Dual {
        Dual {
            v: self::pick(pick, a.v, b.v),
            dx: self::pick(pick, a.dx, b.dx),
            dy: self::pick(pick, a.dy, b.dy),
            dz: self::pick(pick, a.dz, b.dz),
        }
    }

    /// `clamp(a, lo, hi)`, the derivative passed where `lo ≤ a ≤ hi`.
    #[cube]
    fn clamp(a: &Dual, lo: f32, hi: f32) -> Dual {
        let inside = a.v >= lo && a.v <= hi;
        Dual {
            v: f32::clamp(a.v, lo, hi),
            dx: pick(inside, 0.0f32, a.dx),
            dy: pick(inside, 0.0f32, a.dy),
            dz: pick(inside, 0.0f32, a.dz),
        }
    }

    /// One slot's mapping: the three trilinear fractions (x, y, z), the window and the lower
    /// corner's cells.
    #[derive(CubeType, Clone, Copy)]
    struct SlotCells {
        a: Dual,
        b: Dual,
        c: Dual,
        window: Dual,
        lx: u32,
        ly: u32,
        lz: u32,
    }

    /// `u = (c·0.5 + 0.5)·3`, the filter coordinate along one axis.
    #[cube]
    fn coordinate(c: &Dual) -> Dual {
        let half = add_scalar(&scale(c, 0.5f32), 0.5f32);
        scale(&half, comptime![(KERNEL_SIZE - 1) as f32])
    }

    /// The lower cell of coordinate `u`: `clamp(floor(u), 0, 3)`.
    #[cube]
    fn lower(u: &Dual) -> f32 {
        f32::clamp(f32::floor(u.v), 0.0f32, comptime![(KERNEL_SIZE - 1) as f32])
    }

    /// The fraction of coordinate `u` past its lower cell, clamped to [0, 1].
    #[cube]
    fn fraction(u: &Dual) -> Dual {
        clamp(&add_scalar(u, -lower(u)), 0.0f32, 1.0f32)
    }

    /// The mapping of `diff_geometry::pair_weights` (branches from the values) for one slot.
    #[cube]
    fn slot_cells(rx: f32, ry: f32, rz: f32, to_ball: f32, radius2: f32) -> SlotCells {
        let ex = Dual {
            v: rx,
            dx: 1.0f32,
            dy: 0.0f32,
            dz: 0.0f32,
        };
        let ey = Dual {
            v: ry,
            dx: 0.0f32,
            dy: 1.0f32,
            dz: 0.0f32,
        };
        let ez = Dual {
            v: rz,
            dx: 0.0f32,
            dy: 0.0f32,
            dz: 1.0f32,
        };
        // window on the squared distance
        let d2 = add(&add(&mul(&ex, &ex), &mul(&ey, &ey)), &mul(&ez, &ez));
        let t = add_scalar(&scale(&div_scalar(&d2, radius2), -1.0f32), 1.0f32);
        let window = clamp(&mul(&mul(&t, &t), &t), 0.0f32, 1.0f32);
        // sphere → cylinder
        let x = scale(&ex, to_ball);
        let y = scale(&ey, to_ball);
        let z = scale(&ez, to_ball);
        let sq_xy = add(&mul(&x, &x), &mul(&y, &y));
        let sq = add(&sq_xy, &mul(&z, &z));
        let zero = sq.v < 1e-12f32;
        let cap = z.v * z.v * 1.25f32 > sq_xy.v && !zero;
        let side = !cap && !zero;
        let one = constant(1.0f32);
        let nil = constant(0.0f32);
        let norm = sqrt(&select(zero, &sq, &one));
        let s_cap = sqrt(&div(&scale(&norm, 3.0f32), &add(&norm, &abs(&z))));
        let s_side = div(&norm, &sqrt(&select(!side, &sq_xy, &one)));
        let s = select(cap, &s_side, &s_cap);
        let x1 = select(zero, &mul(&x, &s), &nil);
        let y1 = select(zero, &mul(&y, &s), &nil);
        let z_cap = scale(&norm, sign(z.v));
        let z1 = select(zero, &select(cap, &scale(&z, 1.5f32), &z_cap), &nil);
        // cylinder → cube
        let sq_xy1 = add(&mul(&x1, &x1), &mul(&y1, &y1));
        let zero_xy = sq_xy1.v < 1e-12f32;
        let xdom = f32::abs(y1.v) <= f32::abs(x1.v);
        let sign_x = pick(x1.v < 0.0f32, 1.0f32, -1.0f32);
        let sign_y = pick(y1.v < 0.0f32, 1.0f32, -1.0f32);
        let x_ok = xdom && !zero_xy;
        let y_ok = !xdom && !zero_xy;
        let nxy = sqrt(&select(zero_xy, &sq_xy1, &one));
        let safe_x = select(!x_ok, &x1, &one);
        let safe_y = select(!y_ok, &y1, &one);
        let tx = scale(&nxy, sign_x);
        let ty = scale(&nxy, sign_y);
        let four_over_pi = comptime![4.0f32 / std::f32::consts::PI];
        let x_from_y = mul(&scale(&ty, four_over_pi), &atan(&div(&x1, &safe_y)));
        let y_from_x = mul(&scale(&tx, four_over_pi), &atan(&div(&y1, &safe_x)));
        let x2 = select(zero_xy, &select(xdom, &x_from_y, &tx), &nil);
        let y2 = select(zero_xy, &select(xdom, &ty, &y_from_x), &nil);
        let ux = coordinate(&x2);
        let uy = coordinate(&y2);
        let uz = coordinate(&z1);
        SlotCells {
            a: fraction(&ux),
            b: fraction(&uy),
            c: fraction(&uz),
            window,
            lx: u32::cast_from(lower(&ux)),
            ly: u32::cast_from(lower(&uy)),
            lz: u32::cast_from(lower(&uz)),
        }
    }

    /// `w` where `upper`, else `1 − w`.
    #[cube]
    fn side_weight(w: &Dual, upper: bool) -> Dual {
        let flipped = add_scalar(&scale(w, -1.0f32), 1.0f32);
        select(upper, &flipped, w)
    }

    /// `v`, at most `top`.
    #[cube]
    fn capped(v: u32, top: u32) -> u32 {
        let mut out = v;
        if v > top {
            out = top;
        }
        out
    }

    /// The cell of corner `(dz, dy, dx)` of a slot's lower corner.
    #[cube]
    fn corner_cell(g: &SlotCells, dz: u32, dy: u32, dx: u32) -> usize {
        let top = comptime![(KERNEL_SIZE - 1) as u32];
        let k = comptime![KERNEL_SIZE as u32];
        let cz = capped(g.lz + dz, top);
        let cy = capped(g.ly + dy, top);
        let cx = capped(g.lx + dx, top);
        usize::cast_from((cz * k + cy) * k + cx)
    }

    /// Corner `(dz, dy, dx)`'s weight: `((wx·wy)·wz)·window`.
    #[cube]
    fn corner_weight(g: &SlotCells, dz: u32, dy: u32, dx: u32) -> Dual {
        let wx = side_weight(&g.a, dx == 1);
        let wy = side_weight(&g.b, dy == 1);
        let wz = side_weight(&g.c, dz == 1);
        mul(&mul(&mul(&wx, &wy), &wz), &g.window)
    }

    /// Forward (`backward` false): each slot's 64 cell weights into `out [S, 64]`. Backward:
    /// each slot's gradient in its relative position into `out [S, 3]` from the weights'
    /// gradient `grad [S, 64]` (unread in the forward pass).
    #[allow(clippy::too_many_arguments)]
    #[cube(launch)]
    fn slot_cells_kernel(
        rel: &Tensor<f32>,
        real: &Tensor<f32>,
        grad: &Tensor<f32>,
        out: &mut Tensor<f32>,
        slots: usize,
        to_ball: f32,
        radius2: f32,
        #[comptime] backward: bool,
    ) {
        let s = ABSOLUTE_POS;
        if s < slots {
            let cells = comptime![KERNEL_CELLS];
            let row = s * cells;
            let r = real[s];
            let mut gx = 0.0f32;
            let mut gy = 0.0f32;
            let mut gz = 0.0f32;
            if !backward {
                for k in 0..cells {
                    out[row + k] = 0.0f32;
                }
            }
            // a padding slot has no gradient
            if !backward || r != 0.0f32 {
                let g = slot_cells(rel[s * 3], rel[s * 3 + 1], rel[s * 3 + 2], to_ball, radius2);
                for dz in 0..2u32 {
                    for dy in 0..2u32 {
                        for dx in 0..2u32 {
                            let cell = row + corner_cell(&g, dz, dy, dx);
                            let w = corner_weight(&g, dz, dy, dx);
                            if backward {
                                let up = grad[cell] * r;
                                gx += up * w.dx;
                                gy += up * w.dy;
                                gz += up * w.dz;
                            } else {
                                out[cell] += w.v * r;
                            }
                        }
                    }
                }
            }
            if backward {
                out[s * 3] = gx;
                out[s * 3 + 1] = gy;
                out[s * 3 + 2] = gz;
            }
        }
    }

    fn arg(handle: &Handle, len: usize) -> TensorArg {
        cube_tensor::f32_arg(handle, len.max(1))
    }

    /// The buffer of an untracked or tracked cubecl tensor (its value), contiguous.
    fn value_buffer(t: &BurnTensor<2>) -> Option<cubecl::server::Handle> {
        let untracked = match t.clone().try_into_primitive::<Tracked>() {
            Ok(p) => BurnTensor::<2>::from_primitive::<Cube>(p.primitive().clone()),
            Err(_) => t.clone(),
        };
        Some(cube_tensor::float_buffer(untracked)?.handle)
    }

    /// The kernel over `slots` slots (`grad` the weights' gradient in the backward pass) → the
    /// weights `[S, 64]` or the positions' gradient `[S, 3]`.
    fn launch(
        device: &cubecl::Device,
        (rel, real, slots, extent): (&Handle, &Handle, usize, f32),
        grad: Option<&Handle>,
    ) -> BurnTensor<2> {
        let client = device.client();
        let cols = if grad.is_some() { 3 } else { KERNEL_CELLS };
        let out = client.empty(slots.max(1) * cols * 4);
        let radius = search_radius(extent);
        let cube_dim = CubeDim::new_1d(128);
        slot_cells_kernel::launch(
            &client,
            calculate_cube_count_elemwise(&client, slots.max(1), cube_dim),
            cube_dim,
            arg(rel, slots * 3),
            arg(real, slots),
            grad.map_or_else(|| arg(real, 1), |g| arg(g, slots * KERNEL_CELLS)),
            arg(&out, slots * cols),
            slots,
            2.0 * (1.0f32 / extent),
            radius * radius,
            grad.is_some(),
        );
        cube_tensor::float_tensor(device, out, [slots, cols])
    }

    /// The slots' positions, `real` and the filter extent, for the backward pass.
    #[derive(Debug, Clone)]
    struct State {
        device: cubecl::Device,
        rel: Handle,
        real: Handle,
        slots: usize,
        extent: f32,
    }

    #[derive(Debug)]
    struct CellsBackward;

    impl Backward<Cube, 1> for CellsBackward {
        type State = State;

        fn backward(self, ops: Ops<Self::State, 1>, grads: &mut Gradients, _: &mut Checkpointer) {
            let dy = BurnTensor::<2>::from_primitive::<Cube>(grads.consume::<Cube>(&ops.node));
            let [parent] = ops.parents;
            let Some(parent) = parent else { return };
            let st = ops.state;
            let dy = cube_tensor::float_buffer(dy)
                .expect("a cubecl gradient")
                .handle;
            let drel = launch(
                &st.device,
                (&st.rel, &st.real, st.slots, st.extent),
                Some(&dy),
            );
            let p: Primitive = drel.try_into_primitive::<Cube>().expect("a cubecl tensor");
            grads.register::<Cube>(parent.id, p);
        }
    }

    pub(super) fn slot_cell_weights(
        rel: &BurnTensor<2>,
        real: &BurnTensor<2>,
        extent: f32,
    ) -> Option<BurnTensor<2>> {
        if rel.dtype() != DType::F32 || real.dtype() != DType::F32 {
            return None;
        }
        let device = cube_tensor::cube_device(&rel.device())?;
        let [slots, _] = rel.dims();
        let rel_h = value_buffer(rel)?;
        let real_h = value_buffer(real)?;
        let w = launch(&device, (&rel_h, &real_h, slots, extent), None);
        let Ok(tracked) = rel.clone().try_into_primitive::<Tracked>() else {
            return Some(w);
        };
        let w: Primitive = w.try_into_primitive::<Cube>().ok()?;
        let state = State {
            device,
            rel: rel_h,
            real: real_h,
            slots,
            extent,
        };
        let out = match CellsBackward
            .prepare::<NoCheckpointing>([tracked.node()])
            .compute_bound()
            .stateful()
        {
            OpsKind::Tracked(prep) => prep.finish(state, w),
            OpsKind::UnTracked(prep) => prep.finish(w),
        };
        Some(BurnTensor::<2>::from_primitive::<Tracked>(out))
    }
}
