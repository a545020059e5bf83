//! 2D keypoint files and camera files for `lfit data import`.
//!
//! Three documented keypoint formats are read, told apart by their content:
//! - **OpenPose** (`--write_json`): one file per frame, `{"people": [{"pose_keypoints_2d": [x0,
//!   y0, c0, x1, y1, c1, ...], ...}, ...]}` with `3K` numbers per person (K = 25 for BODY_25,
//!   17 for a COCO-17 model). A frame with nobody has no visible keypoint.
//! - **COCO keypoints** (the `person_keypoints_*.json` layout): `{"images": [{"id", "width",
//!   "height", ...}], "annotations": [{"image_id", "keypoints": [x, y, v, ...], "score"?}]}`, one
//!   frame per entry of `images`, in their listed order; an image without annotations has no
//!   visible keypoint. COCO's visibility flag v (0 unlabelled, 1 occluded, 2 visible) stands for
//!   the confidence.
//! - **COCO results** (a detector's output, mmpose's and Detectron2's): `[{"image_id",
//!   "keypoints", "score"?}, ...]`; the image ids are frame numbers, every id from the lowest to
//!   the highest one frame.
//!
//! Layouts: COCO-17, OpenPose's BODY_25 and COCO model (18), AlphaPose's Halpe-26,
//! COCO-WholeBody's 133 (its body part mapped as COCO-17's), MediaPipe's BlazePose 33 (its limb
//! landmarks mapped as COCO-17's; MediaPipe's own output is normalised to [0, 1], which the
//! import refuses: keypoints must be in pixels, as Pose2Sim writes them).
//!
//! Where a frame holds several people, the first such frame keeps the best-ranked (a COCO
//! `score`, else the summed confidence) and every later frame the person nearest the one kept
//! before (the median distance over keypoints both saw): a sequence follows one subject.
//!
//! A keypoint counts as seen when its confidence exceeds the chosen threshold. Pixel coordinates
//! are taken as they are, in the camera file's image frame (x right, y down).
//!
//! The camera file is JSON, `{"cameras": [{"fx", "fy", "cx", "cy", "width", "height",
//! "rotation": [[3], [3], [3]], "translation": [3]}, ...]}`: pinhole intrinsics in pixels and
//! the camera-from-world rotation (row-major) and translation in metres, OpenCV axes (+z into the
//! scene, +y down) — exactly the cameras a `keypoints2d` dataset stores. Each camera may instead
//! use OpenCV's calibration keys (`K`, `R` or `rvec`, `t` or `tvec`, `resolution`; a `name` is
//! allowed) and give its lens distortion, `dist`: OpenCV's `k1 k2 p1 p2 [k3 [k4 k5 k6]]`
//! ([`Distortion`]; its keypoints are undistorted at import, [`undistort_track`]). One key per
//! quantity; unknown keys are refused. A CMU Panoptic calibration file
//! (`calibration_<sequence>.json`: `calibDataSource`, and per camera `name`, `type`, `panel`,
//! `node`, `K`, `distCoef`, `R`, `t`) reads as it is, its translations in centimetres; a
//! top-level `"units": "m" | "cm" | "mm"` gives the translations' unit of any camera file
//! (default metres, Panoptic's centimetres). [`CameraFileRig::select`] chooses cameras by name
//! (a Panoptic file lists its 31 HD, 480 VGA and 10 Kinect cameras; keypoints come from a few).
//! A `.toml` file is an anipose / Pose2Sim calibration; a folder (or its `intri.yml` /
//! `extri.yml`) EasyMocap's cameras ([`super::opencv_yaml`]).

use std::path::{Path, PathBuf};

use lfit_model::camera::Camera;
use lfit_model::skeleton;
use serde::Deserialize;
use serde_json::Value;

use crate::capture::{ImportError, opencv_yaml};

fn fail<T>(msg: impl Into<String>) -> Result<T, ImportError> {
    Err(ImportError::Invalid(msg.into()))
}

/// A keypoint layout of a 2D pose detector.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum KeypointLayout {
    /// COCO's 17 person keypoints.
    Coco17,
    /// OpenPose's BODY_25.
    Body25,
    /// OpenPose's COCO model (18 keypoints: COCO's 17 with a neck, in OpenPose's order).
    Coco18,
    /// AlphaPose's Halpe-26 (COCO's 17, then head, neck, hip and six foot keypoints).
    Halpe26,
    /// COCO-WholeBody's 133 (COCO's 17 first, then feet, face and hands).
    CocoWholeBody,
    /// MediaPipe Pose's 33 landmarks (BlazePose; Bazarevsky et al. 2020), as Pose2Sim writes
    /// them in OpenPose's format.
    BlazePose33,
    /// CMU Panoptic's 19 ("coco19": its 3D skeletons, `hdPose3d_stage1_coco19`; Joo et al.
    /// 2017), in the order and under the names of the Panoptic toolbox's README.
    Panoptic19,
}

/// COCO-17 keypoint names, in order.
pub const COCO17: [&str; 17] = [
    "nose",
    "left_eye",
    "right_eye",
    "left_ear",
    "right_ear",
    "left_shoulder",
    "right_shoulder",
    "left_elbow",
    "right_elbow",
    "left_wrist",
    "right_wrist",
    "left_hip",
    "right_hip",
    "left_knee",
    "right_knee",
    "left_ankle",
    "right_ankle",
];

/// OpenPose BODY_25 keypoint names, in order.
pub const BODY25: [&str; 25] = [
    "Nose",
    "Neck",
    "RShoulder",
    "RElbow",
    "RWrist",
    "LShoulder",
    "LElbow",
    "LWrist",
    "MidHip",
    "RHip",
    "RKnee",
    "RAnkle",
    "LHip",
    "LKnee",
    "LAnkle",
    "REye",
    "LEye",
    "REar",
    "LEar",
    "LBigToe",
    "LSmallToe",
    "LHeel",
    "RBigToe",
    "RSmallToe",
    "RHeel",
];

/// OpenPose COCO-model keypoint names, in order (`--model_pose COCO`).
pub const COCO18: [&str; 18] = [
    "Nose",
    "Neck",
    "RShoulder",
    "RElbow",
    "RWrist",
    "LShoulder",
    "LElbow",
    "LWrist",
    "RHip",
    "RKnee",
    "RAnkle",
    "LHip",
    "LKnee",
    "LAnkle",
    "REye",
    "LEye",
    "REar",
    "LEar",
];

/// Halpe-26 keypoint names, in order (AlphaPose's full-body model; Fang et al., Halpe-FullBody).
pub const HALPE26: [&str; 26] = [
    "Nose",
    "LEye",
    "REye",
    "LEar",
    "REar",
    "LShoulder",
    "RShoulder",
    "LElbow",
    "RElbow",
    "LWrist",
    "RWrist",
    "LHip",
    "RHip",
    "LKnee",
    "RKnee",
    "LAnkle",
    "RAnkle",
    "Head",
    "Neck",
    "Hip",
    "LBigToe",
    "RBigToe",
    "LSmallToe",
    "RSmallToe",
    "LHeel",
    "RHeel",
];

/// COCO-WholeBody keypoint names, in order (133: COCO's 17, six foot, 68 face and 2 × 21 hand
/// keypoints; Jin et al. 2020 — DWPose's and RTMPose's whole-body output).
pub const COCO_WHOLEBODY: [&str; 133] = whole_body(&COCO17, &WHOLEBODY_EXTRA);

/// COCO-WholeBody's keypoints after COCO's 17.
const WHOLEBODY_EXTRA: [&str; 116] = [
    "left_big_toe",
    "left_small_toe",
    "left_heel",
    "right_big_toe",
    "right_small_toe",
    "right_heel",
    "face_0",
    "face_1",
    "face_2",
    "face_3",
    "face_4",
    "face_5",
    "face_6",
    "face_7",
    "face_8",
    "face_9",
    "face_10",
    "face_11",
    "face_12",
    "face_13",
    "face_14",
    "face_15",
    "face_16",
    "face_17",
    "face_18",
    "face_19",
    "face_20",
    "face_21",
    "face_22",
    "face_23",
    "face_24",
    "face_25",
    "face_26",
    "face_27",
    "face_28",
    "face_29",
    "face_30",
    "face_31",
    "face_32",
    "face_33",
    "face_34",
    "face_35",
    "face_36",
    "face_37",
    "face_38",
    "face_39",
    "face_40",
    "face_41",
    "face_42",
    "face_43",
    "face_44",
    "face_45",
    "face_46",
    "face_47",
    "face_48",
    "face_49",
    "face_50",
    "face_51",
    "face_52",
    "face_53",
    "face_54",
    "face_55",
    "face_56",
    "face_57",
    "face_58",
    "face_59",
    "face_60",
    "face_61",
    "face_62",
    "face_63",
    "face_64",
    "face_65",
    "face_66",
    "face_67",
    "left_hand_0",
    "left_hand_1",
    "left_hand_2",
    "left_hand_3",
    "left_hand_4",
    "left_hand_5",
    "left_hand_6",
    "left_hand_7",
    "left_hand_8",
    "left_hand_9",
    "left_hand_10",
    "left_hand_11",
    "left_hand_12",
    "left_hand_13",
    "left_hand_14",
    "left_hand_15",
    "left_hand_16",
    "left_hand_17",
    "left_hand_18",
    "left_hand_19",
    "left_hand_20",
    "right_hand_0",
    "right_hand_1",
    "right_hand_2",
    "right_hand_3",
    "right_hand_4",
    "right_hand_5",
    "right_hand_6",
    "right_hand_7",
    "right_hand_8",
    "right_hand_9",
    "right_hand_10",
    "right_hand_11",
    "right_hand_12",
    "right_hand_13",
    "right_hand_14",
    "right_hand_15",
    "right_hand_16",
    "right_hand_17",
    "right_hand_18",
    "right_hand_19",
    "right_hand_20",
];

/// MediaPipe Pose (BlazePose) landmark names, in order (its 33 landmarks: face, arms with three
/// finger landmarks per hand, legs with heel and foot index). Limb names as COCO-17's.
pub const BLAZEPOSE33: [&str; 33] = [
    "nose",
    "left_eye_inner",
    "left_eye",
    "left_eye_outer",
    "right_eye_inner",
    "right_eye",
    "right_eye_outer",
    "left_ear",
    "right_ear",
    "mouth_left",
    "mouth_right",
    "left_shoulder",
    "right_shoulder",
    "left_elbow",
    "right_elbow",
    "left_wrist",
    "right_wrist",
    "left_pinky",
    "right_pinky",
    "left_index",
    "right_index",
    "left_thumb",
    "right_thumb",
    "left_hip",
    "right_hip",
    "left_knee",
    "right_knee",
    "left_ankle",
    "right_ankle",
    "left_heel",
    "right_heel",
    "left_foot_index",
    "right_foot_index",
];

/// CMU Panoptic's coco19 keypoint names, in order (the panoptic-toolbox README's list; not
/// OpenPose's order, though its method builds on OpenPose). BodyCenter is the centre of the hips.
pub const PANOPTIC19: [&str; 19] = [
    "Neck",
    "Nose",
    "BodyCenter",
    "lShoulder",
    "lElbow",
    "lWrist",
    "lHip",
    "lKnee",
    "lAnkle",
    "rShoulder",
    "rElbow",
    "rWrist",
    "rHip",
    "rKnee",
    "rAnkle",
    "lEye",
    "lEar",
    "rEye",
    "rEar",
];

/// `body` then `extra`, as one array (a const concatenation).
const fn whole_body(body: &[&'static str; 17], extra: &[&'static str; 116]) -> [&'static str; 133] {
    let mut all = [""; 133];
    let mut i = 0;
    while i < 17 {
        all[i] = body[i];
        i += 1;
    }
    while i < 133 {
        all[i] = extra[i - 17];
        i += 1;
    }
    all
}

