//! The sweep's table, like the paper's Table 5: a row per run (variant and seed) with its state,
//! grounding d and prediction d (×1000, lower is better), PSNR, SSIM and LPIPS (means over every
//! test render), and for a variant run under several seeds a row of mean ± standard deviation
//! over the seeds that finished. Runs without a report keep their row, marked with their state.

use std::fmt::Write as _;
use std::path::Path;

use crate::formats::csv_text::{cell as csv_cell, csv_text};
use crate::formats::markup::markdown_text;
use crate::report::{ReportError, Rollout, Summary, write_atomic};

/// Markdown table file name inside the sweep folder.
pub const TABLE_MD_FILE: &str = "table5.md";
/// CSV table file name inside the sweep folder.
pub const TABLE_CSV_FILE: &str = "table5.csv";

/// The state of a run whose report is in the table.
pub const DONE: &str = "done";

/// One run's row.
#[derive(Debug, Clone, PartialEq)]
pub struct TableRow {
    /// The variant's label (rows of one variant follow each other).
    pub label: String,
    /// The run's seed.
    pub seed: u64,
    /// [`DONE`] with a report; otherwise why there is none (`pending`, `running`, `failed`, …).
    pub state: String,
    /// The run's summary (`None` without a report).
    pub summary: Option<Summary>,
}

/// The metric columns: header, CSV header, digits in markdown.
const COLUMNS: [(&str, &str, usize); 5] = [
    ("grounding d ↓", "grounding_d", 2),
    ("prediction d ↓", "prediction_d", 2),
    ("PSNR ↑", "psnr", 2),
    ("SSIM ↑", "ssim", 4),
    ("LPIPS ↓", "lpips", 4),
];

/// The metric columns' values of a summary.
fn values(s: &Summary) -> [Option<f64>; 5] {
    [
        s.grounding.d_of(Rollout::NeuroFluid),
        s.prediction.d_of(Rollout::NeuroFluid),
        s.all.psnr,
        s.all.ssim,
        s.all.lpips,
    ]
}

/// Mean and sample standard deviation (`None` below two values) of `xs`; `None` when empty.
fn mean_sd(xs: &[f64]) -> Option<(f64, Option<f64>)> {
    if xs.is_empty() {
        return None;
    }
    let n = xs.len() as f64;
    let mean = xs.iter().sum::<f64>() / n;
    let sd = (xs.len() > 1)
        .then(|| (xs.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / (n - 1.0)).sqrt());
    Some((mean, sd))
}

/// Over the seeds of one variant: per column, the mean and spread of the finished runs.
struct Aggregate {
    finished: usize,
    runs: usize,
    columns: [Option<(f64, Option<f64>)>; 5],
}

impl Aggregate {
    fn of(rows: &[TableRow]) -> Self {
        let summaries: Vec<[Option<f64>; 5]> = rows
            .iter()
            .filter_map(|r| r.summary.as_ref())
            .map(values)
            .collect();
        let columns = std::array::from_fn(|c| {
            let xs: Vec<f64> = summaries.iter().filter_map(|v| v[c]).collect();
            mean_sd(&xs)
        });
        Self {
            finished: summaries.len(),
            runs: rows.len(),
            columns,
        }
    }

    fn count(&self) -> String {
        format!("{} of {}", self.finished, self.runs)
    }
}

/// The rows in groups of one variant each (consecutive rows with one label).
fn groups(rows: &[TableRow]) -> Vec<&[TableRow]> {
    rows.chunk_by(|a, b| a.label == b.label).collect()
}

fn cell(v: Option<f64>, digits: usize) -> String {
    v.map_or_else(|| "–".into(), |x| format!("{x:.digits$}"))
}

