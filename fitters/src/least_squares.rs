//! Gauss-Newton and Levenberg–Marquardt on the energy's least-squares form
//! ([`Energy::least_squares`]: residuals with `E = Σ r²` and their exact Jacobian).
//!
//! **Levenberg–Marquardt** is the trust-region method as Ceres Solver runs it: the step solves
//! `(JᵀJ + μ D) h = −Jᵀr` by Cholesky in envelope form, the entries ordered children before
//! parents so the factor has no fill ([`damped_step`], `Template::elimination_rank`), with
//! `D = diag(JᵀJ)` clamped to `[1e-6, 1e32]` (Marquardt's scaling, so metres, radians and shape
//! coefficients need no hand-set scales) and raised to at least `3e-3 max(D)` (lfit's
//! `scaling_floor`, below), and `μ = 1/radius`. The radius
//! starts at 1e4 and follows Nielsen's update: on a step with gain ratio `ρ > 1e-3` the radius is
//! divided by `max(1/3, 1 − (2ρ − 1)³)` and the growth factor reset to 2; on a failed step it is
//! divided by the growth factor, which doubles. The defaults are Ceres's
//! (`Solver::Options`: `initial_trust_region_radius` 1e4, `min_relative_decrease` 1e-3,
//! `gradient_tolerance` 1e-10, `parameter_tolerance` 1e-8) but the function tolerance: 1e-5,
//! not Ceres's 1e-6, measured on the MakeHuman body (issue 26, `docs/results/cost-model.md`,
//! 2026-12-03): with the box step below, 20–25 % fewer evaluations on 500 held-out frames per
//! sparse modality and on the captured clip, mean energies equal to four digits, V2V within
//! 0.1 %, and scipy's parity test passing. (Measured before the box step, 1e-5 left one face frame
//! of that test 1.03 % above scipy's energy, and 1e-6 stayed then.)
//!
//! **The scaling's floor** (`LeastSquaresOptions::scaling_floor`, 3e-3; not in Ceres, whose
//! floor is the absolute `min_lm_diagonal` 1e-6): an entry the data barely see (a finger joint
//! of the MakeHuman body under 39 markers, a twist under head and hand tracking) has a diagonal
//! of `JᵀJ` orders of magnitude below the largest, so Marquardt's damping `μ D` barely restrains
//! it: the Gauss-Newton step sends it across its whole box, the next step back (a trace of LM
//! on MakeHuman markers frames: one finger angle hopped ±0.52 rad for 6 accepted iterations
//! while the energy fell by 1 %), and LM converges linearly: the behaviour of Marquardt's
//! scaling on sloppy models that Transtrum & Sethna discuss ("Improvements to the
//! Levenberg-Marquardt algorithm for nonlinear least-squares minimization", 2012). Flooring `D`
//! relative to its largest entry damps those entries like the well-determined ones once the
//! radius shrinks; the other entries keep Marquardt's scale invariance. Chosen by measurement (issue 26,
//! `docs/results/makehuman-import.md`, 2026-12-03 night): on 500 held-out MakeHuman frames per
//! sparse modality and the captured clip, evaluations fell 15–20 % on markers, ~9 % on
//! keypoints2d and ~4 % on hmd for floors 1e-3–1e-2, mean energies equal or lower and V2V
//! lower; 3e-3 had the fewest in total.
//!
//! **Gauss-Newton** solves `JᵀJ h = −Jᵀr` (a 1e-12 relative ridge keeps a rank-deficient system
//! solvable) and halves the step until the energy decreases.
//!
//! **Bounds**: a coordinate at a bound whose descent direction points out of the box is held for
//! that step (the active set). LM's step is the minimiser of its damped quadratic model inside
//! the box (`box_step`: a primal active-set method on one factorisation of the damped system per
//! working set, Nocedal & Wright 2006, Algorithm 16.3), so every trial point is inside the box
//! and predicts a decrease; the predicted decrease uses that step. Gauss-Newton projects its step
//! onto the box.
//!
//! **Stopping**, as Ceres: the projected gradient `‖x − Π(x − ∇E)‖∞ ≤ gradient_tolerance`, a step
//! `‖Δx‖ ≤ parameter_tolerance (‖x‖ + parameter_tolerance)`, a relative decrease
//! `ΔE ≤ function_tolerance · E`, or the budget: one evaluation = one residual vector at a new
//! point, a cap as for L-BFGS. Trial points are evaluated without the Jacobian; an accepted point
//! gets its Jacobian then (counted as a gradient evaluation: a rejected trial costs only its
//! residuals).

