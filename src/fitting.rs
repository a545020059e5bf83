//! The one fitting loop behind `lfit fit`, `lfit bench` and the quickstart (which runs bench):
//! the start of every frame (a sequence's warm start), its search box and free entries, the
//! start energy, batching, seeds and error context live here, once.

use std::path::Path;
use std::sync::Arc;

use anyhow::{Context, Result, bail};
use lfit_fitters::{FitRequest, FitResult, Fitter};
use lfit_model::energy::{Energy, EnergyConfig, JacobianRows, RobustForm, Target};
use lfit_model::layout::Block;
use lfit_model::observe::Modality;
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
    /// Where a markers or keypoints2d sequence's points sit on the body (solved only with a
    /// joint β pass).
    pub marker_placement: MarkerPlacement,
}

/// Where a sequence's markers or 2D keypoints sit on the body (`lfit fit --marker-placement`,
/// Python `marker_placement=`, bench `marker_placement`). Real markers are not on the model's
/// marker vertices: they sit where the subject's suit or the operator put them, a marker's
/// radius off the skin. Markers observed off the model's set cost every fitter ~5 mm V2V at
/// 10 mm of slip and make a sequence's one β take up the placement
/// (`docs/results/captured-motion.md`, round 16). A detector's keypoints are not the
/// skeleton's joint centres either (a COCO hip is where annotators clicked on the outline).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum MarkerPlacement {
    /// On the model's marker vertices.
    #[default]
    Model,
    /// Each marker's rest-frame offset from its vertex, or each keypoint's from its joint's
    /// centre, solved per sequence with its β (MoSh, Loper et al. 2014, solves marker places,
    /// shape and poses together): within `--sequence-shape joint[:N]`'s β pass,
    /// [`MARKER_PLACEMENT_ROUNDS`] rounds of the offsets with the poses held (markers in closed
    /// form, [`lfit_model::energy::marker_offsets`], a Gaussian prior of
    /// [`MARKER_OFFSET_PRIOR_M`] at the marker set; keypoints by Gauss-Newton,
    /// [`lfit_model::energy::keypoint_offsets`], a prior of [`KEYPOINT_OFFSET_PRIOR_M`] at the
    /// joint centres) and β with the poses by the joint solve ([`joint_shape`]) with the offsets
    /// held; the sequence is then fitted with both. With `--known-shape` the sequence is fitted
    /// with the given β and the joint solves move the poses alone.
    Solved,
}

/// [`MarkerPlacement::Solved`]'s alternations of offsets and the joint β solve.
pub const MARKER_PLACEMENT_ROUNDS: usize = 3;

/// The prior scale of a marker's offset from its vertex in [`MarkerPlacement::Solved`] (metres).
pub const MARKER_OFFSET_PRIOR_M: f64 = 0.02;

/// The prior scale of a 2D keypoint's offset from its joint's centre in
/// [`MarkerPlacement::Solved`] (metres).
pub const KEYPOINT_OFFSET_PRIOR_M: f64 = 0.03;

/// What a sensor's point offsets are called (`"marker"` / `"keypoint"`: the `marker_offsets` /
/// `keypoint_offsets` of a shape pass or calibration file) and the prior scale (metres) the
/// placement solve and `lfit calibrate` give them; `None` for a sensor without point offsets.
pub fn point_offsets_of(modality: Modality) -> Option<(&'static str, f64)> {
    match modality {
        Modality::Markers => Some(("marker", MARKER_OFFSET_PRIOR_M)),
        Modality::Keypoints2d => Some(("keypoint", KEYPOINT_OFFSET_PRIOR_M)),
        _ => None,
    }
}

impl MarkerPlacement {
    pub fn name(self) -> &'static str {
        match self {
            Self::Model => "model",
            Self::Solved => "solve",
        }
    }
}

impl std::str::FromStr for MarkerPlacement {
    type Err = anyhow::Error;
    fn from_str(s: &str) -> Result<Self> {
        match s {
            "model" => Ok(Self::Model),
            "solve" => Ok(Self::Solved),
            _ => bail!("unknown marker placement '{s}' (expected model or solve)"),
        }
    }
}

/// How a sequence estimates the subject's shape β (`lfit fit --sequence-shape`, bench
/// `sequence_shape`). One subject has one β; fitting it afresh in every frame lets it drift with
/// each frame's errors (the learned fitter's β reached an RMS error of 2.8 on the captured clip,
/// worse than the prior's 1.0: `docs/results/learned-vs-classical.md`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum SequenceShape {
    /// β free in every frame's fit, carried by the warm start (papers/000 §4.3). The default:
    /// one β per sequence (`joint:64`) helps where the model explains the observations, but with
    /// markers that do not sit where the model's marker set puts them the solve takes the
    /// placement into β (`lfit synth --marker-slip-mm`: `docs/results/captured-motion.md`,
    /// round 16).
    #[default]
    PerFrame,
    /// A first pass fits up to [`FIRST_PASS_FRAMES`] frames spread evenly over the sequence,
    /// each on its own from the dataset's start pose with β free; the per-component median of
    /// their β is the subject's β, held fixed in the sequence pass. The first pass's time is
    /// shared out over the sequence's frames; its evaluations are reported apart
    /// ([`FitReport::shape_pass`]).
    FirstPass,
    /// The sequence is fitted twice. The first pass fits it as `per-frame` does; the subject's β
    /// is then the one that, with every frame's pose free from the first pass's result,
    /// minimises the summed energy of up to `frames` of its frames (spread evenly) with the
    /// shape prior counted once (Levenberg–Marquardt over those frames, the poses eliminated as
    /// in bundle adjustment: [`joint_shape`]), held fixed in the second pass. The most probable
    /// β of the sequence under the energy, rather than the median of noisy per-frame estimates.
    /// Needs an energy in least-squares form. The first pass and the β solve are reported apart
    /// ([`FitReport::shape_pass`]); their time is shared out over the frames. `joint` solves
    /// over up to [`JOINT_SHAPE_FRAMES`], `joint:N` over up to N.
    Joint { frames: usize },
}

/// Frames of [`SequenceShape::FirstPass`]'s first pass, at most.
pub const FIRST_PASS_FRAMES: usize = 32;

/// Frames of the β solve of `joint:64`, the sequences of the quickstart's clip and
/// `scripts/eval-captured.sh`. Round 6 of `docs/results/captured-motion.md`: solved over 64
/// frames of the captured clip's keypoints2d sequence β stayed below 1.0 (0.86), over 32 it
/// reached 0.98; the solve's time grows with its frames (~7 s over the clip's 454, two threads).
pub const FEW_JOINT_FRAMES: usize = 64;

impl SequenceShape {
    pub fn name(self) -> String {
        match self {
            Self::PerFrame => "per-frame".into(),
            Self::FirstPass => "first-pass".into(),
            Self::Joint {
                frames: JOINT_SHAPE_FRAMES,
            } => "joint".into(),
            Self::Joint { frames } => format!("joint:{frames}"),
        }
    }
}

impl std::str::FromStr for SequenceShape {
    type Err = anyhow::Error;
    fn from_str(s: &str) -> Result<Self> {
        let unknown = || {
            anyhow::anyhow!(
                "unknown sequence shape policy '{s}' (expected per-frame, first-pass, joint or joint:N with N frames ≥ 1)"
            )
        };
        Ok(match s {
            "per-frame" => Self::PerFrame,
            "first-pass" => Self::FirstPass,
            "joint" => Self::Joint {
                frames: JOINT_SHAPE_FRAMES,
            },
            _ => match s.strip_prefix("joint:").map(str::parse::<usize>) {
                Some(Ok(frames)) if frames >= 1 => Self::Joint { frames },
                _ => return Err(unknown()),
            },
        })
    }
}

/// The β pass of a [`SequenceShape`] other than `PerFrame`.
#[derive(Debug, Clone, serde::Serialize)]
pub struct ShapePass {
    /// The frames whose fits β was estimated from.
    pub frames: Vec<usize>,
    /// The subject's β: the per-component median of their fits (first pass), or the β that
    /// minimises their summed energy with the shape prior counted once (joint).
    pub beta: Vec<f64>,
    pub evaluations: u64,
    pub time_s: f64,
    /// Joint: the summed energy of the first pass's frames (the shape prior counted once)
    /// before and after the β solve, and its Levenberg–Marquardt iterations (with
    /// [`MarkerPlacement::Solved`]: before the first β solve, after the last, the markers then
    /// at their solved offsets; iterations and evaluations of every solve).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub joint: Option<JointSolve>,
    /// [`MarkerPlacement::Solved`] on markers: each marker's rest-frame offset from its vertex
    /// (metres), in the sensor's marker order.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub marker_offsets: Option<Vec<[f64; 3]>>,
    /// [`MarkerPlacement::Solved`] on keypoints2d: each keypoint's rest-frame offset from its
    /// joint's centre (metres), in the skeleton's joint order.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub keypoint_offsets: Option<Vec<[f64; 3]>>,
}

