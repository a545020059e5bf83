//! A Gaussian — or a mixture of Gaussians — over the body's joint rotations, fitted to captured
//! poses.
//!
//! EA (papers/000 eq. 7) is zero inside the joint limits: inside them the energy prefers no pose
//! over another, and a joint the observations leave open (a foot whose markers are missing, a
//! twist no marker sees) goes wherever the data's noise puts it. SMPLify (Bogo et al. 2016, eq. 4)
//! adds a mixture of Gaussians over the joint rotations fitted to CMU motion capture, over every
//! joint but the root (a person faces any direction: the root orientation and translation stay
//! free). Each component `k` is stored as weight `w_k`, mean `μ_k` and whitening `W_k = L_k⁻¹`
//! (`L_k L_kᵀ = Σ_k + ε² I`, so `W_kᵀW_k = (Σ_k + ε² I)⁻¹`). The term is SMPLify's max-mixture
//! approximation of the negative log-likelihood (times two, up to a constant):
//!
//! `E_pose-prior = min_k ( ‖W_k (θ_b − μ_k)‖² + c_k )`, `c_k = −2 log w_k − 2 log det W_k − min_j(…)`
//!
//! so that `min_k c_k = 0`. With one component it is the squared Mahalanobis distance (`n` on
//! average over the poses it was fitted to). Its residuals are those of the component that
//! attains the minimum: `W_k (θ_b − μ_k)`, linear with Jacobian `W_k` (dense over the rotation
//! entries), plus — for a mixture — one constant row `√c_k`. The energy is continuous where the
//! active component changes; its derivatives are those of the active component.
//!
//! Fitted by [`PosePrior::fit`] (one Gaussian) or [`PosePrior::fit_mixture`] (EM, SMPLify's 8
//! components) — what `lfit motion prior` runs on motion files; applied when an
//! [`super::EnergyConfig`] carries one, weighted by `weights.pose_prior`. Its numbers are checked
//! once, where it is built or read; [`PosePrior::check`] (every energy) compares the skeleton.

use rand::{Rng, SeedableRng};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::error::{ModelError, Result};
use crate::pose::rot_offset;
use crate::template::Template;

/// Default regularisation of a fitted prior's covariance, radians: `Σ + ε² I`. Ours: a joint axis
/// the poses never move gets a standard deviation of ε (3°) instead of a singular covariance,
/// and no axis is held tighter than that.
pub const DEFAULT_PRIOR_EPSILON: f64 = 3.0 * std::f64::consts::PI / 180.0;

/// SMPLify's number of mixture components (Bogo et al. 2016, §3.2: 8 Gaussians fitted to CMU).
pub const SMPLIFY_COMPONENTS: usize = 8;

/// Most EM iterations of [`PosePrior::fit_mixture`].
pub const MIXTURE_MAX_ITERATIONS: usize = 300;

/// EM stops when the mean log-likelihood per pose changes by less than this (scikit-learn's
/// `GaussianMixture` default tolerance, 1e-3, on the same quantity).
pub const MIXTURE_TOLERANCE: f64 = 1e-3;

/// One Gaussian of a [`PosePrior`].
#[derive(Debug, Clone, PartialEq)]
pub struct PriorComponent {
    weight: f64,
    mean: Vec<f64>,
    whitening: Vec<f64>,
    /// `c_k` (module documentation): `≥ 0`, zero for the most probable component's centre.
    penalty: f64,
    /// `W_kᵀ W_k` (`n × n`, row-major): the `JᵀJ` of the component's rows, which does not
    /// depend on the pose (LM's normal equations add it instead of the rows' products).
    gram: std::sync::Arc<Vec<f64>>,
}

impl PriorComponent {
    /// Mixture weight `w_k` (the weights sum to 1).
    pub fn weight(&self) -> f64 {
        self.weight
    }

    /// `μ_k`: three axis-angle entries per joint.
    pub fn mean(&self) -> &[f64] {
        &self.mean
    }

    /// `W_k = L_k⁻¹`, `n × n` row by row (lower triangular).
    pub fn whitening(&self) -> &[f64] {
        &self.whitening
    }

