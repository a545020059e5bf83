//! The body model (SPEC §3, §3a): a template (mesh, rig, morph), its parameter layout and pose
//! space, the skeleton and what a model knows about it, CPU forward kinematics and skinning.
//!
//! [`procedural`] builds the default template; its items are re-exported here, so
//! `lfit_model::body::default_template` is the path it always had.

pub mod info;
pub(crate) mod jacobian;
pub(crate) mod kinematics;
pub mod layout;
pub mod morph;
pub mod pose;
pub mod procedural;
pub mod rig;
pub mod rotation;
pub mod skeleton;
pub mod skinning;
pub mod stature;
pub mod template;

pub use info::ModelInfo;
pub use layout::{Block, Layout};
pub use morph::Morph;
pub use pose::{Bounds, DofMask, POSE_DIM, Pose};
pub use procedural::{
    BodyShape, MORPHABLE_SAMPLES, MORPHABLE_SHAPE_DIM, build_template, default_template,
    fit_regressor, morphable_default_template, signed_volume, smpl_like,
};
pub use rig::{Joint, JointIndex, Marker, Rig};
pub use skinning::SkinningMethod;
pub use template::{Fnv1a, Template};
