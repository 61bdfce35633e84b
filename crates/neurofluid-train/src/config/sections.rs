//! The tables of an experiment file. The models' own settings are embedded as they are
//! (`[physnerf]` is [`PhysNerfConfig`], `[dlf].geometry` is [`GeometryMode`], every optimiser is
//! an [`OptimConfig`]); the tables here hold only what the trainer itself decides.

use std::fmt;
use std::path::PathBuf;

use neurofluid_core::scene::{Role, Scene};
use neurofluid_dlf::{GeometryMode, StepRules};
use serde::{Deserialize, Serialize};

use crate::optim::{
    JointDlfGroup, JointPhysNerfGroup, JointPhysicsGroup, NerfGroup, OptimConfig, WarmupGroup,
};
use crate::stages::joint::terms::TermsSection;
use neurofluid_physnerf::{NerfConfig, Positions};

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

impl fmt::Display for BuiltinScene {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
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

/// `[scene]`: exactly one of `path` (an existing scene folder) or `builtin` (generate one), and
/// the ray segment the renderer samples.
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
    /// Near end of the ray segment; unset = the scene manifest's (9 for the released scenes).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub near: Option<f32>,
    /// Far end of the ray segment; unset = the scene manifest's (13 for the released scenes).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub far: Option<f32>,
    /// Where the particles at t = 0 come from: `"true"` (the scene's, as in the paper's main
    /// results) or `"from_images"` (a NeRF on the warm-up views of frame 0, marching cubes and a
    /// lattice fill: the paper's Table 5, "unknown initial particle positions").
    #[serde(default)]
    pub initial: InitialParticles,
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

    /// The ray segment: the experiment's bounds where set, else the scene manifest's.
    pub fn bounds(&self, manifest_near: f32, manifest_far: f32) -> (f32, f32) {
        (
            self.near.unwrap_or(manifest_near),
            self.far.unwrap_or(manifest_far),
        )
    }
}

/// Where the particles at t = 0 come from.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum InitialParticles {
    /// The scene's particles of frame 0.
    #[default]
    True,
    /// Recovered from the warm-up images of frame 0 (`init-particles`).
    FromImages,
}

/// The images NeRF-T trains on.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum NerfTImages {
    /// One warm-up view per training frame, cycling through the warm-up views: four viewpoints
    /// over time, which a scene has only when its warm-up views are rendered at every frame.
    #[default]
    Cycle,
    /// The images NeuroFluid trains on: the warm-up views of the warm-up frame and the joint
    /// stage's views (`joint.view`, `joint.extra_views`) at every training frame.
    Neurofluid,
}

/// `[nerf]`: a plain NeRF or NeRF-T, trained for the initial particles or as a novel-view
/// baseline. The network is `[nerf.model]` ([`NerfConfig`]).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct NerfSection {
    /// The networks and sampling.
    pub model: NerfConfig,
    /// Iterations (200 000 in the original NeRF's Blender scenes).
    pub iters: u64,
    /// Rays per iteration, spread over the images drawn for the step (1024).
    pub rays: usize,
    /// Images drawn per iteration (4: the warm-up views of frame 0 for NeRF).
    pub images_per_step: usize,
    /// NeRF-T's images (`"cycle"`; `"neurofluid"`: the same images as NeuroFluid's).
    pub t_images: NerfTImages,
    /// Density only inside the scene's box (false: the original NeRF, density anywhere on the
    /// ray). With four views a NeRF explains each view by floaters near its camera; the fluid
    /// is known to be inside the box.
    pub clip_to_box: bool,
    /// Adam and schedule (5e-4, ×0.1 per 250k steps).
    pub optim: OptimConfig<NerfGroup>,
    /// Iterations with s < precrop_iters draw pixels from the central window (500).
    pub precrop_iters: u64,
    /// Size of the central window as a fraction of the image side (0.5).
    pub precrop_frac: f64,
    /// Log a metrics row every this many iterations.
    pub log_every: u64,
    /// Checkpoint every this many iterations (0 = only at the end).
    pub ckpt_every: u64,
    /// Render the first test view every this many iterations (0 = never).
    pub preview_every: u64,
}

