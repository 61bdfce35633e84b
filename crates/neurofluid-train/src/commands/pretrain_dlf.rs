//! `pretrain-dlf`: supervised (pre)training or fine-tuning (the paper's DLF†) of DLF on DLF
//! `.msgpack.zst` records or a scene's particle sequence, with DLF's loss, rotations, schedule
//! and validation errors. It checkpoints into `<output stem>.pretrain/` (locked while it runs)
//! and resumes from there; the weights file is written once the training has finished, so a
//! diverged run never replaces it (fine-tuning in place, `--init X --output X`, is safe).
//! `--keep-checkpoints` also keeps the weights of every checkpoint beside it, to score a
//! supervised reference over its training.
//!
//! On a scene folder only the frames DLF† may see are used: the training split (t < 50), so the
//! prediction window stays unseen.

use std::path::{Path, PathBuf};

use anyhow::Context;
use neurofluid_core::device::parse_device;
use neurofluid_core::scene::{Aabb, MANIFEST_FILE, Role, Scene, UpAxis};
use neurofluid_dlf::train::{TrainingSequence, load_record_dir};
use neurofluid_dlf::{DlfConfig, DlfNet, load_dlf};
use serde::Serialize;

use crate::config::Cadence;
use crate::config::{Experiment, Settings};
use crate::stages::supervised_dlf::{STAGE, SupervisedConfig, SupervisedDlfTrainer};
use crate::trainer::sinks::{MetricsSink, ProgressBars};
use crate::trainer::{Driver, Event, EventSink, Trainer};
use neurofluid_core::folder_lock::FolderLock;
use neurofluid_outputs::metrics_log::MetricsLog;

/// Arguments of `pretrain-dlf`.
#[derive(Debug, Serialize, clap::Args)]
pub struct Args {
    /// Training data: a folder of DLF records (`*.msgpack.zst`, one sequence per file) or a
    /// scene folder (generated or released layout; its training frames are used).
    #[arg(long)]
    pub data: PathBuf,
    /// Validation data (a records folder or a scene folder).
    #[arg(long)]
    #[serde(skip_serializing_if = "Option::is_none")]
    pub val: Option<PathBuf>,
    /// Start from these weights (`.pt`, `.safetensors`, `.bpk`): fine-tuning. Default: random init.
    #[arg(long)]
    #[serde(skip_serializing_if = "Option::is_none")]
    pub init: Option<PathBuf>,
    /// Output weights (burnpack `.bpk`), written once the training has finished.
    #[arg(long)]
    pub output: PathBuf,
    /// Also write the weights of every checkpoint to `<output stem>-<step>.bpk` (e.g.
    /// `dagger-100.bpk`), to score the model over its training.
    #[arg(long)]
    #[serde(skip)]
    pub keep_checkpoints: bool,
    /// Train under the `[dlf]` rules of this experiment file (walls, energy cap, gravity scale,
    /// viscosity, dissipation), the rules the run that evaluates this DLF† rolls it out
    /// under. Its geometry mode is not taken: DLF trains with a constant geometry. Under walls
    /// the samples are not rotated (the box does not turn with them).
    /// Default: DLF's step as published.
    #[arg(long)]
    #[serde(skip_serializing_if = "Option::is_none")]
    pub rules: Option<PathBuf>,
    /// The training settings.
    #[command(flatten)]
    #[serde(flatten)]
    pub train: SupervisedConfig,
    /// Device (cpu, flex, ndarray, wgpu, cuda, cuda:N).
    #[arg(long, default_value = "cpu")]
    #[serde(skip)]
    pub device: String,
    /// Start over: delete the checkpoints of an earlier run with this output.
    #[arg(long)]
    #[serde(skip)]
    pub fresh: bool,
}

/// What DLF's step takes from its training data: the up axis, the box interior (a scene's;
/// DLF records have none) and the time between frames.
#[derive(Debug, Clone, Copy, PartialEq)]
struct DataFrame {
    up: UpAxis,
    box_interior: Option<Aabb>,
    dt: f32,
}

