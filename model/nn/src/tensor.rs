//! Batched, differentiable forward kinematics and linear blend skinning as Burn tensors, exactly
//! the formula of SPEC §3 that [`lfit_model::skinning`] evaluates on the CPU:
//!
//! ```text
//! pose vector (57 numbers): [t_x, t_y, t_z, r_0 (3), ..., r_17 (3)]
//! R_j = exp([r_j]x), W_root = R_root, W_j = W_parent(j) R_j
//! A_root(x) = R_root (x - c_root) + c_root + t
//! A_j(x)    = A_parent(j)(c_j) + W_j (x - c_j)
//! posed joint j:  A_j(c_j)
//! posed vertex v: sum_j w_vj A_j(v)
//! ```
//!
//! A morphable model (SPEC §3a) adds its blend shapes per batch row: rest vertices
//! `T + [S E] [β; ψ] + P (R(θ) − I)` and rest joints `c + (J_regressor [S E]) [β; ψ]`, with the
//! parameters laid out `[pose (3 + 3J) | β | ψ]`.
//!
//! Everything is plain tensor arithmetic, so on a `device.autodiff()` device the outputs are
//! differentiable with respect to the poses (and finite at the zero pose, see [`rodrigues`]).
//! Tensors are `f32` on whatever [`Device`] the caller picks; [`device_from_name`] maps the CLI
//! names `ndarray`, `flex` and `wgpu` to devices.

use std::sync::OnceLock;

use burn::tensor::{Device, DeviceKind, Int, Tensor, TensorData};
use glam::Vec3;

use lfit_model::error::{ModelError, Result};
use lfit_model::template::Template;

/// Added to `|r|^2` before the square root in [`rodrigues`], so that the angle, its gradient and
/// the Rodrigues coefficients stay finite at `r = 0` (the angle there is `1e-6` rad, far below
/// anything a pose cares about; the rotation is still exactly the identity).
const THETA_EPS2: f32 = 1e-12;

/// Names accepted by [`device_from_name`].
pub const DEVICE_NAMES: [&str; 3] = ["ndarray", "flex", "wgpu"];

/// The template as device tensors, ready for batched FK + LBS ([`TensorSkinning::forward`]).
#[derive(Debug, Clone)]
pub struct TensorSkinning {
    /// Rest-pose vertex positions, `[V, 3]`.
    pub rest_vertices: Tensor<2>,
    /// Dense skinning weights (rows sum to 1), `[V, J]`.
    pub weights: Tensor<2>,
    /// Joint rest positions `c_j`, `[J, 3]`.
    pub joint_rest: Tensor<2>,
    /// Parent of every joint (`None` for the root).
    pub parents: Vec<Option<usize>>,
    /// Rest vertices in homogeneous coordinates, `[V, 4]` (last column 1).
    rest_homogeneous: Tensor<2>,
    /// Per joint: `c_j` as `[1, 3]`.
    centers: Vec<Tensor<2>>,
    /// Per joint: `c_j` as `[1, 1, 3]`, to multiply `[B, 3, 3]` rotations with.
    centers_row: Vec<Tensor<3>>,
    /// Per joint: `c_j - c_parent(j)` as `[1, 1, 3]` (`c_j` for the root, unused).
    offsets_row: Vec<Tensor<3>>,
    /// Joints in an order where every parent comes before its children.
    order: Vec<usize>,
    num_vertices: usize,
    device: Device,
    /// B + E of a morphable model, with its directions: `[K, 3V]` and `[K, 3J]`.
    coefficients: usize,
    dirs: Option<Tensor<2>>,
    joint_dirs: Option<Tensor<2>>,
    /// Pose correctives `[9(J − 1), 3V]`.
    posedirs: Option<Tensor<2>>,
}

/// The outputs of [`TensorSkinning::forward`] for a batch of `B` poses.
#[derive(Debug, Clone)]
pub struct SkinnedBatch {
    /// Posed joint positions `A_j(c_j)`, `[B, J, 3]`.
    pub joints: Tensor<3>,
    /// Posed vertex positions `sum_j w_vj A_j(v)`, `[B, V, 3]`.
    pub vertices: Tensor<3>,
    /// World rotations `W_j` (row-major 3x3), `[B, J, 3, 3]`.
    pub world_rotations: Tensor<4>,
}

