//! The DLF network (docs/spec/dlf.md §3) and its integrator (§4).

use burn::nn::{Initializer, Linear, LinearConfig};
use burn::prelude::*;
use burn::tensor::activation::relu;

use crate::bodies::{body_labels, motion_within_bodies};
use crate::config::{DlfConfig, GeometryMode};
use crate::conv::ContinuousConv;
use crate::diff_geometry::differentiable_weights;
use crate::energy_cap::cap_particle_energy;
use crate::geometry::{ConvGeometry, build_host_geometry, chunk_slots, search_radius};
use crate::physics::PhysicsValues;
use crate::rules::{DissipationFrame, EnergyCap};
use crate::viscosity::smooth_velocities;
use neurofluid_core::device_pairs::{device_pairs, device_pairs_from_host};
use neurofluid_core::device_search::{NeighbourSearch, neighbour_search};
use neurofluid_core::neighbors::NeighborGrid;
use neurofluid_core::scene::Aabb;

/// Channel widths of the published model: layer 0 branches, layers 1, 2, 3.
pub const LAYER_CHANNELS: [usize; 4] = [32, 64, 64, 3];

/// The DLF network: parameter names match the upstream PyTorch state dict.
#[derive(Module, Debug)]
pub struct DlfNet {
    /// Fluid→fluid conv on `[1, v]` (4 → 32).
    pub conv0_fluid: ContinuousConv,
    /// Box→fluid conv on the box normals (3 → 32).
    pub conv0_obstacle: ContinuousConv,
    /// Dense layer on `[1, v]` (4 → 32).
    pub dense0_fluid: Linear,
    /// Layer 1 conv (96 → 64).
    pub conv1: ContinuousConv,
    /// Layer 1 dense (96 → 64).
    pub dense1: Linear,
    /// Layer 2 conv (64 → 64).
    pub conv2: ContinuousConv,
    /// Layer 2 dense (64 → 64).
    pub dense2: Linear,
    /// Layer 3 conv (64 → 3).
    pub conv3: ContinuousConv,
    /// Layer 3 dense (64 → 3).
    pub dense3: Linear,
    /// Gravity, time step, frame and geometry mode.
    #[module(skip)]
    pub config: DlfConfig,
    /// The physical scalars as tensors an optimiser fits, in place of the rules' constants
    /// ([`crate::physics`]); `None`: the rules' constants.
    #[module(skip)]
    pub physics: Option<PhysicsValues>,
}

/// Static boundary particles (the box) in the model frame.
#[derive(Debug, Clone)]
pub struct Boundary {
    /// Positions in the model frame (host copy, for the neighbour search).
    pub points: Vec<[f32; 3]>,
    /// Positions `[M, 3]` in the model frame.
    pub points_tensor: Tensor<2>,
    /// Unit normals `[M, 3]` in the model frame, pointing into the fluid region.
    pub normals: Tensor<2>,
}

/// Outputs of one network step.
#[derive(Debug, Clone)]
pub struct StepOutput {
    /// New positions `[N, 3]` (scene frame).
    pub pos: Tensor<2>,
    /// New velocities `[N, 3]` (scene frame).
    pub vel: Tensor<2>,
    /// Fluid neighbours of every particle at x* (self excluded), as used by the loss.
    pub num_fluid_neighbors: Vec<u32>,
}

/// The internals of one step, for parity checks against the reference ([`DlfNet::step_traced`]).
#[derive(Debug, Clone)]
pub struct StepTrace {
    /// Raw network output h3 `[N, 3]` (model frame, before the 1/128 scale).
    pub raw_output: Tensor<2>,
    /// x* after the gravity pre-step (model frame).
    pub pos_pred: Tensor<2>,
    /// v* after the gravity pre-step (model frame).
    pub vel_pred: Tensor<2>,
    /// Layer outputs (model frame): conv0_obstacle, conv0_fluid, dense0_fluid, h1, h2.
    pub features: LayerFeatures,
}

