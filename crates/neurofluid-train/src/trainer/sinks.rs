//! The sinks the CLI attaches to a stage: a progress bar, the metrics log, the preview pictures.

use std::path::PathBuf;

use indicatif::{ProgressBar, ProgressStyle};
use neurofluid_physnerf::save_png;

use super::{Event, EventSink};
use neurofluid_outputs::metrics_log::{MetricsLog, MetricsRow};

/// A progress bar per stage with the latest loss, PSNR and throughput (hidden when stderr is
/// not a terminal, e.g. in CI logs).
#[derive(Debug, Default)]
pub struct ProgressBars {
    bar: Option<ProgressBar>,
    rays_per_s: Option<f64>,
}

impl ProgressBars {
    /// No bar until a stage starts.
    pub fn new() -> Self {
        Self::default()
    }
}

impl EventSink for ProgressBars {
    fn on_event(&mut self, event: &Event<'_>) -> anyhow::Result<()> {
        match event {
            Event::Started {
                stage,
                start,
                total,
                ..
            } => {
                let bar = ProgressBar::new(*total);
                bar.set_style(
                    ProgressStyle::with_template(
                        "{prefix:>8} [{elapsed_precise}] {wide_bar} {pos}/{len} ({eta}) {msg}",
                    )
                    .expect("valid template"),
                );
                bar.set_prefix(stage.to_string());
                bar.set_position(*start);
                self.bar = Some(bar);
            }
            Event::Step { done, stats, .. } => {
                if let Some(bar) = &self.bar {
                    bar.set_position(*done);
                    let mut msg = format!("loss {:.5}", stats.loss);
                    if let Some(p) = stats.psnr {
                        msg.push_str(&format!("  PSNR {p:.2} dB"));
                    }
                    if let Some(r) = self.rays_per_s {
                        msg.push_str(&format!("  {r:.0} rays/s"));
                    }
                    bar.set_message(msg);
                }
            }
            Event::Logged(row) => self.rays_per_s = row.get("rays_per_s"),
            Event::Evaluated {
                stage,
                done,
                evaluation,
                ..
            } => {
                let mut line = format!("{stage} step {done}:");
                if let Some(p) = evaluation.psnr {
                    line.push_str(&format!(" preview PSNR {p:.2} dB"));
                }
                for (name, v) in &evaluation.scores {
                    line.push_str(&format!(" {name} {v:.6}"));
                }
                // a hidden bar (stderr not a terminal) prints nothing: the log keeps the line
                match &self.bar {
                    Some(bar) if !bar.is_hidden() => bar.println(line),
                    _ => tracing::info!("{line}"),
                }
            }
            Event::Diverged { message, .. } => {
                if let Some(bar) = &self.bar {
                    bar.abandon_with_message(message.to_string());
                }
            }
            Event::Finished { .. } => {
                if let Some(bar) = self.bar.take() {
                    bar.finish();
                }
            }
            Event::Stopped { stage, done } => {
                if let Some(bar) = self.bar.take() {
                    bar.abandon_with_message(format!("{stage} stopped after step {done}"));
                }
            }
            Event::Checkpointed { .. } => {}
        }
        Ok(())
    }
}

/// The run's metrics log: the driver's rows, and one row per evaluation holding its named
/// scores: `<stage>-preview` for an evaluation with a PSNR (its loss is the MSE that PSNR
/// stands for; the joint stage's diagnostics), `<stage>-validation` for one without (its loss is
/// its first score: DLF†'s one-step error).
#[derive(Debug)]
pub struct MetricsSink<'a>(pub &'a mut MetricsLog);

impl EventSink for MetricsSink<'_> {
    fn on_event(&mut self, event: &Event<'_>) -> anyhow::Result<()> {
        match event {
            Event::Logged(row) => self.0.append(row)?,
            Event::Evaluated {
                stage,
                done,
                time_s,
                evaluation,
            } => {
                let mut row = match (evaluation.psnr, evaluation.scores.first()) {
                    (Some(psnr), _) => {
                        let mse = 10f64.powf(-psnr / 10.0);
                        let mut row =
                            MetricsRow::new(&format!("{stage}-preview"), *done, mse, *time_s);
                        row.set("psnr", psnr);
                        row
                    }
                    (None, Some((_, first))) => {
                        MetricsRow::new(&format!("{stage}-validation"), *done, *first, *time_s)
                    }
                    (None, None) => return Ok(()),
                };
                for (name, v) in &evaluation.scores {
                    row.set(name, *v);
                }
                self.0.append(&row)?;
            }
            _ => {}
        }
        Ok(())
    }
}

