//! `lfit export` end to end: the `.glb` is read back by an independent glTF skinning
//! implementation (GLB container, accessors, node hierarchy, sampled animation, joint matrices,
//! linear blend) and must pose the mesh as `lfit template pose` does; the Khronos validator must
//! find no error in it; OBJ export equals `lfit template pose`; bad inputs are refused before
//! anything is written.
#![allow(clippy::unwrap_used)]

mod support;

use std::path::{Path, PathBuf};

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde_json::{Value, json};
use support::{
    assert_one_line_error, lfit, lfit_json, obj_vertices, path_str, skip_unless_required,
};

const FPS: f64 = 25.0;
const FRAMES: usize = 6;

/// A `sequence` dataset of `FRAMES` frames at `FPS` Hz.
fn dataset(dir: &Path, modality: &str) -> PathBuf {
    dataset_seeded(dir, modality, 4, &format!("{modality}.npz"))
}

/// [`dataset`] with another seed, written to `dir/name`.
fn dataset_seeded(dir: &Path, modality: &str, seed: u64, name: &str) -> PathBuf {
    let out = dir.join(name);
    let seed = seed.to_string();
    let frames = FRAMES.to_string();
    let fps = FPS.to_string();
    lfit_json(&[
        "synth",
        "--modality",
        modality,
        "--scenario",
        "sequence",
        "--frames",
        &frames,
        "--fps",
        &fps,
        "--seed",
        &seed,
        "--out",
        path_str(&out),
        "-q",
    ]);
    out
}

/// A real `lfit fit` result on frames 0, 2 and 5 (a gap the animation must keep).
fn fit_results(dir: &Path, data: &Path) -> PathBuf {
    let out = dir.join("results.json");
    lfit_json(&[
        "fit",
        "--data",
        path_str(data),
        "--method",
        "random",
        "--budget",
        "4",
        "--frames",
        "0,2,5",
        "--out",
        path_str(&out),
        "-q",
    ]);
    out
}

fn read_json(path: &Path) -> Value {
    serde_json::from_str(&std::fs::read_to_string(path).unwrap()).unwrap()
}

/// `(frame, pose)` of every row of a result file, in file order.
fn result_poses(results: &Value) -> Vec<(usize, Vec<f64>)> {
    results["frames"]
        .as_array()
        .unwrap()
        .iter()
        .map(|r| {
            (
                r["frame"].as_u64().unwrap() as usize,
                r["pose"]
                    .as_array()
                    .unwrap()
                    .iter()
                    .map(|x| x.as_f64().unwrap())
                    .collect(),
            )
        })
        .collect()
}

/// The vertices `lfit template pose` writes for `pose` (procedural default template).
fn template_pose(dir: &Path, pose: &[f64], tag: &str) -> PathBuf {
    let file = dir.join(format!("pose_{tag}.json"));
    std::fs::write(&file, json!({ "pose": pose }).to_string()).unwrap();
    let out = dir.join(format!("posed_{tag}.obj"));
    lfit_json(&[
        "template",
        "pose",
        "--pose",
        path_str(&file),
        "--out",
        path_str(&out),
    ]);
    out
}

// ---- An independent reader and evaluator of glTF 2.0 skinned animation, in plain f64. ----

type M4 = [[f64; 4]; 4];

const IDENTITY: M4 = [
    [1.0, 0.0, 0.0, 0.0],
    [0.0, 1.0, 0.0, 0.0],
    [0.0, 0.0, 1.0, 0.0],
    [0.0, 0.0, 0.0, 1.0],
];

fn mul(a: &M4, b: &M4) -> M4 {
    let mut c = [[0.0; 4]; 4];
    for i in 0..4 {
        for j in 0..4 {
            c[i][j] = (0..4).map(|k| a[i][k] * b[k][j]).sum();
        }
    }
    c
}

