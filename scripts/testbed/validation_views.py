#!/usr/bin/env python3
"""Renders two validation views of a test-bed scene: views no stage reads, to choose settings with.

    /work/bedenv/bin/python scripts/testbed/validation_views.py [--out data/bed] scene ...

A bed scene's warm-up views sit on one ring and its test view off it; every image a rule may read
(the warm-up and training views) is on the ring. This script renders, from the scene's cached
simulation (`<out>/.work/<scene>/sim.npz`, made by make_bed.py) and with the same renderer and
settings, two more views over the test frames and adds them to the scene as its `validation`
views (`scene.json`), which no stage trains on; `--set eval.novel_views="validation"` scores a
run on them (`eval`, `baseline`). The scene is rewritten atomically (a copy of hard links, then
renamed); images already there for the same placements are kept. make_bed.py runs it after
making a ring rig's scene.

Where they sit is fixed from the rig alone (experiments/bed/README.md rule 18): the ring's target,
distance and field of view; view_6 15° below the warm-up ring (at least 5° above the horizon),
view_7 20° above it; azimuths at the midpoints between neighbouring warm-up azimuths, view_6 at
the one farthest from the test camera's azimuth, view_7 at the next farthest. Ring rigs only.
"""

import argparse
import copy
import json
import os
import shutil
import subprocess
import sys
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
from make_bed import (  # noqa: E402
    corners, frame_stem, render_job, replace_dir, ring_camera, transforms_intrinsics)
from specs import SCENES  # noqa: E402

BELOW_DEG, ABOVE_DEG, LOWEST_DEG = 15.0, 20.0, 5.0
SPLIT = "test"  # the validation views' images sit in their view folders' test split


def angle_gap(a, b):
    """The absolute difference of two azimuths in degrees, in [0, 180]."""
    d = abs(a - b) % 360.0
    return min(d, 360.0 - d)


def placements(cams):
    """[(elevation, azimuth)] of view_6 and view_7 for a ring rig."""
    ring = cams["warmup"]["elevation_deg"]
    az = sorted(a % 360.0 for a in cams["warmup"]["azimuths_deg"])
    mids = [((a + (b if b > a else b + 360.0)) / 2.0) % 360.0 for a, b in zip(az, az[1:] + az[:1])]
    test_az = cams["test"][0]["azimuth_deg"]
    far = sorted(mids, key=lambda m: -angle_gap(m, test_az))
    return [(max(ring - BELOW_DEG, LOWEST_DEG), far[0]), (ring + ABOVE_DEG, far[1])]


