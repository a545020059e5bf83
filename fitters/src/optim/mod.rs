//! Zeroth-order optimizers with a nevergrad-style ask/tell interface.
//!
//! Every optimizer works on a box-bounded problem ([`Problem`]): a start point inside the
//! box and a per-coordinate `scale` (the initial mutation step, e.g. 0.1 m or 3°).  Most
//! methods internally work in the normalised space `z` with `x = start + scale ⊙ z`, which is
//! what nevergrad calls the "standardized data" of a parameter with `sigma = scale`.
//!
//! Every point an optimizer asks for lies inside the bounds (the phenotype is clipped or
//! repaired; population methods may keep their own genotype).  [`minimize`] is the single
//! driver loop; it checks that promise and stops at exactly `budget` evaluations.
//!
//! Methods ([`Method`]) and their sources:
//!
//! | name           | module                  | source of the defaults |
//! |----------------|-------------------------|------------------------|
//! | `random`       | [`random`]              | nevergrad `RandomSearch` (uniform in the box) |
//! | `one-plus-one` | [`one_plus_one`]        | nevergrad `DiscreteOnePlusOne` + `OnePlusOne` step-size rule |
//! | `de`           | [`de`]                  | nevergrad `DE` / papers/001 Table 3 (H-DE) |
//! | `pso`          | [`pso`]                 | nevergrad `RealSpacePSO` / papers/001 Table 3 (H-PSO) |
//! | `cma`          | [`cma`]                 | Hansen's CMA tutorial (2016) / papers/001 Tables 2-3 |
//! | `tbpsa`        | [`tbpsa`]               | nevergrad `TBPSA` |
//! | `powell`       | [`powell`]              | Numerical Recipes §10.7 / scipy `fmin_powell` |
//! | `cma-powell`   | [`chain`]               | nevergrad `ChainCMAPowell` |
//! | `ngo`          | [`ngo`]                 | nevergrad `NGO` (continuous, bounded, noise-free branch) |
//! | `shiwa`        | [`ngo`]                 | nevergrad `Shiwa` (its rule; = NGO's pick below 60 DOFs) |
//! | `apf`          | [`apf`]                 | Deutscher & Reid; papers/001 §4.1.1, Table 3 |
//! | `psapf`        | [`psapf`]               | Bandouch et al.; papers/001 §4.1.2, Table 3 |
//!
//! This directory is meant to be copied verbatim into another crate as `crate::optim`; all
//! internal references therefore use `super::` paths.

use std::fmt;
use std::str::FromStr;

use rayon::prelude::*;
use thiserror::Error;

pub mod apf;
pub mod chain;
pub mod cma;
pub mod de;
pub mod ngo;
pub mod one_plus_one;
pub mod powell;
pub mod psapf;
pub mod pso;
pub mod random;
pub mod sequential;
pub mod tbpsa;
pub mod testfns;
mod util;

#[cfg(test)]
mod tests;

