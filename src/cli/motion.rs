//! `lfit motion import` and `lfit motion export` (SPEC §3a "Motions", §10): BVH clips retargeted
//! through a joint-name map and AMASS-layout `.npz` motions become lfit motion files
//! ([`lfit_synth::motion::file::MotionClip`]); motion files and fitted sequences become BVH.
//! `lfit motion coverage` measures how well training motions cover an evaluation motion
//! ([`lfit_synth::motion::coverage`]). `lfit motion prior` fits a Gaussian pose prior to motion
//! files ([`lfit_model::energy::PosePrior`]) and writes it as an energy configuration. Every input is read and checked before anything is written;
//! outputs are written atomically.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail};
use lfit_model::template::{Template, write_atomic};
use lfit_synth::motion::file::{MotionClip, export_bvh, read_amass};
use lfit_synth::motion::rest_pose::{RestPose, rebase, retarget_neutral};
use lfit_synth::motion::retarget::{
    JointMap, RetargetOptions, RootMode, Units, Up, read_bvh, retarget,
};
use serde_json::{Value, json};

/// `lfit motion ...`.
#[derive(Debug, Clone, clap::Subcommand)]
pub enum MotionCommand {
    /// Import a motion as an lfit motion file (.npz: poses (T, P) in the model's layout, fps,
    /// source, the model's signature): a BVH clip retargeted through a joint-name map by world
    /// rotation relative to each skeleton's rest pose (any channel order, cm or m, Y- or Z-up),
    /// or an AMASS-layout .npz (poses (T, 3J), trans, betas, mocap_framerate) for a model with
    /// the same skeleton. Prints a JSON summary (for BVH: the mean and minimum cosine between
    /// the BVH's world bones and the model's posed bones).
    Import(ImportArgs),
    /// Export a motion file or the fitted sequence of `lfit fit` as BVH: the model's skeleton
    /// (OFFSETs in cm), 6 channels at the root, Zrotation Xrotation Yrotation at every joint.
    Export(ExportArgs),
    /// How well training motions cover an evaluation motion: per joint axis (each axis-angle
    /// component of each joint's rotation) the 1st and 99th percentiles of the training frames,
    /// and the fraction of evaluation frames whose every non-root joint axis lies within them
    /// (the root orientation, i.e. the heading, is reported separately). Prints a JSON summary
    /// with the worst joint axes.
    Coverage(CoverageArgs),
    /// Fit a pose prior to motion files: a Gaussian (the mean and covariance, plus ε² I, of every
    /// non-root joint's axis-angle rotation over their frames) or, with --components K, SMPLify's
    /// mixture of K Gaussians fitted by EM. Writes an energy configuration with the prior (the
    /// gradient variant's defaults, or --energy's) for --energy of `lfit fit` and the other
    /// commands: the energy then adds `weights.pose_prior` × the squared Mahalanobis distance of
    /// the pose's rotations (to the nearest component by its likelihood, plus that component's
    /// constant). Prints a JSON summary.
    Prior(PriorArgs),
}

