//! Dataset generation: poses from the motion library, imported motion files or uniform
//! sampling, the scenarios of papers/000 §4 (a start pose and a target per frame), observations
//! from the model crate's observation models, then noise and occlusion.

use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};

use glam::{DVec3, Vec3};
use lfit_model::Template;
use lfit_model::layout::Layout;
use lfit_model::observe::{KeypointSetup, MarkerSetup, Modality, Sensor, points_from_values};
use lfit_model::pose::{
    Bounds, FLOOR_SPREAD, LOCAL_ROTATION_DEG, LOCAL_TRANSLATION, POSE_DIM, Pose, SHAPE_BOUND,
};
use lfit_model::scan::{VoxelGrid, render_silhouettes, squared_edt};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, StandardNormal};
use rayon::prelude::*;

use crate::dataset::config::{FACE_TRANSLATION, MotionFile, PoseSource, Scenario, SynthConfig};
use crate::dataset::{Dataset, FORMAT_VERSION, Meta, Observations};
use crate::error::SynthError;
use crate::motion::augment::Augmenter;
use crate::motion::{MotionParams, motion_pose};
use crate::noise::NoiseConfig;

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
/// Streams of the marker slips ([`SynthConfig::marker_slip`]), one per subject.
const SLIP_STREAM: u64 = 9 << 32;
/// Streams of the keypoint biases ([`SynthConfig::keypoint_bias`]), one per subject.
const BIAS_STREAM: u64 = 11 << 32;
/// The stream of a detector's keypoint offsets ([`SynthConfig::keypoint_detector`]).
const DETECTOR_STREAM: u64 = 12 << 32;
/// Streams of the subjects' noise factors ([`SynthConfig::noise_spread`]), one per subject.
const NOISE_STREAM: u64 = 13 << 32;

/// The noise frame `frame` of a dataset made with `config` is observed with:
/// [`SynthConfig::noise`], times its subject's factor in `[1 − noise_spread, 1]` when the spread
/// is above 0 (drawn from the subject's own stream, apart from every other draw, so a set
/// without a spread keeps its bytes). Whoever observes a set's frames again (a training run's
/// random camera rigs) calls this with the set's config to give them the same noise.
pub fn frame_noise(config: &SynthConfig, frame: usize) -> NoiseConfig {
    if config.noise_spread <= 0.0 {
        return config.noise.clone();
    }
    let subject = subject_of(config.scenario, frame);
    let u: f64 = stream(config.seed, NOISE_STREAM + subject).random();
    config.noise.times(1.0 - config.noise_spread * u)
}

/// The keypoint offsets of the synthetic 2D detector `seed` ([`SynthConfig::keypoint_detector`])
/// on a skeleton of `joints` joints: per joint a normal draw of `sigma` (metres) per axis in
/// the rest frame, the same for every subject and dataset. What `lfit synth
/// --keypoint-detector` observes through, and what `lfit calibrate` should recover.
pub fn detector_offsets(seed: u64, sigma: f64, joints: usize) -> Vec<[f64; 3]> {
    normal_offsets(&mut stream(seed, DETECTOR_STREAM), sigma, joints)
}

/// `joints` offsets of `sigma` per axis.
fn normal_offsets(rng: &mut ChaCha8Rng, sigma: f64, joints: usize) -> Vec<[f64; 3]> {
    (0..joints)
        .map(|_| {
            [0; 3].map(|_| {
                let x: f64 = StandardNormal.sample(rng);
                x * sigma
            })
        })
        .collect()
}
/// Streams of the motion-file augmentation draws (apart from the pose streams, so a
/// configuration without augmentation gives the poses it gave before).
const AUGMENT_STREAM: u64 = 5 << 32;
/// Streams of the coins of [`SynthConfig::uniform_share`] (apart from the pose streams, so a
/// configuration without uniform poses gives the poses it gave before).
const UNIFORM_STREAM: u64 = 7 << 32;

/// Generates a dataset; `progress` is called with the number of frames done.
pub fn synthesize(
    config: &SynthConfig,
    template: &Template,
    sensor: &Sensor,
    progress: &(dyn Fn(usize) + Sync),
) -> Result<Dataset, SynthError> {
    synthesize_until(config, template, sensor, progress, &AtomicBool::new(false))
}

/// [`synthesize`] that stops with [`SynthError::Cancelled`] once `cancel` is set (another thread
/// sets it: a Ctrl-C seen by the caller); checked before every frame. Frames are independent
/// draws, so a run that is not cancelled gives exactly [`synthesize`]'s dataset.
pub fn synthesize_until(
    config: &SynthConfig,
    template: &Template,
    sensor: &Sensor,
    progress: &(dyn Fn(usize) + Sync),
    cancel: &AtomicBool,
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
    let (starts, targets, motions, fps) = scenario_poses(config, template)?;
    let done = AtomicUsize::new(0);
    let layout = template.layout();
    if let Some(i) = (0..config.frames).find(|&i| targets[i].len() != layout.dim()) {
        return Err(SynthError::Setting {
            name: "template",
            value: template.id.clone(),
            reason: format!("frame {i} has {} parameters", targets[i].len()),
        });
    }
    let slip = MarkerSlip::new(config, template, sensor);
    let bias = KeypointBias::new(config, template, sensor);
    let frames: Vec<FrameObs> = (0..config.frames)
        .into_par_iter()
        .map(|i| {
            if cancel.load(Ordering::Relaxed) {
                return Err(SynthError::Cancelled);
            }
            let mut rng = stream(config.seed, i as u64);
            // The subject's own marker placement, or its keypoints' offsets.
            let subject = subject_of(config.scenario, i);
            let own = match (&slip, &bias) {
                (Some(s), _) => Some(s.sensor(subject)),
                (None, Some(b)) => Some(b.sensor(subject)),
                (None, None) => None,
            };
            let observed = own.as_ref().unwrap_or(sensor);
            let noise = frame_noise(config, i);
            let obs = observe_frame(template, observed, &targets[i], &noise, &mut rng);
            progress(done.fetch_add(1, Ordering::Relaxed) + 1);
            Ok(obs)
        })
        .collect::<Result<_, _>>()?;
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
            config: SynthConfig {
                fps,
                ..config.clone()
            },
            frame_motions: motions,
            pose_dim: layout.pose_dim(),
            shape_dim: layout.shape,
            expression_dim: layout.expression,
        },
        sensor: sensor.clone(),
        start_poses: starts,
        gt_poses: targets,
        observations,
        reference: None,
    })
}

