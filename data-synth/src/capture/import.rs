//! Real observations → lfit datasets without ground truth (`lfit data import`).
//!
//! - 3D markers from a C3D file ([`crate::capture::c3d`]): each C3D label named by the label map (or, without
//!   one, equal to a model marker's name) fills that model marker's three entries of the
//!   `markers` observation, in metres; a gap (residual word < 0) or a model marker no label maps
//!   to is an invisible entry.
//! - 2D keypoints ([`crate::capture::keypoints`]): per camera, the keypoints of a COCO-17 or BODY_25
//!   detector, each mapped to a model joint, fill that joint's entries of the `keypoints2d`
//!   observation in that camera; a keypoint whose confidence is not above the threshold, or a
//!   joint no keypoint maps to, is invisible.
//!
//! The datasets have no ground truth ([`Dataset::has_ground_truth`] is false): fitting reports
//! energies and observation errors ([`observation_errors`]) instead of V2V/MPJPE. The start pose of
//! every frame is the model's rest pose moved rigidly onto the data: a least-squares rotation and
//! translation (Horn's quaternion method) of the rest markers onto the seen markers, or of the
//! rest joints onto the joints triangulated from two or more cameras; with one camera, the rest
//! pose is placed along the ray of the seen keypoints' centroid at the depth where its size
//! matches theirs; a frame that allows none of these starts where the previous one did.

use std::path::Path;

use glam::{DMat3, DQuat, DVec3};
use lfit_model::Template;
use lfit_model::camera::Camera;
use lfit_model::observe::{KeypointSetup, MarkerSetup, Modality, Sensor};
use serde::Deserialize;
use serde::de::{Deserializer, MapAccess, Visitor};
use serde_json::{Value, json};

use crate::capture::c3d::C3d;
use crate::capture::keypoints::{KeypointLayout, KeypointTrack};
use crate::dataset::config::{PoseSource, Scenario, SynthConfig};
use crate::dataset::{Dataset, FORMAT_VERSION, Meta, Observations};
use crate::motion::MotionKind;
use crate::motion::retarget::Up;
use crate::noise::NoiseConfig;

pub use super::ImportError;

fn fail<T>(msg: impl Into<String>) -> Result<T, ImportError> {
    Err(ImportError::Invalid(msg.into()))
}

/// The entries of a JSON object in file order, duplicates kept (so that they can be refused).
struct Pairs(Vec<(String, String)>);

impl<'de> Deserialize<'de> for Pairs {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        struct V;
        impl<'de> Visitor<'de> for V {
            type Value = Pairs;
            fn expecting(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
                f.write_str("an object of \"name\": \"name\" entries")
            }
            fn visit_map<A: MapAccess<'de>>(self, mut m: A) -> Result<Pairs, A::Error> {
                let mut out = Vec::new();
                while let Some(e) = m.next_entry::<String, String>()? {
                    out.push(e);
                }
                Ok(Pairs(out))
            }
        }
        d.deserialize_map(V)
    }
}

/// Reads a name map: a JSON object `{"from": "to", ...}`; a name repeated on either side is
/// refused. `what` names the two sides in errors (`"C3D label"`, `"model marker"`).
pub fn read_name_map(path: &Path, what: [&str; 2]) -> Result<Vec<(String, String)>, ImportError> {
    let text = std::fs::read_to_string(path).map_err(|source| ImportError::Read {
        path: path.to_path_buf(),
        source,
    })?;
    let Pairs(pairs) = serde_json::from_str(&text).map_err(|e| {
        ImportError::Invalid(format!(
            "{}: expected a JSON object {{\"{}\": \"{}\", ...}}: {e}",
            path.display(),
            what[0],
            what[1]
        ))
    })?;
    if pairs.is_empty() {
        return fail(format!("{}: the map is empty", path.display()));
    }
    for (side, label) in what.iter().enumerate() {
        let names: Vec<&String> = pairs
            .iter()
            .map(|(a, b)| if side == 0 { a } else { b })
            .collect();
        if let Some(n) =
            (0..names.len()).find_map(|i| names[..i].contains(&names[i]).then(|| names[i]))
        {
            return fail(format!("{}: {label} '{n}' appears twice", path.display()));
        }
    }
    Ok(pairs)
}

/// A dataset made by the import and a JSON summary of what was mapped.
#[derive(Debug)]
pub struct Imported {
    pub dataset: Dataset,
    pub report: Value,
}

fn list(names: &[String], max: usize) -> String {
    let mut s = names
        .iter()
        .take(max)
        .cloned()
        .collect::<Vec<_>>()
        .join(", ");
    if names.len() > max {
        s.push_str(&format!(", … ({} in all)", names.len()));
    }
    s
}

/// A dataset of imported observations: no ground truth, frame sources in `frame_motions`.
#[allow(clippy::too_many_arguments)]
fn imported_dataset(
    template: &Template,
    sensor: Sensor,
    scenario: Scenario,
    fps: f64,
    sources: Vec<String>,
    starts: Vec<Vec<f64>>,
    values: Vec<Vec<f64>>,
    visible: Vec<Vec<bool>>,
) -> Result<Dataset, ImportError> {
    let layout = template.layout();
    let modality = sensor.modality();
    let mut config = SynthConfig::new(modality, scenario, starts.len(), 0);
    config.source = PoseSource::Motion;
    config.fps = fps;
    config.noise = NoiseConfig::none();
    config.motions = MotionKind::CLASSIC.to_vec();
    config.validate()?;
    Ok(Dataset {
        meta: Meta {
            format: "lfit-dataset".into(),
            version: FORMAT_VERSION,
            template_id: template.id.clone(),
            template_vertices: template.num_vertices(),
            config,
            frame_motions: sources,
            pose_dim: layout.pose_dim(),
            shape_dim: layout.shape,
            expression_dim: layout.expression,
        },
        sensor,
        start_poses: starts,
        gt_poses: Vec::new(),
        observations: Observations::Sparse { values, visible },
        reference: None,
    })
}

/// The C3D point a label map's key names: `#K` is point K of POINT:LABELS, counted from 0 (how a
/// label the file repeats is mapped); any other key is a label the file holds once.
fn point_of(c3d: &C3d, key: &str) -> Result<usize, ImportError> {
    if let Some(k) = key.strip_prefix('#') {
        let Ok(k) = k.trim().parse::<usize>() else {
            return fail(format!(
                "label map: '{key}': #K needs a point index (counted from 0)"
            ));
        };
        if k >= c3d.labels.len() {
            return fail(format!(
                "label map: '{key}': the file has {} points (counted from 0)",
                c3d.labels.len()
            ));
        }
        return Ok(k);
    }
    match c3d.label_index(key)? {
        Some(ci) => Ok(ci),
        None => fail(format!(
            "label map: label '{key}' is not in the file (its labels: {})",
            list(&c3d.labels, 12)
        )),
    }
}

