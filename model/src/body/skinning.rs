//! CPU forward kinematics and skinning, exactly as written in SPEC §3:
//!
//! ```text
//! A_root(x) = R_root (x - c_root) + c_root + t
//! A_j(x)    = A_parent(j)(c_j) + W_j (x - c_j)
//! posed joint j:  A_j(c_j)
//! posed vertex v: sum_j w_vj A_j(v)       (linear blend skinning)
//! ```
//! Joint transforms are computed in f64; the vertex loops run in f32 SIMD (`Vec3A`).

use super::rotation::{exp_map, exp_map_and_left_jacobian};
use glam::{Affine3A, DAffine3, DMat3, DQuat, DVec3, Mat3A, Vec3, Vec3A};
use rayon::prelude::*;

use crate::pose::rot_offset;
use crate::template::Template;

/// Skinning method of the CPU path.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum SkinningMethod {
    /// Linear blend skinning (SPEC §3).
    #[default]
    Linear,
    /// Dual-quaternion skinning (Kavan et al.), as papers/000 §3 animates its template.
    DualQuaternion,
}

/// A posed skeleton: the affine maps `A_j` of every joint (world position of a rest-pose point
/// carried by joint j, `x ↦ W_j x + (A_parent(j)(c_j) − W_j c_j)`), the posed joint centres
/// `A_j(c_j)`, and what the rest geometry of a morphable model needs ([`crate::morph`]): the rest
/// joints `c(β, ψ)`, the coefficients `[β; ψ]` and the pose feature `R(θ) − I`.
///
/// Dereferences to the slice of `A_j`.
#[derive(Debug, Clone)]
pub struct Posed {
    pub transforms: Vec<DAffine3>,
    pub joints: Vec<DVec3>,
    pub rest_joints: Vec<DVec3>,
    pub coeffs: Vec<f64>,
    pub pose_feature: Vec<f64>,
}

impl std::ops::Deref for Posed {
    type Target = [DAffine3];
    fn deref(&self) -> &[DAffine3] {
        &self.transforms
    }
}

impl Posed {
    /// Rest position of vertex `v` for this parameter vector (`T(β, ψ) + P (R(θ) − I)`), f64.
    #[inline]
    pub fn rest_vertex(&self, template: &Template, v: usize) -> DVec3 {
        template.morph.rest_vertex(
            v,
            template.vertices[v].as_dvec3(),
            &self.coeffs,
            &self.pose_feature,
        )
    }
}

/// Forward kinematics of SPEC §3/§3a for a parameter vector `params` laid out as
/// [`Template::layout`]: translation, rotations, then β and ψ (missing trailing coefficients
/// count as zero; the callers that read user input check lengths).
pub fn joint_transforms(template: &Template, params: &[f64]) -> Posed {
    joint_transforms_with(template, params, None)
}

