//! Error metrics of SPEC §9, in millimetres: V2V (mean vertex-to-vertex distance), MPJPE (mean
//! per-joint position error), PA-MPJPE (MPJPE after the similarity transform that best aligns the
//! joints, Umeyama 1991) and the RMS Hausdorff distance of papers/000 eq. (1)–(2) between a fitted
//! and a ground-truth pose of the same template.

use glam::{DVec3, Vec3};
use rayon::prelude::*;

use crate::skinning::{joint_transforms, skin_lbs_into, skin_lbs_subset};
use crate::template::Template;

/// Mean distance between corresponding posed vertices, in mm.
pub fn v2v_mm(template: &Template, fitted: &[f64], truth: &[f64]) -> f64 {
    let a = posed_mesh(template, fitted);
    mean_distance_mm(&a, &posed_mesh(template, truth))
}

/// The mesh of `params` (FK and LBS, f32).
fn posed_mesh(template: &Template, params: &[f64]) -> Vec<Vec3> {
    let mut mesh = Vec::new();
    skin_lbs_into(template, &joint_transforms(template, params), &mut mesh);
    mesh
}

/// Mean distance between corresponding vertices of two meshes, in mm.
fn mean_distance_mm(a: &[Vec3], b: &[Vec3]) -> f64 {
    let n = a.len().max(1) as f64;
    1000.0
        * a.iter()
            .zip(b)
            .map(|(p, q)| f64::from(p.distance(*q)))
            .sum::<f64>()
        / n
}

/// One frame's ground truth posed once, for the mesh metrics of many fits of that frame (the
/// iterates of one fit, the methods of a study): each costs one mesh instead of two. The same
/// computations as [`v2v_mm`] and [`hausdorff_rms_mm`] on the same meshes.
#[derive(Debug, Clone)]
pub struct TruthMesh {
    mesh: Vec<Vec3>,
}

impl TruthMesh {
    /// The mesh of `truth` on `template`.
    pub fn new(template: &Template, truth: &[f64]) -> Self {
        Self {
            mesh: posed_mesh(template, truth),
        }
    }

    /// [`v2v_mm`] of `fitted` against this truth (`template` as in [`TruthMesh::new`]).
    pub fn v2v_mm(&self, template: &Template, fitted: &[f64]) -> f64 {
        mean_distance_mm(&posed_mesh(template, fitted), &self.mesh)
    }

    /// [`v2v_mm`] and [`hausdorff_rms_mm`] of `fitted` against this truth, from one fitted mesh.
    pub fn v2v_and_hausdorff_mm(&self, template: &Template, fitted: &[f64]) -> (f64, f64) {
        let a = posed_mesh(template, fitted);
        (
            mean_distance_mm(&a, &self.mesh),
            hausdorff_between_mm(&a, &self.mesh),
        )
    }
}

/// The shape error in mm: the mean distance between corresponding vertices of the rest-pose
/// meshes (every rotation and the translation zero, expression zero) of the fitted and the true
/// shape coefficients β — the per-vertex error in the T-pose that body-shape estimation reports
/// (e.g. PVE-T), where a β RMS weighs every coefficient alike whatever it does to the surface.
/// `None` for a model without shape coefficients.
///
/// At the rest pose the skinning is the identity and the pose correctives are zero, so the two
/// meshes differ by the blend shapes of the coefficients' difference alone: `S (β − β*)`, one
/// pass over the shape directions instead of two posed meshes (0 when the coefficients agree).
pub fn shape_v2v_mm(template: &Template, fitted: &[f64], truth: &[f64]) -> Option<f64> {
    let layout = template.layout();
    let shape = layout.range(crate::layout::Block::Shape);
    if shape.is_empty() || fitted.len() < shape.end || truth.len() < shape.end {
        return None;
    }
    // The shape coefficients are the first columns of the directions (β before ψ).
    let delta: Vec<(usize, f64)> = shape
        .clone()
        .enumerate()
        .map(|(j, i)| (j, fitted[i] - truth[i]))
        .filter(|&(_, d)| d != 0.0)
        .collect();
    if delta.is_empty() {
        return Some(0.0);
    }
    let morph = &template.morph;
    let k = morph.coefficients();
    let n = template.num_vertices();
    let sum: f64 = morph
        .dirs
        .chunks_exact(3 * k)
        .take(n)
        .map(|rows| {
            (0..3)
                .map(|a| {
                    let row = &rows[a * k..(a + 1) * k];
                    let c: f64 = delta.iter().map(|&(j, d)| row[j] * d).sum();
                    c * c
                })
                .sum::<f64>()
                .sqrt()
        })
        .sum();
    Some(1000.0 * sum / n.max(1) as f64)
}

