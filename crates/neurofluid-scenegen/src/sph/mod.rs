//! A compact DFSPH solver (Bender & Koschier 2015): a divergence solve and a constant-density
//! solve per substep (Jacobi, with the DFSPH factor α), explicit Laplacian viscosity with
//! stable sub-iterations, single-layer boundary particles (Akinci 2012 volumes) and a CFL step.
//! Densities are normalised by the rest density (ρ̂ = ρ/ρ₀). Every parallel loop writes its
//! own particle's value and every reduction is sequential, so runs are bit-reproducible.

pub mod grid;
pub mod kernel;

use glam::DVec3;
use rayon::prelude::*;

use grid::{Grid, Neighbours};
use kernel::CubicKernel;

/// Material of the fluid.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Fluid {
    /// Rest density in kg/m³ (recorded; the solver works with ρ/ρ₀).
    pub density: f64,
    /// Kinematic viscosity coefficient of the Laplacian term (m²/s).
    pub viscosity: f64,
    /// Viscosity coefficient against the walls (m²/s); 0 = free slip.
    pub wall_viscosity: f64,
}

impl Fluid {
    /// Water: density 1000, low viscosity, free slip at the walls.
    pub const WATER: Fluid = Fluid {
        density: 1000.0,
        viscosity: 0.05,
        wall_viscosity: 0.0,
    };
    /// Honey: density 1420, high viscosity, sticks to the walls.
    pub const HONEY: Fluid = Fluid {
        density: 1420.0,
        viscosity: 0.4,
        wall_viscosity: 0.4,
    };
}

/// Solver settings (SPlisHSPlasH-like defaults, spec neurofluid.md §5.2).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SolverParams {
    /// Particle radius; lattice spacing 2r, kernel support 4r.
    pub radius: f64,
    /// Largest substep (s).
    pub max_dt: f64,
    /// CFL factor: a particle moves at most `cfl · 2r` per substep.
    pub cfl: f64,
    /// Average density error at which the density solve stops (0.0005 = 0.05 %).
    pub max_density_error: f64,
    /// Average divergence error (per substep, relative) at which the divergence solve stops.
    pub max_divergence_error: f64,
    /// Iteration cap of both solves.
    pub max_iterations: usize,
    /// Gravity (m/s²).
    pub gravity: [f64; 3],
}

impl Default for SolverParams {
    fn default() -> Self {
        Self {
            radius: 0.025,
            max_dt: 0.005,
            cfl: 0.5,
            max_density_error: 0.0005,
            max_divergence_error: 0.001,
            max_iterations: 100,
            gravity: [0.0, -crate::presets::EARTH_GRAVITY, 0.0],
        }
    }
}

/// What one frame of simulation did.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct FrameStats {
    /// Substeps taken.
    pub substeps: usize,
    /// Density-solve iterations, summed over substeps.
    pub density_iterations: usize,
    /// Divergence-solve iterations, summed over substeps.
    pub divergence_iterations: usize,
    /// Times a particle had to be pushed back inside the box (a safety net; ideally 0).
    pub clamped: usize,
    /// Average density error after the last substep.
    pub density_error: f64,
}

/// The fluid state and the static boundary.
pub struct Solver {
    params: SolverParams,
    fluid: Fluid,
    kernel: CubicKernel,
    volume: f64,
    /// Particle positions.
    pub pos: Vec<DVec3>,
    /// Particle velocities.
    pub vel: Vec<DVec3>,
    boundary: Vec<DVec3>,
    psi: Vec<f64>,
    bgrid: Grid,
    lo: DVec3,
    hi: DVec3,
    density: Vec<f64>,
    alpha: Vec<f64>,
    nf: Neighbours,
    nb: Neighbours,
}

impl Solver {
    /// A solver for fluid particles `pos` (velocities `vel`) in the box `[lo, hi]` whose walls
    /// are sampled by `walls` (boundary particles).
    pub fn new(
        pos: Vec<DVec3>,
        vel: Vec<DVec3>,
        walls: &[DVec3],
        lo: DVec3,
        hi: DVec3,
        fluid: Fluid,
        params: SolverParams,
    ) -> Self {
        let h = 4.0 * params.radius;
        let kernel = CubicKernel::new(h);
        let bgrid = Grid::build(walls, h, lo, hi);
        let bn = Neighbours::search(&bgrid, walls, walls, h, true);
        let psi = (0..walls.len())
            .into_par_iter()
            .map(|b| {
                let s: f64 = kernel.w(0.0)
                    + bn.of(b)
                        .iter()
                        .map(|&c| kernel.w((walls[b] - walls[c as usize]).length()))
                        .sum::<f64>();
                1.0 / s
            })
            .collect();
        let n = pos.len();
        Self {
            volume: (2.0 * params.radius).powi(3),
            params,
            fluid,
            kernel,
            pos,
            vel,
            boundary: walls.to_vec(),
            psi,
            bgrid,
            lo,
            hi,
            density: vec![1.0; n],
            alpha: vec![0.0; n],
            nf: Neighbours::default(),
            nb: Neighbours::default(),
        }
    }

