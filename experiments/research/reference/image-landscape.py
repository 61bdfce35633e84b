#!/usr/bin/env python3
"""Probe P7 (issue 71; docs/notebook/2026-12-06-image-landscape.md): where the training view's
image loss puts the gravity scale and the bodies'-frame dissipation, against where the truth
does, on scalar-scan.sh's grid.

    python3 experiments/research/reference/image-landscape.py [--grids] [--figure docs/image-landscapes.png]
    python3 experiments/research/reference/image-landscape.py --u12 | --u13 | --u14 | --u15 | --cand RUN | --silhouette [U14] | --headline

Reads runs/land/<scene>-s<seed>[...]/ (image-landscape.sh: I, the mean image loss over the 49
transitions at each point) and runs/ref/<scene>-scan-body/ (FRAME=body scalar-scan.sh: CD over
t < 50 at each point), D and R_S as quick-table.py reads them. --grids also prints each
landscape as a gravity × dissipation table; --figure draws, per scene, the truth's landscape
beside the image loss's (the mean over the seeds run, one view) and the silhouette's (U13's
search at seed 10), each best starred (needs matplotlib). --u12 prints candidate U12's runs
(search-runs.sh: the scalars the search held) per scene and seed against D, R_S and P_B, with
the issue's targets' quantities; --u13 / --u14 / --u15 the same for candidates U13 (the search
scored by the silhouette), U14 (and by its change between frames; retired) and U15 (U13, then DLF
grounded); --cand RUN for any runs/one/RUN-<scene>-s<seed> (P11: U15-anchor0, P12: U13-rig2,
U13-rig4); each row ends with the search's best score beside the true particles' (where logged). --silhouette [CAND] prints
probe P8 (CAND U14: U14's screen): the search's landscape S (the joint-search rows of CAND's
runs, U13's by default) against the truth's, beside the image loss's best (P7, the mean over its
seeds). --headline prints the report-only scenes' table: D, R_S, D_A (the shipped material rules, no image), A (the bed configs as they ship, seed
10), U12 (the mean over its seeds), U13 and U15 (the mean over its seeds), CD per window with g_S,
and the energy per particle.
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
# g's one formula: scripts/bed-table.py's
gap_share = quick_table.bed_table.gap_share

TRANSITIONS = 49


def image_loss(run):
    """The mean logged loss over the joint epoch's transitions of a run folder (None unless it
    logged all of them) and its evaluation's (psnr_true, rollout_psnr) (None without them)."""
    path = os.path.join(run, "metrics.csv")
    if not os.path.exists(path):
        return None
    rows = list(csv.DictReader(open(path)))
    joint = [r for r in rows if r["stage"] == "joint"]
    if len(joint) != TRANSITIONS:
        return None
    preview = [r for r in rows if r["stage"] == "joint-preview" and r.get("rollout_psnr")]
    psnr = (float(preview[-1]["psnr_true"]), float(preview[-1]["rollout_psnr"])) if preview else None
    return statistics.mean(float(r["loss"]) for r in joint), psnr


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


def psnr_column(image):
    """The renderer's PSNR on the truth and the best on a rollout of the grid (with its point),
    at the diagnostics' frames and pixels, where the evaluation logged them."""
    psnr = {p: v[1] for p, v in image.items() if v[1]}
    if not psnr:
        return "–"
    best = max(psnr, key=lambda p: psnr[p][1])
    on_truth = statistics.mean(v[0] for v in psnr.values())
    return f"{on_truth:.2f} / {psnr[best][1]:.2f} (g {best[0]}, d {best[1]})"


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


def seed_means(lands):
    """{(scene, view suffix): ({point: I's mean over the seeds run}, seeds)} over the points every
    seed has."""
    out = {}
    for (scene, _, view), image in lands.items():
        out.setdefault((scene, view), []).append(image)
    means = {}
    for key, images in out.items():
        common = set.intersection(*(set(i) for i in images))
        means[key] = ({p: statistics.mean(i[p][0] for i in images) for p in common}, len(images))
    return means


