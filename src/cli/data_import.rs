//! `lfit data import`: a user's own captures → an lfit dataset without ground truth.
//!
//! - `--c3d FILE [--label-map MAP.json]`: 3D markers from a C3D file (`lfit_synth::capture::c3d`), each
//!   C3D label that the map names (`{"C3D label": "model marker", ...}`; without a map, labels
//!   equal to a model marker's name, bare or after one subject's `SUBJECT:` prefix) onto that
//!   marker of the model's `markers` modality; gaps and markers no label maps to are invisible
//!   entries. Units from `POINT:UNITS` (mm, cm, m). `--trc FILE`: the same from OpenSim's TRC
//!   text format (`lfit_synth::capture::trc`).
//! - `--keypoints PATH... --layout coco17|body25|coco18|halpe26|wholebody133|blazepose33|panoptic19 --camera CAMERAS.json
//!   [--keypoint-map MAP.json] [--keypoint-scale pixels|image|openpose3|openpose4]`:
//!   2D keypoints (COCO keypoint files or OpenPose frame files/folders, `lfit_synth::capture::keypoints`)
//!   in calibrated cameras as the `keypoints2d` modality; one path per camera in the camera
//!   file's order, or in the order of `--camera-names` (cameras chosen by name or `#K`), or,
//!   with one camera, any number of paths in frame order; a keypoint is seen when its
//!   confidence is above `--min-confidence`. `--reference PATH... [--reference-person ID]`: a
//!   captured 3D reference of the same frames' joints (CMU Panoptic's 3D skeletons, or a TRC/C3D
//!   of 3D keypoints named as `--reference-layout`'s points; `lfit_synth::capture::reference`),
//!   stored with the dataset; `lfit fit` scores against it.
//!
//! The dataset's start poses are the rest pose moved rigidly onto each frame's data
//! (`lfit_synth::capture::import`); the scenario (default `sequence`: each frame starts from the previous
//! frame's fit) picks the free DOFs and the search box of `lfit fit`. Every check runs before
//! anything is written; the file is written to a temporary name and renamed.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail};
use lfit_synth::Scenario;
use lfit_synth::capture::c3d::C3d;
use lfit_synth::capture::import::{import_c3d, import_keypoints, read_name_map};
use lfit_synth::capture::keypoints::{
    CameraFileRig, KeypointLayout, KeypointScale, metres_per_unit, read_camera_file_in, read_track,
    scale_track, undistort_track,
};
use lfit_synth::capture::reference::{attach_reference, read_reference};
use serde_json::{Value, json};

/// `lfit data ...`.
#[derive(Debug, clap::Subcommand)]
pub enum DataCommand {
    /// Turn real observations into an lfit dataset without ground truth (fit it with `lfit fit`,
    /// which then reports energies and observation errors instead of V2V/MPJPE): 3D markers
    /// from a C3D file (--c3d, --label-map) or 2D keypoints from COCO/OpenPose JSON in
    /// calibrated cameras (--keypoints, --layout, --camera).
    Import(ImportArgs),
    /// Write a markers dataset's observations as a C3D file (float points in millimetres, one
    /// label per model marker, invisible markers as gaps, the dataset's frame rate), e.g. to
    /// test `lfit data import` and the fitters on captures with a known ground truth, or to
    /// open synthetic markers in other motion-capture tools.
    ExportC3d(ExportC3dArgs),
    /// Read a camera file as `lfit data import --camera` does (lfit's JSON, OpenCV's keys, a CMU
    /// Panoptic calibration, an anipose / Pose2Sim calibration.toml, an EasyMocap folder), with
    /// --camera-names, --camera-units and --up applied; print where each camera stands in lfit's
    /// Y-up world in metres (its height above y = 0, its distance, its tilt) and write the
    /// cameras in lfit's own JSON (--out): a rig for `lfit synth --camera` (--pinhole: without
    /// the lens distortion, which synthesis does not model) or to check a calibration's unit
    /// and up axis before importing keypoints.
    Cameras(CamerasArgs),
}

