//! Forward-mode Jacobians of the three things the observation models read off a posed model: a
//! skinned vertex, a point carried rigidly by a joint, and a joint's world rotation.
//!
//! These are the columns of the factors that [`super::kinematics`] uses in reverse mode. Rotating
//! joint `a` by the local exp-map increment `δr_a` turns its subtree by the world angle
//! `ω = Ω_a δr_a` (`Ω_a = W_parent(a) Jl(r_a)`, [`Kinematics::factors`]), which moves a point `p`
//! of the subtree by `ω × (p − J_a)` and a rotation `W` by `[ω]× W`. A skinned vertex
//! `Σ_j w_j A_j x` therefore has the rotation block `[W_a J_a − q_a]× Ω_a` for every joint `a`
//! above one of its influences, with `q_a = Σ_{j below a} w_j A_j x` and `W_a = Σ_{j below a} w_j`
//! — one 3×3 product per ancestor, not per influence and ancestor.
//!
//! On a morphable model (SPEC §3a) a point carried by joint `j` from rest point `x` is
//! `W_j (x − c_j) + J_j`, so with `U_j = Σ_{k ∈ chain(j)} (W_parent(k) − W_k) ∂c_k/∂[β; ψ]`
//! (accumulated root to leaf) a skinned vertex has the coefficient block
//! `Σ_j w_j (W_j ∂T_v/∂[β; ψ] + U_j)` and a joint-carried point `U_j + W_j ∂c_j/∂[β; ψ]`. Pose
//! correctives add `Σ_j w_j W_j P_v ∂(R_b − I)/∂r_b` to the rotation block of every joint `b`,
//! with `∂R_b/∂r_b,k = [Jl(r_b) e_k]× R_b`.

use glam::{DMat3, DVec3};

use super::kinematics::{Kinematics, SkinTable, skew};
use crate::body::rotation::exp_map_and_left_jacobian;
use crate::pose::rot_offset;
use crate::template::Template;

/// The per-evaluation factors of the forward-mode Jacobian, and scratch space.
pub(crate) struct PointJacobians<'a> {
    kin: &'a Kinematics,
    skin: &'a SkinTable,
    parents: Vec<Option<usize>>,
    /// Length of the parameter vector (the width of every Jacobian row).
    pub dim: usize,
    /// B + E.
    coefficients: usize,
    /// First coefficient column (`3 + 3J`).
    coefficient_base: usize,
    /// `U_j` as `3 × K` row-major per joint; empty when the rest joints do not follow the
    /// coefficients.
    u: Vec<f64>,
    /// `∂(R_b − I)/∂r_b,k` per joint (`[DMat3; 3]`; joint 0 unused); empty without correctives.
    feature_derivatives: Vec<[DMat3; 3]>,
    /// Per joint: the weighted sum of influence points below it and their weight (scratch).
    accumulated: Vec<(DVec3, f64)>,
    touched: Vec<usize>,
}

impl<'a> PointJacobians<'a> {
    /// `kin` must have been built with factors.
    pub fn new(
        template: &Template,
        kin: &'a Kinematics,
        skin: &'a SkinTable,
        pose: &[f64],
    ) -> Self {
        let nj = template.rig.num_joints();
        let parents: Vec<Option<usize>> = template.rig.joints.iter().map(|j| j.parent).collect();
        let morph = &template.morph;
        let k = morph.coefficients();
        let mut u = Vec::new();
        if k > 0 && !morph.joint_dirs.is_empty() {
            u = vec![0.0; nj * 3 * k];
            for j in 0..nj {
                let wp = parents[j].map_or(DMat3::IDENTITY, |p| kin.world(p));
                let d = wp - kin.world(j);
                let (head, tail) = u.split_at_mut(j * 3 * k);
                let uj = &mut tail[..3 * k];
                if let Some(p) = parents[j] {
                    uj.copy_from_slice(&head[p * 3 * k..(p + 1) * 3 * k]);
                }
                // U_j += (W_parent − W_j) ∂c_j/∂c, row by row over the K contiguous columns
                // (each entry summed as the matrix-vector product sums it).
                let dirs = &morph.joint_dirs[3 * j * k..3 * (j + 1) * k];
                let (cx, rest) = dirs.split_at(k);
                let (cy, cz) = rest.split_at(k);
                for a in 0..3 {
                    let (mx, my, mz) = (d.x_axis[a], d.y_axis[a], d.z_axis[a]);
                    for (i, o) in uj[a * k..(a + 1) * k].iter_mut().enumerate() {
                        *o += mx * cx[i] + my * cy[i] + mz * cz[i];
                    }
                }
            }
        }
        let mut feature_derivatives = Vec::new();
        if morph.posedirs.is_some() {
            feature_derivatives = (0..nj)
                .map(|b| {
                    let o = rot_offset(b);
                    let r = DVec3::new(pose[o], pose[o + 1], pose[o + 2]);
                    let (rot, jl) = exp_map_and_left_jacobian(r);
                    [0, 1, 2].map(|kk| skew(jl.col(kk)) * rot)
                })
                .collect();
        }
        Self {
            kin,
            skin,
            dim: template.param_dim(),
            coefficients: k,
            coefficient_base: 3 + 3 * nj,
            u,
            feature_derivatives,
            accumulated: vec![(DVec3::ZERO, 0.0); nj],
            touched: Vec::with_capacity(nj),
            parents,
        }
    }

