//! The fitting loop of papers/002 Alg. 1 on a batch of frames: the network runs on the tensor
//! device, the energy (residuals R and exact gradients g, detached) on the CPU with rayon. Both
//! training (autodiff device, dropout) and inference use this one loop.

use std::borrow::Cow;

use burn::tensor::{Device, Int, Tensor, TensorData};
use rayon::prelude::*;

use crate::config::{Direction, NetConfig, Views};
use crate::features::{FeatureStats, observation_features_for, pooled_cameras, residual_features};
use crate::layers::Dropout;
use crate::net::NeuralNet;
use crate::tensor::{poses_to_tensor, tensor_to_rows};
use lfit_model::energy::{ChordSystem, Energy};
use lfit_model::error::{ModelError, Result};
use lfit_model::pose::Bounds;

/// Per-frame limits at inference: which DOFs may move and the box they stay in.
#[derive(Debug, Clone)]
pub struct Constraints {
    pub free: Vec<Vec<bool>>,
    pub bounds: Vec<Bounds>,
}

/// What the loop produced.
#[derive(Debug, Clone)]
pub struct Unrolled {
    /// θ0 … θN, `[B, param_dim]` each (differentiable on an autodiff device).
    pub poses: Vec<Tensor<2>>,
    /// The same parameter vectors on the host, `[N + 1][B]`.
    pub host: Vec<Vec<Vec<f64>>>,
    /// Per frame, the iterations it ran: all of them, or fewer where [`Exit::tolerance`]
    /// stopped it (its θ held in `host` and `poses` after that). Its residual evaluations
    /// follow: [`NetConfig::evaluations_per_iteration`] per iteration (the energy counts its
    /// own evaluations and gradient evaluations).
    pub iterations: Vec<usize>,
}

/// The batch rows `rows` as an index tensor.
fn index_tensor(rows: &[usize], device: &Device) -> Tensor<1, Int> {
    let v: Vec<i64> = rows.iter().map(|&r| r as i64).collect();
    let len = v.len();
    Tensor::<1, Int>::from_data(TensorData::new(v, [len]), device)
}

fn rows_tensor(rows: &[f32], batch: usize, device: &Device) -> Tensor<2> {
    let d = if batch == 0 { 0 } else { rows.len() / batch };
    Tensor::from_data(TensorData::new(rows.to_vec(), [batch, d]), device)
}

/// The parameter vectors of a `[B, dim]` tensor on the host (detached).
fn to_host(t: &Tensor<2>, dim: usize) -> Result<Vec<Vec<f64>>> {
    let [batch, d] = t.dims();
    if d != dim {
        return Err(ModelError::Shape {
            what: "pose tensor".into(),
            expected: format!("[{batch}, {dim}]"),
            got: format!("[{batch}, {d}]"),
        });
    }
    Ok(tensor_to_rows(t.clone().detach())?
        .iter()
        .map(|row| row.iter().map(|&x| f64::from(x)).collect())
        .collect())
}

/// Checks an early exit ([`unroll_for`]): between 1 and the N iterations the network was
/// trained for (each of its first N iterates was trained on; beyond N none was).
pub fn check_iterations(config: &NetConfig, iterations: usize) -> Result<()> {
    if iterations == 0 || iterations > config.iterations {
        return Err(ModelError::Config(format!(
            "{iterations} iterations asked of a network trained for {}: choose 1 to {}",
            config.iterations, config.iterations
        )));
    }
    Ok(())
}

/// When the learned loop stops ([`unroll_for`], [`unroll_rows_for`]; `lfit fit
/// --neural-iterations`, `--neural-tolerance`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Exit {
    /// At most this many iterations (1 to the N the network was trained for).
    pub iterations: usize,
    /// The energy rule: the loop stops at θk, k ≥ 2, once the iteration that made it lowered
    /// the energy by less than this fraction, `E(θk−1) − E(θk) < tolerance · E(θk−1)` (a
    /// relative decrease, as a classical optimizer's function tolerance; with the Gauss-Newton
    /// direction θk's energy comes from its residuals alone, and the direction is computed only
    /// if the frame goes on). `None`: every iteration runs. In a
    /// batch each frame stops on its own: a stopped frame's θ is held, its energy no longer
    /// evaluated, its rows out of the network's passes, and the loop ends when every frame
    /// has stopped.
    pub tolerance: Option<f64>,
}

impl Exit {
    /// Every one of `iterations`, no energy rule.
    pub fn after(iterations: usize) -> Self {
        Self {
            iterations,
            tolerance: None,
        }
    }

    /// Checks the exit against the network ([`check_iterations`]): a tolerance is in (0, 1).
    pub fn check(&self, config: &NetConfig) -> Result<()> {
        check_iterations(config, self.iterations)?;
        if let Some(t) = self.tolerance
            && !(t > 0.0 && t < 1.0)
        {
            return Err(ModelError::Config(format!(
                "neural tolerance {t}: a relative energy decrease between 0 and 1 (exclusive)"
            )));
        }
        Ok(())
    }

    /// Whether the loop stops at θn, given E(θn−1) (`previous`) and E(θn) (`energy`).
    fn stops(&self, n: usize, previous: f64, energy: f64) -> bool {
        self.tolerance
            .is_some_and(|t| n >= 2 && previous - energy < t * previous)
    }
}

