#!/usr/bin/env python3
"""Hostile inputs against the built `neurofluid-train`, as an attacker who has read the README
and the code would try them: each case builds a damaged or malicious scene, file, setting or
environment in a scratch folder, runs one command on it under a memory cap and a time limit,
and checks that it ends with a clear error (or the documented behaviour) in bounded memory and
time: no panic, no abort, no hang, no write outside the scratch folder, an error that names the
problem and stays short.

    scripts/hostile-probe.py target/debug/neurofluid-train [--keep DIR]

Prints one row per case (command, exit status, seconds, peak memory, verdict) and a summary;
exits 1 when any case did not hold. Python's standard library only (no numpy): the scenes are
written byte by byte (PNG, `.npy`/`.npz`, JSON).
"""

import json
import os
import resource
import shutil
import struct
import subprocess
import sys
import tempfile
import time
import zipfile
import zlib

TIME_LIMIT_S = 30
PEAK_LIMIT_MIB = 1536  # resident memory a refusal may take
ADDRESS_CAP = 16 << 30  # a safety net for the machine, far above what the tool may use
MESSAGE_LIMIT = 20_000  # bytes of stderr a refusal may take


# ---------------------------------------------------------------- files, byte by byte


def png(width, height, rgba=None, color_type=6, depth=8, palette=None, raw=None):
    """A PNG (colour type 6: RGBA8; 3: indexed with `palette`) of `rgba` rows, or `raw` data."""

    def chunk(kind, data):
        body = kind + data
        return struct.pack(">I", len(data)) + body + struct.pack(">I", zlib.crc32(body))

    ihdr = struct.pack(">IIBBBBB", width, height, depth, color_type, 0, 0, 0)
    if raw is None:
        px = 4 if color_type == 6 else 1
        rgba = rgba or [0] * (width * height * px)
        rows = b"".join(
            b"\0" + bytes(rgba[y * width * px : (y + 1) * width * px]) for y in range(height)
        )
        raw = zlib.compress(rows)
    out = b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr)
    if palette is not None:
        out += chunk(b"PLTE", bytes(palette))
    return out + chunk(b"IDAT", raw) + chunk(b"IEND", b"")


def npy(array_bytes, shape, descr="<f4", fortran=False, header=None):
    """An `.npy` file: the header as NumPy writes it, then the data."""
    if header is None:
        shape_text = "(" + ", ".join(str(s) for s in shape) + ("," if len(shape) == 1 else "") + ")"
        header = "{'descr': '%s', 'fortran_order': %s, 'shape': %s, }" % (
            descr,
            "True" if fortran else "False",
            shape_text,
        )
    header = header.encode("latin1") if isinstance(header, str) else header
    pad = 64 - (10 + len(header) + 1) % 64
    header += b" " * pad + b"\n"
    return b"\x93NUMPY\x01\x00" + struct.pack("<H", len(header)) + header + array_bytes


def f32(values):
    return struct.pack("<%df" % len(values), *values)


def npz(path, arrays):
    with zipfile.ZipFile(path, "w") as z:
        for name, data in arrays.items():
            z.writestr(name + ".npy", data)


