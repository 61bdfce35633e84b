//! The novel-view baselines of NeuroFluid's Tables 3–4: NeRF and NeRF-T, trained by
//! [`super::nerf`] and scored with the evaluation's code on the same test views and frames as
//! NeuroFluid. The scores go to `<run>/<nerf|nerf-t>/scores.json`, which `eval` puts beside
//! NeuroFluid's.

use std::path::PathBuf;

use anyhow::Context;
use neurofluid_core::metrics::Lpips;
use neurofluid_core::scene::Role;
use neurofluid_physnerf::{Nerf, save_png};

use super::nerf::{NerfKind, time_of};
use super::run_folder::Run;
use super::views::ViewFrame;
use crate::config::{NerfTImages, NovelViews};
use neurofluid_outputs::pictures::side_by_side;
use neurofluid_outputs::report::BaselineScores;
use neurofluid_outputs::scoring::{as_image, rendered_steps, scaled_truth, score};

/// A baseline's scores on the test views inside its stage folder.
pub const SCORES_FILE: &str = "scores.json";
/// A baseline's scores on the validation views (`eval.novel_views = "validation"`).
pub const VALIDATION_SCORES_FILE: &str = "scores-validation.json";

/// Where `kind`'s scores on the views of `eval.novel_views` are.
pub fn scores_path(run: &Run, kind: NerfKind) -> PathBuf {
    let file = match run.exp.eval.novel_views {
        NovelViews::Test => SCORES_FILE,
        NovelViews::Validation => VALIDATION_SCORES_FILE,
    };
    run.stage_dir(kind.stage()).join(file)
}

/// Renders the novel views (`eval.novel_views`) at NeuroFluid's evaluated frames with `nerf`
/// and scores them against the truth; writes the renders beside the truth and the scores.
pub fn evaluate(run: &Run, nerf: &Nerf, kind: NerfKind) -> anyhow::Result<BaselineScores> {
    let scene = &run.scene;
    let cfg = &run.exp.eval;
    let test = scene.frames(Role::Test);
    let train = scene.frames(Role::Train);
    let dir = run.stage_dir(kind.stage());
    let lpips = Lpips::new(&neurofluid_core::device::cpu())?;
    let frames = rendered_steps(test.len(), cfg.render_every);
    let model = match (kind, run.exp.nerf.t_images) {
        (NerfKind::NerfT, NerfTImages::Neurofluid) => "NeRF-T (NeuroFluid's images)",
        _ => kind.label(),
    };
    let mut images = Vec::new();
    for view in cfg.views(scene) {
        let bar =
            indicatif::ProgressBar::new(frames.len() as u64).with_prefix(format!("{model} {view}"));
        for &t in &frames {
            let frame = test.start + t;
            let vf = ViewFrame::load(scene, cfg.novel_views.role(), &view, frame)?;
            let truth = scaled_truth(vf.camera, &vf.image, cfg.image_scale)?;
            let cam = truth.camera;
            let time = (kind == NerfKind::NerfT).then(|| time_of(frame, &train));
            let rendered = nerf.render_image(&cam, time)?;
            let pred = as_image(cam.width, cam.height, rendered.best())?;
            let side = side_by_side(&pred, &truth.image);
            save_png(
                dir.join(format!("renders/{view}/t{t:04}.png")),
                side.width,
                side.height,
                &side.rgb,
            )?;
            images.push(score(&view, t, &pred, &truth, &lpips)?);
            bar.inc(1);
        }
        bar.finish_and_clear();
    }
    let scores = BaselineScores {
        model: model.into(),
        images,
    };
    let path = scores_path(run, kind);
    neurofluid_core::atomic::write_bytes(&path, serde_json::to_string_pretty(&scores)?.as_bytes())
        .with_context(|| format!("writing {}", path.display()))?;
    Ok(scores)
}

/// The scores of every baseline that has been evaluated in `run` on the views of
/// `eval.novel_views`.
pub fn read_all(run: &Run) -> anyhow::Result<Vec<BaselineScores>> {
    let mut out = Vec::new();
    for kind in [NerfKind::Nerf, NerfKind::NerfT] {
        let path = scores_path(run, kind);
        if path.is_file() {
            let text = neurofluid_core::input_file::read_string(&path)
                .with_context(|| format!("reading {}", path.display()))?;
            out.push(
                serde_json::from_str(&text)
                    .with_context(|| format!("parsing {}", path.display()))?,
            );
        }
    }
    Ok(out)
}
