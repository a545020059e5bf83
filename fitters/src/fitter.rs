//! The `Fitter` abstraction (SPEC §6): (energy, start pose, budget) → result, and the strategies
//! that split one fit into stages over groups of DOFs.

use std::fmt;
use std::str::FromStr;
use std::time::Instant;

use lfit_model::energy::Energy;
use lfit_model::pose::{Bounds, DofMask, POSE_DIM, Pose, rot_offset};
use lfit_model::skeleton::{
    HEAD, L_ANKLE, L_ELBOW, L_FOOT, L_HAND, L_HIP, L_KNEE, L_SHOULDER, LOWER_TORSO, MIDDLE_TORSO, R_ANKLE, R_ELBOW, R_FOOT,
    R_HAND, R_HIP, R_KNEE, R_SHOULDER, ROOT,
};
use serde::Serialize;

use crate::error::FitError;

/// Initial mutation step of the root translation, metres (papers/000 §4.1: "0.1 meters").
pub const TRANSLATION_STEP: f64 = 0.1;
/// Initial mutation step of every rotation, degrees (papers/000 §4.1: "3° angle").
pub const ROTATION_STEP_DEG: f64 = 3.0;

/// What one fit is asked to do.
#[derive(Debug, Clone)]
pub struct FitRequest<'a> {
    pub energy: &'a Energy,
    pub start: Pose,
    /// Free DOFs; the others keep their start values.
    pub mask: DofMask,
    /// Box on every pose entry; the start is clamped into it.
    pub bounds: Bounds,
    /// Most energy evaluations (exact for the zeroth-order methods).
    pub budget: usize,
    pub seed: u64,
}

/// What a fit returns (SPEC §6).
#[derive(Debug, Clone, Serialize)]
pub struct FitResult {
    pub method: String,
    pub pose: Vec<f64>,
    pub energy: f64,
    pub terms: Vec<(&'static str, f64)>,
    pub evaluations: u64,
    pub gradient_evaluations: u64,
    pub iterations: u64,
    pub time_s: f64,
    /// `(evaluations so far, best energy)` whenever the best improves.
    pub trace: Vec<(u64, f64)>,
    /// Iterative fitters that have iterates (the neural fitter): the pose after every
    /// iteration, θ0 first; empty otherwise.
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub iterates: Vec<Vec<f64>>,
}

/// A fitting method.
pub trait Fitter: Send + Sync {
    fn name(&self) -> String;
    fn fit(&self, request: &FitRequest<'_>) -> Result<FitResult, FitError>;
}

/// How a fit is split into stages (SPEC §6).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum Strategy {
    /// All free DOFs at once.
    #[default]
    Holistic,
    /// papers/000 Algorithm 1: torso + root (3/11 of the budget), then left leg, right leg, left
    /// arm, right arm (2/11 each).
    Grouped,
    /// papers/001 §3.3: root (translation and rotation), torso and head, then the four limbs;
    /// the budget is split in proportion to each step's free DOFs (papers/001 does not state its
    /// split).
    Hierarchical,
}

impl Strategy {
    pub const ALL: [Strategy; 3] = [Strategy::Holistic, Strategy::Grouped, Strategy::Hierarchical];

    pub fn name(self) -> &'static str {
        match self {
            Strategy::Holistic => "holistic",
            Strategy::Grouped => "grouped",
            Strategy::Hierarchical => "hierarchical",
        }
    }

    /// The stages as (pose entries, budget weight). Entries not free in `mask` are dropped, and so
    /// are stages left empty.
    pub fn stages(self, mask: &DofMask) -> Vec<(Vec<usize>, f64)> {
        let joints = |js: &[usize], translation: bool| -> Vec<usize> {
            let mut out: Vec<usize> = if translation { vec![0, 1, 2] } else { Vec::new() };
            for &j in js {
                out.extend(rot_offset(j)..rot_offset(j) + 3);
            }
            out.retain(|i| mask.free.contains(i));
            out.sort_unstable();
            out
        };
        let left_leg = [L_HIP, L_KNEE, L_ANKLE, L_FOOT];
        let right_leg = [R_HIP, R_KNEE, R_ANKLE, R_FOOT];
        let left_arm = [L_SHOULDER, L_ELBOW, L_HAND];
        let right_arm = [R_SHOULDER, R_ELBOW, R_HAND];
        let stages: Vec<(Vec<usize>, f64)> = match self {
            Strategy::Holistic => vec![(mask.free.clone(), 1.0)],
            Strategy::Grouped => vec![
                (joints(&[ROOT, LOWER_TORSO, MIDDLE_TORSO, HEAD], true), 3.0),
                (joints(&left_leg, false), 2.0),
                (joints(&right_leg, false), 2.0),
                (joints(&left_arm, false), 2.0),
                (joints(&right_arm, false), 2.0),
            ],
            Strategy::Hierarchical => {
                let steps = [
                    joints(&[ROOT], true),
                    joints(&[LOWER_TORSO, MIDDLE_TORSO, HEAD], false),
                    joints(&left_arm, false),
                    joints(&right_arm, false),
                    joints(&left_leg, false),
                    joints(&right_leg, false),
                ];
                steps.into_iter().map(|s| {
                    let w = s.len() as f64;
                    (s, w)
                }).collect()
            }
        };
        stages.into_iter().filter(|(s, _)| !s.is_empty()).collect()
    }
}

