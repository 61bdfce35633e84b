//! Every copy between the host and a device, through one door each way, counted.
//!
//! On a GPU a read back to the host (`into_data`, `into_scalar`, …) waits for every queued
//! kernel and stalls the queue, and an upload is a copy over the bus; a training step that does
//! either many times a step keeps the GPU idle. So the project reads and uploads tensors only
//! through this module: [`read_vec`], [`read_data`], [`read_scalar`] (device → host) and
//! [`upload`] (host → device), which count the calls and the bytes. [`counts`] gives the running
//! totals; the step benchmarks and the trainer's metrics report the difference over a step.
//! The project's own kernels (`device_search`) move their buffers themselves and count them here.
//!
//! The counters are per thread (the thread that asked for the copy): a step runs on one thread,
//! and tests that run in parallel do not see each other's copies. The counts are the same on
//! every backend for the same code path; on the CPU backends a "read" is a host copy, cheap.
//! Kernel launches are not counted here: Burn 0.22 does not expose them; cubecl's launch log
//! does, and `scripts/kernel-launches.sh` counts them per step. Nor is the one move of a module's
//! initial weights from the CPU to the device (`device::init_seeded`), once per run.

use std::cell::Cell;

use burn::prelude::*;
use burn::tensor::kind::Basic;
use burn::tensor::{Element, TensorCreationOptions, TensorReadError};

/// Copies between host and device: how many and how many bytes, each way.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Counts {
    /// Device → host reads.
    pub reads: u64,
    /// Bytes read (the tensors' sizes in their own dtype).
    pub read_bytes: u64,
    /// Host → device uploads.
    pub uploads: u64,
    /// Bytes uploaded.
    pub upload_bytes: u64,
}

impl Counts {
    /// The copies made since `earlier` (an earlier [`counts`] of the same thread).
    pub fn since(self, earlier: Counts) -> Counts {
        Counts {
            reads: self.reads - earlier.reads,
            read_bytes: self.read_bytes - earlier.read_bytes,
            uploads: self.uploads - earlier.uploads,
            upload_bytes: self.upload_bytes - earlier.upload_bytes,
        }
    }

    /// The sum of two counts.
    pub fn plus(self, other: Counts) -> Counts {
        Counts {
            reads: self.reads + other.reads,
            read_bytes: self.read_bytes + other.read_bytes,
            uploads: self.uploads + other.uploads,
            upload_bytes: self.upload_bytes + other.upload_bytes,
        }
    }

    /// One line: `N reads (B bytes), M uploads (C bytes)`.
    pub fn describe(&self) -> String {
        format!(
            "{} reads ({}), {} uploads ({})",
            self.reads,
            bytes(self.read_bytes),
            self.uploads,
            bytes(self.upload_bytes)
        )
    }
}

/// A byte count in B, kB or MB (decimal).
fn bytes(n: u64) -> String {
    match n {
        0..1_000 => format!("{n} B"),
        1_000..1_000_000 => format!("{:.1} kB", n as f64 / 1e3),
        _ => format!("{:.2} MB", n as f64 / 1e6),
    }
}

thread_local! {
    static COUNTS: Cell<Counts> = const { Cell::new(Counts { reads: 0, read_bytes: 0, uploads: 0, upload_bytes: 0 }) };
}

/// The copies this thread has made so far.
pub fn counts() -> Counts {
    COUNTS.with(Cell::get)
}

fn add(f: impl FnOnce(&mut Counts)) {
    COUNTS.with(|c| {
        let mut v = c.get();
        f(&mut v);
        c.set(v);
    });
}

/// Counts one read of `bytes` made outside Burn's tensors (a cubecl kernel's own buffers),
/// logged at `trace` with the caller's place (`RUST_LOG=neurofluid_core::transfer=trace` lists
/// where a step's copies come from).
#[track_caller]
pub(crate) fn count_read(bytes: usize) {
    tracing::trace!(bytes, at = %std::panic::Location::caller(), "read");
    add(|c| {
        c.reads += 1;
        c.read_bytes += bytes as u64;
    });
}

/// Counts one upload of `bytes` made outside Burn's tensors (a cubecl kernel's own buffers),
/// logged at `trace` with the caller's place.
#[track_caller]
pub(crate) fn count_upload(bytes: usize) {
    tracing::trace!(bytes, at = %std::panic::Location::caller(), "upload");
    add(|c| {
        c.uploads += 1;
        c.upload_bytes += bytes as u64;
    });
}

/// The size of a tensor in bytes, in its own dtype.
fn size_of<const D: usize, K: Basic>(t: &Tensor<D, K>) -> usize {
    t.shape().num_elements() * t.dtype().size()
}

/// Device → host: the tensor's values as `E` (converted from its dtype), one read.
///
/// # Errors
/// When the backend cannot read the tensor or the values do not convert.
#[track_caller]
pub fn read_vec<E: Element, const D: usize, K: Basic>(
    t: Tensor<D, K>,
) -> Result<Vec<E>, TensorReadError> {
    count_read(size_of(&t));
    t.try_into_vec_as::<E>()
}