impl std::str::FromStr for KeypointLayout {
    type Err = ImportError;
    fn from_str(s: &str) -> Result<Self, ImportError> {
        match s {
            "coco17" => Ok(Self::Coco17),
            "body25" => Ok(Self::Body25),
            "coco18" => Ok(Self::Coco18),
            "halpe26" => Ok(Self::Halpe26),
            "wholebody133" => Ok(Self::CocoWholeBody),
            "blazepose33" => Ok(Self::BlazePose33),
            "panoptic19" => Ok(Self::Panoptic19),
            other => fail(format!(
                "unknown keypoint layout '{other}' (expected coco17, body25, coco18, halpe26, wholebody133, blazepose33 or panoptic19)"
            )),
        }
    }
}

impl KeypointLayout {
    pub fn name(self) -> &'static str {
        match self {
            Self::Coco17 => "coco17",
            Self::Body25 => "body25",
            Self::Coco18 => "coco18",
            Self::Halpe26 => "halpe26",
            Self::CocoWholeBody => "wholebody133",
            Self::BlazePose33 => "blazepose33",
            Self::Panoptic19 => "panoptic19",
        }
    }

    /// Keypoint names, in the detector's order.
    pub fn names(self) -> &'static [&'static str] {
        match self {
            Self::Coco17 => &COCO17,
            Self::Body25 => &BODY25,
            Self::Coco18 => &COCO18,
            Self::Halpe26 => &HALPE26,
            Self::CocoWholeBody => &COCO_WHOLEBODY,
            Self::BlazePose33 => &BLAZEPOSE33,
            Self::Panoptic19 => &PANOPTIC19,
        }
    }

    pub fn count(self) -> usize {
        self.names().len()
    }

    pub fn index(self, name: &str) -> Option<usize> {
        self.names().iter().position(|n| *n == name)
    }

    /// The default correspondence: papers/000 joint → keypoint name. Only keypoints that lie
    /// close to a joint centre of lfit's skeleton: hips, knees, ankles, shoulders, elbows,
    /// wrists (the papers/000 hands); BODY_25, Halpe-26 and Panoptic's coco19 also give the root
    /// (MidHip, Hip, BodyCenter) and the head joint (Neck: papers/000's head joint sits at the
    /// base of the neck), OpenPose's COCO model the head joint. Face and foot keypoints are left out (no joint centre there);
    /// `--keypoint-map` chooses others.
    pub fn default_map(self) -> Vec<(usize, &'static str)> {
        use skeleton::*;
        match self {
            Self::Coco17 | Self::CocoWholeBody | Self::BlazePose33 => vec![
                (R_HIP, "right_hip"),
                (R_KNEE, "right_knee"),
                (R_ANKLE, "right_ankle"),
                (L_HIP, "left_hip"),
                (L_KNEE, "left_knee"),
                (L_ANKLE, "left_ankle"),
                (R_SHOULDER, "right_shoulder"),
                (R_ELBOW, "right_elbow"),
                (R_HAND, "right_wrist"),
                (L_SHOULDER, "left_shoulder"),
                (L_ELBOW, "left_elbow"),
                (L_HAND, "left_wrist"),
            ],
            Self::Body25 | Self::Coco18 | Self::Halpe26 => {
                let mut map = match self {
                    Self::Body25 => vec![(ROOT, "MidHip")],
                    Self::Halpe26 => vec![(ROOT, "Hip")],
                    _ => Vec::new(),
                };
                map.extend(Self::OPENPOSE_LIMBS);
                map
            }
            Self::Panoptic19 => {
                use skeleton::*;
                vec![
                    (ROOT, "BodyCenter"),
                    (HEAD, "Neck"),
                    (R_HIP, "rHip"),
                    (R_KNEE, "rKnee"),
                    (R_ANKLE, "rAnkle"),
                    (L_HIP, "lHip"),
                    (L_KNEE, "lKnee"),
                    (L_ANKLE, "lAnkle"),
                    (R_SHOULDER, "rShoulder"),
                    (R_ELBOW, "rElbow"),
                    (R_HAND, "rWrist"),
                    (L_SHOULDER, "lShoulder"),
                    (L_ELBOW, "lElbow"),
                    (L_HAND, "lWrist"),
                ]
            }
        }
    }

    /// The head joint and the limbs under OpenPose's (and Halpe's) keypoint names.
    const OPENPOSE_LIMBS: [(usize, &'static str); 13] = {
        use skeleton::*;
        [
            (HEAD, "Neck"),
            (R_HIP, "RHip"),
            (R_KNEE, "RKnee"),
            (R_ANKLE, "RAnkle"),
            (L_HIP, "LHip"),
            (L_KNEE, "LKnee"),
            (L_ANKLE, "LAnkle"),
            (R_SHOULDER, "RShoulder"),
            (R_ELBOW, "RElbow"),
            (R_HAND, "RWrist"),
            (L_SHOULDER, "LShoulder"),
            (L_ELBOW, "LElbow"),
            (L_HAND, "LWrist"),
        ]
    };
}

/// One camera's keypoints over time.
#[derive(Debug, Clone, PartialEq)]
pub struct KeypointTrack {
    /// `openpose` or `coco`.
    pub format: &'static str,
    /// Per frame, per keypoint: `[x, y, confidence]` (zeros where nobody was detected).
    pub frames: Vec<Vec<[f64; 3]>>,
    /// Per frame, where it came from (`file` or `file#image_id`).
    pub sources: Vec<String>,
    /// Per frame, the image size a COCO file records.
    pub image_sizes: Vec<Option<(u32, u32)>>,
    /// Frames in which more than one person was found (the best one was kept).
    pub crowded_frames: usize,
}

fn read_json(path: &Path) -> Result<Value, ImportError> {
    let text = std::fs::read_to_string(path).map_err(|source| ImportError::Read {
        path: path.to_path_buf(),
        source,
    })?;
    serde_json::from_str(&text)
        .map_err(|e| ImportError::Invalid(format!("{}: malformed JSON: {e}", path.display())))
}

/// `3K` finite numbers as K `[x, y, c]` triples.
fn triples(v: &Value, layout: KeypointLayout, what: &str) -> Result<Vec<[f64; 3]>, ImportError> {
    let Some(a) = v.as_array() else {
        return fail(format!("{what} is not an array"));
    };
    let k = layout.count();
    if a.len() != 3 * k {
        return fail(format!(
            "{what} has {} values, expected {} ({k} keypoints × 3) for layout {}",
            a.len(),
            3 * k,
            layout.name()
        ));
    }
    let mut nums = Vec::with_capacity(a.len());
    for (i, x) in a.iter().enumerate() {
        match x.as_f64() {
            Some(f) if f.is_finite() => nums.push(f),
            _ => return fail(format!("{what}[{i}] is not a finite number ({x})")),
        }
    }
    Ok(nums.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect())
}

fn confidence_sum(t: &[[f64; 3]]) -> f64 {
    t.iter().map(|p| p[2]).sum()
}

/// The people of each frame, each with its rank (a COCO `score`, else its summed confidence),
/// before one is chosen per frame ([`People::choose`]).
struct People {
    frames: Vec<Vec<(f64, Vec<[f64; 3]>)>>,
    sources: Vec<String>,
    image_sizes: Vec<Option<(u32, u32)>>,
}

impl People {
    fn extend(&mut self, other: People) {
        self.frames.extend(other.frames);
        self.sources.extend(other.sources);
        self.image_sizes.extend(other.image_sizes);
    }

    /// One person per frame: where a frame has several, the first such frame keeps the
    /// best-ranked one, and every later one the person nearest the one kept in the frame before
    /// (the median distance over keypoints both saw), so that a sequence follows one subject
    /// where another scores higher for a while; nobody seen: no visible keypoint.
    fn choose(self, format: &'static str, k: usize) -> KeypointTrack {
        let mut frames = Vec::with_capacity(self.frames.len());
        let mut last: Option<Vec<[f64; 3]>> = None;
        let mut crowded = 0;
        for people in self.frames {
            crowded += usize::from(people.len() > 1);
            let best = |people: &[(f64, Vec<[f64; 3]>)]| {
                (1..people.len()).fold(0, |b, i| if people[i].0 > people[b].0 { i } else { b })
            };
            let pick = match (&last, people.len()) {
                (_, 0) => None,
                (_, 1) | (None, _) => Some(best(&people)),
                (Some(prev), _) => {
                    let distance = |t: &[[f64; 3]]| {
                        let mut d: Vec<f64> = t
                            .iter()
                            .zip(prev)
                            .filter(|(a, b)| a[2] > 0.0 && b[2] > 0.0)
                            .map(|(a, b)| (a[0] - b[0]).hypot(a[1] - b[1]))
                            .collect();
                        d.sort_by(f64::total_cmp);
                        d.get(d.len() / 2).copied()
                    };
                    let near = people
                        .iter()
                        .enumerate()
                        .filter_map(|(i, p)| distance(&p.1).map(|d| (i, d)))
                        .min_by(|a, b| a.1.total_cmp(&b.1));
                    Some(near.map_or_else(|| best(&people), |n| n.0))
                }
            };
            match pick {
                Some(i) => {
                    let t = people[i].1.clone();
                    last = Some(t.clone());
                    frames.push(t);
                }
                None => frames.push(vec![[0.0; 3]; k]),
            }
        }
        KeypointTrack {
            format,
            frames,
            sources: self.sources,
            image_sizes: self.image_sizes,
            crowded_frames: crowded,
        }
    }
}

/// Reads one OpenPose frame file: its people, ranked by summed confidence.
fn openpose_frame(
    v: &Value,
    layout: KeypointLayout,
    name: &str,
) -> Result<Vec<(f64, Vec<[f64; 3]>)>, ImportError> {
    let Some(people) = v.get("people").and_then(Value::as_array) else {
        return fail(format!("{name}: \"people\" is not an array"));
    };
    let mut found = Vec::with_capacity(people.len());
    for (i, p) in people.iter().enumerate() {
        let Some(kp) = p.get("pose_keypoints_2d") else {
            return fail(format!("{name}: people[{i}] has no \"pose_keypoints_2d\""));
        };
        let t = triples(
            kp,
            layout,
            &format!("{name}: people[{i}].pose_keypoints_2d"),
        )?;
        found.push((confidence_sum(&t), t));
    }
    Ok(found)
}

/// Reads a COCO results file, a detector's output (`[{"image_id", "keypoints", "score"?, ...}]`,
/// as mmpose and Detectron2 write it): its image ids are taken as frame numbers, every id from
/// the lowest to the highest is a frame (one without a detection has no visible keypoint); one
/// person is kept per frame by [`People::choose`].
fn coco_results_track(
    list: &[Value],
    layout: KeypointLayout,
    name: &str,
) -> Result<People, ImportError> {
    let mut detections = Vec::with_capacity(list.len());
    for (a, d) in list.iter().enumerate() {
        let Some(image) = d.get("image_id").and_then(Value::as_i64) else {
            return fail(format!("{name}: [{a}].image_id is not an integer id"));
        };
        let Some(kp) = d.get("keypoints") else {
            return fail(format!("{name}: [{a}] has no \"keypoints\""));
        };
        let t = triples(kp, layout, &format!("{name}: [{a}].keypoints"))?;
        let rank = d
            .get("score")
            .and_then(Value::as_f64)
            .unwrap_or_else(|| confidence_sum(&t));
        detections.push((image, rank, t));
    }
    let (Some(lo), Some(hi)) = (
        detections.iter().map(|d| d.0).min(),
        detections.iter().map(|d| d.0).max(),
    ) else {
        return fail(format!("{name}: an empty COCO results list (no detection)"));
    };
    let span = (hi - lo) as u64 + 1;
    if span > 1_000_000 || span > 10 * detections.len() as u64 + 1000 {
        return fail(format!(
            "{name}: image ids {lo}…{hi} span {span} frames for {} detections: not frame numbers (give a COCO file with \"images\" listing the frames)",
            detections.len()
        ));
    }
    let span = span as usize;
    let mut frames = vec![Vec::new(); span];
    for (image, rank, t) in detections {
        frames[(image - lo) as usize].push((rank, t));
    }
    Ok(People {
        frames,
        sources: (lo..=hi).map(|id| format!("{name}#{id}")).collect(),
        image_sizes: vec![None; span],
    })
}

