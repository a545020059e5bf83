//! `lfit export`: fitted poses → posed OBJ meshes, or one animated, skinned binary glTF 2.0 file.
//!
//! The poses come from the result JSON of `lfit fit` (`{"modality", "frames": [{"frame", "pose"},
//! ...]}`) or from the `{"pose"}` / `{"poses"}` file of `lfit template pose` (frames 0..n). They are
//! checked against the dataset (`--data`) before anything is written: frame indices in range,
//! same modality, the model's pose length (57 on the default template), no duplicate frames, at
//! least one frame.
//!
//! # The glTF skin reproduces SPEC §3's linear blend skinning
//!
//! Joint j is node j, child of its rig parent's node. Its rest (bind) local transform is the
//! translation `c_j − c_parent` (root: `c_root`), and frame k animates it with
//! translation `c_j − c_parent` (root: `c_root + t`) and rotation `q_j = exp(r_j)`; the inverse
//! bind matrix is `translate(−c_j)`. By induction over the hierarchy, the node's global transform
//! is `G_j(y) = A_parent(c_j) + W_j y` (root: `c_root + t + R_root y`), where `A_j`, `W_j` are
//! those of [`lfit_model::skinning::joint_transforms`]:
//!
//! ```text
//! G_root(y) = T(c_root + t) R_root y                     = A_root(y + c_root)
//! G_j(y)    = G_p(c_j − c_p + R_j y) = A_p(c_j + R_j y)   = A_p(c_j) + W_p R_j y = A_j(y + c_j)
//! ```
//!
//! (using `G_p(z) = A_p(z + c_p)` and that `A_p` has linear part `W_p`). So glTF's joint matrix
//! `G_j · IBM_j = G_j · translate(−c_j)` is exactly `A_j`, and the skinned vertex
//! `Σ_k w_k G_jk IBM_jk v` is SPEC §3's `Σ_k w_k A_jk(v)`. The mesh node sits at the scene root
//! without a transform (glTF ignores it for skinned meshes); the skeleton root joint is the other
//! scene root and the skin's `skeleton`.
//!
//! # Hand-written JSON and GLB container, no glTF crate
//!
//! `gltf-json` (the document model of the `gltf` crate) is small, but it turns on serde_json's
//! `raw_value` feature, which by feature unification rebuilds serde_json and everything above it
//! in this workspace (burn, cubecl); and its objects have no `name` field unless its `names`
//! feature is on.
//! The document written here is a dozen kinds of objects, so it is built with `serde_json::json!`
//! and the GLB container (12-byte header, JSON chunk padded with spaces, BIN chunk padded with
//! zeros, 4-byte alignment) is written by [`glb_bytes`]. The tests parse the file independently
//! and run the Khronos glTF validator on it.

use std::path::{Path, PathBuf};
use std::str::FromStr;

use anyhow::{Context, Result, bail};
use glam::{DQuat, DVec3, Vec3};
use lfit_model::pose::rot_offset;
use lfit_model::skinning::{SkinningMethod, pose_vertices_batch, vertex_normals};
use lfit_model::template::{ModelSignature, Template, write_atomic, write_obj};
use lfit_synth::Dataset;
use serde_json::{Value, json};

/// Output format of `lfit export`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ExportFormat {
    /// One posed OBJ per fitted frame, `OUT/frame_NNNNN.obj`.
    Obj,
    /// One binary glTF 2.0 file, `OUT/<name>.glb`: skinned template, skeleton, animation.
    Gltf,
}

impl FromStr for ExportFormat {
    type Err = anyhow::Error;

    fn from_str(s: &str) -> Result<Self> {
        match s {
            "obj" => Ok(Self::Obj),
            "gltf" => Ok(Self::Gltf),
            other => bail!("unknown export format '{other}' (expected obj or gltf)"),
        }
    }
}

/// Arguments of `lfit export`.
#[derive(Debug, Clone)]
pub struct ExportArgs {
    /// Dataset the poses were fitted on (template, modality, frame count, frame rate).
    pub data: PathBuf,
    /// Result JSON of `lfit fit`, or `{"pose"}` / `{"poses"}`.
    pub poses: PathBuf,
    /// `obj` or `gltf`.
    pub format: String,
    /// Output directory (created if missing).
    pub out: PathBuf,
    /// Model file or template directory, if the dataset was made with neither the procedural
    /// template nor a shipped model.
    pub template: Option<PathBuf>,
}

