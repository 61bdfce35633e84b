//! Evaluation (spec §6): from the ground-truth state of the first test frame, roll the grounded
//! transition model and the DLF it started from (the baseline) out without feedback, and report
//! the particle distance d (GT→prediction nearest neighbour, ×1000) per frame, its mean over the
//! grounding window (t = 1 … T_train−1) and the prediction window (t = T_train … T_test−1),
//! PSNR/SSIM/LPIPS of the renders of the held-out views, renders beside ground truth (PNG) and the
//! predicted particles of every frame (PLY).

use anyhow::Context;
use burn::module::Module;
use neurofluid_core::camera::Camera;
use neurofluid_core::metrics::{
    Lpips, RgbImage, gt_to_pred_distance, nearest_distances, psnr, ssim,
};
use neurofluid_core::scene::Role;
use neurofluid_dlf::DlfNet;
use neurofluid_dlf::rollout::rollout;
use neurofluid_physnerf::{PhysNerf, render_image, save_png};

use super::joint::Grounded;
use super::run_folder::Run;
use super::views::{ViewFrame, check_sequence, points_tensor, side_by_side};
use crate::config::PlyEncoding;
use crate::metrics_log::{MetricsLog, MetricsRow};
use crate::pictures::{TRUTH_COLOUR, column_of, particle_view, row_of, viridis, write_apng};
use crate::ply::{PlyFormat, write_ply};
use crate::report::{
    EvalReport, FrameDistance, ImageScore, Reverse, Rollout, Windows, count_outside,
};
use crate::trainer::Picture;
use crate::viewer::{Recording, TrackInput};

/// Folder of the stage inside the run folder.
pub const STAGE: &str = "eval";

fn rollout_positions(
    run: &Run,
    net: &DlfNet,
    pos: &[[f32; 3]],
    vel: &[[f32; 3]],
    steps: usize,
    what: &str,
) -> anyhow::Result<Vec<Vec<[f32; 3]>>> {
    let net = net.valid();
    let b = run.scene.boundary()?;
    let boundary = net.boundary(&b.points, &b.normals, &net.device());
    let bar = indicatif::ProgressBar::new(steps as u64).with_prefix(what.to_string());
    let out = rollout(&net, pos, vel, &boundary, steps, |_| bar.inc(1));
    bar.finish_and_clear();
    Ok(out.pos)
}

/// An image of the renderer's fine output as [`RgbImage`] (8-bit quantised, as saved PNGs are).
pub(crate) fn as_image(width: u32, height: u32, rgb: &[f32]) -> anyhow::Result<RgbImage> {
    Ok(RgbImage::new(width as usize, height as usize, rgb.to_vec())?.quantised())
}

/// The camera and ground-truth colours of a view at `scale` × its resolution (the ground truth
/// resampled with a triangle filter; unchanged at scale 1).
pub(crate) fn scaled_view(view: &ViewFrame, scale: f64) -> (Camera, Vec<f32>) {
    let cam = view.camera;
    if (scale - 1.0).abs() < 1e-12 {
        return (cam, view.image.rgb.clone());
    }
    let w = ((cam.width as f64 * scale).round() as u32).max(1);
    let h = ((cam.height as f64 * scale).round() as u32).max(1);
    let scaled = cam.resized(w, h);
    let full = image::Rgb32FImage::from_raw(cam.width, cam.height, view.image.rgb.clone())
        .expect("image size matches its camera");
    let small = image::imageops::resize(&full, w, h, image::imageops::FilterType::Triangle);
    (scaled, small.into_raw())
}

/// Renders `particles` with PhysNeRF from `camera` (8-bit quantised, as saved PNGs are).
fn render(
    physnerf: &PhysNerf,
    camera: &Camera,
    particles: &[[f32; 3]],
) -> anyhow::Result<RgbImage> {
    let device = physnerf
        .devices()
        .into_iter()
        .next()
        .context("PhysNeRF has no device")?;
    let image = render_image(
        physnerf,
        camera,
        &points_tensor(particles, &device),
        physnerf.config.chunk,
        &mut |_, _| {},
    )?;
    as_image(camera.width, camera.height, image.best())
}

