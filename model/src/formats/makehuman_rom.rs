//! Joint limits a human has, for the MakeHuman rigs (`lfit model import-makehuman`).
//!
//! Every joint of a known rig (`cmu_mb`, `game_engine`, `game_engine_with_breast`, `default`,
//! `default_no_toes`) gets the normal adult range of motion (ROM) of the anatomical joint its bone
//! stands for ([`kind_of`], [`movements`]):
//!
//! - **Sources.** The American Academy of Orthopaedic Surgeons' average ranges (AAOS: Greene &
//!   Heckman (eds.), *The Clinical Measurement of Joint Motion*, AAOS, 1994) for the limbs, the
//!   spine, the fingers and the toes; Soucie et al. 2011 ("Range of motion measurements: reference
//!   values and a database for comparison studies", *Haemophilia* 17(3):500–507; passive ROM of
//!   healthy adults) for knee flexion, which AAOS puts at 135°; Floyd (*Manual of Structural
//!   Kinesiology*, appendix 1) for the sternoclavicular and acromioclavicular joints, shoulder
//!   adduction in front of the trunk and finger abduction. Where no source gives a range — the
//!   side bend of a hinge, the axial twist of a joint that hardly has one, knee hyperextension
//!   and tibial rotation, foot abduction, the rigid pelvis links and palm bones — lfit allows a
//!   small slack of its own ([`Source::Lfit`]).
//! - **Shared ranges.** A movement that the body spreads over several rig joints is split evenly
//!   over them: the thoracolumbar range over the rig's spine joints (`cmu_mb`: `LowerBack`,
//!   `Spine`, `Spine1`, a third each; `game_engine`: `spine_01..03`; `default`: `spine01..05`, a
//!   fifth each), the cervical range over the neck joints and the head joint (`cmu_mb`: `Neck`,
//!   `Neck1`, `Head`; `game_engine`: `neck_01`, `head`; `default`: `neck01..03`, `head`), the
//!   shoulder girdle over `clavicle` and `shoulder01` (`default`), and a limb's axial rotation
//!   over its bone and the bone's twist segment (`default`: `upperleg01/02`, `lowerleg01/02`,
//!   `upperarm01/02`, `lowerarm01/02`).
//! - **Axes.** lfit's rotations are axis-angle vectors relative to the parent in the world-aligned
//!   rest frame (y up, the subject faces +z, +x is the subject's left), and a limit bounds each
//!   world component. Each anatomical joint has three movement axes, found from its rest bone
//!   `t` (head → tail, on the mean body): a first swing, whose positive angle moves the bone's tip
//!   towards a named direction `d` (axis `t × d`: hip flexion moves the knee towards +z, knee
//!   flexion the ankle towards −z, shoulder flexion the elbow towards +z, elbow flexion the wrist
//!   towards the shoulder, wrist and finger flexion towards the palm ...); a second swing
//!   perpendicular to it (`± t × u₁`, its sign by its own direction: abduction moves the tip
//!   laterally, for the arm laterally and up); and the twist about the bone (`±t`, positive when a reference
//!   direction turns towards another: internal rotation turns the front (+z) medially). On a
//!   vertical leg or spine these are the world axes; on MakeHuman's A-pose arm (42° below
//!   horizontal, the elbow bent 42°, the forearm and hand pointing forward) they are not, and
//!   the limit is the axis-aligned box around the anatomical one: `Σ_m θ_m u_m` over every
//!   `θ_m` within its range (exact on a world-aligned bone, looser on the arm, where a box of
//!   world components cannot hold a tilted one exactly).
//! - **Rest offsets.** Ranges are clinical angles from the anatomical neutral position; the rest
//!   pose is not neutral at the elbows (42° flexed), the knees (a few degrees) and the shoulders
//!   (the A-pose abducts the arm by 42°), so there the rest angle is subtracted.
//! - **The root** (the pelvis) is the body's global orientation: a person faces any direction,
//!   lies and falls, so it gets ±180° on every axis ([`ROOT_LIMIT_DEG`]). The energy's angle
//!   prior EA never counts the root; only a scenario box bounds it.
//! - Joints with no anatomical counterpart here (face, eyes, tongue, breasts) and every joint but
//!   the root of an unknown rig keep ±[`UNMAPPED_LIMIT_DEG`]. The thumb's movement axes in the
//!   rest pose are not worked out: its joints get symmetric boxes of their largest AAOS range.

use glam::DVec3;

use crate::error::{ModelError, Result};

/// Rotation range of the root (the body's global orientation), degrees either way.
pub const ROOT_LIMIT_DEG: f64 = 180.0;
/// Rotation range of the joints that the table does not cover (face, eyes, tongue, breasts; every
/// joint but the root of an unknown rig), degrees either way.
pub const UNMAPPED_LIMIT_DEG: f64 = 30.0;
/// Limits are rounded to 1/this of a degree.
const ROUND_PER_DEG: f64 = 10.0;

/// Where a range comes from.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Source {
    /// Greene & Heckman (eds.), *The Clinical Measurement of Joint Motion*, AAOS 1994.
    Aaos,
    /// Soucie et al. 2011, *Haemophilia* 17(3):500–507 (passive ROM, healthy adults).
    Soucie,
    /// Floyd, *Manual of Structural Kinesiology*, appendix 1.
    Floyd,
    /// lfit's choice: no source gives this range.
    Lfit,
}

impl Source {
    pub fn name(self) -> &'static str {
        match self {
            Source::Aaos => "AAOS",
            Source::Soucie => "Soucie 2011",
            Source::Floyd => "Floyd",
            Source::Lfit => "lfit",
        }
    }
}

/// One anatomical axis: `pos` degrees of `name`, `neg` degrees of `opposite`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Movement {
    pub name: &'static str,
    pub opposite: &'static str,
    pub pos: f64,
    pub neg: f64,
    /// Sources of `pos` and of `neg`.
    pub source: Source,
    pub opposite_source: Source,
}

const fn mv(
    name: &'static str,
    opposite: &'static str,
    pos: f64,
    neg: f64,
    source: Source,
) -> Movement {
    Movement {
        name,
        opposite,
        pos,
        neg,
        source,
        opposite_source: source,
    }
}

/// A movement whose opposite has another source.
const fn mv2(m: Movement, opposite_source: Source) -> Movement {
    Movement {
        opposite_source,
        ..m
    }
}

/// A symmetric slack of lfit's own.
const fn slack(name: &'static str, deg: f64) -> Movement {
    mv(name, name, deg, deg, Source::Lfit)
}

