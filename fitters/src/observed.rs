//! `--dofs observed`: a fit moves only the entries its observations determine.
//!
//! A sparse sensor does not see every joint: a markers set has one marker per hand for the 18
//! finger and thumb rotations of the MakeHuman body, 2D keypoints see no fingers and little of a
//! limb's twist. The energy has no pose prior (only joint limits), so a converging solver sets
//! those rotations from the noise of the few rows that touch them; on the captured clip this alone
//! costs Levenberg–Marquardt 2–3 mm of V2V (hands are a large share of the mesh's vertices). With
//! `Observed`, every rotation entry the data term determines to no better than
//! [`OBSERVED_MAX_STD_DEG`] (the conditional standard deviation `1/√info` of
//! [`Energy::data_information`] at the start) keeps its start value; translation, shape and
//! expression entries stay as the request frees them. Marker-based body fitting keeps unobserved
//! hands at a given pose in the same way (MoSh++, Mahmood et al. 2019, fits the fingers only where
//! hand markers exist). The objective is unchanged: only the mask is.

use std::time::Instant;

use lfit_model::{Block, DofMask, Energy};

use crate::{FitError, FitRequest, FitResult, Fitter};

/// Largest conditional standard deviation, in degrees, of a rotation entry that an `Observed`
/// fit still moves. Chosen on the validation subject's frames (CMU subject 6, markers, 300 local
/// frames, `neural+lm`): 1° 9.11 mm, **2° 9.09**, 3° 9.55, 5° 9.64, no entry frozen 11.42
/// (`docs/results/captured-motion.md`, round 14); the evaluation clip was not used to choose it.
pub const OBSERVED_MAX_STD_DEG: f64 = 2.0;

/// Which of a request's free entries a fit moves (`lfit fit --dofs`, bench `dofs`).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub enum Dofs {
    /// Every free entry of the request (the scenario's mask).
    #[default]
    All,
    /// Only the rotation entries the observations determine to within `max_std_deg` degrees
    /// (module docs); the others keep the start's values. `observed` is
    /// [`OBSERVED_MAX_STD_DEG`], `observed:DEG` another threshold.
    Observed { max_std_deg: f64 },
    /// Every free entry, the free rotation entries pulled toward the start's values by a
    /// Gaussian of `std_deg` degrees and the free root translation entries by one of
    /// `translation_std_mm` millimetres ([`AnchoredDofs`]): the soft form of `Observed`, where
    /// the data decide how far each entry moves. `anchored` is [`ANCHOR_STD_DEG`] and the
    /// translation's default for where the start comes from (`None`:
    /// [`anchor_translation_std_mm`] — [`ANCHOR_TRANSLATION_STD_MM`] at an estimate,
    /// [`SEQUENCE_ANCHOR_TRANSLATION_STD_MM`] at the previous frame's fit in a sequence),
    /// `anchored:DEG` another rotation standard deviation, `anchored:DEG,MM` both (`MM` wherever
    /// the start comes from).
    Anchored {
        std_deg: f64,
        translation_std_mm: Option<f64>,
    },
    /// Both: the entries `Observed` at `max_std_deg` keeps moving, each pulled toward the start
    /// as `Anchored` pulls (`observed:DEG+anchored:DEG[,MM]`, [`ObservedDofs`] around
    /// [`AnchoredDofs`]). For a fitter that moves entries the energy says nothing of (the
    /// network's own update: the thumbs and fingers of a markers set drift 8–30° over a
    /// sequence where the anchor alone holds LM's within 0.2°), the hard mask holds those and the
    /// soft pull the rest; `docs/results/captured-motion.md`, round 31.
    ObservedAnchored {
        max_std_deg: f64,
        std_deg: f64,
        translation_std_mm: Option<f64>,
    },
}

impl Dofs {
    /// `Observed` at [`OBSERVED_MAX_STD_DEG`].
    pub const OBSERVED: Dofs = Dofs::Observed {
        max_std_deg: OBSERVED_MAX_STD_DEG,
    };

    /// `Anchored` at [`ANCHOR_STD_DEG`].
    pub const ANCHORED: Dofs = Dofs::Anchored {
        std_deg: ANCHOR_STD_DEG,
        translation_std_mm: None,
    };

    /// `Anchored` at `std_deg` degrees and the translation's default for where the start comes
    /// from ([`anchor_translation_std_mm`]).
    pub fn anchored(std_deg: f64) -> Dofs {
        Dofs::Anchored {
            std_deg,
            translation_std_mm: None,
        }
    }

    /// `fitter` moving these entries: itself for `All`, wrapped in [`ObservedDofs`] for
    /// `Observed` and in [`AnchoredDofs`] for `Anchored`.
    pub fn wrap(self, fitter: Box<dyn Fitter>) -> Box<dyn Fitter> {
        match self {
            Dofs::All => fitter,
            Dofs::Observed { max_std_deg } => Box::new(ObservedDofs::new(fitter, max_std_deg)),
            Dofs::Anchored {
                std_deg,
                translation_std_mm,
            } => Box::new(AnchoredDofs::new(fitter, std_deg, translation_std_mm)),
            Dofs::ObservedAnchored {
                max_std_deg,
                std_deg,
                translation_std_mm,
            } => {
                let (observed, anchored) = Dofs::halves(max_std_deg, std_deg, translation_std_mm);
                observed.wrap(anchored.wrap(fitter))
            }
        }
    }

