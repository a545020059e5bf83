//! lfit's body model: the skinned template, the pose space, forward kinematics and skinning on the
//! CPU, the observation models that turn a pose into what a sensor sees, and the energy. No Burn:
//! the network and the tensor FK live in `lfit-nn`.
//!
//! The observation models ([`observe`]) are the only place where pose → observation is computed.

pub mod body;
pub mod camera;
pub mod energy;
pub mod error;
pub mod info;
pub mod layout;
pub mod makehuman;
pub mod makehuman_face;
pub mod makehuman_import;
pub mod makehuman_rom;
pub mod metrics;
pub mod modelfile;
pub mod morph;
pub mod noise;
pub mod observe;
pub mod pose;
pub mod rig;
pub mod scan;
pub mod skeleton;
pub mod skinning;
pub mod template;

pub use body::{BodyShape, build_template, default_template};
pub use energy::{Energy, EnergyConfig, Evaluation, Target};
pub use error::{ModelError, Result};
pub use info::ModelInfo;
pub use layout::{Block, Layout};
pub use morph::Morph;
pub use pose::{Bounds, DofMask, POSE_DIM, Pose};
pub use rig::{Joint, JointIndex, Marker, Rig};
pub use skinning::SkinningMethod;
pub use template::Template;
