//! What supervised training of DLF needs from the model side (docs/spec/dlf.md §5): training
//! sequences (from DLF records or scenes), the 2-step unrolled loss of one sample with γ = 0.5
//! and exp(−n/40) weighting, rotations about the gravity axis, and DLF's validation errors
//! (err_n1, err_n2, whole-sequence nearest-neighbour error), and DLF's learning-rate schedule
//! ([`lr_schedule`]). The loop itself (Adam, batches, checkpoints) is a trainer stage of
//! `neurofluid-train`.

use std::path::Path;

use burn::prelude::*;
use neurofluid_core::lr_schedule::Schedule;

use crate::loss::dlf_step_loss;
use crate::net::{DlfNet, points_tensor, tensor_points};
use crate::records::{RecordError, RecordFrame, read_record};
use crate::rollout::rollout;
use crate::scene::BoxScene;

/// Why training data could not be used.
#[derive(Debug, thiserror::Error)]
pub enum TrainError {
    /// A record could not be read.
    #[error(transparent)]
    Record(#[from] RecordError),
    /// The data is unusable for training.
    #[error("{source_name}: {what}")]
    Data {
        /// The sequence (file or scene).
        source_name: String,
        /// What is wrong.
        what: String,
    },
}

/// A training sequence: consecutive frames (one network step apart) of one scene with a static
/// boundary. Generated scenes and DLF records both become this.
#[derive(Debug, Clone, PartialEq)]
pub struct TrainingSequence {
    /// Where it came from (file or scene name), for messages.
    pub name: String,
    /// Positions per frame.
    pub pos: Vec<Vec<[f32; 3]>>,
    /// Velocities per frame.
    pub vel: Vec<Vec<[f32; 3]>>,
    /// Boundary points.
    pub box_points: Vec<[f32; 3]>,
    /// Boundary normals (unit, pointing into the fluid region).
    pub box_normals: Vec<[f32; 3]>,
}

impl TrainingSequence {
    /// The `frames` frames `net` rolls out from `scene`: data the model fits exactly (its
    /// validation errors are zero), for tests and for fine-tuning on a model's own motion.
    pub fn rollout_of(
        net: &DlfNet,
        scene: BoxScene,
        frames: usize,
        name: impl Into<String>,
    ) -> Result<Self, TrainError> {
        let device = net.device();
        let boundary = net.boundary(&scene.box_points, &scene.box_normals, &device);
        let steps = frames.saturating_sub(1);
        let traj = rollout(net, &scene.pos, &scene.vel, &boundary, steps, |_| {});
        Self::new(
            name,
            traj.pos,
            traj.vel,
            scene.box_points,
            scene.box_normals,
        )
    }

    /// Builds a sequence, checking that frames, velocities and normals line up.
    pub fn new(
        name: impl Into<String>,
        pos: Vec<Vec<[f32; 3]>>,
        vel: Vec<Vec<[f32; 3]>>,
        box_points: Vec<[f32; 3]>,
        box_normals: Vec<[f32; 3]>,
    ) -> Result<Self, TrainError> {
        let name = name.into();
        let err = |what: String| TrainError::Data {
            source_name: name.clone(),
            what,
        };
        if pos.len() != vel.len() {
            return Err(err(format!(
                "{} position frames but {} velocity frames",
                pos.len(),
                vel.len()
            )));
        }
        for (f, (p, v)) in pos.iter().zip(&vel).enumerate() {
            if p.len() != v.len() {
                return Err(err(format!(
                    "frame {f}: {} positions but {} velocities",
                    p.len(),
                    v.len()
                )));
            }
        }
        if box_points.len() != box_normals.len() {
            return Err(err(format!(
                "{} boundary points but {} normals",
                box_points.len(),
                box_normals.len()
            )));
        }
        Ok(Self {
            name,
            pos,
            vel,
            box_points,
            box_normals,
        })
    }

    /// A sequence from the frames of one DLF record (the boundary comes from the first frame).
    pub fn from_record_frames(name: &str, frames: Vec<RecordFrame>) -> Result<Self, TrainError> {
        let first = frames.first().ok_or_else(|| TrainError::Data {
            source_name: name.into(),
            what: "no frames".into(),
        })?;
        let (Some(b), Some(n)) = (first.box_points.clone(), first.box_normals.clone()) else {
            return Err(TrainError::Data {
                source_name: name.into(),
                what: "the first frame has no `box`/`box_normals`".into(),
            });
        };
        let (pos, vel) = frames.into_iter().map(|f| (f.pos, f.vel)).unzip();
        Self::new(name, pos, vel, b, n)
    }