impl TensorSkinning {
    /// Uploads the template's rest vertices, dense weights and joint rest positions to `device`.
    ///
    /// The template's rig must be a tree (every joint reachable from a root without cycles);
    /// [`Template::new`] guarantees this.
    pub fn new(template: &Template, device: &Device) -> Self {
        let num_vertices = template.num_vertices();
        let num_joints = template.rig.joints.len();
        let parents: Vec<Option<usize>> = template.rig.joints.iter().map(|j| j.parent).collect();

        let rest: Vec<f32> = template
            .vertices
            .iter()
            .flat_map(|v| v.to_array())
            .collect();
        let rest_h: Vec<f32> = template
            .vertices
            .iter()
            .flat_map(|v| [v.x, v.y, v.z, 1.0])
            .collect();
        let rest_vertices =
            Tensor::<2>::from_data(TensorData::new(rest, [num_vertices, 3]), device);
        let rest_homogeneous =
            Tensor::<2>::from_data(TensorData::new(rest_h, [num_vertices, 4]), device);
        let weights = Tensor::<2>::from_data(
            TensorData::new(template.dense_weights(), [num_vertices, num_joints]),
            device,
        );

        let c: Vec<[f32; 3]> = template
            .joint_rest()
            .iter()
            .map(|c| c.as_vec3().to_array())
            .collect();
        let joint_rest = Tensor::<2>::from_data(
            TensorData::new(
                c.iter().flatten().copied().collect::<Vec<f32>>(),
                [num_joints, 3],
            ),
            device,
        );
        let row =
            |v: [f32; 3]| Tensor::<3>::from_data(TensorData::new(v.to_vec(), [1, 1, 3]), device);
        let centers = c
            .iter()
            .map(|&v| Tensor::<2>::from_data(TensorData::new(v.to_vec(), [1, 3]), device))
            .collect();
        let centers_row = c.iter().map(|&v| row(v)).collect();
        let offsets_row = (0..num_joints)
            .map(|j| {
                let base = parents[j].map_or([0.0; 3], |p| c[p]);
                row([c[j][0] - base[0], c[j][1] - base[1], c[j][2] - base[2]])
            })
            .collect();

        // Row-major (3V) × K on the CPU side; transposed here so that a batch of coefficients
        // `[B, K]` multiplies it directly.
        let morph = &template.morph;
        let k = morph.coefficients();
        let transpose = |m: &[f64], rows: usize, cols: usize| -> Tensor<2> {
            let mut t = vec![0f32; rows * cols];
            for r in 0..rows {
                for c in 0..cols {
                    t[c * rows + r] = m[r * cols + c] as f32;
                }
            }
            Tensor::<2>::from_data(TensorData::new(t, [cols, rows]), device)
        };
        let dirs = (k > 0).then(|| transpose(&morph.dirs, 3 * num_vertices, k));
        let joint_dirs = (k > 0 && !morph.joint_dirs.is_empty())
            .then(|| transpose(&morph.joint_dirs, 3 * num_joints, k));
        let posedirs = morph
            .posedirs
            .as_ref()
            .map(|pd| transpose(pd, 3 * num_vertices, 9 * (num_joints - 1)));
        let rest_vertices = if morph.rest.is_empty() {
            rest_vertices
        } else {
            let r: Vec<f32> = morph
                .rest
                .iter()
                .flat_map(|v| v.as_vec3().to_array())
                .collect();
            Tensor::<2>::from_data(TensorData::new(r, [num_vertices, 3]), device)
        };
        Self {
            rest_vertices,
            weights,
            joint_rest,
            order: topological_order(&parents),
            parents,
            rest_homogeneous,
            centers,
            centers_row,
            offsets_row,
            num_vertices,
            device: device.clone(),
            coefficients: k,
            dirs,
            joint_dirs,
            posedirs,
        }
    }

    /// The same model restricted to the vertices `ids` (in that order): posing it gives exactly
    /// those rows of the full model's vertices (the joints, which come from the full model's
    /// regressor through `joint_dirs`, are unchanged). For losses on a subset of a large mesh.
    ///
    /// # Panics
    ///
    /// If an index is not below [`Self::num_vertices`].
    pub fn vertex_subset(&self, ids: &[u32]) -> Self {
        assert!(
            ids.iter().all(|&v| (v as usize) < self.num_vertices),
            "vertex_subset: index out of range"
        );
        let n = ids.len();
        let idx = |v: Vec<i64>| {
            let len = v.len();
            Tensor::<1, Int>::from_data(TensorData::new(v, [len]), &self.device)
        };
        let rows = idx(ids.iter().map(|&v| i64::from(v)).collect());
        let cols3 = idx(ids
            .iter()
            .flat_map(|&v| (0..3).map(move |a| 3 * i64::from(v) + a))
            .collect());
        Self {
            rest_vertices: self.rest_vertices.clone().select(0, rows.clone()),
            weights: self.weights.clone().select(0, rows.clone()),
            rest_homogeneous: self.rest_homogeneous.clone().select(0, rows),
            num_vertices: n,
            dirs: self.dirs.clone().map(|d| d.select(1, cols3.clone())),
            posedirs: self.posedirs.clone().map(|d| d.select(1, cols3)),
            ..self.clone()
        }
    }

    /// Length of a parameter vector: `3 + 3J + B + E`.
    pub fn param_dim(&self) -> usize {
        self.pose_dim() + self.coefficients
    }

    /// Number of joints `J`.
    pub fn num_joints(&self) -> usize {
        self.parents.len()
    }

    /// Number of vertices `V`.
    pub fn num_vertices(&self) -> usize {
        self.num_vertices
    }

