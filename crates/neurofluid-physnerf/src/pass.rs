//! One rendering pass in stages, each a function a backend can replace on its own:
//! [`sample_points`] → [`neighbours`] → [`Gate`] → [`features`] → [`field`] → [`place`] →
//! [`composite`]. The sample positions and the gate are host work (the gate decides which
//! samples the networks see), the ball query host work or a kernel on the particles' GPU
//! (`neighbour_search`); the rest are tensor ops on the particles' device.

use burn::prelude::*;
use burn::tensor::DType;
use neurofluid_core::device_search::{NeighbourSearch, neighbour_search};
use neurofluid_core::rows::{RowIndex, add_rows};

use crate::config::PhysNerfConfig;
use crate::encoding::encode_inputs;
use crate::error::{PhysNerfError, Result};
use crate::features::{gather_neighbors, host_tensor, local_features, rows_tensor, valid_tensor};
use crate::mlp::NerfMlp;
use crate::neighbors::{Neighbors, ball_query, ball_query_on_gpu};
use crate::real::Real;
use crate::volume::{Composite, deltas, volume_render};

/// A pass's rays on the host: origins and directions `[R]`, depths `[R·S]`, `s` = S per ray.
#[derive(Debug, Clone, Copy)]
pub struct Rays<'a, T> {
    /// Ray origins.
    pub origins: &'a [[T; 3]],
    /// Ray directions.
    pub dirs: &'a [[T; 3]],
    /// Sorted depths, S per ray.
    pub z: &'a [T],
    /// Samples per ray.
    pub s: usize,
}

/// The sample positions `o + z·d` of every ray, ray after ray `[R·S]`.
pub fn sample_points<T: Real>(rays: &Rays<'_, T>) -> Vec<[T; 3]> {
    let mut x = Vec::with_capacity(rays.z.len());
    for (ray, (o, d)) in rays.origins.iter().zip(rays.dirs).enumerate() {
        for &zi in &rays.z[ray * rays.s..(ray + 1) * rays.s] {
            x.push([o[0] + d[0] * zi, o[1] + d[1] * zi, o[2] + d[2] * zi]);
        }
    }
    x
}

/// The K neighbours of every sample within the search radius (the configured selection rule):
/// on the host, or on `device`'s GPU where the process's `neighbour_search` is `device`, the
/// device is a GPU and the precision f32 (`neurofluid_core::device_search`).
pub fn neighbours<T: Real>(
    particles: &[[T; 3]],
    x: &[[T; 3]],
    cfg: &PhysNerfConfig,
    device: &Device,
) -> Result<Neighbors<T>> {
    if neighbour_search() == NeighbourSearch::Device
        && let Some(found) = ball_query_on_gpu(
            device,
            particles,
            x,
            cfg.search_radius,
            cfg.k,
            cfg.selection,
        )
    {
        return found.map_err(PhysNerfError::Readback);
    }
    Ok(ball_query(
        particles,
        x,
        cfg.search_radius,
        cfg.k,
        cfg.selection,
    ))
}

/// The occupancy gate: a sample is seen by the networks when all K neighbour slots are filled.
#[derive(Debug, Clone)]
pub struct Gate<T> {
    /// The neighbours of every sample.
    pub neighbours: Neighbors<T>,
    /// `[R·S]` filled neighbour slots (0…K).
    pub num_nn: Vec<u8>,
    /// `[R·S]` the gate (all K slots filled).
    pub mask: Vec<bool>,
    /// `[R·S]` sum of the neighbour indices (empty slots count 0).
    pub nbr_idx_sum: Vec<u32>,
    /// The samples the networks evaluate: the gated ones (`gated_only`), else every sample.
    pub selected: Vec<usize>,
}

impl<T: Real> Gate<T> {
    /// The gate of the `samples` samples' `neighbours` under `cfg` (`k`, `gated_only`).
    pub fn of(neighbours: Neighbors<T>, samples: usize, cfg: &PhysNerfConfig) -> Self {
        let q_all = samples;
        let num_nn: Vec<u8> = (0..q_all).map(|q| neighbours.num_valid(q) as u8).collect();
        let mask: Vec<bool> = num_nn.iter().map(|&n| n as usize == cfg.k).collect();
        let nbr_idx_sum = (0..q_all).map(|q| neighbours.index_sum(q) as u32).collect();
        let selected = if cfg.gated_only {
            (0..q_all).filter(|&q| mask[q]).collect()
        } else {
            (0..q_all).collect()
        };
        Self {
            neighbours,
            num_nn,
            mask,
            nbr_idx_sum,
            selected,
        }
    }

