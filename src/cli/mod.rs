//! The command implementations behind the `lfit` binary (which only parses flags and calls
//! them): each takes parsed arguments and returns a JSON summary or an error. `fit` and the data
//! commands are also the library entry points [`crate::api`] re-exports.

pub mod calibrate;
pub mod commands;
pub mod data_import;
pub mod export;
pub mod fit;
pub mod motion;
