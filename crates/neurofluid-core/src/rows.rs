//! Indexed rows: gathers and scatter-adds whose indices are built on the host, in the form each
//! backend runs well, and the same bit for bit from run to run on every backend.
//!
//! - On the CPU (flex): Burn's `select` and `select_assign`.
//! - Elsewhere: a gather with the index repeated over the columns, and every sum of rows into
//!   their destinations (the forward of [`add_rows`], the gradient of [`gather_rows`]) as a
//!   fixed-order sum planned on the host ([`RowIndex`]): the rows of each destination side by
//!   side, padded to the next power of two of their count, gathered and summed along the group.
//!   No atomic adds, so two runs on a GPU give the same bits (Burn's own gradient of `gather` is a
//!   scatter-add with atomic adds); no kernel loops over all rows (Burn's `select_assign` runs one
//!   thread per column, serially over every row: an idle GPU, and on Mesa's lavapipe, whose loops
//!   stop after 65,535 iterations, every later row silently lost). On the cubecl backends
//!   (wgpu, CUDA) with autodiff both operations are autodiff ops of their own, so their
//!   gradients take the same path.

use std::collections::BTreeMap;
use std::sync::{Arc, OnceLock};

use burn::prelude::*;
use burn::tensor::IndexingUpdateOp;

use crate::transfer::upload;

/// Row indices (repeats allowed) with their device copy and, built on first use, the plan that
/// sums rows into their destinations in a fixed order. Cheap to clone.
#[derive(Debug, Clone)]
pub struct RowIndex {
    /// The host copy: given, or (an index made on the device) read back when a plan needs it.
    ids: Arc<OnceLock<Arc<[u32]>>>,
    len: usize,
    tensor: Tensor<1, Int>,
    plan: Arc<OnceLock<SumPlan>>,
    transpose: Option<Arc<dyn RowSum>>,
}

/// A sum of rows into their destinations known to the maker of an index built on the device
/// (e.g. from the index's structure, without its host copy): `Σ values[r]` over the rows `r`
/// whose index is `j`, for every `j < n`, in a fixed order, on untracked tensors.
pub trait RowSum: std::fmt::Debug + Send + Sync {
    /// `[n, c]` from `values [L, c]`; `None` where it cannot (then the index's plan sums).
    fn sum_into(&self, values: Tensor<2>, n: usize) -> Option<Tensor<2>>;
}

/// The fixed-order sum of `L` rows into `n` destinations, planned on the host and uploaded
/// once: every later sum with the plan (the four fluid convs of a DLF step share their
/// geometry's indices, forward and backward) reuses the device copies.
#[derive(Debug)]
struct SumPlan {
    /// Destination rows.
    n: usize,
    /// Groups of destinations with at most `width` rows each: the positions of their rows
    /// `[destinations · width]`, ascending per destination, padded with `L` (a zero row).
    groups: Vec<(Tensor<1, Int>, usize)>,
    /// Per destination, its row in the groups' stacked sums (one past the last: a zero row).
    place: Tensor<1, Int>,
}

impl RowIndex {
    /// Indices `ids` (each below the row count of the tensors they index) on `device`.
    ///
    /// # Panics
    /// When an index does not fit in 32 bits (a programming error: tensors are far smaller).
    pub fn new(ids: impl IntoIterator<Item = usize>, device: &Device) -> Self {
        let ids: Arc<[u32]> = ids
            .into_iter()
            .map(|i| u32::try_from(i).expect("row index below 2^32"))
            .collect();
        let signed: Vec<i32> = ids.iter().map(|&i| i as i32).collect();
        let tensor = upload(TensorData::new(signed, [ids.len()]), device);
        Self {
            len: ids.len(),
            ids: Arc::new(OnceLock::from(ids)),
            tensor,
            plan: Arc::default(),
            transpose: None,
        }
    }

    /// An index made on the device (`tensor`, int32 rows), with no host copy: its sums into
    /// rows by `transpose` where given, else by a plan from a copy read back on first need.
    pub fn on_device(tensor: Tensor<1, Int>, transpose: Option<Arc<dyn RowSum>>) -> Self {
        Self {
            len: tensor.dims()[0],
            ids: Arc::default(),
            tensor,
            plan: Arc::default(),
            transpose,
        }
    }

    /// The indices as a device tensor.
    pub fn tensor(&self) -> &Tensor<1, Int> {
        &self.tensor
    }

    /// Number of indices.
    pub fn len(&self) -> usize {
        self.len
    }

    /// Whether there are no indices.
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// The host copy (read back from the device once, for an index made there).
    fn ids(&self) -> &[u32] {
        self.ids.get_or_init(|| {
            crate::transfer::read_vec::<i32, 1, Int>(self.tensor.clone())
                .expect("reading a row index back from its device")
                .into_iter()
                .map(|i| i as u32)
                .collect()
        })
    }