impl Default for NerfSection {
    fn default() -> Self {
        Self {
            model: NerfConfig::default(),
            iters: 200_000,
            rays: 1024,
            images_per_step: 4,
            t_images: NerfTImages::Cycle,
            clip_to_box: false,
            optim: OptimConfig::default(),
            precrop_iters: 500,
            precrop_frac: 0.5,
            log_every: 100,
            ckpt_every: 1000,
            preview_every: 5000,
        }
    }
}

impl NerfSection {
    /// The precrop fraction for 0-based iteration `step` (`None` = the full image).
    pub fn precrop_at(&self, step: u64) -> Option<f64> {
        (step < self.precrop_iters).then_some(self.precrop_frac)
    }
}

/// Which of the scene's views the evaluation scores as novel views (`eval.novel_views`).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum NovelViews {
    /// The test views: the evaluation's.
    #[default]
    Test,
    /// The validation views (`validation` in `scene.json`): views no stage trains on, kept
    /// aside to choose settings with, so that the test views are never read to choose.
    Validation,
}

impl NovelViews {
    /// The scene role whose views and images are scored.
    pub fn role(self) -> Role {
        match self {
            NovelViews::Test => Role::Test,
            NovelViews::Validation => Role::Validation,
        }
    }
}

/// Where the surface of the NeRF's density lies.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum SurfaceThreshold {
    /// Half the largest density inside the box (the classic half-maximum rule: one voxel's peak
    /// decides it; it kept too little of seven of nine scenes, BENCHMARKS.md).
    HalfMax,
    /// The density at which one particle spacing (2r) of fluid absorbs `opacity` of the light,
    /// σ_iso = −ln(1 − opacity)/(2r): an absolute rule for opaque fluids.
    Opacity,
    /// The density whose body, seen from each warm-up camera, best covers the pixels the fluid
    /// covers in that view's alpha (mean intersection over union): a rule from the images
    /// alone, for any material and any renderer's look (`crate::geometry::silhouette_iso`). Needs
    /// images with an alpha channel. The default: the only rule that recovered every scene of
    /// the bed and the built-in ones within about one particle radius (BENCHMARKS.md).
    #[default]
    Silhouette,
}

/// `[initial]`: how the particles at t = 0 are recovered from the NeRF of frame 0.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct InitialSection {
    /// Grid spacing of the density samples, in particle radii (1: 0.025 in DLF's units).
    pub cell_radii: f64,
    /// Which rule puts the surface (`silhouette`).
    pub threshold: SurfaceThreshold,
    /// The opacity of the `opacity` rule (0.5).
    pub opacity: f64,
    /// Keep only the largest connected body (drops NeRF's floaters; true).
    pub largest_only: bool,
}

impl Default for InitialSection {
    fn default() -> Self {
        Self {
            cell_radii: 1.0,
            threshold: SurfaceThreshold::Silhouette,
            opacity: 0.5,
            largest_only: true,
        }
    }
}

impl InitialSection {
    /// The density threshold σ_iso for particles of radius `radius`, given the largest density
    /// sampled in the box; `None` for the silhouette rule, which the views decide.
    pub fn iso(&self, radius: f64, max_density: f64) -> Option<f64> {
        match self.threshold {
            SurfaceThreshold::HalfMax => Some(0.5 * max_density),
            SurfaceThreshold::Opacity => Some(-(1.0 - self.opacity).ln() / (2.0 * radius)),
            SurfaceThreshold::Silhouette => None,
        }
    }
}

/// `[refit]`: a second renderer for novel views, fitted to the grounded rollout after the joint
/// stage (an option; the paper renders with the PhysNeRF trained jointly). Grounding is left as
/// it is: DLF is frozen, so d and d′ are the joint stage's; the evaluation renders NeuroFluid's
/// views (and the renderer on the true particles) with the refitted PhysNeRF.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct RefitSection {
    /// Fit the second renderer (`false`: the evaluation renders with the joint stage's).
    pub enabled: bool,
    /// `physnerf.positions` of the second renderer (`relative`: it moves with its particles,
    /// which carries over better from frame to frame but, trained during grounding, moved DLF
    /// less; docs/notebook/benchmarks-history.md, "a renderer that moves with its particles"); the rest of
    /// `[physnerf]` is the first renderer's.
    pub positions: Positions,
    /// Rays per fit step replayed from the warm-up renderer's renders of the warm-up frame from
    /// all round the fluid ([`crate::stages::orbit`]; the warm-up stage's renderer, the teacher
    /// whatever `positions`), so that the refitted renderer keeps the colour the warm-up drew
    /// from every direction while it fits the grounded rollout on one view. The dynamics are
    /// the joint stage's whatever it does. 0 = none.
    pub replay_rays: usize,
}

