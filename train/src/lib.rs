//! Training of the neural fitter (SPEC §7, papers/002 supp. §6): batches synthesised on the fly
//! from the motion library, N unrolled iterations through the energy's residuals and gradients,
//! the per-step loss of supp. eq. (13)–(18), Adam with gradient clipping and a step decay of the
//! learning rate, validation on a fixed set (V2V and MPJPE per iteration), atomic checkpoints
//! with `--resume`, a NaN/Inf stop that keeps the last good checkpoint, and a metrics CSV.

pub mod loss;
pub mod starts;

use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Instant;

use burn::module::Module;
use burn::optim::grad_clipping::GradientClippingConfig;
use burn::optim::{AdamConfig, GradientsParams, ModuleOptimizer};
use burn::tensor::{Bytes, Device};
use lfit_model::camera::RigRanges;
use lfit_model::energy::{Energy, EnergyConfig, FloorForm, FloorPrior, Target};
use lfit_model::metrics::{mpjpe_mm, v2v_mm};
use lfit_model::observe::{KeypointSetup, Modality, Sensor};
use lfit_model::{Block, Bounds, Template};
use lfit_nn::checkpoint::{self, checkpoint_files, write_dir};
use lfit_nn::tensor::poses_to_tensor;
use lfit_nn::{
    Constraints, Direction, Dropout, FeatureStats, NetConfig, NeuralNet, StartMode, Views,
    observation_features, observation_features_for, residual_features, unroll,
};
use lfit_synth::motion::MotionKind;
use lfit_synth::{
    Dataset, MotionAugment, MotionFile, NoiseConfig, Observations, PoseSource, Scenario,
    SynthConfig, synthesize,
};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use serde_json::json;

pub use loss::{Loss, LossWeights};
pub use starts::StartMix;

/// Training errors; each is one line naming the cause.
#[derive(Debug, thiserror::Error)]
pub enum TrainError {
    #[error("training config {path}: {reason}")]
    Config { path: PathBuf, reason: String },
    #[error("invalid training setting {name} = {value}: {reason}")]
    Setting {
        name: &'static str,
        value: String,
        reason: String,
    },
    #[error(transparent)]
    Model(#[from] lfit_model::ModelError),
    #[error(transparent)]
    Synth(#[from] lfit_synth::SynthError),
    #[error(
        "loss became {value} at step {step}; training stopped, the last good checkpoint (step {last_good}) is in {dir}"
    )]
    NotFinite {
        value: f64,
        step: usize,
        last_good: usize,
        dir: PathBuf,
    },
    #[error("cannot start from the checkpoint {dir}: {reason}")]
    Init { dir: PathBuf, reason: String },
    #[error("cannot resume from {dir}: {reason}")]
    Resume { dir: PathBuf, reason: String },
}

pub type Result<T, E = TrainError> = std::result::Result<T, E>;

/// Everything a training run depends on (`lfit train --config FILE`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct TrainConfig {
    pub modality: Modality,
    /// Network; `modality` and `residual_dim` are filled in from the sensor.
    pub network: NetConfig,
    /// Optimiser steps.
    pub steps: usize,
    /// Frames per batch (papers/002 used 512 on 4 GPUs).
    pub batch: usize,
    /// Adam learning rate.
    pub learning_rate: f64,
    /// The learning rate is multiplied by `lr_decay` once `lr_decay_at` of the steps are done
    /// (papers/002 supp. §6.4: ×0.1 after 400 epochs).
    pub lr_decay: f64,
    pub lr_decay_at: f64,
    /// Per-parameter gradient norm clip.
    pub grad_clip: f64,
    pub loss: LossWeights,
    /// Frames of the fixed validation set and how often to validate (steps).
    pub val_frames: usize,
    pub val_every: usize,
    /// Checkpoint every this many steps (and at the end).
    pub checkpoint_every: usize,
    /// Frames used to measure the feature statistics.
    pub stats_frames: usize,
    pub seed: u64,
    /// Observation noise and occlusion of the synthesised training data (multiplier of the
    /// default noise model; 0 = clean).
    pub noise: f64,
    /// Every synthesised set (training batches, validation, statistics, the sequence windows of
    /// `"starts"`) observes each subject with `noise` times a factor drawn uniformly in
    /// `[1 − noise_spread, 1]` ([`SynthConfig::noise_spread`]), so the network meets quiet and
    /// noisy sensors and can read which from the residuals. 0 (the default): every subject
    /// with `noise`.
    #[serde(default, skip_serializing_if = "is_zero")]
    pub noise_spread: f64,
    /// Imported motion files (`lfit motion import`, paths relative to the working directory)
    /// that every synthesised set (training batches, validation, statistics) draws its target
    /// poses from instead of the procedural library, as `lfit synth --motions` does.
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub motions: Vec<PathBuf>,
    /// With `motions`: each frame from the library or the files by a fair coin
    /// (`lfit synth --with-library`).
    #[serde(skip_serializing_if = "std::ops::Not::not")]
    pub with_library: bool,
    /// With `motions`: transforms of the files' frames in every synthesised set
    /// ([`MotionAugment`]: `{"mirror": true, "heading": true, "jitter_deg": 5}`); absent: none.
    #[serde(skip_serializing_if = "MotionAugment::is_none")]
    pub motion_augment: MotionAugment,
    /// The procedural library's motion kinds the synthesised sets draw from (`lfit synth
    /// --library-motions`), by name: e.g. the papers' nine and the thirteen extended kinds
    /// (`"sit"`, `"crouch"`, `"kneel"`, `"pickup"`, `"throw"`, `"overhead"`, `"lie"`, `"crawl"`,
    /// `"fall"`, `"stairs"`, `"spin"`, `"circle"`, `"flight"`). Absent: the papers' nine
    /// ([`MotionKind::CLASSIC`]).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub library_motions: Option<Vec<MotionKind>>,
    /// The share of single-frame targets (training batches, validation, statistics; not the
    /// sequence windows of `"starts"`) drawn uniformly within the model's joint limits instead
    /// of from the motions ([`SynthConfig::uniform_share`]; issue 25's "poses sampled uniformly
    /// within the limits"). Absent: 0.
    #[serde(default, skip_serializing_if = "is_zero")]
    pub uniform_poses: f64,
    /// Where target poses come from (`lfit synth --source`): `motion` (the default: the library
    /// or `motions`, local scenario) or `face` (papers/002's face protocol, global scenario: the
    /// fitter starts from the rest pose or Φ(D)). `uniform` is refused.
    #[serde(skip_serializing_if = "is_motion")]
    pub source: PoseSource,
    /// The energy the network learns to minimise (and sees the residuals and gradient of); default
    /// the gradient variant of the default energy. A checkpoint is fitted with the energy it was
    /// trained on (the face's: `configs/face-energy.json`).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub energy: Option<EnergyConfig>,
    /// Random camera rigs of a pooled `keypoints2d` network (`network.views = "pooled"`): every
    /// synthesised frame (training batches, validation, statistics) is seen by a rig of its own
    /// drawn from these ranges ([`RigRanges`]; absent: its defaults, 1–8 cameras). Refused for a
    /// fixed-rig network, which fits only the sensor it was trained on.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub rigs: Option<RigRanges>,
    /// `markers`: the probability that a whole marker of a synthesised frame (training batches,
    /// validation, statistics) is made invisible, on top of the noise model's dropouts, so the
    /// network learns to fit with missing markers. 0 (the default): none.
    #[serde(skip_serializing_if = "is_zero")]
    pub marker_dropout: f64,
    /// `markers`: every synthesised set (training batches, validation, statistics, the sequence
    /// windows of `"starts"`) observes each subject's markers slipped off the model's marker
    /// vertices by this σ in millimetres ([`SynthConfig::marker_slip`], `lfit synth
    /// --marker-slip-mm`), so the network learns to fit a hand-placed marker set. 0 (the
    /// default): the model's marker vertices.
    #[serde(default, skip_serializing_if = "is_zero")]
    pub marker_slip_mm: f64,
    /// Where each sample's θ0 comes from ([`StartMix`]: Φ(D), the scenario's start, perturbed
    /// truth, the rigidly aligned rest pose, the network's own previous-frame result). Absent:
    /// `network.start` decides alone (Φ(D), the scenario's start, or either by a fair coin).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub starts: Option<StartMix>,
    /// The subject's height as a prior in a share of the synthesised frames' energies
    /// (`lfit fit --height-prior`; [`HeightPriorTraining`]), so the network learns to read the
    /// row. Absent: none.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub height_prior: Option<HeightPriorTraining>,
    /// A floor under the subject's soles in a share of the synthesised frames' energies
    /// (`lfit fit --floor contact:…`; [`FloorTraining`]), so the network learns to read the
    /// row. Absent: none.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub floor: Option<FloorTraining>,
    /// Data-parallel shards of each batch (1, the default: the whole batch in one autodiff
    /// graph). With K > 1, row `i` goes to shard `i mod K` and the K shards run forward and
    /// backward on K threads at once, their gradients summed (weighted by rows: the gradient of
    /// the batch mean). BatchNorm then normalises each shard by its own statistics (as in
    /// multi-GPU training without synchronised BatchNorm), and dropout draws from one stream per
    /// shard, so a run with K shards is a different run from K = 1, deterministic for its K.
    #[serde(skip_serializing_if = "is_one")]
    pub shards: usize,
}

fn is_one(x: &usize) -> bool {
    *x == 1
}

fn is_zero(x: &f64) -> bool {
    *x == 0.0
}

fn is_motion(s: &PoseSource) -> bool {
    *s == PoseSource::Motion
}

