//! Where a subject's markers sit on the body: each marker's rest-frame offset from its model
//! vertex, estimated from fitted frames of one subject (MoSh, Loper et al. 2014, solves each
//! marker's place on the body jointly with shape and poses; here one alternation of it: the
//! poses held, the offsets in closed form).
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

use glam::{DMat3, DVec3};

use super::{Energy, Target};
use crate::body::kinematics::Kinematics;
use crate::error::{ModelError, Result};
use crate::observe::Sensor;

impl Energy {
    /// This energy with its markers at `offsets` from their vertices (rest frame, metres; one
    /// per marker), the observations unchanged. Fails on a sensor other than markers and on
    /// offsets of the wrong count or not finite.
    pub fn with_marker_offsets(&self, offsets: &[DVec3]) -> Result<Self> {
        let (Sensor::Markers(setup), Target::Sparse { values, visible }) =
            (&self.sensor, &self.target)
        else {
            return Err(ModelError::Config(format!(
                "marker offsets need a markers energy, this one's sensor is {}",
                self.sensor.name()
            )));
        };
        let sensor = Sensor::Markers(setup.placed(offsets.iter().map(|d| d.to_array()).collect()));
        self.with_sensor(sensor, values.clone(), visible.clone())
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
    if !(prior_sigma.is_finite() && prior_sigma > 0.0) {
        return Err(ModelError::Config(format!(
            "the marker offsets' prior scale must be positive and finite (got {prior_sigma} m)"
        )));
    }
    if energies.len() != poses.len() {
        return Err(ModelError::Shape {
            what: "poses of the marker-offset frames".into(),
            expected: energies.len().to_string(),
            got: poses.len().to_string(),
        });
    }
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