    /// Length of a pose vector, `3 + 3 J` (57 for the 18-joint skeleton).
    pub fn pose_dim(&self) -> usize {
        3 + 3 * self.num_joints()
    }

    /// The device the template tensors live on.
    pub fn device(&self) -> &Device {
        &self.device
    }

    /// Forward kinematics and linear blend skinning of a batch of parameter vectors
    /// `[B, 3 + 3J + B + E]` (`[B, 57]` on the default template).
    ///
    /// The joint chain is walked joint by joint (parents first) on `[B, ...]` tensors; the
    /// per-joint affine maps `[B, J, 12]` (rows of `[W_j | A_parent(j)(c_j) - W_j c_j]`) are then
    /// blended with one `[V, J] x [J, B*12]` matmul and applied to the rest vertices (per batch
    /// row for a morphable model).
    ///
    /// # Panics
    ///
    /// If `poses` is not `[B, param_dim]` or lives on another device than the template tensors.
    pub fn forward(&self, poses: Tensor<2>) -> SkinnedBatch {
        let [batch, dim] = poses.dims();
        let num_joints = self.num_joints();
        assert_eq!(
            dim,
            self.param_dim(),
            "TensorSkinning::forward: poses must be [batch, {}], got [{batch}, {dim}]",
            self.param_dim()
        );
        let k = self.coefficients;
        let coeffs = (k > 0).then(|| poses.clone().narrow(1, self.pose_dim(), k)); // [B, K]

        let translation = poses.clone().narrow(1, 0, 3); // [B, 3]
        let local = rodrigues(
            poses
                .narrow(1, 3, 3 * num_joints)
                .reshape([batch * num_joints, 3]),
        )
        .reshape([batch, num_joints, 3, 3]);

        // Rest joints: constant rows, or per batch row `c + JD [β; ψ]` ([B, J, 3]).
        let shaped_joints: Option<Tensor<3>> = match (&coeffs, &self.joint_dirs) {
            (Some(c), Some(jd)) => Some(
                self.joint_rest.clone().reshape([1, num_joints, 3])
                    + c.clone().matmul(jd.clone()).reshape([batch, num_joints, 3]),
            ),
            _ => None,
        };
        let center = |j: usize| -> Tensor<3> {
            match &shaped_joints {
                Some(c) => c.clone().narrow(1, j, 1), // [B, 1, 3]
                None => self.centers_row[j].clone(),
            }
        };
        let offset = |j: usize, p: usize| -> Tensor<3> {
            match &shaped_joints {
                Some(_) => center(j) - center(p),
                None => self.offsets_row[j].clone(),
            }
        };

        let mut world: Vec<Option<Tensor<3>>> = vec![None; num_joints]; // W_j, [B, 3, 3]
        let mut anchor: Vec<Option<Tensor<2>>> = vec![None; num_joints]; // A_j(c_j), [B, 3]
        for &j in &self.order {
            let r = local.clone().narrow(1, j, 1).reshape([batch, 3, 3]);
            let (w, a) = match self.parents[j] {
                // A_root(c_root) = c_root + t.
                None => (
                    r,
                    match &shaped_joints {
                        Some(_) => translation.clone() + center(j).reshape([batch, 3]),
                        None => translation.clone() + self.centers[j].clone(),
                    },
                ),
                // A_parent(c_j) = A_parent(c_parent) + W_parent (c_j - c_parent).
                Some(p) => {
                    let wp = world[p]
                        .clone()
                        .expect("parents come first in the topological order");
                    let ap = anchor[p]
                        .clone()
                        .expect("parents come first in the topological order");
                    (wp.clone().matmul(r), ap + mat_vec_row(wp, offset(j, p)))
                }
            };
            world[j] = Some(w);
            anchor[j] = Some(a);
        }
        // `order` visits every joint exactly once, so every slot is filled.
        let world: Vec<Tensor<3>> = world.into_iter().flatten().collect();
        let anchor: Vec<Tensor<2>> = anchor.into_iter().flatten().collect();
        assert_eq!(world.len(), num_joints, "the rig is not a tree");

        // Translation of A_j: A_parent(j)(c_j) - W_j c_j (the posed joint minus the rotated centre).
        let translations: Vec<Tensor<2>> = (0..num_joints)
            .map(|j| anchor[j].clone() - mat_vec_row(world[j].clone(), center(j)))
            .collect();

        let world_rotations: Tensor<4> = Tensor::stack(world, 1); // [B, J, 3, 3]
        let joints: Tensor<3> = Tensor::stack(anchor, 1); // [B, J, 3]
        let translations: Tensor<3> = Tensor::stack(translations, 1); // [B, J, 3]
        let affine = Tensor::cat(
            vec![
                world_rotations.clone(),
                translations.reshape([batch, num_joints, 3, 1]),
            ],
            3,
        )
        .reshape([batch, num_joints, 12]);

        // Blend: [V, J] x [J, B*12] -> [V, B*12] -> [B, V, 3, 4].
        let blended = self
            .weights
            .clone()
            .matmul(affine.swap_dims(0, 1).reshape([num_joints, batch * 12]))
            .reshape([self.num_vertices, batch, 3, 4])
            .swap_dims(0, 1);
        let v = self.num_vertices;
        // Rest vertices: the template's, or per batch row T + dirs [β; ψ] + P (R − I).
        let mut offsets: Option<Tensor<2>> = None; // [B, 3V]
        if let (Some(c), Some(d)) = (&coeffs, &self.dirs) {
            offsets = Some(c.clone().matmul(d.clone()));
        }
        if let Some(pd) = &self.posedirs {
            let eye = Tensor::<2>::eye(3, &self.device).reshape([1, 1, 3, 3]);
            let feature = (local.clone().narrow(1, 1, num_joints - 1) - eye)
                .reshape([batch, 9 * (num_joints - 1)]);
            let o = feature.matmul(pd.clone());
            offsets = Some(match offsets {
                Some(prev) => prev + o,
                None => o,
            });
        }
        let vertices = match offsets {
            None => {
                let rest = self.rest_homogeneous.clone().reshape([1, v, 1, 4]);
                (blended * rest).sum_dim(3).reshape([batch, v, 3])
            }
            Some(o) => {
                let rest = self.rest_vertices.clone().reshape([1, v, 3]) + o.reshape([batch, v, 3]); // [B, V, 3]
                let rot = blended.clone().narrow(3, 0, 3); // [B, V, 3, 3]
                let trans = blended.narrow(3, 3, 1).reshape([batch, v, 3]);
                (rot * rest.reshape([batch, v, 1, 3]))
                    .sum_dim(3)
                    .reshape([batch, v, 3])
                    + trans
            }
        };

        SkinnedBatch {
            joints,
            vertices,
            world_rotations,
        }
    }
}

