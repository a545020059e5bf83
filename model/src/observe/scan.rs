//! The `scan` modality's observation data (papers/000 §3): a target point cloud of the posed
//! mesh, its Squared Euclidean Distance Transform `S` on a voxel grid spanning a slightly
//! scaled-up bounding box of the cloud, and `K` silhouette masks rendered from `K` views.
//!
//! * [`VoxelGrid`] stores `S` and samples it the way eq. 4 does: at the clamped position `⌊v⌋`,
//!   plus the extrapolation `‖v − ⌊v⌋‖²` outside the box ([`VoxelGrid::sample_extrapolated`]);
//!   its gradient ([`VoxelGrid::gradient`]) gives the surface orientation of eq. 5.
//! * [`squared_edt`] computes `S` exactly with the separable lower-envelope-of-parabolas
//!   algorithm of Felzenszwalb & Huttenlocher (the "separable algorithm of [24]" of papers/000).
//! * Noise and holes of a synthetic scan are added by `lfit-synth` (its `noise` module).
//! * [`render_silhouette`] / [`render_silhouettes`] rasterise the masks `M_k` and [`iou`] is the
//!   Jaccard index of eq. 6.

use glam::{DVec2, DVec3, Vec3};
use rayon::prelude::*;

use crate::camera::Camera;
use crate::error::{ModelError, Result};

/// Default factor by which the point cloud's bounding box is scaled up about its centre to give
/// the domain of `S` (papers/000 §3: "a slightly scaled up bounding box").
pub const DEFAULT_BOX_SCALE: f64 = 1.1;

/// Padding, in voxels, added on every side of the scaled bounding box.
pub const BOX_PADDING_VOXELS: f64 = 2.0;

/// Largest number of voxels [`VoxelGrid::around_points`] accepts (64 Mi voxels, 256 MiB of `f32`).
pub const MAX_VOXELS: usize = 1 << 26;

/// Minimum camera-frame depth (metres) of a vertex for its triangle to be rasterised; the same
/// near limit as [`Camera::project`].
pub const NEAR_DEPTH: f64 = 0.01;

/// Trilinear interpolation stencil of a point (see [`VoxelGrid::stencil`]).
#[derive(Debug, Clone, Copy)]
pub struct Stencil {
    pub index: [usize; 8],
    pub weight: [f64; 8],
    pub gradient: [DVec3; 8],
}

/// A scalar field sampled on a regular grid of nodes ("voxel centres").
///
/// Node `(i, j, k)` lies at `origin + spacing · (i, j, k)` and its value is
/// `values[i + dims[0] · (j + dims[1] · k)]` (x fastest). The grid's box — the domain of the
/// clamping `⌊·⌋` of papers/000 eq. 4 — is `[origin, origin + spacing · (dims − 1)]`.
#[derive(Debug, Clone, PartialEq)]
pub struct VoxelGrid {
    /// Position of node `(0, 0, 0)` (the box's minimum corner).
    pub origin: [f64; 3],
    /// Distance between neighbouring nodes along every axis, in metres.
    pub spacing: f64,
    /// Number of nodes along x, y and z.
    pub dims: [usize; 3],
    /// One value per node, x fastest. For a distance transform: squared distances in m².
    pub values: Vec<f32>,
}

impl VoxelGrid {
    /// A zero-filled grid covering the points' bounding box scaled up about its centre by
    /// `margin_scale` (use [`DEFAULT_BOX_SCALE`]) plus [`BOX_PADDING_VOXELS`] voxels on every
    /// side. Along each axis the node count is `ceil(extent / spacing) + 1` and the nodes are
    /// centred on the bounding box's centre.
    ///
    /// Fails when there are no points, a point is not finite, `spacing` is not a positive finite
    /// number, `margin_scale` is not a finite number ≥ 1, or the grid would exceed
    /// [`MAX_VOXELS`].
    pub fn around_points(points: &[Vec3], spacing: f64, margin_scale: f64) -> Result<Self> {
        if !(spacing.is_finite() && spacing > 0.0) {
            return Err(setting(
                "scan voxel spacing",
                spacing,
                "must be a positive finite number of metres",
            ));
        }
        if !(margin_scale.is_finite() && margin_scale >= 1.0) {
            return Err(setting(
                "scan box scale",
                margin_scale,
                "must be a finite number >= 1",
            ));
        }
        if points.is_empty() {
            return Err(ModelError::Setting {
                name: "scan point cloud",
                value: "0 points".to_string(),
                reason: "need at least one point to bound the voxel grid".to_string(),
            });
        }
        let mut lo = DVec3::splat(f64::INFINITY);
        let mut hi = DVec3::splat(f64::NEG_INFINITY);
        for (i, p) in points.iter().enumerate() {
            if !p.is_finite() {
                return Err(ModelError::Setting {
                    name: "scan point cloud",
                    value: format!("point {i} = {p}"),
                    reason: "point is not finite".to_string(),
                });
            }
            let p = p.as_dvec3();
            lo = lo.min(p);
            hi = hi.max(p);
        }
        let centre = 0.5 * (lo + hi);
        let half = 0.5 * (hi - lo) * margin_scale + DVec3::splat(BOX_PADDING_VOXELS * spacing);
        let mut dims = [0usize; 3];
        let mut origin = [0.0; 3];
        let mut total = 1.0f64;
        for a in 0..3 {
            // The tolerance keeps e.g. 0.4 / 0.1 = 4.000000000000001 from adding a whole voxel.
            let cells = (2.0 * half[a] / spacing - 1e-9).ceil().max(0.0);
            total *= cells + 1.0;
            if !(total.is_finite() && total <= MAX_VOXELS as f64) {
                return Err(setting(
                    "scan voxel spacing",
                    spacing,
                    &format!(
                        "the grid around a {:.3} x {:.3} x {:.3} m box would exceed {MAX_VOXELS} voxels",
                        hi.x - lo.x,
                        hi.y - lo.y,
                        hi.z - lo.z
                    ),
                ));
            }
            // `cells` is a small non-negative integer here (checked against MAX_VOXELS above).
            dims[a] = cells as usize + 1;
            origin[a] = centre[a] - 0.5 * cells * spacing;
        }
        Ok(Self {
            origin,
            spacing,
            dims,
            values: vec![0.0; dims[0] * dims[1] * dims[2]],
        })
    }

