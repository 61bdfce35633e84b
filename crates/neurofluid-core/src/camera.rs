//! Pinhole cameras and rays in the NeRF-synthetic / Blender convention.
//!
//! The camera-to-world matrix maps camera space (looking down −z, +y up, +x right) to the world.
//! Pixel (row j, column i) shoots along ((i − c_x)/f_x, −(j − c_y)/f_y, −1), rotated by the upper
//! 3×3 block of c2w and normalised to unit length, so a c2w that carries a uniform scale (as
//! NeuroFluid's released cameras do) still gives unit directions. From `camera_angle_x`,
//! f_x = f_y = 0.5·W / tan(0.5·camera_angle_x) and (c_x, c_y) = (W/2, H/2): the ray of pixel i
//! goes through i with **no** half-pixel offset, as in NeRF. (nerfstudio's `cx`, which puts
//! pixel i's ray through i + 0.5, is `c_x + 0.5` here.)

/// A pinhole camera.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Camera {
    /// Image width in pixels.
    pub width: u32,
    /// Image height in pixels.
    pub height: u32,
    /// Focal length along x, in pixels.
    pub fx: f32,
    /// Focal length along y, in pixels.
    pub fy: f32,
    /// Column of the optical axis (W/2 for a centred camera).
    pub cx: f32,
    /// Row of the optical axis (H/2 for a centred camera).
    pub cy: f32,
    /// Camera-to-world transform, row-major (`c2w[row][col]`), translation in the last column.
    pub c2w: [[f32; 4]; 4],
}

/// A batch of rays: one origin and one unit direction per ray.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Rays {
    /// Ray origins (the camera centre for every ray of a pinhole camera).
    pub origins: Vec<[f32; 3]>,
    /// Unit ray directions.
    pub dirs: Vec<[f32; 3]>,
}

impl Rays {
    /// Number of rays.
    pub fn len(&self) -> usize {
        self.dirs.len()
    }

    /// True when there are no rays.
    pub fn is_empty(&self) -> bool {
        self.dirs.is_empty()
    }
}

/// Focal length in pixels from the horizontal field of view (radians).
pub fn focal_from_angle_x(width: u32, camera_angle_x: f32) -> f32 {
    0.5 * width as f32 / (0.5 * camera_angle_x).tan()
}

impl Camera {
    /// A centred camera whose focal length is derived from `camera_angle_x` (radians).
    pub fn from_angle_x(width: u32, height: u32, camera_angle_x: f32, c2w: [[f32; 4]; 4]) -> Self {
        Self::centred(
            width,
            height,
            focal_from_angle_x(width, camera_angle_x),
            c2w,
        )
    }

    /// A camera with one focal length `focal` and the optical axis at the image centre.
    pub fn centred(width: u32, height: u32, focal: f32, c2w: [[f32; 4]; 4]) -> Self {
        Self {
            width,
            height,
            fx: focal,
            fy: focal,
            cx: width as f32 / 2.0,
            cy: height as f32 / 2.0,
            c2w,
        }
    }

    /// The same view at `width × height` pixels (the intrinsics scaled with the image).
    pub fn resized(&self, width: u32, height: u32) -> Self {
        let (kx, ky) = (
            width as f32 / self.width as f32,
            height as f32 / self.height as f32,
        );
        Self {
            width,
            height,
            fx: self.fx * kx,
            fy: self.fy * ky,
            cx: self.cx * kx,
            cy: self.cy * ky,
            c2w: self.c2w,
        }
    }

    /// The camera centre in world coordinates (the translation column of c2w).
    pub fn origin(&self) -> [f32; 3] {
        [self.c2w[0][3], self.c2w[1][3], self.c2w[2][3]]
    }

    /// Number of pixels, the number of rays of a full image.
    pub fn num_pixels(&self) -> usize {
        self.width as usize * self.height as usize
    }