/// Device → host: the values of every tensor of `parts` as f64, one tensor after the other, in
/// one read (Burn's `Transaction`: one wait for the queue however many tensors; on a GPU no
/// kernel gathers them into one tensor first, which a concatenation of `n` parts costs `n`
/// launches).
///
/// # Errors
/// When the backend cannot read a tensor or the values do not convert.
#[track_caller]
pub fn read_together<const D: usize>(parts: Vec<Tensor<D>>) -> Result<Vec<f64>, TensorReadError> {
    count_read(parts.iter().map(size_of).sum());
    let transaction = parts
        .into_iter()
        // a transaction reads one backend's tensors: the graph's are read as their plain values
        .fold(burn::tensor::Transaction::default(), |t, p| {
            t.register(p.without_autodiff())
        });
    let mut values = Vec::new();
    for data in transaction.try_execute()? {
        values.extend(data.try_cast_as::<f64>()?.try_into_vec::<f64>()?);
    }
    Ok(values)
}

/// Device → host: the tensor's data in its own dtype, one read.
///
/// # Panics
/// When the backend cannot read the tensor (a device failure).
#[track_caller]
pub fn read_data<const D: usize, K: Basic>(t: Tensor<D, K>) -> TensorData {
    count_read(size_of(&t));
    t.into_data()
}

/// Device → host: the value of a one-element float tensor as f64 (the tensor's value converted
/// exactly from its dtype), one read.
///
/// # Panics
/// When the tensor has not exactly one element or cannot be read (a programming error).
#[track_caller]
pub fn read_scalar<const D: usize>(t: Tensor<D>) -> f64 {
    count_read(size_of(&t));
    t.into_scalar::<f64>()
}

/// Host → device: `data` as a tensor on the device (and dtype) `options` say, one upload.
#[track_caller]
pub fn upload<const D: usize, K: Basic, O: Into<TensorCreationOptions>>(
    data: impl Into<TensorData>,
    options: O,
) -> Tensor<D, K> {
    let data: TensorData = data.into();
    count_upload(data.as_bytes().len());
    Tensor::from_data(data, options)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn each_copy_is_counted_with_its_bytes() {
        let device = crate::device::cpu();
        let before = counts();
        let t: Tensor<2> = upload(
            TensorData::new(vec![1.0f32, 2.0, 3.0, 4.0], [2, 2]),
            &device,
        );
        let i: Tensor<1, Int> = upload(TensorData::new(vec![3i32, 1], [2]), &device);
        let after_uploads = counts().since(before);
        assert_eq!(after_uploads.uploads, 2);
        assert_eq!(after_uploads.upload_bytes, 16 + 8);
        assert_eq!(after_uploads.reads, 0);

        assert_eq!(
            read_vec::<f32, 2, burn::tensor::Float>(t.clone()).unwrap(),
            [1.0, 2.0, 3.0, 4.0]
        );
        assert_eq!(read_vec::<i64, 1, Int>(i).unwrap(), [3, 1]);
        assert_eq!(read_scalar(t.clone().sum()), 10.0);
        let data = read_data(t);
        assert_eq!(data.as_slice::<f32>().unwrap(), [1.0, 2.0, 3.0, 4.0]);
        let all = counts().since(before);
        assert_eq!(all.reads, 4);
        // 16 B of f32 twice, the index in the backend's int dtype, one f32
        let int_bytes = 2 * Tensor::<1, Int>::zeros([1], &device).dtype().size() as u64;
        assert_eq!(all.read_bytes, 16 + int_bytes + 4 + 16);
        assert_eq!(all.since(after_uploads).uploads, 0);
        assert!(
            all.describe().starts_with("4 reads ("),
            "{}",
            all.describe()
        );
    }

    /// Several tensors of different sizes and float types, with and without autodiff, read in one
    /// go: their values in order, one read of their bytes.
    #[test]
    fn tensors_read_together_are_one_read_in_order() {
        let device = crate::device::cpu();
        let f32s: Tensor<1> = upload(TensorData::new(vec![1.5f32, -2.0], [2]), &device);
        // a tensor of the autodiff graph among plain ones (a step's loss beside its gradients)
        let one: Tensor<1> = upload(
            TensorData::new(vec![0.25f32], [1]),
            &device.clone().autodiff(),
        );
        let one = one.require_grad() * 1.0;
        let f64s: Tensor<1> = upload(
            TensorData::new(vec![1e-300f64, 3.0, 4.0], [3]),
            (&device, burn::tensor::DType::F64),
        );
        let before = counts();
        let values = read_together(vec![f32s, one, f64s]).unwrap();
        assert_eq!(values, [1.5, -2.0, 0.25, 1e-300, 3.0, 4.0]);
        let read = counts().since(before);
        assert_eq!((read.reads, read.read_bytes), (1, 8 + 4 + 24));
        assert!(read_together(Vec::<Tensor<1>>::new()).unwrap().is_empty());
    }

    #[test]
    fn counts_are_per_thread() {
        let device = crate::device::cpu();
        let before = counts();
        std::thread::spawn(move || {
            let t: Tensor<1> = upload(TensorData::new(vec![1.0f32], [1]), &device);
            read_scalar(t);
        })
        .join()
        .unwrap();
        assert_eq!(counts().since(before), Counts::default());
    }
}
