//! CMA-ES (µ/µ_w, λ) with rank-one and rank-µ covariance updates and cumulative step-size
//! adaptation, following Hansen, "The CMA Evolution Strategy: A Tutorial" (2016), Table 1
//! and Appendix C (`cmaes.m` / `purecma` structure); with the tutorial's parameters also the
//! active (negative-weight) covariance update of Table 1 / eq. (47), pycma's default.
//!
//! The search happens in `y`-space with `x = start + norm ⊙ y`:
//!
//! * [`Preset::Nevergrad`]: `norm = scale`, σ0 = 1 (nevergrad `CMA` passes `sigma = scale = 1`
//!   in standardized space, so the initial steps are `scale`), strategy parameters from
//!   Hansen's CMA tutorial (2016) Table 1 via [`CmaParams::tutorial`] (the pycma defaults).
//! * [`Preset::Paper001`]: `norm = 1`, σ0 = 0.5 in x units (papers/001 Table 3, the 0.5 rad
//!   search radius), strategy parameters from papers/001 Table 2 via
//!   [`CmaParams::hansen2004`] (the older Hansen & Kern 2004 formulas).
//!
//! Both start with `m = 0` (the start point), `C = I`, `p_σ = p_c = 0`.
//!
//! **Bounds** — repair, use the repaired step (lfit choice; Lamarckian repair): a sample
//! `x = m + σ y` is clipped into the box and the update uses the repaired step
//! `y' = (clip(x) − m) / σ`.  As the mean is a convex combination of repaired points, it stays
//! inside the box.  Repaired steps are shortened, if needed, to Mahalanobis length
//! `√n + 2n/(n+2)` as Hansen (2011, "Injecting external solutions into CMA-ES") recommends for
//! steps not sampled from the distribution.
//!
//! **Eigendecomposition** is lazy (tutorial Appendix C / `cmaes.m`): every
//! `max(1, ⌈1 / ((c1 + cµ) n 10)⌉)` generations, with nalgebra's `SymmetricEigen`.
//!
//! **Restarts** (IPOP-CMA-ES, Auger & Hansen 2005): from the start point with σ0, `C = I` and
//! λ doubled (at most [`MAX_IPOP_DOUBLINGS`] times) when σ·max(D) < 1e-12·σ0, σ·max(D) > 1e8·σ0, cond(C) > 1e14, the
//! eigensolver fails, or the state becomes non-finite.  Flat fitness (best == ⌈0.1 + λ/4⌉-th
//! best) multiplies σ by `exp(0.2 + cσ/dσ)` as in `purecma`.

use nalgebra::{DMatrix, SymmetricEigen};

use super::util::{self, OptRng};
use super::{Bounds, Optimizer, Preset, Problem};

/// Which formulas the strategy parameters come from.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum CmaStyle {
    /// Hansen's CMA tutorial (2016), Table 1.
    Tutorial,
    /// papers/001 Table 2 (Hansen & Kern 2004).
    Hansen2004,
}

/// Strategy parameters.
#[derive(Debug, Clone, PartialEq)]
pub struct CmaParams {
    /// Formulas used.
    pub style: CmaStyle,
    /// Population size λ.
    pub lambda: usize,
    /// Number of parents µ.
    pub mu: usize,
    /// Positive recombination weights, sum 1.
    pub weights: Vec<f64>,
    /// Variance-effective selection mass µ_eff = 1 / Σ w².
    pub mueff: f64,
    /// Step-size cumulation cσ.
    pub cs: f64,
    /// Step-size damping dσ.
    pub ds: f64,
    /// Covariance cumulation c_c.
    pub cc: f64,
    /// Rank-one learning rate c1.
    pub c1: f64,
    /// Rank-µ learning rate cµ.
    pub cmu: f64,
    /// E‖N(0, I)‖ ≈ √n (1 − 1/(4n) + 1/(21n²)).
    pub chi_n: f64,
    /// Active CMA (Jastrebski & Arnold 2006; the tutorial's Table 1 weights and pycma's default
    /// `CMA_active=True`): the recombination weights of ranks µ+1..λ, negative, used in the
    /// rank-µ covariance update only (empty: no active update).
    pub negative_weights: Vec<f64>,
    /// Separable rates ([`CmaParams::separable`]).
    pub separable: bool,
}

impl CmaParams {
    /// Hansen's CMA tutorial (2016) Table 1 defaults: λ = 4 + ⌊3 ln n⌋, µ = ⌊λ/2⌋,
    /// w_i ∝ ln((λ+1)/2) − ln i, cσ = (µ_eff+2)/(n+µ_eff+5),
    /// dσ = 1 + 2 max(0, √((µ_eff−1)/(n+1)) − 1) + cσ, c_c = (4+µ_eff/n)/(n+4+2µ_eff/n),
    /// c1 = 2/((n+1.3)²+µ_eff), cµ = min(1−c1, 2(µ_eff−2+1/µ_eff)/((n+2)²+µ_eff)).
    pub fn tutorial(n: usize) -> Self {
        Self::tutorial_with_lambda(n, default_lambda(n))
    }

