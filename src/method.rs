//! Fitting methods as types: [`MethodKind`] names every method `lfit fit` and `lfit bench`
//! know (a clap `ValueEnum` on the command line, a kebab-case string in bench configs), and
//! [`build`] is the one place a fitter is made from it. Adding a method is one variant here and
//! one implementation of [`lfit_fitters::Fitter`].

use std::fmt;
use std::str::FromStr;

use anyhow::{Result, bail};
use lfit_fitters::optim::{Method, Preset};
use lfit_fitters::{Fitter, Strategy};
use serde::{Deserialize, Serialize};

/// Every fitting method (the classical ones are [`lfit_fitters::METHOD_NAMES`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize, clap::ValueEnum)]
#[serde(rename_all = "kebab-case")]
#[value(rename_all = "kebab-case")]
pub enum MethodKind {
    /// Random search (zeroth order).
    Random,
    /// (1+1)-ES with the one-fifth rule.
    OnePlusOne,
    /// Differential evolution.
    De,
    /// Particle swarm optimisation.
    Pso,
    /// CMA-ES (active, IPOP restarts).
    Cma,
    /// Test-based population-size adaptation.
    Tbpsa,
    /// Powell's method.
    Powell,
    /// CMA-ES, then Powell.
    CmaPowell,
    /// nevergrad's NGOpt-like selector.
    Ngo,
    /// nevergrad's Shiwa-like selector.
    Shiwa,
    /// Annealed particle filter (papers/001).
    Apf,
    /// Partitioned sampling APF (papers/001).
    Psapf,
    /// L-BFGS with the exact gradient.
    Lbfgs,
    /// Levenberg–Marquardt on the least-squares form (exact Jacobian).
    Lm,
    /// Levenberg–Marquardt with the robust loss by Triggs's correction (IRLS weights) instead
    /// of folded residuals.
    LmTriggs,
    /// Gauss-Newton on the least-squares form.
    Gn,
    /// The learned fitter (papers/002), from a checkpoint.
    Neural,
    /// The learned fitter's N iterations, then Levenberg–Marquardt from its result, within one
    /// budget (`lfit_infer::NeuralThenLm`).
    #[serde(rename = "neural+lm")]
    #[value(name = "neural+lm")]
    NeuralLm,
}

impl MethodKind {
    pub const ALL: [MethodKind; 18] = [
        MethodKind::Random,
        MethodKind::OnePlusOne,
        MethodKind::De,
        MethodKind::Pso,
        MethodKind::Cma,
        MethodKind::Tbpsa,
        MethodKind::Powell,
        MethodKind::CmaPowell,
        MethodKind::Ngo,
        MethodKind::Shiwa,
        MethodKind::Apf,
        MethodKind::Psapf,
        MethodKind::Lbfgs,
        MethodKind::Lm,
        MethodKind::LmTriggs,
        MethodKind::Gn,
        MethodKind::Neural,
        MethodKind::NeuralLm,
    ];

