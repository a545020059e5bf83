//! Motion: the procedural motion library ([`library`], re-exported here), BVH files ([`bvh`]) and
//! their retargeting onto a model ([`retarget`], [`rest_pose`]), motion files on disk
//! ([`file`]), and how well training motion covers an evaluation clip ([`coverage`]).

pub mod augment;
pub mod bvh;
pub mod coverage;
pub mod file;
pub mod library;
pub mod rest_pose;
pub mod retarget;

pub use library::*;