/// Arguments of `lfit data cameras`.
#[derive(Debug, clap::Args)]
pub struct CamerasArgs {
    /// Camera file (any form `lfit data import --camera` reads).
    #[arg(long)]
    pub camera: PathBuf,
    /// The cameras to keep, in this order: names or #K (as `lfit data import --camera-names`).
    #[arg(long, value_delimiter = ',', value_name = "NAME,...")]
    pub camera_names: Vec<String>,
    /// Unit of the translations where the file does not say it: m, cm or mm.
    #[arg(long, value_name = "m|cm|mm")]
    pub camera_units: Option<String>,
    /// Up axis of the camera file's world (as `lfit data import --up`).
    #[arg(long, default_value = "y", allow_hyphen_values = true)]
    pub up: String,
    /// Leave out the lens distortion in --out (a pinhole rig for `lfit synth --camera`).
    #[arg(long)]
    pub pinhole: bool,
    /// Output camera file (lfit's JSON keys, metres, Y up; written atomically); default: only
    /// the summary.
    #[arg(long)]
    pub out: Option<PathBuf>,
}

/// Arguments of `lfit data export-c3d`.
#[derive(Debug, clap::Args)]
pub struct ExportC3dArgs {
    /// Markers dataset (.npz from `lfit synth` or `lfit data import`).
    #[arg(long)]
    pub data: PathBuf,
    /// Output C3D file.
    #[arg(long)]
    pub out: PathBuf,
    /// Prefix of every point label (e.g. "S1:" as Vicon writes them); default none.
    #[arg(long, default_value = "")]
    pub label_prefix: String,
    /// Moves every point by this vector before writing, metres: `X,Y,Z` (e.g. `3,0,-2`: a capture
    /// away from the lab's origin, to test that fits follow it); default none.
    #[arg(long, value_name = "X,Y,Z", allow_hyphen_values = true)]
    pub translate: Option<String>,
}

/// `--translate X,Y,Z`: three finite numbers, metres.
fn parse_translation(text: &str) -> Result<[f64; 3]> {
    let parts: Vec<Option<f64>> = text
        .split(',')
        .map(|s| s.trim().parse::<f64>().ok().filter(|x| x.is_finite()))
        .collect();
    match parts.as_slice() {
        [Some(x), Some(y), Some(z)] => Ok([*x, *y, *z]),
        _ => bail!(
            "--translate {text}: expected three finite numbers in metres, X,Y,Z (e.g. 3,0,-2)"
        ),
    }
}

