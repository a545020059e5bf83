//! What determines a dataset besides the model and sensor: the scenario of papers/000 §4, where
//! target poses come from, imported motion files, and the synthesis settings a dataset records in
//! its metadata ([`SynthConfig`]).

use std::fmt;
use std::path::Path;
use std::str::FromStr;
use std::sync::Arc;

use lfit_model::Template;
use lfit_model::observe::Modality;
use serde::{Deserialize, Serialize};

use crate::error::SynthError;
use crate::motion::MotionKind;
use crate::motion::augment::MotionAugment;
use crate::motion::file::MotionClip;
use crate::noise::NoiseConfig;

/// The experiment cases of papers/000 §4.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Scenario {
    /// The target is near the start (0.03–0.25 s later in the same motion), inside the `local` box.
    Local,
    /// The start is the rest pose; the target is seconds into a motion, inside the `global` box.
    Global,
    /// Consecutive frames of one motion; each frame starts from the previous frame's pose.
    Sequence,
}

impl Scenario {
    pub fn name(self) -> &'static str {
        match self {
            Scenario::Local => "local",
            Scenario::Global => "global",
            Scenario::Sequence => "sequence",
        }
    }
}

impl fmt::Display for Scenario {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

impl FromStr for Scenario {
    type Err = SynthError;
    fn from_str(s: &str) -> Result<Self, SynthError> {
        [Scenario::Local, Scenario::Global, Scenario::Sequence]
            .into_iter()
            .find(|x| x.name() == s)
            .ok_or_else(|| SynthError::UnknownScenario(s.to_string()))
    }
}

/// Where target poses come from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum PoseSource {
    /// Motion: the procedural motion library, or the imported motion files of
    /// [`SynthConfig::motion_files`] (with [`SynthConfig::with_library`]: both).
    #[default]
    Motion,
    /// Uniform sampling within the global bounds (root height within ±0.3 m of standing).
    Uniform,
    /// papers/002's face protocol (supp.: "we vary pose, identity and expression"): every
    /// rotation uniform between half its lower and half its upper joint limit, the root translation uniform within
    /// ±[`FACE_TRANSLATION`] of the rest (in front of the `landmarks2d` camera), identity and
    /// expression from the prior like every subject.
    Face,
}

/// Half-widths (m) of the face protocol's translation box: 5 cm sideways and up, 10 cm towards
/// or away from the camera (0.6 m away: about ±17 % in scale).
pub const FACE_TRANSLATION: [f64; 3] = [0.05, 0.05, 0.1];

impl PoseSource {
    /// The name `--source` takes and datasets record.
    pub fn name(self) -> &'static str {
        match self {
            PoseSource::Motion => "motion",
            PoseSource::Uniform => "uniform",
            PoseSource::Face => "face",
        }
    }
}

impl FromStr for PoseSource {
    type Err = SynthError;
    fn from_str(s: &str) -> Result<Self, SynthError> {
        [PoseSource::Motion, PoseSource::Uniform, PoseSource::Face]
            .into_iter()
            .find(|p| p.name() == s)
            .ok_or_else(|| SynthError::UnknownSource(s.to_string()))
    }
}

