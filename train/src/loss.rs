//! The per-step training loss of papers/002 supp. eq. (13)–(18), through the tensor FK + LBS of
//! [`lfit_nn::tensor`]:
//!
//! ```text
//! L   = Σ_{n=0..N} L_n                                           (13)
//! L_n = λM L^M + λE L^E + λT L^T + λθ L^θ  (+ λt on the root translation)   (14)
//! L^M = |M̂ − M|, L^E = |(M̂_i − M̂_j) − (M_i − M_j)| over mesh edges,
//! L^T = |T̂_j − T_j| (world rotations and joint positions), L^θ = |R̂θ − Rθ| + |t̂ − t|
//! ```
//!
//! Each L1 term is a mean over its entries (the paper writes sums; means keep the weights of
//! supp. §6.2 — λM = λE = 1000, λT = 100, λθ = 1, λt = 100 — independent of mesh size and batch).

use burn::tensor::{Device, Int, Tensor, TensorData};
use lfit_model::Template;
use lfit_nn::tensor::{SkinnedBatch, TensorSkinning, rodrigues};
use serde::{Deserialize, Serialize};

/// Loss weights (papers/002 supp. §6.2).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct LossWeights {
    pub vertices: f64,
    pub edges: f64,
    pub transforms: f64,
    pub rotations: f64,
    pub translation: f64,
}

impl Default for LossWeights {
    fn default() -> Self {
        Self {
            vertices: 1000.0,
            edges: 1000.0,
            transforms: 100.0,
            rotations: 1.0,
            translation: 100.0,
        }
    }
}

/// Ground truth of a batch, computed once (no gradient).
#[derive(Debug, Clone)]
pub struct Truth {
    pub poses: Tensor<2>,
    pub skinned: SkinnedBatch,
    pub local: Tensor<3>,
    pub edges: Tensor<3>,
}

/// The loss with its precomputed template tensors.
#[derive(Debug, Clone)]
pub struct Loss {
    pub skinning: TensorSkinning,
    edge_a: Tensor<1, Int>,
    edge_b: Tensor<1, Int>,
    pub weights: LossWeights,
}

/// Unique undirected edges of the template's triangles.
pub fn mesh_edges(template: &Template) -> Vec<(u32, u32)> {
    let mut edges: Vec<(u32, u32)> = template
        .faces
        .iter()
        .flat_map(|f| [(f[0], f[1]), (f[1], f[2]), (f[2], f[0])])
        .map(|(a, b)| (a.min(b), a.max(b)))
        .collect();
    edges.sort_unstable();
    edges.dedup();
    edges
}

/// The parent-relative rotation matrices of the joints (the pose part of a parameter vector;
/// shape and expression coefficients after it are not rotations).
fn local_rotations(poses: Tensor<2>, joints: usize) -> Tensor<3> {
    let [batch, _] = poses.dims();
    rodrigues(poses.narrow(1, 3, 3 * joints).reshape([batch * joints, 3])).reshape([
        batch,
        joints * 3,
        3,
    ])
}

impl Loss {
    pub fn new(template: &Template, weights: LossWeights, device: &Device) -> Self {
        let edges = mesh_edges(template);
        let idx = |f: fn(&(u32, u32)) -> u32| {
            let v: Vec<i64> = edges.iter().map(|e| i64::from(f(e))).collect();
            let n = v.len();
            Tensor::<1, Int>::from_data(TensorData::new(v, [n]), device)
        };
        Self {
            skinning: TensorSkinning::new(template, device),
            edge_a: idx(|e| e.0),
            edge_b: idx(|e| e.1),
            weights,
        }
    }

    fn edge_vectors(&self, vertices: Tensor<3>) -> Tensor<3> {
        vertices.clone().select(1, self.edge_a.clone()) - vertices.select(1, self.edge_b.clone())
    }

    /// Forward model of the ground-truth parameter vectors `[B, param_dim]` (detached).
    pub fn truth(&self, poses: Tensor<2>) -> Truth {
        let poses = poses.detach();
        let skinned = self.skinning.forward(poses.clone());
        let edges = self.edge_vectors(skinned.vertices.clone());
        Truth {
            local: local_rotations(poses.clone(), self.skinning.num_joints()),
            edges,
            skinned,
            poses,
        }
    }

    /// `L_n` of one iterate `[B, param_dim]`: a scalar tensor `[1]`, and its five weighted parts.
    /// Shape and expression are learned through the vertex, edge and joint terms (the mesh and
    /// the skeleton they change).
    pub fn step(&self, poses: Tensor<2>, truth: &Truth) -> Tensor<1> {
        let w = &self.weights;
        let out = self.skinning.forward(poses.clone());
        let l1 = |a: Tensor<3>, b: Tensor<3>| (a - b).abs().mean();
        let lm = l1(out.vertices.clone(), truth.skinned.vertices.clone());
        let le = l1(self.edge_vectors(out.vertices), truth.edges.clone());
        let lt = (out.world_rotations - truth.skinned.world_rotations.clone())
            .abs()
            .mean()
            + l1(out.joints, truth.skinned.joints.clone());
        let lr = l1(
            local_rotations(poses.clone(), self.skinning.num_joints()),
            truth.local.clone(),
        );
        let ltr = (poses.narrow(1, 0, 3) - truth.poses.clone().narrow(1, 0, 3))
            .abs()
            .mean();
        lm.mul_scalar(w.vertices)
            + le.mul_scalar(w.edges)
            + lt.mul_scalar(w.transforms)
            + lr.mul_scalar(w.rotations)
            + ltr.mul_scalar(w.translation)
    }

    /// Eq. (13): the sum over every iterate θ0 … θN.
    pub fn total(&self, iterates: &[Tensor<2>], truth: &Truth) -> Tensor<1> {
        let mut sum = self.step(iterates[0].clone(), truth);
        for p in &iterates[1..] {
            sum = sum + self.step(p.clone(), truth);
        }
        sum
    }
}
