//! A Gaussian prior over the body's joint rotations, fitted to captured poses.
//!
//! EA (papers/000 eq. 7) is zero inside the joint limits: inside them the energy prefers no pose
//! over another, and a joint the observations leave open (a foot whose markers are missing, a
//! twist no marker sees) goes wherever the data's noise puts it. SMPLify (Bogo et al. 2016, eq. 4)
//! adds a mixture of Gaussians over the joint rotations fitted to CMU motion capture; this is its
//! one-component form, `E_pose-prior = ‖W (θ_b − μ)‖²` over the axis-angle entries `θ_b` of every
//! joint but the root (a person faces any direction: the root orientation and translation stay
//! free, as in SMPLify), with `Σ = L Lᵀ` the poses' covariance and `W = L⁻¹` (so `WᵀW = Σ⁻¹` and
//! the term is the squared Mahalanobis distance, `n` on average over the poses it was fitted to).
//! The residuals `W (θ_b − μ)` are linear: their Jacobian is `W`, dense over the rotation entries.
//!
//! Fitted by [`PosePrior::fit`] (what `lfit motion prior` runs on motion files); applied when an
//! [`super::EnergyConfig`] carries one, weighted by `weights.pose_prior`.

use serde::{Deserialize, Serialize};

use crate::error::{ModelError, Result};
use crate::pose::rot_offset;
use crate::template::Template;

/// Default regularisation of a fitted prior's covariance, radians: `Σ + ε² I`. Ours: a joint axis
/// the poses never move gets a standard deviation of ε (3°) instead of a singular covariance,
/// and no axis is held tighter than that.
pub const DEFAULT_PRIOR_EPSILON: f64 = 3.0 * std::f64::consts::PI / 180.0;

/// A Gaussian over the non-root joint rotations (see the module documentation).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PosePrior {
    /// What it was fitted to (motion files, frame count, ε): for the record.
    pub source: String,
    /// The joints it covers, in the model's order (every joint but the root): a model with
    /// other joints is refused.
    pub joints: Vec<String>,
    /// `μ`: three axis-angle entries per joint.
    pub mean: Vec<f64>,
    /// `W = L⁻¹`, `n × n` row by row (lower triangular), `n = 3 × joints`.
    pub whitening: Vec<f64>,
}

impl PosePrior {
    /// Number of rotation entries it covers.
    pub fn len(&self) -> usize {
        self.mean.len()
    }

    pub fn is_empty(&self) -> bool {
        self.mean.is_empty()
    }

    /// The parameter entries it covers: every rotation entry after the root's.
    pub fn entries(&self) -> std::ops::Range<usize> {
        rot_offset(1)..rot_offset(1) + self.len()
    }

    /// Fits `μ` and `W` to poses (full parameter vectors in `template`'s layout, or their pose
    /// part: translation and rotations): the sample mean and covariance (divided by `T − 1`) of
    /// the non-root rotation entries, plus `ε² I`. Fails on fewer than two poses, a pose of
    /// another length or with a non-finite entry, or `ε ≤ 0`.
    pub fn fit(
        template: &Template,
        poses: &[Vec<f64>],
        epsilon: f64,
        source: impl Into<String>,
    ) -> Result<Self> {
        if !(epsilon.is_finite() && epsilon > 0.0) {
            return Err(ModelError::Setting {
                name: "epsilon",
                value: epsilon.to_string(),
                reason: "must be a positive number of radians".into(),
            });
        }
        if poses.len() < 2 {
            return Err(ModelError::Config(format!(
                "a pose prior needs at least two poses, got {}",
                poses.len()
            )));
        }
        let layout = template.layout();
        let (dim, pose_dim) = (layout.dim(), layout.pose_dim());
        let joints = Self::joints_of(template);
        let range = rot_offset(1)..rot_offset(1) + 3 * joints.len();
        let n = range.len();
        for (k, p) in poses.iter().enumerate() {
            if p.len() != dim && p.len() != pose_dim {
                return Err(ModelError::Shape {
                    what: format!("pose {k}"),
                    expected: format!("{dim} (or {pose_dim} without shape)"),
                    got: p.len().to_string(),
                });
            }
            if let Some(i) = range.clone().find(|&i| !p[i].is_finite()) {
                return Err(ModelError::PoseNotFinite {
                    index: i,
                    value: p[i],
                });
            }
        }
        let t = poses.len() as f64;
        let mut mean = vec![0.0; n];
        for p in poses {
            for (m, x) in mean.iter_mut().zip(&p[range.clone()]) {
                *m += x;
            }
        }
        mean.iter_mut().for_each(|m| *m /= t);
        let mut cov = nalgebra::DMatrix::<f64>::zeros(n, n);
        let mut d = vec![0.0; n];
        for p in poses {
            for ((di, x), m) in d.iter_mut().zip(&p[range.clone()]).zip(&mean) {
                *di = x - m;
            }
            for a in 0..n {
                for b in 0..=a {
                    cov[(a, b)] += d[a] * d[b];
                }
            }
        }
        for a in 0..n {
            for b in 0..=a {
                let v = cov[(a, b)] / (t - 1.0);
                cov[(a, b)] = v;
                cov[(b, a)] = v;
            }
            cov[(a, a)] += epsilon * epsilon;
        }
        // Σ + ε²I is positive definite: its Cholesky factor exists.
        let l = nalgebra::Cholesky::new(cov)
            .ok_or_else(|| {
                ModelError::Config("the poses' covariance is not positive definite".into())
            })?
            .l();
        let w = l
            .solve_lower_triangular(&nalgebra::DMatrix::identity(n, n))
            .ok_or_else(|| ModelError::Config("the covariance's factor is singular".into()))?;
        let whitening = (0..n)
            .flat_map(|a| (0..n).map(move |b| (a, b)))
            .map(|(a, b)| if b <= a { w[(a, b)] } else { 0.0 })
            .collect();
        let prior = Self {
            source: source.into(),
            joints,
            mean,
            whitening,
        };
        prior.check(template)?;
        Ok(prior)
    }

