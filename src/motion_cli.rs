//! `lfit motion import` and `lfit motion export` (SPEC §3a "Motions", §10): BVH clips retargeted
//! through a joint-name map and AMASS-layout `.npz` motions become lfit motion files
//! ([`lfit_synth::motion_io::MotionClip`]); motion files and fitted sequences become BVH. Every
//! input is read and checked before anything is written; outputs are written atomically.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail};
use lfit_model::template::{Template, write_atomic};
use lfit_synth::motion_io::{MotionClip, export_bvh, read_amass};
use lfit_synth::retarget::{JointMap, RetargetOptions, RootMode, Units, Up, read_bvh, retarget};
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
    #[arg(long)]
    pub model: Option<PathBuf>,
    /// Output motion file (.npz).
    #[arg(long)]
    pub out: PathBuf,
    /// Units of the BVH: cm, m, or auto (cm when the rest skeleton is taller than 3 units).
    #[arg(long, default_value = "auto")]
    pub units: String,
    /// Up axis of the input: y, or z (converted by (x, y, z) -> (x, z, -y): a Z-up capture whose
    /// subject faces -y then faces +z).
    #[arg(long, default_value = "y")]
    pub up: String,
    /// BVH root height: floor (the BVH's y = 0 is the ground; the anchor's height and steps are
    /// scaled by the model's over the BVH's leg length (bone lengths from the anchor to the lowest
    /// mapped joint)) or rest (displacement from the BVH's rest pose, unscaled).
    #[arg(long, default_value = "floor")]
    pub root: String,
}

/// Settings of `lfit motion export`.
#[derive(Debug, Clone, clap::Args)]
pub struct ExportArgs {
    /// Output format: bvh.
    #[arg(long)]
    pub format: String,
    /// Model file or template directory; default: the procedural template.
    #[arg(long)]
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

/// Runs a `lfit motion` subcommand.
pub fn run(command: &MotionCommand) -> Result<Value> {
    match command {
        MotionCommand::Import(a) => import(a),
        MotionCommand::Export(a) => export(a),
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
    let up: Up = args.up.parse().map_err(anyhow::Error::msg)?;
    let template = load(args.model.as_deref())?;
    let (clip, extra) = match (&args.bvh, &args.amass) {
        (Some(bvh_path), None) => {
            let units: Units = args.units.parse().map_err(anyhow::Error::msg)?;
            let root: RootMode = args.root.parse().map_err(anyhow::Error::msg)?;
            let bvh = read_bvh(bvh_path)?;
            let map = match &args.map {
                Some(m) => JointMap::read(m)?,
                None => JointMap::identity(&bvh),
            };
            let options = RetargetOptions {
                units,
                up,
                root,
                shape: Vec::new(),
            };
            let r = retarget(&bvh, &map, &template, &options)
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
                    "bvh:{} map:{}",
                    file_name(bvh_path),
                    args.map
                        .as_deref()
                        .map_or_else(|| "identity".to_string(), file_name)
                ),
                model: template.signature(),
            };
            (clip, extra)
        }
        (None, Some(amass_path)) => {
            if args.map.is_some() {
                bail!(
                    "--map applies to --bvh; an AMASS file is for a model with the same skeleton"
                );
            }
            let (poses, fps) = read_amass(amass_path, &template, up)?;
            let clip = MotionClip {
                poses,
                fps,
                source: format!("amass:{}", file_name(amass_path)),
                model: template.signature(),
            };
            (clip, json!({}))
        }
        (Some(_), Some(_)) => bail!("give either --bvh or --amass, not both"),
        (None, None) => {
            bail!("lfit motion import needs --bvh FILE (with --map FILE) or --amass FILE")
        }
    };
    clip.write(&args.out)?;
    let mut summary = json!({
        "out": args.out.display().to_string(),
        "model": template.id,
        "frames": clip.poses.len(),
        "fps": clip.fps,
        "source": clip.source,
    });
    if let (Value::Object(s), Value::Object(e)) = (&mut summary, extra) {
        s.extend(e);
    }
    Ok(summary)
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
            let fitted = crate::export::read_fitted_poses(f, &template)?;
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
        "rotation_order": lfit_synth::motion_io::EXPORT_ORDER.name(),
    }))
}
