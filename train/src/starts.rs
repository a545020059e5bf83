//! Where θ0 of each training sample comes from: the starts the network will meet at inference.
//!
//! papers/002 trains from Φ(D) or the scenario's start. A fitter in use starts elsewhere too: from
//! a start farther from the target than the local box, from the rigidly aligned rest pose that
//! `lfit data import` computes for a capture, and, in a sequence, from its own result on the
//! previous frame, a wrong pose of a kind no synthetic start produces (the shipped fitters,
//! trained without it, stop reducing the error there: `docs/results/learned-vs-classical.md`).
//! [`StartMix`] draws each training sample's θ0 from these sources; the `previous` share is made
//! by running the network itself (inference mode, detached) over a few consecutive frames of a
//! motion and feeding its output forward, so that sequence mode sees in training what it meets
//! at inference.

use std::sync::Arc;

use burn::tensor::Device;
use glam::DVec3;
use lfit_model::observe::Sensor;
use lfit_model::{Block, Energy, Template};
use lfit_nn::{Constraints, Dropout, FeatureStats, NeuralNet, unroll};
use lfit_synth::{Observations, PoseSource, Scenario, SynthConfig, synthesize};
use rand::Rng;
use rand_distr::{Distribution, Normal};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::{Frames, Motions, Result, TrainError, known_shape_constraints};

/// Shares of θ0 sources in a training batch (weights, normalised by their sum).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct StartMix {
    /// Φ(D), the network's own initializer (papers/002 Alg. 1).
    pub phi: f64,
    /// The scenario's start pose: near the target, within the local box (papers/000 §4).
    pub scenario: f64,
    /// The ground truth perturbed: every rotation component by N(0, (r/√3)²), so that the
    /// rotation error has an RMS angle of r, with r drawn from `radii_deg`; the translation by
    /// N(0, (0.1 m · r/15°)²) per axis; β and ψ at the prior's mean, zero. Rotations below the
    /// root stay inside the model's joint limits.
    pub perturbed: f64,
    /// Radii r of `perturbed`, degrees (default 5°, 15° (the local box), 30°, 60°: up to and
    /// beyond the local box).
    pub radii_deg: Vec<f64>,
    /// The rest pose moved rigidly onto the target: the least-squares rotation and translation
    /// of the rest joints onto the posed joints (Horn), as `lfit data import` starts a capture.
    pub rest: f64,
    /// The network's own result on the previous frame of a motion, after `chain` frames fed
    /// forward (the first from Φ(D) or the truth of the frame before, by a fair coin).
    pub previous: f64,
    /// Frames the network runs before the trained frame in `previous`.
    pub chain: usize,
    /// The temporal anchor of the `previous` windows, degrees: every frame of a window that
    /// starts from the frame before (the truth of the frame before or the network's result on
    /// it) is fitted on the energy plus a Gaussian pull toward that start — its rotations by this
    /// σ widened by the window's motion so far, its root translation by
    /// [`lfit_fitters::ANCHOR_TRANSLATION_STD_MM`] — as `lfit fit --method neural --dofs
    /// anchored:DEG,30` fits a sequence's frames ([`lfit_fitters::anchored_energy`]; the shipped
    /// sequence networks were trained so, and fit with `anchored:DEG`'s sequence default of
    /// [`lfit_fitters::SEQUENCE_ANCHOR_TRANSLATION_STD_MM`] since, round 34). Absent (the
    /// default): the plain energy, as before.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub anchor_deg: Option<f64>,
    /// Frame rates of the `previous` windows, frames per second: each window is synthesised at
    /// one of them (drawn by its seed), so the network meets the larger frame-to-frame changes
    /// of slower captures. Absent or empty (the default): the synthesiser's 30.
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub fps: Vec<f64>,
}

impl Default for StartMix {
    /// Equal shares of Φ(D), the scenario's start and perturbed truth, and a smaller share of
    /// rigid rest starts and previous-frame results (ours: every source seen, the papers' two
    /// still half of the batch).
    fn default() -> Self {
        Self {
            phi: 0.25,
            scenario: 0.25,
            perturbed: 0.25,
            radii_deg: vec![5.0, 15.0, 30.0, 60.0],
            rest: 0.1,
            previous: 0.15,
            chain: 2,
            anchor_deg: None,
            fps: Vec::new(),
        }
    }
}

