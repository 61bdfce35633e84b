//! The float types the host kernels run in (f32 for training, f64 for gradient checks) and the
//! vector helpers they share.

use std::ops::AddAssign;

use rayon::prelude::*;

/// A float type of the host kernels (dense layers, DLF's sparse convolution).
pub trait Real:
    Copy
    + Default
    + Send
    + Sync
    + PartialOrd
    + AddAssign
    + num_traits::Num
    + bytemuck::Pod
    + burn::tensor::Element
{
    /// `2^l`, exactly.
    fn of_power_of_two(l: usize) -> Self;
    /// `(sin x, cos x)`, each as the standard library computes it.
    fn sin_cos(self) -> (Self, Self);
}

macro_rules! impl_real {
    ($t:ty) => {
        impl Real for $t {
            fn of_power_of_two(l: usize) -> Self {
                (1u64 << l) as $t
            }
            #[inline]
            fn sin_cos(self) -> (Self, Self) {
                (self.sin(), self.cos())
            }
        }
    };
}
impl_real!(f32);
impl_real!(f64);

/// `len` zeros written by rayon's threads: a large output buffer is cleared (and its pages
/// touched) in parallel rather than on the calling thread before the parallel work starts.
pub fn par_zeros<T: Real>(len: usize) -> Vec<T> {
    let mut v = Vec::with_capacity(len);
    v.par_extend(rayon::iter::repeat_n(T::zero(), len));
    v
}

/// `dst += s·src`.
pub fn axpy<T: Real>(dst: &mut [T], s: T, src: &[T]) {
    for (d, &x) in dst.iter_mut().zip(src) {
        *d += s * x;
    }
}

/// `Σ a·b` in eight lanes, added at the end (an order the compiler vectorises without
/// reassociating; fixed by the length alone).
pub fn dot_in_lanes<T: Real>(a: &[T], b: &[T]) -> T {
    let mut lanes = [T::zero(); 8];
    let (a8, a_rest) = a.split_at(a.len() / 8 * 8);
    let (b8, b_rest) = b.split_at(a8.len());
    for (ca, cb) in a8.chunks_exact(8).zip(b8.chunks_exact(8)) {
        for l in 0..8 {
            lanes[l] += ca[l] * cb[l];
        }
    }
    let mut sum = lanes.iter().fold(T::zero(), |s, &v| s + v);
    for (&x, &y) in a_rest.iter().zip(b_rest) {
        sum += x * y;
    }
    sum
}
