//! The prior terms of papers/000 eq. (3): EP (ellipsoid self-penetration, eq. 8) and EA
//! (joint-angle prior, eq. 7).

use glam::{DMat3, DVec3};
use serde::{Deserialize, Serialize};

use crate::body::jacobian::PointJacobians;
use crate::body::kinematics::{Adjoint, Kinematics, SkinTable};
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
///
/// **Broad phase** (issue 26): the tested vertices are grouped into small spatial clusters
/// ([`Cluster`]); a cluster whose bounding ball — bounded from the posed skeleton alone, without
/// shaping or skinning a vertex — cannot reach into any of its ellipsoids is skipped. The bound
/// is conservative, so EP, its gradient and its Jacobian are those of testing every vertex: only
/// clusters that contribute nothing are left out.
#[derive(Debug, Clone)]
pub(crate) struct Penetration {
    pub(crate) ellipsoids: Vec<Ellipsoid>,
    /// `√λ_max` of every ellipsoid's matrix: the Lipschitz constant of its ellipsoidal radius
    /// `‖Q^½ d‖` (one over its smallest semi-axis).
    stiffness: Vec<f64>,
    /// Tested vertices and, per vertex, the ellipsoids (indices into `ellipsoids`) it is tested
    /// against; ordered by cluster.
    pub(crate) tests: Vec<(u32, Vec<u16>)>,
    clusters: Vec<Cluster>,
    segments: Vec<Segment>,
    pub(crate) count: usize,
}

/// What the broad phase keeps: per cluster a range of `flat`, the ellipsoids it may reach.
struct Near {
    flat: Vec<u16>,
    ranges: Vec<(u32, u32)>,
}

impl Near {
    fn of(&self, cluster: usize) -> &[u16] {
        let (a, b) = self.ranges[cluster];
        &self.flat[a as usize..b as usize]
    }
}

/// All tested vertices of one segment as one ball (tested first), and its clusters.
#[derive(Debug, Clone)]
struct Segment {
    bound: Cluster,
    clusters: std::ops::Range<usize>,
}

/// Fewest tested vertices per broad-phase cluster before it is no longer split.
const CLUSTER_SIZE: usize = 8;

/// A few tested vertices of one segment (dominant joint `joint`), contiguous in `tests`, with
/// what bounds where they can be without shaping or skinning them.
///
/// Every vertex `v` of the cluster has its β = ψ = 0 rest position within `radius` of `centre`;
/// under coefficients `c` and pose feature `f` its rest position lies within
/// `radius + shape_norm · ‖c‖ + pose_norm · ‖f‖` of the shaped centre `centre + S̄ c`
/// (Frobenius norms of its blend-shape rows minus their mean, and of its corrective rows). Skinned, `p_v = Σ_k w_k A_k x_v` with weights ≥ 0 summing to 1, so
/// `|p_v − A_j b| ≤ ρ + max_k (‖W_k − W_j‖ ρ + |A_k b − A_j b|)` over the joints `k` that
/// influence the cluster (`ρ` the shaped radius, `b` the centre).
#[derive(Debug, Clone)]
struct Cluster {
    joint: usize,
    range: (usize, usize),
    centre: DVec3,
    radius: f64,
    /// The mean blend-shape rows of the cluster's vertices, `3 × (B + E)` row-major: the
    /// shaped centre is `centre + S̄ c`.
    shape_mean: Vec<f64>,
    /// `max_v ‖S_v − S̄‖_F`: how far a shaped vertex strays from the shaped centre, per unit `‖c‖`.
    shape_norm: f64,
    pose_norm: f64,
    /// Joints other than `joint` with a skinning weight on a vertex of the cluster.
    influences: Vec<u16>,
    /// A cluster's `influences` as positions in its segment's (empty for a segment).
    slots: Vec<u16>,
    /// The union of the cluster's vertices' ellipsoid lists.
    ellipsoids: Vec<u16>,
    /// Whether the bound holds: every weight of the cluster's vertices ≥ 0 and each vertex's
    /// weights sum to 1 (else the cluster is always tested).
    bounded: bool,
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
        let morph = &template.morph;
        let base = |v: usize| {
            if morph.rest.is_empty() {
                template.vertices[v].as_dvec3()
            } else {
                morph.rest[v]
            }
        };
        // Vertices grouped by their dominant joint, then split into small spatial clusters.
        let mut by_joint: Vec<Vec<usize>> = vec![Vec::new(); nj];
        for v in (0..template.num_vertices()).step_by(step) {
            by_joint[dominant[v]].push(v);
        }
        let mut tests = Vec::new();
        let mut clusters = Vec::new();
        let mut segments = Vec::new();
        for (j, vertices) in by_joint.iter_mut().enumerate() {
            let mut groups = Vec::new();
            split(vertices, &base, &mut groups);
            let (segment_first, cluster_first) = (tests.len(), clusters.len());
            for group in groups {
                let first = tests.len();
                for &v in &group {
                    let x = base(v);
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
                clusters.push(Cluster::bound(
                    template,
                    j,
                    &tests,
                    (first, tests.len()),
                    &base,
                ));
            }
            if tests.len() > segment_first {
                let bound =
                    Cluster::bound(template, j, &tests, (segment_first, tests.len()), &base);
                for cl in &mut clusters[cluster_first..] {
                    cl.slots = cl
                        .influences
                        .iter()
                        .map(|k| bound.influences.binary_search(k).unwrap_or(0) as u16)
                        .collect();
                }
                segments.push(Segment {
                    bound,
                    clusters: cluster_first..clusters.len(),
                });
            }
        }
        let count = tests.len().max(1);
        let stiffness = ellipsoids
            .iter()
            .map(|e| {
                let q = nalgebra::Matrix3::from_fn(|r, c| e.q.col(c)[r]);
                let top = q.symmetric_eigenvalues().max();
                top.max(0.0).sqrt()
            })
            .collect();
        Self {
            ellipsoids,
            stiffness,
            tests,
            clusters,
            segments,
            count,
        }
    }

