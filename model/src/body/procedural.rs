//! The procedural default template (SPEC §3): a watertight humanoid in an A-pose, about 1.75 m
//! tall, built as a quad cage by extrusion (torso, legs with feet, arms with hands, neck and head),
//! smoothed by two Catmull–Clark subdivisions and triangulated. Skinning weights are set per cage
//! ring and subdivided with the same masks as the positions, which makes them smooth, convex and
//! identical in topology for every body-proportion variant.

use std::collections::HashMap;

use glam::{DVec3, Vec3};
use serde::{Deserialize, Serialize};

use crate::error::Result;
use crate::morph::{Morph, SparseRows};
use crate::rig::{Joint, JointIndex, MAX_INFLUENCES, Marker, Rig};
use crate::skeleton::*;
use crate::template::Template;

/// Per-segment scales of the default body (1.0 everywhere is the default template).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct BodyShape {
    /// Uniform scale of the whole body.
    pub height: f64,
    /// Length scale of the legs (hip to sole).
    pub leg_length: f64,
    /// Length scale of the arms (shoulder to hand tip).
    pub arm_length: f64,
    /// Length scale of the trunk (pelvis to neck).
    pub torso_length: f64,
    /// Width/depth scale of the trunk and hips (girth).
    pub girth: f64,
    /// Thickness scale of the limbs.
    pub limb_girth: f64,
    /// Scale of the head.
    pub head: f64,
    /// Arm abduction of the rest A-pose, degrees below horizontal.
    pub arm_angle_deg: f64,
    /// Depth scale of the trunk (front to back), on top of `girth`.
    #[serde(default = "one")]
    pub chest_depth: f64,
    /// Scale of the shoulders' distance from the midline, on top of `girth`.
    #[serde(default = "one")]
    pub shoulder_width: f64,
}

fn one() -> f64 {
    1.0
}

impl Default for BodyShape {
    fn default() -> Self {
        Self {
            height: 1.0,
            leg_length: 1.0,
            arm_length: 1.0,
            torso_length: 1.0,
            girth: 1.0,
            limb_girth: 1.0,
            head: 1.0,
            arm_angle_deg: 45.0,
            chest_depth: 1.0,
            shoulder_width: 1.0,
        }
    }
}

impl BodyShape {
    /// A named variant: `default`, `tall`, `short`, `heavy`, `slim`, `long-legs`, `long-arms`.
    pub fn named(name: &str) -> Option<Self> {
        let d = Self::default();
        Some(match name {
            "default" => d,
            "tall" => Self { height: 1.1, ..d },
            "short" => Self {
                height: 0.88,
                head: 1.05,
                ..d
            },
            "heavy" => Self {
                girth: 1.3,
                limb_girth: 1.25,
                ..d
            },
            "slim" => Self {
                girth: 0.85,
                limb_girth: 0.85,
                ..d
            },
            "long-legs" => Self {
                leg_length: 1.1,
                torso_length: 0.94,
                ..d
            },
            "long-arms" => Self {
                arm_length: 1.12,
                ..d
            },
            _ => return None,
        })
    }

    /// Names accepted by [`BodyShape::named`] (and `morphable`, the shape space of
    /// [`morphable_default_template`], where a template is asked for).
    pub const NAMES: [&'static str; 7] = [
        "default",
        "tall",
        "short",
        "heavy",
        "slim",
        "long-legs",
        "long-arms",
    ];
}

/// Builds the default template (`BodyShape::default()`), id `default`.
pub fn default_template() -> Template {
    build_template(&BodyShape::default(), "default")
        .expect("the procedural template is valid by construction")
}

/// Builds a body-proportion variant of the default template.
pub fn build_template(shape: &BodyShape, id: &str) -> Result<Template> {
    let skeleton = Skeleton::new(shape);
    let mut cage = Cage::default();
    build_cage(&mut cage, &skeleton, shape);
    let (mut positions, quads, weights) = cage.subdivide().subdivide().into_parts();
    // The subdivided sole lies a little above y = 0: put it on the floor.
    let lowest = positions.iter().map(|p| p.y).fold(f64::INFINITY, f64::min);
    for p in &mut positions {
        p.y -= lowest;
    }
    let mut joints_rest = skeleton.joints.clone();
    for j in &mut joints_rest {
        j.y -= lowest;
    }
    let vertices: Vec<Vec3> = positions.iter().map(|p| p.as_vec3()).collect();
    let mut faces = Vec::with_capacity(quads.len() * 2);
    for q in &quads {
        // A fixed diagonal keeps the faces identical across body-proportion variants.
        faces.push([q[0], q[1], q[2]]);
        faces.push([q[0], q[2], q[3]]);
    }
    if signed_volume(&vertices, &faces) < 0.0 {
        for f in &mut faces {
            f.swap(1, 2);
        }
    }
    // Number vertices in order of first use by the faces: OBJ readers that renumber that way
    // (tobj, many engines) then see the file's own order, which the rig's weights index.
    let mut new_index = vec![u32::MAX; vertices.len()];
    let mut order = Vec::with_capacity(vertices.len());
    for f in &mut faces {
        for i in f.iter_mut() {
            if new_index[*i as usize] == u32::MAX {
                new_index[*i as usize] = order.len() as u32;
                order.push(*i as usize);
            }
            *i = new_index[*i as usize];
        }
    }
    let vertices: Vec<Vec3> = order.iter().map(|&i| vertices[i]).collect();
    let weights: Vec<Vec<(JointIndex, f64)>> =
        order.iter().map(|&i| top_influences(&weights[i])).collect();
    let joints = (0..NUM_JOINTS)
        .map(|j| Joint {
            name: JOINT_NAMES[j].to_string(),
            parent: PARENTS[j],
            rest_position: joints_rest[j].to_array(),
        })
        .collect();
    let mut rig = Rig {
        joints,
        weights,
        markers: Vec::new(),
    };
    // Markers sit on the same vertices in every variant: they are placed on the default body.
    rig.markers = if *shape == BodyShape::default() {
        let provisional = Template::new(id, vertices.clone(), faces.clone(), rig.clone())?;
        place_markers(&provisional, &joints_rest, &skeleton)
    } else {
        build_template(&BodyShape::default(), "default")?
            .rig
            .markers
    };
    Template::new(id, vertices, faces, rig)
}

