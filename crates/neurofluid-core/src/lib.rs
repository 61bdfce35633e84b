//! Maths, geometry and IO shared by every NeuroFluid-rs crate: device choice, cameras and rays,
//! uniform-grid neighbour search, particle and image metrics, and `.npz` archives; and the
//! safety of a run's folder: one process per folder ([`folder_lock`]), sealed checkpoint files
//! ([`checksums`]) and stopping between steps on a signal ([`stop_request`]).
//!
//! Nothing here knows about the models or the trainer; dependencies point one way
//! (core ← dlf, physnerf ← train).

pub mod atomic;
pub mod camera;
pub mod checksums;
pub mod choice;
pub mod cpu_time;
#[cfg(feature = "gpu")]
pub mod cube_tensor;
pub mod dense;
pub mod device;
pub mod device_pairs;
pub mod device_search;
#[cfg(feature = "flex")]
pub mod flex_host;
pub mod folder_lock;
pub mod gradients;
pub mod half_matmul;
pub mod input_file;
pub mod io_error;
pub mod limits;
pub mod logging;
pub mod lr_schedule;
pub mod malloc;
pub mod matmul;
pub mod metrics;
pub mod neighbors;
pub mod npz;
pub mod params;
pub mod paths;
pub mod posenc;
pub mod program;
pub mod ray_focus;
pub mod real;
pub mod rows;
pub mod sampler;
pub mod scene;
pub mod square_sums;
pub mod stop_request;
pub mod tensors;
pub mod transfer;
