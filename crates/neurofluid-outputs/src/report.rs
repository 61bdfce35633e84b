//! The evaluation report (spec §6): per-frame particle distance d (GT→pred nearest neighbour
//! × 1000) of NeuroFluid, of the DLF baseline and, when asked, of DLF† (DLF fine-tuned with
//! supervision on the training frames); the paper's Table 2 columns (mean d over the grounding
//! window t = 1–49, d at its last frame, the same over the prediction window t = 50–59) and
//! PSNR/SSIM/LPIPS per view; written as JSON, per-frame CSV and markdown, each atomically.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use neurofluid_core::metrics::FarSplit;
use serde::{Deserialize, Serialize};

use crate::formats::csv_text::{cell, csv_text};
use crate::formats::markup::markdown_text;

/// JSON file name of the report inside an eval folder.
pub const JSON_FILE: &str = "report.json";
/// Per-frame CSV file name.
pub const FRAMES_CSV_FILE: &str = "frames.csv";
/// Markdown summary file name.
pub const MARKDOWN_FILE: &str = "report.md";

/// Errors writing or reading a report.
#[derive(Debug, thiserror::Error)]
pub enum ReportError {
    /// A file could not be read or written.
    #[error("report file {}", path.display())]
    Io {
        /// The file.
        path: PathBuf,
        /// The IO error.
        source: std::io::Error,
    },
    /// A report file is not valid JSON of the expected shape.
    #[error("report file {}: {message}", path.display())]
    Parse {
        /// The file.
        path: PathBuf,
        /// What is wrong.
        message: String,
    },
}

/// The frame windows the means are taken over (inclusive, in rollout steps t from frame 0).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct Windows {
    /// Grounding window (t = 1–49: the frames seen in training).
    pub grounding: (usize, usize),
    /// Prediction window (t = 50–59: beyond the training frames).
    pub prediction: (usize, usize),
}

impl Windows {
    /// The paper's windows: grounding t = 1…49, prediction t = 50…59.
    pub fn paper() -> Self {
        Self {
            grounding: (1, 49),
            prediction: (50, 59),
        }
    }

    /// Windows for a scene whose training sequence has `train_frames` frames and whose test
    /// rollout has `test_frames` frames: grounding 1…train−1, prediction train…test−1
    /// (50 and 60 give the paper's windows).
    pub fn from_lengths(train_frames: usize, test_frames: usize) -> Self {
        Self {
            grounding: (1, train_frames.saturating_sub(1).max(1)),
            prediction: (train_frames, test_frames.saturating_sub(1)),
        }
    }
}

/// Particle distances d and d′ of each rollout at one rollout step, keyed by rollout label.
/// Report files hold a field per model (`neurofluid`, `dlf`, `supervised_dlf`, d′ under `reverse`:
/// [`Rollout::key`]), as every earlier release wrote them.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(from = "FrameDistanceFile", into = "FrameDistanceFile")]
pub struct FrameDistance {
    /// Rollout step t (prediction of frame t from the GT frame 0).
    pub t: usize,
    /// d of each evaluated rollout: NeuroFluid (the grounded transition model), the pretrained
    /// DLF it started from (the paper's baseline), DLF† (`eval.supervised_dlf`: DLF fine-tuned
    /// with supervision on the training frames, the paper's supervised reference).
    pub d: Rollouts<f64>,
    /// d the other way (d′: from each predicted particle to the nearest true one, × 1000) of each
    /// rollout where evaluated: large where a prediction puts particles where the truth has none
    /// (spray, floaters), which d does not see.
    pub reverse: Rollouts<f64>,
}

impl FrameDistance {
    /// Step `t`, no rollout scored yet.
    pub fn new(t: usize) -> Self {
        Self {
            t,
            d: Rollouts::new(),
            reverse: Rollouts::new(),
        }
    }
}

/// [`FrameDistance`] as report files hold it.
#[derive(Serialize, Deserialize)]
struct FrameDistanceFile {
    t: usize,
    neurofluid: f64,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    dlf: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    supervised_dlf: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    published_dlf: Option<f64>,
    #[serde(default, skip_serializing_if = "ReverseFile::is_empty")]
    reverse: ReverseFile,
}

/// d′ of each model as report files hold it.
#[derive(Default, PartialEq, Serialize, Deserialize)]
struct ReverseFile {
    #[serde(default, skip_serializing_if = "Option::is_none")]
    neurofluid: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    dlf: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    supervised_dlf: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    published_dlf: Option<f64>,
}

impl ReverseFile {
    /// True when no model's d′ was evaluated (reports written before d′ existed).
    fn is_empty(&self) -> bool {
        *self == Self::default()
    }
}

impl From<FrameDistanceFile> for FrameDistance {
    fn from(f: FrameDistanceFile) -> Self {
        let r = f.reverse;
        Self {
            t: f.t,
            d: Rollouts::in_table_order([
                Some(f.neurofluid),
                f.dlf,
                f.supervised_dlf,
                f.published_dlf,
            ]),
            reverse: Rollouts::in_table_order([
                r.neurofluid,
                r.dlf,
                r.supervised_dlf,
                r.published_dlf,
            ]),
        }
    }
}

impl From<FrameDistance> for FrameDistanceFile {
    fn from(f: FrameDistance) -> Self {
        let [neurofluid, dlf, supervised_dlf, published_dlf] = f.d.of_models();
        let [r_neurofluid, r_dlf, r_supervised_dlf, r_published_dlf] = f.reverse.of_models();
        Self {
            t: f.t,
            // NeuroFluid's d is in every report: the evaluation always rolls it out
            neurofluid: neurofluid.unwrap_or(f64::NAN),
            dlf,
            supervised_dlf,
            published_dlf,
            reverse: ReverseFile {
                neurofluid: r_neurofluid,
                dlf: r_dlf,
                supervised_dlf: r_supervised_dlf,
                published_dlf: r_published_dlf,
            },
        }
    }
}

/// Values per rollout, keyed by the rollout's table label ([`Rollout::label`], or any other
/// rollout's), in the order they were set: a rollout scored beside the others is one more entry.
/// Two are equal when they hold the same labels with the same values, in any order.
#[derive(Debug, Clone)]
pub struct Rollouts<T>(Vec<(String, T)>);

impl<T> Default for Rollouts<T> {
    fn default() -> Self {
        Self(Vec::new())
    }
}

impl<T: PartialEq> PartialEq for Rollouts<T> {
    fn eq(&self, other: &Self) -> bool {
        self.0.len() == other.0.len() && self.iter().all(|(l, v)| other.get(l) == Some(v))
    }
}

impl<T> Rollouts<T> {
    /// No rollout.
    pub fn new() -> Self {
        Self::default()
    }

    /// The value of the rollout labelled `label`, if set.
    pub fn get(&self, label: impl AsRef<str>) -> Option<&T> {
        let label = label.as_ref();
        self.0.iter().find(|(l, _)| l == label).map(|(_, v)| v)
    }

    /// Sets the value of the rollout labelled `label` (in its place, or after the others).
    pub fn set(&mut self, label: impl AsRef<str>, value: T) {
        let label = label.as_ref();
        match self.0.iter_mut().find(|(l, _)| l == label) {
            Some((_, v)) => *v = value,
            None => self.0.push((label.to_string(), value)),
        }
    }

    /// `self` with `label`'s value set to `value`, where there is one.
    pub fn with(mut self, label: impl AsRef<str>, value: Option<T>) -> Self {
        if let Some(value) = value {
            self.set(label, value);
        }
        self
    }

    /// The labels and values, in order.
    pub fn iter(&self) -> impl Iterator<Item = (&str, &T)> {
        self.0.iter().map(|(l, v)| (l.as_str(), v))
    }

    /// True when no rollout has a value.
    pub fn is_empty(&self) -> bool {
        self.0.is_empty()
    }
}

impl Rollouts<f64> {
    /// The values in the order of the files' fields ([`Rollout::FILE_ORDER`]), where set.
    fn of_models(&self) -> [Option<f64>; 4] {
        Rollout::FILE_ORDER.map(|m| self.get(m).copied())
    }

    /// Values in the order of the files' fields ([`Rollout::FILE_ORDER`]) where there are, in
    /// table order.
    fn in_table_order(values: [Option<f64>; 4]) -> Self {
        Rollout::ALL.into_iter().fold(Self::new(), |r, m| {
            let k = Rollout::FILE_ORDER.iter().position(|f| *f == m);
            r.with(m, k.and_then(|k| values[k]))
        })
    }
}

/// The models whose rollouts the evaluation scores by d, in table order: the labels a report
/// knows (its table's wording, its plots' colours); [`Rollouts`] takes any other label too.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Rollout {
    /// The pretrained DLF (the paper's DLF), under the run's rules.
    Dlf,
    /// The pretrained DLF stepped as the paper steps it (no walls, cap, gravity scale,
    /// viscosity or dissipation): beside [`Rollout::Dlf`] when the run's rules differ, so that
    /// the paper's comparison stays in the report.
    PublishedDlf,
    /// DLF fine-tuned with supervision on the training frames (the paper's DLF†).
    SupervisedDlf,
    /// The grounded DLF.
    NeuroFluid,
}