/// Row-major `T · R · S` of glTF §3.5.3 (quaternion `[x, y, z, w]`).
fn trs(t: [f64; 3], q: [f64; 4], s: [f64; 3]) -> M4 {
    let [x, y, z, w] = q;
    let r = [
        [
            1.0 - 2.0 * (y * y + z * z),
            2.0 * (x * y - z * w),
            2.0 * (x * z + y * w),
        ],
        [
            2.0 * (x * y + z * w),
            1.0 - 2.0 * (x * x + z * z),
            2.0 * (y * z - x * w),
        ],
        [
            2.0 * (x * z - y * w),
            2.0 * (y * z + x * w),
            1.0 - 2.0 * (x * x + y * y),
        ],
    ];
    let mut m = IDENTITY;
    for i in 0..3 {
        for j in 0..3 {
            m[i][j] = r[i][j] * s[j];
        }
        m[i][3] = t[i];
    }
    m
}

/// A parsed `.glb`: the JSON document and the BIN chunk.
struct Glb {
    doc: Value,
    bin: Vec<u8>,
}

fn u32_at(b: &[u8], at: usize) -> u32 {
    u32::from_le_bytes(b[at..at + 4].try_into().unwrap())
}

/// Parses the GLB container of glTF 2.0 §4.4, checking header, chunk types, lengths, alignment
/// and padding.
fn parse_glb(bytes: &[u8]) -> Glb {
    assert_eq!(&bytes[0..4], b"glTF", "magic");
    assert_eq!(u32_at(bytes, 4), 2, "GLB version");
    assert_eq!(
        u32_at(bytes, 8) as usize,
        bytes.len(),
        "header length is the file length"
    );
    let json_len = u32_at(bytes, 12) as usize;
    assert_eq!(u32_at(bytes, 16), 0x4E4F_534A, "first chunk is JSON");
    assert_eq!(json_len % 4, 0, "JSON chunk is 4-byte aligned");
    let json = &bytes[20..20 + json_len];
    let doc: Value =
        serde_json::from_slice(json).expect("the JSON chunk parses (space padding is whitespace)");
    let at = 20 + json_len;
    let bin_len = u32_at(bytes, at) as usize;
    assert_eq!(u32_at(bytes, at + 4), 0x004E_4942, "second chunk is BIN");
    assert_eq!(bin_len % 4, 0);
    assert_eq!(
        at + 8 + bin_len,
        bytes.len(),
        "no bytes after the BIN chunk"
    );
    let bin = bytes[at + 8..].to_vec();
    let declared = doc["buffers"][0]["byteLength"].as_u64().unwrap() as usize;
    assert!(
        declared <= bin.len() && bin.len() - declared < 4,
        "buffer 0 is the BIN chunk"
    );
    assert!(
        doc["buffers"][0].get("uri").is_none(),
        "buffer 0 of a GLB has no uri"
    );
    Glb { doc, bin }
}

impl Glb {
    /// Accessor `index` as `count` elements of its type's component count, converted to f64
    /// (glTF §3.6.2: FLOAT, UNSIGNED_BYTE, UNSIGNED_SHORT, UNSIGNED_INT; byteStride respected).
    fn accessor(&self, index: usize) -> Vec<Vec<f64>> {
        let a = &self.doc["accessors"][index];
        let view = &self.doc["bufferViews"][a["bufferView"].as_u64().unwrap() as usize];
        assert_eq!(view["buffer"], 0);
        let n = match a["type"].as_str().unwrap() {
            "SCALAR" => 1,
            "VEC2" => 2,
            "VEC3" => 3,
            "VEC4" => 4,
            "MAT4" => 16,
            other => panic!("accessor type {other}"),
        };
        let (size, read): (usize, fn(&[u8]) -> f64) = match a["componentType"].as_u64().unwrap() {
            5126 => (4, |b| f64::from(f32::from_le_bytes(b.try_into().unwrap()))),
            5121 => (1, |b| f64::from(b[0])),
            5123 => (2, |b| f64::from(u16::from_le_bytes(b.try_into().unwrap()))),
            5125 => (4, |b| f64::from(u32::from_le_bytes(b.try_into().unwrap()))),
            other => panic!("componentType {other}"),
        };
        let start = view["byteOffset"].as_u64().unwrap_or(0) as usize
            + a["byteOffset"].as_u64().unwrap_or(0) as usize;
        let stride = view["byteStride"].as_u64().map_or(n * size, |s| s as usize);
        let count = a["count"].as_u64().unwrap() as usize;
        assert!(
            start + stride * (count - 1) + n * size
                <= view["byteOffset"].as_u64().unwrap_or(0) as usize
                    + view["byteLength"].as_u64().unwrap() as usize,
            "accessor {index} inside its view"
        );
        (0..count)
            .map(|e| {
                (0..n)
                    .map(|k| {
                        read(
                            &self.bin[start + e * stride + k * size
                                ..start + e * stride + (k + 1) * size],
                        )
                    })
                    .collect()
            })
            .collect()
    }

