//! lfit's classical fitters (SPEC §6): the zeroth-order optimizers of papers/000 and papers/001
//! behind one ask/tell interface ([`optim`]), the holistic / grouped / hierarchical strategies,
//! L-BFGS with the energy's exact gradient, and Gauss-Newton / Levenberg–Marquardt on its
//! least-squares form. Every fitter minimises the same
//! [`lfit_model::energy::Energy`] and every evaluation goes through its counter.

pub mod error;
pub mod fitter;
pub mod lbfgs;
pub mod least_squares;
pub mod observed;
pub mod optim;
pub mod zeroth;

pub use error::FitError;
pub use fitter::{FitRequest, FitResult, Fitter, Strategy, split_budget};
pub use lbfgs::LbfgsFitter;
pub use least_squares::{LeastSquaresFitter, LeastSquaresMethod};
pub use observed::{
    ANCHOR_MOTION_CAP, ANCHOR_MOTION_GAIN, ANCHOR_STD_DEG, ANCHOR_TRANSLATION_STD_MM, AnchorStart,
    AnchoredDofs, Dofs, GIVEN_START_ANCHOR_STD_DEG, HMD_ANCHOR_STD_DEG, KEYPOINTS2D_ANCHOR_STD_DEG,
    KEYPOINTS2D_GIVEN_START_ANCHOR_STD_DEG, OBSERVED_MAX_STD_DEG, ObservedDofs,
    SEQUENCE_ANCHOR_TRANSLATION_STD_MM, SEQUENCE_MOTION_WEIGHT, SEQUENCE_NETWORK_OBSERVED_DEG,
    SequenceMotion, anchor_std_deg, anchor_translation_std_mm, anchored_energy,
    sequence_anchor_std_deg, sequence_network_dofs, widened_std,
};
pub use optim::{Method, Preset};
pub use zeroth::ZerothOrderFitter;

/// Every method `build_fitter` knows.
pub const METHOD_NAMES: [&str; 16] = [
    "random",
    "one-plus-one",
    "de",
    "pso",
    "cma",
    "tbpsa",
    "powell",
    "cma-powell",
    "ngo",
    "shiwa",
    "apf",
    "psapf",
    "lbfgs",
    "lm",
    "lm-triggs",
    "gn",
];

/// Whether `method` needs the energy's gradient (or Jacobian), and so its differentiable variant
/// ([`lfit_model::energy::EnergyConfig::for_gradient`]).
pub fn uses_gradient(method: &str) -> bool {
    matches!(
        method,
        "lbfgs" | "lm" | "lm-triggs" | "gn" | "neural" | "neural+lm"
    )
}

/// The fitter called `method` (one of [`METHOD_NAMES`]) with `preset` and `strategy`.
pub fn build_fitter(
    method: &str,
    preset: Preset,
    strategy: Strategy,
) -> Result<Box<dyn Fitter>, FitError> {
    build_fitter_tuned(
        method,
        preset,
        strategy,
        1.0,
        optim::cma::CmaVariant::default(),
    )
}

/// [`build_fitter`] with the initial steps of a zeroth-order method multiplied by `step_scale`
/// (> 0; gradient methods take no steps and refuse any factor but 1) and CMA-ES's update variant
/// (only `cma` takes one that is not the default).
pub fn build_fitter_tuned(
    method: &str,
    preset: Preset,
    strategy: Strategy,
    step_scale: f64,
    cma: optim::cma::CmaVariant,
) -> Result<Box<dyn Fitter>, FitError> {
    if cma != optim::cma::CmaVariant::default() && method != "cma" {
        return Err(FitError::Start(format!(
            "CMA-ES options (diagonal, elitist, population) given for method {method}"
        )));
    }
    if !(step_scale.is_finite() && step_scale > 0.0) {
        return Err(FitError::Start(format!(
            "step scale must be a positive number (got {step_scale})"
        )));
    }
    if step_scale != 1.0 && uses_gradient(method) {
        return Err(FitError::Start(format!(
            "method {method} has no initial steps to scale"
        )));
    }
    match method {
        "lbfgs" => {
            return Ok(Box::new(LbfgsFitter {
                strategy,
                ..LbfgsFitter::default()
            }));
        }
        "lm" => {
            return Ok(Box::new(LeastSquaresFitter::new(
                LeastSquaresMethod::Lm,
                strategy,
            )));
        }
        "lm-triggs" => {
            let mut lm = LeastSquaresFitter::new(LeastSquaresMethod::Lm, strategy);
            lm.options.robust = lfit_model::energy::RobustForm::Triggs;
            return Ok(Box::new(lm));
        }
        "gn" => {
            return Ok(Box::new(LeastSquaresFitter::new(
                LeastSquaresMethod::Gn,
                strategy,
            )));
        }
        _ => {}
    }
    let m: Method = method
        .parse()
        .map_err(|_| FitError::UnknownMethod(method.to_string()))?;
    Ok(Box::new(ZerothOrderFitter {
        step_scale,
        cma,
        ..ZerothOrderFitter::new(m, preset, strategy)
    }))
}