    /// The two halves of an `ObservedAnchored` of these fields (`Observed`, `Anchored`), which
    /// its wrapper, name and suffix are made of.
    fn halves(max_std_deg: f64, std_deg: f64, translation_std_mm: Option<f64>) -> (Dofs, Dofs) {
        (
            Dofs::Observed { max_std_deg },
            Dofs::Anchored {
                std_deg,
                translation_std_mm,
            },
        )
    }

    /// Whether the fit holds the entries the data leave open (`Observed`, `ObservedAnchored`):
    /// one evaluation of the budget goes to the data's information first.
    pub fn holds_unobserved(self) -> bool {
        matches!(self, Dofs::Observed { .. } | Dofs::ObservedAnchored { .. })
    }

    /// What a fitter's name gets for it: `observed`, `observed-<DEG>deg`, `anchored`,
    /// `anchored-<DEG>deg` or `anchored-<DEG>deg-<MM>mm` (`all`: empty).
    pub fn suffix(self) -> String {
        // The anchor is the inner wrapper: its suffix comes first in the fitter's name.
        if let Dofs::ObservedAnchored {
            max_std_deg,
            std_deg,
            translation_std_mm,
        } = self
        {
            let (observed, anchored) = Dofs::halves(max_std_deg, std_deg, translation_std_mm);
            return format!("{}-{}", anchored.suffix(), observed.suffix());
        }
        match (self, self.name().split_once(':')) {
            (Dofs::All, _) => String::new(),
            (_, Some((name, value))) => match value.split_once(',') {
                Some((deg, mm)) => format!("{name}-{deg}deg-{mm}mm"),
                None => format!("{name}-{value}deg"),
            },
            (_, None) => self.name(),
        }
    }

    /// The name it is given by (`all`, `observed`, `observed:DEG`, `anchored`, `anchored:DEG`,
    /// `anchored:DEG,MM`).
    pub fn name(self) -> String {
        match self {
            Dofs::All => "all".into(),
            Dofs::Observed { max_std_deg } if max_std_deg == OBSERVED_MAX_STD_DEG => {
                "observed".into()
            }
            Dofs::Observed { max_std_deg } => format!("observed:{max_std_deg}"),
            Dofs::Anchored {
                std_deg,
                translation_std_mm: None,
            } => {
                if std_deg == ANCHOR_STD_DEG {
                    "anchored".into()
                } else {
                    format!("anchored:{std_deg}")
                }
            }
            Dofs::Anchored {
                std_deg,
                translation_std_mm: Some(mm),
            } => format!("anchored:{std_deg},{mm}"),
            Dofs::ObservedAnchored {
                max_std_deg,
                std_deg,
                translation_std_mm,
            } => {
                let (observed, anchored) = Dofs::halves(max_std_deg, std_deg, translation_std_mm);
                format!("{}+{}", observed.name(), anchored.name())
            }
        }
    }
}

impl std::str::FromStr for Dofs {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "all" => Ok(Dofs::All),
            "observed" => Ok(Dofs::OBSERVED),
            "anchored" => Ok(Dofs::ANCHORED),
            _ if s.contains('+') => {
                let (a, b) = s.split_once('+').unwrap_or((s, ""));
                match (a.parse::<Dofs>()?, b.parse::<Dofs>()?) {
                    (
                        Dofs::Observed { max_std_deg },
                        Dofs::Anchored {
                            std_deg,
                            translation_std_mm,
                        },
                    ) => Ok(Dofs::ObservedAnchored {
                        max_std_deg,
                        std_deg,
                        translation_std_mm,
                    }),
                    _ => Err(format!(
                        "dofs '{s}': only observed[:DEG]+anchored[:DEG[,MM]] combines two"
                    )),
                }
            }
            _ => {
                let (kind, value) = s.split_once(':').unwrap_or((s, ""));
                let positive =
                    |v: &str| v.parse::<f64>().ok().filter(|d| d.is_finite() && *d > 0.0);
                match kind {
                    "observed" => match positive(value) {
                        Some(d) => Ok(Dofs::Observed { max_std_deg: d }),
                        None => Err(format!(
                            "dofs '{s}': the threshold after observed: must be a positive number of degrees"
                        )),
                    },
                    "anchored" => {
                        let (deg, mm) = match value.split_once(',') {
                            Some((deg, mm)) => (deg, Some(mm)),
                            None => (value, None),
                        };
                        let Some(std_deg) = positive(deg) else {
                            return Err(format!(
                                "dofs '{s}': the standard deviation after anchored: must be a positive number of degrees"
                            ));
                        };
                        let translation_std_mm = match mm.map(positive) {
                            None => None,
                            Some(Some(mm)) => Some(mm),
                            Some(None) => {
                                return Err(format!(
                                    "dofs '{s}': the translation's standard deviation after anchored:DEG, must be a positive number of millimetres"
                                ));
                            }
                        };
                        Ok(Dofs::Anchored {
                            std_deg,
                            translation_std_mm,
                        })
                    }
                    _ => Err(format!(
                        "unknown dofs '{s}' (expected all, observed, observed:DEG, anchored, anchored:DEG, anchored:DEG,MM or observed[:DEG]+anchored[:DEG[,MM]])"
                    )),
                }
            }
        }
    }
}

