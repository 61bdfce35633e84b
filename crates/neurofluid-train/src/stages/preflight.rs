//! Preflight: every input the stages of a run will read (weights, every image, camera and
//! particle file, the box, the views named in the config, the checkpoints a stage starts from)
//! is read and checked before the first iteration, as is whether the images can supply the
//! rays each stage asks for, and every problem is listed at once, so a bad file is
//! not found hours into a run.

use neurofluid_core::scene::{Role, Scene};

use super::initial;
use super::nerf::{NerfData, NerfKind};
use super::run_folder::{Run, Start};
use super::views::{check_sequence, load_particles, ray_share, require_warmup_every_frame};
use crate::config::InitialParticles;
use crate::stage::Stage;
use crate::trainer::checkpoint;
use neurofluid_core::sampler::Rng;

/// Problems found so far.
#[derive(Default)]
struct Problems(Vec<String>);

impl Problems {
    fn check<T, E: std::fmt::Display>(&mut self, what: impl FnOnce() -> String, r: Result<T, E>) {
        if let Err(e) = r {
            self.0.push(format!("{}: {e:#}", what()));
        }
    }

    /// An error that names its subject itself.
    fn error<T>(&mut self, r: anyhow::Result<T>) {
        if let Err(e) = r {
            self.0.push(format!("{e:#}"));
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
            p.check(
                || format!("{role:?} view {view}, frame {t}"),
                scene.camera(role, view, t),
            );
        }
    }
}

/// `count` distinct rays can be drawn from a `size` image in the first steps' precrop window
/// (`precrop`) and over the whole image: the sampler the stage uses answers.
fn rays_fit(p: &mut Problems, what: &str, count: usize, size: (u32, u32), precrop: Option<f64>) {
    for crop in [precrop, None] {
        p.check(
            || format!("{what} ({}×{} images)", size.0, size.1),
            Rng::new(0).sample_pixels(count, size.0, size.1, crop),
        );
    }
}

/// The image size of `view` in `role`'s split, if the scene has it (a missing view is
/// reported by [`images`]).
fn image_size(scene: &Scene, role: Role, view: &str) -> Option<(u32, u32)> {
    scene.view_split(role, view).ok().map(|v| v.image_size)
}

/// A finished stage another stage starts from: its checkpoint must exist, hold all of its steps
/// and match the current settings.
fn finished(p: &mut Problems, run: &Run, stage: Stage, steps: u64) {
    let ckpt = match run.latest_checkpoint(stage) {
        Ok(ckpt) => ckpt,
        Err(e) => return p.0.push(format!("{e:#}")),
    };
    match checkpoint::load_matching(&ckpt, stage.folder(), &run.settings(stage)) {
        Ok(state) if state.step < steps => p.0.push(format!(
            "the {} checkpoint in {} holds {} of its {steps} steps: finish the `{}` stage first",
            stage.folder(),
            ckpt.display(),
            state.step,
            stage.folder()
        )),
        Ok(_) => {}
        Err(e) => p.0.push(format!("{e:#}")),
    }
}

