//! lfit's synthetic and captured data: motion ([`motion`]: a procedural library, BVH import and
//! retargeting, motion files), datasets ([`dataset`]: the scenarios of papers/000 §4 and
//! observation synthesis with noise and occlusion per modality, stored as numpy-readable `.npz`
//! archives) and captured observations imported into datasets ([`capture`]: C3D, 2D keypoints).

pub mod capture;
pub mod dataset;
pub mod error;
pub mod motion;
pub mod noise;
pub mod npz;

pub use dataset::config::{
    MAX_MARKER_SLIP, MotionFile, PoseSource, Scenario, SynthConfig, keypoint_bias_problem,
    marker_slip_problem, noise_spread_problem,
};
pub use dataset::synth::{detector_offsets, frame_noise, synthesize, synthesize_until};
pub use dataset::{Dataset, JointReference, Meta, Observations, ReferenceErrors};
pub use error::SynthError;
pub use motion::augment::MotionAugment;
pub use noise::NoiseConfig;
