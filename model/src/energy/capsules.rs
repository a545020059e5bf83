//! EP on capsules: the self-penetration prior of papers/000 eq. (8) with every segment's ellipsoid
//! replaced by the capsule along its long axis, tested capsule against capsule instead of vertex
//! against ellipsoid (issue 26: the vertex form shapes and skins hundreds of vertices per
//! evaluation, the capsule form reads only the posed skeleton). Capsule approximations of the body
//! for interpenetration are SMPLify's (Bogo et al. 2016, §3.3), whose penalty is a sum over pairs
//! of capsules; here the penalty per pair keeps eq. (8)'s form `(1 − q)²₊`.
//!
//! For segments `a` and `b` with closest points `p_a`, `p_b` on their axes and radii `r_a`, `r_b`,
//! `q = ‖p_a − p_b‖² / (r_a + r_b)²` (< 1 when the capsules overlap) and
//! `EP = κ Σ_pairs (1 − q)²₊`, C¹ like the vertex form. Pairs of the same or adjacent segments
//! and pairs that overlap in the rest pose are not tested (as the vertex form skips a vertex
//! inside an ellipsoid at rest). `κ` puts EP on the vertex form's scale, so that `λ_P` keeps its
//! meaning: it is the ratio of the two forms' sums over poses sampled uniformly within the model's
//! joint limits (fixed seed, computed once per template).
//!
//! The closest points move with their segments' joints: by the envelope theorem the derivative of
//! `‖p_a − p_b‖²` holds the closest-point parameters fixed, so each closest point is a point
//! carried rigidly by its joint ([`PointJacobians::joint_point`], [`Adjoint::joint_point`]).

use glam::DVec3;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use super::prior::Penetration;
use crate::body::jacobian::PointJacobians;
use crate::body::kinematics::{Adjoint, Kinematics, SkinTable};
use crate::pose::{Bounds, rot_offset};
use crate::template::Template;

/// Poses sampled within the joint limits for the scale `κ`.
const CALIBRATION_POSES: usize = 64;
/// The seed of those poses.
const CALIBRATION_SEED: u64 = 0x0e9c_a95e;

/// One segment's capsule in the rest pose: the axis from `ends[0]` to `ends[1]`, as offsets from
/// the joint's rest centre (so that on a morphable model it moves with the joint), and a radius.
#[derive(Debug, Clone)]
struct Capsule {
    joint: usize,
    ends: [DVec3; 2],
    radius: f64,
    /// The axis midpoint (an offset like `ends`) and half the axis length: the capsule's
    /// bounding ball, which a rigid joint transform moves without changing its size.
    mid: DVec3,
    half_length: f64,
}

/// The capsules of a template's segments and the pairs EP tests.
#[derive(Debug, Clone)]
pub(crate) struct Capsules {
    capsules: Vec<Capsule>,
    /// Indices into `capsules` (`a < b`); the pair's term is in capsule `a`'s residual row.
    pub(crate) pairs: Vec<(u16, u16)>,
    /// Per pair: the squared distance of the two bounding balls' centres from which the pair
    /// cannot touch, `(h_a + h_b + r_a + r_b)²`, and `1 / (r_a + r_b)²`.
    reach: Vec<(f64, f64)>,
    /// `κ`: EP = κ Σ (1 − q)²₊.
    pub(crate) scale: f64,
}

/// A pair's closest points (world), `q`, and the pair's capsules.
struct Contact {
    a: usize,
    b: usize,
    pa: DVec3,
    pb: DVec3,
    /// `1 − q` (> 0).
    depth: f64,
    /// `1 / (r_a + r_b)²`.
    inv_r2: f64,
}

