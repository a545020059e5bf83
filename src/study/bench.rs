//! `lfit bench`: methods × strategies × budgets × repetitions × frames on one energy
//! configuration (SPEC §9). Runs in parallel, appends every finished run to `runs.csv` so a killed
//! run resumes where it stopped, shards with `--shard i/n`, and merges shards
//! (`lfit bench merge`). The report is written by [`crate::study::report`].

use std::collections::{BTreeMap, HashSet};
use std::io::Write;
use std::path::{Path, PathBuf};
use std::sync::Mutex;

use anyhow::{Context, Result, bail};
use lfit_fitters::optim::Preset;
use lfit_fitters::optim::cma::CmaVariant;
use lfit_fitters::{Fitter, Strategy};

use crate::method::{MethodKind, MethodSpec};
use lfit_model::energy::{Energy, EnergyConfig};
use lfit_model::metrics::{
    FaceErrors, TruthMesh, aligned_joint_error_mm, face_errors_mm, joint_error_mm, joint_positions,
};
use lfit_model::template::write_atomic;
use lfit_synth::{Dataset, Scenario};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::cli::fit::{frame_seed, iterate_v2v, parse_frames, read_energy_config, template_for};
use crate::fitting::energy_with_priors;

/// Dataset to synthesise when the config names none.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SynthSpec {
    pub modality: String,
    #[serde(default = "default_scenario")]
    pub scenario: String,
    pub frames: usize,
    #[serde(default)]
    pub seed: u64,
    #[serde(default = "one_f")]
    pub noise: f64,
    /// Imported motion files (`lfit motion import`) the target poses come from instead of the
    /// procedural library (`lfit synth --motions`).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub motions: Vec<PathBuf>,
    /// Pose source (`lfit synth --source`): motion (default), uniform or face (papers/002's face
    /// protocol).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub source: Option<String>,
    /// keypoints2d: the cameras of a camera file (`lfit synth --camera`; a relative path is
    /// also looked up where the shipped data are, e.g. `configs/rigs/phone-1.json`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub camera: Option<PathBuf>,
}

fn default_scenario() -> String {
    "local".into()
}
fn one_f() -> f64 {
    1.0
}
fn one() -> usize {
    1
}
fn alpha() -> f64 {
    0.05
}
fn holistic() -> Vec<String> {
    vec!["holistic".into()]
}
fn true_() -> bool {
    true
}

/// `BENCH.toml`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct BenchConfig {
    pub name: String,
    /// Dataset (.npz); or `[synth]` to generate one into the output directory.
    pub data: Option<PathBuf>,
    pub synth: Option<SynthSpec>,
    /// Model file (`lfit model import-*`) the data is made with and fitted on; default the
    /// procedural template. A relative path is looked up like a shipped checkpoint.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub template: Option<PathBuf>,
    /// The subject's shape β is given (each frame's truth) and frozen for every method
    /// (papers/002 §3.2, HMD); required by a checkpoint trained with the shape known.
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub known_shape: bool,
    /// The subject's height as a soft measurement in every method's energy, `"M[:STD]"` or
    /// `"truth[:STD]"` (each frame's ground truth) — `lfit fit --height-prior`
    /// ([`crate::fitting::HeightPriorArg`]). Not with `known_shape`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub height_prior: Option<String>,
    /// The floor the subject stands on in every method's energy, `"FORM:HEIGHT[,MM]"` —
    /// `lfit fit --floor` ([`crate::fitting::FloorArg`]; `truth`: the median over the bench's
    /// frames of the ground truth's lowest sole).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub floor: Option<String>,
    /// `"METHOD"` or `"METHOD:STRATEGY"` ([`MethodSpec`]).
    pub methods: Vec<MethodSpec>,
    pub budgets: Vec<usize>,
    #[serde(default = "one")]
    pub repetitions: usize,
    /// Frames (`A..B`, `A-B`, `I`, comma list); default all.
    pub frames: Option<String>,
    #[serde(default = "holistic")]
    pub strategies: Vec<String>,
    /// `tuned`, `nevergrad` or `paper001` ([`BenchConfig::steps`]); none: tuned where recorded.
    #[serde(default)]
    pub preset: Option<String>,
    /// `paper` (papers/000 eq. 3), `gradient` (EJ off, hinge EA) or a JSON file; default
    /// `gradient` when a gradient method (lbfgs, neural) is in the list, else `paper`.
    pub energy: Option<String>,
    /// Neural fitter checkpoint (required with method `neural`).
    pub checkpoint: Option<PathBuf>,
    #[serde(default)]
    pub neural_start: Option<String>,
    /// Which iterate a neural fit returns: `last` (default) or `lowest` (`lfit fit
    /// --neural-pick`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub neural_pick: Option<String>,
    /// A neural method's first K iterations only (`lfit fit --neural-iterations`); absent: all N.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub neural_iterations: Option<usize>,
    /// A neural method's energy rule (`lfit fit --neural-tolerance`); absent: none.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub neural_tolerance: Option<f64>,
    /// What runs a neural method's network: `burn` (default, on flex), `native` (lfit's own f32
    /// forward, the fastest at batch 1) or `ort` (ONNX Runtime); as `lfit fit --runtime`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub runtime: Option<String>,
    /// How a sequence estimates β: `per-frame` (default), `first-pass`, `joint` or `joint:N`
    /// ([`crate::fitting::SequenceShape`]).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub sequence_shape: Option<String>,
    /// Where a markers sequence's markers sit: `model` (default) or `solve` (with
    /// `sequence_shape = "joint[:N]"`; [`crate::fitting::MarkerPlacement`]).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub marker_placement: Option<String>,
    /// Which free entries each fit moves: `all`, `observed`, `observed:DEG`, `anchored`,
    /// `anchored:DEG`, `anchored:DEG,MM` or `observed[:DEG]+anchored[:DEG[,MM]]` (`lfit fit
    /// --dofs`, every method's, the network's too); default each method's own (anchored for
    /// `neural+lm`'s LM stage on markers, keypoints2d and hmd:
    /// [`crate::method::MethodKind::default_dofs`]; `all` otherwise).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub dofs: Option<String>,
    #[serde(default)]
    pub seed: u64,
    #[serde(default = "alpha")]
    pub alpha: f64,
    /// Run fits in parallel (rayon); false for timing studies.
    #[serde(default = "true_")]
    pub parallel: bool,
    /// Smaller sizes for `--quick` (presets); resolved away before a run.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub quick: Option<QuickSize>,
}

/// The `[quick]` section: what `--quick` replaces.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct QuickSize {
    /// Frames to synthesise (`[synth] frames`).
    pub frames: Option<usize>,
    pub repetitions: Option<usize>,
    pub budgets: Option<Vec<usize>>,
}

