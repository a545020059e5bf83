//! The morphable part of a model (SPEC §3a), SMPL's forward model:
//!
//! ```text
//! T(β, ψ) = v_template + S β + E ψ
//! c(β, ψ) = J_regressor T(β, ψ)                      (rest joints follow the shape)
//! T_P     = T(β, ψ) + P · (R(θ) − I)[joints 1..J−1]    (pose correctives, optional)
//! ```
//!
//! Shape and expression directions are one `(3V) × (B + E)` matrix (row `3v + axis`, shape
//! columns first), pose correctives a `(3V) × 9(J − 1)` matrix, both row-major, in f64. The joint
//! regressor is kept sparse (CSR) and applied once to the directions at load:
//! `c(β, ψ) = c₀ + (J_regressor · [S E]) [β; ψ]`.
//!
//! The default template has none of this ([`Morph::none`]): its rest vertices and joints are the
//! ones of its files, and every function here is then the identity.

use glam::{DMat3, DVec3};

use crate::body::rotation::exp_map;

/// A sparse matrix stored by rows (CSR).
#[derive(Debug, Clone, PartialEq)]
pub struct SparseRows {
    pub rows: usize,
    pub cols: usize,
    pub indptr: Vec<usize>,
    pub indices: Vec<u32>,
    pub values: Vec<f64>,
}

impl SparseRows {
    /// From a dense row-major matrix, keeping the non-zero entries.
    pub fn from_dense(rows: usize, cols: usize, dense: &[f64]) -> Self {
        let mut indptr = vec![0];
        let mut indices = Vec::new();
        let mut values = Vec::new();
        for r in 0..rows {
            for (c, &v) in dense[r * cols..(r + 1) * cols].iter().enumerate() {
                if v != 0.0 {
                    indices.push(c as u32);
                    values.push(v);
                }
            }
            indptr.push(indices.len());
        }
        Self {
            rows,
            cols,
            indptr,
            indices,
            values,
        }
    }

    /// The non-zero entries `(column, value)` of row `r`.
    pub fn row(&self, r: usize) -> impl Iterator<Item = (usize, f64)> + '_ {
        let (a, b) = (self.indptr[r], self.indptr[r + 1]);
        self.indices[a..b]
            .iter()
            .zip(&self.values[a..b])
            .map(|(&c, &v)| (c as usize, v))
    }

    /// The dense row-major matrix.
    pub fn to_dense(&self) -> Vec<f64> {
        let mut out = vec![0.0; self.rows * self.cols];
        for r in 0..self.rows {
            for (c, v) in self.row(r) {
                out[r * self.cols + c] += v;
            }
        }
        out
    }

    /// `M x` for points `x` (one per column).
    pub fn apply(&self, x: &[DVec3]) -> Vec<DVec3> {
        (0..self.rows)
            .map(|r| self.row(r).fold(DVec3::ZERO, |acc, (c, v)| acc + v * x[c]))
            .collect()
    }
}

/// Blend shapes, pose correctives and joint regressor of a morphable model.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Morph {
    /// `v_template` in f64 (empty for [`Morph::none`]: the template's own f32 vertices are used).
    pub rest: Vec<DVec3>,
    /// B.
    pub shape: usize,
    /// E.
    pub expression: usize,
    /// `(3V) × (B + E)`, row-major: `∂T_v[axis] / ∂[β; ψ]_k` at `[(3v + axis)(B + E) + k]`.
    pub dirs: Vec<f64>,
    /// `(3V) × 9(J − 1)`, row-major, or `None` without pose correctives.
    pub posedirs: Option<Vec<f64>>,
    /// `J × V`, or `None` when the rest joints do not follow the shape (the default template).
    pub regressor: Option<SparseRows>,
    /// `(3J) × (B + E)` = `J_regressor · dirs`, row-major.
    pub joint_dirs: Vec<f64>,
    /// The full-mesh loop's f32 copies of the directions, built on first use.
    mesh: MeshColumns,
}