use lfit_model::energy::{DampedFactor, Energy, JacobianRows, RobustForm, marquardt_scaling};
use lfit_model::pose::Bounds;
use nalgebra::DVector;
use serde::Serialize;

use crate::error::FitError;
use crate::fitter::{
    FitRequest, FitResult, Fitter, StageOutcome, StageSolver, Strategy, run_staged,
};

/// The step of one damped Gauss-Newton system (moved to the model crate, where the neural
/// fitter's Gauss-Newton direction uses it too).
pub use lfit_model::energy::damped_step;

/// Which least-squares method.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum LeastSquaresMethod {
    /// Levenberg–Marquardt (trust region, Nielsen's damping update).
    Lm,
    /// Gauss-Newton with step halving.
    Gn,
}

impl LeastSquaresMethod {
    pub fn name(self) -> &'static str {
        match self {
            LeastSquaresMethod::Lm => "lm",
            LeastSquaresMethod::Gn => "gn",
        }
    }
}

/// Stopping rules and trust-region settings (defaults: Ceres Solver's `Solver::Options`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LeastSquaresOptions {
    pub function_tolerance: f64,
    pub gradient_tolerance: f64,
    pub parameter_tolerance: f64,
    pub initial_trust_region_radius: f64,
    pub min_relative_decrease: f64,
    /// LM's scaling `D` is raised to at least this fraction of its largest entry (see the
    /// module's notes; 0: Ceres's scaling).
    pub scaling_floor: f64,
    /// How the robust loss enters the normal equations: folded (default: the exact Jacobian of
    /// `√ρ`-folded residuals, the least-squares problem `objective-server` serves) or Triggs's
    /// correction (IRLS weights for the losses here). Both have E's exact gradient.
    pub robust: RobustForm,
}

impl Default for LeastSquaresOptions {
    fn default() -> Self {
        Self {
            function_tolerance: 1e-5,
            gradient_tolerance: 1e-10,
            parameter_tolerance: 1e-8,
            initial_trust_region_radius: 1e4,
            min_relative_decrease: 1e-3,
            scaling_floor: 3e-3,
            robust: RobustForm::Folded,
        }
    }
}

/// Gauss-Newton or Levenberg–Marquardt under a strategy (normally holistic).
#[derive(Debug, Clone, Copy)]
pub struct LeastSquaresFitter {
    pub method: LeastSquaresMethod,
    pub strategy: Strategy,
    pub options: LeastSquaresOptions,
}

impl LeastSquaresFitter {
    pub fn new(method: LeastSquaresMethod, strategy: Strategy) -> Self {
        Self {
            method,
            strategy,
            options: LeastSquaresOptions::default(),
        }
    }
}

impl Fitter for LeastSquaresFitter {
    fn name(&self) -> String {
        let base = match self.options.robust {
            RobustForm::Folded => self.method.name().to_string(),
            RobustForm::Triggs => format!("{}-triggs", self.method.name()),
        };
        if self.strategy == Strategy::Holistic {
            base
        } else {
            format!("{base}/{}", self.strategy)
        }
    }

    fn fit(&self, request: &FitRequest<'_>) -> Result<FitResult, FitError> {
        if let Some(why) = request.energy.least_squares_unsupported() {
            return Err(FitError::LeastSquares(why));
        }
        run_staged(self.name(), self, self.strategy, request)
    }
}

/// Working-set changes of [`box_step`] at most per factorisation (each costs one solve).
const BOX_CHANGES: usize = 16;

