//! Rotations of the pose vector: axis-angle to matrix (the exponential map), shared by the CPU
//! skinning, the blend shapes and the kinematics with derivatives.

use glam::{DMat3, DQuat, DVec3};

/// `R = exp([r]x)`, the rotation of axis-angle vector `r`.
pub fn exp_map(r: DVec3) -> DMat3 {
    DMat3::from_quat(DQuat::from_scaled_axis(r))
}

/// [`exp_map`] (the same matrix, bit for bit) and the left Jacobian of SO(3) at `r`,
/// `exp([r + δ]×) ≈ exp([Jl(r) δ]×) exp([r]×)`:
/// `Jl = I + (1 − cos θ)/θ² [r]× + (θ − sin θ)/θ³ [r]×²` (Taylor series near θ = 0). Both from one
/// sine and cosine: the quaternion's half-angle values `s = sin(θ/2)` (signed, along `r`) and
/// `c = cos(θ/2)` give `sin θ = 2sc` and `1 − cos θ = 2s²` (the latter without the cancellation
/// of `1 − cos θ` at small angles).
pub(crate) fn exp_map_and_left_jacobian(r: DVec3) -> (DMat3, DMat3) {
    let q = DQuat::from_scaled_axis(r);
    let t2 = r.length_squared();
    let (a, b) = if t2 < 1e-8 {
        (0.5 - t2 / 24.0, 1.0 / 6.0 - t2 / 120.0)
    } else {
        let t = t2.sqrt();
        let it = 1.0 / t;
        let s = DVec3::new(q.x, q.y, q.z).dot(r) * it;
        let inv = it * it;
        (2.0 * s * s * inv, (t - 2.0 * s * q.w) * inv * it)
    };
    // [r]×² = r rᵀ − θ² I: Jl = (1 − bθ²) I + a [r]× + b r rᵀ, entry by entry.
    let d = 1.0 - b * t2;
    let (ar, br) = (a * r, b * r);
    let jl = DMat3::from_cols(
        DVec3::new(d + br.x * r.x, ar.z + br.y * r.x, -ar.y + br.z * r.x),
        DVec3::new(-ar.z + br.x * r.y, d + br.y * r.y, ar.x + br.z * r.y),
        DVec3::new(ar.y + br.x * r.z, -ar.x + br.y * r.z, d + br.z * r.z),
    );
    (DMat3::from_quat(q), jl)
}
