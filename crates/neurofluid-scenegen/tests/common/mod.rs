//! What the generator's tests share: scratch folders, a tiny preset, a folder's files.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use neurofluid_scenegen::shapes::Shape;
use neurofluid_scenegen::{Preset, Scale, SceneConfig, SceneKind};

/// A fresh scratch folder named after the test file (`group`), the case and the process.
pub fn tmp(group: &str, name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("nf_{group}_{name}_{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    d
}

/// A small box, a small sphere, 24-pixel images, `train_frames` and 2 test frames: fast enough
/// for CI (the sizes of the generator tests of the workspace's `tests` crate); `set` adjusts the
/// config before it is resolved.
pub fn tiny(seed: u64, train_frames: usize, set: impl FnOnce(&mut SceneConfig)) -> Preset {
    let mut cfg = SceneConfig::new(SceneKind::WaterSphere, Scale::Quick);
    cfg.seed = seed;
    cfg.image_size = Some(24);
    cfg.samples_per_axis = Some(1);
    cfg.train_frames = Some(train_frames);
    cfg.test_frames = Some(2);
    set(&mut cfg);
    let mut p = Preset::resolve(&cfg);
    p.box_lo = [-0.4, -0.4, -0.4];
    p.box_hi = [0.4, 0.6, 0.4];
    p.shape = Shape::Sphere {
        center: [0.0, 0.0, 0.0],
        radius: 0.2,
    };
    p
}

/// Every file under `root`, relative to it, with its bytes.
pub fn contents(root: &Path) -> BTreeMap<PathBuf, Vec<u8>> {
    let mut out = BTreeMap::new();
    let mut stack = vec![root.to_path_buf()];
    while let Some(d) = stack.pop() {
        for e in std::fs::read_dir(&d).unwrap() {
            let p = e.unwrap().path();
            if p.is_dir() {
                stack.push(p);
            } else {
                let bytes = std::fs::read(&p).unwrap();
                out.insert(p.strip_prefix(root).unwrap().to_path_buf(), bytes);
            }
        }
    }
    out
}
