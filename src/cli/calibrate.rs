//! `lfit calibrate`: where a sensor's points sit, solved once from frames whose poses are known
//! (a calibration recording) and given to every later fit with `lfit fit --offsets`.
//!
//! A 2D detector's keypoint is not the skeleton's joint centre (a COCO hip is where annotators
//! clicked hips), and a marker set is not placed on the model's vertices. Neither is
//! identifiable from the keypoints or markers of a single sequence: an offset along a bone is a
//! bone length (β), and across it a turn of the segment (`docs/results/captured-motion.md`,
//! round 18). With the poses known — motion capture filmed alongside the cameras (its `lfit fit`
//! result, `--poses`), or synthetic frames' ground truth — the offsets are a small least-squares
//! problem per point ([`lfit_model::energy::keypoint_offsets`],
//! [`lfit_model::energy::marker_offsets`]), as SMPLify-style fits learn a regressor for a
//! detector's joints once on data with known bodies instead of per sequence.

use std::path::{Path, PathBuf};
use std::sync::Arc;

use anyhow::{Context, Result, bail};
use glam::DVec3;
use lfit_model::energy::{Energy, EnergyConfig};
use lfit_model::template::{Template, write_atomic};
use lfit_synth::Dataset;
use serde_json::{Value, json};

use crate::cli::export::read_fitted_poses;
use crate::fitting::{energy_for_frame, point_offsets_of};

/// Arguments of `lfit calibrate`.
#[derive(Debug, Clone)]
pub struct CalibrateArgs {
    /// The calibration recording: a markers or keypoints2d dataset.
    pub data: PathBuf,
    /// The poses its frames were recorded at (the result JSON of `lfit fit`, or {"pose"} /
    /// {"poses"}); `None`: the dataset's ground truth.
    pub poses: Option<PathBuf>,
    /// Model file or template directory, as `lfit fit --model`.
    pub template: Option<PathBuf>,
    /// σ of the offsets' Gaussian prior in millimetres; `None`: the placement solve's (20 mm for
    /// markers, 30 mm for keypoints).
    pub prior_mm: Option<f64>,
    pub out: PathBuf,
}

/// `lfit calibrate`: solves the sensor's offsets at the known poses, writes them atomically
/// (`{"calibration": {...}, "keypoint_offsets" | "marker_offsets": [[x, y, z], ...]}`, which
/// `lfit fit --offsets` reads) and returns a summary.
pub fn calibrate(args: &CalibrateArgs) -> Result<Value> {
    let dataset =
        Dataset::load(&args.data).with_context(|| format!("dataset {}", args.data.display()))?;
    let template = crate::cli::fit::template_for(&dataset, args.template.as_deref())?;
    let doc = calibrate_dataset(
        &dataset,
        &args.data.display().to_string(),
        template,
        args.poses.as_deref(),
        args.prior_mm,
    )?;
    write_atomic(&args.out, &serde_json::to_vec_pretty(&doc)?)?;
    Ok(json!({ "out": args.out, "calibration": doc["calibration"] }))
}

/// The document `lfit calibrate` writes, for `dataset` (named `name` in it) of model
/// `template`: its sensor's offsets solved at the poses of `poses` (a fit result or pose file;
/// `None`: the dataset's ground truth) under a prior of `prior_mm` (`None`: the placement
/// solve's). Nothing written.
pub fn calibrate_dataset(
    dataset: &Dataset,
    name: &str,
    template: Arc<Template>,
    poses: Option<&Path>,
    prior_mm: Option<f64>,
) -> Result<Value> {
    let modality = dataset.modality();
    let Some((kind, default_prior)) = point_offsets_of(modality) else {
        bail!(
            "lfit calibrate solves where markers or 2D keypoints sit; {name} is a {modality} dataset"
        );
    };
    let prior = match prior_mm {
        None => default_prior,
        Some(mm) if mm.is_finite() && mm > 0.0 => mm / 1000.0,
        Some(mm) => bail!("--prior-mm {mm}: the prior's σ must be a positive number of mm"),
    };
    let (frames, source): (Vec<(usize, Vec<f64>)>, String) = match poses {
        Some(path) => {
            let fitted = read_fitted_poses(path, &template)?;
            if let Some(&(frame, _)) = fitted.frames.iter().find(|(f, _)| *f >= dataset.len()) {
                bail!(
                    "{}: frame {frame} is out of range: the dataset {name} has {} frames",
                    path.display(),
                    dataset.len()
                );
            }
            (fitted.frames, path.display().to_string())
        }
        None if dataset.gt_poses.is_empty() => bail!(
            "{name} has no ground-truth poses (imported observations): give the poses its frames were recorded at with --poses (e.g. the lfit fit result of the motion capture filmed alongside)"
        ),
        None => (
            dataset.gt_poses.iter().cloned().enumerate().collect(),
            "ground truth".into(),
        ),
    };
    let config = EnergyConfig::default();
    let energies: Vec<Energy> = frames
        .iter()
        .map(|&(f, _)| energy_for_frame(dataset, template.clone(), f, config.clone()))
        .collect::<Result<_>>()?;
    let poses: Vec<Vec<f64>> = frames.iter().map(|(_, p)| p.clone()).collect();
    let solved =
        lfit_model::energy::point_offsets(&energies, &poses, prior).context("lfit calibrate")?;
    // The data term at the known poses, the dataset's own sensor against the calibrated one.
    let data_term = |placed: &[Energy]| -> f64 {
        placed
            .iter()
            .zip(&poses)
            .map(|(e, p)| e.evaluate(p).term("data").unwrap_or(0.0))
            .sum::<f64>()
            / placed.len().max(1) as f64
    };
    let before = data_term(&energies);
    let placed: Vec<Energy> = energies
        .iter()
        .map(|e| e.with_offsets(&solved))
        .collect::<std::result::Result<_, _>>()?;
    let after = data_term(&placed);
    let offsets: Vec<[f64; 3]> = solved.iter().map(DVec3::to_array).collect();
    let rms_mm = 1000.0
        * (solved.iter().map(|d| d.length_squared()).sum::<f64>() / solved.len().max(1) as f64)
            .sqrt();
    let calibration = json!({
        "data": name,
        "modality": modality.name(),
        "template": template.id,
        "frames": frames.len(),
        "poses": source,
        "prior_mm": prior * 1000.0,
        "data_term_before": before,
        "data_term_after": after,
        "offset_rms_mm": rms_mm,
    });
    Ok(json!({ "calibration": calibration, format!("{kind}_offsets"): offsets }))
}