/// Fitted poses read from a file: the modality it names (result files of `lfit fit`) and the
/// frames with their poses, sorted by frame index.
#[derive(Debug, Clone)]
pub struct FittedPoses {
    pub modality: Option<String>,
    /// Frame index and full parameter vector (pose, then shape and expression).
    pub frames: Vec<(usize, Vec<f64>)>,
}

/// Reads the result JSON of `lfit fit` (`"frames": [{"frame", "pose"}, ...]`) or a
/// `{"pose"}` / `{"poses"}` file (frames 0..n), for `template`: poses must be `3 + 3J` finite
/// numbers (57 on the default template), with the model's `shape`/`expression` next to them;
/// frames must be unique and at least one.
pub fn read_fitted_poses(path: &Path, template: &Template) -> Result<FittedPoses> {
    let text =
        std::fs::read_to_string(path).with_context(|| format!("cannot read {}", path.display()))?;
    let value: Value = serde_json::from_str(&text)
        .with_context(|| format!("malformed poses JSON {}", path.display()))?;
    let Some(rows) = value.get("frames") else {
        if value.get("pose").is_some() || value.get("poses").is_some() {
            let poses = crate::data::read_params_file(path, template)?;
            return Ok(FittedPoses {
                modality: None,
                frames: poses.into_iter().enumerate().collect(),
            });
        }
        bail!(
            "{}: expected the result JSON of `lfit fit` (\"frames\": [{{\"frame\", \"pose\"}}, ...]) or {{\"pose\"}} / {{\"poses\"}}",
            path.display()
        );
    };
    let modality = match value.get("modality") {
        None => None,
        Some(Value::String(m)) => Some(m.clone()),
        Some(other) => bail!("{}: \"modality\" is not a string: {other}", path.display()),
    };
    let rows = rows
        .as_array()
        .with_context(|| format!("{}: \"frames\" is not an array", path.display()))?;
    if rows.is_empty() {
        bail!(
            "{}: \"frames\" is empty: no fitted frames to export",
            path.display()
        );
    }
    let mut frames = Vec::with_capacity(rows.len());
    for (i, row) in rows.iter().enumerate() {
        let frame = row.get("frame").and_then(Value::as_u64).with_context(|| {
            format!(
                "{}: frames[{i}].frame is missing or not a non-negative integer",
                path.display()
            )
        })?;
        let pose = crate::data::params_from_json(
            template,
            row.get("pose").unwrap_or(&Value::Null),
            row.get("shape"),
            row.get("expression"),
            "",
            path,
        )
        .with_context(|| format!("frames[{i}]"))?;
        let frame = usize::try_from(frame).with_context(|| {
            format!("{}: frames[{i}].frame {frame} is too large", path.display())
        })?;
        frames.push((i, frame, pose));
    }
    frames.sort_by_key(|&(i, frame, _)| (frame, i));
    if let Some(w) = frames.windows(2).find(|w| w[0].1 == w[1].1) {
        bail!(
            "{}: frame {} appears twice (frames[{}] and frames[{}])",
            path.display(),
            w[0].1,
            w[0].0,
            w[1].0
        );
    }
    Ok(FittedPoses {
        modality,
        frames: frames
            .into_iter()
            .map(|(_, frame, pose)| (frame, pose))
            .collect(),
    })
}

/// Checks that `poses` (read from `poses_path`) were fitted on `dataset` (read from `data_path`):
/// same modality, every frame index in range.
pub fn check_against_dataset(
    poses: &FittedPoses,
    poses_path: &Path,
    dataset: &Dataset,
    data_path: &Path,
) -> Result<()> {
    let modality = dataset.modality().name();
    if let Some(m) = &poses.modality
        && m != modality
    {
        bail!(
            "{}: modality '{m}' differs from the dataset's modality '{modality}' ({})",
            poses_path.display(),
            data_path.display()
        );
    }
    if let Some(&(frame, _)) = poses
        .frames
        .iter()
        .find(|(frame, _)| *frame >= dataset.len())
    {
        bail!(
            "{}: frame {frame} is out of range: the dataset {} has {} frames",
            poses_path.display(),
            data_path.display(),
            dataset.len()
        );
    }
    Ok(())
}