impl Default for TrainConfig {
    fn default() -> Self {
        Self {
            modality: Modality::Markers,
            network: NetConfig::default(),
            steps: 2000,
            batch: 64,
            learning_rate: 1e-3,
            lr_decay: 0.1,
            lr_decay_at: 0.8,
            grad_clip: 1.0,
            loss: LossWeights::default(),
            val_frames: 128,
            val_every: 100,
            checkpoint_every: 200,
            stats_frames: 256,
            seed: 0,
            noise: 1.0,
            noise_spread: 0.0,
            motions: Vec::new(),
            with_library: false,
            motion_augment: MotionAugment::default(),
            library_motions: None,
            uniform_poses: 0.0,
            source: PoseSource::Motion,
            energy: None,
            rigs: None,
            marker_dropout: 0.0,
            marker_slip_mm: 0.0,
            starts: None,
            height_prior: None,
            floor: None,
            shards: 1,
        }
    }
}

/// `"height_prior"` of a training config: each synthesised frame (training batches, validation,
/// statistics, the sequence windows of `"starts"`) gets, with probability `rate`, the height
/// prior of `lfit fit --height-prior` in its energy: a standard deviation σ drawn log-uniformly
/// from `std_m` and a height of the subject's true rest height plus σ times a standard normal
/// draw — a height as wrong as the prior says it may be.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct HeightPriorTraining {
    pub rate: f64,
    /// The range of σ (metres), `[low, high]`.
    pub std_m: [f64; 2],
}

/// `"floor"` of a training config: each synthesised frame (training batches, validation,
/// statistics, the sequence windows of `"starts"`) gets, with probability `rate`, the `contact`
/// floor of `lfit fit --floor` in its energy: a standard deviation σ drawn log-uniformly from
/// `std_m`, at the height of the frame's true lowest sole plus `offset_m` times a standard
/// normal draw — at inference the floor is one level for a whole sequence (`truth`: the median
/// of the truth's lowest soles), and a frame's soles rest a few centimetres above or below it.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FloorTraining {
    pub rate: f64,
    /// The range of σ (metres), `[low, high]`.
    pub std_m: [f64; 2],
    /// The standard deviation of the floor's height about the frame's lowest sole (metres, ≥ 0).
    pub offset_m: f64,
}

impl TrainConfig {
    /// Reads a JSON config; unknown fields and bad values are errors naming the file.
    pub fn load(path: &Path) -> Result<Self> {
        let text = std::fs::read_to_string(path).map_err(|e| TrainError::Config {
            path: path.into(),
            reason: format!("cannot read: {e}"),
        })?;
        let config: Self = serde_json::from_str(&text).map_err(|e| TrainError::Config {
            path: path.into(),
            reason: format!("malformed JSON: {e}"),
        })?;
        config.validate().map_err(|e| TrainError::Config {
            path: path.into(),
            reason: e.to_string(),
        })?;
        Ok(config)
    }

    pub fn validate(&self) -> Result<()> {
        let bad = |name, value: String, reason: &str| {
            Err(TrainError::Setting {
                name,
                value,
                reason: reason.into(),
            })
        };
        if matches!(self.modality, Modality::Scan | Modality::Silhouettes) {
            return bad(
                "modality",
                self.modality.to_string(),
                "the neural fitter supports markers, keypoints2d, hmd and landmarks2d",
            );
        }
        if self.source == PoseSource::Uniform {
            return bad(
                "source",
                "uniform".into(),
                "training draws from motion (the library or motion files) or face",
            );
        }
        if self.source == PoseSource::Face && !self.motions.is_empty() {
            return bad(
                "source",
                "face".into(),
                "the face protocol draws its own head poses: drop \"motions\"",
            );
        }
        if let Some(e) = &self.energy {
            e.validate().map_err(|err| TrainError::Setting {
                name: "energy",
                value: "{..}".into(),
                reason: err.to_string(),
            })?;
            if !e.is_differentiable() {
                return bad(
                    "energy",
                    "{..}".into(),
                    "the network needs the gradient variant: \"angle_prior\": \"hinge\" and \"silhouettes\": false",
                );
            }
        }
        self.validate_views()?;
        if self.steps == 0 {
            return bad("steps", "0".into(), "must be at least 1");
        }
        if self.batch < 2 {
            return bad(
                "batch",
                self.batch.to_string(),
                "must be at least 2 (BatchNorm needs batch statistics)",
            );
        }
        if self.shards == 0 || self.shards > 16 || self.batch / self.shards < 2 {
            return bad(
                "shards",
                self.shards.to_string(),
                &format!(
                    "must be 1 to 16 and leave each shard at least 2 rows of the batch of {} (BatchNorm needs batch statistics)",
                    self.batch
                ),
            );
        }
        if !(self.learning_rate.is_finite() && self.learning_rate > 0.0) {
            return bad(
                "learning_rate",
                self.learning_rate.to_string(),
                "must be positive",
            );
        }
        if !(self.lr_decay.is_finite() && self.lr_decay > 0.0)
            || !(0.0..=1.0).contains(&self.lr_decay_at)
        {
            return bad(
                "lr_decay/lr_decay_at",
                format!("{}/{}", self.lr_decay, self.lr_decay_at),
                "decay must be positive and its point in [0, 1]",
            );
        }
        if !(self.grad_clip.is_finite() && self.grad_clip > 0.0) {
            return bad("grad_clip", self.grad_clip.to_string(), "must be positive");
        }
        if self.val_frames < 2
            || self.val_every == 0
            || self.checkpoint_every == 0
            || self.stats_frames < 2
        {
            return bad(
                "val_frames/val_every/checkpoint_every/stats_frames",
                format!(
                    "{}/{}/{}/{}",
                    self.val_frames, self.val_every, self.checkpoint_every, self.stats_frames
                ),
                "must be positive (frame counts at least 2)",
            );
        }
        if !(self.noise.is_finite() && self.noise >= 0.0) {
            return bad("noise", self.noise.to_string(), "must be ≥ 0");
        }
        if let Some(reason) = lfit_synth::noise_spread_problem(self.noise_spread) {
            return bad("noise_spread", self.noise_spread.to_string(), &reason);
        }
        if let Some(mix) = &self.starts {
            mix.validate(self.source)?;
            if mix.previous_count(self.batch) >= self.batch {
                return bad(
                    "starts.previous",
                    mix.previous.to_string(),
                    "leaves no sample of the batch to the other sources",
                );
            }
        }
        if let Err(reason) = self
            .motion_augment
            .validate_for(self.motions.len(), "list them in \"motions\"")
        {
            return bad(
                "motion_augment",
                format!("{:?}", self.motion_augment),
                &reason,
            );
        }
        if self.library_motions.as_ref().is_some_and(Vec::is_empty) {
            return bad(
                "library_motions",
                "[]".into(),
                "names no motion kind: list some, or drop the key for the papers' nine",
            );
        }
        if self.library_motions.is_some() && !self.motions.is_empty() && !self.with_library {
            return bad(
                "library_motions",
                format!("{:?}", self.library_motions),
                "is unused: the frames come from \"motions\" only; add \"with_library\": true",
            );
        }
        if self.with_library && self.motions.is_empty() {
            return bad(
                "with_library",
                "true".into(),
                "mixes the library with motion files: list them in \"motions\"",
            );
        }
        if !(0.0..=1.0).contains(&self.uniform_poses) {
            return bad(
                "uniform_poses",
                self.uniform_poses.to_string(),
                "is a share of frames: between 0 and 1",
            );
        }
        if self.uniform_poses > 0.0 && self.source != PoseSource::Motion {
            return bad(
                "uniform_poses",
                self.uniform_poses.to_string(),
                "mixes uniform poses into motion frames: drop it with \"source\": \"face\"",
            );
        }
        Ok(())
    }

    /// Checks `network.views`, `rigs` and `marker_dropout` against the modality.
    fn validate_views(&self) -> Result<()> {
        let bad = |name, value: String, reason: String| {
            Err(TrainError::Setting {
                name,
                value,
                reason,
            })
        };
        let pooled = self.network.views == Views::Pooled;
        if pooled && self.modality != Modality::Keypoints2d {
            return bad(
                "network.views",
                "pooled".into(),
                format!("pools keypoints2d cameras; {} has none", self.modality),
            );
        }
        if let Some(r) = &self.rigs {
            if !pooled {
                return bad(
                    "rigs",
                    "{..}".into(),
                    "random rigs train a camera-agnostic network: set network.views to \"pooled\""
                        .into(),
                );
            }
            r.validate().map_err(|e| TrainError::Setting {
                name: "rigs",
                value: "{..}".into(),
                reason: e.to_string(),
            })?;
        }
        if !(self.marker_dropout.is_finite() && (0.0..1.0).contains(&self.marker_dropout)) {
            return bad(
                "marker_dropout",
                self.marker_dropout.to_string(),
                "must be in [0, 1)".into(),
            );
        }
        if self.marker_dropout > 0.0 && self.modality != Modality::Markers {
            return bad(
                "marker_dropout",
                self.marker_dropout.to_string(),
                format!("drops markers; {} data has none", self.modality),
            );
        }
        if let Some(reason) =
            lfit_synth::marker_slip_problem(self.marker_slip_mm / 1000.0, self.modality)
        {
            return bad("marker_slip_mm", self.marker_slip_mm.to_string(), reason);
        }
        if let Some(h) = &self.height_prior {
            let [low, high] = h.std_m;
            if !(h.rate.is_finite() && (0.0..=1.0).contains(&h.rate)) {
                return bad(
                    "height_prior.rate",
                    h.rate.to_string(),
                    "must be in [0, 1]".into(),
                );
            }
            if !(low.is_finite() && high.is_finite() && low > 0.0 && low <= high) {
                return bad(
                    "height_prior.std_m",
                    format!("[{low}, {high}]"),
                    "must be metres with 0 < low ≤ high".into(),
                );
            }
        }
        if let Some(f) = &self.floor {
            let [low, high] = f.std_m;
            if !(f.rate.is_finite() && (0.0..=1.0).contains(&f.rate)) {
                return bad("floor.rate", f.rate.to_string(), "must be in [0, 1]".into());
            }
            if !(low.is_finite() && high.is_finite() && low > 0.0 && low <= high) {
                return bad(
                    "floor.std_m",
                    format!("[{low}, {high}]"),
                    "must be metres with 0 < low ≤ high".into(),
                );
            }
            if !(f.offset_m.is_finite() && f.offset_m >= 0.0) {
                return bad(
                    "floor.offset_m",
                    f.offset_m.to_string(),
                    "must be metres ≥ 0".into(),
                );
            }
        }
        Ok(())
    }

