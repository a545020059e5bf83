//! The built-in vector-valued observation models: `markers`, `keypoints2d` and `hmd`.

use glam::{DMat3, DVec3};
use rand::RngCore;

use super::{
    HMD_DIM, HandVisibility, HmdSetup, KeypointSetup, MarkerSetup, ObservationModel, PoseGradient,
    PoseJacobian, PosedView, ResidualGroup, check_vertices, headset_pose, hmd_layout,
    uniform_groups,
};
use crate::camera::Camera;
use crate::error::{ModelError, Result};
use crate::noise::{NoiseConfig, corrupt_hmd, corrupt_pixels, corrupt_points};
use crate::observe::Scales;
use crate::template::Template;

/// Depth below which a point counts as behind the camera (1 cm).
pub(crate) const DEPTH_FLOOR: f64 = 0.01;

/// Projection of world point `p` by `cam` and the rows `∂(u, v)/∂q` of its derivative with respect
/// to the camera-frame point `q`. Depths are floored at 1 cm (in front of the camera), where the
/// derivative along depth is zero.
pub(crate) fn project(cam: &Camera, p: DVec3) -> ([f64; 2], [DVec3; 2]) {
    project_camera(cam, cam.to_camera(p))
}

/// [`project`] of a point already in the camera frame. The pixel is `f x / z + c` as
/// [`Camera::project_camera`] writes it; the derivative rows share one reciprocal of the depth.
#[inline]
pub(crate) fn project_camera(cam: &Camera, q: DVec3) -> ([f64; 2], [DVec3; 2]) {
    let (z, dz) = if q.z > DEPTH_FLOOR {
        (q.z, 1.0)
    } else {
        (DEPTH_FLOOR, 0.0)
    };
    let u = cam.fx * q.x / z + cam.cx;
    let v = cam.fy * q.y / z + cam.cy;
    let iz = 1.0 / z;
    let (fx, fy) = (cam.fx * iz, cam.fy * iz);
    let du = DVec3::new(fx, 0.0, -dz * fx * q.x * iz);
    let dv = DVec3::new(0.0, fy, -dz * fy * q.y * iz);
    ([u, v], [du, dv])
}

/// [`project_camera`]'s derivative rows alone, applied: `∂(u, v)/∂q` transposed times
/// `(gu, gv)`, the camera-frame gradient of a point whose pixel has gradient `(gu, gv)`.
#[inline]
pub(crate) fn project_camera_adjoint(cam: &Camera, q: DVec3, gu: f64, gv: f64) -> DVec3 {
    let (z, dz) = if q.z > DEPTH_FLOOR {
        (q.z, 1.0)
    } else {
        (DEPTH_FLOOR, 0.0)
    };
    let iz = 1.0 / z;
    let (fu, fv) = (cam.fx * iz * gu, cam.fy * iz * gv);
    DVec3::new(fu, fv, -dz * (fu * q.x + fv * q.y) * iz)
}

/// `out = Σ_a a[a] · rows[a]` for a 3-row, `d`-wide row-major block.
#[inline]
pub(crate) fn combine_rows(out: &mut [f64], a: DVec3, rows: &[f64], d: usize) {
    for (i, o) in out.iter_mut().enumerate() {
        *o = a.x * rows[i] + a.y * rows[d + i] + a.z * rows[2 * d + i];
    }
}

/// The dense Jacobian rows of a factored one ([`ObservationModel::point_factors`]): row `i` is
/// `aᵢᵀ ∂X_p/∂θ` for `rows[i] = (p, aᵢ)`, each point's `3 × d` Jacobian in `points`.
pub(crate) fn expand_point_factors(
    points: &[f64],
    rows: &[(usize, [f64; 3])],
    d: usize,
    out: &mut [f64],
) {
    for (&(p, a), row) in rows.iter().zip(out.chunks_exact_mut(d)) {
        combine_rows(
            row,
            DVec3::from_array(a),
            &points[3 * p * d..3 * (p + 1) * d],
            d,
        );
    }
}

/// A sensor's point offsets: none, or `count` finite ones (`what` names them in a count error,
/// `point(k)` point `k` in a value error).
fn check_offsets(
    offsets: &[[f64; 3]],
    count: usize,
    what: &str,
    point: impl Fn(usize) -> String,
) -> Result<()> {
    if !offsets.is_empty() && offsets.len() != count {
        return Err(ModelError::Shape {
            what: what.into(),
            expected: count.to_string(),
            got: offsets.len().to_string(),
        });
    }
    match offsets
        .iter()
        .position(|d| d.iter().any(|x| !x.is_finite()))
    {
        Some(k) => Err(ModelError::Config(format!(
            "{} has a non-finite offset {:?}",
            point(k),
            offsets[k]
        ))),
        None => Ok(()),
    }
}

