#!/usr/bin/env python3
"""The bed's landscapes of the physical scalars (issue 71; docs/notebook/2026-12-06-bed-reference.md):
(d + d′)/2 over t < 50 of the pretrained DLF under the walls on a grid of the gravity scale and the
dissipation, in the box's frame and in the bodies' frame, per scene, with the grid's best point
(P, P_B) starred and the levels of D (the paper's scalars) and DLF† (R_S, where run) in the title.

    python3 scripts/analysis/scalar-landscapes.py [--out docs/scalar-landscapes.png]

Reads runs/ref/<scene>-scan[-body]/ (experiments/research/reference/scalar-scan.sh) and the S1
rollouts of experiments/research/reference/quick-reference.sh; needs matplotlib.
"""

import argparse
import importlib.util
import os
import statistics

HERE = os.path.dirname(__file__)
_spec = importlib.util.spec_from_file_location(
    "quick_table", os.path.join(HERE, "..", "..", "experiments", "research", "reference", "quick-table.py"))
quick_table = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(quick_table)

FRAMES = [("", "box frame"), ("-body", "bodies' frame")]


def grid(scene, frame):
    """The gravity scales and dissipations rolled out (as the file names write them, in
    increasing order) and CD over t < 50 as rows of gravity × columns of dissipation (None where
    a point is missing)."""
    points = quick_table.scan_points(scene, frame)
    gravity = sorted({g for g, _ in points}, key=float)
    dissipation = sorted({d for _, d in points}, key=float)
    rows = [[points[g, d]["cd"][0] if (g, d) in points else None for d in dissipation] for g in gravity]
    return gravity, dissipation, rows


def dagger(scene):
    """The mean CD over t < 50 of the S1 seeds run, and how many."""
    runs = [quick_table.candidate(scene, "S1", s) for s in quick_table.SEEDS]
    done = [r["cd"][0] for r in runs if r]
    return (statistics.mean(done), len(done)) if done else (None, 0)


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", default="docs/scalar-landscapes.png")
    args = ap.parse_args()

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    scenes = quick_table.BED["scenes"]
    fig, axes = plt.subplots(4, 4, figsize=(16, 15.5))
    for k, scene in enumerate(scenes):
        d_run = quick_table.rollout_scores(f"runs/ref/{scene}-D.log")
        r_s, n = dagger(scene)
        for j, (frame, label) in enumerate(FRAMES):
            ax = axes[k // 2][2 * (k % 2) + j]
            gravity, dissipation, values = grid(scene, frame)
            flat = [v for row in values for v in row if v is not None]
            if not flat:
                ax.set_axis_off()
                continue
            lo = min(flat)
            # colour up to 2× the best, so the scene's good region is readable
            shown = [[min(v, 2 * lo) if v is not None else float("nan") for v in row] for row in values]
            ax.imshow(shown, cmap="viridis_r", origin="lower", aspect="auto")
            # dark text on the light (low) half of the colour scale, light text on the rest
            middle = (lo + min(max(flat), 2 * lo)) / 2
            for a, row in enumerate(values):
                for b, v in enumerate(row):
                    if v is None:
                        continue
                    best = v == lo
                    ax.text(b, a, f"{v:.1f}{'★' if best else ''}", ha="center", va="center", fontsize=7.5,
                            color="black" if v < middle else "white", fontweight="bold" if best else None)
            ax.set_xticks(range(len(dissipation)), dissipation, fontsize=8)
            ax.set_yticks(range(len(gravity)), gravity, fontsize=8)
            ax.set_xlabel(f"dissipation ({label})", fontsize=8)
            ax.set_ylabel("gravity scale", fontsize=8)
            dlf = f"D {d_run['cd'][0]:.1f}" if d_run else ""
            ref = f", DLF† {r_s:.1f} ({n} seed{'s' if n != 1 else ''})" if r_s else ""
            ax.set_title(f"{scene}\n{dlf}{ref}", fontsize=9)
    fig.suptitle("(d + d′)/2 over t < 50 of the pretrained DLF under the walls, the scalars set "
                 "(★ the grid's best: P, P_B)", fontsize=11)
    fig.tight_layout(rect=(0, 0, 1, 0.98))
    fig.savefig(args.out, dpi=80)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