/// Keypoints in another unit or of another image than their camera's: each camera's seen
/// keypoints all within [−1, 1] (normalised coordinates read as pixels: `--keypoint-scale`)
/// or more than half of them over half an image outside its width × height (keypoints of
/// another resolution, or of another camera of the file) are refused — lfit reads pixels of the
/// camera file's image, and such keypoints would fit silently wrong.
fn check_pixels(
    cameras: &[Camera],
    nj: usize,
    values: &[Vec<f64>],
    visible: &[Vec<bool>],
) -> Result<(), ImportError> {
    for (c, cam) in cameras.iter().enumerate() {
        let (w, h) = (f64::from(cam.width), f64::from(cam.height));
        let (mut seen, mut unit, mut far) = (0usize, 0usize, 0usize);
        for (v, b) in values.iter().zip(visible) {
            for j in 0..nj {
                let i = 2 * (c * nj + j);
                if !b[i] {
                    continue;
                }
                let (x, y) = (v[i], v[i + 1]);
                seen += 1;
                if x.abs() <= 1.0 && y.abs() <= 1.0 {
                    unit += 1;
                }
                if x < -0.5 * w || x > 1.5 * w || y < -0.5 * h || y > 1.5 * h {
                    far += 1;
                }
            }
        }
        if seen > 0 && unit == seen && w.max(h) >= 16.0 {
            return fail(format!(
                "camera {c}: every keypoint lies within [-1, 1], in a {}×{} image: normalised coordinates (MediaPipe, OpenPose --keypoint_scale 3 or 4)? read them with --keypoint-scale image|openpose3|openpose4",
                cam.width, cam.height
            ));
        }
        if 2 * far > seen {
            return fail(format!(
                "camera {c}: {far} of its {seen} keypoints lie more than half an image outside its {}×{} image: keypoints of another resolution, or of another camera (one keypoint file per camera, in the camera file's order)?",
                cam.width, cam.height
            ));
        }
    }
    Ok(())
}

/// The fewest model markers a label prefix must name to be read as a subject's.
const MIN_SUBJECT_MARKERS: usize = 3;

/// The default label map: each model marker whose name is a C3D label, or the part of one after
/// a subject's prefix (`SUBJECT:NAME`, as Vicon Nexus writes a labelled subject's markers; a
/// prefix naming fewer than [`MIN_SUBJECT_MARKERS`] is not a subject's). Labels of one subject only: bare names, or one prefix; a file whose labels name the model's
/// markers under several prefixes (or bare and prefixed) is refused, to be mapped with a label
/// map. Returns the prefix read (`None` for bare names).
fn default_pairs(
    c3d: &C3d,
    marker_names: &[String],
    pairs: &mut Vec<(usize, usize)>,
) -> Result<Option<String>, ImportError> {
    // The bare names first: a file without prefixes maps as it always did.
    for (mi, name) in marker_names.iter().enumerate() {
        if let Some(ci) = c3d.label_index(name)? {
            pairs.push((ci, mi));
        }
    }
    // Each subject prefix under which a label names a model marker, and how many it names.
    let mut prefixes: Vec<(String, usize)> = Vec::new();
    for label in &c3d.labels {
        let Some((prefix, name)) = label.trim().rsplit_once(':') else {
            continue;
        };
        if marker_names.iter().any(|m| m == name) {
            match prefixes.iter_mut().find(|p| p.0 == prefix) {
                Some(p) => p.1 += 1,
                None => prefixes.push((prefix.to_string(), 1)),
            }
        }
    }
    // A prefix under which fewer than three labels name model markers is a rigid body or a
    // prop (OptiTrack's `BodyL:Marker1`), not a subject: a rigid start needs three markers.
    prefixes.retain(|p| p.1 >= MIN_SUBJECT_MARKERS);
    if prefixes.is_empty() {
        return Ok(None);
    }
    if prefixes.len() > 1 || !pairs.is_empty() {
        let mut groups: Vec<String> = prefixes
            .iter()
            .map(|(p, n)| format!("'{p}:' {n}"))
            .collect();
        if !pairs.is_empty() {
            groups.insert(0, format!("bare {}", pairs.len()));
        }
        return fail(format!(
            "the file's labels name the model's markers for more than one subject ({}): give --label-map to choose one",
            groups.join(", ")
        ));
    }
    let prefix = &prefixes[0].0;
    for (mi, name) in marker_names.iter().enumerate() {
        if let Some(ci) = c3d.label_index(&format!("{prefix}:{name}"))? {
            pairs.push((ci, mi));
        }
    }
    Ok(Some(prefix.clone()))
}

/// Imports the points of a C3D file as a `markers` dataset of `template`. `map`: C3D label (or
/// `#K`, the file's point K counted from 0) → model marker (default: every model marker whose
/// name is a C3D label, or one subject's label after its `SUBJECT:` prefix, [`default_pairs`]). `up`: the lab frame's up axis; a Z-up file's points are turned into
/// lfit's Y-up frame by `(x, y, z) → (x, z, −y)` (as `lfit motion import --up z`), so that the
/// fitted body stands in renders and exports.
pub fn import_c3d(
    c3d: &C3d,
    source: &str,
    map: Option<&[(String, String)]>,
    template: &Template,
    scenario: Scenario,
    up: Up,
) -> Result<Imported, ImportError> {
    let markers = &template.rig.markers;
    if markers.is_empty() {
        return fail(format!(
            "model '{}' has no markers (a rig's \"markers\", or the model file's marker_names/marker_vertices)",
            template.id
        ));
    }
    if c3d.labels.is_empty() {
        return fail("the file holds no 3D points (a C3D's POINT:USED is 0)");
    }
    let metres = c3d.metres_per_unit()?;
    let to_lfit = up.to_lfit();
    let marker_names: Vec<String> = markers.iter().map(|m| m.name.clone()).collect();
    // (C3D point index, model marker index)
    let mut pairs: Vec<(usize, usize)> = Vec::new();
    // The subject prefix the default map read the labels under (Vicon's `SUBJECT:NAME`).
    let mut subject: Option<String> = None;
    match map {
        Some(map) => {
            for (label, marker) in map {
                let ci = point_of(c3d, label)?;
                let Some(mi) = marker_names.iter().position(|m| m == marker) else {
                    return fail(format!(
                        "label map: '{marker}' is not a marker of model '{}' (its markers: {})",
                        template.id,
                        list(&marker_names, 12)
                    ));
                };
                if let Some(&(_, other)) = pairs.iter().find(|p| p.0 == ci) {
                    return fail(format!(
                        "label map: point #{ci} ('{}') is mapped twice (to '{}' and '{marker}')",
                        c3d.labels[ci].trim(),
                        marker_names[other]
                    ));
                }
                pairs.push((ci, mi));
            }
        }
        None => {
            subject = default_pairs(c3d, &marker_names, &mut pairs)?;
            if pairs.is_empty() {
                return fail(format!(
                    "no label of the file is the name of a marker of model '{}', bare or after a subject's prefix (SUBJECT:NAME): give --label-map (its labels: {})",
                    template.id,
                    list(&c3d.labels, 12)
                ));
            }
        }
    }
    let m = markers.len();
    let mut values = Vec::with_capacity(c3d.frames.len());
    let mut visible = Vec::with_capacity(c3d.frames.len());
    let mut gaps = 0usize;
    for row in &c3d.frames {
        let mut v = vec![0.0; 3 * m];
        let mut b = vec![false; 3 * m];
        for &(ci, mi) in &pairs {
            match row[ci] {
                Some(p) => {
                    let q = to_lfit * (DVec3::from_array(p.position) * metres);
                    v[3 * mi..3 * mi + 3].copy_from_slice(&q.to_array());
                    b[3 * mi..3 * mi + 3].fill(true);
                }
                None => gaps += 1,
            }
        }
        values.push(v);
        visible.push(b);
    }
    if visible.iter().all(|b| !b.contains(&true)) {
        return fail("no mapped marker is seen in any frame (every sample is a gap)");
    }
    let sensor = Sensor::Markers(MarkerSetup {
        names: marker_names.clone(),
        vertices: markers.iter().map(|m| m.vertex).collect(),
        offsets: Vec::new(),
    });
    let (starts, rigid_frames) = marker_starts(template, &sensor, &values, &visible);
    // A point's label in the summary; a label the file repeats with the point's index.
    let shown = |ci: usize| {
        let label = c3d.labels[ci].trim();
        if c3d.labels.iter().filter(|l| l.trim() == label).count() > 1 {
            format!("{label} (#{ci})")
        } else {
            label.to_string()
        }
    };
    let mapped: Vec<String> = pairs
        .iter()
        .map(|&(ci, mi)| format!("{}→{}", shown(ci), marker_names[mi]))
        .collect();
    let unmapped: Vec<String> = (0..m)
        .filter(|mi| !pairs.iter().any(|p| p.1 == *mi))
        .map(|mi| marker_names[mi].clone())
        .collect();
    let ignored: Vec<String> = (0..c3d.labels.len())
        .filter(|ci| !pairs.iter().any(|p| p.0 == *ci))
        .map(shown)
        .collect();
    let n = values.len();
    let sources = (0..n)
        .map(|f| format!("c3d:{source}#{}", c3d.first_frame as usize + f))
        .collect();
    let mut report = json!({
        "format": "c3d",
        "frames": n,
        "fps": c3d.rate,
        "units": c3d.units,
        "up": up.name(),
        "point_format": if c3d.scale < 0.0 { "float" } else { "integer" },
        "mapped_markers": pairs.len(),
        "model_markers": m,
        "unmapped_model_markers": unmapped,
        "ignored_c3d_labels": ignored,
        "gap_fraction": gaps as f64 / (n * pairs.len()).max(1) as f64,
        // Samples of any point whose coordinates were not finite: gaps (NaN marks a gap in
        // kineticstoolkit's files and others').
        "non_finite_samples": c3d.non_finite,
        "rigid_starts": rigid_frames,
        "map": mapped,
    });
    if let Some(subject) = &subject {
        report["subject"] = json!(subject);
    }
    let dataset = imported_dataset(
        template, sensor, scenario, c3d.rate, sources, starts, values, visible,
    )?;
    Ok(Imported { dataset, report })
}