/// Intermediate features of one step (for parity checks).
#[derive(Debug, Clone)]
pub struct LayerFeatures {
    /// conv0_obstacle output `[N, 32]`.
    pub conv0_obstacle: Tensor<2>,
    /// conv0_fluid output `[N, 32]`.
    pub conv0_fluid: Tensor<2>,
    /// dense0_fluid output `[N, 32]`.
    pub dense0_fluid: Tensor<2>,
    /// h1 `[N, 64]`.
    pub layer1: Tensor<2>,
    /// h2 `[N, 64]` (with the residual).
    pub layer2: Tensor<2>,
}

fn linear(d_in: usize, d_out: usize, initializer: Initializer, device: &Device) -> Linear {
    LinearConfig::new(d_in, d_out)
        .with_initializer(initializer)
        .init(device)
}

fn rotation_tensor(r: [[f32; 3]; 3], transpose: bool, device: &Device) -> Tensor<2> {
    let v: Vec<f32> = (0..9)
        .map(|k| {
            let (i, j) = (k / 3, k % 3);
            if transpose { r[j][i] } else { r[i][j] }
        })
        .collect();
    neurofluid_core::transfer::upload(TensorData::new(v, [3, 3]), device)
}

pub use neurofluid_core::tensors::{points_tensor, tensor_points};

/// Positions `pos` `[N, 3]` (scene frame) clamped into `container`, and the velocities `vel`
/// corrected by the same displacement over `dt`, so that v = (x_{t+1} − x_t)/dt still holds.
/// Gradients pass through every coordinate the clamp leaves and stop at the ones it moves.
pub fn contain(
    pos: Tensor<2>,
    vel: Tensor<2>,
    container: &Aabb,
    dt: f32,
) -> (Tensor<2>, Tensor<2>) {
    let device = pos.device();
    let n = pos.dims()[0];
    let bound = |c: [f32; 3]| {
        neurofluid_core::transfer::upload::<2, burn::tensor::Float, _>(
            TensorData::new(c.to_vec(), [1, 3]),
            &device,
        )
        .expand([n, 3])
    };
    let clamped = pos
        .clone()
        .max_pair(bound(container.min))
        .min_pair(bound(container.max));
    let vel = vel + (clamped.clone() - pos) / dt;
    (clamped, vel)
}

impl DlfNet {
    /// A freshly initialised network (Open3D/torch initialisers) with the given settings: the
    /// convs' kernels drawn from the backend's RNG as they are built, in layer order, the dense
    /// layers' weights on their first use.
    pub fn new(config: DlfConfig, device: &Device) -> Self {
        let xavier = || Initializer::XavierUniform { gain: 1.0 };
        Self::build(config, device, ContinuousConv::new, xavier)
    }

    /// A network whose parameters are all zeros, to load weights into: it draws no random
    /// number, so loading weights leaves the backend's RNG where it was.
    pub fn zeros(config: DlfConfig, device: &Device) -> Self {
        Self::build(config, device, ContinuousConv::zeros, || Initializer::Zeros)
    }

    /// The layers, built by `conv` and with the dense layers' `initializer`, in layer order.
    fn build(
        config: DlfConfig,
        device: &Device,
        conv: fn(usize, usize, &Device) -> ContinuousConv,
        initializer: impl Fn() -> Initializer,
    ) -> Self {
        let [c0, c1, c2, c3] = LAYER_CHANNELS;
        let dense = |d_in, d_out| linear(d_in, d_out, initializer(), device);
        Self {
            conv0_fluid: conv(4, c0, device),
            conv0_obstacle: conv(3, c0, device),
            dense0_fluid: dense(4, c0),
            conv1: conv(3 * c0, c1, device),
            dense1: dense(3 * c0, c1),
            conv2: conv(c1, c2, device),
            dense2: dense(c1, c2),
            conv3: conv(c2, c3, device),
            dense3: dense(c2, c3),
            config,
            physics: None,
        }
    }

