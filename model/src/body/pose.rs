//! The pose vector of SPEC §3, DOF masks and bounds.
//!
//! A pose is 57 numbers: `[t_x, t_y, t_z, r_0 (3), ..., r_17 (3)]`, root translation in metres
//! followed by one axis-angle rotation per joint, relative to its parent.

use serde::{Deserialize, Serialize};

use crate::error::{ModelError, Result};
use crate::layout::{Block, Layout};
use crate::skeleton::{self, NUM_JOINTS};
use crate::template::Template;

/// Length of the pose vector: root translation + 3 per joint.
pub const POSE_DIM: usize = 3 + 3 * NUM_JOINTS;

/// A pose vector of the default 18-joint skeleton.
pub type Pose = [f64; POSE_DIM];

pub use crate::layout::rot_offset;

/// Checks a user-given pose: right length, all finite.
pub fn pose_from_slice(values: &[f64]) -> Result<Pose> {
    if values.len() != POSE_DIM {
        return Err(ModelError::PoseLength {
            got: values.len(),
            expected: POSE_DIM,
        });
    }
    if let Some((index, &value)) = values.iter().enumerate().find(|(_, v)| !v.is_finite()) {
        return Err(ModelError::PoseNotFinite { index, value });
    }
    let mut pose = [0.0; POSE_DIM];
    pose.copy_from_slice(values);
    Ok(pose)
}

