//! Noise and occlusion models, applied to the observation models' predictions by synthesis
//! ([`crate::observe::ObservationModel::corrupt`]).

use glam::{DMat3, DQuat, DVec3, Vec3};
use rand::Rng;
use rand_distr::{Distribution, Normal, StandardNormal};
use serde::{Deserialize, Serialize};

use crate::error::ModelError;

/// Noise and occlusion settings of one dataset (units: metres, pixels, degrees).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct NoiseConfig {
    /// Gaussian noise σ of 3D points (markers, hand tips, scan points), metres.
    pub point_sigma: f64,
    /// Gaussian noise σ of 2D keypoints, pixels.
    pub pixel_sigma: f64,
    /// Gaussian σ of HMD rotations (degrees, about a random axis) and positions (metres).
    pub rotation_sigma_deg: f64,
    pub position_sigma: f64,
    /// Probability that a marker or keypoint is an outlier, and its largest displacement
    /// (metres for markers, pixels for keypoints).
    pub outlier_rate: f64,
    pub outlier_scale_m: f64,
    pub outlier_scale_px: f64,
    /// Probability that a marker or keypoint is dropped (not visible).
    pub drop_rate: f64,
    /// Holes punched in a scan: count and radius (metres).
    pub scan_holes: usize,
    pub scan_hole_radius: f64,
}

impl Default for NoiseConfig {
    /// Defaults meant to look like real capture: 5 mm on optical markers and scan points,
    /// 2 px on detected keypoints, 1° / 5 mm on headset tracking, 1 % outliers, 5 % dropouts,
    /// eight 6 cm holes in a scan.
    fn default() -> Self {
        Self {
            point_sigma: 0.005,
            pixel_sigma: 2.0,
            rotation_sigma_deg: 1.0,
            position_sigma: 0.005,
            outlier_rate: 0.01,
            outlier_scale_m: 0.1,
            outlier_scale_px: 30.0,
            drop_rate: 0.05,
            scan_holes: 8,
            scan_hole_radius: 0.06,
        }
    }
}

impl NoiseConfig {
    /// No noise, no outliers, no dropouts, no holes.
    pub fn none() -> Self {
        Self {
            point_sigma: 0.0,
            pixel_sigma: 0.0,
            rotation_sigma_deg: 0.0,
            position_sigma: 0.0,
            outlier_rate: 0.0,
            outlier_scale_m: 0.0,
            outlier_scale_px: 0.0,
            drop_rate: 0.0,
            scan_holes: 0,
            scan_hole_radius: 0.0,
        }
    }

    /// Scales every magnitude and rate by `s` (0 = noise-free, 1 = defaults).
    pub fn scaled(s: f64) -> Result<Self, ModelError> {
        if !(s.is_finite() && s >= 0.0) {
            return Err(ModelError::Setting {
                name: "noise",
                value: s.to_string(),
                reason: "must be a finite number ≥ 0".into(),
            });
        }
        Ok(Self::default().times(s))
    }

    /// These settings with every magnitude and rate (σs, outlier and dropout rates, the number
    /// of scan holes, rounded) multiplied by `s` ≥ 0; rates stay at most 1, the outliers' size
    /// and the holes' radius are kept. `scaled(s)` is `default().times(s)`.
    pub fn times(&self, s: f64) -> Self {
        Self {
            point_sigma: self.point_sigma * s,
            pixel_sigma: self.pixel_sigma * s,
            rotation_sigma_deg: self.rotation_sigma_deg * s,
            position_sigma: self.position_sigma * s,
            outlier_rate: (self.outlier_rate * s).min(1.0),
            outlier_scale_m: self.outlier_scale_m,
            outlier_scale_px: self.outlier_scale_px,
            drop_rate: (self.drop_rate * s).min(1.0),
            scan_holes: (self.scan_holes as f64 * s).round() as usize,
            scan_hole_radius: self.scan_hole_radius,
        }
    }
}

fn gaussian<R: Rng + ?Sized>(rng: &mut R, sigma: f64) -> f64 {
    if sigma == 0.0 {
        return 0.0;
    }
    Normal::new(0.0, sigma).map_or(0.0, |n| n.sample(rng))
}

fn gaussian3<R: Rng + ?Sized>(rng: &mut R, sigma: f64) -> DVec3 {
    DVec3::new(
        gaussian(rng, sigma),
        gaussian(rng, sigma),
        gaussian(rng, sigma),
    )
}

