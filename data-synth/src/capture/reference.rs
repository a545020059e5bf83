//! A captured 3D reference of the joints (`lfit data import --reference`): what a capture
//! studio's own reconstruction says each frame's joints were, so that a fit of the same frames'
//! 2D keypoints can be scored in millimetres where no ground truth exists.
//!
//! Read: CMU Panoptic's 3D skeletons (`hdPose3d_stage1_coco19/body3DScene_XXXXXXXX.json`, one
//! file per HD frame: `{"bodies": [{"id", "joints19": [x, y, z, confidence] × 19}]}`, in
//! centimetres in the calibration's world; the layout and the unit as the panoptic-toolbox
//! README documents them), and 3D keypoints in a TRC or C3D file (Pose2Sim's triangulation,
//! OpenCap's, any tool's) whose labels name a keypoint layout's points
//! ([`read_point_reference`]). The reference's keypoints are mapped onto the model's joints by
//! the layout's default map ([`KeypointLayout::default_map`]), turned into lfit's Y-up world
//! with the cameras ([`attach_reference`]) and stored with the dataset ([`JointReference`]).

use std::path::{Path, PathBuf};

use glam::{DMat3, DVec3};
use lfit_model::template::Template;
use serde_json::{Value, json};

use super::ImportError;
use super::c3d::C3d;
use super::import::{Imported, layout_pairs};
use super::keypoints::KeypointLayout;
use crate::dataset::JointReference;

fn fail<T>(msg: impl Into<String>) -> Result<T, ImportError> {
    Err(ImportError::Invalid(msg.into()))
}

/// A reference's keypoints over time, in the file's world.
#[derive(Debug, Clone, PartialEq)]
pub struct ReferenceTrack {
    /// `panoptic`, `trc` or `c3d`.
    pub format: &'static str,
    /// The layout its keypoints are (`None`: a point file read with a map, its labels as they
    /// are).
    pub layout: Option<KeypointLayout>,
    /// The name of each keypoint, in the frames' order.
    pub names: Vec<String>,
    /// Per frame, per keypoint: `[x, y, z]` in metres and a confidence (all zero in a frame
    /// without the chosen body).
    pub frames: Vec<Vec<[f64; 4]>>,
    /// Per frame, the file it came from.
    pub sources: Vec<String>,
    /// The body kept (its `id`): the one chosen, or the one id of every frame's single body
    /// (`None` when those ids differ — Panoptic may give one person several ids over time).
    pub person: Option<i64>,
    /// Frames that hold no body (or not the chosen one).
    pub empty_frames: usize,
}

/// The JSON files of `paths` (each a file, or a folder whose `.json` files are taken in name
/// order: Panoptic's zero-padded frame numbers).
fn json_files(paths: &[PathBuf]) -> Result<Vec<PathBuf>, ImportError> {
    let mut files = Vec::new();
    for path in paths {
        if path.is_dir() {
            let entries = std::fs::read_dir(path).map_err(|source| ImportError::Read {
                path: path.clone(),
                source,
            })?;
            let mut found: Vec<PathBuf> = entries
                .filter_map(|e| e.ok().map(|e| e.path()))
                .filter(|p| p.is_file() && p.extension().is_some_and(|x| x == "json"))
                .collect();
            if found.is_empty() {
                return fail(format!(
                    "{}: the folder holds no .json file",
                    path.display()
                ));
            }
            found.sort();
            files.extend(found);
        } else {
            files.push(path.clone());
        }
    }
    if files.is_empty() {
        return fail("--reference needs a file or a folder of files");
    }
    Ok(files)
}

