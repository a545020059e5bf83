//! Observation models (SPEC §4): the one place where pose → predicted observation is computed.
//!
//! Synthesis adds noise and occlusion to these predictions; the energy compares them with data.
//! Every observation model ([`ObservationModel`]: `markers`, `keypoints2d`, `hmd`,
//! `silhouettes`, `scan` and any defined downstream, [`Sensor::Custom`]) has a fixed-size
//! prediction and a visibility mask of the same size, so its residual
//! `R(θ) = visible ⊙ (predicted − observed)` has a fixed length. papers/000's scan energy compares
//! the posed surface with a distance transform of the whole point cloud instead of entry by entry.
//!
//! Beside the models live the sensors' geometry ([`camera`]), the `scan` modality's data (point
//! cloud, distance transform, silhouette masks: [`scan`]) and the noise synthesis adds ([`noise`]).

pub(crate) mod builtin;
pub(crate) use builtin::expand_point_factors;
pub mod camera;
pub mod hmd_layout;
mod landmarks;
pub mod noise;
pub mod scan;
mod scan_model;
mod silhouettes;
mod view;

use std::fmt;
use std::str::FromStr;
use std::sync::Arc;

use glam::{DAffine3, DMat3, DQuat, DVec3, Vec3};
use rand::RngCore;
use serde::{Deserialize, Serialize};

pub use self::landmarks::{LANDMARK_CAMERA_DISTANCE, LANDMARK_FOCAL, LANDMARK_IMAGE};
pub use self::view::{PoseGradient, PoseJacobian, PosedView};
use crate::body::kinematics::Kinematics;
use crate::camera::{Camera, DEFAULT_RING_SIZE, default_ring};
use crate::error::{ModelError, Result};
pub use crate::noise::NoiseConfig;
use crate::scan::{Mask, VoxelGrid, render_silhouettes};
use crate::skeleton::{L_HAND, R_HAND};
use crate::skinning::vertex_normals;
use crate::template::Template;

/// Noise scales σ of the sparse residual groups: the typical error that counts as one unit.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Scales {
    /// Marker and hand-tip / headset / wrist positions, metres (1 cm).
    pub position: f64,
    /// 2D keypoints, pixels (4 px at 640×480).
    pub pixel: f64,
    /// HMD rotation matrices, Frobenius norm (0.05 ≈ 2° of rotation).
    pub rotation: f64,
}

impl Default for Scales {
    fn default() -> Self {
        Self {
            position: 0.01,
            pixel: 4.0,
            rotation: 0.05,
        }
    }
}

/// The observation modalities of SPEC §4.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Modality {
    Markers,
    Keypoints2d,
    Hmd,
    Scan,
    /// K binary camera masks (papers/001 §3.2): the foreground images of background subtraction.
    Silhouettes,
    /// Dense face landmarks in one perspective camera (papers/002 §3.3).
    Landmarks2d,
    /// A modality defined outside lfit: an [`ObservationModel`] in [`Sensor::Custom`]. Never
    /// parsed from a name (it has no default setup).
    Custom,
}

impl Modality {
    pub const ALL: [Modality; 6] = [
        Modality::Markers,
        Modality::Keypoints2d,
        Modality::Hmd,
        Modality::Scan,
        Modality::Silhouettes,
        Modality::Landmarks2d,
    ];

    pub fn name(self) -> &'static str {
        match self {
            Modality::Markers => "markers",
            Modality::Keypoints2d => "keypoints2d",
            Modality::Hmd => "hmd",
            Modality::Scan => "scan",
            Modality::Silhouettes => "silhouettes",
            Modality::Landmarks2d => "landmarks2d",
            Modality::Custom => "custom",
        }
    }
}

impl fmt::Display for Modality {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

impl FromStr for Modality {
    type Err = ModelError;
    fn from_str(s: &str) -> Result<Self> {
        Modality::ALL
            .into_iter()
            .find(|m| m.name() == s)
            .ok_or_else(|| ModelError::UnknownModality(s.to_string()))
    }
}

/// Hand visibility of the `hmd` modality (papers/002 §3.2).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum HandVisibility {
    /// Hands always visible.
    Full,
    /// Only hands in front of the headset are visible: a hand whose wrist has z ≥ 0 in the
    /// headset frame (the headset looks along its −z) is behind it and invisible.
    #[default]
    HalfSpace,
}

/// Fixed setup of the `hmd` modality.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct HmdSetup {
    /// Headset position relative to the head joint in the rest frame (eyes: 17 cm up, 9 cm forward).
    pub offset: [f64; 3],
    pub visibility: HandVisibility,
    /// Hand-tip vertices (left, right): the hand vertex furthest from the wrist.
    pub hand_tips: [u32; 2],
}

