#!/usr/bin/env python3
"""What d and d′ give a rollout that does not move: the true first test frame held still, scored
against the truth like every rollout (issue 71; docs/notebook/2026-12-06-image-landscape.md, P9).
On a fluid at rest this is the mean-state predictor: if it scores as well as the best rollout of
the scalars' grid, d and d′ reward a frozen pool over one that moves as the truth's particles do.

    /work/bedenv/bin/python experiments/research/reference/frozen-truth.py SCENE [SCENE ...]

Reads <BED_DATA or data/bed-particles>/<scene>/<test view>/test/particles/NNNN.npz; prints d, d′,
(d + d′)/2 × 1000 over t = 1–49 and t = 50–59, the same windows and units as the reports.
"""

import glob
import json
import os
import sys

import numpy as np


def nearest_mean(a, b):
    """The mean over the points of a of the distance to the nearest point of b (brute force)."""
    d2 = ((a[:, None, :] - b[None, :, :]) ** 2).sum(-1)
    return float(np.sqrt(d2.min(1)).mean())


def frames(scene_dir):
    """The true positions at every test frame of the scene's test view."""
    test = json.load(open(os.path.join(scene_dir, "scene.json")))["test"]
    pattern = os.path.join(scene_dir, test["views"][0], test["split"], "particles", "*.npz")
    return [np.load(p)["pos"] for p in sorted(glob.glob(pattern))]


def main():
    root = os.environ.get("BED_DATA", "data/bed-particles")
    print("| scene | d t < 50 | d′ t < 50 | (d + d′)/2 t < 50 | (d + d′)/2 t ≥ 50 |")
    print("|---|---:|---:|---:|---:|")
    for scene in sys.argv[1:]:
        seq = frames(os.path.join(root, scene))
        held = seq[0]
        rows = [(1000 * nearest_mean(x, held), 1000 * nearest_mean(held, x)) for x in seq[1:]]
        early, late = rows[:49], rows[49:]
        cd = lambda w: float(np.mean([(d + dp) / 2 for d, dp in w]))
        print(f"| {scene} | {np.mean([d for d, _ in early]):.2f} | {np.mean([dp for _, dp in early]):.2f} | "
              f"{cd(early):.2f} | {cd(late):.2f} |")


if __name__ == "__main__":
    main()