/// Factorisations of [`box_step`] at most, after the ones that take out the entries leaving
/// their bound (at most [`BOX_PEELS`]).
const BOX_FACTORS: usize = 4;

/// Re-factorisations of [`box_step`] that take out the entries the step would move off their
/// bound, at most.
const BOX_PEELS: usize = 4;

/// [`box_step`] takes the entries that its step would move off their bound out of the system by
/// re-factorising when there are more than this many, and holds them through the working set
/// (a solve each) otherwise: a factorisation costs 8–10 solves on the MakeHuman body
/// (`envelope_work`: markers 78 k multiply-adds against 7.7 k, hmd 40 k against 5.1 k).
const BOX_PEEL_ABOVE: usize = 8;

/// Levenberg–Marquardt's step inside the box: the minimiser of the damped model
/// `q(s) = 2gᵀs + sᵀKs`, `K = A + μD + 1e-12 max(D) I` ([`lfit_model::energy::Envelope::damped`],
/// factorised as [`DampedFactor`]), over `lo ≤ s ≤ hi` (`lo ≤ 0 ≤ hi`; every slice indexed like
/// `free`, the positions of `a` and `g` in elimination order), by the primal active-set method
/// for convex quadratic programs (Nocedal & Wright, *Numerical Optimization*, 2nd ed., 2006,
/// Algorithm 16.3) from `s = 0`.
///
/// Entries on a bound that the unconstrained step `h = −K⁻¹g` would leave are held at zero:
/// through the working set below when they are few, otherwise taken out of the system and
/// re-factorised ([`BOX_PEEL_ABOVE`]). On the rest, one factorisation serves every working set
/// `W` of entries held on a bound: with `Z = K⁻¹E_W` (one solve per entry that joins),
/// `s = h + Zλ`, `λ = (E_WᵀZ)⁻¹(t_W − h_W)` for the bound values `t_W`, and `λ` are the
/// entries' Lagrange multipliers (`g + Ks = E_W λ`). A move that meets a bound stops there and
/// adds that entry; at a working set's minimiser, the entry whose multiplier says the model
/// decreases off its bound leaves `W`; at the minimiser over all of them, an entry taken out
/// whose gradient points into the box is put back and the system re-factorised. Every iterate
/// is in the box and lowers `q` (a positive predicted decrease whenever `h ≠ 0`), also when
/// the changes ([`BOX_CHANGES`]) or factorisations ([`BOX_FACTORS`]) run out. Returns the step
/// (indexed like `free`) and whether it is the exact minimiser; `None` when `K` is not
/// positive definite.
///
/// Projecting the unconstrained step, or holding the entries it pushes out on their bound and
/// re-solving the rest once (lfit's step before 2026-12-03), can leave the minimiser in the box
/// far away and even predict an increase: on the MakeHuman body's markers frames ~10 entries
/// sit on joint limits at the solution, and about one trial in three was rejected after a
/// step that predicted an increase (issue 26, `docs/results/cost-model.md`).
#[allow(clippy::too_many_arguments)]
fn box_step(
    a: &nalgebra::DMatrix<f64>,
    g: &DVector<f64>,
    free: &[usize],
    diag: &[f64],
    damping: f64,
    max_diag: f64,
    lo: &[f64],
    hi: &[f64],
    peel_above: usize,
) -> Option<(Vec<f64>, bool)> {
    let m = free.len();
    let scale = free
        .iter()
        .fold(0.0f64, |s, &p| s.max(g[p].abs()))
        .max(f64::MIN_POSITIVE);
    let mut s = vec![0.0; m];
    // Entries in the factorised system, and the working set: (entry, bound value, lower?).
    let mut inside = vec![true; m];
    let mut set: Vec<(usize, f64, bool)> = Vec::new();
    let mut peels = 0;
    let mut factors = 0;
    while factors < BOX_FACTORS {
        let ks: Vec<usize> = (0..m).filter(|&k| inside[k]).collect();
        if ks.is_empty() {
            break;
        }
        let positions: Vec<usize> = ks.iter().map(|&k| free[k]).collect();
        let d: Vec<f64> = ks.iter().map(|&k| diag[k]).collect();
        let factor = DampedFactor::new(a, &positions, &d, damping, max_diag)?;
        // Indices below are into `ks` (the factorised entries).
        let mut h: Vec<f64> = positions.iter().map(|&p| -g[p]).collect();
        if !factor.solve(&mut h) {
            return None;
        }
        if peels < BOX_PEELS {
            peels += 1;
            let leaving: Vec<usize> = (0..ks.len())
                .filter(|&j| {
                    let k = ks[j];
                    (lo[k] == 0.0 && h[j] < 0.0) || (hi[k] == 0.0 && h[j] > 0.0)
                })
                .collect();
            if leaving.len() > peel_above && leaving.len() < ks.len() {
                for j in leaving {
                    inside[ks[j]] = false;
                }
                continue;
            }
            // A few: held through the working set (a solve each), not a re-factorisation.
            for j in leaving {
                let k = ks[j];
                set.push((k, 0.0, lo[k] == 0.0 && h[j] < 0.0));
            }
            peels = BOX_PEELS;
        }
        factors += 1;
        let local = |k: usize| ks.binary_search(&k).ok();
        let column = |j: usize| {
            let mut e = vec![0.0; ks.len()];
            e[j] = 1.0;
            factor.solve(&mut e).then_some(e)
        };
        let mut columns: Vec<Vec<f64>> = Vec::with_capacity(set.len());
        for &(k, _, _) in &set {
            columns.push(column(local(k)?)?);
        }
        let mut held = vec![false; ks.len()];
        for &(k, _, _) in &set {
            held[local(k)?] = true;
        }
        let mut optimal = false;
        for _ in 0..BOX_CHANGES {
            // The minimiser with the working set on its bounds.
            let w = set.len();
            let mut target = h.clone();
            let mut lambda = DVector::<f64>::zeros(w);
            if w > 0 {
                let rows: Vec<usize> = set.iter().map(|e| local(e.0)).collect::<Option<_>>()?;
                let gram = nalgebra::DMatrix::<f64>::from_fn(w, w, |i, j| columns[j][rows[i]]);
                let rhs = DVector::<f64>::from_fn(w, |i, _| set[i].1 - h[rows[i]]);
                lambda = gram.cholesky()?.solve(&rhs);
                for (l, c) in lambda.iter().zip(&columns) {
                    for (t, v) in target.iter_mut().zip(c) {
                        *t += l * v;
                    }
                }
                for (&j, e) in rows.iter().zip(&set) {
                    target[j] = e.1;
                }
            }
            if target.iter().any(|v| !v.is_finite()) {
                return None;
            }
            // Towards it, up to the first bound in the way.
            let mut alpha = 1.0f64;
            let mut block = None;
            for (j, &k) in ks.iter().enumerate().filter(|&(j, _)| !held[j]) {
                let (sk, d) = (s[k], target[j] - s[k]);
                let t = if target[j] > hi[k] && d > 0.0 {
                    (hi[k] - sk) / d
                } else if target[j] < lo[k] && d < 0.0 {
                    (lo[k] - sk) / d
                } else {
                    continue;
                };
                if t < alpha {
                    alpha = t.max(0.0);
                    block = Some((j, d < 0.0));
                }
            }
            for (j, &k) in ks.iter().enumerate() {
                s[k] += alpha * (target[j] - s[k]);
            }
            if let Some((j, lower)) = block {
                let k = ks[j];
                s[k] = if lower { lo[k] } else { hi[k] };
                set.push((k, s[k], lower));
                columns.push(column(j)?);
                held[j] = true;
                continue;
            }
            // The working set's minimiser: release the entry whose multiplier is the most
            // wrong-signed (the model decreases moving it off its bound into the box).
            let worst = set
                .iter()
                .zip(lambda.iter())
                .enumerate()
                .map(|(i, (&(_, _, lower), &l))| (i, if lower { -l } else { l }))
                .filter(|&(_, v)| v > 1e-12 * scale)
                .max_by(|x, y| x.1.total_cmp(&y.1));
            match worst {
                Some((i, _)) => {
                    held[local(set[i].0)?] = false;
                    set.remove(i);
                    columns.remove(i);
                }
                None => {
                    optimal = true;
                    break;
                }
            }
        }
        if !optimal {
            return Some((s, false));
        }
        // Entries taken out (held at zero on their bound) whose gradient `g + Ks` points into
        // the box go back in.
        let mut sv = DVector::<f64>::zeros(g.len());
        for (k, &p) in free.iter().enumerate() {
            sv[p] = s[k];
        }
        let ks_out = a * &sv;
        let back = (0..m)
            .filter(|&k| !inside[k])
            .map(|k| {
                let grad = g[free[k]] + ks_out[free[k]];
                (k, if lo[k] == 0.0 { -grad } else { grad })
            })
            .filter(|&(_, v)| v > 1e-12 * scale)
            .max_by(|x, y| x.1.total_cmp(&y.1));
        match back {
            Some((k, _)) => inside[k] = true,
            None => return Some((s, true)),
        }
    }
    Some((s, false))
}

