#!/usr/bin/env python3
"""Novel views on the test bed (issue 34, item 4): NeuroFluid against NeRF-T in two protocols.

    python3 scripts/analysis/novel-views.py [experiments/research/bed/novel-views-runs.txt]

The runs file lists `scene seed shipped_run nerf_t_neurofluid_folder nerf_t_cycle_folder` per
line (`#` starts a comment). NeuroFluid's test-view scores (and, where the run was evaluated with
`eval.render_truth = true`, the renderer's on the true particles) come from the shipped run's
`eval/report.json`; each NeRF-T's from `<folder>/nerf-t/scores.json`, written by `baseline
nerf-t` with `nerf.t_images = "neurofluid"` (the images NeuroFluid trains on) or `"cycle"` (one
warm-up view per training frame, cycling through the four). A missing folder is shown as –.
Prints markdown: PSNR / SSIM / LPIPS over the report's two windows for every run, then PSNR per
scene as mean ± sd over seeds (with the count where a model has fewer seeds than NeuroFluid) and,
per window, whether NeuroFluid's mean is at least each NeRF-T's.
"""

import json
import os
import statistics
import sys

TRUTH = "PhysNeRF on the true particles"


def window_means(images, window):
    a, b = window
    inside = [i for i in images if a <= i["t"] <= b]
    if not inside:
        return None
    lp = [i["lpips"] for i in inside if i.get("lpips") is not None]
    return (
        statistics.mean(i["psnr"] for i in inside),
        statistics.mean(i["ssim"] for i in inside),
        statistics.mean(lp) if lp else None,
    )


def scores(folder):
    path = os.path.join(folder, "nerf-t", "scores.json")
    if not os.path.isfile(path):
        return None
    with open(path, encoding="utf-8") as f:
        return json.load(f)["images"]


def read_runs(path):
    rows = []
    for line in open(path, encoding="utf-8"):
        line = line.split("#", 1)[0].split()
        if not line:
            continue
        scene, seed, run, same, cycle = line
        with open(os.path.join(run, "eval", "report.json"), encoding="utf-8") as f:
            report = json.load(f)
        windows = [tuple(report["windows"]["grounding"]), tuple(report["windows"]["prediction"])]
        truth = next((b["images"] for b in report.get("nvs_baselines", []) if b["model"] == TRUTH), None)
        models = {
            "NeuroFluid": report["images"],
            "renderer on the truth": truth,
            "NeRF-T (NeuroFluid's images)": scores(same),
            "NeRF-T (cycle)": scores(cycle),
        }
        means = {m: [window_means(i, w) if i else None for w in windows] for m, i in models.items()}
        rows.append((scene, int(seed), means))
    return rows


def fmt(m):
    if m is None:
        return "–"
    p, s, l = m
    return f"{p:.2f} / {s:.3f} / {'–' if l is None else f'{l:.3f}'}"


def main():
    path = sys.argv[1] if len(sys.argv) > 1 else "experiments/research/bed/novel-views-runs.txt"
    rows = read_runs(path)
    models = list(rows[0][2])
    print("PSNR / SSIM / LPIPS on the test view, t < 50 | t ≥ 50\n")
    print("| scene | seed | " + " | ".join(models) + " |")
    print("|---|---|" + "---|" * len(models))
    for scene, seed, means in rows:
        cells = [f"{fmt(means[m][0])} ‖ {fmt(means[m][1])}" for m in models]
        print(f"| {scene} | {seed} | " + " | ".join(cells) + " |")
    print("\nPSNR, mean ± sd over seeds (t < 50 / t ≥ 50); ✓ where NeuroFluid's mean is at least the NeRF-T's\n")
    print("| scene | seeds | " + " | ".join(models) + " |")
    print("|---|---|" + "---|" * len(models))
    for scene in dict.fromkeys(r[0] for r in rows):
        runs = [r for r in rows if r[0] == scene]

        def stat(model, w):
            v = [r[2][model][w][0] for r in runs if r[2][model][w] is not None]
            if not v:
                return None, "–"
            sd = f" ± {statistics.stdev(v):.2f}" if len(v) > 1 else ""
            seeds = f" ({len(v)} seed{'s' * (len(v) > 1)})" if len(v) < len(runs) else ""
            return statistics.mean(v), f"{statistics.mean(v):.2f}{sd}{seeds}"

        cells = []
        for m in models:
            parts = []
            for w in (0, 1):
                value, text = stat(m, w)
                mine, _ = stat("NeuroFluid", w)
                if m.startswith("NeRF-T") and value is not None and mine is not None:
                    text += " ✓" if mine >= value else " ✗"
                parts.append(text)
            cells.append(" / ".join(parts))
        print(f"| {scene} | {len(runs)} | " + " | ".join(cells) + " |")


if __name__ == "__main__":
    main()