    /// The 3 × dim Jacobian (row-major, overwritten) of skinned vertex `v`; returns its position.
    pub fn skinned_point(&mut self, v: usize, out: &mut [f64]) -> DVec3 {
        out[..3 * self.dim].fill(0.0);
        self.skinned_point_on_zero(v, DVec3::ZERO, out)
    }

    /// [`PointJacobians::skinned_point`] into rows the caller has just zeroed (a freshly
    /// resized buffer): writes only the non-zero entries. With a nonzero `offset` the point is
    /// skinned like vertex `v` from its rest position plus `offset` (a constant: the shape
    /// columns are the vertex's).
    pub fn skinned_point_on_zero(&mut self, v: usize, offset: DVec3, out: &mut [f64]) -> DVec3 {
        let d = self.dim;
        debug_assert!(out[..3 * d].iter().all(|&x| x == 0.0));
        let kin = self.kin;
        let mut x = kin.rest(&self.skin.rest, v);
        if offset != DVec3::ZERO {
            x += offset;
        }
        let weights = self.skin.weights(v);
        let mut position = DVec3::ZERO;
        let mut wsum = 0.0;
        let mut linear = DMat3::ZERO;
        for &(j, w) in weights {
            if w == 0.0 {
                continue;
            }
            let j = j as usize;
            let p = kin.transforms[j].transform_point3(x);
            position += w * p;
            wsum += w;
            linear += kin.world(j) * w;
            let mut a = Some(j);
            while let Some(b) = a {
                let acc = &mut self.accumulated[b];
                if acc.1 == 0.0 {
                    self.touched.push(b);
                }
                acc.0 += w * p;
                acc.1 += w;
                a = self.parents[b];
            }
        }
        for a in 0..3 {
            out[a * d + a] = wsum;
        }
        for &b in &self.touched {
            let (q, wb) = std::mem::take(&mut self.accumulated[b]);
            write_block(
                out,
                d,
                rot_offset(b),
                skew(kin.joints[b] * wb - q) * kin.factors[b],
            );
        }
        self.touched.clear();
        let k = self.coefficients;
        if let Some((m, _, _)) = &kin.morph {
            if k > 0 {
                // Column kk is `linear · ∂T_v/∂c_kk + Σ_j w_j U_j[:, kk]`, written row by row
                // over the K columns (contiguous in `dirs`, `U` and `out`), each entry summed in
                // the order of the product and the influences: the same numbers to the bit as
                // column by column.
                let dirs = &m.dirs[3 * v * k..3 * (v + 1) * k];
                let (dx, rest) = dirs.split_at(k);
                let (dy, dz) = rest.split_at(k);
                let base = self.coefficient_base;
                for a in 0..3 {
                    let row = &mut out[a * d + base..a * d + base + k];
                    let (lx, ly, lz) = (linear.x_axis[a], linear.y_axis[a], linear.z_axis[a]);
                    for (i, o) in row.iter_mut().enumerate() {
                        *o = lx * dx[i] + ly * dy[i] + lz * dz[i];
                    }
                    if !self.u.is_empty() {
                        for &(j, w) in weights {
                            let uj = &self.u[j as usize * 3 * k + a * k..][..k];
                            for (o, &u) in row.iter_mut().zip(uj) {
                                *o += w * u;
                            }
                        }
                    }
                }
            }
            if let Some(pd) = &m.posedirs
                && !self.feature_derivatives.is_empty()
            {
                // posedirs is (3V) × 9(J − 1).
                let n = 9 * (self.feature_derivatives.len() - 1);
                for (b, dr) in self.feature_derivatives.iter().enumerate().skip(1) {
                    let base = 9 * (b - 1);
                    for (kk, dr) in dr.iter().enumerate() {
                        let mut y = DVec3::ZERO;
                        for a in 0..3 {
                            let row = &pd[(3 * v + a) * n + base..(3 * v + a) * n + base + 9];
                            let mut s = 0.0;
                            for r in 0..3 {
                                for c in 0..3 {
                                    s += row[3 * r + c] * dr.col(c)[r];
                                }
                            }
                            y[a] = s;
                        }
                        let col = linear * y;
                        for a in 0..3 {
                            out[a * d + rot_offset(b) + kk] += col[a];
                        }
                    }
                }
            }
        }
        position
    }

