//! Initial fluid bodies: solid shapes sampled on a cubic lattice of spacing 2r.
//!
//! The bunny is procedural (no Stanford bunny mesh is available from crates.io under a clear
//! licence): a union of ellipsoids — body, head, two upright ears, a tail and two hind feet —
//! facing +x, distinctive enough to test generalisation to a novel shape.

use glam::DVec3;
use rand::Rng;
use serde::{Deserialize, Serialize};

/// A solid used as an initial fluid body.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "lowercase")]
pub enum Shape {
    /// Axis-aligned cube with edge `size`, centred at `center`.
    Cube {
        /// Centre.
        center: [f64; 3],
        /// Edge length.
        size: f64,
    },
    /// Sphere.
    Sphere {
        /// Centre.
        center: [f64; 3],
        /// Radius.
        radius: f64,
    },
    /// Upright cone (apex up, +y), base disc centred at `base`.
    Cone {
        /// Centre of the base disc.
        base: [f64; 3],
        /// Base radius.
        radius: f64,
        /// Height.
        height: f64,
    },
    /// The procedural bunny, sitting with its lowest point at `base` (x, z centred), `scale` 1 ≈ 1.3 m tall.
    Bunny {
        /// Centre of the footprint at the bottom.
        base: [f64; 3],
        /// Uniform scale.
        scale: f64,
    },
}

/// An ellipsoid (centre, radii) of the unit bunny.
const BUNNY: [([f64; 3], [f64; 3]); 8] = [
    ([0.0, 0.0, 0.0], [0.45, 0.36, 0.36]),      // body
    ([0.42, 0.30, 0.0], [0.22, 0.20, 0.19]),    // head
    ([0.33, 0.66, 0.10], [0.07, 0.26, 0.06]),   // ear
    ([0.33, 0.66, -0.10], [0.07, 0.26, 0.06]),  // ear
    ([-0.46, 0.05, 0.0], [0.10, 0.10, 0.10]),   // tail
    ([0.22, -0.29, 0.18], [0.20, 0.08, 0.09]),  // hind foot
    ([0.22, -0.29, -0.18], [0.20, 0.08, 0.09]), // hind foot
    ([0.58, 0.26, 0.0], [0.06, 0.05, 0.05]),    // nose
];
/// Lowest y of the unit bunny (bottom of the body and feet).
const BUNNY_BOTTOM: f64 = -0.37;

impl Shape {
    /// True when `p` lies inside.
    pub fn contains(&self, p: DVec3) -> bool {
        match *self {
            Shape::Cube { center, size } => {
                let d = (p - DVec3::from(center)).abs();
                d.max_element() <= 0.5 * size + 1e-9
            }
            Shape::Sphere { center, radius } => (p - DVec3::from(center)).length() <= radius,
            Shape::Cone {
                base,
                radius,
                height,
            } => {
                let d = p - DVec3::from(base);
                if d.y < 0.0 || d.y > height {
                    return false;
                }
                let r_at = radius * (1.0 - d.y / height);
                (d.x * d.x + d.z * d.z).sqrt() <= r_at
            }
            Shape::Bunny { base, scale } => {
                let q = (p - DVec3::from(base)) / scale + DVec3::new(0.0, BUNNY_BOTTOM, 0.0);
                BUNNY.iter().any(|(c, r)| {
                    let e = (q - DVec3::from(*c)) / DVec3::from(*r);
                    e.length_squared() <= 1.0
                })
            }
        }
    }

    /// Axis-aligned bounds (a conservative box around the shape).
    pub fn bounds(&self) -> (DVec3, DVec3) {
        match *self {
            Shape::Cube { center, size } => {
                let c = DVec3::from(center);
                (c - DVec3::splat(0.5 * size), c + DVec3::splat(0.5 * size))
            }
            Shape::Sphere { center, radius } => {
                let c = DVec3::from(center);
                (c - DVec3::splat(radius), c + DVec3::splat(radius))
            }
            Shape::Cone {
                base,
                radius,
                height,
            } => {
                let b = DVec3::from(base);
                (
                    b - DVec3::new(radius, 0.0, radius),
                    b + DVec3::new(radius, height, radius),
                )
            }
            Shape::Bunny { base, scale } => {
                let b = DVec3::from(base);
                let lo = DVec3::new(-0.6, 0.0, -0.4) * scale;
                let hi = DVec3::new(0.7, 1.35, 0.4) * scale;
                (b + lo, b + hi)
            }
        }
    }

