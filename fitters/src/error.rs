//! Errors of the fitters.

/// Everything that can go wrong when setting up or running a fit.
#[derive(Debug, thiserror::Error)]
pub enum FitError {
    #[error("budget must be at least 1 evaluation (got {0})")]
    Budget(usize),
    #[error("unknown method '{0}' (expected one of: {list})", list = crate::METHOD_NAMES.join(", "))]
    UnknownMethod(String),
    #[error("unknown strategy '{0}' (expected holistic, grouped or hierarchical)")]
    UnknownStrategy(String),
    #[error("unknown preset '{0}' (expected nevergrad or paper001)")]
    UnknownPreset(String),
    #[error("bounds: {0}")]
    Bounds(String),
    #[error("start pose: {0}")]
    Start(String),
    #[error("optimizer: {0}")]
    Optimizer(#[from] crate::optim::OptimError),
    #[error("L-BFGS: {0}")]
    Lbfgs(String),
    #[error("least squares: {0}")]
    LeastSquares(String),
    #[error("neural fitter: {0}")]
    Neural(String),
}
