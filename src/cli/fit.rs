//! `lfit fit`, `lfit objective-server` and `lfit optimize`: datasets → energies → fitters.

use std::io::{BufRead, Write};
use std::path::{Path, PathBuf};
use std::sync::Arc;

use anyhow::{Context, Result, bail};
use lfit_fitters::optim::{self, Method, Preset};
use lfit_fitters::{Fitter, Strategy};
use lfit_model::energy::{Energy, EnergyConfig};
use lfit_model::metrics::{TruthMesh, aligned_joint_error_mm, joint_error_mm, mpjpe_mm};
use lfit_model::pose::DofMask;
use lfit_model::template::{Template, write_atomic};
use lfit_synth::Dataset;
use rayon::prelude::*;
use serde_json::{Map, Value, json};

pub use crate::fitting::{
    energy_for_frame, frame_seed, iterate_errors, iterate_v2v, scenario_bounds, scenario_mask,
    template_for,
};

/// The JSON fields of a parameter vector: `pose`, and `shape`/`expression` when the model has them.
pub fn params_json(template: &Template, params: &[f64]) -> Map<String, Value> {
    let l = template.layout();
    let mut m = Map::new();
    m.insert("pose".into(), json!(params[..l.pose_dim()]));
    if l.shape > 0 {
        m.insert(
            "shape".into(),
            json!(params[l.range(lfit_model::Block::Shape)]),
        );
    }
    if l.expression > 0 {
        m.insert(
            "expression".into(),
            json!(params[l.range(lfit_model::Block::Expression)]),
        );
    }
    m
}

/// A fit's errors against the truth: V2V, MPJPE, PA-MPJPE (after a similarity alignment of
/// the joints: the monocular figure, a single view leaves scale and depth open), the fitted and
/// true joints (for a sequence's acceleration error), β's coefficient RMS and shape V2V where
/// the model has shape, the face's errors where it is a face, and the V2V and MPJPE of every
/// iterate where the fitter kept them.
struct TruthScore {
    v2v: f64,
    mpjpe: f64,
    pa_mpjpe: f64,
    joints: Vec<glam::DVec3>,
    true_joints: Vec<glam::DVec3>,
    coefficient_rms: Option<f64>,
    shape_v2v: Option<f64>,
    face: Option<lfit_model::metrics::FaceErrors>,
    per_iteration: Option<(Vec<f64>, Vec<f64>)>,
}

impl TruthScore {
    fn of(template: &Template, gt: &[f64], pose: &[f64], iterates: &[Vec<f64>]) -> Self {
        let truth = TruthMesh::new(template, gt);
        let v2v = truth.v2v_mm(template, pose);
        // The fitted and true joints, posed once for MPJPE, PA-MPJPE and a sequence's
        // acceleration error.
        let (joints, true_joints) = (
            lfit_model::metrics::joint_positions(template, pose),
            lfit_model::metrics::joint_positions(template, gt),
        );
        Self {
            v2v,
            mpjpe: joint_error_mm(&joints, &true_joints),
            pa_mpjpe: aligned_joint_error_mm(&joints, &true_joints),
            joints,
            true_joints,
            coefficient_rms: coefficient_rms(template, pose, gt),
            shape_v2v: lfit_model::metrics::shape_v2v_mm(template, pose, gt),
            face: lfit_model::metrics::face_errors_mm(template, pose, gt),
            per_iteration: (!iterates.is_empty()).then(|| {
                (
                    iterate_v2v(template, iterates, &truth, pose, v2v),
                    iterate_errors(template, iterates, gt, mpjpe_mm),
                )
            }),
        }
    }
}

/// A fitted frame with ground truth waiting to be scored: its row in the result, the frame, its
/// truth, the fitted pose and the fitter's iterates.
struct Queued<'a> {
    row: usize,
    frame: usize,
    truth: &'a [f64],
    pose: Vec<f64>,
    iterates: Vec<Vec<f64>>,
}

/// Frames fitted with ground truth waiting to be scored ([`TruthScore`]) over rayon's threads,
/// `chunk` at a time ([`TRUTH_CHUNK`]: their iterates are not kept for a whole long sequence),
/// and the sums of their errors, added in frame order: the same numbers as one frame at a time.
struct TruthScores<'a> {
    template: &'a Template,
    /// Whether the frames are a sequence (then each frame's joints are kept).
    sequence: bool,
    chunk: usize,
    pending: Vec<Queued<'a>>,
    v2v: f64,
    mpjpe: f64,
    pa_mpjpe: f64,
    coefficient_rms: f64,
    shape_v2v: f64,
    /// In a sequence: each frame's fitted and true joints, for the acceleration error.
    joints: Vec<(usize, Vec<glam::DVec3>, Vec<glam::DVec3>)>,
}

/// Frames scored against the truth per parallel pass of [`TruthScores`].
const TRUTH_CHUNK: usize = 512;

impl<'a> TruthScores<'a> {
    fn new(template: &'a Template, sequence: bool, chunk: usize) -> Self {
        Self {
            template,
            sequence,
            chunk,
            pending: Vec::new(),
            v2v: 0.0,
            mpjpe: 0.0,
            pa_mpjpe: 0.0,
            coefficient_rms: 0.0,
            shape_v2v: 0.0,
            joints: Vec::new(),
        }
    }

    /// Queues a frame (its row, `queued.row`, not yet in `rows`), scoring the queue first when
    /// it is full.
    fn push(&mut self, queued: Queued<'a>, rows: &mut [Value]) {
        // The queued frames' rows are in `rows` already; this one's is not yet.
        if self.pending.len() >= self.chunk {
            self.flush(rows);
        }
        self.pending.push(queued);
    }

    /// Scores the queued frames over rayon's threads and writes each into its row.
    fn flush(&mut self, rows: &mut [Value]) {
        let template = self.template;
        let scores: Vec<TruthScore> = self
            .pending
            .par_iter()
            .map(|q| TruthScore::of(template, q.truth, &q.pose, &q.iterates))
            .collect();
        for (q, score) in self.pending.drain(..).zip(scores) {
            let row = &mut rows[q.row];
            self.v2v += score.v2v;
            self.mpjpe += score.mpjpe;
            self.pa_mpjpe += score.pa_mpjpe;
            row["v2v_mm"] = json!(score.v2v);
            row["mpjpe_mm"] = json!(score.mpjpe);
            row["pa_mpjpe_mm"] = json!(score.pa_mpjpe);
            if self.sequence {
                self.joints.push((q.frame, score.joints, score.true_joints));
            }
            if let Some(c) = score.coefficient_rms {
                row["shape_rms"] = json!(c);
                self.coefficient_rms += c;
            }
            if let Some(d) = score.shape_v2v {
                row["shape_v2v_mm"] = json!(d);
                self.shape_v2v += d;
            }
            if let Some(f) = score.face {
                row["face"] = json!(f);
            }
            if let Some((v2v, mpjpe)) = score.per_iteration {
                row["v2v_mm_per_iteration"] = json!(v2v);
                row["mpjpe_mm_per_iteration"] = json!(mpjpe);
            }
        }
    }
}

/// RMS difference of the shape and expression coefficients, `None` without them.
pub fn coefficient_rms(template: &Template, fitted: &[f64], truth: &[f64]) -> Option<f64> {
    let l = template.layout();
    let r = l.pose_dim()..l.dim();
    (!r.is_empty()).then(|| {
        (fitted[r.clone()]
            .iter()
            .zip(&truth[r.clone()])
            .map(|(a, b)| (a - b) * (a - b))
            .sum::<f64>()
            / r.len() as f64)
            .sqrt()
    })
}

