//! The renderer with its ball query on the GPU (`neighbour_search = "device"`) against the same
//! render with the host's search, on the reference case and the test device: the same gate,
//! colours and particle gradient, and on a GPU the kernel's copies in the step (on a CPU backend
//! the setting falls back to the host). Its own test binary: the setting is the process's.

mod common;

use burn::prelude::*;
use burn::tensor::DType;
use common::*;
use neurofluid_core::choice::Choice;
use neurofluid_core::device::is_host;
use neurofluid_core::device_search::{NeighbourSearch, set_neighbour_search};
use neurofluid_core::transfer;

#[test]
fn the_gpu_search_renders_what_the_host_search_renders() {
    let (inputs, _) = case();
    let device = neurofluid_core::device::test_device().autodiff();
    let rays = inputs.rays::<f32>();
    let target = Tensor::<2>::full([rays.len(), 3], 0.3, &device);
    let model = model(&inputs, &device, DType::F32);
    // a first render fills the device's caches (the encodings' constants), so that the two
    // renders below upload the same but for the search
    let p = inputs.particles_tensor(&device, DType::F32);
    model.render_rays(&p, &rays, None).unwrap();
    let mut results = Vec::new();
    for &place in NeighbourSearch::ALL {
        set_neighbour_search(place);
        let p = inputs.particles_tensor(&device, DType::F32).require_grad();
        let before = transfer::counts();
        let out = model.render_rays(&p, &rays, None).unwrap();
        let copies = transfer::counts().since(before);
        let fine = out.fine.as_ref().expect("the case has a fine pass");
        let gate = (
            out.coarse.mask.clone(),
            fine.num_nn.clone(),
            fine.nbr_idx_sum.clone(),
        );
        let rgb = vals(out.final_rgb());
        let grads = model.loss(&out, target.clone()).total.backward();
        results.push((gate, rgb, vals(p.grad(&grads).unwrap()), copies));
    }
    set_neighbour_search(NeighbourSearch::Host);
    let (host, gpu) = (&results[0], &results[1]);
    assert!(host.0.0.iter().any(|&m| m), "the case gates some samples");
    assert_eq!(host.0, gpu.0, "the gate");
    assert_eq!(host.1, gpu.1, "the colours");
    assert_eq!(host.2, gpu.2, "the particle gradient");
    // each pass's kernel uploads three buffers and reads its slots back once on a GPU
    let extra = (gpu.3.uploads - host.3.uploads, gpu.3.reads - host.3.reads);
    if is_host(&device) {
        assert_eq!(extra, (0, 0), "a CPU backend searches on the host");
    } else {
        assert_eq!(extra, (6, 2), "the kernel ran for both passes");
    }
}