impl BenchConfig {
    /// Reads and validates a config; `quick` applies its `[quick]` section.
    pub fn load(path: &Path, quick: bool) -> Result<Self> {
        let text = std::fs::read_to_string(path)
            .with_context(|| format!("cannot read bench config {}", path.display()))?;
        let config: Self = toml::from_str(&text).map_err(|e| {
            anyhow::anyhow!("malformed bench config {}: {}", path.display(), e.message())
        })?;
        if quick && config.quick.is_none() {
            bail!(
                "--quick: bench config {} has no [quick] section",
                path.display()
            );
        }
        let config = config.resolve(quick);
        config
            .validate()
            .with_context(|| format!("bench config {}", path.display()))?;
        Ok(config)
    }

    /// The config to run: with `quick`, the `[quick]` sizes replace the full ones; the section
    /// itself is dropped either way.
    pub fn resolve(mut self, quick: bool) -> Self {
        if let (true, Some(q)) = (quick, self.quick.take()) {
            if let (Some(f), Some(s)) = (q.frames, self.synth.as_mut()) {
                s.frames = f;
            }
            if let Some(r) = q.repetitions {
                self.repetitions = r;
            }
            if let Some(b) = q.budgets {
                self.budgets = b;
            }
        }
        self.quick = None;
        self
    }

    /// Every setting checked before any work starts.
    pub fn validate(&self) -> Result<()> {
        if self.methods.is_empty() {
            bail!("methods: need at least one");
        }
        if self.budgets.is_empty() || self.budgets.contains(&0) {
            bail!(
                "budgets: need at least one, each at least 1 evaluation (got {:?})",
                self.budgets
            );
        }
        if self.repetitions == 0 {
            bail!("repetitions must be at least 1");
        }
        for s in &self.strategies {
            s.parse::<Strategy>()?;
        }
        if self.strategies.is_empty() {
            bail!("strategies: need at least one");
        }
        self.preset()?;
        if let Some(d) = &self.dofs {
            d.parse::<lfit_fitters::Dofs>()
                .map_err(anyhow::Error::msg)
                .context("dofs")?;
        }
        self.entries()?;
        match (&self.data, &self.synth) {
            (Some(d), None) if !d.exists() => bail!("data file {} does not exist", d.display()),
            (Some(_), Some(_)) => bail!("give either data or [synth], not both"),
            (None, None) => bail!("give data = \"FILE.npz\" or a [synth] section"),
            (None, Some(s)) if s.frames == 0 => bail!("synth.frames must be at least 1"),
            _ => {}
        }
        if let Some(s) = &self.synth
            && let Some(c) = &s.camera
        {
            if s.modality != "keypoints2d" {
                bail!(
                    "synth.camera sets the keypoints2d rig; {} takes its default setup",
                    s.modality
                );
            }
            crate::shipped::locate(c).context("synth.camera")?;
        }
        if let Some(f) = &self.floor {
            f.parse::<crate::fitting::FloorArg>().context("floor")?;
        }
        if let Some(h) = &self.height_prior {
            h.parse::<crate::fitting::HeightPriorArg>()
                .context("height_prior")?;
            if self.known_shape {
                bail!("height_prior informs an estimated β, known_shape gives β: use one");
            }
        }
        if self.known_shape {
            // `-`: the neural fitter, which has no strategy.
            for (_, s) in self.entries()?.iter().filter(|(_, s)| s != "-") {
                crate::fitting::KnownShape::check_strategy(s.parse()?).context("known_shape")?;
            }
        }
        if let Some(t) = &self.template
            && !t.exists()
        {
            bail!("template {} does not exist", t.display());
        }
        if let Some(m) = self.methods.iter().find(|m| m.kind.is_neural()) {
            let Some(c) = &self.checkpoint else {
                bail!("method {} needs checkpoint = \"DIR\"", m.kind)
            };
            if !c.join("config.json").exists() {
                bail!("checkpoint {} has no config.json", c.display());
            }
            #[cfg(not(feature = "neural"))]
            bail!(crate::method::NO_NEURAL);
            #[cfg(feature = "neural")]
            {
                self.neural_start()?;
                self.runtime()?;
                if !self.known_shape && checkpoint_knows_shape(c)? {
                    bail!(
                        "checkpoint {} was trained with the shape β known (papers/002 §3.2): set known_shape = true",
                        c.display()
                    );
                }
            }
        }
        if (self.neural_iterations.is_some() || self.neural_tolerance.is_some())
            && !self.methods.iter().any(|m| m.kind.is_neural())
        {
            bail!(
                "neural_iterations and neural_tolerance are for the neural methods (neural, neural+lm): none is listed"
            );
        }
        if self.neural_iterations == Some(0) {
            bail!("neural_iterations must be at least 1");
        }
        if let Some(t) = self.neural_tolerance
            && !(t > 0.0 && t < 1.0)
        {
            bail!("neural_tolerance {t}: a relative energy decrease between 0 and 1 (exclusive)");
        }
        self.sequence_shape()?;
        self.marker_placement()?;
        if !(self.alpha > 0.0 && self.alpha < 1.0) {
            bail!("alpha must be in (0, 1), got {}", self.alpha);
        }
        self.energy_config()?;
        Ok(())
    }

    /// The model the benchmark runs on: `template`, or the procedural template.
    fn model(&self) -> Result<lfit_model::Template> {
        crate::data::load_model(self.template.as_deref(), "default")
    }

    /// The sweep's lines, `(method, strategy)` in config order: a method crossed with every
    /// strategy, a `method:strategy` entry with its own, and `neural` with `-`.
    pub fn entries(&self) -> Result<Vec<(String, String)>> {
        let mut out: Vec<(String, String)> = Vec::new();
        for m in &self.methods {
            let name = m.kind.name().to_string();
            let add: Vec<(String, String)> = match m.strategy {
                Some(s) => vec![(name, s.to_string())],
                None if !m.kind.has_strategies() => vec![(name, "-".into())],
                None => self
                    .strategies
                    .iter()
                    .map(|s| Ok((name.clone(), s.parse::<Strategy>()?.to_string())))
                    .collect::<Result<_>>()?,
            };
            for e in add {
                if out.contains(&e) {
                    bail!("methods: '{}' with strategy '{}' is listed twice", e.0, e.1);
                }
                out.push(e);
            }
        }
        Ok(out)
    }

    /// Whether report labels name the strategy (the sweep has more than one).
    pub fn shows_strategy(&self) -> bool {
        let mut seen: Vec<String> = Vec::new();
        for (_, s) in self.entries().unwrap_or_default() {
            if s != "-" && !seen.contains(&s) {
                seen.push(s);
            }
        }
        seen.len() > 1
    }