    /// Number of nodes.
    pub fn len(&self) -> usize {
        self.dims[0] * self.dims[1] * self.dims[2]
    }

    /// Whether the grid has no nodes.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Flat index of node `(i, j, k)` (x fastest).
    pub fn index(&self, i: usize, j: usize, k: usize) -> usize {
        i + self.dims[0] * (j + self.dims[1] * k)
    }

    /// World position of node `(i, j, k)`.
    pub fn node_position(&self, i: usize, j: usize, k: usize) -> DVec3 {
        DVec3::from_array(self.origin) + self.spacing * DVec3::new(i as f64, j as f64, k as f64)
    }

    /// Minimum corner of the grid's box (node `(0, 0, 0)`).
    pub fn box_min(&self) -> DVec3 {
        DVec3::from_array(self.origin)
    }

    /// Maximum corner of the grid's box (the last node).
    pub fn box_max(&self) -> DVec3 {
        let last = |a: usize| self.dims[a].saturating_sub(1) as f64;
        self.box_min() + self.spacing * DVec3::new(last(0), last(1), last(2))
    }

    /// The clamping `⌊p⌋` of papers/000 eq. 4: `p` with every coordinate bounded to the box.
    pub fn clamp(&self, p: DVec3) -> DVec3 {
        p.clamp(self.box_min(), self.box_max())
    }

    /// The node nearest to `p` after clamping it to the box.
    pub fn nearest_node(&self, p: DVec3) -> [usize; 3] {
        let u = (self.clamp(p) - self.box_min()) / self.spacing;
        let mut out = [0usize; 3];
        for a in 0..3 {
            // Non-negative and at most dims − 1 after clamping; NaN maps to 0.
            out[a] = (u[a].round().max(0.0) as usize).min(self.dims[a].saturating_sub(1));
        }
        out
    }

    /// Value of node `(i, j, k)`; `+∞` if `values` is shorter than `dims` says.
    fn value(&self, i: usize, j: usize, k: usize) -> f64 {
        self.values
            .get(self.index(i, j, k))
            .map_or(f64::INFINITY, |&v| f64::from(v))
    }

    /// The cell holding `clamp(p)` and the position within it: per axis the lower node index
    /// and the fraction `t ∈ [0, 1]` towards the upper node. Points on an interior cell face
    /// belong to the cell above it; on the box's upper face, to the last cell (`t = 1`).
    fn cell(&self, p: DVec3) -> ([usize; 3], [usize; 3], [f64; 3]) {
        let u = (self.clamp(p) - self.box_min()) / self.spacing;
        let mut lo = [0usize; 3];
        let mut hi = [0usize; 3];
        let mut t = [0.0; 3];
        for a in 0..3 {
            let cells = self.dims[a].saturating_sub(1);
            if cells == 0 {
                continue;
            }
            let i0 = (u[a].floor().max(0.0) as usize).min(cells - 1);
            lo[a] = i0;
            hi[a] = i0 + 1;
            t[a] = (u[a] - i0 as f64).clamp(0.0, 1.0);
        }
        (lo, hi, t)
    }

    /// The eight corner values of the cell, indexed `dx + 2·dy + 4·dz`.
    fn corners(&self, lo: [usize; 3], hi: [usize; 3]) -> [f64; 8] {
        let mut c = [0.0; 8];
        for (n, v) in c.iter_mut().enumerate() {
            let i = if n & 1 == 0 { lo[0] } else { hi[0] };
            let j = if n & 2 == 0 { lo[1] } else { hi[1] };
            let k = if n & 4 == 0 { lo[2] } else { hi[2] };
            *v = self.value(i, j, k);
        }
        c
    }

    /// Trilinear interpolation of the node values at `clamp(p)` (the `S(⌊v⌋)` of papers/000
    /// eq. 4).
    pub fn sample(&self, p: DVec3) -> f64 {
        let (lo, hi, t) = self.cell(p);
        let c = self.corners(lo, hi);
        let lerp = |a: f64, b: f64, s: f64| a + s * (b - a);
        let x00 = lerp(c[0], c[1], t[0]);
        let x10 = lerp(c[2], c[3], t[0]);
        let x01 = lerp(c[4], c[5], t[0]);
        let x11 = lerp(c[6], c[7], t[0]);
        lerp(lerp(x00, x10, t[1]), lerp(x01, x11, t[1]), t[2])
    }

    /// Analytic gradient (per metre) of the trilinear interpolant, evaluated at `clamp(p)` — the
    /// `∇S(⌊v⌋)` of papers/000 eq. 5. Outside the box this is the interpolant's (one-sided)
    /// gradient on the box's surface, *not* the gradient of `p ↦ sample(p)` (which is zero
    /// along clamped axes) nor of [`Self::sample_extrapolated`] (which adds `2 (p − ⌊p⌋)`).
    /// On an interior cell face the cell above is used (the interpolant is only C⁰ there).
    /// Along an axis with a single node the component is 0. Not normalised: for a squared
    /// distance transform its length is about twice the distance to the surface.
    pub fn gradient(&self, p: DVec3) -> DVec3 {
        let (lo, hi, t) = self.cell(p);
        let c = self.corners(lo, hi);
        let w = |s: f64, bit: bool| if bit { s } else { 1.0 - s };
        let mut g = DVec3::ZERO;
        for a in 0..3 {
            if self.dims[a] < 2 {
                continue;
            }
            let mut d = 0.0;
            for (n, v) in c.iter().enumerate() {
                let mut weight = if n & (1 << a) != 0 { 1.0 } else { -1.0 };
                for b in (0..3).filter(|&b| b != a) {
                    weight *= w(t[b], n & (1 << b) != 0);
                }
                d += weight * v;
            }
            g[a] = d / self.spacing;
        }
        g
    }

