//! Evaluation (spec §6): from the ground-truth state of the first test frame, roll the grounded
//! transition model and the DLF it started from (the baseline) out without feedback, and report
//! the particle distance d (GT→prediction nearest neighbour, ×1000) per frame, its mean over the
//! grounding window (t = 1 … T_train−1) and the prediction window (t = T_train … T_test−1),
//! PSNR/SSIM/LPIPS of the renders of the held-out views, renders beside ground truth (PNG) and the
//! predicted particles of every frame (PLY).
//!
//! Its rooms: [`rollouts`] (the models' rollouts; what they are measured by is
//! [`neurofluid_outputs::sequences`]'s) and [`artifacts`] (what is written; images and
//! particle sets against the truth are [`neurofluid_outputs::scoring`]'s, shared with the
//! baselines). Imports go one way: this module → rollouts, artifacts.

pub mod artifacts;
pub mod rollouts;

use anyhow::Context;
use burn::module::Module;
use neurofluid_core::scene::Role;

pub use artifacts::{
    ANIMATIONS, DISTANCE_PLOT, INTERPOLATION_PLOT, VIEWER_FILE, particle_picture_path,
};

use super::joint::Grounded;
use super::run_folder::Run;
use crate::stage::Stage;
use neurofluid_outputs::report::{EvalReport, Windows};

/// Folder of the stage inside the run folder.
pub const STAGE: Stage = Stage::Eval;

/// Runs the evaluation, writes `eval/` and returns the report.
pub fn run(run: &Run, models: &Grounded) -> anyhow::Result<EvalReport> {
    let scene = &run.scene;
    let cfg = &run.exp.eval;
    let test = scene.frames(Role::Test);
    let train_len = scene.frames(Role::Train).len();
    let rollouts = rollouts::of(run, models)?;
    let mut report = EvalReport::new(
        &run.exp.name,
        &scene.manifest().name,
        &run.stage_dir(super::joint::STAGE).display().to_string(),
        Windows::from_lengths(train_len, test.len()),
    );
    report.scored_seal = scored_seal(run)?;
    report.weight_interpolation =
        Some(run.exp.diagnostics.weight_interpolation).filter(|&f| f != 1.0);
    report.dlf_rules = run.exp.dlf.rules.describe();
    if let Some(fit) = &run.exp.joint.physics {
        use neurofluid_dlf::physics::{PHYSICS_NAMES, values_of};
        let (from, to) = (
            values_of(&run.exp.dlf.rules),
            values_of(&models.dlf.config.rules),
        );
        report.fitted_physics = crate::config::PhysicalScalar::ALL
            .iter()
            .filter(|s| fit.fits(**s))
            .map(|s| {
                let value = to[s.index()];
                let (lo, hi) = s.bounds();
                let at_bound = if value <= lo {
                    Some("lower".into())
                } else if value >= hi {
                    Some("upper".into())
                } else {
                    None
                };
                neurofluid_outputs::report::FittedScalar {
                    name: PHYSICS_NAMES[s.index()].into(),
                    value,
                    from: from[s.index()],
                    at_bound,
                }
            })
            .collect();
    }
    report.renderer = run.exp.refit.enabled.then(|| {
        // the value as the experiment file writes it
        let positions = serde_json::to_value(run.exp.refit.positions).unwrap_or_default();
        format!(
            "the refitted PhysNeRF (`refit.enabled`, `refit.positions = {positions}`), fitted to \
             the grounded rollout after the joint stage"
        )
    });
    report.validation_views = cfg.novel_views == crate::config::NovelViews::Validation;
    report.initial_from_images =
        run.exp.scene.initial == crate::config::InitialParticles::FromImages;
    report.nvs_baselines = super::baseline::read_all(run)?;
    // the frame interval and gravity DLF steps with (the scene's), as the joint stage's own
    let dlf = run.dlf_config();
    let fraction = run.exp.diagnostics.weight_interpolation;
    rollouts.measure(&mut report, scene.manifest(), fraction, dlf.dt, dlf.gravity);
    if let Some(path) = &cfg.reference {
        use neurofluid_outputs::reference::ReferenceFile;
        use neurofluid_outputs::report::Rollout;
        let particles = rollouts.truth.first().map_or(0, Vec::len);
        let gap = ReferenceFile::read(path)
            .and_then(|file| {
                file.gap_share(
                    path,
                    &scene.manifest().name,
                    particles,
                    report.symmetric_means(Rollout::Dlf),
                    report.symmetric_means(Rollout::NeuroFluid),
                )
            })
            .context("eval.reference")?;
        report.gap = Some(gap);
    }

    let dir = run.stage_dir(STAGE);
    std::fs::create_dir_all(&dir).with_context(|| format!("creating {}", dir.display()))?;
    if cfg.write_ply {
        artifacts::write_particles(&dir, &rollouts, cfg.ply_format)?;
    }
    if cfg.render {
        let physnerf = models.physnerf.valid();
        let (images, others) = artifacts::render_views(run, &physnerf, &rollouts, &dir)?;
        report.images = images;
        report.nvs_baselines.extend(others);
    }
    if cfg.viewer {
        artifacts::write_viewer(run, &rollouts, &report, &dir)?;
    }
    artifacts::write_report(run, &report, &dir)?;
    Ok(report)
}

