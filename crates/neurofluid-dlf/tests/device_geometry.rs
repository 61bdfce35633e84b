//! DLF's geometry in slots on the GPU (`ConvGeometry::on_device`, every GPU step without
//! viscosity): the pairs found there (`neighbour_search = "device"`, `neurofluid_core::device_pairs`)
//! or by the host's grid and uploaded, the mapping one kernel (`device_cells`) or, off the
//! cubecl backends, tensor ops with its branches found from the values. Against the host: the
//! mapping's kernel-cell weights on any device (the CPU in CI), the kernel against the tensor
//! ops, and a whole step on the test device (`NEUROFLUID_TEST_DEVICE=wgpu`: lavapipe without a
//! GPU) with the pairs from either search: the positions, the neighbour counts, conv1's kernel
//! gradient and, with the differentiable geometry, the positions' gradient. On a CPU backend
//! the step is the host's to the bit whatever the setting.

mod common;

use burn::prelude::*;
use common::*;
use neurofluid_core::device_search::{NeighbourSearch, set_neighbour_search};
use neurofluid_core::rows::{RowIndex, gather_rows};
use neurofluid_core::transfer::{self, Counts};
use neurofluid_dlf::diff_geometry::{Branches, pair_weights};
use neurofluid_dlf::geometry::{FILTER_EXTENT, build_host_geometry, cell_weights};
use neurofluid_dlf::scene::{block_in_box, dlf_wall_spacing};
use neurofluid_dlf::{DlfConfig, DlfNet, GeometryMode, dlf_step_loss, load_dlf};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// A random cloud with points on the mapping's special lines (axes, poles, diagonals) around
/// its first point, where the branches switch.
fn cloud() -> Vec<[f32; 3]> {
    let mut rng = ChaCha8Rng::seed_from_u64(21);
    let mut pts: Vec<[f32; 3]> = (0..500)
        .map(|_| std::array::from_fn(|_| rng.random_range(0.0..0.5)))
        .collect();
    let c = pts[0];
    for d in [
        [0.05, 0.0, 0.0],
        [0.0, -0.05, 0.0],
        [0.0, 0.0, 0.07],
        [0.0, 0.0, -0.02],
        [0.03, 0.03, 0.0],
        [-0.03, 0.03, 0.01],
        [0.02, -0.02, 0.06],
    ] {
        pts.push([c[0] + d[0], c[1] + d[1], c[2] + d[2]]);
    }
    pts
}

#[test]
fn branches_found_from_the_values_give_the_hosts_cell_weights() {
    let device = device();
    let pts = cloud();
    let host = build_host_geometry(&pts, &pts, FILTER_EXTENT, true, None);
    let p = host.num_pairs();
    assert!(p > 1000, "{p} pairs");
    let x = to_tensor(&pts, &device);
    let cols = RowIndex::new(host.pairs.indices.iter().map(|&i| i as usize), &device);
    let rows = RowIndex::new(host.query_of_pair.iter().map(|&q| q as usize), &device);
    let rel = gather_rows(x.clone(), &cols) - gather_rows(x, &rows);
    let (corners, lower) = pair_weights(rel.clone(), FILTER_EXTENT, Branches::Values);
    let found = host_values(&cell_weights(corners, lower));
    // the host's own arrays: its corner weights and lower corners
    let w = TensorData::new(host.weights.clone(), [p, 8]);
    let l: Vec<f32> = host.lower.iter().flat_map(|l| l.map(f32::from)).collect();
    let expected = host_values(&cell_weights(
        neurofluid_core::transfer::upload(w, &device),
        neurofluid_core::transfer::upload(TensorData::new(l, [p, 3]), &device),
    ));
    let err = rel_err(&found, &expected);
    assert!(err < 2e-6, "cell weights differ by {err:.2e}");
    // and the host branches through the same ops
    let (corners, lower) = pair_weights(rel, FILTER_EXTENT, Branches::Host(&host));
    let err = rel_err(&host_values(&cell_weights(corners, lower)), &expected);
    assert!(err < 2e-6, "host branches: {err:.2e}");
}

