//! A sensor lfit does not know, added from outside: a body-worn IMU suit (papers/002 §2 cites
//! sparse-IMU pose estimation) with six units, as DIP-IMU places them (pelvis, head, forearms,
//! lower legs). Each unit reports its world orientation; the pelvis unit also reports its
//! position (a tracked belt), without which translation would be unobservable.
//!
//! One `ObservationModel` implementation is all it takes: synthesis, the energy, its gradient,
//! Levenberg–Marquardt and neural training then work on it unchanged.
//!
//! `cargo run --release --example imu_sensor` (about a minute on one core).

use std::sync::Arc;

use anyhow::{Context, Result, bail};
use glam::DMat3;
use lfit::cli::fit::{scenario_bounds, scenario_mask};
use lfit::fitters::least_squares::{LeastSquaresFitter, LeastSquaresMethod};
use lfit::fitters::{FitRequest, Fitter, Strategy};
use lfit::model::metrics::v2v_mm;
use lfit::model::noise::{NoiseConfig, add_gaussian, perturb_rotation};
use lfit::model::observe::{
    Modality, ObservationModel, PoseJacobian, PosedView, ResidualGroup, Scales, Sensor,
};
use lfit::model::skeleton::{HEAD, L_ELBOW, L_KNEE, R_ELBOW, R_KNEE, ROOT};
use lfit::model::{Energy, EnergyConfig, Target, Template};
use lfit::synth::{Observations, Scenario, SynthConfig, synthesize};
use lfit::train::{RunOptions, Summary, TrainConfig, train_with_sensor};
use rand::{Rng, RngCore};

/// Six IMUs on joints of the model (through its joint map onto the papers/000 skeleton), each
/// mounted at a fixed rotation to its bone; the first one also gives its position.
#[derive(Debug)]
pub struct ImuSuit {
    joints: Vec<usize>,
    mounts: Vec<DMat3>,
}

impl ImuSuit {
    pub fn new(template: &Template) -> Result<Self> {
        let joints = [ROOT, HEAD, L_ELBOW, R_ELBOW, L_KNEE, R_KNEE]
            .iter()
            .map(|&j| template.info.joint_map.get(j).copied().flatten())
            .collect::<Option<Vec<_>>>()
            .context("the model maps no joint for one of the six IMUs")?;
        // Straps turn a unit about its bone: a different fixed rotation per unit.
        let mounts = (0..6)
            .map(|k| DMat3::from_rotation_y(0.5 * k as f64) * DMat3::from_rotation_x(0.3))
            .collect();
        Ok(Self { joints, mounts })
    }
}

impl ObservationModel for ImuSuit {
    fn name(&self) -> &str {
        "imu-suit"
    }
    fn validate(&self, template: &Template) -> lfit::model::Result<()> {
        match self
            .joints
            .iter()
            .find(|&&j| j >= template.rig.num_joints())
        {
            Some(j) => Err(lfit::model::ModelError::Config(format!("no joint {j}"))),
            None => Ok(()),
        }
    }
    fn dim(&self, _: &Template) -> usize {
        9 * self.joints.len() + 3
    }
    fn groups(&self, t: &Template, scales: &Scales) -> Vec<ResidualGroup> {
        let mut g = lfit::model::observe::uniform_groups(self.joints.len(), 9, scales.rotation);
        g.push(ResidualGroup {
            start: 9 * self.joints.len(),
            len: 3,
            sigma: scales.position,
        });
        debug_assert_eq!(g.iter().map(|g| g.len).sum::<usize>(), self.dim(t));
        g
    }
    fn predict(&self, posed: &PosedView<'_>, values: &mut [f64], visible: &mut [bool]) {
        for (k, (&j, m)) in self.joints.iter().zip(&self.mounts).enumerate() {
            let r = posed.joint_rotation(j) * *m;
            for row in 0..3 {
                values[9 * k + 3 * row..9 * k + 3 * row + 3]
                    .copy_from_slice(&r.row(row).to_array());
            }
        }
        let n = 9 * self.joints.len();
        values[n..n + 3].copy_from_slice(&posed.joint(self.joints[0]).to_array());
        visible.fill(true);
    }
    fn jacobian(&self, posed: &PosedView<'_>, jac: &mut PoseJacobian<'_, '_>, out: &mut [f64]) {
        let d = jac.dim();
        for (k, (&j, m)) in self.joints.iter().zip(&self.mounts).enumerate() {
            let r = posed.joint_rotation(j) * *m;
            jac.carried_rotation(j, r, &mut out[9 * k * d..9 * (k + 1) * d]);
        }
        let n = 9 * self.joints.len();
        jac.joint(self.joints[0], &mut out[n * d..(n + 3) * d]);
    }
    // `backprop` is not written: the trait's default (Jᵀ g through `jacobian`) serves.
    fn corrupt(
        &self,
        values: &mut [f64],
        visible: &mut [bool],
        noise: &NoiseConfig,
        rng: &mut dyn RngCore,
    ) {
        let n = 9 * self.joints.len();
        for k in 0..self.joints.len() {
            perturb_rotation(&mut values[9 * k..9 * k + 9], noise.rotation_sigma_deg, rng);
            // A unit that drops out reports nothing.
            if rng.random::<f64>() < noise.drop_rate {
                values[9 * k..9 * k + 9].fill(0.0);
                visible[9 * k..9 * k + 9].fill(false);
            }
        }
        add_gaussian(&mut values[n..n + 3], noise.position_sigma, rng);
    }
}

