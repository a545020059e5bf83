//! CMA→Powell chain (nevergrad `ChainCMAPowell = Chaining([CMA, Powell], ["half"])`): CMA-ES
//! for the first ⌊budget/2⌋ evaluations, then Powell from the best point found so far for the
//! rest.
//!
//! Deviation (lfit choice): nevergrad's Powell (scipy) starts with unit steps in standardized
//! space, i.e. `scale`; here Powell's initial directions use CMA's final per-coordinate
//! standard deviation `σ √C_ii` (in x units), clamped to `[1e-9 · scale, scale]`, so Powell
//! continues at the resolution CMA reached instead of re-bracketing from `scale`.

use super::cma::Cma;
use super::powell::{PowellConfig, powell_factory};
use super::sequential::Sequential;
use super::util;
use super::{Bounds, Optimizer, Preset, Problem};

/// Smallest initial Powell step relative to `scale`.
pub const MIN_STEP_FRACTION: f64 = 1e-9;

/// The CMA→Powell chain.
pub struct CmaPowell {
    problem: Problem,
    cma: Cma,
    cma_budget: usize,
    cma_used: usize,
    powell: Option<Sequential>,
    asked_from_cma: bool,
    best_x: Vec<f64>,
    best_f: f64,
    seed: u64,
}

impl CmaPowell {
    /// Chain for a total of `budget` evaluations; CMA uses the parameters of `preset`.
    pub fn new(problem: &Problem, preset: Preset, budget: usize, seed: u64) -> Self {
        CmaPowell {
            problem: problem.clone(),
            cma: Cma::with_preset(problem, preset, util::sub_seed(seed, 1)),
            cma_budget: budget / 2,
            cma_used: 0,
            powell: None,
            asked_from_cma: false,
            best_x: problem.start.clone(),
            best_f: f64::INFINITY,
            seed,
        }
    }

    /// Whether the Powell phase has started.
    pub fn in_powell_phase(&self) -> bool {
        self.powell.is_some()
    }

    fn start_powell(&mut self) -> &mut Sequential {
        let p = &self.problem;
        let steps: Vec<f64> = self
            .cma
            .std_x()
            .iter()
            .zip(&p.scale)
            .map(|(&s, &sc)| {
                if s.is_finite() {
                    s.clamp(MIN_STEP_FRACTION * sc, sc)
                } else {
                    sc
                }
            })
            .collect();
        let factory = powell_factory(p, PowellConfig::default(), util::sub_seed(self.seed, 3));
        let seq = Sequential::starting_at(
            "cma-powell",
            p,
            self.best_x.clone(),
            steps,
            factory,
            util::sub_seed(self.seed, 2),
        );
        self.powell.insert(seq)
    }
}

impl Optimizer for CmaPowell {
    fn name(&self) -> &str {
        "cma-powell"
    }

    fn ask(&mut self, max: usize) -> Vec<Vec<f64>> {
        let max = max.max(1);
        if self.cma_used < self.cma_budget {
            self.asked_from_cma = true;
            return self.cma.ask(max.min(self.cma_budget - self.cma_used));
        }
        self.asked_from_cma = false;
        match self.powell.as_mut() {
            Some(p) => p.ask(max),
            None => self.start_powell().ask(max),
        }
    }

    fn tell(&mut self, xs: &[Vec<f64>], values: &[f64]) {
        for (x, &v) in xs.iter().zip(values) {
            let v = util::sanitize(v);
            if v < self.best_f {
                self.best_f = v;
                self.best_x.clone_from(x);
            }
        }
        if self.asked_from_cma {
            self.cma_used += xs.len().min(values.len());
            self.cma.tell(xs, values);
        } else if let Some(p) = self.powell.as_mut() {
            p.tell(xs, values);
        }
    }

    fn bounds(&self) -> &Bounds {
        &self.problem.bounds
    }
}

#[cfg(test)]
mod tests {
    use super::super::{minimize, testfns};
    use super::*;

    #[test]
    fn switches_at_half_budget_and_refines() {
        let p = testfns::problem(10);
        let mut o = CmaPowell::new(&p, Preset::Nevergrad, 3000, 1);
        let out = minimize(&mut o, &testfns::ellipsoid, 1500, false).unwrap();
        assert!(!o.in_powell_phase());
        let cma_best = out.best_value;
        let out2 = minimize(&mut o, &testfns::ellipsoid, 1500, false).unwrap();
        assert!(o.in_powell_phase());
        assert!(out2.best_value <= cma_best);
        assert!(
            out2.best_value < 1e-6,
            "{} (after cma {cma_best})",
            out2.best_value
        );
    }
}
