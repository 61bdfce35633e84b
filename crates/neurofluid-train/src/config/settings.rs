//! The settings that shape a stage's state, as flat `dotted.key = value` pairs with a digest.
//!
//! A checkpoint stores them; a run that resumes from it must have the same ones, or it would
//! continue a different experiment from the saved state. Settings that only decide what is
//! logged, when, and where (cadences, evaluation, the device, where a stage stops) never shape
//! the state and may change between sessions; they are recorded in the run folder instead.

use std::collections::BTreeMap;

use serde::{Deserialize, Serialize};

use super::{Experiment, InitialParticles, NerfTImages};
use crate::stage::Stage;

/// Whether `key` never shapes a training state: it is one of [`Experiment::free_keys`] or
/// under one.
fn is_free(key: &str) -> bool {
    static FREE: std::sync::LazyLock<Vec<String>> = std::sync::LazyLock::new(Experiment::free_keys);
    FREE.iter().any(|p| {
        key == p
            || key
                .strip_prefix(p.as_str())
                .is_some_and(|r| r.starts_with('.'))
    })
}

/// Whether `key` (a dotted setting, not a free one) shapes `stage`'s state in `exp`:
/// - a NeRF's (the baselines, the initial particles'): the seed, the scene, `[nerf]` (not
///   where it stops) and the keys its images come from: `warmup.views`, `warmup.held_out`;
///   for NeRF-T also `nerf.t_images` and, under `"neurofluid"`, the joint stage's views
///   (`joint.view`, `joint.extra_views`);
/// - every stage's: the seed and the scene, except the warm-up views the generator adds at every
///   training frame (`scene.generate.warmup_every_frame`), which only NeRF-T trains on;
/// - the warm-up's: the seed, the scene, PhysNeRF and the warm-up (not where it stops), and
///   with initial particles from images the initial particles' NeRF (where it stops too)
///   and `[initial]`;
/// - the joint stage's: everything the warm-up's state depends on, how long the warm-up
///   ran, DLF and the joint settings (not where it stops);
/// - the refit's: everything the joint stage's state depends on, where the joint stage stops
///   (the grounded DLF it fits to) and `[refit]`.
///
/// The other stages keep no state that settings shape.
fn shapes(stage: Stage, key: &str, exp: &Experiment) -> bool {
    let under = |prefix: &str| key == prefix || key.starts_with(&format!("{prefix}."));
    let every_frame_views = under("scene.generate.warmup_every_frame");
    let common = (under("seed") || under("scene") || under("matmul")) && !every_frame_views;
    let nerf_model = under("nerf") && !under("nerf.t_images");
    let nerf_t_images = under("nerf.t_images")
        || every_frame_views
        || (exp.nerf.t_images == NerfTImages::Neurofluid
            && (under("joint.view") || under("joint.extra_views")));
    let warmup_views = under("warmup.views") || under("warmup.held_out");
    let nerf = |kind_images: bool| {
        (common || nerf_model || warmup_views || kind_images) && !under("nerf.iters")
    };
    let from_images = exp.scene.initial == InitialParticles::FromImages
        && (nerf_model || under("initial") || warmup_views);
    // the searches' place (PhysNeRF's ball query, DLF's pairs: the renderer's stages and
    // those after them, not the NeRFs')
    let renderer = under("physnerf") || under("neighbour_search");
    let warmup = common || renderer || under("warmup") || from_images;
    match stage {
        Stage::Nerf | Stage::Initial => nerf(false),
        Stage::NerfT => nerf(nerf_t_images),
        Stage::Warmup => warmup && !under("warmup.iters"),
        Stage::Joint => (warmup || under("dlf") || under("joint")) && !under("joint.epochs"),
        Stage::Refit => warmup || under("dlf") || under("joint") || under("refit"),
        Stage::Eval | Stage::PretrainDlf => false,
    }
}