/// Everything that determines a dataset (with the template and sensor).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SynthConfig {
    pub modality: Modality,
    pub scenario: Scenario,
    pub source: PoseSource,
    pub frames: usize,
    pub seed: u64,
    /// Frame rate of sequences, Hz.
    pub fps: f64,
    pub noise: NoiseConfig,
    /// Each subject's noise is [`SynthConfig::noise`] times a factor drawn uniformly in
    /// `[1 − spread, 1]` ([`NoiseConfig::times`]: σs, outlier and dropout rates), so one set
    /// holds quiet and noisy sensors and a network trained on it can read the regime from the
    /// residuals. One draw per subject: per frame in the local and global scenarios, once for a
    /// sequence. 0 by default (and then absent from the metadata, so other datasets keep their
    /// bytes); within [0, 1].
    #[serde(default, skip_serializing_if = "is_zero")]
    pub noise_spread: f64,
    /// Procedural motions drawn from (the papers' library, [`MotionKind::CLASSIC`], by default).
    pub motions: Vec<MotionKind>,
    /// Imported motion files (`lfit motion import`) that `source = motion` draws its frames
    /// from instead of the procedural library; empty: the library. Recorded in the dataset's
    /// metadata by path, size and hash (absent when empty, so other datasets keep their bytes).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub motion_files: Vec<MotionFile>,
    /// With motion files: each frame (a sequence: the whole sequence) comes from the library or
    /// from a file by a fair coin.
    #[serde(default, skip_serializing_if = "is_false")]
    pub with_library: bool,
    /// Transforms of motion-file frames ([`MotionAugment`]: mirror, heading, jitter); none by
    /// default (and then absent from the metadata, so other datasets keep their bytes).
    #[serde(default, skip_serializing_if = "MotionAugment::is_none")]
    pub motion_augment: MotionAugment,
    /// With `source = motion` in the local and global scenarios: the share of frames (each by its
    /// own coin) whose target pose is drawn uniformly within the model's joint limits and
    /// global box instead (as `source = uniform` draws them; papers/000's uniform sampling, the
    /// "poses sampled uniformly within the limits" of issue 25). 0 by default (and then absent
    /// from the metadata, so other datasets keep their bytes); a sequence follows a motion, so
    /// it refuses a share above 0.
    #[serde(default, skip_serializing_if = "is_zero")]
    pub uniform_share: f64,
    /// markers: each subject's markers are observed on vertices slipped from the model's marker
    /// vertices (a hand-placed marker set never sits exactly where the model's does): per marker
    /// and subject a normal offset of this σ per axis, in metres, from the marker's rest
    /// position, moved to the nearest rest vertex of the same body part (the same dominant
    /// joint). The dataset keeps the model's marker set, so fits see the mismatch a user's
    /// capture has. One draw per subject: per frame in the local and global scenarios, once for
    /// a sequence. 0 by default (and then absent from the metadata, so other datasets keep their
    /// bytes); at most [`MAX_MARKER_SLIP`].
    #[serde(default, skip_serializing_if = "is_zero")]
    pub marker_slip: f64,
    /// keypoints2d: each subject's keypoints are observed off its joints' centres, as a 2D
    /// detector's are (a COCO hip or shoulder is a point on the body that annotators clicked,
    /// not the skeleton's joint centre): per joint and subject a normal offset of this σ per
    /// axis, in metres, in the rest frame, carried by the segment that ends at the joint
    /// ([`lfit_model::observe::KeypointSetup::offsets`]). The dataset keeps the joint centres,
    /// so fits see the mismatch a detector's keypoints have. One draw per subject: per frame in
    /// the local and global scenarios, once for a sequence. 0 by default (and then absent from
    /// the metadata, so other datasets keep their bytes); at most [`MAX_MARKER_SLIP`].
    #[serde(default, skip_serializing_if = "is_zero")]
    pub keypoint_bias: f64,
    /// keypoints2d with a [`SynthConfig::keypoint_bias`]: the offsets are a detector's, not a
    /// subject's — drawn once from this seed and shared by every subject of every dataset made
    /// with the same detector seed and bias (a 2D detector puts its hip where its training
    /// annotations put hips, whoever is filmed). `None` (the default, absent from the
    /// metadata): one draw per subject from the dataset's seed.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub keypoint_detector: Option<u64>,
}

/// The largest [`SynthConfig::marker_slip`] and [`SynthConfig::keypoint_bias`] accepted, metres.
pub const MAX_MARKER_SLIP: f64 = 0.1;

/// Why `spread` is not a [`SynthConfig::noise_spread`], or `None` when it is: a share of the
/// noise within [0, 1]. The check of `SynthConfig::noise_spread` and of a training config's
/// `noise_spread`.
pub fn noise_spread_problem(spread: f64) -> Option<String> {
    (!(0.0..=1.0).contains(&spread)).then(|| "is a share of the noise in [0, 1]".to_string())
}

/// Why `slip` (metres) is not a marker slip of `modality` data, or `None` when it is: a standard
/// deviation within [0, [`MAX_MARKER_SLIP`]], above 0 only for markers. The check of
/// `SynthConfig::marker_slip` and of a training config's `marker_slip_mm`.
pub fn marker_slip_problem(slip: f64, modality: Modality) -> Option<String> {
    placement_sigma_problem(slip, modality, Modality::Markers, "moves markers")
}

