//! glibc's allocator settings for tensor work.
//!
//! By default glibc returns freed blocks above a (dynamic) threshold to the kernel and the next
//! allocation of that size faults zeroed pages in again. The DLF conv's chunked temporaries
//! (16 MB each, hundreds per step) then spend up to half the step's CPU time in the kernel
//! (BENCHMARKS.md, "DLF step"). [`keep_freed_memory`] re-executes the process once with
//! `GLIBC_TUNABLES` set so that every block comes from the heap (no per-block mmap) and freed
//! memory stays there for reuse (peak resident memory is kept, not returned). The PhysNeRF
//! step's activations (hundreds of MB each) gain the most: the step took half the time.

/// The variable that opts out: `NEUROFLUID_MALLOC=default` keeps glibc's own settings.
pub const MALLOC_VAR: &str = "NEUROFLUID_MALLOC";

/// The glibc tunables set: no mmap per block (`mmap_max=0`; glibc still maps new heap memory
/// when the heap cannot grow), mmap threshold 32 MB (glibc's largest, for when it does), no heap
/// trimming, 256 MB of top padding.
pub const TUNABLES: &str = "glibc.malloc.mmap_max=0:glibc.malloc.mmap_threshold=33554432:\
glibc.malloc.trim_threshold=17179869184:glibc.malloc.top_pad=268435456";

/// The allocator setting in force, as the CLI logs it and the benches print it:
/// `GLIBC_TUNABLES=<value>` or `GLIBC_TUNABLES=(glibc defaults)`.
pub fn allocator_setting() -> String {
    let value = std::env::var("GLIBC_TUNABLES").unwrap_or_else(|_| "(glibc defaults)".into());
    format!("GLIBC_TUNABLES={value}")
}

/// Re-executes the current program with [`TUNABLES`] added to `GLIBC_TUNABLES` unless they are
/// there already or [`MALLOC_VAR`] is `default`; call first thing in `main`, before any thread
/// starts. Returns (doing nothing) on other platforms, and when the re-exec fails.
pub fn keep_freed_memory() {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    {
        use std::os::unix::process::CommandExt;
        if std::env::var(MALLOC_VAR).is_ok_and(|v| v == "default") {
            return;
        }
        let current = std::env::var("GLIBC_TUNABLES").unwrap_or_default();
        if current.contains(TUNABLES) {
            return;
        }
        let Ok(exe) = std::env::current_exe() else {
            return;
        };
        let tunables = if current.is_empty() {
            TUNABLES.to_string()
        } else {
            format!("{current}:{TUNABLES}")
        };
        let mut args = std::env::args_os();
        let arg0 = args.next();
        let mut command = std::process::Command::new(exe);
        if let Some(arg0) = arg0 {
            command.arg0(arg0);
        }
        // exec only returns on failure; the program then goes on with glibc's defaults
        let _ = command.args(args).env("GLIBC_TUNABLES", tunables).exec();
    }
}
