//! Dataset generation: poses from the motion library or uniform sampling, the scenarios of
//! papers/000 §4 (a start pose and a target per frame), observations from the model crate's
//! observation models, then noise and occlusion.

use std::fmt;
use std::str::FromStr;
use std::sync::atomic::{AtomicUsize, Ordering};

use glam::Vec3;
use lfit_model::Template;
use lfit_model::layout::Layout;
use lfit_model::observe::{Modality, Sensor, points_from_values};
use lfit_model::pose::{
    Bounds, LOCAL_ROTATION_DEG, LOCAL_TRANSLATION, POSE_DIM, Pose, SHAPE_BOUND,
};
use lfit_model::scan::{VoxelGrid, render_silhouettes, squared_edt};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, StandardNormal};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::dataset::{Dataset, FORMAT_VERSION, Meta, Observations};
use crate::error::SynthError;
use crate::motion::{MotionKind, MotionParams, motion_pose};
use crate::noise::NoiseConfig;

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
        Self {
            modality,
            scenario,
            source: PoseSource::Motion,
            frames,
            seed,
            fps: 30.0,
            noise: NoiseConfig::default(),
            motions: MotionKind::ALL.to_vec(),
        }
    }

    pub fn validate(&self) -> Result<(), SynthError> {
        let setting = |name, value: String, reason: &str| {
            Err(SynthError::Setting {
                name,
                value,
                reason: reason.into(),
            })
        };
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
            return setting(
                "source",
                "uniform".into(),
                "sequences need smooth motion: use --source motion",
            );
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
/// Streams of the shape and expression draws (apart from the pose streams, so a rigid model's
/// poses are what they were before models had shape).
const SHAPE_STREAM: u64 = 3 << 32;

/// Generates a dataset; `progress` is called with the number of frames done.
pub fn synthesize(
    config: &SynthConfig,
    template: &Template,
    sensor: &Sensor,
    progress: &(dyn Fn(usize) + Sync),
) -> Result<Dataset, SynthError> {
    config.validate()?;
    sensor.validate(template)?;
    if sensor.modality() != config.modality {
        return Err(SynthError::Setting {
            name: "sensor",
            value: sensor.modality().to_string(),
            reason: format!("does not match modality {}", config.modality),
        });
    }
    let (starts, targets, motions) = scenario_poses(config, template)?;
    let done = AtomicUsize::new(0);
    let layout = template.layout();
    if let Some(i) = (0..config.frames).find(|&i| targets[i].len() != layout.dim()) {
        return Err(SynthError::Setting {
            name: "template",
            value: template.id.clone(),
            reason: format!("frame {i} has {} parameters", targets[i].len()),
        });
    }
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
        Modality::Silhouettes => Observations::Silhouettes {
            masks: frames
                .into_iter()
                .map(|f| match f {
                    FrameObs::Silhouettes(m) => m,
                    _ => Vec::new(),
                })
                .collect(),
        },
        _ => {
            let (values, visible) = frames
                .into_iter()
                .map(|f| match f {
                    FrameObs::Sparse(v, b) => (v, b),
                    FrameObs::Scan { .. } | FrameObs::Silhouettes(_) => (Vec::new(), Vec::new()),
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
            pose_dim: layout.pose_dim(),
            shape_dim: layout.shape,
            expression_dim: layout.expression,
        },
        sensor: sensor.clone(),
        start_poses: starts,
        gt_poses: targets,
        observations,
    })
}

/// A pose of the default skeleton (the motion library's) on `template`'s skeleton: the root
/// translation, and each papers/000 joint's rotation on the model joint its joint map names
/// (joints it does not name stay at rest). The identity on the default skeleton.
pub fn retarget(pose: &Pose, template: &Template, layout: &Layout) -> Vec<f64> {
    if layout.pose_dim() == POSE_DIM
        && template
            .info
            .joint_map
            .iter()
            .enumerate()
            .all(|(j, m)| *m == Some(j))
    {
        return pose.to_vec();
    }
    let mut out = vec![0.0; layout.pose_dim()];
    out[..3].copy_from_slice(&pose[..3]);
    for (j, m) in template.info.joint_map.iter().enumerate() {
        if let Some(m) = *m {
            let (a, b) = (layout.rotation_offset(m), lfit_model::pose::rot_offset(j));
            out[a..a + 3].copy_from_slice(&pose[b..b + 3]);
        }
    }
    out
}

/// Shape and expression coefficients of a subject: `N(0, I)` (the shape prior), clipped to
/// ±[`SHAPE_BOUND`]; none for a model without them (and then no random number is drawn).
fn subject_coefficients(layout: &Layout, seed: u64, index: u64) -> Vec<f64> {
    let k = layout.shape + layout.expression;
    if k == 0 {
        return Vec::new();
    }
    let mut rng = stream(seed, SHAPE_STREAM + index);
    (0..k)
        .map(|_| StandardNormal.sample(&mut rng))
        .map(|x: f64| x.clamp(-SHAPE_BOUND, SHAPE_BOUND))
        .collect()
}

/// Per frame: start parameters, target parameters, and the motion behind the frame.
type ScenarioPoses = (Vec<Vec<f64>>, Vec<Vec<f64>>, Vec<String>);

/// Start parameters, targets and the motion behind each frame, in `template`'s layout. Targets
/// carry the subject's shape and expression; starts have the mean (zero) coefficients: a fitter
/// does not know them.
fn scenario_poses(config: &SynthConfig, template: &Template) -> Result<ScenarioPoses, SynthError> {
    let layout = template.layout();
    let global = Bounds::global_for(template);
    let pd = layout.pose_dim();
    let n = config.frames;
    if config.source == PoseSource::Motion && template.info.joint_map.iter().all(Option::is_none) {
        return Err(SynthError::Setting {
            name: "source",
            value: "motion".into(),
            reason: format!(
                "model '{}' maps none of its joints to the papers/000 skeleton (lfit key 'joint_map'): use --source uniform",
                template.id
            ),
        });
    }
    let with_coefficients = |mut pose: Vec<f64>, coefficients: &[f64]| {
        pose.extend_from_slice(coefficients);
        pose
    };
    let zeros = vec![0.0; layout.shape + layout.expression];
    if config.scenario == Scenario::Sequence {
        let mut rng = stream(config.seed, POSE_STREAM);
        let kind = config.motions[rng.random_range(0..config.motions.len())];
        let params = MotionParams::sample(kind, &mut rng);
        let t0 = rng.random_range(0.0..2.0);
        // One frame before the first, so that frame 0 also has a previous pose to start from.
        let mut poses: Vec<Pose> = (0..=n)
            .map(|k| motion_pose(kind, &params, t0 + (k as f64 - 1.0) / config.fps))
            .collect();
        let (mx, mz) = poses
            .iter()
            .fold((0.0, 0.0), |(x, z), p| (x + p[0], z + p[2]));
        for p in &mut poses {
            p[0] -= mx / (n + 1) as f64;
            p[2] -= mz / (n + 1) as f64;
        }
        // One subject for the whole sequence; every frame starts from the previous frame's truth.
        let subject = subject_coefficients(&layout, config.seed, 0);
        let poses: Vec<Vec<f64>> = poses
            .iter()
            .map(|p| with_coefficients(retarget(p, template, &layout), &subject))
            .collect();
        let starts = poses[..n].to_vec();
        let targets = poses[1..].to_vec();
        return Ok((starts, targets, vec![kind.name().to_string(); n]));
    }
    let per_frame: Vec<(Vec<f64>, Vec<f64>, String)> = (0..n)
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
                    (
                        retarget(&target, template, &layout),
                        retarget(&previous, template, &layout),
                        kind.name().to_string(),
                    )
                }
                PoseSource::Uniform => {
                    let mut target = vec![0.0; pd];
                    for (k, v) in target.iter_mut().enumerate() {
                        let (lo, hi) = if k == 1 {
                            (-0.3, 0.3)
                        } else {
                            (global.lower[k], global.upper[k])
                        };
                        *v = rng.random_range(lo..hi);
                    }
                    let mut previous = target.clone();
                    let local = Bounds::local(&target);
                    for k in 0..pd {
                        previous[k] = rng.random_range(local.lower[k]..local.upper[k]);
                    }
                    (target, previous, "uniform".to_string())
                }
            };
            global.clamp(&mut target[..]);
            let start = match config.scenario {
                Scenario::Local => {
                    // A hair inside the box, so that the target lies in the start's local box
                    // despite rounding.
                    let shrink = 1.0 - 1e-9;
                    let mut s = previous;
                    Bounds::around(
                        &target,
                        LOCAL_TRANSLATION * shrink,
                        LOCAL_ROTATION_DEG.to_radians() * shrink,
                    )
                    .clamp(&mut s);
                    s
                }
                _ => vec![0.0; pd],
            };
            let subject = subject_coefficients(&layout, config.seed, 1 + i as u64);
            (
                with_coefficients(start, &zeros),
                with_coefficients(target, &subject),
                name,
            )
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
    Ok((starts, targets, names))
}

