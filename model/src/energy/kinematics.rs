//! f64 forward kinematics with the factors of its exact reverse-mode derivative.
//!
//! Every quantity the energy compares with data is a point, a direction or a rotation carried by
//! one joint of the skeleton (a skinned vertex is a weighted sum of points carried by up to four
//! joints). Rotating joint `k` by a small world-frame angle `ω` moves a point `p` of its subtree by
//! `ω × (p − J_k)`, a direction `d` by `ω × d` and a rotation `W` by `[ω]× W`, where `J_k` is the
//! posed joint centre. With the exponential map, `ω = W_parent(k) · Jl(r_k) · δr_k` (`Jl` the left
//! Jacobian of SO(3)). So the gradient of any scalar with respect to `r_k` is
//! `(W_parent(k) Jl(r_k))ᵀ m_k`, where the *moment* `m_k` sums, over the subtree of `k`,
//! `(p − J_k) × ∂E/∂p` for points, `d × ∂E/∂d` for directions and the torque of rotations. The
//! root translation moves every point by `δt`, so its gradient is the sum of all point forces.
//! [`Adjoint`] accumulates forces and moments per joint and [`Adjoint::finish`] turns them into the
//! 57-entry pose gradient in `O(joints)`.

use glam::{DAffine3, DMat3, DVec3};

use crate::pose::{POSE_DIM, Pose, rot_offset};
use crate::skinning::joint_transforms;
use crate::template::Template;

/// `[v]×`, the matrix of `x ↦ v × x`.
pub(crate) fn skew(v: DVec3) -> DMat3 {
    DMat3::from_cols(DVec3::new(0.0, v.z, -v.y), DVec3::new(-v.z, 0.0, v.x), DVec3::new(v.y, -v.x, 0.0))
}

/// Left Jacobian of SO(3) at `r`: `exp([r + δ]×) ≈ exp([Jl(r) δ]×) exp([r]×)`.
/// `Jl = I + (1 − cos θ)/θ² [r]× + (θ − sin θ)/θ³ [r]×²`, with Taylor series near θ = 0.
pub(crate) fn left_jacobian(r: DVec3) -> DMat3 {
    let t2 = r.length_squared();
    let (a, b) = if t2 < 1e-8 {
        (0.5 - t2 / 24.0, 1.0 / 6.0 - t2 / 120.0)
    } else {
        let t = t2.sqrt();
        ((1.0 - t.cos()) / t2, (t - t.sin()) / (t2 * t))
    };
    let k = skew(r);
    DMat3::IDENTITY + k * a + (k * k) * b
}

/// The torque `τ` with `tr(Gᵀ [ω]× R) = ω · τ`: the derivative of `⟨G, R⟩` for a rotation `R`
/// rotated by a small world angle `ω`.
pub(crate) fn rotation_torque(r: DMat3, g: DMat3) -> DVec3 {
    // B = R Gᵀ; τ = (B₂₃ − B₃₂, B₃₁ − B₁₃, B₁₂ − B₂₁) (1-based, row-column).
    let b = r * g.transpose();
    let e = |row: usize, col: usize| b.col(col)[row];
    DVec3::new(e(1, 2) - e(2, 1), e(2, 0) - e(0, 2), e(0, 1) - e(1, 0))
}

/// Posed skeleton in f64: the affine maps `A_j` of [`joint_transforms`] (whose linear parts are
/// the world rotations `W_j`), the joint centres `J_j` and the Jacobian factors
/// `W_parent(j) Jl(r_j)`.
#[derive(Debug, Clone)]
pub(crate) struct Kinematics {
    pub transforms: Vec<DAffine3>,
    pub joints: Vec<DVec3>,
    pub factors: Vec<DMat3>,
}

impl Kinematics {
    /// The posed skeleton; `factors` (needed only for gradients) is left empty unless
    /// `with_factors`.
    pub fn build(template: &Template, pose: &Pose, with_factors: bool) -> Self {
        let posed = joint_transforms(template, pose);
        let joints = posed.joints.clone();
        let transforms = posed.transforms;
        let factors = if with_factors {
            template
                .rig
                .joints
                .iter()
                .enumerate()
                .map(|(j, joint)| {
                    let o = rot_offset(j);
                    let parent_rot = joint.parent.map_or(DMat3::IDENTITY, |p| transforms[p].matrix3);
                    parent_rot * left_jacobian(DVec3::new(pose[o], pose[o + 1], pose[o + 2]))
                })
                .collect()
        } else {
            Vec::new()
        };
        Self { transforms, joints, factors }
    }