    /// Unit world direction of the ray through pixel (row, col).
    pub fn ray_dir(&self, row: u32, col: u32) -> [f32; 3] {
        let d_cam = [
            (col as f32 - self.cx) / self.fx,
            -(row as f32 - self.cy) / self.fy,
            -1.0f32,
        ];
        let r = &self.c2w;
        let mut d = [0.0f32; 3];
        for (a, out) in d.iter_mut().enumerate() {
            *out = d_cam[0] * r[a][0] + d_cam[1] * r[a][1] + d_cam[2] * r[a][2];
        }
        let norm = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
        [d[0] / norm, d[1] / norm, d[2] / norm]
    }

    /// Where the world point `p` appears: `(col, row, depth)` with the pixel coordinates of
    /// [`Camera::ray_dir`] (fractional) and a depth along the viewing axis (scaled like c2w, for
    /// ordering); `None` behind the camera.
    pub fn project(&self, p: [f32; 3]) -> Option<(f32, f32, f32)> {
        let (c, depth) = self.camera_coords(p)?;
        let col = self.fx * c[0] / depth + self.cx;
        let row = -self.fy * c[1] / depth + self.cy;
        Some((col, row, depth))
    }

    /// The camera coordinates of `p` (the transpose of c2w's rotation applied to p − origin)
    /// and its depth −c₂; `None` behind the camera.
    fn camera_coords(&self, p: [f32; 3]) -> Option<([f32; 3], f32)> {
        let o = self.origin();
        let r = &self.c2w;
        let v = [p[0] - o[0], p[1] - o[1], p[2] - o[2]];
        let c: [f32; 3] = std::array::from_fn(|k| v[0] * r[0][k] + v[1] * r[1][k] + v[2] * r[2][k]);
        let depth = -c[2];
        (!depth.is_nan() && depth > 0.0).then_some((c, depth))
    }

    /// [`Camera::project`]'s `(col, row)` derivatives with respect to the world point `p`:
    /// `[∂col/∂p, ∂row/∂p]`; `None` behind the camera.
    pub fn project_jacobian(&self, p: [f32; 3]) -> Option<[[f32; 3]; 2]> {
        let (c, depth) = self.camera_coords(p)?;
        // camera coordinate k is Σ_j (p − o)_j r[j][k], so ∂c_k/∂p_j = r[j][k]
        let r = &self.c2w;
        // col = fx·c0/depth + cx, depth = −c2: ∂(c0/depth)/∂p_j = (r[j][0] + c0/depth·r[j][2])/depth
        let d_col = std::array::from_fn(|j| self.fx * (r[j][0] + c[0] / depth * r[j][2]) / depth);
        let d_row = std::array::from_fn(|j| -self.fy * (r[j][1] + c[1] / depth * r[j][2]) / depth);
        Some([d_col, d_row])
    }

    /// Rays for the given pixels, each indexed row-major as `row·W + col`.
    ///
    /// # Panics
    /// When a pixel index lies outside the image.
    pub fn rays(&self, pixels: &[u32]) -> Rays {
        let o = self.origin();
        let n = self.num_pixels();
        let dirs = pixels
            .iter()
            .map(|&p| {
                assert!(
                    (p as usize) < n,
                    "pixel {p} outside a {}×{} image",
                    self.width,
                    self.height
                );
                self.ray_dir(p / self.width, p % self.width)
            })
            .collect::<Vec<_>>();
        Rays {
            origins: vec![o; dirs.len()],
            dirs,
        }
    }

    /// Rays for every pixel, row-major.
    pub fn all_rays(&self) -> Rays {
        let pixels: Vec<u32> = (0..self.num_pixels() as u32).collect();
        self.rays(&pixels)
    }