def particles_npz(path, n=8, z0=0.5):
    pos = []
    for i in range(n):
        pos += [0.05 * (i % 4) - 0.1, 0.05 * (i // 4) - 0.1, z0]
    npz(path, {"pos": npy(f32(pos), (n, 3)), "vel": npy(f32([0.0] * 3 * n), (n, 3))})


def write_json(path, value):
    with open(path, "w") as f:
        json.dump(value, f)


def read_json(path):
    with open(path) as f:
        return json.load(f)


def camera(k):
    """A camera on a ring around the z axis, looking at the origin."""
    import math

    a = 2 * math.pi * k / 6
    s, c = math.sin(a), math.cos(a)
    return [[c, 0.0, s, 3 * s], [s, 0.0, -c, -3 * c], [0.0, 1.0, 0.0, 0.5], [0, 0, 0, 1]]


def make_scene(root, size=16, frames=3):
    """A small valid scene: warm-up views 1-2, training view 1, test view 3."""
    os.makedirs(root, exist_ok=True)
    manifest = {
        "name": "probe",
        "up_axis": "z",
        "particle_radius": 0.025,
        "fps": 50.0,
        "warmup": {"views": ["view_1", "view_2"], "split": "train", "frames": {"start": 0, "end": 1}},
        "train": {"views": ["view_1"], "split": "train", "frames": {"start": 0, "end": frames}},
        "test": {"views": ["view_3"], "split": "test", "frames": {"start": 0, "end": frames}},
        "box_file": "box.npz",
        "box_interior": {"min": [-0.5, -0.5, 0.0], "max": [0.5, 0.5, 1.0]},
        "near": 0.1,
        "far": 8.0,
    }
    write_json(os.path.join(root, "scene.json"), manifest)
    box = [0.0, 0.0, 0.0, 0.1, 0.0, 0.0]
    normals = [0.0, 0.0, 1.0, 0.0, 0.0, 1.0]
    npz(
        os.path.join(root, "box.npz"),
        {"box": npy(f32(box), (2, 3)), "box_normals": npy(f32(normals), (2, 3))},
    )
    rgba = []
    for y in range(size):
        for x in range(size):
            inside = abs(x - size / 2) < size / 4 and abs(y - size / 2) < size / 4
            rgba += [40, 90, 200, 255] if inside else [255, 255, 255, 0]
    for k, split in [(1, "train"), (2, "train"), (3, "test")]:
        view = os.path.join(root, "view_%d" % k)
        os.makedirs(os.path.join(view, split, "particles"), exist_ok=True)
        entries = []
        for t in range(frames):
            with open(os.path.join(view, split, "%04d.png" % t), "wb") as f:
                f.write(png(size, size, rgba))
            particles_npz(os.path.join(view, split, "particles", "%04d.npz" % t), z0=0.5 - 0.01 * t)
            entries.append(
                {
                    "file_path": "./%s/%04d" % (split, t),
                    "transform_matrix": camera(k),
                    "particle_path": "particles/%04d.npz" % t,
                }
            )
        write_json(
            os.path.join(view, "transforms_%s.json" % split),
            {"camera_angle_x": 0.8, "frames": entries},
        )
    return manifest


# ---------------------------------------------------------------- running a case


def limit_child():
    resource.setrlimit(resource.RLIMIT_AS, (ADDRESS_CAP, ADDRESS_CAP))


def run(exe, args, cwd, env=None):
    """Runs one command; its exit status (or "timeout"), output, seconds and peak RSS (KiB)."""
    full_env = dict(os.environ)
    full_env.update(env or {})
    start = time.time()
    with tempfile.TemporaryFile() as out, tempfile.TemporaryFile() as err:
        child = subprocess.Popen(
            [exe] + args, cwd=cwd, env=full_env, stdout=out, stderr=err, preexec_fn=limit_child
        )
        rc = None
        while rc is None:
            pid, status, usage = os.wait4(child.pid, os.WNOHANG)
            if pid:
                rc = os.waitstatus_to_exitcode(status)
                peak = usage.ru_maxrss
            elif time.time() - start > TIME_LIMIT_S:
                child.kill()
                _, _, usage = os.wait4(child.pid, 0)
                rc, peak = "timeout", usage.ru_maxrss
            else:
                time.sleep(0.02)
        child.returncode = 0  # reaped above
        out.seek(0)
        err.seek(0)
        text_out = out.read().decode("utf8", "replace")
        text_err = err.read().decode("utf8", "replace")
    return rc, text_out, text_err, time.time() - start, peak


class Probe:
    def __init__(self, exe, scratch):
        self.exe = os.path.abspath(exe)
        self.scratch = scratch
        self.rows = []
        self.n = 0

    def case(self, name, setup, args, expect, ok_codes=(1,), env=None, after=None):
        """One case: `setup(dir)` builds it in a fresh folder; `args(dir)` is the command line;
        `expect` is a word the error must hold; `after(dir)` may check what is left."""
        self.n += 1
        d = os.path.join(self.scratch, "case-%03d" % self.n)
        os.makedirs(d)
        outside = os.path.join(self.scratch, "outside")
        os.makedirs(outside, exist_ok=True)
        try:
            setup(d)
        except Exception as e:  # a broken case is the probe's fault, said as such
            self.rows.append((name, "setup", 0, 0, "PROBE ERROR: %s" % e))
            return
        rc, out, err, seconds, peak = run(self.exe, args(d), d, env)
        text = out + err
        problems = []
        if rc == "timeout":
            problems.append("hung (> %d s)" % TIME_LIMIT_S)
        elif rc not in ok_codes:
            problems.append("exit %s (expected %s)" % (rc, "/".join(map(str, ok_codes))))
        if "panicked" in text or "RUST_BACKTRACE" in text:
            problems.append("panic")
        if expect and expect.lower() not in text.lower():
            problems.append("no %r in the message" % expect)
        if peak / 1024 > PEAK_LIMIT_MIB:
            problems.append("%.0f MiB resident" % (peak / 1024))
        if len(err) > MESSAGE_LIMIT:
            problems.append("a %d-byte message" % len(err))
        if os.listdir(outside):
            problems.append("wrote outside: %s" % os.listdir(outside))
        if after:
            msg = after(d)
            if msg:
                problems.append(msg)
        verdict = "held" if not problems else "FAILED: " + "; ".join(problems)
        first = next((l for l in err.splitlines() if l.startswith("error")), err.strip()[-150:])
        self.rows.append((name, rc, seconds, peak / 1024, verdict, first[:150]))


# ---------------------------------------------------------------- the cases


def cases(p):
    info = lambda d: ["info", os.path.join(d, "s")]
    scene = lambda d: make_scene(os.path.join(d, "s"))
    s = lambda d, *rel: os.path.join(d, "s", *rel)

    def edit_manifest(fn):
        def setup(d):
            scene(d)
            m = read_json(s(d, "scene.json"))
            fn(m)
            write_json(s(d, "scene.json"), m)

        return setup

    def edit_transforms(fn, view="view_1", split="train"):
        def setup(d):
            scene(d)
            path = s(d, view, "transforms_%s.json" % split)
            t = read_json(path)
            fn(t)
            write_json(path, t)

        return setup

    def replace(rel, content=None, action=None):
        def setup(d):
            scene(d)
            path = s(d, *rel.split("/"))
            os.remove(path)
            if action:
                action(path)
            else:
                with open(path, "wb") as f:
                    f.write(content)

        return setup

    # the base scene itself opens: the probe's own control
    p.case("control: a valid scene", scene, info, "probe", ok_codes=(0,))

    # scene.json
    p.case("scene.json: a FIFO", replace("scene.json", action=os.mkfifo), info, "FIFO")
    p.case("scene.json: a link to /dev/zero", replace("scene.json", action=lambda q: os.symlink("/dev/zero", q)), info, "device")
    p.case("scene.json: 2 GB sparse", replace("scene.json", action=lambda q: open(q, "wb").truncate(2 << 30)), info, "limit")
    p.case("scene.json: 100 000 nested arrays", replace("scene.json", b"[" * 100_000), info, "scene.json")
    p.case("scene.json: not UTF-8", replace("scene.json", b"\xff\xfe{}"), info, "UTF-8")
    p.case("scene.json: empty", replace("scene.json", b""), info, "scene.json")
    p.case("scene.json: fps 1e-30", edit_manifest(lambda m: m.update(fps=1e-30)), info, "fps")
    p.case("scene.json: fps 1e300", edit_manifest(lambda m: m.update(fps=1e300)), info, "scene.json")
    p.case("scene.json: radius 0", edit_manifest(lambda m: m.update(particle_radius=0)), info, "particle_radius")
    p.case("scene.json: radius 50 m", edit_manifest(lambda m: m.update(particle_radius=50.0)), info, "particle_radius")
    p.case("scene.json: box ±1e30", edit_manifest(lambda m: m["box_interior"].update(min=[-1e30, -1, 0])), info, "box_interior")
    p.case("scene.json: box min > max", edit_manifest(lambda m: m["box_interior"].update(min=[1, 1, 1])), info, "box_interior")
    p.case("scene.json: far 1e30", edit_manifest(lambda m: m.update(far=1e30)), info, "near/far")
    p.case("scene.json: near < 0", edit_manifest(lambda m: m.update(near=-1)), info, "near/far")
    p.case("scene.json: a test view listed 200 times", edit_manifest(lambda m: m["test"].update(views=["view_3"] * 200)), info, "twice")
    p.case("scene.json: view `..`", edit_manifest(lambda m: m["test"].update(views=[".."])), info, "plain name")
    p.case("scene.json: view with a newline", edit_manifest(lambda m: m["test"].update(views=["a\n| x |"])), info, "transforms_test.json")
    p.case("scene.json: view of 300 bytes", edit_manifest(lambda m: m["test"].update(views=["v" * 300])), info, "255 bytes")
    p.case("scene.json: view of 50 MB (a short message)", edit_manifest(lambda m: m["test"].update(views=["v" * (50 << 20)])), info, "characters")
    p.case("scene.json: split `/etc`", edit_manifest(lambda m: m["test"].update(split="/etc")), info, "plain name")
    p.case("scene.json: frames end 10^18", edit_manifest(lambda m: m["train"].update(frames={"start": 0, "end": 10**18})), info, "frames")
    p.case("scene.json: frames start > end", edit_manifest(lambda m: m["train"].update(frames={"start": 5, "end": 2})), info, "start < end")
    p.case("scene.json: box_file `../../etc/passwd`", edit_manifest(lambda m: m.update(box_file="../../etc/passwd")), info, "box_file")
    p.case("scene.json: validation view = a test view", edit_manifest(lambda m: m.update(validation={"views": ["view_3"], "split": "test", "frames": {"start": 0, "end": 3}})), info, "validation")
    p.case("scene.json: up axis `w`", edit_manifest(lambda m: m.update(up_axis="w")), info, "unknown variant")

    # transforms files
    p.case("transforms: camera_angle_x 0", edit_transforms(lambda t: t.update(camera_angle_x=0)), info, "camera_angle_x")
    p.case("transforms: camera_angle_x 4 rad", edit_transforms(lambda t: t.update(camera_angle_x=4)), info, "camera_angle_x")
    p.case("transforms: no frames", edit_transforms(lambda t: t.update(frames=[])), info, "frames")
    p.case("transforms: a 3×4 matrix", edit_transforms(lambda t: t["frames"][0].update(transform_matrix=camera(1)[:3])), info, "transforms_train.json")
    p.case("transforms: matrix of strings", edit_transforms(lambda t: t["frames"][0].update(transform_matrix=[["NaN"] * 4] * 4)), info, "transforms_train.json")
    p.case("transforms: camera 1e30 away", edit_transforms(lambda t: [f["transform_matrix"][0].__setitem__(3, 1e30) for f in t["frames"]]), info, "camera position")
    p.case("transforms: a sheared rotation", edit_transforms(lambda t: [f["transform_matrix"][1].__setitem__(2, 0.9) for f in t["frames"]]), info, "rotation")
    p.case("transforms: a mirrored scale 10^5", edit_transforms(lambda t: [f.update(transform_matrix=[[v * 1e5 if j < 3 and i < 3 else v for j, v in enumerate(r)] for i, r in enumerate(f["transform_matrix"])]) for f in t["frames"]]), info, "rotation")
    p.case("transforms: file_path absolute", edit_transforms(lambda t: t["frames"][0].update(file_path="/etc/passwd")), info, "file_path")
    p.case("transforms: particle_path climbing out", edit_transforms(lambda t: t["frames"][0].update(particle_path="../../../../x.npz")), info, "particle_path")
    p.case("transforms: fl_x -5", edit_transforms(lambda t: t.update(fl_x=-5)), info, "fl_x")
    p.case("transforms: w 10^9 (no image)", edit_transforms(lambda t: t.update(w=10**9, h=10**9)), info, "transforms_train.json")
    p.case("transforms: a FIFO", replace("view_3/transforms_test.json", action=os.mkfifo), info, "FIFO")
    p.case("transforms: a folder", replace("view_3/transforms_test.json", action=os.mkdir), info, "folder")
    p.case("transforms: test camera = training camera", edit_transforms(lambda t: [f.update(transform_matrix=camera(1)) for f in t["frames"]], "view_3", "test"), info, "novel")

    # images (headers: `info` reads the first image's)
    p.case("PNG: 0×0", replace("view_1/train/0000.png", png(0, 0, raw=b"")), info, "0000.png")
    p.case("PNG: header 60 000² in 100 bytes", replace("view_1/train/0000.png", png(60000, 60000, raw=zlib.compress(b""))), info, "limit")
    p.case("PNG: truncated after the signature", replace("view_1/train/0000.png", b"\x89PNG\r\n\x1a\n"), info, "0000.png")
    p.case("PNG: a JPEG's bytes", replace("view_1/train/0000.png", b"\xff\xd8\xff\xe0" + b"\0" * 100), info, "0000.png")
    p.case("PNG: a 3 GB sparse file", replace("view_1/train/0000.png", action=lambda q: open(q, "wb").truncate(3 << 30)), info, "limit")
    p.case("PNG: 16² where w says 32", edit_transforms(lambda t: t.update(w=32, h=32)), info, "size")

    # particles and the box (read by `mesh` and `info`)
    mesh = lambda rel: (lambda d: ["mesh", s(d, *rel.split("/")), "--output", os.path.join(d, "m")])
    pp = "view_1/train/particles/0000.npz"
    p.case("npz: an empty zip", replace(pp, action=lambda q: zipfile.ZipFile(q, "w").close()), mesh(pp), "pos")
    p.case("npz: pos of shape (8, 2)", replace(pp, action=lambda q: npz(q, {"pos": npy(f32([0.0] * 16), (8, 2))})), mesh(pp), "shape")
    p.case("npz: pos as float16", replace(pp, action=lambda q: npz(q, {"pos": npy(b"\0" * 48, (8, 3), "<f2")})), mesh(pp), "f2")
    p.case("npz: Fortran order", replace(pp, action=lambda q: npz(q, {"pos": npy(f32([0.0] * 24), (8, 3), fortran=True)})), mesh(pp), "fortran")
    p.case("npz: NaN positions", replace(pp, action=lambda q: npz(q, {"pos": npy(f32([float("nan")] * 24), (8, 3))})), mesh(pp), "finite")
    p.case("npz: a header of 60 000 bytes", replace(pp, action=lambda q: npz(q, {"pos": npy(b"", (0, 3), header="{" + " " * 60000 + "}")})), mesh(pp), "pos")
    p.case("npz: shape (2^40, 3) in 200 bytes", replace(pp, action=lambda q: npz(q, {"pos": npy(b"", (1 << 40, 3))})), mesh(pp), "limit")
    p.case("npz: a negative dimension", replace(pp, action=lambda q: npz(q, {"pos": npy(b"", (-3, 3), header="{'descr': '<f4', 'fortran_order': False, 'shape': (-3, 3), }")})), mesh(pp), "pos")
    p.case("npz: two 600 MiB arrays, each within the limit", replace(pp, action=lambda q: _two_big_arrays(q)), mesh(pp), "limit")
    p.case("npz: 20 000 particles at one point", replace(pp, action=lambda q: npz(q, {"pos": npy(f32([0.1, 0.2, 0.3] * 20000), (20000, 3)), "vel": npy(f32([0.0] * 60000), (20000, 3))})), mesh(pp), "neighbour pairs")
    p.case("mesh: --radius 1e30", scene, lambda d: mesh(pp)(d) + ["--radius", "1e30"], "radius")
    p.case("mesh: --threshold 1e30", scene, lambda d: mesh(pp)(d) + ["--threshold", "1e30"], "--threshold")
    p.case("mesh: --radius NaN", scene, lambda d: mesh(pp)(d) + ["--radius", "NaN"], "radius")
    p.case("mesh: --cube-size 1e-9", scene, lambda d: mesh(pp)(d) + ["--cube-size", "1e-9"], "cube")
    p.case("mesh: input a FIFO", replace(pp, action=os.mkfifo), mesh(pp), "FIFO")
    p.case("mesh: an npz without `pos`", replace("box.npz", action=lambda q: npz(q, {"box": npy(f32([0.0] * 6), (2, 3))})), lambda d: ["mesh", s(d, "box.npz"), "--output", os.path.join(d, "m")], "pos")

    # the environment
    p.case("NEUROFLUID_MAX_DATASET_MB=abc", scene, info, "NEUROFLUID_MAX_DATASET_MB", env={"NEUROFLUID_MAX_DATASET_MB": "abc"})
    p.case("NEUROFLUID_MAX_DATASET_MB=1 (a scene over it)", lambda d: make_scene(os.path.join(d, "s"), size=400, frames=3), info, "NEUROFLUID_MAX_DATASET_MB", env={"NEUROFLUID_MAX_DATASET_MB": "1"})
    p.case("NEUROFLUID_MAX_FILE_MB=-1", scene, info, "NEUROFLUID_MAX_FILE_MB", env={"NEUROFLUID_MAX_FILE_MB": "-1"})

    # experiment files and settings
    def experiment(text):
        def setup(d):
            scene(d)
            with open(os.path.join(d, "e.toml"), "w") as f:
                f.write(text.replace("SCENE", s(d)))

        return setup

    rollout = lambda d: ["rollout", os.path.join(d, "e.toml")]
    base = 'name = "probe"\n[scene]\npath = "SCENE"\n'
    p.case("TOML: an unknown key", experiment(base + "[joint]\nbogus = 1\n"), rollout, "bogus")
    p.case("TOML: lr = nan", experiment(base + "[joint.dlf_optim]\nlr = nan\n"), rollout, "lr")
    p.case("TOML: lr = inf", experiment(base + "[joint.dlf_optim]\nlr = inf\n"), rollout, "lr")
    p.case("TOML: an integer of 30 digits", experiment(base + "[warmup]\niters = 999999999999999999999999999999\n"), rollout, "e.toml")
    p.case("TOML: a key of 1 MB", experiment(base + "x" * (1 << 20) + " = 1\n"), rollout, "e.toml")
    p.case("TOML: 100 000 nested tables", experiment(base + "a = " + "[" * 100_000 + "\n"), rollout, "e.toml")
    p.case("TOML: eval.views listing one view 500 times", experiment(base + '[eval]\nviews = [' + ', '.join(['"view_3"'] * 500) + ']\n'), rollout, "twice")
    p.case("TOML: a retired key", experiment(base + "[dlf]\nfree_flight = true\n"), rollout, "free_flight")
    p.case("TOML: the file is a FIFO", lambda d: (scene(d), os.mkfifo(os.path.join(d, "e.toml"))), rollout, "FIFO")
    p.case("--set with no `=`", experiment(base), lambda d: rollout(d) + ["--set", "joint.epochs"], "joint.epochs")

    # sweeps
    def sweep(text):
        def setup(d):
            scene(d)
            with open(os.path.join(d, "e.toml"), "w") as f:
                f.write(base.replace("SCENE", s(d)))
            with open(os.path.join(d, "w.toml"), "w") as f:
                f.write(text)

        return setup

    sw = lambda *extra: (lambda d: ["sweep", os.path.join(d, "w.toml")] + list(extra))
    p.case("sweep: a variant named `../x`", sweep('base = "e.toml"\n[[variant]]\nname = "../x"\n'), sw("--status"), "variant")
    p.case("sweep: a seed listed twice", sweep('base = "e.toml"\nseeds = [1, 1]\n'), sw("--status"), "twice")
    p.case("sweep: --status with no sweep folder", sweep('base = "e.toml"\n'), sw("--status"), "no sweep folder", after=lambda d: "made runs/" if os.path.exists(os.path.join(d, "runs")) else None)
    p.case("sweep: --table with no sweep folder", sweep('base = "e.toml"\n'), sw("--table"), "no sweep folder", after=lambda d: "made runs/" if os.path.exists(os.path.join(d, "runs")) else None)
    p.case("sweep: --partition with a space", sweep('base = "e.toml"\n'), sw("--slurm", "--dry-run", "--partition", "a b"), "one word")
    p.case("sweep: [slurm] sbatch line with a newline", sweep('base = "e.toml"\n[slurm]\nsbatch = ["--x\\n--y"]\n'), sw("--status"), "one line")
    p.case("sweep: --fresh with --status", sweep('base = "e.toml"\n'), sw("--status", "--fresh"), "cannot be used", ok_codes=(2,))


def _two_big_arrays(path):
    """Two 600 MiB zero arrays, deflated to a few MB: each within the 1 GiB limit, together over."""
    n = (600 << 20) // 12
    with zipfile.ZipFile(path, "w", compression=zipfile.ZIP_DEFLATED) as z:
        for name in ["vel", "pos"]:
            with z.open(name + ".npy", "w", force_zip64=True) as f:
                f.write(npy(b"", (n, 3)))
                chunk = b"\0" * (12 << 20)
                for _ in range(50):
                    f.write(chunk)


def main():
    if len(sys.argv) < 2:
        print(__doc__)
        return 2
    exe = sys.argv[1]
    keep = sys.argv[3] if len(sys.argv) > 3 and sys.argv[2] == "--keep" else None
    scratch = keep or tempfile.mkdtemp(prefix="nf-probe-")
    os.makedirs(scratch, exist_ok=True)
    p = Probe(exe, scratch)
    cases(p)
    width = max(len(r[0]) for r in p.rows)
    failed = 0
    print("| case | exit | s | peak MiB | verdict | first error line |\n|---|---|---|---|---|---|")
    for row in p.rows:
        if len(row) == 5:
            name, rc, seconds, peak, verdict = row
            first = ""
        else:
            name, rc, seconds, peak, verdict, first = row
        if verdict != "held":
            failed += 1
        print("| %s | %s | %.1f | %.0f | %s | %s |" % (name.ljust(width), rc, seconds, peak, verdict, first.replace("|", "\\|")))
    print("\n%d cases: %d held, %d did not" % (len(p.rows), len(p.rows) - failed, failed))
    if not keep:
        shutil.rmtree(scratch, ignore_errors=True)
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