    /// [`CmaParams::tutorial`] with population size `lambda` (≥ 2), as used by IPOP restarts.
    pub fn tutorial_with_lambda(n: usize, lambda: usize) -> Self {
        let nf = n.max(1) as f64;
        let lambda = lambda.max(2);
        let mu = lambda / 2;
        let base = ((lambda as f64 + 1.0) / 2.0).ln();
        let (weights, mueff) = normalise((1..=mu).map(|i| base - (i as f64).ln()).collect());
        let cs = (mueff + 2.0) / (nf + mueff + 5.0);
        let ds = 1.0 + 2.0 * (((mueff - 1.0) / (nf + 1.0)).sqrt() - 1.0).max(0.0) + cs;
        let cc = (4.0 + mueff / nf) / (nf + 4.0 + 2.0 * mueff / nf);
        let c1 = 2.0 / ((nf + 1.3).powi(2) + mueff);
        let cmu = (1.0 - c1).min(2.0 * (mueff - 2.0 + 1.0 / mueff) / ((nf + 2.0).powi(2) + mueff));
        // Tutorial Table 1, ranks µ+1..λ: w'_i = ln((λ+1)/2) − ln i < 0, scaled so that
        // Σ|w⁻| = min(α_µ⁻, α_µeff⁻, α_posdef⁻) with α_µ⁻ = 1 + c1/cµ,
        // α_µeff⁻ = 1 + 2µ⁻_eff/(µ_eff + 2), α_posdef⁻ = (1 − c1 − cµ)/(n cµ).
        let negative_weights = negative_weights(lambda, c1, cmu, mueff, nf);
        CmaParams {
            style: CmaStyle::Tutorial,
            lambda,
            mu,
            weights,
            mueff,
            cs,
            ds,
            cc,
            c1,
            cmu,
            chi_n: chi(nf),
            negative_weights,
            separable: false,
        }
    }

    /// pycma's separable rates (see [`CmaVariant::diagonal`]); the active weights follow them.
    pub fn separable(mut self, n: usize) -> Self {
        let nf = n.max(1) as f64;
        let mueff = self.mueff;
        self.c1 = 1.0 / (nf + 2.0 * nf.sqrt() + mueff / nf);
        self.cmu = (1.0 - self.c1)
            .min((0.25 + mueff + 1.0 / mueff - 2.0) / (nf + 4.0 * nf.sqrt() + mueff / 2.0))
            .max(0.0);
        self.cc = (1.0 + 1.0 / nf + mueff / nf) / (nf.sqrt() + 1.0 / nf + 2.0 * mueff / nf);
        if !self.negative_weights.is_empty() {
            self.negative_weights = negative_weights(self.lambda, self.c1, self.cmu, mueff, nf);
        }
        self.separable = true;
        self
    }

    /// [`CmaParams::tutorial`] without the active update (pycma's `CMA_active=False`).
    pub fn without_active(mut self) -> Self {
        self.negative_weights.clear();
        self
    }

    /// papers/001 Table 2 (Hansen & Kern 2004): λ = 4 + ⌊3 ln D⌋, µ = ⌊λ/2⌋,
    /// w_i ∝ ln(µ+1) − ln i, cσ = (µ_eff+2)/(D+µ_eff+3), dσ as in the tutorial,
    /// c_c = 4/(D+4), µ_cov = µ_eff,
    /// c_cov = (1/µ_cov)·2/(D+√2)² + (1 − 1/µ_cov)·min(1, (2µ_eff−1)/((D+2)²+µ_eff)),
    /// i.e. c1 = c_cov/µ_cov and cµ = c_cov (1 − 1/µ_cov).
    pub fn hansen2004(n: usize) -> Self {
        Self::hansen2004_with_lambda(n, default_lambda(n))
    }

    /// [`CmaParams::hansen2004`] with population size `lambda` (≥ 2).
    pub fn hansen2004_with_lambda(n: usize, lambda: usize) -> Self {
        let nf = n.max(1) as f64;
        let lambda = lambda.max(2);
        let mu = lambda / 2;
        let base = (mu as f64 + 1.0).ln();
        let (weights, mueff) = normalise((1..=mu).map(|i| base - (i as f64).ln()).collect());
        let cs = (mueff + 2.0) / (nf + mueff + 3.0);
        let ds = 1.0 + 2.0 * (((mueff - 1.0) / (nf + 1.0)).sqrt() - 1.0).max(0.0) + cs;
        let cc = 4.0 / (nf + 4.0);
        let mucov = mueff;
        let ccov = (1.0 / mucov) * 2.0 / (nf + std::f64::consts::SQRT_2).powi(2)
            + (1.0 - 1.0 / mucov)
                * (1.0f64).min((2.0 * mueff - 1.0) / ((nf + 2.0).powi(2) + mueff));
        let c1 = ccov / mucov;
        let cmu = (ccov * (1.0 - 1.0 / mucov)).min(1.0 - c1);
        CmaParams {
            style: CmaStyle::Hansen2004,
            lambda,
            mu,
            weights,
            mueff,
            cs,
            ds,
            cc,
            c1,
            cmu,
            chi_n: chi(nf),
            negative_weights: Vec::new(),
            separable: false,
        }
    }

    /// The same formulas with another population size (and the same choice of active update).
    pub fn with_lambda(&self, n: usize, lambda: usize) -> Self {
        let p = match self.style {
            CmaStyle::Tutorial => Self::tutorial_with_lambda(n, lambda),
            CmaStyle::Hansen2004 => Self::hansen2004_with_lambda(n, lambda),
        };
        let p = if self.negative_weights.is_empty() {
            p.without_active()
        } else {
            p
        };
        if self.separable { p.separable(n) } else { p }
    }

    /// Whether the fields are mutually consistent (1 ≤ µ ≤ λ, µ weights, finite rates).
    pub fn is_consistent(&self) -> bool {
        self.lambda >= 2
            && self.mu >= 1
            && self.mu <= self.lambda
            && self.weights.len() == self.mu
            && self.negative_weights.len() <= self.lambda - self.mu
            && self.negative_weights.iter().all(|w| *w <= 0.0)
            && [
                self.mueff, self.cs, self.ds, self.cc, self.c1, self.cmu, self.chi_n,
            ]
            .iter()
            .all(|v| v.is_finite())
    }

    /// Generations between eigendecompositions: `max(1, ⌈1/((c1+cµ)·n·10)⌉)` (tutorial App. C).
    pub fn eigen_gap(&self, n: usize) -> usize {
        if self.separable {
            return 1;
        }
        let g = 1.0 / ((self.c1 + self.cmu) * n.max(1) as f64 * 10.0);
        (g.ceil() as usize).max(1)
    }
}