/// Arguments of `lfit data import`.
#[derive(Debug, clap::Args)]
pub struct ImportArgs {
    /// C3D file of 3D marker trajectories (markers modality).
    #[arg(long, conflicts_with_all = ["keypoints", "camera", "layout", "keypoint_map", "trc", "camera_names", "camera_units", "keypoint_scale", "reference", "reference_person", "reference_layout", "reference_map"])]
    pub c3d: Option<PathBuf>,
    /// TRC file of 3D marker trajectories (OpenSim's text format, as OpenCap, Motive and Cortex
    /// write it; markers modality): read as a C3D's points, mapped and fitted alike.
    #[arg(long, conflicts_with_all = ["keypoints", "camera", "layout", "keypoint_map", "camera_names", "camera_units", "keypoint_scale", "reference", "reference_person", "reference_layout", "reference_map"])]
    pub trc: Option<PathBuf>,
    /// JSON object {"C3D label": "model marker", ...} ("#K": the file's point K, counted from 0,
    /// for a label the file repeats); default: C3D labels equal to the model's marker names, bare
    /// or after one subject's prefix (Vicon's SUBJECT:NAME; the summary's "subject").
    #[arg(long)]
    pub label_map: Option<PathBuf>,
    /// Up axis of the C3D's lab frame or of the camera file's world: y, z (points converted
    /// by (x, y, z) -> (x, z, -y), as `lfit motion import --up z`, and the cameras turned with
    /// them, so that the fitted body stands in renders and exports and the floor is lfit's
    /// `--floor` plane: a camera file calibrated on a board laid on the floor is z-up), or the
    /// world's up direction as three numbers x,y,z (the floor plane's normal where the board
    /// was not on the floor, −gravity from a phone's IMU in a camera's own axes): turned onto +y
    /// by the shortest rotation, so a floor n·x = d becomes `--floor contact:d`.
    #[arg(long, default_value = "y", allow_hyphen_values = true)]
    pub up: String,
    /// Keypoint files (COCO keypoint JSON, or OpenPose per-frame JSON files or folders of them):
    /// one per camera in the camera file's order (or --camera-names' order), or any number for a
    /// single camera.
    #[arg(long, num_args = 1..)]
    pub keypoints: Vec<PathBuf>,
    /// Keypoint layout: coco17, body25, coco18 (OpenPose's COCO model), halpe26 (AlphaPose),
    /// wholebody133 (COCO-WholeBody: DWPose, RTMPose), blazepose33 (MediaPipe Pose) or
    /// panoptic19 (CMU Panoptic's coco19).
    #[arg(long)]
    pub layout: Option<String>,
    /// Camera file: {"cameras": [{"fx", "fy", "cx", "cy", "width", "height", "rotation": 3×3
    /// camera-from-world, "translation": [3] metres}, ...]} (OpenCV axes), or per camera
    /// OpenCV's keys: "K", "R" or "rvec", "t" or "tvec", "resolution"; "dist" (OpenCV's k1 k2
    /// p1 p2 [k3 [k4 k5 k6]]) undistorts that camera's keypoints; a CMU Panoptic calibration
    /// file (calibration_<sequence>.json, centimetres) reads as it is; "units": "m"|"cm"|"mm"
    /// gives any file's translation unit. A .toml file is an anipose / Pose2Sim calibration
    /// ([cam_N] name, size, matrix, distortions, rotation, translation); a folder (or its
    /// intri.yml) is EasyMocap's intri.yml + extri.yml (ZJU-MoCap's layout).
    #[arg(long)]
    pub camera: Option<PathBuf>,
    /// Unit of the camera file's translations where the file does not say it: m, cm or mm
    /// (default: metres; a Panoptic file's centimetres; an anipose calibration.toml is in its
    /// board's unit, often mm).
    #[arg(long, value_name = "m|cm|mm")]
    pub camera_units: Option<String>,
    /// The camera file's cameras the keypoints come from, in --keypoints order: each a camera's
    /// "name" (CMU Panoptic's 00_03, ...) or #K, the file's camera K counted from 0; default:
    /// all of them, in the file's order.
    #[arg(long, value_delimiter = ',', value_name = "NAME,...")]
    pub camera_names: Vec<String>,
    /// Unit of the keypoint files' x, y: pixels of the camera's image (default); image:
    /// fractions of its width and height (MediaPipe's normalised landmarks, x·W); openpose3 /
    /// openpose4: OpenPose's --keypoint_scale 3 ([0, 1], x·(W − 1)) / 4 ([−1, 1]).
    #[arg(long, value_name = "pixels|image|openpose3|openpose4")]
    pub keypoint_scale: Option<String>,
    /// JSON object {"model joint": "keypoint name", ...} replacing the layout's default map.
    #[arg(long)]
    pub keypoint_map: Option<PathBuf>,
    /// A captured 3D reference of the same frames' joints, to score fits where no ground truth
    /// exists (`lfit fit` reports MPJPE and PA-MPJPE against it): CMU Panoptic's 3D skeletons
    /// (hdPose3d_stage1_coco19: body3DScene_*.json files or their folder, centimetres, in the
    /// calibration's world), or one TRC or C3D file of 3D keypoints whose labels name the
    /// layout's points (Pose2Sim's triangulation: RHip, right_hip and rHip alike); one frame
    /// per keypoint frame in order; turned with the cameras by --up (Panoptic's world is
    /// y-down: --up 0,-1,0).
    #[arg(long, num_args = 1..)]
    pub reference: Vec<PathBuf>,
    /// The reference body to keep, by its "id" (Panoptic's files, where a frame holds several).
    #[arg(long, value_name = "ID", requires = "reference")]
    pub reference_person: Option<i64>,
    /// The layout a TRC or C3D reference's labels name (default: --layout).
    #[arg(
        long,
        value_name = "LAYOUT",
        requires = "reference",
        conflicts_with = "reference_map"
    )]
    pub reference_layout: Option<String>,
    /// JSON object {"model joint": "reference point", ...} replacing the layout's default map
    /// of the reference (a TRC's or C3D's labels as they are, or Panoptic's point names): for a
    /// reference on another skeleton (Human3.6M's Pelvis, Thorax, ...).
    #[arg(long, value_name = "MAP.json", requires = "reference")]
    pub reference_map: Option<PathBuf>,
    /// Keypoints with a confidence (COCO: visibility flag) at or below this are invisible (the
    /// reference's joints too).
    #[arg(long, default_value_t = 0.1)]
    pub min_confidence: f64,
    /// Frame rate of keypoint files, Hz (C3D files carry theirs).
    #[arg(long, default_value_t = 30.0)]
    pub fps: f64,
    /// Scenario for `lfit fit`: sequence (warm start from the previous frame), local or global.
    #[arg(long, default_value = "sequence")]
    pub scenario: String,
    /// Model: a template directory or an SMPL-layout .npz file; default: the procedural template.
    #[arg(long, visible_alias = "template")]
    pub model: Option<PathBuf>,
    /// Output dataset (.npz).
    #[arg(long)]
    pub out: PathBuf,
}

