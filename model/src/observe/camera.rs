//! Calibrated pinhole cameras (intrinsics + extrinsics), the default ring of cameras and random
//! rigs ([`RigRanges`]) for training camera-agnostic networks.

use glam::{DMat3, DVec2, DVec3};
use rand::Rng;
use serde::{Deserialize, Serialize};

use crate::error::{ModelError, Result};

/// A pinhole camera. `camera_from_world` maps world points into the camera frame, whose +z axis
/// looks into the scene, +x goes right and +y goes down in the image (OpenCV convention).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Camera {
    /// Focal lengths in pixels.
    pub fx: f64,
    pub fy: f64,
    /// Principal point in pixels.
    pub cx: f64,
    pub cy: f64,
    /// Image size in pixels.
    pub width: u32,
    pub height: u32,
    /// Rotation of `camera_from_world` (row-major 3×3).
    pub rotation: [[f64; 3]; 3],
    /// Translation of `camera_from_world`.
    pub translation: [f64; 3],
}

impl Camera {
    /// A camera at `eye` looking at `target`, with world +y up in the image.
    pub fn look_at(eye: DVec3, target: DVec3, fx: f64, width: u32, height: u32) -> Self {
        let forward = (target - eye).normalize();
        let right = forward.cross(DVec3::Y).normalize();
        let down = forward.cross(right);
        // Rows of camera_from_world are the camera axes in world coordinates.
        let r = DMat3::from_cols(right, down, forward).transpose();
        let t = -(r * eye);
        Self {
            fx,
            fy: fx,
            cx: f64::from(width) / 2.0,
            cy: f64::from(height) / 2.0,
            width,
            height,
            rotation: [
                r.row(0).to_array(),
                r.row(1).to_array(),
                r.row(2).to_array(),
            ],
            translation: t.to_array(),
        }
    }

    /// The same camera in a world turned by `r` (a rotation; world points `p ↦ r p`): it sees
    /// `r p` where it saw `p`. How a camera file calibrated in a Z-up world (a board on the
    /// floor) becomes lfit's Y-up one (`lfit data import --up z`).
    pub fn in_rotated_world(&self, r: DMat3) -> Self {
        let rot = self.rot() * r.transpose();
        Self {
            rotation: [
                rot.row(0).to_array(),
                rot.row(1).to_array(),
                rot.row(2).to_array(),
            ],
            ..*self
        }
    }

    /// `camera_from_world` rotation.
    pub fn rot(&self) -> DMat3 {
        DMat3::from_cols_array_2d(&self.rotation).transpose()
    }

    /// A world point in the camera frame.
    pub fn to_camera(&self, p: DVec3) -> DVec3 {
        self.rot() * p + DVec3::from_array(self.translation)
    }

    /// Camera centre in world coordinates.
    pub fn center(&self) -> DVec3 {
        -(self.rot().transpose() * DVec3::from_array(self.translation))
    }

    /// Projects a camera-frame point to pixels (no check of depth).
    pub fn project_camera(&self, q: DVec3) -> DVec2 {
        DVec2::new(self.fx * q.x / q.z + self.cx, self.fy * q.y / q.z + self.cy)
    }

    /// Projects a world point; `None` behind the camera (depth < 1 cm).
    pub fn project(&self, p: DVec3) -> Option<DVec2> {
        let q = self.to_camera(p);
        (q.z > 0.01).then(|| self.project_camera(q))
    }

    /// Whether a pixel lies inside the image.
    pub fn in_image(&self, uv: DVec2) -> bool {
        uv.x >= 0.0 && uv.y >= 0.0 && uv.x < f64::from(self.width) && uv.y < f64::from(self.height)
    }