/// One body of a Panoptic frame: its id and its 19 keypoints (metres, confidence).
fn panoptic_body(body: &Value, file: &str) -> Result<(i64, Vec<[f64; 4]>), ImportError> {
    let id = body.get("id").and_then(Value::as_i64).unwrap_or(-1);
    let Some(joints) = body.get("joints19").and_then(Value::as_array) else {
        return fail(format!("{file}: body {id} has no \"joints19\" array"));
    };
    let count = KeypointLayout::Panoptic19.count();
    if joints.len() != 4 * count {
        return fail(format!(
            "{file}: body {id}: \"joints19\" has {} values, expected {} (19 joints × x, y, z, confidence)",
            joints.len(),
            4 * count
        ));
    }
    let mut out = Vec::with_capacity(count);
    for (k, j) in joints.chunks_exact(4).enumerate() {
        let mut p = [0.0; 4];
        for (i, v) in j.iter().enumerate() {
            match v.as_f64().filter(|x| x.is_finite()) {
                // Centimetres, as the toolbox documents; the confidence as it is.
                Some(x) => p[i] = if i < 3 { x * 0.01 } else { x },
                None => {
                    return fail(format!(
                        "{file}: body {id}: keypoint {k} ({}) holds {v}, not a finite number",
                        KeypointLayout::Panoptic19.names()[k]
                    ));
                }
            }
        }
        out.push(p);
    }
    Ok((id, out))
}

/// Reads CMU Panoptic 3D skeleton files (`body3DScene_*.json`, or folders of them) as one frame
/// each. `person`: the body `id` to keep; without it, every frame must hold at most one body.
pub fn read_panoptic_skeletons(
    paths: &[PathBuf],
    person: Option<i64>,
) -> Result<ReferenceTrack, ImportError> {
    let files = json_files(paths)?;
    let count = KeypointLayout::Panoptic19.count();
    let mut frames = Vec::with_capacity(files.len());
    let mut sources = Vec::with_capacity(files.len());
    let mut ids_seen: Vec<i64> = Vec::new();
    // The ids of the bodies kept, each once.
    let mut kept_ids: Vec<i64> = Vec::new();
    let mut empty = 0;
    for file in &files {
        let name = file.display().to_string();
        let text = std::fs::read_to_string(file).map_err(|source| ImportError::Read {
            path: file.clone(),
            source,
        })?;
        let doc: Value = serde_json::from_str(&text)
            .map_err(|e| ImportError::Invalid(format!("{name}: not JSON ({e})")))?;
        let Some(bodies) = doc.get("bodies").and_then(Value::as_array) else {
            return fail(format!(
                "{name}: no \"bodies\" array (not a Panoptic body3DScene file)"
            ));
        };
        let bodies = bodies
            .iter()
            .map(|b| panoptic_body(b, &name))
            .collect::<Result<Vec<_>, _>>()?;
        for (id, _) in &bodies {
            if !ids_seen.contains(id) {
                ids_seen.push(*id);
            }
        }
        let kept = match person {
            Some(want) => bodies.into_iter().find(|(id, _)| *id == want),
            None => {
                if bodies.len() > 1 {
                    let ids: Vec<String> = bodies.iter().map(|b| b.0.to_string()).collect();
                    return fail(format!(
                        "{name}: {} bodies (ids {}): choose one with --reference-person ID",
                        bodies.len(),
                        ids.join(", ")
                    ));
                }
                bodies.into_iter().next()
            }
        };
        match kept {
            Some((id, points)) => {
                if !kept_ids.contains(&id) {
                    kept_ids.push(id);
                }
                frames.push(points);
            }
            None => {
                empty += 1;
                frames.push(vec![[0.0; 4]; count]);
            }
        }
        sources.push(
            file.file_name()
                .map_or(name.clone(), |n| n.to_string_lossy().into()),
        );
    }
    if let Some(want) = person
        && !ids_seen.contains(&want)
    {
        ids_seen.sort_unstable();
        let ids: Vec<String> = ids_seen.iter().map(i64::to_string).collect();
        return fail(format!(
            "--reference-person {want}: no body has that id (the files' ids: {})",
            if ids.is_empty() {
                "none".to_string()
            } else {
                ids.join(", ")
            }
        ));
    }
    if empty == frames.len() {
        return fail("the reference files hold no body in any frame");
    }
    Ok(ReferenceTrack {
        format: "panoptic",
        layout: Some(KeypointLayout::Panoptic19),
        names: KeypointLayout::Panoptic19
            .names()
            .iter()
            .map(|n| n.to_string())
            .collect(),
        frames,
        sources,
        person: person.or(match kept_ids[..] {
            [one] => Some(one),
            _ => None,
        }),
        empty_frames: empty,
    })
}