/// `(model joint, keypoint index)` pairs of `layout` on `template`: `map` (model joint name →
/// keypoint name) or, without one, the layout's default map through the model's joint map.
pub fn layout_pairs(
    layout: KeypointLayout,
    map: Option<&[(String, String)]>,
    template: &Template,
) -> Result<Vec<(usize, usize)>, ImportError> {
    let rig = &template.rig;
    let mut pairs = Vec::new();
    match map {
        Some(map) => {
            for (joint, kp) in map {
                let Some(j) = rig.joint_index(joint) else {
                    return fail(format!(
                        "keypoint map: '{joint}' is not a joint of model '{}'",
                        template.id
                    ));
                };
                let Some(k) = layout.index(kp) else {
                    return fail(format!(
                        "keypoint map: '{kp}' is not a {} keypoint (its names: {})",
                        layout.name(),
                        layout.names().join(", ")
                    ));
                };
                pairs.push((j, k));
            }
        }
        None => {
            for (p, kp) in layout.default_map() {
                if let Some(Some(j)) = template.info.joint_map.get(p)
                    && let Some(k) = layout.index(kp)
                {
                    pairs.push((*j, k));
                }
            }
            if pairs.is_empty() {
                return fail(format!(
                    "model '{}' maps none of the papers/000 joints the {} layout gives: pass --keypoint-map",
                    template.id,
                    layout.name()
                ));
            }
        }
    }
    Ok(pairs)
}

/// Imports per-camera keypoint tracks as a `keypoints2d` dataset of `template`. `map`: model
/// joint name → keypoint name (default: [`KeypointLayout::default_map`] through the model's joint
/// map); a keypoint is seen when its confidence is above `min_confidence`.
#[allow(clippy::too_many_arguments)]
pub fn import_keypoints(
    tracks: &[KeypointTrack],
    cameras: Vec<Camera>,
    layout: KeypointLayout,
    map: Option<&[(String, String)]>,
    min_confidence: f64,
    fps: f64,
    template: &Template,
    scenario: Scenario,
) -> Result<Imported, ImportError> {
    if !min_confidence.is_finite() {
        return fail("--min-confidence must be a finite number");
    }
    if tracks.len() != cameras.len() {
        return fail(format!(
            "{} keypoint tracks for {} cameras: give one per camera, in the camera file's order",
            tracks.len(),
            cameras.len()
        ));
    }
    let n = tracks[0].frames.len();
    for (c, t) in tracks.iter().enumerate() {
        if t.frames.len() != n {
            return fail(format!(
                "camera {c} has {} frames, camera 0 has {n}",
                t.frames.len()
            ));
        }
        if let Some((f, (w, h))) = t
            .image_sizes
            .iter()
            .enumerate()
            .find_map(|(f, s)| s.map(|s| (f, s)))
            .filter(|(_, s)| *s != (cameras[c].width, cameras[c].height))
        {
            return fail(format!(
                "{}: the image is {w}×{h} but camera {c} is {}×{}",
                t.sources[f], cameras[c].width, cameras[c].height
            ));
        }
    }
    let rig = &template.rig;
    let nj = rig.num_joints();
    let pairs = layout_pairs(layout, map, template)?;
    let k = cameras.len();
    let mut values = Vec::with_capacity(n);
    let mut visible = Vec::with_capacity(n);
    for f in 0..n {
        let mut v = vec![0.0; 2 * k * nj];
        let mut b = vec![false; 2 * k * nj];
        for (c, t) in tracks.iter().enumerate() {
            for &(j, kp) in &pairs {
                let p = t.frames[f][kp];
                if p[2] > min_confidence {
                    let i = 2 * (c * nj + j);
                    v[i] = p[0];
                    v[i + 1] = p[1];
                    b[i] = true;
                    b[i + 1] = true;
                }
            }
        }
        values.push(v);
        visible.push(b);
    }
    if visible.iter().all(|b| !b.contains(&true)) {
        return fail(format!(
            "no mapped keypoint has a confidence above {min_confidence} in any frame"
        ));
    }
    check_pixels(&cameras, nj, &values, &visible)?;
    let joints: Vec<usize> = pairs.iter().map(|p| p.0).collect();
    let (starts, rigid, ray, size) =
        keypoint_starts(template, &cameras, &joints, &values, &visible);
    // A body triangulated many times the model's size: the cameras' translations are in another
    // unit than metres (cm: 100×, mm: 1000×), or the keypoint files are not in their order.
    if let Some(size) = size
        && !(0.125..=8.0).contains(&size)
    {
        return fail(format!(
            "the keypoints triangulate to a body {size:.3}× the model's size (median over {rigid} frames): are the camera translations in another unit (--camera-units m|cm|mm), or the keypoint files in another order than the cameras?"
        ));
    }
    let joint_names: Vec<String> = rig.joints.iter().map(|j| j.name.clone()).collect();
    let mapped: Vec<String> = pairs
        .iter()
        .map(|&(j, kp)| format!("{}→{}", layout.names()[kp], joint_names[j]))
        .collect();
    let unmapped: Vec<String> = (0..nj)
        .filter(|j| !pairs.iter().any(|p| p.0 == *j))
        .map(|j| joint_names[j].clone())
        .collect();
    let seen_fraction = visible
        .iter()
        .map(|b| b.iter().filter(|&&x| x).count())
        .sum::<usize>() as f64
        / (n * 2 * k * pairs.len()).max(1) as f64;
    let sources: Vec<String> = (0..n)
        .map(|f| format!("{}:{}", tracks[0].format, tracks[0].sources[f]))
        .collect();
    let report = json!({
        "format": tracks[0].format,
        "layout": layout.name(),
        "frames": n,
        "cameras": k,
        "fps": fps,
        "mapped_joints": pairs.len(),
        "unmapped_model_joints": unmapped,
        "map": mapped,
        "min_confidence": min_confidence,
        "seen_fraction": seen_fraction,
        "crowded_frames": tracks.iter().map(|t| t.crowded_frames).sum::<usize>(),
        "triangulated_starts": rigid,
        "triangulated_size": size,
        "single_view_starts": ray,
    });
    let sensor = Sensor::Keypoints2d(KeypointSetup::new(cameras));
    let dataset = imported_dataset(
        template, sensor, scenario, fps, sources, starts, values, visible,
    )?;
    Ok(Imported { dataset, report })
}

