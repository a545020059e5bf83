//! The energy (SPEC §5): the one objective every fitter minimises.
//!
//! `E(θ) = Σ λ_term · term(θ)` with named terms. For `scan` these are the terms of papers/000
//! eq. (3): `EJ` (eq. 6), `ED` (eq. 4), `ES` (eq. 5), `EP` (eq. 8) and `EA` (eq. 7). Every other
//! modality has a `data` term computed from its observation model's prediction
//! ([`crate::observe::ObservationModel`]: a robust sum over its residual groups, or the model's
//! own data term such as papers/001's silhouette overlap) plus `EP` and `EA`.
//!
//! Everything is computed on the CPU in **f64**: the value, the per-term values and the exact
//! analytic gradient over the 57 pose entries (reverse mode through FK and linear blend skinning,
//! [`kinematics`]). f64 because the gradient is checked against central finite differences at
//! ~1e-6 relative accuracy and because L-BFGS line searches compare energies that differ in the
//! seventh digit near convergence; the cost over f32 is measured in `benches/energy.rs`.
//! Predictions are not computed here: the energy calls the sensor's observation model on a
//! [`crate::observe::PosedView`] of its kinematics, and its derivatives through
//! [`crate::observe::PoseGradient`] (reverse mode) and [`crate::observe::PoseJacobian`]
//! (forward mode, [`LeastSquares`]).
//!
//! Every evaluation goes through [`Energy::evaluate`], [`Energy::evaluate_with_gradient`] or
//! [`Energy::evaluate_batch`], which count evaluations and gradient evaluations.

mod capsules;
mod floor;
mod least_squares;
mod placement;
mod pose_prior;
mod prior;

use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};

use glam::{DMat3, DVec3, Vec3};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

pub use crate::observe::Scales;
pub use floor::{FloorForm, FloorPrior, SOLE_BAND_M, SOLE_CELL_M, sole_vertices};
pub use least_squares::{
    ChordSystem, DampedFactor, Envelope, JacobianRows, LeastSquares, PointFactors, RobustForm,
    damped_step, envelope_cholesky_solve, envelope_work, marquardt_scaling,
};
pub use placement::{KEYPOINT_OFFSET_STEPS, keypoint_offsets, marker_offsets, point_offsets};
pub use pose_prior::{
    DEFAULT_PRIOR_EPSILON, MIXTURE_MAX_ITERATIONS, MIXTURE_TOLERANCE, MixtureFit, PosePrior,
    PriorComponent, SMPLIFY_COMPONENTS,
};
pub use prior::AnglePrior;

use self::capsules::Capsules;
pub(crate) use self::prior::{AngleLimits, Penetration};
use crate::body::kinematics::{Adjoint, Kinematics, SkinTable, VertexSet};
use crate::camera::Camera;
use crate::error::{ModelError, Result};
use crate::observe::{
    Modality, ObservationModel, PoseGradient, PosedView, ResidualGroup, Sensor, SilhouetteSetup,
    closest_point_offset,
};
use crate::scan::{Mask, VoxelGrid, iou, render_silhouette};
use crate::skinning::vertex_normals;
use crate::stature::positive_metres;
use crate::template::Template;

/// Term weights λ. Defaults: papers/000 §4.1 (λJ = 0.1, λD = 1, λS = 0.01, λP = 1, λA = 1); the
/// sparse data term has weight 1.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Weights {
    pub data: f64,
    pub ej: f64,
    pub ed: f64,
    pub es: f64,
    pub ep: f64,
    pub ea: f64,
    /// Gaussian prior `Σ β²` of a morphable model's shape coefficients (unused without them;
    /// not written when at its default, so rigid-template configurations print as before).
    #[serde(skip_serializing_if = "is_default_shape_weight")]
    pub shape: f64,
    /// Gaussian prior `Σ ψ²` of the expression coefficients.
    #[serde(skip_serializing_if = "is_default_expression_weight")]
    pub expression: f64,
    /// Gaussian prior `Σ θ²` of the joint rotations (root included; not the translation):
    /// papers/002 eq. (9)'s `w_θ‖θ‖²`, the face energy's pose regulariser. Default 0 (off, and
    /// then not part of the energy's terms or residuals, so other energies are unchanged).
    #[serde(skip_serializing_if = "is_zero")]
    pub pose: f64,
    /// Weight of the pose prior fitted to captured poses ([`PosePrior`]; a term only
    /// when the configuration carries one). Default [`DEFAULT_POSE_PRIOR_WEIGHT`].
    #[serde(skip_serializing_if = "is_default_pose_prior_weight")]
    pub pose_prior: f64,
}

fn is_zero(w: &f64) -> bool {
    *w == 0.0
}

/// Default weight of the shape prior: ours. With the sparse data term a mean of squared
/// σ-normalised residuals (≈ 1 per group at 1σ), 0.01 lets ±3 standard deviations of shape cost
/// 0.09 per coefficient: weak next to the data, strong enough to keep unobserved directions near
/// the mean (papers/002 eq. 9 regularises Θ with a tuned `w‖Θ‖²` in the same way).
pub const DEFAULT_SHAPE_WEIGHT: f64 = 0.01;
/// Default weight of the expression prior (same reasoning as [`DEFAULT_SHAPE_WEIGHT`]).
pub const DEFAULT_EXPRESSION_WEIGHT: f64 = 0.01;

/// Default weight of the pose prior: see the measurement in
/// docs/results/captured-motion.md (round 22). Chosen on markers; see
/// [`default_pose_prior_weight`] for the other modalities.
pub const DEFAULT_POSE_PRIOR_WEIGHT: f64 = 0.01;

/// The pose prior's weight for keypoints2d, chosen on the CMU validation subject's keypoints2d
/// sequences (docs/results/captured-motion.md, round 23): its data term is scaled otherwise than
/// markers', and 0.01 pulls the joints off the keypoints (MPJPE 8.8 → 11.1 mm).
pub const KEYPOINTS2D_POSE_PRIOR_WEIGHT: f64 = 0.001;

/// The pose prior's default weight for a modality, where one was chosen by measurement:
/// markers [`DEFAULT_POSE_PRIOR_WEIGHT`], keypoints2d [`KEYPOINTS2D_POSE_PRIOR_WEIGHT`]. None
/// for hmd — with only the head and hands observed, every weight from 3e-5 to 0.01 made LM's
/// single frames worse on the CMU validation subject (57 → 70–84 mm V2V, round 23) — and for the
/// modalities it was not measured on.
pub fn default_pose_prior_weight(modality: crate::observe::Modality) -> Option<f64> {
    match modality {
        crate::observe::Modality::Markers => Some(DEFAULT_POSE_PRIOR_WEIGHT),
        crate::observe::Modality::Keypoints2d => Some(KEYPOINTS2D_POSE_PRIOR_WEIGHT),
        _ => None,
    }
}

fn is_default_pose_prior_weight(w: &f64) -> bool {
    *w == DEFAULT_POSE_PRIOR_WEIGHT
}

fn is_default_shape_weight(w: &f64) -> bool {
    *w == DEFAULT_SHAPE_WEIGHT
}

fn is_default_expression_weight(w: &f64) -> bool {
    *w == DEFAULT_EXPRESSION_WEIGHT
}

impl Default for Weights {
    fn default() -> Self {
        Self {
            data: 1.0,
            ej: 0.1,
            ed: 1.0,
            es: 0.01,
            ep: 1.0,
            ea: 1.0,
            shape: DEFAULT_SHAPE_WEIGHT,
            expression: DEFAULT_EXPRESSION_WEIGHT,
            pose: 0.0,
            pose_prior: DEFAULT_POSE_PRIOR_WEIGHT,
        }
    }
}

/// Robust norm of a residual group (a marker, a keypoint, a headset rotation ...), applied to the
/// group's residual divided by its noise scale σ: `s = ‖r‖ / σ`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "kebab-case")]
pub enum Robust {
    /// `ρ(s) = s²`.
    L2,
    /// `ρ(s) = s²` for `s ≤ δ`, `2δs − δ²` above (Huber, scaled to equal s² inside).
    Huber { delta: f64 },
    /// `ρ(s) = c² ln(1 + s²/c²)` (Cauchy / Lorentzian, as in SCOPE; ≈ s² for s ≪ c).
    Cauchy { c: f64 },
    /// `ρ(s) = s² / (1 + s²/c²)` (Geman–McClure, as in SCOPE; ≈ s² for s ≪ c, bounded by c²).
    GemanMcclure { c: f64 },
}

