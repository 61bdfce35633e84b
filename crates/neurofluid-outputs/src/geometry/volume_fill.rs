//! From a density field on a grid to particles: the iso-surface by marching cubes
//! (`splashsurf_lib`), then the enclosed volume filled on a cubic lattice. Used to recover the
//! particles at t = 0 from a NeRF of frame 0 (NeuroFluid, Table 5).
//!
//! Before triangulating, the grid points above the threshold are split into 6-connected bodies
//! (face neighbours, the grid's own adjacency: two bodies touching only at an edge or a corner
//! count apart, though marching cubes may join their surfaces there); optionally only
//! the largest is kept (NeRF's floaters), and cavities (points the grid's border cannot reach
//! through face neighbours below the threshold) count as inside, so a NeRF that sees a liquid as
//! a hollow shell still gives a solid body. A shell leaking only through edge- or corner-adjacent
//! gaps is thus taken as closed. The grid is padded with a layer below the threshold, so the
//! surface is always closed.

use std::collections::VecDeque;

use anyhow::Context;
use splashsurf_lib::nalgebra::Vector3;

use crate::geometry::mesh::Mesh;

/// Density samples on the points of a regular grid: point (i, j, k) lies at
/// `origin + (i, j, k)·cell` and its value is `values[i + dims[0]·(j + dims[1]·k)]`.
#[derive(Debug, Clone, PartialEq)]
pub struct DensityGrid {
    /// Position of point (0, 0, 0).
    pub origin: [f64; 3],
    /// Spacing of the points.
    pub cell: f64,
    /// Points per axis.
    pub dims: [usize; 3],
    /// One value per point, x fastest.
    pub values: Vec<f32>,
}

impl DensityGrid {
    /// A grid; `values` must hold one finite value per point and every axis at least 2 points.
    pub fn new(
        origin: [f64; 3],
        cell: f64,
        dims: [usize; 3],
        values: Vec<f32>,
    ) -> anyhow::Result<Self> {
        let grid = Self {
            origin,
            cell,
            dims,
            values,
        };
        grid.check()?;
        Ok(grid)
    }

    /// Checks what [`DensityGrid::new`] checks (the fields are public, so [`surface`] checks
    /// again).
    pub fn check(&self) -> anyhow::Result<()> {
        let (cell, dims) = (self.cell, self.dims);
        anyhow::ensure!(
            cell.is_finite() && cell > 0.0,
            "the grid spacing must be > 0, got {cell}"
        );
        anyhow::ensure!(
            self.origin.iter().all(|c| c.is_finite()),
            "the grid origin must be finite, got {:?}",
            self.origin
        );
        anyhow::ensure!(
            dims.iter().all(|&d| d >= 2),
            "a density grid needs at least 2 points per axis, got {dims:?}"
        );
        anyhow::ensure!(
            dims.iter().try_fold(1usize, |n, &d| n.checked_mul(d)) == Some(self.values.len()),
            "{} density values for a grid of {dims:?} points",
            self.values.len()
        );
        if let Some(p) = self.values.iter().position(|v| !v.is_finite()) {
            anyhow::bail!(
                "the density grid holds a non-finite value ({}) at point {p}",
                self.values[p]
            );
        }
        Ok(())
    }

    /// The positions of the points, in value order (to evaluate a network on).
    pub fn points(&self) -> Vec<[f64; 3]> {
        let [nx, ny, nz] = self.dims;
        let mut out = Vec::with_capacity(nx * ny * nz);
        for k in 0..nz {
            for j in 0..ny {
                for i in 0..nx {
                    let idx = [i, j, k];
                    out.push([0, 1, 2].map(|a| self.origin[a] + idx[a] as f64 * self.cell));
                }
            }
        }
        out
    }

    /// The position in `values` of point (i, j, k).
    pub(crate) fn index(&self, i: usize, j: usize, k: usize) -> usize {
        i + self.dims[0] * (j + self.dims[1] * k)
    }

    /// The face neighbours of point `p`.
    fn neighbours(&self, p: usize) -> impl Iterator<Item = usize> + '_ {
        let [nx, ny, nz] = self.dims;
        let (i, j, k) = (p % nx, (p / nx) % ny, p / (nx * ny));
        let steps: [(isize, isize, isize); 6] = [
            (-1, 0, 0),
            (1, 0, 0),
            (0, -1, 0),
            (0, 1, 0),
            (0, 0, -1),
            (0, 0, 1),
        ];
        steps.into_iter().filter_map(move |(di, dj, dk)| {
            let (a, b, c) = (
                i.checked_add_signed(di)?,
                j.checked_add_signed(dj)?,
                k.checked_add_signed(dk)?,
            );
            (a < nx && b < ny && c < nz).then(|| self.index(a, b, c))
        })
    }
}