/// The frames of a batch under [`Exit`]: which still run, each one's last energy and
/// evaluation, and the iterations each ran.
struct Running {
    active: Vec<bool>,
    previous: Vec<f64>,
    evals: Vec<(Vec<f64>, Vec<f64>)>,
    iterations: Vec<usize>,
    /// Each frame's damped system of the last iterate that factorised one (θ0, or the first
    /// `chord_factorisations` iterates), for [`Direction::GaussNewtonChord`].
    chords: Vec<Option<ChordSystem>>,
    /// The frames whose rows the network still runs, in batch order (the loops keep the
    /// recurrent state of these rows only): a frame the energy rule stopped leaves the
    /// network's passes and its θ is held. Without a tolerance (training) every frame runs
    /// every pass.
    alive: Vec<usize>,
}

/// The running frames' energies, evaluations (R, g), poses and observation rows: the batch's
/// own while every frame runs, copies of the running frames' once some stopped.
struct Picked<'a, 'e> {
    energies: Cow<'a, [&'e Energy]>,
    evals: Cow<'a, [(Vec<f64>, Vec<f64>)]>,
    current: Cow<'a, [Vec<f64>]>,
    obs: Cow<'a, [Vec<f32>]>,
}

impl Running {
    fn new(batch: usize) -> Self {
        Self {
            active: vec![true; batch],
            previous: vec![f64::INFINITY; batch],
            evals: vec![(Vec::new(), Vec::new()); batch],
            iterations: vec![0; batch],
            chords: vec![None; batch],
            alive: (0..batch).collect(),
        }
    }

    /// Drops the frames that stopped from [`Running::alive`]; when any stopped, the positions
    /// of those kept among the rows alive before, and how many rows that was (for the
    /// recurrent state's rows).
    fn shrink(&mut self) -> Option<(Vec<usize>, usize)> {
        let before = self.alive.len();
        let keep: Vec<usize> = (0..before)
            .filter(|&p| self.active[self.alive[p]])
            .collect();
        if keep.len() == before {
            return None;
        }
        self.alive = keep.iter().map(|&p| self.alive[p]).collect();
        Some((keep, before))
    }

    /// The running frames' energies, evaluations, poses and observation rows (borrowed while
    /// every frame of the batch runs).
    fn picked<'a, 'e>(
        &'a self,
        energies: &'a [&'e Energy],
        current: &'a [Vec<f64>],
        obs: &'a [Vec<f32>],
    ) -> Picked<'a, 'e> {
        if self.alive.len() == energies.len() {
            return Picked {
                energies: Cow::Borrowed(energies),
                evals: Cow::Borrowed(&self.evals),
                current: Cow::Borrowed(current),
                obs: Cow::Borrowed(obs),
            };
        }
        let a = &self.alive;
        Picked {
            energies: a.iter().map(|&i| energies[i]).collect(),
            evals: a.iter().map(|&i| self.evals[i].clone()).collect(),
            current: a.iter().map(|&i| current[i].clone()).collect(),
            obs: a.iter().map(|&i| obs[i].clone()).collect(),
        }
    }

    /// Iteration `n`: R(θ), g(θ) and E(θ) of the frames still running (a stopped frame's are
    /// not evaluated again: its last ones stay in `evals`, read by nothing that moves it), then
    /// the energy rule; false once no frame runs.
    ///
    /// Where the rule can stop a frame (a tolerance, n ≥ 2) and the direction is Gauss-Newton's,
    /// each running frame's energy comes first, from its residuals alone (one evaluation, the
    /// same value the Gauss-Newton evaluation gives: `residuals_alone_give_the_energy_the_
    /// gauss_newton_evaluation_gives`), and the Jacobian, normal equations and solve only for
    /// the frames that go on — a gradient evaluation at a point already evaluated, as LM's
    /// accepted trial points. A frame that stops then costs no direction it would not use: the
    /// same iterates and evaluations, one gradient evaluation fewer.
    fn evaluate(
        &mut self,
        config: &NetConfig,
        exit: &Exit,
        n: usize,
        energies: &[&Energy],
        current: &[Vec<f64>],
        free: Option<&[Vec<bool>]>,
    ) -> Result<bool> {
        let mut run: Vec<usize> = (0..energies.len()).filter(|&i| self.active[i]).collect();
        // (The chord direction's later iterations read E(θ) from their gradient evaluation.)
        let value_first =
            exit.tolerance.is_some() && n >= 2 && config.direction == Direction::GaussNewton;
        if value_first {
            let values: Vec<f64> = run
                .par_iter()
                .map(|&i| gauss_newton_value(energies[i], &current[i]))
                .collect::<Result<_>>()?;
            for (&i, value) in run.iter().zip(values) {
                if exit.stops(n, self.previous[i], value) {
                    self.active[i] = false;
                } else {
                    self.previous[i] = value;
                }
            }
            run.retain(|&i| self.active[i]);
            if run.is_empty() {
                return Ok(false);
            }
        }
        let all = run.len() == energies.len();
        // The chord direction factorises again at each of its first `chord_factorisations`
        // iterates, and solves the last system after them.
        let chords: Vec<Option<&ChordSystem>> = run
            .iter()
            .map(|&i| {
                self.chords[i]
                    .as_ref()
                    .filter(|_| n >= config.chord_factorisations)
            })
            .collect();
        let (evals, values, systems) = if all {
            evaluate_counted(config, energies, current, free, !value_first, &chords)?
        } else {
            let pick = |v: &[Vec<f64>]| run.iter().map(|&i| v[i].clone()).collect::<Vec<_>>();
            let e: Vec<&Energy> = run.iter().map(|&i| energies[i]).collect();
            let f: Option<Vec<Vec<bool>>> =
                free.map(|f| run.iter().map(|&i| f[i].clone()).collect());
            evaluate_counted(
                config,
                &e,
                &pick(current),
                f.as_deref(),
                !value_first,
                &chords,
            )?
        };
        for (&i, system) in run.iter().zip(systems) {
            if system.is_some() {
                self.chords[i] = system;
            }
        }
        for ((&i, eval), value) in run.iter().zip(evals).zip(values) {
            if !value_first && exit.stops(n, self.previous[i], value) {
                self.active[i] = false;
            } else {
                self.previous[i] = value;
                self.evals[i] = eval;
                self.iterations[i] = n + 1;
            }
        }
        Ok(self.active.iter().any(|&a| a))
    }
}

