//! The experiment TOML: one file describes a whole run (scene, device, seed, models, stages).
//!
//! Every table denies unknown keys; every missing key takes the paper's setting (spec §4, §10).
//! Errors name the file, the dotted key (`joint.lr_renderr`) and, for parse errors, line:column.
//! Relative paths are relative to the working directory the trainer runs in (the repo root).
//!
//! ```toml
//! name = "quick-watercube"
//! [scene]
//! builtin = "watercube"          # or: path = "data/watercube"
//! scale = "quick"
//! [scene.generate]               # passed to the scene generator as it is
//! seed = 3
//! [warmup]
//! iters = 300
//! ```

use std::fmt;
use std::path::{Path, PathBuf};

use serde::de::DeserializeOwned;
use serde::{Deserialize, Serialize};

use crate::schedule::LrSchedule;

/// File name of the resolved configuration inside a run folder.
pub const RESOLVED_FILE: &str = "config.resolved.toml";

/// A configuration error: which file, which key, where and what was expected.
#[derive(Debug, thiserror::Error)]
pub enum ConfigError {
    /// The file could not be read.
    #[error("cannot read experiment file {}", path.display())]
    Read {
        /// The file.
        path: PathBuf,
        /// The IO error.
        source: std::io::Error,
    },
    /// A file could not be written.
    #[error("cannot write {}", path.display())]
    Write {
        /// The file.
        path: PathBuf,
        /// The IO error.
        source: std::io::Error,
    },
    /// A key is unknown, has the wrong type or an invalid value, or the TOML does not parse.
    #[error("{}", invalid_message(path, *location, key, message))]
    Invalid {
        /// The file (or `<override>` / `<string>`).
        path: PathBuf,
        /// Line and column (1-based) when known.
        location: Option<(usize, usize)>,
        /// Dotted key, e.g. `joint.lr_renderer` (empty for pure syntax errors).
        key: String,
        /// What went wrong and what was expected.
        message: String,
    },
}

fn invalid_message(
    path: &Path,
    location: Option<(usize, usize)>,
    key: &str,
    message: &str,
) -> String {
    let mut s = path.display().to_string();
    if let Some((line, col)) = location {
        s.push_str(&format!(":{line}:{col}"));
    }
    if !key.is_empty() {
        s.push_str(&format!(": key `{key}`"));
    }
    s.push_str(&format!(": {message}"));
    s
}

impl ConfigError {
    /// The dotted key the error is about (empty when none).
    pub fn key(&self) -> &str {
        match self {
            ConfigError::Invalid { key, .. } => key,
            _ => "",
        }
    }

    fn invalid(path: &Path, key: &str, message: impl Into<String>) -> Self {
        ConfigError::Invalid {
            path: path.to_path_buf(),
            location: None,
            key: key.to_string(),
            message: message.into(),
        }
    }
}

/// 1-based line and column of byte `offset` in `text`.
pub fn line_col(text: &str, offset: usize) -> (usize, usize) {
    let offset = offset.min(text.len());
    let before = &text[..offset];
    let line = before.matches('\n').count() + 1;
    let col = before.rfind('\n').map_or(before.chars().count(), |nl| {
        before[nl + 1..].chars().count()
    }) + 1;
    (line, col)
}

/// Joins serde's path and the message into a dotted key: `unknown field `x`` at `joint`
/// becomes `joint.x`; `missing field `name`` at `.` becomes `name`.
fn dotted_key(path: &str, message: &str) -> String {
    let base = if path == "." { "" } else { path };
    for prefix in ["unknown field `", "missing field `"] {
        if let Some(rest) = message.strip_prefix(prefix)
            && let Some(end) = rest.find('`')
        {
            let field = &rest[..end];
            if base == field || base.ends_with(&format!(".{field}")) {
                return base.to_string();
            }
            return if base.is_empty() {
                field.to_string()
            } else {
                format!("{base}.{field}")
            };
        }
    }
    base.to_string()
}