impl Capsules {
    /// The capsules of `penetration`'s ellipsoids (the long semi-axis `a₁` becomes the capsule's
    /// half extent, the mean of the other two its radius `r`, so the axis runs `a₁ − r` either
    /// side of the centre) and `κ` against `penetration` itself.
    pub fn new(template: &Template, penetration: &Penetration) -> Self {
        let capsules: Vec<Capsule> = penetration
            .ellipsoids
            .iter()
            .map(|e| {
                // The ellipsoid is {d : dᵀ Q d < 1}: semi-axes 1/√λ of Q's eigenvalues.
                let q = nalgebra::Matrix3::from_fn(|r, c| e.q.col(c)[r]);
                let eig = q.symmetric_eigen();
                let mut axes: Vec<(f64, DVec3)> = (0..3)
                    .map(|k| {
                        let v = eig.eigenvectors.column(k);
                        (
                            1.0 / eig.eigenvalues[k].max(1e-300).sqrt(),
                            DVec3::new(v[0], v[1], v[2]),
                        )
                    })
                    .collect();
                axes.sort_by(|x, y| y.0.total_cmp(&x.0));
                let radius = 0.5 * (axes[1].0 + axes[2].0);
                let half = (axes[0].0 - radius).max(0.0) * axes[0].1;
                let offset = e.centre - e.joint_rest;
                let ends = [offset + half, offset - half];
                Capsule {
                    joint: e.joint,
                    ends,
                    radius,
                    mid: 0.5 * (ends[0] + ends[1]),
                    half_length: 0.5 * (ends[1] - ends[0]).length(),
                }
            })
            .collect();
        let parent = |j: usize| template.rig.joints[j].parent;
        let adjacent = |a: usize, b: usize| a == b || parent(a) == Some(b) || parent(b) == Some(a);
        let rest_joints: Vec<DVec3> = template.rig.joints.iter().map(|j| j.rest()).collect();
        let mut pairs = Vec::new();
        for a in 0..capsules.len() {
            for b in a + 1..capsules.len() {
                let (ca, cb) = (&capsules[a], &capsules[b]);
                if adjacent(ca.joint, cb.joint) {
                    continue;
                }
                let ends = |c: &Capsule| c.ends.map(|o| rest_joints[c.joint] + o);
                let (pa, pb) = closest_points(ends(ca), ends(cb));
                let r = ca.radius + cb.radius;
                if pa.distance_squared(pb) >= r * r {
                    pairs.push((a as u16, b as u16));
                }
            }
        }
        let reach = pairs
            .iter()
            .map(|&(a, b)| {
                let (ca, cb) = (&capsules[a as usize], &capsules[b as usize]);
                let r = ca.radius + cb.radius;
                let reach = ca.half_length + cb.half_length + r;
                (reach * reach, 1.0 / (r * r))
            })
            .collect();
        let mut out = Self {
            capsules,
            pairs,
            reach,
            scale: 1.0,
        };
        out.scale = out.calibrate(template, penetration);
        out
    }

    /// `κ`: the vertex form's EP summed over poses sampled within the joint limits, over this
    /// form's unscaled sum (`1 / pairs` when neither penetrates on any sample).
    fn calibrate(&self, template: &Template, penetration: &Penetration) -> f64 {
        let dim = template.layout().dim();
        let bounds = Bounds::global_for(template);
        let pose_end = 3 + 3 * template.rig.num_joints();
        let skin = SkinTable::new(template);
        let mut rng = ChaCha8Rng::seed_from_u64(CALIBRATION_SEED);
        let (mut vertices, mut capsules) = (0.0, 0.0);
        for _ in 0..CALIBRATION_POSES {
            let mut pose = vec![0.0; dim];
            for i in rot_offset(1)..pose_end.min(bounds.lower.len()) {
                let (lo, hi) = (bounds.lower[i], bounds.upper[i]);
                if lo < hi {
                    pose[i] = rng.random_range(lo..hi);
                }
            }
            let kin = Kinematics::build(template, &pose, false);
            vertices += penetration.evaluate(&kin, &skin, None, None);
            capsules += self
                .contacts(&kin)
                .iter()
                .map(|c| c.depth * c.depth)
                .sum::<f64>();
        }
        if capsules > 0.0 && vertices > 0.0 {
            vertices / capsules
        } else {
            1.0 / self.pairs.len().max(1) as f64
        }
    }

