//! Errors of the synthesis crate.

use std::path::PathBuf;

#[derive(Debug, thiserror::Error)]
pub enum SynthError {
    #[error(transparent)]
    Model(#[from] lfit_model::ModelError),
    #[error("cannot read {path}: {source}")]
    Read {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("malformed dataset: {0}")]
    Dataset(String),
    #[error("unknown scenario '{0}' (expected local, global or sequence)")]
    UnknownScenario(String),
    #[error("unknown pose source '{0}' (expected motion, uniform or face)")]
    UnknownSource(String),
    #[error(
        "unknown motion '{0}' (expected walk, jog, wave, squat, reach, punch, kick, jump or turn)"
    )]
    UnknownMotion(String),
    #[error(
        "unknown body shape '{0}' (expected one of default, tall, short, heavy, slim, long-legs, long-arms)"
    )]
    UnknownShape(String),
    #[error(transparent)]
    Motion(#[from] crate::motion::retarget::MotionError),
    #[error("motion file {path}: {reason}")]
    MotionFile { path: String, reason: String },
    #[error("interrupted")]
    Cancelled,
    #[error("invalid setting {name} = {value}: {reason}")]
    Setting {
        name: &'static str,
        value: String,
        reason: String,
    },
}
