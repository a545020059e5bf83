//! Models, parameter files and datasets, below every command: loading the model a command works
//! on, reading parameter vectors from JSON and synthesising a dataset. The commands, the studies
//! and the renderer all build on this module and it on none of them.

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{Context, Result, bail};
use lfit_model::observe::{Modality, Sensor};
use lfit_model::template::Template;
use lfit_model::{BodyShape, build_template};
use lfit_synth::{
    Dataset, MotionFile, NoiseConfig, Observations, PoseSource, Scenario, SynthConfig,
    synthesize_until,
};
use serde_json::{Value, json};

/// The model a command works on: a template directory or a model file in the SMPL-family `.npz`
/// layout (`--template`), or the default body in a named proportion variant (`--shape`).
pub fn load_model(path: Option<&Path>, shape: &str) -> Result<Template> {
    match path {
        Some(path) => {
            let found = crate::shipped::locate(path)?;
            Template::load(&found).with_context(|| format!("template {}", path.display()))
        }
        None if shape == "morphable" => Ok(lfit_model::body::morphable_default_template()?.0),
        None => {
            let body = BodyShape::named(shape)
                .ok_or_else(|| lfit_synth::SynthError::UnknownShape(shape.to_string()))?;
            let id = if shape == "default" {
                "default".to_string()
            } else {
                format!("default+{shape}")
            };
            Ok(build_template(&body, &id)?)
        }
    }
}

/// The `--shape` whose procedural template has id `id` (`default` or `default+<shape>`); `None`
/// for a template loaded from a directory.
pub fn shape_of_template_id(id: &str) -> Option<&str> {
    match id.strip_prefix("default")? {
        "" => Some("default"),
        rest => rest.strip_prefix('+'),
    }
}

/// Settings of `lfit synth` beyond the template.
#[derive(Debug, Clone)]
pub struct SynthArgs {
    pub modality: String,
    pub scenario: String,
    pub source: String,
    pub frames: usize,
    pub seed: u64,
    pub fps: f64,
    pub noise: f64,
    /// Each subject's noise is `noise` times a factor drawn in `[1 − noise_spread, 1]`
    /// (`--noise-spread`, [`SynthConfig::noise_spread`]); 0: every subject with `noise`.
    pub noise_spread: f64,
    /// Comma-separated procedural motions (`--library-motions`; default: all).
    pub motions: Option<String>,
    /// markers: σ of each subject's marker slip in millimetres (`--marker-slip-mm`,
    /// [`SynthConfig::marker_slip`]); 0: the model's marker vertices.
    pub marker_slip_mm: f64,
    /// keypoints2d: σ of each subject's keypoint offsets from the joint centres in millimetres
    /// (`--keypoint-bias-mm`, [`SynthConfig::keypoint_bias`]); 0: the joint centres.
    pub keypoint_bias_mm: f64,
    /// keypoints2d with a bias: the offsets of the synthetic detector of this seed, shared by
    /// every subject (`--keypoint-detector`, [`SynthConfig::keypoint_detector`]).
    pub keypoint_detector: Option<u64>,
    pub out: PathBuf,
}

/// Imported motion files of `lfit synth` (`--motions FILE...`, `--with-library`).
#[derive(Debug, Clone, Default)]
pub struct MotionFilesArgs {
    pub files: Vec<PathBuf>,
    pub with_library: bool,
    /// Transforms of the files' frames (`--mirror`, `--heading`, `--jitter-deg`).
    pub augment: lfit_synth::MotionAugment,
    /// Share of frames with poses uniform within the model's limits instead (`--uniform-share`,
    /// [`SynthConfig::uniform_share`]).
    pub uniform_share: f64,
}

/// Reads imported motion files for `template` (paths as given, relative to the working
/// directory). A missing file whose name lists procedural motions says where those go.
pub fn load_motion_files(files: &[PathBuf], template: &Template) -> Result<Vec<MotionFile>> {
    files
        .iter()
        .map(|path| {
            if !path.exists() {
                let text = path.to_string_lossy();
                let kinds = text
                    .split(',')
                    .all(|m| m.trim().parse::<lfit_synth::motion::MotionKind>().is_ok());
                if kinds {
                    anyhow::bail!(
                        "motion file {text} does not exist: --motions takes motion files (lfit motion import); procedural motions are chosen with --library-motions {text}"
                    );
                }
            }
            Ok(MotionFile::load(path, template)?)
        })
        .collect()
}