/// Everything that can go wrong when setting up or driving an optimizer.
#[derive(Debug, Error, Clone, PartialEq)]
pub enum OptimError {
    /// The problem has no coordinates.
    #[error("the problem has no coordinates (dimension 0)")]
    EmptyProblem,
    /// Two vectors that must have the same length do not.
    #[error("`{what}` has length {got}, expected {expected}")]
    LengthMismatch {
        what: &'static str,
        expected: usize,
        got: usize,
    },
    /// A bound is NaN or infinite.
    #[error("bound {index} is not finite: lower = {lower}, upper = {upper}")]
    NonFiniteBound {
        index: usize,
        lower: f64,
        upper: f64,
    },
    /// `lower[index] >= upper[index]`.
    #[error("bound {index} is empty: lower = {lower} is not below upper = {upper}")]
    EmptyBound {
        index: usize,
        lower: f64,
        upper: f64,
    },
    /// `start[index]` is NaN/infinite or outside `[lower, upper]`.
    #[error("start[{index}] = {value} is not inside [{lower}, {upper}]")]
    StartOutOfBounds {
        index: usize,
        value: f64,
        lower: f64,
        upper: f64,
    },
    /// `scale[index]` is not a finite positive number.
    #[error("scale[{index}] = {value} must be finite and > 0")]
    BadScale { index: usize, value: f64 },
    /// A budget of zero evaluations was requested.
    #[error("the budget must be at least 1 evaluation")]
    ZeroBudget,
    /// A method name that [`Method::from_str`] does not know.
    #[error("unknown optimizer `{name}`; valid names: {valid}")]
    UnknownMethod { name: String, valid: String },
    /// A preset name that [`Preset::from_str`] does not know.
    #[error("unknown preset `{name}`; valid names: {valid}")]
    UnknownPreset { name: String, valid: String },
    /// The PSAPF partitions are not a partition of `0..dim`.
    #[error("bad partitions: {reason}")]
    BadPartitions { reason: String },
    /// An optimizer asked for a point outside the bounds (a bug in the optimizer).
    #[error(
        "optimizer `{optimizer}` asked for a point outside the bounds: point {point}, coordinate {coord} = {value} not in [{lower}, {upper}]"
    )]
    OutOfBounds {
        optimizer: String,
        point: usize,
        coord: usize,
        value: f64,
        lower: f64,
        upper: f64,
    },
    /// An optimizer asked for a point with a NaN or infinite coordinate (a bug in the optimizer).
    #[error(
        "optimizer `{optimizer}` asked for a non-finite point: point {point}, coordinate {coord} = {value}"
    )]
    NonFinitePoint {
        optimizer: String,
        point: usize,
        coord: usize,
        value: f64,
    },
    /// An optimizer asked for a point of the wrong dimension (a bug in the optimizer).
    #[error(
        "optimizer `{optimizer}` asked for point {point} of dimension {got}, expected {expected}"
    )]
    DimensionMismatch {
        optimizer: String,
        point: usize,
        expected: usize,
        got: usize,
    },
    /// An optimizer returned no point from `ask` (a bug in the optimizer).
    #[error("optimizer `{optimizer}` returned no point from ask")]
    EmptyAsk { optimizer: String },
}

/// A box: `lower[i] < upper[i]`, all finite, same length.
#[derive(Debug, Clone, PartialEq)]
pub struct Bounds {
    pub lower: Vec<f64>,
    pub upper: Vec<f64>,
}

impl Bounds {
    /// Validated constructor.
    pub fn new(lower: Vec<f64>, upper: Vec<f64>) -> Result<Self, OptimError> {
        let b = Bounds { lower, upper };
        b.validate()?;
        Ok(b)
    }

    /// The same interval `[lower, upper]` for each of `dim` coordinates.
    pub fn uniform(dim: usize, lower: f64, upper: f64) -> Result<Self, OptimError> {
        Self::new(vec![lower; dim], vec![upper; dim])
    }

    /// Checks the invariants (the fields are public, so this is re-run by [`build`]).
    pub fn validate(&self) -> Result<(), OptimError> {
        if self.lower.len() != self.upper.len() {
            return Err(OptimError::LengthMismatch {
                what: "upper",
                expected: self.lower.len(),
                got: self.upper.len(),
            });
        }
        if self.lower.is_empty() {
            return Err(OptimError::EmptyProblem);
        }
        for (index, (&lower, &upper)) in self.lower.iter().zip(&self.upper).enumerate() {
            if !lower.is_finite() || !upper.is_finite() {
                return Err(OptimError::NonFiniteBound {
                    index,
                    lower,
                    upper,
                });
            }
            if lower >= upper {
                return Err(OptimError::EmptyBound {
                    index,
                    lower,
                    upper,
                });
            }
        }
        Ok(())
    }

    /// Number of coordinates.
    pub fn dim(&self) -> usize {
        self.lower.len()
    }

    /// Whether `x` has the right length and lies inside the box (bounds included).
    pub fn contains(&self, x: &[f64]) -> bool {
        x.len() == self.dim()
            && x.iter()
                .zip(self.lower.iter().zip(&self.upper))
                .all(|(&v, (&l, &u))| v >= l && v <= u)
    }

    /// Clips `x` into the box in place; a NaN coordinate becomes the box centre.
    pub fn clip(&self, x: &mut [f64]) {
        for ((v, &l), &u) in x.iter_mut().zip(&self.lower).zip(&self.upper) {
            *v = if v.is_nan() {
                0.5 * (l + u)
            } else {
                v.clamp(l, u)
            };
        }
    }
}