impl DataFrame {
    /// DLF records: y-up, no box, DLF's own time step.
    fn records() -> Self {
        Self {
            up: UpAxis::Y,
            box_interior: None,
            dt: DlfConfig::default().dt,
        }
    }
}

/// The sequences of a records folder or of a scene folder, and their frame.
fn load_sequences(path: &Path) -> anyhow::Result<(Vec<TrainingSequence>, DataFrame)> {
    if !path.join(MANIFEST_FILE).is_file() && !path.join("view_1").is_dir() {
        return Ok((load_record_dir(path)?, DataFrame::records()));
    }
    let scene =
        Scene::open(path).with_context(|| format!("opening the scene {}", path.display()))?;
    let frames = scene.particle_sequence(Role::Train)?;
    let walls = scene.boundary()?;
    let name = scene.manifest().name.clone();
    let sequence = TrainingSequence::new(
        name,
        frames.iter().map(|f| f.pos.clone()).collect(),
        frames.iter().map(|f| f.vel.clone()).collect(),
        walls.points,
        walls.normals,
    )?;
    let frame = DataFrame {
        up: scene.up_axis(),
        box_interior: Some(scene.manifest().box_interior),
        dt: 1.0 / scene.manifest().fps,
    };
    Ok((vec![sequence], frame))
}

/// DLF's settings for training data in `frame` (its up axis and time step): as published, or
/// under the `[dlf]` rules of the experiment file `rules`.
fn dlf_config(frame: &DataFrame, rules: Option<&Path>) -> anyhow::Result<DlfConfig> {
    let mut config = DlfConfig::for_up_axis(frame.up);
    config.dt = frame.dt;
    let Some(path) = rules else {
        return Ok(config);
    };
    let exp = Experiment::load(path)?;
    config
        .with_rules(exp.dlf.rules, frame.box_interior)
        .with_context(|| format!("--rules {}", path.display()))
}

/// The folder of the checkpoints that go with `output`.
pub fn checkpoint_dir(output: &Path) -> PathBuf {
    output.with_extension("pretrain")
}

/// Copies the final checkpoint's weights to the output file when the training has finished,
/// so the output (possibly the `--init` file itself) is never replaced by an unfinished or
/// diverged run; with `keep`, every checkpoint's weights to [`kept_checkpoint`] as it is made.
struct ExportWeights<'a> {
    checkpoints: &'a Path,
    output: &'a Path,
    keep: bool,
}

/// Where `--keep-checkpoints` writes the weights of the checkpoint after `step` steps.
pub fn kept_checkpoint(output: &Path, step: u64) -> PathBuf {
    let stem = output.file_stem().unwrap_or_default().to_string_lossy();
    output.with_file_name(format!("{stem}-{step}.bpk"))
}

/// Copies a checkpoint's weights, checked against its checksums, to `target` in one write.
fn copy_weights(checkpoint: &Path, target: &Path) -> anyhow::Result<()> {
    let source = checkpoint.join("dlf.bpk");
    neurofluid_core::checksums::verify_file(&source)?;
    let bytes = neurofluid_core::input_file::read(&source)
        .with_context(|| format!("reading {}", source.display()))?;
    neurofluid_core::atomic::write_bytes(target, &bytes)
        .with_context(|| format!("writing {}", target.display()))
}

impl EventSink for ExportWeights<'_> {
    fn on_event(&mut self, event: &Event<'_>) -> anyhow::Result<()> {
        match event {
            Event::Checkpointed { done, dir, .. } if self.keep => {
                copy_weights(dir, &kept_checkpoint(self.output, *done))
            }
            Event::Finished { .. } => {
                let dir = crate::trainer::checkpoint::latest(self.checkpoints)
                    .with_context(|| format!("no checkpoint in {}", self.checkpoints.display()))?;
                copy_weights(&dir, self.output)
            }
            _ => Ok(()),
        }
    }
}

