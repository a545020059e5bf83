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
//! pose gradient in `O(joints)`.
//!
//! **Morphable models** (SPEC §3a). A point carried by joint j from rest point `x` is
//! `p = W_j (x − c_j) + J_j` with `J_j = c_0 + t + Σ_{k ∈ chain(j), k ≠ 0} W_parent(k) (c_k − c_parent(k))`,
//! so `∂p/∂x = W_j` and `∂p/∂c_k = W_parent(k) − W_k` for every k on the chain from the root
//! (`W_parent(root) = I`). With `F_k` the force summed over the subtree of k, the gradient with
//! respect to the rest joint `c_k` is `(W_parent(k) − W_k)ᵀ F_k` plus the rest-point gradients of
//! points whose rest position *is* `c_k` (posed joints). Rest vertices collect `Σ_j w_j W_jᵀ g`.
//! Both flow to `[β; ψ]` through the directions (`∂T_v/∂β` and `J_regressor ∂T/∂β`), and the rest
//! vertices to the joint rotations through the pose correctives: `∂(R_j − I)` under
//! `δr_j` is `[Jl(r_j) δr_j]× R_j`, so `∂E/∂r_j += Jl(r_j)ᵀ τ(R_j, G_j)` with `G_j` the gradient
//! of the 9 feature entries of joint j ([`rotation_torque`]).

use std::sync::Arc;

use glam::{DAffine3, DMat3, DVec3};

use crate::body::rotation::exp_map_and_left_jacobian;
use crate::morph::Morph;
use crate::pose::rot_offset;
use crate::skinning::joint_transforms_with;
use crate::template::Template;

