//! What the evaluation writes to `eval/`: the predicted particles (PLY), the renders beside the
//! truth (scored as they are made), the animations and particle pictures, the viewer page, the
//! report with its d(t) plot, and the image scores in the run's metrics log.

use std::path::Path;

use neurofluid_core::camera::Camera;
use neurofluid_core::metrics::{Lpips, RgbImage};
use neurofluid_core::scene::Role;
use neurofluid_physnerf::{PhysNerf, render_image, save_png};

use super::rollouts::Rollouts;
use crate::config::PlyEncoding;
use crate::formats::ply::{PlyFormat, write_ply};
use crate::metrics_log::{MetricsLog, MetricsRow};
use crate::pictures::viewer::{Recording, TrackInput};
use crate::pictures::{column_of, row_of, write_apng};
use crate::report::{BaselineScores, EvalReport, ImageScore, Rollout};
use crate::stages::run_folder::Run;
use crate::stages::scoring::{
    as_image, at_least_wide, particle_row, rendered_steps, scaled_truth, score,
};
use crate::stages::views::{ViewFrame, points_tensor, side_by_side};
use crate::stages::{joint, warmup};
use crate::trainer::Picture;

/// The d(t) curves of the rollouts inside `eval/`.
pub const DISTANCE_PLOT: &str = "distance.png";

/// d against d′ of the interpolated DLFs inside `eval/` (`eval.interpolation_sweep`).
pub const INTERPOLATION_PLOT: &str = "interpolation.png";

/// Folder of the animations and particle pictures inside `eval/`.
pub const ANIMATIONS: &str = "animations";

/// The viewer page inside `eval/`.
pub const VIEWER_FILE: &str = "viewer.html";

/// The smallest width (pixels) of a particle picture's panels.
const PARTICLE_PICTURE_WIDTH: u32 = 240;

/// The frames the particle pictures show: the first predicted one, the last of the grounding
/// window and the last of the prediction window.
pub fn picture_frames(train_frames: usize, steps: usize) -> Vec<usize> {
    let mut t = vec![1, train_frames.saturating_sub(1), steps];
    t.retain(|&t| (1..=steps).contains(&t));
    t.dedup();
    t
}

/// NeuroFluid's and DLF's particles of every frame as `particles/<model>_<t>.ply`.
pub fn write_particles(
    dir: &Path,
    rollouts: &Rollouts,
    encoding: PlyEncoding,
) -> anyhow::Result<()> {
    let format = match encoding {
        PlyEncoding::Binary => PlyFormat::BinaryLittleEndian,
        PlyEncoding::Ascii => PlyFormat::Ascii,
    };
    for (t, pos) in rollouts.grounded.iter().enumerate() {
        let path = dir.join(format!("particles/neurofluid_{t:04}.ply"));
        write_ply(&path, pos, None, format)?;
        if let Some(b) = &rollouts.baseline {
            write_ply(
                &dir.join(format!("particles/dlf_{t:04}.ply")),
                &b[t],
                None,
                format,
            )?;
        }
    }
    Ok(())
}

/// The model name of the renders of the true particles (`eval.render_truth`) in the tables.
pub const RENDERER_ON_TRUTH: &str = "PhysNeRF on the true particles";

/// The model name of the renders of the pretrained DLF's rollout (`eval.render_dlf`).
pub const RENDERER_ON_DLF: &str = "PhysNeRF on DLF's particles";

/// The model name of the renders of DLF†'s rollout (`eval.render_dlf`).
pub const RENDERER_ON_SUPERVISED_DLF: &str = "PhysNeRF on DLF†'s particles";

/// A particle set the renderer draws beside NeuroFluid's: its name in the tables, the prefix of
/// its saved renders and its particles at every rollout step.
struct OtherParticles<'a> {
    model: &'static str,
    prefix: &'static str,
    at: Vec<&'a [[f32; 3]]>,
}

/// The particle sets `eval` asks the renderer to draw beside NeuroFluid's: the truth
/// (`eval.render_truth`), then the rollouts of DLF and DLF† where evaluated (`eval.render_dlf`).
fn other_particles<'a>(run: &Run, rollouts: &'a Rollouts) -> Vec<OtherParticles<'a>> {
    let cfg = &run.exp.eval;
    let mut others = Vec::new();
    if cfg.render_truth {
        others.push(OtherParticles {
            model: RENDERER_ON_TRUTH,
            prefix: "true_particles_",
            at: rollouts.truth.iter().map(|p| p.pos.as_slice()).collect(),
        });
    }
    if cfg.render_dlf {
        let sets = [
            (RENDERER_ON_DLF, "dlf_particles_", &rollouts.baseline),
            (
                RENDERER_ON_SUPERVISED_DLF,
                "dlf_supervised_particles_",
                &rollouts.supervised,
            ),
        ];
        for (model, prefix, positions) in sets {
            if let Some(positions) = positions {
                let at = positions.iter().map(Vec::as_slice).collect();
                others.push(OtherParticles { model, prefix, at });
            }
        }
    }
    others
}

