//! Ray tracing of the density-field surface from a Blender-convention camera: water is glass-
//! like (Fresnel reflection plus refraction through the body, lightly absorbing), honey is amber
//! and strongly absorbing with a diffuse term so its shape reads. The background is
//! transparent: alpha is the fraction of a pixel's sub-samples that hit the fluid.

use glam::Vec3;
use neurofluid_core::camera::Camera;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use super::env::{environment, sun_dir};
use super::field::DensityField;

/// Look of the fluid.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Appearance {
    /// Clear water (IOR 1.33, faint blue-green absorption).
    Water,
    /// Honey (IOR 1.5, amber, strong absorption).
    Honey,
}

impl Appearance {
    fn ior(self) -> f32 {
        match self {
            Appearance::Water => 1.33,
            Appearance::Honey => 1.5,
        }
    }

    /// Absorption coefficients (1/m) per channel.
    fn sigma(self) -> Vec3 {
        match self {
            Appearance::Water => Vec3::new(1.6, 0.45, 0.25),
            Appearance::Honey => Vec3::new(0.9, 3.2, 9.0),
        }
    }
}

fn reflect(d: Vec3, n: Vec3) -> Vec3 {
    d - 2.0 * d.dot(n) * n
}

/// Refraction of `d` through a surface with normal `n` facing the incoming side; `eta` = n₁/n₂.
fn refract(d: Vec3, n: Vec3, eta: f32) -> Option<Vec3> {
    let cosi = -d.dot(n);
    let k = 1.0 - eta * eta * (1.0 - cosi * cosi);
    (k >= 0.0).then(|| (eta * d + (eta * cosi - k.sqrt()) * n).normalize())
}

fn schlick(cosi: f32, ior: f32) -> f32 {
    let r0 = ((1.0 - ior) / (1.0 + ior)).powi(2);
    r0 + (1.0 - r0) * (1.0 - cosi.clamp(0.0, 1.0)).powi(5)
}

fn ray_box(o: Vec3, d: Vec3, lo: Vec3, hi: Vec3) -> Option<(f32, f32)> {
    let inv = d.recip();
    let t0 = (lo - o) * inv;
    let t1 = (hi - o) * inv;
    let tmin = t0.min(t1).max_element().max(0.0);
    let tmax = t0.max(t1).min_element();
    (tmax > tmin).then_some((tmin, tmax))
}

/// Finds where the ray leaves (`inside`) or enters (`!inside`) the fluid within [t0, t1].
fn march(
    field: &DensityField,
    o: Vec3,
    d: Vec3,
    t0: f32,
    t1: f32,
    inside: bool,
    step: f32,
) -> Option<f32> {
    let f = |t: f32| {
        let v = field.sample(o + d * t) - field.iso;
        if inside { -v } else { v }
    };
    let mut t = t0;
    let mut prev_t = t;
    while t <= t1 {
        if !inside && let Some(te) = field.skip(o + d * t, o, d) {
            let next = te + 1e-4;
            if next > t {
                prev_t = next;
                t = next;
                continue;
            }
        }
        if f(t) > 0.0 {
            if t == t0 {
                return Some(t);
            }
            let (mut a, mut b) = (prev_t, t);
            for _ in 0..10 {
                let m = 0.5 * (a + b);
                if f(m) > 0.0 {
                    b = m;
                } else {
                    a = m;
                }
            }
            return Some(b);
        }
        prev_t = t;
        t += step;
    }
    None
}