/// The start poses of captured markers (`lfit data import --c3d`): per frame the rest pose moved
/// rigidly onto the seen markers (Horn's method against the rest model's markers as `sensor`
/// places them), a frame with fewer than three seen where the previous one started; and how many
/// frames had their own. Also what `lfit fit --holdout` starts from, on the markers it leaves.
pub fn marker_starts(
    template: &Template,
    sensor: &Sensor,
    values: &[Vec<f64>],
    visible: &[Vec<bool>],
) -> (Vec<Vec<f64>>, usize) {
    let rest = sensor
        .predict_sparse(template, &vec![0.0; template.layout().dim()])
        .values;
    let rest_points: Vec<DVec3> = rest
        .chunks_exact(3)
        .map(|c| DVec3::new(c[0], c[1], c[2]))
        .collect();
    let m = rest_points.len();
    let mut starts = Vec::with_capacity(values.len());
    let mut rigid_frames = 0;
    for (v, b) in values.iter().zip(visible) {
        let (a, o): (Vec<DVec3>, Vec<DVec3>) = (0..m)
            .filter(|&k| b[3 * k])
            .map(|k| {
                (
                    rest_points[k],
                    DVec3::new(v[3 * k], v[3 * k + 1], v[3 * k + 2]),
                )
            })
            .unzip();
        let start = match rigid_fit(&a, &o) {
            Some((q, s)) => {
                rigid_frames += 1;
                Some(rigid_start(template, q, s))
            }
            None => None,
        };
        starts.push(start);
    }
    (fill_starts(starts, template), rigid_frames)
}

/// The start poses of captured 2D keypoints (`lfit data import --keypoints`) seen by `cameras`
/// at the model joints `joints` (in this order): per frame the rest pose moved rigidly onto the
/// joints triangulated from two or more cameras, or, with fewer than three such, placed along
/// the ray of the camera that sees most of them at the depth that matches their spread; a frame
/// with neither where the previous one started. Also how many frames took each way (rigid,
/// ray), and the triangulated joints' size against the rest joints' (the median over the rigid
/// frames of their RMS distances from their centroids; `None` without such a frame): near 1 for
/// a person, a hundred or a thousand times that for cameras whose translations are in cm or mm
/// but read as metres. What `lfit fit --holdout` starts from, on the cameras and keypoints it
/// leaves.
pub fn keypoint_starts(
    template: &Template,
    cameras: &[Camera],
    joints: &[usize],
    values: &[Vec<f64>],
    visible: &[Vec<bool>],
) -> (Vec<Vec<f64>>, usize, usize, Option<f64>) {
    let nj = template.rig.num_joints();
    let k = cameras.len();
    let rest = template.joint_rest();
    let mut starts = Vec::with_capacity(values.len());
    let (mut rigid, mut ray) = (0, 0);
    let mut sizes: Vec<f64> = Vec::new();
    let rms = |p: &[DVec3]| {
        let c = p.iter().copied().sum::<DVec3>() / p.len() as f64;
        (p.iter().map(|x| (*x - c).length_squared()).sum::<f64>() / p.len() as f64).sqrt()
    };
    for (v, b) in values.iter().zip(visible) {
        let seen = |c: usize, j: usize| b[2 * (c * nj + j)];
        let uv = |c: usize, j: usize| {
            let i = 2 * (c * nj + j);
            [v[i], v[i + 1]]
        };
        let (mut a, mut o) = (Vec::new(), Vec::new());
        for &j in joints {
            let views: Vec<(usize, [f64; 2])> = (0..k)
                .filter(|&c| seen(c, j))
                .map(|c| (c, uv(c, j)))
                .collect();
            if views.len() >= 2
                && let Some(x) = triangulate(cameras, &views)
            {
                a.push(rest[j]);
                o.push(x);
            }
        }
        let start = if let Some((q, s)) = rigid_fit(&a, &o) {
            rigid += 1;
            sizes.push(rms(&o) / rms(&a));
            Some(rigid_start(template, q, s))
        } else {
            // One camera: the camera that sees most of the joints.
            let best = (0..k)
                .map(|c| (joints.iter().filter(|&&j| seen(c, j)).count(), c))
                .max()
                .filter(|&(count, _)| count >= 2);
            best.and_then(|(_, c)| {
                let js: Vec<usize> = joints.iter().copied().filter(|&j| seen(c, j)).collect();
                let pts: Vec<[f64; 2]> = js.iter().map(|&j| uv(c, j)).collect();
                let rest_pts: Vec<DVec3> = js.iter().map(|&j| rest[j]).collect();
                let s = place_on_ray(&cameras[c], &pts, &rest_pts)?;
                ray += 1;
                Some(rigid_start(template, DQuat::IDENTITY, s))
            })
        };
        starts.push(start);
    }
    sizes.sort_by(f64::total_cmp);
    let size = (!sizes.is_empty()).then(|| sizes[sizes.len() / 2]);
    (fill_starts(starts, template), rigid, ray, size)
}

/// Frames without an estimate start where the previous one did (the first such frames, where the
/// next estimate does; the rest pose when no frame has one).
fn fill_starts(starts: Vec<Option<Vec<f64>>>, template: &Template) -> Vec<Vec<f64>> {
    let first = starts
        .iter()
        .flatten()
        .next()
        .cloned()
        .unwrap_or_else(|| vec![0.0; template.layout().dim()]);
    let mut last = first;
    starts
        .into_iter()
        .map(|s| {
            if let Some(s) = s {
                last = s;
            }
            last.clone()
        })
        .collect()
}

/// The rest pose moved by `x ↦ q x + s` (about the origin): root rotation `q` and the root
/// translation that keeps the root joint where the motion puts it.
pub fn rigid_start(template: &Template, q: DQuat, s: DVec3) -> Vec<f64> {
    let layout = template.layout();
    let mut pose = vec![0.0; layout.dim()];
    let c = template.joint_rest()[0];
    let t = s + q * c - c;
    pose[..3].copy_from_slice(&t.to_array());
    let r = layout.rotation_offset(0);
    pose[r..r + 3].copy_from_slice(&q.to_scaled_axis().to_array());
    pose
}