/// `M x` for a batch of matrices `[B, 3, 3]` and one vector given as a row `[1, 1, 3]`: `[B, 3]`.
fn mat_vec_row(m: Tensor<3>, x_row: Tensor<3>) -> Tensor<2> {
    let [batch, _, _] = m.dims();
    (m * x_row).sum_dim(2).reshape([batch, 3])
}

/// Joint indices with every parent before its children (roots first, then breadth-first).
fn topological_order(parents: &[Option<usize>]) -> Vec<usize> {
    let mut order: Vec<usize> = (0..parents.len())
        .filter(|&j| parents[j].is_none())
        .collect();
    let mut next = 0;
    while next < order.len() {
        let p = order[next];
        order.extend((0..parents.len()).filter(|&j| parents[j] == Some(p)));
        next += 1;
    }
    order
}

/// Rotation matrices `exp([r]x)` of axis-angle vectors: `r` is `[n, 3]`, the result `[n, 3, 3]`
/// (row-major, acting on column vectors).
///
/// Uses the unnormalized Rodrigues form `I + a K + b K^2` with `K = [r]x`,
/// `theta = sqrt(|r|^2 + 1e-12)`, `a = sin(theta)/theta` and
/// `b = (1 - cos theta)/theta^2 = 2 sin^2(theta/2)/theta^2` (the half-angle form has no
/// cancellation for small angles), and `K^2 = r r^T - |r|^2 I`. Value and gradient are finite
/// everywhere, including `r = 0` where the result is exactly `I`.
pub fn rodrigues(r: Tensor<2>) -> Tensor<3> {
    let [n, _] = r.dims();
    let device = r.device();
    let sq = r.clone().square().sum_dim(1); // |r|^2, [n, 1]
    let theta = sq.clone().add_scalar(THETA_EPS2).sqrt();
    let a = theta.clone().sin() / theta.clone();
    let half = theta.mul_scalar(0.5);
    let sinc_half = half.clone().sin() / half;
    let b = sinc_half.square().mul_scalar(0.5);

    let x = r.clone().narrow(1, 0, 1);
    let y = r.clone().narrow(1, 1, 1);
    let z = r.clone().narrow(1, 2, 1);
    let zero = x.zeros_like();
    let k = Tensor::cat(
        vec![
            zero.clone(),
            z.clone().neg(),
            y.clone(),
            z,
            zero.clone(),
            x.clone().neg(),
            y.neg(),
            x,
            zero,
        ],
        1,
    )
    .reshape([n, 3, 3]);
    let eye = Tensor::<2>::eye(3, &device).reshape([1, 3, 3]);
    let k2 =
        r.clone().reshape([n, 3, 1]) * r.reshape([n, 1, 3]) - eye.clone() * sq.reshape([n, 1, 1]);
    eye + k * a.reshape([n, 1, 1]) + k2 * b.reshape([n, 1, 1])
}

