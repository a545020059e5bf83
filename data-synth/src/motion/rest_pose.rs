//! A BVH's rest pose given explicitly (`lfit motion import --rest-pose`), for captures whose
//! zero-channel pose is not a usable rest pose.
//!
//! [`crate::motion::retarget`] measures every BVH rotation from the zero-channel pose and aligns the
//! model's rest bones with that pose's bones by the minimal rotation. Some exporters write a
//! zero-channel pose whose bones all point along one axis (Character Creator / iClone: every
//! bone along +y, the legs *up* from the hips): a leg is then antiparallel to the model's and
//! the minimal rotation is a half turn about an arbitrary axis, so every limb gets an arbitrary
//! twist — bone directions still match (the bone-direction cosines stay near 1) but knees and
//! elbows bend about the wrong local axes. A rest-pose file names, for some BVH joints, the
//! world rotation (in the BVH's own axes, relative to the zero-channel pose) that puts the
//! skeleton into a proper rest pose (T-pose, legs straight down, feet forward); a joint not
//! named takes the rotation of its nearest named ancestor (the identity above them all).
//! [`rebase`] re-expresses the clip relative to that pose: offsets `o'_j = R_p o_j`, end sites
//! `R_j e_j`, local rotations `L'_j = R_p L_j R_jᵀ` (`R_p` the parent's rest rotation, identity
//! for the root), position channels of non-root joints `R_p t_j`. Every frame's world positions
//! are unchanged and its world rotations become `W_j R_jᵀ`; the rest pose is the new
//! zero-channel pose.
//!
//! **Neutral joints.** The retargeter aligns each model joint's rest bones with the BVH's by
//! direction (what turns a T-pose capture into an A-pose model). Where two rigs place their trunk
//! joints differently that is wrong: Character Creator's waist bone leans 10° forward in a
//! standing pose, the CMU-style rig's lower-back bone 26° back, so direction alignment pitches
//! the model's pelvis 30° forward whenever the capture stands upright (and the bones above
//! compensate). The file may list BVH joints as `"neutral"`: their rest pose and the model's
//! rest pose are the same orientation (both upright), so their model joints take the identity
//! alignment — the rotation from the rest pose is copied as it is — and the bone directions of
//! the two skeletons are left to differ there ([`retarget_neutral`]). A mapped joint without
//! mapped descendants (a head, a hand) that is not neutral takes the alignment of its nearest
//! mapped ancestor, as in the retargeter.
//!
//! **File format** (JSON): `{"description": "...", "joints": {"BvhJoint": "Z 180", ...},
//! "neutral": ["BvhJoint", ...]}` (without `"neutral"` the joints object may stand at the top
//! level); a rotation is a sequence of `axis degrees` pairs, applied left to right as in a BVH
//! channel list (`"Y 180 X -90"` is `R_y(180°) R_x(−90°)`); `""` is the identity.

use std::path::{Path, PathBuf};

use glam::{DMat3, DVec3};

use lfit_model::template::Template;

use crate::motion::bvh::{Axis, Bvh, BvhJoint, Channel};
use crate::motion::retarget::{JointMap, MotionError, RetargetOptions, Retargeted, Retargeter};

/// World rotations of named BVH joints in the rest pose, and the neutral joints (module docs).
#[derive(Debug, Clone, PartialEq)]
pub struct RestPose {
    pub joints: Vec<(String, DMat3)>,
    pub neutral: Vec<String>,
}

fn parse_rotation(spec: &str) -> Result<DMat3, String> {
    let words: Vec<&str> = spec.split_whitespace().collect();
    if words.len() % 2 != 0 {
        return Err(format!(
            "'{spec}' is not a list of 'axis degrees' pairs (e.g. \"Y 180 X -90\")"
        ));
    }
    let mut r = DMat3::IDENTITY;
    for pair in words.chunks(2) {
        let axis = match pair[0] {
            "X" | "x" => Axis::X,
            "Y" | "y" => Axis::Y,
            "Z" | "z" => Axis::Z,
            other => return Err(format!("'{other}' in '{spec}' is not an axis (X, Y or Z)")),
        };
        let degrees: f64 = pair[1]
            .parse()
            .ok()
            .filter(|d: &f64| d.is_finite())
            .ok_or_else(|| format!("'{}' in '{spec}' is not a number of degrees", pair[1]))?;
        r *= axis.rotation(degrees.to_radians());
    }
    Ok(r)
}

