//! Augmentation of motion-file frames: more poses out of the same captured motion.
//!
//! A trained fitter meets motion its training frames never held (another studio, another
//! subject's way of moving). Three transforms of a motion file's frames, each keeping the
//! motion a person can make, widen what a few hundred captured clips teach:
//!
//! - **mirror** (probability ½): the left–right mirror image. Joints swap with their partner by
//!   name (`Left…`/`Right…`, `L…`/`R…` before a capital, `l_`/`r_`, `_l`/`_r`, `.L`/`.R`), each
//!   rotation reflects through the sagittal plane x = 0 (axis-angle `(x, y, z) → (x, −y, −z)`,
//!   valid because a model's joint rotations act in frames aligned with the world at rest) and
//!   the root's x flips. Refused for a model whose rest skeleton is not left–right symmetric
//!   (a joint's partner more than [`SYMMETRY_TOLERANCE`] from its mirror image).
//! - **heading**: the motion turned about the world's vertical (y) axis by a uniform angle —
//!   each body about its root, the root's path about the origin, so a sequence travels the way
//!   it now faces — and every direction of travel and facing is seen, not only the studio's.
//! - **jitter_deg**: every joint but the root turned by a small rotation of its own (each axis
//!   normal with this standard deviation, degrees), the same for every frame the transform is
//!   applied to (a sequence stays as smooth as the file): poses near the captured ones, e.g.
//!   a deeper crouch or a wider arm.
//!
//! One draw ([`Augmenter::draw`]) is applied to a frame and to the frame it starts from (or to
//! every frame of a sequence), so the step between them stays the file's (mirrored, turned).
//! The draws come from their own random stream, so a configuration without augmentation gives
//! the datasets it gave before augmentation existed.

use glam::{DMat3, DQuat, DVec3};
use lfit_model::Template;
use rand::Rng;
use rand_distr::{Distribution, StandardNormal};
use serde::{Deserialize, Serialize};

/// The largest distance (metres) between a joint's partner and its mirror image (a joint on
/// the midline: between it and its own mirror image) at rest for a model to be mirrored.
pub const SYMMETRY_TOLERANCE: f64 = 0.02;

/// The largest jitter standard deviation accepted, degrees.
pub const MAX_JITTER_DEG: f64 = 45.0;

/// Which transforms motion-file frames go through (none by default).
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct MotionAugment {
    /// Mirror half the frames left–right.
    pub mirror: bool,
    /// Turn every frame about the vertical by a uniform heading.
    pub heading: bool,
    /// Standard deviation of each joint's extra rotation per axis, degrees (0: none).
    pub jitter_deg: f64,
}

impl MotionAugment {
    /// No transform at all.
    pub fn is_none(&self) -> bool {
        !self.mirror && !self.heading && self.jitter_deg == 0.0
    }

    /// [`Self::validate`] for a configuration with `files` motion files: a transform without
    /// files to transform is refused too (`give_them` says how to give them).
    pub fn validate_for(&self, files: usize, give_them: &str) -> Result<(), String> {
        if !self.is_none() && files == 0 {
            return Err(format!("transforms motion-file frames: {give_them}"));
        }
        self.validate()
    }

    /// Checks the values; the error names the bad one.
    pub fn validate(&self) -> Result<(), String> {
        if !(self.jitter_deg.is_finite() && (0.0..=MAX_JITTER_DEG).contains(&self.jitter_deg)) {
            return Err(format!(
                "jitter_deg = {} must be in [0, {MAX_JITTER_DEG}] degrees",
                self.jitter_deg
            ));
        }
        Ok(())
    }
}

/// One draw of the transforms.
#[derive(Debug, Clone, PartialEq)]
pub struct Transform {
    pub mirrored: bool,
    /// Turn about the vertical, radians.
    pub heading: f64,
    /// Extra rotation of each joint (axis-angle; the root's is zero).
    pub jitter: Vec<DVec3>,
}

/// [`MotionAugment`] bound to a model: its joints' mirror partners and root.
#[derive(Debug, Clone)]
pub struct Augmenter {
    config: MotionAugment,
    /// Partner of every joint (itself on the midline); `Some` when mirroring.
    partner: Option<Vec<usize>>,
    root_rest: DVec3,
    joints: usize,
}

