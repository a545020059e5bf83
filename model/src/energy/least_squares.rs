//! The energy in least-squares form: `E(θ) = Σ_i r_i(θ)²` with the exact Jacobian `∂r/∂θ`.
//!
//! Rows, in this order (each block a fixed number of rows, so the residual vector of one energy
//! always has the same length):
//! - `data`: the sparse prediction minus the target, per residual group `g` divided by its σ and
//!   folded with the robust loss, `√(λ_data/n) φ(s_g) u_g` ([`Robust::fold`]; `n` visible groups),
//!   so that its squares sum to `λ_data · data`. Unseen groups are rows of zeros.
//! - `EP`: in the capsule form one row per capsule, `√(λ_P κ) ‖((1 − q_ab)₊)_b‖` over the pairs
//!   it opens; in the vertex form one row per tested vertex, `√(λ_P/N) ‖((1 − q_e)₊)_e‖` over the ellipsoids it is
//!   tested against (papers/000 eq. 8; the norm keeps one row per vertex, not per pair).
//! - `height` ([`Energy::with_height_prior`]): one row, `√(λ_data/n) (h(β) − H)/σ`, dense over
//!   the shape entries.
//! - `EA`: one row per non-root rotation entry, `√λ_A` times its excess over the limits (the
//!   [`AnglePrior::Hinge`] form; the binary form of eq. 7 is not a sum of squares).
//! - `shape`, `expression`: `√λ β_k`, `√λ ψ_k`.
//!
//! `Σ r²` equals [`Energy::evaluate`] and `2 Jᵀ r` equals [`Energy::evaluate_with_gradient`]'s
//! gradient (both tested), so Gauss-Newton, Levenberg–Marquardt and an external least-squares
//! solver minimise exactly the energy every other fitter sees.

use std::ops::Range;
use std::sync::atomic::Ordering;

use crate::body::jacobian::PointJacobians;
use crate::body::kinematics::Kinematics;
use nalgebra::{DMatrix, DVector};
use serde::{Deserialize, Serialize};

use super::{AnglePrior, Energy, PenetrationForm, Target};
use crate::error::{ModelError, Result};
use crate::observe::{PoseJacobian, Sensor, expand_point_factors};
use crate::pose::rot_offset;

/// Residuals and (optionally) their Jacobian at one parameter vector.
#[derive(Debug, Clone, PartialEq)]
pub struct LeastSquares {
    pub residuals: Vec<f64>,
    /// Rows `dense_from..dense_to` of the Jacobian, `dim` wide, row-major; empty when not
    /// asked for.
    pub jacobian: Vec<f64>,
    /// The first row `jacobian` holds: 0 (every row) unless the rows were asked for in
    /// [`JacobianRows::Factored`] form and the data rows have one ([`LeastSquares::points`]);
    /// then the data rows are only in `points`.
    pub dense_from: usize,
    /// The row after the last that `jacobian` holds: `residuals.len()` unless the rows were
    /// asked for in [`JacobianRows::Factored`] form; then the rows from here on (joint limits,
    /// pose, shape and expression priors: one nonzero each) are only in `singles`.
    pub dense_to: usize,
    /// Rows `dense_to..` as (column, value) of their one entry (value 0 where the row is zero).
    pub singles: Vec<(usize, f64)>,
    /// Columns of the Jacobian: the energy's parameter vector length.
    pub dim: usize,
    /// The term of every block of rows.
    pub blocks: Vec<(&'static str, Range<usize>)>,
    /// Rows known to be zero, residual and Jacobian (unseen groups, inactive penetration and
    /// joint-limit rows): solvers may skip them. Empty without a Jacobian.
    pub zero_rows: Vec<bool>,
    /// The energy E at these parameters: `Σ r²` in the folded form, `Σ ρ` (not `Σ r²`) in
    /// Triggs's form ([`RobustForm`]).
    pub energy: f64,
    /// The observation residual R(θ) = prediction − target (0 where the target is unseen), as
    /// [`Energy::residual`] gives it, from the same prediction: the unweighted, unfolded data
    /// residual the neural fitter reads as a feature.
    pub observation_residual: Vec<f64>,
    /// The data rows in factored form, where the observation model has one
    /// ([`crate::observe::ObservationModel::point_factors`]) and the Jacobian was asked for.
    pub points: Option<PointFactors>,
    /// Rows whose `JᵀJ` does not depend on the parameters (the pose prior's: its Jacobian is a
    /// component's `c0 W`), with that block precomputed: [`LeastSquares::normal_equations`] adds
    /// it instead of the rows' products. The rows stay in `jacobian` for every other reader.
    pub constant_gram: Option<ConstantGram>,
}

/// Rows `rows` of a [`LeastSquares`] Jacobian, nonzero only on the `n` columns from `first`,
/// whose `JᵀJ` there is `scale · gram` (`n × n`, row-major, symmetric).
#[derive(Debug, Clone, PartialEq)]
pub struct ConstantGram {
    pub rows: Range<usize>,
    pub first: usize,
    pub gram: std::sync::Arc<Vec<f64>>,
    pub scale: f64,
}

/// Data rows `i < rows.len()` of a [`LeastSquares`] Jacobian as `aᵢᵀ ∂X_p/∂θ`: the Jacobian of
/// one posed point `p` times a 3-vector, the robust folding and weights included (`aᵢ = 0` for
/// an unseen row). [`LeastSquares::normal_equations`] adds each point's rows as one
/// `∂X_pᵀ (Σ aᵢaᵢᵀ) ∂X_p`.
#[derive(Debug, Clone, PartialEq)]
pub struct PointFactors {
    /// Each point's `3 × dim` Jacobian, row-major, one after the other.
    pub points: Vec<f64>,
    /// Per data row: its point and `a`.
    pub rows: Vec<(usize, [f64; 3])>,
}

/// Which rows of the Jacobian [`Energy::least_squares_with`] writes densely.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum JacobianRows {
    /// Every row, `dim` wide ([`LeastSquares::jacobian`]; the factored form as well, where the
    /// observation model has one).
    #[default]
    Dense,
    /// Data rows that have a factored form only in that form ([`LeastSquares::points`],
    /// [`LeastSquares::dense_from`]), and rows with one nonzero (joint limits, pose, shape and
    /// expression priors) as that entry ([`LeastSquares::singles`]): what the normal equations
    /// and the gradient read, without writing `rows × dim` entries (keypoints2d: 372 × 112
    /// data rows, and 106 prior rows on every sensor, on the MakeHuman body).
    /// Levenberg–Marquardt, the neural fitter's Gauss-Newton direction and the sequence β
    /// solve ask for this.
    Factored,
}

/// How the robust loss enters the least-squares form of the data term.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum RobustForm {
    /// Folded: the group residual `u` becomes `φ(s) u` with `φ = √ρ(s)/s`, with the exact
    /// Jacobian of the folded residual, so `E = Σ r²` holds literally (what external solvers and
    /// `lfit objective-server` see).
    #[default]
    Folded,
    /// Triggs's correction (Triggs et al. 2000, "Bundle adjustment — a modern synthesis" §4.3,
    /// as Ceres's `Corrector`): with `z = s²` and `ρ̂(z) = ρ(√z)`, the residual and its Jacobian
    /// are scaled by `√ρ̂'(z)` and corrected by `α = 1 − √(1 + 2zρ̂''/ρ̂')` along `u`. For every
    /// loss here `ρ̂'' ≤ 0`, where Ceres sets `α = 0`: the correction is then the IRLS weighting
    /// `√ρ̂'(z)` of residual and Jacobian. `Σ r²` is the IRLS model, not E; the gradient
    /// `2 Jᵀr` is E's exactly. Solvers measure progress with [`LeastSquares::energy`].
    Triggs,
}