    /// The shaped centre of `cl` and its radius under the coefficients and pose feature.
    fn shaped(cl: &Cluster, shape: (&[f64], f64, f64)) -> (DVec3, f64) {
        let (coeffs, coeff_norm, feature_norm) = shape;
        let rho = cl.radius + cl.shape_norm * coeff_norm + cl.pose_norm * feature_norm;
        let mut centre = cl.centre;
        if !coeffs.is_empty() && !cl.shape_mean.is_empty() {
            let k = coeffs.len();
            for axis in 0..3 {
                centre[axis] += cl.shape_mean[axis * k..(axis + 1) * k]
                    .iter()
                    .zip(coeffs)
                    .map(|(m, c)| m * c)
                    .sum::<f64>();
            }
        }
        (centre, rho)
    }

    /// The narrow phase: a posed point `p` against posed ellipsoid `i`. `Some((1 − q, Q d, d))`
    /// when it is inside (`q = dᵀ Q d < 1`, `d = p − c`), `None` outside.
    #[inline]
    fn depth(
        &self,
        p: DVec3,
        i: usize,
        posed_ell: &[(DVec3, DMat3)],
    ) -> Option<(f64, DVec3, DVec3)> {
        let e = &self.ellipsoids[i];
        let (c, q) = posed_ell[i];
        let d = p - c;
        if d.length_squared() >= e.radius * e.radius {
            return None;
        }
        let qd = q * d;
        let s = d.dot(qd);
        (s < 1.0).then_some((1.0 - s, qd, d))
    }

    /// Where the vertices of segment `bound` can be: the posed centre of their ball, its radius,
    /// and per influence `k` of the segment `(‖W_k − W_j‖_F, |A_k b − A_j b|)` at the segment's
    /// shaped centre `b` (what its clusters' bounds reuse).
    fn segment_reach(
        &self,
        bound: &Cluster,
        kin: &Kinematics,
        shape: (&[f64], f64, f64),
        terms: &mut Vec<(f64, f64)>,
    ) -> (DVec3, DVec3, f64) {
        let (centre, rho) = Self::shaped(bound, shape);
        let a = &kin.transforms[bound.joint];
        let at = a.transform_point3(centre);
        terms.clear();
        let mut spread = 0.0f64;
        for &k in &bound.influences {
            let b = &kin.transforms[k as usize];
            let dw = b.matrix3 - a.matrix3;
            let fro = (dw.x_axis.length_squared()
                + dw.y_axis.length_squared()
                + dw.z_axis.length_squared())
            .sqrt();
            let offset = b.transform_point3(centre).distance(at);
            terms.push((fro, offset));
            spread = spread.max(fro * rho + offset);
        }
        // A margin for rounding: the bound is exact in real arithmetic.
        (centre, at, (rho + spread) * (1.0 + 1e-9) + 1e-9)
    }