/// The anatomical joint a rig bone stands for.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum Kind {
    /// The pelvis: the global orientation.
    Root,
    /// A bone rigid in a human (pelvis halves from the pelvis centre to the hip joints).
    Rigid,
    /// Thoracolumbar spine (split over the rig's spine joints).
    Spine,
    /// Cervical spine and head (split over the rig's neck joints and its head joint).
    Neck,
    /// Shoulder girdle: sternoclavicular and acromioclavicular joints (the clavicle bone; split
    /// over the girdle bones).
    Girdle,
    /// Glenohumeral joint (the upper arm).
    Shoulder,
    /// Twist segment of the upper arm (`default`'s `upperarm02`).
    UpperArmTwist,
    /// Elbow and forearm rotation (the forearm).
    Elbow,
    /// Twist segment of the forearm (`default`'s `lowerarm02`).
    ForearmTwist,
    /// Wrist (the hand).
    Wrist,
    /// Palm bones (carpometacarpal joints of the fingers).
    Palm,
    /// Finger metacarpophalangeal, proximal and distal interphalangeal joints.
    FingerMcp,
    FingerPip,
    FingerDip,
    /// Thumb carpometacarpal (1), metacarpophalangeal (2) and interphalangeal (3) joints.
    Thumb(u8),
    /// Hip (the thigh).
    Hip,
    /// Twist segment of the thigh (`default`'s `upperleg02`).
    ThighTwist,
    /// Knee (the shank).
    Knee,
    /// Twist segment of the shank (`default`'s `lowerleg02`).
    ShankTwist,
    /// Ankle and subtalar joints (the foot).
    Ankle,
    /// Great toe metatarsophalangeal and interphalangeal joints (the one toe joint of
    /// `cmu_mb` and `game_engine` is the great toe's MTP).
    GreatToeMtp,
    GreatToeIp,
    /// Lesser toes' metatarsophalangeal, proximal and distal interphalangeal joints.
    ToeMtp,
    ToePip,
    ToeDip,
}

impl Kind {
    pub fn name(self) -> &'static str {
        match self {
            Kind::Root => "root (global orientation)",
            Kind::Rigid => "rigid pelvis link",
            Kind::Spine => "thoracolumbar spine",
            Kind::Neck => "cervical spine and head",
            Kind::Girdle => "shoulder girdle (clavicle)",
            Kind::Shoulder => "shoulder (glenohumeral)",
            Kind::UpperArmTwist => "upper-arm twist segment",
            Kind::Elbow => "elbow and forearm",
            Kind::ForearmTwist => "forearm twist segment",
            Kind::Wrist => "wrist",
            Kind::Palm => "palm (finger CMC)",
            Kind::FingerMcp => "finger MCP",
            Kind::FingerPip => "finger PIP",
            Kind::FingerDip => "finger DIP",
            Kind::Thumb(1) => "thumb CMC",
            Kind::Thumb(2) => "thumb MCP",
            Kind::Thumb(_) => "thumb IP",
            Kind::Hip => "hip",
            Kind::ThighTwist => "thigh twist segment",
            Kind::Knee => "knee",
            Kind::ShankTwist => "shank twist segment",
            Kind::Ankle => "ankle and subtalar",
            Kind::GreatToeMtp => "great toe MTP",
            Kind::GreatToeIp => "great toe IP",
            Kind::ToeMtp => "lesser toe MTP",
            Kind::ToePip => "lesser toe PIP",
            Kind::ToeDip => "lesser toe DIP",
        }
    }

    /// The kind whose axial rotation a twist segment shares.
    fn twist_of(self) -> Option<Kind> {
        match self {
            Kind::UpperArmTwist => Some(Kind::Shoulder),
            Kind::ForearmTwist => Some(Kind::Elbow),
            Kind::ThighTwist => Some(Kind::Hip),
            Kind::ShankTwist => Some(Kind::Knee),
            _ => None,
        }
    }

    /// A box of ±this many degrees on every axis instead of movement axes.
    fn symmetric_box(self) -> Option<f64> {
        match self {
            Kind::Root => Some(ROOT_LIMIT_DEG),
            Kind::Rigid => Some(5.0),
            Kind::Palm => Some(10.0),
            // AAOS: CMC abduction 70° (flexion 15°, extension 20°), MCP flexion 50°, IP
            // flexion 80° (hyperextension 20°).
            Kind::Thumb(1) => Some(70.0),
            Kind::Thumb(2) => Some(50.0),
            Kind::Thumb(_) => Some(80.0),
            _ => None,
        }
    }
}

/// The clinical ranges of `kind`'s three movement axes (first swing, second swing, twist), before
/// shares and rest offsets; `None` for the kinds that get a symmetric box
/// (root ±180°, rigid links ±5°, palm bones ±10°, thumb joints ±70°/±50°/±80°).
pub fn movements(kind: Kind) -> Option<[Movement; 3]> {
    use Source::{Aaos, Floyd, Lfit, Soucie};
    let twist_slack = slack("axial rotation", 5.0);
    Some(match kind {
        Kind::Root | Kind::Rigid | Kind::Palm | Kind::Thumb(_) => return None,
        Kind::Spine => [
            mv("flexion", "extension", 80.0, 25.0, Aaos),
            mv("lateral flexion", "lateral flexion", 35.0, 35.0, Aaos),
            mv("rotation", "rotation", 45.0, 45.0, Aaos),
        ],
        Kind::Neck => [
            mv("flexion", "extension", 45.0, 45.0, Aaos),
            mv("lateral flexion", "lateral flexion", 45.0, 45.0, Aaos),
            mv("rotation", "rotation", 60.0, 60.0, Aaos),
        ],
        Kind::Girdle => [
            mv("elevation", "depression", 45.0, 5.0, Floyd),
            mv("protraction", "retraction", 15.0, 15.0, Floyd),
            // Upward rotation: the sternoclavicular joint's 45°; downward: the
            // acromioclavicular joint's 20–30° (the rig's clavicle bone carries both).
            mv(
                "upward (posterior) rotation",
                "downward rotation",
                45.0,
                30.0,
                Floyd,
            ),
        ],
        Kind::Shoulder => [
            mv("flexion", "extension", 180.0, 60.0, Aaos),
            // Adduction: across the front of the trunk (Floyd; the trunk stops it at 0° in
            // the frontal plane).
            mv2(mv("abduction", "adduction", 180.0, 75.0, Aaos), Floyd),
            mv("internal rotation", "external rotation", 70.0, 90.0, Aaos),
        ],
        Kind::Elbow => [
            mv("flexion", "extension", 150.0, 0.0, Aaos),
            slack("varus/valgus", 5.0),
            mv("pronation", "supination", 80.0, 80.0, Aaos),
        ],
        Kind::Wrist => [
            mv("flexion", "extension", 80.0, 70.0, Aaos),
            mv("radial deviation", "ulnar deviation", 20.0, 30.0, Aaos),
            twist_slack,
        ],
        Kind::FingerMcp => [
            mv("flexion", "hyperextension", 90.0, 45.0, Aaos),
            mv("abduction", "adduction", 20.0, 20.0, Floyd),
            twist_slack,
        ],
        Kind::FingerPip => [
            mv("flexion", "extension", 100.0, 0.0, Aaos),
            slack("side bend", 5.0),
            twist_slack,
        ],
        Kind::FingerDip => [
            mv("flexion", "hyperextension", 90.0, 10.0, Aaos),
            slack("side bend", 5.0),
            twist_slack,
        ],
        Kind::Hip => [
            mv("flexion", "extension", 120.0, 30.0, Aaos),
            mv("abduction", "adduction", 45.0, 30.0, Aaos),
            mv("internal rotation", "external rotation", 45.0, 45.0, Aaos),
        ],
        Kind::Knee => [
            mv2(mv("flexion", "hyperextension", 140.0, 10.0, Soucie), Lfit),
            slack("varus/valgus", 5.0),
            mv("internal rotation", "external rotation", 10.0, 10.0, Lfit),
        ],
        Kind::Ankle => [
            mv("dorsiflexion", "plantarflexion", 20.0, 50.0, Aaos),
            mv("abduction", "adduction", 20.0, 20.0, Lfit),
            mv("inversion", "eversion", 35.0, 15.0, Aaos),
        ],
        Kind::GreatToeMtp => [
            mv("flexion", "extension", 45.0, 70.0, Aaos),
            slack("abduction", 10.0),
            twist_slack,
        ],
        Kind::GreatToeIp => [
            mv("flexion", "extension", 90.0, 0.0, Aaos),
            slack("side bend", 5.0),
            twist_slack,
        ],
        Kind::ToeMtp => [
            mv("flexion", "extension", 40.0, 40.0, Aaos),
            slack("abduction", 10.0),
            twist_slack,
        ],
        Kind::ToePip => [
            mv("flexion", "extension", 35.0, 0.0, Aaos),
            slack("side bend", 5.0),
            twist_slack,
        ],
        Kind::ToeDip => [
            mv("flexion", "extension", 60.0, 30.0, Aaos),
            slack("side bend", 5.0),
            twist_slack,
        ],
        Kind::UpperArmTwist | Kind::ForearmTwist | Kind::ThighTwist | Kind::ShankTwist => {
            let mut m = movements(kind.twist_of().expect("a twist segment"))?;
            m[0] = slack("swing", 5.0);
            m[1] = slack("swing", 5.0);
            m
        }
    })
}