/// Marquardt's scaling `D` of the normal matrix `a` on the positions `free`: its diagonal clamped
/// to `[1e-6, 1e32]` (so metres, radians and shape coefficients need no hand-set scales), and the
/// largest entry, as [`damped_step`] takes them.
pub fn marquardt_scaling(a: &DMatrix<f64>, free: &[usize]) -> (Vec<f64>, f64) {
    let diag: Vec<f64> = free.iter().map(|&p| a[(p, p)].clamp(1e-6, 1e32)).collect();
    let max_diag = diag.iter().fold(0.0f64, |s, v| s.max(*v));
    (diag, max_diag)
}

/// The step of one damped Gauss-Newton system on the entries `free` (positions in `a` and `g`):
/// `(A + μ D + 1e-12 max(D) I) h = −g` with `A = JᵀJ`, `g = Jᵀr`, `D = diag` (Marquardt's
/// scaling) and `μ = damping` (0: Gauss-Newton), by Cholesky in envelope form
/// ([`DampedFactor`]); `None` when the system is not positive definite. `h[k]` is the
/// step of entry `free[k]`; listing `free` in the model's elimination order
/// ([`crate::Template::elimination_rank`]: children before parents, then the entries every row
/// shares) makes the factorisation cost what the Jacobian's tree structure needs, not `m³/6`.
/// Levenberg–Marquardt's parameter update given the residuals and the Jacobian (papers/002
/// compares its cost with the neural update's, Table 7), and the neural fitter's Gauss-Newton
/// direction ([`LeastSquares::damped_gauss_newton`]).
pub fn damped_step(
    a: &DMatrix<f64>,
    g: &DVector<f64>,
    free: &[usize],
    diag: &[f64],
    damping: f64,
    max_diag: f64,
) -> Option<DVector<f64>> {
    let factor = DampedFactor::new(a, free, diag, damping, max_diag)?;
    let mut h: Vec<f64> = free.iter().map(|&p| -g[p]).collect();
    factor.solve(&mut h).then(|| DVector::from_vec(h))
}

/// The damped system of [`damped_step`] on the entries `free`, `A + μ D + 1e-12 max(D) I` in
/// their order ([`Envelope::damped`]), factorised once for every right-hand side a solve needs:
/// `−g` ([`damped_step`]), the columns of Levenberg–Marquardt's box step, the sequence β solve's
/// Schur complement.
#[derive(Debug, Clone)]
pub struct DampedFactor {
    factor: Envelope,
}

impl DampedFactor {
    /// `None` when the damped system is not positive definite.
    pub fn new(
        a: &DMatrix<f64>,
        free: &[usize],
        diag: &[f64],
        damping: f64,
        max_diag: f64,
    ) -> Option<Self> {
        let mut factor = Envelope::damped(a, free, diag, damping, max_diag);
        factor.factorise().then_some(Self { factor })
    }

    /// `b` becomes the system's inverse times `b` ([`Envelope::solve`]); false when that is not
    /// finite.
    pub fn solve(&self, b: &mut [f64]) -> bool {
        self.factor.solve(b);
        b.iter().all(|v| v.is_finite())
    }
}

/// The damped Gauss-Newton system of one point, factorised
/// ([`LeastSquares::damped_gauss_newton_chord`]), for the steps of later points: the neural
/// fitter's chord direction (`lfit_nn::Direction::GaussNewtonChord`), which pays the Jacobian,
/// the normal equations and the factorisation once per frame and a gradient and two triangular
/// solves at every later iterate.
#[derive(Debug, Clone)]
pub struct ChordSystem {
    factor: DampedFactor,
    /// The parameter entries of the factor's rows, in its (elimination) order.
    entries: Vec<usize>,
    dim: usize,
}

impl ChordSystem {
    /// `h` with `(A₀ + μ D₀) h = −∇E/2` over the system's entries (`A₀ = JᵀJ`, `D₀` its
    /// Marquardt scaling, both of the point the system was factorised at; `∇E/2 = Jᵀr` at the
    /// point now), zero elsewhere; `None` for a gradient of another length or a step that is
    /// not finite.
    pub fn step(&self, gradient: &[f64]) -> Option<Vec<f64>> {
        if gradient.len() != self.dim {
            return None;
        }
        self.solve(|e| 0.5 * gradient[self.entries[e]])
    }

    /// The parameter entries the system spans, in its order.
    pub fn entries(&self) -> &[usize] {
        &self.entries
    }

    /// `h = −S⁻¹ g` for `g[e] = half_gradient(e)` over the factor's rows, as a full vector.
    fn solve(&self, half_gradient: impl Fn(usize) -> f64) -> Option<Vec<f64>> {
        let mut h: Vec<f64> = (0..self.entries.len()).map(|e| -half_gradient(e)).collect();
        if !self.factor.solve(&mut h) {
            return None;
        }
        let mut out = vec![0.0; self.dim];
        for (&p, v) in self.entries.iter().zip(h) {
            out[p] = v;
        }
        Some(out)
    }
}

/// The lower triangle of a symmetric `m × m` matrix in envelope (profile) storage, and its
/// Cholesky factorisation in place (Jennings's profile method; George & Liu, *Computer Solution
/// of Large Sparse Positive Definite Systems*, 1981, ch. 4): row `i` is stored from its first
/// nonzero column `first[i]` to the diagonal, and the factor `L` has no entry before it, so a
/// row whose earlier entries are zero costs nothing there, in work ([`envelope_work`] counts it)
/// or memory. On a normal matrix `JᵀJ` ordered children before parents the rows of a joint's
/// rotation reach back only to its own subtree: no fill, a fraction of the dense
/// factorisation's work, and about a third of the dense triangle's memory on the MakeHuman body
/// (one of these is kept per frame by the chord direction, [`ChordSystem`]).
#[derive(Debug, Clone)]
pub struct Envelope {
    /// Row `i`'s entries, columns `first[i]..=i`, at `start[i]..start[i + 1]`.
    values: Vec<f64>,
    first: Vec<usize>,
    start: Vec<usize>,
}

impl Envelope {
    /// The lower triangle of an `m × m` matrix, row `r`'s entries `0..=r` written by
    /// `row(r, buffer)` (the upper triangle is not read); a row's envelope starts at its first
    /// nonzero entry before the diagonal.
    pub fn from_lower(m: usize, mut row: impl FnMut(usize, &mut [f64])) -> Self {
        // The whole triangle reserved (not touched), the rest given back at the end: no
        // reallocation on the way.
        let mut values = Vec::with_capacity(m * (m + 1) / 2);
        let mut first = Vec::with_capacity(m);
        let mut start = Vec::with_capacity(m + 1);
        let mut buffer = vec![0.0; m];
        for r in 0..m {
            let entries = &mut buffer[..=r];
            row(r, entries);
            let f = entries[..r].iter().position(|&v| v != 0.0).unwrap_or(r);
            start.push(values.len());
            first.push(f);
            values.extend_from_slice(&entries[f..]);
        }
        values.shrink_to_fit();
        start.push(values.len());
        Self {
            values,
            first,
            start,
        }
    }