/// `mask` without the rotation entries whose data information `info` (per entry of the
/// parameter vector, [`Energy::data_information`]) leaves a conditional standard deviation above
/// `max_std` radians: `info · max_std² < 1`. `None` when nothing would stay free.
pub fn observed_mask(
    mask: &DofMask,
    info: &[f64],
    rotations: std::ops::Range<usize>,
    max_std: f64,
) -> Option<DofMask> {
    let free: Vec<usize> = mask
        .free
        .iter()
        .copied()
        .filter(|&i| !rotations.contains(&i) || info[i] * max_std * max_std >= 1.0)
        .collect();
    if free.is_empty() {
        return None;
    }
    Some(DofMask {
        name: format!("{}-observed", mask.name),
        free,
    })
}

/// The request's mask for an `Observed` fit from `at` with threshold `max_std_deg`: one counted
/// evaluation with a Jacobian (the data information). `None`: no entry would stay free.
pub fn observed_request_mask(
    energy: &Energy,
    mask: &DofMask,
    at: &[f64],
    max_std_deg: f64,
) -> Result<Option<DofMask>, FitError> {
    let info = energy
        .data_information(at)
        .map_err(|e| FitError::LeastSquares(format!("--dofs observed: {e}")))?;
    let rotations = energy.template().layout().range(Block::Rotations);
    Ok(observed_mask(
        mask,
        &info,
        rotations,
        max_std_deg.to_radians(),
    ))
}

/// A fitter that moves only the observed entries (module docs): it spends one evaluation of the
/// budget on the data information at the (clamped) start, then runs `inner` with the rest on the
/// reduced mask. The evaluations, time and trace it reports include that evaluation.
pub struct ObservedDofs {
    inner: Box<dyn Fitter>,
    max_std_deg: f64,
}

impl ObservedDofs {
    /// `inner` on the rotations determined to within `max_std_deg` degrees.
    pub fn new(inner: Box<dyn Fitter>, max_std_deg: f64) -> Self {
        Self { inner, max_std_deg }
    }
}

impl std::fmt::Debug for ObservedDofs {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "ObservedDofs({})", self.inner.name())
    }
}

impl Fitter for ObservedDofs {
    /// `<inner>-observed`, or `<inner>-observed-<DEG>deg` at another threshold than the default
    /// (no `:`, which separates a method from its strategy in study configs).
    fn name(&self) -> String {
        format!(
            "{}-{}",
            self.inner.name(),
            Dofs::Observed {
                max_std_deg: self.max_std_deg
            }
            .suffix()
        )
    }

    fn fit(&self, request: &FitRequest<'_>) -> Result<FitResult, FitError> {
        let clock = Instant::now();
        if request.budget < 2 {
            return Err(FitError::LeastSquares(format!(
                "--dofs observed needs a budget of at least 2 evaluations (one for the data's information at the start, then the fit); got {}",
                request.budget
            )));
        }
        let mut start = request.start.clone();
        request.bounds.clamp(&mut start);
        let (e0, g0) = (
            request.energy.evaluations(),
            request.energy.gradient_evaluations(),
        );
        let mask = observed_request_mask(request.energy, &request.mask, &start, self.max_std_deg)?;
        let spent = request.energy.evaluations() - e0;
        let spent_gradients = request.energy.gradient_evaluations() - g0;
        let Some(mask) = mask else {
            return Err(FitError::LeastSquares(
                "--dofs observed: the observations determine none of the free entries".into(),
            ));
        };
        let inner = FitRequest {
            energy: request.energy,
            start: request.start.clone(),
            mask,
            bounds: request.bounds.clone(),
            budget: request.budget - spent as usize,
            seed: request.seed,
            motion: request.motion.clone(),
        };
        // A network needs a fixed count of evaluations: say where the one spent here went.
        let mut result = self.inner.fit(&inner).map_err(|e| match e {
            FitError::Neural(m) => FitError::Neural(format!(
                "{m} (--dofs observed spent {spent} of the budget's {} on the data's information)",
                request.budget
            )),
            e => e,
        })?;
        result.method = self.name();
        result.evaluations += spent;
        result.gradient_evaluations += spent_gradients;
        for t in &mut result.trace {
            t.0 += spent;
        }
        result.time_s = clock.elapsed().as_secs_f64();
        Ok(result)
    }
}

/// A fitter on the energy plus a Gaussian pull of the free rotation and root translation entries
/// toward the (clamped) start ([`Energy::with_anchor`], standard deviations `std_deg` and
/// `translation_std_mm` in the data term's units; shape and expression entries stay free): where
/// the observations determine an entry well the data move it as without the anchor, where they
/// leave it open it stays near the start — the soft form of [`ObservedDofs`], deciding per
/// direction of the parameters rather than per entry, at no evaluation of its own. The
/// translation's pull matters where the data leave the body's distance open (one camera: the
/// depth along its axis, which rotations, size and translation trade against each other). After
/// `neural+lm`'s network the start is the network's estimate: a prior centred on it, in place
/// of a generic pose prior. The result's energy and terms are the request's energy (the anchor
/// subtracted: the value every method is compared on); its trace is the objective the inner
/// fitter minimised (energy + anchor), which is never below the energy. The anchored copy's
/// evaluations are counted on the request's energy.
pub struct AnchoredDofs {
    inner: Box<dyn Fitter>,
    std_deg: f64,
    /// `None`: [`anchor_translation_std_mm`] by where each request's start comes from.
    translation_std_mm: Option<f64>,
}

