#!/usr/bin/env python3
"""The test bed's table over scenes × seeds (issue 34, item 6), from the runs' own reports.

    python3 scripts/bed-table.py [experiments/research/bed/table-runs.txt] [--reference FILE.toml]

The runs file lists `scene seed run_folder` per line (`#` starts a comment). Each run folder's
`eval/report.md` gives d and d′ over t = 1–49 and t = 50–59, (d + d′)/2, PSNR/SSIM/LPIPS, the
DLF (and, where evaluated with `eval.supervised_dlf`, DLF†) rows, the particles through the
walls and, where present, the share of particles alone, where the far particles lie, the
fluid's density relative to the first true frame (the truth's and NeuroFluid's) and the
novel-view table; its `metrics.csv` gives the warm-up's and the joint stage's seconds (the
largest `time_s` of each; a run whose warm-up was shared with the other variants of its sweep
shows that warm-up's) and the last `psnr_true` (the renderer on the true
particles of the training frames at the training view, the refit's where the run has one; rules
8 and 12 of experiments/bed/README.md).
With `--reference` (a frozen reference file, crates/neurofluid-outputs/src/reference.rs), the
per-scene table adds g = (CD_DLF − CD_NF) / (CD_DLF − CD_R), CD = (d + d′)/2, from the means over
the scene's seeds, per window (issue 71). Runs under rules also show the published DLF as the
paper steps it.
Prints markdown tables: every run; per scene the mean ± sd over seeds beside DLF and DLF†, with
the issue's targets checked per window (d at least 10 % below DLF's, on honey 30 % over t < 50;
d′ not above DLF's), for the supervised DLF† too; and the novel-view rows (NeuroFluid, NeRF-T, the renderer on the true
particles) of the runs whose report has them.
"""

import csv
import os
import statistics
import sys


def cells(line):
    return [c.strip() for c in line.strip().strip("|").split("|")]


def report_rows(path):
    """{label: [floats or None]} of the report's tables (d, d′, novel views, particles alone and
    far particles in percent), and the walls line."""
    first, second, views, alone, far, density = {}, {}, {}, {}, {}, {}
    table = None
    walls = None
    for line in open(path, encoding="utf-8"):
        if line.startswith("Particles through the walls"):
            walls = line.split("NeuroFluid")[1].strip(" .\n")
        if line.startswith("| sequence | particles alone"):
            table = alone
            continue
        if line.startswith("| sequence | density"):
            table = density
            continue
        if line.startswith("| rollout | far"):
            table = far
            continue
        if line.startswith("| model |"):
            # each table is known by its first column after the model's
            head = cells(line)[1]
            table = (
                first if head.startswith("d_avg")
                else second if head.startswith("d′")
                else views if head.startswith("PSNR")
                else None  # the novel views' error split (MSE on the fluid and around it)
            )
            continue
        if table is None or not line.startswith("| ") or line.startswith("|---"):
            continue
        c = cells(line)
        if c[0] == "view":
            break
        try:
            vals = [None if v in ("–", "") else float(v.removesuffix(" %")) for v in c[1:]]
        except ValueError:
            # the head of a table this script does not read (the energy table, …)
            table = None
            continue
        # the published DLF as the paper steps it has its own row beside the DLF under the rules
        label = PAPER_STEP if "paper's step" in c[0] else c[0].split(" (")[0]
        table[label] = vals
    return first, second, views, alone, far, density, walls


PAPER_STEP = "DLF, paper's step"