/// Keys added after a release, with the value that keeps the earlier behaviour: a checkpoint
/// that does not record such a key was made with that value, and a setting left unset now takes
/// it, so neither is a change.
const ADDED_KEYS: &[(&str, &str)] = &[
    ("physnerf.density", "\"relu\""),
    ("matmul", "\"f32\""),
    ("neighbour_search", "\"host\""),
    ("scene.initial", "\"true\""),
    ("joint.foreground_rays", "0.0"),
    ("joint.dlf_every", "1"),
    ("joint.extra_views", "[]"),
    ("dlf.containment", "\"none\""),
    ("nerf.model.density", "\"relu\""),
    ("refit.replay_rays", "0"),
    ("dlf.energy_cap", "\"none\""),
    ("dlf.gravity_scale", "1.0"),
    ("dlf.viscosity", "0.0"),
    ("dlf.dissipation", "0.0"),
    ("physnerf.positions", "\"world\""),
    ("nerf.t_images", "\"cycle\""),
    ("joint.physics.hold_dlf_epochs", "0"),
    ("joint.terms.truth.matching", "\"index\""),
    ("scene.generate.gravity", "9.81"),
    ("joint.input_noise", "0.0"),
    ("dlf.dissipation_frame", "\"box\""),
];

/// Keys retired since a release, with the value that kept the behaviour of today: a checkpoint
/// that records such a key at that value was made as a run of today is (the key is not a change);
/// at another value it was not, and resuming from it is refused with the key named; a file that
/// sets one is refused ([`super::legacy::retired_note`]). Each one's finding is in docs/notebook/
/// with the commit that had it.
pub(super) const RETIRED_KEYS: &[(&str, &str)] = &[
    ("joint.silhouette_weight", "0.0"),
    ("joint.silhouette_cover", "true"),
    ("joint.density_weight", "0.0"),
    ("joint.rest_density_weight", "0.0"),
    ("joint.anchor_along", "\"all\""),
    ("joint.anchor_horizon", "0"),
    ("joint.replay_rays", "0"),
    ("joint.replay_of", "\"images\""),
    ("joint.colour_head", "\"trained\""),
    ("joint.energy_per", "\"fluid\""),
    ("dlf.no_slip", "false"),
    ("dlf.free_flight", "\"network\""),
];

/// Keys moved since a release: a checkpoint's value under the old key is the new key's; at the
/// old key's "off" value (a weight of 0) the new key is absent.
const MOVED_KEYS: &[(&str, &str, &str)] = &[
    ("joint.anchor_weight", "joint.terms.anchor.weight", "0.0"),
    ("joint.energy_weight", "joint.terms.energy.weight", "0.0"),
    ("joint.truth_weight", "joint.terms.truth.weight", "0.0"),
];

/// Flat settings with a digest.
#[derive(Debug, Clone, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct Settings(pub BTreeMap<String, String>);

/// A setting that differs between two [`Settings`].
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Change {
    /// The dotted key.
    pub key: String,
    /// Its value before (`None`: not set).
    pub before: Option<String>,
    /// Its value now (`None`: not set).
    pub after: Option<String>,
}

impl std::fmt::Display for Change {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let show = |v: &Option<String>| v.clone().unwrap_or_else(|| "(unset)".into());
        write!(
            f,
            "{}: {} → {}",
            self.key,
            show(&self.before),
            show(&self.after)
        )
    }
}

fn flatten(prefix: &str, value: &toml::Value, out: &mut BTreeMap<String, String>) {
    match value {
        toml::Value::Table(t) => {
            for (k, v) in t {
                let key = if prefix.is_empty() {
                    k.clone()
                } else {
                    format!("{prefix}.{k}")
                };
                flatten(&key, v, out);
            }
        }
        other => {
            out.insert(prefix.to_string(), other.to_string());
        }
    }
}

impl Settings {
    /// The settings of anything that serialises to a TOML table (the flags of a command).
    pub fn of<T: Serialize>(value: &T) -> Self {
        let value = toml::Value::try_from(value).expect("settings serialise to TOML");
        let mut out = BTreeMap::new();
        flatten("", &value, &mut out);
        Self(out)
    }

    /// Every setting of the resolved experiment.
    pub fn all(exp: &Experiment) -> Self {
        Self::of(&exp.resolved())
    }

    /// The settings that shape `stage`'s state ([`shapes`]).
    pub fn of_stage(exp: &Experiment, stage: Stage) -> Self {
        let mut all = Self::all(exp);
        all.0.retain(|k, _| !is_free(k) && shapes(stage, k, exp));
        all
    }