    /// The same network with other settings.
    pub fn with_config(mut self, config: DlfConfig) -> Self {
        self.config = config;
        self
    }

    /// The same network stepping with `physics` in place of its rules' constants (`None`: the
    /// constants).
    pub fn with_physics(mut self, physics: Option<PhysicsValues>) -> Self {
        self.physics = physics;
        self
    }

    /// The device of the parameters.
    pub fn device(&self) -> Device {
        self.conv1.kernel.val().device()
    }

    /// Rotates scene rows `[N, 3]` into the model frame.
    pub fn to_model(&self, t: Tensor<2>) -> Tensor<2> {
        match self.config.frame.rotation() {
            None => t,
            Some(r) => {
                let rt = rotation_tensor(r, true, &t.device());
                t.matmul(rt)
            }
        }
    }

    /// Rotates model rows `[N, 3]` back into the scene frame.
    pub fn to_scene(&self, t: Tensor<2>) -> Tensor<2> {
        match self.config.frame.rotation() {
            None => t,
            Some(r) => {
                let rr = rotation_tensor(r, false, &t.device());
                t.matmul(rr)
            }
        }
    }

    /// Prepares the static boundary (scene-frame points and normals) for [`DlfNet::step`].
    pub fn boundary(&self, points: &[[f32; 3]], normals: &[[f32; 3]], device: &Device) -> Boundary {
        let frame = self.config.frame;
        let pts: Vec<[f32; 3]> = points.iter().map(|&p| frame.to_model(p)).collect();
        let nrm: Vec<[f32; 3]> = normals.iter().map(|&n| frame.to_model(n)).collect();
        Boundary {
            points_tensor: points_tensor(&pts, device),
            normals: points_tensor(&nrm, device),
            points: pts,
        }
    }

    /// Builds the fluid and box geometries at x* (model frame).
    fn geometries(
        &self,
        pos_pred: &Tensor<2>,
        boundary: &Boundary,
    ) -> (ConvGeometry, ConvGeometry) {
        let device = pos_pred.device();
        let x = tensor_points(pos_pred);
        if let Some(found) = self.device_geometries(&x, pos_pred, boundary) {
            return found;
        }
        let extent = self.config.extent;
        let fluid = build_host_geometry(&x, &x, extent, true, None);
        let solid = build_host_geometry(&boundary.points, &x, extent, true, None);
        match self.config.geometry {
            GeometryMode::Constant => (
                ConvGeometry::new(fluid, None, &device),
                ConvGeometry::new(solid, None, &device),
            ),
            GeometryMode::Differentiable => {
                let wf = differentiable_weights(&fluid, pos_pred.clone(), pos_pred.clone(), extent);
                let ws = differentiable_weights(
                    &solid,
                    boundary.points_tensor.clone(),
                    pos_pred.clone(),
                    extent,
                );
                (
                    ConvGeometry::new(fluid, wf, &device),
                    ConvGeometry::new(solid, ws, &device),
                )
            }
        }
    }

