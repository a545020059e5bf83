//! The neural fitter's configuration (SPEC §7): sizes and every ablation switch of papers/002.
//!
//! Defaults are papers/002's where it states one (N = 5, supp. §6.7; stacks of 2 GRUs with 1024
//! units and initializers of 2 × 256 units, §3.5; dropout 0.5 on the GRU hidden states and an
//! output-layer gain of 0.01, supp. §6.4; vector λ/γ from one shared network, supp. Table A.1).

use serde::{Deserialize, Serialize};

use lfit_model::error::{ModelError, Result};
use lfit_model::observe::Modality;
use lfit_model::pose::POSE_DIM;

/// The recurrent core `f` (and `fλγ`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum CoreKind {
    /// A stack of layer-normalized GRU cells (papers/002 supp. eq. 12).
    Gru,
    /// A residual MLP without memory: every iteration sees only its current inputs.
    ResidualMlp,
}

/// How `Δθ`, `g`, `λ` and `γ` make the update `θn − θ(n−1)`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum UpdateRule {
    /// `u = Δθ` (LGD: λ = 1, γ = 0; papers/002 Table 5 "Δθn").
    DeltaOnly,
    /// `u = λ ⊙ Δθ − γ ⊙ g` (papers/002 eq. 1).
    Eq1,
    /// `u = λ ⊙ Δθ + (1 − λ) ⊙ (−γ ⊙ g)`, `λ = σ(·)` (supp. eq. 10, first line).
    Convex,
    /// `u = γ ⊙ [λ ⊙ Δθ/‖Δθ‖ + (1 − λ) ⊙ (−g/‖g‖)]`, `λ = σ(·)` (supp. eq. 10, second line).
    ConvexNormalized,
}

/// The descent direction `g` the update mixes with the network's `Δθ`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Direction {
    /// The energy gradient `∇E` (papers/002 eq. 1; every network before this switch).
    #[default]
    Gradient,
    /// The negated Marquardt-damped Gauss-Newton step `−h`, `(JᵀJ + μ D) h = −Jᵀr` over the
    /// free entries (`gn_damping` = μ), from the energy's least-squares form: a preconditioned
    /// gradient, so `θ − γ g` with `γ = 1` is one Levenberg–Marquardt step at fixed damping. The
    /// learned step then inherits Gauss-Newton's local convergence on frames unlike the
    /// training motion (BA-Net, Tang & Tan 2019, and LS-Net, Clark et al. 2018, learn around
    /// the same step). One Jacobian per iteration instead of one gradient.
    GaussNewton,
    /// The chord method over [`Direction::GaussNewton`]'s system (Kelley, *Iterative Methods
    /// for Linear and Nonlinear Equations*, SIAM 1995, ch. 5): the damped system
    /// `JᵀJ + μ D` is built and factorised at θ0 only, and every later iteration solves it
    /// with the gradient at its iterate, `(J₀ᵀJ₀ + μ D₀) h = −∇E(θn)/2`. The first direction is
    /// [`Direction::GaussNewton`]'s; each later one costs a gradient and two triangular solves
    /// instead of a Jacobian, the normal equations and a factorisation (issue 26: the
    /// Gauss-Newton directions were half the neural fitter's time per frame). A network trained
    /// on one of the two directions does not carry to the other (cost-model.md).
    /// `chord_factorisations` > 1 factorises again at each of the first iterates.
    GaussNewtonChord,
}

impl Direction {
    pub fn is_gradient(&self) -> bool {
        *self == Direction::Gradient
    }

    /// Whether the direction solves the damped Gauss-Newton system (at each iterate or at θ0).
    pub fn is_gauss_newton(&self) -> bool {
        matches!(self, Direction::GaussNewton | Direction::GaussNewtonChord)
    }
}

/// Whether γ is predicted or fixed.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum GammaMode {
    Learned,
    /// `γ = gamma_constant` for every parameter (papers/002 Table 6 "constant").
    Constant,
}

/// One value of λ (γ) per pose parameter, or one for all (supp. Table A.1).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum StepShape {
    Vector,
    Scalar,
}