/// A parameter vector of the rigid default skeleton as a [`Pose`] (its first 57 entries; a
/// shorter vector is padded with zeros). For the parts of lfit that still work on that template
/// only, which check the model before they get here.
pub fn as_pose(v: &[f64]) -> Pose {
    std::array::from_fn(|i| v.get(i).copied().unwrap_or(0.0))
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
        Self {
            name: "full57".into(),
            free: (0..POSE_DIM).collect(),
        }
    }

    /// papers/000 §4: drop all 3 DOFs of both feet and 2 DOFs each of both ankles and both hands
    /// (each keeps its flexion axis, see [`skeleton::KEPT_AXIS`]): 43 free.
    pub fn local43() -> Self {
        let free = (0..POSE_DIM)
            .filter(|&i| !Self::dropped_default(MaskKind::Local, i))
            .collect();
        Self {
            name: "local43".into(),
            free,
        }
    }

    /// papers/000 §4.2: `local43` minus 2 DOFs of Middle Torso: 41 free.
    pub fn global41() -> Self {
        let free = (0..POSE_DIM)
            .filter(|&i| !Self::dropped_default(MaskKind::Global, i))
            .collect();
        Self {
            name: "global41".into(),
            free,
        }
    }

    /// Whether pose entry `i` of the default skeleton is dropped by `kind`.
    fn dropped_default(kind: MaskKind, i: usize) -> bool {
        i >= 3 && Self::drops(kind, (i - 3) / 3, (i - 3) % 3)
    }

    /// papers/000 §4's rule: whether `kind` drops rotation axis `axis` of the joint in the place of
    /// papers/000 joint `role` (both feet whole; two of the three DOFs of the ankles and hands, and
    /// for `global` of Middle Torso, each keeping [`skeleton::KEPT_AXIS`]).
    fn drops(kind: MaskKind, role: usize, axis: usize) -> bool {
        match kind {
            MaskKind::Full => false,
            MaskKind::Local | MaskKind::Global => {
                if skeleton::is_foot(role) {
                    return true;
                }
                if skeleton::is_ankle(role)
                    || skeleton::is_hand(role)
                    || (kind == MaskKind::Global && role == skeleton::MIDDLE_TORSO)
                {
                    return Some(axis) != skeleton::KEPT_AXIS[role];
                }
                false
            }
        }
    }

    /// The mask `kind` of papers/000 §4 on any model: its rules (drop both feet, two of the three
    /// DOFs of both ankles and both hands, and for `global` of Middle Torso, each keeping the axis
    /// of [`skeleton::KEPT_AXIS`]) apply to the model joints that its joint map puts in those
    /// places; the shape and expression entries are free when `shape_free`. On the default
    /// skeleton this is exactly `full57`, `local43` and `global41`; elsewhere the name is the
    /// kind and the count (`local65`).
    pub fn standard(kind: MaskKind, template: &Template, shape_free: bool) -> Self {
        let layout = template.layout();
        let map = &template.info.joint_map;
        let role = |j: usize| map.iter().position(|m| *m == Some(j));
        let dropped = |i: usize| -> bool {
            let Some((j, axis)) = layout.rotation_of(i) else {
                return false;
            };
            role(j).is_some_and(|r| Self::drops(kind, r, axis))
        };
        let free: Vec<usize> = (0..layout.dim())
            .filter(|&i| match layout.block_of(i) {
                Some(Block::Shape | Block::Expression) => shape_free,
                _ => !dropped(i),
            })
            .collect();
        let name = if layout.dim() == POSE_DIM && template.is_default_skeleton() {
            match kind {
                MaskKind::Full => "full57".to_string(),
                MaskKind::Local => "local43".to_string(),
                MaskKind::Global => "global41".to_string(),
            }
        } else {
            format!("{}{}", kind.name(), free.len())
        };
        Self { name, free }
    }

    /// Parses a mask for `template`: `full`, `local`, `global` (shape and expression free; with
    /// `:pose` appended, fixed), the default skeleton's `full57`, `local43`, `global41`, or a
    /// comma-separated list of indices or entry names (`l_knee.rx`, `shape.0`).
    pub fn parse_for(spec: &str, template: &Template) -> Result<Self> {
        let (base, pose_only) = match spec.strip_suffix(":pose") {
            Some(b) => (b, true),
            None => (spec, false),
        };
        let kind = match base {
            "full" | "full57" => Some(MaskKind::Full),
            "local" | "local43" => Some(MaskKind::Local),
            "global" | "global41" => Some(MaskKind::Global),
            _ => None,
        };
        if let Some(kind) = kind {
            let mask = Self::standard(kind, template, !pose_only);
            if base.ends_with(char::is_numeric) && mask.name != base {
                return Err(ModelError::Mask(format!(
                    "'{base}' is the default skeleton's mask; on '{}' use '{}'",
                    template.id,
                    kind.name()
                )));
            }
            return Ok(mask);
        }
        let layout = template.layout();
        let mut free = Vec::new();
        for item in spec.split(',').map(str::trim).filter(|s| !s.is_empty()) {
            let index = match item.parse::<usize>() {
                Ok(i) => i,
                Err(_) => layout.index_of(item).ok_or_else(|| {
                    ModelError::Mask(format!(
                        "unknown entry '{item}' (names like t_x, {}.rx, shape.0)",
                        layout.joints[0]
                    ))
                })?,
            };
            if index >= layout.dim() {
                return Err(ModelError::Mask(format!(
                    "index {index} out of range 0..{}",
                    layout.dim()
                )));
            }
            free.push(index);
        }
        if free.is_empty() {
            return Err(ModelError::UnknownMask(spec.to_string()));
        }
        Self::custom_in(free, layout.dim())
    }

    /// A user mask from explicit indices.
    pub fn custom(free: Vec<usize>) -> Result<Self> {
        Self::custom_in(free, POSE_DIM)
    }

    /// A user mask from explicit indices into a parameter vector of `dim` entries.
    pub fn custom_in(mut free: Vec<usize>, dim: usize) -> Result<Self> {
        free.sort_unstable();
        free.dedup();
        if free.is_empty() {
            return Err(ModelError::Mask("a mask must free at least one DOF".into()));
        }
        if let Some(&bad) = free.iter().find(|&&i| i >= dim) {
            return Err(ModelError::Mask(format!(
                "index {bad} out of range 0..{dim}"
            )));
        }
        Ok(Self {
            name: "custom".into(),
            free,
        })
    }

    /// Parses `full57`, `local43`, `global41` or a comma-separated list of indices or DOF names.
    pub fn parse(spec: &str) -> Result<Self> {
        match spec {
            "full57" => Ok(Self::full57()),
            "local43" => Ok(Self::local43()),
            "global41" => Ok(Self::global41()),
            other
                if other.contains(',')
                    || other.chars().all(|c| c.is_ascii_digit())
                    || other.contains('.') =>
            {
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
    pub fn gather(&self, pose: &[f64]) -> Vec<f64> {
        self.free.iter().map(|&i| pose[i]).collect()
    }

    /// Writes `x` (one value per free DOF) into `pose`, leaving the fixed entries as they are.
    pub fn scatter(&self, x: &[f64], pose: &mut [f64]) {
        for (&i, &v) in self.free.iter().zip(x) {
            pose[i] = v;
        }
    }
}

/// The standard masks of papers/000 §4 ([`DofMask::standard`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum MaskKind {
    Full,
    Local,
    Global,
}

impl MaskKind {
    pub fn name(self) -> &'static str {
        match self {
            MaskKind::Full => "full",
            MaskKind::Local => "local",
            MaskKind::Global => "global",
        }
    }
}