/// A box-bounded minimisation problem: bounds, a start point inside them, and the initial
/// per-coordinate mutation step `scale` (> 0).
#[derive(Debug, Clone, PartialEq)]
pub struct Problem {
    pub bounds: Bounds,
    pub start: Vec<f64>,
    pub scale: Vec<f64>,
}

impl Problem {
    /// Validated constructor.
    pub fn new(bounds: Bounds, start: Vec<f64>, scale: Vec<f64>) -> Result<Self, OptimError> {
        let p = Problem {
            bounds,
            start,
            scale,
        };
        p.validate()?;
        Ok(p)
    }

    /// Checks all invariants (the fields are public, so this is re-run by [`build`]).
    pub fn validate(&self) -> Result<(), OptimError> {
        self.bounds.validate()?;
        let d = self.bounds.dim();
        if self.start.len() != d {
            return Err(OptimError::LengthMismatch {
                what: "start",
                expected: d,
                got: self.start.len(),
            });
        }
        if self.scale.len() != d {
            return Err(OptimError::LengthMismatch {
                what: "scale",
                expected: d,
                got: self.scale.len(),
            });
        }
        for index in 0..d {
            let (lower, upper, value) = (
                self.bounds.lower[index],
                self.bounds.upper[index],
                self.start[index],
            );
            if !(value >= lower && value <= upper) {
                return Err(OptimError::StartOutOfBounds {
                    index,
                    value,
                    lower,
                    upper,
                });
            }
            let s = self.scale[index];
            if !(s.is_finite() && s > 0.0) {
                return Err(OptimError::BadScale { index, value: s });
            }
        }
        Ok(())
    }

    /// Number of coordinates.
    pub fn dim(&self) -> usize {
        self.bounds.dim()
    }
}

/// The ask/tell interface every optimizer implements.
pub trait Optimizer: Send {
    /// Short name; wrappers say what they wrap, e.g. `"ngo(cma)"`.
    fn name(&self) -> &str;
    /// Next points to evaluate, 1..=max of them (max ≥ 1 is the remaining budget). Every point
    /// must lie inside the bounds.
    fn ask(&mut self, max: usize) -> Vec<Vec<f64>>;
    /// Values for exactly the points returned by the last ask, same order. (The final ask may
    /// have been cut short by the budget.)
    fn tell(&mut self, xs: &[Vec<f64>], values: &[f64]);
    /// The box all asked points lie in; [`minimize`] checks every ask against it.
    fn bounds(&self) -> &Bounds;
}

/// The available optimizers.  Kebab-case names: see [`Method::as_str`].
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Method {
    RandomSearch,
    OnePlusOne,
    DE,
    PSO,
    CMA,
    TBPSA,
    Powell,
    CMAPowell,
    NGO,
    Shiwa,
    APF,
    PSAPF,
}

impl Method {
    /// All methods, in declaration order.
    pub const ALL: [Method; 12] = [
        Method::RandomSearch,
        Method::OnePlusOne,
        Method::DE,
        Method::PSO,
        Method::CMA,
        Method::TBPSA,
        Method::Powell,
        Method::CMAPowell,
        Method::NGO,
        Method::Shiwa,
        Method::APF,
        Method::PSAPF,
    ];

    /// The kebab-case name used on command lines and in reports.
    pub fn as_str(self) -> &'static str {
        match self {
            Method::RandomSearch => "random",
            Method::OnePlusOne => "one-plus-one",
            Method::DE => "de",
            Method::PSO => "pso",
            Method::CMA => "cma",
            Method::TBPSA => "tbpsa",
            Method::Powell => "powell",
            Method::CMAPowell => "cma-powell",
            Method::NGO => "ngo",
            Method::Shiwa => "shiwa",
            Method::APF => "apf",
            Method::PSAPF => "psapf",
        }
    }

    fn valid_names() -> String {
        Self::ALL
            .iter()
            .map(|m| m.as_str())
            .collect::<Vec<_>>()
            .join(", ")
    }
}

impl fmt::Display for Method {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.as_str())
    }
}