    /// The fluid and box geometries in slots on the GPU ([`ConvGeometry::on_device`]: the
    /// mapping there too), where `pos_pred` lives on a GPU and no part of the step needs the
    /// pairs on the host (viscosity and the free flight's clusters do): the pairs found there
    /// (`neighbour_search = "device"`) or by the host's grid and uploaded; `None` otherwise, or
    /// (with a warning) where the device fails to search.
    fn device_geometries(
        &self,
        x: &[[f32; 3]],
        pos_pred: &Tensor<2>,
        boundary: &Boundary,
    ) -> Option<(ConvGeometry, ConvGeometry)> {
        let device = pos_pred.device();
        if self.config.rules.needs_host_pairs(self.physics.is_some())
            || neurofluid_core::device::is_host(&device)
        {
            return None;
        }
        let extent = self.config.extent;
        let radius = search_radius(extent);
        let slots = chunk_slots(&device);
        let box_points = &boundary.points;
        let (fluid, solid) = if neighbour_search() == NeighbourSearch::Device {
            (
                device_pairs(&device, x, x, radius, true, true, slots)?,
                device_pairs(&device, box_points, x, radius, true, false, slots)?,
            )
        } else {
            let pairs =
                |points: &[[f32; 3]]| NeighborGrid::new(points, radius).pairs(x, radius, true);
            let (fluid, solid) = rayon::join(|| pairs(x), || pairs(box_points));
            (
                device_pairs_from_host(&device, &fluid, x.len(), true, slots)?,
                device_pairs_from_host(&device, &solid, box_points.len(), false, slots)?,
            )
        };
        let (fluid, solid) = match (fluid, solid) {
            (Ok(f), Ok(s)) => (f, s),
            (Err(e), _) | (_, Err(e)) => {
                tracing::warn!("DLF's pairs on the GPU failed ({e}); the geometry on the host");
                return None;
            }
        };
        let positions = match self.config.geometry {
            GeometryMode::Constant => pos_pred.clone().detach(),
            GeometryMode::Differentiable => pos_pred.clone(),
        };
        Some((
            ConvGeometry::on_device(fluid, positions.clone(), positions.clone(), extent),
            ConvGeometry::on_device(solid, boundary.points_tensor.clone(), positions, extent),
        ))
    }

    /// Raw network output h3 `[N, 3]` at x* with velocities v* (model frame).
    pub fn correction(
        &self,
        vel_pred: Tensor<2>,
        boundary: &Boundary,
        fluid: &ConvGeometry,
        solid: &ConvGeometry,
    ) -> (Tensor<2>, LayerFeatures) {
        let [n, _] = vel_pred.dims();
        let ones = Tensor::<2>::ones([n, 1], &vel_pred.device());
        let feats = Tensor::cat(vec![ones, vel_pred], 1);
        let a = self.conv0_obstacle.forward(boundary.normals.clone(), solid);
        let b = self.conv0_fluid.forward(feats.clone(), fluid);
        let c = self.dense0_fluid.forward(feats);
        let h0 = Tensor::cat(vec![a.clone(), b.clone(), c.clone()], 1);
        let layer = |h: Tensor<2>, conv: &ContinuousConv, dense: &Linear| {
            let x = relu(h.clone());
            let y = conv.forward(x.clone(), fluid) + dense.forward(x);
            if y.dims()[1] == h.dims()[1] { y + h } else { y }
        };
        let h1 = layer(h0, &self.conv1, &self.dense1);
        let h2 = layer(h1.clone(), &self.conv2, &self.dense2);
        let h3 = layer(h2.clone(), &self.conv3, &self.dense3);
        let features = LayerFeatures {
            conv0_obstacle: a,
            conv0_fluid: b,
            dense0_fluid: c,
            layer1: h1,
            layer2: h2,
        };
        (h3, features)
    }

    /// One step (one frame, dt): gravity pre-step, network correction, velocity from the position
    /// difference; then, where the rules ask, viscosity, dissipation (in the box's frame or each
    /// body's), container, energy cap (the gravity scale, viscosity and dissipation from
    /// [`DlfNet::physics`] where it holds values).
    /// `pos`, `vel` `[N, 3]` are in the scene frame.
    pub fn step(&self, pos: Tensor<2>, vel: Tensor<2>, boundary: &Boundary) -> StepOutput {
        self.step_traced(pos, vel, boundary).0
    }

