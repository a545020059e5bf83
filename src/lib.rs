//! lfit: learned pose fitting of a skinned human template. This facade crate holds the command
//! implementations behind the `lfit` binary ([`cli`]; the binary only parses flags and calls
//! them), the studies ([`study`]: bench, report, statistics, plots, presets, ablation) and the
//! renderer ([`render`]), on the models and datasets of [`data`] and the one fitting loop of
//! [`fitting`].
//! [`api`] lists the in-memory entry points (datasets, models and fits held in memory) that
//! the Python package `lfit` (`python/`) wraps. The cargo feature `neural` (default) brings the
//! neural fitter and with it Burn; without it the library is Burn-free and the neural methods
//! are a one-line error.

pub mod api;
pub mod cli;
pub mod data;
pub mod fitting;
pub mod holdout;
pub mod method;
pub mod render;
pub mod shipped;
pub mod study;

pub use lfit_fitters as fitters;
#[cfg(feature = "neural")]
pub use lfit_infer as infer;
pub use lfit_model as model;
#[cfg(feature = "neural")]
pub use lfit_nn as nn;
pub use lfit_synth as synth;
#[cfg(feature = "neural")]
pub use lfit_train as train;