/// E(θ) as the Gauss-Newton direction's evaluation gives it (the sum of squares of its
/// residuals: robust loss folded, the data rows factored), from the residuals alone; counts one
/// evaluation.
pub fn gauss_newton_value(energy: &Energy, pose: &[f64]) -> Result<f64> {
    Ok(energy
        .least_squares_with(
            pose,
            false,
            lfit_model::energy::RobustForm::Folded,
            lfit_model::energy::JacobianRows::Factored,
        )?
        .value())
}

/// Checks a batch against the network: at least one frame, one start entry per frame, every
/// frame of the network's modality, and for a pooled network every frame a `keypoints2d` rig of
/// its keypoints.
pub fn check_batch(
    config: &NetConfig,
    energies: &[&Energy],
    starts: &[Option<Vec<f64>>],
) -> Result<()> {
    let batch = energies.len();
    if batch == 0 || starts.len() != batch {
        return Err(ModelError::Shape {
            what: "neural fitter batch".into(),
            expected: format!("{batch} start entries, at least one frame"),
            got: starts.len().to_string(),
        });
    }
    if let Some(e) = energies.iter().find(|e| e.modality() != config.modality) {
        return Err(ModelError::Config(format!(
            "the network fits {} data, this frame is {}",
            config.modality,
            e.modality()
        )));
    }
    if let Some(e) = energies.iter().find(|e| e.dim() != config.param_dim) {
        return Err(ModelError::Config(format!(
            "the network predicts {} parameters, the model '{}' has {}: it was trained on another model",
            config.param_dim,
            e.template().id,
            e.dim()
        )));
    }
    if config.views == Views::Pooled {
        for e in energies {
            pooled_cameras(config, e)?;
        }
    }
    if let Some(s) = starts
        .iter()
        .flatten()
        .find(|s| s.len() != config.param_dim)
    {
        return Err(ModelError::Shape {
            what: "start".into(),
            expected: config.param_dim.to_string(),
            got: s.len().to_string(),
        });
    }
    Ok(())
}

/// The normalised observation features D of every frame.
pub fn observation_rows(
    config: &NetConfig,
    stats: &FeatureStats,
    energies: &[&Energy],
) -> Result<Vec<Vec<f32>>> {
    let dim = config.obs_features();
    let mut out = Vec::with_capacity(energies.len());
    for e in energies {
        let r = observation_features_for(config, e)?;
        if r.len() != dim {
            return Err(ModelError::Shape {
                what: "observation features".into(),
                expected: dim.to_string(),
                got: r.len().to_string(),
            });
        }
        let mut v = Vec::with_capacity(dim);
        stats
            .observation
            .push(&r, config.feature_clip as f32, &mut v);
        out.push(v);
    }
    Ok(out)
}

/// The per-frame limits as `[B, dim]` rows: free mask (1/0), lower and upper bounds.
pub fn constraint_rows(
    constraints: &Constraints,
    batch: usize,
    dim: usize,
) -> Result<(Vec<f32>, Vec<f32>, Vec<f32>)> {
    let k = constraints;
    if k.free.len() != batch || k.bounds.len() != batch {
        return Err(ModelError::Shape {
            what: "constraints".into(),
            expected: batch.to_string(),
            got: k.free.len().to_string(),
        });
    }
    let f: Vec<f32> = k
        .free
        .iter()
        .flat_map(|m| m.iter().map(|&b| if b { 1.0 } else { 0.0 }))
        .collect();
    let lo: Vec<f32> = k
        .bounds
        .iter()
        .flat_map(|b| b.lower.iter().map(|&x| x as f32))
        .collect();
    let hi: Vec<f32> = k
        .bounds
        .iter()
        .flat_map(|b| b.upper.iter().map(|&x| x as f32))
        .collect();
    if lo.len() != batch * dim || hi.len() != batch * dim || f.len() != batch * dim {
        return Err(ModelError::Shape {
            what: "bounds".into(),
            expected: dim.to_string(),
            got: (lo.len() / batch.max(1)).to_string(),
        });
    }
    Ok((f, lo, hi))
}