/// LM's scaling of the damping on the positions `free`: Marquardt's ([`marquardt_scaling`])
/// raised to at least `floor` times its largest entry, and that largest entry.
fn lm_scaling(a: &nalgebra::DMatrix<f64>, free: &[usize], floor: f64) -> (Vec<f64>, f64) {
    let (mut diag, max_diag) = marquardt_scaling(a, free);
    let low = floor * max_diag;
    diag.iter_mut().for_each(|d| *d = d.max(low));
    (diag, max_diag)
}

/// The decrease of `Σr²` that the Gauss-Newton model predicts for the step `s` (over the
/// stage's entries): `−(2 gᵀs + sᵀ A s)` (the IRLS model under Triggs's form).
fn model_decrease(a: &nalgebra::DMatrix<f64>, g: &DVector<f64>, s: &DVector<f64>) -> f64 {
    -(2.0 * g.dot(s) + s.dot(&(a * s)))
}

impl StageSolver for LeastSquaresFitter {
    fn solve(
        &self,
        energy: &Energy,
        pose: &mut [f64],
        dofs: &[usize],
        bounds: &Bounds,
        budget: usize,
        _seed: u64,
    ) -> Result<StageOutcome, FitError> {
        let o = self.options;
        let eval = |x: &[f64], with_jacobian: bool| {
            energy
                .least_squares_with(x, with_jacobian, o.robust, JacobianRows::Factored)
                .map_err(|e| FitError::LeastSquares(e.to_string()))
        };
        // Trial points are evaluated without the Jacobian; an accepted one gets it then (a
        // gradient evaluation, not a second evaluation of the point).
        let jacobian = |x: &[f64]| {
            energy
                .jacobian_with(x, o.robust, JacobianRows::Factored)
                .map_err(|e| FitError::LeastSquares(e.to_string()))
        };
        let mut x = pose.to_vec();
        let mut current = eval(&x, true)?;
        let mut count = 1usize;
        let mut f = current.energy;
        let mut trace = vec![(1u64, f)];
        let mut radius = o.initial_trust_region_radius;
        let mut growth = 2.0;
        let mut iterations = 0u64;
        let n = dofs.len();
        // The systems are solved children before parents (no fill in the Cholesky factor).
        let rank = energy.template().elimination_rank();
        'outer: while count < budget {
            iterations += 1;
            let (a, g) = current.normal_equations(dofs);
            // Projected gradient (∇E = 2 Jᵀr).
            let pg = (0..n).map(|p| {
                let i = dofs[p];
                (x[i] - (x[i] - 2.0 * g[p]).clamp(bounds.lower[i], bounds.upper[i])).abs()
            });
            if pg.fold(0.0f64, f64::max) <= o.gradient_tolerance {
                break;
            }
            // Hold coordinates at a bound that the descent direction leaves.
            let mut free: Vec<usize> = (0..n)
                .filter(|&p| {
                    let i = dofs[p];
                    !((x[i] <= bounds.lower[i] && g[p] > 0.0)
                        || (x[i] >= bounds.upper[i] && g[p] < 0.0))
                })
                .collect();
            free.sort_by_key(|&p| rank[dofs[p]]);
            if free.is_empty() {
                break;
            }
            let (diag, max_diag) = lm_scaling(&a, &free, o.scaling_floor);
            // How far each free entry may move: LM's box (the same for every damping tried).
            let lo: Vec<f64> = free
                .iter()
                .map(|&p| (bounds.lower[dofs[p]] - x[dofs[p]]).min(0.0))
                .collect();
            let hi: Vec<f64> = free
                .iter()
                .map(|&p| (bounds.upper[dofs[p]] - x[dofs[p]]).max(0.0))
                .collect();
            // Gauss-Newton's halving factor along its direction.
            let mut alpha = 1.0;
            loop {
                let damping = match self.method {
                    LeastSquaresMethod::Lm => 1.0 / radius,
                    LeastSquaresMethod::Gn => 0.0,
                };
                let solved = match self.method {
                    // LM: the damped model's minimiser inside the box (`box_step`).
                    LeastSquaresMethod::Lm => box_step(
                        &a,
                        &g,
                        &free,
                        &diag,
                        damping,
                        max_diag,
                        &lo,
                        &hi,
                        BOX_PEEL_ABOVE,
                    )
                    .map(|(h, _)| h),
                    LeastSquaresMethod::Gn => damped_step(&a, &g, &free, &diag, damping, max_diag)
                        .map(|h| h.iter().copied().collect()),
                };
                let Some(h) = solved else {
                    // Not positive definite at this damping: more damping (LM) or give up (GN).
                    match self.method {
                        LeastSquaresMethod::Lm => {
                            radius /= growth;
                            growth *= 2.0;
                            if radius < 1e-32 {
                                break 'outer;
                            }
                            continue;
                        }
                        LeastSquaresMethod::Gn => break 'outer,
                    }
                };
                let mut trial = x.clone();
                for (k, &p) in free.iter().enumerate() {
                    let i = dofs[p];
                    trial[i] = (x[i] + alpha * h[k]).clamp(bounds.lower[i], bounds.upper[i]);
                }
                // The step over every stage entry (the clamp only rounds LM's box step onto its
                // bounds), and the decrease the model predicts for it.
                let step = DVector::<f64>::from_iterator(n, dofs.iter().map(|&i| trial[i] - x[i]));
                let predicted = model_decrease(&a, &g, &step);
                let xnorm = dofs.iter().map(|&i| x[i] * x[i]).sum::<f64>().sqrt();
                if step.norm() <= o.parameter_tolerance * (xnorm + o.parameter_tolerance) {
                    break 'outer;
                }
                let next = eval(&trial, false)?;
                count += 1;
                let f_new = next.energy;
                let accepted = match self.method {
                    LeastSquaresMethod::Lm => {
                        let rho = if predicted > 0.0 {
                            (f - f_new) / predicted
                        } else {
                            -1.0
                        };
                        if rho > o.min_relative_decrease {
                            radius /= (1.0 - (2.0 * rho - 1.0).powi(3)).max(1.0 / 3.0);
                            growth = 2.0;
                            true
                        } else {
                            radius /= growth;
                            growth *= 2.0;
                            false
                        }
                    }
                    LeastSquaresMethod::Gn => f_new < f,
                };
                if accepted {
                    let decrease = f - f_new;
                    x = trial;
                    f = f_new;
                    trace.push((count as u64, f));
                    if decrease <= o.function_tolerance * (f + decrease) {
                        break 'outer;
                    }
                    // The next iteration's normal equations need the Jacobian here.
                    if count >= budget {
                        break 'outer;
                    }
                    current = jacobian(&x)?;
                    continue 'outer;
                }
                if count >= budget {
                    break 'outer;
                }
                match self.method {
                    LeastSquaresMethod::Lm if radius < 1e-32 => break 'outer,
                    LeastSquaresMethod::Lm => {}
                    LeastSquaresMethod::Gn => {
                        alpha *= 0.5;
                        if alpha < 1e-6 {
                            break 'outer;
                        }
                    }
                }
            }
        }
        pose.copy_from_slice(&x);
        Ok(StageOutcome {
            best: f,
            trace,
            iterations,
        })
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod tests {
    use nalgebra::{DMatrix, DVector};
    use rand::{Rng, SeedableRng};

    use super::*;

    /// `q(s) = 2gᵀs + sᵀKs` on the entries `free`.
    fn model(k: &DMatrix<f64>, g: &[f64], s: &[f64]) -> f64 {
        let sv = DVector::from_column_slice(s);
        2.0 * DVector::from_column_slice(g).dot(&sv) + sv.dot(&(k * &sv))
    }

    /// The box step against the minimiser found by trying every active set (each entry free,
    /// on its lower or on its upper bound: 3⁶ equality-constrained solves), on random damped
    /// models whose unconstrained step leaves the box, some entries starting on a bound: the
    /// same step to 1e-9, reported exact, inside the box, and never a higher model value than
    /// the projected step (lfit's step before) or the step that holds the crossing entries on
    /// their bound and re-solves the rest.
    #[test]
    fn lm_scaling_floors_the_diagonal_relative_to_its_largest_entry() {
        let a = DMatrix::from_diagonal(&DVector::from_vec(vec![1e-9, 5.0, 100.0, 0.2, -1.0]));
        // Position 4 is not free: its entry neither counts nor is returned.
        let (d, max) = lm_scaling(&a, &[2, 0, 3, 1], 3e-3);
        assert_eq!(max, 100.0);
        assert_eq!(d, vec![100.0, 0.3, 0.3, 5.0]);
        // Without a floor: Marquardt's scaling, clamped below at 1e-6 as Ceres does.
        let (d, max) = lm_scaling(&a, &[2, 0, 3, 1], 0.0);
        assert_eq!(max, 100.0);
        assert_eq!(d, vec![100.0, 1e-6, 0.2, 5.0]);
    }

    #[test]
    fn the_box_step_is_the_damped_models_minimiser_in_the_box() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
        let n = 6;
        let (mut checked, mut better) = (0, 0);
        for case in 0..300 {
            let j = DMatrix::<f64>::from_fn(n + 3, n, |_, _| rng.random_range(-1.0..1.0));
            let a = j.transpose() * &j;
            let g = DVector::<f64>::from_fn(n, |_, _| rng.random_range(-1.0..1.0));
            // Positions in a scrambled order, as the elimination order lists them.
            let mut free: Vec<usize> = (0..n).collect();
            free.rotate_left(case % n);
            let (diag, max_diag) = marquardt_scaling(&a, &free);
            let damping = 10f64.powf(rng.random_range(-3.0..0.0));
            let mut lo: Vec<f64> = (0..n).map(|_| -rng.random_range(0.02..0.6)).collect();
            let mut hi: Vec<f64> = (0..n).map(|_| rng.random_range(0.02..0.6)).collect();
            for k in 0..n {
                match rng.random_range(0..6) {
                    0 => lo[k] = 0.0,
                    1 => hi[k] = 0.0,
                    _ => {}
                }
            }
            // K and g over `free`'s order.
            let k_mat = DMatrix::<f64>::from_fn(n, n, |r, c| {
                a[(free[r], free[c])]
                    + if r == c {
                        damping * diag[r] + 1e-12 * max_diag
                    } else {
                        0.0
                    }
            });
            let gf: Vec<f64> = free.iter().map(|&p| g[p]).collect();
            let h = k_mat
                .clone()
                .cholesky()
                .unwrap()
                .solve(&-DVector::from_column_slice(&gf));
            if (0..n).all(|k| lo[k] <= h[k] && h[k] <= hi[k]) {
                continue;
            }
            // Every active set: the feasible KKT point of lowest model value.
            let mut best: Option<(f64, Vec<f64>)> = None;
            for code in 0..3usize.pow(n as u32) {
                let state: Vec<usize> = (0..n).map(|k| code / 3usize.pow(k as u32) % 3).collect();
                let mut s = vec![0.0; n];
                for k in 0..n {
                    s[k] = match state[k] {
                        1 => lo[k],
                        2 => hi[k],
                        _ => 0.0,
                    };
                }
                let f: Vec<usize> = (0..n).filter(|&k| state[k] == 0).collect();
                if !f.is_empty() {
                    let kff = DMatrix::<f64>::from_fn(f.len(), f.len(), |r, c| k_mat[(f[r], f[c])]);
                    let rhs = DVector::<f64>::from_fn(f.len(), |r, _| {
                        -gf[f[r]]
                            - (0..n)
                                .filter(|&c| state[c] != 0)
                                .map(|c| k_mat[(f[r], c)] * s[c])
                                .sum::<f64>()
                    });
                    let sf = kff.cholesky().unwrap().solve(&rhs);
                    for (r, &k) in f.iter().enumerate() {
                        s[k] = sf[r];
                    }
                }
                if (0..n).any(|k| s[k] < lo[k] - 1e-12 || s[k] > hi[k] + 1e-12) {
                    continue;
                }
                let q = model(&k_mat, &gf, &s);
                if best.as_ref().is_none_or(|b| q < b.0) {
                    best = Some((q, s));
                }
            }
            let (q_best, s_best) = best.unwrap();
            // Entries leaving their bound taken out by re-factorising (0) and held through the
            // working set (usize::MAX): the same minimiser.
            let (s, exact) = box_step(
                &a,
                &g,
                &free,
                &diag,
                damping,
                max_diag,
                &lo,
                &hi,
                case % 2 * usize::MAX,
            )
            .unwrap();
            assert!(exact, "case {case}: not solved exactly");
            for k in 0..n {
                assert!(
                    lo[k] <= s[k] && s[k] <= hi[k],
                    "case {case}: entry {k} outside"
                );
                assert!(
                    (s[k] - s_best[k]).abs() <= 1e-9,
                    "case {case}: entry {k} {} against {}",
                    s[k],
                    s_best[k]
                );
            }
            let q = model(&k_mat, &gf, &s);
            assert!(
                q <= q_best + 1e-12 && q < 0.0,
                "case {case}: q {q} against {q_best}"
            );
            // The steps it replaces: the projection of h, and h's crossing entries held on
            // their bound with the rest re-solved.
            let projected: Vec<f64> = (0..n).map(|k| h[k].clamp(lo[k], hi[k])).collect();
            let crossing: Vec<usize> = (0..n).filter(|&k| h[k] != projected[k]).collect();
            let kept: Vec<usize> = (0..n).filter(|k| !crossing.contains(k)).collect();
            let mut held = projected.clone();
            if !kept.is_empty() {
                let kff = DMatrix::<f64>::from_fn(kept.len(), kept.len(), |r, c| {
                    k_mat[(kept[r], kept[c])]
                });
                let rhs = DVector::<f64>::from_fn(kept.len(), |r, _| {
                    -gf[kept[r]]
                        - crossing
                            .iter()
                            .map(|&c| k_mat[(kept[r], c)] * projected[c])
                            .sum::<f64>()
                });
                let sf = kff.cholesky().unwrap().solve(&rhs);
                for (r, &k) in kept.iter().enumerate() {
                    held[k] = sf[r].clamp(lo[k], hi[k]);
                }
            }
            let q_old = model(&k_mat, &gf, &projected).min(model(&k_mat, &gf, &held));
            assert!(
                q <= q_old + 1e-12,
                "case {case}: {q} above the old step's {q_old}"
            );
            better += usize::from(q < q_old - 1e-9);
            checked += 1;
        }
        assert!(checked >= 100, "only {checked} models left the box");
        assert!(
            better >= 10,
            "only {better} models where the box step beats the old one"
        );
    }
}