/// How a density grid becomes particles.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FillSettings {
    /// The density of the surface: values above it are inside.
    pub iso: f64,
    /// The lattice spacing of the particles (DLF: 2r).
    pub spacing: f64,
    /// Keep only the largest connected body (drops NeRF's floaters).
    pub largest_only: bool,
}

/// The surface and the particles filling it.
#[derive(Debug, Clone, PartialEq)]
pub struct Filled {
    /// The closed surface (outward-facing triangles).
    pub mesh: Mesh,
    /// Lattice points inside the surface and the bounds.
    pub particles: Vec<[f32; 3]>,
    /// Bodies above the threshold before any was dropped.
    pub components: usize,
    /// The volume the kept surface encloses (cavities included; before clipping to the bounds).
    pub kept_volume: f64,
}

/// Which points are inside: above `iso`, in a kept body, or in a cavity. Also the body count.
fn inside_points(
    grid: &DensityGrid,
    iso: f64,
    largest_only: bool,
) -> anyhow::Result<(Vec<bool>, usize)> {
    let n = grid.values.len();
    let above: Vec<bool> = grid.values.iter().map(|&v| f64::from(v) > iso).collect();
    if !above.iter().any(|&a| a) {
        let max = grid
            .values
            .iter()
            .copied()
            .fold(f32::NEG_INFINITY, f32::max);
        anyhow::bail!(
            "the density grid has no value above the threshold {iso:.4} (its maximum is \
             {max:.4}): the NeRF sees no fluid inside the box (expected some density above the \
             threshold; lower it, or check the NeRF)"
        );
    }
    // bodies of points above the threshold
    let mut label = vec![usize::MAX; n];
    let mut sizes: Vec<usize> = Vec::new();
    let mut queue = VecDeque::new();
    for start in 0..n {
        if !above[start] || label[start] != usize::MAX {
            continue;
        }
        let id = sizes.len();
        let mut size = 0;
        label[start] = id;
        queue.push_back(start);
        while let Some(p) = queue.pop_front() {
            size += 1;
            for q in grid.neighbours(p) {
                if above[q] && label[q] == usize::MAX {
                    label[q] = id;
                    queue.push_back(q);
                }
            }
        }
        sizes.push(size);
    }
    // the largest body; of equal ones the first in index order
    let largest = (0..sizes.len()).fold(0, |best, i| if sizes[i] > sizes[best] { i } else { best });
    let solid: Vec<bool> = (0..n)
        .map(|p| above[p] && (!largest_only || label[p] == largest))
        .collect();
    // the outside: every non-solid point the grid's border reaches through non-solid points
    let [nx, ny, nz] = grid.dims;
    let mut outside = vec![false; n];
    for k in 0..nz {
        for j in 0..ny {
            for i in 0..nx {
                let border =
                    i == 0 || j == 0 || k == 0 || i == nx - 1 || j == ny - 1 || k == nz - 1;
                let p = grid.index(i, j, k);
                if border && !solid[p] && !outside[p] {
                    outside[p] = true;
                    queue.push_back(p);
                }
            }
        }
    }
    while let Some(p) = queue.pop_front() {
        for q in grid.neighbours(p) {
            if !solid[q] && !outside[q] {
                outside[q] = true;
                queue.push_back(q);
            }
        }
    }
    Ok(((0..n).map(|p| !outside[p]).collect(), sizes.len()))
}