    /// `c_k`, the component's constant in the term (0 for a single Gaussian).
    pub fn penalty(&self) -> f64 {
        self.penalty
    }

    /// `W_kᵀ W_k` (`n × n`, row-major, symmetric): `(Σ_k + ε² I)⁻¹`.
    pub fn gram(&self) -> std::sync::Arc<Vec<f64>> {
        self.gram.clone()
    }

    /// `W_k (θ_b − μ_k)` into `out` (length n).
    fn whiten(&self, theta: &[f64], out: &mut [f64]) {
        let n = self.mean.len();
        for (a, o) in out.iter_mut().enumerate().take(n) {
            *o = self.whitening[a * n..a * n + a + 1]
                .iter()
                .zip(theta)
                .zip(&self.mean)
                .map(|((w, x), m)| w * (x - m))
                .sum::<f64>();
        }
    }
}

/// A prior over the non-root joint rotations (see the module documentation). Built by
/// [`PosePrior::fit`], [`PosePrior::fit_mixture`], [`PosePrior::new`] or read from JSON, each of
/// which checks its numbers.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(try_from = "PriorFile", into = "PriorFile")]
pub struct PosePrior {
    source: String,
    joints: Vec<String>,
    components: Vec<PriorComponent>,
}

/// How [`PosePrior::fit_mixture`]'s EM ended.
#[derive(Debug, Clone, PartialEq)]
pub struct MixtureFit {
    /// EM iterations run.
    pub iterations: usize,
    /// Whether the mean log-likelihood settled within [`MIXTURE_TOLERANCE`].
    pub converged: bool,
    /// Mean log-likelihood per pose of the poses under the fitted mixture (nats).
    pub log_likelihood: f64,
    /// Components asked for that ended with less than one pose's responsibility and were
    /// dropped.
    pub dropped: usize,
}

/// The JSON form: one Gaussian as `mean` and `whitening` (the form of the first release), a
/// mixture as `components`.
#[derive(Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct PriorFile {
    source: String,
    joints: Vec<String>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    mean: Option<Vec<f64>>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    whitening: Option<Vec<f64>>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    components: Option<Vec<ComponentFile>>,
}

#[derive(Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct ComponentFile {
    weight: f64,
    mean: Vec<f64>,
    whitening: Vec<f64>,
}

impl TryFrom<PriorFile> for PosePrior {
    type Error = ModelError;

    fn try_from(f: PriorFile) -> Result<Self> {
        let components = match (f.mean, f.whitening, f.components) {
            (Some(mean), Some(whitening), None) => vec![(1.0, mean, whitening)],
            (None, None, Some(c)) => c
                .into_iter()
                .map(|c| (c.weight, c.mean, c.whitening))
                .collect(),
            _ => {
                return Err(ModelError::Config(
                    "a pose prior holds either `mean` and `whitening` (one Gaussian) or `components` (a mixture)".into(),
                ));
            }
        };
        PosePrior::new(f.source, f.joints, components)
    }
}

impl From<PosePrior> for PriorFile {
    fn from(p: PosePrior) -> Self {
        let (source, joints) = (p.source, p.joints);
        match <[PriorComponent; 1]>::try_from(p.components) {
            Ok([c]) => Self {
                source,
                joints,
                mean: Some(c.mean),
                whitening: Some(c.whitening),
                components: None,
            },
            Err(components) => Self {
                source,
                joints,
                mean: None,
                whitening: None,
                components: Some(
                    components
                        .into_iter()
                        .map(|c| ComponentFile {
                            weight: c.weight,
                            mean: c.mean,
                            whitening: c.whitening,
                        })
                        .collect(),
                ),
            },
        }
    }
}

