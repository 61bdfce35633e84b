//! Loss and PSNR curves as a PNG, drawn with the `image` crate and an embedded 8×8 bitmap font
//! (no system fonts needed). One column per stage (warm-up, joint, …); the top row is the loss
//! (log scale when it spans a decade or more), the bottom row the PSNR.

use std::path::{Path, PathBuf};

use image::{Rgb, RgbImage};

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
const MARGIN_L: u32 = 64;
const MARGIN_R: u32 = 14;
const MARGIN_T: u32 = 22;
const MARGIN_B: u32 = 26;
const WHITE: Rgb<u8> = Rgb([255, 255, 255]);
const BLACK: Rgb<u8> = Rgb([0, 0, 0]);
const GRID: Rgb<u8> = Rgb([225, 225, 225]);
/// Colour of the loss curves.
pub const LOSS_COLOUR: Rgb<u8> = Rgb([31, 90, 180]);
/// Colour of the PSNR curves.
pub const PSNR_COLOUR: Rgb<u8> = Rgb([200, 60, 30]);

/// An RGB image to draw on (pixels outside it are ignored).
pub(crate) struct Canvas {
    pub(crate) img: RgbImage,
}

impl Canvas {
    /// A white canvas.
    pub(crate) fn white(width: u32, height: u32) -> Self {
        Self {
            img: RgbImage::from_pixel(width, height, WHITE),
        }
    }

    pub(crate) fn put(&mut self, x: i64, y: i64, c: Rgb<u8>) {
        if x >= 0 && y >= 0 && (x as u32) < self.img.width() && (y as u32) < self.img.height() {
            self.img.put_pixel(x as u32, y as u32, c);
        }
    }

    /// Bresenham line, `width` pixels thick (square pen).
    fn line(&mut self, (x0, y0): (i64, i64), (x1, y1): (i64, i64), c: Rgb<u8>, width: i64) {
        let (dx, dy) = ((x1 - x0).abs(), -(y1 - y0).abs());
        let (sx, sy) = (if x0 < x1 { 1 } else { -1 }, if y0 < y1 { 1 } else { -1 });
        let (mut x, mut y, mut err) = (x0, y0, dx + dy);
        loop {
            for ox in 0..width {
                for oy in 0..width {
                    self.put(x + ox - width / 2, y + oy - width / 2, c);
                }
            }
            if x == x1 && y == y1 {
                break;
            }
            let e2 = 2 * err;
            if e2 >= dy {
                err += dy;
                x += sx;
            }
            if e2 <= dx {
                err += dx;
                y += sy;
            }
        }
    }

    /// Text with the 8×8 public-domain font; non-ASCII characters are drawn as `?`.
    pub(crate) fn text(&mut self, x: i64, y: i64, s: &str, c: Rgb<u8>) {
        for (i, ch) in s.chars().enumerate() {
            let code = if ch.is_ascii() {
                ch as usize
            } else {
                '?' as usize
            };
            let glyph = font8x8::legacy::BASIC_LEGACY[code];
            for (row, bits) in glyph.iter().enumerate() {
                for col in 0..8 {
                    if bits >> col & 1 == 1 {
                        self.put(x + i as i64 * 8 + col, y + row as i64, c);
                    }
                }
            }
        }
    }
}

/// An axis mapping data values to pixels.
#[derive(Debug, Clone, Copy)]
struct Axis {
    lo: f64,
    hi: f64,
    log: bool,
}

impl Axis {
    fn fit(values: &[f64], allow_log: bool) -> Self {
        let lo = values.iter().copied().fold(f64::INFINITY, f64::min);
        let hi = values.iter().copied().fold(f64::NEG_INFINITY, f64::max);
        if allow_log && lo > 0.0 && hi / lo >= 10.0 {
            return Self {
                lo: lo.log10().floor(),
                hi: hi.log10().ceil(),
                log: true,
            };
        }
        let pad = if hi > lo {
            0.05 * (hi - lo)
        } else {
            0.5 * lo.abs().max(1e-3)
        };
        Self {
            lo: lo - pad,
            hi: hi + pad,
            log: false,
        }
    }

    /// Position in [0, 1] of a value.
    fn frac(&self, v: f64) -> f64 {
        let v = if self.log { v.log10() } else { v };
        (v - self.lo) / (self.hi - self.lo)
    }

    /// Tick values and labels.
    fn ticks(&self) -> Vec<(f64, String)> {
        if self.log {
            let (a, b) = (self.lo as i64, self.hi as i64);
            let step = ((b - a) / 6).max(1);
            return (a..=b)
                .step_by(step as usize)
                .map(|k| (10f64.powi(k as i32), format!("1e{k}")))
                .collect();
        }
        nice_ticks(self.lo, self.hi, 6)
            .into_iter()
            .map(|t| (t, tick_label(t)))
            .collect()
    }
}

