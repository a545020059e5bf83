//! Calibrated pinhole cameras (intrinsics + extrinsics) and the default ring of cameras.

use glam::{DMat3, DVec2, DVec3};
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

#[cfg(test)]
mod tests {
    use super::*;

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
}