/// The active (negative) weights of ranks µ+1..λ for rates `c1`, `cµ` (tutorial Table 1):
/// `w'_i = ln((λ+1)/2) − ln i < 0`, scaled so that `Σ|w⁻| = min(α_µ⁻, α_µeff⁻, α_posdef⁻)` with
/// `α_µ⁻ = 1 + c1/cµ`, `α_µeff⁻ = 1 + 2µ⁻_eff/(µ_eff + 2)`, `α_posdef⁻ = (1 − c1 − cµ)/(n cµ)`.
fn negative_weights(lambda: usize, c1: f64, cmu: f64, mueff: f64, nf: f64) -> Vec<f64> {
    let base = ((lambda as f64 + 1.0) / 2.0).ln();
    let raw: Vec<f64> = (lambda / 2 + 1..=lambda)
        .map(|i| base - (i as f64).ln())
        .filter(|w| *w < 0.0)
        .collect();
    if raw.is_empty() || cmu <= 0.0 {
        return Vec::new();
    }
    let sum_abs: f64 = raw.iter().map(|w| w.abs()).sum();
    let mueff_neg = sum_abs * sum_abs / raw.iter().map(|w| w * w).sum::<f64>();
    let alpha = (1.0 + c1 / cmu)
        .min(1.0 + 2.0 * mueff_neg / (mueff + 2.0))
        .min((1.0 - c1 - cmu) / (nf * cmu))
        .max(0.0);
    raw.iter().map(|w| alpha * w / sum_abs).collect()
}

/// `‖C^{-1/2} y‖² = ‖D⁻¹ Bᵀ y‖²` for the eigenvectors `b` (columns, row-major) and the square
/// roots `d` of the eigenvalues of C.
fn mahalanobis_squared(b: &[f64], d: &[f64], y: &[f64]) -> f64 {
    let n = d.len();
    let mut m2 = 0.0;
    for j in 0..n {
        let t: f64 = (0..n).map(|i| b[i * n + j] * y[i]).sum();
        m2 += (t / d[j]) * (t / d[j]);
    }
    m2
}

/// Variants of the update, as pycma's options.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct CmaVariant {
    /// Separable CMA-ES (pycma `CMA_diagonal=True`; Ros & Hansen 2008): only the diagonal of C
    /// is learnt, with pycma's separable rates `c1 = 1/(n + 2√n + µ_eff/n)`,
    /// `cµ = min(1 − c1, (1/4 + µ_eff + 1/µ_eff − 2)/(n + 4√n + µ_eff/2))`,
    /// `c_c = (1 + 1/n + µ_eff/n)/(√n + 1/n + 2µ_eff/n)` — n times faster in n dimensions.
    pub diagonal: bool,
    /// pycma `CMA_elitist=True`: when the best point so far beats a generation's best, it is
    /// ranked first in that generation, its step rescaled to a random Mahalanobis length
    /// (pycma's `random_rescale_to_mahalanobis`).
    pub elitist: bool,
    /// Population size λ (default 4 + ⌊3 ln n⌋).
    pub popsize: Option<usize>,
}

/// Default population size λ = 4 + ⌊3 ln n⌋ (tutorial Table 1 and papers/001 Table 2).
pub fn default_lambda(n: usize) -> usize {
    4 + (3.0 * (n.max(1) as f64).ln()).floor() as usize
}

fn normalise(raw: Vec<f64>) -> (Vec<f64>, f64) {
    let s: f64 = raw.iter().sum();
    let w: Vec<f64> = raw.iter().map(|v| v / s).collect();
    let mueff = 1.0 / w.iter().map(|v| v * v).sum::<f64>();
    (w, mueff)
}

fn chi(nf: f64) -> f64 {
    nf.sqrt() * (1.0 - 1.0 / (4.0 * nf) + 1.0 / (21.0 * nf * nf))
}

/// Lower limit of σ·max(D) relative to σ0 before a restart.
pub const TOL_X: f64 = 1e-12;
/// Upper limit of σ·max(D) relative to σ0 before a restart.
pub const TOL_UP_SIGMA: f64 = 1e8;
/// Largest allowed condition number of C before a restart.
pub const MAX_COND: f64 = 1e14;
/// Restart when the best values of the last `10 + ⌈30 n / λ⌉` generations and all values of
/// the current one lie within this range (pycma `tolfun` = 1e-11; lfit uses 1e-12).
pub const TOL_FUN: f64 = 1e-12;
/// IPOP restarts double λ at most this many times (Auger & Hansen 2005 use up to 9).
pub const MAX_IPOP_DOUBLINGS: usize = 9;

/// CMA-ES optimizer. One ask returns at most the rest of the current generation.
pub struct Cma {
    name: String,
    bounds: Bounds,
    start: Vec<f64>,
    norm: Vec<f64>,
    n: usize,
    p: CmaParams,
    eigen_gap: usize,
    lambda0: usize,
    sigma0: f64,
    sigma: f64,
    mean: Vec<f64>,
    pc: Vec<f64>,
    ps: Vec<f64>,
    /// Covariance, row-major; only the upper triangle is updated between eigendecompositions.
    c: Vec<f64>,
    /// Eigenvectors (columns), row-major.
    b: Vec<f64>,
    /// Square roots of the eigenvalues.
    d: Vec<f64>,
    /// B · diag(D), row-major.
    bd: Vec<f64>,
    gens_since_eigen: usize,
    generation: usize,
    arz: Vec<f64>,
    ary: Vec<f64>,
    /// Whether sample k was repaired into the box (no negative update from it).
    repaired: Vec<bool>,
    arx: Vec<f64>,
    fit: Vec<f64>,
    asked: usize,
    told: usize,
    idx: Vec<usize>,
    yw: Vec<f64>,
    tmp: Vec<f64>,
    tmp2: Vec<f64>,
    rng: OptRng,
    best_y: Vec<f64>,
    best_f: f64,
    /// pycma's `CMA_elitist` ([`CmaVariant::elitist`]).
    elitist: bool,
    /// The injected best-so-far step of this generation (elitist), and the ranking: sample
    /// indices, `usize::MAX` for the injected step.
    injected: Vec<f64>,
    ranked: Vec<usize>,
    restarts: usize,
    mahal_max: f64,
    history: std::collections::VecDeque<f64>,
}