/// Checks everything `stages` of `run` will read, and (when they resume) that their
/// checkpoints match the settings; `Err` lists every problem.
pub fn check(run: &Run, stages: &[Stage], start: Start) -> anyhow::Result<()> {
    let scene = &run.scene;
    let exp = &run.exp;
    let mut p = Problems::default();
    let mut dlf_checked = false;
    let mut check_dlf = |p: &mut Problems| {
        if !std::mem::replace(&mut dlf_checked, true) {
            p.check(|| "dlf.weights".to_string(), run.load_dlf(&exp.dlf.weights));
        }
    };
    if start == Start::Resume {
        // (the refit is not checked: made from the stages before it, it starts over when its
        // settings changed; `refit::run_until`)
        for stage in [Stage::Warmup, Stage::Joint] {
            if stages.contains(&stage)
                && let Some(ckpt) = checkpoint::latest(&run.stage_dir(stage))
                && let Err(e) =
                    checkpoint::load_matching(&ckpt, stage.folder(), &run.settings(stage))
            {
                p.0.push(format!("{e:#}"));
            }
        }
    }
    let from_images = exp.scene.initial == InitialParticles::FromImages;
    let nerfs = [
        (Stage::Nerf, NerfKind::Nerf, true),
        (Stage::Initial, NerfKind::Nerf, from_images),
        (Stage::NerfT, NerfKind::NerfT, true),
    ];
    for (stage, kind, needed) in nerfs {
        if stages.contains(&stage) && needed {
            match NerfData::load(scene, kind, exp, false) {
                Ok(data) => {
                    let cfg = &exp.nerf;
                    let k = cfg.images_per_step.min(data.images.len()).max(1);
                    for image in &data.images {
                        let c = &image.view.camera;
                        let count = ray_share(cfg.rays, k, 0).min((c.width * c.height) as usize);
                        let what = format!("nerf.rays ({} per image)", count);
                        rays_fit(&mut p, &what, count, (c.width, c.height), cfg.precrop_at(0));
                    }
                }
                Err(e) => p.0.push(format!("{e:#}")),
            }
        }
    }
    if from_images
        && !stages.contains(&Stage::Initial)
        && stages.iter().any(|s| Stage::ALL.contains(s))
    {
        let t0 = scene.frames(Role::Warmup).start;
        p.error(
            initial::starting_particles(run, Role::Warmup, t0, "initial particles").map(|_| ()),
        );
    }
    let joint_steps = exp.joint.epochs * scene.frames(Role::Train).len().saturating_sub(1) as u64;
    if stages.contains(&Stage::Warmup) {
        let t0 = scene.frames(Role::Warmup).start;
        images(&mut p, scene, Role::Warmup, &exp.warmup.views(scene), &[t0]);
        if !from_images {
            let what = format!("warm-up particles (frame {t0})");
            p.error(load_particles(scene, Role::Warmup, t0, &what));
        }
        if let Some((v, role)) = exp.warmup.preview_view(scene) {
            images(&mut p, scene, role, &[v], &[t0]);
        }
        for view in exp.warmup.views(scene) {
            if let Some(size) = image_size(scene, Role::Warmup, &view) {
                let what = format!("warmup.rays (view {view})");
                rays_fit(
                    &mut p,
                    &what,
                    exp.warmup.rays,
                    size,
                    exp.warmup.precrop_at(0),
                );
            }
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
        let joint_views = exp.joint.views_by_role(scene);
        for (i, (role, view)) in joint_views.iter().enumerate() {
            if let Some(size) = image_size(scene, *role, view) {
                let count = ray_share(exp.joint.rays, joint_views.len(), i);
                let what = format!("joint.rays ({count} for view {view})");
                rays_fit(&mut p, &what, count, size, exp.joint.precrop_at(0));
                if i == 0 {
                    // the diagnostics draw all of joint.rays from the training view
                    rays_fit(
                        &mut p,
                        "joint.rays (diagnostics)",
                        exp.joint.rays,
                        size,
                        None,
                    );
                }
            }
        }
        match exp.joint.view(scene) {
            Some(v) => images(&mut p, scene, Role::Train, &[v], &frames),
            None => p.0.push("the scene has no training view".into()),
        }
        let extra = &exp.joint.extra_views;
        if !extra.is_empty() {
            match require_warmup_every_frame(scene, &exp.joint.extra_views_label()) {
                Ok(()) => images(&mut p, scene, Role::Warmup, extra, &frames),
                Err(e) => p.0.push(format!("{e}")),
            }
        }
        if let Some(&t) = frames.first() {
            let what = format!("first training frame's particles (frame {t})");
            p.error(load_particles(scene, Role::Train, t, &what));
        }
        p.check(|| "the box".to_string(), scene.boundary());
        check_dlf(&mut p);
        if !stages.contains(&Stage::Warmup) {
            finished(&mut p, run, Stage::Warmup, exp.warmup.iters);
        }
    }
    if exp.refit.enabled {
        // the refit reads what the warm-up and the joint stage read, and the grounded DLF
        if stages.contains(&Stage::Refit) && !stages.contains(&Stage::Joint) {
            finished(&mut p, run, Stage::Joint, joint_steps);
        }
        if stages.contains(&Stage::Eval) && !stages.contains(&Stage::Refit) {
            finished(&mut p, run, Stage::Refit, exp.warmup.iters + joint_steps);
        }
    }
    if stages.contains(&Stage::Eval) {
        let test = scene.frames(Role::Test);
        // read once: checked here, and its particle count for `eval.reference`
        let sequence = scene.particle_sequence(Role::Test);
        let particles = sequence
            .as_ref()
            .ok()
            .map(|seq| seq.first().map_or(0, |f| f.pos.len()));
        p.check(
            || "test particles".to_string(),
            sequence
                .map_err(anyhow::Error::from)
                .and_then(|seq| check_sequence(&seq, test.start)),
        );
        p.check(|| "the box".to_string(), scene.boundary());
        // the grounded DLF is built from the pretrained weights' model, baseline or not
        check_dlf(&mut p);
        if let Some(path) = &exp.eval.supervised_dlf {
            p.check(|| "eval.supervised_dlf".to_string(), run.load_dlf(path));
        }
        if let Some(path) = &exp.eval.reference {
            // the file, the scene's entry and its particles (where the test particles could be
            // read: else their check above names the problem), before any stage runs
            let name = &scene.manifest().name;
            p.check(
                || "eval.reference".to_string(),
                neurofluid_outputs::reference::ReferenceFile::read(path).and_then(|file| {
                    particles.map_or(Ok(()), |n| {
                        file.gap_share(path, name, n, [None; 2], [None; 2])
                            .map(drop)
                    })
                }),
            );
        }
        if exp.eval.render {
            let frames: Vec<usize> =
                neurofluid_outputs::scoring::rendered_steps(test.len(), exp.eval.render_every)
                    .into_iter()
                    .map(|t| test.start + t)
                    .collect();
            let role = exp.eval.novel_views.role();
            images(&mut p, scene, role, &exp.eval.views(scene), &frames);
        }
        if !stages.contains(&Stage::Joint) {
            finished(&mut p, run, Stage::Joint, joint_steps);
        }
    }
    // every stage logs to the run's metrics: a damaged log stops the run now, not after hours
    // (the evaluation reads it for its curves after the renders)
    let log = run.dir.join(neurofluid_outputs::metrics_log::JSONL_FILE);
    let log_removed = start == Start::Fresh && stages.contains(&Stage::ALL[0]);
    if !log_removed && log.is_file() {
        p.check(
            || "the run's metrics log".to_string(),
            neurofluid_outputs::metrics_log::read_jsonl(&log),
        );
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
