//! The pose vector of SPEC §3, DOF masks and bounds.
//!
//! A pose is 57 numbers: `[t_x, t_y, t_z, r_0 (3), ..., r_17 (3)]`, root translation in metres
//! followed by one axis-angle rotation per joint, relative to its parent.

use serde::{Deserialize, Serialize};

use crate::error::{ModelError, Result};
use crate::skeleton::{self, NUM_JOINTS};

/// Length of the pose vector: root translation + 3 per joint.
pub const POSE_DIM: usize = 3 + 3 * NUM_JOINTS;

/// A pose vector of the default 18-joint skeleton.
pub type Pose = [f64; POSE_DIM];

/// Index of the first number of joint `j`'s rotation in the pose vector.
pub const fn rot_offset(j: usize) -> usize {
    3 + 3 * j
}

/// Checks a user-given pose: right length, all finite.
pub fn pose_from_slice(values: &[f64]) -> Result<Pose> {
    if values.len() != POSE_DIM {
        return Err(ModelError::PoseLength { got: values.len(), expected: POSE_DIM });
    }
    if let Some((index, &value)) = values.iter().enumerate().find(|(_, v)| !v.is_finite()) {
        return Err(ModelError::PoseNotFinite { index, value });
    }
    let mut pose = [0.0; POSE_DIM];
    pose.copy_from_slice(values);
    Ok(pose)
}

/// Human-readable name of pose entry `i` (`t_x`, `l_knee.rx`, ...).
pub fn dof_name(i: usize) -> String {
    const AXES: [&str; 3] = ["x", "y", "z"];
    if i < 3 {
        format!("t_{}", AXES[i])
    } else {
        let j = (i - 3) / 3;
        format!("{}.r{}", skeleton::JOINT_NAMES[j], AXES[(i - 3) % 3])
    }
}

/// Which pose entries are free. SPEC §3 / papers/000 §4.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct DofMask {
    /// Name (`full57`, `local43`, `global41` or `custom`).
    pub name: String,
    /// Sorted indices of the free entries of the pose vector.
    pub free: Vec<usize>,
}

impl DofMask {
    /// All 57 numbers free.
    pub fn full57() -> Self {
        Self { name: "full57".into(), free: (0..POSE_DIM).collect() }
    }

    /// papers/000 §4: drop all 3 DOFs of both feet and 2 DOFs each of both ankles and both hands
    /// (each keeps its flexion axis, see [`skeleton::KEPT_AXIS`]): 43 free.
    pub fn local43() -> Self {
        let free = (0..POSE_DIM).filter(|&i| !Self::dropped_local(i)).collect();
        Self { name: "local43".into(), free }
    }

    /// papers/000 §4.2: `local43` minus 2 DOFs of Middle Torso: 41 free.
    pub fn global41() -> Self {
        let mt = skeleton::MIDDLE_TORSO;
        let keep = skeleton::KEPT_AXIS[mt].unwrap_or(0);
        let free = (0..POSE_DIM)
            .filter(|&i| !Self::dropped_local(i))
            .filter(|&i| !(i >= rot_offset(mt) && i < rot_offset(mt) + 3 && i != rot_offset(mt) + keep))
            .collect();
        Self { name: "global41".into(), free }
    }

    fn dropped_local(i: usize) -> bool {
        if i < 3 {
            return false;
        }
        let j = (i - 3) / 3;
        let axis = (i - 3) % 3;
        if skeleton::is_foot(j) {
            return true;
        }
        if skeleton::is_ankle(j) || skeleton::is_hand(j) {
            return Some(axis) != skeleton::KEPT_AXIS[j];
        }
        false
    }

    /// A user mask from explicit indices.
    pub fn custom(mut free: Vec<usize>) -> Result<Self> {
        free.sort_unstable();
        free.dedup();
        if free.is_empty() {
            return Err(ModelError::Mask("a mask must free at least one DOF".into()));
        }
        if let Some(&bad) = free.iter().find(|&&i| i >= POSE_DIM) {
            return Err(ModelError::Mask(format!("index {bad} out of range 0..{POSE_DIM}")));
        }
        Ok(Self { name: "custom".into(), free })
    }

    /// Parses `full57`, `local43`, `global41` or a comma-separated list of indices or DOF names.
    pub fn parse(spec: &str) -> Result<Self> {
        match spec {
            "full57" => Ok(Self::full57()),
            "local43" => Ok(Self::local43()),
            "global41" => Ok(Self::global41()),
            other if other.contains(',') || other.chars().all(|c| c.is_ascii_digit()) || other.contains('.') => {
                let mut free = Vec::new();
                for item in other.split(',').map(str::trim).filter(|s| !s.is_empty()) {
                    let index = match item.parse::<usize>() {
                        Ok(i) => i,
                        Err(_) => (0..POSE_DIM)
                            .find(|&i| dof_name(i) == item)
                            .ok_or_else(|| ModelError::Mask(format!("unknown DOF '{item}'")))?,
                    };
                    free.push(index);
                }
                Self::custom(free)
            }
            other => Err(ModelError::UnknownMask(other.to_string())),
        }
    }

    pub fn dim(&self) -> usize {
        self.free.len()
    }