/// [`joint_transforms`], pushing each joint's left Jacobian `Jl(r_j)` onto `left_jacobians` when
/// given (from the same sine and cosine as its rotation: [`exp_map_and_left_jacobian`]).
pub(crate) fn joint_transforms_with(
    template: &Template,
    params: &[f64],
    mut left_jacobians: Option<&mut Vec<DMat3>>,
) -> Posed {
    let rig = &template.rig;
    let nj = rig.joints.len();
    let morph = &template.morph;
    let k = morph.coefficients();
    let mut coeffs = Vec::new();
    if k > 0 {
        coeffs = params
            .get(3 + 3 * nj..)
            .unwrap_or(&[])
            .iter()
            .copied()
            .take(k)
            .collect();
        coeffs.resize(k, 0.0);
    }
    let rest_joints = if coeffs.is_empty() {
        template.joint_rest()
    } else {
        morph.rest_joints(&template.joint_rest(), &coeffs)
    };
    let pose_feature = if morph.posedirs.is_some() {
        crate::morph::pose_feature(params, nj)
    } else {
        Vec::new()
    };
    let mut transforms: Vec<DAffine3> = Vec::with_capacity(nj);
    let mut joints: Vec<DVec3> = Vec::with_capacity(nj);
    let t = DVec3::new(params[0], params[1], params[2]);
    for (j, joint) in rig.joints.iter().enumerate() {
        let o = rot_offset(j);
        let r = DVec3::new(params[o], params[o + 1], params[o + 2]);
        let local = match left_jacobians.as_deref_mut() {
            Some(out) => {
                let (local, jl) = exp_map_and_left_jacobian(r);
                out.push(jl);
                local
            }
            None => exp_map(r),
        };
        let c = rest_joints[j];
        let (w, anchor) = match joint.parent {
            None => (local, c + t),
            Some(p) => (
                transforms[p].matrix3 * local,
                transforms[p].transform_point3(c),
            ),
        };
        transforms.push(DAffine3 {
            matrix3: w,
            translation: anchor - w * c,
        });
        joints.push(anchor);
    }
    Posed {
        transforms,
        joints,
        rest_joints,
        coeffs,
        pose_feature,
    }
}

fn to_f32(transforms: &[DAffine3]) -> Vec<Affine3A> {
    transforms
        .iter()
        .map(|a| Affine3A {
            matrix3: Mat3A::from_cols(
                a.matrix3.x_axis.as_vec3().into(),
                a.matrix3.y_axis.as_vec3().into(),
                a.matrix3.z_axis.as_vec3().into(),
            ),
            translation: a.translation.as_vec3().into(),
        })
        .collect()
}

#[inline]
fn blend_vertex(template: &Template, a: &[Affine3A], v: usize, rest: Vec3A) -> Vec3A {
    let joints = template.influence_joints[v];
    let w = template.influence_weights[v];
    let mut out = Vec3A::ZERO;
    for k in 0..4 {
        let wk = w[k];
        if wk != 0.0 {
            out += wk * a[joints[k] as usize].transform_point3a(rest);
        }
    }
    out
}

/// Linear blend skinning of a morphable model's vertex, in f64 (its rest point depends on the
/// parameters).
#[inline]
fn blend_vertex_f64(template: &Template, posed: &Posed, v: usize) -> DVec3 {
    let rest = posed.rest_vertex(template, v);
    template.rig.weights[v]
        .iter()
        .fold(DVec3::ZERO, |acc, &(j, w)| {
            acc + w * posed.transforms[j].transform_point3(rest)
        })
}

/// Linear blend skinning of every vertex into `out` (resized to the vertex count), in f32 SIMD
/// (`Vec3A`). A morphable model's rest mesh is shaped first, one vectorised pass per non-zero
/// coefficient ([`crate::morph::Morph::rest_mesh_f32`]); a vertex with more than 4 influences
/// reads the template's flat lists. The shape offsets of a β that repeats are kept by the morph
/// (one subject's sequence shapes once). Within ~1e-6 of the f64 [`skin_lbs_f64`] relative to the
/// mesh size (tested; 2-4e-7 m on the bodies of the tests).
pub fn skin_lbs_into(template: &Template, posed: &Posed, out: &mut Vec<Vec3>) {
    out.clear();
    let a = to_f32(posed);
    if !template.skins_in_f64() {
        out.extend(
            template
                .rest_a()
                .enumerate()
                .map(|(v, rest)| Vec3::from(blend_vertex(template, &a, v, rest))),
        );
        return;
    }
    let mut rest = Vec::new();
    template.morph.rest_mesh_f32(
        &template.vertices,
        &posed.coeffs,
        &posed.pose_feature,
        &mut rest,
    );
    let points = rest.chunks_exact(3).map(|p| Vec3A::new(p[0], p[1], p[2]));
    match &template.wide_influences {
        Some(wide) => out.extend(points.enumerate().map(|(v, x)| {
            let (lo, hi) = (wide.offsets[v] as usize, wide.offsets[v + 1] as usize);
            let mut acc = Vec3A::ZERO;
            for (&j, &w) in wide.joints[lo..hi].iter().zip(&wide.weights[lo..hi]) {
                acc += w * a[j as usize].transform_point3a(x);
            }
            Vec3::from(acc)
        })),
        None => out.extend(
            points
                .enumerate()
                .map(|(v, x)| Vec3::from(blend_vertex(template, &a, v, x))),
        ),
    }
}