/// The direction `g` of the update rule at `pose` ([`Direction`]): the energy gradient, or the
/// negated damped Gauss-Newton step over the `free` entries (all when `None`), each entry
/// clipped to `±gn_max_step`; non-finite
/// entries zeroed, frozen entries of the Gauss-Newton direction zero. Counts one evaluation and
/// one gradient evaluation of `energy` either way.
///
/// Stateless: [`Direction::GaussNewtonChord`] gives its first iteration's direction here (the
/// Gauss-Newton direction at `pose`); the loops keep each frame's system for the later ones.
pub fn direction(
    config: &NetConfig,
    energy: &Energy,
    pose: &[f64],
    free: Option<&[bool]>,
) -> Result<Vec<f64>> {
    Ok(residual_and_direction(config, energy, pose, free, false, true, None)?.1)
}

/// R(θ) (when `with_residual`, else empty), [`direction`] and E(θ) at `pose`. The
/// Gauss-Newton direction's least-squares evaluation gives R(θ) from its own prediction
/// ([`lfit_model::energy::LeastSquares::observation_residual`]), so it costs no second residual
/// pass; the gradient direction computes it apart. With `counted` false the Gauss-Newton
/// evaluation is of a point whose residuals were just evaluated and counted
/// ([`gauss_newton_value`]): it counts one gradient evaluation and no new evaluation
/// ([`Energy::jacobian_with`]).
///
/// [`Direction::GaussNewtonChord`]: with the frame's `chord` system (of its first iterate) the
/// direction solves that system with the gradient at `pose` (one evaluation and one gradient
/// evaluation, as the others; E(θ) from the same evaluation); without one it is the
/// Gauss-Newton direction and the system it factorised is returned for the later iterations.
#[allow(clippy::type_complexity)]
fn residual_and_direction(
    config: &NetConfig,
    energy: &Energy,
    pose: &[f64],
    free: Option<&[bool]>,
    with_residual: bool,
    counted: bool,
    chord: Option<&ChordSystem>,
) -> Result<(Vec<f64>, Vec<f64>, f64, Option<ChordSystem>)> {
    let mut system = None;
    // E(θ), ∇E and, where the features read it, R(θ), from one evaluation.
    let evaluate = || {
        if with_residual {
            energy.evaluate_with_gradient_and_residual(pose)
        } else {
            let (e, g) = energy.evaluate_with_gradient(pose);
            (e, g, Vec::new())
        }
    };
    // A damped step `h` as the direction: `−h`, each entry clipped to `±gn_max_step`.
    let cap = config.gn_max_step;
    let negated = |h: Vec<f64>| -> Vec<f64> { h.iter().map(|v| -v.clamp(-cap, cap)).collect() };
    let (r, mut g, value) = match (config.direction, chord) {
        (Direction::Gradient, _) => {
            let (e, g, r) = evaluate();
            (r, g, e.total)
        }
        (Direction::GaussNewtonChord, Some(chord)) => {
            let (e, g, r) = evaluate();
            // A system that cannot solve (only a non-finite gradient): no step.
            let h = chord.step(&g).unwrap_or_else(|| vec![0.0; pose.len()]);
            (r, negated(h), e.total)
        }
        (Direction::GaussNewton | Direction::GaussNewtonChord, _) => {
            // The normal equations read the data rows in factored form where there is one.
            let (form, rows) = (
                lfit_model::energy::RobustForm::Folded,
                lfit_model::energy::JacobianRows::Factored,
            );
            let ls = if counted {
                energy.least_squares_with(pose, true, form, rows)?
            } else {
                energy.jacobian_with(pose, form, rows)?
            };
            let dofs: Vec<usize> = match free {
                Some(f) => (0..pose.len())
                    .filter(|&i| f.get(i).copied().unwrap_or(false))
                    .collect(),
                None => (0..pose.len()).collect(),
            };
            // Not positive definite (only with a degenerate Jacobian, the ridge aside): no step.
            // The chord direction keeps the factorised system for the later iterations.
            let rank = energy.template().elimination_rank();
            let (h, factorised) = ls
                .damped_gauss_newton_chord(&dofs, config.gn_damping, &rank)
                .unzip();
            system = factorised.filter(|_| config.direction == Direction::GaussNewtonChord);
            let h = h.unwrap_or_else(|| vec![0.0; pose.len()]);
            let value = ls.value();
            (
                if with_residual {
                    ls.observation_residual
                } else {
                    Vec::new()
                },
                negated(h),
                value,
            )
        }
    };
    for x in g.iter_mut() {
        if !x.is_finite() {
            *x = 0.0;
        }
    }
    Ok((r, g, value, system))
}

/// R(θ) and the update direction g(θ) ([`direction`]) of every frame at its current pose, on
/// the CPU; `free[i]` is frame `i`'s free mask (`None`: all entries free).
pub fn evaluate(
    config: &NetConfig,
    energies: &[&Energy],
    current: &[Vec<f64>],
    free: Option<&[Vec<bool>]>,
) -> Result<Vec<(Vec<f64>, Vec<f64>)>> {
    Ok(evaluate_counted(config, energies, current, free, true, &[])?.0)
}

