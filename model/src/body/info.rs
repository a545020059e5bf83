//! What a model knows about its skeleton beyond the rig (SPEC §3a): per-joint rotation limits,
//! body-part labels, the left/right mirror map, the map from the papers/000 skeleton's joints to
//! the model's, the headset offset and hand-tip vertices of the `hmd` modality, and where the
//! model came from.
//!
//! A model file may give each of these ([`crate::modelfile`]); otherwise [`ModelInfo::fallback`]
//! derives them: the default skeleton's own values when the rig is the 18-joint skeleton; SMPL's
//! joint names, parts and map when the rig has SMPL's 24 joints; parts and mirror from the joint
//! names (`left_`/`l_`, `right_`/`r_`, limb words) and uniform ±180° limits otherwise.

use crate::error::{ModelError, Result};
use crate::rig::Rig;
use crate::skeleton;

/// SMPL's 24 joint names, in SMPL's order (the fallback names of a 24-joint model file).
pub const SMPL_JOINT_NAMES: [&str; 24] = [
    "pelvis",
    "left_hip",
    "right_hip",
    "spine1",
    "left_knee",
    "right_knee",
    "spine2",
    "left_ankle",
    "right_ankle",
    "spine3",
    "left_foot",
    "right_foot",
    "neck",
    "left_collar",
    "right_collar",
    "head",
    "left_shoulder",
    "right_shoulder",
    "left_elbow",
    "right_elbow",
    "left_wrist",
    "right_wrist",
    "left_hand",
    "right_hand",
];

/// The SMPL joint that stands for each papers/000 joint (in [`skeleton::JOINT_NAMES`] order).
pub const SMPL_JOINT_MAP: [&str; skeleton::NUM_JOINTS] = [
    "pelvis",
    "spine1",
    "spine3",
    "head",
    "right_hip",
    "right_knee",
    "right_ankle",
    "right_foot",
    "left_hip",
    "left_knee",
    "left_ankle",
    "left_foot",
    "right_shoulder",
    "right_elbow",
    "right_wrist",
    "left_shoulder",
    "left_elbow",
    "left_wrist",
];

/// The body-part labels that the grouped strategy (papers/000 Algorithm 1) uses.
pub const PARTS: [&str; 5] = ["torso", "left_leg", "right_leg", "left_arm", "right_arm"];

/// Headset offset from the head joint in the rest frame (eyes: 17 cm up, 9 cm forward), the
/// default of the `hmd` modality.
pub const DEFAULT_HMD_OFFSET: [f64; 3] = [0.0, 0.17, 0.09];

/// Skeleton information of a model.
#[derive(Debug, Clone, PartialEq)]
pub struct ModelInfo {
    /// Rotation limits per joint and axis, degrees `[lo, hi]`.
    pub limits_deg: Vec<[[f64; 2]; 3]>,
    /// Body-part label per joint (one of [`PARTS`] for the strategies; other labels allowed).
    pub parts: Vec<String>,
    /// Mirror joint of every joint (itself on the midline).
    pub mirror: Vec<usize>,
    /// The model joint standing for each papers/000 joint (`None`: no such joint).
    pub joint_map: Vec<Option<usize>>,
    /// Headset offset from the head joint, rest frame, metres.
    pub hmd_offset: [f64; 3],
    /// Hand-tip vertices (left, right) of the `hmd` modality, when the file names them.
    pub hand_tips: Option<[u32; 2]>,
    /// Where the model came from (file, licence).
    pub provenance: String,
    /// Vertices of the `landmarks2d` modality: a face model's dense landmarks (empty: none).
    pub landmark_vertices: Vec<u32>,
    /// Vertices of the face region, over which a face model's "face" errors are measured (the
    /// whole mesh is the "head"); empty: none.
    pub face_region: Vec<u32>,
}