impl StepShape {
    /// Values per step size for a parameter vector of `dim` entries.
    pub fn outputs(self, dim: usize) -> usize {
        match self {
            StepShape::Vector => dim,
            StepShape::Scalar => 1,
        }
    }
}

/// Where θ0 comes from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum StartMode {
    /// θ0 = Φ(D) (papers/002 Alg. 1).
    Phi,
    /// θ0 is a given pose (the scenario's start pose, or the previous frame's result).
    Given,
    /// Training draws Φ(D) or the given pose per sample with probability ½; inference may use
    /// either. This is what the shipped checkpoints use, so one network serves both starts.
    Mixed,
}

/// How the `keypoints2d` features treat the cameras of the rig.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Views {
    /// The features are the whole residual and observation vectors: the network fits exactly
    /// the rig it was trained on (every network before this switch).
    #[default]
    Fixed,
    /// Camera-agnostic: features are computed per camera and pooled over the cameras (mean and
    /// maximum over the cameras that see each keypoint, the fraction that see it and the camera
    /// count; [`crate::features`]), so one network fits any number of cameras of the same
    /// keypoint set. `residual_dim` is then the residual of one camera (2 × keypoints).
    Pooled,
}

impl Views {
    pub fn is_fixed(&self) -> bool {
        *self == Views::Fixed
    }
}

/// Everything that determines the network's structure and update rule.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct NetConfig {
    /// Observation modality the network was built for.
    pub modality: Modality,
    /// Length of the modality's residual vector R(θ) (also the observation vector's length);
    /// with pooled views, of one camera's part of it.
    pub residual_dim: usize,
    /// Length of the parameter vector θ the network predicts: the model's `3 + 3J + B + E`
    /// (57 on the default template, the value of checkpoints that predate the field).
    pub param_dim: usize,
    /// Fitting iterations N.
    pub iterations: usize,
    pub core: CoreKind,
    /// Layers of the core (GRU cells or residual blocks).
    pub layers: usize,
    /// Units per layer of the core.
    pub hidden: usize,
    /// Units per hidden layer of Φ and Φh (2 layers, ReLU, BatchNorm).
    pub init_width: usize,
    pub update: UpdateRule,
    pub gamma: GammaMode,
    /// γ when `gamma = constant`.
    pub gamma_constant: f64,
    /// γ at initialisation when learned (the head's output is ≈ 0 at first, so this is where
    /// training starts from).
    pub gamma_init: f64,
    /// Shape of λ, and of γ unless `gamma_shape` says otherwise.
    pub step_shape: StepShape,
    /// Shape of γ when it differs from λ's (supp. Table A.1 rows 1–2); `None`: `step_shape`.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub gamma_shape: Option<StepShape>,
    /// One network for λ and γ (true) or one each.
    pub shared_lambda_gamma: bool,
    /// Separate weights for every iteration instead of one set shared by all.
    pub per_step_weights: bool,
    pub start: StartMode,
    /// Dropout probability on the hidden states of the core during training.
    pub dropout: f64,
    /// Gain of the Xavier-uniform initialisation of the output layers.
    pub output_gain: f64,
    /// Normalised input features are clipped to ±this.
    pub feature_clip: f64,
    /// The model's shape β is given, not estimated (papers/002 §3.2: "we assume we are given
    /// body shape β for the HMD fitting scenario"): training fixes the shape entries to the
    /// truth, and a fit must freeze them at the subject's β (`lfit fit --known-shape`).
    #[serde(skip_serializing_if = "std::ops::Not::not")]
    pub known_shape: bool,
    /// `fixed` (the default): the features are tied to the training rig; `pooled`
    /// (`keypoints2d` only): pooled over cameras, any rig of the same keypoints.
    #[serde(skip_serializing_if = "Views::is_fixed")]
    pub views: Views,
    /// The direction `g` of the update rule (`gradient`: papers/002).
    #[serde(skip_serializing_if = "Direction::is_gradient")]
    pub direction: Direction,
    /// μ of the Gauss-Newton direction, relative to `diag(JᵀJ)` (Marquardt's scaling).
    #[serde(skip_serializing_if = "is_default_gn_damping")]
    pub gn_damping: f64,
    /// Largest magnitude of an entry of the Gauss-Newton direction (a box trust region: each
    /// entry is clipped to `±gn_max_step`). Marquardt's scaling leaves entries the data hardly
    /// constrain (a thumb no marker sees: 30–140 rad steps on captured frames) almost undamped;
    /// scaling the whole step down to them would stall every other entry, clipping them alone
    /// does not.
    #[serde(skip_serializing_if = "is_default_gn_max_step")]
    pub gn_max_step: f64,
    /// [`Direction::GaussNewtonChord`]: the iterations that build and factorise the system at
    /// their iterate (1: θ0 only); every later one solves the last of them.
    #[serde(skip_serializing_if = "is_default_chord_factorisations")]
    pub chord_factorisations: usize,
}