/// The rotation and translation `b ≈ q a + s` of least squares (Horn's closed form: the unit
/// quaternion is the top eigenvector of a 4×4 symmetric matrix). `None` with fewer than three
/// pairs or a degenerate (collinear) set.
pub fn rigid_fit(a: &[DVec3], b: &[DVec3]) -> Option<(DQuat, DVec3)> {
    if a.len() < 3 || a.len() != b.len() {
        return None;
    }
    let n = a.len() as f64;
    let ca = a.iter().copied().sum::<DVec3>() / n;
    let cb = b.iter().copied().sum::<DVec3>() / n;
    // Cross-covariance Σ (a − ā)(b − b̄)ᵀ and the rest points' own covariance.
    let outer = |p: DVec3, q: DVec3| DMat3::from_cols(p * q.x, p * q.y, p * q.z);
    let s = a
        .iter()
        .zip(b)
        .fold(DMat3::ZERO, |m, (p, q)| m + outer(*p - ca, *q - cb));
    let own = a
        .iter()
        .fold(DMat3::ZERO, |m, p| m + outer(*p - ca, *p - ca));
    // Degenerate when the centred rest points span less than a plane (second eigenvalue ~ 0).
    let spread = own.x_axis.x + own.y_axis.y + own.z_axis.z;
    if spread < 1e-12 {
        return None;
    }
    let c = own.to_cols_array_2d();
    let (mut vals, _) = jacobi_eigen(&[
        [c[0][0], c[0][1], c[0][2], 0.0],
        [c[1][0], c[1][1], c[1][2], 0.0],
        [c[2][0], c[2][1], c[2][2], 0.0],
        [0.0, 0.0, 0.0, 0.0],
    ]);
    vals.sort_by(|x, y| y.total_cmp(x));
    if vals[1] < 1e-9 * spread {
        return None;
    }
    // s[i][j] = Σ a_i b_j (row i, column j).
    let e = |i: usize, j: usize| s.col(j)[i];
    let (sxx, sxy, sxz) = (e(0, 0), e(0, 1), e(0, 2));
    let (syx, syy, syz) = (e(1, 0), e(1, 1), e(1, 2));
    let (szx, szy, szz) = (e(2, 0), e(2, 1), e(2, 2));
    let m = [
        [sxx + syy + szz, syz - szy, szx - sxz, sxy - syx],
        [syz - szy, sxx - syy - szz, sxy + syx, szx + sxz],
        [szx - sxz, sxy + syx, -sxx + syy - szz, syz + szy],
        [sxy - syx, szx + sxz, syz + szy, -sxx - syy + szz],
    ];
    let (vals, vecs) = jacobi_eigen(&m);
    let top = (0..4).max_by(|&i, &j| vals[i].total_cmp(&vals[j]))?;
    let (w, x, y, z) = (vecs[0][top], vecs[1][top], vecs[2][top], vecs[3][top]);
    let mut q = DQuat::from_xyzw(x, y, z, w).normalize();
    if q.w < 0.0 {
        q = -q;
    }
    if !q.is_finite() {
        return None;
    }
    Some((q, cb - q * ca))
}

/// Eigenvalues and eigenvectors (columns) of a symmetric 4×4 matrix by cyclic Jacobi rotations.
fn jacobi_eigen(m: &[[f64; 4]; 4]) -> ([f64; 4], [[f64; 4]; 4]) {
    let mut a = *m;
    let mut v = [[0.0; 4]; 4];
    for (i, row) in v.iter_mut().enumerate() {
        row[i] = 1.0;
    }
    for _ in 0..64 {
        let off: f64 = (0..4)
            .flat_map(|p| (p + 1..4).map(move |q| (p, q)))
            .map(|(p, q)| a[p][q] * a[p][q])
            .sum();
        let scale: f64 = (0..4).map(|i| a[i][i] * a[i][i]).sum::<f64>() + off;
        if off <= 1e-30 * scale.max(1e-300) {
            break;
        }
        for p in 0..4 {
            for q in p + 1..4 {
                if a[p][q] == 0.0 {
                    continue;
                }
                let theta = (a[q][q] - a[p][p]) / (2.0 * a[p][q]);
                let t = if theta == 0.0 {
                    1.0
                } else {
                    theta.signum() / (theta.abs() + (theta * theta + 1.0).sqrt())
                };
                let c = 1.0 / (t * t + 1.0).sqrt();
                let s = t * c;
                for row in a.iter_mut() {
                    let (kp, kq) = (row[p], row[q]);
                    row[p] = c * kp - s * kq;
                    row[q] = s * kp + c * kq;
                }
                let (rp, rq) = (a[p], a[q]);
                for k in 0..4 {
                    a[p][k] = c * rp[k] - s * rq[k];
                    a[q][k] = s * rp[k] + c * rq[k];
                }
                for row in v.iter_mut() {
                    let (kp, kq) = (row[p], row[q]);
                    row[p] = c * kp - s * kq;
                    row[q] = s * kp + c * kq;
                }
            }
        }
    }
    ([a[0][0], a[1][1], a[2][2], a[3][3]], v)
}

/// The world point that best explains pixel observations `(camera, [u, v])` in two or more
/// cameras (linear least squares on the normalised projection equations); `None` when they are
/// degenerate or the point lands behind a camera.
pub fn triangulate(cameras: &[Camera], views: &[(usize, [f64; 2])]) -> Option<DVec3> {
    let mut m = DMat3::ZERO;
    let mut rhs = DVec3::ZERO;
    for &(c, [u, v]) in views {
        let cam = cameras.get(c)?;
        let r = cam.rotation;
        let t = cam.translation;
        let (xn, yn) = ((u - cam.cx) / cam.fx, (v - cam.cy) / cam.fy);
        let r3 = DVec3::from_array(r[2]);
        for (row, n, ti) in [(r[0], xn, t[0]), (r[1], yn, t[1])] {
            let a = DVec3::from_array(row) - n * r3;
            let b = n * t[2] - ti;
            m += DMat3::from_cols(a * a.x, a * a.y, a * a.z);
            rhs += a * b;
        }
    }
    if m.determinant().abs() < 1e-12 {
        return None;
    }
    let x = m.inverse() * rhs;
    let in_front = views.iter().all(|&(c, _)| cameras[c].to_camera(x).z > 0.01);
    (x.is_finite() && in_front).then_some(x)
}

/// Translation that puts `rest` (unrotated) in front of `cam` where its projection has the size
/// and centroid of `pixels`: depth = focal × (3D spread) / (pixel spread).
fn place_on_ray(cam: &Camera, pixels: &[[f64; 2]], rest: &[DVec3]) -> Option<DVec3> {
    let n = pixels.len() as f64;
    let cu = pixels.iter().map(|p| p[0]).sum::<f64>() / n;
    let cv = pixels.iter().map(|p| p[1]).sum::<f64>() / n;
    let spread_px = (pixels
        .iter()
        .map(|p| (p[0] - cu).powi(2) + (p[1] - cv).powi(2))
        .sum::<f64>()
        / n)
        .sqrt();
    let c3 = rest.iter().copied().sum::<DVec3>() / n;
    let spread_m = (rest.iter().map(|p| (*p - c3).length_squared()).sum::<f64>() / n).sqrt();
    if spread_px < 1e-6 || spread_m < 1e-6 {
        return None;
    }
    let depth = 0.5 * (cam.fx + cam.fy) * spread_m / spread_px;
    let dir_cam = DVec3::new((cu - cam.cx) / cam.fx, (cv - cam.cy) / cam.fy, 1.0);
    let rot = cam.rot();
    let world = rot.transpose() * (dir_cam * depth - DVec3::from_array(cam.translation));
    let s = world - c3;
    s.is_finite().then_some(s)
}

