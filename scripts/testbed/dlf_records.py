#!/usr/bin/env python3
"""Makes DLF training records (`*.msgpack.zst`) of random fluid scenes in the style of DLF's own
data set: the data for a DLF prior trained outside the test bed and the built-in scenes.

    /work/bedenv/bin/python scripts/testbed/dlf_records.py --out data/dlf-records/train --seeds 1-8
    /work/bedenv/bin/python scripts/testbed/dlf_records.py --out data/dlf-records/val --seeds 201-202

Each seed draws one scene the way DLF's `create_physics_scenes.py` does (docs/spec/dlf.md §6.1), within
what `bed_sim.py` simulates: a closed box of random size, one fluid body (a block, sphere,
cylinder or torus) of random size, orientation and place, thrown with x and z velocity U(−2, 2)
and y velocity U(−0.5, 0.5) m/s; water (density 1000, viscosity 0.01), y-up, radius 0.025,
50 fps, SPlisHSPlasH's DFSPH (the simulator of DLF's data; not neurofluid-scenegen). Box
particles on each face's grid at DLF's density (0.0321 m, docs/spec/dlf.md §6.3) with inward normals.
A scene's frames are split into files of `--frames-per-file` (DLF: 16 parts of one scene), each
file a training sequence; the files are written atomically (`.part` then renamed).
"""

import argparse
import json
import math
import os
import shutil
import subprocess
import sys
import time

import msgpack
import numpy as np
import zstandard

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
from make_bed import GL_FIX, box_particles  # noqa: E402

RADIUS = 0.025
WALL_SPACING = 0.0321  # DLF's wall density, about 968 points/m²
WATER = {"viscosityMethod": 1, "viscosity": 0.01}


def nd(a):
    """A numpy array the msgpack-numpy way (binary keys, docs/spec/dlf.md §6.2)."""
    a = np.ascontiguousarray(a)
    return {b"nd": True, b"type": a.dtype.str, b"kind": b"", b"shape": list(a.shape), b"data": a.tobytes()}


def scalar_i64(v):
    return {b"nd": False, b"type": "<i8", b"kind": b"", b"data": np.int64(v).tobytes()}


def random_spec(seed, frames, speed=1.0):
    """One scene of seed `seed`: box, fluid body and throw (y-up); `speed` scales DLF's
    velocity ranges."""
    rng = np.random.default_rng(seed)
    w, h, d = rng.uniform(1.2, 2.0), rng.uniform(1.3, 2.0), rng.uniform(1.2, 2.0)
    lo, hi = np.array([-w / 2, 0.0, -d / 2]), np.array([w / 2, h, d / 2])
    kind = ["block", "sphere", "cylinder", "torus"][int(rng.integers(4))]
    # the body's extent: ~1.5k–5k particles at spacing 2r
    size = rng.uniform(0.65, 0.95)
    vel = [speed * float(rng.uniform(-2, 2)), speed * float(rng.uniform(-0.5, 0.5)),
           speed * float(rng.uniform(-2, 2))]
    if kind == "block":
        ext = np.minimum(np.array([size, size * rng.uniform(0.7, 1.4), size * rng.uniform(0.7, 1.4)]), hi - lo - 0.1)
        start = lo + 0.05 + rng.uniform(0, 1, 3) * (hi - lo - 0.1 - ext)
        fluid = {"shape": "block", "start": list(start), "end": list(start + ext), "velocity": vel}
        reach = None
    else:
        if kind == "sphere":
            fluid, reach = {"shape": "sphere", "radius": size / 2}, size / 2
        elif kind == "cylinder":
            height = size * rng.uniform(0.8, 1.5)
            fluid = {"shape": "cylinder", "radius": size / 2, "height": height}
            reach = math.hypot(size / 2, height / 2)
        else:
            minor = size * 0.3
            fluid = {"shape": "torus", "major": size / 2, "minor": minor}
            reach = size / 2 + minor
        axis = rng.normal(size=3)
        fluid.update({"axis": list(axis / np.linalg.norm(axis)), "angle_deg": float(rng.uniform(0, 180)),
                      "velocity": vel, "mode": 0})
        margin = reach + 0.06
        room = np.maximum(hi - lo - 2 * margin, 0.0)
        fluid["center"] = list(lo + margin + rng.uniform(0, 1, 3) * room)
    sim = {"up": "y", "walls_lo": list(lo), "walls_hi": list(hi), "dt": 0.0025, "frames": frames,
           "density": 1000.0, "material": WATER, "fluid": fluid}
    return sim