impl FromStr for Method {
    type Err = OptimError;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        let t = s.trim();
        Self::ALL
            .iter()
            .copied()
            .find(|m| m.as_str().eq_ignore_ascii_case(t))
            .ok_or_else(|| OptimError::UnknownMethod {
                name: s.to_string(),
                valid: Self::valid_names(),
            })
    }
}

/// Which set of default parameters to use.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
pub enum Preset {
    /// The defaults of the reference implementation (nevergrad, pycma / Hansen's tutorial, scipy).
    #[default]
    Nevergrad,
    /// The settings of papers/001 Table 3 (with Table 2 for CMA-ES) where the paper gives any;
    /// methods the paper does not use fall back to the nevergrad defaults.
    Paper001,
}

impl Preset {
    /// Both presets.
    pub const ALL: [Preset; 2] = [Preset::Nevergrad, Preset::Paper001];

    /// `"nevergrad"` or `"paper001"`.
    pub fn as_str(self) -> &'static str {
        match self {
            Preset::Nevergrad => "nevergrad",
            Preset::Paper001 => "paper001",
        }
    }
}

impl fmt::Display for Preset {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.as_str())
    }
}

impl FromStr for Preset {
    type Err = OptimError;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        let t = s.trim();
        Self::ALL
            .iter()
            .copied()
            .find(|p| p.as_str().eq_ignore_ascii_case(t))
            .ok_or_else(|| OptimError::UnknownPreset {
                name: s.to_string(),
                valid: "nevergrad, paper001".to_string(),
            })
    }
}

/// Builds an optimizer for `problem`.
///
/// `budget` (≥ 1) is the number of evaluations the caller will spend; budget-aware methods
/// (PSO inertia schedule, CMA→Powell split, NGO choice, APF/PSAPF particle counts) use it.
/// `partitions` is only used by PSAPF: coordinate-index groups processed in order, which must
/// partition `0..dim` exactly; `None` means one partition of all coordinates.  Other methods
/// ignore it.  The same `seed` gives the same sequence of asks.
pub fn build(
    method: Method,
    preset: Preset,
    problem: &Problem,
    budget: usize,
    seed: u64,
    partitions: Option<Vec<Vec<usize>>>,
) -> Result<Box<dyn Optimizer>, OptimError> {
    build_with(
        method,
        preset,
        problem,
        budget,
        seed,
        partitions,
        cma::CmaVariant::default(),
    )
}

/// [`build`] with CMA-ES's update variant (ignored by the other methods).
pub fn build_with(
    method: Method,
    preset: Preset,
    problem: &Problem,
    budget: usize,
    seed: u64,
    partitions: Option<Vec<Vec<usize>>>,
    cma_variant: cma::CmaVariant,
) -> Result<Box<dyn Optimizer>, OptimError> {
    problem.validate()?;
    if budget == 0 {
        return Err(OptimError::ZeroBudget);
    }
    Ok(match method {
        Method::RandomSearch => Box::new(random::RandomSearch::new(problem, seed)),
        Method::OnePlusOne => Box::new(one_plus_one::OnePlusOne::new(problem, seed)),
        Method::DE => Box::new(de::DifferentialEvolution::new(
            problem,
            de::DeConfig::preset(preset),
            seed,
        )),
        Method::PSO => Box::new(pso::ParticleSwarm::new(
            problem,
            pso::PsoConfig::preset(preset),
            budget,
            seed,
        )),
        Method::CMA => Box::new(cma::Cma::with_variant(problem, preset, cma_variant, seed)),
        Method::TBPSA => Box::new(tbpsa::Tbpsa::new(problem, seed)),
        Method::Powell => Box::new(powell::build_powell(problem, seed)),
        Method::CMAPowell => Box::new(chain::CmaPowell::new(problem, preset, budget, seed)),
        Method::NGO => Box::new(ngo::Ngo::new(problem, preset, budget, seed)?),
        Method::Shiwa => Box::new(ngo::Ngo::shiwa(problem, preset, budget, seed)?),
        Method::APF => Box::new(apf::Apf::new(
            problem,
            apf::ApfConfig::default(),
            budget,
            seed,
        )),
        Method::PSAPF => {
            let parts = match partitions {
                Some(p) => psapf::validate_partitions(p, problem.dim())?,
                None => vec![(0..problem.dim()).collect()],
            };
            Box::new(psapf::Psapf::new(
                problem,
                apf::ApfConfig::default(),
                parts,
                budget,
                seed,
            ))
        }
    })
}