def stage_log(path):
    """The warm-up's and the joint stage's seconds, and the last `psnr_true` of the renderer the
    views are rendered with: the refit's where the run has one (`refit.enabled`), else the joint
    stage's."""
    most, psnr_true = {}, {}
    with open(path, newline="", encoding="utf-8") as f:
        for row in csv.DictReader(f):
            stage, t = row["stage"], row.get("time_s") or ""
            if stage in ("warmup", "warmup-preview", "joint", "joint-preview") and t:
                key = stage.split("-")[0]
                most[key] = max(most.get(key, 0.0), float(t))
            key = stage.split("-")[0]
            if key in ("joint", "refit") and stage != key and row.get("psnr_true"):
                psnr_true[key] = float(row["psnr_true"])
    return most.get("warmup"), most.get("joint"), psnr_true.get("refit", psnr_true.get("joint"))


def load(runs_file):
    runs = []
    for line in open(runs_file, encoding="utf-8"):
        line = line.split("#")[0].strip()
        if not line:
            continue
        scene, seed, folder = line.split()
        report = os.path.join(folder, "eval", "report.md")
        if not os.path.exists(report):
            print(f"<!-- {scene} seed {seed}: no {report} yet -->")
            continue
        first, second, views, alone, far, density, walls = report_rows(report)
        warm, joint, psnr_true = stage_log(os.path.join(folder, "metrics.csv"))
        runs.append(
            dict(
                scene=scene,
                seed=int(seed),
                first=first,
                second=second,
                views=views,
                alone=alone,
                far=far,
                density=density,
                walls=walls,
                warm=warm,
                joint=joint,
                psnr_true=psnr_true,
            )
        )
    return runs


def f1(v):
    return "–" if v is None else f"{v:.1f}"


def f2(v):
    return "–" if v is None else f"{v:.2f}"


def f3(v):
    return "–" if v is None else f"{v:.3f}"


def f4(v):
    return "–" if v is None else f"{v:.4f}"


def f0(v):
    return "–" if v is None else f"{v:.0f}"


def msd(vs):
    vs = [v for v in vs if v is not None]
    if not vs:
        return "–"
    if len(vs) == 1:
        return f"{vs[0]:.2f}"
    return f"{statistics.mean(vs):.2f} ± {statistics.stdev(vs):.2f}"


def targets(honey, dlf, dlfp, firsts, seconds):
    """Item 3's marks per window for the given rows (every row must meet them): d at least 10 %
    below DLF's (30 % on honey over t < 50), d′ not above DLF's."""
    ok = []
    for w, col in (("t<50", 0), ("t≥50", 2)):
        cut = 0.7 if honey and col == 0 else 0.9
        d_ok = all(row[col] <= cut * dlf[col] for row in firsts)
        dp_ok = all(row[col] <= dlfp[col] for row in seconds)
        ok.append(f"{w}: {'✓' if d_ok else '✗'} {'✓' if dp_ok else '✗'}")
    return "; ".join(ok)


def gap_share(dlf, nf, ref):
    """g = (D − NF) / (D − R); None where R is not below D."""
    if dlf is None or nf is None or ref is None or dlf - ref <= 0:
        return None
    return (dlf - nf) / (dlf - ref)