    /// The name on the command line, in configs and in results.
    pub fn name(self) -> &'static str {
        match self {
            MethodKind::Random => "random",
            MethodKind::OnePlusOne => "one-plus-one",
            MethodKind::De => "de",
            MethodKind::Pso => "pso",
            MethodKind::Cma => "cma",
            MethodKind::Tbpsa => "tbpsa",
            MethodKind::Powell => "powell",
            MethodKind::CmaPowell => "cma-powell",
            MethodKind::Ngo => "ngo",
            MethodKind::Shiwa => "shiwa",
            MethodKind::Apf => "apf",
            MethodKind::Psapf => "psapf",
            MethodKind::Lbfgs => "lbfgs",
            MethodKind::Lm => "lm",
            MethodKind::LmTriggs => "lm-triggs",
            MethodKind::Gn => "gn",
            MethodKind::Neural => "neural",
            MethodKind::NeuralLm => "neural+lm",
        }
    }

    /// The ask/tell optimizer of a zeroth-order method.
    pub fn zeroth_order(self) -> Option<Method> {
        match self {
            MethodKind::Lbfgs
            | MethodKind::Lm
            | MethodKind::LmTriggs
            | MethodKind::Gn
            | MethodKind::Neural
            | MethodKind::NeuralLm => None,
            other => other.name().parse().ok(),
        }
    }

    /// Whether the method needs the energy's gradient or Jacobian, and so its differentiable
    /// variant ([`lfit_model::energy::EnergyConfig::for_gradient`]).
    pub fn uses_gradient(self) -> bool {
        lfit_fitters::uses_gradient(self.name())
    }

    /// Whether strategies (grouped, hierarchical, ...) apply: every method but the neural ones.
    pub fn has_strategies(self) -> bool {
        !self.is_neural()
    }

    /// Whether the method runs a network from a checkpoint (`neural`, `neural+lm`).
    pub fn is_neural(self) -> bool {
        matches!(self, MethodKind::Neural | MethodKind::NeuralLm)
    }

    /// Which entries the method moves unless told (`--dofs`): `neural+lm`'s LM stage on the sparse
    /// body sensors (markers, keypoints2d, hmd) every entry with the rotations and the root
    /// translation anchored at the network's result (`lfit_fitters::AnchoredDofs`, the rotations'
    /// standard deviation chosen per sensor on the validation subject:
    /// [`lfit_fitters::anchor_std_deg`], the translation's [`lfit_fitters::ANCHOR_TRANSLATION_STD_MM`]
    /// on its one-camera keypoints2d — the network's result is an estimate, not the previous
    /// frame's fit, in a sequence too; on the validation subject's markers from Φ(D) 10.4 mm V2V
    /// against 11.5 for the earlier default `observed` and 12.3 for `all`, on real markers
    /// level with LM with every marker on two of three captures and ahead of it on the harder
    /// half of the markers of each: docs/results/captured-motion.md, round 28; from a given
    /// start 8.2 mm at 5° against 8.6 at 15°, the network's 10.6 and LM's 11.7, round 40);
    /// every other method, and `neural+lm` on dense face landmarks (which determine every
    /// entry: 40 face frames 21.5 mm with `all` against 27.8 with `observed`) or a custom sensor,
    /// every free entry (the classical methods' published figures and the scipy parity are over
    /// all entries).
    ///
    /// `start`: where the network starts ([`lfit_fitters::AnchorStart`]); from a given start the
    /// tighter anchor of [`lfit_fitters::GIVEN_START_ANCHOR_STD_DEG`] on markers.
    pub fn default_dofs(
        self,
        modality: lfit_model::observe::Modality,
        start: lfit_fitters::AnchorStart,
    ) -> lfit_fitters::Dofs {
        match (self, lfit_fitters::anchor_std_deg(modality, start)) {
            (MethodKind::NeuralLm, Some(std_deg)) => lfit_fitters::Dofs::anchored(std_deg),
            _ => lfit_fitters::Dofs::All,
        }
    }

    /// Every name, comma-separated (for messages).
    pub fn list() -> String {
        MethodKind::ALL.map(MethodKind::name).join(", ")
    }
}

impl fmt::Display for MethodKind {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

impl FromStr for MethodKind {
    type Err = anyhow::Error;
    fn from_str(s: &str) -> Result<Self> {
        match MethodKind::ALL.into_iter().find(|m| m.name() == s) {
            Some(m) => Ok(m),
            None => bail!(
                "unknown method '{s}' (expected one of: {})",
                MethodKind::list()
            ),
        }
    }
}

/// One entry of a bench config's `methods`: `"METHOD"` (crossed with the config's strategies)
/// or `"METHOD:STRATEGY"`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(try_from = "String", into = "String")]
pub struct MethodSpec {
    pub kind: MethodKind,
    pub strategy: Option<Strategy>,
}

impl TryFrom<String> for MethodSpec {
    type Error = anyhow::Error;
    fn try_from(s: String) -> Result<Self> {
        s.parse()
    }
}

impl From<MethodSpec> for String {
    fn from(m: MethodSpec) -> String {
        m.to_string()
    }
}

impl FromStr for MethodSpec {
    type Err = anyhow::Error;
    fn from_str(s: &str) -> Result<Self> {
        let (name, pin) = match s.split_once(':') {
            Some((n, p)) => (n, Some(p)),
            None => (s, None),
        };
        let kind: MethodKind = name
            .parse()
            .map_err(|e: anyhow::Error| anyhow::anyhow!("{e}; optionally NAME:STRATEGY"))?;
        let strategy = match pin {
            Some(_) if !kind.has_strategies() => {
                bail!("method '{s}': the neural fitter has no strategies")
            }
            Some(p) => Some(
                p.parse::<Strategy>()
                    .map_err(|e| anyhow::anyhow!("method '{s}': {e}"))?,
            ),
            None => None,
        };
        Ok(Self { kind, strategy })
    }
}

impl fmt::Display for MethodSpec {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self.strategy {
            Some(s) => write!(f, "{}:{s}", self.kind),
            None => write!(f, "{}", self.kind),
        }
    }
}

