//! `mesh`: the fluid surface of every frame of a particle sequence — a scene's ground truth
//! (`particles/*.npz`) or an evaluation's rollouts (`eval/particles/*.ply`) — as OBJ or PLY
//! meshes, for Blender or ParaView.

use std::collections::{HashMap, HashSet};
use std::path::{Path, PathBuf};

use anyhow::Context;
use neurofluid_core::scene::Particles;

use neurofluid_outputs::formats::ply::read_ply;
use neurofluid_outputs::geometry::mesh::{SurfaceSettings, reconstruct};

/// Mesh formats.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum MeshFormat {
    /// Wavefront OBJ (text).
    Obj,
    /// Binary little-endian PLY.
    Ply,
}

/// Arguments of `mesh`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// Particle files (`.ply` or `.npz`), or folders of them (each file is one frame).
    #[arg(required = true)]
    pub inputs: Vec<PathBuf>,
    /// Output folder (one mesh per input file, same stem).
    #[arg(long)]
    pub output: PathBuf,
    /// Particle radius (the built-in scenes' and NeuroFluid's: 0.025).
    #[arg(long, default_value_t = 0.025)]
    pub radius: f32,
    /// Mesh format.
    #[arg(long, value_enum, default_value_t = MeshFormat::Obj)]
    pub format: MeshFormat,
    /// Reconstruction settings.
    #[command(flatten)]
    pub surface: SurfaceSettings,
}

fn particle_files(inputs: &[PathBuf]) -> anyhow::Result<Vec<PathBuf>> {
    let mut files = Vec::new();
    for input in inputs {
        if input.is_dir() {
            let mut found: Vec<PathBuf> = std::fs::read_dir(input)
                .with_context(|| format!("reading {}", input.display()))?
                .filter_map(|e| e.ok().map(|e| e.path()))
                .filter(|p| p.extension().is_some_and(|e| e == "ply" || e == "npz"))
                .collect();
            found.sort();
            anyhow::ensure!(
                !found.is_empty(),
                "{}: no .ply or .npz particle files",
                input.display()
            );
            files.extend(found);
        } else {
            // anything but a folder is read as a file: its reader refuses what is not one
            anyhow::ensure!(input.exists(), "{}: no such file", input.display());
            files.push(input.clone());
        }
    }
    Ok(files)
}

fn positions(path: &Path) -> anyhow::Result<Vec<[f32; 3]>> {
    match path.extension().and_then(|e| e.to_str()) {
        Some("ply") => Ok(read_ply(path)?.positions),
        Some("npz") => Ok(Particles::read(path)?.pos),
        _ => anyhow::bail!("{}: expected a .ply or .npz particle file", path.display()),
    }
}

/// The mesh of each file (`output/<stem>.<ext>`), checked before any is written: no mesh may
/// replace an input file, and no two inputs may share a stem (one mesh would replace the other).
fn output_paths(files: &[PathBuf], output: &Path, ext: &str) -> anyhow::Result<Vec<PathBuf>> {
    let out_dir = output
        .canonicalize()
        .unwrap_or_else(|_| output.to_path_buf());
    let inputs: HashSet<PathBuf> = files.iter().filter_map(|f| f.canonicalize().ok()).collect();
    let mut seen: HashMap<PathBuf, &Path> = HashMap::new();
    let mut paths = Vec::with_capacity(files.len());
    for file in files {
        let stem = file.file_stem().context("a file name")?.to_string_lossy();
        let name = format!("{stem}.{ext}");
        let path = output.join(&name);
        let key = out_dir.join(&name);
        anyhow::ensure!(
            !inputs.contains(&key),
            "the mesh of {} would replace the input file {}: choose another --output folder",
            file.display(),
            path.display()
        );
        if let Some(other) = seen.insert(key, file) {
            anyhow::bail!(
                "{} and {} have the same stem: both meshes would be {}; mesh them into \
                 separate --output folders",
                other.display(),
                file.display(),
                path.display()
            );
        }
        paths.push(path);
    }
    Ok(paths)
}

/// Writes one mesh per particle file.
pub fn run(args: Args) -> anyhow::Result<()> {
    let files = particle_files(&args.inputs)?;
    let ext = match args.format {
        MeshFormat::Obj => "obj",
        MeshFormat::Ply => "ply",
    };
    args.surface.check()?;
    let outputs = output_paths(&files, &args.output, ext)?;
    let bar = indicatif::ProgressBar::new(files.len() as u64).with_prefix("mesh");
    for (file, output) in files.iter().zip(&outputs) {
        let pos = positions(file)?;
        let mesh = reconstruct(&pos, args.radius, &args.surface)
            .with_context(|| format!("meshing {}", file.display()))?;
        mesh.write(output)?;
        bar.inc(1);
    }
    bar.finish_and_clear();
    println!("{} meshes in {}", files.len(), args.output.display());
    Ok(())
}