/// Deserializes `T` from TOML `text`; errors name `origin`, the dotted key and line:col.
pub fn from_toml_str<T: DeserializeOwned>(text: &str, origin: &Path) -> Result<T, ConfigError> {
    let de = toml::Deserializer::parse(text).map_err(|e| ConfigError::Invalid {
        path: origin.to_path_buf(),
        location: e.span().map(|s| line_col(text, s.start)),
        key: String::new(),
        message: format!("TOML syntax error: {}", e.message()),
    })?;
    serde_path_to_error::deserialize(de).map_err(|e| {
        let path = e.path().to_string();
        let inner = e.into_inner();
        ConfigError::Invalid {
            path: origin.to_path_buf(),
            location: inner.span().map(|s| line_col(text, s.start)),
            key: dotted_key(&path, inner.message()),
            message: inner.message().to_string(),
        }
    })
}

/// Deserializes `T` from an in-memory TOML table (used after overrides).
fn from_table<T: DeserializeOwned>(table: toml::Table, origin: &Path) -> Result<T, ConfigError> {
    serde_path_to_error::deserialize(toml::Value::Table(table)).map_err(|e| {
        let path = e.path().to_string();
        let inner = e.into_inner();
        ConfigError::Invalid {
            path: origin.to_path_buf(),
            location: None,
            key: dotted_key(&path, inner.message()),
            message: inner.message().to_string(),
        }
    })
}

/// Reads a file, with an error naming it.
pub(crate) fn read_text(path: &Path) -> Result<String, ConfigError> {
    std::fs::read_to_string(path).map_err(|source| ConfigError::Read {
        path: path.to_path_buf(),
        source,
    })
}

// ---------------------------------------------------------------------------------------------
// Sections
// ---------------------------------------------------------------------------------------------

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
    /// Output folder; default `runs/<name>` (see [`Experiment::out_dir`]).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub out_dir: Option<PathBuf>,
    /// Which scene: an existing folder or a built-in one to generate.
    pub scene: SceneSection,
    /// The transition model (DLF).
    #[serde(default)]
    pub dlf: DlfSection,
    /// The renderer (PhysNeRF).
    #[serde(default)]
    pub renderer: RendererSection,
    /// Renderer warm-up on frame 0 (spec §4.1).
    #[serde(default)]
    pub warmup: WarmupSection,
    /// Joint grounding (spec §4.2).
    #[serde(default)]
    pub joint: JointSection,
    /// Evaluation (spec §6).
    #[serde(default)]
    pub eval: EvalSection,
}

fn default_seed() -> u64 {
    10
}
fn default_device() -> String {
    "cpu".into()
}

/// Built-in scenes the generator knows.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum BuiltinScene {
    /// A water cube dropped into the box.
    Watercube,
    /// A water sphere.
    Watersphere,
    /// A honey cone.
    Honeycone,
    /// A water bunny.
    Waterbunny,
}

impl BuiltinScene {
    /// Lower-case name as written in the TOML.
    pub fn name(self) -> &'static str {
        match self {
            BuiltinScene::Watercube => "watercube",
            BuiltinScene::Watersphere => "watersphere",
            BuiltinScene::Honeycone => "honeycone",
            BuiltinScene::Waterbunny => "waterbunny",
        }
    }
}

/// Size class of a generated scene.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum SceneScale {
    /// Small: minutes on 2 CPU cores.
    #[default]
    Quick,
    /// The paper's size (400×400 images, ~10k particles).
    Paper,
}

impl SceneScale {
    /// Lower-case name.
    pub fn name(self) -> &'static str {
        match self {
            SceneScale::Quick => "quick",
            SceneScale::Paper => "paper",
        }
    }
}