/// `lfit synth`: generates a dataset and writes it atomically; `progress` gets frames done.
pub fn synth(
    args: &SynthArgs,
    template: &Template,
    progress: &(dyn Fn(usize) + Sync),
) -> Result<Value> {
    synth_with_motions(args, &MotionFilesArgs::default(), template, progress)
}

/// [`synth`] drawing target poses from imported motion files (next to the library with
/// `with_library`); see [`lfit_synth::dataset::synth`] for how their frames are used.
pub fn synth_with_motions(
    args: &SynthArgs,
    files: &MotionFilesArgs,
    template: &Template,
    progress: &(dyn Fn(usize) + Sync),
) -> Result<Value> {
    synth_with_cameras(args, files, &Rig::Default, template, progress)
}

/// The cameras `lfit synth` observes keypoints2d with.
#[derive(Debug, Clone, PartialEq, Default)]
pub enum Rig {
    /// The modality's default setup (keypoints2d: the default ring's six cameras).
    #[default]
    Default,
    /// `--cameras N`: N cameras on the default ring's circle ([`lfit_model::camera::default_ring`]:
    /// 4 m around the origin, 1.3 m high, evenly spaced starting in front, 640×480, fx = 550).
    Ring(usize),
    /// `--camera FILE`: the calibrated cameras of a camera file, as `lfit data import --camera`
    /// reads them (a user's own rig: its placements, image sizes and focal lengths).
    Cameras(Vec<lfit_model::camera::Camera>),
}

impl Rig {
    /// From `--cameras N` and `--camera FILE` (at most one of them).
    pub fn from_args(cameras: Option<usize>, camera_file: Option<&Path>) -> Result<Rig> {
        match (cameras, camera_file) {
            (Some(_), Some(_)) => bail!("give --cameras N or --camera FILE, not both"),
            (Some(n), None) => Ok(Rig::Ring(n)),
            (None, Some(path)) => Ok(Rig::Cameras(lfit_synth::capture::keypoints::read_cameras(
                path,
            )?)),
            (None, None) => Ok(Rig::Default),
        }
    }
}

/// The sensor of `lfit synth`: the modality's default, or for `keypoints2d` the cameras of
/// `rig` ([`Rig`]); refused for another modality.
pub fn synth_sensor(modality: Modality, rig: &Rig, template: &Template) -> Result<Sensor> {
    let cameras = match rig {
        Rig::Default => return Ok(Sensor::default_for(modality, template)),
        Rig::Ring(0) => bail!("--cameras must be at least 1"),
        Rig::Ring(n) if *n > lfit_model::camera::RigRanges::MAX_CAMERAS => bail!(
            "--cameras {n} is more than {}",
            lfit_model::camera::RigRanges::MAX_CAMERAS
        ),
        Rig::Ring(n) => lfit_model::camera::default_ring(*n),
        Rig::Cameras(cameras) => cameras.clone(),
    };
    if modality != Modality::Keypoints2d {
        bail!("--cameras and --camera set the keypoints2d rig; {modality} takes its default setup");
    }
    Ok(Sensor::Keypoints2d(
        lfit_model::observe::KeypointSetup::new(cameras),
    ))
}

/// [`synth_with_motions`] with the cameras of `rig` (`--cameras N`, `--camera FILE`; see
/// [`synth_sensor`]).
pub fn synth_with_cameras(
    args: &SynthArgs,
    files: &MotionFilesArgs,
    rig: &Rig,
    template: &Template,
    progress: &(dyn Fn(usize) + Sync),
) -> Result<Value> {
    let start = Instant::now();
    let never = std::sync::atomic::AtomicBool::new(false);
    let (dataset, mut summary) = synthesize_dataset(args, files, rig, template, progress, &never)?;
    dataset.save(&args.out)?;
    let bytes = std::fs::metadata(&args.out).map(|m| m.len()).unwrap_or(0);
    summary["out"] = json!(args.out);
    summary["bytes"] = json!(bytes);
    summary["seconds"] = json!(start.elapsed().as_secs_f64());
    Ok(summary)
}

