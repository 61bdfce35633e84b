//! Sweeps: one TOML names a base experiment, variants (dotted overrides) and optionally seeds;
//! each variant (under each seed) resolves to an [`Experiment`] with its own run folder, and the
//! runs' reports are tabulated like the paper's Table 5 (rows = variants and seeds; grounding d,
//! prediction d, PSNR, SSIM, LPIPS; mean ± standard deviation over the seeds).
//!
//! ```toml
//! base = "experiments/quick-watercube.toml"
//! set = ["joint.epochs=1"]          # optional, applied to every variant
//! seeds = [10, 11, 12]              # optional: every variant once per seed
//! [[variant]]
//! name = "no_pc"
//! label = "w/o p_c"
//! set = ["physnerf.encoding.pc=false"]
//! [slurm]                           # optional: defaults of `sweep --slurm`
//! partition = "gpu"
//! ```
//! Without `[[variant]]` the paper's Table 5 set is used: full, unknown initial particle positions
//! (from images), w/o p_c, σ_p, v_D, d_c.
//!
//! A sweep runs in one process (`sweep FILE`), one run at a time (`sweep FILE --variant I`, what
//! each task of a Slurm array runs: [`slurm`]), and records each run's state in its folder
//! ([`state`]); `neurofluid_outputs::sweep_table` collects whatever has finished.

pub mod slurm;
pub mod state;

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use crate::config::{ConfigError, Experiment, from_toml_str, read_text};

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
    /// Seeds: every variant runs once per seed (its run folder `<variant>-seed<N>`); empty =
    /// once, with the base experiment's seed (or the one its overrides set).
    #[serde(default)]
    pub seeds: Vec<u64>,
    /// The variants; empty = [`table5_variants`].
    #[serde(default, rename = "variant")]
    pub variants: Vec<Variant>,
    /// Defaults of `sweep --slurm` (its options override them).
    #[serde(default)]
    pub slurm: slurm::SlurmOptions,
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

/// One run of a sweep: a variant (under one of the sweep's seeds) resolved into a runnable
/// experiment.
#[derive(Debug, Clone, PartialEq)]
pub struct ResolvedVariant {
    /// The run's name, its folder in the sweep folder: the variant's name, with `-seed<N>` when
    /// the sweep lists seeds.
    pub name: String,
    /// The variant's name.
    pub variant: String,
    /// Table row label.
    pub label: String,
    /// The experiment's seed.
    pub seed: u64,
    /// The experiment (name `<base>-<run>`, out dir `<sweep out>/<run>`).
    pub experiment: Experiment,
}

/// A loaded sweep.
#[derive(Debug, Clone, PartialEq)]
pub struct Sweep {
    /// Sweep name (the file stem).
    pub name: String,
    /// Output folder.
    pub out_dir: PathBuf,
    /// The runs: the variants in file order, each under every seed in order.
    pub variants: Vec<ResolvedVariant>,
    /// The file's `[slurm]` defaults.
    pub slurm: slurm::SlurmOptions,
    /// The sweep file as read.
    pub file: SweepFile,
    /// The base experiment as loaded.
    pub base: Experiment,
}

/// The folder of a sweep folder where a submission's frozen sweep file and base experiment go.
pub const SUBMITTED_DIR: &str = "submitted";

impl Sweep {
    /// Reads a sweep file, loads its base experiment and resolves every variant.
    pub fn load(path: &Path) -> Result<Self, ConfigError> {
        let text = read_text(path)?;
        let file: SweepFile = from_toml_str(&text, path)?;
        let name = path
            .file_stem()
            .map_or_else(|| "sweep".into(), |s| s.to_string_lossy().into_owned());
        let base_path = locate(&file.base, path);
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
            if resolved.iter().any(|r| r.variant == v.name) {
                return Err(invalid(&key, format!("`{}` is used twice", v.name)));
            }
            let mut exp = base.clone();
            let specs: Vec<&String> = file.set.iter().chain(&v.set).collect();
            exp.apply_overrides(&specs).map_err(|e| match e {
                ConfigError::Invalid {
                    path, key, message, ..
                } => invalid(
                    &format!("variant `{}`: {key}", v.name),
                    format!("{}: {message}", path.display()),
                ),
                other => other,
            })?;
            let label = v.label.clone().unwrap_or_else(|| v.name.clone());
            let seeds: Vec<Option<u64>> = if file.seeds.is_empty() {
                vec![None]
            } else {
                file.seeds.iter().copied().map(Some).collect()
            };
            for seed in seeds {
                let mut exp = exp.clone();
                let name = match seed {
                    Some(seed) => {
                        exp.seed = seed;
                        format!("{}-seed{seed}", v.name)
                    }
                    None => v.name.clone(),
                };
                exp.name = format!("{}-{name}", base.name);
                exp.out_dir = Some(out_dir.join(&name));
                resolved.push(ResolvedVariant {
                    name,
                    variant: v.name.clone(),
                    label: label.clone(),
                    seed: exp.seed,
                    experiment: exp,
                });
            }
        }
        if let Some(i) = (1..file.seeds.len()).find(|&i| file.seeds[..i].contains(&file.seeds[i])) {
            return Err(invalid(
                &format!("seeds[{i}]"),
                format!("seed {} is listed twice", file.seeds[i]),
            ));
        }
        file.slurm.validate(origin)?;
        Ok(Self {
            name: name.into(),
            out_dir,
            variants: resolved,
            slurm: file.slurm.clone(),
            file: file.clone(),
            base: base.clone(),
        })
    }

    /// Writes this sweep, as loaded now, into `<sweep_dir>/submitted/`: the sweep file (same
    /// name, `out_dir` set to `sweep_dir`) and its base experiment with every default written
    /// out. The tasks of a submission read these, so editing the sweep file or its base after
    /// submitting changes nothing that is queued. Returns the frozen sweep file.
    pub fn freeze(&self, sweep_dir: &Path) -> anyhow::Result<PathBuf> {
        use anyhow::Context;
        let dir = sweep_dir.join(SUBMITTED_DIR);
        let base = dir.join("base.toml");
        let frozen = SweepFile {
            base: base.clone(),
            out_dir: Some(sweep_dir.to_path_buf()),
            ..self.file.clone()
        };
        let path = dir.join(format!("{}.toml", self.name));
        let sweep_text = format!(
            "# The sweep as submitted (written by `neurofluid-train sweep --slurm`); its tasks read \
             this copy.\n{}",
            toml::to_string_pretty(&frozen).context("the sweep as TOML")?
        );
        for (file, text) in [(&base, self.base.to_toml_string()), (&path, sweep_text)] {
            neurofluid_core::atomic::write_bytes(file, text.as_bytes())
                .with_context(|| format!("writing {}", file.display()))?;
        }
        Ok(path)
    }

    /// The run `key` names: its index (0-based, file order, as Slurm's array task ids) or its
    /// name.
    pub fn find(&self, key: &str) -> anyhow::Result<(usize, &ResolvedVariant)> {
        let found = match key.parse::<usize>() {
            Ok(i) => self.variants.get(i).map(|v| (i, v)),
            Err(_) => self
                .variants
                .iter()
                .enumerate()
                .find(|(_, v)| v.name == key),
        };
        found.ok_or_else(|| {
            let names: Vec<&str> = self.variants.iter().map(|v| v.name.as_str()).collect();
            anyhow::anyhow!(
                "sweep {}: no run `{key}`; expected an index from 0 to {} or one of: {}",
                self.name,
                self.variants.len().saturating_sub(1),
                names.join(", ")
            )
        })
    }
}

