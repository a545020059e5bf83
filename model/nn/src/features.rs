//! Input features of the neural fitter and their normalisation statistics (stored in every
//! checkpoint): observations D, residuals R(θ), gradients g and poses θ, each standardised per
//! entry with a mean and standard deviation measured on training data, then clipped.
//!
//! **Pooled views** ([`Views::Pooled`], `keypoints2d`): the residual and the observations are
//! laid out camera after camera (`2 × keypoints` values each, [`lfit_model::observe`]); a pooled
//! network sees them per camera, in the camera's normalised image coordinates (pixels minus the
//! principal point, over the focal length: the same for any image size and focal length), and
//! reduced over the cameras that see each keypoint by permutation-invariant pools, so the feature
//! length does not depend on the rig:
//!
//! - observations D: the mean over the seeing cameras of each normalised coordinate, then the
//!   maximum, then per keypoint the fraction of the cameras that see it, then the camera count
//!   (`2·2K + K + 1` values for K keypoints);
//! - residual features of R(θ): the mean over the seeing cameras of each normalised residual
//!   entry, then the largest magnitude (`2·2K`).
//!
//! An entry no camera sees pools to 0. The gradient g(θ) and the pose θ have the model's length
//! whatever the rig, and pass as they are.

use std::borrow::Cow;

use serde::{Deserialize, Serialize};

use crate::config::{NetConfig, Views};
use lfit_model::camera::Camera;
use lfit_model::energy::{Energy, Target};
use lfit_model::error::{ModelError, Result};
use lfit_model::observe::Sensor;

/// Per-entry mean and standard deviation.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Norm {
    pub mean: Vec<f32>,
    pub std: Vec<f32>,
}

impl Norm {
    /// Statistics of `rows` (all the same length); a standard deviation below `1e-6` (an entry
    /// that never changes) becomes 1 so the entry passes through centred.
    pub fn from_rows(rows: &[Vec<f64>]) -> Self {
        let d = rows.first().map_or(0, Vec::len);
        let n = rows.len().max(1) as f64;
        let mut mean = vec![0.0f64; d];
        for r in rows {
            for (m, v) in mean.iter_mut().zip(r) {
                *m += v / n;
            }
        }
        let mut var = vec![0.0f64; d];
        for r in rows {
            for ((s, v), m) in var.iter_mut().zip(r).zip(&mean) {
                *s += (v - m) * (v - m) / n;
            }
        }
        Self {
            mean: mean.iter().map(|&m| m as f32).collect(),
            std: var
                .iter()
                .map(|&s| {
                    if s.sqrt() < 1e-6 {
                        1.0
                    } else {
                        s.sqrt() as f32
                    }
                })
                .collect(),
        }
    }

    /// Appends `clip((x − mean) / std)` to `out`.
    pub fn push(&self, x: &[f64], clip: f32, out: &mut Vec<f32>) {
        out.extend(
            x.iter()
                .zip(&self.mean)
                .zip(&self.std)
                .map(|((&v, &m), &s)| {
                    let z = (v as f32 - m) / s;
                    if z.is_finite() {
                        z.clamp(-clip, clip)
                    } else {
                        0.0
                    }
                }),
        );
    }

    fn check(&self, name: &str, len: usize) -> Result<()> {
        if self.mean.len() != len || self.std.len() != len {
            return Err(ModelError::Config(format!(
                "feature statistics '{name}' have {} means and {} deviations, the network needs {len}",
                self.mean.len(),
                self.std.len()
            )));
        }
        if let Some(i) = self
            .mean
            .iter()
            .chain(&self.std)
            .position(|v| !v.is_finite())
        {
            return Err(ModelError::Config(format!(
                "feature statistics '{name}': entry {i} is not finite"
            )));
        }
        if let Some(i) = self.std.iter().position(|&s| s <= 0.0) {
            return Err(ModelError::Config(format!(
                "feature statistics '{name}': deviation {i} is not positive"
            )));
        }
        Ok(())
    }
}

/// Normalisation of every input the network sees.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct FeatureStats {
    pub observation: Norm,
    pub residual: Norm,
    pub gradient: Norm,
    pub pose: Norm,
}

impl FeatureStats {
    /// Checks the lengths against the features of a network; one-line error naming the
    /// mismatch.
    pub fn validate(&self, config: &NetConfig) -> Result<()> {
        self.observation
            .check("observation", config.obs_features())?;
        self.residual
            .check("residual", config.residual_features())?;
        self.gradient.check("gradient", config.param_dim)?;
        self.pose.check("pose", config.param_dim)
    }

    /// Statistics from samples of observations, and of residuals, gradients and poses at the
    /// poses the fitter is expected to visit.
    pub fn measure(
        observations: &[Vec<f64>],
        residuals: &[Vec<f64>],
        gradients: &[Vec<f64>],
        poses: &[Vec<f64>],
    ) -> Self {
        Self {
            observation: Norm::from_rows(observations),
            residual: Norm::from_rows(residuals),
            gradient: Norm::from_rows(gradients),
            pose: Norm::from_rows(poses),
        }
    }
}