/// `[S E]` and `P` column by column in f32 (`[k][3v + axis]`): the rest mesh of a parameter
/// vector is then one contiguous `out += c_k · column_k` per coefficient, which vectorises,
/// instead of a dot product of B + E entries per vertex axis. A cache, not part of the value: a
/// clone (whose directions may be changed) starts without it and two morphs compare equal
/// whatever their caches hold.
#[derive(Default)]
#[allow(clippy::type_complexity)]
struct MeshColumns(
    std::sync::OnceLock<(Vec<f32>, Vec<f32>)>,
    /// The last shape coefficients and, once they came twice in a row, their offsets
    /// `S β + E ψ` (f32, `[3v + axis]`).
    std::sync::Mutex<Option<(Vec<f64>, Option<Vec<f32>>)>>,
);

impl Clone for MeshColumns {
    fn clone(&self) -> Self {
        Self::default()
    }
}

impl PartialEq for MeshColumns {
    fn eq(&self, _: &Self) -> bool {
        true
    }
}

impl std::fmt::Debug for MeshColumns {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(if self.0.get().is_some() {
            "MeshColumns(built)"
        } else {
            "MeshColumns(not built)"
        })
    }
}

/// The columns of a row-major `rows × cols` matrix, each contiguous, in f32.
fn columns_f32(matrix: &[f64], cols: usize) -> Vec<f32> {
    if cols == 0 {
        return Vec::new();
    }
    let rows = matrix.len() / cols;
    let mut out = vec![0f32; matrix.len()];
    for (r, row) in matrix.chunks_exact(cols).enumerate() {
        for (c, &x) in row.iter().enumerate() {
            out[c * rows + r] = x as f32;
        }
    }
    out
}

/// `out += c · column`, the loop the compiler vectorises.
#[inline]
fn axpy(out: &mut [f32], c: f32, column: &[f32]) {
    for (o, &d) in out.iter_mut().zip(column) {
        *o += c * d;
    }
}

impl Morph {
    /// No shape, no expression, no correctives.
    pub fn none() -> Self {
        Self::default()
    }

    /// B + E.
    pub fn coefficients(&self) -> usize {
        self.shape + self.expression
    }

    /// Whether the rest geometry depends on the parameters at all.
    pub fn is_rigid(&self) -> bool {
        self.coefficients() == 0 && self.posedirs.is_none()
    }

    /// Builds the morph of a model with `joints` joints; computes `joint_dirs`.
    ///
    /// # Panics
    /// Never on inputs that [`crate::modelfile`] validated: the sizes must agree.
    pub fn new(
        rest: Vec<DVec3>,
        shape: usize,
        expression: usize,
        dirs: Vec<f64>,
        posedirs: Option<Vec<f64>>,
        regressor: Option<SparseRows>,
    ) -> Self {
        let k = shape + expression;
        let joint_dirs = match &regressor {
            Some(reg) => {
                let mut out = vec![0.0; 3 * reg.rows * k];
                for j in 0..reg.rows {
                    for (v, w) in reg.row(j) {
                        for a in 0..3 {
                            let src = &dirs[(3 * v + a) * k..(3 * v + a + 1) * k];
                            let dst = &mut out[(3 * j + a) * k..(3 * j + a + 1) * k];
                            for (d, s) in dst.iter_mut().zip(src) {
                                *d += w * s;
                            }
                        }
                    }
                }
                out
            }
            None => Vec::new(),
        };
        Self {
            rest,
            shape,
            expression,
            dirs,
            posedirs,
            regressor,
            joint_dirs,
            mesh: MeshColumns::default(),
        }
    }

