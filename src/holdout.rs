//! `lfit fit --holdout`: observations kept out of a fit and scored against it afterwards.
//!
//! A capture has no ground truth, and the distance from a fit to the observations it fitted
//! rewards whichever method follows them most closely (Levenberg–Marquardt by construction,
//! noise and misplaced markers included). What a fit predicts where it saw nothing is a
//! measure of accuracy that needs no ground truth: markers left out of the fit (MoSh, Loper et
//! al. 2014, §6, reports this held-out marker error on real captures) or a camera left out of a
//! multi-view fit (the held-out view's reprojection error). The fit sees the dataset with those
//! observations unseen — and, without ground truth, starts from the rigid alignment of what is
//! left, as `lfit data import` aligns the rest pose, so nothing held out reaches the fit.

use anyhow::{Result, bail};
use lfit_model::observe::Sensor;
use lfit_model::template::Template;
use lfit_synth::Dataset;
use lfit_synth::capture::import::{
    ObservationErrors, keypoint_starts, marker_starts, observation_distances_of,
};
use lfit_synth::dataset::Observations;

/// What a fit leaves out: markers by name; 2D keypoints by camera (`camera:K`, counted from 0)
/// and by joint (in every camera).
#[derive(Debug, Clone, PartialEq)]
pub struct Holdout {
    /// What was asked for, one entry per item (`LTIB`, `camera:2`).
    pub items: Vec<String>,
    /// Per group of the sensor's observation vector (a marker's 3 values, a keypoint's 2 in one
    /// camera): the item (index into `items`) that holds it out, `None` where it is fitted.
    held: Vec<Option<usize>>,
    /// Values per group.
    group: usize,
}

impl Holdout {
    /// Parses `--holdout` (comma-separated items) against the dataset's sensor; every bad item
    /// is a one-line error naming it. Holding out everything leaves nothing to fit: refused.
    pub fn parse(spec: &str, dataset: &Dataset, template: &Template) -> Result<Self> {
        let items: Vec<String> = spec
            .split(',')
            .map(|s| s.trim().to_string())
            .filter(|s| !s.is_empty())
            .collect();
        if items.is_empty() {
            bail!("--holdout: no markers, cameras or keypoints named");
        }
        let (held, group) = match &dataset.sensor {
            Sensor::Markers(setup) => {
                let mut held = vec![None; setup.names.len()];
                for (i, item) in items.iter().enumerate() {
                    let Some(k) = setup.names.iter().position(|n| n == item) else {
                        bail!(
                            "--holdout: '{item}' is not a marker of the data (its markers: {})",
                            preview(&setup.names)
                        );
                    };
                    mark(&mut held, k, i, item)?;
                }
                (held, 3)
            }
            Sensor::Keypoints2d(setup) => {
                let nj = template.rig.num_joints();
                let cameras = setup.cameras.len();
                let mut held = vec![None; cameras * nj];
                for (i, item) in items.iter().enumerate() {
                    if let Some(c) = item.strip_prefix("camera:") {
                        let c: usize = c.parse().map_err(|_| {
                            anyhow::anyhow!("--holdout: '{item}': camera:K needs a camera index")
                        })?;
                        if c >= cameras {
                            bail!(
                                "--holdout: '{item}': the data has {cameras} camera(s), counted from 0"
                            );
                        }
                        if held[c * nj..(c + 1) * nj].iter().any(Option::is_some) {
                            bail!("--holdout: '{item}' overlaps an item named before");
                        }
                        held[c * nj..(c + 1) * nj].fill(Some(i));
                    } else {
                        let Some(j) = template.rig.joint_index(item) else {
                            bail!(
                                "--holdout: '{item}' is neither camera:K nor a joint of model '{}'",
                                template.id
                            );
                        };
                        for c in 0..cameras {
                            mark(&mut held, c * nj + j, i, item)?;
                        }
                    }
                }
                (held, 2)
            }
            other => bail!(
                "--holdout leaves markers or 2D keypoints out of a fit: the data's modality is {}",
                other.modality()
            ),
        };
        let Observations::Sparse { visible, .. } = &dataset.observations else {
            bail!("--holdout: the data's observations are not sparse");
        };
        let left = visible
            .iter()
            .any(|b| (0..held.len()).any(|g| held[g].is_none() && b[g * group]));
        if !left {
            bail!("--holdout leaves nothing seen to fit in any frame");
        }
        Ok(Self { items, held, group })
    }

    /// The dataset the fit sees: the held-out observations unseen (and zero), and without ground
    /// truth (a capture) every frame's start the rigid alignment of what is left
    /// ([`marker_starts`], [`keypoint_starts`] on every joint).
    pub fn hide(&self, dataset: &Dataset, template: &Template) -> Result<Dataset> {
        let Observations::Sparse { values, visible } = &dataset.observations else {
            bail!("--holdout: the data's observations are not sparse");
        };
        let mut values = values.clone();
        let mut visible = visible.clone();
        for (v, b) in values.iter_mut().zip(visible.iter_mut()) {
            for (g, _) in self.held.iter().enumerate().filter(|e| e.1.is_some()) {
                let r = g * self.group..(g + 1) * self.group;
                v[r.clone()].fill(0.0);
                b[r].fill(false);
            }
        }
        let start_poses = if dataset.has_ground_truth() {
            dataset.start_poses.clone()
        } else {
            match &dataset.sensor {
                Sensor::Markers(_) => marker_starts(template, &dataset.sensor, &values, &visible).0,
                Sensor::Keypoints2d(setup) => {
                    let joints: Vec<usize> = (0..template.rig.num_joints()).collect();
                    keypoint_starts(template, &setup.cameras, &joints, &values, &visible).0
                }
                _ => dataset.start_poses.clone(),
            }
        };
        // Field by field: `..dataset.clone()` would copy the observations again to drop them.
        Ok(Dataset {
            meta: dataset.meta.clone(),
            sensor: dataset.sensor.clone(),
            start_poses,
            gt_poses: dataset.gt_poses.clone(),
            observations: Observations::Sparse { values, visible },
            reference: dataset.reference.clone(),
        })
    }

    /// The held-out observations of `frame` of `dataset` (the one before [`Holdout::hide`]) that
    /// were seen, against `pose` as `sensor` predicts them (with a fit's solved placement, when it
    /// has one): their errors, and each one's distance with the item (index into `items`) that
    /// held it out; `None` when none of them was seen in that frame.
    pub fn score(
        &self,
        dataset: &Dataset,
        sensor: &Sensor,
        template: &Template,
        frame: usize,
        pose: &[f64],
    ) -> Option<(ObservationErrors, Vec<(usize, f64)>)> {
        let item = |g: usize| self.held.get(g).copied().flatten();
        let (unit, d) = observation_distances_of(dataset, sensor, template, frame, pose, &|g| {
            item(g).is_some()
        })?;
        let errors = ObservationErrors::of(unit, &d.iter().map(|e| e.1).collect::<Vec<_>>())?;
        let by_item = d
            .into_iter()
            .filter_map(|(g, x)| Some((item(g)?, x)))
            .collect();
        Some((errors, by_item))
    }
}

fn mark(held: &mut [Option<usize>], g: usize, i: usize, item: &str) -> Result<()> {
    if held[g].is_some() {
        bail!("--holdout: '{item}' is named twice");
    }
    held[g] = Some(i);
    Ok(())
}

fn preview(names: &[String]) -> String {
    let mut s = names
        .iter()
        .take(12)
        .cloned()
        .collect::<Vec<_>>()
        .join(", ");
    if names.len() > 12 {
        s.push_str(", …");
    }
    s
}
