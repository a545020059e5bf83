//! Inference with a trained neural fitter (SPEC §7): [`NeuralFitter`] loads a checkpoint onto a
//! backend (`ndarray`, `flex`, `wgpu`) and fits frames through the same [`Fitter`] abstraction
//! as the classical methods — per frame, as one batch of frames, or along a sequence (each frame
//! starting from the previous result).

use std::path::{Path, PathBuf};
use std::time::Instant;

use burn::tensor::Device;
use lfit_fitters::{FitError, FitRequest, FitResult, Fitter};
use lfit_model::network::checkpoint::{self, Checkpoint};
use lfit_model::network::{Constraints, Dropout, unroll};
use lfit_model::pose::{Bounds, POSE_DIM, Pose};
use lfit_model::{Energy, ModelError};

/// Where θ0 comes from at inference.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Start {
    /// θ0 = Φ(D), the network's own initializer (papers/002 Alg. 1).
    Phi,
    /// θ0 = the request's start pose (the scenario's start, or the previous frame's result).
    Given,
}

impl std::str::FromStr for Start {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "phi" => Ok(Start::Phi),
            "given" | "start" => Ok(Start::Given),
            _ => Err(format!("unknown neural start '{s}' (expected phi or given)")),
        }
    }
}

/// A trained fitter on a device.
#[derive(Debug)]
pub struct NeuralFitter {
    pub checkpoint: Checkpoint,
    pub dir: PathBuf,
    pub device: Device,
    pub start: Start,
}

fn neural(e: impl std::fmt::Display) -> FitError {
    FitError::Neural(e.to_string())
}

impl NeuralFitter {
    /// Loads the checkpoint in `dir` onto `device`.
    pub fn load(dir: &Path, device: &Device, start: Start) -> Result<Self, ModelError> {
        let checkpoint = checkpoint::load(dir, device)?;
        Ok(Self { checkpoint, dir: dir.to_path_buf(), device: device.clone(), start })
    }

    /// Iterations N of one fit.
    pub fn iterations(&self) -> usize {
        self.checkpoint.meta.network.iterations
    }

    /// Checks that the checkpoint fits an energy (modality, residual size, template).
    pub fn check(&self, energy: &Energy) -> Result<(), ModelError> {
        let template = energy.template();
        self.checkpoint.check_compatible(&self.dir, energy.modality(), energy.sensor().residual_dim(template), template)
    }

    /// Fits a batch of frames in one pass of the network; every result carries the batch's wall
    /// time divided by its size. The budget of each request must allow the fitter's
    /// evaluations (2 per iteration: one gradient evaluation, one residual at θ + Δθ).
    pub fn fit_batch(&self, requests: &[FitRequest<'_>]) -> Result<Vec<FitResult>, FitError> {
        if requests.is_empty() {
            return Ok(Vec::new());
        }
        let net = &self.checkpoint.net;
        let n = net.config.iterations;
        let per_iteration = net.config.evaluations_per_iteration();
        for r in requests {
            self.check(r.energy).map_err(neural)?;
            if r.budget == 0 {
                return Err(FitError::Budget(0));
            }
            if r.budget < per_iteration * n {
                return Err(FitError::Neural(format!("budget {} is below the {} evaluations of {n} iterations", r.budget, per_iteration * n)));
            }
            if r.bounds.lower.len() != POSE_DIM || r.bounds.upper.len() != POSE_DIM {
                return Err(FitError::Bounds(format!("need {POSE_DIM} lower and upper values")));
            }
            if r.start.iter().any(|v| !v.is_finite()) {
                return Err(FitError::Start("not finite".into()));
            }
        }
        let timer = Instant::now();
        let e0: Vec<(u64, u64)> = requests.iter().map(|r| (r.energy.evaluations(), r.energy.gradient_evaluations())).collect();
        let energies: Vec<&Energy> = requests.iter().map(|r| r.energy).collect();
        let starts: Vec<Option<Pose>> = requests
            .iter()
            .map(|r| {
                let mut s = r.start;
                r.bounds.clamp(&mut s);
                (self.start == Start::Given).then_some(s)
            })
            .collect();
        let constraints = Constraints {
            free: requests
                .iter()
                .map(|r| {
                    let mut f = [false; POSE_DIM];
                    for &i in &r.mask.free {
                        if i < POSE_DIM {
                            f[i] = true;
                        }
                    }
                    f
                })
                .collect(),
            bounds: requests.iter().map(|r| r.bounds.clone()).collect::<Vec<Bounds>>(),
        };
        let out = unroll(net, &self.checkpoint.stats, &energies, &starts, Some(&constraints), &self.device, &mut Dropout::off()).map_err(neural)?;
        let time_s = timer.elapsed().as_secs_f64() / requests.len() as f64;
        let name = self.name();
        Ok(requests
            .iter()
            .enumerate()
            .map(|(i, r)| {
                let pose = out.host[n][i];
                let report = r.energy.inspect(&pose);
                let evaluations = r.energy.evaluations() - e0[i].0 + out.residual_evaluations - n as u64;
                // Energy of every iterate (reporting only: `inspect` is not counted); the x axis
                // is the evaluations used to reach it.
                let trace = (0..=n).map(|k| ((per_iteration * k) as u64, r.energy.inspect(&out.host[k][i]).total)).collect();
                FitResult {
                    method: name.clone(),
                    pose: pose.to_vec(),
                    energy: report.total,
                    terms: report.terms,
                    evaluations,
                    gradient_evaluations: r.energy.gradient_evaluations() - e0[i].1,
                    iterations: n as u64,
                    time_s,
                    trace,
                    iterates: out.host.iter().map(|h| h[i].to_vec()).collect(),
                }
            })
            .collect())
    }
}

impl Fitter for NeuralFitter {
    fn name(&self) -> String {
        match self.start {
            Start::Phi => "neural".into(),
            Start::Given => "neural-given".into(),
        }
    }

    fn fit(&self, request: &FitRequest<'_>) -> Result<FitResult, FitError> {
        self.fit_batch(std::slice::from_ref(request))?.pop().ok_or_else(|| FitError::Neural("no result".into()))
    }
}