/// Shape coefficients of the morphable default template.
pub const MORPHABLE_SHAPE_DIM: usize = 8;

/// Body-proportion samples behind the morphable default template's shape space.
pub const MORPHABLE_SAMPLES: usize = 64;

/// The morphable default template (id `default+morphable`): the default template as the mean
/// (β = 0 poses exactly like it), and a shape space of [`MORPHABLE_SHAPE_DIM`] directions from
/// a PCA of [`MORPHABLE_SAMPLES`] random body-proportion variants (height 0.88–1.12, legs
/// 0.9–1.1, arms 0.9–1.12, trunk 0.92–1.08, girth 0.8–1.3, limb girth 0.8–1.25, head 0.92–1.08,
/// chest depth 0.85–1.2, shoulder width 0.9–1.12: our ranges, bracketing the named variants;
/// seed fixed; nine proportions, so the eight directions all carry variance). Directions are scaled to one standard
/// deviation of the samples, so β ~ N(0, I) is the sampled population. The rest joints follow the
/// shape through a joint regressor fitted on the mean ([`fit_regressor`]).
/// Returns the template and the fraction of the samples' variance each direction explains.
pub fn morphable_default_template() -> Result<(Template, Vec<f64>)> {
    use rand::{Rng, SeedableRng};
    let mean = default_template();
    let v = mean.num_vertices();
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(0x5eed_b0d1);
    let mut rows: Vec<Vec<f64>> = Vec::with_capacity(MORPHABLE_SAMPLES);
    for _ in 0..MORPHABLE_SAMPLES {
        let shape = BodyShape {
            height: rng.random_range(0.88..1.12),
            leg_length: rng.random_range(0.9..1.1),
            arm_length: rng.random_range(0.9..1.12),
            torso_length: rng.random_range(0.92..1.08),
            girth: rng.random_range(0.8..1.3),
            limb_girth: rng.random_range(0.8..1.25),
            head: rng.random_range(0.92..1.08),
            chest_depth: rng.random_range(0.85..1.2),
            shoulder_width: rng.random_range(0.9..1.12),
            ..BodyShape::default()
        };
        let t = build_template(&shape, "sample")?;
        rows.push(
            t.vertices
                .iter()
                .zip(&mean.vertices)
                .flat_map(|(a, b)| (a.as_dvec3() - b.as_dvec3()).to_array())
                .collect(),
        );
    }
    // PCA of the deviations from the mean template through the N × N Gram matrix.
    let n = rows.len();
    let gram = nalgebra::DMatrix::from_fn(n, n, |i, j| {
        rows[i]
            .iter()
            .zip(&rows[j])
            .map(|(a, b)| a * b)
            .sum::<f64>()
            / n as f64
    });
    let eig = nalgebra::SymmetricEigen::new(gram);
    let mut order: Vec<usize> = (0..n).collect();
    order.sort_by(|&a, &b| eig.eigenvalues[b].total_cmp(&eig.eigenvalues[a]));
    let total: f64 = eig.eigenvalues.iter().map(|l| l.max(0.0)).sum();
    let k = MORPHABLE_SHAPE_DIM;
    let mut dirs = vec![0.0; 3 * v * k];
    let mut explained = Vec::with_capacity(k);
    for (c, &e) in order.iter().take(k).enumerate() {
        explained.push(eig.eigenvalues[e].max(0.0) / total);
        // d = Xᵀ a / √N: the principal direction scaled by its standard deviation.
        let a = eig.eigenvectors.column(e);
        // A fixed sign: the direction's largest component positive.
        let mut col = vec![0.0; 3 * v];
        for (i, row) in rows.iter().enumerate() {
            for (o, x) in col.iter_mut().zip(row) {
                *o += a[i] * x / (n as f64).sqrt();
            }
        }
        let big = col
            .iter()
            .copied()
            .fold(0.0f64, |m, x| if x.abs() > m.abs() { x } else { m });
        let sign = if big < 0.0 { -1.0 } else { 1.0 };
        for (r, x) in col.iter().enumerate() {
            dirs[r * k + c] = sign * x;
        }
    }
    let reg = fit_regressor(&mean);
    let rest = mean.vertices.iter().map(|p| p.as_dvec3()).collect();
    let mut info = mean.info.clone();
    info.provenance = format!(
        "lfit procedural default template with a PCA shape space of {MORPHABLE_SAMPLES} body-proportion variants"
    );
    let mut t = mean.with_morph(Morph::new(rest, k, 0, dirs, None, Some(reg)), info)?;
    t.id = "default+morphable".into();
    Ok((t, explained))
}

/// Signed volume of a closed triangle mesh (positive when faces wind counter-clockwise from outside).
pub fn signed_volume(vertices: &[Vec3], faces: &[[u32; 3]]) -> f64 {
    faces
        .iter()
        .map(|f| {
            let [a, b, c] = f.map(|i| vertices[i as usize].as_dvec3());
            a.dot(b.cross(c)) / 6.0
        })
        .sum()
}

fn top_influences(w: &[f64; NUM_JOINTS]) -> Vec<(JointIndex, f64)> {
    let mut list: Vec<(JointIndex, f64)> = w
        .iter()
        .copied()
        .enumerate()
        .filter(|&(_, w)| w > 1e-3)
        .collect();
    list.sort_by(|a, b| b.1.total_cmp(&a.1).then(a.0.cmp(&b.0)));
    list.truncate(MAX_INFLUENCES);
    let sum: f64 = list.iter().map(|p| p.1).sum();
    for p in &mut list {
        p.1 /= sum;
    }
    list
}

