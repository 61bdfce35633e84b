//! `physnerf-case`: render a PhysNeRF reference case file (particles, camera, targets in it)
//! with its weights, and write the same keys as the reference (`rays/*`, `coarse/*`, `fine/*`,
//! `loss/*`, `grad/*`, `gradnorm/values`) so the case can be compared from the command line.

use std::path::PathBuf;

use crate::physnerf_case::run_case_file;
use anyhow::Context;
use burn::tensor::DType;
use neurofluid_core::device::{float64_supported, parse_device};

/// Arguments of `physnerf-case`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// The case file (`.safetensors` made by `physnerf_reference.py make-case`).
    #[arg(long)]
    pub case: PathBuf,
    /// Where to write the outputs (`.safetensors`).
    #[arg(long)]
    pub output: PathBuf,
    /// Weights file; default: the case's `<stem>_weights.safetensors` sibling.
    #[arg(long)]
    pub weights: Option<PathBuf>,
    /// Compute in float64 (compare with the case's `f64/` keys) instead of float32.
    #[arg(long)]
    pub f64: bool,
    /// Device (cpu, flex, ndarray, wgpu, cuda).
    #[arg(long, default_value = "cpu")]
    pub device: String,
}

/// Runs the case and writes the outputs.
pub fn run(args: Args) -> anyhow::Result<()> {
    let device = parse_device(&args.device)?;
    let dtype = if args.f64 { DType::F64 } else { DType::F32 };
    anyhow::ensure!(
        !args.f64 || float64_supported(&args.device),
        "--f64: device {} has no exact float64 (wgpu's shaders have no 64-bit exp, log, sin or \
         cos); run the float64 case on the cpu",
        args.device
    );
    let t0 = std::time::Instant::now();
    let out = run_case_file(
        &args.case,
        args.weights.as_deref(),
        &args.output,
        &device,
        dtype,
    )
    .with_context(|| format!("rendering case {}", args.case.display()))?;
    tracing::info!(
        "{}: loss {:.9} (coarse {:.9}, fine {:.9}) in {:.1} s, wrote {}",
        args.case.display(),
        out.float("loss/value")[0],
        out.float("loss/mse_coarse")[0],
        out.float("loss/mse_fine")[0],
        t0.elapsed().as_secs_f64(),
        args.output.display()
    );
    Ok(())
}