    /// Local TRS of every node at animation time `t` (animation 0): the node's own values,
    /// overridden by the channels sampled per glTF §3.11 (LINEAR: lerp, slerp for rotation).
    fn local_trs(&self, t: f64) -> Vec<([f64; 3], [f64; 4], [f64; 3])> {
        let vec = |v: &Value, default: &[f64]| -> Vec<f64> {
            v.as_array().map_or(default.to_vec(), |a| {
                a.iter().map(|x| x.as_f64().unwrap()).collect()
            })
        };
        let mut trs: Vec<([f64; 3], [f64; 4], [f64; 3])> = self.doc["nodes"]
            .as_array()
            .unwrap()
            .iter()
            .map(|n| {
                assert!(n.get("matrix").is_none(), "nodes use TRS");
                let t = vec(&n["translation"], &[0.0; 3]);
                let r = vec(&n["rotation"], &[0.0, 0.0, 0.0, 1.0]);
                let s = vec(&n["scale"], &[1.0; 3]);
                (
                    [t[0], t[1], t[2]],
                    [r[0], r[1], r[2], r[3]],
                    [s[0], s[1], s[2]],
                )
            })
            .collect();
        let anim = &self.doc["animations"][0];
        for channel in anim["channels"].as_array().unwrap() {
            let sampler = &anim["samplers"][channel["sampler"].as_u64().unwrap() as usize];
            assert_eq!(sampler["interpolation"], "LINEAR");
            let times: Vec<f64> = self
                .accessor(sampler["input"].as_u64().unwrap() as usize)
                .into_iter()
                .map(|v| v[0])
                .collect();
            let values = self.accessor(sampler["output"].as_u64().unwrap() as usize);
            assert_eq!(times.len(), values.len());
            let (i, u) = match times.iter().position(|&k| k > t) {
                Some(0) => (0, 0.0),
                None => (times.len() - 1, 0.0),
                Some(next) => (
                    next - 1,
                    (t - times[next - 1]) / (times[next] - times[next - 1]),
                ),
            };
            let a = &values[i];
            let b = values.get(i + 1).unwrap_or(a);
            let node = channel["target"]["node"].as_u64().unwrap() as usize;
            match channel["target"]["path"].as_str().unwrap() {
                "translation" => trs[node].0 = [0, 1, 2].map(|k| a[k] + u * (b[k] - a[k])),
                "rotation" => trs[node].1 = slerp(a, b, u),
                "scale" => trs[node].2 = [0, 1, 2].map(|k| a[k] + u * (b[k] - a[k])),
                other => panic!("path {other}"),
            }
        }
        trs
    }

    /// Global matrix of every node at time `t`, from the scene's roots down.
    fn globals(&self, t: f64) -> Vec<M4> {
        let local = self.local_trs(t);
        let nodes = self.doc["nodes"].as_array().unwrap();
        let mut global: Vec<Option<M4>> = vec![None; nodes.len()];
        let mut stack: Vec<(usize, M4)> = self.doc["scenes"]
            [self.doc["scene"].as_u64().unwrap() as usize]["nodes"]
            .as_array()
            .unwrap()
            .iter()
            .map(|n| (n.as_u64().unwrap() as usize, IDENTITY))
            .collect();
        while let Some((n, parent)) = stack.pop() {
            let (t, r, s) = local[n];
            let g = mul(&parent, &trs(t, r, s));
            assert!(global[n].is_none(), "node {n} reached twice");
            global[n] = Some(g);
            for c in nodes[n]["children"]
                .as_array()
                .map(Vec::as_slice)
                .unwrap_or_default()
            {
                stack.push((c.as_u64().unwrap() as usize, g));
            }
        }
        global
            .into_iter()
            .enumerate()
            .map(|(n, g)| g.unwrap_or_else(|| panic!("node {n} is not in the scene")))
            .collect()
    }