/// `[scene]`: exactly one of `path` (an existing scene folder) or `builtin` (generate one).
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SceneSection {
    /// An existing scene folder in NeuroFluid's layout (spec §5.1).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub path: Option<PathBuf>,
    /// A built-in scene, generated into `dir` when that folder holds no scene yet.
    #[serde(default, alias = "name", skip_serializing_if = "Option::is_none")]
    pub builtin: Option<BuiltinScene>,
    /// Scale of the generated scene (`quick` default, or `paper`).
    #[serde(default)]
    pub scale: SceneScale,
    /// Where the generated scene lives; default `data/<builtin>_<scale>`.
    #[serde(default, alias = "out", skip_serializing_if = "Option::is_none")]
    pub dir: Option<PathBuf>,
    /// Further generator settings, passed through to the scene generator unchanged
    /// (e.g. `seed`, `image_size`, `train_frames`, `test_frames`).
    #[serde(default, skip_serializing_if = "toml::Table::is_empty")]
    pub generate: toml::Table,
}

impl SceneSection {
    /// The scene folder: `path`, or `dir`, or `data/<builtin>_<scale>`.
    pub fn scene_dir(&self) -> PathBuf {
        if let Some(p) = &self.path {
            return p.clone();
        }
        if let Some(d) = &self.dir {
            return d.clone();
        }
        let name = self.builtin.map_or("scene", BuiltinScene::name);
        PathBuf::from(format!("data/{name}_{}", self.scale.name()))
    }

    /// The generator's `[scene]` table: `name`, `scale`, `out` plus the `[scene.generate]`
    /// keys (deserialize the scene generator's config from it). `None` when `path` is used.
    pub fn generator_table(&self) -> Option<toml::Table> {
        let builtin = self.builtin?;
        let mut t = self.generate.clone();
        t.insert("name".into(), builtin.name().into());
        t.insert("scale".into(), self.scale.name().into());
        t.insert(
            "out".into(),
            self.scene_dir().to_string_lossy().into_owned().into(),
        );
        Some(t)
    }
}

/// `[dlf]`: the transition model.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct DlfSection {
    /// Pretrained weights (`.pt` or `.safetensors`).
    pub weights: PathBuf,
    /// Gradients through the continuous-conv geometry (an improvement; off in the reference).
    pub geometry_grad: bool,
    /// Transitions unrolled per joint iteration (1 = the reference's truncated BPTT).
    pub bptt_steps: usize,
}

impl Default for DlfSection {
    fn default() -> Self {
        Self {
            weights: PathBuf::from("assets/dlf_pretrained/pretrained_model_weights.pt"),
            geometry_grad: false,
            bptt_steps: 1,
        }
    }
}

/// Which K particles the renderer's ball query keeps.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum NeighborSelection {
    /// The K lowest indices inside the ball (pytorch3d, the reference).
    #[default]
    LowestIndex,
    /// The K nearest particles.
    Nearest,
}

/// `[renderer.encoding]`: the particle encoding terms (the paper's Table 5 ablations).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct EncodingSection {
    /// γ(p_c), the fictitious particle centre.
    pub pc: bool,
    /// γ(σ_p), the particle density.
    pub sigma_p: bool,
    /// γ(v_d), the per-axis neighbour spread.
    pub vd: bool,
    /// γ(d_c), the camera-to-centre direction.
    pub dc: bool,
}

impl Default for EncodingSection {
    fn default() -> Self {
        Self {
            pc: true,
            sigma_p: true,
            vd: true,
            dc: true,
        }
    }
}

/// `[renderer]`: PhysNeRF sampling and encoding settings.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct RendererSection {
    /// Near ray bound; unset = the scene manifest's (9 for the released scenes).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub near: Option<f32>,
    /// Far ray bound; unset = the scene manifest's (13 for the released scenes).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub far: Option<f32>,
    /// Coarse samples per ray (64).
    pub n_samples: usize,
    /// Importance samples per ray (128).
    pub n_importance: usize,
    /// Ball-query radius r_s (0.225).
    pub radius: f32,
    /// Neighbour slots K (20).
    pub k: usize,
    /// Neighbour selection (`lowest_index`, the reference, or `nearest`).
    pub selection: NeighborSelection,
    /// Stratified jitter of the samples (off in the reference).
    pub jitter: bool,
    /// Rays per chunk when rendering full images (memory knob).
    pub chunk: usize,
    /// MLP depth D (8).
    pub depth: usize,
    /// MLP width W (256).
    pub width: usize,
    /// Layer whose input is concatenated with the encoding again (4).
    pub skip: usize,
    /// Encoding switches.
    pub encoding: EncodingSection,
}