    /// The rest mesh `T(β, ψ) + P (R(θ) − I)` of every vertex in f32 (`out[3v + axis]`, resized),
    /// for the full-mesh loops: [`Morph::rest_vertex`] of every vertex. The offsets
    /// `S β + E ψ + P f` are summed in f32 in coefficient order (their rounding is relative to the
    /// offsets, centimetres, not to the body), then added to the f64 rest position with one
    /// rounding. `base`: the template's own vertices, used when the morph has no `rest`. A zero
    /// coefficient costs nothing; the offsets of coefficients given twice in a row are kept and
    /// reused while they repeat (bit for bit the same mesh).
    pub fn rest_mesh_f32(
        &self,
        base: &[glam::Vec3],
        coeffs: &[f64],
        pose_feature: &[f64],
        out: &mut Vec<f32>,
    ) {
        out.clear();
        let n = 3 * if self.rest.is_empty() {
            base.len()
        } else {
            self.rest.len()
        };
        out.resize(n, 0.0);
        let k = self.coefficients();
        let with_pose = self.posedirs.is_some() && !pose_feature.is_empty();
        let with_shape = k > 0 && coeffs.iter().any(|&c| c != 0.0);
        if n > 0 && (with_shape || with_pose) {
            let (dirs, posedirs) = self.mesh.0.get_or_init(|| {
                let pose_cols = self.posedirs.as_ref().map_or(0, |pd| pd.len() / n);
                (
                    columns_f32(&self.dirs, k),
                    self.posedirs
                        .as_ref()
                        .map_or_else(Vec::new, |pd| columns_f32(pd, pose_cols)),
                )
            });
            // The last coefficients are remembered, and their shape offsets kept once they come
            // twice in a row: a sequence of one subject (one β: rendering, export,
            // `--sequence-shape`) pays the shape pass twice, not per mesh, and a mesh per random β
            // copies nothing.
            if with_shape {
                // Other threads never wait: a locked slot is skipped (the mesh is computed).
                let mut slot = self.mesh.1.try_lock().ok();
                match slot.as_deref() {
                    Some(Some((c, Some(kept)))) if c.as_slice() == coeffs && kept.len() == n => {
                        out.copy_from_slice(kept);
                    }
                    _ => {
                        for (column, &c) in dirs.chunks_exact(n).zip(coeffs) {
                            if c != 0.0 {
                                axpy(out, c as f32, column);
                            }
                        }
                        if let Some(last) = slot.as_deref_mut() {
                            let repeated = matches!(last, Some((c, _)) if c.as_slice() == coeffs);
                            *last = Some((coeffs.to_vec(), repeated.then(|| out.clone())));
                        }
                    }
                }
            }
            if with_pose {
                for (column, &f) in posedirs.chunks_exact(n).zip(pose_feature) {
                    if f != 0.0 {
                        axpy(out, f as f32, column);
                    }
                }
            }
        }
        if self.rest.is_empty() {
            for (o, r) in out.chunks_exact_mut(3).zip(base) {
                for a in 0..3 {
                    o[a] = (f64::from(o[a]) + f64::from(r[a])) as f32;
                }
            }
        } else {
            for (o, r) in out.chunks_exact_mut(3).zip(&self.rest) {
                for a in 0..3 {
                    o[a] = (f64::from(o[a]) + r[a]) as f32;
                }
            }
        }
    }

    /// The rest joints `c(β, ψ)`: `base` (the β = ψ = 0 joints) plus the joint directions.
    pub fn rest_joints(&self, base: &[DVec3], coeffs: &[f64]) -> Vec<DVec3> {
        let k = self.coefficients();
        if k == 0 || self.joint_dirs.is_empty() || coeffs.iter().all(|&c| c == 0.0) {
            return base.to_vec();
        }
        base.iter()
            .enumerate()
            .map(|(j, &c)| {
                let mut d = [0.0; 3];
                for (a, da) in d.iter_mut().enumerate() {
                    *da = dot(
                        &self.joint_dirs[(3 * j + a) * k..(3 * j + a + 1) * k],
                        coeffs,
                    );
                }
                c + DVec3::from_array(d)
            })
            .collect()
    }

