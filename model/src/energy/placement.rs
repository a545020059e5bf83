//! Where a subject's sensor points sit on the body, estimated from fitted frames of one subject
//! with the poses held: each marker's rest-frame offset from its model vertex (MoSh, Loper et
//! al. 2014, solves each marker's place on the body jointly with shape and poses; here one
//! alternation of it), and each 2D keypoint's offset from its joint's centre (a detector's
//! keypoint is not a skeleton's joint centre).
//!
//! A marker offset by `d` from vertex `v` is the skinned point `Σ_j w_j A_j (x_v + d)`, affine in
//! `d` with the linear part `L = Σ_j w_j W_j` ([`PosedView::skin_linear`]). With the poses held,
//! each marker's offset is the minimiser of
//! `Σ_f w_f ‖L_f d − e_f‖² / σ² + ‖d‖² / σ_d²` over the frames `f` that see it: `e_f` what the
//! marker's observation asks of `L_f d`, `σ` the data term's noise scale of a marker
//! ([`crate::observe::Scales::position`]), `w_f` the robust loss's IRLS weight `ρ'(s)/2s` at the
//! frame's residual with the offsets it was fitted with (1 for the quadratic loss), and `σ_d` the
//! prior's scale of an offset (a Gaussian prior at the model's marker set) — a 3 × 3 system per
//! marker.
//!
//! A keypoint offset by `d` from joint `j`'s centre `x_j` is `x_j + W d` (`W` the world rotation
//! of its carrier, [`crate::observe::KeypointSetup::carrier`]), seen through each
//! camera's projection `π_c`: `Σ_{f,c} w ‖π_c(x_j + W d) − y_{fc}‖² / σ² + ‖d‖² / σ_d²`, not
//! affine in `d`, so each keypoint's offset is a few Gauss-Newton steps on its own 3 × 3 system
//! (the IRLS weights retaken at every step, `σ` the pixel scale
//! [`crate::observe::Scales::pixel`]).

use glam::{DMat3, DVec3};

use super::{Energy, Target};
use crate::body::kinematics::Kinematics;
use crate::error::{ModelError, Result};
use crate::observe::builtin::project;
use crate::observe::{KeypointSetup, Sensor};

impl Energy {
    /// This energy with its sensor's points at `offsets` (rest frame, metres; [`Sensor::placed`]:
    /// markers from their vertices, one per marker, keypoints from their joints' centres, one
    /// per joint), the observations unchanged. Fails on another sensor and on offsets of the
    /// wrong count or not finite.
    pub fn with_offsets(&self, offsets: &[DVec3]) -> Result<Self> {
        let Target::Sparse { values, visible } = &self.target else {
            return Err(ModelError::Config(format!(
                "point offsets need a markers or keypoints2d energy, this one's sensor is {}",
                self.sensor.name()
            )));
        };
        let sensor = self
            .sensor
            .placed(offsets.iter().map(|d| d.to_array()).collect())?;
        self.with_sensor(sensor, values.clone(), visible.clone())
    }
}

/// The offsets of the frames' sensor points at the poses held, with a prior of scale
/// `prior_sigma` (metres): [`marker_offsets`] for markers energies, [`keypoint_offsets`] for
/// keypoints2d ones (by the first frame's sensor); an error for any other sensor.
pub fn point_offsets(
    energies: &[Energy],
    poses: &[Vec<f64>],
    prior_sigma: f64,
) -> Result<Vec<DVec3>> {
    match energies.first().map(Energy::sensor) {
        Some(Sensor::Keypoints2d(_)) => keypoint_offsets(energies, poses, prior_sigma),
        // Markers, no frames, or another sensor: marker_offsets says why it cannot.
        _ => marker_offsets(energies, poses, prior_sigma),
    }
}