/// The seal of the checkpoints an evaluation of `run` scores (their latest): the joint
/// stage's, and with `refit.enabled` the refit's after it.
fn scored_seal(run: &Run) -> anyhow::Result<Option<String>> {
    let seal = |stage| match crate::trainer::checkpoint::latest(&run.stage_dir(stage)) {
        Some(dir) => neurofluid_core::checksums::seal_digest(&dir),
        None => Ok(None),
    };
    let joint = seal(super::joint::STAGE)?;
    if !run.exp.refit.enabled {
        return Ok(joint);
    }
    Ok(joint
        .zip(seal(super::refit::STAGE)?)
        .map(|(j, r)| format!("{j}+{r}")))
}

/// Checks that `report` (read from `run`'s evaluation folder) scored the joint stage's current
/// checkpoint (and the refit's, when on): a report made before a stage went on, or with the
/// other renderer, describes another model.
pub fn check_current(run: &Run, report: &EvalReport) -> anyhow::Result<()> {
    let now = scored_seal(run)?;
    anyhow::ensure!(
        report.scored_seal.is_some() && report.scored_seal == now,
        "the report in {} scored {} (seal {}), not the current checkpoint of the joint stage \
         (or of the refit, with refit.enabled) (seal {}, joint step {}): it is stale; evaluate \
         again",
        run.stage_dir(STAGE).display(),
        report.checkpoint,
        report.scored_seal.as_deref().unwrap_or("unrecorded"),
        now.as_deref().unwrap_or("none"),
        crate::trainer::checkpoint::saved_step(&run.stage_dir(super::joint::STAGE))
    );
    Ok(())
}

#[cfg(test)]
mod tests {
    use crate::config::DlfSection;
    use neurofluid_dlf::{Containment, EnergyCap};

    /// The report names the rules every DLF rollout stepped under as `[dlf]` words them: none for
    /// the reference, the walls and the energy cap when asked.
    #[test]
    fn the_reports_rules_are_the_dlf_sections() {
        let mut dlf = DlfSection::default();
        assert!(
            dlf.rules.describe().is_empty(),
            "the reference has no rules"
        );
        dlf.rules.containment = Containment::Box;
        dlf.rules.energy_cap = EnergyCap::Particle;
        assert_eq!(
            dlf.rules.describe(),
            [
                "the walls (`dlf.containment = \"box\"`)",
                "the energy cap (`dlf.energy_cap = \"particle\"`)"
            ]
        );
    }
}
