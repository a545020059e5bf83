//! Inference with a trained neural fitter (SPEC §7): [`NeuralFitter`] loads a checkpoint onto a
//! backend (`ndarray`, `flex`, `wgpu`) and fits frames through the same [`Fitter`] abstraction
//! as the classical methods — per frame, as one batch of frames, or along a sequence (each frame
//! starting from the previous result). The same loop runs with the network in ONNX Runtime
//! ([`onnx`], `--runtime ort`) and with lfit's own f32 forward on the host
//! ([`lfit_nn::host`], `--runtime native`).

pub mod onnx;
pub mod refine;

pub use refine::NeuralThenLm;

use std::path::{Path, PathBuf};
use std::sync::Mutex;
use std::time::Instant;

use burn::tensor::Device;
use glam::DVec3;
use lfit_fitters::{FitError, FitRequest, FitResult, Fitter};
use lfit_model::pose::{Bounds, FLOOR_SPREAD, LOCAL_TRANSLATION};
use lfit_model::{Energy, ModelError};
use lfit_nn::checkpoint::{self, Checkpoint, CheckpointMeta};
use lfit_nn::{Constraints, Dropout, FeatureStats, NeuralNet, unroll_for};

/// Where θ0 comes from at inference.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Start {
    /// θ0 = Φ(D), the network's own initializer (papers/002 Alg. 1).
    Phi,
    /// θ0 = the request's start pose (the scenario's start, or the previous frame's result).
    Given,
    /// θ0 = the better by energy of the request's start and Φ(D) (two counted evaluations): a
    /// sequence restarts from Φ(D) where its previous result no longer explains the frame.
    Best,
    /// Two fits, one from the request's start and one from Φ(D), and the result of lower energy
    /// (twice the iterations' evaluations, and the two results' energies): a sequence whose
    /// previous result has drifted where the data do not see it is caught by the fit that does
    /// not depend on it once that fit explains the frame better.
    Both,
}

impl std::str::FromStr for Start {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "phi" => Ok(Start::Phi),
            "given" | "start" => Ok(Start::Given),
            "best" => Ok(Start::Best),
            "both" => Ok(Start::Both),
            _ => Err(format!(
                "unknown neural start '{s}' (expected phi, given, best or both)"
            )),
        }
    }
}

/// Which iterate a neural fit returns.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Pick {
    /// θN, the last iterate (papers/002 Alg. 1).
    #[default]
    Last,
    /// The iterate of lowest energy among θ0 … θN, as a classical optimizer returns the best
    /// point it has seen: the loop has evaluated θ0 … θN−1 already (each iteration's gradient
    /// carries the energy), θN costs one more counted evaluation. A step that made the energy
    /// worse is not returned, so a sequence does not carry it forward.
    Lowest,
}

impl std::str::FromStr for Pick {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "last" => Ok(Pick::Last),
            "lowest" => Ok(Pick::Lowest),
            _ => Err(format!(
                "unknown neural pick '{s}' (expected last or lowest)"
            )),
        }
    }
}

/// What executes the network.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Runtime {
    /// Burn on the fitter's device (ndarray, flex, wgpu).
    Burn,
    /// ONNX Runtime (CPU) on the exported graphs.
    Ort,
    /// lfit's own f32 forward on the host ([`lfit_nn::HostNet`]): no per-operation dispatch,
    /// the fastest at batch 1 on a CPU.
    Native,
}

impl std::str::FromStr for Runtime {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "burn" => Ok(Runtime::Burn),
            "ort" | "onnxruntime" => Ok(Runtime::Ort),
            "native" => Ok(Runtime::Native),
            _ => Err(format!(
                "unknown runtime '{s}' (expected burn, ort or native)"
            )),
        }
    }
}

/// The network of a fitter, in Burn or in ONNX Runtime sessions.
#[derive(Debug)]
pub enum Engine {
    Burn {
        net: Box<NeuralNet>,
        device: Device,
    },
    /// Sessions need exclusive access to run; frames of one batch share one call.
    Ort(Box<Mutex<onnx::runtime::OrtNetwork>>),
    /// The weights copied to the host once ([`lfit_nn::host`]).
    Native(Box<lfit_nn::HostNet>),
}