/// Each marker's rest-frame offset from its vertex that best explains the frames `energies[f]`
/// at the poses `poses[f]` (all of one subject: one markers sensor, the same marker set), with a
/// Gaussian prior of scale `prior_sigma` (metres) at the model's marker set (module docs). The
/// frames' own offsets (their sensor's) are the point the robust weights are taken at. A marker
/// no frame sees keeps offset zero.
pub fn marker_offsets(
    energies: &[Energy],
    poses: &[Vec<f64>],
    prior_sigma: f64,
) -> Result<Vec<DVec3>> {
    check_frames(energies, poses, prior_sigma, "marker")?;
    let Some(first) = energies.first() else {
        return Ok(Vec::new());
    };
    let Sensor::Markers(setup) = first.sensor() else {
        return Err(ModelError::Config(format!(
            "marker offsets need markers energies, these are {}",
            first.sensor().name()
        )));
    };
    let count = setup.vertices.len();
    // Per marker: Σ w LᵀL / σ² and Σ w Lᵀe / σ².
    let mut systems = vec![(DMat3::ZERO, DVec3::ZERO); count];
    for (energy, pose) in energies.iter().zip(poses) {
        let (Sensor::Markers(s), Target::Sparse { values, visible }) =
            (energy.sensor(), energy.target())
        else {
            return Err(ModelError::Config(
                "marker offsets need every frame's energy to be a markers energy".into(),
            ));
        };
        if s.vertices != setup.vertices {
            return Err(ModelError::Config(
                "marker offsets need one marker set over the frames (one subject's)".into(),
            ));
        }
        energy.check_length(pose)?;
        let kin = Kinematics::build(energy.template(), pose, false);
        let view = energy.view(&kin);
        for (k, (&v, group)) in s.vertices.iter().zip(&energy.groups).enumerate() {
            if !visible[3 * k] {
                continue;
            }
            let (v, d0) = (v as usize, s.offset(k));
            let p = view.skinned_offset(v, d0);
            let y = DVec3::new(values[3 * k], values[3 * k + 1], values[3 * k + 2]);
            let l = view.skin_linear(v);
            let scaled = (p - y) / group.sigma;
            let w =
                0.5 * energy.config().robust.eval(scaled.length()).1 / (group.sigma * group.sigma);
            // p(d) − y = L d − e with e = y − p + L d0.
            let e = y - p + l * d0;
            systems[k].0 += l.transpose() * l * w;
            systems[k].1 += l.transpose() * e * w;
        }
    }
    let prior = DMat3::IDENTITY * (1.0 / (prior_sigma * prior_sigma));
    systems
        .into_iter()
        .enumerate()
        .map(|(k, (a, b))| {
            let d = (a + prior).inverse() * b;
            if d.is_finite() {
                Ok(d)
            } else {
                Err(ModelError::Config(format!(
                    "marker '{}': its offset's system is singular",
                    setup.names[k]
                )))
            }
        })
        .collect()
}

/// What [`marker_offsets`] and [`keypoint_offsets`] check first: a positive, finite prior scale
/// and a pose per frame (`what` names the points in the errors).
fn check_frames(
    energies: &[Energy],
    poses: &[Vec<f64>],
    prior_sigma: f64,
    what: &str,
) -> Result<()> {
    if !(prior_sigma.is_finite() && prior_sigma > 0.0) {
        return Err(ModelError::Config(format!(
            "the {what} offsets' prior scale must be positive and finite (got {prior_sigma} m)"
        )));
    }
    if energies.len() != poses.len() {
        return Err(ModelError::Shape {
            what: format!("poses of the {what}-offset frames"),
            expected: energies.len().to_string(),
            got: poses.len().to_string(),
        });
    }
    Ok(())
}

/// Gauss-Newton steps of [`keypoint_offsets`] per keypoint, at most.
pub const KEYPOINT_OFFSET_STEPS: usize = 20;