/// Writes every evaluation's picture to `<run>/<stage>/previews/<stage>_<step>.png`.
#[derive(Debug)]
pub struct PreviewWriter {
    run_dir: PathBuf,
}

impl PreviewWriter {
    /// Pictures go under the stage folders of `run_dir`.
    pub fn new(run_dir: impl Into<PathBuf>) -> Self {
        Self {
            run_dir: run_dir.into(),
        }
    }
}

impl EventSink for PreviewWriter {
    fn on_event(&mut self, event: &Event<'_>) -> anyhow::Result<()> {
        if let Event::Evaluated {
            stage,
            done,
            evaluation,
            ..
        } = event
            && let Some(p) = &evaluation.picture
        {
            let path = self
                .run_dir
                .join(stage)
                .join("previews")
                .join(format!("{stage}_{done:07}.png"));
            save_png(&path, p.width, p.height, &p.rgb)?;
            tracing::info!(stage, step = done, psnr = evaluation.psnr, "preview");
        }
        Ok(())
    }
}

/// Redraws `curves.png` from the metrics log whenever a stage finishes.
#[derive(Debug)]
pub struct CurvesPlot {
    jsonl: PathBuf,
    png: PathBuf,
}

impl CurvesPlot {
    /// Plots the rows of `jsonl` into `png`.
    pub fn new(jsonl: impl Into<PathBuf>, png: impl Into<PathBuf>) -> Self {
        Self {
            jsonl: jsonl.into(),
            png: png.into(),
        }
    }
}

impl EventSink for CurvesPlot {
    fn on_event(&mut self, event: &Event<'_>) -> anyhow::Result<()> {
        if let Event::Finished { .. } | Event::Stopped { .. } = event {
            neurofluid_outputs::pictures::plot::plot_metrics_file(&self.jsonl, &self.png)?;
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use std::io::Write;
    use std::sync::{Arc, Mutex};

    use super::*;
    use crate::trainer::Evaluation;

    #[derive(Clone, Default)]
    struct Captured(Arc<Mutex<Vec<u8>>>);

    impl Write for Captured {
        fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
            self.0.lock().unwrap().extend_from_slice(buf);
            Ok(buf.len())
        }
        fn flush(&mut self) -> std::io::Result<()> {
            Ok(())
        }
    }

    /// Under a stage's bar, hidden when stderr is not a terminal (this test's), every
    /// evaluation's line still reaches the log: `pretrain-dlf`'s validation errors were lost.
    #[test]
    fn evaluations_reach_the_log_under_a_hidden_bar() {
        let out = Captured::default();
        let writer = out.clone();
        let subscriber = tracing_subscriber::fmt()
            .with_writer(move || writer.clone())
            .with_ansi(false)
            .finish();
        tracing::subscriber::with_default(subscriber, || {
            let mut bars = ProgressBars::new();
            bars.on_event(&Event::Started {
                stage: "pretrain-dlf",
                start: 0,
                total: 10,
                resumed_from: None,
            })
            .unwrap();
            assert!(bars.bar.as_ref().is_some_and(|b| b.is_hidden()));
            let evaluation = Evaluation {
                scores: vec![("whole_seq_err", 0.0123)],
                ..Evaluation::default()
            };
            bars.on_event(&Event::Evaluated {
                stage: "pretrain-dlf",
                done: 5,
                time_s: 1.0,
                evaluation: &evaluation,
            })
            .unwrap();
        });
        let text = String::from_utf8(out.0.lock().unwrap().clone()).unwrap();
        assert!(
            text.contains("pretrain-dlf step 5: whole_seq_err 0.012300"),
            "{text}"
        );
    }
}
