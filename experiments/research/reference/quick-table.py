#!/usr/bin/env python3
"""The quick reference's table and file (issue 71, item 3; protocol in
docs/notebook/2026-12-05-quick-reference.md), and the one-config screen scored against it.

    python3 experiments/research/reference/quick-table.py            # the tables
    python3 experiments/research/reference/quick-table.py --write    # and experiments/reference/quick-walls.toml

CD = (d + d′)/2, averaged over the grounding window (t = 1–49) and the prediction window
(t = 50–59). Runs are read from runs/ref (quick-reference.sh), runs/one (one-config-runs.sh) and
runs/physics-material-<scene>-s<seed> (U0: the material probe).
"""

import importlib.util
import json
import os
import re
import statistics
import sys

# g as the bed's table computes it (one formula: scripts/bed-table.py's gap_share)
_spec = importlib.util.spec_from_file_location(
    "bed_table", os.path.join(os.path.dirname(__file__), "..", "..", "..", "scripts", "bed-table.py"))
bed_table = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(bed_table)

SCENES = ["watercube", "honeycone"]
SEEDS = [10, 11, 12]
REFERENCE = "experiments/reference/quick-walls.toml"


def report_scores(run):
    """CD per window, the energy per particle over t < 50 (the run's, the truth's), D's CD
    (the DLF under the run's rules) and the fitted scalars, from a run's eval/report.json."""
    path = os.path.join(run, "eval", "report.json")
    if not os.path.exists(path):
        return None
    r = json.load(open(path))

    def cd(model, lo, hi):
        v = [(f[model] + f["reverse"][model]) / 2 for f in r["frames"] if lo <= f["t"] <= hi]
        return statistics.mean(v)

    energy = {e["model"]: e["grounding_per_particle"] for e in r["energy"]}
    return {
        "cd": (cd("neurofluid", 1, 49), cd("neurofluid", 50, 59)),
        "d_cd": (cd("dlf", 1, 49), cd("dlf", 50, 59)),
        "energy": energy["NeuroFluid"],
        "truth_energy": energy["truth"],
        "fitted": {p["name"]: p["value"] for p in r.get("fitted_physics", [])} if r.get("fitted_physics") else {},
    }


def rollout_scores(log):
    """CD per window and the energy per particle over t < 50 from a `rollout` log."""
    if not os.path.exists(log):
        return None
    text = open(log).read()
    m = re.search(r"^\| \(d \+ d′\)/2 \| ([0-9.]+) \| ([0-9.]+) \|", text, re.M)
    e = re.search(r"^\| energy gained per particle \(J/kg; the truth's\) \| ([0-9.]+) \(([0-9.]+)\)", text, re.M)
    if not m:
        return None
    return {"cd": (float(m.group(1)), float(m.group(2))), "energy": float(e.group(1)),
            "truth_energy": float(e.group(2))}


def candidate(scene, step, seed):
    if step in ("T1", "T1h", "T4"):
        return report_scores(f"runs/ref/{scene}-s{seed}-{step}")
    if step in ("S1", "S4"):
        return rollout_scores(f"runs/ref/{scene}-s{seed}-{step}.log")
    if step == "U0":
        return report_scores(f"runs/physics-material-{scene}-s{seed}")
    return report_scores(f"runs/one/{step}-{scene}-s{seed}")


def mean_over_seeds(scene, step):
    runs = [candidate(scene, step, s) for s in SEEDS]
    done = [r for r in runs if r]
    if not done:
        return None, 0
    out = {"cd": tuple(statistics.mean(r["cd"][w] for r in done) for w in (0, 1)),
           "energy": statistics.mean(r["energy"] for r in done),
           "truth_energy": done[0]["truth_energy"]}
    if all("d_cd" in r for r in done):
        out["d_cd"] = tuple(statistics.mean(r["d_cd"][w] for r in done) for w in (0, 1))
    return out, len(done)


