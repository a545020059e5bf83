//! A template (a model): triangle mesh + rig, and for a morphable model its blend shapes and
//! joint regressor ([`Morph`]). Read from a directory (`template.obj` + `rig.json`) or from a
//! model file in the SMPL-family `.npz` layout ([`crate::modelfile`]); validated on load, written
//! atomically.

use std::io::Write;
use std::path::{Path, PathBuf};
use std::sync::Arc;

use glam::{DVec3, Vec3, Vec3A, Vec4};

use crate::error::{ModelError, Result};
use crate::layout::Layout;
use crate::morph::Morph;
use crate::rig::{JointIndex, MAX_INFLUENCES, Rig};
use crate::skeleton::{self, NUM_JOINTS};

/// File names inside a template directory.
pub const OBJ_FILE: &str = "template.obj";
pub const RIG_FILE: &str = "rig.json";

/// What identifies a model: id, parameter layout and a hash of its arrays
/// ([`Template::signature`]).
#[derive(Debug, Clone, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub struct ModelSignature {
    pub id: String,
    pub layout: Layout,
    pub hash: String,
}

/// FNV-1a, 64 bit: a hash stable across runs and platforms, for fingerprints of a model's
/// arrays ([`Template::signature`]) and of the files a study's results depend on.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Fnv1a(u64);

impl Default for Fnv1a {
    fn default() -> Self {
        Fnv1a(0xcbf2_9ce4_8422_2325)
    }
}

impl Fnv1a {
    /// Folds `bytes` into the hash.
    pub fn eat(&mut self, bytes: &[u8]) {
        for &b in bytes {
            self.0 ^= u64::from(b);
            self.0 = self.0.wrapping_mul(0x0000_0100_0000_01b3);
        }
    }

    /// The hash so far, 16 lowercase hex digits.
    pub fn hex(&self) -> String {
        format!("{:016x}", self.0)
    }
}

/// A skinned template mesh.
#[derive(Debug, Clone)]
pub struct Template {
    /// Identifier stored in datasets (`default`, `default+tall`, or the directory name).
    pub id: String,
    /// Rest-pose vertex positions, metres.
    pub vertices: Vec<Vec3>,
    /// Triangles, counter-clockwise seen from outside.
    pub faces: Vec<[u32; 3]>,
    pub rig: Rig,
    /// Blend shapes, pose correctives and joint regressor ([`Morph::none`] for a rigid template).
    pub morph: Arc<Morph>,
    /// Joint limits, part labels, mirror map, joint map and provenance.
    pub info: crate::info::ModelInfo,
    /// Whether some vertex has more than 4 influences (then skinning runs in f64 on the rig's lists).
    pub(crate) wide: bool,
    /// Packed influences for the skinning loops: joint indices and weights, zero-padded to 4.
    pub(crate) influence_joints: Vec<[u16; MAX_INFLUENCES]>,
    pub(crate) influence_weights: Vec<Vec4>,
    /// Every vertex's influences as flat f32 lists when some vertex has more than 4 (`wide`):
    /// vertex v's are `offsets[v]..offsets[v + 1]` of `joints` and `weights`.
    pub(crate) wide_influences: Option<WideInfluences>,
}

/// The influences of a template with more than 4 per vertex, flat (CSR), for the f32 loops.
#[derive(Debug, Clone)]
pub(crate) struct WideInfluences {
    pub(crate) offsets: Vec<u32>,
    pub(crate) joints: Vec<u16>,
    pub(crate) weights: Vec<f32>,
}

