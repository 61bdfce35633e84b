//! Backward parity with the Open3D reference: DLF's 2-step training loss on the cube-drop input
//! (targets = the input positions) and every parameter gradient
//! (`cubedrop2197_dlfwall_grad_open3d.npz`), 1e-4 relative.

use crate::common;

use burn::prelude::*;
use common::*;
use neurofluid_core::npz::NpzReader;
use neurofluid_dlf::{dlf_step_loss, two_step_loss};

#[test]
fn two_step_loss_and_gradients_match_open3d() {
    let device = device().autodiff();
    let net = pretrained(&device);
    let scene = Scene::load("cubedrop2197_dlfwall");
    let boundary = scene.boundary(&net, &device);
    let mut reference = NpzReader::open(case("cubedrop2197_dlfwall_grad_open3d.npz")).unwrap();

    let pos = to_tensor(&scene.pos, &device);
    let vel = to_tensor(&scene.vel, &device);
    let target = pos.clone();
    let s1 = net.step(pos, vel, &boundary);
    let l1 = dlf_step_loss(s1.pos.clone(), target.clone(), &s1.num_fluid_neighbors);
    let s2 = net.step(s1.pos, s1.vel, &boundary);
    let l2 = dlf_step_loss(s2.pos.clone(), target, &s2.num_fluid_neighbors);
    let loss = two_step_loss(l1.clone(), l2.clone());

    let scalar = |t: &Tensor<1>| t.clone().into_scalar::<f32>() as f64;
    for (key, value) in [
        ("loss", scalar(&loss)),
        ("loss_step1", scalar(&l1)),
        ("loss_step2", scalar(&l2)),
    ] {
        let r = reference.f32(key).unwrap().data[0] as f64;
        let e = (value - r).abs() / r.abs();
        eprintln!("{key}: ours {value:.7} reference {r:.7} relative {e:.2e}");
        assert!(e <= 1e-5, "{key}: {value} vs {r}");
    }
    let e = rel_err(&host(&s2.pos), &reference.f32("pos2").unwrap().data);
    assert!(e <= 1e-5, "pos2 relative error {e:.3e}");

    let grads = loss.backward();
    let mut params: Vec<(String, Tensor<2>, Vec<usize>)> = Vec::new();
    let mut push_conv = |name: &str, c: &neurofluid_dlf::ContinuousConv| {
        let k = c.kernel.val();
        let dims = k.dims().to_vec();
        let n: usize = dims.iter().product();
        let g = k.grad(&grads).expect("kernel grad").reshape([1, n]);
        params.push((format!("{name}.kernel"), g, dims));
        let b = c.bias.val();
        let g = b.grad(&grads).expect("bias grad").unsqueeze_dim::<2>(0);
        params.push((format!("{name}.bias"), g, b.dims().to_vec()));
    };
    push_conv("conv0_fluid", &net.conv0_fluid);
    push_conv("conv0_obstacle", &net.conv0_obstacle);
    push_conv("conv1", &net.conv1);
    push_conv("conv2", &net.conv2);
    push_conv("conv3", &net.conv3);
    for (name, lin) in [
        ("dense0_fluid", &net.dense0_fluid),
        ("dense1", &net.dense1),
        ("dense2", &net.dense2),
        ("dense3", &net.dense3),
    ] {
        let w = lin.weight.val();
        // Burn stores [in, out]; torch's gradient is [out, in].
        let g = w.grad(&grads).expect("weight grad").transpose();
        let dims = g.dims().to_vec();
        params.push((format!("{name}.weight"), g, dims));
        let b = lin.bias.as_ref().unwrap().val();
        let g = b.grad(&grads).expect("bias grad").unsqueeze_dim::<2>(0);
        params.push((format!("{name}.bias"), g, b.dims().to_vec()));
    }
    assert_eq!(params.len(), 18);
    for (name, g, _dims) in params {
        let ours = host(&g);
        let norm = ours
            .iter()
            .map(|&x| (x as f64) * (x as f64))
            .sum::<f64>()
            .sqrt();
        let rnorm = reference.f32(&format!("gradnorm/{name}")).unwrap().data[0] as f64;
        let en = (norm - rnorm).abs() / rnorm.max(1e-30);
        let (key, head) = if reference.contains(&format!("grad/{name}")) {
            (format!("grad/{name}"), ours.len())
        } else {
            (format!("gradhead/{name}"), 4096)
        };
        let r = reference.f32(&key).unwrap().data;
        assert_eq!(r.len(), head, "{key}");
        let e = rel_err(&ours[..head], &r);
        eprintln!("{name}: |grad| relative {en:.2e}, entries relative {e:.2e}");
        if rnorm == 0.0 {
            // conv0_obstacle: the falling cube never comes near a wall in these two steps.
            assert!(
                ours.iter().all(|&x| x == 0.0),
                "{name}: expected a zero gradient"
            );
            continue;
        }
        assert!(en <= 1e-4, "{name}: gradient norm {norm} vs {rnorm}");
        assert!(e <= 1e-4, "{key}: relative error {e:.3e}");
    }
}
