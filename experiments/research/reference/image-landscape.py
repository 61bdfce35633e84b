#!/usr/bin/env python3
"""Probe P7 (issue 71; docs/notebook/2026-12-06-image-landscape.md): where the training view's
image loss puts the gravity scale and the bodies'-frame dissipation, against where the truth
does, on scalar-scan.sh's grid.

    python3 experiments/research/reference/image-landscape.py [--grids]

Reads runs/land/<scene>-s<seed>[...]/ (image-landscape.sh: I, the mean image loss over the 49
transitions at each point) and runs/ref/<scene>-scan-body/ (FRAME=body scalar-scan.sh: CD over
t < 50 at each point), D and R_S as quick-table.py reads them. --grids also prints each
landscape as a gravity × dissipation table.
"""

import csv
import importlib.util
import os
import re
import statistics
import sys

_spec = importlib.util.spec_from_file_location(
    "quick_table", os.path.join(os.path.dirname(__file__), "quick-table.py"))
quick_table = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(quick_table)

TRANSITIONS = 49


def image_loss(run):
    """The mean logged loss over the joint epoch's transitions of a run folder (None unless it
    logged all of them)."""
    path = os.path.join(run, "metrics.csv")
    if not os.path.exists(path):
        return None
    rows = [r for r in csv.DictReader(open(path)) if r["stage"] == "joint"]
    if len(rows) != TRANSITIONS:
        return None
    return statistics.mean(float(r["loss"]) for r in rows)


def landscapes():
    """{(scene, seed, view suffix): {(gravity, dissipation) as the scan's file names: I}}."""
    out = {}
    root = "runs/land"
    for name in sorted(os.listdir(root)) if os.path.isdir(root) else []:
        m = re.fullmatch(r"(.+)-s(\d+)", name)
        if not m:
            continue
        for point in sorted(os.listdir(os.path.join(root, name))):
            p = re.fullmatch(r"g([0-9.]+)-d([0-9.]+)(-.+)?", point)
            i = image_loss(os.path.join(root, name, point)) if p else None
            if i is not None:
                out.setdefault((m.group(1), int(m.group(2)), p.group(3) or ""), {})[p.group(1), p.group(2)] = i
    return out


def ranks(values):
    """Ranks from 1 (ties share their mean rank)."""
    order = sorted(range(len(values)), key=lambda k: values[k])
    r = [0.0] * len(values)
    k = 0
    while k < len(order):
        j = k
        while j + 1 < len(order) and values[order[j + 1]] == values[order[k]]:
            j += 1
        for m in range(k, j + 1):
            r[order[m]] = (k + j) / 2 + 1
        k = j + 1
    return r


def spearman(a, b):
    ra, rb = ranks(a), ranks(b)
    ma, mb = statistics.mean(ra), statistics.mean(rb)
    num = sum((x - ma) * (y - mb) for x, y in zip(ra, rb))
    den = (sum((x - ma) ** 2 for x in ra) * sum((y - mb) ** 2 for y in rb)) ** 0.5
    return num / den if den else float("nan")


def share(d, cd, best):
    return (d - cd) / (d - best) if best is not None and d != best else None


def fmt(v):
    return "–" if v is None else f"{v:.2f}"


def main():
    grids = "--grids" in sys.argv
    print("| scene | seed | views | points | I* (image loss's best) | CD(I*) | P_B's point | CD(P_B) | "
          "rank of P_B's point on I | Spearman(I, CD) | D | R_S | g_P | g_S |")
    print("|---|---:|---|---:|---|---:|---|---:|---:|---:|---:|---:|---:|---:|")
    for (scene, seed, view), image in landscapes().items():
        truth = quick_table.scan_points(scene, "-body")
        common = [p for p in image if p in truth]
        if not common:
            continue
        cds = [truth[p]["cd"][0] for p in common]
        ims = [image[p] for p in common]
        i_star = min(common, key=lambda p: image[p])
        p_b = min(truth, key=lambda p: truth[p]["cd"][0])
        rank_pb = int(ranks(ims)[common.index(p_b)]) if p_b in common else None
        d = quick_table.rollout_scores(f"runs/ref/{scene}-D.log")
        r_s, _ = quick_table.mean_over_seeds(scene, "S1")
        d_cd = d["cd"][0]
        cd_star = truth[i_star]["cd"][0]
        cd_pb = truth[p_b]["cd"][0]
        print(f"| {scene} | {seed} | {1 + bool(view)}{view and ' (' + view[1:] + ')'} | {len(common)} | "
              f"g {i_star[0]}, d {i_star[1]} | {cd_star:.2f} | g {p_b[0]}, d {p_b[1]} | {cd_pb:.2f} | "
              f"{rank_pb or '–'} | {spearman(ims, cds):.2f} | {d_cd:.2f} | {fmt(r_s and r_s['cd'][0])} | "
              f"{fmt(share(d_cd, cd_star, cd_pb))} | {fmt(share(d_cd, cd_star, r_s and r_s['cd'][0]))} |")
        if grids:
            gs = sorted({g for g, _ in common}, key=float)
            ds = sorted({x for _, x in common}, key=float)
            print(f"\n{scene} seed {seed}{view}: I × 1000 (CD over t < 50) by gravity scale (rows) × dissipation\n")
            print("| g \\ d | " + " | ".join(ds) + " |")
            print("|---" * (len(ds) + 1) + "|")
            for g in gs:
                cells = [f"{1000 * image[g, x]:.3f} ({truth[g, x]['cd'][0]:.1f})" if (g, x) in common else "–"
                         for x in ds]
                print(f"| {g} | " + " | ".join(cells) + " |")
            print()


if __name__ == "__main__":
    main()