/// The anchor's standard deviation, degrees, of `--dofs anchored` and of `neural+lm`'s default
/// on markers where the network starts from Φ(D): the best of 2, 5, 10, 15, 20, 30 and 50° for
/// `neural+lm` on the validation subject's synthetic markers (CMU subject 6, 300 local frames
/// from Φ(D): V2V 11.61, 10.87, 10.46, **10.42**, 10.51, 10.79, 11.25 mm, against 11.50 for
/// `observed` and 12.34 for `all`; docs/results/captured-motion.md, round 28; with the networks
/// of round 40 still ahead of 5°: 10.42 against 10.87). The evaluation captures were not used
/// to choose it.
pub const ANCHOR_STD_DEG: f64 = 15.0;

/// `neural+lm`'s anchor on markers where the network starts from a given pose near the target
/// (`--neural-start given`: the scenario's start, a tracker's estimate; the issue's
/// single-frame protocol): the best of 2, 3, 5, 8, 10, 15 and 20° on the same validation
/// frames with the shipped `markers-makehuman` (V2V 8.51, 8.35, **8.22**, 8.24, 8.33, 8.61,
/// 8.90 mm; the network alone 10.64, LM 11.68; `markers-makehuman-chord` 8.79, 8.42, 8.13,
/// **8.10**, 8.18, 8.47, 8.78; `./scripts/eval-neural-lm-budget.sh`, captured-motion.md round
/// 40). From that start the network's result is closer to the truth (the clip's frames 9.5 mm
/// against 13.5 from Φ(D)), and a tighter pull keeps more of it.
pub const GIVEN_START_ANCHOR_STD_DEG: f64 = 5.0;

/// `neural+lm`'s anchor on keypoints2d from Φ(D), chosen the same way (5, 10, 15, 20, 30°:
/// 19.91, **19.78**, 19.85, 19.98, 20.30 mm; `observed` 20.66, `all` 22.89; round 40: 3° 20.12).
pub const KEYPOINTS2D_ANCHOR_STD_DEG: f64 = 10.0;

/// `neural+lm`'s anchor on keypoints2d from a given start (round 40: 2, 3, 5, 8, 10, 15, 20°:
/// 13.78, **13.68**, 13.70, 14.00, 14.27, 14.98, 15.65 mm; the network alone 16.18, LM 22.06).
pub const KEYPOINTS2D_GIVEN_START_ANCHOR_STD_DEG: f64 = 3.0;

/// `neural+lm`'s anchor on hmd (β given), chosen the same way from Φ(D) (0.5, 1, 2, 3, 5, 10, 15,
/// 20, 30°: 59.72, **58.74**, 58.87, 59.21, 60.13, 62.23, 63.72, 64.74, 65.94 mm; `observed`
/// 66.96, `all` 70.80) and from a given start (round 40: 0.5, 1, 2, 3, 5, 10°: 32.05, **31.68**,
/// 31.71, 31.78, 31.93, 32.25): three trackers leave most of the body to the network's values.
pub const HMD_ANCHOR_STD_DEG: f64 = 1.0;

/// The anchor's standard deviation of the root translation, millimetres (every modality): the
/// largest of 3, 10, 30, 100 and 300 mm within 0.2 mm of the best for `neural+lm` (given start)
/// on the validation subject's keypoints2d seen by one camera of `lfit synth --cameras 1` (CMU
/// subject 6, 300 local frames: V2V 107.34, 107.34, **107.49**, 109.57, 123.17 mm; without it
/// 161.74, `observed` 115.34) — one view leaves the depth along its axis open, and LM anchored
/// on the rotations only slid the body along it. On the validation subject's markers, its
/// keypoints2d on three cameras and on the default rig, and hmd, 30 mm changes V2V by at most
/// 0.07 mm (docs/results/captured-motion.md, round 29).
pub const ANCHOR_TRANSLATION_STD_MM: f64 = 30.0;

/// The temporal anchor's standard deviation of the root translation, millimetres: the pull
/// toward the previous frame's fit in a sequence ([`anchor_translation_std_mm`]). A person
/// moves between two frames: walking at 1.4 m/s is 47 mm a frame at 30 fps and 140 at 10, and
/// [`ANCHOR_TRANSLATION_STD_MM`]'s 30 mm — chosen for a pull toward an estimate — held a subject
/// who walks toward one camera hundreds of millimetres behind (LM anchored, the subject's
/// height as a prior, six phone-rig sequences of the validation subject: 123.9 mm V2V at 30 mm,
/// 75.5 at 60, 66.8 at 100, 65.4 at 200, **65.5** at 300, 65.7 with no pull; at 10 fps 169.1,
/// 83.2 at 100, 76.0 at 200, **75.6** at 300, 75.9). The tightest σ level with no pull on one
/// camera at 10 and 30 fps: it still bounds a frame the data leave open. It moved the
/// validation subject's markers and six-camera keypoints2d sequences at 30, 15 and 10 fps, the
/// two- and three-camera rigs and the captured clip's sequences by at most 0.16 mm, none by
/// more than 0.01 mm for the worse (docs/results/captured-motion.md, round 34).
pub const SEQUENCE_ANCHOR_TRANSLATION_STD_MM: f64 = 300.0;