impl Default for RendererSection {
    fn default() -> Self {
        Self {
            near: None,
            far: None,
            n_samples: 64,
            n_importance: 128,
            radius: 0.225,
            k: 20,
            selection: NeighborSelection::LowestIndex,
            jitter: false,
            chunk: 1024,
            depth: 8,
            width: 256,
            skip: 4,
            encoding: EncodingSection::default(),
        }
    }
}

impl RendererSection {
    /// The ray bounds: the config's when set, else the scene manifest's.
    pub fn bounds(&self, manifest_near: f32, manifest_far: f32) -> (f32, f32) {
        (
            self.near.unwrap_or(manifest_near),
            self.far.unwrap_or(manifest_far),
        )
    }
}

/// `[warmup]`: the renderer warm-up on frame 0 (spec §4.1).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct WarmupSection {
    /// Iterations (100 000).
    pub iters: u64,
    /// Rays per view per iteration (1024).
    pub rays: usize,
    /// Initial Adam learning rate (5e-4).
    pub lr: f64,
    /// lr(s) = lr · 0.1^(s / decay_steps) (10 000).
    pub decay_steps: u64,
    /// Iterations with s < precrop_iters draw pixels from the central window (500).
    pub precrop_iters: u64,
    /// Size of the central window as a fraction of the image side (0.5).
    pub precrop_frac: f64,
    /// Warm-up views; unset = the scene manifest's (view_1..view_4).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub views: Option<Vec<String>>,
    /// Log a metrics row every this many iterations.
    pub log_every: u64,
    /// Checkpoint every this many iterations (0 = only at the end).
    pub ckpt_every: u64,
    /// Render the held-out view every this many iterations (0 = only at the end).
    pub eval_every: u64,
}

impl Default for WarmupSection {
    fn default() -> Self {
        Self {
            iters: 100_000,
            rays: 1024,
            lr: 5e-4,
            decay_steps: 10_000,
            precrop_iters: 500,
            precrop_frac: 0.5,
            views: None,
            log_every: 100,
            ckpt_every: 500,
            eval_every: 5000,
        }
    }
}

impl WarmupSection {
    /// The warm-up learning-rate schedule (exponential, ×0.1 per `decay_steps`).
    pub fn lr_schedule(&self) -> LrSchedule {
        LrSchedule::Exponential {
            lr0: self.lr,
            decay_steps: self.decay_steps,
        }
    }

    /// The precrop fraction for 0-based iteration `step` (`None` = the full image).
    pub fn precrop_at(&self, step: u64) -> Option<f64> {
        (step < self.precrop_iters).then_some(self.precrop_frac)
    }
}

/// `[joint]`: joint grounding of DLF and PhysNeRF (spec §4.2).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct JointSection {
    /// Epochs over the training frames (20 000; one epoch = frames − 1 iterations).
    pub epochs: u64,
    /// Rays per iteration (1024).
    pub rays: usize,
    /// Renderer Adam learning rate (3e-4).
    pub lr_renderer: f64,
    /// Transition Adam learning rate (1e-5).
    pub lr_transition: f64,
    /// Renderer milestones: the factor halves for s > each (10k, 75k, 150k).
    pub renderer_milestones: Vec<u64>,
    /// Renderer factor per milestone passed (0.5).
    pub renderer_gamma: f64,
    /// Transition milestones (10k, 30k, 50k, 100k, 300k).
    pub transition_milestones: Vec<u64>,
    /// Transition factor per milestone passed (0.5).
    pub transition_gamma: f64,
    /// Weight of the box L1 penalty (1.0).
    pub boundary_weight: f64,
    /// Iterations with s < precrop_iters draw pixels from the central window (500).
    pub precrop_iters: u64,
    /// Central window fraction (0.5).
    pub precrop_frac: f64,
    /// Training view; unset = the scene manifest's (view_1).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub view: Option<String>,
    /// Log a metrics row every this many iterations.
    pub log_every: u64,
    /// Checkpoint every this many iterations (500; 0 = only at the end).
    pub ckpt_every: u64,
    /// Evaluate (rollout + renders) every this many iterations (500; 0 = only at the end).
    pub eval_every: u64,
}

