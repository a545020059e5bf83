//! NGO-like selector: nevergrad `NGO`'s rule for a continuous, bounded, noise-free problem
//! with one worker, simplified as the brief specifies:
//!
//! * `budget < 30 d` → `one-plus-one`;
//! * `budget ≤ 6000` → `cma`;
//! * otherwise → `cma-powell`.
//!
//! (nevergrad additionally requires `d > 7` for ChainCMAPowell and special-cases tiny
//! dimensions; those branches are not reproduced.)  The wrapped optimizer is built with the
//! same preset and seed; [`Optimizer::name`] reports the choice, e.g. `"ngo(cma)"`.

use super::{Bounds, Method, OptimError, Optimizer, Preset, Problem, build};

/// The method NGO picks for dimension `d` and `budget`.
pub fn choose(d: usize, budget: usize) -> Method {
    if budget < 30 * d {
        Method::OnePlusOne
    } else if budget <= 6000 {
        Method::CMA
    } else {
        Method::CMAPowell
    }
}

/// The method nevergrad's `Shiwa` picks (papers/000 §2, item 9). Shiwa only departs from NGO for
/// noisy or non-metrizable problems (then RecombiningPortfolio…DiscreteOnePlusOne) and for
/// non-metrizable ones of 60 or more dimensions (then CMA); a bounded continuous pose vector is
/// metrizable and noise-free, so Shiwa's pick is NGO's for every dimension. It is kept as its own
/// name so that papers/000's ten-optimizer table has its tenth row, and it reports its pick.
pub fn choose_shiwa(d: usize, budget: usize) -> Method {
    choose(d, budget)
}

/// The NGO (and Shiwa) wrapper.
pub struct Ngo {
    name: String,
    choice: Method,
    inner: Box<dyn Optimizer>,
}

impl Ngo {
    /// Picks with [`choose`] and builds the chosen optimizer.
    pub fn new(
        problem: &Problem,
        preset: Preset,
        budget: usize,
        seed: u64,
    ) -> Result<Self, OptimError> {
        let choice = choose(problem.dim(), budget);
        let inner = build(choice, preset, problem, budget, seed, None)?;
        Ok(Ngo {
            name: format!("ngo({})", choice.as_str()),
            choice,
            inner,
        })
    }

    /// Shiwa: [`choose_shiwa`], named e.g. `"shiwa(cma)"`.
    pub fn shiwa(
        problem: &Problem,
        preset: Preset,
        budget: usize,
        seed: u64,
    ) -> Result<Self, OptimError> {
        let choice = choose_shiwa(problem.dim(), budget);
        let inner = build(choice, preset, problem, budget, seed, None)?;
        Ok(Ngo {
            name: format!("shiwa({})", choice.as_str()),
            choice,
            inner,
        })
    }

    /// The method that was picked.
    pub fn choice(&self) -> Method {
        self.choice
    }
}

impl Optimizer for Ngo {
    fn name(&self) -> &str {
        &self.name
    }

    fn ask(&mut self, max: usize) -> Vec<Vec<f64>> {
        self.inner.ask(max)
    }

    fn tell(&mut self, xs: &[Vec<f64>], values: &[f64]) {
        self.inner.tell(xs, values)
    }

    fn bounds(&self) -> &Bounds {
        self.inner.bounds()
    }
}

#[cfg(test)]
mod tests {
    use super::super::testfns;
    use super::*;

    #[test]
    fn rule() {
        assert_eq!(choose(10, 299), Method::OnePlusOne);
        assert_eq!(choose(10, 300), Method::CMA);
        assert_eq!(choose(10, 6000), Method::CMA);
        assert_eq!(choose(10, 6001), Method::CMAPowell);
        assert_eq!(choose(43, 1000), Method::OnePlusOne);
        let p = testfns::problem(43);
        let o = build(Method::NGO, Preset::Nevergrad, &p, 4000, 0, None).unwrap();
        assert_eq!(o.name(), "ngo(cma)");
        let o = build(Method::NGO, Preset::Nevergrad, &p, 100, 0, None).unwrap();
        assert_eq!(o.name(), "ngo(one-plus-one)");
        let o = build(Method::NGO, Preset::Nevergrad, &p, 7000, 0, None).unwrap();
        assert_eq!(o.name(), "ngo(cma-powell)");
        let o = build(Method::Shiwa, Preset::Nevergrad, &p, 4000, 0, None).unwrap();
        assert_eq!(o.name(), "shiwa(cma)");
    }
}