/// The root translation's standard deviation of an anchor given without one (`anchored`,
/// `anchored:DEG`): [`SEQUENCE_ANCHOR_TRANSLATION_STD_MM`] where the start is the previous
/// frame's fit in a sequence (`chained`: the request carries the sequence's motion,
/// [`FitRequest::motion`]), [`ANCHOR_TRANSLATION_STD_MM`] where it is an estimate (a frame's
/// own start, `neural+lm`'s network result).
pub fn anchor_translation_std_mm(chained: bool) -> f64 {
    if chained {
        SEQUENCE_ANCHOR_TRANSLATION_STD_MM
    } else {
        ANCHOR_TRANSLATION_STD_MM
    }
}

/// Where `neural+lm`'s network starts, for the σ of its anchor ([`anchor_std_deg`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum AnchorStart {
    /// Φ(D), or the better of Φ(D) and the given start (`--neural-start phi`, `best`, `both`).
    Estimate,
    /// A given pose near the target (`--neural-start given` on single frames).
    Given,
    /// The previous frame's fit (`--neural-start given` in a sequence).
    Previous,
}

/// The anchor chosen for `neural+lm` on a modality (the constants above) and where its network
/// starts, where one was measured: markers, keypoints2d, hmd. From a given start near the target
/// a tighter pull was better on markers and keypoints2d single frames; in a sequence, from the
/// previous frame's fit, on markers too (the validation subject's 300-frame sequences: 11.20 mm
/// at 5° against 14.60 at 15°) but not on keypoints2d (22.93 at 10° against 23.70 at 3°;
/// docs/results/captured-motion.md, round 40).
pub fn anchor_std_deg(modality: lfit_model::observe::Modality, start: AnchorStart) -> Option<f64> {
    use AnchorStart::{Estimate, Given, Previous};
    use lfit_model::observe::Modality;
    match (modality, start) {
        (Modality::Markers, Given | Previous) => Some(GIVEN_START_ANCHOR_STD_DEG),
        (Modality::Markers, Estimate) => Some(ANCHOR_STD_DEG),
        (Modality::Keypoints2d, Given) => Some(KEYPOINTS2D_GIVEN_START_ANCHOR_STD_DEG),
        (Modality::Keypoints2d, Estimate | Previous) => Some(KEYPOINTS2D_ANCHOR_STD_DEG),
        (Modality::Hmd, _) => Some(HMD_ANCHOR_STD_DEG),
        _ => None,
    }
}

/// How much the temporal anchor widens with the sequence's motion: in a sequence (each frame
/// started from the previous frame's fit, [`FitRequest::motion`] given) an anchored rotation's
/// standard deviation is `min(ANCHOR_MOTION_CAP · σ, √(σ² + (ANCHOR_MOTION_GAIN · m)²))`, `σ` the
/// anchor's and `m` the entry's recent root-mean-square change per frame
/// ([`SequenceMotion`]). Where the body moves fast (a serve's arm, a low frame rate) the pull
/// loosens; where it is still, it holds at `σ`. The root translation's pull is not widened (it
/// holds the depth a view leaves open; widening it too moved the validation sequences by at
/// most 0.1 mm). Chosen with [`SEQUENCE_MOTION_WEIGHT`] and the
/// cap on the validation subject's sequences at 30, 15 and 10 frames per second (CMU subject 6,
/// four 100-frame sequences each; LM, V2V mm): markers with σ = 3°, gain 1 / 2 / 3 / 4 / 6
/// (uncapped, weight 0.5) 8.72 / 8.52 / **8.49** / 8.54 / 9.18 at 30 fps, 10.50 / 9.80 /
/// **9.51** / 9.56 / 10.07 at 15, 13.34 / 12.40 / 12.15 / **11.98** / 12.27 at 10 (3 and 4
/// within 0.02 on the mean); docs/results/captured-motion.md, round 30.
pub const ANCHOR_MOTION_GAIN: f64 = 3.0;

/// The most the motion widens the temporal anchor, as a multiple of its standard deviation
/// ([`ANCHOR_MOTION_GAIN`]): without a cap an entry the data leave open drifts, its noisy
/// changes widen its own pull and it drifts further (the validation subject's 300-frame
/// sequences: markers 10.36 mm uncapped, **9.98** capped at 3, 10.10 at 2, 10.39 at 1.5; the fixed
/// 5° 10.32).
pub const ANCHOR_MOTION_CAP: f64 = 3.0;