/// The observation features D of a sparse energy: observed values (0 where not visible), then
/// visibility as 0/1. Empty for `scan`.
pub fn observation_features(energy: &Energy) -> Vec<f64> {
    match energy.target() {
        Target::Sparse { values, visible } => values
            .iter()
            .zip(visible)
            .map(|(&v, &s)| if s { v } else { 0.0 })
            .chain(visible.iter().map(|&s| if s { 1.0 } else { 0.0 }))
            .collect(),
        Target::Scan { .. } | Target::Silhouettes { .. } => Vec::new(),
    }
}

/// The cameras of a `keypoints2d` frame that a pooled network fits: one-line error unless the
/// sensor is `keypoints2d` with at least one camera of the network's keypoints.
pub fn pooled_cameras<'a>(config: &NetConfig, energy: &'a Energy) -> Result<&'a [Camera]> {
    let Sensor::Keypoints2d(setup) = energy.sensor() else {
        return Err(ModelError::Config(format!(
            "the pooled network fits keypoints2d data, this frame is {}",
            energy.sensor().name()
        )));
    };
    let dim = energy.sensor().residual_dim(energy.template());
    let cameras = setup.cameras.len();
    if cameras == 0 || dim != cameras * config.residual_dim {
        return Err(ModelError::Config(format!(
            "the pooled network fits {} keypoints per camera ({} values), this frame's {cameras} cameras give {dim} values",
            config.keypoints(),
            config.residual_dim
        )));
    }
    Ok(&setup.cameras)
}

/// `[means…, maxima…]` over the cameras that see each of the `len` entries of a camera, of
/// `value(camera, entry)` (with `magnitude`, maxima of `|value|`); 0 for an entry no camera sees.
fn pool(
    cameras: usize,
    len: usize,
    seen: impl Fn(usize, usize) -> bool,
    value: impl Fn(usize, usize) -> f64,
    magnitude: bool,
) -> Vec<f64> {
    let mut sum = vec![0.0; len];
    let mut max = vec![f64::NEG_INFINITY; len];
    let mut count = vec![0usize; len];
    for c in 0..cameras {
        for i in 0..len {
            if seen(c, i) {
                let v = value(c, i);
                sum[i] += v;
                max[i] = max[i].max(if magnitude { v.abs() } else { v });
                count[i] += 1;
            }
        }
    }
    let mut out: Vec<f64> = sum
        .iter()
        .zip(&count)
        .map(|(&s, &n)| if n > 0 { s / n as f64 } else { 0.0 })
        .collect();
    out.extend(
        max.iter()
            .zip(&count)
            .map(|(&m, &n)| if n > 0 { m } else { 0.0 }),
    );
    out
}

/// Entry `i` of a camera's part (u, v alternate) in normalised image coordinates.
fn normalised(cam: &Camera, i: usize, pixels: f64, offset: bool) -> f64 {
    let (f, c) = if i % 2 == 0 {
        (cam.fx, cam.cx)
    } else {
        (cam.fy, cam.cy)
    };
    if offset { (pixels - c) / f } else { pixels / f }
}

/// The sparse target of a frame (empty for dense targets).
fn sparse_target(energy: &Energy) -> (&[f64], &[bool]) {
    match energy.target() {
        Target::Sparse { values, visible } => (values, visible),
        Target::Scan { .. } | Target::Silhouettes { .. } => (&[], &[]),
    }
}

/// The observation features D of a frame as `config`'s network sees them: [`observation_features`]
/// for a fixed-rig network, the pooled observation features (module docs) for a pooled one.
pub fn observation_features_for(config: &NetConfig, energy: &Energy) -> Result<Vec<f64>> {
    if config.views == Views::Fixed {
        return Ok(observation_features(energy));
    }
    let cams = pooled_cameras(config, energy)?;
    let per = config.residual_dim;
    let (values, visible) = sparse_target(energy);
    if values.len() != cams.len() * per || visible.len() != values.len() {
        return Err(ModelError::Shape {
            what: "keypoints2d target".into(),
            expected: (cams.len() * per).to_string(),
            got: values.len().to_string(),
        });
    }
    let seen = |c: usize, i: usize| visible[c * per + i];
    let mut out = pool(
        cams.len(),
        per,
        seen,
        |c, i| normalised(&cams[c], i, values[c * per + i], true),
        false,
    );
    let n = cams.len() as f64;
    out.extend(
        (0..config.keypoints())
            .map(|k| (0..cams.len()).filter(|&c| seen(c, 2 * k)).count() as f64 / n),
    );
    out.push(n);
    Ok(out)
}

/// The residual features of R(θ) (`residual`, the frame's residual at θ) as `config`'s network
/// sees them: R itself for a fixed-rig network, the pooled residual features (module docs) for a
/// pooled one.
pub fn residual_features<'a>(
    config: &NetConfig,
    energy: &Energy,
    residual: &'a [f64],
) -> Result<Cow<'a, [f64]>> {
    if config.views == Views::Fixed {
        return Ok(Cow::Borrowed(residual));
    }
    let cams = pooled_cameras(config, energy)?;
    let per = config.residual_dim;
    let (_, visible) = sparse_target(energy);
    if residual.len() != cams.len() * per || visible.len() != residual.len() {
        return Err(ModelError::Shape {
            what: "residual".into(),
            expected: (cams.len() * per).to_string(),
            got: residual.len().to_string(),
        });
    }
    let seen = |c: usize, i: usize| visible[c * per + i];
    let r = |c: usize, i: usize| normalised(&cams[c], i, residual[c * per + i], false);
    Ok(Cow::Owned(pool(cams.len(), per, seen, r, true)))
}
