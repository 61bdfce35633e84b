//! Loading weights draws no random number: every way a model is read from a file (DLF's `.pt`,
//! `.safetensors` and `.bpk`, PhysNeRF's safetensors, a stage's checkpoint into a model built
//! for it) leaves Burn's backend RNG where it was, so a seeded draw after a load is the draw
//! without it (a loader that built DLF's convs the random way advanced it).

use burn::prelude::*;
use burn::tensor::Distribution;
use neurofluid_dlf::{DlfConfig, DlfNet};
use neurofluid_physnerf::{PhysNerf, PhysNerfConfig};
use neurofluid_tests::{seeded_turn, workspace_root};
use neurofluid_train::trainer::checkpoint::{load_module, save_module};

const SEED: u64 = 7;

/// The first numbers the backend draws after `SEED`, with `between` run after the seed.
fn draw_after(device: &Device, between: impl FnOnce()) -> Vec<f32> {
    device.seed(SEED);
    between();
    Tensor::<1>::random([16], Distribution::Default, device)
        .into_data()
        .try_to_vec::<f32>()
        .unwrap()
}

#[test]
fn loading_weights_leaves_the_backends_rng_where_it_was() {
    let _turn = seeded_turn();
    let device = neurofluid_core::device::cpu();
    let dir = tempfile::tempdir().unwrap();
    let published = workspace_root().join("assets/dlf_pretrained");
    let (pt, st) = (
        published.join("pretrained_model_weights.pt"),
        published.join("pretrained_model_weights.safetensors"),
    );
    // the files, written before any seeded draw (building PhysNeRF and saving it draws)
    let bpk = dir.path().join("dlf.bpk");
    let dlf = neurofluid_dlf::load_dlf(&pt, DlfConfig::default(), &device).unwrap();
    neurofluid_dlf::save_checkpoint(&dlf, &bpk).unwrap();
    let dlf_ckpt = dir.path().join("dlf-module.bpk");
    save_module(&dlf, &dlf_ckpt).unwrap();
    let cfg = PhysNerfConfig {
        depth: 2,
        width: 8,
        skip: 1,
        ..Default::default()
    };
    let physnerf = PhysNerf::new(cfg.clone(), &device).unwrap();
    let (nerf_st, nerf_ckpt) = (
        dir.path().join("physnerf.safetensors"),
        dir.path().join("physnerf.bpk"),
    );
    physnerf.save(&nerf_st).unwrap();
    save_module(&physnerf, &nerf_ckpt).unwrap();
    // sealed, as a stage's checkpoint is (an unsealed one is refused)
    neurofluid_core::checksums::seal(dir.path()).unwrap();

    let expected = draw_after(&device, || {});
    // the check can fail: building DLF from scratch between the seed and the draw moves it
    let moved = draw_after(&device, || {
        DlfNet::new(DlfConfig::default(), &device);
    });
    assert_ne!(moved, expected, "building DLF draws its convs' kernels");

    for path in [&pt, &st, &bpk] {
        let after = draw_after(&device, || {
            neurofluid_dlf::load_dlf(path, DlfConfig::default(), &device).unwrap();
        });
        assert_eq!(after, expected, "loading {} drew", path.display());
    }
    let after = draw_after(&device, || {
        let shell = DlfNet::zeros(DlfConfig::default(), &device);
        load_module(shell, &dlf_ckpt).unwrap();
    });
    assert_eq!(after, expected, "loading DLF's stage checkpoint drew");
    let after = draw_after(&device, || {
        PhysNerf::load(&nerf_st, &device, burn::tensor::DType::F32).unwrap();
    });
    assert_eq!(after, expected, "loading PhysNeRF's safetensors drew");
    let after = draw_after(&device, || {
        // as the stages load a checkpoint: into a model built for it, whose layers draw their
        // weights on first use only
        let built = PhysNerf::new(cfg.clone(), &device).unwrap();
        load_module(built, &nerf_ckpt).unwrap();
    });
    assert_eq!(after, expected, "loading PhysNeRF's stage checkpoint drew");
}
