//! The library's in-memory entry points, for programs that hold models, datasets and fits in
//! memory rather than in files (the Python package `lfit`, `python/`, wraps exactly these):
//! every one is the command's own code with the file reading and writing left to the caller,
//! and the command calls it too.

pub use crate::cli::calibrate::calibrate_dataset;
pub use crate::cli::commands::model_info;
pub use crate::cli::data_import::{
    CamerasArgs as DataCamerasArgs, ImportArgs as DataImportArgs, cameras as data_cameras,
    import_dataset,
};
pub use crate::cli::fit::{FitArgs, FrameProblem, fit_dataset, parse_frames, read_energy_config};
pub use crate::cli::motion::{
    ImportArgs as MotionImportArgs, PriorArgs as MotionPriorArgs, import_clip, prior_energy,
};
pub use crate::data::params_from_json;
pub use crate::data::{MotionFilesArgs, Rig, SynthArgs, load_model, synthesize_dataset};
pub use crate::fitting::{FloorArg, HeightPriorArg, check_model, template_for};
pub use crate::method::{MethodKind, NO_NEURAL};

/// The one line an error prints (`lfit` prints it after `error: `): the error and its causes,
/// each said once (errors whose message already quotes their source, `thiserror`'s `{0}` with
/// `#[from]`, would otherwise repeat it), joined by `: `, newlines turned into spaces.
pub fn error_line(e: &anyhow::Error) -> String {
    let mut text = e.to_string();
    for cause in e.chain().skip(1) {
        let c = cause.to_string();
        if !text.contains(&c) {
            text.push_str(": ");
            text.push_str(&c);
        }
    }
    text.replace('\n', " ")
}

/// Whether this build has the neural fitter (the cargo feature `neural`).
pub const HAS_NEURAL: bool = cfg!(feature = "neural");
