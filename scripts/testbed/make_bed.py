#!/usr/bin/env python3
"""Makes the test bed: fluid scenes NOT made by neurofluid-scenegen, in the layout the tool reads.

    /work/bedenv/bin/python scripts/testbed/make_bed.py [--out data/bed] [scene ...]

For each scene of specs.py (all, in specs.ORDER, unless named): simulate with SPlisHSPlasH's
DFSPH (bed_sim.py, pysplishsplash), render with Blender Cycles (bed_render.py, bpy), and write

    <out>/<scene>/scene.json, box.npz, view_k/transforms_<split>.json,
    view_k/<split>/NNNN.png, view_k/<split>/particles/NNNN.npz

into <out>/.tmp-<scene>/ first, renamed to <out>/<scene> when complete; a ring rig's scene then
gets its two validation views (validation_views.py). The simulation is kept in
<out>/.work/<scene>/sim.npz and reused while the scene's "sim" spec is unchanged (--resim forces
it). Timings are appended to <out>/timings.jsonl. Options: --frames-only N (render only the
first N frames: a smoke test), --samples S, --keep-going, --no-render (no images: a scene for
DLF rollouts only, e.g. `--out data/bed-particles`).
"""

import argparse
import hashlib
import json
import os
import shutil
import subprocess
import sys
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
from specs import FRAMES, ORDER, SCENES, TRAIN_FRAMES  # noqa: E402

RADIUS = 0.025
FPS = 50.0
GL_FIX = "/lib/x86_64-linux-gnu/libGLdispatch.so.0"


# --------------------------------------------------------------------------- cameras

def look_at(eye, target, up):
    eye, target, up = (np.asarray(v, float) for v in (eye, target, up))
    z = eye - target
    z /= np.linalg.norm(z)
    x = np.cross(up, z)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    m = np.eye(4)
    m[:3, 0], m[:3, 1], m[:3, 2], m[:3, 3] = x, y, z, eye
    return m


def up_vector(axis):
    return np.array([0.0, 1.0, 0.0]) if axis == "y" else np.array([0.0, 0.0, 1.0])


def horizontal_axes(axis):
    # (e1, e2, up) right-handed
    if axis == "y":
        return np.array([0.0, 0.0, 1.0]), np.array([1.0, 0.0, 0.0])
    return np.array([1.0, 0.0, 0.0]), np.array([0.0, 1.0, 0.0])


def corners(lo, hi):
    return np.array([[(lo, hi)[(c >> a) & 1][a] for a in range(3)] for c in range(8)])


def ring_camera(spec, elevation_deg, azimuth_deg):
    """The camera-to-world matrix of a ring rig's camera at that elevation and azimuth: it looks
    at the ring's target from the distance at which the box fills `fill` of the field of view."""
    sim, cams = spec["sim"], spec["cameras"]
    axis = sim["up"]
    up = up_vector(axis)
    lo, hi = np.array(sim["walls_lo"]), np.array(sim["walls_hi"])
    ui = "xyz".index(axis)
    target = 0.5 * (lo + hi)
    target[ui] = lo[ui] + cams["target_height"] * (hi[ui] - lo[ui])
    r_t = np.max(np.linalg.norm(corners(lo, hi) - target, axis=1))
    dist = r_t / (cams["fill"] * np.tan(0.5 * cams["angle_x"]))
    e1, e2 = horizontal_axes(axis)
    el, az = np.radians(elevation_deg), np.radians(azimuth_deg)
    eye = target + dist * (np.cos(el) * np.cos(az) * e1 + np.cos(el) * np.sin(az) * e2 + np.sin(el) * up)
    return look_at(eye, target, up)