/// Colour of a ray hitting the surface at `p`.
fn shade(field: &DensityField, p: Vec3, d: Vec3, look: Appearance, step: f32, far: f32) -> Vec3 {
    let n = field.normal(p);
    let ior = look.ior();
    let cosi = (-d.dot(n)).clamp(0.0, 1.0);
    let fres = schlick(cosi, ior);
    let refl = environment(reflect(d, n));
    let l = sun_dir();
    // through the body
    let transmitted = match refract(d, n, 1.0 / ior) {
        Some(t_dir) => {
            let start = p + t_dir * (0.5 * step);
            let exit = march(field, start, t_dir, 0.0, far, true, step).unwrap_or(far);
            let q = start + t_dir * exit;
            let n2 = field.normal(q);
            let out = refract(t_dir, -n2, ior).unwrap_or_else(|| reflect(t_dir, -n2));
            let absorb = (-look.sigma() * exit).exp();
            environment(out) * absorb
        }
        None => refl,
    };
    let body = match look {
        Appearance::Water => {
            let lambert = n.dot(l).max(0.0);
            transmitted * 0.9 + Vec3::new(0.05, 0.12, 0.16) * (0.4 + 0.6 * lambert)
        }
        Appearance::Honey => {
            let lambert = n.dot(l).max(0.0);
            let amber = Vec3::new(0.85, 0.47, 0.08);
            let diffuse = amber * (0.3 + 0.7 * lambert);
            transmitted * 0.45 + diffuse * 0.55
        }
    };
    let h = (l - d).normalize();
    let spec = n.dot(h).max(0.0).powi(120) * 1.5;
    fres * refl + (1.0 - fres) * body + Vec3::splat(spec)
}

/// World direction through fractional pixel coordinates (row `y`, column `x`).
fn dir_at(cam: &Camera, y: f32, x: f32) -> Vec3 {
    let dc = Vec3::new((x - cam.cx) / cam.fx, -(y - cam.cy) / cam.fy, -1.0);
    let r = &cam.c2w;
    Vec3::new(
        r[0][0] * dc.x + r[0][1] * dc.y + r[0][2] * dc.z,
        r[1][0] * dc.x + r[1][1] * dc.y + r[1][2] * dc.z,
        r[2][0] * dc.x + r[2][1] * dc.y + r[2][2] * dc.z,
    )
    .normalize()
}

/// Renders the field's surface from `cam` as 8-bit RGBA (row-major), with `spp × spp`
/// sub-samples per pixel centred on the pixel's ray (no half-pixel offset, like the camera).
pub fn render(cam: &Camera, field: &DensityField, look: Appearance, spp: u32) -> Vec<u8> {
    let (lo, hi) = field.bounds();
    let o = Vec3::from(cam.origin());
    let step = field_step(field);
    let far = (hi - lo).length();
    let spp = spp.max(1);
    let w = cam.width as usize;
    let mut out = vec![0u8; w * cam.height as usize * 4];
    out.par_chunks_mut(w * 4)
        .enumerate()
        .for_each(|(row, line)| {
            for col in 0..w {
                let mut acc = Vec3::ZERO;
                let mut hits = 0u32;
                for sy in 0..spp {
                    for sx in 0..spp {
                        let y = row as f32 + (sy as f32 + 0.5) / spp as f32 - 0.5;
                        let x = col as f32 + (sx as f32 + 0.5) / spp as f32 - 0.5;
                        let d = dir_at(cam, y, x);
                        let Some((t0, t1)) = ray_box(o, d, lo, hi) else {
                            continue;
                        };
                        if let Some(t) = march(field, o, d, t0, t1, false, step) {
                            acc += shade(field, o + d * t, d, look, step, far)
                                .clamp(Vec3::ZERO, Vec3::ONE);
                            hits += 1;
                        }
                    }
                }
                if hits > 0 {
                    let c = acc / hits as f32;
                    let px = &mut line[col * 4..col * 4 + 4];
                    px[0] = (c.x * 255.0).round() as u8;
                    px[1] = (c.y * 255.0).round() as u8;
                    px[2] = (c.z * 255.0).round() as u8;
                    px[3] = ((hits as f32 / (spp * spp) as f32) * 255.0).round() as u8;
                }
            }
        });
    out
}

/// March step: 0.6 voxel (the field's finest feature is one kernel support, ≈ 4 voxels).
fn field_step(field: &DensityField) -> f32 {
    field.cell_size() * 0.6
}
