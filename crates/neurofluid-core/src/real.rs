//! The float types the host kernels run in: f32 for training, f64 for gradient checks.

use std::ops::AddAssign;

/// A float type of the host kernels (dense layers, DLF's sparse convolution).
pub trait Real:
    Copy
    + Default
    + Send
    + Sync
    + PartialOrd
    + AddAssign
    + ndarray::LinalgScalar
    + bytemuck::Pod
    + burn::tensor::Element
{
}

impl Real for f32 {}
impl Real for f64 {}