def figure(path, lands):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    means = seed_means(complete_grids(lands))
    silhouettes = {scene: sil for scene in quick_table.BED["scenes"]
                   if len(sil := search_rows(f"runs/one/U13-{scene}-s10")) == 25}
    scenes = [s for s in quick_table.BED["scenes"] if any(k[0] == s for k in means) or s in silhouettes]
    fig, axes = plt.subplots(len(scenes), 3, figsize=(13, 3.6 * len(scenes)), squeeze=False)
    for row, scene in zip(axes, scenes):
        truth = {p: v["cd"][0] for p, v in quick_table.scan_points(scene, "-body").items()}
        role = "chooses" if scene in quick_table.specs.CHOOSE else "reports only"
        panels = [(truth, f"(d + d′)/2 over t < 50, the truth's ({role})", "{:.1f}")]
        if (scene, "") in means:
            image, n = means[scene, ""]
            panels.append(({p: 1000 * v for p, v in image.items()},
                           f"image loss × 1000, one view ({n} seed{'s' * (n != 1)})", "{:.2f}"))
        else:
            panels.append(None)
        if scene in silhouettes:
            panels.append(({p: 100 * v for p, v in silhouettes[scene].items()},
                           "silhouette: 1 − IoU × 100, one view", "{:.1f}"))
        for ax, panel in zip(row, panels + [None] * (3 - len(panels))):
            if not panel or not panel[0]:
                ax.set_axis_off()
                continue
            values, title, form = panel
            gs = sorted({g for g, _ in values}, key=float)
            ds = sorted({d for _, d in values}, key=float)
            grid = [[values.get((g, d), float("nan")) for d in ds] for g in gs]
            best = min(values, key=values.get)
            ax.imshow(grid, cmap="viridis_r", origin="lower", aspect="auto")
            lo, hi = min(values.values()), max(values.values())
            for a, g in enumerate(gs):
                for b, d in enumerate(ds):
                    if (g, d) in values:
                        v = values[g, d]
                        ax.text(b, a, form.format(v) + ("★" if (g, d) == best else ""), ha="center",
                                va="center", fontsize=7.5, color="black" if v < (lo + hi) / 2 else "white",
                                fontweight="bold" if (g, d) == best else None)
            ax.set_xticks(range(len(ds)), ds, fontsize=8)
            ax.set_yticks(range(len(gs)), gs, fontsize=8)
            ax.set_xlabel("dissipation (bodies' frame)", fontsize=8)
            ax.set_ylabel("gravity scale", fontsize=8)
            ax.set_title(f"{scene}: {title}", fontsize=9)
    fig.suptitle("Where the truth, the training view's image loss and its silhouette put the scalars "
                 "(the pretrained DLF; ★ each landscape's best)", fontsize=11)
    fig.tight_layout(rect=(0, 0, 1, 0.98))
    fig.savefig(path, dpi=80)
    print(f"wrote {path}")


def complete_grids(lands):
    """The landscapes with every point of the grid."""
    return {k: v for k, v in lands.items() if len(v) == 25}


def print_seed_means(lands):
    """P7's decision: per scene and rig, the point of least I averaged over the seeds whose grid
    is complete, its CD and g_P."""
    complete = complete_grids(lands)
    print("Seed means (the seeds with all 25 points): scene, views, seeds: I*, CD(I*), g_P")
    for (scene, view), (image, n) in seed_means(complete).items():
        truth = quick_table.scan_points(scene, "-body")
        d_cd = quick_table.rollout_scores(f"runs/ref/{scene}-D.log")["cd"][0]
        i_star = min(image, key=image.get)
        best = min(v["cd"][0] for v in truth.values())
        cd = truth[i_star]["cd"][0]
        print(f"- {scene}, {1 + bool(view)} view(s), {n} seed(s): g {i_star[0]}, d {i_star[1]}; "
              f"CD {cd:.2f}; g_P {gap_share(d_cd, cd, best):.2f}")
    print()


