//! Procedural motion library (SPEC §8): walk, jog, wave, squat, reach, punch, kick, jump and turn
//! as smooth functions of time that return pose vectors of the default 18-joint skeleton — the
//! papers' library ([`MotionKind::CLASSIC`], the default everywhere) — and thirteen kinds of what
//! people do that it lacks ([`MotionKind::EXTENDED`], chosen by name: `--library-motions`,
//! `"library_motions"`): sit down and stand up, a deep crouch, kneeling on one knee, bending to
//! pick something up, an overarm throw, reaching overhead or behind; lying down on the back and
//! getting up, crawling on hands and knees, falling forward or backward and getting up, stepping
//! up onto a step and down, turning full circles in place, walking round a circle and climbing a
//! flight of stairs, turning on the landing and coming down. The last six of those but stairs
//! leave papers/000's root box (lying, on all fours, every heading:
//! [`MotionKind::has_free_root`]).
//!
//! Every motion is written in a *heading frame*: the body's own rotations, with the root path
//! (position on the floor and yaw) added on top. One-sided motions are written for a left lead
//! and mirrored (left ↔ right joints, axis-angle `(x, y, z) → (x, −y, −z)`, `t_x → −t_x`) for a
//! right lead.
//!
//! Conventions (SPEC §3, [`lfit_model::skeleton`]): y up, the subject faces +z, +x is the
//! subject's left; rotations are axis-angle relative to the parent in the world-aligned rest frame;
//! the rest pose is an A-pose with the arms 45° below horizontal. So: −x at a hip flexes the thigh
//! forward, +x at a knee flexes it, +x at an ankle points the toes down, +x on the spine bends the
//! trunk forward, +y at the root turns the body to its left, +z raises the left arm.
//!
//! Amplitudes follow typical adult biomechanics: sagittal gait angles after Winter (*Biomechanics
//! and Motor Control of Human Gait*, 1991) and Perry (*Gait Analysis*, 1992) — hip about 30°
//! flexion to 15° extension, knee about 5° at heel strike, a 15° loading bump and about 60° in
//! swing, ankle within about 10° dorsi- to 15–20° plantar-flexion, pelvis rotation and obliquity
//! of a few degrees, 2–4 cm vertical excursion of the pelvis, cadence about 108 steps/min at
//! 1.3 m/s; running after Novacheck (*Gait & Posture* 7, 1998) — more hip flexion, a stance knee
//! bump of 30–40°, a forward-leaning trunk, elbows near 90°. Peak joint speeds are kept to about
//! 7 rad/s (brisk, not ballistic, motion) so that sequences at 30 fps stay smooth; where a real
//! motion is faster (running knees, punches) the timing is stretched rather than the range cut.
//!
//! The output of a classic kind always lies inside the rotation limits of [`Bounds::global`]
//! ([`skeleton::rotation_limits_deg`], papers/000 Table 1); amplitudes are chosen so that the final
//! clamp rarely acts. Those limits stop a knee at 100°, a hip at 100° and a shoulder 60° from the
//! A-pose, so a person's deep flexions and overhead reaches cannot be written inside them: the
//! extended kinds lie inside [`clinical_limits_deg`] instead (AAOS and Soucie 2011 normal adult
//! ranges on the legs' flexion axes and the arms, the table's other ranges kept), and a model's own
//! limits clamp them again when they are retargeted onto it.
//! Two limits shape the library: the root yaw box is ±50°, so the heading of walks stays within
//! [`YAW_LIMIT`] (approached smoothly) and a turn sweeps at most about 80° in total (±41°); the
//! ankle dorsiflexion limit is 10°, so deep squats lift the heels slightly. The root translation is
//! *not* kept inside the ±1.25 m box: walks leave it; see [`recentre`].
//!
//! [`Bounds::global`]: lfit_model::Bounds::global

use std::f64::consts::{FRAC_PI_2, FRAC_PI_4, PI, TAU};
use std::fmt;
use std::str::FromStr;

use glam::{DQuat, DVec2, DVec3};
use lfit_model::pose::{POSE_DIM, Pose, rot_offset};
use lfit_model::skeleton::{
    self, HEAD, L_ANKLE, L_ELBOW, L_FOOT, L_HAND, L_HIP, L_KNEE, L_SHOULDER, LOWER_TORSO,
    MIDDLE_TORSO, NUM_JOINTS, ROOT,
};
use rand::Rng;
use serde::{Deserialize, Serialize};

/// Largest |yaw| (rad, about 43°) of the root path of walks and jogs, and of the facing of the
/// static motions: the root's yaw limit is ±50° ([`skeleton::rotation_limits_deg`]) and the
/// pelvis adds a few degrees of its own rotation on top of the heading.
pub const YAW_LIMIT: f64 = 0.75;

/// Half-width (m) of the square that [`recentre`] clamps the root's x and z into (the global
/// translation box is ±1.25 m, SPEC §3).
pub const RECENTRE_LIMIT: f64 = 1.2;

/// Standard gravity (m/s²), for the flight phase of [`MotionKind::Jump`].
const GRAVITY: f64 = 9.81;

/// Thigh and shank lengths (m) of the default template (hip 0.92 m, knee 0.50 m, ankle 0.085 m
/// above the floor, `lfit_model::body`), for the root drop of crouching motions.
const THIGH: f64 = 0.42;
const SHANK: f64 = 0.415;

/// Arm angle of the rest A-pose below horizontal (rad), `lfit_model::BodyShape::arm_angle_deg`.
const A_POSE: f64 = FRAC_PI_4;

/// The kinds of motion in the library (SPEC §8).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum MotionKind {
    /// Walking along a gently curving path at about 1.3 m/s × speed.
    Walk,
    /// Jogging along a gently curving path at about 2.3 m/s × speed.
    Jog,
    /// One arm raised, the forearm waving; the other arm relaxed.
    Wave,
    /// Repeated squats: hips, knees and ankles flex, the trunk leans forward, the arms go forward.
    Squat,
    /// One arm reaches forward/up towards a target and back, with trunk lean and twist.
    Reach,
    /// Alternating straight punches from a guard, with trunk twist.
    Punch,
    /// One leg kicks forward from a standing position, the arms balance.
    Kick,
    /// Counter-movement jumps in place: crouch, take off, fly (root up to about 0.3 m), land.
    Jump,
    /// Turning in place back and forth through up to 82° of root yaw, stepping while turning.
    Turn,
    /// Sitting down onto a seat 42–54 cm high and standing up again, the trunk leaning forward
    /// through the transfer (extended).
    Sit,
    /// A deep crouch with the heels rising: thighs 70–95° forward, knees to 130° (extended).
    Crouch,
    /// Kneeling down on one knee (the trailing leg's) and getting up (extended).
    Kneel,
    /// Bending to pick something up from the floor with one hand, from a stoop (straight legs) to
    /// a squat lift (extended).
    Pickup,
    /// An overarm throw: cocking with the trunk turned back, a step, release and follow-through
    /// (extended).
    Throw,
    /// Reaching both arms overhead, or one arm behind the body with the trunk turned (extended).
    Overhead,
    /// Getting down onto the floor (crouch, sit), lying on the back, and getting up again
    /// (extended, free root).
    Lie,
    /// Crawling forward on hands and knees (extended, free root).
    Crawl,
    /// Falling forward onto the knees and hands, or backward onto the seat and back, then getting
    /// up (extended, free root).
    Fall,
    /// Stepping up onto a step 15–27 cm high and down again, one leg leading (extended).
    Stairs,
    /// Turning in place through full circles, stepping (extended, free root).
    Spin,
    /// Walking round a circle of 0.7–1.1 m radius, leaning into the turn: turning while walking
    /// (extended, free root).
    Circle,
    /// Climbing a flight of 3–5 stairs step over step, turning round on the landing, coming down
    /// and turning round at the foot (extended, free root).
    Flight,
}

/// Error of [`MotionKind::from_str`]: the name matches no motion kind.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error(
    "unknown motion kind '{name}' (expected one of walk, jog, wave, squat, reach, punch, kick, jump, turn, sit, crouch, kneel, pickup, throw, overhead, lie, crawl, fall, stairs, spin, circle, flight)"
)]
pub struct UnknownMotionKind {
    /// The name that was given.
    pub name: String,
}

impl MotionKind {
    /// The papers' library (SPEC §8), in declaration order: what the library draws from unless
    /// told otherwise (so datasets and checkpoints made before the extended kinds keep their bytes).
    pub const CLASSIC: [MotionKind; 9] = [
        MotionKind::Walk,
        MotionKind::Jog,
        MotionKind::Wave,
        MotionKind::Squat,
        MotionKind::Reach,
        MotionKind::Punch,
        MotionKind::Kick,
        MotionKind::Jump,
        MotionKind::Turn,
    ];

    /// The kinds added for captured motion (issue 25, item 2), in declaration order.
    pub const EXTENDED: [MotionKind; 13] = [
        MotionKind::Sit,
        MotionKind::Crouch,
        MotionKind::Kneel,
        MotionKind::Pickup,
        MotionKind::Throw,
        MotionKind::Overhead,
        MotionKind::Lie,
        MotionKind::Crawl,
        MotionKind::Fall,
        MotionKind::Stairs,
        MotionKind::Spin,
        MotionKind::Circle,
        MotionKind::Flight,
    ];

    /// Every kind, in declaration order: [`MotionKind::CLASSIC`] then [`MotionKind::EXTENDED`].
    pub const ALL: [MotionKind; 22] = {
        let mut all = [MotionKind::Walk; 22];
        let mut i = 0;
        while i < all.len() {
            all[i] = if i < Self::CLASSIC.len() {
                Self::CLASSIC[i]
            } else {
                Self::EXTENDED[i - Self::CLASSIC.len()]
            };
            i += 1;
        }
        all
    };

    /// Lower-case name, as accepted by [`FromStr`] and written by serde.
    pub const fn name(self) -> &'static str {
        match self {
            MotionKind::Walk => "walk",
            MotionKind::Jog => "jog",
            MotionKind::Wave => "wave",
            MotionKind::Squat => "squat",
            MotionKind::Reach => "reach",
            MotionKind::Punch => "punch",
            MotionKind::Kick => "kick",
            MotionKind::Jump => "jump",
            MotionKind::Turn => "turn",
            MotionKind::Sit => "sit",
            MotionKind::Crouch => "crouch",
            MotionKind::Kneel => "kneel",
            MotionKind::Pickup => "pickup",
            MotionKind::Throw => "throw",
            MotionKind::Overhead => "overhead",
            MotionKind::Lie => "lie",
            MotionKind::Crawl => "crawl",
            MotionKind::Fall => "fall",
            MotionKind::Stairs => "stairs",
            MotionKind::Spin => "spin",
            MotionKind::Circle => "circle",
            MotionKind::Flight => "flight",
        }
    }

    /// Whether the kind is one of [`MotionKind::EXTENDED`] (written inside
    /// [`clinical_limits_deg`] rather than papers/000's limits).
    pub const fn is_extended(self) -> bool {
        matches!(
            self,
            MotionKind::Sit
                | MotionKind::Crouch
                | MotionKind::Kneel
                | MotionKind::Pickup
                | MotionKind::Throw
                | MotionKind::Overhead
                | MotionKind::Lie
                | MotionKind::Crawl
                | MotionKind::Fall
                | MotionKind::Stairs
                | MotionKind::Spin
                | MotionKind::Circle
                | MotionKind::Flight
        )
    }

    /// Whether the kind's root (the body's global orientation) leaves papers/000's root box
    /// (pitch −30…100°, yaw and roll ±50°): lying on the back, crawling, falling and full turns
    /// (in place, walking, on a flight's landing).
    /// Their root may take any orientation (±180° per axis-angle component, as a person's does:
    /// issue 25, item 1); its axis-angle vector jumps where the rotation angle passes π (a full
    /// turn), the rotation itself stays continuous.
    pub const fn has_free_root(self) -> bool {
        matches!(
            self,
            MotionKind::Lie
                | MotionKind::Crawl
                | MotionKind::Fall
                | MotionKind::Spin
                | MotionKind::Circle
                | MotionKind::Flight
        )
    }

    /// The rotation limits (degrees, about x, y, z) the kind's poses lie in for joint `j`:
    /// [`skeleton::rotation_limits_deg`] for the classic kinds, [`clinical_limits_deg`] for the
    /// extended ones, with ±180° at the root for those with [`MotionKind::has_free_root`].
    pub fn limits_deg(self, j: usize) -> [(f64, f64); 3] {
        if self.has_free_root() && j == ROOT {
            [(-180.0, 180.0); 3]
        } else if self.is_extended() {
            clinical_limits_deg(j)
        } else {
            skeleton::rotation_limits_deg(j)
        }
    }

    /// Whether the root travels along a path (walk, jog, crawl, circle, flight); the other kinds
    /// stay near the origin.
    pub const fn is_locomotion(self) -> bool {
        matches!(
            self,
            MotionKind::Walk
                | MotionKind::Jog
                | MotionKind::Crawl
                | MotionKind::Circle
                | MotionKind::Flight
        )
    }

    /// Whether [`MotionParams::side`] picks the lead limb (wave, reach, punch, kick, kneel,
    /// pickup, throw, overhead, stairs, flight); for [`MotionKind::Turn`] and [`MotionKind::Spin`] it
    /// picks the (first) turning direction instead.
    pub const fn is_one_sided(self) -> bool {
        matches!(
            self,
            MotionKind::Wave
                | MotionKind::Reach
                | MotionKind::Punch
                | MotionKind::Kick
                | MotionKind::Kneel
                | MotionKind::Pickup
                | MotionKind::Throw
                | MotionKind::Overhead
                | MotionKind::Stairs
                | MotionKind::Flight
        )
    }

    /// Range of [`MotionParams::speed`] drawn by [`MotionParams::sample`]: wide for slow motions,
    /// narrow where the nominal tempo already brings joint speeds near 7 rad/s (jog, punch).
    pub const fn speed_range(self) -> (f64, f64) {
        match self {
            MotionKind::Walk => (0.75, 1.2),
            MotionKind::Jog => (0.85, 1.1),
            MotionKind::Wave => (0.8, 1.25),
            MotionKind::Squat => (0.7, 1.3),
            MotionKind::Reach => (0.7, 1.3),
            MotionKind::Punch => (0.75, 1.2),
            MotionKind::Kick => (0.7, 1.2),
            MotionKind::Jump => (0.8, 1.2),
            MotionKind::Turn => (0.7, 1.3),
            MotionKind::Sit => (0.7, 1.3),
            MotionKind::Crouch => (0.7, 1.3),
            MotionKind::Kneel => (0.7, 1.3),
            MotionKind::Pickup => (0.7, 1.3),
            MotionKind::Throw => (0.7, 1.1),
            MotionKind::Overhead => (0.7, 1.3),
            MotionKind::Lie => (0.7, 1.3),
            MotionKind::Crawl => (0.7, 1.3),
            MotionKind::Fall => (0.8, 1.1),
            MotionKind::Stairs => (0.7, 1.3),
            MotionKind::Spin => (0.7, 1.2),
            MotionKind::Circle => (0.75, 1.2),
            MotionKind::Flight => (0.8, 1.1),
        }
    }
}

/// Rotation limits (degrees, `[(min, max); 3]` about x, y, z) of the extended kinds on the
/// default skeleton: papers/000's table ([`skeleton::rotation_limits_deg`]) with the ranges a
/// person has where that table is narrower, in this crate's convention (−x flexes a hip, +x flexes
/// a knee, +x plantar-flexes an ankle):
///
/// - hip flexion 120°, extension 30° (AAOS: Greene & Heckman, *The Clinical Measurement of Joint
///   Motion*, 1994);
/// - knee flexion 140° (Soucie et al. 2011, *Haemophilia* 17(3):500–507), hyperextension 10°;
/// - ankle dorsiflexion 20°, plantar flexion 50° (AAOS);
/// - shoulder: AAOS's 180° of flexion and abduction are 135° from the A-pose's 45°; as a box of
///   rotation-vector components about the A-pose arm, ±150° on the swing axes (y, z) and ±90° on
///   the twist (x, AAOS's 70° internal and 90° external rotation);
/// - elbow: AAOS's 150° of flexion about an axis 45° between −x and −y gives up to 106° on each
///   of x and y: ±110° there, papers/000's ±90° on z.
///
/// The root, the spine, the head, the feet and the hands keep papers/000's ranges.
pub fn clinical_limits_deg(j: usize) -> [(f64, f64); 3] {
    let mut limits = skeleton::rotation_limits_deg(j);
    match j {
        skeleton::R_HIP | L_HIP => limits[0] = (-120.0, 30.0),
        skeleton::R_KNEE | L_KNEE => limits[0] = (-10.0, 140.0),
        skeleton::R_ANKLE | L_ANKLE => limits[0] = (-20.0, 50.0),
        skeleton::R_SHOULDER | L_SHOULDER => {
            limits = [(-90.0, 90.0), (-150.0, 150.0), (-150.0, 150.0)];
        }
        skeleton::R_ELBOW | L_ELBOW => {
            limits[0] = (-110.0, 110.0);
            limits[1] = (-110.0, 110.0);
        }
        _ => {}
    }
    limits
}

impl fmt::Display for MotionKind {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

impl FromStr for MotionKind {
    type Err = UnknownMotionKind;

    /// Parses a kind's name, ignoring ASCII case and surrounding white space.
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        let name = s.trim();
        MotionKind::ALL
            .into_iter()
            .find(|k| k.name().eq_ignore_ascii_case(name))
            .ok_or_else(|| UnknownMotionKind {
                name: s.to_string(),
            })
    }
}

/// Body side of the lead limb of one-sided motions.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Side {
    /// The subject's left (+x).
    #[default]
    Left,
    /// The subject's right (−x).
    Right,
}

impl Side {
    /// The other side.
    pub const fn opposite(self) -> Side {
        match self {
            Side::Left => Side::Right,
            Side::Right => Side::Left,
        }
    }

    /// +1 for left, −1 for right (the sign of a turn towards that side about +y).
    pub const fn sign(self) -> f64 {
        match self {
            Side::Left => 1.0,
            Side::Right => -1.0,
        }
    }
}

/// The random knobs of one motion. [`motion_pose`] accepts any values (it sanitises them, see
/// [`MotionParams::sanitized`]); [`MotionParams::sample`] draws them from ranges where the motion
/// looks natural and stays smooth at 30 fps.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct MotionParams {
    /// Tempo scale: multiplies the cycle frequency (1 = nominal, e.g. 0.9 gait cycles/s for a walk)
    /// and, for walk and jog, the forward speed.
    pub speed: f64,
    /// Scale of the joint excursions, about 0.6–1.2 (1 = the typical ranges of the module docs).
    pub amplitude: f64,
    /// Phase offset of the motion's cycle, rad (2π = one full cycle).
    pub phase: f64,
    /// Yaw (rad, about +y; positive turns towards the subject's left) of the root path at t = 0 for
    /// walk and jog, the constant facing of the static motions, the centre of the yaw sweep of
    /// turn. Kept within ±[`YAW_LIMIT`].
    pub heading: f64,
    /// Turning rate of the path of walk and jog (rad/s) while the heading is near 0; the rate fades
    /// as the heading nears ±[`YAW_LIMIT`], which it never passes. Ignored by the other kinds.
    pub curvature: f64,
    /// Lead side of wave, reach, punch (the first punching arm) and kick; first turning direction
    /// of turn. Ignored by walk, jog, squat and jump.
    pub side: Side,
    /// Kind-specific variation in [0, 1]: target height of reach and punch, arm height of wave,
    /// depth of squat and jump, height of kick.
    pub style: f64,
    /// How far (rad) relaxed arms hang below the rest A-pose (0.35–0.6: 10–25° away from the body).
    pub arm_drop: f64,
}

impl Default for MotionParams {
    /// The nominal motion: speed 1, amplitude 1, phase 0, facing +z on a straight path, left lead.
    fn default() -> Self {
        Self {
            speed: 1.0,
            amplitude: 1.0,
            phase: 0.0,
            heading: 0.0,
            curvature: 0.0,
            side: Side::Left,
            style: 0.5,
            arm_drop: 0.5,
        }
    }
}