/// `[v]×`, the matrix of `x ↦ v × x`.
pub(crate) fn skew(v: DVec3) -> DMat3 {
    DMat3::from_cols(
        DVec3::new(0.0, v.z, -v.y),
        DVec3::new(-v.z, 0.0, v.x),
        DVec3::new(v.y, -v.x, 0.0),
    )
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
/// `W_parent(j) Jl(r_j)`; for a morphable model also what its rest geometry depends on.
#[derive(Debug, Clone)]
pub(crate) struct Kinematics {
    pub transforms: Vec<DAffine3>,
    pub joints: Vec<DVec3>,
    pub factors: Vec<DMat3>,
    /// Rest joints `c(β, ψ)`.
    pub rest_joints: Vec<DVec3>,
    /// The morph, coefficients `[β; ψ]` and pose feature when the rest geometry moves.
    pub morph: Option<(Arc<Morph>, Vec<f64>, Vec<f64>)>,
    /// Rest positions of a [`VertexSet`] shaped once for this evaluation
    /// ([`Kinematics::shape_vertices`]), in the set's order.
    shaped: Option<(Arc<VertexSet>, Vec<DVec3>)>,
}

/// A fixed set of mesh vertices (what an observation model reads: marker vertices, hand tips)
/// whose rest positions one evaluation reads more than once — the prediction, then the Jacobian
/// or the gradient — found by vertex in an open-addressing table of at least twice the count.
#[derive(Debug, Default)]
pub(crate) struct VertexSet {
    pub vertices: Vec<u32>,
    /// `u32::MAX`: empty.
    keys: Vec<u32>,
    slots: Vec<u32>,
    shift: u32,
}

impl VertexSet {
    pub fn new(vertices: &[u32]) -> Self {
        let mut unique = vertices.to_vec();
        unique.sort_unstable();
        unique.dedup();
        if unique.is_empty() {
            return Self::default();
        }
        let size = (2 * unique.len()).next_power_of_two().max(8);
        let shift = 32 - size.trailing_zeros();
        let (mut keys, mut slots) = (vec![u32::MAX; size], vec![0; size]);
        for (k, &v) in unique.iter().enumerate() {
            let mut i = Self::home(v, shift);
            while keys[i] != u32::MAX {
                i = (i + 1) & (size - 1);
            }
            keys[i] = v;
            slots[i] = k as u32;
        }
        Self {
            vertices: unique,
            keys,
            slots,
            shift,
        }
    }

    pub fn is_empty(&self) -> bool {
        self.vertices.is_empty()
    }

    /// Distinct vertices in the set.
    #[cfg(test)]
    pub fn len(&self) -> usize {
        self.vertices.len()
    }

    /// Fibonacci hashing: the top bits of `v` times 2³²/φ.
    #[inline]
    fn home(v: u32, shift: u32) -> usize {
        (v.wrapping_mul(0x9E37_79B9) >> shift) as usize
    }

    /// Vertex `v`'s position in the set.
    #[inline]
    pub fn slot(&self, v: u32) -> Option<usize> {
        if self.keys.is_empty() {
            return None;
        }
        let mask = self.keys.len() - 1;
        let mut i = Self::home(v, self.shift);
        loop {
            match self.keys[i] {
                k if k == v => return Some(self.slots[i] as usize),
                u32::MAX => return None,
                _ => i = (i + 1) & mask,
            }
        }
    }
}

impl Kinematics {
    /// The posed skeleton; `factors` (needed only for gradients) is left empty unless
    /// `with_factors`.
    pub fn build(template: &Template, pose: &[f64], with_factors: bool) -> Self {
        // The left Jacobians come from the sine and cosine of each joint's exp map.
        let mut left = Vec::new();
        let posed = joint_transforms_with(template, pose, with_factors.then_some(&mut left));
        let joints = posed.joints;
        let transforms = posed.transforms;
        // W_parent(j) Jl(r_j) in place (the root's parent rotation is the identity).
        let mut factors = left;
        for (f, joint) in factors.iter_mut().zip(&template.rig.joints) {
            if let Some(p) = joint.parent {
                *f = transforms[p].matrix3 * *f;
            }
        }
        let morph = (!template.morph.is_rigid())
            .then(|| (template.morph.clone(), posed.coeffs, posed.pose_feature));
        Self {
            transforms,
            joints,
            factors,
            rest_joints: posed.rest_joints,
            morph,
            shaped: None,
        }
    }

    /// Shapes the rest positions of `set` (`table`: the β = ψ = 0 rest vertices, as
    /// [`Kinematics::rest`] takes) once: [`Kinematics::rest`] then reads them. Nothing on a rigid
    /// model (its rest vertices are the table's).
    pub fn shape_vertices(&mut self, table: &[DVec3], set: &Arc<VertexSet>) {
        if let Some((m, c, f)) = &self.morph
            && !set.is_empty()
        {
            let values = set
                .vertices
                .iter()
                .map(|&v| m.rest_vertex(v as usize, table[v as usize], c, f))
                .collect();
            self.shaped = Some((set.clone(), values));
        }
    }

    /// Rest position of vertex `v`: the table's (rigid model) or `T(β, ψ) + P (R(θ) − I)`
    /// (shaped here, or read from [`Kinematics::shape_vertices`]'s when `v` is in its set).
    #[inline]
    pub fn rest(&self, table: &[DVec3], v: usize) -> DVec3 {
        match &self.morph {
            None => table[v],
            Some((m, c, f)) => {
                if let Some((set, values)) = &self.shaped
                    && let Some(k) = set.slot(v as u32)
                {
                    return values[k];
                }
                m.rest_vertex(v, table[v], c, f)
            }
        }
    }

    /// Rest position of vertex `v` whose β = ψ = 0 rest position is `x` (as [`Kinematics::rest`]).
    #[inline]
    pub fn rest_of(&self, v: usize, x: DVec3) -> DVec3 {
        match &self.morph {
            None => x,
            Some((m, c, f)) => m.rest_vertex(v, x, c, f),
        }
    }

    /// World rotation `W_j` of joint `j`.
    #[inline]
    pub fn world(&self, j: usize) -> DMat3 {
        self.transforms[j].matrix3
    }

    /// Linear blend skinning of rest point `x` with `weights` (`Σ w_j A_j(x)`).
    #[inline]
    pub fn skin(&self, weights: &[(u16, f64)], x: DVec3) -> DVec3 {
        weights.iter().fold(DVec3::ZERO, |acc, &(j, w)| {
            acc + w * self.transforms[j as usize].transform_point3(x)
        })
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

/// `out += Mᵀ g` for a row-major `(3n) × out.len()` matrix `m` (rows `3i + axis`) and gradients
/// `g_i` of points `i`: how point gradients reach the coefficients of the directions (`[S E]`,
/// `J_regressor [S E]`) or of the pose correctives.
fn add_transposed(out: &mut [f64], m: &[f64], gradients: impl Iterator<Item = (usize, DVec3)>) {
    let k = out.len();
    for (i, g) in gradients {
        for a in 0..3 {
            if g[a] != 0.0 {
                for (o, d) in out.iter_mut().zip(&m[(3 * i + a) * k..(3 * i + a + 1) * k]) {
                    *o += g[a] * d;
                }
            }
        }
    }
}

/// Per-joint forces and moments of the reverse pass; for a morphable model also the gradients
/// of the rest joints and of the rest vertices.
#[derive(Debug, Clone)]
pub(crate) struct Adjoint {
    force: Vec<DVec3>,
    moment: Vec<DVec3>,
    /// `∂E/∂c_k` from points whose rest position is a joint centre (posed joints, joint-carried
    /// offsets); the chain part is added in [`Adjoint::finish`].
    joint_rest: Vec<DVec3>,
    /// `(v, ∂E/∂T_P,v)`, only when the rest geometry moves.
    rest: Option<Vec<(u32, DVec3)>>,
}

impl Adjoint {
    /// `vertices`: how many rest-vertex gradients to make room for (the sensor's vertices).
    pub fn new(joints: usize, morphable: bool, vertices: usize) -> Self {
        Self {
            force: vec![DVec3::ZERO; joints],
            moment: vec![DVec3::ZERO; joints],
            joint_rest: vec![DVec3::ZERO; joints],
            rest: morphable.then(|| Vec::with_capacity(vertices)),
        }
    }

    /// A point `p` (world position) carried by `joint` with weight `w` and gradient `g`, whose
    /// rest position does not depend on the parameters.
    #[inline]
    pub fn point(&mut self, joint: usize, p: DVec3, g: DVec3, w: f64) {
        self.force[joint] += w * g;
        self.moment[joint] += w * p.cross(g);
    }

    /// A point carried by `joint` whose rest position is `c_joint` plus a constant offset (the
    /// posed joint centre itself, a headset, a segment ellipsoid's centre).
    #[inline]
    pub fn joint_point(&mut self, kin: &Kinematics, joint: usize, p: DVec3, g: DVec3) {
        self.point(joint, p, g, 1.0);
        self.joint_rest[joint] += kin.world(joint).transpose() * g;
    }

    /// A point `p = x_joint + W_carrier d` at a constant offset `d` from `joint`'s centre in the
    /// frame of `carrier` (one of `joint`'s ancestors; see
    /// `PointJacobians::carried_point_on_zero`): the joint's centre, and the offset as a
    /// direction the carrier turns.
    #[inline]
    pub fn carried_point(
        &mut self,
        kin: &Kinematics,
        joint: usize,
        carrier: usize,
        p: DVec3,
        g: DVec3,
    ) {
        let centre = kin.joints[joint];
        self.joint_point(kin, joint, centre, g);
        self.moment[carrier] += (p - centre).cross(g);
    }

    /// Skinned rest vertex `v` (rest point `x`) with gradient `g` of its posed position.
    #[inline]
    pub fn skinned_point(
        &mut self,
        kin: &Kinematics,
        weights: &[(u16, f64)],
        v: usize,
        x: DVec3,
        g: DVec3,
    ) {
        let mut rest_g = DVec3::ZERO;
        for &(j, w) in weights {
            let j = j as usize;
            self.point(j, kin.transforms[j].transform_point3(x), g, w);
            if self.rest.is_some() {
                rest_g += w * (kin.world(j).transpose() * g);
            }
        }
        if let Some(r) = &mut self.rest {
            r.push((v as u32, rest_g));
        }
    }

    /// A skinned rest direction `d` with gradient `g` of its (unnormalised) posed direction. Rest
    /// directions (normals) are those of the β = ψ = 0 mesh, constant in the joint frames.
    #[inline]
    pub fn skinned_direction(
        &mut self,
        kin: &Kinematics,
        weights: &[(u16, f64)],
        d: DVec3,
        g: DVec3,
    ) {
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

    /// The gradient over the whole parameter vector (`3 + 3J + B + E` entries): subtree sums,
    /// moments about each joint centre, the exp-map factor; then rest joints and rest vertices
    /// through the directions and the pose correctives.
    pub fn finish(mut self, template: &Template, kin: &Kinematics, pose: &[f64]) -> Vec<f64> {
        let nj = template.rig.joints.len();
        let morph = &template.morph;
        let k = morph.coefficients();
        let mut grad = vec![0.0; 3 + 3 * nj + k];
        let track_joints = k > 0 && !morph.joint_dirs.is_empty();
        // Parents precede children, so a backward sweep accumulates whole subtrees.
        for j in (0..nj).rev() {
            let m = self.moment[j] - kin.joints[j].cross(self.force[j]);
            let g = kin.factors[j].transpose() * m;
            let o = rot_offset(j);
            grad[o..o + 3].copy_from_slice(&g.to_array());
            let parent = template.rig.joints[j].parent;
            if track_joints {
                let wp = parent.map_or(DMat3::IDENTITY, |p| kin.world(p));
                self.joint_rest[j] += (wp - kin.world(j)).transpose() * self.force[j];
            }
            if let Some(p) = parent {
                let (f, mo) = (self.force[j], self.moment[j]);
                self.force[p] += f;
                self.moment[p] += mo;
            }
        }
        grad[0..3].copy_from_slice(&self.force[0].to_array());
        let Some((m, _, feature)) = &kin.morph else {
            return grad;
        };
        let rest = self.rest.take().unwrap_or_default();
        let base = 3 + 3 * nj;
        if k > 0 {
            let gc = &mut grad[base..base + k];
            add_transposed(gc, &m.dirs, rest.iter().map(|&(v, g)| (v as usize, g)));
            if track_joints {
                add_transposed(
                    gc,
                    &m.joint_dirs,
                    self.joint_rest.iter().copied().enumerate(),
                );
            }
        }
        if let Some(pd) = &m.posedirs
            && !feature.is_empty()
        {
            let mut gf = vec![0.0; feature.len()];
            add_transposed(&mut gf, pd, rest.iter().map(|&(v, g)| (v as usize, g)));
            for j in 1..nj {
                let f = &gf[9 * (j - 1)..9 * j];
                // The feature is row-major: f[3 row + col] = ∂E/∂R[row][col].
                let gm = DMat3::from_cols(
                    DVec3::new(f[0], f[3], f[6]),
                    DVec3::new(f[1], f[4], f[7]),
                    DVec3::new(f[2], f[5], f[8]),
                );
                let o = rot_offset(j);
                let r = DVec3::new(pose[o], pose[o + 1], pose[o + 2]);
                let (rot, jl) = exp_map_and_left_jacobian(r);
                let g = jl.transpose() * rotation_torque(rot, gm);
                for a in 0..3 {
                    grad[o + a] += g[a];
                }
            }
        }
        grad
    }
}

/// Skinning weights and rest geometry in f64, flattened.
#[derive(Debug, Clone)]
pub(crate) struct SkinTable {
    pub rest: Vec<DVec3>,
    entries: Vec<(u16, f64)>,
    offsets: Vec<u32>,
}

impl SkinTable {
    pub(crate) fn new(template: &Template) -> Self {
        let mut entries = Vec::new();
        let mut offsets = vec![0u32];
        for list in &template.rig.weights {
            entries.extend(list.iter().map(|&(j, w)| (j as u16, w)));
            offsets.push(entries.len() as u32);
        }
        Self {
            rest: template.vertices.iter().map(|v| v.as_dvec3()).collect(),
            entries,
            offsets,
        }
    }

    #[inline]
    pub fn weights(&self, v: usize) -> &[(u16, f64)] {
        &self.entries[self.offsets[v] as usize..self.offsets[v + 1] as usize]
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::body::rotation::exp_map;

    #[test]
    fn a_vertex_set_finds_its_members_and_nothing_else() {
        let members: Vec<u32> = (0..40).map(|k| k * 337 % 13_380).chain([5, 5, 0]).collect();
        let set = VertexSet::new(&members);
        let mut distinct = members.clone();
        distinct.sort_unstable();
        distinct.dedup();
        assert_eq!(set.len(), distinct.len());
        for (k, &v) in distinct.iter().enumerate() {
            assert_eq!(set.slot(v), Some(k), "vertex {v}");
        }
        for v in (0..13_380).filter(|v| !distinct.contains(v)) {
            assert_eq!(set.slot(v), None, "vertex {v}");
        }
        assert_eq!(VertexSet::new(&[]).slot(0), None);
    }

    #[test]
    fn left_jacobian_matches_finite_differences_of_exp() {
        // exp([r + h e_i]×) exp([r]×)ᵀ ≈ exp([h Jl e_i]×): compare the skew part.
        // Past π the half angle's cosine turns negative, past 2π its sine (read along `r`).
        for r in [
            DVec3::new(0.3, -0.7, 0.2),
            DVec3::new(1e-6, 0.0, -2e-6),
            DVec3::new(0.0, 2.5, 0.1),
            DVec3::new(-3.1, 1.9, 0.4),
            DVec3::new(0.5, 6.9, -1.2),
        ] {
            let (rot, jl) = exp_map_and_left_jacobian(r);
            assert_eq!(rot, exp_map(r), "the rotation is exp_map's, bit for bit");
            for i in 0..3 {
                let h = 1e-6;
                let mut e = DVec3::ZERO;
                e[i] = h;
                let d = (exp_map(r + e) - exp_map(r - e)) * exp_map(r).transpose() * (0.5 / h);
                let omega = DVec3::new(d.y_axis.z, d.z_axis.x, d.x_axis.y);
                assert!(
                    (omega - jl.col(i)).length() < 1e-7,
                    "r = {r}, axis {i}: {omega} vs {}",
                    jl.col(i)
                );
            }
        }
    }
}
