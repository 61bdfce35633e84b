//! What each section of the experiment checks of itself that serde cannot (ranges, exclusive
//! choices, ordering), the cadence of each training section, and the keys in each that never
//! shape a training state. [`super::Experiment::validate`] and [`super::settings`] ask the
//! sections; no rule is restated as a dotted-key literal elsewhere.

use neurofluid_physnerf::{DensityActivation, PhysNerfConfig};

use super::{
    DiagnosticsSection, DlfSection, EvalSection, InitialSection, JointSection, NerfSection,
    SceneSection, WarmupSection,
};

/// The first problem of a section: the field (dotted, relative to the section) and what was
/// expected.
pub type Problem = Option<(String, String)>;

/// A section of the experiment TOML.
pub trait Section {
    /// Its key in the experiment (`warmup`).
    const KEY: &'static str;

    /// Its keys (relative) that never shape a training state: what is logged and when, memory.
    fn free_keys() -> Vec<&'static str> {
        Vec::new()
    }

    /// The first value that serde accepted but the section cannot run with.
    fn problem(&self) -> Problem;
}

/// When the driver logs, evaluates and checkpoints (every this many steps; 0 = never, and
/// for checkpoints: only at the end).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Cadence {
    /// A metrics row every this many steps (and after the last one).
    pub log_every: u64,
    /// An evaluation every this many steps.
    pub evaluate_every: u64,
    /// A checkpoint every this many steps (and always after the last step run).
    pub checkpoint_every: u64,
}

/// The keys of a training section's cadence (in every such section).
pub const CADENCE_KEYS: [&str; 3] = ["log_every", "ckpt_every", "preview_every"];

/// A training stage's section: its cadence is one [`Cadence`], built from the section's
/// `log_every`, `preview_every` and `ckpt_every` (the keys stay flat in each section: serde's
/// `flatten` cannot deny unknown keys).
pub trait Cadenced: Section {
    /// When the stage logs, evaluates and checkpoints.
    fn cadence(&self) -> Cadence;
}

/// A list of views `views` (`field`): at least one when `at_least_one`, and none named twice (a
/// view listed twice would be trained on or scored twice as if it were two).
fn views_problem(views: &[String], field: &str, at_least_one: bool) -> Problem {
    if at_least_one && views.is_empty() {
        return problem(field, "expected at least one view");
    }
    let twice = neurofluid_core::paths::first_repeated(views)?;
    problem(
        field,
        &format!(
            "{} is listed twice; expected each view once",
            neurofluid_core::paths::shown(twice)
        ),
    )
}

fn problem(field: &str, msg: &str) -> Problem {
    Some((field.to_string(), msg.to_string()))
}

fn frac(v: f64, field: &str) -> Problem {
    (!(v.is_finite() && v > 0.0 && v <= 1.0))
        .then(|| (field.into(), "expected a fraction in (0, 1]".into()))
}

fn under(prefix: &str, p: Option<(&str, impl Into<String>)>) -> Problem {
    p.map(|(k, m)| (format!("{prefix}.{k}"), m.into()))
}

macro_rules! cadenced {
    ($section:ty) => {
        impl Cadenced for $section {
            fn cadence(&self) -> Cadence {
                Cadence {
                    log_every: self.log_every,
                    evaluate_every: self.preview_every,
                    checkpoint_every: self.ckpt_every,
                }
            }
        }
    };
}
cadenced!(WarmupSection);
cadenced!(JointSection);
cadenced!(NerfSection);

impl Section for SceneSection {
    const KEY: &'static str = "scene";

