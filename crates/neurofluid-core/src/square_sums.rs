//! The sum of the squares of each of many tensors (a step's gradients, for their norms): on the
//! cubecl backends one kernel for a group of tensors where a reduction per tensor took one launch
//! each (48 for PhysNeRF's two networks, every training step); elsewhere
//! [`crate::tensors::sum_all`] of each square, as before.
//!
//! In the kernel each tensor of a group is summed by one workgroup of [`UNITS`] units: unit `u`
//! adds the squares of elements `u`, `u + 256`, … in order, then the units' partial sums are added
//! in a fixed tree in shared memory (unit `u` takes `u + h` for h = 128, 64, …, 1). No atomic
//! adds: the same bits on every run. A group holds what the device binds in one kernel (its
//! storage buffers less the output and the metadata: 29 tensors on Mesa's lavapipe), at most
//! [`MOST_PER_GROUP`].

use burn::prelude::*;

/// Units of the workgroup that sums one tensor.
pub const UNITS: usize = 256;

/// The most tensors one kernel sums (each is a branch of the kernel's code).
pub const MOST_PER_GROUP: usize = 64;

/// The sum of the squares of each tensor's elements, in order, on the tensors' device: tensors
/// whose values, read back one after the other ([`crate::transfer::read_together`]), are one sum
/// per input (on a cubecl device one tensor per group; elsewhere a `[1]` tensor per input).
pub fn square_sums(tensors: Vec<Tensor<1>>) -> Vec<Tensor<1>> {
    #[cfg(feature = "gpu")]
    if let Some(sums) = kernel::square_sums(&tensors) {
        return sums;
    }
    tensors
        .into_iter()
        .map(|t| crate::tensors::sum_all(t.powi_scalar(2)))
        .collect()
}

/// The number of values [`square_sums`]' tensors hold (one per input tensor).
pub fn count(sums: &[Tensor<1>]) -> usize {
    sums.iter().map(|t| t.dims()[0]).sum()
}

#[cfg(feature = "gpu")]
mod kernel {
    use burn::prelude::Tensor as BurnTensor;
    use burn::tensor::DType;
    use cubecl::prelude::*;

    use super::{MOST_PER_GROUP, UNITS};
    use crate::cube_tensor::{self, f32_arg};

    /// Workgroup `c` sums the squares of `tensors[c]` into `out[c]` (see the module docs).
    #[cube(launch)]
    fn square_sums_kernel(tensors: &Sequence<OwnedTensor<f32>>, out: &mut Tensor<f32>) {
        let mut partial = Shared::<[f32]>::new_slice(comptime![UNITS]);
        let unit = UNIT_POS as usize;
        let units = CUBE_DIM as usize;
        let count = tensors.len().comptime();
        let mut acc = 0.0f32;
        #[unroll]
        for i in 0..count {
            if CUBE_POS == i {
                let t = tensors.index(i);
                let len = t.len();
                let rounds = len.div_ceil(units);
                for r in 0..rounds {
                    let j = r * units + unit;
                    if j < len {
                        let v = t[j];
                        acc += v * v;
                    }
                }
            }
        }
        partial[unit] = acc;
        sync_cube();
        let mut half = units / 2;
        while half > 0 {
            if unit < half {
                let other = partial[unit + half];
                partial[unit] += other;
            }
            half /= 2;
            sync_cube();
        }
        if unit == 0 {
            out[CUBE_POS] = partial[0];
        }
    }

    /// The kernel's sums of `tensors` (untracked f32 tensors with elements, on one cubecl
    /// device); `None` where one is not, and nothing has been launched.
    pub(super) fn square_sums(tensors: &[BurnTensor<1>]) -> Option<Vec<BurnTensor<1>>> {
        let device = cube_tensor::cube_device(&tensors.first()?.device())?;
        if tensors
            .iter()
            .any(|t| t.dtype() != DType::F32 || t.dims()[0] == 0)
        {
            return None;
        }
        let buffers = tensors
            .iter()
            .map(|t| Some((cube_tensor::float_buffer(t.clone())?.handle, t.dims()[0])))
            .collect::<Option<Vec<_>>>()?;
        let client = device.client();
        // the output and the kernel's metadata take a binding each
        let per_group = (client.properties().hardware.max_bindings as usize)
            .saturating_sub(2)
            .clamp(1, MOST_PER_GROUP);
        Some(
            buffers
                .chunks(per_group)
                .map(|group| {
                    let out = client.empty(group.len() * 4);
                    let inputs: SequenceArg<OwnedTensor<f32>> =
                        group.iter().map(|(h, len)| f32_arg(h, *len)).collect();
                    square_sums_kernel::launch(
                        &client,
                        CubeCount::Static(group.len() as u32, 1, 1),
                        CubeDim::new_1d(UNITS as u32),
                        inputs,
                        f32_arg(&out, group.len()),
                    );
                    cube_tensor::float_tensor(&device, out, [group.len()])
                })
                .collect(),
        )
    }
}