    /// World rotation `W_j` of joint `j`.
    #[inline]
    pub fn world(&self, j: usize) -> DMat3 {
        self.transforms[j].matrix3
    }

    /// Linear blend skinning of rest point `x` with `weights` (`Σ w_j A_j(x)`).
    #[inline]
    pub fn skin(&self, weights: &[(u16, f64)], x: DVec3) -> DVec3 {
        weights.iter().fold(DVec3::ZERO, |acc, &(j, w)| acc + w * self.transforms[j as usize].transform_point3(x))
    }

    /// Linear blend skinning of rest point `x` and rest direction `d` together: the blended
    /// affine map `Σ w_j A_j` applied to both (its linear part is `Σ w_j W_j`).
    #[inline]
    pub fn skin_both(&self, weights: &[(u16, f64)], x: DVec3, d: DVec3) -> (DVec3, DVec3) {
        let mut m = glam::DMat3::ZERO;
        let mut t = DVec3::ZERO;
        for &(j, w) in weights {
            let a = &self.transforms[j as usize];
            m += a.matrix3 * w;
            t += a.translation * w;
        }
        (m * x + t, m * d)
    }
}

/// Per-joint forces and moments of the reverse pass.
#[derive(Debug, Clone)]
pub(crate) struct Adjoint {
    force: Vec<DVec3>,
    moment: Vec<DVec3>,
}

impl Adjoint {
    pub fn new(joints: usize) -> Self {
        Self { force: vec![DVec3::ZERO; joints], moment: vec![DVec3::ZERO; joints] }
    }

    /// A point `p` (world position) carried by `joint` with weight `w` and gradient `g`.
    #[inline]
    pub fn point(&mut self, joint: usize, p: DVec3, g: DVec3, w: f64) {
        self.force[joint] += w * g;
        self.moment[joint] += w * p.cross(g);
    }

    /// A skinned rest point `x` with gradient `g` of its posed position.
    #[inline]
    pub fn skinned_point(&mut self, kin: &Kinematics, weights: &[(u16, f64)], x: DVec3, g: DVec3) {
        for &(j, w) in weights {
            let j = j as usize;
            self.point(j, kin.transforms[j].transform_point3(x), g, w);
        }
    }

    /// A skinned rest direction `d` with gradient `g` of its (unnormalised) posed direction.
    #[inline]
    pub fn skinned_direction(&mut self, kin: &Kinematics, weights: &[(u16, f64)], d: DVec3, g: DVec3) {
        for &(j, w) in weights {
            let j = j as usize;
            self.moment[j] += w * (kin.world(j) * d).cross(g);
        }
    }

    /// A torque on a rotation carried by `joint` (see [`rotation_torque`]).
    #[inline]
    pub fn torque(&mut self, joint: usize, tau: DVec3) {
        self.moment[joint] += tau;
    }

    /// The pose gradient: subtree sums, moments about each joint centre, then the exp-map factor.
    pub fn finish(mut self, template: &Template, kin: &Kinematics) -> Pose {
        let mut grad = [0.0; POSE_DIM];
        // Parents precede children, so a backward sweep accumulates whole subtrees.
        for j in (0..template.rig.joints.len()).rev() {
            let m = self.moment[j] - kin.joints[j].cross(self.force[j]);
            let g = kin.factors[j].transpose() * m;
            let o = rot_offset(j);
            grad[o..o + 3].copy_from_slice(&g.to_array());
            if let Some(p) = template.rig.joints[j].parent {
                let (f, mo) = (self.force[j], self.moment[j]);
                self.force[p] += f;
                self.moment[p] += mo;
            }
        }
        grad[0..3].copy_from_slice(&self.force[0].to_array());
        grad
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::skinning::exp_map;

    #[test]
    fn left_jacobian_matches_finite_differences_of_exp() {
        // exp([r + h e_i]×) exp([r]×)ᵀ ≈ exp([h Jl e_i]×): compare the skew part.
        for r in [DVec3::new(0.3, -0.7, 0.2), DVec3::new(1e-6, 0.0, -2e-6), DVec3::new(0.0, 2.5, 0.1)] {
            let jl = left_jacobian(r);
            for i in 0..3 {
                let h = 1e-6;
                let mut e = DVec3::ZERO;
                e[i] = h;
                let d = (exp_map(r + e) - exp_map(r - e)) * exp_map(r).transpose() * (0.5 / h);
                let omega = DVec3::new(d.y_axis.z, d.z_axis.x, d.x_axis.y);
                assert!((omega - jl.col(i)).length() < 1e-7, "r = {r}, axis {i}: {omega} vs {}", jl.col(i));
            }
        }
    }
}