impl RestPose {
    pub fn parse(text: &str) -> Result<Self, String> {
        let top: serde_json::Value =
            serde_json::from_str(text).map_err(|e| format!("malformed JSON ({e})"))?;
        let serde_json::Value::Object(top) = top else {
            return Err("expected a JSON object".into());
        };
        let mut neutral = Vec::new();
        match top.get("neutral") {
            None => {}
            Some(serde_json::Value::Array(names)) => {
                for n in names {
                    let serde_json::Value::String(n) = n else {
                        return Err("\"neutral\" holds something other than joint names".into());
                    };
                    neutral.push(n.clone());
                }
            }
            Some(_) => return Err("\"neutral\" is not a list of BVH joint names".into()),
        }
        let joints = top.get("joints").cloned();
        let entries = match joints {
            Some(serde_json::Value::Object(o)) => o,
            Some(_) => return Err("\"joints\" is not an object".into()),
            None if !neutral.is_empty() => {
                return Err("a file with \"neutral\" needs its rotations under \"joints\"".into());
            }
            None => top
                .into_iter()
                .filter(|(k, _)| k != "description" && k != "neutral")
                .collect(),
        };
        if entries.is_empty() && neutral.is_empty() {
            return Err("the rest pose names no joint".into());
        }
        let mut joints = Vec::new();
        for (name, value) in entries {
            let serde_json::Value::String(spec) = value else {
                return Err(format!(
                    "the value of \"{name}\" is not a rotation string such as \"Z 180\""
                ));
            };
            let r = parse_rotation(&spec).map_err(|e| format!("joint \"{name}\": {e}"))?;
            joints.push((name, r));
        }
        Ok(Self { joints, neutral })
    }

    pub fn read(path: &Path) -> Result<Self, MotionError> {
        let text = std::fs::read_to_string(path).map_err(|source| MotionError::Read {
            path: PathBuf::from(path),
            source,
        })?;
        Self::parse(&text)
            .map_err(|e| MotionError::Invalid(format!("rest pose {}: {e}", path.display())))
    }

    /// The rest world rotation of every joint of `bvh` (named joints, else the nearest named
    /// ancestor's, else the identity).
    pub fn resolve(&self, bvh: &Bvh) -> Result<Vec<DMat3>, MotionError> {
        let mut named: Vec<Option<DMat3>> = vec![None; bvh.joints.len()];
        for (name, r) in &self.joints {
            let Some(j) = bvh.joint_index(name) else {
                return Err(MotionError::Invalid(format!(
                    "the rest pose names BVH joint '{name}', which the BVH file does not have"
                )));
            };
            named[j] = Some(*r);
        }
        let mut out: Vec<DMat3> = Vec::with_capacity(bvh.joints.len());
        for (j, joint) in bvh.joints.iter().enumerate() {
            let inherited = joint.parent.map_or(DMat3::IDENTITY, |p| out[p]);
            out.push(named[j].unwrap_or(inherited));
        }
        Ok(out)
    }
}

fn same(a: DMat3, b: DMat3) -> bool {
    (a - b).to_cols_array().iter().all(|v| v.abs() < 1e-12)
}