/// Linear blend skinning of every vertex in f64 (the rest point of each vertex shaped in f64 by
/// [`Posed::rest_vertex`]): the reference [`skin_lbs_into`] is tested against, and the
/// positions where f32 is not enough.
pub fn skin_lbs_f64(template: &Template, posed: &Posed) -> Vec<DVec3> {
    (0..template.num_vertices())
        .map(|v| blend_vertex_f64(template, posed, v))
        .collect()
}

/// Linear blend skinning of the listed vertices only (markers, hand tips, EDT samples).
pub fn skin_lbs_subset(template: &Template, posed: &Posed, vertices: &[u32]) -> Vec<Vec3> {
    if template.skins_in_f64() {
        return vertices
            .iter()
            .map(|&v| blend_vertex_f64(template, posed, v as usize).as_vec3())
            .collect();
    }
    let a = to_f32(posed);
    vertices
        .iter()
        .map(|&v| {
            Vec3::from(blend_vertex(
                template,
                &a,
                v as usize,
                Vec3A::from(template.vertices[v as usize]),
            ))
        })
        .collect()
}

/// A unit dual quaternion `(real, dual)` of a rigid transform.
fn dual_quat(a: &DAffine3) -> (DQuat, DQuat) {
    let real = DQuat::from_mat3(&a.matrix3).normalize();
    let t = a.translation;
    let dual = DQuat::from_xyzw(t.x, t.y, t.z, 0.0) * real * 0.5;
    (real, dual)
}

/// Dual-quaternion skinning of every vertex (blended with antipodality correction against the
/// vertex's first influence).
pub fn skin_dqs_into(template: &Template, posed: &Posed, out: &mut Vec<Vec3>) {
    let dqs: Vec<(DQuat, DQuat)> = posed.iter().map(dual_quat).collect();
    let rigid = template.morph.is_rigid();
    out.clear();
    out.extend(template.vertices.iter().enumerate().map(|(v, rest)| {
        let rest = if rigid {
            rest.as_dvec3()
        } else {
            posed.rest_vertex(template, v)
        };
        // The packed f32 weights (as before) unless the vertex has more than 4 influences.
        let list: Vec<(usize, f64)> = if template.wide {
            template.rig.weights[v].clone()
        } else {
            let (joints, w) = (template.influence_joints[v], template.influence_weights[v]);
            (0..4)
                .map(|k| (joints[k] as usize, f64::from(w[k])))
                .collect()
        };
        let pivot = dqs[list[0].0].0;
        let (mut real, mut dual) = (
            DQuat::from_xyzw(0.0, 0.0, 0.0, 0.0),
            DQuat::from_xyzw(0.0, 0.0, 0.0, 0.0),
        );
        for &(j, wk) in &list {
            if wk == 0.0 {
                continue;
            }
            let (r, d) = dqs[j];
            let s = if r.dot(pivot) < 0.0 { -wk } else { wk };
            real = real + r * s;
            dual = dual + d * s;
        }
        let norm = real.length();
        let (real, dual) = (real / norm, dual / norm);
        let t = (dual * 2.0) * real.conjugate();
        let p = real * rest + DVec3::new(t.x, t.y, t.z);
        p.as_vec3()
    }));
}