/// Runs `lfit data ...`.
pub fn run(command: &DataCommand) -> Result<Value> {
    match command {
        DataCommand::Import(args) => import(args),
        DataCommand::ExportC3d(args) => export_c3d(args),
        DataCommand::Cameras(args) => cameras(args),
    }
}

fn check_out(out: &Path) -> Result<()> {
    if out.is_dir() {
        bail!("--out {} is a directory, expected a file", out.display());
    }
    Ok(())
}

/// `lfit data export-c3d`.
pub fn export_c3d(args: &ExportC3dArgs) -> Result<Value> {
    check_out(&args.out)?;
    let shift = match &args.translate {
        Some(text) => parse_translation(text)?,
        None => [0.0; 3],
    };
    let dataset = lfit_synth::Dataset::load(&args.data)
        .with_context(|| format!("dataset {}", args.data.display()))?;
    let names = match &dataset.sensor {
        lfit_model::observe::Sensor::Markers(m) => m.names.clone(),
        other => bail!(
            "dataset {} holds {} observations; only a markers dataset can be written as C3D",
            args.data.display(),
            other.modality().name()
        ),
    };
    let lfit_synth::Observations::Sparse { values, visible } = &dataset.observations else {
        bail!(
            "dataset {} has no sparse marker observations",
            args.data.display()
        );
    };
    let fps = dataset.meta.config.fps;
    if !(fps.is_finite() && fps > 0.0) {
        bail!(
            "dataset {} has frame rate {fps}, not a positive number",
            args.data.display()
        );
    }
    let mut gaps = 0usize;
    let mut frames = Vec::with_capacity(values.len());
    for (f, (v, b)) in values.iter().zip(visible).enumerate() {
        if v.len() != 3 * names.len() || b.len() != v.len() {
            bail!(
                "dataset {} frame {f} has {} values for {} markers",
                args.data.display(),
                v.len(),
                names.len()
            );
        }
        let mut row = Vec::with_capacity(names.len());
        for k in 0..names.len() {
            let p = [
                v[3 * k] + shift[0],
                v[3 * k + 1] + shift[1],
                v[3 * k + 2] + shift[2],
            ];
            if b[3 * k] && p.iter().all(|x| x.is_finite()) {
                row.push(Some(lfit_synth::capture::c3d::C3dPoint {
                    position: p.map(|x| x * 1e3),
                    residual: 0.0,
                    cameras: 0,
                }));
            } else {
                gaps += 1;
                row.push(None);
            }
        }
        frames.push(row);
    }
    let c3d = C3d {
        processor: lfit_synth::capture::c3d::Processor::Intel,
        labels: names
            .iter()
            .map(|n| format!("{}{n}", args.label_prefix))
            .collect(),
        units: "mm".into(),
        scale: -1.0,
        rate: fps,
        first_frame: 1,
        analog_per_frame: 0,
        frames,
        non_finite: 0,
    };
    let bytes = c3d
        .to_bytes()
        .with_context(|| format!("C3D file {}", args.out.display()))?;
    lfit_model::template::write_atomic(&args.out, &bytes)
        .with_context(|| format!("C3D file {}", args.out.display()))?;
    Ok(json!({
        "out": args.out,
        "data": args.data,
        "frames": values.len(),
        "markers": names.len(),
        "gaps": gaps,
        "fps": fps,
        "units": "mm",
        "translate_m": shift,
    }))
}