impl Rollout {
    /// Every rollout, in table order.
    pub const ALL: [Rollout; 4] = [
        Rollout::Dlf,
        Rollout::PublishedDlf,
        Rollout::SupervisedDlf,
        Rollout::NeuroFluid,
    ];

    /// The order of the report files' fields (earlier releases wrote the first three).
    const FILE_ORDER: [Rollout; 4] = [
        Rollout::NeuroFluid,
        Rollout::Dlf,
        Rollout::SupervisedDlf,
        Rollout::PublishedDlf,
    ];

    /// The rollout's d in `f`, if it was evaluated.
    pub fn of(self, f: &FrameDistance) -> Option<f64> {
        f.d.get(self).copied()
    }

    /// The rollout's d′ (prediction → truth) in `f`, if it was evaluated.
    pub fn reverse_of(self, f: &FrameDistance) -> Option<f64> {
        f.reverse.get(self).copied()
    }

    /// The name in tables and plots: the rollout's label.
    pub fn label(self) -> &'static str {
        match self {
            Rollout::Dlf => "DLF",
            Rollout::PublishedDlf => "DLF (paper's step)",
            Rollout::SupervisedDlf => "DLF†",
            Rollout::NeuroFluid => "NeuroFluid",
        }
    }

    /// The rollout labelled `label`, if it is one of these.
    pub fn of_label(label: &str) -> Option<Self> {
        Self::ALL.into_iter().find(|r| r.label() == label)
    }

    /// The rollout's name in report files' fields and CSV columns (`neurofluid_d`, …).
    pub fn key(self) -> &'static str {
        match self {
            Rollout::Dlf => "dlf",
            Rollout::PublishedDlf => "published_dlf",
            Rollout::SupervisedDlf => "supervised_dlf",
            Rollout::NeuroFluid => "neurofluid",
        }
    }
}

impl AsRef<str> for Rollout {
    fn as_ref(&self) -> &str {
        self.label()
    }
}

/// What a row of a per-sequence table is of: the truth, or a rollout (by its label). Report files
/// hold it as text: `truth`, or the label.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
#[serde(from = "String", into = "String")]
pub enum Sequence {
    /// The true particles.
    Truth,
    /// A rollout, by its table label.
    Rollout(String),
}

impl From<String> for Sequence {
    fn from(s: String) -> Self {
        if s == "truth" {
            Self::Truth
        } else {
            Self::Rollout(s)
        }
    }
}

impl From<Sequence> for String {
    fn from(s: Sequence) -> Self {
        s.to_string()
    }
}

impl std::fmt::Display for Sequence {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Self::Truth => f.write_str("truth"),
            Self::Rollout(label) => f.write_str(label),
        }
    }
}

/// One row of the paper's Table 2: d over the grounding and prediction windows.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct DistanceRow {
    /// Mean d over the grounding window (the paper's d_avg, t < 50).
    pub grounding_mean: Option<f64>,
    /// d at the last frame of the grounding window (t = 49).
    pub grounding_last: Option<f64>,
    /// Mean d over the prediction window (t ≥ 50).
    pub prediction_mean: Option<f64>,
    /// d at the last frame of the prediction window (t = 59).
    pub prediction_last: Option<f64>,
}

/// Image metrics of one rendered test image.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ImageScore {
    /// Test view (`view_5`).
    pub view: String,
    /// Rollout step t.
    pub t: usize,
    /// PSNR in dB (8-bit images, spec §6.3).
    pub psnr: f64,
    /// SSIM (valid Gaussian window, spec §6.3).
    pub ssim: f64,
    /// LPIPS (AlexNet, v0.1; absent for images under 31 pixels a side and in older reports).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub lpips: Option<f64>,
    /// The share of the render's squared error on the pixels where the truth shows fluid (its
    /// alpha ≥ ½), the rest being around it (absent for a perfect render and in older reports).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub error_on_fluid: Option<f64>,
}

/// Means over a window, `None` where the window holds no value: d of each rollout (by label)
/// and the image metrics. Report files hold a field per model's d (`neurofluid_d`, `dlf_d`,
/// `supervised_dlf_d`, as every earlier release wrote them, and `published_dlf_d`).
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(from = "WindowMeansFile", into = "WindowMeansFile")]
pub struct WindowMeans {
    /// Each rollout's mean d, where it has d in the window.
    pub d: Rollouts<f64>,
    /// Mean PSNR over views and frames.
    pub psnr: Option<f64>,
    /// Mean SSIM over views and frames.
    pub ssim: Option<f64>,
    /// Mean LPIPS over views and frames.
    pub lpips: Option<f64>,
}

/// [`WindowMeans`] as report files hold it.
#[derive(Serialize, Deserialize)]
struct WindowMeansFile {
    neurofluid_d: Option<f64>,
    dlf_d: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    supervised_dlf_d: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    published_dlf_d: Option<f64>,
    psnr: Option<f64>,
    ssim: Option<f64>,
    #[serde(default)]
    lpips: Option<f64>,
}

impl From<WindowMeansFile> for WindowMeans {
    fn from(f: WindowMeansFile) -> Self {
        Self {
            d: Rollouts::in_table_order([
                f.neurofluid_d,
                f.dlf_d,
                f.supervised_dlf_d,
                f.published_dlf_d,
            ]),
            psnr: f.psnr,
            ssim: f.ssim,
            lpips: f.lpips,
        }
    }
}

impl From<WindowMeans> for WindowMeansFile {
    fn from(m: WindowMeans) -> Self {
        let [neurofluid_d, dlf_d, supervised_dlf_d, published_dlf_d] = m.d.of_models();
        Self {
            neurofluid_d,
            dlf_d,
            supervised_dlf_d,
            published_dlf_d,
            psnr: m.psnr,
            ssim: m.ssim,
            lpips: m.lpips,
        }
    }
}

impl WindowMeans {
    /// The mean d of the rollout labelled `label`, where it has d in the window.
    pub fn d_of(&self, label: impl AsRef<str>) -> Option<f64> {
        self.d.get(label).copied()
    }
}

/// Per-view image means over all evaluated frames.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ViewMeans {
    /// View name.
    pub view: String,
    /// Mean PSNR.
    pub psnr: f64,
    /// Mean SSIM.
    pub ssim: f64,
    /// Mean LPIPS.
    #[serde(default)]
    pub lpips: Option<f64>,
    /// Number of images.
    pub images: usize,
}

/// The report's summary.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Summary {
    /// Means over the grounding window.
    pub grounding: WindowMeans,
    /// Means over the prediction window.
    pub prediction: WindowMeans,
    /// Means over every evaluated frame.
    pub all: WindowMeans,
    /// Image means per view.
    pub views: Vec<ViewMeans>,
}

/// The whole evaluation of one run.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct EvalReport {
    /// Experiment name.
    pub experiment: String,
    /// Scene name or folder.
    pub scene: String,
    /// Which checkpoint / stage was evaluated (free text, e.g. `joint step 98`).
    pub checkpoint: String,
    /// The averaging windows.
    pub windows: Windows,
    /// d per rollout step.
    pub frames: Vec<FrameDistance>,
    /// Image metrics per view and step.
    pub images: Vec<ImageScore>,
    /// The rollouts started from particles recovered from images (not the true frame 0).
    #[serde(default)]
    pub initial_from_images: bool,
    /// Novel-view rows scored on the same test views and frames beside NeuroFluid's: the
    /// baselines (NeRF, NeRF-T) and, with `diagnostics.render_truth`, the renderer on the true particles.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub nvs_baselines: Vec<BaselineScores>,
    /// Per rollout (its table label), the most predicted particles at any step farther than one
    /// particle radius outside the box interior: particles through the walls.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub escaped: Vec<(String, usize)>,
    /// The seal (SHA-256 of `checksums.json`) of the joint checkpoint scored: the report
    /// describes the run only while that checkpoint is the joint stage's latest.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub scored_seal: Option<String>,
    /// `diagnostics.weight_interpolation` where it was not 1: NeuroFluid's DLF was the pretrained
    /// weights plus this fraction of grounding's change.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub weight_interpolation: Option<f64>,
    /// The rules every DLF rollout of the run stepped under, the pretrained baseline's too (the
    /// walls, the energy cap: `[dlf]`), as the table's note names them; empty = DLF's steps as
    /// they are.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub dlf_rules: Vec<String>,
    /// The physical scalars the joint stage fitted (`[joint.physics]`), each with the value it
    /// started from: NeuroFluid's DLF steps with the fitted ones, the pretrained baseline with
    /// the rules'. Empty = none fitted.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub fitted_physics: Vec<FittedScalar>,
    /// The share of the way to supervision the images went, where a reference file was given
    /// (`eval.reference`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub gap: Option<crate::reference::GapShare>,
    /// What rendered NeuroFluid's views (and the renderer on the true particles) when it was not
    /// the PhysNeRF trained jointly with DLF (`refit.enabled`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub renderer: Option<String>,
    /// The novel views scored are the scene's validation views (`eval.novel_views =
    /// "validation"`), not its test views.
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub validation_views: bool,
    /// `diagnostics.interpolation_sweep`: d and d′ of NeuroFluid's DLF from the pretrained weights to
    /// the grounded ones, by fraction.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub interpolation: Vec<InterpolationPoint>,
    /// Per rollout and the truth, the mechanical energy gained over each window
    /// ([`neurofluid_core::metrics::energy_gains`]): a fluid in a closed box gains none, and what a
    /// rollout gains it keeps as fluid thrown where the truth has none.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub energy: Vec<EnergyGain>,
    /// Per rollout and the truth, the share of particles alone over each window
    /// ([`neurofluid_core::metrics::alone_share`] at [`ALONE_REACH_RADII`] radii).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub alone: Vec<WindowMean>,
    /// Per rollout and the truth, the mean kernel density relative to the truth's at the first
    /// test frame over each window ([`neurofluid_core::metrics::mean_density`]): a fluid that keeps
    /// its density stays near 1; below it, spread thinner than the truth.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub density: Vec<WindowMean>,
    /// Per rollout, where its far particles lie over each window
    /// ([`neurofluid_core::metrics::far_split`] at [`FAR_REACH_RADII`] radii).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub far: Vec<FarShare>,
}