/// Renders NeuroFluid's particles from every evaluated view at the rendered steps, writes each
/// beside the truth (and, with `eval.animate`, the animation and the particle pictures of the
/// view) and returns the renders' scores, with the scores of the renderer on the other particle
/// sets asked for (`eval.render_truth`, `eval.render_dlf`), each saved beside the truth too.
pub fn render_views(
    run: &Run,
    physnerf: &PhysNerf,
    rollouts: &Rollouts,
    dir: &Path,
) -> anyhow::Result<(Vec<ImageScore>, Vec<BaselineScores>)> {
    let scene = &run.scene;
    let cfg = &run.exp.eval;
    let test = scene.frames(Role::Test);
    let train_len = scene.frames(Role::Train).len();
    let radius = scene.manifest().particle_radius;
    let frames = rendered_steps(test.len(), cfg.render_every);
    let lpips = Lpips::new(&neurofluid_core::device::cpu())?;
    let others = other_particles(run, rollouts);
    let mut scores = Vec::new();
    let mut others_scores: Vec<BaselineScores> = others
        .iter()
        .map(|o| BaselineScores {
            model: o.model.into(),
            images: Vec::new(),
        })
        .collect();
    for view in &cfg.views(scene) {
        let bar =
            indicatif::ProgressBar::new(frames.len() as u64).with_prefix(format!("render {view}"));
        let mut animation = Vec::new();
        for &t in &frames {
            let vf = ViewFrame::load(scene, cfg.novel_views.role(), view, test.start + t)?;
            let truth = scaled_truth(&vf, cfg.image_scale)?;
            let cam = truth.camera;
            // a render saved beside the truth as `renders/<view>/<prefix>t<step>.png`
            let save_beside_truth = |render: &RgbImage, prefix: &str| {
                let side = side_by_side(render, &truth.image);
                let png = dir.join(format!("renders/{view}/{prefix}t{t:04}.png"));
                save_png(&png, side.width, side.height, &side.rgb)
            };
            let pred = render(physnerf, &cam, &rollouts.grounded[t])?;
            save_beside_truth(&pred, "")?;
            scores.push(score(view, t, &pred, &truth, &lpips)?);
            let mut dlf_render = None;
            for (other, other_scores) in others.iter().zip(&mut others_scores) {
                let image = render(physnerf, &cam, other.at[t])?;
                save_beside_truth(&image, other.prefix)?;
                other_scores
                    .images
                    .push(score(view, t, &image, &truth, &lpips)?);
                if other.model == RENDERER_ON_DLF {
                    dlf_render = Some(image);
                }
            }
            if cfg.animate {
                let mut panels = vec![("truth", picture(&truth.image))];
                if let Some(b) = &rollouts.baseline {
                    let image = match dlf_render {
                        Some(image) => image,
                        None => render(physnerf, &cam, &b[t])?,
                    };
                    panels.push(("DLF", picture(&image)));
                }
                panels.push(("NeuroFluid", picture(&pred)));
                let labelled: Vec<(&str, &Picture)> = panels.iter().map(|(l, p)| (*l, p)).collect();
                animation.push(row_of(&labelled));
            }
            bar.inc(1);
        }
        bar.finish_and_clear();
        if cfg.animate {
            write_apng(
                &dir.join(format!("{ANIMATIONS}/{view}.png")),
                &animation,
                // half speed: two frame intervals per rendered step
                (2000.0 * cfg.render_every.max(1) as f64 / f64::from(scene.manifest().fps))
                    .round()
                    .clamp(20.0, 5000.0) as u16,
            )?;
            let rows: Vec<Picture> = picture_frames(train_len, rollouts.steps())
                .into_iter()
                .map(|t| -> anyhow::Result<Picture> {
                    let cam = scene.camera(cfg.novel_views.role(), view, test.start + t)?;
                    let cam = at_least_wide(&cam, PARTICLE_PICTURE_WIDTH);
                    let mut predictions: Vec<(&str, &[[f32; 3]])> = Vec::new();
                    if let Some(b) = &rollouts.baseline {
                        predictions.push(("DLF", &b[t]));
                    }
                    predictions.push(("NeuroFluid", &rollouts.grounded[t]));
                    Ok(particle_row(
                        &cam,
                        radius,
                        t,
                        &rollouts.truth[t].pos,
                        &predictions,
                    ))
                })
                .collect::<anyhow::Result<_>>()?;
            let grid = column_of(&rows);
            save_png(
                dir.join(format!("{ANIMATIONS}/{view}_particles.png")),
                grid.width,
                grid.height,
                &grid.rgb,
            )?;
        }
    }
    Ok((scores, others_scores))
}

