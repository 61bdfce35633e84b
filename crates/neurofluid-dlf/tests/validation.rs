//! DLF's validation errors: the pretrained model scores (numerically) zero error on its own
//! rollout. (The supervised training loop is a stage of `neurofluid-train`, tested there.)

use crate::common;

use common::*;
use neurofluid_dlf::scene::{block_in_box, dlf_wall_spacing};
use neurofluid_dlf::train::{TrainingSequence, validate};

fn generated_sequence(frames: usize, seed: u64) -> TrainingSequence {
    let s = block_in_box(216, dlf_wall_spacing(), [0.2, 0.0, -0.1], 0.002, seed, 0.02);
    let name = format!("block216_seed{seed}");
    TrainingSequence::rollout_of(&pretrained(&device()), s, frames, name).unwrap()
}

#[test]
fn pretrained_model_has_zero_error_on_its_own_rollout() {
    let seq = generated_sequence(8, 3);
    let m = validate(&pretrained(&device()), &[seq], 2);
    assert!(
        m.err_n1 < 1e-6 && m.err_n2 < 1e-6 && m.whole_seq_err < 1e-6,
        "{m:?}"
    );
}