/// How far (in particle radii) a particle's nearest other must be for it to count as alone:
/// a fluid packs its particles two radii apart; no particle of a honey's truth (built-in or the
/// bed's) is ever three radii from its nearest, and 1–2 % of a splashing water's are.
pub const ALONE_REACH_RADII: f64 = 3.0;

/// How far (in particle radii) a predicted particle's nearest true one must be for it to count
/// as far: two radii beyond the packing, so that a fluid merely shifted by a particle is not.
pub const FAR_REACH_RADII: f64 = 4.0;

/// Where a rollout's far particles lie ([`FarSplit`]), the mean over each window's frames.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct FarShare {
    /// The rollout's table label.
    pub model: String,
    /// Over the grounding window (fractions of all predicted particles, 0–1).
    pub grounding: FarSplit,
    /// Over the prediction window.
    pub prediction: FarSplit,
}

/// A per-frame statistic of one sequence (the share of its particles alone, its density
/// relative to the truth's first frame), the mean over each window's frames.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct WindowMean {
    /// The truth, or a rollout.
    pub model: Sequence,
    /// Over the grounding window.
    pub grounding: f64,
    /// Over the prediction window.
    pub prediction: f64,
}

/// The energy a sequence gains over the two windows, in J/kg: the sum of every step's gain
/// (steps t ≥ 2 of each window; a step that loses energy adds nothing), of the fluid's energy
/// and of each particle's ([`neurofluid_core::metrics::energy_gains`]).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct EnergyGain {
    /// The truth, or a rollout.
    pub model: Sequence,
    /// The fluid's, over the grounding window.
    pub grounding: f64,
    /// The fluid's, over the prediction window.
    pub prediction: f64,
    /// Each particle's (the mean of their gains), over the grounding window; 0 in reports
    /// written before it existed.
    #[serde(default)]
    pub grounding_per_particle: f64,
    /// Each particle's, over the prediction window.
    #[serde(default)]
    pub prediction_per_particle: f64,
}

/// NeuroFluid's DLF at one `diagnostics.weight_interpolation` fraction: `[d, d′]` averaged over each
/// window.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct InterpolationPoint {
    /// The fraction of grounding's change (0 = the pretrained DLF, 1 = the grounded one).
    pub fraction: f64,
    /// `[d, d′]` over the grounding window.
    pub grounding: [f64; 2],
    /// `[d, d′]` over the prediction window.
    pub prediction: [f64; 2],
}

/// The number of `points` farther than `margin` outside `interior` (on any axis).
pub fn count_outside(
    points: &[[f32; 3]],
    interior: &neurofluid_core::scene::Aabb,
    margin: f32,
) -> usize {
    points
        .iter()
        .filter(|&&p| !interior.within(p, margin))
        .count()
}

/// A physical scalar of DLF's step fitted by the images.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct FittedScalar {
    /// Its name (`gravity_scale`, `viscosity`, `dissipation`).
    pub name: String,
    /// The value fitted.
    pub value: f64,
    /// The value it started from (the run's `[dlf]` rules).
    pub from: f64,
    /// The bound it was stopped at (`"lower"` or `"upper"`), where the fit ended on one: the
    /// images asked for more than the bounds allow.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub at_bound: Option<String>,
}

/// A novel-view row's image metrics (NeRF, NeRF-T, the renderer on the true particles).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct BaselineScores {
    /// The model's name in tables.
    pub model: String,
    /// Image metrics per view and step.
    pub images: Vec<ImageScore>,
}

/// Mean PSNR, SSIM and LPIPS of the images with `a ≤ t ≤ b`.
pub fn image_means(images: &[ImageScore], (a, b): (usize, usize)) -> [Option<f64>; 3] {
    let inside = || images.iter().filter(|i| (a..=b).contains(&i.t));
    [
        mean(inside().map(|i| i.psnr)),
        mean(inside().map(|i| i.ssim)),
        mean(inside().filter_map(|i| i.lpips)),
    ]
}

/// The mean squared error of the renders of `images` in the window `[a, b]` split into its part
/// on the truth's fluid and its part around it (each a mean over the renders that have the
/// split, a perfect render counting 0 in both; `None` where none has it).
pub fn error_split(images: &[ImageScore], (a, b): (usize, usize)) -> Option<(f64, f64)> {
    let parts: Vec<(f64, f64)> = images
        .iter()
        .filter(|i| (a..=b).contains(&i.t))
        .filter_map(|i| {
            if i.psnr == f64::INFINITY {
                return Some((0.0, 0.0));
            }
            let mse = 10f64.powf(-i.psnr / 10.0);
            i.error_on_fluid.map(|s| (s * mse, (1.0 - s) * mse))
        })
        .collect();
    Some((
        mean(parts.iter().map(|p| p.0))?,
        mean(parts.iter().map(|p| p.1))?,
    ))
}

fn mean(values: impl Iterator<Item = f64>) -> Option<f64> {
    let (sum, n) = values.fold((0.0, 0usize), |(s, n), v| (s + v, n + 1));
    (n > 0).then(|| sum / n as f64)
}

fn fmt_opt(v: Option<f64>, digits: usize) -> String {
    v.map_or_else(|| "–".into(), |x| format!("{x:.digits$}"))
}

impl EvalReport {
    /// An empty report.
    pub fn new(experiment: &str, scene: &str, checkpoint: &str, windows: Windows) -> Self {
        Self {
            experiment: experiment.into(),
            scene: scene.into(),
            checkpoint: checkpoint.into(),
            initial_from_images: false,
            nvs_baselines: Vec::new(),
            scored_seal: None,
            weight_interpolation: None,
            dlf_rules: Vec::new(),
            fitted_physics: Vec::new(),
            gap: None,
            renderer: None,
            validation_views: false,
            interpolation: Vec::new(),
            energy: Vec::new(),
            alone: Vec::new(),
            density: Vec::new(),
            far: Vec::new(),
            windows,
            frames: Vec::new(),
            images: Vec::new(),
            escaped: Vec::new(),
        }
    }

    /// Means over the inclusive step window `(a, b)`.
    pub fn window_means(&self, (a, b): (usize, usize)) -> WindowMeans {
        let frames = || self.frames.iter().filter(|f| (a..=b).contains(&f.t));
        let images = || self.images.iter().filter(|i| (a..=b).contains(&i.t));
        let mut d = Rollouts::new();
        for label in self.rollout_labels() {
            if let Some(m) = mean(frames().filter_map(|f| f.d.get(&label).copied())) {
                d.set(&label, m);
            }
        }
        WindowMeans {
            d,
            psnr: mean(images().map(|i| i.psnr)),
            ssim: mean(images().map(|i| i.ssim)),
            lpips: mean(images().filter_map(|i| i.lpips)),
        }
    }

    /// The labels of the rollouts scored (d or d′) in any frame: those of [`Rollout::ALL`] in
    /// table order, then any other in the order first seen.
    pub fn rollout_labels(&self) -> Vec<String> {
        let mut labels: Vec<String> = Vec::new();
        for f in &self.frames {
            for (label, _) in f.d.iter().chain(f.reverse.iter()) {
                if !labels.iter().any(|l| l == label) {
                    labels.push(label.to_string());
                }
            }
        }
        let rank = |l: &String| Rollout::ALL.iter().position(|r| r.label() == l);
        labels.sort_by_key(|l| rank(l).unwrap_or(Rollout::ALL.len()));
        labels
    }

    /// The paper's Table 2 row of the rollout labelled `model` ([`Rollout`] or any label): `None`
    /// where it was not evaluated.
    pub fn distance_row(&self, model: impl AsRef<str>) -> Option<DistanceRow> {
        self.row_of(|f| f.d.get(&model).copied())
    }