/// How far a pose's prediction lies from a frame's seen observations: per seen marker the 3D
/// distance (mm), per seen keypoint the image distance (px).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ObservationErrors {
    /// `mm` or `px`.
    pub unit: &'static str,
    pub mean: f64,
    pub rms: f64,
    pub max: f64,
    /// Seen markers or keypoints.
    pub count: usize,
}

/// [`ObservationErrors`] of `pose` on frame `frame` as `sensor` predicts it (the dataset's, or
/// its markers at offsets a fit solved: `lfit fit --marker-placement solve`; `markers` and
/// `keypoints2d` only; `None` for other modalities and frames with nothing seen).
pub fn observation_errors(
    dataset: &Dataset,
    sensor: &Sensor,
    template: &Template,
    frame: usize,
    pose: &[f64],
) -> Option<ObservationErrors> {
    let (unit, d) = observation_distances_of(dataset, sensor, template, frame, pose, &|_| true)?;
    ObservationErrors::of(unit, &d.into_iter().map(|e| e.1).collect::<Vec<_>>())
}

/// The distance of each seen marker or keypoint that `scored` picks (by index: marker `k`;
/// keypoint `c · joints + j` of camera `c`) from `pose`'s prediction, with its index: (unit,
/// [(index, distance)]), in index order: `lfit fit --holdout`'s errors on what it held out.
/// `None` where [`observation_errors`] has none (another modality, the frame missing, a sensor
/// of another length); the list may be empty.
pub fn observation_distances_of(
    dataset: &Dataset,
    sensor: &Sensor,
    template: &Template,
    frame: usize,
    pose: &[f64],
    scored: &dyn Fn(usize) -> bool,
) -> Option<(&'static str, Vec<(usize, f64)>)> {
    let (len, factor, unit) = match dataset.modality() {
        Modality::Markers => (3, 1000.0, "mm"),
        Modality::Keypoints2d => (2, 1.0, "px"),
        _ => return None,
    };
    let Observations::Sparse { values, visible } = &dataset.observations else {
        return None;
    };
    let (obs, seen) = (values.get(frame)?, visible.get(frame)?);
    let pred = sensor.predict_sparse(template, pose).values;
    if pred.len() != obs.len() {
        return None;
    }
    let d = (0..obs.len() / len)
        .filter(|&g| seen[g * len] && scored(g))
        .map(|g| {
            let d = (0..len)
                .map(|a| (pred[g * len + a] - obs[g * len + a]).powi(2))
                .sum::<f64>()
                .sqrt();
            (g, d * factor)
        })
        .collect();
    Some((unit, d))
}