/// Reads a COCO keypoint file: one frame per image (or a results list, [`coco_results_track`]).
fn coco_track(v: &Value, layout: KeypointLayout, name: &str) -> Result<People, ImportError> {
    if let Some(list) = v.as_array() {
        return coco_results_track(list, layout, name);
    }
    let Some(images) = v.get("images").and_then(Value::as_array) else {
        return fail(format!("{name}: \"images\" is not an array"));
    };
    let Some(annotations) = v.get("annotations").and_then(Value::as_array) else {
        return fail(format!("{name}: \"annotations\" is not an array"));
    };
    let id_of = |x: &Value, what: &str| -> Result<i64, ImportError> {
        x.as_i64()
            .ok_or_else(|| ImportError::Invalid(format!("{name}: {what} is not an integer id")))
    };
    let mut ids = Vec::with_capacity(images.len());
    let mut sizes = Vec::with_capacity(images.len());
    for (i, im) in images.iter().enumerate() {
        let id = id_of(
            im.get("id").unwrap_or(&Value::Null),
            &format!("images[{i}].id"),
        )?;
        if ids.contains(&id) {
            return fail(format!("{name}: image id {id} appears twice"));
        }
        ids.push(id);
        let dim = |k: &str| im.get(k).and_then(Value::as_u64).map(|x| x as u32);
        sizes.push(match (dim("width"), dim("height")) {
            (Some(w), Some(h)) => Some((w, h)),
            _ => None,
        });
    }
    let mut frames = vec![Vec::new(); ids.len()];
    for (a, ann) in annotations.iter().enumerate() {
        let image = id_of(
            ann.get("image_id").unwrap_or(&Value::Null),
            &format!("annotations[{a}].image_id"),
        )?;
        let Some(frame) = ids.iter().position(|&i| i == image) else {
            return fail(format!(
                "{name}: annotations[{a}] refers to image {image}, which \"images\" does not list"
            ));
        };
        let Some(kp) = ann.get("keypoints") else {
            return fail(format!("{name}: annotations[{a}] has no \"keypoints\""));
        };
        let t = triples(kp, layout, &format!("{name}: annotations[{a}].keypoints"))?;
        let rank = ann
            .get("score")
            .and_then(Value::as_f64)
            .unwrap_or_else(|| confidence_sum(&t));
        frames[frame].push((rank, t));
    }
    Ok(People {
        frames,
        sources: ids.iter().map(|id| format!("{name}#{id}")).collect(),
        image_sizes: sizes,
    })
}

/// A file name's order among frame files: runs of digits compare as numbers (`frame_2` before
/// `frame_10`, as the frames were written by tools that do not pad), equal numbers by their
/// written length, the rest as text. Zero-padded names (OpenPose's) keep their plain order.
fn natural_key(name: &str) -> Vec<(u8, usize, String, usize)> {
    let mut key = Vec::new();
    let mut chars = name.chars().peekable();
    while let Some(&c) = chars.peek() {
        let digit = c.is_ascii_digit();
        let mut run = String::new();
        while let Some(&d) = chars.peek() {
            if d.is_ascii_digit() != digit {
                break;
            }
            run.push(d);
            chars.next();
        }
        if digit {
            // A number by its digit count, then its digits: any length, no overflow.
            let value = run.trim_start_matches('0').to_string();
            key.push((0, value.len(), value, run.len()));
        } else {
            key.push((1, 0, run, 0));
        }
    }
    key
}

/// The JSON files of a directory, in frame order (an OpenPose output folder): [`natural_key`].
fn json_files(dir: &Path) -> Result<Vec<PathBuf>, ImportError> {
    let entries = std::fs::read_dir(dir).map_err(|source| ImportError::Read {
        path: dir.to_path_buf(),
        source,
    })?;
    let mut files: Vec<PathBuf> = entries
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.extension().is_some_and(|x| x == "json"))
        .collect();
    files.sort_by_cached_key(|p| {
        let name = p
            .file_name()
            .map_or_else(String::new, |n| n.to_string_lossy().into_owned());
        (natural_key(&name), p.clone())
    });
    if files.is_empty() {
        return fail(format!(
            "{}: no .json files in this directory",
            dir.display()
        ));
    }
    Ok(files)
}

/// Reads keypoints of one camera from `paths`, in order: COCO files (each a run of frames),
/// OpenPose frame files, or directories of OpenPose frame files (in frame order: numbers in
/// their names compared as numbers). A track is
/// either all COCO or all OpenPose.
pub fn read_track(paths: &[PathBuf], layout: KeypointLayout) -> Result<KeypointTrack, ImportError> {
    let mut files = Vec::new();
    for p in paths {
        if p.is_dir() {
            files.extend(json_files(p)?);
        } else {
            files.push(p.clone());
        }
    }
    let mut people = People {
        frames: Vec::new(),
        sources: Vec::new(),
        image_sizes: Vec::new(),
    };
    let mut track_format = "";
    for f in &files {
        let v = read_json(f)?;
        let name = f.display().to_string();
        let format = if v.get("people").is_some() {
            "openpose"
        } else if v.get("annotations").is_some() || v.is_array() {
            "coco"
        } else {
            return fail(format!(
                "{name}: neither an OpenPose frame (\"people\") nor a COCO keypoint file (\"annotations\") or results list"
            ));
        };
        if !track_format.is_empty() && track_format != format {
            return fail(format!(
                "{name} is a {format} file but the files before it are {track_format}"
            ));
        }
        track_format = format;
        if format == "openpose" {
            people.frames.push(openpose_frame(&v, layout, &name)?);
            people.sources.push(name);
            people.image_sizes.push(None);
        } else {
            people.extend(coco_track(&v, layout, &name)?);
        }
    }
    if people.frames.is_empty() {
        return fail("the keypoint files hold no frame");
    }
    Ok(people.choose(track_format, layout.count()))
}

/// One camera of a camera file: lfit's own keys, or OpenCV's calibration output (`K`, `R` or
/// `rvec`, `t` or `tvec`, `dist`), and the image size as `width`/`height` or `resolution`.
#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct CameraJson {
    fx: Option<f64>,
    fy: Option<f64>,
    cx: Option<f64>,
    cy: Option<f64>,
    #[serde(rename = "K")]
    k: Option<[[f64; 3]; 3]>,
    width: Option<u32>,
    height: Option<u32>,
    resolution: Option<[u32; 2]>,
    rotation: Option<[[f64; 3]; 3]>,
    #[serde(rename = "R")]
    r: Option<[[f64; 3]; 3]>,
    rvec: Option<Value>,
    translation: Option<Value>,
    t: Option<Value>,
    tvec: Option<Value>,
    #[serde(alias = "distortion", alias = "distCoef")]
    dist: Option<Value>,
    /// A label (OpenCV's, CMU Panoptic's and most calibration tools' files carry one): what
    /// `--camera-names` chooses cameras by.
    name: Option<Value>,
    /// CMU Panoptic's camera kind (`hd`, `vga`, `kinect-color`, ...), panel and node: not read
    /// (its `name` is `PP_NN`, panel and node).
    #[serde(rename = "type")]
    #[allow(dead_code)]
    kind: Option<Value>,
    #[allow(dead_code)]
    panel: Option<Value>,
    #[allow(dead_code)]
    node: Option<Value>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct CameraFile {
    cameras: Vec<CameraJson>,
    /// Unit of the translations: `m` (lfit's own files; the default), `cm` (CMU Panoptic's
    /// default) or `mm`.
    units: Option<String>,
    /// The capture a CMU Panoptic calibration file (`calibration_<sequence>.json`) belongs to:
    /// such a file's translations are in centimetres unless `units` says otherwise.
    #[serde(rename = "calibDataSource")]
    #[allow(dead_code)]
    calib_data_source: Option<Value>,
}

/// The cameras of a camera file ([`read_camera_file`]): each one's pinhole camera, lens
/// distortion where the file gives one, and name where it gives one.
#[derive(Debug, Clone, PartialEq)]
pub struct CameraFileRig {
    /// The pinhole cameras, translations in metres.
    pub cameras: Vec<Camera>,
    /// Each camera's lens distortion, `None` for a pinhole camera.
    pub distortion: Vec<Option<Distortion>>,
    /// Each camera's `name`, `None` where the file gives none.
    pub names: Vec<Option<String>>,
    /// Per camera, whether the file leaves its image size out (an EasyMocap `intri.yml` without
    /// `W_`/`H_`): then taken as twice the principal point.
    pub sizes_from_principal_point: Vec<bool>,
}

impl CameraFileRig {
    /// The cameras whose image size is twice their principal point, by name (`#K` unnamed).
    pub fn size_guessed_names(&self) -> Vec<String> {
        (0..self.cameras.len())
            .filter(|&i| self.sizes_from_principal_point[i])
            .map(|i| self.names[i].clone().unwrap_or_else(|| format!("#{i}")))
            .collect()
    }

    /// The cameras `chosen`, in that order: each entry a name the file gives exactly one camera,
    /// or `#K` for its camera K (counted from 0). An unknown, ambiguous or repeated choice is a
    /// one-line error.
    pub fn select(&self, chosen: &[String]) -> Result<Self, ImportError> {
        let mut picked: Vec<usize> = Vec::with_capacity(chosen.len());
        for want in chosen {
            let index = if let Some(k) = want.strip_prefix('#') {
                match k.parse::<usize>() {
                    Ok(k) if k < self.cameras.len() => k,
                    _ => {
                        return fail(format!(
                            "camera '{want}': the camera file has cameras #0 to #{}",
                            self.cameras.len() - 1
                        ));
                    }
                }
            } else {
                let hits: Vec<usize> = (0..self.names.len())
                    .filter(|&i| self.names[i].as_deref() == Some(want.as_str()))
                    .collect();
                match hits.as_slice() {
                    [i] => *i,
                    [] => {
                        let named: Vec<&str> =
                            self.names.iter().flatten().map(String::as_str).collect();
                        let shown = named
                            .iter()
                            .take(12)
                            .copied()
                            .collect::<Vec<_>>()
                            .join(", ");
                        let more = if named.len() > 12 { ", ..." } else { "" };
                        return fail(if named.is_empty() {
                            format!(
                                "no camera named '{want}': the camera file names none (choose by #K)"
                            )
                        } else {
                            format!(
                                "no camera named '{want}' in the camera file (its {} names: {shown}{more})",
                                named.len()
                            )
                        });
                    }
                    [i, j, ..] => {
                        return fail(format!(
                            "cameras #{i} and #{j} are both named '{want}': choose by #K"
                        ));
                    }
                }
            };
            if let Some(before) = picked.iter().position(|&p| p == index) {
                return fail(format!(
                    "camera '{want}' chosen twice (it is '{}' too)",
                    chosen[before]
                ));
            }
            picked.push(index);
        }
        if picked.is_empty() {
            return fail("no camera chosen");
        }
        Ok(Self {
            cameras: picked.iter().map(|&i| self.cameras[i].clone()).collect(),
            distortion: picked.iter().map(|&i| self.distortion[i]).collect(),
            names: picked.iter().map(|&i| self.names[i].clone()).collect(),
            sizes_from_principal_point: picked
                .iter()
                .map(|&i| self.sizes_from_principal_point[i])
                .collect(),
        })
    }
}