    /// `S = A + μ D + 1e-12 max(D) I` on the entries `free` of the symmetric `a` (in their order),
    /// `D = diag` ([`marquardt_scaling`]) and `μ = damping`: [`damped_step`]'s system.
    pub fn damped(
        a: &DMatrix<f64>,
        free: &[usize],
        diag: &[f64],
        damping: f64,
        max_diag: f64,
    ) -> Self {
        Self::from_lower(free.len(), |r, entries| {
            // Column free[r] of the symmetric a: contiguous.
            let column = a.column(free[r]);
            for (e, &pc) in entries.iter_mut().zip(free) {
                *e = column[pc];
            }
            entries[r] += damping * diag[r] + 1e-12 * max_diag;
        })
    }

    /// The matrix's order `m`.
    pub fn order(&self) -> usize {
        self.first.len()
    }

    /// The entries stored (the envelope's size; the dense triangle has `m(m+1)/2`).
    pub fn stored(&self) -> usize {
        self.values.len()
    }

    /// Overwrites the matrix with its Cholesky factor `L` (`S = L Lᵀ`), column by column (the
    /// entries of one column are independent of each other, so their dot products overlap in
    /// the pipeline; row by row each waits on the one before). False (leaving the values
    /// undefined) when a pivot is not positive and finite: `S` is not positive definite.
    pub fn factorise(&mut self) -> bool {
        let m = self.order();
        for j in 0..m {
            let fj = self.first[j];
            let (head, tail) = self.values.split_at_mut(self.start[j + 1]);
            let lj = &mut head[self.start[j]..];
            let (below, diagonal) = lj.split_at_mut(j - fj);
            let d = diagonal[0] - dot(below, below);
            if !(d > 0.0 && d.is_finite()) {
                return false;
            }
            diagonal[0] = d.sqrt();
            let inv = 1.0 / diagonal[0];
            let lj: &[f64] = below;
            let offset = self.start[j + 1];
            for i in j + 1..m {
                let fi = self.first[i];
                if fi > j {
                    continue;
                }
                let k0 = fi.max(fj);
                let row = &mut tail[self.start[i] - offset..self.start[i + 1] - offset];
                row[j - fi] = (row[j - fi] - dot(&row[k0 - fi..j - fi], &lj[k0 - fj..])) * inv;
            }
        }
        true
    }

    /// Solves `L Lᵀ x = b` with the factor [`Envelope::factorise`] left; `b` becomes `x`.
    pub fn solve(&self, b: &mut [f64]) {
        let m = self.order();
        debug_assert_eq!(b.len(), m);
        // L y = b, then Lᵀ x = y.
        for i in 0..m {
            let (row, fi) = (
                &self.values[self.start[i]..self.start[i + 1]],
                self.first[i],
            );
            b[i] = (b[i] - dot(&row[..i - fi], &b[fi..i])) / row[i - fi];
        }
        for i in (0..m).rev() {
            let (row, fi) = (
                &self.values[self.start[i]..self.start[i + 1]],
                self.first[i],
            );
            let x = b[i] / row[i - fi];
            b[i] = x;
            for (bk, lk) in b[fi..i].iter_mut().zip(&row[..i - fi]) {
                *bk -= lk * x;
            }
        }
    }
}

/// Solves `S x = b` for a symmetric positive definite `S` (`m × m`, row-major; only the lower
/// triangle is read) by the Cholesky factorisation of its envelope ([`Envelope`]); `b` becomes
/// `x`. Returns false (leaving `b` undefined) when `S` is not positive definite.
pub fn envelope_cholesky_solve(s: &[f64], m: usize, b: &mut [f64]) -> bool {
    debug_assert!(s.len() == m * m && b.len() == m);
    let mut factor = Envelope::from_lower(m, |r, row| row.copy_from_slice(&s[r * m..=r * m + r]));
    if !factor.factorise() {
        return false;
    }
    factor.solve(b);
    b.iter().all(|v| v.is_finite())
}

/// The multiply-adds [`envelope_cholesky_solve`] does on the symmetric `a` with its entries
/// taken in `order`: `(factorisation, the two triangular solves)`. Row `i` reaches back to its
/// first nonzero `first[i]`; its entry at column `j` costs the overlap of rows `i` and `j`
/// before `j`, plus one. The cost model's count (`cargo bench -p lfit-model --bench energy`).
pub fn envelope_work(a: &DMatrix<f64>, order: &[usize]) -> (usize, usize) {
    let n = order.len();
    let first: Vec<usize> = (0..n)
        .map(|r| {
            (0..r)
                .find(|&c| a[(order[r], order[c])] != 0.0)
                .unwrap_or(r)
        })
        .collect();
    let factor = (0..n)
        .map(|i| {
            (first[i]..i)
                .map(|j| j - first[i].max(first[j]) + 1)
                .sum::<usize>()
        })
        .sum();
    (factor, 2 * (0..n).map(|i| i - first[i] + 1).sum::<usize>())
}

/// `Σ x_k y_k` over four lanes (so the compiler vectorises it).
fn dot(x: &[f64], y: &[f64]) -> f64 {
    if x.len() < 8 {
        return x.iter().zip(y).map(|(a, b)| a * b).sum();
    }
    let mut acc = [0.0; 4];
    let (xc, yc) = (x.chunks_exact(4), y.chunks_exact(4));
    let (xr, yr) = (xc.remainder(), yc.remainder());
    for (a, b) in xc.zip(yc) {
        for l in 0..4 {
            acc[l] += a[l] * b[l];
        }
    }
    let mut tail = 0.0;
    for (a, b) in xr.iter().zip(yr) {
        tail += a * b;
    }
    (acc[0] + acc[2]) + (acc[1] + acc[3]) + tail
}

impl LeastSquares {
    /// `Σ r²`: the energy.
    pub fn value(&self) -> f64 {
        self.residuals.iter().map(|r| r * r).sum()
    }

    /// Row `i` of the Jacobian, for `dense_from ≤ i < dense_to` ([`LeastSquares::dense`] has
    /// every row).
    pub fn row(&self, i: usize) -> &[f64] {
        let k = i - self.dense_from;
        &self.jacobian[k * self.dim..(k + 1) * self.dim]
    }

    /// Whether every row is in `jacobian` ([`JacobianRows::Dense`]).
    pub fn is_dense(&self) -> bool {
        self.dense_from == 0 && self.dense_to == self.residuals.len()
    }

    /// Whether the Jacobian was asked for (in either form: a factored one may hold no dense
    /// row at all).
    pub fn has_jacobian(&self) -> bool {
        !self.jacobian.is_empty() || self.dense_from > 0 || !self.singles.is_empty()
    }

    /// These residuals with every Jacobian row dense: the factored-only data rows
    /// ([`JacobianRows::Factored`]) expanded, the same numbers [`JacobianRows::Dense`] writes.
    pub fn dense(&self) -> LeastSquares {
        let mut out = self.clone();
        if !self.has_jacobian() || self.is_dense() {
            return out;
        }
        let dim = self.dim;
        let mut jacobian = vec![0.0; self.residuals.len() * dim];
        if let Some(f) = &self.points {
            let p = self.dense_from;
            expand_point_factors(&f.points, &f.rows[..p], dim, &mut jacobian[..p * dim]);
        }
        jacobian[self.dense_from * dim..self.dense_to * dim].copy_from_slice(&self.jacobian);
        for (k, &(c, v)) in self.singles.iter().enumerate() {
            jacobian[(self.dense_to + k) * dim + c] = v;
        }
        out.jacobian = jacobian;
        out.dense_from = 0;
        out.dense_to = self.residuals.len();
        out.singles.clear();
        out
    }

