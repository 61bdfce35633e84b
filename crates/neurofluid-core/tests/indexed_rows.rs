//! `rows::gather_rows` and `rows::add_rows` against sums written out on the host: values
//! and gradients, with more rows than 65,535 (Mesa's lavapipe stops a shader loop after 65,535
//! iterations, which once lost the gradient of every later row on wgpu) and with repeated
//! indices, spread evenly or skewed; a second run must give the same bits (the sums run in a fixed
//! order on every backend). Runs on the device `NEUROFLUID_TEST_DEVICE` names.

use burn::prelude::*;
use burn::tensor::TensorData;
use neurofluid_core::device::test_device;
use neurofluid_core::rows::{RowIndex, add_rows, gather_rows};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

const ROWS: usize = 70_000;
const N: usize = 50;
const C: usize = 3;

fn f32s(t: Tensor<2>) -> Vec<f32> {
    t.into_data()
        .convert::<f32>()
        .try_to_vec::<f32>()
        .expect("f32")
}

fn random(len: usize, rng: &mut ChaCha8Rng) -> Vec<f32> {
    (0..len).map(|_| rng.random_range(-1.0f32..1.0)).collect()
}

/// Row indices into `N` rows: 70,000 spread evenly (about 1,400 per row), and a skewed set
/// (rows with 0, 1, 2, 3, 5 and 9,000 indices, shuffled).
fn index_sets(rng: &mut ChaCha8Rng) -> Vec<(&'static str, Vec<i32>)> {
    let even = (0..ROWS).map(|_| rng.random_range(0..N as i32)).collect();
    let mut skewed: Vec<i32> = [(1, 1), (2, 2), (3, 3), (4, 5), (7, 9_000)]
        .into_iter()
        .flat_map(|(row, count)| std::iter::repeat_n(row, count))
        .collect();
    for i in (1..skewed.len()).rev() {
        skewed.swap(i, rng.random_range(0..=i));
    }
    vec![("even", even), ("skewed", skewed)]
}

/// `Σ_r coeff[r] at row idx[r]`, summed in f64.
fn rows_summed(idx: &[i32], coeff: &[f32]) -> Vec<f64> {
    let mut s = vec![0.0f64; N * C];
    for (r, &i) in idx.iter().enumerate() {
        for c in 0..C {
            s[i as usize * C + c] += f64::from(coeff[r * C + c]);
        }
    }
    s
}

fn assert_close(what: &str, got: &[f32], want: &[f64]) {
    assert_eq!(got.len(), want.len(), "{what}: length");
    for (j, (&g, &w)) in got.iter().zip(want).enumerate() {
        assert!(
            (f64::from(g) - w).abs() <= 1e-4 * (1.0 + w.abs()),
            "{what}[{j}]: {g} vs {w}"
        );
    }
}

/// The gathered rows and the table's gradient under `Σ coeff ⊙ rows`.
fn gather_and_gradient(idx: &[i32], table: &[f32], coeff: &[f32]) -> (Vec<f32>, Vec<f32>) {
    let device = test_device().autodiff();
    let t = Tensor::<2>::from_data(TensorData::new(table.to_vec(), [N, C]), &device).require_grad();
    let ids = RowIndex::new(idx.iter().map(|&i| i as usize), &device);
    let g = gather_rows(t.clone(), &ids);
    let k = Tensor::<2>::from_data(TensorData::new(coeff.to_vec(), [idx.len(), C]), &device);
    let grads = (g.clone() * k).sum().backward();
    let grad = f32s(t.grad(&grads).expect("gradient of the table"));
    (f32s(g), grad)
}