/// The weight of the newest frame-to-frame change in [`SequenceMotion`]'s exponential average
/// of squared changes (0.1 / 0.2 / 0.5 / 1 on the validation sequences of
/// [`ANCHOR_MOTION_GAIN`], markers, gain 3, σ 3°: 8.44 / 8.44 / 8.49 / 8.46 mm at 30 fps, 9.41 /
/// 9.40 / 9.51 / 9.86 at 15, 11.89 / 11.94 / 12.15 / 12.81 at 10).
pub const SEQUENCE_MOTION_WEIGHT: f64 = 0.2;

/// An anchor's standard deviation `std` widened by an entry's recent motion `motion` (the
/// same unit: radians or metres per frame): [`ANCHOR_MOTION_GAIN`], [`ANCHOR_MOTION_CAP`].
pub fn widened_std(std: f64, motion: f64) -> f64 {
    let g = ANCHOR_MOTION_GAIN * motion;
    (std * std + g * g).sqrt().min(ANCHOR_MOTION_CAP * std)
}

/// How fast a sequence's fits have been moving: per parameter entry, an exponential average
/// (weight [`SEQUENCE_MOTION_WEIGHT`] on the newest) of the squared change between consecutive
/// frames' fits. The sequence driver feeds it each fitted frame that started from the previous
/// frame's fit and resets it where the chain breaks; [`FitRequest::motion`] carries its root.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct SequenceMotion {
    mean_square: Option<Vec<f64>>,
}

impl SequenceMotion {
    /// Adds the change from `before` (the previous frame's fit) to `after` (this frame's).
    /// A change of another length, or one that is not finite, restarts the average from it
    /// (non-finite entries count as no change).
    pub fn update(&mut self, before: &[f64], after: &[f64]) {
        let square: Vec<f64> = before
            .iter()
            .zip(after)
            .map(|(a, b)| {
                let d = b - a;
                if d.is_finite() { d * d } else { 0.0 }
            })
            .collect();
        self.mean_square = Some(match self.mean_square.take() {
            Some(m) if m.len() == square.len() => m
                .iter()
                .zip(&square)
                .map(|(m, d)| (1.0 - SEQUENCE_MOTION_WEIGHT) * m + SEQUENCE_MOTION_WEIGHT * d)
                .collect(),
            _ => square,
        });
    }

    /// Forgets the motion (a frame that does not follow the previous one).
    pub fn reset(&mut self) {
        self.mean_square = None;
    }

    /// The root-mean-square change per frame of each entry; `None` before any change.
    pub fn rms(&self) -> Option<Vec<f64>> {
        self.mean_square
            .as_ref()
            .map(|m| m.iter().map(|v| v.sqrt()).collect())
    }
}

/// The temporal anchor of a classical fit in a sequence (each frame started from the previous
/// frame's result, `lfit fit --method lm --dofs anchored:DEG`: LM pulled toward its previous
/// frame, widened by the sequence's motion: [`ANCHOR_MOTION_GAIN`]), degrees, where one was
/// chosen: the best σ for LM on the validation subject's sequences at 30, 15 and 10 frames per
/// second (CMU subject 6, `lfit synth --scenario sequence --frames 100 --fps F`, seeds 11–14;
/// V2V mm, mean of the three rates): markers **4°** (2° / 3° / 4° / 5°: 10.32 / 9.92 / **9.91** /
/// 10.01; round 28's fixed 5° without the motion 10.57), keypoints2d
/// **5°** (3° / 4° / 5° / 8°: 15.52 / 15.15 / **15.04** / 15.45; the fixed 8° 15.79);
/// docs/results/captured-motion.md, round 30. Not chosen for
/// hmd (σ moved its sequence by 16 mm without a trend, round 28). The classical baseline a
/// learned fitter has to beat in a sequence: LM's default stays every entry free (the published
/// figures and the scipy parity).
pub fn sequence_anchor_std_deg(modality: lfit_model::observe::Modality) -> Option<f64> {
    use lfit_model::observe::Modality;
    match modality {
        Modality::Markers => Some(4.0),
        Modality::Keypoints2d => Some(5.0),
        _ => None,
    }
}

/// The energy of [`AnchoredDofs`]: `energy` plus a Gaussian pull of the `free` rotation entries
/// toward `centre` by `std_deg` degrees (each widened by the sequence's `motion`,
/// [`widened_std`], where given) and of the free root translation entries by
/// `translation_std_mm` millimetres; shape and expression entries stay free. The one place the
/// temporal anchor is built: `--dofs anchored` and the training of networks that fit on it
/// (`"starts": {"anchor_deg": …}`). A motion of the wrong length or with a negative or
/// non-finite entry is refused.
pub fn anchored_energy(
    energy: &Energy,
    centre: &[f64],
    free: &[usize],
    std_deg: f64,
    translation_std_mm: f64,
    motion: Option<&[f64]>,
) -> Result<Energy, String> {
    let layout = energy.template().layout();
    let rotations = layout.range(Block::Rotations);
    let translation = layout.range(Block::Translation);
    if let Some(m) = motion {
        if m.len() != centre.len() || m.iter().any(|v| !(v.is_finite() && *v >= 0.0)) {
            return Err(format!(
                "the sequence's motion must hold {} finite non-negative entries",
                centre.len()
            ));
        }
    }
    let widen = |i: usize, std: f64| match motion {
        Some(m) => widened_std(std, m[i]),
        None => std,
    };
    let entries: Vec<(usize, f64)> = free
        .iter()
        .filter_map(|&i| {
            if rotations.contains(&i) {
                Some((i, widen(i, std_deg.to_radians())))
            } else if translation.contains(&i) {
                Some((i, translation_std_mm / 1000.0))
            } else {
                None
            }
        })
        .collect();
    energy
        .with_anchor(centre, &entries)
        .map_err(|e| e.to_string())
}