/// Removes the checkpoints of an earlier run (`--fresh`), and nothing else of the folder.
fn reset_checkpoints(dir: &Path) -> anyhow::Result<()> {
    for p in [dir.join("checkpoint"), dir.join("checkpoint.old")] {
        if p.is_dir() {
            std::fs::remove_dir_all(&p).with_context(|| format!("removing {}", p.display()))?;
        }
    }
    Ok(())
}

/// Checks, before any training, that the weights can be written to `output`: a file name in
/// an existing folder where a file can be created, not a folder.
fn check_output(output: &Path) -> anyhow::Result<()> {
    anyhow::ensure!(
        !output.is_dir(),
        "--output {} is a folder; expected a weights file name (e.g. dlf.bpk)",
        output.display()
    );
    anyhow::ensure!(
        output.file_name().is_some(),
        "--output {}: expected a weights file name (e.g. dlf.bpk)",
        output.display()
    );
    let parent = output
        .parent()
        .filter(|p| !p.as_os_str().is_empty())
        .unwrap_or(Path::new("."));
    anyhow::ensure!(
        parent.is_dir(),
        "--output {}: the folder {} does not exist",
        output.display(),
        parent.display()
    );
    let probe = parent.join(format!(".pretrain-dlf-probe.{}", std::process::id()));
    std::fs::write(&probe, b"").with_context(|| {
        format!(
            "--output {}: cannot write in {}",
            output.display(),
            parent.display()
        )
    })?;
    std::fs::remove_file(&probe).with_context(|| format!("removing {}", probe.display()))?;
    Ok(())
}