fn host_values(t: &Tensor<2>) -> Vec<f32> {
    transfer::read_vec::<f32, 2, burn::tensor::Float>(t.clone()).expect("read")
}

/// One step at `place` on `device` (autodiff): the positions, the neighbour counts, conv1's
/// kernel gradient, the input positions' gradient, and the step's copies.
struct Step {
    pos: Vec<f32>,
    counts: Vec<u32>,
    kernel_grad: Vec<f32>,
    pos_grad: Option<Vec<f32>>,
    copies: Counts,
}

fn step(place: NeighbourSearch, mode: GeometryMode) -> Step {
    let device = device().autodiff();
    set_neighbour_search(place);
    let config = DlfConfig {
        geometry: mode,
        ..DlfConfig::default()
    };
    let net: DlfNet =
        load_dlf(&weights("pretrained_model_weights.pt"), config, &device).expect("weights");
    let scene = block_in_box(700, dlf_wall_spacing(), [0.3, -0.2, 0.2], 0.002, 3, 0.01);
    let boundary = net.boundary(&scene.box_points, &scene.box_normals, &device);
    let pos = to_tensor(&scene.pos, &device).require_grad();
    let vel = to_tensor(&scene.vel, &device);
    let before = transfer::counts();
    let o = net.step(pos.clone(), vel, &boundary);
    let loss = dlf_step_loss(
        o.pos.clone(),
        pos.clone().detach() + 0.01,
        &o.num_fluid_neighbors,
    );
    let grads = loss.backward();
    let copies = transfer::counts().since(before);
    set_neighbour_search(NeighbourSearch::Host);
    let kernel_grad = net
        .conv1
        .kernel
        .val()
        .grad(&grads)
        .expect("kernel gradient");
    Step {
        pos: host_values(&o.pos),
        counts: o.num_fluid_neighbors,
        kernel_grad: host_values(&kernel_grad.reshape([1, -1])),
        pos_grad: (mode == GeometryMode::Differentiable)
            .then(|| host_values(&pos.grad(&grads).expect("positions' gradient"))),
        copies,
    }
}

/// One test (the search's place is a process setting, which parallel tests would share).
#[test]
fn a_step_with_the_search_on_the_gpu_is_the_hosts() {
    let on_gpu = !neurofluid_core::device::is_host(&device());
    for mode in [GeometryMode::Constant, GeometryMode::Differentiable] {
        let host = step(NeighbourSearch::Host, mode);
        let found = step(NeighbourSearch::Device, mode);
        assert_eq!(found.counts, host.counts, "{mode:?}: neighbour counts");
        if !on_gpu {
            // the CPU backends search on the host whatever the setting
            assert_eq!(found.pos, host.pos);
            assert_eq!(found.kernel_grad, host.kernel_grad);
            continue;
        }
        let e = rel_err(&found.pos, &host.pos);
        assert!(e < 1e-6, "{mode:?}: positions differ by {e:.2e}");
        let e = rel_err(&found.kernel_grad, &host.kernel_grad);
        assert!(
            e < 1e-4,
            "{mode:?}: conv1's kernel gradient differs by {e:.2e}"
        );
        if let (Some(a), Some(b)) = (&found.pos_grad, &host.pos_grad) {
            let e = rel_err(a, b);
            assert!(
                e < 1e-4,
                "{mode:?}: the positions' gradient differs by {e:.2e}"
            );
        }
        eprintln!(
            "{mode:?}: copies of a step with its gradient, search on the host: {}; on the GPU: {}",
            host.copies.describe(),
            found.copies.describe()
        );
        assert!(
            found.copies.upload_bytes < host.copies.upload_bytes,
            "{mode:?}: fewer bytes up with the search on the GPU"
        );
    }
}