impl Default for JointSection {
    fn default() -> Self {
        Self {
            epochs: 20_000,
            rays: 1024,
            lr_renderer: 3e-4,
            lr_transition: 1e-5,
            renderer_milestones: vec![10_000, 75_000, 150_000],
            renderer_gamma: 0.5,
            transition_milestones: vec![10_000, 30_000, 50_000, 100_000, 300_000],
            transition_gamma: 0.5,
            boundary_weight: 1.0,
            precrop_iters: 500,
            precrop_frac: 0.5,
            view: None,
            log_every: 49,
            ckpt_every: 500,
            eval_every: 500,
        }
    }
}

impl JointSection {
    /// The renderer's multi-step schedule.
    pub fn renderer_schedule(&self) -> LrSchedule {
        LrSchedule::MultiStep {
            lr0: self.lr_renderer,
            milestones: self.renderer_milestones.clone(),
            gamma: self.renderer_gamma,
        }
    }

    /// The transition model's multi-step schedule.
    pub fn transition_schedule(&self) -> LrSchedule {
        LrSchedule::MultiStep {
            lr0: self.lr_transition,
            milestones: self.transition_milestones.clone(),
            gamma: self.transition_gamma,
        }
    }

    /// The precrop fraction for 0-based iteration `step` (`None` = the full image).
    pub fn precrop_at(&self, step: u64) -> Option<f64> {
        (step < self.precrop_iters).then_some(self.precrop_frac)
    }
}

/// How particle files are encoded.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum PlyEncoding {
    /// Binary little-endian (compact, the default).
    #[default]
    Binary,
    /// ASCII (readable).
    Ascii,
}

/// `[eval]`: evaluation outputs (spec §6).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct EvalSection {
    /// Render the test view(s) and compute PSNR/SSIM.
    pub render: bool,
    /// Render every this many rollout steps (1 = every frame, as the paper's `eval_e2e.py`).
    pub render_every: usize,
    /// Image scale of the evaluation renders (1.0 = full size).
    pub image_scale: f64,
    /// Write predicted particles per frame as PLY.
    pub write_ply: bool,
    /// PLY encoding.
    pub ply_format: PlyEncoding,
    /// Also roll out the pretrained DLF (the paper's baseline).
    pub baseline: bool,
    /// Test views; unset = the scene manifest's (view_5).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub views: Option<Vec<String>>,
}

impl Default for EvalSection {
    fn default() -> Self {
        Self {
            render: true,
            render_every: 1,
            image_scale: 1.0,
            write_ply: true,
            ply_format: PlyEncoding::Binary,
            baseline: true,
            views: None,
        }
    }
}

// ---------------------------------------------------------------------------------------------
// Loading, validation, overrides
// ---------------------------------------------------------------------------------------------

impl Experiment {
    /// Reads and validates an experiment file.
    pub fn load(path: &Path) -> Result<Self, ConfigError> {
        let text = read_text(path)?;
        Self::from_toml_str(&text, path)
    }

    /// Parses and validates TOML text (`origin` names the source in errors).
    pub fn from_toml_str(text: &str, origin: &Path) -> Result<Self, ConfigError> {
        let exp: Experiment = from_toml_str(text, origin)?;
        exp.validate(origin)?;
        Ok(exp)
    }

    /// The output folder: `out_dir`, or `runs/<name>`.
    pub fn out_dir(&self) -> PathBuf {
        self.out_dir
            .clone()
            .unwrap_or_else(|| PathBuf::from("runs").join(&self.name))
    }

