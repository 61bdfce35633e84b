//! Plots as PNGs, drawn with `plotters` and a bundled font (no system fonts needed): the
//! training curves (one column per stage — warm-up, joint, …; the loss on top, log scale when it
//! spans a decade or more, the PSNR below) and the evaluation's particle distance d(t) of each
//! rollout.

use std::path::{Path, PathBuf};

use image::{Rgb, RgbImage};
use plotters::coord::Shift;
use plotters::prelude::*;
use plotters::style::FontStyle;

use crate::metrics_log::{MetricsError, MetricsRow, read_jsonl};
use crate::report::{EvalReport, InterpolationPoint, Rollout};

/// Errors of the plotter.
#[derive(Debug, thiserror::Error)]
pub enum PlotError {
    /// The metrics could not be read.
    #[error(transparent)]
    Metrics(#[from] MetricsError),
    /// The PNG could not be encoded or written.
    #[error("cannot write plot {}: {message}", path.display())]
    Write {
        /// The file.
        path: PathBuf,
        /// What went wrong.
        message: String,
    },
}

const PANEL_W: u32 = 460;
const PANEL_H: u32 = 260;
/// Colour of the loss curves.
pub const LOSS_COLOUR: Rgb<u8> = Rgb([31, 90, 180]);
/// Colour of the PSNR curves.
pub const PSNR_COLOUR: Rgb<u8> = Rgb([200, 60, 30]);
/// Colour of the renderer's PSNR on the true particles (joint diagnostics).
pub const PSNR_TRUE_COLOUR: Rgb<u8> = Rgb([120, 120, 120]);
/// Colour of the training-rollout d and the gradient alignment (joint diagnostics).
pub const DIAGNOSTIC_COLOUR: Rgb<u8> = Rgb([46, 158, 91]);

/// DejaVu Sans (Bitstream Vera licence, `assets/fonts/`), compiled in: plots and picture labels
/// need no system font.
const FONT: &[u8] = include_bytes!("../../../../assets/fonts/DejaVuSans.ttf");
/// The family name the bundled font is registered under.
pub(crate) const FONT_FAMILY: &str = "sans-serif";

/// Registers the bundled font with plotters (once).
pub(crate) fn register_bundled_font() {
    static ONCE: std::sync::Once = std::sync::Once::new();
    ONCE.call_once(|| {
        if plotters::style::register_font(FONT_FAMILY, FontStyle::Normal, FONT).is_err() {
            tracing::warn!("the bundled font could not be registered; plot text is missing");
        }
    });
}

/// A `w` × `h` white image with `draw` drawn on it; what fails to draw is logged (naming
/// `what`) and the image kept as far as it got.
fn draw_image(
    w: u32,
    h: u32,
    what: &str,
    draw: impl FnOnce(&DrawingArea<BitMapBackend<'_>, Shift>) -> Result<(), String>,
) -> RgbImage {
    register_bundled_font();
    let mut buf = vec![255u8; (w * h * 3) as usize];
    let drawn = (|| {
        let root = BitMapBackend::with_buffer(&mut buf, (w, h)).into_drawing_area();
        root.fill(&WHITE).map_err(|e| e.to_string())?;
        draw(&root)?;
        root.present().map_err(|e| e.to_string())
    })();
    if let Err(e) = drawn {
        tracing::warn!("drawing {what}: {e}");
    }
    RgbImage::from_raw(w, h, buf).expect("buffer of the image's size")
}

fn rgb(c: Rgb<u8>) -> RGBColor {
    RGBColor(c.0[0], c.0[1], c.0[2])
}

/// One curve of a panel: its points (x = step) and colour.
type Series = (Vec<(f64, f64)>, Rgb<u8>);

/// One panel: curves (x = step) of one quantity, log-scaled when they span a decade or more.
fn draw_panel<DB: DrawingBackend>(
    area: &DrawingArea<DB, plotters::coord::Shift>,
    title: &str,
    series: &[Series],
    allow_log: bool,
) -> Result<(), String> {
    let e = |e: DrawingAreaErrorKind<DB::ErrorType>| e.to_string();
    let points = || series.iter().flat_map(|(p, _)| p.iter());
    if points().next().is_none() {
        area.titled(title, (FONT_FAMILY, 14)).map_err(e)?;
        return Ok(());
    }
    let (mut x0, mut x1) = points().fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), p| {
        (a.min(p.0), b.max(p.0))
    });
    if x1 <= x0 {
        (x0, x1) = (x0 - 1.0, x1 + 1.0);
    }
    let (lo, hi) = points().fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), p| {
        (a.min(p.1), b.max(p.1))
    });
    let mut chart = ChartBuilder::on(area);
    chart
        .caption(title, (FONT_FAMILY, 14))
        .margin(8)
        .x_label_area_size(24)
        .y_label_area_size(56);
    let lines = || {
        series.iter().filter(|(p, _)| !p.is_empty()).map(|(p, c)| {
            // a single point (one evaluation so far) as a dot
            let size = if p.len() == 1 { 3 } else { 0 };
            LineSeries::new(p.iter().copied(), rgb(*c).stroke_width(2)).point_size(size)
        })
    };
    if allow_log && lo > 0.0 && hi / lo >= 10.0 {
        let mut c = chart
            .build_cartesian_2d(x0..x1, (lo..hi).log_scale())
            .map_err(e)?;
        c.configure_mesh()
            .label_style((FONT_FAMILY, 11))
            .y_label_formatter(&|v| format!("{v:.0e}"))
            .draw()
            .map_err(e)?;
        for line in lines() {
            c.draw_series(line).map_err(e)?;
        }
    } else {
        let pad = if hi > lo {
            0.05 * (hi - lo)
        } else {
            0.5 * lo.abs().max(1e-3)
        };
        let mut c = chart
            .build_cartesian_2d(x0..x1, (lo - pad)..(hi + pad))
            .map_err(e)?;
        c.configure_mesh()
            .label_style((FONT_FAMILY, 11))
            .draw()
            .map_err(e)?;
        for line in lines() {
            c.draw_series(line).map_err(e)?;
        }
    }
    Ok(())
}

