#!/usr/bin/env python3
"""The bed screen of the one-config candidates against A, the bed configs as they ship (issue
71, item 2; the screen rule of experiments/bed/README.md, "A screen"), from
runs/bed71/<scene>-s<seed>-<variant>/eval/report.json, the variants A and those of CANDIDATES
(experiments/research/bed/screen.sh with VARIANT=one-config, one-config-noise,
one-config-noise-body or one-config-fit-then-ground[-a|-b|-c|-u9], OUT runs/bed71; U0, U0N,
U0NB, U5, U5a, U5b, U5c and U9 of docs/notebook/2026-12-05-quick-reference.md; and the runs of
U6, U6c, U7 and U8, whose free-flight variants left screen.sh with the option, 6b5d68d, and of
U10 and U11, whose variants left it with theirs, fba426a).

    python3 experiments/research/bed/one-config-table.py [SEED ...]    (default: 10)

The measure is CD = (d + d′)/2 over t = 1–49; t = 50–59 and the energies are reported, never
used. Means over the seeds given.
"""

import json
import os
import statistics
import sys

WATER = ["water-dam-z", "water-torus-tilted-z", "water-sphere-y"]
HONEY = ["honey-drop-z", "honey-slump-y-400"]
# A's seed-to-seed sd of the measure per water scene (rule 24)
SD = {"water-dam-z": 0.16, "water-torus-tilted-z": 0.38, "water-sphere-y": 0.15}
CANDIDATES = {"one-config": "U0", "one-config-noise": "U0N", "one-config-noise-body": "U0NB",
              "one-config-fit-then-ground": "U5", "one-config-fit-then-ground-a": "U5a",
              "one-config-fit-then-ground-b": "U5b", "one-config-fit-then-ground-c": "U5c",
              "one-config-free-flight": "U6", "one-config-free-flight-c": "U6c",
              "one-config-free-flight-u7": "U7", "one-config-fit-then-ground-ff": "U8",
              "one-config-fit-then-ground-u9": "U9", "one-config-settle-u10": "U10",
              "one-config-shrink-u11": "U11"}
# U5c and U6c are U5b and U6 with the one config's 4 transitions unrolled: on a scene whose config
# already unrolls 4 (honey's) their commands are the same to the argument, and the other's run is
# theirs
SAME_RUN = {("one-config-fit-then-ground-c", "honey-drop-z"): "one-config-fit-then-ground-b",
            ("one-config-fit-then-ground-c", "honey-slump-y-400"): "one-config-fit-then-ground-b",
            ("one-config-free-flight-c", "honey-drop-z"): "one-config-free-flight",
            ("one-config-free-flight-c", "honey-slump-y-400"): "one-config-free-flight"}


def scores(scene, seed, variant):
    variant = SAME_RUN.get((variant, scene), variant)
    path = f"runs/bed71/{scene}-s{seed}-{variant}/eval/report.json"
    if not os.path.exists(path):
        return None
    r = json.load(open(path))

    def mean(key, lo, hi):
        return statistics.mean(key(f) for f in r["frames"] if lo <= f["t"] <= hi)

    d = mean(lambda f: f["neurofluid"], 1, 49)
    dp = mean(lambda f: f["reverse"]["neurofluid"], 1, 49)
    late = mean(lambda f: (f["neurofluid"] + f["reverse"]["neurofluid"]) / 2, 50, 59)
    energy = {e["model"]: e["grounding_per_particle"] for e in r["energy"]}
    fitted = {p["name"]: p["value"] for p in r.get("fitted_physics") or []}
    return {"d": d, "dp": dp, "cd": (d + dp) / 2, "late": late, "energy": energy["NeuroFluid"],
            "bound": 2 * energy["truth"] + 0.1, "fitted": fitted}


def over_seeds(scene, seeds, variant):
    runs = [scores(scene, s, variant) for s in seeds]
    if not all(runs):
        return None
    keys = ["d", "dp", "cd", "late", "energy", "bound"]
    m = {k: statistics.mean(r[k] for r in runs) for k in keys}
    m["fitted"] = runs[0]["fitted"]
    return m


def main():
    seeds = [int(s) for s in sys.argv[1:]] or [10]
    print(f"seeds {seeds}; CD = (d + d′)/2 over t = 1–49 (t = 50–59 and energies reported only)\n")
    print("| scene | run | d | d′ | CD t < 50 | CD t ≥ 50 | J/kg t < 50 (bound) | fitted (first seed) |")
    print("|---|---|---:|---:|---:|---:|---|---|")
    table = {}
    for scene in WATER + HONEY:
        for variant in ["A", *CANDIDATES]:
            m = over_seeds(scene, seeds, variant)
            if not m:
                continue
            table[scene, variant] = m
            fit = ", ".join(f"{k} {v:.3f}" for k, v in m["fitted"].items())
            print(f"| {scene} | {CANDIDATES.get(variant, 'A')} | {m['d']:.2f} | {m['dp']:.2f} | "
                  f"{m['cd']:.2f} | {m['late']:.2f} | {m['energy']:.3f} ({m['bound']:.3f}) | {fit} |")

    for variant, label in CANDIDATES.items():
        print()
        screen(table, variant, label)


def screen(table, variant, label):
    """The README's screen rule for one candidate, per material, on the scenes run."""

    def five_percent(scene):
        a, b = table[scene, "A"], table[scene, variant]
        return b["d"] <= 1.05 * a["d"] and b["dp"] <= 1.05 * a["dp"]

    def ran(scenes):
        return [s for s in scenes if (s, "A") in table and (s, variant) in table]

    water, honey = ran(WATER), ran(HONEY)
    if water:
        a = statistics.mean(table[s, "A"]["cd"] for s in water)
        b = statistics.mean(table[s, variant]["cd"] for s in water)
        within = all(table[s, variant]["cd"] <= table[s, "A"]["cd"] + SD[s] for s in water)
        five = all(five_percent(s) for s in water)
        ok = b < a and within and five
        state = "passes" if ok else "fails"
        if ok and len(water) < len(WATER):
            state = "passes so far (scenes missing)"
        print(f"{label} water ({', '.join(water)}): mean CD {b:.2f} against A's {a:.2f}; each "
              f"scene within A's sd: {within}; d and d′ within 5 %: {five} → {state}")
    if honey:
        lower = all(table[s, variant]["cd"] < table[s, "A"]["cd"] for s in honey)
        five = all(five_percent(s) for s in honey)
        state = "passes" if lower and five else "fails"
        if lower and five and len(honey) < len(HONEY):
            state = "passes so far (scenes missing)"
        print(f"{label} honey ({', '.join(honey)}): lower on each: {lower}; d and d′ within 5 %: "
              f"{five} → {state}")


if __name__ == "__main__":
    main()