def simulate(spec, work):
    os.makedirs(work, exist_ok=True)
    spec_path = os.path.join(work, "sim_spec.json")
    with open(spec_path, "w") as f:
        json.dump(spec, f, indent=1)
    out = os.path.join(work, "sim.npz")
    env = dict(os.environ, LD_PRELOAD=GL_FIX) if os.path.exists(GL_FIX) else dict(os.environ)
    with open(os.path.join(work, "sim.log"), "w") as log:
        subprocess.run(["nice", "-n", "5", sys.executable, os.path.join(HERE, "bed_sim.py"), spec_path,
                        os.path.join(work, "sph"), out], env=env, stdout=log, stderr=subprocess.STDOUT,
                       check=True)
    return np.load(out)


def write_records(out_dir, scene_id, pos, vel, box, normals, frames_per_file):
    """`scene_id`_YY.msgpack.zst, one file per `frames_per_file` frames (the last may be longer)."""
    n = pos.shape[1]
    mass = np.full(n, 1000.0 * (2 * RADIUS) ** 3, np.float32)
    visc = np.full(n, WATER["viscosity"], np.float32)
    parts = max(1, len(pos) // frames_per_file)
    for k, idx in enumerate(np.array_split(np.arange(len(pos)), parts)):
        frames = []
        for j, t in enumerate(idx):
            f = {"pos": nd(pos[t].astype(np.float32)), "vel": nd(vel[t].astype(np.float32)), "m": nd(mass),
                 "viscosity": nd(visc), "frame_id": scalar_i64(int(t)), "scene_id": scene_id}
            if j == 0:
                f["box"], f["box_normals"] = nd(box), nd(normals)
            frames.append(f)
        raw = msgpack.packb(frames, use_bin_type=True)
        path = os.path.join(out_dir, f"{scene_id}_{k:02d}.msgpack.zst")
        with open(path + ".part", "wb") as fh:
            fh.write(zstandard.ZstdCompressor(level=19).compress(raw))
        os.replace(path + ".part", path)


def parse_seeds(text):
    seeds = []
    for part in text.split(","):
        a, _, b = part.partition("-")
        seeds += list(range(int(a), int(b or a) + 1))
    return seeds


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", required=True)
    ap.add_argument("--seeds", required=True, help="e.g. 1-8 or 201,202")
    ap.add_argument("--frames", type=int, default=80)
    ap.add_argument("--frames-per-file", type=int, default=40)
    ap.add_argument("--speed", type=float, default=1.0,
                    help="scales DLF's throw velocities (x, z U(-2, 2), y U(-0.5, 0.5) m/s)")
    ap.add_argument("--work", default=None, help="simulation folder (default <out>/.work)")
    args = ap.parse_args()
    os.makedirs(args.out, exist_ok=True)
    work_root = os.path.abspath(args.work or os.path.join(args.out, ".work"))
    for seed in parse_seeds(args.seeds):
        scene_id = f"sim_{seed:04d}"
        if any(f.startswith(scene_id + "_") and f.endswith(".msgpack.zst") for f in os.listdir(args.out)):
            print(f"[{scene_id}] already written", flush=True)
            continue
        spec = random_spec(seed, args.frames, args.speed)
        t0 = time.time()
        sim = simulate(spec, os.path.join(work_root, scene_id))
        lo, hi = np.array(spec["walls_lo"]), np.array(spec["walls_hi"])
        box, normals = box_particles(lo, hi, WALL_SPACING, 1, open_top=False)
        pos, vel = sim["pos"], sim["vel"]
        inside = np.all((pos >= lo - RADIUS) & (pos <= hi + RADIUS), axis=2).mean()
        write_records(args.out, scene_id, pos, vel, box, normals, args.frames_per_file)
        with open(os.path.join(args.out, f"{scene_id}.json"), "w") as f:
            json.dump({"spec": spec, "particles": int(pos.shape[1]), "box_points": int(len(box)),
                       "inside_walls": float(inside), "seconds": round(time.time() - t0, 1)}, f, indent=1)
        print(f"[{scene_id}] {spec['fluid']['shape']}, {pos.shape[1]} particles, {len(pos)} frames, "
              f"{len(box)} box points, {time.time() - t0:.0f} s", flush=True)
        shutil.rmtree(os.path.join(work_root, scene_id, "sph"), ignore_errors=True)


if __name__ == "__main__":
    main()
