//! One stage identity: each stage of a run (and `pretrain-dlf`) with its folder in the run
//! folder (also the name of its metrics rows and of its random stream), its name in tables, and
//! the files of its checkpoints (the settings that shape its state: `config::settings`).

use std::path::{Path, PathBuf};

/// A stage.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Stage {
    /// Initial particles from images (only when `scene.initial = "from_images"`).
    Initial,
    /// PhysNeRF's warm-up.
    Warmup,
    /// Joint grounding.
    Joint,
    /// The second renderer fitted to the grounded rollout (only when `refit.enabled`).
    Refit,
    /// Evaluation.
    Eval,
    /// The NeRF baseline (also the NeRF of the initial particles).
    Nerf,
    /// The NeRF-T baseline.
    NerfT,
    /// Supervised DLF training (`pretrain-dlf`, outside a run folder).
    PretrainDlf,
}

impl Stage {
    /// Every stage of `run`, in the order they run (the baselines stand apart).
    pub const ALL: [Stage; 5] = [
        Stage::Initial,
        Stage::Warmup,
        Stage::Joint,
        Stage::Refit,
        Stage::Eval,
    ];

    /// The novel-view baselines.
    pub const BASELINES: [Stage; 2] = [Stage::Nerf, Stage::NerfT];

    /// The stage's folder in the run folder, the name of its metrics rows and of its random
    /// stream.
    pub const fn folder(self) -> &'static str {
        match self {
            Stage::Initial => "initial",
            Stage::Warmup => "warmup",
            Stage::Joint => "joint",
            Stage::Refit => "refit",
            Stage::Eval => "eval",
            Stage::Nerf => "nerf",
            Stage::NerfT => "nerf-t",
            Stage::PretrainDlf => "pretrain-dlf",
        }
    }

    /// The name in tables.
    pub const fn label(self) -> &'static str {
        match self {
            Stage::Initial => "initial particles",
            Stage::Warmup => "warm-up",
            Stage::Joint => "joint",
            Stage::Refit => "renderer refit",
            Stage::Eval => "evaluation",
            Stage::Nerf => "NeRF",
            Stage::NerfT => "NeRF-T",
            Stage::PretrainDlf => "DLF†",
        }
    }

    /// The stage whose folder is `name`.
    pub fn of_folder(name: &str) -> Option<Stage> {
        Self::ALL
            .into_iter()
            .chain(Self::BASELINES)
            .chain([Stage::PretrainDlf])
            .find(|s| s.folder() == name)
    }
}

impl std::fmt::Display for Stage {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.folder())
    }
}

/// A file of a checkpoint, with the names earlier releases gave it (which keep loading).
#[derive(Debug, Clone, Copy)]
pub struct CheckpointFile {
    /// The name written now.
    pub name: &'static str,
    /// Names read when the current one is absent, in order.
    pub formerly: &'static [&'static str],
}

impl CheckpointFile {
    /// Where the file is written in the checkpoint folder `dir`.
    pub fn save_path(&self, dir: &Path) -> PathBuf {
        dir.join(self.name)
    }

    /// Where the file is read from in `dir`: the current name or the first earlier one that
    /// exists, the current name when none does (so the error names it).
    pub fn load_path(&self, dir: &Path) -> PathBuf {
        std::iter::once(&self.name)
            .chain(self.formerly)
            .map(|n| dir.join(n))
            .find(|p| p.is_file())
            .unwrap_or_else(|| dir.join(self.name))
    }
}

/// The checkpoint files of the stages.
pub mod files {
    use super::CheckpointFile;

    /// PhysNeRF's weights (warm-up, joint).
    pub const PHYSNERF: CheckpointFile = CheckpointFile {
        name: "physnerf.bpk",
        formerly: &["renderer.bpk"],
    };
    /// The warm-up's Adam of PhysNeRF.
    pub const WARMUP_PHYSNERF_ADAM: CheckpointFile = CheckpointFile {
        name: "optim_physnerf.bpk",
        formerly: &["optim.bpk"],
    };
    /// The refit's Adam of PhysNeRF on the grounded rollout (its warm-up's is
    /// [`WARMUP_PHYSNERF_ADAM`]).
    pub const REFIT_PHYSNERF_ADAM: CheckpointFile = CheckpointFile {
        name: "optim_fit.bpk",
        formerly: &[],
    };
    /// The joint stage's Adam of PhysNeRF.
    pub const JOINT_PHYSNERF_ADAM: CheckpointFile = CheckpointFile {
        name: "optim_physnerf.bpk",
        formerly: &["optim_renderer.bpk"],
    };
    /// DLF's weights (joint, `pretrain-dlf`).
    pub const DLF: CheckpointFile = CheckpointFile {
        name: "dlf.bpk",
        formerly: &[],
    };
    /// The physical scalars the joint stage fits (`[joint.physics]`).
    pub const JOINT_PHYSICS: CheckpointFile = CheckpointFile {
        name: "physics.bpk",
        formerly: &[],
    };
    /// The joint stage's Adam of the physical scalars.
    pub const JOINT_PHYSICS_ADAM: CheckpointFile = CheckpointFile {
        name: "optim_physics.bpk",
        formerly: &[],
    };
    /// The joint stage's Adam of DLF.
    pub const JOINT_DLF_ADAM: CheckpointFile = CheckpointFile {
        name: "optim_dlf.bpk",
        formerly: &["optim_transition.bpk"],
    };
    /// `pretrain-dlf`'s Adam of DLF.
    pub const SUPERVISED_DLF_ADAM: CheckpointFile = CheckpointFile {
        name: "optim_dlf.bpk",
        formerly: &[],
    };
    /// A NeRF's weights.
    pub const NERF: CheckpointFile = CheckpointFile {
        name: "nerf.bpk",
        formerly: &[],
    };
    /// A NeRF's Adam.
    pub const NERF_ADAM: CheckpointFile = CheckpointFile {
        name: "optim_nerf.bpk",
        formerly: &[],
    };
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn folders_name_their_stage_back() {
        for s in Stage::ALL.into_iter().chain(Stage::BASELINES) {
            assert_eq!(Stage::of_folder(s.folder()), Some(s));
        }
        assert_eq!(Stage::of_folder("pretrain-dlf"), Some(Stage::PretrainDlf));
        assert_eq!(Stage::of_folder("eval-r_0"), None);
    }

    #[test]
    fn a_checkpoint_file_loads_an_earlier_name() {
        let dir = tempfile::tempdir().unwrap();
        assert_eq!(
            files::PHYSNERF.load_path(dir.path()),
            dir.path().join("physnerf.bpk")
        );
        std::fs::write(dir.path().join("renderer.bpk"), b"x").unwrap();
        assert_eq!(
            files::PHYSNERF.load_path(dir.path()),
            dir.path().join("renderer.bpk")
        );
        std::fs::write(dir.path().join("physnerf.bpk"), b"x").unwrap();
        assert_eq!(
            files::PHYSNERF.load_path(dir.path()),
            dir.path().join("physnerf.bpk")
        );
    }
}