/// The rig name with its side marker removed: `LeftUpLeg` → `UpLeg`, `LHipJoint` → `HipJoint`,
/// `thigh_l` → `thigh`, `upperleg01.L` → `upperleg01`.
fn stem(name: &str) -> &str {
    for s in ["_l", "_r", ".L", ".R"] {
        if let Some(stem) = name.strip_suffix(s) {
            return stem;
        }
    }
    for p in ["Left", "Right"] {
        if let Some(stem) = name.strip_prefix(p) {
            return stem;
        }
    }
    let b = name.as_bytes();
    if b.len() > 1 && matches!(b[0], b'L' | b'R') && b[1].is_ascii_uppercase() {
        return &name[1..];
    }
    name
}

/// The anatomical joint that bone `name` of `rig` stands for; `None` for bones the table does
/// not cover and for unknown rigs (the root is found by the caller: the parentless bone).
pub fn kind_of(rig: &str, name: &str) -> Option<Kind> {
    let s = stem(name);
    match rig {
        "cmu_mb" => Some(match s {
            "HipJoint" => Kind::Rigid,
            "UpLeg" => Kind::Hip,
            "Leg" => Kind::Knee,
            "Foot" => Kind::Ankle,
            "ToeBase" => Kind::GreatToeMtp,
            "LowerBack" | "Spine" | "Spine1" => Kind::Spine,
            "Neck" | "Neck1" | "Head" => Kind::Neck,
            "Shoulder" => Kind::Girdle,
            "Arm" => Kind::Shoulder,
            "ForeArm" => Kind::Elbow,
            "Hand" => Kind::Wrist,
            "FingerBase" => Kind::Palm,
            "HandFinger1" => Kind::FingerMcp,
            "Thumb" => Kind::Thumb(1),
            _ => return None,
        }),
        "game_engine" | "game_engine_with_breast" => Some(match s {
            "spine_01" | "spine_02" | "spine_03" => Kind::Spine,
            "neck_01" | "head" => Kind::Neck,
            "clavicle" => Kind::Girdle,
            "upperarm" => Kind::Shoulder,
            "lowerarm" => Kind::Elbow,
            "hand" => Kind::Wrist,
            "thigh" => Kind::Hip,
            "calf" => Kind::Knee,
            "foot" => Kind::Ankle,
            "ball" => Kind::GreatToeMtp,
            _ => {
                let (finger, level) = s.rsplit_once('_')?;
                let level: u8 = level.parse().ok().filter(|l| (1..=3).contains(l))?;
                match finger {
                    "thumb" => Kind::Thumb(level),
                    "index" | "middle" | "ring" | "pinky" => {
                        [Kind::FingerMcp, Kind::FingerPip, Kind::FingerDip][level as usize - 1]
                    }
                    _ => return None,
                }
            }
        }),
        "default" | "default_no_toes" => Some(match s {
            "spine01" | "spine02" | "spine03" | "spine04" | "spine05" => Kind::Spine,
            "neck01" | "neck02" | "neck03" | "head" => Kind::Neck,
            "pelvis" => Kind::Rigid,
            "upperleg01" => Kind::Hip,
            "upperleg02" => Kind::ThighTwist,
            "lowerleg01" => Kind::Knee,
            "lowerleg02" => Kind::ShankTwist,
            "foot" => Kind::Ankle,
            "clavicle" | "shoulder01" => Kind::Girdle,
            "upperarm01" => Kind::Shoulder,
            "upperarm02" => Kind::UpperArmTwist,
            "lowerarm01" => Kind::Elbow,
            "lowerarm02" => Kind::ForearmTwist,
            "wrist" => Kind::Wrist,
            "metacarpal1" | "metacarpal2" | "metacarpal3" | "metacarpal4" => Kind::Palm,
            _ => {
                let (digit, level) = s.rsplit_once('-')?;
                let level: u8 = level.parse().ok().filter(|l| (1..=3).contains(l))?;
                match digit {
                    "finger1" => Kind::Thumb(level),
                    "finger2" | "finger3" | "finger4" | "finger5" => {
                        [Kind::FingerMcp, Kind::FingerPip, Kind::FingerDip][level as usize - 1]
                    }
                    "toe1" => [Kind::GreatToeMtp, Kind::GreatToeIp]
                        .get(level as usize - 1)
                        .copied()?,
                    "toe2" | "toe3" | "toe4" | "toe5" => {
                        [Kind::ToeMtp, Kind::ToePip, Kind::ToeDip][level as usize - 1]
                    }
                    _ => return None,
                }
            }
        }),
        _ => None,
    }
}

/// A rig bone as the table sees it: its rest head (the joint) and tail, lfit frame, metres.
#[derive(Debug, Clone)]
pub struct RomBone<'a> {
    pub name: &'a str,
    pub parent: Option<usize>,
    pub head: DVec3,
    pub tail: DVec3,
}