/// `lfit synth` in memory: the dataset [`synth_with_cameras`] writes (`args.out` unused) and its
/// summary, without `out`, `bytes` and `seconds`. Setting `cancel` (from another thread) stops
/// it with an "interrupted" error before the next frame.
pub fn synthesize_dataset(
    args: &SynthArgs,
    files: &MotionFilesArgs,
    rig: &Rig,
    template: &Template,
    progress: &(dyn Fn(usize) + Sync),
    cancel: &std::sync::atomic::AtomicBool,
) -> Result<(Dataset, Value)> {
    let modality: Modality = args.modality.parse()?;
    let sensor = synth_sensor(modality, rig, template)?;
    let scenario: Scenario = args.scenario.parse()?;
    let mut config = SynthConfig::new(modality, scenario, args.frames, args.seed);
    config.source = args.source.parse::<PoseSource>()?;
    config.fps = args.fps;
    config.noise = NoiseConfig::scaled(args.noise)?;
    if let Some(list) = &args.motions {
        config.motions = list
            .split(',')
            .map(|m| {
                m.trim()
                    .parse()
                    .map_err(|_| lfit_synth::SynthError::UnknownMotion(m.trim().to_string()))
            })
            .collect::<Result<_, _>>()?;
    }
    config.motion_files = load_motion_files(&files.files, template)?;
    config.with_library = files.with_library;
    config.motion_augment = files.augment;
    config.uniform_share = files.uniform_share;
    config.noise_spread = args.noise_spread;
    config.marker_slip = args.marker_slip_mm / 1000.0;
    config.keypoint_bias = args.keypoint_bias_mm / 1000.0;
    config.keypoint_detector = args.keypoint_detector;
    config.validate()?;
    let dataset = synthesize_until(&config, template, &sensor, progress, cancel)?;
    let mut summary = json!({
        "modality": modality,
        "scenario": scenario,
        "source": config.source,
        "frames": dataset.len(),
        "seed": args.seed,
        "template": template.id,
        "noise": args.noise,
        "visible_fraction": visible_fraction(&dataset),
    });
    if modality == Modality::Keypoints2d {
        summary["cameras"] = json!(dataset.sensor.cameras().len());
    }
    if !config.motion_files.is_empty() {
        // Which frames came from the files, and how many of them were clamped into the bounds.
        let names = &dataset.meta.frame_motions;
        summary["motion_files"] = json!(config.motion_files);
        summary["frames_from_files"] = json!(names.iter().filter(|m| m.contains(':')).count());
        summary["frames_clamped"] =
            json!(names.iter().filter(|m| m.ends_with("(clamped)")).count());
        summary["fps"] = json!(dataset.meta.config.fps);
    }
    if config.noise_spread > 0.0 {
        summary["noise_spread"] = json!(args.noise_spread);
    }
    if config.marker_slip > 0.0 {
        summary["marker_slip_mm"] = json!(args.marker_slip_mm);
    }
    if config.keypoint_bias > 0.0 {
        summary["keypoint_bias_mm"] = json!(args.keypoint_bias_mm);
    }
    if let Some(seed) = config.keypoint_detector {
        summary["keypoint_detector"] = json!(seed);
    }
    if config.uniform_share > 0.0 {
        summary["frames_uniform"] = json!(
            dataset
                .meta
                .frame_motions
                .iter()
                .filter(|m| *m == "uniform")
                .count()
        );
    }
    Ok((dataset, summary))
}

/// Fraction of observation entries (or scan points, or foreground mask pixels) that are
/// visible (set).
pub fn visible_fraction(dataset: &Dataset) -> f64 {
    let flags: Vec<&Vec<bool>> = match &dataset.observations {
        Observations::Sparse { visible, .. } | Observations::Scan { visible, .. } => {
            visible.iter().collect()
        }
        Observations::Silhouettes { masks } => {
            let (set, total) = masks.iter().flatten().fold((0usize, 0usize), |(s, t), m| {
                (
                    s + m.data.iter().filter(|&&p| p != 0).count(),
                    t + m.data.len(),
                )
            });
            return if total == 0 {
                0.0
            } else {
                set as f64 / total as f64
            };
        }
    };
    let total: usize = flags.iter().map(|v| v.len()).sum();
    let seen: usize = flags.iter().map(|v| v.iter().filter(|&&b| b).count()).sum();
    if total == 0 {
        0.0
    } else {
        seen as f64 / total as f64
    }
}

