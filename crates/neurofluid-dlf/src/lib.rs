//! DLF (Deep Lagrangian Fluids, Ummenhofer et al. 2020) in Burn: the continuous convolution with
//! Open3D's semantics, the DLF network and integrator, weight import, the supervised loss and
//! training loop, and DLF's `.msgpack.zst` records.
//!
//! The geometry of a step (neighbour pairs, mapped coordinates, trilinear corners × window) is
//! built once, on the host or on the GPU ([`geometry`]), and shared by the four fluid convs;
//! each conv is then a gather/scatter and one matmul ([`ContinuousConv`]).

pub mod bodies;
pub mod config;
pub mod conv;
pub mod device_cells;
pub mod diff_geometry;
pub mod energy_cap;
pub mod fused;
pub mod geometry;
pub mod loss;
pub mod mapping;
pub mod net;
pub mod physics;
pub mod records;
pub mod rollout;
pub mod rules;
pub mod scene;
pub mod sparse;
pub mod train;
pub mod viscosity;
pub mod weights;

pub use config::{DlfConfig, Frame, GeometryMode};
pub use conv::ContinuousConv;
pub use geometry::{ConvGeometry, FILTER_EXTENT, HostGeometry, build_host_geometry};
pub use loss::{dlf_step_loss, two_step_loss};
pub use net::{Boundary, DlfNet, StepOutput, StepTrace};
pub use physics::{PHYSICS_NAMES, PhysicsValues};
pub use rules::{Containment, DissipationFrame, EnergyCap, RulesError, StepRules};
pub use weights::{WeightsError, load_checkpoint, load_dlf, save_checkpoint};
