//! The per-run metrics file: one row per logged step, appended to `metrics.csv` (header once)
//! and `metrics.jsonl`, flushed after every row so a crashed or running job can be plotted.

use std::fs::{File, OpenOptions};
use std::io::{BufRead, BufReader, Write};
use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use crate::csv_text::{cell, csv_text};

/// CSV file name inside a run folder.
pub const CSV_FILE: &str = "metrics.csv";
/// JSON-lines file name inside a run folder.
pub const JSONL_FILE: &str = "metrics.jsonl";
/// The CSV header.
pub const CSV_HEADER: &str = "stage,step,loss,psnr,lr_physnerf,lr_dlf,rays_per_s,time_s,grad_norm_physnerf,grad_norm_dlf,reads_per_step,read_bytes_per_step,uploads_per_step,upload_bytes_per_step,ssim,lpips,rollout_d,grad_alignment,psnr_true,rollout_d_prime";

/// Errors of the metrics log.
#[derive(Debug, thiserror::Error)]
pub enum MetricsError {
    /// A file could not be opened, read or written.
    #[error("metrics file {}", path.display())]
    Io {
        /// The file.
        path: PathBuf,
        /// The IO error.
        source: std::io::Error,
    },
    /// A line of the JSONL file is not a metrics row.
    #[error("metrics file {}, line {line}: {message}", path.display())]
    Parse {
        /// The file.
        path: PathBuf,
        /// 1-based line.
        line: usize,
        /// What is wrong.
        message: String,
    },
}

/// One logged step.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct MetricsRow {
    /// Stage: `warmup`, `joint`, `eval`, …
    pub stage: String,
    /// 0-based iteration within the stage.
    pub step: u64,
    /// Training loss of the step (or batch mean since the last row).
    pub loss: f64,
    /// PSNR (dB) of the step's batch or of an evaluation.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub psnr: Option<f64>,
    /// PhysNeRF's learning rate (the warm-up's only one).
    #[serde(
        default,
        alias = "lr_renderer",
        skip_serializing_if = "Option::is_none"
    )]
    pub lr_physnerf: Option<f64>,
    /// DLF's learning rate (joint stage, supervised DLF).
    #[serde(
        default,
        alias = "lr_transition",
        skip_serializing_if = "Option::is_none"
    )]
    pub lr_dlf: Option<f64>,
    /// Throughput in rays per second.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub rays_per_s: Option<f64>,
    /// Seconds since the run (or stage) started.
    pub time_s: f64,
    /// L2 norm of PhysNeRF's gradients in the update.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub grad_norm_physnerf: Option<f64>,
    /// L2 norm of DLF's gradients in the update.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub grad_norm_dlf: Option<f64>,
    /// Device → host reads per step (mean over the steps since the previous row; the step and
    /// the trainer's state check, `neurofluid_core::transfer`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub reads_per_step: Option<f64>,
    /// Bytes read per step (as `reads_per_step`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub read_bytes_per_step: Option<f64>,
    /// Host → device uploads per step (as `reads_per_step`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub uploads_per_step: Option<f64>,
    /// Bytes uploaded per step (as `reads_per_step`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub upload_bytes_per_step: Option<f64>,
    /// SSIM of an evaluation render.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub ssim: Option<f64>,
    /// LPIPS of an evaluation render.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub lpips: Option<f64>,
    /// Joint stage: d (× 1000) of DLF's rollout over the training frames against the truth.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub rollout_d: Option<f64>,
    /// Joint stage: mean cosine between the image gradient's descent direction at the
    /// prediction and the true error.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub grad_alignment: Option<f64>,
    /// Joint stage: the renderer's PSNR on the true particles of training frames.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub psnr_true: Option<f64>,
    /// Joint stage: d′ (× 1000, from each predicted particle to the nearest true one) of the
    /// same rollout as `rollout_d`: spray that d does not see.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub rollout_d_prime: Option<f64>,
}