    /// The Gauss-Newton normal equations `(JᵀJ, Jᵀr)` over the columns `dofs` (in their order),
    /// skipping zero rows and entries (a row of a skinned point is zero outside its joint chain;
    /// most penetration rows are zero). `∇E = 2 Jᵀr`. Empty without a Jacobian.
    ///
    /// Consecutive rows with the same nonzero columns (the x, y, z rows of one marker, the u, v
    /// rows of one keypoint) are applied together, up to three at a time: one scattered update of
    /// `JᵀJ` per pair of columns instead of one per row. Every entry still sums the rows in
    /// order, so the result is bit for bit [`LeastSquares::normal_equations_by_row`]'s — but for
    /// the [`LeastSquares::constant_gram`] rows (a pose prior's), whose precomputed block is
    /// added instead of their products (equal to rounding).
    pub fn normal_equations(&self, dofs: &[usize]) -> (DMatrix<f64>, DVector<f64>) {
        let n = dofs.len();
        let position = self.positions(dofs);
        let mut upper = vec![0.0; n * n];
        let mut g = DVector::<f64>::zeros(n);
        // The group: its positions, its rows' values interleaved (`values[3k + r]`: row r of the
        // group at its k-th position) and residuals.
        let mut group: Vec<usize> = Vec::with_capacity(self.dim);
        let mut values = vec![0.0; 3 * self.dim];
        let mut residuals = [0.0; 3];
        let mut rows = 0usize;
        let mut next: Vec<(usize, f64)> = vec![(0, 0.0); self.dim + 1];
        // The open group's columns, and which columns are free.
        let mut columns: Vec<usize> = Vec::with_capacity(self.dim);
        let free: Vec<bool> = position.iter().map(|&p| p != usize::MAX).collect();
        // Rows in factored form first: one 3-row update per point.
        let factored = match &self.points {
            Some(f) if self.has_jacobian() => {
                self.accumulate_points(f, &position, &mut upper, &mut g, n);
                f.rows.len()
            }
            _ => 0,
        };
        let constant = self.constant_gram.as_ref().map_or(0..0, |c| c.rows.clone());
        for (i, &r) in self.residuals[..self.dense_to]
            .iter()
            .enumerate()
            .skip(factored)
        {
            if self.zero_rows.get(i).copied().unwrap_or(false) || constant.contains(&i) {
                continue;
            }
            // A row with the open group's nonzero columns (as many free nonzeros, none of the
            // group's columns zero) joins it without compaction: the values compaction would give.
            if rows > 0 && rows < 3 && columns.first().is_some_and(|&c| self.row(i)[c] != 0.0) {
                let row = self.row(i);
                let count: usize = row
                    .iter()
                    .zip(&free)
                    .map(|(&v, &f)| usize::from((v != 0.0) & f))
                    .sum();
                if count == columns.len() && columns.iter().all(|&c| row[c] != 0.0) {
                    for (k, &c) in columns.iter().enumerate() {
                        values[3 * k + rows] = row[c];
                    }
                    residuals[rows] = r;
                    rows += 1;
                    continue;
                }
            }
            let len = self.compact(i, &position, &mut next);
            let nz = &next[..len];
            let same = rows > 0
                && rows < 3
                && len == group.len()
                && nz.iter().zip(&group).all(|(e, &p)| e.0 == p);
            if !same {
                accumulate(&mut upper, &mut g, n, &group, &values, &residuals[..rows]);
                group.clear();
                group.extend(nz.iter().map(|e| e.0));
                columns.clear();
                columns.extend(group.iter().map(|&p| dofs[p]));
                rows = 0;
            }
            for (k, e) in nz.iter().enumerate() {
                values[3 * k + rows] = e.1;
            }
            residuals[rows] = r;
            rows += 1;
        }
        accumulate(&mut upper, &mut g, n, &group, &values, &residuals[..rows]);
        // The constant block: its precomputed JᵀJ, and Jᵀr from its rows.
        if let Some(c) = &self.constant_gram {
            let m = c.gram.len().isqrt();
            let at: Vec<usize> = (c.first..c.first + m).map(|col| position[col]).collect();
            for (a, &pa) in at.iter().enumerate() {
                if pa == usize::MAX {
                    continue;
                }
                for (b, &pb) in at.iter().enumerate() {
                    if pb != usize::MAX && pa <= pb {
                        upper[pa * n + pb] += c.scale * c.gram[a * m + b];
                    }
                }
            }
            for i in c.rows.clone() {
                let r = self.residuals[i];
                for (&v, &pa) in self.row(i)[c.first..c.first + m].iter().zip(&at) {
                    if v != 0.0 && pa != usize::MAX {
                        g[pa] += v * r;
                    }
                }
            }
        }
        // Rows with one entry, as their dense rows would add it.
        for (k, (&(c, v), &r)) in self
            .singles
            .iter()
            .zip(&self.residuals[self.dense_to..])
            .enumerate()
        {
            let p = position[c];
            if v == 0.0 || p == usize::MAX || self.zero_rows[self.dense_to + k] {
                continue;
            }
            g[p] += v * r;
            upper[p * n + p] += v * v;
        }
        (mirror(upper, n), g)
    }

    /// Adds the factored rows ([`PointFactors`]) to `JᵀJ`'s upper triangle and `Jᵀr`: per point
    /// `C = Σ aᵢaᵢᵀ` and `b = Σ aᵢrᵢ` over its rows that are not zero, then
    /// `JᵀJ[α][β] += ∂X_αᵀ C ∂X_β` and `Jᵀr[α] += ∂X_αᵀ b` over the point's nonzero free columns
    /// (3 multiply-adds per pair of columns, where its k rows take k).
    fn accumulate_points(
        &self,
        f: &PointFactors,
        position: &[usize],
        upper: &mut [f64],
        g: &mut DVector<f64>,
        n: usize,
    ) {
        let dim = self.dim;
        let count = f.points.len() / (3 * dim);
        let mut c = vec![[0.0f64; 9]; count];
        let mut b = vec![[0.0f64; 3]; count];
        let mut seen = vec![false; count];
        for (i, &(p, a)) in f.rows.iter().enumerate() {
            if self.zero_rows.get(i).copied().unwrap_or(false) {
                continue;
            }
            let r = self.residuals[i];
            seen[p] = true;
            for x in 0..3 {
                b[p][x] += a[x] * r;
                for y in 0..3 {
                    c[p][3 * x + y] += a[x] * a[y];
                }
            }
        }
        // The point's free nonzero columns: position, ∂X column, C ∂X column.
        let mut columns: Vec<(usize, [f64; 3], [f64; 3])> = Vec::with_capacity(dim);
        let mut positions: Vec<usize> = Vec::with_capacity(dim);
        let mut v: [Vec<f64>; 3] = std::array::from_fn(|_| Vec::with_capacity(dim));
        let mut terms = vec![0.0; dim];
        for p in (0..count).filter(|&p| seen[p]) {
            let jp = &f.points[3 * p * dim..3 * (p + 1) * dim];
            let cp = &c[p];
            columns.clear();
            for col in 0..dim {
                let v = [jp[col], jp[dim + col], jp[2 * dim + col]];
                let q = position[col];
                if q == usize::MAX || v == [0.0; 3] {
                    continue;
                }
                let w = [
                    cp[0] * v[0] + cp[1] * v[1] + cp[2] * v[2],
                    cp[3] * v[0] + cp[4] * v[1] + cp[5] * v[2],
                    cp[6] * v[0] + cp[7] * v[1] + cp[8] * v[2],
                ];
                columns.push((q, v, w));
            }
            if !columns.is_sorted_by_key(|e| e.0) {
                columns.sort_unstable_by_key(|e| e.0);
            }
            // ∂X's rows apart (contiguous, so that the terms below vectorise), then per column
            // k the terms of its row, `w_k · v_m` for m ≥ k, added to `JᵀJ` at their positions:
            // each entry gets the same rounded term as one product at a time gave it.
            let len = columns.len();
            positions.clear();
            positions.extend(columns.iter().map(|e| e.0));
            for (x, vx) in v.iter_mut().enumerate() {
                vx.clear();
                vx.extend(columns.iter().map(|e| e.1[x]));
            }
            let bp = b[p];
            for (k, &(qa, va, wa)) in columns.iter().enumerate() {
                g[qa] += va[0] * bp[0] + va[1] * bp[1] + va[2] * bp[2];
                let terms = &mut terms[..len - k];
                for (t, ((v0, v1), v2)) in terms
                    .iter_mut()
                    .zip(v[0][k..].iter().zip(&v[1][k..]).zip(&v[2][k..]))
                {
                    *t = wa[0] * v0 + wa[1] * v1 + wa[2] * v2;
                }
                let row = &mut upper[qa * n..(qa + 1) * n];
                for (&t, &qb) in terms.iter().zip(&positions[k..]) {
                    row[qb] += t;
                }
            }
        }
    }