    /// The corner indices and interpolation weights of [`Self::stencil`], without the weights'
    /// gradients (the value-only fast path).
    pub fn stencil_weights(&self, p: DVec3) -> ([usize; 8], [f64; 8]) {
        let (lo, hi, t) = self.cell(p);
        let mut index = [0usize; 8];
        let mut weight = [0.0; 8];
        let base = self.index(lo[0], lo[1], lo[2]);
        let step = [
            hi[0] - lo[0],
            self.dims[0] * (hi[1] - lo[1]),
            self.dims[0] * self.dims[1] * (hi[2] - lo[2]),
        ];
        for n in 0..8 {
            let mut i = base;
            let mut w = 1.0;
            for a in 0..3 {
                if n & (1 << a) != 0 {
                    i += step[a];
                    w *= t[a];
                } else {
                    w *= 1.0 - t[a];
                }
            }
            index[n] = i;
            weight[n] = w;
        }
        (index, weight)
    }

    /// The trilinear stencil at `clamp(p)`: the eight corner node indices (into `values`),
    /// their interpolation weights and the weights' gradients (per metre; zero along axes with a
    /// single node). `Σ w_c f_c` interpolates any node field `f`, `Σ ∇w_c f_c` is its gradient.
    pub fn stencil(&self, p: DVec3) -> Stencil {
        let (lo, hi, t) = self.cell(p);
        let mut out = Stencil {
            index: [0; 8],
            weight: [0.0; 8],
            gradient: [DVec3::ZERO; 8],
        };
        let w = |s: f64, bit: bool| if bit { s } else { 1.0 - s };
        for n in 0..8 {
            let bit = |a: usize| n & (1 << a) != 0;
            let node = |a: usize| if bit(a) { hi[a] } else { lo[a] };
            out.index[n] = self.index(node(0), node(1), node(2));
            out.weight[n] = w(t[0], bit(0)) * w(t[1], bit(1)) * w(t[2], bit(2));
            let mut g = DVec3::ZERO;
            for a in 0..3 {
                if self.dims[a] < 2 {
                    continue;
                }
                let mut d = if bit(a) { 1.0 } else { -1.0 } / self.spacing;
                for b in (0..3).filter(|&b| b != a) {
                    d *= w(t[b], bit(b));
                }
                g[a] = d;
            }
            out.gradient[n] = g;
        }
        out
    }

    /// One summand of papers/000 eq. 4: `S(⌊p⌋) + ‖p − ⌊p⌋‖²`, i.e. [`Self::sample`] extended
    /// outside the box by the squared distance to it.
    pub fn sample_extrapolated(&self, p: DVec3) -> f64 {
        let q = self.clamp(p);
        self.sample(q) + p.distance_squared(q)
    }
}

fn setting(name: &'static str, value: f64, reason: &str) -> ModelError {
    ModelError::Setting {
        name,
        value: value.to_string(),
        reason: reason.to_string(),
    }
}

/// Fills `grid.values` with the Squared Euclidean Distance Transform of the point cloud
/// (papers/000 §3, the `S_P` of eqs. 4–5), computed exactly with the separable algorithm of
/// Felzenszwalb & Huttenlocher ("Distance Transforms of Sampled Functions", 2012): 1D lower
/// envelopes of parabolas along x, then y, then z, each pass's independent lines in parallel.
///
/// The sites are the grid nodes nearest to each point (points outside the box are clamped to
/// it first, non-finite points are ignored), so like papers/000 — a distance transform of the
/// reconstructed surface on the grid — the distances are quantised to the nodes: every node gets
/// `spacing² · (squared integer distance to the nearest site node)`, in m². Without any finite
/// point every value is `+∞`. `values` is resized to `dims` if needed.
pub fn squared_edt(grid: &mut VoxelGrid, points: &[Vec3]) {
    let n = grid.len();
    let mut f = vec![f64::INFINITY; n];
    for p in points.iter().filter(|p| p.is_finite()) {
        let [i, j, k] = grid.nearest_node(p.as_dvec3());
        f[grid.index(i, j, k)] = 0.0;
    }
    let d = edt_in_node_units(f, grid.dims);
    let s2 = grid.spacing * grid.spacing;
    grid.values = d.into_par_iter().map(|v| (v * s2) as f32).collect();
}

/// Builds the grid around the points ([`VoxelGrid::around_points`]) and fills it with their
/// squared distance transform ([`squared_edt`]).
pub fn distance_transform(points: &[Vec3], spacing: f64, margin_scale: f64) -> Result<VoxelGrid> {
    let mut grid = VoxelGrid::around_points(points, spacing, margin_scale)?;
    squared_edt(&mut grid, points);
    Ok(grid)
}

/// Squared EDT of `f` (x fastest, `dims` nodes, 0 at sites and `+∞` elsewhere, or any sampled
/// function) in units of node spacing: `d(p) = min_q |p − q|² + f(q)`. Returns x-fastest values.
fn edt_in_node_units(mut data: Vec<f64>, dims: [usize; 3]) -> Vec<f64> {
    if data.is_empty() || dims.contains(&0) {
        return data;
    }
    // Each pass transforms the contiguous lines of the current layout, then rotates the layout
    // so the next axis becomes the fastest: (x,y,z) → (y,z,x) → (z,x,y) → (x,y,z).
    let mut d = dims;
    for _ in 0..3 {
        let len = d[0];
        data.par_chunks_mut(len)
            .for_each_init(|| Envelope::new(len), |env, line| env.transform(line));
        data = rotate_layout(&data, d);
        d = [d[1], d[2], d[0]];
    }
    data
}

/// Re-lays out `input` (dims `[na, nb, nc]`, a fastest) so that b is fastest: (b, c, a).
fn rotate_layout(input: &[f64], [na, nb, nc]: [usize; 3]) -> Vec<f64> {
    let mut out = vec![0.0; input.len()];
    out.par_chunks_mut(nb).enumerate().for_each(|(line, dst)| {
        let (c, a) = (line % nc, line / nc);
        for (b, v) in dst.iter_mut().enumerate() {
            *v = input[a + na * (b + nb * c)];
        }
    });
    out
}

