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
//!
//! **Large meshes.** The paper's body (SMPL) has 6,890 vertices. On a model with more than
//! [`LOSS_MAX_VERTICES`] vertices (the MakeHuman body: 13,380) L^M and L^E are computed on
//! [`LOSS_MAX_VERTICES`] vertices spread over the rest surface by farthest-point sampling, with
//! each subset vertex's [`LOSS_SUBSET_NEIGHBOURS`] nearest subset vertices as its edges: the
//! skinning in the loss dominates a training step, and this keeps a 1,500-step run on the
//! MakeHuman body near the default template's cost. The joint, rotation and translation terms
//! are unchanged (the joints come from the full model's regressor).

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
    /// Edge vectors `[B, 3E]` (x, y, z of each edge in turn; see [`Loss::edge_vectors`]).
    pub edges: Tensor<2>,
}

/// The loss with its precomputed template tensors.
#[derive(Debug, Clone)]
pub struct Loss {
    pub skinning: TensorSkinning,
    edge_a: Tensor<1, Int>,
    edge_b: Tensor<1, Int>,
    pub weights: LossWeights,
}

/// Largest mesh on which the loss runs on every vertex (the default template has 3,106).
pub const LOSS_MAX_VERTICES: usize = 3200;
/// Edges per subset vertex on a larger mesh.
pub const LOSS_SUBSET_NEIGHBOURS: usize = 6;

/// `n` vertices spread over the rest mesh by farthest-point sampling from vertex 0
/// (deterministic; ties go to the lower index).
pub fn farthest_point_subset(points: &[glam::Vec3], n: usize) -> Vec<u32> {
    let n = n.min(points.len());
    if n == 0 {
        return Vec::new();
    }
    let mut dist = vec![f32::INFINITY; points.len()];
    let mut out = Vec::with_capacity(n);
    let mut cur = 0usize;
    for _ in 0..n {
        out.push(cur as u32);
        let c = points[cur];
        let mut best = (f32::MIN, 0usize);
        for (i, (d, p)) in dist.iter_mut().zip(points).enumerate() {
            *d = d.min(p.distance_squared(c));
            if *d > best.0 {
                best = (*d, i);
            }
        }
        cur = best.1;
    }
    out
}

/// Undirected edges joining each of `points` to its `k` nearest others (deduplicated, sorted).
pub fn knn_edges(points: &[glam::Vec3], k: usize) -> Vec<(u32, u32)> {
    let mut edges = Vec::with_capacity(points.len() * k);
    for (i, p) in points.iter().enumerate() {
        let mut near: Vec<(f32, usize)> = points
            .iter()
            .enumerate()
            .filter(|&(j, _)| j != i)
            .map(|(j, q)| (p.distance_squared(*q), j))
            .collect();
        let kk = k.min(near.len());
        if kk == 0 {
            continue;
        }
        near.select_nth_unstable_by(kk - 1, |a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
        for &(_, j) in &near[..kk] {
            edges.push(((i.min(j)) as u32, (i.max(j)) as u32));
        }
    }
    edges.sort_unstable();
    edges.dedup();
    edges
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
        let full = TensorSkinning::new(template, device);
        let (skinning, edges) = if template.num_vertices() > LOSS_MAX_VERTICES {
            let rest: Vec<glam::Vec3> = if template.morph.rest.is_empty() {
                template.vertices.clone()
            } else {
                template.morph.rest.iter().map(|v| v.as_vec3()).collect()
            };
            let ids = farthest_point_subset(&rest, LOSS_MAX_VERTICES);
            let points: Vec<glam::Vec3> = ids.iter().map(|&i| rest[i as usize]).collect();
            (
                full.vertex_subset(&ids),
                knn_edges(&points, LOSS_SUBSET_NEIGHBOURS),
            )
        } else {
            (full, mesh_edges(template))
        };
        // Coordinate indices into the flattened `[B, 3V]` vertices: x, y, z of each edge's end.
        let idx = |f: fn(&(u32, u32)) -> u32| {
            let v: Vec<i64> = edges
                .iter()
                .flat_map(|e| {
                    let v = 3 * i64::from(f(e));
                    [v, v + 1, v + 2]
                })
                .collect();
            let n = v.len();
            Tensor::<1, Int>::from_data(TensorData::new(v, [n]), device)
        };
        Self {
            skinning,
            edge_a: idx(|e| e.0),
            edge_b: idx(|e| e.1),
            weights,
        }
    }

    /// `M_i − M_j` of every edge, `[B, 3E]`: the vertices `[B, V, 3]` flattened to `[B, 3V]`
    /// (a free reshape) and their coordinates selected along the last axis. The same numbers as
    /// selecting whole vertices of `[B, V, 3]`, but Burn flex's `select` and its backward
    /// (`select_add`) have a row loop for 2-d tensors and an index computation per element for
    /// 3-d ones: a third of a markers training step went there.
    fn edge_vectors(&self, vertices: Tensor<3>) -> Tensor<2> {
        let [batch, n, _] = vertices.dims();
        let flat = vertices.reshape([batch, 3 * n]);
        flat.clone().select(1, self.edge_a.clone()) - flat.select(1, self.edge_b.clone())
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
        let le = (self.edge_vectors(out.vertices) - truth.edges.clone())
            .abs()
            .mean();
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

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod tests {
    use super::*;
    use glam::Vec3;

    #[test]
    fn farthest_points_spread_over_a_line_and_knn_joins_neighbours() {
        // 101 points on a line, crowded at one end: the first picks are the far ends and the
        // middle, not the crowd.
        let mut pts: Vec<Vec3> = (0..=100)
            .map(|i| Vec3::new(i as f32 / 100.0, 0.0, 0.0))
            .collect();
        pts.extend((0..50).map(|i| Vec3::new(i as f32 * 1e-4, 0.0, 0.0)));
        let ids = farthest_point_subset(&pts, 3);
        assert_eq!(ids, vec![0, 100, 50]);
        let sub: Vec<Vec3> = (0..=10).map(|i| Vec3::new(i as f32, 0.0, 0.0)).collect();
        let e = knn_edges(&sub, 2);
        // Interior points join both neighbours; the ends join the next two.
        assert!(e.contains(&(4, 5)) && e.contains(&(5, 6)) && e.contains(&(0, 2)));
        assert!(!e.iter().any(|&(a, b)| b - a > 2), "{e:?}");
    }

    #[test]
    fn a_large_mesh_trains_on_a_spread_subset_and_a_small_one_on_every_vertex() {
        let device = lfit_nn::tensor::ndarray_device();
        let small = lfit_model::default_template();
        let loss = Loss::new(&small, LossWeights::default(), &device);
        assert_eq!(loss.skinning.num_vertices(), small.num_vertices());
        let big = lfit_model::body::smpl_like(3, 4000, 4, false);
        let loss = Loss::new(&big, LossWeights::default(), &device);
        assert_eq!(loss.skinning.num_vertices(), LOSS_MAX_VERTICES);
        // The loss of the truth against itself is zero, and a perturbed pose raises it.
        let p = vec![vec![0.1f64; loss.skinning.param_dim()]];
        let t = lfit_nn::tensor::poses_to_tensor(&p, &device);
        let truth = loss.truth(t.clone());
        let zero: f32 = loss.step(t.clone(), &truth).into_scalar();
        assert!(zero.abs() < 1e-6, "{zero}");
        let mut q = p.clone();
        q[0][10] += 0.2;
        let moved: f32 = loss
            .step(lfit_nn::tensor::poses_to_tensor(&q, &device), &truth)
            .into_scalar();
        assert!(moved > 0.1, "{moved}");
    }
}