    /// `Σ values[r]` over the rows `r` whose index is `j`, for every `j < n` → `[n, c]`, in the
    /// plan's fixed order (the plan is cached for the first `n` asked for); a composition of
    /// Burn's gather and sum (any backend, any tracking).
    fn sum_into(&self, values: Tensor<2>, n: usize) -> Tensor<2> {
        if let Some(out) = self
            .transpose
            .as_ref()
            .and_then(|t| t.sum_into(values.clone(), n))
        {
            return out;
        }
        let device = values.device();
        let owned;
        let cached = self
            .plan
            .get_or_init(|| SumPlan::new(self.ids(), n, &device));
        let plan = if cached.n == n {
            cached
        } else {
            owned = SumPlan::new(self.ids(), n, &device);
            &owned
        };
        let c = values.dims()[1];
        let dtype = values.dtype();
        let zero = || Tensor::<2>::zeros([1, c], (&device, dtype));
        let padded = Tensor::cat(vec![values, zero()], 0);
        // a group's gathered rows are its largest temporary: cut where the device's buffers
        // are smaller (lavapipe binds 128 MiB, and past it a fused kernel read wrong rows)
        let buffer = crate::device::max_buffer_bytes(&device).map_or(usize::MAX, |b| b as usize);
        let row_bytes = c * dtype.size();
        let mut parts: Vec<Tensor<2>> = Vec::new();
        for (positions, width) in &plan.groups {
            let dests = positions.dims()[0] / width;
            let per_piece = (buffer / (width * row_bytes).max(1)).clamp(1, dests);
            for first in (0..dests).step_by(per_piece) {
                let rows = per_piece.min(dests - first);
                let piece = positions.clone().narrow(0, first * width, rows * width);
                let g = plain_gather(padded.clone(), piece);
                parts.push(if *width == 1 {
                    g
                } else {
                    g.reshape([rows, *width, c]).sum_dim(1).reshape([rows, c])
                });
            }
        }
        parts.push(zero());
        plain_gather(Tensor::cat(parts, 0), plan.place.clone())
    }
}

impl SumPlan {
    /// Groups the positions of `ids` (each below `n`) by destination (a stable counting sort, so
    /// each destination's rows stay in ascending order), destinations by the next power of two
    /// of their row count; the arrays uploaded to `device`.
    fn new(ids: &[u32], n: usize, device: &Device) -> Self {
        let l = ids.len();
        let (start, order) = crate::neighbors::counting_sort(ids, n, |i| Some(i as usize));
        let start: Vec<usize> = start.into_iter().map(|s| s as usize).collect();
        let mut by_width: BTreeMap<usize, Vec<usize>> = BTreeMap::new();
        for j in 0..n {
            let count = start[j + 1] - start[j];
            if count > 0 {
                by_width
                    .entry(count.next_power_of_two())
                    .or_default()
                    .push(j);
            }
        }
        let mut place = vec![-1i32; n];
        let mut stacked = 0usize;
        let groups = by_width
            .into_iter()
            .map(|(width, dests)| {
                let mut positions = Vec::with_capacity(dests.len() * width);
                for &j in &dests {
                    let rows = &order[start[j]..start[j + 1]];
                    positions.extend(rows.iter().map(|&p| p as i32));
                    positions.resize(positions.len() + width - rows.len(), l as i32);
                    place[j] = stacked as i32;
                    stacked += 1;
                }
                (int_tensor(&positions, device), width)
            })
            .collect();
        for p in &mut place {
            if *p < 0 {
                *p = stacked as i32;
            }
        }
        Self {
            n,
            groups,
            place: int_tensor(&place, device),
        }
    }
}

fn int_tensor(v: &[i32], device: &Device) -> Tensor<1, Int> {
    upload(TensorData::new(v.to_vec(), [v.len()]), device)
}

/// Rows `idx` of `t` by Burn's `gather` (one index per value).
fn plain_gather(t: Tensor<2>, idx: Tensor<1, Int>) -> Tensor<2> {
    let [l] = idx.dims();
    let c = t.dims()[1];
    t.gather(0, idx.reshape([l, 1]).expand([l, c]))
}

/// Rows `idx` of `t [n, c]` → `[L, c]` (repeats allowed); its gradient sums into the rows in a
/// fixed order (module docs).
pub fn gather_rows(t: Tensor<2>, idx: &RowIndex) -> Tensor<2> {
    if on_flex(&t) {
        return t.select(0, idx.tensor.clone());
    }
    #[cfg(feature = "gpu")]
    if let Some(y) = cube_ops::gather_rows(&t, idx) {
        return y;
    }
    plain_gather(t, idx.tensor.clone())
}

/// `base [n, c]` with `values [L, c]` added into rows `idx` (repeats add up, in a fixed order
/// off the CPU: module docs).
pub fn add_rows(base: Tensor<2>, idx: &RowIndex, values: Tensor<2>) -> Tensor<2> {
    if on_flex(&base) {
        return base.select_assign(0, idx.tensor.clone(), values, IndexingUpdateOp::Add);
    }
    #[cfg(feature = "gpu")]
    if let Some(y) = cube_ops::add_rows(&base, idx, &values) {
        return y;
    }
    let n = base.dims()[0];
    base + idx.sum_into(values, n)
}