    fn joints_of(template: &Template) -> Vec<String> {
        template.rig.joints[1..]
            .iter()
            .map(|j| j.name.clone())
            .collect()
    }

    /// Fails unless the prior fits `template` (the same non-root joints in the same order) and
    /// its numbers are finite with a whitening of `n × n`.
    pub fn check(&self, template: &Template) -> Result<()> {
        let model = &template.rig.joints[1..];
        // Every frame's energy checks its prior: the names are compared without copying them.
        if !self.joints.iter().eq(model.iter().map(|j| &j.name)) {
            let joints = Self::joints_of(template);
            let first = self
                .joints
                .iter()
                .zip(&joints)
                .position(|(a, b)| a != b)
                .unwrap_or(self.joints.len().min(joints.len()));
            return Err(ModelError::Config(format!(
                "the pose prior was fitted to another skeleton: {} joints against the model's {} non-root joints, first difference at joint {} ('{}' vs '{}')",
                self.joints.len(),
                joints.len(),
                first + 1,
                self.joints.get(first).map_or("none", String::as_str),
                joints.get(first).map_or("none", String::as_str),
            )));
        }
        let n = 3 * model.len();
        if self.mean.len() != n || self.whitening.len() != n * n {
            return Err(ModelError::Shape {
                what: "pose prior".into(),
                expected: format!("{n} means and a {n} × {n} whitening"),
                got: format!(
                    "{} means and {} whitening entries",
                    self.mean.len(),
                    self.whitening.len()
                ),
            });
        }
        if self
            .mean
            .iter()
            .chain(&self.whitening)
            .any(|v| !v.is_finite())
        {
            return Err(ModelError::Config(
                "the pose prior holds a non-finite number".into(),
            ));
        }
        Ok(())
    }

    /// The residuals `W (θ_b − μ)` scaled by `c0` (lower-triangular: row `a` reads entries ≤ a).
    pub(crate) fn residuals(&self, params: &[f64], c0: f64, out: &mut [f64]) {
        let n = self.len();
        let theta = &params[self.entries()];
        for (a, o) in out.iter_mut().enumerate().take(n) {
            let row = &self.whitening[a * n..a * n + a + 1];
            *o = c0
                * row
                    .iter()
                    .zip(theta)
                    .zip(&self.mean)
                    .map(|((w, x), m)| w * (x - m))
                    .sum::<f64>();
        }
    }

    /// Row `a` of the Jacobian of [`PosePrior::residuals`] over the rotation entries it covers:
    /// `c0 W[a, ..]`, nonzero up to entry `a`.
    pub(crate) fn jacobian_row(&self, a: usize) -> &[f64] {
        let n = self.len();
        &self.whitening[a * n..a * n + a + 1]
    }

    /// `‖W (θ_b − μ)‖²` of a full parameter vector: the squared Mahalanobis distance of its
    /// rotations (what the energy's term is, unweighted).
    pub fn mahalanobis(&self, params: &[f64]) -> f64 {
        self.evaluate(params, None)
    }

    /// `‖W (θ_b − μ)‖²` and, when asked, adds `2 weight Wᵀ W (θ_b − μ)` to `grad`.
    pub(crate) fn evaluate(&self, params: &[f64], grad: Option<(&mut [f64], f64)>) -> f64 {
        let mut r = vec![0.0; self.len()];
        self.residuals(params, 1.0, &mut r);
        if let Some((grad, weight)) = grad {
            let first = self.entries().start;
            for (a, ra) in r.iter().enumerate() {
                for (b, w) in self.jacobian_row(a).iter().enumerate() {
                    grad[first + b] += 2.0 * weight * w * ra;
                }
            }
        }
        r.iter().map(|x| x * x).sum()
    }
}

/// Serde for `Option<Arc<PosePrior>>` (the energy configuration is cloned per frame; the prior
/// is shared), written as the prior itself.
pub(crate) mod shared {
    use std::sync::Arc;

    use serde::{Deserialize, Deserializer, Serialize, Serializer};

    use super::PosePrior;

    pub fn serialize<S: Serializer>(v: &Option<Arc<PosePrior>>, s: S) -> Result<S::Ok, S::Error> {
        v.as_deref().serialize(s)
    }

    pub fn deserialize<'de, D: Deserializer<'de>>(
        d: D,
    ) -> Result<Option<Arc<PosePrior>>, D::Error> {
        Ok(Option::<PosePrior>::deserialize(d)?.map(Arc::new))
    }
}