    /// Skinned positions of mesh 0 / primitive 0 at time `t` (glTF §3.7.3: joint matrix =
    /// inverse(global(mesh node)) · global(joint) · IBM; vertex = Σ w_k · jointMatrix_k · v).
    fn skinned(&self, t: f64) -> Vec<[f64; 3]> {
        let globals = self.globals(t);
        let mesh_node = self.doc["nodes"]
            .as_array()
            .unwrap()
            .iter()
            .position(|n| n.get("mesh").is_some())
            .unwrap();
        let mesh_global = globals[mesh_node];
        assert_eq!(
            mesh_global, IDENTITY,
            "the skinned mesh node is untransformed (so its inverse is the identity)"
        );
        let skin =
            &self.doc["skins"][self.doc["nodes"][mesh_node]["skin"].as_u64().unwrap() as usize];
        let ibm = self.accessor(skin["inverseBindMatrices"].as_u64().unwrap() as usize);
        let joint_matrices: Vec<M4> = skin["joints"]
            .as_array()
            .unwrap()
            .iter()
            .zip(&ibm)
            .map(|(node, m)| {
                // Accessor MAT4 is column-major.
                let ibm: M4 = [0, 1, 2, 3].map(|i| [0, 1, 2, 3].map(|j| m[4 * j + i]));
                mul(&globals[node.as_u64().unwrap() as usize], &ibm)
            })
            .collect();
        let prim = &self.doc["meshes"][0]["primitives"][0];
        let attribute =
            |name: &str| self.accessor(prim["attributes"][name].as_u64().unwrap() as usize);
        let (positions, joints, weights) = (
            attribute("POSITION"),
            attribute("JOINTS_0"),
            attribute("WEIGHTS_0"),
        );
        positions
            .iter()
            .zip(&joints)
            .zip(&weights)
            .map(|((p, j), w)| {
                let mut out = [0.0; 3];
                for k in 0..4 {
                    let m = &joint_matrices[j[k] as usize];
                    for (i, o) in out.iter_mut().enumerate() {
                        *o += w[k] * (m[i][0] * p[0] + m[i][1] * p[1] + m[i][2] * p[2] + m[i][3]);
                    }
                }
                out
            })
            .collect()
    }
}

/// Spherical linear interpolation of unit quaternions (shortest arc).
fn slerp(a: &[f64], b: &[f64], u: f64) -> [f64; 4] {
    let mut dot: f64 = (0..4).map(|k| a[k] * b[k]).sum();
    let sign = if dot < 0.0 { -1.0 } else { 1.0 };
    dot *= sign;
    let (wa, wb) = if dot > 0.9995 {
        (1.0 - u, u)
    } else {
        let theta = dot.acos();
        (
            ((1.0 - u) * theta).sin() / theta.sin(),
            (u * theta).sin() / theta.sin(),
        )
    };
    let q = [0, 1, 2, 3].map(|k| wa * a[k] + wb * sign * b[k]);
    let n = q.iter().map(|x| x * x).sum::<f64>().sqrt();
    q.map(|x| x / n)
}

fn max_deviation(a: &[[f64; 3]], b: &[[f64; 3]]) -> f64 {
    assert_eq!(a.len(), b.len());
    a.iter()
        .zip(b)
        .map(|(p, q)| (0..3).map(|k| (p[k] - q[k]).powi(2)).sum::<f64>().sqrt())
        .fold(0.0, support::nan_max)
}

fn export(data: &Path, poses: &Path, format: &str, out: &Path) -> Value {
    lfit_json(&[
        "export",
        "--data",
        path_str(data),
        "--poses",
        path_str(poses),
        "--format",
        format,
        "--out",
        path_str(out),
    ])
}