/// Settings of `lfit motion import`.
#[derive(Debug, Clone, clap::Args)]
pub struct ImportArgs {
    /// BVH file to retarget.
    #[arg(long, conflicts_with = "amass")]
    pub bvh: Option<PathBuf>,
    /// Joint-name map for --bvh: JSON {"BvhJoint": "model_joint", ...} (or {"joints": {...}}),
    /// or text lines `BvhJoint model_joint`; default: every BVH joint onto the model joint of the
    /// same name (e.g. a BVH written by `lfit motion export`).
    #[arg(long)]
    pub map: Option<PathBuf>,
    /// AMASS-layout .npz for a model with the same skeleton.
    #[arg(long)]
    pub amass: Option<PathBuf>,
    /// Model file (SMPL-family .npz layout) or template directory; default: the procedural
    /// template.
    #[arg(long, visible_alias = "template")]
    pub model: Option<PathBuf>,
    /// Output motion file (.npz).
    #[arg(long)]
    pub out: PathBuf,
    /// Units of the BVH: cm, m, or auto (cm when the rest skeleton is taller than 3 units).
    #[arg(long, default_value = "auto")]
    pub units: String,
    /// Up axis of the input: y, z (converted by (x, y, z) -> (x, z, -y): a Z-up capture whose
    /// subject faces -y then faces +z), or any up direction as three numbers x,y,z (turned onto
    /// +y by the shortest rotation).
    #[arg(long, default_value = "y", allow_hyphen_values = true)]
    pub up: String,
    /// BVH root height: floor (the BVH's y = 0 is the ground; the anchor's height and steps are
    /// scaled by the model's over the BVH's leg length (bone lengths from the anchor to the lowest
    /// mapped joint)) or rest (displacement from the BVH's rest pose, unscaled).
    #[arg(long, default_value = "floor")]
    pub root: String,
    /// Keep every N-th frame (frames 0, N, 2N, ...); the frame rate becomes fps / N.
    #[arg(long, default_value_t = 1, value_name = "N")]
    pub stride: usize,
    /// Rest pose of the BVH (JSON: world rotations of BVH joints such as
    /// {"joints": {"LeftThigh": "Z 180", "LeftFoot": "Y 180 X -90"}}, unnamed joints turning
    /// with their parent), for files whose zero-channel pose is not a usable rest pose (every
    /// bone along one axis); the clip is re-expressed relative to it before retargeting. Its
    /// optional "neutral": [BVH joints] take the identity rest alignment (their rest pose is the
    /// model's, e.g. an upright trunk) instead of the alignment by bone directions.
    #[arg(long, value_name = "FILE")]
    pub rest_pose: Option<PathBuf>,
}

/// Settings of `lfit motion export`.
#[derive(Debug, Clone, clap::Args)]
pub struct ExportArgs {
    /// Output format: bvh.
    #[arg(long)]
    pub format: String,
    /// Model file or template directory; default: the procedural template.
    #[arg(long, visible_alias = "template")]
    pub model: Option<PathBuf>,
    /// Motion file written by `lfit motion import`.
    #[arg(long, conflicts_with = "fit")]
    pub motion: Option<PathBuf>,
    /// Result JSON of `lfit fit` (frames in order), or {"pose"} / {"poses"}.
    #[arg(long)]
    pub fit: Option<PathBuf>,
    /// Frame rate (default: the motion file's, 30 for --fit).
    #[arg(long)]
    pub fps: Option<f64>,
    /// Output .bvh file.
    #[arg(long)]
    pub out: PathBuf,
}

/// Settings of `lfit motion coverage`.
#[derive(Debug, Clone, clap::Args)]
pub struct CoverageArgs {
    /// Training motion files (written by `lfit motion import`).
    #[arg(long, num_args = 1.., value_name = "FILE")]
    pub train: Vec<PathBuf>,
    /// Datasets (`lfit synth` output for the same model) whose ground-truth poses join the
    /// training frames, e.g. frames of the procedural library or of a training run's mix.
    #[arg(long = "train-data", num_args = 1.., value_name = "FILE")]
    pub train_data: Vec<PathBuf>,
    /// Evaluation motion file.
    #[arg(long, value_name = "FILE")]
    pub eval: PathBuf,
    /// Model the motions must be made for; default: the first training file's skeleton (every
    /// file must share it).
    #[arg(long, visible_alias = "template")]
    pub model: Option<PathBuf>,
    /// Slack (radians) around each [p1, p99] range, for joints that are constant up to rounding.
    #[arg(long, default_value_t = 1e-6)]
    pub tolerance: f64,
    /// How many of the worst joint axes to list.
    #[arg(long, default_value_t = 10)]
    pub worst: usize,
    /// Count only these joints (comma-separated model joint names) in the covered fraction,
    /// e.g. those that the training and the evaluation motions' joint maps both drive; default:
    /// every joint but the root. Statistics are listed for all.
    #[arg(long, value_delimiter = ',', value_name = "JOINTS")]
    pub joints: Vec<String>,
}