impl PosePrior {
    /// A prior over `joints` (every joint of the model but the root, in its order) from its
    /// components `(w_k, μ_k, W_k)`: `n = 3 × joints` means and an `n × n` lower-triangular
    /// whitening with a positive diagonal each, every number finite, weights positive and summing
    /// to 1 (within 1e-6; then normalised).
    pub fn new(
        source: impl Into<String>,
        joints: Vec<String>,
        components: Vec<(f64, Vec<f64>, Vec<f64>)>,
    ) -> Result<Self> {
        let n = 3 * joints.len();
        if n == 0 || components.is_empty() {
            return Err(ModelError::Config(format!(
                "a pose prior needs at least one joint and one component, got {} and {}",
                joints.len(),
                components.len()
            )));
        }
        let total: f64 = components.iter().map(|c| c.0).sum();
        let mut log_terms = Vec::with_capacity(components.len());
        for (k, (weight, mean, whitening)) in components.iter().enumerate() {
            if mean.len() != n || whitening.len() != n * n {
                return Err(ModelError::Shape {
                    what: format!("pose prior component {k}"),
                    expected: format!("{n} means and a {n} × {n} whitening"),
                    got: format!(
                        "{} means and {} whitening entries",
                        mean.len(),
                        whitening.len()
                    ),
                });
            }
            if !(weight.is_finite() && *weight > 0.0)
                || mean.iter().chain(whitening).any(|v| !v.is_finite())
            {
                return Err(ModelError::Config(format!(
                    "the pose prior's component {k} holds a non-finite number or a weight that is not positive"
                )));
            }
            if (0..n).any(|a| whitening[a * n + a] <= 0.0)
                || (0..n).any(|a| {
                    whitening[a * n + a + 1..(a + 1) * n]
                        .iter()
                        .any(|&v| v != 0.0)
                })
            {
                return Err(ModelError::Config(format!(
                    "the pose prior's component {k} has a whitening that is not lower triangular with a positive diagonal"
                )));
            }
            // −2 log w_k − 2 log det W_k (W_k triangular: its determinant is its diagonal's product).
            let log_det: f64 = (0..n).map(|a| whitening[a * n + a].ln()).sum();
            log_terms.push(-2.0 * (weight / total).ln() - 2.0 * log_det);
        }
        if (total - 1.0).abs() > 1e-6 {
            return Err(ModelError::Config(format!(
                "the pose prior's component weights sum to {total}, not 1"
            )));
        }
        let least = log_terms.iter().copied().fold(f64::INFINITY, f64::min);
        let single = components.len() == 1;
        let components = components
            .into_iter()
            .zip(log_terms)
            .map(|((weight, mean, whitening), c)| PriorComponent {
                weight: weight / total,
                gram: std::sync::Arc::new(gram_of(&whitening, n)),
                mean,
                whitening,
                penalty: if single { 0.0 } else { c - least },
            })
            .collect();
        Ok(Self {
            source: source.into(),
            joints,
            components,
        })
    }

    /// What it was fitted to (motion files, frame count, ε, components): for the record.
    pub fn source(&self) -> &str {
        &self.source
    }

    /// The joints it covers, in the model's order (every joint but the root).
    pub fn joints(&self) -> &[String] {
        &self.joints
    }

    /// Its Gaussians (one for [`PosePrior::fit`]).
    pub fn components(&self) -> &[PriorComponent] {
        &self.components
    }

    /// Number of rotation entries it covers.
    pub fn len(&self) -> usize {
        3 * self.joints.len()
    }

    pub fn is_empty(&self) -> bool {
        self.joints.is_empty()
    }

    /// Rows of its least-squares form: one per rotation entry, and for a mixture one more (the
    /// active component's constant `√c_k`).
    pub fn rows(&self) -> usize {
        self.len() + usize::from(self.components.len() > 1)
    }

    /// The parameter entries it covers: every rotation entry after the root's.
    pub fn entries(&self) -> std::ops::Range<usize> {
        rot_offset(1)..rot_offset(1) + self.len()
    }