impl Robust {
    /// `ρ(s)` and `ρ'(s)/s` (so that `∂ρ/∂r = ρ'(s)/s · r/σ²`).
    #[inline]
    pub(crate) fn eval(self, s: f64) -> (f64, f64) {
        match self {
            Robust::Huber { delta } if s > delta => {
                (2.0 * delta * s - delta * delta, 2.0 * delta / s)
            }
            Robust::Cauchy { c } => {
                let x = s * s / (c * c);
                (c * c * x.ln_1p(), 2.0 / (1.0 + x))
            }
            Robust::GemanMcclure { c } => {
                let x = s * s / (c * c);
                (s * s / (1.0 + x), 2.0 / ((1.0 + x) * (1.0 + x)))
            }
            _ => (s * s, 2.0),
        }
    }

    /// The least-squares fold of the loss: `φ(s) = √ρ(s) / s` and `φ'(s)/s`. A residual group
    /// `u` (σ-normalised, `s = ‖u‖`) becomes `φ(s) u`, whose squared norm is exactly `ρ(s)`, with
    /// the exact Jacobian `(φ I + (φ'/s) u uᵀ) ∂u`. Every loss here is `s²` near 0, so `φ → 1`
    /// there; series keep small `s` free of cancellation.
    #[inline]
    pub(crate) fn fold(self, s: f64) -> (f64, f64) {
        match self {
            Robust::L2 => (1.0, 0.0),
            Robust::Huber { delta } => {
                if s <= delta {
                    (1.0, 0.0)
                } else {
                    let sq = (2.0 * delta * s - delta * delta).sqrt();
                    (sq / s, (delta / sq - sq / s) / (s * s))
                }
            }
            Robust::Cauchy { c } => {
                // g(x) = ln(1 + x)/x, φ = √g, φ'/s = g'(x) / (c² √g).
                let x = s * s / (c * c);
                let (g, dg) = if x < 1e-4 {
                    (1.0 - x / 2.0 + x * x / 3.0, -0.5 + 2.0 * x / 3.0)
                } else {
                    let l = x.ln_1p();
                    (l / x, (x / (1.0 + x) - l) / (x * x))
                };
                let sg = g.sqrt();
                (sg, dg / (c * c * sg))
            }
            Robust::GemanMcclure { c } => {
                let x = s * s / (c * c);
                let f = 1.0 / (1.0 + x).sqrt();
                (f, -f * f * f / (c * c))
            }
        }
    }
}

/// How the energy is put together. Print it with every result: two results are comparable only
/// when their energy configurations are equal.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct EnergyConfig {
    pub weights: Weights,
    /// Robust norm of the sparse data term. Default Huber with δ = 3σ.
    pub robust: Robust,
    pub scales: Scales,
    /// Form of EA. Default [`AnglePrior::Binary`] (papers/000 eq. 7).
    pub angle_prior: AnglePrior,
    /// Whether EJ (silhouette 1 − IoU, no gradient) is part of the `scan` energy.
    pub silhouettes: bool,
    /// Width in pixels at which EJ renders (heights keep the cameras' aspect ratio).
    pub silhouette_width: u32,
    /// EP tests every `penetration_stride`-th template vertex (default 16: 195 of the default
    /// template's 3,106, a coarse proxy like the paper's) in the vertex form; the capsule form
    /// is scaled against that form.
    pub penetration_stride: usize,
    /// How EP tests for self-penetration. Default [`PenetrationForm::Capsules`].
    pub penetration: PenetrationForm,
    /// A Gaussian (or a mixture) over the joint rotations fitted to captured poses (`lfit
    /// motion prior`), weighted by `weights.pose_prior`. Default none (and then not written).
    #[serde(skip_serializing_if = "Option::is_none", with = "pose_prior::shared")]
    pub pose_prior: Option<Arc<PosePrior>>,
}

/// The form of the self-penetration prior EP.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum PenetrationForm {
    /// Capsule against capsule: every segment's ellipsoid as the capsule along its long axis,
    /// `(1 − q)²₊` per pair of non-adjacent capsules, scaled to the vertex form (see
    /// `capsules.rs`). Reads the posed skeleton only: what the sparse energies use.
    #[default]
    Capsules,
    /// papers/000 eq. (8) as written: every `penetration_stride`-th vertex against the
    /// ellipsoids of the other segments (shapes and skins the tested vertices at every
    /// evaluation).
    Vertices,
}

impl Default for EnergyConfig {
    fn default() -> Self {
        Self {
            weights: Weights::default(),
            robust: Robust::Huber { delta: 3.0 },
            scales: Scales::default(),
            angle_prior: AnglePrior::Binary,
            silhouettes: true,
            silhouette_width: 128,
            penetration_stride: 16,
            penetration: PenetrationForm::default(),
            pose_prior: None,
        }
    }
}

impl EnergyConfig {
    /// The variant for gradient-based fitters (L-BFGS, the neural fitter): EJ off (it has no
    /// gradient) and the smooth hinge form of EA. A run reports which variant it used.
    pub fn for_gradient(mut self) -> Self {
        self.silhouettes = false;
        self.angle_prior = AnglePrior::Hinge;
        self
    }

    /// Whether every term of this configuration has a gradient.
    pub fn is_differentiable(&self) -> bool {
        !self.silhouettes && self.angle_prior == AnglePrior::Hinge
    }

    pub fn validate(&self) -> Result<()> {
        let w = &self.weights;
        for (name, v) in [
            ("weights.data", w.data),
            ("weights.ej", w.ej),
            ("weights.ed", w.ed),
            ("weights.es", w.es),
            ("weights.ep", w.ep),
            ("weights.ea", w.ea),
            ("weights.shape", w.shape),
            ("weights.expression", w.expression),
            ("weights.pose", w.pose),
            ("weights.pose_prior", w.pose_prior),
        ] {
            if !(v.is_finite() && v >= 0.0) {
                return Err(ModelError::Setting {
                    name,
                    value: v.to_string(),
                    reason: "must be a finite number ≥ 0".into(),
                });
            }
        }
        for (name, v) in [
            ("scales.position", self.scales.position),
            ("scales.pixel", self.scales.pixel),
            ("scales.rotation", self.scales.rotation),
        ] {
            if !(v.is_finite() && v > 0.0) {
                return Err(ModelError::Setting {
                    name,
                    value: v.to_string(),
                    reason: "must be positive".into(),
                });
            }
        }
        let (name, scale) = match self.robust {
            Robust::L2 => ("robust", 1.0),
            Robust::Huber { delta } => ("robust.delta", delta),
            Robust::Cauchy { c } | Robust::GemanMcclure { c } => ("robust.c", c),
        };
        if !(scale.is_finite() && scale > 0.0) {
            return Err(ModelError::Setting {
                name,
                value: scale.to_string(),
                reason: "must be positive".into(),
            });
        }
        if self.silhouette_width < 8 || self.silhouette_width > 4096 {
            return Err(ModelError::Setting {
                name: "silhouette_width",
                value: self.silhouette_width.to_string(),
                reason: "must be in 8..=4096".into(),
            });
        }
        if self.penetration_stride == 0 {
            return Err(ModelError::Setting {
                name: "penetration_stride",
                value: "0".into(),
                reason: "must be ≥ 1".into(),
            });
        }
        Ok(())
    }
}

/// What one frame's energy compares the template with.
#[derive(Debug, Clone)]
pub enum Target {
    /// A sparse modality's observation vector and visibility (layout of [`Sensor::predict_sparse`]).
    Sparse {
        values: Vec<f64>,
        visible: Vec<bool>,
    },
    /// `scan`: the target's squared distance transform and silhouettes (one per sensor camera).
    Scan {
        grid: VoxelGrid,
        silhouettes: Vec<Mask>,
    },
    /// `silhouettes`: the foreground mask of every sensor camera.
    Silhouettes { masks: Vec<Mask> },
}

/// Value and named (unweighted) terms of one evaluation; `total = Σ λ_term · term`.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Evaluation {
    pub total: f64,
    pub terms: Vec<(&'static str, f64)>,
}

impl Evaluation {
    pub fn term(&self, name: &str) -> Option<f64> {
        self.terms.iter().find(|(n, _)| *n == name).map(|&(_, v)| v)
    }
}

