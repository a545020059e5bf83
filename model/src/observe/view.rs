//! What an observation model reads off a posed model, and the two ways its derivatives reach the
//! parameters: forward mode ([`PoseJacobian`], rows of `∂prediction/∂θ` for least squares) and
//! reverse mode ([`PoseGradient`], `(∂prediction/∂θ)ᵀ g` for the energy's gradient).
//!
//! All three speak of the same three things a sensor can see: a skinned vertex, a point carried
//! rigidly by a joint (the joint centre itself, a headset, a body-worn sensor) and a rotation
//! carried by a joint (an IMU's or a tracker's orientation). Everything is f64, built on the
//! body's kinematics with derivatives ([`crate::body::kinematics`]), so a prediction, its Jacobian and its gradient are
//! the same function.

use glam::{DMat3, DVec3, Vec3};

use crate::body::jacobian::PointJacobians;
use crate::body::kinematics::{Adjoint, Kinematics, SkinTable, rotation_torque};
use crate::skinning::{Posed, skin_lbs_into};
use crate::template::Template;

/// A posed model, read-only: joint centres, joint world rotations and skinned vertices.
pub struct PosedView<'a> {
    pub(crate) template: &'a Template,
    pub(crate) kin: &'a Kinematics,
    /// The energy's flattened skinning table; `None` outside an energy (then vertices are skinned
    /// from the template's own weights, with the same arithmetic).
    pub(crate) skin: Option<&'a SkinTable>,
}

impl<'a> PosedView<'a> {
    pub fn template(&self) -> &'a Template {
        self.template
    }

    pub fn num_joints(&self) -> usize {
        self.kin.joints.len()
    }

    /// World position of joint `j`'s centre.
    pub fn joint(&self, j: usize) -> DVec3 {
        self.kin.joints[j]
    }

    /// World rotation of joint `j`'s frame.
    pub fn joint_rotation(&self, j: usize) -> DMat3 {
        self.kin.world(j)
    }

    /// The point skinned like vertex `v` from its rest position plus `offset` (rest frame,
    /// metres): a marker that sits off its vertex ([`crate::observe::MarkerSetup::offsets`]).
    /// [`PosedView::vertex`] when `offset` is zero.
    pub fn skinned_offset(&self, v: usize, offset: DVec3) -> DVec3 {
        // The offset is added only when there is one: a vertex's own position to the bit.
        let moved = |x: DVec3| if offset == DVec3::ZERO { x } else { x + offset };
        match self.skin {
            Some(s) => self
                .kin
                .skin(s.weights(v), moved(self.kin.rest(&s.rest, v))),
            None => {
                let x = moved(self.kin.rest_of(v, self.template.vertices[v].as_dvec3()));
                self.template.rig.weights[v]
                    .iter()
                    .fold(DVec3::ZERO, |acc, &(j, w)| {
                        acc + w * self.kin.transforms[j].transform_point3(x)
                    })
            }
        }
    }

    /// The linear part `Σ_j w_j W_j` of vertex `v`'s skinning: how a rest-frame offset of a point
    /// skinned like `v` moves it ([`PosedView::skinned_offset`] is affine in the offset).
    pub fn skin_linear(&self, v: usize) -> DMat3 {
        let add = |acc: DMat3, j: usize, w: f64| acc + self.kin.world(j) * w;
        match self.skin {
            Some(s) => s
                .weights(v)
                .iter()
                .fold(DMat3::ZERO, |acc, &(j, w)| add(acc, j as usize, w)),
            None => self.template.rig.weights[v]
                .iter()
                .fold(DMat3::ZERO, |acc, &(j, w)| add(acc, j, w)),
        }
    }

    /// Skinned position of template vertex `v` (blend shapes and pose correctives included).
    pub fn vertex(&self, v: usize) -> DVec3 {
        self.skinned_offset(v, DVec3::ZERO)
    }
}

impl PosedView<'_> {
    /// Every posed vertex as the renderers skin them ([`crate::skinning::skin_lbs_into`]: f32 on
    /// the rigid template, f64 otherwise): the mesh dense sensors render or sample, identical to
    /// what [`crate::skinning`] gives for the same parameters.
    pub fn mesh(&self) -> Vec<Vec3> {
        let (coeffs, pose_feature) = match &self.kin.morph {
            Some((_, c, f)) => (c.clone(), f.clone()),
            None => (Vec::new(), Vec::new()),
        };
        let posed = Posed {
            transforms: self.kin.transforms.clone(),
            joints: self.kin.joints.clone(),
            rest_joints: self.kin.rest_joints.clone(),
            coeffs,
            pose_feature,
        };
        let mut out = Vec::with_capacity(self.template.num_vertices());
        skin_lbs_into(self.template, &posed, &mut out);
        out
    }
}

/// Forward-mode derivatives: each method overwrites rows of `dim()` columns (row-major) with the
/// Jacobian of what it names over the whole parameter vector.
pub struct PoseJacobian<'a, 'b> {
    pub(crate) inner: &'b mut PointJacobians<'a>,
    pub(crate) kin: &'a Kinematics,
}

impl PoseJacobian<'_, '_> {
    /// Columns of every row: the parameter vector's length.
    pub fn dim(&self) -> usize {
        self.inner.dim
    }

    /// 3 rows: skinned vertex `v`. Returns its position.
    pub fn vertex(&mut self, v: usize, out: &mut [f64]) -> DVec3 {
        self.offset_vertex(v, DVec3::ZERO, out)
    }