impl fmt::Display for Strategy {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

impl FromStr for Strategy {
    type Err = FitError;
    fn from_str(s: &str) -> Result<Self, FitError> {
        Strategy::ALL.into_iter().find(|k| k.name() == s).ok_or_else(|| FitError::UnknownStrategy(s.to_string()))
    }
}

/// Splits `budget` over `weights` exactly: floors of the proportional shares, the remainder one by
/// one to the first stages.
pub fn split_budget(budget: usize, weights: &[f64]) -> Vec<usize> {
    let total: f64 = weights.iter().sum();
    if weights.is_empty() || total <= 0.0 {
        return vec![0; weights.len()];
    }
    let mut out: Vec<usize> = weights.iter().map(|w| (budget as f64 * w / total).floor() as usize).collect();
    let mut rest = budget - out.iter().sum::<usize>().min(budget);
    let n = out.len();
    let mut i = 0;
    while rest > 0 {
        out[i % n] += 1;
        rest -= 1;
        i += 1;
    }
    out
}

/// The per-entry initial step (papers/000 §4.1) of pose entries `dofs`.
pub fn steps(dofs: &[usize]) -> Vec<f64> {
    dofs.iter().map(|&i| if i < 3 { TRANSLATION_STEP } else { ROTATION_STEP_DEG.to_radians() }).collect()
}

/// Checks a request: budget ≥ 1, bounds of the right shape with lower ≤ upper, finite start.
pub fn check_request(request: &FitRequest<'_>) -> Result<Pose, FitError> {
    if request.budget == 0 {
        return Err(FitError::Budget(0));
    }
    let b = &request.bounds;
    if b.lower.len() != POSE_DIM || b.upper.len() != POSE_DIM {
        return Err(FitError::Bounds(format!("bounds have {}/{} entries, expected {POSE_DIM}", b.lower.len(), b.upper.len())));
    }
    if let Some(i) = (0..POSE_DIM).find(|&i| !(b.lower[i] <= b.upper[i]) || !b.lower[i].is_finite() || !b.upper[i].is_finite()) {
        return Err(FitError::Bounds(format!("entry {i}: [{}, {}]", b.lower[i], b.upper[i])));
    }
    if let Some(i) = request.start.iter().position(|v| !v.is_finite()) {
        return Err(FitError::Start(format!("start pose entry {i} is not finite")));
    }
    let mut start = request.start;
    b.clamp(&mut start);
    Ok(start)
}

/// One stage: optimise `dofs` of `pose` (in place) within `bounds` using at most `budget`
/// evaluations of `energy`; returns the trace in evaluations relative to the stage start.
pub(crate) trait StageSolver: Sync {
    fn solve(&self, energy: &Energy, pose: &mut Pose, dofs: &[usize], bounds: &Bounds, budget: usize, seed: u64) -> Result<StageOutcome, FitError>;
}

pub(crate) struct StageOutcome {
    pub best: f64,
    pub trace: Vec<(u64, f64)>,
    pub iterations: u64,
}

/// Runs the strategy's stages with one stage solver and assembles the result.
pub(crate) fn run_staged(name: String, solver: &dyn StageSolver, strategy: Strategy, request: &FitRequest<'_>) -> Result<FitResult, FitError> {
    let mut pose = check_request(request)?;
    let energy = request.energy;
    let (e0, g0) = (energy.evaluations(), energy.gradient_evaluations());
    let timer = Instant::now();
    let stages = strategy.stages(&request.mask);
    let weights: Vec<f64> = stages.iter().map(|(_, w)| *w).collect();
    // The start is evaluation 1, so a fit is never worse than its start; the stages share the rest.
    let mut best = energy.evaluate(&pose).total;
    let mut trace: Vec<(u64, f64)> = vec![(1, best)];
    let budgets = split_budget(request.budget - 1, &weights);
    let mut iterations = 0;
    for (k, ((dofs, _), budget)) in stages.iter().zip(budgets).enumerate() {
        if budget == 0 {
            continue;
        }
        let offset = energy.evaluations() - e0;
        // Stage seeds differ but follow from the request's seed.
        let seed = request.seed.wrapping_mul(0x9E37_79B9_7F4A_7C15).wrapping_add(k as u64);
        let before = pose;
        let out = solver.solve(energy, &mut pose, dofs, &request.bounds, budget, seed)?;
        iterations += out.iterations;
        if out.best < best {
            for (n, v) in out.trace {
                // Later stages start from the earlier stages' pose, so their bests are comparable.
                if v < best {
                    best = v;
                    trace.push((offset + n, v));
                }
            }
            best = best.min(out.best);
        } else {
            pose = before;
        }
    }
    let time_s = timer.elapsed().as_secs_f64();
    let report = energy.inspect(&pose);
    Ok(FitResult {
        method: name,
        pose: pose.to_vec(),
        energy: report.total,
        terms: report.terms,
        evaluations: energy.evaluations() - e0,
        gradient_evaluations: energy.gradient_evaluations() - g0,
        iterations,
        time_s,
        trace,
        iterates: Vec::new(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn budgets_split_exactly_as_papers_000_algorithm_1() {
        let b = split_budget(2200, &[3.0, 2.0, 2.0, 2.0, 2.0]);
        assert_eq!(b, vec![600, 400, 400, 400, 400]);
        for budget in [1, 7, 2000, 4000, 7000] {
            assert_eq!(split_budget(budget, &[3.0, 2.0, 2.0, 2.0, 2.0]).iter().sum::<usize>(), budget);
        }
    }

    #[test]
    fn strategies_cover_every_free_dof_once() {
        for mask in [DofMask::full57(), DofMask::local43(), DofMask::global41()] {
            for s in Strategy::ALL {
                let mut all: Vec<usize> = s.stages(&mask).into_iter().flat_map(|(d, _)| d).collect();
                all.sort_unstable();
                assert_eq!(all, mask.free, "{s} on {}", mask.name);
            }
        }
        assert_eq!(Strategy::Grouped.stages(&DofMask::local43()).len(), 5);
        assert_eq!(Strategy::Hierarchical.stages(&DofMask::local43()).len(), 6);
    }
}