/// Fixed setup of the `scan` modality.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ScanSetup {
    /// Views whose silhouettes are rendered (papers/000 §3: aligned with the capture cameras).
    pub cameras: Vec<Camera>,
    /// Voxel size of the distance-transform grid, metres.
    pub voxel_size: f64,
    /// Template vertices whose closest-point vectors form the residual.
    pub residual_vertices: Vec<u32>,
}

/// Fixed setup of the `silhouettes` modality (papers/001 §3.2): the calibrated cameras whose
/// foreground masks are observed.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SilhouetteSetup {
    pub cameras: Vec<Camera>,
}

/// Fixed setup of the `landmarks2d` modality (papers/002 §3.3): model vertices (a face model's
/// `landmark_vertices`) seen by one calibrated perspective camera. A landmark is seen when it is in
/// front of the camera, inside the image and its vertex faces the camera: its rest normal
/// (`normals`, one per vertex), turned by the skinning rotations, points to the camera centre.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct LandmarkSetup {
    pub camera: Camera,
    pub vertices: Vec<u32>,
    pub normals: Vec<[f64; 3]>,
}

/// Fixed setup of the `markers` modality: named skin markers on template vertices.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct MarkerSetup {
    pub names: Vec<String>,
    pub vertices: Vec<u32>,
    /// Each marker's offset from its vertex in the rest pose (metres, the model's rest frame),
    /// carried by the vertex's skinning: the marker is the skinned point `Σ_j w_j A_j (x_v + d)`.
    /// Empty (the default, and what every synthesised dataset has): the markers sit on their
    /// vertices. Solved per subject by `lfit fit --marker-placement solve`
    /// ([`crate::energy::marker_offsets`]), as MoSh solves a marker's place on the body.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub offsets: Vec<[f64; 3]>,
}

impl MarkerSetup {
    /// Marker `k`'s rest offset from its vertex (zero without offsets).
    #[inline]
    pub fn offset(&self, k: usize) -> DVec3 {
        self.offsets
            .get(k)
            .map_or(DVec3::ZERO, |&d| DVec3::from_array(d))
    }

    /// This marker set with its markers at `offsets` from their vertices (rest frame, metres;
    /// one per marker, checked by the sensor's validation).
    pub fn placed(&self, offsets: Vec<[f64; 3]>) -> Self {
        Self {
            offsets,
            ..self.clone()
        }
    }
}

/// Fixed setup of the `keypoints2d` modality: calibrated cameras that see a keypoint per joint,
/// the joint's centre or a point it carries.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct KeypointSetup {
    pub cameras: Vec<Camera>,
    /// Each keypoint's offset from its joint's centre (metres, the rest frame), carried by the
    /// segment that ends at the joint: keypoint `j` is `x_j + W_p d_j` (`W_p` the world rotation
    /// of `j`'s parent; of the root itself for the root) [`KeypointSetup::carrier`]. Empty (the
    /// default, and what every synthesised and imported dataset has): the keypoints are the
    /// joint centres. A detector's keypoint is not a skeleton's joint centre (a COCO hip is a
    /// point on the body's outline that annotators clicked, not the femoral head), so a
    /// subject's keypoints sit off them by a fixed amount; solved per sequence by `lfit fit
    /// --marker-placement solve` ([`crate::energy::keypoint_offsets`]).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub offsets: Vec<[f64; 3]>,
}

impl KeypointSetup {
    /// Cameras that see the joint centres (no offsets).
    pub fn new(cameras: Vec<Camera>) -> Self {
        Self {
            cameras,
            offsets: Vec::new(),
        }
    }

    /// Keypoint `j`'s offset from its joint's centre (zero without offsets).
    #[inline]
    pub fn offset(&self, j: usize) -> DVec3 {
        self.offsets
            .get(j)
            .map_or(DVec3::ZERO, |&d| DVec3::from_array(d))
    }

    /// The joint whose frame carries keypoint `j`'s offset: `j`'s parent, the root itself.
    /// Not `j`: a joint's centre does not move with its own rotation, so 2D keypoints at the
    /// centres leave a limb's twist to the prior; an offset that turned with it would make the
    /// twist follow the offset (one sequence's solve turned every twist with its offsets: V2V
    /// 30.2 → 33.0 mm noise-free, `docs/results/captured-motion.md`, round 18).
    #[inline]
    pub fn carrier(template: &Template, j: usize) -> usize {
        template.rig.joints[j].parent.unwrap_or(j)
    }