    /// The Table 2 row of `model` in d′ (prediction → truth): `None` where it was not evaluated.
    pub fn reverse_row(&self, model: impl AsRef<str>) -> Option<DistanceRow> {
        self.row_of(|f| f.reverse.get(&model).copied())
    }

    /// The mean symmetric distance (d + d′)/2 of `model` over the grounding and the prediction
    /// window: `None` where it was not evaluated.
    pub fn symmetric_means(&self, model: impl AsRef<str>) -> [Option<f64>; 2] {
        let row = self.symmetric_row(model);
        [
            row.as_ref().and_then(|r| r.grounding_mean),
            row.and_then(|r| r.prediction_mean),
        ]
    }

    /// The symmetric distance (d + d′)/2 of `model`, frame by frame: `None` where d′ was not
    /// evaluated.
    pub fn symmetric_row(&self, model: impl AsRef<str>) -> Option<DistanceRow> {
        self.row_of(|f| Some(0.5 * (f.d.get(&model)? + f.reverse.get(&model)?)))
    }

    /// Window means and last frames of the per-frame values `of`.
    fn row_of(&self, of: impl Fn(&FrameDistance) -> Option<f64>) -> Option<DistanceRow> {
        let d = |t: usize| self.frames.iter().find(|f| f.t == t).and_then(&of);
        let window = |(a, b): (usize, usize)| {
            mean(
                self.frames
                    .iter()
                    .filter(|f| (a..=b).contains(&f.t))
                    .filter_map(&of),
            )
        };
        let (g, p) = (self.windows.grounding, self.windows.prediction);
        let row = DistanceRow {
            grounding_mean: window(g),
            grounding_last: d(g.1),
            prediction_mean: window(p),
            prediction_last: d(p.1),
        };
        self.frames.iter().any(|f| of(f).is_some()).then_some(row)
    }

    /// The summary: window means and per-view image means (views in first-seen order).
    pub fn summary(&self) -> Summary {
        let mut views: Vec<String> = Vec::new();
        for i in &self.images {
            if !views.contains(&i.view) {
                views.push(i.view.clone());
            }
        }
        let views = views
            .into_iter()
            .map(|v| {
                let of = || self.images.iter().filter(|i| i.view == v);
                ViewMeans {
                    psnr: mean(of().map(|i| i.psnr)).unwrap_or(f64::NAN),
                    ssim: mean(of().map(|i| i.ssim)).unwrap_or(f64::NAN),
                    lpips: mean(of().filter_map(|i| i.lpips)),
                    images: of().count(),
                    view: v,
                }
            })
            .collect();
        Summary {
            grounding: self.window_means(self.windows.grounding),
            prediction: self.window_means(self.windows.prediction),
            all: self.window_means((0, usize::MAX)),
            views,
        }
    }

    /// The markdown summary table (the table the trainer prints at the end).
    pub fn markdown(&self) -> String {
        let s = self.summary();
        let (g, p) = (self.windows.grounding, self.windows.prediction);
        let mut md = String::new();
        let _ = writeln!(
            md,
            "## Evaluation: {} ({}, {})\n",
            markdown_text(&self.experiment),
            markdown_text(&self.scene),
            markdown_text(&self.checkpoint)
        );
        let _ = writeln!(
            md,
            "| model | d_avg (t = {}–{}) | d (t = {}) | d_avg (t = {}–{}) | d (t = {}) | PSNR | SSIM | LPIPS |",
            g.0, g.1, g.1, p.0, p.1, p.1
        );
        let _ = writeln!(md, "|---|---:|---:|---:|---:|---:|---:|---:|");
        let from_images = self.initial_from_images;
        for model in self.rollout_labels() {
            let Some(row) = self.distance_row(&model) else {
                continue;
            };
            let (label, images) = match Rollout::of_label(&model) {
                Some(Rollout::Dlf) if from_images => {
                    ("DLF (pretrained, from the same particles)".into(), None)
                }
                Some(Rollout::Dlf) => ("DLF (pretrained baseline)".into(), None),
                Some(Rollout::PublishedDlf) => (
                    "DLF (pretrained, the paper's step: published, no rules)".into(),
                    None,
                ),
                Some(Rollout::SupervisedDlf) => {
                    ("DLF† (supervised on the training frames)".into(), None)
                }
                Some(Rollout::NeuroFluid) if from_images => (
                    "NeuroFluid, initial particles from images".into(),
                    Some(&s.all),
                ),
                Some(Rollout::NeuroFluid) => ("NeuroFluid".into(), Some(&s.all)),
                None => (markdown_text(&model), None),
            };
            let image = |f: fn(&WindowMeans) -> Option<f64>, digits| {
                images.map_or_else(|| "–".to_string(), |m| fmt_opt(f(m), digits))
            };
            let _ = writeln!(
                md,
                "| {label} | {} | {} | {} | {} | {} | {} | {} |",
                fmt_opt(row.grounding_mean, 2),
                fmt_opt(row.grounding_last, 2),
                fmt_opt(row.prediction_mean, 2),
                fmt_opt(row.prediction_last, 2),
                image(|m| m.psnr, 2),
                image(|m| m.ssim, 4),
                image(|m| m.lpips, 4),
            );
        }
        let _ = writeln!(
            md,
            "\nd = mean distance from each ground-truth particle to the nearest predicted one, × 1000 \
             (25 = one particle radius); PSNR/SSIM/LPIPS (AlexNet, v0.1) over the test views' \
             renders."
        );
        if !self.dlf_rules.is_empty() {
            let _ = writeln!(
                md,
                "\nEvery DLF rollout, the pretrained baseline's too, steps under {}.",
                self.dlf_rules.join(" and ")
            );
        }
        if !self.fitted_physics.is_empty() {
            let values: Vec<String> = self
                .fitted_physics
                .iter()
                .map(|f| {
                    let bound = f.at_bound.as_ref().map(|b| format!("; at its {b} bound"));
                    let bound = bound.unwrap_or_default();
                    format!("{} {:.4} (from {}{bound})", f.name, f.value, f.from)
                })
                .collect();
            let _ = writeln!(
                md,
                "\nNeuroFluid's DLF steps with the physical scalars the images fitted \
                 (`[joint.physics]`): {}.",
                values.join(", ")
            );
        }
        if let Some(gap) = &self.gap {
            let w = self.windows;
            let _ = writeln!(md, "\n{}", gap.markdown([w.grounding, w.prediction]));
        }
        if let Some(fraction) = self.weight_interpolation {
            let _ = writeln!(
                md,
                "\nNeuroFluid's DLF: the pretrained weights plus {fraction} of what grounding \
                 changed (`diagnostics.weight_interpolation`)."
            );
        }
        md.push_str(&self.reverse_markdown());
        md.push_str(&self.energy_markdown());
        md.push_str(&self.alone_markdown());
        md.push_str(&self.density_markdown());
        md.push_str(&self.far_markdown());
        if !self.escaped.is_empty() {
            let counts: Vec<String> = self
                .escaped
                .iter()
                .map(|(model, n)| format!("{} {n}", markdown_text(model)))
                .collect();
            let _ = writeln!(
                md,
                "\nParticles through the walls (the most at any step farther than one particle \
                 radius outside the box interior): {}.",
                counts.join(", ")
            );
        }
        // by window, and where the error is, whenever there is more than NeuroFluid's row of
        // Table 2 to say
        if !self.nvs_baselines.is_empty() || self.images.iter().any(|i| i.error_on_fluid.is_some())
        {
            md.push_str(&self.nvs_markdown());
        }
        if !self.interpolation.is_empty() {
            let _ = writeln!(
                md,
                "\nNeuroFluid's DLF from the pretrained weights (0) to the grounded ones (1) \
                 (`diagnostics.interpolation_sweep`; `interpolation.png`):\n\n\
                 | fraction | d_avg (t = {}–{}) | d′_avg | d_avg (t = {}–{}) | d′_avg |\n\
                 |---:|---:|---:|---:|---:|",
                g.0, g.1, p.0, p.1
            );
            for i in &self.interpolation {
                let _ = writeln!(
                    md,
                    "| {} | {:.2} | {:.2} | {:.2} | {:.2} |",
                    i.fraction, i.grounding[0], i.grounding[1], i.prediction[0], i.prediction[1]
                );
            }
        }
        if !s.views.is_empty() {
            let _ = writeln!(
                md,
                "\n| view | images | PSNR | SSIM | LPIPS |\n|---|---:|---:|---:|---:|"
            );
            for v in &s.views {
                let _ = writeln!(
                    md,
                    "| {} | {} | {:.2} | {:.4} | {} |",
                    markdown_text(&v.view),
                    v.images,
                    v.psnr,
                    v.ssim,
                    fmt_opt(v.lpips, 4)
                );
            }
        }
        md
    }