    /// Checks finiteness, positive focal lengths and image size, and an orthonormal rotation.
    pub fn validate(&self, index: usize) -> Result<()> {
        let fail = |reason: &str| {
            Err(ModelError::Camera {
                index,
                reason: reason.to_string(),
            })
        };
        let numbers = [self.fx, self.fy, self.cx, self.cy]
            .into_iter()
            .chain(self.rotation.iter().flatten().copied())
            .chain(self.translation);
        if numbers.into_iter().any(|v| !v.is_finite()) {
            return fail("a parameter is not finite");
        }
        if self.fx <= 0.0 || self.fy <= 0.0 || self.width == 0 || self.height == 0 {
            return fail("focal lengths and image size must be positive");
        }
        let r = self.rot();
        if !(r * r.transpose()).abs_diff_eq(DMat3::IDENTITY, 1e-6) || r.determinant() < 0.0 {
            return fail("rotation is not a proper rotation matrix");
        }
        Ok(())
    }
}

/// The default ring: `count` cameras evenly spaced on a circle of radius 4 m at 1.3 m height,
/// all looking at (0, 1, 0), 640×480 pixels, 60° horizontal field of view-ish (fx = 550).
pub fn default_ring(count: usize) -> Vec<Camera> {
    (0..count)
        .map(|k| {
            let a = std::f64::consts::TAU * k as f64 / count as f64;
            let eye = DVec3::new(4.0 * a.sin(), 1.3, 4.0 * a.cos());
            Camera::look_at(eye, DVec3::new(0.0, 1.0, 0.0), 550.0, 640, 480)
        })
        .collect()
}

/// Number of cameras in the default ring (SPEC §4: 4–7).
pub const DEFAULT_RING_SIZE: usize = 6;

/// Ranges of random camera rigs (how a camera-agnostic `keypoints2d` network is trained: every
/// frame seen by a rig of its own). A rig has `cameras` cameras (uniform count); each camera is
/// drawn independently: its azimuth `yaw_deg` around the subject (0° in front of the rest pose,
/// on +z; uniform), its horizontal distance `distance_m` from its aim point and its height
/// `height_m` above the floor (y = 0; both uniform), its aim point the subject's root joint plus
/// a uniform offset of up to `aim_jitter_m` per axis, no roll (world up is up in the image), an
/// image size from `images` and a horizontal field of view `hfov_deg` (uniform), so
/// `fx = fy = (width / 2) / tan(hfov / 2)` and the principal point is the image centre. Joints
/// outside an image or behind a camera are not seen, as with any rig.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct RigRanges {
    /// Cameras per rig, `[min, max]` inclusive.
    pub cameras: [usize; 2],
    /// Horizontal distance from the aim point, metres.
    pub distance_m: [f64; 2],
    /// Camera centre above the floor, metres.
    pub height_m: [f64; 2],
    /// Azimuth around the subject, degrees.
    pub yaw_deg: [f64; 2],
    /// Horizontal field of view, degrees.
    pub hfov_deg: [f64; 2],
    /// Image sizes `[width, height]` in pixels, one drawn per camera.
    pub images: Vec<[u32; 2]>,
    /// Largest offset of the aim point from the subject's root, per axis, metres.
    pub aim_jitter_m: f64,
}

impl Default for RigRanges {
    /// 1–8 cameras all around the subject, 2.5–6 m away, 0.5–2.5 m high, 40°–90° wide, VGA to
    /// full HD (landscape, and portrait full HD as phones film), aimed within 20 cm of the root.
    fn default() -> Self {
        Self {
            cameras: [1, 8],
            distance_m: [2.5, 6.0],
            height_m: [0.5, 2.5],
            yaw_deg: [0.0, 360.0],
            hfov_deg: [40.0, 90.0],
            images: vec![[640, 480], [1280, 720], [1920, 1080], [1080, 1920]],
            aim_jitter_m: 0.2,
        }
    }
}

impl RigRanges {
    /// Most cameras a rig may have.
    pub const MAX_CAMERAS: usize = 64;

