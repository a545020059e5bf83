//! Rotations of the pose vector: axis-angle to matrix (the exponential map), shared by the CPU
//! skinning, the blend shapes and the kinematics with derivatives.

use glam::{DMat3, DQuat, DVec3};

/// `R = exp([r]x)`, the rotation of axis-angle vector `r`.
pub fn exp_map(r: DVec3) -> DMat3 {
    DMat3::from_quat(DQuat::from_scaled_axis(r))
}
