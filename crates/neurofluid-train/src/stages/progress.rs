//! Progress bars for the training stages: loss, PSNR and rays/s as they go.

use std::time::Instant;

use indicatif::{ProgressBar, ProgressStyle};

/// A stage's progress bar (hidden when stderr is not a terminal, e.g. in CI logs).
#[derive(Debug)]
pub struct StageProgress {
    bar: ProgressBar,
    started: Instant,
    rays_per_s: f64,
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

    /// Records the latest throughput for the message.
    pub fn set_rays_per_s(&mut self, r: f64) {
        self.rays_per_s = r;
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