impl ObservationModel for MarkerSetup {
    fn name(&self) -> &str {
        "markers"
    }

    fn validate(&self, template: &Template) -> Result<()> {
        if self.names.len() != self.vertices.len() {
            return Err(ModelError::Shape {
                what: "marker names".into(),
                expected: self.vertices.len().to_string(),
                got: self.names.len().to_string(),
            });
        }
        if self.vertices.is_empty() {
            return Err(ModelError::Config(format!(
                "model '{}' has no markers for the markers modality (a rig's \"markers\", or the model file's marker_names/marker_vertices)",
                template.id
            )));
        }
        check_offsets(&self.offsets, self.vertices.len(), "marker offsets", |k| {
            format!("marker '{}'", self.names[k])
        })?;
        check_vertices(template, &self.vertices, "marker vertex")
    }

    fn dim(&self, _: &Template) -> usize {
        3 * self.vertices.len()
    }

    fn groups(&self, _: &Template, scales: &Scales) -> Vec<ResidualGroup> {
        uniform_groups(self.vertices.len(), 3, scales.position)
    }

    fn predict(&self, posed: &PosedView<'_>, values: &mut [f64], visible: &mut [bool]) {
        for (k, &v) in self.vertices.iter().enumerate() {
            let p = posed.skinned_offset(v as usize, self.offset(k));
            values[3 * k..3 * k + 3].copy_from_slice(&p.to_array());
        }
        visible.fill(true);
    }

    fn jacobian(&self, _: &PosedView<'_>, jac: &mut PoseJacobian<'_, '_>, out: &mut [f64]) {
        let d = jac.dim();
        for (k, &v) in self.vertices.iter().enumerate() {
            let rows = &mut out[3 * k * d..3 * (k + 1) * d];
            jac.offset_vertex(v as usize, self.offset(k), rows);
        }
    }

    /// Each marker vertex's Jacobian, and its x, y, z rows as the unit vectors: the robust
    /// folding then acts on 3-vectors, and the normal equations add one `∂Xᵀ C ∂X` per marker.
    fn point_factors(
        &self,
        _: &PosedView<'_>,
        jac: &mut PoseJacobian<'_, '_>,
        points: &mut Vec<f64>,
        rows: &mut Vec<(usize, [f64; 3])>,
    ) -> bool {
        let d = jac.dim();
        points.clear();
        points.resize(3 * self.vertices.len() * d, 0.0);
        for (k, &v) in self.vertices.iter().enumerate() {
            let rows = &mut points[3 * k * d..3 * (k + 1) * d];
            jac.offset_vertex_on_zero(v as usize, self.offset(k), rows);
        }
        rows.clear();
        for k in 0..self.vertices.len() {
            rows.extend([
                (k, [1.0, 0.0, 0.0]),
                (k, [0.0, 1.0, 0.0]),
                (k, [0.0, 0.0, 1.0]),
            ]);
        }
        true
    }

    fn vertices_read(&self) -> Vec<u32> {
        self.vertices.clone()
    }

    fn backprop(&self, _: &PosedView<'_>, dpred: &[f64], grad: &mut PoseGradient<'_, '_>) {
        for (k, &v) in self.vertices.iter().enumerate() {
            let g = DVec3::new(dpred[3 * k], dpred[3 * k + 1], dpred[3 * k + 2]);
            grad.offset_vertex(v as usize, self.offset(k), g);
        }
    }

    fn corrupt(
        &self,
        values: &mut [f64],
        visible: &mut [bool],
        noise: &NoiseConfig,
        rng: &mut dyn RngCore,
    ) {
        corrupt_points(
            values,
            visible,
            3,
            noise.point_sigma,
            noise.outlier_scale_m,
            noise,
            rng,
        );
    }
}

impl ObservationModel for KeypointSetup {
    fn name(&self) -> &str {
        "keypoints2d"
    }

    fn validate(&self, template: &Template) -> Result<()> {
        self.cameras
            .iter()
            .enumerate()
            .try_for_each(|(i, c)| c.validate(i))?;
        check_offsets(
            &self.offsets,
            template.rig.num_joints(),
            "keypoint offsets (one per joint)",
            |j| format!("the keypoint of joint {j}"),
        )
    }

    fn dim(&self, template: &Template) -> usize {
        2 * self.cameras.len() * template.rig.num_joints()
    }

    fn groups(&self, template: &Template, scales: &Scales) -> Vec<ResidualGroup> {
        uniform_groups(
            self.cameras.len() * template.rig.num_joints(),
            2,
            scales.pixel,
        )
    }

