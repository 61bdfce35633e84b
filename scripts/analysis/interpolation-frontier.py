#!/usr/bin/env python3
"""d against d′ as NeuroFluid's DLF moves from the pretrained weights (fraction 0) to the grounded
ones (1) by `eval.weight_interpolation`, per scene and joint-stage setting: the training window
(t < 50, what settings are chosen on) above, the prediction window (t ≥ 50, reported) below.

    python3 scripts/analysis/interpolation-frontier.py [--runs experiments/research/bed/interpolation-runs.txt]
        [--out docs/interpolation-frontier.png] [--table]

Reads runs/interpolation/<name>/eval/report.json (scripts/analysis/interpolation-evals.sh); draws seed 10.
--table prints the figures as a markdown table instead of drawing them (needs only the standard
library; the drawing needs matplotlib).
"""

import argparse
import json
import os


def read(runs):
    """[(scene, setting, seed, [(fraction, {window: (d, d′)})])] in the file's order."""
    out = []
    for line in open(runs):
        if not line.strip() or line.startswith("#"):
            continue
        scene, setting, seed, name, _source = line.split()
        path = os.path.join("runs", "interpolation", name, "eval", "report.json")
        if not os.path.isfile(path):
            print(f"missing {path}: scripts/analysis/interpolation-evals.sh makes it")
            continue
        points = [
            (p["fraction"], {"grounding": tuple(p["grounding"]),
                             "prediction": tuple(p["prediction"])})
            for p in json.load(open(path))["interpolation"]
        ]
        out.append((scene, setting, int(seed), points))
    return out


def table(data):
    print("| scene | joint setting | seed | fraction | d t<50 | d′ t<50 | d t≥50 | d′ t≥50 |")
    print("|---|---|---:|---:|---:|---:|---:|---:|")
    for scene, setting, seed, points in data:
        for fraction, m in points:
            g, p = m["grounding"], m["prediction"]
            print(f"| {scene} | {setting} | {seed} | {fraction:g} | {g[0]:.2f} | {g[1]:.2f} | "
                  f"{p[0]:.2f} | {p[1]:.2f} |")


def draw(data, out):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.lines
    import matplotlib.pyplot as plt

    data = [d for d in data if d[2] == 10]
    scenes = list(dict.fromkeys(s for s, *_ in data))
    fig, axes = plt.subplots(2, len(scenes), figsize=(3.1 * len(scenes), 6.4), squeeze=False)
    colours = {"no-anchor": "tab:blue", "anchor-0.1": "tab:orange", "anchor-depth": "tab:green"}
    for col, scene in enumerate(scenes):
        for row, (window, title) in enumerate(
            [("grounding", "t < 50 (choosing)"), ("prediction", "t ≥ 50 (reported)")]
        ):
            ax = axes[row][col]
            dlf = None
            for s, setting, _seed, points in data:
                if s != scene or not points:
                    continue
                xs = [m[window][0] for _, m in points]
                ys = [m[window][1] for _, m in points]
                c = colours.get(setting, "tab:gray")
                ax.plot(xs, ys, "-o", color=c, ms=3, lw=1.2, label=setting)
                ax.plot(xs[-1:], ys[-1:], "s", color=c, ms=6)  # as trained
                for (f, _m), x, y in zip(points, xs, ys):
                    if f in (0.25, 0.5, 0.75):
                        ax.annotate(f"{f:g}", (x, y), fontsize=6, xytext=(2, 2),
                                    textcoords="offset points", color=c)
                dlf = points[0][1][window] if points[0][0] == 0 else None
            if dlf:
                target = 0.7 if "honey" in scene.lower() else 0.9
                ax.axhline(dlf[1], color="k", lw=0.8, ls="--")
                ax.axvline(dlf[0] * target, color="k", lw=0.6, ls=":")
                ax.plot([dlf[0]], [dlf[1]], "k*", ms=9)
            ax.set_title(f"{scene}\n{title}", fontsize=8)
            ax.tick_params(labelsize=7)
            ax.set_xlabel("d", fontsize=8)
            if col == 0:
                ax.set_ylabel("d′ (spray)", fontsize=8)
    handles = [matplotlib.lines.Line2D([], [], color=c, marker="o", ms=3, label=k)
               for k, c in colours.items()]
    fig.legend(handles=handles, loc="upper right", fontsize=7, title="joint stage", title_fontsize=7)
    fig.suptitle(
        "NeuroFluid's DLF from the pretrained weights (★, fraction 0) to the grounded ones (■, 1):"
        " d against d′; dashed: DLF's d′; dotted: the d target (10 % below DLF's, 30 % on honey)",
        fontsize=9)
    fig.tight_layout(rect=(0, 0, 0.95, 1))
    fig.savefig(out, dpi=110)
    print(f"wrote {out}")


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", default="experiments/research/bed/interpolation-runs.txt")
    ap.add_argument("--out", default="docs/interpolation-frontier.png")
    ap.add_argument("--table", action="store_true")
    a = ap.parse_args()
    data = read(a.runs)
    if a.table:
        table(data)
    else:
        draw(data, a.out)


if __name__ == "__main__":
    main()
