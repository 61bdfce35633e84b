//! The experiment TOML: one file describes a whole run (scene, device, seed, models, stages).
//!
//! Every table denies unknown keys; every missing key takes the paper's setting (spec §4, §10),
//! written once, where the setting is defined: the models' own configs are embedded as they are
//! (`[physnerf]` is `PhysNerfConfig`, optimisers are [`OptimConfig`]s). Errors name the file,
//! the dotted key (`joint.dlf_optim.lrr`) and, for parse errors, line:column. Keys of the
//! previous release still load for one release, with a warning naming the new key.
//! Relative paths are relative to the working directory the trainer runs in (the repo root).
//!
//! ```toml
//! name = "quick-watercube"
//! [scene]
//! builtin = "watercube"          # or: path = "data/watercube"
//! scale = "quick"
//! [scene.generate]               # passed to the scene generator as it is
//! seed = 3
//! [physnerf]
//! width = 128
//! [warmup]
//! iters = 300
//! [joint.dlf_optim]
//! lr = 1e-4
//! ```

pub mod checks;
mod errors;
mod legacy;
pub mod preset;
mod sections;
pub mod settings;

use std::path::{Path, PathBuf};

use neurofluid_physnerf::PhysNerfConfig;
use serde::{Deserialize, Serialize};

pub use checks::{Cadence, Cadenced, Section};
pub use errors::{ConfigError, from_toml_str, line_col};
pub(crate) use errors::{from_table, read_text};
pub use preset::Preset;
pub use sections::{
    BuiltinScene, DiagnosticsSection, DlfSection, EvalSection, InitialParticles, InitialSection,
    JointSection, NerfSection, NerfTImages, NovelViews, PhysicalScalar, PhysicsFit, PlyEncoding,
    RefitSection, ScalarGrid, SceneScale, SceneSection, SearchObjective, SurfaceThreshold,
    WarmupSection,
};
pub use settings::Settings;

#[cfg(doc)]
use crate::optim::OptimConfig;

/// File name of the resolved configuration inside a run folder.
pub const RESOLVED_FILE: &str = "config.resolved.toml";

/// A whole experiment.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Experiment {
    /// Name of the run (also the default output folder `runs/<name>`).
    pub name: String,
    /// Seed of every random choice (ray batches, initialisation). Default 10 (spec §4.5).
    #[serde(default = "default_seed")]
    pub seed: u64,
    /// Device: `cpu`, `flex`, `ndarray`, `wgpu`, `cuda`, `cuda:N`. Default `cpu`.
    #[serde(default = "default_device")]
    pub device: String,
    /// The operands of the dense layers' matmuls on an accelerator: `f32` (default), `f16` or
    /// `bf16` for a GPU's tensor cores, f32 accumulation, each operand scaled by its largest
    /// magnitude (`neurofluid_core::half_matmul`). The CPU's host layers ignore it.
    #[serde(default)]
    pub matmul: neurofluid_core::half_matmul::MatmulOperands,
    /// Where PhysNeRF's ball query and DLF's pair search run: `host` (default, the uniform grid on
    /// the CPU's cores) or `device` (kernels on the GPU the particles are on; the host on a CPU
    /// device). Fused multiply-adds on a GPU can move a point within an ulp of the radius, so it
    /// shapes every stage with a renderer (`neurofluid_core::device_search`,
    /// `neurofluid_core::device_pairs`).
    #[serde(default)]
    pub neighbour_search: neurofluid_core::device_search::NeighbourSearch,
    /// Output folder; default `runs/<name>` (see [`Experiment::out_dir`]).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub out_dir: Option<PathBuf>,
    /// Training rules laid over the file's values: `"paper"` = the reference's (see
    /// [`preset`]); unset = the file's values.
    #[serde(default, skip_serializing_if = "Preset::is_none")]
    pub preset: Preset,
    /// Which scene: an existing folder or a built-in one to generate.
    pub scene: SceneSection,
    /// DLF, the transition model.
    #[serde(default)]
    pub dlf: DlfSection,
    /// PhysNeRF, the renderer (its own config; the ray segment comes from `[scene]`).
    #[serde(default)]
    pub physnerf: PhysNerfConfig,
    /// PhysNeRF's warm-up on frame 0 (spec §4.1).
    #[serde(default)]
    pub warmup: WarmupSection,
    /// Joint grounding (spec §4.2).
    #[serde(default)]
    pub joint: JointSection,
    /// A second renderer fitted to the grounded rollout, for novel views (an option).
    #[serde(default)]
    pub refit: RefitSection,
    /// Evaluation (spec §6).
    #[serde(default)]
    pub eval: EvalSection,
    /// What a run measures to be understood, never to choose a setting (all off by default).
    #[serde(default)]
    pub diagnostics: DiagnosticsSection,
    /// The NeRF of the initial particles and of the novel-view baselines.
    #[serde(default)]
    pub nerf: NerfSection,
    /// Initial particles from images.
    #[serde(default)]
    pub initial: InitialSection,
}

fn default_seed() -> u64 {
    10
}
fn default_device() -> String {
    "cpu".into()
}