    /// A 64-bit FNV-1a digest of the pairs, as 16 hex digits.
    pub fn digest(&self) -> String {
        let mut h: u64 = 0xCBF2_9CE4_8422_2325;
        for (k, v) in &self.0 {
            for b in k.bytes().chain([b'=']).chain(v.bytes()).chain([b'\n']) {
                h = (h ^ u64::from(b)).wrapping_mul(0x0100_0000_01B3);
            }
        }
        format!("{h:016x}")
    }

    /// These settings with the retired and moved keys of an earlier release brought to today's
    /// names ([`RETIRED_KEYS`], [`MOVED_KEYS`]).
    fn upgraded(&self) -> Settings {
        let mut out = self.0.clone();
        for (key, kept) in RETIRED_KEYS {
            if out.get(*key).is_some_and(|v| v == kept) {
                out.remove(*key);
            }
        }
        for (old, new, off) in MOVED_KEYS {
            if let Some(v) = out.remove(*old)
                && v != *off
            {
                out.insert(new.to_string(), v);
            }
        }
        Settings(out)
    }

    /// The value of `key`: an added key left unset holds the value that keeps the old behaviour
    /// ([`ADDED_KEYS`]).
    fn read(&self, key: &str) -> Option<&str> {
        self.0.get(key).map(String::as_str).or_else(|| {
            ADDED_KEYS
                .iter()
                .find_map(|(k, v)| (*k == key).then_some(*v))
        })
    }

