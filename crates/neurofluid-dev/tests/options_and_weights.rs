//! The configuration switches (gated-only evaluation, stratified jitter, ablations, nearest-K)
//! and the weight files (save/load round trip, clear errors for bad files).

use crate::common;

use burn::prelude::*;
use burn::tensor::DType;
use common::*;
use neurofluid_physnerf::safetensors_file::{StFile, StWriter};
use neurofluid_physnerf::{
    EncodingTerms, NeighborSelection, PhysNerf, PhysNerfConfig, Positions, RayBatch,
};
use rand::SeedableRng;

/// The case's renderer under `config`, with the case's reference weights.
fn case_model(
    inputs: &neurofluid_dev::physnerf_case::CaseInputs,
    config: PhysNerfConfig,
    device: &burn::tensor::Device,
) -> PhysNerf {
    PhysNerf::from_nerf_pl(inputs.weights_path(), config, device, DType::F32).unwrap()
}

/// The error of loading the weights file `path` under `config`.
fn load_error(
    path: &std::path::Path,
    config: PhysNerfConfig,
    device: &burn::tensor::Device,
) -> String {
    PhysNerf::from_nerf_pl(path, config, device, DType::F32)
        .unwrap_err()
        .to_string()
}

/// The 6×6 centre block of the case's rays.
fn centre_rays(inputs: &neurofluid_dev::physnerf_case::CaseInputs) -> RayBatch {
    let all = inputs.rays::<f32>();
    let ids: Vec<usize> = (5..11)
        .flat_map(|r| (5..11).map(move |c| r * 16 + c))
        .collect();
    RayBatch {
        origins: ids.iter().map(|&i| all.origins[i]).collect(),
        dirs: ids.iter().map(|&i| all.dirs[i]).collect(),
    }
}

#[test]
fn gated_only_evaluation_gives_the_same_colours_and_gradients() {
    let (inputs, _) = case();
    let device = neurofluid_core::device::test_device().autodiff();
    let rays = centre_rays(&inputs);
    let target = Tensor::<2>::full([rays.len(), 3], 0.3, &device);
    let mut results = Vec::new();
    for gated_only in [true, false] {
        let cfg = PhysNerfConfig {
            gated_only,
            ..inputs.config.clone()
        };
        let model = case_model(&inputs, cfg, &device);
        let p = inputs.particles_tensor(&device, DType::F32).require_grad();
        let out = model.render_rays(&p, &rays, None).unwrap();
        let evaluated = out.coarse.evaluated;
        let rgb = vals(out.final_rgb());
        let grads = model.loss(&out, target.clone()).total.backward();
        results.push((rgb, vals(p.grad(&grads).unwrap()), evaluated));
    }
    let (a, b) = (&results[0], &results[1]);
    assert!(
        a.2 < b.2,
        "gated-only must evaluate fewer samples ({} vs {})",
        a.2,
        b.2
    );
    assert_close("fine rgb, gated-only vs all", &a.0, &b.0, 1e-6);
    let rn = rel_norm(&a.1, &b.1);
    assert!(rn < 1e-5, "particle gradients differ: {rn}");
}

#[test]
fn stratified_jitter_needs_an_rng_and_stays_in_its_intervals() {
    let (inputs, _) = case();
    let device = neurofluid_core::device::test_device();
    let rays = centre_rays(&inputs);
    let cfg = PhysNerfConfig {
        stratified: true,
        ..inputs.config.clone()
    };
    let model = case_model(&inputs, cfg.clone(), &device);
    let p = inputs.particles_tensor(&device, DType::F32);
    assert!(
        model.render_rays(&p, &rays, None).is_err(),
        "stratified without an RNG must be an error"
    );
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(5);
    let out = model.render_rays(&p, &rays, Some(&mut rng)).unwrap();
    let z = &out.coarse.z;
    let det = neurofluid_physnerf::sampling::coarse_depths::<f64>(cfg.near, cfg.far, 64);
    let step = (cfg.far - cfg.near) / 63.0;
    let mut moved = 0;
    for ray in z.chunks(64) {
        for (k, (&zj, &zd)) in ray.iter().zip(&det).enumerate() {
            assert!(
                (zj - zd).abs() <= 0.5 * step + 1e-6,
                "sample {k} left its interval"
            );
            moved += usize::from((zj - zd).abs() > 1e-6);
        }
        assert!(
            ray.windows(2).all(|w| w[0] <= w[1]),
            "jittered depths must stay sorted"
        );
    }
    assert!(moved > z.len() / 2, "jitter moved only {moved} depths");
    let fine = out.fine.as_ref().unwrap();
    assert!(
        fine.z
            .chunks(192)
            .all(|r| r.windows(2).all(|w| w[0] <= w[1]))
    );
    // the same seed gives the same picture
    let mut rng2 = rand_chacha::ChaCha8Rng::seed_from_u64(5);
    let again = model.render_rays(&p, &rays, Some(&mut rng2)).unwrap();
    assert_eq!(vals(out.final_rgb()), vals(again.final_rgb()));
}