/// A trained fitter.
#[derive(Debug)]
pub struct NeuralFitter {
    pub meta: CheckpointMeta,
    pub stats: FeatureStats,
    pub engine: Engine,
    pub dir: PathBuf,
    pub start: Start,
    /// Which iterate a fit returns ([`Pick::Last`] unless [`NeuralFitter::with_pick`]).
    pub pick: Pick,
    /// Iterations a fit runs: the N the checkpoint was trained for, or fewer
    /// ([`NeuralFitter::with_iterations`]).
    iterations: usize,
    /// The energy rule that may stop a fit before them ([`NeuralFitter::with_tolerance`]).
    tolerance: Option<f64>,
    /// Models (with modality and residual length) already checked against the checkpoint: the
    /// check hashes the whole model (13,380 vertices and 16 shape directions take milliseconds),
    /// so it runs once per model, not once per call. A `Weak` keeps the model's allocation, so
    /// a live entry's pointer cannot be reused by another model.
    verified: Mutex<Vec<Verified>>,
}

type Verified = (
    std::sync::Weak<lfit_model::Template>,
    lfit_model::observe::Modality,
    usize,
);

/// Why [`NeuralFitter::with_tolerance`] refuses two starts or the lowest-energy pick.
const TOLERANCE_ONE_FIT: &str = "the neural tolerance stops one fit on its last iterate: not with --neural-start both or --neural-pick lowest";

fn neural(e: impl std::fmt::Display) -> FitError {
    FitError::Neural(e.to_string())
}

impl NeuralFitter {
    /// Loads the checkpoint in `dir` onto `device` (Burn).
    pub fn load(dir: &Path, device: &Device, start: Start) -> Result<Self, ModelError> {
        Ok(Self::from_checkpoint(
            checkpoint::load(dir, device)?,
            dir,
            device,
            start,
        ))
    }

    /// A loaded checkpoint on `device` (Burn).
    pub fn from_checkpoint(
        checkpoint: Checkpoint,
        dir: &Path,
        device: &Device,
        start: Start,
    ) -> Self {
        let Checkpoint {
            meta, stats, net, ..
        } = checkpoint;
        Self {
            iterations: meta.network.iterations,
            meta,
            stats,
            engine: Engine::Burn {
                net: Box::new(net),
                device: device.clone(),
            },
            dir: dir.to_path_buf(),
            start,
            pick: Pick::Last,
            tolerance: None,
            verified: Mutex::new(Vec::new()),
        }
    }

    /// The checkpoint in `dir` with its network run by lfit's own f32 forward on the host
    /// (`--runtime native`): the weights are read through Burn's CPU backend once.
    pub fn load_native(dir: &Path, start: Start) -> Result<Self, ModelError> {
        let Checkpoint {
            meta, stats, net, ..
        } = checkpoint::load(dir, &lfit_nn::tensor::ndarray_device())?;
        let host = lfit_nn::HostNet::new(&net, stats.clone())
            .map_err(|e| ModelError::Config(format!("{}: {e}", dir.display())))?;
        Ok(Self {
            iterations: meta.network.iterations,
            meta,
            stats,
            engine: Engine::Native(Box::new(host)),
            dir: dir.to_path_buf(),
            start,
            pick: Pick::Last,
            tolerance: None,
            verified: Mutex::new(Vec::new()),
        })
    }

    /// The fitter with its network in ONNX Runtime: `dir` is a checkpoint (exported to ONNX in
    /// memory) or a directory written by `lfit export-onnx`.
    pub fn load_ort(
        dir: &Path,
        start: Start,
        options: onnx::runtime::SessionOptions,
    ) -> Result<Self, onnx::OnnxError> {
        let network = if dir.join(checkpoint::CONFIG_FILE).is_file() {
            let (_, exported) = onnx::export::export_checkpoint(dir)?;
            onnx::runtime::OrtNetwork::from_exported(&exported, dir, options)?
        } else if dir.join("init.onnx").is_file() {
            onnx::runtime::OrtNetwork::load_dir(dir, options)?
        } else {
            return Err(onnx::OnnxError::model(
                dir,
                "neither a checkpoint (config.json) nor an lfit ONNX export (init.onnx)",
            ));
        };
        Ok(Self {
            iterations: network.meta.network.iterations,
            meta: network.meta.clone(),
            stats: network.stats.clone(),
            engine: Engine::Ort(Box::new(Mutex::new(network))),
            dir: dir.to_path_buf(),
            start,
            pick: Pick::Last,
            tolerance: None,
            verified: Mutex::new(Vec::new()),
        })
    }