    /// The overlapping pairs. The bounding balls (each capsule's posed axis midpoint, and the
    /// pair's reach precomputed: the joint transforms are rigid) rule out most pairs; the axis
    /// ends are posed only for the capsules of the pairs left.
    fn contacts(&self, kin: &Kinematics) -> Vec<Contact> {
        let place = |c: &Capsule, o: DVec3| {
            kin.transforms[c.joint].transform_point3(kin.rest_joints[c.joint] + o)
        };
        let mids: Vec<DVec3> = self.capsules.iter().map(|c| place(c, c.mid)).collect();
        let mut posed: Vec<Option<[DVec3; 2]>> = vec![None; self.capsules.len()];
        let mut ends = |k: usize| {
            *posed[k].get_or_insert_with(|| {
                let c = &self.capsules[k];
                c.ends.map(|o| place(c, o))
            })
        };
        let mut out = Vec::new();
        for (&(a, b), &(reach2, inv_r2)) in self.pairs.iter().zip(&self.reach) {
            let (a, b) = (a as usize, b as usize);
            if mids[a].distance_squared(mids[b]) >= reach2 {
                continue;
            }
            let (pa, pb) = closest_points(ends(a), ends(b));
            let q = pa.distance_squared(pb) * inv_r2;
            if q < 1.0 {
                out.push(Contact {
                    a,
                    b,
                    pa,
                    pb,
                    depth: 1.0 - q,
                    inv_r2,
                });
            }
        }
        out
    }

    /// Every pair's contact, without the bounding balls (for tests of [`Capsules::contacts`]):
    /// `(a, b, p_a, p_b, 1 − q)` of the pairs that overlap.
    #[cfg(test)]
    pub(super) fn contacts_of_every_pair(
        &self,
        kin: &Kinematics,
    ) -> Vec<(usize, usize, DVec3, DVec3, f64)> {
        let ends = |c: &Capsule| {
            let t = &kin.transforms[c.joint];
            c.ends
                .map(|o| t.transform_point3(kin.rest_joints[c.joint] + o))
        };
        let mut out = Vec::new();
        for &(a, b) in &self.pairs {
            let (a, b) = (a as usize, b as usize);
            let (ca, cb) = (&self.capsules[a], &self.capsules[b]);
            let r = ca.radius + cb.radius;
            let (pa, pb) = closest_points(ends(ca), ends(cb));
            let q = pa.distance_squared(pb) * (1.0 / (r * r));
            if q < 1.0 {
                out.push((a, b, pa, pb, 1.0 - q));
            }
        }
        out
    }

    /// [`Capsules::contacts`] as tuples, for tests.
    #[cfg(test)]
    pub(super) fn contacts_found(
        &self,
        kin: &Kinematics,
    ) -> Vec<(usize, usize, DVec3, DVec3, f64)> {
        self.contacts(kin)
            .into_iter()
            .map(|c| (c.a, c.b, c.pa, c.pb, c.depth))
            .collect()
    }

    /// EP, accumulating its gradient (times the given scale) into the adjoint when given.
    pub fn evaluate(&self, kin: &Kinematics, adjoint: Option<(&mut Adjoint, f64)>) -> f64 {
        let contacts = self.contacts(kin);
        if let Some((adj, scale)) = adjoint {
            for c in &contacts {
                // ∂(1 − q)²/∂p_a = −2 (1 − q) · 2 (p_a − p_b) / R²; the opposite for p_b.
                let g = (c.pa - c.pb) * (-4.0 * c.depth * c.inv_r2 * self.scale * scale);
                adj.joint_point(kin, self.capsules[c.a].joint, c.pa, g);
                adj.joint_point(kin, self.capsules[c.b].joint, c.pb, -g);
            }
        }
        self.scale * contacts.iter().map(|c| c.depth * c.depth).sum::<f64>()
    }

