//! `neurofluid-train info <scene dir>`: a summary of a scene in NeuroFluid's layout (generated
//! or released): particle count, frames, views, image size, box bounds, up axis.

use std::path::PathBuf;

use anyhow::Context;
use neurofluid_core::scene::{Role, Scene};

/// Arguments of `info`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// The scene directory.
    pub dir: PathBuf,
}

/// Prints the summary.
pub fn run(args: Args) -> anyhow::Result<()> {
    let scene =
        Scene::open(&args.dir).with_context(|| format!("opening scene {}", args.dir.display()))?;
    let m = scene.manifest();
    println!("scene        {} ({})", m.name, scene.root().display());
    println!(
        "manifest     {}",
        if scene.has_manifest_file() {
            "scene.json"
        } else {
            "none (released-layout defaults)"
        }
    );
    println!(
        "up axis      {:?} (gravity {:?})",
        m.up_axis,
        m.up_axis.gravity()
    );
    println!("radius       {} m, {} fps", m.particle_radius, m.fps);
    let t0 = scene.frames(Role::Train).start;
    match scene.particles(Role::Train, t0) {
        Ok(p) => println!("particles    {} (train frame {t0})", p.len()),
        Err(e) => println!("particles    unavailable: {e}"),
    }
    let roles = [
        ("warm-up", Role::Warmup),
        ("train", Role::Train),
        ("test", Role::Test),
        ("validation", Role::Validation),
    ];
    for (label, role) in roles
        .into_iter()
        .filter(|&(_, r)| !scene.views(r).is_empty())
    {
        let r = scene.frames(role);
        let views = scene.views(role);
        let sizes: Vec<String> = views
            .iter()
            .filter_map(|v| scene.view_split(role, v).ok())
            .map(|vs| {
                let fx = vs.camera(r.start).map_or(f32::NAN, |c| c.fx);
                format!(
                    "{} {}×{} f_x {fx:.1} px",
                    vs.view, vs.image_size.0, vs.image_size.1
                )
            })
            .collect();
        println!(
            "{label:<12} split `{}`, frames {}..{} ({}), views: {}",
            m.role(role).split,
            r.start,
            r.end,
            r.len(),
            sizes.join(", ")
        );
    }
    match scene.boundary() {
        Ok(b) => {
            let (lo, hi) = b.bounds().unwrap_or(([0.0; 3], [0.0; 3]));
            println!(
                "box          {} wall particles, bounds {lo:?} .. {hi:?}",
                b.len()
            );
        }
        Err(e) => println!("box          unavailable: {e}"),
    }
    println!(
        "interior     {:?} .. {:?}",
        m.box_interior.min, m.box_interior.max
    );
    println!("near/far     {} / {}", m.near, m.far);
    Ok(())
}
