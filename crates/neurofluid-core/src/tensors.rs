//! Moving point sets between the host (`[[f32; 3]]`) and Burn tensors (`[N, 3]`), and sums of
//! every element that give the same bits on every run.

use burn::prelude::*;

/// A `[N, 3]` float tensor of points on `device`.
pub fn points_tensor(points: &[[f32; 3]], device: &Device) -> Tensor<2> {
    crate::transfer::upload(
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
    let v: Vec<f32> = crate::transfer::read_vec(t.clone()).expect("float tensor data");
    v.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect()
}

/// `x [m, c]` with zero rows appended up to `rows` (≥ m); `x` itself when it has them.
pub fn with_zero_rows(x: Tensor<2>, rows: usize) -> Tensor<2> {
    let [m, c] = x.dims();
    if rows == m {
        return x;
    }
    let zeros = Tensor::<2>::zeros([rows - m, c], (&x.device(), x.dtype()));
    Tensor::cat(vec![x, zeros], 0)
}

/// The longest run of elements [`sum_all`] sums along one dimension at once.
pub const SUM_BLOCK: usize = 1 << 16;

/// The sum of every element of `t` as `[1]`, the same bits on every run on every backend: sums
/// along one dimension, in blocks of at most [`SUM_BLOCK`] elements (the last padded with zeros)
/// whose sums are then summed. Burn's whole-tensor `sum` (and `mean`) on the cubecl backends
/// without autotune adds each workgroup's part into the result with atomic adds, in whatever
/// order the workgroups finish; and on Mesa's lavapipe a sum along a dimension of a million
/// elements came out wrong, one of 256,000 right (its loops stop after 65,535 iterations; BENCHMARKS.md,
/// "Issue 30: kernel launches per step").
pub fn sum_all<const D: usize>(t: Tensor<D>) -> Tensor<1> {
    let n = t.shape().num_elements();
    if n <= SUM_BLOCK {
        return t.reshape([1, n]).sum_dim(1).reshape([1]);
    }
    let blocks = n.div_ceil(SUM_BLOCK);
    with_zero_rows(t.reshape([n, 1]), blocks * SUM_BLOCK)
        .reshape([blocks, SUM_BLOCK])
        .sum_dim(1)
        .reshape([1, blocks])
        .sum_dim(1)
        .reshape([1])
}

/// The mean of every element of `t` as `[1]`, the same bits on every run (see [`sum_all`]).
pub fn mean_all<const D: usize>(t: Tensor<D>) -> Tensor<1> {
    let n = t.shape().num_elements();
    if n <= SUM_BLOCK {
        return t.reshape([1, n]).mean_dim(1).reshape([1]);
    }
    // divided by a tensor: Burn's autodiff rounds a scalar divisor to f32 in the backward pass
    let sum = sum_all(t);
    sum.clone() / sum.full_like(n as f64)
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