    /// The initial steps and CMA-ES variant of zeroth-order method `method` on `modality`.
    /// `preset = "tuned"`: its recorded setting ([`crate::study::tuned`]; an error when there is none).
    /// No preset: the recorded setting where there is one, papers/000's steps otherwise (each
    /// baseline at its best; the papers' studies name their preset). `nevergrad`, `paper001`:
    /// papers/000's steps.
    pub fn steps(&self, method: &str, modality: &str) -> Result<(f64, CmaVariant)> {
        let tuned = crate::study::tuned::choose(self.preset.as_deref(), method, &mut || {
            Ok(modality.to_string())
        })?;
        Ok(tuned.map_or((1.0, CmaVariant::default()), |t| (t.step_scale, t.cma)))
    }

    fn preset(&self) -> Result<Preset> {
        let p = self.preset.as_deref().unwrap_or("nevergrad");
        if p == "tuned" {
            return Ok(Preset::Nevergrad);
        }
        p.parse()
            .map_err(|_| lfit_fitters::FitError::UnknownPreset(p.to_string()).into())
    }

    /// `dofs` for one method on data of `modality`, a sequence or not (`lfit fit --dofs`; the
    /// network too).
    fn dofs_for(
        &self,
        kind: MethodKind,
        modality: lfit_model::observe::Modality,
        sequence: bool,
    ) -> Result<lfit_fitters::Dofs> {
        crate::method::dofs_for(
            kind,
            self.dofs.as_deref(),
            &mut || Ok((modality, sequence)),
            self.neural_start_name(),
        )
        .context("dofs")
    }

    /// The sequence shape policy (`sequence_shape`, default per-frame).
    pub fn sequence_shape(&self) -> Result<crate::fitting::SequenceShape> {
        self.sequence_shape
            .as_deref()
            .unwrap_or("per-frame")
            .parse()
            .context("sequence_shape")
    }

    /// Where a markers sequence's markers sit (`marker_placement`, default model).
    pub fn marker_placement(&self) -> Result<crate::fitting::MarkerPlacement> {
        self.marker_placement
            .as_deref()
            .unwrap_or("model")
            .parse()
            .context("marker_placement")
    }

    /// `neural_start` as named (default `given`): the network's start and its anchor's.
    fn neural_start_name(&self) -> &str {
        self.neural_start.as_deref().unwrap_or("given")
    }

    #[cfg(feature = "neural")]
    fn neural_start(&self) -> Result<lfit_infer::Start> {
        self.neural_start_name().parse().map_err(anyhow::Error::msg)
    }

    #[cfg(feature = "neural")]
    fn runtime(&self) -> Result<lfit_infer::Runtime> {
        self.runtime
            .as_deref()
            .unwrap_or("burn")
            .parse()
            .map_err(anyhow::Error::msg)
            .context("runtime")
    }

    /// The one energy configuration of the benchmark and its name.
    pub fn energy_config(&self) -> Result<(EnergyConfig, String)> {
        let gradient_method = self.methods.iter().any(|m| m.kind.uses_gradient());
        match self.energy.as_deref() {
            None if gradient_method => {
                Ok((EnergyConfig::default().for_gradient(), "gradient".into()))
            }
            None | Some("paper") => Ok((EnergyConfig::default(), "paper".into())),
            Some("gradient") => Ok((EnergyConfig::default().for_gradient(), "gradient".into())),
            Some(path) => Ok((
                read_energy_config(Some(Path::new(path)), false)?,
                path.to_string(),
            )),
        }
    }
}

/// The work of one parallel task: one entry (method with strategy), budget and repetition on
/// one frame, or on every frame in order for a sequence (indices into the selected frames).
#[derive(Debug, Clone, PartialEq, Eq)]
struct Unit {
    entry: usize,
    budget: usize,
    rep: usize,
    frames: Vec<usize>,
}

/// One row of `runs.csv`.
#[derive(Debug, Clone, PartialEq)]
pub struct Run {
    pub method: String,
    pub strategy: String,
    pub budget: usize,
    pub rep: usize,
    pub frame: usize,
    pub seed: u64,
    pub energy: f64,
    pub start_energy: f64,
    pub v2v_mm: f64,
    pub mpjpe_mm: f64,
    pub pa_mpjpe_mm: f64,
    pub hausdorff_mm: f64,
    /// RMS error of the shape (and expression) coefficients; NaN on a model without them.
    pub shape_rms: f64,
    pub evaluations: u64,
    pub gradient_evaluations: u64,
    pub iterations: u64,
    pub time_s: f64,
    /// `(evaluations, best energy)`.
    pub trace: Vec<(u64, f64)>,
    /// V2V (mm) of every iterate (neural fitter only).
    pub v2v_per_iteration: Vec<f64>,
    /// papers/002 Table 7's errors on a face model (with a face region and landmarks).
    pub face: Option<FaceErrors>,
    /// The shape error in mm: the mean vertex distance of the fitted and the true shape's rest
    /// meshes ([`lfit_model::metrics::shape_v2v_mm`], PVE-T); NaN on a model without shape
    /// coefficients.
    pub shape_v2v_mm: f64,
}

pub const CSV_HEADER: &str = "method,strategy,budget,rep,frame,seed,energy,start_energy,v2v_mm,mpjpe_mm,pa_mpjpe_mm,hausdorff_mm,shape_rms,evaluations,gradient_evaluations,iterations,time_s,trace,v2v_per_iteration,face,shape_v2v_mm";
/// The header before the `shape_v2v_mm` column (files written before it still read, as NaN).
const CSV_HEADER_V3: &str = "method,strategy,budget,rep,frame,seed,energy,start_energy,v2v_mm,mpjpe_mm,pa_mpjpe_mm,hausdorff_mm,shape_rms,evaluations,gradient_evaluations,iterations,time_s,trace,v2v_per_iteration,face";
/// The header before the `face` column (files written before it still read, without face errors).
const CSV_HEADER_V2: &str = "method,strategy,budget,rep,frame,seed,energy,start_energy,v2v_mm,mpjpe_mm,pa_mpjpe_mm,hausdorff_mm,shape_rms,evaluations,gradient_evaluations,iterations,time_s,trace,v2v_per_iteration";
/// The header before the `shape_rms` column (files written before it still read, as NaN).
const CSV_HEADER_V1: &str = "method,strategy,budget,rep,frame,seed,energy,start_energy,v2v_mm,mpjpe_mm,pa_mpjpe_mm,hausdorff_mm,evaluations,gradient_evaluations,iterations,time_s,trace,v2v_per_iteration";

impl Run {
    pub fn key(&self) -> (String, String, usize, usize, usize) {
        (
            self.method.clone(),
            self.strategy.clone(),
            self.budget,
            self.rep,
            self.frame,
        )
    }