    /// Learning rate at `step` (0-based).
    pub fn lr_at(&self, step: usize) -> f64 {
        if (step as f64) >= self.lr_decay_at * self.steps as f64 {
            self.learning_rate * self.lr_decay
        } else {
            self.learning_rate
        }
    }
}

/// Seeds of the synthesised data: training batches, validation, statistics, and (for
/// evaluation elsewhere) a held-out test range none of them touches.
pub mod seeds {
    /// Seed of the random rigs of a set synthesised with dataset seed `frames`.
    pub fn rigs(frames: u64) -> u64 {
        frames ^ 0x5215_0000_0000_0001
    }
    /// Seed of the marker dropout of a set synthesised with dataset seed `frames`.
    pub fn marker_dropout(frames: u64) -> u64 {
        frames ^ 0xD209_0000_0000_0002
    }
    /// Seed of the height priors of a set synthesised with dataset seed `frames`.
    pub fn height_prior(frames: u64) -> u64 {
        frames ^ 0x4E16_0000_0000_0003
    }
    /// Seed of the floors of a set synthesised with dataset seed `frames`.
    pub fn floor(frames: u64) -> u64 {
        frames ^ 0xF100_0000_0000_0004
    }
    /// Dataset seed of training batch `step`.
    pub fn batch(seed: u64, step: usize) -> u64 {
        seed.wrapping_mul(0x9E37_79B9_7F4A_7C15)
            .wrapping_add(1_000_000 + step as u64)
    }
    pub fn validation(seed: u64) -> u64 {
        seed.wrapping_mul(0x9E37_79B9_7F4A_7C15).wrapping_add(1)
    }
    pub fn stats(seed: u64) -> u64 {
        seed.wrapping_mul(0x9E37_79B9_7F4A_7C15).wrapping_add(2)
    }
    /// First seed of held-out test sets: far from every training seed of any run with a
    /// training `seed` below 2^20 and fewer than 2^40 steps.
    pub const TEST_BASE: u64 = 0x7E57_0000_0000_0000;
}

/// Synthesised frames with their energies.
pub struct Frames {
    pub dataset: Dataset,
    pub energies: Vec<Energy>,
}

/// Where synthesised frames take their target poses from: the procedural library (the
/// default), or imported motion files (with the library too if `with_library`).
#[derive(Debug, Clone, Default)]
pub struct Motions {
    pub files: Vec<MotionFile>,
    pub with_library: bool,
    /// Transforms of the files' frames.
    pub augment: MotionAugment,
    /// The library's motion kinds; `None`: [`MotionKind::CLASSIC`].
    pub library: Option<Vec<MotionKind>>,
    /// `face`: papers/002's face protocol in the global scenario instead.
    pub source: PoseSource,
    /// The share of single frames with uniform poses ([`SynthConfig::uniform_share`]).
    pub uniform_share: f64,
    /// The markers' slip σ in metres ([`SynthConfig::marker_slip`]).
    pub marker_slip: f64,
    /// The spread of the subjects' noise ([`SynthConfig::noise_spread`]).
    pub noise_spread: f64,
}

impl Motions {
    /// The motion files of `config` read and checked against `template`.
    pub fn load(config: &TrainConfig, template: &Template) -> Result<Self> {
        Ok(Self {
            files: config
                .motions
                .iter()
                .map(|p| MotionFile::load(p, template))
                .collect::<Result<_, _>>()?,
            with_library: config.with_library,
            augment: config.motion_augment,
            library: config.library_motions.clone(),
            source: config.source,
            uniform_share: config.uniform_poses,
            marker_slip: config.marker_slip_mm / 1000.0,
            noise_spread: config.noise_spread,
        })
    }

    /// Sets `config`'s motion files, library mix, augmentation, library kinds, (but for a
    /// sequence, which follows one motion) share of uniform poses, the markers' slip and the
    /// noise's spread to these (the pose source and the noise are the caller's).
    pub fn apply_to(&self, config: &mut SynthConfig) {
        config.motion_files = self.files.clone();
        config.with_library = self.with_library;
        config.motion_augment = self.augment;
        if let Some(kinds) = &self.library {
            config.motions = kinds.clone();
        }
        if config.scenario != Scenario::Sequence {
            config.uniform_share = self.uniform_share;
        }
        config.marker_slip = self.marker_slip;
        config.noise_spread = self.noise_spread;
    }
}

/// A dataset of `frames` local-scenario frames (start near the target, papers/000 §4) with
/// noise, and one gradient-variant energy per frame.
pub fn synth_frames(
    template: &Arc<Template>,
    sensor: &Sensor,
    base: &Energy,
    frames: usize,
    seed: u64,
    noise: f64,
) -> Result<Frames> {
    synth_frames_with(
        template,
        sensor,
        base,
        frames,
        seed,
        noise,
        &Motions::default(),
    )
}

/// [`synth_frames`] with target poses from `motions`.
pub fn synth_frames_with(
    template: &Arc<Template>,
    sensor: &Sensor,
    base: &Energy,
    frames: usize,
    seed: u64,
    noise: f64,
    motions: &Motions,
) -> Result<Frames> {
    let scenario = if motions.source == PoseSource::Face {
        Scenario::Global
    } else {
        Scenario::Local
    };
    let mut config = SynthConfig::new(sensor.modality(), scenario, frames, seed);
    motions.apply_to(&mut config);
    config.source = motions.source;
    config.noise = noise_model(noise)?;
    let dataset = synthesize(&config, template, sensor, &|_| {})?;
    let Observations::Sparse { values, visible } = &dataset.observations else {
        return Err(TrainError::Setting {
            name: "modality",
            value: sensor.modality().to_string(),
            reason: "needs a sparse modality".into(),
        });
    };
    let energies = values
        .par_iter()
        .zip(visible.par_iter())
        .map(|(v, s)| base.with_target(v.clone(), s.clone()))
        .collect::<Result<Vec<_>, _>>()?;
    Ok(Frames { dataset, energies })
}

/// The noise model of a run's synthesised sets for its `"noise"` multiplier: none at 0 (a
/// noise-free set's metadata then names no outlier sizes either), the defaults scaled otherwise.
pub(crate) fn noise_model(noise: f64) -> Result<NoiseConfig> {
    Ok(if noise == 0.0 {
        NoiseConfig::none()
    } else {
        NoiseConfig::scaled(noise)?
    })
}

/// The gradient-variant energy of a modality on `template`, with an empty (invisible) target;
/// frames clone it with their own targets ([`Energy::with_target`]).
pub fn base_energy(template: &Arc<Template>, sensor: &Sensor) -> Result<Energy> {
    base_energy_with(template, sensor, EnergyConfig::default().for_gradient())
}

/// [`base_energy`] with the energy configuration `config` (a training config's `energy`).
pub fn base_energy_with(
    template: &Arc<Template>,
    sensor: &Sensor,
    config: EnergyConfig,
) -> Result<Energy> {
    let dim = sensor.residual_dim(template);
    Ok(Energy::new(
        template.clone(),
        sensor.clone(),
        Target::Sparse {
            values: vec![0.0; dim],
            visible: vec![false; dim],
        },
        config,
    )?)
}

/// What a training config changes in synthesised frames (`seed`: the set's dataset seed): a
/// pooled network's frames get random rigs ([`random_rigs`], `config.rigs`), markers frames
/// lose markers with `config.marker_dropout` ([`drop_markers`]); other frames pass unchanged.
pub fn augment_frames(
    config: &TrainConfig,
    base: &Energy,
    mut frames: Frames,
    seed: u64,
) -> Result<Frames> {
    if config.network.views == Views::Pooled {
        let ranges = config.rigs.clone().unwrap_or_default();
        random_rigs(&mut frames, base, &ranges, seeds::rigs(seed))?;
    }
    if config.marker_dropout > 0.0 {
        drop_markers(
            &mut frames,
            config.marker_dropout,
            seeds::marker_dropout(seed),
        )?;
    }
    if let Some(h) = &config.height_prior {
        add_height_priors(&mut frames, h, seeds::height_prior(seed))?;
    }
    if let Some(f) = &config.floor {
        add_floors(&mut frames, f, seeds::floor(seed))?;
    }
    Ok(frames)
}

/// The height prior's vertices on `template`, measured once per model in a process
/// ([`lfit_model::stature::StatureVertices`]: ~30 whole-mesh scans) and reused by every set.
fn stature_prior(template: &Template) -> Result<lfit_model::energy::HeightPrior> {
    static CACHE: std::sync::Mutex<Vec<(String, usize, lfit_model::energy::HeightPrior)>> =
        std::sync::Mutex::new(Vec::new());
    let key = (template.id.clone(), template.vertices.len());
    let mut cache = CACHE
        .lock()
        .unwrap_or_else(std::sync::PoisonError::into_inner);
    if let Some((.., p)) = cache.iter().find(|(id, n, _)| (id, n) == (&key.0, &key.1)) {
        return Ok(p.clone());
    }
    let p = lfit_model::energy::HeightPrior::at_mean_shape(template, 1.0)?;
    cache.push((key.0, key.1, p.clone()));
    Ok(p)
}

/// Gives frames of `frames` a height prior ([`HeightPriorTraining`]): frame `i` draws from
/// stream `i` of `seed` whether it gets one, its σ and its height's error.
pub fn add_height_priors(
    frames: &mut Frames,
    setting: &HeightPriorTraining,
    seed: u64,
) -> Result<()> {
    let Some(first) = frames.energies.first() else {
        return Ok(());
    };
    let template = first.template().clone();
    let base = stature_prior(&template)?;
    let shape = template.layout().range(Block::Shape);
    add_rows(
        frames,
        seed,
        setting.rate,
        setting.std_m,
        |e, gt, std, z| {
            let truth = base.rest_height(&template, &gt[shape.clone()]);
            let prior = base.at((truth + std * z).max(0.1 * truth))?.with_std(std)?;
            e.with_height_prior(&prior)
        },
    )
}

