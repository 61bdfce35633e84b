//! Forward parity with the Open3D reference: `cubedrop2197_dlfwall`, 5 steps of the pretrained
//! model (tests/data/dlf/README.md). Tolerance 1e-5 relative, neighbour counts exact.

use crate::common;

use common::*;
use neurofluid_core::npz::NpzReader;
use neurofluid_dlf::rollout::rollout;

#[test]
fn five_step_forward_matches_open3d() {
    let device = device();
    let net = pretrained(&device);
    let scene = Scene::load("cubedrop2197_dlfwall");
    let boundary = scene.boundary(&net, &device);
    let mut reference = NpzReader::open(case("cubedrop2197_dlfwall_out_open3d.npz")).unwrap();
    let ref_pos = reference.f32("pos").unwrap();
    let ref_vel = reference.f32("vel").unwrap();
    let n = scene.pos.len();
    assert_eq!(ref_pos.shape, vec![6, n, 3]);

    // Step 0 internals.
    let p0 = common::to_tensor(&scene.pos, &device);
    let v0 = common::to_tensor(&scene.vel, &device);
    let (out, trace) = net.step_traced(p0, v0, &boundary);
    let counts = reference.i64("num_fluid_neighbors_step0").unwrap().data;
    let ours: Vec<i64> = out.num_fluid_neighbors.iter().map(|&c| c as i64).collect();
    assert_eq!(ours, counts, "neighbour counts differ");
    for (key, t) in [
        ("pos_pred_step0", &trace.pos_pred),
        ("vel_pred_step0", &trace.vel_pred),
        ("raw_output_step0", &trace.raw_output),
    ] {
        let e = rel_err(&host(t), &reference.f32(key).unwrap().data);
        eprintln!("{key}: relative error {e:.3e}");
        assert!(e <= 1e-5, "{key}: relative error {e:.3e}");
    }
    let rows = reference.i64("feature_rows").unwrap().data;
    for (key, t) in [
        ("conv0_obstacle_step0", &trace.features.conv0_obstacle),
        ("conv0_fluid_step0", &trace.features.conv0_fluid),
        ("dense0_fluid_step0", &trace.features.dense0_fluid),
        ("layer1_step0", &trace.features.layer1),
        ("layer2_step0", &trace.features.layer2),
    ] {
        let all = host(t);
        let width = all.len() / n;
        let picked: Vec<f32> = rows
            .iter()
            .flat_map(|&r| all[r as usize * width..(r as usize + 1) * width].to_vec())
            .collect();
        let e = rel_err(&picked, &reference.f32(key).unwrap().data);
        eprintln!("{key}: relative error {e:.3e}");
        assert!(e <= 1e-5, "{key}: relative error {e:.3e}");
    }

    // Five steps.
    let traj = rollout(&net, &scene.pos, &scene.vel, &boundary, 5, |_| {});
    let stride = n * 3;
    for step in 0..=5 {
        let rp = &ref_pos.data[step * stride..(step + 1) * stride];
        let rv = &ref_vel.data[step * stride..(step + 1) * stride];
        let ep = rel_err(&flat(&traj.pos[step]), rp);
        let ev = rel_err(&flat(&traj.vel[step]), rv);
        eprintln!("step {step}: pos {ep:.3e} vel {ev:.3e}");
        assert!(ep <= 1e-5, "step {step}: position relative error {ep:.3e}");
        // v = (x_new − x)/dt: one float32 ulp of a 0.6 m position (6e-8 m) is 3e-6 m/s, about
        // 1e-5 of |v|max = 0.33 m/s; Open3D rerun against itself differs by as much (README).
        assert!(ev <= 2e-5, "step {step}: velocity relative error {ev:.3e}");
    }
}
