//! `render`: render a whole view of a PhysNeRF case (its particles, camera and weights) in ray
//! chunks with bounded memory, and save it as a PNG.

use std::path::PathBuf;

use crate::physnerf_case::{CaseInputs, load_case_model};
use anyhow::Context;
use burn::tensor::DType;
use indicatif::{ProgressBar, ProgressStyle};
use neurofluid_core::device::parse_device;
use neurofluid_physnerf::{render_image, save_png};

/// Arguments of `render`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// The case file holding particles and camera (`.safetensors` of `physnerf_reference.py`).
    #[arg(long)]
    pub case: PathBuf,
    /// Weights file; default: the case's `<stem>_weights.safetensors` sibling.
    #[arg(long)]
    pub weights: Option<PathBuf>,
    /// Output PNG.
    #[arg(long)]
    pub output: PathBuf,
    /// Image height and width (default: the case camera's); the field of view is kept.
    #[arg(long, num_args = 2, value_names = ["H", "W"])]
    pub hw: Option<Vec<u32>>,
    /// Rays per chunk (bounds the memory).
    #[arg(long, default_value_t = 1024)]
    pub chunk: usize,
    /// Write coarse | fine side by side instead of the fine render alone.
    #[arg(long)]
    pub side_by_side: bool,
    /// Device (cpu, flex, ndarray, wgpu, cuda).
    #[arg(long, default_value = "cpu")]
    pub device: String,
}

/// Renders the view and writes the PNG.
pub fn run(args: Args) -> anyhow::Result<()> {
    let device = parse_device(&args.device)?;
    let inputs = CaseInputs::load(&args.case)?;
    let hw = match args.hw.as_deref() {
        None => None,
        Some([h, w]) if *h > 0 && *w > 0 => Some([*h, *w]),
        Some(v) => anyhow::bail!("--hw needs two positive sizes H W, got {v:?}"),
    };
    let camera = inputs.camera(hw);
    let model = load_case_model(&inputs, args.weights.as_deref(), &device, DType::F32)
        .with_context(|| format!("loading the weights of {}", args.case.display()))?;
    let particles = inputs.particles_tensor(&device, DType::F32);
    let bar = ProgressBar::new(camera.num_pixels() as u64);
    bar.set_style(
        ProgressStyle::with_template("{msg} [{bar:40}] {pos}/{len} rays ({eta})")
            .expect("valid template"),
    );
    bar.set_message("rendering");
    let t0 = std::time::Instant::now();
    let image = render_image(&model, &camera, &particles, args.chunk, &mut |done, _| {
        bar.set_position(done as u64)
    })?;
    bar.finish_and_clear();
    let (w, h, rgb) = if args.side_by_side {
        image.side_by_side()
    } else {
        (image.width, image.height, image.best().to_vec())
    };
    save_png(&args.output, w, h, &rgb)?;
    tracing::info!(
        "rendered {}×{} in {:.1} s, wrote {}",
        camera.width,
        camera.height,
        t0.elapsed().as_secs_f64(),
        args.output.display()
    );
    Ok(())
}
