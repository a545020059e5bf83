//! Error metrics of SPEC §9, in millimetres: V2V (mean vertex-to-vertex distance) and MPJPE (mean
//! per-joint position error) between a fitted and a ground-truth pose of the same template.

use crate::pose::Pose;
use crate::skinning::{joint_transforms, posed_joints, skin_lbs_into};
use crate::template::Template;

/// Mean distance between corresponding posed vertices, in mm.
pub fn v2v_mm(template: &Template, fitted: &Pose, truth: &Pose) -> f64 {
    let (mut a, mut b) = (Vec::new(), Vec::new());
    skin_lbs_into(template, &joint_transforms(template, fitted), &mut a);
    skin_lbs_into(template, &joint_transforms(template, truth), &mut b);
    let n = a.len().max(1) as f64;
    1000.0 * a.iter().zip(&b).map(|(p, q)| f64::from(p.distance(*q))).sum::<f64>() / n
}

/// Mean distance between corresponding posed joint centres, in mm.
pub fn mpjpe_mm(template: &Template, fitted: &Pose, truth: &Pose) -> f64 {
    let a = posed_joints(template, &joint_transforms(template, fitted));
    let b = posed_joints(template, &joint_transforms(template, truth));
    let n = a.len().max(1) as f64;
    1000.0 * a.iter().zip(&b).map(|(p, q)| p.distance(*q)).sum::<f64>() / n
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::body::default_template;
    use crate::pose::POSE_DIM;

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
}