impl Default for RefitSection {
    fn default() -> Self {
        Self {
            enabled: false,
            positions: Positions::Relative,
            replay_rays: 0,
        }
    }
}

/// `[dlf]`: where DLF's weights come from, how its conv geometry enters autodiff, and the rules
/// of its step (`neurofluid_dlf::StepRules`: `containment`, `energy_cap`, `gravity_scale`,
/// `viscosity`, `dissipation`, `dissipation_frame`), in every rollout, the baseline DLF's too.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct DlfSection {
    /// Pretrained weights (`.pt`, `.safetensors` or one of our `.bpk` checkpoints).
    pub weights: PathBuf,
    /// `constant` (Open3D, the reference) or `differentiable` (gradients through the geometry).
    pub geometry: GeometryMode,
    /// The rules of DLF's step, keys of this table.
    #[serde(flatten)]
    pub rules: StepRules,
}

impl Default for DlfSection {
    fn default() -> Self {
        Self {
            weights: PathBuf::from("assets/dlf_pretrained/pretrained_model_weights.pt"),
            geometry: GeometryMode::Constant,
            rules: StepRules::default(),
        }
    }
}

/// `[warmup]`: PhysNeRF alone on frame 0 (spec §4.1).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct WarmupSection {
    /// Iterations (100 000).
    pub iters: u64,
    /// Rays per view per iteration (1024).
    pub rays: usize,
    /// PhysNeRF's Adam and schedule (5e-4, ×0.1 per 10 000 steps).
    pub optim: OptimConfig<WarmupGroup>,
    /// Iterations with s < precrop_iters draw pixels from the central window (500).
    pub precrop_iters: u64,
    /// Size of the central window as a fraction of the image side (0.5).
    pub precrop_frac: f64,
    /// Warm-up views; unset = the scene manifest's (view_1..view_4).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub views: Option<Vec<String>>,
    /// A warm-up view held out of the warm-up (and of the NeRFs, which see the warm-up's
    /// views): the previews render it at the warm-up's frame instead of the first test view,
    /// so their PSNR scores a novel view from the training images alone. Unset: none.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub held_out: Option<String>,
    /// Log a metrics row every this many iterations.
    pub log_every: u64,
    /// Checkpoint every this many iterations (0 = only at the end).
    pub ckpt_every: u64,
    /// Render the held-out view every this many iterations (0 = never).
    pub preview_every: u64,
}

impl Default for WarmupSection {
    fn default() -> Self {
        Self {
            iters: 100_000,
            rays: 1024,
            optim: OptimConfig::default(),
            precrop_iters: 500,
            precrop_frac: 0.5,
            views: None,
            held_out: None,
            log_every: 100,
            ckpt_every: 500,
            preview_every: 5000,
        }
    }
}

impl WarmupSection {
    /// The view the previews render at the warm-up's frame, with the role its images are
    /// read under, when previews are on: the held-out warm-up view (`held_out`), else the first
    /// test view.
    pub fn preview_view(&self, scene: &Scene) -> Option<(String, Role)> {
        if self.preview_every == 0 {
            return None;
        }
        match &self.held_out {
            Some(v) => Some((v.clone(), Role::Warmup)),
            None => scene
                .views(Role::Test)
                .first()
                .map(|v| (v.clone(), Role::Test)),
        }
    }

    /// The warm-up views: the configured ones, else the scene's, without the held-out one.
    pub fn views(&self, scene: &Scene) -> Vec<String> {
        let mut views = self.views_before_holding_out(scene);
        views.retain(|v| Some(v) != self.held_out.as_ref());
        views
    }