/// What an energy needs of its template that depends on nothing else (skinning table, rest
/// normals, EP's ellipsoids and clusters, EA's limits): built once per template and EP stride and
/// shared by every energy of it — an energy per frame costs no per-vertex work.
struct TemplateParts {
    skin: Arc<SkinTable>,
    rest_normals: Arc<Vec<DVec3>>,
    penetration: Arc<Penetration>,
    capsules: Arc<Capsules>,
    limits: Arc<AngleLimits>,
}

impl TemplateParts {
    /// The parts of `template` (by identity) and `stride`, from the cache or built. The cache
    /// holds a [`std::sync::Weak`] to the template: while it does, `Arc::get_mut` cannot alter
    /// the template in place, and `Arc::make_mut` moves it to a new allocation, so an entry never
    /// describes a template that changed. Entries of dropped templates are pruned.
    fn of(template: &Arc<Template>, stride: usize) -> Arc<Self> {
        type Entry = (std::sync::Weak<Template>, usize, Arc<TemplateParts>);
        static CACHE: std::sync::Mutex<Vec<Entry>> = std::sync::Mutex::new(Vec::new());
        let mut cache = CACHE
            .lock()
            .unwrap_or_else(|poisoned| poisoned.into_inner());
        cache.retain(|(weak, _, _)| weak.strong_count() > 0);
        let weak = Arc::downgrade(template);
        if let Some((_, _, parts)) = cache
            .iter()
            .find(|(w, s, _)| *s == stride && w.ptr_eq(&weak))
        {
            return parts.clone();
        }
        let penetration = Penetration::new(template, stride);
        let parts = Arc::new(Self {
            capsules: Arc::new(Capsules::new(template, &penetration)),
            skin: Arc::new(SkinTable::new(template)),
            rest_normals: Arc::new(
                vertex_normals(&template.vertices, &template.faces)
                    .iter()
                    .map(|n| n.as_dvec3())
                    .collect(),
            ),
            penetration: Arc::new(penetration),
            limits: Arc::new(AngleLimits::new(template)),
        });
        cache.push((weak, stride, parts.clone()));
        parts
    }
}

/// EJ's cameras (scaled to the render size) and target silhouettes (resampled to it).
#[derive(Debug, Clone)]
struct SilhouetteTerm {
    cameras: Vec<Camera>,
    targets: Vec<Mask>,
}

/// The energy of one frame: template, sensor, target and configuration, with evaluation counters.
#[derive(Debug)]
pub struct Energy {
    template: Arc<Template>,
    sensor: Sensor,
    target: Target,
    config: EnergyConfig,
    skin: Arc<SkinTable>,
    rest_normals: Arc<Vec<DVec3>>,
    groups: Vec<ResidualGroup>,
    penetration: Arc<Penetration>,
    capsules: Arc<Capsules>,
    limits: Arc<AngleLimits>,
    silhouettes: Option<SilhouetteTerm>,
    /// `silhouettes`: the observation model at the render width (the sensor's is full size).
    render: Option<SilhouetteSetup>,
    /// ES direction tensors per grid node (`scan` only), shared by clones.
    axes: Option<Arc<Vec<[f32; 6]>>>,
    /// The vertices the sensor reads ([`ObservationModel::vertices_read`]), shaped once per
    /// evaluation with derivatives.
    observed: Arc<VertexSet>,
    /// A pull of some entries toward given values ([`Energy::with_anchor`]); none by default.
    anchor: Option<Arc<Anchor>>,
    /// A prior on the subject's stature ([`Energy::with_height_prior`]); none by default.
    height: Option<Arc<HeightPrior>>,
    /// The ground plane ([`Energy::with_floor`]); none by default.
    floor: Option<Arc<FloorPrior>>,
    evaluations: AtomicU64,
    gradient_evaluations: AtomicU64,
}

/// The `anchor` term of [`Energy::with_anchor`]: `Σ_k a_k (θ_{i_k} − c_k)²` over some parameter
/// entries — a Gaussian centred on a given pose (another fit's result, the previous frame's),
/// written like the other priors as one residual row `√a_k (θ_{i_k} − c_k)` per entry.
#[derive(Debug, Clone, PartialEq)]
pub struct Anchor {
    /// `(entry, centre, weight a)` per row, in entry order.
    rows: Vec<(usize, f64, f64)>,
}

impl Anchor {
    /// `(entry, centre, weight)` per row of the term.
    pub fn rows(&self) -> &[(usize, f64, f64)] {
        &self.rows
    }

    /// The term's value at `pose`.
    pub fn value(&self, pose: &[f64]) -> f64 {
        self.rows
            .iter()
            .map(|&(i, c, a)| a * (pose[i] - c) * (pose[i] - c))
            .sum()
    }
}

/// The `height` term of [`Energy::with_height_prior`]: the subject's stature as one more
/// measurement, `((h(β) − H) / σ)²` with `h(β)` the rest mesh's height at the frame's shape
/// ([`crate::stature::rest_height`], sole to crown — what `--known-shape height:M` matches
/// exactly), weighted like one visible group of the data term (`λ_data / n`, `n` the visible
/// groups, at least 1): a Gaussian of standard deviation `σ` on the height in the posterior the
/// data term's likelihood makes. β stays free: the height fixes one direction of it, the
/// observations the others.
#[derive(Debug, Clone, PartialEq)]
pub struct HeightPrior {
    height_m: f64,
    std_m: f64,
    /// The template it was made for (`id`, vertex count), checked where it is used.
    template: (String, usize),
    vertices: Arc<crate::stature::StatureVertices>,
}

impl HeightPrior {
    /// A prior of `height_m` metres with standard deviation `std_m` on `template`'s rest height.
    /// One-line errors where the model has no shape coefficients or either number is not finite
    /// and positive.
    pub fn new(template: &Template, height_m: f64, std_m: f64) -> Result<Self> {
        if template.morph.shape == 0 {
            return Err(ModelError::Config(format!(
                "a height prior needs a model with shape coefficients: '{}' has none",
                template.id
            )));
        }
        Ok(Self {
            height_m: positive_metres("height prior", height_m)?,
            std_m: positive_metres("height prior standard deviation", std_m)?,
            template: (template.id.clone(), template.vertices.len()),
            vertices: Arc::new(crate::stature::StatureVertices::of(template)),
        })
    }

    /// A prior at the rest height of `template`'s mean shape (β = 0), standard deviation
    /// `std_m`: the base of priors whose height each frame gives ([`HeightPrior::at`]: a subject
    /// per frame, the truth's height in training). Fails like [`HeightPrior::new`].
    pub fn at_mean_shape(template: &Template, std_m: f64) -> Result<Self> {
        let (mean, ..) = crate::stature::rest_height(template, &[]);
        Self::new(template, mean, std_m)
    }

    /// The same prior (model, standard deviation, the vertices it reads) at another height: a
    /// subject per frame without measuring the mesh again. Fails like [`HeightPrior::new`] on a
    /// height that is not finite and positive.
    pub fn at(&self, height_m: f64) -> Result<Self> {
        Ok(Self {
            height_m: positive_metres("height prior", height_m)?,
            ..self.clone()
        })
    }

    /// The same prior with another standard deviation (`std_m`, finite and positive).
    pub fn with_std(&self, std_m: f64) -> Result<Self> {
        Ok(Self {
            std_m: positive_metres("height prior standard deviation", std_m)?,
            ..self.clone()
        })
    }

    /// The rest height of shape `beta` on the prior's model ([`crate::stature::rest_height`],
    /// from the vertices the prior reads).
    pub fn rest_height(&self, template: &Template, beta: &[f64]) -> f64 {
        self.vertices.height(template, beta).0
    }

    /// The prior's height (metres).
    pub fn height_m(&self) -> f64 {
        self.height_m
    }

    /// Its standard deviation (metres).
    pub fn std_m(&self) -> f64 {
        self.std_m
    }

    /// The rest height at the shape entries of `pose` and the gradient of it with respect to
    /// those entries (`with_gradient`; empty otherwise).
    fn measure(&self, template: &Template, pose: &[f64], with_gradient: bool) -> (f64, Vec<f64>) {
        let base = 3 + 3 * template.rig.num_joints();
        let beta = pose.get(base..base + template.morph.shape).unwrap_or(&[]);
        let (h, top, sole) = self.vertices.height(template, beta);
        let g = if with_gradient {
            crate::stature::height_gradient(template, top, sole)
        } else {
            Vec::new()
        };
        (h, g)
    }
}