    /// Validation views are added to a scene beside its other views, which they leave as they
    /// are, and no stage reads them.
    fn free_keys() -> Vec<&'static str> {
        vec!["generate.validation_views"]
    }

    fn problem(&self) -> Problem {
        match (&self.path, &self.builtin) {
            (Some(_), Some(_)) => {
                return problem(
                    "",
                    "give either `path` (an existing scene) or `builtin` (generate one), not both",
                );
            }
            (None, None) => {
                return problem(
                    "",
                    "expected `path = \"<scene dir>\"` or `builtin = \"watercube\" | \"watersphere\" | \"honeycone\" | \"waterbunny\"`",
                );
            }
            (Some(_), None) if !self.generate.is_empty() => {
                return problem("generate", "generator settings need `builtin`, not `path`");
            }
            _ => {}
        }
        for reserved in ["name", "scale", "out"] {
            if self.generate.contains_key(reserved) {
                return problem(
                    &format!("generate.{reserved}"),
                    "set this as `scene.builtin` / `scene.scale` / `scene.dir` instead",
                );
            }
        }
        for (key, v) in [("near", self.near), ("far", self.far)] {
            if v.is_some_and(|v| !(v.is_finite() && v >= 0.0)) {
                return problem(key, "expected a finite distance ≥ 0");
            }
        }
        if let (Some(n), Some(f)) = (self.near, self.far)
            && n >= f
        {
            return problem("far", "expected far > near");
        }
        None
    }
}

impl Section for PhysNerfConfig {
    const KEY: &'static str = "physnerf";

    fn free_keys() -> Vec<&'static str> {
        vec!["chunk"]
    }

    fn problem(&self) -> Problem {
        PhysNerfConfig::problem(self).map(|(k, m)| (k.to_string(), m))
    }
}

impl Section for WarmupSection {
    const KEY: &'static str = "warmup";

    fn free_keys() -> Vec<&'static str> {
        CADENCE_KEYS.to_vec()
    }

    fn problem(&self) -> Problem {
        if self.iters == 0 {
            return problem("iters", "expected at least 1 iteration");
        }
        if self.rays == 0 {
            return problem("rays", "expected at least 1");
        }
        under("optim", self.optim.problem())
            .or_else(|| frac(self.precrop_frac, "precrop_frac"))
            .or_else(|| {
                let views = self.views.as_deref()?;
                views_problem(views, "views", true)
            })
    }
}

impl Section for JointSection {
    const KEY: &'static str = "joint";

    fn free_keys() -> Vec<&'static str> {
        CADENCE_KEYS.to_vec()
    }

    fn problem(&self) -> Problem {
        if self.epochs == 0 {
            return problem("epochs", "expected at least 1 epoch");
        }
        if self.rays == 0 {
            return problem("rays", "expected at least 1");
        }
        if self.dlf_every == 0 {
            return problem("dlf_every", "expected at least 1");
        }
        if self.bptt_steps == 0 {
            return problem("bptt_steps", "expected at least 1");
        }
        if let Some(p) = under("physnerf_optim", self.physnerf_optim.problem())
            .or_else(|| under("dlf_optim", self.dlf_optim.problem()))
        {
            return Some(p);
        }
        if !(self.boundary_weight.is_finite() && self.boundary_weight >= 0.0) {
            return problem("boundary_weight", "expected a weight ≥ 0");
        }
        if let Some(p) = frac(self.precrop_frac, "precrop_frac") {
            return Some(p);
        }
        if !(0.0..=1.0).contains(&self.foreground_rays) {
            return problem("foreground_rays", "expected a share in [0, 1]");
        }
        if !(self.input_noise.is_finite() && self.input_noise >= 0.0) {
            return problem("input_noise", "expected a standard deviation ≥ 0 (m/s)");
        }
        if let Some((field, msg)) = self.terms.problem() {
            return Some((format!("terms.{field}"), msg));
        }
        if let Some(physics) = &self.physics {
            if physics.fit.is_empty() {
                return problem(
                    "physics.fit",
                    "expected at least one of \"gravity_scale\", \"viscosity\", \"dissipation\" \
                     (or no [joint.physics] table)",
                );
            }
            if let Some(twice) = neurofluid_core::paths::first_repeated(&physics.fit) {
                return problem("physics.fit", &format!("{twice:?} is listed twice"));
            }
            if let Some(p) = under("physics.optim", physics.optim.problem()) {
                return Some(p);
            }
            if let Some((field, msg)) = physics
                .search
                .as_ref()
                .and_then(|g| g.problem(&physics.fit))
            {
                return Some((format!("physics.search.{field}"), msg));
            }
        }
        views_problem(&self.extra_views, "extra_views", false)
    }
}

