//! TBPSA — test-based population-size adaptation (nevergrad `_TBPSA` +
//! `_PopulationSizeController`, after Hellwig & Beyer 2016, pcCMSA-ES).
//!
//! In standardized space `z` (`x = start + scale ⊙ z`), with the nevergrad defaults:
//!
//! * initial µ = d, λ = 4µ = 4d; the smallest µ the controller shrinks back to is d;
//! * each child draws its own step `σ_k = σ · exp(N(0,1)/√d)` (nevergrad uses τ = 1/√d; the
//!   brief's 1/√(2d) is the textbook self-adaptation constant — we keep nevergrad's) and is
//!   sampled as `center + σ_k N(0, I)`;
//! * after λ children: parents = the µ best, `center` = their mean, `σ` = the geometric mean
//!   of their σ_k (σ0 = 1);
//! * every told loss is recorded; once 5λ losses are recorded, the first λ and the last λ are
//!   compared with `z = (mean_first − mean_last) / √(s_first² + s_last²)`,
//!   `s = std / √(λ − 1)`.  If `z < 2` (no significant progress: noise dominates) µ doubles,
//!   otherwise µ shrinks to `max(min µ, ⌊0.84 µ⌋)`; then λ = 4µ and the record is cleared.
//!   (The brief describes a record of generation means; nevergrad records single losses —
//!   we follow nevergrad.)
//!
//! Bounds: children are clipped into the box; the stored genotype is the clipped point
//! (lfit choice), so the center stays inside the box.

use super::util::{self, OptRng};
use super::{Bounds, Optimizer, Problem};

/// Population-size controller (nevergrad `_PopulationSizeController`).
#[derive(Debug, Clone, PartialEq)]
pub struct PopulationSizeController {
    /// Offspring per generation λ.
    pub lambda: usize,
    /// Parents µ.
    pub mu: usize,
    /// Smallest µ (nevergrad: `min(initial µ, dimension)`).
    pub min_mu: usize,
    record: Vec<f64>,
}

impl PopulationSizeController {
    /// Controller starting at `mu` parents, `lambda = 4 mu`.
    pub fn new(mu: usize, dim: usize) -> Self {
        let mu = mu.max(1);
        PopulationSizeController {
            lambda: 4 * mu,
            mu,
            min_mu: mu.min(dim.max(1)),
            record: Vec::new(),
        }
    }

    /// Records one loss; may change µ and λ.
    pub fn add_value(&mut self, loss: f64) {
        self.record.push(loss);
        let l = self.lambda;
        if self.record.len() >= 5 * l {
            let (m0, s0) = mean_std(&self.record[..l]);
            let (m1, s1) = mean_std(&self.record[self.record.len() - l..]);
            let denom = (l as f64 - 1.0).max(1.0).sqrt();
            let (e0, e1) = (s0 / denom, s1 / denom);
            let z = (m0 - m1) / (e0 * e0 + e1 * e1).sqrt();
            // NaN z (identical or infinite losses) counts as "no significant progress".
            if z.is_nan() || z < 2.0 {
                self.mu *= 2;
            } else {
                self.mu = self.min_mu.max((self.mu as f64 * 0.84) as usize);
            }
            self.lambda = 4 * self.mu;
            self.record.clear();
        }
    }
}

fn mean_std(v: &[f64]) -> (f64, f64) {
    let n = v.len() as f64;
    let m = v.iter().sum::<f64>() / n;
    let var = v.iter().map(|x| (x - m) * (x - m)).sum::<f64>() / n; // numpy std (ddof = 0)
    (m, var.sqrt())
}

/// Upper limit on µ (lfit choice: keeps memory bounded on endless noisy runs).
pub const MAX_MU: usize = 1 << 14;

struct Child {
    z: Vec<f64>,
    sigma: f64,
    loss: f64,
}

/// TBPSA optimizer.
pub struct Tbpsa {
    problem: Problem,
    rng: OptRng,
    center: Vec<f64>,
    sigma: f64,
    tau: f64,
    pop: PopulationSizeController,
    children: Vec<Child>,
    pending_sigma: Vec<f64>,
}

impl Tbpsa {
    /// TBPSA with nevergrad's defaults (µ = d, λ = 4d, σ0 = 1, τ = 1/√d).
    pub fn new(problem: &Problem, seed: u64) -> Self {
        let d = problem.dim();
        Tbpsa {
            problem: problem.clone(),
            rng: util::rng(seed),
            center: vec![0.0; d],
            sigma: 1.0,
            tau: 1.0 / (d as f64).sqrt(),
            pop: PopulationSizeController::new(d, d),
            children: Vec::new(),
            pending_sigma: Vec::new(),
        }
    }

    /// Current number of parents µ.
    pub fn mu(&self) -> usize {
        self.pop.mu
    }

    /// Current number of offspring λ.
    pub fn lambda(&self) -> usize {
        self.pop.lambda
    }

    /// Current σ (standardized units).
    pub fn sigma(&self) -> f64 {
        self.sigma
    }

    /// Current center in x units.
    pub fn center_x(&self) -> Vec<f64> {
        let p = &self.problem;
        let mut x: Vec<f64> = (0..p.dim())
            .map(|j| p.start[j] + p.scale[j] * self.center[j])
            .collect();
        p.bounds.clip(&mut x);
        x
    }