impl Clone for Energy {
    /// A copy with fresh (zero) counters.
    fn clone(&self) -> Self {
        Self {
            template: self.template.clone(),
            sensor: self.sensor.clone(),
            target: self.target.clone(),
            config: self.config.clone(),
            skin: self.skin.clone(),
            rest_normals: self.rest_normals.clone(),
            groups: self.groups.clone(),
            penetration: self.penetration.clone(),
            capsules: self.capsules.clone(),
            limits: self.limits.clone(),
            silhouettes: self.silhouettes.clone(),
            render: self.render.clone(),
            axes: self.axes.clone(),
            observed: self.observed.clone(),
            anchor: self.anchor.clone(),
            height: self.height.clone(),
            floor: self.floor.clone(),
            evaluations: AtomicU64::new(0),
            gradient_evaluations: AtomicU64::new(0),
        }
    }
}

impl Energy {
    /// Builds the energy of one frame. Fails when the configuration is invalid, the sensor does
    /// not fit the template, the target has the wrong shape or modality, or a visible target
    /// value is not finite.
    pub fn new(
        template: Arc<Template>,
        sensor: Sensor,
        target: Target,
        config: EnergyConfig,
    ) -> Result<Self> {
        config.validate()?;
        if let Some(prior) = &config.pose_prior {
            prior.check(&template)?;
        }
        sensor.validate(&template)?;
        let dim = sensor.residual_dim(&template);
        let mut silhouettes = None;
        let mut render = None;
        let mut target = target;
        match (&sensor, &target) {
            (
                Sensor::Scan(setup),
                Target::Scan {
                    grid,
                    silhouettes: masks,
                },
            ) => {
                if grid.values.len() != grid.len() || grid.values.is_empty() {
                    return Err(ModelError::Target(format!(
                        "distance transform has {} values for {:?} nodes",
                        grid.values.len(),
                        grid.dims
                    )));
                }
                if let Some(i) = grid.values.iter().position(|v| !v.is_finite()) {
                    return Err(ModelError::Target(format!(
                        "distance transform value {i} is not finite"
                    )));
                }
                if !(grid.spacing.is_finite() && grid.spacing > 0.0)
                    || grid.origin.iter().any(|o| !o.is_finite())
                {
                    return Err(ModelError::Target(
                        "distance transform grid has a non-finite or non-positive origin/spacing"
                            .into(),
                    ));
                }
                check_masks(masks, &setup.cameras)?;
                if config.silhouettes {
                    silhouettes = Some(SilhouetteTerm::new(
                        &setup.cameras,
                        masks,
                        config.silhouette_width,
                    ));
                }
            }
            (Sensor::Silhouettes(setup), Target::Silhouettes { masks }) => {
                // The observation model at the render width, against the masks resampled to it.
                check_masks(masks, &setup.cameras)?;
                let term = SilhouetteTerm::new(&setup.cameras, masks, config.silhouette_width);
                let small = SilhouetteSetup {
                    cameras: term.cameras,
                };
                let values = small.values(&term.targets);
                let visible = vec![true; values.len()];
                target = Target::Sparse { values, visible };
                render = Some(small);
            }
            (Sensor::Scan(_), _) => {
                return Err(ModelError::Target(
                    "a scan energy needs a scan target".into(),
                ));
            }
            (Sensor::Silhouettes(_), _) => {
                return Err(ModelError::Target(
                    "a silhouettes energy needs one foreground mask per camera".into(),
                ));
            }
            (_, Target::Scan { .. } | Target::Silhouettes { .. }) => {
                return Err(ModelError::Target(format!(
                    "a {} energy needs a sparse target",
                    sensor.name()
                )));
            }
            (_, Target::Sparse { values, visible }) => {
                if values.len() != dim || visible.len() != dim {
                    return Err(ModelError::Shape {
                        what: format!("{} target", sensor.name()),
                        expected: dim.to_string(),
                        got: format!(
                            "{} values, {} visibility flags",
                            values.len(),
                            visible.len()
                        ),
                    });
                }
                if let Some(i) = (0..dim).find(|&i| visible[i] && !values[i].is_finite()) {
                    return Err(ModelError::Target(format!(
                        "visible target value {i} is not finite ({})",
                        values[i]
                    )));
                }
            }
        }
        let axes = match &target {
            Target::Scan { grid, .. } => Some(Arc::new(direction_tensors(grid))),
            Target::Sparse { .. } | Target::Silhouettes { .. } => None,
        };
        let parts = TemplateParts::of(&template, config.penetration_stride);
        let observed = Arc::new(VertexSet::new(&sensor.observation_model().vertices_read()));
        let mut energy = Self {
            limits: parts.limits.clone(),
            skin: parts.skin.clone(),
            rest_normals: parts.rest_normals.clone(),
            penetration: parts.penetration.clone(),
            capsules: parts.capsules.clone(),
            template,
            sensor,
            target,
            config,
            groups: Vec::new(),
            silhouettes,
            render,
            axes,
            observed,
            anchor: None,
            height: None,
            floor: None,
            evaluations: AtomicU64::new(0),
            gradient_evaluations: AtomicU64::new(0),
        };
        // Residual groups serve a vector target (`scan` compares a distance transform instead).
        if matches!(energy.target, Target::Sparse { .. }) {
            let m = energy.observation_model();
            let groups = m.groups(&energy.template, &energy.config.scales);
            check_groups(&groups, m.dim(&energy.template), m.name())?;
            energy.groups = groups;
        }
        Ok(energy)
    }

    /// The same energy (template, sensor, configuration and precomputed tables) with another
    /// sparse target; much cheaper than [`Energy::new`] when many frames share one setup.
    /// Fails like [`Energy::new`] on a target of the wrong shape or with a non-finite visible
    /// value, or on a `scan` energy.
    pub fn with_target(&self, values: Vec<f64>, visible: Vec<bool>) -> Result<Self> {
        if matches!(self.sensor, Sensor::Scan(_) | Sensor::Silhouettes(_)) {
            return Err(ModelError::Target(format!(
                "a {} energy has no sparse target",
                self.sensor.name()
            )));
        }
        check_sparse_target(&self.sensor, &self.template, &values, &visible)?;
        let mut energy = self.clone();
        energy.target = Target::Sparse { values, visible };
        Ok(energy)
    }

    /// The same energy (template, configuration and precomputed tables) with another sensor of a
    /// vector-valued modality and a target for it, as cheap as [`Energy::with_target`]: how a
    /// training set gives every frame a camera rig of its own. Fails like [`Energy::new`] on a
    /// sensor that does not fit the template or a target of the wrong shape, and on a `scan` or
    /// `silhouettes` sensor (here or in `sensor`).
    pub fn with_sensor(
        &self,
        sensor: Sensor,
        values: Vec<f64>,
        visible: Vec<bool>,
    ) -> Result<Self> {
        let dense = |s: &Sensor| matches!(s, Sensor::Scan(_) | Sensor::Silhouettes(_));
        if dense(&self.sensor) || dense(&sensor) {
            return Err(ModelError::Target(format!(
                "a {} energy cannot take a {} sensor: only vector-valued sensors swap",
                self.sensor.name(),
                sensor.name()
            )));
        }
        sensor.validate(&self.template)?;
        let model = sensor.observation_model();
        let groups = model.groups(&self.template, &self.config.scales);
        check_groups(&groups, model.dim(&self.template), model.name())?;
        check_sparse_target(&sensor, &self.template, &values, &visible)?;
        let mut energy = self.clone();
        energy.observed = Arc::new(VertexSet::new(&model.vertices_read()));
        energy.sensor = sensor;
        energy.groups = groups;
        energy.target = Target::Sparse { values, visible };
        Ok(energy)
    }

    /// The same frame with the body and its observations moved rigidly by `offset`
    /// ([`Sensor::translated`]): `E'(θ') = E(θ)` for `θ'` the pose `θ` with its root translation
    /// moved by `offset`. `Ok(None)` for a sensor without that form or a dense target.
    pub fn translated(&self, offset: DVec3) -> Result<Option<Self>> {
        let Target::Sparse { values, visible } = &self.target else {
            return Ok(None);
        };
        let Some((sensor, moved)) = self.sensor.translated(values, offset) else {
            return Ok(None);
        };
        let mut energy = self.with_sensor(sensor, moved, visible.clone())?;
        if let Some(anchor) = &self.anchor {
            let shift = [offset.x, offset.y, offset.z];
            let rows = anchor
                .rows
                .iter()
                .map(|&(i, c, a)| (i, if i < 3 { c + shift[i] } else { c }, a))
                .collect();
            energy.anchor = Some(Arc::new(Anchor { rows }));
        }
        if let Some(floor) = &self.floor {
            energy.floor = Some(Arc::new(floor.at(floor.height_m() + offset.y)?));
        }
        Ok(Some(energy))
    }