/// Mean distance between corresponding posed joint centres, in mm.
pub fn mpjpe_mm(template: &Template, fitted: &[f64], truth: &[f64]) -> f64 {
    joint_error_mm(
        &joint_positions(template, fitted),
        &joint_positions(template, truth),
    )
}

/// MPJPE after Procrustes alignment (rotation, uniform scale, translation) of the fitted joints
/// onto the true ones, in mm.
pub fn pa_mpjpe_mm(template: &Template, fitted: &[f64], truth: &[f64]) -> f64 {
    aligned_joint_error_mm(
        &joint_positions(template, fitted),
        &joint_positions(template, truth),
    )
}

/// [`mpjpe_mm`] of joints already posed ([`joint_positions`], metres): the mean distance of
/// corresponding joints, mm.
pub fn joint_error_mm(fitted: &[DVec3], truth: &[DVec3]) -> f64 {
    let n = fitted.len().max(1) as f64;
    1000.0
        * fitted
            .iter()
            .zip(truth)
            .map(|(p, q)| p.distance(*q))
            .sum::<f64>()
        / n
}

/// [`pa_mpjpe_mm`] of joints already posed: [`joint_error_mm`] after [`procrustes_align`].
pub fn aligned_joint_error_mm(fitted: &[DVec3], truth: &[DVec3]) -> f64 {
    joint_error_mm(&procrustes_align(fitted, truth), truth)
}

/// `p` mapped by the similarity `s R p + t` that minimises `Σ |s R p_i + t − q_i|²` (Umeyama).
pub fn procrustes_align(p: &[DVec3], q: &[DVec3]) -> Vec<DVec3> {
    let n = p.len().min(q.len());
    if n == 0 {
        return Vec::new();
    }
    let nf = n as f64;
    let mp = p.iter().copied().sum::<DVec3>() / nf;
    let mq = q.iter().copied().sum::<DVec3>() / nf;
    let mut cov = nalgebra::Matrix3::<f64>::zeros();
    let mut var_p = 0.0;
    for (a, b) in p.iter().zip(q) {
        let (x, y) = (*a - mp, *b - mq);
        cov += nalgebra::Vector3::new(y.x, y.y, y.z)
            * nalgebra::Vector3::new(x.x, x.y, x.z).transpose();
        var_p += x.length_squared();
    }
    cov /= nf;
    var_p /= nf;
    let svd = cov.svd(true, true);
    let (Some(u), Some(vt)) = (svd.u, svd.v_t) else {
        return p.to_vec();
    };
    let mut sign = nalgebra::Matrix3::<f64>::identity();
    if u.determinant() * vt.determinant() < 0.0 {
        sign[(2, 2)] = -1.0;
    }
    let r = u * sign * vt;
    let scale = if var_p > 0.0 {
        (svd.singular_values.component_mul(&sign.diagonal())).sum() / var_p
    } else {
        1.0
    };
    p.iter()
        .map(|a| {
            let x = *a - mp;
            let y = r * nalgebra::Vector3::new(x.x, x.y, x.z) * scale;
            DVec3::new(y.x, y.y, y.z) + mq
        })
        .collect()
}

