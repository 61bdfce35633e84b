//! The project's own kernels' buffers as Burn tensors and back, on the cubecl backends (wgpu,
//! CUDA), without a copy through the host.
//!
//! Burn's cubecl backend runs under its fusion layer here (the `wgpu-base` and `cuda` features
//! turn fusion on), so a buffer written by a kernel becomes a tensor the way Burn's own
//! `from_data` makes one: the buffer is registered with the fusion client as an initialised
//! tensor. A tensor becomes a buffer by resolving it (its queued operations run first) and
//! making it contiguous.

use burn::backend::Cube;
use burn::backend::tensor::{FloatTensor, IntTensor};
use burn::prelude::*;
use burn::tensor::{DType, Shape};
use burn_cubecl::CubeBackend;
use burn_cubecl::tensor::CubeTensor;
use burn_fusion::stream::StreamId;
use burn_fusion::{FusionBackend, NoOp, get_client};
use burn_ir::{BackendIr, InitOperationIr, OperationIr};
use cubecl::ir::ElemType;
use cubecl::prelude::{Scalar, TensorArg};
use cubecl::server::Handle;
use cubecl::std::tensor::TensorHandle;

type FusionTensor = burn_fusion::FusionTensor<<CubeBackend as FusionBackend>::FusionRuntime>;

/// A buffer of `shape`'s elements of `dtype` on `device`, registered with the fusion client as
/// an initialised tensor (as Burn's `from_data` does after its upload).
fn init(device: &cubecl::Device, handle: Handle, shape: Shape, dtype: DType) -> FusionTensor {
    let tensor = CubeTensor::new_contiguous(
        device.client(),
        device.clone(),
        shape.clone(),
        handle,
        dtype,
    );
    let client = get_client::<CubeBackend>(device);
    let handle = CubeBackend::float_tensor_handle(tensor);
    let desc = InitOperationIr::create(shape, dtype, || client.register_tensor_handle(handle));
    client
        .register(
            StreamId::current(),
            OperationIr::Init(desc),
            NoOp::<CubeBackend>::new(),
        )
        .into_iter()
        .next()
        .expect("an initialised tensor")
}

/// The float32 buffer `handle` (`shape`, row-major) on `device` as a tensor.
pub fn float_tensor<const D: usize>(
    device: &cubecl::Device,
    handle: Handle,
    shape: [usize; D],
) -> Tensor<D> {
    let p: FloatTensor<Cube> = init(device, handle, Shape::from(shape), DType::F32);
    Tensor::<D>::from_primitive::<Cube>(p)
}

/// The int32 buffer `handle` (`shape`, row-major) on `device` as an int tensor.
pub fn int_tensor<const D: usize>(
    device: &cubecl::Device,
    handle: Handle,
    shape: [usize; D],
) -> Tensor<D, Int> {
    let p: IntTensor<Cube> = init(device, handle, Shape::from(shape), DType::I32);
    Tensor::<D, Int>::from_primitive::<Cube>(p)
}

/// The buffer under an untracked float tensor of the cubecl backend, contiguous, with its
/// dtype; `None` for another backend or a tracked tensor.
pub fn float_buffer<const D: usize>(t: Tensor<D>) -> Option<CubeTensor> {
    let p: FloatTensor<Cube> = t.try_into_primitive::<Cube>().ok()?;
    let client = p.client.clone();
    let resolved = client.resolve_tensor_float::<CubeBackend>(p);
    Some(burn_cubecl::kernel::into_contiguous(resolved))
}

/// The cubecl device under a Burn device (autodiff unwrapped); `None` for other backends.
pub fn cube_device(device: &Device) -> Option<cubecl::Device> {
    match device.clone().without_autodiff().as_dispatch() {
        burn::backend::DispatchDevice::Cube(d) => Some(d.clone()),
        #[allow(unreachable_patterns)]
        _ => None,
    }
}

/// A kernel argument over the first `len` elements of `dtype` in `handle`, contiguous.
pub fn arg(handle: &Handle, len: usize, dtype: ElemType) -> TensorArg {
    TensorHandle::new_contiguous([len], handle.clone(), dtype).into_arg()
}

/// [`arg`] for float32 elements.
pub fn f32_arg(handle: &Handle, len: usize) -> TensorArg {
    arg(handle, len, f32::elem_type_native())
}
