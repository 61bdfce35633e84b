#!/usr/bin/env python3
"""The table of the input-noise screen on the time split (issue 71, item 7; protocol in
docs/notebook/2026-12-05-steady-rollouts.md): U0 and N0 per scene and seed from
runs/noise/<variant>-<scene>-s<seed>/eval/report.json, the means over seeds, and the rule.

    python3 experiments/research/physics/noise-table.py

CD = (d + d′)/2 over t = 1–29 (the split's training window) and t = 30–49 (its prediction
window, frames of the real task's training window the split never trains on); the energy is each
rollout's gain per particle over t < 30 and its bound twice the truth's + 0.1 J/kg.
"""

import json
import os
import statistics

SCENES = ["watercube", "honeycone"]
SEEDS = [10, 11, 12]
VARIANTS = ["U0", "N0"]
SPLIT = 30


def scores(variant, scene, seed):
    path = f"runs/noise/{variant}-{scene}-s{seed}/eval/report.json"
    if not os.path.exists(path):
        return None
    r = json.load(open(path))

    def cd(lo, hi):
        return statistics.mean((f["neurofluid"] + f["reverse"]["neurofluid"]) / 2
                               for f in r["frames"] if lo <= f["t"] <= hi)

    energy = {e["model"]: e["grounding_per_particle"] for e in r["energy"]}
    fitted = {p["name"]: p["value"] for p in r.get("fitted_physics") or []}
    return {"cd": (cd(1, SPLIT - 1), cd(SPLIT, 49)), "energy": energy["NeuroFluid"],
            "bound": 2 * energy["truth"] + 0.1, "fitted": fitted}


def main():
    means = {}
    print("| scene | run | seed | CD t < 30 | CD t = 30–49 | J/kg t < 30 (bound) | fitted |")
    print("|---|---|---:|---:|---:|---|---|")
    for scene in SCENES:
        for variant in VARIANTS:
            done = []
            for seed in SEEDS:
                s = scores(variant, scene, seed)
                if not s:
                    continue
                done.append(s)
                fit = ", ".join(f"{k} {v:.3f}" for k, v in s["fitted"].items())
                print(f"| {scene} | {variant} | {seed} | {s['cd'][0]:.2f} | {s['cd'][1]:.2f} | "
                      f"{s['energy']:.3f} ({s['bound']:.3f}) | {fit} |")
            if done:
                means[scene, variant] = (
                    statistics.mean(s["cd"][0] for s in done),
                    statistics.mean(s["cd"][1] for s in done),
                    statistics.mean(s["energy"] for s in done),
                    statistics.mean(s["bound"] for s in done),
                    len(done))
    print()
    print("| scene | run | seeds | CD t < 30 | CD t = 30–49 | J/kg t < 30 (bound) |")
    print("|---|---|---:|---:|---:|---|")
    for (scene, variant), (a, b, e, bound, n) in means.items():
        print(f"| {scene} | {variant} | {n} | {a:.2f} | {b:.2f} | {e:.3f} ({bound:.3f}) |")
    complete = all(means.get((s, v), (0,) * 5)[4] == len(SEEDS) for s in SCENES for v in VARIANTS)
    verdicts = []
    for scene in SCENES:
        if (scene, "U0") not in means or (scene, "N0") not in means:
            continue
        u, n = means[scene, "U0"], means[scene, "N0"]
        ok = n[1] < u[1] and n[0] <= 1.05 * u[0] and n[2] <= n[3]
        verdicts.append(ok)
        print(f"\n{scene}: t = 30–49 {n[1]:.2f} vs {u[1]:.2f} ({100 * (n[1] / u[1] - 1):+.1f} %), "
              f"t < 30 {100 * (n[0] / u[0] - 1):+.1f} % (≤ +5 %), energy {n[2]:.3f} ≤ {n[3]:.3f}: "
              f"{'passes' if ok else 'fails'}")
    if not complete:
        print("\nincomplete (runs missing): decides nothing")
    else:
        print(f"\nN0 {'passes' if all(verdicts) else 'fails'} (means over seeds 10–12, both scenes)")


if __name__ == "__main__":
    main()