/// Scalars drawn grey beside another's curve, not in a row of their own: (scalar, beside, what
/// the grey curve is).
const BESIDE: [(&str, &str, &str); 3] = [
    ("psnr_true", "psnr", "on the true particles"),
    ("rollout_d_prime", "rollout_d", "d′ (spray)"),
    (
        "rollout_particle_energy_gain",
        "rollout_energy_gain",
        "per particle",
    ),
];

/// Colours of a family's further groups (`lr/<group>`: the first group takes the row's colour).
const GROUP_COLOURS: [Rgb<u8>; 3] = [Rgb([217, 130, 43]), Rgb([128, 60, 170]), Rgb([31, 90, 180])];

/// One row of panels: the scalars it draws (a name, or a family's `<family>/<group>` names).
struct PanelRow {
    /// The scalar, or the family (`lr`, `grad_norm`).
    title: String,
    /// The scalars of the row, each with its colour.
    names: Vec<(String, Rgb<u8>)>,
    /// Log-scaled when it spans a decade or more.
    log: bool,
}

/// The rows of panels for `rows`: loss and PSNR, then every further scalar that arrives (in
/// first-seen order), a parameter-group family (`lr/…`, `grad_norm/…`) in one row; the scalars
/// of [`BESIDE`] are drawn in their companion's row.
fn panel_rows(rows: &[MetricsRow]) -> Vec<PanelRow> {
    let row = |title: &str, colour, log| PanelRow {
        title: title.to_string(),
        names: vec![(title.to_string(), colour)],
        log,
    };
    let mut out = vec![
        row("loss", LOSS_COLOUR, true),
        row("psnr", PSNR_COLOUR, false),
    ];
    for r in rows {
        for (name, _) in &r.scalars {
            if BESIDE.iter().any(|(n, _, _)| n == name)
                || out.iter().any(|p| p.names.iter().any(|(n, _)| n == name))
            {
                continue;
            }
            let family = crate::metrics_log::GROUP_FAMILIES
                .into_iter()
                .find(|f| name.strip_prefix(f).is_some_and(|g| g.starts_with('/')));
            match family.and_then(|f| out.iter_mut().find(|p| p.title == f)) {
                Some(p) => {
                    let colour = GROUP_COLOURS[(p.names.len() - 1) % GROUP_COLOURS.len()];
                    p.names.push((name.clone(), colour));
                }
                None => {
                    let title = family.unwrap_or(name);
                    out.push(PanelRow {
                        title: title.to_string(),
                        names: vec![(name.clone(), DIAGNOSTIC_COLOUR)],
                        log: family.is_some(),
                    });
                }
            }
        }
    }
    out
}