enum FrameObs {
    Sparse(Vec<f64>, Vec<bool>),
    Scan {
        points: Vec<Vec3>,
        visible: Vec<bool>,
        silhouettes: Vec<lfit_model::scan::Mask>,
    },
    Silhouettes(Vec<lfit_model::scan::Mask>),
}

fn observe_frame(
    template: &Template,
    sensor: &Sensor,
    target: &[f64],
    noise: &NoiseConfig,
    rng: &mut ChaCha8Rng,
) -> FrameObs {
    // Every sensor is an observation model: its clean prediction, then its own corruption.
    let model = sensor.observation_model();
    let pred = sensor.predict_sparse(template, target);
    // `scan` renders its silhouettes from the clean surface.
    let silhouettes = match sensor {
        Sensor::Scan(setup) => render_silhouettes(
            &setup.cameras,
            &points_from_values(&pred.values),
            &template.faces,
        ),
        _ => Vec::new(),
    };
    let (mut values, mut visible) = (pred.values, pred.visible);
    model.corrupt(&mut values, &mut visible, noise, rng);
    match sensor {
        // Stored as masks (u8), not as a vector of f64 pixels.
        Sensor::Silhouettes(setup) => FrameObs::Silhouettes(setup.masks(&values)),
        // A point cloud with per-point visibility, and the silhouettes of the clean surface.
        Sensor::Scan(_) => FrameObs::Scan {
            points: points_from_values(&values),
            visible: visible.chunks_exact(3).map(|v| v[0]).collect(),
            silhouettes,
        },
        _ => FrameObs::Sparse(values, visible),
    }
}