impl Section for NerfSection {
    const KEY: &'static str = "nerf";

    fn free_keys() -> Vec<&'static str> {
        let mut keys = CADENCE_KEYS.to_vec();
        keys.push("model.chunk");
        keys
    }

    fn problem(&self) -> Problem {
        if let Some(p) = under("model", self.model.problem()) {
            return Some(p);
        }
        if self.model.density == DensityActivation::Softplus && !self.clip_to_box {
            return problem(
                "model.density",
                "\"softplus\" needs nerf.clip_to_box = true (outside the box the density must \
                 be zero, or every ray's infinite last interval is opaque)",
            );
        }
        if self.iters == 0 {
            return problem("iters", "expected at least 1 iteration");
        }
        if self.rays == 0 || self.images_per_step == 0 {
            return problem("rays", "expected at least 1 ray and 1 image per step");
        }
        if self.rays < self.images_per_step {
            return problem(
                "images_per_step",
                "expected at most `nerf.rays` images per step",
            );
        }
        under("optim", self.optim.problem()).or_else(|| frac(self.precrop_frac, "precrop_frac"))
    }
}

impl Section for InitialSection {
    const KEY: &'static str = "initial";

    fn problem(&self) -> Problem {
        if !(self.cell_radii.is_finite() && self.cell_radii > 0.0) {
            return problem("cell_radii", "expected a grid spacing > 0 particle radii");
        }
        if !(self.opacity > 0.0 && self.opacity < 1.0) {
            return problem("opacity", "expected an opacity in (0, 1)");
        }
        None
    }
}

impl Section for DlfSection {
    const KEY: &'static str = "dlf";

    fn problem(&self) -> Problem {
        self.rules
            .problem()
            .map(|e| (e.field.to_string(), e.expected))
    }
}

impl Section for EvalSection {
    const KEY: &'static str = "eval";

    /// The whole section: evaluation never shapes a training state.
    fn free_keys() -> Vec<&'static str> {
        vec![""]
    }

    fn problem(&self) -> Problem {
        if !(self.image_scale.is_finite() && self.image_scale > 0.0 && self.image_scale <= 1.0) {
            return problem("image_scale", "expected a scale in (0, 1]");
        }
        if self.render_every == 0 {
            return problem("render_every", "expected at least 1");
        }
        let views = self.views.as_deref()?;
        views_problem(views, "views", true)
    }
}

impl Section for DiagnosticsSection {
    const KEY: &'static str = "diagnostics";

    /// The whole section: diagnostics never shape a training state.
    fn free_keys() -> Vec<&'static str> {
        vec![""]
    }

    fn problem(&self) -> Problem {
        if !(0.0..=1.0).contains(&self.weight_interpolation) {
            return problem("weight_interpolation", "expected a fraction in [0, 1]");
        }
        if !self
            .interpolation_sweep
            .iter()
            .all(|f| (0.0..=1.0).contains(f))
        {
            return problem("interpolation_sweep", "expected fractions in [0, 1]");
        }
        None
    }
}

/// `section.field` (`section` alone for the whole section).
pub fn dotted(section: &str, field: &str) -> String {
    if field.is_empty() {
        section.to_string()
    } else {
        format!("{section}.{field}")
    }
}

/// The free keys of `S`, dotted.
pub fn free_keys_of<S: Section>() -> Vec<String> {
    S::free_keys()
        .into_iter()
        .map(|k| dotted(S::KEY, k))
        .collect()
}

/// The first problem of `section`, its field dotted under the section's key.
pub fn problem_of<S: Section>(section: &S) -> Problem {
    section.problem().map(|(k, m)| (dotted(S::KEY, &k), m))
}
