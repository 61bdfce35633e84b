"""The neighbour-search benchmark's reference: scipy's cKDTree on the same kind of data.

Same sizes as benches/neighbors.rs (a jittered 2r lattice of 100k particles, 1M uniform queries
over 1.5x its box; 30k particles for the pairs), median of 3, all cores (workers=-1).
- K nearest within r (cKDTree.query with k=20, distance_upper_bound=r) ~ our Selection::Nearest
- fixed-radius pairs (cKDTree.query_ball_point, the DLF reference harness's search)
Run: python3 crates/neurofluid-core/benches/neighbors_scipy.py
"""
import time

import numpy as np
from scipy.spatial import cKDTree


def lattice(n, rng):
    side = int(np.ceil(n ** (1 / 3)))
    i = np.arange(n)
    p = np.stack([i % side, i // side % side, i // (side * side)], axis=1) * 0.05
    return (p + rng.uniform(-0.002, 0.002, p.shape)).astype(np.float32)


def median(f):
    f()
    t = []
    for _ in range(3):
        s = time.perf_counter()
        f()
        t.append(time.perf_counter() - s)
    return sorted(t)[1]


rng = np.random.default_rng(0)
particles = lattice(100_000, rng)
extent = 47 * 0.05
queries = rng.uniform(-0.25 * extent, 1.25 * extent, (1_000_000, 3)).astype(np.float32)
t_build = median(lambda: cKDTree(particles))
tree = cKDTree(particles)
t_knn = median(lambda: tree.query(queries, k=20, distance_upper_bound=0.225, workers=-1))
print(f"cKDTree build, 100k particles: {t_build:.4f} s")
print(f"cKDTree 20 nearest within r 0.225, 1M queries: {t_knn:.3f} s")
fluid = lattice(30_000, rng)


def pairs():
    t = cKDTree(fluid)
    return t.query_ball_point(fluid, 0.1125, workers=-1)


print(f"cKDTree fixed-radius pairs, 30k particles, R 0.1125, build included: {median(pairs):.4f} s")
