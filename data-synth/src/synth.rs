//! Dataset generation: poses from the motion library or uniform sampling, the scenarios of
//! papers/000 §4 (a start pose and a target per frame), observations from the model crate's
//! observation models, then noise and occlusion.

use std::fmt;
use std::str::FromStr;
use std::sync::atomic::{AtomicUsize, Ordering};

use glam::Vec3;
use lfit_model::observe::{Modality, Sensor};
use lfit_model::pose::{Bounds, LOCAL_ROTATION_DEG, LOCAL_TRANSLATION, POSE_DIM, Pose};
use lfit_model::scan::{VoxelGrid, squared_edt};
use lfit_model::Template;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::dataset::{Dataset, Meta, Observations, FORMAT_VERSION};
use crate::error::SynthError;
use crate::motion::{MotionKind, MotionParams, motion_pose};
use crate::noise::{NoiseConfig, corrupt_hmd, corrupt_points, jitter_points, punch_holes};

/// The experiment cases of papers/000 §4.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Scenario {
    /// The target is near the start (0.03–0.25 s later in the same motion), inside the `local` box.
    Local,
    /// The start is the rest pose; the target is seconds into a motion, inside the `global` box.
    Global,
    /// Consecutive frames of one motion; each frame starts from the previous frame's pose.
    Sequence,
}

impl Scenario {
    pub fn name(self) -> &'static str {
        match self {
            Scenario::Local => "local",
            Scenario::Global => "global",
            Scenario::Sequence => "sequence",
        }
    }
}

impl fmt::Display for Scenario {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

impl FromStr for Scenario {
    type Err = SynthError;
    fn from_str(s: &str) -> Result<Self, SynthError> {
        [Scenario::Local, Scenario::Global, Scenario::Sequence]
            .into_iter()
            .find(|x| x.name() == s)
            .ok_or_else(|| SynthError::UnknownScenario(s.to_string()))
    }
}

/// Where target poses come from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum PoseSource {
    /// The procedural motion library.
    Motion,
    /// Uniform sampling within the global bounds (root height within ±0.3 m of standing).
    Uniform,
}

impl FromStr for PoseSource {
    type Err = SynthError;
    fn from_str(s: &str) -> Result<Self, SynthError> {
        match s {
            "motion" => Ok(PoseSource::Motion),
            "uniform" => Ok(PoseSource::Uniform),
            _ => Err(SynthError::UnknownSource(s.to_string())),
        }
    }
}

/// Everything that determines a dataset (with the template and sensor).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SynthConfig {
    pub modality: Modality,
    pub scenario: Scenario,
    pub source: PoseSource,
    pub frames: usize,
    pub seed: u64,
    /// Frame rate of sequences, Hz.
    pub fps: f64,
    pub noise: NoiseConfig,
    /// Motions drawn from (all by default).
    pub motions: Vec<MotionKind>,
}

impl SynthConfig {
    pub fn new(modality: Modality, scenario: Scenario, frames: usize, seed: u64) -> Self {
        Self { modality, scenario, source: PoseSource::Motion, frames, seed, fps: 30.0, noise: NoiseConfig::default(), motions: MotionKind::ALL.to_vec() }
    }

    pub fn validate(&self) -> Result<(), SynthError> {
        let setting = |name, value: String, reason: &str| Err(SynthError::Setting { name, value, reason: reason.into() });
        if self.frames == 0 {
            return setting("frames", "0".into(), "must be at least 1");
        }
        if !(self.fps.is_finite() && self.fps > 0.0) {
            return setting("fps", self.fps.to_string(), "must be positive");
        }
        if self.motions.is_empty() {
            return setting("motions", "[]".into(), "need at least one motion");
        }
        if self.scenario == Scenario::Sequence && self.source == PoseSource::Uniform {
            return setting("source", "uniform".into(), "sequences need smooth motion: use --source motion");
        }
        Ok(())
    }
}

/// Per-frame random stream: the same (seed, stream) gives the same numbers whatever the thread.
fn stream(seed: u64, index: u64) -> ChaCha8Rng {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    rng.set_stream(index);
    rng
}

const POSE_STREAM: u64 = 1 << 32;