/// Gives each frame of `frames` whose [`row_draw`] gets one the row `add` builds from its
/// energy, its truth, its σ and its standard normal draw (`"height_prior"`, `"floor"`).
fn add_rows(
    frames: &mut Frames,
    seed: u64,
    rate: f64,
    std_m: [f64; 2],
    add: impl Fn(&Energy, &[f64], f64, f64) -> lfit_model::Result<Energy> + Sync,
) -> Result<()> {
    frames.energies = frames
        .energies
        .par_iter()
        .zip(&frames.dataset.gt_poses)
        .enumerate()
        .map(|(i, (e, gt))| match row_draw(seed, i, rate, std_m) {
            Some((std, z)) => add(e, gt, std, z),
            None => Ok(e.clone()),
        })
        .collect::<Result<Vec<_>, _>>()?;
    Ok(())
}

/// Frame `i`'s draw for a row of `"height_prior"` or `"floor"`, from stream `i` of `seed`:
/// `None` where it gets none (probability `1 − rate`), else its σ (log-uniform in `std_m`) and a
/// standard normal draw for its error.
fn row_draw(seed: u64, i: usize, rate: f64, std_m: [f64; 2]) -> Option<(f64, f64)> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    rng.set_stream(i as u64);
    if !rng.random_bool(rate) {
        return None;
    }
    let [low, high] = std_m;
    let std = (low.ln() + (high.ln() - low.ln()) * rng.random::<f64>()).exp();
    let z: f64 = rand_distr::Distribution::sample(&rand_distr::StandardNormal, &mut rng);
    Some((std, z))
}

/// Gives frames of `frames` a `contact` floor ([`FloorTraining`]): frame `i` draws from stream
/// `i` of `seed` whether it gets one, its σ and its height's offset from the frame's true
/// lowest sole.
pub fn add_floors(frames: &mut Frames, setting: &FloorTraining, seed: u64) -> Result<()> {
    let Some(first) = frames.energies.first() else {
        return Ok(());
    };
    let base = FloorPrior::new(first.template(), 0.0, setting.std_m[0], FloorForm::Contact)?;
    add_rows(
        frames,
        seed,
        setting.rate,
        setting.std_m,
        |e, gt, std, z| {
            let sole = e.lowest_sole(&base, gt)?;
            e.with_floor(&base.at(sole + setting.offset_m * z)?.with_std(std)?)
        },
    )
}

/// [`synth_frames_with`] then [`augment_frames`]: the frames a training run with `config` sees.
pub fn training_frames(
    config: &TrainConfig,
    template: &Arc<Template>,
    sensor: &Sensor,
    base: &Energy,
    frames: usize,
    seed: u64,
    motions: &Motions,
) -> Result<Frames> {
    let f = synth_frames_with(template, sensor, base, frames, seed, config.noise, motions)?;
    augment_frames(config, base, f, seed)
}

/// Gives every frame its own random `keypoints2d` rig drawn from `ranges` around the frame's
/// subject (aimed at its root joint), and its observations in that rig: the clean projection
/// of the ground truth corrupted by the noise the set's frame was synthesised with
/// ([`lfit_synth::frame_noise`]: the set's noise, times its subject's factor under a
/// `noise_spread`). Frame `i` draws from stream `i` of `seed`, so the same seed gives the same
/// rigs and observations.
/// `frames.energies` carry the new rigs; `frames.dataset` keeps the poses (its `observations`
/// and `sensor` remain those of the synthesised rig).
pub fn random_rigs(
    frames: &mut Frames,
    base: &Energy,
    ranges: &RigRanges,
    seed: u64,
) -> Result<()> {
    ranges.validate()?;
    let synthesised = frames.dataset.meta.config.clone();
    let template = base.template();
    let root = template
        .rig
        .joints
        .first()
        .map_or(glam::DVec3::ZERO, |j| j.rest());
    frames.energies = frames
        .dataset
        .gt_poses
        .par_iter()
        .enumerate()
        .map(|(i, gt)| {
            let mut rng = ChaCha8Rng::seed_from_u64(seed);
            rng.set_stream(i as u64);
            let at = root + glam::DVec3::new(gt[0], gt[1], gt[2]);
            let sensor = Sensor::Keypoints2d(KeypointSetup::new(ranges.sample(&mut rng, at)));
            let pred = sensor.predict_sparse(template, gt);
            let (mut values, mut visible) = (pred.values, pred.visible);
            let noise = lfit_synth::frame_noise(&synthesised, i);
            sensor
                .observation_model()
                .corrupt(&mut values, &mut visible, &noise, &mut rng);
            base.with_sensor(sensor, values, visible)
        })
        .collect::<Result<Vec<_>, _>>()?;
    Ok(())
}

/// Makes each whole marker (3 entries) of every frame invisible with probability `rate` (its
/// values become 0, as the noise model reports unseen markers); frame `i` draws from stream `i`
/// of `seed`. Markers already unseen stay unseen.
pub fn drop_markers(frames: &mut Frames, rate: f64, seed: u64) -> Result<()> {
    if !(rate.is_finite() && (0.0..=1.0).contains(&rate)) {
        return Err(TrainError::Setting {
            name: "marker_dropout",
            value: rate.to_string(),
            reason: "must be in [0, 1)".into(),
        });
    }
    frames.energies = frames
        .energies
        .par_iter()
        .enumerate()
        .map(|(i, e)| {
            let (Target::Sparse { values, visible }, Modality::Markers) =
                (e.target(), e.modality())
            else {
                return Err(lfit_model::ModelError::Target(format!(
                    "marker dropout needs markers data, not {}",
                    e.sensor().name()
                )));
            };
            let mut rng = ChaCha8Rng::seed_from_u64(seed);
            rng.set_stream(i as u64);
            let (mut values, mut visible) = (values.clone(), visible.clone());
            for (v, s) in values.chunks_mut(3).zip(visible.chunks_mut(3)) {
                if rng.random_bool(rate) {
                    v.fill(0.0);
                    s.fill(false);
                }
            }
            e.with_target(values, visible)
        })
        .collect::<Result<Vec<_>, _>>()?;
    Ok(())
}

/// The residual length a network of `net` (views) has on `sensor`: the sensor's, or for a
/// pooled network one camera's part of it (the sensor must be `keypoints2d`).
pub fn network_residual_dim(
    net: &NetConfig,
    sensor: &Sensor,
    template: &Template,
) -> Result<usize> {
    let dim = sensor.residual_dim(template);
    match (net.views, sensor) {
        (Views::Fixed, _) => Ok(dim),
        (Views::Pooled, Sensor::Keypoints2d(s)) if !s.cameras.is_empty() => {
            Ok(dim / s.cameras.len())
        }
        (Views::Pooled, _) => Err(TrainError::Setting {
            name: "network.views",
            value: "pooled".into(),
            reason: format!(
                "pools the cameras of a keypoints2d sensor; this {} sensor has none",
                sensor.name()
            ),
        }),
    }
}

/// The residuals, gradients and poses of every frame at the poses the fitter visits early
/// (the scenario's start pose, the rest pose at the origin where Φ starts, and halfway to the
/// target).
type Visited = Vec<(Vec<Vec<f64>>, Vec<Vec<f64>>, Vec<Vec<f64>>)>;

fn visited(frames: &Frames, net: &NetConfig) -> Result<Visited> {
    let d = &frames.dataset;
    frames
        .energies
        .par_iter()
        .enumerate()
        .map(|(i, e)| {
            let start = d.start_poses[i].clone();
            let gt = &d.gt_poses[i];
            let mut half = start.clone();
            for (h, g) in half.iter_mut().zip(gt) {
                *h = 0.5 * (*h + g);
            }
            let (mut r, mut g, mut p) = (Vec::new(), Vec::new(), Vec::new());
            for pose in [start, vec![0.0; gt.len()], half] {
                r.push(e.residual(&pose));
                g.push(lfit_nn::direction(net, e, &pose, None)?);
                p.push(pose.to_vec());
            }
            Ok((r, g, p))
        })
        .collect::<std::result::Result<Visited, lfit_model::ModelError>>()
        .map_err(Into::into)
}

/// [`measure_stats`] for the features of a network configured as `net`: pooled features for a
/// pooled network ([`lfit_nn::features`]).
pub fn measure_stats_with(frames: &Frames, net: &NetConfig) -> Result<FeatureStats> {
    if net.views == Views::Fixed && net.direction == Direction::Gradient {
        return Ok(measure_stats(frames));
    }
    let mut obs = Vec::new();
    let (mut res, mut grad, mut pose) = (Vec::new(), Vec::new(), Vec::new());
    for (e, (r, g, p)) in frames.energies.iter().zip(visited(frames, net)?) {
        obs.push(observation_features_for(net, e)?);
        for r in &r {
            res.push(residual_features(net, e, r)?.into_owned());
        }
        grad.extend(g);
        pose.extend(p);
    }
    Ok(FeatureStats::measure(&obs, &res, &grad, &pose))
}

/// Feature statistics from `frames`: observations, and residuals/gradients/poses at the poses
/// the fitter visits early (the scenario's start poses, the rest pose at the origin where Φ
/// starts, and halfway to the target).
pub fn measure_stats(frames: &Frames) -> FeatureStats {
    let mut obs = Vec::new();
    let (mut res, mut grad, mut pose) = (Vec::new(), Vec::new(), Vec::new());
    // The gradient direction of the default network evaluates on every energy.
    let visited = visited(frames, &NetConfig::default()).unwrap_or_default();
    for (e, (r, g, p)) in frames.energies.iter().zip(visited) {
        obs.push(observation_features(e));
        res.extend(r);
        grad.extend(g);
        pose.extend(p);
    }
    FeatureStats::measure(&obs, &res, &grad, &pose)
}