/// Each keypoint's rest-frame offset from its joint's centre that best explains the frames
/// `energies[f]` at the poses `poses[f]` (all of one subject: keypoints2d energies of one joint
/// set), with a Gaussian prior of scale `prior_sigma` (metres) at the joint centres (module
/// docs): from the frames' own offsets (the first frame's sensor's), up to
/// [`KEYPOINT_OFFSET_STEPS`] Gauss-Newton steps per keypoint, ending at a step under 1 nm. The
/// cameras may differ per frame. A keypoint no frame sees keeps its start.
pub fn keypoint_offsets(
    energies: &[Energy],
    poses: &[Vec<f64>],
    prior_sigma: f64,
) -> Result<Vec<DVec3>> {
    check_frames(energies, poses, prior_sigma, "keypoint")?;
    let Some(first) = energies.first() else {
        return Ok(Vec::new());
    };
    let Sensor::Keypoints2d(setup) = first.sensor() else {
        return Err(ModelError::Config(format!(
            "keypoint offsets need keypoints2d energies, these are {}",
            first.sensor().name()
        )));
    };
    let nj = first.template().rig.num_joints();
    // What a keypoint's residuals need of each frame, the poses held: its joint's centre, its
    // carrier's world rotation, and per camera that sees it the camera and its rotation's
    // transpose, the observation, its noise scale and the frame's robust loss.
    struct Seen<'a> {
        centre: DVec3,
        rotation: DMat3,
        camera: &'a crate::camera::Camera,
        camera_t: DMat3,
        y: [f64; 2],
        sigma: f64,
        robust: super::Robust,
    }
    let mut seen: Vec<Vec<Seen>> = (0..nj).map(|_| Vec::new()).collect();
    for (energy, pose) in energies.iter().zip(poses) {
        let (Sensor::Keypoints2d(s), Target::Sparse { values, visible }) =
            (energy.sensor(), energy.target())
        else {
            return Err(ModelError::Config(
                "keypoint offsets need every frame's energy to be a keypoints2d energy".into(),
            ));
        };
        if energy.template().rig.num_joints() != nj {
            return Err(ModelError::Config(
                "keypoint offsets need one skeleton over the frames (one subject's)".into(),
            ));
        }
        energy.check_length(pose)?;
        let kin = Kinematics::build(energy.template(), pose, false);
        let view = energy.view(&kin);
        for (c, camera) in s.cameras.iter().enumerate() {
            for (j, list) in seen.iter_mut().enumerate() {
                let g = c * nj + j;
                let i = 2 * g;
                if !visible[i] {
                    continue;
                }
                let rotation = view.joint_rotation(KeypointSetup::carrier(energy.template(), j));
                list.push(Seen {
                    centre: view.joint(j),
                    rotation,
                    camera,
                    camera_t: camera.rot().transpose(),
                    y: [values[i], values[i + 1]],
                    sigma: energy.groups[g].sigma,
                    robust: energy.config().robust,
                });
            }
        }
    }
    let prior = 1.0 / (prior_sigma * prior_sigma);
    seen.iter()
        .enumerate()
        .map(|(j, list)| {
            let mut d = setup.offset(j);
            for _ in 0..KEYPOINT_OFFSET_STEPS {
                // Σ w JᵀJ/σ² + I/σ_d² and −(Σ w Jᵀr/σ² + d/σ_d²), J = ∂π/∂X · W.
                let (mut a, mut b) = (DMat3::IDENTITY * prior, -d * prior);
                for o in list {
                    let (uv, dq) = project(o.camera, o.centre + o.rotation * d);
                    let r = DVec3::new(uv[0] - o.y[0], uv[1] - o.y[1], 0.0);
                    let scaled = (r / o.sigma).length();
                    let w = 0.5 * o.robust.eval(scaled).1 / (o.sigma * o.sigma);
                    for (row, res) in dq.iter().zip([r.x, r.y]) {
                        let jrow = o.rotation.transpose() * (o.camera_t * *row);
                        a += outer(jrow, jrow) * w;
                        b -= jrow * (res * w);
                    }
                }
                let step = a.inverse() * b;
                if !step.is_finite() {
                    return Err(ModelError::Config(format!(
                        "the keypoint of joint {j}: its offset's system is singular"
                    )));
                }
                d += step;
                if step.length() < 1e-9 {
                    break;
                }
            }
            Ok(d)
        })
        .collect()
}

/// `u vᵀ`.
fn outer(u: DVec3, v: DVec3) -> DMat3 {
    DMat3::from_cols(u * v.x, u * v.y, u * v.z)
}