impl Template {
    /// Builds a template from parts, validating mesh and rig (SPEC §3).
    pub fn new(
        id: impl Into<String>,
        vertices: Vec<Vec3>,
        faces: Vec<[u32; 3]>,
        rig: Rig,
    ) -> Result<Self> {
        for (vertex, v) in vertices.iter().enumerate() {
            if !v.is_finite() {
                return Err(ModelError::Vertex {
                    vertex,
                    reason: format!("position {v} is not finite"),
                });
            }
        }
        for (face, f) in faces.iter().enumerate() {
            if let Some(&bad) = f.iter().find(|&&i| i as usize >= vertices.len()) {
                return Err(ModelError::Face {
                    face,
                    reason: format!(
                        "vertex index {bad} out of range (the mesh has {} vertices)",
                        vertices.len()
                    ),
                });
            }
            if f[0] == f[1] || f[1] == f[2] || f[0] == f[2] {
                return Err(ModelError::Face {
                    face,
                    reason: format!("repeats a vertex: {f:?}"),
                });
            }
        }
        if faces.is_empty() {
            return Err(ModelError::Face {
                face: 0,
                reason: "the mesh has no triangles".into(),
            });
        }
        rig.validate_with(vertices.len(), crate::rig::MAX_FILE_INFLUENCES)?;
        let wide = rig.weights.iter().any(|l| l.len() > MAX_INFLUENCES);
        let mut influence_joints = Vec::with_capacity(vertices.len());
        let mut influence_weights = Vec::with_capacity(vertices.len());
        for list in &rig.weights {
            let mut joints = [0u16; MAX_INFLUENCES];
            let mut weights = [0f32; MAX_INFLUENCES];
            for (k, &(j, w)) in list.iter().take(MAX_INFLUENCES).enumerate() {
                joints[k] = j as u16;
                weights[k] = w as f32;
            }
            influence_joints.push(joints);
            influence_weights.push(Vec4::from_array(weights));
        }
        let wide_influences = wide.then(|| {
            let mut offsets = Vec::with_capacity(rig.weights.len() + 1);
            offsets.push(0u32);
            let (mut joints, mut weights) = (Vec::new(), Vec::new());
            for list in &rig.weights {
                for &(j, w) in list {
                    joints.push(j as u16);
                    weights.push(w as f32);
                }
                offsets.push(joints.len() as u32);
            }
            WideInfluences {
                offsets,
                joints,
                weights,
            }
        });
        let info = crate::info::ModelInfo::fallback(&rig);
        Ok(Self {
            id: id.into(),
            vertices,
            faces,
            rig,
            morph: Arc::new(Morph::none()),
            info,
            wide,
            influence_joints,
            influence_weights,
            wide_influences,
        })
    }

    /// The same template with blend shapes and model information; checks their sizes.
    /// The rest vertices at β = ψ = 0 in f64: the morph's `v_template`, or the template's own
    /// (f32) vertices for a rigid template.
    pub fn rest_positions(&self) -> Vec<DVec3> {
        if self.morph.rest.is_empty() {
            self.vertices.iter().map(|v| v.as_dvec3()).collect()
        } else {
            self.morph.rest.clone()
        }
    }

    pub fn with_morph(mut self, morph: Morph, info: crate::info::ModelInfo) -> Result<Self> {
        let (v, j) = (self.vertices.len(), self.rig.num_joints());
        let k = morph.coefficients();
        let shape_err = |what: &str, expected: usize, got: usize| ModelError::Shape {
            what: what.into(),
            expected: expected.to_string(),
            got: got.to_string(),
        };
        if !morph.rest.is_empty() && morph.rest.len() != v {
            return Err(shape_err("morph rest vertices", v, morph.rest.len()));
        }
        if morph.dirs.len() != 3 * v * k {
            return Err(shape_err(
                "shape/expression directions",
                3 * v * k,
                morph.dirs.len(),
            ));
        }
        if let Some(pd) = &morph.posedirs
            && pd.len() != 3 * v * 9 * (j - 1)
        {
            return Err(shape_err("pose correctives", 3 * v * 9 * (j - 1), pd.len()));
        }
        if let Some(r) = &morph.regressor
            && (r.rows != j || r.cols != v)
        {
            return Err(ModelError::Shape {
                what: "J_regressor".into(),
                expected: format!("({j}, {v})"),
                got: format!("({}, {})", r.rows, r.cols),
            });
        }
        info.validate(j, v)?;
        self.morph = Arc::new(morph);
        self.info = info;
        Ok(self)
    }

    /// Whether skinning runs in f64 on the rig's weight lists: a morphable model (its rest points
    /// depend on the parameters) or one with more than 4 influences per vertex. Otherwise it runs
    /// in f32 SIMD on the packed influences.
    pub fn skins_in_f64(&self) -> bool {
        self.wide || !self.morph.is_rigid()
    }