    /// Fits one Gaussian to poses (full parameter vectors in `template`'s layout, or their pose
    /// part: translation and rotations): the sample mean and covariance (divided by `T − 1`) of
    /// the non-root rotation entries, plus `ε² I`. Fails on fewer than two poses, a pose of
    /// another length or with a non-finite entry, or `ε ≤ 0`.
    pub fn fit(
        template: &Template,
        poses: &[Vec<f64>],
        epsilon: f64,
        source: impl Into<String>,
    ) -> Result<Self> {
        let (joints, x) = Self::rotations(template, poses, epsilon, 2)?;
        let n = 3 * joints.len();
        let t = x.len() as f64;
        let mut mean = vec![0.0; n];
        for p in &x {
            for (m, v) in mean.iter_mut().zip(p) {
                *m += v;
            }
        }
        mean.iter_mut().for_each(|m| *m /= t);
        let mut cov = vec![0.0; n * n];
        let mut d = vec![0.0; n];
        for p in &x {
            for ((di, v), m) in d.iter_mut().zip(p).zip(&mean) {
                *di = v - m;
            }
            for a in 0..n {
                for b in 0..=a {
                    cov[a * n + b] += d[a] * d[b];
                }
            }
        }
        cov.iter_mut().for_each(|c| *c /= t - 1.0);
        let whitening = whitening_of(&cov, n, epsilon)?;
        Self::new(source, joints, vec![(1.0, mean, whitening)])
    }

    /// Fits a mixture of `components` Gaussians to poses (as [`PosePrior::fit`]) by
    /// expectation–maximisation: k-means++ seeding and ten Lloyd iterations from `seed`, then EM
    /// with full covariances, each plus `ε² I` (maximum likelihood: divided by the component's
    /// share of the poses), until the mean log-likelihood per pose changes by less than
    /// [`MIXTURE_TOLERANCE`] or after [`MIXTURE_MAX_ITERATIONS`]. A component left with less than
    /// one pose's responsibility is dropped. One component is [`PosePrior::fit`]. The same poses
    /// and seed give the same prior whatever the thread count. Fails as `fit` does, and on fewer
    /// than two poses per component.
    pub fn fit_mixture(
        template: &Template,
        poses: &[Vec<f64>],
        components: usize,
        epsilon: f64,
        seed: u64,
        source: impl Into<String>,
    ) -> Result<(Self, MixtureFit)> {
        if components == 0 {
            return Err(ModelError::Setting {
                name: "components",
                value: "0".into(),
                reason: "a mixture needs at least one component".into(),
            });
        }
        if components == 1 {
            let prior = Self::fit(template, poses, epsilon, source)?;
            let log_likelihood = prior.log_likelihood(poses);
            return Ok((
                prior,
                MixtureFit {
                    iterations: 0,
                    converged: true,
                    log_likelihood,
                    dropped: 0,
                },
            ));
        }
        let (joints, x) = Self::rotations(template, poses, epsilon, 2 * components)?;
        let n = 3 * joints.len();
        let mut resp = kmeans_responsibilities(&x, components, seed);
        let mut k = components;
        let mut previous = f64::NEG_INFINITY;
        let mut fit = MixtureFit {
            iterations: 0,
            converged: false,
            log_likelihood: f64::NEG_INFINITY,
            dropped: 0,
        };
        let mut model;
        loop {
            model = m_step(&x, &resp, k, n, epsilon)?;
            if model.len() < k {
                fit.dropped += k - model.len();
                k = model.len();
            }
            let (r, ll) = e_step(&x, &model, n);
            resp = r;
            fit.iterations += 1;
            fit.log_likelihood = ll;
            if (ll - previous).abs() < MIXTURE_TOLERANCE {
                fit.converged = true;
                break;
            }
            if fit.iterations >= MIXTURE_MAX_ITERATIONS {
                break;
            }
            previous = ll;
        }
        let components = model
            .into_iter()
            .map(|g| {
                let w = invert_lower(&g.l, n)?;
                Ok((g.weight, g.mean, w))
            })
            .collect::<Result<Vec<_>>>()?;
        Ok((Self::new(source, joints, components)?, fit))
    }