    pub fn to_csv(&self) -> String {
        let trace = self
            .trace
            .iter()
            .map(|(e, v)| format!("{e}:{v:e}"))
            .collect::<Vec<_>>()
            .join(";");
        let iters = self
            .v2v_per_iteration
            .iter()
            .map(|v| format!("{v:.4}"))
            .collect::<Vec<_>>()
            .join(";");
        let face = self.face.map_or_else(String::new, |f| {
            f.to_array()
                .iter()
                .map(|v| format!("{v:.4}"))
                .collect::<Vec<_>>()
                .join(";")
        });
        format!(
            "{},{},{},{},{},{},{:e},{:e},{:.4},{:.4},{:.4},{:.4},{:.5},{},{},{},{:.6},{trace},{iters},{face},{:.4}",
            self.method,
            self.strategy,
            self.budget,
            self.rep,
            self.frame,
            self.seed,
            self.energy,
            self.start_energy,
            self.v2v_mm,
            self.mpjpe_mm,
            self.pa_mpjpe_mm,
            self.hausdorff_mm,
            self.shape_rms,
            self.evaluations,
            self.gradient_evaluations,
            self.iterations,
            self.time_s,
            self.shape_v2v_mm
        )
    }

    pub fn from_csv(line: &str) -> Option<Self> {
        let mut f: Vec<&str> = line.split(',').collect();
        // A row without `shape_rms` (CSV_HEADER_V1): NaN.
        if f.len() == 18 {
            f.insert(12, "NaN");
        }
        // A row without `face` (CSV_HEADER_V2): none.
        if f.len() == 19 {
            f.push("");
        }
        // A row without `shape_v2v_mm` (CSV_HEADER_V3): NaN.
        if f.len() == 20 {
            f.push("NaN");
        }
        if f.len() != 21 {
            return None;
        }
        let face = if f[19].is_empty() {
            None
        } else {
            let v: Vec<f64> = f[19]
                .split(';')
                .map(|v| v.parse().ok())
                .collect::<Option<_>>()?;
            Some(FaceErrors::from_array(v.try_into().ok()?))
        };
        let trace = if f[17].is_empty() {
            Vec::new()
        } else {
            f[17]
                .split(';')
                .map(|p| {
                    p.split_once(':')
                        .and_then(|(e, v)| Some((e.parse().ok()?, v.parse().ok()?)))
                })
                .collect::<Option<Vec<_>>>()?
        };
        let iters = if f[18].is_empty() {
            Vec::new()
        } else {
            f[18]
                .split(';')
                .map(|v| v.parse().ok())
                .collect::<Option<Vec<f64>>>()?
        };
        Some(Self {
            method: f[0].to_string(),
            strategy: f[1].to_string(),
            budget: f[2].parse().ok()?,
            rep: f[3].parse().ok()?,
            frame: f[4].parse().ok()?,
            seed: f[5].parse().ok()?,
            energy: f[6].parse().ok()?,
            start_energy: f[7].parse().ok()?,
            v2v_mm: f[8].parse().ok()?,
            mpjpe_mm: f[9].parse().ok()?,
            pa_mpjpe_mm: f[10].parse().ok()?,
            hausdorff_mm: f[11].parse().ok()?,
            shape_rms: f[12].parse().ok()?,
            evaluations: f[13].parse().ok()?,
            gradient_evaluations: f[14].parse().ok()?,
            iterations: f[15].parse().ok()?,
            time_s: f[16].parse().ok()?,
            trace,
            v2v_per_iteration: iters,
            face,
            shape_v2v_mm: f[20].parse().ok()?,
        })
    }
}

/// Reads the complete rows of a `runs.csv` (a torn last line from a killed run is dropped).
pub fn read_runs(path: &Path) -> Result<Vec<Run>> {
    let text = match std::fs::read_to_string(path) {
        Ok(t) => t,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(Vec::new()),
        Err(e) => return Err(e).with_context(|| format!("cannot read {}", path.display())),
    };
    let mut lines: Vec<&str> = text.split('\n').collect();
    // Only lines ended by '\n' are complete.
    lines.pop();
    let mut runs = Vec::new();
    for (i, line) in lines.iter().enumerate() {
        if i == 0 {
            if ![CSV_HEADER, CSV_HEADER_V3, CSV_HEADER_V2, CSV_HEADER_V1].contains(line) {
                bail!(
                    "{} is not an lfit bench runs.csv (unexpected header)",
                    path.display()
                );
            }
            continue;
        }
        match Run::from_csv(line) {
            Some(r) => runs.push(r),
            None => bail!("{}: malformed row {}", path.display(), i + 1),
        }
    }
    Ok(runs)
}

/// Which jobs this process runs: `i/n` (0-based shard `i` of `n`).
pub fn parse_shard(spec: Option<&str>) -> Result<(usize, usize)> {
    let Some(s) = spec else { return Ok((0, 1)) };
    let parsed = s.split_once('/').and_then(|(a, b)| {
        Some((
            a.trim().parse::<usize>().ok()?,
            b.trim().parse::<usize>().ok()?,
        ))
    });
    match parsed {
        Some((i, n)) if n >= 1 && i < n => Ok((i, n)),
        _ => bail!("--shard must be i/n with 0 ≤ i < n, got '{s}'"),
    }
}

/// What a sweep's rows are fitted from, beyond `bench.json`.
struct Inputs<'a> {
    data: &'a Path,
    template: &'a lfit_model::Template,
    energy: &'a EnergyConfig,
    /// The fitters' names, one per entry: they say what a method does where a build changed it
    /// under the same config (`neural+lm`'s LM stage anchored at the network: `…+lm-anchored`).
    fitters: &'a [String],
}

/// What the rows of `runs.csv` depend on beyond `bench.json`: the bytes of the data file, the
/// model's signature, the energy configuration, the checkpoint's files (a retrained network
/// under the same path) and the fitters' names, each as an FNV-1a hash.
fn input_hashes(
    config: &BenchConfig,
    inputs: &Inputs<'_>,
) -> Result<serde_json::Map<String, serde_json::Value>> {
    let Inputs {
        data,
        template,
        energy,
        fitters,
    } = *inputs;
    let file_hash = |paths: &[PathBuf]| -> Result<String> {
        let mut h = lfit_model::Fnv1a::default();
        for p in paths {
            let bytes = std::fs::read(p).with_context(|| format!("cannot read {}", p.display()))?;
            h.eat(&(bytes.len() as u64).to_le_bytes());
            h.eat(&bytes);
        }
        Ok(h.hex())
    };
    let mut inputs = serde_json::Map::new();
    inputs.insert("data".into(), file_hash(&[data.to_path_buf()])?.into());
    inputs.insert("model".into(), template.signature().hash.into());
    let mut h = lfit_model::Fnv1a::default();
    h.eat(&serde_json::to_vec(energy)?);
    if let Some(p) = &config.height_prior {
        // The height prior is a row of every frame's energy.
        h.eat(p.as_bytes());
    }
    if let Some(f) = &config.floor {
        // So is the floor.
        h.eat(b"floor");
        h.eat(f.as_bytes());
    }
    inputs.insert("energy".into(), h.hex().into());
    if let Some(c) = &config.checkpoint
        && config.methods.iter().any(|m| m.kind.is_neural())
    {
        let dir = crate::shipped::locate_or_given(c);
        // The files a fit reads: the network's description, feature statistics and weights, and
        // the graphs of an `lfit export-onnx` directory (not metrics or optimizer state).
        let mut files: Vec<PathBuf> = std::fs::read_dir(&dir)
            .with_context(|| format!("cannot read checkpoint {}", dir.display()))?
            .filter_map(|e| e.ok().map(|e| e.path()))
            .filter(|p| {
                let name = p.file_name().and_then(|n| n.to_str()).unwrap_or_default();
                matches!(name, "config.json" | "stats.json" | "weights.bpk")
                    || name.ends_with(".onnx")
            })
            .collect();
        files.sort();
        inputs.insert("checkpoint".into(), file_hash(&files)?.into());
    }
    let mut h = lfit_model::Fnv1a::default();
    h.eat(&serde_json::to_vec(fitters)?);
    inputs.insert("fitters".into(), h.hex().into());
    Ok(inputs)
}

