//! Retargeting a BVH clip onto an lfit model (SPEC §3a "Motions"): through a joint-name map,
//! by world-space rotation relative to each skeleton's rest pose.
//!
//! **Rotations.** lfit's rest pose has the identity orientation at every joint (rotations are
//! relative to the parent in the world-aligned rest frame); so does a BVH's (all channels zero).
//! For a mapped model joint `m` driven by BVH joint `b`, `W_b` is the BVH world rotation in a
//! frame (converted to lfit's axes, `C W_b Cᵀ`), `d` the model's rest bone directions from `m` to
//! its nearest mapped descendants and `e` the BVH's rest bone directions between the joints they
//! map to. `Q_m` is the rest-alignment rotation taking the `d` onto the `e` (the minimal rotation
//! for one bone or collinear bones; the least-squares rotation, Wahba's problem solved by SVD,
//! for several), so that a T-pose capture drives an A-pose model. The model's world rotation is
//! then `G_m = W_b Q_m`: its posed bones `G_m d = W_b e` point where the BVH's do. A joint with no
//! mapped descendant (a hand, the head) takes the alignment of its nearest mapped ancestor;
//! unmapped model joints keep the identity relative to their parent. Local rotations are
//! `R_m = G_parent(m)ᵀ G_m`, written as axis-angle.
//!
//! **Axes and units.** lfit is y up, the subject faces +z, +x is the subject's left, metres.
//! `--up y` takes the BVH's axes as they are; `--up z` converts a Z-up capture (Blender, 3ds
//! Max: the subject facing −y) by a −90° rotation about x: `(x, y, z) ↦ (x, z, −y)`. A subject
//! facing elsewhere is turned by the root's rest alignment. Units: `m`, `cm`, or `auto` (cm when
//! the rest skeleton, end sites included, is more than 3 units tall along the up axis).
//!
//! **Root translation.** The translation follows the *anchor*: the mapped model joint nearest the
//! root (normally the root/pelvis) and its BVH joint. With `--root floor` (the default) the BVH's
//! ground is its plane y = 0 (after the up-axis conversion) and the model's is lfit's y = 0; the
//! anchor's height above the ground is scaled by `k = l_model / l_bvh`, the ratio of the leg
//! lengths (bone lengths from the anchor to the lowest mapped joint), and its horizontal
//! displacement from the BVH's rest position is scaled by the same `k` and added to the model's
//! rest position, so a shorter model takes proportionally shorter steps and keeps its feet on the
//! ground. The lowest mapped joint is the lowest in the model's rest pose (which stands); the leg
//! is the path of model joints from it to the anchor, and its length the sum of the straight-line
//! rest distances between consecutive *mapped* joints on that path, measured on the model and
//! between the BVH joints they map to. Being lengths, not heights, they do not depend on how the
//! rest pose is oriented: a BVH whose zero-rotation rest pose does not stand (bones along +x, as
//! game engines export them) scales like a standing one. `k = 1` when either length is zero or
//! the lowest mapped joint is the anchor. For a BVH written from the same model (`lfit motion
//! export`) `k = 1` and the translation comes back exactly. With `--root rest` the anchor moves by
//! the BVH displacement from its rest position (metres, unscaled): for files whose rest pose
//! already stands where the motion does.

use std::path::{Path, PathBuf};

use glam::{DMat3, DQuat, DVec3};
use lfit_model::template::Template;

use crate::motion::bvh::{Bvh, BvhError, BvhPose};

/// Errors of motion import and export.
#[derive(Debug, thiserror::Error)]
pub enum MotionError {
    #[error("{path}: {source}")]
    Bvh {
        path: PathBuf,
        #[source]
        source: BvhError,
    },
    #[error("cannot read {path}: {source}")]
    Read {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("{0}")]
    Invalid(String),
    #[error(transparent)]
    Model(#[from] lfit_model::ModelError),
}

fn invalid<T>(msg: impl Into<String>) -> Result<T, MotionError> {
    Err(MotionError::Invalid(msg.into()))
}

/// Reads and parses a BVH file.
pub fn read_bvh(path: &Path) -> Result<Bvh, MotionError> {
    let text = std::fs::read_to_string(path).map_err(|source| MotionError::Read {
        path: path.to_path_buf(),
        source,
    })?;
    Bvh::parse(&text).map_err(|source| MotionError::Bvh {
        path: path.to_path_buf(),
        source,
    })
}

/// A joint-name map: BVH joint name → model joint name.
///
/// File formats: a JSON object `{"Hips": "root", ...}`, or `{"joints": {...}, ...}` (other
/// top-level keys such as `"description"` are ignored), or text lines `BVH_NAME MODEL_NAME`
/// (`#` starts a comment; use JSON for names with spaces).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct JointMap {
    pub pairs: Vec<(String, String)>,
}

/// A JSON value that keeps object keys in file order, duplicates included (serde_json's map
/// sorts them and keeps only the last duplicate).
#[derive(Debug, Clone)]
enum JsonItem {
    Text(String),
    Object(Vec<(String, JsonItem)>),
    Other,
}

