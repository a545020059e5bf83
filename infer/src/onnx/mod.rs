//! The neural fitter outside Burn: export to standard ONNX ([`export`]), and the same fitting
//! loop with the network executed by ONNX Runtime through the `ort` crate ([`runtime`]).

pub mod export;
pub mod graph;
pub mod proto;
pub mod runtime;

use std::path::{Path, PathBuf};

pub use proto::{FLOAT, INT64};

/// `lfit.format` of every exported graph.
pub const FORMAT: &str = "lfit-onnx";
/// `lfit.version`: the layout of inputs, outputs and metadata described in [`export`].
pub const VERSION: u32 = 1;
/// The ONNX operator set the graphs use (LayerNormalization needs 17).
pub const OPSET: i64 = 17;
/// The ONNX Runtime release lfit is built and tested against (its `api-31` C API).
pub const ORT_RELEASE: &str = "1.31.1";

/// Metadata keys (`metadata_props`) of the exported graphs.
pub mod keys {
    pub const FORMAT: &str = "lfit.format";
    pub const VERSION: &str = "lfit.version";
    pub const ROLE: &str = "lfit.role";
    pub const WEIGHT_SET: &str = "lfit.weight_set";
    pub const WEIGHT_SETS: &str = "lfit.weight_sets";
    pub const MODALITY: &str = "lfit.modality";
    pub const ITERATIONS: &str = "lfit.iterations";
    pub const RESIDUAL_DIM: &str = "lfit.residual_dim";
    pub const DOF_MASK: &str = "lfit.dof_mask";
    pub const CHECKPOINT: &str = "lfit.checkpoint";
    pub const FEATURE_STATS: &str = "lfit.feature_stats";
    pub const FEATURE_CLIP: &str = "lfit.feature_clip";
}

/// What can go wrong exporting or running ONNX; every message is one line naming the cause.
#[derive(Debug, thiserror::Error)]
pub enum OnnxError {
    #[error("ONNX export: {0}")]
    Export(String),
    #[error("{0}")]
    Io(String),
    #[error("{path}: {reason}")]
    Model { path: PathBuf, reason: String },
    #[error("{0}")]
    Library(String),
    #[error("ONNX Runtime: {0}")]
    Runtime(String),
}

impl From<lfit_model::ModelError> for OnnxError {
    fn from(e: lfit_model::ModelError) -> Self {
        OnnxError::Runtime(e.to_string())
    }
}

impl OnnxError {
    pub fn model(path: &Path, reason: impl Into<String>) -> Self {
        OnnxError::Model {
            path: path.to_path_buf(),
            reason: reason.into(),
        }
    }
}
