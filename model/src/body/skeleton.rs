//! The 18-joint skeleton of papers/000 §4 (Root, Lower/Middle Torso, Head, R/L Hip, Knee, Ankle,
//! Foot, R/L Shoulder, Elbow, Hand), its joint order and its per-joint rotation limits.
//!
//! Axis convention (SPEC §3): y up, the subject faces +z, +x is the subject's left. Rotations are
//! axis-angle relative to the parent, expressed in the rest-pose (world-aligned) joint frame, so a
//! rotation about +x bends the trunk forward and a negative rotation about +x flexes the hip.

/// Number of joints of the default skeleton.
pub const NUM_JOINTS: usize = 18;

pub const ROOT: usize = 0;
pub const LOWER_TORSO: usize = 1;
pub const MIDDLE_TORSO: usize = 2;
pub const HEAD: usize = 3;
pub const R_HIP: usize = 4;
pub const R_KNEE: usize = 5;
pub const R_ANKLE: usize = 6;
pub const R_FOOT: usize = 7;
pub const L_HIP: usize = 8;
pub const L_KNEE: usize = 9;
pub const L_ANKLE: usize = 10;
pub const L_FOOT: usize = 11;
pub const R_SHOULDER: usize = 12;
pub const R_ELBOW: usize = 13;
pub const R_HAND: usize = 14;
pub const L_SHOULDER: usize = 15;
pub const L_ELBOW: usize = 16;
pub const L_HAND: usize = 17;

/// Joint names in topological order (parent before child).
pub const JOINT_NAMES: [&str; NUM_JOINTS] = [
    "root",
    "lower_torso",
    "middle_torso",
    "head",
    "r_hip",
    "r_knee",
    "r_ankle",
    "r_foot",
    "l_hip",
    "l_knee",
    "l_ankle",
    "l_foot",
    "r_shoulder",
    "r_elbow",
    "r_hand",
    "l_shoulder",
    "l_elbow",
    "l_hand",
];

/// Parent of every joint (`None` for the root).
pub const PARENTS: [Option<usize>; NUM_JOINTS] = [
    None,
    Some(ROOT),
    Some(LOWER_TORSO),
    Some(MIDDLE_TORSO),
    Some(ROOT),
    Some(R_HIP),
    Some(R_KNEE),
    Some(R_ANKLE),
    Some(ROOT),
    Some(L_HIP),
    Some(L_KNEE),
    Some(L_ANKLE),
    Some(MIDDLE_TORSO),
    Some(R_SHOULDER),
    Some(R_ELBOW),
    Some(MIDDLE_TORSO),
    Some(L_SHOULDER),
    Some(L_ELBOW),
];

/// The axis (0 = x, 1 = y, 2 = z) that a joint keeps when a mask drops 2 of its 3 DOFs
/// (papers/000 §4 keeps Swing #1 of the ankles, hands and, in the global case, Middle Torso).
pub const KEPT_AXIS: [Option<usize>; NUM_JOINTS] = {
    let mut k = [None; NUM_JOINTS];
    k[MIDDLE_TORSO] = Some(0);
    k[R_ANKLE] = Some(0);
    k[L_ANKLE] = Some(0);
    k[R_HAND] = Some(1);
    k[L_HAND] = Some(1);
    k
};

pub const fn is_foot(j: usize) -> bool {
    j == R_FOOT || j == L_FOOT
}
pub const fn is_ankle(j: usize) -> bool {
    j == R_ANKLE || j == L_ANKLE
}
pub const fn is_hand(j: usize) -> bool {
    j == R_HAND || j == L_HAND
}
pub const fn is_left(j: usize) -> bool {
    matches!(
        j,
        L_HIP | L_KNEE | L_ANKLE | L_FOOT | L_SHOULDER | L_ELBOW | L_HAND
    )
}

/// The mirror joint (left ↔ right), itself for the spine.
pub const fn mirror(j: usize) -> usize {
    match j {
        R_HIP..=R_FOOT => j + 4,
        L_HIP..=L_FOOT => j - 4,
        R_SHOULDER..=R_HAND => j + 3,
        L_SHOULDER..=L_HAND => j - 3,
        _ => j,
    }
}

/// Rotation limits in degrees, `[(min, max); 3]` about this crate's x, y, z axes.
///
/// From papers/000 Table 1, re-assigned to this axis convention: the paper's Swing #1, Swing #2
/// and Twist go to the flexion, abduction and along-bone axes of each segment (x, z, y for the
/// spine and legs; y, z, x for the arms, whose rest bones run along ±x), with each joint's largest
/// range on its flexion axis; the ankle's one-sided range [−100°, 10°] is mirrored to this
/// convention's plantar-flexion sign (+x turns the toes down). DOFs the paper removes (feet, the
/// second and third axes of the ankles and hands, Middle Torso's in the global case) get ±30°
/// (feet, hands) or ±25° (Middle Torso): our choice, used only by `full57`/`local43` masks.
pub fn rotation_limits_deg(j: usize) -> [(f64, f64); 3] {
    match j {
        ROOT => [(-30.0, 100.0), (-50.0, 50.0), (-50.0, 50.0)],
        LOWER_TORSO => [(-50.0, 50.0), (-50.0, 50.0), (-25.0, 25.0)],
        MIDDLE_TORSO => [(-50.0, 50.0), (-25.0, 25.0), (-25.0, 25.0)],
        HEAD => [(-25.0, 25.0), (-25.0, 25.0), (-25.0, 25.0)],
        R_HIP | L_HIP => [(-100.0, 100.0), (-60.0, 60.0), (-45.0, 45.0)],
        R_KNEE | L_KNEE => [(-100.0, 100.0), (-20.0, 20.0), (-45.0, 45.0)],
        R_ANKLE | L_ANKLE => [(-10.0, 100.0), (-30.0, 30.0), (-30.0, 30.0)],
        R_FOOT | L_FOOT => [(-30.0, 30.0), (-30.0, 30.0), (-30.0, 30.0)],
        R_SHOULDER | L_SHOULDER => [(-60.0, 60.0), (-60.0, 60.0), (-60.0, 60.0)],
        R_ELBOW | L_ELBOW => [(-90.0, 90.0), (-90.0, 90.0), (-90.0, 90.0)],
        _ => [(-30.0, 30.0), (-90.0, 90.0), (-30.0, 30.0)],
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parents_are_topological_and_mirror_is_an_involution() {
        for j in 1..NUM_JOINTS {
            assert!(PARENTS[j].is_some_and(|p| p < j), "joint {j}");
            assert_eq!(mirror(mirror(j)), j);
            assert_eq!(is_left(j) && j != mirror(j), is_left(j));
            assert_eq!(
                JOINT_NAMES[mirror(j)].replace("r_", "l_"),
                JOINT_NAMES[j].replace("r_", "l_")
            );
        }
        assert!(PARENTS[0].is_none());
    }

    #[test]
    fn limits_contain_zero() {
        for j in 0..NUM_JOINTS {
            for (lo, hi) in rotation_limits_deg(j) {
                assert!(lo < 0.0 && hi > 0.0);
            }
        }
    }
}
