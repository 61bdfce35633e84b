#!/usr/bin/env python3
"""Where a run's spray is: for frames of the test view, the share of predicted particles farther
than three radii from every true particle ("far"), their share of d′, and how many of them are
sparse (the RMS distance to their K = 20 nearest predicted particles above the largest of the
true first frame, so PhysNeRF's gate hides them) or dense (fluid put where the truth has none).

    python3 scripts/testbed/spray_diagnosis.py RUN_DIR SCENE_DIR [--frames 25 49 59]

Needs numpy; reads RUN_DIR/eval/particles/{dlf,neurofluid}_TTTT.ply (eval.write_ply) and
SCENE_DIR/<test view>/test/particles/TTTT.npz.
"""

import argparse
import glob
import os

import numpy as np

K = 20
FAR = 0.075  # three radii of 0.025 m


def read_ply(path):
    data = open(path, "rb").read()
    end = data.index(b"end_header\n") + len(b"end_header\n")
    header = data[:end].split(b"\n")
    n = int(next(l for l in header if l.startswith(b"element vertex")).split()[-1])
    return np.frombuffer(data[end:end + 12 * n], dtype="<f4").reshape(n, 3)


def truth(scene, t):
    path = glob.glob(os.path.join(scene, "*", "test", "particles", f"{t:04d}.npz"))[0]
    return np.load(path)["pos"].reshape(-1, 3)


def spread(x):
    """RMS distance from each point to its K nearest others."""
    out = []
    for s in range(0, len(x), 512):
        d2 = ((x[s:s + 512, None, :] - x[None, :, :]) ** 2).sum(-1)
        d2 = np.sort(d2, axis=1)[:, 1:K + 1]
        out.append(np.sqrt(d2.mean(1)))
    return np.concatenate(out)


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("run")
    ap.add_argument("scene")
    ap.add_argument("--frames", type=int, nargs="+", default=[25, 49, 59])
    a = ap.parse_args()
    tau = spread(truth(a.scene, 0)).max()
    print(f"tau (largest spread of the true first frame) = {tau:.4f} m")
    print("frame model       d'   far  far's share of d'  sparse among far")
    for t in a.frames:
        g = truth(a.scene, t)
        for model in ("dlf", "neurofluid"):
            x = read_ply(os.path.join(a.run, "eval", "particles", f"{model}_{t:04d}.ply"))
            d = np.sqrt(((x[:, None, :] - g[None, :, :]) ** 2).sum(-1).min(1))
            far = d > FAR
            sparse = spread(x) > tau
            share = d[far].sum() / d.sum()
            among = (sparse[far]).mean() if far.any() else 0.0
            print(f"{t:5d} {model:10s} {1000 * d.mean():6.1f} {far.mean():5.3f} {share:17.2f} {among:17.2f}")


if __name__ == "__main__":
    main()