/// Parameter vectors of one length as an `f32` tensor `[B, D]` on `device` (`[B, 57]` for
/// poses of the default template).
pub fn poses_to_tensor<P: AsRef<[f64]>>(poses: &[P], device: &Device) -> Tensor<2> {
    let dim = poses.first().map_or(0, |p| p.as_ref().len());
    let values: Vec<f32> = poses
        .iter()
        .flat_map(|p| p.as_ref().iter().map(|&v| v as f32))
        .collect();
    Tensor::from_data(TensorData::new(values, [poses.len(), dim]), device)
}

/// Reads a `[B, N, 3]` tensor (posed joints or vertices) back to the host as `B` lists of points.
pub fn tensor_to_vec3s(t: Tensor<3>) -> Result<Vec<Vec<Vec3>>> {
    let [batch, n, k] = t.dims();
    if k != 3 {
        return Err(ModelError::Shape {
            what: "points tensor".into(),
            expected: "[batch, n, 3]".into(),
            got: format!("[{batch}, {n}, {k}]"),
        });
    }
    let values = t
        .try_into_vec_as::<f32>()
        .map_err(|e| ModelError::Backend(format!("cannot read tensor: {e}")))?;
    if n == 0 {
        return Ok(vec![Vec::new(); batch]);
    }
    Ok(values
        .chunks_exact(3 * n)
        .map(|item| item.chunks_exact(3).map(Vec3::from_slice).collect())
        .collect())
}

/// Reads a `[B, D]` tensor back to the host as `B` rows of `f32`.
pub fn tensor_to_rows(t: Tensor<2>) -> Result<Vec<Vec<f32>>> {
    let [batch, d] = t.dims();
    let values = t
        .try_into_vec_as::<f32>()
        .map_err(|e| ModelError::Backend(format!("cannot read tensor: {e}")))?;
    if d == 0 {
        return Ok(vec![Vec::new(); batch]);
    }
    Ok(values.chunks_exact(d).map(<[f32]>::to_vec).collect())
}

/// The device of a backend name: `ndarray`, `flex` (both CPU) or `wgpu` (the default wgpu
/// adapter; checked with [`wgpu_status`] first so a machine without one gets an error, not a
/// panic later).
pub fn device_from_name(name: &str) -> Result<Device> {
    match name.trim().to_ascii_lowercase().as_str() {
        "ndarray" => Ok(ndarray_device()),
        "flex" => Ok(Device::flex()),
        "wgpu" => {
            wgpu_status().map_err(|reason| {
                ModelError::Backend(format!("the wgpu device is unavailable: {reason}"))
            })?;
            Ok(Device::wgpu(DeviceKind::DefaultDevice))
        }
        _ => Err(ModelError::Backend(format!(
            "unknown device '{name}' (expected one of: {})",
            DEVICE_NAMES.join(", ")
        ))),
    }
}

/// Burn's deprecated ndarray CPU device (still the reference CPU backend here).
#[allow(deprecated)]
pub fn ndarray_device() -> Device {
    Device::ndarray()
}

/// Whether a wgpu adapter can be initialised and runs a tiny kernel correctly; never panics.
pub fn wgpu_available() -> bool {
    wgpu_status().is_ok()
}

/// `Ok(description of the adapter)` if the default wgpu device works, otherwise `Err(why not)`.
///
/// Probed once per process, without panicking: initialises the runtime with
/// `Device::wgpu_options().init_with_setup()` (an "already registered" error counts as
/// available), then sums a 3-element tensor inside `catch_unwind` and checks the result. The
/// adapter can be steered with cubecl's `CUBECL_WGPU_DEFAULT_DEVICE` (e.g. `Cpu`,
/// `DiscreteGpu(0)`).
pub fn wgpu_status() -> std::result::Result<String, String> {
    static STATUS: OnceLock<std::result::Result<String, String>> = OnceLock::new();
    STATUS.get_or_init(probe_wgpu).clone()
}

