//! Preflight: every input the stages of a run will read (weights, every image and particle file,
//! the box, the views named in the config, the checkpoints a stage starts from) is read and
//! checked before the first iteration, and every problem is listed at once, so a bad file is
//! not found hours into a run.

use neurofluid_core::scene::{Role, Scene};

use super::run_folder::Run;
use super::views::{check_particles, check_sequence};
use super::{eval, joint, warmup};
use crate::trainer::checkpoint;

/// The stages a command will run.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Stage {
    /// The warm-up.
    Warmup,
    /// Joint grounding.
    Joint,
    /// Evaluation.
    Eval,
}

/// Problems found so far.
#[derive(Default)]
struct Problems(Vec<String>);

impl Problems {
    fn check<T, E: std::fmt::Display>(&mut self, what: impl FnOnce() -> String, r: Result<T, E>) {
        if let Err(e) = r {
            self.0.push(format!("{}: {e:#}", what()));
        }
    }
}

fn images(p: &mut Problems, scene: &Scene, role: Role, views: &[String], frames: &[usize]) {
    for view in views {
        if let Err(e) = scene.view_split(role, view) {
            p.0.push(format!("{e}"));
            continue;
        }
        for &t in frames {
            p.check(
                || format!("{role:?} view {view}, frame {t}"),
                scene.image(role, view, t),
            );
        }
    }
}

/// Checks everything `stages` of `run` will read; `Err` lists every problem.
pub fn check(run: &Run, stages: &[Stage]) -> anyhow::Result<()> {
    let scene = &run.scene;
    let exp = &run.exp;
    let mut p = Problems::default();
    let mut dlf_checked = false;
    let mut check_dlf = |p: &mut Problems| {
        if !std::mem::replace(&mut dlf_checked, true) {
            p.check(|| "dlf.weights".to_string(), run.load_dlf(&exp.dlf.weights));
        }
    };
    if stages.contains(&Stage::Warmup) {
        let t0 = scene.frames(Role::Warmup).start;
        let views = exp
            .warmup
            .views
            .clone()
            .unwrap_or_else(|| scene.views(Role::Warmup).to_vec());
        images(&mut p, scene, Role::Warmup, &views, &[t0]);
        p.check(
            || format!("warm-up particles (frame {t0})"),
            scene
                .particles(Role::Warmup, t0)
                .map_err(anyhow::Error::from)
                .and_then(|s| check_particles(&s, "particles")),
        );
        if exp.warmup.preview_every > 0
            && let Some(v) = scene.views(Role::Test).first()
        {
            images(&mut p, scene, Role::Test, std::slice::from_ref(v), &[t0]);
        }
    }
    if stages.contains(&Stage::Joint) {
        let frames: Vec<usize> = scene.frames(Role::Train).collect();
        if frames.len() < 2 {
            p.0.push(format!(
                "the training split has {} frame(s); joint training needs at least 2",
                frames.len()
            ));
        }
        let view = exp
            .joint
            .view
            .clone()
            .or_else(|| scene.views(Role::Train).first().cloned());
        match view {
            Some(v) => images(&mut p, scene, Role::Train, &[v], &frames),
            None => p.0.push("the scene has no training view".into()),
        }
        if let Some(&t) = frames.first() {
            p.check(
                || format!("first training frame's particles (frame {t})"),
                scene
                    .particles(Role::Train, t)
                    .map_err(anyhow::Error::from)
                    .and_then(|s| check_particles(&s, "particles")),
            );
        }
        p.check(|| "the box".to_string(), scene.boundary());
        check_dlf(&mut p);
        if !stages.contains(&Stage::Warmup)
            && checkpoint::latest(&run.stage_dir(warmup::STAGE)).is_none()
        {
            p.0.push(format!(
                "no warm-up checkpoint in {}: run the `warmup` stage first",
                run.stage_dir(warmup::STAGE).display()
            ));
        }
    }
    if stages.contains(&Stage::Eval) {
        let test = scene.frames(Role::Test);
        p.check(
            || "test particles".to_string(),
            scene
                .particle_sequence(Role::Test)
                .map_err(anyhow::Error::from)
                .and_then(|seq| check_sequence(&seq, test.start)),
        );
        p.check(|| "the box".to_string(), scene.boundary());
        if exp.eval.baseline {
            check_dlf(&mut p);
        }
        if exp.eval.render {
            let views = exp
                .eval
                .views
                .clone()
                .unwrap_or_else(|| scene.views(Role::Test).to_vec());
            let frames: Vec<usize> = eval::rendered_steps(test.len(), exp.eval.render_every)
                .into_iter()
                .map(|t| test.start + t)
                .collect();
            images(&mut p, scene, Role::Test, &views, &frames);
        }
        if !stages.contains(&Stage::Joint)
            && checkpoint::latest(&run.stage_dir(joint::STAGE)).is_none()
        {
            p.0.push(format!(
                "no joint checkpoint in {}: run the `joint` stage first",
                run.stage_dir(joint::STAGE).display()
            ));
        }
    }
    p.0.dedup();
    if p.0.is_empty() {
        return Ok(());
    }
    anyhow::bail!(
        "the run cannot start; {} problem(s) with its inputs:\n  {}",
        p.0.len(),
        p.0.join("\n  ")
    )
}
