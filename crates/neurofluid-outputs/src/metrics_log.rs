//! The per-run metrics file: one row per logged step, appended to `metrics.csv` (header once)
//! and `metrics.jsonl`, flushed after every row so a crashed or running job can be plotted.

use std::fs::{File, OpenOptions};
use std::io::{BufRead, BufReader, Write};
use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use crate::formats::csv_text::{cell, csv_text};
use crate::report::ImageScore;

/// CSV file name inside a run folder.
pub const CSV_FILE: &str = "metrics.csv";
/// JSON-lines file name inside a run folder.
pub const JSONL_FILE: &str = "metrics.jsonl";
/// The CSV's first columns, always written in this order (the columns of every earlier
/// release): a scalar named `a/b` goes to column `a_b`; names beyond these get columns of their
/// own after them, in the order they first arrive.
pub const CSV_HEADER: &str = "stage,step,loss,psnr,lr_physnerf,lr_dlf,rays_per_s,time_s,grad_norm_physnerf,grad_norm_dlf,ssim,lpips,rollout_d,grad_alignment,psnr_true,rollout_d_prime";

/// Keys of earlier releases' files and the scalar names they stand for.
const RENAMED: [(&str, &str); 2] = [("lr_renderer", "lr/physnerf"), ("lr_transition", "lr/dlf")];

/// Scalars with one value per parameter group: `<family>/<group>`.
pub const GROUP_FAMILIES: [&str; 2] = ["lr", "grad_norm"];

/// The scalar name of a CSV column or JSON key: `lr_dlf` (a column, or an earlier release's
/// key) is `lr/dlf`, as is an older release's `lr_transition`.
pub fn scalar_name(key: &str) -> String {
    if let Some((_, new)) = RENAMED.iter().find(|(old, _)| *old == key) {
        return new.to_string();
    }
    for family in GROUP_FAMILIES {
        if let Some(group) = key
            .strip_prefix(family)
            .and_then(|rest| rest.strip_prefix('_'))
        {
            return format!("{family}/{group}");
        }
    }
    key.to_string()
}

/// The CSV column of a scalar: `/` becomes `_`.
pub fn column_name(scalar: &str) -> String {
    scalar.replace('/', "_")
}

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

/// One logged step: its stage, step, loss and time, and whatever named scalars the step or
/// evaluation reported (`psnr`, `lr/<group>`, `grad_norm/<group>`, `rays_per_s`, `ssim`,
/// `rollout_d`, …), in the order they were set. A JSON line holds them as keys of one object.
#[derive(Debug, Clone, PartialEq)]
pub struct MetricsRow {
    /// Stage: `warmup`, `joint`, `eval`, …
    pub stage: String,
    /// 0-based iteration within the stage.
    pub step: u64,
    /// Training loss of the step (or batch mean since the last row).
    pub loss: f64,
    /// Seconds since the run (or stage) started.
    pub time_s: f64,
    /// The named scalars, each name once.
    pub scalars: Vec<(String, f64)>,
}

impl MetricsRow {
    /// A row with only the required fields set.
    pub fn new(stage: &str, step: u64, loss: f64, time_s: f64) -> Self {
        Self {
            stage: stage.to_string(),
            step,
            loss,
            time_s,
            scalars: Vec::new(),
        }
    }

    /// The scalar `name`, if the row has it.
    pub fn get(&self, name: &str) -> Option<f64> {
        self.scalars
            .iter()
            .find(|(n, _)| n == name)
            .map(|(_, v)| *v)
    }

    /// Sets the scalar `name` (replacing an earlier value).
    pub fn set(&mut self, name: &str, value: f64) {
        match self.scalars.iter_mut().find(|(n, _)| n == name) {
            Some(slot) => slot.1 = value,
            None => self.scalars.push((name.to_string(), value)),
        }
    }