    fn end_generation(&mut self) {
        let mu = self.pop.mu.min(self.children.len()).max(1);
        self.children.sort_by(|a, b| a.loss.total_cmp(&b.loss));
        let d = self.problem.dim();
        let mut c = vec![0.0; d];
        let mut log_s = 0.0;
        for ch in &self.children[..mu] {
            for (a, b) in c.iter_mut().zip(&ch.z) {
                *a += b / mu as f64;
            }
            log_s += ch.sigma.ln() / mu as f64;
        }
        self.children.clear();
        if c.iter().all(|v| v.is_finite()) && log_s.is_finite() {
            self.center = c;
            self.sigma = log_s.exp().clamp(1e-300, 1e300);
        }
    }
}

impl Optimizer for Tbpsa {
    fn name(&self) -> &str {
        "tbpsa"
    }

    fn ask(&mut self, max: usize) -> Vec<Vec<f64>> {
        let k = self
            .pop
            .lambda
            .saturating_sub(self.children.len())
            .max(1)
            .min(max.max(1));
        let p = &self.problem;
        self.pending_sigma.clear();
        let mut out = Vec::with_capacity(k);
        for _ in 0..k {
            let s = self.sigma * (self.tau * util::normal(&mut self.rng)).exp();
            let mut x: Vec<f64> = (0..p.dim())
                .map(|j| {
                    p.start[j] + p.scale[j] * (self.center[j] + s * util::normal(&mut self.rng))
                })
                .collect();
            p.bounds.clip(&mut x);
            self.pending_sigma.push(s);
            out.push(x);
        }
        out
    }

    fn tell(&mut self, xs: &[Vec<f64>], values: &[f64]) {
        let d = self.problem.dim();
        let pending = std::mem::take(&mut self.pending_sigma);
        for ((x, &v), &s) in xs.iter().zip(values).zip(&pending) {
            let v = util::sanitize(v);
            self.pop.add_value(v);
            if self.pop.mu > MAX_MU {
                self.pop.mu = MAX_MU;
                self.pop.lambda = 4 * MAX_MU;
            }
            let z = (0..d)
                .map(|j| (x[j] - self.problem.start[j]) / self.problem.scale[j])
                .collect();
            self.children.push(Child {
                z,
                sigma: s,
                loss: v,
            });
            if self.children.len() >= self.pop.lambda {
                self.end_generation();
            }
        }
        self.pending_sigma = pending;
        self.pending_sigma.clear();
    }

    fn bounds(&self) -> &Bounds {
        &self.problem.bounds
    }
}

#[cfg(test)]
mod tests {
    use super::super::{Optimizer, minimize, testfns};
    use super::*;
    use rand::SeedableRng;
    use rand_chacha::ChaCha8Rng;
    use rand_distr::{Distribution, StandardNormal};

    #[test]
    fn improves_sphere_10() {
        let p = testfns::problem(10);
        let f0 = testfns::sphere(&p.start);
        for seed in 0..3 {
            let mut o = Tbpsa::new(&p, seed);
            let out = minimize(&mut o, &testfns::sphere, 3000, false).unwrap();
            // Measured best at 3000 evaluations, seeds 0..9: 6.4e-16 .. 4.2e-14.
            assert!(
                out.best_value < 0.01 * f0,
                "seed {seed}: {}",
                out.best_value
            );
            assert_eq!(o.mu(), 10, "no noise: µ stays at its minimum");
        }
    }

    #[test]
    fn population_doubles_under_noise() {
        let d = 5;
        let p = testfns::problem(d);
        let mut o = Tbpsa::new(&p, 1);
        assert_eq!((o.mu(), o.lambda()), (5, 20));
        let mut noise = ChaCha8Rng::seed_from_u64(99);
        let mut max_mu = 0;
        let mut evals = 0;
        while evals < 20_000 {
            let xs = o.ask(20_000 - evals);
            evals += xs.len();
            let v: Vec<f64> = xs
                .iter()
                .map(|x| {
                    testfns::sphere(x)
                        + <StandardNormal as Distribution<f64>>::sample(&StandardNormal, &mut noise)
                })
                .collect();
            o.tell(&xs, &v);
            max_mu = max_mu.max(o.mu());
        }
        assert!(max_mu >= 20, "µ never grew beyond {max_mu}");
        assert_eq!(o.lambda(), 4 * o.mu());
        // The center is still near the optimum.
        assert!(testfns::sphere(&o.center_x()) < 0.5, "{:?}", o.center_x());
    }

    #[test]
    fn controller_follows_nevergrad_rule() {
        let mut c = PopulationSizeController::new(4, 10);
        // Strong progress: z ≫ 2 → µ shrinks, but not below min µ = 4.
        for i in 0..80 {
            c.add_value(1000.0 - 10.0 * i as f64);
        }
        assert_eq!((c.mu, c.lambda), (4, 16));
        // Pure noise around a constant: z < 2 → µ doubles.
        for i in 0..80 {
            c.add_value(if i % 2 == 0 { 1.0 } else { -1.0 });
        }
        assert_eq!((c.mu, c.lambda), (8, 32));
    }
}
