//! The neural fitter of papers/002 (SPEC §7) as Burn modules: configuration and ablation
//! switches, the layer-normalized GRU, the initializers, the update rule, the fitting loop and
//! checkpoints; and FK + skinning as Burn tensors ([`tensor`]) for the training losses.
//!
//! The only lfit crate besides `train` and `infer` that compiles Burn: the body model, the
//! observation models and the energy (`lfit-model`) do not.

pub mod checkpoint;
pub mod config;
pub mod features;
pub mod host;
pub mod layers;
pub mod net;
pub mod tensor;
pub mod unroll;

pub use checkpoint::{Checkpoint, CheckpointMeta};
pub use config::{
    CoreKind, Direction, GammaMode, NetConfig, StartMode, StepShape, UpdateRule, Views,
};
pub use features::{
    FeatureStats, Norm, observation_features, observation_features_for, residual_features,
};
pub use host::HostNet;
pub use layers::Dropout;
pub use net::{NeuralNet, State, StepSizes};
pub use unroll::{
    Constraints, Exit, RowNetwork, RowState, StepOut, Unrolled, check_iterations, direction,
    initial_poses, initial_poses_rows, unroll, unroll_for, unroll_rows, unroll_rows_for,
};

#[cfg(test)]
mod tests;
