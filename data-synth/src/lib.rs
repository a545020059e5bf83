//! lfit's synthetic data: a procedural motion library, uniform pose sampling, the scenarios of
//! papers/000 §4, observation synthesis with noise and occlusion per modality, and datasets on
//! disk as numpy-readable `.npz` archives.

pub mod bvh;
pub mod c3d;
pub mod coverage;
pub mod dataset;
pub mod error;
pub mod import;
pub mod keypoints;
pub mod motion;
pub mod motion_io;
pub mod noise;
pub mod npz;
pub mod rest_pose;
pub mod retarget;
pub mod synth;

pub use dataset::{Dataset, Meta, Observations};
pub use error::SynthError;
pub use noise::NoiseConfig;
pub use synth::{MotionFile, PoseSource, Scenario, SynthConfig, synthesize};