impl<'de> serde::Deserialize<'de> for JsonItem {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        struct V;
        impl<'de> serde::de::Visitor<'de> for V {
            type Value = JsonItem;
            fn expecting(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
                f.write_str("a JSON value")
            }
            fn visit_str<E: serde::de::Error>(self, v: &str) -> Result<JsonItem, E> {
                Ok(JsonItem::Text(v.to_string()))
            }
            fn visit_map<A: serde::de::MapAccess<'de>>(
                self,
                mut a: A,
            ) -> Result<JsonItem, A::Error> {
                let mut out = Vec::new();
                while let Some((k, v)) = a.next_entry::<String, JsonItem>()? {
                    out.push((k, v));
                }
                Ok(JsonItem::Object(out))
            }
            fn visit_seq<A: serde::de::SeqAccess<'de>>(
                self,
                mut a: A,
            ) -> Result<JsonItem, A::Error> {
                while a.next_element::<serde::de::IgnoredAny>()?.is_some() {}
                Ok(JsonItem::Other)
            }
            fn visit_bool<E: serde::de::Error>(self, _: bool) -> Result<JsonItem, E> {
                Ok(JsonItem::Other)
            }
            fn visit_i64<E: serde::de::Error>(self, _: i64) -> Result<JsonItem, E> {
                Ok(JsonItem::Other)
            }
            fn visit_u64<E: serde::de::Error>(self, _: u64) -> Result<JsonItem, E> {
                Ok(JsonItem::Other)
            }
            fn visit_f64<E: serde::de::Error>(self, _: f64) -> Result<JsonItem, E> {
                Ok(JsonItem::Other)
            }
            fn visit_unit<E: serde::de::Error>(self) -> Result<JsonItem, E> {
                Ok(JsonItem::Other)
            }
        }
        d.deserialize_any(V)
    }
}

impl JointMap {
    pub fn parse(text: &str) -> Result<Self, String> {
        let trimmed = text.trim_start();
        let pairs: Vec<(String, String)> = if trimmed.starts_with('{') {
            let top: JsonItem =
                serde_json::from_str(text).map_err(|e| format!("malformed JSON ({e})"))?;
            let JsonItem::Object(top) = top else {
                return Err("expected a JSON object".into());
            };
            let entries = match top.iter().find(|(k, _)| k == "joints") {
                Some((_, JsonItem::Object(o))) => o.clone(),
                Some(_) => return Err("\"joints\" is not an object".into()),
                None => top,
            };
            let mut pairs = Vec::new();
            for (k, v) in entries {
                let JsonItem::Text(m) = v else {
                    return Err(format!("the value of \"{k}\" is not a model joint name"));
                };
                pairs.push((k, m));
            }
            pairs
        } else {
            let mut pairs = Vec::new();
            for (i, line) in text.lines().enumerate() {
                let line = line.split('#').next().unwrap_or("").trim();
                if line.is_empty() {
                    continue;
                }
                let words: Vec<&str> = line.split_whitespace().collect();
                let [b, m] = words.as_slice() else {
                    return Err(format!(
                        "line {}: expected 'BVH_JOINT MODEL_JOINT', found '{line}'",
                        i + 1
                    ));
                };
                pairs.push(((*b).to_string(), (*m).to_string()));
            }
            pairs
        };
        if pairs.is_empty() {
            return Err("the map has no entries".into());
        }
        for (i, (b, m)) in pairs.iter().enumerate() {
            if let Some((_, m2)) = pairs[..i].iter().find(|(b2, _)| b2 == b) {
                return Err(format!(
                    "BVH joint '{b}' is mapped twice (to '{m2}' and '{m}')"
                ));
            }
            if let Some((b2, _)) = pairs[..i].iter().find(|(_, m2)| m2 == m) {
                return Err(format!(
                    "model joint '{m}' is the target of both '{b2}' and '{b}'"
                ));
            }
        }
        Ok(Self { pairs })
    }

    pub fn read(path: &Path) -> Result<Self, MotionError> {
        let text = std::fs::read_to_string(path).map_err(|source| MotionError::Read {
            path: path.to_path_buf(),
            source,
        })?;
        Self::parse(&text)
            .map_err(|e| MotionError::Invalid(format!("joint map {}: {e}", path.display())))
    }

    /// Every BVH joint onto the model joint of the same name (all must exist in the model).
    pub fn identity(bvh: &Bvh) -> Self {
        Self {
            pairs: bvh
                .joints
                .iter()
                .map(|j| (j.name.clone(), j.name.clone()))
                .collect(),
        }
    }
}

/// Units of the BVH's lengths.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Units {
    Metres,
    Centimetres,
    /// Centimetres when the rest skeleton is more than 3 units tall, else metres.
    #[default]
    Auto,
}

