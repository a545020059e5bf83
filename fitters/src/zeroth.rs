//! Zeroth-order fitters: an ask/tell optimizer from [`crate::optim`] run by a strategy over the
//! free DOFs of the pose, every candidate scored by the energy (batched in parallel).

use lfit_model::energy::Energy;
use lfit_model::pose::{Bounds, DofMask};

use crate::error::FitError;
use crate::fitter::{
    FitRequest, FitResult, Fitter, StageOutcome, StageSolver, Strategy, run_staged, steps,
};
use crate::optim::{self, Method, Preset, Problem};

/// A zeroth-order method under a strategy.
#[derive(Debug, Clone, Copy)]
pub struct ZerothOrderFitter {
    pub method: Method,
    pub preset: Preset,
    pub strategy: Strategy,
    /// Factor on every initial step (papers/000 §4.1's 0.1 m / 3° / 0.3 σ; 1 = as published):
    /// the knob of the `tuned` settings (see `configs/tuned.json`).
    pub step_scale: f64,
    /// CMA-ES's update variant (diagonal, elitist, population; ignored by other methods).
    pub cma: crate::optim::cma::CmaVariant,
}

impl ZerothOrderFitter {
    pub fn new(method: Method, preset: Preset, strategy: Strategy) -> Self {
        Self {
            method,
            preset,
            strategy,
            step_scale: 1.0,
            cma: Default::default(),
        }
    }
}

impl Fitter for ZerothOrderFitter {
    fn name(&self) -> String {
        let mut name = self.method.as_str().to_string();
        if self.preset != Preset::Nevergrad {
            name = format!("{name}[{}]", self.preset.as_str());
        }
        if self.step_scale != 1.0 {
            name = format!("{name}[steps×{}]", self.step_scale);
        }
        let v = self.cma;
        if v != Default::default() {
            let mut parts = Vec::new();
            if v.diagonal {
                parts.push("diagonal".to_string());
            }
            if v.elitist {
                parts.push("elitist".to_string());
            }
            if let Some(l) = v.popsize {
                parts.push(format!("λ={l}"));
            }
            name = format!("{name}[{}]", parts.join(","));
        }
        if self.strategy != Strategy::Holistic {
            name = format!("{name}/{}", self.strategy);
        }
        name
    }

    fn fit(&self, request: &FitRequest<'_>) -> Result<FitResult, FitError> {
        run_staged(self.name(), self, self.strategy, request)
    }
}

impl StageSolver for ZerothOrderFitter {
    fn solve(
        &self,
        energy: &Energy,
        pose: &mut [f64],
        dofs: &[usize],
        bounds: &Bounds,
        budget: usize,
        seed: u64,
    ) -> Result<StageOutcome, FitError> {
        let lower: Vec<f64> = dofs.iter().map(|&i| bounds.lower[i]).collect();
        let upper: Vec<f64> = dofs.iter().map(|&i| bounds.upper[i]).collect();
        let start: Vec<f64> = dofs.iter().map(|&i| pose[i]).collect();
        let problem = Problem::new(
            optim::Bounds::new(lower, upper)?,
            start,
            steps(dofs, &energy.template().layout())
                .into_iter()
                .map(|s| s * self.step_scale)
                .collect(),
        )?;
        // PSAPF partitions its stage by the hierarchical steps of papers/001 §3.3.
        let partitions = (self.method == Method::PSAPF).then(|| {
            let mask = DofMask {
                name: "stage".into(),
                free: dofs.to_vec(),
            };
            Strategy::Hierarchical
                .stages(&mask, energy.template())
                .into_iter()
                .map(|(s, _)| {
                    s.iter()
                        .filter_map(|i| dofs.iter().position(|d| d == i))
                        .collect::<Vec<usize>>()
                })
                .collect::<Vec<_>>()
        });
        let mut opt = optim::build_with(
            self.method,
            self.preset,
            &problem,
            budget,
            seed,
            partitions,
            self.cma,
        )?;
        let base = pose.to_vec();
        let f = |x: &[f64]| {
            let mut p = base.clone();
            for (k, &i) in dofs.iter().enumerate() {
                p[i] = x[k];
            }
            energy.evaluate(&p).total
        };
        let out = optim::minimize(opt.as_mut(), &f, budget, true)?;
        for (k, &i) in dofs.iter().enumerate() {
            pose[i] = out.best_x[k];
        }
        Ok(StageOutcome {
            best: out.best_value,
            trace: out.trace.iter().map(|&(n, v)| (n as u64, v)).collect(),
            iterations: out.evaluations as u64,
        })
    }
}