/// The marker placements of [`SynthConfig::marker_slip`]: each marker's candidate vertices
/// (those of its vertex's body part within four σ of its rest position, the mean shape's), and
/// per subject the candidate nearest to the rest position plus a normal draw of σ per axis.
struct MarkerSlip {
    setup: MarkerSetup,
    sigma: f64,
    seed: u64,
    rest: Vec<DVec3>,
    candidates: Vec<Vec<u32>>,
}

impl MarkerSlip {
    /// `None` without a slip (or for a sensor that is not markers: the config refuses that).
    fn new(config: &SynthConfig, template: &Template, sensor: &Sensor) -> Option<Self> {
        let Sensor::Markers(setup) = sensor else {
            return None;
        };
        if config.marker_slip <= 0.0 {
            return None;
        }
        let sigma = config.marker_slip;
        let rest = template.rest_positions();
        let dominant = template.dominant_joint();
        let reach2 = (4.0 * sigma).powi(2);
        let candidates = setup
            .vertices
            .iter()
            .map(|&m| {
                let (p, j) = (rest[m as usize], dominant[m as usize]);
                (0..rest.len() as u32)
                    .filter(|&u| {
                        dominant[u as usize] == j && rest[u as usize].distance_squared(p) <= reach2
                    })
                    .collect()
            })
            .collect();
        Some(Self {
            setup: setup.clone(),
            sigma,
            seed: config.seed,
            rest,
            candidates,
        })
    }

    /// The markers sensor of subject `subject`: every marker moved to its slipped vertex.
    fn sensor(&self, subject: u64) -> Sensor {
        let mut rng = stream(self.seed, SLIP_STREAM + subject);
        let vertices = self
            .setup
            .vertices
            .iter()
            .zip(&self.candidates)
            .map(|(&m, near)| {
                let offset = DVec3::new(
                    StandardNormal.sample(&mut rng),
                    StandardNormal.sample(&mut rng),
                    StandardNormal.sample(&mut rng),
                ) * self.sigma;
                let aim = self.rest[m as usize] + offset;
                // The marker's own vertex is always a candidate; the first nearest wins ties.
                near.iter()
                    .copied()
                    .min_by(|&a, &b| {
                        let da = self.rest[a as usize].distance_squared(aim);
                        let db = self.rest[b as usize].distance_squared(aim);
                        da.total_cmp(&db).then(a.cmp(&b))
                    })
                    .unwrap_or(m)
            })
            .collect();
        Sensor::Markers(MarkerSetup {
            names: self.setup.names.clone(),
            vertices,
            offsets: Vec::new(),
        })
    }
}

/// The keypoint offsets of [`SynthConfig::keypoint_bias`]: per subject and joint a normal draw
/// of σ per axis in the joint's rest frame.
struct KeypointBias {
    setup: KeypointSetup,
    sigma: f64,
    seed: u64,
    joints: usize,
    /// A detector's offsets, shared by every subject ([`SynthConfig::keypoint_detector`]).
    detector: Option<Vec<[f64; 3]>>,
}

impl KeypointBias {
    /// `None` without a bias (or for a sensor that is not keypoints2d: the config refuses that).
    fn new(config: &SynthConfig, template: &Template, sensor: &Sensor) -> Option<Self> {
        let Sensor::Keypoints2d(setup) = sensor else {
            return None;
        };
        let joints = template.rig.num_joints();
        (config.keypoint_bias > 0.0).then(|| Self {
            setup: setup.clone(),
            sigma: config.keypoint_bias,
            seed: config.seed,
            joints,
            detector: config
                .keypoint_detector
                .map(|seed| detector_offsets(seed, config.keypoint_bias, joints)),
        })
    }