/// Lens distortion of a camera, OpenCV's model (Brown–Conrady with its rational radial terms):
/// on normalised coordinates `(x, y)`, `r² = x² + y²`,
/// `x_d = x (1 + k1 r² + k2 r⁴ + k3 r⁶) / (1 + k4 r² + k5 r⁴ + k6 r⁶) + 2 p1 x y + p2 (r² + 2x²)`
/// and `y_d` alike with `p1 (r² + 2y²) + 2 p2 x y`. A camera file's `dist` lists OpenCV's
/// coefficients in its order, `k1 k2 p1 p2 [k3 [k4 k5 k6]]` (4, 5 or 8 numbers).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Distortion {
    /// k1 … k6.
    pub k: [f64; 6],
    /// p1, p2.
    pub p: [f64; 2],
}

impl Distortion {
    /// From OpenCV's coefficient list (4, 5 or 8 finite numbers); `None` for all zeros.
    pub fn from_opencv(c: &[f64]) -> Result<Option<Self>, ImportError> {
        if ![4, 5, 8].contains(&c.len()) {
            return fail(format!(
                "{} distortion coefficients: expected OpenCV's k1 k2 p1 p2 [k3 [k4 k5 k6]] (4, 5 or 8; the thin-prism and tilt terms are not modelled)",
                c.len()
            ));
        }
        if c.iter().any(|v| !v.is_finite()) {
            return fail("distortion coefficients must be finite");
        }
        let at = |i: usize| c.get(i).copied().unwrap_or(0.0);
        let d = Self {
            k: [at(0), at(1), at(4), at(5), at(6), at(7)],
            p: [at(2), at(3)],
        };
        Ok((d.k.iter().chain(&d.p).any(|&v| v != 0.0)).then_some(d))
    }

    /// OpenCV's coefficient list `k1 k2 p1 p2 k3` (5), or with `k4 k5 k6` (8) where the rational
    /// terms are not zero: what [`Distortion::from_opencv`] reads back.
    pub fn to_opencv(&self) -> Vec<f64> {
        let [k1, k2, k3, k4, k5, k6] = self.k;
        let [p1, p2] = self.p;
        let mut c = vec![k1, k2, p1, p2, k3];
        if [k4, k5, k6].iter().any(|&v| v != 0.0) {
            c.extend([k4, k5, k6]);
        }
        c
    }

    /// Distorted normalised coordinates of the undistorted `(x, y)`.
    pub fn distort(&self, x: f64, y: f64) -> (f64, f64) {
        let [k1, k2, k3, k4, k5, k6] = self.k;
        let [p1, p2] = self.p;
        let r2 = x * x + y * y;
        let radial =
            (1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))) / (1.0 + r2 * (k4 + r2 * (k5 + r2 * k6)));
        (
            x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x),
            y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y,
        )
    }

    /// The undistorted normalised coordinates whose distortion is `(xd, yd)`: Newton's method
    /// on the model above (its 2 × 2 Jacobian by central differences), from `(xd, yd)`, to
    /// 1e-12; `None` where it does not converge or converges past where the radial map folds
    /// over (a point the lens cannot have imaged there).
    pub fn undistort(&self, xd: f64, yd: f64) -> Option<(f64, f64)> {
        let (mut x, mut y) = (xd, yd);
        for _ in 0..50 {
            let (fx, fy) = self.distort(x, y);
            let (rx, ry) = (fx - xd, fy - yd);
            if rx.abs().max(ry.abs()) < 1e-12 {
                return self.unfolded(x.hypot(y)).then_some((x, y));
            }
            let h = 1e-7;
            let (ax, ay) = self.distort(x + h, y);
            let (bx, by) = self.distort(x - h, y);
            let (cx, cy) = self.distort(x, y + h);
            let (dx, dy) = self.distort(x, y - h);
            let (j11, j21) = ((ax - bx) / (2.0 * h), (ay - by) / (2.0 * h));
            let (j12, j22) = ((cx - dx) / (2.0 * h), (cy - dy) / (2.0 * h));
            let det = j11 * j22 - j12 * j21;
            if !det.is_finite() || det.abs() < 1e-12 {
                return None;
            }
            x -= (j22 * rx - j12 * ry) / det;
            y -= (j11 * ry - j21 * rx) / det;
        }
        None
    }

    /// Whether the radial map `r ↦ r (1 + k1 r² + …) / (1 + k4 r² + …)` rises all the way from the
    /// centre to radius `r` (checked at 256 radii): a point past where it folds over has a second
    /// preimage, not the one the lens imaged.
    fn unfolded(&self, r: f64) -> bool {
        let [k1, k2, k3, k4, k5, k6] = self.k;
        let g = |r: f64| {
            let r2 = r * r;
            r * (1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))) / (1.0 + r2 * (k4 + r2 * (k5 + r2 * k6)))
        };
        let mut last = 0.0;
        r == 0.0
            || (1..=256).all(|i| {
                let now = g(r * f64::from(i) / 256.0);
                let rising = now > last;
                last = now;
                rising
            })
    }

    /// The pixel `(u, v)` of `camera` as the pinhole camera without this distortion sees it.
    pub fn undistort_pixel(&self, camera: &Camera, u: f64, v: f64) -> Option<(f64, f64)> {
        let (x, y) = self.undistort((u - camera.cx) / camera.fx, (v - camera.cy) / camera.fy)?;
        Some((camera.fx * x + camera.cx, camera.fy * y + camera.cy))
    }
}

/// Three numbers given as `[x, y, z]` or as a column `[[x], [y], [z]]` (OpenCV's `tvec`).
fn three(v: &Value, what: &str) -> Result<[f64; 3], ImportError> {
    let flat: Vec<f64> = match v {
        Value::Array(a) if a.len() == 3 && a.iter().all(Value::is_array) => a
            .iter()
            .map(|r| match r.as_array().map(Vec::as_slice) {
                Some([x]) => x.as_f64(),
                _ => None,
            })
            .collect::<Option<_>>()
            .unwrap_or_default(),
        Value::Array(a) => a
            .iter()
            .map(Value::as_f64)
            .collect::<Option<_>>()
            .unwrap_or_default(),
        _ => Vec::new(),
    };
    flat.try_into().map_err(|_| {
        ImportError::Invalid(format!(
            "'{what}' must be 3 numbers, [x, y, z] or [[x], [y], [z]]"
        ))
    })
}

/// A camera file's distortion list, flat or as one row (`[[k1, k2, ...]]`).
fn coefficients(v: &Value) -> Result<Vec<f64>, ImportError> {
    let row = match v {
        Value::Array(a) if a.len() == 1 && a[0].is_array() => &a[0],
        other => other,
    };
    row.as_array()
        .and_then(|a| a.iter().map(Value::as_f64).collect::<Option<Vec<f64>>>())
        .ok_or_else(|| ImportError::Invalid("'dist' must be a list of numbers".into()))
}

/// Exactly one of the keys that give one quantity: its value and key.
fn one_of<'a, T>(
    what: &str,
    given: &[(&'static str, &'a Option<T>)],
) -> Result<(&'a T, &'static str), ImportError> {
    let present: Vec<(&'static str, &'a T)> = given
        .iter()
        .filter_map(|&(k, v)| v.as_ref().map(|v| (k, v)))
        .collect();
    match present.as_slice() {
        [(k, v)] => Ok((*v, *k)),
        [] => fail(format!(
            "no {what}: give {}",
            given.iter().map(|g| g.0).collect::<Vec<_>>().join(" or ")
        )),
        _ => fail(format!(
            "{what} given twice ({}): give one",
            present.iter().map(|p| p.0).collect::<Vec<_>>().join(", ")
        )),
    }
}

/// A rotation vector (axis times angle, OpenCV's `rvec`) as a row-major matrix.
fn rodrigues(r: [f64; 3]) -> [[f64; 3]; 3] {
    let m = lfit_model::body::rotation::exp_map(glam::DVec3::from_array(r));
    [
        m.row(0).to_array(),
        m.row(1).to_array(),
        m.row(2).to_array(),
    ]
}

impl CameraJson {
    /// The camera, its distortion and name; `metres`: metres per unit of the translation.
    fn resolve(
        &self,
        metres: f64,
    ) -> Result<(Camera, Option<Distortion>, Option<String>), ImportError> {
        let name = match &self.name {
            None => None,
            Some(Value::String(s)) => Some(s.clone()),
            Some(Value::Number(n)) => Some(n.to_string()),
            Some(_) => return fail("'name' must be a string"),
        };
        let (fx, fy, cx, cy) = match (&self.k, (self.fx, self.fy, self.cx, self.cy)) {
            (Some(_), (None, None, None, None)) => {
                let k = self.k.unwrap_or_default();
                if k[0][1].abs() > 1e-9 * k[0][0].abs() {
                    return fail(format!("K has skew {} (K[0][1]): not modelled", k[0][1]));
                }
                if k[1][0] != 0.0 || k[2][0] != 0.0 || k[2][1] != 0.0 || k[2][2] != 1.0 {
                    return fail("K must be [[fx, 0, cx], [0, fy, cy], [0, 0, 1]]");
                }
                (k[0][0], k[1][1], k[0][2], k[1][2])
            }
            (None, (Some(fx), Some(fy), Some(cx), Some(cy))) => (fx, fy, cx, cy),
            (Some(_), _) => return fail("intrinsics given twice (K and fx/fy/cx/cy): give one"),
            (None, _) => return fail("no intrinsics: give fx, fy, cx and cy, or K"),
        };
        let (width, height) = match (self.width, self.height, self.resolution) {
            (Some(w), Some(h), None) => (w, h),
            (None, None, Some([w, h])) => (w, h),
            (None, None, None) | (Some(_), None, None) | (None, Some(_), None) => {
                return fail("no image size: give width and height, or resolution [w, h]");
            }
            _ => return fail("image size given twice (width/height and resolution): give one"),
        };
        let rvec = self
            .rvec
            .as_ref()
            .map(|v| three(v, "rvec").map(rodrigues))
            .transpose()?;
        let (rotation, _) = one_of(
            "rotation",
            &[
                ("rotation", &self.rotation),
                ("R", &self.r),
                ("rvec", &rvec),
            ],
        )?;
        let rotation = *rotation;
        let (t, key) = one_of(
            "translation",
            &[
                ("translation", &self.translation),
                ("t", &self.t),
                ("tvec", &self.tvec),
            ],
        )?;
        let translation = three(t, key)?.map(|x| x * metres);
        let dist = match &self.dist {
            Some(v) => Distortion::from_opencv(&coefficients(v)?)?,
            None => None,
        };
        Ok((
            Camera {
                fx,
                fy,
                cx,
                cy,
                width,
                height,
                rotation,
                translation,
            },
            dist,
            name,
        ))
    }
}

