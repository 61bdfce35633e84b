//! Loss and PSNR curves as a PNG, drawn with `plotters` and a bundled font (no system fonts
//! needed). One column per stage (warm-up, joint, …); the top row is the loss (log scale when it
//! spans a decade or more), the bottom row the PSNR.

use std::path::{Path, PathBuf};

use image::{Rgb, RgbImage};
use plotters::prelude::*;
use plotters::style::FontStyle;

use crate::metrics_log::{MetricsError, MetricsRow, read_jsonl};

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

/// DejaVu Sans (Bitstream Vera licence, `assets/fonts/`), compiled in: plots and picture labels
/// need no system font.
const FONT: &[u8] = include_bytes!("../../../assets/fonts/DejaVuSans.ttf");
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

fn rgb(c: Rgb<u8>) -> RGBColor {
    RGBColor(c.0[0], c.0[1], c.0[2])
}

/// One panel: `points` (x = step) of one quantity, log-scaled when it spans a decade or more.
fn draw_panel<DB: DrawingBackend>(
    area: &DrawingArea<DB, plotters::coord::Shift>,
    title: &str,
    points: &[(f64, f64)],
    colour: Rgb<u8>,
    allow_log: bool,
) -> Result<(), String> {
    let e = |e: DrawingAreaErrorKind<DB::ErrorType>| e.to_string();
    if points.is_empty() {
        area.titled(title, (FONT_FAMILY, 14)).map_err(e)?;
        return Ok(());
    }
    let (mut x0, mut x1) = points
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), p| {
            (a.min(p.0), b.max(p.0))
        });
    if x1 <= x0 {
        (x0, x1) = (x0 - 1.0, x1 + 1.0);
    }
    let (lo, hi) = points
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), p| {
            (a.min(p.1), b.max(p.1))
        });
    let mut chart = ChartBuilder::on(area);
    chart
        .caption(title, (FONT_FAMILY, 14))
        .margin(8)
        .x_label_area_size(24)
        .y_label_area_size(56);
    let line = LineSeries::new(points.iter().copied(), rgb(colour).stroke_width(2));
    if allow_log && lo > 0.0 && hi / lo >= 10.0 {
        let mut c = chart
            .build_cartesian_2d(x0..x1, (lo..hi).log_scale())
            .map_err(e)?;
        c.configure_mesh()
            .label_style((FONT_FAMILY, 11))
            .y_label_formatter(&|v| format!("{v:.0e}"))
            .draw()
            .map_err(e)?;
        c.draw_series(line).map_err(e)?;
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
        c.draw_series(line).map_err(e)?;
    }
    Ok(())
}

/// Draws the curves of `rows` into an image: one column per stage (first-seen order), loss on
/// top, PSNR below; x = the stage's step. Non-finite values are skipped.
pub fn render_curves(rows: &[MetricsRow]) -> RgbImage {
    register_bundled_font();
    let mut stages: Vec<&str> = Vec::new();
    for r in rows {
        if !stages.contains(&r.stage.as_str()) {
            stages.push(&r.stage);
        }
    }
    let cols = stages.len().max(1);
    let (w, h) = (cols as u32 * PANEL_W, 2 * PANEL_H);
    let mut buf = vec![255u8; (w * h * 3) as usize];
    let drawn = (|| -> Result<(), String> {
        let root = BitMapBackend::with_buffer(&mut buf, (w, h)).into_drawing_area();
        root.fill(&WHITE).map_err(|e| e.to_string())?;
        if stages.is_empty() {
            root.draw_text(
                "no metrics",
                &(FONT_FAMILY, 16).into_text_style(&root),
                (w as i32 / 2 - 40, h as i32 / 2),
            )
            .map_err(|e| e.to_string())?;
        }
        let areas = root.split_evenly((2, cols));
        for (i, stage) in stages.iter().enumerate() {
            let of = |f: &dyn Fn(&MetricsRow) -> Option<f64>| -> Vec<(f64, f64)> {
                rows.iter()
                    .filter(|r| r.stage == *stage)
                    .filter_map(|r| f(r).map(|v| (r.step as f64, v)))
                    .filter(|(_, v)| v.is_finite())
                    .collect()
            };
            let loss = of(&|r| Some(r.loss).filter(|l| *l > 0.0));
            draw_panel(
                &areas[i],
                &format!("{stage}: loss"),
                &loss,
                LOSS_COLOUR,
                true,
            )?;
            let psnr = of(&|r| r.psnr);
            let title = format!("{stage}: PSNR (dB)");
            draw_panel(&areas[cols + i], &title, &psnr, PSNR_COLOUR, false)?;
        }
        root.present().map_err(|e| e.to_string())
    })();
    if let Err(e) = drawn {
        tracing::warn!("drawing the curves: {e}");
    }
    RgbImage::from_raw(w, h, buf).expect("buffer of the image's size")
}

/// Writes the curves of `rows` as a PNG at `path` (atomically).
pub fn plot_curves(rows: &[MetricsRow], path: &Path) -> Result<(), PlotError> {
    let img = render_curves(rows);
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
            r.psnr = Some(psnr_from_mse(loss / 2.0));
            v.push(r);
        }
        for s in 0..98 {
            let loss = 0.01 + 0.002 * (s as f64 / 10.0).sin();
            let mut r = MetricsRow::new("joint", s, loss, 400.0 + s as f64);
            r.psnr = Some(psnr_from_mse(loss / 2.0));
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