    /// What is wrong with `held_out` on `scene` for the warm-up: not one of the warm-up views,
    /// or the only one ([`crate::config::Experiment::scene_problem`] checks the other stages).
    pub fn held_out_problem(&self, scene: &Scene) -> Option<String> {
        let held = self.held_out.as_ref()?;
        let views = self.views_before_holding_out(scene);
        if !views.contains(held) {
            return Some(format!(
                "warmup.held_out: expected one of the warm-up views {views:?}, got {held:?}"
            ));
        }
        self.views(scene).is_empty().then(|| {
            format!("warmup.held_out: {held:?} is the only warm-up view; the warm-up needs another")
        })
    }

    /// The configured warm-up views, else the scene's.
    fn views_before_holding_out(&self, scene: &Scene) -> Vec<String> {
        self.views
            .clone()
            .unwrap_or_else(|| scene.views(Role::Warmup).to_vec())
    }

    /// The precrop fraction for 0-based iteration `step` (`None` = the full image).
    pub fn precrop_at(&self, step: u64) -> Option<f64> {
        (step < self.precrop_iters).then_some(self.precrop_frac)
    }
}

/// `[joint]`: DLF and PhysNeRF grounded together (spec §4.2).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct JointSection {
    /// Epochs over the training frames (20 000; one epoch = frames − 1 iterations).
    pub epochs: u64,
    /// Rays per iteration (1024).
    pub rays: usize,
    /// Transitions unrolled per optimiser step (1 = the reference's truncated BPTT).
    pub bptt_steps: usize,
    /// DLF steps once every this many windows of `bptt_steps` transitions (and at the end of
    /// every epoch), its gradients summed over them; PhysNeRF steps after every window (1 = the
    /// reference: both every transition).
    pub dlf_every: usize,
    /// PhysNeRF's Adam and schedule (3e-4, halved after 10k, 75k, 150k).
    pub physnerf_optim: OptimConfig<JointPhysNerfGroup>,
    /// DLF's Adam and schedule (1e-5, halved after 10k, 30k, 50k, 100k, 300k).
    pub dlf_optim: OptimConfig<JointDlfGroup>,
    /// Weight of the box L1 penalty (1.0).
    pub boundary_weight: f64,
    /// Iterations with s < precrop_iters draw pixels from the central window (500).
    pub precrop_iters: u64,
    /// Central window fraction (0.5).
    pub precrop_frac: f64,
    /// The share of each step's rays drawn from the pixels where the target shows fluid or the
    /// projected prediction covers ([`neurofluid_core::ray_focus`]); the rest uniform over the
    /// image. 0 = the reference's uniform draw.
    pub foreground_rays: f64,
    /// Standard deviation (m/s) of Gaussian noise added to the velocities DLF steps from at
    /// every transition of the joint stage ([`crate::stages::joint`]'s `input_noise`): training
    /// for long rollouts. 0 = the paper's rollout.
    pub input_noise: f64,
    /// The particle terms, each under its own table (`[joint.terms.anchor]`, …): none = the
    /// paper's loss ([`crate::stages::joint::terms`]).
    pub terms: TermsSection,
    /// Physical scalars of DLF's step fitted by the images (`[joint.physics]`); unset = the
    /// rules' constants, as the paper.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub physics: Option<PhysicsFit>,
    /// Training view; unset = the scene manifest's (view_1).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub view: Option<String>,
    /// Warm-up views whose images at every training frame join the training view's in every
    /// step's loss, the step's rays shared among the views (needs the warm-up views at every
    /// frame: `scene.generate.warmup_every_frame`). Empty = the paper's single view.
    pub extra_views: Vec<String>,
    /// Log a metrics row every this many iterations.
    pub log_every: u64,
    /// Checkpoint every this many iterations (500; 0 = only at the end).
    pub ckpt_every: u64,
    /// Render the training view from the prediction every this many iterations (0 = never).
    pub preview_every: u64,
}

impl Default for JointSection {
    fn default() -> Self {
        Self {
            epochs: 20_000,
            rays: 1024,
            bptt_steps: 1,
            dlf_every: 1,
            physnerf_optim: OptimConfig::default(),
            dlf_optim: OptimConfig::default(),
            boundary_weight: 1.0,
            precrop_iters: 500,
            precrop_frac: 0.5,
            foreground_rays: 0.0,
            input_noise: 0.0,
            terms: TermsSection::default(),
            physics: None,
            view: None,
            extra_views: Vec::new(),
            log_every: 49,
            ckpt_every: 500,
            preview_every: 500,
        }
    }
}