    /// The same energy plus the `anchor` term ([`Anchor`]): each entry of `entries` (`(entry,
    /// std)`) pulled toward its value in `centre` by a Gaussian of standard deviation `std`
    /// (metres for the root translation, radians for rotations, the model's units for shape and
    /// expression), expressed in the data term's units — the data term is the mean over the
    /// visible groups of `s² = ‖r‖²/σ²`, so the weight is `a = λ_data / (n · std²)` with `n` the
    /// visible groups (at least 1), and the anchor counts as a Gaussian prior of that standard
    /// deviation in the posterior the data term's likelihood makes. Replaces an earlier anchor;
    /// [`Energy::translated`] moves the translation entries' centres with the sensor. Fails on a
    /// `centre` of the wrong length, a non-finite centre at an anchored entry, an entry out of
    /// range, or a `std` that is not finite and positive.
    pub fn with_anchor(&self, centre: &[f64], entries: &[(usize, f64)]) -> Result<Self> {
        self.check_length(centre)?;
        let dim = self.dim();
        let per_std = self.group_weight();
        let mut rows = Vec::with_capacity(entries.len());
        for &(i, std) in entries {
            if i >= dim {
                return Err(ModelError::Target(format!(
                    "anchor entry {i}: out of range (the parameter vector has {dim})"
                )));
            }
            if !(std.is_finite() && std > 0.0) {
                return Err(ModelError::Target(format!(
                    "anchor standard deviation {std} at entry {i}: must be finite and positive"
                )));
            }
            if !centre[i].is_finite() {
                return Err(ModelError::Target(format!(
                    "anchor centre entry {i} is not finite ({})",
                    centre[i]
                )));
            }
            rows.push((i, centre[i], per_std / (std * std)));
        }
        rows.sort_by_key(|r| r.0);
        rows.dedup_by_key(|r| r.0);
        let mut energy = self.clone();
        energy.anchor = Some(Arc::new(Anchor { rows }));
        Ok(energy)
    }

    /// The same energy plus the `height` term ([`HeightPrior`]); replaces an earlier one. Fails
    /// on a prior made for another model.
    pub fn with_height_prior(&self, prior: &HeightPrior) -> Result<Self> {
        if prior.template != (self.template.id.clone(), self.template.vertices.len()) {
            return Err(ModelError::Config(format!(
                "a height prior made for model '{}' ({} vertices) cannot serve '{}' ({} vertices)",
                prior.template.0,
                prior.template.1,
                self.template.id,
                self.template.vertices.len()
            )));
        }
        let mut energy = self.clone();
        energy.height = Some(Arc::new(prior.clone()));
        Ok(energy)
    }

    /// The same energy plus the `floor` term ([`FloorPrior`]); replaces an earlier one. Fails
    /// on a floor made for another model.
    pub fn with_floor(&self, floor: &FloorPrior) -> Result<Self> {
        floor.made_for(&self.template)?;
        let mut energy = self.clone();
        energy.floor = Some(Arc::new(floor.clone()));
        Ok(energy)
    }

    /// The floor term, when [`Energy::with_floor`] gave one.
    pub fn floor(&self) -> Option<&FloorPrior> {
        self.floor.as_deref()
    }

    /// The floor term's weight `a` (its value is `a d²`): one visible group of the data term at
    /// standard deviation σ.
    fn floor_weight(&self, floor: &FloorPrior) -> f64 {
        self.group_weight() / (floor.std_m() * floor.std_m())
    }

    /// The height of the lowest sole of `floor`'s candidates at `pose` (metres, world `+y`):
    /// where the fit put the feet against the floor. Fails on a pose of the wrong length.
    pub fn lowest_sole(&self, floor: &FloorPrior, pose: &[f64]) -> Result<f64> {
        self.check_length(pose)?;
        floor.made_for(&self.template)?;
        let kin = Kinematics::build(&self.template, pose, false);
        Ok(floor.lowest_height(&kin, &self.skin))
    }

    /// The height term, when [`Energy::with_height_prior`] gave one.
    pub fn height_prior(&self) -> Option<&HeightPrior> {
        self.height.as_deref()
    }

    /// The height term's weight `a` (its value is `a (h − H)²`): one visible group of the data
    /// term at standard deviation σ.
    fn height_weight(&self, prior: &HeightPrior) -> f64 {
        self.group_weight() / (prior.std_m * prior.std_m)
    }

    /// The weight of one visible group in the data term, `λ_data / n` (`n` the visible groups,
    /// at least 1; 1 for a dense target): what a prior of unit standard deviation weighs as one
    /// more measurement (the anchor's and the height prior's rows).
    fn group_weight(&self) -> f64 {
        let seen = match &self.target {
            Target::Sparse { visible, .. } => self.visible_groups(visible),
            Target::Scan { .. } | Target::Silhouettes { .. } => 1,
        };
        self.config.weights.data / seen.max(1) as f64
    }

    /// How many of the sensor's groups `visible` (a sparse target's flags) sees: the count the
    /// data term's mean runs over.
    fn visible_groups(&self, visible: &[bool]) -> usize {
        self.groups.iter().filter(|g| visible[g.start]).count()
    }

    /// The anchor term, when [`Energy::with_anchor`] gave one.
    pub fn anchor(&self) -> Option<&Anchor> {
        self.anchor.as_deref()
    }

    /// Counts evaluations made on a derived copy of this energy ([`Energy::with_anchor`]: a
    /// copy has counters of its own) so that this energy's counters cover a whole fit.
    pub fn add_counts(&self, evaluations: u64, gradient_evaluations: u64) {
        self.evaluations.fetch_add(evaluations, Ordering::Relaxed);
        self.gradient_evaluations
            .fetch_add(gradient_evaluations, Ordering::Relaxed);
    }

    pub fn template(&self) -> &Arc<Template> {
        &self.template
    }

    pub fn sensor(&self) -> &Sensor {
        &self.sensor
    }

    pub fn target(&self) -> &Target {
        &self.target
    }

    pub fn config(&self) -> &EnergyConfig {
        &self.config
    }

    pub fn modality(&self) -> Modality {
        self.sensor.modality()
    }