/// Joint centres and limb directions of a body shape.
struct Skeleton {
    joints: Vec<DVec3>,
    /// Direction of the left arm (the right arm mirrors it).
    arm_dir: DVec3,
    /// "Up" across the left arm, perpendicular to `arm_dir` in the frontal plane.
    arm_up: DVec3,
    upper_arm: f64,
    forearm: f64,
    hand: f64,
}

impl Skeleton {
    fn new(s: &BodyShape) -> Self {
        let h = s.height;
        let leg = s.leg_length * h;
        let torso = s.torso_length * h;
        let g = s.girth * h;
        let hip_y = 0.92 * leg;
        let mut joints = vec![DVec3::ZERO; NUM_JOINTS];
        joints[ROOT] = DVec3::new(0.0, hip_y + 0.02 * torso, 0.0);
        joints[LOWER_TORSO] = DVec3::new(0.0, hip_y + 0.11 * torso, -0.01 * g);
        joints[MIDDLE_TORSO] = DVec3::new(0.0, hip_y + 0.30 * torso, -0.01 * g);
        joints[HEAD] = DVec3::new(0.0, hip_y + 0.58 * torso, -0.01 * g);
        for (side, sign) in [(0usize, -1.0), (4usize, 1.0)] {
            joints[R_HIP + side] = DVec3::new(sign * 0.09 * g, hip_y, 0.0);
            joints[R_KNEE + side] = DVec3::new(sign * 0.10 * g, 0.50 * leg, 0.01 * h);
            joints[R_ANKLE + side] = DVec3::new(sign * 0.105 * g, 0.085 * leg, -0.01 * h);
            joints[R_FOOT + side] = DVec3::new(sign * 0.105 * g, 0.03 * h, 0.12 * h);
        }
        let angle = s.arm_angle_deg.to_radians();
        let arm_dir = DVec3::new(angle.cos(), -angle.sin(), 0.0);
        let arm_up = DVec3::new(angle.sin(), angle.cos(), 0.0);
        let arm = s.arm_length * h;
        let (upper_arm, forearm, hand) = (0.28 * arm, 0.25 * arm, 0.18 * arm);
        let shoulder = DVec3::new(0.19 * g * s.shoulder_width, hip_y + 0.50 * torso, -0.01 * g);
        for (side, sign) in [(0usize, -1.0), (3usize, 1.0)] {
            let m = DVec3::new(sign, 1.0, 1.0);
            joints[R_SHOULDER + side] = shoulder * m;
            joints[R_ELBOW + side] = (shoulder + arm_dir * upper_arm) * m;
            joints[R_HAND + side] = (shoulder + arm_dir * (upper_arm + forearm)) * m;
        }
        Self {
            joints,
            arm_dir,
            arm_up,
            upper_arm,
            forearm,
            hand,
        }
    }
}

/// A closed quad mesh with per-vertex joint weights.
#[derive(Default, Clone)]
struct Cage {
    positions: Vec<DVec3>,
    weights: Vec<[f64; NUM_JOINTS]>,
    quads: Vec<[u32; 4]>,
}

/// One cross-section target of an extrusion: centre, frame axes and half sizes.
struct Section {
    center: DVec3,
    u: DVec3,
    v: DVec3,
    half_u: f64,
    half_v: f64,
    weights: [f64; NUM_JOINTS],
}

fn w1(j: usize) -> [f64; NUM_JOINTS] {
    let mut w = [0.0; NUM_JOINTS];
    w[j] = 1.0;
    w
}

fn w2(a: usize, b: usize, t: f64) -> [f64; NUM_JOINTS] {
    let mut w = [0.0; NUM_JOINTS];
    w[a] += 1.0 - t;
    w[b] += t;
    w
}

impl Cage {
    fn add_vertex(&mut self, p: DVec3, w: [f64; NUM_JOINTS]) -> u32 {
        self.positions.push(p);
        self.weights.push(w);
        (self.positions.len() - 1) as u32
    }

    fn centroid(&self, face: usize) -> DVec3 {
        self.quads[face]
            .iter()
            .map(|&i| self.positions[i as usize])
            .sum::<DVec3>()
            / 4.0
    }

    /// Extrudes quad `face` to `section`; returns the four side quads (in edge order). The moved
    /// face keeps its index.
    fn extrude(&mut self, face: usize, s: &Section) -> [usize; 4] {
        let old = self.quads[face];
        let c = self.centroid(face);
        let new: Vec<u32> = old
            .iter()
            .map(|&i| {
                let o = self.positions[i as usize] - c;
                let p = s.center
                    + s.u * s.half_u * o.dot(s.u).signum()
                    + s.v * s.half_v * o.dot(s.v).signum();
                self.add_vertex(p, s.weights)
            })
            .collect();
        let mut sides = [0; 4];
        for k in 0..4 {
            let (p, q) = (old[k], old[(k + 1) % 4]);
            let (p2, q2) = (new[k], new[(k + 1) % 4]);
            self.quads.push([p, q, q2, p2]);
            sides[k] = self.quads.len() - 1;
        }
        self.quads[face] = [new[0], new[1], new[2], new[3]];
        sides
    }