    /// [`LeastSquares::normal_equations`] one row at a time: the reference it is tested against
    /// and benchmarked with (`cargo bench -p lfit-model --bench energy`).
    pub fn normal_equations_by_row(&self, dofs: &[usize]) -> (DMatrix<f64>, DVector<f64>) {
        if !self.is_dense() {
            return self.dense().normal_equations_by_row(dofs);
        }
        let n = dofs.len();
        let position = self.positions(dofs);
        let mut upper = vec![0.0; n * n];
        let mut g = DVector::<f64>::zeros(n);
        let mut buffer: Vec<(usize, f64)> = vec![(0, 0.0); self.dim + 1];
        for (i, &r) in self.residuals.iter().enumerate() {
            if self.zero_rows.get(i).copied().unwrap_or(false) {
                continue;
            }
            let len = self.compact(i, &position, &mut buffer);
            let nz = &buffer[..len];
            for (k, &(p, vp)) in nz.iter().enumerate() {
                g[p] += vp * r;
                let row = &mut upper[p * n..(p + 1) * n];
                for &(q, vq) in &nz[k..] {
                    row[q] += vp * vq;
                }
            }
        }
        (mirror(upper, n), g)
    }

    /// Column → position among the free entries `dofs` (usize::MAX: held).
    fn positions(&self, dofs: &[usize]) -> Vec<usize> {
        let mut position = vec![usize::MAX; self.dim];
        for (p, &c) in dofs.iter().enumerate() {
            position[c] = p;
        }
        position
    }

    /// Row `i`'s free nonzero entries as `(position, value)` in ascending positions, into
    /// `buffer` (at least `dim + 1` long); returns how many.
    fn compact(&self, i: usize, position: &[usize], buffer: &mut [(usize, f64)]) -> usize {
        // Branch-free compaction, skipping runs of eight zeros (a skinned point's row is zero
        // outside its joints' chain).
        let row = self.row(i);
        let mut len = 0;
        let mut c0 = 0;
        for chunk in row.chunks(8) {
            if chunk.iter().fold(0u32, |z, &v| z | u32::from(v != 0.0)) != 0 {
                for (k, &v) in chunk.iter().enumerate() {
                    let p = position[c0 + k];
                    buffer[len] = (p, v);
                    len += usize::from((v != 0.0) & (p != usize::MAX));
                }
            }
            c0 += chunk.len();
        }
        let nz = &mut buffer[..len];
        // Positions ascend with columns when `dofs` is sorted; sort otherwise.
        if !nz.is_sorted_by_key(|e| e.0) {
            nz.sort_unstable_by_key(|e| e.0);
        }
        len
    }

    /// The Marquardt-damped Gauss-Newton step over the entries `dofs`: `h` with
    /// `(JᵀJ + μ D) h = −Jᵀr`, `D = diag(JᵀJ)` clamped to `[1e-6, 1e32]` as Levenberg–Marquardt
    /// scales it ([`damped_step`]), as a full parameter vector (zero outside `dofs`); `θ + h`
    /// minimises the damped quadratic model of E. `None` without a Jacobian or when the system
    /// is not positive definite. The system is solved in the order `rank` gives the entries
    /// ([`crate::Template::elimination_rank`] of the energy's model; any order gives the same
    /// step up to rounding). The neural fitter's Gauss-Newton direction
    /// (`lfit_nn::Direction::GaussNewton`).
    pub fn damped_gauss_newton(
        &self,
        dofs: &[usize],
        damping: f64,
        rank: &[usize],
    ) -> Option<Vec<f64>> {
        self.damped_gauss_newton_chord(dofs, damping, rank)
            .map(|(h, _)| h)
    }

    /// [`LeastSquares::damped_gauss_newton`] and its factorised damped system, kept for the
    /// steps of later points ([`ChordSystem::step`]: the chord method, which solves the system
    /// of the first point with each later point's gradient; Kelley, *Iterative Methods for
    /// Linear and Nonlinear Equations*, SIAM 1995, ch. 5). The step is
    /// [`LeastSquares::damped_gauss_newton`]'s to the bit.
    pub fn damped_gauss_newton_chord(
        &self,
        dofs: &[usize],
        damping: f64,
        rank: &[usize],
    ) -> Option<(Vec<f64>, ChordSystem)> {
        if !self.has_jacobian() {
            return None;
        }
        let (a, g) = self.normal_equations(dofs);
        let mut free: Vec<usize> = (0..dofs.len()).collect();
        free.sort_by_key(|&p| rank.get(dofs[p]).copied().unwrap_or(usize::MAX));
        let (diag, max_diag) = marquardt_scaling(&a, &free);
        let factor = DampedFactor::new(&a, &free, &diag, damping, max_diag)?;
        let system = ChordSystem {
            factor,
            entries: free.iter().map(|&p| dofs[p]).collect(),
            dim: self.dim,
        };
        let h = system.solve(|e| g[free[e]])?;
        Some((h, system))
    }

    /// `∇E = 2 Jᵀ r` (empty without a Jacobian).
    pub fn gradient(&self) -> Vec<f64> {
        if !self.has_jacobian() {
            return Vec::new();
        }
        let mut g = vec![0.0; self.dim];
        let dim = self.dim;
        if let (Some(f), true) = (&self.points, self.dense_from > 0) {
            // 2 r aᵀ ∂X, as [`expand_point_factors`] forms the row.
            for (&(p, a), &r) in f.rows.iter().zip(&self.residuals) {
                if r != 0.0 {
                    let jp = &f.points[3 * p * dim..3 * (p + 1) * dim];
                    for (c, gi) in g.iter_mut().enumerate() {
                        *gi +=
                            2.0 * r * (a[0] * jp[c] + a[1] * jp[dim + c] + a[2] * jp[2 * dim + c]);
                    }
                }
            }
        }
        for (i, &r) in self.residuals[..self.dense_to]
            .iter()
            .enumerate()
            .skip(self.dense_from)
        {
            if r != 0.0 {
                for (gi, j) in g.iter_mut().zip(self.row(i)) {
                    *gi += 2.0 * r * j;
                }
            }
        }
        for (&(c, v), &r) in self.singles.iter().zip(&self.residuals[self.dense_to..]) {
            g[c] += 2.0 * r * v;
        }
        g
    }
}