/// Result of [`minimize`].
#[derive(Debug, Clone, PartialEq)]
pub struct Outcome {
    /// Best evaluated point (the first point evaluated if every value was +inf/NaN).
    pub best_x: Vec<f64>,
    /// Its value (NaN values are reported as +inf).
    pub best_value: f64,
    /// Number of evaluations spent: always exactly the budget.
    pub evaluations: usize,
    /// `(evaluations so far, best value)`, appended whenever the best value improves, plus a
    /// final entry at the last evaluation unless the last improvement already happened there.
    pub trace: Vec<(usize, f64)>,
}

/// The driver loop (argmin-executor style).
///
/// Repeatedly asks for at most the remaining budget, truncates an over-long ask, checks that
/// every point has the right dimension, is finite and lies inside `opt.bounds()` (otherwise
/// returns [`OptimError::OutOfBounds`] & co. before evaluating anything of that batch),
/// evaluates the batch (with rayon when `parallel`), tells the values (NaN → +inf), and
/// tracks the best point.  `f` is called exactly `budget` times.
pub fn minimize<F: Fn(&[f64]) -> f64 + Sync>(
    opt: &mut dyn Optimizer,
    f: &F,
    budget: usize,
    parallel: bool,
) -> Result<Outcome, OptimError> {
    if budget == 0 {
        return Err(OptimError::ZeroBudget);
    }
    opt.bounds().validate()?;
    let dim = opt.bounds().dim();
    let mut evaluations = 0usize;
    let mut best_x: Option<Vec<f64>> = None;
    let mut best_value = f64::INFINITY;
    let mut trace = Vec::new();
    let mut values: Vec<f64> = Vec::new();
    while evaluations < budget {
        let remaining = budget - evaluations;
        let mut xs = opt.ask(remaining);
        if xs.is_empty() {
            return Err(OptimError::EmptyAsk {
                optimizer: opt.name().to_string(),
            });
        }
        xs.truncate(remaining);
        check_points(opt, &xs, dim)?;
        values.clear();
        if parallel && xs.len() > 1 {
            xs.par_iter()
                .map(|x| util::sanitize(f(x)))
                .collect_into_vec(&mut values);
        } else {
            values.extend(xs.iter().map(|x| util::sanitize(f(x))));
        }
        opt.tell(&xs, &values);
        for (x, &v) in xs.iter().zip(&values) {
            evaluations += 1;
            if best_x.is_none() || v < best_value {
                if v < best_value {
                    trace.push((evaluations, v));
                }
                best_value = v;
                best_x = Some(x.clone());
            }
        }
    }
    if trace.last().map(|&(e, _)| e) != Some(evaluations) {
        trace.push((evaluations, best_value));
    }
    // `best_x` is always set: budget ≥ 1 and every ask is non-empty.
    let best_x = best_x.unwrap_or_default();
    Ok(Outcome {
        best_x,
        best_value,
        evaluations,
        trace,
    })
}

fn check_points(opt: &dyn Optimizer, xs: &[Vec<f64>], dim: usize) -> Result<(), OptimError> {
    let b = opt.bounds();
    for (point, x) in xs.iter().enumerate() {
        if x.len() != dim {
            return Err(OptimError::DimensionMismatch {
                optimizer: opt.name().to_string(),
                point,
                expected: dim,
                got: x.len(),
            });
        }
        for (coord, &value) in x.iter().enumerate() {
            if !value.is_finite() {
                return Err(OptimError::NonFinitePoint {
                    optimizer: opt.name().to_string(),
                    point,
                    coord,
                    value,
                });
            }
            let (lower, upper) = (b.lower[coord], b.upper[coord]);
            if value < lower || value > upper {
                return Err(OptimError::OutOfBounds {
                    optimizer: opt.name().to_string(),
                    point,
                    coord,
                    value,
                    lower,
                    upper,
                });
            }
        }
    }
    Ok(())
}