    /// One Catmull–Clark step on a closed quad mesh; weights follow the position masks.
    fn subdivide(&self) -> Cage {
        let nv = self.positions.len();
        let mut out = Cage::default();
        // Edge table in first-seen order: (a, b) with a < b → (edge index, adjacent faces).
        let mut edge_index: HashMap<(u32, u32), usize> = HashMap::new();
        let mut edges: Vec<((u32, u32), Vec<usize>)> = Vec::new();
        for (f, q) in self.quads.iter().enumerate() {
            for k in 0..4 {
                let (a, b) = (q[k], q[(k + 1) % 4]);
                let key = (a.min(b), a.max(b));
                let e = *edge_index.entry(key).or_insert_with(|| {
                    edges.push((key, Vec::new()));
                    edges.len() - 1
                });
                edges[e].1.push(f);
            }
        }
        let face_pts: Vec<(DVec3, [f64; NUM_JOINTS])> = self
            .quads
            .iter()
            .map(|q| {
                let p = q.iter().map(|&i| self.positions[i as usize]).sum::<DVec3>() / 4.0;
                (p, avg(q.iter().map(|&i| &self.weights[i as usize])))
            })
            .collect();
        let edge_pts: Vec<(DVec3, [f64; NUM_JOINTS])> = edges
            .iter()
            .map(|((a, b), faces)| {
                debug_assert_eq!(faces.len(), 2, "the cage must be closed and manifold");
                let (a, b) = (*a as usize, *b as usize);
                let p = (self.positions[a]
                    + self.positions[b]
                    + face_pts[faces[0]].0
                    + face_pts[faces[1]].0)
                    / 4.0;
                let w = avg([
                    &self.weights[a],
                    &self.weights[b],
                    &face_pts[faces[0]].1,
                    &face_pts[faces[1]].1,
                ]);
                (p, w)
            })
            .collect();
        // Vertex rule: (F + 2R + (n − 3) P) / n.
        let mut f_sum = vec![(DVec3::ZERO, [0.0; NUM_JOINTS], 0usize); nv];
        for (f, q) in self.quads.iter().enumerate() {
            for &i in q {
                let s = &mut f_sum[i as usize];
                s.0 += face_pts[f].0;
                add(&mut s.1, &face_pts[f].1, 1.0);
                s.2 += 1;
            }
        }
        let mut r_sum = vec![(DVec3::ZERO, [0.0; NUM_JOINTS]); nv];
        for ((a, b), _) in &edges {
            let (a, b) = (*a as usize, *b as usize);
            let mid = (self.positions[a] + self.positions[b]) / 2.0;
            let wmid = avg([&self.weights[a], &self.weights[b]]);
            for i in [a, b] {
                r_sum[i].0 += mid;
                add(&mut r_sum[i].1, &wmid, 1.0);
            }
        }
        for i in 0..nv {
            let n = f_sum[i].2 as f64;
            let p = (f_sum[i].0 / n + 2.0 * r_sum[i].0 / n + (n - 3.0) * self.positions[i]) / n;
            let mut w = [0.0; NUM_JOINTS];
            add(&mut w, &f_sum[i].1, 1.0 / (n * n));
            add(&mut w, &r_sum[i].1, 2.0 / (n * n));
            add(&mut w, &self.weights[i], (n - 3.0) / n);
            out.add_vertex(p, w);
        }
        let e0 = out.positions.len() as u32;
        for (p, w) in &edge_pts {
            out.add_vertex(*p, *w);
        }
        let f0 = out.positions.len() as u32;
        for (p, w) in &face_pts {
            out.add_vertex(*p, *w);
        }
        for (f, q) in self.quads.iter().enumerate() {
            let e = |k: usize| {
                let (a, b) = (q[k], q[(k + 1) % 4]);
                e0 + edge_index[&(a.min(b), a.max(b))] as u32
            };
            for k in 0..4 {
                out.quads.push([q[k], e(k), f0 + f as u32, e((k + 3) % 4)]);
            }
        }
        out
    }

    fn into_parts(self) -> (Vec<DVec3>, Vec<[u32; 4]>, Vec<[f64; NUM_JOINTS]>) {
        (self.positions, self.quads, self.weights)
    }
}

fn add(acc: &mut [f64; NUM_JOINTS], w: &[f64; NUM_JOINTS], s: f64) {
    for (a, b) in acc.iter_mut().zip(w) {
        *a += s * b;
    }
}

fn avg<'a>(ws: impl IntoIterator<Item = &'a [f64; NUM_JOINTS]>) -> [f64; NUM_JOINTS] {
    let mut acc = [0.0; NUM_JOINTS];
    let mut n = 0.0;
    for w in ws {
        add(&mut acc, w, 1.0);
        n += 1.0;
    }
    acc.map(|a| a / n)
}

/// Cage sizes are those of the subdivided surface times this factor (Catmull–Clark pulls a coarse
/// cage inwards by roughly a quarter of its half-width on convex sections).
const INFLATE: f64 = 1.3;