/// PSNR, SSIM and LPIPS of a render against the truth (LPIPS absent for images too small for
/// AlexNet).
pub(crate) fn score(
    view: &str,
    t: usize,
    pred: &RgbImage,
    truth: &RgbImage,
    lpips: &Lpips,
) -> anyhow::Result<ImageScore> {
    Ok(ImageScore {
        view: view.into(),
        t,
        psnr: psnr(pred, truth)?,
        ssim: ssim(pred, truth).unwrap_or(f64::NAN),
        lpips: lpips.distance(pred, truth).ok(),
    })
}

fn picture(image: &RgbImage) -> Picture {
    Picture {
        width: image.width as u32,
        height: image.height as u32,
        rgb: image.data.clone(),
    }
}

/// The particle sets at frame `t` seen from `camera`: truth, then each prediction coloured by
/// its particles' distances to the nearest true particle (0 → 4 particle radii, viridis), with
/// its d in the label.
pub(crate) fn particle_row(
    camera: &Camera,
    radius: f32,
    t: usize,
    truth: &[[f32; 3]],
    predictions: &[(&str, &[[f32; 3]])],
) -> Picture {
    let mut pictures = vec![(
        format!("truth t={t}"),
        particle_view(camera, truth, radius, |_| TRUTH_COLOUR),
    )];
    for (name, pred) in predictions {
        let d = nearest_distances(pred, truth);
        let colour =
            |i: usize| viridis(d.as_ref().map_or(f64::NAN, |d| d[i]) / (4.0 * radius as f64));
        let mean = gt_to_pred_distance(truth, pred).mean;
        pictures.push((
            format!("{name} d={mean:.1}"),
            particle_view(camera, pred, radius, colour),
        ));
    }
    let labelled: Vec<(&str, &Picture)> = pictures.iter().map(|(l, p)| (l.as_str(), p)).collect();
    row_of(&labelled)
}

/// The smallest width (pixels) of a particle picture's panels.
const PARTICLE_PICTURE_WIDTH: u32 = 240;

/// `camera` enlarged (same view) to at least `width` pixels wide.
pub(crate) fn at_least_wide(camera: &Camera, width: u32) -> Camera {
    let k = (width as f32 / camera.width as f32).max(1.0);
    camera.resized(
        (camera.width as f32 * k).round() as u32,
        (camera.height as f32 * k).round() as u32,
    )
}

/// The d(t) curves of the rollouts inside `eval/`.
pub const DISTANCE_PLOT: &str = "distance.png";

/// Folder of the animations and particle pictures inside `eval/`.
pub const ANIMATIONS: &str = "animations";

/// The frames the particle pictures show: the first predicted one, the last of the grounding
/// window and the last of the prediction window.
pub fn picture_frames(train_frames: usize, steps: usize) -> Vec<usize> {
    let mut t = vec![1, train_frames.saturating_sub(1), steps];
    t.retain(|&t| (1..=steps).contains(&t));
    t.dedup();
    t
}

/// The rollout steps rendered (of a test split of `frames` frames): every `every`-th and the
/// last.
pub fn rendered_steps(frames: usize, every: usize) -> Vec<usize> {
    let steps = frames.saturating_sub(1);
    let every = every.max(1);
    (1..=steps)
        .filter(|t| t % every == 0 || *t == steps)
        .collect()
}

