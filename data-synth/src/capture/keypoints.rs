//! 2D keypoint files and camera files for `lfit data import`.
//!
//! Two documented keypoint formats are read, told apart by their content:
//! - **OpenPose** (`--write_json`): one file per frame, `{"people": [{"pose_keypoints_2d": [x0,
//!   y0, c0, x1, y1, c1, ...], ...}, ...]}` with `3K` numbers per person (K = 25 for BODY_25,
//!   17 for a COCO-17 model). A frame with several people keeps the one with the largest summed
//!   confidence; a frame with nobody has no visible keypoint.
//! - **COCO keypoints** (the `person_keypoints_*.json` layout): `{"images": [{"id", "width",
//!   "height", ...}], "annotations": [{"image_id", "keypoints": [x, y, v, ...], "score"?}]}`, one
//!   frame per entry of `images`, in their listed order. An image with several annotations keeps
//!   the one with the highest `score` (else the largest summed `v`); one without any has no
//!   visible keypoint. COCO's visibility flag v (0 unlabelled, 1 occluded, 2 visible) stands for
//!   the confidence.
//!
//! A keypoint counts as seen when its confidence exceeds the chosen threshold. Pixel coordinates
//! are taken as they are, in the camera file's image frame (x right, y down).
//!
//! The camera file is JSON, `{"cameras": [{"fx", "fy", "cx", "cy", "width", "height",
//! "rotation": [[3], [3], [3]], "translation": [3]}, ...]}`: pinhole intrinsics in pixels and
//! the camera-from-world rotation (row-major) and translation in metres, OpenCV axes (+z into the
//! scene, +y down) — exactly the cameras a `keypoints2d` dataset stores. Unknown keys are refused.

use std::path::{Path, PathBuf};

use lfit_model::camera::Camera;
use lfit_model::skeleton;
use serde::Deserialize;
use serde_json::Value;

use crate::capture::ImportError;

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

impl std::str::FromStr for KeypointLayout {
    type Err = ImportError;
    fn from_str(s: &str) -> Result<Self, ImportError> {
        match s {
            "coco17" => Ok(Self::Coco17),
            "body25" => Ok(Self::Body25),
            other => fail(format!(
                "unknown keypoint layout '{other}' (expected coco17 or body25)"
            )),
        }
    }
}

