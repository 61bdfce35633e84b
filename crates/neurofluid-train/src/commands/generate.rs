//! `neurofluid-train generate`: writes a built-in scene (simulation + renders) in NeuroFluid's
//! layout, from an experiment TOML's `[scene]` table or from flags.

use std::path::PathBuf;

use anyhow::{Context, bail};
use neurofluid_scenegen::{Preset, Scale, SceneConfig, SceneKind, generate, preview};

/// Arguments of `generate`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// Experiment TOML holding a `[scene]` table (name, scale, seed, out, overrides).
    pub experiment: Option<PathBuf>,
    /// Scene to generate: watercube, watersphere, honeycone, waterbunny (overrides the TOML).
    #[arg(long)]
    pub scene: Option<String>,
    /// Generate all four scenes, each into `<out>/<name>_<scale>` (out defaults to `data`).
    #[arg(long, conflicts_with = "scene")]
    pub all: bool,
    /// Scale: quick (default) or paper (overrides the TOML).
    #[arg(long)]
    pub scale: Option<String>,
    /// Seed (overrides the TOML).
    #[arg(long)]
    pub seed: Option<u64>,
    /// Output directory (overrides the TOML; default `data/<name>_<scale>`).
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Also write a contact-sheet PNG of each scene into this directory (`<name>_<scale>.png`).
    #[arg(long)]
    pub preview: Option<PathBuf>,
    /// Hide the progress bars.
    #[arg(long)]
    pub no_progress: bool,
}

fn configs(args: &Args) -> anyhow::Result<Vec<SceneConfig>> {
    let mut base = match &args.experiment {
        Some(path) => {
            let exp = crate::config::Experiment::load(path)?;
            let cfg = crate::stages::scene_source::generator_config(&exp)?.with_context(|| {
                format!(
                    "{}: [scene] names an existing folder (scene.path); there is nothing to generate",
                    path.display()
                )
            })?;
            Some(cfg)
        }
        None => None,
    };
    let scale = match &args.scale {
        Some(s) => {
            Some(Scale::parse(s).with_context(|| format!("--scale {s}: expected quick or paper"))?)
        }
        None => None,
    };
    let kinds: Vec<SceneKind> = if args.all {
        SceneKind::ALL.to_vec()
    } else if let Some(s) = &args.scene {
        vec![SceneKind::parse(s).with_context(|| {
            format!("--scene {s}: expected watercube, watersphere, honeycone or waterbunny")
        })?]
    } else if let Some(b) = &base {
        vec![b.name]
    } else {
        bail!("give an experiment TOML with a [scene] table, --scene NAME or --all");
    };
    let mut out = Vec::new();
    for kind in kinds {
        let mut cfg = match base.take() {
            Some(mut b) => {
                b.name = kind;
                b
            }
            None => SceneConfig::new(kind, Scale::Quick),
        };
        if let Some(s) = scale {
            cfg.scale = s;
        }
        if let Some(seed) = args.seed {
            cfg.seed = seed;
        }
        if args.all {
            let parent = args.out.clone().unwrap_or_else(|| PathBuf::from("data"));
            cfg.out = Some(parent.join(format!("{}_{}", kind.name(), cfg.scale.name())));
        } else if let Some(o) = &args.out {
            cfg.out = Some(o.clone());
        }
        base = Some(cfg.clone());
        out.push(cfg);
    }
    Ok(out)
}

/// Generates the requested scene(s).
pub fn run(args: Args) -> anyhow::Result<()> {
    for cfg in configs(&args)? {
        let preset = Preset::resolve(&cfg);
        let dir = cfg.out_dir();
        let r = generate::generate(&preset, &dir, !args.no_progress)
            .with_context(|| format!("generating {} ({})", cfg.name.name(), cfg.scale.name()))?;
        println!("{} ({}): {r}", cfg.name.name(), cfg.scale.name());
        if let Some(pdir) = &args.preview {
            let png = pdir.join(format!("{}_{}.png", cfg.name.name(), cfg.scale.name()));
            preview::contact_sheet(&dir, &png)
                .with_context(|| format!("writing {}", png.display()))?;
            println!("preview → {}", png.display());
        }
    }
    Ok(())
}