    /// Names of the terms, in the order of [`Evaluation::terms`].
    pub fn term_names(&self) -> Vec<&'static str> {
        match self.sensor {
            Sensor::Scan(_) => {
                let mut names = vec!["ED", "ES"];
                if self.silhouettes.is_some() {
                    names.push("EJ");
                }
                names.extend(["EP", "EA"]);
                names
            }
            _ => vec!["data", "EP", "EA"],
        }
    }

    /// Why this energy has no gradient, or `None` when it has one: the `silhouettes` energy's
    /// data term (papers/001 eq. 5) counts pixels, so it is piecewise constant in the pose.
    pub fn gradient_unsupported(&self) -> Option<String> {
        self.observation_model().no_gradient()
    }

    /// The observation model the energy evaluates: the sensor's (for `silhouettes` at the render
    /// width).
    pub fn observation_model(&self) -> &dyn ObservationModel {
        match &self.render {
            Some(r) => r,
            None => self.sensor.observation_model(),
        }
    }

    /// Evaluations so far (every call of an `evaluate*` method counts one per pose).
    pub fn evaluations(&self) -> u64 {
        self.evaluations.load(Ordering::Relaxed)
    }

    /// Gradient evaluations so far.
    pub fn gradient_evaluations(&self) -> u64 {
        self.gradient_evaluations.load(Ordering::Relaxed)
    }

    pub fn reset_counters(&self) {
        self.evaluations.store(0, Ordering::Relaxed);
        self.gradient_evaluations.store(0, Ordering::Relaxed);
    }

    /// Length of the parameter vector the energy takes (`3 + 3J + B + E`,
    /// [`Template::param_dim`]; 57 on the default template).
    pub fn dim(&self) -> usize {
        self.template.param_dim()
    }

    /// Value and terms at `pose` (one counted evaluation).
    pub fn evaluate(&self, pose: &[f64]) -> Evaluation {
        self.evaluations.fetch_add(1, Ordering::Relaxed);
        self.compute(pose, false).0
    }

    /// Value, terms and exact gradient over every parameter entry (translation, rotations, β, ψ;
    /// one counted evaluation and one counted gradient evaluation). Terms without a gradient
    /// (EJ, binary EA) contribute their value but nothing to the gradient: use
    /// [`EnergyConfig::for_gradient`] for gradient methods.
    pub fn evaluate_with_gradient(&self, pose: &[f64]) -> (Evaluation, Vec<f64>) {
        self.evaluations.fetch_add(1, Ordering::Relaxed);
        self.gradient_evaluations.fetch_add(1, Ordering::Relaxed);
        let (e, g) = self.compute(pose, true);
        (e, g.unwrap_or_else(|| vec![0.0; pose.len()]))
    }

    /// [`Energy::evaluate_with_gradient`] and the residual R(θ) ([`Energy::residual`], not counted)
    /// of the same evaluation: one pass of the body where the two calls take two (the neural
    /// fitter's features at each iterate).
    pub fn evaluate_with_gradient_and_residual(
        &self,
        pose: &[f64],
    ) -> (Evaluation, Vec<f64>, Vec<f64>) {
        self.evaluations.fetch_add(1, Ordering::Relaxed);
        self.gradient_evaluations.fetch_add(1, Ordering::Relaxed);
        let mut residual = Vec::new();
        let (e, g) = self.compute_with(pose, true, Some(&mut residual));
        (e, g.unwrap_or_else(|| vec![0.0; pose.len()]), residual)
    }

    /// Value and terms for reporting a result, **not** counted: fitters never call it while
    /// searching, only to report the terms of the pose they return.
    pub fn inspect(&self, pose: &[f64]) -> Evaluation {
        self.compute(pose, false).0
    }

    /// Totals of many poses, evaluated in parallel (rayon); counts one evaluation per pose.
    pub fn evaluate_batch<P: AsRef<[f64]> + Sync>(&self, poses: &[P]) -> Vec<f64> {
        self.evaluations
            .fetch_add(poses.len() as u64, Ordering::Relaxed);
        poses
            .par_iter()
            .map(|p| self.compute(p.as_ref(), false).0.total)
            .collect()
    }

    /// The residual vector R(θ) of SPEC §4, computed by the observation model ([`crate::observe`]);
    /// not counted as an evaluation.
    pub fn residual(&self, pose: &[f64]) -> Vec<f64> {
        match (&self.sensor, &self.target) {
            (Sensor::Scan(setup), Target::Scan { grid, .. }) => {
                let kin = Kinematics::build(&self.template, pose, false);
                setup
                    .residual_vertices
                    .iter()
                    .flat_map(|&v| {
                        closest_point_offset(
                            grid,
                            kin.skin(
                                self.skin.weights(v as usize),
                                kin.rest(&self.skin.rest, v as usize),
                            ),
                        )
                        .to_array()
                    })
                    .collect()
            }
            (_, Target::Sparse { values, visible }) => {
                let kin = Kinematics::build(&self.template, pose, false);
                let pred = self.prediction(self.observation_model(), &self.view(&kin));
                Sensor::sparse_residual(&pred, values, visible)
            }
            _ => Vec::new(),
        }
    }

    fn compute(&self, pose: &[f64], want_grad: bool) -> (Evaluation, Option<Vec<f64>>) {
        self.compute_with(pose, want_grad, None)
    }

    /// [`Energy::compute`], and with `residual` the residual R(θ) of the same evaluation's
    /// prediction (a sparse target's; [`Energy::residual`] for the others).
    fn compute_with(
        &self,
        pose: &[f64],
        want_grad: bool,
        mut residual: Option<&mut Vec<f64>>,
    ) -> (Evaluation, Option<Vec<f64>>) {
        let mut kin = Kinematics::build(&self.template, pose, want_grad);
        if want_grad {
            kin.shape_vertices(&self.skin.rest, &self.observed);
        }
        let nj = self.template.rig.num_joints();
        let mut adj =
            want_grad.then(|| Adjoint::new(nj, kin.morph.is_some(), self.observed.vertices.len()));
        let mut grad_direct = vec![0.0; if want_grad { pose.len() } else { 0 }];
        let w = self.config.weights;
        let mut terms = Vec::with_capacity(7);
        let mut total = 0.0;
        let posed = match &self.target {
            Target::Sparse { values, visible } => {
                let data = self.sparse_data(
                    &kin,
                    pose,
                    values,
                    visible,
                    adj.as_mut()
                        .map(|a| (a, grad_direct.as_mut_slice(), w.data)),
                    residual.take(),
                );
                terms.push(("data", data));
                total += w.data * data;
                None
            }
            Target::Scan { grid, .. } => {
                let (posed, normals): (Vec<DVec3>, Vec<DVec3>) = (0..self.skin.rest.len())
                    .map(|v| {
                        kin.skin_both(
                            self.skin.weights(v),
                            kin.rest(&self.skin.rest, v),
                            self.rest_normals[v],
                        )
                    })
                    .unzip();
                let (ed, es) = self.surface_terms(
                    &posed,
                    &normals,
                    grid,
                    adj.as_mut().map(|a| (a, &kin, w.ed, w.es)),
                );
                terms.push(("ED", ed));
                terms.push(("ES", es));
                total += w.ed * ed + w.es * es;
                if let Some(sil) = &self.silhouettes {
                    let ej = sil.evaluate(&posed, &self.template.faces);
                    terms.push(("EJ", ej));
                    total += w.ej * ej;
                }
                Some(posed)
            }
            Target::Silhouettes { .. } => {
                // `Energy::new` turns mask targets into the render-size model's vector target.
                terms.push(("data", 0.0));
                None
            }
        };
        let ep = match self.config.penetration {
            PenetrationForm::Vertices => self.penetration.evaluate(
                &kin,
                &self.skin,
                posed.as_deref(),
                adj.as_mut().map(|a| (a, w.ep)),
            ),
            PenetrationForm::Capsules => self
                .capsules
                .evaluate(&kin, adj.as_mut().map(|a| (a, w.ep))),
        };
        terms.push(("EP", ep));
        total += w.ep * ep;
        let ea = self.limits.evaluate(
            pose,
            self.config.angle_prior,
            want_grad.then_some((grad_direct.as_mut_slice(), w.ea)),
        );
        terms.push(("EA", ea));
        total += w.ea * ea;
        if let Some(prior) = &self.config.pose_prior {
            let value = prior.evaluate(
                pose,
                want_grad.then_some((grad_direct.as_mut_slice(), w.pose_prior)),
            );
            terms.push(("pose-prior", value));
            total += w.pose_prior * value;
        }
        // Gaussian priors of the shape and expression coefficients (unit variance in the model's
        // units: PCA standard deviations for a PCA space), only on models that have them.
        let layout_shape = self.template.morph.shape;
        let layout_expr = self.template.morph.expression;
        let base = 3 + 3 * nj;
        let pose_range = if w.pose > 0.0 { 3..base } else { 0..0 };
        for (name, weight, range) in [
            ("pose", w.pose, pose_range),
            ("shape", w.shape, base..base + layout_shape),
            (
                "expression",
                w.expression,
                base + layout_shape..base + layout_shape + layout_expr,
            ),
        ] {
            if range.is_empty() {
                continue;
            }
            let value: f64 = pose
                .get(range.clone())
                .unwrap_or(&[])
                .iter()
                .map(|b| b * b)
                .sum();
            terms.push((name, value));
            total += weight * value;
            if want_grad {
                for i in range {
                    if let Some(&b) = pose.get(i) {
                        grad_direct[i] += 2.0 * weight * b;
                    }
                }
            }
        }
        if let Some(anchor) = &self.anchor {
            let value = anchor.value(pose);
            terms.push(("anchor", value));
            total += value;
            if want_grad {
                for &(i, c, a) in &anchor.rows {
                    grad_direct[i] += 2.0 * a * (pose[i] - c);
                }
            }
        }
        if let Some(prior) = &self.height {
            let (h, g) = prior.measure(&self.template, pose, want_grad);
            let (a, d) = (self.height_weight(prior), h - prior.height_m);
            terms.push(("height", a * d * d));
            total += a * d * d;
            for (i, gi) in g.iter().enumerate() {
                if let Some(x) = grad_direct.get_mut(base + i) {
                    *x += 2.0 * a * d * gi;
                }
            }
        }
        if let Some(floor) = &self.floor {
            let a = self.floor_weight(floor);
            let d = floor.evaluate(&kin, &self.skin, adj.as_mut().map(|g| (g, a)));
            terms.push(("floor", a * d * d));
            total += a * d * d;
        }
        let grad = adj.map(|a| {
            let mut g = a.finish(&self.template, &kin, pose);
            g.resize(pose.len(), 0.0);
            for (gi, di) in g.iter_mut().zip(&grad_direct) {
                *gi += di;
            }
            g
        });
        if let Some(out) = residual {
            *out = self.residual(pose);
        }
        (Evaluation { total, terms }, grad)
    }

    /// The robust data term of a sparse modality: mean of `ρ(‖r_g‖/σ_g)` over visible groups.
    fn sparse_data(
        &self,
        kin: &Kinematics,
        params: &[f64],
        values: &[f64],
        visible: &[bool],
        grad: Option<(&mut Adjoint, &mut [f64], f64)>,
        residual: Option<&mut Vec<f64>>,
    ) -> f64 {
        let model = self.observation_model();
        let view = self.view(kin);
        let pred = self.prediction(model, &view);
        if let Some(out) = residual {
            *out = Sensor::sparse_residual(&pred, values, visible);
        }
        if let Some(value) = model.data_term(&pred, values) {
            // A data term of the model's own (no gradient: see `gradient_unsupported`).
            return value;
        }
        let seen = || self.groups.iter().filter(|g| visible[g.start]);
        let count = self.visible_groups(visible);
        if count == 0 {
            return 0.0;
        }
        let n = count as f64;
        // ∂data/∂prediction, entry by entry.
        let mut dpred = if grad.is_some() {
            vec![0.0; pred.len()]
        } else {
            Vec::new()
        };
        let mut sum = 0.0;
        // 1 / (σ² n), retaken when σ changes (groups of one kind share theirs).
        let mut scale = (f64::NAN, 0.0);
        for g in seen() {
            let r = (g.start..g.start + g.len).map(|i| (pred[i] - values[i]) / g.sigma);
            let s = r.map(|x| x * x).sum::<f64>().sqrt();
            let (rho, dr) = self.config.robust.eval(s);
            sum += rho;
            if !dpred.is_empty() {
                if scale.0 != g.sigma {
                    scale = (g.sigma, 1.0 / (g.sigma * g.sigma * n));
                }
                let f = dr * scale.1;
                for i in g.start..g.start + g.len {
                    dpred[i] = f * (pred[i] - values[i]);
                }
            }
        }
        if let Some((adjoint, direct, scale)) = grad {
            for d in &mut dpred {
                *d *= scale;
            }
            let mut pg = PoseGradient {
                template: &self.template,
                kin,
                skin: &self.skin,
                params,
                adjoint,
                direct,
            };
            model.backprop(&view, &dpred, &mut pg);
        }
        sum / n
    }

    /// The posed model as observation models read it.
    pub(crate) fn view<'a>(&'a self, kin: &'a Kinematics) -> PosedView<'a> {
        PosedView {
            template: &self.template,
            kin,
            skin: Some(&self.skin),
        }
    }

    /// The observation model's prediction (its visibility is the sensor's, unused here: the
    /// target's visibility decides which groups count).
    pub(crate) fn prediction(
        &self,
        model: &dyn ObservationModel,
        view: &PosedView<'_>,
    ) -> Vec<f64> {
        let n = model.dim(&self.template);
        let mut values = vec![0.0; n];
        let mut visible = vec![false; n];
        model.predict(view, &mut values, &mut visible);
        values
    }

    /// ED (papers/000 eq. 4) and ES (eq. 5) over all template vertices.
    fn surface_terms(
        &self,
        posed: &[DVec3],
        normals: &[DVec3],
        grid: &VoxelGrid,
        adj: Option<(&mut Adjoint, &Kinematics, f64, f64)>,
    ) -> (f64, f64) {
        let v_count = posed.len() as f64;
        let (lo, hi) = (grid.box_min(), grid.box_max());
        let axes: &[[f32; 6]] = self.axes.as_ref().map_or(&[], |a| a.as_slice());
        let mut ed_sum = 0.0;
        let mut es_sum = 0.0;
        let want = adj.is_some();
        // Per vertex: ∂ED_sum/∂v, ∂ES_v/∂v and ∂ES_v/∂(unnormalised normal).
        let mut grads: Vec<[DVec3; 3]> = if want {
            Vec::with_capacity(posed.len())
        } else {
            Vec::new()
        };
        if !want {
            // Value-only fast path: weights without their gradients, the tensor interpolated
            // first and one quadratic form per vertex.
            for (v, &p) in posed.iter().enumerate() {
                let c = p.clamp(lo, hi);
                let (index, weight) = grid.stencil_weights(c);
                let mut s = 0.0;
                for n in 0..8 {
                    s += weight[n] * f64::from(grid.values[index[n]]);
                }
                ed_sum += s + p.distance_squared(c);
                if c != p || axes.is_empty() {
                    es_sum += 1.0;
                    continue;
                }
                let n_raw = normals[v];
                let nl2 = n_raw.length_squared();
                if nl2 <= 1e-24 {
                    es_sum += 1.0;
                    continue;
                }
                let mut t = [0.0f64; 6];
                for k in 0..8 {
                    let a = axes[index[k]];
                    for (ti, ai) in t.iter_mut().zip(a) {
                        *ti += weight[k] * f64::from(ai);
                    }
                }
                let (x, y, z) = (n_raw.x, n_raw.y, n_raw.z);
                let q = t[0] * x * x
                    + t[3] * y * y
                    + t[5] * z * z
                    + 2.0 * (t[1] * x * y + t[2] * x * z + t[4] * y * z);
                es_sum += 1.0 - q / nl2;
            }
            return ((ed_sum.max(0.0) / v_count).sqrt(), es_sum / v_count);
        }
        for (v, &p) in posed.iter().enumerate() {
            let c = p.clamp(lo, hi);
            let st = grid.stencil(c);
            let mut s = 0.0;
            let mut ds = DVec3::ZERO;
            for n in 0..8 {
                let value = f64::from(grid.values[st.index[n]]);
                s += st.weight[n] * value;
                ds += st.gradient[n] * value;
            }
            ed_sum += s + p.distance_squared(c);
            // ES: 1 − nᵀ T n with T the interpolated direction tensor of ∇S; 1 outside the grid.
            let n_raw = normals[v];
            let nl = n_raw.length();
            let mut g_es = [DVec3::ZERO; 2];
            if c == p && nl > 1e-12 && !axes.is_empty() {
                let n = n_raw / nl;
                let mut align = 0.0;
                let mut d_align = DVec3::ZERO;
                let mut tn = DVec3::ZERO;
                for k in 0..8 {
                    let t = axes[st.index[k]];
                    let tk = DMat3::from_cols(
                        DVec3::new(f64::from(t[0]), f64::from(t[1]), f64::from(t[2])),
                        DVec3::new(f64::from(t[1]), f64::from(t[3]), f64::from(t[4])),
                        DVec3::new(f64::from(t[2]), f64::from(t[4]), f64::from(t[5])),
                    );
                    let q = n.dot(tk * n);
                    align += st.weight[k] * q;
                    d_align += st.gradient[k] * q;
                    tn += st.weight[k] * (tk * n);
                }
                es_sum += 1.0 - align;
                if want {
                    let de_dn = tn * -2.0;
                    g_es = [-d_align, (de_dn - n * n.dot(de_dn)) / nl];
                }
            } else {
                es_sum += 1.0;
            }
            if want {
                // ∂/∂p of S(⌊p⌋) + ‖p − ⌊p⌋‖²: the interpolant's gradient along unclamped axes,
                // plus 2(p − ⌊p⌋) along clamped ones.
                for a in 0..3 {
                    if p[a] != c[a] {
                        ds[a] = 0.0;
                    }
                }
                grads.push([ds + 2.0 * (p - c), g_es[0], g_es[1]]);
            }
        }
        let ed = (ed_sum.max(0.0) / v_count).sqrt();
        let es = es_sum / v_count;
        if let Some((adj, kin, wd, ws)) = adj {
            let ed_scale = if ed > 0.0 {
                wd / (2.0 * ed * v_count)
            } else {
                0.0
            };
            let es_scale = ws / v_count;
            for (v, [ded, des, den]) in grads.into_iter().enumerate() {
                let weights = self.skin.weights(v);
                let gp = ded * ed_scale + des * es_scale;
                if gp != DVec3::ZERO {
                    adj.skinned_point(kin, weights, v, kin.rest(&self.skin.rest, v), gp);
                }
                if den != DVec3::ZERO {
                    adj.skinned_direction(kin, weights, self.rest_normals[v], den * es_scale);
                }
            }
        }
        (ed, es)
    }
}