    /// Sets the scalar `name` where there is a value.
    pub fn set_some(&mut self, name: &str, value: Option<f64>) {
        if let Some(v) = value {
            self.set(name, v);
        }
    }

    /// An evaluation's row of an image score: stage `eval-<view>`, step = rollout step, loss = the
    /// MSE that the PSNR stands for.
    pub fn of_image(i: &ImageScore) -> Self {
        let mut row = Self::new(
            &format!("eval-{}", i.view),
            i.t as u64,
            10f64.powf(-i.psnr / 10.0),
            0.0,
        );
        row.set("psnr", i.psnr);
        row.set_some("ssim", Some(i.ssim).filter(|v| v.is_finite()));
        row.set_some("lpips", i.lpips);
        row
    }

    /// Removes the scalar `name`.
    pub fn remove(&mut self, name: &str) {
        self.scalars.retain(|(n, _)| n != name);
    }

    /// The CSV line under `columns` (with its newline); empty cells for missing values.
    pub fn csv_line(&self, columns: &[String]) -> String {
        csv_text([columns.iter().map(|c| match c.as_str() {
            "stage" => self.stage.clone(),
            "step" => self.step.to_string(),
            "loss" => self.loss.to_string(),
            "time_s" => self.time_s.to_string(),
            c => cell(
                self.scalars
                    .iter()
                    .find(|(n, _)| column_name(n) == c)
                    .map(|(_, v)| *v),
            ),
        })])
    }
}

impl Serialize for MetricsRow {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        use serde::ser::SerializeMap;
        let mut map = s.serialize_map(Some(4 + self.scalars.len()))?;
        map.serialize_entry("stage", &self.stage)?;
        map.serialize_entry("step", &self.step)?;
        map.serialize_entry("loss", &self.loss)?;
        for (name, v) in &self.scalars {
            map.serialize_entry(name, v)?;
        }
        map.serialize_entry("time_s", &self.time_s)?;
        map.end()
    }
}

impl<'de> Deserialize<'de> for MetricsRow {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        struct Visit;
        impl<'de> serde::de::Visitor<'de> for Visit {
            type Value = MetricsRow;
            fn expecting(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
                f.write_str("a metrics row (an object with stage, step, loss and time_s)")
            }
            fn visit_map<A: serde::de::MapAccess<'de>>(
                self,
                mut m: A,
            ) -> Result<MetricsRow, A::Error> {
                use serde::de::Error;
                let (mut stage, mut step, mut loss, mut time_s) = (None, None, None, None);
                let mut row = MetricsRow::new("", 0, 0.0, 0.0);
                while let Some(key) = m.next_key::<String>()? {
                    match key.as_str() {
                        "stage" => stage = Some(m.next_value::<String>()?),
                        "step" => step = Some(m.next_value::<u64>()?),
                        "loss" => loss = Some(m.next_value::<f64>()?),
                        "time_s" => time_s = Some(m.next_value::<f64>()?),
                        // a missing value (`null`) or another kind of value is no scalar
                        _ => {
                            if let serde_json::Value::Number(n) =
                                m.next_value::<serde_json::Value>()?
                            {
                                let v =
                                    n.as_f64().ok_or_else(|| A::Error::custom("not a number"))?;
                                row.set(&scalar_name(&key), v);
                            }
                        }
                    }
                }
                row.stage = stage.ok_or_else(|| A::Error::missing_field("stage"))?;
                row.step = step.ok_or_else(|| A::Error::missing_field("step"))?;
                row.loss = loss.ok_or_else(|| A::Error::missing_field("loss"))?;
                row.time_s = time_s.ok_or_else(|| A::Error::missing_field("time_s"))?;
                Ok(row)
            }
        }
        d.deserialize_map(Visit)
    }
}