    /// Rows of EP's least-squares form: one per capsule.
    pub(crate) fn rows(&self) -> usize {
        self.capsules.len()
    }

    /// EP in least-squares form: per capsule `a`, `c0 ‖((1 − q_ab)₊)_b‖` over the pairs `(a, b)`
    /// it opens (`b > a`), with `c0 = √(λ_P κ)` (so `Σ r²` is `λ_P EP`; one row per capsule, not
    /// per pair, as the vertex form keeps one row per vertex: 31 rows on the MakeHuman body, not
    /// 433), into `residuals` (one per capsule, all written) and, with `jacobians`, its row of
    /// `jacobian` (capsules × dim, zero as given; only rows with an overlap are written).
    pub fn residuals(
        &self,
        kin: &Kinematics,
        jacobians: Option<&mut PointJacobians<'_>>,
        c0: f64,
        residuals: &mut [f64],
        jacobian: &mut [f64],
    ) {
        residuals.fill(0.0);
        let contacts = self.contacts(kin);
        for c in &contacts {
            residuals[c.a] += c.depth * c.depth;
        }
        for r in residuals.iter_mut() {
            *r = c0 * r.sqrt();
        }
        let Some(pj) = jacobians else {
            return;
        };
        let dim = pj.dim;
        let (mut ja, mut jb) = (vec![0.0; 3 * dim], vec![0.0; 3 * dim]);
        for c in &contacts {
            pj.joint_point(self.capsules[c.a].joint, c.pa, &mut ja);
            pj.joint_point(self.capsules[c.b].joint, c.pb, &mut jb);
            // r_a = c0 √(Σ_b s_b²), s_b = 1 − q_ab: ∂r_a = c0² Σ_b s_b ∂s_b / r_a, and
            // ∂s_b = −∂q = −2 (p_a − p_b)ᵀ (∂p_a − ∂p_b) / R².
            let d = (c.pa - c.pb) * (-2.0 * c0 * c0 * c.depth * c.inv_r2 / residuals[c.a]);
            let out = &mut jacobian[c.a * dim..(c.a + 1) * dim];
            for (k, o) in out.iter_mut().enumerate() {
                *o += d.x * (ja[k] - jb[k])
                    + d.y * (ja[dim + k] - jb[dim + k])
                    + d.z * (ja[2 * dim + k] - jb[2 * dim + k]);
            }
        }
    }
}

/// The closest points of segments `s` and `t` (Ericson, *Real-Time Collision Detection*, 2005,
/// §5.1.9): `s(σ) = s₀ + σ (s₁ − s₀)`, `t(τ)` likewise, σ, τ ∈ [0, 1].
pub(crate) fn closest_points(s: [DVec3; 2], t: [DVec3; 2]) -> (DVec3, DVec3) {
    const EPS: f64 = 1e-18;
    let (d1, d2, r) = (s[1] - s[0], t[1] - t[0], s[0] - t[0]);
    let (a, e, f) = (d1.length_squared(), d2.length_squared(), d2.dot(r));
    let (sigma, tau) = if a <= EPS && e <= EPS {
        (0.0, 0.0)
    } else if a <= EPS {
        (0.0, (f / e).clamp(0.0, 1.0))
    } else {
        let c = d1.dot(r);
        if e <= EPS {
            ((-c / a).clamp(0.0, 1.0), 0.0)
        } else {
            let b = d1.dot(d2);
            let denom = a * e - b * b;
            let sigma = if denom > EPS * a * e {
                ((b * f - c * e) / denom).clamp(0.0, 1.0)
            } else {
                0.0
            };
            let tau = (b * sigma + f) / e;
            if tau < 0.0 {
                ((-c / a).clamp(0.0, 1.0), 0.0)
            } else if tau > 1.0 {
                (((b - c) / a).clamp(0.0, 1.0), 1.0)
            } else {
                (sigma, tau)
            }
        }
    };
    (s[0] + sigma * d1, t[0] + tau * d2)
}