/// Parses `--frames`: `A..B` (B excluded), `A-B` (B included), `I`, or a comma list of those.
pub fn parse_frames(spec: Option<&str>, len: usize) -> Result<Vec<usize>> {
    let Some(spec) = spec else {
        return Ok((0..len).collect());
    };
    let mut out = Vec::new();
    for part in spec.split(',').map(str::trim) {
        let num = |s: &str| {
            s.trim()
                .parse::<usize>()
                .with_context(|| format!("--frames: '{s}' is not a frame index"))
        };
        let (a, b) = if let Some((a, b)) = part.split_once("..") {
            (num(a)?, num(b)?)
        } else if let Some((a, b)) = part.split_once('-') {
            (num(a)?, num(b)? + 1)
        } else {
            let i = num(part)?;
            (i, i + 1)
        };
        if a >= b {
            bail!("--frames: empty range '{part}'");
        }
        if b > len {
            bail!(
                "--frames: '{part}' goes past the last frame ({} frames)",
                len
            );
        }
        out.extend(a..b);
    }
    Ok(out)
}

/// Reads an energy configuration JSON file (unknown keys refused).
pub fn read_energy_config(path: Option<&Path>, gradient: bool) -> Result<EnergyConfig> {
    let config = match path {
        Some(p) => {
            let text = std::fs::read_to_string(crate::shipped::locate_or_given(p))
                .with_context(|| format!("cannot read {}", p.display()))?;
            serde_json::from_str(&text)
                .with_context(|| format!("malformed energy configuration {}", p.display()))?
        }
        None if gradient => EnergyConfig::default().for_gradient(),
        None => EnergyConfig::default(),
    };
    config.validate()?;
    Ok(config)
}

/// Mean marker error (mm) of a capture's fit above which the markers are taken to sit off the
/// model's marker set. Markers on the set fit to under 2 mm (a C3D of synthetic frames, noise
/// free) and real markers, hand placed, leave 23–30 mm on it and 4–6 mm once their placement is
/// solved (`docs/results/captured-motion.md`, round 20).
pub const PLACEMENT_HINT_MM: f64 = 10.0;

/// The summary's `hint` for a capture's markers fitted on the model's marker set with more than
/// [`PLACEMENT_HINT_MM`] left on them: where they sit can be solved. `None` otherwise.
fn placement_hint(
    dataset: &Dataset,
    placement: crate::fitting::MarkerPlacement,
    offsets: bool,
    mean_mm: f64,
) -> Option<String> {
    let markers = dataset.sensor.modality() == lfit_model::observe::Modality::Markers;
    (markers
        && !offsets
        && placement == crate::fitting::MarkerPlacement::Model
        && mean_mm > PLACEMENT_HINT_MM)
        .then(|| {
            let how = if dataset.meta.config.scenario == lfit_synth::Scenario::Sequence {
                "--sequence-shape joint:64 --marker-placement solve (or --offsets from a static trial's solve)"
            } else {
                "--offsets from a sequence's --marker-placement solve"
            };
            format!(
                "the fit leaves {mean_mm:.1} mm on the markers: markers placed by hand sit off the model's marker set, and {how} puts them where they are (a lab's captures: 23–30 → 4–6 mm)"
            )
        })
}

/// Whether a fit's β left the subject's size to its box: an entry of the shape block at
/// ±[`lfit_model::pose::SHAPE_BOUND`]. Where the observations leave the body's size open (one
/// camera trades size against depth) a per-frame β runs along that valley until the box stops it:
/// on a one-camera keypoints2d sequence (`configs/rigs/phone-1.json`, CMU subject 6, 100 frames)
/// LM with `--dofs anchored:5,30` (the translation held by 30 mm, the default before round 34)
/// ended 75 frames there at 401 mm V2V, against none of the frames of the two- and three-camera
/// rigs (`docs/results/captured-motion.md`, rounds 32 and 34).
fn shape_at_bound(template: &Template, pose: &[f64]) -> bool {
    let shape = template.layout().range(lfit_model::layout::Block::Shape);
    pose[shape]
        .iter()
        .any(|b| b.abs() >= lfit_model::pose::SHAPE_BOUND * (1.0 - 1e-9))
}

/// The summary's `shape_hint` where `at_bound` of `frames` fitted frames ended with β at its box
/// ([`shape_at_bound`]): the fit's size is the box's, not the subject's. `None` when none did.
/// With `height_prior` (the fit had `--height-prior`) the advice is a tighter one or β; with
/// `floor` (it had `--floor`) the floor is not suggested again. In a
/// sequence it adds one β over the sequence, `joint:64`: its first pass is a chain, where
/// `first-pass` fits frames alone from their starts (one camera's sequences from starts 300 mm
/// off in depth: 55 mm against 240; docs/results/captured-motion.md, round 34). `one_camera`
/// (the data are seen by one camera) names depth as the likely cause; other data (markers, a
/// headset, several cameras) are not told about a camera.
fn shape_hint(
    at_bound: usize,
    frames: usize,
    sequence: bool,
    height_prior: bool,
    floor: bool,
    one_camera: bool,
) -> Option<String> {
    (at_bound > 0).then(|| {
        let give = match (height_prior, floor) {
            (true, _) => "the height prior did not hold it: give β or the height as β (--known-shape height:M), or a smaller --height-prior STD",
            (false, true) => "give β or the subject's height (--known-shape height:M, or --height-prior M with β estimated)",
            (false, false) => "give β or the subject's height (--known-shape height:M, or --height-prior M with β estimated), or where the floor is (--floor contact:HEIGHT)",
        };
        let fix = if sequence {
            format!("{give}, or fix one β over the sequence (--sequence-shape joint:64)")
        } else {
            give.to_string()
        };
        let cause = if one_camera {
            "the observations leave the body's size open (one camera trades size against depth)"
        } else {
            "the observations did not hold the body's size inside the box"
        };
        format!(
            "β reached the ±{} bound of its box in {at_bound} of {frames} frames: {cause}, and those fits take the box's size, not the subject's; {fix}",
            lfit_model::pose::SHAPE_BOUND
        )
    })
}

/// A frame's distances to observations into its row: `{prefix}_error_{unit}` (mean),
/// `{prefix}_rms_{unit}`, `{prefix}_max_{unit}` and `seen` (how many).
fn errors_json(
    row: &mut Value,
    prefix: &str,
    seen: &str,
    e: &lfit_synth::capture::import::ObservationErrors,
) {
    let u = e.unit;
    row[format!("{prefix}_error_{u}")] = json!(e.mean);
    row[format!("{prefix}_rms_{u}")] = json!(e.rms);
    row[format!("{prefix}_max_{u}")] = json!(e.max);
    row[seen] = json!(e.count);
}