    /// The run folder (same as [`Experiment::out_dir`]).
    pub fn run_dir(&self) -> PathBuf {
        self.out_dir()
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
    /// string): `joint.lr_renderer=1e-4`, `renderer.encoding.pc=false`, `scene.path=data/x`.
    /// Unknown keys, wrong types and invalid values are errors naming the key.
    pub fn apply_override(&mut self, spec: &str) -> Result<(), ConfigError> {
        let origin = PathBuf::from(format!("override `{spec}`"));
        let (key, value) = parse_override(spec, &origin)?;
        let mut table =
            toml::Table::try_from(&*self).expect("experiment serialises to a TOML table");
        set_dotted(&mut table, &key, value, &origin)?;
        let exp: Experiment = from_table(table, &origin)?;
        exp.validate(&origin)?;
        *self = exp;
        Ok(())
    }

    /// Applies several overrides in order.
    pub fn apply_overrides<S: AsRef<str>>(&mut self, specs: &[S]) -> Result<(), ConfigError> {
        specs
            .iter()
            .try_for_each(|s| self.apply_override(s.as_ref()))
    }

    /// Checks values serde cannot: ranges, exclusive choices, ordering.
    pub fn validate(&self, origin: &Path) -> Result<(), ConfigError> {
        let bad = |key: &str, msg: &str| Err(ConfigError::invalid(origin, key, msg));
        if self.name.trim().is_empty() || self.name.contains(['/', '\\']) {
            return bad("name", "expected a non-empty name without slashes");
        }
        match (&self.scene.path, &self.scene.builtin) {
            (Some(_), Some(_)) => {
                return bad(
                    "scene",
                    "give either `path` (an existing scene) or `builtin` (generate one), not both",
                );
            }
            (None, None) => {
                return bad(
                    "scene",
                    "expected `path = \"<scene dir>\"` or `builtin = \"watercube\" | \"watersphere\" | \"honeycone\" | \"waterbunny\"`",
                );
            }
            (Some(_), None) if !self.scene.generate.is_empty() => {
                return bad(
                    "scene.generate",
                    "generator settings need `builtin`, not `path`",
                );
            }
            _ => {}
        }
        for reserved in ["name", "scale", "out"] {
            if self.scene.generate.contains_key(reserved) {
                return bad(
                    &format!("scene.generate.{reserved}"),
                    "set this as `scene.builtin` / `scene.scale` / `scene.dir` instead",
                );
            }
        }
        if self.dlf.bptt_steps == 0 {
            return bad("dlf.bptt_steps", "expected at least 1");
        }
        let r = &self.renderer;
        for (key, v) in [("renderer.near", r.near), ("renderer.far", r.far)] {
            if v.is_some_and(|v| !(v.is_finite() && v >= 0.0)) {
                return bad(key, "expected a finite distance ≥ 0");
            }
        }
        if let (Some(n), Some(f)) = (r.near, r.far)
            && n >= f
        {
            return bad("renderer.far", "expected far > near");
        }
        if r.n_samples < 2 {
            return bad("renderer.n_samples", "expected at least 2");
        }
        if !(r.radius.is_finite() && r.radius > 0.0) {
            return bad("renderer.radius", "expected a positive radius");
        }
        if r.k == 0 {
            return bad("renderer.k", "expected at least 1");
        }
        if r.chunk == 0 {
            return bad("renderer.chunk", "expected at least 1");
        }
        if r.depth == 0 || r.width == 0 {
            return bad(
                "renderer.depth",
                "expected an MLP of depth ≥ 1 and width ≥ 1",
            );
        }
        let w = &self.warmup;
        if w.rays == 0 {
            return bad("warmup.rays", "expected at least 1");
        }
        if !(w.lr.is_finite() && w.lr > 0.0) {
            return bad("warmup.lr", "expected a positive learning rate");
        }
        if w.decay_steps == 0 {
            return bad("warmup.decay_steps", "expected at least 1");
        }
        check_frac(w.precrop_frac, "warmup.precrop_frac", origin)?;
        if w.views.as_ref().is_some_and(Vec::is_empty) {
            return bad("warmup.views", "expected at least one view");
        }
        let j = &self.joint;
        if j.rays == 0 {
            return bad("joint.rays", "expected at least 1");
        }
        for (key, lr) in [
            ("joint.lr_renderer", j.lr_renderer),
            ("joint.lr_transition", j.lr_transition),
        ] {
            if !(lr.is_finite() && lr >= 0.0) {
                return bad(key, "expected a learning rate ≥ 0");
            }
        }
        for (key, m) in [
            ("joint.renderer_milestones", &j.renderer_milestones),
            ("joint.transition_milestones", &j.transition_milestones),
        ] {
            if m.windows(2).any(|w| w[0] >= w[1]) {
                return bad(key, "expected strictly increasing steps");
            }
        }
        for (key, g) in [
            ("joint.renderer_gamma", j.renderer_gamma),
            ("joint.transition_gamma", j.transition_gamma),
        ] {
            if !(g.is_finite() && g > 0.0 && g <= 1.0) {
                return bad(key, "expected a factor in (0, 1]");
            }
        }
        if !(j.boundary_weight.is_finite() && j.boundary_weight >= 0.0) {
            return bad("joint.boundary_weight", "expected a weight ≥ 0");
        }
        check_frac(j.precrop_frac, "joint.precrop_frac", origin)?;
        let e = &self.eval;
        if !(e.image_scale.is_finite() && e.image_scale > 0.0 && e.image_scale <= 1.0) {
            return bad("eval.image_scale", "expected a scale in (0, 1]");
        }
        if e.render_every == 0 {
            return bad("eval.render_every", "expected at least 1");
        }
        if e.views.as_ref().is_some_and(Vec::is_empty) {
            return bad("eval.views", "expected at least one view");
        }
        Ok(())
    }
}

fn check_frac(v: f64, key: &str, origin: &Path) -> Result<(), ConfigError> {
    if v.is_finite() && v > 0.0 && v <= 1.0 {
        Ok(())
    } else {
        Err(ConfigError::invalid(
            origin,
            key,
            "expected a fraction in (0, 1]",
        ))
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
            "expected a dotted key like `joint.lr_renderer`",
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

impl fmt::Display for BuiltinScene {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
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
        assert!(!e.dlf.geometry_grad);
        assert_eq!(e.dlf.bptt_steps, 1);
        let r = &e.renderer;
        assert_eq!(r.bounds(9.0, 13.0), (9.0, 13.0));
        assert_eq!((r.n_samples, r.n_importance, r.k), (64, 128, 20));
        assert_eq!(r.radius, 0.225);
        assert_eq!(r.selection, NeighborSelection::LowestIndex);
        assert!(!r.jitter);
        assert_eq!((r.depth, r.width, r.skip), (8, 256, 4));
        assert_eq!(e.eval.render_every, 1);
        assert_eq!(e.run_dir(), e.out_dir());
        assert_eq!(r.encoding, EncodingSection::default());
        assert!(r.encoding.pc && r.encoding.sigma_p && r.encoding.vd && r.encoding.dc);
        let w = &e.warmup;
        assert_eq!(
            (w.iters, w.rays, w.decay_steps, w.precrop_iters),
            (100_000, 1024, 10_000, 500)
        );
        assert_eq!((w.lr, w.precrop_frac), (5e-4, 0.5));
        let j = &e.joint;
        assert_eq!((j.epochs, j.rays), (20_000, 1024));
        assert_eq!((j.lr_renderer, j.lr_transition), (3e-4, 1e-5));
        assert_eq!(j.renderer_milestones, vec![10_000, 75_000, 150_000]);
        assert_eq!(
            j.transition_milestones,
            vec![10_000, 30_000, 50_000, 100_000, 300_000]
        );
        assert_eq!((j.renderer_gamma, j.transition_gamma), (0.5, 0.5));
        assert_eq!(j.boundary_weight, 1.0);
        assert!(e.eval.render && e.eval.write_ply);
        assert_eq!(e.eval.image_scale, 1.0);
        // the schedules built from the config are the reference's
        assert!((w.lr_schedule().lr_at(10_000) - 5e-5).abs() < 1e-18);
        assert_eq!(j.renderer_schedule().lr_at(10_001), 1.5e-4);
        assert_eq!(w.precrop_at(499), Some(0.5));
        assert_eq!(w.precrop_at(500), None);
    }

    #[test]
    fn unknown_key_names_the_dotted_key_file_and_line() {
        let text = format!("{MINIMAL}[joint]\nepochs = 2\nlr_renderr = 1e-4\n");
        let err = parse(&text).unwrap_err();
        assert_eq!(err.key(), "joint.lr_renderr");
        let msg = err.to_string();
        assert!(msg.starts_with("exp.toml:6:"), "{msg}");
        assert!(msg.contains("joint.lr_renderr"), "{msg}");
        assert!(
            msg.contains("lr_renderer"),
            "should list the expected keys: {msg}"
        );
        // nested table
        let text = format!("{MINIMAL}[renderer.encoding]\npc = true\npq = false\n");
        let err = parse(&text).unwrap_err();
        assert_eq!(err.key(), "renderer.encoding.pq");
        // top level
        let err = parse(&format!("seeed = 3\n{MINIMAL}")).unwrap_err();
        assert_eq!(err.key(), "seeed");
        assert!(err.to_string().starts_with("exp.toml:1:"), "{err}");
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
                "[scene]\nbuiltin = \"watercube\"\n[dlf]\nbptt_steps = 0\n",
                "dlf.bptt_steps",
            ),
            (
                "[scene]\nbuiltin = \"watercube\"\n[warmup]\nprecrop_frac = 1.5\n",
                "warmup.precrop_frac",
            ),
            (
                "[scene]\nbuiltin = \"watercube\"\n[joint]\nrenderer_milestones = [5, 3]\n",
                "joint.renderer_milestones",
            ),
            (
                "[scene]\nbuiltin = \"watercube\"\n[renderer]\nnear = 5.0\nfar = 4.0\n",
                "renderer.far",
            ),
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
            let err = parse(&format!("name = \"t\"\n{body}")).unwrap_err();
            assert_eq!(err.key(), key, "{err}");
            assert!(err.to_string().contains("exp.toml"), "{err}");
        }
    }