/// Draws the curves of `rows` into an image: one column per stage (first-seen order), one row
/// per quantity (loss on top, PSNR below, then whatever further scalars the rows hold; see
/// [`panel_rows`]); x = the stage's step. A stage's panel draws its own rows' values, or, for
/// a scalar its own rows lack, those of its evaluations (`<stage>-preview`, e.g. the joint
/// diagnostics). Non-finite values are skipped.
pub fn render_curves(rows: &[MetricsRow]) -> RgbImage {
    let mut stages: Vec<&str> = Vec::new();
    for r in rows {
        if !stages.contains(&r.stage.as_str()) {
            stages.push(&r.stage);
        }
    }
    let panels = panel_rows(rows);
    let cols = stages.len().max(1);
    let n_rows = panels.len();
    let (w, h) = (cols as u32 * PANEL_W, n_rows as u32 * PANEL_H);
    draw_image(w, h, "the curves", |root| {
        if stages.is_empty() {
            root.draw_text(
                "no metrics",
                &(FONT_FAMILY, 16).into_text_style(root),
                (w as i32 / 2 - 40, h as i32 / 2),
            )
            .map_err(|e| e.to_string())?;
        }
        let areas = root.split_evenly((n_rows, cols));
        for (i, stage) in stages.iter().enumerate() {
            let preview = format!("{stage}-preview");
            let of_stage = |name: &str, s: &str| -> Vec<(f64, f64)> {
                rows.iter()
                    .filter(|r| r.stage == s)
                    .filter_map(|r| {
                        let v = if name == "loss" {
                            Some(r.loss).filter(|l| *l > 0.0)
                        } else {
                            r.get(name)
                        };
                        v.map(|v| (r.step as f64, v))
                    })
                    .filter(|(_, v)| v.is_finite())
                    .collect()
            };
            // the stage's own values, or else its evaluations'
            let of = |name: &str| {
                let own = of_stage(name, stage);
                if own.is_empty() && name != "loss" {
                    of_stage(name, &preview)
                } else {
                    own
                }
            };
            for (k, panel) in panels.iter().enumerate() {
                let mut series: Vec<Series> =
                    panel.names.iter().map(|(n, c)| (of(n), *c)).collect();
                if k >= 2 && series.iter().all(|(p, _)| p.is_empty()) {
                    continue;
                }
                let mut title = format!("{stage}: {}", panel.title);
                if panel.names.len() > 1 {
                    // the groups this stage has, in their colours' order
                    let groups: Vec<&str> = panel
                        .names
                        .iter()
                        .zip(&series)
                        .filter(|(_, (points, _))| !points.is_empty())
                        .map(|((n, _), _)| n.rsplit('/').next().unwrap_or(n))
                        .collect();
                    title.push_str(&format!(" ({})", groups.join(", ")));
                }
                for (name, beside, what) in BESIDE {
                    if panel.names.iter().any(|(n, _)| n == beside) {
                        let points = of(name);
                        if !points.is_empty() {
                            title.push_str(&format!("; grey: {what}"));
                            series.push((points, PSNR_TRUE_COLOUR));
                        }
                    }
                }
                draw_panel(&areas[k * cols + i], &title, &series, panel.log)?;
            }
        }
        Ok(())
    })
}