#[test]
fn ablations_change_the_input_widths_and_nearest_k_changes_the_picture() {
    let (inputs, _) = case();
    let device = neurofluid_core::device::test_device();
    let rays = centre_rays(&inputs);
    let p = inputs.particles_tensor(&device, DType::F32);
    for flags in [
        EncodingTerms::none(),
        EncodingTerms {
            pc: false,
            ..EncodingTerms::all()
        },
        EncodingTerms {
            dc: false,
            ..EncodingTerms::all()
        },
    ] {
        let cfg = PhysNerfConfig {
            encoding: flags,
            width: 32,
            ..inputs.config.clone()
        };
        let model = PhysNerf::new(cfg.clone(), &device).unwrap();
        assert_eq!(
            model.coarse.xyz_encoding[0].weight.dims(),
            [cfg.in_xyz(), 32]
        );
        assert_eq!(
            model.coarse.xyz_encoding[4].weight.dims(),
            [cfg.in_xyz() + 32, 32]
        );
        assert_eq!(
            model.fine.dir_encoding.weight.dims(),
            [32 + cfg.in_dir(), 16]
        );
        let out = model.render_rays(&p, &rays, None).unwrap();
        assert_eq!(out.final_rgb().dims(), [rays.len(), 3]);
        // the case's full-width weights do not fit an ablated network: a clear error
        let err = load_error(
            &inputs.weights_path(),
            PhysNerfConfig {
                encoding: flags,
                ..inputs.config.clone()
            },
            &device,
        );
        assert!(
            err.contains("nerf_coarse.") && err.contains("expected shape"),
            "{err}"
        );
    }
    let lowest = case_model(&inputs, inputs.config.clone(), &device);
    let nearest_cfg = PhysNerfConfig {
        selection: NeighborSelection::Nearest,
        ..inputs.config.clone()
    };
    let nearest = case_model(&inputs, nearest_cfg, &device);
    let a = lowest.render_rays(&p, &rays, None).unwrap();
    let b = nearest.render_rays(&p, &rays, None).unwrap();
    assert_eq!(
        a.coarse.num_nn, b.coarse.num_nn,
        "same counts, different members"
    );
    assert_ne!(a.coarse.nbr_idx_sum, b.coarse.nbr_idx_sum);
    assert!(max_abs(&vals(a.coarse.rgb_map), &vals(b.coarse.rgb_map)) > 1e-2);
}

/// With relative positions the picture is the same when the particles and the cameras move
/// together (a translation invariance the world encoding does not have: the control).
#[test]
fn relative_positions_move_the_field_with_its_particles() {
    let (inputs, _) = case();
    let device = neurofluid_core::device::test_device();
    let rays = centre_rays(&inputs);
    let shift = [0.5f64, -0.25, 0.125];
    let moved_rays = RayBatch {
        origins: rays
            .origins
            .iter()
            .map(|o| [o[0] + shift[0], o[1] + shift[1], o[2] + shift[2]])
            .collect(),
        dirs: rays.dirs.clone(),
    };
    let p = inputs.particles_tensor(&device, DType::F32);
    let offset = Tensor::<1>::from_floats(shift.map(|s| s as f32), &device).reshape([1, 3]);
    let moved = p.clone() + offset;
    let mut change = Vec::new();
    for positions in [Positions::Relative, Positions::World] {
        // seeded, and a density that cannot start dead (a dead ReLU field renders white
        // whatever the particles, which no translation changes)
        let cfg = PhysNerfConfig {
            positions,
            width: 32,
            density: neurofluid_physnerf::DensityActivation::Softplus,
            ..inputs.config.clone()
        };
        let model = neurofluid_core::device::init_seeded(7, &device, |cpu| PhysNerf::new(cfg, cpu))
            .unwrap();
        let a = model.render_rays(&p, &rays, None).unwrap();
        let b = model.render_rays(&moved, &moved_rays, None).unwrap();
        assert!(a.coarse.evaluated > 0, "no sample reached the networks");
        assert_eq!(a.coarse.evaluated, b.coarse.evaluated);
        let picture = vals(a.final_rgb());
        let darkest = picture.iter().copied().fold(1.0, f64::min);
        assert!(darkest < 0.99, "the picture is empty: darkest {darkest}");
        change.push(max_abs(&picture, &vals(b.final_rgb())));
    }
    eprintln!("colour change, relative / world: {change:?}");
    assert!(change[0] < 1e-5, "relative: {change:?}");
    assert!(change[1] > 1e-4, "world (control): {change:?}");
}