fn build_cage(cage: &mut Cage, sk: &Skeleton, s: &BodyShape) {
    let h = s.height;
    let g = s.girth * h;
    let lg = s.limb_girth * h;
    let j = &sk.joints;
    let hip_y = j[R_HIP].y;
    let torso = s.torso_length * h;
    // Torso rings: (height above hips in torso units, half-width w, inner x a, half-depth d, weights).
    let rings: [(f64, f64, f64, f64, [f64; NUM_JOINTS]); 6] = [
        (-0.12, 0.15, 0.055, 0.085, w1(ROOT)),
        (0.01, 0.175, 0.07, 0.11, w1(ROOT)),
        (0.15, 0.145, 0.06, 0.095, w2(ROOT, LOWER_TORSO, 0.8)),
        (
            0.30,
            0.155,
            0.065,
            0.105,
            w2(LOWER_TORSO, MIDDLE_TORSO, 0.6),
        ),
        (0.44, 0.17, 0.07, 0.11, w1(MIDDLE_TORSO)),
        (0.56, 0.16, 0.055, 0.075, w1(MIDDLE_TORSO)),
    ];
    let mut ring_ids: Vec<[u32; 8]> = Vec::new();
    for (dy, w, a, d, wt) in rings {
        let y = hip_y + dy * torso;
        let (w, a, d) = (
            w * g * INFLATE,
            a * g * INFLATE,
            d * g * INFLATE * s.chest_depth,
        );
        let z0 = -0.01 * g;
        let pts = [
            (w, d),
            (a, d),
            (-a, d),
            (-w, d),
            (-w, -d),
            (-a, -d),
            (a, -d),
            (w, -d),
        ];
        ring_ids.push(pts.map(|(x, z)| cage.add_vertex(DVec3::new(x, y, z + z0), wt)));
    }
    let mut left_arm_face = 0;
    let mut right_arm_face = 0;
    for k in 0..ring_ids.len() - 1 {
        let (r0, r1) = (ring_ids[k], ring_ids[k + 1]);
        for i in 0..8 {
            let i1 = (i + 1) % 8;
            cage.quads.push([r0[i], r0[i1], r1[i1], r1[i]]);
            if k == 4 && i == 7 {
                left_arm_face = cage.quads.len() - 1;
            }
            if k == 4 && i == 3 {
                right_arm_face = cage.quads.len() - 1;
            }
        }
    }
    let b = ring_ids[0];
    cage.quads.push([b[1], b[0], b[7], b[6]]);
    let left_leg_face = cage.quads.len() - 1;
    cage.quads.push([b[2], b[1], b[6], b[5]]);
    cage.quads.push([b[3], b[2], b[5], b[4]]);
    let right_leg_face = cage.quads.len() - 1;
    let t = ring_ids[5];
    cage.quads.push([t[0], t[1], t[6], t[7]]);
    cage.quads.push([t[1], t[2], t[5], t[6]]);
    let neck_face = cage.quads.len() - 1;
    cage.quads.push([t[2], t[3], t[4], t[5]]);

    // Legs: (height as a fraction of leg length, half-width, z, half-depth, weights).
    let leg = s.leg_length * h;
    for (face, hip, knee, ankle, foot) in [
        (left_leg_face, L_HIP, L_KNEE, L_ANKLE, L_FOOT),
        (right_leg_face, R_HIP, R_KNEE, R_ANKLE, R_FOOT),
    ] {
        let x0 = j[hip].x;
        let xa = j[ankle].x;
        let sections: [(f64, f64, f64, f64, [f64; NUM_JOINTS]); 6] = [
            (0.80, 0.082, 0.0, 0.085, w2(ROOT, hip, 0.8)),
            (0.68, 0.075, 0.005, 0.078, w1(hip)),
            (0.54, 0.055, 0.012, 0.058, w2(hip, knee, 0.5)),
            (0.38, 0.052, 0.0, 0.058, w1(knee)),
            (0.13, 0.034, -0.012, 0.038, w2(knee, ankle, 0.6)),
            (0.02, 0.04, -0.015, 0.05, w1(ankle)),
        ];
        let mut sides = [0; 4];
        for (yf, hw, z, hd, wt) in sections {
            let y = yf * leg;
            let x = x0 + (xa - x0) * ((0.92 - yf) / 0.84).clamp(0.0, 1.0);
            let sec = Section {
                center: DVec3::new(x, y, z * h),
                u: DVec3::X,
                v: DVec3::Z,
                half_u: hw * lg * INFLATE,
                half_v: hd * lg * INFLATE,
                weights: wt,
            };
            sides = cage.extrude(face, &sec);
        }
        // The foot grows forward from the front side of the last (heel) segment.
        let front = *sides
            .iter()
            .max_by(|&&a, &&b| cage.centroid(a).z.total_cmp(&cage.centroid(b).z))
            .unwrap_or(&sides[0]);
        let fx = j[foot].x;
        for (y, z, hw, hh, wt) in [
            (0.045, 0.07, 0.045, 0.035, w2(ankle, foot, 0.2)),
            (0.03, 0.13, 0.047, 0.025, w2(ankle, foot, 0.7)),
            (0.022, 0.19, 0.04, 0.016, w1(foot)),
        ] {
            let sec = Section {
                center: DVec3::new(fx, y * h, z * h),
                u: DVec3::X,
                v: DVec3::Y,
                half_u: hw * lg * INFLATE,
                half_v: hh * lg * INFLATE,
                weights: wt,
            };
            cage.extrude(front, &sec);
        }
    }

    // Arms: (distance along the arm from the shoulder, half-size across (z), half-size up, weights).
    for (sign, face, shoulder, elbow, hand) in [
        (1.0, left_arm_face, L_SHOULDER, L_ELBOW, L_HAND),
        (-1.0, right_arm_face, R_SHOULDER, R_ELBOW, R_HAND),
    ] {
        let m = DVec3::new(sign, 1.0, 1.0);
        let dir = sk.arm_dir * m;
        let up = sk.arm_up * m;
        let (ua, fa, hd) = (sk.upper_arm, sk.forearm, sk.hand);
        let sections: [(f64, f64, f64, [f64; NUM_JOINTS]); 7] = [
            (0.03, 0.058, 0.062, w2(MIDDLE_TORSO, shoulder, 0.6)),
            (ua * 0.5, 0.05, 0.05, w1(shoulder)),
            (ua, 0.042, 0.042, w2(shoulder, elbow, 0.5)),
            (ua + fa * 0.45, 0.04, 0.036, w1(elbow)),
            (ua + fa, 0.028, 0.022, w2(elbow, hand, 0.5)),
            (ua + fa + hd * 0.45, 0.045, 0.016, w1(hand)),
            (ua + fa + hd, 0.03, 0.011, w1(hand)),
        ];
        for (dist, hu, hv, wt) in sections {
            let sec = Section {
                center: j[shoulder] + dir * dist,
                u: DVec3::Z,
                v: up,
                half_u: hu * lg * INFLATE,
                half_v: hv * lg * INFLATE,
                weights: wt,
            };
            cage.extrude(face, &sec);
        }
    }

    // Neck and head: (height above the head joint, z, half-width, half-depth, weights).
    let hs = s.head * h;
    let base = j[HEAD];
    for (dy, z, hw, hd, wt) in [
        (0.03, 0.0, 0.05, 0.05, w2(MIDDLE_TORSO, HEAD, 0.5)),
        (0.09, 0.01, 0.055, 0.065, w1(HEAD)),
        (0.15, 0.015, 0.08, 0.095, w1(HEAD)),
        (0.23, 0.01, 0.085, 0.1, w1(HEAD)),
        (0.30, 0.0, 0.065, 0.08, w1(HEAD)),
    ] {
        let sec = Section {
            center: DVec3::new(0.0, base.y + dy * hs, base.z + z * hs),
            u: DVec3::X,
            v: DVec3::Z,
            half_u: hw * hs * INFLATE,
            half_v: hd * hs * INFLATE,
            weights: wt,
        };
        cage.extrude(neck_face, &sec);
    }
}