    /// 3 rows: the point skinned like vertex `v` from its rest position plus `offset`
    /// ([`PosedView::skinned_offset`]). Returns its position.
    pub fn offset_vertex(&mut self, v: usize, offset: DVec3, out: &mut [f64]) -> DVec3 {
        out[..3 * self.dim()].fill(0.0);
        self.inner.skinned_point_on_zero(v, offset, out)
    }

    /// 3 rows: joint `j`'s centre.
    pub fn joint(&self, j: usize, out: &mut [f64]) {
        self.inner.joint_point(j, self.kin.joints[j], out);
    }

    /// [`PoseJacobian::offset_vertex`] into rows the caller has just zeroed (a freshly resized
    /// buffer): skips the second zero fill.
    pub(crate) fn offset_vertex_on_zero(
        &mut self,
        v: usize,
        offset: DVec3,
        out: &mut [f64],
    ) -> DVec3 {
        self.inner.skinned_point_on_zero(v, offset, out)
    }

    /// Into rows the caller has just zeroed: the world point `p` at a constant offset from joint
    /// `j`'s centre in the frame of `carrier` (`j` or an ancestor): `p = x_j + W_carrier d`.
    pub(crate) fn carried_point_on_zero(
        &self,
        j: usize,
        carrier: usize,
        p: DVec3,
        out: &mut [f64],
    ) {
        self.inner.carried_point_on_zero(j, carrier, p, out);
    }

    /// 3 rows: the world point `p` carried rigidly by joint `j` at a constant offset from its
    /// centre (a headset, a body-worn sensor).
    pub fn joint_point(&self, j: usize, p: DVec3, out: &mut [f64]) {
        self.inner.joint_point(j, p, out);
    }

    /// 9 rows: the entries (row-major) of the world rotation `rot` carried by joint `j`
    /// (`rot = W_j C` for a constant `C`): `∂rot = [ω]× rot` for every rotation on `j`'s chain.
    pub fn carried_rotation(&self, j: usize, rot: DMat3, out: &mut [f64]) {
        let d = self.dim();
        out[..9 * d].fill(0.0);
        for (col_param, omega) in self.inner.rotation(j) {
            for col in 0..3 {
                let dv = omega.cross(rot.col(col));
                for row in 0..3 {
                    out[(3 * row + col) * d + col_param] = dv[row];
                }
            }
        }
    }
}

/// Reverse-mode derivatives: each method adds `(∂x/∂θ)ᵀ g` for the gradient `g` of the objective
/// with respect to the thing `x` it names.
pub struct PoseGradient<'a, 'b> {
    pub(crate) template: &'a Template,
    pub(crate) kin: &'a Kinematics,
    pub(crate) skin: &'a SkinTable,
    pub(crate) params: &'a [f64],
    pub(crate) adjoint: &'b mut Adjoint,
    /// Gradient entries added directly (by [`PoseGradient::parameters`]).
    pub(crate) direct: &'b mut [f64],
}

impl PoseGradient<'_, '_> {
    /// Length of the parameter vector.
    pub fn dim(&self) -> usize {
        self.template.param_dim()
    }

    /// Skinned vertex `v`.
    pub fn vertex(&mut self, v: usize, g: DVec3) {
        self.offset_vertex(v, DVec3::ZERO, g);
    }

    /// The point skinned like vertex `v` from its rest position plus `offset`
    /// ([`PosedView::skinned_offset`]).
    pub fn offset_vertex(&mut self, v: usize, offset: DVec3, g: DVec3) {
        if g != DVec3::ZERO {
            let s = self.skin;
            let mut x = self.kin.rest(&s.rest, v);
            if offset != DVec3::ZERO {
                x += offset;
            }
            self.adjoint.skinned_point(self.kin, s.weights(v), v, x, g);
        }
    }

    /// Joint `j`'s centre.
    pub fn joint(&mut self, j: usize, g: DVec3) {
        self.adjoint.joint_point(self.kin, j, self.kin.joints[j], g);
    }

    /// A world point `p` carried rigidly by joint `j` (see [`PoseJacobian::joint_point`]).
    pub fn joint_point(&mut self, j: usize, p: DVec3, g: DVec3) {
        self.adjoint.joint_point(self.kin, j, p, g);
    }

    /// A world point `p = x_j + W_carrier d` at a constant offset `d` from joint `j`'s centre in
    /// the frame of `carrier` (`j` or an ancestor).
    pub(crate) fn carried_point(&mut self, j: usize, carrier: usize, p: DVec3, g: DVec3) {
        self.adjoint.carried_point(self.kin, j, carrier, p, g);
    }

    /// The world rotation `rot` carried by joint `j`, with `g[row][col] = ∂E/∂rot[row][col]`
    /// (as glam columns: `g.col(c)[r]`).
    pub fn carried_rotation(&mut self, j: usize, rot: DMat3, g: DMat3) {
        self.adjoint.torque(j, rotation_torque(rot, g));
    }

    /// Adds a gradient over the whole parameter vector (`dim()` entries).
    pub fn parameters(&mut self, g: &[f64]) {
        for (d, gi) in self.direct.iter_mut().zip(g) {
            *d += gi;
        }
    }

    /// Runs `f` with a forward-mode Jacobian of the same posed model (how the default
    /// [`super::ObservationModel::backprop`] works: `Jᵀ g`).
    pub fn with_jacobian<R>(&self, f: impl FnOnce(&mut PoseJacobian<'_, '_>) -> R) -> R {
        let mut pj = PointJacobians::new(self.template, self.kin, self.skin, self.params);
        f(&mut PoseJacobian {
            inner: &mut pj,
            kin: self.kin,
        })
    }
}
