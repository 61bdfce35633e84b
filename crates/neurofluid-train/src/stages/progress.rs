//! Progress bars for the training stages: loss, PSNR and rays/s as they go.

use std::time::Instant;

use indicatif::{ProgressBar, ProgressStyle};

use crate::metrics_log::MetricsRow;

/// A stage's progress bar (hidden when stderr is not a terminal, e.g. in CI logs).
#[derive(Debug)]
pub struct StageProgress {
    bar: ProgressBar,
    started: Instant,
    rays_per_s: f64,
    window: Instant,
    window_rays: usize,
}

impl StageProgress {
    /// A bar for steps `start..total` of stage `name`.
    pub fn new(name: &str, start: u64, total: u64) -> Self {
        let bar = ProgressBar::new(total);
        bar.set_style(
            ProgressStyle::with_template(
                "{prefix:>8} [{elapsed_precise}] {wide_bar} {pos}/{len} ({eta}) {msg}",
            )
            .expect("valid template"),
        );
        bar.set_prefix(name.to_string());
        bar.set_position(start);
        Self {
            bar,
            started: Instant::now(),
            rays_per_s: 0.0,
            window: Instant::now(),
            window_rays: 0,
        }
    }

    /// Moves the bar to `pos` and shows the latest loss and PSNR.
    pub fn update(&mut self, pos: u64, loss: f64, psnr: f64) {
        self.bar.set_position(pos);
        self.bar.set_message(format!(
            "loss {loss:.5}  PSNR {psnr:.2} dB  {:.0} rays/s",
            self.rays_per_s
        ));
    }

    /// Counts rays rendered since the last metrics row.
    pub fn add_rays(&mut self, rays: usize) {
        self.window_rays += rays;
    }

    /// A metrics row for `step` with the loss, the PSNR and the throughput since the previous
    /// row (which the bar then shows).
    pub fn row(&mut self, stage: &str, step: u64, loss: f64, psnr: f64) -> MetricsRow {
        let secs = self.window.elapsed().as_secs_f64().max(1e-9);
        self.rays_per_s = self.window_rays as f64 / secs;
        self.window = Instant::now();
        self.window_rays = 0;
        let mut row = MetricsRow::new(stage, step, loss, self.elapsed());
        row.psnr = Some(psnr);
        row.rays_per_s = Some(self.rays_per_s);
        row
    }

    /// Seconds since the bar was created.
    pub fn elapsed(&self) -> f64 {
        self.started.elapsed().as_secs_f64()
    }

    /// Finishes the bar, leaving it on screen.
    pub fn finish(&self) {
        self.bar.finish();
    }
}
