"""Writes the box.pt fixtures of tests/tests/released_box.rs: the same dict of float32 arrays
{'box': (5, 3), 'box_normals': (5, 3)} as joblib 1.1 (the release era, no array alignment),
joblib >= 1.2 (16-byte alignment padding) and plain pickle (protocols 2 and 4), plus the
expected values as JSON.

    python -m venv v11 && v11/bin/pip install "joblib==1.1.0" "numpy<2"
    python -m venv v16 && v16/bin/pip install "joblib==1.6.0" numpy
    v11/bin/python make_boxes.py 1.1 && v16/bin/python make_boxes.py 1.6

and `box_joblib-compressed.pt` (rejected with a clear error) with
`joblib.dump(joblib.load("box_joblib-1.6.pt"), "box_joblib-compressed.pt", compress=3)`.
"""
import json
import pickle
import sys

import joblib
import numpy as np

rng = np.random.default_rng(7)
box = rng.uniform(-1.0, 1.0, size=(5, 3)).astype(np.float32)
normals = np.zeros((5, 3), dtype=np.float32)
normals[np.arange(5), np.arange(5) % 3] = 1.0
data = {"box": box, "box_normals": normals}
tag = sys.argv[1]
joblib.dump(data, f"box_joblib-{tag}.pt")
if tag == "1.6":
    for protocol in (2, 4):
        with open(f"box_pickle-p{protocol}.pt", "wb") as f:
            pickle.dump(data, f, protocol=protocol)
    with open("expected.json", "w") as f:
        json.dump({k: v.tolist() for k, v in data.items()}, f)