/// Checks a fit result against the model and dataset beyond what reading its poses checks
/// (lengths, modality, frame range): a recorded model signature must be this model's, and a
/// recorded V2V must be what the pose gives against this dataset's ground truth (a fit of
/// another dataset with the same model fails here).
pub fn check_fit_file(
    value: &Value,
    path: &Path,
    template: &Template,
    dataset: &Dataset,
    frames: &[(usize, Vec<f64>)],
) -> Result<()> {
    if let Some(sig) = value.get("model") {
        let recorded: ModelSignature = serde_json::from_value(sig.clone())
            .with_context(|| format!("{}: malformed \"model\" signature", path.display()))?;
        let ours = template.signature();
        if recorded != ours {
            bail!(
                "{}: fitted with model '{}' (signature {}), not this model '{}' ({})",
                path.display(),
                recorded.id,
                recorded.hash,
                ours.id,
                ours.hash
            );
        }
    }
    let rows = value
        .get("frames")
        .and_then(Value::as_array)
        .map(Vec::as_slice)
        .unwrap_or_default();
    for row in rows {
        let (Some(frame), Some(recorded)) = (
            row.get("frame").and_then(Value::as_u64),
            row.get("v2v_mm").and_then(Value::as_f64),
        ) else {
            continue;
        };
        let Some(params) = frames
            .iter()
            .find(|(f, _)| *f as u64 == frame)
            .map(|(_, p)| p)
        else {
            continue;
        };
        let Some(gt) = dataset.ground_truth(frame as usize) else {
            continue;
        };
        let v2v = lfit_model::metrics::v2v_mm(template, params, gt);
        if recorded.is_finite() && (v2v - recorded).abs() > 1e-3 * (1.0 + recorded.abs()) {
            bail!(
                "{}: frame {frame} records V2V {recorded:.3} mm but its pose is {v2v:.3} mm from this dataset's ground truth: it was fitted on another dataset",
                path.display()
            );
        }
    }
    Ok(())
}

/// `lfit export`: reads and checks everything, then writes OBJ files or one `.glb` into `out`.
pub fn export(args: &ExportArgs) -> Result<Value> {
    let format: ExportFormat = args.format.parse()?;
    let dataset =
        Dataset::load(&args.data).with_context(|| format!("dataset {}", args.data.display()))?;
    let template = crate::cli::fit::template_for(&dataset, args.template.as_deref())?;
    let fitted = read_fitted_poses(&args.poses, &template)?;
    check_against_dataset(&fitted, &args.poses, &dataset, &args.data)?;
    let text = std::fs::read_to_string(&args.poses)
        .with_context(|| format!("cannot read {}", args.poses.display()))?;
    let value: Value = serde_json::from_str(&text)
        .with_context(|| format!("malformed poses JSON {}", args.poses.display()))?;
    check_fit_file(&value, &args.poses, &template, &dataset, &fitted.frames)?;
    let fps = dataset.meta.config.fps;
    if !(fps.is_finite() && fps > 0.0) {
        bail!(
            "dataset {}: frame rate {fps} is not a positive number",
            args.data.display()
        );
    }
    let frame_list: Vec<usize> = fitted.frames.iter().map(|&(f, _)| f).collect();
    // Everything is built in memory first, so a failure leaves `out` untouched.
    let files: Vec<(PathBuf, Vec<u8>)> = match format {
        ExportFormat::Obj => {
            let poses: Vec<&[f64]> = fitted.frames.iter().map(|(_, p)| p.as_slice()).collect();
            let meshes = pose_vertices_batch(&template, &poses, SkinningMethod::Linear);
            fitted
                .frames
                .iter()
                .zip(&meshes)
                .map(|(&(frame, _), vertices)| {
                    let mut bytes = Vec::new();
                    let comment = format!(
                        "lfit export: template '{}' posed (Linear skinning), frame {frame} of {}",
                        template.id,
                        args.poses.display()
                    );
                    write_obj(&mut bytes, &comment, vertices, &template.faces);
                    (args.out.join(format!("frame_{frame:05}.obj")), bytes)
                })
                .collect()
        }
        ExportFormat::Gltf => {
            let name = args.poses.file_stem().map_or_else(
                || "motion".to_string(),
                |s| s.to_string_lossy().into_owned(),
            );
            // A glTF skin has one bind mesh: the subject's mean shape over the exported frames
            // (pose correctives, if the model has them, are not expressible and left out).
            let layout = template.layout();
            let k = layout.dim() - layout.pose_dim();
            let mut mean = vec![0.0; k];
            for (_, p) in &fitted.frames {
                for (m, v) in mean.iter_mut().zip(&p[layout.pose_dim()..]) {
                    *m += v / fitted.frames.len() as f64;
                }
            }
            let shaped = template.shaped(&mean)?;
            let bytes = gltf_animation(&shaped, &fitted.frames, fps, &name)?;
            vec![(args.out.join(format!("{name}.glb")), bytes)]
        }
    };
    std::fs::create_dir_all(&args.out)
        .with_context(|| format!("cannot create {}", args.out.display()))?;
    let mut written = Vec::with_capacity(files.len());
    for (path, bytes) in &files {
        write_atomic(path, bytes)?;
        written.push(path.clone());
    }
    tracing::info!(files = written.len(), frames = frame_list.len(), out = %args.out.display(), "exported");
    Ok(json!({
        "format": match format { ExportFormat::Obj => "obj", ExportFormat::Gltf => "gltf" },
        "out": args.out,
        "template": template.id,
        "frames": frame_list.len(),
        "first_frame": frame_list.first(),
        "last_frame": frame_list.last(),
        "fps": fps,
        "written": written,
    }))
}