/// Moves the previous release's keys of `table` and warns about each.
fn migrate_legacy(table: &mut toml::Table, origin: &Path) -> bool {
    let moved = legacy::migrate(table);
    for (old, new) in &moved {
        tracing::warn!(
            "{}: `{old}` is the previous release's key; write `{new}` (the old key is read until the next release)",
            origin.display()
        );
    }
    !moved.is_empty()
}

/// How an error names the override `spec`.
fn override_origin(spec: &str) -> PathBuf {
    PathBuf::from(format!("override `{spec}`"))
}

/// `err` named after the last override whose key is the error's key, lies under it or holds it
/// (`keys`: each override's dotted key and text); unchanged when none is.
fn blame_override(err: ConfigError, keys: &[(String, &str)]) -> ConfigError {
    let ConfigError::Invalid {
        path,
        location,
        key,
        message,
    } = err
    else {
        return err;
    };
    let within = |inner: &str, outer: &str| {
        inner == outer
            || inner
                .strip_prefix(outer)
                .is_some_and(|r| r.starts_with('.'))
    };
    let path = keys
        .iter()
        .rev()
        .find(|(k, _)| !key.is_empty() && (within(&key, k) || within(k, &key)))
        .map_or(path, |(_, spec)| override_origin(spec));
    ConfigError::Invalid {
        path,
        location,
        key,
        message,
    }
}

impl Experiment {
    /// What is wrong with the views the experiment names on `scene`: `warmup.held_out` not a
    /// warm-up view, the only one, or a view the joint stage trains on (`joint.view`,
    /// `joint.extra_views`), which would not be held out; `eval.novel_views = "validation"` on a
    /// scene without validation views.
    pub fn scene_problem(&self, scene: &neurofluid_core::scene::Scene) -> Option<String> {
        self.warmup
            .held_out_problem(scene)
            .or_else(|| self.held_out_trained_on(scene))
            .or_else(|| self.eval.novel_views_problem(scene))
    }

    /// `warmup.held_out` names a view the joint stage trains on.
    fn held_out_trained_on(&self, scene: &neurofluid_core::scene::Scene) -> Option<String> {
        let held = self.warmup.held_out.as_ref()?;
        self.joint
            .views_by_role(scene)
            .iter()
            .any(|(_, v)| v == held)
            .then(|| {
                format!(
                    "warmup.held_out: {held:?} is a view the joint stage trains on \
                     (joint.view, joint.extra_views); hold out another"
                )
            })
    }

    /// Reads and validates an experiment file.
    pub fn load(path: &Path) -> Result<Self, ConfigError> {
        let text = read_text(path)?;
        Self::from_toml_str(&text, path)
    }

    /// Parses and validates TOML text (`origin` names the source in errors).
    pub fn from_toml_str(text: &str, origin: &Path) -> Result<Self, ConfigError> {
        // a file with keys of the previous release is migrated as a table (errors then carry
        // no line numbers); a current file is read from its text, with line numbers
        let legacy = toml::from_str::<toml::Table>(text)
            .ok()
            .and_then(|mut table| migrate_legacy(&mut table, origin).then_some(table));
        let exp: Experiment = match legacy {
            Some(table) => from_table(table, origin)?,
            None => from_toml_str(text, origin)?,
        };
        let exp = exp.with_preset(origin);
        exp.validate(origin)?;
        Ok(exp)
    }

    /// This experiment with its [`Preset`] laid over it; each value the preset changes is logged.
    fn with_preset(mut self, origin: &Path) -> Self {
        for change in preset::apply(&mut self) {
            tracing::info!("{}: preset = \"paper\" sets {change}", origin.display());
        }
        self
    }

    /// The output folder: `out_dir`, or `runs/<name>`.
    pub fn out_dir(&self) -> PathBuf {
        self.out_dir
            .clone()
            .unwrap_or_else(|| PathBuf::from("runs").join(&self.name))
    }

    /// This experiment with every default written out (`out_dir` filled in).
    pub fn resolved(&self) -> Self {
        let mut r = self.clone();
        r.out_dir = Some(self.out_dir());
        r
    }

    /// The resolved configuration as TOML text.
    pub fn to_toml_string(&self) -> String {
        // Serialising plain structs, strings, numbers and tables cannot fail.
        toml::to_string_pretty(&self.resolved()).expect("experiment serialises to TOML")
    }

    /// Writes the resolved configuration to `dir/config.resolved.toml` atomically; returns the path.
    pub fn save_resolved(&self, dir: &Path) -> Result<PathBuf, ConfigError> {
        let path = dir.join(RESOLVED_FILE);
        let text = format!(
            "# Resolved experiment (every default filled in), written by neurofluid-train.\n{}",
            self.to_toml_string()
        );
        neurofluid_core::atomic::write_bytes(&path, text.as_bytes()).map_err(|source| {
            ConfigError::Write {
                path: path.clone(),
                source,
            }
        })?;
        Ok(path)
    }

    /// Applies a dotted override `key.path=value` (TOML value syntax; a bare word is taken as a
    /// string): `joint.dlf_optim.lr=1e-4`, `physnerf.encoding.pc=false`, `scene.path=data/x`.
    /// Unknown keys, wrong types and invalid values are errors naming the key.
    pub fn apply_override(&mut self, spec: &str) -> Result<(), ConfigError> {
        self.apply_overrides(&[spec])
    }

