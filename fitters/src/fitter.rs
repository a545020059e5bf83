//! The `Fitter` abstraction (SPEC §6): (energy, start pose, budget) → result, and the strategies
//! that split one fit into stages over groups of DOFs.

use std::fmt;
use std::str::FromStr;
use std::time::Instant;

use lfit_model::energy::Energy;
use lfit_model::layout::{Block, Layout};
use lfit_model::pose::{Bounds, DofMask, rot_offset};
use lfit_model::template::Template;
use serde::Serialize;

use crate::error::FitError;

/// Initial mutation step of the root translation, metres (papers/000 §4.1: "0.1 meters").
pub const TRANSLATION_STEP: f64 = 0.1;
/// Initial mutation step of every rotation, degrees (papers/000 §4.1: "3° angle").
pub const ROTATION_STEP_DEG: f64 = 3.0;
/// Initial mutation step of shape and expression coefficients, standard deviations (ours: a
/// tenth of the ±3 box, as 3° is of a typical joint range).
pub const SHAPE_STEP: f64 = 0.3;

/// What one fit is asked to do.
#[derive(Debug, Clone)]
pub struct FitRequest<'a> {
    pub energy: &'a Energy,
    /// Start parameters in the energy's layout (`Energy::dim` entries).
    pub start: Vec<f64>,
    /// Free DOFs; the others keep their start values.
    pub mask: DofMask,
    /// Box on every pose entry; the start is clamped into it.
    pub bounds: Bounds,
    /// Most energy evaluations (exact for the zeroth-order methods).
    pub budget: usize,
    pub seed: u64,
    /// In a sequence whose frame starts from the previous frame's fit: how fast the fits before
    /// it moved, per entry (the root-mean-square change per frame, an exponential average:
    /// [`crate::observed::SequenceMotion`]; zeros at the chain's second frame, before any
    /// change); `None` for a frame fitted on its own or the first of a chain. The temporal
    /// anchor ([`crate::AnchoredDofs`]) widens its pull by it and, given no translation σ, takes
    /// the sequence's ([`crate::anchor_translation_std_mm`]); every other fitter ignores it.
    pub motion: Option<Vec<f64>>,
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

    /// Fits independent frames, results in request order. One at a time by default; a fitter
    /// that gains from batches (the neural fitter: one network pass for all) overrides it.
    fn fit_batch(&self, requests: &[FitRequest<'_>]) -> Result<Vec<FitResult>, FitError> {
        requests.iter().map(|r| self.fit(r)).collect()
    }
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
    /// For morphable models: first the translation with the shape and expression coefficients
    /// (the pose held at its start), then every free entry (1/3 and 2/3 of the budget). Holistic
    /// on a model without coefficients.
    ShapeFirst,
}

impl Strategy {
    pub const ALL: [Strategy; 3] = [
        Strategy::Holistic,
        Strategy::Grouped,
        Strategy::Hierarchical,
    ];