impl std::str::FromStr for Units {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "m" => Ok(Units::Metres),
            "cm" => Ok(Units::Centimetres),
            "auto" => Ok(Units::Auto),
            other => Err(format!("unknown units '{other}' (expected cm, m or auto)")),
        }
    }
}

/// The up direction of a capture's world (a BVH's axes, a C3D's lab frame, a camera file's
/// world), turned onto lfit's +y.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub enum Up {
    #[default]
    Y,
    Z,
    /// Any other up direction, as a unit vector in the capture's axes (e.g. the floor plane's
    /// normal of a calibration whose board was not on the floor, or −gravity from a phone's
    /// IMU): turned onto +y by the shortest rotation, so heights above that floor become lfit's
    /// `y` (the yaw about the new up is the one that rotation leaves).
    Vector(DVec3),
}

impl std::str::FromStr for Up {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "y" | "Y" => return Ok(Up::Y),
            "z" | "Z" => return Ok(Up::Z),
            _ => {}
        }
        let bad = || {
            format!(
                "unknown up axis '{s}' (expected y, z or the up direction as three numbers x,y,z)"
            )
        };
        let parts: Vec<&str> = s.split(',').collect();
        if parts.len() != 3 {
            return Err(bad());
        }
        let mut v = [0.0; 3];
        for (x, part) in v.iter_mut().zip(&parts) {
            *x = part.trim().parse::<f64>().map_err(|_| bad())?;
        }
        let v = DVec3::from_array(v);
        if !v.is_finite() || v.length() < 1e-9 {
            return Err(format!(
                "up direction '{s}': needs three finite numbers, not all zero"
            ));
        }
        let v = v.normalize();
        // The axes named by a letter keep their exact rotations.
        Ok(if v == DVec3::Y {
            Up::Y
        } else if v == DVec3::Z {
            Up::Z
        } else {
            Up::Vector(v)
        })
    }
}

impl Up {
    /// The rotation taking the capture's axes to lfit's (y up).
    pub fn to_lfit(self) -> DMat3 {
        match self {
            Up::Y => DMat3::IDENTITY,
            Up::Z => DMat3::from_rotation_x(-std::f64::consts::FRAC_PI_2),
            Up::Vector(v) => DMat3::from_quat(DQuat::from_rotation_arc(v, DVec3::Y)),
        }
    }

    /// The setting as written: `y`, `z` or the unit vector `x,y,z`.
    pub fn name(self) -> String {
        match self {
            Up::Y => "y".into(),
            Up::Z => "z".into(),
            Up::Vector(v) => format!("{},{},{}", v.x, v.y, v.z),
        }
    }
}

/// How the root translation is placed (module docs).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum RootMode {
    #[default]
    Floor,
    Rest,
}

impl std::str::FromStr for RootMode {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "floor" => Ok(RootMode::Floor),
            "rest" => Ok(RootMode::Rest),
            other => Err(format!(
                "unknown root mode '{other}' (expected floor or rest)"
            )),
        }
    }
}

/// Settings of [`retarget`].
#[derive(Debug, Clone, Default)]
pub struct RetargetOptions {
    pub units: Units,
    pub up: Up,
    pub root: RootMode,
    /// β of the model (zero-padded; empty: zeros).
    pub shape: Vec<f64>,
}

/// The map resolved against a BVH and a model, and the rest alignments.
#[derive(Debug, Clone)]
pub struct Retargeter {
    /// BVH joint of every model joint (`None`: unmapped).
    pub bvh_of: Vec<Option<usize>>,
    /// Rest alignment `Q_m` of every mapped model joint.
    pub align: Vec<DMat3>,
    /// Bones compared for the bone-direction check: (model joint, model descendant), both mapped.
    pub bones: Vec<(usize, usize)>,
    /// Metres per BVH unit.
    pub scale: f64,
    /// BVH axes → lfit axes.
    pub axes: DMat3,
    /// The anchor model joint (the translation follows it).
    pub anchor: usize,
    /// Scale of the anchor's motion (`k` of the module docs; 1 in rest mode).
    pub root_scale: f64,
    pub root: RootMode,
    /// The model's rest joints at the options' β.
    pub rest: Vec<DVec3>,
    /// BVH rest positions in lfit axes, metres.
    pub bvh_rest: Vec<DVec3>,
    /// The full parameter vector's length and the β written into every pose.
    pub dim: usize,
    pub coeffs: Vec<f64>,
}