/// A keypoint name as the tools spell it apart: lower case, `left`/`right` as `l`/`r`, without
/// `_`, `-`, `.` or spaces — `right_hip` (COCO), `RHip` (OpenPose, Pose2Sim) and `rHip`
/// (Panoptic) are all `rhip`.
fn plain_name(name: &str) -> String {
    let lower: String = name
        .chars()
        .filter(|c| !matches!(c, '_' | '-' | '.' | ' '))
        .flat_map(char::to_lowercase)
        .collect();
    for (long, short) in [("left", "l"), ("right", "r")] {
        if let Some(rest) = lower.strip_prefix(long) {
            return format!("{short}{rest}");
        }
    }
    lower
}

/// Reads 3D keypoints from a TRC or C3D file (by its extension) as a reference in `layout`:
/// each point whose label is one of the layout's keypoint names (as [`plain_name`] compares
/// them; a label after one `SUBJECT:` prefix too) is that keypoint, in the file's unit and
/// world; a gap is a frame without it. No confidence: every sample is held (1). Without a
/// layout every point is a keypoint under its label (after one prefix), for a map to name.
pub fn read_point_reference(
    path: &Path,
    layout: Option<KeypointLayout>,
) -> Result<ReferenceTrack, ImportError> {
    let ext = path
        .extension()
        .map(|e| e.to_string_lossy().to_lowercase())
        .unwrap_or_default();
    let (points, format): (C3d, &'static str) = match ext.as_str() {
        "trc" => (super::trc::read_trc(path)?, "trc"),
        "c3d" => (C3d::read(path)?, "c3d"),
        _ => {
            return fail(format!(
                "{}: a reference is Panoptic's .json files (or their folder), a .trc or a .c3d file",
                path.display()
            ));
        }
    };
    let scale = points.metres_per_unit()?;
    let bare = |label: &str| label.rsplit(':').next().unwrap_or(label).trim().to_string();
    let Some(layout) = layout else {
        let names: Vec<String> = points.labels.iter().map(|l| bare(l)).collect();
        let column: Vec<Option<usize>> = (0..names.len()).map(Some).collect();
        return Ok(point_track(
            &points, format, None, names, &column, scale, path,
        ));
    };
    let names = layout.names();
    // Keypoint k ← the file's point that names it (one per keypoint).
    let mut column: Vec<Option<usize>> = vec![None; names.len()];
    for (i, label) in points.labels.iter().enumerate() {
        let plain = plain_name(&bare(label));
        if let Some(k) = names.iter().position(|n| plain_name(n) == plain) {
            if let Some(j) = column[k] {
                return fail(format!(
                    "{}: labels '{}' and '{label}' both name the {} keypoint {}",
                    path.display(),
                    points.labels[j],
                    layout.name(),
                    names[k]
                ));
            }
            column[k] = Some(i);
        }
    }
    if column.iter().all(Option::is_none) {
        let labels: Vec<&str> = points.labels.iter().take(8).map(String::as_str).collect();
        return fail(format!(
            "{}: none of its labels ({}{}) names a {} keypoint ({}): choose the layout with --reference-layout",
            path.display(),
            labels.join(", "),
            if points.labels.len() > 8 { ", …" } else { "" },
            layout.name(),
            names.iter().take(8).copied().collect::<Vec<_>>().join(", ")
        ));
    }
    let names = names.iter().map(|n| n.to_string()).collect();
    Ok(point_track(
        &points,
        format,
        Some(layout),
        names,
        &column,
        scale,
        path,
    ))
}

/// The track of a point file's `column`s (keypoint k ← point `column[k]`), in metres.
fn point_track(
    points: &C3d,
    format: &'static str,
    layout: Option<KeypointLayout>,
    names: Vec<String>,
    column: &[Option<usize>],
    scale: f64,
    path: &Path,
) -> ReferenceTrack {
    let frames: Vec<Vec<[f64; 4]>> = points
        .frames
        .iter()
        .map(|row| {
            column
                .iter()
                .map(|c| match c.and_then(|i| row[i]) {
                    Some(p) => [
                        p.position[0] * scale,
                        p.position[1] * scale,
                        p.position[2] * scale,
                        1.0,
                    ],
                    None => [0.0; 4],
                })
                .collect()
        })
        .collect();
    let empty_frames = frames
        .iter()
        .filter(|f| f.iter().all(|p| p[3] == 0.0))
        .count();
    let sources = (0..frames.len())
        .map(|f| format!("{}#{f}", path.display()))
        .collect();
    ReferenceTrack {
        format,
        layout,
        names,
        frames,
        sources,
        person: None,
        empty_frames,
    }
}

