//! Where an experiment's scene comes from: an existing folder, or a built-in scene generated on
//! first use.

use std::path::{Path, PathBuf};

use anyhow::Context;
use neurofluid_core::scene::{MANIFEST_FILE, Role, SceneManifest};
use neurofluid_scenegen::{Preset, SceneConfig};

use crate::config::Experiment;
use neurofluid_core::folder_lock::FolderLock;

/// The generator settings of an experiment's `[scene]` (`None` when it names an existing folder).
pub fn generator_config(exp: &Experiment) -> anyhow::Result<Option<SceneConfig>> {
    let Some(table) = exp.scene.generator_table() else {
        return Ok(None);
    };
    let cfg: SceneConfig = toml::Value::Table(table)
        .try_into()
        .context("the experiment's [scene] / [scene.generate] settings")?;
    cfg.validate(std::path::Path::new("the experiment's [scene]"))?;
    Ok(Some(cfg))
}

/// The scene folder of an experiment; a built-in scene is generated first when its folder holds
/// none.
pub fn generate_scene_if_missing(exp: &Experiment) -> anyhow::Result<PathBuf> {
    let dir = exp.scene.scene_dir();
    match generator_config(exp)? {
        None => {
            anyhow::ensure!(
                dir.is_dir(),
                "scene folder {} (scene.path) does not exist",
                dir.display()
            );
        }
        Some(cfg) => {
            let preset = Preset::resolve(&cfg);
            // runs sharing a scene (a sweep's array tasks) generate it once: the others wait
            let _lock = if dir.join(MANIFEST_FILE).is_file() {
                None
            } else {
                Some(FolderLock::wait(&dir)?)
            };
            if !dir.join(MANIFEST_FILE).is_file() {
                tracing::info!(
                    "generating the built-in scene {} ({}) into {}",
                    cfg.name.name(),
                    cfg.scale.name(),
                    dir.display()
                );
                let report = neurofluid_scenegen::generate(&preset, &dir, true)
                    .with_context(|| format!("generating the scene into {}", dir.display()))?;
                tracing::info!(
                    particles = report.particles,
                    frames = report.frames,
                    images = report.images,
                    seconds = report.simulate_s + report.render_s + report.write_s,
                    "scene generated"
                );
            } else if let Some(recorded) = recorded_generator(&dir)?
                && let changes = preset.changes_from(&recorded)
                && !changes.is_empty()
            {
                anyhow::bail!(
                    "the scene in {} was generated with other settings ({}): the experiment's \
                     [scene] / [scene.generate] settings no longer describe it. Put them back, \
                     or move the folder away (or set scene.dir) to generate the scene anew",
                    dir.display(),
                    changes.join(", ")
                );
            } else if cfg.validation_views == Some(true)
                && let Ok(scene) = neurofluid_core::scene::Scene::open(&dir)
                && scene.views(Role::Validation).is_empty()
            {
                // a scene generated before its validation views were asked for: generated again
                // with them (every other file comes out the same; the warm-up views at every
                // frame kept where it has them)
                let _lock = FolderLock::wait(&dir)?;
                let preset = Preset {
                    warmup_every_frame: preset.warmup_every_frame || has_warmup_every_frame(&scene),
                    ..preset
                };
                tracing::info!("the scene lacks validation views: generating it again with them");
                neurofluid_scenegen::generate(&preset, &dir, true)
                    .with_context(|| format!("adding the validation views to {}", dir.display()))?;
            } else if cfg.warmup_every_frame == Some(true)
                && neurofluid_core::scene::Scene::open(&dir)
                    .is_ok_and(|s| !has_warmup_every_frame(&s))
            {
                // a scene generated before the warm-up views were asked for at every frame: its
                // stored particles are rendered from those views (nothing is simulated again)
                tracing::info!("the scene lacks warm-up views at every frame: rendering them");
                neurofluid_scenegen::render_warmup_frames(&preset, &dir, true).with_context(
                    || {
                        format!(
                            "adding the warm-up views at every frame to {}",
                            dir.display()
                        )
                    },
                )?;
            }
        }
    }
    Ok(dir)
}

/// Whether `scene` has its warm-up views at every training frame (not at frame 0 only).
fn has_warmup_every_frame(scene: &neurofluid_core::scene::Scene) -> bool {
    scene.frames(Role::Warmup).len() >= scene.frames(Role::Train).len()
}

/// The generator settings a generated scene's manifest records (`None` for a scene without).
fn recorded_generator(dir: &Path) -> anyhow::Result<Option<serde_json::Value>> {
    let path = dir.join(MANIFEST_FILE);
    let manifest = SceneManifest::read(&path)?;
    Ok(manifest.generator)
}