/// `lfit motion prior`'s default ε in degrees ([`lfit_model::energy::DEFAULT_PRIOR_EPSILON`]).
pub const DEFAULT_EPSILON_DEG: f64 = 3.0;

/// Settings of `lfit motion prior`.
#[derive(Debug, Clone, clap::Args)]
pub struct PriorArgs {
    /// Motion files (written by `lfit motion import`) for the model: the poses the prior is
    /// fitted to. Keep evaluation clips out of them.
    #[arg(long, num_args = 1.., value_name = "FILE", required_unless_present = "data")]
    pub motions: Vec<PathBuf>,
    /// Datasets (`lfit synth` output for the same model) whose ground-truth poses join the
    /// motions' frames, e.g. frames of the procedural library.
    #[arg(long, num_args = 1.., value_name = "FILE")]
    pub data: Vec<PathBuf>,
    /// Model the motions are made for (a model file or template directory); default: the
    /// procedural template.
    #[arg(long, visible_alias = "template")]
    pub model: Option<PathBuf>,
    /// Keep every N-th frame of each motion and dataset (frames 0, N, 2N, ...).
    #[arg(long, default_value_t = 1, value_name = "N")]
    pub stride: usize,
    /// ε in degrees: the covariance is Σ + ε² I (an axis the motions never move is held to ε).
    #[arg(long = "epsilon-deg", default_value_t = DEFAULT_EPSILON_DEG, value_name = "DEG")]
    pub epsilon_deg: f64,
    /// Weight of the prior in the energy (`weights.pose_prior`); default: --modality's (markers
    /// 0.01, keypoints2d 0.001; required for any other modality).
    #[arg(long)]
    pub weight: Option<f64>,
    /// The sensor the energy is for, which sets the default --weight (markers, keypoints2d; other
    /// modalities need --weight); default markers.
    #[arg(long, default_value = "markers")]
    pub modality: String,
    /// Gaussians in the prior: 1 (default) or a mixture fitted by EM (SMPLify uses 8).
    #[arg(long, default_value_t = 1, value_name = "K")]
    pub components: usize,
    /// Seed of the mixture's k-means++ start (same seed and frames, same prior).
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Motion files kept out of the fit (e.g. a validation subject): the summary reports the
    /// prior's mean log-likelihood and term on their frames (every frame), to compare priors.
    #[arg(long, num_args = 1.., value_name = "FILE")]
    pub held_out: Vec<PathBuf>,
    /// Energy configuration to add the prior to; default: the gradient variant's defaults.
    #[arg(long)]
    pub energy: Option<PathBuf>,
    /// Output energy configuration (.json), written atomically.
    #[arg(long)]
    pub out: PathBuf,
}

/// Runs a `lfit motion` subcommand.
pub fn run(command: &MotionCommand) -> Result<Value> {
    match command {
        MotionCommand::Import(a) => import(a),
        MotionCommand::Export(a) => export(a),
        MotionCommand::Coverage(a) => coverage(a),
        MotionCommand::Prior(a) => prior(a),
    }
}

fn load(model: Option<&Path>) -> Result<Template> {
    crate::data::load_model(model, "default")
}

fn file_name(path: &Path) -> String {
    path.file_name().map_or_else(
        || path.display().to_string(),
        |n| n.to_string_lossy().into_owned(),
    )
}

/// `lfit motion import`.
pub fn import(args: &ImportArgs) -> Result<Value> {
    let (clip, mut summary) = import_clip(args, None)?;
    clip.write(&args.out)?;
    summary["out"] = json!(args.out.display().to_string());
    Ok(summary)
}