    /// Number of frames.
    pub fn num_frames(&self) -> usize {
        self.pos.len()
    }

    /// The sequence from its second frame on, each velocity replaced by the backward difference
    /// `(x_t − x_{t−1}) / dt`: the velocity a DLF rollout carries (its last step's mean), where
    /// a simulator stores its own (in free fall half a step of gravity ahead). Frames whose
    /// particle count differs from the one before keep their stored velocities.
    pub fn with_backward_velocities(&self, dt: f32) -> Self {
        let vel = (1..self.pos.len())
            .map(|t| {
                let (now, before) = (&self.pos[t], &self.pos[t - 1]);
                if now.len() != before.len() {
                    return self.vel[t].clone();
                }
                now.iter()
                    .zip(before)
                    .map(|(a, b)| std::array::from_fn(|k| (a[k] - b[k]) / dt))
                    .collect()
            })
            .collect();
        Self {
            name: self.name.clone(),
            pos: self.pos[1.min(self.pos.len())..].to_vec(),
            vel,
            box_points: self.box_points.clone(),
            box_normals: self.box_normals.clone(),
        }
    }

    /// Start frames t of the 3-frame windows (t, t+1, t+2) with a constant particle count.
    pub fn windows(&self) -> Vec<usize> {
        (0..self.num_frames().saturating_sub(2))
            .filter(|&t| {
                let n = self.pos[t].len();
                n > 0 && self.pos[t + 1].len() == n && self.pos[t + 2].len() == n
            })
            .collect()
    }
}

/// Reads every `*.msgpack.zst` of a folder (sorted by name), one sequence per file.
pub fn load_record_dir(dir: &Path) -> Result<Vec<TrainingSequence>, TrainError> {
    let entries = std::fs::read_dir(dir).map_err(|e| {
        TrainError::Record(RecordError::Io {
            path: dir.to_path_buf(),
            error: e,
        })
    })?;
    let mut files: Vec<_> = entries
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.to_string_lossy().ends_with(".msgpack.zst"))
        .collect();
    files.sort();
    if files.is_empty() {
        return Err(TrainError::Data {
            source_name: dir.display().to_string(),
            what: "no *.msgpack.zst files".into(),
        });
    }
    files
        .iter()
        .map(|f| TrainingSequence::from_record_frames(&f.display().to_string(), read_record(f)?))
        .collect()
}

/// Rotation matrix (row-major) by `angle` about the unit `axis` (Rodrigues).
pub fn rotation_about(axis: [f32; 3], angle: f32) -> [[f32; 3]; 3] {
    let n = (axis[0] * axis[0] + axis[1] * axis[1] + axis[2] * axis[2]).sqrt();
    let [x, y, z] = axis.map(|c| c / n);
    let (s, c) = angle.sin_cos();
    let t = 1.0 - c;
    [
        [t * x * x + c, t * x * y - s * z, t * x * z + s * y],
        [t * x * y + s * z, t * y * y + c, t * y * z - s * x],
        [t * x * z - s * y, t * y * z + s * x, t * z * z + c],
    ]
}

fn rotate(r: &[[f32; 3]; 3], pts: &[[f32; 3]]) -> Vec<[f32; 3]> {
    pts.iter()
        .map(|v| std::array::from_fn(|i| r[i][0] * v[0] + r[i][1] * v[1] + r[i][2] * v[2]))
        .collect()
}

/// DLF's validation errors (metres).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ValidationMetrics {
    /// Mean Euclidean error after one step from ground-truth frames (every `frame_skip` frames).
    pub err_n1: f64,
    /// Mean Euclidean error after two steps.
    pub err_n2: f64,
    /// Mean ground-truth→prediction nearest-neighbour distance along a full rollout from frame 0,
    /// every `frame_skip` frames (NaN when no sequence has a constant particle count).
    pub whole_seq_err: f64,
}