def fmt(v):
    return "–" if v is None else f"{v:.2f}"


def search_rows(run):
    """{(gravity, dissipation) as the scan's file names: score} from a run's joint-search rows."""
    path = os.path.join(run, "metrics.csv")
    if not os.path.exists(path):
        return {}
    name = lambda v: str(float(v)) if float(v) != 0 else "0"
    return {(str(float(r["physics_gravity_scale"])), name(r["physics_dissipation"])): float(r["loss"])
            for r in csv.DictReader(open(path)) if r["stage"] == "joint-search"}


def search_scores(run):
    """The search's best score and the true particles' (its joint-search-truth row; None in runs
    made before the search scored the truth), as 'best / truth'."""
    path = os.path.join(run, "metrics.csv")
    if not os.path.exists(path):
        return "–"
    rows = list(csv.DictReader(open(path)))
    tried = [float(r["loss"]) for r in rows if r["stage"] == "joint-search"]
    truth = [float(r["loss"]) for r in rows if r["stage"] == "joint-search-truth"]
    if not tried:
        return "–"
    return f"{min(tried):.4f} / " + (f"{truth[0]:.4f}" if truth else "–")


def silhouette_table(cand="U13"):
    """P8 (U14: its screen): per scene with a run of `cand`, S*, CD(S*), g_P, Spearman(S, CD),
    and P7's I* beside."""
    image_means = seed_means(complete_grids(landscapes()))
    print("| scene | seed | points | S* (the silhouette's best) | CD(S*) | P_B's point | CD(P_B) | "
          "Spearman(S, CD) | D | g_P | g_S | I* (P7, seed mean) | CD(I*) | g_P of I* |")
    print("|---|---:|---:|---|---:|---|---:|---:|---:|---:|---:|---|---:|---:|")
    shares = []
    for scene in quick_table.BED["scenes"]:
        runs = [(seed, sil) for seed in quick_table.SEEDS
                if (sil := search_rows(f"runs/one/{cand}-{scene}-s{seed}"))]
        if not runs:
            continue
        # what depends on the scene alone: the truth's landscape, D, R_S, P7's best
        truth = quick_table.scan_points(scene, "-body")
        p_b = min(truth, key=lambda p: truth[p]["cd"][0])
        cd_pb = truth[p_b]["cd"][0]
        d_cd = quick_table.rollout_scores(f"runs/ref/{scene}-D.log")["cd"][0]
        r_s, _ = quick_table.mean_over_seeds(scene, "S1")
        image = image_means.get((scene, ""))
        i_cells = "– | – | –"
        if image:
            i_star = min(image[0], key=image[0].get)
            i_cd = truth[i_star]["cd"][0]
            i_cells = f"g {i_star[0]}, d {i_star[1]} | {i_cd:.2f} | {fmt(gap_share(d_cd, i_cd, cd_pb))}"
        for seed, sil in runs:
            common = [p for p in sil if p in truth]
            if not common:
                continue
            cds = [truth[p]["cd"][0] for p in common]
            s_star = min(common, key=lambda p: sil[p])
            cd_star = truth[s_star]["cd"][0]
            g_p = gap_share(d_cd, cd_star, cd_pb)
            print(f"| {scene} | {seed} | {len(common)} | g {s_star[0]}, d {s_star[1]} | {cd_star:.2f} | "
                  f"g {p_b[0]}, d {p_b[1]} | {cd_pb:.2f} | {spearman([sil[p] for p in common], cds):.2f} | "
                  f"{d_cd:.2f} | {fmt(g_p)} | {fmt(gap_share(d_cd, cd_star, r_s and r_s['cd'][0]))} | {i_cells} |")
            if len(common) == 25 and image:
                shares.append(g_p)
    if shares:
        print(f"\nMean g_P of S* over the scenes with a complete grid and a P7 landscape: "
              f"{statistics.mean(shares):.2f} ({len(shares)})")


