//! lfit's body model: the skinned template, the pose space, forward kinematics and skinning on the
//! CPU, the observation models that turn a pose into what a sensor sees, and the energy. No Burn:
//! the network and the tensor FK live in `lfit-nn`.
//!
//! The observation models ([`observe`]) are the only place where pose → observation is computed.
//!
//! Folders: [`body`] (the body model: template, layout, pose, rig, skeleton, morph, skinning, the
//! procedural default body), [`formats`] (model files and the MakeHuman importers), [`observe`]
//! (observation models, with the cameras, the scan data and the noise), [`energy`] (the objective).

pub mod body;
pub mod energy;
pub mod error;
pub mod formats;
pub mod metrics;
pub mod observe;

// The paths the modules had before they moved into their folders (issue 28), kept for every crate.
pub use body::{info, layout, morph, pose, rig, skeleton, skinning, stature, template};
pub use formats::{makehuman, makehuman_face, makehuman_import, makehuman_rom, modelfile};
pub use observe::{camera, noise, scan};

pub use body::{
    Block, BodyShape, Bounds, DofMask, Fnv1a, Joint, JointIndex, Layout, Marker, ModelInfo, Morph,
    POSE_DIM, Pose, Rig, SkinningMethod, Template, build_template, default_template,
};
pub use energy::{Energy, EnergyConfig, Evaluation, Target};
pub use error::{ModelError, Result};