/// Adds the rows of one group (positions `group`, values interleaved `values[rows·k + r]` with
/// stride 3, residuals `residuals`, 0–3 rows) to the upper triangle of `JᵀJ` (row-major, `n`
/// wide) and to `Jᵀr`, each entry summing the rows in order.
fn accumulate(
    upper: &mut [f64],
    g: &mut DVector<f64>,
    n: usize,
    group: &[usize],
    values: &[f64],
    residuals: &[f64],
) {
    match residuals.len() {
        0 => {}
        1 => accumulate_rows::<1>(upper, g, n, group, values, residuals),
        2 => accumulate_rows::<2>(upper, g, n, group, values, residuals),
        _ => accumulate_rows::<3>(upper, g, n, group, values, residuals),
    }
}

fn accumulate_rows<const R: usize>(
    upper: &mut [f64],
    g: &mut DVector<f64>,
    n: usize,
    group: &[usize],
    values: &[f64],
    residuals: &[f64],
) {
    for (k, &p) in group.iter().enumerate() {
        let vp = &values[3 * k..3 * k + R];
        let mut gp = g[p];
        for r in 0..R {
            gp += vp[r] * residuals[r];
        }
        g[p] = gp;
        let row = &mut upper[p * n..(p + 1) * n];
        for (l, &q) in group.iter().enumerate().skip(k) {
            let vq = &values[3 * l..3 * l + R];
            let mut acc = row[q];
            for r in 0..R {
                acc += vp[r] * vq[r];
            }
            row[q] = acc;
        }
    }
}

/// The symmetric matrix of an upper triangle stored row-major (read column-major, the same
/// numbers are the lower triangle, copied up in place).
fn mirror(upper: Vec<f64>, n: usize) -> DMatrix<f64> {
    let mut m = DMatrix::<f64>::from_vec(n, n, upper);
    m.fill_upper_triangle_with_lower_triangle();
    m
}

impl Energy {
    /// Why this energy has no least-squares form, or `None` when it has one: `scan` (ED is the
    /// root of a mean, papers/000 eq. 4), the silhouette term EJ (no gradient) and the binary
    /// joint-angle prior (piecewise constant) have none.
    pub fn least_squares_unsupported(&self) -> Option<String> {
        if let Some(why) = self.gradient_unsupported() {
            return Some(why);
        }
        if matches!(self.sensor, Sensor::Scan(_)) {
            return Some("the scan energy is not a sum of squares (ED is a root mean square, papers/000 eq. 4; EJ has no gradient): use a zeroth-order method or L-BFGS".into());
        }
        if self.config.angle_prior != AnglePrior::Hinge {
            return Some("the binary joint-angle prior (papers/000 eq. 7) is not a sum of squares: use the hinge form (the gradient variant of the energy)".into());
        }
        None
    }

    /// Number of residuals of [`Energy::least_squares`] (fixed for an energy).
    pub fn residual_count(&self) -> usize {
        let data = match &self.target {
            Target::Sparse { values, .. } => values.len(),
            Target::Scan { .. } | Target::Silhouettes { .. } => 0,
        };
        let pose_end = self.limits.lower.len();
        data + self.penetration_rows()
            + self.pose_prior_len()
            + pose_end.saturating_sub(rot_offset(1))
            + self.rotation_prior_rows().len()
            + self.template.morph.coefficients()
            + self.anchor.as_ref().map_or(0, |a| a.rows().len())
            + self.height_rows()
            + self.floor_rows()
    }

    /// The floor's row ([`Energy::with_floor`]): one or none.
    fn floor_rows(&self) -> usize {
        usize::from(self.floor.is_some())
    }

    /// The height prior's row ([`Energy::with_height_prior`]): one or none.
    fn height_rows(&self) -> usize {
        usize::from(self.height.is_some())
    }

    /// EP's rows: one per tested vertex (vertex form) or per tested pair of capsules.
    fn penetration_rows(&self) -> usize {
        match self.config.penetration {
            PenetrationForm::Vertices => self.penetration.tests.len(),
            PenetrationForm::Capsules => self.capsules.rows(),
        }
    }

    /// Rows of the pose prior ([`crate::energy::PosePrior::rows`]) when the configuration
    /// carries one. Dense (written beside EP's, before EA's).
    fn pose_prior_len(&self) -> usize {
        self.config.pose_prior.as_ref().map_or(0, |p| p.rows())
    }

    /// Parameters of the rotation prior's residual rows (papers/002 eq. 9's `w_θ‖θ‖²`): every
    /// rotation entry when its weight is positive, none otherwise.
    fn rotation_prior_rows(&self) -> std::ops::Range<usize> {
        if self.config.weights.pose > 0.0 {
            3..3 + 3 * self.template.rig.num_joints()
        } else {
            0..0
        }
    }

    /// Residuals `r` with `E = Σ r²` and, when `with_jacobian`, their exact Jacobian; counts one
    /// evaluation (and one gradient evaluation with the Jacobian). Fails with
    /// [`Energy::least_squares_unsupported`]'s reason or on a parameter vector of the wrong length.
    pub fn least_squares(&self, params: &[f64], with_jacobian: bool) -> Result<LeastSquares> {
        self.least_squares_in(params, with_jacobian, RobustForm::Folded)
    }

    /// [`Energy::least_squares`] with the robust loss in the given form.
    pub fn least_squares_in(
        &self,
        params: &[f64],
        with_jacobian: bool,
        form: RobustForm,
    ) -> Result<LeastSquares> {
        self.least_squares_with(params, with_jacobian, form, JacobianRows::Dense)
    }

    /// [`Energy::least_squares_in`] with the Jacobian's rows in the given form.
    pub fn least_squares_with(
        &self,
        params: &[f64],
        with_jacobian: bool,
        form: RobustForm,
        rows: JacobianRows,
    ) -> Result<LeastSquares> {
        self.check_least_squares(params)?;
        self.evaluations.fetch_add(1, Ordering::Relaxed);
        if with_jacobian {
            self.gradient_evaluations.fetch_add(1, Ordering::Relaxed);
        }
        Ok(self.compute_least_squares(params, with_jacobian, form, rows))
    }

    /// The residuals and Jacobian at a point whose residuals were just evaluated and counted
    /// ([`Energy::least_squares_in`] without the Jacobian): counts one gradient evaluation and
    /// no new evaluation. Levenberg–Marquardt evaluates its trial points without the Jacobian
    /// and asks for it only at the points it accepts.
    pub fn jacobian_in(&self, params: &[f64], form: RobustForm) -> Result<LeastSquares> {
        self.jacobian_with(params, form, JacobianRows::Dense)
    }

    /// [`Energy::jacobian_in`] with the Jacobian's rows in the given form.
    pub fn jacobian_with(
        &self,
        params: &[f64],
        form: RobustForm,
        rows: JacobianRows,
    ) -> Result<LeastSquares> {
        self.check_least_squares(params)?;
        self.gradient_evaluations.fetch_add(1, Ordering::Relaxed);
        Ok(self.compute_least_squares(params, true, form, rows))
    }