/// The largest data standard deviation, degrees, of a rotation the sequence networks move
/// ([`sequence_network_dofs`]): the thumbs and fingers a markers set barely sees, and what
/// keypoints leave as open, stay at the previous frame's values. Chosen on the validation
/// subject's markers sequences at 30, 15 and 10 fps (CMU subject 6, seeds 11–14, the markers
/// sequence network with `anchored:4`; V2V mm): 20° 9.12 / 12.71 / 17.66, **30°** 9.12 /
/// 12.60 / 17.47, 45° 9.27 / 12.66 / 17.53 (docs/results/captured-motion.md, round 31).
pub const SEQUENCE_NETWORK_OBSERVED_DEG: f64 = 30.0;

/// What a network fine-tuned on the temporal anchor (`checkpoints/<modality>-makehuman-sequence`,
/// `"starts": {"anchor_deg": σ}`) fits a sequence's frames with: the anchor of LM's sequences
/// ([`sequence_anchor_std_deg`], the σ it was trained with) and the rotations the data leave
/// beyond [`SEQUENCE_NETWORK_OBSERVED_DEG`] held — the network's own update moves entries the
/// energy says nothing of, and over 300 frames the markers network's thumbs and fingers drifted
/// 8–30° with the anchor alone (V2V 13.17 mm against 11.82 with both). `None` where no
/// sequence σ was chosen.
pub fn sequence_network_dofs(modality: lfit_model::observe::Modality) -> Option<Dofs> {
    sequence_anchor_std_deg(modality).map(|std_deg| Dofs::ObservedAnchored {
        max_std_deg: SEQUENCE_NETWORK_OBSERVED_DEG,
        std_deg,
        translation_std_mm: None,
    })
}

impl AnchoredDofs {
    /// `inner` with the free rotations anchored at the start by `std_deg` degrees and the free
    /// translation entries by `translation_std_mm` millimetres (`None`: the default for where
    /// each request's start comes from, [`anchor_translation_std_mm`]).
    pub fn new(inner: Box<dyn Fitter>, std_deg: f64, translation_std_mm: Option<f64>) -> Self {
        Self {
            inner,
            std_deg,
            translation_std_mm,
        }
    }
}

impl std::fmt::Debug for AnchoredDofs {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "AnchoredDofs({})", self.inner.name())
    }
}

impl Fitter for AnchoredDofs {
    /// `<inner>-anchored`, or `<inner>-anchored-<DEG>deg` (`-<DEG>deg-<MM>mm`) at other
    /// standard deviations ([`Dofs::suffix`]).
    fn name(&self) -> String {
        format!(
            "{}-{}",
            self.inner.name(),
            Dofs::Anchored {
                std_deg: self.std_deg,
                translation_std_mm: self.translation_std_mm,
            }
            .suffix()
        )
    }