    /// Applies several overrides together: each is set in order (a later one wins on the same
    /// key), then the result is read and checked once, so overrides that are only valid together
    /// (a `[joint.physics]` table built key by key) may come in any order. An error names the
    /// override of the key it is about; a failed call leaves the experiment unchanged.
    pub fn apply_overrides<S: AsRef<str>>(&mut self, specs: &[S]) -> Result<(), ConfigError> {
        let mut table =
            toml::Table::try_from(&*self).expect("experiment serialises to a TOML table");
        let mut keys = Vec::with_capacity(specs.len());
        for spec in specs.iter().map(AsRef::as_ref) {
            let origin = override_origin(spec);
            let (key, value) = parse_override(spec, &origin)?;
            set_dotted(&mut table, &key, value, &origin)?;
            migrate_legacy(&mut table, &origin);
            keys.push((key.join("."), spec));
        }
        let all = match specs {
            [one] => override_origin(one.as_ref()),
            _ => PathBuf::from("the overrides"),
        };
        let exp = from_table::<Experiment>(table, &all)
            .map(|e| e.with_preset(&all))
            .and_then(|e| e.validate(&all).map(|()| e))
            .map_err(|e| blame_override(e, &keys))?;
        *self = exp;
        Ok(())
    }

    /// Checks values serde cannot: ranges, exclusive choices, ordering. Each section checks
    /// itself ([`checks::Section::problem`]); the first problem is the error.
    pub fn validate(&self, origin: &Path) -> Result<(), ConfigError> {
        let name = self.name.trim();
        if name.is_empty() || name == "." || name == ".." || self.name.contains(['/', '\\']) {
            return Err(ConfigError::invalid(
                origin,
                "name",
                "expected a name that is one folder name (not empty, `.` or `..`, no slashes)",
            ));
        }
        let problem = checks::problem_of(&self.scene)
            .or_else(|| checks::problem_of(&self.physnerf))
            .or_else(|| checks::problem_of(&self.dlf))
            .or_else(|| checks::problem_of(&self.warmup))
            .or_else(|| checks::problem_of(&self.joint))
            .or_else(|| checks::problem_of(&self.nerf))
            .or_else(|| checks::problem_of(&self.initial))
            .or_else(|| checks::problem_of(&self.eval))
            .or_else(|| checks::problem_of(&self.diagnostics))
            .or_else(|| self.refit_problem())
            .or_else(|| self.truth_problem());
        match problem {
            Some((key, msg)) => Err(ConfigError::invalid(origin, &key, &msg)),
            None => Ok(()),
        }
    }

    /// `joint.terms.truth` matches predicted and true particles by index: the joint stage must
    /// start from the true first state.
    fn truth_problem(&self) -> checks::Problem {
        let truth = self
            .joint
            .terms
            .truth
            .as_ref()
            .is_some_and(|t| t.weight > 0.0);
        if truth && self.scene.initial == InitialParticles::FromImages {
            return Some((
                "joint.terms.truth.weight".into(),
                "expected 0 with scene.initial = \"from_images\": the truth term matches \
                 predicted and true particles by index, which only a start from the true first \
                 state has"
                    .into(),
            ));
        }
        None
    }

    /// The refitted renderer's `[physnerf]` (the first renderer's with `refit.positions`).
    pub fn refit_physnerf(&self) -> PhysNerfConfig {
        PhysNerfConfig {
            positions: self.refit.positions,
            ..self.physnerf.clone()
        }
    }

    /// What `[physnerf]` with `refit.positions` cannot run with, named under `refit`.
    fn refit_problem(&self) -> checks::Problem {
        if !self.refit.enabled {
            return None;
        }
        checks::problem_of(&self.refit_physnerf()).map(|(key, msg)| {
            let key = if key == "physnerf.positions" {
                "refit.positions".to_string()
            } else {
                key
            };
            (key, format!("{msg} (the refitted renderer's [physnerf])"))
        })
    }

    /// The keys that never shape a training state (prefixes on whole key segments): what is
    /// logged and when, the device, where outputs go, memory; each section names its own.
    pub fn free_keys() -> Vec<String> {
        let mut keys: Vec<String> = ["name", "device", "out_dir"].map(String::from).to_vec();
        keys.extend(checks::free_keys_of::<SceneSection>());
        keys.extend(checks::free_keys_of::<EvalSection>());
        keys.extend(checks::free_keys_of::<DiagnosticsSection>());
        keys.extend(checks::free_keys_of::<PhysNerfConfig>());
        keys.extend(checks::free_keys_of::<WarmupSection>());
        keys.extend(checks::free_keys_of::<JointSection>());
        keys.extend(checks::free_keys_of::<NerfSection>());
        keys
    }
}