    /// The shape moved by `offset`.
    pub fn translated(&self, offset: DVec3) -> Shape {
        let add = |a: [f64; 3]| (DVec3::from(a) + offset).to_array();
        match *self {
            Shape::Cube { center, size } => Shape::Cube {
                center: add(center),
                size,
            },
            Shape::Sphere { center, radius } => Shape::Sphere {
                center: add(center),
                radius,
            },
            Shape::Cone {
                base,
                radius,
                height,
            } => Shape::Cone {
                base: add(base),
                radius,
                height,
            },
            Shape::Bunny { base, scale } => Shape::Bunny {
                base: add(base),
                scale,
            },
        }
    }

    /// Fills the shape with particles on a cubic lattice of spacing `2·radius` anchored at the
    /// shape's lower bound, each jittered by up to `jitter·radius` per axis with `rng`;
    /// ordered by z, then y, then x.
    pub fn sample(&self, radius: f64, jitter: f64, rng: &mut impl Rng) -> Vec<DVec3> {
        let d = 2.0 * radius;
        let (lo, hi) = self.bounds();
        let n = ((hi - lo) / d + DVec3::splat(1e-6)).floor();
        let (nx, ny, nz) = (n.x as i64 + 1, n.y as i64 + 1, n.z as i64 + 1);
        // centre the lattice inside the bounds
        let start = lo + 0.5 * (hi - lo - n * d);
        let mut out = Vec::new();
        for k in 0..nz {
            for j in 0..ny {
                for i in 0..nx {
                    let p = start + DVec3::new(i as f64, j as f64, k as f64) * d;
                    if self.contains(p) {
                        let jit = DVec3::new(
                            rng.random_range(-1.0..=1.0),
                            rng.random_range(-1.0..=1.0),
                            rng.random_range(-1.0..=1.0),
                        ) * (jitter * radius);
                        out.push(p + jit);
                    }
                }
            }
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;

    #[test]
    fn lattice_counts_match_volumes() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(0);
        let cube = Shape::Cube {
            center: [0.0; 3],
            size: 0.7,
        };
        assert_eq!(cube.sample(0.025, 0.0, &mut rng).len(), 15 * 15 * 15);
        let v0 = 0.05f64.powi(3);
        let sphere = Shape::Sphere {
            center: [0.0; 3],
            radius: 0.5,
        };
        let n = sphere.sample(0.025, 0.0, &mut rng).len() as f64;
        let expect = 4.0 / 3.0 * std::f64::consts::PI * 0.125 / v0;
        assert!((n - expect).abs() / expect < 0.03, "{n} vs {expect}");
        let cone = Shape::Cone {
            base: [0.0; 3],
            radius: 0.5,
            height: 0.8,
        };
        let n = cone.sample(0.025, 0.0, &mut rng).len() as f64;
        // the base layer sits on the base disc, so the lattice represents the cone extended by
        // half a layer (d/2) below its base
        let (h, r) = (0.8 + 0.025, 0.5 * (1.0 + 0.025 / 0.8));
        let expect = std::f64::consts::PI * r * r * h / 3.0 / v0;
        assert!((n - expect).abs() / expect < 0.03, "{n} vs {expect}");
        // the bunny sits on its base and stays inside its bounds
        let bunny = Shape::Bunny {
            base: [0.0, 0.0, 0.0],
            scale: 1.0,
        };
        let pts = bunny.sample(0.025, 0.0, &mut rng);
        let (lo, hi) = bunny.bounds();
        assert!(pts.iter().all(|p| p.cmpge(lo).all() && p.cmple(hi).all()));
        let ymin = pts.iter().map(|p| p.y).fold(f64::INFINITY, f64::min);
        assert!(ymin.abs() < 0.06, "{ymin}");
    }
}