/// Work buffers of the 1D lower envelope of parabolas (Felzenszwalb & Huttenlocher, alg. DT).
struct Envelope {
    /// Sample positions of the parabolas in the envelope.
    v: Vec<usize>,
    /// Boundaries between the envelope's parabolas (`z[k]..z[k+1]` belongs to `v[k]`).
    z: Vec<f64>,
    /// Copy of the input line.
    f: Vec<f64>,
}

impl Envelope {
    fn new(n: usize) -> Self {
        Self {
            v: vec![0; n],
            z: vec![0.0; n + 1],
            f: vec![0.0; n],
        }
    }

    /// In place: `line[q] ← min_p (q − p)² + line[p]`; `+∞` samples are no parabola at all.
    fn transform(&mut self, line: &mut [f64]) {
        self.f.clear();
        self.f.extend_from_slice(line);
        let f = &self.f;
        let Some(first) = f.iter().position(|v| v.is_finite()) else {
            return; // no finite sample: the line stays +∞
        };
        let (v, z) = (&mut self.v, &mut self.z);
        let intersect = |q: usize, p: usize| {
            let (qf, pf) = (q as f64, p as f64);
            ((f[q] + qf * qf) - (f[p] + pf * pf)) / (2.0 * (qf - pf))
        };
        let mut k = 0usize;
        v[0] = first;
        z[0] = f64::NEG_INFINITY;
        z[1] = f64::INFINITY;
        for (q, fq) in f.iter().enumerate().skip(first + 1) {
            if !fq.is_finite() {
                continue;
            }
            let mut s = intersect(q, v[k]);
            // Terminates at k = 0 because z[0] = −∞ and s is finite.
            while s <= z[k] {
                k -= 1;
                s = intersect(q, v[k]);
            }
            k += 1;
            v[k] = q;
            z[k] = s;
            z[k + 1] = f64::INFINITY;
        }
        k = 0;
        for (q, out) in line.iter_mut().enumerate() {
            let qf = q as f64;
            while z[k + 1] < qf {
                k += 1;
            }
            let dq = qf - v[k] as f64;
            *out = dq * dq + f[v[k]];
        }
    }
}

/// A binary image, row-major (`data[x + width · y]`), 1 = inside the silhouette, 0 = outside.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Mask {
    pub width: u32,
    pub height: u32,
    pub data: Vec<u8>,
}

impl Mask {
    /// An empty (all-zero) mask.
    pub fn new(width: u32, height: u32) -> Self {
        Self {
            width,
            height,
            data: vec![0; width as usize * height as usize],
        }
    }

    /// Number of inside pixels.
    pub fn count(&self) -> usize {
        self.data.iter().filter(|&&v| v != 0).count()
    }

    /// Whether pixel `(x, y)` is inside; `false` outside the image.
    pub fn get(&self, x: u32, y: u32) -> bool {
        x < self.width
            && y < self.height
            && self
                .data
                .get(x as usize + self.width as usize * y as usize)
                .is_some_and(|&v| v != 0)
    }

    /// The mask with inside and outside swapped.
    pub fn complement(&self) -> Self {
        Self {
            width: self.width,
            height: self.height,
            data: self.data.iter().map(|&v| u8::from(v == 0)).collect(),
        }
    }
}

/// Jaccard index `|a ∩ b| / |a ∪ b|` of two masks (the ratio of papers/000 eq. 6); 1.0 when
/// both are empty. Masks of different sizes are compared pixel by pixel on the union of their
/// image domains, with pixels outside a mask counting as outside.
pub fn iou(a: &Mask, b: &Mask) -> f64 {
    let (mut inter, mut union) = (0usize, 0usize);
    if a.width == b.width && a.height == b.height && a.data.len() == b.data.len() {
        for (&p, &q) in a.data.iter().zip(&b.data) {
            let (p, q) = (p != 0, q != 0);
            inter += usize::from(p && q);
            union += usize::from(p || q);
        }
    } else {
        for y in 0..a.height.max(b.height) {
            for x in 0..a.width.max(b.width) {
                let (p, q) = (a.get(x, y), b.get(x, y));
                inter += usize::from(p && q);
                union += usize::from(p || q);
            }
        }
    }
    if union == 0 {
        1.0
    } else {
        inter as f64 / union as f64
    }
}

/// Rasterises the silhouette of a triangle mesh seen by `camera` (the rendering function `R_k`
/// of papers/000 eq. 6): a pixel is inside when its centre `(x + 0.5, y + 0.5)` lies inside or on
/// the boundary of some projected triangle. All three edge functions must have the triangle's
/// orientation sign or be zero (inclusive rule, either winding), so pixel centres on an edge
/// shared by two triangles are always filled — harmless for a union of triangles. Triangles with
/// an out-of-range index, a non-finite vertex, a vertex at camera-frame depth ≤ [`NEAR_DEPTH`]
/// (no clipping) or zero projected area are skipped.
pub fn render_silhouette(camera: &Camera, vertices: &[Vec3], faces: &[[u32; 3]]) -> Mask {
    let mut mask = Mask::new(camera.width, camera.height);
    let (w, h) = (camera.width as usize, camera.height as usize);
    if w == 0 || h == 0 {
        return mask;
    }
    // Projected vertices; None when behind the near limit or not finite.
    let projected: Vec<Option<DVec2>> = vertices
        .iter()
        .map(|v| {
            let q = camera.to_camera(v.as_dvec3());
            (q.is_finite() && q.z > NEAR_DEPTH)
                .then(|| camera.project_camera(q))
                .filter(|uv| uv.is_finite())
        })
        .collect();
    let get = |i: u32| projected.get(i as usize).copied().flatten();
    for face in faces {
        let (Some(a), Some(b), Some(c)) = (get(face[0]), get(face[1]), get(face[2])) else {
            continue;
        };
        fill_triangle(&mut mask.data, w, h, [a, b, c]);
    }
    mask
}