/// The direction field of ES as sign-free tensors `u uᵀ` per node (`u` the unit central-difference
/// gradient of S; zero where that gradient vanishes), stored as `[xx, xy, xz, yy, yz, zz]`.
///
/// papers/000 eq. (5) compares `∇S(⌊v⌋)` with the vertex normal. The gradient of a squared
/// distance transform vanishes on the surface and flips sign across it, so its normalised
/// trilinear interpolant is discontinuous exactly where ES matters; interpolating `u uᵀ` instead
/// gives the same `⟨u, n⟩²` at the nodes, stays continuous, and has an exact gradient. Nodes on
/// the surface take the mean tensor of their off-surface neighbours.
fn direction_tensors(grid: &VoxelGrid) -> Vec<[f32; 6]> {
    let [nx, ny, nz] = grid.dims;
    let value = |i: usize, j: usize, k: usize| f64::from(grid.values[grid.index(i, j, k)]);
    let diff = |i: usize, n: usize, at: &dyn Fn(usize) -> f64| -> f64 {
        if n < 2 {
            0.0
        } else if i == 0 {
            at(1) - at(0)
        } else if i == n - 1 {
            at(n - 1) - at(n - 2)
        } else {
            0.5 * (at(i + 1) - at(i - 1))
        }
    };
    let mut out = vec![[0f32; 6]; grid.values.len()];
    for k in 0..nz {
        for j in 0..ny {
            for i in 0..nx {
                let g = DVec3::new(
                    diff(i, nx, &|x| value(x, j, k)),
                    diff(j, ny, &|y| value(i, y, k)),
                    diff(k, nz, &|z| value(i, j, z)),
                );
                let l = g.length();
                if l > 1e-12 {
                    let u = g / l;
                    out[grid.index(i, j, k)] = [
                        u.x * u.x,
                        u.x * u.y,
                        u.x * u.z,
                        u.y * u.y,
                        u.y * u.z,
                        u.z * u.z,
                    ]
                    .map(|v| v as f32);
                }
            }
        }
    }
    // Site nodes (S = 0, on the target surface) have no usable gradient: give them the mean
    // tensor of their non-site face neighbours, which agree across the surface because u uᵀ
    // ignores the sign flip.
    let mut filled = out.clone();
    for k in 0..nz {
        for j in 0..ny {
            for i in 0..nx {
                let at = grid.index(i, j, k);
                if grid.values[at] > 0.0 {
                    continue;
                }
                let mut sum = [0f32; 6];
                let mut count = 0.0f32;
                let neighbours = [
                    (i.wrapping_sub(1), j, k),
                    (i + 1, j, k),
                    (i, j.wrapping_sub(1), k),
                    (i, j + 1, k),
                    (i, j, k.wrapping_sub(1)),
                    (i, j, k + 1),
                ];
                for (a, b, c) in neighbours {
                    if a < nx && b < ny && c < nz {
                        let n = grid.index(a, b, c);
                        if grid.values[n] > 0.0 {
                            for (s, v) in sum.iter_mut().zip(out[n]) {
                                *s += v;
                            }
                            count += 1.0;
                        }
                    }
                }
                filled[at] = if count > 0.0 {
                    sum.map(|v| v / count)
                } else {
                    [0.0; 6]
                };
            }
        }
    }
    filled
}