// glTF 2.0 constants (specification §3.6.2 / §5).
const FLOAT: u32 = 5126;
const UNSIGNED_SHORT: u32 = 5123;
const UNSIGNED_INT: u32 = 5125;
const ARRAY_BUFFER: u32 = 34962;
const ELEMENT_ARRAY_BUFFER: u32 = 34963;
const GLB_MAGIC: u32 = 0x4654_6C67;
const GLB_JSON: u32 = 0x4E4F_534A;
const GLB_BIN: u32 = 0x004E_4942;

/// The BIN chunk being built: one buffer view per accessor, each 4-byte aligned.
#[derive(Default)]
struct BinBuilder {
    bytes: Vec<u8>,
    views: Vec<Value>,
    accessors: Vec<Value>,
}

impl BinBuilder {
    /// Appends `data` as a new buffer view and an accessor over it; returns the accessor index.
    fn accessor(
        &mut self,
        data: &[u8],
        component_type: u32,
        count: usize,
        kind: &str,
        target: Option<u32>,
        min_max: Option<(Vec<f32>, Vec<f32>)>,
    ) -> usize {
        let offset = self.bytes.len();
        self.bytes.extend_from_slice(data);
        while !self.bytes.len().is_multiple_of(4) {
            self.bytes.push(0);
        }
        let mut view = json!({ "buffer": 0, "byteOffset": offset, "byteLength": data.len() });
        if let Some(t) = target {
            view["target"] = json!(t);
        }
        self.views.push(view);
        let mut accessor = json!({ "bufferView": self.views.len() - 1, "componentType": component_type, "count": count, "type": kind });
        if let Some((min, max)) = min_max {
            // f32 → f64 is exact, so the JSON bounds equal the stored values bit for bit.
            accessor["min"] = json!(min.iter().map(|&v| f64::from(v)).collect::<Vec<_>>());
            accessor["max"] = json!(max.iter().map(|&v| f64::from(v)).collect::<Vec<_>>());
        }
        self.accessors.push(accessor);
        self.accessors.len() - 1
    }

    fn floats(
        &mut self,
        values: &[f32],
        count: usize,
        kind: &str,
        target: Option<u32>,
        min_max: Option<(Vec<f32>, Vec<f32>)>,
    ) -> usize {
        let data: Vec<u8> = values.iter().flat_map(|v| v.to_le_bytes()).collect();
        self.accessor(&data, FLOAT, count, kind, target, min_max)
    }
}

/// Component-wise bounds of `n`-vectors stored flat in `values`.
fn bounds(values: &[f32], n: usize) -> (Vec<f32>, Vec<f32>) {
    let mut min = vec![f32::INFINITY; n];
    let mut max = vec![f32::NEG_INFINITY; n];
    for item in values.chunks_exact(n) {
        for k in 0..n {
            min[k] = min[k].min(item[k]);
            max[k] = max[k].max(item[k]);
        }
    }
    (min, max)
}