    /// The model's signature: its parameter layout and a hash of every array that shapes its
    /// output (rest vertices, faces, joints, weights, blend shapes, regressor). A checkpoint
    /// stores it; fitting with another model is refused.
    pub fn signature(&self) -> ModelSignature {
        // FNV-1a, 64 bit: stable across runs and platforms (little-endian bytes of every value).
        let mut hash = Fnv1a::default();
        let mut eat = |bytes: &[u8]| hash.eat(bytes);
        for v in &self.vertices {
            for x in v.to_array() {
                eat(&x.to_le_bytes());
            }
        }
        for f in &self.faces {
            for i in f {
                eat(&i.to_le_bytes());
            }
        }
        for j in &self.rig.joints {
            eat(j.name.as_bytes());
            eat(&j.parent.map_or(u64::MAX, |p| p as u64).to_le_bytes());
            for x in j.rest_position {
                eat(&x.to_le_bytes());
            }
        }
        for list in &self.rig.weights {
            for &(j, w) in list {
                eat(&(j as u64).to_le_bytes());
                eat(&w.to_le_bytes());
            }
        }
        let m = &self.morph;
        for x in m
            .rest
            .iter()
            .flat_map(|p| p.to_array())
            .chain(m.dirs.iter().copied())
            .chain(m.posedirs.iter().flatten().copied())
            .chain(m.joint_dirs.iter().copied())
        {
            eat(&x.to_le_bytes());
        }
        eat(&(m.shape as u64).to_le_bytes());
        eat(&(m.expression as u64).to_le_bytes());
        ModelSignature {
            id: self.id.clone(),
            layout: self.layout(),
            hash: hash.hex(),
        }
    }

    /// Head, left wrist and right wrist joints (the `hmd` modality's devices), through the joint
    /// map to the papers/000 skeleton.
    pub fn hmd_joints(&self) -> Result<[usize; 3]> {
        let mut out = [0; 3];
        for (o, j) in out
            .iter_mut()
            .zip([skeleton::HEAD, skeleton::L_HAND, skeleton::R_HAND])
        {
            *o = self.info.joint_map.get(j).copied().flatten().ok_or_else(|| {
                ModelError::Config(format!(
                    "model '{}' maps no joint to the papers/000 '{}' that the hmd modality needs (lfit key 'joint_map')",
                    self.id,
                    skeleton::JOINT_NAMES[j]
                ))
            })?;
        }
        Ok(out)
    }

    /// The rigid template of one subject: rest vertices `T(β, ψ)` and rest joints `c(β, ψ)` for
    /// the coefficients `coeffs` (`[β; ψ]`, zero-padded), without blend shapes or pose
    /// correctives (what a glTF skin can hold). `self` when the model has no coefficients.
    pub fn shaped(&self, coeffs: &[f64]) -> Result<Self> {
        let k = self.morph.coefficients();
        if k == 0 {
            let mut t = self.clone();
            t.morph = Arc::new(Morph::none());
            return Ok(t);
        }
        let mut c = coeffs.to_vec();
        c.resize(k, 0.0);
        let vertices: Vec<Vec3> = (0..self.num_vertices())
            .map(|v| {
                self.morph
                    .rest_vertex(v, self.vertices[v].as_dvec3(), &c, &[])
                    .as_vec3()
            })
            .collect();
        let joints = self.morph.rest_joints(&self.joint_rest(), &c);
        let mut rig = self.rig.clone();
        for (j, p) in rig.joints.iter_mut().zip(&joints) {
            j.rest_position = p.to_array();
        }
        let mut t = Self::new(self.id.clone(), vertices, self.faces.clone(), rig)?;
        t.info = self.info.clone();
        Ok(t)
    }

    /// Length of the parameter vector, `3 + 3J + B + E` ([`Layout::dim`] without building the
    /// layout's names).
    pub fn param_dim(&self) -> usize {
        3 + 3 * self.rig.num_joints() + self.morph.coefficients()
    }

    /// The parameter layout: translation, one rotation per joint, β, ψ.
    pub fn layout(&self) -> Layout {
        Layout {
            joints: self.rig.joints.iter().map(|j| j.name.clone()).collect(),
            shape: self.morph.shape,
            expression: self.morph.expression,
        }
    }

