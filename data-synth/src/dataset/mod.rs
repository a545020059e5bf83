//! Datasets on disk: one `.npz` archive that numpy opens directly (`numpy.load(path)`), holding
//! ground-truth and start poses, observations, visibility, cameras and a JSON `meta` string
//! (template id, seed, generator settings, sensor setup). Same content → identical bytes.
//!
//! Imported datasets (`lfit data import`: real captures) have no ground truth: their `gt_*`
//! arrays have no rows and `meta` says `"ground_truth": false` (files with ground truth omit the
//! key, so their bytes are those of before).

pub mod config;
pub mod synth;

use std::path::Path;

use glam::Vec3;
use lfit_model::observe::{Modality, Sensor};
use lfit_model::pose::POSE_DIM;
use lfit_model::scan::{Mask, VoxelGrid};
use lfit_model::template::write_atomic;
use serde::{Deserialize, Serialize};

use crate::dataset::config::SynthConfig;
use crate::error::SynthError;
use crate::npz::{Array, npz_bytes, read_npz};

/// Version of the on-disk layout; loading another version is an error.
pub const FORMAT_VERSION: u32 = 1;

/// Metadata stored as JSON in the `meta` array.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Meta {
    /// Always `lfit-dataset`.
    pub format: String,
    pub version: u32,
    pub template_id: String,
    pub template_vertices: usize,
    /// Generator settings, seed included.
    pub config: SynthConfig,
    /// The motion behind each frame (`walk`, ..., or `uniform`).
    pub frame_motions: Vec<String>,
    /// Pose entries per frame (`3 + 3J`); absent in files of the default skeleton (57).
    #[serde(
        default = "default_pose_dim",
        skip_serializing_if = "is_default_pose_dim"
    )]
    pub pose_dim: usize,
    /// Shape coefficients per frame (`gt_shape`, `start_shape`); absent when 0.
    #[serde(default, skip_serializing_if = "is_zero")]
    pub shape_dim: usize,
    /// Expression coefficients per frame (`gt_expression`, `start_expression`); absent when 0.
    #[serde(default, skip_serializing_if = "is_zero")]
    pub expression_dim: usize,
}

fn default_pose_dim() -> usize {
    POSE_DIM
}

fn is_default_pose_dim(d: &usize) -> bool {
    *d == POSE_DIM
}

fn is_zero(d: &usize) -> bool {
    *d == 0
}

impl Meta {
    /// Length of a frame's full parameter vector: pose, shape, expression.
    pub fn param_dim(&self) -> usize {
        self.pose_dim + self.shape_dim + self.expression_dim
    }
}

/// Per-frame observations.
#[derive(Debug, Clone)]
pub enum Observations {
    /// Sparse modalities: one fixed-size vector per frame and its visibility.
    Sparse {
        values: Vec<Vec<f64>>,
        visible: Vec<Vec<bool>>,
    },
    /// `scan`: per frame, one point per template vertex (noisy) with visibility (holes), the
    /// squared distance transform of the visible points and K silhouettes.
    Scan {
        points: Vec<Vec<Vec3>>,
        visible: Vec<Vec<bool>>,
        grids: Vec<VoxelGrid>,
        silhouettes: Vec<Vec<Mask>>,
    },
    /// `silhouettes`: per frame, the foreground mask of every camera (on disk `silhouettes`,
    /// `[N, K, H, W]` uint8, as for `scan`).
    Silhouettes { masks: Vec<Vec<Mask>> },
}

/// A synthetic (or converted) dataset.
#[derive(Debug, Clone)]
pub struct Dataset {
    pub meta: Meta,
    pub sensor: Sensor,
    /// Per frame, the fitters' start: a full parameter vector in the model's layout (pose, then
    /// shape and expression, mean = 0).
    pub start_poses: Vec<Vec<f64>>,
    /// Per frame, the ground truth: pose, shape and expression (on disk `gt_poses`, `gt_shape`,
    /// `gt_expression`). Empty when the dataset has none (imported observations).
    pub gt_poses: Vec<Vec<f64>>,
    pub observations: Observations,
    /// A captured 3D reference of the model's joints (imported observations only: a studio's
    /// own reconstruction, `lfit data import --reference`), which `lfit fit` scores the fit
    /// against where no ground truth exists; `None` without one.
    pub reference: Option<JointReference>,
}

