"""Simulates one test-bed scene with SPlisHSPlasH's DFSPH (pysplishsplash) and saves the fluid
particles of every frame.

    python bed_sim.py <spec.json> <work dir> <out.npz>

Runs in its own process (make_bed.py starts it with LD_PRELOAD set to the system's
libGLdispatch: the wheel's bundled copy crashes at import next to the system's libGLX).
The spec is the scene's "sim" table (see make_bed.py); lengths in metres, the frame rate 50 fps.
Writes `out.npz` with `pos`, `vel` (T×N×3 float32, frame 0 the initial state) and `dt`.
"""

import json
import math
import os
import sys
import time

import numpy as np


def box_obj(path):
    """A unit cube centred at the origin (SPlisHSPlasH scales and places it)."""
    v = [(x, y, z) for z in (-0.5, 0.5) for y in (-0.5, 0.5) for x in (-0.5, 0.5)]
    # vertices: index = 1 + x + 2y + 4z
    quads = [(1, 3, 4, 2), (5, 6, 8, 7), (1, 2, 6, 5), (3, 7, 8, 4), (1, 5, 7, 3), (2, 4, 8, 6)]
    with open(path, "w") as f:
        for p in v:
            f.write("v %g %g %g\n" % p)
        for a, b, c, d in quads:
            f.write(f"f {a} {b} {c}\nf {a} {c} {d}\n")


def sphere_obj(path, radius, n_lat=48, n_lon=96):
    verts = [(0.0, 0.0, radius)]
    for i in range(1, n_lat):
        th = math.pi * i / n_lat
        for j in range(n_lon):
            ph = 2 * math.pi * j / n_lon
            verts.append((radius * math.sin(th) * math.cos(ph), radius * math.sin(th) * math.sin(ph), radius * math.cos(th)))
    verts.append((0.0, 0.0, -radius))
    faces = []
    ring = lambda i, j: 2 + (i - 1) * n_lon + (j % n_lon)
    for j in range(n_lon):
        faces.append((1, ring(1, j), ring(1, j + 1)))
    for i in range(1, n_lat - 1):
        for j in range(n_lon):
            a, b, c, d = ring(i, j), ring(i + 1, j), ring(i + 1, j + 1), ring(i, j + 1)
            faces += [(a, b, c), (a, c, d)]
    last = len(verts)
    for j in range(n_lon):
        faces.append((last, ring(n_lat - 1, j + 1), ring(n_lat - 1, j)))
    write_obj(path, verts, faces)


def torus_obj(path, major, minor, n_u=96, n_v=48):
    verts, faces = [], []
    for i in range(n_u):
        u = 2 * math.pi * i / n_u
        for j in range(n_v):
            w = 2 * math.pi * j / n_v
            r = major + minor * math.cos(w)
            verts.append((r * math.cos(u), r * math.sin(u), minor * math.sin(w)))
    idx = lambda i, j: 1 + (i % n_u) * n_v + (j % n_v)
    for i in range(n_u):
        for j in range(n_v):
            a, b, c, d = idx(i, j), idx(i + 1, j), idx(i + 1, j + 1), idx(i, j + 1)
            faces += [(a, b, c), (a, c, d)]
    write_obj(path, verts, faces)


def cylinder_obj(path, radius, height, n=96):
    verts = []
    for z in (-0.5 * height, 0.5 * height):
        for j in range(n):
            ph = 2 * math.pi * j / n
            verts.append((radius * math.cos(ph), radius * math.sin(ph), z))
    verts += [(0.0, 0.0, -0.5 * height), (0.0, 0.0, 0.5 * height)]
    bot, top = 2 * n + 1, 2 * n + 2
    faces = []
    for j in range(n):
        a, b = 1 + j, 1 + (j + 1) % n
        c, d = a + n, b + n
        faces += [(a, b, d), (a, d, c), (bot, b, a), (top, c, d)]
    write_obj(path, verts, faces)


def write_obj(path, verts, faces):
    with open(path, "w") as f:
        for p in verts:
            f.write("v %.6f %.6f %.6f\n" % p)
        for t in faces:
            f.write("f %d %d %d\n" % t)