    /// Rest position of vertex `v` under coefficients `[β; ψ]` and pose feature `R(θ) − I`
    /// (empty when the model has no correctives). `base` is the template's own rest vertex.
    #[inline]
    pub fn rest_vertex(
        &self,
        v: usize,
        base: DVec3,
        coeffs: &[f64],
        pose_feature: &[f64],
    ) -> DVec3 {
        let mut p = if self.rest.is_empty() {
            base
        } else {
            self.rest[v]
        };
        let k = self.coefficients();
        if k > 0 {
            // The three rows' dot products in one loop: three independent chains (each summed in
            // the order `dot` sums it, so the position is the same to the bit).
            let rows = &self.dirs[3 * v * k..3 * (v + 1) * k];
            let (x, rest) = rows.split_at(k);
            let (y, z) = rest.split_at(k);
            let mut s = [-0.0f64; 3];
            for (i, &c) in coeffs.iter().enumerate().take(k) {
                s[0] += x[i] * c;
                s[1] += y[i] * c;
                s[2] += z[i] * c;
            }
            for a in 0..3 {
                p[a] += s[a];
            }
        }
        if let Some(pd) = &self.posedirs
            && !pose_feature.is_empty()
        {
            let n = pose_feature.len();
            for a in 0..3 {
                p[a] += dot(&pd[(3 * v + a) * n..(3 * v + a + 1) * n], pose_feature);
            }
        }
        p
    }
}

/// SMPL's pose feature: `R(r_j) − I` of joints 1..J−1, each row-major, from the rotation block
/// of `params` (entries `3 + 3j ..`).
pub fn pose_feature(params: &[f64], joints: usize) -> Vec<f64> {
    let mut out = Vec::with_capacity(9 * joints.saturating_sub(1));
    for j in 1..joints {
        let o = 3 + 3 * j;
        let r = exp_map(DVec3::new(params[o], params[o + 1], params[o + 2])) - DMat3::IDENTITY;
        for row in 0..3 {
            for col in 0..3 {
                out.push(r.col(col)[row]);
            }
        }
    }
    out
}

#[inline]
fn dot(a: &[f64], b: &[f64]) -> f64 {
    a.iter().zip(b).map(|(x, y)| x * y).sum()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sparse_rows_round_trip_and_apply() {
        let dense = [0.5, 0.0, 0.5, 0.0, 0.0, 1.0];
        let m = SparseRows::from_dense(2, 3, &dense);
        assert_eq!(m.to_dense(), dense);
        let x = [DVec3::X, DVec3::Y, DVec3::Z];
        assert_eq!(m.apply(&x), vec![DVec3::new(0.5, 0.0, 0.5), DVec3::Z]);
    }

    #[test]
    fn joints_follow_the_regressed_shape() {
        // Two vertices, one joint at their mean; β moves vertex 1 by +1 along y.
        let rest = vec![DVec3::ZERO, DVec3::X];
        let dirs = vec![0.0, 0.0, 0.0, 0.0, 1.0, 0.0];
        let reg = SparseRows::from_dense(1, 2, &[0.5, 0.5]);
        let m = Morph::new(rest, 1, 0, dirs, None, Some(reg));
        let c = m.rest_joints(&[DVec3::new(0.5, 0.0, 0.0)], &[2.0]);
        assert!((c[0] - DVec3::new(0.5, 1.0, 0.0)).length() < 1e-15);
        assert_eq!(
            m.rest_vertex(1, DVec3::ZERO, &[2.0], &[]),
            DVec3::new(1.0, 2.0, 0.0)
        );
    }

    #[test]
    fn pose_feature_is_zero_at_rest_and_row_major() {
        let mut p = vec![0.0; 3 + 3 * 3];
        assert!(pose_feature(&p, 3).iter().all(|&v| v == 0.0));
        p[6 + 2] = std::f64::consts::FRAC_PI_2; // joint 1 about z: R = [[0,-1,0],[1,0,0],[0,0,1]]
        let f = pose_feature(&p, 3);
        assert_eq!(f.len(), 18);
        let expect = [-1.0, -1.0, 0.0, 1.0, -1.0, 0.0, 0.0, 0.0, 0.0];
        for (a, b) in f[..9].iter().zip(expect) {
            assert!((a - b).abs() < 1e-12, "{f:?}");
        }
    }
}