/// Reads the reference `paths` name: one `.trc` or `.c3d` file ([`read_point_reference`], in
/// `layout`), else CMU Panoptic skeleton files or folders ([`read_panoptic_skeletons`], whose
/// layout is `panoptic19`: another `layout` is refused). `person` chooses a Panoptic body; a
/// point file holds one subject (refused with it). `mapped`: a map will name the keypoints
/// ([`attach_reference`]), so a point file is read with every label (not with a given layout).
pub fn read_reference(
    paths: &[PathBuf],
    layout: KeypointLayout,
    layout_given: bool,
    person: Option<i64>,
    mapped: bool,
) -> Result<ReferenceTrack, ImportError> {
    let point_file = |p: &PathBuf| {
        p.is_file()
            && p.extension()
                .is_some_and(|e| e.eq_ignore_ascii_case("trc") || e.eq_ignore_ascii_case("c3d"))
    };
    match paths {
        [one] if point_file(one) => {
            if person.is_some() {
                return fail(
                    "--reference-person chooses a body of Panoptic's files; a TRC or C3D reference holds one subject",
                );
            }
            if mapped && layout_given {
                return fail(
                    "--reference-map names the file's points: give it or --reference-layout, not both",
                );
            }
            read_point_reference(one, (!mapped).then_some(layout))
        }
        _ if paths.iter().any(point_file) => {
            fail("give one TRC or C3D file as the reference (or Panoptic's .json files)")
        }
        _ => {
            if layout_given && layout != KeypointLayout::Panoptic19 {
                return fail(format!(
                    "Panoptic's skeletons are in the panoptic19 layout, not {}",
                    layout.name()
                ));
            }
            read_panoptic_skeletons(paths, person)
        }
    }
}

/// `(model joint, keypoint)` pairs of a reference map `{"model joint": "reference point"}`
/// against the reference's keypoint `names` (compared as [`plain_name`] does).
fn named_pairs(
    map: &[(String, String)],
    names: &[String],
    template: &Template,
) -> Result<Vec<(usize, usize)>, ImportError> {
    map.iter()
        .map(|(joint, point)| {
            let Some(j) = template.rig.joint_index(joint) else {
                return fail(format!(
                    "reference map: '{joint}' is not a joint of model '{}'",
                    template.id
                ));
            };
            let plain = plain_name(point);
            let Some(k) = names.iter().position(|n| plain_name(n) == plain) else {
                let some: Vec<&str> = names.iter().take(12).map(String::as_str).collect();
                return fail(format!(
                    "reference map: '{point}' is not a point of the reference (its points: {}{})",
                    some.join(", "),
                    if names.len() > 12 { ", …" } else { "" }
                ));
            };
            Ok((j, k))
        })
        .collect()
}

