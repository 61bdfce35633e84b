//! Moving point sets between the host (`[[f32; 3]]`) and Burn tensors (`[N, 3]`), and indexed
//! rows (gathers and scatter-adds) in the form each backend runs well.

use burn::prelude::*;
use burn::tensor::IndexingUpdateOp;

/// Rows `idx [L]` of `t [n, c]` → `[L, c]` (repeats allowed).
///
/// On the CPU (flex) Burn's `select`. Elsewhere `gather` with the index repeated over the
/// columns: its gradient is a scatter-add that runs one GPU thread per value (atomic adds),
/// where `select`'s gradient (`select_assign`) runs one thread per column, serially over all
/// L rows: an idle GPU, and on Mesa's lavapipe, whose loops stop after 65,535 iterations,
/// every row past the 65,535th silently lost.
pub fn gather_rows(t: Tensor<2>, idx: Tensor<1, Int>) -> Tensor<2> {
    if on_flex(&t) {
        return t.select(0, idx);
    }
    let [l] = idx.dims();
    let c = t.dims()[1];
    t.gather(0, idx.reshape([l, 1]).expand([l, c]))
}

/// `base [n, c]` with `values [L, c]` added into rows `idx [L]` (repeats add up): Burn's
/// `select_assign` on the CPU (flex), `scatter` elsewhere (see [`gather_rows`]).
pub fn add_rows(base: Tensor<2>, idx: Tensor<1, Int>, values: Tensor<2>) -> Tensor<2> {
    if on_flex(&base) {
        return base.select_assign(0, idx, values, IndexingUpdateOp::Add);
    }
    let [l, c] = values.dims();
    let idx = idx.reshape([l, 1]).expand([l, c]);
    base.scatter(0, idx, values, IndexingUpdateOp::Add)
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

/// A `[N, 3]` float tensor of points on `device`.
pub fn points_tensor(points: &[[f32; 3]], device: &Device) -> Tensor<2> {
    Tensor::from_data(
        TensorData::new(points.as_flattened().to_vec(), [points.len(), 3]),
        device,
    )
}

/// Host copy of a `[N, 3]` float tensor (any float dtype, converted to f32).
///
/// # Panics
/// When the tensor is not `[N, 3]` or cannot be read back (a programming error).
pub fn tensor_points(t: &Tensor<2>) -> Vec<[f32; 3]> {
    assert_eq!(
        t.dims()[1],
        3,
        "expected a [N, 3] tensor, got {:?}",
        t.dims()
    );
    let v = t
        .clone()
        .try_into_vec_as::<f32>()
        .expect("float tensor data");
    v.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn round_trip() {
        let device = crate::device::cpu();
        let p = vec![[1.0, -2.0, 3.5], [0.25, 0.0, -7.0]];
        let t = points_tensor(&p, &device);
        assert_eq!(t.dims(), [2, 3]);
        assert_eq!(tensor_points(&t), p);
        assert!(tensor_points(&points_tensor(&[], &device)).is_empty());
    }
}
