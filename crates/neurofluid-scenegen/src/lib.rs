//! Built-in benchmark scenes for NeuroFluid-rs: a DFSPH fluid simulation in a closed box
//! ([`sph`]), DLF-density wall particles ([`walls`]), initial fluid bodies ([`shapes`]), a CPU
//! surface renderer ([`render`]) and the generator that writes NeuroFluid's scene layout
//! ([`generate`]) for the paper's scenes ([`presets`]), configured by a `[scene]` TOML table
//! ([`config`]); [`warmup`] adds the warm-up views at every training frame to a generated scene.

pub mod config;
pub mod generate;
pub mod presets;
pub mod preview;
pub mod render;
pub mod shapes;
pub mod sph;
pub mod walls;
pub mod warmup;

pub use config::{Scale, SceneConfig, SceneKind};
pub use generate::{Report, Simulation, generate, simulate};
pub use presets::Preset;
pub use warmup::{WarmupReport, render_warmup_frames};