impl ShapePass {
    /// The solved offsets of the sensor's points ([`MarkerPlacement::Solved`]), if any.
    pub fn offsets(&self) -> Option<&Vec<[f64; 3]>> {
        self.marker_offsets
            .as_ref()
            .or(self.keypoint_offsets.as_ref())
    }
}

/// What [`joint_shape`]'s β solve did.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct JointSolve {
    pub energy_before: f64,
    pub energy_after: f64,
    pub iterations: usize,
    /// Energy evaluations of the solve (value, or residuals and Jacobian), over all frames.
    pub evaluations: u64,
}

/// `energy` with the gradient form of its terms ([`EnergyConfig::for_gradient`]: the hinge
/// joint-angle prior, no silhouette term) and its shape prior's weight times `shape_share`, for
/// [`joint_shape`]; a height prior ([`Energy::with_height_prior`]: one measurement of the one
/// subject, like the shape prior) kept with its weight times `shape_share` too, a floor
/// ([`Energy::with_floor`]) as it is. The joint-angle
/// prior depends on the pose alone: with the poses held, both forms move β alike.
fn least_squares_variant(energy: &Energy, shape_share: f64) -> Result<Energy> {
    let mut config = energy.config().clone().for_gradient();
    config.weights.shape *= shape_share;
    let variant = Energy::new(
        energy.template().clone(),
        energy.sensor().clone(),
        energy.target().clone(),
        config,
    )?;
    let variant = match energy.height_prior() {
        // Its weight goes as 1/σ².
        Some(p) => variant.with_height_prior(&p.with_std(p.std_m() / shape_share.sqrt())?)?,
        None => variant,
    };
    // The floor measures each frame's pose, as the data do: its weight stays.
    Ok(match energy.floor() {
        Some(f) => variant.with_floor(f)?,
        None => variant,
    })
}

/// What [`fit_frames`] did beyond the frames it handed to its sink.
#[derive(Debug, Clone, Default)]
pub struct FitReport {
    pub shape_pass: Option<ShapePass>,
}

/// Where a known shape β comes from (`lfit fit --known-shape`, bench `known_shape`), once the
/// model is known ([`KnownShapeArg::resolve`]).
#[derive(Debug, Clone, PartialEq)]
pub enum KnownShape {
    /// Each frame's ground-truth β (synthetic data; papers/002 §3.2 uses the truth).
    Truth,
    /// One β for every frame (a subject measured beforehand, or the β of a height).
    Given(Vec<f64>),
}

/// `--known-shape` as given: a [`KnownShape`], or the subject's height, which needs the model
/// to become one.
#[derive(Debug, Clone, PartialEq)]
pub enum KnownShapeArg {
    Shape(KnownShape),
    /// The subject's height in metres: the most likely β of that stature
    /// ([`lfit_model::stature::shape_for_height`]).
    Height(f64),
}

impl std::str::FromStr for KnownShapeArg {
    type Err = anyhow::Error;
    /// `truth`, `height:M` (metres), or the comma-separated β values.
    fn from_str(s: &str) -> Result<Self> {
        if s == "truth" {
            return Ok(Self::Shape(KnownShape::Truth));
        }
        if let Some(h) = s.strip_prefix("height:") {
            return h
                .trim()
                .parse::<f64>()
                .ok()
                .filter(|x| x.is_finite() && *x > 0.0)
                .map(Self::Height)
                .with_context(|| {
                    format!("--known-shape height:{h}: the subject's height must be a positive number of metres")
                });
        }
        let values = s
            .split(',')
            .map(|v| {
                v.trim()
                    .parse::<f64>()
                    .ok()
                    .filter(|x| x.is_finite())
                    .with_context(|| format!("--known-shape: '{v}' is not a finite number (expected 'truth', 'height:M' or comma-separated β values)"))
            })
            .collect::<Result<Vec<f64>>>()?;
        Ok(Self::Shape(KnownShape::Given(values)))
    }
}

impl KnownShapeArg {
    /// The shape on `template`: a height becomes the β of that height
    /// ([`lfit_model::stature::shape_for_height`]).
    pub fn resolve(&self, template: &Template) -> Result<KnownShape> {
        match self {
            Self::Shape(k) => Ok(k.clone()),
            Self::Height(h) => Ok(KnownShape::Given(
                lfit_model::stature::shape_for_height(template, *h)
                    .with_context(|| format!("--known-shape height:{h}"))?,
            )),
        }
    }
}

/// `--height-prior M[:STD]` or `truth[:STD]` (Python `height_prior=`, bench `height_prior`):
/// the subject's stature as a soft measurement beside the observations
/// ([`lfit_model::energy::HeightPrior`]), β otherwise estimated — where `--known-shape
/// height:M` fixes the most likely β of that height.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct HeightPriorArg {
    pub height: HeightOf,
    pub std_m: f64,
}

/// Whose height [`HeightPriorArg`] gives.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum HeightOf {
    /// One subject's, in metres.
    Metres(f64),
    /// Each frame's ground truth's rest height (synthetic data; a subject per frame).
    Truth,
}

/// The height prior's standard deviation when `--height-prior` gives none (metres): a
/// stature measured on the subject — a stadiometer's repeat measurements agree within about
/// half a centimetre, and the model's rest mesh is not the subject standing in the same
/// posture; a self-reported height is off by 2–3 cm on average (Gorber et al. 2007, Obesity
/// Reviews 8(4)) and wants `M:0.03`.
pub const HEIGHT_PRIOR_STD_M: f64 = 0.01;

impl std::str::FromStr for HeightPriorArg {
    type Err = anyhow::Error;
    /// `M`, `M:STD`, `truth` or `truth:STD` (metres).
    fn from_str(s: &str) -> Result<Self> {
        let (h, std) = match s.split_once(':') {
            Some((h, std)) => (h, Some(std)),
            None => (s, None),
        };
        let number = |v: &str| {
            v.trim()
                .parse::<f64>()
                .ok()
                .filter(|x| x.is_finite() && *x > 0.0)
        };
        let height = if h.trim() == "truth" {
            Some(HeightOf::Truth)
        } else {
            number(h).map(HeightOf::Metres)
        };
        let std_m = std.map_or(Some(HEIGHT_PRIOR_STD_M), number);
        match (height, std_m) {
            (Some(height), Some(std_m)) => Ok(Self { height, std_m }),
            _ => bail!(
                "--height-prior '{s}': expected the subject's height and optionally its standard deviation, positive numbers of metres (M or M:STD, e.g. 1.72 or 1.72:0.03; truth[:STD] for each frame's ground truth)"
            ),
        }
    }
}

impl HeightPriorArg {
    /// The result file's `height_prior`: `{"height_m": M | "truth", "std_m": STD}`.
    pub fn json(&self) -> serde_json::Value {
        let height = match self.height {
            HeightOf::Metres(m) => serde_json::json!(m),
            HeightOf::Truth => serde_json::json!("truth"),
        };
        serde_json::json!({ "height_m": height, "std_m": self.std_m })
    }
}

/// A [`HeightPriorArg`] on one model: the prior's vertices measured once, each frame's energy
/// given its prior ([`FrameHeights::apply`]).
#[derive(Debug, Clone)]
pub struct FrameHeights {
    base: lfit_model::energy::HeightPrior,
    truth: bool,
}

impl FrameHeights {
    /// `arg` on `template`; `truth` needs data with ground truth (`has_truth`). One-line errors
    /// for a model without shape coefficients and `truth` without ground truth.
    pub fn new(arg: HeightPriorArg, template: &Template, has_truth: bool) -> Result<Self> {
        use lfit_model::energy::HeightPrior;
        let (base, truth) = match arg.height {
            HeightOf::Metres(m) => (HeightPrior::new(template, m, arg.std_m), false),
            HeightOf::Truth if !has_truth => bail!(
                "--height-prior truth: the data have no ground truth (imported observations); give the subject's height in metres"
            ),
            // Each frame's height replaces the mean shape's (`apply`).
            HeightOf::Truth => (HeightPrior::at_mean_shape(template, arg.std_m), true),
        };
        Ok(Self {
            base: base.context("--height-prior")?,
            truth,
        })
    }