/// Per frame, a position (metres, the dataset's world) for each joint of the model's rig and
/// whether the reference holds it (on disk `reference_joints` `[N, J, 3]` and
/// `reference_visible` `[N, J]`; an entry not held is stored as 0).
#[derive(Debug, Clone, PartialEq)]
pub struct JointReference {
    pub points: Vec<Vec<[f64; 3]>>,
    pub visible: Vec<Vec<bool>>,
}

impl JointReference {
    /// Frame `frame`'s held joints: `(joint index, position)` in joint order.
    pub fn seen(&self, frame: usize) -> Vec<(usize, glam::DVec3)> {
        self.points[frame]
            .iter()
            .zip(&self.visible[frame])
            .enumerate()
            .filter(|(_, (_, v))| **v)
            .map(|(j, (p, _))| (j, glam::DVec3::from_array(*p)))
            .collect()
    }

    /// A fit's errors against frame `frame`'s held joints: `pose`'s joints (the model's joint
    /// centres, [`lfit_model::metrics::joint_positions`]) against the reference's, MPJPE and,
    /// with three or more held, PA-MPJPE (after a similarity alignment). `None` when the frame
    /// holds none.
    pub fn errors(
        &self,
        template: &lfit_model::template::Template,
        frame: usize,
        pose: &[f64],
    ) -> Option<ReferenceErrors> {
        self.errors_of_joints(frame, &lfit_model::metrics::joint_positions(template, pose))
    }

    /// [`JointReference::errors`] of a fit's posed `joints` (every joint of the model).
    pub fn errors_of_joints(
        &self,
        frame: usize,
        joints: &[glam::DVec3],
    ) -> Option<ReferenceErrors> {
        let held = self.seen(frame);
        if held.is_empty() {
            return None;
        }
        let fitted: Vec<glam::DVec3> = held.iter().map(|(j, _)| joints[*j]).collect();
        let reference: Vec<glam::DVec3> = held.iter().map(|(_, p)| *p).collect();
        Some(ReferenceErrors {
            mpjpe_mm: lfit_model::metrics::joint_error_mm(&fitted, &reference),
            pa_mpjpe_mm: (held.len() >= 3)
                .then(|| lfit_model::metrics::aligned_joint_error_mm(&fitted, &reference)),
            seen: held.len(),
        })
    }
}

impl JointReference {
    /// A fitted sequence's acceleration error against the reference, mm per frame²
    /// ([`lfit_model::metrics::accel_error_mm`]) over the joints the reference holds in every
    /// one of the `fitted` frames (each frame's index and posed joints); `None` where no joint
    /// is held throughout or no three consecutive frames were fitted.
    pub fn accel_error_mm(&self, fitted: &[(usize, Vec<glam::DVec3>)]) -> Option<f64> {
        let nj = self.visible.first().map_or(0, Vec::len);
        let common: Vec<usize> = (0..nj)
            .filter(|&j| fitted.iter().all(|(f, _)| self.visible[*f][j]))
            .collect();
        if common.is_empty() {
            return None;
        }
        let frames: Vec<(usize, Vec<glam::DVec3>, Vec<glam::DVec3>)> = fitted
            .iter()
            .map(|(f, joints)| {
                (
                    *f,
                    common.iter().map(|&j| joints[j]).collect(),
                    common
                        .iter()
                        .map(|&j| glam::DVec3::from_array(self.points[*f][j]))
                        .collect(),
                )
            })
            .collect();
        lfit_model::metrics::accel_error_mm(&frames)
    }
}

/// [`JointReference::errors`]: millimetres, over the `seen` joints.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ReferenceErrors {
    pub mpjpe_mm: f64,
    pub pa_mpjpe_mm: Option<f64>,
    pub seen: usize,
}

#[derive(Serialize, Deserialize)]
struct MetaJson {
    #[serde(flatten)]
    meta: Meta,
    sensor: Sensor,
    /// False for datasets without ground truth (absent, i.e. true, in every other file).
    #[serde(default = "yes", skip_serializing_if = "is_true")]
    ground_truth: bool,
}

fn yes() -> bool {
    true
}