    /// Keypoint `j` of a posed model: its joint's centre, moved by its carrier's rotation of its
    /// offset when it has one.
    #[inline]
    pub fn keypoint(&self, posed: &PosedView<'_>, j: usize) -> DVec3 {
        match self.offsets.get(j) {
            Some(&d) => {
                let carrier = Self::carrier(posed.template(), j);
                posed.joint(j) + posed.joint_rotation(carrier) * DVec3::from_array(d)
            }
            None => posed.joint(j),
        }
    }

    /// These cameras with the keypoints at `offsets` from their joints (rest frame, metres; one
    /// per joint, checked by the sensor's validation).
    pub fn placed(&self, offsets: Vec<[f64; 3]>) -> Self {
        Self {
            offsets,
            ..self.clone()
        }
    }
}

/// One robust group of a prediction: `len` entries from `start` whose residual is judged as one
/// vector (a marker, a keypoint, a rotation), with the noise scale `sigma` that counts as one
/// unit. Visibility is per group: the group is seen when its first entry is.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ResidualGroup {
    pub start: usize,
    pub len: usize,
    pub sigma: f64,
}

/// `count` consecutive groups of `len` entries with noise scale `sigma`.
pub fn uniform_groups(count: usize, len: usize, sigma: f64) -> Vec<ResidualGroup> {
    (0..count)
        .map(|k| ResidualGroup {
            start: k * len,
            len,
            sigma,
        })
        .collect()
}

/// An observation model (SPEC §4): what one sensor sees of a posed model, as a fixed-length
/// vector with per-entry visibility. It is the one place where parameters → observation is
/// computed: synthesis corrupts its prediction, the energy compares it with data, its Jacobian
/// feeds Gauss-Newton/LM and its reverse-mode derivative the energy's gradient (which L-BFGS and
/// the neural fitter see).
///
/// `markers`, `keypoints2d` and `hmd` are implementations ([`MarkerSetup`], [`KeypointSetup`],
/// [`HmdSetup`]); a sensor defined in another crate implements it too and travels as
/// [`Sensor::Custom`], with no change to lfit (see `examples/imu_sensor.rs`). `silhouettes`
/// ([`SilhouetteSetup`]) is one too: its prediction is the mask pixels, its data term papers/001's
/// overlap fitness ([`Self::data_term`]) and it has no gradient ([`Self::no_gradient`]). So is
/// `scan` ([`ScanSetup`]: the point cloud, jitter and holes), whose energy (papers/000's ED, ES,
/// EJ) compares the surface with a distance transform built from the whole cloud rather than
/// entry by entry, and so keeps its own terms.
pub trait ObservationModel: fmt::Debug + Send + Sync {
    /// Short name, used in reports and errors.
    fn name(&self) -> &str;

    /// Checks the setup against a model (indices in range, joints it needs, cameras).
    fn validate(&self, template: &Template) -> Result<()>;

    /// Length of the prediction (and of the residual R(θ)).
    fn dim(&self, template: &Template) -> usize;

    /// The robust groups that cover the prediction, with their noise scales.
    fn groups(&self, template: &Template, scales: &Scales) -> Vec<ResidualGroup>;