/// RMS Hausdorff-like distance of papers/000 eq. (1)–(2) between the fitted and true posed
/// meshes, in mm: `max(dist(A, B), dist(B, A))` with `dist(A, B) = sqrt(mean_{v∈A} min_{u∈B}
/// |v − u|²)` over vertices.
pub fn hausdorff_rms_mm(template: &Template, fitted: &[f64], truth: &[f64]) -> f64 {
    hausdorff_between_mm(&posed_mesh(template, fitted), &posed_mesh(template, truth))
}

/// The RMS Hausdorff distance of [`hausdorff_rms_mm`] between two meshes, in mm.
fn hausdorff_between_mm(a: &[Vec3], b: &[Vec3]) -> f64 {
    1000.0 * rms_directed(a, b).max(rms_directed(b, a))
}

/// RMS over `a` of the distance to the nearest point of `b` (an R*-tree over `b`: the meshes of
/// a real body have 10⁴ vertices, where the all-pairs search costs ~10⁸ distances per call).
fn rms_directed(a: &[Vec3], b: &[Vec3]) -> f64 {
    if a.is_empty() || b.is_empty() {
        return 0.0;
    }
    let tree = rstar::RTree::bulk_load(b.iter().map(|u| u.to_array()).collect());
    let sum: f64 = a
        .par_iter()
        .map(|v| {
            tree.nearest_neighbor(&v.to_array())
                .map_or(f64::INFINITY, |u| {
                    f64::from(v.distance_squared(Vec3::from_array(*u)))
                })
        })
        .sum();
    (sum / a.len() as f64).sqrt()
}

/// Vertices whose largest skinning weight belongs to `joint`: the body part of papers/002's
/// part errors (H = head, L / R = hands).
pub fn part_vertices(template: &Template, joint: usize) -> Vec<u32> {
    template
        .dominant_joint()
        .iter()
        .enumerate()
        .filter(|(_, j)| **j == joint)
        .map(|(v, _)| v as u32)
        .collect()
}

/// V2V (mm) over the vertices `subset` only.
pub fn v2v_subset_mm(template: &Template, fitted: &[f64], truth: &[f64], subset: &[u32]) -> f64 {
    let a = skin_lbs_subset(template, &joint_transforms(template, fitted), subset);
    let b = skin_lbs_subset(template, &joint_transforms(template, truth), subset);
    let n = a.len().max(1) as f64;
    1000.0
        * a.iter()
            .zip(&b)
            .map(|(p, q)| f64::from(p.distance(*q)))
            .sum::<f64>()
        / n
}

/// papers/002 Table 7's errors of a face fit (mm): V2V over the model's face region and over the
/// whole head (every vertex), and LdmkErr (the mean 3D distance of the landmarks), each plain and
/// after Procrustes alignment (the paper's "PA" columns: rotation, uniform scale and translation
/// fitted on the same vertices the error is measured on).
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct FaceErrors {
    pub v2v_face_mm: f64,
    pub v2v_head_mm: f64,
    pub ldmk_mm: f64,
    pub pa_v2v_face_mm: f64,
    pub pa_v2v_head_mm: f64,
    pub pa_ldmk_mm: f64,
}

impl FaceErrors {
    /// The six errors in the order of the fields (the columns of `runs.csv` and Table 7).
    pub fn to_array(&self) -> [f64; 6] {
        [
            self.v2v_face_mm,
            self.v2v_head_mm,
            self.ldmk_mm,
            self.pa_v2v_face_mm,
            self.pa_v2v_head_mm,
            self.pa_ldmk_mm,
        ]
    }

    pub fn from_array(a: [f64; 6]) -> Self {
        Self {
            v2v_face_mm: a[0],
            v2v_head_mm: a[1],
            ldmk_mm: a[2],
            pa_v2v_face_mm: a[3],
            pa_v2v_head_mm: a[4],
            pa_ldmk_mm: a[5],
        }
    }
}

