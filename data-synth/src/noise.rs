//! Noise and occlusion models: they live with the observation models in `lfit-model`
//! ([`lfit_model::noise`]), which apply them per modality; re-exported here for synthesis users.

pub use lfit_model::noise::*;