/// The closed surface at `iso` (outward-facing triangles) and the number of bodies found above
/// the threshold. Cavities count as inside, and with `largest_only` only the largest body is
/// kept (see the module docs for why 6-connectivity); the grid is padded with a layer below
/// `iso`, so the surface is closed even where the fluid touches the grid's border.
pub fn surface(grid: &DensityGrid, iso: f64, largest_only: bool) -> anyhow::Result<(Mesh, usize)> {
    anyhow::ensure!(
        iso.is_finite(),
        "the surface threshold must be finite, got {iso}"
    );
    grid.check().context("the density grid")?;
    let (inside, components) = inside_points(grid, iso, largest_only)?;
    // the field the surface is taken of: the density inside (cavities lifted above the
    // threshold), strictly below the threshold outside (dropped bodies lowered; a value equal to
    // the threshold is outside, which splashsurf's vertex and corner tests only agree on when
    // no value equals it), padded by one layer below it
    let [nx, ny, nz] = grid.dims;
    let (px, py, pz) = (nx + 2, ny + 2, nz + 2);
    let lift = iso.abs().max(1.0);
    let (low, high, below) = (iso - lift, iso + lift, iso.next_down());
    let mut field = vec![low; px * py * pz];
    for k in 0..nz {
        for j in 0..ny {
            for i in 0..nx {
                let p = grid.index(i, j, k);
                let v = f64::from(grid.values[p]);
                let f = match (inside[p], v > iso) {
                    (true, true) => v,
                    (true, false) => high,
                    (false, true) => low,
                    (false, false) => v.min(below),
                };
                // splashsurf's point order: z fastest
                field[(i + 1) * py * pz + (j + 1) * pz + (k + 1)] = f;
            }
        }
    }
    let min = Vector3::new(
        grid.origin[0] - grid.cell,
        grid.origin[1] - grid.cell,
        grid.origin[2] - grid.cell,
    );
    let cells = [px as i64 - 1, py as i64 - 1, pz as i64 - 1];
    let sgrid = splashsurf_lib::UniformGrid::<i64, f64>::new(&min, &cells, grid.cell)
        .map_err(|e| anyhow::anyhow!("the marching-cubes grid: {e:?}"))?;
    let map = splashsurf_lib::DensityMap::from(field);
    let tri = splashsurf_lib::marching_cubes::triangulate_density_map(&sgrid, &map, iso)
        .map_err(|e| anyhow::anyhow!("marching cubes: {e:#}"))?;
    anyhow::ensure!(
        tri.vertices.len() <= u32::MAX as usize,
        "the surface has {} vertices, more than a mesh holds: use a coarser grid",
        tri.vertices.len()
    );
    let mut mesh = Mesh {
        vertices: tri
            .vertices
            .iter()
            .map(|v| [v.x as f32, v.y as f32, v.z as f32])
            .collect(),
        triangles: tri.triangles.iter().map(|t| t.map(|i| i as u32)).collect(),
    };
    // splashsurf's triangles already face outwards (values above the threshold inside; the
    // tests check the volume is positive); a guard, as with cavities filled every surface bounds
    // a body from the outside and the sign of the volume tells the orientation
    if mesh.volume() < 0.0 {
        for t in &mut mesh.triangles {
            t.swap(1, 2);
        }
    }
    Ok((mesh, components))
}

/// The cubic lattice of spacing `s` centred in a box: `n[a]` points per axis from `first[a]`.
struct Lattice {
    first: [f64; 3],
    n: [usize; 3],
    s: f64,
    lo: [f64; 3],
    hi: [f64; 3],
}

impl Lattice {
    /// At most this many lattice points.
    const MAX_POINTS: f64 = 2.0e9;

    fn centred(s: f64, (lo, hi): ([f64; 3], [f64; 3])) -> anyhow::Result<Self> {
        // a relative slack so that a box of exactly m spacings holds m + 1 points
        let n = [0, 1, 2].map(|a| ((hi[a] - lo[a]) / s * (1.0 + 1e-9)).floor() + 1.0);
        anyhow::ensure!(
            n.iter().product::<f64>() <= Self::MAX_POINTS,
            "a lattice of spacing {s} over the bounds {lo:?}..{hi:?} has {:.3e} points (at most \
             {:.0e} expected): use a larger spacing",
            n.iter().product::<f64>(),
            Self::MAX_POINTS
        );
        let n = n.map(|c| c as usize);
        let first = [0, 1, 2].map(|a| lo[a] + 0.5 * ((hi[a] - lo[a]) - (n[a] - 1) as f64 * s));
        Ok(Self {
            first,
            n,
            s,
            lo,
            hi,
        })
    }

    /// Coordinate `a` of lattice index `i`, kept inside the box (the centring rounds).
    fn at(&self, a: usize, i: usize) -> f64 {
        (self.first[a] + i as f64 * self.s).clamp(self.lo[a], self.hi[a])
    }

    /// [`Lattice::at`] as the nearest `f32` inside the box.
    fn at_f32(&self, a: usize, i: usize) -> f32 {
        let (x, lo, hi) = (self.at(a, i), self.lo[a], self.hi[a]);
        let mut y = x as f32;
        if f64::from(y) > hi {
            y = y.next_down();
        }
        if f64::from(y) < lo {
            y = y.next_up();
        }
        y
    }

    /// The lattice indices along axis `a` of the coordinates `from..=to`, widened by one.
    fn span(&self, a: usize, from: f64, to: f64) -> Option<(usize, usize)> {
        let start = ((from - self.first[a]) / self.s).floor() - 1.0;
        let end = ((to - self.first[a]) / self.s).ceil() + 1.0;
        let last = (self.n[a] - 1) as f64;
        (end >= 0.0 && start <= last).then(|| (start.max(0.0) as usize, end.min(last) as usize))
    }
}