/// Builds the per-frame distance transforms on grids of one common size, each centred on its
/// frame's (visible) point cloud, so that the dataset stores them as one `[N, Z, Y, X]` array.
fn assemble_scan(frames: Vec<FrameObs>, sensor: &Sensor) -> Result<Observations, SynthError> {
    let Sensor::Scan(setup) = sensor else {
        unreachable!("scan sensor")
    };
    let mut points = Vec::with_capacity(frames.len());
    let mut visible = Vec::with_capacity(frames.len());
    let mut silhouettes = Vec::with_capacity(frames.len());
    for f in frames {
        if let FrameObs::Scan {
            points: p,
            visible: v,
            silhouettes: s,
        } = f
        {
            points.push(p);
            visible.push(v);
            silhouettes.push(s);
        }
    }
    let clouds: Vec<Vec<Vec3>> = points
        .iter()
        .zip(&visible)
        .map(|(p, v)| {
            p.iter()
                .zip(v)
                .filter(|(_, b)| **b)
                .map(|(p, _)| *p)
                .collect()
        })
        .collect();
    let boxes = clouds
        .iter()
        .map(|c| VoxelGrid::around_points(c, setup.voxel_size, lfit_model::scan::DEFAULT_BOX_SCALE))
        .collect::<Result<Vec<_>, _>>()?;
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
            let mut grid = VoxelGrid {
                origin,
                spacing: b.spacing,
                dims,
                values: vec![0.0; dims.iter().product()],
            };
            squared_edt(&mut grid, cloud);
            grid
        })
        .collect();
    Ok(Observations::Scan {
        points,
        visible,
        grids,
        silhouettes,
    })
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
                let (starts, targets, _) = scenario_poses(&c, &t).unwrap();
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
        let (starts, targets, _) = scenario_poses(&c, &t).unwrap();
        for i in 1..30 {
            assert_eq!(starts[i], targets[i - 1]);
        }
    }

    #[test]
    fn other_models_get_retargeted_motion_uniform_poses_and_shapes_from_the_prior() {
        let (m, _) = lfit_model::body::morphable_default_template().unwrap();
        let layout = m.layout();
        let mut c = SynthConfig::new(Modality::Markers, Scenario::Local, 200, 5);
        let (starts, targets, _) = scenario_poses(&c, &m).unwrap();
        let global = Bounds::global_for(&m);
        let mut second_moment = 0.0;
        for (s, g) in starts.iter().zip(&targets) {
            assert_eq!((s.len(), g.len()), (65, 65));
            assert!(global.contains(g));
            assert!(Bounds::local_in(&layout, s).contains(g));
            assert!(
                s[57..].iter().all(|&b| b == 0.0),
                "starts have the mean shape"
            );
            second_moment += g[57..].iter().map(|b| b * b).sum::<f64>();
        }
        // β ~ N(0, I): the mean of β² over 200 × 8 draws is near 1.
        let mean_sq = second_moment / (200.0 * 8.0);
        assert!((0.85..1.15).contains(&mean_sq), "{mean_sq}");
        // The rigid template's poses are the same poses, so old datasets are reproduced.
        let d = lfit_model::default_template();
        let (_, rigid, _) = scenario_poses(&c, &d).unwrap();
        for (a, b) in rigid.iter().zip(&targets) {
            assert_eq!(&a[..], &b[..57]);
        }
        c.source = PoseSource::Uniform;
        assert!(scenario_poses(&c, &m).is_ok());
    }

    #[test]
    fn bad_configs_are_refused() {
        assert!(
            SynthConfig::new(Modality::Hmd, Scenario::Local, 0, 1)
                .validate()
                .is_err()
        );
        let mut c = SynthConfig::new(Modality::Hmd, Scenario::Sequence, 3, 1);
        c.source = PoseSource::Uniform;
        assert!(c.validate().is_err());
    }
}