impl Cma {
    /// CMA with the parameters of `preset` and the update variant `variant`.
    pub fn with_variant(problem: &Problem, preset: Preset, variant: CmaVariant, seed: u64) -> Self {
        let n = problem.dim();
        let (norm, sigma0, mut params) = match preset {
            Preset::Nevergrad => (problem.scale.clone(), 1.0, CmaParams::tutorial(n)),
            Preset::Paper001 => (vec![1.0; n], 0.5, CmaParams::hansen2004(n)),
        };
        if let Some(lambda) = variant.popsize {
            params = params.with_lambda(n, lambda.max(2));
        }
        if variant.diagonal {
            params = params.separable(n);
        }
        let mut cma = Self::new(problem, norm, sigma0, params, seed);
        cma.elitist = variant.elitist;
        cma
    }

    /// CMA with the parameters of `preset` (see the module docs).
    pub fn with_preset(problem: &Problem, preset: Preset, seed: u64) -> Self {
        Self::with_variant(problem, preset, CmaVariant::default(), seed)
    }

    /// General constructor: search space `x = start + norm ⊙ y`, initial step σ0 in `y` units.
    /// Inconsistent hand-made `params` are replaced by the defaults of their style.
    pub fn new(
        problem: &Problem,
        norm: Vec<f64>,
        sigma0: f64,
        params: CmaParams,
        seed: u64,
    ) -> Self {
        let n = problem.dim();
        let params = if params.is_consistent() {
            params
        } else {
            params.with_lambda(n, default_lambda(n))
        };
        let lambda = params.lambda;
        let norm: Vec<f64> = (0..n)
            .map(|j| match norm.get(j) {
                Some(&v) if v.is_finite() && v > 0.0 => v,
                _ => problem.scale[j],
            })
            .collect();
        let sigma0 = if sigma0.is_finite() && sigma0 > 0.0 {
            sigma0
        } else {
            1.0
        };
        let nf = n as f64;
        let mut cma = Cma {
            name: "cma".to_string(),
            bounds: problem.bounds.clone(),
            start: problem.start.clone(),
            norm,
            n,
            eigen_gap: params.eigen_gap(n),
            lambda0: lambda,
            p: params,
            sigma0,
            sigma: sigma0,
            mean: vec![0.0; n],
            pc: vec![0.0; n],
            ps: vec![0.0; n],
            c: vec![0.0; n * n],
            b: vec![0.0; n * n],
            d: vec![1.0; n],
            bd: vec![0.0; n * n],
            gens_since_eigen: 0,
            generation: 0,
            arz: vec![0.0; lambda * n],
            ary: vec![0.0; lambda * n],
            repaired: vec![false; lambda],
            arx: vec![0.0; lambda * n],
            fit: vec![f64::INFINITY; lambda],
            asked: 0,
            told: 0,
            idx: (0..lambda).collect(),
            yw: vec![0.0; n],
            tmp: vec![0.0; n],
            tmp2: vec![0.0; n],
            rng: util::rng(seed),
            best_y: vec![0.0; n],
            best_f: f64::INFINITY,
            elitist: false,
            injected: vec![0.0; n],
            ranked: Vec::with_capacity(lambda + 1),
            restarts: 0,
            mahal_max: nf.sqrt() + 2.0 * nf / (nf + 2.0),
            history: std::collections::VecDeque::new(),
        };
        cma.reset_distribution(vec![0.0; n]);
        cma
    }

    /// Current global step size σ (in `y` units).
    pub fn sigma(&self) -> f64 {
        self.sigma
    }

    /// The strategy parameters in use.
    pub fn params(&self) -> &CmaParams {
        &self.p
    }

    /// Number of restarts so far.
    pub fn restarts(&self) -> usize {
        self.restarts
    }

    /// Distribution mean in x units.
    pub fn mean_x(&self) -> Vec<f64> {
        let mut x: Vec<f64> = (0..self.n)
            .map(|j| self.start[j] + self.norm[j] * self.mean[j])
            .collect();
        self.bounds.clip(&mut x);
        x
    }

    /// Per-coordinate standard deviation of the sampling distribution in x units:
    /// `σ · √C_ii · norm_i`.
    pub fn std_x(&self) -> Vec<f64> {
        (0..self.n)
            .map(|j| self.sigma * self.c[j * self.n + j].max(0.0).sqrt() * self.norm[j])
            .collect()
    }

    /// Best point told so far (x units) and its value.
    pub fn best(&self) -> (Vec<f64>, f64) {
        let mut x: Vec<f64> = (0..self.n)
            .map(|j| self.start[j] + self.norm[j] * self.best_y[j])
            .collect();
        self.bounds.clip(&mut x);
        (x, self.best_f)
    }

    fn reset_distribution(&mut self, mean: Vec<f64>) {
        let n = self.n;
        self.mean = mean;
        self.sigma = self.sigma0;
        self.pc.iter_mut().for_each(|v| *v = 0.0);
        self.ps.iter_mut().for_each(|v| *v = 0.0);
        for i in 0..n {
            for j in 0..n {
                let v = if i == j { 1.0 } else { 0.0 };
                self.c[i * n + j] = v;
                self.b[i * n + j] = v;
                self.bd[i * n + j] = v;
            }
            self.d[i] = 1.0;
        }
        self.generation = 0;
        self.gens_since_eigen = 0;
        self.history.clear();
        self.asked = 0;
        self.told = 0;
    }