/// [`evaluate`] and every frame's energy at its current pose (from the same evaluation);
/// `counted` as [`residual_and_direction`]; `chords[i]` frame `i`'s system of
/// [`Direction::GaussNewtonChord`] (empty: none yet), and the systems factorised now.
#[allow(clippy::type_complexity)]
fn evaluate_counted(
    config: &NetConfig,
    energies: &[&Energy],
    current: &[Vec<f64>],
    free: Option<&[Vec<bool>]>,
    counted: bool,
    chords: &[Option<&ChordSystem>],
) -> Result<Evaluated> {
    let all: Vec<(Vec<f64>, Vec<f64>, f64, Option<ChordSystem>)> = energies
        .par_iter()
        .zip(current.par_iter())
        .enumerate()
        .map(|(i, (e, p))| {
            let f = free.and_then(|f| f.get(i)).map(Vec::as_slice);
            let chord = chords.get(i).copied().flatten();
            residual_and_direction(config, e, p, f, true, counted, chord)
        })
        .collect::<Result<_>>()?;
    let (mut evals, mut values, mut systems) = (Vec::new(), Vec::new(), Vec::new());
    for (r, g, e, s) in all {
        evals.push((r, g));
        values.push(e);
        systems.push(s);
    }
    Ok((evals, values, systems))
}

/// Every frame's (R, g), E and new chord system ([`evaluate_counted`]).
type Evaluated = (
    Vec<(Vec<f64>, Vec<f64>)>,
    Vec<f64>,
    Vec<Option<ChordSystem>>,
);

/// The normalised core inputs `[R(θ), g, θ, D]` (R as the residual features of
/// [`residual_features`]), `[B, core_inputs]` row-major; `evals` and `obs` are of `energies`.
pub fn core_rows(
    config: &NetConfig,
    stats: &FeatureStats,
    energies: &[&Energy],
    evals: &[(Vec<f64>, Vec<f64>)],
    current: &[Vec<f64>],
    obs: &[Vec<f32>],
) -> Result<Vec<f32>> {
    let clip = config.feature_clip as f32;
    let mut core_in = Vec::with_capacity(evals.len() * config.core_inputs());
    for (((r, g), (p, d)), e) in evals.iter().zip(current.iter().zip(obs)).zip(energies) {
        let r = residual_features(config, e, r)?;
        if r.len() != config.residual_features() {
            return Err(ModelError::Shape {
                what: "residual".into(),
                expected: config.residual_features().to_string(),
                got: r.len().to_string(),
            });
        }
        stats.residual.push(&r, clip, &mut core_in);
        stats.gradient.push(g, clip, &mut core_in);
        stats.pose.push(p, clip, &mut core_in);
        core_in.extend_from_slice(d);
    }
    Ok(core_in)
}

/// The normalised λ/γ inputs `[R(θ), R(θ + Δθ)]` (papers/002 eq. 2: where the network alone
/// would go; both as residual features), `[B, step_inputs]` row-major.
pub fn step_rows(
    config: &NetConfig,
    stats: &FeatureStats,
    energies: &[&Energy],
    current: &[Vec<f64>],
    evals: &[(Vec<f64>, Vec<f64>)],
    delta: &[Vec<f64>],
) -> Result<Vec<f32>> {
    let clip = config.feature_clip as f32;
    let tried: Vec<Vec<f64>> = energies
        .par_iter()
        .zip(current.par_iter().zip(delta.par_iter()))
        .map(|(e, (p, d))| {
            let mut q = p.clone();
            for (a, b) in q.iter_mut().zip(d) {
                *a += b;
            }
            e.residual(&q)
        })
        .collect();
    let mut step_in = Vec::with_capacity(energies.len() * config.step_inputs());
    for (((r, _), r2), e) in evals.iter().zip(&tried).zip(energies) {
        for r in [r, r2] {
            let f = residual_features(config, e, r)?;
            if f.len() != config.residual_features() {
                return Err(ModelError::Shape {
                    what: "residual".into(),
                    expected: config.residual_features().to_string(),
                    got: f.len().to_string(),
                });
            }
            stats.residual.push(&f, clip, &mut step_in);
        }
    }
    Ok(step_in)
}

/// Parameter vectors of `[B, dim]` f32 rows.
pub fn rows_to_poses(rows: &[f32], dim: usize) -> Vec<Vec<f64>> {
    rows.chunks_exact(dim.max(1))
        .map(|r| r.iter().map(|&x| f64::from(x)).collect())
        .collect()
}

/// Φ(D) of every frame (the initializer alone, no iteration): the candidate start that
/// [`unroll`] takes where a frame gives none. Inference uses it to choose between a given start
/// and Φ(D) by energy before unrolling.
pub fn initial_poses(
    net: &NeuralNet,
    stats: &FeatureStats,
    energies: &[&Energy],
    device: &Device,
) -> Result<Vec<Vec<f64>>> {
    let c = &net.config;
    let none: Vec<Option<Vec<f64>>> = vec![None; energies.len()];
    check_batch(c, energies, &none)?;
    let obs_norm = observation_rows(c, stats, energies)?;
    let obs = rows_tensor(&obs_norm.concat(), energies.len(), device);
    let (phi, _) = net.initial(obs);
    to_host(&phi, c.param_dim)
}

