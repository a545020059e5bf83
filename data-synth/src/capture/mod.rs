//! Captured observations into datasets (`lfit data import`): C3D marker files ([`c3d`]), TRC
//! marker files ([`trc`], read as a C3D's points), 2D keypoint and camera files ([`keypoints`]),
//! and their import onto a model with rigid start poses and observation errors ([`import`]);
//! a captured 3D reference of the joints that scores fits of those keypoints ([`reference`]).

use std::path::PathBuf;

use crate::error::SynthError;

pub mod c3d;
pub mod import;
pub mod keypoints;
pub mod opencv_yaml;
pub mod reference;
pub mod trc;

/// Errors of the import: each a one-line cause.
#[derive(Debug, thiserror::Error)]
pub enum ImportError {
    #[error("cannot read {path}: {source}")]
    Read {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("{0}")]
    Invalid(String),
    #[error(transparent)]
    Synth(#[from] SynthError),
    #[error(transparent)]
    Model(#[from] lfit_model::ModelError),
}