def main():
    args = sys.argv[1:]
    reference = None
    if "--reference" in args:
        k = args.index("--reference")
        import tomllib
        with open(args[k + 1], "rb") as f:
            reference = tomllib.load(f)["scenes"]
        args = args[:k] + args[k + 2:]
    runs_file = args[0] if args else "experiments/research/bed/table-runs.txt"
    runs = load(runs_file)
    print("| scene | seed | d (t<50 / t≥50) | d′ (t<50 / t≥50) | (d+d′)/2 (t<50 / t≥50) | PSNR / SSIM / LPIPS | through walls | alone % (t<50 / t≥50) | far % beside / above / within (t<50) | density, truth / NF (t<50) | renderer on the truth, training view (dB) | warm-up / joint s |")
    print("|---|---:|---|---|---|---|---:|---|---|---|---:|---|")
    for r in runs:
        nf, nfp = r["first"]["NeuroFluid"], r["second"]["NeuroFluid"]
        al = r["alone"].get("NeuroFluid", [None, None])
        fa = r["far"].get("NeuroFluid", [None] * 8)
        de = [r["density"].get(m, [None])[0] for m in ("truth", "NeuroFluid")]
        print(
            f"| {r['scene']} | {r['seed']} | {f2(nf[0])} / {f2(nf[2])} | {f2(nfp[0])} / {f2(nfp[2])} | "
            f"{f2(nfp[4])} / {f2(nfp[5])} | {f2(nf[4])} / {f4(nf[5])} / {f4(nf[6])} | "
            f"{r['walls'] or '–'} | {f2(al[0])} / {f2(al[1])} | {f1(fa[1])} / {f1(fa[2])} / {f1(fa[3])} | "
            f"{f3(de[0])} / {f3(de[1])} | {f2(r['psnr_true'])} | {f0(r['warm'])} / {f0(r['joint'])} |"
        )
    print()
    print("| scene | model | seeds | d (t<50) | d (t≥50) | d′ (t<50) | d′ (t≥50) | targets (d, d′ per window) |")
    print("|---|---|---:|---|---|---|---|---|")
    for scene in dict.fromkeys(r["scene"] for r in runs):
        rs = [r for r in runs if r["scene"] == scene]
        dlf, dlfp = rs[0]["first"]["DLF"], rs[0]["second"]["DLF"]
        honey = scene.startswith("honey")
        col = lambda table, i: [r[table]["NeuroFluid"][i] for r in rs]
        print(
            f"| {scene} | NeuroFluid | {len(rs)} | {msd(col('first', 0))} | {msd(col('first', 2))} | "
            f"{msd(col('second', 0))} | {msd(col('second', 2))} | "
            f"{targets(honey, dlf, dlfp, [r['first']['NeuroFluid'] for r in rs], [r['second']['NeuroFluid'] for r in rs])} |"
        )
        print(f"| {scene} | DLF (pretrained) | – | {f2(dlf[0])} | {f2(dlf[2])} | {f2(dlfp[0])} | {f2(dlfp[2])} | |")
        if PAPER_STEP in rs[0]["first"]:
            a, b = rs[0]["first"][PAPER_STEP], rs[0]["second"][PAPER_STEP]
            print(f"| {scene} | DLF (published, the paper's step) | – | {f2(a[0])} | {f2(a[2])} | {f2(b[0])} | {f2(b[2])} | |")
        if reference is not None and scene in reference:
            ref = reference[scene]
            gs = []
            for w, col in (("t<50", 4), ("t≥50", 5)):
                nf_cd = statistics.mean(r["second"]["NeuroFluid"][col] for r in rs)
                g = gap_share(rs[0]["second"]["DLF"][col], nf_cd, ref["grounding" if col == 4 else "prediction"])
                gs.append(f"{w}: {f2(g)}")
            print(f"| {scene} | g (share of the way to the reference) | {len(rs)} | {'; '.join(gs)} | | | | |")
        dag = [r for r in rs if "DLF†" in r["first"]]
        if dag:
            a, b = dag[0]["first"]["DLF†"], dag[0]["second"]["DLF†"]
            print(
                f"| {scene} | DLF† (supervised, t<50) | – | {f2(a[0])} | {f2(a[2])} | {f2(b[0])} | {f2(b[2])} | "
                f"{targets(honey, dlf, dlfp, [a], [b])} |"
            )

    with_views = [r for r in runs if r["views"]]
    if with_views:
        print()
        print("| scene | seed | model | PSNR / SSIM / LPIPS (t<50) | PSNR / SSIM / LPIPS (t≥50) |")
        print("|---|---:|---|---|---|")
        for r in with_views:
            for model, v in r["views"].items():
                print(
                    f"| {r['scene']} | {r['seed']} | {model} | {f2(v[0])} / {f4(v[1])} / {f4(v[2])} | "
                    f"{f2(v[3])} / {f4(v[4])} / {f4(v[5])} |"
                )


if __name__ == "__main__":
    main()