/// The colour of the curve of the rollout labelled `label` (as in the viewer; a rollout the
/// report does not know in the loss curves' blue).
pub fn rollout_colour(label: impl AsRef<str>) -> Rgb<u8> {
    match Rollout::of_label(label.as_ref()) {
        Some(Rollout::Dlf) => Rgb([217, 130, 43]),
        Some(Rollout::PublishedDlf) => Rgb([150, 150, 150]),
        Some(Rollout::SupervisedDlf) => Rgb([128, 60, 170]),
        Some(Rollout::NeuroFluid) => Rgb([46, 158, 91]),
        None => LOSS_COLOUR,
    }
}

const DISTANCE_W: u32 = 720;
const DISTANCE_H: u32 = 360;

/// Draws d(t) of every rollout of `report` (the paper's Table 2 as a curve): one line per model,
/// a dashed line where the grounding window ends.
pub fn render_distances(report: &EvalReport) -> RgbImage {
    let (w, h) = (DISTANCE_W, DISTANCE_H);
    let series: Vec<(String, Vec<(f64, f64)>)> = report
        .rollout_labels()
        .into_iter()
        .map(|m| {
            let points = report
                .frames
                .iter()
                .filter_map(|f| f.d.get(&m).map(|&d| (f.t as f64, d)))
                .filter(|(_, d)| d.is_finite())
                .collect::<Vec<_>>();
            (m, points)
        })
        .filter(|(_, p)| !p.is_empty())
        .collect();
    draw_image(w, h, "the distance curves", |root| {
        let e = |e: DrawingAreaErrorKind<_>| e.to_string();
        let all = || series.iter().flat_map(|(_, p)| p.iter());
        let x1 = all().map(|p| p.0).fold(1.0, f64::max);
        let y1 = all().map(|p| p.1).fold(1.0, f64::max) * 1.05;
        let mut chart = ChartBuilder::on(root)
            .caption(
                "particle distance d(t) (× 1000; 25 = one particle radius)",
                (FONT_FAMILY, 15),
            )
            .margin(10)
            .x_label_area_size(30)
            .y_label_area_size(50)
            .build_cartesian_2d(0.0..x1, 0.0..y1)
            .map_err(e)?;
        chart
            .configure_mesh()
            .x_desc("t (frames from the first test frame)")
            .label_style((FONT_FAMILY, 12))
            .draw()
            .map_err(e)?;
        let end = report.windows.grounding.1 as f64 + 0.5;
        if end < x1 {
            let grey = RGBColor(150, 150, 150);
            chart
                .draw_series(DashedLineSeries::new(
                    [(end, 0.0), (end, y1)],
                    6,
                    4,
                    grey.stroke_width(1),
                ))
                .map_err(e)?;
        }
        for (model, points) in &series {
            let colour = rgb(rollout_colour(model));
            chart
                .draw_series(LineSeries::new(
                    points.iter().copied(),
                    colour.stroke_width(2),
                ))
                .map_err(e)?
                .label(model.as_str())
                .legend(move |(x, y)| {
                    PathElement::new([(x, y), (x + 18, y)], colour.stroke_width(2))
                });
        }
        chart
            .configure_series_labels()
            .position(SeriesLabelPosition::LowerRight)
            .label_font((FONT_FAMILY, 13))
            .background_style(WHITE.mix(0.8))
            .border_style(BLACK)
            .draw()
            .map_err(e)?;
        Ok(())
    })
}

const INTERPOLATION_W: u32 = 900;
const INTERPOLATION_H: u32 = 400;

