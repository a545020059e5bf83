//! `lfit render`: a PNG of fitted frames (fit, ground truth, observations; front, side and the
//! dataset's camera), of a dataset's frames, or of bare poses and shapes.
//!
//! Everything is read and checked before anything is drawn, and the PNG is written atomically
//! (temporary file, then rename): on any error nothing is written.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail};
use lfit_model::skinning::SkinningMethod;
use lfit_model::template::write_atomic;
use lfit_synth::Dataset;
use serde_json::{Value, json};

use super::scene::{Panel, Role, Scene, View, draw};
use super::{FrameRow, frame_panels, legend};

/// Most frames (rows) one picture shows.
pub const MAX_FRAMES: usize = 16;
/// Most poses (columns) of a `--pose` picture.
pub const MAX_POSES: usize = 16;
/// Smallest and largest image side, pixels.
pub const MIN_SIDE: u32 = 32;
pub const MAX_SIDE: u32 = 8192;

/// Flags of `lfit render`.
#[derive(Debug, Clone, clap::Args)]
pub struct RenderArgs {
    /// Model: a model file (.npz) or template directory. Default: the dataset's model (the
    /// procedural template or shipped model named by its id), or the procedural template in
    /// --shape.
    #[arg(long, visible_alias = "template")]
    pub model: Option<PathBuf>,
    /// Body-proportion variant of the procedural template when neither --model nor --data names
    /// the model (default, tall, short, heavy, slim, long-legs, long-arms, morphable).
    #[arg(long, default_value = "default")]
    pub shape: String,
    /// Dataset (.npz from `lfit synth` or `lfit data import`): ground truth and observations.
    #[arg(long)]
    pub data: Option<PathBuf>,
    /// Result JSON of `lfit fit` on --data: the fitted poses.
    #[arg(long)]
    pub fit: Option<PathBuf>,
    /// Frames, one row each: I, A..B (B excluded), A-B (B included) or a comma list (at most
    /// 16). Default: the first fitted frame, or frame 0.
    #[arg(long)]
    pub frame: Option<String>,
    /// Instead of a dataset: {"pose": [...], "shape": [...]} or {"poses": [...], "shapes":
    /// [...]} (as `lfit template pose`), one column per pose. Without --pose, --data and --fit:
    /// the model at rest.
    #[arg(long)]
    pub pose: Option<PathBuf>,
    /// Output PNG file.
    #[arg(long)]
    pub out: PathBuf,
    /// Image size WxH in pixels (default: 300 × 380 per panel).
    #[arg(long)]
    pub size: Option<String>,
    /// Camera of the dataset shown as the third view (keypoints2d, silhouettes).
    #[arg(long, default_value_t = 0)]
    pub camera: usize,
    /// Skinning: lbs or dqs.
    #[arg(long, default_value = "lbs")]
    pub skinning: String,
}

/// Parses `WxH`.
pub fn parse_size(s: &str) -> Result<(u32, u32)> {
    let parsed = s
        .split_once(['x', 'X', '×'])
        .and_then(|(w, h)| Some((w.trim().parse::<u32>().ok()?, h.trim().parse::<u32>().ok()?)));
    match parsed {
        Some((w, h))
            if (MIN_SIDE..=MAX_SIDE).contains(&w) && (MIN_SIDE..=MAX_SIDE).contains(&h) =>
        {
            Ok((w, h))
        }
        Some(_) => {
            bail!("--size {s}: width and height must be between {MIN_SIDE} and {MAX_SIDE} pixels")
        }
        None => bail!("--size must be WIDTHxHEIGHT in pixels, e.g. 900x500, got '{s}'"),
    }
}

/// Parses `--frame`: indices and ranges, each below `len`, no repeats.
pub fn parse_frame_list(spec: &str, len: usize) -> Result<Vec<usize>> {
    let mut out: Vec<usize> = Vec::new();
    for part in spec.split(',').map(str::trim) {
        let num = |s: &str| {
            s.trim()
                .parse::<usize>()
                .with_context(|| format!("--frame: '{s}' is not a frame index"))
        };
        let (a, b) = if let Some((a, b)) = part.split_once("..") {
            (num(a)?, num(b)?)
        } else if let Some((a, b)) = part.split_once('-') {
            (num(a)?, num(b)?.saturating_add(1))
        } else {
            let i = num(part)?;
            (i, i.saturating_add(1))
        };
        if a >= b {
            bail!("--frame: empty range '{part}'");
        }
        if b > len {
            bail!("--frame {part}: out of range, the dataset has {len} frames (0..{len})",);
        }
        for f in a..b {
            if out.contains(&f) {
                bail!("--frame: frame {f} is listed twice");
            }
            out.push(f);
            if out.len() > MAX_FRAMES {
                bail!("--frame: at most {MAX_FRAMES} frames per picture");
            }
        }
    }
    Ok(out)
}