impl MotionParams {
    /// Draws the parameters of one `kind` motion: speed in [`MotionKind::speed_range`], amplitude
    /// in [0.6, 1.2), phase in [0, 2π), heading within ±0.6 rad (turn: what its sweep leaves of
    /// ±[`YAW_LIMIT`]), curvature within ±0.12 rad/s for walk and jog (a radius of 10 m or more at
    /// 1.3 m/s) and 0 otherwise, a fair side, a uniform style and an arm drop in [0.35, 0.6).
    ///
    /// The same number of draws is made for every kind, in a fixed order, so the same RNG state
    /// gives the same parameters.
    pub fn sample(kind: MotionKind, rng: &mut impl Rng) -> Self {
        let speed_u: f64 = rng.random();
        let amplitude = rng.random_range(0.6..1.2);
        let phase = rng.random_range(0.0..TAU);
        let heading_u: f64 = rng.random_range(-1.0..1.0);
        let curvature_u: f64 = rng.random_range(-1.0..1.0);
        let side = if rng.random_bool(0.5) {
            Side::Left
        } else {
            Side::Right
        };
        let style: f64 = rng.random();
        let arm_drop = rng.random_range(0.35..0.6);

        let (lo, hi) = kind.speed_range();
        let heading = match kind {
            MotionKind::Turn => heading_u * (YAW_LIMIT - turn_half_sweep(amplitude)),
            _ => heading_u * 0.6,
        };
        let curvature = if kind.is_locomotion() {
            curvature_u * 0.12
        } else {
            0.0
        };
        Self {
            speed: lo + (hi - lo) * speed_u,
            amplitude,
            phase,
            heading,
            curvature,
            side,
            style,
            arm_drop,
        }
    }

    /// The parameters [`motion_pose`] actually uses: non-finite values replaced by the
    /// [`Default`] ones, then speed clamped to [0.05, 3], amplitude to [0, 1.5], heading to
    /// ±0.98·[`YAW_LIMIT`], curvature to ±0.5 rad/s, style to [0, 1] and arm drop to [0, 0.75].
    pub fn sanitized(&self) -> Self {
        let d = Self::default();
        let pick = |v: f64, default: f64, lo: f64, hi: f64| {
            if v.is_finite() {
                v.clamp(lo, hi)
            } else {
                default
            }
        };
        let yaw = 0.98 * YAW_LIMIT;
        Self {
            speed: pick(self.speed, d.speed, 0.05, 3.0),
            amplitude: pick(self.amplitude, d.amplitude, 0.0, 1.5),
            phase: pick(self.phase, d.phase, f64::MIN, f64::MAX).rem_euclid(TAU),
            heading: pick(self.heading, d.heading, -yaw, yaw),
            curvature: pick(self.curvature, d.curvature, -0.5, 0.5),
            side: self.side,
            style: pick(self.style, d.style, 0.0, 1.0),
            arm_drop: pick(self.arm_drop, d.arm_drop, 0.0, 0.75),
        }
    }
}

/// The pose of a `kind` motion with parameters `params` at time `time_s` (seconds; any real, a
/// non-finite time is read as 0).
///
/// The result is finite, C1 (at least) in time, and its rotations lie within
/// [`MotionKind::limits_deg`] (for the classic kinds the limits of
/// [`lfit_model::Bounds::global`]). The root translation is the rest root position's offset: the
/// floor path (x, z) plus vertical motion (y); walks travel away from the origin (see
/// [`recentre`]).
pub fn motion_pose(kind: MotionKind, params: &MotionParams, time_s: f64) -> Pose {
    let mut pose = motion_pose_unclamped(kind, params, time_s);
    clamp_rotations(&mut pose, kind);
    pose
}

/// `frames` poses of a motion sampled at `fps` frames per second from `start_time` (s):
/// frame i is [`motion_pose`] at `start_time + i / fps`. A non-finite or non-positive `fps`
/// yields `frames` copies of the pose at `start_time`.
pub fn sequence(
    kind: MotionKind,
    params: &MotionParams,
    fps: f64,
    frames: usize,
    start_time: f64,
) -> Vec<Pose> {
    let dt = if fps.is_finite() && fps > 0.0 {
        1.0 / fps
    } else {
        0.0
    };
    (0..frames)
        .map(|i| motion_pose(kind, params, start_time + i as f64 * dt))
        .collect()
}

/// Shifts the root x and z of every pose by one common offset so that their mean is 0, then
/// clamps each pose's root x and z into ±[`RECENTRE_LIMIT`] (on a straight walk at constant speed
/// the clamp acts only on paths longer than 2.4 m: it then holds the ends of the path still).
/// Root y and the rotations are left alone. Non-finite root values make the offset non-finite;
/// the poses from [`motion_pose`] are always finite.
pub fn recentre(poses: &mut [Pose]) {
    if poses.is_empty() {
        return;
    }
    let n = poses.len() as f64;
    let mean_x = poses.iter().map(|p| p[0]).sum::<f64>() / n;
    let mean_z = poses.iter().map(|p| p[2]).sum::<f64>() / n;
    for p in poses.iter_mut() {
        p[0] = (p[0] - mean_x).clamp(-RECENTRE_LIMIT, RECENTRE_LIMIT);
        p[2] = (p[2] - mean_z).clamp(-RECENTRE_LIMIT, RECENTRE_LIMIT);
    }
}

// ---------------------------------------------------------------------------------------------
// Assembly: heading frame → world.

/// A motion's body pose in its heading frame (root rotation and translation relative to the
/// heading frame) plus the heading frame's yaw and floor position.
struct Local {
    body: Body,
    yaw: f64,
    path: DVec3,
}

impl Local {
    fn fixed(body: Body, yaw: f64) -> Self {
        Self {
            body,
            yaw,
            path: DVec3::ZERO,
        }
    }
}

/// [`motion_pose`] before the final clamp into the rotation limits.
fn motion_pose_unclamped(kind: MotionKind, params: &MotionParams, time_s: f64) -> Pose {
    let p = params.sanitized();
    let t = if time_s.is_finite() { time_s } else { 0.0 };
    let Local { body, yaw, path } = match kind {
        MotionKind::Walk => gait(&WALK, &p, t),
        MotionKind::Jog => gait(&JOG, &p, t),
        MotionKind::Wave => wave(&p, t),
        MotionKind::Squat => squat(&p, t),
        MotionKind::Reach => reach(&p, t),
        MotionKind::Punch => punch(&p, t),
        MotionKind::Kick => kick(&p, t),
        MotionKind::Jump => jump(&p, t),
        MotionKind::Turn => turn(&p, t),
        MotionKind::Sit => sit(&p, t),
        MotionKind::Crouch => deep_crouch(&p, t),
        MotionKind::Kneel => kneel(&p, t),
        MotionKind::Pickup => pickup(&p, t),
        MotionKind::Throw => throw(&p, t),
        MotionKind::Overhead => overhead(&p, t),
        MotionKind::Lie => lie(&p, t),
        MotionKind::Crawl => crawl(&p, t),
        MotionKind::Fall => fall(&p, t),
        MotionKind::Stairs => stairs(&p, t),
        MotionKind::Spin => spin(&p, t),
        MotionKind::Circle => circle(&p, t),
        MotionKind::Flight => flight(&p, t),
    };
    let mut pose = if kind.is_one_sided() && p.side == Side::Right {
        mirror_pose(&body.pose)
    } else {
        body.pose
    };
    let heading = DQuat::from_rotation_y(yaw);
    let root = rotvec(heading * DQuat::from_scaled_axis(joint(&pose, ROOT)));
    set_joint(&mut pose, ROOT, root);
    let offset = path + heading * DVec3::new(pose[0], pose[1], pose[2]);
    pose[..3].copy_from_slice(&offset.to_array());
    pose
}

/// Clamps every rotation into `kind`'s [`MotionKind::limits_deg`]; returns whether anything
/// moved.
fn clamp_rotations(pose: &mut Pose, kind: MotionKind) -> bool {
    let mut clamped = false;
    for j in 0..NUM_JOINTS {
        for (axis, (lo, hi)) in kind.limits_deg(j).into_iter().enumerate() {
            let i = rot_offset(j) + axis;
            let v = pose[i].clamp(lo.to_radians(), hi.to_radians());
            clamped |= v != pose[i];
            pose[i] = v;
        }
    }
    clamped
}

/// The left–right mirror image of a pose: the sagittal plane x = 0 reflects positions
/// (`t_x → −t_x`) and axis-angle vectors (`(x, y, z) → (x, −y, −z)`), and left and right joints
/// swap.
fn mirror_pose(pose: &Pose) -> Pose {
    let mut out = [0.0; POSE_DIM];
    out[0] = -pose[0];
    out[1] = pose[1];
    out[2] = pose[2];
    for j in 0..NUM_JOINTS {
        set_joint(&mut out, skeleton::mirror(j), mirror_rotvec(joint(pose, j)));
    }
    out
}

fn mirror_rotvec(r: DVec3) -> DVec3 {
    DVec3::new(r.x, -r.y, -r.z)
}

fn joint(pose: &Pose, j: usize) -> DVec3 {
    let o = rot_offset(j);
    DVec3::new(pose[o], pose[o + 1], pose[o + 2])
}

fn set_joint(pose: &mut Pose, j: usize, r: DVec3) {
    let o = rot_offset(j);
    pose[o..o + 3].copy_from_slice(&r.to_array());
}

/// The axis-angle vector (log map) of a unit quaternion, with angle in [0, π].
fn rotvec(q: DQuat) -> DVec3 {
    let q = if q.w < 0.0 { -q } else { q };
    let v = q.xyz();
    let s = v.length();
    if s < 1e-12 {
        2.0 * v
    } else {
        v * (2.0 * s.atan2(q.w) / s)
    }
}

/// A pose under construction, in the heading frame.
#[derive(Clone)]
struct Body {
    pose: Pose,
}

impl Body {
    fn new() -> Self {
        Self {
            pose: [0.0; POSE_DIM],
        }
    }

    /// Sets a midline joint's rotation.
    fn set(&mut self, j: usize, r: DVec3) {
        set_joint(&mut self.pose, j, r);
    }

    /// Sets the rotation of `left_joint` or of its mirror on the right, `r` being given in the
    /// left side's convention (so the same numbers give mirror-symmetric motions).
    fn limb(&mut self, side: Side, left_joint: usize, r: DVec3) {
        match side {
            Side::Left => set_joint(&mut self.pose, left_joint, r),
            Side::Right => set_joint(
                &mut self.pose,
                skeleton::mirror(left_joint),
                mirror_rotvec(r),
            ),
        }
    }

    /// Sets the root translation (heading frame).
    fn translate(&mut self, t: DVec3) {
        self.pose[..3].copy_from_slice(&t.to_array());
    }
}

// ---------------------------------------------------------------------------------------------
// Small smooth building blocks.

/// A vector of angles given in degrees, in radians.
fn deg(x: f64, y: f64, z: f64) -> DVec3 {
    DVec3::new(x, y, z) * (PI / 180.0)
}

/// A periodic (period 1 in `phase`) von Mises bump: 1 at `centre`, `exp(−2κ)` opposite.
fn bump(phase: f64, centre: f64, kappa: f64) -> f64 {
    (kappa * ((TAU * (phase - centre)).cos() - 1.0)).exp()
}

/// A periodic raised-cosine pulse `((1 + cos)/2)^n`: 1 at `centre`, 0 half a period away.
fn pulse(phase: f64, centre: f64, n: i32) -> f64 {
    (0.5 * (1.0 + (TAU * (phase - centre)).cos())).powi(n)
}

/// `3x² − 2x³`.
fn smoothstep(x: f64) -> f64 {
    x * x * (3.0 - 2.0 * x)
}

/// A periodic 0 → 1 → 0 profile (period 1) that dwells at both ends: 0 at phase 0, 1 at 0.5.
fn dwell(phase: f64) -> f64 {
    smoothstep(0.5 * (1.0 - (TAU * phase).cos()))
}

/// Linear interpolation between two rotation vectors (stays inside any box containing both).
fn lerp(a: DVec3, b: DVec3, s: f64) -> DVec3 {
    a + (b - a) * s
}

/// A key of a piecewise cubic Hermite curve: time, value, derivative.
#[derive(Debug, Clone, Copy)]
struct Key {
    t: f64,
    v: f64,
    d: f64,
}

const fn key(t: f64, v: f64, d: f64) -> Key {
    Key { t, v, d }
}

/// The C1 piecewise cubic Hermite curve through `keys` (sorted by time); constant outside.
fn hermite(keys: &[Key], t: f64) -> f64 {
    let (Some(first), Some(last)) = (keys.first(), keys.last()) else {
        return 0.0;
    };
    if t <= first.t {
        return first.v;
    }
    for w in keys.windows(2) {
        let (k0, k1) = (w[0], w[1]);
        if t <= k1.t {
            let h = k1.t - k0.t;
            if h <= 0.0 {
                return k1.v;
            }
            let s = (t - k0.t) / h;
            let (s2, s3) = (s * s, s * s * s);
            return (2.0 * s3 - 3.0 * s2 + 1.0) * k0.v
                + (s3 - 2.0 * s2 + s) * h * k0.d
                + (3.0 * s2 - 2.0 * s3) * k1.v
                + (s3 - s2) * h * k1.d;
        }
    }
    last.v
}

// ---------------------------------------------------------------------------------------------
// Arms and legs (left-side convention; `Body::limb` mirrors them for the right).

/// Rest direction of the left upper arm (A-pose).
fn rest_arm() -> DVec3 {
    DVec3::new(A_POSE.cos(), -A_POSE.sin(), 0.0)
}

/// Left elbow flexion by `angle` (rad): about the axis perpendicular to the rest arm and to +z,
/// which brings the forearm forward.
fn elbow_flex(angle: f64) -> DVec3 {
    DVec3::new(-A_POSE.sin(), -A_POSE.cos(), 0.0) * angle
}

/// Left shoulder of a relaxed arm: lowered by `drop` from the A-pose towards the body, then
/// swung in the sagittal plane by `swing` (rad; negative = forward).
fn hanging_arm(drop: f64, swing: f64) -> DVec3 {
    rotvec(DQuat::from_rotation_x(swing) * DQuat::from_rotation_z(-drop))
}

/// Left shoulder rotation that points the upper arm along `dir` (heading/trunk frame of the
/// parent). The shortest arc is used when it fits the shoulder's limits; otherwise a humeral
/// twist (about the rest arm, which leaves the arm's direction unchanged) is searched for the
/// rotation vector that best fits them.
fn arm_towards(dir: DVec3) -> DVec3 {
    arm_towards_within(dir, skeleton::rotation_limits_deg(L_SHOULDER))
}

/// [`arm_towards`] within the shoulder limits `limits` (degrees per axis).
fn arm_towards_within(dir: DVec3, limits: [(f64, f64); 3]) -> DVec3 {
    let a = rest_arm();
    let d = dir.try_normalize().unwrap_or(DVec3::Z);
    let arc = DQuat::from_rotation_arc(a, d);
    let usage = |r: DVec3| {
        r.to_array()
            .into_iter()
            .zip(limits)
            .map(|(v, (lo, hi))| {
                if v >= 0.0 {
                    v / hi.to_radians()
                } else {
                    v / lo.to_radians()
                }
            })
            .fold(0.0, f64::max)
    };
    let best = rotvec(arc);
    if usage(best) <= 0.95 {
        return best;
    }
    (-40..=40)
        .map(|k| {
            let twist = f64::from(k) * 1.5_f64.to_radians();
            rotvec(arc * DQuat::from_axis_angle(a, twist))
        })
        .fold((best, usage(best)), |(b, u), r| {
            let ur = usage(r);
            if ur < u { (r, ur) } else { (b, u) }
        })
        .0
}

/// Unit direction from yaw `azimuth` (rad, positive outwards for the left arm) and `elevation`.
fn direction(azimuth: f64, elevation: f64) -> DVec3 {
    DVec3::new(
        azimuth.sin() * elevation.cos(),
        elevation.sin(),
        azimuth.cos() * elevation.cos(),
    )
}

/// Both relaxed arms, with sagittal swings and elbow flexions per side (rad).
fn relaxed_arms(body: &mut Body, drop: f64, swing: [f64; 2], elbow: [f64; 2]) {
    for (i, side) in [Side::Left, Side::Right].into_iter().enumerate() {
        body.limb(side, L_SHOULDER, hanging_arm(drop, swing[i]));
        body.limb(side, L_ELBOW, elbow_flex(elbow[i]));
    }
}

/// Ankle dorsiflexion per unit of shank lean in a crouch: less than 1 (the heels lift a little)
/// because the ankle's dorsiflexion limit is only 10°.
const CROUCH_ANKLE: f64 = 0.45;

/// Hip drop (m, ≥ 0) and backward hip shift (m, ≤ 0 is back) of a crouch whose thigh leans
/// forward by `alpha` and whose shank leans forward by `beta·alpha` (feet flat and fixed).
fn crouch_offset(alpha: f64, beta: f64) -> (f64, f64) {
    let drop = THIGH * (1.0 - alpha.cos()) + SHANK * (1.0 - (beta * alpha).cos());
    let shift = SHANK * (beta * alpha).sin() - THIGH * alpha.sin();
    (drop, shift)
}

