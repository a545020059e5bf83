//! Random search: the start point first, then points uniform in the box (nevergrad
//! `RandomSearch` with a fully bounded parametrization samples uniformly in the bounds).

use super::util::{self, OptRng};
use super::{Bounds, Optimizer, Problem};

/// Largest batch returned by one ask (lfit choice: big enough for rayon, small enough to keep
/// memory flat for large budgets).
pub const RANDOM_BATCH: usize = 64;

/// Uniform random search.
pub struct RandomSearch {
    bounds: Bounds,
    start: Vec<f64>,
    rng: OptRng,
    started: bool,
}

impl RandomSearch {
    /// Random search on `problem`; the first point asked is `problem.start`.
    pub fn new(problem: &Problem, seed: u64) -> Self {
        RandomSearch {
            bounds: problem.bounds.clone(),
            start: problem.start.clone(),
            rng: util::rng(seed),
            started: false,
        }
    }
}

impl Optimizer for RandomSearch {
    fn name(&self) -> &str {
        "random"
    }

    fn ask(&mut self, max: usize) -> Vec<Vec<f64>> {
        let n = max.clamp(1, RANDOM_BATCH);
        let mut out = Vec::with_capacity(n);
        if !self.started {
            self.started = true;
            out.push(self.start.clone());
        }
        while out.len() < n {
            let mut x: Vec<f64> = self
                .bounds
                .lower
                .iter()
                .zip(&self.bounds.upper)
                .map(|(&l, &u)| l + (u - l) * util::uniform(&mut self.rng))
                .collect();
            self.bounds.clip(&mut x);
            out.push(x);
        }
        out
    }

    fn tell(&mut self, _xs: &[Vec<f64>], _values: &[f64]) {}

    fn bounds(&self) -> &Bounds {
        &self.bounds
    }
}

#[cfg(test)]
mod tests {
    use super::super::testfns;
    use super::super::{Bounds, Optimizer, Problem, minimize};
    use super::*;

    #[test]
    fn first_point_is_start_then_uniform_inside() {
        let p = Problem::new(
            Bounds::uniform(3, -1.0, 2.0).unwrap(),
            vec![0.5; 3],
            vec![1.0; 3],
        )
        .unwrap();
        let mut r = RandomSearch::new(&p, 1);
        let xs = r.ask(1000);
        assert_eq!(xs.len(), RANDOM_BATCH);
        assert_eq!(xs[0], vec![0.5; 3]);
        assert!(xs.iter().all(|x| p.bounds.contains(x)));
        // Uniform: the sample mean of every coordinate is near the box centre 0.5.
        let mut all = xs[1..].to_vec();
        for _ in 0..50 {
            all.extend(r.ask(64));
        }
        for j in 0..3 {
            let m = all.iter().map(|x| x[j]).sum::<f64>() / all.len() as f64;
            assert!((m - 0.5).abs() < 0.05, "coordinate {j} mean {m}");
        }
    }

    #[test]
    fn improves_over_start_on_sphere() {
        let p = testfns::problem(5);
        let mut r = RandomSearch::new(&p, 3);
        let out = minimize(&mut r, &testfns::sphere, 500, false).unwrap();
        assert!(out.best_value < testfns::sphere(&p.start));
    }
}