impl Default for ModelInfo {
    fn default() -> Self {
        Self {
            limits_deg: Vec::new(),
            parts: Vec::new(),
            mirror: Vec::new(),
            joint_map: Vec::new(),
            hmd_offset: DEFAULT_HMD_OFFSET,
            hand_tips: None,
            provenance: String::new(),
            landmark_vertices: Vec::new(),
            face_region: Vec::new(),
        }
    }
}

fn side_of(name: &str) -> Option<(&'static str, String)> {
    let lower = name.to_ascii_lowercase();
    for (prefix, side, other) in [
        ("left_", "left", "right_"),
        ("right_", "right", "left_"),
        ("l_", "left", "r_"),
        ("r_", "right", "l_"),
    ] {
        if let Some(rest) = lower.strip_prefix(prefix) {
            return Some((side, format!("{other}{rest}")));
        }
    }
    None
}

fn is_leg_word(name: &str) -> bool {
    [
        "hip", "knee", "ankle", "foot", "toe", "leg", "thigh", "calf", "shin", "heel",
    ]
    .iter()
    .any(|w| name.contains(w))
}

impl ModelInfo {
    /// The information of the default 18-joint skeleton.
    pub fn default_skeleton() -> Self {
        let n = skeleton::NUM_JOINTS;
        Self {
            limits_deg: (0..n)
                .map(|j| skeleton::rotation_limits_deg(j).map(|(lo, hi)| [lo, hi]))
                .collect(),
            parts: (0..n).map(|j| default_part(j).to_string()).collect(),
            mirror: (0..n).map(skeleton::mirror).collect(),
            joint_map: (0..n).map(Some).collect(),
            ..Self::default()
        }
    }

    /// What can be derived from a rig alone (see the module documentation).
    pub fn fallback(rig: &Rig) -> Self {
        let names: Vec<&str> = rig.joints.iter().map(|j| j.name.as_str()).collect();
        let is_default = names.len() == skeleton::NUM_JOINTS
            && names
                .iter()
                .zip(skeleton::JOINT_NAMES)
                .all(|(a, b)| *a == b)
            && rig
                .joints
                .iter()
                .zip(skeleton::PARENTS)
                .all(|(j, p)| j.parent == p);
        if is_default {
            return Self::default_skeleton();
        }
        let lower: Vec<String> = names.iter().map(|n| n.to_ascii_lowercase()).collect();
        let parts = lower
            .iter()
            .map(|n| match side_of(n) {
                Some((side, _)) => format!("{side}_{}", if is_leg_word(n) { "leg" } else { "arm" }),
                None => "torso".to_string(),
            })
            .collect();
        let mirror = lower
            .iter()
            .enumerate()
            .map(|(j, n)| {
                side_of(n)
                    .and_then(|(_, other)| lower.iter().position(|m| *m == other))
                    .unwrap_or(j)
            })
            .collect();
        let joint_map =
            if names.len() == 24 && names.iter().zip(SMPL_JOINT_NAMES).all(|(a, b)| *a == b) {
                SMPL_JOINT_MAP
                    .iter()
                    .map(|m| names.iter().position(|n| n == m))
                    .collect()
            } else {
                skeleton::JOINT_NAMES
                    .iter()
                    .map(|m| names.iter().position(|n| n == m))
                    .collect()
            };
        Self {
            limits_deg: vec![[[-180.0, 180.0]; 3]; names.len()],
            parts,
            mirror,
            joint_map,
            ..Self::default()
        }
    }

