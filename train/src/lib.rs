//! Training of the neural fitter (SPEC §7, papers/002 supp. §6): batches synthesised on the fly
//! from the motion library, N unrolled iterations through the energy's residuals and gradients,
//! the per-step loss of supp. eq. (13)–(18), Adam with gradient clipping and a step decay of the
//! learning rate, validation on a fixed set (V2V and MPJPE per iteration), atomic checkpoints
//! with `--resume`, a NaN/Inf stop that keeps the last good checkpoint, and a metrics CSV.

pub mod loss;

use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Instant;

use burn::module::Module;
use burn::optim::grad_clipping::GradientClippingConfig;
use burn::optim::{AdamConfig, GradientsParams, ModuleOptimizer};
use burn::tensor::{Bytes, Device};
use lfit_model::energy::{Energy, EnergyConfig, Target};
use lfit_model::metrics::{mpjpe_mm, v2v_mm};
use lfit_model::observe::{Modality, Sensor};
use lfit_model::{Block, Bounds, Template};
use lfit_nn::checkpoint::{self, checkpoint_files, write_dir};
use lfit_nn::tensor::poses_to_tensor;
use lfit_nn::{
    Constraints, Dropout, FeatureStats, NetConfig, NeuralNet, StartMode, observation_features,
    unroll,
};
use lfit_synth::{
    Dataset, MotionFile, NoiseConfig, Observations, PoseSource, Scenario, SynthConfig, synthesize,
};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use serde_json::json;

pub use loss::{Loss, LossWeights};

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
    /// Imported motion files (`lfit motion import`, paths relative to the working directory)
    /// that every synthesised set (training batches, validation, statistics) draws its target
    /// poses from instead of the procedural library, as `lfit synth --motions` does.
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub motions: Vec<PathBuf>,
    /// With `motions`: each frame from the library or the files by a fair coin
    /// (`lfit synth --with-library`).
    #[serde(skip_serializing_if = "std::ops::Not::not")]
    pub with_library: bool,
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
            motions: Vec::new(),
            with_library: false,
            source: PoseSource::Motion,
            energy: None,
        }
    }
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
        if self.with_library && self.motions.is_empty() {
            return bad(
                "with_library",
                "true".into(),
                "mixes the library with motion files: list them in \"motions\"",
            );
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
    /// `face`: papers/002's face protocol in the global scenario instead.
    pub source: PoseSource,
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
            source: config.source,
        })
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
    config.motion_files = motions.files.clone();
    config.with_library = motions.with_library;
    config.source = motions.source;
    config.noise = if noise == 0.0 {
        NoiseConfig::none()
    } else {
        NoiseConfig::scaled(noise)?
    };
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

/// Feature statistics from `frames`: observations, and residuals/gradients/poses at the poses
/// the fitter visits early (the scenario's start poses, the rest pose at the origin where Φ
/// starts, and halfway to the target).
pub fn measure_stats(frames: &Frames) -> FeatureStats {
    let d = &frames.dataset;
    let rows: Vec<(Vec<f64>, Vec<Vec<f64>>, Vec<Vec<f64>>, Vec<Vec<f64>>)> = frames
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
                g.push(e.evaluate_with_gradient(&pose).1.to_vec());
                p.push(pose.to_vec());
            }
            (observation_features(e), r, g, p)
        })
        .collect();
    let mut obs = Vec::new();
    let (mut res, mut grad, mut pose) = (Vec::new(), Vec::new(), Vec::new());
    for (o, r, g, p) in rows {
        obs.push(o);
        res.extend(r);
        grad.extend(g);
        pose.extend(p);
    }
    FeatureStats::measure(&obs, &res, &grad, &pose)
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
    net_config.residual_dim = sensor.residual_dim(&template);
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
        let stats = measure_stats(&stats_frames);
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
        let frames = synth_frames_with(
            &template,
            &sensor,
            &base,
            config.batch,
            seeds::batch(config.seed, step),
            config.noise,
            &motions,
        )?;
        let mut rng = ChaCha8Rng::seed_from_u64(seeds::batch(config.seed, step) ^ 0x5EED);
        let starts: Vec<Option<Vec<f64>>> = frames
            .dataset
            .start_poses
            .iter()
            .map(|s| match net_config.start {
                StartMode::Phi => None,
                StartMode::Given => Some(s.clone()),
                StartMode::Mixed => rng.random_bool(0.5).then(|| s.clone()),
            })
            .collect();
        let refs: Vec<&Energy> = frames.energies.iter().collect();
        let truth = loss.truth(poses_to_tensor(&frames.dataset.gt_poses, &ad));
        let constraints = training_constraints(&net, &frames);
        let out = unroll(
            &net,
            &stats,
            &refs,
            &starts,
            constraints.as_ref(),
            &ad,
            &mut Dropout {
                p: net_config.dropout,
                rng: Some(&mut rng),
            },
        )?;
        let total = loss.total(&out.poses, &truth);
        let value = f64::from(
            total
                .clone()
                .detach()
                .try_into_scalar::<f32>()
                .map_err(|e| {
                    lfit_model::ModelError::Backend(format!("cannot read the loss: {e}"))
                })?,
        );
        let elapsed = elapsed0 + started.elapsed().as_secs_f64();
        if !value.is_finite() {
            return Err(TrainError::NotFinite {
                value,
                step,
                last_good,
                dir: options.out.clone(),
            });
        }
        let grads = GradientsParams::from_grads(total.backward(), &net);
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