impl KeypointLayout {
    pub fn name(self) -> &'static str {
        match self {
            Self::Coco17 => "coco17",
            Self::Body25 => "body25",
        }
    }

    /// Keypoint names, in the detector's order.
    pub fn names(self) -> &'static [&'static str] {
        match self {
            Self::Coco17 => &COCO17,
            Self::Body25 => &BODY25,
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
    /// wrists (the papers/000 hands); BODY_25 also gives the root (MidHip) and the head joint
    /// (Neck: papers/000's head joint sits at the base of the neck). Face and foot keypoints are
    /// left out (no joint centre there); `--keypoint-map` chooses others.
    pub fn default_map(self) -> Vec<(usize, &'static str)> {
        use skeleton::*;
        match self {
            Self::Coco17 => vec![
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
            Self::Body25 => vec![
                (ROOT, "MidHip"),
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
            ],
        }
    }
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

/// Reads one OpenPose frame file.
fn openpose_frame(
    v: &Value,
    layout: KeypointLayout,
    name: &str,
) -> Result<(Vec<[f64; 3]>, usize), ImportError> {
    let Some(people) = v.get("people").and_then(Value::as_array) else {
        return fail(format!("{name}: \"people\" is not an array"));
    };
    let mut best: Option<Vec<[f64; 3]>> = None;
    for (i, p) in people.iter().enumerate() {
        let Some(kp) = p.get("pose_keypoints_2d") else {
            return fail(format!("{name}: people[{i}] has no \"pose_keypoints_2d\""));
        };
        let t = triples(
            kp,
            layout,
            &format!("{name}: people[{i}].pose_keypoints_2d"),
        )?;
        if best
            .as_ref()
            .is_none_or(|b| confidence_sum(&t) > confidence_sum(b))
        {
            best = Some(t);
        }
    }
    Ok((
        best.unwrap_or_else(|| vec![[0.0; 3]; layout.count()]),
        people.len(),
    ))
}

/// Reads a COCO keypoint file: one frame per image.
fn coco_track(v: &Value, layout: KeypointLayout, name: &str) -> Result<KeypointTrack, ImportError> {
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
    let mut best: Vec<Option<(f64, Vec<[f64; 3]>)>> = vec![None; ids.len()];
    let mut count = vec![0usize; ids.len()];
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
        count[frame] += 1;
        if best[frame].as_ref().is_none_or(|(r, _)| rank > *r) {
            best[frame] = Some((rank, t));
        }
    }
    Ok(KeypointTrack {
        format: "coco",
        frames: best
            .into_iter()
            .map(|b| b.map_or_else(|| vec![[0.0; 3]; layout.count()], |(_, t)| t))
            .collect(),
        sources: ids.iter().map(|id| format!("{name}#{id}")).collect(),
        image_sizes: sizes,
        crowded_frames: count.iter().filter(|&&c| c > 1).count(),
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
    let mut track = KeypointTrack {
        format: "",
        frames: Vec::new(),
        sources: Vec::new(),
        image_sizes: Vec::new(),
        crowded_frames: 0,
    };
    for f in &files {
        let v = read_json(f)?;
        let name = f.display().to_string();
        let format = if v.get("people").is_some() {
            "openpose"
        } else if v.get("annotations").is_some() {
            "coco"
        } else {
            return fail(format!(
                "{name}: neither an OpenPose frame (\"people\") nor a COCO keypoint file (\"annotations\")"
            ));
        };
        if !track.format.is_empty() && track.format != format {
            return fail(format!(
                "{name} is a {format} file but the files before it are {}",
                track.format
            ));
        }
        track.format = format;
        if format == "openpose" {
            let (t, people) = openpose_frame(&v, layout, &name)?;
            track.frames.push(t);
            track.sources.push(name);
            track.image_sizes.push(None);
            track.crowded_frames += usize::from(people > 1);
        } else {
            let c = coco_track(&v, layout, &name)?;
            track.frames.extend(c.frames);
            track.sources.extend(c.sources);
            track.image_sizes.extend(c.image_sizes);
            track.crowded_frames += c.crowded_frames;
        }
    }
    if track.frames.is_empty() {
        return fail("the keypoint files hold no frame");
    }
    Ok(track)
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct CameraJson {
    fx: f64,
    fy: f64,
    cx: f64,
    cy: f64,
    width: u32,
    height: u32,
    rotation: [[f64; 3]; 3],
    translation: [f64; 3],
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct CameraFile {
    cameras: Vec<CameraJson>,
}

/// Reads and checks a camera file (see the module documentation).
pub fn read_cameras(path: &Path) -> Result<Vec<Camera>, ImportError> {
    let text = std::fs::read_to_string(path).map_err(|source| ImportError::Read {
        path: path.to_path_buf(),
        source,
    })?;
    let file: CameraFile = serde_json::from_str(&text)
        .map_err(|e| ImportError::Invalid(format!("camera file {}: {e}", path.display())))?;
    if file.cameras.is_empty() {
        return fail(format!("camera file {}: no cameras", path.display()));
    }
    let cams: Vec<Camera> = file
        .cameras
        .into_iter()
        .map(|c| Camera {
            fx: c.fx,
            fy: c.fy,
            cx: c.cx,
            cy: c.cy,
            width: c.width,
            height: c.height,
            rotation: c.rotation,
            translation: c.translation,
        })
        .collect();
    for (i, c) in cams.iter().enumerate() {
        c.validate(i)
            .map_err(|e| ImportError::Invalid(format!("camera file {}: {e}", path.display())))?;
    }
    Ok(cams)
}

/// The JSON text of a camera file for `cameras` (the format [`read_cameras`] reads).
pub fn cameras_json(cameras: &[Camera]) -> String {
    let list: Vec<Value> = cameras
        .iter()
        .map(|c| {
            serde_json::json!({
                "fx": c.fx, "fy": c.fy, "cx": c.cx, "cy": c.cy,
                "width": c.width, "height": c.height,
                "rotation": c.rotation, "translation": c.translation,
            })
        })
        .collect();
    serde_json::json!({ "cameras": list }).to_string()
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
}