    /// The energy table, empty when no energy was evaluated.
    pub fn energy_markdown(&self) -> String {
        if self.energy.is_empty() {
            return String::new();
        }
        let (g, p) = (self.windows.grounding, self.windows.prediction);
        let (g0, p0) = (g.0.max(2), p.0);
        let mut md = format!(
            "\n| sequence | energy gained, t = {g0}–{} (J/kg) | t = {p0}–{} (J/kg) | per particle, \
             t = {g0}–{} | per particle, t = {p0}–{} |\n|---|---:|---:|---:|---:|\n",
            g.1, p.1, g.1, p.1
        );
        for e in &self.energy {
            let _ = writeln!(
                md,
                "| {} | {:.3} | {:.3} | {:.3} | {:.3} |",
                e.model,
                e.grounding,
                e.prediction,
                e.grounding_per_particle,
                e.prediction_per_particle
            );
        }
        md.push_str(
            "\nEnergy gained: the sum over frames of each frame's gain in mechanical energy per \
             kilogram (½|v|² + g·height, v from consecutive positions), a loss counting 0; per \
             particle, the mean of each particle's own gains. A fluid in a closed box only loses \
             energy; a rollout that gains it throws fluid where the truth has none \
             (`joint.terms.energy` penalises it; `dlf.energy_cap = \"particle\"` stops each \
             particle's, which in a viscous fluid none gains).\n",
        );
        md
    }

    /// The table of densities, empty when they were not evaluated.
    pub fn density_markdown(&self) -> String {
        if self.density.is_empty() {
            return String::new();
        }
        let (g, p) = (self.windows.grounding, self.windows.prediction);
        let mut md = format!(
            "\n| sequence | density / first frame's, t = {}–{} | t = {}–{} |\n|---|---:|---:|\n",
            g.0, g.1, p.0, p.1
        );
        for a in &self.density {
            let _ = writeln!(
                md,
                "| {} | {:.3} | {:.3} |",
                a.model, a.grounding, a.prediction
            );
        }
        let _ = writeln!(
            md,
            "\nDensity: each particle's kernel density within {} radii, the fluid's mean, \
             relative to the truth's at the first test frame, the mean over the window's \
             frames. A viscous truth keeps it near 1; a rollout below its truth has spread its \
             particles thinner (fluid beside the truth, which d′ counts), above it pressed them.",
            neurofluid_core::metrics::SUPPORT_RADII
        );
        md
    }

    /// The table of particles alone, empty when they were not evaluated.
    pub fn alone_markdown(&self) -> String {
        if self.alone.is_empty() {
            return String::new();
        }
        let (g, p) = (self.windows.grounding, self.windows.prediction);
        let mut md = format!(
            "\n| sequence | particles alone, t = {}–{} | t = {}–{} |\n|---|---:|---:|\n",
            g.0, g.1, p.0, p.1
        );
        for a in &self.alone {
            let _ = writeln!(
                md,
                "| {} | {:.2} % | {:.2} % |",
                a.model,
                100.0 * a.grounding,
                100.0 * a.prediction
            );
        }
        let _ = writeln!(
            md,
            "\nParticles alone: the share with no other particle within {ALONE_REACH_RADII} \
             radii (a fluid packs them two radii apart), the mean over the window's frames: \
             spray, which d′ mixes with fluid put in the wrong place. A viscous fluid's truth \
             has none; a splashing water's has droplets of its own."
        );
        md
    }

    /// The table of where the rollouts' far particles lie, empty when not evaluated.
    pub fn far_markdown(&self) -> String {
        if self.far.is_empty() {
            return String::new();
        }
        let (g, p) = (self.windows.grounding, self.windows.prediction);
        let mut md = format!(
            "\n| rollout | far, t = {}–{} | beside | above | within | far, t = {}–{} | beside | \
             above | within |\n|---|---:|---:|---:|---:|---:|---:|---:|---:|\n",
            g.0, g.1, p.0, p.1
        );
        for f in &self.far {
            let _ = write!(md, "| {} |", markdown_text(&f.model));
            for s in [f.grounding, f.prediction] {
                for share in [s.total(), s.beside, s.above, s.within] {
                    let _ = write!(md, " {:.1} % |", 100.0 * share);
                }
            }
            md.push('\n');
        }
        let _ = writeln!(
            md,
            "\nFar particles: the predicted particles more than {FAR_REACH_RADII} radii from \
             every true one (most of what d′ counts), by where they lie: beside the truth (no \
             true particle within {FAR_REACH_RADII} radii horizontally: spread or thrown past \
             it), above it (higher than every true particle within that reach: held up or \
             thrown over it) or within its column (in its gaps or under it); the mean over the \
             window's frames."
        );
        md
    }

    /// The d′ table (prediction → truth), empty when no d′ was evaluated.
    pub fn reverse_markdown(&self) -> String {
        let rows: Vec<(String, DistanceRow)> = self
            .rollout_labels()
            .into_iter()
            .filter_map(|m| self.reverse_row(&m).map(|r| (m, r)))
            .collect();
        if rows.is_empty() {
            return String::new();
        }
        let (g, p) = (self.windows.grounding, self.windows.prediction);
        let mut md = format!(
            "\n| model | d′_avg (t = {}–{}) | d′ (t = {}) | d′_avg (t = {}–{}) | d′ (t = {}) | (d + d′)/2 avg (t = {}–{}) | (d + d′)/2 avg (t = {}–{}) |\n|---|---:|---:|---:|---:|---:|---:|\n",
            g.0, g.1, g.1, p.0, p.1, p.1, g.0, g.1, p.0, p.1
        );
        for (model, row) in rows {
            let both = self.symmetric_row(&model);
            let _ = writeln!(
                md,
                "| {} | {} | {} | {} | {} | {} | {} |",
                markdown_text(&model),
                fmt_opt(row.grounding_mean, 2),
                fmt_opt(row.grounding_last, 2),
                fmt_opt(row.prediction_mean, 2),
                fmt_opt(row.prediction_last, 2),
                fmt_opt(both.as_ref().and_then(|b| b.grounding_mean), 2),
                fmt_opt(both.as_ref().and_then(|b| b.prediction_mean), 2),
            );
        }
        md.push_str(
            "\nd′ = the other way: mean distance from each predicted particle to the nearest true \
             one, × 1000 (a diagnostic, not the paper's metric): large where a prediction puts \
             particles where the truth has none, which d does not see. (d + d′)/2 weighs both: \
             missing fluid and spray.\n",
        );
        md
    }

    /// The novel-view table (the paper's Tables 3–4): PSNR, SSIM and LPIPS over the observed
    /// frames and over the predicted ones, for NeuroFluid and every other row (the baselines, the
    /// renderer on the true particles).
    pub fn nvs_markdown(&self) -> String {
        let (g, p) = (self.windows.grounding, self.windows.prediction);
        let seen = (0, g.1);
        let mut md = String::new();
        let _ = writeln!(
            md,
            "\n### Novel views{}\n\n| model | PSNR t = {}–{} | SSIM | LPIPS | PSNR t = {}–{} | SSIM | LPIPS |\n|---|---:|---:|---:|---:|---:|---:|",
            if self.validation_views {
                ": the validation views (kept aside to choose settings with; not the test views)"
            } else {
                ""
            },
            seen.0,
            seen.1,
            p.0,
            p.1
        );
        let mut rows = vec![("NeuroFluid", &self.images)];
        rows.extend(
            self.nvs_baselines
                .iter()
                .map(|b| (b.model.as_str(), &b.images)),
        );
        for (model, images) in &rows {
            let [a, b] = [seen, p].map(|w| image_means(images, w));
            let _ = writeln!(
                md,
                "| {} | {} | {} | {} | {} | {} | {} |",
                markdown_text(model),
                fmt_opt(a[0], 2),
                fmt_opt(a[1], 4),
                fmt_opt(a[2], 4),
                fmt_opt(b[0], 2),
                fmt_opt(b[1], 4),
                fmt_opt(b[2], 4)
            );
        }
        let splits: Vec<_> = rows
            .iter()
            .map(|(model, images)| (model, [seen, p].map(|w| error_split(images, w))))
            .filter(|(_, s)| s.iter().any(Option::is_some))
            .collect();
        if !splits.is_empty() {
            let _ = writeln!(
                md,
                "\n| model | MSE on the fluid, t = {}–{} | around it | MSE on the fluid, t = {}–{} | around it |\n|---|---:|---:|---:|---:|",
                seen.0, seen.1, p.0, p.1
            );
            for (model, windows) in splits {
                let cells = windows.map(|w| match w {
                    Some((on, around)) => format!("{:.2} | {:.2}", 1e3 * on, 1e3 * around),
                    None => "– | –".into(),
                });
                let _ = writeln!(
                    md,
                    "| {} | {} | {} |",
                    markdown_text(model),
                    cells[0],
                    cells[1]
                );
            }
            let _ = writeln!(
                md,
                "\nWhere the renders' error is (MSE ×10⁻³; the two add up to the mean MSE of the \
                 window's renders, not to the mean PSNR's): on the pixels where the truth shows \
                 fluid (its alpha ≥ ½: the fluid's colour, or fluid missing) and around it (fluid \
                 drawn where the truth has none, halos, floaters)."
            );
        }
        if let Some(renderer) = &self.renderer {
            let _ = writeln!(
                md,
                "\nNeuroFluid's views and the renderer on the true particles: {renderer}."
            );
        }
        md
    }