/// The thigh angle whose crouch drops the hips by `drop` (m), by bisection on [0, 1.5] rad.
fn crouch_angle(drop: f64, beta: f64) -> f64 {
    let (mut lo, mut hi) = (0.0, 1.5);
    for _ in 0..50 {
        let mid = 0.5 * (lo + hi);
        if crouch_offset(mid, beta).0 < drop {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    0.5 * (lo + hi)
}

/// Crouches both legs (thigh world angle −`alpha`, shank `beta·alpha`) under a root pitched
/// forward by `pitch`: the hips flex by `alpha + pitch`, the knees by `(1 + beta)·alpha`, the
/// ankles dorsiflex by `ankle` times the shank lean (1: the foot flat; less lifts the heels —
/// the papers' ankle limit is 10°, so their squats take [`CROUCH_ANKLE`]).
fn crouch_legs(body: &mut Body, alpha: f64, beta: f64, pitch: f64, ankle: f64) {
    for side in [Side::Left, Side::Right] {
        leg(
            body,
            side,
            alpha + pitch,
            (1.0 + beta) * alpha,
            ankle * beta * alpha,
        );
    }
}

// ---------------------------------------------------------------------------------------------
// Root path of walk and jog.

/// The heading at time `t`: `YAW_LIMIT · tanh(atanh(heading / YAW_LIMIT) + curvature·t / YAW_LIMIT)`,
/// which starts at `heading` with rate about `curvature` and never leaves ±[`YAW_LIMIT`].
fn path_yaw(heading: f64, curvature: f64, t: f64) -> f64 {
    YAW_LIMIT * ((heading / YAW_LIMIT).atanh() + curvature * t / YAW_LIMIT).tanh()
}

/// `∫₀ᵗ (sin ψ, cos ψ) ds` for the heading ψ of [`path_yaw`]: the (x, z) path of unit speed.
/// Integrated in `u = atanh(ψ / YAW_LIMIT)`, where the integrand is constant beyond |u| = 20, so
/// the cost is bounded whatever `t` is.
fn path_integral(heading: f64, curvature: f64, t: f64) -> DVec2 {
    let u0 = (heading / YAW_LIMIT).atanh();
    if curvature.abs() < 1e-9 {
        let psi = YAW_LIMIT * u0.tanh();
        return DVec2::new(psi.sin(), psi.cos()) * t;
    }
    let du = curvature * t / YAW_LIMIT;
    let (a, b) = if du >= 0.0 {
        (u0, u0 + du)
    } else {
        (u0 + du, u0)
    };
    let integral = integrate_heading(a, b);
    let signed = if du >= 0.0 { integral } else { -integral };
    signed * (YAW_LIMIT / curvature)
}

/// `∫ₐᵇ (sin, cos)(YAW_LIMIT · tanh u) du` for a ≤ b.
fn integrate_heading(a: f64, b: f64) -> DVec2 {
    const U: f64 = 20.0;
    let g = |u: f64| {
        let psi = YAW_LIMIT * u.tanh();
        DVec2::new(psi.sin(), psi.cos())
    };
    let mut total = DVec2::ZERO;
    if a < -U {
        total += g(-U) * (b.min(-U) - a);
    }
    if b > U {
        total += g(U) * (b - a.max(U));
    }
    let (lo, hi) = (a.max(-U), b.min(U));
    if hi > lo {
        // 5-point Gauss–Legendre on pieces of at most 0.5 in u.
        const NODES: [f64; 5] = [
            0.0,
            -0.538_469_310_105_683,
            0.538_469_310_105_683,
            -0.906_179_845_938_664,
            0.906_179_845_938_664,
        ];
        const WEIGHTS: [f64; 5] = [
            0.568_888_888_888_889,
            0.478_628_670_499_366,
            0.478_628_670_499_366,
            0.236_926_885_056_189,
            0.236_926_885_056_189,
        ];
        let pieces = ((hi - lo) / 0.5).ceil().max(1.0) as usize;
        let h = (hi - lo) / pieces as f64;
        for k in 0..pieces {
            let mid = lo + (k as f64 + 0.5) * h;
            for (x, w) in NODES.iter().zip(WEIGHTS) {
                total += g(mid + 0.5 * h * x) * (w * 0.5 * h);
            }
        }
    }
    total
}

// ---------------------------------------------------------------------------------------------
// Walk and jog.

/// Shape of a gait cycle (degrees, metres, Hz, m/s). Phase 0 is the left heel strike; the right
/// leg runs half a cycle later.
struct GaitShape {
    /// Gait cycles per second at speed 1 (a cycle is two steps).
    freq: f64,
    /// Forward speed at speed 1 and amplitude 1 (m/s).
    speed: f64,
    /// Hip flexion: mean, half range and phase of the peak of the first harmonic, amplitude and
    /// first peak of the second harmonic (it makes stance extension steadier than a sinusoid).
    hip_mean: f64,
    hip_amp: f64,
    hip_peak: f64,
    hip_h2: f64,
    hip_h2_peak: f64,
    /// Knee flexion: base, loading bump (height, phase) and swing peak (height, phase, width κ).
    knee_base: f64,
    knee_stance: f64,
    knee_stance_at: f64,
    knee_stance_kappa: f64,
    knee_swing: f64,
    knee_swing_at: f64,
    knee_kappa: f64,
    /// Ankle: stance dorsiflexion (depth, phase) and push-off plantar-flexion (height, phase).
    ankle_dorsi: f64,
    ankle_dorsi_at: f64,
    ankle_plantar: f64,
    ankle_plantar_at: f64,
    /// Phase of mid-stance of the left leg (pelvis obliquity and lateral sway peak there).
    stance_mid: f64,
    /// Root vertical excursion (half range, m), mean drop (m) and phase of the lowest point.
    bob: f64,
    bob_mean: f64,
    bob_low_at: f64,
    /// Lateral sway of the root towards the stance leg (m).
    sway: f64,
    /// Pelvis rotation and obliquity half ranges, pelvis forward tilt.
    pelvis_yaw: f64,
    pelvis_roll: f64,
    pelvis_pitch: f64,
    /// Thorax counter-rotation half range and forward lean.
    thorax_yaw: f64,
    trunk_lean: f64,
    /// Arm swing half range and mean (negative = forward), elbow flexion mean and half range.
    arm_swing: f64,
    arm_mean: f64,
    elbow_mean: f64,
    elbow_amp: f64,
}

/// Normal walking (Winter 1991, Perry 1992): 0.9 cycles/s (108 steps/min) at 1.3 m/s. The hip is
/// the first two Fourier harmonics of the textbook curve, widened to about 33° of flexion and 17°
/// of extension (5° more than textbook, so that the stance foot slides less under the constant
/// root speed); knee 4° at heel strike, 18° loading bump, 60° in swing at 72 % of the cycle.
const WALK: GaitShape = GaitShape {
    freq: 0.9,
    speed: 1.3,
    hip_mean: 8.0,
    hip_amp: 23.0,
    hip_peak: -0.017,
    hip_h2: 3.5,
    hip_h2_peak: 0.302,
    knee_base: 4.0,
    knee_stance: 14.0,
    knee_stance_at: 0.17,
    knee_stance_kappa: 4.0,
    knee_swing: 55.0,
    knee_swing_at: 0.72,
    knee_kappa: 3.0,
    ankle_dorsi: 7.0,
    ankle_dorsi_at: 0.42,
    ankle_plantar: 16.0,
    ankle_plantar_at: 0.62,
    stance_mid: 0.25,
    bob: 0.02,
    bob_mean: 0.01,
    bob_low_at: 0.0,
    sway: 0.02,
    pelvis_yaw: 4.0,
    pelvis_roll: 3.0,
    pelvis_pitch: 2.0,
    thorax_yaw: 5.0,
    trunk_lean: 2.0,
    arm_swing: 16.0,
    arm_mean: -3.0,
    elbow_mean: 20.0,
    elbow_amp: 8.0,
};

/// Easy jogging (Novacheck 1998, slowed for 30 fps): 1.2 cycles/s (144 steps/min) at 2.3 m/s,
/// stance about 40 % of the cycle, knee near 40° at mid-stance and about 70° in swing.
const JOG: GaitShape = GaitShape {
    freq: 1.2,
    speed: 2.3,
    hip_mean: 15.0,
    hip_amp: 24.0,
    hip_peak: 0.92,
    hip_h2: 0.0,
    hip_h2_peak: 0.0,
    knee_base: 12.0,
    knee_stance: 25.0,
    knee_stance_at: 0.17,
    knee_stance_kappa: 8.0,
    knee_swing: 58.0,
    knee_swing_at: 0.7,
    knee_kappa: 2.0,
    ankle_dorsi: 8.0,
    ankle_dorsi_at: 0.2,
    ankle_plantar: 18.0,
    ankle_plantar_at: 0.42,
    stance_mid: 0.18,
    bob: 0.03,
    bob_mean: 0.03,
    bob_low_at: 0.17,
    sway: 0.015,
    pelvis_yaw: 5.0,
    pelvis_roll: 4.0,
    pelvis_pitch: 5.0,
    thorax_yaw: 8.0,
    trunk_lean: 4.0,
    arm_swing: 20.0,
    arm_mean: -8.0,
    elbow_mean: 80.0,
    elbow_amp: 12.0,
};

fn gait(shape: &GaitShape, p: &MotionParams, t: f64) -> Local {
    let a = p.amplitude;
    // Knee and ankle peaks scale less than the hips: they set the peak joint speeds.
    let ka = 0.7 + 0.3 * a;
    let phase = shape.freq * p.speed * t + p.phase / TAU;
    let mut body = Body::new();

    for (side, offset) in [(Side::Left, 0.0), (Side::Right, 0.5)] {
        let phi = phase + offset;
        let swing = (TAU * (phi - shape.hip_peak)).cos(); // 1 at peak hip flexion
        let stance = (TAU * (phi - shape.stance_mid)).cos(); // 1 at mid-stance
        let h2 = (2.0 * TAU * (phi - shape.hip_h2_peak)).cos();
        let hip = deg(
            -(shape.hip_mean + shape.hip_amp * a * swing + shape.hip_h2 * a * h2),
            -3.0 * a * swing,
            -2.5 * a * stance,
        );
        let knee = shape.knee_base
            + ka * (shape.knee_stance * bump(phi, shape.knee_stance_at, shape.knee_stance_kappa)
                + shape.knee_swing * bump(phi, shape.knee_swing_at, shape.knee_kappa));
        let ankle = ka
            * (shape.ankle_plantar * bump(phi, shape.ankle_plantar_at, 8.0)
                - shape.ankle_dorsi * bump(phi, shape.ankle_dorsi_at, 4.0));
        let toes = -8.0 * ka * bump(phi, shape.ankle_plantar_at - 0.05, 8.0);
        body.limb(side, L_HIP, hip);
        body.limb(side, L_KNEE, deg(knee, 0.0, 0.0));
        body.limb(side, L_ANKLE, deg(ankle, 0.0, 0.0));
        body.limb(side, L_FOOT, deg(toes, 0.0, 0.0));
        // The arm swings against the same-side leg: back while that hip is flexed.
        let arm = (shape.arm_mean + shape.arm_swing * a * swing).to_radians();
        let elbow = (shape.elbow_mean - shape.elbow_amp * a * swing).to_radians();
        body.limb(side, L_SHOULDER, hanging_arm(p.arm_drop, arm));
        body.limb(side, L_ELBOW, elbow_flex(elbow));
        body.limb(side, L_HAND, deg(0.0, -4.0 * a * swing, 0.0));
    }

    // Pelvis turns with the forward leg (left side forward = −y), drops on the swing side.
    let swing = (TAU * (phase - shape.hip_peak)).cos();
    let stance = (TAU * (phase - shape.stance_mid)).cos();
    let pelvis_yaw = -shape.pelvis_yaw * a * swing;
    let pitch = shape.pelvis_pitch + (TAU * 2.0 * phase).sin();
    body.set(ROOT, deg(pitch, pelvis_yaw, shape.pelvis_roll * a * stance));
    let lower_yaw = -0.3 * pelvis_yaw;
    body.set(
        LOWER_TORSO,
        deg(0.0, lower_yaw, -0.5 * shape.pelvis_roll * a * stance),
    );
    let thorax_yaw = shape.thorax_yaw * a * swing;
    body.set(MIDDLE_TORSO, deg(shape.trunk_lean, thorax_yaw, 0.0));
    body.set(
        HEAD,
        deg(
            -0.8 * (pitch + shape.trunk_lean),
            -0.8 * (pelvis_yaw + lower_yaw + thorax_yaw),
            -0.3 * shape.pelvis_roll * a * stance,
        ),
    );
    let bob = -shape.bob_mean - shape.bob * a * (2.0 * TAU * (phase - shape.bob_low_at)).cos();
    body.translate(DVec3::new(shape.sway * a * stance, bob, 0.0));

    let v = shape.speed * p.speed * (0.55 + 0.45 * a);
    let path = path_integral(p.heading, p.curvature, t) * v;
    Local {
        body,
        yaw: path_yaw(p.heading, p.curvature, t),
        path: DVec3::new(path.x, 0.0, path.y),
    }
}

// ---------------------------------------------------------------------------------------------
// Static motions (left lead; mirrored by the caller for a right lead).

/// Standing legs with a slow idle weight shift (about 0.2 Hz, ±1.5 cm).
fn idle_legs(body: &mut Body, t: f64, phase: f64) -> DVec3 {
    let shift = (TAU * 0.2 * t + phase).sin();
    for side in [Side::Left, Side::Right] {
        body.limb(side, L_HIP, deg(-2.0, 0.0, 1.5 * side.sign() * shift));
        body.limb(side, L_KNEE, deg(4.0, 0.0, 0.0));
        body.limb(side, L_ANKLE, deg(-2.0, 0.0, 0.0));
    }
    DVec3::new(0.015 * shift, -0.003, 0.0)
}

/// Wave: the left arm rises (abducted to about horizontal, slightly forward), the forearm stands
/// up and waves side to side at about 1.8 Hz (±20°); it stays up for half of a 5 s cycle.
fn wave(p: &MotionParams, t: f64) -> Local {
    let (a, s) = (p.amplitude, p.speed);
    let up = dwell(s * t / 5.0 + p.phase / TAU);
    let osc = (TAU * 1.8 * s * t + p.phase).sin() * (0.7 + 0.3 * a);
    let mut body = Body::new();
    let root_shift = idle_legs(&mut body, t, p.phase);
    body.translate(root_shift);

    let raised = deg(0.0, -10.0 - 8.0 * p.style, 48.0 + 10.0 * p.style);
    body.limb(
        Side::Left,
        L_SHOULDER,
        lerp(hanging_arm(p.arm_drop, 0.0), raised, up),
    );
    let forearm_up = elbow_flex(15f64.to_radians()) + deg(0.0, 0.0, 65.0 + 20.0 * osc);
    body.limb(
        Side::Left,
        L_ELBOW,
        lerp(elbow_flex(12f64.to_radians()), forearm_up, up),
    );
    body.limb(Side::Left, L_HAND, deg(0.0, 0.0, 10.0 * up * osc));
    let idle = (TAU * 0.2 * t + p.phase).sin();
    body.limb(
        Side::Right,
        L_SHOULDER,
        hanging_arm(p.arm_drop, (3.0 * idle).to_radians()),
    );
    body.limb(Side::Right, L_ELBOW, elbow_flex(12f64.to_radians()));
    // The trunk bends a little away from the raised arm, the head tilts towards it.
    body.set(MIDDLE_TORSO, deg(1.0, 0.0, 4.0 * up));
    body.set(HEAD, deg(0.0, 5.0 * up * a, -6.0 * up));
    Local::fixed(body, p.heading)
}

/// Squat: 3.5 s cycles that dwell standing and at the bottom; thighs to 40–66° forward (root
/// 11–27 cm down), knees to 55–85°, trunk leaning 30–46° forward, hips back, arms forward for
/// balance; the feet stay planted ([`crouch_offset`]).
fn squat(p: &MotionParams, t: f64) -> Local {
    let q = dwell(p.speed * t / 3.5 + p.phase / TAU);
    let depth = ((0.6 + 0.45 * p.amplitude) * (0.85 + 0.2 * p.style)).min(1.15);
    let alpha = depth * q;
    let beta = 0.28;
    let pitch = 0.35 * alpha;
    let mut body = Body::new();
    crouch_legs(&mut body, alpha, beta, pitch, CROUCH_ANKLE);
    let (drop, shift) = crouch_offset(alpha, beta);
    body.translate(DVec3::new(0.0, -drop, shift));
    body.set(ROOT, DVec3::new(pitch, 0.0, 0.0));
    body.set(LOWER_TORSO, DVec3::new(0.2 * alpha, 0.0, 0.0));
    body.set(MIDDLE_TORSO, DVec3::new(0.15 * alpha, 0.0, 0.0));
    body.set(HEAD, DVec3::new(-0.3 * alpha, 0.0, 0.0));
    let forward = arm_towards(direction(17f64.to_radians(), 0.0));
    for side in [Side::Left, Side::Right] {
        body.limb(
            side,
            L_SHOULDER,
            lerp(hanging_arm(p.arm_drop, 0.0), forward, 0.9 * q),
        );
        body.limb(side, L_ELBOW, elbow_flex((12.0 - 6.0 * q).to_radians()));
    }
    Local::fixed(body, p.heading)
}

/// Reach: over 4 s cycles the left arm reaches out to a target between 10° below and 25° above
/// shoulder height, 22–28° outwards of the (turned) trunk, holds, and comes back; the trunk leans and turns towards it.
fn reach(p: &MotionParams, t: f64) -> Local {
    let a = p.amplitude;
    let r = dwell(p.speed * t / 4.0 + p.phase / TAU);
    let elevation = (-10.0 + 35.0 * p.style).to_radians();
    let azimuth = (22.0 + 6.0 * p.style).to_radians();
    let mut body = Body::new();

    let pitch = (5.0 * a * r).to_radians();
    for side in [Side::Left, Side::Right] {
        body.limb(
            side,
            L_HIP,
            DVec3::new(-pitch, 0.0, 0.0) + deg(-3.0 * r, 0.0, 0.0),
        );
        body.limb(side, L_KNEE, deg(6.0 * r, 0.0, 0.0));
        body.limb(side, L_ANKLE, deg(-3.0 * r, 0.0, 0.0));
    }
    body.translate(DVec3::new(0.0, -0.015 * r, 0.06 * a * r));
    body.set(ROOT, DVec3::new(pitch, 0.0, 0.0));
    body.set(LOWER_TORSO, deg(7.0 * a * r, -6.0 * a * r, -2.0 * a * r));
    body.set(MIDDLE_TORSO, deg(8.0 * a * r, -9.0 * a * r, -3.0 * a * r));
    body.set(
        HEAD,
        DVec3::new(-0.3 * elevation * r, 0.0, 0.0) + deg(-6.0 * a * r, 9.0 * a * r, 0.0),
    );

    let target = arm_towards(direction(azimuth, elevation));
    body.limb(
        Side::Left,
        L_SHOULDER,
        lerp(hanging_arm(p.arm_drop, 0.0), target, r),
    );
    let elbow = 12.0 * (1.0 - r) + 4.0 * r + 30.0 * (PI * r).sin();
    body.limb(Side::Left, L_ELBOW, elbow_flex(elbow.to_radians()));
    body.limb(Side::Left, L_HAND, deg(0.0, -8.0 * r, 0.0));
    body.limb(
        Side::Right,
        L_SHOULDER,
        hanging_arm(p.arm_drop, (6.0 * r).to_radians()),
    );
    body.limb(
        Side::Right,
        L_ELBOW,
        elbow_flex((15.0 + 10.0 * r).to_radians()),
    );
    Local::fixed(body, p.heading)
}

/// Punch: a guard (upper arms down and forward, elbows bent about 110°, fists at the chest), and
/// alternating straight punches, left first, 0.7 cycles/s (one punch per arm per cycle), each
/// with a trunk twist that brings the punching shoulder forward; slightly staggered stance.
fn punch(p: &MotionParams, t: f64) -> Local {
    let a = p.amplitude;
    let phi = 0.7 * p.speed * t + p.phase / TAU;
    let hits = [pulse(phi, 0.25, 2), pulse(phi, 0.75, 2)];
    let twist = a * (hits[0] - hits[1]);
    let mut body = Body::new();

    let guard_shoulder = hanging_arm(35f64.to_radians(), -30f64.to_radians());
    let elevation = (-5.0 + 15.0 * p.style).to_radians();
    let target = arm_towards(direction(20f64.to_radians(), elevation));
    for (side, hit) in [(Side::Left, hits[0]), (Side::Right, hits[1])] {
        body.limb(side, L_SHOULDER, lerp(guard_shoulder, target, hit));
        body.limb(
            side,
            L_ELBOW,
            elbow_flex((110.0 - 105.0 * hit).to_radians()),
        );
        body.limb(side, L_HAND, deg(0.0, 0.0, -5.0 * hit));
    }
    // Left foot forward; knees soft; a small bounce at twice the punch rate.
    body.limb(Side::Left, L_HIP, deg(-12.0, 0.0, 3.0));
    body.limb(Side::Right, L_HIP, deg(6.0, 0.0, 3.0));
    for side in [Side::Left, Side::Right] {
        body.limb(side, L_KNEE, deg(15.0, 0.0, 0.0));
        body.limb(side, L_ANKLE, deg(-6.0, 0.0, 0.0));
    }
    let bounce = (2.0 * TAU * phi).sin();
    body.translate(DVec3::new(
        -0.01 * twist,
        -0.03 - 0.008 * bounce,
        0.03 * (hits[0] + hits[1]),
    ));
    let root_yaw = -6.0 - 4.0 * twist;
    let lower_yaw = -8.0 * twist;
    let thorax_yaw = -12.0 * twist;
    body.set(ROOT, deg(3.0, root_yaw, 0.0));
    body.set(LOWER_TORSO, deg(2.0, lower_yaw, 0.0));
    body.set(MIDDLE_TORSO, deg(3.0, thorax_yaw, 0.0));
    body.set(
        HEAD,
        deg(-6.0, -0.6 * (root_yaw + lower_yaw + thorax_yaw), 0.0),
    );
    Local::fixed(body, p.heading)
}

/// Kick: every 2.4 s the left leg chambers (knee up and bent), snaps forward to 35–80° of hip
/// flexion with the knee nearly straight and the toes pointed, and comes back down; the trunk
/// leans back, the standing knee softens, the arms open and counter-swing.
fn kick(p: &MotionParams, t: f64) -> Local {
    let phi = p.speed * t / 2.4 + p.phase / TAU;
    let h = pulse(phi, 0.4, 2);
    let height = (p.amplitude * (0.85 + 0.25 * p.style)).min(1.15);
    let mut body = Body::new();

    let pitch = (-10.0 * height * h).to_radians();
    body.set(ROOT, DVec3::new(pitch, 0.0, 0.0));
    body.set(MIDDLE_TORSO, deg(6.0 * h, 0.0, 0.0));
    body.set(
        HEAD,
        DVec3::new(-0.5 * pitch, 0.0, 0.0) + deg(-3.0 * h, 0.0, 0.0),
    );
    body.limb(Side::Left, L_HIP, deg(-70.0 * height * h, 0.0, 0.0));
    let chamber = 4.0 * h * (1.0 - h);
    body.limb(Side::Left, L_KNEE, deg(60.0 * chamber + 8.0 * h, 0.0, 0.0));
    body.limb(Side::Left, L_ANKLE, deg(18.0 * h, 0.0, 0.0));
    body.limb(Side::Left, L_FOOT, deg(-10.0 * h, 0.0, 0.0));
    // Standing leg stays vertical under the back-leaning pelvis.
    // Standing leg: vertical under the back-leaning pelvis, knee soft, adducted under the
    // pelvis's shift over it.
    let shift = 0.05 * h;
    let (bend, _) = crouch_offset(10f64.to_radians() * h, 1.0);
    body.limb(
        Side::Right,
        L_HIP,
        DVec3::new(-pitch, 0.0, -(shift / (THIGH + SHANK)).asin()) + deg(-10.0 * h, 0.0, 0.0),
    );
    body.limb(Side::Right, L_KNEE, deg(20.0 * h, 0.0, 0.0));
    body.limb(Side::Right, L_ANKLE, deg(-8.0 * h, 0.0, 0.0));
    body.translate(DVec3::new(-shift, -bend, 0.0));

    let drop = p.arm_drop;
    body.limb(
        Side::Left,
        L_SHOULDER,
        hanging_arm(drop - (25.0 * h).to_radians(), (20.0 * h).to_radians()),
    );
    body.limb(
        Side::Right,
        L_SHOULDER,
        hanging_arm(drop - (30.0 * h).to_radians(), (-25.0 * h).to_radians()),
    );
    for side in [Side::Left, Side::Right] {
        body.limb(side, L_ELBOW, elbow_flex((15.0 + 25.0 * h).to_radians()));
    }
    Local::fixed(body, p.heading)
}

/// Timing (s) and heights (m) of one jump cycle, from the parameters.
struct JumpPlan {
    /// Crouch bottom, legs straight (heels start to rise), take-off, landing (toes touch), heels
    /// down, landing absorbed, standing again, cycle length.
    t_crouch: f64,
    t_extended: f64,
    t_off: f64,
    t_land: f64,
    t_touch: f64,
    t_absorb: f64,
    t_stand: f64,
    period: f64,
    /// Thigh angle at the crouch bottom and at the bottom of the landing absorption (rad).
    alpha_crouch: f64,
    alpha_absorb: f64,
    /// Root rise from standing onto the toes (m) and take-off speed (m/s).
    toe: f64,
    v0: f64,
}

/// Shank lean per unit of thigh lean in the jump's crouch.
const JUMP_BETA: f64 = 0.3;
/// Ankle plantar-flexion on the toes (rad, 30°): with the 0.14 m from ankle to the ball of the
/// foot it lifts the ankle by about [`JumpPlan::toe`].
const JUMP_PLANTAR: f64 = PI / 6.0;

impl JumpPlan {
    fn new(p: &MotionParams) -> Self {
        let s = p.speed;
        let toe = 0.06;
        // Apex of the root above standing: 0.21–0.30 m for amplitudes 0.6–1.2.
        let apex = 0.12 + 0.15 * p.amplitude.min(1.2);
        let v0 = (2.0 * GRAVITY * (apex - toe).max(0.01)).sqrt();
        let depth = 0.18 + 0.06 * p.style;
        // Rising onto the toes and coming down from them: a Hermite segment with end slope v0
        // neither dips nor overshoots when slope × length ≤ 3 × rise; keep it at 2.8.
        let on_toes = 2.8 * toe / v0;
        let t_crouch = 0.6 / s;
        let t_extended = t_crouch + 0.42;
        let t_off = t_extended + on_toes;
        let t_land = t_off + 2.0 * v0 / GRAVITY;
        let t_touch = t_land + on_toes;
        let t_absorb = t_touch + 0.3;
        let t_stand = t_absorb + 0.6 / s;
        Self {
            t_crouch,
            t_extended,
            t_off,
            t_land,
            t_touch,
            t_absorb,
            t_stand,
            period: t_stand + 0.8 / s,
            alpha_crouch: crouch_angle(depth, JUMP_BETA),
            alpha_absorb: crouch_angle(0.6 * depth, JUMP_BETA),
            toe,
            v0,
        }
    }
}

/// Jump: counter-movement jumps in place. The legs crouch (root 18–24 cm down) and extend with
/// the feet flat, the heels rise (root 6 cm up on the toes) while the root reaches 1.7–2.1 m/s,
/// the body flies ballistically (root apex 0.21–0.30 m above standing), lands on the toes, the
/// heels come down and the legs absorb, then it stands; the arms swing back in the crouch and
/// forward-up at take-off. On the floor the root height follows the legs' geometry
/// ([`crouch_offset`]) plus the toe rise, so the feet stay on the floor; it is C1 throughout.
fn jump(p: &MotionParams, t: f64) -> Local {
    let plan = JumpPlan::new(p);
    let tau = (t + p.phase / TAU * plan.period).rem_euclid(plan.period);
    let flight = plan.t_land - plan.t_off;

    // Thigh angle of the crouch and the landing; zero (straight legs) around the flight.
    let alpha = hermite(
        &[
            key(0.0, 0.0, 0.0),
            key(plan.t_crouch, plan.alpha_crouch, 0.0),
            key(plan.t_extended, 0.0, 0.0),
            key(plan.t_touch, 0.0, 0.0),
            key(plan.t_absorb, plan.alpha_absorb, 0.0),
            key(plan.t_stand, 0.0, 0.0),
        ],
        tau,
    );
    // Root height above the straight-legged stance: on the toes before take-off and after
    // landing, ballistic in between.
    let (lift, tuck) = if tau > plan.t_off && tau < plan.t_land {
        let f = tau - plan.t_off;
        let y = plan.toe + plan.v0 * f - 0.5 * GRAVITY * f * f;
        (y, (PI * f / flight).sin().powi(2))
    } else {
        let keys = [
            key(plan.t_extended, 0.0, 0.0),
            key(plan.t_off, plan.toe, plan.v0),
            key(plan.t_land, plan.toe, -plan.v0),
            key(plan.t_touch, 0.0, 0.0),
        ];
        (hermite(&keys, tau), 0.0)
    };
    // Heels rise with the toe lift (a little ahead of it: the ankle is the faster joint there).
    let on_toes = hermite(
        &[
            key(plan.t_extended - 0.1, 0.0, 0.0),
            key(plan.t_off, 1.0, 0.0),
            key(plan.t_land, 1.0, 0.0),
            key(plan.t_touch + 0.1, 0.0, 0.0),
        ],
        tau,
    );
    let swing = hermite(
        &[
            key(0.0, 0.0, 0.0),
            key(plan.t_crouch, 45f64.to_radians(), 0.0),
            key(plan.t_off + 0.05, -55f64.to_radians(), 0.0),
            key(plan.t_land, -35f64.to_radians(), 0.0),
            key(plan.t_absorb, -20f64.to_radians(), 0.0),
            key(plan.t_stand, 0.0, 0.0),
        ],
        tau,
    );

    let mut body = Body::new();
    let pitch = 0.35 * alpha;
    for side in [Side::Left, Side::Right] {
        body.limb(
            side,
            L_HIP,
            DVec3::new(-alpha - pitch, 0.0, 0.0) + deg(-15.0 * tuck, 0.0, 0.0),
        );
        body.limb(
            side,
            L_KNEE,
            DVec3::new((1.0 + JUMP_BETA) * alpha, 0.0, 0.0) + deg(20.0 * tuck, 0.0, 0.0),
        );
        body.limb(
            side,
            L_ANKLE,
            DVec3::new(
                -CROUCH_ANKLE * JUMP_BETA * alpha + JUMP_PLANTAR * on_toes,
                0.0,
                0.0,
            ),
        );
    }
    body.set(ROOT, DVec3::new(pitch, 0.0, 0.0));
    body.set(LOWER_TORSO, DVec3::new(0.15 * alpha, 0.0, 0.0));
    body.set(HEAD, DVec3::new(-0.4 * alpha, 0.0, 0.0));
    relaxed_arms(&mut body, p.arm_drop, [swing; 2], [20f64.to_radians(); 2]);
    let (drop, shift) = crouch_offset(alpha, JUMP_BETA);
    body.translate(DVec3::new(0.0, lift - drop, shift));
    Local::fixed(body, p.heading)
}

/// Half of the yaw sweep of a turn (rad): 0.6 × amplitude, at most 0.72 (41°).
fn turn_half_sweep(amplitude: f64) -> f64 {
    (0.6 * amplitude).min(0.72)
}

/// How a turn in place steps and leads: peak hip and knee flexion and ankle plantar flexion of
/// a stepping leg (degrees), the root's lateral sway and drop (m), the lower torso's, thorax's
/// and head's lead into the turn (degrees of yaw), the arms' swing and the elbows (degrees).
struct TurnSteps {
    hip: f64,
    knee: f64,
    ankle: f64,
    sway: f64,
    drop: f64,
    lead: [f64; 3],
    arm: f64,
    elbow: f64,
}

/// [`MotionKind::Turn`]'s steps.
const TURN_STEPS: TurnSteps = TurnSteps {
    hip: 25.0,
    knee: 45.0,
    ankle: 12.0,
    sway: 0.02,
    drop: 0.01,
    lead: [3.0, 6.0, 12.0],
    arm: 6.0,
    elbow: 15.0,
};

/// [`MotionKind::Spin`]'s steps: higher and livelier, for a faster turn.
const SPIN_STEPS: TurnSteps = TurnSteps {
    hip: 30.0,
    knee: 50.0,
    ankle: 15.0,
    sway: 0.025,
    drop: 0.015,
    lead: [4.0, 8.0, 18.0],
    arm: 8.0,
    elbow: 25.0,
};

/// A body stepping in place while it turns (heading frame): each leg lifts once per cycle of
/// `step_phase` (the legs half a cycle apart), scaled by `stepping` in [0, 1]; the trunk and head
/// lead by `lead` (signed: the turn's direction and strength).
fn stepping_round(
    p: &MotionParams,
    steps: &TurnSteps,
    step_phase: f64,
    stepping: f64,
    lead: f64,
) -> Body {
    let mut body = Body::new();
    for (side, offset) in [(Side::Left, 0.0), (Side::Right, 0.5)] {
        let lift = pulse(step_phase, offset, 2) * stepping;
        body.limb(side, L_HIP, deg(-2.0 - steps.hip * lift, 0.0, 0.0));
        body.limb(side, L_KNEE, deg(4.0 + steps.knee * lift, 0.0, 0.0));
        body.limb(side, L_ANKLE, deg(-2.0 + steps.ankle * lift, 0.0, 0.0));
    }
    let sway = (TAU * step_phase).cos();
    body.translate(DVec3::new(
        steps.sway * stepping * sway,
        -0.004 - steps.drop * stepping,
        0.0,
    ));
    body.set(ROOT, deg(0.0, 0.0, -2.0 * stepping * sway));
    body.set(LOWER_TORSO, deg(0.0, steps.lead[0] * lead, 0.0));
    body.set(MIDDLE_TORSO, deg(1.0, steps.lead[1] * lead, 0.0));
    body.set(HEAD, deg(0.0, steps.lead[2] * lead, 0.0));
    let arm = (steps.arm * stepping * sway).to_radians();
    relaxed_arms(
        &mut body,
        p.arm_drop,
        [arm, -arm],
        [steps.elbow.to_radians(); 2],
    );
    body
}

/// Turn: every 4 s the body turns towards `side` by up to 2 × 41°, holds, and turns back,
/// stepping in place (about 0.9 steps/s per leg) while the yaw changes; head and thorax lead the
/// turn. The root yaw limit (±50°) bounds the sweep.
fn turn(p: &MotionParams, t: f64) -> Local {
    const K: f64 = 1.8;
    let sweep = turn_half_sweep(p.amplitude);
    let centre = p.heading.clamp(-(YAW_LIMIT - sweep), YAW_LIMIT - sweep);
    let theta = TAU * (0.25 * p.speed * t + p.phase / TAU);
    let g = (K * theta.sin()).tanh() / K.tanh();
    // Turning rate relative to its peak (at theta = 0), in [−1, 1].
    let rate = theta.cos() / (K * theta.sin()).cosh().powi(2);
    let stepping = rate * rate;
    let yaw = centre + p.side.sign() * sweep * g;

    let step_phase = 0.9 * p.speed * t + p.phase / TAU;
    let lead = p.side.sign() * rate * p.amplitude;
    let body = stepping_round(p, &TURN_STEPS, step_phase, stepping, lead);
    Local {
        body,
        yaw,
        path: DVec3::ZERO,
    }
}

// ---------------------------------------------------------------------------------------------
// Extended kinds (issue 25, item 2): what people do that the papers' library lacks. Written
// inside [`clinical_limits_deg`]; left lead where one-sided (mirrored by the caller).

/// Left shoulder rotation that points the upper arm along `dir`, within the clinical limits.
fn arm_reaching(dir: DVec3) -> DVec3 {
    arm_towards_within(dir, clinical_limits_deg(L_SHOULDER))
}

/// Sets one leg (left convention): hip flexion, knee flexion and ankle dorsiflexion (rad; the
/// crate's signs are −x, +x and −x).
fn leg(body: &mut Body, side: Side, hip: f64, knee: f64, dorsi: f64) {
    body.limb(side, L_HIP, DVec3::new(-hip, 0.0, 0.0));
    body.limb(side, L_KNEE, DVec3::new(knee, 0.0, 0.0));
    body.limb(side, L_ANKLE, DVec3::new(-dorsi, 0.0, 0.0));
}

/// Sit: 6 s cycles that dwell standing and seated. The thighs go from vertical to 80–95° forward
/// (a higher seat, less; root 35–46 cm down, the hips 35 cm back over the planted feet), the
/// shanks lean forward through the transfer and stand nearly vertical on the seat, the trunk
/// leans 20–30° forward at the transfer's middle (sit-to-stand kinematics: hip flexion peaks near
/// seat-off, e.g. Schenkman et al., *Phys Ther* 70(10), 1990), the hands come to the thighs.
fn sit(p: &MotionParams, t: f64) -> Local {
    let q = dwell(p.speed * t / 6.0 + p.phase / TAU);
    let transfer = (PI * q).sin();
    let alpha = (80.0 + 15.0 * (1.0 - p.style)).to_radians() * q;
    let beta = 0.1 * q + 0.25 * transfer;
    let pitch = 0.1 * alpha + (0.3 + 0.15 * p.amplitude.min(1.2)) * transfer;
    let mut body = Body::new();
    crouch_legs(&mut body, alpha, beta, pitch, 1.0);
    for side in [Side::Left, Side::Right] {
        body.limb(
            side,
            L_HIP,
            DVec3::new(-alpha - pitch, 0.0, (5.0 * q).to_radians()),
        );
    }
    let (drop, shift) = crouch_offset(alpha, beta);
    // The feet 20 cm in front of the origin, so that the root stays near it.
    body.translate(DVec3::new(0.0, -drop, shift + 0.2));
    body.set(ROOT, DVec3::new(pitch, 0.0, 0.0));
    body.set(LOWER_TORSO, deg(6.0 * transfer + 4.0 * q, 0.0, 0.0));
    body.set(MIDDLE_TORSO, deg(4.0 * transfer + 4.0 * q, 0.0, 0.0));
    body.set(HEAD, DVec3::new(-0.4 * pitch, 0.0, 0.0));
    let swing = -(0.35 * q + 0.35 * transfer);
    let elbow = (12.0 + 45.0 * q).to_radians();
    relaxed_arms(&mut body, p.arm_drop, [swing; 2], [elbow; 2]);
    Local::fixed(body, p.heading)
}

/// Crouch: 5 s cycles down into a deep crouch and up: thighs to 70–95° forward, shanks leaning
/// 0.4 as far (knees to 98–133°), the heels rising (ankles dorsiflexed half the shank lean), the
/// trunk 12–24° forward, the arms forward or towards the floor.
fn deep_crouch(p: &MotionParams, t: f64) -> Local {
    let q = dwell(p.speed * t / 5.0 + p.phase / TAU);
    let beta = 0.4;
    let alpha = (70.0 + 25.0 * p.style).to_radians() * q;
    let pitch = (0.12 + 0.1 * p.amplitude.min(1.2)) * alpha;
    let mut body = Body::new();
    crouch_legs(&mut body, alpha, beta, pitch, 0.5);
    for side in [Side::Left, Side::Right] {
        body.limb(
            side,
            L_HIP,
            DVec3::new(-alpha - pitch, 0.0, (8.0 * q).to_radians()),
        );
    }
    let (drop, shift) = crouch_offset(alpha, beta);
    body.translate(DVec3::new(0.0, -drop, shift));
    body.set(ROOT, DVec3::new(pitch, 0.0, 0.0));
    body.set(LOWER_TORSO, DVec3::new(0.12 * alpha, 0.0, 0.0));
    body.set(MIDDLE_TORSO, DVec3::new(0.1 * alpha, 0.0, 0.0));
    body.set(HEAD, DVec3::new(-0.3 * (pitch + 0.22 * alpha), 0.0, 0.0));
    // arm_drop's range [0.35, 0.6) also picks where the hands go: forward or to the floor.
    let down = ((p.arm_drop - 0.35) / 0.25).clamp(0.0, 1.0);
    let forward = arm_reaching(direction(17f64.to_radians(), 0.0));
    let floor = arm_reaching(direction(10f64.to_radians(), -50f64.to_radians()));
    let target = lerp(forward, floor, down);
    for side in [Side::Left, Side::Right] {
        body.limb(
            side,
            L_SHOULDER,
            lerp(hanging_arm(p.arm_drop, 0.0), target, 0.9 * q),
        );
        body.limb(side, L_ELBOW, elbow_flex((12.0 + 20.0 * q).to_radians()));
    }
    Local::fixed(body, p.heading)
}

/// Kneel: 7 s cycles from standing down onto the right knee and up (left lead): the left foot
/// steps 18 cm forward and its thigh comes to horizontal or a little above over a shank leaning
/// 5–33° forward (the heel rising as it leans), the right shank swings back to the floor (toes
/// tucked) under a thigh that stays near vertical (an upright kneel, knee 95°) or, as the body
/// sinks back towards the heel, leans 40° forward (knee 125°, the trunk leaning over the front
/// thigh); the root drops 38–52 cm. The amplitude sets how far the body sinks, the style the
/// front shank's lean.
fn kneel(p: &MotionParams, t: f64) -> Local {
    let q = dwell(p.speed * t / 7.0 + p.phase / TAU);
    let transfer = (PI * q).sin();
    let sink = ((p.amplitude - 0.6) / 0.6).clamp(0.0, 1.0);
    let pitch = (0.1 + 0.12 * p.amplitude.min(1.2)) * transfer + (0.05 + 0.3 * sink) * q;
    let lean = (5.0 + 10.0 * p.style + 18.0 * sink).to_radians() * q;
    let lead = (85.0 + 10.0 * sink).to_radians() * q;
    let back = (10.0 + 30.0 * sink).to_radians() * q;
    let back_shank = 85f64.to_radians() * q;
    let mut body = Body::new();
    leg(&mut body, Side::Left, lead + pitch, lead + lean, 0.6 * lean);
    leg(&mut body, Side::Right, back + pitch, back + back_shank, 0.0);
    body.limb(Side::Right, L_ANKLE, deg(25.0 * q, 0.0, 0.0));
    let drop = THIGH * (1.0 - lead.cos()) + SHANK * (1.0 - lean.cos());
    let shift = SHANK * lean.sin() - THIGH * lead.sin();
    body.translate(DVec3::new(0.0, -drop, 0.18 * q + shift + 0.1));
    body.set(ROOT, DVec3::new(pitch, 0.0, 0.0));
    body.set(LOWER_TORSO, DVec3::new(0.2 * pitch, 0.0, 0.0));
    body.set(HEAD, DVec3::new(-0.5 * pitch, 0.0, 0.0));
    body.limb(Side::Left, L_SHOULDER, hanging_arm(p.arm_drop, -0.5 * q));
    body.limb(
        Side::Left,
        L_ELBOW,
        elbow_flex((12.0 + 30.0 * q).to_radians()),
    );
    body.limb(
        Side::Right,
        L_SHOULDER,
        hanging_arm(p.arm_drop, -0.1 * q - 0.2 * transfer),
    );
    body.limb(Side::Right, L_ELBOW, elbow_flex(15f64.to_radians()));
    Local::fixed(body, p.heading)
}

/// Pickup: 4.5 s cycles bending down to the floor and back: style 0 a stoop (pelvis ~80°
/// forward, knees ~18°), style 1 a squat lift (thighs 85° forward, knees 104°, pelvis ~30°); the
/// spine rounds, the left hand reaches to the floor, the right arm hangs.
fn pickup(p: &MotionParams, t: f64) -> Local {
    let q = dwell(p.speed * t / 4.5 + p.phase / TAU);
    let squat = p.style;
    let beta = 0.22;
    let alpha_max = (15.0 + 70.0 * squat).to_radians();
    let bend_max = ((80.0 - 50.0 * squat) * (0.8 + 0.2 * p.amplitude.min(1.2))).to_radians();
    let spine_max = (30.0 - 7.5 * squat).to_radians();
    let (alpha, bend) = (alpha_max * q, bend_max * q);
    let mut body = Body::new();
    crouch_legs(&mut body, alpha, beta, bend, 1.0);
    let (drop, shift) = crouch_offset(alpha, beta);
    // The hips go back over the planted feet, which stand 12 cm in front of the origin.
    body.translate(DVec3::new(
        0.0,
        -drop,
        shift - 0.1 * q * (1.0 - squat) + 0.12,
    ));
    body.set(ROOT, DVec3::new(bend, 0.0, 0.0));
    body.set(LOWER_TORSO, DVec3::new(0.5 * spine_max * q, 0.0, 0.0));
    body.set(MIDDLE_TORSO, DVec3::new(0.5 * spine_max * q, 0.0, 0.0));
    let total = bend_max + spine_max;
    body.set(HEAD, DVec3::new(-0.2 * total * q, 0.0, 0.0));
    // At the bottom the left arm points at the floor: world down in the thorax's frame.
    let reach = arm_reaching(direction(0.15, total - FRAC_PI_2));
    body.limb(
        Side::Left,
        L_SHOULDER,
        lerp(hanging_arm(p.arm_drop, 0.0), reach, q),
    );
    body.limb(
        Side::Left,
        L_ELBOW,
        elbow_flex((12.0 - 4.0 * q).to_radians()),
    );
    body.limb(
        Side::Right,
        L_SHOULDER,
        hanging_arm(p.arm_drop, -0.7 * total * q),
    );
    body.limb(
        Side::Right,
        L_ELBOW,
        elbow_flex((12.0 + 15.0 * q).to_radians()),
    );
    Local::fixed(body, p.heading)
}

/// Throw: an overarm throw with the left arm every 3 s. The body blends from a relaxed stance
/// into the cocked pose (throwing arm out to the side and back, elbow 90°, trunk turned 40° back,
/// the right foot stepping forward), then — a third of a second or more, the timing stretched to
/// keep joint speeds near 7 rad/s — into the follow-through (arm forward and down across the
/// body, trunk turned 40° the other way and bent forward, weight on the front leg), holds, and
/// returns.
fn throw(p: &MotionParams, t: f64) -> Local {
    let phi = (p.speed * t / 3.0 + p.phase / TAU).rem_euclid(1.0);
    let cock = hermite(
        &[key(0.1, 0.0, 0.0), key(0.42, 1.0, 0.0), key(0.68, 0.0, 0.0)],
        phi,
    );
    let follow = hermite(
        &[
            key(0.45, 0.0, 0.0),
            key(0.68, 1.0, 0.0),
            key(0.8, 1.0, 0.0),
            key(1.0, 0.0, 0.0),
        ],
        phi,
    );
    let turn = 0.7 + 0.3 * p.amplitude.min(1.2);

    let mut neutral = Body::new();
    for side in [Side::Left, Side::Right] {
        leg(
            &mut neutral,
            side,
            2f64.to_radians(),
            4f64.to_radians(),
            2f64.to_radians(),
        );
    }
    relaxed_arms(&mut neutral, p.arm_drop, [0.0; 2], [12f64.to_radians(); 2]);

    let mut cocked = neutral.clone();
    cocked.limb(
        Side::Left,
        L_SHOULDER,
        arm_reaching(direction(
            100f64.to_radians(),
            (5.0 + 10.0 * p.style).to_radians(),
        )),
    );
    cocked.limb(Side::Left, L_ELBOW, elbow_flex(FRAC_PI_2));
    cocked.limb(
        Side::Right,
        L_SHOULDER,
        arm_towards(direction(15f64.to_radians(), 15f64.to_radians())),
    );
    cocked.limb(Side::Right, L_ELBOW, elbow_flex(20f64.to_radians()));
    cocked.set(ROOT, deg(0.0, 10.0 * turn, 0.0));
    cocked.set(LOWER_TORSO, deg(0.0, 15.0 * turn, -4.0));
    cocked.set(MIDDLE_TORSO, deg(-5.0, 15.0 * turn, -4.0));
    cocked.set(HEAD, deg(0.0, -20.0 * turn, 0.0));
    leg(
        &mut cocked,
        Side::Right,
        25f64.to_radians(),
        20f64.to_radians(),
        5f64.to_radians(),
    );
    leg(
        &mut cocked,
        Side::Left,
        -8f64.to_radians(),
        15f64.to_radians(),
        -5f64.to_radians(),
    );
    cocked.translate(DVec3::new(0.0, -0.04, -0.05));

    let mut through = neutral.clone();
    through.limb(
        Side::Left,
        L_SHOULDER,
        arm_reaching(direction(-30f64.to_radians(), -45f64.to_radians())),
    );
    through.limb(Side::Left, L_ELBOW, elbow_flex(25f64.to_radians()));
    through.limb(Side::Right, L_SHOULDER, hanging_arm(p.arm_drop, 0.4));
    through.limb(Side::Right, L_ELBOW, elbow_flex(60f64.to_radians()));
    through.set(ROOT, deg(10.0, -10.0 * turn, 0.0));
    through.set(LOWER_TORSO, deg(10.0, -15.0 * turn, 0.0));
    through.set(MIDDLE_TORSO, deg(10.0, -15.0 * turn, 0.0));
    through.set(HEAD, deg(-10.0, 20.0 * turn, 0.0));
    leg(
        &mut through,
        Side::Right,
        50f64.to_radians(),
        35f64.to_radians(),
        12f64.to_radians(),
    );
    leg(
        &mut through,
        Side::Left,
        -5f64.to_radians(),
        40f64.to_radians(),
        -25f64.to_radians(),
    );
    through.translate(DVec3::new(0.0, -0.08, 0.15));

    let mut body = neutral.clone();
    for i in 0..POSE_DIM {
        body.pose[i] += cock * (cocked.pose[i] - neutral.pose[i])
            + follow * (through.pose[i] - neutral.pose[i]);
    }
    Local::fixed(body, p.heading)
}

/// Overhead: 4 s cycles reaching and back. Style below ½: both arms overhead (60–85° above
/// horizontal), the trunk extending and the head tilting back; from ½: the left arm reaches
/// behind the body (110–160° from the front, 15° below the shoulder), the trunk and head turning
/// towards it.
fn overhead(p: &MotionParams, t: f64) -> Local {
    let q = dwell(p.speed * t / 4.0 + p.phase / TAU);
    let a = p.amplitude.min(1.2);
    let mut body = Body::new();
    let root_shift = idle_legs(&mut body, t, p.phase);
    body.translate(root_shift);
    if p.style < 0.5 {
        let elevation = (60.0 + 50.0 * p.style).to_radians();
        let up = arm_reaching(direction(15f64.to_radians(), elevation));
        for side in [Side::Left, Side::Right] {
            body.limb(side, L_SHOULDER, lerp(hanging_arm(p.arm_drop, 0.0), up, q));
            body.limb(side, L_ELBOW, elbow_flex((12.0 - 4.0 * q).to_radians()));
        }
        body.set(LOWER_TORSO, deg(-6.0 * a * q, 0.0, 0.0));
        body.set(MIDDLE_TORSO, deg(-8.0 * a * q, 0.0, 0.0));
        body.set(HEAD, deg(-15.0 * q, 0.0, 0.0));
    } else {
        let azimuth = (110.0 + 100.0 * (p.style - 0.5)).to_radians();
        let behind = arm_reaching(direction(azimuth, -15f64.to_radians()));
        body.limb(
            Side::Left,
            L_SHOULDER,
            lerp(hanging_arm(p.arm_drop, 0.0), behind, q),
        );
        body.limb(
            Side::Left,
            L_ELBOW,
            elbow_flex((12.0 + 8.0 * q).to_radians()),
        );
        body.limb(Side::Right, L_SHOULDER, hanging_arm(p.arm_drop, -0.2 * q));
        body.limb(Side::Right, L_ELBOW, elbow_flex(20f64.to_radians()));
        body.set(ROOT, deg(0.0, 8.0 * a * q, 0.0));
        body.set(LOWER_TORSO, deg(0.0, 15.0 * a * q, 0.0));
        body.set(MIDDLE_TORSO, deg(0.0, 18.0 * a * q, 0.0));
        body.set(HEAD, deg(0.0, 20.0 * q, 0.0));
    }
    Local::fixed(body, p.heading)
}

// ---------------------------------------------------------------------------------------------
// Extended kinds down on the floor, on steps and turning full circles (issue 25, item 2). Lie,
// crawl, fall and spin leave papers/000's root box ([`MotionKind::has_free_root`]). Heights are
// those of the default template (hips 0.92 m, ankles 0.085 m above the floor).

/// Height (m) of the hip joints of the default template standing at rest.
const HIP_HEIGHT: f64 = 0.92;
/// Height (m) of the ankle joints above the floor, standing.
const ANKLE_HEIGHT: f64 = 0.085;
/// Height (m) of the hip joints above the floor when sitting or lying on it (half the pelvis'
/// depth, about).
const HIPS_ON_FLOOR: f64 = 0.11;
/// Height (m) of the knee joints above the floor when kneeling on them.
const KNEE_ON_FLOOR: f64 = 0.06;

/// The pose at `phase` (period 1) of a cycle through key poses: `keys` are (time, pose) with
/// times increasing from 0 within [0, 1); between consecutive keys (and from the last back to
/// the first at phase 1) every degree of freedom blends by a smoothstep, so the motion is C1 and
/// rests at every key. Rotation vectors blend linearly, which stays inside any box holding both.
fn key_poses(keys: &[(f64, Body)], phase: f64) -> Body {
    let f = phase.rem_euclid(1.0);
    let i = keys.iter().rposition(|(t, _)| *t <= f).unwrap_or(0);
    let (t0, a) = (keys[i].0, &keys[i].1);
    let (t1, b) = match keys.get(i + 1) {
        Some((t, b)) => (*t, b),
        None => (1.0 + keys[0].0, &keys[0].1),
    };
    let s = smoothstep(((f - t0) / (t1 - t0)).clamp(0.0, 1.0));
    let mut body = a.clone();
    for (v, w) in body.pose.iter_mut().zip(&b.pose) {
        *v += (w - *v) * s;
    }
    body
}

/// Sagittal two-link inverse kinematics of a leg (left convention): the hip flexion, knee
/// flexion and ankle dorsiflexion (rad) that put the ankle at `ankle` ((z, y) in the heading
/// frame, m) from hip joints at `hip`, under a root pitched forward by `pitch`, the foot flat
/// (dorsiflexion within 19°: beyond it the heel rises). An ankle out of reach gets the straight
/// leg pointing at it.
fn leg_to(hip: DVec2, ankle: DVec2, pitch: f64) -> (f64, f64, f64) {
    let d = ankle - hip;
    // Smooth saturations (a hard clamp would put a kink into the motion).
    let reach = soft_min(d.length(), 0.995 * (THIGH + SHANK), 0.004).max(0.3);
    let knee = PI
        - ((THIGH * THIGH + SHANK * SHANK - reach * reach) / (2.0 * THIGH * SHANK))
            .clamp(-1.0, 1.0)
            .acos();
    // The thigh's forward angle from straight down: the hip→ankle line's, plus the knee's offset.
    let line = d.x.atan2(-d.y);
    let thigh = line
        + ((THIGH * THIGH + reach * reach - SHANK * SHANK) / (2.0 * THIGH * reach))
            .clamp(-1.0, 1.0)
            .acos();
    let dorsi = -soft_min(
        -soft_min(knee - thigh, 19f64.to_radians(), 0.03),
        45f64.to_radians(),
        0.03,
    );
    (thigh + pitch, knee, dorsi)
}

/// A smooth minimum of `a` and `b` (log-sum-exp with width `k`): within `k·ln 2` of
/// `min(a, b)`, and as smooth as they are.
fn soft_min(a: f64, b: f64, k: f64) -> f64 {
    a.min(b) - k * (-(a - b).abs() / k).exp().ln_1p()
}

/// Standing at rest (knees 4°), relaxed arms.
fn standing(p: &MotionParams) -> Body {
    let mut body = Body::new();
    for side in [Side::Left, Side::Right] {
        leg(
            &mut body,
            side,
            2f64.to_radians(),
            4f64.to_radians(),
            2f64.to_radians(),
        );
    }
    relaxed_arms(&mut body, p.arm_drop, [0.0; 2], [12f64.to_radians(); 2]);
    body
}

/// A crouch on the way down to the floor or up from it (thighs `thigh_deg` forward: 85° a deep
/// crouch with the knees at 119° and the heels rising, 45° half-way), the hands reaching towards
/// the floor, the feet at the origin.
fn crouching(thigh_deg: f64) -> Body {
    let (alpha, beta) = (thigh_deg.to_radians(), 0.4);
    let pitch = 0.25 * alpha;
    let mut body = Body::new();
    crouch_legs(&mut body, alpha, beta, pitch, 0.5);
    let (drop, shift) = crouch_offset(alpha, beta);
    body.translate(DVec3::new(0.0, -drop, shift));
    body.set(ROOT, DVec3::new(pitch, 0.0, 0.0));
    body.set(LOWER_TORSO, DVec3::new(0.1 * alpha, 0.0, 0.0));
    body.set(HEAD, DVec3::new(-0.3 * pitch, 0.0, 0.0));
    let down = arm_reaching(direction(10f64.to_radians(), -40f64.to_radians()));
    for side in [Side::Left, Side::Right] {
        body.limb(
            side,
            L_SHOULDER,
            lerp(hanging_arm(0.5, 0.0), down, alpha / 1.5),
        );
        body.limb(side, L_ELBOW, elbow_flex(20f64.to_radians()));
    }
    body
}

/// Both legs of sitting or lying on the floor under a root pitched by `pitch` (rad), the knees
/// flexed by `knee` (rad): hips and ankles at about the same height, so thigh and shank make
/// equal angles with the floor (the thigh rising knee/2 above horizontal); the ankles plantar
/// flexed by `ankle + ankle_per_rad · knee` degrees.
fn legs_on_the_floor(body: &mut Body, pitch: f64, knee: f64, ankle: f64, ankle_per_rad: f64) {
    let thigh = FRAC_PI_2 + 0.5 * knee;
    for side in [Side::Left, Side::Right] {
        leg(
            body,
            side,
            thigh + pitch,
            knee,
            -(ankle + ankle_per_rad * knee).to_radians(),
        );
    }
}

/// Sitting on the floor, the hips `hips` m behind the origin, leaning back 15° on the hands
/// behind, the knees flexed by `knee` (rad: ~0.2 legs out straight, ~1.4 knees up, feet flat).
fn sitting_on_floor(p: &MotionParams, hips: f64, knee: f64) -> Body {
    let pitch = -15f64.to_radians();
    let mut body = Body::new();
    legs_on_the_floor(&mut body, pitch, knee, 20.0, 20.0);
    body.translate(DVec3::new(0.0, HIPS_ON_FLOOR + 0.01 - HIP_HEIGHT, -hips));
    seated_on_the_hands(&mut body, p, pitch, 6.0, -55.0);
    body
}

/// The trunk and arms of sitting on the floor: the root pitched by `pitch` (rad), the spine and
/// head flexed `flex` degrees each, the arms reaching back (150° from the front) and down
/// (`elevation` degrees) to the hands on the floor behind.
fn seated_on_the_hands(body: &mut Body, p: &MotionParams, pitch: f64, flex: f64, elevation: f64) {
    body.set(ROOT, DVec3::new(pitch, 0.0, 0.0));
    for j in [LOWER_TORSO, MIDDLE_TORSO, HEAD] {
        body.set(j, deg(flex, 0.0, 0.0));
    }
    let behind = arm_reaching(direction(150f64.to_radians(), elevation.to_radians()));
    for side in [Side::Left, Side::Right] {
        body.limb(
            side,
            L_SHOULDER,
            lerp(hanging_arm(p.arm_drop, 0.0), behind, 0.9),
        );
        body.limb(side, L_ELBOW, elbow_flex(10f64.to_radians()));
    }
}

/// Sitting on the floor just after sitting down from a crouch: the hips `hips` m behind the
/// feet (which stand at the origin), the knees up (about 123° for 0.4 m), the trunk 30° back on
/// the hands behind (the hip then flexes 117°, inside the clinical 120°).
fn sitting_tucked(p: &MotionParams, hips: f64) -> Body {
    let pitch = -30f64.to_radians();
    let (h, k, a) = leg_to(
        DVec2::new(-hips, HIPS_ON_FLOOR),
        DVec2::new(0.0, ANKLE_HEIGHT),
        pitch,
    );
    let mut body = Body::new();
    for side in [Side::Left, Side::Right] {
        leg(&mut body, side, h, k, a);
    }
    body.translate(DVec3::new(0.0, HIPS_ON_FLOOR - HIP_HEIGHT, -hips));
    seated_on_the_hands(&mut body, p, pitch, 10.0, -50.0);
    body
}

/// Lying on the back (supine), the hips `hips` m behind the origin, the head towards −z, the
/// knees flexed by `knee` (rad; with the feet flat: a hook-lying position), the arms by the sides
/// or (`arms_up`) beside the head.
fn lying(p: &MotionParams, hips: f64, knee: f64, arms_up: bool) -> Body {
    let pitch = -FRAC_PI_2;
    let mut body = Body::new();
    legs_on_the_floor(&mut body, pitch, knee, 25.0, 15.0);
    body.translate(DVec3::new(0.0, HIPS_ON_FLOOR - HIP_HEIGHT, -hips));
    body.set(ROOT, DVec3::new(pitch, 0.0, 0.0));
    body.set(HEAD, deg(8.0, 0.0, 0.0));
    for side in [Side::Left, Side::Right] {
        let arm = if arms_up {
            arm_reaching(direction(30f64.to_radians(), 80f64.to_radians()))
        } else {
            hanging_arm(p.arm_drop, 0.0)
        };
        body.limb(side, L_SHOULDER, arm);
        body.limb(side, L_ELBOW, elbow_flex(15f64.to_radians()));
    }
    body
}

/// Kneeling upright on both knees (thighs vertical, shanks on the floor, toes pointing back),
/// the knees `knees` m in front of the origin; the arms forward and down by `arms` (0 hanging,
/// 1 reaching for the floor).
fn kneeling_upright(p: &MotionParams, knees: f64, arms: f64) -> Body {
    let mut body = Body::new();
    for side in [Side::Left, Side::Right] {
        leg(
            &mut body,
            side,
            0.0,
            92f64.to_radians(),
            -40f64.to_radians(),
        );
    }
    body.translate(DVec3::new(0.0, KNEE_ON_FLOOR + THIGH - HIP_HEIGHT, knees));
    body.set(ROOT, deg(10.0 * arms, 0.0, 0.0));
    let forward = arm_reaching(direction(12f64.to_radians(), -20f64.to_radians()));
    for side in [Side::Left, Side::Right] {
        body.limb(
            side,
            L_SHOULDER,
            lerp(hanging_arm(p.arm_drop, 0.0), forward, arms),
        );
        body.limb(side, L_ELBOW, elbow_flex((12.0 + 8.0 * arms).to_radians()));
    }
    body
}

/// Root pitch (rad) of the hands-and-knees position: the trunk about 10° above horizontal, so
/// that straight arms reach the floor.
const ON_ALL_FOURS: f64 = 1.4;

/// On hands and knees, the knees `knees` m in front of the origin: thighs vertical under the
/// hips, shanks on the floor, the arms straight down under the shoulders, the head up. `legs` and
/// `arms` swing the left and right thighs and upper arms forward (rad, world sagittal angle);
/// `lift` bends the knees further while they swing (rad).
fn on_all_fours(knees: f64, legs: [f64; 2], arms: [f64; 2], lift: [f64; 2]) -> Body {
    let pitch = ON_ALL_FOURS;
    let mut body = Body::new();
    for (i, side) in [Side::Left, Side::Right].into_iter().enumerate() {
        leg(
            &mut body,
            side,
            pitch + legs[i],
            90f64.to_radians() + lift[i],
            -45f64.to_radians(),
        );
        // World down in the trunk's frame is `direction(·, pitch − 90°)`; forward swings raise it.
        let trunk = pitch + 10f64.to_radians();
        body.limb(
            side,
            L_SHOULDER,
            arm_reaching(direction(0.12, trunk - FRAC_PI_2 + arms[i])),
        );
        body.limb(side, L_ELBOW, elbow_flex(8f64.to_radians()));
    }
    body.translate(DVec3::new(0.0, KNEE_ON_FLOOR + THIGH - HIP_HEIGHT, knees));
    body.set(ROOT, DVec3::new(pitch, 0.0, 0.0));
    body.set(MIDDLE_TORSO, deg(10.0, 0.0, 0.0));
    body.set(HEAD, deg(-25.0, 0.0, 0.0));
    body
}

/// Lie: 14 s cycles: from standing down into a crouch, onto the seat (sitting on the floor,
/// first with the knees up, then the legs out, hands behind), back onto the floor (lying supine, legs out straight or knees up by the style,
/// arms by the sides or, with an amplitude above 0.9, beside the head), a rest, and up again the
/// same way (sit up, crouch, stand): one of the common adult ways of rising from the floor
/// (VanSant, *Phys Ther* 68(2), 1988, describes the components).
fn lie(p: &MotionParams, t: f64) -> Local {
    let knee = (10.0 + 70.0 * p.style).to_radians();
    let hips = 0.4;
    // Down and up the same way: each pose built once.
    let stand = standing(p);
    let (half, deep) = (crouching(45.0), crouching(85.0));
    let (tucked, sitting) = (sitting_tucked(p, hips), sitting_on_floor(p, hips, knee));
    let lying = lying(p, hips, knee, p.amplitude > 0.9);
    let keys = [
        (0.0, stand.clone()),
        (0.05, half.clone()),
        (0.09, deep.clone()),
        (0.17, tucked.clone()),
        (0.24, sitting.clone()),
        (0.33, lying.clone()),
        (0.55, lying),
        (0.64, sitting),
        (0.71, tucked),
        (0.8, deep),
        (0.85, half),
        (0.9, stand),
    ];
    Local::fixed(
        key_poses(&keys, p.speed * t / 14.0 + p.phase / TAU),
        p.heading,
    )
}

/// Crawl: on hands and knees along a gently curving path, the diagonal limbs moving together
/// (left hand with right knee; the crawling pattern of adults, Patrick et al., *J Neurophysiol*
/// 101, 2009): about 0.7 cycles/s × speed, thighs swinging ±(11–22)° by the amplitude, upper arms
/// ±12°, each knee lifting as it swings forward; speed = stride × cadence (0.1–0.25 m/s).
fn crawl(p: &MotionParams, t: f64) -> Local {
    let freq = 0.7 * p.speed;
    let phase = freq * t + p.phase / TAU;
    let swing = (18.0 * p.amplitude.min(1.2)).to_radians();
    let leg_of = |offset: f64| swing * (TAU * (phase + offset)).sin();
    // Forward motion of a limb: the derivative's sign; the knee lifts while it is positive.
    let lift_of = |offset: f64| 10f64.to_radians() * pulse(phase + offset, 0.0, 2);
    let legs = [leg_of(0.0), leg_of(0.5)];
    let arms = [0.7 * leg_of(0.5), 0.7 * leg_of(0.0)];
    let mut body = on_all_fours(0.0, legs, arms, [lift_of(0.0), lift_of(0.5)]);
    // The pelvis rolls and yaws a little with the stepping knee.
    let sway = (TAU * phase).sin();
    let root = joint(&body.pose, ROOT);
    body.set(ROOT, root + deg(0.0, 0.0, 3.0 * sway));
    body.set(LOWER_TORSO, deg(0.0, 0.0, -2.0 * sway));
    let v = 2.0 * THIGH * swing.sin() * freq;
    let path = path_integral(p.heading, p.curvature, t) * v;
    Local {
        body,
        yaw: path_yaw(p.heading, p.curvature, t),
        path: DVec3::new(path.x, 0.0, path.y),
    }
}

/// Fall: 9 s cycles. Style below ½: a fall forward (0.5 s onto both knees, 0.4 s more onto the
/// hands), a rest on hands and knees, and up through kneeling and a crouch. From ½: a fall
/// backward (0.6 s onto the seat, knees up, hands behind, then half-way onto the back), a rest,
/// and up through sitting and a crouch. The falls are the fastest motions of the library (joint speeds near
/// 6 rad/s, the root dropping at up to 1.5 m/s).
fn fall(p: &MotionParams, t: f64) -> Local {
    let phase = p.speed * t / 9.0 + p.phase / TAU;
    let body = if p.style < 0.5 {
        let fours = on_all_fours(0.2, [0.0; 2], [0.0; 2], [0.0; 2]);
        key_poses(
            &[
                (0.0, standing(p)),
                (0.06, kneeling_upright(p, 0.2, 0.6)),
                (0.11, fours.clone()),
                (0.3, fours),
                (0.42, kneeling_upright(p, 0.2, 0.0)),
                (0.58, crouching(85.0)),
                (0.65, crouching(45.0)),
                (0.72, standing(p)),
            ],
            phase,
        )
    } else {
        let knee = (40.0 + 40.0 * p.amplitude.min(1.2) - 24.0).to_radians();
        let mut back = lying(p, 0.4, knee, false);
        // Half-way onto the back: the trunk 55° behind the vertical, not flat.
        let pitch = -55f64.to_radians();
        back.set(ROOT, DVec3::new(pitch, 0.0, 0.0));
        legs_on_the_floor(&mut back, pitch, knee, 25.0, 15.0);
        let tucked = sitting_tucked(p, 0.4);
        key_poses(
            &[
                (0.0, standing(p)),
                (0.07, tucked.clone()),
                (0.13, back.clone()),
                (0.3, back),
                (0.42, tucked),
                (0.56, crouching(85.0)),
                (0.63, crouching(45.0)),
                (0.7, standing(p)),
            ],
            phase,
        )
    };
    Local::fixed(body, p.heading)
}

/// Stairs: 4.5 s step-up cycles onto a step 15–27 cm high (by the style) whose tread begins
/// 15 cm in front: the lead (left) foot steps up onto it (28 cm forward), the body rises over
/// it, the trailing foot follows, then the lead foot steps back down, the body lowers, and the
/// trailing foot follows (the step test's up-up-down-down). The legs follow the feet by
/// two-link inverse kinematics (feet flat; the trailing heel rises where the foot is out of
/// reach); the trunk leans 8–16° forward while rising.
fn stairs(p: &MotionParams, t: f64) -> Local {
    let f = (p.speed * t / 4.5 + p.phase / TAU).rem_euclid(1.0);
    let rise = 0.15 + 0.12 * p.style;
    let tread = 0.28;
    let floor = DVec2::new(0.0, ANKLE_HEIGHT);
    let step = DVec2::new(tread, ANKLE_HEIGHT + rise);
    // A foot's swing from `a` to `b` during [t0, t1], clearing the step edge.
    let swing = |a: DVec2, b: DVec2, t0: f64, t1: f64| {
        let s = ((f - t0) / (t1 - t0)).clamp(0.0, 1.0);
        let e = smoothstep(s);
        a + (b - a) * e + DVec2::new(0.0, 0.08 * (PI * s).sin().powi(2))
    };
    let lead = if f < 0.5 {
        swing(floor, step, 0.05, 0.25)
    } else {
        swing(step, floor, 0.62, 0.78)
    };
    let trail = if f < 0.6 {
        swing(floor, step, 0.34, 0.52)
    } else {
        swing(step, floor, 0.78, 0.94)
    };
    // The hips: up and forward over the lead foot during [0.2, 0.5], back down during [0.6, 0.8]
    // (ending 5 cm ahead), home by 0.94.
    let up = hermite(
        &[
            key(0.2, 0.0, 0.0),
            key(0.5, 1.0, 0.0),
            key(0.6, 1.0, 0.0),
            key(0.8, 0.0, 0.0),
        ],
        f,
    );
    let ahead = hermite(
        &[
            key(0.2, 0.0, 0.0),
            key(0.5, tread, 0.0),
            key(0.6, tread, 0.0),
            key(0.8, 0.05, 0.0),
            key(0.94, 0.0, 0.0),
        ],
        f,
    );
    let hip = DVec2::new(ahead, HIP_HEIGHT - 0.005 + rise * up);
    let lean =
        (8.0 + 8.0 * p.amplitude.min(1.2)) * (PI * ((f - 0.2) / 0.3).clamp(0.0, 1.0)).sin().powi(2);
    let pitch = (2.0 + lean).to_radians();
    let mut body = Body::new();
    for (side, foot) in [(Side::Left, lead), (Side::Right, trail)] {
        let (h, k, a) = leg_to(hip, foot, pitch);
        leg(&mut body, side, h, k, a);
    }
    body.translate(DVec3::new(0.0, hip.y - HIP_HEIGHT, hip.x));
    body.set(ROOT, DVec3::new(pitch, 0.0, 0.0));
    body.set(
        HEAD,
        DVec3::new(-0.5 * pitch + 10f64.to_radians() * up, 0.0, 0.0),
    );
    // The arms swing against the legs: the right forward while the left leg steps up.
    let arm = 0.25 * (PI * ((f - 0.05) / 0.45).clamp(0.0, 1.0)).sin().powi(2);
    relaxed_arms(
        &mut body,
        p.arm_drop,
        [arm, -arm],
        [(15f64).to_radians(); 2],
    );
    Local::fixed(body, p.heading)
}

/// Spin: turning in place through full circles towards `side`: each 4 s × speed⁻¹ the body
/// turns once round (360° in the first three quarters, easing in and out, up to about
/// 3.5 rad/s), stepping in place while it turns, head and thorax leading; then stands a moment.
fn spin(p: &MotionParams, t: f64) -> Local {
    let u = p.speed * t / 4.0 + p.phase / TAU;
    let (turns, f) = (u.floor(), u - u.floor());
    let s = (f / 0.75).clamp(0.0, 1.0);
    let yaw = p.heading + p.side.sign() * TAU * (turns + smoothstep(s));
    // How much the body steps and leads with the head: the turning rate relative to its peak,
    // squared (so that it starts and ends smoothly), in [0, 1].
    let rate = (4.0 * s * (1.0 - s)).powi(2);
    let step_phase = 1.1 * p.speed * t + p.phase / TAU;
    let lead = p.side.sign() * rate * p.amplitude.min(1.2);
    let body = stepping_round(p, &SPIN_STEPS, step_phase, rate, lead);
    Local {
        body,
        yaw,
        path: DVec3::ZERO,
    }
}

/// Circle: walking round a circle centred on the origin, towards `side` (its turning direction),
/// of radius 0.7–1.1 m by `style`, from the facing `heading`. The walk's gait at 0.7 of its
/// cadence (people slow down in a tight turn), the root path the circle (its tangent the facing),
/// the body leaning into the turn by `atan(v² / (r g))` (up to ~12°) — turning while walking,
/// a full circle every 3.5–12 s.
fn circle(p: &MotionParams, t: f64) -> Local {
    let slow = MotionParams {
        speed: 0.7 * p.speed,
        heading: 0.0,
        curvature: 0.0,
        ..*p
    };
    let Local { mut body, .. } = gait(&WALK, &slow, t);
    let v = WALK.speed * slow.speed * (0.55 + 0.45 * p.amplitude);
    let radius = 0.7 + 0.4 * p.style;
    let omega = p.side.sign() * v / radius;
    let yaw = p.heading + omega * t;
    // +z raises the left side: a turn to the left leans the body to its left, −z.
    let lean = (v * v / (radius * 9.81)).atan();
    let root = joint(&body.pose, ROOT);
    body.set(ROOT, root + DVec3::new(0.0, 0.0, -p.side.sign() * lean));
    // The circle's point whose tangent is the facing (sin ψ, cos ψ): r·(−cos ψ, sin ψ) turning
    // left, r·(cos ψ, −sin ψ) turning right.
    let path = DVec3::new(-yaw.cos(), 0.0, yaw.sin()) * (v / omega);
    Local { body, yaw, path }
}

/// Flight: climbing a flight of 3–5 stairs (by `style`; rise 15–18 cm, tread 28 cm) step over
/// step — the lead (left) foot onto the first stair, each foot then two stairs up, the trailing
/// foot closing beside the other on the landing — at 0.95 s per step × speed⁻¹ (55–70 steps/min:
/// a calm pace; stair cadences run ~70–100), turning round on the landing while stepping in place
/// (1.8 s × speed⁻¹), coming down step over step the same way, and turning round again at the
/// foot. The legs follow the feet by two-link inverse kinematics (feet flat; the trailing heel
/// rises where the foot is out of reach); the pelvis follows 0.7 of a step behind the feet, eight
/// centimetres low while stepping (the knees bent), and going down it leads by 0.9 of a stair
/// (the stance knee lowers the body before the swinging foot lands). The trunk leans 6–12°
/// forward going up; the head looks down going down.
fn flight(p: &MotionParams, t: f64) -> Local {
    let n = 3 + (3.0 * p.style).floor().min(2.0) as usize;
    let steps = n as f64;
    let rise = 0.15 + 0.03 * p.style;
    let tread = 0.28;
    let step_t = 0.95 / p.speed;
    let turn_t = 1.8 / p.speed;
    let climb_t = (steps + 1.2) * step_t;
    let cycle = 2.0 * (climb_t + turn_t);
    let tau = (t + p.phase / TAU * cycle).rem_euclid(cycle);
    let heading = DQuat::from_rotation_y(p.heading);
    // World (forward z, up y) of the stair levels' ankles and of the pelvis, in the heading frame.
    let level = |i: f64| DVec2::new(i * tread, ANKLE_HEIGHT + i * rise);
    let at_rest = |i: f64| DVec3::new(0.0, i * rise, i * tread);
    let (phase, local) = if tau < climb_t {
        (0, tau)
    } else if tau < climb_t + turn_t {
        (1, tau - climb_t)
    } else if tau < 2.0 * climb_t + turn_t {
        (2, tau - climb_t - turn_t)
    } else {
        (3, tau - 2.0 * climb_t - turn_t)
    };
    // Turning towards the lead side: left for a left lead (the caller mirrors a right lead,
    // whose yaw turns the other way here).
    let turn = p.side.sign() * PI;
    let pitch_at_rest = 2f64.to_radians();
    if phase == 1 || phase == 3 {
        // Turning round on the landing (1) or at the foot (3), stepping in place: the legs are
        // those of standing on the stair (as the climb ends and starts) with each foot lifted
        // in turn, so that the motion stays smooth across the phases.
        let s = local / turn_t;
        let rate = (4.0 * s * (1.0 - s)).powi(2);
        let step_phase = 0.8 * p.speed * local;
        let mut body = Body::new();
        for (side, offset) in [(Side::Left, 0.0), (Side::Right, 0.5)] {
            let lift = 0.04 * pulse(step_phase, offset, 2) * rate;
            let foot = DVec2::new(0.0, ANKLE_HEIGHT + lift - HIP_HEIGHT);
            let (h, k, a) = leg_to(DVec2::ZERO, foot, pitch_at_rest);
            leg(&mut body, side, h, k, a);
        }
        body.set(ROOT, DVec3::new(pitch_at_rest, 0.0, 0.0));
        body.set(MIDDLE_TORSO, deg(0.0, 8.0 * rate, 0.0));
        body.set(
            HEAD,
            DVec3::new(-0.5 * pitch_at_rest, 12f64.to_radians() * rate, 0.0),
        );
        relaxed_arms(&mut body, p.arm_drop, [0.0, 0.0], [(15f64).to_radians(); 2]);
        let (floor, from) = if phase == 1 {
            (steps, 0.0)
        } else {
            (0.0, turn)
        };
        return Local {
            body,
            yaw: p.heading + from + turn * smoothstep(s),
            path: heading * at_rest(floor),
        };
    }
    let up = phase == 0;
    // Progress in steps: swing k (1 ..= n + 1) of the foot of its parity (odd: the lead foot)
    // takes it from stair k − 2 to stair k (the last, n + 1, closes on stair n) during
    // [k − 1, k − 0.1] of `u`.
    let u = local / step_t;
    let stair = |k: f64| {
        if up {
            k.clamp(0.0, steps)
        } else {
            steps - k.clamp(0.0, steps)
        }
    };
    let foot = |parity: usize| -> DVec2 {
        let mut at = level(stair(0.0));
        for k in (1..=n + 1).filter(|k| k % 2 == parity) {
            let kf = k as f64;
            let s = ((u - (kf - 1.0)) / 0.9).clamp(0.0, 1.0);
            if s <= 0.0 {
                break;
            }
            let (a, b) = (level(stair(kf - 2.0)), level(stair(kf)));
            // Up: the foot rises before it moves forward (over the stair's nose); down: it moves
            // forward first, then down.
            let (sz, sy) = if up {
                (smoothstep(s), smoothstep((1.25 * s).min(1.0)))
            } else {
                (smoothstep((1.25 * s).min(1.0)), smoothstep(s))
            };
            at = DVec2::new(a.x + (b.x - a.x) * sz, a.y + (b.y - a.y) * sy)
                + DVec2::new(0.0, 0.03 * (PI * s).sin().powi(2));
        }
        at
    };
    // The body's progress in stairs: u − 0.7 (0.7 of a step behind the feet), clamped to
    // [0, n] with the corners rounded over half a step either side (velocity eased in and out).
    let x = u - 0.7;
    let progress = if x <= -0.5 {
        0.0
    } else if x < 0.5 {
        (x + 0.5).powi(2) / 2.0
    } else if x <= steps - 0.5 {
        x
    } else if x < steps + 0.5 {
        steps - (steps + 0.5 - x).powi(2) / 2.0
    } else {
        steps
    };
    // Eight centimetres low while stepping (the knees bent), eased in and out; down, the pelvis
    // leads by 0.9 of a stair (the stance knee lowers the body before the swinging foot lands).
    let busy =
        smoothstep(u.clamp(0.0, 1.0)) * (1.0 - smoothstep((u - steps - 0.2).clamp(0.0, 1.0)));
    let (z, y) = if up {
        (progress * tread, progress * rise - 0.08 * busy)
    } else {
        (
            (steps - progress) * tread,
            (steps - progress - 0.9 * busy) * rise - 0.08 * busy,
        )
    };
    let hip = DVec2::new(z, HIP_HEIGHT + y);
    let dir = if up { 1.0 } else { -1.0 };
    let lean = if up {
        (6.0 + 6.0 * p.amplitude.min(1.0)) * busy
    } else {
        2.0 * busy
    };
    let pitch = pitch_at_rest + lean.to_radians();
    let mut body = Body::new();
    for (side, parity) in [(Side::Left, 1), (Side::Right, 0)] {
        let f = foot(parity);
        // The legs' plane is the body's: forward is +z going up, −z coming down.
        let rel = DVec2::new(dir * (f.x - hip.x), f.y - hip.y);
        let (h, k, a) = leg_to(DVec2::ZERO, rel, pitch);
        leg(&mut body, side, h, k, a);
    }
    body.set(ROOT, DVec3::new(pitch, 0.0, 0.0));
    let look = if up { 0.0 } else { 15f64.to_radians() * busy };
    body.set(HEAD, DVec3::new(-0.5 * pitch + look, 0.0, 0.0));
    let arm = 0.2 * (PI * u).sin() * busy;
    relaxed_arms(
        &mut body,
        p.arm_drop,
        [arm, -arm],
        [(15f64).to_radians(); 2],
    );
    Local {
        body,
        yaw: p.heading + if up { 0.0 } else { turn },
        path: heading * DVec3::new(0.0, y, z),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use lfit_model::skeleton::{R_HIP, R_SHOULDER};
    use lfit_model::{Bounds, Template};
    use rand::SeedableRng;
    use rand_chacha::ChaCha8Rng;

    const FPS: f64 = 30.0;
    /// 10 s at 30 fps.
    const FRAMES: usize = 300;
    /// Largest per-frame change at 30 fps: 0.25 rad is 7.5 rad/s (≈ 430°/s, the order of peak
    /// knee speeds in brisk walking), 0.1 m is 3 m/s (a jog's forward speed).
    const MAX_ROT_STEP: f64 = 0.25;
    const MAX_TRANS_STEP: f64 = 0.1;

    fn params(kind: MotionKind, seed: u64) -> MotionParams {
        MotionParams::sample(kind, &mut ChaCha8Rng::seed_from_u64(seed))
    }

    fn rotations_inside(pose: &Pose, bounds: &Bounds) -> bool {
        (3..POSE_DIM).all(|i| pose[i] >= bounds.lower[i] && pose[i] <= bounds.upper[i])
    }

    fn root_rotation(pose: &Pose) -> DQuat {
        DQuat::from_scaled_axis(joint(pose, ROOT))
    }

    /// Whether every rotation of `pose` lies inside `kind`'s limits.
    fn inside_limits(pose: &Pose, kind: MotionKind) -> bool {
        (0..NUM_JOINTS).all(|j| {
            kind.limits_deg(j)
                .into_iter()
                .enumerate()
                .all(|(axis, (lo, hi))| {
                    let v = pose[rot_offset(j) + axis];
                    v >= lo.to_radians() && v <= hi.to_radians()
                })
        })
    }

    #[test]
    fn every_kind_is_finite_and_inside_the_rotation_bounds() {
        let bounds = Bounds::global();
        for kind in MotionKind::ALL {
            for seed in 0..20 {
                let p = params(kind, seed);
                for pose in sequence(kind, &p, FPS, FRAMES, 0.0) {
                    assert!(pose.iter().all(|v| v.is_finite()), "{kind} seed {seed}");
                    assert!(inside_limits(&pose, kind), "{kind} seed {seed}");
                    if !kind.is_extended() {
                        assert!(rotations_inside(&pose, &bounds), "{kind} seed {seed}");
                    }
                }
            }
        }
    }

    #[test]
    fn the_kind_lists_partition_every_kind_and_the_default_is_the_classic_library() {
        assert_eq!(
            MotionKind::CLASSIC.len() + MotionKind::EXTENDED.len(),
            MotionKind::ALL.len()
        );
        // In declaration order (`Ord` is derived from it), each kind once.
        assert!(MotionKind::ALL.windows(2).all(|w| w[0] < w[1]));
        for kind in MotionKind::ALL {
            assert_eq!(
                MotionKind::EXTENDED.contains(&kind),
                kind.is_extended(),
                "{kind}"
            );
            assert_ne!(
                MotionKind::CLASSIC.contains(&kind),
                MotionKind::EXTENDED.contains(&kind),
                "{kind}"
            );
        }
        // The clinical limits are papers/000's but for the legs' flexion axes and the arms,
        // where they allow more flexion (and less of the hip's and knee's other way).
        for j in 0..NUM_JOINTS {
            let (c, s) = (clinical_limits_deg(j), skeleton::rotation_limits_deg(j));
            let changed = [
                skeleton::R_HIP,
                L_HIP,
                skeleton::R_KNEE,
                L_KNEE,
                skeleton::R_ANKLE,
                L_ANKLE,
                skeleton::R_SHOULDER,
                L_SHOULDER,
                skeleton::R_ELBOW,
                L_ELBOW,
            ];
            assert_eq!(c != s, changed.contains(&j), "joint {j}");
        }
        assert!(clinical_limits_deg(L_HIP)[0].0 < skeleton::rotation_limits_deg(L_HIP)[0].0);
        assert!(clinical_limits_deg(L_KNEE)[0].1 > skeleton::rotation_limits_deg(L_KNEE)[0].1);
    }

    #[test]
    fn extended_kinds_reach_what_the_papers_limits_cut() {
        // Largest flexions over many draws: a deep crouch bends the knees past papers/000's 100°,
        // sitting and crouching flex the hips past 90°, overhead reaches raise the arm past the
        // 60° the papers' shoulder allows.
        let peak = |kind: MotionKind, dof: usize, sign: f64| {
            (0..20)
                .flat_map(|seed| sequence(kind, &params(kind, seed), FPS, FRAMES, 0.0))
                .map(|pose| sign * pose[dof])
                .fold(f64::MIN, f64::max)
                .to_degrees()
        };
        let knee = peak(MotionKind::Crouch, rot_offset(L_KNEE), 1.0);
        assert!(knee > 120.0 && knee <= 140.0, "crouch knee {knee}");
        let hip = peak(MotionKind::Sit, rot_offset(L_HIP), -1.0);
        assert!(hip > 95.0 && hip <= 120.0, "sit hip {hip}");
        let shoulder = peak(MotionKind::Overhead, rot_offset(L_SHOULDER) + 2, 1.0);
        assert!(
            shoulder > 100.0 && shoulder <= 150.0,
            "overhead shoulder {shoulder}"
        );
        // The classic kinds stay inside the papers' limits.
        let classic_knee = MotionKind::CLASSIC
            .into_iter()
            .map(|k| peak(k, rot_offset(L_KNEE), 1.0))
            .fold(f64::MIN, f64::max);
        assert!(classic_knee <= 100.0, "{classic_knee}");
    }

    #[test]
    fn the_clamp_rarely_acts() {
        // Amplitudes are designed inside the limits: the final clamp should be a safety net.
        for kind in MotionKind::ALL {
            let mut clamped = 0;
            for seed in 0..20 {
                let p = params(kind, seed);
                for i in 0..FRAMES {
                    let mut pose = motion_pose_unclamped(kind, &p, i as f64 / FPS);
                    clamped += usize::from(clamp_rotations(&mut pose, kind));
                }
            }
            let fraction = clamped as f64 / (20 * FRAMES) as f64;
            assert!(
                fraction < 0.01,
                "{kind}: {:.2}% of frames clamped",
                100.0 * fraction
            );
        }
    }

    #[test]
    fn consecutive_frames_are_close() {
        for kind in MotionKind::ALL {
            for seed in 0..20 {
                let p = params(kind, seed);
                let poses = sequence(kind, &p, FPS, FRAMES, 0.0);
                for (f, w) in poses.windows(2).enumerate() {
                    // A free root's rotation vector jumps where its angle passes π: its step is
                    // the angle between the two rotations.
                    let root_step = root_rotation(&w[0]).angle_between(root_rotation(&w[1]));
                    assert!(
                        root_step < MAX_ROT_STEP,
                        "{kind} seed {seed} frame {f}: root turns {root_step:.3}"
                    );
                    for (i, (a, b)) in w[0].iter().zip(&w[1]).enumerate() {
                        if kind.has_free_root() && (3..6).contains(&i) {
                            continue;
                        }
                        let step = (b - a).abs();
                        let bound = if i < 3 { MAX_TRANS_STEP } else { MAX_ROT_STEP };
                        assert!(
                            step < bound,
                            "{kind} seed {seed} frame {f} {}: step {step:.3}",
                            lfit_model::pose::dof_name(i)
                        );
                    }
                }
            }
        }
    }

    #[test]
    fn motions_are_continuous_with_continuous_velocity() {
        // Dense sampling: a jump in value (or in slope) shows up as a first (or second)
        // difference far above what a bounded velocity (or acceleration) allows.
        let dt = 1e-3;
        for kind in MotionKind::ALL {
            for seed in 0..4 {
                let p = params(kind, seed);
                let poses = sequence(kind, &p, 1.0 / dt, 8000, -1.0);
                for w in poses.windows(3) {
                    // The root's angular velocity (world frame) and its change.
                    let q: Vec<DQuat> = w.iter().map(root_rotation).collect();
                    let omega = |a: DQuat, b: DQuat| rotvec(b * a.inverse()) / dt;
                    let (w0, w1) = (omega(q[0], q[1]), omega(q[1], q[2]));
                    assert!(w0.length() < 12.0, "{kind} seed {seed}: root turns at {w0}");
                    let spin = (w1 - w0).length() / dt;
                    assert!(spin < 600.0, "{kind} seed {seed}: root acceleration {spin}");
                    for (i, ((a, b), c)) in w[0].iter().zip(&w[1]).zip(&w[2]).enumerate() {
                        if kind.has_free_root() && (3..6).contains(&i) {
                            continue;
                        }
                        let d1 = (b - a).abs() / dt;
                        let d2 = (c - 2.0 * b + a).abs() / (dt * dt);
                        assert!(d1 < 12.0, "{kind} seed {seed} dof {i}: speed {d1}");
                        // The motions stay below ~250 rad/s² (a clamp acting would add a kink).
                        assert!(d2 < 600.0, "{kind} seed {seed} dof {i}: acceleration {d2}");
                    }
                }
            }
        }
    }

    #[test]
    fn walking_moves_along_the_heading() {
        for seed in 0..20 {
            let p = MotionParams {
                speed: 1.0,
                ..params(MotionKind::Walk, seed)
            };
            let start = motion_pose(MotionKind::Walk, &p, 0.0);
            let end = motion_pose(MotionKind::Walk, &p, 3.0);
            let along = DVec2::new(p.heading.sin(), p.heading.cos());
            let moved = DVec2::new(end[0] - start[0], end[2] - start[2]);
            assert!(moved.dot(along) > 1.0, "seed {seed}: {moved}");
            // Curvature bends the path only a little in 3 s.
            assert!(moved.perp_dot(along).abs() < 0.5, "seed {seed}: {moved}");
        }
        // Jogging is faster than walking.
        let p = MotionParams::default();
        let walk = motion_pose(MotionKind::Walk, &p, 3.0);
        let jog = motion_pose(MotionKind::Jog, &p, 3.0);
        assert!(jog[2] > 1.5 * walk[2]);
        // A straight nominal walk goes 1.3 m/s along +z.
        assert!((walk[2] - 3.9).abs() < 0.05, "{}", walk[2]);
        assert!(walk[0].abs() < 0.05);
    }

    #[test]
    fn static_motions_stay_near_the_origin() {
        for kind in MotionKind::ALL.into_iter().filter(|k| !k.is_locomotion()) {
            // Sitting and lying on the floor put the hips 40 cm behind the feet.
            let limit = if kind.has_free_root() { 0.45 } else { 0.3 };
            for seed in 0..20 {
                let p = params(kind, seed);
                for pose in sequence(kind, &p, FPS, FRAMES, 0.0) {
                    let r = DVec2::new(pose[0], pose[2]).length();
                    assert!(
                        r < limit,
                        "{kind} seed {seed}: root {r:.3} m from the origin"
                    );
                }
            }
        }
    }

    fn correlation(a: &[f64], b: &[f64]) -> f64 {
        let n = a.len() as f64;
        let (ma, mb) = (a.iter().sum::<f64>() / n, b.iter().sum::<f64>() / n);
        let cov: f64 = a.iter().zip(b).map(|(x, y)| (x - ma) * (y - mb)).sum();
        let va: f64 = a.iter().map(|x| (x - ma).powi(2)).sum();
        let vb: f64 = b.iter().map(|y| (y - mb).powi(2)).sum();
        cov / (va * vb).sqrt()
    }

    #[test]
    fn gait_legs_are_in_anti_phase() {
        for kind in [MotionKind::Walk, MotionKind::Jog] {
            for seed in 0..20 {
                let poses = sequence(kind, &params(kind, seed), FPS, FRAMES, 0.0);
                let left: Vec<f64> = poses.iter().map(|p| p[rot_offset(L_HIP)]).collect();
                let right: Vec<f64> = poses.iter().map(|p| p[rot_offset(R_HIP)]).collect();
                let c = correlation(&left, &right);
                assert!(c < -0.5, "{kind} seed {seed}: hip correlation {c}");
                // Arms swing against the same-side leg.
                let arm: Vec<f64> = poses.iter().map(|p| p[rot_offset(L_SHOULDER)]).collect();
                assert!(correlation(&left, &arm) < -0.5, "{kind} seed {seed}");
            }
        }
    }

    #[test]
    fn jump_leaves_the_floor_and_squat_goes_down() {
        for seed in 0..20 {
            let p = params(MotionKind::Jump, seed);
            let poses = sequence(MotionKind::Jump, &p, FPS, FRAMES, 0.0);
            let top = poses.iter().map(|p| p[1]).fold(f64::MIN, f64::max);
            let bottom = poses.iter().map(|p| p[1]).fold(f64::MAX, f64::min);
            assert!(top > 0.1 && top < 0.32, "seed {seed}: apex {top}");
            assert!(bottom < -0.1, "seed {seed}: crouch {bottom}");

            let p = params(MotionKind::Squat, seed);
            let poses = sequence(MotionKind::Squat, &p, FPS, FRAMES, 0.0);
            let bottom = poses.iter().map(|p| p[1]).fold(f64::MAX, f64::min);
            assert!(bottom < -0.1, "seed {seed}: squat bottom {bottom}");
            assert!(poses.iter().all(|p| p[1] < 0.01));
        }
    }

    #[test]
    fn same_seed_same_motion_different_seed_different_motion() {
        for kind in MotionKind::ALL {
            let (a, b, c) = (params(kind, 7), params(kind, 7), params(kind, 8));
            assert_eq!(a, b);
            assert_ne!(a, c);
            let (sa, sb, sc) = (
                sequence(kind, &a, FPS, 60, 0.5),
                sequence(kind, &b, FPS, 60, 0.5),
                sequence(kind, &c, FPS, 60, 0.5),
            );
            assert_eq!(sa, sb);
            assert_ne!(sa, sc);
        }
    }

    #[test]
    fn sampled_params_are_in_their_ranges() {
        for kind in MotionKind::ALL {
            let (lo, hi) = kind.speed_range();
            for seed in 0..50 {
                let p = params(kind, seed);
                assert!(p.speed >= lo && p.speed <= hi);
                assert!((0.6..1.2).contains(&p.amplitude));
                assert!((0.0..TAU).contains(&p.phase));
                assert!(p.heading.abs() <= 0.6);
                assert_eq!(p.curvature != 0.0, kind.is_locomotion());
                assert_eq!(p.sanitized(), p, "sampled values are already sane");
            }
        }
    }

    #[test]
    fn names_parse_and_serialise() {
        for kind in MotionKind::ALL {
            assert_eq!(kind.name().parse::<MotionKind>(), Ok(kind));
            assert_eq!(
                kind.to_string().to_uppercase().parse::<MotionKind>(),
                Ok(kind)
            );
            let json = serde_json::to_string(&kind).expect("serialise");
            assert_eq!(json, format!("\"{}\"", kind.name()));
            assert_eq!(serde_json::from_str::<MotionKind>(&json).ok(), Some(kind));
        }
        let Err(err) = "moonwalk".parse::<MotionKind>() else {
            panic!("'moonwalk' parsed");
        };
        assert_eq!(err.name, "moonwalk");
        assert!(err.to_string().contains("walk, jog"));
        let p = MotionParams {
            side: Side::Right,
            ..MotionParams::default()
        };
        let json = serde_json::to_string(&p).expect("serialise");
        assert!(json.contains("\"side\":\"right\""), "{json}");
        assert_eq!(serde_json::from_str::<MotionParams>(&json).ok(), Some(p));
    }

    #[test]
    fn bad_params_and_times_still_give_valid_poses() {
        let bounds = Bounds::global();
        let bad = MotionParams {
            speed: f64::NAN,
            amplitude: f64::INFINITY,
            phase: -1e300,
            heading: 10.0,
            curvature: f64::NEG_INFINITY,
            side: Side::Right,
            style: -3.0,
            arm_drop: f64::NAN,
        };
        for kind in MotionKind::ALL {
            for t in [f64::NAN, -1e9, -3.3, 0.0, 1e-7, 12.5, 1e7, f64::INFINITY] {
                for p in [&bad, &MotionParams::default()] {
                    let pose = motion_pose(kind, p, t);
                    assert!(pose.iter().all(|v| v.is_finite()), "{kind} t={t}");
                    assert!(inside_limits(&pose, kind), "{kind} t={t}");
                    if !kind.is_extended() {
                        assert!(rotations_inside(&pose, &bounds), "{kind} t={t}");
                    }
                }
            }
        }
        assert!(
            sequence(MotionKind::Walk, &bad, 0.0, 3, 1.0)
                .windows(2)
                .all(|w| w[0] == w[1])
        );
        assert!(sequence(MotionKind::Walk, &bad, 30.0, 0, 1.0).is_empty());
    }

    #[test]
    fn right_lead_mirrors_left_lead() {
        for kind in MotionKind::ALL.into_iter().filter(|k| k.is_one_sided()) {
            let left = MotionParams {
                side: Side::Left,
                heading: 0.0,
                ..params(kind, 11)
            };
            let right = MotionParams {
                side: Side::Right,
                ..left
            };
            for i in 0..40 {
                let t = i as f64 * 0.1;
                let l = motion_pose(kind, &left, t);
                let r = motion_pose(kind, &right, t);
                let m = mirror_pose(&l);
                assert!(
                    r.iter().zip(&m).all(|(a, b)| (a - b).abs() < 1e-12),
                    "{kind}"
                );
            }
        }
        let p = MotionParams::default();
        let pose = motion_pose(MotionKind::Walk, &p, 0.7);
        assert_eq!(mirror_pose(&mirror_pose(&pose)), pose);
    }

    #[test]
    fn heading_path_is_exact_for_straight_and_bounded_for_curved_paths() {
        let straight = path_integral(0.3, 0.0, 2.0);
        assert!((straight - DVec2::new(0.3f64.sin(), 0.3f64.cos()) * 2.0).length() < 1e-12);
        // Against a fine trapezoid rule.
        let (h0, k, t) = (-0.4, 0.11, 9.0);
        let n = 200_000;
        let mut trap = DVec2::ZERO;
        for i in 0..=n {
            let s = t * i as f64 / n as f64;
            let psi = path_yaw(h0, k, s);
            let w = if i == 0 || i == n { 0.5 } else { 1.0 };
            trap += DVec2::new(psi.sin(), psi.cos()) * (w * t / n as f64);
        }
        assert!((path_integral(h0, k, t) - trap).length() < 1e-6);
        // Far in time the heading saturates, and the cost stays bounded.
        assert!(path_yaw(0.0, 0.5, 1e9) <= YAW_LIMIT);
        let far = path_integral(0.0, 0.5, 1e9);
        assert!(far.is_finite() && (far.length() - 1e9).abs() < 1e3);
    }

    #[test]
    fn recentre_zeroes_the_mean_and_clamps() {
        let p = MotionParams::default();
        let mut walk = sequence(MotionKind::Walk, &p, FPS, 90, 0.0);
        let y: Vec<f64> = walk.iter().map(|q| q[1]).collect();
        recentre(&mut walk);
        let mean_x = walk.iter().map(|q| q[0]).sum::<f64>() / 90.0;
        let mean_z = walk.iter().map(|q| q[2]).sum::<f64>() / 90.0;
        assert!(mean_x.abs() < 1e-12 && mean_z.abs() < 1e-12);
        assert!(walk.iter().zip(&y).all(|(q, y)| q[1] == *y));
        let mut long = sequence(MotionKind::Walk, &p, FPS, 300, 0.0);
        recentre(&mut long);
        assert!(
            long.iter()
                .all(|q| q[0].abs() <= RECENTRE_LIMIT && q[2].abs() <= RECENTRE_LIMIT)
        );
        assert!(long.iter().any(|q| q[2] == RECENTRE_LIMIT));
        recentre(&mut []);
    }

    // --- Kinematic plausibility through the model's forward kinematics (SPEC §3). ---

    fn joints(template: &Template, pose: &Pose) -> Vec<DVec3> {
        lfit_model::skinning::joint_transforms(template, pose).joints
    }

    /// The yaw (rad, about +y, 0 facing +z) of the hip line of forward-kinematics joints.
    fn hip_facing(joints: &[DVec3]) -> f64 {
        let across = joints[L_HIP] - joints[R_HIP];
        (-across.z).atan2(across.x)
    }

    /// The signed angle the hip line turns through over the frames (unwrapped frame to frame).
    fn hip_line_turn(frames: &[Vec<DVec3>]) -> f64 {
        frames
            .windows(2)
            .map(|w| (hip_facing(&w[1]) - hip_facing(&w[0]) + PI).rem_euclid(TAU) - PI)
            .sum()
    }

    /// Flight: the pelvis climbs the flight's height and comes back to the floor, the feet stand
    /// on every stair (each foot on its own stairs, step over step) and never sink under the
    /// floor, the body travels the flight's length and turns round at its top and foot, one way.
    #[test]
    fn a_flight_climbs_turns_round_and_comes_down() {
        use lfit_model::skeleton::R_ANKLE;
        let template = lfit_model::default_template();
        let rest = joints(&template, &[0.0; POSE_DIM]);
        let floor = rest[L_ANKLE].y - ANKLE_HEIGHT;
        for seed in 0..6 {
            let p = MotionParams {
                heading: 0.0,
                phase: 0.0,
                side: Side::Left,
                ..params(MotionKind::Flight, seed)
            };
            let n = 3 + (3.0 * p.style).floor().min(2.0) as usize;
            let rise = 0.15 + 0.03 * p.style;
            // One whole cycle: up, round, down, round.
            let climb = (n as f64 + 1.2) * 0.95 / p.speed;
            let cycle = 2.0 * (climb + 1.8 / p.speed);
            let count = (cycle * FPS).ceil() as usize;
            let frames: Vec<Vec<DVec3>> = sequence(MotionKind::Flight, &p, FPS, count, 0.0)
                .iter()
                .map(|q| joints(&template, q))
                .collect();
            let heights: Vec<f64> = frames.iter().map(|f| f[ROOT].y - rest[ROOT].y).collect();
            let top = heights.iter().copied().fold(f64::MIN, f64::max);
            let want = n as f64 * rise;
            assert!(
                (top - want).abs() < 0.03,
                "flight seed {seed}: pelvis up {top:.3} for {n} stairs of {rise:.3}"
            );
            assert!(heights[0].abs() < 0.03 && heights[count - 1].abs() < 0.03);
            // Each stair carries a foot for a while; going up, the lead foot the odd stairs below
            // the landing, the other the even ones.
            let on_in = |frames: &[Vec<DVec3>], a: usize, i: usize| {
                let h = ANKLE_HEIGHT + i as f64 * rise;
                frames
                    .iter()
                    .filter(|f| (f[a].y - floor - h).abs() < 0.02)
                    .count()
            };
            let climbing = &frames[..(climb * FPS) as usize];
            let frames_on = |a: usize, i: usize| on_in(climbing, a, i);
            for i in 1..n {
                let (on, off) = if i % 2 == 1 {
                    (L_ANKLE, R_ANKLE)
                } else {
                    (R_ANKLE, L_ANKLE)
                };
                assert!(
                    frames_on(on, i) >= 6,
                    "flight seed {seed}: stair {i} under the stepping foot {} frames",
                    frames_on(on, i)
                );
                assert!(
                    frames_on(off, i) < frames_on(on, i) / 2,
                    "flight seed {seed}: stair {i} under the other foot too"
                );
            }
            for a in [L_ANKLE, R_ANKLE] {
                assert!(on_in(&frames, a, n) >= 15, "flight seed {seed}: landing");
                let lowest = frames
                    .iter()
                    .map(|f| f[a].y - floor)
                    .fold(f64::MAX, f64::min);
                assert!(
                    lowest > ANKLE_HEIGHT - 0.02,
                    "flight seed {seed}: {lowest:.3}"
                );
            }
            let (zmin, zmax) = frames.iter().fold((f64::MAX, f64::MIN), |(lo, hi), f| {
                (lo.min(f[ROOT].z), hi.max(f[ROOT].z))
            });
            assert!(
                (zmax - zmin - n as f64 * 0.28).abs() < 0.1,
                "flight seed {seed}: travelled {:.2} m",
                zmax - zmin
            );
            let turned = hip_line_turn(&frames);
            assert!(
                (turned.abs() - TAU).abs() < 0.5,
                "flight seed {seed}: turned {:.0}°",
                turned.to_degrees()
            );
        }
    }

    /// Circle: the root goes round a circle of the drawn radius about the origin, more than one
    /// full turn in 15 s in the side's direction, the hips facing along the path, the pelvis
    /// leaning into the turn.
    #[test]
    fn circle_walks_round_its_circle_facing_along_it() {
        let template = lfit_model::default_template();
        for seed in 0..10 {
            let p = params(MotionKind::Circle, seed);
            let poses = sequence(MotionKind::Circle, &p, FPS, 450, 0.0);
            let radius = 0.7 + 0.4 * p.style;
            for pose in &poses {
                let r = DVec2::new(pose[0], pose[2]).length();
                assert!(
                    (r - radius).abs() < 0.06,
                    "seed {seed}: {r:.3} m from the centre of a {radius:.3} m circle"
                );
            }
            let frames: Vec<Vec<DVec3>> = poses.iter().map(|q| joints(&template, q)).collect();
            let turned = hip_line_turn(&frames);
            assert!(
                turned * p.side.sign() > TAU,
                "seed {seed}: {:.0}° in 15 s",
                turned.to_degrees()
            );
            // The direction of travel over a third of a second against the facing.
            for (i, w) in poses.windows(11).enumerate().step_by(15) {
                let step = DVec2::new(w[10][0] - w[0][0], w[10][2] - w[0][2]);
                let travel = step.x.atan2(step.y);
                let off = (travel - hip_facing(&frames[i + 5]) + PI).rem_euclid(TAU) - PI;
                assert!(
                    off.abs() < 25f64.to_radians(),
                    "seed {seed} frame {i}: travelling {:.0}° off the facing",
                    off.to_degrees()
                );
            }
            // Leaning in: the pelvis' up axis tilts towards the centre.
            let tilt: f64 = poses
                .iter()
                .map(|q| {
                    let up = root_rotation(q) * DVec3::Y;
                    DVec2::new(up.x, up.z).dot(-DVec2::new(q[0], q[2]).normalize())
                })
                .sum::<f64>()
                / poses.len() as f64;
            assert!(
                tilt > 0.02,
                "seed {seed}: mean tilt towards the centre {tilt:.3}"
            );
        }
    }

    #[test]
    fn forward_kinematics_look_like_the_motions() {
        use lfit_model::skeleton::{L_HAND, R_ANKLE, R_HAND};
        let template = lfit_model::default_template();
        let rest = joints(&template, &[0.0; POSE_DIM]);
        let p = MotionParams::default();
        let run = |kind: MotionKind, p: &MotionParams| -> Vec<Vec<DVec3>> {
            sequence(kind, p, FPS, 180, 0.0)
                .iter()
                .map(|q| joints(&template, q))
                .collect()
        };

        // Walk: the ankles stay near the floor level of the rest pose and swap front and back.
        let walk = run(MotionKind::Walk, &p);
        let low = walk
            .iter()
            .map(|j| j[L_ANKLE].y.min(j[R_ANKLE].y))
            .fold(f64::MAX, f64::min);
        let lift = walk.iter().map(|j| j[L_ANKLE].y).fold(f64::MIN, f64::max);
        assert!((low - rest[L_ANKLE].y).abs() < 0.06, "lowest ankle {low}");
        assert!(
            lift - rest[L_ANKLE].y > 0.05,
            "swing lifts the foot: {lift}"
        );
        let ahead: Vec<f64> = walk.iter().map(|j| j[L_ANKLE].z - j[R_ANKLE].z).collect();
        assert!(ahead.iter().fold(f64::MIN, |m, &v| m.max(v)) > 0.3);
        assert!(ahead.iter().fold(f64::MAX, |m, &v| m.min(v)) < -0.3);

        // Wave: the waving hand goes above the shoulder; mirrored with a right lead.
        for (side, hand, shoulder) in [
            (Side::Left, L_HAND, L_SHOULDER),
            (Side::Right, R_HAND, R_SHOULDER),
        ] {
            let wave = run(MotionKind::Wave, &MotionParams { side, ..p });
            let up = wave
                .iter()
                .map(|j| j[hand].y - j[shoulder].y)
                .fold(f64::MIN, f64::max);
            assert!(up > 0.2, "{side:?}: hand {up} above the shoulder");
        }

        // Squat: the feet stay planted while the hips go down.
        let squat = run(MotionKind::Squat, &p);
        for j in &squat {
            for a in [L_ANKLE, R_ANKLE] {
                assert!(
                    (j[a] - rest[a]).length() < 0.05,
                    "ankle moved {}",
                    (j[a] - rest[a]).length()
                );
            }
        }
        assert!(squat.iter().any(|j| j[ROOT].y < rest[ROOT].y - 0.15));

        // Reach and punch: the lead hand goes well in front of the chest.
        for kind in [MotionKind::Reach, MotionKind::Punch] {
            let frames = run(kind, &p);
            let front = frames
                .iter()
                .map(|j| j[L_HAND].z - j[MIDDLE_TORSO].z)
                .fold(f64::MIN, f64::max);
            assert!(front > 0.4, "{kind}: hand {front} in front");
        }

        // Kick: the lead foot rises in front of the body.
        let kick = run(MotionKind::Kick, &p);
        let foot = kick.iter().map(|j| j[L_ANKLE].y).fold(f64::MIN, f64::max);
        assert!(foot > 0.5, "kick height {foot}");
        assert!(kick.iter().any(|j| j[L_ANKLE].z > 0.4));

        // Jump: both feet leave the floor.
        let jump = run(MotionKind::Jump, &p);
        let air = jump
            .iter()
            .map(|j| j[L_ANKLE].y.min(j[R_ANKLE].y))
            .fold(f64::MIN, f64::max);
        assert!(air > rest[L_ANKLE].y + 0.1, "feet at {air}");

        // Turn: the facing (hip line) sweeps more than 60°.
        let turn = run(MotionKind::Turn, &p);
        let yaws: Vec<f64> = turn
            .iter()
            .map(|j| {
                let across = j[L_HIP] - j[R_HIP];
                (-across.z).atan2(across.x)
            })
            .collect();
        let span = yaws.iter().fold(f64::MIN, |m, &v| m.max(v))
            - yaws.iter().fold(f64::MAX, |m, &v| m.min(v));
        assert!(span > 60f64.to_radians(), "turn span {}", span.to_degrees());
    }

    #[test]
    fn forward_kinematics_look_like_the_extended_motions() {
        use lfit_model::skeleton::{L_HAND, R_ANKLE, R_HAND, R_KNEE};
        let template = lfit_model::default_template();
        let rest = joints(&template, &[0.0; POSE_DIM]);
        // The rest ankles are 8.5 cm above the floor.
        let floor = rest[L_ANKLE].y - 0.085;
        let run = |kind: MotionKind, p: &MotionParams| -> Vec<Vec<DVec3>> {
            sequence(kind, p, FPS, 600, 0.0)
                .iter()
                .map(|q| joints(&template, q))
                .collect()
        };
        let lowest = |frames: &[Vec<DVec3>], j: usize| {
            frames.iter().map(|f| f[j].y).fold(f64::MAX, f64::min)
        };
        for seed in 0..6 {
            let p = MotionParams {
                heading: 0.0,
                side: Side::Left,
                ..params(MotionKind::Sit, seed)
            };
            // Sit and crouch: the hips go down by 35 cm or more, the ankles stay on the floor.
            for kind in [MotionKind::Sit, MotionKind::Crouch] {
                let frames = run(kind, &MotionParams { ..p });
                assert!(
                    lowest(&frames, ROOT) < rest[ROOT].y - 0.33,
                    "{kind} seed {seed}: root {}",
                    lowest(&frames, ROOT)
                );
                for f in &frames {
                    for a in [L_ANKLE, R_ANKLE] {
                        assert!(
                            (f[a].y - rest[a].y).abs() < 0.08,
                            "{kind}: ankle at {}",
                            f[a].y
                        );
                    }
                }
            }
            // Kneel: the trailing (right) knee comes down to the floor, the lead knee does not.
            let frames = run(MotionKind::Kneel, &p);
            let (knee, lead) = (
                lowest(&frames, R_KNEE) - floor,
                lowest(&frames, lfit_model::skeleton::L_KNEE) - floor,
            );
            assert!(
                knee < 0.12 && lead > 0.3,
                "seed {seed}: knees {knee:.2}, {lead:.2}"
            );
            // Pickup: the left wrist comes within 45 cm of the floor (the fingertips ~20 cm
            // lower; standing it hangs ~80 cm up), the right stays higher.
            let frames = run(MotionKind::Pickup, &p);
            let hand = lowest(&frames, L_HAND);
            assert!(
                hand < floor + 0.45,
                "seed {seed}: hand {:.2} above the floor",
                hand - floor
            );
            assert!(lowest(&frames, R_HAND) > hand);
        }
        let p = MotionParams::default();
        // Throw: the throwing hand goes behind the shoulder line when cocked and well in front of
        // the chest after release.
        let frames = run(MotionKind::Throw, &p);
        let back = frames
            .iter()
            .map(|f| f[L_HAND].z - f[MIDDLE_TORSO].z)
            .fold(f64::MAX, f64::min);
        let front = frames
            .iter()
            .map(|f| f[L_HAND].z - f[MIDDLE_TORSO].z)
            .fold(f64::MIN, f64::max);
        assert!(
            back < -0.1 && front > 0.3,
            "throw hand {back:.2} .. {front:.2}"
        );
        // Overhead: both hands above the head (style < ½); one hand behind the back (style ≥ ½).
        let frames = run(MotionKind::Overhead, &MotionParams { style: 0.3, ..p });
        for hand in [L_HAND, R_HAND] {
            let top = frames
                .iter()
                .map(|f| f[hand].y - f[HEAD].y)
                .fold(f64::MIN, f64::max);
            assert!(top > 0.2, "hand {top:.2} above the head");
        }
        let frames = run(MotionKind::Overhead, &MotionParams { style: 0.8, ..p });
        let behind = frames
            .iter()
            .map(|f| f[L_HAND].z - f[ROOT].z)
            .fold(f64::MAX, f64::min);
        assert!(behind < -0.2, "hand {behind:.2} behind");
    }

    #[test]
    fn forward_kinematics_look_like_the_floor_stairs_and_spin_motions() {
        use lfit_model::skeleton::{L_HAND, R_ANKLE, R_HAND, R_KNEE};
        let template = lfit_model::default_template();
        let rest = joints(&template, &[0.0; POSE_DIM]);
        let floor = rest[L_ANKLE].y - ANKLE_HEIGHT;
        let run = |kind: MotionKind, p: &MotionParams| -> Vec<Vec<DVec3>> {
            sequence(kind, p, FPS, 450, 0.0)
                .iter()
                .map(|q| joints(&template, q))
                .collect()
        };
        let lowest = |frames: &[Vec<DVec3>], j: usize| {
            frames
                .iter()
                .map(|f| f[j].y - floor)
                .fold(f64::MAX, f64::min)
        };
        // The largest drop of the root within one second (30 frames).
        let fastest_drop = |frames: &[Vec<DVec3>]| {
            frames
                .windows(31)
                .map(|w| w[0][ROOT].y - w[30][ROOT].y)
                .fold(f64::MIN, f64::max)
        };
        for seed in 0..6 {
            let p = MotionParams {
                heading: 0.0,
                ..params(MotionKind::Lie, seed)
            };
            // Lie: down to the floor (pelvis and head within 20 cm of it, the trunk flat), up
            // again to standing, the ankles never more than 5 cm under the floor.
            let frames = run(MotionKind::Lie, &p);
            assert!(
                lowest(&frames, ROOT) < 0.2,
                "lie seed {seed}: pelvis {:.2}",
                lowest(&frames, ROOT)
            );
            assert!(
                lowest(&frames, HEAD) < 0.2,
                "lie seed {seed}: head {:.2}",
                lowest(&frames, HEAD)
            );
            assert!(
                frames
                    .iter()
                    .any(|f| (f[ROOT].y - rest[ROOT].y).abs() < 0.02)
            );
            for a in [L_ANKLE, R_ANKLE] {
                assert!(
                    lowest(&frames, a) > ANKLE_HEIGHT - 0.05,
                    "lie seed {seed}: ankle {:.2}",
                    lowest(&frames, a)
                );
            }
            // Crawl: knees and wrists on the floor in every frame, the pelvis half a metre up,
            // moving forward along the heading by half a metre or more in 15 s.
            let p = MotionParams {
                heading: 0.0,
                curvature: 0.0,
                ..params(MotionKind::Crawl, seed)
            };
            let frames = run(MotionKind::Crawl, &p);
            for f in &frames {
                for j in [L_KNEE, R_KNEE] {
                    assert!(
                        f[j].y - floor < 0.15,
                        "crawl seed {seed}: knee {:.2}",
                        f[j].y - floor
                    );
                }
                for j in [L_HAND, R_HAND] {
                    assert!(
                        f[j].y - floor < 0.12,
                        "crawl seed {seed}: wrist {:.2}",
                        f[j].y - floor
                    );
                }
                assert!((f[ROOT].y - floor - 0.5).abs() < 0.08);
            }
            let travelled = frames[449][ROOT].z - frames[0][ROOT].z;
            assert!(travelled > 0.5, "crawl seed {seed}: {travelled:.2} m");
            // Fall: the root drops 0.4 m or more within a second; forward onto the knees and
            // hands, backward onto the seat.
            for style in [0.2, 0.8] {
                let p = MotionParams {
                    style,
                    heading: 0.0,
                    ..params(MotionKind::Fall, seed)
                };
                let frames = run(MotionKind::Fall, &p);
                assert!(
                    fastest_drop(&frames) > 0.4,
                    "fall {style} seed {seed}: {:.2}",
                    fastest_drop(&frames)
                );
                if style < 0.5 {
                    assert!(lowest(&frames, L_KNEE) < 0.1 && lowest(&frames, L_HAND) < 0.1);
                } else {
                    assert!(lowest(&frames, ROOT) < 0.2 && lowest(&frames, HEAD) > 0.3);
                }
            }
            // Stairs: each foot comes up onto the step (its height by the style) and back, the
            // pelvis rises by the step's height.
            let p = MotionParams {
                heading: 0.0,
                ..params(MotionKind::Stairs, seed)
            };
            let rise = 0.15 + 0.12 * p.style;
            let frames = run(MotionKind::Stairs, &p);
            for a in [L_ANKLE, R_ANKLE] {
                let on_step = frames
                    .iter()
                    .filter(|f| (f[a].y - floor - ANKLE_HEIGHT - rise).abs() < 0.03)
                    .count();
                assert!(
                    on_step > 30,
                    "stairs seed {seed}: ankle {a} on the step in {on_step} frames"
                );
                assert!(lowest(&frames, a) > ANKLE_HEIGHT - 0.02);
            }
            let top = frames.iter().map(|f| f[ROOT].y).fold(f64::MIN, f64::max) - rest[ROOT].y;
            assert!(
                (top - rise).abs() < 0.03,
                "stairs seed {seed}: pelvis up {top:.3} for a {rise:.3} step"
            );
            // Spin: the hip line turns through more than two full circles in 15 s, one way.
            let p = params(MotionKind::Spin, seed);
            let frames = run(MotionKind::Spin, &p);
            let turned = hip_line_turn(&frames);
            assert!(
                turned * p.side.sign() > 2.0 * TAU,
                "spin seed {seed}: {:.0}°",
                turned.to_degrees()
            );
        }
    }
}