impl JointSection {
    /// The training view: the configured one, else the scene's first (none in a scene without
    /// training views).
    pub fn view(&self, scene: &Scene) -> Option<String> {
        self.view
            .clone()
            .or_else(|| scene.views(Role::Train).first().cloned())
    }

    /// The views the joint stage trains on with the split each comes from: the training view
    /// (split `train`; none when the scene has no training view), then `extra_views` (warm-up
    /// views). Unchecked: [`crate::stages::views::joint_sources`] checks them.
    pub fn views_by_role(&self, scene: &Scene) -> Vec<(Role, String)> {
        self.view(scene)
            .map(|v| (Role::Train, v))
            .into_iter()
            .chain(self.extra_views.iter().map(|v| (Role::Warmup, v.clone())))
            .collect()
    }

    /// `joint.extra_views (view_2, view_3)`: how errors name the extra views.
    pub fn extra_views_label(&self) -> String {
        format!("joint.extra_views ({})", self.extra_views.join(", "))
    }

    /// The precrop fraction for 0-based iteration `step` (`None` = the full image).
    pub fn precrop_at(&self, step: u64) -> Option<f64> {
        (step < self.precrop_iters).then_some(self.precrop_frac)
    }
}

/// A physical scalar of DLF's step that the joint stage can fit
/// ([`neurofluid_dlf::physics`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum PhysicalScalar {
    /// The pre-step's gravity scale (`dlf.gravity_scale`), kept in [0.25, 4].
    GravityScale,
    /// The XSPH viscosity's strength (`dlf.viscosity`), kept in [0, 1].
    Viscosity,
    /// The share of each velocity a step takes away (`dlf.dissipation`), kept in [0, 0.5].
    Dissipation,
}

impl PhysicalScalar {
    /// All of them, in the order of [`neurofluid_dlf::PHYSICS_NAMES`].
    pub const ALL: [Self; 3] = [Self::GravityScale, Self::Viscosity, Self::Dissipation];

    /// Its place in [`neurofluid_dlf::PhysicsValues::to_array`].
    pub fn index(self) -> usize {
        self as usize
    }

    /// Its name in the config and the metrics ([`neurofluid_dlf::PHYSICS_NAMES`]).
    pub fn name(self) -> &'static str {
        neurofluid_dlf::PHYSICS_NAMES[self.index()]
    }

    /// The values it is kept within.
    pub fn bounds(self) -> (f64, f64) {
        match self {
            Self::GravityScale => (0.25, 4.0),
            Self::Viscosity => (0.0, 1.0),
            Self::Dissipation => (0.0, 0.5),
        }
    }
}

/// `[joint.physics]`: physical scalars of DLF's step fitted by the images, starting from the
/// `[dlf]` rules' values, with their own Adam; the others keep the rules' constants. The values
/// fitted are logged (`physics/<name>`) and step every later rollout of the grounded DLF.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PhysicsFit {
    /// The scalars fitted: any of `"gravity_scale"`, `"viscosity"`, `"dissipation"`.
    pub fit: Vec<PhysicalScalar>,
    /// Their Adam and schedule (1e-2, constant).
    #[serde(default)]
    pub optim: OptimConfig<JointPhysicsGroup>,
    /// Epochs at the start in which DLF's weights take no step: the scalars (and the renderer)
    /// are fitted with DLF held, then all jointly (0 = jointly from the start; at least
    /// `joint.epochs` = the scalars alone).
    #[serde(default)]
    pub hold_dlf_epochs: u64,
    /// `[joint.physics.search]`: a grid the fitted scalars start from instead of the rules'
    /// values: the point whose rollout best matches the joint stage's views (the training view,
    /// then `joint.extra_views`) by the grid's objective ([`crate::stages::joint::search`]).
    /// Unset = no search.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub search: Option<ScalarGrid>,
}

/// What `[joint.physics.search]` scores each point of its grid by.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum SearchObjective {
    /// The warm-up renderer's image loss on each view (coarse + fine MSE).
    #[default]
    Image,
    /// Each view's silhouette: the Jaccard distance between the pixels where its images show
    /// fluid (alpha, or colour off the white background) and those the rollout's particles
    /// cover. No renderer, no random pixels.
    Silhouette,
}