def u12_table(cand="U12"):
    print("| scene | seed | held (g, d) | d \\| d′ t < 50 | CD t < 50 | D's | R_S | P_B | g_S | CD t ≥ 50 (D's) | "
          "g_S t ≥ 50 | d′ t < 50 \\| t ≥ 50 (D's) | J/kg t < 50 (bound) | search: best / truth |")
    print("|---|---:|---|---|---:|---:|---:|---:|---:|---|---:|---|---|---|")
    shares = {}
    for scene in quick_table.BED["scenes"]:
        r_s, _ = quick_table.mean_over_seeds(scene, "S1")
        p_b = quick_table.scalar_scan(scene, "-body")
        for seed in quick_table.SEEDS:
            w = quick_table.report_scores(f"runs/one/{cand}-{scene}-s{seed}")
            if not w:
                continue
            (d0, dp0), (d1, dp1) = w["windows"]["neurofluid"]
            (e0, ep0), (e1, ep1) = w["windows"]["dlf"]
            cd0, cd1, dcd0, dcd1 = (d0 + dp0) / 2, (d1 + dp1) / 2, (e0 + ep0) / 2, (e1 + ep1) / 2
            held = w["fitted"]
            energy, truth = w["energy"], w["truth_energy"]
            print(f"| {scene} | {seed} | {held.get('gravity_scale', 0):.2f}, {held.get('dissipation', 0):.2f} | "
                  f"{d0:.2f} \\| {dp0:.2f} | {cd0:.2f} | {dcd0:.2f} | {fmt(r_s and r_s['cd'][0])} | "
                  f"{fmt(p_b and p_b['cd'][0])} | {fmt(gap_share(dcd0, cd0, r_s and r_s['cd'][0]))} | "
                  f"{cd1:.2f} ({dcd1:.2f}) | {fmt(gap_share(dcd1, cd1, r_s and r_s['cd'][1]))} | "
                  f"{dp0:.2f} \\| {dp1:.2f} ({ep0:.2f} \\| {ep1:.2f}) | "
                  f"{energy:.3f} ({2 * truth + 0.1:.3f}) | "
                  f"{search_scores(f'runs/one/{cand}-{scene}-s{seed}')} |")
            if r_s:
                shares.setdefault(scene, []).append(
                    (gap_share(dcd0, cd0, r_s["cd"][0]), gap_share(dcd1, cd1, r_s["cd"][1])))
    mean = lambda xs: fmt(statistics.mean(xs) if None not in xs else None)
    print("\nMeans over the seeds run, g_S t < 50 | t ≥ 50: " + "; ".join(
        f"{scene} {mean([a for a, _ in v])} | {mean([b for _, b in v])} ({len(v)})"
        for scene, v in shares.items()))