    /// `energy` with the prior of a frame whose ground-truth parameters are `truth` (read only
    /// for `truth`).
    pub fn apply(&self, energy: Energy, truth: Option<&[f64]>) -> Result<Energy> {
        let prior = if self.truth {
            let template = energy.template();
            let shape = template.layout().range(Block::Shape);
            let beta = truth
                .and_then(|t| t.get(shape))
                .context("--height-prior truth: a frame without ground truth")?;
            self.base.at(self.base.rest_height(template, beta))?
        } else {
            self.base.clone()
        };
        Ok(energy.with_height_prior(&prior)?)
    }

    /// The rest height of shape `beta` ([`lfit_model::energy::HeightPrior::rest_height`]).
    pub fn rest_height(&self, template: &Template, beta: &[f64]) -> f64 {
        self.base.rest_height(template, beta)
    }
}

/// `--floor FORM:HEIGHT[,MM]` (bench `floor`): the ground the subject stands on, a horizontal
/// plane at HEIGHT metres of the world's up axis (`+y`), as one more measurement of the lowest
/// sole ([`lfit_model::energy::FloorPrior`]) — `above` keeps every sole above it (one-sided),
/// `contact` puts the lowest sole on it; MM its standard deviation in millimetres (default
/// [`FLOOR_STD_M`]). HEIGHT `truth` (synthetic data): the median over the fitted frames of the
/// ground truth's lowest sole — the level the soles rest at, robust to frames in flight and to
/// retargeted feet that sink through the floor in some frames (a captured clip's lowest sole
/// spans −193 to +62 mm over 200 frames, its median −6; docs/results/captured-motion.md,
/// round 36).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FloorArg {
    pub form: lfit_model::energy::FloorForm,
    /// `None`: the ground truth's (`truth`).
    pub height_m: Option<f64>,
    pub std_m: f64,
}

/// The floor's standard deviation when `--floor` gives none (metres): a floor measured in the
/// capture's frame (a calibration board laid on it, or three points on it) is known to a few
/// millimetres, but the model's sole is not the subject's shoe (a sole 1–3 cm thick) nor is
/// every frame's lowest sole on the floor; 20 mm, measured against 10 and 40 on validation
/// motion (docs/results/captured-motion.md, round 36).
pub const FLOOR_STD_M: f64 = 0.02;

impl std::str::FromStr for FloorArg {
    type Err = anyhow::Error;
    /// `above:H`, `contact:H`, either with `,MM`; `H` metres or `truth`.
    fn from_str(s: &str) -> Result<Self> {
        let bad = || {
            anyhow::anyhow!(
                "--floor '{s}': expected FORM:HEIGHT[,MM] — FORM above or contact, HEIGHT the floor's height in metres on the world's up axis (or truth, for synthetic data), MM its standard deviation in millimetres (e.g. contact:0 or above:0.02,30)"
            )
        };
        let (form, rest) = s.split_once(':').ok_or_else(bad)?;
        let form: lfit_model::energy::FloorForm = form.trim().parse().map_err(|_| bad())?;
        let (height, std) = match rest.split_once(',') {
            Some((h, mm)) => (h, Some(mm)),
            None => (rest, None),
        };
        let height_m = match height.trim() {
            "truth" => None,
            h => Some(
                h.parse::<f64>()
                    .ok()
                    .filter(|x| x.is_finite())
                    .ok_or_else(bad)?,
            ),
        };
        let std_m = match std {
            Some(mm) => {
                mm.trim()
                    .parse::<f64>()
                    .ok()
                    .filter(|x| x.is_finite() && *x > 0.0)
                    .ok_or_else(bad)?
                    / 1000.0
            }
            None => FLOOR_STD_M,
        };
        Ok(Self {
            form,
            height_m,
            std_m,
        })
    }
}

impl FloorArg {
    /// The result file's `floor`: `{"form", "height_m": H | "truth", "std_m", "at_m"}` (`at_m`
    /// the height used).
    pub fn json(&self, at_m: f64) -> serde_json::Value {
        let height = match self.height_m {
            Some(m) => serde_json::json!(m),
            None => serde_json::json!("truth"),
        };
        serde_json::json!({
            "form": self.form.name(),
            "height_m": height,
            "std_m": self.std_m,
            "at_m": at_m,
        })
    }

    /// The floor on `template` at the given height (at 0 for `truth`, to be moved to the truth's
    /// soles with [`lfit_model::energy::FloorPrior::at`]).
    pub fn prior(&self, template: &Template) -> Result<lfit_model::energy::FloorPrior> {
        Ok(lfit_model::energy::FloorPrior::new(
            template,
            self.height_m.unwrap_or(0.0),
            self.std_m,
            self.form,
        )
        .context("--floor")?)
    }