fn is_true(b: &bool) -> bool {
    *b
}

/// Entries `range` of every row, flattened.
/// Per-frame camera masks as one `[N, K, H, W]` uint8 array.
fn mask_array(masks: &[Vec<Mask>], n: usize, k: usize) -> Array {
    let (w, h) = masks
        .first()
        .and_then(|s| s.first())
        .map_or((0, 0), |m| (m.width as usize, m.height as usize));
    let data: Vec<u8> = masks
        .iter()
        .flatten()
        .flat_map(|m| m.data.iter().copied())
        .collect();
    Array::u8(vec![n, k, h, w], data)
}

/// The `[N, K, H, W]` mask array `silhouettes` back into per-frame masks.
fn read_masks(s: &Array, n: usize, k: usize) -> Result<Vec<Vec<Mask>>, SynthError> {
    if s.shape.len() != 4 || s.shape[0] != n || s.shape[1] != k {
        return Err(SynthError::Dataset(format!(
            "array 'silhouettes' has shape {:?}, expected [{n}, {k}, H, W]",
            s.shape
        )));
    }
    let (h, w) = (s.shape[2], s.shape[3]);
    let data = s.to_u8("silhouettes")?;
    Ok((0..n)
        .map(|i| {
            (0..k)
                .map(|c| Mask {
                    width: w as u32,
                    height: h as u32,
                    data: data[(i * k + c) * w * h..(i * k + c + 1) * w * h].to_vec(),
                })
                .collect()
        })
        .collect())
}

fn flat_block(rows: &[Vec<f64>], range: std::ops::Range<usize>) -> Vec<f64> {
    rows.iter()
        .flat_map(|p| p[range.clone()].iter().copied())
        .collect()
}

impl Dataset {
    pub fn len(&self) -> usize {
        self.start_poses.len()
    }

    pub fn is_empty(&self) -> bool {
        self.start_poses.is_empty()
    }

    /// Whether the frames have ground-truth parameters (false for imported observations).
    pub fn has_ground_truth(&self) -> bool {
        !self.gt_poses.is_empty()
    }

    /// The ground-truth parameters of `frame`, `None` without ground truth.
    pub fn ground_truth(&self, frame: usize) -> Option<&[f64]> {
        self.gt_poses.get(frame).map(Vec::as_slice)
    }

    pub fn modality(&self) -> Modality {
        self.sensor.modality()
    }

