#!/usr/bin/env python3
"""The silhouette objective of `[joint.physics.search]` scored on the true particles themselves
(issue 71, P9; docs/notebook/2026-12-06-image-landscape.md): the mean over training frames 1–49
of 1 − IoU between the training view's fluid pixels (alpha above 2 %) and the pixels the true
particles cover once projected (each a disc of the particle radius × SCALE + 1 px, as
`ray_focus::mark_particles` with SCALE 1). Compared with the search's scores of the rollouts
(the `joint-search` rows), it says whether the objective ranks the truth above them, and how
the disc's size moves it.

    /work/bedenv/bin/python experiments/research/reference/truth-silhouette.py SCENE [SCALE ...]

Since ed03b6a the search itself scores the true particles (its `joint-search-truth` row), which
is the reference for SCALE 1: on water-tank-rest-y the two agree (0.0416 against this script's
0.042); on water-pool-rest-z the search gives 0.0129 where this script gave 0.037 (the grid's
best 0.044 in both), a difference not traced; the rankings agree.
"""

import json
import math
import os
import sys

import numpy as np
from PIL import Image

RADIUS = 0.025


def camera(meta, frame, width, height):
    c2w = np.array(frame["transform_matrix"], dtype=np.float64)
    if "fl_x" in meta or "fl_x" in frame:
        src = frame if "fl_x" in frame else meta
        fx, fy, cx, cy = src["fl_x"], src.get("fl_y", src["fl_x"]), src["cx"], src["cy"]
    else:
        fx = fy = 0.5 * width / math.tan(0.5 * meta["camera_angle_x"])
        cx, cy = width / 2, height / 2
    return c2w, fx, fy, cx, cy


def covered(pos, cam, width, height, scale):
    c2w, fx, fy, cx, cy = cam
    c = (pos - c2w[:3, 3]) @ c2w[:3, :3]
    depth = -c[:, 2]
    ok = depth > 0
    col = fx * c[ok, 0] / depth[ok] + cx
    row = -fy * c[ok, 1] / depth[ok] + cy
    r = max(fx, fy) * RADIUS * scale / depth[ok] + 1.0
    ys, xs = np.mgrid[0:height, 0:width]
    mask = np.zeros((height, width), bool)
    for x0, y0, rr in zip(col, row, r):
        a, b = int(max(0, math.floor(y0 - rr))), int(min(height - 1, math.ceil(y0 + rr)))
        e, f = int(max(0, math.floor(x0 - rr))), int(min(width - 1, math.ceil(x0 + rr)))
        if a > b or e > f:
            continue
        sub = (xs[a:b + 1, e:f + 1] - x0) ** 2 + (ys[a:b + 1, e:f + 1] - y0) ** 2 <= rr * rr
        mask[a:b + 1, e:f + 1] |= sub
    return mask


def main():
    scene = sys.argv[1]
    scales = [float(s) for s in sys.argv[2:]] or [1.0]
    root = os.path.join(os.environ.get("BED_DATA", "data/bed-particles"), scene)
    train = json.load(open(os.path.join(root, "scene.json")))["train"]
    view = os.path.join(root, train["views"][0])
    meta = json.load(open(os.path.join(view, f"transforms_{train['split']}.json")))
    frames = sorted(meta["frames"], key=lambda f: f["time"])[1:50]
    for scale in scales:
        dist = []
        for fr in frames:
            name = fr["file_path"][2:] if fr["file_path"].startswith("./") else fr["file_path"]
            img = np.asarray(Image.open(os.path.join(view, name if name.endswith(".png") else name + ".png")))
            h, w = img.shape[:2]
            fluid = img[..., 3] / 255.0 > 0.02
            # the particles' path is relative to the image's folder
            pos = np.load(os.path.join(view, os.path.dirname(name), fr["particle_path"]))["pos"]
            cov = covered(pos, camera(meta, fr, w, h), w, h, scale)
            union = (cov | fluid).sum()
            dist.append(1.0 - (cov & fluid).sum() / union if union else 0.0)
        print(f"{scene}: the truth's silhouette distance, disc radius × {scale}: {np.mean(dist):.4f}")


if __name__ == "__main__":
    main()