/// Posed vertices of one parameter vector with the given method.
pub fn pose_vertices(template: &Template, pose: &[f64], method: SkinningMethod) -> Vec<Vec3> {
    let transforms = joint_transforms(template, pose);
    let mut out = Vec::with_capacity(template.num_vertices());
    match method {
        SkinningMethod::Linear => skin_lbs_into(template, &transforms, &mut out),
        SkinningMethod::DualQuaternion => skin_dqs_into(template, &transforms, &mut out),
    }
    out
}

/// Posed vertices of many poses in parallel (rayon).
pub fn pose_vertices_batch<P: AsRef<[f64]> + Sync>(
    template: &Template,
    poses: &[P],
    method: SkinningMethod,
) -> Vec<Vec<Vec3>> {
    poses
        .par_iter()
        .map(|p| pose_vertices(template, p.as_ref(), method))
        .collect()
}

/// Area-weighted vertex normals of a posed mesh.
pub fn vertex_normals(vertices: &[Vec3], faces: &[[u32; 3]]) -> Vec<Vec3> {
    let mut normals = vec![Vec3::ZERO; vertices.len()];
    for f in faces {
        let [a, b, c] = f.map(|i| vertices[i as usize]);
        let n = (b - a).cross(c - a);
        for &i in f {
            normals[i as usize] += n;
        }
    }
    normals.iter().map(|n| n.normalize_or_zero()).collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::body::default_template;
    use crate::pose::{POSE_DIM, Pose};

    fn test_pose() -> Pose {
        let mut p = [0.0; POSE_DIM];
        for (i, v) in p.iter_mut().enumerate() {
            *v = ((i * 37 % 19) as f64 / 19.0 - 0.5) * 1.2;
        }
        p
    }

    #[test]
    fn dual_quaternion_equals_linear_blend_where_one_joint_rules() {
        let t = default_template();
        let pose = test_pose();
        let lbs = pose_vertices(&t, &pose, SkinningMethod::Linear);
        let dqs = pose_vertices(&t, &pose, SkinningMethod::DualQuaternion);
        let mut single = 0;
        for (v, list) in t.rig.weights.iter().enumerate() {
            if list.len() == 1 {
                single += 1;
                assert!((lbs[v] - dqs[v]).length() < 1e-5, "vertex {v}");
            }
        }
        assert!(single > 100);
        // Blended vertices differ (DQS keeps volume at bent joints), but stay close.
        let max = lbs
            .iter()
            .zip(&dqs)
            .map(|(a, b)| (*a - *b).length())
            .fold(0.0, f32::max);
        assert!(max > 1e-4 && max < 0.1, "{max}");
    }

    #[test]
    fn root_only_pose_is_rigid_for_both_methods() {
        let t = default_template();
        let mut pose = [0.0; POSE_DIM];
        pose[..6].copy_from_slice(&[0.1, 0.2, -0.3, 0.5, -0.4, 0.9]);
        let a = joint_transforms(&t, &pose);
        let expect: Vec<Vec3> = t
            .vertices
            .iter()
            .map(|v| a[0].transform_point3(v.as_dvec3()).as_vec3())
            .collect();
        for method in [SkinningMethod::Linear, SkinningMethod::DualQuaternion] {
            let got = pose_vertices(&t, &pose, method);
            let max = got
                .iter()
                .zip(&expect)
                .map(|(a, b)| (*a - *b).length())
                .fold(0.0, f32::max);
            assert!(max < 1e-5, "{method:?}: {max}");
        }
    }

    /// `max` that is NaN once either side is (`f64::max` drops NaN): a NaN vertex fails a bound
    /// instead of being skipped.
    fn nan_max(m: f64, d: f64) -> f64 {
        if m.is_nan() || d.is_nan() {
            f64::NAN
        } else {
            m.max(d)
        }
    }

    #[test]
    fn the_f32_mesh_loop_equals_the_f64_reference() {
        use rand::{Rng, SeedableRng};
        use rand_distr::{Distribution, StandardNormal};
        let mh =
            std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../models/makehuman-cmu_mb.npz");
        let models = [
            ("default (rigid)", default_template()),
            (
                "morphable default",
                crate::body::morphable_default_template().unwrap().0,
            ),
            (
                "SMPL-like, 6 influences, correctives",
                crate::body::procedural::smpl_like(3, 300, 10, true),
            ),
            ("MakeHuman", crate::modelfile::load(&mh).unwrap()),
        ];
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(11);
        let mut out = Vec::new();
        for (name, t) in &models {
            let layout = t.layout();
            let extent = t
                .vertices
                .iter()
                .map(|v| v.abs().max_element())
                .fold(0f32, f32::max);
            for trial in 0..4 {
                let mut p: Vec<f64> = (0..layout.pose_dim())
                    .map(|_| rng.random_range(-0.5..0.5))
                    .collect();
                for _ in 0..layout.shape + layout.expression {
                    let z: f64 = StandardNormal.sample(&mut rng);
                    // Trial 0 at the mean shape, the others up to 3 standard deviations.
                    p.push(if trial == 0 { 0.0 } else { 1.5 * z });
                }
                let posed = joint_transforms(t, &p);
                skin_lbs_into(t, &posed, &mut out);
                // Again with the same β (its offsets kept on the second call, reused on the
                // third) and another pose: the same mesh as computed afresh.
                let mut again = Vec::new();
                for _ in 0..2 {
                    skin_lbs_into(t, &posed, &mut again);
                    assert_eq!(again, out, "{name}, trial {trial}: kept shape offsets");
                }
                let mut q = p.clone();
                q[5] += 0.2;
                let other = joint_transforms(t, &q);
                skin_lbs_into(t, &other, &mut again);
                let fresh = skin_lbs_f64(t, &other);
                let worst = again
                    .iter()
                    .zip(&fresh)
                    .map(|(a, b)| (a.as_dvec3() - *b).length())
                    .fold(0.0f64, nan_max);
                assert!(
                    worst < 2e-6,
                    "{name}, trial {trial}: cached β, new pose: {worst:e}"
                );
                let reference = skin_lbs_f64(t, &posed);
                assert_eq!(out.len(), reference.len());
                let max = out
                    .iter()
                    .zip(&reference)
                    .map(|(a, b)| (a.as_dvec3() - *b).abs().max_element())
                    .fold(0.0f64, nan_max);
                let tol = 1e-6 * (1.0 + f64::from(extent));
                println!("{name}, trial {trial}: f32 loop vs f64 reference {max:.2e} m");
                assert!(max <= tol, "{name}, trial {trial}: {max:e} > {tol:e}");
            }
        }
        assert!(models[2].1.wide && !models[2].1.morph.is_rigid());
        assert!(models[2].1.morph.posedirs.is_some());
    }

    #[test]
    fn posed_joints_follow_the_chain() {
        // A_j(c_j) = A_parent(c_j): rotating the left shoulder moves the elbow and hand, not the head.
        let t = default_template();
        let mut pose = [0.0; POSE_DIM];
        pose[crate::pose::rot_offset(crate::skeleton::L_SHOULDER) + 2] = 0.7;
        let j0 = joint_transforms(&t, &[0.0; POSE_DIM]).joints;
        let j1 = joint_transforms(&t, &pose).joints;
        use crate::skeleton::*;
        assert!((j0[HEAD] - j1[HEAD]).length() < 1e-12);
        assert!((j0[L_SHOULDER] - j1[L_SHOULDER]).length() < 1e-12);
        assert!((j1[L_ELBOW] - j0[L_ELBOW]).length() > 0.1);
        assert!(
            j1[L_HAND].y > j0[L_HAND].y,
            "a positive z rotation raises the left arm"
        );
        let bone0 = (j0[L_HAND] - j0[L_ELBOW]).length();
        let bone1 = (j1[L_HAND] - j1[L_ELBOW]).length();
        assert!((bone0 - bone1).abs() < 1e-12);
    }
}
