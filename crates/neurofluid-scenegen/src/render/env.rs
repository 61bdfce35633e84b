//! A simple procedural environment (y up): a sky gradient with a sun, a checkered ground
//! below the horizon. Reflections and refractions of it make the water read as glass.

use glam::Vec3;

/// Direction towards the key light (the sun).
pub fn sun_dir() -> Vec3 {
    Vec3::new(0.45, 0.8, 0.4).normalize()
}

/// Radiance seen along unit direction `d` (display-referred RGB, may exceed 1 at the sun).
pub fn environment(d: Vec3) -> Vec3 {
    let horizon = Vec3::new(0.93, 0.95, 0.98);
    if d.y >= 0.0 {
        let zenith = Vec3::new(0.28, 0.48, 0.82);
        let sky = horizon.lerp(zenith, d.y.powf(0.55));
        let s = d.dot(sun_dir()).max(0.0);
        sky + Vec3::new(1.0, 0.95, 0.85) * (8.0 * s.powi(600) + 0.25 * s.powi(12))
    } else {
        let t = 1.0 / (-d.y).max(1e-3);
        let (u, v) = (d.x * t, d.z * t);
        let check = ((u * 1.5).floor() as i64 + (v * 1.5).floor() as i64).rem_euclid(2);
        let ground = if check == 0 {
            Vec3::new(0.42, 0.45, 0.50)
        } else {
            Vec3::new(0.78, 0.78, 0.75)
        };
        let fade = (-(-d.y) * 6.0).exp();
        ground.lerp(Vec3::new(0.6, 0.62, 0.66), fade)
    }
}