    /// Where the vertices of cluster `cl` can be, from its segment's terms (segment shaped centre
    /// `b_s`): `|A_k b − A_j b| ≤ |A_k b_s − A_j b_s| + ‖W_k − W_j‖ |b − b_s|`.
    fn cluster_reach(
        cl: &Cluster,
        kin: &Kinematics,
        shape: (&[f64], f64, f64),
        segment_centre: DVec3,
        terms: &[(f64, f64)],
    ) -> (DVec3, f64) {
        let (centre, rho) = Self::shaped(cl, shape);
        let at = kin.transforms[cl.joint].transform_point3(centre);
        let lever = rho + centre.distance(segment_centre);
        let spread = cl
            .slots
            .iter()
            .map(|&s| {
                let (fro, offset) = terms[s as usize];
                fro * lever + offset
            })
            .fold(0.0f64, f64::max);
        (at, (rho + spread) * (1.0 + 1e-9) + 1e-9)
    }

    /// Whether a ball (`at`, `reach`) may reach into the posed ellipsoid `i`.
    #[inline]
    fn may_reach(&self, at: DVec3, reach: f64, i: usize, posed_ell: &[(DVec3, DMat3)]) -> bool {
        let (c, q) = posed_ell[i];
        let d = at - c;
        let outer = reach + self.ellipsoids[i].radius;
        if d.length_squared() >= outer * outer {
            return false;
        }
        // ‖Q^½ d‖ is Lipschitz with constant √λ_max(Q): no point of the ball is inside when
        // the centre's ellipsoidal radius minus that reach is ≥ 1.
        let inner = 1.0 + reach * self.stiffness[i];
        d.dot(q * d) < inner * inner
    }

    /// The broad phase, from the posed skeleton alone: for every cluster the ellipsoids it may
    /// reach into, as ranges of one flat list (an empty range: the cluster is skipped). Segments
    /// first, then the clusters of the segments that reach anything.
    fn broad_phase(&self, kin: &Kinematics, posed_ell: &[(DVec3, DMat3)]) -> Near {
        let empty: &[f64] = &[];
        let shape = match &kin.morph {
            None => (empty, 0.0, 0.0),
            Some((_, c, f)) => (
                c.as_slice(),
                c.iter().map(|x| x * x).sum::<f64>().sqrt(),
                f.iter().map(|x| x * x).sum::<f64>().sqrt(),
            ),
        };
        let mut near = Near {
            flat: Vec::with_capacity(4 * self.clusters.len()),
            ranges: vec![(0, 0); self.clusters.len()],
        };
        let mut flags = vec![false; self.ellipsoids.len()];
        let mut terms = Vec::new();
        for segment in &self.segments {
            let bound = &segment.bound;
            flags.fill(false);
            let mut any = false;
            let (segment_centre, at, reach) = self.segment_reach(bound, kin, shape, &mut terms);
            if bound.bounded {
                for &i in &bound.ellipsoids {
                    let hit = self.may_reach(at, reach, i as usize, posed_ell);
                    flags[i as usize] = hit;
                    any |= hit;
                }
            } else {
                for &i in &bound.ellipsoids {
                    flags[i as usize] = true;
                }
                any = !bound.ellipsoids.is_empty();
            }
            if !any {
                continue;
            }
            for c in segment.clusters.clone() {
                let cl = &self.clusters[c];
                let start = near.flat.len();
                if bound.bounded {
                    let (at, reach) = Self::cluster_reach(cl, kin, shape, segment_centre, &terms);
                    for &i in &cl.ellipsoids {
                        if flags[i as usize] && self.may_reach(at, reach, i as usize, posed_ell) {
                            near.flat.push(i);
                        }
                    }
                } else {
                    near.flat
                        .extend(cl.ellipsoids.iter().filter(|&&i| flags[i as usize]));
                }
                near.ranges[c] = (start as u32, near.flat.len() as u32);
            }
        }
        near
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
        let broad = self.broad_phase(kin, &posed_ell);
        let mut sum = 0.0;
        let mut near = vec![false; self.ellipsoids.len()];
        for (c, cl) in self.clusters.iter().enumerate() {
            let reach = broad.of(c);
            if reach.is_empty() {
                continue;
            }
            near.fill(false);
            for &i in reach {
                near[i as usize] = true;
            }
            for (v, list) in &self.tests[cl.range.0..cl.range.1] {
                let v = *v as usize;
                if !list.iter().any(|&i| near[i as usize]) {
                    continue;
                }
                let p = match posed {
                    Some(all) => all[v],
                    None => kin.skin(skin.weights(v), rest(v)),
                };
                for &i in list {
                    if !near[i as usize] {
                        continue;
                    }
                    let Some((a, qd, d)) = self.depth(p, i as usize, &posed_ell) else {
                        continue;
                    };
                    sum += a * a;
                    if let Some((adj, scale)) = adjoint.as_mut() {
                        // dρ/ds = −2a (a = 1 − s); ds/dp = 2 Q d; the ellipsoid's own motion enters as a
                        // point force at its centre and the torque h × d (see kinematics.rs).
                        let h = qd * (-4.0 * a * *scale / self.count as f64);
                        adj.skinned_point(kin, skin.weights(v), v, rest(v), h);
                        let joint = self.ellipsoids[i as usize].joint;
                        adj.joint_point(kin, joint, posed_ell[i as usize].0, -h);
                        adj.torque(joint, h.cross(d));
                    }
                }
            }
        }
        sum / self.count as f64
    }
}