fn probe_wgpu() -> std::result::Result<String, String> {
    use burn::tensor::wgpu::WgpuInitError;
    let adapter = match Device::wgpu_options().init_with_setup() {
        Ok((_, setup)) => {
            let info = setup.adapter.get_info();
            Some(format!(
                "{} ({:?}, {:?})",
                info.name, info.device_type, info.backend
            ))
        }
        // Registration fails when the runtime already exists (initialised earlier): usable.
        Err(WgpuInitError::Registration { .. }) => None,
        Err(e) => return Err(e.to_string()),
    };
    let device = Device::wgpu(DeviceKind::DefaultDevice);
    let run = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
        Tensor::<1>::from_floats([1.0, 2.0, 3.0], &device)
            .sum()
            .try_into_scalar::<f32>()
    }));
    match run {
        Ok(Ok(v)) if (v - 6.0).abs() < 1e-6 => Ok(adapter
            .or_else(|| device.identity().map(|id| id.name))
            .unwrap_or_else(|| "default wgpu adapter".into())),
        Ok(Ok(v)) => Err(format!("a test reduction returned {v} instead of 6")),
        Ok(Err(e)) => Err(format!("reading a test tensor failed: {e}")),
        Err(panic) => {
            let msg = panic
                .downcast_ref::<String>()
                .cloned()
                .or_else(|| panic.downcast_ref::<&str>().map(|s| (*s).to_string()))
                .unwrap_or_else(|| "unknown panic".into());
            Err(format!("a test kernel panicked: {msg}"))
        }
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod tests {
    use glam::{DMat3, DVec3};
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    use super::*;
    use lfit_model::pose::{POSE_DIM, Pose, rot_offset};
    use lfit_model::skinning::{SkinningMethod, joint_transforms, pose_vertices};

    #[test]
    fn a_vertex_subset_poses_to_the_same_rows_as_the_full_model() {
        let device = ndarray_device();
        let template = lfit_model::body::smpl_like(3, 300, 6, true);
        let full = TensorSkinning::new(&template, &device);
        let ids: Vec<u32> = vec![299, 0, 17, 150, 151, 42];
        let sub = full.vertex_subset(&ids);
        assert_eq!(sub.num_vertices(), ids.len());
        let mut rng = ChaCha8Rng::seed_from_u64(9);
        let params: Vec<Vec<f64>> = (0..4)
            .map(|_| {
                (0..full.param_dim())
                    .map(|_| rng.random_range(-1.0..1.0))
                    .collect()
            })
            .collect();
        let a = full.forward(poses_to_tensor(&params, &device));
        let b = sub.forward(poses_to_tensor(&params, &device));
        let (av, bv) = (
            tensor_to_vec3s(a.vertices).unwrap(),
            tensor_to_vec3s(b.vertices).unwrap(),
        );
        for (fa, fb) in av.iter().zip(&bv) {
            for (k, &v) in ids.iter().enumerate() {
                assert!((fa[v as usize] - fb[k]).abs().max_element() < 1e-6);
            }
        }
        let (aj, bj) = (
            tensor_to_vec3s(a.joints).unwrap(),
            tensor_to_vec3s(b.joints).unwrap(),
        );
        assert_eq!(aj, bj);
    }

    #[test]
    fn a_morphable_model_with_another_skeleton_agrees_with_the_cpu() {
        // 24 joints, 6 shape coefficients, pose correctives, up to 6 influences per vertex.
        let device = ndarray_device();
        for posedirs in [false, true] {
            let template = lfit_model::body::smpl_like(3, 300, 6, posedirs);
            let skin = TensorSkinning::new(&template, &device);
            assert_eq!(skin.param_dim(), 3 + 72 + 6);
            let mut rng = ChaCha8Rng::seed_from_u64(5);
            let params: Vec<Vec<f64>> = (0..6)
                .map(|_| {
                    (0..skin.param_dim())
                        .map(|i| {
                            if i < 75 {
                                rng.random_range(-1.0..1.0)
                            } else {
                                rng.random_range(-3.0..3.0)
                            }
                        })
                        .collect()
                })
                .collect();
            let out = skin.forward(poses_to_tensor(&params, &device));
            let joints = tensor_to_vec3s(out.joints).unwrap();
            let vertices = tensor_to_vec3s(out.vertices).unwrap();
            let (mut je, mut ve) = (0f32, 0f32);
            for (b, p) in params.iter().enumerate() {
                let cj = joint_transforms(&template, p).joints;
                let cv = pose_vertices(&template, p, SkinningMethod::Linear);
                for (g, c) in joints[b].iter().zip(&cj) {
                    je = nan_max(je, (*g - c.as_vec3()).abs());
                }
                for (g, c) in vertices[b].iter().zip(&cv) {
                    ve = nan_max(ve, (*g - *c).abs());
                }
            }
            println!(
                "morphable 24-joint model (posedirs {posedirs}): max |joint diff| {je:.3e} m, max |vertex diff| {ve:.3e} m"
            );
            assert!(je < 1e-5 && ve < 1e-5, "{je} {ve}");
        }
    }

    fn random_pose(rng: &mut ChaCha8Rng) -> Pose {
        let mut pose = [0.0; POSE_DIM];
        for (i, v) in pose.iter_mut().enumerate() {
            *v = if i < 3 {
                rng.random_range(-0.5..0.5)
            } else {
                rng.random_range(-1.0..1.0)
            };
        }
        pose
    }

    /// Eight random poses, the zero pose, and a random pose with some joints exactly zero.
    fn test_poses() -> Vec<Pose> {
        let mut rng = ChaCha8Rng::seed_from_u64(7);
        let mut poses: Vec<Pose> = (0..8).map(|_| random_pose(&mut rng)).collect();
        poses.push([0.0; POSE_DIM]);
        let mut partial = random_pose(&mut rng);
        for j in [0, 3, 7, 8, 12, 17] {
            partial[rot_offset(j)..rot_offset(j) + 3].fill(0.0);
        }
        poses.push(partial);
        poses
    }

    /// Max |tensor - CPU| over joints and vertices of all poses.
    fn max_errors(device: &Device) -> (f32, f32) {
        let template = lfit_model::default_template();
        let skin = TensorSkinning::new(&template, device);
        let poses = test_poses();
        let out = skin.forward(poses_to_tensor(&poses, device));
        assert_eq!(out.world_rotations.dims(), [poses.len(), 18, 3, 3]);
        let joints = tensor_to_vec3s(out.joints).unwrap();
        let vertices = tensor_to_vec3s(out.vertices).unwrap();
        assert_eq!(vertices.len(), poses.len());
        let (mut joint_err, mut vertex_err) = (0f32, 0f32);
        for (b, pose) in poses.iter().enumerate() {
            let cpu_joints = joint_transforms(&template, pose).joints;
            let cpu_vertices = pose_vertices(&template, pose, SkinningMethod::Linear);
            assert_eq!(joints[b].len(), cpu_joints.len());
            assert_eq!(vertices[b].len(), cpu_vertices.len());
            for (g, c) in joints[b].iter().zip(&cpu_joints) {
                joint_err = nan_max(joint_err, (*g - c.as_vec3()).abs());
            }
            for (g, c) in vertices[b].iter().zip(&cpu_vertices) {
                vertex_err = nan_max(vertex_err, (*g - *c).abs());
            }
        }
        (joint_err, vertex_err)
    }

    /// `max` that is NaN as soon as one value is (`f32::max` and glam's `max_element` drop NaN, so
    /// a NaN output would compare as agreeing).
    fn nan_max(a: f32, b: glam::Vec3) -> f32 {
        if a.is_nan() || !b.is_finite() {
            f32::NAN
        } else {
            a.max(b.max_element())
        }
    }

    fn check_agreement(name: &str, device: &Device) {
        let (joint_err, vertex_err) = max_errors(device);
        println!(
            "{name}: max |joint diff| = {joint_err:.3e} m, max |vertex diff| = {vertex_err:.3e} m"
        );
        assert!(joint_err < 1e-5, "{name}: joint error {joint_err}");
        assert!(vertex_err < 1e-5, "{name}: vertex error {vertex_err}");
    }

    #[test]
    fn tensor_matches_cpu_on_ndarray() {
        check_agreement("ndarray", &device_from_name("ndarray").unwrap());
    }

    #[test]
    fn tensor_matches_cpu_on_flex() {
        check_agreement("flex", &device_from_name("flex").unwrap());
    }

    #[test]
    fn tensor_matches_cpu_on_wgpu() {
        if let Err(reason) = wgpu_status() {
            assert!(
                std::env::var("LFIT_REQUIRE_WGPU").as_deref() != Ok("1"),
                "LFIT_REQUIRE_WGPU=1 but wgpu is unavailable: {reason}"
            );
            println!("skipping wgpu: {reason}");
            return;
        }
        let adapter = wgpu_status().unwrap();
        check_agreement(
            &format!("wgpu on {adapter}"),
            &device_from_name("wgpu").unwrap(),
        );
    }

    #[test]
    fn world_rotations_match_cpu() {
        let template = lfit_model::default_template();
        let device = device_from_name("flex").unwrap();
        let skin = TensorSkinning::new(&template, &device);
        let poses = test_poses();
        let out = skin.forward(poses_to_tensor(&poses, &device));
        let rows = tensor_to_rows(out.world_rotations.reshape([poses.len(), 18 * 9])).unwrap();
        for (b, pose) in poses.iter().enumerate() {
            for (j, a) in joint_transforms(&template, pose).iter().enumerate() {
                for r in 0..3 {
                    for c in 0..3 {
                        let got = f64::from(rows[b][j * 9 + r * 3 + c]);
                        let want = a.matrix3.col(c)[r];
                        assert!(
                            (got - want).abs() < 1e-5,
                            "pose {b} joint {j} ({r},{c}): {got} vs {want}"
                        );
                    }
                }
            }
        }
    }

    #[test]
    fn rodrigues_matches_glam() {
        let device = device_from_name("ndarray").unwrap();
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        let mut rs: Vec<DVec3> = vec![
            DVec3::ZERO,
            DVec3::new(1e-4, 0.0, 0.0),
            DVec3::new(0.0, -1e-7, 2e-7),
            DVec3::new(0.0, std::f64::consts::FRAC_PI_2, 0.0),
            DVec3::new(0.0, 0.0, std::f64::consts::PI),
            DVec3::new(-3.0, 0.5, 1.0).normalize() * 2.5,
        ];
        rs.extend((0..20).map(|_| {
            DVec3::new(
                rng.random_range(-1.0..1.0),
                rng.random_range(-1.0..1.0),
                rng.random_range(-1.0..1.0),
            ) * 1.5
        }));
        // Round the inputs to f32 so both sides rotate by the same vector.
        let rs: Vec<DVec3> = rs.iter().map(|r| r.as_vec3().as_dvec3()).collect();
        let flat: Vec<f32> = rs.iter().flat_map(|r| r.as_vec3().to_array()).collect();
        let mats = rodrigues(Tensor::from_data(
            TensorData::new(flat, [rs.len(), 3]),
            &device,
        ));
        let rows = tensor_to_rows(mats.reshape([rs.len(), 9])).unwrap();
        let mut max_err = 0f64;
        for (r, row) in rs.iter().zip(&rows) {
            let angle = r.length();
            let want = if angle == 0.0 {
                DMat3::IDENTITY
            } else {
                DMat3::from_axis_angle(*r / angle, angle)
            };
            for i in 0..3 {
                for c in 0..3 {
                    let err = (f64::from(row[i * 3 + c]) - want.col(c)[i]).abs();
                    assert!(
                        err <= 1e-6,
                        "r = {r}: entry ({i},{c}) = {} vs {}",
                        row[i * 3 + c],
                        want.col(c)[i]
                    );
                    max_err = max_err.max(err);
                }
            }
        }
        println!("rodrigues: max |entry diff| vs glam = {max_err:.3e}");
    }

    /// `sum_v d_v . posed_v` evaluated entirely in f64 from the CPU joint transforms and the
    /// rig's f64 weights.
    fn loss_f64(template: &Template, pose: &Pose, directions: &[DVec3]) -> f64 {
        let transforms = joint_transforms(template, pose);
        template
            .vertices
            .iter()
            .zip(&template.rig.weights)
            .zip(directions)
            .map(|((v, influences), d)| {
                let x = v.as_dvec3();
                let posed: DVec3 = influences
                    .iter()
                    .map(|&(j, w)| w * transforms[j].transform_point3(x))
                    .sum();
                d.dot(posed)
            })
            .sum()
    }

    fn check_gradient(
        template: &Template,
        skin: &TensorSkinning,
        device: &Device,
        pose: &Pose,
        directions: &[DVec3],
    ) -> f64 {
        let v = template.num_vertices();
        let poses = poses_to_tensor(std::slice::from_ref(pose), device).require_grad();
        let dirs: Vec<f32> = directions
            .iter()
            .flat_map(|d| d.as_vec3().to_array())
            .collect();
        let dirs = Tensor::<3>::from_data(TensorData::new(dirs, [1, v, 3]), device);
        let out = skin.forward(poses.clone());
        let loss = (out.vertices * dirs).sum();
        let grads = loss.backward();
        let grad = tensor_to_rows(poses.grad(&grads).expect("poses require a gradient"))
            .unwrap()
            .remove(0);
        assert_eq!(grad.len(), POSE_DIM);

        let h = 1e-4;
        let mut worst = 0f64;
        for i in 0..POSE_DIM {
            let (mut plus, mut minus) = (*pose, *pose);
            plus[i] += h;
            minus[i] -= h;
            let fd = (loss_f64(template, &plus, directions)
                - loss_f64(template, &minus, directions))
                / (2.0 * h);
            let g = f64::from(grad[i]);
            assert!(g.is_finite(), "gradient {i} is not finite: {g}");
            let rel = (g - fd).abs() / fd.abs().max(1.0);
            assert!(
                rel <= 1e-3,
                "d L / d pose[{i}]: autodiff {g} vs finite differences {fd}"
            );
            worst = worst.max(rel);
        }
        worst
    }

    #[test]
    fn gradient_matches_finite_differences() {
        let template = lfit_model::default_template();
        let device = device_from_name("ndarray").unwrap().autodiff();
        let skin = TensorSkinning::new(&template, &device);
        let mut rng = ChaCha8Rng::seed_from_u64(11);
        let directions: Vec<DVec3> = (0..template.num_vertices())
            .map(|_| {
                DVec3::new(
                    rng.random_range(-1.0..1.0),
                    rng.random_range(-1.0..1.0),
                    rng.random_range(-1.0..1.0),
                )
            })
            .map(|d: DVec3| d.as_vec3().as_dvec3())
            .collect();
        let pose = test_poses()[0];
        let random = check_gradient(&template, &skin, &device, &pose, &directions);
        let zero = check_gradient(&template, &skin, &device, &[0.0; POSE_DIM], &directions);
        println!("gradient: max relative error {random:.3e} (random pose), {zero:.3e} (zero pose)");
    }

    #[test]
    fn device_names() {
        assert!(device_from_name("flex").is_ok());
        assert!(device_from_name(" NdArray ").is_ok());
        let err = device_from_name("cuda").unwrap_err().to_string();
        assert!(
            err.contains("cuda") && err.contains("ndarray, flex, wgpu"),
            "{err}"
        );
    }

    #[test]
    fn topological_order_puts_parents_first() {
        let parents = [Some(2), None, Some(1), Some(0), Some(1)];
        let order = topological_order(&parents);
        assert_eq!(order.len(), parents.len());
        for (k, &j) in order.iter().enumerate() {
            if let Some(p) = parents[j] {
                assert!(order[..k].contains(&p), "{order:?}");
            }
        }
    }
}
