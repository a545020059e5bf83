//! Errors of the body model and the observation models.

use std::path::PathBuf;

/// Everything that can go wrong while loading, validating or evaluating the body model.
#[derive(Debug, thiserror::Error)]
pub enum ModelError {
    #[error("cannot read {path}: {source}")]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("malformed OBJ {path}: {reason}")]
    Obj { path: PathBuf, reason: String },
    #[error("malformed rig JSON {path}: {reason}")]
    RigJson { path: PathBuf, reason: String },
    #[error("rig joint {index} ('{name}'): {reason}")]
    Joint {
        index: usize,
        name: String,
        reason: String,
    },
    #[error("rig weights of vertex {vertex}: {reason}")]
    Weights { vertex: usize, reason: String },
    #[error("marker '{name}': {reason}")]
    Marker { name: String, reason: String },
    #[error("mesh vertex {vertex}: {reason}")]
    Vertex { vertex: usize, reason: String },
    #[error("mesh face {face}: {reason}")]
    Face { face: usize, reason: String },
    #[error("pose has {got} numbers, expected {expected}")]
    PoseLength { got: usize, expected: usize },
    #[error("pose value {index} is not finite ({value})")]
    PoseNotFinite { index: usize, value: f64 },
    #[error("unknown DOF mask '{0}' (expected full57, local43, global41 or a list of DOF indices)")]
    UnknownMask(String),
    #[error("DOF mask: {0}")]
    Mask(String),
    #[error(
        "unknown modality '{0}' (expected markers, keypoints2d, hmd, scan, silhouettes or landmarks2d)"
    )]
    UnknownModality(String),
    #[error("camera {index}: {reason}")]
    Camera { index: usize, reason: String },
    #[error("invalid setting {name} = {value}: {reason}")]
    Setting {
        name: &'static str,
        value: String,
        reason: String,
    },
    #[error("shape mismatch for {what}: expected {expected}, got {got}")]
    Shape {
        what: String,
        expected: String,
        got: String,
    },
    #[error("target data: {0}")]
    Target(String),
    #[error("tensor backend: {0}")]
    Backend(String),
    #[error("{0}")]
    Config(String),
    #[error("model file {path}: {reason}")]
    ModelFile { path: PathBuf, reason: String },
    #[error("checkpoint {path}: {reason}")]
    Checkpoint { path: PathBuf, reason: String },
}

impl ModelError {
    pub fn io(path: impl Into<PathBuf>, source: std::io::Error) -> Self {
        Self::Io {
            path: path.into(),
            source,
        }
    }
}

/// Result alias of the model crate.
pub type Result<T, E = ModelError> = std::result::Result<T, E>;
