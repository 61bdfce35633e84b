//! Sweeps: one TOML names a base experiment and variants (dotted overrides); each variant
//! resolves to an [`Experiment`] with its own output folder, and the variants' reports are
//! tabulated like the paper's Table 5 (rows = variants; grounding d, prediction d, PSNR, SSIM).
//!
//! ```toml
//! base = "experiments/quick-watercube.toml"
//! set = ["joint.epochs=1"]          # optional, applied to every variant
//! [[variant]]
//! name = "no_pc"
//! label = "w/o p_c"
//! set = ["physnerf.encoding.pc=false"]
//! ```
//! Without `[[variant]]` the paper's Table 5 set is used: full, unknown initial particle positions
//! (from images), w/o p_c, σ_p, v_D, d_c.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use crate::config::{ConfigError, Experiment, from_toml_str, read_text};
use crate::csv_text::{cell as csv_cell, csv_text};
use crate::report::{EvalReport, ReportError, Summary, write_atomic};

/// Markdown table file name inside the sweep folder.
pub const TABLE_MD_FILE: &str = "table5.md";
/// CSV table file name inside the sweep folder.
pub const TABLE_CSV_FILE: &str = "table5.csv";

/// The sweep file.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SweepFile {
    /// The base experiment (relative to the working directory, else to the sweep file's folder
    /// or its parent).
    pub base: PathBuf,
    /// Output folder of the sweep; default `runs/<sweep file stem>`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub out_dir: Option<PathBuf>,
    /// Overrides applied to every variant before its own.
    #[serde(default)]
    pub set: Vec<String>,
    /// The variants; empty = [`table5_variants`].
    #[serde(default, rename = "variant")]
    pub variants: Vec<Variant>,
}

/// One variant.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Variant {
    /// Short name (folder name): letters, digits, `_`, `-`, `.`.
    pub name: String,
    /// Row label in the table; default the name.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub label: Option<String>,
    /// Dotted overrides, e.g. `physnerf.encoding.pc=false`.
    #[serde(default)]
    pub set: Vec<String>,
}

/// The paper's Table 5: the full model, the initial particles recovered from images instead of
/// given ("unknown initial particle positions"), and each particle encoding switched off.
pub fn table5_variants() -> Vec<Variant> {
    let v = |name: &str, label: &str, set: &[&str]| Variant {
        name: name.into(),
        label: Some(label.into()),
        set: set.iter().map(|s| s.to_string()).collect(),
    };
    vec![
        v("full", "Full model", &[]),
        v(
            "from_images",
            "Unknown initial particle positions",
            &["scene.initial=from_images"],
        ),
        v("no_pc", "w/o p_c", &["physnerf.encoding.pc=false"]),
        v(
            "no_sigma_p",
            "w/o σ_p",
            &["physnerf.encoding.sigma_p=false"],
        ),
        v("no_vd", "w/o v_D", &["physnerf.encoding.vd=false"]),
        v("no_dc", "w/o d_c", &["physnerf.encoding.dc=false"]),
    ]
}

/// A variant resolved into a runnable experiment.
#[derive(Debug, Clone, PartialEq)]
pub struct ResolvedVariant {
    /// Variant name.
    pub name: String,
    /// Table row label.
    pub label: String,
    /// The experiment (name `<base>-<variant>`, out dir `<sweep out>/<variant>`).
    pub experiment: Experiment,
}

/// A loaded sweep.
#[derive(Debug, Clone, PartialEq)]
pub struct Sweep {
    /// Sweep name (the file stem).
    pub name: String,
    /// Output folder.
    pub out_dir: PathBuf,
    /// Variants in file order.
    pub variants: Vec<ResolvedVariant>,
}