    /// The arrays of the archive, in a fixed order.
    pub fn to_arrays(&self) -> Result<Vec<(&'static str, Array)>, SynthError> {
        if let Sensor::Custom(m) = &self.sensor {
            return Err(SynthError::Dataset(format!(
                "a dataset of the custom observation model '{}' cannot be written: its setup is code, not data",
                m.name()
            )));
        }
        let n = self.len();
        // Ground-truth arrays: one row per frame, or none at all.
        let ng = self.gt_poses.len();
        if ng != 0 && ng != n {
            return Err(SynthError::Dataset(format!(
                "{ng} ground-truth rows for {n} frames (expected {n}, or 0 without ground truth)"
            )));
        }
        let meta = serde_json::to_string(&MetaJson {
            meta: self.meta.clone(),
            sensor: self.sensor.clone(),
            ground_truth: self.has_ground_truth() || n == 0,
        })
        .map_err(|e| SynthError::Dataset(e.to_string()))?;
        let m = &self.meta;
        let (p, b, e) = (m.pose_dim, m.shape_dim, m.expression_dim);
        if let Some(i) = self
            .gt_poses
            .iter()
            .chain(&self.start_poses)
            .position(|r| r.len() != m.param_dim())
        {
            return Err(SynthError::Dataset(format!(
                "row {i} has the wrong number of parameters (expected {})",
                m.param_dim()
            )));
        }
        let mut arrays = vec![
            ("meta", Array::string(&meta)),
            (
                "gt_poses",
                Array::f64(vec![ng, p], &flat_block(&self.gt_poses, 0..p)),
            ),
            (
                "start_poses",
                Array::f64(vec![n, p], &flat_block(&self.start_poses, 0..p)),
            ),
        ];
        if b > 0 {
            arrays.push((
                "gt_shape",
                Array::f64(vec![ng, b], &flat_block(&self.gt_poses, p..p + b)),
            ));
            arrays.push((
                "start_shape",
                Array::f64(vec![n, b], &flat_block(&self.start_poses, p..p + b)),
            ));
        }
        if e > 0 {
            arrays.push((
                "gt_expression",
                Array::f64(vec![ng, e], &flat_block(&self.gt_poses, p + b..p + b + e)),
            ));
            arrays.push((
                "start_expression",
                Array::f64(vec![n, e], &flat_block(&self.start_poses, p + b..p + b + e)),
            ));
        }
        let cams = self.sensor.cameras();
        let k = cams.len();
        arrays.push((
            "camera_intrinsics",
            Array::f64(
                vec![k, 4],
                &cams
                    .iter()
                    .flat_map(|c| [c.fx, c.fy, c.cx, c.cy])
                    .collect::<Vec<_>>(),
            ),
        ));
        arrays.push((
            "camera_image_size",
            Array::u32(
                vec![k, 2],
                &cams
                    .iter()
                    .flat_map(|c| [c.width, c.height])
                    .collect::<Vec<_>>(),
            ),
        ));
        let extrinsics: Vec<f64> = cams
            .iter()
            .flat_map(|c| {
                (0..3).flat_map(move |r| {
                    [
                        c.rotation[r][0],
                        c.rotation[r][1],
                        c.rotation[r][2],
                        c.translation[r],
                    ]
                })
            })
            .collect();
        arrays.push(("camera_extrinsics", Array::f64(vec![k, 3, 4], &extrinsics)));
        match &self.observations {
            Observations::Sparse { values, visible } => {
                let d = values.first().map_or(0, Vec::len);
                arrays.push(("observations", Array::f64(vec![n, d], &values.concat())));
                arrays.push(("visibility", Array::bool(vec![n, d], &visible.concat())));
            }
            Observations::Scan {
                points,
                visible,
                grids,
                silhouettes,
            } => {
                let v = points.first().map_or(0, Vec::len);
                let flat: Vec<f32> = points.iter().flatten().flat_map(|p| p.to_array()).collect();
                arrays.push(("points", Array::f32(vec![n, v, 3], &flat)));
                arrays.push((
                    "point_visibility",
                    Array::bool(vec![n, v], &visible.concat()),
                ));
                let dims = grids.first().map_or([0; 3], |g| g.dims);
                let values: Vec<f32> = grids
                    .iter()
                    .flat_map(|g| g.values.iter().copied())
                    .collect();
                arrays.push((
                    "edt",
                    Array::f32(vec![n, dims[2], dims[1], dims[0]], &values),
                ));
                arrays.push((
                    "edt_origin",
                    Array::f64(
                        vec![n, 3],
                        &grids.iter().flat_map(|g| g.origin).collect::<Vec<_>>(),
                    ),
                ));
                arrays.push((
                    "edt_spacing",
                    Array::f64(
                        vec![n],
                        &grids.iter().map(|g| g.spacing).collect::<Vec<_>>(),
                    ),
                ));
                arrays.push(("silhouettes", mask_array(silhouettes, n, k)));
            }
            Observations::Silhouettes { masks } => {
                arrays.push(("silhouettes", mask_array(masks, n, k)));
            }
        }
        if let Some(r) = &self.reference {
            let j = r.points.first().map_or(0, Vec::len);
            if r.points.len() != n
                || r.visible.len() != n
                || r.points.iter().any(|p| p.len() != j)
                || r.visible.iter().any(|v| v.len() != j)
            {
                return Err(SynthError::Dataset(format!(
                    "the joint reference is not one row of {j} joints per frame for {n} frames"
                )));
            }
            let flat: Vec<f64> = r.points.iter().flatten().flatten().copied().collect();
            arrays.push(("reference_joints", Array::f64(vec![n, j, 3], &flat)));
            arrays.push((
                "reference_visible",
                Array::bool(vec![n, j], &r.visible.concat()),
            ));
        }
        Ok(arrays)
    }

    /// Writes the dataset atomically (temporary file, then rename).
    pub fn save(&self, path: &Path) -> Result<(), SynthError> {
        let bytes = npz_bytes(&self.to_arrays()?)?;
        write_atomic(path, &bytes)?;
        Ok(())
    }