/// Box of every shape and expression coefficient, in standard deviations of the model's shape
/// space: ±3, the range of the shape prior's mass that SMPL-family fitting works in.
pub const SHAPE_BOUND: f64 = 3.0;

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
/// Half-width of the floor square on which synthesis places the root of local and global frames
/// (x and z within ±0.6 m of the origin): the frames every shipped network was trained on.
pub const FLOOR_SPREAD: f64 = 0.6;
/// Translation box of the `global` scenario (papers/000 §4.2: [−1.25, 1.25] on every axis).
pub const GLOBAL_TRANSLATION: f64 = 1.25;

impl Bounds {
    /// The `local` box around `start` (a pose of the default skeleton: translation then
    /// rotations; see [`Bounds::local_in`] for any layout).
    pub fn local(start: &[f64]) -> Self {
        Self::around(start, LOCAL_TRANSLATION, LOCAL_ROTATION_DEG.to_radians())
    }

    /// A box of half-ranges `translation` (m, the first 3 entries) and `rotation` (rad, every
    /// other entry) around `start`.
    pub fn around(start: &[f64], translation: f64, rotation: f64) -> Self {
        let half = |i: usize| if i < 3 { translation } else { rotation };
        Self {
            lower: (0..start.len()).map(|i| start[i] - half(i)).collect(),
            upper: (0..start.len()).map(|i| start[i] + half(i)).collect(),
        }
    }

    /// The `local` box around `start` for a model with this layout: translation ±0.4 m, rotations
    /// ±15° around the start, shape and expression within ±[`SHAPE_BOUND`].
    pub fn local_in(layout: &Layout, start: &[f64]) -> Self {
        Self::around_in(
            layout,
            start,
            LOCAL_TRANSLATION,
            LOCAL_ROTATION_DEG.to_radians(),
        )
    }

    /// [`Bounds::around`] for any layout: shape and expression within ±[`SHAPE_BOUND`].
    pub fn around_in(layout: &Layout, start: &[f64], translation: f64, rotation: f64) -> Self {
        let mut b = Self::around(&start[..layout.pose_dim()], translation, rotation);
        b.lower.resize(layout.dim(), -SHAPE_BOUND);
        b.upper.resize(layout.dim(), SHAPE_BOUND);
        b
    }

    /// The `global` box of `template`: translation ±1.25 m, rotations within the model's
    /// per-joint limits, shape and expression within ±[`SHAPE_BOUND`]. On the default template
    /// this is [`Bounds::global`].
    pub fn global_for(template: &Template) -> Self {
        Self::global_from_limits(&template.info.limits_deg, template.morph.coefficients())
    }

    /// [`Bounds::global_for`] with its ±1.25 m translation box around `start`'s root translation
    /// instead of the origin: the box of a frame whose start is a rigid alignment to its data
    /// (`lfit data import`: a capture's subject stands wherever the lab's volume has them, not
    /// within 1.25 m of its origin). A start at the origin (every synthetic global frame's) gives
    /// [`Bounds::global_for`] exactly.
    pub fn global_around(template: &Template, start: &[f64]) -> Self {
        let mut b = Self::global_for(template);
        for ((lower, upper), s) in b.lower.iter_mut().zip(&mut b.upper).zip(&start[..3]) {
            *lower += s;
            *upper += s;
        }
        b
    }

