//! Stopping between steps on request: SIGTERM (what Slurm sends before it preempts a job, or
//! through `--signal` before its time limit) and SIGINT (Ctrl-C) ask the running stage to finish
//! the step it is in, write a checkpoint and stop; the process then exits with
//! [`REQUEUE_EXIT_CODE`], which says "requeue me": a rerun resumes exactly from that checkpoint.
//!
//! The signal handlers only set a flag; the trainer's driver checks it between steps
//! ([`requested`]), so no model code sees a signal. A second SIGINT or SIGTERM, a second or more
//! after the first, ends the process at once (status 130 or 143), so a stage stuck outside the
//! driver's loop (generating a scene, a long fit, a hung read) can always be stopped without
//! SIGKILL; its last checkpoint stays. Signals that come together count as one: Slurm's
//! preemption signals both the batch shell, which passes it on, and the trainer.

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

/// How long after the first stop request a second signal ends the process.
pub const SECOND_SIGNAL_AFTER: std::time::Duration = std::time::Duration::from_secs(1);

/// Makes SIGTERM and SIGINT set [`process_flag`] instead of ending the process; one that comes
/// [`SECOND_SIGNAL_AFTER`] or later after the first still ends it, with status 128 + the
/// signal's number (130 or 143).
pub fn install_signal_handlers() -> Result<(), SignalHandlerError> {
    use signal_hook::consts::{SIGINT, SIGTERM};
    use signal_hook::flag;
    let requested = process_flag();
    let refused = |handler: String| move |source| SignalHandlerError { handler, source };
    // a watcher that blocks until a signal comes: the first starts the clock, one that comes
    // SECOND_SIGNAL_AFTER or later ends the process (the handlers themselves may only set flags)
    let mut signals = signal_hook::iterator::Signals::new([SIGINT, SIGTERM])
        .map_err(refused("the stop-request watcher".into()))?;
    std::thread::Builder::new()
        .name("stop-request".into())
        .spawn(move || {
            let mut first = None;
            for signal in signals.forever() {
                match first {
                    None => first = Some(std::time::Instant::now()),
                    Some(at) if at.elapsed() >= SECOND_SIGNAL_AFTER => {
                        std::process::exit(128 + signal)
                    }
                    Some(_) => {}
                }
            }
        })
        .map_err(refused("the stop-request watcher".into()))?;
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

    /// The first SIGTERM asks for a stop, and one that comes with it changes nothing; a later
    /// one ends the process at once with status 143, whatever it is doing (issue 72: a run
    /// stuck in a loop outside the driver ignored SIGTERM and only SIGKILL ended it). The test
    /// runs itself again as a child that signals itself.
    #[test]
    fn a_second_signal_ends_the_process() {
        const CHILD: &str = "NEUROFLUID_SIGNAL_TEST_CHILD";
        if std::env::var_os(CHILD).is_some() {
            use signal_hook::consts::SIGTERM;
            use signal_hook::low_level::raise;
            install_signal_handlers().unwrap();
            // preemption: the batch shell passes its SIGTERM on as the trainer gets its own
            raise(SIGTERM).unwrap();
            raise(SIGTERM).unwrap();
            assert!(requested(&process_flag()));
            std::thread::sleep(SECOND_SIGNAL_AFTER * 2);
            // a stuck loop: only the later signal ends it
            raise(SIGTERM).unwrap();
            std::thread::sleep(std::time::Duration::from_secs(30));
            std::process::exit(0);
        }
        let out = std::process::Command::new(std::env::current_exe().unwrap())
            .args([
                "--exact",
                "stop_request::tests::a_second_signal_ends_the_process",
            ])
            .env(CHILD, "1")
            .output()
            .unwrap();
        assert_eq!(
            out.status.code(),
            Some(143),
            "{}",
            String::from_utf8_lossy(&out.stdout)
        );
    }

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