/// A file a sweep file names (its base, its script template): as given (relative to the working
/// directory), else relative to the sweep file's folder, else to that folder's parent (sweeps in
/// `experiments/` naming `experiments/x.toml`); the path as given when none exists (the error of
/// its reader names it).
pub(crate) fn locate(base: &Path, sweep_file: &Path) -> PathBuf {
    if base.is_absolute() || base.exists() {
        return base.to_path_buf();
    }
    let dir = sweep_file.parent().unwrap_or(Path::new(""));
    [dir.join(base), dir.join("..").join(base)]
        .into_iter()
        .find(|p| p.exists())
        .unwrap_or_else(|| base.to_path_buf())
}

#[cfg(test)]
mod tests {
    use super::*;

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

    /// A frozen sweep loads back to the same runs (in the submission's folder), whatever
    /// happens to the sweep file and its base after (issue 72: queued tasks re-read the edited
    /// file).
    #[test]
    fn a_frozen_sweep_runs_what_was_submitted() {
        let original = sweep(
            "base = \"b.toml\"\nset = [\"joint.epochs=1\"]\nseeds = [10, 11]\n\
             [[variant]]\nname = \"a\"\nset = [\"joint.bptt_steps=2\"]\n\
             [[variant]]\nname = \"b\"\nlabel = \"B | x\"\n",
        )
        .unwrap();
        let dir = tempfile::tempdir().unwrap();
        let frozen_path = original.freeze(dir.path()).unwrap();
        assert_eq!(frozen_path, dir.path().join(SUBMITTED_DIR).join("s.toml"));
        let frozen = Sweep::load(&frozen_path).unwrap();
        assert_eq!(frozen.name, original.name);
        assert_eq!(frozen.out_dir, dir.path());
        assert_eq!(frozen.variants.len(), 4);
        for (f, o) in frozen.variants.iter().zip(&original.variants) {
            let mut o = o.clone();
            o.experiment.out_dir = Some(dir.path().join(&o.name));
            assert_eq!(f, &o);
        }
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
    fn seeds_multiply_the_runs_and_runs_are_found_by_index_or_name() {
        let s = sweep(
            "base = \"b\"\nseeds = [10, 12]\n[[variant]]\nname = \"a\"\n[[variant]]\nname = \"b\"\nlabel = \"B\"\n",
        )
        .unwrap();
        let runs: Vec<(&str, &str, u64)> = s
            .variants
            .iter()
            .map(|v| (v.name.as_str(), v.variant.as_str(), v.seed))
            .collect();
        assert_eq!(
            runs,
            [
                ("a-seed10", "a", 10),
                ("a-seed12", "a", 12),
                ("b-seed10", "b", 10),
                ("b-seed12", "b", 12)
            ]
        );
        assert!(s.variants.iter().all(|v| v.experiment.seed == v.seed));
        assert_eq!(
            s.variants[3].experiment.out_dir(),
            PathBuf::from("runs/s/b-seed12")
        );
        assert_eq!(s.variants[3].label, "B");
        assert_eq!(s.find("2").unwrap().1.name, "b-seed10");
        assert_eq!(s.find("a-seed12").unwrap().0, 1);
        let err = s.find("4").unwrap_err().to_string();
        assert!(
            err.contains("from 0 to 3") && err.contains("a-seed10"),
            "{err}"
        );
        // without seeds: one run per variant, with the base's seed
        let s = sweep("base = \"b\"\n[[variant]]\nname = \"a\"\n").unwrap();
        assert_eq!((s.variants[0].name.as_str(), s.variants[0].seed), ("a", 10));
        let err =
            sweep("base = \"b\"\nseeds = [1, 2, 1]\n[[variant]]\nname = \"a\"\n").unwrap_err();
        assert_eq!(err.key(), "seeds[2]", "{err}");
    }
}