/// Vicon Plug-in Gait-like marker set: (name, anchor, direction, joints the vertex may belong to).
fn marker_specs(j: &[DVec3], sk: &Skeleton) -> Vec<(String, DVec3, DVec3, Vec<usize>)> {
    let mut specs: Vec<(String, DVec3, DVec3, Vec<usize>)> = Vec::new();
    let head_c = j[HEAD] + DVec3::new(0.0, 0.17, 0.01);
    for (n, d) in [
        ("LFHD", (0.5, 0.3, 1.0)),
        ("RFHD", (-0.5, 0.3, 1.0)),
        ("LBHD", (0.5, 0.3, -1.0)),
        ("RBHD", (-0.5, 0.3, -1.0)),
    ] {
        specs.push((n.into(), head_c, DVec3::from(d), vec![HEAD]));
    }
    let mt = j[MIDDLE_TORSO];
    specs.push((
        "C7".into(),
        j[HEAD] - DVec3::new(0.0, 0.02, 0.0),
        DVec3::new(0.0, 0.3, -1.0),
        vec![MIDDLE_TORSO, HEAD],
    ));
    specs.push((
        "T10".into(),
        mt,
        DVec3::new(0.0, 0.0, -1.0),
        vec![LOWER_TORSO, MIDDLE_TORSO],
    ));
    specs.push((
        "CLAV".into(),
        j[HEAD] - DVec3::new(0.0, 0.06, 0.0),
        DVec3::new(0.0, 0.2, 1.0),
        vec![MIDDLE_TORSO],
    ));
    specs.push((
        "STRN".into(),
        mt + DVec3::new(0.0, 0.07, 0.0),
        DVec3::new(0.0, 0.0, 1.0),
        vec![MIDDLE_TORSO, LOWER_TORSO],
    ));
    specs.push((
        "RBAK".into(),
        mt + DVec3::new(-0.08, 0.09, 0.0),
        DVec3::new(-0.3, 0.0, -1.0),
        vec![MIDDLE_TORSO],
    ));
    for (p, sign, sh, el, hd, hip, kn, an, ft) in [
        (
            "L", 1.0, L_SHOULDER, L_ELBOW, L_HAND, L_HIP, L_KNEE, L_ANKLE, L_FOOT,
        ),
        (
            "R", -1.0, R_SHOULDER, R_ELBOW, R_HAND, R_HIP, R_KNEE, R_ANKLE, R_FOOT,
        ),
    ] {
        let m = DVec3::new(sign, 1.0, 1.0);
        let dir = sk.arm_dir * m;
        let up = sk.arm_up * m;
        let out = (up + DVec3::new(0.0, 0.0, -0.3)).normalize();
        specs.push((format!("{p}SHO"), j[sh], DVec3::Y, vec![sh, MIDDLE_TORSO]));
        specs.push((
            format!("{p}UPA"),
            j[sh] + dir * sk.upper_arm * 0.5,
            out,
            vec![sh],
        ));
        specs.push((
            format!("{p}ELB"),
            j[el],
            DVec3::new(0.0, 0.0, -1.0),
            vec![el, sh],
        ));
        specs.push((
            format!("{p}FRM"),
            j[el] + dir * sk.forearm * 0.5,
            out,
            vec![el],
        ));
        specs.push((format!("{p}WRA"), j[hd], DVec3::Z, vec![hd, el]));
        specs.push((format!("{p}WRB"), j[hd], -DVec3::Z, vec![hd, el]));
        specs.push((
            format!("{p}FIN"),
            j[hd] + dir * sk.hand * 0.45,
            up,
            vec![hd],
        ));
        let pelvis = DVec3::new(sign * 0.09, j[ROOT].y + 0.04, 0.0);
        specs.push((
            format!("{p}ASI"),
            pelvis,
            DVec3::new(sign * 0.2, 0.0, 1.0),
            vec![ROOT],
        ));
        specs.push((
            format!("{p}PSI"),
            pelvis * DVec3::new(0.5, 1.0, 1.0),
            DVec3::new(sign * 0.1, 0.0, -1.0),
            vec![ROOT],
        ));
        let lateral = DVec3::new(sign, 0.0, 0.0);
        specs.push((
            format!("{p}THI"),
            j[hip].lerp(j[kn], 0.45),
            lateral + DVec3::new(0.0, 0.0, 0.2),
            vec![hip],
        ));
        specs.push((format!("{p}KNE"), j[kn], lateral, vec![kn, hip]));
        specs.push((
            format!("{p}TIB"),
            j[kn].lerp(j[an], 0.5),
            lateral + DVec3::new(0.0, 0.0, 0.2),
            vec![kn],
        ));
        specs.push((format!("{p}ANK"), j[an], lateral, vec![an, kn]));
        specs.push((
            format!("{p}HEE"),
            DVec3::new(j[an].x, 0.05, j[an].z),
            -DVec3::Z,
            vec![an],
        ));
        specs.push((
            format!("{p}TOE"),
            j[ft],
            DVec3::new(0.0, 0.5, 1.0),
            vec![ft, an],
        ));
    }
    specs
}