/// Draws d against d′ of `report.interpolation` (`diagnostics.interpolation_sweep`), one panel per
/// window: NeuroFluid's DLF from the pretrained weights (fraction 0) to the grounded ones (1),
/// each point labelled with its fraction, and a dashed line at the pretrained DLF's d′.
pub fn render_interpolation(report: &EvalReport) -> RgbImage {
    let (w, h) = (INTERPOLATION_W, INTERPOLATION_H);
    let points = &report.interpolation;
    draw_image(w, h, "the interpolation plot", |root| {
        let e = |e: DrawingAreaErrorKind<_>| e.to_string();
        let (g, p) = (report.windows.grounding, report.windows.prediction);
        let panels = root.split_evenly((1, 2));
        type Window = fn(&InterpolationPoint) -> [f64; 2];
        let windows: [(String, Window); 2] = [
            (format!("t = {}–{}", g.0, g.1), |i| i.grounding),
            (format!("t = {}–{}", p.0, p.1), |i| i.prediction),
        ];
        let colour = rgb(rollout_colour(Rollout::NeuroFluid));
        for (area, (title, of)) in panels.iter().zip(windows) {
            let xy: Vec<(f64, f64)> = points.iter().map(|i| (of(i)[0], of(i)[1])).collect();
            let range = |v: &mut dyn Iterator<Item = f64>| {
                let (lo, hi) = v.fold((f64::MAX, f64::MIN), |(l, h), x| (l.min(x), h.max(x)));
                let pad = ((hi - lo) * 0.1).max(0.5);
                (lo - pad)..(hi + pad)
            };
            let xs = range(&mut xy.iter().map(|p| p.0));
            let ys = range(&mut xy.iter().map(|p| p.1));
            let mut chart = ChartBuilder::on(area)
                .caption(
                    format!("d against d′, {title} (fraction of grounding's change)"),
                    (FONT_FAMILY, 14),
                )
                .margin(10)
                .x_label_area_size(30)
                .y_label_area_size(45)
                .build_cartesian_2d(xs.clone(), ys)
                .map_err(e)?;
            chart
                .configure_mesh()
                .x_desc("d (truth → prediction)")
                .y_desc("d′ (prediction → truth)")
                .label_style((FONT_FAMILY, 12))
                .draw()
                .map_err(e)?;
            if let Some(dlf) = points.iter().find(|i| i.fraction == 0.0) {
                let y = of(dlf)[1];
                chart
                    .draw_series(DashedLineSeries::new(
                        [(xs.start, y), (xs.end, y)],
                        6,
                        4,
                        rgb(rollout_colour(Rollout::Dlf)).stroke_width(1),
                    ))
                    .map_err(e)?;
            }
            chart
                .draw_series(LineSeries::new(xy.iter().copied(), colour.stroke_width(2)))
                .map_err(e)?;
            chart
                .draw_series(points.iter().zip(&xy).map(|(i, &(x, y))| {
                    EmptyElement::at((x, y))
                        + Circle::new((0, 0), 3, colour.filled())
                        + Text::new(format!("{}", i.fraction), (5, -12), (FONT_FAMILY, 11))
                }))
                .map_err(e)?;
        }
        Ok(())
    })
}

/// Writes [`render_interpolation`] of `report` as a PNG at `path` (atomically).
pub fn plot_interpolation(report: &EvalReport, path: &Path) -> Result<(), PlotError> {
    write_png(&render_interpolation(report), path)
}

/// Writes d(t) of every rollout of `report` as a PNG at `path` (atomically).
pub fn plot_distances(report: &EvalReport, path: &Path) -> Result<(), PlotError> {
    write_png(&render_distances(report), path)
}

/// Encodes `img` as a PNG and writes it at `path` (atomically).
fn write_png(img: &RgbImage, path: &Path) -> Result<(), PlotError> {
    let mut bytes = Vec::new();
    let err = |message: String| PlotError::Write {
        path: path.to_path_buf(),
        message,
    };
    img.write_to(
        &mut std::io::Cursor::new(&mut bytes),
        image::ImageFormat::Png,
    )
    .map_err(|e| err(e.to_string()))?;
    neurofluid_core::atomic::write_bytes(path, &bytes).map_err(|e| err(e.to_string()))
}

/// Writes the curves of `rows` as a PNG at `path` (atomically).
pub fn plot_curves(rows: &[MetricsRow], path: &Path) -> Result<(), PlotError> {
    write_png(&render_curves(rows), path)
}

