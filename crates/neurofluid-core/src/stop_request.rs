//! Stopping between steps on request: SIGTERM (what Slurm sends before it preempts a job, or
//! through `--signal` before its time limit) and SIGINT (Ctrl-C) ask the running stage to finish
//! the step it is in, write a checkpoint and stop; the process then exits with
//! [`REQUEUE_EXIT_CODE`], which says "requeue me": a rerun resumes exactly from that checkpoint.
//!
//! The signal handlers only set a flag; the trainer's driver checks it between steps
//! ([`requested`]), so no model code sees a signal. A second Ctrl-C ends the process at once (a
//! stage stuck outside the driver's loop, e.g. generating a scene, can still be interrupted by
//! hand).

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, OnceLock};

/// The exit status of a process stopped on request with its checkpoint written
/// (`EX_TEMPFAIL` of sysexits.h: a temporary failure, retrying is expected).
pub const REQUEUE_EXIT_CODE: u8 = 75;

/// The process-wide stop request the signal handlers set.
pub fn process_flag() -> Arc<AtomicBool> {
    static FLAG: OnceLock<Arc<AtomicBool>> = OnceLock::new();
    Arc::clone(FLAG.get_or_init(|| Arc::new(AtomicBool::new(false))))
}

/// A signal handler the operating system refused.
#[derive(Debug, thiserror::Error)]
#[error("installing {handler}")]
pub struct SignalHandlerError {
    /// The handler (`the SIGINT handler`, `the handler of signal 15`).
    pub handler: String,
    /// The operating system's error.
    pub source: std::io::Error,
}

/// Makes SIGTERM and SIGINT set [`process_flag`] instead of ending the process (a second
/// SIGINT still ends it, with status 130).
pub fn install_signal_handlers() -> Result<(), SignalHandlerError> {
    use signal_hook::consts::{SIGINT, SIGTERM};
    use signal_hook::flag;
    let requested = process_flag();
    let refused = |handler: String| move |source| SignalHandlerError { handler, source };
    // registered first, so it sees the flag as it was before this signal set it
    flag::register_conditional_shutdown(SIGINT, 130, Arc::clone(&requested))
        .map_err(refused("the SIGINT handler".into()))?;
    for signal in [SIGINT, SIGTERM] {
        flag::register(signal, Arc::clone(&requested))
            .map_err(refused(format!("the handler of signal {signal}")))?;
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

/// The [`Stopped`] in `err`'s chain of sources, if the error is a stop on request (for an
/// `anyhow::Error`, pass `err.as_ref()`).
pub fn stopped<'a>(err: &'a (dyn std::error::Error + 'static)) -> Option<&'a Stopped> {
    std::iter::successors(Some(err), |e| e.source()).find_map(|e| e.downcast_ref::<Stopped>())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// An error with a source, as a context wraps the error it adds to.
    #[derive(Debug, thiserror::Error)]
    #[error("running the stages")]
    struct Context(#[source] Stopped);

    #[test]
    fn a_stop_is_found_under_the_errors_that_wrap_it() {
        let stop = Stopped {
            stage: "warmup",
            done: 7,
        };
        assert!(stop.to_string().contains("after step 7"));
        let wrapped = Context(stop);
        assert_eq!(stopped(&wrapped).map(|s| s.done), Some(7));
        let other = std::io::Error::other("no stop");
        assert!(stopped(&other).is_none());
    }
}