    /// A camera at `eye` looking at `target` with world `up`, in the Blender convention
    /// (the camera's −z axis points at the target).
    pub fn look_at(
        width: u32,
        height: u32,
        camera_angle_x: f32,
        eye: [f32; 3],
        target: [f32; 3],
        up: [f32; 3],
    ) -> Self {
        let eye_v = glam::Vec3::from(eye);
        let back = (eye_v - glam::Vec3::from(target)).normalize();
        let right = glam::Vec3::from(up).cross(back).normalize();
        let cam_up = back.cross(right);
        let c2w = [
            [right.x, cam_up.x, back.x, eye_v.x],
            [right.y, cam_up.y, back.y, eye_v.y],
            [right.z, cam_up.z, back.z, eye_v.z],
            [0.0, 0.0, 0.0, 1.0],
        ];
        Self::from_angle_x(width, height, camera_angle_x, c2w)
    }
}

/// `n` cameras at `distance` from `centre`, spread evenly over the half sphere above it (a
/// Fibonacci lattice, none on the up axis itself), each looking at `centre` with the
/// intrinsics of `like` (scaled to at most `max_width` pixels wide).
pub fn orbit_cameras(
    like: &Camera,
    centre: [f32; 3],
    distance: f32,
    up_axis: usize,
    n: usize,
    max_width: u32,
) -> Vec<Camera> {
    let k = (max_width as f32 / like.width as f32).min(1.0);
    let scaled = like.resized(
        ((like.width as f32 * k).round() as u32).max(1),
        ((like.height as f32 * k).round() as u32).max(1),
    );
    let mut up = [0.0f32; 3];
    up[up_axis] = 1.0;
    let (a, b) = ((up_axis + 1) % 3, (up_axis + 2) % 3);
    let golden = std::f32::consts::PI * (3.0 - 5f32.sqrt());
    (0..n)
        .map(|i| {
            // equal areas of the half sphere: the height above the centre uniform in (0, 1)
            let h = (i as f32 + 0.5) / n as f32;
            let r = (1.0 - h * h).sqrt();
            let phi = golden * i as f32;
            let mut eye = centre;
            eye[a] += distance * r * phi.cos();
            eye[b] += distance * r * phi.sin();
            eye[up_axis] += distance * h;
            let pose = Camera::look_at(scaled.width, scaled.height, 1.0, eye, centre, up);
            Camera {
                c2w: pose.c2w,
                ..scaled
            }
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn close(a: [f32; 3], b: [f32; 3], tol: f32) -> bool {
        a.iter().zip(b).all(|(x, y)| (x - y).abs() <= tol)
    }

    #[test]
    fn focal_matches_the_released_watercube_camera() {
        // spec: focal 1225.86 px at 400 px for camera_angle_x ≈ 0.3235 rad
        let f = focal_from_angle_x(400, 0.3235);
        assert!((f - 1225.9).abs() < 1.0, "{f}");
        // 90° field of view: f = W/2
        assert!((focal_from_angle_x(64, std::f32::consts::FRAC_PI_2) - 32.0).abs() < 1e-4);
    }

    /// The projection's Jacobian against central differences of the projection (in f64 steps
    /// small enough for f32), for a scaled, rotated, off-centre camera.
    #[test]
    fn projection_jacobian_matches_finite_differences() {
        let s = 0.8f32;
        let (c, sn) = (0.6f32.cos(), 0.6f32.sin());
        let c2w = [
            [s * c, 0.0, s * sn, 1.5],
            [0.0, s, 0.0, 0.7],
            [-s * sn, 0.0, s * c, 4.0],
            [0.0, 0.0, 0.0, 1.0],
        ];
        let mut cam = Camera::from_angle_x(120, 90, 0.7, c2w);
        cam.fy *= 1.1;
        cam.cx += 3.0;
        for p in [[0.1f32, 0.2, 0.3], [-0.4, 0.5, -0.2], [0.9, -0.3, 0.6]] {
            let jac = cam.project_jacobian(p).unwrap();
            for j in 0..3 {
                let h = 1e-3f32;
                let (mut a, mut b) = (p, p);
                a[j] += h;
                b[j] -= h;
                let (pa, pb) = (cam.project(a).unwrap(), cam.project(b).unwrap());
                let fd = [(pa.0 - pb.0) / (2.0 * h), (pa.1 - pb.1) / (2.0 * h)];
                for k in 0..2 {
                    let tol = 1e-2 * (1.0 + fd[k].abs());
                    assert!(
                        (jac[k][j] - fd[k]).abs() < tol,
                        "{p:?} {k} {j}: {jac:?} vs {fd:?}"
                    );
                }
            }
        }
        assert!(
            cam.project_jacobian([1.5, 0.7, 10.0]).is_none(),
            "behind the camera"
        );
    }

    /// Projecting a point on a pixel's ray lands on that pixel, for a scaled, rotated camera.
    #[test]
    fn projection_inverts_the_rays() {
        let s = 0.4155f32;
        // off-centre, with different focal lengths along x and y
        let cam = Camera {
            width: 40,
            height: 30,
            fx: 35.0,
            fy: 30.0,
            cx: 18.5,
            cy: 16.0,
            c2w: [
                [0.0, -s, 0.0, 1.0],
                [s, 0.0, 0.0, -2.0],
                [0.0, 0.0, s, 3.0],
                [0.0, 0.0, 0.0, 1.0],
            ],
        };
        let o = cam.origin();
        for (row, col) in [(0, 0), (15, 20), (29, 3), (7, 39)] {
            let d = cam.ray_dir(row, col);
            for t in [0.5f32, 4.0] {
                let p = std::array::from_fn(|k| o[k] + t * d[k]);
                let (c, r, depth) = cam.project(p).unwrap();
                assert!((c - col as f32).abs() < 1e-3 && (r - row as f32).abs() < 1e-3);
                assert!(depth > 0.0);
            }
            let behind = std::array::from_fn(|k| o[k] - d[k]);
            assert!(cam.project(behind).is_none());
        }
    }

    #[test]
    fn identity_camera_rays_by_hand() {
        let id = [
            [1.0, 0.0, 0.0, 0.0],
            [0.0, 1.0, 0.0, 0.0],
            [0.0, 0.0, 1.0, 0.0],
            [0.0, 0.0, 0.0, 1.0],
        ];
        let cam = Camera::centred(4, 2, 2.0, id);
        // pixel (row 1, col 2) is the image centre W/2, H/2: straight down −z, no half-pixel offset
        assert!(close(cam.ray_dir(1, 2), [0.0, 0.0, -1.0], 1e-7));
        // pixel (row 0, col 0): ((0 − 2)/2, −(0 − 1)/2, −1) = (−1, 0.5, −1) / 1.5
        assert!(close(
            cam.ray_dir(0, 0),
            [-1.0 / 1.5, 0.5 / 1.5, -1.0 / 1.5],
            1e-6
        ));
        let rays = cam.rays(&[0, 6]);
        assert_eq!(rays.origins, vec![[0.0; 3]; 2]);
        assert!(close(rays.dirs[1], cam.ray_dir(1, 2), 0.0));
    }

    #[test]
    fn scaled_rotated_camera_gives_unit_directions() {
        // rotation of 90° about z, scaled by 0.4155 (the released cameras carry a scale), translated
        let s = 0.4155f32;
        let c2w = [
            [0.0, -s, 0.0, 1.0],
            [s, 0.0, 0.0, 2.0],
            [0.0, 0.0, s, 3.0],
            [0.0, 0.0, 0.0, 1.0],
        ];
        let cam = Camera::centred(10, 10, 5.0, c2w);
        assert_eq!(cam.origin(), [1.0, 2.0, 3.0]);
        // pixel (0, 0): d_cam = (−1, 1, −1); R·d = s·(−1, −1, −1) → unit (−1,−1,−1)/√3
        let inv = 1.0 / 3f32.sqrt();
        assert!(close(cam.ray_dir(0, 0), [-inv, -inv, -inv], 1e-6));
        for p in 0..100u32 {
            let d = cam.ray_dir(p / 10, p % 10);
            let n = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
            assert!((n - 1.0).abs() < 1e-6);
        }
    }

    /// A resized camera sees the same view: the ray through the same fraction of the image
    /// is the same.
    #[test]
    fn a_resized_camera_keeps_its_view() {
        let cam = Camera {
            width: 40,
            height: 30,
            fx: 35.0,
            fy: 30.0,
            cx: 18.0,
            cy: 16.0,
            c2w: Camera::look_at(4, 4, 0.6, [3.0, 1.0, 2.0], [0.0; 3], [0.0, 1.0, 0.0]).c2w,
        };
        let half = cam.resized(20, 15);
        assert!(close(cam.ray_dir(16, 18), half.ray_dir(8, 9), 1e-6));
        assert!(close(cam.ray_dir(0, 0), half.ray_dir(0, 0), 1e-6));
    }

    #[test]
    fn look_at_points_the_centre_ray_at_the_target() {
        let cam = Camera::look_at(8, 8, 0.6, [3.0, 1.0, 2.0], [0.0, 0.5, 0.0], [0.0, 1.0, 0.0]);
        let d = cam.ray_dir(4, 4);
        let to = glam::Vec3::new(-3.0, -0.5, -2.0).normalize();
        assert!(close(d, to.into(), 1e-6), "{d:?}");
        // image-up points to world-up-ish: pixel row 0 looks higher than row 7
        assert!(cam.ray_dir(0, 4)[1] > cam.ray_dir(7, 4)[1]);
    }

    /// Every camera sits at the distance asked, above the centre, looks at it through its
    /// principal point, keeps the intrinsics' field of view, and no two look from one place.
    #[test]
    fn an_orbit_surrounds_the_centre_from_above() {
        let like = Camera::look_at(400, 300, 0.6, [0.0, -4.0, 2.0], [0.0; 3], [0.0, 0.0, 1.0]);
        let centre = [0.2, -0.1, 0.3];
        let cams = orbit_cameras(&like, centre, 3.0, 2, 16, 128);
        assert_eq!(cams.len(), 16);
        let mut azimuths = Vec::new();
        for c in &cams {
            assert_eq!((c.width, c.height), (128, 96));
            assert!((c.fx / c.width as f32 - like.fx / like.width as f32).abs() < 1e-5);
            let o = c.origin();
            let rel: [f32; 3] = std::array::from_fn(|k| o[k] - centre[k]);
            let dist = rel.iter().map(|x| x * x).sum::<f32>().sqrt();
            assert!((dist - 3.0).abs() < 1e-4, "{dist}");
            assert!(rel[2] > 0.0 && rel[2] < 3.0, "{rel:?}");
            // the principal ray (camera −z) points from the eye at the centre
            let ahead = [-c.c2w[0][2], -c.c2w[1][2], -c.c2w[2][2]];
            for k in 0..3 {
                assert!((ahead[k] + rel[k] / dist).abs() < 1e-4);
            }
            azimuths.push(rel[1].atan2(rel[0]));
        }
        // heights spread from near the floor to near the top, azimuths all round
        let heights: Vec<f32> = cams.iter().map(|c| c.origin()[2] - centre[2]).collect();
        assert!(heights.iter().cloned().fold(f32::MAX, f32::min) < 0.2);
        assert!(heights.iter().cloned().fold(f32::MIN, f32::max) > 2.8);
        for q in 0..4 {
            let lo = -std::f32::consts::PI + q as f32 * std::f32::consts::FRAC_PI_2;
            let hi = lo + std::f32::consts::FRAC_PI_2;
            assert!(azimuths.iter().filter(|a| (lo..hi).contains(*a)).count() >= 3);
        }
    }
}