fn is_default_chord_factorisations(v: &usize) -> bool {
    *v == 1
}

/// [`NetConfig::gn_max_step`] unless a config says otherwise: half a radian per rotation
/// entry, half a metre of translation, half a standard deviation of shape, per iteration.
pub const DEFAULT_GN_MAX_STEP: f64 = 0.5;

fn is_default_gn_max_step(v: &f64) -> bool {
    *v == DEFAULT_GN_MAX_STEP
}

/// μ of [`Direction::GaussNewton`] unless a config says otherwise: a hundred times the
/// `1/radius = 1e-4` that lfit's LM (Ceres's default radius 1e4) starts from, because the network's
/// loop has no step rejection — the damping keeps a step from a far start from overshooting.
pub const DEFAULT_GN_DAMPING: f64 = 1e-2;

fn is_default_gn_damping(v: &f64) -> bool {
    *v == DEFAULT_GN_DAMPING
}

impl Default for NetConfig {
    fn default() -> Self {
        Self {
            modality: Modality::Markers,
            residual_dim: 0,
            param_dim: POSE_DIM,
            iterations: 5,
            core: CoreKind::Gru,
            layers: 2,
            hidden: 1024,
            init_width: 256,
            update: UpdateRule::Eq1,
            gamma: GammaMode::Learned,
            gamma_constant: 1e-4,
            gamma_init: 1e-4,
            step_shape: StepShape::Vector,
            gamma_shape: None,
            shared_lambda_gamma: true,
            per_step_weights: false,
            start: StartMode::Phi,
            dropout: 0.5,
            output_gain: 0.01,
            feature_clip: 10.0,
            known_shape: false,
            views: Views::Fixed,
            direction: Direction::Gradient,
            gn_damping: DEFAULT_GN_DAMPING,
            gn_max_step: DEFAULT_GN_MAX_STEP,
            chord_factorisations: 1,
        }
    }
}

impl NetConfig {
    /// Length of the observation features D: observed values (0 where invisible) and visibility;
    /// pooled: the mean and maximum over cameras of each observed value, the fraction of the
    /// cameras that see each keypoint, and the camera count.
    pub fn obs_features(&self) -> usize {
        match self.views {
            Views::Fixed => 2 * self.residual_dim,
            Views::Pooled => 2 * self.residual_dim + self.keypoints() + 1,
        }
    }

    /// Length of the residual features the network sees of R(θ): R itself; pooled: the mean
    /// and the largest magnitude over cameras of each entry.
    pub fn residual_features(&self) -> usize {
        match self.views {
            Views::Fixed => self.residual_dim,
            Views::Pooled => 2 * self.residual_dim,
        }
    }

    /// Keypoints per camera of a pooled network (`residual_dim / 2`).
    pub fn keypoints(&self) -> usize {
        self.residual_dim / 2
    }

    /// Input of the core at every iteration: `[R(θ), g, θ, D]`.
    pub fn core_inputs(&self) -> usize {
        self.residual_features() + 2 * self.param_dim + self.obs_features()
    }

    /// Input of the λ/γ network: `[R(θ), R(θ + Δθ)]` (papers/002 eq. 2).
    pub fn step_inputs(&self) -> usize {
        2 * self.residual_features()
    }

    /// Outputs of λ: one per parameter, or one.
    pub fn step_outputs(&self) -> usize {
        self.step_shape.outputs(self.param_dim)
    }