    /// Number of fluid particles.
    pub fn len(&self) -> usize {
        self.pos.len()
    }

    /// True when there are no fluid particles.
    pub fn is_empty(&self) -> bool {
        self.pos.is_empty()
    }

    /// Kinetic energy per unit rest density, ½ Σ V₀ |v|² (multiply by ρ₀ for joules).
    pub fn kinetic_energy(&self) -> f64 {
        0.5 * self.volume * self.vel.iter().map(|v| v.length_squared()).sum::<f64>()
    }

    /// Normalised densities ρ/ρ₀ of the last substep.
    pub fn densities(&self) -> &[f64] {
        &self.density
    }

    /// Advances by one frame of length `frame_dt`, in CFL-limited equal substeps.
    pub fn advance(&mut self, frame_dt: f64) -> FrameStats {
        let vmax = self.vel.iter().map(|v| v.length()).fold(0.0, f64::max);
        let g = DVec3::from(self.params.gravity).length();
        let v_est = vmax + g * frame_dt;
        let dt_cfl = if v_est > 0.0 {
            (self.params.cfl * 2.0 * self.params.radius / v_est).min(self.params.max_dt)
        } else {
            self.params.max_dt
        };
        let n = (frame_dt / dt_cfl).ceil().max(1.0) as usize;
        let dt = frame_dt / n as f64;
        let mut stats = FrameStats {
            substeps: n,
            ..Default::default()
        };
        for _ in 0..n {
            self.step(dt, &mut stats);
        }
        stats
    }

    fn update_neighbours_and_density(&mut self) {
        let h = self.kernel.support();
        let fgrid = Grid::build(&self.pos, h, self.lo, self.hi);
        self.nf = Neighbours::search(&fgrid, &self.pos, &self.pos, h, true);
        self.nb = Neighbours::search(&self.bgrid, &self.boundary, &self.pos, h, false);
        let (k, v0) = (self.kernel, self.volume);
        let (pos, bnd, psi, nf, nb) = (&self.pos, &self.boundary, &self.psi, &self.nf, &self.nb);
        let res: Vec<(f64, f64)> = (0..pos.len())
            .into_par_iter()
            .map(|i| {
                let xi = pos[i];
                let mut rho = v0 * k.w(0.0);
                let mut grad = DVec3::ZERO;
                let mut sq = 0.0;
                for &j in nf.of(i) {
                    let x = xi - pos[j as usize];
                    rho += v0 * k.w(x.length());
                    let gw = k.grad(x) * v0;
                    grad += gw;
                    sq += gw.length_squared();
                }
                for &b in nb.of(i) {
                    let x = xi - bnd[b as usize];
                    rho += psi[b as usize] * k.w(x.length());
                    grad += k.grad(x) * psi[b as usize];
                }
                let denom = grad.length_squared() + sq;
                (rho, if denom > 1e-6 { 1.0 / denom } else { 0.0 })
            })
            .collect();
        for (i, (rho, a)) in res.into_iter().enumerate() {
            self.density[i] = rho;
            self.alpha[i] = a;
        }
    }

    /// Rate of change of ρ̂ of every particle under the current velocities.
    fn density_rates(&self) -> Vec<f64> {
        let (k, v0) = (self.kernel, self.volume);
        let (pos, vel, bnd, psi, nf, nb) = (
            &self.pos,
            &self.vel,
            &self.boundary,
            &self.psi,
            &self.nf,
            &self.nb,
        );
        (0..pos.len())
            .into_par_iter()
            .map(|i| {
                let (xi, vi) = (pos[i], vel[i]);
                let mut s = 0.0;
                for &j in nf.of(i) {
                    let j = j as usize;
                    s += v0 * (vi - vel[j]).dot(k.grad(xi - pos[j]));
                }
                for &b in nb.of(i) {
                    let b = b as usize;
                    s += psi[b] * vi.dot(k.grad(xi - bnd[b]));
                }
                s
            })
            .collect()
    }

