//! The one fitting loop behind `lfit fit`, `lfit bench` and the quickstart (which runs bench):
//! the start of every frame (a sequence's warm start), its search box and free entries, the
//! start energy, batching, seeds and error context live here, once.

use std::path::Path;
use std::sync::Arc;

use anyhow::{Context, Result, bail};
use lfit_fitters::{FitRequest, FitResult, Fitter};
use lfit_model::energy::{Energy, EnergyConfig, Target};
use lfit_model::layout::Block;
use lfit_model::pose::{Bounds, DofMask, MaskKind};
use lfit_model::template::Template;
use lfit_synth::{Dataset, Observations, Scenario};

/// What every frame of one run shares.
pub struct Plan<'a> {
    pub dataset: &'a Dataset,
    pub template: &'a Arc<Template>,
    /// Evaluations per frame (a cap; exact for the zeroth-order methods).
    pub budget: usize,
    /// Frames per [`Fitter::fit_batch`] call outside sequences (sequences go one frame at a time:
    /// each frame needs its predecessor's result).
    pub batch: usize,
    /// The subject's shape β, when it is given rather than estimated (papers/002 §3.2, HMD).
    pub known_shape: Option<KnownShape>,
}

/// Where a known shape β comes from (`lfit fit --known-shape`, bench `known_shape`).
#[derive(Debug, Clone, PartialEq)]
pub enum KnownShape {
    /// Each frame's ground-truth β (synthetic data; papers/002 §3.2 uses the truth).
    Truth,
    /// One β for every frame (a subject measured beforehand).
    Given(Vec<f64>),
}

impl std::str::FromStr for KnownShape {
    type Err = anyhow::Error;
    /// `truth`, or the comma-separated β values.
    fn from_str(s: &str) -> Result<Self> {
        if s == "truth" {
            return Ok(Self::Truth);
        }
        let values = s
            .split(',')
            .map(|v| {
                v.trim()
                    .parse::<f64>()
                    .ok()
                    .filter(|x| x.is_finite())
                    .with_context(|| format!("--known-shape: '{v}' is not a finite number (expected 'truth' or comma-separated β values)"))
            })
            .collect::<Result<Vec<f64>>>()?;
        Ok(Self::Given(values))
    }
}

impl KnownShape {
    /// A strategy that can run with the shape frozen (`shape-first` fits the shape first).
    pub fn check_strategy(strategy: lfit_fitters::Strategy) -> Result<()> {
        if strategy == lfit_fitters::Strategy::ShapeFirst {
            bail!("strategy shape-first fits the shape first: it needs the shape free");
        }
        Ok(())
    }

    /// Checks the shape against the dataset and model before any fit runs.
    pub fn check(&self, dataset: &Dataset, template: &Template) -> Result<()> {
        let b = template.layout().shape;
        if b == 0 {
            bail!(
                "--known-shape: model '{}' has no shape parameters",
                template.id
            );
        }
        match self {
            Self::Truth if !dataset.has_ground_truth() => bail!(
                "--known-shape truth: the dataset has no ground truth (imported observations); give the subject's β as comma-separated values"
            ),
            Self::Given(v) if v.len() != b => bail!(
                "--known-shape: {} values given, model '{}' has {b} shape parameters",
                v.len(),
                template.id
            ),
            _ => Ok(()),
        }
    }

    /// β of `frame`.
    fn beta<'a>(&'a self, dataset: &'a Dataset, template: &Template, frame: usize) -> &'a [f64] {
        match self {
            Self::Truth => &dataset.gt_poses[frame][template.layout().range(Block::Shape)],
            Self::Given(v) => v,
        }
    }
}

impl Plan<'_> {
    /// The free entries of every fit: the scenario's, less the shape when it is known (the
    /// known shape is checked against the dataset and model here, before any fit).
    pub fn mask(&self) -> Result<DofMask> {
        let mask = scenario_mask(self.dataset.meta.config.scenario, self.template);
        let Some(k) = &self.known_shape else {
            return Ok(mask);
        };
        k.check(self.dataset, self.template)?;
        let shape = self.template.layout().range(Block::Shape);
        let mut known = DofMask::custom_in(
            mask.free
                .iter()
                .copied()
                .filter(|i| !shape.contains(i))
                .collect(),
            self.template.layout().dim(),
        )?;
        known.name = format!("{}-known-shape", mask.name);
        Ok(known)
    }

    /// Frames per [`Fitter::fit_batch`] call: `batch`, except in a sequence (one at a time).
    pub fn frames_per_call(&self) -> usize {
        if self.dataset.meta.config.scenario == Scenario::Sequence {
            1
        } else {
            self.batch.max(1)
        }
    }
}

/// One fitted frame.
pub struct FrameFit {
    pub frame: usize,
    pub seed: u64,
    /// The energy at the frame's start (not counted as an evaluation).
    pub start_energy: f64,
    pub result: FitResult,
}