/// The cameras of a camera file with `--camera-units`, `--camera-names` and `--up` applied: the
/// chosen ones (default all) in that order, in lfit's Y-up world, translations in metres.
fn load_cameras(
    path: &Path,
    units: Option<&str>,
    names: &[String],
    up: lfit_synth::motion::retarget::Up,
) -> Result<CameraFileRig> {
    if let Some(u) = units
        && metres_per_unit(u).is_none()
    {
        bail!("--camera-units {u}: expected m, cm or mm");
    }
    let mut rig = read_camera_file_in(path, units)?;
    if !names.is_empty() {
        rig = rig
            .select(names)
            .with_context(|| format!("--camera-names, camera file {}", path.display()))?;
    }
    if up != lfit_synth::motion::retarget::Up::Y {
        // The cameras turned with the world (y up: the file as it is, to the bit).
        for c in &mut rig.cameras {
            *c = c.in_rotated_world(up.to_lfit());
        }
    }
    Ok(rig)
}

/// `lfit data cameras`.
pub fn cameras(args: &CamerasArgs) -> Result<Value> {
    if let Some(out) = &args.out {
        check_out(out)?;
    }
    let up: lfit_synth::motion::retarget::Up = args.up.parse().map_err(anyhow::Error::msg)?;
    let rig = load_cameras(
        &args.camera,
        args.camera_units.as_deref(),
        &args.camera_names,
        up,
    )?;
    let list: Vec<Value> = rig
        .cameras
        .iter()
        .enumerate()
        .map(|(i, c)| {
            let centre = c.center();
            // The optical axis (+z of the camera) in the world: its tilt above the horizon.
            let axis = glam::DVec3::from_array(c.rotation[2]);
            json!({
                "name": rig.names[i],
                "centre_m": centre.to_array(),
                "height_m": centre.y,
                "distance_m": centre.x.hypot(centre.z),
                "tilt_deg": axis.y.clamp(-1.0, 1.0).asin().to_degrees(),
                "fx": c.fx,
                "image": [c.width, c.height],
                "distortion": rig.distortion[i].map(|d| d.to_opencv()),
            })
        })
        .collect();
    if let Some(out) = &args.out {
        let text = lfit_synth::capture::keypoints::camera_file_json(&rig, args.pinhole);
        lfit_model::template::write_atomic(out, text.as_bytes())
            .with_context(|| format!("camera file {}", out.display()))?;
    }
    Ok(json!({
        "camera": args.camera,
        "count": rig.cameras.len(),
        "cameras": list,
        "image_size_from_principal_point": rig.size_guessed_names(),
        "out": args.out,
        "pinhole": args.pinhole,
    }))
}

/// `lfit data import`.
pub fn import(args: &ImportArgs) -> Result<Value> {
    check_out(&args.out)?;
    let (dataset, mut summary) = import_dataset(args, None)?;
    dataset.save(&args.out)?;
    summary["out"] = json!(args.out);
    Ok(summary)
}