    /// [`DlfNet::step`], also returning the step's internals (x*, v*, the raw output and the
    /// layer features) for parity checks.
    pub fn step_traced(
        &self,
        pos: Tensor<2>,
        vel: Tensor<2>,
        boundary: &Boundary,
    ) -> (StepOutput, StepTrace) {
        let cfg = self.config;
        let device = pos.device();
        // the state in the scene frame, which the energy cap compares the step with
        let start =
            (cfg.rules.energy_cap == EnergyCap::Particle).then(|| (pos.clone(), vel.clone()));
        let pos = self.to_model(pos);
        let vel = self.to_model(vel);
        let row = |g: [f32; 3]| -> Tensor<2> {
            neurofluid_core::transfer::upload(TensorData::new(g.to_vec(), [1, 3]), &device)
        };
        let g = match &self.physics {
            None => row(cfg
                .model_gravity()
                .map(|c| cfg.dt * cfg.rules.gravity_scale as f32 * c)),
            Some(p) => {
                row(cfg.model_gravity().map(|c| cfg.dt * c))
                    * p.gravity_scale.clone().reshape([1, 1])
            }
        };
        let vel_pred = vel.clone() + g;
        let pos_pred = pos.clone() + ((vel_pred.clone() + vel) * cfg.dt) / 2.0;
        let (fluid, solid) = self.geometries(&pos_pred, boundary);
        let num_fluid_neighbors = fluid.counts();
        let (raw, features) = self.correction(vel_pred.clone(), boundary, &fluid, &solid);
        let shift = raw.clone() * cfg.output_scale;
        let pos_new = pos_pred.clone() + shift;
        let vel_new = (pos_new.clone() - pos) / cfg.dt;
        let (pos_new, vel_new) = (self.to_scene(pos_new), self.to_scene(vel_new));
        let radius = search_radius(cfg.extent);
        // each changes the velocities and shortens or lengthens the move to match
        let moved = |pos: Tensor<2>, vel: Tensor<2>, changed: Tensor<2>| {
            (pos + (changed.clone() - vel) * cfg.dt, changed)
        };
        let (pos_new, vel_new) = match &self.physics {
            None if cfg.rules.viscosity > 0.0 => {
                let strength = cfg.rules.viscosity as f32;
                let smoothed = smooth_velocities(vel_new.clone(), fluid.host(), radius, strength);
                moved(pos_new, vel_new, smoothed)
            }
            None => (pos_new, vel_new),
            // the smoothing is linear in its strength: v + s·(smoothed at strength 1 − v)
            Some(p) => {
                let full = smooth_velocities(vel_new.clone(), fluid.host(), radius, 1.0);
                let s = p.viscosity.clone().reshape([1, 1]);
                let smoothed = vel_new.clone() + (full - vel_new.clone()) * s;
                moved(pos_new, vel_new, smoothed)
            }
        };
        // the share of the velocity (the box's frame) or of its motion within its body taken away
        let body = cfg.rules.dissipation_frame == DissipationFrame::Body;
        let within =
            |vel: &Tensor<2>| motion_within_bodies(vel.clone(), &body_labels(fluid.host()));
        let (pos_new, vel_new) = match &self.physics {
            None if cfg.rules.dissipation > 0.0 => {
                let c = cfg.rules.dissipation as f32;
                let kept = if body {
                    vel_new.clone() - within(&vel_new) * c
                } else {
                    vel_new.clone() * (1.0 - c)
                };
                moved(pos_new, vel_new, kept)
            }
            None => (pos_new, vel_new),
            Some(p) => {
                let c = p.dissipation.clone().reshape([1, 1]);
                let kept = if body {
                    vel_new.clone() - within(&vel_new) * c
                } else {
                    vel_new.clone() * (c.neg() + 1.0)
                };
                moved(pos_new, vel_new, kept)
            }
        };
        let (pos_new, vel_new) = match &cfg.container {
            Some(c) => contain(pos_new, vel_new, c, cfg.dt),
            None => (pos_new, vel_new),
        };
        let (pos, vel) = match start {
            Some((x, v)) => cap_particle_energy(x, v, pos_new, vel_new, cfg.gravity),
            None => (pos_new, vel_new),
        };
        let out = StepOutput {
            pos,
            vel,
            num_fluid_neighbors,
        };
        let trace = StepTrace {
            raw_output: raw,
            pos_pred,
            vel_pred,
            features,
        };
        (out, trace)
    }
}