/// Runs the evaluation, writes `eval/` and returns the report.
pub fn run(run: &Run, models: &Grounded) -> anyhow::Result<EvalReport> {
    let scene = &run.scene;
    let cfg = &run.exp.eval;
    let test = scene.frames(Role::Test);
    let train_len = scene.frames(Role::Train).len();
    let gt: Vec<_> = scene.particle_sequence(Role::Test)?;
    check_sequence(&gt, test.start).context("the test split's particles")?;
    let steps = test.len() - 1;
    // both rollouts start from the same state: the truth, or the particles from images
    let start =
        super::initial::starting_particles(run, Role::Test, test.start, "first test frame")?;
    tracing::info!(steps, "evaluating: rollouts from the first test frame");
    let grounded = rollout_positions(
        run,
        &models.dlf,
        &start.pos,
        &start.vel,
        steps,
        "NeuroFluid",
    )?;
    let baseline = if cfg.baseline {
        let net = run.load_dlf(&run.exp.dlf.weights)?;
        Some(rollout_positions(
            run, &net, &start.pos, &start.vel, steps, "DLF",
        )?)
    } else {
        None
    };
    let supervised = match &cfg.supervised_dlf {
        Some(path) => {
            let net = run.load_dlf(path).context("eval.supervised_dlf")?;
            Some(rollout_positions(
                run, &net, &start.pos, &start.vel, steps, "DLF†",
            )?)
        }
        None => None,
    };
    let mut report = EvalReport::new(
        &run.exp.name,
        &scene.manifest().name,
        &run.stage_dir(super::joint::STAGE).display().to_string(),
        Windows::from_lengths(train_len, test.len()),
    );
    report.scored_seal = scored_seal(run)?;
    report.initial_from_images =
        run.exp.scene.initial == crate::config::InitialParticles::FromImages;
    report.nvs_baselines = super::baseline::read_all(run)?;
    report.frames = (1..=steps)
        .map(|t| {
            let truth = &gt[t].pos;
            let d = |pred: &[[f32; 3]]| gt_to_pred_distance(truth, pred).mean;
            let d_rev = |pred: &[[f32; 3]]| gt_to_pred_distance(pred, truth).mean;
            FrameDistance {
                t,
                neurofluid: d(&grounded[t]),
                dlf: baseline.as_ref().map(|b| d(&b[t])),
                supervised_dlf: supervised.as_ref().map(|b| d(&b[t])),
                reverse: Reverse {
                    neurofluid: Some(d_rev(&grounded[t])),
                    dlf: baseline.as_ref().map(|b| d_rev(&b[t])),
                    supervised_dlf: supervised.as_ref().map(|b| d_rev(&b[t])),
                },
            }
        })
        .collect();

    let interior = scene.manifest().box_interior;
    let radius = scene.manifest().particle_radius;
    let escaped = |label: &str, frames: &[Vec<[f32; 3]>]| {
        let most = frames[1..]
            .iter()
            .map(|p| count_outside(p, &interior, radius))
            .max()
            .unwrap_or(0);
        (label.to_string(), most)
    };
    report.escaped = [
        baseline
            .as_deref()
            .map(|b| escaped(Rollout::Dlf.label(), b)),
        supervised
            .as_deref()
            .map(|b| escaped(Rollout::SupervisedDlf.label(), b)),
        Some(escaped(Rollout::NeuroFluid.label(), &grounded)),
    ]
    .into_iter()
    .flatten()
    .collect();

    let dir = run.stage_dir(STAGE);
    std::fs::create_dir_all(&dir).with_context(|| format!("creating {}", dir.display()))?;
    if cfg.write_ply {
        let format = match cfg.ply_format {
            PlyEncoding::Binary => PlyFormat::BinaryLittleEndian,
            PlyEncoding::Ascii => PlyFormat::Ascii,
        };
        for (t, pos) in grounded.iter().enumerate() {
            let path = dir.join(format!("particles/neurofluid_{t:04}.ply"));
            write_ply(&path, pos, None, format)?;
            if let Some(b) = &baseline {
                write_ply(
                    &dir.join(format!("particles/dlf_{t:04}.ply")),
                    &b[t],
                    None,
                    format,
                )?;
            }
        }
    }
    if cfg.render {
        let physnerf = models.physnerf.valid();
        let frames = rendered_steps(test.len(), cfg.render_every);
        let views = cfg.views(scene);
        let lpips = Lpips::new(&neurofluid_core::device::cpu())?;
        for view in &views {
            let bar = indicatif::ProgressBar::new(frames.len() as u64)
                .with_prefix(format!("render {view}"));
            let mut animation = Vec::new();
            for &t in &frames {
                let vf = ViewFrame::load(scene, Role::Test, view, test.start + t)?;
                let (cam, gt_rgb) = scaled_view(&vf, cfg.image_scale);
                let truth = as_image(cam.width, cam.height, &gt_rgb)?;
                let pred = render(&physnerf, &cam, &grounded[t])?;
                let side = side_by_side(&pred, &truth);
                let png = dir.join(format!("renders/{view}/t{t:04}.png"));
                save_png(&png, side.width, side.height, &side.rgb)?;
                report.images.push(score(view, t, &pred, &truth, &lpips)?);
                if cfg.animate {
                    let mut panels = vec![("truth", picture(&truth))];
                    if let Some(b) = &baseline {
                        panels.push(("DLF", picture(&render(&physnerf, &cam, &b[t])?)));
                    }
                    panels.push(("NeuroFluid", picture(&pred)));
                    let labelled: Vec<(&str, &Picture)> =
                        panels.iter().map(|(l, p)| (*l, p)).collect();
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
                let rows: Vec<Picture> = picture_frames(train_len, steps)
                    .into_iter()
                    .map(|t| -> anyhow::Result<Picture> {
                        let cam = scene.camera(Role::Test, view, test.start + t)?;
                        let cam = at_least_wide(&cam, PARTICLE_PICTURE_WIDTH);
                        let mut predictions: Vec<(&str, &[[f32; 3]])> = Vec::new();
                        if let Some(b) = &baseline {
                            predictions.push(("DLF", &b[t]));
                        }
                        predictions.push(("NeuroFluid", &grounded[t]));
                        Ok(particle_row(&cam, radius, t, &gt[t].pos, &predictions))
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
    }
    if cfg.viewer {
        let truth: Vec<Vec<[f32; 3]>> = gt.iter().map(|f| f.pos.clone()).collect();
        let mut sets: Vec<TrackInput<'_>> = vec![("truth", "#3a6fc4", &truth)];
        if let Some(b) = &baseline {
            sets.push(("DLF", "#d9822b", b));
        }
        sets.push(("NeuroFluid", "#2e9e5b", &grounded));
        let title = format!("{}: {}", run.exp.name, scene.manifest().name);
        let mut rec = Recording::new(&title, scene.manifest().particle_radius, &sets)?;
        let rendered: Vec<usize> = if cfg.render {
            rendered_steps(test.len(), cfg.render_every)
        } else {
            Vec::new()
        };
        let views = cfg.views(scene);
        for view in &views {
            let cam = scene.camera(Role::Test, view, test.start)?;
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
            for (stage, colour) in [
                (super::warmup::STAGE, "#3a6fc4"),
                (super::joint::STAGE, "#c0392b"),
            ] {
                let points: Vec<(usize, f64)> = rows
                    .iter()
                    .filter(|r| r.stage == stage && r.loss.is_finite())
                    .map(|r| (r.step as usize, r.loss))
                    .collect();
                if !points.is_empty() {
                    rec = rec.with_training_curve(&format!("{stage} loss"), colour, points);
                }
            }
        }
        rec.write(&dir.join(VIEWER_FILE))?;
    }
    report.write_all(&dir)?;
    crate::plot::plot_distances(&report, &dir.join(DISTANCE_PLOT))?;
    log_images(run, &report)?;
    Ok(report)
}

/// The seal of the joint checkpoint an evaluation of `run` scores (its latest).
fn scored_seal(run: &Run) -> anyhow::Result<Option<String>> {
    let stage_dir = run.stage_dir(super::joint::STAGE);
    match crate::trainer::checkpoint::latest(&stage_dir) {
        Some(dir) => crate::trainer::checksums::seal_digest(&dir),
        None => Ok(None),
    }
}

/// Checks that `report` (read from `run`'s evaluation folder) scored the joint stage's current
/// checkpoint: a report made before the stage went on describes another model.
pub fn check_current(run: &Run, report: &EvalReport) -> anyhow::Result<()> {
    let now = scored_seal(run)?;
    anyhow::ensure!(
        report.scored_seal.is_some() && report.scored_seal == now,
        "the report in {} scored {} (seal {}), not the joint stage's current checkpoint \
         (seal {}, step {}): it is stale; evaluate again",
        run.stage_dir(STAGE).display(),
        report.checkpoint,
        report.scored_seal.as_deref().unwrap_or("unrecorded"),
        now.as_deref().unwrap_or("none"),
        crate::trainer::checkpoint::saved_step(&run.stage_dir(super::joint::STAGE))
    );
    Ok(())
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
        row.psnr = Some(i.psnr);
        row.ssim = Some(i.ssim).filter(|v| v.is_finite());
        row.lpips = i.lpips;
        log.append(&row)?;
    }
    Ok(())
}

/// The viewer page inside `eval/`.
pub const VIEWER_FILE: &str = "viewer.html";