    /// The mean log-likelihood per pose of `poses` under the prior as a density (the mixture's,
    /// not its max approximation).
    pub fn log_likelihood(&self, poses: &[Vec<f64>]) -> f64 {
        let n = self.len();
        let half_log_2pi = 0.5 * (2.0 * std::f64::consts::PI).ln();
        let mut r = vec![0.0; n];
        let mut logs = vec![0.0; self.components.len()];
        // log w_k + log det W_k − (n/2) log 2π per component.
        let norms: Vec<f64> = self
            .components
            .iter()
            .map(|c| {
                let log_det: f64 = (0..n).map(|a| c.whitening[a * n + a].ln()).sum();
                c.weight.ln() + log_det - n as f64 * half_log_2pi
            })
            .collect();
        let mut total = 0.0;
        for p in poses {
            let theta = &p[self.entries()];
            for ((c, l), norm) in self.components.iter().zip(&mut logs).zip(&norms) {
                c.whiten(theta, &mut r);
                *l = norm - 0.5 * r.iter().map(|v| v * v).sum::<f64>();
            }
            total += log_sum_exp(&logs);
        }
        total / poses.len() as f64
    }

    /// The rotation entries of `poses` after checking them (and ε); at least `least` poses.
    fn rotations(
        template: &Template,
        poses: &[Vec<f64>],
        epsilon: f64,
        least: usize,
    ) -> Result<(Vec<String>, Vec<Vec<f64>>)> {
        if !(epsilon.is_finite() && epsilon > 0.0) {
            return Err(ModelError::Setting {
                name: "epsilon",
                value: epsilon.to_string(),
                reason: "must be a positive number of radians".into(),
            });
        }
        if poses.len() < least {
            return Err(ModelError::Config(format!(
                "a pose prior needs at least {least} poses{}, got {}",
                if least > 2 {
                    " (two per component)"
                } else {
                    ""
                },
                poses.len()
            )));
        }
        let layout = template.layout();
        let (dim, pose_dim) = (layout.dim(), layout.pose_dim());
        let joints = Self::joints_of(template);
        let range = rot_offset(1)..rot_offset(1) + 3 * joints.len();
        let mut x = Vec::with_capacity(poses.len());
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
            x.push(p[range.clone()].to_vec());
        }
        Ok((joints, x))
    }

    fn joints_of(template: &Template) -> Vec<String> {
        template.rig.joints[1..]
            .iter()
            .map(|j| j.name.clone())
            .collect()
    }

    /// Fails unless the prior fits `template`: the same non-root joints in the same order (its
    /// sizes follow from them and its numbers were checked when it was built).
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
        Ok(())
    }

    /// The active component at `params` (the first attaining `min_k ‖W_k (θ_b − μ_k)‖² + c_k`),
    /// with its whitened residual left in `r` and its squared norm.
    fn active(&self, params: &[f64], r: &mut [f64]) -> (usize, f64) {
        let theta = &params[self.entries()];
        let [only] = self.components.as_slice() else {
            let mut scratch = vec![0.0; r.len()];
            let mut best = (0, f64::INFINITY, f64::INFINITY);
            for (k, c) in self.components.iter().enumerate() {
                c.whiten(theta, &mut scratch);
                let d = scratch.iter().map(|v| v * v).sum::<f64>();
                if d + c.penalty < best.1 {
                    best = (k, d + c.penalty, d);
                    r.copy_from_slice(&scratch);
                }
            }
            return (best.0, best.2);
        };
        only.whiten(theta, r);
        (0, r.iter().map(|v| v * v).sum())
    }

    /// The residuals of the active component scaled by `c0` into `out` ([`PosePrior::rows`]
    /// long); returns the component.
    pub(crate) fn residuals(&self, params: &[f64], c0: f64, out: &mut [f64]) -> usize {
        let n = self.len();
        let (k, _) = self.active(params, &mut out[..n]);
        out[..n].iter_mut().for_each(|v| *v *= c0);
        if self.components.len() > 1 {
            out[n] = c0 * self.components[k].penalty.sqrt();
        }
        k
    }

    /// Row `a` of the Jacobian of [`PosePrior::residuals`] over the rotation entries it covers
    /// when component `k` is active: `W_k[a, ..]`, nonzero up to entry `a` (the constant row has
    /// none).
    pub(crate) fn jacobian_row(&self, k: usize, a: usize) -> &[f64] {
        let n = self.len();
        &self.components[k].whitening[a * n..a * n + a + 1]
    }

    /// The term's value at a full parameter vector, unweighted: `min_k ‖W_k (θ_b − μ_k)‖² + c_k`
    /// (for one Gaussian the squared Mahalanobis distance of the rotations).
    pub fn value(&self, params: &[f64]) -> f64 {
        self.evaluate(params, None)
    }

    /// The squared Mahalanobis distance `‖W_k (θ_b − μ_k)‖²` to the active component, and which
    /// component that is.
    pub fn mahalanobis(&self, params: &[f64]) -> (usize, f64) {
        let mut r = vec![0.0; self.len()];
        self.active(params, &mut r)
    }

    /// The term's value and, when asked, adds `2 weight W_kᵀ W_k (θ_b − μ_k)` (the active
    /// component's) to `grad`.
    pub(crate) fn evaluate(&self, params: &[f64], grad: Option<(&mut [f64], f64)>) -> f64 {
        let mut r = vec![0.0; self.len()];
        let (k, d) = self.active(params, &mut r);
        if let Some((grad, weight)) = grad {
            let first = self.entries().start;
            for (a, ra) in r.iter().enumerate() {
                for (b, w) in self.jacobian_row(k, a).iter().enumerate() {
                    grad[first + b] += 2.0 * weight * w * ra;
                }
            }
        }
        d + self.components[k].penalty
    }
}