impl SearchObjective {
    fn is_image(&self) -> bool {
        *self == Self::Image
    }
}

/// `[joint.physics.search]`: the values tried for each fitted scalar; a fitted scalar without
/// values keeps the rules' value in every point.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ScalarGrid {
    /// What each point is scored by (`"image"` or `"silhouette"`).
    #[serde(default, skip_serializing_if = "SearchObjective::is_image")]
    pub objective: SearchObjective,
    /// Gravity scales tried.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub gravity_scale: Vec<f64>,
    /// Viscosities tried.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub viscosity: Vec<f64>,
    /// Dissipations tried.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub dissipation: Vec<f64>,
}

impl ScalarGrid {
    /// The most points a search may try (each costs a rollout and a render of the training view).
    pub const MAX_POINTS: usize = 400;

    /// The values tried for `scalar`.
    pub fn values(&self, scalar: PhysicalScalar) -> &[f64] {
        match scalar {
            PhysicalScalar::GravityScale => &self.gravity_scale,
            PhysicalScalar::Viscosity => &self.viscosity,
            PhysicalScalar::Dissipation => &self.dissipation,
        }
    }

    /// Every point of the grid (in the order of [`PhysicalScalar::ALL`]), the first scalar's
    /// values outermost; a scalar without values keeps its value in `start`.
    pub fn points(&self, start: [f64; 3]) -> Vec<[f64; 3]> {
        let mut points = vec![start];
        for scalar in PhysicalScalar::ALL {
            let values = self.values(scalar);
            if values.is_empty() {
                continue;
            }
            points = points
                .iter()
                .flat_map(|p| {
                    values.iter().map(move |&v| {
                        let mut q = *p;
                        q[scalar.index()] = v;
                        q
                    })
                })
                .collect();
        }
        points
    }

    /// What is wrong with the grid for the scalars `fit`, as (field, message).
    pub fn problem(&self, fit: &[PhysicalScalar]) -> Option<(String, String)> {
        if PhysicalScalar::ALL
            .iter()
            .all(|s| self.values(*s).is_empty())
        {
            return Some((
                "gravity_scale".into(),
                "expected values for at least one fitted scalar (or no search table)".into(),
            ));
        }
        let mut count = 1usize;
        for scalar in PhysicalScalar::ALL {
            let values = self.values(scalar);
            let field = scalar.name();
            if values.is_empty() {
                continue;
            }
            if !fit.contains(&scalar) {
                return Some((
                    field.into(),
                    format!("{field:?} is searched but not fitted (add it to joint.physics.fit)"),
                ));
            }
            let (lo, hi) = scalar.bounds();
            if let Some(v) = values.iter().find(|v| !(lo..=hi).contains(*v)) {
                return Some((field.into(), format!("{v} is outside [{lo}, {hi}]")));
            }
            count = count.saturating_mul(values.len());
        }
        (count > Self::MAX_POINTS).then(|| {
            (
                "gravity_scale".into(),
                format!("{count} points; at most {}", Self::MAX_POINTS),
            )
        })
    }
}

impl PhysicsFit {
    /// Whether `scalar` is fitted.
    pub fn fits(&self, scalar: PhysicalScalar) -> bool {
        self.fit.contains(&scalar)
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
    /// DLF† weights: DLF fine-tuned with supervision on the training frames (`pretrain-dlf
    /// --scene`), the paper's supervised reference; rolled out beside the others when set.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub supervised_dlf: Option<PathBuf>,
    /// A frozen supervised reference (a TOML file: [`neurofluid_outputs::reference`]): the report
    /// adds g, the share of the way from the pretrained DLF to it that the images went.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub reference: Option<PathBuf>,
    /// Write, per test view, an animation of truth | DLF | NeuroFluid over the rendered frames
    /// and a picture of the particle sets coloured by their distance to the truth (renders the
    /// baseline's particles too).
    pub animate: bool,
    /// Write `eval/viewer.html`: the particle sets of every frame, the test cameras, the
    /// distances and the renders in a page any browser opens.
    pub viewer: bool,
    /// Test views; unset = the scene manifest's (view_5).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub views: Option<Vec<String>>,
    /// Which views are scored as novel views: the test views, or the scene's validation views
    /// (to choose settings with; the report says which).
    pub novel_views: NovelViews,
}

impl EvalSection {
    /// The views rendered and scored: the configured ones, else the scene's views of
    /// `novel_views`' role.
    pub fn views(&self, scene: &Scene) -> Vec<String> {
        self.views
            .clone()
            .unwrap_or_else(|| scene.views(self.novel_views.role()).to_vec())
    }