    fn fit(&self, request: &FitRequest<'_>) -> Result<FitResult, FitError> {
        let clock = Instant::now();
        let mut centre = request.start.clone();
        request.bounds.clamp(&mut centre);
        let translation_std_mm = self
            .translation_std_mm
            .unwrap_or_else(|| anchor_translation_std_mm(request.motion.is_some()));
        let anchored = anchored_energy(
            request.energy,
            &centre,
            &request.mask.free,
            self.std_deg,
            translation_std_mm,
            request.motion.as_deref(),
        )
        .map_err(|e| FitError::LeastSquares(format!("--dofs anchored: {e}")))?;
        let inner = FitRequest {
            energy: &anchored,
            start: request.start.clone(),
            mask: request.mask.clone(),
            bounds: request.bounds.clone(),
            budget: request.budget,
            seed: request.seed,
            // The motion is the anchor's: the inner fitter minimises the anchored energy.
            motion: None,
        };
        let result = self.inner.fit(&inner);
        request
            .energy
            .add_counts(anchored.evaluations(), anchored.gradient_evaluations());
        let mut result = result?;
        let pull = anchored.anchor().map_or(0.0, |a| a.value(&result.pose));
        result.energy -= pull;
        result.terms.retain(|(name, _)| *name != "anchor");
        result.method = self.name();
        result.time_s = clock.elapsed().as_secs_f64();
        Ok(result)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_round_trip_and_unknown_is_refused() {
        let three = Dofs::Observed { max_std_deg: 3.0 };
        let loose = Dofs::anchored(2.5);
        let both = Dofs::Anchored {
            std_deg: 2.5,
            translation_std_mm: Some(100.0),
        };
        let moved = Dofs::Anchored {
            std_deg: ANCHOR_STD_DEG,
            translation_std_mm: Some(5.0),
        };
        for d in [
            Dofs::All,
            Dofs::OBSERVED,
            three,
            Dofs::ANCHORED,
            loose,
            both,
            moved,
        ] {
            assert_eq!(d.name().parse::<Dofs>().unwrap(), d);
        }
        assert_eq!(Dofs::ANCHORED.name(), "anchored");
        assert_eq!(loose.name(), "anchored:2.5");
        assert_eq!(both.name(), "anchored:2.5,100");
        assert_eq!(moved.name(), "anchored:15,5");
        let combined = Dofs::ObservedAnchored {
            max_std_deg: 30.0,
            std_deg: 4.0,
            translation_std_mm: None,
        };
        assert_eq!("observed:30+anchored:4".parse::<Dofs>().unwrap(), combined);
        assert_eq!(combined.name(), "observed:30+anchored:4");
        assert_eq!(combined.suffix(), "anchored-4deg-observed-30deg");
        let defaults = "observed+anchored".parse::<Dofs>().unwrap();
        assert_eq!(defaults.name().parse::<Dofs>().unwrap(), defaults);
        assert_eq!(defaults.suffix(), "anchored-observed");
        for (bad, want) in [
            ("anchored:4+observed", "only observed[:DEG]+anchored"),
            ("all+anchored", "only observed[:DEG]+anchored"),
            ("observed+observed", "only observed[:DEG]+anchored"),
            ("observed+anchored:0", "standard deviation after anchored:"),
            ("observed:x+anchored", "threshold after observed:"),
            ("observed+", "unknown dofs"),
        ] {
            let e = bad.parse::<Dofs>().unwrap_err();
            assert!(e.contains(want), "{bad}: {e}");
        }
        assert_eq!(
            [Dofs::ANCHORED, loose, both].map(Dofs::suffix),
            ["anchored", "anchored-2.5deg", "anchored-2.5deg-100mm"]
        );
        // An explicit translation σ is kept wherever the start comes from, even at a default's
        // value: `anchored` alone is the default by start.
        let explicit = "anchored:15,30".parse::<Dofs>().unwrap();
        assert_eq!(
            explicit,
            Dofs::Anchored {
                std_deg: ANCHOR_STD_DEG,
                translation_std_mm: Some(ANCHOR_TRANSLATION_STD_MM),
            }
        );
        assert_ne!(explicit, Dofs::ANCHORED);
        assert_eq!(explicit.name(), "anchored:15,30");
        for bad in [
            "anchored:",
            "anchored:0",
            "anchored:-1",
            "anchored:inf",
            "anchored:y",
            "anchored:,30",
        ] {
            let e = bad.parse::<Dofs>().unwrap_err();
            assert!(
                e.contains("standard deviation after anchored:"),
                "{bad}: {e}"
            );
        }
        for bad in [
            "anchored:5,",
            "anchored:5,0",
            "anchored:5,-3",
            "anchored:5,nan",
            "anchored:5,2,3",
        ] {
            let e = bad.parse::<Dofs>().unwrap_err();
            assert!(
                e.contains("translation's standard deviation") && e.contains("millimetres"),
                "{bad}: {e}"
            );
        }
        assert_eq!(Dofs::OBSERVED.name(), "observed");
        assert_eq!(three.name(), "observed:3");
        assert_eq!(
            [Dofs::All, Dofs::OBSERVED, three].map(Dofs::suffix),
            ["", "observed", "observed-3deg"]
        );
        let e = "some".parse::<Dofs>().unwrap_err();
        assert!(
            e.contains("all, observed, observed:DEG, anchored, anchored:DEG, anchored:DEG,MM or observed[:DEG]+anchored[:DEG[,MM]]"),
            "{e}"
        );
        for bad in [
            "observed:",
            "observed:-1",
            "observed:0",
            "observed:nan",
            "observed:x",
        ] {
            let e = bad.parse::<Dofs>().unwrap_err();
            assert!(e.contains("positive number of degrees"), "{bad}: {e}");
        }
    }

    #[test]
    fn only_rotations_below_the_information_threshold_are_frozen() {
        // Entries: 0..3 translation, 3..9 rotations, 9..11 shape.
        let mask = DofMask {
            name: "m".into(),
            free: (0..11).collect(),
        };
        let max_std = 0.1_f64; // information ≥ 100 keeps an entry
        let mut info = vec![0.0; 11];
        info[3] = 100.0; // exactly at the threshold: kept
        info[4] = 99.0; // just below: frozen
        info[5] = 1e6;
        info[6] = 0.0; // unseen: frozen
        info[7] = 500.0;
        info[8] = 1.0;
        // translation and shape kept whatever their information (0 here)
        let m = observed_mask(&mask, &info, 3..9, max_std).unwrap();
        assert_eq!(m.free, vec![0, 1, 2, 3, 5, 7, 9, 10]);
        assert_eq!(m.name, "m-observed");
        // Entries already fixed stay fixed.
        let fixed = DofMask {
            name: "k".into(),
            free: vec![4, 5],
        };
        assert_eq!(
            observed_mask(&fixed, &info, 3..9, max_std).unwrap().free,
            vec![5]
        );
        // Nothing left: None.
        let only = DofMask {
            name: "k".into(),
            free: vec![4, 6],
        };
        assert!(observed_mask(&only, &info, 3..9, max_std).is_none());
    }
}