/// The side of the point `q` = (y, z) of the edge `from → to` of a triangle projected along x:
/// its edge function (> 0 left) and whether `q` counts as left. Computed from the edge's lower
/// vertex index, so the two triangles sharing an edge get exactly opposite answers; a `q` on
/// the edge is decided as if moved by (ε, ε²) (simulation of simplicity), so a ray through an
/// edge or a vertex crosses the surface exactly as a ray beside it. `None` where the edge
/// projects to a point.
fn side(v: &[[f64; 3]], from: u32, to: u32, q: [f64; 2]) -> Option<(f64, bool)> {
    let (s, t) = (from.min(to) as usize, from.max(to) as usize);
    let d = [v[t][1] - v[s][1], v[t][2] - v[s][2]];
    let w = [q[0] - v[s][1], q[1] - v[s][2]];
    let e = d[0] * w[1] - d[1] * w[0];
    let left = if e != 0.0 {
        e > 0.0
    } else if d[1] != 0.0 {
        d[1] < 0.0
    } else if d[0] != 0.0 {
        d[0] > 0.0
    } else {
        return None;
    };
    Some(if from < to { (e, left) } else { (-e, !left) })
}

/// Where the ray along +x through `q` = (y, z) meets triangle `t`, and +1 if it enters there
/// (the projected triangle runs clockwise: the outward normal points against the ray), −1 if it
/// leaves.
fn crossing(v: &[[f64; 3]], t: [u32; 3], q: [f64; 2]) -> Option<(f64, i32)> {
    let (eab, l0) = side(v, t[0], t[1], q)?;
    let (ebc, l1) = side(v, t[1], t[2], q)?;
    let (eca, l2) = side(v, t[2], t[0], q)?;
    if l0 != l1 || l1 != l2 {
        return None;
    }
    // barycentric weights: the edge functions, all of one sign
    let [a, b, c] = t.map(|i| v[i as usize][0]);
    let sum = eab + ebc + eca;
    let x = if sum != 0.0 {
        (ebc * a + eca * b + eab * c) / sum
    } else {
        (a + b + c) / 3.0
    };
    Some((x, if l0 { -1 } else { 1 }))
}

/// Lattice points of spacing `spacing` inside the closed `mesh` and inside `bounds` (min, max
/// corners); the lattice is centred in the bounds. Inside-ness by the non-zero winding rule
/// along one ray in +x per lattice column (a scanline fill): all the crossings of a column at
/// once, robust to rays through edges and vertices (see [`side`]). Deterministic; the points
/// come z-major, then y, then x.
pub fn fill(
    mesh: &Mesh,
    spacing: f64,
    bounds: ([f64; 3], [f64; 3]),
) -> anyhow::Result<Vec<[f32; 3]>> {
    anyhow::ensure!(
        spacing.is_finite() && spacing > 0.0,
        "the particle spacing must be finite and > 0, got {spacing}"
    );
    let (lo, hi) = bounds;
    anyhow::ensure!(
        (0..3).all(|a| lo[a].is_finite() && hi[a].is_finite() && hi[a] >= lo[a]),
        "the bounds {lo:?}..{hi:?} are empty or not finite (expected min ≤ max on every axis)"
    );
    anyhow::ensure!(
        !mesh.triangles.is_empty(),
        "the surface has no triangles: nothing to fill"
    );
    let nv = mesh.vertices.len();
    anyhow::ensure!(
        mesh.triangles.iter().flatten().all(|&i| (i as usize) < nv),
        "a triangle of the surface refers to a vertex it does not have ({nv} vertices)"
    );
    anyhow::ensure!(
        mesh.vertices.iter().flatten().all(|c| c.is_finite()),
        "the surface has a non-finite vertex"
    );
    let (open, edges) = mesh.open_edges();
    anyhow::ensure!(
        open == 0,
        "the surface is not closed: {open} of its {edges} edges are not shared by exactly two \
         triangles of opposite orientation, so it has no inside to fill (expected a closed \
         surface such as `surface` gives)"
    );
    let lat = Lattice::centred(spacing, bounds)?;
    let v: Vec<[f64; 3]> = mesh.vertices.iter().map(|p| p.map(f64::from)).collect();
    // every (column, x, ±1) where a column's ray crosses a triangle
    let mut hits: Vec<(usize, f64, i32)> = Vec::new();
    for &t in &mesh.triangles {
        let p = t.map(|i| v[i as usize]);
        let range = |a: usize| {
            let (mn, mx) = p
                .iter()
                .fold((f64::INFINITY, f64::NEG_INFINITY), |(mn, mx), q| {
                    (mn.min(q[a]), mx.max(q[a]))
                });
            lat.span(a, mn, mx)
        };
        let (Some((j0, j1)), Some((k0, k1))) = (range(1), range(2)) else {
            continue;
        };
        for k in k0..=k1 {
            for j in j0..=j1 {
                if let Some((x, dir)) = crossing(&v, t, [lat.at(1, j), lat.at(2, k)]) {
                    hits.push((j + lat.n[1] * k, x, dir));
                }
            }
        }
    }
    hits.sort_unstable_by(|a, b| a.0.cmp(&b.0).then(a.1.total_cmp(&b.1)).then(a.2.cmp(&b.2)));
    let mut out = Vec::new();
    let mut unbalanced = 0;
    for column in hits.chunk_by(|a, b| a.0 == b.0) {
        let (j, k) = (column[0].0 % lat.n[1], column[0].0 / lat.n[1]);
        let (y, z) = (lat.at_f32(1, j), lat.at_f32(2, k));
        let mut winding = 0;
        for pair in column.windows(2) {
            winding += pair[0].2;
            let (x0, x1) = (pair[0].1, pair[1].1);
            if winding == 0 || x1 <= x0 {
                continue;
            }
            let Some((i0, i1)) = lat.span(0, x0, x1) else {
                continue;
            };
            for i in i0..=i1 {
                let x = lat.at(0, i);
                if x > x0 && x < x1 {
                    out.push([lat.at_f32(0, i), y, z]);
                }
            }
        }
        winding += column[column.len() - 1].2;
        if winding != 0 {
            unbalanced += 1;
        }
    }
    if unbalanced > 0 {
        // a closed surface is entered as often as it is left; only rounding can break that
        tracing::warn!(
            unbalanced,
            "lattice columns cross the surface unevenly (rounding): their fill may be off"
        );
    }
    Ok(out)
}