/// Resuming is safe only over the same inputs: refuses an `out` whose runs were fitted with
/// another data file, model, energy, checkpoint or fitter than now (a checkpoint retrained in
/// place would otherwise leave its old rows in the report), and records the inputs of a new one;
/// `has_rows`: `runs.csv` holds complete rows already.
fn check_inputs(
    config: &BenchConfig,
    out: &Path,
    inputs: &Inputs<'_>,
    has_rows: bool,
) -> Result<()> {
    let now = input_hashes(config, inputs)?;
    let path = out.join("inputs.json");
    if let Ok(text) = std::fs::read_to_string(&path) {
        let before: serde_json::Map<String, serde_json::Value> =
            serde_json::from_str(&text).with_context(|| format!("malformed {}", path.display()))?;
        let changed: Vec<&str> = now
            .iter()
            .filter(|(k, v)| before.get(*k) != Some(*v))
            .map(|(k, _)| k.as_str())
            .chain(
                before
                    .keys()
                    .filter(|k| !now.contains_key(*k))
                    .map(String::as_str),
            )
            .collect();
        if !changed.is_empty() {
            bail!(
                "{} holds runs fitted with other inputs ({} changed since: {}); use another --out or remove it",
                out.display(),
                changed.join(", "),
                path.display()
            );
        }
        return Ok(());
    }
    // Rows without a record of their inputs (a directory of a build before this one) cannot be
    // vouched for.
    if has_rows {
        bail!(
            "{} holds runs without a record of their inputs ({} is missing: written by an older lfit); use another --out or remove it",
            out.display(),
            path.display()
        );
    }
    write_atomic(&path, &serde_json::to_vec_pretty(&now)?)?;
    Ok(())
}

/// Whether the checkpoint in `dir` was trained with the shape known.
#[cfg(feature = "neural")]
fn checkpoint_knows_shape(dir: &Path) -> Result<bool> {
    let path = dir.join("config.json");
    let text = std::fs::read_to_string(&path)
        .with_context(|| format!("cannot read {}", path.display()))?;
    let meta: lfit_nn::CheckpointMeta =
        serde_json::from_str(&text).with_context(|| format!("malformed {}", path.display()))?;
    Ok(meta.network.known_shape)
}

