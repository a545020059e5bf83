//! The prior terms of papers/000 eq. (3): EP (ellipsoid self-penetration, eq. 8) and EA
//! (joint-angle prior, eq. 7).

use glam::{DMat3, DVec3};
use serde::{Deserialize, Serialize};

use super::SkinTable;
use super::jacobian::PointJacobians;
use super::kinematics::{Adjoint, Kinematics};
use crate::pose::{Bounds, rot_offset};
use crate::template::Template;

/// Form of the joint-angle prior EA.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum AnglePrior {
    /// papers/000 eq. (7): `α_j = 1` when any rotation component of joint j lies outside its
    /// limits, else 0. Piecewise constant: no gradient.
    #[default]
    Binary,
    /// A smooth counterpart for gradient methods: `Σ_j Σ_axes (max(0, r − hi)² + max(0, lo − r)²)`
    /// in rad².
    Hinge,
}

/// Fewest dominant vertices a segment needs to get an ellipsoid.
const MIN_SEGMENT_VERTICES: usize = 8;
/// A surface sample of an ellipsoid with semi-axis `a` has variance `a²/3` along that axis, so
/// the ellipsoid through a segment's vertices is `(y − μ)ᵀ (3Σ)⁻¹ (y − μ) ≤ 1`; we shrink it by
/// this factor so that it sits inside the flesh of the segment rather than on its skin.
const ELLIPSOID_SHRINK: f64 = 0.85;

/// One body-segment ellipsoid in the rest pose: `{y : (y − μ)ᵀ Q (y − μ) < 1}`.
#[derive(Debug, Clone)]
pub(crate) struct Ellipsoid {
    pub(crate) joint: usize,
    pub(crate) centre: DVec3,
    pub(crate) q: DMat3,
    /// Radius of a sphere around `centre` that holds the ellipsoid.
    pub(crate) radius: f64,
    /// The joint's rest position when the ellipsoid was fitted: on a morphable model the
    /// ellipsoid moves with its joint, `centre + c_j(β, ψ) − joint_rest`.
    pub(crate) joint_rest: DVec3,
}

/// EP of papers/000 eq. (8) with per-segment ellipsoids fitted to the vertices whose dominant
/// skinning weight belongs to the segment's joint.
///
/// `ρ_j(v) = (1 − q_j(v))²` when the posed vertex `v` is inside the posed ellipsoid of joint j
/// (`q < 1`, `q` its ellipsoidal radius squared), else 0 — smooth (C¹) so EP has an exact gradient.
/// A vertex is not tested against its own segment, the segments adjacent to it in the skeleton,
/// or an ellipsoid it already lies in at rest. EP is averaged over the tested vertices (a
/// fixed subset, every `stride`-th vertex) so its scale does not depend on the mesh resolution.
#[derive(Debug, Clone)]
pub(crate) struct Penetration {
    pub(crate) ellipsoids: Vec<Ellipsoid>,
    /// Tested vertices and, per vertex, the ellipsoids (indices into `ellipsoids`) it is tested
    /// against.
    pub(crate) tests: Vec<(u32, Vec<u16>)>,
    /// Ranges of `tests` that share a dominant joint.
    segments: Vec<(usize, usize)>,
    pub(crate) count: usize,
}

impl Penetration {
    pub fn new(template: &Template, stride: usize) -> Self {
        let dominant = template.dominant_joint();
        let nj = template.rig.num_joints();
        let mut ellipsoids = Vec::new();
        for j in 0..nj {
            let pts: Vec<DVec3> = template
                .vertices
                .iter()
                .zip(&dominant)
                .filter(|&(_, &d)| d == j)
                .map(|(v, _)| v.as_dvec3())
                .collect();
            if pts.len() < MIN_SEGMENT_VERTICES {
                continue;
            }
            let mu = pts.iter().copied().sum::<DVec3>() / pts.len() as f64;
            let mut cov = DMat3::ZERO;
            for p in &pts {
                let d = *p - mu;
                cov += DMat3::from_cols(d * d.x, d * d.y, d * d.z);
            }
            let shape = cov * (3.0 * ELLIPSOID_SHRINK * ELLIPSOID_SHRINK / pts.len() as f64);
            if shape.determinant().abs() < 1e-18 {
                continue;
            }
            // The largest semi-axis is at most sqrt(trace(shape)).
            let radius = (shape.x_axis.x + shape.y_axis.y + shape.z_axis.z).sqrt();
            ellipsoids.push(Ellipsoid {
                joint: j,
                centre: mu,
                q: shape.inverse(),
                radius,
                joint_rest: template.rig.joints[j].rest(),
            });
        }
        let parent = |j: usize| template.rig.joints[j].parent;
        let adjacent = |a: usize, b: usize| a == b || parent(a) == Some(b) || parent(b) == Some(a);
        let step = stride.max(1);
        let mut tests = Vec::new();
        // Vertices grouped by their dominant joint, so that a whole segment can be skipped
        // against a far ellipsoid (see `evaluate`).
        let mut order: Vec<usize> = (0..template.num_vertices()).step_by(step).collect();
        order.sort_by_key(|&v| (dominant[v], v));
        for v in order {
            let x = template.vertices[v].as_dvec3();
            let list: Vec<u16> = ellipsoids
                .iter()
                .enumerate()
                .filter(|(_, e)| !adjacent(e.joint, dominant[v]))
                .filter(|(_, e)| {
                    let d = x - e.centre;
                    d.dot(e.q * d) >= 1.0
                })
                .map(|(i, _)| i as u16)
                .collect();
            tests.push((v as u32, list));
        }
        let count = tests.len().max(1);
        let mut segments: Vec<(usize, usize)> = Vec::new();
        let mut k = 0;
        while k < tests.len() {
            let d = dominant[tests[k].0 as usize];
            let start = k;
            while k < tests.len() && dominant[tests[k].0 as usize] == d {
                k += 1;
            }
            segments.push((start, k));
        }
        Self {
            ellipsoids,
            tests,
            segments,
            count,
        }
    }