/// Rows of a training batch as the loss sees them: their energies, starts and ground truths.
#[derive(Clone, Copy)]
struct BatchRows<'a> {
    energies: &'a [&'a Energy],
    starts: &'a [Option<Vec<f64>>],
    gt: &'a [Vec<f64>],
}

/// The loss of `rows` unrolled by `net` (papers/002 supp. eq. 13, summed over the iterates), on
/// the autodiff `device`; a known-shape network is held at the rows' true β.
#[allow(clippy::too_many_arguments)]
fn rows_loss(
    net: &NeuralNet,
    stats: &FeatureStats,
    loss: &Loss,
    template: &Template,
    rows: BatchRows<'_>,
    dropout: &mut Dropout<'_>,
    device: &Device,
) -> Result<burn::tensor::Tensor<1>> {
    let truth = loss.truth(poses_to_tensor(rows.gt, device));
    let constraints = net
        .config
        .known_shape
        .then(|| known_shape_constraints(template, rows.gt));
    let out = unroll(
        net,
        stats,
        rows.energies,
        rows.starts,
        constraints.as_ref(),
        device,
        dropout,
    )?;
    Ok(loss.total(&out.poses, &truth))
}

/// What a step's backward pass gives the optimiser: the whole batch's loss (differentiated
/// when the loss has been checked finite) or the shards' summed gradients.
enum StepGrads {
    Whole(burn::tensor::Tensor<1>),
    Sharded(GradientsParams),
}

impl StepGrads {
    fn into_params(self, net: &NeuralNet) -> GradientsParams {
        match self {
            StepGrads::Whole(total) => GradientsParams::from_grads(total.backward(), net),
            StepGrads::Sharded(grads) => grads,
        }
    }
}

fn scalar_of(total: &burn::tensor::Tensor<1>) -> Result<f64> {
    Ok(f64::from(
        total
            .clone()
            .detach()
            .try_into_scalar::<f32>()
            .map_err(|e| lfit_model::ModelError::Backend(format!("cannot read the loss: {e}")))?,
    ))
}

/// Data-parallel step ([`TrainConfig::shards`]): row `i` of the batch goes to shard `i mod K`;
/// each shard unrolls and differentiates its rows on its own thread with its own copy of the
/// network (same parameters, its own autodiff leaves and BatchNorm statistics) and its own
/// dropout stream (seeded from `rng` in shard order), its loss weighted by its share of the rows
/// so the summed gradients are those of the batch mean. Gradients are summed and the BatchNorm
/// running statistics averaged in shard order, so the result does not depend on scheduling.
#[allow(clippy::too_many_arguments)]
fn sharded_step(
    net: &NeuralNet,
    stats: &FeatureStats,
    loss: &Loss,
    template: &Template,
    batch: BatchRows<'_>,
    shards: usize,
    dropout: f64,
    rng: &mut ChaCha8Rng,
    device: &Device,
) -> Result<(f64, StepGrads)> {
    let rows = batch.energies.len();
    let seeds: Vec<u64> = (0..shards).map(|_| rng.random::<u64>()).collect();
    let copies: Vec<NeuralNet> = (0..shards)
        .map(|k| {
            if k == 0 {
                net.clone()
            } else {
                net.valid().train()
            }
        })
        .collect();
    let pick = |k: usize| -> Vec<usize> { (k..rows).step_by(shards).collect() };
    let run = |k: usize, copy: &NeuralNet| -> Result<(f64, GradientsParams)> {
        let idx = pick(k);
        let energies: Vec<&Energy> = idx.iter().map(|&i| batch.energies[i]).collect();
        let starts: Vec<Option<Vec<f64>>> = idx.iter().map(|&i| batch.starts[i].clone()).collect();
        let gt: Vec<Vec<f64>> = idx.iter().map(|&i| batch.gt[i].clone()).collect();
        let mut shard_rng = ChaCha8Rng::seed_from_u64(seeds[k]);
        let total = rows_loss(
            copy,
            stats,
            loss,
            template,
            BatchRows {
                energies: &energies,
                starts: &starts,
                gt: &gt,
            },
            &mut Dropout {
                p: dropout,
                rng: Some(&mut shard_rng),
            },
            device,
        )?;
        let value = scalar_of(&total)?;
        let share = idx.len() as f64 / rows as f64;
        if !value.is_finite() {
            // The caller stops on the non-finite loss; no gradient is taken.
            return Ok((value * share, GradientsParams::new()));
        }
        let grads = GradientsParams::from_grads(total.mul_scalar(share).backward(), copy);
        Ok((value * share, grads))
    };
    let results: Vec<Result<(f64, GradientsParams)>> = std::thread::scope(|scope| {
        let handles: Vec<_> = copies[1..]
            .iter()
            .enumerate()
            .map(|(j, copy)| scope.spawn(move || run(j + 1, copy)))
            .collect();
        let mut results = vec![run(0, &copies[0])];
        for h in handles {
            results.push(h.join().unwrap_or_else(|_| {
                Err(
                    lfit_model::ModelError::Backend("a training shard's thread panicked".into())
                        .into(),
                )
            }));
        }
        results
    });
    let mut value = 0.0;
    let mut sum = burn::optim::GradientsAccumulator::<NeuralNet>::new();
    for r in results {
        let (v, g) = r?;
        value += v;
        sum.accumulate(net, g);
    }
    let others: Vec<&NeuralNet> = copies[1..].iter().collect();
    copies[0].average_running_stats(&others);
    Ok((value, StepGrads::Sharded(sum.grads())))
}

/// Constraints of a known-shape network ([`lfit_nn::NetConfig::known_shape`], papers/002 §3.2):
/// every pose entry free and unbounded, the shape entries frozen at the truth (lower = upper =
/// β of `gt`), so θ0 (Φ(D) or the start pose) is clamped onto the true β and no update moves it.
pub fn known_shape_constraints(template: &Template, gt: &[Vec<f64>]) -> Constraints {
    let layout = template.layout();
    let shape = layout.range(Block::Shape);
    let dim = layout.dim();
    let free: Vec<bool> = (0..dim).map(|i| !shape.contains(&i)).collect();
    Constraints {
        free: vec![free; gt.len()],
        bounds: gt
            .iter()
            .map(|g| {
                let (mut lower, mut upper) =
                    (vec![f64::NEG_INFINITY; dim], vec![f64::INFINITY; dim]);
                for i in shape.clone() {
                    lower[i] = g[i];
                    upper[i] = g[i];
                }
                Bounds { lower, upper }
            })
            .collect(),
    }
}

/// The constraints `net` trains and validates under: [`known_shape_constraints`] for a
/// known-shape network, none otherwise.
fn training_constraints(net: &NeuralNet, frames: &Frames) -> Option<Constraints> {
    net.config
        .known_shape
        .then(|| known_shape_constraints(frames.energies[0].template(), &frames.dataset.gt_poses))
}

/// Validation errors per iteration θ0 … θN, averaged over frames (mm).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Validation {
    pub v2v_mm: Vec<f64>,
    pub mpjpe_mm: Vec<f64>,
}

/// Runs `net` (inference mode) on `frames` from Φ(D) (or from the start poses) and measures
/// V2V/MPJPE after every iteration.
pub fn validate(
    net: &NeuralNet,
    stats: &FeatureStats,
    frames: &Frames,
    from_start: bool,
    device: &Device,
) -> Result<Validation> {
    let refs: Vec<&Energy> = frames.energies.iter().collect();
    let starts: Vec<Option<Vec<f64>>> = frames
        .dataset
        .start_poses
        .iter()
        .map(|s| from_start.then(|| s.clone()))
        .collect();
    let constraints = training_constraints(net, frames);
    let out = unroll(
        net,
        stats,
        &refs,
        &starts,
        constraints.as_ref(),
        device,
        &mut Dropout::off(),
    )?;
    let template = frames.energies[0].template();
    let gt = &frames.dataset.gt_poses;
    let per = |f: fn(&Template, &[f64], &[f64]) -> f64| -> Vec<f64> {
        out.host
            .iter()
            .map(|poses| {
                poses
                    .par_iter()
                    .zip(gt.par_iter())
                    .map(|(p, g)| f(template, p, g))
                    .sum::<f64>()
                    / gt.len() as f64
            })
            .collect()
    };
    Ok(Validation {
        v2v_mm: per(v2v_mm),
        mpjpe_mm: per(mpjpe_mm),
    })
}

/// What the trainer reports to its caller (progress bars, logs).
#[derive(Debug, Clone)]
pub enum Event {
    Step {
        step: usize,
        steps: usize,
        loss: f64,
    },
    Validation {
        step: usize,
        validation: Validation,
    },
    Checkpoint {
        step: usize,
    },
}

/// Resume state written next to the checkpoint.
#[derive(Debug, Clone, Serialize, Deserialize)]
struct TrainState {
    /// Steps completed.
    step: usize,
    elapsed_s: f64,
    config: TrainConfig,
}

const OPTIMIZER_FILE: &str = "optimizer.bpk";
const STATE_FILE: &str = "train_state.json";
pub const METRICS_CSV: &str = "metrics.csv";

/// Options of one run besides the config.
#[derive(Debug, Clone)]
pub struct RunOptions {
    pub out: PathBuf,
    pub device_name: String,
    pub resume: bool,
    /// Start from this checkpoint's weights and feature statistics instead of a fresh network
    /// (fine-tuning: a new run of `steps` steps with a fresh optimiser, in `out`). The
    /// checkpoint must have the run's network, modality, residual size and model; refused with
    /// `resume`.
    pub init: Option<PathBuf>,
    /// The command line, recorded in the metrics card.
    pub command: String,
}

/// What a finished run reports.
#[derive(Debug, Clone, Serialize)]
pub struct Summary {
    pub steps: usize,
    pub time_s: f64,
    pub samples_per_s: f64,
    pub first_validation: Validation,
    pub final_validation: Validation,
    pub parameters: usize,
}