/// Mean distance (mm) between `a` and `b` at `subset` (all when `None`), plain and after aligning
/// `a` onto `b` there.
fn plain_and_aligned(a: &[Vec3], b: &[Vec3], subset: Option<&[u32]>) -> (f64, f64) {
    let pick = |m: &[Vec3]| -> Vec<DVec3> {
        match subset {
            Some(s) => s.iter().map(|&v| m[v as usize].as_dvec3()).collect(),
            None => m.iter().map(|v| v.as_dvec3()).collect(),
        }
    };
    let (p, q) = (pick(a), pick(b));
    let n = p.len().max(1) as f64;
    let mean =
        |x: &[DVec3]| 1000.0 * x.iter().zip(&q).map(|(u, v)| u.distance(*v)).sum::<f64>() / n;
    (mean(&p), mean(&procrustes_align(&p, &q)))
}

/// The [`FaceErrors`] of `fitted` against `truth`, or `None` for a model without a face region
/// and landmarks (the model file's `face_region` and `landmark_vertices`).
pub fn face_errors_mm(template: &Template, fitted: &[f64], truth: &[f64]) -> Option<FaceErrors> {
    let info = &template.info;
    if info.face_region.is_empty() || info.landmark_vertices.is_empty() {
        return None;
    }
    let (mut a, mut b) = (Vec::new(), Vec::new());
    skin_lbs_into(template, &joint_transforms(template, fitted), &mut a);
    skin_lbs_into(template, &joint_transforms(template, truth), &mut b);
    let (v2v_face_mm, pa_v2v_face_mm) = plain_and_aligned(&a, &b, Some(&info.face_region));
    let (v2v_head_mm, pa_v2v_head_mm) = plain_and_aligned(&a, &b, None);
    let (ldmk_mm, pa_ldmk_mm) = plain_and_aligned(&a, &b, Some(&info.landmark_vertices));
    Some(FaceErrors {
        v2v_face_mm,
        v2v_head_mm,
        ldmk_mm,
        pa_v2v_face_mm,
        pa_v2v_head_mm,
        pa_ldmk_mm,
    })
}

/// Ground penetration (mm, papers/002 Tables 3–6 "GrPe"): the mean depth below the floor plane
/// y = 0 (where the template stands) of the posed vertices that lie below it; 0 when none do.
pub fn ground_penetration_mm(template: &Template, pose: &[f64]) -> f64 {
    let mut v = Vec::new();
    skin_lbs_into(template, &joint_transforms(template, pose), &mut v);
    let below: Vec<f64> = v
        .iter()
        .filter(|p| p.y < 0.0)
        .map(|p| -f64::from(p.y))
        .collect();
    if below.is_empty() {
        0.0
    } else {
        1000.0 * below.iter().sum::<f64>() / below.len() as f64
    }
}

/// The posed joint centres of `params` (the positions MPJPE compares), metres.
pub fn joint_positions(template: &Template, params: &[f64]) -> Vec<DVec3> {
    joint_transforms(template, params).joints
}