/// `WᵀW` of a lower-triangular `n × n` `W` (row by row): entry `(a, b)` sums rows `c ≥ max(a, b)`.
fn gram_of(w: &[f64], n: usize) -> Vec<f64> {
    let mut g = vec![0.0; n * n];
    for c in 0..n {
        let row = &w[c * n..c * n + c + 1];
        for (a, &wa) in row.iter().enumerate() {
            for (b, &wb) in row.iter().enumerate().skip(a) {
                g[a * n + b] += wa * wb;
            }
        }
    }
    for a in 0..n {
        for b in a + 1..n {
            g[b * n + a] = g[a * n + b];
        }
    }
    g
}

/// `log Σ exp(v)`, stable.
fn log_sum_exp(v: &[f64]) -> f64 {
    let m = v.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    if m == f64::NEG_INFINITY {
        return m;
    }
    m + v.iter().map(|x| (x - m).exp()).sum::<f64>().ln()
}

/// `W = L⁻¹` for `L Lᵀ = cov + ε² I` (`cov` row by row, its lower triangle read).
fn whitening_of(cov: &[f64], n: usize, epsilon: f64) -> Result<Vec<f64>> {
    let l = cholesky(cov, n, epsilon)?;
    invert_lower(&l, n)
}

/// The Cholesky factor of `cov + ε² I` (lower triangle of `cov` read), row by row.
fn cholesky(cov: &[f64], n: usize, epsilon: f64) -> Result<Vec<f64>> {
    let m = nalgebra::DMatrix::from_fn(n, n, |a, b| {
        let (i, j) = if b <= a { (a, b) } else { (b, a) };
        cov[i * n + j] + if a == b { epsilon * epsilon } else { 0.0 }
    });
    // Σ + ε²I is positive definite: its Cholesky factor exists.
    let l = nalgebra::Cholesky::new(m)
        .ok_or_else(|| ModelError::Config("the poses' covariance is not positive definite".into()))?
        .l();
    Ok((0..n)
        .flat_map(|a| (0..n).map(move |b| (a, b)))
        .map(|(a, b)| if b <= a { l[(a, b)] } else { 0.0 })
        .collect())
}

/// `L⁻¹` of a lower-triangular `L` (row by row), lower triangular.
fn invert_lower(l: &[f64], n: usize) -> Result<Vec<f64>> {
    let m = nalgebra::DMatrix::from_fn(n, n, |a, b| l[a * n + b]);
    let w = m
        .solve_lower_triangular(&nalgebra::DMatrix::identity(n, n))
        .ok_or_else(|| ModelError::Config("the covariance's factor is singular".into()))?;
    Ok((0..n)
        .flat_map(|a| (0..n).map(move |b| (a, b)))
        .map(|(a, b)| if b <= a { w[(a, b)] } else { 0.0 })
        .collect())
}