    /// Samples of the pass.
    pub fn len(&self) -> usize {
        self.mask.len()
    }

    /// Whether the pass has no samples.
    pub fn is_empty(&self) -> bool {
        self.mask.is_empty()
    }
}

/// The networks' inputs for the selected samples: the encoded positions with the particle
/// features, and the encoded directions (`None` when no sample is selected).
pub fn features<T: Real>(
    particles: &Tensor<2>,
    rays: &Rays<'_, T>,
    x: &[[T; 3]],
    gate: &Gate<T>,
    cfg: &PhysNerfConfig,
) -> Option<(Tensor<2>, Tensor<2>)> {
    if gate.selected.is_empty() {
        return None;
    }
    let device = particles.device();
    let (k, s) = (cfg.k, rays.s);
    let nb = &gate.neighbours;
    let selected = &gate.selected;
    let xs: Vec<[T; 3]> = selected.iter().map(|&q| x[q]).collect();
    let os: Vec<[T; 3]> = selected.iter().map(|&q| rays.origins[q / s]).collect();
    let ds: Vec<[T; 3]> = selected.iter().map(|&q| rays.dirs[q / s]).collect();
    let mut idx = Vec::with_capacity(selected.len() * k);
    let mut d2 = Vec::with_capacity(selected.len() * k);
    for &q in selected {
        idx.extend_from_slice(&nb.idx[q * k..(q + 1) * k]);
        d2.extend_from_slice(&nb.dist2[q * k..(q + 1) * k]);
    }
    let x_t = rows_tensor(&xs, &device);
    let nbr = gather_neighbors(particles, &idx, k);
    let feats = local_features(
        x_t.clone(),
        nbr,
        valid_tensor(&d2, k, &device),
        rows_tensor(&os, &device),
        cfg.search_radius,
    );
    Some(encode_inputs(x_t, rows_tensor(&ds, &device), &feats, cfg))
}

/// The radiance field on the selected samples: colours `[G, 3]` and densities `[G, 1]`, the
/// density activation applied (softplus must come before the gate, which zeroes the density of
/// ungated samples).
pub fn field(
    net: &NerfMlp,
    e_x: Tensor<2>,
    e_d: Tensor<2>,
    cfg: &PhysNerfConfig,
) -> (Tensor<2>, Tensor<2>) {
    let (rgb, sigma) = net.forward(e_x, e_d);
    (rgb, cfg.density.before_mask(sigma))
}

/// The field's values at every sample `[R·S, 3]`, `[R·S, 1]`: the selected samples' in place,
/// zero elsewhere (`gated_only`), or every sample's times the gate.
pub fn place<T: Real>(
    field: Option<(Tensor<2>, Tensor<2>)>,
    gate: &Gate<T>,
    device: &Device,
    dtype: DType,
    cfg: &PhysNerfConfig,
) -> (Tensor<2>, Tensor<2>) {
    let q_all = gate.len();
    let zeros = |c: usize| Tensor::<2>::zeros([q_all, c], (device, dtype));
    let Some((rgb, sigma)) = field else {
        return (zeros(3), zeros(1));
    };
    if cfg.gated_only {
        let ids = RowIndex::new(gate.selected.iter().copied(), device);
        (
            add_rows(zeros(3), &ids, rgb),
            add_rows(zeros(1), &ids, sigma),
        )
    } else {
        let m: Vec<T> = gate
            .mask
            .iter()
            .map(|&b| if b { T::one() } else { T::zero() })
            .collect();
        let m = host_tensor(m, [q_all, 1], device);
        (rgb * m.clone(), sigma * m)
    }
}

/// Volume rendering of every ray from the placed colours and densities.
pub fn composite<T: Real>(
    rgb: Tensor<2>,
    sigma: Tensor<2>,
    rays: &Rays<'_, T>,
    device: &Device,
    cfg: &PhysNerfConfig,
) -> Composite {
    let (r, s) = (rays.dirs.len(), rays.s);
    let dl = host_tensor(deltas(rays.z, s, rays.dirs), [r, s], device);
    volume_render(
        rgb.reshape([r, s, 3]),
        sigma.reshape([r, s]),
        dl,
        cfg.white_background,
    )
}