/// Maps `track` onto the model's joints and stores it with `imported`'s dataset: each mapped
/// keypoint seen with a confidence above `min_confidence` is the joint's reference, turned by
/// `to_lfit` (the rotation the cameras were turned by: `--up`). One reference frame per
/// imported frame, in order. Adds `"reference"` to the import's report: the mapping, how much
/// of it was seen, and the median over frames of the mean distance from each frame's start pose
/// to the reference (a world or unit that does not match the cameras' shows there in metres).
pub fn attach_reference(
    imported: &mut Imported,
    track: &ReferenceTrack,
    source: &Path,
    template: &Template,
    to_lfit: DMat3,
    min_confidence: f64,
    map: Option<&[(String, String)]>,
) -> Result<(), ImportError> {
    let n = imported.dataset.len();
    if track.frames.len() != n {
        return fail(format!(
            "{}: the reference has {} frames, the keypoints {n}: give one reference frame per keypoint frame, in the same order",
            source.display(),
            track.frames.len()
        ));
    }
    // The map's pairs, or the layout's default ones, whose keypoint the reference holds in
    // some frame.
    let pairs = match (map, track.layout) {
        (Some(map), _) => named_pairs(map, &track.names, template)?,
        (None, Some(layout)) => layout_pairs(layout, None, template)?,
        (None, None) => return fail("a reference read without a layout needs --reference-map"),
    };
    let pairs: Vec<(usize, usize)> = pairs
        .into_iter()
        .filter(|&(_, k)| track.frames.iter().any(|f| f[k][3] > min_confidence))
        .collect();
    let nj = template.rig.num_joints();
    let mut points = vec![vec![[0.0; 3]; nj]; n];
    let mut visible = vec![vec![false; nj]; n];
    for (f, frame) in track.frames.iter().enumerate() {
        for &(j, k) in &pairs {
            let p = frame[k];
            if p[3] > min_confidence {
                points[f][j] = (to_lfit * DVec3::new(p[0], p[1], p[2])).to_array();
                visible[f][j] = true;
            }
        }
    }
    let seen: usize = visible.iter().flatten().filter(|&&v| v).count();
    if seen == 0 {
        return fail(format!(
            "{}: no mapped reference keypoint has a confidence above {min_confidence}",
            source.display()
        ));
    }
    let reference = JointReference { points, visible };
    // How far each frame's start lies from the reference: metres off in a matched world, the
    // size of a unit or axis mistake otherwise.
    let mut distances: Vec<f64> = (0..n)
        .filter_map(|f| {
            reference
                .errors(template, f, &imported.dataset.start_poses[f])
                .map(|e| e.mpjpe_mm / 1000.0)
        })
        .collect();
    distances.sort_by(f64::total_cmp);
    let median = distances.get(distances.len() / 2).copied();
    let names = &track.names;
    let map_given = map.is_some();
    let map: Vec<String> = pairs
        .iter()
        .map(|&(j, k)| format!("{}→{}", names[k], template.rig.joints[j].name))
        .collect();
    imported.report["reference"] = json!({
        "format": track.format,
        "layout": track.layout.map(KeypointLayout::name),
        "reference_map": map_given,
        "frames": n,
        "person": track.person,
        "empty_frames": track.empty_frames,
        "mapped_joints": pairs.len(),
        "map": map,
        "min_confidence": min_confidence,
        "seen_fraction": seen as f64 / (n * pairs.len()).max(1) as f64,
        "start_distance_m": median,
    });
    imported.dataset.reference = Some(reference);
    Ok(())
}

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod tests {
    use super::*;

    /// One body's `joints19`: keypoint k at (k, 2k, −k) cm with confidence 0.5.
    fn body(id: i64) -> Value {
        let flat: Vec<f64> = (0..19)
            .flat_map(|k| [k as f64, 2.0 * k as f64, -(k as f64), 0.5])
            .collect();
        json!({"id": id, "joints19": flat})
    }

    fn write(dir: &Path, name: &str, doc: &Value) -> PathBuf {
        let p = dir.join(name);
        std::fs::write(&p, doc.to_string()).unwrap();
        p
    }

    #[test]
    fn the_tools_spellings_of_a_keypoint_compare_equal() {
        for (a, b) in [
            ("right_hip", "RHip"),
            ("rHip", "RHip"),
            ("left_small_toe", "LSmallToe"),
            ("Mid-Hip", "midhip"),
        ] {
            assert_eq!(plain_name(a), plain_name(b), "{a} {b}");
        }
        assert_ne!(plain_name("right_hip"), plain_name("LHip"));
        assert_ne!(plain_name("MidHip"), plain_name("Hip"));
    }

    /// A TRC of keypoints named as Pose2Sim names them (and one after a subject's prefix), in
    /// millimetres: the COCO-17 keypoints they name, in metres; a gap and an unnamed keypoint
    /// not held; labels that name nothing, or one keypoint twice, refused.
    #[test]
    fn a_trc_reference_reads_its_labels_as_a_layouts_keypoints() {
        use crate::capture::c3d::{C3dPoint, Processor};
        let d = tempfile::tempdir().unwrap();
        let point = |x: f64| {
            Some(C3dPoint {
                position: [x, 2.0 * x, -x],
                residual: 0.0,
                cameras: 0,
            })
        };
        let file = |labels: &[&str], name: &str| {
            let c3d = C3d {
                processor: Processor::Intel,
                labels: labels.iter().map(|l| l.to_string()).collect(),
                units: "mm".into(),
                scale: -1.0,
                rate: 30.0,
                first_frame: 1,
                analog_per_frame: 0,
                frames: vec![
                    vec![point(100.0), point(200.0), point(300.0)],
                    vec![point(110.0), None, point(310.0)],
                ],
                non_finite: 0,
            };
            let p = d.path().join(name);
            std::fs::write(&p, crate::capture::trc::to_trc(&c3d, name)).unwrap();
            p
        };
        let p = file(&["RHip", "S1:LKnee", "Extra"], "ok.trc");
        let t = read_point_reference(&p, Some(KeypointLayout::Coco17)).unwrap();
        assert_eq!((t.format, t.frames.len(), t.empty_frames), ("trc", 2, 0));
        let at = |name| KeypointLayout::Coco17.index(name).unwrap();
        assert_eq!(t.frames[0][at("right_hip")], [0.1, 0.2, -0.1, 1.0]);
        assert_eq!(t.frames[1][at("left_knee")], [0.0; 4]);
        assert_eq!(t.frames[0][at("left_knee")], [0.2, 0.4, -0.2, 1.0]);
        assert_eq!(t.frames[0][at("nose")], [0.0; 4]);
        let e = read_point_reference(
            &file(&["RHip", "right_hip", "X"], "twice.trc"),
            Some(KeypointLayout::Coco17),
        )
        .unwrap_err()
        .to_string();
        assert!(e.contains("'RHip' and 'right_hip' both name"), "{e}");
        let e = read_point_reference(
            &file(&["A", "B", "C"], "none.trc"),
            Some(KeypointLayout::Coco17),
        )
        .unwrap_err()
        .to_string();
        assert!(
            e.contains("(A, B, C)") && e.contains("--reference-layout"),
            "{e}"
        );
        // Through read_reference: no person for a point file, no other layout for Panoptic's.
        let e = read_reference(
            std::slice::from_ref(&p),
            KeypointLayout::Coco17,
            false,
            Some(1),
            false,
        )
        .unwrap_err()
        .to_string();
        assert!(e.contains("holds one subject"), "{e}");
        let t = read_reference(
            std::slice::from_ref(&p),
            KeypointLayout::Body25,
            true,
            None,
            false,
        )
        .unwrap();
        assert_eq!(
            t.frames[0][KeypointLayout::Body25.index("RHip").unwrap()][3],
            1.0
        );
        let json = write(d.path(), "f.json", &json!({"bodies": [body(0)]}));
        let e = read_reference(
            std::slice::from_ref(&json),
            KeypointLayout::Coco17,
            true,
            None,
            false,
        )
        .unwrap_err()
        .to_string();
        assert!(e.contains("panoptic19 layout, not coco17"), "{e}");
        assert!(
            read_reference(
                std::slice::from_ref(&json),
                KeypointLayout::Coco17,
                false,
                None,
                false
            )
            .is_ok()
        );
        let e = read_reference(
            &[p.clone(), p.clone()],
            KeypointLayout::Coco17,
            false,
            None,
            false,
        )
        .unwrap_err()
        .to_string();
        assert!(e.contains("one TRC or C3D file"), "{e}");
        // For a map: every label under its name (the prefix dropped), the layout not given.
        let t = read_reference(
            std::slice::from_ref(&p),
            KeypointLayout::Coco17,
            false,
            None,
            true,
        )
        .unwrap();
        assert_eq!(
            (t.layout, t.names.clone()),
            (
                None,
                vec!["RHip".to_string(), "LKnee".into(), "Extra".into()]
            )
        );
        assert_eq!(t.frames[0][2], [0.3, 0.6, -0.3, 1.0]);
        let e = read_reference(&[p], KeypointLayout::Body25, true, None, true)
            .unwrap_err()
            .to_string();
        assert!(e.contains("not both"), "{e}");
    }

    #[test]
    fn panoptic_frames_read_in_name_order_in_metres_with_empty_frames() {
        let d = tempfile::tempdir().unwrap();
        // Written out of order; a file that is not JSON by extension is not a frame.
        write(
            d.path(),
            "body3DScene_00000002.json",
            &json!({"bodies": [body(4)]}),
        );
        write(
            d.path(),
            "body3DScene_00000000.json",
            &json!({"bodies": [body(4)]}),
        );
        write(
            d.path(),
            "body3DScene_00000001.json",
            &json!({"bodies": []}),
        );
        write(d.path(), "notes.txt", &json!("not a frame"));
        let t = read_panoptic_skeletons(&[d.path().to_path_buf()], None).unwrap();
        assert_eq!(t.sources[0], "body3DScene_00000000.json");
        assert_eq!(t.sources[2], "body3DScene_00000002.json");
        assert_eq!((t.frames.len(), t.empty_frames, t.person), (3, 1, Some(4)));
        let wrist = KeypointLayout::Panoptic19.index("lWrist").unwrap();
        assert_eq!(wrist, 5);
        assert_eq!(t.frames[0][wrist], [0.05, 0.10, -0.05, 0.5]);
        assert_eq!(t.frames[1][wrist], [0.0; 4]);
    }

    #[test]
    fn several_bodies_need_a_person_and_bad_files_say_why() {
        let d = tempfile::tempdir().unwrap();
        let two = write(d.path(), "a.json", &json!({"bodies": [body(1), body(6)]}));
        let err = |paths: &[PathBuf], person: Option<i64>| {
            read_panoptic_skeletons(paths, person)
                .unwrap_err()
                .to_string()
        };
        let e = err(std::slice::from_ref(&two), None);
        assert!(
            e.contains("2 bodies (ids 1, 6)") && e.contains("--reference-person"),
            "{e}"
        );
        let t = read_panoptic_skeletons(std::slice::from_ref(&two), Some(6)).unwrap();
        assert_eq!((t.person, t.empty_frames), (Some(6), 0));
        // One body per frame under two ids (one person's track broken in two): no one id.
        let a = write(d.path(), "id1.json", &json!({"bodies": [body(1)]}));
        let b = write(d.path(), "id2.json", &json!({"bodies": [body(2)]}));
        let t = read_panoptic_skeletons(&[a.clone(), b], None).unwrap();
        assert_eq!((t.frames.len(), t.person), (2, None));
        assert_eq!(read_panoptic_skeletons(&[a], None).unwrap().person, Some(1));
        let e = err(std::slice::from_ref(&two), Some(2));
        assert!(
            e.contains("no body has that id (the files' ids: 1, 6)"),
            "{e}"
        );
        let mut short = body(0);
        short["joints19"].as_array_mut().unwrap().pop();
        let p = write(d.path(), "short.json", &json!({"bodies": [short]}));
        assert!(err(&[p], None).contains("\"joints19\" has 75 values, expected 76"));
        let mut text = body(0);
        text["joints19"][8] = json!("x");
        let p = write(d.path(), "text.json", &json!({"bodies": [text]}));
        let e = err(&[p], None);
        assert!(e.contains("keypoint 2 (BodyCenter)"), "{e}");
        let p = write(d.path(), "other.json", &json!({"people": []}));
        assert!(err(&[p], None).contains("no \"bodies\" array"));
        let p = d.path().join("broken.json");
        std::fs::write(&p, "{\"bodies\": [").unwrap();
        assert!(err(&[p], None).contains("not JSON"));
        let p = write(d.path(), "none.json", &json!({"bodies": []}));
        assert!(err(&[p], None).contains("no body in any frame"));
        let e = err(&[d.path().join("missing.json")], None);
        assert!(e.contains("cannot read"), "{e}");
        let empty = tempfile::tempdir().unwrap();
        assert!(err(&[empty.path().to_path_buf()], None).contains("holds no .json file"));
    }
}