def main():
    write = "--write" in sys.argv
    print("## The candidates for R (means over the seeds run; CD = (d + d′)/2, t < 50 | t ≥ 50)\n")
    print("| scene | candidate | seeds | CD | J/kg per particle, t < 50 (truth's) |")
    print("|---|---|---:|---|---|")
    reference = {}
    for scene in SCENES:
        d = rollout_scores(f"runs/ref/{scene}-D.log")
        if d:
            print(f"| {scene} | D (pretrained, walls) | – | {d['cd'][0]:.2f} \\| {d['cd'][1]:.2f} | "
                  f"{d['energy']:.3f} ({d['truth_energy']:.3f}) |")
        best = [None, None]
        for step in ("T1", "T1h", "T4", "S1", "S4"):
            m, n = mean_over_seeds(scene, step)
            if not m:
                continue
            per_seed = " / ".join(
                f"{c['cd'][0]:.2f}" if (c := candidate(scene, step, s)) else "–" for s in SEEDS)
            print(f"| {scene} | {step} | {n} ({per_seed}) | {m['cd'][0]:.2f} \\| {m['cd'][1]:.2f} | "
                  f"{m['energy']:.3f} ({m['truth_energy']:.3f}) |")
            if n == len(SEEDS):
                for w in (0, 1):
                    if best[w] is None or m["cd"][w] < best[w][0]:
                        best[w] = (m["cd"][w], step)
        if best[0] and best[1]:
            reference[scene] = best
    print("\n## R per scene (the lowest mean over seeds 10–12 per window)\n")
    for scene, best in reference.items():
        print(f"- {scene}: t < 50 {best[0][0]:.2f} ({best[0][1]}), t ≥ 50 {best[1][0]:.2f} ({best[1][1]})")
    if write and reference:
        os.makedirs(os.path.dirname(REFERENCE), exist_ok=True)
        with open(REFERENCE, "w") as f:
            f.write("# The supervised reference on the built-in quick scenes (issue 71, item 3): protocol and\n"
                    "# figures in docs/notebook/2026-12-05-quick-reference.md; written by\n"
                    "#   python3 experiments/research/reference/quick-table.py --write\n")
            f.write('description = "R: the lowest mean CD over seeds 10-12 of the joint stage given the truth '
                    '(the quick budget; DLF trained or held) and DLF-dagger (300 steps) under the walls"\n')
            f.write('rules = "the walls (`dlf.containment = \\"box\\"`)"\n')
            for scene, best in reference.items():
                f.write(f"\n[scenes.{scene}]\ngrounding = {best[0][0]:.4f}\nprediction = {best[1][0]:.4f}\n"
                        f'source = "{best[0][1]} (grounding), {best[1][1]} (prediction)"\n')
        print(f"\nwrote {REFERENCE}")

    print("\n## The one-config screen (means over seeds 10–12; g = (CD_D − CD) / (CD_D − CD_R))\n")
    print("| scene | run | seeds | CD t < 50 | g t < 50 | CD t ≥ 50 | g t ≥ 50 | D's CD | J/kg (bound) | fitted (seed 10) |")
    print("|---|---|---:|---|---:|---|---:|---|---|---|")
    for scene in SCENES:
        for step in ("U0", "U0N", "U0NB", "U1", "U2", "U4", "U4N", "U5", "U5a", "U5b", "U6", "U7", "U8", "U9", "U10", "U11", "A"):
            m, n = mean_over_seeds(scene, step)
            if not m:
                continue
            g = ["–", "–"]
            if scene in reference and "d_cd" in m:
                for w in (0, 1):
                    share = bed_table.gap_share(m["d_cd"][w], m["cd"][w], reference[scene][w][0])
                    g[w] = "n/a" if share is None else f"{share:.2f}"
            if step == "A":
                g = ["(own rules)", "(own rules)"]
            first = candidate(scene, step, SEEDS[0])
            fitted = ", ".join(f"{k} {v:.3f}" for k, v in (first or {}).get("fitted", {}).items())
            bound = 2 * m["truth_energy"] + 0.1
            print(f"| {scene} | {step} | {n} | {m['cd'][0]:.2f} | {g[0]} | {m['cd'][1]:.2f} | {g[1]} | "
                  f"{m['d_cd'][0]:.2f} \\| {m['d_cd'][1]:.2f} | {m['energy']:.3f} ({bound:.3f}) | {fitted} |")


if __name__ == "__main__":
    main()