/// The groups of an observation model cover its prediction, in order, with positive scales.
/// A sparse target of `sensor` on `template`: one value and one flag per residual entry, every
/// visible value finite.
fn check_sparse_target(
    sensor: &Sensor,
    template: &Template,
    values: &[f64],
    visible: &[bool],
) -> Result<()> {
    let dim = sensor.residual_dim(template);
    if values.len() != dim || visible.len() != dim {
        return Err(ModelError::Shape {
            what: format!("{} target", sensor.name()),
            expected: dim.to_string(),
            got: format!(
                "{} values, {} visibility flags",
                values.len(),
                visible.len()
            ),
        });
    }
    if let Some(i) = (0..dim).find(|&i| visible[i] && !values[i].is_finite()) {
        return Err(ModelError::Target(format!(
            "visible target value {i} is not finite ({})",
            values[i]
        )));
    }
    Ok(())
}

fn check_groups(groups: &[ResidualGroup], dim: usize, name: &str) -> Result<()> {
    let mut next = 0;
    for g in groups {
        if g.start != next || g.len == 0 || !(g.sigma.is_finite() && g.sigma > 0.0) {
            return Err(ModelError::Config(format!(
                "observation model '{name}': residual groups must tile its {dim} entries in order with positive σ (group at {} of {} entries, σ {})",
                g.start, g.len, g.sigma
            )));
        }
        next += g.len;
    }
    if next != dim {
        return Err(ModelError::Config(format!(
            "observation model '{name}': residual groups cover {next} of its {dim} entries"
        )));
    }
    Ok(())
}

/// One target mask per camera, each of its camera's size.
fn check_masks(masks: &[Mask], cameras: &[Camera]) -> Result<()> {
    if masks.len() != cameras.len() {
        return Err(ModelError::Shape {
            what: "target silhouettes".into(),
            expected: cameras.len().to_string(),
            got: masks.len().to_string(),
        });
    }
    for (k, (m, c)) in masks.iter().zip(cameras).enumerate() {
        if m.width != c.width
            || m.height != c.height
            || m.data.len() != (m.width * m.height) as usize
        {
            return Err(ModelError::Shape {
                what: format!("silhouette {k}"),
                expected: format!("{}x{}", c.width, c.height),
                got: format!("{}x{}", m.width, m.height),
            });
        }
    }
    Ok(())
}

impl SilhouetteTerm {
    fn new(cameras: &[Camera], masks: &[Mask], width: u32) -> Self {
        let scaled = SilhouetteSetup {
            cameras: cameras.to_vec(),
        }
        .at_width(width)
        .cameras;
        let targets = masks
            .iter()
            .zip(&scaled)
            .map(|(m, c)| resample_mask(m, c.width, c.height))
            .collect();
        Self {
            cameras: scaled,
            targets,
        }
    }

    /// EJ of papers/000 eq. (6): mean over views of `1 − IoU`.
    fn evaluate(&self, posed: &[DVec3], faces: &[[u32; 3]]) -> f64 {
        let verts: Vec<Vec3> = posed.iter().map(|p| p.as_vec3()).collect();
        let sum: f64 = self
            .cameras
            .iter()
            .zip(&self.targets)
            .map(|(cam, target)| 1.0 - iou(&render_silhouette(cam, &verts, faces), target))
            .sum();
        sum / self.cameras.len().max(1) as f64
    }
}

/// Resamples a mask to `width × height`: a small pixel is inside when at least half of the
/// source pixels whose centres fall in its footprint are inside.
fn resample_mask(mask: &Mask, width: u32, height: u32) -> Mask {
    let mut out = Mask::new(width, height);
    let sx = f64::from(mask.width) / f64::from(width);
    let sy = f64::from(mask.height) / f64::from(height);
    let mut inside = vec![0u32; (width * height) as usize];
    let mut total = vec![0u32; (width * height) as usize];
    for y in 0..mask.height {
        let ty = (((f64::from(y) + 0.5) / sy) as u32).min(height - 1);
        for x in 0..mask.width {
            let tx = (((f64::from(x) + 0.5) / sx) as u32).min(width - 1);
            let i = (tx + width * ty) as usize;
            total[i] += 1;
            inside[i] += u32::from(mask.get(x, y));
        }
    }
    for (o, (&a, &t)) in out.data.iter_mut().zip(inside.iter().zip(&total)) {
        *o = u8::from(t > 0 && 2 * a >= t);
    }
    out
}

#[cfg(test)]
mod tests;