/// Ticks at 1, 2 or 5 × 10^k inside [lo, hi], at most about `max` of them.
pub fn nice_ticks(lo: f64, hi: f64, max: usize) -> Vec<f64> {
    if !(lo.is_finite() && hi.is_finite()) || hi <= lo {
        return vec![lo];
    }
    let raw = (hi - lo) / max.max(1) as f64;
    let mag = 10f64.powf(raw.log10().floor());
    let step = [1.0, 2.0, 5.0, 10.0]
        .into_iter()
        .map(|m| m * mag)
        .find(|s| *s >= raw)
        .unwrap_or(10.0 * mag);
    let first = (lo / step).ceil() as i64;
    let last = (hi / step).floor() as i64;
    (first..=last).map(|k| k as f64 * step).collect()
}

/// A short label: integers plainly, otherwise up to 3 significant decimals or an exponent.
fn tick_label(v: f64) -> String {
    if v == 0.0 {
        return "0".into();
    }
    let a = v.abs();
    if !(1e-3..1e5).contains(&a) {
        return format!("{v:.0e}");
    }
    if (v - v.round()).abs() < 1e-9 * a.max(1.0) {
        return format!("{}", v.round() as i64);
    }
    let s = format!("{v:.3}");
    s.trim_end_matches('0').trim_end_matches('.').to_string()
}

struct Panel {
    x0: u32,
    y0: u32,
    title: String,
    points: Vec<(f64, f64)>,
    colour: Rgb<u8>,
    allow_log: bool,
}

fn draw_panel(cv: &mut Canvas, p: &Panel) {
    let (px, py) = (p.x0 + MARGIN_L, p.y0 + MARGIN_T);
    let (pw, ph) = (PANEL_W - MARGIN_L - MARGIN_R, PANEL_H - MARGIN_T - MARGIN_B);
    cv.text(i64::from(px), i64::from(p.y0) + 6, &p.title, BLACK);
    let to_px = |fx: f64, fy: f64| -> (i64, i64) {
        (
            i64::from(px) + (fx * f64::from(pw - 1)).round() as i64,
            i64::from(py + ph - 1) - (fy * f64::from(ph - 1)).round() as i64,
        )
    };
    if p.points.is_empty() {
        cv.text(
            i64::from(px + pw / 2) - 28,
            i64::from(py + ph / 2),
            "no data",
            BLACK,
        );
    } else {
        let xs: Vec<f64> = p.points.iter().map(|q| q.0).collect();
        let ys: Vec<f64> = p.points.iter().map(|q| q.1).collect();
        let xa = Axis::fit(&xs, false);
        let xa = Axis {
            lo: xs.iter().copied().fold(f64::INFINITY, f64::min),
            hi: xs
                .iter()
                .copied()
                .fold(f64::NEG_INFINITY, f64::max)
                .max(xa.lo + 1.0),
            log: false,
        };
        let ya = Axis::fit(&ys, p.allow_log);
        for (v, label) in ya.ticks() {
            let f = ya.frac(v);
            if !(0.0..=1.0).contains(&f) {
                continue;
            }
            let (_, y) = to_px(0.0, f);
            cv.line((i64::from(px), y), (i64::from(px + pw - 1), y), GRID, 1);
            cv.line((i64::from(px) - 4, y), (i64::from(px), y), BLACK, 1);
            cv.text(
                i64::from(px) - 6 - 8 * label.len() as i64,
                y - 4,
                &label,
                BLACK,
            );
        }
        for t in nice_ticks(xa.lo, xa.hi, 5) {
            let f = xa.frac(t);
            if !(0.0..=1.0).contains(&f) {
                continue;
            }
            let (x, _) = to_px(f, 0.0);
            cv.line((x, i64::from(py)), (x, i64::from(py + ph - 1)), GRID, 1);
            cv.line(
                (x, i64::from(py + ph)),
                (x, i64::from(py + ph + 3)),
                BLACK,
                1,
            );
            let label = tick_label(t);
            cv.text(
                x - 4 * label.len() as i64,
                i64::from(py + ph) + 6,
                &label,
                BLACK,
            );
        }
        let mut prev: Option<(i64, i64)> = None;
        for &(x, y) in &p.points {
            let q = to_px(xa.frac(x), ya.frac(y));
            match prev {
                Some(a) => cv.line(a, q, p.colour, 2),
                None => cv.line(q, q, p.colour, 3),
            }
            prev = Some(q);
        }
    }
    // frame
    let (l, t) = (i64::from(px), i64::from(py));
    let (r, b) = (i64::from(px + pw - 1), i64::from(py + ph - 1));
    cv.line((l, t), (r, t), BLACK, 1);
    cv.line((l, b), (r, b), BLACK, 1);
    cv.line((l, t), (l, b), BLACK, 1);
    cv.line((r, t), (r, b), BLACK, 1);
}