/// What the table made of one joint.
#[derive(Debug, Clone, PartialEq)]
pub struct JointRom {
    /// `None`: not covered (±[`UNMAPPED_LIMIT_DEG`]).
    pub kind: Option<Kind>,
    /// Fraction of the anatomical range this joint carries (shared movements), 1 otherwise.
    pub share: f64,
    /// The movement axes in the world frame (first swing, second swing, twist) and each one's
    /// range `[−opposite, +movement]` after share and rest offset, degrees; empty for boxes.
    pub axes: Vec<(DVec3, [f64; 2])>,
    /// Limits per world axis, degrees `[lo, hi]`.
    pub limits_deg: [[f64; 2]; 3],
}

/// The movement directions of one kind (see the module docs).
enum Dir {
    /// Positive angles swing the tip towards this direction.
    Swing(DVec3),
    /// A symmetric swing: any sign.
    AnySwing,
    /// Positive angles turn the first direction towards the second about the bone.
    Twist(DVec3, DVec3),
    /// A symmetric twist: any sign.
    AnyTwist,
}

/// Where a rest angle is measured from.
enum Neutral {
    /// The parent bone's direction (a straight hinge).
    ParentBone,
    /// Straight down (the arm at the side).
    Down,
}

fn cfg(name: &str, reason: impl std::fmt::Display) -> ModelError {
    ModelError::Config(format!("joint limits of bone '{name}': {reason}"))
}

/// Rotation angle (degrees) about the unit axis `u` that takes `from` to `to`, both projected on
/// the plane perpendicular to `u`.
fn angle_about(u: DVec3, from: DVec3, to: DVec3) -> f64 {
    let a = from - from.dot(u) * u;
    let b = to - to.dot(u) * u;
    u.dot(a.cross(b)).atan2(a.dot(b)).to_degrees()
}

fn round(x: f64) -> f64 {
    ((x * ROUND_PER_DEG).round() / ROUND_PER_DEG).clamp(-ROOT_LIMIT_DEG, ROOT_LIMIT_DEG) + 0.0
}