/// Runs the training.
pub fn run(args: Args) -> anyhow::Result<()> {
    check_output(&args.output)?;
    let device = parse_device(&args.device)?.autodiff();
    let (train, frame) = load_sequences(&args.data)?;
    let val = match &args.val {
        Some(dir) => load_sequences(dir)?.0,
        None => Vec::new(),
    };
    let config = dlf_config(&frame, args.rules.as_deref())?;
    let net: DlfNet = match &args.init {
        Some(path) => load_dlf(path, config, &device)?,
        None => neurofluid_core::device::init_seeded(args.train.seed, &device, |cpu| {
            anyhow::Ok(DlfNet::new(config, cpu))
        })?,
    };
    tracing::info!(
        "pretrain-dlf: {} training and {} validation sequences, {} steps of batch {}",
        train.len(),
        val.len(),
        args.train.iterations,
        args.train.batch_size
    );
    let mut trainer = SupervisedDlfTrainer::new(&args.train, net, train, val)?;
    let dir = checkpoint_dir(&args.output);
    let _lock = FolderLock::acquire(&dir)?;
    if args.fresh {
        reset_checkpoints(&dir)?;
    }
    let mut bars = ProgressBars::new();
    // the training curve and the validation errors; the rows past the checkpoint resumed
    // dropped (every row when none is)
    let resumed = crate::trainer::checkpoint::latest(&dir)
        .map(|_| crate::trainer::checkpoint::saved_step(&dir));
    let mut log = MetricsLog::open_resumed(&dir, |row| resumed.is_some_and(|s| row.step <= s))?;
    let mut metrics = MetricsSink(&mut log);
    if resumed.is_none()
        && let Some(e) = trainer.evaluate(0)?
    {
        let event = Event::Evaluated {
            stage: STAGE.folder(),
            done: 0,
            time_s: 0.0,
            evaluation: &e,
        };
        bars.on_event(&event)?;
        metrics.on_event(&event)?;
    }
    let cadence = Cadence {
        log_every: 1,
        evaluate_every: args.train.validate_every,
        checkpoint_every: args.train.validate_every,
    };
    let mut export = ExportWeights {
        checkpoints: &dir,
        output: &args.output,
        keep: args.keep_checkpoints,
    };
    Driver::new(&dir, cadence, Settings::of(&args))
        .with_sink(&mut bars)
        .with_sink(&mut metrics)
        .with_sink(&mut export)
        .run(&mut trainer, None)?;
    tracing::info!("wrote {}", args.output.display());
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// An output that cannot be written is refused before any training.
    #[test]
    fn the_output_is_checked_first() {
        let dir = tempfile::tempdir().unwrap();
        let err = check_output(dir.path()).unwrap_err().to_string();
        assert!(err.contains("is a folder"), "{err}");
        let missing = dir.path().join("no/such/folder/dlf.bpk");
        let err = check_output(&missing).unwrap_err().to_string();
        assert!(err.contains("does not exist"), "{err}");
        check_output(&dir.path().join("dlf.bpk")).unwrap();
        assert_eq!(
            std::fs::read_dir(dir.path()).unwrap().count(),
            0,
            "the probe stays"
        );
        let args = Args {
            data: dir.path().join("nothing"),
            val: None,
            init: None,
            output: missing,
            rules: None,
            train: SupervisedConfig {
                iterations: 1,
                batch_size: 1,
                lr: 1e-5,
                validate_every: 1,
                frame_skip: 1,
                seed: 1,
                ..SupervisedConfig::DLF
            },
            device: "cpu".into(),
            fresh: false,
            keep_checkpoints: false,
        };
        // the data is missing too, but the output is named first
        let err = format!("{:#}", run(args).unwrap_err());
        assert!(err.contains("--output"), "{err}");
    }
    use neurofluid_dlf::records::{RecordFrame, write_record};
    use neurofluid_dlf::rollout::rollout;
    use neurofluid_dlf::scene::{block_in_box, dlf_wall_spacing};

    /// Fine-tuning on a record made by the pretrained model runs and writes a loadable checkpoint.
    #[test]
    fn fine_tunes_on_a_record_folder() {
        let weights = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("../../assets/dlf_pretrained/pretrained_model_weights.pt");
        let device = neurofluid_core::device::cpu();
        let net = load_dlf(&weights, DlfConfig::default(), &device).unwrap();
        let s = block_in_box(125, dlf_wall_spacing(), [0.1, 0.0, 0.0], 0.002, 4, 0.02);
        let boundary = net.boundary(&s.box_points, &s.box_normals, &device);
        let traj = rollout(&net, &s.pos, &s.vel, &boundary, 3, |_| {});
        let frames: Vec<RecordFrame> = (0..4)
            .map(|f| RecordFrame {
                pos: traj.pos[f].clone(),
                vel: traj.vel[f].clone(),
                box_points: (f == 0).then(|| s.box_points.clone()),
                box_normals: (f == 0).then(|| s.box_normals.clone()),
                ..RecordFrame::default()
            })
            .collect();
        let dir = tempfile::tempdir().unwrap();
        write_record(&dir.path().join("sim_0001_00.msgpack.zst"), &frames).unwrap();
        let output = dir.path().join("ft.bpk");
        let args = |init: Option<PathBuf>, output: &Path, iterations, batch_size, lr| Args {
            data: dir.path().to_path_buf(),
            val: Some(dir.path().to_path_buf()),
            init,
            output: output.to_path_buf(),
            rules: None,
            train: SupervisedConfig {
                iterations,
                batch_size,
                lr,
                validate_every: 1,
                frame_skip: 1,
                seed: 1,
                ..SupervisedConfig::DLF
            },
            device: "cpu".into(),
            fresh: false,
            keep_checkpoints: false,
        };
        run(args(Some(weights.clone()), &output, 2, 1, 1e-5)).unwrap();
        load_dlf(&output, DlfConfig::default(), &device).unwrap();
        assert!(!kept_checkpoint(&output, 1).exists());
        // its training curve and validation errors are in the checkpoints' folder, once each,
        // also when it starts over
        let rows = || {
            neurofluid_outputs::metrics_log::read_jsonl(
                &checkpoint_dir(&output).join(neurofluid_outputs::metrics_log::JSONL_FILE),
            )
            .unwrap()
        };
        let steps = |stage: &str| -> Vec<u64> {
            rows()
                .iter()
                .filter(|r| r.stage == stage)
                .map(|r| r.step)
                .collect()
        };
        assert_eq!(steps("pretrain-dlf-validation"), [0, 1, 2]);
        assert_eq!(steps("pretrain-dlf"), [1, 2]);
        let val = rows()
            .into_iter()
            .find(|r| r.stage == "pretrain-dlf-validation")
            .unwrap();
        assert!(val.get("whole_seq_err").is_some_and(f64::is_finite));
        assert_eq!(Some(val.loss), val.get("err_n1"));
        let mut again = args(Some(weights.clone()), &output, 2, 1, 1e-5);
        again.fresh = true;
        run(again).unwrap();
        assert_eq!(steps("pretrain-dlf-validation"), [0, 1, 2]);
        assert_eq!(steps("pretrain-dlf"), [1, 2]);
        assert!(
            checkpoint_dir(&output)
                .join("checkpoint/state.json")
                .is_file()
        );

        // --keep-checkpoints: the weights after each checkpointed step beside the output, the
        // last one the output's, the first another model (one step of training apart)
        let kept = dir.path().join("kept.bpk");
        let mut keep = args(Some(weights.clone()), &kept, 2, 1, 1e-3);
        keep.keep_checkpoints = true;
        run(keep).unwrap();
        let (first, last) = (kept_checkpoint(&kept, 1), kept_checkpoint(&kept, 2));
        assert_eq!(first, dir.path().join("kept-1.bpk"));
        assert_eq!(std::fs::read(&last).unwrap(), std::fs::read(&kept).unwrap());
        assert_ne!(
            std::fs::read(&first).unwrap(),
            std::fs::read(&kept).unwrap()
        );
        load_dlf(&first, DlfConfig::default(), &device).unwrap();

        // a batch larger than the data is refused at once, naming the flag
        let big = dir.path().join("big.bpk");
        let err = run(args(None, &big, 1, 100_000, 1e-5))
            .unwrap_err()
            .to_string();
        assert!(err.contains("--batch-size 100000"), "{err}");

        // fine-tuning in place with a learning rate that diverges: the run stops with a
        // message and the weights it started from are untouched
        let in_place = dir.path().join("in_place.bpk");
        neurofluid_dlf::weights::save_checkpoint(&net, &in_place).unwrap();
        let before = std::fs::read(&in_place).unwrap();
        let err = run(args(Some(in_place.clone()), &in_place, 20, 1, 1e8))
            .unwrap_err()
            .to_string();
        assert!(err.contains("pretrain-dlf stopped at step"), "{err}");
        assert_eq!(std::fs::read(&in_place).unwrap(), before);
        // and every checkpoint left behind loads: finite parameters only
        if let Some(ckpt) = crate::trainer::checkpoint::latest(&checkpoint_dir(&in_place)) {
            load_dlf(&ckpt.join("dlf.bpk"), DlfConfig::default(), &device).unwrap();
        }
    }

    /// `--rules` takes the experiment's `[dlf]` rules, and nothing else of it (not its geometry
    /// mode, which changes only gradients); the walls need a scene's box.
    #[test]
    fn rules_come_from_the_experiment() {
        let dir = tempfile::tempdir().unwrap();
        let file = |name: &str, dlf: &str| {
            let path = dir.path().join(name);
            let text = format!("name = \"t\"\n[scene]\nbuiltin = \"watercube\"\n[dlf]\n{dlf}");
            std::fs::write(&path, text).unwrap();
            path
        };
        let rules = file(
            "rules.toml",
            "gravity_scale = 1.7\nviscosity = 0.25\nenergy_cap = \"particle\"\n\
             geometry = \"differentiable\"\n",
        );
        let interior = Aabb {
            min: [-1.0, -1.0, 0.0],
            max: [1.0, 1.0, 2.0],
        };
        let frame = |up, box_interior| DataFrame {
            up,
            box_interior,
            dt: DlfConfig::default().dt,
        };
        let cfg = dlf_config(&frame(UpAxis::Z, Some(interior)), Some(&rules)).unwrap();
        let want = DlfConfig {
            rules: neurofluid_dlf::StepRules {
                gravity_scale: 1.7,
                viscosity: 0.25,
                energy_cap: neurofluid_dlf::EnergyCap::Particle,
                ..Default::default()
            },
            ..DlfConfig::z_up()
        };
        assert_eq!(cfg, want);
        assert_eq!(
            dlf_config(&frame(UpAxis::Z, Some(interior)), None).unwrap(),
            DlfConfig::z_up()
        );

        let walls = file("walls.toml", "containment = \"box\"\n");
        let cfg = dlf_config(&frame(UpAxis::Y, Some(interior)), Some(&walls)).unwrap();
        assert_eq!(cfg.container, Some(interior));
        let err = format!(
            "{:#}",
            dlf_config(&frame(UpAxis::Y, None), Some(&walls)).unwrap_err()
        );
        assert!(
            err.contains("walls.toml")
                && err.contains("dlf.containment")
                && err.contains("records"),
            "{err}"
        );
        let bad = file("bad.toml", "viscosity = 1.5\n");
        let err = format!(
            "{:#}",
            dlf_config(&frame(UpAxis::Y, None), Some(&bad)).unwrap_err()
        );
        assert!(err.contains("dlf.viscosity"), "{err}");
    }

    /// A scene's DLF steps at the scene's frame rate, with or without rules: DLF† of a 25 fps
    /// scene learns 40 ms steps, not DLF's 20 ms.
    #[test]
    fn a_scene_sets_the_time_step() {
        let dir = tempfile::tempdir().unwrap();
        let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("../..");
        let mut exp = Experiment::load(&root.join("experiments/tiny-ci.toml")).unwrap();
        exp.scene.dir = Some(dir.path().join("scene"));
        let scene = crate::stages::scene_source::generate_scene_if_missing(&exp).unwrap();
        let manifest = scene.join(MANIFEST_FILE);
        let text = std::fs::read_to_string(&manifest).unwrap();
        let mut json: serde_json::Value = serde_json::from_str(&text).unwrap();
        json["fps"] = serde_json::json!(25.0);
        std::fs::write(&manifest, json.to_string()).unwrap();
        let (seqs, frame) = load_sequences(&scene).unwrap();
        assert_eq!(seqs.len(), 1);
        assert_eq!(frame.dt, 1.0 / 25.0);
        assert!(frame.box_interior.is_some());
        assert_eq!(dlf_config(&frame, None).unwrap().dt, 1.0 / 25.0);
        let walls = dir.path().join("walls.toml");
        std::fs::write(
            &walls,
            "name = \"t\"\n[scene]\nbuiltin = \"watercube\"\n[dlf]\ncontainment = \"box\"\n",
        )
        .unwrap();
        assert_eq!(dlf_config(&frame, Some(&walls)).unwrap().dt, 1.0 / 25.0);
        let records = DataFrame::records();
        assert_eq!(dlf_config(&records, None).unwrap(), DlfConfig::default());
    }

    /// `--lr` must be a finite positive number; `--batch-size` must fit the data.
    #[test]
    fn bad_learning_rates_are_refused_by_the_command_line() {
        use clap::Parser;
        #[derive(clap::Parser)]
        struct Cli {
            #[command(flatten)]
            train: SupervisedConfig,
        }
        for bad in ["NaN", "-1", "0", "inf", "fast"] {
            assert!(Cli::try_parse_from(["x", "--lr", bad]).is_err(), "{bad}");
        }
        assert!(Cli::try_parse_from(["x", "--batch-size", "0"]).is_err());
        assert!(Cli::try_parse_from(["x", "--iterations", "0"]).is_err());
        assert_eq!(
            Cli::try_parse_from(["x", "--lr", "1e-4"]).unwrap().train.lr,
            1e-4
        );
    }
}
