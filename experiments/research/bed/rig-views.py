#!/usr/bin/env python3
"""The `joint.extra_views` of a rig of RIG views on a bed scene (issue 71, item 5): RIG 2 adds the
warm-up view whose camera is farthest from the training view's (the opposite one on a ring),
RIG 4 the three farthest. Prints the TOML list.

    python3 experiments/research/bed/rig-views.py SCENE_DIR RIG
"""

import json
import math
import sys

scene, rig = sys.argv[1], int(sys.argv[2])
m = json.load(open(f"{scene}/scene.json"))
train = m["train"]["views"][0]


def centre(v):
    t = json.load(open(f"{scene}/{v}/transforms_train.json"))["frames"][0]["transform_matrix"]
    return [t[i][3] for i in range(3)]


others = [v for v in m["warmup"]["views"] if v != train]
others.sort(key=lambda v: -math.dist(centre(v), centre(train)))
if rig not in (2, 4) or len(others) < rig - 1:
    sys.exit(f"RIG: 2 or 4 with {len(others)} other warm-up views, not {rig}")
print("[" + ", ".join(f'"{v}"' for v in others[: rig - 1]) + "]")