    #[test]
    fn overrides_set_values_and_reject_unknown_keys() {
        let mut e = parse(MINIMAL).unwrap();
        e.apply_overrides(&[
            "joint.lr_renderer=1e-4",
            "renderer.encoding.pc=false",
            "warmup.iters = 7",
            "joint.renderer_milestones=[1, 2]",
            "eval.views=[\"view_5\", \"view_6\"]",
            "renderer.near=8",
        ])
        .unwrap();
        assert_eq!(e.joint.lr_renderer, 1e-4);
        assert!(!e.renderer.encoding.pc);
        assert_eq!(e.warmup.iters, 7);
        assert_eq!(e.joint.renderer_milestones, vec![1, 2]);
        assert_eq!(e.renderer.near, Some(8.0));
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
        let err = e.apply_override("warmup.iters=lots").unwrap_err();
        assert_eq!(err.key(), "warmup.iters");
        let err = e.apply_override("warmup.iters.x=1").unwrap_err();
        assert_eq!(err.key(), "warmup.iters");
        let err = e.apply_override("dlf.bptt_steps=0").unwrap_err();
        assert_eq!(err.key(), "dlf.bptt_steps");
        assert!(e.apply_override("no_equals_sign").is_err());
        assert_eq!(e, before, "failed overrides leave the experiment unchanged");
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
            "lr_transition = 0.00001",
            "epochs = 3",
            "[renderer.encoding]",
        ] {
            assert!(text.contains(needle), "missing {needle} in\n{text}");
        }
        let back = Experiment::load(&path).unwrap();
        assert_eq!(back, e.resolved());
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
