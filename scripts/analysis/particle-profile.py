#!/usr/bin/env python3
"""The shape of a bed run's fluid over the test frames (issue 34): per frame, of the truth, the
pretrained DLF's rollout and NeuroFluid's, the mean and 90th-percentile height above the box's
floor (the interior's lowest face), the rms horizontal distance from the truth's centre,
and the mean (10th-percentile) number of other particles within four radii (the kernel support of
`joint.rest_density_weight` and of the report's density table).

    python3 scripts/analysis/particle-profile.py RUN_DIR [FRAMES…]      (needs numpy)

RUN_DIR is a run whose evaluation wrote particles (`eval.write_ply`); the scene is the one its
`config.resolved.toml` names (`scene.path`). The twenty-eighth session read honey's thinner pile
from this (BENCHMARKS.md).
"""
import json
import os
import re
import sys

import numpy as np


def ply(path):
    data = open(path, "rb").read()
    start = data.index(b"end_header\n") + len(b"end_header\n")
    return np.frombuffer(data[start:], dtype="<f4").reshape(-1, 3)


def neighbours(points, reach):
    d2 = ((points[:, None, :] - points[None, :, :]) ** 2).sum(-1)
    return (d2 < reach * reach).sum(1) - 1


def main():
    run = sys.argv[1]
    frames = [int(f) for f in sys.argv[2:]] or [0, 5, 10, 15, 20, 25, 30, 40, 49, 59]
    config = open(os.path.join(run, "config.resolved.toml"), encoding="utf-8").read()
    scene_dir = re.search(r'^path = "(.*)"', config, re.M).group(1)
    scene = json.load(open(os.path.join(scene_dir, "scene.json"), encoding="utf-8"))
    up = "xyz".index(scene["up_axis"])
    radius = scene["particle_radius"]
    view = scene["test"]["views"][0]

    def truth(t):
        return np.load(os.path.join(scene_dir, view, "test", "particles", f"{t:04d}.npz"))["pos"]

    floor = scene["box_interior"]["min"][up]
    print("| t | truth: mean / p90 height, rms radius, neighbours | DLF | NeuroFluid |")
    print("|---:|---|---|---|")
    for t in frames:
        sequences = [truth(t)] + [
            ply(os.path.join(run, "eval", "particles", f"{m}_{t:04d}.ply"))
            for m in ("dlf", "neurofluid")
        ]
        centre = np.delete(sequences[0].mean(0), up)
        cells = []
        for p in sequences:
            h = p[:, up] - floor
            across = np.delete(p, up, 1) - centre
            n = neighbours(p, 4 * radius)
            cells.append(
                f"{h.mean():.3f} / {np.percentile(h, 90):.3f} m, {np.sqrt((across ** 2).sum(1).mean()):.3f} m, "
                f"{n.mean():.1f} ({np.percentile(n, 10):.0f})"
            )
        print(f"| {t} | " + " | ".join(cells) + " |")


if __name__ == "__main__":
    main()