    fn restart(&mut self) {
        self.restarts += 1;
        let n = self.n;
        let lambda = (self.p.lambda * 2).min(self.lambda0 << MAX_IPOP_DOUBLINGS);
        if lambda != self.p.lambda {
            self.p = self.p.with_lambda(n, lambda);
            self.eigen_gap = self.p.eigen_gap(n);
            self.arz.resize(lambda * n, 0.0);
            self.ary.resize(lambda * n, 0.0);
            self.repaired.resize(lambda, false);
            self.arx.resize(lambda * n, 0.0);
            self.fit.resize(lambda, f64::INFINITY);
            self.idx = (0..lambda).collect();
        }
        self.reset_distribution(vec![0.0; n]);
    }

    /// Current population size λ (doubles at every restart, IPOP).
    pub fn lambda(&self) -> usize {
        self.p.lambda
    }

    fn sample_generation(&mut self) {
        let n = self.n;
        for k in 0..self.p.lambda {
            let z = &mut self.arz[k * n..(k + 1) * n];
            for v in z.iter_mut() {
                *v = util::normal(&mut self.rng);
            }
            let y = &mut self.ary[k * n..(k + 1) * n];
            for (yi, row) in y.iter_mut().zip(self.bd.chunks_exact(n)) {
                *yi = row.iter().zip(z.iter()).map(|(a, b)| a * b).sum();
            }
            let x = &mut self.arx[k * n..(k + 1) * n];
            let mut repaired = false;
            for j in 0..n {
                let raw = self.start[j] + self.norm[j] * (self.mean[j] + self.sigma * y[j]);
                let (lo, hi) = (self.bounds.lower[j], self.bounds.upper[j]);
                let xc = if raw.is_nan() {
                    self.start[j].clamp(lo, hi)
                } else {
                    raw.clamp(lo, hi)
                };
                x[j] = xc;
                if xc != raw {
                    repaired = true;
                    y[j] = ((xc - self.start[j]) / self.norm[j] - self.mean[j]) / self.sigma;
                }
            }
            self.repaired[k] = repaired;
            if repaired {
                // Mahalanobis length of the repaired step.
                let m = mahalanobis_squared(&self.b, &self.d, y).sqrt();
                if m.is_finite() && m > self.mahal_max {
                    let f = self.mahal_max / m;
                    y.iter_mut().for_each(|v| *v *= f);
                }
            }
        }
    }

    fn update(&mut self) {
        let n = self.n;
        let lambda = self.p.lambda;
        let mu = self.p.mu;
        let fit = &self.fit;
        self.idx.iter_mut().enumerate().for_each(|(i, v)| *v = i);
        self.idx.sort_by(|&a, &b| fit[a].total_cmp(&fit[b]));

        // Flat fitness (purecma): enlarge σ.
        let kflat = ((0.1 + lambda as f64 / 4.0).ceil() as usize).min(lambda - 1);
        if self.fit[self.idx[0]] == self.fit[self.idx[kflat]] {
            self.sigma *= (0.2 + self.p.cs / self.p.ds).exp();
        }

        // The ranking: the generation's samples, best first; with elitism the best point so far
        // goes first when it beats them, its step rescaled to a random Mahalanobis length.
        self.ranked.clear();
        if self.elitist && self.best_f < self.fit[self.idx[0]] {
            for j in 0..n {
                self.injected[j] = (self.best_y[j] - self.mean[j]) / self.sigma;
            }
            let m = mahalanobis_squared(&self.b, &self.d, &self.injected).sqrt();
            if m.is_finite() && m > 0.0 {
                let r = (0..n)
                    .map(|_| util::normal(&mut self.rng).powi(2))
                    .sum::<f64>()
                    .sqrt();
                self.injected.iter_mut().for_each(|v| *v *= r / m);
                self.ranked.push(usize::MAX);
            }
        }
        let idx = self.idx.clone();
        self.ranked.extend(idx);
        let total = self.ranked.len();

        // Weighted mean step.
        self.yw.iter_mut().for_each(|v| *v = 0.0);
        for k in 0..mu {
            let w = self.p.weights[k];
            let y: &[f64] = match self.ranked[k] {
                usize::MAX => &self.injected,
                i => &self.ary[i * n..(i + 1) * n],
            };
            for (a, &b) in self.yw.iter_mut().zip(y) {
                *a += w * b;
            }
        }
        for j in 0..n {
            self.mean[j] += self.sigma * self.yw[j];
        }

        // C^{-1/2} yw = B D^{-1} Bᵀ yw.
        self.tmp.iter_mut().for_each(|v| *v = 0.0);
        for i in 0..n {
            let yi = self.yw[i];
            let row = &self.b[i * n..(i + 1) * n];
            for (t, &bij) in self.tmp.iter_mut().zip(row) {
                *t += bij * yi;
            }
        }
        for (t, d) in self.tmp.iter_mut().zip(&self.d) {
            *t /= d;
        }
        for i in 0..n {
            let row = &self.b[i * n..(i + 1) * n];
            self.tmp2[i] = row.iter().zip(&self.tmp).map(|(a, b)| a * b).sum();
        }

        let p = &self.p;
        let csn = (p.cs * (2.0 - p.cs) * p.mueff).sqrt();
        for (ps, z) in self.ps.iter_mut().zip(&self.tmp2) {
            *ps = (1.0 - p.cs) * *ps + csn * z;
        }
        let ps_norm = self.ps.iter().map(|v| v * v).sum::<f64>().sqrt();
        let gen1 = (self.generation + 1) as f64;
        let hsig = ps_norm / (1.0 - (1.0 - p.cs).powf(2.0 * gen1)).sqrt()
            < (1.4 + 2.0 / (n as f64 + 1.0)) * p.chi_n;
        let ccn = if hsig {
            (p.cc * (2.0 - p.cc) * p.mueff).sqrt()
        } else {
            0.0
        };
        for (pc, y) in self.pc.iter_mut().zip(&self.yw) {
            *pc = (1.0 - p.cc) * *pc + ccn * y;
        }

        // Covariance (upper triangle). With active CMA the decay is 1 − c1 − cµ Σ_all w
        // (tutorial eq. 47), the negative weights entering as w° = w n / ‖C^{-1/2} y‖².
        let delta_h = if hsig { 0.0 } else { p.cc * (2.0 - p.cc) };
        let sum_w: f64 = 1.0 + p.negative_weights.iter().sum::<f64>();
        let factor = 1.0 - p.c1 - p.cmu * sum_w + p.c1 * delta_h;
        for i in 0..n {
            let a = p.c1 * self.pc[i];
            for j in i..if p.separable { i + 1 } else { n } {
                let cij = &mut self.c[i * n + j];
                *cij = factor * *cij + a * self.pc[j];
            }
        }
        let first_negative = total - p.negative_weights.len();
        let diagonal = p.separable;
        for k in (0..mu).chain(first_negative..total) {
            let y: &[f64] = match self.ranked[k] {
                usize::MAX => &self.injected,
                i => &self.ary[i * n..(i + 1) * n],
            };
            let wk = if k < mu {
                p.cmu * p.weights[k]
            } else if self.ranked[k] == usize::MAX || self.repaired[self.ranked[k]] {
                // A repaired step is not a sample of the distribution: it only shortens C
                // along the box's faces, so it gets no negative weight (lfit choice).
                continue;
            } else {
                let m2 = mahalanobis_squared(&self.b, &self.d, y);
                if !(m2.is_finite() && m2 > 0.0) {
                    continue;
                }
                p.cmu * p.negative_weights[k - first_negative] * n as f64 / m2
            };
            for i in 0..n {
                let a = wk * y[i];
                if diagonal {
                    self.c[i * n + i] += a * y[i];
                    continue;
                }
                let row = &mut self.c[i * n + i..(i + 1) * n];
                for (cij, &yj) in row.iter_mut().zip(&y[i..]) {
                    *cij += a * yj;
                }
            }
        }

        // Step size (exponent capped at 1 as in purecma).
        self.sigma *= ((p.cs / p.ds) * (ps_norm / p.chi_n - 1.0)).min(1.0).exp();
        self.generation += 1;
        self.gens_since_eigen += 1;

        let mut ok = self.sigma.is_finite() && self.mean.iter().all(|v| v.is_finite());
        if ok && self.gens_since_eigen >= self.eigen_gap {
            ok = self.eigen();
        }
        if ok {
            let spread = self.sigma * self.d.iter().cloned().fold(0.0, f64::max);
            ok = spread > TOL_X * self.sigma0 && spread < TOL_UP_SIGMA * self.sigma0;
        }
        if ok {
            // TolFun on the recent best values plus the current generation.
            let len = 10 + (30 * n).div_ceil(lambda);
            self.history.push_back(self.fit[self.idx[0]]);
            while self.history.len() > len {
                self.history.pop_front();
            }
            if self.history.len() == len {
                let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
                for &v in self.history.iter().chain(self.fit.iter()) {
                    lo = lo.min(v);
                    hi = hi.max(v);
                }
                let range = hi - lo;
                ok = range.is_nan() || range >= TOL_FUN;
            }
        }
        if !ok {
            self.restart();
        }
    }