/// Per-joint rotation limits (degrees, `[lo, hi]` per world axis) of `bones` of `rig`, with what
/// the table made of each joint.
pub fn joint_roms(rig: &str, bones: &[RomBone<'_>]) -> Result<Vec<JointRom>> {
    let kinds: Vec<Option<Kind>> = bones
        .iter()
        .map(|b| match b.parent {
            None => Some(Kind::Root),
            Some(_) => kind_of(rig, b.name),
        })
        .collect();
    let dir = |j: usize| -> Result<DVec3> {
        let d = bones[j].tail - bones[j].head;
        if d.length() < 1e-6 {
            return Err(cfg(bones[j].name, "its rest bone has no length"));
        }
        Ok(d.normalize())
    };
    // Side: +1 on the subject's left (+x), −1 on the right; +1 on the midline (any sign does).
    let side = |j: usize| {
        if bones[j].head.x + bones[j].tail.x < -1e-4 {
            -1.0
        } else {
            1.0
        }
    };
    let count = |k: Kind, s: f64| {
        (0..bones.len())
            .filter(|&i| kinds[i] == Some(k) && (k != Kind::Girdle || side(i) == s))
            .count()
            .max(1) as f64
    };
    let children = |j: usize| (0..bones.len()).filter(move |&i| bones[i].parent == Some(j));
    // Palm normal and radial direction of a wrist: the thumb (its first bone's tail) gives the
    // radial side; the palm faces `side · (t × r)` (the left palm faces +z in the anatomical
    // position, fingers down, thumb at +x).
    let hand = |w: usize| -> Result<(DVec3, DVec3)> {
        let t = dir(w)?;
        let thumb = children(w)
            .find(|&c| kinds[c] == Some(Kind::Thumb(1)))
            .ok_or_else(|| cfg(bones[w].name, "the wrist has no thumb bone"))?;
        let d = bones[thumb].tail - bones[w].head;
        let r = d - d.dot(t) * t;
        if r.length() < 1e-4 {
            return Err(cfg(bones[w].name, "the thumb lies on the hand's axis"));
        }
        let r = r.normalize();
        Ok((side(w) * t.cross(r).normalize(), r))
    };
    let wrist_of = |mut j: usize| -> Result<usize> {
        let name = bones[j].name;
        while let Some(p) = bones[j].parent {
            if kinds[p] == Some(Kind::Wrist) {
                return Ok(p);
            }
            j = p;
        }
        Err(cfg(name, "a finger bone with no wrist above it"))
    };
    let (x, y, z) = (DVec3::X, DVec3::Y, DVec3::Z);
    let mut out = Vec::with_capacity(bones.len());
    for (j, b) in bones.iter().enumerate() {
        let Some(kind) = kinds[j] else {
            out.push(JointRom {
                kind: None,
                share: 1.0,
                axes: Vec::new(),
                limits_deg: [[-UNMAPPED_LIMIT_DEG, UNMAPPED_LIMIT_DEG]; 3],
            });
            continue;
        };
        if let Some(a) = kind.symmetric_box() {
            out.push(JointRom {
                kind: Some(kind),
                share: 1.0,
                axes: Vec::new(),
                limits_deg: [[-a, a]; 3],
            });
            continue;
        }
        let moves = movements(kind).expect("a kind without a box has movements");
        let t = dir(j)?;
        let s = side(j);
        let parent_dir = || b.parent.map(dir).transpose();
        let medial = -s * x;
        let (mut dirs, mut neutral): ([Dir; 3], [Option<Neutral>; 3]) = match kind
            .twist_of()
            .unwrap_or(kind)
        {
            Kind::Spine | Kind::Neck => (
                [Dir::Swing(z), Dir::Swing(x), Dir::Twist(z, x)],
                [None, None, None],
            ),
            Kind::Girdle => (
                [Dir::Swing(y), Dir::Swing(z), Dir::Twist(y, -z)],
                [None, None, None],
            ),
            Kind::Shoulder => (
                [Dir::Swing(z), Dir::Swing(s * x + y), Dir::Twist(z, medial)],
                [None, Some(Neutral::Down), None],
            ),
            Kind::Elbow => {
                let p = parent_dir()?.ok_or_else(|| cfg(b.name, "an elbow with no parent"))?;
                // Flexion brings the wrist towards the shoulder; a straight arm (anatomical
                // position, palm forward) flexes forward.
                let d = if t.cross(p).length() > 0.17 { -p } else { z };
                (
                    [Dir::Swing(d), Dir::AnySwing, Dir::Twist(z, medial)],
                    [Some(Neutral::ParentBone), None, None],
                )
            }
            Kind::Wrist | Kind::FingerMcp | Kind::FingerPip | Kind::FingerDip => {
                let w = if kind == Kind::Wrist { j } else { wrist_of(j)? };
                let (palm, radial) = hand(w)?;
                (
                    [Dir::Swing(palm), Dir::Swing(radial), Dir::AnyTwist],
                    [None, None, None],
                )
            }
            Kind::Hip => (
                [Dir::Swing(z), Dir::Swing(s * x), Dir::Twist(z, medial)],
                [None, None, None],
            ),
            Kind::Knee => (
                [Dir::Swing(-z), Dir::AnySwing, Dir::Twist(z, medial)],
                [Some(Neutral::ParentBone), None, None],
            ),
            Kind::Ankle => (
                [Dir::Swing(y), Dir::Swing(s * x), Dir::Twist(-y, medial)],
                [None, None, None],
            ),
            Kind::GreatToeMtp | Kind::GreatToeIp | Kind::ToeMtp | Kind::ToePip | Kind::ToeDip => (
                [Dir::Swing(-y), Dir::AnySwing, Dir::AnyTwist],
                [None, None, None],
            ),
            _ => unreachable!("kinds with a box are handled above"),
        };
        if kind.twist_of().is_some() {
            // A twist segment: its limb's axial rotation, slack swings.
            dirs[0] = Dir::AnySwing;
            dirs[1] = Dir::AnySwing;
            neutral = [None, None, None];
        }
        // Twist segments and limbs with one: the axial rotation is shared.
        let twist_share = match kind.twist_of() {
            Some(_) => 0.5,
            None => {
                if children(j).any(|c| kinds[c].and_then(Kind::twist_of) == Some(kind)) {
                    0.5
                } else {
                    1.0
                }
            }
        };
        let share = match kind {
            Kind::Spine | Kind::Neck | Kind::Girdle => 1.0 / count(kind, s),
            _ => 1.0,
        };
        // World axes: the first swing's from its direction, the second perpendicular to it, the
        // twist along the bone.
        let swing = |d: DVec3| -> Result<DVec3> {
            let u = t.cross(d);
            if u.length() < 0.1 {
                return Err(cfg(
                    b.name,
                    "its rest bone points along a movement direction",
                ));
            }
            Ok(u.normalize())
        };
        let u0 = match dirs[0] {
            Dir::Swing(d) => swing(d)?,
            // Any axis perpendicular to the bone: across the world axis least along it.
            _ => {
                let a = [x, y, z]
                    .into_iter()
                    .min_by(|a, b| a.dot(t).abs().total_cmp(&b.dot(t).abs()))
                    .expect("three axes");
                swing(a)?
            }
        };
        let mut u1 = t.cross(u0).normalize();
        if let Dir::Swing(d) = dirs[1] {
            let sign = u1.cross(t).dot(d);
            if sign.abs() < 1e-3 {
                return Err(cfg(b.name, "its second movement direction is degenerate"));
            }
            u1 *= sign.signum();
        }
        let mut u2 = t;
        if let Dir::Twist(r, d) = dirs[2] {
            let sign = t.dot(r.cross(d));
            if sign.abs() < 1e-3 {
                return Err(cfg(b.name, "its twist reference is degenerate"));
            }
            u2 *= sign.signum();
        }
        let mut axes = Vec::with_capacity(3);
        for (m, (u, neutral)) in [u0, u1, u2].into_iter().zip(neutral).enumerate() {
            let mv = moves[m];
            let k = if m == 2 { share * twist_share } else { share };
            let offset = match neutral {
                None => 0.0,
                Some(Neutral::Down) => angle_about(u, -y, t),
                Some(Neutral::ParentBone) => {
                    let p = parent_dir()?.ok_or_else(|| cfg(b.name, "a hinge with no parent"))?;
                    angle_about(u, p, t)
                }
            };
            axes.push((u, [-mv.neg * k - offset, mv.pos * k - offset]));
        }
        let mut limits = [[0.0; 2]; 3];
        for (u, [lo, hi]) in &axes {
            for (c, l) in limits.iter_mut().enumerate() {
                let (a, b) = (lo * u[c], hi * u[c]);
                l[0] += a.min(b);
                l[1] += a.max(b);
            }
        }
        out.push(JointRom {
            kind: Some(kind),
            share,
            axes,
            limits_deg: limits.map(|l| l.map(round)),
        });
    }
    Ok(out)
}

/// Per-joint rotation limits (degrees, `[lo, hi]` per world axis) of `bones` of `rig`
/// ([`joint_roms`]).
pub fn limits_deg(rig: &str, bones: &[RomBone<'_>]) -> Result<Vec<[[f64; 2]; 3]>> {
    Ok(joint_roms(rig, bones)?
        .into_iter()
        .map(|r| r.limits_deg)
        .collect())
}

#[cfg(test)]
mod tests {
    use std::path::Path;

    use super::*;
    use crate::energy::{AngleLimits, AnglePrior};
    use crate::skinning::joint_transforms;
    use crate::template::Template;

    fn bone(
        name: &'static str,
        parent: Option<usize>,
        head: [f64; 3],
        tail: [f64; 3],
    ) -> RomBone<'static> {
        RomBone {
            name,
            parent,
            head: DVec3::from_array(head),
            tail: DVec3::from_array(tail),
        }
    }

    /// A `cmu_mb`-named skeleton with vertical legs and spine, arms straight down at the sides
    /// (the anatomical position), palms forward with the thumbs lateral.
    fn upright() -> Vec<RomBone<'static>> {
        vec![
            bone("Hips", None, [0.0, 1.0, 0.0], [0.0, 1.1, 0.0]),
            bone("LowerBack", Some(0), [0.0, 1.1, 0.0], [0.0, 1.2, 0.0]),
            bone("Spine", Some(1), [0.0, 1.2, 0.0], [0.0, 1.3, 0.0]),
            bone("Spine1", Some(2), [0.0, 1.3, 0.0], [0.0, 1.4, 0.0]),
            bone("LHipJoint", Some(0), [0.0, 1.0, 0.0], [0.1, 1.0, 0.0]),
            bone("LeftUpLeg", Some(4), [0.1, 1.0, 0.0], [0.1, 0.55, 0.0]),
            bone("LeftLeg", Some(5), [0.1, 0.55, 0.0], [0.1, 0.1, 0.0]),
            bone("LeftFoot", Some(6), [0.1, 0.1, 0.0], [0.1, 0.0, 0.15]),
            bone("RHipJoint", Some(0), [0.0, 1.0, 0.0], [-0.1, 1.0, 0.0]),
            bone("RightUpLeg", Some(8), [-0.1, 1.0, 0.0], [-0.1, 0.55, 0.0]),
            bone("LeftArm", Some(3), [0.2, 1.4, 0.0], [0.2, 1.1, 0.0]),
            bone("LeftForeArm", Some(10), [0.2, 1.1, 0.0], [0.2, 0.85, 0.0]),
            bone("LeftHand", Some(11), [0.2, 0.85, 0.0], [0.2, 0.8, 0.0]),
            bone("LThumb", Some(12), [0.21, 0.84, 0.01], [0.25, 0.8, 0.0]),
            bone("Neck", Some(3), [0.0, 1.4, 0.0], [0.0, 1.5, 0.0]),
            bone("Tongue", Some(14), [0.0, 1.5, 0.0], [0.0, 1.5, 0.1]),
        ]
    }

    fn rom(bones: &[RomBone<'_>], name: &str) -> JointRom {
        let roms = joint_roms("cmu_mb", bones).unwrap();
        roms[bones.iter().position(|b| b.name == name).unwrap()].clone()
    }

    /// On a world-aligned skeleton the limits are the clinical ranges themselves, with the signs
    /// of lfit's axes: −x flexes a hip, +x flexes a spine joint, +z abducts the left hip, −z the
    /// right one, and so on.
    #[test]
    fn an_upright_skeleton_gets_the_clinical_ranges_on_the_world_axes() {
        let b = upright();
        let l = |n: &str| rom(&b, n).limits_deg;
        assert_eq!(l("Hips"), [[-180.0, 180.0]; 3]);
        assert_eq!(l("LHipJoint"), [[-5.0, 5.0]; 3]);
        // Hip: flexion 120 about −x, abduction 45 (left +z, right −z), rotation ±45 about y.
        assert_eq!(
            l("LeftUpLeg"),
            [[-120.0, 30.0], [-45.0, 45.0], [-30.0, 45.0]]
        );
        assert_eq!(
            l("RightUpLeg"),
            [[-120.0, 30.0], [-45.0, 45.0], [-45.0, 30.0]]
        );
        // Knee: flexion 140 about +x, 10 of hyperextension; no rest flexion here.
        assert_eq!(l("LeftLeg"), [[-10.0, 140.0], [-10.0, 10.0], [-5.0, 5.0]]);
        // Spine: 80 flexion / 25 extension, lateral ±35, rotation ±45, a third per joint.
        let third = |x: f64| (x / 3.0 * 10.0).round() / 10.0;
        assert_eq!(
            l("Spine"),
            [
                [-third(25.0), third(80.0)],
                [-15.0, 15.0],
                [-third(35.0), third(35.0)]
            ]
        );
        // The arm at the side: flexion 180 about −x, abduction about +z (left) from 0 at
        // rest, internal rotation 70 about the bone (−y for the left arm: +t).
        assert_eq!(
            l("LeftArm"),
            [[-180.0, 60.0], [-70.0, 90.0], [-75.0, 180.0]]
        );
        // An unknown bone keeps ±30°.
        assert_eq!(l("Tongue"), [[-30.0, 30.0]; 3]);
        assert_eq!(rom(&b, "Tongue").kind, None);
        // The foot points forward and down: dorsiflexion about −x (20), plantar 50.
        let foot = rom(&b, "LeftFoot");
        assert_eq!(foot.kind, Some(Kind::Ankle));
        assert!(foot.axes[0].0.x < -0.5, "{:?}", foot.axes[0]);
        assert_eq!(foot.axes[0].1, [-50.0, 20.0]);
        // The wrist: the palm faces +z, so flexion swings the hand forward (about −x ... for
        // a hand pointing down, the tip moves towards +z), radial deviation towards the thumb.
        let wrist = rom(&b, "LeftHand");
        assert!(
            (wrist.axes[0].0 - DVec3::NEG_X).length() < 1e-9,
            "{wrist:?}"
        );
        assert!((wrist.axes[1].0 - DVec3::Z).length() < 1e-9, "{wrist:?}");
        assert_eq!(wrist.limits_deg[0], [-80.0, 70.0]);
    }

    #[test]
    fn rest_angles_shift_the_hinges_and_the_a_pose_shoulder() {
        let mut b = upright();
        // Bend the elbow by 40° (the forearm forward) and raise the arm 40° sideways.
        let (s, c) = 40f64.to_radians().sin_cos();
        b[11].tail = b[11].head + DVec3::new(0.0, -c, s) * 0.25;
        let arm = rom(&b, "LeftForeArm");
        assert!((arm.axes[0].1[0] + 40.0).abs() < 1e-9, "{arm:?}");
        assert!((arm.axes[0].1[1] - 110.0).abs() < 1e-9, "{arm:?}");
        b[10].tail = b[10].head + DVec3::new(s, -c, 0.0) * 0.3;
        let shoulder = rom(&b, "LeftArm");
        assert!((shoulder.axes[1].0 - DVec3::Z).length() < 1e-9);
        assert!((shoulder.axes[1].1[0] + 115.0).abs() < 1e-9, "{shoulder:?}");
        assert!((shoulder.axes[1].1[1] - 140.0).abs() < 1e-9, "{shoulder:?}");
    }

    #[test]
    fn bad_bones_are_one_line_errors() {
        let mut b = upright();
        b[5].tail = b[5].head;
        let e = joint_roms("cmu_mb", &b).unwrap_err().to_string();
        assert!(e.contains("LeftUpLeg") && !e.contains('\n'), "{e}");
        let mut b = upright();
        b.remove(13);
        b.truncate(13);
        let e = joint_roms("cmu_mb", &b).unwrap_err().to_string();
        assert!(e.contains("thumb") && !e.contains('\n'), "{e}");
    }

    #[test]
    fn rig_bones_map_to_anatomical_joints() {
        assert_eq!(kind_of("cmu_mb", "LeftUpLeg"), Some(Kind::Hip));
        assert_eq!(kind_of("cmu_mb", "RHipJoint"), Some(Kind::Rigid));
        assert_eq!(kind_of("cmu_mb", "LThumb"), Some(Kind::Thumb(1)));
        assert_eq!(kind_of("game_engine", "pinky_03_r"), Some(Kind::FingerDip));
        assert_eq!(kind_of("game_engine", "thumb_02_l"), Some(Kind::Thumb(2)));
        assert_eq!(kind_of("default", "toe1-2.L"), Some(Kind::GreatToeIp));
        assert_eq!(kind_of("default", "toe1-3.L"), None);
        assert_eq!(kind_of("default", "finger3-1.R"), Some(Kind::FingerMcp));
        assert_eq!(
            kind_of("default", "upperarm02.L"),
            Some(Kind::UpperArmTwist)
        );
        assert_eq!(kind_of("default", "tongue01"), None);
        assert_eq!(kind_of("mixamo", "LeftUpLeg"), None);
    }

    fn committed() -> Template {
        let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../models/makehuman-cmu_mb.npz");
        crate::modelfile::load(&path).unwrap()
    }

    struct Poser {
        t: Template,
    }

    impl Poser {
        fn index(&self, name: &str) -> usize {
            self.t
                .rig
                .joints
                .iter()
                .position(|j| j.name == name)
                .unwrap_or_else(|| panic!("no joint {name}"))
        }
        fn limits(&self, name: &str) -> [[f64; 2]; 3] {
            self.t.info.limits_deg[self.index(name)]
        }
        fn rest(&self, name: &str) -> DVec3 {
            self.t.rig.joints[self.index(name)].rest()
        }
        /// Whether rotation `deg` (axis-angle, degrees) is within `name`'s limits.
        fn allows(&self, name: &str, deg: DVec3) -> bool {
            let l = self.limits(name);
            (0..3).all(|a| deg[a] >= l[a][0] - 1e-9 && deg[a] <= l[a][1] + 1e-9)
        }
        /// Joint positions with `name` rotated by `deg` (axis-angle, degrees), all else at rest.
        fn pose(&self, rotations: &[(&str, DVec3)]) -> crate::skinning::Posed {
            let mut p = vec![0.0; self.t.layout().dim()];
            for (name, deg) in rotations {
                let o = crate::pose::rot_offset(self.index(name));
                for a in 0..3 {
                    p[o + a] = deg[a].to_radians();
                }
            }
            joint_transforms(&self.t, &p)
        }
        fn at(&self, posed: &crate::skinning::Posed, name: &str) -> DVec3 {
            posed.joints[self.index(name)]
        }
    }

    fn x(v: f64) -> DVec3 {
        DVec3::new(v, 0.0, 0.0)
    }

    /// The committed model, posed at its limits: each major joint's "flexion" end moves the
    /// child the anatomical way (thigh forward and up, shank back, toes down, trunk and head
    /// forward, arm forward and up, forearm to the shoulder). A wrong sign fails here.
    #[test]
    fn the_committed_model_flexes_the_anatomical_way_at_its_limits() {
        flexes_the_anatomical_way(committed());
    }

    /// The check above fails when a joint's limits have the wrong signs (the box mirrored
    /// through zero: every movement and its opposite swapped).
    #[test]
    fn mirrored_limits_fail_the_posing_check() {
        let t = committed();
        for joint in [
            "LeftUpLeg",
            "RightUpLeg",
            "LeftLeg",
            "RightFoot",
            "Spine",
            "LeftArm",
            "RightForeArm",
        ] {
            let mut bad = t.clone();
            let j = bad.rig.joints.iter().position(|x| x.name == joint).unwrap();
            bad.info.limits_deg[j] = bad.info.limits_deg[j].map(|[lo, hi]| [-hi, -lo]);
            let r = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
                flexes_the_anatomical_way(bad)
            }));
            assert!(r.is_err(), "{joint} with mirrored limits passed");
        }
    }

    fn flexes_the_anatomical_way(t: Template) {
        let m = Poser { t };
        assert_eq!(m.limits("Hips"), [[-180.0, 180.0]; 3]);
        for (side, s) in [("Left", 1.0), ("Right", -1.0)] {
            let n = |b: &str| format!("{side}{b}");
            let (hip, knee, ankle, toe) = (n("UpLeg"), n("Leg"), n("Foot"), n("ToeBase"));
            // Hip flexion: about −x, 120°; the knee ends in front of and above the hip.
            let l = m.limits(&hip);
            assert!(
                l[0][0] <= -115.0 && (25.0..=35.0).contains(&l[0][1]),
                "{hip} {l:?}"
            );
            let p = m.pose(&[(&hip, x(l[0][0]))]);
            let (h, k) = (m.at(&p, &hip), m.at(&p, &knee));
            assert!(
                k.z > h.z + 0.15 && k.y > h.y,
                "{hip} flexed: hip {h}, knee {k}"
            );
            let p = m.pose(&[(&hip, x(l[0][1]))]);
            assert!(m.at(&p, &knee).z < h.z - 0.1, "{hip} extended");
            // Hip abduction: +z on the left, −z on the right; the knee moves outwards.
            let abd = DVec3::new(0.0, 0.0, 44.0 * s);
            assert!(m.allows(&hip, abd), "{hip} {l:?}");
            let p = m.pose(&[(&hip, abd)]);
            assert!(
                s * (m.at(&p, &knee).x - m.rest(&knee).x) > 0.15,
                "{hip} abducted"
            );
            assert!(
                !m.allows(&hip, -abd * 50.0 / 44.0),
                "{hip}: adduction is 30°"
            );
            // Knee flexion: about +x, ~135° from rest; the ankle ends behind the knee.
            let l = m.limits(&knee);
            assert!(
                l[0][1] >= 125.0 && (-20.0..=-5.0).contains(&l[0][0]),
                "{knee} {l:?}"
            );
            let p = m.pose(&[(&knee, x(l[0][1]))]);
            let (k, a) = (m.at(&p, &knee), m.at(&p, &ankle));
            assert!(a.z < k.z - 0.25, "{knee} flexed: knee {k}, ankle {a}");
            // Ankle: plantarflexion about +x (50°) lowers the toes, dorsiflexion (20°) lifts them.
            let l = m.limits(&ankle);
            assert!((45.0..=55.0).contains(&l[0][1]), "{ankle} {l:?}");
            assert!((-25.0..=-15.0).contains(&l[0][0]), "{ankle} {l:?}");
            let toe_rest = m.rest(&toe);
            let p = m.pose(&[(&ankle, x(l[0][1]))]);
            assert!(
                m.at(&p, &toe).y < toe_rest.y - 0.03,
                "{ankle} plantarflexed"
            );
            let p = m.pose(&[(&ankle, x(l[0][0]))]);
            assert!(m.at(&p, &toe).y > toe_rest.y + 0.01, "{ankle} dorsiflexed");

            // Shoulder: the A-pose arm's flexion axis is t × z (t the rest bone); 170° of it
            // is allowed and lifts the elbow in front of and above the shoulder.
            let (arm, fore, hand) = (n("Arm"), n("ForeArm"), n("Hand"));
            let (sh, el) = (m.rest(&arm), m.rest(&fore));
            let t = (el - sh).normalize();
            let u = t.cross(DVec3::Z).normalize();
            assert!(m.allows(&arm, u * 170.0), "{arm} {:?}", m.limits(&arm));
            let p = m.pose(&[(&arm, u * 170.0)]);
            let e = m.at(&p, &fore);
            assert!(
                e.y > sh.y + 0.1 && e.z > sh.z,
                "{arm} flexed: shoulder {sh}, elbow {e}"
            );
            assert!(m.allows(&arm, u * -55.0), "{arm} extension");
            assert!(m.at(&m.pose(&[(&arm, u * -55.0)]), &fore).z < sh.z - 0.1);
            // Abduction: about +z on the left, −z on the right; 130° raises the elbow.
            let abd = DVec3::new(0.0, 0.0, 130.0 * s);
            assert!(m.allows(&arm, abd), "{arm} {:?}", m.limits(&arm));
            assert!(m.at(&m.pose(&[(&arm, abd)]), &fore).y > sh.y + 0.15);
            // Elbow: the hinge axis is t_upper × t_fore (the forearm rests 42° flexed); the
            // rest of 150° flexion is allowed and brings the wrist close to the shoulder.
            let w = m.rest(&hand);
            let tf = (w - el).normalize();
            let hinge = t.cross(tf).normalize();
            let rest_flexion = t.angle_between(tf).to_degrees();
            assert!((30.0..55.0).contains(&rest_flexion), "{rest_flexion}");
            let flex = hinge * (150.0 - rest_flexion - 1.0);
            assert!(m.allows(&fore, flex), "{fore} {:?}", m.limits(&fore));
            let p = m.pose(&[(&fore, flex)]);
            let d = (m.at(&p, &hand) - sh).length();
            assert!(
                d < 0.6 * (w - sh).length(),
                "{fore} flexed: wrist {d} m from the shoulder"
            );
        }
        // Spine: +x flexes each segment, 80° in all; the head ends well in front.
        let spine = ["LowerBack", "Spine", "Spine1"];
        let total: f64 = spine.iter().map(|j| m.limits(j)[0][1]).sum();
        assert!((total - 80.0).abs() < 2.0, "{total}");
        let flexed: Vec<(&str, DVec3)> = spine.iter().map(|j| (*j, x(m.limits(j)[0][1]))).collect();
        let p = m.pose(&flexed);
        assert!(
            m.at(&p, "Head").z > m.rest("Head").z + 0.25,
            "trunk flexion"
        );
        let extended: Vec<(&str, DVec3)> =
            spine.iter().map(|j| (*j, x(m.limits(j)[0][0]))).collect();
        assert!(
            m.at(&m.pose(&extended), "Head").z < m.rest("Head").z - 0.05,
            "trunk extension"
        );
        // Neck: +x flexes Neck, Neck1 and Head, 45° in all; a point above the head moves forward.
        let neck = ["Neck", "Neck1", "Head"];
        let total: f64 = neck.iter().map(|j| m.limits(j)[0][1]).sum();
        assert!((total - 45.0).abs() < 2.0, "{total}");
        let crown = m.rest("Head") + DVec3::new(0.0, 0.15, 0.0);
        let flexed: Vec<(&str, DVec3)> = neck.iter().map(|j| (*j, x(m.limits(j)[0][1]))).collect();
        let p = m.pose(&flexed);
        let moved = p.transforms[m.index("Head")].transform_point3(crown);
        assert!(
            moved.z > crown.z + 0.08 && moved.y < crown.y,
            "head flexion: {moved}"
        );
    }

    /// The root is the global orientation: EA (either form) never counts it, whatever it is,
    /// and the global box lets it take any orientation.
    #[test]
    fn an_unlimited_root_is_not_part_of_the_angle_prior() {
        let t = committed();
        let limits = AngleLimits::new(&t);
        let mut pose = vec![0.0; t.layout().pose_dim()];
        for form in [AnglePrior::Binary, AnglePrior::Hinge] {
            assert_eq!(limits.evaluate(&pose, form, None), 0.0);
        }
        pose[3..6].copy_from_slice(&[3.0, -3.1, 2.5]);
        for form in [AnglePrior::Binary, AnglePrior::Hinge] {
            assert_eq!(limits.evaluate(&pose, form, None), 0.0, "{form:?}");
        }
        let knee = t
            .rig
            .joints
            .iter()
            .position(|j| j.name == "LeftLeg")
            .unwrap();
        pose[crate::pose::rot_offset(knee)] = 170f64.to_radians();
        assert_eq!(limits.evaluate(&pose, AnglePrior::Binary, None), 1.0);
        assert!(limits.evaluate(&pose, AnglePrior::Hinge, None) > 0.0);
        let g = crate::pose::Bounds::global_for(&t);
        assert!(g.contains(&{
            let mut p = vec![0.0; t.layout().dim()];
            p[3..6].copy_from_slice(&[3.0, -3.1, 2.5]);
            p
        }));
        assert_eq!(
            (g.lower[3], g.upper[5]),
            (-std::f64::consts::PI, std::f64::consts::PI)
        );
    }

    /// The real rig files (LFIT_MPFB2_DIR): every bone of `cmu_mb` and `game_engine` has an
    /// anatomical joint; on `default` every bone but the face, eyes, tongue and breasts.
    #[test]
    fn every_body_bone_of_the_known_rigs_has_a_range() {
        let Some(dir) = crate::makehuman::tests::real_assets() else {
            return;
        };
        for rig in ["cmu_mb", "game_engine", "default"] {
            let path = dir.join(format!("rigs/standard/rig.{rig}.json"));
            let bones = crate::makehuman::read_rig(&path).unwrap();
            let uncovered: Vec<&str> = bones
                .iter()
                // The root: the parentless bone, or the child of `game_engine`'s weightless
                // ground bone `Root`, which the importer drops.
                .filter(|b| b.parent.is_some() && b.parent.as_deref() != Some("Root"))
                .filter(|b| kind_of(rig, &b.name).is_none())
                .map(|b| b.name.as_str())
                .collect();
            let face = [
                "breast",
                "eye",
                "jaw",
                "tongue",
                "levator",
                "oris",
                "special",
                "temporalis",
                "risorius",
                "orbicularis",
                "oculi",
                "toe1-3",
            ];
            let unexpected: Vec<&&str> = uncovered
                .iter()
                .filter(|n| !face.iter().any(|f| n.starts_with(f)))
                .collect();
            assert!(unexpected.is_empty(), "{rig}: {unexpected:?}");
            if rig != "default" {
                assert!(uncovered.is_empty(), "{rig}: {uncovered:?}");
            }
            // The table on the rig's default body (the file's bone ends, Blender → lfit axes;
            // `game_engine`'s ground bone dropped as the importer does): no degenerate axes, and
            // mirror bones get mirrored limits (x kept, y and z negated).
            let from_blender = |p: [f64; 3]| DVec3::new(p[0], p[2], -p[1]);
            let kept: Vec<&crate::makehuman::Bone> =
                bones.iter().filter(|b| b.name != "Root").collect();
            let index = |n: &str| kept.iter().position(|b| b.name == n);
            let rom_bones: Vec<RomBone<'_>> = kept
                .iter()
                .map(|b| RomBone {
                    name: &b.name,
                    parent: b.parent.as_deref().and_then(index),
                    head: from_blender(b.head_default),
                    tail: from_blender(b.tail_default),
                })
                .collect();
            let roms = joint_roms(rig, &rom_bones).unwrap();
            for (j, b) in kept.iter().enumerate() {
                let Some(m) = index(&crate::makehuman_import::mirror_name(&b.name)) else {
                    continue;
                };
                let (l, r) = (roms[j].limits_deg, roms[m].limits_deg);
                let mirrored = [l[0], [-l[1][1], -l[1][0]], [-l[2][1], -l[2][0]]];
                for a in 0..3 {
                    for e in 0..2 {
                        assert!(
                            (mirrored[a][e] - r[a][e]).abs() < 0.25,
                            "{rig}: {} {l:?} vs {} {r:?}",
                            b.name,
                            kept[m].name
                        );
                    }
                }
                if rig == "cmu_mb" && !b.name.starts_with("Right") && !b.name.starts_with('R') {
                    let rom = &roms[j];
                    let axes: Vec<String> = rom
                        .axes
                        .iter()
                        .map(|(u, r)| format!("({:.2} {:.2} {:.2}) {r:?}", u.x, u.y, u.z))
                        .collect();
                    eprintln!("{} {:?} {:?} {axes:?}", b.name, rom.kind, rom.limits_deg);
                }
            }
        }
    }
}
