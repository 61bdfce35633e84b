#!/usr/bin/env python3
"""Checks test-bed scenes the way crates/neurofluid-core/src/scene reads them, but every frame:

    /work/bedenv/bin/python scripts/testbed/verify_bed.py [data/bed/<scene> ...]

scene.json's fields; each role's views have transforms_<split>.json with enough frames; every
frame's image resolves (file_path without "./", ".png" appended unless present) to an RGBA PNG
of the view's size; every particle_path (relative to view_k/<split>/) holds `pos`, `vel` as N×3
float32 with one N; box.npz holds `box`, `box_normals` (unit normals pointing into the box);
every particle lies in box_interior; the near/far bounds bracket the box from every camera.
Then runs `target/debug/neurofluid-train info <scene>` when that binary exists.
"""

import json
import os
import struct
import subprocess
import sys

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.abspath(os.path.join(HERE, "..", ".."))


def png_info(path):
    with open(path, "rb") as f:
        head = f.read(33)
    assert head[:8] == b"\x89PNG\r\n\x1a\n", f"{path}: not a PNG"
    w, h, depth, ctype = struct.unpack(">IIBB", head[16:26])
    return w, h, depth, ctype


def image_path(view_dir, file_path):
    rel = file_path[2:] if file_path.startswith("./") else file_path
    p = os.path.join(view_dir, rel)
    return p if p.endswith(".png") else p + ".png"


def check(scene):
    problems = []
    m = json.load(open(os.path.join(scene, "scene.json")))
    for key in ("name", "up_axis", "particle_radius", "fps", "warmup", "train", "test", "box_file",
                "box_interior", "near", "far"):
        if key not in m:
            problems.append(f"scene.json: no `{key}`")
    lo, hi = np.array(m["box_interior"]["min"]), np.array(m["box_interior"]["max"])
    box = np.load(os.path.join(scene, m["box_file"]))
    b, bn = box["box"], box["box_normals"]
    assert b.dtype == np.float32 and b.shape == bn.shape and b.shape[1] == 3
    if not np.allclose(np.linalg.norm(bn, axis=1), 1.0, atol=1e-5):
        problems.append("box normals not unit")
    centre = 0.5 * (lo + hi)
    inward = np.einsum("ij,ij->i", centre - b, bn)
    if np.any(inward <= 0):
        problems.append(f"{int(np.sum(inward <= 0))} box normals point outward")
    n_particles, outside, images, cams = None, 0, 0, []
    seen = {}
    for role in ("warmup", "train", "test"):
        rs = m[role]
        for view in rs["views"]:
            key = (view, rs["split"])
            tf_path = os.path.join(scene, view, f"transforms_{rs['split']}.json")
            tf = seen.get(key) or json.load(open(tf_path))
            seen[key] = tf
            frames = tf["frames"]
            if len(frames) < rs["frames"]["end"]:
                problems.append(f"{tf_path}: {len(frames)} frames, {role} needs {rs['frames']['end']}")
                continue
            if "camera_angle_x" not in tf and "fl_x" not in tf:
                problems.append(f"{tf_path}: no intrinsics")
            size = None
            for t in range(rs["frames"]["start"], rs["frames"]["end"]):
                e = frames[t]
                ip = image_path(os.path.join(scene, view), e["file_path"])
                if not os.path.isfile(ip):
                    problems.append(f"missing image {ip}")
                    continue
                w, h, depth, ctype = png_info(ip)
                images += 1
                if ctype != 6:
                    problems.append(f"{ip}: PNG colour type {ctype}, not RGBA")
                size = size or (w, h)
                if (w, h) != size or ("w" in tf and (tf["w"], tf["h"]) != (w, h)):
                    problems.append(f"{ip}: {w}x{h}, view size {size}")
                pp = os.path.join(scene, view, rs["split"], e["particle_path"].removeprefix("./"))
                d = np.load(pp)
                pos, vel = d["pos"], d["vel"]
                if pos.dtype != np.float32 or pos.shape != vel.shape or pos.ndim != 2 or pos.shape[1] != 3:
                    problems.append(f"{pp}: pos {pos.dtype} {pos.shape}, vel {vel.shape}")
                n_particles = n_particles or len(pos)
                if len(pos) != n_particles:
                    problems.append(f"{pp}: {len(pos)} particles, not {n_particles}")
                if not np.all(np.isfinite(pos)):
                    problems.append(f"{pp}: non-finite positions")
                outside += int(np.sum(np.any((pos < lo) | (pos > hi), axis=1)))
                c2w = np.array(e["transform_matrix"])
                cams.append(c2w[:3, 3])
    # near/far bracket the walls (the box particles' bounds) from every camera
    blo, bhi = b.min(0), b.max(0)
    corners = np.array([[(blo, bhi)[(c >> a) & 1][a] for a in range(3)] for c in range(8)])
    for eye in cams:
        near = np.linalg.norm(eye - np.clip(eye, blo, bhi))
        far = np.max(np.linalg.norm(corners - eye, axis=1))
        if near < m["near"] - 1e-4 or far > m["far"] + 1e-4:
            problems.append(f"camera at {eye.round(3)}: box spans {near:.3f}..{far:.3f}, bounds {m['near']:.3f}..{m['far']:.3f}")
            break
    if outside:
        problems.append(f"{outside} particle-frames outside box_interior")
    return problems, {"particles": n_particles, "box_particles": len(b), "images_checked": images}


def main():
    scenes = sys.argv[1:] or sorted(
        os.path.join(ROOT, "data", "bed", d) for d in os.listdir(os.path.join(ROOT, "data", "bed"))
        if not d.startswith(".") and os.path.isfile(os.path.join(ROOT, "data", "bed", d, "scene.json")))
    binary = os.path.join(ROOT, "target", "debug", "neurofluid-train")
    bad = 0
    for s in scenes:
        problems, info = check(s)
        status = "OK" if not problems else "PROBLEMS"
        print(f"{s}: {status} {info}")
        for p in problems[:20]:
            print("   ", p)
        bad += bool(problems)
        if os.path.exists(binary):
            r = subprocess.run([binary, "info", s], capture_output=True, text=True)
            print("    neurofluid-train info: " + ("ok" if r.returncode == 0 else f"FAILED rc={r.returncode}"))
            if r.returncode != 0:
                print(r.stdout[-2000:], r.stderr[-2000:])
                bad += 1
    sys.exit(1 if bad else 0)


if __name__ == "__main__":
    main()