impl Sweep {
    /// Reads a sweep file, loads its base experiment and resolves every variant.
    pub fn load(path: &Path) -> Result<Self, ConfigError> {
        let text = read_text(path)?;
        let file: SweepFile = from_toml_str(&text, path)?;
        let name = path
            .file_stem()
            .map_or_else(|| "sweep".into(), |s| s.to_string_lossy().into_owned());
        let base_path = locate_base(&file.base, path);
        let base = Experiment::load(&base_path)?;
        Self::resolve(&name, path, &file, &base)
    }

    /// Resolves `file`'s variants on top of `base` (`origin` names the sweep file in errors).
    pub fn resolve(
        name: &str,
        origin: &Path,
        file: &SweepFile,
        base: &Experiment,
    ) -> Result<Self, ConfigError> {
        let invalid = |key: &str, message: String| ConfigError::Invalid {
            path: origin.to_path_buf(),
            location: None,
            key: key.into(),
            message,
        };
        let out_dir = file
            .out_dir
            .clone()
            .unwrap_or_else(|| PathBuf::from("runs").join(name));
        let variants = if file.variants.is_empty() {
            table5_variants()
        } else {
            file.variants.clone()
        };
        let mut resolved: Vec<ResolvedVariant> = Vec::new();
        for (i, v) in variants.iter().enumerate() {
            let key = format!("variant[{i}].name");
            if v.name.is_empty()
                || !v
                    .name
                    .chars()
                    .all(|c| c.is_ascii_alphanumeric() || matches!(c, '_' | '-' | '.'))
                || v.name.starts_with('.')
            {
                return Err(invalid(
                    &key,
                    format!("`{}`: expected letters, digits, `_`, `-` or `.`", v.name),
                ));
            }
            if resolved.iter().any(|r| r.name == v.name) {
                return Err(invalid(&key, format!("`{}` is used twice", v.name)));
            }
            let mut exp = base.clone();
            for spec in file.set.iter().chain(&v.set) {
                exp.apply_override(spec).map_err(|e| match e {
                    ConfigError::Invalid { key, message, .. } => invalid(
                        &format!("variant `{}`: {key}", v.name),
                        format!("override `{spec}`: {message}"),
                    ),
                    other => other,
                })?;
            }
            exp.name = format!("{}-{}", base.name, v.name);
            exp.out_dir = Some(out_dir.join(&v.name));
            resolved.push(ResolvedVariant {
                name: v.name.clone(),
                label: v.label.clone().unwrap_or_else(|| v.name.clone()),
                experiment: exp,
            });
        }
        Ok(Self {
            name: name.into(),
            out_dir,
            variants: resolved,
        })
    }
}

/// The base file: as given (relative to the working directory), else relative to the sweep
/// file's folder, else to that folder's parent (sweeps in `experiments/` naming
/// `experiments/x.toml`); the path as given when none exists (the load error names it).
fn locate_base(base: &Path, sweep_file: &Path) -> PathBuf {
    if base.is_absolute() || base.exists() {
        return base.to_path_buf();
    }
    let dir = sweep_file.parent().unwrap_or(Path::new(""));
    [dir.join(base), dir.join("..").join(base)]
        .into_iter()
        .find(|p| p.exists())
        .unwrap_or_else(|| base.to_path_buf())
}

/// One row of the Table-5-shaped table.
#[derive(Debug, Clone, PartialEq)]
pub struct TableRow {
    /// Row label.
    pub label: String,
    /// The variant's summary (`None` when the variant produced no report).
    pub summary: Option<Summary>,
}

/// Builds the table rows from each variant's report (`None` = missing or failed run).
pub fn table_rows(rows: &[(String, Option<EvalReport>)]) -> Vec<TableRow> {
    rows.iter()
        .map(|(label, r)| TableRow {
            label: label.clone(),
            summary: r.as_ref().map(EvalReport::summary),
        })
        .collect()
}

fn cell(v: Option<f64>, digits: usize) -> String {
    v.map_or_else(|| "–".into(), |x| format!("{x:.digits$}"))
}

