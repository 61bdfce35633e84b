"""The test-bed scenes: one dict each. Every scene differs from `neurofluid-scenegen`'s (y-up box
[-0.7, 0.7]×[-0.7, 1.0]×[-0.7, 0.7], walls at 0.0321 m, a 26° ring of five views with
camera_angle_x 0.55, its own SPH code and ray-marched renderer) in the ways listed in `differs`.

Keys:
  sim      the SPlisHSPlasH run (bed_sim.py): up axis, walls (the container's inner faces),
           time step, fluid shape and material (SPlisHSPlasH's material keys)
  walls    the DLF box particles: spacing (m), open_top
  cameras  "ring" (warm-up views at azimuths, one elevation; a test view) or "list" (explicit
           eyes/targets); angle_x = horizontal field of view (rad); fill = the share of the image
           half-width that the box's bounding sphere spans
  render   image size, Cycles samples, material ("water" glass or "honey" opaque), how the
           intrinsics are written ("angle": camera_angle_x only, NeRF-synthetic style; "pixels":
           fl_x/fl_y/cx/cy/w/h only, nerfstudio style), the file_path style
  roles    which views warm up (frame 0), train (frames 0-49), test (frames 0-59);
           warmup_every_frame renders the warm-up views at every training frame too (NeRF-T)
"""

FRAMES = 60
TRAIN_FRAMES = 50

WATER = {"viscosityMethod": 1, "viscosity": 0.01}  # SPlisHSPlasH's standard viscosity