    /// How well the observations alone determine each parameter at `params`: the diagonal of the
    /// data term's Fisher information in σ-normalised units, `Σ_g Σ_k (∂pred_k/∂θ_j / σ_g)²` over
    /// the visible groups (the robust loss's folding included: an outlier beyond Huber's δ informs
    /// less). `1/√info_j` is the standard deviation to which the data fix entry `j` with every
    /// other entry held (conditional, not marginal); a parameter no observation moves has 0.
    /// Priors and joint limits are not included, so it exists for every prior form (the binary
    /// angle prior of the zeroth-order methods' energy too). Counts one evaluation with a
    /// Jacobian; fails for a dense sensor (scan, silhouettes: no per-observation rows) and a
    /// wrong-length vector.
    pub fn data_information(&self, params: &[f64]) -> Result<Vec<f64>> {
        if let Some(why) = self.gradient_unsupported() {
            return Err(ModelError::Target(why));
        }
        let Target::Sparse { visible, .. } = &self.target else {
            return Err(ModelError::Target(
                "the data information needs a sparse sensor (markers, keypoints, hmd, landmarks): a scan or silhouettes have no per-observation rows".into(),
            ));
        };
        self.check_length(params)?;
        let dim = self.dim();
        self.evaluations.fetch_add(1, Ordering::Relaxed);
        self.gradient_evaluations.fetch_add(1, Ordering::Relaxed);
        // The data rows do not depend on the prior's form (the EA rows are written as hinges).
        let ls = self.compute_least_squares(params, true, RobustForm::Folded, JacobianRows::Dense);
        let mut info = vec![0.0; dim];
        let seen = self.visible_groups(visible);
        let w = self.config.weights.data;
        if seen == 0 || w <= 0.0 {
            return Ok(info);
        }
        // The rows carry c0 = √(w / seen) (the data term is the mean over visible groups).
        let scale = seen as f64 / w;
        for (_, rows) in ls.blocks.iter().filter(|(name, _)| *name == "data") {
            for r in rows.clone() {
                for (i, j) in info.iter_mut().zip(ls.row(r)) {
                    *i += scale * j * j;
                }
            }
        }
        Ok(info)
    }

    fn check_least_squares(&self, params: &[f64]) -> Result<()> {
        if let Some(why) = self.least_squares_unsupported() {
            return Err(ModelError::Target(why));
        }
        self.check_length(params)
    }

    /// A parameter vector of the energy's length ([`Energy::dim`]).
    pub(crate) fn check_length(&self, params: &[f64]) -> Result<()> {
        let dim = self.dim();
        if params.len() != dim {
            return Err(ModelError::Shape {
                what: "parameter vector".into(),
                expected: dim.to_string(),
                got: params.len().to_string(),
            });
        }
        Ok(())
    }