/// The markdown table: rows = variants; grounding d, prediction d (×1000, lower is better),
/// PSNR, SSIM, LPIPS (means over every test render).
pub fn table_markdown(title: &str, rows: &[TableRow]) -> String {
    let mut md = format!(
        "## {title}\n\n| variant | grounding d ↓ | prediction d ↓ | PSNR ↑ | SSIM ↑ | LPIPS ↓ |\n|---|---:|---:|---:|---:|---:|\n"
    );
    for r in rows {
        let s = r.summary.as_ref();
        let _ = writeln!(
            md,
            "| {} | {} | {} | {} | {} | {} |",
            r.label,
            cell(s.and_then(|s| s.grounding.neurofluid_d), 2),
            cell(s.and_then(|s| s.prediction.neurofluid_d), 2),
            cell(s.and_then(|s| s.all.psnr), 2),
            cell(s.and_then(|s| s.all.ssim), 4),
            cell(s.and_then(|s| s.all.lpips), 4)
        );
    }
    md
}

/// The CSV table (same columns as the markdown; empty cells for missing values).
pub fn table_csv(rows: &[TableRow]) -> String {
    let header = [
        "variant",
        "grounding_d",
        "prediction_d",
        "psnr",
        "ssim",
        "lpips",
    ]
    .map(String::from)
    .to_vec();
    let body = rows.iter().map(|r| {
        let s = r.summary.as_ref();
        vec![
            r.label.clone(),
            csv_cell(s.and_then(|s| s.grounding.neurofluid_d)),
            csv_cell(s.and_then(|s| s.prediction.neurofluid_d)),
            csv_cell(s.and_then(|s| s.all.psnr)),
            csv_cell(s.and_then(|s| s.all.ssim)),
            csv_cell(s.and_then(|s| s.all.lpips)),
        ]
    });
    csv_text(std::iter::once(header).chain(body))
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
    use crate::report::{FrameDistance, ImageScore, Windows};

    fn base() -> Experiment {
        Experiment::from_toml_str(
            "name = \"quick\"\n[scene]\nbuiltin = \"watercube\"\n",
            Path::new("base.toml"),
        )
        .unwrap()
    }

    fn sweep(text: &str) -> Result<Sweep, ConfigError> {
        let file: SweepFile = from_toml_str(text, Path::new("s.toml"))?;
        Sweep::resolve("s", Path::new("s.toml"), &file, &base())
    }

    #[test]
    fn default_variants_are_table5() {
        let s = sweep("base = \"b.toml\"\nset = [\"joint.epochs=1\"]\n").unwrap();
        let names: Vec<&str> = s.variants.iter().map(|v| v.name.as_str()).collect();
        assert_eq!(
            names,
            [
                "full",
                "from_images",
                "no_pc",
                "no_sigma_p",
                "no_vd",
                "no_dc"
            ]
        );
        let initial: Vec<_> = s
            .variants
            .iter()
            .map(|v| v.experiment.scene.initial)
            .collect();
        assert_eq!(initial[1], crate::config::InitialParticles::FromImages);
        assert!(
            initial
                .iter()
                .enumerate()
                .all(|(i, &x)| (x == crate::config::InitialParticles::FromImages) == (i == 1))
        );
        let enc: Vec<_> = s
            .variants
            .iter()
            .filter(|v| v.name != "from_images")
            .map(|v| v.experiment.physnerf.encoding)
            .collect();
        assert!(enc[0].pc && enc[0].sigma_p && enc[0].vd && enc[0].dc);
        assert!(!enc[1].pc && enc[1].sigma_p && enc[1].vd && enc[1].dc);
        assert!(enc[2].pc && !enc[2].sigma_p && enc[2].vd && enc[2].dc);
        assert!(enc[3].pc && enc[3].sigma_p && !enc[3].vd && enc[3].dc);
        assert!(enc[4].pc && enc[4].sigma_p && enc[4].vd && !enc[4].dc);
        assert!(s.variants.iter().all(|v| v.experiment.joint.epochs == 1));
        let dirs: std::collections::HashSet<_> =
            s.variants.iter().map(|v| v.experiment.out_dir()).collect();
        assert_eq!(dirs.len(), 6);
        assert_eq!(
            s.variants[2].experiment.out_dir(),
            PathBuf::from("runs/s/no_pc")
        );
        assert_eq!(s.variants[2].experiment.name, "quick-no_pc");
        assert_eq!(s.variants[3].label, "w/o σ_p");
    }

    #[test]
    fn explicit_variants_and_errors() {
        let s = sweep(
            "base = \"b\"\nout_dir = \"runs/x\"\n[[variant]]\nname = \"a\"\n[[variant]]\nname = \"b\"\nset = [\"joint.physnerf_optim.lr=1e-4\"]\n",
        )
        .unwrap();
        assert_eq!(s.variants.len(), 2);
        assert_eq!(s.variants[0].label, "a");
        assert_eq!(s.variants[1].experiment.joint.physnerf_optim.lr, 1e-4);
        assert_eq!(
            s.variants[1].experiment.out_dir(),
            PathBuf::from("runs/x/b")
        );
        let err =
            sweep("base = \"b\"\n[[variant]]\nname = \"a\"\nset = [\"joint.lr_renderr=1\"]\n")
                .unwrap_err();
        assert!(err.key().contains("joint.lr_renderr"), "{err}");
        assert!(err.to_string().contains("s.toml"), "{err}");
        let err = sweep("base = \"b\"\n[[variant]]\nname = \"a\"\n[[variant]]\nname = \"a\"\n")
            .unwrap_err();
        assert!(err.to_string().contains("twice"), "{err}");
        let err = sweep("base = \"b\"\n[[variant]]\nname = \"../a\"\n").unwrap_err();
        assert_eq!(err.key(), "variant[0].name");
        let err = sweep("base = \"b\"\n[[variant]]\nnme = \"a\"\n").unwrap_err();
        assert!(err.key().contains("nme"), "{err}");
    }

    #[test]
    fn table_has_one_row_per_variant() {
        let report = |d: f64, psnr: f64| {
            let mut r = EvalReport::new("e", "s", "c", Windows::paper());
            for t in 1..=59 {
                let nf = if t < 50 { d } else { 2.0 * d };
                r.frames.push(FrameDistance {
                    supervised_dlf: None,
                    reverse: Default::default(),
                    t,
                    neurofluid: nf,
                    dlf: None,
                });
                r.images.push(ImageScore {
                    view: "view_5".into(),
                    t,
                    psnr,
                    ssim: 0.5,
                    lpips: Some(0.25),
                });
            }
            r
        };
        let rows = table_rows(&[
            ("Full model".into(), Some(report(10.0, 30.0))),
            ("w/o p_c".into(), Some(report(12.5, 28.0))),
            ("w/o d_c".into(), None),
        ]);
        let dir = tempfile::tempdir().unwrap();
        let md = write_table(dir.path(), "Table 5", &rows).unwrap();
        assert!(
            md.contains("| Full model | 10.00 | 20.00 | 30.00 | 0.5000 | 0.2500 |"),
            "{md}"
        );
        assert!(
            md.contains("| w/o p_c | 12.50 | 25.00 | 28.00 | 0.5000 | 0.2500 |"),
            "{md}"
        );
        assert!(md.contains("| w/o d_c | – | – | – | – | – |"), "{md}");
        let csv = std::fs::read_to_string(dir.path().join(TABLE_CSV_FILE)).unwrap();
        let lines: Vec<&str> = csv.lines().collect();
        assert_eq!(lines[0], "variant,grounding_d,prediction_d,psnr,ssim,lpips");
        assert_eq!(lines[1], "Full model,10,20,30,0.5,0.25");
        assert_eq!(lines[3], "w/o d_c,,,,,");
        assert_eq!(
            std::fs::read_to_string(dir.path().join(TABLE_MD_FILE)).unwrap(),
            md
        );
    }
}
