//! Keys of the previous release, still read for one release: each is moved to its new place
//! (with its value converted where the type changed) and reported, so old experiment files and
//! `--set` lines keep working while they are updated.

use crate::optim::{JointDlfGroup, JointPhysNerfGroup, OptimDefaults, WarmupGroup};

/// One renamed key.
struct Rename {
    old: &'static str,
    new: &'static str,
    /// Converts the old value (`None`: unchanged).
    convert: Option<fn(toml::Value) -> toml::Value>,
    /// The schedule table the new key lives in, filled with its group's default first.
    schedule: Option<fn() -> toml::Value>,
}

const fn plain(old: &'static str, new: &'static str) -> Rename {
    Rename {
        old,
        new,
        convert: None,
        schedule: None,
    }
}

const fn in_schedule(
    old: &'static str,
    new: &'static str,
    schedule: fn() -> toml::Value,
) -> Rename {
    Rename {
        old,
        new,
        convert: None,
        schedule: Some(schedule),
    }
}

fn schedule_of<G: OptimDefaults>() -> toml::Value {
    toml::Value::try_from(G::schedule()).expect("a schedule serialises to TOML")
}

fn geometry_from_bool(v: toml::Value) -> toml::Value {
    match v {
        toml::Value::Boolean(true) => "differentiable".into(),
        toml::Value::Boolean(false) => "constant".into(),
        other => other,
    }
}

/// Specific keys first; the whole `[renderer]` table last.
const RENAMES: &[Rename] = &[
    plain("renderer.near", "scene.near"),
    plain("renderer.far", "scene.far"),
    plain("renderer.radius", "physnerf.search_radius"),
    plain("renderer.jitter", "physnerf.stratified"),
    plain("renderer", "physnerf"),
    Rename {
        old: "dlf.geometry_grad",
        new: "dlf.geometry",
        convert: Some(geometry_from_bool),
        schedule: None,
    },
    plain("dlf.bptt_steps", "joint.bptt_steps"),
    plain("warmup.lr", "warmup.optim.lr"),
    in_schedule(
        "warmup.decay_steps",
        "warmup.optim.schedule.decay_steps",
        schedule_of::<WarmupGroup>,
    ),
    plain("warmup.eval_every", "warmup.preview_every"),
    plain("joint.lr_renderer", "joint.physnerf_optim.lr"),
    plain("joint.lr_transition", "joint.dlf_optim.lr"),
    in_schedule(
        "joint.renderer_milestones",
        "joint.physnerf_optim.schedule.milestones",
        schedule_of::<JointPhysNerfGroup>,
    ),
    in_schedule(
        "joint.renderer_gamma",
        "joint.physnerf_optim.schedule.gamma",
        schedule_of::<JointPhysNerfGroup>,
    ),
    in_schedule(
        "joint.transition_milestones",
        "joint.dlf_optim.schedule.milestones",
        schedule_of::<JointDlfGroup>,
    ),
    in_schedule(
        "joint.transition_gamma",
        "joint.dlf_optim.schedule.gamma",
        schedule_of::<JointDlfGroup>,
    ),
    plain("joint.eval_every", "joint.preview_every"),
    plain("joint.anchor_weight", "joint.terms.anchor.weight"),
    plain("joint.energy_weight", "joint.terms.energy.weight"),
    plain("joint.truth_weight", "joint.terms.truth.weight"),
    plain("eval.render_truth", "diagnostics.render_truth"),
    plain("eval.render_dlf", "diagnostics.render_dlf"),
    plain(
        "eval.weight_interpolation",
        "diagnostics.weight_interpolation",
    ),
    plain(
        "eval.interpolation_sweep",
        "diagnostics.interpolation_sweep",
    ),
];

/// What to tell a user whose file sets `key`, when it is a retired option.
pub(crate) fn retired_note(key: &str) -> Option<&'static str> {
    super::settings::RETIRED_KEYS
        .iter()
        .any(|(retired, _)| *retired == key)
        .then_some(
            "an option retired on 2026-12-05 after failing its screen \
         (docs/notebook/2026-12-05-retired-options.md); commit 96ee8cc still has it",
        )
}

fn take(table: &mut toml::Table, path: &[&str]) -> Option<toml::Value> {
    let (last, parents) = path.split_last()?;
    let mut cur = table;
    for p in parents {
        cur = cur.get_mut(*p)?.as_table_mut()?;
    }
    cur.remove(*last)
}