/// `lfit motion import` in memory: the motion [`import`] writes (`args.out` unused) and its
/// summary without `out`. `model` replaces `args.model` (the model retargeted onto).
pub fn import_clip(args: &ImportArgs, model: Option<&Template>) -> Result<(MotionClip, Value)> {
    let up: Up = args.up.parse().map_err(anyhow::Error::msg)?;
    if args.stride == 0 {
        bail!("--stride 0: keep every N-th frame needs N of at least 1");
    }
    if args.rest_pose.is_some() && args.bvh.is_none() {
        bail!("--rest-pose applies to --bvh");
    }
    let template = match model {
        Some(t) => std::borrow::Cow::Borrowed(t),
        None => std::borrow::Cow::Owned(load(args.model.as_deref())?),
    };
    let (clip, extra, source_frames) = match (&args.bvh, &args.amass) {
        (Some(bvh_path), None) => {
            let units: Units = args.units.parse().map_err(anyhow::Error::msg)?;
            let root: RootMode = args.root.parse().map_err(anyhow::Error::msg)?;
            let mut bvh = read_bvh(bvh_path)?;
            let mut neutral = Vec::new();
            if let Some(path) = &args.rest_pose {
                let rest = RestPose::read(path)?;
                bvh =
                    rebase(&bvh, &rest).with_context(|| format!("rest pose {}", path.display()))?;
                neutral = rest.neutral;
            }
            let source_frames = bvh.frames.len();
            if args.stride > 1 {
                bvh.frames = bvh.frames.into_iter().step_by(args.stride).collect();
                bvh.frame_time *= args.stride as f64;
            }
            let map = match &args.map {
                Some(m) => JointMap::read(&crate::shipped::locate_or_given(m))?,
                None => JointMap::identity(&bvh),
            };
            let options = RetargetOptions {
                units,
                up,
                root,
                shape: Vec::new(),
            };
            let r = if neutral.is_empty() {
                retarget(&bvh, &map, &template, &options)
            } else {
                retarget_neutral(&bvh, &map, &template, &options, &neutral)
            }
            .with_context(|| format!("retargeting {}", bvh_path.display()))?;
            let extra = json!({
                "metres_per_unit": r.scale,
                "root_scale": r.root_scale,
                "joints_mapped": r.mapped,
                "bones_compared": r.bones,
                "bone_cosine_mean": r.cosine_mean,
                "bone_cosine_min": r.cosine_min,
            });
            let clip = MotionClip {
                poses: r.poses,
                fps: r.fps,
                source: format!(
                    "bvh:{} map:{}{}{}",
                    file_name(bvh_path),
                    args.map
                        .as_deref()
                        .map_or_else(|| "identity".to_string(), file_name),
                    args.rest_pose
                        .as_deref()
                        .map_or_else(String::new, |p| format!(" rest:{}", file_name(p))),
                    if args.stride > 1 {
                        format!(" stride:{}", args.stride)
                    } else {
                        String::new()
                    }
                ),
                model: template.signature(),
            };
            (clip, extra, source_frames)
        }
        (None, Some(amass_path)) => {
            if args.map.is_some() {
                bail!(
                    "--map applies to --bvh; an AMASS file is for a model with the same skeleton"
                );
            }
            let (poses, fps) = read_amass(amass_path, &template, up)?;
            let source_frames = poses.len();
            let poses: Vec<Vec<f64>> = poses.into_iter().step_by(args.stride).collect();
            let clip = MotionClip {
                poses,
                fps: fps / args.stride as f64,
                source: if args.stride > 1 {
                    format!("amass:{} stride:{}", file_name(amass_path), args.stride)
                } else {
                    format!("amass:{}", file_name(amass_path))
                },
                model: template.signature(),
            };
            (clip, json!({}), source_frames)
        }
        (Some(_), Some(_)) => bail!("give either --bvh or --amass, not both"),
        (None, None) => {
            bail!("lfit motion import needs --bvh FILE (with --map FILE) or --amass FILE")
        }
    };
    let mut summary = json!({
        "model": template.id,
        "frames": clip.poses.len(),
        "fps": clip.fps,
        "stride": args.stride,
        "source_frames": source_frames,
        "source": clip.source,
    });
    if let (Value::Object(s), Value::Object(e)) = (&mut summary, extra) {
        s.extend(e);
    }
    Ok((clip, summary))
}