/// Whether `t` is a tensor of Burn's flex CPU backend (plain or with autodiff).
fn on_flex(t: &Tensor<2>) -> bool {
    #[cfg(feature = "flex")]
    {
        use burn::backend::{Autodiff, Flex};
        if t.clone().try_into_primitive::<Flex>().is_ok()
            || t.clone().try_into_primitive::<Autodiff<Flex>>().is_ok()
        {
            return true;
        }
    }
    #[cfg(not(feature = "flex"))]
    let _ = t;
    false
}

/// [`gather_rows`] and [`add_rows`] as autodiff operations of the cubecl backend (wgpu, CUDA),
/// their gradients computed on the untracked tensors: the gather's by the planned sum, the
/// added values' by a gather.
#[cfg(feature = "gpu")]
mod cube_ops {
    use super::*;
    use burn::backend::autodiff::checkpoint::base::Checkpointer;
    use burn::backend::autodiff::checkpoint::strategy::NoCheckpointing;
    use burn::backend::autodiff::grads::Gradients;
    use burn::backend::autodiff::ops::{Backward, Ops, OpsKind};
    use burn::backend::tensor::FloatTensor;
    use burn::backend::{Autodiff, Cube};

    type Tracked = Autodiff<Cube>;
    type Primitive = FloatTensor<Cube>;

    /// The index on the untracked cubecl device.
    fn untracked_index(idx: &RowIndex) -> Tensor<1, Int> {
        match idx.tensor.clone().try_into_primitive::<Tracked>() {
            Ok(p) => Tensor::<1, Int>::from_primitive::<Cube>(p),
            Err(_) => idx.tensor.clone(),
        }
    }

    fn untracked(p: Primitive) -> Tensor<2> {
        Tensor::<2>::from_primitive::<Cube>(p)
    }

    fn primitive(t: Tensor<2>) -> Primitive {
        t.try_into_primitive::<Cube>()
            .expect("an untracked cubecl tensor")
    }

    #[derive(Debug)]
    struct GatherBackward;

    impl Backward<Cube, 1> for GatherBackward {
        /// The index and the gathered tensor's row count.
        type State = (RowIndex, usize);

        fn backward(self, ops: Ops<Self::State, 1>, grads: &mut Gradients, _: &mut Checkpointer) {
            let dy = untracked(grads.consume::<Cube>(&ops.node));
            let (idx, n) = ops.state;
            if let [Some(parent)] = ops.parents {
                grads.register::<Cube>(parent.id, primitive(idx.sum_into(dy, n)));
            }
        }
    }

    #[derive(Debug)]
    struct AddBackward;

    impl Backward<Cube, 2> for AddBackward {
        type State = RowIndex;

        fn backward(self, ops: Ops<Self::State, 2>, grads: &mut Gradients, _: &mut Checkpointer) {
            let dy = grads.consume::<Cube>(&ops.node);
            let [base, values] = ops.parents;
            if let Some(values) = values {
                let dv = plain_gather(untracked(dy.clone()), untracked_index(&ops.state));
                grads.register::<Cube>(values.id, primitive(dv));
            }
            if let Some(base) = base {
                grads.register::<Cube>(base.id, dy);
            }
        }
    }

    /// [`super::gather_rows`] of a tracked cubecl tensor; `None` for any other tensor.
    pub fn gather_rows(t: &Tensor<2>, idx: &RowIndex) -> Option<Tensor<2>> {
        let ta = t.clone().try_into_primitive::<Tracked>().ok()?;
        let n = t.dims()[0];
        let y = primitive(plain_gather(
            untracked(ta.primitive().clone()),
            untracked_index(idx),
        ));
        let out = match GatherBackward
            .prepare::<NoCheckpointing>([ta.node()])
            .compute_bound()
            .stateful()
        {
            OpsKind::Tracked(prep) => prep.finish((idx.clone(), n), y),
            OpsKind::UnTracked(prep) => prep.finish(y),
        };
        Some(Tensor::<2>::from_primitive::<Tracked>(out))
    }

    /// [`super::add_rows`] of tracked cubecl tensors; `None` for any other tensors.
    pub fn add_rows(base: &Tensor<2>, idx: &RowIndex, values: &Tensor<2>) -> Option<Tensor<2>> {
        let ba = base.clone().try_into_primitive::<Tracked>().ok()?;
        let va = values.clone().try_into_primitive::<Tracked>().ok()?;
        let n = base.dims()[0];
        let y =
            untracked(ba.primitive().clone()) + idx.sum_into(untracked(va.primitive().clone()), n);
        let y = primitive(y);
        let out = match AddBackward
            .prepare::<NoCheckpointing>([ba.node(), va.node()])
            .compute_bound()
            .stateful()
        {
            OpsKind::Tracked(prep) => prep.finish(idx.clone(), y),
            OpsKind::UnTracked(prep) => prep.finish(y),
        };
        Some(Tensor::<2>::from_primitive::<Tracked>(out))
    }
}