/// The sums `base + Σ values` and the values' gradient under `Σ k ⊙ sums`.
fn add_and_gradient(idx: &[i32], base: &[f32], values: &[f32], k: &[f32]) -> (Vec<f32>, Vec<f32>) {
    let device = test_device().autodiff();
    let b = Tensor::<2>::from_data(TensorData::new(base.to_vec(), [N, C]), &device);
    let v = Tensor::<2>::from_data(TensorData::new(values.to_vec(), [idx.len(), C]), &device)
        .require_grad();
    let ids = RowIndex::new(idx.iter().map(|&i| i as usize), &device);
    let out = add_rows(b, &ids, v.clone());
    let kt = Tensor::<2>::from_data(TensorData::new(k.to_vec(), [N, C]), &device);
    let grads = (out.clone() * kt).sum().backward();
    let grad = f32s(v.grad(&grads).expect("gradient of the values"));
    (f32s(out), grad)
}

/// Rows `idx` of a `[N, C]` table, in f64.
fn rows_of(idx: &[i32], table: &[f32]) -> Vec<f64> {
    idx.iter()
        .flat_map(|&i| (0..C).map(move |c| i as usize * C + c))
        .map(|j| f64::from(table[j]))
        .collect()
}

#[test]
fn gathered_rows_and_their_gradient() {
    let mut rng = ChaCha8Rng::seed_from_u64(11);
    for (name, idx) in index_sets(&mut rng) {
        let table = random(N * C, &mut rng);
        let coeff = random(idx.len() * C, &mut rng);
        let (g, grad) = gather_and_gradient(&idx, &table, &coeff);
        assert_close(
            &format!("{name}: gathered rows"),
            &g,
            &rows_of(&idx, &table),
        );
        assert_close(
            &format!("{name}: gradient"),
            &grad,
            &rows_summed(&idx, &coeff),
        );
        // the sums run in a fixed order: the same bits again (atomic adds would not promise it)
        let again = gather_and_gradient(&idx, &table, &coeff);
        assert!(again == (g, grad), "{name}: a second run gave other bits");
    }
}

#[test]
fn added_rows_and_their_gradient() {
    let mut rng = ChaCha8Rng::seed_from_u64(12);
    for (name, idx) in index_sets(&mut rng) {
        let base = random(N * C, &mut rng);
        let values = random(idx.len() * C, &mut rng);
        let k = random(N * C, &mut rng);
        let (out, grad) = add_and_gradient(&idx, &base, &values, &k);
        let mut want = rows_summed(&idx, &values);
        for (w, &b) in want.iter_mut().zip(&base) {
            *w += f64::from(b);
        }
        assert_close(&format!("{name}: added rows"), &out, &want);
        // d Σ k⊙out / d values[r] = k[idx[r]]
        assert_close(&format!("{name}: gradient"), &grad, &rows_of(&idx, &k));
        let again = add_and_gradient(&idx, &base, &values, &k);
        assert!(again == (out, grad), "{name}: a second run gave other bits");
    }
}

#[test]
fn an_index_uploads_its_plan_once_and_sums_alike_every_time() {
    use neurofluid_core::transfer::counts;
    let mut rng = ChaCha8Rng::seed_from_u64(13);
    let device = test_device();
    let (_, idx) = index_sets(&mut rng).remove(1);
    let ids = RowIndex::new(idx.iter().map(|&i| i as usize), &device);
    let base = Tensor::<2>::zeros([N, C], &device);
    let sums: Vec<Vec<f32>> = (0..3)
        .map(|_| {
            let values = random(idx.len() * C, &mut ChaCha8Rng::seed_from_u64(14));
            let v = Tensor::<2>::from_data(TensorData::new(values, [idx.len(), C]), &device);
            let before = counts();
            let out = add_rows(base.clone(), &ids, v);
            let uploads = counts().since(before).uploads;
            (uploads, f32s(out))
        })
        .enumerate()
        .map(|(i, (uploads, out))| {
            // the first sum may plan and upload (off the CPU backend); later ones reuse it
            if i > 0 {
                assert_eq!(uploads, 0, "sum {i} uploaded its plan again");
            }
            out
        })
        .collect();
    let values = random(idx.len() * C, &mut ChaCha8Rng::seed_from_u64(14));
    assert_close("sums", &sums[0], &rows_summed(&idx, &values));
    assert!(
        sums[1] == sums[0] && sums[2] == sums[0],
        "the same sums, bit for bit"
    );
}