fn skinning(name: &str) -> Result<SkinningMethod> {
    match name {
        "lbs" => Ok(SkinningMethod::Linear),
        "dqs" => Ok(SkinningMethod::DualQuaternion),
        other => bail!("unknown skinning '{other}' (expected lbs or dqs)"),
    }
}

/// Default image size: 300 × 380 pixels per panel plus the title band.
fn default_size(columns: usize, rows: usize) -> (u32, u32) {
    let w = (300 * columns.max(1) as u32).min(MAX_SIDE);
    let h = (380 * rows.max(1) as u32 + 26).min(MAX_SIDE);
    (w, h)
}

/// `lfit render`.
pub fn render(args: &RenderArgs) -> Result<Value> {
    let skinning = skinning(&args.skinning)?;
    let ext_ok = args
        .out
        .extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("png"));
    if !ext_ok {
        bail!("--out {}: expected a .png file name", args.out.display());
    }
    let size = args.size.as_deref().map(parse_size).transpose()?;
    if args.pose.is_some() && (args.data.is_some() || args.fit.is_some()) {
        bail!("--pose draws bare poses: it does not go with --data or --fit");
    }
    if args.fit.is_some() && args.data.is_none() {
        bail!("--fit needs --data, the dataset it was fitted on (ground truth, observations)");
    }
    if args.frame.is_some() && args.data.is_none() {
        bail!("--frame needs --data");
    }
    let (scene, faces, summary) = match &args.data {
        Some(data) => dataset_scene(args, data, skinning)?,
        None => pose_scene(args, skinning)?,
    };
    let rows = scene.panels.len().div_ceil(scene.columns.max(1));
    let (w, h) = size.unwrap_or_else(|| default_size(scene.columns, rows));
    if w / scene.columns.max(1) as u32 <= 24 || h / rows.max(1) as u32 <= 40 {
        bail!(
            "--size {w}x{h} is too small for {rows} × {} panels",
            scene.columns
        );
    }
    let canvas = draw(&scene, &faces, w, h)?;
    let bytes = canvas.to_png()?;
    write_atomic(&args.out, &bytes)
        .with_context(|| format!("cannot write {}", args.out.display()))?;
    let mut out = json!({ "out": args.out, "width": w, "height": h, "panels": scene.panels.len() });
    if let Value::Object(m) = &mut out
        && let Value::Object(s) = summary
    {
        m.extend(s);
    }
    Ok(out)
}

/// Bare poses (or the rest pose): one column per pose, front above side.
fn pose_scene(
    args: &RenderArgs,
    skinning: SkinningMethod,
) -> Result<(Scene, Vec<[u32; 3]>, Value)> {
    let template = crate::data::load_model(args.model.as_deref(), &args.shape)?;
    let params = match &args.pose {
        Some(path) => crate::data::read_params_file(path, &template)?,
        None => vec![vec![0.0; template.layout().dim()]],
    };
    if params.len() > MAX_POSES {
        bail!(
            "{}: {} poses, at most {MAX_POSES} per picture",
            args.pose
                .as_deref()
                .map_or_else(String::new, |p| p.display().to_string()),
            params.len()
        );
    }
    let meshes: Vec<_> = params
        .iter()
        .map(|p| lfit_model::skinning::pose_vertices(&template, p, skinning))
        .collect();
    let n = meshes.len();
    let mut panels = Vec::with_capacity(2 * n);
    for (view, name) in [(View::Front, "front"), (View::Side, "side")] {
        for (i, mesh) in meshes.iter().enumerate() {
            let label = if n == 1 {
                name.to_string()
            } else {
                format!("pose {i} · {name}")
            };
            let mut panel = Panel::new(view.clone(), label);
            panel.meshes.push((mesh.clone(), Role::Body));
            panels.push(panel);
        }
    }
    let what = if args.pose.is_some() {
        format!("{n} pose(s)")
    } else {
        "rest pose".to_string()
    };
    let scene = Scene {
        title: format!(
            "{} · {what} · {} vertices",
            template.id,
            template.num_vertices()
        ),
        // One pose: front and side next to each other; several: a row of each.
        columns: if n == 1 { 2 } else { n },
        panels,
    };
    Ok((
        scene,
        template.faces.clone(),
        json!({ "model": template.id, "poses": n }),
    ))
}