/// Draws the curves of `rows` into an image: one column per stage (first-seen order), loss on
/// top, PSNR below; x = the stage's step. Non-finite values are skipped.
pub fn render_curves(rows: &[MetricsRow]) -> RgbImage {
    let mut stages: Vec<&str> = Vec::new();
    for r in rows {
        if !stages.contains(&r.stage.as_str()) {
            stages.push(&r.stage);
        }
    }
    let cols = stages.len().max(1) as u32;
    let mut cv = Canvas {
        img: RgbImage::from_pixel(cols * PANEL_W, 2 * PANEL_H, WHITE),
    };
    for (i, stage) in stages.iter().enumerate() {
        let of = |f: &dyn Fn(&MetricsRow) -> Option<f64>| -> Vec<(f64, f64)> {
            rows.iter()
                .filter(|r| r.stage == *stage)
                .filter_map(|r| f(r).map(|v| (r.step as f64, v)))
                .filter(|(_, v)| v.is_finite())
                .collect()
        };
        let x0 = i as u32 * PANEL_W;
        draw_panel(
            &mut cv,
            &Panel {
                x0,
                y0: 0,
                title: format!("{stage}: loss vs step"),
                points: of(&|r| Some(r.loss).filter(|l| *l > 0.0)),
                colour: LOSS_COLOUR,
                allow_log: true,
            },
        );
        draw_panel(
            &mut cv,
            &Panel {
                x0,
                y0: PANEL_H,
                title: format!("{stage}: PSNR (dB) vs step"),
                points: of(&|r| r.psnr),
                colour: PSNR_COLOUR,
                allow_log: false,
            },
        );
    }
    if stages.is_empty() {
        cv.text(
            i64::from(PANEL_W / 2) - 40,
            i64::from(PANEL_H),
            "no metrics",
            BLACK,
        );
    }
    cv.img
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

    /// Pixels of `colour` in the panel at column `col`, row `row`.
    fn coloured(img: &RgbImage, col: u32, row: u32, colour: Rgb<u8>) -> Vec<(u32, u32)> {
        let mut out = Vec::new();
        for y in row * PANEL_H..(row + 1) * PANEL_H {
            for x in col * PANEL_W..(col + 1) * PANEL_W {
                if *img.get_pixel(x, y) == colour {
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
        // the curve spans the plot width
        assert!(right.0 - left.0 > PANEL_W - MARGIN_L - MARGIN_R - 10);
        // PSNR rises
        let psnr = coloured(&img, 0, 1, PSNR_COLOUR);
        let left = psnr.iter().min_by_key(|p| p.0).unwrap();
        let right = psnr.iter().max_by_key(|p| p.0).unwrap();
        assert!(left.1 > right.1 + 100, "left {left:?} right {right:?}");
        // the joint column has curves of both kinds, and no colour leaks across panels
        assert!(coloured(&img, 1, 0, LOSS_COLOUR).len() > 200);
        assert!(coloured(&img, 1, 1, PSNR_COLOUR).len() > 200);
        assert!(coloured(&img, 1, 0, PSNR_COLOUR).is_empty());
        // labels were drawn (black pixels left of the plot area)
        let black = (0..PANEL_H)
            .flat_map(|y| (0..MARGIN_L).map(move |x| (x, y)))
            .filter(|&(x, y)| *img.get_pixel(x, y) == BLACK)
            .count();
        assert!(black > 50);
    }

    #[test]
    fn nice_ticks_are_round_numbers() {
        assert_eq!(
            nice_ticks(0.0, 400.0, 5),
            vec![0.0, 100.0, 200.0, 300.0, 400.0]
        );
        assert_eq!(
            nice_ticks(0.3, 1.0, 4),
            vec![0.4, 0.6000000000000001, 0.8, 1.0]
        );
        assert_eq!(nice_ticks(12.0, 31.0, 6), vec![15.0, 20.0, 25.0, 30.0]);
        assert_eq!(tick_label(0.6000000000000001), "0.6");
        assert_eq!(tick_label(200.0), "200");
        assert_eq!(tick_label(2e-5), "2e-5");
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