/// Why `bias` (metres) is not a keypoint bias of `modality` data, or `None` when it is: a
/// standard deviation within [0, [`MAX_MARKER_SLIP`]], above 0 only for keypoints2d. The check
/// of `SynthConfig::keypoint_bias`.
pub fn keypoint_bias_problem(bias: f64, modality: Modality) -> Option<String> {
    placement_sigma_problem(
        bias,
        modality,
        Modality::Keypoints2d,
        "moves 2D keypoints off the joints",
    )
}

/// Why `sigma` (metres) is not a standard deviation within [0, [`MAX_MARKER_SLIP`]] that `moves`
/// the points of `for_modality` data, given `modality` data.
fn placement_sigma_problem(
    sigma: f64,
    modality: Modality,
    for_modality: Modality,
    moves: &str,
) -> Option<String> {
    if !(sigma.is_finite() && (0.0..=MAX_MARKER_SLIP).contains(&sigma)) {
        return Some(format!(
            "is a standard deviation between 0 and {} mm",
            1000.0 * MAX_MARKER_SLIP
        ));
    }
    (sigma > 0.0 && modality != for_modality)
        .then(|| format!("{moves}: the modality is {modality}"))
}

fn is_false(b: &bool) -> bool {
    !*b
}

fn is_zero(x: &f64) -> bool {
    *x == 0.0
}

/// An imported motion file (`lfit motion import`: poses in a model's parameter layout) that
/// synthesis draws target poses from. Only its description is serialised (the dataset's
/// metadata says where its frames came from); [`MotionFile::load`] reads the poses.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct MotionFile {
    /// The path as given.
    pub path: String,
    /// The file's own record of its origin (e.g. `bvh:clip.bvh map:map.json`).
    pub source: String,
    pub frames: usize,
    /// Frame rate, Hz.
    pub fps: f64,
    /// FNV-1a (64 bit) of the poses' little-endian f64 bytes, in hex: which contents were used.
    pub poses_hash: String,
    /// The poses (not serialised: a config read back from a dataset has none).
    #[serde(skip)]
    pub clip: Option<Arc<MotionClip>>,
}

impl MotionFile {
    /// Reads a motion file and checks it against `template` (a motion made for another
    /// parameter layout is refused).
    pub fn load(path: &Path, template: &Template) -> Result<Self, SynthError> {
        let clip = MotionClip::read(path)?;
        Self::from_clip(&path.display().to_string(), clip, template)
    }

    /// A motion held in memory, named `path`, checked against `template`.
    pub fn from_clip(
        path: &str,
        clip: MotionClip,
        template: &Template,
    ) -> Result<Self, SynthError> {
        let bad = |reason: String| SynthError::MotionFile {
            path: path.to_string(),
            reason,
        };
        clip.check_model(template).map_err(|e| bad(e.to_string()))?;
        let dim = template.layout().dim();
        if clip.poses.is_empty() || clip.poses.iter().any(|p| p.len() != dim) {
            return Err(bad(format!(
                "needs at least one pose of {dim} numbers per frame"
            )));
        }
        if clip.poses.iter().flatten().any(|v| !v.is_finite()) {
            return Err(bad("a pose value is not finite".into()));
        }
        if !(clip.fps.is_finite() && clip.fps > 0.0) {
            return Err(bad(format!("frame rate {} is not positive", clip.fps)));
        }
        let mut hash = 0xcbf2_9ce4_8422_2325_u64;
        for byte in clip.poses.iter().flatten().flat_map(|v| v.to_le_bytes()) {
            hash = (hash ^ u64::from(byte)).wrapping_mul(0x0100_0000_01b3);
        }
        Ok(Self {
            path: path.to_string(),
            source: clip.source.clone(),
            frames: clip.poses.len(),
            fps: clip.fps,
            poses_hash: format!("{hash:016x}"),
            clip: Some(Arc::new(clip)),
        })
    }

    /// The file's name, for the per-frame motion names (`walk.npz:17`).
    pub fn label(&self) -> String {
        Path::new(&self.path)
            .file_name()
            .map_or_else(|| self.path.clone(), |n| n.to_string_lossy().into_owned())
    }