/// A random direction (uniform on the sphere).
fn unit<R: Rng + ?Sized>(rng: &mut R) -> DVec3 {
    loop {
        let v = DVec3::new(
            StandardNormal.sample(rng),
            StandardNormal.sample(rng),
            StandardNormal.sample(rng),
        );
        if v.length_squared() > 1e-12 {
            return v.normalize();
        }
    }
}

/// Corrupts 2D image points (keypoints, landmarks): [`corrupt_points`] with the pixel noise,
/// outlier scale, outlier and dropout rates of `cfg`.
pub fn corrupt_pixels<R: Rng + ?Sized>(
    values: &mut [f64],
    visible: &mut [bool],
    cfg: &NoiseConfig,
    rng: &mut R,
) {
    corrupt_points(
        values,
        visible,
        2,
        cfg.pixel_sigma,
        cfg.outlier_scale_px,
        cfg,
        rng,
    );
}

/// Corrupts groups of `stride` values (a 3D marker or a 2D keypoint): Gaussian noise `sigma`,
/// outliers (uniform displacement up to `outlier_scale` along a random direction) and dropouts
/// (visibility cleared). Invisible groups are reported as zeros.
pub fn corrupt_points<R: Rng + ?Sized>(
    values: &mut [f64],
    visible: &mut [bool],
    stride: usize,
    sigma: f64,
    outlier_scale: f64,
    cfg: &NoiseConfig,
    rng: &mut R,
) {
    for (group, vis) in values.chunks_mut(stride).zip(visible.chunks_mut(stride)) {
        let dropped = cfg.drop_rate > 0.0 && rng.random::<f64>() < cfg.drop_rate;
        let outlier = cfg.outlier_rate > 0.0 && rng.random::<f64>() < cfg.outlier_rate;
        let dir = unit(rng);
        let magnitude = if outlier {
            rng.random::<f64>() * outlier_scale
        } else {
            0.0
        };
        for (k, v) in group.iter_mut().enumerate() {
            *v += gaussian(rng, sigma) + magnitude * dir[k % 3];
        }
        if dropped {
            vis.iter_mut().for_each(|b| *b = false);
        }
        if !vis[0] {
            group.iter_mut().for_each(|v| *v = 0.0);
        }
    }
}

/// Noise on the HMD vector (three 3×4 `[R | t]` blocks, then points): rotations are perturbed by
/// a random rotation of σ degrees and stay orthonormal; positions and points get Gaussian noise.
pub fn corrupt_hmd<R: Rng + ?Sized>(
    values: &mut [f64],
    visible: &[bool],
    cfg: &NoiseConfig,
    rng: &mut R,
) {
    use super::hmd_layout::{BLOCK, DEVICES, device, tip};
    for d in 0..DEVICES {
        let b = &mut values[device(d)..device(d) + BLOCK];
        perturb_rotation(&mut b[..9], cfg.rotation_sigma_deg, rng);
        add_gaussian(&mut b[9..12], cfg.position_sigma, rng);
    }
    add_gaussian(&mut values[tip(0)..], cfg.point_sigma, rng);
    for (v, &vis) in values.iter_mut().zip(visible) {
        if !vis {
            *v = 0.0;
        }
    }
}

/// Turns a rotation stored row-major in `r` (9 entries) by a random rotation of `sigma_deg`
/// degrees (Gaussian angle, uniform axis); the result stays orthonormal.
pub fn perturb_rotation<R: Rng + ?Sized>(r: &mut [f64], sigma_deg: f64, rng: &mut R) {
    let m = DMat3::from_cols_array(&[r[0], r[3], r[6], r[1], r[4], r[7], r[2], r[5], r[8]]);
    let angle = gaussian(rng, sigma_deg.to_radians());
    let m = DMat3::from_quat(DQuat::from_axis_angle(unit(rng), angle)) * m;
    for row in 0..3 {
        r[3 * row] = m.x_axis[row];
        r[3 * row + 1] = m.y_axis[row];
        r[3 * row + 2] = m.z_axis[row];
    }
}

/// Adds independent Gaussian noise of σ `sigma` to every value.
pub fn add_gaussian<R: Rng + ?Sized>(values: &mut [f64], sigma: f64, rng: &mut R) {
    for v in values {
        *v += gaussian(rng, sigma);
    }
}

