//! `devices`: which backends this build holds, and whether a device comes up.

use burn::prelude::Tensor;
use neurofluid_core::device::{compiled_backends, parse_device};

/// Arguments of `devices`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// Also run a tiny computation on this device (cpu, flex, ndarray, wgpu, cuda, cuda:N).
    #[arg(long)]
    pub probe: Option<String>,
}

/// Lists the compiled-in backends; with `--probe`, checks that a device computes.
pub fn run(args: Args) -> anyhow::Result<()> {
    println!("compiled-in backends: {}", compiled_backends().join(", "));
    println!(
        "choose one with --device (or `device = \"...\"` in the experiment TOML): cpu is the first CPU backend"
    );
    if let Some(name) = args.probe {
        let device = parse_device(&name)?;
        let x: Tensor<1> = neurofluid_core::transfer::upload([1.0f32, 2.0, 3.0], &device);
        let s = neurofluid_core::transfer::read_scalar(x.clone().mul(x).sum()) as f32;
        anyhow::ensure!(
            (s - 14.0).abs() < 1e-5,
            "device {name} computed 1²+2²+3² = {s}"
        );
        println!("device {name}: {device:?} works (1²+2²+3² = {s})");
        if neurofluid_core::device::is_wgpu_name(&name)
            && let Some(shapes) = neurofluid_core::device::wgpu_tensor_core_shapes()
        {
            if shapes.is_empty() {
                println!("tensor cores: none offered (every matmul on the scalar kernel)");
            } else {
                println!(
                    "tensor cores (operands × operands → accumulator, m×n×k): {}; `matmul = \"f16\"` or \"bf16\" in the experiment uses them",
                    shapes.join(", ")
                );
            }
        }
    }
    Ok(())
}
