//! What the evaluation writes to `eval/`: the predicted particles (PLY), the renders beside the
//! truth (scored as they are made), the animations and particle pictures, the viewer page, the
//! report with its d(t) plot, and the image scores in the run's metrics log.

use std::path::{Path, PathBuf};

use neurofluid_core::camera::Camera;
use neurofluid_core::metrics::{Lpips, RgbImage};
use neurofluid_core::scene::Role;
use neurofluid_physnerf::{PhysNerf, render_image, save_png};

use crate::config::PlyEncoding;
use crate::stages::run_folder::Run;
use crate::stages::views::{ViewFrame, points_tensor};
use crate::stages::{joint, warmup};
use crate::trainer::Picture;
use neurofluid_outputs::formats::ply::PlyFormat;
use neurofluid_outputs::metrics_log::{MetricsLog, MetricsRow};
use neurofluid_outputs::pictures::{
    column_of, half_speed_frame_ms, row_of, side_by_side, write_apng,
};
use neurofluid_outputs::report::{BaselineScores, EvalReport, ImageScore};
use neurofluid_outputs::scoring::{
    as_image, at_least_wide, picture_frames, rendered_steps, scaled_truth, score,
};
use neurofluid_outputs::sequences::{RENDERER_ON_DLF, Sequences};

/// The d(t) curves of the rollouts inside `eval/`.
pub const DISTANCE_PLOT: &str = "distance.png";

/// d against d′ of the interpolated DLFs inside `eval/` (`diagnostics.interpolation_sweep`).
pub const INTERPOLATION_PLOT: &str = "interpolation.png";

/// Folder of the animations and particle pictures inside `eval/`.
pub const ANIMATIONS: &str = "animations";

/// The particle picture of test view `view` in the evaluation folder `dir`: in a folder of its
/// own, so no view's name (`view_5_particles`) can name another view's picture.
pub fn particle_picture_path(dir: &Path, view: &str) -> PathBuf {
    dir.join(ANIMATIONS)
        .join("particles")
        .join(format!("{view}.png"))
}

/// The viewer page inside `eval/`.
pub const VIEWER_FILE: &str = "viewer.html";

/// The smallest width (pixels) of a particle picture's panels.
const PARTICLE_PICTURE_WIDTH: u32 = 240;

/// NeuroFluid's and DLF's particles of every frame as `particles/<model>_<t>.ply`.
pub fn write_particles(
    dir: &Path,
    rollouts: &Sequences,
    encoding: PlyEncoding,
) -> anyhow::Result<()> {
    let format = match encoding {
        PlyEncoding::Binary => PlyFormat::BinaryLittleEndian,
        PlyEncoding::Ascii => PlyFormat::Ascii,
    };
    Ok(rollouts.write_ply(dir, format)?)
}

/// Renders NeuroFluid's particles from every evaluated view at the rendered steps, writes each
/// beside the truth (and, with `eval.animate`, the animation and the particle pictures of the
/// view) and returns the renders' scores, with the scores of the renderer on the other particle
/// sets asked for (`diagnostics.render_truth`, `diagnostics.render_dlf`), each saved beside the truth too.
pub fn render_views(
    run: &Run,
    physnerf: &PhysNerf,
    rollouts: &Sequences,
    dir: &Path,
) -> anyhow::Result<(Vec<ImageScore>, Vec<BaselineScores>)> {
    let scene = &run.scene;
    let cfg = &run.exp.eval;
    let test = scene.frames(Role::Test);
    let train_len = scene.frames(Role::Train).len();
    let radius = scene.manifest().particle_radius;
    let frames = rendered_steps(test.len(), cfg.render_every);
    let lpips = Lpips::new(&neurofluid_core::device::cpu())?;
    let diagnostics = &run.exp.diagnostics;
    let others = rollouts.others(diagnostics.render_truth, diagnostics.render_dlf);
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
            let truth = scaled_truth(vf.camera, &vf.image, cfg.image_scale)?;
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
                let mut panels = vec![("truth", Picture::from(&truth.image))];
                if let Some(b) = &rollouts.baseline {
                    let image = match dlf_render {
                        Some(image) => image,
                        None => render(physnerf, &cam, &b[t])?,
                    };
                    panels.push(("DLF", Picture::from(&image)));
                }
                panels.push(("NeuroFluid", Picture::from(&pred)));
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
                half_speed_frame_ms(cfg.render_every, scene.manifest().fps),
            )?;
            let rows: Vec<Picture> = picture_frames(train_len, rollouts.steps())
                .into_iter()
                .map(|t| -> anyhow::Result<Picture> {
                    let cam = scene.camera(cfg.novel_views.role(), view, test.start + t)?;
                    let cam = at_least_wide(&cam, PARTICLE_PICTURE_WIDTH);
                    Ok(rollouts.particle_picture(&cam, radius, t))
                })
                .collect::<anyhow::Result<_>>()?;
            let grid = column_of(&rows);
            save_png(
                particle_picture_path(dir, view),
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

/// The viewer page: the rollouts on a timeline, the test cameras with their renders, the d
/// curves of `report` and the training loss curves of the run's metrics log.
pub fn write_viewer(
    run: &Run,
    rollouts: &Sequences,
    report: &EvalReport,
    dir: &Path,
) -> anyhow::Result<()> {
    let scene = &run.scene;
    let cfg = &run.exp.eval;
    let test = scene.frames(Role::Test);
    let title = format!("{}: {}", run.exp.name, scene.manifest().name);
    let mut rec = rollouts.recording(&title, scene.manifest().particle_radius)?;
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
    rec = rec.with_distance_curves(report);
    let jsonl = run.dir.join(neurofluid_outputs::metrics_log::JSONL_FILE);
    if jsonl.is_file() {
        let rows = neurofluid_outputs::metrics_log::read_jsonl(&jsonl)?;
        let stages = [warmup::STAGE, joint::STAGE].map(|s| s.folder());
        rec = rec.with_loss_curves(&rows, &[(stages[0], "#3a6fc4"), (stages[1], "#c0392b")]);
    }
    rec.write(&dir.join(VIEWER_FILE))
}

/// The report (`report.{md,json}`, `frames.csv`), its d(t) plot, and its image scores in the
/// run's metrics log.
pub fn write_report(run: &Run, report: &EvalReport, dir: &Path) -> anyhow::Result<()> {
    report.write_all(dir)?;
    neurofluid_outputs::pictures::plot::plot_distances(report, &dir.join(DISTANCE_PLOT))?;
    if !report.interpolation.is_empty() {
        neurofluid_outputs::pictures::plot::plot_interpolation(
            report,
            &dir.join(INTERPOLATION_PLOT),
        )?;
    }
    log_images(run, report)
}

/// The evaluation's image scores in the run's metrics log, a row per render
/// ([`MetricsRow::of_image`]), replacing an earlier evaluation's rows.
fn log_images(run: &Run, report: &EvalReport) -> anyhow::Result<()> {
    let mut log = MetricsLog::open_resumed(&run.dir, |r| !r.stage.starts_with("eval-"))?;
    for i in &report.images {
        log.append(&MetricsRow::of_image(i))?;
    }
    Ok(())
}