/// Runs N iterations on `energies` (one frame each). `starts[i]` is the given θ0 of frame `i`
/// (`None`: θ0 = Φ(D)). `constraints` freezes DOFs and clamps every iterate into bounds.
pub fn unroll(
    net: &NeuralNet,
    stats: &FeatureStats,
    energies: &[&Energy],
    starts: &[Option<Vec<f64>>],
    constraints: Option<&Constraints>,
    device: &Device,
    dropout: &mut Dropout<'_>,
) -> Result<Unrolled> {
    let n = net.config.iterations;
    unroll_for(
        net,
        stats,
        energies,
        starts,
        constraints,
        device,
        dropout,
        Exit::after(n),
    )
}

/// [`unroll`] stopped by `exit`: after its first `exit.iterations` iterations (1 to the N the
/// network was built for; `lfit fit --neural-iterations`) or, with a tolerance, once an
/// iteration lowers the energy by less than that fraction (`--neural-tolerance`). Each iterate is
/// the one the full unroll computes (the same weights, inputs and state up to it).
#[allow(clippy::too_many_arguments)]
pub fn unroll_for(
    net: &NeuralNet,
    stats: &FeatureStats,
    energies: &[&Energy],
    starts: &[Option<Vec<f64>>],
    constraints: Option<&Constraints>,
    device: &Device,
    dropout: &mut Dropout<'_>,
    exit: Exit,
) -> Result<Unrolled> {
    let c = &net.config;
    exit.check(c)?;
    check_batch(c, energies, starts)?;
    let batch = energies.len();

    // Observation features D, normalised once per frame.
    let obs_norm = observation_rows(c, stats, energies)?;
    let obs = rows_tensor(&obs_norm.concat(), batch, device);

    let (phi, mut state) = net.initial(obs);
    let dim = c.param_dim;
    let given: Vec<Vec<f64>> = starts
        .iter()
        .map(|s| s.clone().unwrap_or_else(|| vec![0.0; dim]))
        .collect();
    let use_given: Vec<f32> = starts
        .iter()
        .map(|s| if s.is_some() { 1.0 } else { 0.0 })
        .collect();
    let mut theta = if use_given.iter().all(|&g| g == 1.0) {
        poses_to_tensor(&given, device)
    } else if use_given.iter().all(|&g| g == 0.0) {
        phi
    } else {
        let m = rows_tensor(&use_given, batch, device);
        poses_to_tensor(&given, device) * m.clone() + phi * m.neg().add_scalar(1.0)
    };

    let (free, lower, upper) = match constraints {
        Some(k) => {
            let (f, lo, hi) = constraint_rows(k, batch, dim)?;
            (
                Some(rows_tensor(&f, batch, device)),
                Some(rows_tensor(&lo, batch, device)),
                Some(rows_tensor(&hi, batch, device)),
            )
        }
        None => (None, None, None),
    };
    let constrain = |t: Tensor<2>| match (&lower, &upper) {
        (Some(lo), Some(hi)) => t.max_pair(lo.clone()).min_pair(hi.clone()),
        _ => t,
    };
    theta = constrain(theta);

    let mut host = vec![to_host(&theta, dim)?];
    let mut poses = vec![theta.clone()];
    let mut running = Running::new(batch);
    for n in 0..exit.iterations {
        let current = host.last().cloned().unwrap_or_default();
        // R(θ) and g(θ) on the CPU (detached inputs), and E(θ) for the energy rule.
        let free_rows = constraints.map(|k| k.free.as_slice());
        if !running.evaluate(c, &exit, n, energies, &current, free_rows)? {
            break;
        }
        if let Some((keep, _)) = running.shrink() {
            state = state.select(&index_tensor(&keep, device));
        }
        let alive = &running.alive;
        let rows = alive.len();
        let picked = running.picked(energies, &current, &obs_norm);
        let (e, evals, cur, obs) = (
            &picked.energies[..],
            &picked.evals[..],
            &picked.current[..],
            &picked.obs[..],
        );
        // The running frames' rows of the batch (None: all of them).
        let index = (rows < batch).then(|| index_tensor(alive, device));
        let core_in = core_rows(c, stats, e, evals, cur, obs)?;
        let mut delta = net.propose(n, rows_tensor(&core_in, rows, device), &mut state, dropout);
        let mut grad = poses_to_tensor(
            &evals.iter().map(|(_, g)| g.as_slice()).collect::<Vec<_>>(),
            device,
        );
        if let Some(f) = &free {
            let f = match &index {
                Some(i) => f.clone().select(0, i.clone()),
                None => f.clone(),
            };
            delta = delta * f.clone();
            grad = grad * f;
        }

        let sizes = if c.has_step_network() {
            let step_in = step_rows(c, stats, e, cur, evals, &to_host(&delta, dim)?)?;
            net.step_sizes(n, rows_tensor(&step_in, rows, device), &mut state, dropout)
        } else {
            net.step_sizes(n, Tensor::zeros([rows, 1], device), &mut state, dropout)
        };
        let mut step = net.update(delta, grad, &sizes);
        // A stopped frame's θ is held: the running rows' steps into a batch of zeros.
        if let Some(i) = index {
            step = Tensor::zeros([batch, dim], device).select_assign(
                0,
                i,
                step,
                burn::tensor::IndexingUpdateOp::Add,
            );
        }
        theta = constrain(theta + step);
        host.push(to_host(&theta, dim)?);
        poses.push(theta.clone());
    }
    Ok(Unrolled {
        poses,
        host,
        iterations: running.iterations,
    })
}

