#!/usr/bin/env python3
"""Sums cubecl's kernel profile (CUBECL_DEBUG_OPTION=profile: one `| duration | name` line per
kernel launch, timed on the device) by kernel name: launches, device time, share.

    scripts/cubecl-profile-summary.py LOG [--top 25]
"""
import re
import sys
from collections import defaultdict

UNITS = {"ns": 1e-9, "µs": 1e-6, "us": 1e-6, "ms": 1e-3, "s": 1.0}
LINE = re.compile(r"^\|\s*([0-9.]+)(ns|µs|us|ms|s)\s*\|\s*(.+?)\s*$")


def main():
    args = sys.argv[1:]
    if not args:
        sys.exit(__doc__)
    top = 25
    if "--top" in args:
        i = args.index("--top")
        top = int(args[i + 1])
        del args[i : i + 2]
    count, total = defaultdict(int), defaultdict(float)
    for line in open(args[0], errors="replace"):
        m = LINE.match(line.strip())
        if not m:
            continue
        # one kernel's name without its launch-specific shapes
        name = re.sub(r"\s+", " ", m.group(3))[:120]
        count[name] += 1
        total[name] += float(m.group(1)) * UNITS[m.group(2)]
    launches = sum(count.values())
    device = sum(total.values())
    print(f"kernel launches: {launches}, device time {device:.4f} s")
    for name in sorted(total, key=total.get, reverse=True)[:top]:
        share = 100 * total[name] / device if device else 0
        print(f"  {total[name]:9.4f} s {share:5.1f} % {count[name]:7d}x  {name}")


if __name__ == "__main__":
    main()
