//! Every scene-generation config in `experiments/scenes/` parses and resolves to its preset.

use std::path::Path;

use neurofluid_scenegen::generate::initial_particles;
use neurofluid_scenegen::{Preset, Scale, SceneConfig};

#[test]
fn experiment_scene_tables_parse() {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../experiments/scenes");
    let mut n = 0;
    for entry in std::fs::read_dir(&dir).unwrap() {
        let path = entry.unwrap().path();
        if path.extension().is_none_or(|e| e != "toml") {
            continue;
        }
        let cfg = SceneConfig::from_toml_file(&path).unwrap();
        let stem = path.file_stem().unwrap().to_string_lossy().into_owned();
        assert_eq!(
            stem,
            format!("{}_{}", cfg.name.name(), cfg.scale.name()),
            "{path:?}"
        );
        let p = Preset::resolve(&cfg);
        let (size, range) = match cfg.scale {
            Scale::Quick => (100, 1_500..4_000),
            Scale::Paper => (400, 6_000..15_000),
        };
        assert_eq!(p.image_size, size);
        let count = initial_particles(&p).len();
        assert!(range.contains(&count), "{path:?}: {count} particles");
        // the initial body lies inside the box, clear of the walls
        for x in initial_particles(&p) {
            for a in 0..3 {
                assert!(
                    x[a] > p.box_lo[a] + p.radius && x[a] < p.box_hi[a] - p.radius,
                    "{path:?}: {x}"
                );
            }
        }
        n += 1;
    }
    assert_eq!(n, 8, "expected the 4 scenes × 2 scales in {dir:?}");
}