/// Everything a classical fitter is built from.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ClassicOptions {
    pub preset: Preset,
    pub strategy: Strategy,
    /// Factor on a zeroth-order method's initial steps (1 = papers/000 §4.1's).
    pub step_scale: f64,
    /// CMA-ES's update variant (diagonal, elitist, population; `cma` only).
    pub cma: lfit_fitters::optim::cma::CmaVariant,
    /// Which free entries the fit moves (`--dofs`).
    pub dofs: lfit_fitters::Dofs,
}

impl Default for ClassicOptions {
    fn default() -> Self {
        Self {
            preset: Preset::Nevergrad,
            strategy: Strategy::Holistic,
            step_scale: 1.0,
            cma: Default::default(),
            dofs: lfit_fitters::Dofs::All,
        }
    }
}

/// The classical fitter of `kind` (every method but the neural one, which is loaded from a
/// checkpoint: [`lfit_infer::NeuralFitter`]), built by [`lfit_fitters::build_fitter_with_steps`].
pub fn build_classic(kind: MethodKind, options: ClassicOptions) -> Result<Box<dyn Fitter>> {
    if kind.is_neural() {
        bail!(
            "method {kind} runs the neural fitter, which is loaded from a checkpoint (--checkpoint DIR), not built"
        );
    }
    let fitter = lfit_fitters::build_fitter_tuned(
        kind.name(),
        options.preset,
        options.strategy,
        options.step_scale,
        options.cma,
    )?;
    Ok(options.dofs.wrap(fitter))
}

/// The data's modality and whether it is a sequence (each frame started from the previous
/// frame's fit).
pub type DataKind = (lfit_model::observe::Modality, bool);

/// `--dofs` by name, or the method's default for the data's modality and the network's start
/// (`--neural-start`; a sequence's given start is the previous frame's fit;
/// [`MethodKind::default_dofs`]). `data` gives the data's modality and whether it is a
/// sequence, asked only then. Every method takes one, the
/// network too (`anchored` adds the pull toward the start to the energy it fits, `observed`
/// holds what the data leave open).
pub fn dofs_for(
    kind: MethodKind,
    name: Option<&str>,
    data: &mut dyn FnMut() -> Result<DataKind>,
    neural_start: &str,
) -> Result<lfit_fitters::Dofs> {
    match name {
        None if kind == MethodKind::NeuralLm => {
            let (modality, sequence) = data()?;
            Ok(kind.default_dofs(modality, anchor_start(neural_start, sequence)?))
        }
        None => Ok(lfit_fitters::Dofs::All),
        Some(n) => n.parse().map_err(anyhow::Error::msg),
    }
}

/// Where `neural+lm`'s network starts for its anchor ([`lfit_fitters::AnchorStart`]):
/// `neural_start` as `--neural-start` names it ([`lfit_infer::Start`]'s names, refused as it
/// refuses them), on a sequence's frames or on single ones.
#[cfg(feature = "neural")]
fn anchor_start(neural_start: &str, sequence: bool) -> Result<lfit_fitters::AnchorStart> {
    use lfit_fitters::AnchorStart;
    let start: lfit_infer::Start = neural_start.parse().map_err(anyhow::Error::msg)?;
    Ok(match (start, sequence) {
        (lfit_infer::Start::Given, false) => AnchorStart::Given,
        (lfit_infer::Start::Given, true) => AnchorStart::Previous,
        _ => AnchorStart::Estimate,
    })
}

/// Without the neural fitter there is no network to start.
#[cfg(not(feature = "neural"))]
fn anchor_start(_neural_start: &str, _sequence: bool) -> Result<lfit_fitters::AnchorStart> {
    anyhow::bail!(NO_NEURAL)
}

/// The error of a neural method in a build without the `neural` feature (no Burn).
pub const NO_NEURAL: &str = "this build of lfit has no neural fitter: rebuild with the cargo feature `neural` (the Python wheel: maturin build --features neural)";