    /// Where each parameter entry comes in the elimination order of a normal matrix `JᵀJ`
    /// (`rank[i]`; sort a system's entries by it before [`crate::energy::damped_step`]): the
    /// joints' rotations in post-order (every joint after its whole subtree, a joint's three
    /// entries together), then translation, shape and expression, which every row of a skinned
    /// point reads. A point depends on the joints of its chain only, so in this order the rows
    /// of a joint's entries reach back only over its own subtree and the Cholesky factor has no
    /// fill (George & Liu 1981, ch. 4: the elimination tree is the skeleton).
    pub fn elimination_rank(&self) -> Vec<usize> {
        let n = self.rig.num_joints();
        let mut children: Vec<Vec<usize>> = vec![Vec::new(); n];
        let mut roots = Vec::new();
        for (j, joint) in self.rig.joints.iter().enumerate() {
            match joint.parent {
                Some(p) if p < n => children[p].push(j),
                _ => roots.push(j),
            }
        }
        // Iterative post-order: a joint is emitted once its children are.
        let mut order = Vec::with_capacity(n);
        let mut stack: Vec<(usize, usize)> = roots.iter().rev().map(|&r| (r, 0)).collect();
        while let Some((j, k)) = stack.pop() {
            if k < children[j].len() {
                stack.push((j, k + 1));
                stack.push((children[j][k], 0));
            } else {
                order.push(j);
            }
        }
        let dim = self.param_dim();
        let mut rank = vec![0; dim];
        let mut next = 0;
        for &j in &order {
            for axis in 0..3 {
                rank[crate::layout::rot_offset(j) + axis] = next;
                next += 1;
            }
        }
        for (i, r) in rank.iter_mut().enumerate() {
            if !(3..3 + 3 * n).contains(&i) {
                *r = next;
                next += 1;
            }
        }
        rank
    }

    /// Whether this is the 18-joint skeleton of papers/000 (names and parents), rigid (no shape
    /// or expression): the model every part of lfit supports.
    pub fn is_default_skeleton(&self) -> bool {
        check_skeleton(&self.rig).is_ok()
            && self.morph.coefficients() == 0
            && self.morph.posedirs.is_none()
    }

    pub fn num_vertices(&self) -> usize {
        self.vertices.len()
    }

    /// Rest positions of the joints.
    pub fn joint_rest(&self) -> Vec<DVec3> {
        self.rig.joints.iter().map(|j| j.rest()).collect()
    }

    /// Dense `[vertex][joint]` weight matrix (row-major), for the tensor path.
    pub fn dense_weights(&self) -> Vec<f32> {
        let j = self.rig.num_joints();
        let mut dense = vec![0f32; self.vertices.len() * j];
        for (v, list) in self.rig.weights.iter().enumerate() {
            for &(joint, w) in list {
                dense[v * j + joint] += w as f32;
            }
        }
        dense
    }

    /// Rest positions as `Vec3A`, for the SIMD skinning loops.
    pub(crate) fn rest_a(&self) -> impl Iterator<Item = Vec3A> + '_ {
        self.vertices.iter().map(|&v| Vec3A::from(v))
    }

    /// The joint with the largest weight of every vertex.
    pub fn dominant_joint(&self) -> Vec<JointIndex> {
        self.rig
            .weights
            .iter()
            .map(|list| {
                list.iter()
                    .copied()
                    .fold(
                        (0, f64::MIN),
                        |best, (j, w)| if w > best.1 { (j, w) } else { best },
                    )
                    .0
            })
            .collect()
    }

    /// Loads `template.obj` + `rig.json` from `dir`.
    pub fn load_dir(dir: &Path) -> Result<Self> {
        let obj_path = dir.join(OBJ_FILE);
        let rig_path = dir.join(RIG_FILE);
        let (vertices, faces) = read_obj(&obj_path)?;
        let rig = read_rig(&rig_path)?;
        rig.validate(vertices.len())?;
        let id = dir.file_name().map_or_else(
            || "custom".to_string(),
            |n| n.to_string_lossy().into_owned(),
        );
        Self::new(id, vertices, faces, rig)
    }

    /// Writes `template.obj` + `rig.json` into `dir` (created if missing), each atomically.
    pub fn save(&self, dir: &Path) -> Result<()> {
        std::fs::create_dir_all(dir).map_err(|e| ModelError::io(dir, e))?;
        let mut obj = Vec::new();
        write_obj(
            &mut obj,
            &format!("lfit template '{}'", self.id),
            &self.vertices,
            &self.faces,
        );
        write_atomic(&dir.join(OBJ_FILE), &obj)?;
        let json = serde_json::to_vec_pretty(&self.rig).map_err(|e| ModelError::RigJson {
            path: dir.join(RIG_FILE),
            reason: e.to_string(),
        })?;
        write_atomic(&dir.join(RIG_FILE), &json)
    }
}

