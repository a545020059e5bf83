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
    /// How a sequence estimates β (ignored outside sequences and with a known shape).
    pub sequence_shape: SequenceShape,
}

/// How a sequence estimates the subject's shape β (`lfit fit --sequence-shape`, bench
/// `sequence_shape`). One subject has one β; fitting it afresh in every frame lets it drift with
/// each frame's errors (the learned fitter's β reached an RMS error of 2.8 on the captured clip,
/// worse than the prior's 1.0: `docs/results/learned-vs-classical.md`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum SequenceShape {
    /// β free in every frame's fit, carried by the warm start (papers/000 §4.3).
    #[default]
    PerFrame,
    /// A first pass fits up to [`FIRST_PASS_FRAMES`] frames spread evenly over the sequence,
    /// each on its own from the dataset's start pose with β free; the per-component median of
    /// their β is the subject's β, held fixed in the sequence pass. The first pass's time is
    /// shared out over the sequence's frames; its evaluations are reported apart
    /// ([`FitReport::shape_pass`]).
    FirstPass,
}

/// Frames of [`SequenceShape::FirstPass`]'s first pass, at most.
pub const FIRST_PASS_FRAMES: usize = 32;

impl SequenceShape {
    pub fn name(self) -> &'static str {
        match self {
            Self::PerFrame => "per-frame",
            Self::FirstPass => "first-pass",
        }
    }
}

impl std::str::FromStr for SequenceShape {
    type Err = anyhow::Error;
    fn from_str(s: &str) -> Result<Self> {
        match s {
            "per-frame" => Ok(Self::PerFrame),
            "first-pass" => Ok(Self::FirstPass),
            _ => bail!("unknown sequence shape policy '{s}' (expected per-frame or first-pass)"),
        }
    }
}

/// The first pass of [`SequenceShape::FirstPass`].
#[derive(Debug, Clone, serde::Serialize)]
pub struct ShapePass {
    /// The frames fitted on their own.
    pub frames: Vec<usize>,
    /// The subject's β: the per-component median of their fits.
    pub beta: Vec<f64>,
    pub evaluations: u64,
    pub time_s: f64,
}

/// What [`fit_frames`] did beyond the frames it handed to its sink.
#[derive(Debug, Clone, Default)]
pub struct FitReport {
    pub shape_pass: Option<ShapePass>,
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
        self.mask_with(self.known_shape.as_ref())
    }

    /// Whether this plan runs [`SequenceShape::FirstPass`]'s first pass: a sequence whose model
    /// has shape parameters that are not given.
    pub fn runs_shape_pass(&self) -> bool {
        self.sequence_shape == SequenceShape::FirstPass
            && self.dataset.meta.config.scenario == Scenario::Sequence
            && self.known_shape.is_none()
            && self.template.layout().shape > 0
    }

    fn mask_with(&self, known: Option<&KnownShape>) -> Result<DofMask> {
        let mask = scenario_mask(self.dataset.meta.config.scenario, self.template);
        let Some(k) = known else {
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
/// in the energy) and `seed` its seed. With [`SequenceShape::FirstPass`] a first pass estimates
/// the sequence's β before the frames are fitted with it fixed ([`FitReport::shape_pass`]).
pub fn fit_frames(
    fitter: &dyn Fitter,
    plan: &Plan<'_>,
    frames: &[usize],
    energy: &dyn Fn(usize) -> Result<Energy>,
    seed: &dyn Fn(usize) -> u64,
    sink: &mut dyn FnMut(FrameFit) -> Result<()>,
) -> Result<FitReport> {
    let dataset = plan.dataset;
    let scenario = dataset.meta.config.scenario;
    let mut report = FitReport::default();
    let mut known = plan.known_shape.clone();
    if plan.runs_shape_pass() && !frames.is_empty() {
        let pass = shape_pass(fitter, plan, frames, energy, seed)?;
        known = Some(KnownShape::Given(pass.beta.clone()));
        report.shape_pass = Some(pass);
    }
    // The first pass's time, shared out over the sequence's frames.
    let shared_time = report
        .shape_pass
        .as_ref()
        .map_or(0.0, |p| p.time_s / frames.len() as f64);
    let mask = plan.mask_with(known.as_ref())?;
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
                let start = match previous.take() {
                    Some((p, pose)) if scenario == Scenario::Sequence && p + 1 == frame => pose,
                    _ => dataset.start_poses[frame].clone(),
                };
                request(
                    plan,
                    known.as_ref(),
                    &mask,
                    frame,
                    start,
                    energy,
                    seed(frame),
                )
            })
            .collect();
        let start_energies: Vec<f64> = requests
            .iter()
            .map(|r| r.energy.inspect(&r.start).total)
            .collect();
        let results = fit_group(fitter, &requests, group)?;
        for (((&frame, mut result), request), start_energy) in
            group.iter().zip(results).zip(&requests).zip(start_energies)
        {
            previous = Some((frame, result.pose.clone()));
            result.time_s += shared_time;
            sink(FrameFit {
                frame,
                seed: request.seed,
                start_energy,
                result,
            })?;
        }
    }
    Ok(report)
}