    /// Checks sizes and ranges against a model of `joints` joints and `vertices` vertices.
    pub fn validate(&self, joints: usize, vertices: usize) -> Result<()> {
        let bad =
            |what: &str, reason: String| ModelError::Config(format!("model {what}: {reason}"));
        if self.limits_deg.len() != joints {
            return Err(bad(
                "joint limits",
                format!("{} rows for {joints} joints", self.limits_deg.len()),
            ));
        }
        for (j, l) in self.limits_deg.iter().enumerate() {
            if l.iter()
                .any(|[lo, hi]| !(lo.is_finite() && hi.is_finite() && lo <= hi))
            {
                return Err(bad(
                    "joint limits",
                    format!("joint {j}: {l:?} is not a finite range lo ≤ hi"),
                ));
            }
        }
        if self.parts.len() != joints {
            return Err(bad(
                "part labels",
                format!("{} labels for {joints} joints", self.parts.len()),
            ));
        }
        if self.mirror.len() != joints {
            return Err(bad(
                "mirror map",
                format!("{} entries for {joints} joints", self.mirror.len()),
            ));
        }
        for (j, &m) in self.mirror.iter().enumerate() {
            if m >= joints || self.mirror[m] != j {
                return Err(bad(
                    "mirror map",
                    format!("joint {j} → {m} is out of range or not an involution"),
                ));
            }
        }
        if self.joint_map.len() != skeleton::NUM_JOINTS {
            return Err(bad(
                "joint map",
                format!(
                    "{} entries, expected one per papers/000 joint ({})",
                    self.joint_map.len(),
                    skeleton::NUM_JOINTS
                ),
            ));
        }
        if let Some(j) = self.joint_map.iter().flatten().find(|&&j| j >= joints) {
            return Err(bad(
                "joint map",
                format!("joint {j} out of range ({joints} joints)"),
            ));
        }
        if self.hmd_offset.iter().any(|v| !v.is_finite()) {
            return Err(bad("hmd offset", "is not finite".into()));
        }
        if let Some(t) = self.hand_tips
            && t.iter().any(|&v| v as usize >= vertices)
        {
            return Err(bad(
                "hand tips",
                format!("{t:?} out of range ({vertices} vertices)"),
            ));
        }
        Ok(())
    }
}

/// Part label of a default-skeleton joint (papers/000 Algorithm 1's groups).
fn default_part(j: usize) -> &'static str {
    use skeleton::*;
    match j {
        R_HIP..=R_FOOT => "right_leg",
        L_HIP..=L_FOOT => "left_leg",
        R_SHOULDER..=R_HAND => "right_arm",
        L_SHOULDER..=L_HAND => "left_arm",
        _ => "torso",
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rig::Joint;

    fn rig(names: &[&str]) -> Rig {
        let joints = names
            .iter()
            .enumerate()
            .map(|(i, n)| Joint {
                name: (*n).into(),
                parent: (i > 0).then_some(0),
                rest_position: [0.0; 3],
            })
            .collect();
        Rig {
            joints,
            weights: Vec::new(),
            markers: Vec::new(),
        }
    }

    #[test]
    fn smpl_fallback_maps_parts_mirror_and_papers000_joints() {
        let info = ModelInfo::fallback(&rig(&SMPL_JOINT_NAMES));
        info.validate(24, 0).unwrap();
        let idx = |n: &str| SMPL_JOINT_NAMES.iter().position(|m| *m == n).unwrap();
        assert_eq!(info.mirror[idx("left_wrist")], idx("right_wrist"));
        assert_eq!(info.mirror[idx("spine2")], idx("spine2"));
        assert_eq!(info.parts[idx("left_knee")], "left_leg");
        assert_eq!(info.parts[idx("right_collar")], "right_arm");
        assert_eq!(info.parts[idx("neck")], "torso");
        assert_eq!(info.joint_map[skeleton::R_HAND], Some(idx("right_wrist")));
        assert_eq!(info.limits_deg[5], [[-180.0, 180.0]; 3]);
    }

    #[test]
    fn default_skeleton_info_matches_the_constants() {
        let info = ModelInfo::default_skeleton();
        info.validate(18, 0).unwrap();
        assert_eq!(info.parts.iter().filter(|p| *p == "torso").count(), 4);
        assert_eq!(info.limits_deg[skeleton::R_KNEE][0], [-100.0, 100.0]);
        let mut bad = info.clone();
        bad.mirror[1] = 5;
        assert!(
            bad.validate(18, 0)
                .unwrap_err()
                .to_string()
                .contains("mirror")
        );
    }
}