    /// The keys whose values differ from `before`'s, in key order (`before` read with the keys
    /// of today, [`Settings::upgraded`]).
    pub fn changes_since(&self, before: &Settings) -> Vec<Change> {
        let before = &before.upgraded();
        let mut keys: Vec<&String> = self.0.keys().chain(before.0.keys()).collect();
        keys.sort();
        keys.dedup();
        keys.into_iter()
            .filter(|k| before.read(k) != self.read(k))
            .map(|k| Change {
                key: k.clone(),
                before: before.0.get(k).cloned(),
                after: self.0.get(k).cloned(),
            })
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::path::Path;

    /// The free keys the sections name are the hand list of the release before them, the
    /// validation views added to a built-in scene since, and the diagnostics.
    #[test]
    fn free_keys_come_from_the_sections() {
        let mut keys = Experiment::free_keys();
        keys.sort();
        let mut before = [
            "name",
            "device",
            "out_dir",
            "eval",
            "diagnostics",
            "physnerf.chunk",
            "warmup.log_every",
            "warmup.ckpt_every",
            "warmup.preview_every",
            "joint.log_every",
            "joint.ckpt_every",
            "joint.preview_every",
            "nerf.log_every",
            "nerf.ckpt_every",
            "nerf.preview_every",
            "nerf.model.chunk",
            "scene.generate.validation_views",
        ];
        before.sort();
        assert_eq!(keys, before);
        assert!(is_free("eval.views") && is_free("warmup.log_every"));
        assert!(is_free("scene.generate.validation_views") && !is_free("scene.generate.seed"));
        assert!(!is_free("evaluate") && !is_free("warmup.log_everything"));
    }

    fn exp(overrides: &[&str]) -> Experiment {
        let mut e = Experiment::from_toml_str(
            "name = \"t\"\n[scene]\nbuiltin = \"watercube\"\n",
            Path::new("t.toml"),
        )
        .unwrap();
        e.apply_overrides(overrides).unwrap();
        e
    }

    #[test]
    fn state_shaping_keys_change_the_digest_and_are_named() {
        let base = Settings::of_stage(&exp(&[]), Stage::Joint);
        let lr = Settings::of_stage(&exp(&["joint.dlf_optim.lr=1e-4"]), Stage::Joint);
        assert_ne!(base.digest(), lr.digest());
        let changes = lr.changes_since(&base);
        assert_eq!(changes.len(), 1);
        assert_eq!(changes[0].key, "joint.dlf_optim.lr");
        assert_eq!(
            changes[0].to_string(),
            "joint.dlf_optim.lr: 0.00001 → 0.0001"
        );
        // the renderer's width shapes both stages; the DLF learning rate only the joint one
        let wide = exp(&["physnerf.width=64"]);
        for stage in [Stage::Warmup, Stage::Joint] {
            let s = Settings::of_stage(&wide, stage);
            assert_eq!(
                s.changes_since(&Settings::of_stage(&exp(&[]), stage)).len(),
                1
            );
        }
        let w = Settings::of_stage(&exp(&["joint.dlf_optim.lr=1e-4"]), Stage::Warmup);
        assert_eq!(w, Settings::of_stage(&exp(&[]), Stage::Warmup));
        // the matmuls' operands shape every stage with a network, the ball query's place every
        // stage with PhysNeRF; neither the evaluation
        for (set, change) in [
            ("matmul=\"f16\"", "matmul: \"f32\" → \"f16\""),
            (
                "neighbour_search=\"device\"",
                "neighbour_search: \"host\" → \"device\"",
            ),
        ] {
            let changed = exp(&[set]);
            let nerf = set.starts_with("matmul");
            for stage in [Stage::Warmup, Stage::Joint, Stage::Refit, Stage::Nerf] {
                if stage == Stage::Nerf && !nerf {
                    // the NeRFs search no particles
                    let s = Settings::of_stage(&changed, stage);
                    assert_eq!(s, Settings::of_stage(&exp(&[]), stage));
                    continue;
                }
                let changes = Settings::of_stage(&changed, stage)
                    .changes_since(&Settings::of_stage(&exp(&[]), stage));
                assert_eq!(changes.len(), 1, "{stage}");
                assert_eq!(changes[0].to_string(), change);
            }
            assert!(
                Settings::of_stage(&changed, Stage::Eval)
                    .changes_since(&Settings::of_stage(&exp(&[]), Stage::Eval))
                    .is_empty()
            );
        }
    }

    #[test]
    fn cadence_evaluation_device_and_stops_are_free() {
        let base = exp(&[]);
        let free = exp(&[
            "joint.log_every=3",
            "warmup.preview_every=9",
            "eval.render=false",
            "device=flex",
            "physnerf.chunk=77",
            "joint.epochs=5",
            "warmup.iters=9",
        ]);
        assert_eq!(
            Settings::of_stage(&free, Stage::Warmup),
            Settings::of_stage(&base, Stage::Warmup)
        );
        // how long the warm-up ran shapes the joint stage that starts from it
        let joint = Settings::of_stage(&free, Stage::Joint)
            .changes_since(&Settings::of_stage(&base, Stage::Joint));
        let keys: Vec<&str> = changes_keys(&joint);
        assert_eq!(keys, ["warmup.iters"]);
    }

    /// A checkpoint of the release before `physnerf.density` existed resumes with the default
    /// (the behaviour it was made with), and not with softplus.
    #[test]
    fn a_key_added_later_with_the_old_behaviour_is_no_change() {
        let now = Settings::of_stage(&exp(&[]), Stage::Warmup);
        let mut older = now.clone();
        assert_eq!(
            older.0.remove("physnerf.density").as_deref(),
            Some("\"relu\"")
        );
        assert!(now.changes_since(&older).is_empty());
        let softplus = Settings::of_stage(&exp(&["physnerf.density=softplus"]), Stage::Warmup);
        assert_eq!(
            changes_keys(&softplus.changes_since(&older)),
            ["physnerf.density"]
        );
    }

    /// A built-in scene's gravity left unset is the world's, whichever side names it: a
    /// checkpoint made at `gravity = 9.81` resumes from a config that leaves it out, and the
    /// other way round; another gravity is a change.
    #[test]
    fn an_added_key_unset_on_either_side_is_its_old_value() {
        let at = |g: &[&str]| Settings::of_stage(&exp(g), Stage::Warmup);
        // the value ADDED_KEYS holds is the generator's world gravity, as settings spell it
        let world = toml::Value::from(neurofluid_scenegen::presets::EARTH_GRAVITY).to_string();
        assert!(ADDED_KEYS.contains(&("scene.generate.gravity", world.as_str())));
        let (unset, earth) = (at(&[]), at(&[&format!("scene.generate.gravity={world}")]));
        assert!(!unset.0.contains_key("scene.generate.gravity"));
        assert!(unset.changes_since(&earth).is_empty());
        assert!(earth.changes_since(&unset).is_empty());
        let slow = at(&["scene.generate.gravity=4.9"]);
        for (now, before) in [(&slow, &unset), (&unset, &slow), (&slow, &earth)] {
            assert_eq!(
                changes_keys(&now.changes_since(before)),
                ["scene.generate.gravity"]
            );
        }
    }

    /// The warm-up views the generator adds at every training frame are NeRF-T's training
    /// images and nothing else's: no other stage is shaped by them.
    #[test]
    fn warm_up_views_at_every_frame_shape_nerf_t_alone() {
        let every = exp(&["scene.generate.warmup_every_frame=true"]);
        for stage in [
            Stage::Nerf,
            Stage::Initial,
            Stage::Warmup,
            Stage::Joint,
            Stage::Refit,
        ] {
            assert_eq!(
                Settings::of_stage(&every, stage),
                Settings::of_stage(&exp(&[]), stage),
                "{stage}"
            );
        }
        let nerf_t = Settings::of_stage(&every, Stage::NerfT)
            .changes_since(&Settings::of_stage(&exp(&[]), Stage::NerfT));
        assert_eq!(changes_keys(&nerf_t), ["scene.generate.warmup_every_frame"]);
    }

    /// The NeRF shapes its own stage always, and the warm-up and joint stages only when the
    /// initial particles come from it.
    #[test]
    fn the_nerf_shapes_the_training_stages_only_from_images() {
        let base = exp(&[]);
        let wide = exp(&["nerf.model.width=64", "initial.opacity=0.7"]);
        let nerf = Settings::of_stage(&wide, Stage::Nerf)
            .changes_since(&Settings::of_stage(&base, Stage::Nerf));
        assert_eq!(changes_keys(&nerf), ["nerf.model.width"]);
        for stage in [Stage::Warmup, Stage::Joint] {
            assert_eq!(
                Settings::of_stage(&wide, stage),
                Settings::of_stage(&base, stage)
            );
        }
        let from = |o: &[&str]| {
            let mut all = vec!["scene.initial=from_images"];
            all.extend_from_slice(o);
            Settings::of_stage(&exp(&all), Stage::Warmup)
        };
        let changed =
            from(&["nerf.model.width=64", "initial.opacity=0.7"]).changes_since(&from(&[]));
        assert_eq!(
            changes_keys(&changed),
            ["initial.opacity", "nerf.model.width"]
        );
        // where the NeRF's stage stops is free for the NeRF, but shapes the particles the
        // warm-up starts from
        let longer = exp(&["nerf.iters=5"]);
        assert_eq!(
            Settings::of_stage(&longer, Stage::Nerf),
            Settings::of_stage(&base, Stage::Nerf)
        );
        let longer = from(&["nerf.iters=5"]).changes_since(&from(&[]));
        assert_eq!(changes_keys(&longer), ["nerf.iters"]);
    }

    /// A NeRF is shaped by the keys its images come from and no other stage by those: the
    /// protocol `nerf.t_images` NeRF-T only (with initial particles from images too), the joint
    /// stage's views NeRF-T only when it trains on NeuroFluid's images, the warm-up views every
    /// NeRF (and the stages PhysNeRF warms up in).
    #[test]
    fn a_nerf_is_shaped_by_where_its_images_come_from() {
        let changed = |base: &[&str], extra: &[&str], stage| -> Vec<String> {
            let with: Vec<&str> = base.iter().chain(extra).copied().collect();
            Settings::of_stage(&exp(&with), stage)
                .changes_since(&Settings::of_stage(&exp(base), stage))
                .into_iter()
                .map(|c| c.key)
                .collect()
        };
        let neurofluid = ["nerf.t_images=neurofluid"];
        for base in [&[][..], &["scene.initial=from_images"][..]] {
            assert_eq!(changed(base, &neurofluid, Stage::NerfT), ["nerf.t_images"]);
            for stage in [Stage::Nerf, Stage::Initial, Stage::Warmup, Stage::Joint] {
                assert!(changed(base, &neurofluid, stage).is_empty(), "{stage}");
            }
        }
        let views = ["joint.view=view_2", "joint.extra_views=[\"view_3\"]"];
        assert_eq!(
            changed(&neurofluid, &views, Stage::NerfT),
            ["joint.extra_views", "joint.view"]
        );
        assert!(changed(&[], &views, Stage::NerfT).is_empty());
        for stage in [Stage::Nerf, Stage::Initial, Stage::Warmup] {
            assert!(changed(&neurofluid, &views, stage).is_empty(), "{stage}");
        }
        for (setting, key) in [
            ("warmup.views=[\"view_2\", \"view_3\"]", "warmup.views"),
            ("warmup.held_out=\"view_2\"", "warmup.held_out"),
        ] {
            for stage in [
                Stage::Nerf,
                Stage::NerfT,
                Stage::Initial,
                Stage::Warmup,
                Stage::Joint,
            ] {
                assert_eq!(changed(&[], &[setting], stage), [key], "{stage}");
            }
        }
    }

    /// The refit's renderer is fitted to the grounded DLF after the joint stage: `[refit]` shapes
    /// it alone, and where the joint stage stops (the DLF it fits to) and the warm-up's length
    /// (its own warm-up phase) shape it too.
    #[test]
    fn the_refit_is_shaped_by_its_section_and_the_stages_before_it() {
        let changed = |extra: &[&str], stage| -> Vec<String> {
            Settings::of_stage(&exp(extra), stage)
                .changes_since(&Settings::of_stage(&exp(&[]), stage))
                .into_iter()
                .map(|c| c.key)
                .collect()
        };
        let refit = ["refit.enabled=true", "refit.positions=\"world\""];
        assert_eq!(
            changed(&refit, Stage::Refit),
            ["refit.enabled", "refit.positions"]
        );
        for stage in [Stage::Initial, Stage::Warmup, Stage::Joint, Stage::Nerf] {
            assert!(changed(&refit, stage).is_empty(), "{stage}");
        }
        for key in ["joint.epochs=3", "warmup.iters=9", "dlf.gravity_scale=1.5"] {
            let name = key.split('=').next().unwrap();
            assert_eq!(changed(&[key], Stage::Refit), [name]);
        }
        assert!(changed(&["joint.epochs=3"], Stage::Joint).is_empty());
        assert!(changed(&["joint.log_every=3"], Stage::Refit).is_empty());
    }

    fn changes_keys(c: &[Change]) -> Vec<&str> {
        c.iter().map(|c| c.key.as_str()).collect()
    }

    /// A checkpoint of the release before the particle terms records the anchor's weight under
    /// its old key and the retired options at their off values: resumed under today's keys with
    /// the same weight, nothing changed; with another weight, or a retired option that was on,
    /// the key is named.
    #[test]
    fn an_earlier_releases_keys_are_read_under_todays_names() {
        let old = |pairs: &[(&str, &str)]| {
            Settings(
                pairs
                    .iter()
                    .map(|(k, v)| (k.to_string(), v.to_string()))
                    .collect(),
            )
        };
        let now = old(&[("joint.terms.anchor.weight", "0.1"), ("joint.epochs", "6")]);
        let before = old(&[
            ("joint.anchor_weight", "0.1"),
            ("joint.energy_weight", "0.0"),
            ("joint.silhouette_weight", "0.0"),
            ("dlf.free_flight", "\"network\""),
            ("joint.epochs", "6"),
        ]);
        assert_eq!(now.changes_since(&before), vec![]);
        let other = old(&[("joint.anchor_weight", "0.2"), ("joint.epochs", "6")]);
        let keys: Vec<String> = now
            .changes_since(&other)
            .into_iter()
            .map(|c| c.key)
            .collect();
        assert_eq!(keys, ["joint.terms.anchor.weight"]);
        let on = old(&[
            ("joint.anchor_weight", "0.1"),
            ("joint.silhouette_weight", "0.5"),
            ("joint.epochs", "6"),
        ]);
        let keys: Vec<String> = now.changes_since(&on).into_iter().map(|c| c.key).collect();
        assert_eq!(keys, ["joint.silhouette_weight"]);
    }
}
