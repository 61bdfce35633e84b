#!/usr/bin/env python3
"""The renderer's novel-view reach from the training images alone (experiments/bed/README.md
rule 13): warm-ups with one warm-up view held out (`warmup.held_out`), scored on it.

    python3 scripts/analysis/held-out-table.py [runs/r13]

Reads `<root>/<scene>-<variant>-<view>/metrics.jsonl` (as `experiments/research/bed/view-dependence-screen.sh`
names them) and takes the held-out view's PSNR from the last `warmup-preview` row (the warm-up's
last step; a mean is shown only where every fold has reached the last step of any run). Prints
markdown: PSNR per fold, the mean over folds per scene and variant, and for
each variant other than A whether its mean is above A's on every scene where both have a mean
(the rules' test).
"""

import json
import os
import statistics
import sys


def last_preview(path):
    best = None
    with open(path) as f:
        for line in f:
            row = json.loads(line)
            if row["stage"] == "warmup-preview" and (best is None or row["step"] >= best["step"]):
                best = row
    return best


def main():
    root = sys.argv[1] if len(sys.argv) > 1 else "runs/r13"
    found = {}
    for name in sorted(os.listdir(root)):
        path = os.path.join(root, name, "metrics.jsonl")
        parts = name.rsplit("-", 2)
        if len(parts) != 3 or not os.path.isfile(path):
            continue
        row = last_preview(path)
        if row is not None:
            scene, variant, view = parts
            found.setdefault(scene, {}).setdefault(variant, {})[view] = (row["step"], row["psnr"])
    if not found:
        sys.exit(f"no warm-up previews under {root}")
    views = sorted({v for s in found.values() for r in s.values() for v in r})
    last = max(step for s in found.values() for r in s.values() for step, _ in r.values())
    variants = sorted({v for s in found.values() for v in s})
    print("| scene | variant | " + " | ".join(f"{v} held out" for v in views) + " | mean |")
    print("|---|---|" + "---:|" * (len(views) + 1))
    means = {}
    for scene, by_variant in found.items():
        for variant in variants:
            folds = by_variant.get(variant, {})
            cells = [f"{folds[v][1]:.2f} (step {folds[v][0]})" if v in folds else "–" for v in views]
            complete = len(folds) == len(views) and all(st == last for st, _ in folds.values())
            mean = statistics.mean(p for _, p in folds.values()) if complete else None
            means[(scene, variant)] = mean
            shown = f"{mean:.2f}" if mean is not None else "–"
            print(f"| {scene} | {variant} | " + " | ".join(cells) + f" | {shown} |")
    for variant in variants[1:]:
        both = [
            s for s in found
            if means.get((s, variant)) is not None and means.get((s, variants[0])) is not None
        ]
        wins = sum(means[(s, variant)] > means[(s, variants[0])] for s in both)
        print(f"\n{variant} above {variants[0]} on every scene screened with both: "
              f"{bool(both) and wins == len(both)} ({wins} of {len(both)})")


if __name__ == "__main__":
    main()