#[test]
fn export_gltf_skinned_by_an_independent_reader_equals_template_pose() {
    let dir = tempfile::tempdir().unwrap();
    let data = dataset(dir.path(), "markers");
    let results = fit_results(dir.path(), &data);
    let poses = result_poses(&read_json(&results));
    let out = dir.path().join("gltf");
    let summary = export(&data, &results, "gltf", &out);
    assert_eq!(summary["frames"], 3);
    let glb_path = out.join("results.glb");
    assert_eq!(summary["written"], json!([glb_path]));
    let glb = parse_glb(&std::fs::read(&glb_path).unwrap());

    // Skeleton: one node per rig joint, named and parented as in rig.json.
    let tpl = dir.path().join("tpl");
    lfit_json(&["template", "export", "--out-dir", path_str(&tpl)]);
    let rig = read_json(&tpl.join("rig.json"));
    let joints = rig["joints"].as_array().unwrap();
    let skin = &glb.doc["skins"][0];
    let skin_joints: Vec<usize> = skin["joints"]
        .as_array()
        .unwrap()
        .iter()
        .map(|j| j.as_u64().unwrap() as usize)
        .collect();
    assert_eq!(skin_joints.len(), joints.len());
    let nodes = glb.doc["nodes"].as_array().unwrap();
    let mut parent_of = vec![None; nodes.len()];
    for (n, node) in nodes.iter().enumerate() {
        for c in node["children"]
            .as_array()
            .map(Vec::as_slice)
            .unwrap_or_default()
        {
            parent_of[c.as_u64().unwrap() as usize] = Some(n);
        }
    }
    for (j, joint) in joints.iter().enumerate() {
        let node = skin_joints[j];
        assert_eq!(nodes[node]["name"], joint["name"], "joint {j}");
        let expected_parent = joint["parent"].as_u64().map(|p| skin_joints[p as usize]);
        assert_eq!(parent_of[node], expected_parent, "parent of joint {j}");
    }
    let root = skin_joints[0];
    assert_eq!(skin["skeleton"].as_u64(), Some(root as u64));
    let scene_roots = &glb.doc["scenes"][0]["nodes"];
    let mesh_node = nodes.iter().position(|n| n.get("mesh").is_some()).unwrap();
    assert!(
        parent_of[mesh_node].is_none(),
        "the skinned mesh node is a scene root"
    );
    for n in [root, mesh_node] {
        assert!(
            scene_roots.as_array().unwrap().contains(&json!(n)),
            "node {n} is a scene root"
        );
    }
    for key in ["translation", "rotation", "scale", "matrix"] {
        assert!(
            nodes[mesh_node].get(key).is_none(),
            "the skinned mesh node has no {key}"
        );
    }

    // Time keys are frame / fps of the result's frames (gaps kept), strictly increasing.
    let anim = &glb.doc["animations"][0];
    assert_eq!(
        anim["channels"].as_array().unwrap().len(),
        2 * joints.len(),
        "translation + rotation per joint"
    );
    for sampler in anim["samplers"].as_array().unwrap() {
        let times: Vec<f64> = glb
            .accessor(sampler["input"].as_u64().unwrap() as usize)
            .into_iter()
            .map(|v| v[0])
            .collect();
        let expected: Vec<f64> = poses
            .iter()
            .map(|(f, _)| f64::from((*f as f64 / FPS) as f32))
            .collect();
        assert_eq!(times, expected);
        assert!(times.windows(2).all(|w| w[0] < w[1]));
    }
    assert_eq!(poses.iter().map(|(f, _)| *f).collect::<Vec<_>>(), [0, 2, 5]);

    // Frame 0 (the first key) and frame 5 (the last): the glTF skin equals `lfit template pose`.
    for (frame, pose) in [&poses[0], &poses[2]] {
        let skinned = glb.skinned(*frame as f64 / FPS);
        let expected = obj_vertices(&template_pose(dir.path(), pose, &frame.to_string()));
        let max = max_deviation(&skinned, &expected);
        eprintln!("frame {frame}: glTF skinning vs lfit template pose, max deviation {max:.2e} m");
        assert!(
            max < 1e-4,
            "frame {frame}: glTF skinning deviates from lfit template pose by {max} m"
        );
    }
    // Half-way between frames 2 and 5 the animation interpolates: the mesh differs from both ends.
    let mid = glb.skinned(3.5 / FPS);
    let at2 = glb.skinned(2.0 / FPS);
    assert!(max_deviation(&mid, &at2) > 0.0);
}