/// One sample's θ0 source, drawn from a [`StartMix`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum StartKind {
    Phi,
    Scenario,
    /// Perturbed truth at this radius (degrees).
    Perturbed(f64),
    Rest,
}

impl StartMix {
    pub fn validate(&self, source: PoseSource) -> Result<()> {
        let bad = |value: String, reason: &str| {
            Err(TrainError::Setting {
                name: "starts",
                value,
                reason: reason.into(),
            })
        };
        let weights = [
            self.phi,
            self.scenario,
            self.perturbed,
            self.rest,
            self.previous,
        ];
        if weights.iter().any(|w| !(w.is_finite() && *w >= 0.0)) {
            return bad(
                format!("{weights:?}"),
                "weights must be finite and non-negative",
            );
        }
        if weights.iter().sum::<f64>() <= 0.0 {
            return bad(
                format!("{weights:?}"),
                "at least one weight must be positive",
            );
        }
        if self.perturbed > 0.0
            && (self.radii_deg.is_empty()
                || self
                    .radii_deg
                    .iter()
                    .any(|r| !(r.is_finite() && *r > 0.0 && *r <= 180.0)))
        {
            return bad(
                format!("radii_deg {:?}", self.radii_deg),
                "perturbed starts need radii in (0, 180] degrees",
            );
        }
        if self.previous > 0.0 && self.chain == 0 {
            return bad(
                "chain 0".into(),
                "previous-frame starts need at least one frame before",
            );
        }
        if let Some(a) = self.anchor_deg {
            if !(a.is_finite() && a > 0.0) {
                return bad(
                    format!("anchor_deg {a}"),
                    "the temporal anchor's standard deviation must be finite and positive (degrees)",
                );
            }
            if self.previous <= 0.0 {
                return bad(
                    format!("anchor_deg {a}"),
                    "the temporal anchor applies to previous-frame starts: set \"previous\" above 0",
                );
            }
        }
        if self.fps.iter().any(|f| !(f.is_finite() && *f > 0.0)) {
            return bad(
                format!("fps {:?}", self.fps),
                "the windows' frame rates must be finite and positive",
            );
        }
        if self.previous > 0.0 && source == PoseSource::Face {
            return bad(
                "previous".into(),
                "the face protocol has no sequences: set \"previous\": 0",
            );
        }
        Ok(())
    }

    fn total(&self) -> f64 {
        self.phi + self.scenario + self.perturbed + self.rest + self.previous
    }

    /// Samples of a batch of `batch` that start from the previous frame's result (a fixed count,
    /// so the batch's layout does not vary; at least one left for the other sources).
    pub fn previous_count(&self, batch: usize) -> usize {
        let n = (batch as f64 * self.previous / self.total()).round() as usize;
        if self.previous > 0.0 && self.previous < self.total() {
            n.clamp(1, batch.saturating_sub(1))
        } else {
            n.min(batch)
        }
    }

    /// The source of one sample outside the previous-frame share.
    pub fn draw(&self, rng: &mut impl Rng) -> StartKind {
        let total = self.phi + self.scenario + self.perturbed + self.rest;
        if total <= 0.0 {
            return StartKind::Scenario;
        }
        let mut u = rng.random::<f64>() * total;
        for (w, kind) in [
            (self.phi, StartKind::Phi),
            (self.scenario, StartKind::Scenario),
            (self.perturbed, StartKind::Perturbed(0.0)),
        ] {
            if u < w {
                return match kind {
                    StartKind::Perturbed(_) => StartKind::Perturbed(
                        self.radii_deg[rng.random_range(0..self.radii_deg.len())],
                    ),
                    k => k,
                };
            }
            u -= w;
        }
        StartKind::Rest
    }
}