/// Gaussian noise on scan points.
pub fn jitter_points<R: Rng + ?Sized>(points: &mut [Vec3], sigma: f64, rng: &mut R) {
    if sigma == 0.0 {
        return;
    }
    for p in points {
        *p += gaussian3(rng, sigma).as_vec3();
    }
}

/// Clears the visibility of points within `count` random spheres of `radius` centred on visible
/// points (holes of a scan).
pub fn punch_holes<R: Rng + ?Sized>(
    points: &[Vec3],
    visible: &mut [bool],
    count: usize,
    radius: f64,
    rng: &mut R,
) {
    let r2 = (radius * radius) as f32;
    for _ in 0..count {
        let candidates: Vec<usize> = (0..points.len()).filter(|&i| visible[i]).collect();
        if candidates.is_empty() {
            return;
        }
        let c = points[candidates[rng.random_range(0..candidates.len())]];
        for (p, v) in points.iter().zip(visible.iter_mut()) {
            if (*p - c).length_squared() <= r2 {
                *v = false;
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;
    use rand_chacha::ChaCha8Rng;

    #[test]
    fn noise_free_config_changes_nothing() {
        let cfg = NoiseConfig::scaled(0.0).unwrap();
        let none = NoiseConfig {
            outlier_scale_m: cfg.outlier_scale_m,
            outlier_scale_px: cfg.outlier_scale_px,
            scan_hole_radius: cfg.scan_hole_radius,
            ..NoiseConfig::none()
        };
        assert_eq!(cfg, none, "every rate and σ is zero");
        let mut rng = ChaCha8Rng::seed_from_u64(1);
        let mut v = vec![1.0, 2.0, 3.0, 4.0, 5.0, 6.0];
        let mut vis = vec![true; 6];
        corrupt_points(&mut v, &mut vis, 3, 0.0, 0.0, &cfg, &mut rng);
        assert_eq!(v, vec![1.0, 2.0, 3.0, 4.0, 5.0, 6.0]);
        assert!(vis.iter().all(|&b| b));
        assert!(NoiseConfig::scaled(f64::NAN).is_err());
    }

    #[test]
    fn point_noise_has_the_requested_spread_and_drop_rate() {
        let cfg = NoiseConfig {
            outlier_rate: 0.0,
            drop_rate: 0.2,
            ..NoiseConfig::default()
        };
        let mut rng = ChaCha8Rng::seed_from_u64(7);
        let n = 20_000;
        let mut v = vec![0.0; 3 * n];
        let mut vis = vec![true; 3 * n];
        corrupt_points(&mut v, &mut vis, 3, 0.005, 0.0, &cfg, &mut rng);
        let kept: Vec<f64> = v
            .iter()
            .zip(&vis)
            .filter(|(_, b)| **b)
            .map(|(x, _)| *x)
            .collect();
        let sd = (kept.iter().map(|x| x * x).sum::<f64>() / kept.len() as f64).sqrt();
        assert!((sd - 0.005).abs() < 0.0002, "{sd}");
        let drop = 1.0 - kept.len() as f64 / (3 * n) as f64;
        assert!((drop - 0.2).abs() < 0.015, "{drop}");
    }

    #[test]
    fn hmd_rotations_stay_orthonormal() {
        let cfg = NoiseConfig {
            rotation_sigma_deg: 5.0,
            ..NoiseConfig::default()
        };
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        let mut v = vec![0.0; 42];
        for b in 0..3 {
            v[12 * b] = 1.0;
            v[12 * b + 4] = 1.0;
            v[12 * b + 8] = 1.0;
        }
        corrupt_hmd(&mut v, &[true; 42], &cfg, &mut rng);
        for b in 0..3 {
            let r = DMat3::from_cols_array(&[
                v[12 * b],
                v[12 * b + 3],
                v[12 * b + 6],
                v[12 * b + 1],
                v[12 * b + 4],
                v[12 * b + 7],
                v[12 * b + 2],
                v[12 * b + 5],
                v[12 * b + 8],
            ]);
            assert!((r * r.transpose()).abs_diff_eq(DMat3::IDENTITY, 1e-12));
            assert!(!r.abs_diff_eq(DMat3::IDENTITY, 1e-6));
        }
    }
}