/// Acceleration error of a sequence, mm per frame²: the mean over every three consecutive
/// frames and every joint of `‖(f₊ − 2f + f₋) − (g₊ − 2g + g₋)‖`, `f` the fitted and `g` the true
/// joint positions (metres) — the temporal metric of video pose work (Kanazawa et al. 2019,
/// "Learning 3D Human Dynamics from Video"; VIBE, Kocabas et al. 2020): a fit that jitters
/// frame to frame has a large one even where its mean error is small; a constant or linearly
/// drifting offset has none. `frames` holds each fitted frame's index with its fitted and true
/// joints; a triple counts only where the three indices are consecutive (a gap in `--frames`
/// breaks it). `None` where no triple does or the joint counts differ.
pub fn accel_error_mm(frames: &[(usize, Vec<DVec3>, Vec<DVec3>)]) -> Option<f64> {
    let mut sorted: Vec<&(usize, Vec<DVec3>, Vec<DVec3>)> = frames.iter().collect();
    sorted.sort_by_key(|f| f.0);
    let (mut sum, mut count) = (0.0, 0usize);
    for w in sorted.windows(3) {
        let [(a, fa, ga), (b, fb, gb), (c, fc, gc)] = [w[0], w[1], w[2]].map(|f| (f.0, &f.1, &f.2));
        if b != a + 1 || c != b + 1 {
            continue;
        }
        let n = fb.len();
        if [fa.len(), fc.len(), ga.len(), gb.len(), gc.len()] != [n; 5] || n == 0 {
            return None;
        }
        let mean: f64 = (0..n)
            .map(|j| {
                let fitted = fc[j] - 2.0 * fb[j] + fa[j];
                let truth = gc[j] - 2.0 * gb[j] + ga[j];
                (fitted - truth).length()
            })
            .sum::<f64>()
            / n as f64;
        sum += mean;
        count += 1;
    }
    (count > 0).then(|| 1000.0 * sum / count as f64)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::body::default_template;
    use crate::pose::POSE_DIM;

    /// The shape error sees β alone (poses and translation do not count), and is the mean
    /// distance between the rest-pose meshes of the two coefficient vectors, posed and skinned
    /// here (the function takes the blend shapes of their difference); a rigid model has none.
    #[test]
    fn shape_v2v_is_the_rest_mesh_distance_of_the_coefficients() {
        let (t, _) = crate::body::morphable_default_template().unwrap();
        let layout = t.layout();
        let shape = layout.range(crate::layout::Block::Shape);
        assert!(!shape.is_empty());
        let mut truth = vec![0.0; layout.dim()];
        let mut fitted = truth.clone();
        for (k, i) in shape.clone().enumerate() {
            truth[i] = 0.5 * (k as f64 + 1.0).sin();
            fitted[i] = truth[i] + 0.3 * (k as f64 * 2.0 + 0.5).cos();
        }
        // Another pose and place: the same shape error.
        fitted[0] = 0.4;
        fitted[crate::pose::rot_offset(3)] = 0.7;
        let e = shape_v2v_mm(&t, &fitted, &truth).unwrap();
        // The rest-pose meshes themselves: every rotation and the translation zero.
        let rest = |params: &[f64]| {
            let mut p = vec![0.0; layout.dim()];
            p[shape.clone()].copy_from_slice(&params[shape.clone()]);
            posed_mesh(&t, &p)
        };
        let direct = mean_distance_mm(&rest(&fitted), &rest(&truth));
        assert!(direct > 1.0, "{direct}");
        assert!((e - direct).abs() < 1e-3 * direct, "{e} against {direct}");
        let mut same_shape = truth.clone();
        same_shape[1] = -0.2;
        same_shape[crate::pose::rot_offset(5) + 2] = 0.4;
        assert!(shape_v2v_mm(&t, &same_shape, &truth).unwrap() < 1e-6);
        let rigid = default_template();
        let zero = [0.0; POSE_DIM];
        assert!(shape_v2v_mm(&rigid, &zero, &zero).is_none());
    }

    /// A rigid motion of the whole model moves every vertex (plain errors) and is undone by the
    /// alignment (PA errors ~0); a pose change inside the face is not.
    #[test]
    fn face_errors_separate_rigid_motion_from_deformation() {
        let mut t = default_template();
        let truth = [0.0; POSE_DIM];
        assert!(face_errors_mm(&t, &truth, &truth).is_none());
        // Vertices the head joint alone moves.
        let head: Vec<u32> = (0..t.num_vertices() as u32)
            .filter(|&v| {
                let w = &t.rig.weights[v as usize];
                w.len() == 1 && w[0].0 == crate::skeleton::HEAD
            })
            .collect();
        assert!(head.len() > 30);
        t.info.face_region = head.clone();
        t.info.landmark_vertices = head.iter().copied().step_by(3).collect();
        let zero = face_errors_mm(&t, &truth, &truth).unwrap();
        assert!(zero.to_array().iter().all(|&x| x < 1e-9), "{zero:?}");
        let mut moved = truth;
        moved[0] = 0.02;
        moved[crate::pose::rot_offset(0) + 1] = 0.3;
        let e = face_errors_mm(&t, &moved, &truth).unwrap();
        assert!(
            e.v2v_head_mm > 20.0 && e.v2v_face_mm > 20.0 && e.ldmk_mm > 20.0,
            "{e:?}"
        );
        for pa in [e.pa_v2v_face_mm, e.pa_v2v_head_mm, e.pa_ldmk_mm] {
            assert!(pa < 1e-3, "{e:?}");
        }
        // Bending the neck deforms the body against the head: the head's own error aligns away,
        // the whole model's does not.
        let mut bent = truth;
        bent[crate::pose::rot_offset(crate::skeleton::HEAD)] = 0.5;
        let e = face_errors_mm(&t, &bent, &truth).unwrap();
        assert!(e.pa_v2v_face_mm < 1e-3 && e.pa_v2v_head_mm > 1.0, "{e:?}");
        assert_eq!(FaceErrors::from_array(e.to_array()), e);
        // The whole-head V2V is the model's V2V.
        let d = (e.v2v_head_mm - v2v_mm(&t, &bent, &truth)).abs();
        assert!(d < 1e-4, "{d}"); // f32 vs f64 distances of the same f32 vertices
    }

    /// The truth posed once gives the figures of posing it per call: V2V bit for bit on the
    /// MakeHuman body with β and on the default template, the Hausdorff distance to rounding
    /// (its sums run in parallel); a pose other than the truth has a nonzero error.
    #[test]
    fn truth_mesh_gives_the_per_call_figures() {
        use rand::{Rng, SeedableRng};
        let mh =
            std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../models/makehuman-cmu_mb.npz");
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
        for t in [crate::modelfile::load(&mh).unwrap(), default_template()] {
            let dim = t.layout().dim();
            let mut draw =
                || -> Vec<f64> { (0..dim).map(|_| rng.random_range(-0.3..0.3)).collect() };
            let truth = draw();
            let mesh = TruthMesh::new(&t, &truth);
            for _ in 0..3 {
                let fitted = draw();
                let v2v = v2v_mm(&t, &fitted, &truth);
                assert!(v2v > 1.0, "{v2v}");
                assert_eq!(mesh.v2v_mm(&t, &fitted).to_bits(), v2v.to_bits());
                let (a, h) = mesh.v2v_and_hausdorff_mm(&t, &fitted);
                assert_eq!(a.to_bits(), v2v.to_bits());
                let h0 = hausdorff_rms_mm(&t, &fitted, &truth);
                assert!((h - h0).abs() <= 1e-9 * h0 && h > 0.0, "{h} vs {h0}");
            }
            assert_eq!(mesh.v2v_mm(&t, &truth), 0.0);
        }
    }

    #[test]
    fn a_pure_translation_moves_everything_by_its_length() {
        let t = default_template();
        let zero = [0.0; POSE_DIM];
        let mut moved = zero;
        moved[0] = 0.03;
        moved[2] = -0.04; // 5 cm
        assert!((v2v_mm(&t, &moved, &zero) - 50.0).abs() < 1e-3);
        assert!((mpjpe_mm(&t, &moved, &zero) - 50.0).abs() < 1e-9);
        assert_eq!(v2v_mm(&t, &zero, &zero), 0.0);
    }

    #[test]
    fn procrustes_undoes_a_similarity_and_never_raises_the_rms_joint_error() {
        let t = default_template();
        let mut rng_pose = [0.0; POSE_DIM];
        for (i, v) in rng_pose.iter_mut().enumerate() {
            *v = ((i * 37 % 11) as f64 - 5.0) * 0.04;
        }
        let joints = joint_transforms(&t, &rng_pose).joints;
        let r = glam::DQuat::from_euler(glam::EulerRot::YXZ, 0.7, -0.3, 0.2);
        let moved: Vec<DVec3> = joints
            .iter()
            .map(|p| r * *p * 1.3 + DVec3::new(0.2, -0.1, 0.5))
            .collect();
        let back = procrustes_align(&moved, &joints);
        for (a, b) in back.iter().zip(&joints) {
            assert!(a.distance(*b) < 1e-9, "{a} vs {b}");
        }
        // A pure root translation and rotation of the whole body: PA-MPJPE 0, MPJPE not.
        let mut turned = rng_pose;
        turned[0] += 0.1;
        turned[4] += 0.5;
        assert!(pa_mpjpe_mm(&t, &turned, &rng_pose) < 1e-6);
        assert!(mpjpe_mm(&t, &turned, &rng_pose) > 50.0);
        let mut bent = rng_pose;
        bent[3 + 3 * 5] += 0.6;
        assert!(pa_mpjpe_mm(&t, &bent, &rng_pose) > 0.0);
        // The alignment minimises the squared joint error, so it cannot raise the RMS error.
        let rms = |a: &[f64], b: &[f64], align: bool| {
            let (ja, jb) = (
                joint_transforms(&t, a).joints,
                joint_transforms(&t, b).joints,
            );
            let ja = if align {
                procrustes_align(&ja, &jb)
            } else {
                ja
            };
            (ja.iter()
                .zip(&jb)
                .map(|(p, q)| p.distance_squared(*q))
                .sum::<f64>()
                / ja.len() as f64)
                .sqrt()
        };
        assert!(rms(&bent, &rng_pose, true) <= rms(&bent, &rng_pose, false) + 1e-12);
    }

    #[test]
    fn the_tree_search_equals_the_all_pairs_search() {
        use rand::{Rng, SeedableRng};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(5);
        let mut cloud = |n: usize| -> Vec<Vec3> {
            (0..n)
                .map(|_| Vec3::new(rng.random(), rng.random::<f32>() * 2.0, rng.random()))
                .collect()
        };
        let brute = |a: &[Vec3], b: &[Vec3]| -> f64 {
            let sum: f64 = a
                .iter()
                .map(|v| {
                    b.iter()
                        .map(|u| f64::from(v.distance_squared(*u)))
                        .fold(f64::INFINITY, f64::min)
                })
                .sum();
            (sum / a.len() as f64).sqrt()
        };
        for (na, nb) in [(1, 1), (50, 3), (700, 900), (2000, 40)] {
            let (a, b) = (cloud(na), cloud(nb));
            assert_eq!(rms_directed(&a, &b), brute(&a, &b), "{na} × {nb}");
        }
        assert_eq!(rms_directed(&[], &cloud(3)), 0.0);
    }

    #[test]
    fn hausdorff_is_zero_for_the_same_pose_and_bounded_by_a_translation() {
        let t = default_template();
        let zero = [0.0; POSE_DIM];
        assert_eq!(hausdorff_rms_mm(&t, &zero, &zero), 0.0);
        let mut moved = zero;
        moved[2] = 0.05;
        let h = hausdorff_rms_mm(&t, &moved, &zero);
        // Nearest vertices are at most the 50 mm shift away, and closer than that on the sides.
        assert!(h > 0.0 && h <= 50.0 + 1e-3, "{h}");
        assert!(h <= v2v_mm(&t, &moved, &zero) + 1e-3);
    }

    #[test]
    fn part_errors_see_only_their_part_and_ground_penetration_measures_depth() {
        let t = default_template();
        let head = part_vertices(&t, crate::skeleton::HEAD);
        let hand = part_vertices(&t, crate::skeleton::R_HAND);
        assert!(!head.is_empty() && !hand.is_empty());
        assert!(head.iter().all(|v| !hand.contains(v)));
        let rest = [0.0; crate::pose::POSE_DIM];
        // Bending the right elbow moves the right hand but not the head.
        let mut bent = rest;
        bent[3 + 3 * crate::skeleton::R_ELBOW + 1] = 0.8;
        assert!(v2v_subset_mm(&t, &bent, &rest, &hand) > 10.0);
        assert!(v2v_subset_mm(&t, &bent, &rest, &head) < 1e-6);
        // The whole-body V2V is the vertex-weighted mean of disjoint parts' V2V.
        let all: Vec<u32> = (0..t.num_vertices() as u32).collect();
        assert!((v2v_subset_mm(&t, &bent, &rest, &all) - v2v_mm(&t, &bent, &rest)).abs() < 1e-6);
        // Standing on the floor: nothing below it (within the template's rounding); sinking the
        // root by 5 cm puts the soles 5 cm deep.
        assert!(ground_penetration_mm(&t, &rest) < 1.0);
        let mut sunk = rest;
        sunk[1] -= 0.05;
        let g = ground_penetration_mm(&t, &sunk);
        assert!(g > 1.0 && g <= 50.0 + 1e-3, "{g}");
        let mut lifted = rest;
        lifted[1] += 0.05;
        assert_eq!(ground_penetration_mm(&t, &lifted), 0.0);
    }

    /// The acceleration error against its definition: zero for the truth itself, for a constant
    /// offset and for an offset drifting linearly; a spike of d at one frame counts d, 2d and d
    /// in the three triples around it; gaps break triples, and mismatched joint counts are None.
    #[test]
    fn the_acceleration_error_sees_jitter_not_offsets() {
        let truth: Vec<Vec<DVec3>> = (0..6)
            .map(|k| {
                let t = k as f64;
                vec![
                    DVec3::new(0.1 * t, 0.02 * t * t, 1.0),
                    DVec3::new(-0.3, 0.5 * t, 0.0),
                ]
            })
            .collect();
        let seq = |fitted: &dyn Fn(usize, &Vec<DVec3>) -> Vec<DVec3>| -> Vec<(usize, Vec<DVec3>, Vec<DVec3>)> {
            truth
                .iter()
                .enumerate()
                .map(|(k, g)| (k, fitted(k, g), g.clone()))
                .collect()
        };
        let same = seq(&|_, g| g.clone());
        assert_eq!(accel_error_mm(&same), Some(0.0));
        let drift = seq(&|k, g| {
            g.iter()
                .map(|p| *p + DVec3::new(0.05, -0.01, 0.2) * (1.0 + k as f64))
                .collect()
        });
        assert!(accel_error_mm(&drift).unwrap() < 1e-9);
        // A 6 mm spike along x at frame 2: triples (1,2,3), (0,1,2), (2,3,4) see 12, 6, 6 mm
        // on every joint; the other one (3,4,5) none: (6 + 12 + 6 + 0) / 4 = 6 mm.
        let spike = seq(&|k, g| {
            g.iter()
                .map(|p| {
                    if k == 2 {
                        *p + DVec3::new(0.006, 0.0, 0.0)
                    } else {
                        *p
                    }
                })
                .collect()
        });
        assert!((accel_error_mm(&spike).unwrap() - 6.0).abs() < 1e-9);
        // Frames out of order are sorted; a gap (frame 3 missing) leaves only (0,1,2): 6 mm.
        let mut gappy: Vec<_> = spike.iter().filter(|f| f.0 != 3).cloned().collect();
        gappy.reverse();
        assert!((accel_error_mm(&gappy).unwrap() - 6.0).abs() < 1e-9);
        assert_eq!(accel_error_mm(&spike[..2]), None);
        let mut short = same.clone();
        short[1].1.pop();
        assert_eq!(accel_error_mm(&short), None);
    }
}