    pub(crate) fn poses(&self) -> Result<&[Vec<f64>], SynthError> {
        match &self.clip {
            Some(c) if c.poses.len() == self.frames => Ok(&c.poses),
            _ => Err(SynthError::MotionFile {
                path: self.path.clone(),
                reason: "its poses are not loaded (a configuration read back from a dataset holds only the file's description)".into(),
            }),
        }
    }

    /// Frames between two sequence frames so that the sequence runs near `fps` (at least 1).
    pub(crate) fn stride(&self, fps: f64) -> usize {
        ((self.fps / fps).round() as usize).max(1)
    }
}

impl SynthConfig {
    pub fn new(modality: Modality, scenario: Scenario, frames: usize, seed: u64) -> Self {
        Self {
            modality,
            scenario,
            source: PoseSource::Motion,
            frames,
            seed,
            fps: 30.0,
            noise: NoiseConfig::default(),
            noise_spread: 0.0,
            motions: MotionKind::CLASSIC.to_vec(),
            motion_files: Vec::new(),
            with_library: false,
            motion_augment: MotionAugment::default(),
            uniform_share: 0.0,
            marker_slip: 0.0,
            keypoint_bias: 0.0,
            keypoint_detector: None,
        }
    }

    /// Whether frames may come from the procedural library.
    pub(crate) fn uses_library(&self) -> bool {
        self.source == PoseSource::Motion && (self.motion_files.is_empty() || self.with_library)
    }

    pub fn validate(&self) -> Result<(), SynthError> {
        let setting = |name, value: String, reason: &str| {
            Err(SynthError::Setting {
                name,
                value,
                reason: reason.into(),
            })
        };
        if self.frames == 0 {
            return setting("frames", "0".into(), "must be at least 1");
        }
        if !(self.fps.is_finite() && self.fps > 0.0) {
            return setting("fps", self.fps.to_string(), "must be positive");
        }
        if self.motions.is_empty() {
            return setting("motions", "[]".into(), "need at least one motion");
        }
        let source_name = self.source.name();
        if self.scenario == Scenario::Sequence && self.source != PoseSource::Motion {
            return setting(
                "source",
                source_name.into(),
                "sequences need smooth motion: use --source motion",
            );
        }
        if self.source != PoseSource::Motion && !self.motion_files.is_empty() {
            return setting(
                "source",
                source_name.into(),
                "motion files (--motions) are drawn from by --source motion",
            );
        }
        if let Err(reason) = self
            .motion_augment
            .validate_for(self.motion_files.len(), "give them (--motions FILE...)")
        {
            return setting(
                "motion_augment",
                format!("{:?}", self.motion_augment),
                &reason,
            );
        }
        if self.with_library && self.motion_files.is_empty() {
            return setting(
                "with_library",
                "true".into(),
                "mixes the library with motion files: give them (--motions FILE...)",
            );
        }
        if !(0.0..=1.0).contains(&self.uniform_share) {
            return setting(
                "uniform_share",
                self.uniform_share.to_string(),
                "is a share of frames: between 0 and 1",
            );
        }
        if self.uniform_share > 0.0 && self.source != PoseSource::Motion {
            return setting(
                "uniform_share",
                self.uniform_share.to_string(),
                "mixes uniform poses into --source motion",
            );
        }
        if self.uniform_share > 0.0 && self.scenario == Scenario::Sequence {
            return setting(
                "uniform_share",
                self.uniform_share.to_string(),
                "a sequence follows one motion: uniform poses are for single frames",
            );
        }
        if let Some(reason) = noise_spread_problem(self.noise_spread) {
            return setting("noise_spread", self.noise_spread.to_string(), &reason);
        }
        if let Some(reason) = marker_slip_problem(self.marker_slip, self.modality) {
            return setting("marker_slip", format!("{} m", self.marker_slip), &reason);
        }
        if let Some(reason) = keypoint_bias_problem(self.keypoint_bias, self.modality) {
            return setting(
                "keypoint_bias",
                format!("{} m", self.keypoint_bias),
                &reason,
            );
        }
        if let (Some(seed), true) = (self.keypoint_detector, self.keypoint_bias <= 0.0) {
            return setting(
                "keypoint_detector",
                seed.to_string(),
                "a detector's offsets are drawn with keypoint_bias's σ: give a keypoint bias above 0",
            );
        }
        for f in &self.motion_files {
            f.poses()?;
        }
        Ok(())
    }
}