    /// The keypoints2d sensor of subject `subject`: every keypoint at its drawn offset (the
    /// detector's, when there is one).
    fn sensor(&self, subject: u64) -> Sensor {
        let offsets = match &self.detector {
            Some(d) => d.clone(),
            None => normal_offsets(
                &mut stream(self.seed, BIAS_STREAM + subject),
                self.sigma,
                self.joints,
            ),
        };
        Sensor::Keypoints2d(self.setup.placed(offsets))
    }
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

/// The subject of frame `frame`: a sequence is one subject (0), every local or global frame its
/// own (`1 + frame`). Its β ([`subject_coefficients`]) and its marker placement
/// ([`MarkerSlip::sensor`]) are drawn from this index.
fn subject_of(scenario: Scenario, frame: usize) -> u64 {
    match scenario {
        Scenario::Sequence => 0,
        Scenario::Local | Scenario::Global => 1 + frame as u64,
    }
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

/// Start parameters, target parameters, the motion behind each frame, and the frame rate of
/// a sequence (the requested one, or that of the motion file's frames it holds).
type ScenarioPoses = (Vec<Vec<f64>>, Vec<Vec<f64>>, Vec<String>, f64);

/// The name of frame `index` of `file` in `frame_motions`: `clip.npz:17`, with ` (clamped)`
/// when the frame was moved into the model's bounds.
fn file_frame_name(file: &MotionFile, index: usize, clamped: bool) -> String {
    let suffix = if clamped { " (clamped)" } else { "" };
    format!("{}:{index}{suffix}", file.label())
}

/// Start parameters, targets and the motion behind each frame, in `template`'s layout. Targets
/// carry the subject's shape and expression; starts have the mean (zero) coefficients: a fitter
/// does not know them.
///
/// Frames of motion files (`config.motion_files`) follow the library's rules: the pose's
/// rotations and root height are the file's frame, its root x/z is moved onto the capture
/// floor as the library's are (local/global: a random spot within ±0.6 m, the previous frame
/// keeping its step; sequence: the window's mean x/z at the origin); local starts are an
/// earlier frame of the same file (0.03–0.25 s before; a later one near the file's start)
/// clamped into the target's local box, global starts the rest pose. Targets are clamped into
/// the model's global bounds (sequences: the rotations into the joint limits); the shape and
/// expression coefficients of a file's poses are not used (the subject's are drawn from the
/// prior as for the library).
fn scenario_poses(config: &SynthConfig, template: &Template) -> Result<ScenarioPoses, SynthError> {
    let layout = template.layout();
    let global = Bounds::global_for(template);
    let pd = layout.pose_dim();
    let n = config.frames;
    if config.uses_library() && template.info.joint_map.iter().all(Option::is_none) {
        return Err(SynthError::Setting {
            name: "source",
            value: "motion".into(),
            reason: format!(
                "model '{}' maps none of its joints to the papers/000 skeleton (lfit key 'joint_map'): use --source uniform{}",
                template.id,
                if config.with_library {
                    " or motion files without the library"
                } else {
                    " or motion files (--motions)"
                }
            ),
        });
    }
    let files = if config.source == PoseSource::Motion {
        &config.motion_files[..]
    } else {
        &[]
    };
    let mut clips = Vec::with_capacity(files.len());
    for f in files {
        let poses = f.poses()?;
        if let Some(clip) = &f.clip {
            clip.check_model(template)
                .map_err(|e| SynthError::MotionFile {
                    path: f.path.clone(),
                    reason: e.to_string(),
                })?;
        }
        clips.push(poses);
    }
    let augmenter = if files.is_empty() || config.motion_augment.is_none() {
        None
    } else {
        Some(
            Augmenter::new(config.motion_augment, template).map_err(|reason| {
                SynthError::Setting {
                    name: "motion_augment",
                    value: format!("{:?}", config.motion_augment),
                    reason,
                }
            })?,
        )
    };
    let with_coefficients = |mut pose: Vec<f64>, coefficients: &[f64]| {
        pose.extend_from_slice(coefficients);
        pose
    };
    let zeros = vec![0.0; layout.shape + layout.expression];
    if config.scenario == Scenario::Sequence {
        // A window of n + 1 frames (one before the first) of a file, at its stride.
        let eligible: Vec<usize> = (0..files.len())
            .filter(|&k| files[k].frames > n * files[k].stride(config.fps))
            .collect();
        if !files.is_empty() && eligible.is_empty() {
            return Err(SynthError::Setting {
                name: "frames",
                value: n.to_string(),
                reason: format!(
                    "a sequence of {n} frames needs {} consecutive frames of a motion file (one before the first) at about {} Hz; the longest file has {}",
                    n + 1,
                    config.fps,
                    files.iter().map(|f| f.frames).max().unwrap_or(0)
                ),
            });
        }
        let mut rng = stream(config.seed, POSE_STREAM);
        let from_file = !files.is_empty() && (!config.with_library || rng.random_bool(0.5));
        let (mut poses, names, fps): (Vec<Vec<f64>>, Vec<String>, f64) = if from_file {
            let k = eligible[rng.random_range(0..eligible.len())];
            let file = &files[k];
            let stride = file.stride(config.fps);
            let first = rng.random_range(0..=file.frames - 1 - n * stride);
            let mut names = Vec::with_capacity(n + 1);
            // One draw of the augmentation for the whole window.
            let transform = augmenter
                .as_ref()
                .map(|a| (a, a.draw(&mut stream(config.seed, AUGMENT_STREAM))));
            let poses = (0..=n)
                .map(|i| {
                    let index = first + i * stride;
                    let mut pose = clips[k][index][..pd].to_vec();
                    if let Some((a, t)) = &transform {
                        a.apply(t, &mut pose);
                    }
                    let before = pose.clone();
                    global.clamp(&mut pose[..]);
                    // Rotations into the limits; the path stays the file's (centred below).
                    pose[..3].copy_from_slice(&before[..3]);
                    names.push(file_frame_name(file, index, pose != before));
                    pose
                })
                .collect();
            (poses, names, file.fps / stride as f64)
        } else {
            let kind = config.motions[rng.random_range(0..config.motions.len())];
            let params = MotionParams::sample(kind, &mut rng);
            let t0 = rng.random_range(0.0..2.0);
            // One frame before the first, so that frame 0 also has a previous pose to start from.
            let poses: Vec<Pose> = (0..=n)
                .map(|k| motion_pose(kind, &params, t0 + (k as f64 - 1.0) / config.fps))
                .collect();
            (
                poses.iter().map(|p| p.to_vec()).collect(),
                vec![kind.name().to_string(); n + 1],
                config.fps,
            )
        };
        let (mx, mz) = poses
            .iter()
            .fold((0.0, 0.0), |(x, z), p| (x + p[0], z + p[2]));
        for p in &mut poses {
            p[0] -= mx / (n + 1) as f64;
            p[2] -= mz / (n + 1) as f64;
        }
        // One subject for the whole sequence; every frame starts from the previous frame's truth
        // pose with the mean coefficients (a fitter does not know the subject's: only frames that
        // are not warm-started read these starts, the first and a β pass's).
        let subject = subject_coefficients(&layout, config.seed, subject_of(config.scenario, 0));
        let poses: Vec<Vec<f64>> = poses
            .into_iter()
            .map(|p| {
                if from_file {
                    p
                } else {
                    let mut pose = [0.0; POSE_DIM];
                    pose.copy_from_slice(&p);
                    retarget(&pose, template, &layout)
                }
            })
            .collect();
        let starts = poses[..n]
            .iter()
            .map(|p| with_coefficients(p.clone(), &zeros))
            .collect();
        let targets = poses[1..]
            .iter()
            .map(|p| with_coefficients(p.clone(), &subject))
            .collect();
        return Ok((starts, targets, names[1..].to_vec(), fps));
    }
    let per_frame: Vec<(Vec<f64>, Vec<f64>, String)> = (0..n)
        .into_par_iter()
        .map(|i| {
            let mut rng = stream(config.seed, POSE_STREAM + 1 + i as u64);
            let from_file = !files.is_empty() && (!config.with_library || rng.random_bool(0.5));
            let source = if config.uniform_share > 0.0
                && stream(config.seed, UNIFORM_STREAM + 1 + i as u64)
                    .random_bool(config.uniform_share)
            {
                PoseSource::Uniform
            } else {
                config.source
            };
            let (mut target, previous, name) = match source {
                PoseSource::Motion if from_file => {
                    let k = rng.random_range(0..files.len());
                    let (file, poses) = (&files[k], clips[k]);
                    let index = rng.random_range(0..poses.len());
                    let dt = rng.random_range(1.0 / 30.0..0.25);
                    let step = ((dt * file.fps).round() as usize).max(1);
                    let before = if index >= step {
                        index - step
                    } else {
                        (index + step).min(poses.len() - 1)
                    };
                    let mut target = poses[index][..pd].to_vec();
                    let mut previous = poses[before][..pd].to_vec();
                    if let Some(a) = &augmenter {
                        let t = a.draw(&mut stream(config.seed, AUGMENT_STREAM + 1 + i as u64));
                        a.apply(&t, &mut target);
                        a.apply(&t, &mut previous);
                    }
                    let (x, z) = (
                        rng.random_range(-FLOOR_SPREAD..FLOOR_SPREAD),
                        rng.random_range(-FLOOR_SPREAD..FLOOR_SPREAD),
                    );
                    let (tx, tz) = (target[0], target[2]);
                    for p in [&mut previous, &mut target] {
                        p[0] += x - tx;
                        p[2] += z - tz;
                    }
                    let mut clamped = target.clone();
                    global.clamp(&mut clamped[..]);
                    let name = file_frame_name(file, index, clamped != target);
                    (target, previous, name)
                }
                PoseSource::Motion => {
                    let kind = config.motions[rng.random_range(0..config.motions.len())];
                    let params = MotionParams::sample(kind, &mut rng);
                    let t = rng.random_range(0.5..10.0);
                    let dt = rng.random_range(1.0 / 30.0..0.25);
                    let mut target = motion_pose(kind, &params, t);
                    let mut previous = motion_pose(kind, &params, t - dt);
                    // Put the subject somewhere on the capture floor, keeping the motion's step.
                    let (x, z) = (
                        rng.random_range(-FLOOR_SPREAD..FLOOR_SPREAD),
                        rng.random_range(-FLOOR_SPREAD..FLOOR_SPREAD),
                    );
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
                PoseSource::Face => {
                    let mut target = vec![0.0; pd];
                    for (k, v) in target.iter_mut().enumerate() {
                        *v = if k < 3 {
                            rng.random_range(-FACE_TRANSLATION[k]..=FACE_TRANSLATION[k])
                        } else {
                            rng.random_range(0.5 * global.lower[k]..=0.5 * global.upper[k])
                        };
                    }
                    let mut previous = target.clone();
                    let local = Bounds::local(&target);
                    for k in 0..pd {
                        previous[k] = rng.random_range(local.lower[k]..local.upper[k]);
                    }
                    (target, previous, "face".to_string())
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
            let subject =
                subject_coefficients(&layout, config.seed, subject_of(config.scenario, i));
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
    Ok((starts, targets, names, config.fps))
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
#[allow(clippy::unwrap_used)]
mod tests {
    use super::*;
    use crate::motion::MotionKind;
    use crate::motion::file::MotionClip;
    use lfit_model::default_template;
    use std::sync::Arc;

    #[test]
    fn scenarios_respect_their_boxes() {
        let t = default_template();
        for scenario in [Scenario::Local, Scenario::Global] {
            for source in [PoseSource::Motion, PoseSource::Uniform] {
                let mut c = SynthConfig::new(Modality::Markers, scenario, 40, 5);
                c.source = source;
                let (starts, targets, _, _) = scenario_poses(&c, &t).unwrap();
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
        let (starts, targets, _, _) = scenario_poses(&c, &t).unwrap();
        for i in 1..30 {
            assert_eq!(starts[i], targets[i - 1]);
        }
    }

    #[test]
    fn a_sequence_starts_from_the_previous_truth_pose_with_the_mean_shape() {
        // The subject's β is the truth: a sequence's starts (read by its first frame and by a β
        // pass) hold the previous frame's pose and the prior's mean, as local starts do.
        let (m, _) = lfit_model::body::morphable_default_template().unwrap();
        let pd = m.layout().pose_dim();
        let c = SynthConfig::new(Modality::Markers, Scenario::Sequence, 30, 5);
        let (starts, targets, _, _) = scenario_poses(&c, &m).unwrap();
        assert!(targets[0][pd..].iter().any(|&b| b != 0.0));
        for i in 0..30 {
            assert!(starts[i][pd..].iter().all(|&b| b == 0.0), "frame {i}");
            assert_eq!(targets[i][pd..], targets[0][pd..], "one subject");
            if i > 0 {
                assert_eq!(starts[i][..pd], targets[i - 1][..pd], "frame {i}");
            }
        }
    }

    #[test]
    fn other_models_get_retargeted_motion_uniform_poses_and_shapes_from_the_prior() {
        let (m, _) = lfit_model::body::morphable_default_template().unwrap();
        let layout = m.layout();
        let mut c = SynthConfig::new(Modality::Markers, Scenario::Local, 200, 5);
        let (starts, targets, _, _) = scenario_poses(&c, &m).unwrap();
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
        let (_, rigid, _, _) = scenario_poses(&c, &d).unwrap();
        for (a, b) in rigid.iter().zip(&targets) {
            assert_eq!(&a[..], &b[..57]);
        }
        c.source = PoseSource::Uniform;
        assert!(scenario_poses(&c, &m).is_ok());
    }

    /// A motion of `frames` frames on `template`: a smooth motion of every rotation, the root
    /// walking along x, with one frame far outside the joint limits.
    fn clip(template: &Template, frames: usize, fps: f64) -> MotionClip {
        let dim = template.layout().dim();
        let poses = (0..frames)
            .map(|f| {
                let t = f as f64 / fps;
                let mut p: Vec<f64> = (0..dim).map(|k| 0.3 * (0.7 * t + k as f64).sin()).collect();
                p[0] = 1.2 * t + 3.0;
                p[1] = 0.02 * t.sin();
                p[2] = -2.0;
                if f == 5 {
                    p[10] = 3.0;
                }
                p
            })
            .collect();
        MotionClip {
            poses,
            fps,
            source: "test".into(),
            model: template.signature(),
        }
    }

    fn with_files(scenario: Scenario, frames: usize, files: Vec<MotionFile>) -> SynthConfig {
        let mut c = SynthConfig::new(Modality::Markers, scenario, frames, 9);
        c.motion_files = files;
        c
    }

    /// Index of the file frame named by `name` (`file.npz:17`, maybe ` (clamped)`).
    fn frame_of(name: &str, label: &str) -> (usize, bool) {
        let rest = name.strip_prefix(&format!("{label}:")).unwrap();
        let clamped = rest.ends_with(" (clamped)");
        (
            rest.trim_end_matches(" (clamped)").parse().unwrap(),
            clamped,
        )
    }

    #[test]
    fn local_and_global_frames_of_motion_files_are_file_frames_placed_on_the_floor() {
        let (m, _) = lfit_model::body::morphable_default_template().unwrap();
        let layout = m.layout();
        let pd = layout.pose_dim();
        let global = Bounds::global_for(&m);
        let c = clip(&m, 60, 30.0);
        let file = MotionFile::from_clip("dir/walk.npz", c.clone(), &m).unwrap();
        assert_eq!((file.label().as_str(), file.frames), ("walk.npz", 60));
        for scenario in [Scenario::Local, Scenario::Global] {
            let config = with_files(scenario, 120, vec![file.clone()]);
            let (starts, targets, names, _) = scenario_poses(&config, &m).unwrap();
            let mut seen_clamped = false;
            for i in 0..120 {
                let (f, clamped) = frame_of(&names[i], "walk.npz");
                let mut want = c.poses[f][..pd].to_vec();
                let (x, z) = (targets[i][0], targets[i][2]);
                assert!(x.abs() <= 0.6 && z.abs() <= 0.6, "on the floor: {x} {z}");
                want[0] = x;
                want[2] = z;
                let mut clamped_want = want.clone();
                global.clamp(&mut clamped_want);
                assert_eq!(clamped, clamped_want != want, "{}", names[i]);
                seen_clamped |= clamped;
                assert_eq!(&targets[i][..pd], &clamped_want[..], "frame {i}");
                assert!(global.contains(&targets[i]));
                assert_eq!(targets[i].len(), layout.dim(), "β appended");
                match scenario {
                    Scenario::Local => {
                        assert!(Bounds::local_in(&layout, &starts[i]).contains(&targets[i]))
                    }
                    _ => assert_eq!(starts[i], vec![0.0; layout.dim()]),
                }
            }
            assert!(seen_clamped, "frame 5 is outside the limits and was drawn");
            // β is drawn as for the library: the same subjects.
            let library = SynthConfig::new(Modality::Markers, scenario, 120, 9);
            let (_, lib, _, _) = scenario_poses(&library, &m).unwrap();
            for (a, b) in lib.iter().zip(&targets) {
                assert_eq!(&a[pd..], &b[pd..]);
            }
        }
    }

    #[test]
    fn augmented_file_frames_are_the_plain_draws_mirrored_or_turned() {
        use crate::motion::augment::{MotionAugment, Transform};
        use glam::{DMat3, DQuat, DVec3};
        let t = default_template();
        let pd = t.layout().pose_dim();
        let n = t.rig.num_joints();
        let global = Bounds::global_for(&t);
        let c = clip(&t, 60, 30.0);
        let file = MotionFile::from_clip("walk.npz", c.clone(), &t).unwrap();
        let plain = with_files(Scenario::Local, 200, vec![file.clone()]);
        let (_, base, base_names, _) = scenario_poses(&plain, &t).unwrap();
        let mut config = plain.clone();
        config.motion_augment = MotionAugment {
            mirror: true,
            ..Default::default()
        };
        let (_, targets, names, _) = scenario_poses(&config, &t).unwrap();
        assert_eq!(scenario_poses(&config, &t).unwrap().1, targets, "same seed");
        let a = Augmenter::new(config.motion_augment, &t).unwrap();
        let flip = Transform {
            mirrored: true,
            heading: 0.0,
            jitter: vec![DVec3::ZERO; n],
        };
        let (mut kept, mut mirrored) = (0, 0);
        for i in 0..200 {
            // The pose stream is the plain run's: the same file frame, the same floor spot.
            let f = frame_of(&base_names[i], "walk.npz").0;
            assert_eq!(frame_of(&names[i], "walk.npz").0, f);
            if targets[i] == base[i] {
                kept += 1;
                continue;
            }
            let mut want = c.poses[f][..pd].to_vec();
            a.apply(&flip, &mut want);
            want[0] = targets[i][0];
            want[2] = targets[i][2];
            global.clamp(&mut want);
            for k in 0..pd {
                assert!(
                    (targets[i][k] - want[k]).abs() < 1e-12,
                    "frame {i} entry {k}"
                );
            }
            mirrored += 1;
        }
        assert!(
            kept > 60 && mirrored > 60,
            "{kept} kept, {mirrored} mirrored"
        );
        // Augmentation without motion files is refused; without it the key is not written.
        let mut library = SynthConfig::new(Modality::Markers, Scenario::Local, 5, 1);
        assert!(
            !serde_json::to_string(&library)
                .unwrap()
                .contains("motion_augment")
        );
        library.motion_augment.heading = true;
        let e = library.validate().unwrap_err().to_string();
        assert!(e.contains("motion_augment"), "{e}");

        // A sequence turns as a whole: one heading for every frame of the window.
        let c = clip(&t, 200, 120.0);
        let file = MotionFile::from_clip("a.npz", c.clone(), &t).unwrap();
        let mut config = with_files(Scenario::Sequence, 30, vec![file]);
        config.motion_augment = MotionAugment {
            heading: true,
            ..Default::default()
        };
        let (_, targets, names, _) = scenario_poses(&config, &t).unwrap();
        let quat = |p: &[f64]| {
            let r = DVec3::new(p[3], p[4], p[5]);
            DQuat::from_scaled_axis(r)
        };
        let mut turn = None;
        for i in 0..30 {
            let f = frame_of(&names[i], "a.npz").0;
            let file_rot = DMat3::from_quat(quat(&c.poses[f]));
            let got = DMat3::from_quat(quat(&targets[i]));
            let q = got * file_rot.transpose();
            // A turn about the vertical, the same for the whole window.
            assert!((q * DVec3::Y - DVec3::Y).length() < 1e-9, "frame {i}");
            let q = DQuat::from_mat3(&q);
            let q0 = *turn.get_or_insert(q);
            assert!(q.dot(q0).abs() > 1.0 - 1e-12, "frame {i}");
        }
        let angle = DQuat::to_axis_angle(turn.unwrap()).1;
        assert!(angle > 1e-3, "turned: {angle}");
    }

    #[test]
    fn a_sequence_of_a_motion_file_is_a_contiguous_window_at_the_file_stride() {
        let t = default_template();
        let c = clip(&t, 200, 120.0);
        let file = MotionFile::from_clip("a.npz", c.clone(), &t).unwrap();
        let config = with_files(Scenario::Sequence, 30, vec![file.clone()]);
        let (starts, targets, names, fps) = scenario_poses(&config, &t).unwrap();
        assert_eq!(fps, 30.0, "every 4th frame of a 120 Hz file");
        let first = frame_of(&names[0], "a.npz").0;
        let (mx, mz): (f64, f64) = (0..=30)
            .map(|k| &c.poses[first - 4 + 4 * k])
            .fold((0.0, 0.0), |(x, z), p| (x + p[0], z + p[2]));
        for i in 0..30 {
            let f = first + 4 * i;
            assert_eq!(frame_of(&names[i], "a.npz").0, f);
            let mut want = c.poses[f].clone();
            want[0] -= mx / 31.0;
            want[2] -= mz / 31.0;
            let mut g = Bounds::global();
            g.lower.drain(..3);
            g.upper.drain(..3);
            g.clamp(&mut want[3..]);
            for k in 0..POSE_DIM {
                assert!(
                    (targets[i][k] - want[k]).abs() < 1e-12,
                    "frame {i} entry {k}"
                );
            }
            if i > 0 {
                assert_eq!(starts[i], targets[i - 1]);
            }
        }
        // Too short for the sequence: one line naming the longest file.
        let config = with_files(Scenario::Sequence, 60, vec![file]);
        let e = scenario_poses(&config, &t).unwrap_err().to_string();
        assert!(e.contains("longest file has 200"), "{e}");
    }

    #[test]
    fn the_library_mixes_in_and_motion_files_for_another_model_are_refused() {
        let t = default_template();
        let file = MotionFile::from_clip("a.npz", clip(&t, 50, 30.0), &t).unwrap();
        let mut config = with_files(Scenario::Local, 200, vec![file.clone()]);
        config.with_library = true;
        let (_, _, names, _) = scenario_poses(&config, &t).unwrap();
        let from_file = names.iter().filter(|n| n.starts_with("a.npz:")).count();
        assert!(
            (70..130).contains(&from_file),
            "{from_file} of 200 from the file"
        );
        assert!(
            names
                .iter()
                .any(|n| MotionKind::ALL.iter().any(|k| k.name() == n))
        );
        // Same seed, same frames.
        assert_eq!(
            scenario_poses(&config, &t).unwrap(),
            scenario_poses(&config, &t).unwrap()
        );
        // Without files the library's frames are what they were.
        let plain = SynthConfig::new(Modality::Markers, Scenario::Local, 200, 9);
        let (_, _, names, _) = scenario_poses(&plain, &t).unwrap();
        assert!(names.iter().all(|n| !n.contains(':')));
        // Another model's motion.
        let (m, _) = lfit_model::body::morphable_default_template().unwrap();
        let e = MotionFile::from_clip("b.npz", clip(&m, 5, 30.0), &t)
            .unwrap_err()
            .to_string();
        assert!(
            e.starts_with("motion file b.npz: the motion was made for model"),
            "{e}"
        );
        let mut config = with_files(Scenario::Local, 3, vec![file.clone()]);
        config.motion_files[0].clip = Some(Arc::new(clip(&m, 5, 30.0)));
        config.motion_files[0].frames = 5;
        assert!(scenario_poses(&config, &t).is_err());
        // Settings that do not go together.
        let mut c = with_files(Scenario::Local, 3, vec![file.clone()]);
        c.source = PoseSource::Uniform;
        assert!(c.validate().is_err());
        let mut c = SynthConfig::new(Modality::Markers, Scenario::Local, 3, 1);
        c.with_library = true;
        assert!(c.validate().is_err());
        // A description read back from a dataset has no poses.
        let mut c = with_files(Scenario::Local, 3, vec![file]);
        c.motion_files[0].clip = None;
        assert!(c.validate().unwrap_err().to_string().contains("not loaded"));
    }

    #[test]
    fn a_cancelled_synthesis_stops_and_an_uncancelled_one_is_synthesize() {
        let t = default_template();
        let sensor = Sensor::default_for(Modality::Markers, &t);
        let c = SynthConfig::new(Modality::Markers, Scenario::Local, 40, 3);
        let plain = synthesize(&c, &t, &sensor, &|_| {}).unwrap();
        let until = synthesize_until(&c, &t, &sensor, &|_| {}, &AtomicBool::new(false)).unwrap();
        let (Observations::Sparse { values: a, .. }, Observations::Sparse { values: b, .. }) =
            (&plain.observations, &until.observations)
        else {
            panic!("markers datasets are sparse")
        };
        assert_eq!(a, b);
        assert_eq!(plain.gt_poses, until.gt_poses);
        // Set after 5 frames (from inside the run, as a Ctrl-C watcher would from outside).
        let cancel = AtomicBool::new(false);
        let seen = AtomicUsize::new(0);
        let big = SynthConfig::new(Modality::Markers, Scenario::Local, 5000, 3);
        let stopped = synthesize_until(
            &big,
            &t,
            &sensor,
            &|done| {
                seen.store(done, Ordering::Relaxed);
                if done >= 5 {
                    cancel.store(true, Ordering::Relaxed);
                }
            },
            &cancel,
        );
        assert!(matches!(stopped, Err(SynthError::Cancelled)), "{stopped:?}");
        // Each worker finishes at most the frame it was on.
        let done = seen.load(Ordering::Relaxed);
        assert!(done < 5 + rayon::current_num_threads() + 1, "{done} frames");
    }

    #[test]
    fn slipped_markers_stay_on_their_body_part_one_placement_per_subject() {
        let t = default_template();
        let sensor = Sensor::default_for(Modality::Markers, &t);
        let Sensor::Markers(nominal) = &sensor else {
            panic!("markers sensor")
        };
        let sigma = 0.03;
        let mut c = SynthConfig::new(Modality::Markers, Scenario::Local, 12, 5);
        c.noise = NoiseConfig::none();
        c.marker_slip = sigma;
        let slip = MarkerSlip::new(&c, &t, &sensor).expect("a slip");
        let (rest, dominant) = (t.rest_positions(), t.dominant_joint());
        let markers = |s: Sensor| match s {
            Sensor::Markers(m) => m,
            _ => panic!("markers sensor"),
        };
        let a = markers(slip.sensor(4));
        assert_eq!(a.names, nominal.names);
        let mut moved = 0.0;
        for (&m, &v) in nominal.vertices.iter().zip(&a.vertices) {
            assert_eq!(
                dominant[m as usize], dominant[v as usize],
                "marker {m} → {v}"
            );
            let d = rest[m as usize].distance(rest[v as usize]);
            assert!(d <= 4.0 * sigma + 1e-12, "marker {m} moved {d} m");
            moved += d;
        }
        let mean = moved / a.vertices.len() as f64;
        assert!(
            mean > 0.3 * sigma && mean < 3.0 * sigma,
            "mean slip {mean} m"
        );
        // One draw per subject: the same subject again is the same placement, another is not.
        assert_eq!(markers(slip.sensor(4)), a);
        assert_ne!(markers(slip.sensor(5)), a);

        // Local frames: frame i is subject 1 + i's placement; the dataset keeps the model's set.
        let data = synthesize(&c, &t, &sensor, &|_| {}).unwrap();
        assert_eq!(&markers(data.sensor.clone()), nominal);
        let Observations::Sparse { values, .. } = &data.observations else {
            panic!("sparse")
        };
        for (i, (obs, gt)) in values.iter().zip(&data.gt_poses).enumerate() {
            let own = slip.sensor(1 + i as u64).predict_sparse(&t, gt).values;
            assert_eq!(obs, &own, "frame {i}");
            assert_ne!(obs, &sensor.predict_sparse(&t, gt).values, "frame {i}");
        }
        // A sequence: one subject, one placement (subject 0) for every frame.
        let mut q = SynthConfig::new(Modality::Markers, Scenario::Sequence, 6, 5);
        q.noise = NoiseConfig::none();
        q.marker_slip = sigma;
        let seq = synthesize(&q, &t, &sensor, &|_| {}).unwrap();
        let Observations::Sparse { values, .. } = &seq.observations else {
            panic!("sparse")
        };
        let placed = MarkerSlip::new(&q, &t, &sensor).unwrap().sensor(0);
        for (obs, gt) in values.iter().zip(&seq.gt_poses) {
            assert_eq!(obs, &placed.predict_sparse(&t, gt).values);
        }
        // Without a slip the metadata does not name it (datasets keep their bytes).
        let plain = SynthConfig::new(Modality::Markers, Scenario::Local, 3, 5);
        assert!(
            !serde_json::to_string(&plain)
                .unwrap()
                .contains("marker_slip")
        );
        assert!(serde_json::to_string(&c).unwrap().contains("marker_slip"));
        assert!(MarkerSlip::new(&plain, &t, &sensor).is_none());
    }

    #[test]
    fn biased_keypoints_one_offset_set_per_subject() {
        let t = default_template();
        let sensor = Sensor::default_for(Modality::Keypoints2d, &t);
        let sigma = 0.03;
        let mut c = SynthConfig::new(Modality::Keypoints2d, Scenario::Local, 8, 5);
        c.noise = NoiseConfig::none();
        c.keypoint_bias = sigma;
        let bias = KeypointBias::new(&c, &t, &sensor).expect("a bias");
        let setup = |s: Sensor| match s {
            Sensor::Keypoints2d(k) => k,
            _ => panic!("keypoints2d sensor"),
        };
        let a = setup(bias.sensor(4));
        assert_eq!(a.offsets.len(), t.rig.num_joints());
        let n = 3 * a.offsets.len();
        let rms = (a.offsets.iter().flatten().map(|x| x * x).sum::<f64>() / n as f64).sqrt();
        assert!(rms > 0.7 * sigma && rms < 1.3 * sigma, "rms {rms} m");
        assert_eq!(setup(bias.sensor(4)), a);
        assert_ne!(setup(bias.sensor(5)), a);
        // Local frames: frame i is subject 1 + i's offsets; the dataset keeps the joint centres.
        let data = synthesize(&c, &t, &sensor, &|_| {}).unwrap();
        assert_eq!(data.sensor, sensor);
        let Observations::Sparse { values, .. } = &data.observations else {
            panic!("sparse")
        };
        for (i, (obs, gt)) in values.iter().zip(&data.gt_poses).enumerate() {
            let own = bias.sensor(1 + i as u64).predict_sparse(&t, gt).values;
            assert_eq!(obs, &own, "frame {i}");
            assert_ne!(obs, &sensor.predict_sparse(&t, gt).values, "frame {i}");
        }
        // A sequence: one subject, one set of offsets.
        let mut q = SynthConfig::new(Modality::Keypoints2d, Scenario::Sequence, 5, 5);
        q.noise = NoiseConfig::none();
        q.keypoint_bias = sigma;
        let seq = synthesize(&q, &t, &sensor, &|_| {}).unwrap();
        let Observations::Sparse { values, .. } = &seq.observations else {
            panic!("sparse")
        };
        let placed = KeypointBias::new(&q, &t, &sensor).unwrap().sensor(0);
        for (obs, gt) in values.iter().zip(&seq.gt_poses) {
            assert_eq!(obs, &placed.predict_sparse(&t, gt).values);
        }
        let plain = SynthConfig::new(Modality::Keypoints2d, Scenario::Local, 3, 5);
        assert!(
            !serde_json::to_string(&plain)
                .unwrap()
                .contains("keypoint_bias")
        );
        assert!(serde_json::to_string(&c).unwrap().contains("keypoint_bias"));
        assert!(KeypointBias::new(&plain, &t, &sensor).is_none());
        for bad in [-0.01, 0.2, f64::NAN] {
            let mut c = SynthConfig::new(Modality::Keypoints2d, Scenario::Local, 3, 1);
            c.keypoint_bias = bad;
            let e = c.validate().unwrap_err().to_string();
            assert!(e.contains("keypoint_bias"), "{e}");
        }
        let mut m = SynthConfig::new(Modality::Markers, Scenario::Local, 3, 1);
        m.keypoint_bias = 0.01;
        let e = m.validate().unwrap_err().to_string();
        assert!(e.contains("keypoint_bias") && e.contains("markers"), "{e}");
    }

    #[test]
    fn a_detector_offsets_every_subject_alike() {
        let t = default_template();
        let sensor = Sensor::default_for(Modality::Keypoints2d, &t);
        let sigma = 0.02;
        let config = |seed: u64, detector: Option<u64>| {
            let mut c = SynthConfig::new(Modality::Keypoints2d, Scenario::Local, 4, seed);
            c.noise = NoiseConfig::none();
            c.keypoint_bias = sigma;
            c.keypoint_detector = detector;
            c
        };
        let offsets = |c: &SynthConfig, subject: u64| match KeypointBias::new(c, &t, &sensor)
            .unwrap()
            .sensor(subject)
        {
            Sensor::Keypoints2d(k) => k.offsets,
            _ => panic!("keypoints2d sensor"),
        };
        let nj = t.rig.num_joints();
        let detector = detector_offsets(7, sigma, nj);
        assert_eq!(detector.len(), nj);
        // Every subject of every dataset seed: the detector's offsets.
        for seed in [5, 6] {
            for subject in [0, 1, 3] {
                assert_eq!(offsets(&config(seed, Some(7)), subject), detector);
            }
        }
        assert_ne!(detector_offsets(8, sigma, nj), detector);
        assert_ne!(offsets(&config(5, None), 1), offsets(&config(5, None), 2));
        // The frames are observed through it; the metadata names it only when set.
        let c = config(5, Some(7));
        let data = synthesize(&c, &t, &sensor, &|_| {}).unwrap();
        let Observations::Sparse { values, .. } = &data.observations else {
            panic!("sparse")
        };
        let placed = sensor.placed(detector.clone()).unwrap();
        for (obs, gt) in values.iter().zip(&data.gt_poses) {
            assert_eq!(obs, &placed.predict_sparse(&t, gt).values);
        }
        assert!(
            serde_json::to_string(&c)
                .unwrap()
                .contains("keypoint_detector")
        );
        assert!(
            !serde_json::to_string(&config(5, None))
                .unwrap()
                .contains("keypoint_detector")
        );
        // A detector without a bias is refused.
        let mut bare = config(5, Some(7));
        bare.keypoint_bias = 0.0;
        let e = bare.validate().unwrap_err().to_string();
        assert!(e.contains("keypoint_detector"), "{e}");
    }

    /// Under a noise spread every subject gets its own factor in `[1 − spread, 1]` (a sequence
    /// one for all its frames) and its observations carry that much noise; without one every
    /// frame has the set's noise and the metadata does not name the spread.
    #[test]
    fn a_noise_spread_gives_each_subject_its_own_noise() {
        let t = default_template();
        let sensor = Sensor::default_for(Modality::Markers, &t);
        let sigma = NoiseConfig::default().point_sigma;
        let mut c = SynthConfig::new(Modality::Markers, Scenario::Local, 60, 5);
        c.noise_spread = 0.8;
        let data = synthesize(&c, &t, &sensor, &|_| {}).unwrap();
        let Observations::Sparse { values, visible } = &data.observations else {
            panic!("sparse")
        };
        let mut factors = Vec::new();
        for (i, gt) in data.gt_poses.iter().enumerate() {
            let noise = frame_noise(&c, i);
            let f = noise.point_sigma / sigma;
            assert!((0.2 - 1e-12..=1.0).contains(&f), "frame {i}: factor {f}");
            // Every magnitude and rate by the same factor.
            let d = NoiseConfig::default();
            for (x, y) in [
                (noise.pixel_sigma, d.pixel_sigma),
                (noise.outlier_rate, d.outlier_rate),
                (noise.drop_rate, d.drop_rate),
            ] {
                assert!(
                    (x - f * y).abs() <= 1e-12 * y,
                    "frame {i}: {x} against {f} × {y}"
                );
            }
            let clean = sensor.predict_sparse(&t, gt).values;
            let mut dev: Vec<f64> = values[i]
                .iter()
                .zip(&clean)
                .zip(&visible[i])
                .filter(|(_, seen)| **seen)
                .map(|((o, c), _)| (o - c).abs())
                .collect();
            dev.sort_by(f64::total_cmp);
            // The median |N(0, σ²)| is 0.6745 σ.
            let ratio = dev[dev.len() / 2] / (0.6745 * noise.point_sigma);
            assert!(
                (0.5..1.6).contains(&ratio),
                "frame {i}: factor {f}, {ratio}"
            );
            factors.push(f);
        }
        let (lo, hi) = factors
            .iter()
            .fold((f64::INFINITY, 0.0f64), |(a, b), &f| (a.min(f), b.max(f)));
        assert!(lo < 0.4 && hi > 0.8, "factors {lo}..{hi}");
        assert!(serde_json::to_string(&c).unwrap().contains("noise_spread"));
        // The same config gives the same factors (its own stream per subject).
        assert_eq!(frame_noise(&c, 7), frame_noise(&c.clone(), 7));
        // A sequence: one subject, one factor.
        let mut q = SynthConfig::new(Modality::Markers, Scenario::Sequence, 6, 5);
        q.noise_spread = 0.8;
        let first = frame_noise(&q, 0);
        assert!((1..6).all(|i| frame_noise(&q, i) == first));
        // No spread: the set's noise for every frame, and the metadata does not name it.
        let plain = SynthConfig::new(Modality::Markers, Scenario::Local, 3, 5);
        assert!((0..3).all(|i| frame_noise(&plain, i) == plain.noise));
        assert!(
            !serde_json::to_string(&plain)
                .unwrap()
                .contains("noise_spread")
        );
        for bad in [-0.1, 1.5, f64::NAN] {
            let mut b = plain.clone();
            b.noise_spread = bad;
            let e = b.validate().unwrap_err().to_string();
            assert!(e.contains("noise_spread"), "{e}");
        }
    }

    #[test]
    fn bad_configs_are_refused() {
        for bad in [-0.01, 0.2, f64::NAN] {
            let mut c = SynthConfig::new(Modality::Markers, Scenario::Local, 3, 1);
            c.marker_slip = bad;
            let e = c.validate().unwrap_err().to_string();
            assert!(e.contains("marker_slip"), "{e}");
        }
        let mut c = SynthConfig::new(Modality::Hmd, Scenario::Local, 3, 1);
        c.marker_slip = 0.01;
        let e = c.validate().unwrap_err().to_string();
        assert!(e.contains("marker_slip") && e.contains("hmd"), "{e}");
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