def make_cameras(spec):
    """[(name, c2w 4x4, angle_x)] for view_1.. (warm-up views first, then test views)."""
    sim, cams = spec["sim"], spec["cameras"]
    up = up_vector(sim["up"])
    views = []
    if cams["kind"] == "ring":
        w = cams["warmup"]
        mats = [ring_camera(spec, w["elevation_deg"], a) for a in w["azimuths_deg"]]
        mats += [ring_camera(spec, t["elevation_deg"], t["azimuth_deg"]) for t in cams["test"]]
    else:
        mats = [look_at(c["eye"], c["target"], up) for c in cams["warmup"] + cams["test"]]
    for k, m in enumerate(mats):
        views.append({"name": f"view_{k + 1}", "c2w": m, "angle_x": cams["angle_x"]})
    n_warm = len(cams["warmup"]["azimuths_deg"]) if cams["kind"] == "ring" else len(cams["warmup"])
    return views[:n_warm], views[n_warm:]


def near_far(views, lo, hi):
    """Ray bounds that bracket the box [lo, hi] from every camera."""
    near, far = np.inf, 0.0
    for v in views:
        eye = v["c2w"][:3, 3]
        closest = np.clip(eye, lo, hi)
        near = min(near, np.linalg.norm(eye - closest))
        far = max(far, np.max(np.linalg.norm(corners(lo, hi) - eye, axis=1)))
    return float(max(0.05, 0.95 * near)), float(1.05 * far)


# --------------------------------------------------------------------------- box particles

def box_particles(lo, hi, spacing, up_index, open_top):
    """Each face sampled on its own cell-centred grid at about `spacing` (no point on an edge or
    corner, normals exactly the faces' inward normals: unlike neurofluid-scenegen's lattice
    surface); the top face left out when the box is open."""
    pts, nrm = [], []
    for a in range(3):
        b, c = [i for i in range(3) if i != a]
        nb = max(1, int(round((hi[b] - lo[b]) / spacing)))
        nc = max(1, int(round((hi[c] - lo[c]) / spacing)))
        ub = lo[b] + (np.arange(nb) + 0.5) * (hi[b] - lo[b]) / nb
        uc = lo[c] + (np.arange(nc) + 0.5) * (hi[c] - lo[c]) / nc
        gb, gc = np.meshgrid(ub, uc, indexing="ij")
        for side, sign in ((lo[a], 1.0), (hi[a], -1.0)):
            if open_top and a == up_index and sign < 0:
                continue
            p = np.zeros((gb.size, 3))
            p[:, a], p[:, b], p[:, c] = side, gb.ravel(), gc.ravel()
            n = np.zeros_like(p)
            n[:, a] = sign
            pts.append(p)
            nrm.append(n)
    return np.concatenate(pts).astype(np.float32), np.concatenate(nrm).astype(np.float32)


# --------------------------------------------------------------------------- steps

def log_line(path, record):
    with open(path, "a") as f:
        f.write(json.dumps(record) + "\n")


def spec_hash(obj):
    return hashlib.sha1(json.dumps(obj, sort_keys=True).encode()).hexdigest()[:12]


def simulate(name, spec, work, resim):
    os.makedirs(work, exist_ok=True)
    sim_path = os.path.join(work, "sim.npz")
    h = spec_hash(spec["sim"])
    stamp = os.path.join(work, "sim.hash")
    if not resim and os.path.isfile(sim_path) and os.path.isfile(stamp) and open(stamp).read() == h:
        print(f"[{name}] reusing the simulation {sim_path}", flush=True)
        return sim_path, 0.0
    spec_path = os.path.join(work, "sim_spec.json")
    with open(spec_path, "w") as f:
        json.dump(spec["sim"], f, indent=1)
    t0 = time.time()
    env = dict(os.environ, LD_PRELOAD=GL_FIX) if os.path.exists(GL_FIX) else dict(os.environ)
    with open(os.path.join(work, "sim.log"), "w") as log:
        subprocess.run(["nice", "-n", "5", sys.executable, os.path.join(HERE, "bed_sim.py"), spec_path,
                        os.path.join(work, "sph"), sim_path + ".part.npz"],
                       env=env, stdout=log, stderr=subprocess.STDOUT, check=True)
    os.replace(sim_path + ".part.npz", sim_path)
    with open(stamp, "w") as f:
        f.write(h)
    return sim_path, time.time() - t0