/// Fills the pixels of a `w × h` row-major image whose centres lie in the closed triangle.
fn fill_triangle(data: &mut [u8], w: usize, h: usize, [a, b, c]: [DVec2; 3]) {
    let area = (b - a).perp_dot(c - a);
    if !(area.is_finite() && area != 0.0) {
        return;
    }
    let sign = area.signum();
    let lo = a.min(b).min(c);
    let hi = a.max(b).max(c);
    // Pixels x with centre x + 0.5 in [lo.x, hi.x], clipped to the image (in f64 before casting).
    let range = |lo: f64, hi: f64, n: usize| -> Option<(usize, usize)> {
        let first = (lo - 0.5).ceil().max(0.0);
        let last = (hi - 0.5).floor().min(n as f64 - 1.0);
        (first <= last).then_some((first as usize, last as usize))
    };
    let (Some((x0, x1)), Some((y0, y1))) = (range(lo.x, hi.x, w), range(lo.y, hi.y, h)) else {
        return;
    };
    // Edge function of edge (p, q) at point s, times the orientation sign: ≥ 0 on the inner side.
    let edge = |p: DVec2, q: DVec2, s: DVec2| sign * (q - p).perp_dot(s - p);
    for y in y0..=y1 {
        let row = &mut data[y * w..(y + 1) * w];
        let py = y as f64 + 0.5;
        for (x, px) in row.iter_mut().enumerate().take(x1 + 1).skip(x0) {
            let s = DVec2::new(x as f64 + 0.5, py);
            if edge(a, b, s) >= 0.0 && edge(b, c, s) >= 0.0 && edge(c, a, s) >= 0.0 {
                *px = 1;
            }
        }
    }
}