/// What the example measures: V2V (mm) at the start poses, after LM, and the neural fitter's
/// validation V2V before and after its short training.
#[derive(Debug)]
pub struct Report {
    pub start_v2v_mm: f64,
    pub lm_v2v_mm: f64,
    pub training: Summary,
}

/// Synthesises `frames` local-scenario frames of the IMU suit, fits each with LM, then trains a
/// small neural fitter for `steps` steps into `out`.
pub fn run(
    template: Arc<Template>,
    frames: usize,
    steps: usize,
    out: &std::path::Path,
) -> Result<Report> {
    let sensor = Sensor::Custom(Arc::new(ImuSuit::new(&template)?));
    // 1. Synthesis: the suit's prediction, corrupted by its own noise model.
    let config = SynthConfig::new(Modality::Custom, Scenario::Local, frames, 7);
    let data = synthesize(&config, &template, &sensor, &|_| {})?;
    let Observations::Sparse { values, visible } = &data.observations else {
        bail!("not a vector sensor")
    };
    // 2. Levenberg–Marquardt on the energy built on the suit.
    let n = sensor.residual_dim(&template);
    let target = Target::Sparse {
        values: vec![0.0; n],
        visible: vec![false; n],
    };
    let base = Energy::new(
        template.clone(),
        sensor.clone(),
        target,
        EnergyConfig::default().for_gradient(),
    )?;
    let lm = LeastSquaresFitter::new(LeastSquaresMethod::Lm, Strategy::Holistic);
    let (mut start_v2v, mut lm_v2v) = (0.0, 0.0);
    for i in 0..frames {
        let energy = base.with_target(values[i].clone(), visible[i].clone())?;
        let start = data.start_poses[i].clone();
        let request = FitRequest {
            energy: &energy,
            mask: scenario_mask(Scenario::Local, &template),
            bounds: scenario_bounds(Scenario::Local, &template, &start),
            start,
            budget: 100,
            seed: i as u64,
            motion: None,
        };
        let fit = lm.fit(&request)?;
        start_v2v += v2v_mm(&template, &data.start_poses[i], &data.gt_poses[i]) / frames as f64;
        lm_v2v += v2v_mm(&template, &fit.pose, &data.gt_poses[i]) / frames as f64;
    }
    // 3. A short neural training on the same sensor.
    let mut train = TrainConfig {
        modality: Modality::Custom,
        steps,
        batch: 16,
        val_frames: 32,
        stats_frames: 64,
        ..TrainConfig::default()
    };
    train.network.hidden = 64;
    train.network.iterations = 3;
    (train.val_every, train.checkpoint_every) = (steps, steps);
    let options = RunOptions {
        out: out.to_path_buf(),
        device_name: "ndarray".into(),
        resume: false,
        init: None,
        command: "imu_sensor example".into(),
    };
    let device = lfit::nn::tensor::ndarray_device();
    let training = train_with_sensor(&train, template, &sensor, &device, &options, &|_| {})?;
    Ok(Report {
        start_v2v_mm: start_v2v,
        lm_v2v_mm: lm_v2v,
        training,
    })
}

#[allow(dead_code)]
fn main() -> Result<()> {
    let out = std::env::temp_dir().join("lfit-imu-sensor-example");
    let r = run(Arc::new(lfit::model::default_template()), 100, 100, &out)?;
    let v = |s: &lfit::train::Validation| s.v2v_mm.last().copied().unwrap_or(f64::NAN);
    println!(
        "IMU suit, 100 local frames: V2V {:.1} mm at the start, {:.1} mm after LM",
        r.start_v2v_mm, r.lm_v2v_mm
    );
    println!(
        "neural fitter, {} steps: validation V2V {:.1} mm -> {:.1} mm (checkpoint in {})",
        r.training.steps,
        v(&r.training.first_validation),
        v(&r.training.final_validation),
        out.display()
    );
    Ok(())
}