/// The markdown table.
pub fn table_markdown(title: &str, rows: &[TableRow]) -> String {
    let headers: Vec<&str> = COLUMNS.iter().map(|c| c.0).collect();
    let mut md = format!(
        "## {}\n\n| variant | seed | state | {} |\n|---|---|---|{}\n",
        markdown_text(title),
        headers.join(" | "),
        "---:|".repeat(COLUMNS.len())
    );
    for group in groups(rows) {
        for r in group {
            let v = r.summary.as_ref().map(values).unwrap_or_default();
            let cells: Vec<String> = COLUMNS.iter().zip(v).map(|(c, x)| cell(x, c.2)).collect();
            let _ = writeln!(
                md,
                "| {} | {} | {} | {} |",
                markdown_text(&r.label),
                r.seed,
                r.state,
                cells.join(" | ")
            );
        }
        if group.len() > 1 {
            let a = Aggregate::of(group);
            let cells: Vec<String> = COLUMNS
                .iter()
                .zip(&a.columns)
                .map(|(c, m)| match m {
                    Some((mean, Some(sd))) => format!("{mean:.d$} ± {sd:.d$}", d = c.2),
                    Some((mean, None)) => cell(Some(*mean), c.2),
                    None => "–".into(),
                })
                .collect();
            let _ = writeln!(
                md,
                "| **{}** | mean ± sd | {} | {} |",
                markdown_text(&group[0].label),
                a.count(),
                cells.join(" | ")
            );
        }
    }
    md
}

/// The CSV table: a line per run, then for a variant with several seeds a `mean` and an `sd`
/// line (state: how many of its runs finished); empty cells for missing values.
pub fn table_csv(rows: &[TableRow]) -> String {
    let header = ["variant", "seed", "state"]
        .into_iter()
        .chain(COLUMNS.iter().map(|c| c.1))
        .map(String::from)
        .collect::<Vec<_>>();
    let mut records = vec![header];
    for group in groups(rows) {
        for r in group {
            let v = r.summary.as_ref().map(values).unwrap_or_default();
            records.push(
                [r.label.clone(), r.seed.to_string(), r.state.clone()]
                    .into_iter()
                    .chain(v.into_iter().map(csv_cell))
                    .collect(),
            );
        }
        if group.len() > 1 {
            let a = Aggregate::of(group);
            for (what, pick) in [
                ("mean", (|m: &(f64, Option<f64>)| Some(m.0)) as fn(&_) -> _),
                ("sd", |m: &(f64, Option<f64>)| m.1),
            ] {
                records.push(
                    [group[0].label.clone(), what.into(), a.count()]
                        .into_iter()
                        .chain(
                            a.columns
                                .iter()
                                .map(|m| csv_cell(m.as_ref().and_then(pick))),
                        )
                        .collect(),
                );
            }
        }
    }
    csv_text(records)
}

