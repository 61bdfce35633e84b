//! Process CPU time, for benchmarks that report CPU seconds beside wall seconds.

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

#[cfg(test)]
mod tests {
    use super::*;

    /// Spinning shows up as CPU time, and never more than the wall time it took on this
    /// machine's cores (work, not wall time, is what grows it: a loaded machine may give the
    /// spinning thread little of the wall time).
    #[test]
    fn cpu_time_grows_with_work() {
        let t0 = process_cpu_seconds();
        if t0.is_nan() {
            return; // not Linux
        }
        let mut x = 0u64;
        let start = std::time::Instant::now();
        let mut spent = 0.0;
        while spent < 0.1 && start.elapsed().as_secs() < 60 {
            for _ in 0..1_000_000 {
                x = x.wrapping_mul(6364136223846793005).wrapping_add(1);
            }
            spent = process_cpu_seconds() - t0;
        }
        std::hint::black_box(x);
        let wall = start.elapsed().as_secs_f64();
        let cores = std::thread::available_parallelism().map_or(1, |n| n.get()) as f64;
        assert!(spent >= 0.1, "{spent} CPU-s after {wall} s of spinning");
        assert!(
            spent <= (wall + 0.05) * cores,
            "{spent} CPU-s in {wall} s on {cores} cores"
        );
    }
}