/// Renders `particles` with PhysNeRF from `camera` (8-bit quantised, as saved PNGs are).
fn render(
    physnerf: &PhysNerf,
    camera: &Camera,
    particles: &[[f32; 3]],
) -> anyhow::Result<RgbImage> {
    let device = physnerf.device();
    let image = render_image(
        physnerf,
        camera,
        &points_tensor(particles, &device),
        physnerf.config.chunk,
        &mut |_, _| {},
    )?;
    as_image(camera.width, camera.height, image.best())
}

fn picture(image: &RgbImage) -> Picture {
    Picture {
        width: image.width as u32,
        height: image.height as u32,
        rgb: image.data.clone(),
    }
}

/// The viewer page: the rollouts on a timeline, the test cameras with their renders, the d
/// curves of `report` and the training loss curves of the run's metrics log.
pub fn write_viewer(
    run: &Run,
    rollouts: &Rollouts,
    report: &EvalReport,
    dir: &Path,
) -> anyhow::Result<()> {
    let scene = &run.scene;
    let cfg = &run.exp.eval;
    let test = scene.frames(Role::Test);
    let truth: Vec<Vec<[f32; 3]>> = rollouts.truth.iter().map(|f| f.pos.clone()).collect();
    let mut sets: Vec<TrackInput<'_>> = vec![("truth", "#3a6fc4", &truth)];
    if let Some(b) = &rollouts.baseline {
        sets.push(("DLF", "#d9822b", b));
    }
    sets.push(("NeuroFluid", "#2e9e5b", &rollouts.grounded));
    let title = format!("{}: {}", run.exp.name, scene.manifest().name);
    let mut rec = Recording::new(&title, scene.manifest().particle_radius, &sets)?;
    let rendered: Vec<usize> = if cfg.render {
        rendered_steps(test.len(), cfg.render_every)
    } else {
        Vec::new()
    };
    let views = cfg.views(scene);
    for view in &views {
        let cam = scene.camera(cfg.novel_views.role(), view, test.start)?;
        let renders = rendered
            .iter()
            .map(|&t| (t, format!("renders/{view}/t{t:04}.png")))
            .collect();
        rec = rec.with_camera(view, &cam, renders);
    }
    rec = rec.with_curve(
        "NeuroFluid d",
        "#2e9e5b",
        report.frames.iter().map(|f| (f.t, f.neurofluid)).collect(),
    );
    for (model, colour) in [
        (Rollout::Dlf, "#d9822b"),
        (Rollout::SupervisedDlf, "#803caa"),
    ] {
        let points: Vec<(usize, f64)> = report
            .frames
            .iter()
            .filter_map(|f| model.of(f).map(|d| (f.t, d)))
            .collect();
        if !points.is_empty() {
            rec = rec.with_curve(&format!("{} d", model.label()), colour, points);
        }
    }
    let jsonl = run.dir.join(crate::metrics_log::JSONL_FILE);
    if jsonl.is_file() {
        let rows = crate::metrics_log::read_jsonl(&jsonl)?;
        for (stage, colour) in [(warmup::STAGE, "#3a6fc4"), (joint::STAGE, "#c0392b")] {
            let points: Vec<(usize, f64)> = rows
                .iter()
                .filter(|r| r.stage == stage.folder() && r.loss.is_finite())
                .map(|r| (r.step as usize, r.loss))
                .collect();
            if !points.is_empty() {
                rec = rec.with_training_curve(&format!("{stage} loss"), colour, points);
            }
        }
    }
    rec.write(&dir.join(VIEWER_FILE))
}

/// The report (`report.{md,json}`, `frames.csv`), its d(t) plot, and its image scores in the
/// run's metrics log.
pub fn write_report(run: &Run, report: &EvalReport, dir: &Path) -> anyhow::Result<()> {
    report.write_all(dir)?;
    crate::pictures::plot::plot_distances(report, &dir.join(DISTANCE_PLOT))?;
    if !report.interpolation.is_empty() {
        crate::pictures::plot::plot_interpolation(report, &dir.join(INTERPOLATION_PLOT))?;
    }
    log_images(run, report)
}

/// The evaluation's image scores in the run's metrics log: one `eval-<view>` row per render
/// (step = rollout step; loss = the MSE that the PSNR stands for), replacing an earlier
/// evaluation's rows.
fn log_images(run: &Run, report: &EvalReport) -> anyhow::Result<()> {
    let mut log = MetricsLog::open_resumed(&run.dir, |r| !r.stage.starts_with("eval-"))?;
    for i in &report.images {
        let mut row = MetricsRow::new(
            &format!("eval-{}", i.view),
            i.t as u64,
            10f64.powf(-i.psnr / 10.0),
            0.0,
        );
        row.set("psnr", i.psnr);
        row.set_some("ssim", Some(i.ssim).filter(|v| v.is_finite()));
        row.set_some("lpips", i.lpips);
        log.append(&row)?;
    }
    Ok(())
}