/// The θ0 of one sample of `kind` (`None`: Φ(D)).
pub fn start_of(
    kind: StartKind,
    template: &Template,
    scenario_start: &[f64],
    truth: &[f64],
    rng: &mut impl Rng,
) -> Option<Vec<f64>> {
    match kind {
        StartKind::Phi => None,
        StartKind::Scenario => Some(scenario_start.to_vec()),
        StartKind::Perturbed(r) => Some(perturbed(template, truth, r, rng)),
        StartKind::Rest => Some(rest_aligned(template, truth)),
    }
}

/// `truth` perturbed at radius `radius_deg` ([`StartMix::perturbed`]).
pub fn perturbed(
    template: &Template,
    truth: &[f64],
    radius_deg: f64,
    rng: &mut impl Rng,
) -> Vec<f64> {
    let layout = template.layout();
    let sigma_r = radius_deg.to_radians() / 3f64.sqrt();
    let sigma_t = 0.1 * radius_deg / 15.0;
    let (nr, nt) = (
        Normal::new(0.0, sigma_r).unwrap_or_else(|_| Normal::new(0.0, 0.0).expect("σ 0")),
        Normal::new(0.0, sigma_t).unwrap_or_else(|_| Normal::new(0.0, 0.0).expect("σ 0")),
    );
    let mut pose = vec![0.0; layout.dim()];
    for i in 0..3 {
        pose[i] = truth[i] + nt.sample(rng);
    }
    let limits = &template.info.limits_deg;
    for j in 0..layout.num_joints() {
        let o = layout.rotation_offset(j);
        for a in 0..3 {
            let mut v = truth[o + a] + nr.sample(rng);
            if j > 0
                && let Some(l) = limits.get(j)
            {
                v = v.clamp(l[a][0].to_radians(), l[a][1].to_radians());
            }
            pose[o + a] = v;
        }
    }
    // β and ψ at the prior's mean.
    for i in layout
        .range(Block::Shape)
        .chain(layout.range(Block::Expression))
    {
        pose[i] = 0.0;
    }
    pose
}

/// The rest pose moved rigidly onto the posed joints of `truth` ([`StartMix::rest`]); the rest
/// pose at the truth's translation where the joints are degenerate.
pub fn rest_aligned(template: &Template, truth: &[f64]) -> Vec<f64> {
    let dim = template.layout().dim();
    let posed = lfit_model::skinning::joint_transforms(template, truth).joints;
    let rest = template.joint_rest();
    match lfit_synth::capture::import::rigid_fit(&rest, &posed) {
        Some((q, s)) => lfit_synth::capture::import::rigid_start(template, q, s),
        None => {
            let mut p = vec![0.0; dim];
            let shift: DVec3 = posed[0] - rest[0];
            p[..3].copy_from_slice(&shift.to_array());
            p
        }
    }
}