/// `lfit motion export`.
pub fn export(args: &ExportArgs) -> Result<Value> {
    if args.format != "bvh" {
        bail!("unknown motion format '{}' (expected bvh)", args.format);
    }
    if let Some(fps) = args.fps
        && !(fps.is_finite() && fps > 0.0)
    {
        bail!("--fps {fps} is not a positive number");
    }
    let template = load(args.model.as_deref())?;
    let (poses, fps) = match (&args.motion, &args.fit) {
        (Some(m), None) => {
            let clip = MotionClip::read(m)?;
            clip.check_model(&template)
                .with_context(|| format!("motion {}", m.display()))?;
            (clip.poses, args.fps.unwrap_or(clip.fps))
        }
        (None, Some(f)) => {
            let fitted = crate::cli::export::read_fitted_poses(f, &template)?;
            let poses = fitted.frames.into_iter().map(|(_, p)| p).collect();
            (poses, args.fps.unwrap_or(30.0))
        }
        (Some(_), Some(_)) => bail!("give either --motion or --fit, not both"),
        (None, None) => bail!("lfit motion export needs --motion FILE or --fit FILE"),
    };
    let bvh = export_bvh(&template, &poses, fps)?;
    write_atomic(&args.out, bvh.write(8).as_bytes())?;
    Ok(json!({
        "out": args.out.display().to_string(),
        "format": "bvh",
        "model": template.id,
        "frames": poses.len(),
        "fps": fps,
        "joints": bvh.joints.len(),
        "units": "cm",
        "rotation_order": lfit_synth::motion::file::EXPORT_ORDER.name(),
    }))
}

/// `lfit motion coverage`.
pub fn coverage(args: &CoverageArgs) -> Result<Value> {
    if args.train.is_empty() && args.train_data.is_empty() {
        bail!(
            "lfit motion coverage needs --train FILE [FILE ...] (training motion files) or --train-data FILE [FILE ...] (lfit synth datasets)"
        );
    }
    if !(args.tolerance.is_finite() && args.tolerance >= 0.0) {
        bail!(
            "--tolerance {} is not a non-negative number",
            args.tolerance
        );
    }
    let template = args.model.as_deref().map(|m| load(Some(m))).transpose()?;
    let mut train = Vec::with_capacity(args.train.len());
    for path in &args.train {
        train.push(MotionClip::read(path)?);
    }
    let eval = MotionClip::read(&args.eval)?;
    let layout = match &template {
        Some(t) => t.layout(),
        None => train
            .first()
            .map_or_else(|| eval.model.layout.clone(), |c| c.model.layout.clone()),
    };
    let model_id = template.as_ref().map_or_else(
        || {
            train
                .first()
                .map_or_else(|| eval.model.id.clone(), |c| c.model.id.clone())
        },
        |t| t.id.clone(),
    );
    let mut data_poses: Vec<Vec<Vec<f64>>> = Vec::with_capacity(args.train_data.len());
    for path in &args.train_data {
        data_poses.push(ground_truth_poses(
            path,
            &model_id,
            layout.pose_dim(),
            "count",
        )?);
    }
    for (path, clip) in args.train.iter().zip(&train).chain([(&args.eval, &eval)]) {
        if clip.model.layout != layout {
            bail!(
                "motion {} was made for model '{}' ({} joints), not for {} ({} joints); every motion must be for the same model",
                path.display(),
                clip.model.id,
                clip.model.layout.num_joints(),
                match (&template, args.train.first()) {
                    (None, Some(first)) => format!("model '{model_id}' of {}", first.display()),
                    _ => format!("model '{model_id}'"),
                },
                layout.num_joints()
            );
        }
    }
    let mut counted = Vec::with_capacity(args.joints.len());
    for name in &args.joints {
        let Some(j) = layout.joints.iter().position(|n| n == name) else {
            bail!(
                "--joints names '{name}', which model '{model_id}' does not have (its joints: {})",
                layout.joints.join(", ")
            );
        };
        if j == 0 {
            bail!("--joints names the root '{name}', whose orientation is reported on its own");
        }
        counted.push(j);
    }
    let slices: Vec<&[Vec<f64>]> = train
        .iter()
        .map(|c| c.poses.as_slice())
        .chain(data_poses.iter().map(Vec::as_slice))
        .collect();
    let c = lfit_synth::motion::coverage::coverage(
        &layout,
        &slices,
        &eval.poses,
        args.tolerance,
        (!counted.is_empty()).then_some(counted.as_slice()),
    )
    .map_err(anyhow::Error::msg)?;
    let body: Vec<&lfit_synth::motion::coverage::AxisCoverage> = c
        .axes
        .iter()
        .filter(|a| c.counted.contains(&a.joint))
        .collect();
    let mut worst = body.clone();
    worst.sort_by(|a, b| b.outside.total_cmp(&a.outside));
    let row = |a: &lfit_synth::motion::coverage::AxisCoverage| {
        json!({
            "axis": a.name,
            "outside": a.outside,
            "p1_deg": a.p1.to_degrees(),
            "p99_deg": a.p99.to_degrees(),
        })
    };
    Ok(json!({
        "model": model_id,
        "train_files": args.train.len(),
        "train_datasets": args.train_data.len(),
        "train_frames": c.train_frames,
        "eval": args.eval.display().to_string(),
        "eval_frames": c.eval_frames,
        "covered": c.covered,
        "covered_with_root": c.covered_with_root,
        "joints_counted": c.counted.iter().map(|&j| layout.joints[j].as_str()).collect::<Vec<_>>(),
        "axes": body.len(),
        "axes_with_outside_frames": body.iter().filter(|a| a.outside > 0.0).count(),
        "worst": worst.iter().take(args.worst).copied().map(row).collect::<Vec<_>>(),
        "root": c.axes.iter().filter(|a| a.joint == 0).map(row).collect::<Vec<_>>(),
        "percentiles": [1, 99],
        "tolerance_rad": args.tolerance,
    }))
}