    /// EP at the posed vertices (`posed`, indexed like the template, or skinned here when `None`),
    /// accumulating its gradient (times the given scale) into the adjoint when given.
    pub fn evaluate(
        &self,
        kin: &Kinematics,
        skin: &SkinTable,
        posed: Option<&[DVec3]>,
        adjoint: Option<(&mut Adjoint, f64)>,
    ) -> f64 {
        // One instance per kind of rest geometry, so the rigid template's loop is exactly the
        // plain table lookup it always was.
        if kin.morph.is_none() {
            self.evaluate_with(kin, skin, posed, adjoint, |v| skin.rest[v])
        } else {
            self.evaluate_with(kin, skin, posed, adjoint, |v| kin.rest(&skin.rest, v))
        }
    }

    fn evaluate_with<R: Fn(usize) -> DVec3>(
        &self,
        kin: &Kinematics,
        skin: &SkinTable,
        posed: Option<&[DVec3]>,
        mut adjoint: Option<(&mut Adjoint, f64)>,
        rest: R,
    ) -> f64 {
        let posed_ell = self.posed_ellipsoids(kin);
        let mut sum = 0.0;
        let mut points: Vec<DVec3> = Vec::new();
        let mut near = vec![false; self.ellipsoids.len()];
        for &(first, last) in &self.segments {
            // Broad phase: the segment's posed vertices' bounding sphere against each
            // ellipsoid's bounding sphere.
            points.clear();
            points.extend(self.tests[first..last].iter().map(|(v, _)| {
                let v = *v as usize;
                match posed {
                    Some(all) => all[v],
                    None => kin.skin(skin.weights(v), rest(v)),
                }
            }));
            let centre = points.iter().copied().sum::<DVec3>() / points.len().max(1) as f64;
            let reach = points
                .iter()
                .map(|p| p.distance_squared(centre))
                .fold(0.0, f64::max)
                .sqrt();
            let mut any = false;
            for (i, e) in self.ellipsoids.iter().enumerate() {
                near[i] = posed_ell[i].0.distance(centre) < reach + e.radius;
                any |= near[i];
            }
            if !any {
                continue;
            }
            for ((v, list), &p) in self.tests[first..last].iter().zip(&points) {
                let v = *v as usize;
                for &i in list {
                    if !near[i as usize] {
                        continue;
                    }
                    let e = &self.ellipsoids[i as usize];
                    let (c, q) = posed_ell[i as usize];
                    let d = p - c;
                    if d.length_squared() >= e.radius * e.radius {
                        continue;
                    }
                    let qd = q * d;
                    let s = d.dot(qd);
                    if s >= 1.0 {
                        continue;
                    }
                    sum += (1.0 - s) * (1.0 - s);
                    if let Some((adj, scale)) = adjoint.as_mut() {
                        // dρ/ds = −2(1 − s); ds/dp = 2 Q d; the ellipsoid's own motion enters as a
                        // point force at its centre and the torque h × d (see kinematics.rs).
                        let h = qd * (-4.0 * (1.0 - s) * *scale / self.count as f64);
                        adj.skinned_point(kin, skin.weights(v), v, rest(v), h);
                        adj.joint_point(kin, e.joint, c, -h);
                        adj.torque(e.joint, h.cross(d));
                    }
                }
            }
        }
        sum / self.count as f64
    }
}

impl Penetration {
    /// The posed ellipsoids: centre `A_j(μ)` and matrix `W_j Q W_jᵀ`. On a morphable model the
    /// ellipsoid moves with its joint's rest position.
    fn posed_ellipsoids(&self, kin: &Kinematics) -> Vec<(DVec3, DMat3)> {
        self.ellipsoids
            .iter()
            .map(|e| {
                let w = kin.world(e.joint);
                let centre = if kin.morph.is_none() {
                    e.centre
                } else {
                    e.centre + (kin.rest_joints[e.joint] - e.joint_rest)
                };
                (
                    kin.transforms[e.joint].transform_point3(centre),
                    w * e.q * w.transpose(),
                )
            })
            .collect()
    }