    /// The Burn network, if this fitter runs on Burn.
    pub fn burn_net(&self) -> Option<&NeuralNet> {
        match &self.engine {
            Engine::Burn { net, .. } => Some(net.as_ref()),
            Engine::Ort(_) | Engine::Native(_) => None,
        }
    }

    /// Iterations N of one fit.
    pub fn iterations(&self) -> usize {
        self.iterations
    }

    /// The same fitter stopping after its first `iterations` iterations (`lfit fit
    /// --neural-iterations`): 1 to the N it was trained for, an error naming the range
    /// otherwise. Fewer iterations, fewer evaluations: the early iterates are those of the full
    /// fit, each trained on (papers/002's loss reads every iterate).
    pub fn with_iterations(mut self, iterations: usize) -> Result<Self, ModelError> {
        lfit_nn::check_iterations(&self.meta.network, iterations)
            .map_err(|e| ModelError::Config(format!("{}: {e}", self.dir.display())))?;
        self.iterations = iterations;
        Ok(self)
    }

    /// The same fitter stopping a frame's fit at θk (k ≥ 2) once the iteration that made it
    /// lowered the energy by less than `tolerance` of it (`lfit fit --neural-tolerance`;
    /// [`lfit_nn::Exit`]): at most its iterations, and 2k + 1 evaluations when it stops at θk
    /// (θk's own evaluation decides). Between 0 and 1; in a batch each frame stops on its own;
    /// the last iterate returned from one start ([`Start::Both`] and [`Pick::Lowest`] are
    /// refused).
    pub fn with_tolerance(mut self, tolerance: f64) -> Result<Self, ModelError> {
        let exit = lfit_nn::Exit {
            iterations: self.iterations,
            tolerance: Some(tolerance),
        };
        exit.check(&self.meta.network)?;
        if self.start == Start::Both || self.pick == Pick::Lowest {
            return Err(ModelError::Config(TOLERANCE_ONE_FIT.into()));
        }
        self.tolerance = Some(tolerance);
        Ok(self)
    }

    /// When the loop stops.
    fn exit(&self) -> lfit_nn::Exit {
        lfit_nn::Exit {
            iterations: self.iterations,
            tolerance: self.tolerance,
        }
    }

    /// Checks that the checkpoint fits an energy (modality, residual size, template, and the
    /// training energy when the checkpoint records one).
    pub fn check(&self, energy: &Energy) -> Result<(), ModelError> {
        // Before the cache of verified models: frames of one model may carry other energies.
        self.meta.check_energy(&self.dir, energy.config())?;
        let template = energy.template();
        let (modality, dim) = (energy.modality(), energy.sensor().residual_dim(template));
        let known = |v: &Verified| {
            v.1 == modality
                && v.2 == dim
                && v.0
                    .upgrade()
                    .is_some_and(|t| std::sync::Arc::ptr_eq(&t, template))
        };
        if let Ok(list) = self.verified.lock()
            && list.iter().any(known)
        {
            return Ok(());
        }
        self.meta
            .check_compatible(&self.dir, modality, dim, template)?;
        if let Ok(mut list) = self.verified.lock() {
            list.retain(|v| v.0.strong_count() > 0);
            list.push((std::sync::Arc::downgrade(template), modality, dim));
        }
        Ok(())
    }

    /// Φ(D) of every frame, from the engine.
    fn initial(&self, energies: &[&Energy]) -> Result<Vec<Vec<f64>>, FitError> {
        match &self.engine {
            Engine::Burn { net, device } => {
                lfit_nn::initial_poses(net, &self.stats, energies, device).map_err(neural)
            }
            Engine::Ort(network) => {
                let mut network = network.lock().map_err(|_| {
                    FitError::Neural(
                        "the ONNX Runtime session was poisoned by an earlier failure".into(),
                    )
                })?;
                lfit_nn::initial_poses_rows(&mut *network, energies).map_err(neural)
            }
            Engine::Native(host) => {
                lfit_nn::initial_poses_rows(&mut host.as_ref(), energies).map_err(neural)
            }
        }
    }