impl MetricsRow {
    /// A row with only the required fields set.
    pub fn new(stage: &str, step: u64, loss: f64, time_s: f64) -> Self {
        Self {
            stage: stage.to_string(),
            step,
            loss,
            psnr: None,
            lr_physnerf: None,
            lr_dlf: None,
            rays_per_s: None,
            time_s,
            grad_norm_physnerf: None,
            grad_norm_dlf: None,
            reads_per_step: None,
            read_bytes_per_step: None,
            uploads_per_step: None,
            upload_bytes_per_step: None,
            ssim: None,
            lpips: None,
            rollout_d: None,
            grad_alignment: None,
            psnr_true: None,
            rollout_d_prime: None,
        }
    }

    /// Sets the column named `name` (`rollout_d`, `rollout_d_prime`, `grad_alignment`,
    /// `psnr_true`); false for a
    /// name that is not a column.
    pub fn set_score(&mut self, name: &str, value: f64) -> bool {
        let slot = match name {
            "rollout_d" => &mut self.rollout_d,
            "rollout_d_prime" => &mut self.rollout_d_prime,
            "grad_alignment" => &mut self.grad_alignment,
            "psnr_true" => &mut self.psnr_true,
            _ => return false,
        };
        *slot = Some(value);
        true
    }

    /// The CSV line (with its newline); empty cells for missing values.
    pub fn csv_line(&self) -> String {
        csv_text([[
            self.stage.clone(),
            self.step.to_string(),
            self.loss.to_string(),
            cell(self.psnr),
            cell(self.lr_physnerf),
            cell(self.lr_dlf),
            cell(self.rays_per_s),
            self.time_s.to_string(),
            cell(self.grad_norm_physnerf),
            cell(self.grad_norm_dlf),
            cell(self.reads_per_step),
            cell(self.read_bytes_per_step),
            cell(self.uploads_per_step),
            cell(self.upload_bytes_per_step),
            cell(self.ssim),
            cell(self.lpips),
            cell(self.rollout_d),
            cell(self.grad_alignment),
            cell(self.psnr_true),
            cell(self.rollout_d_prime),
        ]])
    }
}

/// PSNR (dB) of a mean squared error on [0, 1] colours: −10·log10(mse).
pub fn psnr_from_mse(mse: f64) -> f64 {
    -10.0 * mse.log10()
}

/// An open metrics log (both files kept open in append mode).
#[derive(Debug)]
pub struct MetricsLog {
    csv_path: PathBuf,
    jsonl_path: PathBuf,
    csv: File,
    jsonl: File,
}

fn io(path: &Path) -> impl FnOnce(std::io::Error) -> MetricsError + '_ {
    move |source| MetricsError::Io {
        path: path.to_path_buf(),
        source,
    }
}

impl MetricsLog {
    /// Opens (creating) the log in `dir`, appending to existing files. A CSV written under
    /// another header (an earlier release's columns) is first written again from the JSONL.
    pub fn open(dir: &Path) -> Result<Self, MetricsError> {
        std::fs::create_dir_all(dir).map_err(io(dir))?;
        let csv_path = dir.join(CSV_FILE);
        let jsonl_path = dir.join(JSONL_FILE);
        let header = File::open(&csv_path).ok().and_then(|f| {
            let mut line = String::new();
            BufReader::new(f).read_line(&mut line).ok().map(|_| line)
        });
        if header.is_some_and(|h| !h.is_empty() && h.trim_end() != CSV_HEADER)
            && jsonl_path.is_file()
        {
            return Self::open_resumed(dir, |_| true);
        }
        let open = |p: &Path| {
            OpenOptions::new()
                .create(true)
                .append(true)
                .open(p)
                .map_err(io(p))
        };
        let mut csv = open(&csv_path)?;
        let jsonl = open(&jsonl_path)?;
        let empty = csv.metadata().map_err(io(&csv_path))?.len() == 0;
        if empty {
            writeln!(csv, "{CSV_HEADER}")
                .and_then(|()| csv.flush())
                .map_err(io(&csv_path))?;
        }
        Ok(Self {
            csv_path,
            jsonl_path,
            csv,
            jsonl,
        })
    }