/// The name of the other side's joint, if `name` says a side.
pub fn partner_name(name: &str) -> Option<String> {
    for (a, b) in [
        ("Left", "Right"),
        ("Right", "Left"),
        ("left", "right"),
        ("right", "left"),
        ("LEFT", "RIGHT"),
        ("RIGHT", "LEFT"),
    ] {
        if name.contains(a) {
            return Some(name.replacen(a, b, 1));
        }
    }
    let bytes = name.as_bytes();
    // `LHipJoint`, `RThumb`: a side letter before a capital.
    if bytes.len() >= 2 && (bytes[0] == b'L' || bytes[0] == b'R') && bytes[1].is_ascii_uppercase() {
        let other = if bytes[0] == b'L' { "R" } else { "L" };
        return Some(format!("{other}{}", &name[1..]));
    }
    for (a, b) in [("l_", "r_"), ("r_", "l_"), ("L_", "R_"), ("R_", "L_")] {
        if let Some(rest) = name.strip_prefix(a) {
            return Some(format!("{b}{rest}"));
        }
    }
    for (a, b) in [
        ("_l", "_r"),
        ("_r", "_l"),
        (".L", ".R"),
        (".R", ".L"),
        ("_L", "_R"),
        ("_R", "_L"),
    ] {
        if let Some(rest) = name.strip_suffix(a) {
            return Some(format!("{rest}{b}"));
        }
    }
    None
}

/// The left–right mirror image of an axis-angle rotation acting in a world-aligned frame.
pub fn mirror_rotvec(r: DVec3) -> DVec3 {
    DVec3::new(r.x, -r.y, -r.z)
}

fn rotvec(m: DMat3) -> DVec3 {
    let (axis, angle) = DQuat::from_mat3(&m).normalize().to_axis_angle();
    if angle.abs() < 1e-15 {
        DVec3::ZERO
    } else {
        // `to_axis_angle` gives angles in [0, 2π); keep the rotation vector short.
        let angle = if angle > std::f64::consts::PI {
            angle - std::f64::consts::TAU
        } else {
            angle
        };
        axis * angle
    }
}

fn matrix(r: DVec3) -> DMat3 {
    let angle = r.length();
    if angle < 1e-15 {
        DMat3::IDENTITY
    } else {
        DMat3::from_axis_angle(r / angle, angle)
    }
}

impl Augmenter {
    /// Binds `config` to `template`; mirroring a model that is not left–right symmetric, or
    /// whose joints' sides cannot be told from their names, is an error saying which joint.
    pub fn new(config: MotionAugment, template: &Template) -> Result<Self, String> {
        config.validate()?;
        let joints = &template.rig.joints;
        let partner = if config.mirror {
            let mut partner = Vec::with_capacity(joints.len());
            for (j, joint) in joints.iter().enumerate() {
                let p = match partner_name(&joint.name) {
                    Some(other) => template.rig.joint_index(&other).ok_or_else(|| {
                        format!(
                            "mirror: joint '{}' of model '{}' has no partner '{other}'",
                            joint.name, template.id
                        )
                    })?,
                    None => j,
                };
                let image = joint.rest() * DVec3::new(-1.0, 1.0, 1.0);
                let gap = (image - joints[p].rest()).length();
                if gap > SYMMETRY_TOLERANCE {
                    return Err(format!(
                        "mirror: model '{}' is not left-right symmetric: the mirror image of joint '{}' at rest is {:.3} m from '{}' (more than {SYMMETRY_TOLERANCE} m)",
                        template.id, joint.name, gap, joints[p].name
                    ));
                }
                partner.push(p);
            }
            Some(partner)
        } else {
            None
        };
        Ok(Self {
            config,
            partner,
            root_rest: joints.first().map(|j| j.rest()).unwrap_or(DVec3::ZERO),
            joints: joints.len(),
        })
    }

    pub fn config(&self) -> MotionAugment {
        self.config
    }

    /// One draw of the transforms from `rng`.
    pub fn draw(&self, rng: &mut impl Rng) -> Transform {
        let mirrored = self.config.mirror && rng.random_bool(0.5);
        let heading = if self.config.heading {
            rng.random_range(-std::f64::consts::PI..std::f64::consts::PI)
        } else {
            0.0
        };
        let sigma = self.config.jitter_deg.to_radians();
        let jitter = (0..self.joints)
            .map(|j| {
                if j == 0 || sigma == 0.0 {
                    DVec3::ZERO
                } else {
                    let mut n = || -> f64 { StandardNormal.sample(rng) };
                    DVec3::new(n(), n(), n()) * sigma
                }
            })
            .collect();
        Transform {
            mirrored,
            heading,
            jitter,
        }
    }