def headline():
    """The report-only scenes: CD t < 50 | t ≥ 50 (g_S over t < 50) and J/kg per particle over
    t < 50 of D, R_S, D_A, A, U12, U13 and U15 (means over the seeds run), with the issue's
    bound."""
    print("| scene | D | R_S | D_A (shipped rules, no image) | A (shipped config, seed 10) | "
          "U12 (image-loss search, seeds 10–12) | U13 (silhouette search) | U15 (U13, then grounded; seeds) | "
          "J/kg: D_A / A / U12 / U13 / U15 (bound) |")
    print("|---|---|---|---|---|---|---|---|---|")

    def seed_mean(cand, scene):
        runs = [w for s in quick_table.SEEDS if (w := quick_table.report_scores(f"runs/one/{cand}-{scene}-s{s}"))]
        if not runs:
            return None, None, 0
        cd = tuple(statistics.mean(w["cd"][k] for w in runs) for k in (0, 1))
        return cd, statistics.mean(w["energy"] for w in runs), len(runs)

    for scene in quick_table.specs.REPORT_ONLY:
        d = quick_table.rollout_scores(f"runs/ref/{scene}-D.log")
        da = quick_table.rollout_scores(f"runs/ref/{scene}-DA.log")
        r_s, _ = quick_table.mean_over_seeds(scene, "S1")
        a = quick_table.report_scores(f"runs/one/A-{scene}-s10")
        u12_cd, u12_e, _ = seed_mean("U12", scene)
        u13 = quick_table.report_scores(f"runs/one/U13-{scene}-s10")
        u15_cd, u15_e, u15_n = seed_mean("U15", scene)
        r0 = r_s and r_s["cd"][0]

        def cell(cd):
            if cd is None:
                return "–"
            return f"{cd[0]:.2f} \\| {cd[1]:.2f} ({fmt(gap_share(d['cd'][0], cd[0], r0))})"

        energies = [da and da["energy"], a and a["energy"], u12_e, u13 and u13["energy"], u15_e]
        print(f"| {scene} | {d['cd'][0]:.2f} \\| {d['cd'][1]:.2f} | {fmt(r0)} | {cell(da and da['cd'])} | "
              f"{cell(a and a['cd'])} | {cell(u12_cd)} | {cell(u13 and u13['cd'])} | "
              f"{cell(u15_cd)}{f' ({u15_n})' if u15_n else ''} | "
              f"{' / '.join(f'{e:.3f}' if e is not None else '–' for e in energies)} "
              f"({2 * d['truth_energy'] + 0.1:.3f}) |")


def main():
    if "--headline" in sys.argv:
        headline()
        return
    for cand in ("U12", "U13", "U14", "U15"):
        if f"--{cand.lower()}" in sys.argv:
            u12_table(cand)
            return
    if "--cand" in sys.argv:
        u12_table(sys.argv[sys.argv.index("--cand") + 1])
        return
    if "--silhouette" in sys.argv:
        k = sys.argv.index("--silhouette")
        silhouette_table(sys.argv[k + 1] if len(sys.argv) > k + 1 else "U13")
        return
    grids = "--grids" in sys.argv
    lands = landscapes()
    if "--figure" in sys.argv:
        figure(sys.argv[sys.argv.index("--figure") + 1], lands)
        return
    print_seed_means(lands)
    print("| scene | seed | views | points | I* (image loss's best) | CD(I*) | P_B's point | CD(P_B) | "
          "rank of P_B's point on I | Spearman(I, CD) | D | R_S | g_P | g_S | PSNR on the truth / "
          "the best rollout's (its point) | t ≥ 50: CD(I*) (D's) |")
    print("|---|---:|---|---:|---|---:|---|---:|---:|---:|---:|---:|---:|---:|---|---|")
    for (scene, seed, view), image in lands.items():
        truth = quick_table.scan_points(scene, "-body")
        common = [p for p in image if p in truth]
        if not common:
            continue
        cds = [truth[p]["cd"][0] for p in common]
        ims = [image[p][0] for p in common]
        i_star = min(common, key=lambda p: image[p][0])
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
              f"{fmt(gap_share(d_cd, cd_star, cd_pb))} | {fmt(gap_share(d_cd, cd_star, r_s and r_s['cd'][0]))} | "
              f"{psnr_column(image)} | {truth[i_star]['cd'][1]:.2f} ({d['cd'][1]:.2f}) |")
        if grids:
            gs = sorted({g for g, _ in common}, key=float)
            ds = sorted({x for _, x in common}, key=float)
            print(f"\n{scene} seed {seed}{view}: I × 1000 (CD over t < 50) by gravity scale (rows) × dissipation\n")
            print("| g \\ d | " + " | ".join(ds) + " |")
            print("|---" * (len(ds) + 1) + "|")
            for g in gs:
                cells = [f"{1000 * image[g, x][0]:.3f} ({truth[g, x]['cd'][0]:.1f})" if (g, x) in common else "–"
                         for x in ds]
                print(f"| {g} | " + " | ".join(cells) + " |")
            print()


if __name__ == "__main__":
    main()