/// The rotation taking the directions `from` onto the directions `to` (unit vectors, pairwise):
/// the minimal rotation when they are one direction (or collinear), else the least-squares
/// rotation (Wahba's problem, by SVD).
pub fn align_directions(from: &[DVec3], to: &[DVec3]) -> DMat3 {
    if from.is_empty() {
        return DMat3::IDENTITY;
    }
    let mut b = nalgebra::Matrix3::<f64>::zeros();
    for (d, e) in from.iter().zip(to) {
        b += nalgebra::Vector3::new(e.x, e.y, e.z)
            * nalgebra::Vector3::new(d.x, d.y, d.z).transpose();
    }
    let svd = b.svd(true, true);
    let mut s: Vec<f64> = svd.singular_values.iter().copied().collect();
    s.sort_by(|a, b| b.total_cmp(a));
    let (Some(u), Some(v_t)) = (svd.u, svd.v_t) else {
        return DMat3::IDENTITY;
    };
    if s[1] <= 1e-9 * s[0].max(1e-300) {
        let mean = |v: &[DVec3]| v.iter().copied().sum::<DVec3>().normalize_or_zero();
        let (a, c) = (mean(from), mean(to));
        if a == DVec3::ZERO || c == DVec3::ZERO {
            return DMat3::IDENTITY;
        }
        return DMat3::from_quat(DQuat::from_rotation_arc(a, c));
    }
    let det = (u * v_t).determinant();
    let fix = nalgebra::Matrix3::from_diagonal(&nalgebra::Vector3::new(1.0, 1.0, det.signum()));
    let r = u * fix * v_t;
    DMat3::from_cols_array(&[
        r[(0, 0)],
        r[(1, 0)],
        r[(2, 0)],
        r[(0, 1)],
        r[(1, 1)],
        r[(2, 1)],
        r[(0, 2)],
        r[(1, 2)],
        r[(2, 2)],
    ])
}

/// The joints on the tree path from `a` to `b` (both included, in order), through their lowest
/// common ancestor; empty when they share no ancestor.
fn tree_path(parents: &[Option<usize>], a: usize, b: usize) -> Vec<usize> {
    let up = |mut j: usize| {
        let mut chain = vec![j];
        while let Some(p) = parents[j] {
            chain.push(p);
            j = p;
        }
        chain
    };
    let (from_a, from_b) = (up(a), up(b));
    let Some((i, k)) = from_a
        .iter()
        .enumerate()
        .find_map(|(i, j)| from_b.iter().position(|x| x == j).map(|k| (i, k)))
    else {
        return Vec::new();
    };
    let mut path = from_a[..=i].to_vec();
    path.extend(from_b[..k].iter().rev());
    path
}

/// The axis-angle vector of a rotation matrix (angle in [0, π]), accurate near 0 and π.
pub fn log_map(r: DMat3) -> DVec3 {
    let mut q = DQuat::from_mat3(&r).normalize();
    if q.w < 0.0 {
        q = -q;
    }
    let v = DVec3::new(q.x, q.y, q.z);
    let s = v.length();
    if s < 1e-300 {
        return DVec3::ZERO;
    }
    let angle = 2.0 * s.atan2(q.w);
    v * (angle / s)
}

/// The angle of the rotation `aᵀ b`, radians, accurate for small angles.
pub fn rotation_angle_between(a: DMat3, b: DMat3) -> f64 {
    log_map(a.transpose() * b).length()
}