    /// The same fitter returning the iterate `pick` chooses.
    pub fn with_pick(mut self, pick: Pick) -> Self {
        self.pick = pick;
        self
    }

    /// Evaluations a fit of this fitter makes: 2 per iteration, 2 more to choose the start
    /// with [`Start::Best`], 1 more for the last iterate's energy with [`Pick::Lowest`]; with
    /// [`Start::Both`] the iterations twice and each fit's last iterate's energy (which the
    /// pick reads too).
    pub fn evaluations_per_fit(&self) -> usize {
        let iterations = self.meta.network.evaluations_per_iteration() * self.iterations;
        if self.start == Start::Both {
            return 2 * (iterations + 1);
        }
        let choose = if self.start == Start::Best { 2 } else { 0 };
        let pick = usize::from(self.pick == Pick::Lowest);
        iterations + choose + pick
    }

    /// θ0 … θN of every frame, `[N + 1][B]`, from the engine, and the iterations each frame ran
    /// (fewer than N where the energy rule stopped it; its θ held after that).
    #[allow(clippy::type_complexity)]
    fn run(
        &self,
        energies: &[&Energy],
        starts: &[Option<Vec<f64>>],
        constraints: &Constraints,
    ) -> Result<(Vec<Vec<Vec<f64>>>, Vec<usize>), FitError> {
        match &self.engine {
            Engine::Burn { net, device } => {
                let unrolled = unroll_for(
                    net,
                    &self.stats,
                    energies,
                    starts,
                    Some(constraints),
                    device,
                    &mut Dropout::off(),
                    self.exit(),
                )
                .map_err(neural)?;
                Ok((unrolled.host, unrolled.iterations))
            }
            Engine::Ort(network) => {
                let mut network = network.lock().map_err(|_| {
                    FitError::Neural(
                        "the ONNX Runtime session was poisoned by an earlier failure".into(),
                    )
                })?;
                lfit_nn::unroll_rows_for(
                    &mut *network,
                    energies,
                    starts,
                    Some(constraints),
                    self.exit(),
                )
                .map_err(neural)
            }
            Engine::Native(host) => lfit_nn::unroll_rows_for(
                &mut host.as_ref(),
                energies,
                starts,
                Some(constraints),
                self.exit(),
            )
            .map_err(neural),
        }
    }