/// Writes `table5.md` and `table5.csv` into `dir` atomically; returns the markdown.
pub fn write_table(dir: &Path, title: &str, rows: &[TableRow]) -> Result<String, ReportError> {
    let md = table_markdown(title, rows);
    write_atomic(&dir.join(TABLE_MD_FILE), &md)?;
    write_atomic(&dir.join(TABLE_CSV_FILE), &table_csv(rows))?;
    Ok(md)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::report::{EvalReport, FrameDistance, ImageScore, Rollouts, Windows};

    /// A report whose d is `d` over the grounding window and `2d` over the prediction window.
    fn summary(d: f64, psnr: f64) -> Summary {
        let mut r = EvalReport::new("e", "s", "c", Windows::paper());
        for t in 1..=59 {
            let nf = if t < 50 { d } else { 2.0 * d };
            r.frames.push(FrameDistance {
                d: Rollouts::new().with(Rollout::NeuroFluid, Some(nf)),
                ..FrameDistance::new(t)
            });
            r.images.push(ImageScore {
                view: "view_5".into(),
                t,
                psnr,
                ssim: 0.5,
                lpips: Some(0.25),
                error_on_fluid: None,
            });
        }
        r.summary()
    }

    fn row(label: &str, seed: u64, s: Option<Summary>) -> TableRow {
        TableRow {
            label: label.into(),
            seed,
            state: if s.is_some() { DONE } else { "failed" }.into(),
            summary: s,
        }
    }

    #[test]
    fn a_row_per_run_and_mean_and_spread_over_finished_seeds() {
        let rows = [
            row("Full model", 10, Some(summary(10.0, 30.0))),
            row("Full model", 11, Some(summary(12.0, 28.0))),
            row("Full model", 12, None),
            row("w/o p_c", 10, Some(summary(12.5, 28.0))),
            row("w/o d_c", 10, None),
        ];
        let dir = tempfile::tempdir().unwrap();
        let md = write_table(dir.path(), "Table 5", &rows).unwrap();
        let lines: Vec<&str> = md.lines().collect();
        assert_eq!(
            lines[2],
            "| variant | seed | state | grounding d ↓ | prediction d ↓ | PSNR ↑ | SSIM ↑ | LPIPS ↓ |"
        );
        assert_eq!(
            lines[4],
            "| Full model | 10 | done | 10.00 | 20.00 | 30.00 | 0.5000 | 0.2500 |"
        );
        assert_eq!(lines[6], "| Full model | 12 | failed | – | – | – | – | – |");
        // mean 11, sd √2 (d); mean 22, sd 2√2 (prediction d); PSNR 29 ± √2
        assert_eq!(
            lines[7],
            "| **Full model** | mean ± sd | 2 of 3 | 11.00 ± 1.41 | 22.00 ± 2.83 | 29.00 ± 1.41 \
             | 0.5000 ± 0.0000 | 0.2500 ± 0.0000 |"
        );
        assert_eq!(
            lines[8],
            "| w/o p_c | 10 | done | 12.50 | 25.00 | 28.00 | 0.5000 | 0.2500 |"
        );
        assert_eq!(lines[9], "| w/o d_c | 10 | failed | – | – | – | – | – |");
        assert_eq!(lines.len(), 10, "{md}");
        let csv = std::fs::read_to_string(dir.path().join(TABLE_CSV_FILE)).unwrap();
        let lines: Vec<&str> = csv.lines().collect();
        assert_eq!(
            lines[0],
            "variant,seed,state,grounding_d,prediction_d,psnr,ssim,lpips"
        );
        assert_eq!(lines[1], "Full model,10,done,10,20,30,0.5,0.25");
        assert_eq!(lines[3], "Full model,12,failed,,,,,");
        assert_eq!(lines[4], "Full model,mean,2 of 3,11,22,29,0.5,0.25");
        let sd: Vec<f64> = lines[5]
            .split(',')
            .skip(3)
            .map(|x| x.parse().unwrap())
            .collect();
        let root2 = 2f64.sqrt();
        assert_eq!(lines[5].split(',').nth(1), Some("sd"));
        for (got, want) in sd.iter().zip([root2, 2.0 * root2, root2, 0.0, 0.0]) {
            assert!((got - want).abs() < 1e-12, "{got} vs {want}");
        }
        assert_eq!(lines[7], "w/o d_c,10,failed,,,,,");
        assert_eq!(lines.len(), 8);
        assert_eq!(
            std::fs::read_to_string(dir.path().join(TABLE_MD_FILE)).unwrap(),
            md
        );
    }

    #[test]
    fn a_variant_without_finished_seeds_has_an_empty_mean() {
        let rows = [row("a", 1, None), row("a", 2, Some(summary(3.0, 20.0)))];
        let md = table_markdown("t", &rows);
        assert!(
            md.contains("| **a** | mean ± sd | 1 of 2 | 3.00 | 6.00 | 20.00 | 0.5000 | 0.2500 |"),
            "{md}"
        );
        let md = table_markdown("t", &[row("a", 1, None), row("a", 2, None)]);
        assert!(
            md.contains("| **a** | mean ± sd | 0 of 2 | – | – | – | – | – |"),
            "{md}"
        );
    }
}