    /// Loads and checks a dataset: version, shapes against the metadata, finite numbers.
    pub fn load(path: &Path) -> Result<Self, SynthError> {
        let bytes = std::fs::read(path).map_err(|source| SynthError::Read {
            path: path.to_path_buf(),
            source,
        })?;
        Self::from_npz(&bytes).map_err(|e| match e {
            SynthError::Dataset(why) => SynthError::Dataset(format!("{}: {why}", path.display())),
            other => other,
        })
    }

    pub fn from_npz(bytes: &[u8]) -> Result<Self, SynthError> {
        let arrays = read_npz(bytes)?;
        let get = |name: &str| {
            arrays
                .iter()
                .find(|(n, _)| n == name)
                .map(|(_, a)| a)
                .ok_or_else(|| SynthError::Dataset(format!("missing array '{name}'")))
        };
        let meta_text = get("meta")?.to_string("meta")?;
        let MetaJson {
            meta,
            sensor,
            ground_truth,
        } = serde_json::from_str(&meta_text)
            .map_err(|e| SynthError::Dataset(format!("meta: {e}")))?;
        if meta.format != "lfit-dataset" || meta.version != FORMAT_VERSION {
            return Err(SynthError::Dataset(format!(
                "format {} version {} is not lfit-dataset version {FORMAT_VERSION}",
                meta.format, meta.version
            )));
        }
        let n = meta.config.frames;
        let shape = |name: &str, a: &Array, expected: &[usize]| {
            if a.shape != expected {
                return Err(SynthError::Dataset(format!(
                    "array '{name}' has shape {:?}, expected {expected:?}",
                    a.shape
                )));
            }
            Ok(())
        };
        let block = |name: &str, n: usize, width: usize| -> Result<Vec<Vec<f64>>, SynthError> {
            if width == 0 {
                return Ok(vec![Vec::new(); n]);
            }
            let a = get(name)?;
            shape(name, a, &[n, width])?;
            let flat = a.to_f64(name)?;
            if let Some(i) = flat.iter().position(|x| !x.is_finite()) {
                return Err(SynthError::Dataset(format!(
                    "{name}[{}]: value {} is not finite ({})",
                    i / width,
                    i % width,
                    flat[i]
                )));
            }
            Ok(flat.chunks_exact(width).map(<[f64]>::to_vec).collect())
        };
        let rows = |pose: &str,
                    shape_key: &str,
                    expr_key: &str,
                    n: usize|
         -> Result<Vec<Vec<f64>>, SynthError> {
            let mut out = block(pose, n, meta.pose_dim)?;
            for (r, (b, e)) in
                out.iter_mut()
                    .zip(block(shape_key, n, meta.shape_dim)?.into_iter().zip(block(
                        expr_key,
                        n,
                        meta.expression_dim,
                    )?))
            {
                r.extend(b);
                r.extend(e);
            }
            Ok(out)
        };
        // Without ground truth the gt arrays have no rows (an absent `gt_poses` is accepted).
        let gt_poses = if ground_truth {
            rows("gt_poses", "gt_shape", "gt_expression", n)?
        } else if arrays.iter().any(|(name, _)| name == "gt_poses") {
            rows("gt_poses", "gt_shape", "gt_expression", 0)?
        } else {
            Vec::new()
        };
        let start_poses = rows("start_poses", "start_shape", "start_expression", n)?;
        let observations = match sensor.modality() {
            Modality::Scan => {
                let v = meta.template_vertices;
                let k = sensor.cameras().len();
                let p = get("points")?;
                shape("points", p, &[n, v, 3])?;
                let flat = p.to_f32("points")?;
                if flat.iter().any(|x| !x.is_finite()) {
                    return Err(SynthError::Dataset(
                        "array 'points' holds a non-finite number".into(),
                    ));
                }
                let points = flat
                    .chunks_exact(3 * v.max(1))
                    .map(|c| {
                        c.chunks_exact(3)
                            .map(|q| Vec3::new(q[0], q[1], q[2]))
                            .collect()
                    })
                    .collect();
                let vis = get("point_visibility")?;
                shape("point_visibility", vis, &[n, v])?;
                let visible = vis
                    .to_bool("point_visibility")?
                    .chunks_exact(v.max(1))
                    .map(<[bool]>::to_vec)
                    .collect();
                let edt = get("edt")?;
                if edt.shape.len() != 4 || edt.shape[0] != n {
                    return Err(SynthError::Dataset(format!(
                        "array 'edt' has shape {:?}, expected [{n}, Z, Y, X]",
                        edt.shape
                    )));
                }
                let dims = [edt.shape[3], edt.shape[2], edt.shape[1]];
                let values = edt.to_f32("edt")?;
                let origin = get("edt_origin")?;
                shape("edt_origin", origin, &[n, 3])?;
                let origin = origin.to_f64("edt_origin")?;
                let spacing = get("edt_spacing")?;
                shape("edt_spacing", spacing, &[n])?;
                let spacing = spacing.to_f64("edt_spacing")?;
                let per = dims.iter().product::<usize>();
                let grids = (0..n)
                    .map(|i| VoxelGrid {
                        origin: [origin[3 * i], origin[3 * i + 1], origin[3 * i + 2]],
                        spacing: spacing[i],
                        dims,
                        values: values[i * per..(i + 1) * per].to_vec(),
                    })
                    .collect();
                let silhouettes = read_masks(get("silhouettes")?, n, k)?;
                Observations::Scan {
                    points,
                    visible,
                    grids,
                    silhouettes,
                }
            }
            Modality::Silhouettes => Observations::Silhouettes {
                masks: read_masks(get("silhouettes")?, n, sensor.cameras().len())?,
            },
            _ => {
                let o = get("observations")?;
                if o.shape.len() != 2 || o.shape[0] != n {
                    return Err(SynthError::Dataset(format!(
                        "array 'observations' has shape {:?}, expected [{n}, D]",
                        o.shape
                    )));
                }
                let d = o.shape[1];
                let flat = o.to_f64("observations")?;
                if let Some(i) = flat.iter().position(|x| !x.is_finite()) {
                    return Err(SynthError::Dataset(format!(
                        "observations[{}][{}] is not finite",
                        i / d.max(1),
                        i % d.max(1)
                    )));
                }
                let vis = get("visibility")?;
                shape("visibility", vis, &[n, d])?;
                let values = flat.chunks_exact(d.max(1)).map(<[f64]>::to_vec).collect();
                let visible = vis
                    .to_bool("visibility")?
                    .chunks_exact(d.max(1))
                    .map(<[bool]>::to_vec)
                    .collect();
                Observations::Sparse { values, visible }
            }
        };
        if meta.frame_motions.len() != n {
            return Err(SynthError::Dataset(format!(
                "meta lists {} frame motions for {n} frames",
                meta.frame_motions.len()
            )));
        }
        let has = |name: &str| arrays.iter().any(|(a, _)| a == name);
        let reference = match (has("reference_joints"), has("reference_visible")) {
            (false, false) => None,
            (true, true) => {
                let p = get("reference_joints")?;
                if p.shape.len() != 3 || p.shape[0] != n || p.shape[2] != 3 {
                    return Err(SynthError::Dataset(format!(
                        "array 'reference_joints' has shape {:?}, expected [{n}, J, 3]",
                        p.shape
                    )));
                }
                let j = p.shape[1];
                let flat = p.to_f64("reference_joints")?;
                if let Some(i) = flat.iter().position(|x| !x.is_finite()) {
                    return Err(SynthError::Dataset(format!(
                        "reference_joints[{}][{}] is not finite",
                        i / (3 * j).max(1),
                        i % (3 * j).max(1) / 3
                    )));
                }
                let v = get("reference_visible")?;
                shape("reference_visible", v, &[n, j])?;
                let points = flat
                    .chunks_exact((3 * j).max(1))
                    .take(n)
                    .map(|row| row.chunks_exact(3).map(|q| [q[0], q[1], q[2]]).collect())
                    .collect();
                let visible = v
                    .to_bool("reference_visible")?
                    .chunks_exact(j.max(1))
                    .take(n)
                    .map(<[bool]>::to_vec)
                    .collect();
                Some(JointReference { points, visible })
            }
            _ => {
                return Err(SynthError::Dataset(
                    "a joint reference needs both 'reference_joints' and 'reference_visible'"
                        .into(),
                ));
            }
        };
        Ok(Self {
            meta,
            sensor,
            start_poses,
            gt_poses,
            observations,
            reference,
        })
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod tests {
    use super::*;
    use crate::dataset::synth::synthesize;
    use crate::{Scenario, SynthConfig};
    use lfit_model::default_template;

    /// A joint reference saves and loads with its dataset, bit for bit; a file with one of its
    /// two arrays is refused; a pose moved 10 cm scores 100 mm by MPJPE and 0 by PA-MPJPE.
    #[test]
    fn a_joint_reference_round_trips_and_scores_a_pose() {
        let t = default_template();
        let sensor = Sensor::default_for(Modality::Keypoints2d, &t);
        let c = SynthConfig::new(Modality::Keypoints2d, Scenario::Local, 3, 5);
        let mut data = synthesize(&c, &t, &sensor, &|_| {}).unwrap();
        let nj = t.rig.num_joints();
        let mut points = Vec::new();
        let mut visible = Vec::new();
        for f in 0..3 {
            let joints = lfit_model::metrics::joint_positions(&t, &data.gt_poses[f]);
            points.push(joints.iter().map(|p| p.to_array()).collect::<Vec<_>>());
            // Frame 1 holds two joints (no PA-MPJPE), the others every joint but the first.
            visible.push(
                (0..nj)
                    .map(|j| if f == 1 { j < 2 } else { j > 0 })
                    .collect(),
            );
        }
        data.reference = Some(JointReference { points, visible });
        let bytes = npz_bytes(&data.to_arrays().unwrap()).unwrap();
        let back = Dataset::from_npz(&bytes).unwrap();
        assert_eq!(back.reference, data.reference);
        let r = back.reference.as_ref().unwrap();
        let e = r.errors(&t, 0, &data.gt_poses[0]).unwrap();
        assert_eq!((e.seen, e.pa_mpjpe_mm.is_some()), (nj - 1, true));
        assert!(e.mpjpe_mm < 1e-9);
        let e = r.errors(&t, 1, &data.gt_poses[1]).unwrap();
        assert_eq!((e.seen, e.pa_mpjpe_mm), (2, None));
        // The root moved by (0.06, 0, −0.08) m.
        let mut moved = data.gt_poses[2].clone();
        let at = t
            .layout()
            .range(lfit_model::layout::Block::Translation)
            .start;
        moved[at] += 0.06;
        moved[at + 2] -= 0.08;
        let e = r.errors(&t, 2, &moved).unwrap();
        assert!((e.mpjpe_mm - 100.0).abs() < 1e-6, "{}", e.mpjpe_mm);
        assert!(e.pa_mpjpe_mm.unwrap() < 1e-6);
        // The acceleration error: 0 for the truth, over the joints held in every frame.
        let posed: Vec<(usize, Vec<glam::DVec3>)> = (0..3)
            .map(|f| {
                (
                    f,
                    lfit_model::metrics::joint_positions(&t, &data.gt_poses[f]),
                )
            })
            .collect();
        assert!(r.accel_error_mm(&posed[..]).is_some_and(|a| a < 1e-9));
        // Frame 1 holds joints 0 and 1, the others all but 0: joint 1 throughout; frame 1's fit
        // moved 3 mm along x: (0 − 2·3 + 0) mm on that joint.
        let mut jittered = posed.clone();
        jittered[1].1[1].x += 0.003;
        let a = r.accel_error_mm(&jittered).unwrap();
        assert!((a - 6.0).abs() < 1e-6, "{a}");
        assert!(r.accel_error_mm(&jittered[..2]).is_none());
        // One array without the other.
        let arrays: Vec<_> = data
            .to_arrays()
            .unwrap()
            .into_iter()
            .filter(|(n, _)| *n != "reference_visible")
            .collect();
        let e = Dataset::from_npz(&npz_bytes(&arrays).unwrap())
            .unwrap_err()
            .to_string();
        assert!(e.contains("needs both"), "{e}");
        // A reference of the wrong length is not written.
        let mut bad = data.clone();
        bad.reference.as_mut().unwrap().points.pop();
        assert!(bad.to_arrays().is_err());
    }
}
