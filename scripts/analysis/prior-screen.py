#!/usr/bin/env python3
"""Screens DLF priors by rollouts alone (experiments/bed/README.md rule 11): on every bed scene and
every built-in scene, the published DLF under the shipped rules and at g × 1.0, and each prior at
g × 1.0, scored by `neurofluid-train rollout` (d and d′ over t < 50 and t ≥ 50), as a table.

    python3 scripts/analysis/prior-screen.py --prior "300 steps=runs/dlf-dagger/dlf-records-bv.bpk" \\
        --prior "1000 steps=runs/dlf-dagger/dlf-records-bv-1000.bpk" [--bin target/debug/neurofluid-train]

The bed scenes are read from `--bed` (default data/bed-particles, made by `scripts/testbed/make_bed.py
--no-render --out data/bed-particles`; images are not needed); the built-in scenes are generated
when missing. Scores are kept in `--out` (one JSON per rollout) and reused.
"""

import argparse
import json
import os
import subprocess

BED = ["water-dam-z", "water-torus-tilted-z", "water-sphere-y", "honey-drop-z", "honey-slump-y-400"]
BUILTIN = ["watercube", "watersphere", "waterbunny", "honeycone"]
PUBLISHED = "assets/dlf_pretrained/pretrained_model_weights.pt"


def rollout(args, name, config, weights, sets):
    path = os.path.join(args.out, name + ".json")
    if not os.path.isfile(path):
        cmd = [args.bin, "rollout", config, "--weights", weights, "--json"]
        for s in sets:
            cmd += ["--set", s]
        out = subprocess.run(cmd, check=True, capture_output=True, text=True).stdout
        with open(path + ".part", "w") as f:
            f.write(out)
        os.replace(path + ".part", path)
    with open(path) as f:
        return json.load(f)


def cell(j):
    d, r = j["d"], j["d_reverse"]
    text = "%.2f / %.2f ‖ %.2f / %.2f" % (d["grounding_mean"], r["grounding_mean"], d["prediction_mean"],
                                         r["prediction_mean"])
    return text + (f" ({j['outside']} out)" if j["outside"] else "")


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--prior", action="append", default=[], help="LABEL=WEIGHTS, rolled out at g × 1.0")
    ap.add_argument("--bin", default="target/debug/neurofluid-train")
    ap.add_argument("--bed", default="data/bed-particles")
    ap.add_argument("--out", default="runs/prior-screen")
    args = ap.parse_args()
    os.makedirs(args.out, exist_ok=True)
    priors = [p.split("=", 1) for p in args.prior]
    cols = [("published DLF, shipped rules", PUBLISHED, []), ("published DLF, g × 1.0", PUBLISHED, ["dlf.gravity_scale=1.0"])]
    cols += [(f"{label}, g × 1.0", w, ["dlf.gravity_scale=1.0"]) for label, w in priors]
    print("| scene | " + " | ".join(c[0] for c in cols) + " |")
    print("|---|" + "---|" * len(cols))
    scenes = [(s, f"experiments/bed/{s}.toml", [f"scene.path={args.bed}/{s}"]) for s in BED]
    scenes += [(s, f"experiments/quick-{s}.toml", []) for s in BUILTIN]
    for scene, config, where in scenes:
        row = []
        for k, (label, weights, sets) in enumerate(cols):
            name = f"{scene}.{k}-{os.path.basename(weights)}-{'-'.join(sets) or 'shipped'}"
            row.append(cell(rollout(args, name, config, weights, where + sets)))
        print(f"| {scene} | " + " | ".join(row) + " |", flush=True)


if __name__ == "__main__":
    main()
