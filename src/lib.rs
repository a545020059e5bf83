//! lfit: learned pose fitting of a skinned human template. This facade crate holds the command
//! implementations behind the `lfit` binary; the binary only parses flags and calls them.
//! [`api`] lists the in-memory entry points (datasets, models and fits held in memory) that
//! the Python package `lfit` (`python/`) wraps. The cargo feature `neural` (default) brings the
//! neural fitter and with it Burn; without it the library is Burn-free and the neural methods
//! are a one-line error.

#[cfg(feature = "neural")]
pub mod ablate;
pub mod api;
pub mod bench;
pub mod commands;
pub mod data;
pub mod data_import;
pub mod export;
pub mod fit;
pub mod fitting;
pub mod method;
pub mod motion_cli;
pub mod plots;
pub mod presets;
pub mod render;
pub mod report;
pub mod shipped;
pub mod stats;
pub mod tuned;

pub use lfit_fitters as fitters;
#[cfg(feature = "neural")]
pub use lfit_infer as infer;
pub use lfit_model as model;
#[cfg(feature = "neural")]
pub use lfit_nn as nn;
pub use lfit_synth as synth;
#[cfg(feature = "neural")]
pub use lfit_train as train;