def scene_json(spec, work):
    """The SPlisHSPlasH scene file of `spec` (written into `work`)."""
    lo, hi = np.array(spec["walls_lo"], float), np.array(spec["walls_hi"], float)
    up = {"y": 1, "z": 2}[spec["up"]]
    g = [0.0, 0.0, 0.0]
    g[up] = -9.81
    box_obj(os.path.join(work, "box.obj"))
    # the simulator's container is closed; its lid sits above the walls DLF sees when those are
    # open at the top
    sim_hi = hi.copy()
    sim_hi[up] += spec.get("sim_lid", 0.0)
    cfg = {
        "particleRadius": 0.025,
        "numberOfStepsPerRenderUpdate": 1,
        "density0": spec.get("density", 1000.0),
        "simulationMethod": 4,  # DFSPH
        "gravitation": g,
        "cflMethod": 0,  # a fixed step that divides the 1/50 s frame interval
        "timeStepSize": spec["dt"],
        "stopAt": (spec["frames"] - 1) / 50.0 + 0.5 * spec["dt"],
        "boundaryHandlingMethod": 0,  # Akinci et al. 2012 boundary particles
        "enableZSort": False,  # keep particle order fixed over the frames
        "enablePartioExport": False,
        "enableVTKExport": False,
        "maxIterations": 100,
        "maxError": 0.05,
        "maxIterationsV": 100,
        "maxErrorV": 0.1,
        "enableDivergenceSolver": True,
    }
    mat = {"id": "Fluid", "density0": spec.get("density", 1000.0), "colorMapType": 1}
    mat.update(spec.get("material", {}))
    rigid = {
        "geometryFile": "box.obj",
        "translation": list(0.5 * (lo + sim_hi)),
        "scale": list(sim_hi - lo),
        "isDynamic": False,
        "isWall": True,
        "mapInvert": True,
        "mapThickness": 0.0,
        "mapResolution": [20, 20, 20],
    }
    scene = {"Configuration": cfg, "Materials": [mat], "RigidBodies": [rigid]}
    fluid = spec["fluid"]
    kind = fluid["shape"]
    if kind == "block":
        scene["FluidBlocks"] = [{
            "id": "Fluid", "denseMode": fluid.get("mode", 0), "start": fluid["start"], "end": fluid["end"],
            "initialVelocity": fluid.get("velocity", [0, 0, 0]),
        }]
    else:
        obj = os.path.join(work, kind + ".obj")
        if kind == "sphere":
            sphere_obj(obj, fluid["radius"])
        elif kind == "torus":
            torus_obj(obj, fluid["major"], fluid["minor"])
        elif kind == "cylinder":
            cylinder_obj(obj, fluid["radius"], fluid["height"])
        else:
            raise ValueError(kind)
        scene["FluidModels"] = [{
            "id": "Fluid",
            "particleFile": os.path.basename(obj),
            "translation": fluid["center"],
            "rotationAxis": fluid.get("axis", [1, 0, 0]),
            "rotationAngle": math.radians(fluid.get("angle_deg", 0.0)),
            "scale": [1, 1, 1],
            "initialVelocity": fluid.get("velocity", [0, 0, 0]),
            "initialAngularVelocity": fluid.get("angular_velocity", [0, 0, 0]),
            "mode": fluid.get("mode", 0),
            "resolutionSDF": [48, 48, 48],
        }]
    path = os.path.join(work, "sph_scene.json")
    with open(path, "w") as f:
        json.dump(scene, f, indent=1)
    return path


def main():
    spec_path, work, out = sys.argv[1:4]
    with open(spec_path) as f:
        spec = json.load(f)
    os.makedirs(work, exist_ok=True)
    path = scene_json(spec, work)
    import pysplishsplash as sph

    steps_per_frame = round(0.02 / spec["dt"])
    assert abs(steps_per_frame * spec["dt"] - 0.02) < 1e-9, "dt must divide 1/50 s"
    base = sph.Exec.SimulatorBase()
    base.init(useGui=False, sceneFile=path, outputDir=os.path.join(work, "sph_out"))
    frames_p, frames_v, times = [], [], []
    state = {"k": 0}
    t0 = time.time()

    def grab(fm, initial=False):
        n = fm.numActiveParticles()
        gp = fm.getPosition0 if initial else fm.getPosition
        gv = fm.getVelocity0 if initial else fm.getVelocity
        p = np.array([gp(i) for i in range(n)], np.float32)
        v = np.array([gv(i) for i in range(n)], np.float32)
        return p, v

    def apply_material(fm):
        """The material's values, set on the fluid model and its viscosity object (this
        pysplishsplash build reads the method from the scene file but leaves the method's own
        coefficients at their defaults, e.g. Weiler 2018's viscosity at 0.01)."""
        wanted = {k: v for k, v in spec.get("material", {}).items() if k != "viscosityMethod"}
        done = {}
        for obj in (fm, fm.getViscosityBase()):
            if obj is None:
                continue
            for i in range(obj.numParameters()):
                name = obj.getName(i)
                if name in wanted:
                    val = wanted[name]
                    if isinstance(val, int) and not isinstance(val, bool):
                        try:
                            obj.setValueUInt(i, val)
                        except Exception:  # noqa: BLE001
                            obj.setValueInt(i, val)
                    else:
                        obj.setValueFloat(i, float(val))
                    done[name] = val
        print(f"[sim] material set: {done} (viscosity method {fm.getViscosityMethod()})", flush=True)

    def cb():
        fm = sph.Simulation.getCurrent().getFluidModel(0)
        if state["k"] == 0:
            apply_material(fm)
            p, v = grab(fm, initial=True)
            frames_p.append(p)
            frames_v.append(v)
            times.append(0.0)
        state["k"] += 1
        if state["k"] % steps_per_frame == 0 and len(frames_p) < spec["frames"]:
            p, v = grab(fm)
            frames_p.append(p)
            frames_v.append(v)
            times.append(sph.TimeManager.getCurrent().getTime())
            if len(frames_p) % 10 == 0:
                print(f"[sim] frame {len(frames_p)}/{spec['frames']} t={times[-1]:.3f} "
                      f"{time.time() - t0:.1f}s", flush=True)

    base.setTimeStepCB(cb)
    base.run()
    pos, vel = np.stack(frames_p), np.stack(frames_v)
    assert len(pos) == spec["frames"], f"{len(pos)} frames simulated, {spec['frames']} asked"
    np.savez(out, pos=pos, vel=vel, times=np.array(times), dt=spec["dt"])
    print(f"[sim] {pos.shape[1]} particles, {len(pos)} frames in {time.time() - t0:.1f}s", flush=True)


if __name__ == "__main__":
    main()
