//! Generates one built-in scene and prints its timings (the scene-generation benchmark).
//!
//! `cargo run --release -p neurofluid-scenegen --example generate_scene -- watercube quick OUT [train_frames test_frames]`

use neurofluid_scenegen::{Preset, Scale, SceneConfig, SceneKind, generate};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let kind = SceneKind::parse(args.first().map_or("watercube", String::as_str))
        .ok_or("unknown scene")?;
    let scale = Scale::parse(args.get(1).map_or("quick", String::as_str)).ok_or("unknown scale")?;
    let out = args.get(2).cloned().unwrap_or_else(|| "data/bench".into());
    let mut cfg = SceneConfig::new(kind, scale);
    if let Some(f) = args.get(3) {
        cfg.train_frames = Some(f.parse()?);
    }
    if let Some(f) = args.get(4) {
        cfg.test_frames = Some(f.parse()?);
    }
    let preset = Preset::resolve(&cfg);
    let t = std::time::Instant::now();
    let r = generate::generate(&preset, std::path::Path::new(&out), true)?;
    println!(
        "{} {}: {r}, total {:.1} s",
        kind.name(),
        scale.name(),
        t.elapsed().as_secs_f64()
    );
    Ok(())
}