/// Recurrent state of a batch on the host, `[B, H]` rows per GRU layer: of `f`, of fλ(γ) (with
/// a λ/γ network) and of a separate fγ.
#[derive(Debug, Clone, Default)]
pub struct RowState {
    pub core: Vec<Vec<f32>>,
    pub lambda: Vec<Vec<f32>>,
    pub gamma: Vec<Vec<f32>>,
    /// Per weight set, what a runtime keeps of the rows' observation features for the whole
    /// loop: the native forward's `b + D W_D` of the core's first layer (`[B, 3H]` for a GRU
    /// core, `[B, H]` for a residual MLP; computed in `initial`); empty where a runtime keeps
    /// nothing (ONNX Runtime).
    pub constant: Vec<Vec<f32>>,
}

impl RowState {
    /// The state of the rows `keep` (positions in this state's batch of `batch` rows, in
    /// order), every layer's rows copied as they are.
    pub fn select(&self, keep: &[usize], batch: usize) -> Self {
        let rows = |layers: &[Vec<f32>]| -> Vec<Vec<f32>> {
            layers
                .iter()
                .map(|v| {
                    let width = v.len() / batch.max(1);
                    keep.iter()
                        .flat_map(|&r| v[r * width..(r + 1) * width].iter().copied())
                        .collect()
                })
                .collect()
        };
        Self {
            core: rows(&self.core),
            lambda: rows(&self.lambda),
            gamma: rows(&self.gamma),
            constant: rows(&self.constant),
        }
    }

    /// `core` (Φh(D)) and zeros for the λ/γ cores, as [`NeuralNet::initial`].
    pub fn zeros(config: &NetConfig, batch: usize, core: Vec<Vec<f32>>) -> Self {
        let zeros = |on: bool| {
            if on {
                (0..config.recurrent_layers())
                    .map(|_| vec![0.0f32; batch * config.hidden])
                    .collect()
            } else {
                Vec::new()
            }
        };
        Self {
            core,
            lambda: zeros(config.has_step_network()),
            gamma: zeros(config.separate_gamma_network()),
            constant: Vec::new(),
        }
    }
}

/// What the λ/γ part of one iteration gives: the update (θn − θ(n−1) before clamping), λ and γ,
/// `[B, dim]`, `[B, k]`, `[B, kg]` row-major.
#[derive(Debug, Clone)]
pub struct StepOut {
    pub update: Vec<f32>,
    pub lambda: Vec<f32>,
    pub gamma: Vec<f32>,
}

/// A network executed on host rows (`f32`, `[B, width]` row-major): ONNX Runtime sessions or
/// [`crate::host::HostNet`]. [`unroll_rows`] runs papers/002 Alg. 1 with it, with the energy side
/// of [`unroll`].
pub trait RowNetwork {
    type Error: From<ModelError>;
    fn config(&self) -> &NetConfig;
    fn stats(&self) -> &FeatureStats;
    /// θ0 = Φ(D) `[B, param_dim]` and the initial state, from normalised observations.
    fn initial(
        &mut self,
        obs: &[f32],
        batch: usize,
    ) -> std::result::Result<(Vec<f32>, RowState), Self::Error>;
    /// Δθ of iteration `n` (0-based) from the normalised core inputs; updates the core state.
    fn propose(
        &mut self,
        n: usize,
        core_in: &[f32],
        batch: usize,
        state: &mut RowState,
    ) -> std::result::Result<Vec<f32>, Self::Error>;
    /// λ, γ and the update of iteration `n`; updates the λ/γ states. `delta` and `grad` are
    /// already masked; `grad` is the raw direction.
    #[allow(clippy::too_many_arguments)]
    fn step(
        &mut self,
        n: usize,
        step_in: &[f32],
        delta: &[f32],
        grad: &[f32],
        batch: usize,
        state: &mut RowState,
    ) -> std::result::Result<StepOut, Self::Error>;
}

/// Φ(D) of every frame through a host network, as [`initial_poses`] does through Burn.
pub fn initial_poses_rows<N: RowNetwork>(
    net: &mut N,
    energies: &[&Energy],
) -> std::result::Result<Vec<Vec<f64>>, N::Error> {
    let c = net.config().clone();
    let none: Vec<Option<Vec<f64>>> = vec![None; energies.len()];
    check_batch(&c, energies, &none)?;
    let obs_norm = observation_rows(&c, net.stats(), energies)?;
    let (phi, _) = net.initial(&obs_norm.concat(), energies.len())?;
    Ok(rows_to_poses(&phi, c.param_dim))
}