/// Frames of a dataset, with their fit when --fit is given.
fn dataset_scene(
    args: &RenderArgs,
    data: &Path,
    skinning: SkinningMethod,
) -> Result<(Scene, Vec<[u32; 3]>, Value)> {
    let dataset = Dataset::load(data).with_context(|| format!("dataset {}", data.display()))?;
    let template = crate::fitting::template_for(&dataset, args.model.as_deref())?;
    let fitted = match &args.fit {
        Some(path) => {
            let fitted = crate::cli::export::read_fitted_poses(path, &template)?;
            crate::cli::export::check_against_dataset(&fitted, path, &dataset, data)?;
            let text = std::fs::read_to_string(path)
                .with_context(|| format!("cannot read {}", path.display()))?;
            let value: Value = serde_json::from_str(&text)
                .with_context(|| format!("malformed fit JSON {}", path.display()))?;
            crate::cli::export::check_fit_file(&value, path, &template, &dataset, &fitted.frames)?;
            let method = value
                .get("method")
                .and_then(Value::as_str)
                .unwrap_or("fit")
                .to_string();
            Some((fitted.frames, method))
        }
        None => None,
    };
    if dataset.is_empty() {
        bail!("dataset {} has no frames", data.display());
    }
    let frames = match (&args.frame, &fitted) {
        (Some(spec), _) => parse_frame_list(spec, dataset.len())?,
        (None, Some((rows, _))) => rows.first().map(|(f, _)| vec![*f]).unwrap_or_default(),
        (None, None) => vec![0],
    };
    let cameras = dataset.sensor.cameras().len();
    if args.camera > 0 && args.camera >= cameras {
        bail!(
            "--camera {}: the dataset has {cameras} cameras",
            args.camera
        );
    }
    let mut rows = Vec::with_capacity(frames.len());
    let mut errors = Vec::new();
    for &frame in &frames {
        let fit = match &fitted {
            Some((list, _)) => Some(
                list.iter()
                    .find(|(f, _)| *f == frame)
                    .map(|(_, p)| p.clone())
                    .with_context(|| {
                        format!(
                            "--frame {frame}: {} has no fit of frame {frame} (it has {} frames: {})",
                            args.fit
                                .as_deref()
                                .map_or_else(String::new, |p| p.display().to_string()),
                            list.len(),
                            list.iter()
                                .take(10)
                                .map(|(f, _)| f.to_string())
                                .collect::<Vec<_>>()
                                .join(", ")
                        )
                    })?,
            ),
            None => None,
        };
        let v2v = match (&fit, dataset.ground_truth(frame)) {
            (Some(p), Some(gt)) => Some(lfit_model::metrics::v2v_mm(&template, p, gt)),
            _ => None,
        };
        errors.push(json!({ "frame": frame, "v2v_mm": v2v }));
        let label = match v2v {
            Some(e) => format!("frame {frame} · V2V {e:.1} mm"),
            None => format!("frame {frame}"),
        };
        rows.push(FrameRow { frame, fit, label });
    }
    let mut panels = Vec::new();
    for row in &rows {
        panels.extend(frame_panels(
            &template,
            &dataset,
            row,
            args.camera,
            skinning,
        ));
    }
    let columns = panels.len() / rows.len().max(1);
    let name = data
        .file_name()
        .map_or_else(String::new, |n| n.to_string_lossy().into_owned());
    let method = fitted.as_ref().map(|(_, m)| m.as_str());
    let views = super::view_names(&dataset, args.camera);
    let title = match method {
        Some(m) => format!(
            "{m} on {name} ({}) · {views} · {}",
            dataset.modality(),
            legend(true, dataset.has_ground_truth())
        ),
        None => format!(
            "{name} ({}) · {views} · {}",
            dataset.modality(),
            legend(false, dataset.has_ground_truth())
        ),
    };
    let scene = Scene {
        title,
        columns,
        panels,
    };
    Ok((
        scene,
        template.faces.clone(),
        json!({ "model": template.id, "method": method, "frames": errors }),
    ))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sizes_and_frame_lists_parse_or_fail_with_a_reason() {
        assert_eq!(parse_size("900x500").unwrap(), (900, 500));
        assert_eq!(parse_size("64X64").unwrap(), (64, 64));
        for bad in ["900", "0x10", "10x", "axb", "9000x100", "-5x100"] {
            assert!(parse_size(bad).is_err(), "{bad}");
        }
        assert_eq!(parse_frame_list("3", 5).unwrap(), vec![3]);
        assert_eq!(parse_frame_list("0..2,4", 5).unwrap(), vec![0, 1, 4]);
        assert_eq!(parse_frame_list("1-3", 5).unwrap(), vec![1, 2, 3]);
        let e = parse_frame_list("5", 5).unwrap_err().to_string();
        assert!(e.contains("out of range"), "{e}");
        assert!(parse_frame_list("1,1", 5).is_err());
        assert!(parse_frame_list("x", 5).is_err());
        assert!(
            parse_frame_list("0..40", 40).is_err(),
            "more than 16 frames"
        );
    }
}