/// The clip re-expressed relative to `rest` (module docs): same joints, channels and frames
/// count; world positions unchanged; world rotations `W_j R_jᵀ`.
pub fn rebase(bvh: &Bvh, rest: &RestPose) -> Result<Bvh, MotionError> {
    let r = rest.resolve(bvh)?;
    let parent_rest = |joint: &BvhJoint| joint.parent.map_or(DMat3::IDENTITY, |p| r[p]);
    // Channel sets the new local rotations and translations can be written in.
    for (j, joint) in bvh.joints.iter().enumerate() {
        let rotations = joint
            .channels
            .iter()
            .filter(|c| matches!(c, Channel::Rotation(_)))
            .count();
        let rp = parent_rest(joint);
        if joint.euler_order().is_none() && !(rotations == 0 && same(rp, r[j])) {
            return Err(MotionError::Invalid(format!(
                "BVH joint '{}' has {rotations} rotation channels; a rest pose can only turn joints with three (or none, when it turns them with their parent)",
                joint.name
            )));
        }
        let positions = joint.channels.len() - rotations;
        if joint.parent.is_some() && positions > 0 && positions < 3 && !same(rp, DMat3::IDENTITY) {
            return Err(MotionError::Invalid(format!(
                "BVH joint '{}' has {positions} position channels under a turned parent; a rest pose needs all three there",
                joint.name
            )));
        }
    }
    let joints: Vec<BvhJoint> = bvh
        .joints
        .iter()
        .enumerate()
        .map(|(j, joint)| {
            let rp = parent_rest(joint);
            BvhJoint {
                offset: if joint.parent.is_some() {
                    rp * joint.offset
                } else {
                    joint.offset
                },
                end_site: joint.end_site.map(|e| r[j] * e),
                ..joint.clone()
            }
        })
        .collect();
    let mut frames = Vec::with_capacity(bvh.frames.len());
    for values in &bvh.frames {
        let mut out = values.clone();
        for (j, joint) in bvh.joints.iter().enumerate() {
            let (local, t) = bvh.local(j, values);
            let rp = parent_rest(joint);
            let new_local = rp * local * r[j].transpose();
            let new_t: DVec3 = if joint.parent.is_some() { rp * t } else { t };
            let angles = joint
                .euler_order()
                .map(|o| o.from_matrix(new_local).map(f64::to_degrees));
            let mut k = 0;
            for (c, v) in joint
                .channels
                .iter()
                .zip(&mut out[joint.first_channel..joint.first_channel + joint.channels.len()])
            {
                match c {
                    Channel::Rotation(_) => {
                        if let Some(a) = angles {
                            *v = a[k];
                        }
                        k += 1;
                    }
                    Channel::Position(a) => {
                        *v = match a {
                            Axis::X => new_t.x,
                            Axis::Y => new_t.y,
                            Axis::Z => new_t.z,
                        }
                    }
                }
            }
        }
        frames.push(out);
    }
    Ok(Bvh {
        joints,
        frame_time: bvh.frame_time,
        frames,
    })
}