    /// Fits a batch of frames in one pass of the network; every result carries the batch's wall
    /// time divided by its size. The budget of each request must allow the fitter's
    /// evaluations (2 per iteration: one gradient evaluation, one residual at θ + Δθ).
    pub fn fit_batch(&self, requests: &[FitRequest<'_>]) -> Result<Vec<FitResult>, FitError> {
        if requests.is_empty() {
            return Ok(Vec::new());
        }
        let n = self.iterations;
        if self.tolerance.is_some() && (self.start == Start::Both || self.pick == Pick::Lowest) {
            return Err(FitError::Neural(TOLERANCE_ONE_FIT.into()));
        }
        // `check` remembers the models it has checked: the signature hash runs once per model.
        for r in requests {
            self.check(r.energy).map_err(neural)?;
            if self.meta.network.known_shape {
                let shape = r.energy.template().layout().range(lfit_model::Block::Shape);
                if r.mask.free.iter().any(|i| shape.contains(i)) {
                    return Err(FitError::Neural(format!(
                        "checkpoint {} was trained with the shape β known (papers/002 §3.2): give β and freeze it (lfit fit --known-shape truth|β values; bench known_shape = true)",
                        self.dir.display()
                    )));
                }
            }
            if r.budget == 0 {
                return Err(FitError::Budget(0));
            }
            if r.budget < self.evaluations_per_fit() {
                return Err(FitError::Neural(format!(
                    "budget {} is below the {} evaluations of {n} iterations{}",
                    r.budget,
                    self.evaluations_per_fit(),
                    match (self.start, self.pick == Pick::Lowest) {
                        (Start::Both, _) => ", twice, and the choice between the two fits",
                        (Start::Best, true) => " and the start and iterate choices",
                        (Start::Best, false) => " and the start choice",
                        (_, true) => " and the iterate choice",
                        (_, false) => "",
                    }
                )));
            }
            // `check` matched the model's parameter count with the network's; the start must match too.
            let dim = self.meta.network.param_dim;
            if r.start.len() != dim {
                return Err(FitError::Start(format!(
                    "start has {} entries, the model's parameter vector {dim}",
                    r.start.len()
                )));
            }
            if r.bounds.lower.len() != dim || r.bounds.upper.len() != dim {
                return Err(FitError::Bounds(format!(
                    "need {dim} lower and upper values"
                )));
            }
            if r.start.iter().any(|v| !v.is_finite()) {
                return Err(FitError::Start("not finite".into()));
            }
        }
        // Frames that stand off the floor the network was trained on are fitted moved onto it
        // ([`floor_move`]), and their results moved back.
        let moves: Vec<DVec3> = requests.iter().map(|r| floor_move(&r.start)).collect();
        if moves.iter().all(|m| *m == DVec3::ZERO) {
            return self.fit_checked(requests);
        }
        let moved: Vec<Option<Energy>> = requests
            .iter()
            .zip(&moves)
            .map(|(r, &m)| match m == DVec3::ZERO {
                true => Ok(None),
                false => r.energy.translated(m),
            })
            .collect::<Result<_, _>>()
            .map_err(neural)?;
        let shift = |p: &mut [f64], m: DVec3| {
            p[0] += m.x;
            p[2] += m.z;
        };
        let on_floor: Vec<FitRequest<'_>> = requests
            .iter()
            .zip(&moves)
            .zip(&moved)
            .map(|((r, &m), e)| match e {
                Some(energy) => {
                    let mut request = FitRequest {
                        energy,
                        ..r.clone()
                    };
                    shift(&mut request.start, m);
                    shift(&mut request.bounds.lower, m);
                    shift(&mut request.bounds.upper, m);
                    request
                }
                // A sensor without a translated form is fitted where it stands.
                None => r.clone(),
            })
            .collect();
        let mut results = self.fit_checked(&on_floor)?;
        for ((result, &m), e) in results.iter_mut().zip(&moves).zip(&moved) {
            if e.is_some() {
                shift(&mut result.pose, -m);
                for p in &mut result.iterates {
                    shift(p, -m);
                }
            }
        }
        Ok(results)
    }

    /// [`NeuralFitter::fit_batch`] on requests it has checked.
    fn fit_checked(&self, requests: &[FitRequest<'_>]) -> Result<Vec<FitResult>, FitError> {
        let per_iteration = self.meta.network.evaluations_per_iteration();
        let timer = Instant::now();
        let e0: Vec<(u64, u64)> = requests
            .iter()
            .map(|r| (r.energy.evaluations(), r.energy.gradient_evaluations()))
            .collect();
        let energies: Vec<&Energy> = requests.iter().map(|r| r.energy).collect();
        let given = requests.iter().map(|r| {
            let mut s = r.start.clone();
            r.bounds.clamp(&mut s);
            s
        });
        let starts: Vec<Option<Vec<f64>>> = match self.start {
            Start::Phi => vec![None; requests.len()],
            Start::Given | Start::Both => given.map(Some).collect(),
            Start::Best => {
                // Both candidates inside the box, each evaluated once (counted).
                let phi = self.initial(&energies)?;
                given
                    .zip(phi)
                    .zip(requests)
                    .map(|((g, mut p), r)| {
                        // As with Start::Phi: Φ(D) inside the box.
                        r.bounds.clamp(&mut p);
                        let (eg, ep) = (r.energy.evaluate(&g).total, r.energy.evaluate(&p).total);
                        Some(if ep < eg { p } else { g })
                    })
                    .collect()
            }
        };
        let constraints = Constraints {
            free: requests
                .iter()
                .map(|r| {
                    let mut f = vec![false; r.start.len()];
                    for &i in &r.mask.free {
                        if i < f.len() {
                            f[i] = true;
                        }
                    }
                    f
                })
                .collect(),
            bounds: requests
                .iter()
                .map(|r| r.bounds.clone())
                .collect::<Vec<Bounds>>(),
        };
        // One fit, or with Start::Both the fit from the given start and the fit from Φ(D).
        let (first, ran) = self.run(&energies, &starts, &constraints)?;
        let mut runs = vec![first];
        if self.start == Start::Both {
            runs.push(
                self.run(&energies, &vec![None; requests.len()], &constraints)?
                    .0,
            );
        }
        // The loop clamps in f32; clamp again in f64 so that every iterate is exactly inside
        // the request's bounds (the two differ by at most an f32 rounding).
        for iterate in runs.iter_mut().flatten() {
            for (p, r) in iterate.iter_mut().zip(requests) {
                r.bounds.clamp(p);
            }
        }
        let time_s = timer.elapsed().as_secs_f64() / requests.len() as f64;
        let name = self.name();
        Ok(requests
            .iter()
            .enumerate()
            .map(|(i, r)| {
                // The frame's iterations: all of them, or with the energy rule (one fit) those
                // before it stopped; θn was then evaluated by the loop too (counted there).
                let n = ran[i];
                let stopped = self.tolerance.is_some() && n < self.iterations;
                let residual_evaluations = (per_iteration * n) as u64;
                // Energy of every iterate of every fit, once: for the trace and the picks.
                // θ0 … θN−1 were evaluated by the loop (reporting only here: `inspect` is not
                // counted); θN is new to the fit, so a choice made by it ([`Pick::Lowest`], the
                // choice between the fits of [`Start::Both`]) counts it.
                let both = runs.len() > 1;
                let energies: Vec<Vec<f64>> = runs
                    .iter()
                    .map(|host| {
                        (0..=n)
                            .map(|k| {
                                if k == n && (both || self.pick == Pick::Lowest) {
                                    r.energy.evaluate(&host[k][i]).total
                                } else {
                                    r.energy.inspect(&host[k][i]).total
                                }
                            })
                            .collect()
                    })
                    .collect();
                let picked: Vec<usize> = energies
                    .iter()
                    .map(|e| match self.pick {
                        Pick::Last => n,
                        Pick::Lowest => {
                            (0..n).fold(n, |best, k| if e[k] < e[best] { k } else { best })
                        }
                    })
                    .collect();
                // The fit whose pick has the lower energy (the given start's on a tie).
                let fit = (1..runs.len()).fold(0, |best, f| {
                    if energies[f][picked[f]] < energies[best][picked[best]] {
                        f
                    } else {
                        best
                    }
                });
                let host = &runs[fit];
                let pose = host[picked[fit]][i].clone();
                let report = r.energy.inspect(&pose);
                let evaluations = r.energy.evaluations() - e0[i].0
                    + runs.len() as u64 * (residual_evaluations - n as u64);
                // The x axis of the trace is the evaluations used to reach each iterate; with
                // two fits, the second's iterates follow the first's.
                let trace = if both {
                    (0..runs.len())
                        .flat_map(|f| {
                            let offset = f * (per_iteration * n + 1);
                            let e = &energies[f];
                            (0..=n).map(move |k| {
                                (
                                    (offset + per_iteration * k + usize::from(k == n)) as u64,
                                    e[k],
                                )
                            })
                        })
                        .collect()
                } else {
                    // The start's and the pick's evaluations, then 2 per iteration (and θn's own
                    // where the energy rule stopped there).
                    let extra = self.evaluations_per_fit() - per_iteration * self.iterations;
                    (0..=n)
                        .map(|k| {
                            (
                                (extra + per_iteration * k + usize::from(stopped && k == n)) as u64,
                                energies[0][k],
                            )
                        })
                        .collect()
                };
                FitResult {
                    method: name.clone(),
                    pose,
                    energy: report.total,
                    terms: report.terms,
                    evaluations,
                    gradient_evaluations: r.energy.gradient_evaluations() - e0[i].1,
                    iterations: n as u64,
                    time_s,
                    trace,
                    iterates: host[..=n].iter().map(|h| h[i].clone()).collect(),
                }
            })
            .collect())
    }
}

/// The horizontal move (world x, z) that brings a frame whose start stands beyond the starts
/// the networks were trained from onto the floor their targets covered. Synthesis puts the root
/// of every training frame within ±[`FLOOR_SPREAD`] (0.6 m) of the origin and starts it at most
/// [`LOCAL_TRANSLATION`] (0.4 m) from there; a capture's subject stands anywhere in the lab's
/// volume (a C3D's lab frame has its origin wherever the studio put it), and the network reads
/// positions, not only their differences: frames imported 3.6 m from the origin ended at a
/// marker RMS of 88 mm (V2V 124) where the same frames at the origin ended at 12 (V2V 17;
/// `docs/results/captured-motion.md`, round 16). Each of x and z beyond ±1.0 m is moved to ±0.6 m; the energy does not change under the
/// move ([`Energy::translated`]). Frames that start within ±1.0 m are not moved: their results
/// are bit for bit those of the fitter without it.
pub fn floor_move(start: &[f64]) -> DVec3 {
    let along = |x: f64| {
        if x.abs() > FLOOR_SPREAD + LOCAL_TRANSLATION {
            x.clamp(-FLOOR_SPREAD, FLOOR_SPREAD) - x
        } else {
            0.0
        }
    };
    DVec3::new(along(start[0]), 0.0, along(start[2]))
}

impl Fitter for NeuralFitter {
    fn name(&self) -> String {
        let start = match self.start {
            Start::Phi => "neural",
            Start::Given => "neural-given",
            Start::Best => "neural-best",
            Start::Both => "neural-both",
        };
        let mut base = match self.pick {
            Pick::Last => start.to_string(),
            Pick::Lowest => format!("{start}-lowest"),
        };
        // An early exit says how many iterations it ran.
        if self.iterations != self.meta.network.iterations {
            base = format!("{base}-n{}", self.iterations);
        }
        if let Some(t) = self.tolerance {
            base = format!("{base}-tol{t}");
        }
        match self.engine {
            Engine::Burn { .. } => base.into(),
            Engine::Ort(_) => format!("{base}-ort"),
            Engine::Native(_) => format!("{base}-native"),
        }
    }

    fn fit(&self, request: &FitRequest<'_>) -> Result<FitResult, FitError> {
        NeuralFitter::fit_batch(self, std::slice::from_ref(request))?
            .pop()
            .ok_or_else(|| FitError::Neural("no result".into()))
    }

    fn fit_batch(&self, requests: &[FitRequest<'_>]) -> Result<Vec<FitResult>, FitError> {
        NeuralFitter::fit_batch(self, requests)
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod tests {
    use std::sync::Arc;

    use lfit_model::energy::{EnergyConfig, Target};
    use lfit_model::observe::{Modality, Sensor};

    use super::*;

    fn energy(t: &Arc<lfit_model::Template>) -> Energy {
        let sensor = Sensor::default_for(Modality::Markers, t);
        let p = sensor.predict_sparse(t, &vec![0.0; t.param_dim()]);
        Energy::new(
            t.clone(),
            sensor,
            Target::Sparse {
                values: p.values,
                visible: p.visible,
            },
            EnergyConfig::default(),
        )
        .unwrap()
    }

    /// The compatibility check is remembered per model, and a model with the same layout but
    /// other arrays is still refused after another model passed.
    #[test]
    fn the_model_check_is_cached_per_model_and_still_refuses_another_model() {
        let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
        let model = Arc::new(
            lfit_model::modelfile::load(&root.join("models/makehuman-cmu_mb.npz")).unwrap(),
        );
        let device = lfit_nn::tensor::ndarray_device();
        let f = NeuralFitter::load(
            &root.join("checkpoints/markers-makehuman"),
            &device,
            Start::Given,
        )
        .unwrap();
        let e = energy(&model);
        f.check(&e).unwrap();
        f.check(&e).unwrap();
        assert_eq!(f.verified.lock().unwrap().len(), 1);
        // Same layout, one rest vertex moved: another signature.
        let mut other = (*model).clone();
        let mut morph = (*other.morph).clone();
        morph.rest[0].x += 0.01;
        other.morph = Arc::new(morph);
        other.vertices[0].x += 0.01;
        let other = Arc::new(other);
        assert_eq!(other.param_dim(), model.param_dim());
        let err = f.check(&energy(&other)).unwrap_err().to_string();
        assert!(err.contains("was trained on model"), "{err}");
        assert_eq!(f.verified.lock().unwrap().len(), 1);
        // A dropped model leaves the list when the next one is added.
        drop(e);
        drop(model);
        let third = Arc::new(
            lfit_model::modelfile::load(&root.join("models/makehuman-cmu_mb.npz")).unwrap(),
        );
        f.check(&energy(&third)).unwrap();
        assert_eq!(f.verified.lock().unwrap().len(), 1);
    }

    /// A frame whose start stands beyond the floor the network was trained on is fitted moved
    /// onto it: the frame 3 m further along x gives the fit of the frame on the floor's edge,
    /// moved back (within the network's f32 rounding), where without the move the network,
    /// which reads positions, fits another pose. Starts within ±1.0 m are not moved, nor is y.
    #[test]
    fn a_frame_far_across_the_floor_fits_as_the_frame_on_it() {
        let mut p = vec![0.0; 6];
        for (x, want) in [(0.9, 0.0), (-1.0, 0.0), (1.2, -0.6), (-3.0, 2.4)] {
            p[0] = x;
            p[1] = 7.0;
            p[2] = -x;
            let m = floor_move(&p);
            assert!(
                (m.x - want).abs() < 1e-12 && (m.z + want).abs() < 1e-12,
                "{x}: {m}"
            );
            assert_eq!(m.y, 0.0);
        }
        let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
        let model = Arc::new(
            lfit_model::modelfile::load(&root.join("models/makehuman-cmu_mb.npz")).unwrap(),
        );
        let f =
            NeuralFitter::load_native(&root.join("checkpoints/markers-makehuman"), Start::Given)
                .unwrap();
        let dim = model.param_dim();
        let pose_dim = model.layout().pose_dim();
        let truth: Vec<f64> = (0..dim)
            .map(|i| match i {
                0 => 0.6,
                1 => 0.0,
                2 => 0.3,
                i if i < pose_dim => 0.12 * ((i * 7) as f64).sin(),
                _ => 0.5 * ((i * 3) as f64).cos(),
            })
            .collect();
        let mut start = truth.clone();
        for (i, v) in start.iter_mut().enumerate().skip(3) {
            *v = if i < pose_dim { *v + 0.05 } else { 0.0 };
        }
        let sensor = Sensor::default_for(Modality::Markers, &model);
        let pred = sensor.predict_sparse(&model, &truth);
        let target = Target::Sparse {
            values: pred.values,
            visible: pred.visible,
        };
        let config = EnergyConfig::default().for_gradient();
        let near = Energy::new(model.clone(), sensor, target, config).unwrap();
        let offset = DVec3::new(3.0, 0.0, 0.0);
        let far = near.translated(offset).unwrap().unwrap();
        let layout = model.layout();
        let mask = lfit_model::pose::DofMask {
            name: "custom".into(),
            free: (0..dim).collect(),
        };
        let request = |energy, start: Vec<f64>| FitRequest {
            energy,
            bounds: Bounds::local_in(&layout, &start),
            start,
            mask: mask.clone(),
            budget: 100,
            seed: 1,
            motion: None,
        };
        let mut far_start = start.clone();
        far_start[0] += offset.x;
        let a = f.fit_batch(&[request(&near, start)]).unwrap().remove(0);
        let b = f
            .fit_batch(&[request(&far, far_start.clone())])
            .unwrap()
            .remove(0);
        assert_eq!(a.evaluations, b.evaluations);
        assert!(
            (a.energy - b.energy).abs() <= 1e-4 * a.energy,
            "{} vs {}",
            a.energy,
            b.energy
        );
        let gap = |x: &[f64], y: &[f64]| {
            (0..dim).fold(0.0f64, |m, i| {
                let shift = if i == 0 { offset.x } else { 0.0 };
                m.max((x[i] + shift - y[i]).abs())
            })
        };
        assert!(
            gap(&a.pose, &b.pose) < 1e-4,
            "moved fit off by {}",
            gap(&a.pose, &b.pose)
        );
        assert_eq!(a.iterates.len(), b.iterates.len());
        for (x, y) in a.iterates.iter().zip(&b.iterates) {
            assert!(gap(x, y) < 1e-4);
        }
        // Fitted where it stands, the far frame is another fit.
        let unmoved = f
            .fit_checked(&[request(&far, far_start)])
            .unwrap()
            .remove(0);
        assert!(
            gap(&a.pose, &unmoved.pose) > 1e-3,
            "{}",
            gap(&a.pose, &unmoved.pose)
        );
    }
}