/// The default skeleton's tree: 18 joints with its names' parents.
fn check_skeleton(rig: &Rig) -> Result<()> {
    if rig.joints.len() != NUM_JOINTS {
        let index = rig.joints.len().min(NUM_JOINTS - 1);
        let name = rig
            .joints
            .get(index)
            .map_or_else(String::new, |j| j.name.clone());
        return Err(ModelError::Joint {
            index,
            name,
            reason: format!(
                "the rig has {} joints; this needs the 18-joint skeleton of papers/000",
                rig.joints.len()
            ),
        });
    }
    for (index, joint) in rig.joints.iter().enumerate() {
        if joint.parent != skeleton::PARENTS[index] {
            return Err(ModelError::Joint {
                index,
                name: joint.name.clone(),
                reason: format!(
                    "parent {:?} differs from the 18-joint skeleton's {:?} (joint {index} must be {})",
                    joint.parent,
                    skeleton::PARENTS[index],
                    skeleton::JOINT_NAMES[index]
                ),
            });
        }
    }
    Ok(())
}

/// Reads the positions (`v`) and faces (`f`, polygons fan-triangulated; `v/vt/vn` and negative
/// indices accepted) of an OBJ file, keeping the file's vertex order.
///
/// Written here rather than with `tobj` because the rig's weights are indexed by the file's
/// vertex order, and `tobj` renumbers vertices in order of first use by the faces.
pub fn read_obj(path: &Path) -> Result<(Vec<Vec3>, Vec<[u32; 3]>)> {
    let text = std::fs::read_to_string(path).map_err(|e| ModelError::io(path, e))?;
    parse_obj(&text).map_err(|reason| ModelError::Obj {
        path: path.to_path_buf(),
        reason,
    })
}

/// Parses OBJ text; the error names the line.
pub fn parse_obj(text: &str) -> std::result::Result<(Vec<Vec3>, Vec<[u32; 3]>), String> {
    let mut vertices = Vec::new();
    let mut faces = Vec::new();
    for (n, line) in text.lines().enumerate() {
        let line_no = n + 1;
        let mut items = line.split_whitespace();
        match items.next() {
            Some("v") => {
                let coords: Vec<f32> = items
                    .take(3)
                    .map(|s| {
                        s.parse::<f32>()
                            .map_err(|_| format!("line {line_no}: bad vertex coordinate '{s}'"))
                    })
                    .collect::<std::result::Result<_, _>>()?;
                if coords.len() != 3 {
                    return Err(format!("line {line_no}: a vertex needs 3 coordinates"));
                }
                let v = Vec3::new(coords[0], coords[1], coords[2]);
                if !v.is_finite() {
                    return Err(format!(
                        "line {line_no}: vertex {} is not finite",
                        vertices.len()
                    ));
                }
                vertices.push(v);
            }
            Some("f") => {
                let corners: Vec<u32> = items
                    .map(|item| {
                        let first = item.split('/').next().unwrap_or("");
                        let i: i64 = first
                            .parse()
                            .map_err(|_| format!("line {line_no}: bad face index '{item}'"))?;
                        let resolved = if i < 0 {
                            vertices.len() as i64 + i
                        } else {
                            i - 1
                        };
                        if i == 0 || resolved < 0 || resolved >= vertices.len() as i64 {
                            return Err(format!(
                                "line {line_no}: face index {i} out of range ({} vertices so far)",
                                vertices.len()
                            ));
                        }
                        Ok(resolved as u32)
                    })
                    .collect::<std::result::Result<_, _>>()?;
                if corners.len() < 3 {
                    return Err(format!("line {line_no}: a face needs at least 3 vertices"));
                }
                for k in 1..corners.len() - 1 {
                    faces.push([corners[0], corners[k], corners[k + 1]]);
                }
            }
            _ => {}
        }
    }
    if vertices.is_empty() {
        return Err("no vertices".into());
    }
    if faces.is_empty() {
        return Err("no faces".into());
    }
    Ok((vertices, faces))
}

