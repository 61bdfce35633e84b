//! `pretrain-dlf` fine-tunes on a generated scene folder (its training frames), under an
//! experiment's `[dlf]` rules, and writes a checkpoint that loads.

use neurofluid_dlf::{DlfConfig, load_dlf};
use neurofluid_tests::{seeded_turn, tiny_experiment, workspace_root};
use neurofluid_train::commands::pretrain_dlf::{Args, run};
use neurofluid_train::stages::scene_source::generate_scene_if_missing;
use neurofluid_train::stages::supervised_dlf::SupervisedConfig;

#[test]
fn fine_tunes_on_a_generated_scene() {
    let _turn = seeded_turn();
    let tmp = tempfile::tempdir().unwrap();
    let scene = generate_scene_if_missing(&tiny_experiment(tmp.path(), "pretrain")).unwrap();
    let weights = workspace_root().join("assets/dlf_pretrained/pretrained_model_weights.pt");
    let output = tmp.path().join("ft.bpk");
    // every rule, the walls (which need the scene's box) among them
    let rules = tmp.path().join("rules.toml");
    std::fs::write(
        &rules,
        "name = \"rules\"\n[scene]\nbuiltin = \"watercube\"\n[dlf]\ncontainment = \"box\"\n\
         energy_cap = \"particle\"\ngravity_scale = 1.7\nviscosity = 0.2\n",
    )
    .unwrap();
    run(Args {
        data: scene.clone(),
        val: Some(scene),
        init: Some(weights),
        output: output.clone(),
        rules: Some(rules),
        train: SupervisedConfig {
            iterations: 2,
            batch_size: 1,
            lr: 1e-5,
            validate_every: 1,
            frame_skip: 1,
            seed: 1,
            ..SupervisedConfig::DLF
        },
        device: neurofluid_core::device::test_device_name(),
        fresh: false,
        keep_checkpoints: false,
    })
    .unwrap();
    load_dlf(
        &output,
        DlfConfig::default(),
        &neurofluid_core::device::test_device(),
    )
    .unwrap();
}