    /// The 3 × dim Jacobian (overwritten) of the world point `p` carried rigidly by `joint` whose
    /// rest position is the joint's rest centre plus a constant offset (the joint centre itself,
    /// a headset, an ellipsoid's centre).
    pub fn joint_point(&self, joint: usize, p: DVec3, out: &mut [f64]) {
        out[..3 * self.dim].fill(0.0);
        self.joint_point_on_zero(joint, p, out);
    }

    /// [`PointJacobians::joint_point`] into rows the caller has just zeroed.
    pub fn joint_point_on_zero(&self, joint: usize, p: DVec3, out: &mut [f64]) {
        self.carried_point_on_zero(joint, joint, p, out);
    }

    /// Into rows the caller has just zeroed: the world point `p` at a constant offset from
    /// `joint`'s centre in the frame of `carrier` (`joint` itself or one of its ancestors), `p =
    /// x_joint + W_carrier d`: the rotations from `carrier` up move it, β moves it as it moves the
    /// joint's centre. [`PointJacobians::joint_point_on_zero`] when `carrier` is `joint`.
    pub fn carried_point_on_zero(&self, joint: usize, carrier: usize, p: DVec3, out: &mut [f64]) {
        let d = self.dim;
        debug_assert!(out[..3 * d].iter().all(|&x| x == 0.0));
        for a in 0..3 {
            out[a * d + a] = 1.0;
        }
        let kin = self.kin;
        let mut a = Some(carrier);
        while let Some(b) = a {
            write_block(
                out,
                d,
                rot_offset(b),
                skew(kin.joints[b] - p) * kin.factors[b],
            );
            a = self.parents[b];
        }
        let k = self.coefficients;
        if k > 0
            && !self.u.is_empty()
            && let Some((m, _, _)) = &kin.morph
        {
            let w = kin.world(joint);
            let uj = &self.u[joint * 3 * k..(joint + 1) * 3 * k];
            for kk in 0..k {
                let c = DVec3::new(
                    m.joint_dirs[3 * joint * k + kk],
                    m.joint_dirs[(3 * joint + 1) * k + kk],
                    m.joint_dirs[(3 * joint + 2) * k + kk],
                );
                let col = DVec3::new(uj[kk], uj[k + kk], uj[2 * k + kk]) + w * c;
                for a in 0..3 {
                    out[a * d + self.coefficient_base + kk] = col[a];
                }
            }
        }
    }

    /// The world angular velocities `∂W_joint = [ω_c]× W_joint` of `joint`'s world rotation, as
    /// `(column, ω_c)` for every column that moves it (the rotations on its chain).
    pub fn rotation(&self, joint: usize) -> Vec<(usize, DVec3)> {
        let mut out = Vec::with_capacity(24);
        let mut a = Some(joint);
        while let Some(b) = a {
            for k in 0..3 {
                out.push((rot_offset(b) + k, self.kin.factors[b].col(k)));
            }
            a = self.parents[b];
        }
        out
    }
}

/// Writes a 3×3 block at columns `col..col + 3` of a 3-row, `d`-wide row-major matrix.
#[inline]
fn write_block(out: &mut [f64], d: usize, col: usize, m: DMat3) {
    for c in 0..3 {
        let v = m.col(c);
        for r in 0..3 {
            out[r * d + col + c] = v[r];
        }
    }
}