def render_key(spec, sim, job):
    return spec_hash({"sim": sim, "cameras": spec["cameras"], "render": dict(spec["render"], samples=job["samples"]),
                      "surface": [job["surface_radius"], job["voxel"], job["denoise"]]})


def reuse_images(final, spec, sim, job, renders, tmp):
    try:
        with open(os.path.join(final, "scene.json")) as f:
            old = json.load(f).get("generator", {})
    except (OSError, ValueError):
        return 0
    if old.get("render_key") != render_key(spec, sim, job):
        return 0
    n = 0
    for r in renders:
        src = os.path.join(final, os.path.relpath(r[2], tmp))
        if os.path.isfile(src) and not os.path.exists(r[2]):
            os.link(src, r[2])
            n += 1
    return n


def frame_stem(t):
    return f"{t:04d}"


def transforms_intrinsics(rnd, angle_x, size):
    """The intrinsics of a view's transforms file as the spec's `render.intrinsics` asks."""
    tf = {}
    if rnd["intrinsics"] in ("angle", "both"):
        tf["camera_angle_x"] = angle_x
    if rnd["intrinsics"] in ("pixels", "both"):
        f = 0.5 * size / np.tan(0.5 * angle_x)
        # nerfstudio's principal point: pixel i's ray through i + 0.5, as Blender renders it
        tf.update({"fl_x": f, "fl_y": f, "cx": size / 2.0, "cy": size / 2.0, "w": size, "h": size})
    return tf


def render_job(spec, sim_path, samples, views, renders):
    """bed_render.py's job: `renders` ([frame, camera index, path]) of `views` (name, c2w,
    angle_x) with the spec's material and surface settings at `samples` Cycles samples."""
    rnd = spec["render"]
    return {
        "particles": sim_path,
        "up_index": "xyz".index(spec["sim"]["up"]),
        "size": rnd["size"],
        "samples": samples,
        "material": rnd["material"],
        "surface_radius": rnd.get("surface_radius", 0.042),
        "voxel": rnd.get("voxel", 0.018),
        "denoise": rnd.get("denoise", False),
        "cameras": [{"name": v["name"], "c2w": np.asarray(v["c2w"]).tolist(), "angle_x": v["angle_x"]}
                    for v in views],
        "renders": renders,
    }


def replace_dir(tmp, final):
    """Puts the complete folder `tmp` at `final`, the old one (if any) removed only after."""
    if os.path.exists(final):
        old = os.path.join(os.path.dirname(final), ".old-" + os.path.basename(final))
        shutil.rmtree(old, ignore_errors=True)
        os.rename(final, old)
        os.rename(tmp, final)
        shutil.rmtree(old)
    else:
        os.rename(tmp, final)