/// [`crate::motion::retarget::retarget`] with the identity rest alignment at the model joints of the
/// `neutral` BVH joints (module docs); a mapped model joint without mapped descendants that is
/// not neutral takes its nearest mapped ancestor's alignment afterwards, as the retargeter does.
pub fn retarget_neutral(
    bvh: &Bvh,
    map: &JointMap,
    template: &Template,
    options: &RetargetOptions,
    neutral: &[String],
) -> Result<Retargeted, MotionError> {
    if bvh.frames.is_empty() {
        return Err(MotionError::Invalid("the BVH file has no frames".into()));
    }
    let mut r = Retargeter::new(bvh, map, template, options)?;
    let mut is_neutral = vec![false; r.bvh_of.len()];
    for name in neutral {
        let Some(b) = bvh.joint_index(name) else {
            return Err(MotionError::Invalid(format!(
                "the rest pose lists BVH joint '{name}' as neutral, which the BVH file does not have"
            )));
        };
        let Some(m) = r.bvh_of.iter().position(|x| *x == Some(b)) else {
            return Err(MotionError::Invalid(format!(
                "the rest pose lists BVH joint '{name}' as neutral, but the joint map does not map it"
            )));
        };
        r.align[m] = DMat3::IDENTITY;
        is_neutral[m] = true;
    }
    // Joints without mapped descendants (neutral ones aside): the nearest mapped ancestor's
    // alignment (parents come before children in the rig, so ancestors are final when a joint is
    // reached).
    let parents: Vec<Option<usize>> = template.rig.joints.iter().map(|j| j.parent).collect();
    for m in 0..parents.len() {
        if r.bvh_of[m].is_none() || is_neutral[m] || r.bones.iter().any(|&(a, _)| a == m) {
            continue;
        }
        let mut k = parents[m];
        while let Some(p) = k {
            if r.bvh_of[p].is_some() {
                r.align[m] = r.align[p];
                break;
            }
            k = parents[p];
        }
    }
    let mut poses = Vec::with_capacity(bvh.frames.len());
    let (mut sum, mut count, mut min) = (0.0, 0usize, f64::INFINITY);
    for values in &bvh.frames {
        let params = r.frame(bvh, template, values);
        if params.iter().any(|v| !v.is_finite()) {
            return Err(MotionError::Invalid(
                "retargeting produced a non-finite pose (degenerate skeleton?)".into(),
            ));
        }
        for c in r.bone_cosines(bvh, template, values, &params) {
            sum += c;
            count += 1;
            min = min.min(c);
        }
        poses.push(params);
    }
    Ok(Retargeted {
        poses,
        fps: 1.0 / bvh.frame_time,
        scale: r.scale,
        root_scale: r.root_scale,
        mapped: r.bvh_of.iter().filter(|b| b.is_some()).count(),
        cosine_mean: if count > 0 {
            sum / count as f64
        } else {
            f64::NAN
        },
        cosine_min: if count > 0 { min } else { f64::NAN },
        bones: r.bones.len(),
    })
}

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod tests {
    use super::*;

    fn rand_unit(seed: &mut u64) -> f64 {
        *seed = seed
            .wrapping_mul(6_364_136_223_846_793_005)
            .wrapping_add(1_442_695_040_888_963_407);
        ((*seed >> 11) as f64) / ((1u64 << 53) as f64)
    }

    /// A small chain with a branch, mixed channel orders, position channels at the root and at
    /// one child, and end sites; random frames.
    fn clip() -> Bvh {
        let text = "HIERARCHY
ROOT Hips
{
  OFFSET 1 2 3
  CHANNELS 6 Xposition Yposition Zposition Zrotation Yrotation Xrotation
  JOINT Thigh
  {
    OFFSET 10 -2 0
    CHANNELS 3 Xrotation Zrotation Yrotation
    JOINT Calf
    {
      OFFSET 0 45 0
      CHANNELS 6 Xposition Yposition Zposition Yrotation Xrotation Zrotation
      End Site
      {
        OFFSET 0 40 1
      }
    }
  }
  JOINT Waist
  {
    OFFSET 0 8 1
    CHANNELS 3 Zrotation Xrotation Yrotation
    End Site
    {
      OFFSET 0 30 0
    }
  }
}
MOTION
Frames: 1
Frame Time: 0.5
0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0
";
        let mut bvh = Bvh::parse(text).unwrap();
        let mut seed = 7u64;
        bvh.frames = (0..6)
            .map(|_| {
                (0..bvh.num_channels())
                    .map(|_| 360.0 * rand_unit(&mut seed) - 180.0)
                    .collect()
            })
            .collect();
        bvh
    }

    fn end_positions(bvh: &Bvh, values: &[f64]) -> Vec<DVec3> {
        let pose = bvh.pose(values);
        bvh.joints
            .iter()
            .enumerate()
            .filter_map(|(j, joint)| {
                joint
                    .end_site
                    .map(|e| pose.positions[j] + pose.rotations[j] * e)
            })
            .collect()
    }

    #[test]
    fn rotation_strings_parse_and_bad_ones_are_refused() {
        let r = parse_rotation("Y 180 X -90").unwrap();
        let expected =
            Axis::Y.rotation(std::f64::consts::PI) * Axis::X.rotation(-std::f64::consts::FRAC_PI_2);
        assert!(same(r, expected));
        // y ↦ z, z ↦ y, x ↦ −x: a foot pointing forward from a bone along +y.
        assert!((r * DVec3::Y - DVec3::Z).length() < 1e-12);
        assert!(same(parse_rotation("").unwrap(), DMat3::IDENTITY));
        assert!(parse_rotation("Z").is_err());
        assert!(parse_rotation("W 10").is_err());
        assert!(parse_rotation("Z ten").is_err());
        assert!(parse_rotation("Z inf").is_err());
        let p = RestPose::parse("{\"description\": \"x\", \"joints\": {\"Thigh\": \"Z 180\"}}")
            .unwrap();
        assert_eq!(p.joints.len(), 1);
        let q = RestPose::parse("{\"Thigh\": \"Z 180\", \"description\": \"x\"}").unwrap();
        assert_eq!(p, q);
        assert!(RestPose::parse("{\"joints\": {}}").is_err());
        let n = RestPose::parse("{\"joints\": {}, \"neutral\": [\"Hips\", \"Waist\"]}").unwrap();
        assert_eq!(n.neutral, ["Hips", "Waist"]);
        assert!(n.joints.is_empty());
        assert!(RestPose::parse("{\"joints\": {}, \"neutral\": \"Hips\"}").is_err());
        assert!(RestPose::parse("{\"joints\": {}, \"neutral\": [1]}").is_err());
        assert!(RestPose::parse("{\"Thigh\": \"Z 180\", \"neutral\": [\"Hips\"]}").is_err());
        assert!(RestPose::parse("{\"joints\": {\"Thigh\": 180}}").is_err());
        assert!(RestPose::parse("[1]").is_err());
        let missing = RestPose::parse("{\"Knee\": \"Z 180\"}").unwrap();
        assert!(rebase(&clip(), &missing).is_err());
    }

    #[test]
    fn rebasing_keeps_world_positions_and_turns_world_rotations() {
        let bvh = clip();
        let rest = RestPose::parse(
            "{\"joints\": {\"Thigh\": \"Z 180\", \"Calf\": \"Z 180 X 30\", \"Waist\": \"Y 40\"}}",
        )
        .unwrap();
        let r = rest.resolve(&bvh).unwrap();
        // Hips is above every named joint: the identity.
        assert!(same(r[0], DMat3::IDENTITY));
        let out = rebase(&bvh, &rest).unwrap();
        assert_eq!(out.frames.len(), bvh.frames.len());
        let mut worst: f64 = 0.0;
        for (a, b) in bvh.frames.iter().zip(&out.frames) {
            let (pa, pb) = (bvh.pose(a), out.pose(b));
            for j in 0..bvh.joints.len() {
                worst = worst.max((pa.positions[j] - pb.positions[j]).length());
                let turned = pa.rotations[j] * r[j].transpose();
                worst = worst.max(
                    (turned - pb.rotations[j])
                        .to_cols_array()
                        .iter()
                        .fold(0.0, |m: f64, v| m.max(v.abs())),
                );
            }
            for (x, y) in end_positions(&bvh, a).iter().zip(end_positions(&out, b)) {
                worst = worst.max((*x - y).length());
            }
        }
        assert!(worst < 1e-9, "worst difference {worst}");
        // The new zero pose is the rest pose: the thigh (turned a half turn about z) now points
        // down from the hips, as the calf's offset does.
        let zero = vec![0.0; out.num_channels()];
        let p = out.pose(&zero);
        assert!((p.positions[2] - p.positions[1] - DVec3::new(0.0, -45.0, 0.0)).length() < 1e-9);
        // A joint with fewer than three rotation channels cannot be turned.
        let mut two = bvh.clone();
        two.joints[3].channels.pop();
        assert!(rebase(&two, &rest).is_err());
    }
}