    /// Opens the log for a resumed run: keeps only the existing rows for which `keep` is true
    /// (e.g. rows logged before the checkpoint), rewriting both files atomically, then appends.
    pub fn open_resumed(
        dir: &Path,
        keep: impl Fn(&MetricsRow) -> bool,
    ) -> Result<Self, MetricsError> {
        let jsonl_path = dir.join(JSONL_FILE);
        if jsonl_path.exists() {
            let rows: Vec<MetricsRow> = read_jsonl(&jsonl_path)?.into_iter().filter(keep).collect();
            let mut csv = format!("{CSV_HEADER}\n");
            let mut jsonl = String::new();
            for r in &rows {
                csv.push_str(&r.csv_line());
                jsonl.push_str(&serde_json::to_string(r).expect("row serialises"));
                jsonl.push('\n');
            }
            let csv_path = dir.join(CSV_FILE);
            neurofluid_core::atomic::write_bytes(&csv_path, csv.as_bytes())
                .map_err(io(&csv_path))?;
            neurofluid_core::atomic::write_bytes(&jsonl_path, jsonl.as_bytes())
                .map_err(io(&jsonl_path))?;
        }
        Self::open(dir)
    }

    /// Appends one row to both files and flushes them.
    pub fn append(&mut self, row: &MetricsRow) -> Result<(), MetricsError> {
        write!(self.csv, "{}", row.csv_line())
            .and_then(|()| self.csv.flush())
            .map_err(io(&self.csv_path))?;
        let json = serde_json::to_string(row).expect("row serialises");
        writeln!(self.jsonl, "{json}")
            .and_then(|()| self.jsonl.flush())
            .map_err(io(&self.jsonl_path))?;
        Ok(())
    }

    /// The JSONL file (read it back with [`read_jsonl`]).
    pub fn jsonl_path(&self) -> &Path {
        &self.jsonl_path
    }

    /// The CSV file.
    pub fn csv_path(&self) -> &Path {
        &self.csv_path
    }
}