/// An anipose / Pose2Sim calibration (`calibration.toml`, `Calib*.toml`): one table per camera,
/// in the file's order, with `name`, `size` ([width, height] px), `matrix` (K), `distortions`
/// (OpenCV's coefficients), `rotation` (a rotation vector) and `translation` (camera from
/// world, in the calibration board's unit), and `fisheye` (OpenCV's fisheye model: refused, not
/// modelled); a `[metadata]` table is not read. Each camera as a camera file's JSON entry.
fn toml_cameras(text: &str) -> Result<CameraFile, String> {
    let table: toml::Table = toml::from_str(text).map_err(|e| {
        let line = e
            .span()
            .map(|s| text[..s.start.min(text.len())].lines().count().max(1));
        match line {
            Some(l) => format!("malformed TOML at line {l}: {}", e.message().trim()),
            None => format!("malformed TOML: {}", e.message().trim()),
        }
    })?;
    let mut cameras = Vec::new();
    for (key, section) in &table {
        if key == "metadata" {
            continue;
        }
        let Some(section) = section.as_table() else {
            return Err(format!(
                "'{key}' is not a camera table ([{key}] with name, size, matrix, distortions, rotation, translation)"
            ));
        };
        let mut cam = serde_json::Map::new();
        for (k, v) in section {
            let v = serde_json::to_value(v).map_err(|e| format!("[{key}] {k}: {e}"))?;
            let json_key = match k.as_str() {
                "name" => "name",
                "matrix" => "K",
                "distortions" => "dist",
                "rotation" => "rvec",
                "translation" => "translation",
                "size" => {
                    let size = v
                        .as_array()
                        .filter(|a| a.len() == 2)
                        .and_then(|a| {
                            a.iter()
                                .map(|x| {
                                    x.as_f64()
                                        .filter(|x| x.fract() == 0.0 && *x > 0.0 && *x < 1e6)
                                })
                                .collect::<Option<Vec<f64>>>()
                        })
                        .ok_or_else(|| {
                            format!("[{key}] size must be [width, height] in whole pixels")
                        })?;
                    cam.insert(
                        "resolution".into(),
                        serde_json::json!([size[0] as u32, size[1] as u32]),
                    );
                    continue;
                }
                "fisheye" => match v.as_bool() {
                    Some(false) => continue,
                    Some(true) => {
                        return Err(format!(
                            "[{key}] is a fisheye camera (OpenCV's fisheye model), which lfit does not model"
                        ));
                    }
                    None => return Err(format!("[{key}] fisheye must be true or false")),
                },
                other => {
                    return Err(format!(
                        "[{key}] has the unknown key '{other}' (expected name, size, matrix, distortions, rotation, translation, fisheye)"
                    ));
                }
            };
            cam.insert(json_key.into(), v);
        }
        cam.entry("name")
            .or_insert_with(|| Value::String(key.clone()));
        let cam: CameraJson =
            serde_json::from_value(Value::Object(cam)).map_err(|e| format!("[{key}]: {e}"))?;
        cameras.push(cam);
    }
    Ok(CameraFile {
        cameras,
        units: None,
        calib_data_source: None,
    })
}

/// Reads and checks a camera file (see the module documentation): the cameras, each one's lens
/// distortion and name where the file gives them.
pub fn read_camera_file(path: &Path) -> Result<CameraFileRig, ImportError> {
    read_camera_file_in(path, None)
}

/// Metres per unit of a camera file's translations: `m`, `cm` or `mm` (else `None`).
pub fn metres_per_unit(unit: &str) -> Option<f64> {
    match unit {
        "m" => Some(1.0),
        "cm" => Some(0.01),
        "mm" => Some(0.001),
        _ => None,
    }
}

/// [`read_camera_file`] with the translations' unit given (`m`, `cm` or `mm`): for a file that
/// does not say it (anipose's calibrations are in the board's unit, often millimetres); a file
/// whose `units` says otherwise is refused.
pub fn read_camera_file_in(path: &Path, units: Option<&str>) -> Result<CameraFileRig, ImportError> {
    let bad = |e: String| ImportError::Invalid(format!("camera file {}: {e}", path.display()));
    let mut guessed = Vec::new();
    let mut file: CameraFile = if let Some(dir) = opencv_yaml::easymocap_dir(path) {
        let (cameras, sizes) = opencv_yaml::easymocap_cameras(&dir).map_err(bad)?;
        guessed = sizes;
        CameraFile {
            cameras: cameras
                .into_iter()
                .enumerate()
                .map(|(i, c)| {
                    serde_json::from_value(c).map_err(|e| bad(format!("camera {i}: {e}")))
                })
                .collect::<Result<_, _>>()?,
            units: None,
            calib_data_source: None,
        }
    } else {
        let text = std::fs::read_to_string(path).map_err(|source| ImportError::Read {
            path: path.to_path_buf(),
            source,
        })?;
        let is_toml = path
            .extension()
            .is_some_and(|e| e.eq_ignore_ascii_case("toml"));
        if is_toml {
            toml_cameras(&text).map_err(bad)?
        } else {
            serde_json::from_str(&text).map_err(|e| bad(e.to_string()))?
        }
    };
    if file.cameras.is_empty() {
        return fail(format!("camera file {}: no cameras", path.display()));
    }
    match (units, file.units.as_deref()) {
        (Some(given), Some(own)) if given != own => {
            return Err(bad(format!(
                "its units are '{own}', not the '{given}' asked for"
            )));
        }
        (Some(given), _) => file.units = Some(given.to_string()),
        (None, _) => {}
    }
    let metres = match (file.units.as_deref(), &file.calib_data_source) {
        (None, None) => 1.0,
        // A CMU Panoptic calibration, in centimetres.
        (None, Some(_)) => 0.01,
        (Some(unit), _) => metres_per_unit(unit).ok_or_else(|| {
            bad(format!(
                "units '{unit}': expected m, cm or mm (the translations' unit)"
            ))
        })?,
    };
    let mut rig = CameraFileRig {
        cameras: Vec::with_capacity(file.cameras.len()),
        distortion: Vec::with_capacity(file.cameras.len()),
        names: Vec::with_capacity(file.cameras.len()),
        sizes_from_principal_point: (0..file.cameras.len())
            .map(|i| guessed.get(i).copied().unwrap_or(false))
            .collect(),
    };
    for (i, c) in file.cameras.iter().enumerate() {
        let label = match &c.name {
            Some(Value::String(n)) => format!("camera {i} ({n})"),
            _ => format!("camera {i}"),
        };
        let (cam, dist, name) = c
            .resolve(metres)
            .map_err(|e| bad(format!("{label}: {e}")))?;
        cam.validate(i).map_err(|e| bad(e.to_string()))?;
        rig.cameras.push(cam);
        rig.distortion.push(dist);
        rig.names.push(name);
    }
    Ok(rig)
}

/// Reads and checks a camera file of pinhole cameras (a rig to synthesise through, `lfit synth
/// --camera`): one that gives a lens distortion is refused (synthesis does not model it).
pub fn read_cameras(path: &Path) -> Result<Vec<Camera>, ImportError> {
    let rig = read_camera_file(path)?;
    if let Some(i) = rig.distortion.iter().position(Option::is_some) {
        return fail(format!(
            "camera file {}: camera {i} has a lens distortion, which synthesis does not model (lfit data import undistorts keypoints with it): `lfit data cameras --camera {} --pinhole --out RIG.json` writes the rig without it",
            path.display(),
            path.display()
        ));
    }
    Ok(rig.cameras)
}

/// The unit of a keypoint file's `x, y`: lfit reads pixels of the camera's image; other tools
/// write fractions of it.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum KeypointScale {
    /// Pixels of the camera's image (OpenPose's default `--keypoint_scale 0`, mmpose, AlphaPose,
    /// Detectron2, Pose2Sim's files).
    #[default]
    Pixels,
    /// Fractions of the image's width and height: `x·W`, `y·H` (MediaPipe's normalised
    /// landmarks).
    Image,
    /// OpenPose `--keypoint_scale 3`: [0, 1] from the first pixel to the last, `x·(W − 1)`.
    OpenPose3,
    /// OpenPose `--keypoint_scale 4`: [−1, 1] from the first pixel to the last,
    /// `(x + 1)/2·(W − 1)`.
    OpenPose4,
}

impl KeypointScale {
    /// The names `--keypoint-scale` takes.
    pub const NAMES: &'static str = "pixels, image, openpose3 or openpose4";

    pub fn name(self) -> &'static str {
        match self {
            KeypointScale::Pixels => "pixels",
            KeypointScale::Image => "image",
            KeypointScale::OpenPose3 => "openpose3",
            KeypointScale::OpenPose4 => "openpose4",
        }
    }

    /// `(x, y)` in this unit as pixels of a `width × height` image.
    pub fn to_pixels(self, x: f64, y: f64, width: u32, height: u32) -> (f64, f64) {
        let (w, h) = (f64::from(width), f64::from(height));
        match self {
            KeypointScale::Pixels => (x, y),
            KeypointScale::Image => (x * w, y * h),
            KeypointScale::OpenPose3 => (x * (w - 1.0), y * (h - 1.0)),
            KeypointScale::OpenPose4 => ((x + 1.0) / 2.0 * (w - 1.0), (y + 1.0) / 2.0 * (h - 1.0)),
        }
    }
}

impl std::str::FromStr for KeypointScale {
    type Err = ImportError;

    fn from_str(s: &str) -> Result<Self, ImportError> {
        [
            KeypointScale::Pixels,
            KeypointScale::Image,
            KeypointScale::OpenPose3,
            KeypointScale::OpenPose4,
        ]
        .into_iter()
        .find(|k| k.name() == s)
        .ok_or_else(|| {
            ImportError::Invalid(format!(
                "--keypoint-scale {s}: expected {}",
                KeypointScale::NAMES
            ))
        })
    }
}

/// `track`'s seen keypoints (confidence above 0) from `scale`'s unit into pixels of `camera`'s
/// image, before anything reads them as pixels (undistortion, the import).
pub fn scale_track(track: &mut KeypointTrack, camera: &Camera, scale: KeypointScale) {
    if scale == KeypointScale::Pixels {
        return;
    }
    for p in track.frames.iter_mut().flatten() {
        if p[2] > 0.0 {
            (p[0], p[1]) = scale.to_pixels(p[0], p[1], camera.width, camera.height);
        }
    }
}

/// `track`'s keypoints as the pinhole `camera` without `distortion` sees them (each seen
/// keypoint undistorted, [`Distortion::undistort_pixel`]); a keypoint where the model does not
/// invert is an error naming its frame.
pub fn undistort_track(
    track: &mut KeypointTrack,
    camera: &Camera,
    distortion: &Distortion,
) -> Result<(), ImportError> {
    for (f, frame) in track.frames.iter_mut().enumerate() {
        for p in frame.iter_mut() {
            if p[2] <= 0.0 {
                continue;
            }
            let Some((u, v)) = distortion.undistort_pixel(camera, p[0], p[1]) else {
                return fail(format!(
                    "{}: keypoint at ({}, {}) px is where the lens distortion does not invert (beyond its fold)",
                    track.sources[f], p[0], p[1]
                ));
            };
            p[0] = u;
            p[1] = v;
        }
    }
    Ok(())
}

/// The JSON text of a camera file in lfit's own keys for `rig` (metres): each camera's `name`
/// where it has one and its `dist` (OpenCV's coefficients) unless `pinhole`. What
/// [`read_camera_file`] reads back as `rig`.
pub fn camera_file_json(rig: &CameraFileRig, pinhole: bool) -> String {
    let list: Vec<Value> = rig
        .cameras
        .iter()
        .enumerate()
        .map(|(i, c)| {
            let mut cam = serde_json::json!({
                "fx": c.fx, "fy": c.fy, "cx": c.cx, "cy": c.cy,
                "width": c.width, "height": c.height,
                "rotation": c.rotation, "translation": c.translation,
            });
            if let Some(n) = &rig.names[i] {
                cam["name"] = serde_json::json!(n);
            }
            if let (Some(d), false) = (&rig.distortion[i], pinhole) {
                cam["dist"] = serde_json::json!(d.to_opencv());
            }
            cam
        })
        .collect();
    serde_json::to_string_pretty(&serde_json::json!({ "cameras": list }))
        .expect("numbers and strings serialise")
}

/// The JSON text of a camera file for `cameras` (the format [`read_cameras`] reads).
pub fn cameras_json(cameras: &[Camera]) -> String {
    let list: Vec<Value> = cameras.iter().map(camera_entry).collect();
    serde_json::json!({ "cameras": list }).to_string()
}