/// One Gaussian of EM: weight, mean and the Cholesky factor of its covariance (+ ε² I).
struct Gaussian {
    weight: f64,
    mean: Vec<f64>,
    l: Vec<f64>,
    /// `log w − Σ log L_aa − (n/2) log 2π`.
    log_norm: f64,
}

/// Hard responsibilities from k-means++ seeding and ten Lloyd iterations (T × K, row by row).
fn kmeans_responsibilities(x: &[Vec<f64>], k: usize, seed: u64) -> Vec<f64> {
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    let dist = |a: &[f64], b: &[f64]| a.iter().zip(b).map(|(u, v)| (u - v) * (u - v)).sum::<f64>();
    let mut centres = vec![x[rng.random_range(0..x.len())].clone()];
    let mut d2: Vec<f64> = x.iter().map(|p| dist(p, &centres[0])).collect();
    while centres.len() < k {
        let total: f64 = d2.iter().sum();
        let pick = if total > 0.0 {
            let u = rng.random::<f64>() * total;
            let mut acc = 0.0;
            d2.iter()
                .position(|d| {
                    acc += d;
                    acc >= u
                })
                .unwrap_or(x.len() - 1)
        } else {
            rng.random_range(0..x.len())
        };
        centres.push(x[pick].clone());
        let c = centres.last().unwrap();
        for (d, p) in d2.iter_mut().zip(x) {
            *d = d.min(dist(p, c));
        }
    }
    let mut assign = vec![0; x.len()];
    for _ in 0..10 {
        assign = x
            .par_iter()
            .map(|p| {
                (0..k)
                    .map(|j| (j, dist(p, &centres[j])))
                    .fold((0, f64::INFINITY), |b, c| if c.1 < b.1 { c } else { b })
                    .0
            })
            .collect();
        for (j, c) in centres.iter_mut().enumerate() {
            let members: Vec<&Vec<f64>> = x
                .iter()
                .zip(&assign)
                .filter(|(_, a)| **a == j)
                .map(|(p, _)| p)
                .collect();
            if members.is_empty() {
                continue;
            }
            c.iter_mut().enumerate().for_each(|(i, v)| {
                *v = members.iter().map(|p| p[i]).sum::<f64>() / members.len() as f64;
            });
        }
    }
    let mut resp = vec![0.0; x.len() * k];
    for (t, a) in assign.iter().enumerate() {
        resp[t * k + a] = 1.0;
    }
    resp
}

/// EM's M step: each component's weight, mean and covariance (+ ε² I) from the
/// responsibilities; components with less than one pose's responsibility are left out.
fn m_step(x: &[Vec<f64>], resp: &[f64], k: usize, n: usize, epsilon: f64) -> Result<Vec<Gaussian>> {
    let t = x.len();
    let half_log_2pi = 0.5 * (2.0 * std::f64::consts::PI).ln();
    let fitted: Vec<Option<Result<(f64, Vec<f64>, Vec<f64>)>>> = (0..k)
        .into_par_iter()
        .map(|j| {
            let share: f64 = (0..t).map(|s| resp[s * k + j]).sum();
            if share < 1.0 {
                return None;
            }
            let mut mean = vec![0.0; n];
            for (s, p) in x.iter().enumerate() {
                let r = resp[s * k + j];
                if r > 0.0 {
                    mean.iter_mut().zip(p).for_each(|(m, v)| *m += r * v);
                }
            }
            mean.iter_mut().for_each(|m| *m /= share);
            let mut cov = vec![0.0; n * n];
            let mut d = vec![0.0; n];
            for (s, p) in x.iter().enumerate() {
                let r = resp[s * k + j];
                // Responsibilities below 1e-12 add nothing a covariance of ε = 3° would notice.
                if r < 1e-12 {
                    continue;
                }
                d.iter_mut()
                    .zip(p)
                    .zip(&mean)
                    .for_each(|((di, v), m)| *di = v - m);
                for a in 0..n {
                    let ra = r * d[a];
                    for (c, db) in cov[a * n..a * n + a + 1].iter_mut().zip(&d) {
                        *c += ra * db;
                    }
                }
            }
            cov.iter_mut().for_each(|c| *c /= share);
            Some(cholesky(&cov, n, epsilon).map(|l| (share, mean, l)))
        })
        .collect();
    let kept = fitted.into_iter().flatten().collect::<Result<Vec<_>>>()?;
    // The weights of the components kept: their shares of the poses they hold (a dropped
    // component's share is the kept ones' no more).
    let total: f64 = kept.iter().map(|c| c.0).sum();
    Ok(kept
        .into_iter()
        .map(|(share, mean, l)| {
            let log_diag: f64 = (0..n).map(|a| l[a * n + a].ln()).sum();
            let weight = share / total;
            Gaussian {
                weight,
                mean,
                l,
                log_norm: weight.ln() - log_diag - n as f64 * half_log_2pi,
            }
        })
        .collect())
}