/// The fitter of a neural method from the command line's words: `start` (`given`, `phi`,
/// `best`), `pick` (`last`, `lowest`), `iterations` and `tolerance` (an early exit), `runtime` (`burn`, `ort`, `native`), the Burn `device`
/// and ONNX Runtime's threads.
#[cfg(feature = "neural")]
#[allow(clippy::too_many_arguments)]
pub fn load_neural_named(
    kind: MethodKind,
    checkpoint: &std::path::Path,
    start: &str,
    pick: &str,
    iterations: Option<usize>,
    tolerance: Option<f64>,
    runtime: &str,
    device: &str,
    ort_threads: Option<usize>,
    dofs: lfit_fitters::Dofs,
) -> Result<Box<dyn Fitter>> {
    load_neural(
        kind,
        &NeuralOptions {
            checkpoint,
            start: start.parse().map_err(anyhow::Error::msg)?,
            pick: pick.parse().map_err(anyhow::Error::msg)?,
            iterations,
            tolerance,
            runtime: runtime.parse().map_err(anyhow::Error::msg)?,
            device,
            ort_threads,
            dofs,
        },
    )
}

/// Without the `neural` feature: the one-line error [`NO_NEURAL`].
#[cfg(not(feature = "neural"))]
#[allow(clippy::too_many_arguments)]
pub fn load_neural_named(
    _kind: MethodKind,
    _checkpoint: &std::path::Path,
    _start: &str,
    _pick: &str,
    _iterations: Option<usize>,
    _tolerance: Option<f64>,
    _runtime: &str,
    _device: &str,
    _ort_threads: Option<usize>,
    _dofs: lfit_fitters::Dofs,
) -> Result<Box<dyn Fitter>> {
    bail!(NO_NEURAL)
}

/// Where and how a neural method's network runs (`lfit fit --checkpoint --neural-start
/// --runtime --device --ort-threads`, bench `checkpoint`/`neural_start`).
#[cfg(feature = "neural")]
#[derive(Debug, Clone)]
pub struct NeuralOptions<'a> {
    pub checkpoint: &'a std::path::Path,
    pub start: lfit_infer::Start,
    /// Which iterate a fit returns (`--neural-pick`).
    pub pick: lfit_infer::Pick,
    /// The network's first K iterations only (`--neural-iterations`); `None`: all N.
    pub iterations: Option<usize>,
    /// The energy rule that stops a frame's network early (`--neural-tolerance`).
    pub tolerance: Option<f64>,
    pub runtime: lfit_infer::Runtime,
    /// Burn device name (`ndarray`, `flex`, `wgpu`); Burn only.
    pub device: &'a str,
    /// ONNX Runtime's intra-op threads; ORT only.
    pub ort_threads: Option<usize>,
    /// Which entries `neural+lm`'s LM stage moves (`neural`: `All` only).
    pub dofs: lfit_fitters::Dofs,
}

