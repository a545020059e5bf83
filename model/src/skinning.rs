//! CPU forward kinematics and skinning, exactly as written in SPEC §3:
//!
//! ```text
//! A_root(x) = R_root (x - c_root) + c_root + t
//! A_j(x)    = A_parent(j)(c_j) + W_j (x - c_j)
//! posed joint j:  A_j(c_j)
//! posed vertex v: sum_j w_vj A_j(v)       (linear blend skinning)
//! ```
//! Joint transforms are computed in f64; the vertex loops run in f32 SIMD (`Vec3A`).

use glam::{Affine3A, DAffine3, DMat3, DQuat, DVec3, Mat3A, Vec3, Vec3A};
use rayon::prelude::*;

use crate::pose::{Pose, rot_offset};
use crate::template::Template;

/// `R = exp([r]x)`, the rotation of axis-angle vector `r`.
pub fn exp_map(r: DVec3) -> DMat3 {
    DMat3::from_quat(DQuat::from_scaled_axis(r))
}

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

/// The affine maps `A_j` of every joint (world position of a rest-pose point carried by joint j),
/// as `x ↦ W_j x + (A_parent(j)(c_j) − W_j c_j)`.
pub fn joint_transforms(template: &Template, pose: &Pose) -> Vec<DAffine3> {
    let rig = &template.rig;
    let mut world_rot: Vec<DMat3> = Vec::with_capacity(rig.joints.len());
    let mut transforms: Vec<DAffine3> = Vec::with_capacity(rig.joints.len());
    let t = DVec3::new(pose[0], pose[1], pose[2]);
    for (j, joint) in rig.joints.iter().enumerate() {
        let o = rot_offset(j);
        let local = exp_map(DVec3::new(pose[o], pose[o + 1], pose[o + 2]));
        let c = joint.rest();
        let (w, anchor) = match joint.parent {
            None => (local, c + t),
            Some(p) => (world_rot[p] * local, transforms[p].transform_point3(c)),
        };
        world_rot.push(w);
        transforms.push(DAffine3 { matrix3: w, translation: anchor - w * c });
    }
    transforms
}

/// Posed joint positions `A_j(c_j)`.
pub fn posed_joints(template: &Template, transforms: &[DAffine3]) -> Vec<DVec3> {
    template.rig.joints.iter().zip(transforms).map(|(j, a)| a.transform_point3(j.rest())).collect()
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

/// Linear blend skinning of every vertex into `out` (resized to the vertex count).
pub fn skin_lbs_into(template: &Template, transforms: &[DAffine3], out: &mut Vec<Vec3>) {
    let a = to_f32(transforms);
    out.clear();
    out.extend(template.rest_a().enumerate().map(|(v, rest)| Vec3::from(blend_vertex(template, &a, v, rest))));
}

/// Linear blend skinning of the listed vertices only (markers, hand tips, EDT samples).
pub fn skin_lbs_subset(template: &Template, transforms: &[DAffine3], vertices: &[u32]) -> Vec<Vec3> {
    let a = to_f32(transforms);
    vertices
        .iter()
        .map(|&v| Vec3::from(blend_vertex(template, &a, v as usize, Vec3A::from(template.vertices[v as usize]))))
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
pub fn skin_dqs_into(template: &Template, transforms: &[DAffine3], out: &mut Vec<Vec3>) {
    let dqs: Vec<(DQuat, DQuat)> = transforms.iter().map(dual_quat).collect();
    out.clear();
    out.extend(template.vertices.iter().enumerate().map(|(v, rest)| {
        let joints = template.influence_joints[v];
        let w = template.influence_weights[v];
        let pivot = dqs[joints[0] as usize].0;
        let (mut real, mut dual) = (DQuat::from_xyzw(0.0, 0.0, 0.0, 0.0), DQuat::from_xyzw(0.0, 0.0, 0.0, 0.0));
        for k in 0..4 {
            let wk = f64::from(w[k]);
            if wk == 0.0 {
                continue;
            }
            let (r, d) = dqs[joints[k] as usize];
            let s = if r.dot(pivot) < 0.0 { -wk } else { wk };
            real = real + r * s;
            dual = dual + d * s;
        }
        let norm = real.length();
        let (real, dual) = (real / norm, dual / norm);
        let t = (dual * 2.0) * real.conjugate();
        let p = real * rest.as_dvec3() + DVec3::new(t.x, t.y, t.z);
        p.as_vec3()
    }));
}

/// Posed vertices of one pose with the given method.
pub fn pose_vertices(template: &Template, pose: &Pose, method: SkinningMethod) -> Vec<Vec3> {
    let transforms = joint_transforms(template, pose);
    let mut out = Vec::with_capacity(template.num_vertices());
    match method {
        SkinningMethod::Linear => skin_lbs_into(template, &transforms, &mut out),
        SkinningMethod::DualQuaternion => skin_dqs_into(template, &transforms, &mut out),
    }
    out
}

/// Posed vertices of many poses in parallel (rayon).
pub fn pose_vertices_batch(template: &Template, poses: &[Pose], method: SkinningMethod) -> Vec<Vec<Vec3>> {
    poses.par_iter().map(|p| pose_vertices(template, p, method)).collect()
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
    use crate::pose::POSE_DIM;

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
        let max = lbs.iter().zip(&dqs).map(|(a, b)| (*a - *b).length()).fold(0.0, f32::max);
        assert!(max > 1e-4 && max < 0.1, "{max}");
    }

    #[test]
    fn root_only_pose_is_rigid_for_both_methods() {
        let t = default_template();
        let mut pose = [0.0; POSE_DIM];
        pose[..6].copy_from_slice(&[0.1, 0.2, -0.3, 0.5, -0.4, 0.9]);
        let a = joint_transforms(&t, &pose);
        let expect: Vec<Vec3> = t.vertices.iter().map(|v| a[0].transform_point3(v.as_dvec3()).as_vec3()).collect();
        for method in [SkinningMethod::Linear, SkinningMethod::DualQuaternion] {
            let got = pose_vertices(&t, &pose, method);
            let max = got.iter().zip(&expect).map(|(a, b)| (*a - *b).length()).fold(0.0, f32::max);
            assert!(max < 1e-5, "{method:?}: {max}");
        }
    }

    #[test]
    fn posed_joints_follow_the_chain() {
        // A_j(c_j) = A_parent(c_j): rotating the left shoulder moves the elbow and hand, not the head.
        let t = default_template();
        let mut pose = [0.0; POSE_DIM];
        pose[crate::pose::rot_offset(crate::skeleton::L_SHOULDER) + 2] = 0.7;
        let j0 = posed_joints(&t, &joint_transforms(&t, &[0.0; POSE_DIM]));
        let j1 = posed_joints(&t, &joint_transforms(&t, &pose));
        use crate::skeleton::*;
        assert!((j0[HEAD] - j1[HEAD]).length() < 1e-12);
        assert!((j0[L_SHOULDER] - j1[L_SHOULDER]).length() < 1e-12);
        assert!((j1[L_ELBOW] - j0[L_ELBOW]).length() > 0.1);
        assert!(j1[L_HAND].y > j0[L_HAND].y, "a positive z rotation raises the left arm");
        let bone0 = (j0[L_HAND] - j0[L_ELBOW]).length();
        let bone1 = (j1[L_HAND] - j1[L_ELBOW]).length();
        assert!((bone0 - bone1).abs() < 1e-12);
    }
}