    /// Applies `t` to the pose part (translation, rotations) of `pose`; entries after it
    /// (shape, expression) are left alone.
    pub fn apply(&self, t: &Transform, pose: &mut [f64]) {
        let n = self.joints;
        let get = |p: &[f64], j: usize| DVec3::new(p[3 + 3 * j], p[4 + 3 * j], p[5 + 3 * j]);
        if t.mirrored {
            if let Some(partner) = &self.partner {
                let before = pose[..3 + 3 * n].to_vec();
                // The root's world x, j0.x + t.x, goes to its negative.
                pose[0] = -before[0] - 2.0 * self.root_rest.x;
                for (j, &p) in partner.iter().enumerate() {
                    let r = mirror_rotvec(get(&before, p));
                    pose[3 + 3 * j..6 + 3 * j].copy_from_slice(&r.to_array());
                }
            }
        }
        for (j, d) in t.jitter.iter().enumerate().skip(1) {
            if *d != DVec3::ZERO {
                let r = rotvec(matrix(get(pose, j)) * matrix(*d));
                pose[3 + 3 * j..6 + 3 * j].copy_from_slice(&r.to_array());
            }
        }
        if t.heading != 0.0 {
            let q = DMat3::from_rotation_y(t.heading);
            let root = rotvec(q * matrix(get(pose, 0)));
            pose[3..6].copy_from_slice(&root.to_array());
            // The root's world position j0 + t turns about the world's vertical axis too (a
            // sequence's path turns with its facing): t' = Q (j0 + t) − j0.
            let tr = DVec3::new(pose[0], pose[1], pose[2]);
            let moved = q * (self.root_rest + tr) - self.root_rest;
            pose[..3].copy_from_slice(&moved.to_array());
        }
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod tests {
    use super::*;
    use lfit_model::{Template, default_template};
    use rand::SeedableRng;
    use rand_chacha::ChaCha8Rng;

    #[test]
    fn partner_names_of_the_usual_conventions() {
        for (a, b) in [
            ("LeftUpLeg", "RightUpLeg"),
            ("RightForeArm", "LeftForeArm"),
            ("LHipJoint", "RHipJoint"),
            ("RThumb", "LThumb"),
            ("l_knee", "r_knee"),
            ("r_hand", "l_hand"),
            ("upperarm_l", "upperarm_r"),
            ("thigh.R", "thigh.L"),
            ("left_ankle", "right_ankle"),
        ] {
            assert_eq!(partner_name(a).as_deref(), Some(b), "{a}");
            assert_eq!(partner_name(b).as_deref(), Some(a), "{b}");
        }
        for midline in [
            "Hips",
            "Spine1",
            "LowerBack",
            "Head",
            "pelvis",
            "root",
            "Neck1",
        ] {
            assert_eq!(partner_name(midline), None, "{midline}");
        }
    }

    fn posed_points(template: &Template, pose: &[f64]) -> Vec<DVec3> {
        let mut p = pose.to_vec();
        p.resize(template.param_dim(), 0.0);
        lfit_model::skinning::joint_transforms(template, &p).joints
    }

    #[test]
    fn a_mirrored_pose_puts_every_joint_at_its_partners_mirror_image() {
        // The default model is symmetric to rounding; the MakeHuman body (CMU names) within
        // millimetres at rest, which a chain of joints adds up.
        let mh =
            std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../models/makehuman-cmu_mb.npz");
        let mh = lfit_model::modelfile::load(&mh).expect("models/makehuman-cmu_mb.npz");
        for (template, tolerance) in [(default_template(), 1e-9), (mh, 0.03)] {
            mirrored_joints_within(&template, tolerance);
        }
    }

    fn mirrored_joints_within(template: &Template, tolerance: f64) {
        let template = template.clone();
        let a = Augmenter::new(
            MotionAugment {
                mirror: true,
                ..Default::default()
            },
            &template,
        )
        .unwrap();
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        let n = template.rig.num_joints();
        let mut pose = vec![0.0; 3 + 3 * n];
        for v in pose.iter_mut() {
            *v = rng.random_range(-0.5..0.5);
        }
        let mut mirrored = pose.clone();
        let t = Transform {
            mirrored: true,
            heading: 0.0,
            jitter: vec![DVec3::ZERO; n],
        };
        a.apply(&t, &mut mirrored);
        assert_ne!(mirrored, pose);
        let before = posed_points(&template, &pose);
        let after = posed_points(&template, &mirrored);
        let partner = a.partner.clone().unwrap();
        for j in 0..n {
            let image = before[partner[j]] * DVec3::new(-1.0, 1.0, 1.0);
            assert!(
                (image - after[j]).length() < tolerance,
                "{}: joint {j}: {image} vs {}",
                template.id,
                after[j]
            );
        }
        // Twice is the identity.
        a.apply(&t, &mut mirrored);
        for (x, y) in mirrored.iter().zip(&pose) {
            assert!((x - y).abs() < 1e-12);
        }
    }

    #[test]
    fn a_heading_turns_the_posed_body_about_the_vertical_through_its_root() {
        let template = default_template();
        let a = Augmenter::new(
            MotionAugment {
                heading: true,
                ..Default::default()
            },
            &template,
        )
        .unwrap();
        let n = template.rig.num_joints();
        let mut rng = ChaCha8Rng::seed_from_u64(5);
        let mut pose = vec![0.0; 3 + 3 * n];
        for v in pose.iter_mut() {
            *v = rng.random_range(-0.5..0.5);
        }
        let t = Transform {
            mirrored: false,
            heading: 1.1,
            jitter: vec![DVec3::ZERO; n],
        };
        let mut turned = pose.clone();
        a.apply(&t, &mut turned);
        let before = posed_points(&template, &pose);
        let after = posed_points(&template, &turned);
        let q = DMat3::from_rotation_y(1.1);
        // Turned about the vertical through the root joint, up to where the root is.
        for j in 0..n {
            let expect = q * (before[j] - before[0]) + after[0];
            assert!((expect - after[j]).length() < 1e-9, "joint {j}");
        }
        assert!((after[0].y - before[0].y).abs() < 1e-12);
        // The joints' own rotations are untouched.
        assert_eq!(turned[6..], pose[6..]);
    }

    #[test]
    fn jitter_moves_joints_but_not_the_root_and_is_drawn_once_per_draw() {
        let template = default_template();
        let a = Augmenter::new(
            MotionAugment {
                jitter_deg: 10.0,
                ..Default::default()
            },
            &template,
        )
        .unwrap();
        let mut rng = ChaCha8Rng::seed_from_u64(7);
        let t = a.draw(&mut rng);
        assert!(!t.mirrored);
        assert_eq!(t.heading, 0.0);
        assert_eq!(t.jitter[0], DVec3::ZERO);
        let spread =
            t.jitter[1..].iter().map(|d| d.length()).sum::<f64>() / (t.jitter.len() - 1) as f64;
        // Mean length of a 3-d normal of σ = 10°: σ·√(8/π) ≈ 16°.
        assert!(
            (5f64.to_radians()..30f64.to_radians()).contains(&spread),
            "{spread}"
        );
        let n = template.rig.num_joints();
        let mut pose = vec![0.0; 3 + 3 * n];
        a.apply(&t, &mut pose);
        assert_eq!(pose[..6], [0.0; 6]);
        for j in 1..n {
            let r = DVec3::new(pose[3 + 3 * j], pose[4 + 3 * j], pose[5 + 3 * j]);
            assert!((r - t.jitter[j]).length() < 1e-9, "joint {j}");
        }
        // Same seed, same draw.
        assert_eq!(a.draw(&mut ChaCha8Rng::seed_from_u64(7)), t);
    }

    #[test]
    fn bad_settings_and_asymmetric_models_are_refused() {
        let template = default_template();
        for bad in [-1.0, 46.0, f64::NAN] {
            let e = Augmenter::new(
                MotionAugment {
                    jitter_deg: bad,
                    ..Default::default()
                },
                &template,
            )
            .unwrap_err();
            assert!(e.contains("jitter_deg"), "{e}");
        }
        let mut lopsided = template.clone();
        let k = lopsided
            .rig
            .joints
            .iter()
            .position(|j| partner_name(&j.name).is_some())
            .unwrap();
        lopsided.rig.joints[k].rest_position[1] += 0.05;
        let e = Augmenter::new(
            MotionAugment {
                mirror: true,
                ..Default::default()
            },
            &lopsided,
        )
        .unwrap_err();
        assert!(e.contains("not left-right symmetric"), "{e}");
        // Without mirroring the same model is fine.
        assert!(
            Augmenter::new(
                MotionAugment {
                    heading: true,
                    ..Default::default()
                },
                &lopsided
            )
            .is_ok()
        );
    }
}