fn mean_distance(a: &[[f32; 3]], b: &[[f32; 3]]) -> f64 {
    a.iter()
        .zip(b)
        .map(|(p, q)| {
            (0..3)
                .map(|k| ((p[k] - q[k]) as f64).powi(2))
                .sum::<f64>()
                .sqrt()
        })
        .sum::<f64>()
        / a.len().max(1) as f64
}

/// Mean distance from each ground-truth particle to the nearest predicted one (world units).
fn mean_nn_distance(gt: &[[f32; 3]], pred: &[[f32; 3]]) -> f64 {
    neurofluid_core::metrics::gt_to_pred_distance(gt, pred).mean / 1000.0
}

/// Evaluates DLF's validation errors of `net` (any device; no gradients are taken).
pub fn validate(
    net: &DlfNet,
    sequences: &[TrainingSequence],
    frame_skip: usize,
) -> ValidationMetrics {
    let device = net.device();
    let skip = frame_skip.max(1);
    let (mut e1, mut e2, mut n12) = (0.0, 0.0, 0usize);
    let (mut ew, mut nw) = (0.0, 0usize);
    for seq in sequences {
        let boundary = net.boundary(&seq.box_points, &seq.box_normals, &device);
        for t in seq.windows().into_iter().filter(|t| t % skip == 0) {
            let s1 = net.step(
                points_tensor(&seq.pos[t], &device),
                points_tensor(&seq.vel[t], &device),
                &boundary,
            );
            let p1 = tensor_points(&s1.pos);
            let s2 = net.step(s1.pos, s1.vel, &boundary);
            let p2 = tensor_points(&s2.pos);
            e1 += mean_distance(&p1, &seq.pos[t + 1]);
            e2 += mean_distance(&p2, &seq.pos[t + 2]);
            n12 += 1;
        }
        let n = seq.pos[0].len();
        if n == 0 || seq.pos.iter().any(|p| p.len() != n) {
            tracing::debug!(
                "{}: particle count changes; no whole-sequence error",
                seq.name
            );
            continue;
        }
        let mut pos = points_tensor(&seq.pos[0], &device);
        let mut vel = points_tensor(&seq.vel[0], &device);
        for t in 1..seq.num_frames() {
            let s = net.step(pos, vel, &boundary);
            if t % skip == 0 {
                ew += mean_nn_distance(&seq.pos[t], &tensor_points(&s.pos));
                nw += 1;
            }
            pos = s.pos;
            vel = s.vel;
        }
    }
    let div = |s: f64, n: usize| if n == 0 { f64::NAN } else { s / n as f64 };
    ValidationMetrics {
        err_n1: div(e1, n12),
        err_n2: div(e2, n12),
        whole_seq_err: div(ew, nw),
    }
}

/// DLF's loss of one training sample: two steps unrolled from frame `t` of `seq` (rotated by
/// `rot`), `0.5·L(step 1) + 0.5·L(step 2)`, in the autodiff graph (before the ×128 scale).
pub fn supervised_loss(
    net: &DlfNet,
    seq: &TrainingSequence,
    t: usize,
    rot: Option<[[f32; 3]; 3]>,
) -> Tensor<1> {
    let device = net.device();
    let tr = |p: &[[f32; 3]]| match &rot {
        Some(r) => rotate(r, p),
        None => p.to_vec(),
    };
    let boundary = net.boundary(&tr(&seq.box_points), &tr(&seq.box_normals), &device);
    let pos0 = points_tensor(&tr(&seq.pos[t]), &device);
    let vel0 = points_tensor(&tr(&seq.vel[t]), &device);
    let gt1 = points_tensor(&tr(&seq.pos[t + 1]), &device);
    let gt2 = points_tensor(&tr(&seq.pos[t + 2]), &device);
    let s1 = net.step(pos0, vel0, &boundary);
    let l1 = dlf_step_loss(s1.pos.clone(), gt1, &s1.num_fluid_neighbors);
    let s2 = net.step(s1.pos, s1.vel, &boundary);
    let l2 = dlf_step_loss(s2.pos, gt2, &s2.num_fluid_neighbors);
    l1 * 0.5 + l2 * 0.5
}

/// The factors of DLF's schedule, after each of its boundaries.
const LR_FACTORS: [f64; 5] = [0.5, 0.25, 0.125, 0.0625, 0.03125];