/// Generates a dataset; `progress` is called with the number of frames done.
pub fn synthesize(config: &SynthConfig, template: &Template, sensor: &Sensor, progress: &(dyn Fn(usize) + Sync)) -> Result<Dataset, SynthError> {
    config.validate()?;
    sensor.validate(template)?;
    if sensor.modality() != config.modality {
        return Err(SynthError::Setting { name: "sensor", value: sensor.modality().to_string(), reason: format!("does not match modality {}", config.modality) });
    }
    let (starts, targets, motions) = scenario_poses(config);
    let done = AtomicUsize::new(0);
    let frames: Vec<FrameObs> = (0..config.frames)
        .into_par_iter()
        .map(|i| {
            let mut rng = stream(config.seed, i as u64);
            let obs = observe_frame(template, sensor, &targets[i], &config.noise, &mut rng);
            progress(done.fetch_add(1, Ordering::Relaxed) + 1);
            obs
        })
        .collect();
    let observations = match config.modality {
        Modality::Scan => assemble_scan(frames, sensor)?,
        _ => {
            let (values, visible) = frames
                .into_iter()
                .map(|f| match f {
                    FrameObs::Sparse(v, b) => (v, b),
                    FrameObs::Scan { .. } => (Vec::new(), Vec::new()),
                })
                .unzip();
            Observations::Sparse { values, visible }
        }
    };
    Ok(Dataset {
        meta: Meta {
            format: "lfit-dataset".into(),
            version: FORMAT_VERSION,
            template_id: template.id.clone(),
            template_vertices: template.num_vertices(),
            config: config.clone(),
            frame_motions: motions,
        },
        sensor: sensor.clone(),
        start_poses: starts,
        gt_poses: targets,
        observations,
    })
}

/// Start poses, targets and the motion behind each frame.
fn scenario_poses(config: &SynthConfig) -> (Vec<Pose>, Vec<Pose>, Vec<String>) {
    let global = Bounds::global();
    let n = config.frames;
    if config.scenario == Scenario::Sequence {
        let mut rng = stream(config.seed, POSE_STREAM);
        let kind = config.motions[rng.random_range(0..config.motions.len())];
        let params = MotionParams::sample(kind, &mut rng);
        let t0 = rng.random_range(0.0..2.0);
        // One frame before the first, so that frame 0 also has a previous pose to start from.
        let mut poses: Vec<Pose> = (0..=n).map(|k| motion_pose(kind, &params, t0 + (k as f64 - 1.0) / config.fps)).collect();
        let (mx, mz) = poses.iter().fold((0.0, 0.0), |(x, z), p| (x + p[0], z + p[2]));
        for p in &mut poses {
            p[0] -= mx / (n + 1) as f64;
            p[2] -= mz / (n + 1) as f64;
        }
        let starts = poses[..n].to_vec();
        let targets = poses[1..].to_vec();
        return (starts, targets, vec![kind.name().to_string(); n]);
    }
    let per_frame: Vec<(Pose, Pose, String)> = (0..n)
        .into_par_iter()
        .map(|i| {
            let mut rng = stream(config.seed, POSE_STREAM + 1 + i as u64);
            let (mut target, previous, name) = match config.source {
                PoseSource::Motion => {
                    let kind = config.motions[rng.random_range(0..config.motions.len())];
                    let params = MotionParams::sample(kind, &mut rng);
                    let t = rng.random_range(0.5..10.0);
                    let dt = rng.random_range(1.0 / 30.0..0.25);
                    let mut target = motion_pose(kind, &params, t);
                    let mut previous = motion_pose(kind, &params, t - dt);
                    // Put the subject somewhere on the capture floor, keeping the motion's step.
                    let (x, z) = (rng.random_range(-0.6..0.6), rng.random_range(-0.6..0.6));
                    let (tx, tz) = (target[0], target[2]);
                    for p in [&mut previous, &mut target] {
                        p[0] += x - tx;
                        p[2] += z - tz;
                    }
                    (target, previous, kind.name().to_string())
                }
                PoseSource::Uniform => {
                    let mut target = [0.0; POSE_DIM];
                    for (k, v) in target.iter_mut().enumerate() {
                        let (lo, hi) = if k == 1 { (-0.3, 0.3) } else { (global.lower[k], global.upper[k]) };
                        *v = rng.random_range(lo..hi);
                    }
                    let mut previous = target;
                    let local = Bounds::local(&target);
                    for k in 0..POSE_DIM {
                        previous[k] = rng.random_range(local.lower[k]..local.upper[k]);
                    }
                    (target, previous, "uniform".to_string())
                }
            };
            global.clamp(&mut target);
            let start = match config.scenario {
                Scenario::Local => {
                    // A hair inside the box, so that the target lies in the start's local box
                    // despite rounding.
                    let shrink = 1.0 - 1e-9;
                    let mut s = previous;
                    Bounds::around(&target, LOCAL_TRANSLATION * shrink, LOCAL_ROTATION_DEG.to_radians() * shrink).clamp(&mut s);
                    s
                }
                _ => [0.0; POSE_DIM],
            };
            (start, target, name)
        })
        .collect();
    let mut starts = Vec::with_capacity(n);
    let mut targets = Vec::with_capacity(n);
    let mut names = Vec::with_capacity(n);
    for (s, t, m) in per_frame {
        starts.push(s);
        targets.push(t);
        names.push(m);
    }
    (starts, targets, names)
}

enum FrameObs {
    Sparse(Vec<f64>, Vec<bool>),
    Scan { points: Vec<Vec3>, visible: Vec<bool>, silhouettes: Vec<lfit_model::scan::Mask> },
}