/// Runs the sweep (or one shard of it) into `out`; returns the rows of this shard, sorted.
pub fn run(
    config: &BenchConfig,
    out: &Path,
    shard: (usize, usize),
    progress: &(dyn Fn(usize, usize) + Sync),
) -> Result<Vec<Run>> {
    config.validate()?;
    std::fs::create_dir_all(out).with_context(|| format!("cannot create {}", out.display()))?;
    let config_json = serde_json::to_vec_pretty(config)?;
    let saved = out.join("bench.json");
    if let Ok(prev) = std::fs::read(&saved)
        && prev != config_json
    {
        bail!(
            "{} holds a different benchmark (bench.json differs); use another --out",
            out.display()
        );
    }
    write_atomic(&saved, &config_json)?;
    let data = match (&config.data, &config.synth) {
        (Some(d), _) => d.clone(),
        (None, Some(s)) => {
            let path = out.join("data.npz");
            if !path.exists() {
                let template = config.model()?;
                let args = crate::data::SynthArgs {
                    modality: s.modality.clone(),
                    scenario: s.scenario.clone(),
                    source: s.source.clone().unwrap_or_else(|| "motion".into()),
                    frames: s.frames,
                    seed: s.seed,
                    fps: 30.0,
                    noise: s.noise,
                    noise_spread: 0.0,
                    motions: None,
                    marker_slip_mm: 0.0,
                    keypoint_bias_mm: 0.0,
                    keypoint_detector: None,
                    out: path.clone(),
                };
                let files = crate::data::MotionFilesArgs {
                    files: s.motions.clone(),
                    ..Default::default()
                };
                let camera = s.camera.as_deref().map(crate::shipped::locate_or_given);
                let rig =
                    crate::data::Rig::from_args(None, camera.as_deref()).context("synth.camera")?;
                crate::data::synth_with_cameras(&args, &files, &rig, &template, &|_| {})?;
            }
            path
        }
        (None, None) => bail!("no data"),
    };
    let dataset = Dataset::load(&data).with_context(|| format!("dataset {}", data.display()))?;
    if !dataset.has_ground_truth() {
        bail!(
            "dataset {} has no ground truth (imported observations): lfit bench reports V2V/MPJPE; fit it with lfit fit, which reports energies and observation errors",
            data.display()
        );
    }
    let frames = parse_frames(config.frames.as_deref(), dataset.len())?;
    let template = template_for(&dataset, config.template.as_deref())?;
    let (energy_config, _) = config.energy_config()?;
    let csv = out.join("runs.csv");
    let existing = read_runs(&csv)?;
    let scenario = dataset.meta.config.scenario;
    let sequence = scenario == Scenario::Sequence;
    let entries = config.entries()?;
    let preset = config.preset()?;
    // One fitter per entry; the neural checkpoint is loaded once.
    let mut fitters: Vec<Box<dyn Fitter>> = Vec::new();
    for (m, s) in &entries {
        let kind: MethodKind = m.parse()?;
        if kind.is_neural() {
            let dir = config.checkpoint.as_deref().context("checkpoint")?;
            fitters.push(crate::method::load_neural_named(
                kind,
                dir,
                config.neural_start_name(),
                config.neural_pick.as_deref().unwrap_or("last"),
                config.neural_iterations,
                config.neural_tolerance,
                config.runtime.as_deref().unwrap_or("burn"),
                "flex",
                None,
                config.dofs_for(kind, dataset.modality(), sequence)?,
            )?);
        } else {
            let (step_scale, cma) = if kind.zeroth_order().is_some() {
                config.steps(kind.name(), dataset.modality().name())?
            } else {
                (1.0, Default::default())
            };
            fitters.push(crate::method::build_classic(
                kind,
                crate::method::ClassicOptions {
                    preset,
                    strategy: s.parse()?,
                    step_scale,
                    cma,
                    dofs: config.dofs_for(kind, dataset.modality(), sequence)?,
                },
            )?);
        }
    }
    let names: Vec<String> = fitters.iter().map(|f| f.name()).collect();
    check_inputs(
        config,
        out,
        &Inputs {
            data: &data,
            template: &template,
            energy: &energy_config,
            fitters: &names,
        },
        !existing.is_empty(),
    )?;
    let heights = config
        .height_prior
        .as_deref()
        .map(|h| -> Result<_> {
            crate::fitting::FrameHeights::new(h.parse()?, &template, dataset.has_ground_truth())
        })
        .transpose()?;
    let floor = config
        .floor
        .as_deref()
        .map(|f| -> Result<_> {
            f.parse::<crate::fitting::FloorArg>()?.resolve(
                &dataset,
                &template,
                &frames,
                &energy_config,
            )
        })
        .transpose()?;
    let energies: Vec<Energy> = frames
        .iter()
        .map(|&f| {
            energy_with_priors(
                &dataset,
                template.clone(),
                f,
                energy_config.clone(),
                heights.as_ref(),
                floor.as_ref(),
            )
        })
        .collect::<Result<_>>()?;

    // A unit of work: one frame, or in a sequence the whole chain of frames, where each frame
    // starts from the previous frame's result (papers/000 §4.3 warm start).
    let chains = scenario == Scenario::Sequence;
    let mut units: Vec<Unit> = Vec::new();
    for entry in 0..entries.len() {
        for budget in 0..config.budgets.len() {
            for rep in 0..config.repetitions {
                if chains {
                    units.push(Unit {
                        entry,
                        budget,
                        rep,
                        frames: (0..frames.len()).collect(),
                    });
                } else {
                    units.extend((0..frames.len()).map(|f| Unit {
                        entry,
                        budget,
                        rep,
                        frames: vec![f],
                    }));
                }
            }
        }
    }
    let mine: Vec<Unit> = units
        .into_iter()
        .enumerate()
        .filter(|(i, _)| i % shard.1 == shard.0)
        .map(|(_, u)| u)
        .collect();
    let done: HashSet<(String, String, usize, usize, usize)> =
        existing.iter().map(Run::key).collect();
    let key = |u: &Unit, f: usize| {
        (
            entries[u.entry].0.clone(),
            entries[u.entry].1.clone(),
            config.budgets[u.budget],
            u.rep,
            frames[f],
        )
    };
    let todo: Vec<&Unit> = mine
        .iter()
        .filter(|u| u.frames.iter().any(|&f| !done.contains(&key(u, f))))
        .collect();
    // Rewrite the file with the complete rows (drops a torn last line), then append.
    {
        let mut text = String::from(CSV_HEADER);
        text.push('\n');
        for r in &existing {
            text.push_str(&r.to_csv());
            text.push('\n');
        }
        write_atomic(&csv, text.as_bytes())?;
    }
    let file = Mutex::new(
        std::fs::OpenOptions::new()
            .append(true)
            .open(&csv)
            .with_context(|| format!("cannot append to {}", csv.display()))?,
    );
    // Fitted poses of the runs the report's pictures draw (crate::render::pictures).
    let poses_path = out.join(crate::study::poses::POSES_FILE);
    let poses_file = Mutex::new(
        std::fs::OpenOptions::new()
            .create(true)
            .append(true)
            .open(&poses_path)
            .with_context(|| format!("cannot append to {}", poses_path.display()))?,
    );
    let total: usize = mine.iter().map(|u| u.frames.len()).sum();
    let counter = std::sync::atomic::AtomicUsize::new(
        mine.iter()
            .flat_map(|u| u.frames.iter().map(move |&f| (u, f)))
            .filter(|(u, f)| done.contains(&key(u, *f)))
            .count(),
    );
    progress(counter.load(std::sync::atomic::Ordering::Relaxed), total);
    let index_of: std::collections::HashMap<usize, usize> =
        frames.iter().enumerate().map(|(i, &f)| (f, i)).collect();
    let work = |unit: &&Unit| -> Result<()> {
        let (method, strategy) = entries[unit.entry].clone();
        let (budget, rep) = (config.budgets[unit.budget], unit.rep);
        let plan = crate::fitting::Plan {
            dataset: &dataset,
            template: &template,
            budget,
            batch: 1,
            known_shape: config
                .known_shape
                .then_some(crate::fitting::KnownShape::Truth),
            sequence_shape: config.sequence_shape()?,
            marker_placement: config.marker_placement()?,
        };
        let unit_frames: Vec<usize> = unit.frames.iter().map(|&fi| frames[fi]).collect();
        crate::fitting::fit_frames(
            fitters[unit.entry].as_ref(),
            &plan,
            &unit_frames,
            // Each fit gets its own copy: the evaluation counter lives in the energy, and
            // parallel fits of one frame must not share it.
            &|frame| Ok(energies[index_of[&frame]].clone()),
            &|frame| {
                frame_seed(config.seed, frame) ^ (rep as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15)
            },
            &mut |fitted| {
                let frame = fitted.frame;
                if done.contains(&(method.clone(), strategy.clone(), budget, rep, frame)) {
                    // Resumed chain: this row is already in the CSV; the fit only rebuilt the
                    // warm start of the next frame.
                    return Ok(());
                }
                let result = fitted.result;
                let (pose, gt) = (&result.pose, &dataset.gt_poses[frame]);
                if crate::study::poses::records_pose(&config.budgets, budget, rep) {
                    // Before the row: a run killed in between is redone, its pose line repeated.
                    let key = (method.clone(), strategy.clone(), budget, rep, frame);
                    let line = crate::study::poses::pose_line(&key, pose);
                    let mut f = poses_file
                        .lock()
                        .map_err(|_| anyhow::anyhow!("poses.jsonl lock poisoned"))?;
                    f.write_all(line.as_bytes())?;
                    f.flush()?;
                }
                // The truth posed once, the result once (V2V and Hausdorff), each other iterate
                // once.
                let truth = TruthMesh::new(&template, gt);
                let (v2v_mm, hausdorff_mm) = truth.v2v_and_hausdorff_mm(&template, pose);
                let v2v_per_iteration =
                    iterate_v2v(&template, &result.iterates, &truth, pose, v2v_mm);
                // The fitted and true joints, posed once for MPJPE and PA-MPJPE.
                let (joints, true_joints) = (
                    joint_positions(&template, pose),
                    joint_positions(&template, gt),
                );
                let row = Run {
                    method: method.clone(),
                    strategy: strategy.clone(),
                    budget,
                    rep,
                    frame,
                    seed: fitted.seed,
                    energy: result.energy,
                    start_energy: fitted.start_energy,
                    v2v_mm,
                    mpjpe_mm: joint_error_mm(&joints, &true_joints),
                    pa_mpjpe_mm: aligned_joint_error_mm(&joints, &true_joints),
                    hausdorff_mm,
                    shape_rms: crate::cli::fit::coefficient_rms(&template, pose, gt)
                        .unwrap_or(f64::NAN),
                    evaluations: result.evaluations,
                    gradient_evaluations: result.gradient_evaluations,
                    iterations: result.iterations,
                    time_s: result.time_s,
                    v2v_per_iteration,
                    trace: result.trace,
                    face: face_errors_mm(&template, pose, gt),
                    shape_v2v_mm: lfit_model::metrics::shape_v2v_mm(&template, pose, gt)
                        .unwrap_or(f64::NAN),
                };
                let mut line = row.to_csv();
                line.push('\n');
                {
                    let mut f = file
                        .lock()
                        .map_err(|_| anyhow::anyhow!("runs.csv lock poisoned"))?;
                    f.write_all(line.as_bytes())?;
                    f.flush()?;
                }
                let n = counter.fetch_add(1, std::sync::atomic::Ordering::Relaxed) + 1;
                progress(n, total);
                Ok(())
            },
        )?;
        Ok(())
    };
    if config.parallel {
        todo.par_iter().try_for_each(work)?;
    } else {
        todo.iter().try_for_each(work)?;
    }
    drop(file);
    drop(poses_file);
    let mut runs = read_runs(&csv)?;
    sort_runs(config, &mut runs);
    write_runs(&csv, &runs)?;
    Ok(runs)
}

