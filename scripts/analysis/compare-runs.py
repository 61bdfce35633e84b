"""Compares two run folders: every metrics row without its timing fields, and the report's files.

Usage: python3 scripts/analysis/compare-runs.py BEFORE_RUN_DIR AFTER_RUN_DIR
"""
import json, sys, os, difflib
TIMING = {"rays_per_s", "step_s", "time_s", "wall_s", "seconds"}
def rows(d):
    out = []
    for l in open(os.path.join(d, "metrics.jsonl")):
        r = json.loads(l)
        out.append({k: v for k, v in r.items() if k not in TIMING and not k.endswith("_s")})
    return out
a, b = sys.argv[1], sys.argv[2]
ra, rb = rows(a), rows(b)
print("rows", len(ra), len(rb))
diff = 0
extra_keys = set()
for x, y in zip(ra, rb):
    for k in x:
        if x[k] != y.get(k):
            diff += 1
            if diff < 10: print("DIFF", x.get("stage"), x.get("step"), k, x[k], y.get(k))
    extra_keys |= set(y) - set(x)
    missing = set(x) - set(y)
    if missing: print("MISSING", missing)
print("value differences:", diff, "keys only in the new rows:", sorted(extra_keys))
for f in ["eval/report.md", "eval/report.json", "eval/frames.csv"]:
    pa, pb = os.path.join(a, f), os.path.join(b, f)
    if not os.path.exists(pa): continue
    ta, tb = open(pa).read().splitlines(), open(pb).read().splitlines()
    d = [l for l in difflib.unified_diff(ta, tb, lineterm="", n=0)]
    print(f, "identical" if not d else "differs:")
    for l in d[:40]: print("   ", l[:300])
