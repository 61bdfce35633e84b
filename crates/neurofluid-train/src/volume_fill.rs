//! From a density field on a grid to particles: the iso-surface by marching cubes
//! (`splashsurf_lib`), then the enclosed volume filled on a cubic lattice. Used to recover the
//! particles at t = 0 from a NeRF of frame 0 (NeuroFluid, Table 5).
//!
//! Before triangulating, the grid points above the threshold are split into 6-connected bodies
//! (face neighbours: the grid's own notion of adjacency, so two bodies touching only at an edge
//! stay apart); optionally only the largest is kept (NeRF's floaters), and cavities (points below
//! the threshold that the outside cannot reach) count as inside, so a NeRF that sees a liquid as
//! a hollow shell still gives a solid body. The grid is padded with a layer below the threshold,
//! so the surface is always closed.

use std::collections::VecDeque;

use anyhow::Context;
use splashsurf_lib::nalgebra::Vector3;

use crate::mesh::Mesh;

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
        anyhow::ensure!(
            cell.is_finite() && cell > 0.0,
            "the grid spacing must be > 0, got {cell}"
        );
        anyhow::ensure!(
            dims.iter().all(|&d| d >= 2),
            "a density grid needs at least 2 points per axis, got {dims:?}"
        );
        anyhow::ensure!(
            values.len() == dims.iter().product::<usize>(),
            "{} density values for a grid of {dims:?} points",
            values.len()
        );
        anyhow::ensure!(
            values.iter().all(|v| v.is_finite()),
            "the density grid holds a non-finite value"
        );
        Ok(Self {
            origin,
            cell,
            dims,
            values,
        })
    }

    /// The positions of the points, in value order.
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

    fn index(&self, i: usize, j: usize, k: usize) -> usize {
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
    /// The density of the surface.
    pub iso: f64,
    /// The lattice spacing of the particles (DLF: 2r).
    pub spacing: f64,
    /// Keep only the largest connected body.
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
            "the density grid has no value above the threshold {iso:.3} (its maximum is \
             {max:.3}): the NeRF sees no fluid inside the box"
        );
    }
    // bodies of points above the threshold
    let mut label = vec![usize::MAX; n];
    let mut sizes = Vec::new();
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
    let largest = (0..sizes.len()).max_by_key(|&i| sizes[i]).unwrap_or(0);
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