impl Retargeter {
    /// Resolves `map` against `bvh` and `template` and computes the rest alignments.
    pub fn new(
        bvh: &Bvh,
        map: &JointMap,
        template: &Template,
        options: &RetargetOptions,
    ) -> Result<Self, MotionError> {
        let layout = template.layout();
        let nj = layout.num_joints();
        let mut bvh_of: Vec<Option<usize>> = vec![None; nj];
        for (b_name, m_name) in &map.pairs {
            let Some(b) = bvh.joint_index(b_name) else {
                return invalid(format!(
                    "the joint map names BVH joint '{b_name}', which the BVH file does not have (its joints: {})",
                    bvh.joints
                        .iter()
                        .map(|j| j.name.as_str())
                        .collect::<Vec<_>>()
                        .join(", ")
                ));
            };
            let Some(m) = layout.joints.iter().position(|n| n == m_name) else {
                return invalid(format!(
                    "the joint map sends BVH joint '{b_name}' to '{m_name}', which model '{}' does not have (its joints: {})",
                    template.id,
                    layout.joints.join(", ")
                ));
            };
            bvh_of[m] = Some(b);
        }
        let parents: Vec<Option<usize>> = template.rig.joints.iter().map(|j| j.parent).collect();
        let mapped_ancestor = |m: usize| {
            let mut k = parents[m];
            while let Some(p) = k {
                if bvh_of[p].is_some() {
                    return Some(p);
                }
                k = parents[p];
            }
            None
        };
        for m in 0..nj {
            if let (Some(b), Some(a)) = (bvh_of[m], mapped_ancestor(m)) {
                let ba = bvh_of[a].unwrap_or(b);
                if !bvh.is_ancestor(ba, b) {
                    return invalid(format!(
                        "the joint map does not follow the hierarchies: model joint '{}' descends from '{}', but BVH joint '{}' does not descend from '{}'",
                        layout.joints[m], layout.joints[a], bvh.joints[b].name, bvh.joints[ba].name
                    ));
                }
            }
        }
        let Some(anchor) = (0..nj).find(|&m| bvh_of[m].is_some()) else {
            return invalid("the joint map maps no joint");
        };
        let axes = options.up.to_lfit();
        // Units from the rest skeleton's extent along the up axis (end sites included).
        let raw_rest = bvh.rest_positions();
        let mut points: Vec<DVec3> = raw_rest.clone();
        for (j, joint) in bvh.joints.iter().enumerate() {
            if let Some(e) = joint.end_site {
                points.push(raw_rest[j] + e);
            }
        }
        let ups: Vec<f64> = points.iter().map(|p| (axes * *p).y).collect();
        let height = ups.iter().copied().fold(f64::NEG_INFINITY, f64::max)
            - ups.iter().copied().fold(f64::INFINITY, f64::min);
        let scale = match options.units {
            Units::Metres => 1.0,
            Units::Centimetres => 0.01,
            Units::Auto => {
                if height > 3.0 {
                    0.01
                } else {
                    1.0
                }
            }
        };
        let bvh_rest: Vec<DVec3> = raw_rest.iter().map(|p| axes * *p * scale).collect();
        let k = template.morph.coefficients();
        let mut coeffs = options.shape.clone();
        if coeffs.len() > template.morph.shape {
            return invalid(format!(
                "{} shape coefficients given; model '{}' has {}",
                coeffs.len(),
                template.id,
                template.morph.shape
            ));
        }
        coeffs.resize(k, 0.0);
        let dim = template.param_dim();
        let mut zero = vec![0.0; dim];
        zero[3 + 3 * nj..].copy_from_slice(&coeffs);
        let rest = lfit_model::skinning::joint_transforms(template, &zero).rest_joints;
        // First mapped descendants of every model joint.
        let mut children: Vec<Vec<usize>> = vec![Vec::new(); nj];
        for (j, p) in parents.iter().enumerate() {
            if let Some(p) = p {
                children[*p].push(j);
            }
        }
        let first_mapped = |m: usize| {
            let mut out = Vec::new();
            let mut stack: Vec<usize> = children[m].iter().rev().copied().collect();
            while let Some(c) = stack.pop() {
                if bvh_of[c].is_some() {
                    out.push(c);
                } else {
                    stack.extend(children[c].iter().rev());
                }
            }
            out
        };
        let mut align = vec![DMat3::IDENTITY; nj];
        let mut has_align = vec![false; nj];
        let mut bones = Vec::new();
        for m in 0..nj {
            let Some(b) = bvh_of[m] else { continue };
            let mut from = Vec::new();
            let mut to = Vec::new();
            for c in first_mapped(m) {
                let Some(bc) = bvh_of[c] else { continue };
                let d = rest[c] - rest[m];
                let e = bvh_rest[bc] - bvh_rest[b];
                if d.length() < 1e-9 || e.length() < 1e-9 {
                    continue;
                }
                from.push(d.normalize());
                to.push(e.normalize());
                bones.push((m, c));
            }
            if !from.is_empty() {
                align[m] = align_directions(&from, &to);
                has_align[m] = true;
            } else if let Some(a) = mapped_ancestor(m) {
                align[m] = align[a];
                has_align[m] = has_align[a];
            }
        }
        // Root motion scale (floor mode): the leg length, model over BVH (module docs).
        let root_scale = match options.root {
            RootMode::Rest => 1.0,
            RootMode::Floor => {
                let low = (0..nj)
                    .filter(|&m| bvh_of[m].is_some())
                    .min_by(|&a, &b| rest[a].y.total_cmp(&rest[b].y))
                    .unwrap_or(anchor);
                let leg: Vec<(usize, usize)> = tree_path(&parents, low, anchor)
                    .into_iter()
                    .filter_map(|m| bvh_of[m].map(|b| (m, b)))
                    .collect();
                let (mut l_m, mut l_b) = (0.0, 0.0);
                for w in leg.windows(2) {
                    l_m += rest[w[0].0].distance(rest[w[1].0]);
                    l_b += bvh_rest[w[0].1].distance(bvh_rest[w[1].1]);
                }
                if low != anchor && l_m > 1e-6 && l_b > 1e-6 {
                    l_m / l_b
                } else {
                    1.0
                }
            }
        };
        Ok(Self {
            bvh_of,
            align,
            bones,
            scale,
            axes,
            anchor,
            root_scale,
            root: options.root,
            rest,
            bvh_rest,
            dim,
            coeffs,
        })
    }

    /// World rotations of the BVH pose in lfit's axes.
    fn world(&self, pose: &BvhPose, b: usize) -> DMat3 {
        self.axes * pose.rotations[b] * self.axes.transpose()
    }