/// [`surface`] then [`fill`]: the particles of a density grid, inside `bounds` (min, max).
pub fn surface_and_fill(
    grid: &DensityGrid,
    settings: &FillSettings,
    bounds: ([f64; 3], [f64; 3]),
) -> anyhow::Result<Filled> {
    let (mesh, components) = surface(grid, settings.iso, settings.largest_only)?;
    let particles = fill(&mesh, settings.spacing, bounds).context("filling the surface")?;
    let kept_volume = mesh.volume();
    anyhow::ensure!(
        !particles.is_empty(),
        "the surface (volume {kept_volume:.3e}) holds no lattice point of spacing {} inside the \
         bounds {:?}..{:?}: expected a body at least one particle thick inside them",
        settings.spacing,
        bounds.0,
        bounds.1
    );
    Ok(Filled {
        mesh,
        particles,
        components,
        kept_volume,
    })
}

#[cfg(test)]
mod tests {
    use std::f64::consts::PI;

    use super::*;

    /// A grid over [−0.5, 0.5]³ of spacing 0.02 with the values of `f`.
    fn grid_of(f: impl Fn([f64; 3]) -> f64) -> DensityGrid {
        let n = 51;
        let mut g = DensityGrid::new([-0.5; 3], 0.02, [n; 3], vec![0.0; n * n * n]).unwrap();
        g.values = g.points().into_iter().map(|p| f(p) as f32).collect();
        g
    }