    /// The free entries of `pose`.
    pub fn gather(&self, pose: &Pose) -> Vec<f64> {
        self.free.iter().map(|&i| pose[i]).collect()
    }

    /// Writes `x` (one value per free DOF) into `pose`, leaving the fixed entries as they are.
    pub fn scatter(&self, x: &[f64], pose: &mut Pose) {
        for (&i, &v) in self.free.iter().zip(x) {
            pose[i] = v;
        }
    }
}

/// A box constraint per pose entry (fixed entries keep their box too, so a mask can change).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Bounds {
    pub lower: Vec<f64>,
    pub upper: Vec<f64>,
}

/// Half-range of the `local` box: 0.4 m translation, 15° rotations (papers/000 §4.1: a 0.8 m /
/// 30° range around the start pose).
pub const LOCAL_TRANSLATION: f64 = 0.4;
pub const LOCAL_ROTATION_DEG: f64 = 15.0;
/// Translation box of the `global` scenario (papers/000 §4.2: [−1.25, 1.25] on every axis).
pub const GLOBAL_TRANSLATION: f64 = 1.25;

impl Bounds {
    /// The `local` box around `start`.
    pub fn local(start: &Pose) -> Self {
        Self::around(start, LOCAL_TRANSLATION, LOCAL_ROTATION_DEG.to_radians())
    }

    /// A box of half-ranges `translation` (m) and `rotation` (rad) around `start`.
    pub fn around(start: &Pose, translation: f64, rotation: f64) -> Self {
        let half = |i: usize| if i < 3 { translation } else { rotation };
        Self {
            lower: (0..POSE_DIM).map(|i| start[i] - half(i)).collect(),
            upper: (0..POSE_DIM).map(|i| start[i] + half(i)).collect(),
        }
    }

    /// The `global` box: translation ±1.25 m around the template's rest root position, rotations
    /// within the per-joint limits of papers/000 Table 1 ([`skeleton::rotation_limits_deg`]).
    pub fn global() -> Self {
        let mut lower = vec![-GLOBAL_TRANSLATION; POSE_DIM];
        let mut upper = vec![GLOBAL_TRANSLATION; POSE_DIM];
        for j in 0..NUM_JOINTS {
            let limits = skeleton::rotation_limits_deg(j);
            for a in 0..3 {
                lower[rot_offset(j) + a] = limits[a].0.to_radians();
                upper[rot_offset(j) + a] = limits[a].1.to_radians();
            }
        }
        Self { lower, upper }
    }

    pub fn contains(&self, pose: &Pose) -> bool {
        (0..POSE_DIM).all(|i| pose[i] >= self.lower[i] && pose[i] <= self.upper[i])
    }

    /// Clamps every entry of `pose` into the box.
    pub fn clamp(&self, pose: &mut Pose) {
        for i in 0..POSE_DIM {
            pose[i] = pose[i].clamp(self.lower[i], self.upper[i]);
        }
    }

    /// The box restricted to the free DOFs of `mask`.
    pub fn restrict(&self, mask: &DofMask) -> (Vec<f64>, Vec<f64>) {
        (mask.free.iter().map(|&i| self.lower[i]).collect(), mask.free.iter().map(|&i| self.upper[i]).collect())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn mask_sizes_match_papers() {
        // papers/000 §4: 57 → 43 (local) → 41 (global).
        assert_eq!(DofMask::full57().dim(), 57);
        assert_eq!(DofMask::local43().dim(), 43);
        assert_eq!(DofMask::global41().dim(), 41);
        let g = DofMask::global41();
        assert!(DofMask::local43().free.iter().filter(|i| !g.free.contains(i)).all(|&i| (i - 3) / 3 == skeleton::MIDDLE_TORSO));
    }

    #[test]
    fn parse_masks() {
        assert_eq!(DofMask::parse("local43").unwrap(), DofMask::local43());
        let m = DofMask::parse("0,1,2,head.rx").unwrap();
        assert_eq!(m.free, vec![0, 1, 2, rot_offset(skeleton::HEAD)]);
        assert!(DofMask::parse("local42").is_err());
        assert!(DofMask::parse("0,99").is_err());
    }

    #[test]
    fn gather_scatter_roundtrip() {
        let m = DofMask::global41();
        let mut pose = [0.0; POSE_DIM];
        let x: Vec<f64> = (0..m.dim()).map(|i| i as f64 * 0.01).collect();
        m.scatter(&x, &mut pose);
        assert_eq!(m.gather(&pose), x);
    }

    #[test]
    fn bounds_contain_rest_and_clamp() {
        let g = Bounds::global();
        assert!(g.contains(&[0.0; POSE_DIM]));
        let mut p = [10.0; POSE_DIM];
        g.clamp(&mut p);
        assert!(g.contains(&p));
        let l = Bounds::local(&[0.0; POSE_DIM]);
        assert!((l.upper[0] - l.lower[0] - 0.8).abs() < 1e-12);
        assert!((l.upper[10] - l.lower[10] - 30f64.to_radians()).abs() < 1e-12);
        assert!(pose_from_slice(&[0.0; 3]).is_err());
        let mut bad = [0.0; POSE_DIM];
        bad[5] = f64::NAN;
        assert!(matches!(pose_from_slice(&bad), Err(ModelError::PoseNotFinite { index: 5, .. })));
    }
}