/// The ground-truth poses of an `lfit synth` dataset made for model `model_id` (`pose_dim`
/// translation and rotation entries); `purpose` ends the error for a dataset without them.
fn ground_truth_poses(
    path: &Path,
    model_id: &str,
    pose_dim: usize,
    purpose: &str,
) -> Result<Vec<Vec<f64>>> {
    let d =
        lfit_synth::Dataset::load(path).with_context(|| format!("dataset {}", path.display()))?;
    if d.meta.template_id != model_id || d.meta.pose_dim != pose_dim {
        bail!(
            "dataset {} was made for model '{}' ({} pose entries), not for model '{}' ({} pose entries)",
            path.display(),
            d.meta.template_id,
            d.meta.pose_dim,
            model_id,
            pose_dim
        );
    }
    if d.gt_poses.is_empty() {
        bail!(
            "dataset {} has no ground-truth poses (imported observations): nothing to {purpose}",
            path.display()
        );
    }
    Ok(d.gt_poses)
}

/// `lfit motion prior`: [`prior_energy`] on the model and files of `args`, written to `--out`.
pub fn prior(args: &PriorArgs) -> Result<Value> {
    let template = load(args.model.as_deref())?;
    let (config, mut summary) = prior_energy(args, &template, &[])?;
    let text = serde_json::to_string_pretty(&config)?;
    write_atomic(&args.out, text.as_bytes())?;
    summary["out"] = json!(args.out.display().to_string());
    Ok(summary)
}