    fn norm(p: [f64; 3]) -> f64 {
        (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt()
    }

    fn sub(p: [f64; 3], c: [f64; 3]) -> [f64; 3] {
        [p[0] - c[0], p[1] - c[1], p[2] - c[2]]
    }

    /// Density 10 at the centre falling linearly to 0 at r = 0.6: the iso-5 surface is r = 0.3.
    fn ball(p: [f64; 3]) -> f64 {
        (10.0 * (1.0 - norm(p) / 0.6)).max(0.0)
    }

    fn ball_volume(r: f64) -> f64 {
        4.0 / 3.0 * PI * r.powi(3)
    }

    const BOUNDS: ([f64; 3], [f64; 3]) = ([-0.5; 3], [0.5; 3]);
    const SPACING: f64 = 0.05;

    fn settings(largest_only: bool) -> FillSettings {
        FillSettings {
            iso: 5.0,
            spacing: SPACING,
            largest_only,
        }
    }

    fn min_pair_distance(p: &[[f32; 3]]) -> f64 {
        let mut best = f64::INFINITY;
        for (i, a) in p.iter().enumerate() {
            for b in &p[i + 1..] {
                let d: f64 = (0..3).map(|k| f64::from(a[k] - b[k]).powi(2)).sum();
                best = best.min(d.sqrt());
            }
        }
        best
    }

    fn in_bounds(p: &[f32; 3], (lo, hi): ([f64; 3], [f64; 3])) -> bool {
        (0..3).all(|a| (lo[a]..=hi[a]).contains(&f64::from(p[a])))
    }

    #[test]
    fn a_ball_gives_its_volume_and_a_lattice_inside_it() {
        let f = surface_and_fill(&grid_of(ball), &settings(true), BOUNDS).unwrap();
        let exact = ball_volume(0.3);
        assert!(f.mesh.is_closed());
        assert_eq!(f.components, 1);
        assert_eq!(f.kept_volume, f.mesh.volume());
        let err = (f.kept_volume - exact) / exact;
        let lattice = f.particles.len() as f64 * SPACING.powi(3);
        let lattice_err = (lattice - exact) / exact;
        eprintln!(
            "ball: {} triangles, volume error {:+.3} %, {} particles, lattice volume error \
             {:+.2} %",
            f.mesh.triangles.len(),
            100.0 * err,
            f.particles.len(),
            100.0 * lattice_err
        );
        assert!(
            err.abs() < 0.03,
            "surface volume {} vs {exact}",
            f.kept_volume
        );
        assert!(lattice_err.abs() < 0.10, "{} particles", f.particles.len());
        for p in &f.particles {
            assert!(
                norm(p.map(f64::from)) <= 0.3 + SPACING / 2.0,
                "{p:?} outside the ball"
            );
            assert!(in_bounds(p, BOUNDS), "{p:?} outside the bounds");
        }
        assert!(min_pair_distance(&f.particles) >= SPACING * (1.0 - 1e-4));
        // the lattice is centred in the bounds: −0.5, −0.45, …, 0.5; 30 of its points, like
        // (0.3, 0, 0) and (0.2, 0.2, 0.1), lie on the sphere, the others at least 4e-3 from it
        let count = |r: f64| {
            let m = -10i32..=10;
            m.clone()
                .flat_map(|i| {
                    m.clone()
                        .flat_map(move |j| (-10i32..=10).map(move |k| [i, j, k]))
                })
                .filter(|c| norm(c.map(|x| f64::from(x) * SPACING)) < r)
                .count()
        };
        let (inner, outer) = (count(0.3 - 2e-3), count(0.3 + 2e-3));
        assert_eq!(outer - inner, 30);
        assert!(
            (inner..=outer).contains(&f.particles.len()),
            "{inner}..={outer}"
        );
    }

    #[test]
    fn a_hollow_shell_is_filled_solid() {
        // density 10 at r = 0.25 falling linearly to 0 at r = 0.15 and 0.35: the iso-5 shell is
        // 0.2 < r < 0.3, empty inside
        let shell = |p: [f64; 3]| (10.0 * (1.0 - (norm(p) - 0.25).abs() / 0.1)).max(0.0);
        let f = surface_and_fill(&grid_of(shell), &settings(true), BOUNDS).unwrap();
        let full = ball_volume(0.3);
        let err = (f.kept_volume - full) / full;
        let lattice = f.particles.len() as f64 * SPACING.powi(3);
        let lattice_err = (lattice - full) / full;
        eprintln!(
            "shell: volume error {:+.3} % of the full ball, {} particles, lattice volume error \
             {:+.2} %",
            100.0 * err,
            f.particles.len(),
            100.0 * lattice_err
        );
        assert!(f.mesh.is_closed());
        assert!(
            err.abs() < 0.03,
            "the cavity was not filled: {}",
            f.kept_volume
        );
        assert!(lattice_err.abs() < 0.10, "{} particles", f.particles.len());
        assert!(
            f.particles.iter().any(|p| norm(p.map(f64::from)) < 0.1),
            "the cavity is empty"
        );
    }

    #[test]
    fn the_largest_body_is_kept_and_floaters_dropped() {
        let (big, small) = ([-0.15, 0.0, 0.0], [0.35, 0.0, 0.0]);
        let two = |p: [f64; 3]| {
            let b = 10.0 * (1.0 - norm(sub(p, big)) / 0.5);
            let s = 10.0 * (1.0 - norm(sub(p, small)) / 0.16);
            b.max(s).max(0.0)
        };
        let one = surface_and_fill(&grid_of(two), &settings(true), BOUNDS).unwrap();
        let both = surface_and_fill(&grid_of(two), &settings(false), BOUNDS).unwrap();
        assert_eq!((one.components, both.components), (2, 2));
        assert!(
            one.particles
                .iter()
                .all(|p| norm(sub(p.map(f64::from), big)) <= 0.25 + SPACING / 2.0),
            "a floater survived"
        );
        let near_small = |f: &Filled| {
            f.particles
                .iter()
                .filter(|p| norm(sub(p.map(f64::from), small)) <= 0.08 + SPACING / 2.0)
                .count()
        };
        assert_eq!(near_small(&one), 0);
        assert!(near_small(&both) > 0, "the small body is missing");
        assert_eq!(
            both.particles.len(),
            one.particles.len() + near_small(&both)
        );
        let small_volume = both.kept_volume - one.kept_volume;
        eprintln!(
            "two bodies: kept {:.5} (big exact {:.5}), both {:.5}, small {:.5} (exact {:.5}); \
             particles {} vs {}",
            one.kept_volume,
            ball_volume(0.25),
            both.kept_volume,
            small_volume,
            ball_volume(0.08),
            one.particles.len(),
            both.particles.len()
        );
        assert!((one.kept_volume - ball_volume(0.25)).abs() / ball_volume(0.25) < 0.03);
        assert!((small_volume - ball_volume(0.08)).abs() / ball_volume(0.08) < 0.10);
    }

    #[test]
    fn particles_stay_inside_the_bounds() {
        // a ball of radius 0.3 at x = 0.25 through the wall x = 0.4 of the bounds
        let off = |p: [f64; 3]| ball(sub(p, [0.25, 0.0, 0.0]));
        let bounds = ([-0.5; 3], [0.4, 0.5, 0.5]);
        let f = surface_and_fill(&grid_of(off), &settings(true), bounds).unwrap();
        assert!(f.particles.iter().all(|p| in_bounds(p, bounds)));
        let max_x = f.particles.iter().map(|p| p[0]).fold(f32::MIN, f32::max);
        // the lattice over [−0.5, 0.4]: 19 points from −0.5 to 0.4, the wall's layer included
        assert!((f64::from(max_x) - 0.4).abs() < 1e-6, "max x {max_x}");
        // the same ball in wide bounds has particles beyond the wall
        let wide = surface_and_fill(&grid_of(off), &settings(true), BOUNDS).unwrap();
        assert!(wide.particles.iter().any(|p| p[0] > 0.41));
        assert!(wide.particles.len() > f.particles.len());
    }

    #[test]
    fn a_cube_fills_the_lattice_it_holds() {
        // a cube of side 0.4 centred at c = 0.0125 (faces between the grid points, at −0.1875
        // and 0.2125), its density linear in the distance from its faces
        let c = 0.0125;
        let cube = |p: [f64; 3]| {
            let d = p.iter().map(|x| (x - c).abs()).fold(0.0, f64::max);
            5.0 + 50.0 * (0.2 - d)
        };
        let f = surface_and_fill(&grid_of(cube), &settings(true), BOUNDS).unwrap();
        let exact = 0.4f64.powi(3);
        let err = (f.kept_volume - exact) / exact;
        eprintln!(
            "cube: volume error {:+.3} %, {} particles",
            100.0 * err,
            f.particles.len()
        );
        assert!(f.mesh.is_closed());
        assert!(err.abs() < 0.03, "{}", f.kept_volume);
        // the lattice points are multiples of 0.05 (centred in [−0.5, 0.5]); per axis those in
        // (−0.1875, 0.2125): −0.15, −0.10, …, 0.20, 8 of them, each at least 0.0125 from a face,
        // and grid points too, which marching cubes never leaves on the wrong side → 8³
        assert_eq!(f.particles.len(), 8 * 8 * 8);
    }

    /// A deterministic stream of numbers in [0, 1).
    fn uniform(seed: u64) -> impl FnMut() -> f64 {
        let mut s = seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) | 1;
        move || {
            s ^= s << 13;
            s ^= s >> 7;
            s ^= s << 17;
            (s >> 11) as f64 / (1u64 << 53) as f64
        }
    }