/// Reads a `metrics.jsonl` and writes its curves as a PNG.
pub fn plot_metrics_file(jsonl: &Path, png: &Path) -> Result<(), PlotError> {
    let rows = read_jsonl(jsonl)?;
    plot_curves(&rows, png)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::metrics_log::psnr_from_mse;

    fn rows() -> Vec<MetricsRow> {
        let mut v = Vec::new();
        for s in (0..=400).step_by(10) {
            let loss = 0.2 * (-(s as f64) / 80.0).exp() + 2e-3;
            let mut r = MetricsRow::new("warmup", s, loss, s as f64);
            r.set("psnr", psnr_from_mse(loss / 2.0));
            v.push(r);
        }
        for s in 0..98 {
            let loss = 0.01 + 0.002 * (s as f64 / 10.0).sin();
            let mut r = MetricsRow::new("joint", s, loss, 400.0 + s as f64);
            r.set("psnr", psnr_from_mse(loss / 2.0));
            v.push(r);
        }
        v.push(MetricsRow::new("joint", 98, f64::NAN, 500.0));
        v
    }

    /// Pixels close to `colour` in the panel at column `col`, row `row`.
    fn coloured(img: &RgbImage, col: u32, row: u32, colour: Rgb<u8>) -> Vec<(u32, u32)> {
        let near = |p: &Rgb<u8>| (0..3).all(|k| p.0[k].abs_diff(colour.0[k]) < 40);
        let mut out = Vec::new();
        for y in row * PANEL_H..(row + 1) * PANEL_H {
            for x in col * PANEL_W..(col + 1) * PANEL_W {
                if near(img.get_pixel(x, y)) {
                    out.push((x, y));
                }
            }
        }
        out
    }

    #[test]
    fn curves_go_where_the_data_goes() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("curves.png");
        plot_curves(&rows(), &path).unwrap();
        let img = image::open(&path).unwrap().to_rgb8();
        assert_eq!((img.width(), img.height()), (2 * PANEL_W, 2 * PANEL_H));
        // warm-up loss falls: its leftmost curve pixel is higher (smaller y) than its rightmost
        let loss = coloured(&img, 0, 0, LOSS_COLOUR);
        assert!(loss.len() > 300, "{}", loss.len());
        let left = loss.iter().min_by_key(|p| p.0).unwrap();
        let right = loss.iter().max_by_key(|p| p.0).unwrap();
        assert!(left.1 + 100 < right.1, "left {left:?} right {right:?}");
        // the curve spans most of the panel's width
        assert!(right.0 - left.0 > PANEL_W * 3 / 4);
        // PSNR rises
        let psnr = coloured(&img, 0, 1, PSNR_COLOUR);
        let left = psnr.iter().min_by_key(|p| p.0).unwrap();
        let right = psnr.iter().max_by_key(|p| p.0).unwrap();
        assert!(left.1 > right.1 + 100, "left {left:?} right {right:?}");
        // the joint column has curves of both kinds, and no colour leaks across panels
        assert!(coloured(&img, 1, 0, LOSS_COLOUR).len() > 200);
        assert!(coloured(&img, 1, 1, PSNR_COLOUR).len() > 200);
        assert!(coloured(&img, 1, 0, PSNR_COLOUR).is_empty());
        // text was drawn with the bundled font (dark pixels in the title strip)
        let dark = (0..20)
            .flat_map(|y| (0..PANEL_W).map(move |x| (x, y)))
            .filter(|&(x, y)| img.get_pixel(x, y).0.iter().all(|&v| v < 100))
            .count();
        assert!(dark > 30, "{dark}");
    }

    #[test]
    fn joint_diagnostics_get_rows_of_their_own() {
        let mut rows = rows();
        // three evaluations of the joint stage: rollout d falls, the alignment rises
        for (k, step) in [32u64, 65, 98].into_iter().enumerate() {
            let mut r = MetricsRow::new("joint-preview", step, 1e-3, 500.0);
            r.set("psnr", 25.0);
            r.set("rollout_d", 40.0 - 10.0 * k as f64);
            r.set("grad_alignment", 0.1 * k as f64);
            r.set("psnr_true", 28.0);
            rows.push(r);
        }
        let img = render_curves(&rows);
        // warmup, joint and joint-preview columns; loss, PSNR, rollout d and alignment rows
        assert_eq!((img.width(), img.height()), (3 * PANEL_W, 4 * PANEL_H));
        let d = coloured(&img, 1, 2, DIAGNOSTIC_COLOUR);
        let left = d.iter().min_by_key(|p| p.0).unwrap();
        let right = d.iter().max_by_key(|p| p.0).unwrap();
        assert!(
            left.1 + 100 < right.1,
            "rollout d falls: {left:?} {right:?}"
        );
        let a = coloured(&img, 1, 3, DIAGNOSTIC_COLOUR);
        let left = a.iter().min_by_key(|p| p.0).unwrap();
        let right = a.iter().max_by_key(|p| p.0).unwrap();
        assert!(
            left.1 > right.1 + 100,
            "alignment rises: {left:?} {right:?}"
        );
        // the PSNR on the true particles is drawn in grey beside the PSNR (text and grid are
        // grey too: compare with the same plot without it)
        let without: Vec<MetricsRow> = rows
            .iter()
            .cloned()
            .map(|mut r| {
                r.remove("psnr_true");
                r
            })
            .collect();
        let grey = |img: &RgbImage| coloured(img, 1, 1, PSNR_TRUE_COLOUR).len();
        let (with, plain) = (grey(&img), grey(&render_curves(&without)));
        assert!(with > plain + 100, "{with} vs {plain}");
        // the warm-up has no diagnostics
        assert!(coloured(&img, 0, 2, DIAGNOSTIC_COLOUR).is_empty());
    }

    #[test]
    fn distances_go_where_the_data_goes() {
        use crate::report::{FrameDistance, Rollouts, Windows};
        let mut r = EvalReport::new("e", "s", "c", Windows::paper());
        // DLF drifts twice as fast as NeuroFluid; no DLF† in this report
        r.frames = (1..=59)
            .map(|t| FrameDistance {
                d: Rollouts::new()
                    .with(Rollout::NeuroFluid, Some(t as f64))
                    .with(Rollout::Dlf, Some(2.0 * t as f64)),
                ..FrameDistance::new(t)
            })
            .collect();
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("d.png");
        plot_distances(&r, &path).unwrap();
        let img = image::open(&path).unwrap().to_rgb8();
        assert_eq!((img.width(), img.height()), (DISTANCE_W, DISTANCE_H));
        let pixels = |m: Rollout| {
            let c = rollout_colour(m);
            img.enumerate_pixels()
                .filter(|(_, _, p)| (0..3).all(|k| p.0[k].abs_diff(c.0[k]) < 30))
                .map(|(x, y, _)| (x, y))
                .collect::<Vec<_>>()
        };
        let (dlf, nf) = (pixels(Rollout::Dlf), pixels(Rollout::NeuroFluid));
        assert!(
            dlf.len() > 300 && nf.len() > 300,
            "{} {}",
            dlf.len(),
            nf.len()
        );
        assert!(pixels(Rollout::SupervisedDlf).is_empty());
        // at the right end DLF (d = 118) is drawn higher (smaller y) than NeuroFluid (d = 59),
        // and both rise from left to right
        let right = |p: &[(u32, u32)]| *p.iter().max_by_key(|q| q.0).unwrap();
        let left = |p: &[(u32, u32)]| *p.iter().min_by_key(|q| q.0).unwrap();
        assert!(
            right(&dlf).1 + 100 < right(&nf).1,
            "{:?} {:?}",
            right(&dlf),
            right(&nf)
        );
        assert!(right(&nf).1 + 50 < left(&nf).1);
    }

    #[test]
    fn empty_metrics_still_give_an_image() {
        let img = render_curves(&[]);
        assert_eq!(img.width(), PANEL_W);
        let dir = tempfile::tempdir().unwrap();
        std::fs::write(dir.path().join("m.jsonl"), "").unwrap();
        plot_metrics_file(&dir.path().join("m.jsonl"), &dir.path().join("c.png")).unwrap();
        assert!(
            plot_metrics_file(&dir.path().join("none.jsonl"), &dir.path().join("c.png")).is_err()
        );
    }
}