def build(name, spec, out_root, args):
    work = os.path.join(out_root, ".work", name)
    timings = {"scene": name, "started": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())}
    t_all = time.time()
    sim_path, timings["simulate_s"] = simulate(name, spec, work, args.resim)
    data = np.load(sim_path)
    pos, vel = data["pos"], data["vel"]
    n_frames = FRAMES if args.frames_only is None else min(args.frames_only, FRAMES)
    train_frames = min(TRAIN_FRAMES, n_frames)

    sim = spec["sim"]
    up_index = "xyz".index(sim["up"])
    lo, hi = np.array(sim["walls_lo"], float), np.array(sim["walls_hi"], float)
    interior_lo, interior_hi = lo + RADIUS, hi - RADIUS
    # how far the simulated particles stray out of the walls inset by one radius (the
    # simulator's boundary particles are soft): the interior is widened, per side, to hold
    # every true particle (rounded out to 1 mm), so the truth never leaves box_interior
    over = np.maximum(interior_lo - pos, 0.0).max(), np.maximum(pos - interior_hi, 0.0).max()
    outside = int(np.sum(np.any((pos < interior_lo) | (pos > interior_hi), axis=2)))
    flat = pos.reshape(-1, 3)
    interior_lo = np.minimum(interior_lo, np.floor(flat.min(0) * 1000.0) / 1000.0)
    interior_hi = np.maximum(interior_hi, np.ceil(flat.max(0) * 1000.0) / 1000.0)
    timings["particles"] = int(pos.shape[1])
    timings["outside_inset_particle_frames"] = outside
    timings["outside_inset_max_m"] = float(max(over))

    warm, test = make_cameras(spec)
    views = warm + test
    roles = spec["roles"]
    train_view = warm[roles["train_view"]]["name"]
    every = roles.get("warmup_every_frame", False)
    near, far = near_far(views, lo, hi)
    rnd = spec["render"]
    size = rnd["size"]

    tmp = os.path.join(out_root, f".tmp-{name}")
    shutil.rmtree(tmp, ignore_errors=True)
    os.makedirs(tmp)

    # which frames each (view, split) holds
    holdings = []  # (view dict, split, frames)
    for v in warm:
        frames = range(train_frames) if (v["name"] == train_view or every) else range(1)
        holdings.append((v, "train", list(frames)))
    for v in test:
        holdings.append((v, "test", list(range(n_frames))))

    # particles: written once per frame, hard-linked into every view folder that holds the frame
    t0 = time.time()
    master = os.path.join(tmp, ".particles")
    os.makedirs(master)
    for t in range(n_frames):
        np.savez(os.path.join(master, frame_stem(t) + ".npz"), pos=pos[t].astype(np.float32),
                 vel=vel[t].astype(np.float32))
    renders = []
    for v, split, frames in holdings:
        k = views.index(v)
        vdir = os.path.join(tmp, v["name"])
        os.makedirs(os.path.join(vdir, split, "particles"), exist_ok=True)
        entries = []
        for t in frames:
            stem = frame_stem(t)
            os.link(os.path.join(master, stem + ".npz"), os.path.join(vdir, split, "particles", stem + ".npz"))
            renders.append([t, k, os.path.join(vdir, split, stem + ".png")])
            entry = {
                "file_path": rnd["file_path"].format(split=split, stem=stem),
                "transform_matrix": v["c2w"].tolist(),
                "particle_path": f"particles/{stem}.npz",
                "time": t / FPS,
            }
            entries.append(entry)
        tf = transforms_intrinsics(rnd, v["angle_x"], size)
        if args.no_render:
            # no images to read the size from: the transforms give it (nerfstudio's w, h)
            tf.setdefault("w", size)
            tf.setdefault("h", size)
        tf["frames"] = entries
        with open(os.path.join(vdir, f"transforms_{split}.json"), "w") as fh:
            json.dump(tf, fh, indent=1)
    shutil.rmtree(master)  # the links keep the files
    b, bn = box_particles(lo, hi, spec["walls"]["spacing"], up_index, spec["walls"]["open_top"])
    np.savez(os.path.join(tmp, "box.npz"), box=b, box_normals=bn)
    timings["box_particles"] = int(len(b))
    timings["write_s"] = time.time() - t0

    # render
    job = render_job(spec, sim_path, args.samples or rnd["samples"], views, renders)
    if args.no_render:
        timings["images"] = 0
    else:
        # images of the scene already built with the same simulation, cameras and render settings
        # are kept (hard links), so adding frames (e.g. warm-up views at every frame) renders only
        # the new ones; Cycles with a fixed seed would render them the same
        reused = reuse_images(os.path.join(out_root, name), spec, sim, job, renders, tmp)
        job["renders"] = [r for r in renders if not os.path.isfile(r[2])]
        timings["images_reused"] = reused
        job_path = os.path.join(work, "render_job.json")
        with open(job_path, "w") as f:
            json.dump(job, f)
        t0 = time.time()
        with open(os.path.join(work, "render.log"), "w") as log:
            subprocess.run(["nice", "-n", "5", sys.executable, os.path.join(HERE, "bed_render.py"), job_path],
                           stdout=log, stderr=subprocess.STDOUT, check=True)
        timings["render_s"] = time.time() - t0
        timings["images"] = len(renders)
        timings["images_rendered"] = len(job["renders"])
        missing = [r[2] for r in renders if not os.path.isfile(r[2])]
        if missing:
            raise RuntimeError(f"{len(missing)} images missing, e.g. {missing[0]} (see {work}/render.log)")

    manifest = {
        "name": name,
        "up_axis": sim["up"],
        "particle_radius": RADIUS,
        "fps": FPS,
        "warmup": {"views": [v["name"] for v in warm], "split": "train",
                   "frames": {"start": 0, "end": train_frames if every else 1}},
        "train": {"views": [train_view], "split": "train", "frames": {"start": 0, "end": train_frames}},
        "test": {"views": [v["name"] for v in test], "split": "test", "frames": {"start": 0, "end": n_frames}},
        "box_file": "box.npz",
        "box_interior": {"min": interior_lo.tolist(), "max": interior_hi.tolist()},
        "near": near,
        "far": far,
        "generator": {
            "made_by": "scripts/testbed/make_bed.py (SPlisHSPlasH DFSPH via pysplishsplash; Blender Cycles via bpy)",
            "spec": spec["spec"],
            "differs": spec["differs"],
            "sim": sim,
            "walls": spec["walls"],
            "cameras": spec["cameras"],
            "render": dict(rnd, samples=job["samples"]),
            "particles": int(pos.shape[1]),
            "box_particles": int(len(b)),
            "sim_hash": spec_hash(sim),
            "render_key": render_key(spec, sim, job),
        },
    }
    with open(os.path.join(tmp, "scene.json"), "w") as f:
        json.dump(manifest, f, indent=1)

    replace_dir(tmp, os.path.join(out_root, name))
    if not args.no_render and spec["cameras"]["kind"] == "ring":
        # the validation views (rule 18), which a remade scene would otherwise lack
        import validation_views  # imports this module: here, not at the top

        t0 = time.time()
        validation_views.build(name, out_root, args.samples)
        timings["validation_s"] = time.time() - t0
    timings["total_s"] = time.time() - t_all
    timings["finished"] = time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())
    log_line(os.path.join(out_root, "timings.jsonl"), timings)
    print(f"[{name}] done: {json.dumps(timings)}", flush=True)
    return timings


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("scenes", nargs="*", help=f"scene names (default: all: {', '.join(ORDER)})")
    ap.add_argument("--out", default=os.path.join(HERE, "..", "..", "data", "bed"))
    ap.add_argument("--resim", action="store_true", help="simulate again even if the spec is unchanged")
    ap.add_argument("--frames-only", type=int, default=None, help="render only the first N frames (smoke test)")
    ap.add_argument("--samples", type=int, default=None, help="override the Cycles samples")
    ap.add_argument("--no-render", action="store_true",
                    help="particles, box and cameras only, no images (for DLF rollouts; needs no bpy)")
    ap.add_argument("--keep-going", action="store_true", help="go on with the next scene after a failure")
    ap.add_argument("--ready-file", default=None, help="append each finished scene's folder to this file")
    args = ap.parse_args()
    out = os.path.abspath(args.out)
    os.makedirs(out, exist_ok=True)
    names = args.scenes or ORDER
    for n in names:
        if n not in SCENES:
            ap.error(f"unknown scene {n}; known: {', '.join(ORDER)}")
    failed = []
    for n in names:
        try:
            build(n, SCENES[n], out, args)
            if args.ready_file:
                with open(args.ready_file, "a") as f:
                    f.write(os.path.join(out, n) + "\n")
        except Exception as e:  # noqa: BLE001
            print(f"[{n}] FAILED: {e}", flush=True)
            failed.append(n)
            if not args.keep_going:
                raise
    if failed:
        sys.exit(f"failed: {', '.join(failed)}")


if __name__ == "__main__":
    main()