/// [`render_silhouette`] for every camera, in parallel.
pub fn render_silhouettes(cameras: &[Camera], vertices: &[Vec3], faces: &[[u32; 3]]) -> Vec<Mask> {
    cameras
        .par_iter()
        .map(|cam| render_silhouette(cam, vertices, faces))
        .collect()
}

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod tests {
    use super::*;
    use crate::camera::default_ring;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;
    use rand_distr::StandardNormal;

    #[test]
    fn stencils_reproduce_sample_and_gradient() {
        // The energy interpolates through `stencil`/`stencil_weights`; they must agree with the
        // trilinear `sample` and `gradient`, inside the box and (clamped) outside it.
        let mut rng = ChaCha8Rng::seed_from_u64(5);
        let points: Vec<Vec3> = (0..200)
            .map(|_| {
                Vec3::new(
                    rng.random_range(-0.3..0.3),
                    rng.random_range(0.0..1.7),
                    rng.random_range(-0.2..0.2),
                )
            })
            .collect();
        let grid = distance_transform(&points, 0.03, DEFAULT_BOX_SCALE).unwrap();
        for _ in 0..500 {
            let p = DVec3::new(
                rng.random_range(-0.6..0.6),
                rng.random_range(-0.3..2.0),
                rng.random_range(-0.5..0.5),
            );
            let c = grid.clamp(p);
            let st = grid.stencil(c);
            let (index, weight) = grid.stencil_weights(c);
            assert_eq!(index, st.index);
            let value = |i: usize| f64::from(grid.values[i]);
            let (mut s, mut g) = (0.0, DVec3::ZERO);
            for n in 0..8 {
                assert!((weight[n] - st.weight[n]).abs() < 1e-15);
                s += st.weight[n] * value(st.index[n]);
                g += st.gradient[n] * value(st.index[n]);
            }
            assert!(
                (s - grid.sample(p)).abs() <= 1e-12 * (1.0 + s.abs()),
                "{p}: {s} vs {}",
                grid.sample(p)
            );
            assert!(
                (g - grid.gradient(p)).length() <= 1e-9 * (1.0 + g.length()),
                "{p}: {g} vs {}",
                grid.gradient(p)
            );
        }
    }

    /// Squared integer distance from every node to the nearest site, by brute force.
    fn brute_force(dims: [usize; 3], sites: &[[usize; 3]]) -> Vec<f64> {
        let mut out = Vec::new();
        for k in 0..dims[2] {
            for j in 0..dims[1] {
                for i in 0..dims[0] {
                    let d = sites
                        .iter()
                        .map(|s| {
                            let d = [
                                i as f64 - s[0] as f64,
                                j as f64 - s[1] as f64,
                                k as f64 - s[2] as f64,
                            ];
                            d[0] * d[0] + d[1] * d[1] + d[2] * d[2]
                        })
                        .fold(f64::INFINITY, f64::min);
                    out.push(d);
                }
            }
        }
        out
    }

    fn sites_function(dims: [usize; 3], sites: &[[usize; 3]]) -> Vec<f64> {
        let mut f = vec![f64::INFINITY; dims[0] * dims[1] * dims[2]];
        for s in sites {
            f[s[0] + dims[0] * (s[1] + dims[1] * s[2])] = 0.0;
        }
        f
    }

    fn random_sites(rng: &mut ChaCha8Rng, dims: [usize; 3], n: usize) -> Vec<[usize; 3]> {
        (0..n)
            .map(|_| std::array::from_fn(|a| rng.random_range(0..dims[a])))
            .collect()
    }

    fn assert_close(got: &[f64], want: &[f64], tol: f64) {
        assert_eq!(got.len(), want.len());
        for (n, (g, w)) in got.iter().zip(want).enumerate() {
            assert!((g - w).abs() <= tol, "node {n}: got {g}, want {w}");
        }
    }

    #[test]
    fn edt_matches_brute_force_on_random_small_grids() {
        let mut rng = ChaCha8Rng::seed_from_u64(7);
        for dims in [[13, 9, 7], [1, 5, 4], [6, 1, 1], [3, 8, 1], [17, 2, 11]] {
            for n_sites in [1, 2, 5, 12] {
                let sites = random_sites(&mut rng, dims, n_sites);
                let got = edt_in_node_units(sites_function(dims, &sites), dims);
                assert_close(&got, &brute_force(dims, &sites), 1e-9);
            }
        }
    }

    #[test]
    fn edt_of_a_single_site_in_a_20_cube() {
        let dims = [20, 20, 20];
        let site = [3, 11, 17];
        let got = edt_in_node_units(sites_function(dims, &[site]), dims);
        assert_close(&got, &brute_force(dims, &[site]), 1e-9);
        assert_eq!(got[site[0] + 20 * (site[1] + 20 * site[2])], 0.0);
        assert_eq!(got[19], (16 * 16 + 11 * 11 + 17 * 17) as f64);
    }

    #[test]
    fn edt_without_sites_is_infinite() {
        let got = edt_in_node_units(vec![f64::INFINITY; 24], [2, 3, 4]);
        assert!(got.iter().all(|v| *v == f64::INFINITY));
        let mut grid = VoxelGrid::around_points(&[Vec3::ZERO], 0.1, DEFAULT_BOX_SCALE).unwrap();
        squared_edt(&mut grid, &[Vec3::NAN]);
        assert!(grid.values.iter().all(|v| *v == f32::INFINITY));
    }

    #[test]
    fn squared_edt_of_points_is_in_square_metres_and_snaps_to_nodes() {
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        let points: Vec<Vec3> = (0..6)
            .map(|_| Vec3::new(rng.random(), rng.random(), rng.random()) * Vec3::new(0.6, 0.4, 0.3))
            .collect();
        let spacing = 0.05;
        let grid = distance_transform(&points, spacing, DEFAULT_BOX_SCALE).unwrap();
        let sites: Vec<[usize; 3]> = points
            .iter()
            .map(|p| grid.nearest_node(p.as_dvec3()))
            .collect();
        let want = brute_force(grid.dims, &sites);
        for (n, (g, w)) in grid.values.iter().zip(&want).enumerate() {
            let w = w * spacing * spacing;
            assert!(
                (f64::from(*g) - w).abs() <= 1e-6 * w.max(1e-3),
                "node {n}: got {g}, want {w}"
            );
        }
        // Each point snaps to the node within half a voxel per axis, where S = 0.
        for (p, s) in points.iter().zip(&sites) {
            let node = grid.node_position(s[0], s[1], s[2]);
            assert!((node - p.as_dvec3()).abs().max_element() <= 0.5 * spacing + 1e-12);
            assert_eq!(grid.values[grid.index(s[0], s[1], s[2])], 0.0);
        }
        // With spacing 1 the values are the exact integer squared distances.
        let mut unit = VoxelGrid {
            origin: [0.0; 3],
            spacing: 1.0,
            dims: [13, 9, 7],
            values: Vec::new(),
        };
        let pts = [
            Vec3::new(2.2, 3.9, 0.1),
            Vec3::new(11.6, 0.4, 6.3),
            Vec3::new(-5.0, 20.0, 3.0),
        ];
        squared_edt(&mut unit, &pts);
        let sites = [[2, 4, 0], [12, 0, 6], [0, 8, 3]]; // the last point is clamped into the box
        let want: Vec<f32> = brute_force(unit.dims, &sites)
            .iter()
            .map(|v| *v as f32)
            .collect();
        assert_eq!(unit.values, want);
    }

    #[test]
    fn squared_edt_approximates_the_distance_to_a_sampled_sphere() {
        let mut rng = ChaCha8Rng::seed_from_u64(11);
        let points: Vec<Vec3> = (0..20000)
            .map(|_| {
                let n: [f32; 3] = std::array::from_fn(|_| rng.sample(StandardNormal));
                Vec3::from_array(n).normalize() * 0.5
            })
            .collect();
        let spacing = 0.02;
        let grid = distance_transform(&points, spacing, DEFAULT_BOX_SCALE).unwrap();
        // Snapping sites to nodes and interpolating between nodes each cost up to half a voxel
        // diagonal; the 20000 samples leave gaps of about 1 cm on the sphere.
        let tol = 3f64.sqrt() * spacing + 0.01;
        for p in [
            DVec3::ZERO,
            DVec3::new(0.3, 0.1, 0.0),
            DVec3::new(0.0, 0.5, 0.0),
            DVec3::new(0.1, 0.0, 0.45),
        ] {
            let want = (p.length() - 0.5).abs();
            let got = grid.sample(p).sqrt();
            assert!((got - want).abs() < tol, "at {p}: got {got}, want {want}");
        }
    }

    #[test]
    fn around_points_bounds_the_scaled_box_with_padding() {
        let points = [Vec3::new(-0.3, 0.0, 0.1), Vec3::new(0.5, 1.8, 0.4)];
        let spacing = 0.01;
        let grid = VoxelGrid::around_points(&points, spacing, DEFAULT_BOX_SCALE).unwrap();
        let (lo, hi) = (points[0].as_dvec3(), points[1].as_dvec3());
        let centre = 0.5 * (lo + hi);
        let half = 0.5 * (hi - lo) * DEFAULT_BOX_SCALE + DVec3::splat(2.0 * spacing);
        assert!(grid.box_min().cmple(centre - half + 1e-9).all());
        assert!(grid.box_max().cmpge(centre + half - 1e-9).all());
        for a in 0..3 {
            let extent = 2.0 * half[a];
            assert_eq!(grid.dims[a], (extent / spacing - 1e-9).ceil() as usize + 1);
        }
        let mid = 0.5 * (grid.box_min() + grid.box_max());
        assert!((mid - centre).length() < 1e-9);
        assert_eq!(grid.values.len(), grid.dims.iter().product::<usize>());
        // A single point still gets a padded grid.
        let one = VoxelGrid::around_points(&[Vec3::ONE], 0.1, 1.0).unwrap();
        assert_eq!(one.dims, [5, 5, 5]);
        assert!((one.node_position(2, 2, 2) - DVec3::ONE).length() < 1e-12);
    }

    #[test]
    fn around_points_rejects_bad_input() {
        let pts = [Vec3::ZERO, Vec3::ONE];
        let msg = |r: Result<VoxelGrid>| r.unwrap_err().to_string();
        assert!(msg(VoxelGrid::around_points(&[], 0.1, 1.1)).contains("0 points"));
        assert!(
            msg(VoxelGrid::around_points(
                &[Vec3::ZERO, Vec3::new(0.0, f32::NAN, 0.0)],
                0.1,
                1.1
            ))
            .contains("point 1")
        );
        assert!(msg(VoxelGrid::around_points(&pts, 0.0, 1.1)).contains("spacing = 0"));
        assert!(msg(VoxelGrid::around_points(&pts, -1.0, 1.1)).contains("-1"));
        assert!(msg(VoxelGrid::around_points(&pts, f64::NAN, 1.1)).contains("NaN"));
        assert!(msg(VoxelGrid::around_points(&pts, 0.1, 0.9)).contains("0.9"));
        assert!(msg(VoxelGrid::around_points(&pts, 1e-4, 1.1)).contains("voxels"));
        assert!(
            msg(VoxelGrid::around_points(
                &[Vec3::ZERO, Vec3::splat(1e30)],
                0.01,
                1.1
            ))
            .contains("voxels")
        );
    }

    fn random_grid(rng: &mut ChaCha8Rng) -> VoxelGrid {
        let dims = [6, 5, 4];
        let values = (0..120).map(|_| rng.random_range(0.0..4.0f32)).collect();
        VoxelGrid {
            origin: [-0.2, 0.1, 0.3],
            spacing: 0.1,
            dims,
            values,
        }
    }

    #[test]
    fn sample_interpolates_nodes_and_linear_functions() {
        let mut rng = ChaCha8Rng::seed_from_u64(5);
        let grid = random_grid(&mut rng);
        for k in 0..4 {
            for j in 0..5 {
                for i in 0..6 {
                    let v = f64::from(grid.values[grid.index(i, j, k)]);
                    assert!((grid.sample(grid.node_position(i, j, k)) - v).abs() < 1e-12);
                }
            }
        }
        // A linear field is reproduced exactly and its gradient is the field's slope.
        let slope = DVec3::new(1.5, -2.0, 0.75);
        let mut lin = grid.clone();
        for k in 0..4 {
            for j in 0..5 {
                for i in 0..6 {
                    let idx = lin.index(i, j, k);
                    lin.values[idx] = (3.0 + slope.dot(lin.node_position(i, j, k))) as f32;
                }
            }
        }
        for _ in 0..200 {
            let p = lin.box_min()
                + (lin.box_max() - lin.box_min())
                    * DVec3::new(rng.random(), rng.random(), rng.random());
            assert!((lin.sample(p) - (3.0 + slope.dot(p))).abs() < 1e-5);
            assert!((lin.gradient(p) - slope).length() < 1e-4);
        }
    }

    #[test]
    fn gradient_matches_finite_differences_inside_cells() {
        let mut rng = ChaCha8Rng::seed_from_u64(9);
        let grid = random_grid(&mut rng);
        let h = 1e-6;
        for _ in 0..200 {
            let p = grid.box_min()
                + (grid.box_max() - grid.box_min())
                    * DVec3::new(rng.random(), rng.random(), rng.random());
            let g = grid.gradient(p);
            for a in 0..3 {
                let mut e = DVec3::ZERO;
                e[a] = h;
                // Skip points within h of a cell face, where the interpolant is only C⁰.
                let u = (p[a] - grid.origin[a]) / grid.spacing;
                if (u - u.round()).abs() < 1e-3 {
                    continue;
                }
                let fd = (grid.sample(p + e) - grid.sample(p - e)) / (2.0 * h);
                assert!(
                    (fd - g[a]).abs() < 1e-5 * (1.0 + g[a].abs()),
                    "axis {a}: fd {fd}, analytic {}",
                    g[a]
                );
            }
        }
    }

    #[test]
    fn clamp_and_extrapolation_outside_the_box() {
        let mut rng = ChaCha8Rng::seed_from_u64(1);
        let grid = random_grid(&mut rng);
        let inside = DVec3::new(0.0, 0.3, 0.45);
        assert_eq!(grid.clamp(inside), inside);
        assert_eq!(grid.sample_extrapolated(inside), grid.sample(inside));
        let outside = DVec3::new(-1.0, 0.35, 2.0);
        let q = grid.clamp(outside);
        assert!((q - DVec3::new(-0.2, 0.35, 0.6)).length() < 1e-12);
        assert_eq!(grid.sample(outside), grid.sample(q));
        assert_eq!(grid.gradient(outside), grid.gradient(q));
        let want = grid.sample(q) + 0.8 * 0.8 + 1.4 * 1.4;
        assert!((grid.sample_extrapolated(outside) - want).abs() < 1e-12);
        // Upper box faces belong to the last cell.
        let corner = grid.box_max();
        let v = f64::from(grid.values[grid.index(5, 4, 3)]);
        assert!((grid.sample(corner) - v).abs() < 1e-12);
        assert!(grid.gradient(corner).is_finite());
    }

    fn quad(lo: [f32; 2], hi: [f32; 2], z: f32) -> (Vec<Vec3>, Vec<[u32; 3]>) {
        let v = vec![
            Vec3::new(lo[0], lo[1], z),
            Vec3::new(hi[0], lo[1], z),
            Vec3::new(hi[0], hi[1], z),
            Vec3::new(lo[0], hi[1], z),
        ];
        (v, vec![[0, 1, 2], [0, 2, 3]])
    }

    /// Camera at the origin looking along +z with f = 1 and no principal point offset: a world
    /// point `(u, v, 1)` lands on pixel coordinates `(u, v)`.
    fn identity_camera(width: u32, height: u32) -> Camera {
        Camera {
            fx: 1.0,
            fy: 1.0,
            cx: 0.0,
            cy: 0.0,
            width,
            height,
            rotation: [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
            translation: [0.0; 3],
        }
    }

    #[test]
    fn triangle_pixel_count_matches_its_area() {
        let cam = identity_camera(100, 100);
        let (a, b, c) = (
            DVec2::new(10.3, 10.7),
            DVec2::new(83.2, 20.1),
            DVec2::new(30.9, 91.4),
        );
        let area = 0.5 * (b - a).perp_dot(c - a).abs();
        let perimeter = (b - a).length() + (c - b).length() + (a - c).length();
        for faces in [[[0u32, 1, 2]], [[0u32, 2, 1]]] {
            // Either winding, and the same triangle seen at depth 2 (twice as far, twice the size).
            for z in [1.0f32, 2.0] {
                let vertices: Vec<Vec3> = [a, b, c]
                    .iter()
                    .map(|p| Vec3::new(p.x as f32, p.y as f32, 1.0) * z)
                    .collect();
                let mask = render_silhouette(&cam, &vertices, &faces);
                let n = mask.count() as f64;
                assert!((n - area).abs() < perimeter, "count {n}, area {area}");
                // Vertices' pixels are near-edge; the centroid's pixel is inside.
                let g = (a + b + c) / 3.0;
                assert!(mask.get(g.x as u32, g.y as u32));
                assert!(!mask.get(95, 5) && !mask.get(2, 98));
            }
        }
    }

    #[test]
    fn quad_covering_the_image_fills_every_pixel() {
        let cam = identity_camera(64, 48);
        // Exactly the image: pixel centres on the shared diagonal need the inclusive rule.
        let (v, f) = quad([0.0, 0.0], [64.0, 48.0], 1.0);
        assert_eq!(render_silhouette(&cam, &v, &f).count(), 64 * 48);
        let (v, f) = quad([0.0, 0.0], [48.0, 48.0], 1.0);
        let m = render_silhouette(&cam, &v, &f);
        assert_eq!(m.count(), 48 * 48);
        // Far larger than the image, both windings.
        let (v, mut f) = quad([-1e4, -1e4], [1e4, 1e4], 1.0);
        f.iter_mut().for_each(|t| t.swap(1, 2));
        let m = render_silhouette(&cam, &v, &f);
        assert!(m.data.iter().all(|&p| p == 1));
    }

    #[test]
    fn geometry_behind_the_camera_renders_nothing() {
        let cam = identity_camera(64, 48);
        let (v, f) = quad([-10.0, -10.0], [100.0, 100.0], -1.0);
        assert_eq!(render_silhouette(&cam, &v, &f).count(), 0);
        // One vertex behind the near limit drops the whole triangle.
        let v = vec![
            Vec3::new(0.0, 0.0, 1.0),
            Vec3::new(60.0, 0.0, 1.0),
            Vec3::new(0.0, 40.0, 0.005),
        ];
        assert_eq!(render_silhouette(&cam, &v, &[[0, 1, 2]]).count(), 0);
        // Bad indices and degenerate triangles are skipped too.
        let (v, _) = quad([0.0, 0.0], [64.0, 48.0], 1.0);
        assert_eq!(
            render_silhouette(&cam, &v, &[[0, 1, 7], [0, 1, 1]]).count(),
            0
        );
    }

    #[test]
    fn iou_of_masks() {
        let cam = identity_camera(40, 30);
        let (v, f) = quad([5.0, 5.0], [25.0, 20.0], 1.0);
        let a = render_silhouette(&cam, &v, &f);
        assert_eq!(a.count(), 20 * 15);
        assert_eq!(iou(&a, &a), 1.0);
        assert_eq!(iou(&a, &a.complement()), 0.0);
        let empty = Mask::new(40, 30);
        assert_eq!(iou(&empty, &empty), 1.0);
        assert_eq!(iou(&a, &empty), 0.0);
        let (v, f) = quad([15.0, 5.0], [35.0, 20.0], 1.0);
        let b = render_silhouette(&cam, &v, &f);
        assert!((iou(&a, &b) - 150.0 / 450.0).abs() < 1e-12);
        // Different sizes compare on the union of the domains.
        let mut big = Mask::new(50, 30);
        for y in 0..30 {
            for x in 0..40 {
                big.data[x + 50 * y] = a.data[x + 40 * y];
            }
        }
        assert_eq!(iou(&a, &big), 1.0);
        big.data[45] = 1;
        assert!((iou(&a, &big) - 300.0 / 301.0).abs() < 1e-12);
    }

    #[test]
    fn ring_silhouettes_of_a_box_are_centred_and_parallel_matches_serial() {
        // An axis-aligned box 0.4 × 1.6 × 0.3 m centred on the ring's target (0, 1, 0).
        let (lo, hi) = (Vec3::new(-0.2, 0.2, -0.15), Vec3::new(0.2, 1.8, 0.15));
        let vertices: Vec<Vec3> = (0..8)
            .map(|n| {
                Vec3::new(
                    if n & 1 == 0 { lo.x } else { hi.x },
                    if n & 2 == 0 { lo.y } else { hi.y },
                    if n & 4 == 0 { lo.z } else { hi.z },
                )
            })
            .collect();
        let faces = [
            [0, 1, 3],
            [0, 3, 2],
            [4, 6, 7],
            [4, 7, 5],
            [0, 4, 5],
            [0, 5, 1],
            [2, 3, 7],
            [2, 7, 6],
            [0, 2, 6],
            [0, 6, 4],
            [1, 5, 7],
            [1, 7, 3],
        ];
        let cameras = default_ring(6);
        let masks = render_silhouettes(&cameras, &vertices, &faces);
        assert_eq!(masks.len(), 6);
        for (cam, mask) in cameras.iter().zip(&masks) {
            assert_eq!(*mask, render_silhouette(cam, &vertices, &faces));
            assert!(mask.get(320, 240));
            assert!(!mask.get(5, 5) && !mask.get(635, 475));
            // Each projected corner (with depth) bounds the silhouette.
            let uv: Vec<DVec2> = vertices
                .iter()
                .map(|v| cam.project(v.as_dvec3()).unwrap())
                .collect();
            let min = uv
                .iter()
                .fold(DVec2::splat(f64::INFINITY), |m, p| m.min(*p));
            let max = uv
                .iter()
                .fold(DVec2::splat(f64::NEG_INFINITY), |m, p| m.max(*p));
            for y in 0..mask.height {
                for x in 0..mask.width {
                    if mask.get(x, y) {
                        let c = DVec2::new(f64::from(x) + 0.5, f64::from(y) + 0.5);
                        assert!(c.cmpge(min).all() && c.cmple(max).all());
                    }
                }
            }
        }
    }
}