    /// The per-frame CSV: `t,neurofluid_d,dlf_d,<view>_psnr,<view>_ssim,<view>_lpips,…`.
    pub fn frames_csv(&self) -> String {
        let views: Vec<String> = self.summary().views.into_iter().map(|v| v.view).collect();
        let mut ts: Vec<usize> = self
            .frames
            .iter()
            .map(|f| f.t)
            .chain(self.images.iter().map(|i| i.t))
            .collect();
        ts.sort_unstable();
        ts.dedup();
        // a column per model's d, then per model's d′, whether or not it was evaluated
        let models = Rollout::FILE_ORDER;
        let mut header = vec!["t".to_string()];
        header.extend(models.map(|m| format!("{}_d", m.key())));
        header.extend(models.map(|m| format!("{}_d_rev", m.key())));
        for v in &views {
            header.extend([
                format!("{v}_psnr"),
                format!("{v}_ssim"),
                format!("{v}_lpips"),
            ]);
        }
        let rows = ts.into_iter().map(|t| {
            let f = self.frames.iter().find(|f| f.t == t);
            let mut row = vec![t.to_string()];
            row.extend(models.map(|m| cell(f.and_then(|f| m.of(f)))));
            row.extend(models.map(|m| cell(f.and_then(|f| m.reverse_of(f)))));
            for v in &views {
                let i = self.images.iter().find(|i| i.t == t && &i.view == v);
                row.extend([
                    cell(i.map(|i| i.psnr)),
                    cell(i.map(|i| i.ssim)),
                    cell(i.and_then(|i| i.lpips)),
                ]);
            }
            row
        });
        csv_text(std::iter::once(header).chain(rows))
    }

    /// The JSON document: the report plus its summary.
    pub fn to_json(&self) -> String {
        #[derive(Serialize)]
        struct Doc<'a> {
            #[serde(flatten)]
            report: &'a EvalReport,
            summary: Summary,
        }
        serde_json::to_string_pretty(&Doc {
            report: self,
            summary: self.summary(),
        })
        .expect("report serialises")
    }

    /// Writes `report.json`, `frames.csv` and `report.md` into `dir` (atomically each).
    pub fn write_all(&self, dir: &Path) -> Result<(), ReportError> {
        write_atomic(&dir.join(JSON_FILE), &self.to_json())?;
        write_atomic(&dir.join(FRAMES_CSV_FILE), &self.frames_csv())?;
        write_atomic(&dir.join(MARKDOWN_FILE), &self.markdown())
    }

    /// Reads a `report.json` written by [`EvalReport::write_all`].
    pub fn read_json(path: &Path) -> Result<Self, ReportError> {
        let text =
            neurofluid_core::input_file::read_string(path).map_err(|source| ReportError::Io {
                path: path.to_path_buf(),
                source,
            })?;
        serde_json::from_str(&text).map_err(|e| ReportError::Parse {
            path: path.to_path_buf(),
            message: e.to_string(),
        })
    }
}