    /// Every keypoint (a joint centre, or the point at its offset) in every camera; a keypoint
    /// is seen when it is in front of the camera (depth > 1 cm) and projects inside the image.
    fn predict(&self, posed: &PosedView<'_>, values: &mut [f64], visible: &mut [bool]) {
        let nj = posed.num_joints();
        for (c, cam) in self.cameras.iter().enumerate() {
            for j in 0..nj {
                let q = cam.to_camera(self.keypoint(posed, j));
                let (uv, _) = project_camera(cam, q);
                let i = 2 * (c * nj + j);
                values[i..i + 2].copy_from_slice(&uv);
                let seen = q.z > DEPTH_FLOOR && cam.in_image(glam::DVec2::new(uv[0], uv[1]));
                visible[i..i + 2].fill(seen);
            }
        }
    }

    fn jacobian(&self, posed: &PosedView<'_>, jac: &mut PoseJacobian<'_, '_>, out: &mut [f64]) {
        let (mut points, mut rows) = (Vec::new(), Vec::new());
        self.point_factors(posed, jac, &mut points, &mut rows);
        expand_point_factors(&points, &rows, jac.dim(), out);
    }

    /// Each keypoint's Jacobian (its joint's centre, or the point at its offset), and per row
    /// the camera's projection row `∂uv/∂X`.
    fn point_factors(
        &self,
        posed: &PosedView<'_>,
        jac: &mut PoseJacobian<'_, '_>,
        points: &mut Vec<f64>,
        rows: &mut Vec<(usize, [f64; 3])>,
    ) -> bool {
        let d = jac.dim();
        let nj = posed.num_joints();
        points.clear();
        points.resize(3 * nj * d, 0.0);
        for j in 0..nj {
            let carrier = KeypointSetup::carrier(posed.template(), j);
            let p = self.keypoint(posed, j);
            jac.carried_point_on_zero(j, carrier, p, &mut points[3 * j * d..3 * (j + 1) * d]);
        }
        rows.clear();
        for cam in &self.cameras {
            let rot_t = cam.rot().transpose();
            for j in 0..nj {
                let (_, dq) = project(cam, self.keypoint(posed, j));
                rows.extend(dq.iter().map(|dq| (j, (rot_t * *dq).to_array())));
            }
        }
        true
    }

    fn backprop(&self, posed: &PosedView<'_>, dpred: &[f64], grad: &mut PoseGradient<'_, '_>) {
        // A keypoint's gradient summed over the cameras first: one reverse-mode point per joint.
        let nj = posed.num_joints();
        let mut g = vec![DVec3::ZERO; nj];
        for (c, cam) in self.cameras.iter().enumerate() {
            let rot_t = cam.rot().transpose();
            for (j, gj) in g.iter_mut().enumerate() {
                let i = 2 * (c * nj + j);
                let (gu, gv) = (dpred[i], dpred[i + 1]);
                if gu == 0.0 && gv == 0.0 {
                    continue;
                }
                let q = cam.to_camera(self.keypoint(posed, j));
                *gj += rot_t * project_camera_adjoint(cam, q, gu, gv);
            }
        }
        for (j, gj) in g.into_iter().enumerate() {
            if gj != DVec3::ZERO {
                let carrier = KeypointSetup::carrier(posed.template(), j);
                grad.carried_point(j, carrier, self.keypoint(posed, j), gj);
            }
        }
    }

    fn corrupt(
        &self,
        values: &mut [f64],
        visible: &mut [bool],
        noise: &NoiseConfig,
        rng: &mut dyn RngCore,
    ) {
        corrupt_pixels(values, visible, noise, rng);
    }
}

/// Headset and both wrists as (joint, rotation, position), in the order of the `hmd` prediction.
fn hmd_devices(setup: &HmdSetup, posed: &PosedView<'_>) -> Option<[(usize, DMat3, DVec3); 3]> {
    let [head, left, right] = posed.template().hmd_joints().ok()?;
    let headset = headset_pose(setup, posed.joint_rotation(head), posed.joint(head));
    Some([
        (head, headset.matrix3, headset.translation),
        (left, posed.joint_rotation(left), posed.joint(left)),
        (right, posed.joint_rotation(right), posed.joint(right)),
    ])
}

impl ObservationModel for HmdSetup {
    fn name(&self) -> &str {
        "hmd"
    }

    fn validate(&self, template: &Template) -> Result<()> {
        template.hmd_joints()?;
        check_vertices(template, &self.hand_tips, "hand tip vertex")
    }

    fn dim(&self, _: &Template) -> usize {
        HMD_DIM
    }