    /// The model's parameter vector for one BVH frame.
    pub fn frame(&self, bvh: &Bvh, template: &Template, values: &[f64]) -> Vec<f64> {
        let pose = bvh.pose(values);
        let nj = self.bvh_of.len();
        let mut global = vec![DMat3::IDENTITY; nj];
        let mut params = vec![0.0; self.dim];
        for (m, joint) in template.rig.joints.iter().enumerate() {
            let parent = joint.parent.map_or(DMat3::IDENTITY, |p| global[p]);
            global[m] = match self.bvh_of[m] {
                Some(b) => self.world(&pose, b) * self.align[m],
                None => parent,
            };
            let local = parent.transpose() * global[m];
            let r = log_map(local);
            params[3 + 3 * m..6 + 3 * m].copy_from_slice(&r.to_array());
        }
        params[3 + 3 * nj..].copy_from_slice(&self.coeffs);
        // Translation: place the anchor.
        let a = self.anchor;
        let Some(b) = self.bvh_of[a] else {
            return params;
        };
        let p = self.axes * pose.positions[b] * self.scale;
        let p_rest = self.bvh_rest[b];
        let c = self.rest[a];
        let k = self.root_scale;
        let target = match self.root {
            RootMode::Floor => DVec3::new(
                c.x + k * (p.x - p_rest.x),
                k * p.y,
                c.z + k * (p.z - p_rest.z),
            ),
            RootMode::Rest => c + (p - p_rest),
        };
        let posed = lfit_model::skinning::joint_transforms(template, &params);
        let t = target - posed.joints[a];
        params[..3].copy_from_slice(&t.to_array());
        params
    }

    /// Cosines between the BVH's world bones and the model's posed bones (over [`Self::bones`])
    /// for one frame: `params` from [`Self::frame`].
    pub fn bone_cosines(
        &self,
        bvh: &Bvh,
        template: &Template,
        values: &[f64],
        params: &[f64],
    ) -> Vec<f64> {
        let pose = bvh.pose(values);
        let posed = lfit_model::skinning::joint_transforms(template, params);
        self.bones
            .iter()
            .filter_map(|&(m, c)| {
                let (bm, bc) = (self.bvh_of[m]?, self.bvh_of[c]?);
                let e = self.axes * (pose.positions[bc] - pose.positions[bm]);
                let d = posed.joints[c] - posed.joints[m];
                let n = e.length() * d.length();
                (n > 0.0).then(|| e.dot(d) / n)
            })
            .collect()
    }
}

/// A retargeted clip.
#[derive(Debug, Clone)]
pub struct Retargeted {
    /// One full parameter vector per frame (the model's layout).
    pub poses: Vec<Vec<f64>>,
    pub fps: f64,
    /// Metres per BVH unit.
    pub scale: f64,
    pub root_scale: f64,
    pub mapped: usize,
    /// Mean and minimum bone-direction cosine over all frames and mapped bones.
    pub cosine_mean: f64,
    pub cosine_min: f64,
    pub bones: usize,
}