/// Writes `text` to `path` atomically.
pub(crate) fn write_atomic(path: &Path, text: &str) -> Result<(), ReportError> {
    neurofluid_core::atomic::write_bytes(path, text.as_bytes()).map_err(|source| ReportError::Io {
        path: path.to_path_buf(),
        source,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use neurofluid_core::metrics::gt_to_pred_distance;

    /// A report whose d values come from the core metric on known point sets: the prediction is
    /// the GT shifted by δ(t) along x (farther than the GT spacing is not reached), so d = δ·1000.
    fn sample_report() -> EvalReport {
        let gt: Vec<[f32; 3]> = (0..20).map(|i| [i as f32, 0.0, 0.0]).collect();
        let shifted = |d: f32| {
            gt.iter()
                .map(|p| [p[0] + d, p[1], p[2]])
                .collect::<Vec<_>>()
        };
        let mut r = EvalReport::new("quick", "watercube", "joint step 98", Windows::paper());
        for t in 1..=59 {
            let nf = gt_to_pred_distance(&gt, &shifted(0.001 * t as f32)).mean;
            let dlf = gt_to_pred_distance(&gt, &shifted(0.002 * t as f32)).mean;
            // d′ of NeuroFluid: from the shifted set back to the GT
            let nf_rev = gt_to_pred_distance(&shifted(0.001 * t as f32), &gt).mean;
            r.frames.push(FrameDistance {
                t,
                d: Rollouts::new()
                    .with(Rollout::NeuroFluid, Some(nf))
                    .with(Rollout::Dlf, Some(dlf)),
                reverse: Rollouts::new().with(Rollout::NeuroFluid, Some(nf_rev)),
            });
            for view in ["view_5", "view_6"] {
                let bonus = if view == "view_6" { 1.0 } else { 0.0 };
                r.images.push(ImageScore {
                    view: view.into(),
                    t,
                    psnr: 20.0 + bonus + t as f64 * 0.1,
                    ssim: 0.9,
                    lpips: (view == "view_5").then_some(0.1),
                    error_on_fluid: Some(if t < 50 { 0.25 } else { 0.75 }),
                });
            }
        }
        r
    }

    /// Scene, experiment and view names reach `report.md` as text: no markup, no extra rows
    /// (issue 72: `<script>` went in raw, and a name with a newline added a results row).
    #[test]
    fn names_in_the_markdown_are_text() {
        let mut r = sample_report();
        r.scene = "<script>alert(1)</script>".into();
        r.experiment = "e\n| NeuroFluid | 0.00 | 0 | 0 | 0 | 99 | 1 | 0 |".into();
        for i in &mut r.images {
            if i.view == "view_6" {
                i.view = "<svg onload=alert(1)>\n| fake |".into();
            }
        }
        let md = r.markdown();
        assert!(!md.contains("<script") && !md.contains("<svg"), "{md}");
        let table_rows = |md: &str| {
            md.lines()
                .filter(|l| l.starts_with("| NeuroFluid |"))
                .count()
        };
        assert_eq!(
            table_rows(&md),
            table_rows(&sample_report().markdown()),
            "{md}"
        );
        assert!(!md.lines().any(|l| l.starts_with("| fake")), "{md}");
    }

    #[test]
    fn window_means_follow_the_papers_windows() {
        let r = sample_report();
        let s = r.summary();
        // NeuroFluid d(t) = t (×1e-3 m × 1000): mean of 1..=49 is 25, of 50..=59 is 54.5
        assert!((s.grounding.d_of(Rollout::NeuroFluid).unwrap() - 25.0).abs() < 5e-3);
        assert!((s.prediction.d_of(Rollout::NeuroFluid).unwrap() - 54.5).abs() < 5e-3);
        assert!((s.grounding.d_of(Rollout::Dlf).unwrap() - 50.0).abs() < 5e-3);
        assert!((s.prediction.d_of(Rollout::Dlf).unwrap() - 109.0).abs() < 5e-3);
        // PSNR over both views: 20.5 + 0.1·t
        assert!((s.grounding.psnr.unwrap() - (20.5 + 2.5)).abs() < 1e-9);
        assert_eq!(s.views.len(), 2);
        assert_eq!(s.views[0].view, "view_5");
        assert_eq!(s.views[1].images, 59);
        // LPIPS where it was computed
        assert!((s.all.lpips.unwrap() - 0.1).abs() < 1e-12);
        assert!((s.views[0].lpips.unwrap() - 0.1).abs() < 1e-12);
        assert_eq!(s.views[1].lpips, None);
        assert!((s.views[1].psnr - s.views[0].psnr - 1.0).abs() < 1e-9);
        assert_eq!(Windows::from_lengths(50, 60), Windows::paper());
        assert_eq!(
            Windows::from_lengths(4, 6),
            Windows {
                grounding: (1, 3),
                prediction: (4, 5)
            }
        );
        let empty = EvalReport::new("e", "s", "c", Windows::paper()).summary();
        assert_eq!(empty.grounding.d_of(Rollout::NeuroFluid), None);
    }

    #[test]
    fn table2_rows_hold_window_means_and_last_frames() {
        let mut r = sample_report();
        assert_eq!(r.distance_row(Rollout::SupervisedDlf), None);
        // DLF† d(t) = 0.5·t, read back from the core metric as the others
        let gt: Vec<[f32; 3]> = (0..20).map(|i| [i as f32, 0.0, 0.0]).collect();
        for f in &mut r.frames {
            let shifted: Vec<[f32; 3]> = gt
                .iter()
                .map(|p| [p[0] + 0.0005 * f.t as f32, p[1], p[2]])
                .collect();
            f.d.set(
                Rollout::SupervisedDlf,
                gt_to_pred_distance(&gt, &shifted).mean,
            );
        }
        let close = |a: Option<f64>, b: f64| (a.unwrap() - b).abs() < 5e-3;
        let row = r.distance_row(Rollout::SupervisedDlf).unwrap();
        assert!(close(row.grounding_mean, 12.5), "{row:?}");
        assert!(close(row.grounding_last, 24.5), "{row:?}");
        assert!(close(row.prediction_mean, 27.25), "{row:?}");
        assert!(close(row.prediction_last, 29.5), "{row:?}");
        let nf = r.distance_row(Rollout::NeuroFluid).unwrap();
        assert!(close(nf.grounding_last, 49.0) && close(nf.prediction_last, 59.0));
        assert!(close(
            r.summary().grounding.d_of(Rollout::SupervisedDlf),
            12.5
        ));
        let md = r.markdown();
        let rows: Vec<&str> = md
            .lines()
            .filter(|l| l.starts_with("| D") || l.starts_with("| N"))
            .collect();
        assert!(rows[0].starts_with("| DLF (pretrained"), "{md}");
        assert!(
            rows[1].starts_with(
                "| DLF† (supervised on the training frames) | 12.50 | 24.50 | 27.25 | 29.50 | – |"
            ),
            "{md}"
        );
        assert!(rows[2].starts_with("| NeuroFluid |"), "{md}");
        let csv = r.frames_csv();
        let second: Vec<&str> = csv.lines().nth(2).unwrap().split(',').collect();
        assert!(
            (second[3].parse::<f64>().unwrap() - 1.0).abs() < 1e-3,
            "{second:?}"
        );
    }

    /// The energy table lists each sequence's gains in both windows, and a report without them
    /// (written before the energy existed) has none.
    #[test]
    fn energy_table_lists_each_sequence() {
        let mut r = sample_report();
        assert!(!r.markdown().contains("energy gained"));
        r.energy = vec![
            EnergyGain {
                model: Sequence::Truth,
                grounding: 0.0,
                prediction: 0.0,
                grounding_per_particle: 0.0,
                prediction_per_particle: 0.0,
            },
            EnergyGain {
                model: Sequence::Rollout("NeuroFluid".into()),
                grounding: 0.588,
                prediction: 0.0123,
                grounding_per_particle: 1.78,
                prediction_per_particle: 0.25,
            },
        ];
        let md = r.markdown();
        assert!(md.contains("energy gained, t = 2–"), "{md}");
        assert!(
            md.contains("| truth | 0.000 | 0.000 | 0.000 | 0.000 |"),
            "{md}"
        );
        assert!(
            md.contains("| NeuroFluid | 0.588 | 0.012 | 1.780 | 0.250 |"),
            "{md}"
        );
        let back: EvalReport = serde_json::from_str(&serde_json::to_string(&r).unwrap()).unwrap();
        assert_eq!(back.energy, r.energy);
        // a report written before the per-particle gains existed reads them as 0
        let old = r#"{"model":"DLF","grounding":0.5,"prediction":0.25}"#;
        let e: EnergyGain = serde_json::from_str(old).unwrap();
        assert_eq!((e.grounding, e.grounding_per_particle), (0.5, 0.0));
    }

    /// The table of particles alone lists each sequence in percent, and a report without it
    /// (written before it existed) still reads.
    #[test]
    fn a_fitted_scalar_at_its_bound_is_said_to_be() {
        let mut r = sample_report();
        r.fitted_physics = vec![
            FittedScalar {
                name: "viscosity".into(),
                value: 0.0,
                from: 0.0,
                at_bound: Some("lower".into()),
            },
            FittedScalar {
                name: "dissipation".into(),
                value: 0.1752,
                from: 0.0,
                at_bound: None,
            },
        ];
        let md = r.markdown();
        assert!(
            md.contains(
                "viscosity 0.0000 (from 0; at its lower bound), dissipation 0.1752 (from 0)"
            ),
            "{md}"
        );
        let back: EvalReport = serde_json::from_str(&serde_json::to_string(&r).unwrap()).unwrap();
        assert_eq!(back.fitted_physics, r.fitted_physics);
    }

    #[test]
    fn the_published_dlf_row_sits_beside_the_dlf_under_rules_and_survives_the_file() {
        let mut r = sample_report();
        assert!(!r.markdown().contains("the paper's step"));
        for f in &mut r.frames {
            let d = f.t as f64 * 3.0;
            f.d.set(Rollout::PublishedDlf, d);
            f.reverse.set(Rollout::PublishedDlf, d + 1.0);
        }
        let md = r.markdown();
        let row = md
            .lines()
            .position(|l| l.starts_with("| DLF (pretrained, the paper's step"))
            .expect("the published DLF's row");
        let dlf = md
            .lines()
            .position(|l| l.starts_with("| DLF (pretrained baseline)"));
        assert_eq!(dlf.map(|k| k + 1), Some(row), "{md}");
        let back: EvalReport = serde_json::from_str(&serde_json::to_string(&r).unwrap()).unwrap();
        assert_eq!(back.frames, r.frames);
        let s = back.summary();
        assert_eq!(
            s.grounding.d_of(Rollout::PublishedDlf),
            r.summary().grounding.d_of(Rollout::PublishedDlf)
        );
        assert!(s.grounding.d_of(Rollout::PublishedDlf).is_some());
    }

    #[test]
    fn alone_table_lists_each_sequence() {
        let mut r = sample_report();
        assert!(!r.markdown().contains("particles alone"));
        r.alone = vec![
            WindowMean {
                model: Sequence::Truth,
                grounding: 0.0,
                prediction: 0.0,
            },
            WindowMean {
                model: Sequence::Rollout("NeuroFluid".into()),
                grounding: 0.0125,
                prediction: 0.034_81,
            },
        ];
        let md = r.markdown();
        assert!(
            md.contains("| sequence | particles alone, t = 1–49 | t = 50–59 |"),
            "{md}"
        );
        assert!(md.contains("| truth | 0.00 % | 0.00 % |"), "{md}");
        assert!(md.contains("| NeuroFluid | 1.25 % | 3.48 % |"), "{md}");
        let back: EvalReport = serde_json::from_str(&serde_json::to_string(&r).unwrap()).unwrap();
        assert_eq!(back.alone, r.alone);
        let mut old = serde_json::to_value(&r).unwrap();
        old.as_object_mut().unwrap().remove("alone");
        let back: EvalReport = serde_json::from_value(old).unwrap();
        assert!(back.alone.is_empty());
    }

    /// The density table lists each sequence's ratio per window, and a report without it
    /// (written before it existed) still reads.
    #[test]
    fn density_table_lists_each_sequence() {
        let mut r = sample_report();
        assert!(!r.markdown().contains("density / first frame's"));
        r.density = vec![
            WindowMean {
                model: Sequence::Truth,
                grounding: 1.054,
                prediction: 1.071,
            },
            WindowMean {
                model: Sequence::Rollout("NeuroFluid".into()),
                grounding: 0.8412,
                prediction: 0.9,
            },
        ];
        let md = r.markdown();
        assert!(
            md.contains("| sequence | density / first frame's, t = 1–49 | t = 50–59 |"),
            "{md}"
        );
        assert!(md.contains("| truth | 1.054 | 1.071 |"), "{md}");
        assert!(md.contains("| NeuroFluid | 0.841 | 0.900 |"), "{md}");
        let back: EvalReport = serde_json::from_str(&serde_json::to_string(&r).unwrap()).unwrap();
        assert_eq!(back.density, r.density);
        let mut old = serde_json::to_value(&r).unwrap();
        old.as_object_mut().unwrap().remove("density");
        let back: EvalReport = serde_json::from_value(old).unwrap();
        assert!(back.density.is_empty());
    }

    /// The far table gives each rollout's shares in percent, both windows, and a report without
    /// it reads.
    #[test]
    fn far_table_lists_each_rollout() {
        let mut r = sample_report();
        assert!(!r.markdown().contains("| rollout | far"));
        let split = |beside, above, within| FarSplit {
            beside,
            above,
            within,
        };
        r.far = vec![FarShare {
            model: "NeuroFluid".into(),
            grounding: split(0.1, 0.02, 0.003),
            prediction: split(0.2, 0.0, 0.05),
        }];
        let md = r.markdown();
        assert!(
            md.contains(
                "| NeuroFluid | 12.3 % | 10.0 % | 2.0 % | 0.3 % | 25.0 % | 20.0 % | 0.0 % | 5.0 % |"
            ),
            "{md}"
        );
        let json = serde_json::to_value(&r).unwrap();
        let back: EvalReport = serde_json::from_value(json.clone()).unwrap();
        assert_eq!(back.far, r.far);
        let mut old = json;
        old.as_object_mut().unwrap().remove("far");
        let back: EvalReport = serde_json::from_value(old).unwrap();
        assert!(back.far.is_empty());
    }

    /// Particles where the truth has none (spray above the fluid) leave d at zero and show in d′.
    #[test]
    fn reverse_d_sees_what_d_misses() {
        let gt: Vec<[f32; 3]> = (0..20).map(|i| [i as f32, 0.0, 0.0]).collect();
        let mut pred = gt.clone();
        pred.extend(gt.iter().map(|p| [p[0], 1.0, 0.0]));
        let mut r = EvalReport::new("spray", "s", "c", Windows::from_lengths(4, 6));
        for t in 1..=5 {
            r.frames.push(FrameDistance {
                t,
                d: Rollouts::new()
                    .with(
                        Rollout::NeuroFluid,
                        Some(gt_to_pred_distance(&gt, &pred).mean),
                    )
                    .with(Rollout::Dlf, Some(gt_to_pred_distance(&gt, &gt).mean)),
                reverse: Rollouts::new()
                    .with(
                        Rollout::NeuroFluid,
                        Some(gt_to_pred_distance(&pred, &gt).mean),
                    )
                    .with(Rollout::Dlf, Some(gt_to_pred_distance(&gt, &gt).mean)),
            });
        }
        let d = r.distance_row(Rollout::NeuroFluid).unwrap();
        let rev = r.reverse_row(Rollout::NeuroFluid).unwrap();
        assert_eq!(d.grounding_mean, Some(0.0));
        assert!(
            (rev.grounding_mean.unwrap() - 500.0).abs() < 1e-3,
            "{rev:?}"
        );
        assert!(
            (rev.prediction_last.unwrap() - 500.0).abs() < 1e-3,
            "{rev:?}"
        );
        assert_eq!(r.reverse_row(Rollout::SupervisedDlf), None);
        // (d + d′)/2: half of the spray's 500
        let both = r.symmetric_row(Rollout::NeuroFluid).unwrap();
        assert!(
            (both.prediction_mean.unwrap() - 250.0).abs() < 1e-3,
            "{both:?}"
        );
        assert_eq!(r.symmetric_row(Rollout::SupervisedDlf), None);
        let md = r.markdown();
        assert!(
            md.contains("| NeuroFluid | 500.00 | 500.00 | 500.00 | 500.00 | 250.00 | 250.00 |"),
            "{md}"
        );
        assert!(
            md.contains("| DLF | 0.00 | 0.00 | 0.00 | 0.00 | 0.00 | 0.00 |"),
            "{md}"
        );
        // a report written before d′ existed has no d′ table
        assert!(
            !sample_report_without_reverse()
                .markdown()
                .contains("d′_avg")
        );
    }

    /// Particles beyond one radius outside the box count, on every side; those within it do
    /// not; the report says how many each rollout lost through the walls.
    #[test]
    fn particles_through_the_walls_are_counted_and_reported() {
        let interior = neurofluid_core::scene::Aabb {
            min: [0.0; 3],
            max: [1.0, 2.0, 1.0],
        };
        let points = [
            [0.5, 1.0, 0.5],   // inside
            [0.5, -0.02, 0.5], // within a radius of the floor
            [0.5, -0.2, 0.5],  // below the floor
            [1.3, 1.0, 0.5],   // through a side wall
            [0.5, 2.5, -0.4],  // above and beside
        ];
        assert_eq!(count_outside(&points, &interior, 0.025), 3);
        assert_eq!(count_outside(&points[..2], &interior, 0.025), 0);
        let mut r = sample_report();
        assert!(!r.markdown().contains("through the walls"));
        r.escaped = vec![("DLF".into(), 1), ("NeuroFluid".into(), 0)];
        let md = r.markdown();
        assert!(
            md.contains("outside the box interior): DLF 1, NeuroFluid 0."),
            "{md}"
        );
        let back: EvalReport = serde_json::from_str(&serde_json::to_string(&r).unwrap()).unwrap();
        assert_eq!(back.escaped, r.escaped);
    }

    /// The rules DLF stepped under are named under the table, from the run's `[dlf]`, and a
    /// report written before them reads as one without.
    #[test]
    fn the_rules_of_every_dlf_rollout_are_named() {
        let mut r = sample_report();
        assert!(!r.markdown().contains("steps under"));
        // as `[dlf]` names them (the trainer's `DlfSection::rules`)
        r.dlf_rules = vec![
            "the walls (`dlf.containment = \"box\"`)".into(),
            "the energy cap (`dlf.energy_cap = \"particle\"`)".into(),
        ];
        let md = r.markdown();
        assert!(
            md.contains(
                "pretrained baseline's too, steps under the walls (`dlf.containment = \"box\"`) \
                 and the energy cap (`dlf.energy_cap = \"particle\"`)."
            ),
            "{md}"
        );
        let mut old = serde_json::to_value(sample_report()).unwrap();
        old.as_object_mut().unwrap().remove("dlf_rules");
        let back: EvalReport = serde_json::from_value(old).unwrap();
        assert!(back.dlf_rules.is_empty());
    }

    fn sample_report_without_reverse() -> EvalReport {
        let mut r = sample_report();
        for f in &mut r.frames {
            f.reverse = Rollouts::new();
        }
        r
    }

    #[test]
    fn writers_produce_json_csv_and_markdown() {
        let dir = tempfile::tempdir().unwrap();
        let r = sample_report();
        r.write_all(dir.path()).unwrap();
        let back = EvalReport::read_json(&dir.path().join(JSON_FILE)).unwrap();
        assert_eq!(back, r);
        let json: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(dir.path().join(JSON_FILE)).unwrap())
                .unwrap();
        assert!(
            (json["summary"]["grounding"]["neurofluid_d"]
                .as_f64()
                .unwrap()
                - 25.0)
                .abs()
                < 5e-3
        );
        let csv = std::fs::read_to_string(dir.path().join(FRAMES_CSV_FILE)).unwrap();
        let lines: Vec<&str> = csv.lines().collect();
        assert_eq!(
            lines[0],
            "t,neurofluid_d,dlf_d,supervised_dlf_d,published_dlf_d,neurofluid_d_rev,dlf_d_rev,\
             supervised_dlf_d_rev,published_dlf_d_rev,\
             view_5_psnr,view_5_ssim,view_5_lpips,view_6_psnr,view_6_ssim,view_6_lpips"
        );
        assert_eq!(lines.len(), 60);
        let cells: Vec<&str> = lines[1].split(',').collect();
        assert_eq!(cells[0], "1");
        assert!((cells[1].parse::<f64>().unwrap() - 1.0).abs() < 1e-3);
        let md = std::fs::read_to_string(dir.path().join(MARKDOWN_FILE)).unwrap();
        // Table 2: DLF d(t) = 2t: mean 50 over 1..=49, 98 at 49, 109 over 50..=59, 118 at 59
        assert!(
            md.contains("| DLF (pretrained baseline) | 50.00 | 98.00 | 109.00 | 118.00 | – |"),
            "{md}"
        );
        assert!(
            md.contains("| NeuroFluid | 25.00 | 49.00 | 54.50 | 59.00 | 23.50 |"),
            "{md}"
        );
        assert!(!md.contains("DLF†"), "{md}");
        assert!(md.contains("d_avg (t = 1–49) | d (t = 49) | d_avg (t = 50–59) | d (t = 59)"));
        assert!(md.contains("| view_6 | 59 |"));
        // PSNR 20 + 0.1 t dB on view_5 and 1 dB more on view_6: at t = 10 MSEs 10^-2.1, 10^-2.2
        let split = error_split(&r.images, (10, 10)).unwrap();
        let mse = [10f64.powf(-2.1), 10f64.powf(-2.2)];
        assert!((split.0 - 0.25 * (mse[0] + mse[1]) / 2.0).abs() < 1e-12);
        assert!((split.1 - 0.75 * (mse[0] + mse[1]) / 2.0).abs() < 1e-12);
        let late = error_split(&r.images, (59, 59)).unwrap();
        let mse = [10f64.powf(-2.59), 10f64.powf(-2.69)];
        assert!((late.0 - 0.75 * (mse[0] + mse[1]) / 2.0).abs() < 1e-12);
        assert!(
            md.contains("### Novel views"),
            "the split is reported without baselines"
        );
        let nvs = r.nvs_markdown();
        let (early, late) = (
            error_split(&r.images, (0, 49)).unwrap(),
            error_split(&r.images, (50, 59)).unwrap(),
        );
        let row = format!(
            "| NeuroFluid | {:.2} | {:.2} | {:.2} | {:.2} |",
            1e3 * early.0,
            1e3 * early.1,
            1e3 * late.0,
            1e3 * late.1
        );
        assert!(nvs.contains("MSE on the fluid, t = 0–49"), "{nvs}");
        assert!(nvs.contains(&row), "{row} in {nvs}");
        assert_eq!(error_split(&[], (0, 49)), None);
        let perfect = ImageScore {
            psnr: f64::INFINITY,
            error_on_fluid: None,
            ..r.images[0].clone()
        };
        assert_eq!(error_split(&[perfect], (0, 59)), Some((0.0, 0.0)));
        assert!(EvalReport::read_json(&dir.path().join("nope.json")).is_err());
        // a report written before the error's share was scored still loads, without it
        let old: ImageScore =
            serde_json::from_str(r#"{"view":"view_5","t":3,"psnr":20.0,"ssim":0.5}"#).unwrap();
        assert_eq!(old.error_on_fluid, None);
    }
}