    /// Applies Δvᵢ = −dt·(Σⱼ V₀(κᵢ+κⱼ)∇Wᵢⱼ + Σ_b Ψ_b κᵢ ∇W_ib).
    fn apply_kappa(&mut self, kappa: &[f64], dt: f64) {
        let (k, v0) = (self.kernel, self.volume);
        let (pos, bnd, psi, nf, nb) = (&self.pos, &self.boundary, &self.psi, &self.nf, &self.nb);
        let dv: Vec<DVec3> = (0..pos.len())
            .into_par_iter()
            .map(|i| {
                let xi = pos[i];
                let mut acc = DVec3::ZERO;
                for &j in nf.of(i) {
                    let j = j as usize;
                    acc += k.grad(xi - pos[j]) * (v0 * (kappa[i] + kappa[j]));
                }
                for &b in nb.of(i) {
                    let b = b as usize;
                    acc += k.grad(xi - bnd[b]) * (psi[b] * kappa[i]);
                }
                -dt * acc
            })
            .collect();
        for (v, d) in self.vel.iter_mut().zip(dv) {
            *v += d;
        }
    }

    /// Jacobi iterations of the divergence (`divergence = true`) or constant-density solve.
    fn solve(&mut self, dt: f64, divergence: bool) -> (usize, f64) {
        let n = self.len().max(1) as f64;
        let min_iter = if divergence { 1 } else { 2 };
        let tol = if divergence {
            self.params.max_divergence_error
        } else {
            self.params.max_density_error
        };
        let mut err = 0.0;
        for iter in 0..self.params.max_iterations {
            let rates = self.density_rates();
            let mut kappa = vec![0.0; rates.len()];
            let mut sum = 0.0;
            for i in 0..rates.len() {
                if divergence {
                    let enough = self.nf.of(i).len() + self.nb.of(i).len() >= 20;
                    let s = if enough { rates[i].max(0.0) } else { 0.0 };
                    sum += s * dt;
                    kappa[i] = s * self.alpha[i] / dt;
                } else {
                    let e = (self.density[i] + dt * rates[i] - 1.0).max(0.0);
                    sum += e;
                    kappa[i] = e * self.alpha[i] / (dt * dt);
                }
            }
            err = sum / n;
            if iter >= min_iter && err <= tol {
                return (iter, err);
            }
            self.apply_kappa(&kappa, dt);
        }
        (self.params.max_iterations, err)
    }

    fn viscosity(&mut self, dt: f64) {
        let nu = self.fluid.viscosity.max(self.fluid.wall_viscosity);
        if nu <= 0.0 {
            return;
        }
        let subs = ((dt * nu * 7000.0).ceil() as usize).clamp(1, 500);
        let sdt = dt / subs as f64;
        let (k, v0) = (self.kernel, self.volume);
        let h2 = k.support() * k.support();
        let (nuf, nub) = (self.fluid.viscosity, self.fluid.wall_viscosity);
        for _ in 0..subs {
            let (pos, vel, bnd, psi, nf, nb) = (
                &self.pos,
                &self.vel,
                &self.boundary,
                &self.psi,
                &self.nf,
                &self.nb,
            );
            let acc: Vec<DVec3> = (0..pos.len())
                .into_par_iter()
                .map(|i| {
                    let (xi, vi) = (pos[i], vel[i]);
                    let mut a = DVec3::ZERO;
                    for &j in nf.of(i) {
                        let j = j as usize;
                        let x = xi - pos[j];
                        let f = (vi - vel[j]).dot(x) / (x.length_squared() + 0.01 * h2);
                        a += k.grad(x) * (10.0 * nuf * v0 * f);
                    }
                    if nub > 0.0 {
                        for &b in nb.of(i) {
                            let b = b as usize;
                            let x = xi - bnd[b];
                            let f = vi.dot(x) / (x.length_squared() + 0.01 * h2);
                            a += k.grad(x) * (10.0 * nub * psi[b] * f);
                        }
                    }
                    a
                })
                .collect();
            for (v, a) in self.vel.iter_mut().zip(acc) {
                *v += sdt * a;
            }
        }
    }

    fn step(&mut self, dt: f64, stats: &mut FrameStats) {
        self.update_neighbours_and_density();
        let (it, _) = self.solve(dt, true);
        stats.divergence_iterations += it;
        let g = DVec3::from(self.params.gravity);
        for v in &mut self.vel {
            *v += dt * g;
        }
        self.viscosity(dt);
        let (it, err) = self.solve(dt, false);
        stats.density_iterations += it;
        stats.density_error = err;
        let r = self.params.radius;
        let (lo, hi) = (self.lo + DVec3::splat(r), self.hi - DVec3::splat(r));
        for (x, v) in self.pos.iter_mut().zip(self.vel.iter_mut()) {
            *x += dt * *v;
            for a in 0..3 {
                if x[a] < lo[a] {
                    x[a] = lo[a];
                    v[a] = v[a].max(0.0);
                    stats.clamped += 1;
                } else if x[a] > hi[a] {
                    x[a] = hi[a];
                    v[a] = v[a].min(0.0);
                    stats.clamped += 1;
                }
            }
        }
    }
}