#[test]
fn export_gltf_reproduces_lbs_for_large_rotations_from_a_poses_file() {
    // Angles up to 2.5 rad around random axes (beyond π in some sums), root moves by metres:
    // quaternion signs, hierarchy order and the root translation all show up.
    let dir = tempfile::tempdir().unwrap();
    let data = dataset(dir.path(), "markers");
    let mut rng = ChaCha8Rng::seed_from_u64(77);
    let poses: Vec<Vec<f64>> = (0..4)
        .map(|_| {
            (0..57)
                .map(|i| {
                    if i < 3 {
                        rng.random_range(-2.0..2.0)
                    } else {
                        rng.random_range(-2.5..2.5)
                    }
                })
                .collect()
        })
        .collect();
    let file = dir.path().join("wild.json");
    std::fs::write(&file, json!({ "poses": poses }).to_string()).unwrap();
    let out = dir.path().join("gltf");
    export(&data, &file, "gltf", &out);
    let glb = parse_glb(&std::fs::read(out.join("wild.glb")).unwrap());
    for (frame, pose) in poses.iter().enumerate() {
        let skinned = glb.skinned(frame as f64 / FPS);
        let expected = obj_vertices(&template_pose(dir.path(), pose, &frame.to_string()));
        let max = max_deviation(&skinned, &expected);
        eprintln!("wild pose {frame}: max deviation {max:.2e} m");
        assert!(max < 1e-4, "frame {frame}: {max} m");
    }
}

#[test]
fn export_gltf_passes_the_khronos_validator() {
    let prefix = match support::gltf_validator() {
        Ok(p) => p,
        Err(reason) => {
            skip_unless_required(
                &format!("the glTF validator is unavailable: {reason}"),
                None,
            );
            return;
        }
    };
    let dir = tempfile::tempdir().unwrap();
    let data = dataset(dir.path(), "markers");
    let results = fit_results(dir.path(), &data);
    let out = dir.path().join("gltf");
    export(&data, &results, "gltf", &out);
    let (report, stdout) = support::validate_glb(&prefix, &out.join("results.glb"));
    let issues = &report["issues"];
    let codes: Vec<String> = issues["messages"]
        .as_array()
        .unwrap()
        .iter()
        .map(|m| format!("{} {} {}", m["severity"], m["code"], m["pointer"]))
        .collect();
    eprintln!(
        "gltf-validator {}: {} errors, {} warnings, {} infos, {} hints; messages (severity 0 error .. 3 hint): {codes:?}",
        report["validatorVersion"],
        issues["numErrors"],
        issues["numWarnings"],
        issues["numInfos"],
        issues["numHints"]
    );
    assert_eq!(issues["numErrors"], 0, "{stdout}");
    assert_eq!(issues["numWarnings"], 0, "{stdout}");
    assert_eq!(report["info"]["animationCount"], 1);
    assert_eq!(report["info"]["hasSkins"], true);
}

#[test]
fn export_obj_writes_one_template_pose_mesh_per_fitted_frame() {
    let dir = tempfile::tempdir().unwrap();
    let data = dataset(dir.path(), "markers");
    let results = fit_results(dir.path(), &data);
    let poses = result_poses(&read_json(&results));
    let out = dir.path().join("obj");
    let summary = export(&data, &results, "obj", &out);
    let mut files: Vec<String> = std::fs::read_dir(&out)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    files.sort();
    assert_eq!(
        files,
        ["frame_00000.obj", "frame_00002.obj", "frame_00005.obj"]
    );
    assert_eq!(summary["written"].as_array().unwrap().len(), poses.len());
    // Same LBS and the same writer: every vertex and face line is byte-identical.
    let body = |p: &Path| {
        std::fs::read_to_string(p)
            .unwrap()
            .lines()
            .filter(|l| !l.starts_with('#'))
            .map(str::to_string)
            .collect::<Vec<_>>()
    };
    for (frame, pose) in &poses {
        let expected = template_pose(dir.path(), pose, &frame.to_string());
        assert_eq!(
            body(&out.join(format!("frame_{frame:05}.obj"))),
            body(&expected),
            "frame {frame}"
        );
    }
    // A {"poses": [...]} file is frames 0..n.
    let file = dir.path().join("two.json");
    std::fs::write(
        &file,
        json!({ "poses": [poses[1].1, poses[0].1] }).to_string(),
    )
    .unwrap();
    let out2 = dir.path().join("obj2");
    export(&data, &file, "obj", &out2);
    assert_eq!(
        body(&out2.join("frame_00000.obj")),
        body(&out.join("frame_00002.obj"))
    );
    assert_eq!(
        body(&out2.join("frame_00001.obj")),
        body(&out.join("frame_00000.obj"))
    );
    assert_eq!(std::fs::read_dir(&out2).unwrap().count(), 2);
}