    /// Symmetrises C, decomposes it, refreshes B, D, B·D. Returns false if C is unusable.
    fn eigen(&mut self) -> bool {
        let n = self.n;
        self.gens_since_eigen = 0;
        if self.p.separable {
            // Diagonal C: B = I, D = √diag(C).
            let (mut lo, mut hi) = (f64::INFINITY, 0.0f64);
            for i in 0..n {
                let v = self.c[i * n + i];
                if !v.is_finite() || v <= 0.0 {
                    return false;
                }
                lo = lo.min(v);
                hi = hi.max(v);
                self.d[i] = v.sqrt();
                self.bd[i * n + i] = self.d[i];
            }
            return hi / lo <= MAX_COND;
        }
        for i in 0..n {
            for j in 0..i {
                self.c[i * n + j] = self.c[j * n + i];
            }
        }
        if !self.c.iter().all(|v| v.is_finite()) {
            return false;
        }
        let m = DMatrix::from_row_slice(n, n, &self.c);
        let Some(e) = SymmetricEigen::try_new(m, f64::EPSILON, 100_000) else {
            return false;
        };
        let (mut lo, mut hi) = (f64::INFINITY, 0.0f64);
        for &v in e.eigenvalues.iter() {
            if !v.is_finite() {
                return false;
            }
            lo = lo.min(v);
            hi = hi.max(v);
        }
        if lo <= 0.0 || hi / lo > MAX_COND {
            return false;
        }
        for i in 0..n {
            self.d[i] = e.eigenvalues[i].sqrt();
        }
        for i in 0..n {
            for j in 0..n {
                let bij = e.eigenvectors[(i, j)];
                self.b[i * n + j] = bij;
                self.bd[i * n + j] = bij * self.d[j];
            }
        }
        true
    }
}

impl Optimizer for Cma {
    fn name(&self) -> &str {
        &self.name
    }

    fn ask(&mut self, max: usize) -> Vec<Vec<f64>> {
        let n = self.n;
        if self.told < self.asked {
            // The previous ask was not fully told: ask those points again.
            self.asked = self.told;
        }
        if self.asked == 0 {
            self.sample_generation();
        }
        let k = max.max(1).min(self.p.lambda - self.asked);
        let out = (self.asked..self.asked + k)
            .map(|i| self.arx[i * n..(i + 1) * n].to_vec())
            .collect();
        self.asked += k;
        out
    }

    fn tell(&mut self, _xs: &[Vec<f64>], values: &[f64]) {
        let n = self.n;
        for &v in values {
            if self.told >= self.asked {
                break;
            }
            let v = util::sanitize(v);
            let k = self.told;
            self.fit[k] = v;
            if v < self.best_f {
                self.best_f = v;
                for j in 0..n {
                    self.best_y[j] = (self.arx[k * n + j] - self.start[j]) / self.norm[j];
                }
            }
            self.told += 1;
        }
        if self.told == self.p.lambda {
            self.update();
            self.asked = 0;
            self.told = 0;
        }
    }

