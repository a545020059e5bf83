//! Gauss-Newton and Levenberg–Marquardt on the energy's least-squares form
//! ([`Energy::least_squares`]: residuals with `E = Σ r²` and their exact Jacobian).
//!
//! **Levenberg–Marquardt** is the trust-region method as Ceres Solver runs it: the step solves
//! `(JᵀJ + μ D) h = −Jᵀr` by dense Cholesky (nalgebra; the parameter vector has at most a few
//! hundred entries), with `D = diag(JᵀJ)` clamped to `[1e-6, 1e32]` (Marquardt's scaling, so
//! metres, radians and shape coefficients need no hand-set scales) and `μ = 1/radius`. The radius
//! starts at 1e4 and follows Nielsen's update: on a step with gain ratio `ρ > 1e-3` the radius is
//! divided by `max(1/3, 1 − (2ρ − 1)³)` and the growth factor reset to 2; on a failed step it is
//! divided by the growth factor, which doubles. The defaults are Ceres's
//! (`Solver::Options`: `initial_trust_region_radius` 1e4, `min_relative_decrease` 1e-3,
//! `function_tolerance` 1e-6, `gradient_tolerance` 1e-10, `parameter_tolerance` 1e-8).
//!
//! **Gauss-Newton** solves `JᵀJ h = −Jᵀr` (a 1e-12 relative ridge keeps a rank-deficient system
//! solvable) and halves the step until the energy decreases.
//!
//! **Bounds**: a coordinate at a bound whose descent direction points out of the box is held for
//! that step (the active set), and every trial point is projected into the box, so every
//! evaluated point is inside it. The predicted decrease uses the projected step.
//!
//! **Stopping**, as Ceres: the projected gradient `‖x − Π(x − ∇E)‖∞ ≤ gradient_tolerance`, a step
//! `‖Δx‖ ≤ parameter_tolerance (‖x‖ + parameter_tolerance)`, a relative decrease
//! `ΔE ≤ function_tolerance · E`, or the budget: one evaluation = one residual and Jacobian
//! evaluation, a cap as for L-BFGS.

use lfit_model::energy::{Energy, RobustForm, marquardt_scaling};
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
    /// How the robust loss enters the normal equations: folded (default: the exact Jacobian of
    /// `√ρ`-folded residuals, the least-squares problem `objective-server` serves) or Triggs's
    /// correction (IRLS weights for the losses here). Both have E's exact gradient.
    pub robust: RobustForm,
}

impl Default for LeastSquaresOptions {
    fn default() -> Self {
        Self {
            function_tolerance: 1e-6,
            gradient_tolerance: 1e-10,
            parameter_tolerance: 1e-8,
            initial_trust_region_radius: 1e4,
            min_relative_decrease: 1e-3,
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
        let eval = |x: &[f64]| {
            energy
                .least_squares_in(x, true, o.robust)
                .map_err(|e| FitError::LeastSquares(e.to_string()))
        };
        let mut x = pose.to_vec();
        let mut current = eval(&x)?;
        let mut count = 1usize;
        let mut f = current.energy;
        let mut trace = vec![(1u64, f)];
        let mut radius = o.initial_trust_region_radius;
        let mut growth = 2.0;
        let mut iterations = 0u64;
        let n = dofs.len();
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
            let free: Vec<usize> = (0..n)
                .filter(|&p| {
                    let i = dofs[p];
                    !((x[i] <= bounds.lower[i] && g[p] > 0.0)
                        || (x[i] >= bounds.upper[i] && g[p] < 0.0))
                })
                .collect();
            if free.is_empty() {
                break;
            }
            let (diag, max_diag) = marquardt_scaling(&a, &free);
            // Gauss-Newton's halving factor along its direction.
            let mut alpha = 1.0;
            loop {
                let damping = match self.method {
                    LeastSquaresMethod::Lm => 1.0 / radius,
                    LeastSquaresMethod::Gn => 0.0,
                };
                let Some(h) = damped_step(&a, &g, &free, &diag, damping, max_diag) else {
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
                // The projected step, over every stage entry.
                let step = DVector::<f64>::from_iterator(n, dofs.iter().map(|&i| trial[i] - x[i]));
                let xnorm = dofs.iter().map(|&i| x[i] * x[i]).sum::<f64>().sqrt();
                if step.norm() <= o.parameter_tolerance * (xnorm + o.parameter_tolerance) {
                    break 'outer;
                }
                let next = eval(&trial)?;
                count += 1;
                let f_new = next.energy;
                let accepted = match self.method {
                    LeastSquaresMethod::Lm => {
                        // Model decrease of Σr² (the IRLS model under Triggs): −(2 gᵀh + hᵀ A h).
                        let predicted = -(2.0 * g.dot(&step) + step.dot(&(&a * &step)));
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
                    current = next;
                    f = f_new;
                    trace.push((count as u64, f));
                    if decrease <= o.function_tolerance * (f + decrease) {
                        break 'outer;
                    }
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
