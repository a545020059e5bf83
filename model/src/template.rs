//! A template: triangle mesh (OBJ) + rig (JSON), validated on load, written atomically.

use std::io::{BufReader, Write};
use std::path::{Path, PathBuf};

use glam::{DVec3, Vec3, Vec3A, Vec4};

use crate::error::{ModelError, Result};
use crate::rig::{JointIndex, MAX_INFLUENCES, Rig};
use crate::skeleton::{self, NUM_JOINTS};

/// File names inside a template directory.
pub const OBJ_FILE: &str = "template.obj";
pub const RIG_FILE: &str = "rig.json";

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
    /// Packed influences for the skinning loops: joint indices and weights, zero-padded to 4.
    pub(crate) influence_joints: Vec<[u16; MAX_INFLUENCES]>,
    pub(crate) influence_weights: Vec<Vec4>,
}

impl Template {
    /// Builds a template from parts, validating mesh and rig (SPEC §3).
    pub fn new(id: impl Into<String>, vertices: Vec<Vec3>, faces: Vec<[u32; 3]>, rig: Rig) -> Result<Self> {
        for (vertex, v) in vertices.iter().enumerate() {
            if !v.is_finite() {
                return Err(ModelError::Vertex { vertex, reason: format!("position {v} is not finite") });
            }
        }
        for (face, f) in faces.iter().enumerate() {
            if let Some(&bad) = f.iter().find(|&&i| i as usize >= vertices.len()) {
                return Err(ModelError::Face {
                    face,
                    reason: format!("vertex index {bad} out of range (the mesh has {} vertices)", vertices.len()),
                });
            }
            if f[0] == f[1] || f[1] == f[2] || f[0] == f[2] {
                return Err(ModelError::Face { face, reason: format!("repeats a vertex: {f:?}") });
            }
        }
        if faces.is_empty() {
            return Err(ModelError::Face { face: 0, reason: "the mesh has no triangles".into() });
        }
        rig.validate(vertices.len())?;
        check_skeleton(&rig)?;
        let mut influence_joints = Vec::with_capacity(vertices.len());
        let mut influence_weights = Vec::with_capacity(vertices.len());
        for list in &rig.weights {
            let mut joints = [0u16; MAX_INFLUENCES];
            let mut weights = [0f32; MAX_INFLUENCES];
            for (k, &(j, w)) in list.iter().enumerate() {
                joints[k] = j as u16;
                weights[k] = w as f32;
            }
            influence_joints.push(joints);
            influence_weights.push(Vec4::from_array(weights));
        }
        Ok(Self { id: id.into(), vertices, faces, rig, influence_joints, influence_weights })
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
            .map(|list| list.iter().copied().fold((0, f64::MIN), |best, (j, w)| if w > best.1 { (j, w) } else { best }).0)
            .collect()
    }

    /// Loads `template.obj` + `rig.json` from `dir`.
    pub fn load(dir: &Path) -> Result<Self> {
        let obj_path = dir.join(OBJ_FILE);
        let rig_path = dir.join(RIG_FILE);
        let (vertices, faces) = read_obj(&obj_path)?;
        let rig = read_rig(&rig_path)?;
        let id = dir.file_name().map_or_else(|| "custom".to_string(), |n| n.to_string_lossy().into_owned());
        Self::new(id, vertices, faces, rig)
    }

    /// Writes `template.obj` + `rig.json` into `dir` (created if missing), each atomically.
    pub fn save(&self, dir: &Path) -> Result<()> {
        std::fs::create_dir_all(dir).map_err(|e| ModelError::io(dir, e))?;
        let mut obj = Vec::new();
        write_obj(&mut obj, &format!("lfit template '{}'", self.id), &self.vertices, &self.faces);
        write_atomic(&dir.join(OBJ_FILE), &obj)?;
        let json = serde_json::to_vec_pretty(&self.rig).map_err(|e| ModelError::RigJson {
            path: dir.join(RIG_FILE),
            reason: e.to_string(),
        })?;
        write_atomic(&dir.join(RIG_FILE), &json)
    }
}

/// The pose vector is defined for the 18-joint skeleton: another template must share its tree.
fn check_skeleton(rig: &Rig) -> Result<()> {
    if rig.joints.len() != NUM_JOINTS {
        let index = rig.joints.len().min(NUM_JOINTS - 1);
        let name = rig.joints.get(index).map_or_else(String::new, |j| j.name.clone());
        return Err(ModelError::Joint {
            index,
            name,
            reason: format!("the rig has {} joints; lfit's pose vector needs the 18-joint skeleton of papers/000", rig.joints.len()),
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

/// Reads triangle mesh positions and faces with `tobj` (quads and polygons are triangulated).
pub fn read_obj(path: &Path) -> Result<(Vec<Vec3>, Vec<[u32; 3]>)> {
    let file = std::fs::File::open(path).map_err(|e| ModelError::io(path, e))?;
    let mut reader = BufReader::new(file);
    let options = tobj::LoadOptions { triangulate: true, ignore_points: true, ignore_lines: true, ..Default::default() };
    let (models, _) = tobj::load_obj_buf(&mut reader, &options, |_| Err(tobj::LoadError::GenericFailure))
        .map_err(|e| ModelError::Obj { path: path.to_path_buf(), reason: e.to_string() })?;
    let mut vertices = Vec::new();
    let mut faces = Vec::new();
    for model in models {
        let mesh = model.mesh;
        if mesh.positions.len() % 3 != 0 {
            return Err(ModelError::Obj { path: path.to_path_buf(), reason: "positions are not triples".into() });
        }
        let base = vertices.len() as u32;
        vertices.extend(mesh.positions.chunks_exact(3).map(|p| Vec3::new(p[0], p[1], p[2])));
        faces.extend(mesh.indices.chunks_exact(3).map(|f| [f[0] + base, f[1] + base, f[2] + base]));
    }
    if vertices.is_empty() {
        return Err(ModelError::Obj { path: path.to_path_buf(), reason: "no vertices".into() });
    }
    if faces.is_empty() {
        return Err(ModelError::Obj { path: path.to_path_buf(), reason: "no faces".into() });
    }
    Ok((vertices, faces))
}

/// Reads and parses `rig.json` (validation happens in [`Template::new`]).
pub fn read_rig(path: &Path) -> Result<Rig> {
    let text = std::fs::read_to_string(path).map_err(|e| ModelError::io(path, e))?;
    serde_json::from_str(&text).map_err(|e| ModelError::RigJson { path: path.to_path_buf(), reason: e.to_string() })
}

/// Appends an OBJ text of the mesh to `out`; positions print in shortest round-trip form.
pub fn write_obj(out: &mut Vec<u8>, comment: &str, vertices: &[Vec3], faces: &[[u32; 3]]) {
    let _ = writeln!(out, "# {comment}\n# {} vertices, {} triangles", vertices.len(), faces.len());
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
    let name = path.file_name().map_or_else(|| "out".into(), |n| n.to_string_lossy().into_owned());
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
