//! Host slices of Burn's flex tensors, for the operations that run on the host with their own
//! backward pass (the dense layers, DLF's conv).

use burn::backend::flex::FlexTensor;
use burn::tensor::TensorData;

use crate::real::Real;

/// A contiguous tensor (a copy only when it is not one already).
pub fn contiguous(t: FlexTensor) -> FlexTensor {
    if t.layout().is_contiguous() && t.layout().start_offset() == 0 {
        t
    } else {
        t.to_contiguous()
    }
}

/// The values of a contiguous tensor of float type `T`.
///
/// # Panics
/// When the tensor is not contiguous or holds another type (callers check the dtype first).
pub fn slice<T: Real>(t: &FlexTensor) -> &[T] {
    t.as_slice::<T>()
        .expect("a contiguous tensor of the operation's float type")
}

/// A flex tensor of `v` with `shape`.
pub fn tensor<T: Real>(v: Vec<T>, shape: Vec<usize>) -> FlexTensor {
    FlexTensor::from_data(TensorData::new(v, shape))
}