/// Frames whose θ0 is the network's own result on the previous frame: `count` windows of
/// `chain + 1` consecutive frames of a motion (the sequence scenario of the library or the motion
/// files), the network (inference mode, `net`) run over the first `chain` frames of each, each
/// frame from the previous frame's result (the first from Φ(D) or the truth of the frame before,
/// by a fair coin). `augment` changes each window's frames as the run's other frames are
/// changed (random rigs, marker dropout: [`crate::augment_frames`]), with the window's seed.
/// Returns the last frame of every window: its energy, truth and θ0.
#[allow(clippy::too_many_arguments)]
pub fn previous_frames(
    net: &NeuralNet,
    stats: &FeatureStats,
    template: &Arc<Template>,
    sensor: &Sensor,
    base: &Energy,
    count: usize,
    chain: usize,
    seed: u64,
    noise: f64,
    (anchor_deg, fps): (Option<f64>, &[f64]),
    motions: &Motions,
    augment: &(dyn Fn(Frames, u64) -> Result<Frames> + Sync),
    device: &Device,
    rng: &mut impl Rng,
) -> Result<(Vec<Energy>, Vec<Vec<f64>>, Vec<Option<Vec<f64>>>)> {
    if count == 0 {
        return Ok((Vec::new(), Vec::new(), Vec::new()));
    }
    let noise = crate::noise_model(noise)?;
    // One window per sample, each from its own seed.
    let windows: Vec<(Vec<Energy>, Vec<Vec<f64>>, Vec<f64>)> = (0..count)
        .into_par_iter()
        .map(|i| {
            let window_seed = seed.wrapping_add((i as u64).wrapping_mul(0xA24B_AED4_963E_E407));
            let mut c = SynthConfig::new(
                sensor.modality(),
                Scenario::Sequence,
                chain + 1,
                window_seed,
            );
            motions.apply_to(&mut c);
            c.noise = noise.clone();
            if !fps.is_empty() {
                c.fps = fps[(window_seed % fps.len() as u64) as usize];
            }
            let d = synthesize(&c, template, sensor, &|_| {})?;
            let Observations::Sparse { values, visible } = &d.observations else {
                return Err(TrainError::Setting {
                    name: "modality",
                    value: sensor.modality().to_string(),
                    reason: "needs a sparse modality".into(),
                });
            };
            let energies = values
                .iter()
                .zip(visible)
                .map(|(v, s)| base.with_target(v.clone(), s.clone()))
                .collect::<Result<Vec<_>, _>>()?;
            let frames = augment(
                Frames {
                    dataset: d,
                    energies,
                },
                window_seed,
            )?;
            let before = frames.dataset.start_poses[0].clone();
            Ok((frames.energies, frames.dataset.gt_poses, before))
        })
        .collect::<Result<_>>()?;
    let mut starts: Vec<Option<Vec<f64>>> = windows
        .iter()
        .map(|(_, _, before)| rng.random_bool(0.5).then(|| before.clone()))
        .collect();
    // With a temporal anchor, each window's frames that start from the frame before are fitted
    // on the anchored energy, widened by the window's motion as the sequence driver does.
    let mut motion = vec![lfit_fitters::SequenceMotion::default(); windows.len()];
    let anchored =
        |k: usize, starts: &[Option<Vec<f64>>], motion: &[lfit_fitters::SequenceMotion]| {
            windows
                .iter()
                .zip(starts)
                .zip(motion)
                .map(|((w, start), m)| match (anchor_deg, start) {
                    (Some(deg), Some(centre)) => {
                        let free: Vec<usize> = (0..centre.len()).collect();
                        lfit_fitters::anchored_energy(
                            &w.0[k],
                            centre,
                            &free,
                            deg,
                            lfit_fitters::ANCHOR_TRANSLATION_STD_MM,
                            m.rms().as_deref(),
                        )
                        .map(Some)
                        .map_err(|e| TrainError::Setting {
                            name: "starts",
                            value: format!("anchor_deg {deg}"),
                            reason: e,
                        })
                    }
                    _ => Ok(None),
                })
                .collect::<Result<Vec<Option<Energy>>>>()
        };
    for k in 0..chain {
        let own = anchored(k, &starts, &motion)?;
        let energies: Vec<&Energy> = windows
            .iter()
            .zip(&own)
            .map(|(w, a)| a.as_ref().unwrap_or(&w.0[k]))
            .collect();
        let truths: Vec<Vec<f64>> = windows.iter().map(|w| w.1[k].clone()).collect();
        let constraints: Option<Constraints> = net
            .config
            .known_shape
            .then(|| known_shape_constraints(template, &truths));
        let out = unroll(
            net,
            stats,
            &energies,
            &starts,
            constraints.as_ref(),
            device,
            &mut Dropout::off(),
        )?;
        let last = out.host.last().cloned().unwrap_or_default();
        for ((m, start), result) in motion.iter_mut().zip(&starts).zip(&last) {
            if let Some(start) = start {
                m.update(start, result);
            }
        }
        starts = last.into_iter().map(Some).collect();
    }
    let own = anchored(chain, &starts, &motion)?;
    let mut energies = Vec::with_capacity(count);
    let mut truths = Vec::with_capacity(count);
    for ((mut e, mut t, _), a) in windows.into_iter().zip(own) {
        let last = e.swap_remove(chain);
        energies.push(a.unwrap_or(last));
        truths.push(t.swap_remove(chain));
    }
    Ok((energies, truths, starts))
}

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod tests {
    use rand::SeedableRng;
    use rand_chacha::ChaCha8Rng;

    use super::*;

    #[test]
    fn the_mix_draws_every_source_in_proportion() {
        let mix = StartMix {
            phi: 1.0,
            scenario: 2.0,
            perturbed: 1.0,
            rest: 0.0,
            previous: 0.0,
            ..StartMix::default()
        };
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        let mut counts = [0usize; 4];
        let mut radii = std::collections::BTreeSet::new();
        for _ in 0..40_000 {
            match mix.draw(&mut rng) {
                StartKind::Phi => counts[0] += 1,
                StartKind::Scenario => counts[1] += 1,
                StartKind::Perturbed(r) => {
                    counts[2] += 1;
                    radii.insert(r as i64);
                }
                StartKind::Rest => counts[3] += 1,
            }
        }
        let share = |i: usize| counts[i] as f64 / 40_000.0;
        assert!((share(0) - 0.25).abs() < 0.01, "{counts:?}");
        assert!((share(1) - 0.5).abs() < 0.01, "{counts:?}");
        assert!((share(2) - 0.25).abs() < 0.01, "{counts:?}");
        assert_eq!(counts[3], 0);
        assert_eq!(radii.into_iter().collect::<Vec<_>>(), vec![5, 15, 30, 60]);
        assert_eq!(StartMix::default().previous_count(64), 10);
        assert_eq!(
            StartMix {
                previous: 0.0,
                ..StartMix::default()
            }
            .previous_count(64),
            0
        );
        assert!(StartMix::default().validate(PoseSource::Motion).is_ok());
        for bad in [
            StartMix {
                phi: -1.0,
                ..StartMix::default()
            },
            StartMix {
                radii_deg: vec![],
                ..StartMix::default()
            },
            StartMix {
                chain: 0,
                ..StartMix::default()
            },
            StartMix {
                phi: 0.0,
                scenario: 0.0,
                perturbed: 0.0,
                rest: 0.0,
                previous: 0.0,
                ..StartMix::default()
            },
        ] {
            assert!(bad.validate(PoseSource::Motion).is_err(), "{bad:?}");
        }
        assert!(StartMix::default().validate(PoseSource::Face).is_err());
    }

    #[test]
    fn perturbed_starts_have_the_asked_radius_and_rest_starts_the_truth_root() {
        let (t, _) = lfit_model::body::morphable_default_template().unwrap();
        let layout = t.layout();
        let mut rng = ChaCha8Rng::seed_from_u64(5);
        let mut truth = vec![0.0; layout.dim()];
        truth[..3].copy_from_slice(&[0.2, 0.9, -0.1]);
        let r0 = layout.rotation_offset(0);
        truth[r0..r0 + 3].copy_from_slice(&[0.1, 2.0, -0.2]);
        for i in layout.range(Block::Shape) {
            truth[i] = 0.7;
        }
        // Root rotation error: RMS angle ≈ the radius (small-angle, unclamped root).
        let (mut sq, n) = (0.0, 2000);
        for _ in 0..n {
            let p = perturbed(&t, &truth, 10.0, &mut rng);
            let d: f64 = (0..3).map(|a| (p[r0 + a] - truth[r0 + a]).powi(2)).sum();
            sq += d;
            assert!(layout.range(Block::Shape).all(|i| p[i] == 0.0));
        }
        let rms_deg = (sq / n as f64).sqrt().to_degrees();
        assert!((rms_deg - 10.0).abs() < 0.5, "{rms_deg}");
        // The rigid rest start puts the root joint where the truth has it, facing its way.
        let rest = rest_aligned(&t, &truth);
        let posed = lfit_model::skinning::joint_transforms(&t, &truth).joints;
        let start = lfit_model::skinning::joint_transforms(&t, &rest).joints;
        assert!(
            (posed[0] - start[0]).length() < 0.05,
            "{:?} {:?}",
            posed[0],
            start[0]
        );
        let q = glam::DQuat::from_scaled_axis(DVec3::from_slice(&rest[r0..r0 + 3]));
        let want = glam::DQuat::from_scaled_axis(DVec3::from_slice(&truth[r0..r0 + 3]));
        assert!(q.angle_between(want).to_degrees() < 10.0);
        assert!(
            (layout.rotation_offset(1)..layout.rotation_offset(0) + 3 * layout.num_joints())
                .all(|i| rest[i] == 0.0)
        );
    }
}
