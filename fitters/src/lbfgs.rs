//! L-BFGS with the energy's exact gradient (papers/002's classical baseline), via argmin.
//!
//! Bounds: L-BFGS minimises `E(clip(x))`, whose exact gradient is the energy's gradient on free
//! coordinates inside the box and 0 on coordinates clipped at it; every evaluated pose is inside
//! the box. Budget: each distinct point costs one evaluation (value and gradient together); a run
//! stops when the budget is spent or when L-BFGS converges (then using fewer evaluations).

use std::sync::Mutex;

use argmin::core::{CostFunction, Executor, Gradient, State};
use argmin::solver::linesearch::MoreThuenteLineSearch;
use argmin::solver::quasinewton::LBFGS;
use lfit_model::energy::Energy;
use lfit_model::pose::Bounds;

use crate::error::FitError;
use crate::fitter::{
    FitRequest, FitResult, Fitter, StageOutcome, StageSolver, Strategy, run_staged,
};

/// History length of L-BFGS (argmin examples and scipy's L-BFGS-B default use 5–10; we take 7).
pub const DEFAULT_MEMORY: usize = 7;

/// L-BFGS under a strategy (normally holistic).
#[derive(Debug, Clone, Copy)]
pub struct LbfgsFitter {
    pub memory: usize,
    pub strategy: Strategy,
}

impl Default for LbfgsFitter {
    fn default() -> Self {
        Self {
            memory: DEFAULT_MEMORY,
            strategy: Strategy::Holistic,
        }
    }
}

impl Fitter for LbfgsFitter {
    fn name(&self) -> String {
        if self.strategy == Strategy::Holistic {
            "lbfgs".into()
        } else {
            format!("lbfgs/{}", self.strategy)
        }
    }

    fn fit(&self, request: &FitRequest<'_>) -> Result<FitResult, FitError> {
        if let Some(why) = request.energy.gradient_unsupported() {
            return Err(FitError::Lbfgs(why));
        }
        run_staged(self.name(), self, self.strategy, request)
    }
}

struct Tracker {
    count: usize,
    best: (f64, Vec<f64>),
    trace: Vec<(u64, f64)>,
    cache: Option<(Vec<f64>, f64, Vec<f64>)>,
}

struct Objective<'a> {
    energy: &'a Energy,
    base: Vec<f64>,
    dofs: &'a [usize],
    lower: Vec<f64>,
    upper: Vec<f64>,
    budget: usize,
    state: Mutex<Tracker>,
}

const BUDGET_SPENT: &str = "evaluation budget spent";

impl Objective<'_> {
    fn eval(&self, x: &[f64]) -> Result<(f64, Vec<f64>), argmin::core::Error> {
        let mut st = self
            .state
            .lock()
            .map_err(|_| argmin::core::Error::msg("poisoned tracker"))?;
        if let Some((cx, v, g)) = &st.cache
            && cx.as_slice() == x
        {
            return Ok((*v, g.clone()));
        }
        if st.count >= self.budget {
            return Err(argmin::core::Error::msg(BUDGET_SPENT));
        }
        let mut pose = self.base.clone();
        let mut clipped = Vec::with_capacity(x.len());
        for (k, &i) in self.dofs.iter().enumerate() {
            let c = if x[k].is_finite() {
                x[k].clamp(self.lower[k], self.upper[k])
            } else {
                self.base[i]
            };
            pose[i] = c;
            clipped.push(c);
        }
        let (ev, g) = self.energy.evaluate_with_gradient(&pose);
        st.count += 1;
        let grad: Vec<f64> = self
            .dofs
            .iter()
            .enumerate()
            .map(|(k, &i)| {
                if x[k] < self.lower[k] || x[k] > self.upper[k] {
                    0.0
                } else {
                    g[i]
                }
            })
            .collect();
        if ev.total < st.best.0 {
            st.best = (ev.total, clipped);
            let n = st.count as u64;
            st.trace.push((n, ev.total));
        }
        st.cache = Some((x.to_vec(), ev.total, grad.clone()));
        Ok((ev.total, grad))
    }
}

// `Executor::new` takes the problem by value; it gets a shared reference so the tracker can be
// read after the run.
impl CostFunction for &Objective<'_> {
    type Param = Vec<f64>;
    type Output = f64;
    fn cost(&self, x: &Vec<f64>) -> Result<f64, argmin::core::Error> {
        self.eval(x).map(|(v, _)| v)
    }
}

impl Gradient for &Objective<'_> {
    type Param = Vec<f64>;
    type Gradient = Vec<f64>;
    fn gradient(&self, x: &Vec<f64>) -> Result<Vec<f64>, argmin::core::Error> {
        self.eval(x).map(|(_, g)| g)
    }
}

impl StageSolver for LbfgsFitter {
    fn solve(
        &self,
        energy: &Energy,
        pose: &mut [f64],
        dofs: &[usize],
        bounds: &Bounds,
        budget: usize,
        _seed: u64,
    ) -> Result<StageOutcome, FitError> {
        let x0: Vec<f64> = dofs.iter().map(|&i| pose[i]).collect();
        let objective = Objective {
            energy,
            base: pose.to_vec(),
            dofs,
            lower: dofs.iter().map(|&i| bounds.lower[i]).collect(),
            upper: dofs.iter().map(|&i| bounds.upper[i]).collect(),
            budget,
            state: Mutex::new(Tracker {
                count: 0,
                best: (f64::INFINITY, x0.clone()),
                trace: Vec::new(),
                cache: None,
            }),
        };
        let lbfgs = LBFGS::new(MoreThuenteLineSearch::new(), self.memory.max(1))
            .with_tolerance_grad(1e-9)
            .and_then(|s| s.with_tolerance_cost(1e-13))
            .map_err(|e| FitError::Lbfgs(e.to_string()))?;
        let run = Executor::new(&objective, lbfgs)
            .configure(|s| s.param(x0).max_iters(budget as u64))
            .run();
        let iterations = match &run {
            Ok(res) => res.state().get_iter(),
            Err(e) if e.to_string().contains(BUDGET_SPENT) => 0,
            // Line-search failures end the run like convergence: keep the best point seen.
            Err(e) => {
                tracing::debug!("L-BFGS stopped: {e}");
                0
            }
        };
        let st = objective
            .state
            .into_inner()
            .map_err(|_| FitError::Lbfgs("poisoned tracker".into()))?;
        for (k, &i) in dofs.iter().enumerate() {
            pose[i] = st.best.1[k];
        }
        Ok(StageOutcome {
            best: st.best.0,
            trace: st.trace,
            iterations: if iterations > 0 {
                iterations
            } else {
                st.count as u64
            },
        })
    }
}