/// The fitter of a neural method (`neural`, `neural+lm`), loaded from its checkpoint.
#[cfg(feature = "neural")]
pub fn load_neural(kind: MethodKind, options: &NeuralOptions<'_>) -> Result<Box<dyn Fitter>> {
    if !kind.is_neural() {
        bail!("method {kind} does not run a network");
    }
    if options.ort_threads == Some(0) {
        bail!("--ort-threads must be at least 1");
    }
    // A relative checkpoint found nowhere names the places searched (LFIT_DATA_DIR, ...).
    let checkpoint = crate::shipped::locate(options.checkpoint)
        .map_err(|e| anyhow::anyhow!("checkpoint {e}"))?;
    let fitter = match options.runtime {
        lfit_infer::Runtime::Burn => {
            if options.ort_threads.is_some() {
                bail!("--ort-threads is only for --runtime ort");
            }
            let device = lfit_nn::tensor::device_from_name(options.device)?;
            lfit_infer::NeuralFitter::load(&checkpoint, &device, options.start)?
        }
        lfit_infer::Runtime::Native => {
            if options.ort_threads.is_some() {
                bail!("--ort-threads is only for --runtime ort");
            }
            lfit_infer::NeuralFitter::load_native(&checkpoint, options.start)?
        }
        lfit_infer::Runtime::Ort => lfit_infer::NeuralFitter::load_ort(
            &checkpoint,
            options.start,
            lfit_infer::onnx::runtime::SessionOptions {
                threads: options.ort_threads,
            },
        )?,
    };
    let fitter = fitter.with_pick(options.pick);
    let fitter = match options.iterations {
        Some(k) => fitter.with_iterations(k)?,
        None => fitter,
    };
    let fitter = match options.tolerance {
        Some(t) => fitter.with_tolerance(t)?,
        None => fitter,
    };
    Ok(match kind {
        MethodKind::NeuralLm => Box::new(lfit_infer::NeuralThenLm::new(fitter, options.dofs)?),
        // The network fits the energy with the pull toward its start (in a sequence, the previous
        // frame's fit), or moves only the entries the data determine, as a classical fitter.
        _ => options.dofs.wrap(Box::new(fitter)),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_method_round_trips_and_builds() {
        for m in MethodKind::ALL {
            assert_eq!(m.name().parse::<MethodKind>().unwrap(), m);
            let json = serde_json::to_string(&m).unwrap();
            assert_eq!(json, format!("\"{}\"", m.name()));
            assert_eq!(
                <MethodKind as clap::ValueEnum>::from_str(m.name(), false).unwrap(),
                m
            );
            if !m.is_neural() {
                let f = build_classic(m, ClassicOptions::default()).unwrap();
                assert_eq!(
                    f.name(),
                    m.name(),
                    "a holistic fitter is named like its method"
                );
            }
        }
        // The fitters crate knows every zeroth-order name.
        for name in lfit_fitters::METHOD_NAMES {
            assert!(name.parse::<MethodKind>().is_ok(), "{name}");
        }
        let spec: MethodSpec = "cma:grouped".parse().unwrap();
        assert_eq!(
            (spec.kind, spec.strategy),
            (MethodKind::Cma, Some(Strategy::Grouped))
        );
        assert_eq!(spec.to_string(), "cma:grouped");
        assert!(
            "neural:grouped"
                .parse::<MethodSpec>()
                .unwrap_err()
                .to_string()
                .contains("no strategies")
        );
        assert!(
            "cmaes"
                .parse::<MethodSpec>()
                .unwrap_err()
                .to_string()
                .contains("unknown method 'cmaes'")
        );
        assert!(
            build_classic(
                MethodKind::Lm,
                ClassicOptions {
                    step_scale: 2.0,
                    ..ClassicOptions::default()
                }
            )
            .is_err()
        );
    }

    /// `neural+lm`'s default anchor follows the sensor and where the network starts (round 40):
    /// 5° on markers from a given start or the previous frame's fit, 15° (`anchored`) from
    /// Φ(D); keypoints2d 3° only from a given start on single frames, 10° in a sequence and
    /// from Φ(D); hmd 1° from anywhere. A name given wins, the data are not asked for it, and
    /// the other methods move every entry.
    #[test]
    fn neural_lm_default_anchor_follows_the_start() {
        use lfit_model::observe::Modality;
        let default = |modality: Modality, sequence: bool, start: &str| {
            dofs_for(
                MethodKind::NeuralLm,
                None,
                &mut || Ok((modality, sequence)),
                start,
            )
            .unwrap()
            .name()
        };
        for (modality, sequence, start, want) in [
            (Modality::Markers, false, "given", "anchored:5"),
            (Modality::Markers, true, "given", "anchored:5"),
            (Modality::Markers, false, "phi", "anchored"),
            (Modality::Markers, true, "both", "anchored"),
            (Modality::Keypoints2d, false, "given", "anchored:3"),
            (Modality::Keypoints2d, false, "start", "anchored:3"),
            (Modality::Keypoints2d, true, "given", "anchored:10"),
            (Modality::Keypoints2d, false, "best", "anchored:10"),
            (Modality::Hmd, false, "given", "anchored:1"),
            (Modality::Hmd, true, "phi", "anchored:1"),
            (Modality::Landmarks2d, false, "given", "all"),
        ] {
            assert_eq!(
                default(modality, sequence, start),
                want,
                "{modality:?}, sequence {sequence}, {start}"
            );
        }
        let mut asked = false;
        let named = dofs_for(
            MethodKind::NeuralLm,
            Some("observed"),
            &mut || {
                asked = true;
                Ok((Modality::Markers, false))
            },
            "given",
        )
        .unwrap();
        assert_eq!((named.name(), asked), ("observed".to_string(), false));
        let unknown = dofs_for(
            MethodKind::NeuralLm,
            None,
            &mut || Ok((Modality::Markers, false)),
            "gvien",
        );
        assert!(
            unknown
                .unwrap_err()
                .to_string()
                .contains("unknown neural start 'gvien'")
        );
        let lm = dofs_for(
            MethodKind::Lm,
            None,
            &mut || Ok((Modality::Markers, false)),
            "given",
        );
        assert_eq!(lm.unwrap().name(), "all");
    }
}