/// One camera in lfit's own keys (metres, camera-from-world).
fn camera_entry(c: &Camera) -> Value {
    serde_json::json!({
        "fx": c.fx, "fy": c.fy, "cx": c.cx, "cy": c.cy,
        "width": c.width, "height": c.height,
        "rotation": c.rotation, "translation": c.translation,
    })
}

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod tests {
    use super::*;
    use lfit_model::camera::default_ring;

    fn write(dir: &Path, name: &str, text: &str) -> PathBuf {
        let p = dir.join(name);
        std::fs::write(&p, text).unwrap();
        p
    }

    fn flat(k: usize, f: impl Fn(usize) -> [f64; 3]) -> Vec<f64> {
        (0..k).flat_map(f).collect()
    }

    #[test]
    fn openpose_frames_keep_the_most_confident_person() {
        let d = tempfile::tempdir().unwrap();
        let a = flat(25, |i| [i as f64, 2.0 * i as f64, 0.5]);
        let b = flat(25, |i| [100.0 + i as f64, 0.0, 0.9]);
        write(
            d.path(),
            "f_000.json",
            &serde_json::json!({"version": 1.3, "people": [{"pose_keypoints_2d": a}, {"pose_keypoints_2d": b}]}).to_string(),
        );
        write(d.path(), "f_001.json", r#"{"people": []}"#);
        let t = read_track(&[d.path().to_path_buf()], KeypointLayout::Body25).unwrap();
        assert_eq!(t.format, "openpose");
        assert_eq!(t.frames.len(), 2);
        assert_eq!(t.frames[0][3], [103.0, 0.0, 0.9]);
        assert_eq!(t.frames[1][0], [0.0; 3]);
        assert_eq!(t.crowded_frames, 1);
    }

    /// A folder's frame files in frame order: unpadded numbers as numbers (`f_2` before `f_10`),
    /// padded ones as written, whatever order the directory lists them in.
    #[test]
    fn a_folder_of_frames_reads_in_frame_order() {
        let d = tempfile::tempdir().unwrap();
        for i in [10, 2, 1, 100, 9] {
            let k = flat(25, |_| [i as f64, 0.0, 0.9]);
            write(
                d.path(),
                &format!("clip_{i}_keypoints.json"),
                &serde_json::json!({"people": [{"pose_keypoints_2d": k}]}).to_string(),
            );
        }
        let t = read_track(&[d.path().to_path_buf()], KeypointLayout::Body25).unwrap();
        let order: Vec<f64> = t.frames.iter().map(|f| f[0][0]).collect();
        assert_eq!(order, [1.0, 2.0, 9.0, 10.0, 100.0]);
        let mut names = vec![
            "v_000000000010_keypoints.json",
            "v_000000000002_keypoints.json",
            "v_000000000000_keypoints.json",
        ];
        names.sort_by_key(|n| natural_key(n));
        assert_eq!(
            names,
            [
                "v_000000000000_keypoints.json",
                "v_000000000002_keypoints.json",
                "v_000000000010_keypoints.json"
            ]
        );
        // Numbers longer than any integer type still order.
        let (nines, one) = (
            format!("f_{}.json", "9".repeat(60)),
            format!("f_1{}.json", "0".repeat(60)),
        );
        let mut names = vec![one.as_str(), nines.as_str(), "f_7.json"];
        names.sort_by_key(|n| natural_key(n));
        assert_eq!(names, ["f_7.json", nines.as_str(), one.as_str()]);
    }

    /// Every layout's default map names keypoints of that layout, each joint once; OpenPose's
    /// COCO model and Halpe-26 read by name (their counts, the root and the neck where they have
    /// them); a frame of 18 people's keypoints reads as `coco18`, not as `body25`.
    #[test]
    fn every_layout_maps_its_own_keypoints() {
        use lfit_model::skeleton::{HEAD, ROOT};
        for (name, count, root) in [
            ("coco17", 17, None),
            ("body25", 25, Some("MidHip")),
            ("coco18", 18, None),
            ("halpe26", 26, Some("Hip")),
            ("wholebody133", 133, None),
            ("blazepose33", 33, None),
            ("panoptic19", 19, Some("BodyCenter")),
        ] {
            let layout: KeypointLayout = name.parse().unwrap();
            assert_eq!((layout.name(), layout.count()), (name, count));
            let map = layout.default_map();
            for (joint, kp) in &map {
                assert!(layout.index(kp).is_some(), "{name}: {kp}");
                assert_eq!(map.iter().filter(|m| m.0 == *joint).count(), 1, "{name}");
            }
            assert_eq!(
                map.iter().find(|m| m.0 == ROOT).map(|m| m.1),
                root,
                "{name}"
            );
            let neck = map.iter().find(|m| m.0 == HEAD).map(|m| m.1);
            let necked = !matches!(name, "coco17" | "wholebody133" | "blazepose33");
            assert_eq!(neck, necked.then_some("Neck"), "{name}");
            assert_eq!(
                map.len(),
                12 + usize::from(neck.is_some()) + usize::from(root.is_some())
            );
        }
        let e = "coco19".parse::<KeypointLayout>().unwrap_err().to_string();
        assert!(
            e.contains("coco17, body25, coco18, halpe26, wholebody133, blazepose33 or panoptic19"),
            "{e}"
        );
        // The whole-body layout's first 17 are COCO's, its default map COCO-17's.
        assert_eq!(&COCO_WHOLEBODY[..17], &COCO17[..]);
        assert_eq!(
            KeypointLayout::CocoWholeBody.default_map(),
            KeypointLayout::Coco17.default_map()
        );
        let d = tempfile::tempdir().unwrap();
        let k = flat(18, |i| [i as f64, 1.0, 0.9]);
        write(
            d.path(),
            "f.json",
            &serde_json::json!({"people": [{"pose_keypoints_2d": k}]}).to_string(),
        );
        let t = read_track(&[d.path().to_path_buf()], KeypointLayout::Coco18).unwrap();
        assert_eq!(
            t.frames[0][KeypointLayout::Coco18.index("LWrist").unwrap()],
            [7.0, 1.0, 0.9]
        );
        let e = read_track(&[d.path().to_path_buf()], KeypointLayout::Body25)
            .unwrap_err()
            .to_string();
        assert!(e.contains("54 values, expected 75"), "{e}");
    }

    /// A detector's COCO results list: its image ids are frames, every id between the lowest
    /// and the highest a frame (none detected: nothing seen), one person followed;
    /// a list without ids, an empty one and ids that cannot be frame numbers are refused.
    #[test]
    fn a_coco_results_list_gives_a_frame_per_image_id() {
        let d = tempfile::tempdir().unwrap();
        let det = |id: i64, x: f64, score: f64| serde_json::json!({"image_id": id, "category_id": 1, "keypoints": flat(17, |_| [x, 2.0, 0.8]), "score": score});
        let list = serde_json::json!([
            det(5, 50.0, 0.4),
            det(3, 30.0, 0.9),
            det(5, 90.0, 0.7),
            det(6, 60.0, 0.5)
        ]);
        let p = write(d.path(), "results.json", &list.to_string());
        let t = read_track(&[p], KeypointLayout::Coco17).unwrap();
        assert_eq!(t.format, "coco");
        let xs: Vec<f64> = t.frames.iter().map(|f| f[0][0]).collect();
        // Frame 5's two detections: the one nearer the person of frame 3, not the higher score.
        assert_eq!(xs, [30.0, 0.0, 50.0, 60.0]);
        assert_eq!(t.frames[1][0], [0.0; 3]);
        assert!(t.sources[1].ends_with("results.json#4"), "{}", t.sources[1]);
        assert_eq!(t.crowded_frames, 1);
        assert!(t.image_sizes.iter().all(Option::is_none));
        for (text, needle) in [
            (serde_json::json!([]).to_string(), "empty COCO results list"),
            (
                serde_json::json!([{"keypoints": flat(17, |_| [1.0, 1.0, 1.0])}]).to_string(),
                "[0].image_id is not an integer id",
            ),
            (
                serde_json::json!([det(1, 1.0, 0.5), det(9_000_000, 1.0, 0.5)]).to_string(),
                "not frame numbers",
            ),
        ] {
            let p = write(d.path(), "bad.json", &text);
            let e = read_track(&[p], KeypointLayout::Coco17)
                .unwrap_err()
                .to_string();
            assert!(e.contains(needle), "{needle}: {e}");
        }
    }

    /// With two people in view a sequence follows the one it started with: the first crowded
    /// frame keeps the more confident, later frames the person nearest the one kept before, even
    /// where the other is more confident; a frame with one person keeps that one and the
    /// sequence follows it from there.
    #[test]
    fn a_sequence_follows_one_person_through_crowded_frames() {
        let d = tempfile::tempdir().unwrap();
        let person = |x: f64, c: f64| flat(25, |i| [x + i as f64, 100.0 + i as f64, c]);
        let frames = [
            vec![person(100.0, 0.9), person(500.0, 0.5)],
            vec![person(500.0, 0.95), person(104.0, 0.6)],
            vec![person(108.0, 0.4), person(502.0, 0.9)],
            vec![person(504.0, 0.8)],
            vec![person(112.0, 0.9), person(506.0, 0.3)],
        ];
        for (f, people) in frames.iter().enumerate() {
            let people: Vec<Value> = people
                .iter()
                .map(|k| serde_json::json!({"pose_keypoints_2d": k}))
                .collect();
            write(
                d.path(),
                &format!("v_{f:012}_keypoints.json"),
                &serde_json::json!({ "people": people }).to_string(),
            );
        }
        let t = read_track(&[d.path().to_path_buf()], KeypointLayout::Body25).unwrap();
        let xs: Vec<f64> = t.frames.iter().map(|f| f[0][0]).collect();
        assert_eq!(xs, [100.0, 104.0, 108.0, 504.0, 506.0]);
        assert_eq!(t.crowded_frames, 4);
    }

    #[test]
    fn coco_files_give_one_frame_per_image() {
        let d = tempfile::tempdir().unwrap();
        let k = flat(17, |i| [i as f64, 1.0, 2.0]);
        let text = serde_json::json!({
            "images": [{"id": 5, "width": 640, "height": 480}, {"id": 2}],
            "annotations": [{"image_id": 2, "keypoints": k, "num_keypoints": 17}],
            "categories": [{"id": 1, "name": "person"}]
        })
        .to_string();
        let p = write(d.path(), "c.json", &text);
        let t = read_track(&[p], KeypointLayout::Coco17).unwrap();
        assert_eq!(t.format, "coco");
        assert_eq!(t.frames.len(), 2);
        assert_eq!(t.frames[0][4], [0.0; 3]);
        assert_eq!(t.frames[1][4], [4.0, 1.0, 2.0]);
        assert_eq!(t.image_sizes[0], Some((640, 480)));
    }

    #[test]
    fn wrong_counts_and_formats_are_one_line_errors() {
        let d = tempfile::tempdir().unwrap();
        let short = flat(16, |_| [1.0, 1.0, 1.0]);
        let p = write(
            d.path(),
            "c.json",
            &serde_json::json!({"images": [{"id": 1}], "annotations": [{"image_id": 1, "keypoints": short}]}).to_string(),
        );
        let e = read_track(&[p], KeypointLayout::Coco17)
            .unwrap_err()
            .to_string();
        assert!(e.contains("48 values, expected 51"), "{e}");
        let p = write(
            d.path(),
            "o.json",
            &serde_json::json!({"people": [{"pose_keypoints_2d": flat(17, |_| [1.0, 1.0, 1.0])}]})
                .to_string(),
        );
        let e = read_track(&[p], KeypointLayout::Body25)
            .unwrap_err()
            .to_string();
        assert!(e.contains("51 values, expected 75"), "{e}");
        let p = write(d.path(), "x.json", r#"{"frames": []}"#);
        let e = read_track(&[p], KeypointLayout::Body25)
            .unwrap_err()
            .to_string();
        assert!(e.contains("neither"), "{e}");
        let p = write(d.path(), "bad.json", "{");
        assert!(
            read_track(&[p], KeypointLayout::Body25)
                .unwrap_err()
                .to_string()
                .contains("malformed JSON")
        );
        let p = write(
            d.path(),
            "nan.json",
            r#"{"images": [{"id": 1}], "annotations": [{"image_id": 3, "keypoints": []}]}"#,
        );
        let e = read_track(&[p], KeypointLayout::Coco17)
            .unwrap_err()
            .to_string();
        assert!(e.contains("image 3"), "{e}");
        let e = read_track(&[d.path().join("missing.json")], KeypointLayout::Coco17)
            .unwrap_err()
            .to_string();
        assert!(e.contains("cannot read"), "{e}");
    }

    #[test]
    fn camera_files_round_trip_and_are_checked() {
        let d = tempfile::tempdir().unwrap();
        let ring = default_ring(3);
        let p = write(d.path(), "cams.json", &cameras_json(&ring));
        assert_eq!(read_cameras(&p).unwrap(), ring);
        let p = write(d.path(), "typo.json", r#"{"cameras": [{"f": 1}]}"#);
        assert!(read_cameras(&p).is_err());
        let mut bad = ring.clone();
        bad[1].rotation[0][0] = 3.0;
        let p = write(d.path(), "rot.json", &cameras_json(&bad));
        let e = read_cameras(&p).unwrap_err().to_string();
        assert!(e.contains("rotation"), "{e}");
        let p = write(d.path(), "none.json", r#"{"cameras": []}"#);
        assert!(
            read_cameras(&p)
                .unwrap_err()
                .to_string()
                .contains("no cameras")
        );
    }

    /// The same cameras written with OpenCV's keys (`K`, `rvec` or `R`, `tvec` as a column,
    /// `resolution`, a `name`) read as lfit's own; a `dist` list gives each camera its
    /// distortion (4, 5 or 8 coefficients, flat or as one row; all zeros none); every ambiguous,
    /// missing or unmodelled entry is a one-line error naming the camera; `read_cameras` (a rig
    /// to synthesise) refuses a distortion.
    #[test]
    fn a_camera_file_takes_opencv_keys_and_a_distortion() {
        let d = tempfile::tempdir().unwrap();
        let ring = default_ring(3);
        let log = |c: &Camera| {
            let q = glam::DQuat::from_mat3(&c.rot());
            let (axis, angle) = q.to_axis_angle();
            (axis * angle).to_array()
        };
        let opencv: Vec<Value> = ring
            .iter()
            .enumerate()
            .map(|(i, c)| {
                let mut cam = serde_json::json!({
                    "name": format!("cam{i}"),
                    "K": [[c.fx, 0.0, c.cx], [0.0, c.fy, c.cy], [0.0, 0.0, 1.0]],
                    "resolution": [c.width, c.height],
                    "tvec": [[c.translation[0]], [c.translation[1]], [c.translation[2]]],
                });
                if i == 1 {
                    cam["R"] = serde_json::json!(c.rotation);
                } else {
                    cam["rvec"] = serde_json::json!(log(c));
                }
                cam
            })
            .collect();
        let mut file = serde_json::json!({ "cameras": opencv });
        file["cameras"][0]["dist"] = serde_json::json!([[-0.28, 0.07, 1e-4, -2e-4, -0.008]]);
        file["cameras"][2]["distortion"] = serde_json::json!([0.0, 0.0, 0.0, 0.0]);
        let p = write(d.path(), "opencv.json", &file.to_string());
        let CameraFileRig {
            cameras: cams,
            distortion: dists,
            ..
        } = read_camera_file(&p).unwrap();
        for (a, b) in cams.iter().zip(&ring) {
            assert_eq!(
                (a.fx, a.fy, a.cx, a.cy, a.width, a.height, a.translation),
                (b.fx, b.fy, b.cx, b.cy, b.width, b.height, b.translation)
            );
            for (x, y) in a.rotation.iter().flatten().zip(b.rotation.iter().flatten()) {
                assert!((x - y).abs() < 1e-12, "{a:?} vs {b:?}");
            }
        }
        assert_eq!(
            dists,
            [
                Some(Distortion {
                    k: [-0.28, 0.07, -0.008, 0.0, 0.0, 0.0],
                    p: [1e-4, -2e-4]
                }),
                None,
                None
            ]
        );
        let e = read_cameras(&p).unwrap_err().to_string();
        assert!(e.contains("camera 0 has a lens distortion"), "{e}");
        let one = |edit: &dyn Fn(&mut Value), needle: &str| {
            let mut f = serde_json::json!({ "cameras": [file["cameras"][1].clone()] });
            edit(&mut f["cameras"][0]);
            let p = write(d.path(), "bad.json", &f.to_string());
            let e = read_camera_file(&p).unwrap_err().to_string();
            assert!(e.contains(needle), "{needle}: {e}");
            assert!(!e.contains('\n'), "{e}");
        };
        one(
            &|c| c["fx"] = serde_json::json!(500.0),
            "intrinsics given twice",
        );
        one(
            &|c| c.as_object_mut().unwrap().retain(|k, _| k != "K"),
            "no intrinsics",
        );
        one(&|c| c["K"][0][1] = serde_json::json!(2.0), "skew");
        one(&|c| c["K"][2][2] = serde_json::json!(2.0), "K must be");
        one(
            &|c| c["width"] = serde_json::json!(640),
            "image size given twice",
        );
        one(
            &|c| c.as_object_mut().unwrap().retain(|k, _| k != "resolution"),
            "no image size",
        );
        one(
            &|c| c["rvec"] = serde_json::json!([0.1, 0.2, 0.3]),
            "rotation given twice (R, rvec)",
        );
        one(
            &|c| c.as_object_mut().unwrap().retain(|k, _| k != "R"),
            "no rotation: give rotation or R or rvec",
        );
        one(
            &|c| c["t"] = serde_json::json!([0.0, 0.0, 1.0]),
            "translation given twice (t, tvec)",
        );
        one(
            &|c| c["tvec"] = serde_json::json!([1.0, 2.0]),
            "'tvec' must be 3 numbers",
        );
        one(
            &|c| c["dist"] = serde_json::json!([0.1, 0.0, 0.0, 0.0, 0.0, 0.0]),
            "6 distortion coefficients",
        );
        one(
            &|c| c["dist"] = serde_json::json!(["a"]),
            "'dist' must be a list of numbers",
        );
        one(
            &|c| c["focal"] = serde_json::json!(1.0),
            "unknown field `focal`",
        );
        one(&|c| c["R"][0][0] = serde_json::json!(3.0), "rotation");
    }

    /// A CMU Panoptic calibration file (`calibDataSource`; per camera `name`, `type`, `panel`,
    /// `node`, `K`, `distCoef`, `R`, `t` as a column in centimetres) reads as the same cameras in
    /// metres; `units` overrides the unit of any file; cameras are chosen by name or `#K` in the
    /// order asked, and an unknown, ambiguous or repeated choice is a one-line error.
    #[test]
    fn a_panoptic_calibration_reads_in_centimetres_and_cameras_are_chosen_by_name() {
        let d = tempfile::tempdir().unwrap();
        let ring = default_ring(5);
        let kinds = ["hd", "hd", "vga", "vga", "kinect-color"];
        let names = ["00_03", "00_12", "01_01", "07_19", "50_02"];
        let list: Vec<Value> = ring
            .iter()
            .enumerate()
            .map(|(i, c)| {
                serde_json::json!({
                    "name": names[i], "type": kinds[i], "panel": i, "node": i + 1,
                    "resolution": [c.width, c.height],
                    "K": [[c.fx, 0.0, c.cx], [0.0, c.fy, c.cy], [0.0, 0.0, 1.0]],
                    "distCoef": [-0.22 + 0.01 * i as f64, 0.19, 1e-4, -3e-4, -0.03],
                    "R": c.rotation,
                    "t": c.translation.map(|x| [x * 100.0]),
                })
            })
            .collect();
        let file = serde_json::json!({ "calibDataSource": "160906_calib_norm", "cameras": list });
        let p = write(
            d.path(),
            "calibration_160906_pizza1.json",
            &file.to_string(),
        );
        let rig = read_camera_file(&p).unwrap();
        assert_eq!(rig.names, names.map(|n| Some(n.to_string())));
        for (a, b) in rig.cameras.iter().zip(&ring) {
            assert_eq!(a.rotation, b.rotation);
            assert_eq!((a.fx, a.cx, a.width), (b.fx, b.cx, b.width));
            for (x, y) in a.translation.iter().zip(&b.translation) {
                assert!((x - y).abs() < 1e-12, "{a:?} vs {b:?}");
            }
        }
        assert_eq!(
            rig.distortion[2],
            Some(Distortion {
                k: [-0.2, 0.19, -0.03, 0.0, 0.0, 0.0],
                p: [1e-4, -3e-4]
            })
        );
        // The same file declared in metres, millimetres: its numbers as that unit.
        for (unit, scale) in [("m", 100.0), ("mm", 0.1)] {
            let mut f = file.clone();
            f["units"] = serde_json::json!(unit);
            let p = write(d.path(), "units.json", &f.to_string());
            let r = read_camera_file(&p).unwrap();
            let t = r.cameras[1].translation;
            for (x, y) in t.iter().zip(&ring[1].translation) {
                assert!((x - y * scale).abs() < 1e-12, "{unit}: {t:?}");
            }
        }
        // lfit's own file without `units` is in metres, with `units: cm` in centimetres.
        let mut own: Value = serde_json::from_str(&cameras_json(&ring)).unwrap();
        assert_eq!(
            read_camera_file(&write(d.path(), "own.json", &own.to_string()))
                .unwrap()
                .cameras,
            ring
        );
        own["units"] = serde_json::json!("cm");
        let r = read_camera_file(&write(d.path(), "own-cm.json", &own.to_string())).unwrap();
        assert!((r.cameras[3].translation[2] - ring[3].translation[2] / 100.0).abs() < 1e-15);
        assert_eq!(r.names, vec![None; 5]);
        // Choosing: by name and by index, in the order asked.
        let chosen = rig
            .select(&["07_19".into(), "#0".into(), "50_02".into()])
            .unwrap();
        assert_eq!(
            chosen.names,
            [
                Some("07_19".to_string()),
                Some("00_03".into()),
                Some("50_02".into())
            ]
        );
        assert_eq!(chosen.cameras[0], rig.cameras[3]);
        assert_eq!(chosen.cameras[1], rig.cameras[0]);
        assert_eq!(chosen.distortion[2], rig.distortion[4]);
        let refused = |rig: &CameraFileRig, pick: &[&str], needle: &str| {
            let pick: Vec<String> = pick.iter().map(|s| s.to_string()).collect();
            let e = rig.select(&pick).unwrap_err().to_string();
            assert!(e.contains(needle), "{needle}: {e}");
            assert!(!e.contains('\n'), "{e}");
        };
        refused(
            &rig,
            &["00_04"],
            "no camera named '00_04' in the camera file (its 5 names: 00_03, 00_12",
        );
        refused(&rig, &["#5"], "cameras #0 to #4");
        refused(&rig, &["#x"], "cameras #0 to #4");
        refused(
            &rig,
            &["00_12", "#1"],
            "camera '#1' chosen twice (it is '00_12' too)",
        );
        refused(&rig, &[], "no camera chosen");
        refused(&r, &["00_03"], "the camera file names none (choose by #K)");
        let mut twice = rig.clone();
        twice.names[4] = Some("00_03".into());
        refused(
            &twice,
            &["00_03"],
            "cameras #0 and #4 are both named '00_03': choose by #K",
        );
        assert_eq!(
            twice.select(&["#4".into()]).unwrap().cameras,
            [rig.cameras[4].clone()]
        );
        // Bad units and names, one line each.
        for (edit, needle) in [
            (
                serde_json::json!({"units": "inch"}),
                "units 'inch': expected m, cm or mm",
            ),
            (
                serde_json::json!({"name": [1]}),
                "camera 0: 'name' must be a string",
            ),
        ] {
            let mut f = file.clone();
            let (key, value) = edit.as_object().unwrap().iter().next().unwrap();
            if key == "units" {
                f[key] = value.clone();
            } else {
                f["cameras"][0][key] = value.clone();
            }
            let p = write(d.path(), "bad.json", &f.to_string());
            let e = read_camera_file(&p).unwrap_err().to_string();
            assert!(e.contains(needle), "{needle}: {e}");
            assert!(!e.contains('\n'), "{e}");
        }
        // Synthesis refuses the file for its lenses.
        let e = read_cameras(&p).unwrap_err().to_string();
        assert!(e.contains("lens distortion"), "{e}");
    }

    /// An anipose / Pose2Sim `calibration.toml` (one table per camera: name, size as floats,
    /// matrix, four distortions, a rotation vector, translation; a `[metadata]` table) reads
    /// as the same cameras in the file's order (not sorted by name); the translations' unit is
    /// given where the file does not say it; a fisheye camera, an unknown key, a fractional size
    /// and malformed TOML are one-line errors naming the table or the line.
    #[test]
    fn an_anipose_calibration_toml_reads_in_its_order_and_unit() {
        let d = tempfile::tempdir().unwrap();
        let ring = default_ring(3);
        let names = ["cam_2", "cam_10", "cam_1"];
        let log = |c: &Camera| {
            let (axis, angle) = glam::DQuat::from_mat3(&c.rot()).to_axis_angle();
            (axis * angle).to_array()
        };
        let f = |v: &[f64]| {
            v.iter()
                .map(|x| format!("{x:?}"))
                .collect::<Vec<_>>()
                .join(", ")
        };
        let toml_of = |unit: f64, extra: &str| {
            let mut text = String::new();
            for (i, c) in ring.iter().enumerate() {
                text += &format!(
                    "[{n}]\nname = \"{n}\"\nsize = [ {w:?}, {h:?}]\nmatrix = [ [ {fx:?}, 0.0, {cx:?}], [ 0.0, {fy:?}, {cy:?}], [ 0.0, 0.0, 1.0]]\ndistortions = [ -0.05, 0.15, -0.0001, 0.0006]\nrotation = [ {r}]\ntranslation = [ {t}]\nfisheye = false\n{extra}\n",
                    n = names[i],
                    w = f64::from(c.width),
                    h = f64::from(c.height),
                    fx = c.fx,
                    cx = c.cx,
                    fy = c.fy,
                    cy = c.cy,
                    r = f(&log(c)),
                    t = f(&c.translation.map(|x| x * unit)),
                );
            }
            text + "[metadata]\nadjusted = false\nerror = 0.0\n"
        };
        let p = write(d.path(), "Calib_scene.toml", &toml_of(1.0, ""));
        let rig = read_camera_file(&p).unwrap();
        assert_eq!(rig.names, names.map(|n| Some(n.to_string())));
        let close = |a: &[Camera], scale: f64| {
            for (a, b) in a.iter().zip(&ring) {
                assert_eq!(
                    (a.fx, a.cy, a.width, a.height),
                    (b.fx, b.cy, b.width, b.height)
                );
                for (x, y) in a.rotation.iter().flatten().zip(b.rotation.iter().flatten()) {
                    assert!((x - y).abs() < 1e-12, "{a:?} vs {b:?}");
                }
                for (x, y) in a.translation.iter().zip(&b.translation) {
                    assert!((x - y * scale).abs() < 1e-12, "{a:?} vs {b:?}");
                }
            }
        };
        close(&rig.cameras, 1.0);
        assert_eq!(
            rig.distortion[1],
            Some(Distortion {
                k: [-0.05, 0.15, 0.0, 0.0, 0.0, 0.0],
                p: [-0.0001, 0.0006]
            })
        );
        // In millimetres (anipose's board unit): read as metres unless told.
        let p = write(d.path(), "calibration.toml", &toml_of(1000.0, ""));
        close(&read_camera_file(&p).unwrap().cameras, 1000.0);
        close(&read_camera_file_in(&p, Some("mm")).unwrap().cameras, 1.0);
        // A JSON file that says its unit refuses another.
        let mut own: Value = serde_json::from_str(&cameras_json(&ring)).unwrap();
        own["units"] = serde_json::json!("m");
        let pj = write(d.path(), "own.json", &own.to_string());
        assert_eq!(read_camera_file_in(&pj, Some("m")).unwrap().cameras, ring);
        let e = read_camera_file_in(&pj, Some("mm"))
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("its units are 'm', not the 'mm' asked for"),
            "{e}"
        );
        for (text, needle) in [
            (
                toml_of(1.0, "").replacen("fisheye = false", "fisheye = true", 1),
                "[cam_2] is a fisheye camera",
            ),
            (
                toml_of(1.0, "board = 3"),
                "[cam_2] has the unknown key 'board'",
            ),
            (
                toml_of(1.0, "").replacen("size = [ 640.0", "size = [ 640.5", 1),
                "[cam_2] size must be [width, height] in whole pixels",
            ),
            (
                toml_of(1.0, "").replacen("rotation = [", "rotation = [ 0.1,", 1),
                "camera 0 (cam_2): 'rvec' must be 3 numbers",
            ),
            (
                toml_of(1.0, "").replacen("matrix = [ [", "matrix = [ [ [", 1),
                "malformed TOML at line 4",
            ),
            ("cam_1 = 3\n".to_string(), "'cam_1' is not a camera table"),
            ("[metadata]\nerror = 0.0\n".to_string(), "no cameras"),
        ] {
            let p = write(d.path(), "bad.toml", &text);
            let e = read_camera_file(&p).unwrap_err().to_string();
            assert!(e.contains(needle), "{needle}: {e}");
            assert!(!e.contains('\n'), "{e}");
        }
    }

    /// Undistortion inverts OpenCV's model to 1e-9 px over the image of a wide lens (a GoPro-like
    /// barrel, and the 8-coefficient rational model), and the pixel form equals the normalised one.
    /// Each unit's corners of a 640 × 480 image land on the pixels its tool means, every name
    /// parses back to its unit, and only seen keypoints are scaled.
    #[test]
    fn keypoint_scales_map_their_corners_to_pixels() {
        let (w, h) = (640, 480);
        let cases = [
            (
                KeypointScale::Pixels,
                [(0.0, 0.0), (639.0, 479.0)],
                [(0.0, 0.0), (639.0, 479.0)],
            ),
            (
                KeypointScale::Image,
                [(0.0, 0.0), (1.0, 1.0)],
                [(0.0, 0.0), (640.0, 480.0)],
            ),
            (
                KeypointScale::OpenPose3,
                [(0.0, 0.0), (1.0, 1.0)],
                [(0.0, 0.0), (639.0, 479.0)],
            ),
            (
                KeypointScale::OpenPose4,
                [(-1.0, -1.0), (1.0, 1.0)],
                [(0.0, 0.0), (639.0, 479.0)],
            ),
        ];
        for (scale, from, to) in cases {
            for ((x, y), want) in from.into_iter().zip(to) {
                assert_eq!(scale.to_pixels(x, y, w, h), want, "{scale:?}");
            }
            assert_eq!(scale.name().parse::<KeypointScale>().expect("name"), scale);
        }
        let e = "percent".parse::<KeypointScale>().unwrap_err().to_string();
        assert!(
            e.contains("expected pixels, image, openpose3 or openpose4"),
            "{e}"
        );
        let camera = default_ring(1).remove(0);
        assert_eq!((camera.width, camera.height), (w, h));
        let mut track = KeypointTrack {
            format: "openpose",
            frames: vec![vec![[0.5, 0.5, 0.9], [0.5, 0.5, 0.0]]],
            sources: vec!["f".into()],
            image_sizes: vec![None],
            crowded_frames: 0,
        };
        scale_track(&mut track, &camera, KeypointScale::Image);
        assert_eq!(track.frames[0], vec![[320.0, 240.0, 0.9], [0.5, 0.5, 0.0]]);
    }

    #[test]
    fn undistortion_inverts_the_lens_model() {
        let cam = default_ring(1)[0];
        let models = [
            Distortion::from_opencv(&[-0.28, 0.07, 1e-4, -2e-4, -0.008])
                .unwrap()
                .unwrap(),
            Distortion::from_opencv(&[0.5, -0.2, 3e-4, 1e-4, 0.01, 0.6, -0.1, 0.02])
                .unwrap()
                .unwrap(),
        ];
        assert_eq!(Distortion::from_opencv(&[0.0; 5]).unwrap(), None);
        for d in models {
            for i in 0..=10 {
                for j in 0..=10 {
                    let (u, v) = (
                        f64::from(cam.width) * f64::from(i) / 10.0,
                        f64::from(cam.height) * f64::from(j) / 10.0,
                    );
                    let (x, y) = ((u - cam.cx) / cam.fx, (v - cam.cy) / cam.fy);
                    let (xd, yd) = d.distort(x, y);
                    let (ud, vd) = (cam.fx * xd + cam.cx, cam.fy * yd + cam.cy);
                    let Some((uu, vu)) = d.undistort_pixel(&cam, ud, vd) else {
                        panic!("{d:?} at ({u}, {v}) r {}", x.hypot(y))
                    };
                    assert!(
                        (uu - u).abs() < 1e-9 && (vu - v).abs() < 1e-9,
                        "{d:?} at ({u}, {v}): ({uu}, {vu})"
                    );
                }
            }
            // The model bends: a distorted point is not where the pinhole puts it.
            let (xd, _) = d.distort(0.4, 0.3);
            assert!((xd - 0.4).abs() > 1e-3);
        }
        // A track: seen keypoints undistorted, unseen ones (confidence 0) left as they are.
        let d = models[0];
        let (xd, yd) = d.distort(0.2, -0.1);
        let mut t = KeypointTrack {
            format: "openpose",
            frames: vec![vec![
                [cam.fx * xd + cam.cx, cam.fy * yd + cam.cy, 0.8],
                [7.0, 9.0, 0.0],
            ]],
            sources: vec!["f".into()],
            image_sizes: vec![None],
            crowded_frames: 0,
        };
        undistort_track(&mut t, &cam, &d).unwrap();
        let p = t.frames[0][0];
        assert!(
            (p[0] - (cam.fx * 0.2 + cam.cx)).abs() < 1e-9
                && (p[1] - (cam.fy * -0.1 + cam.cy)).abs() < 1e-9
        );
        assert_eq!(t.frames[0][1], [7.0, 9.0, 0.0]);
        // Past the fold of a strong barrel (x (1 − r²) peaks at r = 1/√3, x_d ≈ 0.385) nothing
        // maps there: a one-line error naming the keypoint's frame.
        let fold = Distortion::from_opencv(&[-1.0, 0.0, 0.0, 0.0])
            .unwrap()
            .unwrap();
        assert!(fold.undistort(0.5, 0.0).is_none());
        t.frames[0][0] = [cam.fx * 0.5 + cam.cx, cam.cy, 0.9];
        let e = undistort_track(&mut t, &cam, &fold)
            .unwrap_err()
            .to_string();
        assert!(
            e.starts_with("f: keypoint at") && e.contains("does not invert"),
            "{e}"
        );
    }
}