/// Canonical order: as the config lists methods, strategies and budgets, then rep, frame.
pub fn sort_runs(config: &BenchConfig, runs: &mut [Run]) {
    let entries = config.entries().unwrap_or_default();
    let pos = |r: &Run| {
        entries
            .iter()
            .position(|(m, s)| *m == r.method && *s == r.strategy)
            .unwrap_or(usize::MAX)
    };
    let budget_pos = |b: usize| {
        config
            .budgets
            .iter()
            .position(|&x| x == b)
            .unwrap_or(usize::MAX)
    };
    runs.sort_by_key(|r| (pos(r), budget_pos(r.budget), r.rep, r.frame));
}

pub fn write_runs(path: &Path, runs: &[Run]) -> Result<()> {
    let mut text = String::from(CSV_HEADER);
    text.push('\n');
    for r in runs {
        text.push_str(&r.to_csv());
        text.push('\n');
    }
    write_atomic(path, text.as_bytes())?;
    Ok(())
}

/// Merges shard directories into `out`: same `bench.json` everywhere, rows deduplicated. Refuses
/// when runs of the sweep are in no shard, unless `partial` (then the count of missing runs is
/// returned, and the caller says so).
pub fn merge(
    shards: &[PathBuf],
    out: &Path,
    partial: bool,
) -> Result<(BenchConfig, Vec<Run>, usize)> {
    if shards.is_empty() {
        bail!("bench merge needs at least one shard directory");
    }
    let mut config: Option<(Vec<u8>, BenchConfig)> = None;
    let mut rows: BTreeMap<(String, String, usize, usize, usize), Run> = BTreeMap::new();
    let mut poses = std::collections::HashMap::new();
    for dir in shards {
        let bytes = std::fs::read(dir.join("bench.json"))
            .with_context(|| format!("{} is not a bench output (no bench.json)", dir.display()))?;
        let c: BenchConfig = serde_json::from_slice(&bytes)
            .with_context(|| format!("malformed {}/bench.json", dir.display()))?;
        match &config {
            Some((b, _)) if *b != bytes => bail!(
                "{} ran another benchmark than {}",
                dir.display(),
                shards[0].display()
            ),
            Some(_) => {}
            None => config = Some((bytes, c)),
        }
        for r in read_runs(&dir.join("runs.csv"))? {
            rows.insert(r.key(), r);
        }
        poses.extend(crate::study::poses::read_poses(
            &dir.join(crate::study::poses::POSES_FILE),
        )?);
    }
    let (bytes, config) = config.context("no shard")?;
    // Every run the sweep holds must be in some shard: count the missing ones before writing.
    let data = match &config.data {
        Some(d) => d.clone(),
        None => shards
            .iter()
            .map(|d| d.join("data.npz"))
            .find(|p| p.is_file())
            .context("no shard holds the sweep's synthesised data.npz")?,
    };
    let dataset = Dataset::load(&data).with_context(|| format!("dataset {}", data.display()))?;
    let frames = parse_frames(config.frames.as_deref(), dataset.len())?;
    let mut expected = 0usize;
    let mut missing = 0usize;
    for (method, strategy) in config.entries()? {
        for &budget in &config.budgets {
            for rep in 0..config.repetitions {
                for &frame in &frames {
                    expected += 1;
                    let key = (method.clone(), strategy.clone(), budget, rep, frame);
                    missing += usize::from(!rows.contains_key(&key));
                }
            }
        }
    }
    if missing > 0 && !partial {
        bail!(
            "{missing} of the sweep's {expected} runs are in none of the {} shard directories given (a shard not listed or not finished): list every shard, or pass --partial to merge what there is",
            shards.len()
        );
    }
    std::fs::create_dir_all(out).with_context(|| format!("cannot create {}", out.display()))?;
    write_atomic(&out.join("bench.json"), &bytes)?;
    let mut runs: Vec<Run> = rows.into_values().collect();
    sort_runs(&config, &mut runs);
    write_runs(&out.join("runs.csv"), &runs)?;
    crate::study::poses::write_poses(&out.join(crate::study::poses::POSES_FILE), &poses)?;
    // A synthesised dataset lives in each shard; the report's pictures read it from `out`.
    let merged_data = out.join("data.npz");
    if config.data.is_none()
        && !merged_data.exists()
        && let Some(src) = shards
            .iter()
            .map(|d| d.join("data.npz"))
            .find(|p| p.is_file())
    {
        let bytes =
            std::fs::read(&src).with_context(|| format!("cannot read {}", src.display()))?;
        write_atomic(&merged_data, &bytes)?;
    }
    Ok((config, runs, missing))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A row survives the CSV; a row written before the `shape_rms` or the `shape_v2v_mm`
    /// column reads with NaN there, one written before `face` without face errors.
    #[test]
    fn runs_round_trip_and_rows_without_shape_rms_still_read() {
        let row = Run {
            method: "lm".into(),
            strategy: "holistic".into(),
            budget: 200,
            rep: 1,
            frame: 7,
            seed: 42,
            energy: 0.5,
            start_energy: 3.0,
            v2v_mm: 12.25,
            mpjpe_mm: 8.5,
            pa_mpjpe_mm: 6.0,
            hausdorff_mm: 9.0,
            shape_rms: 0.125,
            evaluations: 90,
            gradient_evaluations: 10,
            iterations: 9,
            time_s: 0.02,
            trace: vec![(1, 3.0), (90, 0.5)],
            v2v_per_iteration: vec![20.0, 12.25],
            face: Some(FaceErrors::from_array([1.5, 2.25, 3.0, 0.5, 0.75, 1.0])),
            shape_v2v_mm: 4.5,
        };
        let line = row.to_csv();
        assert_eq!(Run::from_csv(&line).as_ref(), Some(&row));
        assert_eq!(
            line.split(',').count(),
            CSV_HEADER.split(',').count(),
            "{line}"
        );
        // The same row in the layout before `shape_v2v_mm` (the last column): NaN.
        let mut v3: Vec<&str> = line.split(',').collect();
        v3.pop();
        let read = Run::from_csv(&v3.join(",")).expect("v3 row");
        assert!(read.shape_v2v_mm.is_nan());
        assert_eq!(
            Run {
                shape_v2v_mm: row.shape_v2v_mm,
                ..read
            },
            row
        );
        // And before `face`: no face errors.
        let mut v2 = v3.clone();
        v2.pop();
        let read = Run::from_csv(&v2.join(",")).expect("v2 row");
        assert!(read.shape_v2v_mm.is_nan());
        assert_eq!(
            Run {
                face: None,
                ..row.clone()
            },
            Run {
                shape_v2v_mm: row.shape_v2v_mm,
                ..read
            }
        );
        // And before `shape_rms` (column 12).
        let mut old = v2.clone();
        old.remove(12);
        let read = Run::from_csv(&old.join(",")).expect("old row");
        assert!(read.shape_rms.is_nan());
        assert_eq!(
            Run {
                shape_rms: row.shape_rms,
                face: row.face,
                shape_v2v_mm: row.shape_v2v_mm,
                ..read
            },
            row
        );
        let dir = tempfile::tempdir().expect("tmp");
        let csv = dir.path().join("runs.csv");
        std::fs::write(&csv, format!("{CSV_HEADER_V1}\n{}\n", old.join(","))).expect("csv");
        assert_eq!(read_runs(&csv).expect("v1 file").len(), 1);
        std::fs::write(&csv, format!("{CSV_HEADER_V2}\n{}\n", v2.join(","))).expect("csv");
        assert_eq!(read_runs(&csv).expect("v2 file").len(), 1);
        std::fs::write(&csv, format!("{CSV_HEADER_V3}\n{}\n", v3.join(","))).expect("csv");
        assert_eq!(read_runs(&csv).expect("v3 file").len(), 1);
        // A face column with five numbers is not a row.
        let mut bad: Vec<&str> = line.split(',').collect();
        bad[19] = "1;2;3;4;5";
        assert!(Run::from_csv(&bad.join(",")).is_none());
        std::fs::write(&csv, "method,frame\nlm,1\n").expect("csv");
        assert!(read_runs(&csv).is_err());
    }

    /// `height_prior`: the forms of `lfit fit --height-prior`, read back from the TOML; a bad
    /// one and one beside `known_shape` refused before any work, naming the key.
    #[test]
    fn a_bench_height_prior_is_checked_before_any_work() {
        let config = |extra: &str| -> BenchConfig {
            toml::from_str(&format!(
                "name = \"h\"\nmethods = [\"lm\"]\nbudgets = [10]\n{extra}\n[synth]\nmodality = \"markers\"\nframes = 2\n"
            ))
            .expect("toml")
        };
        for good in ["1.72", "1.72:0.03", "truth", "truth:0.02"] {
            let c = config(&format!("height_prior = \"{good}\""));
            assert_eq!(c.height_prior.as_deref(), Some(good));
            c.validate().expect(good);
        }
        assert_eq!(config("").height_prior, None);
        let err = config("height_prior = \"tall\"").validate().unwrap_err();
        assert!(format!("{err:#}").starts_with("height_prior: "), "{err:#}");
        let err = config("height_prior = \"1.7\"\nknown_shape = true")
            .validate()
            .unwrap_err();
        assert!(format!("{err:#}").contains("use one"), "{err:#}");
    }

    /// `floor`: the forms of `lfit fit --floor`, read back from the TOML; a bad one refused
    /// before any work, naming the key.
    #[test]
    fn a_bench_floor_is_checked_before_any_work() {
        let config = |extra: &str| -> BenchConfig {
            toml::from_str(&format!(
                "name = \"f\"\nmethods = [\"lm\"]\nbudgets = [10]\n{extra}\n[synth]\nmodality = \"markers\"\nframes = 2\n"
            ))
            .expect("toml")
        };
        for good in [
            "contact:0",
            "above:-0.05,30",
            "contact:truth",
            "above:truth,10",
        ] {
            let c = config(&format!("floor = \"{good}\""));
            assert_eq!(c.floor.as_deref(), Some(good));
            c.validate().expect(good);
        }
        assert_eq!(config("").floor, None);
        for bad in [
            "0.0",
            "below:0",
            "contact:low",
            "contact:0,0",
            "contact:nan",
        ] {
            let err = config(&format!("floor = \"{bad}\""))
                .validate()
                .unwrap_err();
            assert!(
                format!("{err:#}").starts_with("floor: --floor"),
                "{bad}: {err:#}"
            );
        }
    }

    /// `[synth] camera`: a keypoints2d rig from a camera file, looked up like the shipped data;
    /// refused for another modality and when the file is nowhere, before any work.
    #[test]
    fn a_synth_camera_file_is_for_keypoints2d_and_must_exist() {
        let config = |modality: &str, camera: &str| -> BenchConfig {
            toml::from_str(&format!(
                "name = \"c\"\nmethods = [\"lm\"]\nbudgets = [10]\n[synth]\nmodality = \"{modality}\"\nframes = 2\ncamera = \"{camera}\"\n"
            ))
            .expect("toml")
        };
        // The unit tests run in the package root, where configs/rigs/ is.
        config("keypoints2d", "configs/rigs/phone-1.json")
            .validate()
            .expect("a shipped rig");
        let err = config("markers", "configs/rigs/phone-1.json")
            .validate()
            .unwrap_err();
        assert!(
            format!("{err:#}").contains("synth.camera sets the keypoints2d rig"),
            "{err:#}"
        );
        let err = config("keypoints2d", "configs/rigs/none.json")
            .validate()
            .unwrap_err();
        assert!(
            format!("{err:#}").contains("synth.camera") && format!("{err:#}").contains("none.json"),
            "{err:#}"
        );
    }
}