/// Up to four `(joint, weight)` influences of a vertex, duplicates merged, zero-padded (joint 0,
/// weight 0), normalized so that the f32 weights sum to 1 (glTF §3.7.3.3; the validator's
/// ACCESSOR_WEIGHTS_NON_NORMALIZED): the largest weight takes up the rounding rest.
fn packed_influences(list: &[(usize, f64)]) -> ([u16; 4], [f32; 4]) {
    let mut merged: Vec<(usize, f64)> = Vec::with_capacity(4);
    for &(j, w) in list {
        match merged.iter_mut().find(|(k, _)| *k == j) {
            Some(entry) => entry.1 += w,
            None => merged.push((j, w)),
        }
    }
    merged.retain(|&(_, w)| w > 0.0);
    merged.sort_by(|a, b| b.1.total_cmp(&a.1));
    let sum: f64 = merged.iter().map(|&(_, w)| w).sum();
    let mut joints = [0u16; 4];
    let mut weights = [0f32; 4];
    for (k, &(j, w)) in merged.iter().take(4).enumerate() {
        joints[k] = j as u16;
        weights[k] = (w / sum) as f32;
    }
    let rest: f64 = weights[1..].iter().map(|&w| f64::from(w)).sum();
    weights[0] = (1.0 - rest) as f32;
    (joints, weights)
}