/// The energy configuration of `lfit motion prior` (the prior fitted to `args`' motion files,
/// the `clips` given already read — named for the record — and `args`' datasets, every N-th
/// frame, on `template`; `args.model` and `args.out` are not read) and its summary (frames, the
/// prior's scores on them and on `args.held_out`). Every input is read and checked before the
/// fit.
pub fn prior_energy(
    args: &PriorArgs,
    template: &Template,
    clips: &[(String, &MotionClip)],
) -> Result<(lfit_model::energy::EnergyConfig, Value)> {
    if args.stride == 0 {
        bail!("--stride 0: keep every N-th frame needs N of at least 1");
    }
    if !(args.epsilon_deg.is_finite() && args.epsilon_deg > 0.0) {
        bail!(
            "--epsilon-deg {} is not a positive number of degrees",
            args.epsilon_deg
        );
    }
    let modality: lfit_model::observe::Modality = args
        .modality
        .parse()
        .with_context(|| format!("--modality {}", args.modality))?;
    let Some(weight) = args
        .weight
        .or_else(|| lfit_model::energy::default_pose_prior_weight(modality))
    else {
        bail!(
            "--modality {modality}: no default weight (measured only for markers and keypoints2d; on hmd the prior made LM worse): give --weight"
        );
    };
    let mut config = crate::cli::fit::read_energy_config(args.energy.as_deref(), true)?;
    config.weights.pose_prior = weight;
    config
        .validate()
        .with_context(|| format!("--weight {weight}"))?;
    let mut poses = Vec::new();
    for path in &args.motions {
        let clip = MotionClip::read(path)?;
        clip.check_model(template)
            .with_context(|| format!("motion {}", path.display()))?;
        poses.extend(clip.poses.into_iter().step_by(args.stride));
    }
    for (name, clip) in clips {
        clip.check_model(template)
            .with_context(|| format!("motion {name}"))?;
        poses.extend(clip.poses.iter().step_by(args.stride).cloned());
    }
    let mut held_out = Vec::new();
    for path in &args.held_out {
        let clip = MotionClip::read(path)?;
        clip.check_model(template)
            .with_context(|| format!("--held-out {}", path.display()))?;
        held_out.extend(clip.poses);
    }
    let pose_dim = template.layout().pose_dim();
    for path in &args.data {
        let gt = ground_truth_poses(path, &template.id, pose_dim, "fit")?;
        poses.extend(gt.into_iter().step_by(args.stride));
    }
    let names: Vec<String> = args
        .motions
        .iter()
        .map(|p| file_name(p))
        .chain(clips.iter().map(|c| c.0.clone()))
        .chain(args.data.iter().map(|p| file_name(p)))
        .collect();
    let mixture = if args.components > 1 {
        format!(", {} components (seed {})", args.components, args.seed)
    } else {
        String::new()
    };
    let source = format!(
        "lfit motion prior: {} frames (every {} of {}), ε {}°{mixture}",
        poses.len(),
        args.stride,
        names.join(", "),
        args.epsilon_deg
    );
    let (prior, em) = lfit_model::energy::PosePrior::fit_mixture(
        template,
        &poses,
        args.components,
        args.epsilon_deg.to_radians(),
        args.seed,
        source,
    )
    .with_context(|| format!("--components {}", args.components))?;
    // The squared Mahalanobis distance (to the active component) over the frames it was fitted
    // to: n on average for one Gaussian without ε.
    // The term is that distance plus the active component's constant: one search per pose.
    let scores = |poses: &[Vec<f64>]| {
        let t = poses.len() as f64;
        let (mut distance, mut term) = (0.0, 0.0);
        for p in poses {
            let (k, d) = prior.mahalanobis(p);
            distance += d;
            term += d + prior.components()[k].penalty();
        }
        json!({
            "frames": poses.len(),
            "mean_log_likelihood": prior.log_likelihood(poses),
            "mean_squared_mahalanobis": distance / t,
            "mean_term": term / t,
        })
    };
    let fitted = scores(&poses);
    let held = (!held_out.is_empty()).then(|| scores(&held_out));
    let entries = prior.len();
    let components = prior.components().len();
    config.pose_prior = Some(std::sync::Arc::new(prior));
    let summary = json!({
        "model": template.id,
        "files": names,
        "frames": poses.len(),
        "entries": entries,
        "epsilon_deg": args.epsilon_deg,
        "weight": weight,
        "modality": modality.name(),
        "components": components,
        "em_iterations": em.iterations,
        "em_converged": em.converged,
        "components_dropped": em.dropped,
        "mean_log_likelihood": fitted["mean_log_likelihood"],
        "mean_squared_mahalanobis": fitted["mean_squared_mahalanobis"],
        "mean_term": fitted["mean_term"],
        "held_out": held,
    });
    Ok((config, summary))
}