#[cfg(test)]
impl Penetration {
    /// EP without the broad phase: every tested vertex shaped, skinned and tested against every
    /// ellipsoid of its list (the reference the broad phase must reproduce).
    pub(crate) fn exhaustive(&self, kin: &Kinematics, skin: &SkinTable) -> f64 {
        let posed_ell = self.posed_ellipsoids(kin);
        let mut sum = 0.0;
        for (v, list) in &self.tests {
            let v = *v as usize;
            let p = kin.skin(skin.weights(v), kin.rest(&skin.rest, v));
            for &i in list {
                let (c, q) = posed_ell[i as usize];
                let d = p - c;
                let s = d.dot(q * d);
                if s < 1.0 {
                    sum += (1.0 - s) * (1.0 - s);
                }
            }
        }
        sum / self.count as f64
    }

    /// Tested vertices in the clusters the broad phase keeps, of all tested vertices.
    pub(crate) fn kept(&self, kin: &Kinematics) -> (usize, usize) {
        let posed_ell = self.posed_ellipsoids(kin);
        let near = self.broad_phase(kin, &posed_ell);
        let kept = (0..self.clusters.len())
            .filter(|&c| !near.of(c).is_empty())
            .map(|c| self.clusters[c].range.1 - self.clusters[c].range.0)
            .sum();
        (kept, self.tests.len())
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
        let broad = self.broad_phase(kin, &posed_ell);
        let mut near = vec![false; self.ellipsoids.len()];
        for (c, cl) in self.clusters.iter().enumerate() {
            let reach = broad.of(c);
            if reach.is_empty() {
                // Rows of clusters that reach no ellipsoid stay zero (as the caller gave them).
                residuals[cl.range.0..cl.range.1].fill(0.0);
                continue;
            };
            near.fill(false);
            for &i in reach {
                near[i as usize] = true;
            }
            for t in cl.range.0..cl.range.1 {
                let (v, list) = &self.tests[t];
                let v = *v as usize;
                if !list.iter().any(|&i| near[i as usize]) {
                    residuals[t] = 0.0;
                    continue;
                }
                let p = kin.skin(skin.weights(v), kin.rest(&skin.rest, v));
                active.clear();
                for &i in list {
                    if !near[i as usize] {
                        continue;
                    }
                    if let Some((a, qd, d)) = self.depth(p, i as usize, &posed_ell) {
                        active.push((i as usize, a, qd, d));
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
}

impl Cluster {
    /// The bound of the tests `range` (vertices of dominant joint `joint`; `base` their β = ψ = 0
    /// rest positions).
    fn bound(
        template: &Template,
        joint: usize,
        tests: &[(u32, Vec<u16>)],
        range: (usize, usize),
        base: &impl Fn(usize) -> DVec3,
    ) -> Self {
        let morph = &template.morph;
        let k = morph.coefficients();
        let nj = template.rig.num_joints();
        let group: Vec<usize> = tests[range.0..range.1]
            .iter()
            .map(|t| t.0 as usize)
            .collect();
        let n = group.len() as f64;
        let centre = group.iter().map(|&v| base(v)).sum::<DVec3>() / n;
        let radius = group
            .iter()
            .map(|&v| base(v).distance(centre))
            .fold(0.0, f64::max);
        let mut influences: Vec<u16> = Vec::new();
        let mut bounded = true;
        let mut pose_norm = 0.0f64;
        for &v in &group {
            let weights = &template.rig.weights[v];
            let sum: f64 = weights.iter().map(|w| w.1).sum();
            bounded &= weights.iter().all(|w| w.1 >= 0.0) && (sum - 1.0).abs() < 1e-9;
            influences.extend(
                weights
                    .iter()
                    .filter(|w| w.0 != joint && w.1 != 0.0)
                    .map(|w| w.0 as u16),
            );
            if let Some(pd) = &morph.posedirs {
                let width = 9 * nj.saturating_sub(1);
                let norm = pd[3 * v * width..3 * (v + 1) * width]
                    .iter()
                    .map(|x| x * x)
                    .sum::<f64>()
                    .sqrt();
                pose_norm = pose_norm.max(norm);
            }
        }
        influences.sort_unstable();
        influences.dedup();
        let mut shape_mean = vec![0.0; 3 * k];
        for &v in &group {
            for (m, d) in shape_mean
                .iter_mut()
                .zip(&morph.dirs[3 * v * k..3 * (v + 1) * k])
            {
                *m += d / n;
            }
        }
        let shape_norm = group
            .iter()
            .map(|&v| {
                morph.dirs[3 * v * k..3 * (v + 1) * k]
                    .iter()
                    .zip(&shape_mean)
                    .map(|(d, m)| (d - m) * (d - m))
                    .sum::<f64>()
                    .sqrt()
            })
            .fold(0.0, f64::max);
        let mut ellipsoids: Vec<u16> = tests[range.0..range.1]
            .iter()
            .flat_map(|t| t.1.iter().copied())
            .collect();
        ellipsoids.sort_unstable();
        ellipsoids.dedup();
        Self {
            joint,
            range,
            centre,
            radius,
            shape_mean,
            shape_norm,
            pose_norm,
            influences,
            slots: Vec::new(),
            ellipsoids,
            bounded,
        }
    }
}

/// Splits `vertices` into groups of at most [`CLUSTER_SIZE`] by halving along the longest axis
/// of their rest bounding box (at the median), appending the groups to `out`.
fn split(vertices: &mut [usize], base: &impl Fn(usize) -> DVec3, out: &mut Vec<Vec<usize>>) {
    if vertices.is_empty() {
        return;
    }
    if vertices.len() <= CLUSTER_SIZE {
        out.push(vertices.to_vec());
        return;
    }
    let (mut lo, mut hi) = (DVec3::splat(f64::INFINITY), DVec3::splat(f64::NEG_INFINITY));
    for &v in vertices.iter() {
        lo = lo.min(base(v));
        hi = hi.max(base(v));
    }
    let extent = hi - lo;
    let axis = if extent.x >= extent.y && extent.x >= extent.z {
        0
    } else if extent.y >= extent.z {
        1
    } else {
        2
    };
    vertices.sort_by(|&a, &b| base(a)[axis].total_cmp(&base(b)[axis]).then(a.cmp(&b)));
    let mid = vertices.len() / 2;
    let (left, right) = vertices.split_at_mut(mid);
    split(left, base, out);
    split(right, base, out);
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