/// The binary glTF 2.0 file of `frames` (frame index, pose; sorted, unique) on `template`: the
/// rest mesh (POSITION, NORMAL, indices, JOINTS_0, WEIGHTS_0), one node per rig joint, a skin,
/// and an animation named `name` with translation + rotation channels per joint (LINEAR) keyed at
/// `frame / fps` seconds.
pub fn gltf_animation(
    template: &Template,
    frames: &[(usize, Vec<f64>)],
    fps: f64,
    name: &str,
) -> Result<Vec<u8>> {
    if frames.is_empty() {
        bail!("no frames to export");
    }
    let rig = &template.rig;
    let num_joints = rig.num_joints();
    if num_joints > usize::from(u16::MAX) {
        bail!(
            "the rig has {num_joints} joints; glTF JOINTS_0 holds at most {}",
            u16::MAX
        );
    }
    if let Some((f, p)) = frames
        .iter()
        .find(|(_, p)| p.len() < rot_offset(num_joints))
    {
        bail!(
            "the rig has {num_joints} joints but the pose of frame {f} holds rotations for {}",
            p.len().saturating_sub(3) / 3
        );
    }
    let times: Vec<f32> = frames
        .iter()
        .map(|&(f, _)| (f as f64 / fps) as f32)
        .collect();
    if let Some(w) = times.windows(2).find(|w| w[1] <= w[0]) {
        bail!(
            "frame times {} and {} s are not strictly increasing in single precision (fps {fps})",
            w[0],
            w[1]
        );
    }
    let mut bin = BinBuilder::default();

    // The mesh in its rest (bind) pose.
    let positions: Vec<f32> = template
        .vertices
        .iter()
        .flat_map(|v| v.to_array())
        .collect();
    let position = bin.floats(
        &positions,
        template.num_vertices(),
        "VEC3",
        Some(ARRAY_BUFFER),
        Some(bounds(&positions, 3)),
    );
    // A vertex without a normal (on no face of non-zero area) gets +y: glTF normals must be unit.
    let normals: Vec<f32> = vertex_normals(&template.vertices, &template.faces)
        .into_iter()
        .flat_map(|n| if n == Vec3::ZERO { Vec3::Y } else { n }.to_array())
        .collect();
    let normal = bin.floats(
        &normals,
        template.num_vertices(),
        "VEC3",
        Some(ARRAY_BUFFER),
        None,
    );
    let (joints, weights): (Vec<[u16; 4]>, Vec<[f32; 4]>) = rig
        .weights
        .iter()
        .map(|list| packed_influences(list))
        .unzip();
    let joint_bytes: Vec<u8> = joints
        .iter()
        .flatten()
        .flat_map(|j| j.to_le_bytes())
        .collect();
    let joints_0 = bin.accessor(
        &joint_bytes,
        UNSIGNED_SHORT,
        joints.len(),
        "VEC4",
        Some(ARRAY_BUFFER),
        None,
    );
    let weights_flat: Vec<f32> = weights.iter().flatten().copied().collect();
    let weights_0 = bin.floats(
        &weights_flat,
        weights.len(),
        "VEC4",
        Some(ARRAY_BUFFER),
        None,
    );
    let index_bytes: Vec<u8> = template
        .faces
        .iter()
        .flatten()
        .flat_map(|i| i.to_le_bytes())
        .collect();
    let indices = bin.accessor(
        &index_bytes,
        UNSIGNED_INT,
        3 * template.faces.len(),
        "SCALAR",
        Some(ELEMENT_ARRAY_BUFFER),
        None,
    );

    // Inverse bind matrices translate(−c_j), column-major.
    let rest: Vec<DVec3> = template.joint_rest();
    let ibm: Vec<f32> = rest
        .iter()
        .flat_map(|c| {
            let c = c.as_vec3();
            [
                1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, -c.x, -c.y, -c.z, 1.0,
            ]
        })
        .collect();
    let inverse_bind = bin.floats(&ibm, num_joints, "MAT4", None, None);

    // The animation: one time accessor, per joint a translation and a rotation sampler.
    let input = bin.floats(&times, times.len(), "SCALAR", None, Some(bounds(&times, 1)));
    let local_rest = |j: usize| -> DVec3 {
        match rig.joints[j].parent {
            None => rest[j],
            Some(p) => rest[j] - rest[p],
        }
    };
    let mut samplers = Vec::with_capacity(2 * num_joints);
    let mut channels = Vec::with_capacity(2 * num_joints);
    for j in 0..num_joints {
        let translations: Vec<f32> = frames
            .iter()
            .flat_map(|(_, pose)| {
                let t = if rig.joints[j].parent.is_none() {
                    DVec3::new(pose[0], pose[1], pose[2])
                } else {
                    DVec3::ZERO
                };
                (local_rest(j) + t).as_vec3().to_array()
            })
            .collect();
        let o = rot_offset(j);
        let mut previous: Option<DQuat> = None;
        let rotations: Vec<f32> = frames
            .iter()
            .flat_map(|(_, pose)| {
                let mut q = DQuat::from_scaled_axis(DVec3::new(pose[o], pose[o + 1], pose[o + 2]))
                    .normalize();
                // q and −q are the same rotation; keep consecutive keys in one hemisphere so that
                // interpolation between them takes the short way.
                if previous.is_some_and(|p| p.dot(q) < 0.0) {
                    q = -q;
                }
                previous = Some(q);
                q.as_quat().normalize().to_array()
            })
            .collect();
        let translation_output = bin.floats(&translations, frames.len(), "VEC3", None, None);
        let rotation_output = bin.floats(&rotations, frames.len(), "VEC4", None, None);
        for (output, path) in [
            (translation_output, "translation"),
            (rotation_output, "rotation"),
        ] {
            samplers.push(json!({ "input": input, "output": output, "interpolation": "LINEAR" }));
            channels.push(
                json!({ "sampler": samplers.len() - 1, "target": { "node": j, "path": path } }),
            );
        }
    }

    // Nodes 0..J are the joints (node j = rig joint j), node J carries the skinned mesh.
    let children = rig.children();
    let mut nodes: Vec<Value> = rig
        .joints
        .iter()
        .enumerate()
        .map(|(j, joint)| {
            let mut node = json!({ "name": joint.name, "translation": local_rest(j).to_array() });
            if !children[j].is_empty() {
                node["children"] = json!(children[j]);
            }
            node
        })
        .collect();
    let mesh_node = nodes.len();
    nodes.push(json!({ "name": template.id, "mesh": 0, "skin": 0 }));
    let document = json!({
        "asset": { "version": "2.0", "generator": concat!("lfit ", env!("CARGO_PKG_VERSION"), " (lfit export)") },
        "scene": 0,
        "scenes": [{ "name": name, "nodes": [0, mesh_node] }],
        "nodes": nodes,
        "meshes": [{
            "name": template.id,
            "primitives": [{
                "attributes": { "POSITION": position, "NORMAL": normal, "JOINTS_0": joints_0, "WEIGHTS_0": weights_0 },
                "indices": indices,
                "mode": 4,
            }],
        }],
        "skins": [{ "name": "skeleton", "inverseBindMatrices": inverse_bind, "joints": (0..num_joints).collect::<Vec<_>>(), "skeleton": 0 }],
        "animations": [{ "name": name, "samplers": samplers, "channels": channels }],
        "accessors": bin.accessors,
        "bufferViews": bin.views,
        "buffers": [{ "byteLength": bin.bytes.len() }],
    });
    glb_bytes(&document, &bin.bytes)
}