    #[test]
    fn noisy_fields_give_closed_surfaces_filled_exactly_at_their_grid_points() {
        // random values on a dyadic grid whose points are the lattice's: every ray runs along a
        // grid line, through marching-cubes vertices; quantised values hit the threshold
        // exactly. A grid point is inside the surface iff it is classified inside, so the fill
        // must be exactly the inside points.
        let n = 17;
        let cell = 1.0 / 16.0;
        for (seed, iso, quantised, largest_only) in [
            (1, 0.5, false, false),
            (2, 0.3, false, true),
            (3, 0.7, false, false),
            (4, 0.5, true, false),
            (5, 0.5, true, true),
        ] {
            let mut r = uniform(seed);
            let values = (0..n * n * n)
                .map(|_| {
                    let x = r();
                    (if quantised {
                        (x * 4.0).floor() / 4.0
                    } else {
                        x
                    }) as f32
                })
                .collect();
            let grid = DensityGrid::new([-0.5; 3], cell, [n; 3], values).unwrap();
            let (mesh, _) = surface(&grid, iso, largest_only).unwrap();
            assert!(mesh.is_closed(), "seed {seed}: open surface");
            let (inside, _) = inside_points(&grid, iso, largest_only).unwrap();
            let points = grid.points();
            let expected: Vec<[f32; 3]> = (0..points.len())
                .filter(|&p| inside[p])
                .map(|p| points[p].map(|c| c as f32))
                .collect();
            let got = fill(&mesh, cell, BOUNDS).unwrap();
            // a point of value exactly `iso` lies on the surface: either side will do
            let on_surface: Vec<[f32; 3]> = (0..points.len())
                .filter(|&p| !inside[p] && f64::from(grid.values[p]) == iso)
                .map(|p| points[p].map(|c| c as f32))
                .collect();
            let key = |p: &[f32; 3]| (p[2].to_bits(), p[1].to_bits(), p[0].to_bits());
            let got: std::collections::BTreeSet<_> = got.iter().map(key).collect();
            let on_surface: std::collections::BTreeSet<_> = on_surface.iter().map(key).collect();
            let missing = expected.iter().filter(|p| !got.contains(&key(p))).count();
            let expected: std::collections::BTreeSet<_> = expected.iter().map(key).collect();
            let extra = got
                .difference(&expected)
                .filter(|p| !on_surface.contains(p))
                .count();
            let touching = got.intersection(&on_surface).count();
            eprintln!(
                "noise seed {seed}: {} triangles, {} inside points, {} on the surface ({touching} \
                 filled)",
                mesh.triangles.len(),
                expected.len(),
                on_surface.len()
            );
            assert_eq!((missing, extra), (0, 0), "seed {seed}");
        }
    }