def build(name, out_root, samples):
    spec = SCENES[name]
    if spec["cameras"]["kind"] != "ring":
        raise SystemExit(f"{name}: validation views are placed on ring rigs only")
    src = os.path.join(out_root, name)
    with open(os.path.join(src, "scene.json")) as f:
        manifest = json.load(f)
    gen = manifest.get("generator", {})
    if gen.get("cameras") != spec["cameras"]:
        raise SystemExit(f"{name}: {src} was made from other camera specs than specs.py's; make it again")
    sim_path = os.path.join(out_root, ".work", name, "sim.npz")
    if not os.path.isfile(sim_path):
        raise SystemExit(f"{name}: no cached simulation {sim_path}; run make_bed.py {name} first")
    sim = np.load(sim_path)
    pos, vel = sim["pos"], sim["vel"]
    frames = range(manifest["test"]["frames"]["start"], manifest["test"]["frames"]["end"])
    rnd = spec["render"]
    size = rnd["size"]
    places = placements(spec["cameras"])
    mats = [ring_camera(spec, el, az) for el, az in places]
    angle_x = spec["cameras"]["angle_x"]
    others = manifest["warmup"]["views"] + manifest["train"]["views"] + manifest["test"]["views"]
    first = 1 + max(int(v.split("_")[-1]) for v in others if v.split("_")[-1].isdigit())
    names = [f"view_{first + k}" for k in range(len(mats))]
    wanted = [{"name": n, "elevation_deg": el, "azimuth_deg": az} for n, (el, az) in zip(names, places)]
    before = gen.get("validation", {})
    keep = before.get("views") == wanted and manifest.get("validation", {}).get("views") == names

    # the scene's ray bounds (which every stage's settings hold) must bracket the box from these
    # cameras too; they are not changed
    lo, hi = np.array(spec["sim"]["walls_lo"], float), np.array(spec["sim"]["walls_hi"], float)
    for n, m in zip(names, mats):
        eye = m[:3, 3]
        near, far = np.linalg.norm(eye - np.clip(eye, lo, hi)), np.max(np.linalg.norm(corners(lo, hi) - eye, axis=1))
        if near < manifest["near"] or far > manifest["far"]:
            raise SystemExit(f"{name}: the box from {n} spans {near:.3f}..{far:.3f}, outside the scene's ray "
                             f"bounds {manifest['near']:.3f}..{manifest['far']:.3f}")

    tmp = os.path.join(out_root, f".tmp-{name}-val")
    shutil.rmtree(tmp, ignore_errors=True)
    shutil.copytree(src, tmp, copy_function=os.link)
    renders = []
    for k, (vname, m) in enumerate(zip(names, mats)):
        vdir = os.path.join(tmp, vname)
        if not keep:
            shutil.rmtree(vdir, ignore_errors=True)
        os.makedirs(os.path.join(vdir, SPLIT, "particles"), exist_ok=True)
        entries = []
        for t in frames:
            stem = frame_stem(t)
            npz = os.path.join(vdir, SPLIT, "particles", stem + ".npz")
            if os.path.exists(npz):
                os.remove(npz)  # a link to the scene's: written anew, never through the link
            if k == 0:
                np.savez(npz, pos=pos[t].astype(np.float32), vel=vel[t].astype(np.float32))
            else:  # the frame's particles are the first view's: one file, linked
                os.link(os.path.join(tmp, names[0], SPLIT, "particles", stem + ".npz"), npz)
            png = os.path.join(vdir, SPLIT, stem + ".png")
            if not os.path.isfile(png):
                renders.append([t, k, png])
            entries.append({"file_path": rnd["file_path"].format(split=SPLIT, stem=stem),
                            "transform_matrix": m.tolist(), "particle_path": f"particles/{stem}.npz",
                            "time": t / manifest["fps"]})
        tf = transforms_intrinsics(rnd, angle_x, size)
        tf["frames"] = entries
        tf_path = os.path.join(vdir, f"transforms_{SPLIT}.json")
        if os.path.exists(tf_path):
            os.remove(tf_path)
        with open(tf_path, "w") as fh:
            json.dump(tf, fh, indent=1)

    views = [{"name": n, "c2w": m, "angle_x": angle_x} for n, m in zip(names, mats)]
    job = render_job(spec, sim_path, samples or gen.get("render", {}).get("samples", rnd["samples"]), views,
                     renders)
    work = os.path.join(out_root, ".work", name)
    job_path = os.path.join(work, "validation_job.json")
    with open(job_path, "w") as f:
        json.dump(job, f)
    t0 = time.time()
    if renders:
        with open(os.path.join(work, "validation_render.log"), "w") as log:
            subprocess.run(["nice", "-n", "5", sys.executable, os.path.join(HERE, "bed_render.py"), job_path],
                           stdout=log, stderr=subprocess.STDOUT, check=True)
    missing = [r[2] for r in renders if not os.path.isfile(r[2])]
    if missing:
        raise SystemExit(f"{name}: {len(missing)} images missing, e.g. {missing[0]} (see {work}/validation_render.log)")

    val = copy.deepcopy(manifest)
    val["validation"] = {"views": names, "split": SPLIT, "frames": dict(manifest["test"]["frames"])}
    val["generator"]["validation"] = {
        "made_by": "scripts/testbed/validation_views.py (experiments/bed/README.md rule 18)",
        "views": wanted,
    }
    os.remove(os.path.join(tmp, "scene.json"))  # a hard link to the original's
    with open(os.path.join(tmp, "scene.json"), "w") as f:
        json.dump(val, f, indent=1)
    replace_dir(tmp, src)
    print(f"[{name}] {src}: validation {', '.join(f'{n} at {el:.0f}° / {az:.1f}°' for n, (el, az) in zip(names, places))}; "
          f"{len(renders)} images rendered in {time.time() - t0:.0f} s", flush=True)


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("scenes", nargs="+")
    ap.add_argument("--out", default=os.path.join(HERE, "..", "..", "data", "bed"))
    ap.add_argument("--samples", type=int, default=None, help="override the Cycles samples")
    args = ap.parse_args()
    for n in args.scenes:
        if n not in SCENES:
            ap.error(f"unknown scene {n}")
        build(n, os.path.abspath(args.out), args.samples)


if __name__ == "__main__":
    main()