/// Splits `key=value` and parses the value as TOML (a bare word becomes a string).
pub(crate) fn parse_override(
    spec: &str,
    origin: &Path,
) -> Result<(Vec<String>, toml::Value), ConfigError> {
    let (key, raw) = spec.split_once('=').ok_or_else(|| {
        ConfigError::invalid(
            origin,
            "",
            "expected `key.path=value`, e.g. `joint.epochs=2`",
        )
    })?;
    let key = key.trim();
    let parts: Vec<String> = key.split('.').map(|p| p.trim().to_string()).collect();
    if parts.iter().any(String::is_empty) {
        return Err(ConfigError::invalid(
            origin,
            key,
            "expected a dotted key like `joint.dlf_optim.lr`",
        ));
    }
    let raw = raw.trim();
    let value = match toml::from_str::<toml::Table>(&format!("v = {raw}")) {
        Ok(mut t) => t.remove("v").expect("parsed table holds `v`"),
        Err(_) => toml::Value::String(raw.to_string()),
    };
    Ok((parts, value))
}

/// Sets `value` at the dotted `key` inside `table`, creating missing tables on the way.
pub(crate) fn set_dotted(
    table: &mut toml::Table,
    key: &[String],
    value: toml::Value,
    origin: &Path,
) -> Result<(), ConfigError> {
    let (last, parents) = key.split_last().expect("non-empty key");
    let mut cur = table;
    for (i, part) in parents.iter().enumerate() {
        let entry = cur
            .entry(part.clone())
            .or_insert_with(|| toml::Value::Table(toml::Table::new()));
        cur = match entry {
            toml::Value::Table(t) => t,
            _ => {
                return Err(ConfigError::invalid(
                    origin,
                    &key[..=i].join("."),
                    "is a value, not a table",
                ));
            }
        };
    }
    cur.insert(last.clone(), value);
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn parse(text: &str) -> Result<Experiment, ConfigError> {
        Experiment::from_toml_str(text, Path::new("exp.toml"))
    }

    const MINIMAL: &str = "name = \"t\"\n[scene]\nbuiltin = \"watercube\"\n";

    #[test]
    fn defaults_are_the_papers_settings() {
        let e = parse(MINIMAL).unwrap();
        assert_eq!(e.seed, 10);
        assert_eq!(e.device, "cpu");
        assert_eq!(e.out_dir(), PathBuf::from("runs/t"));
        assert_eq!(e.scene.scene_dir(), PathBuf::from("data/watercube_quick"));
        assert_eq!(
            e.dlf.weights,
            PathBuf::from("assets/dlf_pretrained/pretrained_model_weights.pt")
        );
        assert_eq!(e.dlf.geometry, neurofluid_dlf::GeometryMode::Constant);
        assert_eq!(e.joint.bptt_steps, 1);
        assert_eq!(e.scene.bounds(9.0, 13.0), (9.0, 13.0));
        let r = &e.physnerf;
        assert_eq!((r.n_samples, r.n_importance, r.k), (64, 128, 20));
        assert_eq!(r.search_radius, 0.225);
        assert_eq!(
            r.selection,
            neurofluid_physnerf::NeighborSelection::LowestIndex
        );
        assert!(!r.stratified);
        assert_eq!((r.depth, r.width, r.skip), (8, 256, 4));
        assert_eq!(e.eval.render_every, 1);
        assert_eq!(r.encoding, neurofluid_physnerf::EncodingTerms::all());
        assert!(r.encoding.pc && r.encoding.sigma_p && r.encoding.vd && r.encoding.dc);
        let w = &e.warmup;
        assert_eq!((w.iters, w.rays, w.precrop_iters), (100_000, 1024, 500));
        assert_eq!(
            w.optim.schedule,
            neurofluid_core::lr_schedule::Schedule::Exponential {
                decay_steps: 10_000
            }
        );
        assert_eq!((w.optim.lr, w.precrop_frac), (5e-4, 0.5));
        let j = &e.joint;
        assert_eq!((j.epochs, j.rays), (20_000, 1024));
        assert_eq!((j.physnerf_optim.lr, j.dlf_optim.lr), (3e-4, 1e-5));
        assert_eq!(
            j.physnerf_optim.schedule,
            neurofluid_core::lr_schedule::Schedule::MultiStep {
                milestones: vec![10_000, 75_000, 150_000],
                gamma: 0.5
            }
        );
        assert_eq!(
            j.dlf_optim.schedule,
            neurofluid_core::lr_schedule::Schedule::MultiStep {
                milestones: vec![10_000, 30_000, 50_000, 100_000, 300_000],
                gamma: 0.5
            }
        );
        assert_eq!(j.boundary_weight, 1.0);
        assert!(e.eval.render && e.eval.write_ply);
        assert_eq!(e.eval.image_scale, 1.0);
        // the schedules built from the config are the reference's
        assert!((w.optim.lr_at(10_000) - 5e-5).abs() < 1e-18);
        assert_eq!(j.physnerf_optim.lr_at(10_001), 1.5e-4);
        assert_eq!(w.precrop_at(499), Some(0.5));
        assert_eq!(w.precrop_at(500), None);
    }

    /// `preset = "paper"` on a quick experiment that departs from the reference: every rule
    /// is back to the defaults (the paper's, above), every budget stays the file's, and a rule
    /// set after the preset is still the paper's.
    #[test]
    fn paper_preset_restores_the_reference_rules_and_keeps_the_budgets() {
        let file =
            Path::new(env!("CARGO_MANIFEST_DIR")).join("../../experiments/quick-honeycone.toml");
        let quick = Experiment::load(&file).unwrap();
        assert_eq!(
            quick.joint.bptt_steps, 4,
            "the quick experiment departs from the paper"
        );
        let mut paper = quick.clone();
        paper
            .apply_overrides(&[
                "diagnostics.weight_interpolation=0.25",
                "dlf.energy_cap=\"particle\"",
                "dlf.gravity_scale=1.7",
                "dlf.viscosity=0.4",
                "joint.terms.anchor.weight=0.1",
                "joint.terms.energy.weight=0.005",
                "physnerf.positions=\"relative\"",
                "refit.enabled=true",
                "joint.physics.fit=[\"gravity_scale\"]",
                "joint.physics.search.gravity_scale=[1.0, 2.0]",
                "preset=\"paper\"",
            ])
            .unwrap();
        assert_eq!(paper.diagnostics.weight_interpolation, 1.0);
        assert!(
            !paper.refit.enabled,
            "the paper renders with the joint PhysNeRF"
        );
        let reference = parse(MINIMAL).unwrap();
        assert_eq!(paper.preset, Preset::Paper);
        // every DLF rule back to the reference's; the weights stay the experiment's
        assert_eq!(paper.dlf.weights, quick.dlf.weights);
        let paper_dlf = DlfSection {
            weights: reference.dlf.weights.clone(),
            ..paper.dlf.clone()
        };
        assert_eq!(paper_dlf, reference.dlf);
        let (p, r) = (&paper.physnerf, &reference.physnerf);
        assert_eq!((p.selection, p.density), (r.selection, r.density));
        assert_eq!((p.frequencies, p.positions), (r.frequencies, r.positions));
        assert_eq!(paper.warmup.optim, reference.warmup.optim);
        let (j, r) = (&paper.joint, &reference.joint);
        assert_eq!((j.bptt_steps, j.dlf_every), (r.bptt_steps, r.dlf_every));
        assert_eq!(j.physnerf_optim, r.physnerf_optim);
        assert_eq!(j.dlf_optim, r.dlf_optim);
        assert_eq!((j.boundary_weight, j.foreground_rays), (1.0, 0.0));
        assert_eq!(j.terms, r.terms, "no particle terms");
        assert!(j.extra_views.is_empty());
        assert_eq!(j.physics, None, "no physical scalar fitted or searched");
        // the budgets are the file's
        assert_eq!(
            (paper.warmup.iters, paper.joint.epochs, paper.joint.rays),
            (quick.warmup.iters, quick.joint.epochs, quick.joint.rays)
        );
        assert_eq!(
            (p.width, p.n_samples, p.n_importance),
            (
                quick.physnerf.width,
                quick.physnerf.n_samples,
                quick.physnerf.n_importance
            )
        );
        // the preset wins over a rule set after it, and survives a round trip of the file
        paper.apply_overrides(&["joint.bptt_steps=4"]).unwrap();
        assert_eq!(paper.joint.bptt_steps, 1);
        let again = parse(&paper.to_toml_string()).unwrap();
        assert_eq!(again.preset, Preset::Paper);
        assert_eq!(again.joint, paper.joint);
    }

    #[test]
    fn unknown_key_names_the_dotted_key_file_and_line() {
        let text = format!("{MINIMAL}[joint]\nepochs = 2\nbptt_step = 1\n");
        let err = parse(&text).unwrap_err();
        assert_eq!(err.key(), "joint.bptt_step");
        let msg = err.to_string();
        assert!(msg.starts_with("exp.toml:6:"), "{msg}");
        assert!(msg.contains("joint.bptt_step"), "{msg}");
        assert!(
            msg.contains("bptt_steps"),
            "should list the expected keys: {msg}"
        );
        // nested tables, down into the model's own config and an optimiser group
        let text = format!("{MINIMAL}[physnerf.encoding]\npc = true\npq = false\n");
        let err = parse(&text).unwrap_err();
        assert_eq!(err.key(), "physnerf.encoding.pq");
        let text = format!("{MINIMAL}[joint.dlf_optim]\nlrr = 1e-4\n");
        let err = parse(&text).unwrap_err();
        assert_eq!(err.key(), "joint.dlf_optim.lrr");
        assert!(err.to_string().starts_with("exp.toml:5:"), "{err}");
        // top level
        let err = parse(&format!("seeed = 3\n{MINIMAL}")).unwrap_err();
        assert_eq!(err.key(), "seeed");
        assert!(err.to_string().starts_with("exp.toml:1:"), "{err}");
    }

    /// The refitted renderer is `[physnerf]` with `refit.positions`: what that cannot run with
    /// is refused under `refit.positions`, and only when the refit is on.
    #[test]
    fn a_refit_that_cannot_run_names_its_positions() {
        let no_particle_terms =
            "[physnerf.encoding]\npc = false\nsigma_p = false\nvd = false\n[refit]\n";
        let text = format!("{MINIMAL}{no_particle_terms}enabled = true\n");
        let err = parse(&text).unwrap_err();
        assert_eq!(err.key(), "refit.positions");
        assert!(err.to_string().contains("refitted renderer"), "{err}");
        let world = format!("{MINIMAL}{no_particle_terms}enabled = true\npositions = \"world\"\n");
        assert!(parse(&world).is_ok());
        assert!(parse(&format!("{MINIMAL}{no_particle_terms}")).is_ok());
    }

    /// The truth term matches particles by index, so it is refused with initial particles from
    /// images, naming its key; with the true first state it is accepted.
    #[test]
    fn the_truth_term_needs_the_true_first_state() {
        let truth = "[joint.terms.truth]\nweight = 1.0\n";
        let text = format!("{MINIMAL}initial = \"from_images\"\n{truth}");
        let err = parse(&text).unwrap_err();
        assert_eq!(err.key(), "joint.terms.truth.weight");
        assert!(err.to_string().contains("from_images"), "{err}");
        assert!(parse(&format!("{MINIMAL}{truth}")).is_ok());
        assert!(parse(&format!("{MINIMAL}initial = \"from_images\"\n")).is_ok());
    }

    #[test]
    fn wrong_type_names_the_key_and_line() {
        let text = format!("{MINIMAL}[warmup]\niters = \"many\"\n");
        let err = parse(&text).unwrap_err();
        assert_eq!(err.key(), "warmup.iters");
        assert!(err.to_string().starts_with("exp.toml:5:"), "{err}");
        let err = parse("name = \"t\"\n[scene]\nbuiltin = \"lavalamp\"\n").unwrap_err();
        assert_eq!(err.key(), "scene.builtin");
        assert!(err.to_string().contains("watercube"), "{err}");
    }

    #[test]
    fn missing_required_key_and_syntax_errors_are_named() {
        let err = parse("[scene]\nbuiltin = \"watercube\"\n").unwrap_err();
        assert_eq!(err.key(), "name");
        let err = parse("name = \"t\"\n").unwrap_err();
        assert_eq!(err.key(), "scene");
        let err = parse("name = \"t\n").unwrap_err();
        assert!(err.to_string().starts_with("exp.toml:1:"), "{err}");
        assert!(err.to_string().contains("syntax"), "{err}");
    }

    #[test]
    fn missing_file_names_the_path() {
        let err = Experiment::load(Path::new("no/such/experiment.toml")).unwrap_err();
        assert!(matches!(err, ConfigError::Read { .. }));
        assert!(err.to_string().contains("no/such/experiment.toml"), "{err}");
    }

    #[test]
    fn validation_names_the_key() {
        let cases = [
            ("[scene]\npath = \"d\"\nbuiltin = \"watercube\"\n", "scene"),
            (
                "[scene]\nbuiltin = \"watercube\"\n[joint]\nbptt_steps = 0\n",
                "joint.bptt_steps",
            ),
            (
                "[scene]\nbuiltin = \"watercube\"\n[warmup]\nprecrop_frac = 1.5\n",
                "warmup.precrop_frac",
            ),
            (
                "[scene]\nbuiltin = \"watercube\"\n[joint]\nforeground_rays = 1.5\n",
                "joint.foreground_rays",
            ),
            (
                "[scene]\nbuiltin = \"watercube\"\n[joint]\ninput_noise = -0.1\n",
                "joint.input_noise",
            ),
            (
                "[scene]\nbuiltin = \"watercube\"\n[dlf]\ngravity_scale = 0.0\n",
                "dlf.gravity_scale",
            ),
            (
                "[scene]\nbuiltin = \"watercube\"\n[dlf]\ngravity_scale = inf\n",
                "dlf.gravity_scale",
            ),
            (
                "[scene]\nbuiltin = \"watercube\"\n[dlf]\nviscosity = -0.1\n",
                "dlf.viscosity",
            ),
            (
                "[scene]\nbuiltin = \"watercube\"\n[joint.terms.energy]\nweight = -1.0\n",
                "joint.terms.energy.weight",
            ),
            (
                "[scene]\nbuiltin = \"watercube\"\n[dlf]\ndissipation = 1.0\n",
                "dlf.dissipation",
            ),
            (
                "[scene]\nbuiltin = \"watercube\"\n[dlf]\ndissipation_frame = \"fluid\"\n",
                "dlf.dissipation_frame",
            ),
            (
                "[scene]\nbuiltin = \"watercube\"\n[dlf]\ncontainment = \"walls\"\n",
                "dlf.containment",
            ),
            (
                "[scene]\nbuiltin = \"watercube\"\n[dlf]\ngravity_scale = \"high\"\n",
                "dlf.gravity_scale",
            ),
            (
                "[scene]\nbuiltin = \"watercube\"\n[dlf]\nviscosity = true\n",
                "dlf.viscosity",
            ),
            (
                "[scene]\nbuiltin = \"watercube\"\n[joint.physics]\nfit = []\n",
                "joint.physics.fit",
            ),
            (
                "[scene]\nbuiltin = \"watercube\"\n[joint.physics]\nfit = [\"viscosity\", \"viscosity\"]\n",
                "joint.physics.fit",
            ),
            (
                "[scene]\nbuiltin = \"watercube\"\n[joint.physics]\nfit = [\"viscosity\"]\noptim = { lr = -1.0 }\n",
                "joint.physics.optim.lr",
            ),
            (
                "[scene]\nbuiltin = \"watercube\"\n[joint.physics]\nfit = [\"viscosity\"]\nsearch = { dissipation = [0.0, 0.1] }\n",
                "joint.physics.search.dissipation",
            ),
            (
                "[scene]\nbuiltin = \"watercube\"\n[joint.physics]\nfit = [\"dissipation\"]\nsearch = { dissipation = [0.0, 0.6] }\n",
                "joint.physics.search.dissipation",
            ),
            (
                "[scene]\nbuiltin = \"watercube\"\n[joint.physics]\nfit = [\"gravity_scale\"]\nsearch = {}\n",
                "joint.physics.search.gravity_scale",
            ),
            (
                "[scene]\nbuiltin = \"watercube\"\n[eval]\nviews = [\"view_5\", \"view_5\"]\n",
                "eval.views",
            ),
            (
                "[scene]\nbuiltin = \"watercube\"\n[warmup]\nviews = [\"view_2\", \"view_3\", \"view_2\"]\n",
                "warmup.views",
            ),
            (
                "[scene]\nbuiltin = \"watercube\"\n[joint]\nextra_views = [\"view_2\", \"view_2\"]\n",
                "joint.extra_views",
            ),
            (
                "[scene]\nbuiltin = \"watercube\"\n[joint.terms.anchor]\nweight = nan\n",
                "joint.terms.anchor.weight",
            ),
            (
                "[scene]\nbuiltin = \"watercube\"\n[diagnostics]\nweight_interpolation = 1.5\n",
                "diagnostics.weight_interpolation",
            ),
            (
                "[scene]\nbuiltin = \"watercube\"\n[diagnostics]\ninterpolation_sweep = [0.5, -0.1]\n",
                "diagnostics.interpolation_sweep",
            ),
            (
                "[scene]\nbuiltin = \"watercube\"\n[joint.physnerf_optim.schedule]\nkind = \"multi_step\"\nmilestones = [5, 3]\ngamma = 0.5\n",
                "joint.physnerf_optim.schedule",
            ),
            (
                "[scene]\nbuiltin = \"watercube\"\nnear = 5.0\nfar = 4.0\n",
                "scene.far",
            ),
            (
                "[scene]\nbuiltin = \"watercube\"\n[physnerf]\nwidth = 0\n",
                "physnerf.width",
            ),
            (
                "[scene]\nbuiltin = \"watercube\"\n[physnerf]\ndepth = 1\n",
                "physnerf.depth",
            ),
            (
                "[scene]\nbuiltin = \"watercube\"\n[physnerf]\nsearch_radius = -1.0\n",
                "physnerf.search_radius",
            ),
            (
                "[scene]\nbuiltin = \"watercube\"\n[warmup]\niters = 0\n",
                "warmup.iters",
            ),
            (
                "[scene]\nbuiltin = \"watercube\"\n[joint]\nepochs = 0\n",
                "joint.epochs",
            ),
            ("[scene]\nbuiltin = \"watercube\"\n", "name"),
            (
                "[scene]\nbuiltin = \"watercube\"\n[scene.generate]\nname = \"x\"\n",
                "scene.generate.name",
            ),
            (
                "[scene]\npath = \"d\"\n[scene.generate]\nseed = 1\n",
                "scene.generate",
            ),
        ];
        for (body, key) in cases {
            let name = if key == "name" { ".." } else { "t" };
            let err = parse(&format!("name = \"{name}\"\n{body}")).unwrap_err();
            assert_eq!(err.key(), key, "{err}");
            assert!(err.to_string().contains("exp.toml"), "{err}");
        }
        // a run name is one folder name
        for bad in ["..", ".", "", "a/b", "a\\b", "../x"] {
            let err = parse(&format!(
                "name = '{bad}'\n[scene]\nbuiltin = \"watercube\"\n"
            ))
            .unwrap_err();
            assert_eq!(err.key(), "name", "{bad}: {err}");
        }
    }

    #[test]
    fn overrides_set_values_and_reject_unknown_keys() {
        let mut e = parse(MINIMAL).unwrap();
        e.apply_overrides(&[
            "joint.physnerf_optim.lr=1e-4",
            "physnerf.encoding.pc=false",
            "warmup.iters = 7",
            "joint.physnerf_optim.schedule.milestones=[1, 2]",
            "eval.views=[\"view_5\", \"view_6\"]",
            "scene.near=8",
        ])
        .unwrap();
        assert_eq!(e.joint.physnerf_optim.lr, 1e-4);
        assert!(!e.physnerf.encoding.pc);
        assert_eq!(e.warmup.iters, 7);
        assert_eq!(
            e.joint.physnerf_optim.schedule,
            neurofluid_core::lr_schedule::Schedule::MultiStep {
                milestones: vec![1, 2],
                gamma: 0.5
            }
        );
        assert_eq!(e.scene.near, Some(8.0));
        assert_eq!(e.eval.views.as_deref().unwrap(), ["view_5", "view_6"]);
        // bare words are strings; generator keys pass through
        e.apply_override("scene.dir=data/elsewhere").unwrap();
        assert_eq!(e.scene.scene_dir(), PathBuf::from("data/elsewhere"));
        e.apply_override("scene.generate.image_size=32").unwrap();
        let g = e.scene.generator_table().unwrap();
        assert_eq!(g["image_size"].as_integer(), Some(32));
        assert_eq!(g["name"].as_str(), Some("watercube"));
        assert_eq!(g["out"].as_str(), Some("data/elsewhere"));

        let before = e.clone();
        let err = e.apply_override("joint.lr_renderr=1").unwrap_err();
        assert_eq!(err.key(), "joint.lr_renderr");
        let err = e.apply_override("physnerf.near=1").unwrap_err();
        assert_eq!(err.key(), "physnerf.near");
        let err = e.apply_override("warmup.iters=lots").unwrap_err();
        assert_eq!(err.key(), "warmup.iters");
        let err = e.apply_override("warmup.iters.x=1").unwrap_err();
        assert_eq!(err.key(), "warmup.iters");
        let err = e.apply_override("joint.bptt_steps=0").unwrap_err();
        assert_eq!(err.key(), "joint.bptt_steps");
        assert!(e.apply_override("no_equals_sign").is_err());
        assert_eq!(e, before, "failed overrides leave the experiment unchanged");
    }

    /// Overrides are read together: a `[joint.physics]` table built key by key on the command
    /// line is accepted in either order, and an error still names the override of its key.
    #[test]
    fn overrides_valid_together_apply_in_any_order() {
        let fit = "joint.physics.fit=[\"gravity_scale\"]";
        let hold = "joint.physics.hold_dlf_epochs=2";
        for order in [[fit, hold], [hold, fit]] {
            let mut e = parse(MINIMAL).unwrap();
            e.apply_overrides(&order).unwrap();
            let p = e.joint.physics.unwrap();
            assert_eq!((p.fit.len(), p.hold_dlf_epochs), (1, 2), "{order:?}");
        }
        let mut e = parse(MINIMAL).unwrap();
        let before = e.clone();
        let err = e
            .apply_overrides(&["joint.epochs=3", "warmup.iters=lots", "joint.rays=8"])
            .unwrap_err();
        assert_eq!(err.key(), "warmup.iters");
        assert!(
            err.to_string().starts_with("override `warmup.iters=lots`"),
            "{err}"
        );
        assert_eq!(e, before, "a failed call leaves the experiment unchanged");
    }

    #[test]
    fn resolved_config_round_trips_with_defaults_filled() {
        let dir = tempfile::tempdir().unwrap();
        let mut e = parse(MINIMAL).unwrap();
        e.apply_override("joint.epochs=3").unwrap();
        let path = e.save_resolved(dir.path()).unwrap();
        assert_eq!(path, dir.path().join(RESOLVED_FILE));
        let text = std::fs::read_to_string(&path).unwrap();
        for needle in [
            "out_dir = \"runs/t\"",
            "lr = 0.00001",
            "epochs = 3",
            "[physnerf.encoding]",
            "[joint.dlf_optim.schedule]",
        ] {
            assert!(text.contains(needle), "missing {needle} in\n{text}");
        }
        let back = Experiment::load(&path).unwrap();
        assert_eq!(back, e.resolved());
    }

    #[test]
    fn keys_of_the_previous_release_still_load() {
        let old = format!(
            "{MINIMAL}[renderer]\nwidth = 128\njitter = true\nnear = 8.0\n[dlf]\ngeometry_grad = true\nbptt_steps = 3\n\
             [warmup]\nlr = 1e-3\ndecay_steps = 800\neval_every = 5\n[joint]\nlr_transition = 1e-4\nlr_renderer = 2e-4\n"
        );
        let e = parse(&old).unwrap();
        let new = parse(&format!(
            "{MINIMAL}near = 8.0\n[physnerf]\nwidth = 128\nstratified = true\n[dlf]\ngeometry = \"differentiable\"\n\
             [warmup]\npreview_every = 5\n[warmup.optim]\nlr = 1e-3\n[warmup.optim.schedule]\nkind = \"exponential\"\ndecay_steps = 800\n\
             [joint]\nbptt_steps = 3\n[joint.dlf_optim]\nlr = 1e-4\n[joint.physnerf_optim]\nlr = 2e-4\n"
        ))
        .unwrap();
        assert_eq!(e, new);
        // and as overrides
        let mut o = parse(MINIMAL).unwrap();
        o.apply_overrides(&["joint.lr_transition=1e-4", "renderer.encoding.vd=false"])
            .unwrap();
        assert_eq!(o.joint.dlf_optim.lr, 1e-4);
        assert!(!o.physnerf.encoding.vd);
    }

    #[test]
    fn line_col_counts_from_one() {
        let t = "ab\ncd\n";
        assert_eq!(line_col(t, 0), (1, 1));
        assert_eq!(line_col(t, 1), (1, 2));
        assert_eq!(line_col(t, 3), (2, 1));
        assert_eq!(line_col(t, 4), (2, 2));
    }
}
