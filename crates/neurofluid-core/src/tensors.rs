//! Moving point sets between the host (`[[f32; 3]]`) and Burn tensors (`[N, 3]`).

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