/// The boundaries of DLF's schedule for a run of `iterations` steps: 25k/30k/35k/40k/45k of 50k
/// steps, scaled in proportion for other run lengths.
fn lr_boundaries(iterations: u64) -> impl Iterator<Item = u64> {
    let scale = iterations as f64 / 50_000.0;
    [25_000.0, 30_000.0, 35_000.0, 40_000.0, 45_000.0]
        .into_iter()
        .map(move |b: f64| (b * scale).floor() as u64)
}

/// DLF's training schedule (spec dlf.md §5) for a run of `iterations` steps: factor 1, then
/// 0.5/0.25/0.125/0.0625/0.03125 after 25k/30k/35k/40k/45k of 50k steps, the boundaries
/// scaled in proportion for other run lengths.
pub fn lr_schedule(iterations: u64) -> Schedule {
    Schedule::Piecewise {
        boundaries: lr_boundaries(iterations).collect(),
        factors: LR_FACTORS.to_vec(),
    }
}

/// [`lr_schedule`] over the updates taken: DLF's reference steps its scheduler before each
/// update, so an update's factor is `lr_schedule`'s at one more than the updates taken before
/// it; here every boundary is one lower (one at 0, in a run of a single step, stays at 0).
pub fn lr_schedule_per_update(iterations: u64) -> Schedule {
    Schedule::Piecewise {
        boundaries: lr_boundaries(iterations)
            .map(|b| b.saturating_sub(1))
            .collect(),
        factors: LR_FACTORS.to_vec(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Under a constant acceleration a, x_t = ½·a·(t·dt)², the backward difference is
    /// a·dt·(t − ½), one frame fewer, the stored velocities ignored.
    #[test]
    fn backward_velocities_are_the_last_steps_mean() {
        let (dt, a) = (0.02f32, -9.81f32);
        let pos: Vec<Vec<[f32; 3]>> = (0..5)
            .map(|t| {
                let y = 0.5 * a * (t as f32 * dt).powi(2);
                vec![[0.1, y, 0.0], [0.2, y + 0.5, -0.1]]
            })
            .collect();
        let vel = vec![vec![[9.0; 3]; 2]; 5];
        let seq = TrainingSequence::new("fall", pos.clone(), vel, vec![], vec![]).unwrap();
        let back = seq.with_backward_velocities(dt);
        assert_eq!(back.pos, pos[1..].to_vec());
        assert_eq!(back.vel.len(), 4);
        for (i, frame) in back.vel.iter().enumerate() {
            let t = (i + 1) as f32;
            for v in frame {
                assert!(v[0].abs() < 1e-4 && v[2].abs() < 1e-4, "{v:?}");
                assert!((v[1] - a * dt * (t - 0.5)).abs() < 1e-3, "t {t}: {v:?}");
            }
        }
        assert_eq!(back.windows(), vec![0, 1]);
    }

    #[test]
    fn the_lr_schedule_at_every_boundary() {
        let s = lr_schedule(50_000);
        let factors = [
            (0, 1.0),
            (25_000, 1.0),
            (25_001, 0.5),
            (30_000, 0.5),
            (30_001, 0.25),
            (35_001, 0.125),
            (40_000, 0.125),
            (40_001, 0.0625),
            (45_000, 0.0625),
            (45_001, 0.03125),
            (50_000, 0.03125),
        ];
        for (step, f) in factors {
            assert_eq!(s.factor_at(step), f, "step {step}");
        }
        assert!((1e-3 * s.factor_at(45_001) - 3.125e-5).abs() <= 1e-12 * 3.125e-5);
        // other run lengths scale the boundaries (DLF's `dlf_lr_factor`)
        let short = lr_schedule(100);
        assert_eq!(short.factor_at(50), 1.0);
        assert_eq!(short.factor_at(51), 0.5);
        assert_eq!(short.factor_at(91), 0.03125);
        assert!(s.problem().is_none());
    }

    #[test]
    fn the_schedule_per_update_is_one_update_later() {
        // the supervised trainer's rates before groups counted updates: `lr_at(step + 1)`
        for iterations in [2, 3, 7, 100, 1234, 50_000] {
            let (reference, per_update) =
                (lr_schedule(iterations), lr_schedule_per_update(iterations));
            for n in 0..iterations {
                assert_eq!(
                    per_update.factor_at(n),
                    reference.factor_at(n + 1),
                    "{iterations} iterations, update {n}"
                );
            }
        }
    }
}