    /// Rejects empty, reversed or non-finite ranges, naming the field.
    pub fn validate(&self) -> Result<()> {
        let bad = |field: &str, why: String| {
            Err(ModelError::Config(format!("rig ranges: {field} {why}")))
        };
        let [lo, hi] = self.cameras;
        if lo == 0 || lo > hi || hi > Self::MAX_CAMERAS {
            return bad(
                "cameras",
                format!(
                    "must be [min, max] with 1 ≤ min ≤ max ≤ {}, got [{lo}, {hi}]",
                    Self::MAX_CAMERAS
                ),
            );
        }
        for (field, [a, b], low, high) in [
            ("distance_m", self.distance_m, 0.5, 1e3),
            ("height_m", self.height_m, -1e3, 1e3),
            ("yaw_deg", self.yaw_deg, -720.0, 720.0),
            ("hfov_deg", self.hfov_deg, 1.0, 170.0),
        ] {
            if !(a.is_finite() && b.is_finite() && low <= a && a <= b && b <= high) {
                return bad(
                    field,
                    format!("must be [min, max] with {low} ≤ min ≤ max ≤ {high}, got [{a}, {b}]"),
                );
            }
        }
        if self.images.is_empty() || self.images.iter().any(|&[w, h]| w == 0 || h == 0) {
            return bad(
                "images",
                "must list at least one [width, height] with positive sizes".into(),
            );
        }
        if !(self.aim_jitter_m.is_finite() && (0.0..=10.0).contains(&self.aim_jitter_m)) {
            return bad(
                "aim_jitter_m",
                format!("must be in [0, 10], got {}", self.aim_jitter_m),
            );
        }
        Ok(())
    }