/// Runs N iterations through a host network on `energies`, exactly as [`unroll`] does through
/// Burn (θ in `f32` as there); returns θ0 … θN per frame (`[N + 1][B]`).
pub fn unroll_rows<N: RowNetwork>(
    net: &mut N,
    energies: &[&Energy],
    starts: &[Option<Vec<f64>>],
    constraints: Option<&Constraints>,
) -> std::result::Result<Vec<Vec<Vec<f64>>>, N::Error> {
    let n = net.config().iterations;
    Ok(unroll_rows_for(net, energies, starts, constraints, Exit::after(n))?.0)
}

/// [`unroll_rows`] stopped by `exit`, as [`unroll_for`]; also the iterations each frame ran
/// ([`Unrolled::iterations`]).
#[allow(clippy::type_complexity)]
pub fn unroll_rows_for<N: RowNetwork>(
    net: &mut N,
    energies: &[&Energy],
    starts: &[Option<Vec<f64>>],
    constraints: Option<&Constraints>,
    exit: Exit,
) -> std::result::Result<(Vec<Vec<Vec<f64>>>, Vec<usize>), N::Error> {
    let c = net.config().clone();
    exit.check(&c)?;
    check_batch(&c, energies, starts)?;
    let batch = energies.len();
    let obs_norm = observation_rows(&c, net.stats(), energies)?;
    let (phi, mut state) = net.initial(&obs_norm.concat(), batch)?;
    // θ0: the given pose where there is one, Φ(D) elsewhere (in f32, as the Burn loop).
    let dim = c.param_dim;
    let mut theta: Vec<f32> = Vec::with_capacity(batch * dim);
    for (i, s) in starts.iter().enumerate() {
        match s {
            Some(p) => theta.extend(p.iter().map(|&v| v as f32)),
            None => theta.extend_from_slice(&phi[i * dim..(i + 1) * dim]),
        }
    }
    let limits = constraints
        .map(|k| constraint_rows(k, batch, dim))
        .transpose()?;
    let constrain = |t: &mut [f32]| {
        if let Some((_, lo, hi)) = &limits {
            for ((v, l), h) in t.iter_mut().zip(lo).zip(hi) {
                *v = v.max(*l).min(*h);
            }
        }
    };
    constrain(&mut theta);
    let mut host = vec![rows_to_poses(&theta, dim)];
    let mut running = Running::new(batch);
    for n in 0..exit.iterations {
        let current = host.last().cloned().unwrap_or_default();
        let free_rows = constraints.map(|k| k.free.as_slice());
        if !running.evaluate(&c, &exit, n, energies, &current, free_rows)? {
            break;
        }
        // The native forward computes every row alone, so its results do not depend on which
        // rows share a pass.
        if let Some((keep, before)) = running.shrink() {
            state = state.select(&keep, before);
        }
        let alive = &running.alive;
        let (rows, pick) = (alive.len(), |r: usize| alive[r]);
        let picked = running.picked(energies, &current, &obs_norm);
        let (e, evals, cur, obs) = (
            &picked.energies[..],
            &picked.evals[..],
            &picked.current[..],
            &picked.obs[..],
        );
        let core_in = core_rows(&c, net.stats(), e, evals, cur, obs)?;
        let mut delta = net.propose(n, &core_in, rows, &mut state)?;
        let mut grad: Vec<f32> = evals
            .iter()
            .flat_map(|(_, g)| g.iter().map(|&v| v as f32))
            .collect();
        if let Some((free, _, _)) = &limits {
            for (r, (d, g)) in delta.chunks_mut(dim).zip(grad.chunks_mut(dim)).enumerate() {
                let f = &free[pick(r) * dim..(pick(r) + 1) * dim];
                for ((d, g), f) in d.iter_mut().zip(g.iter_mut()).zip(f) {
                    *d *= f;
                    *g *= f;
                }
            }
        }
        let update = if c.has_step_network() {
            let step_in = step_rows(&c, net.stats(), e, cur, evals, &rows_to_poses(&delta, dim))?;
            net.step(n, &step_in, &delta, &grad, rows, &mut state)?
                .update
        } else {
            delta
        };
        for (r, u) in update.chunks(dim).enumerate() {
            let i = pick(r);
            for (t, u) in theta[i * dim..(i + 1) * dim].iter_mut().zip(u) {
                *t += u;
            }
        }
        constrain(&mut theta);
        host.push(rows_to_poses(&theta, dim));
    }
    Ok((host, running.iterations))
}

impl<T: RowNetwork + ?Sized> RowNetwork for &mut T {
    type Error = T::Error;
    fn config(&self) -> &NetConfig {
        (**self).config()
    }
    fn stats(&self) -> &FeatureStats {
        (**self).stats()
    }
    fn initial(
        &mut self,
        obs: &[f32],
        batch: usize,
    ) -> std::result::Result<(Vec<f32>, RowState), Self::Error> {
        (**self).initial(obs, batch)
    }
    fn propose(
        &mut self,
        n: usize,
        core_in: &[f32],
        batch: usize,
        state: &mut RowState,
    ) -> std::result::Result<Vec<f32>, Self::Error> {
        (**self).propose(n, core_in, batch, state)
    }
    fn step(
        &mut self,
        n: usize,
        step_in: &[f32],
        delta: &[f32],
        grad: &[f32],
        batch: usize,
        state: &mut RowState,
    ) -> std::result::Result<StepOut, Self::Error> {
        (**self).step(n, step_in, delta, grad, batch, state)
    }
}