/// A GLB container (glTF 2.0 §4.4): 12-byte header, the JSON chunk padded with spaces, the BIN
/// chunk padded with zeros, both to 4 bytes.
pub fn glb_bytes(document: &Value, bin: &[u8]) -> Result<Vec<u8>> {
    let mut json = serde_json::to_vec(document)?;
    while !json.len().is_multiple_of(4) {
        json.push(b' ');
    }
    let mut bin = bin.to_vec();
    while !bin.len().is_multiple_of(4) {
        bin.push(0);
    }
    let total = 12 + 8 + json.len() + if bin.is_empty() { 0 } else { 8 + bin.len() };
    let length = |n: usize| {
        u32::try_from(n)
            .with_context(|| format!("the glTF file would be {n} bytes, over GLB's 4 GiB limit"))
    };
    let mut out = Vec::with_capacity(total);
    out.extend_from_slice(&GLB_MAGIC.to_le_bytes());
    out.extend_from_slice(&2u32.to_le_bytes());
    out.extend_from_slice(&length(total)?.to_le_bytes());
    out.extend_from_slice(&length(json.len())?.to_le_bytes());
    out.extend_from_slice(&GLB_JSON.to_le_bytes());
    out.extend_from_slice(&json);
    if !bin.is_empty() {
        out.extend_from_slice(&length(bin.len())?.to_le_bytes());
        out.extend_from_slice(&GLB_BIN.to_le_bytes());
        out.extend_from_slice(&bin);
    }
    Ok(out)
}

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod tests {
    use super::*;

    #[test]
    fn influences_are_merged_padded_and_sum_to_one_in_f32() {
        let (j, w) = packed_influences(&[(3, 0.2), (5, 0.7), (3, 0.1)]);
        assert_eq!(j, [5, 3, 0, 0]);
        assert_eq!(w[2..], [0.0, 0.0]);
        assert!(
            (w[0] - 0.7).abs() < 1e-7 && (w[1] - 0.3).abs() < 1e-7,
            "{w:?}"
        );
        // Weights summing to 1 + 1e-4 (SPEC §3's tolerance) come out normalized.
        let (_, w) = packed_influences(&[(0, 0.3), (1, 0.3), (2, 0.2), (4, 0.2001)]);
        let sum: f64 = w.iter().map(|&x| f64::from(x)).sum();
        assert!((sum - 1.0).abs() < 1e-7, "{sum}");
    }

    #[test]
    fn glb_chunks_are_aligned_and_padded() {
        let bytes = glb_bytes(&json!({ "asset": { "version": "2.0" } }), &[1, 2, 3, 4, 5]).unwrap();
        assert_eq!(bytes.len() % 4, 0);
        assert_eq!(&bytes[0..4], b"glTF");
        assert_eq!(
            u32::from_le_bytes(bytes[8..12].try_into().unwrap()) as usize,
            bytes.len()
        );
        let json_len = u32::from_le_bytes(bytes[12..16].try_into().unwrap()) as usize;
        assert_eq!(json_len % 4, 0);
        assert_eq!(&bytes[16..20], b"JSON");
        let json_end = 20 + json_len;
        assert_eq!(bytes[json_end - 1], b' ');
        assert_eq!(
            u32::from_le_bytes(bytes[json_end..json_end + 4].try_into().unwrap()),
            8
        );
        assert_eq!(&bytes[json_end + 4..json_end + 8], b"BIN\0");
        assert_eq!(&bytes[json_end + 8..], &[1, 2, 3, 4, 5, 0, 0, 0]);
    }

    #[test]
    fn unknown_format_is_named() {
        let e = "fbx".parse::<ExportFormat>().unwrap_err().to_string();
        assert!(e.contains("fbx") && e.contains("obj or gltf"), "{e}");
    }
}