    /// A random rig around a subject whose root joint is at `root` (world). Deterministic in
    /// the state of `rng`: the same seed gives the same rigs.
    pub fn sample<R: Rng + ?Sized>(&self, rng: &mut R, root: DVec3) -> Vec<Camera> {
        let uniform = |rng: &mut R, [a, b]: [f64; 2]| {
            if a < b { rng.random_range(a..b) } else { a }
        };
        let count = rng.random_range(self.cameras[0]..=self.cameras[1].max(self.cameras[0]));
        (0..count)
            .map(|_| {
                let yaw = uniform(rng, self.yaw_deg).to_radians();
                let distance = uniform(rng, self.distance_m);
                let height = uniform(rng, self.height_m);
                let hfov = uniform(rng, self.hfov_deg).to_radians();
                let [width, height_px] = self.images[rng.random_range(0..self.images.len().max(1))];
                let j = self.aim_jitter_m;
                let jitter = DVec3::new(
                    uniform(rng, [-j, j]),
                    uniform(rng, [-j, j]),
                    uniform(rng, [-j, j]),
                );
                let aim = root + jitter;
                let eye = DVec3::new(
                    aim.x + distance * yaw.sin(),
                    height,
                    aim.z + distance * yaw.cos(),
                );
                let fx = f64::from(width) / 2.0 / (hfov / 2.0).tan();
                Camera::look_at(eye, aim, fx, width, height_px)
            })
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// [`Camera::in_rotated_world`]: the turned camera projects `r p` where the camera projected
    /// `p`, its centre is `r c`, and turning back gives the camera again.
    #[test]
    fn a_camera_in_a_rotated_world_sees_the_rotated_points() {
        let cam = Camera::look_at(
            DVec3::new(1.5, 1.2, 3.0),
            DVec3::new(0.0, 0.9, 0.0),
            800.0,
            1280,
            720,
        );
        let r = DMat3::from_rotation_x(-std::f64::consts::FRAC_PI_2) * DMat3::from_rotation_y(0.3);
        let turned = cam.in_rotated_world(r);
        turned.validate(0).expect("a proper rotation");
        assert!(turned.center().abs_diff_eq(r * cam.center(), 1e-12));
        for p in [DVec3::new(0.1, 1.0, -0.2), DVec3::new(-0.4, 0.2, 0.5)] {
            let (a, b) = (cam.project(p).unwrap(), turned.project(r * p).unwrap());
            assert!(a.abs_diff_eq(b, 1e-9), "{a} vs {b}");
        }
        let back = turned.in_rotated_world(r.transpose());
        for (x, y) in back
            .rotation
            .iter()
            .flatten()
            .zip(cam.rotation.iter().flatten())
        {
            assert!((x - y).abs() < 1e-12);
        }
        assert_eq!((back.fx, back.translation), (cam.fx, cam.translation));
    }

    #[test]
    fn ring_cameras_see_the_target_at_the_centre() {
        for (i, cam) in default_ring(DEFAULT_RING_SIZE).iter().enumerate() {
            cam.validate(i).unwrap();
            let uv = cam.project(DVec3::new(0.0, 1.0, 0.0)).unwrap();
            assert!((uv - DVec2::new(320.0, 240.0)).length() < 1e-9);
            // A point above the target appears higher in the image (smaller v).
            let up = cam.project(DVec3::new(0.0, 1.5, 0.0)).unwrap();
            assert!(up.y < uv.y);
            assert!((cam.center().length() - (16.0f64 + 1.69).sqrt()).abs() < 1e-9);
        }
    }

    #[test]
    fn random_rigs_are_seeded_valid_and_within_their_ranges() {
        use rand::SeedableRng;
        let ranges = RigRanges::default();
        ranges.validate().unwrap();
        let root = DVec3::new(0.3, 0.9, -0.2);
        let rigs = |seed| {
            let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
            (0..200)
                .map(|_| ranges.sample(&mut rng, root))
                .collect::<Vec<_>>()
        };
        let a = rigs(7);
        assert_eq!(a, rigs(7), "same seed, same rigs");
        assert_ne!(a, rigs(8));
        let mut counts = [0usize; 9];
        for rig in &a {
            counts[rig.len()] += 1;
            for (i, cam) in rig.iter().enumerate() {
                cam.validate(i).unwrap();
                let c = cam.center();
                let horizontal = DVec2::new(c.x - root.x, c.z - root.z).length();
                assert!(
                    (2.5 - 0.3..=6.0 + 0.3).contains(&horizontal),
                    "{horizontal}"
                );
                assert!((0.5..=2.5).contains(&c.y), "{}", c.y);
                assert!(ranges.images.contains(&[cam.width, cam.height]));
                let hfov = 2.0 * (f64::from(cam.width) / 2.0 / cam.fx).atan().to_degrees();
                assert!((40.0 - 1e-9..=90.0 + 1e-9).contains(&hfov), "{hfov}");
                // The subject's root is in front of the camera, near the image centre.
                let uv = cam.project(root).unwrap();
                assert!(
                    cam.in_image(uv),
                    "root at {uv} outside {}x{}",
                    cam.width,
                    cam.height
                );
            }
        }
        assert_eq!(counts[0], 0);
        assert!(
            counts[1..].iter().all(|&n| n > 5),
            "every count 1..=8 drawn: {counts:?}"
        );
    }

    #[test]
    fn bad_rig_ranges_are_refused_naming_the_field() {
        let cases: [(&str, RigRanges); 5] = [
            (
                "cameras",
                RigRanges {
                    cameras: [0, 3],
                    ..RigRanges::default()
                },
            ),
            (
                "cameras",
                RigRanges {
                    cameras: [4, 2],
                    ..RigRanges::default()
                },
            ),
            (
                "distance_m",
                RigRanges {
                    distance_m: [0.0, 3.0],
                    ..RigRanges::default()
                },
            ),
            (
                "hfov_deg",
                RigRanges {
                    hfov_deg: [30.0, f64::NAN],
                    ..RigRanges::default()
                },
            ),
            (
                "images",
                RigRanges {
                    images: vec![[0, 480]],
                    ..RigRanges::default()
                },
            ),
        ];
        for (field, r) in cases {
            let e = r.validate().unwrap_err().to_string();
            assert!(e.contains(field) && !e.contains('\n'), "{e}");
        }
    }
}
