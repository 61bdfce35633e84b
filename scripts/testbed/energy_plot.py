#!/usr/bin/env python3
"""E(t), the mechanical energy per kilogram of the truth, the pretrained DLF and each run's
NeuroFluid over the test frames, one panel per scene (docs/energy.png):

    python3 scripts/testbed/energy_plot.py [--per-particle] OUT.png SCENE_DIR LABEL=RUN \
        [LABEL=RUN ...] [-- SCENE_DIR LABEL=RUN ...]

Needs numpy and matplotlib; reads the runs' eval/particles/*.ply (eval.write_ply). E_t is
energy_gains.py's: mean(½|v|² + g·height), v = (x_t − x_{t−1}) · fps; the truth and DLF are
read from the first run of each panel. With --per-particle, each curve is instead the energy
gained per particle up to frame t: the sum over steps of the mean of each particle's own gain
(docs/particle-energy.png; flat at 0 where no particle gains, as in a viscous fluid).
"""

import glob
import json
import os
import sys

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from energy_gains import particle_energies  # noqa: E402
from spray_diagnosis import read_ply, truth  # noqa: E402


PER_PARTICLE = False


def energies(frames, fps, up):
    """E_t for t ≥ 1, or with --per-particle the per-particle gain accumulated up to t."""
    each = particle_energies(frames, fps, up)
    if not PER_PARTICLE:
        return each.mean(1)
    gains = np.clip(np.diff(each, axis=0), 0.0, None).mean(1)
    return np.concatenate([[0.0], np.cumsum(gains)])


def panel(ax, scene, runs):
    meta = json.load(open(os.path.join(scene, "scene.json")))
    up = {"x": 0, "y": 1, "z": 2}[meta.get("up_axis", "y")]
    fps = meta.get("fps", 50.0)
    first = runs[0][1]
    n = len(glob.glob(os.path.join(first, "eval", "particles", "dlf_*.ply")))
    ply = lambda run, model: [read_ply(os.path.join(run, "eval", "particles", f"{model}_{t:04d}.ply")).astype(np.float64) for t in range(n)]
    t = np.arange(1, n)
    ax.plot(t, energies([truth(scene, k).astype(np.float64) for k in range(n)], fps, up), "k-", lw=2, label="truth")
    ax.plot(t, energies(ply(first, "dlf"), fps, up), "k--", lw=1.2, label="DLF (pretrained)")
    for label, run in runs:
        ax.plot(t, energies(ply(run, "neurofluid"), fps, up), lw=1.4, label=f"NeuroFluid, {label}")
    ax.axvline(49.5, color="grey", lw=0.8, ls=":")
    ax.set_title(meta.get("name", os.path.basename(scene)))
    ax.set_xlabel("frame t (training frames < 50)")
    ax.set_ylabel("energy gained per particle up to t (J/kg)" if PER_PARTICLE
                  else "E (J/kg): ½|v|² + g·height")
    ax.legend(fontsize=7)


def main():
    global PER_PARTICLE
    args = sys.argv[1:]
    if args and args[0] == "--per-particle":
        PER_PARTICLE, args = True, args[1:]
    out, rest = args[0], args[1:]
    groups, cur = [], []
    for a in rest:
        if a == "--":
            groups.append(cur)
            cur = []
        else:
            cur.append(a)
    groups.append(cur)
    fig, axes = plt.subplots(1, len(groups), figsize=(5.2 * len(groups), 4.0), squeeze=False)
    for ax, g in zip(axes[0], groups):
        panel(ax, g[0], [tuple(a.split("=", 1)) for a in g[1:]])
    fig.tight_layout()
    fig.savefig(out, dpi=110)
    print(out)


if __name__ == "__main__":
    main()