SCENES = {
    "water-dam-z": {
        "spec": "water, z-up, a 3.1k-particle block dropped 0.15 m into a 1.6x1.2x1.4 m closed box "
                "and collapsing; walls at 0.04 m; glass water on a transparent film; 100²; a 35° ring "
                "at the 50 mm-lens field of view",
        "differs": ["z-up", "another DFSPH code", "box walls at 0.04 m, each face on its own grid", "path-traced glass water",
                    "camera ring: 35° elevation, fov 0.69 rad", "camera_angle_x only (half-pixel convention of Blender data)"],
        "sim": {
            "up": "z", "walls_lo": [-0.8, -0.6, 0.0], "walls_hi": [0.8, 0.6, 1.4],
            "dt": 0.0025, "frames": FRAMES, "density": 1000.0, "material": WATER,
            "fluid": {"shape": "block", "start": [-0.78, -0.58, 0.12], "end": [-0.17, 0.58, 0.8]},
        },
        "walls": {"spacing": 0.04, "open_top": False},
        "cameras": {
            "kind": "ring", "angle_x": 0.6911, "fill": 0.85, "target_height": 0.38,
            "warmup": {"elevation_deg": 35.0, "azimuths_deg": [30.0, 120.0, 210.0, 300.0]},
            "test": [{"elevation_deg": 18.0, "azimuth_deg": 75.0}],
        },
        "render": {"size": 100, "samples": 16, "material": "water", "intrinsics": "angle",
                   "file_path": "./{split}/{stem}"},
        "roles": {"train_view": 0, "warmup_every_frame": True},
    },
    "honey-drop-z": {
        "spec": "honey (Weiler 2018 implicit viscosity, density 1420), z-up, a 3.1k-particle tilted "
                "cylinder dropped into a 1.3x1.3x1.25 m closed box; walls at 0.028 m; opaque amber; 100²; "
                "a low 20° ring with a narrow fov",
        "differs": ["z-up", "another viscosity model (implicit, Weiler 2018)", "box walls at 0.028 m",
                    "path-traced opaque amber", "camera ring: 20° elevation, fov 0.45 rad, far",
                    "test view from 48° above"],
        "sim": {
            "up": "z", "walls_lo": [-0.65, -0.65, 0.0], "walls_hi": [0.65, 0.65, 1.25],
            "dt": 0.0025, "frames": FRAMES, "density": 1420.0,
            "material": {"viscosityMethod": 6, "viscosity": 1.0, "viscosityBoundary": 1.0,
                         "viscoMaxIter": 100, "viscoMaxError": 0.01},
            "fluid": {"shape": "cylinder", "radius": 0.42, "height": 0.72, "center": [0.05, -0.03, 0.62],
                      "axis": [1.0, 1.0, 0.0], "angle_deg": 20.0},
        },
        "walls": {"spacing": 0.028, "open_top": False},
        "cameras": {
            "kind": "ring", "angle_x": 0.45, "fill": 0.8, "target_height": 0.3,
            "warmup": {"elevation_deg": 20.0, "azimuths_deg": [10.0, 100.0, 190.0, 280.0]},
            "test": [{"elevation_deg": 48.0, "azimuth_deg": 145.0}],
        },
        "render": {"size": 100, "samples": 16, "material": "honey", "intrinsics": "angle",
                   "file_path": "{split}/{stem}.png"},
        "roles": {"train_view": 0, "warmup_every_frame": True},
    },
    "water-sphere-y": {
        "spec": "water, y-up, a 4.2k-particle sphere (r 0.5 m) dropped from 0.45 m in a 1.5x1.7x1.5 m "
                "box; walls at 0.045 m; glass water; 400² (warm-up too); five cameras off any ring "
                "(7.8-8.8 m from off-centre targets, 1.0-6.5 m high), fov 0.40 rad; intrinsics in pixels",
        "differs": ["y-up like ours but another box and walls (0.045 m)", "400² images",
                    "irregular camera positions, long focal length", "fl_x/cx intrinsics (nerfstudio), no camera_angle_x",
                    "training view is view_3"],
        "sim": {
            "up": "y", "walls_lo": [-0.75, 0.0, -0.75], "walls_hi": [0.75, 1.7, 0.75],
            "dt": 0.002, "frames": FRAMES, "density": 1000.0, "material": WATER,
            "fluid": {"shape": "sphere", "radius": 0.5, "center": [0.08, 0.98, -0.05], "mode": 0},
        },
        "walls": {"spacing": 0.045, "open_top": False},
        "cameras": {
            "kind": "list", "angle_x": 0.40, "up": [0.0, 1.0, 0.0],
            "warmup": [
                {"eye": [5.58, 4.24, 5.22], "target": [0.0, 0.55, 0.0]},
                {"eye": [-6.52, 1.78, 3.96], "target": [0.05, 0.7, 0.0]},
                {"eye": [-2.12, 6.54, -6.16], "target": [-0.05, 0.6, 0.05]},
                {"eye": [7.92, 1.02, -3.38], "target": [0.0, 0.75, -0.05]},
            ],
            "test": [{"eye": [1.08, 3.08, 8.28], "target": [0.0, 0.65, 0.0]}],
        },
        "render": {"size": 400, "samples": 8, "material": "water", "intrinsics": "pixels",
                   "file_path": "./{split}/{stem}"},
        "roles": {"train_view": 2, "warmup_every_frame": True},
    },
    "water-torus-tilted-z": {
        "spec": "water, z-up, a 3.2k-particle torus (R 0.5, r 0.2) tilted 35° and thrown sideways at "
                "(1.2, 0.5, 0) m/s with a spin, in a 1.8x1.8x1.6 m box; walls at 0.036 m; "
                "glass water; 100²; a 28° ring",
        "differs": ["z-up", "a shape the generator has not", "initial velocity and spin",
                    "box walls at 0.036 m", "path-traced glass water", "camera ring: 28°, fov 0.60 rad"],
        "sim": {
            "up": "z", "walls_lo": [-0.9, -0.9, 0.0], "walls_hi": [0.9, 0.9, 1.6],
            "dt": 0.002, "frames": FRAMES, "density": 1000.0, "material": WATER,
            "fluid": {"shape": "torus", "major": 0.5, "minor": 0.2, "center": [-0.12, 0.05, 0.95],
                      "axis": [1.0, 0.3, 0.0], "angle_deg": 35.0, "velocity": [1.2, 0.5, 0.0],
                      "angular_velocity": [0.0, 0.0, 1.5], "mode": 0},
        },
        "walls": {"spacing": 0.036, "open_top": False},
        "cameras": {
            "kind": "ring", "angle_x": 0.60, "fill": 0.8, "target_height": 0.35,
            "warmup": {"elevation_deg": 28.0, "azimuths_deg": [-15.0, 80.0, 165.0, 260.0]},
            "test": [{"elevation_deg": 40.0, "azimuth_deg": 215.0}],
        },
        "render": {"size": 100, "samples": 16, "material": "water", "intrinsics": "angle",
                   "file_path": "./{split}/{stem}"},
        "roles": {"train_view": 0, "warmup_every_frame": True},
    },
    "honey-slump-y-400": {
        "spec": "honey, y-up, a 3.7k-particle block slumping from a corner of a 1.4x1.3x1.4 m box; "
                "walls at 0.05 m; opaque amber; 400²; a 30° ring",
        "differs": ["honey at 400²", "box walls at 0.05 m", "path-traced opaque amber"],
        "sim": {
            "up": "y", "walls_lo": [-0.7, 0.0, -0.7], "walls_hi": [0.7, 1.3, 0.7],
            "dt": 0.0025, "frames": FRAMES, "density": 1420.0,
            "material": {"viscosityMethod": 6, "viscosity": 0.6, "viscosityBoundary": 0.6,
                         "viscoMaxIter": 100, "viscoMaxError": 0.01},
            "fluid": {"shape": "block", "start": [-0.68, 0.02, -0.68], "end": [0.3, 0.82, 0.0]},
        },
        "walls": {"spacing": 0.05, "open_top": False},
        "cameras": {
            "kind": "ring", "angle_x": 0.55, "fill": 0.8, "target_height": 0.3, "up": "y",
            "warmup": {"elevation_deg": 30.0, "azimuths_deg": [40.0, 130.0, 220.0, 310.0]},
            "test": [{"elevation_deg": 12.0, "azimuth_deg": 85.0}],
        },
        "render": {"size": 400, "samples": 8, "material": "honey", "intrinsics": "pixels",
                   "file_path": "{split}/{stem}"},
        "roles": {"train_view": 0, "warmup_every_frame": True},
    },
}