    /// Per device a rotation group (9 entries) and a position group (3), then the two hand tips.
    fn groups(&self, _: &Template, scales: &Scales) -> Vec<ResidualGroup> {
        let mut out = Vec::with_capacity(8);
        for d in 0..hmd_layout::DEVICES {
            out.push(ResidualGroup {
                start: hmd_layout::device(d),
                len: 9,
                sigma: scales.rotation,
            });
            out.push(ResidualGroup {
                start: hmd_layout::position(d),
                len: 3,
                sigma: scales.position,
            });
        }
        out.extend((0..2).map(|k| ResidualGroup {
            start: hmd_layout::tip(k),
            len: 3,
            sigma: scales.position,
        }));
        out
    }

    /// The headset and both wrists as 3×4 `[R | t]` (row-major), then both hand tips. The headset
    /// is always seen; with [`HandVisibility::HalfSpace`] a hand (wrist and tip) is seen only in
    /// front of the headset (negative z in its frame).
    fn predict(&self, posed: &PosedView<'_>, values: &mut [f64], visible: &mut [bool]) {
        let Some(devices) = hmd_devices(self, posed) else {
            // `validate` refuses a model without the joints; nothing is seen.
            values.fill(0.0);
            visible.fill(false);
            return;
        };
        let device_from_world = glam::DAffine3 {
            matrix3: devices[0].1,
            translation: devices[0].2,
        }
        .inverse();
        for (d, &(_, rot, pos)) in devices.iter().enumerate() {
            let (o, p) = (hmd_layout::device(d), hmd_layout::position(d));
            for row in 0..3 {
                values[o + 3 * row..o + 3 * row + 3].copy_from_slice(&[
                    rot.x_axis[row],
                    rot.y_axis[row],
                    rot.z_axis[row],
                ]);
            }
            values[p..p + 3].copy_from_slice(&pos.to_array());
            let seen = d == 0
                || match self.visibility {
                    HandVisibility::Full => true,
                    HandVisibility::HalfSpace => device_from_world.transform_point3(pos).z < 0.0,
                };
            visible[o..o + hmd_layout::BLOCK].fill(seen);
        }
        for (k, &tip) in self.hand_tips.iter().enumerate() {
            let o = hmd_layout::tip(k);
            values[o..o + 3].copy_from_slice(&posed.vertex(tip as usize).to_array());
            let seen = visible[hmd_layout::device(hmd_layout::tip_device(k))];
            visible[o..o + 3].fill(seen);
        }
    }

    fn jacobian(&self, posed: &PosedView<'_>, jac: &mut PoseJacobian<'_, '_>, out: &mut [f64]) {
        let d = jac.dim();
        let Some(devices) = hmd_devices(self, posed) else {
            out.fill(0.0);
            return;
        };
        for (dev, &(joint, rot, pos)) in devices.iter().enumerate() {
            let (o, p) = (hmd_layout::device(dev), hmd_layout::position(dev));
            jac.carried_rotation(joint, rot, &mut out[o * d..(o + 9) * d]);
            jac.joint_point(joint, pos, &mut out[p * d..(p + 3) * d]);
        }
        for (k, &tip) in self.hand_tips.iter().enumerate() {
            let o = hmd_layout::tip(k);
            jac.vertex(tip as usize, &mut out[o * d..(o + 3) * d]);
        }
    }

    fn vertices_read(&self) -> Vec<u32> {
        self.hand_tips.to_vec()
    }

    fn backprop(&self, posed: &PosedView<'_>, dpred: &[f64], grad: &mut PoseGradient<'_, '_>) {
        let Some(devices) = hmd_devices(self, posed) else {
            return;
        };
        let vec3 = |i: usize| DVec3::new(dpred[i], dpred[i + 1], dpred[i + 2]);
        for (dev, &(joint, rot, pos)) in devices.iter().enumerate() {
            let o = hmd_layout::device(dev);
            let g = DMat3::from_cols(
                DVec3::new(dpred[o], dpred[o + 3], dpred[o + 6]),
                DVec3::new(dpred[o + 1], dpred[o + 4], dpred[o + 7]),
                DVec3::new(dpred[o + 2], dpred[o + 5], dpred[o + 8]),
            );
            grad.carried_rotation(joint, rot, g);
            grad.joint_point(joint, pos, vec3(hmd_layout::position(dev)));
        }
        for (k, &tip) in self.hand_tips.iter().enumerate() {
            grad.vertex(tip as usize, vec3(hmd_layout::tip(k)));
        }
    }

    fn corrupt(
        &self,
        values: &mut [f64],
        visible: &mut [bool],
        noise: &NoiseConfig,
        rng: &mut dyn RngCore,
    ) {
        corrupt_hmd(values, visible, noise, rng);
    }
}