    /// The prediction and whether the sensor sees each entry (`dim` entries each, overwritten).
    fn predict(&self, posed: &PosedView<'_>, values: &mut [f64], visible: &mut [bool]);

    /// The Jacobian of the prediction over the whole parameter vector: `dim × jac.dim()`,
    /// row-major, written into `out`.
    fn jacobian(&self, posed: &PosedView<'_>, jac: &mut PoseJacobian<'_, '_>, out: &mut [f64]);

    /// The Jacobian of the prediction in factored form, where every row is `aᵀ ∂X/∂θ` for a
    /// 3-vector `a` and the Jacobian `∂X/∂θ` of one posed point (keypoints2d: a joint centre
    /// seen through a camera's projection). Fills `points` (each point's `3 × jac.dim()`
    /// Jacobian, row-major, one after the other) and `rows` (per prediction entry: its point and
    /// `a`; cleared first) and returns true; the default returns false and [`Self::jacobian`]
    /// serves. Where it returns true, `aᵀ ∂X/∂θ` must be [`Self::jacobian`]'s row. The
    /// least-squares normal equations use it: a point seen in k rows costs one update of
    /// `∂Xᵀ (Σ a aᵀ) ∂X` instead of k row updates ([`crate::energy::LeastSquares::normal_equations`]).
    fn point_factors(
        &self,
        _posed: &PosedView<'_>,
        _jac: &mut PoseJacobian<'_, '_>,
        _points: &mut Vec<f64>,
        _rows: &mut Vec<(usize, [f64; 3])>,
    ) -> bool {
        false
    }

    /// The mesh vertices whose rest positions this model reads ([`PosedView::skinned_offset`],
    /// [`PoseJacobian::offset_vertex`], [`PoseGradient::offset_vertex`] and their `vertex`
    /// forms). An evaluation with derivatives reads each twice (prediction, then Jacobian or
    /// gradient): the energy shapes these once per evaluation instead. Only a saving: a vertex
    /// not listed is shaped where it is read; the default lists none.
    fn vertices_read(&self) -> Vec<u32> {
        Vec::new()
    }

    /// Adds `(∂prediction/∂θ)ᵀ dpred` to `grad`. The default goes through [`Self::jacobian`];
    /// the built-in models override it with cheaper reverse-mode sums.
    fn backprop(&self, posed: &PosedView<'_>, dpred: &[f64], grad: &mut PoseGradient<'_, '_>) {
        let d = grad.dim();
        let mut jac = vec![0.0; dpred.len() * d];
        grad.with_jacobian(|j| self.jacobian(posed, j, &mut jac));
        let mut g = vec![0.0; d];
        for (row, &dp) in jac.chunks_exact(d).zip(dpred) {
            if dp != 0.0 {
                for (gi, j) in g.iter_mut().zip(row) {
                    *gi += dp * j;
                }
            }
        }
        grad.parameters(&g);
    }

    /// Why this model's prediction has no derivatives, or `None` (the default) when
    /// [`Self::jacobian`] and [`Self::backprop`] serve. Without them the energy serves
    /// zeroth-order methods only; gradient methods and least squares refuse it with this reason.
    fn no_gradient(&self) -> Option<String> {
        None
    }

    /// A data term of the model's own in place of the robust residual groups (papers/001's
    /// silhouette overlap), from the prediction and the observation (`dim` entries each), or
    /// `None` (the default): the mean over seen groups of `ρ(‖r_g‖/σ_g)`.
    fn data_term(&self, predicted: &[f64], observed: &[f64]) -> Option<f64> {
        let _ = (predicted, observed);
        None
    }

    /// Noise, outliers and dropouts that synthesis applies to a clean prediction (entries the
    /// sensor does not see are reported as 0 and invisible).
    fn corrupt(
        &self,
        values: &mut [f64],
        visible: &mut [bool],
        noise: &NoiseConfig,
        rng: &mut dyn RngCore,
    );
}

/// The observation model of [`Sensor::default_for`]`(Modality::Custom, ..)`: a custom modality has
/// no default setup, so it refuses every template with that reason.
#[derive(Debug, Clone, Copy)]
struct NoDefaultSetup;

impl ObservationModel for NoDefaultSetup {
    fn name(&self) -> &str {
        "custom"
    }
    fn validate(&self, _: &Template) -> Result<()> {
        Err(ModelError::Config(
            "a custom modality has no default setup: build its Sensor::Custom in code (see examples/imu_sensor.rs)".into(),
        ))
    }
    fn dim(&self, _: &Template) -> usize {
        0
    }
    fn groups(&self, _: &Template, _: &Scales) -> Vec<ResidualGroup> {
        Vec::new()
    }
    fn predict(&self, _: &PosedView<'_>, _: &mut [f64], _: &mut [bool]) {}
    fn jacobian(&self, _: &PosedView<'_>, _: &mut PoseJacobian<'_, '_>, _: &mut [f64]) {}
    fn corrupt(&self, _: &mut [f64], _: &mut [bool], _: &NoiseConfig, _: &mut dyn RngCore) {}
}

/// A modality with its sensor setup.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(tag = "modality", rename_all = "lowercase")]
pub enum Sensor {
    Markers(MarkerSetup),
    Keypoints2d(KeypointSetup),
    Hmd(HmdSetup),
    Scan(ScanSetup),
    Silhouettes(SilhouetteSetup),
    Landmarks2d(LandmarkSetup),
    /// An observation model defined outside lfit. It lives in memory only: datasets of it cannot
    /// be written (serialising it is an error naming the reason).
    #[serde(skip)]
    Custom(Arc<dyn ObservationModel>),
}

impl PartialEq for Sensor {
    /// Built-in setups compare by value, custom ones by identity.
    fn eq(&self, other: &Self) -> bool {
        match (self, other) {
            (Sensor::Markers(a), Sensor::Markers(b)) => a == b,
            (Sensor::Keypoints2d(a), Sensor::Keypoints2d(b)) => a == b,
            (Sensor::Hmd(a), Sensor::Hmd(b)) => a == b,
            (Sensor::Scan(a), Sensor::Scan(b)) => a == b,
            (Sensor::Silhouettes(a), Sensor::Silhouettes(b)) => a == b,
            (Sensor::Landmarks2d(a), Sensor::Landmarks2d(b)) => a == b,
            (Sensor::Custom(a), Sensor::Custom(b)) => Arc::ptr_eq(a, b),
            _ => false,
        }
    }
}

/// Entries per HMD prediction: head, left wrist and right wrist as 3×4 `[R | t]` (12 each), then
/// the left and right hand tips (3 each) — [`hmd_layout`].
pub const HMD_DIM: usize = hmd_layout::tip(2);

/// A prediction of a sparse modality: a flat vector and, per entry, whether the sensor sees it.
#[derive(Debug, Clone, PartialEq)]
pub struct SparsePrediction {
    pub values: Vec<f64>,
    pub visible: Vec<bool>,
}

/// What the `scan` sensor sees: the posed surface (vertices, normals) and K silhouettes.
#[derive(Debug, Clone)]
pub struct ScanPrediction {
    pub vertices: Vec<Vec3>,
    pub normals: Vec<Vec3>,
    pub silhouettes: Vec<Mask>,
}

/// A scan observation: the (noisy, holed) point cloud, its squared distance transform and the
/// silhouettes of the target.
#[derive(Debug, Clone)]
pub struct ScanObservation {
    pub points: Vec<Vec3>,
    pub grid: VoxelGrid,
    pub silhouettes: Vec<Mask>,
}

impl Sensor {
    /// This sensor and its observations `values` of the body moved rigidly by `offset` (a world
    /// translation): 3D points (markers, the headset's and wrists' positions, hand tips) move
    /// with it, cameras move with it (`keypoints2d`: pixels unchanged); rotations and
    /// visibility do not change. With the root translation moved by `offset` too, every
    /// observation model predicts the moved values, so the energy of a frame is unchanged. `None`
    /// for the modalities without this form (scan, silhouettes, landmarks2d, custom sensors).
    pub fn translated(&self, values: &[f64], offset: DVec3) -> Option<(Sensor, Vec<f64>)> {
        let mut moved = values.to_vec();
        let shift = |v: &mut [f64]| {
            for p in v.chunks_exact_mut(3) {
                p[0] += offset.x;
                p[1] += offset.y;
                p[2] += offset.z;
            }
        };
        let sensor = match self {
            Sensor::Markers(_) => {
                shift(&mut moved);
                self.clone()
            }
            Sensor::Hmd(_) => {
                for d in 0..hmd_layout::DEVICES {
                    let p = hmd_layout::position(d);
                    shift(&mut moved[p..p + 3]);
                }
                shift(&mut moved[hmd_layout::tip(0)..HMD_DIM]);
                self.clone()
            }
            Sensor::Keypoints2d(setup) => {
                // camera_from_world: q = R p + t; for p' = p + offset, t' = t − R offset.
                let cameras = setup
                    .cameras
                    .iter()
                    .map(|c| {
                        let mut c = *c;
                        for (i, row) in c.rotation.iter().enumerate() {
                            c.translation[i] -= DVec3::from_array(*row).dot(offset);
                        }
                        c
                    })
                    .collect();
                Sensor::Keypoints2d(KeypointSetup::new(cameras))
            }
            _ => return None,
        };
        Some((sensor, moved))
    }

    /// The default setup of `modality` for `template` (a custom modality has none: its sensor
    /// refuses every template with that reason).
    pub fn default_for(modality: Modality, template: &Template) -> Self {
        match modality {
            Modality::Markers => Sensor::Markers(MarkerSetup {
                names: template
                    .rig
                    .markers
                    .iter()
                    .map(|m| m.name.clone())
                    .collect(),
                vertices: template.rig.markers.iter().map(|m| m.vertex).collect(),
                offsets: Vec::new(),
            }),
            Modality::Keypoints2d => {
                Sensor::Keypoints2d(KeypointSetup::new(default_ring(DEFAULT_RING_SIZE)))
            }
            Modality::Hmd => Sensor::Hmd(HmdSetup {
                offset: template.info.hmd_offset,
                visibility: HandVisibility::HalfSpace,
                hand_tips: hand_tips(template),
            }),
            Modality::Scan => Sensor::Scan(ScanSetup {
                cameras: default_ring(4),
                voxel_size: 0.02,
                residual_vertices: (0..template.num_vertices() as u32).step_by(8).collect(),
            }),
            // papers/001 used V calibrated views around the subject; the scan's four-camera ring.
            Modality::Silhouettes => Sensor::Silhouettes(SilhouetteSetup {
                cameras: default_ring(4),
            }),
            Modality::Landmarks2d => Sensor::Landmarks2d(LandmarkSetup::for_template(template)),
            Modality::Custom => Sensor::Custom(Arc::new(NoDefaultSetup)),
        }
    }

    pub fn modality(&self) -> Modality {
        match self {
            Sensor::Markers(_) => Modality::Markers,
            Sensor::Keypoints2d(_) => Modality::Keypoints2d,
            Sensor::Hmd(_) => Modality::Hmd,
            Sensor::Scan(_) => Modality::Scan,
            Sensor::Silhouettes(_) => Modality::Silhouettes,
            Sensor::Landmarks2d(_) => Modality::Landmarks2d,
            Sensor::Custom(_) => Modality::Custom,
        }
    }

    /// This sensor with its points at `offsets` (rest frame, metres): a markers sensor's
    /// markers from their vertices ([`MarkerSetup::placed`]), a keypoints2d sensor's keypoints
    /// from their joints' centres ([`KeypointSetup::placed`]). The count and values are checked
    /// by the sensor's validation; other sensors have no placement and give an error.
    pub fn placed(&self, offsets: Vec<[f64; 3]>) -> Result<Sensor> {
        match self {
            Sensor::Markers(m) => Ok(Sensor::Markers(m.placed(offsets))),
            Sensor::Keypoints2d(k) => Ok(Sensor::Keypoints2d(k.placed(offsets))),
            s => Err(ModelError::Config(format!(
                "a {} sensor has no point offsets (markers and keypoints2d have)",
                s.name()
            ))),
        }
    }

    /// The sensor's name: its modality's, or a custom model's own.
    pub fn name(&self) -> &str {
        match self {
            Sensor::Custom(m) => m.name(),
            _ => self.modality().name(),
        }
    }

    /// The sensor's observation model.
    pub fn observation_model(&self) -> &dyn ObservationModel {
        match self {
            Sensor::Markers(s) => s,
            Sensor::Keypoints2d(s) => s,
            Sensor::Hmd(s) => s,
            Sensor::Scan(s) => s,
            Sensor::Silhouettes(s) => s,
            Sensor::Landmarks2d(s) => s,
            Sensor::Custom(m) => m.as_ref(),
        }
    }

    /// Cameras of the setup (none for markers, hmd and custom sensors; one for landmarks2d).
    pub fn cameras(&self) -> &[Camera] {
        match self {
            Sensor::Keypoints2d(s) => &s.cameras,
            Sensor::Scan(s) => &s.cameras,
            Sensor::Silhouettes(s) => &s.cameras,
            Sensor::Landmarks2d(s) => std::slice::from_ref(&s.camera),
            _ => &[],
        }
    }

    /// Length of the residual vector R(θ).
    pub fn residual_dim(&self, template: &Template) -> usize {
        match self {
            Sensor::Scan(s) => 3 * s.residual_vertices.len(),
            // Masks are compared as images: no residual vector.
            Sensor::Silhouettes(_) => 0,
            _ => self.observation_model().dim(template),
        }
    }

    /// Checks the setup against a template (vertex indices in range, valid cameras).
    pub fn validate(&self, template: &Template) -> Result<()> {
        self.observation_model().validate(template)
    }

    /// The observation model's clean prediction at `pose` (for `silhouettes` the pixels of every
    /// camera at full resolution, for `scan` every posed vertex).
    pub fn predict_sparse(&self, template: &Template, pose: &[f64]) -> SparsePrediction {
        let model = self.observation_model();
        let kin = Kinematics::build(template, pose, false);
        let view = PosedView {
            template,
            kin: &kin,
            skin: None,
        };
        let n = model.dim(template);
        let mut values = vec![0.0; n];
        let mut visible = vec![false; n];
        model.predict(&view, &mut values, &mut visible);
        SparsePrediction { values, visible }
    }

    /// The model's silhouettes in every camera of the `silhouettes` modality at `pose` (full
    /// camera resolution). `None` for other modalities.
    pub fn predict_silhouettes(&self, template: &Template, pose: &[f64]) -> Option<Vec<Mask>> {
        let Sensor::Silhouettes(setup) = self else {
            return None;
        };
        Some(setup.masks(&self.predict_sparse(template, pose).values))
    }

    /// Predicted scan observation at `pose` (posed surface and silhouettes). `None` for other
    /// modalities.
    pub fn predict_scan(&self, template: &Template, pose: &[f64]) -> Option<ScanPrediction> {
        let Sensor::Scan(setup) = self else {
            return None;
        };
        let vertices = points_from_values(&self.predict_sparse(template, pose).values);
        let normals = vertex_normals(&vertices, &template.faces);
        let silhouettes = render_silhouettes(&setup.cameras, &vertices, &template.faces);
        Some(ScanPrediction {
            vertices,
            normals,
            silhouettes,
        })
    }

    /// Residual R(θ) of a sparse modality: `observed_visible ⊙ (predicted − observed)`.
    pub fn sparse_residual(
        predicted: &[f64],
        observed: &[f64],
        observed_visible: &[bool],
    ) -> Vec<f64> {
        predicted
            .iter()
            .zip(observed)
            .zip(observed_visible)
            .map(|((p, o), &v)| if v { p - o } else { 0.0 })
            .collect()
    }

    /// Residual R(θ) of `scan`: at each residual vertex, the vector from its closest point on the
    /// target to the vertex, `½ ∇S` for the squared distance transform S (plus the out-of-grid
    /// offset `v − ⌊v⌋`, papers/000 eq. 4).
    pub fn scan_residual(
        &self,
        predicted: &ScanPrediction,
        observed: &ScanObservation,
    ) -> Vec<f64> {
        let Sensor::Scan(setup) = self else {
            return Vec::new();
        };
        setup
            .residual_vertices
            .iter()
            .flat_map(|&v| {
                closest_point_offset(&observed.grid, predicted.vertices[v as usize].as_dvec3())
                    .to_array()
            })
            .collect()
    }
}

/// A vector of `3n` coordinates as `n` points (f32, as point clouds and meshes are stored).
pub fn points_from_values(values: &[f64]) -> Vec<Vec3> {
    values
        .chunks_exact(3)
        .map(|p| Vec3::new(p[0] as f32, p[1] as f32, p[2] as f32))
        .collect()
}

/// Vertex indices in range of `template`.
pub(crate) fn check_vertices(template: &Template, vs: &[u32], what: &str) -> Result<()> {
    let n = template.num_vertices() as u32;
    match vs.iter().find(|&&v| v >= n) {
        Some(v) => Err(ModelError::Shape {
            what: what.to_string(),
            expected: format!("vertex < {n}"),
            got: v.to_string(),
        }),
        None => Ok(()),
    }
}

/// One 3-vector of the `scan` residual: the offset from the target's closest point to `p`,
/// `½ ∇S(⌊p⌋) + (p − ⌊p⌋)` for the squared distance transform `S` of `grid`.
pub fn closest_point_offset(grid: &VoxelGrid, p: DVec3) -> DVec3 {
    let c = grid.clamp(p);
    grid.gradient(c) * 0.5 + (p - c)
}

/// World pose of the headset: the head joint's frame composed with the fixed offset, turned so
/// that the headset's −z looks where the face looks (+z in the rest pose).
pub fn headset_pose(setup: &HmdSetup, head_rotation: DMat3, head_position: DVec3) -> DAffine3 {
    let world_from_head = DAffine3 {
        matrix3: head_rotation,
        translation: head_position,
    };
    let head_from_device = DAffine3 {
        matrix3: DMat3::from_quat(DQuat::from_rotation_y(std::f64::consts::PI)),
        translation: DVec3::from_array(setup.offset),
    };
    world_from_head * head_from_device
}

/// Hand-tip vertices (left, right): the model file's `hand_tips` when it names them; otherwise,
/// of the vertices dominated by each hand joint (the model's joint mapped to the papers/000 hand)
/// or a joint below it, the one furthest from that joint (the middle-finger tip). Vertex 0 when
/// the model maps no hand.
pub fn hand_tips(template: &Template) -> [u32; 2] {
    if let Some(t) = template.info.hand_tips {
        return t;
    }
    let dominant = template.dominant_joint();
    let rig = &template.rig;
    [L_HAND, R_HAND].map(|h| {
        let Some(hand) = template.info.joint_map.get(h).copied().flatten() else {
            return 0;
        };
        // Joints in the subtree of `hand` (parents precede children).
        let mut inside = vec![false; rig.num_joints()];
        inside[hand] = true;
        for (j, joint) in rig.joints.iter().enumerate() {
            if let Some(p) = joint.parent
                && inside[p]
            {
                inside[j] = true;
            }
        }
        let wrist = rig.joints[hand].rest();
        let mut best = (f64::MIN, 0u32);
        for (v, p) in template.vertices.iter().enumerate() {
            if inside[dominant[v]] {
                let d = (p.as_dvec3() - wrist).length();
                if d > best.0 {
                    best = (d, v as u32);
                }
            }
        }
        best.1
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::body::default_template;
    use crate::pose::{POSE_DIM, rot_offset};
    use crate::skeleton::{L_SHOULDER, R_SHOULDER};

    #[test]
    fn modality_names_roundtrip() {
        for m in Modality::ALL {
            assert_eq!(m.name().parse::<Modality>().unwrap(), m);
        }
        assert!(matches!(
            "lidar".parse::<Modality>(),
            Err(ModelError::UnknownModality(_))
        ));
        // The message lists every modality a user can name.
        let msg = "lidar".parse::<Modality>().unwrap_err().to_string();
        for m in Modality::ALL {
            assert!(msg.contains(m.name()), "{msg}");
        }
    }

    /// The projection's adjoint (the keypoints' gradient) is the transpose of its derivative
    /// rows (their Jacobian), in front of the camera and below the depth floor.
    #[test]
    fn the_projection_adjoint_is_its_rows_transposed() {
        use builtin::{project_camera, project_camera_adjoint};
        let cam = Camera::look_at(DVec3::new(0.3, 1.2, 3.0), DVec3::Y, 610.0, 640, 480);
        for (q, gu, gv) in [
            (DVec3::new(0.2, -0.4, 2.5), 0.7, -1.3),
            (DVec3::new(-1.1, 0.3, 0.4), -2.0, 0.25),
            (DVec3::new(0.5, 0.5, -0.3), 1.5, 0.5),
        ] {
            let (_, dq) = project_camera(&cam, q);
            let want = dq[0] * gu + dq[1] * gv;
            let got = project_camera_adjoint(&cam, q, gu, gv);
            assert!(
                (got - want).length() <= 1e-12 * want.length(),
                "{q}: {got} vs {want}"
            );
        }
    }

    #[test]
    fn prediction_sizes_match_residual_dims() {
        let t = default_template();
        let pose = [0.0; POSE_DIM];
        for m in [Modality::Markers, Modality::Keypoints2d, Modality::Hmd] {
            let s = Sensor::default_for(m, &t);
            s.validate(&t).unwrap();
            let p = s.predict_sparse(&t, &pose);
            assert_eq!(p.values.len(), s.residual_dim(&t), "{m}");
            assert_eq!(p.visible.len(), p.values.len());
        }
    }

    #[test]
    fn keypoints_in_rest_pose_are_all_visible_and_hmd_hands_follow_the_half_space() {
        let t = default_template();
        let s = Sensor::default_for(Modality::Keypoints2d, &t);
        let p = s.predict_sparse(&t, &[0.0; POSE_DIM]);
        assert!(p.visible.iter().all(|&v| v));
        // Rest pose: hands hang beside the hips, below and beside the headset; they are in front
        // of the headset plane only if forward of it. Raise the arms forward: visible.
        let hmd = Sensor::default_for(Modality::Hmd, &t);
        let mut pose = [0.0; POSE_DIM];
        let rest = hmd.predict_sparse(&t, &pose);
        assert!(rest.visible[..12].iter().all(|&v| v));
        // Swing both arms backwards by 60° about the vertical: the wrists go behind the headset.
        pose[rot_offset(L_SHOULDER) + 1] = 60f64.to_radians();
        pose[rot_offset(R_SHOULDER) + 1] = -60f64.to_radians();
        let back = hmd.predict_sparse(&t, &pose);
        assert!(
            !back.visible[12] && !back.visible[24],
            "hands behind the headset are hidden"
        );
        // And forwards: visible.
        pose[rot_offset(L_SHOULDER) + 1] = -60f64.to_radians();
        pose[rot_offset(R_SHOULDER) + 1] = 60f64.to_radians();
        let front = hmd.predict_sparse(&t, &pose);
        assert!(front.visible[12] && front.visible[24] && front.visible[36] && front.visible[39]);
    }

    #[test]
    fn the_scan_model_predicts_exactly_the_renderers_mesh() {
        // Synthesis of scan datasets goes through the observation model; its prediction must be
        // bit for bit the mesh skinning.rs gives (so datasets are the bytes they always were).
        let t = default_template();
        let mut pose = [0.0; POSE_DIM];
        pose[rot_offset(L_SHOULDER) + 2] = 0.7;
        pose[1] = 0.05;
        let s = Sensor::default_for(Modality::Scan, &t);
        let p = s.predict_sparse(&t, &pose);
        let mesh = crate::skinning::pose_vertices(&t, &pose, crate::SkinningMethod::Linear);
        assert_eq!(p.values.len(), 3 * mesh.len());
        for (v, m) in mesh.iter().enumerate() {
            for a in 0..3 {
                assert_eq!(p.values[3 * v + a], f64::from(m[a]), "vertex {v}");
            }
        }
        assert!(p.visible.iter().all(|&b| b));
    }

    #[test]
    fn headset_looks_forward_at_rest() {
        let t = default_template();
        let Sensor::Hmd(setup) = Sensor::default_for(Modality::Hmd, &t) else {
            unreachable!()
        };
        let h = headset_pose(
            &setup,
            DMat3::IDENTITY,
            t.rig.joints[crate::skeleton::HEAD].rest(),
        );
        let forward = h.matrix3 * DVec3::NEG_Z;
        assert!((forward - DVec3::Z).length() < 1e-12);
        // A point 1 m in front of the face has negative z in the headset frame.
        let p = h.translation + DVec3::Z;
        assert!(h.inverse().transform_point3(p).z < 0.0);
    }
}