#[test]
fn export_refuses_results_that_do_not_match_the_dataset_before_writing() {
    let dir = tempfile::tempdir().unwrap();
    let data = dataset(dir.path(), "markers");
    let other_modality = dataset(dir.path(), "keypoints2d");
    let other_seed = dataset_seeded(dir.path(), "markers", 5, "other-seed.npz");
    let results = fit_results(dir.path(), &data);
    let good = read_json(&results);
    let out = dir.path().join("never");
    let write = |name: &str, text: &str| {
        let p = dir.path().join(name);
        std::fs::write(&p, text).unwrap();
        p
    };
    let edited = |name: &str, edit: &dyn Fn(&mut Value)| {
        let mut v = good.clone();
        edit(&mut v);
        write(name, &v.to_string())
    };
    let run = |data: &Path, poses: &Path, format: &str| {
        lfit(&[
            "export",
            "--data",
            path_str(data),
            "--poses",
            path_str(poses),
            "--format",
            format,
            "--out",
            path_str(&out),
        ])
    };

    let cases: Vec<(PathBuf, PathBuf, &str, &str)> = vec![
        (
            data.clone(),
            edited("beyond.json", &|v| {
                v["frames"][1]["frame"] = json!(FRAMES + 3)
            }),
            "gltf",
            "out of range",
        ),
        (other_modality.clone(), results.clone(), "gltf", "modality"),
        // The fit of another dataset of the same model and modality (another seed): its
        // recorded V2V is not what its poses give against this dataset's ground truth.
        (
            other_seed.clone(),
            results.clone(),
            "obj",
            "another dataset",
        ),
        (
            other_seed.clone(),
            results.clone(),
            "gltf",
            "another dataset",
        ),
        (other_modality.clone(), results.clone(), "obj", "modality"),
        (
            data.clone(),
            write(
                "malformed.json",
                "{\"frames\": [{\"frame\": 0, \"pose\": [0, 1,",
            ),
            "gltf",
            "malformed",
        ),
        (data.clone(), results.clone(), "bad", "format"),
        (
            data.clone(),
            edited("short.json", &|v| {
                v["frames"][0]["pose"] = json!(vec![0.0; 56])
            }),
            "obj",
            "57",
        ),
        (
            data.clone(),
            edited("nan.json", &|v| v["frames"][2]["pose"][7] = Value::Null),
            "gltf",
            "not a finite number",
        ),
        (
            data.clone(),
            edited("dup.json", &|v| v["frames"][1]["frame"] = json!(0)),
            "gltf",
            "twice",
        ),
        (
            data.clone(),
            edited("empty.json", &|v| v["frames"] = json!([])),
            "gltf",
            "empty",
        ),
        (
            data.clone(),
            write("neither.json", "{\"x\": 1}"),
            "obj",
            "expected",
        ),
        (
            data.clone(),
            dir.path().join("missing.json"),
            "obj",
            "cannot read",
        ),
    ];
    for (data, poses, format, needle) in &cases {
        let output = run(data, poses, format);
        assert_one_line_error(&output, needle);
        assert!(!out.exists(), "{needle}: nothing may be written to --out");
    }
    // The same results against their own dataset export fine.
    assert!(run(&data, &results, "gltf").status.success());
    assert!(out.join("results.glb").is_file());
}