    fn bounds(&self) -> &Bounds {
        &self.bounds
    }
}

#[cfg(test)]
mod tests {
    use super::super::{Method, Outcome, Preset, build, minimize, testfns};
    use super::*;

    fn evals_to(out: &Outcome, target: f64) -> Option<usize> {
        out.trace
            .iter()
            .find(|&&(_, v)| v < target)
            .map(|&(e, _)| e)
    }

    fn run(f: fn(&[f64]) -> f64, d: usize, budget: usize, seed: u64) -> Outcome {
        let p = testfns::problem(d);
        let mut o = build(Method::CMA, Preset::Nevergrad, &p, budget, seed, None).unwrap();
        minimize(o.as_mut(), &f, budget, false).unwrap()
    }

    #[test]
    fn separable_and_elitist_variants_converge_and_keep_their_rates_over_restarts() {
        let evals = |variant: CmaVariant, f: fn(&[f64]) -> f64, d: usize, seed: u64| {
            let p = testfns::problem(d);
            let mut o = Cma::with_variant(&p, Preset::Nevergrad, variant, seed);
            evals_to(&minimize(&mut o, &f, 60_000, false).unwrap(), 1e-8)
        };
        let diag = CmaVariant {
            diagonal: true,
            ..CmaVariant::default()
        };
        // On the axis-parallel ellipsoid at d = 30 the separable update learns the n variances
        // with rates ~n times larger than the full update's: far fewer evaluations.
        let mut full: Vec<usize> = (0..3)
            .map(|s| evals(CmaVariant::default(), testfns::ellipsoid, 30, s).unwrap())
            .collect();
        let mut sep: Vec<usize> = (0..3)
            .map(|s| evals(diag, testfns::ellipsoid, 30, s).unwrap())
            .collect();
        full.sort_unstable();
        sep.sort_unstable();
        assert!(2 * sep[1] < full[1], "separable {sep:?} vs full {full:?}");
        // Elitism keeps full CMA convergent on sphere and Rosenbrock; the separable elitist
        // variant (nevergrad 1.0's CMA on bounded domains) converges on separable functions (on
        // Rosenbrock neither it nor pycma's reaches 1e-8 in 60,000 evaluations).
        let elitist = CmaVariant {
            elitist: true,
            ..CmaVariant::default()
        };
        let bounded = CmaVariant {
            diagonal: true,
            elitist: true,
            popsize: Some(7),
        };
        for (variant, f) in [
            (elitist, testfns::sphere as fn(&[f64]) -> f64),
            (elitist, testfns::rosenbrock),
            (bounded, testfns::sphere),
            (bounded, testfns::ellipsoid),
        ] {
            assert!(evals(variant, f, 10, 1).is_some(), "{variant:?}");
        }
        // The separable rates (pycma's) survive a population change (IPOP restart).
        let p = CmaParams::tutorial(30).separable(30);
        assert!((p.c1 - 1.0 / (30.0 + 2.0 * 30f64.sqrt() + p.mueff / 30.0)).abs() < 1e-15);
        let q = p.with_lambda(30, 2 * p.lambda);
        assert!(
            q.separable
                && q.lambda == 2 * p.lambda
                && q.c1 > 5.0 * CmaParams::tutorial_with_lambda(30, q.lambda).c1
        );
        assert!(!q.negative_weights.is_empty() && q.is_consistent());
    }

    /// Evaluations to 1e-8 at d = 10, median over seeds 0..11, against pycma 4.5.0's defaults
    /// (active CMA) in the same setting ([-5, 5]^10, start 0, σ0 = 1), whose medians
    /// docs/results/pycma_reference.py recorded in docs/results/pycma_reference.json.
    #[test]
    fn active_cma_needs_at_most_1_1x_pycmas_evaluations_at_d10() {
        let reference: serde_json::Value =
            serde_json::from_str(include_str!("../../../docs/results/pycma_reference.json"))
                .unwrap();
        let mut active_ellipsoid = 0;
        for (name, f) in [
            ("sphere", testfns::sphere as fn(&[f64]) -> f64),
            ("ellipsoid", testfns::ellipsoid),
            ("rosenbrock", testfns::rosenbrock),
        ] {
            let mut evals: Vec<usize> = (0..11)
                .map(|seed| evals_to(&run(f, 10, 30_000, seed), 1e-8).unwrap_or(usize::MAX))
                .collect();
            evals.sort_unstable();
            let ours = evals[5];
            let pycma = reference["median_evals_to_1e-8"][name]["median"]
                .as_u64()
                .unwrap() as usize;
            eprintln!(
                "{name}: lfit median {ours}, pycma {pycma} ({:.2}×)",
                ours as f64 / pycma as f64
            );
            if name == "ellipsoid" {
                active_ellipsoid = ours;
            }
            assert!(
                ours as f64 <= 1.1 * pycma as f64,
                "{name}: median {ours} evaluations vs pycma's {pycma}: {evals:?}"
            );
        }
        // Without the active update the ellipsoid needs clearly more (the reason it exists).
        let p = testfns::problem(10);
        let mut plain: Vec<usize> = (0..11)
            .map(|seed| {
                let mut o = Cma::new(
                    &p,
                    p.scale.clone(),
                    1.0,
                    CmaParams::tutorial(10).without_active(),
                    seed,
                );
                evals_to(
                    &minimize(&mut o, &testfns::ellipsoid, 30_000, false).unwrap(),
                    1e-8,
                )
                .unwrap_or(usize::MAX)
            })
            .collect();
        plain.sort_unstable();
        eprintln!("ellipsoid without active CMA: median {}", plain[5]);
        assert!(
            plain[5] as f64 > 1.3 * active_ellipsoid as f64,
            "active {active_ellipsoid} vs plain {}",
            plain[5]
        );
    }