/// The CSV columns of `rows`: [`CSV_HEADER`]'s, then each further scalar's in first-seen order.
pub fn columns_of<'a>(rows: impl IntoIterator<Item = &'a MetricsRow>) -> Vec<String> {
    let mut columns: Vec<String> = CSV_HEADER.split(',').map(str::to_string).collect();
    for r in rows {
        for (name, _) in &r.scalars {
            let c = column_name(name);
            if !columns.contains(&c) {
                columns.push(c);
            }
        }
    }
    columns
}

/// The whole CSV text (header and lines) of `rows`.
fn csv_of(rows: &[MetricsRow]) -> String {
    let columns = columns_of(rows);
    let mut csv = format!("{}\n", columns.join(","));
    for r in rows {
        csv.push_str(&r.csv_line(&columns));
    }
    csv
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
    /// The CSV's columns.
    columns: Vec<String>,
}

fn io(path: &Path) -> impl FnOnce(std::io::Error) -> MetricsError + '_ {
    move |source| MetricsError::Io {
        path: path.to_path_buf(),
        source,
    }
}

fn append_to(p: &Path) -> Result<File, MetricsError> {
    OpenOptions::new()
        .create(true)
        .append(true)
        .open(p)
        .map_err(io(p))
}

impl MetricsLog {
    /// Opens (creating) the log in `dir`, appending to existing files. A CSV whose header does
    /// not begin with [`CSV_HEADER`] (an earlier release's columns) is first written again from
    /// the JSONL.
    pub fn open(dir: &Path) -> Result<Self, MetricsError> {
        std::fs::create_dir_all(dir).map_err(io(dir))?;
        let csv_path = dir.join(CSV_FILE);
        let jsonl_path = dir.join(JSONL_FILE);
        let header = File::open(&csv_path).ok().and_then(|f| {
            let mut line = String::new();
            BufReader::new(f).read_line(&mut line).ok().map(|_| line)
        });
        let header = header.map(|h| h.trim_end().to_string()).unwrap_or_default();
        let ours = header == CSV_HEADER || header.starts_with(&format!("{CSV_HEADER},"));
        if !header.is_empty() && !ours && jsonl_path.is_file() {
            return Self::open_resumed(dir, |_| true);
        }
        let mut csv = append_to(&csv_path)?;
        let jsonl = append_to(&jsonl_path)?;
        let empty = csv.metadata().map_err(io(&csv_path))?.len() == 0;
        if empty {
            writeln!(csv, "{CSV_HEADER}")
                .and_then(|()| csv.flush())
                .map_err(io(&csv_path))?;
        }
        let columns = if empty || !ours {
            columns_of([])
        } else {
            header.split(',').map(str::to_string).collect()
        };
        Ok(Self {
            csv_path,
            jsonl_path,
            csv,
            jsonl,
            columns,
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
            let mut jsonl = String::new();
            for r in &rows {
                jsonl.push_str(&serde_json::to_string(r).expect("row serialises"));
                jsonl.push('\n');
            }
            let csv_path = dir.join(CSV_FILE);
            neurofluid_core::atomic::write_bytes(&csv_path, csv_of(&rows).as_bytes())
                .map_err(io(&csv_path))?;
            neurofluid_core::atomic::write_bytes(&jsonl_path, jsonl.as_bytes())
                .map_err(io(&jsonl_path))?;
        }
        Self::open(dir)
    }

    /// Appends one row to both files and flushes them. A scalar without a CSV column yet
    /// widens the CSV: it is written again from the JSONL under the new header.
    pub fn append(&mut self, row: &MetricsRow) -> Result<(), MetricsError> {
        let json = serde_json::to_string(row).expect("row serialises");
        writeln!(self.jsonl, "{json}")
            .and_then(|()| self.jsonl.flush())
            .map_err(io(&self.jsonl_path))?;
        let new = row
            .scalars
            .iter()
            .any(|(n, _)| !self.columns.contains(&column_name(n)));
        if new {
            let rows = read_jsonl(&self.jsonl_path)?;
            let csv = csv_of(&rows);
            neurofluid_core::atomic::write_bytes(&self.csv_path, csv.as_bytes())
                .map_err(io(&self.csv_path))?;
            self.csv = append_to(&self.csv_path)?;
            self.columns = columns_of(&rows);
            return Ok(());
        }
        write!(self.csv, "{}", row.csv_line(&self.columns))
            .and_then(|()| self.csv.flush())
            .map_err(io(&self.csv_path))
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

/// Reads every row of a `metrics.csv` file, this release's or an earlier one's (columns by
/// name; `lr_dlf` is the scalar `lr/dlf`).
pub fn read_csv(path: &Path) -> Result<Vec<MetricsRow>, MetricsError> {
    let parse = |line: usize, message: String| MetricsError::Parse {
        path: path.to_path_buf(),
        line,
        message,
    };
    let mut reader = csv::Reader::from_path(path).map_err(|e| parse(1, e.to_string()))?;
    let header: Vec<String> = reader
        .headers()
        .map_err(|e| parse(1, e.to_string()))?
        .iter()
        .map(str::to_string)
        .collect();
    let mut rows = Vec::new();
    for (i, record) in reader.records().enumerate() {
        let line = i + 2;
        let record = record.map_err(|e| parse(line, e.to_string()))?;
        let mut row = MetricsRow::new("", 0, 0.0, 0.0);
        for (column, text) in header.iter().zip(record.iter()) {
            let number = || {
                text.parse::<f64>()
                    .map_err(|e| parse(line, format!("{column}: {e}")))
            };
            match column.as_str() {
                "stage" => row.stage = text.to_string(),
                "step" => {
                    row.step = text
                        .parse()
                        .map_err(|e| parse(line, format!("step: {e}")))?
                }
                "loss" => row.loss = number()?,
                "time_s" => row.time_s = number()?,
                _ if text.is_empty() => {}
                c => row.set(&scalar_name(c), number()?),
            }
        }
        rows.push(row);
    }
    Ok(rows)
}

/// Reads every row of a `metrics.jsonl` file (blank lines skipped). A last line without its
/// newline that is not a row (a write in progress, or cut short by a crash) is left out.
pub fn read_jsonl(path: &Path) -> Result<Vec<MetricsRow>, MetricsError> {
    let text = neurofluid_core::input_file::read(path).map_err(io(path))?;
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
        r.set("psnr", psnr_from_mse(loss));
        r.set("lr/physnerf", 5e-4);
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
            r.set("lr/dlf", 1e-5);
            log.append(&r).unwrap();
        }
        let csv = std::fs::read_to_string(dir.path().join(CSV_FILE)).unwrap();
        let lines: Vec<&str> = csv.lines().collect();
        assert_eq!(lines.len(), 4, "{csv}");
        assert_eq!(lines[0], CSV_HEADER);
        assert_eq!(lines.iter().filter(|l| l.starts_with("stage,")).count(), 1);
        assert_eq!(lines[1], "warmup,0,0.1,10,0.0005,,,0,,,,,,,,");
        assert_eq!(lines[3], "joint,0,0.2,,,0.00001,,9,,,,,,,,");
        let rows = read_jsonl(&dir.path().join(JSONL_FILE)).unwrap();
        assert_eq!(rows.len(), 3);
        assert_eq!(rows[1], row("warmup", 10, 0.05));
        assert_eq!(rows[2].get("lr/dlf"), Some(1e-5));
        assert_eq!(rows[2].get("psnr"), None);
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

    /// Files of an earlier release (the fixed 16 columns; `lr_physnerf`-style JSON keys, and
    /// the older `lr_renderer`/`lr_transition`) read as named scalars, and a log opened over them
    /// keeps appending under the same header.
    #[test]
    fn old_files_read_as_named_scalars() {
        let fixtures = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures");
        let csv = read_csv(&fixtures.join("metrics-v1.csv")).unwrap();
        let jsonl = read_jsonl(&fixtures.join("metrics-v1.jsonl")).unwrap();
        assert_eq!(csv.len(), 5);
        assert_eq!(jsonl.len(), 6);
        // the CSV and the JSONL of the same release say the same
        for (a, b) in csv.iter().zip(&jsonl) {
            let mut a = a.clone();
            a.scalars.sort_by(|x, y| x.0.cmp(&y.0));
            let mut b = b.clone();
            b.scalars.sort_by(|x, y| x.0.cmp(&y.0));
            assert_eq!(a, b);
        }
        let joint = &jsonl[2];
        assert_eq!((joint.stage.as_str(), joint.step), ("joint", 28));
        assert_eq!(joint.get("lr/physnerf"), Some(1e-4));
        assert_eq!(joint.get("lr/dlf"), Some(1e-4));
        assert_eq!(joint.get("grad_norm/dlf"), Some(0.33109222170497077));
        assert_eq!(joint.get("rays_per_s"), Some(599.7043510425078));
        assert_eq!(jsonl[3].get("rollout_d_prime"), Some(30.732555655048223));
        assert_eq!(jsonl[4].get("lpips"), Some(0.1003879806958139));
        assert_eq!(jsonl[5].get("lr/physnerf"), Some(4e-4));
        assert_eq!(jsonl[5].get("lr/dlf"), Some(1e-4));
        // written again, a row has the same CSV line as before
        let columns = columns_of([]);
        let old = std::fs::read_to_string(fixtures.join("metrics-v1.csv")).unwrap();
        let lines: Vec<String> = csv.iter().map(|r| r.csv_line(&columns)).collect();
        assert_eq!(old.lines().nth(3).unwrap(), lines[2].trim_end());
        // a log in a folder of old files appends under the old header
        let dir = tempfile::tempdir().unwrap();
        for f in ["metrics-v1.csv", "metrics-v1.jsonl"] {
            let to = if f.ends_with("csv") {
                CSV_FILE
            } else {
                JSONL_FILE
            };
            std::fs::copy(fixtures.join(f), dir.path().join(to)).unwrap();
        }
        let mut log = MetricsLog::open(dir.path()).unwrap();
        log.append(&row("warmup", 75, 0.08)).unwrap();
        let text = std::fs::read_to_string(dir.path().join(CSV_FILE)).unwrap();
        assert!(text.starts_with(&old), "{text}");
        assert_eq!(read_csv(&dir.path().join(CSV_FILE)).unwrap().len(), 6);
    }

    /// A scalar the CSV has no column for yet widens it; rows before it get an empty cell.
    #[test]
    fn a_new_scalar_gets_a_column_of_its_own() {
        let dir = tempfile::tempdir().unwrap();
        let mut log = MetricsLog::open(dir.path()).unwrap();
        log.append(&row("nerf", 0, 0.1)).unwrap();
        let mut r = row("nerf", 1, 0.1);
        r.set("grad_norm/nerf", 2.5);
        log.append(&r).unwrap();
        log.append(&r).unwrap();
        let csv = std::fs::read_to_string(dir.path().join(CSV_FILE)).unwrap();
        let lines: Vec<&str> = csv.lines().collect();
        assert_eq!(lines[0], format!("{CSV_HEADER},grad_norm_nerf"));
        assert!(lines[1].ends_with(",,"), "{csv}");
        assert!(
            lines[2].ends_with(",2.5") && lines[3].ends_with(",2.5"),
            "{csv}"
        );
        assert_eq!(
            read_csv(&dir.path().join(CSV_FILE)).unwrap()[2].get("grad_norm/nerf"),
            Some(2.5)
        );
        // reopened, the log keeps the wider header
        drop(log);
        MetricsLog::open(dir.path()).unwrap().append(&r).unwrap();
        let csv = std::fs::read_to_string(dir.path().join(CSV_FILE)).unwrap();
        assert_eq!(csv.lines().count(), 5);
        assert!(csv.lines().last().unwrap().ends_with(",2.5"));
    }
}