    fn compute_least_squares(
        &self,
        params: &[f64],
        with_jacobian: bool,
        form: RobustForm,
        dense_rows: JacobianRows,
    ) -> LeastSquares {
        let m = self.residual_count();
        let dim = self.dim();
        let mut kin = Kinematics::build(&self.template, params, with_jacobian);
        if with_jacobian {
            kin.shape_vertices(&self.skin.rest, &self.observed);
        }
        let mut pj =
            with_jacobian.then(|| PointJacobians::new(&self.template, &kin, &self.skin, params));
        let mut residuals = vec![0.0; m];
        // Allocated once the data rows' form is known (`dense_from`). With factored rows, the
        // rows from the joint limits on are `singles`.
        let mut jacobian = Vec::new();
        let mut dense_from = 0;
        let factored = dense_rows == JacobianRows::Factored;
        let dense_to = match (&self.target, factored) {
            (Target::Sparse { values, .. }, true) if with_jacobian => {
                values.len()
                    + self.penetration_rows()
                    + self.pose_prior_len()
                    + self.height_rows()
                    + self.floor_rows()
            }
            _ => m,
        };
        let mut singles: Vec<(usize, f64)> = Vec::new();
        let w = self.config.weights;
        let mut blocks = Vec::with_capacity(5);
        let mut row = 0;
        // E's data part, Σ λ/n ρ(s_g), and the data rows (their squares are E's only when folded).
        let mut data_energy = 0.0;
        let mut data_rows = 0..0;
        let mut observation_residual = Vec::new();
        let mut points: Option<PointFactors> = None;

        // Data rows: the prediction's Jacobian is written into the block, then folded in place.
        if let Target::Sparse { values, visible } = &self.target {
            let model = self.observation_model();
            let p = values.len();
            let view = self.view(&kin);
            let pred = self.prediction(model, &view);
            observation_residual = Sensor::sparse_residual(&pred, values, visible);
            if let Some(pj) = pj.as_mut() {
                let mut jac = PoseJacobian {
                    inner: pj,
                    kin: &kin,
                };
                let mut f = PointFactors {
                    points: Vec::new(),
                    rows: Vec::new(),
                };
                if model.point_factors(&view, &mut jac, &mut f.points, &mut f.rows)
                    && f.rows.len() == p
                {
                    if factored {
                        dense_from = p;
                        jacobian = vec![0.0; (dense_to - p) * dim];
                    } else {
                        jacobian = vec![0.0; dense_to * dim];
                        expand_point_factors(&f.points, &f.rows, dim, &mut jacobian[..p * dim]);
                    }
                    points = Some(f);
                } else {
                    jacobian = vec![0.0; dense_to * dim];
                    model.jacobian(&view, &mut jac, &mut jacobian[..p * dim]);
                }
            }
            let seen = self.visible_groups(visible);
            let c0 = if seen > 0 {
                (w.data / seen as f64).sqrt()
            } else {
                0.0
            };
            let mut u = Vec::with_capacity(12);
            let mut v = vec![0.0; dim];
            data_rows = row..row + p;
            // The data rows written densely (none when only factored).
            let dense_data = with_jacobian && dense_from == 0;
            for g in &self.groups {
                let rows = g.start * dim..(g.start + g.len) * dim;
                if !visible[g.start] || c0 == 0.0 {
                    if dense_data {
                        jacobian[rows].fill(0.0);
                    }
                    if let Some(f) = points.as_mut() {
                        f.rows[g.start..g.start + g.len]
                            .iter_mut()
                            .for_each(|r| r.1 = [0.0; 3]);
                    }
                    continue;
                }
                u.clear();
                u.extend((g.start..g.start + g.len).map(|i| (pred[i] - values[i]) / g.sigma));
                let s = u.iter().map(|x| x * x).sum::<f64>().sqrt();
                let (rho, weight) = self.config.robust.eval(s);
                data_energy += c0 * c0 * rho;
                let (phi, dphi) = match form {
                    RobustForm::Folded => self.config.robust.fold(s),
                    // ρ̂'(z) = ρ'(s)/(2s); α = 0 (ρ̂'' ≤ 0 for every loss here).
                    RobustForm::Triggs => ((0.5 * weight).sqrt(), 0.0),
                };
                for (k, &uk) in u.iter().enumerate() {
                    residuals[row + g.start + k] = c0 * phi * uk;
                }
                // The Jacobian's 1/σ, one division per group.
                let inv_sigma = 1.0 / g.sigma;
                if dense_data {
                    // J̃ = c0 (φ Ju + (φ'/s) u (uᵀ Ju)), Ju = Jpred / σ.
                    let block = &mut jacobian[rows];
                    if dphi != 0.0 {
                        v.fill(0.0);
                        for (k, &uk) in u.iter().enumerate() {
                            for (vi, j) in v.iter_mut().zip(&block[k * dim..(k + 1) * dim]) {
                                *vi += uk * j * inv_sigma;
                            }
                        }
                        for (k, &uk) in u.iter().enumerate() {
                            for (d, vi) in block[k * dim..(k + 1) * dim].iter_mut().zip(&v) {
                                *d = c0 * (phi * *d * inv_sigma + dphi * uk * vi);
                            }
                        }
                    } else {
                        let f = c0 * phi * inv_sigma;
                        block.iter_mut().for_each(|d| *d *= f);
                    }
                }
                if with_jacobian {
                    // The same folding on the factors' vectors.
                    if let Some(f) = points.as_mut() {
                        let rows = &mut f.rows[g.start..g.start + g.len];
                        let mut va = [0.0; 3];
                        for (r, &uk) in rows.iter().zip(&u) {
                            for x in 0..3 {
                                va[x] += uk * r.1[x] * inv_sigma;
                            }
                        }
                        for (r, &uk) in rows.iter_mut().zip(&u) {
                            for x in 0..3 {
                                r.1[x] = c0 * (phi * r.1[x] * inv_sigma + dphi * uk * va[x]);
                            }
                        }
                    }
                }
            }
            blocks.push(("data", row..row + p));
            row += p;
        }

        if with_jacobian && dense_from == 0 && jacobian.len() != dense_to * dim {
            jacobian = vec![0.0; dense_to * dim];
        }
        // Rows below are written at `row * dim - off` (`jacobian` starts at row `dense_from`).
        let off = dense_from * dim;

        // EP rows.
        let tests = self.penetration_rows();
        if w.ep > 0.0 {
            let (r, j) = (
                &mut residuals[row..row + tests],
                if with_jacobian {
                    &mut jacobian[row * dim - off..(row + tests) * dim - off]
                } else {
                    &mut [][..]
                },
            );
            match self.config.penetration {
                PenetrationForm::Vertices => {
                    let c0 = (w.ep / self.penetration.count as f64).sqrt();
                    self.penetration
                        .residuals(&kin, &self.skin, pj.as_mut(), c0, r, j);
                }
                PenetrationForm::Capsules => {
                    let c0 = (w.ep * self.capsules.scale).sqrt();
                    self.capsules.residuals(&kin, pj.as_mut(), c0, r, j);
                }
            }
        }
        blocks.push(("EP", row..row + tests));
        row += tests;

        // The Gaussian pose prior's rows (dense: W is lower triangular over the rotations).
        // A mixture's last row is the active component's constant (no Jacobian).
        let mut constant_gram = None;
        if let Some(prior) = &self.config.pose_prior {
            let (n, rows) = (prior.len(), prior.rows());
            let c0 = w.pose_prior.sqrt();
            let k = prior.residuals(params, c0, &mut residuals[row..row + rows]);
            if with_jacobian {
                constant_gram = Some(ConstantGram {
                    rows: row..row + rows,
                    first: prior.entries().start,
                    gram: prior.components()[k].gram(),
                    scale: w.pose_prior,
                });
                let first = prior.entries().start;
                for a in 0..n {
                    let at = (row + a) * dim - off + first;
                    for (d, v) in jacobian[at..].iter_mut().zip(prior.jacobian_row(k, a)) {
                        *d = c0 * v;
                    }
                }
            }
            blocks.push(("pose-prior", row..row + rows));
            row += rows;
        }

        // The height prior's row (dense over the shape entries).
        if let Some(prior) = &self.height {
            let (h, g) = prior.measure(&self.template, params, with_jacobian);
            let c0 = self.height_weight(prior).sqrt();
            residuals[row] = c0 * (h - prior.height_m);
            let at = (row * dim + 3 + 3 * self.template.rig.num_joints()).wrapping_sub(off);
            for (i, gi) in g.iter().enumerate() {
                jacobian[at + i] = c0 * gi;
            }
            blocks.push(("height", row..row + 1));
            row += 1;
        }

        // The floor's row (dense: the lowest sole's height row, written only off the floor's
        // zero; Energy::with_floor).
        if let Some(floor) = &self.floor {
            let c0 = self.floor_weight(floor).sqrt();
            let out = if with_jacobian {
                &mut jacobian[row * dim - off..(row + 1) * dim - off]
            } else {
                &mut [][..]
            };
            residuals[row] = floor.residual(&kin, &self.skin, pj.as_mut(), c0, out);
            blocks.push(("floor", row..row + 1));
            row += 1;
        }

        // EA rows (hinge).
        let (lower, upper) = (&self.limits.lower, &self.limits.upper);
        let first = rot_offset(1);
        let ea_rows = lower.len().saturating_sub(first);
        let c0 = w.ea.sqrt();
        for (k, i) in (first..lower.len()).enumerate() {
            let over = (params[i] - upper[i]).max(0.0) - (lower[i] - params[i]).max(0.0);
            residuals[row + k] = c0 * over;
            if with_jacobian && row + k >= dense_to {
                singles.push((i, if over != 0.0 { c0 } else { 0.0 }));
            } else if with_jacobian && over != 0.0 {
                jacobian[(row + k) * dim + i - off] = c0;
            }
        }
        blocks.push(("EA", row..row + ea_rows));
        row += ea_rows;

        // The diagonal rows `c0 (θ_i − centre)`, one entry each: the Gaussian priors of the
        // rotations, shape and expression (centre 0), then the anchor (Energy::with_anchor).
        let mut diagonal =
            |name: &'static str, rows: &mut dyn Iterator<Item = (usize, f64, f64)>| {
                let start = row;
                for (i, centre, c0) in rows {
                    residuals[row] = c0 * (params[i] - centre);
                    if with_jacobian && row >= dense_to {
                        singles.push((i, c0));
                    } else if with_jacobian {
                        jacobian[row * dim + i - off] = c0;
                    }
                    row += 1;
                }
                blocks.push((name, start..row));
            };
        let morph = &self.template.morph;
        let base = 3 + 3 * self.template.rig.num_joints();
        for (name, weight, range) in [
            ("pose", w.pose, self.rotation_prior_rows()),
            ("shape", w.shape, base..base + morph.shape),
            (
                "expression",
                w.expression,
                base + morph.shape..base + morph.coefficients(),
            ),
        ] {
            if range.is_empty() {
                continue;
            }
            let c0 = weight.sqrt();
            diagonal(name, &mut range.map(|i| (i, 0.0, c0)));
        }
        if let Some(anchor) = &self.anchor {
            diagonal(
                "anchor",
                &mut anchor.rows().iter().map(|&(i, c, a)| (i, c, a.sqrt())),
            );
        }
        debug_assert_eq!(row, m);
        // Zero rows: penetration and joint-limit rows are zero exactly when their residual is
        // (their Jacobian is only written for active rows); data rows of unseen groups.
        let mut zero_rows = Vec::new();
        if with_jacobian {
            zero_rows = vec![false; m];
            for (name, range) in &blocks {
                for i in range.clone() {
                    zero_rows[i] = match *name {
                        "EP" | "EA" | "floor" => residuals[i] == 0.0,
                        "data" => match &self.target {
                            Target::Sparse { visible, .. } => {
                                !visible[i - range.start] || w.data == 0.0
                            }
                            Target::Scan { .. } | Target::Silhouettes { .. } => false,
                        },
                        _ => false,
                    };
                }
            }
        }
        let energy = data_energy
            + residuals
                .iter()
                .enumerate()
                .filter(|(i, _)| !data_rows.contains(i))
                .map(|(_, r)| r * r)
                .sum::<f64>();
        LeastSquares {
            residuals,
            jacobian,
            dense_from,
            dense_to,
            singles,
            dim,
            blocks,
            zero_rows,
            energy,
            observation_residual,
            points,
            constant_gram,
        }
    }
}
