#!/usr/bin/env python3
"""CPU time of each thread per training step on a cubecl backend (wgpu, CUDA).

Burn 0.22's cubecl backends run every tensor operation on device threads: the training thread
enqueues each operation into a queue of 32 tasks (spinning while the queue is full), a thread
named DSU-<type>-<index> (cubecl's upstream stage, fusion's streams) and one named DSD-<…> (the
downstream stage: kernel compilation, launches, copies; a driver's own threads may inherit its
name) run them. A step is bound by whichever of them is busy for the whole step, or by the device
when none is. This script reads each thread's CPU time (nanoseconds on a CPU, Linux's
/proc/PID/task/TID/schedstat) at every step mark of the trainer (target neurofluid_train::step)
and prints, per stage, each busy thread's CPU milliseconds per step beside the step's wall time.
A thread at ~100 % of the wall is the bottleneck; the training thread's share includes its spins
on a full queue, which say that the device threads are behind.

    scripts/thread-times.py BIN EXPERIMENT OUT [--warmup-iters N] [--joint-seconds S] [-- ARGS]

ARGS go to both stages (default: --device wgpu). Runs the warm-up for N steps (default 30) and the
joint stage for S seconds (default 120) in a scratch folder linking experiments/, data/, assets/;
writes OUT/threads.txt and the trainer's logs. The first two steps of each stage (kernel
compilation) are left out of the figures.
"""

import argparse
import os
import re
import signal
import statistics
import subprocess
import sys
import tempfile
import time


def thread_times(pid):
    """{tid: (name, cpu ns)} of every thread of `pid` (those that exit meanwhile are skipped)."""
    out = {}
    try:
        tids = os.listdir(f"/proc/{pid}/task")
    except OSError:
        return out
    for tid in tids:
        try:
            with open(f"/proc/{pid}/task/{tid}/comm") as f:
                name = f.read().strip()
            with open(f"/proc/{pid}/task/{tid}/schedstat") as f:
                ns = int(f.read().split()[0])
        except (OSError, ValueError, IndexError):
            continue
        out[int(tid)] = (name, ns)
    return out


class Stop(Exception):
    """A time limit (SIGTERM from `timeout`) ended the measurement: summarise what was measured."""


def stop(_signum, _frame):
    raise Stop


def run_stage(cmd, env, log_path, seconds, marks):
    """Runs `cmd`, adding to `marks` every thread's times at each step mark:
    (stage, wall s, {tid: (name, ns)})."""
    with open(log_path, "w") as log:
        proc = subprocess.Popen(cmd, env=env, stderr=subprocess.PIPE, stdout=log, text=True,
                                errors="replace")
        start = time.monotonic()
        try:
            for line in proc.stderr:
                log.write(line)
                if "step finished" in line:
                    stage = re.search(r'stage="?(\w+)', line)
                    marks.append((stage.group(1) if stage else "?", time.monotonic(),
                                  thread_times(proc.pid)))
                if seconds is not None and time.monotonic() - start > seconds:
                    break
        finally:
            proc.terminate()
            proc.wait()


def summarise(marks, skip=2):
    lines = []
    for stage in dict.fromkeys(s for s, _, _ in marks):
        ms = [m for m in marks if m[0] == stage][skip:]
        if len(ms) < 2:
            lines.append(f"{stage}: too few steps ({len(ms)} after the first {skip})")
            continue
        walls = [b[1] - a[1] for a, b in zip(ms, ms[1:])]
        per_thread = {}
        for a, b in zip(ms, ms[1:]):
            for tid, (name, ns) in b[2].items():
                if tid in a[2]:
                    per_thread.setdefault((tid, name), []).append((ns - a[2][tid][1]) * 1e-6)
        wall = statistics.median(walls)
        lines.append(f"{stage}: {len(walls)} steps, wall per step median {wall * 1e3:.1f} ms "
                     f"(mean {statistics.mean(walls) * 1e3:.1f})")
        busiest = sorted(per_thread.items(), key=lambda kv: -statistics.mean(kv[1]))
        for (tid, name), cpu in busiest[:8]:
            med = statistics.median(cpu)
            lines.append(f"    {name:<16} tid {tid:<8} CPU per step median {med:9.1f} ms "
                         f"({100 * med / (wall * 1e3):5.1f} % of the wall)")
    return lines


def main():
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("bin")
    p.add_argument("experiment")
    p.add_argument("out")
    p.add_argument("--warmup-iters", type=int, default=30)
    p.add_argument("--joint-seconds", type=float, default=120)
    p.add_argument("args", nargs="*")
    a = p.parse_args()
    extra = a.args or ["--device", "wgpu"]
    binary = os.path.realpath(a.bin)
    repo = os.path.dirname(os.path.dirname(os.path.realpath(__file__)))
    os.makedirs(a.out, exist_ok=True)
    out = os.path.realpath(a.out)
    env = dict(os.environ, RUST_LOG="info,neurofluid_train::step=trace")
    with tempfile.TemporaryDirectory() as scratch:
        for d in ["experiments", "data", "assets"]:
            if os.path.exists(os.path.join(repo, d)):
                os.symlink(os.path.join(repo, d), os.path.join(scratch, d))
        os.chdir(scratch)
        common = ["--set", "name=thread-times", "--set", f"warmup.iters={a.warmup_iters}"]
        marks = []
        signal.signal(signal.SIGTERM, stop)
        try:
            run_stage([binary, "warmup", a.experiment, "--fresh", *common,
                       "--set", "warmup.ckpt_every=100000", "--set", "warmup.preview_every=0",
                       *extra], env, os.path.join(out, "warmup.log"), None, marks)
            run_stage([binary, "joint", a.experiment, *common,
                       "--set", "joint.ckpt_every=100000", "--set", "joint.preview_every=0",
                       *extra], env, os.path.join(out, "joint.log"), a.joint_seconds, marks)
        except Stop:
            print("stopped by the time limit; the steps measured so far:")
    lines = summarise(marks)
    with open(os.path.join(out, "threads.txt"), "w") as f:
        f.write("\n".join(lines) + "\n")
    print("\n".join(lines))
    return 0 if marks else 1


if __name__ == "__main__":
    sys.exit(main())
