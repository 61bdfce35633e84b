#!/usr/bin/env python3
"""The renderer chosen on the validation views (experiments/bed/README.md rules 18 and 19).

    python3 scripts/analysis/validation-table.py [experiments/research/bed/validation-runs.txt]
    python3 scripts/analysis/validation-table.py experiments/research/bed/validation-builtin-runs.txt   # rule 19

The runs file lists `scene seed candidate run validation_copy` per line (`#` starts a comment);
each validation copy was evaluated by experiments/research/bed/validation-evals.sh (`eval.novel_views =
"validation"`), candidate A's with NeRF-T too. Prints markdown: per scene, seed and candidate,
PSNR / SSIM / LPIPS over t < 50 on the validation views (both together; each view's PSNR after),
the renderer on the true particles there, NeRF-T's; the test view over both windows from the
candidate's own run where it evaluated that renderer (reported, never used); then the rule: at
seed 10, per material, the candidate highest on every scene of the material; over the seeds
10-12, each candidate's mean PSNR per scene, against A's.
"""

import importlib.util
import json
import os
import sys

HERE = os.path.dirname(os.path.abspath(__file__))
_spec = importlib.util.spec_from_file_location("novel_views", os.path.join(HERE, "novel-views.py"))
novel_views = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(novel_views)
window_means, TRUTH = novel_views.window_means, novel_views.TRUTH

MATERIAL = {"water-dam-z": "water", "water-torus-tilted-z": "water", "honey-drop-z": "honey",
            "water-sphere-y": "water", "honey-slump-y-400": "honey",
            "watercube": "water", "watersphere": "water", "waterbunny": "water", "honeycone": "honey"}


def read(path):
    with open(path) as f:
        return json.load(f)


def fmt(m):
    if m is None:
        return "–"
    p, s, lp = m
    return f"{p:.2f} / {s:.3f} / {lp:.3f}" if lp is not None else f"{p:.2f} / {s:.3f}"


def main():
    runs_file = sys.argv[1] if len(sys.argv) > 1 else "experiments/research/bed/validation-runs.txt"
    rows = []
    with open(runs_file) as f:
        for line in f:
            line = line.split("#", 1)[0].split()
            if line:
                rows.append(line)  # scene seed candidate run copy
    val_psnr = {}  # (scene, seed, candidate) -> PSNR over t < 50 on the validation views
    nerf_t_psnr = {}  # (scene, seed) -> NeRF-T's
    print("| scene | seed | renderer | validation views, t < 50: PSNR / SSIM / LPIPS | each view's PSNR (view_6 ‖ view_7 …) | "
          "the renderer on the true particles | NeRF-T (NeuroFluid's images) | test view PSNR, t < 50 ‖ t ≥ 50 |")
    print("|---|---|---|---|---|---|---|---|")
    for scene, seed, cand, run, copy in rows:
        path = os.path.join(copy, "eval", "report.json")
        if not os.path.isfile(path):
            print(f"| {scene} | {seed} | {cand} | – | – | – | – | – |")
            continue
        rep = read(path)
        assert rep.get("validation_views"), f"{path} did not score the validation views"
        g = rep["windows"]["grounding"]
        ours = window_means(rep["images"], g)
        views = sorted({i["view"] for i in rep["images"]})
        per_view = " ‖ ".join(f"{window_means([i for i in rep['images'] if i['view'] == v], g)[0]:.2f}"
                              for v in views)
        base = {b["model"]: b["images"] for b in rep["nvs_baselines"]}
        truth = window_means(base[TRUTH], g) if TRUTH in base else None
        nerf_t = next((window_means(im, g) for m, im in base.items() if m.startswith("NeRF-T")), None)
        test = read(os.path.join(run, "eval", "report.json"))
        test_cell = "–"
        if bool(test.get("renderer")) == (cand != "A"):  # the run's own evaluation is this renderer's
            tw = [window_means(test["images"], test["windows"][w]) for w in ("grounding", "prediction")]
            test_cell = " ‖ ".join(f"{m[0]:.2f}" for m in tw)
        val_psnr[(scene, seed, cand)] = ours[0]
        if nerf_t:
            nerf_t_psnr[(scene, seed)] = nerf_t[0]
        print(f"| {scene} | {seed} | {cand} | {fmt(ours)} | {per_view} | {fmt(truth)} | {fmt(nerf_t)} | {test_cell} |")

    print()
    materials = {}
    for (scene, seed, cand), p in val_psnr.items():
        if seed == "10":
            materials.setdefault(MATERIAL[scene], {}).setdefault(scene, {})[cand] = p
    for material, scenes in sorted(materials.items()):
        best = {s: max(c, key=c.get) for s, c in scenes.items()}
        winners = set(best.values())
        verdict = (f"**{winners.pop()}** is highest on every {material} scene"
                   if len(winners) == 1 else f"no candidate is highest on every {material} scene (A stays)")
        detail = ", ".join(f"{s}: {b} ({scenes[s][b]:.2f} dB)" for s, b in sorted(best.items()))
        print(f"- seed 10, {material}: {verdict} — {detail}")
    print()
    seeds = ("10", "11", "12")
    for scene in dict.fromkeys(r[0] for r in rows):
        cands = sorted({c for (s_, _, c) in val_psnr if s_ == scene})
        means = {c: sum(val_psnr[(scene, s, c)] for s in seeds) / 3 for c in cands
                 if all((scene, s, c) in val_psnr for s in seeds)}
        if "A" not in means or len(means) < 2:
            continue
        nt = ([nerf_t_psnr[(scene, s)] for s in seeds if (scene, s) in nerf_t_psnr])
        nt_cell = f"; NeRF-T {sum(nt) / len(nt):.2f}" if len(nt) == 3 else ""
        cells = ", ".join(f"{c} {m:.2f}" + ("" if c == "A" else (" (higher than A)" if m > means["A"] else " (not higher than A)"))
                          for c, m in sorted(means.items()))
        print(f"- seeds 10-12, {scene}, mean PSNR on the validation views over t < 50: {cells}{nt_cell}")


if __name__ == "__main__":
    main()