    pub fn name(self) -> &'static str {
        match self {
            Strategy::Holistic => "holistic",
            Strategy::Grouped => "grouped",
            Strategy::Hierarchical => "hierarchical",
            Strategy::ShapeFirst => "shape-first",
        }
    }

    /// The stages as (parameter entries, budget weight), on the joints' part labels
    /// ([`lfit_model::info::ModelInfo::parts`]): grouped = `torso` (with the root translation,
    /// and the shape and expression coefficients), then `left_leg`, `right_leg`, `left_arm`,
    /// `right_arm`; hierarchical = the root joint with the translation (and shape/expression),
    /// the rest of `torso`, then the arms and the legs. Entries not free in `mask` are dropped,
    /// and so are stages left empty. Joints with other labels join the torso stage.
    pub fn stages(self, mask: &DofMask, template: &Template) -> Vec<(Vec<usize>, f64)> {
        let layout = template.layout();
        let parts = &template.info.parts;
        let coefficients: Vec<usize> = layout
            .range(Block::Shape)
            .chain(layout.range(Block::Expression))
            .collect();
        let entries = |joints: &[usize], with_root_entries: bool| -> Vec<usize> {
            let mut out: Vec<usize> = if with_root_entries {
                [0, 1, 2]
                    .into_iter()
                    .chain(coefficients.iter().copied())
                    .collect()
            } else {
                Vec::new()
            };
            for &j in joints {
                out.extend(rot_offset(j)..rot_offset(j) + 3);
            }
            out.retain(|i| mask.free.contains(i));
            out.sort_unstable();
            out
        };
        let with_part = |name: &str| -> Vec<usize> {
            (0..layout.num_joints())
                .filter(|&j| parts[j] == name)
                .collect()
        };
        let limbs = ["left_leg", "right_leg", "left_arm", "right_arm"];
        let torso: Vec<usize> = (0..layout.num_joints())
            .filter(|&j| !limbs.contains(&parts[j].as_str()))
            .collect();
        let stages: Vec<(Vec<usize>, f64)> = match self {
            Strategy::Holistic => vec![(mask.free.clone(), 1.0)],
            Strategy::Grouped => vec![
                (entries(&torso, true), 3.0),
                (entries(&with_part("left_leg"), false), 2.0),
                (entries(&with_part("right_leg"), false), 2.0),
                (entries(&with_part("left_arm"), false), 2.0),
                (entries(&with_part("right_arm"), false), 2.0),
            ],
            Strategy::ShapeFirst => {
                let mut first: Vec<usize> = [0, 1, 2]
                    .into_iter()
                    .chain(coefficients.iter().copied())
                    .filter(|i| mask.free.contains(i))
                    .collect();
                first.sort_unstable();
                if coefficients.is_empty() {
                    vec![(mask.free.clone(), 1.0)]
                } else {
                    vec![(first, 1.0), (mask.free.clone(), 2.0)]
                }
            }
            Strategy::Hierarchical => {
                let rest_of_torso: Vec<usize> = torso.iter().copied().filter(|&j| j != 0).collect();
                let steps = [
                    entries(&[0], true),
                    entries(&rest_of_torso, false),
                    entries(&with_part("left_arm"), false),
                    entries(&with_part("right_arm"), false),
                    entries(&with_part("left_leg"), false),
                    entries(&with_part("right_leg"), false),
                ];
                steps
                    .into_iter()
                    .map(|s| {
                        let w = s.len() as f64;
                        (s, w)
                    })
                    .collect()
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
        Strategy::ALL
            .into_iter()
            .chain([Strategy::ShapeFirst])
            .find(|k| k.name() == s)
            .ok_or_else(|| FitError::UnknownStrategy(s.to_string()))
    }
}

/// Splits `budget` over `weights` exactly: floors of the proportional shares, the remainder one by
/// one to the first stages.
pub fn split_budget(budget: usize, weights: &[f64]) -> Vec<usize> {
    let total: f64 = weights.iter().sum();
    if weights.is_empty() || total <= 0.0 {
        return vec![0; weights.len()];
    }
    let mut out: Vec<usize> = weights
        .iter()
        .map(|w| (budget as f64 * w / total).floor() as usize)
        .collect();
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

/// The per-entry initial step (papers/000 §4.1) of parameter entries `dofs`: translation,
/// rotations, and [`SHAPE_STEP`] for shape and expression.
pub fn steps(dofs: &[usize], layout: &Layout) -> Vec<f64> {
    dofs.iter()
        .map(|&i| match layout.block_of(i) {
            Some(Block::Translation) => TRANSLATION_STEP,
            Some(Block::Shape | Block::Expression) => SHAPE_STEP,
            _ => ROTATION_STEP_DEG.to_radians(),
        })
        .collect()
}

/// Checks a request: budget ≥ 1, a start and bounds of the energy's length with lower ≤ upper,
/// finite start, mask inside it.
pub fn check_request(request: &FitRequest<'_>) -> Result<Vec<f64>, FitError> {
    if request.budget == 0 {
        return Err(FitError::Budget(0));
    }
    let dim = request.energy.dim();
    if request.start.len() != dim {
        return Err(FitError::Start(format!(
            "start has {} entries, the model's parameter vector {dim}",
            request.start.len()
        )));
    }
    let b = &request.bounds;
    if b.lower.len() != dim || b.upper.len() != dim {
        return Err(FitError::Bounds(format!(
            "bounds have {}/{} entries, expected {dim}",
            b.lower.len(),
            b.upper.len()
        )));
    }
    if let Some(i) = (0..dim).find(|&i| {
        !(b.lower[i] <= b.upper[i]) || !b.lower[i].is_finite() || !b.upper[i].is_finite()
    }) {
        return Err(FitError::Bounds(format!(
            "entry {i}: [{}, {}]",
            b.lower[i], b.upper[i]
        )));
    }
    if let Some(&i) = request.mask.free.iter().find(|&&i| i >= dim) {
        return Err(FitError::Start(format!(
            "mask '{}' frees entry {i}, beyond the model's {dim}",
            request.mask.name
        )));
    }
    if let Some(i) = request.start.iter().position(|v| !v.is_finite()) {
        return Err(FitError::Start(format!(
            "start pose entry {i} is not finite"
        )));
    }
    let mut start = request.start.clone();
    b.clamp(&mut start);
    Ok(start)
}

/// One stage: optimise `dofs` of `pose` (in place) within `bounds` using at most `budget`
/// evaluations of `energy`; returns the trace in evaluations relative to the stage start.
pub(crate) trait StageSolver: Sync {
    fn solve(
        &self,
        energy: &Energy,
        pose: &mut [f64],
        dofs: &[usize],
        bounds: &Bounds,
        budget: usize,
        seed: u64,
    ) -> Result<StageOutcome, FitError>;
}

pub(crate) struct StageOutcome {
    pub best: f64,
    pub trace: Vec<(u64, f64)>,
    pub iterations: u64,
}

/// Runs the strategy's stages with one stage solver and assembles the result.
pub(crate) fn run_staged(
    name: String,
    solver: &dyn StageSolver,
    strategy: Strategy,
    request: &FitRequest<'_>,
) -> Result<FitResult, FitError> {
    let mut pose = check_request(request)?;
    let energy = request.energy;
    let (e0, g0) = (energy.evaluations(), energy.gradient_evaluations());
    let timer = Instant::now();
    let stages = strategy.stages(&request.mask, energy.template());
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
        let seed = request
            .seed
            .wrapping_mul(0x9E37_79B9_7F4A_7C15)
            .wrapping_add(k as u64);
        let before = pose.clone();
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
        pose,
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
            assert_eq!(
                split_budget(budget, &[3.0, 2.0, 2.0, 2.0, 2.0])
                    .iter()
                    .sum::<usize>(),
                budget
            );
        }
    }

    #[test]
    fn strategies_cover_every_free_dof_once() {
        let t = lfit_model::default_template();
        for mask in [DofMask::full57(), DofMask::local43(), DofMask::global41()] {
            for s in Strategy::ALL {
                let mut all: Vec<usize> = s
                    .stages(&mask, &t)
                    .into_iter()
                    .flat_map(|(d, _)| d)
                    .collect();
                all.sort_unstable();
                assert_eq!(all, mask.free, "{s} on {}", mask.name);
            }
        }
        assert_eq!(Strategy::Grouped.stages(&DofMask::local43(), &t).len(), 5);
        assert_eq!(
            Strategy::Hierarchical.stages(&DofMask::local43(), &t).len(),
            6
        );
        // papers/000 Algorithm 1's groups on the default skeleton: torso + root, then the limbs.
        let g = Strategy::Grouped.stages(&DofMask::full57(), &t);
        assert_eq!(
            g[0].0,
            [0, 1, 2]
                .into_iter()
                .chain(rot_offset(0)..rot_offset(4))
                .collect::<Vec<_>>()
        );
        assert_eq!(g[1].0, (rot_offset(8)..rot_offset(12)).collect::<Vec<_>>());
        // On a morphable model the shape coefficients go with the torso and root.
        let (m, _) = lfit_model::body::morphable_default_template().unwrap();
        let mask = DofMask::parse_for("local", &m).unwrap();
        for s in Strategy::ALL {
            let stages = s.stages(&mask, &m);
            let mut all: Vec<usize> = stages.iter().flat_map(|(d, _)| d.clone()).collect();
            all.sort_unstable();
            assert_eq!(all, mask.free, "{s}");
            assert!(stages[0].0.contains(&57), "{s}: shape in the first stage");
        }
        // Shape first: translation and β, then everything; holistic without coefficients.
        let sf = Strategy::ShapeFirst.stages(&mask, &m);
        assert_eq!(
            sf[0].0,
            [0, 1, 2].into_iter().chain(57..65).collect::<Vec<_>>()
        );
        assert_eq!(sf[1].0, mask.free);
        assert_eq!(
            Strategy::ShapeFirst.stages(&DofMask::local43(), &t),
            vec![(DofMask::local43().free, 1.0)]
        );
        assert_eq!(
            "shape-first".parse::<Strategy>().unwrap(),
            Strategy::ShapeFirst
        );
    }
}