fn table_at<'a>(table: &'a mut toml::Table, path: &[&str]) -> Option<&'a mut toml::Table> {
    let mut cur = table;
    for p in path {
        cur = cur
            .entry(p.to_string())
            .or_insert_with(|| toml::Value::Table(toml::Table::new()))
            .as_table_mut()?;
    }
    Some(cur)
}

/// Merges `new` into `into`, key by key, down through nested tables (`new` wins).
fn merge(into: &mut toml::Table, new: toml::Table) {
    for (k, v) in new {
        match (into.get_mut(&k), v) {
            (Some(toml::Value::Table(existing)), toml::Value::Table(v)) => merge(existing, v),
            (_, v) => {
                into.insert(k, v);
            }
        }
    }
}

/// Puts `value` at `path`; a table merges into a table already there (its keys win).
fn put(table: &mut toml::Table, path: &[&str], value: toml::Value) {
    let Some((last, parents)) = path.split_last() else {
        return;
    };
    let Some(parent) = table_at(table, parents) else {
        return;
    };
    let mut one = toml::Table::new();
    one.insert(last.to_string(), value);
    merge(parent, one);
}

/// Moves every key of the previous release in `table` to its new place; returns
/// `(old, new)` for each one moved.
pub(crate) fn migrate(table: &mut toml::Table) -> Vec<(&'static str, &'static str)> {
    let mut moved = Vec::new();
    for r in RENAMES {
        let old: Vec<&str> = r.old.split('.').collect();
        let Some(mut value) = take(table, &old) else {
            continue;
        };
        if let Some(convert) = r.convert {
            value = convert(value);
        }
        let new: Vec<&str> = r.new.split('.').collect();
        if let Some(schedule) = r.schedule {
            let parent = &new[..new.len() - 1];
            if table_at(table, parent).is_some_and(|t| t.is_empty()) {
                put(table, parent, schedule());
            }
        }
        put(table, &new, value);
        moved.push((r.old, r.new));
    }
    moved
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn old_keys_move_to_their_new_places() {
        let mut t: toml::Table = toml::from_str(
            "[renderer]\nwidth = 128\nradius = 0.2\nnear = 8.0\n[renderer.encoding]\npc = false\n\
             [dlf]\ngeometry_grad = true\nbptt_steps = 4\n\
             [joint]\nlr_transition = 1e-4\ntransition_gamma = 0.25\neval_every = 7\n",
        )
        .unwrap();
        let moved = migrate(&mut t);
        assert_eq!(moved.len(), 8, "{moved:?}");
        let p = t["physnerf"].as_table().unwrap();
        assert_eq!(p["width"].as_integer(), Some(128));
        assert_eq!(p["search_radius"].as_float(), Some(0.2));
        assert_eq!(p["encoding"]["pc"].as_bool(), Some(false));
        assert!(!t.contains_key("renderer"));
        assert_eq!(t["scene"]["near"].as_float(), Some(8.0));
        assert_eq!(t["dlf"]["geometry"].as_str(), Some("differentiable"));
        assert_eq!(t["joint"]["bptt_steps"].as_integer(), Some(4));
        assert_eq!(t["joint"]["dlf_optim"]["lr"].as_float(), Some(1e-4));
        let s = t["joint"]["dlf_optim"]["schedule"].as_table().unwrap();
        // the rest of the group's schedule is its default
        assert_eq!(s["kind"].as_str(), Some("multi_step"));
        assert_eq!(s["gamma"].as_float(), Some(0.25));
        assert_eq!(s["milestones"].as_array().unwrap().len(), 5);
        assert_eq!(t["joint"]["preview_every"].as_integer(), Some(7));
    }

    /// A retired option is refused with the key, the note and the commit that has it named.
    #[test]
    fn a_retired_option_says_where_it_went() {
        let text = "name = \"t\"\n[scene]\nbuiltin = \"watercube\"\n[joint]\nanchor_horizon = 3\n";
        let err = crate::config::Experiment::from_toml_str(text, std::path::Path::new("x.toml"))
            .unwrap_err();
        assert_eq!(err.key(), "joint.anchor_horizon");
        let message = err.to_string();
        assert!(
            message.contains("retired")
                && message.contains("96ee8cc")
                && message.contains("x.toml"),
            "{message}"
        );
        assert_eq!(
            retired_note("joint.anchor_weight"),
            None,
            "moved, not retired"
        );
    }
}
