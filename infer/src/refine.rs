//! `neural+lm`: the learned fitter's N iterations, then Levenberg–Marquardt from its result,
//! within one budget. The network brings the fit into the basin of the right minimum in a few
//! evaluations; LM then converges there on the exact energy (papers/002 §4 suggests a learned
//! start for classical refinement; LM is lfit's most accurate classical solver on the sparse
//! modalities, `docs/results/learned-vs-classical.md`).
//!
//! With [`Dofs::Anchored`] (the CLI's default for `neural+lm` on the sparse body sensors) LM
//! moves every entry on the energy plus a Gaussian pull of the rotations and the root translation
//! toward the network's result ([`lfit_fitters::AnchoredDofs`]): what the sensor leaves open
//! (fingers, thumbs, a limb's twist under 2D keypoints, an arm whose markers are missing, the
//! depth along a single camera's axis) stays near the network's
//! estimate, which is learned from human motion, where LM would set it from the noise of the few
//! rows that touch it; what the data determine moves as LM moves it. With [`Dofs::OBSERVED`]
//! LM moves only the rotation entries the observations determine ([`lfit_fitters::observed`])
//! and keeps the network's β (the hard form, the default before round 28 of
//! docs/results/captured-motion.md).

use lfit_fitters::optim::Preset;
use lfit_fitters::{Dofs, FitError, FitRequest, FitResult, Fitter, Strategy};
use lfit_model::{Block, DofMask};

use crate::NeuralFitter;

/// The network, then LM (module docs).
#[derive(Debug)]
pub struct NeuralThenLm {
    pub neural: NeuralFitter,
    lm: LmFitter,
    dofs: Dofs,
}

struct LmFitter(Box<dyn Fitter>);

impl std::fmt::Debug for LmFitter {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.0.name())
    }
}

impl NeuralThenLm {
    /// The network of `neural` followed by holistic LM (exact Jacobian) over the entries `dofs`
    /// names (module docs).
    pub fn new(neural: NeuralFitter, dofs: Dofs) -> Result<Self, FitError> {
        let lm = lfit_fitters::build_fitter("lm", Preset::Nevergrad, Strategy::Holistic)?;
        Ok(Self {
            neural,
            lm: LmFitter(dofs.wrap(lm)),
            dofs,
        })
    }

    /// Evaluations the network leaves LM at the least (one for the data information with
    /// [`Dofs::holds_unobserved`], one for LM).
    fn lm_minimum(&self) -> usize {
        if self.dofs.holds_unobserved() { 2 } else { 1 }
    }

    /// LM's mask: the request's, without β where [`Dofs::holds_unobserved`] (the network's β is
    /// kept).
    fn lm_mask(&self, request: &FitRequest<'_>) -> DofMask {
        let mut mask = request.mask.clone();
        if self.dofs.holds_unobserved() {
            let shape = request.energy.template().layout().range(Block::Shape);
            mask.free.retain(|i| !shape.contains(i));
        }
        mask
    }
}

impl Fitter for NeuralThenLm {
    fn name(&self) -> String {
        let neural = self.neural.name();
        match self.dofs {
            Dofs::All => format!("{neural}+lm"),
            d => format!("{neural}+lm-{}", d.suffix()),
        }
    }

    fn fit(&self, request: &FitRequest<'_>) -> Result<FitResult, FitError> {
        self.fit_batch(std::slice::from_ref(request))?
            .pop()
            .ok_or_else(|| FitError::Neural("no result".into()))
    }

    /// One network pass for the batch, then LM on every frame from the network's result with
    /// the evaluations the network left of the budget. Evaluations, iterations, times and the
    /// trace are the sums of both stages; the iterates are the network's, then LM's result.
    fn fit_batch(&self, requests: &[FitRequest<'_>]) -> Result<Vec<FitResult>, FitError> {
        let network = self.neural.evaluations_per_fit();
        let least = network + self.lm_minimum();
        if let Some(r) = requests.iter().find(|r| r.budget < least) {
            let what = if self.dofs.holds_unobserved() {
                " (with --dofs observed: one for the data's information, one for LM)"
            } else {
                ""
            };
            return Err(FitError::Neural(format!(
                "budget {} leaves LM nothing after the network's {network} evaluations (neural+lm needs at least {least}{what})",
                r.budget,
            )));
        }
        let first = self.neural.fit_batch(requests)?;
        let mut out = Vec::with_capacity(requests.len());
        for (r, nn) in requests.iter().zip(first) {
            let refine = FitRequest {
                energy: r.energy,
                start: nn.pose.clone(),
                mask: self.lm_mask(r),
                bounds: r.bounds.clone(),
                budget: r.budget - nn.evaluations as usize,
                seed: r.seed,
                motion: None,
            };
            let lm = self.lm.0.fit(&refine)?;
            // LM keeps the best point it saw, which includes its start: never above the network.
            let (pose, energy, terms) = if lm.energy <= nn.energy {
                (lm.pose.clone(), lm.energy, lm.terms.clone())
            } else {
                (nn.pose.clone(), nn.energy, nn.terms.clone())
            };
            let mut trace = nn.trace.clone();
            let mut best = trace.last().map_or(f64::INFINITY, |&(_, e)| e);
            for &(k, e) in &lm.trace {
                if e < best {
                    trace.push((k + nn.evaluations, e));
                    best = e;
                }
            }
            let mut iterates = nn.iterates.clone();
            iterates.push(pose.clone());
            out.push(FitResult {
                method: self.name(),
                pose,
                energy,
                terms,
                evaluations: nn.evaluations + lm.evaluations,
                gradient_evaluations: nn.gradient_evaluations + lm.gradient_evaluations,
                iterations: nn.iterations + lm.iterations,
                time_s: nn.time_s + lm.time_s,
                trace,
                iterates,
            });
        }
        Ok(out)
    }
}