# Issue 71: scenes that only report (experiments/bed/README.md, "Choose on some scenes, report
# on others"): never used to choose a setting. Specified 2026-12-05, before any run on them.
SYRUP = {"viscosityMethod": 6, "viscosity": 0.15, "viscosityBoundary": 0.15,
         "viscoMaxIter": 100, "viscoMaxError": 0.01}  # a third viscosity, between water and honey

SCENES.update({
    "water-pool-rest-z": {
        "spec": "water at rest: a 0.25 m deep pool filling the floor of a 1.2x1.0x1.0 m closed box, "
                "z-up; walls at 0.04 m; glass water; 160²; a 30° ring",
        "differs": ["fluid at rest from the first frame", "z-up", "160² images",
                    "fl_x/cx intrinsics (nerfstudio)"],
        "sim": {
            "up": "z", "walls_lo": [-0.6, -0.5, 0.0], "walls_hi": [0.6, 0.5, 1.0],
            "dt": 0.0025, "frames": FRAMES, "density": 1000.0, "material": WATER,
            "fluid": {"shape": "block", "start": [-0.58, -0.48, 0.02], "end": [0.58, 0.48, 0.27]},
        },
        "walls": {"spacing": 0.04, "open_top": False},
        "cameras": {
            "kind": "ring", "angle_x": 0.55, "fill": 0.85, "target_height": 0.2,
            "warmup": {"elevation_deg": 30.0, "azimuths_deg": [20.0, 110.0, 200.0, 290.0]},
            "test": [{"elevation_deg": 15.0, "azimuth_deg": 65.0}],
        },
        "render": {"size": 160, "samples": 16, "material": "water", "intrinsics": "pixels",
                   "file_path": "./{split}/{stem}"},
        "roles": {"train_view": 0, "warmup_every_frame": True},
    },
    "water-drop-settle-y": {
        "spec": "water, y-up, a sphere (r 0.3 m) dropped 0.15 m into a 1.0x1.2x1.0 m box, spreading "
                "into a shallow pool that settles; walls at 0.035 m; glass water; 200²; four cameras "
                "off any ring, fov 0.50 rad",
        "differs": ["fluid that comes to rest within the window", "200² images",
                    "irregular camera positions", "training view is view_2"],
        "sim": {
            "up": "y", "walls_lo": [-0.5, 0.0, -0.5], "walls_hi": [0.5, 1.2, 0.5],
            "dt": 0.002, "frames": FRAMES, "density": 1000.0, "material": WATER,
            "fluid": {"shape": "sphere", "radius": 0.3, "center": [0.05, 0.45, -0.03], "mode": 0},
        },
        "walls": {"spacing": 0.035, "open_top": False},
        "cameras": {
            "kind": "list", "angle_x": 0.50, "up": [0.0, 1.0, 0.0],
            "warmup": [
                {"eye": [3.1, 2.2, 2.4], "target": [0.0, 0.3, 0.0]},
                {"eye": [-3.4, 1.4, 1.9], "target": [0.0, 0.35, 0.05]},
                {"eye": [-1.2, 3.6, -2.8], "target": [0.05, 0.3, 0.0]},
                {"eye": [3.0, 0.9, -2.6], "target": [0.0, 0.4, 0.0]},
            ],
            "test": [{"eye": [0.6, 1.9, 3.9], "target": [0.0, 0.3, 0.0]}],
        },
        "render": {"size": 200, "samples": 12, "material": "water", "intrinsics": "angle",
                   "file_path": "./{split}/{stem}"},
        "roles": {"train_view": 1, "warmup_every_frame": True},
    },
    "syrup-column-y-256": {
        "spec": "a syrup of a third viscosity (Weiler 2018, 0.15: between the bed's water 0.01 and "
                "honey 0.6-1.0; density 1300), y-up, a 0.5x0.8x0.5 m column collapsing in a "
                "1.2x1.2x1.2 m box; walls at 0.03 m; opaque amber; 256²; a 45° ring",
        "differs": ["a third viscosity", "a tall column", "256² images", "camera ring: 45° elevation"],
        "sim": {
            "up": "y", "walls_lo": [-0.6, 0.0, -0.6], "walls_hi": [0.6, 1.2, 0.6],
            "dt": 0.0025, "frames": FRAMES, "density": 1300.0, "material": SYRUP,
            "fluid": {"shape": "block", "start": [-0.2, 0.02, -0.25], "end": [0.3, 0.82, 0.25]},
        },
        "walls": {"spacing": 0.03, "open_top": False},
        "cameras": {
            "kind": "ring", "angle_x": 0.50, "fill": 0.8, "target_height": 0.35, "up": "y",
            "warmup": {"elevation_deg": 45.0, "azimuths_deg": [0.0, 90.0, 180.0, 270.0]},
            "test": [{"elevation_deg": 25.0, "azimuth_deg": 130.0}],
        },
        "render": {"size": 256, "samples": 8, "material": "honey", "intrinsics": "angle",
                   "file_path": "{split}/{stem}.png"},
        "roles": {"train_view": 0, "warmup_every_frame": True},
    },
    "water-tank-rest-y": {
        "spec": "water at rest: a 0.3 m deep pool filling the floor of a 1.0x0.9x0.8 m closed box, "
                "y-up; walls at 0.04 m; glass water on a transparent film; 100²; a 40° ring",
        "differs": ["fluid at rest from the first frame", "y-up", "a deeper pool in a smaller box",
                    "camera ring: 40° elevation, fov 0.55 rad"],
        "sim": {
            "up": "y", "walls_lo": [-0.5, 0.0, -0.4], "walls_hi": [0.5, 0.9, 0.4],
            "dt": 0.0025, "frames": FRAMES, "density": 1000.0, "material": WATER,
            "fluid": {"shape": "block", "start": [-0.48, 0.02, -0.38], "end": [0.48, 0.32, 0.38]},
        },
        "walls": {"spacing": 0.04, "open_top": False},
        "cameras": {
            "kind": "ring", "angle_x": 0.55, "fill": 0.85, "target_height": 0.2, "up": "y",
            "warmup": {"elevation_deg": 40.0, "azimuths_deg": [45.0, 135.0, 225.0, 315.0]},
            "test": [{"elevation_deg": 20.0, "azimuth_deg": 100.0}],
        },
        "render": {"size": 100, "samples": 16, "material": "water", "intrinsics": "angle",
                   "file_path": "./{split}/{stem}"},
        "roles": {"train_view": 0, "warmup_every_frame": True},
    },
})

# Which scenes choose a setting and which only report (issue 71, written before any run on the
# report-only ones): every dynamics choice so far was screened on the first five, so they go on
# choosing; the three new ones never choose, and the headline table is theirs. water-tank-rest-y
# (added 2026-12-06, before its first run) chooses: a fluid at rest among the choosing scenes,
# after U13 missed the report-only pool at rest (docs/notebook/2026-12-06-image-landscape.md).
CHOOSE = ["water-dam-z", "honey-drop-z", "water-torus-tilted-z", "water-sphere-y", "honey-slump-y-400",
          "water-tank-rest-y"]
REPORT_ONLY = ["water-pool-rest-z", "water-drop-settle-y", "syrup-column-y-256"]

# the order make_bed.py builds them in (the first two are needed first)
ORDER = CHOOSE + REPORT_ONLY