/// `lfit data import` in memory: the dataset [`import`] writes (`args.out` unused) and its
/// summary without `out`. `model` replaces `args.model` (the model the data is imported for).
pub fn import_dataset(
    args: &ImportArgs,
    model: Option<&lfit_model::template::Template>,
) -> Result<(lfit_synth::Dataset, Value)> {
    let load = || -> Result<std::borrow::Cow<'_, lfit_model::template::Template>> {
        Ok(match model {
            Some(t) => std::borrow::Cow::Borrowed(t),
            None => {
                std::borrow::Cow::Owned(crate::data::load_model(args.model.as_deref(), "default")?)
            }
        })
    };
    let scenario: Scenario = args.scenario.parse()?;
    let up: lfit_synth::motion::retarget::Up = args.up.parse().map_err(anyhow::Error::msg)?;
    let markers = match (&args.c3d, &args.trc) {
        (Some(_), Some(_)) => bail!("give either --c3d or --trc, not both"),
        (Some(p), None) => Some((p, false)),
        (None, Some(p)) => Some((p, true)),
        (None, None) => None,
    };
    if args.reference_person.is_some() && args.reference.is_empty() {
        bail!("--reference-person chooses a body of the --reference files: give --reference");
    }
    if args.reference_layout.is_some() && args.reference.is_empty() {
        bail!("--reference-layout names the --reference file's labels: give --reference");
    }
    if args.reference_map.is_some() && args.reference.is_empty() {
        bail!("--reference-map maps the --reference file's points: give --reference");
    }
    if markers.is_some() && !args.reference.is_empty() {
        bail!("--reference scores the fits of 2D keypoints: give it with --keypoints");
    }
    if markers.is_none() && args.label_map.is_some() {
        bail!("--label-map maps a marker file's labels: give it with --c3d or --trc");
    }
    let (imported, source) = match (markers, args.keypoints.is_empty()) {
        (Some(_), false) => bail!("give either --c3d/--trc or --keypoints, not both"),
        (None, true) => {
            bail!("lfit data import needs --c3d FILE, --trc FILE or --keypoints FILE...")
        }
        (Some((path, trc)), true) => {
            let map = args
                .label_map
                .as_deref()
                .map(|p| {
                    read_name_map(
                        &crate::shipped::locate_or_given(p),
                        [if trc { "TRC label" } else { "C3D label" }, "model marker"],
                    )
                })
                .transpose()
                .context("label map")?;
            let template = load()?;
            let kind = if trc { "TRC" } else { "C3D" };
            let c3d = if trc {
                lfit_synth::capture::trc::read_trc(path)
            } else {
                C3d::read(path)
            }
            .with_context(|| format!("{kind} file {}", path.display()))?;
            let name = path.file_name().map_or_else(
                || path.display().to_string(),
                |n| n.to_string_lossy().into(),
            );
            let mut imported = import_c3d(&c3d, &name, map.as_deref(), &template, scenario, up)
                .with_context(|| format!("{kind} file {}", path.display()))?;
            if trc {
                // Text points: no C3D storage format to report.
                imported.report["format"] = json!("trc");
                if let Some(r) = imported.report.as_object_mut() {
                    r.remove("point_format");
                }
                (imported, json!({ "trc": path }))
            } else {
                (imported, json!({ "c3d": path }))
            }
        }
        (None, false) => {
            let Some(layout) = &args.layout else {
                bail!(
                    "--keypoints needs --layout coco17|body25|coco18|halpe26|wholebody133|blazepose33|panoptic19"
                );
            };
            let layout: KeypointLayout = layout.parse()?;
            let Some(camera) = &args.camera else {
                bail!("--keypoints needs --camera FILE (the calibrated cameras of the keypoints)");
            };
            if !(args.fps.is_finite() && args.fps > 0.0) {
                bail!("--fps must be positive (got {})", args.fps);
            }
            let rig = load_cameras(camera, args.camera_units.as_deref(), &args.camera_names, up)?;
            let sizes_from_principal_point = rig.size_guessed_names();
            let CameraFileRig {
                cameras,
                distortion,
                names,
                ..
            } = rig;
            let map = args
                .keypoint_map
                .as_deref()
                .map(|p| read_name_map(p, ["model joint", "keypoint"]))
                .transpose()
                .context("keypoint map")?;
            let groups: Vec<Vec<PathBuf>> = if args.keypoints.len() == cameras.len() {
                args.keypoints.iter().map(|p| vec![p.clone()]).collect()
            } else if cameras.len() == 1 {
                vec![args.keypoints.clone()]
            } else {
                bail!(
                    "{} keypoint paths for {} cameras: give one file or folder per camera, in the {} order",
                    args.keypoints.len(),
                    cameras.len(),
                    if args.camera_names.is_empty() {
                        "camera file's (or choose its cameras with --camera-names)"
                    } else {
                        "--camera-names"
                    }
                );
            };
            let scale: KeypointScale = match &args.keypoint_scale {
                Some(s) => s.parse()?,
                None => KeypointScale::Pixels,
            };
            let mut tracks = groups
                .iter()
                .map(|g| read_track(g, layout))
                .collect::<Result<Vec<_>, _>>()?;
            for (track, camera) in tracks.iter_mut().zip(&cameras) {
                scale_track(track, camera, scale);
            }
            // Keypoints of a camera with lens distortion, as its pinhole camera sees them.
            let undistorted = distortion.iter().filter(|d| d.is_some()).count();
            for ((track, camera), d) in tracks.iter_mut().zip(&cameras).zip(&distortion) {
                if let Some(d) = d {
                    undistort_track(track, camera, d)?;
                }
            }
            // The reference is read before the model loads and the starts are solved: a bad file
            // fails first.
            let reference = if args.reference.is_empty() {
                None
            } else {
                let (reference_layout, given) = match &args.reference_layout {
                    Some(l) => (l.parse::<KeypointLayout>()?, true),
                    None => (layout, false),
                };
                Some(
                    read_reference(
                        &args.reference,
                        reference_layout,
                        given,
                        args.reference_person,
                        args.reference_map.is_some(),
                    )
                    .context("--reference")?,
                )
            };
            let reference_map = args
                .reference_map
                .as_deref()
                .map(|p| read_name_map(p, ["model joint", "reference point"]))
                .transpose()
                .context("--reference-map")?;
            let template = load()?;
            let mut imported = import_keypoints(
                &tracks,
                cameras,
                layout,
                map.as_deref(),
                args.min_confidence,
                args.fps,
                &template,
                scenario,
            )?;
            if let Some(track) = &reference {
                attach_reference(
                    &mut imported,
                    track,
                    &args.reference[0],
                    &template,
                    up.to_lfit(),
                    args.min_confidence,
                    reference_map.as_deref(),
                )
                .context("--reference")?;
            }
            let mut source = json!({ "keypoints": args.keypoints, "camera": camera });
            if reference.is_some() {
                source["reference"] = json!(args.reference);
            }
            if undistorted > 0 {
                source["undistorted_cameras"] = json!(undistorted);
            }
            if !args.camera_names.is_empty() {
                source["camera_names"] = json!(names);
            }
            if let Some(u) = &args.camera_units {
                source["camera_units"] = json!(u);
            }
            if scale != KeypointScale::Pixels {
                source["keypoint_scale"] = json!(scale.name());
            }
            if !sizes_from_principal_point.is_empty() {
                source["image_size_from_principal_point"] = json!(sizes_from_principal_point);
            }
            (imported, source)
        }
    };
    let dataset = imported.dataset;
    let summary = json!({
        "source": source,
        "modality": dataset.modality().name(),
        "scenario": scenario.name(),
        "frames": dataset.len(),
        "template": dataset.meta.template_id,
        "ground_truth": false,
        "visible_fraction": crate::data::visible_fraction(&dataset),
        "import": imported.report,
    });
    Ok((dataset, summary))
}