impl ObservationErrors {
    /// Mean, RMS and largest of `distances` (in `unit`); `None` when there are none.
    pub fn of(unit: &'static str, distances: &[f64]) -> Option<Self> {
        if distances.is_empty() {
            return None;
        }
        let n = distances.len() as f64;
        Some(Self {
            unit,
            mean: distances.iter().sum::<f64>() / n,
            rms: (distances.iter().map(|x| x * x).sum::<f64>() / n).sqrt(),
            max: distances.iter().copied().fold(0.0, f64::max),
            count: distances.len(),
        })
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod tests {
    use super::*;
    use crate::capture::c3d::{C3dPoint, Processor};
    use lfit_model::camera::default_ring;
    use lfit_model::default_template;

    fn template() -> Template {
        default_template()
    }

    #[test]
    fn horn_recovers_a_rigid_motion() {
        let a: Vec<DVec3> = (0..7)
            .map(|i| DVec3::new((i as f64).sin(), (i as f64 * 0.7).cos(), i as f64 * 0.1))
            .collect();
        let q = DQuat::from_scaled_axis(DVec3::new(0.3, -1.2, 2.0));
        let s = DVec3::new(1.0, -2.0, 0.5);
        let b: Vec<DVec3> = a.iter().map(|p| q * *p + s).collect();
        let (q2, s2) = rigid_fit(&a, &b).unwrap();
        assert!(q2.angle_between(q) < 1e-9, "{q2:?} vs {q:?}");
        assert!((s2 - s).length() < 1e-9);
        // Collinear points are refused.
        let line: Vec<DVec3> = (0..5).map(|i| DVec3::X * i as f64).collect();
        assert!(rigid_fit(&line, &line).is_none());
    }

    #[test]
    fn triangulation_inverts_the_projection() {
        let cams = default_ring(4);
        let x = DVec3::new(0.2, 1.3, -0.4);
        let views: Vec<(usize, [f64; 2])> = cams
            .iter()
            .enumerate()
            .map(|(c, cam)| {
                let p = cam.project(x).unwrap();
                (c, [p.x, p.y])
            })
            .collect();
        assert!((triangulate(&cams, &views).unwrap() - x).length() < 1e-9);
        assert!(triangulate(&cams, &views[..1]).is_none());
    }

    /// The label map of [`c3d_of`]'s files: "S1:<marker>" → marker.
    fn s1_label_map(template: &Template) -> Vec<(String, String)> {
        template
            .rig
            .markers
            .iter()
            .map(|m| (format!("S1:{}", m.name), m.name.clone()))
            .collect()
    }

    /// A C3D file of the template's markers at a known rigid pose, one marker renamed and one gap.
    fn c3d_of(template: &Template, pose: &[f64]) -> C3d {
        let sensor = Sensor::default_for(Modality::Markers, template);
        let p = sensor.predict_sparse(template, pose).values;
        let labels: Vec<String> = template
            .rig
            .markers
            .iter()
            .map(|m| format!("S1:{}", m.name))
            .collect();
        let frames = (0..3)
            .map(|f| {
                (0..labels.len())
                    .map(|k| {
                        (!(f == 1 && k == 4)).then(|| C3dPoint {
                            position: [p[3 * k] * 1e3, p[3 * k + 1] * 1e3, p[3 * k + 2] * 1e3],
                            residual: 1.0,
                            cameras: 3,
                        })
                    })
                    .collect()
            })
            .collect();
        C3d {
            processor: Processor::Intel,
            labels,
            units: "mm".into(),
            scale: -0.1,
            rate: 100.0,
            first_frame: 1,
            analog_per_frame: 0,
            frames,
            non_finite: 0,
        }
    }

    #[test]
    fn c3d_import_maps_labels_gaps_and_a_rigid_start() {
        let t = template();
        let mut pose = vec![0.0; t.layout().dim()];
        pose[..3].copy_from_slice(&[0.3, 0.05, -0.2]);
        pose[4] = 0.8; // root yaw
        let c = C3d::from_bytes(&c3d_of(&t, &pose).to_bytes().unwrap()).unwrap();
        let map = s1_label_map(&t);
        let imp = import_c3d(&c, "x.c3d", Some(&map), &t, Scenario::Sequence, Up::Y).unwrap();
        let d = &imp.dataset;
        assert!(!d.has_ground_truth());
        assert_eq!(d.len(), 3);
        let Observations::Sparse { values, visible } = &d.observations else {
            panic!()
        };
        assert!(!visible[1][12] && visible[0][12] && visible[1][15]);
        let truth = d.sensor.predict_sparse(&t, &pose).values;
        for (a, b) in values[0].iter().zip(&truth) {
            assert!((a - b).abs() < 2e-7, "{a} vs {b}");
        }
        // The rigid start is the true pose (rest pose + root motion).
        for (a, b) in d.start_poses[2].iter().zip(&pose) {
            assert!((a - b).abs() < 1e-5, "{:?}", &d.start_poses[2][..6]);
        }
        let e = observation_errors(d, &d.sensor, &t, 0, &pose).unwrap();
        assert!(e.max < 1e-3 && e.count == t.rig.markers.len());

        // Bad maps: an unknown C3D label, an unknown model marker; no map matches nothing.
        let mut bad = map.clone();
        bad[0].0 = "S1:NOPE".into();
        let e = import_c3d(&c, "x", Some(&bad), &t, Scenario::Local, Up::Y).unwrap_err();
        assert!(
            e.to_string().contains("'S1:NOPE' is not in the file"),
            "{e}"
        );
        let mut bad = map.clone();
        bad[0].1 = "NOPE".into();
        let e = import_c3d(&c, "x", Some(&bad), &t, Scenario::Local, Up::Y).unwrap_err();
        assert!(e.to_string().contains("'NOPE' is not a marker"), "{e}");
        // Without a map the labels are read after their subject's prefix (Vicon's `S1:LFHD`):
        // the dataset of the explicit map, and the summary names the subject.
        let unmapped = |c: &C3d| import_c3d(c, "x.c3d", None, &t, Scenario::Sequence, Up::Y);
        let plain = unmapped(&c).unwrap();
        assert_eq!(plain.report["subject"], "S1");
        assert_eq!(plain.report["map"], imp.report["map"]);
        assert!(imp.report.get("subject").is_none());
        let sparse = |d: &Dataset| match &d.observations {
            Observations::Sparse { values, visible } => (values.clone(), visible.clone()),
            _ => panic!("markers are sparse"),
        };
        assert_eq!(sparse(&plain.dataset), sparse(&imp.dataset));
        assert_eq!(plain.dataset.start_poses, imp.dataset.start_poses);
        // Bare labels map as they are (no subject); labels of two subjects, or bare and
        // prefixed, are refused; labels naming no marker either way ask for a map.
        let relabel = |f: &dyn Fn(usize, &str) -> String| C3d {
            labels: c
                .labels
                .iter()
                .enumerate()
                .map(|(i, l)| f(i, l.strip_prefix("S1:").unwrap()))
                .collect(),
            ..c.clone()
        };
        let bare = unmapped(&relabel(&|_, n| n.to_string())).unwrap();
        assert!(bare.report.get("subject").is_none());
        assert_eq!(sparse(&bare.dataset), sparse(&imp.dataset));
        // A prefix naming fewer than three markers is a rigid body's, not a subject's: ignored.
        let one = unmapped(&relabel(&|i, n| {
            if i < 2 { format!("Body:{n}") } else { n.into() }
        }))
        .unwrap();
        assert!(one.report.get("subject").is_none());
        assert_eq!(one.report["mapped_markers"], t.rig.markers.len() - 2);
        for (labels, needle) in [
            (
                relabel(&|i, n| format!("{}:{n}", if i % 2 == 0 { "A" } else { "B" })),
                "more than one subject ('A:'",
            ),
            (
                relabel(&|i, n| if i < 3 { format!("S1:{n}") } else { n.into() }),
                "more than one subject (bare 36, 'S1:' 3)",
            ),
            (relabel(&|i, _| format!("S1:M{i}")), "--label-map"),
            (
                relabel(&|i, n| {
                    if i < 2 {
                        format!("Body:{n}")
                    } else {
                        format!("S1:M{i}")
                    }
                }),
                "--label-map",
            ),
        ] {
            let e = unmapped(&labels).unwrap_err();
            assert!(e.to_string().contains(needle), "{e}");
        }
        // A file without points (kineticstoolkit's C3DRotationExample holds rotations only).
        let empty = C3d {
            labels: Vec::new(),
            frames: c.frames.iter().map(|_| Vec::new()).collect(),
            ..c.clone()
        };
        let e = import_c3d(&empty, "x", None, &t, Scenario::Local, Up::Y).unwrap_err();
        assert!(e.to_string().contains("holds no 3D points"), "{e}");
    }

    /// `--up z`: the same C3D read as Z-up lands in lfit's Y-up frame by (x, y, z) → (x, z, −y),
    /// point by point, and the report says which axis was up.
    #[test]
    fn a_z_up_c3d_is_turned_into_the_y_up_frame() {
        let t = template();
        let mut pose = vec![0.0; t.layout().dim()];
        pose[..3].copy_from_slice(&[0.3, 0.05, -0.2]);
        let c = C3d::from_bytes(&c3d_of(&t, &pose).to_bytes().unwrap()).unwrap();
        let map = s1_label_map(&t);
        let y = import_c3d(&c, "x", Some(&map), &t, Scenario::Local, Up::Y).unwrap();
        let z = import_c3d(&c, "x", Some(&map), &t, Scenario::Local, Up::Z).unwrap();
        assert_eq!(
            (&y.report["up"], &z.report["up"]),
            (&json!("y"), &json!("z"))
        );
        let (
            Observations::Sparse {
                values: vy,
                visible: by,
            },
            Observations::Sparse {
                values: vz,
                visible: bz,
            },
        ) = (&y.dataset.observations, &z.dataset.observations)
        else {
            panic!()
        };
        assert_eq!(by, bz);
        let mut seen = 0;
        for (fy, fz) in vy.iter().zip(vz) {
            for (a, b) in fy.chunks_exact(3).zip(fz.chunks_exact(3)) {
                assert!((b[0] - a[0]).abs() < 1e-12, "{a:?} -> {b:?}");
                assert!((b[1] - a[2]).abs() < 1e-12, "{a:?} -> {b:?}");
                assert!((b[2] + a[1]).abs() < 1e-12, "{a:?} -> {b:?}");
                seen += usize::from(a[1] != 0.0);
            }
        }
        assert!(seen > 0);
    }

    #[test]
    fn a_label_the_file_repeats_is_mapped_by_its_point_index() {
        let t = template();
        let mut pose = vec![0.0; t.layout().dim()];
        pose[4] = 0.4;
        let mut c = c3d_of(&t, &pose);
        // Points 3 and 5 carry one label (as kineticstoolkit's duplicate_labels.c3d does).
        c.labels[5] = c.labels[3].clone();
        let c = C3d::from_bytes(&c.to_bytes().unwrap()).unwrap();
        let mut map = s1_label_map(&t);
        let e = import_c3d(&c, "x", Some(&map), &t, Scenario::Sequence, Up::Y).unwrap_err();
        assert!(
            e.to_string().contains("points #3 and #5") && e.to_string().contains("\"#3\""),
            "{e}"
        );
        // By index, each of the two goes to its own marker: the import is the file's points.
        map[3].0 = "#3".into();
        map[5].0 = "# 5".into();
        let imp = import_c3d(&c, "x", Some(&map), &t, Scenario::Sequence, Up::Y).unwrap();
        let Observations::Sparse { values, .. } = &imp.dataset.observations else {
            panic!()
        };
        let truth = imp.dataset.sensor.predict_sparse(&t, &pose).values;
        for k in [3, 5] {
            for a in 0..3 {
                assert!((values[0][3 * k + a] - truth[3 * k + a]).abs() < 2e-7);
            }
        }
        assert_ne!(values[0][9..12], values[0][15..18]);
        // The summary tells the two apart by index.
        let mapped = imp.report["map"].to_string();
        assert!(
            mapped.contains(&format!("{} (#3)→{}", c.labels[3], t.rig.markers[3].name))
                && mapped.contains(&format!("{} (#5)→{}", c.labels[5], t.rig.markers[5].name)),
            "{mapped}"
        );
        // An index past the points, one that is not a number, a point mapped twice.
        for (key, want) in [
            ("#39", "the file has 39 points"),
            ("#x", "#K needs a point index"),
            ("#4", "point #4 ('S1:"),
        ] {
            let mut bad = map.clone();
            bad[0].0 = key.into();
            let e = import_c3d(&c, "x", Some(&bad), &t, Scenario::Local, Up::Y).unwrap_err();
            assert!(e.to_string().contains(want), "{key}: {e}");
        }
    }

    #[test]
    fn name_maps_refuse_repeats() {
        let d = tempfile::tempdir().unwrap();
        let p = d.path().join("m.json");
        std::fs::write(&p, r#"{"A": "LFHD", "B": "LFHD"}"#).unwrap();
        let e = read_name_map(&p, ["C3D label", "model marker"]).unwrap_err();
        assert!(
            e.to_string().contains("model marker 'LFHD' appears twice"),
            "{e}"
        );
        std::fs::write(&p, r#"{"A": "LFHD", "A": "RFHD"}"#).unwrap();
        let e = read_name_map(&p, ["C3D label", "model marker"]).unwrap_err();
        assert!(e.to_string().contains("C3D label 'A' appears twice"), "{e}");
        std::fs::write(&p, r#"["A"]"#).unwrap();
        assert!(read_name_map(&p, ["a", "b"]).is_err());
        std::fs::write(&p, r#"{"A": "LFHD"}"#).unwrap();
        assert_eq!(read_name_map(&p, ["a", "b"]).unwrap().len(), 1);
    }

    #[test]
    fn keypoint_import_maps_joints_and_triangulates_a_start() {
        let t = template();
        let cams = default_ring(4);
        let mut pose = vec![0.0; t.layout().dim()];
        pose[..3].copy_from_slice(&[0.1, 0.0, 0.2]);
        pose[4] = -0.5;
        let sensor = Sensor::Keypoints2d(KeypointSetup::new(cams.clone()));
        let p = sensor.predict_sparse(&t, &pose).values;
        let nj = t.rig.num_joints();
        let layout = KeypointLayout::Coco17;
        let map = layout.default_map();
        let tracks: Vec<KeypointTrack> = (0..cams.len())
            .map(|c| {
                let mut kp = vec![[0.0; 3]; 17];
                for &(j, name) in &map {
                    let i = 2 * (c * nj + j);
                    kp[layout.index(name).unwrap()] = [p[i], p[i + 1], 0.9];
                }
                kp[layout.index("right_knee").unwrap()][2] = 0.05; // below the threshold
                KeypointTrack {
                    format: "coco",
                    frames: vec![kp],
                    sources: vec!["c#1".into()],
                    image_sizes: vec![Some((640, 480))],
                    crowded_frames: 0,
                }
            })
            .collect();
        let imp = import_keypoints(
            &tracks,
            cams.clone(),
            layout,
            None,
            0.1,
            30.0,
            &t,
            Scenario::Local,
        )
        .unwrap();
        let Observations::Sparse { values, visible } = &imp.dataset.observations else {
            panic!()
        };
        let knee = lfit_model::skeleton::R_KNEE;
        let hip = lfit_model::skeleton::R_HIP;
        assert!(!visible[0][2 * knee] && visible[0][2 * hip]);
        assert_eq!(values[0][2 * hip], p[2 * hip]);
        // root and head: no COCO keypoint.
        assert!(!visible[0][0] && !visible[0][2 * lfit_model::skeleton::HEAD]);
        for (a, b) in imp.dataset.start_poses[0].iter().zip(&pose) {
            assert!(
                (a - b).abs() < 1e-6,
                "{:?}",
                &imp.dataset.start_poses[0][..6]
            );
        }
        // One camera: a start on the ray, in front of it.
        let one = import_keypoints(
            &tracks[..1],
            cams[..1].to_vec(),
            layout,
            None,
            0.1,
            30.0,
            &t,
            Scenario::Local,
        )
        .unwrap();
        let s = &one.dataset.start_poses[0];
        assert!((DVec3::new(s[0], s[1], s[2]) - DVec3::new(0.1, 0.0, 0.2)).length() < 0.5);
        assert_eq!(one.report["single_view_starts"], 1);
        // Keypoints in the unit square (normalised), or of an image twice the camera's.
        let scaled = |k: f64| -> Vec<KeypointTrack> {
            tracks
                .iter()
                .map(|t| KeypointTrack {
                    frames: vec![
                        t.frames[0]
                            .iter()
                            .map(|&[x, y, c]| [k * x, k * y, c])
                            .collect(),
                    ],
                    image_sizes: vec![None],
                    ..t.clone()
                })
                .collect()
        };
        let with_ring = |tracks: &[KeypointTrack]| {
            import_keypoints(
                tracks,
                cams.clone(),
                layout,
                None,
                0.1,
                30.0,
                &t,
                Scenario::Local,
            )
        };
        let e = with_ring(&scaled(1.0 / 640.0)).unwrap_err();
        assert!(e.to_string().contains("normalised coordinates"), "{e}");
        let e = with_ring(&scaled(4.0)).unwrap_err();
        assert!(e.to_string().contains("another resolution"), "{e}");
        // A fifth more pixels (a tall subject near the edge) still imports.
        with_ring(&scaled(1.2)).unwrap();
        // Wrong sizes and counts.
        let mut small = cams.clone();
        small[2].width = 320;
        let e = import_keypoints(&tracks, small, layout, None, 0.1, 30.0, &t, Scenario::Local)
            .unwrap_err();
        assert!(
            e.to_string().contains("640×480 but camera 2 is 320×480"),
            "{e}"
        );
        let e = import_keypoints(
            &tracks[..2],
            cams.clone(),
            layout,
            None,
            0.1,
            30.0,
            &t,
            Scenario::Local,
        )
        .unwrap_err();
        assert!(
            e.to_string().contains("2 keypoint tracks for 4 cameras"),
            "{e}"
        );
        let bad = vec![("r_knee".to_string(), "left_foot".to_string())];
        let e = import_keypoints(
            &tracks,
            cams,
            layout,
            Some(&bad),
            0.1,
            30.0,
            &t,
            Scenario::Local,
        )
        .unwrap_err();
        assert!(
            e.to_string()
                .contains("'left_foot' is not a coco17 keypoint"),
            "{e}"
        );
    }

    #[test]
    fn imported_datasets_round_trip_without_ground_truth() {
        let t = template();
        let pose = vec![0.0; t.layout().dim()];
        let c = c3d_of(&t, &pose);
        let imp = import_c3d(
            &c,
            "x",
            Some(
                &c.labels
                    .iter()
                    .zip(&t.rig.markers)
                    .map(|(l, m)| (l.clone(), m.name.clone()))
                    .collect::<Vec<_>>(),
            ),
            &t,
            Scenario::Sequence,
            Up::Y,
        )
        .unwrap();
        let d = tempfile::tempdir().unwrap();
        let p = d.path().join("i.npz");
        imp.dataset.save(&p).unwrap();
        let back = Dataset::load(&p).unwrap();
        assert!(!back.has_ground_truth());
        assert_eq!(back.len(), 3);
        assert_eq!(back.start_poses, imp.dataset.start_poses);
        assert_eq!(back.meta.frame_motions[1], "c3d:x#2");
        assert!(back.ground_truth(0).is_none());
    }
}
