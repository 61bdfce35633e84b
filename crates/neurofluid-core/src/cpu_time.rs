//! CPU time, for benchmarks that report CPU seconds beside wall seconds and for the trainer's
//! share of a step spent on the host.

/// User + system CPU seconds of this process (all threads) from `/proc/self/stat` (Linux);
/// NaN elsewhere.
pub fn process_cpu_seconds() -> f64 {
    let Ok(stat) = std::fs::read_to_string("/proc/self/stat") else {
        return f64::NAN;
    };
    // fields after the ")" of the command name: state is field 3, utime 14, stime 15
    let rest = stat.rsplit(')').next().unwrap_or("");
    let f: Vec<&str> = rest.split_whitespace().collect();
    let ticks = |i: usize| {
        f.get(i)
            .and_then(|v| v.parse::<f64>().ok())
            .unwrap_or(f64::NAN)
    };
    (ticks(11) + ticks(12)) / 100.0
}

/// CPU seconds the calling thread has run, from `/proc/thread-self/schedstat` (Linux: its first
/// field, nanoseconds on a CPU); NaN elsewhere. On an accelerator the training thread's CPU time
/// per step is the host's part of the step: its own work and the backend's launches and copies
/// (and a driver's busy waits, where it spins while the device works).
pub fn thread_cpu_seconds() -> f64 {
    std::fs::read_to_string("/proc/thread-self/schedstat")
        .ok()
        .and_then(|s| s.split_whitespace().next()?.parse::<f64>().ok())
        .map_or(f64::NAN, |ns| ns * 1e-9)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn cpu_time_grows_with_work() {
        let t0 = process_cpu_seconds();
        if t0.is_nan() {
            return; // not Linux
        }
        let mut x = 0u64;
        let start = std::time::Instant::now();
        while start.elapsed().as_millis() < 300 {
            x = x.wrapping_mul(6364136223846793005).wrapping_add(1);
        }
        std::hint::black_box(x);
        let spent = process_cpu_seconds() - t0;
        assert!(
            spent > 0.1 && spent < 5.0,
            "{spent} CPU-s for 0.3 s of spinning"
        );
    }

    /// A thread's CPU time counts its own spinning, not its sleeping nor another thread's work.
    #[test]
    fn thread_cpu_time_is_the_threads_own() {
        let t0 = thread_cpu_seconds();
        if t0.is_nan() {
            return; // not Linux
        }
        let spinner = std::thread::spawn(|| {
            let start = std::time::Instant::now();
            let mut x = 0u64;
            while start.elapsed().as_millis() < 300 {
                x = x.wrapping_mul(6364136223846793005).wrapping_add(1);
            }
            x
        });
        std::thread::sleep(std::time::Duration::from_millis(300));
        std::hint::black_box(spinner.join().unwrap());
        let slept = thread_cpu_seconds() - t0;
        assert!(slept < 0.1, "{slept} CPU-s while sleeping");
        let t1 = thread_cpu_seconds();
        let start = std::time::Instant::now();
        let mut x = 0u64;
        while start.elapsed().as_millis() < 300 {
            x = x.wrapping_mul(6364136223846793005).wrapping_add(1);
        }
        std::hint::black_box(x);
        let (spun, wall) = (thread_cpu_seconds() - t1, start.elapsed().as_secs_f64());
        // under load the thread gets part of the wall time, never more than all of it
        assert!(
            spun > 0.01 && spun <= wall + 0.01,
            "{spun} CPU-s for {wall} s of spinning"
        );
    }
}