/// Each marker goes on the vertex furthest along its ray from the anchor, penalising distance
/// from the ray, among vertices dominated by one of the listed joints; no two share a vertex.
fn place_markers(template: &Template, joints: &[DVec3], sk: &Skeleton) -> Vec<Marker> {
    let dominant = template.dominant_joint();
    let mut used = std::collections::HashSet::new();
    let mut markers = Vec::new();
    for (name, anchor, dir, allowed) in marker_specs(joints, sk) {
        let dir = dir.normalize();
        let mut best: Option<(f64, usize)> = None;
        for (v, p) in template.vertices.iter().enumerate() {
            if !allowed.contains(&dominant[v]) || used.contains(&v) {
                continue;
            }
            let o = p.as_dvec3() - anchor;
            let along = o.dot(dir);
            if along <= 0.0 {
                continue;
            }
            let score = along - 3.0 * (o - dir * along).length();
            if best.is_none_or(|(s, _)| score > s) {
                best = Some((score, v));
            }
        }
        if let Some((_, v)) = best {
            used.insert(v);
            markers.push(Marker {
                name,
                vertex: v as u32,
            });
        }
    }
    markers
}

/// A random SMPL-like model for tests and benchmarks: 24 joints in SMPL's tree and names, `v`
/// vertices in a standing body's box, 1–6 influences per vertex, `b` shape columns, optional pose
/// correctives, a sparse regressor (5 vertices per joint), 30 markers. Same seed, same model.
///
/// # Panics
/// Never for `v ≥ 3`.
pub fn smpl_like(seed: u64, v: usize, b: usize, with_posedirs: bool) -> crate::template::Template {
    use rand::{Rng, SeedableRng};
    const PARENTS: [i64; 24] = [
        -1, 0, 0, 0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 9, 9, 12, 13, 14, 16, 17, 18, 19, 20, 21,
    ];
    let j = PARENTS.len();
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    let rest: Vec<DVec3> = (0..v)
        .map(|_| {
            DVec3::new(
                rng.random_range(-0.4..0.4),
                rng.random_range(0.0..1.7),
                rng.random_range(-0.15..0.15),
            )
        })
        .collect();
    let mut reg = vec![0.0; j * v];
    for r in 0..j {
        let picks: Vec<(usize, f64)> = (0..5)
            .map(|_| (rng.random_range(0..v), rng.random_range(0.1..1.0)))
            .collect();
        let total: f64 = picks.iter().map(|p| p.1).sum();
        for (c, w) in picks {
            reg[r * v + c] += w / total;
        }
    }
    let reg = SparseRows::from_dense(j, v, &reg);
    let joints_rest = reg.apply(&rest);
    let weights: Vec<Vec<(usize, f64)>> = (0..v)
        .map(|i| {
            let mut raw = vec![0.0; j];
            for _ in 0..1 + i % 6 {
                raw[rng.random_range(0..j)] += rng.random_range(0.05..1.0);
            }
            let total: f64 = raw.iter().sum();
            raw.iter()
                .enumerate()
                .filter(|(_, w)| **w > 0.0)
                .map(|(c, w)| (c, w / total))
                .collect()
        })
        .collect();
    let faces: Vec<[u32; 3]> = (0..v / 2)
        .map(|k| {
            [
                (2 * k) as u32,
                ((2 * k + 1) % v) as u32,
                ((2 * k + 2) % v) as u32,
            ]
        })
        .collect();
    let joints = (0..j)
        .map(|c| crate::rig::Joint {
            name: crate::info::SMPL_JOINT_NAMES[c].into(),
            parent: (PARENTS[c] >= 0).then(|| PARENTS[c] as usize),
            rest_position: joints_rest[c].to_array(),
        })
        .collect();
    let markers = (0..30)
        .map(|m| crate::rig::Marker {
            name: format!("m{m}"),
            vertex: rng.random_range(0..v) as u32,
        })
        .collect();
    let rig = crate::rig::Rig {
        joints,
        weights,
        markers,
    };
    let vertices: Vec<glam::Vec3> = rest.iter().map(|p| p.as_vec3()).collect();
    let t = crate::template::Template::new("smpl-like", vertices, faces, rig)
        .expect("valid test model");
    let dirs: Vec<f64> = (0..3 * v * b)
        .map(|_| rng.random_range(-0.02..0.02))
        .collect();
    let posedirs = with_posedirs.then(|| {
        (0..3 * v * 9 * (j - 1))
            .map(|_| rng.random_range(-0.01..0.01))
            .collect()
    });
    let info = crate::info::ModelInfo::fallback(&t.rig);
    t.with_morph(Morph::new(rest, b, 0, dirs, posedirs, Some(reg)), info)
        .expect("consistent test morph")
}