/// Retargets every frame of `bvh` onto `template` through `map`.
pub fn retarget(
    bvh: &Bvh,
    map: &JointMap,
    template: &Template,
    options: &RetargetOptions,
) -> Result<Retargeted, MotionError> {
    if bvh.frames.is_empty() {
        return invalid("the BVH file has no frames");
    }
    let r = Retargeter::new(bvh, map, template, options)?;
    let mut poses = Vec::with_capacity(bvh.frames.len());
    let (mut sum, mut count, mut min) = (0.0, 0usize, f64::INFINITY);
    for values in &bvh.frames {
        let params = r.frame(bvh, template, values);
        if params.iter().any(|v| !v.is_finite()) {
            return invalid("retargeting produced a non-finite pose (degenerate skeleton?)");
        }
        for c in r.bone_cosines(bvh, template, values, &params) {
            sum += c;
            count += 1;
            min = min.min(c);
        }
        poses.push(params);
    }
    Ok(Retargeted {
        poses,
        fps: 1.0 / bvh.frame_time,
        scale: r.scale,
        root_scale: r.root_scale,
        mapped: r.bvh_of.iter().filter(|b| b.is_some()).count(),
        cosine_mean: if count > 0 {
            sum / count as f64
        } else {
            f64::NAN
        },
        cosine_min: if count > 0 { min } else { f64::NAN },
        bones: r.bones.len(),
    })
}

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod tests {
    use super::*;

    /// `--up`: the letters, the same axes given as vectors (the letters' exact rotations), any
    /// other direction turned onto +y by a proper rotation, and one-line refusals.
    #[test]
    fn an_up_direction_is_turned_onto_y() {
        assert_eq!("y".parse::<Up>(), Ok(Up::Y));
        assert_eq!("Z".parse::<Up>(), Ok(Up::Z));
        assert_eq!(" 0, 2.5 ,0".parse::<Up>(), Ok(Up::Y));
        assert_eq!("0,0,1e-3".parse::<Up>(), Ok(Up::Z));
        for (text, v) in [
            ("1,1,0", DVec3::new(1.0, 1.0, 0.0)),
            ("0.2,-0.9,0.4", DVec3::new(0.2, -0.9, 0.4)),
            ("0,-1,0", DVec3::NEG_Y),
            ("1,0,0", DVec3::X),
        ] {
            let up: Up = text.parse().expect(text);
            let Up::Vector(u) = up else {
                panic!("{text}: {up:?}")
            };
            assert!((u - v.normalize()).length() < 1e-15, "{text}: {u}");
            let r = up.to_lfit();
            assert!((r * v.normalize() - DVec3::Y).length() < 1e-12, "{text}");
            assert!((r.determinant() - 1.0).abs() < 1e-12, "{text}");
            assert!(
                (r * r.transpose() - DMat3::IDENTITY)
                    .to_cols_array()
                    .iter()
                    .all(|x| x.abs() < 1e-12),
                "{text}"
            );
            let Ok(Up::Vector(again)) = up.name().parse::<Up>() else {
                panic!("{text}: {} does not parse back", up.name())
            };
            assert!((again - u).length() < 1e-15, "{text}: {}", up.name());
        }
        assert!((Up::Z.to_lfit() * DVec3::Z - DVec3::Y).length() < 1e-15);
        for (text, needle) in [
            ("x", "unknown up axis 'x'"),
            ("1,2", "unknown up axis '1,2'"),
            ("a,b,c", "unknown up axis"),
            ("0,0,0", "not all zero"),
            ("nan,1,0", "finite"),
            ("inf,0,0", "finite"),
        ] {
            let e = text.parse::<Up>().unwrap_err();
            assert!(e.contains(needle), "{text}: {e}");
        }
    }

    #[test]
    fn map_formats_and_errors() {
        let a = JointMap::parse("{\"Hips\": \"root\", \"Chest\": \"lower_torso\"}").unwrap();
        let b = JointMap::parse("{\"description\": \"x\", \"joints\": {\"Hips\": \"root\", \"Chest\": \"lower_torso\"}}").unwrap();
        let c =
            JointMap::parse("# comment\nHips root\n\n  Chest   lower_torso  # trailing\n").unwrap();
        assert_eq!(a, b);
        assert_eq!(a, c);
        assert!(
            JointMap::parse("Hips root extra")
                .unwrap_err()
                .contains("line 1")
        );
        assert!(
            JointMap::parse("Hips root\nChest root")
                .unwrap_err()
                .contains("target of both")
        );
        assert!(
            JointMap::parse("{\"Hips\": 3}")
                .unwrap_err()
                .contains("\"Hips\"")
        );
        assert!(JointMap::parse("").unwrap_err().contains("no entries"));
        assert!(JointMap::parse("{").unwrap_err().contains("malformed JSON"));
        let e = JointMap::parse("{\"Hips\": \"root\", \"Hips\": \"l_hip\"}").unwrap_err();
        assert!(e.contains("mapped twice"), "{e}");
    }

    #[test]
    fn log_map_inverts_exp_map_near_zero_and_pi() {
        for r in [
            DVec3::new(1e-9, -2e-9, 3e-10),
            DVec3::new(0.3, -0.2, 0.9),
            DVec3::new(0.0, std::f64::consts::PI - 1e-7, 0.0),
            DVec3::new(1.0, 1.0, 1.0).normalize() * 3.0,
        ] {
            let m = lfit_model::body::rotation::exp_map(r);
            let back = log_map(m);
            assert!(rotation_angle_between(m, lfit_model::body::rotation::exp_map(back)) < 1e-12);
        }
        assert!(
            (log_map(lfit_model::body::rotation::exp_map(DVec3::new(
                0.0, 2.0, 0.0
            ))) - DVec3::new(0.0, 2.0, 0.0))
            .length()
                < 1e-12
        );
    }

    #[test]
    fn alignment_single_bone_is_minimal_and_several_bones_exact() {
        let d = DVec3::new(1.0, -1.0, 0.0).normalize();
        let e = DVec3::X;
        let q = align_directions(&[d], &[e]);
        assert!((q * d - e).length() < 1e-12);
        // Minimal: the axis is perpendicular to both (here z).
        assert!((log_map(q).normalize() - DVec3::Z).length() < 1e-9);
        // Several bones rotated rigidly: the rotation comes back.
        let r = DMat3::from_quat(DQuat::from_scaled_axis(DVec3::new(0.3, -0.5, 0.2)));
        let from = [
            DVec3::Y,
            DVec3::new(1.0, -0.2, 0.1).normalize(),
            DVec3::new(-1.0, -0.2, 0.1).normalize(),
        ];
        let to: Vec<DVec3> = from.iter().map(|v| r * *v).collect();
        let q = align_directions(&from, &to);
        assert!(rotation_angle_between(q, r) < 1e-12);
        // Identical directions: the identity.
        assert!(rotation_angle_between(align_directions(&from, &from), DMat3::IDENTITY) < 1e-14);
    }

    /// A game-engine style BVH: every leg bone along +x in the zero-rotation rest pose (the hip
    /// joints 1 cm below the root there), the frames' rotations make it stand. The root scale is
    /// the ratio of leg lengths; the ratio of rest heights (the hips 1 cm above the lowest joint)
    /// gave 85.5 and put the pelvis 84 m above the floor.
    #[test]
    fn floor_scale_uses_leg_length_for_a_rest_pose_along_x() {
        // Hips: Z 90, X 90 takes local x to world y (up), y to z, z to x; the up-legs
        // (Z 180, X 90) then point their +x down; LeftLeg and LeftFoot keep it.
        let leg = |side: &str, z: f64| {
            format!(
                "JOINT {side}UpLeg
{{
OFFSET -2 -1 {z}
CHANNELS 3 Zrotation Xrotation Yrotation
JOINT {side}Leg
{{
OFFSET 44 0 0
CHANNELS 3 Zrotation Xrotation Yrotation
JOINT {side}Foot
{{
OFFSET 44 0 0
CHANNELS 3 Zrotation Xrotation Yrotation
End Site
{{
OFFSET 15 0 0
}}
}}
}}
}}
"
            )
        };
        let frame = "90 90 0  180 90 0  0 0 0  0 0 0  180 90 0  0 0 0  0 0 0  0 0 0";
        let text = format!(
            "HIERARCHY
ROOT Hips
{{
OFFSET 0 0 0
CHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation Yrotation
{}{}JOINT Spine
{{
OFFSET 10 0 0
CHANNELS 3 Zrotation Xrotation Yrotation
End Site
{{
OFFSET 40 0 0
}}
}}
}}
MOTION
Frames: 2
Frame Time: 0.0333333
0 98 0  {frame}
20 98 30  {frame}
",
            leg("Left", 10.0),
            leg("Right", -10.0),
        );
        let bvh = Bvh::parse(&text).unwrap();
        // The construction: the rest pose lies along +x, the first frame stands (ankles 8 cm up).
        let rest_b = bvh.rest_positions();
        let foot = bvh.joint_index("LeftFoot").unwrap();
        assert!((rest_b[foot] - DVec3::new(86.0, -1.0, 10.0)).length() < 1e-9);
        let posed_b = bvh.pose(&bvh.frames[0]);
        assert!((posed_b.positions[foot] - DVec3::new(10.0, 8.0, -1.0)).length() < 1e-9);
        let spine = bvh.joint_index("Spine").unwrap();
        assert!((posed_b.positions[spine] - DVec3::new(0.0, 108.0, 0.0)).length() < 1e-9);
        let map = JointMap::parse(
            "Hips root\nSpine lower_torso\nLeftUpLeg l_hip\nLeftLeg l_knee\nLeftFoot l_ankle\nRightUpLeg r_hip\nRightLeg r_knee\nRightFoot r_ankle\n",
        )
        .unwrap();
        let template = lfit_model::body::default_template();
        let options = RetargetOptions {
            units: Units::Centimetres,
            ..RetargetOptions::default()
        };
        let r = retarget(&bvh, &map, &template, &options).unwrap();
        assert_eq!(r.scale, 0.01);
        let names = &template.layout().joints;
        let j = |n: &str| names.iter().position(|x| x == n).unwrap();
        let rest =
            lfit_model::skinning::joint_transforms(&template, &vec![0.0; template.param_dim()])
                .rest_joints;
        let chain_m = ["root", "l_hip", "l_knee", "l_ankle"].map(|n| rest[j(n)]);
        let chain_b = ["Hips", "LeftUpLeg", "LeftLeg", "LeftFoot"]
            .map(|n| rest_b[bvh.joint_index(n).unwrap()] * 0.01);
        let length = |c: &[DVec3]| c.windows(2).map(|w| w[0].distance(w[1])).sum::<f64>();
        let k = length(&chain_m) / length(&chain_b);
        assert!(
            (r.root_scale - k).abs() <= 1e-9 * k,
            "root scale {} (leg lengths give {k})",
            r.root_scale
        );
        let posed = lfit_model::skinning::joint_transforms(&template, &r.poses[0]).joints;
        let pelvis = posed[j("root")];
        assert!(
            (pelvis.y - rest[j("root")].y).abs() < 0.03,
            "pelvis at {pelvis} (standing {})",
            rest[j("root")].y
        );
        for side in ["l", "r"] {
            let ankle = posed[j(&format!("{side}_ankle"))];
            assert!(
                (ankle.y - rest[j(&format!("{side}_ankle"))].y).abs() < 0.03,
                "{side} ankle at {ankle}"
            );
            let foot = posed[j(&format!("{side}_foot"))];
            assert!(foot.y.abs() < 0.05, "{side} foot at {foot}");
        }
        // Steps are scaled by the same k.
        let moved = lfit_model::skinning::joint_transforms(&template, &r.poses[1]).joints;
        let step = moved[j("root")] - pelvis;
        assert!(
            (step - DVec3::new(0.2 * k, 0.0, 0.3 * k)).length() < 1e-9,
            "{step}"
        );
        // The hips' bones differ a little in direction (its alignment is a least-squares fit).
        assert!(r.cosine_min > 0.99, "{}", r.cosine_min);
    }
}