    /// Translation ±1.25 m, rotations within `limits_deg` (per joint and axis), then
    /// `coefficients` shape/expression entries within ±[`SHAPE_BOUND`].
    fn global_from_limits(limits_deg: &[[[f64; 2]; 3]], coefficients: usize) -> Self {
        let mut lower = vec![-GLOBAL_TRANSLATION; 3];
        let mut upper = vec![GLOBAL_TRANSLATION; 3];
        for range in limits_deg.iter().flatten() {
            lower.push(range[0].to_radians());
            upper.push(range[1].to_radians());
        }
        lower.extend(std::iter::repeat_n(-SHAPE_BOUND, coefficients));
        upper.extend(std::iter::repeat_n(SHAPE_BOUND, coefficients));
        Self { lower, upper }
    }

    /// The `global` box: translation ±1.25 m around the template's rest root position, rotations
    /// within the per-joint limits of papers/000 Table 1 ([`skeleton::rotation_limits_deg`]).
    pub fn global() -> Self {
        Self::global_from_limits(&crate::info::ModelInfo::default_skeleton().limits_deg, 0)
    }

    pub fn contains(&self, pose: &[f64]) -> bool {
        pose.len() == self.lower.len()
            && (0..pose.len()).all(|i| pose[i] >= self.lower[i] && pose[i] <= self.upper[i])
    }

    /// Clamps every entry of `pose` into the box.
    pub fn clamp(&self, pose: &mut [f64]) {
        for i in 0..pose.len().min(self.lower.len()) {
            pose[i] = pose[i].clamp(self.lower[i], self.upper[i]);
        }
    }

    /// The box restricted to the free DOFs of `mask`.
    pub fn restrict(&self, mask: &DofMask) -> (Vec<f64>, Vec<f64>) {
        (
            mask.free.iter().map(|&i| self.lower[i]).collect(),
            mask.free.iter().map(|&i| self.upper[i]).collect(),
        )
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
        assert!(
            DofMask::local43()
                .free
                .iter()
                .filter(|i| !g.free.contains(i))
                .all(|&i| (i - 3) / 3 == skeleton::MIDDLE_TORSO)
        );
    }

    #[test]
    fn standard_masks_on_the_default_and_on_other_models() {
        let d = crate::default_template();
        assert_eq!(
            DofMask::standard(MaskKind::Local, &d, true),
            DofMask::local43()
        );
        assert_eq!(
            DofMask::standard(MaskKind::Global, &d, false),
            DofMask::global41()
        );
        assert_eq!(
            DofMask::standard(MaskKind::Full, &d, true),
            DofMask::full57()
        );
        assert_eq!(
            DofMask::parse_for("local43", &d).unwrap(),
            DofMask::local43()
        );
        assert_eq!(Bounds::global_for(&d), Bounds::global());
        let (m, _) = crate::body::morphable_default_template().unwrap();
        let local = DofMask::parse_for("local", &m).unwrap();
        assert_eq!(local.name, "local51");
        assert_eq!(&local.free[..43], &DofMask::local43().free[..]);
        assert_eq!(
            DofMask::parse_for("local:pose", &m).unwrap().free,
            DofMask::local43().free
        );
        assert!(
            DofMask::parse_for("local43", &m)
                .unwrap_err()
                .to_string()
                .contains("use 'local'")
        );
        assert_eq!(
            DofMask::parse_for("shape.0,t_x", &m).unwrap().free,
            vec![0, 57]
        );
        let g = Bounds::global_for(&m);
        assert_eq!(g.lower.len(), 65);
        assert_eq!((g.lower[60], g.upper[60]), (-SHAPE_BOUND, SHAPE_BOUND));
        let smpl = crate::body::smpl_like(1, 120, 3, false);
        let l = DofMask::standard(MaskKind::Local, &smpl, true);
        // SMPL's feet drop 6, ankles and wrists keep one axis each (−8): 3 + 72 + 3 − 14.
        assert_eq!(l.dim(), 3 + 72 + 3 - 14, "{}", l.name);
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
        assert!(matches!(
            pose_from_slice(&bad),
            Err(ModelError::PoseNotFinite { index: 5, .. })
        ));
    }
}