/// The fit request of one frame from `start`: the scenario's box around it, β fixed where it
/// is known.
fn request<'e>(
    plan: &Plan<'_>,
    known: Option<&KnownShape>,
    mask: &DofMask,
    frame: usize,
    mut start: Vec<f64>,
    energy: &'e Energy,
    seed: u64,
) -> FitRequest<'e> {
    let scenario = plan.dataset.meta.config.scenario;
    let mut bounds = scenario_bounds(scenario, plan.template, &start);
    if let Some(k) = known {
        // β is fixed: the start holds it and the box is the single point.
        let shape = plan.template.layout().range(Block::Shape);
        for (i, &b) in shape.zip(k.beta(plan.dataset, plan.template, frame)) {
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
        seed,
    }
}

/// One [`Fitter::fit_batch`] call, its error naming the frames.
fn fit_group(
    fitter: &dyn Fitter,
    requests: &[FitRequest<'_>],
    group: &[usize],
) -> Result<Vec<FitResult>> {
    fitter.fit_batch(requests).with_context(|| match group {
        [frame] => format!("{} on frame {frame}", fitter.name()),
        _ => format!(
            "{} on frames {}–{}",
            fitter.name(),
            group[0],
            group[group.len() - 1]
        ),
    })
}

/// [`SequenceShape::FirstPass`]'s first pass: up to [`FIRST_PASS_FRAMES`] frames spread evenly
/// over `frames`, each fitted on its own from the dataset's start pose with β free (in batches of
/// the plan's `batch`); β is the per-component median of their fits.
fn shape_pass(
    fitter: &dyn Fitter,
    plan: &Plan<'_>,
    frames: &[usize],
    energy: &dyn Fn(usize) -> Result<Energy>,
    seed: &dyn Fn(usize) -> u64,
) -> Result<ShapePass> {
    let count = frames.len().min(FIRST_PASS_FRAMES);
    // Evenly spread: the i-th of `count` picks the middle of its share of the sequence.
    let picked: Vec<usize> = (0..count)
        .map(|i| frames[(2 * i + 1) * frames.len() / (2 * count)])
        .collect();
    let mask = plan.mask_with(None)?;
    let (mut evaluations, mut time_s) = (0u64, 0.0);
    let mut betas: Vec<Vec<f64>> = Vec::with_capacity(count);
    let shape = plan.template.layout().range(Block::Shape);
    for group in picked.chunks(plan.batch.max(1)) {
        let energies = group
            .iter()
            .map(|&f| energy(f))
            .collect::<Result<Vec<_>>>()?;
        let requests: Vec<FitRequest<'_>> = group
            .iter()
            .zip(&energies)
            .map(|(&frame, e)| {
                let start = plan.dataset.start_poses[frame].clone();
                request(plan, None, &mask, frame, start, e, seed(frame))
            })
            .collect();
        let results = fit_group(fitter, &requests, group)
            .context("the first pass of --sequence-shape first-pass")?;
        for r in results {
            evaluations += r.evaluations;
            time_s += r.time_s;
            betas.push(r.pose[shape.clone()].to_vec());
        }
    }
    let beta = (0..shape.len())
        .map(|k| {
            let mut v: Vec<f64> = betas.iter().map(|b| b[k]).collect();
            v.sort_by(f64::total_cmp);
            let n = v.len();
            if n % 2 == 1 {
                v[n / 2]
            } else {
                0.5 * (v[n / 2 - 1] + v[n / 2])
            }
        })
        .collect();
    Ok(ShapePass {
        frames: picked,
        beta,
        evaluations,
        time_s,
    })
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
    check_model(dataset, &template)?;
    Ok(Arc::new(template))
}

/// Checks that `template` is the model `dataset` was made with (id, vertex count and parameter
/// layout), so that its frames can be fitted with it.
pub fn check_model(dataset: &Dataset, template: &Template) -> Result<()> {
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
    Ok(())
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
