//! Input features of the neural fitter and their normalisation statistics (stored in every
//! checkpoint): observations D, residuals R(θ), gradients g and poses θ, each standardised per
//! entry with a mean and standard deviation measured on training data, then clipped.

use serde::{Deserialize, Serialize};

use lfit_model::energy::{Energy, Target};
use lfit_model::error::{ModelError, Result};

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
    /// Checks the lengths against a residual and a parameter dimension; one-line error naming
    /// the mismatch.
    pub fn validate(&self, residual_dim: usize, param_dim: usize) -> Result<()> {
        self.observation.check("observation", 2 * residual_dim)?;
        self.residual.check("residual", residual_dim)?;
        self.gradient.check("gradient", param_dim)?;
        self.pose.check("pose", param_dim)
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
