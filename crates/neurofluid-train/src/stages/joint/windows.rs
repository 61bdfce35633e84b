//! When each parameter group of the joint stage steps: PhysNeRF at the end of every window of
//! `bptt_steps` transitions, DLF at the end of every `dlf_every`-th window, both at the end of
//! every epoch.

use crate::config::JointSection;

/// Which parameter groups a step of the joint stage updates.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Updates {
    /// PhysNeRF: at the end of every window of `bptt_steps` transitions and of every epoch.
    pub physnerf: bool,
    /// DLF: at the end of every `dlf_every`-th window and of every epoch.
    pub dlf: bool,
}

/// The groups updated after iteration `step` (0-based) of a joint stage of `total` iterations
/// over `transitions` per epoch.
pub fn updates_after(cfg: &JointSection, transitions: u64, total: u64, step: u64) -> Updates {
    let done = step + 1;
    let edge = done.is_multiple_of(transitions) || done == total;
    let window = cfg.bptt_steps.max(1) as u64;
    let window_end = edge || done.is_multiple_of(window);
    Updates {
        physnerf: window_end,
        dlf: window_end && (edge || done.is_multiple_of(window * cfg.dlf_every.max(1) as u64)),
    }
}

/// The updates (PhysNeRF's, DLF's) of the first `done` iterations: the counts of a checkpoint
/// written before the groups counted their own. Counted in closed form (the iterations that end
/// an epoch, a window or the stage), so a checkpoint's step of any size is counted at once.
pub fn updates_before(cfg: &JointSection, transitions: u64, total: u64, done: u64) -> (u64, u64) {
    let window = cfg.bptt_steps.max(1) as u64;
    let dlf_window = window.saturating_mul(cfg.dlf_every.max(1) as u64);
    // the iterations d in 1..=done with d a multiple of `transitions` or of `every`, or d = total
    let ends = |every: u64| {
        let both = lcm(transitions, every);
        // (the multiples of `every` that are not of both, then those of `transitions`: never
        // more than `done`, so no sum overflows)
        let multiples = done / every - both.map_or(0, |b| done / b) + done / transitions;
        let last = total >= 1
            && done >= total
            && !total.is_multiple_of(transitions)
            && !total.is_multiple_of(every);
        multiples.saturating_add(u64::from(last))
    };
    (ends(window), ends(dlf_window))
}

/// The least common multiple of `a` and `b` (≥ 1), `None` past `u64::MAX`.
fn lcm(a: u64, b: u64) -> Option<u64> {
    let gcd = |mut x: u64, mut y: u64| {
        while y != 0 {
            (x, y) = (y, x % y);
        }
        x
    };
    (a / gcd(a, b)).checked_mul(b)
}