fn terms_json(terms: &[(&'static str, f64)]) -> Value {
    Value::Object(
        terms
            .iter()
            .map(|(k, v)| ((*k).to_string(), json!(v)))
            .collect::<Map<_, _>>(),
    )
}

/// Arguments of `lfit fit`.
#[derive(Debug, Clone)]
pub struct FitArgs {
    pub data: PathBuf,
    pub method: crate::method::MethodKind,
    pub budget: usize,
    pub strategy: String,
    /// `tuned`, `nevergrad` or `paper001`; `None`: tuned where a setting is recorded for the
    /// method and modality (and no step or CMA-ES flag is given), nevergrad's otherwise.
    pub preset: Option<String>,
    pub step_scale: Option<f64>,
    /// CMA-ES's update variant (`--cma-diagonal`, `--cma-elitist`, `--cma-popsize`).
    pub cma: lfit_fitters::optim::cma::CmaVariant,
    pub frames: Option<String>,
    pub seed: u64,
    pub out: PathBuf,
    pub energy: Option<PathBuf>,
    pub template: Option<PathBuf>,
    /// Neural fitter: checkpoint directory, θ0 source, backend, frames per network pass.
    pub checkpoint: Option<PathBuf>,
    pub neural_start: String,
    /// `last` or `lowest` ([`lfit_infer::Pick`] by name).
    pub neural_pick: String,
    /// `--neural-iterations K`: the network's first K iterations only (an early exit); `None`:
    /// the N it was trained for.
    pub neural_iterations: Option<usize>,
    /// `--neural-tolerance TOL`: the energy rule that stops a frame's network early.
    pub neural_tolerance: Option<f64>,
    pub device: String,
    pub batch: usize,
    /// `burn` or `ort`, and ONNX Runtime's intra-op threads.
    pub runtime: String,
    pub ort_threads: Option<usize>,
    /// `--known-shape`: `truth`, `height:M` or comma-separated β values
    /// ([`crate::fitting::KnownShapeArg`]).
    pub known_shape: Option<String>,
    /// `--height-prior`: `M`, `M:STD`, `truth` or `truth:STD` (metres;
    /// [`crate::fitting::HeightPriorArg`]).
    pub height_prior: Option<String>,
    /// `--floor`: `FORM:HEIGHT[,MM]` ([`crate::fitting::FloorArg`]).
    pub floor: Option<String>,
    /// `--sequence-shape`: `per-frame`, `first-pass`, `joint` or `joint:N`
    /// ([`crate::fitting::SequenceShape`]).
    pub sequence_shape: String,
    /// `--marker-placement`: `model` or `solve` ([`crate::fitting::MarkerPlacement`]).
    pub marker_placement: String,
    /// `--offsets`: where the markers or keypoints sit, from an earlier fit of the same subject
    /// and sensor ([`read_offsets`]); `None`: the dataset's sensor as it is.
    pub offsets: Option<PathBuf>,
    /// `--dofs`: `all`, `observed`, `observed:DEG`, `anchored`, `anchored:DEG`, `anchored:DEG,MM` or `observed[:DEG]+anchored[:DEG[,MM]]` ([`lfit_fitters::Dofs`]); `None`: the
    /// method's default ([`crate::method::MethodKind::default_dofs`]).
    pub dofs: Option<String>,
    /// `--holdout`: markers (by name) or 2D keypoints (`camera:K`, joint names) left out of the
    /// fit and scored against it ([`crate::holdout::Holdout`]).
    pub holdout: Option<String>,
}

/// What `lfit fit` settles before it touches the frames: the parsed settings, the fitter (a
/// neural checkpoint loaded) and the energy configuration.
struct Prepared {
    strategy: Strategy,
    known_shape: Option<crate::fitting::KnownShapeArg>,
    height_prior: Option<crate::fitting::HeightPriorArg>,
    floor: Option<crate::fitting::FloorArg>,
    sequence_shape: crate::fitting::SequenceShape,
    marker_placement: crate::fitting::MarkerPlacement,
    /// `--offsets`, read: the offsets and what they place (`"marker"` or `"keypoint"`, `None`
    /// for a bare list).
    offsets: Option<(Vec<[f64; 3]>, Option<&'static str>)>,
    /// `tuned` when the steps are a recorded setting, else the preset's name.
    preset_name: &'static str,
    step_scale: f64,
    cma: lfit_fitters::optim::cma::CmaVariant,
    fitter: Box<dyn Fitter>,
    config: EnergyConfig,
    /// Which entries the fit moves (`--dofs`, or the method's default for the data).
    dofs: lfit_fitters::Dofs,
}

/// Checks the settings of `args` and builds the fitter, before any frame is fitted. `data`
/// gives the data's modality and whether it is a sequence, asked only when a recorded setting
/// or default may apply (`--preset tuned`, or no preset; `neural+lm` without `--dofs`);
/// `config` replaces `--energy`.
fn prepare(
    args: &FitArgs,
    data: &mut dyn FnMut() -> Result<crate::method::DataKind>,
    config: Option<EnergyConfig>,
) -> Result<Prepared> {
    if args.budget == 0 {
        bail!("--budget must be at least 1 evaluation");
    }
    let strategy: Strategy = args.strategy.parse()?;
    let known_shape: Option<crate::fitting::KnownShapeArg> =
        args.known_shape.as_deref().map(str::parse).transpose()?;
    if known_shape.is_some() {
        crate::fitting::KnownShape::check_strategy(strategy).context("--known-shape")?;
    }
    let height_prior: Option<crate::fitting::HeightPriorArg> =
        args.height_prior.as_deref().map(str::parse).transpose()?;
    if height_prior.is_some() && known_shape.is_some() {
        bail!(
            "--height-prior informs an estimated β, --known-shape gives β: use one (--known-shape height:M fixes the most likely β of a height)"
        );
    }
    let floor: Option<crate::fitting::FloorArg> =
        args.floor.as_deref().map(str::parse).transpose()?;
    let sequence_shape: crate::fitting::SequenceShape =
        args.sequence_shape.parse().context("--sequence-shape")?;
    let marker_placement: crate::fitting::MarkerPlacement = args
        .marker_placement
        .parse()
        .context("--marker-placement")?;
    let offsets = args.offsets.as_deref().map(read_offsets).transpose()?;
    // The steps of a zeroth-order method (crate::study::tuned::choose): a flag that sets them
    // (--step-scale, --cma-*) keeps the recorded setting out, and goes with no `tuned` preset.
    let overridden = args.step_scale.is_some() || args.cma != Default::default();
    if args.preset.as_deref() == Some("tuned") && overridden {
        bail!(
            "--preset tuned sets the steps and CMA-ES options itself: drop --step-scale and --cma-*"
        );
    }
    let preset: Preset = match args.preset.as_deref() {
        None | Some("tuned") => Preset::Nevergrad,
        Some(p) => p
            .parse()
            .map_err(|_| lfit_fitters::FitError::UnknownPreset(p.to_string()))?,
    };
    let tuned = if args.preset.is_some() || (!overridden && args.method.zeroth_order().is_some()) {
        crate::study::tuned::choose(args.preset.as_deref(), args.method.name(), &mut || {
            Ok(data()?.0.name().to_string())
        })?
    } else {
        None
    };
    let (preset_name, step_scale, cma) = match tuned {
        Some(t) => ("tuned", t.step_scale, t.cma),
        None => (preset.as_str(), args.step_scale.unwrap_or(1.0), args.cma),
    };
    if args.batch == 0 {
        bail!("--batch must be at least 1");
    }
    // The flags each kind of method refuses, before anything is read for the fit; a neural
    // method's checkpoint.
    let checkpoint = if args.method.is_neural() {
        if args.step_scale.is_some()
            || args.preset.as_deref() == Some("tuned")
            || args.cma != Default::default()
        {
            bail!(
                "--step-scale, --cma-* and --preset tuned are for zeroth-order methods, not {}",
                args.method
            );
        }
        Some(
            args.checkpoint
                .as_deref()
                .with_context(|| format!("--method {} needs --checkpoint DIR", args.method))?,
        )
    } else {
        if args.checkpoint.is_some() {
            bail!("--checkpoint is only for --method neural or neural+lm");
        }
        if args.runtime != "burn" || args.ort_threads.is_some() {
            bail!("--runtime and --ort-threads are only for --method neural or neural+lm");
        }
        if args.neural_iterations.is_some() || args.neural_tolerance.is_some() {
            bail!(
                "--neural-iterations and --neural-tolerance are only for --method neural or neural+lm"
            );
        }
        None
    };
    let dofs =
        crate::method::dofs_for(args.method, args.dofs.as_deref(), data, &args.neural_start)?;
    let fitter: Box<dyn Fitter> = match checkpoint {
        Some(dir) => crate::method::load_neural_named(
            args.method,
            dir,
            &args.neural_start,
            &args.neural_pick,
            args.neural_iterations,
            args.neural_tolerance,
            &args.runtime,
            &args.device,
            args.ort_threads,
            dofs,
        )?,
        None => crate::method::build_classic(
            args.method,
            crate::method::ClassicOptions {
                preset,
                strategy,
                step_scale,
                cma,
                dofs,
            },
        )?,
    };
    let config = match config {
        Some(c) => {
            c.validate()?;
            c
        }
        None => read_energy_config(args.energy.as_deref(), args.method.uses_gradient())?,
    };
    Ok(Prepared {
        strategy,
        known_shape,
        height_prior,
        floor,
        sequence_shape,
        marker_placement,
        offsets,
        preset_name,
        step_scale,
        cma,
        fitter,
        config,
        dofs,
    })
}

/// `--offsets FILE`: an `lfit fit` result whose `summary.shape_pass` holds `marker_offsets` or
/// `keypoint_offsets` (`--marker-placement solve` on a sequence of the same subject and sensor),
/// or a JSON list of `[x, y, z]` offsets in metres (markers from their vertices, keypoints from
/// their joints' centres, in the rest frame). Returns them with the kind a result names.
pub fn read_offsets(path: &std::path::Path) -> Result<(Vec<[f64; 3]>, Option<&'static str>)> {
    let what = || format!("--offsets {}", path.display());
    let text = std::fs::read_to_string(path).with_context(what)?;
    let doc: Value =
        serde_json::from_str(&text).with_context(|| format!("{}: not JSON", what()))?;
    let (list, kind) = if doc.is_array() {
        (&doc, None)
    } else {
        // An `lfit calibrate` file names them at the top; a fit result in its shape pass.
        let pass = if doc.get("calibration").is_some() {
            &doc
        } else {
            &doc["summary"]["shape_pass"]
        };
        match (pass.get("marker_offsets"), pass.get("keypoint_offsets")) {
            (Some(m), _) => (m, Some("marker")),
            (None, Some(k)) => (k, Some("keypoint")),
            (None, None) => bail!(
                "{}: neither a list of [x, y, z] offsets, an lfit calibrate file, nor an lfit fit result with summary.shape_pass.marker_offsets or keypoint_offsets (a --marker-placement solve of a sequence)",
                what()
            ),
        }
    };
    let offsets: Vec<[f64; 3]> = serde_json::from_value(list.clone()).with_context(|| {
        format!(
            "{}: the offsets are not a list of [x, y, z] numbers",
            what()
        )
    })?;
    if offsets.is_empty() {
        bail!("{}: no offsets", what());
    }
    Ok((offsets, kind))
}

/// The dataset's modality and whether it is a sequence ([`crate::method::DataKind`]).
fn data_kind(dataset: &Dataset) -> crate::method::DataKind {
    (
        dataset.sensor.modality(),
        dataset.meta.config.scenario == lfit_synth::Scenario::Sequence,
    )
}

/// `lfit fit`: fits every selected frame, writes the result JSON atomically and returns a summary.
pub fn fit(args: &FitArgs, progress: &dyn Fn(usize, usize)) -> Result<Value> {
    let load =
        || Dataset::load(&args.data).with_context(|| format!("dataset {}", args.data.display()));
    // Settings first, before any work; a recorded setting's modality reads the dataset, once.
    let mut loaded = None;
    let prepared = prepare(args, &mut || Ok(data_kind(loaded.insert(load()?))), None)?;
    let dataset = match loaded {
        Some(d) => d,
        None => load()?,
    };
    let template = template_for(&dataset, args.template.as_deref())?;
    let out = fit_prepared(args, &prepared, &dataset, template, &|done, total| {
        progress(done, total);
        Ok(())
    })?;
    let bytes = serde_json::to_vec_pretty(&out)?;
    write_atomic(&args.out, &bytes)?;
    Ok(
        json!({ "out": args.out, "method": out["method"], "budget": args.budget, "summary": out["summary"] }),
    )
}

/// `lfit fit` on a dataset held in memory: the result document `lfit fit` writes (`args.data`
/// is only recorded, `args.out` unused), nothing written. `template` is the dataset's model
/// (checked against it; `None`: `args.template` or the procedural body the dataset names);
/// `config` replaces `args.energy`. `progress(done, total)` runs after every fitted frame; its
/// error (e.g. an interrupt) stops the fit and is returned.
pub fn fit_dataset(
    args: &FitArgs,
    dataset: &Dataset,
    template: Option<Arc<Template>>,
    config: Option<EnergyConfig>,
    progress: &dyn Fn(usize, usize) -> Result<()>,
) -> Result<Value> {
    let prepared = prepare(args, &mut || Ok(data_kind(dataset)), config)?;
    let template = match template {
        Some(t) => {
            crate::fitting::check_model(dataset, &t)?;
            t
        }
        None => template_for(dataset, args.template.as_deref())?,
    };
    fit_prepared(args, &prepared, dataset, template, progress)
}

/// The fitting part of [`fit`] and [`fit_dataset`]: every selected frame, into the result
/// document.
fn fit_prepared(
    args: &FitArgs,
    prepared: &Prepared,
    dataset: &Dataset,
    template: Arc<Template>,
    progress: &dyn Fn(usize, usize) -> Result<()>,
) -> Result<Value> {
    let Prepared {
        strategy,
        known_shape,
        height_prior,
        floor,
        sequence_shape,
        marker_placement,
        offsets,
        preset_name,
        step_scale,
        cma,
        fitter,
        config,
        dofs,
    } = prepared;
    let (strategy, sequence_shape, preset_name, step_scale, cma) =
        (*strategy, *sequence_shape, *preset_name, *step_scale, *cma);
    // `--known-shape height:M` becomes the β of that height on this model.
    let height = match known_shape {
        Some(crate::fitting::KnownShapeArg::Height(h)) => Some(*h),
        _ => None,
    };
    let known_shape = known_shape
        .as_ref()
        .map(|k| k.resolve(&template))
        .transpose()?;
    // `--height-prior`: the stature as one more measurement in every frame's energy.
    let heights = height_prior
        .map(|h| crate::fitting::FrameHeights::new(h, &template, dataset.has_ground_truth()))
        .transpose()?;
    let fitter = fitter.as_ref();
    // `--offsets`: the dataset's sensor with its points where an earlier fit put them.
    let placed;
    let dataset = match offsets {
        Some((offsets, kind)) => {
            let modality = dataset.sensor.modality();
            let expected = crate::fitting::point_offsets_of(modality).map(|(k, _)| k);
            if let Some(kind) = kind
                && Some(*kind) != expected
            {
                bail!(
                    "--offsets: the file holds {kind} offsets, the data's modality is {modality}"
                );
            }
            let sensor = dataset
                .sensor
                .placed(offsets.clone())
                .context("--offsets")?;
            sensor.validate(&template).context("--offsets")?;
            placed = Dataset {
                sensor,
                ..dataset.clone()
            };
            &placed
        }
        None => dataset,
    };
    // `--holdout`: the fit sees the data without what is held out; the data as it was scores it.
    let scored = dataset;
    let holdout = args
        .holdout
        .as_deref()
        .map(|spec| crate::holdout::Holdout::parse(spec, scored, &template))
        .transpose()?;
    let hidden;
    let dataset = match &holdout {
        Some(h) => {
            hidden = h.hide(scored, &template)?;
            &hidden
        }
        None => scored,
    };
    let neural = args.method.is_neural();
    let frames = parse_frames(args.frames.as_deref(), dataset.len())?;
    let scenario = dataset.meta.config.scenario;
    let mut rows = Vec::with_capacity(frames.len());
    // With `--height-prior`: the fitted β's rest heights.
    let mut sum_rest_height = 0.0;
    // Frames whose estimated β ended at its box (none counted where β is given).
    let mut shape_at_bound_frames = 0usize;
    let (mut sum_e, mut sum_t) = (0.0, 0.0);
    // With a captured joint reference (`lfit data import --reference`): MPJPE and PA-MPJPE
    // against it, over the frames that hold some of it.
    let (mut sum_ref, mut ref_frames) = (0.0, 0usize);
    let (mut sum_ref_pa, mut ref_pa_frames) = (0.0, 0usize);
    // In a sequence: each fitted frame's joints, for the acceleration error against it.
    let mut reference_joints: Vec<(usize, Vec<glam::DVec3>)> = Vec::new();
    // Without ground truth (imported observations): how far the fit lies from the observations.
    let (mut sum_obs, mut obs_frames, mut obs_unit) = (0.0, 0usize, "");
    let mut observed: Vec<(usize, usize, Vec<f64>)> = Vec::new();
    // With `--holdout`, every fitted frame (row, frame, pose), scored after the pass.
    let mut fitted_poses: Vec<(usize, usize, Vec<f64>)> = Vec::new();
    // With ground truth: the errors against it.
    let sequence = scenario == lfit_synth::Scenario::Sequence;
    let mut truth = TruthScores::new(&template, sequence, TRUTH_CHUNK);
    // Frames go through the network `--batch` at a time (the plan keeps sequences one by one).
    let plan = crate::fitting::Plan {
        dataset: &dataset,
        template: &template,
        budget: args.budget,
        batch: if neural { args.batch } else { 1 },
        known_shape: known_shape.clone(),
        sequence_shape,
        marker_placement: *marker_placement,
    };
    if sequence_shape != crate::fitting::SequenceShape::PerFrame && !plan.runs_pass() {
        bail!(
            "--sequence-shape {} needs a sequence dataset (this one is {scenario}) of a model with shape parameters whose β is not given (--known-shape; with it, only for --marker-placement solve)",
            sequence_shape.name()
        );
    }
    plan.check_marker_placement()?;
    let mask = plan.mask()?;
    // `--floor`: the ground plane in every frame's energy (`truth`: measured on these frames).
    let floor = floor
        .map(|f| f.resolve(dataset, &template, &frames, config))
        .transpose()?;
    let mut sum_lowest_sole = 0.0;
    let frame_energy = |frame: usize| -> Result<lfit_model::energy::Energy> {
        crate::fitting::energy_with_priors(
            dataset,
            template.clone(),
            frame,
            config.clone(),
            heights.as_ref(),
            floor.as_ref(),
        )
    };
    let mut done = 0;
    let report = crate::fitting::fit_frames(
        fitter,
        &plan,
        &frames,
        &frame_energy,
        &|frame| frame_seed(args.seed, frame),
        &mut |fitted| {
            let (frame, result) = (fitted.frame, fitted.result);
            let pose = &result.pose;
            sum_e += result.energy;
            sum_t += result.time_s;
            let mut row = json!({
                "frame": frame,
                "energy": result.energy,
                "start_energy": fitted.start_energy,
                "terms": terms_json(&result.terms),
                "evaluations": result.evaluations,
                "gradient_evaluations": result.gradient_evaluations,
                "iterations": result.iterations,
                "time_s": result.time_s,
                "trace": result.trace,
            });
            if let Value::Object(fields) = &mut row {
                fields.extend(params_json(&template, pose));
            }
            if holdout.is_some() {
                fitted_poses.push((rows.len(), frame, pose.clone()));
            }
            if known_shape.is_none() && shape_at_bound(&template, pose) {
                shape_at_bound_frames += 1;
            }
            if let Some(heights) = &heights {
                // How tall the fitted β is, beside the prior's height.
                let beta = &pose[template.layout().range(lfit_model::layout::Block::Shape)];
                let h = heights.rest_height(&template, beta);
                row["rest_height_m"] = json!(h);
                sum_rest_height += h;
            }
            if let Some(f) = &floor {
                // Where the fit put the lowest sole, beside the floor's height.
                let h = frame_energy(frame)?.lowest_sole(f, pose)?;
                row["lowest_sole_m"] = json!(h);
                sum_lowest_sole += h;
            }
            let posed = scored
                .reference
                .as_ref()
                .map(|_| lfit_model::metrics::joint_positions(&template, pose));
            if let (Some(reference), Some(joints)) = (&scored.reference, &posed)
                && let Some(e) = reference.errors_of_joints(frame, joints)
            {
                row["reference_mpjpe_mm"] = json!(e.mpjpe_mm);
                row["reference_joints_seen"] = json!(e.seen);
                sum_ref += e.mpjpe_mm;
                ref_frames += 1;
                if let Some(pa) = e.pa_mpjpe_mm {
                    row["reference_pa_mpjpe_mm"] = json!(pa);
                    sum_ref_pa += pa;
                    ref_pa_frames += 1;
                }
            }
            if let Some(joints) = posed
                && sequence
            {
                reference_joints.push((frame, joints));
            }
            if let Some(gt) = dataset.ground_truth(frame) {
                // Scored against the truth over rayon's threads, a chunk of frames at a time.
                let queued = Queued {
                    row: rows.len(),
                    frame,
                    truth: gt,
                    pose: result.pose,
                    iterates: result.iterates,
                };
                truth.push(queued, &mut rows);
            } else {
                // The distances to the observations come after the pass, with the markers
                // where it put them (a solved placement is known once the β pass is done).
                observed.push((rows.len(), frame, pose.clone()));
                if !result.iterates.is_empty() {
                    let energy = frame_energy(frame)?;
                    let per: Vec<f64> = result
                        .iterates
                        .iter()
                        .map(|p| energy.inspect(p).total)
                        .collect();
                    row["energy_per_iteration"] = json!(per);
                }
            }
            rows.push(row);
            done += 1;
            progress(done, frames.len())
        },
    )?;
    // The errors against the truth of the frames left (a dozen full meshes per frame with the
    // iterates' V2V: more than the fit itself for the batched neural fitter).
    truth.flush(&mut rows);
    let sensor = match report
        .shape_pass
        .as_ref()
        .and_then(crate::fitting::ShapePass::offsets)
    {
        Some(offsets) => dataset.sensor.placed(offsets.clone())?,
        None => dataset.sensor.clone(),
    };
    for (k, frame, pose) in observed {
        if let Some(e) = lfit_synth::capture::import::observation_errors(
            &dataset, &sensor, &template, frame, &pose,
        ) {
            errors_json(&mut rows[k], "observation", "observations_seen", &e);
            sum_obs += e.mean;
            obs_frames += 1;
            obs_unit = e.unit;
        }
    }
    // The held-out observations against each fit (with the markers or keypoints where a
    // solved placement put them).
    let (mut sum_held, mut held_frames, mut held_unit) = (0.0, 0usize, "");
    // Per item asked for: the sum of its held-out distances and how many were seen.
    let mut by_item = vec![(0.0, 0usize); holdout.as_ref().map_or(0, |h| h.items.len())];
    if let Some(h) = &holdout {
        for (k, frame, pose) in &fitted_poses {
            if let Some((e, items)) = h.score(scored, &sensor, &template, *frame, pose) {
                errors_json(&mut rows[*k], "holdout", "holdout_seen", &e);
                sum_held += e.mean;
                held_frames += 1;
                held_unit = e.unit;
                for (i, d) in items {
                    by_item[i].0 += d;
                    by_item[i].1 += 1;
                }
            }
        }
    }
    let n = frames.len().max(1) as f64;
    let mut summary = json!({
        "frames": frames.len(),
        "mean_energy": sum_e / n,
        "mean_time_s": sum_t / n,
    });
    if height_prior.is_some() {
        summary["mean_rest_height_m"] = json!(sum_rest_height / n);
    }
    if floor.is_some() {
        summary["mean_lowest_sole_m"] = json!(sum_lowest_sole / n);
    }
    if dataset.has_ground_truth() {
        summary["mean_v2v_mm"] = json!(truth.v2v / n);
        summary["mean_mpjpe_mm"] = json!(truth.mpjpe / n);
        summary["mean_pa_mpjpe_mm"] = json!(truth.pa_mpjpe / n);
        // A sequence's jitter against the truth's motion (mm per frame²).
        if let Some(a) = lfit_model::metrics::accel_error_mm(&truth.joints) {
            summary["mean_accel_error_mm"] = json!(a);
        }
        if template.morph.coefficients() > 0 {
            summary["mean_shape_rms"] = json!(truth.coefficient_rms / n);
        }
        if template.layout().shape > 0 {
            summary["mean_shape_v2v_mm"] = json!(truth.shape_v2v / n);
        }
    } else {
        // No V2V/MPJPE without ground truth: energies and distances to the observations.
        summary["ground_truth"] = json!(false);
        if obs_frames > 0 {
            let mean = sum_obs / obs_frames as f64;
            summary[format!("mean_observation_error_{obs_unit}")] = json!(mean);
            if let Some(hint) = placement_hint(dataset, *marker_placement, offsets.is_some(), mean)
            {
                summary["hint"] = json!(hint);
            }
        }
    }
    if scored.reference.is_some() {
        // Frames without any reference joint are left out of the means (and counted here);
        // PA-MPJPE over the frames that hold three or more.
        summary["reference_frames"] = json!(ref_frames);
        if ref_frames > 0 {
            summary["mean_reference_mpjpe_mm"] = json!(sum_ref / ref_frames as f64);
        }
        if ref_pa_frames > 0 {
            summary["mean_reference_pa_mpjpe_mm"] = json!(sum_ref_pa / ref_pa_frames as f64);
            summary["reference_pa_frames"] = json!(ref_pa_frames);
        }
        // A sequence's jitter against the reference's motion (the joints it holds throughout).
        if let Some(a) = scored
            .reference
            .as_ref()
            .and_then(|r| r.accel_error_mm(&reference_joints))
        {
            summary["mean_reference_accel_error_mm"] = json!(a);
        }
    }
    if held_frames > 0 {
        summary[format!("mean_holdout_error_{held_unit}")] = json!(sum_held / held_frames as f64);
        summary["holdout_frames"] = json!(held_frames);
        // Where a fit predicts badly: each item's mean over every frame that saw it (a marker;
        // a camera's keypoints; a joint's keypoints in every camera), in the order given.
        let items = holdout.as_ref().map_or(&[][..], |h| &h.items[..]);
        summary["holdout_by_item"] = Value::Array(
            items
                .iter()
                .zip(&by_item)
                .map(|(item, &(sum, seen))| {
                    let mut o = json!({ "item": item, "seen": seen });
                    if seen > 0 {
                        o[format!("mean_error_{held_unit}")] = json!(sum / seen as f64);
                    }
                    o
                })
                .collect(),
        );
    }
    if let Some(pass) = &report.shape_pass {
        summary["shape_pass"] = json!(pass);
    }
    if known_shape.is_none() && template.layout().shape > 0 {
        summary["shape_at_bound_frames"] = json!(shape_at_bound_frames);
        if let Some(hint) = shape_hint(
            shape_at_bound_frames,
            frames.len(),
            sequence,
            height_prior.is_some(),
            floor.is_some(),
            dataset.sensor.cameras().len() == 1,
        ) {
            eprintln!("warning: {hint}");
            summary["shape_hint"] = json!(hint);
        }
    }
    let mut out = json!({
        "method": fitter.name(),
        "budget": args.budget,
        "strategy": strategy.name(),
        "preset": preset_name,
        "step_scale": step_scale,
        "cma_variant": { "diagonal": cma.diagonal, "elitist": cma.elitist, "popsize": cma.popsize },
        "seed": args.seed,
        "data": (!args.data.as_os_str().is_empty()).then_some(&args.data),
        "modality": dataset.modality().name(),
        "ground_truth": dataset.has_ground_truth(),
        "scenario": scenario.to_string(),
        "mask": mask.name,
        "sequence_shape": sequence_shape.name(),
        "marker_placement": marker_placement.name(),
        "energy_config": config,
        "energy_variant": if config.is_differentiable() { "gradient (EJ off, hinge EA)" } else { "paper (papers/000 eq. 3)" },
        "summary": summary,
        "frames": rows,
    });
    if let Some(h) = &holdout {
        out["holdout"] = json!(h.items);
    }
    if let (Some(h), Some(crate::fitting::KnownShape::Given(beta))) = (height, &known_shape) {
        // The β every frame was given, from the subject's height.
        out["known_shape"] = json!({ "height_m": h, "beta": beta });
    }
    if let Some(h) = height_prior {
        out["height_prior"] = h.json();
    }
    if let (Some(arg), Some(f)) = (prepared.floor, &floor) {
        out["floor"] = arg.json(f.height_m());
    }
    if let Some((o, _)) = offsets {
        // Where the points sat: the file, and the offsets it gave.
        out["offsets"] = json!({ "file": args.offsets, "values": o });
    }
    if neural {
        out["checkpoint"] = json!(args.checkpoint);
        out["device"] = json!(if args.runtime == "burn" {
            args.device.as_str()
        } else {
            "cpu"
        });
        out["runtime"] = json!(args.runtime);
        out["batch"] = json!(plan.frames_per_call());
        // Only when not the default, so that earlier results keep their keys.
        if args.neural_pick != "last" {
            out["neural_pick"] = json!(args.neural_pick);
        }
        if let Some(k) = args.neural_iterations {
            out["neural_iterations"] = json!(k);
        }
        if let Some(t) = args.neural_tolerance {
            out["neural_tolerance"] = json!(t);
        }
    }
    // Which entries moved, where not all of them (the method's name says it too).
    if *dofs != lfit_fitters::Dofs::All {
        out["dofs"] = json!(dofs.name());
    }
    Ok(out)
}

/// Arguments of `lfit objective-server`.
#[derive(Debug, Clone)]
pub struct ServerArgs {
    pub data: PathBuf,
    pub frame: usize,
    pub energy: Option<PathBuf>,
    pub gradient: bool,
    pub budget: Option<usize>,
    pub template: Option<PathBuf>,
}

/// One frame as a problem for an external optimizer: its energy, the scenario's free entries,
/// their box and the start, as `lfit fit` poses it (what `lfit objective-server` serves and the
/// Python `lfit.Energy` wraps). Points `x` hold the free entries only.
pub struct FrameProblem {
    pub energy: Energy,
    pub mask: DofMask,
    pub lower: Vec<f64>,
    pub upper: Vec<f64>,
    /// The full parameter vector the free entries are written into.
    pub start: Vec<f64>,
}

impl FrameProblem {
    /// The same problem with the subject's height as a soft measurement in its energy
    /// (`lfit fit --height-prior`, [`lfit_model::energy::HeightPrior`]).
    /// `truth`: the frame's ground-truth parameters, for `truth` (refused without them).
    pub fn with_height_prior(
        mut self,
        prior: crate::fitting::HeightPriorArg,
        truth: Option<&[f64]>,
    ) -> Result<Self> {
        let heights =
            crate::fitting::FrameHeights::new(prior, self.energy.template(), truth.is_some())?;
        self.energy = heights.apply(self.energy, truth)?;
        Ok(self)
    }

    /// The same problem with the floor as a measurement in its energy (`lfit fit --floor`,
    /// [`lfit_model::energy::FloorPrior`]). `truth`: the frame's ground-truth parameters, for
    /// `truth` (the floor at their lowest sole; refused without them).
    pub fn with_floor(
        mut self,
        arg: crate::fitting::FloorArg,
        truth: Option<&[f64]>,
    ) -> Result<Self> {
        let floor = arg.prior(self.energy.template())?;
        let floor = match arg.height_m {
            Some(_) => floor,
            None => {
                let truth = truth.context(
                    "--floor truth: the frame has no ground truth; give the floor's height in metres",
                )?;
                let at = self.energy.lowest_sole(&floor, truth)?;
                floor.at(at)?
            }
        };
        self.energy = self.energy.with_floor(&floor)?;
        Ok(self)
    }

    /// Frame `frame` of `dataset` with `config`: the dataset's start pose, the scenario's free
    /// entries and box around it.
    pub fn from_dataset(
        dataset: &Dataset,
        template: Arc<Template>,
        frame: usize,
        config: EnergyConfig,
    ) -> Result<Self> {
        let energy = energy_for_frame(dataset, template, frame, config)?;
        let start = dataset.start_poses[frame].clone();
        Ok(Self::around(energy, dataset.meta.config.scenario, start))
    }

    /// `energy` with `scenario`'s free entries and box around `start` (a full parameter vector).
    pub fn around(energy: Energy, scenario: lfit_synth::Scenario, start: Vec<f64>) -> Self {
        let template = energy.template().clone();
        let mask = scenario_mask(scenario, &template);
        let (lower, upper) = scenario_bounds(scenario, &template, &start).restrict(&mask);
        Self {
            energy,
            mask,
            lower,
            upper,
            start,
        }
    }

    /// Number of free entries (the length of a point `x`).
    pub fn dim(&self) -> usize {
        self.mask.dim()
    }

    /// The full parameter vector of the point `x` of the free entries.
    pub fn full(&self, x: &[f64]) -> Vec<f64> {
        let mut pose = self.start.clone();
        self.mask.scatter(x, &mut pose);
        pose
    }

    /// Checks a point: as many numbers as free entries, all finite.
    pub fn check_point(&self, x: &[f64]) -> Result<()> {
        if x.len() != self.dim() {
            bail!("x has {} numbers, expected {}", x.len(), self.dim());
        }
        if let Some(i) = x.iter().position(|v| !v.is_finite()) {
            bail!("x[{i}] is not a finite number ({})", x[i]);
        }
        Ok(())
    }

    /// Residuals at `x` (energy = their sum of squares) and, when asked, the Jacobian over the
    /// free entries, row-major `[residuals × dim]`.
    pub fn residuals_at(&self, x: &[f64], jacobian: bool) -> Result<(Vec<f64>, Option<Vec<f64>>)> {
        if let Some(why) = self.energy.least_squares_unsupported() {
            bail!("no residuals for this energy: {why}");
        }
        let ls = self.energy.least_squares(&self.full(x), jacobian)?;
        let jac = jacobian.then(|| {
            (0..ls.residuals.len())
                .flat_map(|i| {
                    let row = ls.row(i);
                    self.mask.free.iter().map(move |&j| row[j])
                })
                .collect()
        });
        Ok((ls.residuals, jac))
    }
}

/// The energy, free DOFs, box and start of one frame, as served to external optimizers.
pub struct Served {
    pub problem: FrameProblem,
    /// The energy of residual/Jacobian answers: without `--energy`, the one `lfit fit --method
    /// lm` minimises by default (the gradient variant); with it, the same as `problem.energy`.
    pub least_squares: Option<Energy>,
    pub budget: Option<usize>,
}

impl Served {
    pub fn new(args: &ServerArgs) -> Result<Self> {
        if args.budget == Some(0) {
            bail!("--budget must be at least 1 evaluation");
        }
        let config = read_energy_config(args.energy.as_deref(), args.gradient)?;
        let dataset = Dataset::load(&args.data)
            .with_context(|| format!("dataset {}", args.data.display()))?;
        let template = template_for(&dataset, args.template.as_deref())?;
        let problem = FrameProblem::from_dataset(&dataset, template.clone(), args.frame, config)?;
        let least_squares = if args.energy.is_none() && !args.gradient {
            Some(energy_for_frame(
                &dataset,
                template,
                args.frame,
                read_energy_config(None, true)?,
            )?)
        } else {
            None
        };
        Ok(Self {
            problem,
            least_squares,
            budget: args.budget,
        })
    }

    /// The energy that residual answers serve.
    pub fn least_squares_energy(&self) -> &Energy {
        self.least_squares.as_ref().unwrap_or(&self.problem.energy)
    }

    /// Evaluations served so far, values and residuals together.
    pub fn evaluations(&self) -> u64 {
        self.problem.energy.evaluations()
            + self.least_squares.as_ref().map_or(0, Energy::evaluations)
    }

    /// Answers one request line; errors are answers too (`{"error": ...}`), so the server keeps
    /// serving.
    pub fn answer(&self, line: &str) -> Value {
        match self.try_answer(line) {
            Ok(v) => v,
            Err(e) => json!({ "error": format!("{e:#}") }),
        }
    }

    fn try_answer(&self, line: &str) -> Result<Value> {
        let request: Value = serde_json::from_str(line).context("malformed JSON line")?;
        if request.get("describe").and_then(Value::as_bool) == Some(true) {
            return Ok(json!({
                "dim": self.problem.mask.dim(),
                "lower": self.problem.lower,
                "upper": self.problem.upper,
                "start": self.problem.mask.gather(&self.problem.start),
                "names": self.problem.mask.free.iter().map(|&i| self.problem.energy.template().layout().name(i)).collect::<Vec<_>>(),
                "modality": self.problem.energy.modality().name(),
                "energy_config": self.problem.energy.config(),
                "evaluations": self.evaluations(),
                "residuals": self.least_squares_energy().least_squares_unsupported().is_none().then(|| self.least_squares_energy().residual_count()),
            }));
        }
        let Some(x) = request.get("x") else {
            bail!("expected {{\"x\": [...]}} or {{\"describe\": true}}")
        };
        let x = x.as_array().context("\"x\" is not an array")?;
        if x.len() != self.problem.mask.dim() {
            bail!(
                "x has {} numbers, expected {}",
                x.len(),
                self.problem.mask.dim()
            );
        }
        let mut values = Vec::with_capacity(x.len());
        for (i, v) in x.iter().enumerate() {
            match v.as_f64() {
                Some(f) if f.is_finite() => values.push(f),
                _ => bail!("x[{i}] is not a finite number ({v})"),
            }
        }
        let flag = |name: &str| -> Result<bool> {
            match request.get(name) {
                None | Some(Value::Null) => Ok(false),
                Some(Value::Bool(b)) => Ok(*b),
                Some(other) => bail!("\"{name}\" must be true or false (got {other})"),
            }
        };
        let (want_residuals, want_jacobian) = (flag("residuals")?, flag("jacobian")?);
        if want_residuals || want_jacobian {
            let ls_energy = self.least_squares_energy();
            if let Some(why) = ls_energy.least_squares_unsupported() {
                bail!("no residuals for this energy: {why}");
            }
        }
        if let Some(b) = self.budget
            && self.evaluations() >= b as u64
        {
            bail!("budget of {b} evaluations spent");
        }
        let mut pose = self.problem.start.clone();
        self.problem.mask.scatter(&values, &mut pose);
        if want_residuals || want_jacobian {
            let ls = self
                .least_squares_energy()
                .least_squares(&pose, want_jacobian)?;
            let mut answer = json!({ "energy": ls.value(), "residuals": ls.residuals });
            if want_jacobian {
                let rows: Vec<Vec<f64>> = (0..ls.residuals.len())
                    .map(|i| self.problem.mask.gather(ls.row(i)))
                    .collect();
                answer["jacobian"] = json!(rows);
            }
            return Ok(answer);
        }
        let want_grad = request.get("gradient").and_then(Value::as_bool) == Some(true);
        if want_grad {
            let (ev, g) = self.problem.energy.evaluate_with_gradient(&pose);
            Ok(
                json!({ "energy": ev.total, "terms": terms_json(&ev.terms), "gradient": self.problem.mask.gather(&g) }),
            )
        } else {
            let ev = self.problem.energy.evaluate(&pose);
            Ok(json!({ "energy": ev.total, "terms": terms_json(&ev.terms) }))
        }
    }
}

/// `lfit objective-server`: JSON lines on stdin → JSON lines on stdout until end of input.
pub fn objective_server(
    args: &ServerArgs,
    input: impl BufRead,
    mut output: impl Write,
) -> Result<Value> {
    let served = Served::new(args)?;
    for line in input.lines() {
        let line = line.context("reading stdin")?;
        if line.trim().is_empty() {
            continue;
        }
        let answer = served.answer(&line);
        writeln!(output, "{answer}").context("writing stdout")?;
        output.flush().context("writing stdout")?;
    }
    Ok(json!({ "evaluations": served.evaluations() }))
}

/// Arguments of `lfit optimize`.
#[derive(Debug, Clone)]
pub struct OptimizeArgs {
    pub function: String,
    pub dim: usize,
    pub method: String,
    pub preset: String,
    pub budget: usize,
    pub seed: u64,
}

/// `lfit optimize`: one optimizer on a standard test function (domain [−5, 5]^d, start 0, optimum
/// at (1, …, 1) with value 0).
pub fn optimize(args: &OptimizeArgs) -> Result<Value> {
    if args.budget == 0 {
        bail!("--budget must be at least 1 evaluation");
    }
    if args.dim == 0 {
        bail!("--dim must be at least 1");
    }
    let function = optim::testfns::ALL
        .iter()
        .find(|(name, _)| *name == args.function)
        .map(|&(_, f)| f)
        .with_context(|| {
            format!(
                "unknown function '{}' (expected sphere, ellipsoid, rosenbrock or rastrigin)",
                args.function
            )
        })?;
    let method: Method = args
        .method
        .parse()
        .map_err(|_| lfit_fitters::FitError::UnknownMethod(args.method.clone()))?;
    let preset: Preset = args
        .preset
        .parse()
        .map_err(|_| lfit_fitters::FitError::UnknownPreset(args.preset.clone()))?;
    let problem = optim::testfns::problem(args.dim);
    let mut opt = optim::build(method, preset, &problem, args.budget, args.seed, None)?;
    let f = |x: &[f64]| function(x);
    let out = optim::minimize(opt.as_mut(), &f, args.budget, false)?;
    Ok(json!({
        "function": args.function,
        "dim": args.dim,
        "method": opt.name(),
        "seed": args.seed,
        "best_value": out.best_value,
        "best_x": out.best_x,
        "evaluations": out.evaluations,
        "trace": out.trace,
    }))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// β at its box is blamed on depth only where one camera sees the data (a markers or
    /// headset fit was told "one camera trades size against depth"); the count, the advice and
    /// the sequence's β hold either way, and no frame at the box gives no hint.
    #[test]
    fn the_shape_hint_names_one_camera_only_for_one_camera() {
        let phone = shape_hint(3, 30, true, false, false, true).expect("a hint");
        let markers = shape_hint(1, 500, false, false, false, false).expect("a hint");
        assert!(
            phone.contains("one camera trades size against depth"),
            "{phone}"
        );
        assert!(!markers.contains("camera"), "{markers}");
        assert!(markers.contains("in 1 of 500 frames"), "{markers}");
        assert!(markers.contains("--known-shape height:M"), "{markers}");
        assert!(phone.contains("--sequence-shape joint:64"), "{phone}");
        assert!(!markers.contains("--sequence-shape"), "{markers}");
        assert!(shape_hint(0, 500, false, false, false, true).is_none());
    }

    /// Scoring the frames a chunk at a time (2, 3: the queue flushed before a frame is added,
    /// whose row is not in `rows` yet) writes every row and sums every error as scoring them all
    /// at the end does, in frame order and to the bit; each row gets its V2V, MPJPE and the
    /// iterates' V2V, and a sequence keeps every frame's joints. Breaks if a flush scores a
    /// frame whose row is not there yet (out of bounds), skips or repeats one, or sums out of
    /// order.
    #[test]
    fn chunked_truth_scores_are_the_scores_of_all_frames_at_once() {
        let t = lfit_model::default_template();
        let pose = |k: usize| crate::fitting::tests::varied_pose(t.layout().dim(), k);
        let truths: Vec<Vec<f64>> = (0..7).map(|f| pose(f + 20)).collect();
        // Every other frame with the fitter's iterates.
        let iterates = |f: usize| match f % 2 {
            0 => vec![pose(f + 40), pose(f)],
            _ => Vec::new(),
        };
        let score = |chunk: usize| {
            let mut scores = TruthScores::new(&t, true, chunk);
            let mut rows: Vec<Value> = Vec::new();
            for (f, truth) in truths.iter().enumerate() {
                let queued = Queued {
                    row: rows.len(),
                    frame: f,
                    truth,
                    pose: pose(f),
                    iterates: iterates(f),
                };
                scores.push(queued, &mut rows);
                rows.push(json!({ "frame": f }));
            }
            scores.flush(&mut rows);
            assert!(scores.pending.is_empty());
            (rows, scores)
        };
        let (want_rows, want) = score(usize::MAX);
        assert!(want.v2v > 0.0 && want.mpjpe > 0.0, "{}", want.v2v);
        assert_eq!(want.joints.len(), 7);
        for (f, row) in want_rows.iter().enumerate() {
            assert!(row["v2v_mm"].as_f64().is_some_and(|v| v > 0.0), "{row}");
            assert!(row["mpjpe_mm"].is_f64(), "{row}");
            assert_eq!(row["v2v_mm_per_iteration"].is_array(), f % 2 == 0, "{row}");
        }
        for chunk in [1, 2, 3] {
            let (rows, got) = score(chunk);
            assert_eq!(rows, want_rows, "chunk {chunk}");
            for (g, w) in [
                (got.v2v, want.v2v),
                (got.mpjpe, want.mpjpe),
                (got.pa_mpjpe, want.pa_mpjpe),
                (got.coefficient_rms, want.coefficient_rms),
                (got.shape_v2v, want.shape_v2v),
            ] {
                assert_eq!(g.to_bits(), w.to_bits(), "chunk {chunk}");
            }
            let frames = |s: &TruthScores| s.joints.iter().map(|j| j.0).collect::<Vec<_>>();
            assert_eq!(frames(&got), (0..7).collect::<Vec<_>>(), "chunk {chunk}");
        }
    }
}