/// EM's E step: the responsibilities (T × K, row by row) and the mean log-likelihood per pose.
fn e_step(x: &[Vec<f64>], model: &[Gaussian], n: usize) -> (Vec<f64>, f64) {
    let k = model.len();
    let rows: Vec<(Vec<f64>, f64)> = x
        .par_iter()
        .map(|p| {
            let mut z = vec![0.0; n];
            let logs: Vec<f64> = model
                .iter()
                .map(|g| {
                    // z = L⁻¹ (x − μ) by forward substitution.
                    for a in 0..n {
                        let row = &g.l[a * n..a * n + a];
                        let s: f64 = row.iter().zip(&z).map(|(l, v)| l * v).sum();
                        z[a] = (p[a] - g.mean[a] - s) / g.l[a * n + a];
                    }
                    g.log_norm - 0.5 * z.iter().map(|v| v * v).sum::<f64>()
                })
                .collect();
            let lse = log_sum_exp(&logs);
            (logs.iter().map(|l| (l - lse).exp()).collect(), lse)
        })
        .collect();
    let mut resp = Vec::with_capacity(x.len() * k);
    let mut total = 0.0;
    for (r, l) in rows {
        resp.extend(r);
        total += l;
    }
    (resp, total / x.len() as f64)
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

#[cfg(test)]
mod tests {
    use super::*;

    /// EM's M step leaves out a component holding less than one pose and gives the others
    /// weights that sum to 1 (their shares of the poses they hold), so that the mixture is built.
    #[test]
    fn a_component_with_less_than_one_pose_is_dropped_and_the_weights_still_sum_to_one() {
        let n = 3;
        let x: Vec<Vec<f64>> = (0..10)
            .map(|i| vec![0.1 * i as f64, 0.2 * (i % 3) as f64, -0.05 * i as f64])
            .collect();
        // Three components: the third holds half a pose.
        let mut resp = vec![0.0; 10 * 3];
        for (t, row) in resp.chunks_mut(3).enumerate() {
            match t {
                0 => row.copy_from_slice(&[0.0, 0.5, 0.5]),
                t if t < 5 => row[0] = 1.0,
                _ => row[1] = 1.0,
            }
        }
        let model = m_step(&x, &resp, 3, n, 0.05).unwrap();
        assert_eq!(model.len(), 2);
        let total: f64 = model.iter().map(|g| g.weight).sum();
        assert!((total - 1.0).abs() < 1e-15, "{total}");
        assert!((model[0].weight - 4.0 / 9.5).abs() < 1e-15);
        let components = model
            .into_iter()
            .map(|g| Ok((g.weight, g.mean, invert_lower(&g.l, n)?)))
            .collect::<Result<Vec<_>>>()
            .unwrap();
        let joints = vec!["a".to_string()];
        PosePrior::new("test", joints, components).unwrap();
    }
}