/// Fits `frames` in order with `fitter` and hands each result to `sink`, in order.
///
/// A frame of a `sequence` dataset that directly follows the frame fitted before it starts from
/// that frame's result (papers/000 §4.3's warm start); every other frame starts from the
/// dataset's start pose. `energy` gives a frame's energy (its own copy: evaluation counters live
/// in the energy) and `seed` its seed.
pub fn fit_frames(
    fitter: &dyn Fitter,
    plan: &Plan<'_>,
    frames: &[usize],
    energy: &dyn Fn(usize) -> Result<Energy>,
    seed: &dyn Fn(usize) -> u64,
    sink: &mut dyn FnMut(FrameFit) -> Result<()>,
) -> Result<()> {
    let dataset = plan.dataset;
    let scenario = dataset.meta.config.scenario;
    let mask = plan.mask()?;
    let shape = plan.template.layout().range(Block::Shape);
    let chunk = plan.frames_per_call();
    let mut previous: Option<(usize, Vec<f64>)> = None;
    for group in frames.chunks(chunk) {
        let energies = group
            .iter()
            .map(|&f| energy(f))
            .collect::<Result<Vec<_>>>()?;
        let requests: Vec<FitRequest<'_>> = group
            .iter()
            .zip(&energies)
            .map(|(&frame, energy)| {
                let mut start = match previous.take() {
                    Some((p, pose)) if scenario == Scenario::Sequence && p + 1 == frame => pose,
                    _ => dataset.start_poses[frame].clone(),
                };
                let mut bounds = scenario_bounds(scenario, plan.template, &start);
                if let Some(k) = &plan.known_shape {
                    // β is fixed: the start holds it and the box is the single point.
                    for (i, &b) in shape.clone().zip(k.beta(dataset, plan.template, frame)) {
                        start[i] = b;
                        bounds.lower[i] = b;
                        bounds.upper[i] = b;
                    }
                }
                FitRequest {
                    energy,
                    bounds,
                    start,
                    mask: mask.clone(),
                    budget: plan.budget,
                    seed: seed(frame),
                }
            })
            .collect();
        let start_energies: Vec<f64> = requests
            .iter()
            .map(|r| r.energy.inspect(&r.start).total)
            .collect();
        let results = fitter.fit_batch(&requests).with_context(|| match group {
            [frame] => format!("{} on frame {frame}", fitter.name()),
            _ => format!(
                "{} on frames {}–{}",
                fitter.name(),
                group[0],
                group[group.len() - 1]
            ),
        })?;
        for (((&frame, result), request), start_energy) in
            group.iter().zip(results).zip(&requests).zip(start_energies)
        {
            previous = Some((frame, result.pose.clone()));
            sink(FrameFit {
                frame,
                seed: request.seed,
                start_energy,
                result,
            })?;
        }
    }
    Ok(())
}

/// The template a dataset was synthesised with: `--template DIR` when given (its id must match
/// the dataset's), else the procedural body named by the dataset's template id.
pub fn template_for(dataset: &Dataset, dir: Option<&Path>) -> Result<Arc<Template>> {
    let template = match dir {
        Some(d) => crate::data::load_model(Some(d), "default")?,
        None => {
            let id = &dataset.meta.template_id;
            let Some(shape) = crate::data::shape_of_template_id(id) else {
                bail!(
                    "dataset was made with template '{id}': pass that template with --template DIR"
                );
            };
            crate::data::load_model(None, shape)?
        }
    };
    let layout = template.layout();
    if template.id != dataset.meta.template_id
        || template.num_vertices() != dataset.meta.template_vertices
        || (layout.pose_dim(), layout.shape, layout.expression)
            != (
                dataset.meta.pose_dim,
                dataset.meta.shape_dim,
                dataset.meta.expression_dim,
            )
    {
        bail!(
            "dataset was made with template '{}' ({} vertices), not '{}' ({} vertices)",
            dataset.meta.template_id,
            dataset.meta.template_vertices,
            template.id,
            template.num_vertices()
        );
    }
    Ok(Arc::new(template))
}

/// The energy of frame `frame` of `dataset`.
pub fn energy_for_frame(
    dataset: &Dataset,
    template: Arc<Template>,
    frame: usize,
    config: EnergyConfig,
) -> Result<Energy> {
    if frame >= dataset.len() {
        bail!(
            "frame {frame} is out of range: the dataset has {} frames",
            dataset.len()
        );
    }
    let target = match &dataset.observations {
        Observations::Sparse { values, visible } => Target::Sparse {
            values: values[frame].clone(),
            visible: visible[frame].clone(),
        },
        Observations::Scan {
            grids, silhouettes, ..
        } => Target::Scan {
            grid: grids[frame].clone(),
            silhouettes: silhouettes[frame].clone(),
        },
        Observations::Silhouettes { masks } => Target::Silhouettes {
            masks: masks[frame].clone(),
        },
    };
    Energy::new(template, dataset.sensor.clone(), target, config)
        .with_context(|| format!("frame {frame}"))
}

/// Free entries of a scenario (papers/000 §4: 43 local, 41 global on the default template; the
/// same rules through the joint map on another model, with its shape and expression free).
pub fn scenario_mask(scenario: Scenario, template: &Template) -> DofMask {
    let kind = match scenario {
        Scenario::Global => MaskKind::Global,
        Scenario::Local | Scenario::Sequence => MaskKind::Local,
    };
    DofMask::standard(kind, template, true)
}

/// Search box of a scenario around a start (shape and expression within their own box).
pub fn scenario_bounds(scenario: Scenario, template: &Template, start: &[f64]) -> Bounds {
    match scenario {
        Scenario::Global => Bounds::global_for(template),
        Scenario::Local | Scenario::Sequence => Bounds::local_in(&template.layout(), start),
    }
}

/// The seed of one frame's fit: the run's seed mixed with the frame index.
pub fn frame_seed(seed: u64, frame: usize) -> u64 {
    seed ^ (frame as u64).wrapping_mul(0xD1B5_4A32_D192_ED03)
}

/// An error metric (`v2v_mm`, `mpjpe_mm`, ...) of every iterate of a fit against the truth.
pub fn iterate_errors(
    template: &Template,
    iterates: &[Vec<f64>],
    truth: &[f64],
    metric: fn(&Template, &[f64], &[f64]) -> f64,
) -> Vec<f64> {
    iterates
        .iter()
        .map(|p| metric(template, p, truth))
        .collect()
}