/// Trains a network on `template` as configured and writes checkpoints to `options.out`, with
/// the default sensor of `config.modality`.
pub fn train(
    config: &TrainConfig,
    template: Arc<Template>,
    device: &Device,
    options: &RunOptions,
    report: &(dyn Fn(Event) + Sync),
) -> Result<Summary> {
    let sensor = Sensor::default_for(config.modality, &template);
    train_with_sensor(config, template, &sensor, device, options, report)
}

/// [`train`] with a given sensor: another setup of a built-in modality, or an observation model
/// defined outside lfit ([`Sensor::Custom`], with `config.modality` [`Modality::Custom`]).
pub fn train_with_sensor(
    config: &TrainConfig,
    template: Arc<Template>,
    sensor: &Sensor,
    device: &Device,
    options: &RunOptions,
    report: &(dyn Fn(Event) + Sync),
) -> Result<Summary> {
    config.validate()?;
    if let Some(dir) = &options.init {
        if options.resume {
            return Err(TrainError::Init {
                dir: dir.clone(),
                reason:
                    "a fine-tuning run starts from a checkpoint; --resume continues one (not both)"
                        .into(),
            });
        }
        let same = match (dir.canonicalize(), options.out.canonicalize()) {
            (Ok(a), Ok(b)) => a == b,
            _ => false,
        };
        if same {
            return Err(TrainError::Init {
                dir: dir.clone(),
                reason: "--out is the checkpoint itself (write the fine-tuned run elsewhere)"
                    .into(),
            });
        }
    }
    if sensor.modality() != config.modality {
        return Err(TrainError::Setting {
            name: "modality",
            value: config.modality.to_string(),
            reason: format!("the sensor is a {} sensor", sensor.name()),
        });
    }
    sensor.validate(&template)?;
    let mut net_config = config.network.clone();
    net_config.modality = config.modality;
    net_config.residual_dim = network_residual_dim(&net_config, sensor, &template)?;
    net_config.param_dim = template.param_dim();
    net_config.validate()?;
    if net_config.known_shape && template.layout().shape == 0 {
        return Err(TrainError::Setting {
            name: "network.known_shape",
            value: "true".into(),
            reason: format!("model '{}' has no shape parameters to give", template.id),
        });
    }
    let base = base_energy_with(
        &template,
        &sensor,
        config
            .energy
            .clone()
            .unwrap_or_else(|| EnergyConfig::default().for_gradient()),
    )?;
    let motions = Motions::load(config, &template)?;
    let ad = device.clone().autodiff();
    let loss = Loss::new(&template, config.loss.clone(), &ad);

    let val = synth_frames_with(
        &template,
        &sensor,
        &base,
        config.val_frames,
        seeds::validation(config.seed),
        config.noise,
        &motions,
    )?;
    let val = augment_frames(config, &base, val, seeds::validation(config.seed))?;
    let mut optim: ModuleOptimizer = AdamConfig::new()
        .with_grad_clipping(Some(GradientClippingConfig::Norm(config.grad_clip as f32)))
        .init();

    let (mut net, stats, start_step, elapsed0) = if options.resume {
        let ck = checkpoint::load(&options.out, &ad).map_err(|e| TrainError::Resume {
            dir: options.out.clone(),
            reason: e.to_string(),
        })?;
        let state: TrainState =
            serde_json::from_slice(&std::fs::read(options.out.join(STATE_FILE)).map_err(|e| {
                TrainError::Resume {
                    dir: options.out.clone(),
                    reason: format!("no {STATE_FILE}: {e}"),
                }
            })?)
            .map_err(|e| TrainError::Resume {
                dir: options.out.clone(),
                reason: format!("malformed {STATE_FILE}: {e}"),
            })?;
        // Only `steps` may change (to extend a run); everything else must be the same config.
        if (TrainConfig {
            steps: config.steps,
            ..state.config.clone()
        }) != *config
        {
            return Err(TrainError::Resume { dir: options.out.clone(), reason: "the checkpoint was trained with another config (pass the same --config; only --steps may change)".into() });
        }
        if state.step >= config.steps {
            return Err(TrainError::Resume {
                dir: options.out.clone(),
                reason: format!(
                    "the run already has {} steps (ask for more with --steps)",
                    state.step
                ),
            });
        }
        ck.check_compatible(
            &options.out,
            config.modality,
            net_config.residual_dim,
            &template,
        )
        .map_err(|e| TrainError::Resume {
            dir: options.out.clone(),
            reason: e.to_string(),
        })?;
        let bytes =
            std::fs::read(options.out.join(OPTIMIZER_FILE)).map_err(|e| TrainError::Resume {
                dir: options.out.clone(),
                reason: format!("no {OPTIMIZER_FILE}: {e}"),
            })?;
        optim = optim
            .from_bytes(Bytes::from_bytes_vec(bytes))
            .map_err(|e| TrainError::Resume {
                dir: options.out.clone(),
                reason: format!("optimizer state: {e}"),
            })?;
        (ck.net.train(), ck.stats, state.step, state.elapsed_s)
    } else if let Some(dir) = &options.init {
        let bad = |reason: String| TrainError::Init {
            dir: dir.clone(),
            reason,
        };
        let mut ck = checkpoint::load(dir, &ad).map_err(|e| bad(e.to_string()))?;
        ck.check_compatible(dir, config.modality, net_config.residual_dim, &template)
            .map_err(|e| bad(e.to_string()))?;
        // A Gauss-Newton network may be fine-tuned for the chord direction (or back): the
        // weights do not depend on it, and its first direction is the one the input statistics
        // were measured on.
        let mut theirs = ck.meta.network.clone();
        if theirs.direction.is_gauss_newton() && net_config.direction.is_gauss_newton() {
            theirs.direction = net_config.direction;
            theirs.chord_factorisations = net_config.chord_factorisations;
        }
        if theirs != net_config {
            return Err(bad(
                "its network differs from the config's (\"network\" must be the checkpoint's config.json network; a Gauss-Newton network may change to the chord direction)".into(),
            ));
        }
        ck.net.config = net_config.clone();
        (ck.net.train(), ck.stats, 0, 0.0)
    } else {
        let stats_frames = synth_frames_with(
            &template,
            &sensor,
            &base,
            config.stats_frames,
            seeds::stats(config.seed),
            config.noise,
            &motions,
        )?;
        let stats_frames = augment_frames(config, &base, stats_frames, seeds::stats(config.seed))?;
        let stats = measure_stats_with(&stats_frames, &net_config)?;
        (
            NeuralNet::new(&net_config, config.seed, &ad)?,
            stats,
            0,
            0.0,
        )
    };

    let csv_path = options.out.join(METRICS_CSV);
    let mut csv_rows: Vec<String> = if options.resume {
        std::fs::read_to_string(&csv_path)
            .unwrap_or_default()
            .lines()
            .skip(1)
            .filter(|l| {
                l.split(',')
                    .next()
                    .and_then(|s| s.parse::<usize>().ok())
                    .is_some_and(|s| s <= start_step)
            })
            .map(String::from)
            .collect()
    } else {
        Vec::new()
    };
    let n_iter = net_config.iterations;
    let csv_header = {
        let mut h = String::from("step,kind,loss,lr,elapsed_s");
        for k in 0..=n_iter {
            h.push_str(&format!(",v2v_mm_{k}"));
        }
        for k in 0..=n_iter {
            h.push_str(&format!(",mpjpe_mm_{k}"));
        }
        h
    };

    let first_validation = validate(&net.valid(), &stats, &val, false, device)?;
    report(Event::Validation {
        step: start_step,
        validation: first_validation.clone(),
    });
    let mut last_validation = first_validation.clone();
    let started = Instant::now();
    let mut last_good = start_step;

    let save = |net: &NeuralNet,
                optim: &ModuleOptimizer,
                step: usize,
                elapsed: f64,
                validation: &Validation,
                rows: &[String]|
     -> Result<()> {
        let card = json!({
            "command": options.command,
            "seed": config.seed,
            "steps": step,
            "batch": config.batch,
            "time_s": elapsed,
            "device": options.device_name,
            "samples_per_s": if elapsed > 0.0 { (step * config.batch) as f64 / elapsed } else { 0.0 },
            "build": if cfg!(debug_assertions) { "debug" } else { "release" },
            "parameters": net.parameters(),
            "validation": {"frames": config.val_frames, "seed": seeds::validation(config.seed), "start": "phi",
                            "iteration": (0..=n_iter).collect::<Vec<_>>(), "v2v_mm": validation.v2v_mm, "mpjpe_mm": validation.mpjpe_mm},
            "train_config": config,
        });
        let mut files: Vec<(&str, Vec<u8>)> = checkpoint_files(
            &net.valid(),
            &stats,
            &template,
            config.energy.as_ref(),
            &card,
        )?
        .into_iter()
        .collect();
        let opt = optim.into_bytes().map_err(|e| TrainError::Setting {
            name: "optimizer",
            value: String::new(),
            reason: format!("cannot serialise the optimizer state: {e}"),
        })?;
        files.push((OPTIMIZER_FILE, opt.to_vec()));
        let state = TrainState {
            step,
            elapsed_s: elapsed,
            config: config.clone(),
        };
        files.push((
            STATE_FILE,
            serde_json::to_vec_pretty(&state).unwrap_or_default(),
        ));
        let mut csv = csv_header.clone();
        csv.push('\n');
        for r in rows {
            csv.push_str(r);
            csv.push('\n');
        }
        files.push((METRICS_CSV, csv.into_bytes()));
        write_dir(&options.out, &files)?;
        Ok(())
    };

    for step in start_step..config.steps {
        let previous = config
            .starts
            .as_ref()
            .map_or(0, |m| m.previous_count(config.batch));
        let frames = synth_frames_with(
            &template,
            &sensor,
            &base,
            config.batch - previous,
            seeds::batch(config.seed, step),
            config.noise,
            &motions,
        )?;
        let frames = augment_frames(config, &base, frames, seeds::batch(config.seed, step))?;
        let mut rng = ChaCha8Rng::seed_from_u64(seeds::batch(config.seed, step) ^ 0x5EED);
        let mut starts: Vec<Option<Vec<f64>>> = frames
            .dataset
            .start_poses
            .iter()
            .zip(&frames.dataset.gt_poses)
            .map(|(s, gt)| match &config.starts {
                Some(mix) => {
                    let kind = mix.draw(&mut rng);
                    starts::start_of(kind, &template, s, gt, &mut rng)
                }
                None => match net_config.start {
                    StartMode::Phi => None,
                    StartMode::Given => Some(s.clone()),
                    StartMode::Mixed => rng.random_bool(0.5).then(|| s.clone()),
                },
            })
            .collect();
        let mut energies: Vec<&Energy> = frames.energies.iter().collect();
        let mut gt = frames.dataset.gt_poses.clone();
        // The previous-frame share: the network's own results fed forward (inference, detached).
        let chained = match &config.starts {
            Some(mix) if previous > 0 => starts::previous_frames(
                &net.valid(),
                &stats,
                &template,
                &sensor,
                &base,
                previous,
                mix.chain,
                seeds::batch(config.seed, step) ^ 0xC4A1_0000_0000_0000,
                config.noise,
                (mix.anchor_deg, &mix.fps),
                &motions,
                &|f, s| augment_frames(config, &base, f, s),
                device,
                &mut rng,
            )?,
            _ => (Vec::new(), Vec::new(), Vec::new()),
        };
        energies.extend(chained.0.iter());
        gt.extend(chained.1.iter().cloned());
        starts.extend(chained.2.iter().cloned());
        let rows = BatchRows {
            energies: &energies,
            starts: &starts,
            gt: &gt,
        };
        let (value, grads) = if config.shards <= 1 {
            let total = rows_loss(
                &net,
                &stats,
                &loss,
                &template,
                rows,
                &mut Dropout {
                    p: net_config.dropout,
                    rng: Some(&mut rng),
                },
                &ad,
            )?;
            let value = scalar_of(&total)?;
            (value, StepGrads::Whole(total))
        } else {
            sharded_step(
                &net,
                &stats,
                &loss,
                &template,
                rows,
                config.shards,
                net_config.dropout,
                &mut rng,
                &ad,
            )?
        };
        let elapsed = elapsed0 + started.elapsed().as_secs_f64();
        if !value.is_finite() {
            return Err(TrainError::NotFinite {
                value,
                step,
                last_good,
                dir: options.out.clone(),
            });
        }
        let grads = grads.into_params(&net);
        net = optim.step(config.lr_at(step), net, grads);
        csv_rows.push(format!(
            "{},train,{value},{},{elapsed:.3}",
            step + 1,
            config.lr_at(step)
        ));
        report(Event::Step {
            step: step + 1,
            steps: config.steps,
            loss: value,
        });

        let done = step + 1;
        if done % config.val_every == 0 || done == config.steps {
            last_validation = validate(&net.valid(), &stats, &val, false, device)?;
            let mut row = format!("{done},validation,,,{elapsed:.3}");
            for v in last_validation
                .v2v_mm
                .iter()
                .chain(&last_validation.mpjpe_mm)
            {
                row.push_str(&format!(",{v:.3}"));
            }
            csv_rows.push(row);
            report(Event::Validation {
                step: done,
                validation: last_validation.clone(),
            });
        }
        if done % config.checkpoint_every == 0 || done == config.steps {
            save(
                &net,
                &optim,
                done,
                elapsed0 + started.elapsed().as_secs_f64(),
                &last_validation,
                &csv_rows,
            )?;
            last_good = done;
            report(Event::Checkpoint { step: done });
        }
    }
    let time_s = started.elapsed().as_secs_f64();
    let steps_run = config.steps - start_step;
    Ok(Summary {
        steps: config.steps,
        time_s,
        samples_per_s: if time_s > 0.0 {
            (steps_run * config.batch) as f64 / time_s
        } else {
            0.0
        },
        first_validation,
        final_validation: last_validation,
        parameters: net.parameters(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `"library_motions"` reaches the synthesised frames: only the named kinds, the papers'
    /// nine without it.
    #[test]
    fn library_motions_pick_the_kinds_of_the_synthesised_frames() {
        let template = Arc::new(lfit_model::default_template());
        let sensor = Sensor::default_for(Modality::Markers, &template);
        let base = base_energy(&template, &sensor).expect("energy");
        let config = TrainConfig {
            library_motions: Some(vec![MotionKind::Sit, MotionKind::Kneel]),
            ..TrainConfig::default()
        };
        let motions = Motions::load(&config, &template).expect("motions");
        let frames =
            synth_frames_with(&template, &sensor, &base, 24, 3, 0.0, &motions).expect("frames");
        let names = &frames.dataset.meta.frame_motions;
        assert!(
            names.iter().all(|n| n == "sit" || n == "kneel"),
            "{names:?}"
        );
        assert!(names.iter().any(|n| n == "sit") && names.iter().any(|n| n == "kneel"));
        let plain = synth_frames_with(&template, &sensor, &base, 24, 3, 0.0, &Motions::default())
            .expect("frames");
        assert!(
            plain
                .dataset
                .meta
                .frame_motions
                .iter()
                .all(|n| MotionKind::CLASSIC.iter().any(|k| k.name() == n))
        );
    }

    /// `"marker_slip_mm"` reaches every synthesised set, single frames and sequence windows: the
    /// same targets, the markers observed off the model's vertices; bad values and other
    /// modalities are refused.
    #[test]
    fn marker_slip_reaches_every_synthesised_set() {
        let template = Arc::new(lfit_model::default_template());
        let sensor = Sensor::default_for(Modality::Markers, &template);
        let base = base_energy(&template, &sensor).expect("energy");
        let config = TrainConfig {
            marker_slip_mm: 20.0,
            ..TrainConfig::default()
        };
        config.validate().expect("a markers config with a slip");
        let motions = Motions::load(&config, &template).expect("motions");
        let slipped =
            synth_frames_with(&template, &sensor, &base, 20, 5, 0.0, &motions).expect("frames");
        let plain = synth_frames_with(&template, &sensor, &base, 20, 5, 0.0, &Motions::default())
            .expect("frames");
        assert_eq!(slipped.dataset.gt_poses, plain.dataset.gt_poses);
        let (Observations::Sparse { values: a, .. }, Observations::Sparse { values: b, .. }) =
            (&slipped.dataset.observations, &plain.dataset.observations)
        else {
            panic!("sparse")
        };
        let moved = a
            .iter()
            .zip(b)
            .flat_map(|(x, y)| x.iter().zip(y).map(|(p, q)| (p - q).abs()))
            .fold(0.0f64, f64::max);
        assert!(moved > 0.005, "markers moved by at most {moved} m");
        assert_eq!(slipped.dataset.meta.config.marker_slip, 0.02);
        let mut sequence = SynthConfig::new(Modality::Markers, Scenario::Sequence, 4, 1);
        motions.apply_to(&mut sequence);
        assert_eq!(sequence.marker_slip, 0.02);
        for bad in [-1.0, 150.0, f64::NAN] {
            let e = TrainConfig {
                marker_slip_mm: bad,
                ..TrainConfig::default()
            }
            .validate()
            .unwrap_err()
            .to_string();
            assert!(e.contains("marker_slip_mm"), "{e}");
        }
        let e = TrainConfig {
            modality: Modality::Hmd,
            marker_slip_mm: 10.0,
            ..TrainConfig::default()
        }
        .validate()
        .unwrap_err()
        .to_string();
        assert!(e.contains("marker_slip_mm") && e.contains("hmd"), "{e}");
    }

    /// `"height_prior"` gives about its share of the frames the height row, each σ in its
    /// range and each height off the subject's true rest height by σ times a standard normal
    /// draw (the standardised errors' mean near 0 and spread near 1); the same seed the same
    /// priors; rate 0 none, 1 all; bad settings refused by name.
    #[test]
    fn a_height_prior_reaches_its_share_of_the_frames() {
        let (t, _) = lfit_model::body::morphable_default_template().expect("template");
        let template = Arc::new(t);
        let sensor = Sensor::default_for(Modality::Markers, &template);
        let base = base_energy(&template, &sensor).expect("energy");
        let with = |rate: f64| TrainConfig {
            height_prior: Some(HeightPriorTraining {
                rate,
                std_m: [0.01, 0.04],
            }),
            ..TrainConfig::default()
        };
        with(0.5).validate().expect("a height prior");
        let frames = |config: &TrainConfig| {
            let f = synth_frames_with(&template, &sensor, &base, 200, 5, 0.0, &Motions::default())
                .expect("frames");
            augment_frames(config, &base, f, 5).expect("augmented")
        };
        let shape = template.layout().range(Block::Shape);
        let half = frames(&with(0.5));
        let mut z = Vec::new();
        for (e, gt) in half.energies.iter().zip(&half.dataset.gt_poses) {
            let Some(p) = e.height_prior() else { continue };
            assert!((0.01..=0.04).contains(&p.std_m()), "{}", p.std_m());
            let truth = lfit_model::stature::rest_height(&template, &gt[shape.clone()]).0;
            z.push((p.height_m() - truth) / p.std_m());
        }
        assert!((70..=130).contains(&z.len()), "{} of 200 frames", z.len());
        let mean = z.iter().sum::<f64>() / z.len() as f64;
        let sd = (z.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / z.len() as f64).sqrt();
        assert!(
            mean.abs() < 0.3 && (0.7..1.3).contains(&sd),
            "mean {mean}, sd {sd}"
        );
        let again = frames(&with(0.5));
        let heights = |f: &Frames| -> Vec<Option<(f64, f64)>> {
            f.energies
                .iter()
                .map(|e| e.height_prior().map(|p| (p.height_m(), p.std_m())))
                .collect()
        };
        assert_eq!(heights(&half), heights(&again));
        assert!(
            frames(&with(0.0))
                .energies
                .iter()
                .all(|e| e.height_prior().is_none())
        );
        assert!(
            frames(&with(1.0))
                .energies
                .iter()
                .all(|e| e.height_prior().is_some())
        );
        for (rate, std_m) in [(1.5, [0.01, 0.04]), (0.5, [0.05, 0.01]), (0.5, [0.0, 0.01])] {
            let e = TrainConfig {
                height_prior: Some(HeightPriorTraining { rate, std_m }),
                ..TrainConfig::default()
            }
            .validate()
            .unwrap_err()
            .to_string();
            assert!(e.contains("height_prior"), "{e}");
        }
    }

    /// Every training config the repository carries (`configs/*.json` with a `"network"`, and
    /// each shipped checkpoint's `train.json`) loads: parsed with unknown fields refused and
    /// validated, so a recipe the docs point to runs as written.
    #[test]
    fn every_committed_training_config_loads() {
        let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
        let mut paths: Vec<PathBuf> = std::fs::read_dir(root.join("configs"))
            .expect("configs/")
            .map(|e| e.expect("entry").path())
            .filter(|p| p.extension().is_some_and(|x| x == "json"))
            .collect();
        for entry in std::fs::read_dir(root.join("checkpoints")).expect("checkpoints/") {
            let train = entry.expect("entry").path().join("train.json");
            if train.is_file() {
                paths.push(train);
            }
        }
        let mut loaded = 0;
        for path in &paths {
            let text = std::fs::read_to_string(path).expect("readable");
            let value: serde_json::Value = serde_json::from_str(&text).expect("JSON");
            if value.get("network").is_none() {
                continue; // an energy, a rig or a pose prior
            }
            TrainConfig::load(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
            loaded += 1;
        }
        assert!(loaded >= 30, "{loaded} training configs");
    }

    /// `"floor"` gives about its share of the frames a `contact` floor, each σ in its range and
    /// its height the frame's true lowest sole (measured again here on the posed mesh) off by σ'
    /// times a standard normal draw; the same seed the same floors; offset 0 puts the floor at the
    /// lowest sole itself (the frame's row zero at the truth); rate 0 none, 1 all; bad settings
    /// refused by name.
    #[test]
    fn a_floor_reaches_its_share_of_the_frames() {
        let (t, _) = lfit_model::body::morphable_default_template().expect("template");
        let template = Arc::new(t);
        let sensor = Sensor::default_for(Modality::Markers, &template);
        let base = base_energy(&template, &sensor).expect("energy");
        let with = |rate: f64, offset_m: f64| TrainConfig {
            floor: Some(FloorTraining {
                rate,
                std_m: [0.01, 0.04],
                offset_m,
            }),
            ..TrainConfig::default()
        };
        with(0.5, 0.02).validate().expect("a floor");
        let frames = |config: &TrainConfig| {
            let f = synth_frames_with(&template, &sensor, &base, 200, 5, 0.0, &Motions::default())
                .expect("frames");
            augment_frames(config, &base, f, 5).expect("augmented")
        };
        // The lowest posed sole candidate, from the skinned mesh itself.
        let lowest = |floor: &FloorPrior, gt: &[f64]| {
            let mesh = lfit_model::skinning::pose_vertices(
                &template,
                gt,
                lfit_model::skinning::SkinningMethod::Linear,
            );
            floor
                .vertices()
                .iter()
                .map(|&v| f64::from(mesh[v].y))
                .fold(f64::INFINITY, f64::min)
        };
        let half = frames(&with(0.5, 0.02));
        let mut z = Vec::new();
        for (e, gt) in half.energies.iter().zip(&half.dataset.gt_poses) {
            let Some(f) = e.floor() else { continue };
            assert_eq!(f.form(), FloorForm::Contact);
            assert!((0.01..=0.04).contains(&f.std_m()), "{}", f.std_m());
            z.push((f.height_m() - lowest(f, gt)) / 0.02);
        }
        assert!((70..=130).contains(&z.len()), "{} of 200 frames", z.len());
        let mean = z.iter().sum::<f64>() / z.len() as f64;
        let sd = (z.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / z.len() as f64).sqrt();
        assert!(
            mean.abs() < 0.3 && (0.7..1.3).contains(&sd),
            "mean {mean}, sd {sd}"
        );
        let floors = |f: &Frames| -> Vec<Option<(f64, f64)>> {
            f.energies
                .iter()
                .map(|e| e.floor().map(|p| (p.height_m(), p.std_m())))
                .collect()
        };
        assert_eq!(floors(&half), floors(&frames(&with(0.5, 0.02))));
        let exact = frames(&with(1.0, 0.0));
        for (e, gt) in exact.energies.iter().zip(&exact.dataset.gt_poses) {
            let f = e.floor().expect("every frame a floor");
            assert!((f.height_m() - lowest(f, gt)).abs() < 1e-5);
        }
        assert!(
            frames(&with(0.0, 0.02))
                .energies
                .iter()
                .all(|e| e.floor().is_none())
        );
        for (rate, std_m, offset_m, field) in [
            (1.5, [0.01, 0.04], 0.02, "floor.rate"),
            (0.5, [0.05, 0.01], 0.02, "floor.std_m"),
            (0.5, [0.0, 0.01], 0.02, "floor.std_m"),
            (0.5, [0.01, 0.04], -0.01, "floor.offset_m"),
            (0.5, [0.01, 0.04], f64::NAN, "floor.offset_m"),
        ] {
            let e = TrainConfig {
                floor: Some(FloorTraining {
                    rate,
                    std_m,
                    offset_m,
                }),
                ..TrainConfig::default()
            }
            .validate()
            .unwrap_err()
            .to_string();
            assert!(e.contains(field), "{e}");
        }
    }

    /// `"uniform_poses"` reaches the single frames (about that share named `uniform`, their
    /// targets inside the model's bounds) but not the sequence windows; 0 leaves every frame as
    /// it was; a share outside [0, 1] or with the face source is refused.
    #[test]
    fn uniform_poses_mix_into_single_frames_only() {
        let template = Arc::new(lfit_model::default_template());
        let sensor = Sensor::default_for(Modality::Markers, &template);
        let base = base_energy(&template, &sensor).expect("energy");
        let with = |share: f64| TrainConfig {
            uniform_poses: share,
            ..TrainConfig::default()
        };
        let motions = Motions::load(&with(0.5), &template).expect("motions");
        let frames =
            synth_frames_with(&template, &sensor, &base, 200, 5, 0.0, &motions).expect("frames");
        let names = &frames.dataset.meta.frame_motions;
        let uniform = names.iter().filter(|n| *n == "uniform").count();
        assert!((70..=130).contains(&uniform), "{uniform} of 200 uniform");
        let bounds = Bounds::global_for(&template);
        let pd = template.layout().pose_dim();
        for (name, target) in names.iter().zip(&frames.dataset.gt_poses) {
            if name == "uniform" {
                assert!(
                    (0..pd).all(|k| target[k] >= bounds.lower[k] && target[k] <= bounds.upper[k])
                );
            }
        }
        // The other frames are the library frames a config without the share makes.
        let plain = synth_frames_with(&template, &sensor, &base, 200, 5, 0.0, &Motions::default())
            .expect("frames");
        for (i, name) in names.iter().enumerate() {
            if name != "uniform" {
                assert_eq!(
                    frames.dataset.gt_poses[i], plain.dataset.gt_poses[i],
                    "frame {i}"
                );
            }
        }
        let mut sequence = SynthConfig::new(Modality::Markers, Scenario::Sequence, 4, 1);
        motions.apply_to(&mut sequence);
        assert_eq!(sequence.uniform_share, 0.0);
        for (bad, source) in [
            (1.5, PoseSource::Motion),
            (-0.1, PoseSource::Motion),
            (f64::NAN, PoseSource::Motion),
            (0.2, PoseSource::Face),
        ] {
            let config = TrainConfig {
                source,
                ..with(bad)
            };
            let err = config.validate().expect_err("refused").to_string();
            assert!(err.contains("uniform_poses"), "{err}");
        }
    }

    /// A known-shape network starts and stays on the true β (θ0 = Φ(D) or the start pose,
    /// clamped); the same network without the flag does not.
    #[test]
    fn a_known_shape_network_is_held_on_the_true_shape() {
        let (template, _) = lfit_model::body::morphable_default_template().expect("template");
        let template = Arc::new(template);
        let sensor = Sensor::default_for(Modality::Hmd, &template);
        let base = base_energy(&template, &sensor).expect("energy");
        let frames = synth_frames(&template, &sensor, &base, 4, 9, 1.0).expect("frames");
        let device = lfit_nn::tensor::device_from_name("ndarray").expect("device");
        let shape = template.layout().range(Block::Shape);
        let stats = measure_stats(&frames);
        let refs: Vec<&Energy> = frames.energies.iter().collect();
        for known in [true, false] {
            let config = NetConfig {
                modality: Modality::Hmd,
                residual_dim: sensor.residual_dim(&template),
                param_dim: template.param_dim(),
                hidden: 8,
                init_width: 8,
                layers: 1,
                iterations: 2,
                known_shape: known,
                ..NetConfig::default()
            };
            let net = NeuralNet::new(&config, 1, &device).expect("net").valid();
            let constraints = training_constraints(&net, &frames);
            assert_eq!(constraints.is_some(), known);
            for given in [false, true] {
                let starts: Vec<Option<Vec<f64>>> = frames
                    .dataset
                    .start_poses
                    .iter()
                    .map(|s| given.then(|| s.clone()))
                    .collect();
                let out = unroll(
                    &net,
                    &stats,
                    &refs,
                    &starts,
                    constraints.as_ref(),
                    &device,
                    &mut Dropout::off(),
                )
                .expect("unroll");
                let worst = out
                    .host
                    .iter()
                    .flat_map(|poses| poses.iter().zip(&frames.dataset.gt_poses))
                    .flat_map(|(p, g)| shape.clone().map(move |i| (p[i] - g[i]).abs()))
                    .fold(0.0, f64::max);
                if known {
                    // f32 in the loop: within its rounding of β.
                    assert!(worst < 1e-6, "given {given}: β off by {worst}");
                } else {
                    assert!(worst > 1e-3, "given {given}: β should move freely");
                }
            }
        }
    }
}