    #[test]
    fn default_parameters_match_the_tutorial() {
        let p = CmaParams::tutorial(10);
        assert_eq!(p.lambda, 10);
        assert_eq!(p.mu, 5);
        assert!((p.weights.iter().sum::<f64>() - 1.0).abs() < 1e-12);
        assert!(p.weights.windows(2).all(|w| w[0] > w[1]));
        // Values from Hansen's tutorial formulas for n = 10, λ = 10 (µ_eff ≈ 3.1672).
        assert!((p.mueff - 3.1672).abs() < 1e-3, "{}", p.mueff);
        assert!((p.cs - (p.mueff + 2.0) / (10.0 + p.mueff + 5.0)).abs() < 1e-15);
        assert!(p.c1 > 0.0 && p.cmu > 0.0 && p.c1 + p.cmu <= 1.0);
        let q = CmaParams::hansen2004(43);
        assert_eq!(q.lambda, 15);
        assert!(q.c1 + q.cmu <= 1.0 && q.cc == 4.0 / 47.0);
        assert_eq!(CmaParams::tutorial(1).lambda, 4);
    }

    #[test]
    fn sphere_10_to_1e8() {
        // Measured with examples/cma_convergence.rs, evaluations to f < 1e-8 over seeds 0..10:
        // median 1306 (1213 .. 1481).
        let out = run(testfns::sphere, 10, 2500, 1);
        let e = evals_to(&out, 1e-8);
        assert!(
            e.is_some_and(|e| e <= 2500),
            "{:?} best {}",
            e,
            out.best_value
        );
    }

    #[test]
    fn ellipsoid_10_to_1e8() {
        // Measured: median 5859 (5281 .. 6124) over seeds 0..10.
        let out = run(testfns::ellipsoid, 10, 8000, 1);
        let e = evals_to(&out, 1e-8);
        assert!(
            e.is_some_and(|e| e <= 8000),
            "{:?} best {}",
            e,
            out.best_value
        );
    }

    #[test]
    fn rosenbrock_10_to_1e8() {
        // Measured: median 6045 (4835 .. 13572) over seeds 0..10; seed 4 first converges to the
        // local minimum near x1 = -1 and needs an IPOP restart (13572).
        let out = run(testfns::rosenbrock, 10, 15000, 1);
        let e = evals_to(&out, 1e-8);
        assert!(
            e.is_some_and(|e| e <= 15000),
            "{:?} best {}",
            e,
            out.best_value
        );
    }

    #[test]
    fn ipop_restart_escapes_the_rosenbrock_local_minimum() {
        let p = testfns::problem(10);
        let mut o = Cma::with_preset(&p, Preset::Nevergrad, 4);
        let out = minimize(&mut o, &testfns::rosenbrock, 15000, false).unwrap();
        assert!(o.restarts() >= 1);
        assert_eq!(o.lambda(), 10 << o.restarts());
        assert!(out.best_value < 1e-8, "{}", out.best_value);
    }

    #[test]
    fn sphere_40_to_1e8() {
        // Measured: 4588 .. 4970 evaluations over seeds 0..4.
        let out = run(testfns::sphere, 40, 12000, 2);
        let e = evals_to(&out, 1e-8);
        assert!(
            e.is_some_and(|e| e <= 12000),
            "{:?} best {}",
            e,
            out.best_value
        );
    }

    #[test]
    fn paper_preset_converges_on_sphere() {
        let p = testfns::problem(10);
        let mut o = build(Method::CMA, Preset::Paper001, &p, 4000, 3, None).unwrap();
        let out = minimize(o.as_mut(), &testfns::sphere, 4000, false).unwrap();
        assert!(out.best_value < 1e-8, "{}", out.best_value);
    }

    #[test]
    fn repaired_mean_stays_in_bounds_and_finds_boundary_optimum() {
        // Optimum (1,…,1) outside [2, 5]^d: the constrained optimum is the corner (2,…,2).
        let d = 8;
        let p = Problem::new(
            Bounds::uniform(d, 2.0, 5.0).unwrap(),
            vec![3.5; d],
            vec![1.0; d],
        )
        .unwrap();
        let mut o = Cma::with_preset(&p, Preset::Nevergrad, 4);
        let out = minimize(&mut o, &testfns::sphere, 3000, false).unwrap();
        assert!(p.bounds.contains(&o.mean_x()));
        assert!(
            (out.best_value - d as f64).abs() < 1e-6,
            "{}",
            out.best_value
        );
    }

    #[test]
    fn initial_steps_follow_scale() {
        let d = 4;
        let mut p = testfns::problem(d);
        p.scale = vec![1e-3, 1e-3, 1.0, 1.0];
        let mut o = Cma::with_preset(&p, Preset::Nevergrad, 1);
        let xs = o.ask(100);
        let small = xs
            .iter()
            .map(|x| x[0].abs().max(x[1].abs()))
            .fold(0.0, f64::max);
        let big = xs
            .iter()
            .map(|x| x[2].abs().max(x[3].abs()))
            .fold(0.0, f64::max);
        assert!(small < 0.01 && big > 0.1, "{small} {big}");
        let s = o.std_x();
        assert!((s[0] - 1e-3).abs() < 1e-15 && (s[3] - 1.0).abs() < 1e-15);
    }

    #[test]
    fn flat_function_does_not_break_it() {
        let p = testfns::problem(5);
        let mut o = Cma::with_preset(&p, Preset::Nevergrad, 1);
        let out = minimize(&mut o, &|_: &[f64]| 1.0, 2000, false).unwrap();
        assert_eq!(out.evaluations, 2000);
        let nan = minimize(&mut o, &|_: &[f64]| f64::NAN, 500, false).unwrap();
        assert_eq!(nan.best_value, f64::INFINITY);
    }
}