    /// The floor on `template` for `frames` of `dataset`: at the given height, or (`truth`) at
    /// the median over those frames of the ground truth's lowest sole (the mean of the middle
    /// two for an even count). One-line errors for `truth` without ground truth and for a model
    /// without soles.
    pub fn resolve(
        &self,
        dataset: &Dataset,
        template: &Arc<Template>,
        frames: &[usize],
        config: &EnergyConfig,
    ) -> Result<lfit_model::energy::FloorPrior> {
        let floor = self.prior(template)?;
        if self.height_m.is_some() {
            return Ok(floor);
        }
        if !dataset.has_ground_truth() {
            bail!(
                "--floor truth: the data have no ground truth (imported observations); give the floor's height in metres"
            );
        }
        let mut lowest = Vec::with_capacity(frames.len());
        for &f in frames {
            let energy = energy_for_frame(dataset, template.clone(), f, config.clone())?;
            let truth = dataset
                .ground_truth(f)
                .context("--floor truth: a frame without ground truth")?;
            lowest.push(energy.lowest_sole(&floor, truth)?);
        }
        lowest.sort_by(f64::total_cmp);
        let n = lowest.len();
        if n == 0 {
            bail!("--floor truth: no frames to measure the floor on");
        }
        let median = if n % 2 == 1 {
            lowest[n / 2]
        } else {
            0.5 * (lowest[n / 2 - 1] + lowest[n / 2])
        };
        Ok(floor.at(median)?)
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

    /// Whether this plan runs a β pass (every [`SequenceShape`] but `PerFrame`): a sequence
    /// whose model has shape parameters that are not given.
    pub fn runs_shape_pass(&self) -> bool {
        self.sequence_shape != SequenceShape::PerFrame
            && self.dataset.meta.config.scenario == Scenario::Sequence
            && self.known_shape.is_none()
            && self.template.layout().shape > 0
    }

    /// Whether a pass runs before a sequence's frames are fitted: a β pass
    /// ([`Self::runs_shape_pass`]), or with β given (`--known-shape`) the placement pass of
    /// [`MarkerPlacement::Solved`] in `--sequence-shape joint[:N]`.
    pub fn runs_pass(&self) -> bool {
        self.runs_shape_pass()
            || (self.marker_placement == MarkerPlacement::Solved
                && self.known_shape.is_some()
                && self.dataset.meta.config.scenario == Scenario::Sequence
                && matches!(self.sequence_shape, SequenceShape::Joint { .. }))
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

    /// [`MarkerPlacement::Solved`] needs a markers or keypoints2d sequence and the joint β
    /// pass it runs in.
    pub fn check_marker_placement(&self) -> Result<()> {
        if self.marker_placement == MarkerPlacement::Model {
            return Ok(());
        }
        let modality = self.dataset.meta.config.modality;
        if !matches!(modality, Modality::Markers | Modality::Keypoints2d) {
            bail!(
                "--marker-placement solve places markers or 2D keypoints: the data's modality is {modality}"
            );
        }
        if !matches!(self.sequence_shape, SequenceShape::Joint { .. }) || !self.runs_pass() {
            bail!(
                "--marker-placement solve runs in the β pass of --sequence-shape joint[:N]: it needs a sequence dataset (β estimated, or given by --known-shape), with --sequence-shape joint or joint:N (got {})",
                self.sequence_shape.name()
            );
        }
        Ok(())
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
/// in the energy) and `seed` its seed. With a [`SequenceShape`] other than `PerFrame` a β pass
/// estimates the sequence's β before the frames are fitted with it fixed
/// ([`FitReport::shape_pass`]).
pub fn fit_frames(
    fitter: &dyn Fitter,
    plan: &Plan<'_>,
    frames: &[usize],
    energy: &dyn Fn(usize) -> Result<Energy>,
    seed: &dyn Fn(usize) -> u64,
    sink: &mut dyn FnMut(FrameFit) -> Result<()>,
) -> Result<FitReport> {
    let mut report = FitReport::default();
    plan.check_marker_placement()?;
    let mut known = plan.known_shape.clone();
    if plan.runs_shape_pass() && !frames.is_empty() {
        let pass = match plan.sequence_shape {
            SequenceShape::Joint { frames: count } => {
                joint_shape_pass(fitter, plan, frames, energy, seed, count, None)?
            }
            _ => shape_pass(fitter, plan, frames, energy, seed)?,
        };
        known = Some(KnownShape::Given(pass.beta.clone()));
        report.shape_pass = Some(pass);
    } else if let (MarkerPlacement::Solved, Some(given), SequenceShape::Joint { frames: count }) = (
        plan.marker_placement,
        &plan.known_shape,
        plan.sequence_shape,
    ) && !frames.is_empty()
    {
        // β given: the placement pass with the poses alone beside the offsets.
        let pass = joint_shape_pass(fitter, plan, frames, energy, seed, count, Some(given))?;
        report.shape_pass = Some(pass);
    }
    // The β pass's time, shared out over the sequence's frames.
    let shared_time = report
        .shape_pass
        .as_ref()
        .map_or(0.0, |p| p.time_s / frames.len() as f64);
    let offsets: Option<Vec<glam::DVec3>> = report
        .shape_pass
        .as_ref()
        .and_then(ShapePass::offsets)
        .map(|o| o.iter().map(|&d| glam::DVec3::from_array(d)).collect());
    let placed = |f: usize| -> Result<Energy> {
        let e = energy(f)?;
        match &offsets {
            Some(o) => Ok(e.with_offsets(o)?),
            None => Ok(e),
        }
    };
    fit_pass(
        fitter,
        plan,
        frames,
        known.as_ref(),
        &placed,
        seed,
        &mut |mut f| {
            f.result.time_s += shared_time;
            sink(f)
        },
    )?;
    Ok(report)
}

/// One pass of [`fit_frames`] over `frames` with the shape `known` (if any).
fn fit_pass(
    fitter: &dyn Fitter,
    plan: &Plan<'_>,
    frames: &[usize],
    known: Option<&KnownShape>,
    energy: &dyn Fn(usize) -> Result<Energy>,
    seed: &dyn Fn(usize) -> u64,
    sink: &mut dyn FnMut(FrameFit) -> Result<()>,
) -> Result<()> {
    let dataset = plan.dataset;
    let scenario = dataset.meta.config.scenario;
    let mask = plan.mask_with(known)?;
    let chunk = plan.frames_per_call();
    let mut previous: Option<(usize, Vec<f64>)> = None;
    // How fast the chain's fits have moved (the temporal anchor widens by it).
    let mut motion = lfit_fitters::SequenceMotion::default();
    for group in frames.chunks(chunk) {
        let energies = group
            .iter()
            .map(|&f| energy(f))
            .collect::<Result<Vec<_>>>()?;
        // Which requests start from the previous frame's fit (their start is that fit).
        let mut warm_starts: Vec<bool> = Vec::with_capacity(group.len());
        let requests: Vec<FitRequest<'_>> = group
            .iter()
            .zip(&energies)
            .map(|(&frame, energy)| {
                let (start, warm) = match previous.take() {
                    Some((p, pose)) if scenario == Scenario::Sequence && p + 1 == frame => {
                        (pose, true)
                    }
                    _ => (dataset.start_poses[frame].clone(), false),
                };
                if !warm {
                    motion.reset();
                }
                warm_starts.push(warm);
                let mut r = request(
                    plan,
                    known,
                    &mask,
                    frame,
                    (start, warm),
                    energy,
                    seed(frame),
                );
                // A chained frame always carries a motion (zero before the chain's first
                // change): the temporal anchor's translation default reads it.
                r.motion = warm.then(|| motion.rms().unwrap_or_else(|| vec![0.0; r.start.len()]));
                r
            })
            .collect();
        let start_energies: Vec<f64> = requests
            .iter()
            .map(|r| r.energy.inspect(&r.start).total)
            .collect();
        let results = fit_group(fitter, &requests, group)?;
        for ((((&frame, result), request), start_energy), warm) in group
            .iter()
            .zip(results)
            .zip(&requests)
            .zip(start_energies)
            .zip(warm_starts)
        {
            if warm {
                motion.update(&request.start, &result.pose);
            }
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

/// The fit request of one frame from `start` (`warm`: the previous frame's fit in a sequence):
/// the scenario's box around it, β fixed where it is known. A sequence frame that does not start
/// from the previous frame's fit (the first frame, a β pass's frames) is searched in the global
/// box around its start ([`scenario_bounds`]): the sequence box describes a frame's
/// neighbourhood of the previous one, and the dataset's start of an imported sequence is the rest
/// pose aligned rigidly to the data (from it the sequence box left a C3D import's first frames
/// 108 → 4 mm off over its first 9 frames: `docs/results/captured-motion.md`, round 16).
fn request<'e>(
    plan: &Plan<'_>,
    known: Option<&KnownShape>,
    mask: &DofMask,
    frame: usize,
    (mut start, warm): (Vec<f64>, bool),
    energy: &'e Energy,
    seed: u64,
) -> FitRequest<'e> {
    let scenario = match plan.dataset.meta.config.scenario {
        Scenario::Sequence if !warm => Scenario::Global,
        s => s,
    };
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
        motion: None,
    }
}

/// One [`Fitter::fit_batch`] call, its error naming the frames. The call runs on one of
/// rayon's threads (inline where this is one already, as under `lfit`'s commands): a batch's
/// parallel loops then share their work from inside the pool instead of each being handed to
/// it from outside and waited for (a caller of the library, as the Python package, is not on
/// one).
fn fit_group(
    fitter: &dyn Fitter,
    requests: &[FitRequest<'_>],
    group: &[usize],
) -> Result<Vec<FitResult>> {
    rayon::scope(|_| fitter.fit_batch(requests)).with_context(|| match group {
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
    let picked: Vec<usize> = spread(frames.len(), FIRST_PASS_FRAMES)
        .into_iter()
        .map(|k| frames[k])
        .collect();
    let mask = plan.mask_with(None)?;
    let (mut evaluations, mut time_s) = (0u64, 0.0);
    let mut betas: Vec<Vec<f64>> = Vec::with_capacity(picked.len());
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
                request(plan, None, &mask, frame, (start, false), e, seed(frame))
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
    let beta = median_per_component(betas.iter().map(Vec::as_slice), shape.len());
    Ok(ShapePass {
        frames: picked,
        beta,
        evaluations,
        time_s,
        joint: None,
        marker_offsets: None,
        keypoint_offsets: None,
    })
}

/// Up to `count` of the positions `0..len`, evenly spread: the i-th picks the middle of its share
/// (every position when `len ≤ count`). The frames of a β pass.
fn spread(len: usize, count: usize) -> Vec<usize> {
    let count = len.min(count);
    (0..count)
        .map(|i| (2 * i + 1) * len / (2 * count))
        .collect()
}

/// The per-component median of `rows` (each `n` long; the mean of the two middle values for an
/// even count): the β of [`shape_pass`] and [`joint_shape`]'s start.
fn median_per_component<'a>(rows: impl Iterator<Item = &'a [f64]> + Clone, n: usize) -> Vec<f64> {
    (0..n)
        .map(|k| {
            let mut v: Vec<f64> = rows.clone().map(|r| r[k]).collect();
            v.sort_by(f64::total_cmp);
            0.5 * (v[(v.len() - 1) / 2] + v[v.len() / 2])
        })
        .collect()
}

/// [`SequenceShape::Joint`]'s β pass: the sequence fitted with β free in every frame, then
/// [`joint_shape`] over up to `count` of its frames, spread evenly.
///
/// With `known` (a β given, [`MarkerPlacement::Solved`] only) the sequence is fitted with that β
/// and the solves move the poses alone beside the offsets (β stays the given one).
fn joint_shape_pass(
    fitter: &dyn Fitter,
    plan: &Plan<'_>,
    frames: &[usize],
    energy: &dyn Fn(usize) -> Result<Energy>,
    seed: &dyn Fn(usize) -> u64,
    count: usize,
    known: Option<&KnownShape>,
) -> Result<ShapePass> {
    if let Some(why) = least_squares_variant(&energy(frames[0])?, 1.0)?.least_squares_unsupported()
    {
        bail!("--sequence-shape joint solves for β in least-squares form: {why}");
    }
    let (mut evaluations, mut time_s) = (0u64, 0.0);
    let mut poses: Vec<Vec<f64>> = Vec::with_capacity(frames.len());
    fit_pass(fitter, plan, frames, known, energy, seed, &mut |f| {
        evaluations += f.result.evaluations;
        time_s += f.result.time_s;
        poses.push(f.result.pose);
        Ok(())
    })
    .context("the first pass of --sequence-shape joint")?;
    let timer = std::time::Instant::now();
    let picked = spread(frames.len(), count);
    let energies = picked
        .iter()
        .map(|&k| energy(frames[k]))
        .collect::<Result<Vec<_>>>()?;
    let poses: Vec<Vec<f64>> = picked.iter().map(|&k| poses[k].clone()).collect();
    let full_shape = plan.template.layout().range(Block::Shape);
    // With β given, none of it is solved for (the poses keep theirs).
    let shape = match known {
        Some(_) => full_shape.start..full_shape.start,
        None => full_shape.clone(),
    };
    let free = plan.mask_with(known)?.free;
    // Each frame in the scenario's box around its first-pass result (a sequence's fits have no
    // other: the joint limits are EA's, a soft prior, and the root goes where the motion goes).
    let scenario = plan.dataset.meta.config.scenario;
    let bounds: Vec<Bounds> = poses
        .iter()
        .map(|p| scenario_bounds(scenario, plan.template, p))
        .collect();
    let modality = plan.dataset.meta.config.modality;
    let (beta, solve, offsets) = match plan.marker_placement {
        MarkerPlacement::Model => {
            let (beta, _, solve) = joint_shape(&energies, &poses, shape, &free, &bounds)?;
            (beta, solve, None)
        }
        MarkerPlacement::Solved => {
            // joint's β pass with the markers on the model's vertices (the keypoints at the
            // joint centres), then rounds of the offsets with the poses held and β with the
            // poses with the offsets held; the last round's joint solve is the pass's. (Offsets
            // first, from the per-frame fits, took up their β errors: on the clip without slip
            // β RMS 0.41 -> 0.88.)
            let (beta, mut poses, first) =
                joint_shape(&energies, &poses, shape.clone(), &free, &bounds)?;
            let mut placed = energies;
            let mut evaluations = first.evaluations;
            let mut iterations = first.iterations;
            let mut last = (beta, first);
            let mut offsets = Vec::new();
            let (_, prior) = point_offsets_of(modality).with_context(|| {
                format!("--marker-placement solve: {modality} has no points to place")
            })?;
            for _ in 0..MARKER_PLACEMENT_ROUNDS {
                offsets = lfit_model::energy::point_offsets(&placed, &poses, prior)
                    .context("--marker-placement solve")?;
                placed = placed
                    .iter()
                    .map(|e| e.with_offsets(&offsets))
                    .collect::<std::result::Result<Vec<_>, _>>()?;
                let (beta, next, solve) =
                    joint_shape(&placed, &poses, shape.clone(), &free, &bounds)?;
                poses = next;
                evaluations += solve.evaluations;
                iterations += solve.iterations;
                last = (beta, solve);
            }
            // The pass's solve: from the energy before the first β solve to the last one's
            // result, iterations and evaluations over all of them.
            let (beta, mut solve) = last;
            solve.energy_before = first.energy_before;
            solve.iterations = iterations;
            solve.evaluations = evaluations;
            (
                beta,
                solve,
                Some(offsets.iter().map(|d| d.to_array()).collect()),
            )
        }
    };
    // β given: the pass reports the β it fitted with (the first picked frame's).
    let beta = match known {
        Some(_) => poses[0][full_shape].to_vec(),
        None => beta,
    };
    evaluations += solve.evaluations;
    time_s += timer.elapsed().as_secs_f64();
    Ok(ShapePass {
        frames: picked.iter().map(|&k| frames[k]).collect(),
        beta,
        evaluations,
        time_s,
        joint: Some(solve),
        keypoint_offsets: offsets
            .clone()
            .filter(|_| modality == Modality::Keypoints2d),
        marker_offsets: offsets.filter(|_| modality == Modality::Markers),
    })
}

/// Iterations of [`joint_shape`]'s Levenberg–Marquardt, at most.
pub const JOINT_SHAPE_ITERATIONS: usize = 50;

/// Frames of [`SequenceShape::Joint`]'s β solve, at most (spread evenly over the sequence): its
/// memory (a frame's blocks of the normal equations, ~90 KB on the MakeHuman body) and time grow
/// with them. Ours: the captured clip's 454 frames fit under it; solving on 256, 128, 64 or 32
/// of them moved the clip's β RMS by up to 0.4 and V2V by up to 3 mm either way
/// (`docs/results/captured-motion.md`, round 6).
pub const JOINT_SHAPE_FRAMES: usize = 512;

/// What [`joint_shape`] returns: the sequence's β, every frame's pose with it, and the solve.
pub type JointShape = (Vec<f64>, Vec<Vec<f64>>, JointSolve);

/// The β (entries `shape` of every pose) and the poses that together minimise the sequence's
/// energy, from `poses` (each frame's fit with β free) and the per-component median of their β:
/// one β for every frame, each frame's other `free` entries its own, each frame inside its own
/// box (`bounds[k]`; β inside every frame's shape box).
///
/// The sequence's energy is `Σ_k E_k(θ_k)` with the shape prior (and a height prior) counted
/// once, not once per frame: each frame's energy carries the prior `w‖β‖²` for a β seen by that frame alone, and
/// summing N of them would weigh the one subject's prior N times against the data (the
/// per-frame estimate's shrinkage towards the mean, however long the sequence), where the
/// posterior of one β given N frames' independent observations has it once (each frame's prior
/// weight is `w / N` here). The poses are free with β: held at fits made with another β, they
/// would carry that β's errors (a bone too short bent into the joints) into the solve.
///
/// Levenberg–Marquardt on the whole sequence, as bundle adjustment solves cameras and points
/// (Triggs et al. 2000, §6.1): each frame's normal equations `[A_k B_k; B_kᵀ C_k]` (pose, β),
/// the poses eliminated frame by frame (the Schur complement `Σ_k C_k − B_kᵀ A_k⁻¹ B_k` on β,
/// then each frame's pose step), Marquardt scaling, Nielsen's damping update, a step that leaves
/// the box clamped to it; stops when a step lowers the energy by less than 1e-6 of it, or after
/// [`JOINT_SHAPE_ITERATIONS`]. Frames are evaluated in parallel, each on the least-squares form
/// of its energy ([`least_squares_variant`]); [`JointSolve::evaluations`] counts them,
/// [`JointSolve::energy_before`] and `energy_after` are the sequence's energy.
pub fn joint_shape(
    energies: &[Energy],
    poses: &[Vec<f64>],
    shape: std::ops::Range<usize>,
    free: &[usize],
    bounds: &[Bounds],
) -> Result<JointShape> {
    use nalgebra::DMatrix;
    use rayon::prelude::*;
    let n = shape.len();
    let dim = poses.first().map_or(0, Vec::len);
    if energies.is_empty()
        || energies.len() != poses.len()
        || bounds.len() != poses.len()
        || poses.iter().any(|p| p.len() != dim)
        || bounds
            .iter()
            .any(|b| b.lower.len() != dim || b.upper.len() != dim)
        || shape.end > dim
    {
        bail!(
            "joint β solve: {} energies, {} poses, {} boxes, shape entries {shape:?}",
            energies.len(),
            poses.len(),
            bounds.len()
        );
    }
    // Their least-squares form (and their own evaluation counters), the prior once in all.
    let share = 1.0 / energies.len() as f64;
    let energies = energies
        .iter()
        .map(|e| least_squares_variant(e, share))
        .collect::<Result<Vec<_>>>()?;
    // The system's entries: each frame's free pose entries, in the skeleton's elimination order
    // (children before parents: the envelope factorisation of a pose block has no fill), then β.
    let rank = energies[0].template().elimination_rank();
    let mut pose_free: Vec<usize> = free
        .iter()
        .copied()
        .filter(|i| !shape.contains(i))
        .collect();
    pose_free.sort_by_key(|&i| rank.get(i).copied().unwrap_or(usize::MAX));
    let np = pose_free.len();
    let dofs: Vec<usize> = pose_free.iter().copied().chain(shape.clone()).collect();
    // β's box: every frame's shape box at once.
    let beta_box: Vec<(f64, f64)> = shape
        .clone()
        .map(|i| {
            bounds
                .iter()
                .fold((f64::NEG_INFINITY, f64::INFINITY), |(l, u), b| {
                    (l.max(b.lower[i]), u.min(b.upper[i]))
                })
        })
        .collect();
    if beta_box.iter().any(|(l, u)| l > u) {
        bail!("joint β solve: the frames' shape boxes do not overlap");
    }
    let clamp_beta = |k: usize, v: f64| v.clamp(beta_box[k].0, beta_box[k].1);
    let mut beta = median_per_component(poses.iter().map(|p| &p[shape.clone()]), n);
    for (k, b) in beta.iter_mut().enumerate() {
        *b = clamp_beta(k, *b);
    }
    let mut poses: Vec<Vec<f64>> = poses
        .iter()
        .zip(bounds)
        .map(|(p, b)| {
            let mut q = p.clone();
            b.clamp(&mut q);
            q[shape.clone()].copy_from_slice(&beta);
            q
        })
        .collect();
    let total = |poses: &[Vec<f64>]| -> f64 {
        energies
            .par_iter()
            .zip(poses)
            .map(|(e, p)| e.evaluate(p).total)
            .sum()
    };
    let before = total(&poses);
    let mut current = before;
    let (mut damping, mut nu) = (1e-4, 2.0);
    let mut iterations = 0;
    while iterations < JOINT_SHAPE_ITERATIONS {
        iterations += 1;
        // Each frame's blocks: A (pose), B (pose × β), C (β), and the gradient's two parts.
        let systems: Vec<FrameSystem> = energies
            .par_iter()
            .zip(&poses)
            .map(|(e, p)| -> Result<_> {
                let (h, g) = e
                    .least_squares_with(p, true, RobustForm::Folded, JacobianRows::Factored)?
                    .normal_equations(&dofs);
                Ok((
                    h.view((0, 0), (np, np)).into_owned(),
                    h.view((0, np), (np, n)).into_owned(),
                    h.view((np, np), (n, n)).into_owned(),
                    g.rows(0, np).into_owned(),
                    g.rows(np, n).into_owned(),
                ))
            })
            .collect::<Result<_>>()?;
        let summed_c = systems
            .iter()
            .fold(DMatrix::zeros(n, n), |s, (_, _, c, _, _)| s + c);
        let mut improved = false;
        // Raise the damping until a step lowers the energy (at most 20 tries).
        for _ in 0..20 {
            let step = schur_step(&systems, &summed_c, damping);
            let Some((dbeta, dposes)) = step else {
                damping *= nu;
                nu *= 2.0;
                continue;
            };
            let trial_beta: Vec<f64> = (0..n).map(|k| clamp_beta(k, beta[k] + dbeta[k])).collect();
            let trial: Vec<Vec<f64>> = poses
                .iter()
                .zip(&dposes)
                .zip(bounds)
                .map(|((p, d), b)| {
                    let mut q = p.clone();
                    for (k, &i) in pose_free.iter().enumerate() {
                        q[i] = (q[i] + d[k]).clamp(b.lower[i], b.upper[i]);
                    }
                    q[shape.clone()].copy_from_slice(&trial_beta);
                    q
                })
                .collect();
            let value = total(&trial);
            if value.is_finite() && value < current {
                let gain = (current - value) / current.max(f64::MIN_POSITIVE);
                beta = trial_beta;
                poses = trial;
                current = value;
                damping = (damping / 3.0).max(1e-12);
                nu = 2.0;
                improved = gain >= 1e-6;
                break;
            }
            damping *= nu;
            nu *= 2.0;
        }
        if !improved {
            break;
        }
    }
    let evaluations = energies.iter().map(Energy::evaluations).sum();
    Ok((
        beta,
        poses,
        JointSolve {
            energy_before: before,
            energy_after: current,
            iterations,
            evaluations,
        },
    ))
}

/// One frame's blocks of the sequence's normal equations in [`joint_shape`]: `A` (pose),
/// `B` (pose × β), `C` (β), and the gradient's pose and β parts.
type FrameSystem = (
    nalgebra::DMatrix<f64>,
    nalgebra::DMatrix<f64>,
    nalgebra::DMatrix<f64>,
    nalgebra::DVector<f64>,
    nalgebra::DVector<f64>,
);

/// The damped Gauss-Newton step of [`joint_shape`]'s sequence system by the Schur complement on
/// β: with `Ã_k = A_k + μ D_k` (`D` Marquardt's scaling, damped as
/// [`lfit_model::energy::damped_step`] damps),
/// `(Σ_k C̃_k − B_kᵀ Ã_k⁻¹ B_k) Δβ = −Σ_k (g_β,k − B_kᵀ Ã_k⁻¹ g_θ,k)`, then
/// `Δθ_k = −Ã_k⁻¹ (g_θ,k + B_k Δβ)`. `None` when a system is not positive definite.
fn schur_step(
    systems: &[FrameSystem],
    summed_c: &nalgebra::DMatrix<f64>,
    damping: f64,
) -> Option<(nalgebra::DVector<f64>, Vec<nalgebra::DVector<f64>>)> {
    use lfit_model::energy::{DampedFactor, marquardt_scaling};
    use nalgebra::{DMatrix, DVector};
    use rayon::prelude::*;
    let n = summed_c.nrows();
    // Per frame: Ã⁻¹ [B | g_θ].
    let solved: Vec<DMatrix<f64>> = systems
        .par_iter()
        .map(|(a, b, _, gt, _)| {
            let np = a.nrows();
            // The pose entries come in the skeleton's elimination order, so the envelope
            // factorisation has no fill (`damped_step`'s reasoning).
            let all: Vec<usize> = (0..np).collect();
            let (diag, max) = marquardt_scaling(a, &all);
            let factor = DampedFactor::new(a, &all, &diag, damping, max)?;
            let mut x = DMatrix::zeros(np, n + 1);
            for k in 0..=n {
                let mut column: Vec<f64> = if k < n {
                    b.column(k).iter().copied().collect()
                } else {
                    gt.iter().copied().collect()
                };
                if !factor.solve(&mut column) {
                    return None;
                }
                x.column_mut(k).copy_from_slice(&column);
            }
            Some(x)
        })
        .collect::<Option<_>>()?;
    let mut s = summed_c.clone();
    let (diag, max) = marquardt_scaling(summed_c, &(0..n).collect::<Vec<_>>());
    for i in 0..n {
        s[(i, i)] += damping * diag[i] + 1e-12 * max;
    }
    let mut rhs = DVector::zeros(n);
    for ((_, b, _, _, gb), x) in systems.iter().zip(&solved) {
        let ainv_b = x.view((0, 0), (x.nrows(), n));
        let ainv_g = x.column(n);
        s -= b.transpose() * ainv_b;
        rhs -= gb - b.transpose() * ainv_g;
    }
    // Symmetric up to rounding: its lower triangle is what the factorisation reads.
    let dbeta = s.cholesky()?.solve(&rhs);
    let dposes = solved
        .iter()
        .map(|x| {
            let ainv_b = x.view((0, 0), (x.nrows(), n));
            -(x.column(n) + ainv_b * &dbeta)
        })
        .collect();
    Some((dbeta, dposes))
}

/// The template a dataset was synthesised with: `--model` when given (its id must match the
/// dataset's), else the procedural body named by the dataset's template id, else the shipped
/// model file of that id (`models/<id>.npz`, found as every shipped path is: the MakeHuman body
/// and face).
pub fn template_for(dataset: &Dataset, dir: Option<&Path>) -> Result<Arc<Template>> {
    let template = match dir {
        Some(d) => crate::data::load_model(Some(d), "default")?,
        None => {
            let id = &dataset.meta.template_id;
            match crate::data::shape_of_template_id(id) {
                Some(shape) => crate::data::load_model(None, shape)?,
                None => match shipped_model(id) {
                    Some(path) => crate::data::load_model(Some(&path), "default")?,
                    None => bail!(
                        "dataset was made with model '{id}', which is not a shipped one: pass it with --model (its model file or template directory)"
                    ),
                },
            }
        }
    };
    check_model(dataset, &template)?;
    Ok(Arc::new(template))
}

/// `models/<id>.npz` where the shipped data are found, for a plain model id (letters, digits,
/// `-`, `_`, `+`, `.`; not a path).
fn shipped_model(id: &str) -> Option<std::path::PathBuf> {
    let plain = !id.is_empty()
        && !id.starts_with('.')
        && id
            .chars()
            .all(|c| c.is_ascii_alphanumeric() || "-_+.".contains(c));
    if !plain {
        return None;
    }
    crate::shipped::locate(&Path::new("models").join(format!("{id}.npz"))).ok()
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

/// [`energy_for_frame`] with the frame's height prior where `heights` gives one
/// ([`FrameHeights::apply`], `--height-prior`) and the floor where `floor` gives one
/// ([`Energy::with_floor`], `--floor`): what `lfit fit` and the bench fit.
pub fn energy_with_priors(
    dataset: &Dataset,
    template: Arc<Template>,
    frame: usize,
    config: EnergyConfig,
    heights: Option<&FrameHeights>,
    floor: Option<&lfit_model::energy::FloorPrior>,
) -> Result<Energy> {
    let energy = energy_for_frame(dataset, template, frame, config)?;
    let energy = match heights {
        Some(h) => h.apply(energy, dataset.ground_truth(frame))?,
        None => energy,
    };
    Ok(match floor {
        Some(f) => energy.with_floor(f)?,
        None => energy,
    })
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

/// Search box of a scenario around a start (shape and expression within their own box): the
/// local box around it, or the global one ([`Bounds::global_around`]: the model's rotation limits,
/// the translation within ±1.25 m of the start's, which is the origin for synthetic global frames
/// and the rigid alignment to the data for imported ones).
pub fn scenario_bounds(scenario: Scenario, template: &Template, start: &[f64]) -> Bounds {
    match scenario {
        Scenario::Global => Bounds::global_around(template, start),
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

/// V2V of each iterate of a fit against the truth, the truth's mesh posed once
/// ([`lfit_model::metrics::TruthMesh`]); an iterate equal to the fit's `result`, whose V2V is
/// `result_v2v`, is not posed again. The figures of [`iterate_errors`] with
/// [`lfit_model::metrics::v2v_mm`], bit for bit, from one mesh per distinct pose instead of two
/// per iterate.
pub fn iterate_v2v(
    template: &Template,
    iterates: &[Vec<f64>],
    truth: &lfit_model::metrics::TruthMesh,
    result: &[f64],
    result_v2v: f64,
) -> Vec<f64> {
    iterates
        .iter()
        .map(|p| {
            if p.as_slice() == result {
                result_v2v
            } else {
                truth.v2v_mm(template, p)
            }
        })
        .collect()
}

#[cfg(test)]
#[allow(clippy::unwrap_used)]
pub(crate) mod tests {
    use super::*;
    use lfit_model::observe::{Modality, Sensor};
    use lfit_synth::{SynthConfig, synthesize};

    /// `--height-prior`'s forms ([`HeightPriorArg`]) and [`FrameHeights`]: metres or each
    /// frame's truth (refused without ground truth), the prior in the frame's energy at the
    /// truth's rest height; the joint β solve's variant keeps it at the shape prior's share.
    #[test]
    fn a_height_prior_reaches_each_frame_s_energy_and_the_joint_solve() {
        for (text, want) in [
            ("1.72", (HeightOf::Metres(1.72), HEIGHT_PRIOR_STD_M)),
            ("1.72:0.03", (HeightOf::Metres(1.72), 0.03)),
            ("truth", (HeightOf::Truth, HEIGHT_PRIOR_STD_M)),
            ("truth:0.02", (HeightOf::Truth, 0.02)),
        ] {
            let arg: HeightPriorArg = text.parse().unwrap();
            assert_eq!((arg.height, arg.std_m), want, "{text}");
        }
        for bad in [
            "",
            "tall",
            "1.7:",
            "1.7:-1",
            "0",
            "nan",
            "truth:0",
            "1.7:0.01:2",
        ] {
            let err = bad.parse::<HeightPriorArg>().unwrap_err().to_string();
            assert!(err.starts_with(&format!("--height-prior '{bad}'")), "{err}");
        }
        let (t, _) = lfit_model::body::morphable_default_template().unwrap();
        let t = Arc::new(t);
        let config = SynthConfig::new(Modality::Markers, Scenario::Local, 3, 5);
        let sensor = Sensor::default_for(Modality::Markers, &t);
        let d = synthesize(&config, &t, &sensor, &|_| {}).unwrap();
        let shape = t.layout().range(Block::Shape);
        let truth: HeightPriorArg = "truth:0.02".parse().unwrap();
        let err = FrameHeights::new(truth, &t, false).unwrap_err().to_string();
        assert!(err.contains("no ground truth"), "{err}");
        let heights = FrameHeights::new(truth, &t, true).unwrap();
        for f in 0..d.len() {
            let plain =
                energy_for_frame(&d, t.clone(), f, EnergyConfig::default().for_gradient()).unwrap();
            let e = heights.apply(plain.clone(), d.ground_truth(f)).unwrap();
            let want = lfit_model::stature::rest_height(&t, &d.gt_poses[f][shape.clone()]).0;
            let p = e.height_prior().unwrap();
            assert_eq!((p.height_m(), p.std_m()), (want, 0.02));
            assert_eq!(e.inspect(&d.gt_poses[f]).term("height"), Some(0.0));
            assert!(heights.apply(plain, None).is_err());
            // The joint solve's variant: the term at the share's weight.
            let mut x = d.gt_poses[f].clone();
            x[shape.start] += 0.5;
            let full = least_squares_variant(&e, 1.0).unwrap();
            let half = least_squares_variant(&e, 0.25).unwrap();
            let (a, b) = (
                full.inspect(&x).term("height").unwrap(),
                half.inspect(&x).term("height").unwrap(),
            );
            assert!(a > 0.0 && (b - 0.25 * a).abs() <= 1e-12 * a, "{a} {b}");
        }
        let metres = FrameHeights::new("1.7".parse().unwrap(), &t, false).unwrap();
        let plain = energy_for_frame(&d, t.clone(), 0, EnergyConfig::default()).unwrap();
        let e = metres.apply(plain, None).unwrap();
        assert_eq!(e.height_prior().unwrap().height_m(), 1.7);
    }

    /// A parameter vector of `dim` entries within ±0.05, a different one for each `k`.
    pub(crate) fn varied_pose(dim: usize, k: usize) -> Vec<f64> {
        (0..dim)
            .map(|i| 0.01 * ((i * 7 + k * 13) % 11) as f64 - 0.05)
            .collect()
    }

    /// [`iterate_v2v`] gives [`iterate_errors`]'s V2V bit for bit, the iterate equal to the
    /// result included.
    #[test]
    fn iterate_v2v_is_iterate_errors_with_v2v() {
        use lfit_model::metrics::{TruthMesh, v2v_mm};
        let t = lfit_model::default_template();
        let dim = t.layout().dim();
        let pose = |k: usize| varied_pose(dim, k);
        let truth = pose(0);
        let iterates: Vec<Vec<f64>> = (1..5).map(pose).collect();
        let result = iterates[3].clone();
        let mesh = TruthMesh::new(&t, &truth);
        let v2v = mesh.v2v_mm(&t, &result);
        let got = iterate_v2v(&t, &iterates, &mesh, &result, v2v);
        let want = iterate_errors(&t, &iterates, &truth, v2v_mm);
        assert_eq!(got.len(), 4);
        assert!(want.iter().all(|&v| v > 0.0), "{want:?}");
        for (g, w) in got.iter().zip(&want) {
            assert_eq!(g.to_bits(), w.to_bits(), "{got:?} vs {want:?}");
        }
    }

    /// The sequence driver hands each warm frame the motion of the fits before it
    /// ([`FitRequest::motion`], `lfit_fitters::SequenceMotion`): none for the first frame (no
    /// previous fit), zeros for the second (one fit, no change yet), then the root of the exponential
    /// average of the squared changes between consecutive fits; a frame fitted on its own (the
    /// local scenario) never gets one.
    #[test]
    fn a_sequence_hands_each_frame_the_motion_of_the_fits_before_it() {
        use std::sync::Mutex;
        /// Moves entry 4 by `step × (frame + 1)` from the start and records each request's motion.
        struct Recorder {
            step: f64,
            seen: Mutex<Vec<Option<Vec<f64>>>>,
        }
        impl Fitter for Recorder {
            fn name(&self) -> String {
                "recorder".into()
            }
            fn fit(&self, r: &FitRequest<'_>) -> Result<FitResult, lfit_fitters::FitError> {
                let mut seen = self.seen.lock().unwrap();
                let n = seen.len();
                seen.push(r.motion.clone());
                let mut pose = r.start.clone();
                pose[4] += self.step * (n + 1) as f64;
                Ok(FitResult {
                    method: self.name(),
                    energy: r.energy.inspect(&pose).total,
                    pose,
                    terms: Vec::new(),
                    evaluations: 0,
                    gradient_evaluations: 0,
                    iterations: 0,
                    time_s: 0.0,
                    trace: Vec::new(),
                    iterates: Vec::new(),
                })
            }
        }
        let (t, _) = lfit_model::body::morphable_default_template().unwrap();
        let t = Arc::new(t);
        let sensor = Sensor::default_for(Modality::Markers, &t);
        for scenario in [Scenario::Sequence, Scenario::Local] {
            let d = synthesize(
                &SynthConfig::new(Modality::Markers, scenario, 5, 3),
                &t,
                &sensor,
                &|_| {},
            )
            .unwrap();
            let plan = Plan {
                dataset: &d,
                template: &t,
                budget: 10,
                batch: 1,
                known_shape: None,
                sequence_shape: SequenceShape::PerFrame,
                marker_placement: MarkerPlacement::Model,
            };
            let recorder = Recorder {
                step: 0.01,
                seen: Mutex::new(Vec::new()),
            };
            let frames: Vec<usize> = (0..d.len()).collect();
            fit_frames(
                &recorder,
                &plan,
                &frames,
                &|f| energy_for_frame(&d, t.clone(), f, EnergyConfig::default().for_gradient()),
                &|f| f as u64,
                &mut |_| Ok(()),
            )
            .unwrap();
            let seen = recorder.seen.into_inner().unwrap();
            assert_eq!(seen.len(), 5);
            if scenario == Scenario::Local {
                assert!(seen.iter().all(Option::is_none), "{scenario:?}: {seen:?}");
                continue;
            }
            // The second frame is chained but nothing has moved yet: a zero motion.
            assert!(seen[0].is_none(), "{seen:?}");
            assert_eq!(seen[1], Some(vec![0.0; t.layout().dim()]), "{seen:?}");
            // Fit k moved entry 4 by 0.01 (k + 1) from fit k − 1: changes 0.02, 0.03, 0.04.
            let w = lfit_fitters::SEQUENCE_MOTION_WEIGHT;
            let mut mean_square = 0.02f64 * 0.02;
            for (k, change) in [(2usize, 0.03f64), (3, 0.04)] {
                let m = seen[k]
                    .as_ref()
                    .expect("a warm frame with a change before it");
                assert_eq!(m.len(), t.layout().dim());
                assert!(
                    (m[4] - mean_square.sqrt()).abs() < 1e-12,
                    "frame {k}: {} against {}",
                    m[4],
                    mean_square.sqrt()
                );
                assert!(m.iter().enumerate().all(|(i, v)| i == 4 || *v == 0.0));
                mean_square = (1.0 - w) * mean_square + w * change * change;
            }
            assert!(seen[4].is_some());
        }
    }

    /// [`joint_shape`] against its definition: from per-frame β that scatter around a biased
    /// mean and poses a few degrees off, it reaches a sequence energy (the frames' summed, the
    /// shape prior once) no higher than the truth's, with β much nearer the subject's than the
    /// per-frame values and the poses moved with it; it stays inside its box.
    #[test]
    fn the_joint_shape_minimises_the_sequence_energy_and_recovers_the_subject() {
        let (t, _) = lfit_model::body::morphable_default_template().unwrap();
        let t = Arc::new(t);
        let config = SynthConfig::new(Modality::Markers, Scenario::Sequence, 16, 7);
        let sensor = Sensor::default_for(Modality::Markers, &t);
        let d = synthesize(&config, &t, &sensor, &|_| {}).unwrap();
        let shape = t.layout().range(Block::Shape);
        let n = shape.len();
        assert!(n > 0);
        let energies: Vec<Energy> = (0..d.len())
            .map(|f| {
                energy_for_frame(&d, t.clone(), f, EnergyConfig::default().for_gradient()).unwrap()
            })
            .collect();
        let truth = d.gt_poses[0][shape.clone()].to_vec();
        let bounds = Bounds::global_for(&t);
        let free = scenario_mask(Scenario::Sequence, &t).free;
        let poses: Vec<Vec<f64>> = d
            .gt_poses
            .iter()
            .enumerate()
            .map(|(f, p)| {
                let mut q = p.clone();
                for (k, i) in shape.clone().enumerate() {
                    q[i] += 0.4 + 0.3 * ((f * 7 + k * 3) as f64).sin();
                }
                // Joint rotations a few degrees off (not the root's translation).
                for i in 3..shape.start {
                    q[i] += 0.05 * ((f * 5 + i) as f64).cos();
                }
                bounds.clamp(&mut q);
                q
            })
            .collect();
        // The sequence's energy counts the one subject's shape prior once, not once per frame.
        let sequence = |ps: &[Vec<f64>]| -> f64 {
            let summed: f64 = energies
                .iter()
                .zip(ps)
                .map(|(e, p)| e.inspect(p).total)
                .sum();
            let prior = energies[0].config().weights.shape
                * energies[0].inspect(&ps[0]).term("shape").unwrap();
            summed - (ps.len() - 1) as f64 * prior
        };
        let rms = |b: &[f64]| {
            (b.iter()
                .zip(&truth)
                .map(|(a, t)| (a - t).powi(2))
                .sum::<f64>()
                / n as f64)
                .sqrt()
        };
        let boxes = vec![bounds.clone(); poses.len()];
        let (beta, fitted, solve) =
            joint_shape(&energies, &poses, shape.clone(), &free, &boxes).unwrap();
        assert!(fitted.iter().all(|p| p[shape.clone()] == beta[..]), "one β");
        assert!(
            (solve.energy_after - sequence(&fitted)).abs() <= 1e-9 * solve.energy_after,
            "{} against the sequence's energy {}",
            solve.energy_after,
            sequence(&fitted)
        );
        assert!(solve.energy_after < solve.energy_before);
        assert!(
            solve.energy_after <= sequence(&d.gt_poses) * (1.0 + 1e-9),
            "above the truth's energy: {} > {}",
            solve.energy_after,
            sequence(&d.gt_poses)
        );
        let per_frame =
            poses.iter().map(|p| rms(&p[shape.clone()])).sum::<f64>() / poses.len() as f64;
        assert!(
            rms(&beta) < 0.25 * per_frame,
            "β error {} against the per-frame values' {per_frame}",
            rms(&beta)
        );
        // The poses moved too: with β alone at its solution they would be worse off.
        let held: Vec<Vec<f64>> = poses
            .iter()
            .map(|p| {
                let mut q = p.clone();
                q[shape.clone()].copy_from_slice(&beta);
                q
            })
            .collect();
        assert!(
            solve.energy_after < 0.9 * sequence(&held),
            "{} against {} with the poses held",
            solve.energy_after,
            sequence(&held)
        );
        // The prior counted once shrinks β less towards the mean than once per frame would: at
        // the solution, the frames' plain sum still falls when β is shrunk a little.
        let plain = |b: &[f64]| -> f64 {
            energies
                .iter()
                .zip(&fitted)
                .map(|(e, p)| {
                    let mut q = p.clone();
                    q[shape.clone()].copy_from_slice(b);
                    e.inspect(&q).total
                })
                .sum()
        };
        let shrunk = plain(&beta.iter().map(|b| 0.9999 * b).collect::<Vec<_>>());
        assert!(shrunk < plain(&beta), "{shrunk} {}", plain(&beta));
        // A box that excludes the solution: every entry inside it.
        let mut boxed_bounds = bounds.clone();
        for i in shape.clone() {
            boxed_bounds.lower[i] = -0.1;
            boxed_bounds.upper[i] = 0.1;
        }
        // Each frame in its own box: a box around its start, shape boxes that differ by frame
        // (β in all of them: ±0.1).
        let own: Vec<Bounds> = poses
            .iter()
            .enumerate()
            .map(|(f, p)| {
                let mut b = Bounds::local_in(&t.layout(), p);
                for i in shape.clone() {
                    b.lower[i] = boxed_bounds.lower[i] - 0.01 * f as f64;
                    b.upper[i] = boxed_bounds.upper[i] + 0.01 * f as f64;
                }
                b
            })
            .collect();
        let (boxed, boxed_poses, _) =
            joint_shape(&energies, &poses, shape.clone(), &free, &own).unwrap();
        assert!(boxed.iter().all(|b| (-0.1..=0.1).contains(b)), "{boxed:?}");
        assert!(boxed_poses.iter().zip(&own).all(|(p, b)| b.contains(p)));
        // Mismatched inputs, boxes that share no β: an error, not a panic.
        assert!(joint_shape(&energies, &poses[1..], shape.clone(), &free, &boxes).is_err());
        assert!(joint_shape(&energies, &poses, shape.clone(), &free, &boxes[1..]).is_err());
        assert!(joint_shape(&energies, &poses, 0..200, &free, &boxes).is_err());
        let mut apart = boxes.clone();
        let s0 = shape.start;
        (apart[0].lower[s0], apart[0].upper[s0]) = (1.0, 2.0);
        (apart[1].lower[s0], apart[1].upper[s0]) = (-2.0, -1.0);
        let e = joint_shape(&energies, &poses, shape.clone(), &free, &apart).unwrap_err();
        assert!(e.to_string().contains("do not overlap"), "{e}");
    }
}