/// One parameter vector of `template` from JSON values: `pose` (3 + 3J numbers) and optional
/// `shape`/`expression` (at most B/E numbers, zero-padded). `suffix` goes after the field names
/// in errors (`poses[3]`), which also name `path`.
pub fn params_from_json(
    template: &Template,
    pose: &Value,
    shape: Option<&Value>,
    expr: Option<&Value>,
    suffix: &str,
    path: &Path,
) -> Result<Vec<f64>> {
    let layout = template.layout();
    let pd = layout.pose_dim();
    let numbers = |v: &Value, what: &str, len: Option<usize>, max: usize| -> Result<Vec<f64>> {
        let items = v.as_array().with_context(|| {
            format!(
                "{}: {what} is missing or not an array of numbers",
                path.display()
            )
        })?;
        let out = items
            .iter()
            .enumerate()
            .map(|(i, x)| {
                x.as_f64().filter(|x| x.is_finite()).with_context(|| {
                    format!(
                        "{}: {what}[{i}] is not a finite number: {x} is not a number",
                        path.display()
                    )
                })
            })
            .collect::<Result<Vec<f64>>>()?;
        if let Some(n) = len
            && out.len() != n
        {
            bail!(
                "{}: {what} has {} numbers, expected {n} (3 + 3 × {} joints of '{}')",
                path.display(),
                out.len(),
                layout.num_joints(),
                template.id
            );
        }
        if out.len() > max {
            bail!(
                "{}: {what} has {} numbers, but the model '{}' has only {max}",
                path.display(),
                out.len(),
                template.id
            );
        }
        Ok(out)
    };
    let mut params = numbers(pose, &format!("pose{suffix}"), Some(pd), pd)?;
    for (v, what, n) in [
        (shape, "shape", layout.shape),
        (expr, "expression", layout.expression),
    ] {
        let mut b = match v {
            Some(v) => numbers(v, &format!("{what}{suffix}"), None, n)?,
            None => Vec::new(),
        };
        b.resize(n, 0.0);
        params.extend(b);
    }
    Ok(params)
}

/// Reads a parameter file for `template`: `{"pose": [3 + 3J], "shape": [≤ B], "expression":
/// [≤ E]}` or `{"poses": [[...], ...], "shapes": [[...], ...], "expressions": [[...], ...]}`
/// (`shape`/`expression` optional, zero-padded to B/E; longer is an error). Returns full
/// parameter vectors in the model's layout.
pub fn read_params_file(path: &Path, template: &Template) -> Result<Vec<Vec<f64>>> {
    let pd = template.layout().pose_dim();
    let text =
        std::fs::read_to_string(path).with_context(|| format!("cannot read {}", path.display()))?;
    let value: Value = serde_json::from_str(&text)
        .with_context(|| format!("malformed pose JSON {}", path.display()))?;
    match (value.get("pose"), value.get("poses")) {
        (Some(p), None) => Ok(vec![params_from_json(
            template,
            p,
            value.get("shape"),
            value.get("expression"),
            "",
            path,
        )?]),
        (None, Some(Value::Array(list))) if !list.is_empty() => {
            let nth = |key: &str, i: usize| -> Result<Option<&Value>> {
                match value.get(key) {
                    None => Ok(None),
                    Some(Value::Array(rows)) if rows.len() == list.len() => Ok(Some(&rows[i])),
                    Some(_) => bail!(
                        "{}: {key} must be a list with one entry per pose ({})",
                        path.display(),
                        list.len()
                    ),
                }
            };
            list.iter()
                .enumerate()
                .map(|(i, p)| {
                    params_from_json(
                        template,
                        p,
                        nth("shapes", i)?,
                        nth("expressions", i)?,
                        &format!("s[{i}]"),
                        path,
                    )
                })
                .collect()
        }
        _ => bail!(
            "{}: expected {{\"pose\": [{pd} numbers]}} or {{\"poses\": [[{pd} numbers], ...]}}",
            path.display()
        ),
    }
}