    /// What is wrong with `novel_views` on `scene`: validation views asked of a scene that has
    /// none.
    pub fn novel_views_problem(&self, scene: &Scene) -> Option<String> {
        (self.novel_views == NovelViews::Validation && scene.views(Role::Validation).is_empty())
            .then(|| {
                format!(
                    "eval.novel_views = \"validation\": {} lists no validation views (a \
                     `validation` view set beside `test`; scripts/testbed/validation_views.py \
                     adds two to a test-bed scene)",
                    scene
                        .root()
                        .join(neurofluid_core::scene::MANIFEST_FILE)
                        .display()
                )
            })
    }
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
            supervised_dlf: None,
            reference: None,
            animate: true,
            viewer: true,
            views: None,
            novel_views: NovelViews::Test,
        }
    }
}

/// `[diagnostics]`: what a run measures to be understood, never to choose a setting: more
/// renders and rollouts at the evaluation. Nothing here changes what is trained (no key shapes a
/// stage's state) nor the evaluation's own rows; each adds rows, pictures or tables beside them.
/// All off by default and in the quick configs.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct DiagnosticsSection {
    /// Also render the true particles of every rendered step with the grounded renderer and
    /// score them beside NeuroFluid's (a row of the novel-view table): what the renderer would
    /// score with perfect dynamics, which splits a novel-view gap into the renderer's part and
    /// the dynamics' part. One more render per rendered step.
    pub render_truth: bool,
    /// Also render the rollouts of the pretrained DLF (`eval.baseline`) and of DLF†
    /// (`eval.supervised_dlf`), where evaluated, with the grounded renderer and score them beside
    /// NeuroFluid's (rows of the novel-view table): the novel views the same renderer gives on
    /// dynamics not grounded, and on dynamics supervised with the true particles. One more
    /// render per rendered step and rollout.
    pub render_dlf: bool,
    /// NeuroFluid's DLF as evaluated: the pretrained weights (`dlf.weights`) plus this fraction
    /// of what grounding changed, parameter by parameter (a weight-space interpolation, as
    /// WiSE-FT does for fine-tuned networks). 1 = the grounded DLF as trained (the paper), 0 =
    /// the pretrained DLF. The renderer stays the grounded one.
    pub weight_interpolation: f64,
    /// Also roll out NeuroFluid's DLF at these `diagnostics.weight_interpolation` fractions (d and d′ only,
    /// no renders) and draw d against d′ in both windows from the pretrained DLF to the
    /// grounded one (`eval/interpolation.png`, a table in the report): how much of grounding's
    /// change fits the truth and where it starts to throw spray. Empty = none.
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub interpolation_sweep: Vec<f64>,
}

impl Default for DiagnosticsSection {
    fn default() -> Self {
        Self {
            render_truth: false,
            render_dlf: false,
            weight_interpolation: 1.0,
            interpolation_sweep: Vec::new(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn surface_thresholds_follow_their_rules() {
        let half = InitialSection {
            threshold: SurfaceThreshold::HalfMax,
            ..InitialSection::default()
        };
        assert_eq!(half.iso(0.025, 8.0), Some(4.0));
        let opaque = InitialSection {
            threshold: SurfaceThreshold::Opacity,
            opacity: 0.5,
            ..InitialSection::default()
        };
        // one spacing (0.05) at σ_iso absorbs half the light: exp(−σ·0.05) = 0.5
        let s = opaque.iso(0.025, 8.0).unwrap();
        assert!(((-s * 0.05).exp() - 0.5).abs() < 1e-12, "{s}");
        assert_eq!(InitialSection::default().iso(0.025, 8.0), None);
    }
}