/// Reads every row of a `metrics.jsonl` file (blank lines skipped). A last line without its
/// newline that is not a row (a write in progress, or cut short by a crash) is left out.
pub fn read_jsonl(path: &Path) -> Result<Vec<MetricsRow>, MetricsError> {
    let text = std::fs::read(path).map_err(io(path))?;
    let text = String::from_utf8_lossy(&text);
    let torn = !text.is_empty() && !text.ends_with('\n');
    let lines: Vec<&str> = text.lines().collect();
    let mut rows = Vec::new();
    for (i, line) in lines.iter().enumerate() {
        if line.trim().is_empty() {
            continue;
        }
        match serde_json::from_str(line) {
            Ok(row) => rows.push(row),
            Err(_) if torn && i + 1 == lines.len() => {
                tracing::debug!("{}: leaving out the unfinished last line", path.display());
            }
            Err(e) => {
                return Err(MetricsError::Parse {
                    path: path.to_path_buf(),
                    line: i + 1,
                    message: e.to_string(),
                });
            }
        }
    }
    Ok(rows)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn row(stage: &str, step: u64, loss: f64) -> MetricsRow {
        let mut r = MetricsRow::new(stage, step, loss, step as f64 * 0.5);
        r.psnr = Some(psnr_from_mse(loss));
        r.lr_physnerf = Some(5e-4);
        r
    }

    #[test]
    fn psnr_of_known_mse() {
        assert!((psnr_from_mse(0.01) - 20.0).abs() < 1e-12);
        assert!((psnr_from_mse(1e-3) - 30.0).abs() < 1e-12);
    }

    #[test]
    fn rows_append_to_csv_and_jsonl_with_one_header() {
        let dir = tempfile::tempdir().unwrap();
        {
            let mut log = MetricsLog::open(dir.path()).unwrap();
            log.append(&row("warmup", 0, 0.1)).unwrap();
            log.append(&row("warmup", 10, 0.05)).unwrap();
            // readable while the log is still open (flushed per row)
            assert_eq!(read_jsonl(log.jsonl_path()).unwrap().len(), 2);
        }
        {
            let mut log = MetricsLog::open(dir.path()).unwrap();
            let mut r = MetricsRow::new("joint", 0, 0.2, 9.0);
            r.lr_dlf = Some(1e-5);
            log.append(&r).unwrap();
        }
        let csv = std::fs::read_to_string(dir.path().join(CSV_FILE)).unwrap();
        let lines: Vec<&str> = csv.lines().collect();
        assert_eq!(lines.len(), 4, "{csv}");
        assert_eq!(lines[0], CSV_HEADER);
        assert_eq!(lines.iter().filter(|l| l.starts_with("stage,")).count(), 1);
        // (four empty cells more since issue 30: the host–device copies per step)
        assert_eq!(lines[1], "warmup,0,0.1,10,0.0005,,,0,,,,,,,,,,,,");
        assert_eq!(lines[3], "joint,0,0.2,,,0.00001,,9,,,,,,,,,,,,");
        let rows = read_jsonl(&dir.path().join(JSONL_FILE)).unwrap();
        assert_eq!(rows.len(), 3);
        assert_eq!(rows[1], row("warmup", 10, 0.05));
        assert_eq!(rows[2].lr_dlf, Some(1e-5));
        assert_eq!(rows[2].psnr, None);
    }

    #[test]
    fn a_csv_of_other_columns_is_rewritten_from_the_jsonl() {
        let dir = tempfile::tempdir().unwrap();
        {
            let mut log = MetricsLog::open(dir.path()).unwrap();
            log.append(&row("warmup", 0, 0.1)).unwrap();
        }
        // an earlier release's header and row
        let old = "stage,step,loss\nwarmup,0,0.1\n";
        std::fs::write(dir.path().join(CSV_FILE), old).unwrap();
        let mut log = MetricsLog::open(dir.path()).unwrap();
        log.append(&row("warmup", 10, 0.05)).unwrap();
        let csv = std::fs::read_to_string(dir.path().join(CSV_FILE)).unwrap();
        let lines: Vec<&str> = csv.lines().collect();
        assert_eq!(lines.len(), 3, "{csv}");
        assert_eq!(lines[0], CSV_HEADER);
        assert!(lines[1].starts_with("warmup,0,0.1,10,"), "{csv}");
        assert!(lines[2].starts_with("warmup,10,0.05,"), "{csv}");
    }

    #[test]
    fn resume_drops_rows_after_the_checkpoint() {
        let dir = tempfile::tempdir().unwrap();
        let mut log = MetricsLog::open(dir.path()).unwrap();
        for s in [0, 10, 20, 30] {
            log.append(&row("warmup", s, 0.1)).unwrap();
        }
        drop(log);
        let mut log = MetricsLog::open_resumed(dir.path(), |r| r.step <= 10).unwrap();
        log.append(&row("warmup", 20, 0.07)).unwrap();
        let rows = read_jsonl(&dir.path().join(JSONL_FILE)).unwrap();
        assert_eq!(rows.iter().map(|r| r.step).collect::<Vec<_>>(), [0, 10, 20]);
        assert_eq!(rows[2].loss, 0.07);
        let csv = std::fs::read_to_string(dir.path().join(CSV_FILE)).unwrap();
        assert_eq!(csv.lines().count(), 4);
    }

    /// A crash in the middle of a row leaves a torn last line: reads leave it out (and only it),
    /// and a resume rewrites the file without it.
    #[test]
    fn resume_drops_a_torn_last_line() {
        let dir = tempfile::tempdir().unwrap();
        let mut log = MetricsLog::open(dir.path()).unwrap();
        for s in [1, 2] {
            log.append(&row("warmup", s, 0.1)).unwrap();
        }
        drop(log);
        let p = dir.path().join(JSONL_FILE);
        let mut text = std::fs::read_to_string(&p).unwrap();
        text.push_str("{\"stage\":\"warmup\",\"st");
        std::fs::write(&p, &text).unwrap();
        assert_eq!(read_jsonl(&p).unwrap().len(), 2);
        let log = MetricsLog::open_resumed(dir.path(), |_| true).unwrap();
        drop(log);
        let rows = read_jsonl(&p).unwrap();
        assert_eq!(rows.iter().map(|r| r.step).collect::<Vec<_>>(), [1, 2]);
        // a bad line that is not the torn tail still fails
        std::fs::write(&p, format!("not json\n{text}")).unwrap();
        assert!(MetricsLog::open_resumed(dir.path(), |_| true).is_err());
    }

    #[test]
    fn bad_jsonl_line_is_named() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join(JSONL_FILE);
        std::fs::write(
            &p,
            "{\"stage\":\"w\",\"step\":0,\"loss\":1,\"time_s\":0}\nnot json\n",
        )
        .unwrap();
        let err = read_jsonl(&p).unwrap_err();
        assert!(err.to_string().contains("line 2"), "{err}");
    }
}