    /// EP in least-squares form: per tested vertex, `scale · ‖((1 − q_e)₊)_e‖` over the ellipsoids
    /// it is tested against (`residuals`, one per test) and, with `jacobians`, its Jacobian row
    /// (`jacobian`, tests × dim). `scale² Σ r²` is EP's sum, so `scale = √(λ_P / N)`.
    pub fn residuals(
        &self,
        kin: &Kinematics,
        skin: &SkinTable,
        mut jacobians: Option<&mut PointJacobians<'_>>,
        scale: f64,
        residuals: &mut [f64],
        jacobian: &mut [f64],
    ) {
        let posed_ell = self.posed_ellipsoids(kin);
        let mut active: Vec<(usize, f64, DVec3, DVec3)> = Vec::new();
        let dim = jacobians.as_ref().map_or(0, |j| j.dim);
        let (mut jp, mut jc) = (vec![0.0; 3 * dim], vec![0.0; 3 * dim]);
        for (t, (v, list)) in self.tests.iter().enumerate() {
            let v = *v as usize;
            let p = kin.skin(skin.weights(v), kin.rest(&skin.rest, v));
            active.clear();
            for &i in list {
                let e = &self.ellipsoids[i as usize];
                let (c, q) = posed_ell[i as usize];
                let d = p - c;
                if d.length_squared() >= e.radius * e.radius {
                    continue;
                }
                let qd = q * d;
                let s = d.dot(qd);
                if s < 1.0 {
                    active.push((i as usize, 1.0 - s, qd, d));
                }
            }
            let r = active.iter().map(|a| a.1 * a.1).sum::<f64>().sqrt();
            residuals[t] = scale * r;
            let Some(pj) = jacobians.as_mut() else {
                continue;
            };
            if r == 0.0 {
                continue;
            }
            pj.skinned_point(v, &mut jp);
            let row = &mut jacobian[t * dim..(t + 1) * dim];
            for &(i, a, qd, d) in &active {
                // ∂q = 2 (Q d)ᵀ (∂p − ∂c) + 2 (Q d × d)ᵀ ω; ∂r = −Σ a ∂q / r.
                let e = &self.ellipsoids[i];
                pj.joint_point(e.joint, posed_ell[i].0, &mut jc);
                let f = -2.0 * scale * a / r;
                for (k, o) in row.iter_mut().enumerate() {
                    *o += f
                        * (qd.x * (jp[k] - jc[k])
                            + qd.y * (jp[dim + k] - jc[dim + k])
                            + qd.z * (jp[2 * dim + k] - jc[2 * dim + k]));
                }
                let torque = qd.cross(d);
                for (col, omega) in pj.rotation(e.joint) {
                    row[col] += f * torque.dot(omega);
                }
            }
        }
    }
}

/// EA of papers/000 eq. (7) over every joint except the root (whose rotation is the body's
/// global orientation, not an inter-joint angle), with the per-axis limits of the `global`
/// bounds (papers/000 Table 1, [`crate::skeleton::rotation_limits_deg`]).
#[derive(Debug, Clone)]
pub(crate) struct AngleLimits {
    pub(crate) lower: Vec<f64>,
    pub(crate) upper: Vec<f64>,
}

impl AngleLimits {
    /// The rotation limits of the template's `global` box ([`Bounds::global_for`]: the model's
    /// per-joint limits, papers/000 Table 1 on the default skeleton), over the pose entries.
    pub fn new(template: &Template) -> Self {
        let pose_dim = 3 + 3 * template.rig.num_joints();
        let mut b = Bounds::global_for(template);
        b.lower.truncate(pose_dim);
        b.upper.truncate(pose_dim);
        Self {
            lower: b.lower,
            upper: b.upper,
        }
    }

    /// Value and, for [`AnglePrior::Hinge`], gradient (times `scale`) added into `grad`.
    pub fn evaluate(&self, pose: &[f64], form: AnglePrior, grad: Option<(&mut [f64], f64)>) -> f64 {
        let end = self.lower.len();
        let joints = (end - 3) / 3;
        match form {
            AnglePrior::Binary => (1..joints)
                .filter(|&j| {
                    (0..3).any(|a| {
                        let i = rot_offset(j) + a;
                        pose[i] < self.lower[i] || pose[i] > self.upper[i]
                    })
                })
                .count() as f64,
            AnglePrior::Hinge => {
                let mut sum = 0.0;
                let mut g = grad;
                for i in rot_offset(1)..end {
                    let over =
                        (pose[i] - self.upper[i]).max(0.0) - (self.lower[i] - pose[i]).max(0.0);
                    sum += over * over;
                    if let Some((gr, scale)) = g.as_mut() {
                        gr[i] += 2.0 * over * *scale;
                    }
                }
                sum
            }
        }
    }
}
