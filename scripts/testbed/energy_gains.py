#!/usr/bin/env python3
"""The mechanical energy a run's rollouts and the truth gain, from the particle files alone: per
kilogram, E_t = mean(½|v|² + g·height), v = (x_t − x_{t−1}) · fps, and the gain of a window the
sum of max(0, E_t − E_{t−1}) over its steps t ≥ 2; per particle, the mean over particles of each
one's own gains (the evaluation's own table, `eval/report.md`, for runs evaluated before it
existed). A fluid in a closed box only loses energy; in a viscous one, every particle does.

    python3 scripts/testbed/energy_gains.py RUN_DIR SCENE_DIR

Needs numpy; reads RUN_DIR/eval/particles/{dlf,neurofluid}_TTTT.ply (eval.write_ply) and
SCENE_DIR/<test view>/test/particles/TTTT.npz; the windows are t = 2–49 and 50–59.
"""

import glob
import json
import os
import sys

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from spray_diagnosis import read_ply, truth  # noqa: E402


def particle_energies(x, fps, up):
    """Each particle's ½|v|² + g·height at frames t = 1 … (rows), v = (x_t − x_{t−1}) · fps, of
    the positions x (a list of (N, 3) arrays; particle i the same in every frame)."""
    return np.array([
        0.5 * (((x[t] - x[t - 1]) * fps) ** 2).sum(1) + 9.81 * x[t][:, up]
        for t in range(1, len(x))
    ])


def main():
    run, scene = sys.argv[1], sys.argv[2]
    meta = json.load(open(os.path.join(scene, "scene.json")))
    up = {"x": 0, "y": 1, "z": 2}[meta.get("up_axis", "y")]
    fps = meta.get("fps", 50.0)
    frames = len(glob.glob(os.path.join(run, "eval", "particles", "dlf_*.ply")))

    def positions(model, t):
        if model == "truth":
            return truth(scene, t)
        return read_ply(os.path.join(run, "eval", "particles", f"{model}_{t:04d}.ply"))

    print(f"{run}: energy gained (J/kg), t = 2–49 | t = 50–59 | per particle, t = 2–49 | "
          f"t = 50–59 | E at t = 1, 49, 59")
    for model in ("truth", "dlf", "neurofluid"):
        x = [positions(model, t).astype(np.float64) for t in range(frames)]
        each = particle_energies(x, fps, up)
        energy = np.concatenate([[np.nan], each.mean(1)])
        gain = np.concatenate([[0.0, 0.0], np.clip(np.diff(energy[1:]), 0.0, None)])
        mine = np.concatenate([[0.0, 0.0], np.clip(np.diff(each, axis=0), 0.0, None).mean(1)])
        print(f"  {model:10s} {gain[2:50].sum():8.3f} | {gain[50:].sum():8.3f} | "
              f"{mine[2:50].sum():8.3f} | {mine[50:].sum():8.3f} | "
              f"{energy[1]:.2f}, {energy[49]:.2f}, {energy[-1]:.2f}")


if __name__ == "__main__":
    main()