    #[test]
    fn bad_inputs_are_refused_with_reasons() {
        let empty = grid_of(|_| 0.0);
        let e = surface(&empty, 5.0, true).unwrap_err().to_string();
        assert!(e.contains("no value above the threshold 5"), "{e}");
        assert!(e.contains("maximum is 0"), "{e}");
        let (mut mesh, _) = surface(&grid_of(ball), 5.0, true).unwrap();
        let closed = mesh.clone();
        mesh.triangles.pop();
        let e = fill(&mesh, SPACING, BOUNDS).unwrap_err().to_string();
        assert!(e.contains("not closed: 3 of its"), "{e}");
        assert!(e.contains("not shared by exactly two triangles"), "{e}");
        let e = fill(&closed, 0.0, BOUNDS).unwrap_err().to_string();
        assert!(e.contains("spacing must be finite and > 0, got 0"), "{e}");
        assert!(fill(&closed, f64::NAN, BOUNDS).is_err());
        let e = fill(&closed, SPACING, ([0.0; 3], [1.0, -1.0, 1.0]))
            .unwrap_err()
            .to_string();
        assert!(e.contains("are empty"), "{e}");
        let e = fill(&closed, 1e-6, BOUNDS).unwrap_err().to_string();
        assert!(e.contains("use a larger spacing"), "{e}");
        assert!(fill(&Mesh::default(), SPACING, BOUNDS).is_err());
        // a body thinner than the lattice: no particle
        let thin = |p: [f64; 3]| 10.0 * (1.0 - norm(sub(p, [0.025; 3])) / 0.02);
        let e = surface_and_fill(&grid_of(thin), &settings(true), BOUNDS)
            .unwrap_err()
            .to_string();
        assert!(e.contains("holds no lattice point"), "{e}");
        assert!(DensityGrid::new([0.0; 3], 0.1, [2, 2, 2], vec![0.0; 7]).is_err());
        assert!(DensityGrid::new([0.0; 3], 0.1, [2, 2, 1], vec![0.0; 4]).is_err());
        assert!(DensityGrid::new([0.0; 3], 0.0, [2, 2, 2], vec![0.0; 8]).is_err());
        assert!(DensityGrid::new([0.0; 3], 0.1, [2, 2, 2], vec![f32::NAN; 8]).is_err());
        // the fields are public: `surface` checks them again
        let mut g = grid_of(ball);
        g.values[7] = f32::INFINITY;
        let e = format!("{:#}", surface(&g, 5.0, true).unwrap_err());
        assert!(e.contains("non-finite value (inf) at point 7"), "{e}");
    }

    /// A wobbly ball on a 128³ grid: `cargo test -p neurofluid-train --lib volume_fill --
    /// --ignored --nocapture`.
    #[test]
    #[ignore = "timing"]
    fn timing_of_a_128_grid() {
        let n = 128;
        let cell = 1.0 / (n - 1) as f64;
        let mut g = DensityGrid::new([-0.5; 3], cell, [n; 3], vec![0.0; n * n * n]).unwrap();
        g.values = g
            .points()
            .into_iter()
            .map(|p| {
                let wobble = 0.03 * (17.0 * p[0]).sin() * (13.0 * p[1]).sin() * (11.0 * p[2]).sin();
                (10.0 * (1.0 - (norm(p) + wobble) / 0.8)).max(0.0) as f32
            })
            .collect();
        let t = std::time::Instant::now();
        let (mesh, _) = surface(&g, 5.0, true).unwrap();
        let t_surface = t.elapsed();
        let t = std::time::Instant::now();
        // DLF's spacing 2r with the grid's cell r
        let particles = fill(&mesh, 2.0 * cell, BOUNDS).unwrap();
        let t_fill = t.elapsed();
        eprintln!(
            "128³: surface {t_surface:.2?} ({} triangles, volume {:.4}), fill {t_fill:.2?} ({} \
             particles)",
            mesh.triangles.len(),
            mesh.volume(),
            particles.len()
        );
        let t = std::time::Instant::now();
        let fine = fill(&mesh, cell, BOUNDS).unwrap();
        eprintln!(
            "  fill at spacing r: {:.2?} ({} particles)",
            t.elapsed(),
            fine.len()
        );
    }
}