    /// Outputs of γ: one per parameter, or one.
    pub fn gamma_outputs(&self) -> usize {
        self.gamma_shape
            .unwrap_or(self.step_shape)
            .outputs(self.param_dim)
    }

    /// Whether the update rule uses λ/γ at all (so whether the λ/γ network exists).
    pub fn has_step_network(&self) -> bool {
        self.update != UpdateRule::DeltaOnly
    }

    /// Evaluations of the observation model one iteration costs: the gradient evaluation at θ,
    /// plus R(θ + Δθ) for the λ/γ network when the rule has one.
    pub fn evaluations_per_iteration(&self) -> usize {
        if self.has_step_network() { 2 } else { 1 }
    }

    /// Whether the network predicts γ.
    pub fn learns_gamma(&self) -> bool {
        self.has_step_network() && self.gamma == GammaMode::Learned
    }

    /// Number of weight sets of the per-iteration networks.
    pub fn weight_sets(&self) -> usize {
        if self.per_step_weights {
            self.iterations
        } else {
            1
        }
    }

    /// The weight set iteration `n` (0-based) uses.
    pub fn weight_set(&self, n: usize) -> usize {
        if self.per_step_weights {
            n.min(self.iterations - 1)
        } else {
            0
        }
    }

    /// Recurrent layers of each core: the GRU's layers, none for the residual MLP.
    pub fn recurrent_layers(&self) -> usize {
        if self.core == CoreKind::Gru {
            self.layers
        } else {
            0
        }
    }

    /// Whether γ has a core and head of its own (learned γ, not shared with λ).
    pub fn separate_gamma_network(&self) -> bool {
        self.learns_gamma() && !self.shared_lambda_gamma
    }

    /// Rejects configurations the network cannot be built from, naming the field.
    pub fn validate(&self) -> Result<()> {
        let bad = |what: &str, why: String| {
            Err(ModelError::Config(format!("network config: {what} {why}")))
        };
        if self.residual_dim == 0 {
            return bad("residual_dim", "must be positive".into());
        }
        if self.param_dim < 6 {
            return bad(
                "param_dim",
                format!(
                    "must be at least 6 (translation and one joint), got {}",
                    self.param_dim
                ),
            );
        }
        if self.iterations == 0 || self.iterations > 100 {
            return bad(
                "iterations",
                format!("must be in 1..=100, got {}", self.iterations),
            );
        }
        if self.layers == 0 || self.layers > 8 {
            return bad("layers", format!("must be in 1..=8, got {}", self.layers));
        }
        if self.hidden == 0 || self.hidden > 8192 || self.init_width == 0 || self.init_width > 8192
        {
            return bad("hidden/init_width", "must be in 1..=8192".into());
        }
        if !(0.0..1.0).contains(&self.dropout) {
            return bad(
                "dropout",
                format!("must be in [0, 1), got {}", self.dropout),
            );
        }
        for (name, v) in [
            ("gamma_constant", self.gamma_constant),
            ("gamma_init", self.gamma_init),
            ("output_gain", self.output_gain),
            ("feature_clip", self.feature_clip),
            ("gn_damping", self.gn_damping),
            ("gn_max_step", self.gn_max_step),
        ] {
            if !(v.is_finite() && v > 0.0) {
                return bad(name, format!("must be positive, got {v}"));
            }
        }
        if self.chord_factorisations == 0 || self.chord_factorisations > self.iterations {
            return bad(
                "chord_factorisations",
                format!(
                    "must be in 1..={} (the iterations), got {}",
                    self.iterations, self.chord_factorisations
                ),
            );
        }
        if self.views == Views::Pooled
            && (self.modality != Modality::Keypoints2d || self.residual_dim % 2 != 0)
        {
            return bad(
                "views",
                format!(
                    "pooled needs keypoints2d data (2 values per keypoint and camera), got {} with residual_dim {}",
                    self.modality, self.residual_dim
                ),
            );
        }
        if matches!(self.modality, Modality::Scan | Modality::Silhouettes) {
            return bad(
                "modality",
                format!(
                    "{} has no neural fitter (its residual is not an observation vector)",
                    self.modality
                ),
            );
        }
        Ok(())
    }
}
