//! `gravity` sets the truth's fall: a clump in free flight drops ½ g t² (a physical invariant,
//! not the solver's own numbers), at the world's gravity and at others; the manifest records a
//! gravity only where it is not the world's.

use neurofluid_scenegen::simulate;
use neurofluid_scenegen::sph::SolverParams;
use neurofluid_scenegen::{Preset, SceneConfig};

use crate::common::tiny;

/// The mean height's drop from frame 0 to frame `t`.
fn drop_at(p: &Preset, t: usize) -> f64 {
    let sim = simulate(p, t + 1, false);
    let mean_y = |k: usize| {
        let f = &sim.frames[k].pos;
        f.iter().map(|x| f64::from(x[1])).sum::<f64>() / f.len() as f64
    };
    mean_y(0) - mean_y(t)
}

#[test]
fn a_clump_in_free_flight_falls_at_the_set_gravity() {
    // the sphere's lowest particle is 0.2 m above the floor: 4 frames at 50 fps (0.08 s) leave
    // it in the air at every gravity below (at 20 m/s², 0.064 m)
    let frames = 4;
    let t = frames as f64 / 50.0;
    for g in [None, Some(4.9), Some(19.6)] {
        let p = tiny(0, frames, |c: &mut SceneConfig| c.gravity = g);
        // ½ g t², as the solver's semi-implicit Euler integrates it at its substep h (velocity
        // first): ½ g t (t + h)
        let h = SolverParams::default().max_dt;
        let expected = 0.5 * g.unwrap_or(9.81) * t * (t + h);
        let dropped = drop_at(&p, frames);
        assert!(
            (dropped - expected).abs() < 0.01 * expected,
            "gravity {g:?}: the clump dropped {dropped:.5} m in {t} s, free fall {expected:.5} m"
        );
    }
}

#[test]
fn the_manifest_records_gravity_only_where_it_is_not_the_worlds() {
    let world = serde_json::to_value(tiny(0, 2, |_| {})).unwrap();
    assert!(world.get("gravity").is_none(), "{world}");
    let heavy = tiny(0, 2, |c: &mut SceneConfig| c.gravity = Some(19.6));
    let heavy_json = serde_json::to_value(&heavy).unwrap();
    assert_eq!(heavy_json["gravity"], 19.6);
    // a scene made at the world's gravity is not the heavy one, either way round
    assert_eq!(heavy.changes_from(&world), vec!["gravity".to_string()]);
    assert_eq!(
        tiny(0, 2, |_| {}).changes_from(&heavy_json),
        vec!["gravity".to_string()]
    );
}

#[test]
fn a_gravity_out_of_range_is_refused() {
    let text = "[scene]\nname = \"watercube\"\ngravity = -3.0\n";
    let err = SceneConfig::from_toml_str(text, std::path::Path::new("x.toml")).unwrap_err();
    assert!(err.to_string().contains("gravity"), "{err}");
}