#[test]
fn a_chunk_fits_the_devices_largest_buffer() {
    use neurofluid_dlf::geometry::{HOST_CHUNK_SLOTS, SLOT_BYTES, chunk_slots};
    let device = device();
    let slots = chunk_slots(&device);
    match neurofluid_core::device::max_buffer_bytes(&device) {
        None => assert_eq!(slots, HOST_CHUNK_SLOTS),
        Some(bytes) => {
            assert!(
                slots as u64 * SLOT_BYTES <= bytes,
                "{slots} slots in {bytes} bytes"
            );
            assert!(slots >= 1);
        }
    }
}

/// The slots' kernel-cell weights as one kernel (`device_cells`, the cubecl backends) against
/// the tensor mapping they replace, values and gradients in the relative positions: the cloud's
/// pairs (the mapping's special lines among them), each also as a padding slot, and a query on
/// its own point. Off the cubecl backends the kernel declines.
#[test]
fn the_slot_kernel_is_the_tensor_mapping() {
    use neurofluid_dlf::device_cells::slot_cell_weights;
    let device = device().autodiff();
    let pts = cloud();
    let host = build_host_geometry(&pts, &pts, FILTER_EXTENT, true, None);
    let mut rel: Vec<f32> = Vec::new();
    for (p, &j) in host.pairs.indices.iter().enumerate() {
        let (a, b) = (pts[j as usize], pts[host.query_of_pair[p] as usize]);
        rel.extend((0..3).map(|k| a[k] - b[k]));
    }
    let pairs = rel.len() / 3;
    // padding: the same pairs again, weight zero; a pair of a point with itself
    rel.extend_from_within(..);
    rel.extend([0.0, 0.0, 0.0]);
    let slots = rel.len() / 3;
    let real: Vec<f32> = (0..slots)
        .map(|s| f32::from(u8::from(s < pairs || s == slots - 1)))
        .collect();
    let mut rng = ChaCha8Rng::seed_from_u64(3);
    let up: Vec<f32> = (0..slots * 64)
        .map(|_| rng.random_range(-1.0..1.0))
        .collect();
    let up =
        transfer::upload::<2, burn::tensor::Float, _>(TensorData::new(up, [slots, 64]), &device);
    let real =
        transfer::upload::<2, burn::tensor::Float, _>(TensorData::new(real, [slots, 1]), &device);
    let rel_of = || {
        transfer::upload::<2, burn::tensor::Float, _>(
            TensorData::new(rel.clone(), [slots, 3]),
            &device,
        )
        .require_grad()
    };
    if slot_cell_weights(&rel_of(), &real, FILTER_EXTENT).is_none() {
        assert!(
            neurofluid_core::device::is_host(&device),
            "the kernel declined on a GPU backend"
        );
        return;
    }
    let rel_k = rel_of();
    let found = slot_cell_weights(&rel_k, &real, FILTER_EXTENT).expect("the kernel");
    let rel_t = rel_of();
    let (corners, lower) = pair_weights(rel_t.clone(), FILTER_EXTENT, Branches::Values);
    let expected = cell_weights(corners * real.clone(), lower);
    let e = rel_err(&host_values(&found), &host_values(&expected));
    assert!(e < 2e-6, "cell weights differ by {e:.2e}");
    let g_found = (found * up.clone()).sum().backward();
    let g_expected = (expected * up).sum().backward();
    let a = host_values(&rel_k.grad(&g_found).expect("kernel gradient"));
    let b = host_values(&rel_t.grad(&g_expected).expect("tensor gradient"));
    assert!(
        a[pairs * 3..(slots - 1) * 3].iter().all(|&g| g == 0.0),
        "padding has no gradient"
    );
    let e = rel_err(&a, &b);
    assert!(e < 1e-4, "gradients differ by {e:.2e}");
    eprintln!("{slots} slots: weights and gradients agree ({e:.2e})");
}