fn observe_frame(template: &Template, sensor: &Sensor, target: &Pose, noise: &NoiseConfig, rng: &mut ChaCha8Rng) -> FrameObs {
    match sensor {
        Sensor::Scan(_) => {
            let Some(pred) = sensor.predict_scan(template, target) else { unreachable!("scan sensor") };
            let mut points = pred.vertices;
            let mut visible = vec![true; points.len()];
            jitter_points(&mut points, noise.point_sigma, rng);
            punch_holes(&points, &mut visible, noise.scan_holes, noise.scan_hole_radius, rng);
            FrameObs::Scan { points, visible, silhouettes: pred.silhouettes }
        }
        _ => {
            let Some(pred) = sensor.predict_sparse(template, target) else { unreachable!("sparse sensor") };
            let (mut values, mut visible) = (pred.values, pred.visible);
            match sensor.modality() {
                Modality::Markers => corrupt_points(&mut values, &mut visible, 3, noise.point_sigma, noise.outlier_scale_m, noise, rng),
                Modality::Keypoints2d => corrupt_points(&mut values, &mut visible, 2, noise.pixel_sigma, noise.outlier_scale_px, noise, rng),
                _ => corrupt_hmd(&mut values, &visible, noise, rng),
            }
            FrameObs::Sparse(values, visible)
        }
    }
}

/// Builds the per-frame distance transforms on grids of one common size, each centred on its
/// frame's (visible) point cloud, so that the dataset stores them as one `[N, Z, Y, X]` array.
fn assemble_scan(frames: Vec<FrameObs>, sensor: &Sensor) -> Result<Observations, SynthError> {
    let Sensor::Scan(setup) = sensor else { unreachable!("scan sensor") };
    let mut points = Vec::with_capacity(frames.len());
    let mut visible = Vec::with_capacity(frames.len());
    let mut silhouettes = Vec::with_capacity(frames.len());
    for f in frames {
        if let FrameObs::Scan { points: p, visible: v, silhouettes: s } = f {
            points.push(p);
            visible.push(v);
            silhouettes.push(s);
        }
    }
    let clouds: Vec<Vec<Vec3>> = points.iter().zip(&visible).map(|(p, v)| p.iter().zip(v).filter(|(_, b)| **b).map(|(p, _)| *p).collect()).collect();
    let boxes = clouds.iter().map(|c| VoxelGrid::around_points(c, setup.voxel_size, lfit_model::scan::DEFAULT_BOX_SCALE)).collect::<Result<Vec<_>, _>>()?;
    let mut dims = [0usize; 3];
    for b in &boxes {
        for k in 0..3 {
            dims[k] = dims[k].max(b.dims[k]);
        }
    }
    let grids = boxes
        .into_par_iter()
        .zip(clouds.par_iter())
        .map(|(b, cloud)| {
            let mut origin = [0.0; 3];
            for k in 0..3 {
                let centre = b.origin[k] + (b.dims[k] - 1) as f64 * b.spacing / 2.0;
                origin[k] = centre - (dims[k] - 1) as f64 * b.spacing / 2.0;
            }
            let mut grid = VoxelGrid { origin, spacing: b.spacing, dims, values: vec![0.0; dims.iter().product()] };
            squared_edt(&mut grid, cloud);
            grid
        })
        .collect();
    Ok(Observations::Scan { points, visible, grids, silhouettes })
}

#[cfg(test)]
mod tests {
    use super::*;
    use lfit_model::default_template;

    #[test]
    fn scenarios_respect_their_boxes() {
        let t = default_template();
        for scenario in [Scenario::Local, Scenario::Global] {
            for source in [PoseSource::Motion, PoseSource::Uniform] {
                let mut c = SynthConfig::new(Modality::Markers, scenario, 40, 5);
                c.source = source;
                let (starts, targets, _) = scenario_poses(&c);
                for (s, g) in starts.iter().zip(&targets) {
                    assert!(Bounds::global().contains(g), "{scenario} {source:?}");
                    match scenario {
                        Scenario::Local => assert!(Bounds::local(s).contains(g)),
                        _ => assert_eq!(s, &[0.0; POSE_DIM]),
                    }
                }
            }
        }
        let c = SynthConfig::new(Modality::Markers, Scenario::Sequence, 30, 5);
        let (starts, targets, _) = scenario_poses(&c);
        for i in 1..30 {
            assert_eq!(starts[i], targets[i - 1]);
        }
        let _ = t;
    }

    #[test]
    fn bad_configs_are_refused() {
        assert!(SynthConfig::new(Modality::Hmd, Scenario::Local, 0, 1).validate().is_err());
        let mut c = SynthConfig::new(Modality::Hmd, Scenario::Sequence, 3, 1);
        c.source = PoseSource::Uniform;
        assert!(c.validate().is_err());
    }
}