/// Reads and parses `rig.json` (validation happens in [`Template::new`]).
pub fn read_rig(path: &Path) -> Result<Rig> {
    let text = std::fs::read_to_string(path).map_err(|e| ModelError::io(path, e))?;
    serde_json::from_str(&text).map_err(|e| ModelError::RigJson {
        path: path.to_path_buf(),
        reason: e.to_string(),
    })
}

/// Appends an OBJ text of the mesh to `out`; positions print in shortest round-trip form.
pub fn write_obj(out: &mut Vec<u8>, comment: &str, vertices: &[Vec3], faces: &[[u32; 3]]) {
    let _ = writeln!(
        out,
        "# {comment}\n# {} vertices, {} triangles",
        vertices.len(),
        faces.len()
    );
    for v in vertices {
        let _ = writeln!(out, "v {} {} {}", v.x, v.y, v.z);
    }
    for f in faces {
        let _ = writeln!(out, "f {} {} {}", f[0] + 1, f[1] + 1, f[2] + 1);
    }
}

/// Writes `bytes` to a temporary file beside `path`, then renames it over `path`, so a reader
/// never sees a half-written file and a failure leaves the old file intact.
pub fn write_atomic(path: &Path, bytes: &[u8]) -> Result<()> {
    let dir = match path.parent() {
        Some(d) if !d.as_os_str().is_empty() => d.to_path_buf(),
        _ => PathBuf::from("."),
    };
    let name = path
        .file_name()
        .map_or_else(|| "out".into(), |n| n.to_string_lossy().into_owned());
    let tmp = dir.join(format!(".{name}.tmp{}", std::process::id()));
    let result = (|| {
        let mut f = std::fs::File::create(&tmp)?;
        f.write_all(bytes)?;
        f.sync_all()?;
        std::fs::rename(&tmp, path)
    })();
    if let Err(e) = result {
        let _ = std::fs::remove_file(&tmp);
        return Err(ModelError::io(path, e));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_shaped_template_poses_like_the_morphable_model_at_its_coefficients() {
        // Without pose correctives a subject's rigid template is the morphable model at fixed β.
        let m = crate::body::smpl_like(2, 200, 4, false);
        let beta = [1.5, -2.0, 0.7, 0.0];
        let shaped = m.shaped(&beta).unwrap();
        assert!(shaped.morph.is_rigid());
        let mut params: Vec<f64> = (0..m.layout().pose_dim())
            .map(|i| ((i * 7 % 11) as f64 / 11.0 - 0.5) * 0.8)
            .collect();
        let pose = params.clone();
        params.extend(beta);
        let a = crate::skinning::pose_vertices(&m, &params, crate::SkinningMethod::Linear);
        let b = crate::skinning::pose_vertices(&shaped, &pose, crate::SkinningMethod::Linear);
        let worst = a
            .iter()
            .zip(&b)
            .map(|(p, q)| (*p - *q).length())
            .fold(0.0, f32::max);
        assert!(worst < 1e-5, "{worst}");
        // And β changes the mesh, so the comparison means something.
        let c = crate::skinning::pose_vertices(
            &m.shaped(&[0.0; 4]).unwrap(),
            &pose,
            crate::SkinningMethod::Linear,
        );
        assert!(
            a.iter()
                .zip(&c)
                .map(|(p, q)| (*p - *q).length())
                .fold(0.0, f32::max)
                > 1e-3
        );
    }

    #[test]
    fn obj_parser_keeps_vertex_order_and_triangulates() {
        let text = "# c\nv 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nvn 0 0 1\nf 3/1/1 4/2/1 1/3/1 2//1\nf -1 -2 -3\n";
        let (v, f) = parse_obj(text).unwrap();
        assert_eq!(v[2], Vec3::new(1.0, 1.0, 0.0));
        assert_eq!(f, vec![[2, 3, 0], [2, 0, 1], [3, 2, 1]]);
    }

    #[test]
    fn obj_parser_names_the_bad_line() {
        assert!(
            parse_obj("v 0 0 0\nv 1 0\n")
                .unwrap_err()
                .contains("line 2")
        );
        assert!(
            parse_obj("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 4\n")
                .unwrap_err()
                .contains("out of range")
        );
        assert!(parse_obj("v 0 0 nan\n").unwrap_err().contains("not finite"));
        assert!(parse_obj("v 0 0 0\n").unwrap_err().contains("no faces"));
        assert!(
            parse_obj("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 x\n")
                .unwrap_err()
                .contains("line 4")
        );
    }
}