/// A joint regressor for a template without one: for each joint, the minimum-norm affine
/// combination of the `K` rest vertices nearest to it that reproduces the joint exactly
/// (`Σ w = 1`, `Σ w v = c`), so `J_regressor · v_template` gives the rig's rest joints.
pub fn fit_regressor(template: &Template) -> SparseRows {
    const K: usize = 32;
    let v = template.num_vertices();
    let rest: Vec<DVec3> = template.vertices.iter().map(|p| p.as_dvec3()).collect();
    let mut dense = vec![0.0; template.rig.num_joints() * v];
    for (j, joint) in template.rig.joints.iter().enumerate() {
        let c = joint.rest();
        let mut order: Vec<usize> = (0..v).collect();
        order.sort_by(|&a, &b| {
            rest[a]
                .distance_squared(c)
                .total_cmp(&rest[b].distance_squared(c))
        });
        order.truncate(K.min(v));
        // A (4 × K) = [v; 1], w = Aᵀ (A Aᵀ)⁻¹ [c; 1], centred on c for conditioning.
        let a = nalgebra::DMatrix::from_fn(4, order.len(), |r, k| {
            if r < 3 { (rest[order[k]] - c)[r] } else { 1.0 }
        });
        let b = nalgebra::DVector::from_vec(vec![0.0, 0.0, 0.0, 1.0]);
        let aat = &a * a.transpose();
        let w = match aat.clone().cholesky() {
            Some(ch) => a.transpose() * ch.solve(&b),
            // Degenerate (all nearest vertices coplanar with the joint): the nearest vertex.
            None => nalgebra::DVector::from_fn(order.len(), |k, _| if k == 0 { 1.0 } else { 0.0 }),
        };
        for (k, &vi) in order.iter().enumerate() {
            dense[j * v + vi] = w[k];
        }
    }
    SparseRows::from_dense(template.rig.num_joints(), v, &dense)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_morphable_default_template_spans_the_proportion_variants() {
        let (t, explained) = morphable_default_template().unwrap();
        assert_eq!(t.layout().dim(), 57 + MORPHABLE_SHAPE_DIM);
        let cumulative: f64 = explained.iter().sum();
        println!(
            "morphable default template: variance explained {explained:.4?}, total {cumulative:.5}"
        );
        assert!(explained.windows(2).all(|w| w[0] >= w[1]));
        assert!(cumulative > 0.99, "{cumulative}");
        // Every direction carries variance: none is unobservable.
        assert!(explained[MORPHABLE_SHAPE_DIM - 1] > 1e-4, "{explained:?}");
        // β = 0 is the default template, exactly.
        let d = default_template();
        let pose: Vec<f64> = (0..57)
            .map(|i| ((i * 37 % 19) as f64 / 19.0 - 0.5) * 0.8)
            .collect();
        let mut x = pose.clone();
        x.extend([0.0; MORPHABLE_SHAPE_DIM]);
        let a = crate::skinning::pose_vertices(&d, &pose, crate::SkinningMethod::Linear);
        let b = crate::skinning::pose_vertices(&t, &x, crate::SkinningMethod::Linear);
        let worst = a
            .iter()
            .zip(&b)
            .map(|(p, q)| (*p - *q).length())
            .fold(0.0, f32::max);
        assert!(worst < 1e-5, "{worst}");
        // The tall variant is close to the span: its least-squares coefficients reproduce it
        // within a few millimetres, and the first direction changes the height.
        let tall = build_template(&BodyShape::named("tall").unwrap(), "tall").unwrap();
        let k = MORPHABLE_SHAPE_DIM;
        let m = &t.morph;
        let dev: Vec<f64> = tall
            .vertices
            .iter()
            .zip(&d.vertices)
            .flat_map(|(p, q)| (p.as_dvec3() - q.as_dvec3()).to_array())
            .collect();
        let a_mat = nalgebra::DMatrix::from_fn(dev.len(), k, |r, c| m.dirs[r * k + c]);
        let beta = a_mat
            .clone()
            .svd(true, true)
            .solve(&nalgebra::DVector::from_vec(dev.clone()), 1e-12)
            .unwrap();
        let fit = &a_mat * &beta;
        let worst = (0..dev.len() / 3)
            .map(|v| {
                ((fit[3 * v] - dev[3 * v]).powi(2)
                    + (fit[3 * v + 1] - dev[3 * v + 1]).powi(2)
                    + (fit[3 * v + 2] - dev[3 * v + 2]).powi(2))
                .sqrt()
            })
            .fold(0.0, f64::max);
        println!(
            "tall variant in the shape space: worst vertex error {:.2} mm, β = {:.2?}",
            worst * 1e3,
            beta.as_slice()
        );
        assert!(worst < 0.01, "{worst}");
        let ys: Vec<f64> = (0..d.num_vertices())
            .map(|v| m.dirs[(3 * v + 1) * k])
            .collect();
        assert!(
            ys.iter().copied().fold(f64::MIN, f64::max) > 0.01,
            "the first direction moves vertices"
        );
    }

    #[test]
    fn default_template_is_a_closed_two_manifold_of_the_right_size() {
        let t = default_template();
        let n = t.num_vertices();
        assert!((3000..=8000).contains(&n), "{n} vertices");
        let mut edges: HashMap<(u32, u32), usize> = HashMap::new();
        for f in &t.faces {
            for k in 0..3 {
                let (a, b) = (f[k], f[(k + 1) % 3]);
                *edges.entry((a.min(b), a.max(b))).or_default() += 1;
            }
        }
        assert!(
            edges.values().all(|&c| c == 2),
            "an edge without exactly two faces"
        );
        // Euler characteristic of a sphere: V − E + F = 2.
        assert_eq!(n as i64 - edges.len() as i64 + t.faces.len() as i64, 2);
        assert!(
            signed_volume(&t.vertices, &t.faces) > 0.03,
            "outward winding, body-sized volume"
        );
        assert_eq!(t.rig.joints.len(), 18);
        assert_eq!(t.rig.markers.len(), 39);
    }

    #[test]
    fn height_and_symmetry() {
        let t = default_template();
        let (lo, hi) = t.vertices.iter().fold((f32::MAX, f32::MIN), |(lo, hi), v| {
            (lo.min(v.y), hi.max(v.y))
        });
        assert!(lo.abs() < 1e-6);
        assert!((1.65..1.85).contains(&hi), "height {hi}");
        // Every vertex has a mirror image across x = 0.
        let set: std::collections::HashSet<[i64; 3]> = t
            .vertices
            .iter()
            .map(|v| {
                [
                    (v.x * 1e4).round() as i64,
                    (v.y * 1e4).round() as i64,
                    (v.z * 1e4).round() as i64,
                ]
            })
            .collect();
        let mirrored = t
            .vertices
            .iter()
            .filter(|v| {
                set.contains(&[
                    (-v.x * 1e4).round() as i64,
                    (v.y * 1e4).round() as i64,
                    (v.z * 1e4).round() as i64,
                ])
            })
            .count();
        assert!(mirrored as f64 > 0.95 * t.num_vertices() as f64);
    }

    #[test]
    fn variants_share_topology() {
        let d = default_template();
        for name in BodyShape::NAMES {
            let shape = BodyShape::named(name).unwrap();
            let t = build_template(&shape, name).unwrap();
            assert_eq!(t.num_vertices(), d.num_vertices());
            assert_eq!(t.faces, d.faces);
        }
        let tall = build_template(&BodyShape::named("tall").unwrap(), "tall").unwrap();
        let h = |t: &Template| t.vertices.iter().map(|v| v.y).fold(f32::MIN, f32::max);
        assert!(h(&tall) > 1.05 * h(&d));
    }
}
