#!/usr/bin/env python3
"""Runs a sweep whose variants differ only after the warm-up (joint, DLF, evaluation settings)
with one warm-up: the first variant's warm-up is trained, copied into every other variant's
folder, and `neurofluid-train sweep` then runs each variant's joint stage and evaluation (a run
finds the copied warm-up complete and with its own settings, so it goes on from it; a variant
that changes a warm-up setting is refused by the run, with the keys named).

    python3 scripts/sweep-shared-warmup.py experiments/research/bed/sweeps/water-dam-z.toml [--bin PATH] [-- --keep-going]
"""

import argparse
import shutil
import subprocess
import sys
import tomllib
from pathlib import Path


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("sweep", type=Path)
    ap.add_argument("--bin", default="target/debug/neurofluid-train")
    ap.add_argument("sweep_args", nargs="*", help="passed to `sweep` (e.g. --keep-going)")
    args = ap.parse_args()
    sweep = tomllib.loads(args.sweep.read_text())
    variants = sweep.get("variant", [])
    if not variants:
        sys.exit(f"{args.sweep}: no [[variant]]")
    out = Path(sweep.get("out_dir", f"runs/{args.sweep.stem}"))
    base = tomllib.loads(Path(sweep["base"]).read_text())
    first = variants[0]
    sets = [*sweep.get("set", []), *first.get("set", [])]
    # one warm-up per seed (the seed shapes the warm-up); run folders as `sweep` names them
    seeds = sweep.get("seeds") or [None]
    run = lambda v, seed: v["name"] if seed is None else f'{v["name"]}-seed{seed}'
    for seed in seeds:
        first_dir = out / run(first, seed)
        cmd = [args.bin, "warmup", sweep["base"],
               "--set", f'name="{base["name"]}-{run(first, seed)}"',
               "--set", f'out_dir="{first_dir}"']
        for s in sets + ([] if seed is None else [f"seed={seed}"]):
            cmd += ["--set", s]
        print("+", " ".join(cmd), flush=True)
        subprocess.run(cmd, check=True)
        for v in variants[1:]:
            dest = out / run(v, seed)
            if (dest / "warmup").exists():
                continue
            dest.mkdir(parents=True, exist_ok=True)
            shutil.copytree(first_dir / "warmup", dest / "warmup")
            for f in ("metrics.csv", "metrics.jsonl"):
                if (first_dir / f).exists():
                    shutil.copy2(first_dir / f, dest / f)
            shutil.copy2(first_dir / "config.resolved.toml", dest / "config.resolved.toml")
    cmd = [args.bin, "sweep", str(args.sweep), *args.sweep_args]
    print("+", " ".join(cmd), flush=True)
    return subprocess.run(cmd).returncode


if __name__ == "__main__":
    sys.exit(main())
