//! Stopping between steps on request: SIGTERM (what Slurm sends before it preempts a job, or
//! through `--signal` before its time limit) and SIGINT (Ctrl-C) ask the running stage to finish
//! the step it is in, write a checkpoint and stop; the process then exits with
//! [`REQUEUE_EXIT_CODE`], which says "requeue me": a rerun resumes exactly from that checkpoint.
//!
//! The signal handlers only set a flag; the [`Driver`](super::Driver) checks it between steps,
//! so no model code sees a signal. A second Ctrl-C ends the process at once (a stage stuck
//! outside the driver's loop, e.g. generating a scene, can still be interrupted by hand).

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, OnceLock};

use anyhow::Context;

/// The exit status of a process stopped on request with its checkpoint written
/// (`EX_TEMPFAIL` of sysexits.h: a temporary failure, retrying is expected).
pub const REQUEUE_EXIT_CODE: u8 = 75;

/// The process-wide stop request the signal handlers set.
pub fn process_flag() -> Arc<AtomicBool> {
    static FLAG: OnceLock<Arc<AtomicBool>> = OnceLock::new();
    Arc::clone(FLAG.get_or_init(|| Arc::new(AtomicBool::new(false))))
}

/// Makes SIGTERM and SIGINT set [`process_flag`] instead of ending the process (a second
/// SIGINT still ends it, with status 130).
pub fn install_signal_handlers() -> anyhow::Result<()> {
    use signal_hook::consts::{SIGINT, SIGTERM};
    use signal_hook::flag;
    let requested = process_flag();
    // registered first, so it sees the flag as it was before this signal set it
    flag::register_conditional_shutdown(SIGINT, 130, Arc::clone(&requested))
        .context("installing the SIGINT handler")?;
    for signal in [SIGINT, SIGTERM] {
        flag::register(signal, Arc::clone(&requested))
            .with_context(|| format!("installing the handler of signal {signal}"))?;
    }
    Ok(())
}

/// Whether a stop was requested through `flag`.
pub fn requested(flag: &AtomicBool) -> bool {
    flag.load(Ordering::SeqCst)
}

/// A stage stopped on request after `done` steps, its checkpoint written.
#[derive(Debug, thiserror::Error)]
#[error(
    "{stage} stopped on request (SIGTERM or SIGINT) after step {done}; its checkpoint is written \
     and running the same command again resumes from it"
)]
pub struct Stopped {
    /// The stage.
    pub stage: &'static str,
    /// Steps done (and checkpointed).
    pub done: u64,
}

/// The [`Stopped`] in `err`'s chain, if the error is a stop on request.
pub fn stopped(err: &anyhow::Error) -> Option<&Stopped> {
    err.chain().find_map(|e| e.downcast_ref::<Stopped>())
}
