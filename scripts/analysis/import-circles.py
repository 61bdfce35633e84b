"""Module-level import circles of a crate: edges from `crate::X` paths in code (comments and
test modules left out), modules grouped to DEPTH path segments (1: top-level modules).

Usage: python3 scripts/analysis/import-circles.py crates/neurofluid-train/src [DEPTH]
"""
import re, os, sys, itertools
root = sys.argv[1]
depth = int(sys.argv[2]) if len(sys.argv) > 2 else 2
mods = {}
for dp, _, fs in os.walk(root):
    for f in fs:
        if not f.endswith('.rs'): continue
        p = os.path.join(dp, f)
        rel = os.path.relpath(p, root)[:-3].split(os.sep)
        if rel[-1] in ('mod', 'lib', 'main'): rel = rel[:-1]
        name = '::'.join(rel[:depth]) or 'crate'
        text = open(p).read()
        text = text.split("#[cfg(test)]")[0]
        text = "\n".join(l for l in text.splitlines() if not l.strip().startswith("//"))
        for m in re.finditer(r'crate::([a-z_]+(?:::[a-z_]+)?)', text):
            target = '::'.join(m.group(1).split('::')[:depth])
            parts = target.split('::')
            # keep only targets that are modules (a file or folder exists)
            cand = os.path.join(root, *parts)
            if not (os.path.exists(cand + '.rs') or os.path.isdir(cand)):
                target = parts[0]
            if target != name and not name.startswith(target + '::') and not target.startswith(name + '::'):
                mods.setdefault(name, set()).add(target)
# find cycles (simple, length 2..4)
seen = set()
def dfs(start, node, path):
    for n in mods.get(node, ()):
        if n == start and len(path) > 1:
            c = tuple(path)
            k = frozenset(c)
            if k not in seen:
                seen.add(k); print(' -> '.join(path + [start]))
        elif n not in path and len(path) < 4:
            dfs(start, n, path + [n])
for m in sorted(mods): dfs(m, m, [m])