#[test]
fn weights_roundtrip_and_bad_files_are_reported() {
    let (inputs, _) = case();
    let device = neurofluid_core::device::test_device();
    let dir = std::env::temp_dir().join(format!("nf_weights_{}", std::process::id()));
    let model = case_model(&inputs, inputs.config.clone(), &device);
    let path = dir.join("ours.safetensors");
    model.save(&path).unwrap();
    let back = PhysNerf::load(&path, &device, DType::F32).unwrap();
    assert_eq!(back.config, model.config);
    for (a, b) in model
        .coarse
        .named_layers()
        .iter()
        .zip(back.coarse.named_layers())
    {
        assert_eq!(vals(a.1.weight.val()), vals(b.1.weight.val()), "{}", a.0);
    }
    // torch layout on disk: [out, in]
    let f = StFile::open(&path).unwrap();
    assert_eq!(
        f.floats("nerf_fine.xyz_encoding_5.0.weight", None)
            .unwrap()
            .0,
        vec![256, 454]
    );
    // the reference weights have no config metadata: load() says what to do instead
    let err = PhysNerf::load(inputs.weights_path(), &device, DType::F32)
        .unwrap_err()
        .to_string();
    assert!(
        err.contains("physnerf_config") && err.contains("from_nerf_pl"),
        "{err}"
    );

    // a file with one tensor missing, one extra
    let src = StFile::open(inputs.weights_path()).unwrap();
    let mut w = StWriter::new();
    for name in src.names() {
        if name == "nerf_fine.rgb.0.bias" {
            continue;
        }
        let (shape, v) = src.floats(&name, None).unwrap();
        w.float(&name, &shape, &v, false);
    }
    let missing = dir.join("missing.safetensors");
    w.write(&missing).unwrap();
    let err = load_error(&missing, inputs.config.clone(), &device);
    assert!(
        err.contains("missing.safetensors")
            && err.contains("nerf_fine.rgb.0.bias")
            && err.contains("missing"),
        "{err}"
    );
    let mut w = StWriter::new();
    for name in src.names() {
        let (shape, v) = src.floats(&name, None).unwrap();
        w.float(&name, &shape, &v, false);
    }
    w.f32("nerf_coarse.extra.weight", &[1], &[0.0]);
    let extra = dir.join("extra.safetensors");
    w.write(&extra).unwrap();
    let err = load_error(&extra, inputs.config.clone(), &device);
    assert!(err.contains("nerf_coarse.extra.weight"), "{err}");
    std::fs::remove_dir_all(dir).ok();
}

#[test]
fn a_render_given_the_particles_on_the_host_reads_one_less_and_gives_the_same_bits() {
    use neurofluid_core::transfer::counts;
    let (inputs, _) = case();
    let device = neurofluid_core::device::test_device().autodiff();
    let rays = centre_rays(&inputs);
    let target = Tensor::<2>::full([rays.len(), 3], 0.3, &device);
    let model = case_model(&inputs, inputs.config.clone(), &device);
    let host: Vec<[f32; 3]> = inputs
        .particles
        .iter()
        .map(|p| p.map(|c| c as f32))
        .collect();
    let mut results = Vec::new();
    for given in [false, true] {
        let p = inputs.particles_tensor(&device, DType::F32).require_grad();
        let before = counts();
        let out = if given {
            model.render_rays_with_host(&p, &host, &rays, None).unwrap()
        } else {
            model.render_rays(&p, &rays, None).unwrap()
        };
        let reads = counts().since(before).reads;
        let rgb = vals(out.final_rgb());
        let grads = model.loss(&out, target.clone()).total.backward();
        results.push((rgb, vals(p.grad(&grads).unwrap()), reads));
    }
    let (read, given) = (&results[0], &results[1]);
    assert_eq!(given.0, read.0, "colours");
    assert_eq!(given.1, read.1, "particle gradients");
    assert_eq!(given.2 + 1, read.2, "the particles are not read back");
    // the host copy must be the tensor's: another length is refused
    let p = inputs.particles_tensor(&device, DType::F32);
    assert!(
        model
            .render_rays_with_host(&p, &host[1..], &rays, None)
            .is_err()
    );
}