/// The closed surface at `iso` (see the module docs for bodies and cavities) and the number of
/// bodies found above the threshold.
pub fn surface(grid: &DensityGrid, iso: f64, largest_only: bool) -> anyhow::Result<(Mesh, usize)> {
    anyhow::ensure!(
        iso.is_finite(),
        "the surface threshold must be finite, got {iso}"
    );
    let (inside, components) = inside_points(grid, iso, largest_only)?;
    // the field the surface is taken of: the density inside (cavities lifted above the
    // threshold), below the threshold outside, padded by one layer below it
    let [nx, ny, nz] = grid.dims;
    let (px, py, pz) = (nx + 2, ny + 2, nz + 2);
    let low = (iso - iso.abs().max(1.0)) as f32;
    let high = (iso + iso.abs().max(1.0)) as f32;
    let mut field = vec![low; px * py * pz];
    for k in 0..nz {
        for j in 0..ny {
            for i in 0..nx {
                let p = grid.index(i, j, k);
                let v = grid.values[p];
                let f = match (inside[p], f64::from(v) > iso) {
                    (true, true) => v,
                    (true, false) => high,
                    (false, true) => low,
                    (false, false) => v,
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
    let values: Vec<f64> = field.into_iter().map(f64::from).collect();
    let map = splashsurf_lib::DensityMap::from(values);
    let tri = splashsurf_lib::marching_cubes::triangulate_density_map(&sgrid, &map, iso)
        .map_err(|e| anyhow::anyhow!("marching cubes: {e:?}"))?;
    let mut mesh = Mesh {
        vertices: tri
            .vertices
            .iter()
            .map(|v| [v.x as f32, v.y as f32, v.z as f32])
            .collect(),
        triangles: tri
            .triangles
            .iter()
            .map(|t| [t[0] as u32, t[1] as u32, t[2] as u32])
            .collect(),
    };
    if mesh.volume() < 0.0 {
        for t in &mut mesh.triangles {
            t.swap(1, 2);
        }
    }
    Ok((mesh, components))
}

/// Lattice points of spacing `spacing` inside the closed `mesh` and inside `bounds` (min, max);
/// the lattice is centred in the bounds. Inside-ness by ray parity along +x, one ray per lattice
/// column.
pub fn fill(
    mesh: &Mesh,
    spacing: f64,
    bounds: ([f64; 3], [f64; 3]),
) -> anyhow::Result<Vec<[f32; 3]>> {
    anyhow::ensure!(
        spacing.is_finite() && spacing > 0.0,
        "the particle spacing must be > 0, got {spacing}"
    );
    let (lo, hi) = bounds;
    anyhow::ensure!(
        (0..3).all(|a| lo[a].is_finite() && hi[a].is_finite() && hi[a] > lo[a]),
        "the bounds {lo:?}..{hi:?} are empty"
    );
    if !mesh.is_closed() {
        anyhow::bail!(
            "the surface is not closed (some edges are not shared by exactly two triangles of \
             opposite orientation): its inside is undefined"
        );
    }
    let counts = [0, 1, 2].map(|a| ((hi[a] - lo[a]) / spacing).floor() as usize + 1);
    let first =
        [0, 1, 2].map(|a| lo[a] + 0.5 * ((hi[a] - lo[a]) - (counts[a] - 1) as f64 * spacing));
    let at = |a: usize, i: usize| first[a] + i as f64 * spacing;
    // triangles bucketed by the lattice column (y, z) their bounding box overlaps
    let v = |i: u32| mesh.vertices[i as usize].map(f64::from);
    let mut buckets: Vec<Vec<usize>> = vec![Vec::new(); counts[1] * counts[2]];
    let column = |a: usize, c: f64| ((c - first[a]) / spacing).floor();
    for (ti, t) in mesh.triangles.iter().enumerate() {
        let p = t.map(v);
        let range = |a: usize| {
            let (mn, mx) = p
                .iter()
                .fold((f64::INFINITY, f64::NEG_INFINITY), |(mn, mx), q| {
                    (mn.min(q[a]), mx.max(q[a]))
                });
            let start = (column(a, mn)).max(0.0) as usize;
            let end = (column(a, mx) + 1.0).min(counts[a] as f64 - 1.0);
            (start, end)
        };
        let ((y0, y1), (z0, z1)) = (range(1), range(2));
        if y1 < 0.0 || z1 < 0.0 {
            continue;
        }
        for k in z0..=z1 as usize {
            for j in y0..=y1 as usize {
                buckets[j + counts[1] * k].push(ti);
            }
        }
    }
    // a ray nudged off the lattice so it meets no edge or vertex exactly
    let nudge = [0.0, spacing * 1.234_567e-6, spacing * 2.345_678e-6];
    let mut out = Vec::new();
    let mut crossings = Vec::new();
    for k in 0..counts[2] {
        for j in 0..counts[1] {
            let (y, z) = (at(1, j) + nudge[1], at(2, k) + nudge[2]);
            crossings.clear();
            for &ti in &buckets[j + counts[1] * k] {
                let [a, b, c] = mesh.triangles[ti].map(v);
                // barycentric coordinates of (y, z) in the triangle's projection
                let det = (b[1] - a[1]) * (c[2] - a[2]) - (c[1] - a[1]) * (b[2] - a[2]);
                if det == 0.0 {
                    continue;
                }
                let u = ((y - a[1]) * (c[2] - a[2]) - (c[1] - a[1]) * (z - a[2])) / det;
                let w = ((b[1] - a[1]) * (z - a[2]) - (y - a[1]) * (b[2] - a[2])) / det;
                if u >= 0.0 && w >= 0.0 && u + w <= 1.0 {
                    crossings.push(a[0] + u * (b[0] - a[0]) + w * (c[0] - a[0]));
                }
            }
            crossings.sort_by(f64::total_cmp);
            for pair in crossings.chunks_exact(2) {
                for i in 0..counts[0] {
                    let x = at(0, i);
                    if x > pair[0] && x < pair[1] {
                        out.push([x as f32, at(1, j) as f32, at(2, k) as f32]);
                    }
                }
            }
        }
    }
    Ok(out)
}

/// [`surface`] then [`fill`]: the particles of a density grid.
pub fn surface_and_fill(
    grid: &DensityGrid,
    settings: &FillSettings,
    bounds: ([f64; 3], [f64; 3]),
) -> anyhow::Result<Filled> {
    let (mesh, components) = surface(grid, settings.iso, settings.largest_only)?;
    let particles = fill(&mesh, settings.spacing, bounds).context("filling the surface")?;
    anyhow::ensure!(
        !particles.is_empty(),
        "the surface (volume {:.2e}) holds no lattice point of spacing {}: the body is thinner \
         than one particle",
        mesh.volume(),
        settings.spacing
    );
    Ok(Filled {
        mesh,
        particles,
        components,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A grid over [−0.5, 0.5]³ of spacing 0.02 with the values of `f`.
    fn grid_of(f: impl Fn([f64; 3]) -> f64) -> DensityGrid {
        let cell = 0.02;
        let n = 51;
        let mut g = DensityGrid::new([-0.5; 3], cell, [n; 3], vec![0.0; n * n * n]).unwrap();
        g.values = g.points().into_iter().map(|p| f(p) as f32).collect();
        g
    }

    fn norm(p: [f64; 3]) -> f64 {
        (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt()
    }

    /// Density 10 at the centre falling linearly to 0 at r = 0.6: the iso 5 surface is r = 0.3.
    fn ball(p: [f64; 3]) -> f64 {
        (10.0 * (1.0 - norm(p) / 0.6)).max(0.0)
    }

    const BOUNDS: ([f64; 3], [f64; 3]) = ([-0.5; 3], [0.5; 3]);

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

    #[test]
    fn a_ball_gives_its_volume_and_a_lattice_inside_it() {
        let settings = FillSettings {
            iso: 5.0,
            spacing: 0.05,
            largest_only: true,
        };
        let f = surface_and_fill(&grid_of(ball), &settings, BOUNDS).unwrap();
        let exact = 4.0 / 3.0 * std::f64::consts::PI * 0.3f64.powi(3);
        assert!(f.mesh.is_closed());
        let err = (f.mesh.volume() - exact).abs() / exact;
        assert!(err < 0.03, "surface volume {} vs {exact}", f.mesh.volume());
        let lattice = f.particles.len() as f64 * 0.05f64.powi(3);
        assert!(
            (lattice - exact).abs() / exact < 0.10,
            "{} particles",
            f.particles.len()
        );
        for p in &f.particles {
            assert!(
                norm(p.map(f64::from)) <= 0.3 + 0.025,
                "{p:?} outside the ball"
            );
        }
        assert!(min_pair_distance(&f.particles) >= 0.05 * (1.0 - 1e-4));
        assert_eq!(f.components, 1);
    }

    #[test]
    fn a_hollow_shell_is_filled_solid() {
        let shell = |p: [f64; 3]| {
            if (0.2..0.3).contains(&norm(p)) {
                10.0
            } else {
                0.0
            }
        };
        let settings = FillSettings {
            iso: 5.0,
            spacing: 0.05,
            largest_only: true,
        };
        let f = surface_and_fill(&grid_of(shell), &settings, BOUNDS).unwrap();
        let full = 4.0 / 3.0 * std::f64::consts::PI * 0.3f64.powi(3);
        let lattice = f.particles.len() as f64 * 0.05f64.powi(3);
        assert!(
            (lattice - full).abs() / full < 0.15,
            "{} particles",
            f.particles.len()
        );
        assert!(
            f.particles.iter().any(|p| norm(p.map(f64::from)) < 0.1),
            "the cavity is empty"
        );
    }

    #[test]
    fn the_largest_body_is_kept_and_floaters_dropped() {
        let two = |p: [f64; 3]| {
            let big = norm([p[0] + 0.15, p[1], p[2]]) < 0.25;
            let small = norm([p[0] - 0.35, p[1], p[2]]) < 0.08;
            if big || small { 10.0 } else { 0.0 }
        };
        let keep = |largest_only| {
            let s = FillSettings {
                iso: 5.0,
                spacing: 0.05,
                largest_only,
            };
            surface_and_fill(&grid_of(two), &s, BOUNDS).unwrap()
        };
        let one = keep(true);
        assert_eq!(one.components, 2);
        assert!(
            one.particles.iter().all(|p| p[0] < 0.15),
            "a floater survived"
        );
        let both = keep(false);
        assert!(
            both.particles.iter().any(|p| p[0] > 0.25),
            "the small body is missing"
        );
        assert!(both.particles.len() > one.particles.len());
    }

    #[test]
    fn particles_stay_inside_the_bounds() {
        let off = |p: [f64; 3]| ball([p[0] - 0.25, p[1], p[2]]);
        let bounds = ([-0.5; 3], [0.4, 0.5, 0.5]);
        let s = FillSettings {
            iso: 5.0,
            spacing: 0.05,
            largest_only: true,
        };
        let f = surface_and_fill(&grid_of(off), &s, bounds).unwrap();
        assert!(!f.particles.is_empty());
        assert!(f.particles.iter().all(|p| f64::from(p[0]) <= 0.4 + 1e-6));
    }

    #[test]
    fn a_cube_fills_the_lattice_it_holds() {
        // the cube |x|, |y|, |z| < 0.2 between grid points (the grid points are multiples of
        // 0.02, the surface sits where the step changes: halfway, at ±0.21 → side 0.42)
        let cube = |p: [f64; 3]| {
            if p.iter().all(|c| c.abs() < 0.2 + 1e-9) {
                10.0
            } else {
                0.0
            }
        };
        let s = FillSettings {
            iso: 5.0,
            spacing: 0.05,
            largest_only: true,
        };
        let f = surface_and_fill(&grid_of(cube), &s, BOUNDS).unwrap();
        let side: f64 = 0.42;
        assert!(
            (f.mesh.volume() - side.powi(3)).abs() / side.powi(3) < 0.03,
            "{}",
            f.mesh.volume()
        );
        // lattice points centred in [−0.5, 0.5] with spacing 0.05: 0, ±0.05, …, ±0.2 lie inside
        // |c| < 0.21 on each axis → 9³
        assert_eq!(f.particles.len(), 9 * 9 * 9);
    }

    #[test]
    fn bad_inputs_are_refused_with_reasons() {
        let empty = grid_of(|_| 0.0);
        let e = surface(&empty, 5.0, true).unwrap_err().to_string();
        assert!(e.contains("no value above the threshold"), "{e}");
        let (mut mesh, _) = surface(&grid_of(ball), 5.0, true).unwrap();
        mesh.triangles.pop();
        let e = fill(&mesh, 0.05, BOUNDS).unwrap_err().to_string();
        assert!(e.contains("not closed"), "{e}");
        let (mesh, _) = surface(&grid_of(ball), 5.0, true).unwrap();
        assert!(fill(&mesh, 0.0, BOUNDS).is_err());
        assert!(fill(&mesh, 0.05, ([0.0; 3], [0.0; 3])).is_err());
        assert!(DensityGrid::new([0.0; 3], 0.1, [2, 2, 2], vec![0.0; 7]).is_err());
        assert!(DensityGrid::new([0.0; 3], 0.1, [2, 2, 2], vec![f32::NAN; 8]).is_err());
    }
}
