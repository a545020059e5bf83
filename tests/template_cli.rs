//! `lfit template export` / `lfit template pose` end to end, checked against a generic OBJ reader
//! and an independent re-implementation of SPEC §3.

mod support;

use std::collections::HashMap;

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use support::{lfit_json, obj_vertices, path_str};

/// A generic OBJ reader (tobj), as a downstream tool would load the file.
fn load_obj(path: &std::path::Path) -> (Vec<[f64; 3]>, Vec<[usize; 3]>) {
    let (models, _) = tobj::load_obj(
        path,
        &tobj::LoadOptions {
            triangulate: true,
            ..Default::default()
        },
    )
    .expect("generic OBJ reader loads it");
    let mesh = &models[0].mesh;
    let v = mesh
        .positions
        .chunks(3)
        .map(|p| [p[0] as f64, p[1] as f64, p[2] as f64])
        .collect();
    let f = mesh
        .indices
        .chunks(3)
        .map(|f| [f[0] as usize, f[1] as usize, f[2] as usize])
        .collect();
    (v, f)
}

#[test]
fn exported_template_is_a_closed_manifold_with_18_joints_and_markers() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("tpl");
    let summary = lfit_json(&["template", "export", "--out-dir", path_str(&out)]);
    let (vertices, faces) = load_obj(&out.join("template.obj"));
    assert_eq!(vertices.len() as u64, summary["vertices"].as_u64().unwrap());
    // The template numbers its vertices in order of first use, so a reader that renumbers that
    // way (tobj) keeps the file order that rig.json's weights index.
    let in_file = obj_vertices(&out.join("template.obj"));
    assert_eq!(vertices.len(), in_file.len());
    assert!(
        vertices
            .iter()
            .zip(&in_file)
            .all(|(a, b)| (0..3).all(|k| (a[k] - b[k]).abs() < 1e-6)),
        "tobj sees the file's vertex order"
    );
    assert!(
        (3000..=8000).contains(&vertices.len()),
        "{} vertices",
        vertices.len()
    );
    let mut edges: HashMap<(usize, usize), usize> = HashMap::new();
    for f in &faces {
        for k in 0..3 {
            let (a, b) = (f[k], f[(k + 1) % 3]);
            *edges.entry((a.min(b), a.max(b))).or_default() += 1;
        }
    }
    let bad = edges.values().filter(|&&c| c != 2).count();
    assert_eq!(bad, 0, "edges without exactly two faces");
    let rig: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("rig.json")).unwrap()).unwrap();
    assert_eq!(rig["joints"].as_array().unwrap().len(), 18);
    let markers = rig["markers"].as_array().unwrap().len();
    assert!((36..=44).contains(&markers), "{markers} markers");
    assert_eq!(rig["weights"].as_array().unwrap().len(), vertices.len());
}

// ---- An independent implementation of SPEC §3 in plain f64 arrays (no glam). ----

type M3 = [[f64; 3]; 3];

fn mat_mul(a: &M3, b: &M3) -> M3 {
    let mut c = [[0.0; 3]; 3];
    for i in 0..3 {
        for j in 0..3 {
            c[i][j] = (0..3).map(|k| a[i][k] * b[k][j]).sum();
        }
    }
    c
}

fn mat_vec(a: &M3, v: [f64; 3]) -> [f64; 3] {
    [0, 1, 2].map(|i| a[i][0] * v[0] + a[i][1] * v[1] + a[i][2] * v[2])
}

/// R = I + sin θ K̂ + (1 − cos θ) K̂², K̂ the cross matrix of the unit axis.
fn rodrigues(r: [f64; 3]) -> M3 {
    let theta = (r[0] * r[0] + r[1] * r[1] + r[2] * r[2]).sqrt();
    if theta < 1e-14 {
        return [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
    }
    let k = [r[0] / theta, r[1] / theta, r[2] / theta];
    let kx = [[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]];
    let kx2 = mat_mul(&kx, &kx);
    let mut m = [[0.0; 3]; 3];
    for i in 0..3 {
        for j in 0..3 {
            m[i][j] = f64::from(u8::from(i == j))
                + theta.sin() * kx[i][j]
                + (1.0 - theta.cos()) * kx2[i][j];
        }
    }
    m
}

fn sub(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

fn add(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [a[0] + b[0], a[1] + b[1], a[2] + b[2]]
}

/// Posed vertices per SPEC §3 from rig.json + rest vertices.
fn reference_pose(rig: &serde_json::Value, rest: &[[f64; 3]], pose: &[f64]) -> Vec<[f64; 3]> {
    let joints = rig["joints"].as_array().unwrap();
    let c: Vec<[f64; 3]> = joints
        .iter()
        .map(|j| [0, 1, 2].map(|k| j["rest_position"][k].as_f64().unwrap()))
        .collect();
    let parent: Vec<Option<usize>> = joints
        .iter()
        .map(|j| j["parent"].as_u64().map(|p| p as usize))
        .collect();
    let t = [pose[0], pose[1], pose[2]];
    let mut w: Vec<M3> = Vec::new();
    // A_j(x) = anchor_j + W_j (x − c_j), anchor_root = c_root + t, anchor_j = A_parent(c_j).
    let mut anchor: Vec<[f64; 3]> = Vec::new();
    for j in 0..joints.len() {
        let r = rodrigues([pose[3 + 3 * j], pose[4 + 3 * j], pose[5 + 3 * j]]);
        match parent[j] {
            None => {
                w.push(r);
                anchor.push(add(c[j], t));
            }
            Some(p) => {
                let a = add(anchor[p], mat_vec(&w[p], sub(c[j], c[p])));
                w.push(mat_mul(&w[p], &r));
                anchor.push(a);
            }
        }
    }
    let weights = rig["weights"].as_array().unwrap();
    rest.iter()
        .zip(weights)
        .map(|(x, list)| {
            let mut out = [0.0; 3];
            for pair in list.as_array().unwrap() {
                let j = pair[0].as_u64().unwrap() as usize;
                let wt = pair[1].as_f64().unwrap();
                let a = add(anchor[j], mat_vec(&w[j], sub(*x, c[j])));
                out = add(out, a.map(|v| v * wt));
            }
            out
        })
        .collect()
}

#[test]
fn posed_template_matches_an_independent_implementation_of_spec_3() {
    let dir = tempfile::tempdir().unwrap();
    let tpl = dir.path().join("tpl");
    lfit_json(&["template", "export", "--out-dir", path_str(&tpl)]);
    let rig: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(tpl.join("rig.json")).unwrap()).unwrap();
    let rest = obj_vertices(&tpl.join("template.obj"));
    let (_, rest_faces) = load_obj(&tpl.join("template.obj"));
    let mut rng = ChaCha8Rng::seed_from_u64(2024);
    let poses: Vec<Vec<f64>> = (0..4)
        .map(|_| {
            (0..57)
                .map(|i| {
                    if i < 3 {
                        rng.random_range(-0.5..0.5)
                    } else {
                        rng.random_range(-0.8..0.8)
                    }
                })
                .collect()
        })
        .collect();
    let pose_file = dir.path().join("poses.json");
    std::fs::write(
        &pose_file,
        serde_json::to_string(&serde_json::json!({ "poses": poses })).unwrap(),
    )
    .unwrap();
    let out = dir.path().join("posed.obj");
    let summary = lfit_json(&[
        "template",
        "pose",
        "--pose",
        path_str(&pose_file),
        "--out",
        path_str(&out),
        "--template",
        path_str(&tpl),
    ]);
    assert_eq!(summary["written"].as_array().unwrap().len(), 4);
    for (i, pose) in poses.iter().enumerate() {
        let path = dir.path().join(format!("posed_{i:04}.obj"));
        let (_, faces) = load_obj(&path);
        assert_eq!(faces, rest_faces, "faces kept");
        let posed = obj_vertices(&path);
        let expected = reference_pose(&rig, &rest, pose);
        let max = posed
            .iter()
            .zip(&expected)
            .map(|(a, b)| {
                (0..3)
                    .map(|k| (a[k] - b[k]).abs())
                    .fold(0.0, support::nan_max)
            })
            .fold(0.0, support::nan_max);
        assert!(max < 1e-5, "pose {i}: max deviation {max} m");
    }
}

#[test]
fn root_only_pose_moves_the_mesh_rigidly() {
    let dir = tempfile::tempdir().unwrap();
    let tpl = dir.path().join("tpl");
    lfit_json(&["template", "export", "--out-dir", path_str(&tpl)]);
    let rest = obj_vertices(&tpl.join("template.obj"));
    let mut pose = vec![0.0; 57];
    pose[..6].copy_from_slice(&[0.3, -0.1, 0.7, 0.4, -1.1, 0.6]);
    let pose_file = dir.path().join("pose.json");
    std::fs::write(&pose_file, serde_json::json!({ "pose": pose }).to_string()).unwrap();
    let out = dir.path().join("posed.obj");
    lfit_json(&[
        "template",
        "pose",
        "--pose",
        path_str(&pose_file),
        "--out",
        path_str(&out),
        "--template",
        path_str(&tpl),
    ]);
    let posed = obj_vertices(&out);
    // Rigid: every pairwise distance is kept, and the map is R (x − c_root) + c_root + t.
    let rig: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(tpl.join("rig.json")).unwrap()).unwrap();
    let c = [0, 1, 2].map(|k| rig["joints"][0]["rest_position"][k].as_f64().unwrap());
    let r = rodrigues([0.4, -1.1, 0.6]);
    for (x, y) in rest.iter().zip(&posed) {
        let expect = add(add(mat_vec(&r, sub(*x, c)), c), [0.3, -0.1, 0.7]);
        assert!((0..3).all(|k| (expect[k] - y[k]).abs() < 1e-5));
    }
    for i in (0..rest.len()).step_by(97) {
        for j in (0..rest.len()).step_by(89) {
            let d0 = sub(rest[i], rest[j]);
            let d1 = sub(posed[i], posed[j]);
            let n = |d: [f64; 3]| (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
            assert!((n(d0) - n(d1)).abs() < 2e-5);
        }
    }
}

#[test]
fn reloaded_template_equals_the_generated_one_and_any_vertex_order_is_kept() {
    use lfit::model::template::Template;
    let dir = tempfile::tempdir().unwrap();
    let tpl = dir.path().join("tpl");
    lfit_json(&["template", "export", "--out-dir", path_str(&tpl)]);
    let generated = lfit::model::default_template();
    let loaded = Template::load(&tpl).unwrap();
    assert_eq!(loaded.vertices, generated.vertices);
    assert_eq!(loaded.faces, generated.faces);
    assert_eq!(loaded.rig, generated.rig);

    // Reverse the vertex order of the files (faces, weights and markers renumbered to match): the
    // posed mesh must be the same surface, in the reversed order.
    let n = generated.num_vertices();
    let rev = |i: usize| n - 1 - i;
    let mut obj = String::new();
    for v in generated.vertices.iter().rev() {
        obj.push_str(&format!("v {} {} {}\n", v.x, v.y, v.z));
    }
    for f in &generated.faces {
        obj.push_str(&format!(
            "f {} {} {}\n",
            rev(f[0] as usize) + 1,
            rev(f[1] as usize) + 1,
            rev(f[2] as usize) + 1
        ));
    }
    let mut rig = generated.rig.clone();
    rig.weights.reverse();
    for m in &mut rig.markers {
        m.vertex = rev(m.vertex as usize) as u32;
    }
    let other = dir.path().join("reversed");
    std::fs::create_dir_all(&other).unwrap();
    std::fs::write(other.join("template.obj"), obj).unwrap();
    std::fs::write(other.join("rig.json"), serde_json::to_string(&rig).unwrap()).unwrap();
    let mut rng = ChaCha8Rng::seed_from_u64(5);
    let pose: Vec<f64> = (0..57).map(|_| rng.random_range(-0.6..0.6)).collect();
    let pose_file = dir.path().join("p.json");
    std::fs::write(&pose_file, serde_json::json!({ "pose": pose }).to_string()).unwrap();
    let a = dir.path().join("a.obj");
    let b = dir.path().join("b.obj");
    lfit_json(&[
        "template",
        "pose",
        "--pose",
        path_str(&pose_file),
        "--out",
        path_str(&a),
        "--template",
        path_str(&tpl),
    ]);
    lfit_json(&[
        "template",
        "pose",
        "--pose",
        path_str(&pose_file),
        "--out",
        path_str(&b),
        "--template",
        path_str(&other),
    ]);
    let (a, mut b) = (obj_vertices(&a), obj_vertices(&b));
    b.reverse();
    assert_eq!(a, b);
}

/// `lfit model info`: the procedural template and the committed MakeHuman body as JSON — joint
/// names and parents, the parameter layout (whose names index `template pose` vectors), markers
/// and limits — checked against what is known of each independently; a missing file is refused
/// with one line.
#[test]
fn model_info_lists_joints_layout_markers_and_limits() {
    let root = env!("CARGO_MANIFEST_DIR");
    let d = lfit_json(&["model", "info"]);
    assert_eq!(d["id"], "default");
    let joints = d["joints"].as_array().unwrap();
    assert_eq!(joints.len(), 18);
    assert_eq!(joints[0]["parent"], serde_json::Value::Null);
    assert_eq!(d["parameters"]["dim"], 57);
    assert_eq!(d["parameters"]["names"].as_array().unwrap().len(), 57);
    assert_eq!(d["shape_components"], 0);

    let model = format!("{root}/models/makehuman-cmu_mb.npz");
    let d = lfit_json(&["model", "info", "--model", &model]);
    assert_eq!(d["id"], "makehuman-cmu_mb");
    assert_eq!(d["vertices"], 13380);
    let joints = d["joints"].as_array().unwrap();
    assert_eq!(joints.len(), 31);
    let by_name = |n: &str| joints.iter().find(|j| j["name"] == n).unwrap().clone();
    // The cmu_mb rig's chains (its joint names are the CMU database's).
    assert_eq!(by_name("LeftForeArm")["parent"], "LeftArm");
    assert_eq!(by_name("LeftArm")["mirror"], "RightArm");
    assert_eq!(by_name("Hips")["parent"], serde_json::Value::Null);
    // Limits: [lo, hi] in degrees per axis, lo < hi.
    for j in joints {
        for axis in j["limits_deg"].as_array().unwrap() {
            let (lo, hi) = (axis[0].as_f64().unwrap(), axis[1].as_f64().unwrap());
            assert!(lo < hi, "{}: {lo} .. {hi}", j["name"]);
        }
    }
    // 3 translation + 3 × 31 rotations + 16 shape, in that order.
    let p = &d["parameters"];
    assert_eq!(p["dim"], 112);
    let blocks: Vec<(String, u64, u64)> = p["blocks"]
        .as_array()
        .unwrap()
        .iter()
        .map(|b| {
            (
                b["block"].as_str().unwrap().to_string(),
                b["start"].as_u64().unwrap(),
                b["end"].as_u64().unwrap(),
            )
        })
        .collect();
    assert_eq!(
        blocks,
        vec![
            ("translation".to_string(), 0, 3),
            ("rotations".to_string(), 3, 96),
            ("shape".to_string(), 96, 112)
        ]
    );
    assert_eq!(p["names"].as_array().unwrap().len(), 112);
    // The markers the model file lists (the CMU/Vicon set), in its order.
    let markers: Vec<&str> = d["markers"]
        .as_array()
        .unwrap()
        .iter()
        .map(|m| m["name"].as_str().unwrap())
        .collect();
    assert_eq!(markers.len(), 39);
    assert_eq!(&markers[..4], &["LFHD", "RFHD", "LBHD", "RBHD"]);
    assert!(d["markers"][0]["vertex"].as_u64().unwrap() < 13380);

    let out = support::lfit(&["model", "info", "--model", "/nonexistent/model.npz"]);
    support::assert_one_line_error(&out, "model.npz");
}

/// An installed lfit (`scripts/install.sh PREFIX`: `PREFIX/bin/lfit` and
/// `PREFIX/share/lfit/{models,configs,checkpoints}`) finds the shipped data from any working
/// directory; so does a binary whose data folder `LFIT_DATA_DIR` names; without either, a
/// shipped path is a one-line error naming the places searched. No path of the build is
/// compiled in.
#[test]
fn shipped_paths_resolve_next_to_the_binary_or_through_lfit_data_dir() {
    let tmp = tempfile::tempdir().unwrap();
    let prefix = tmp.path().join("prefix");
    let bin = prefix.join("bin");
    std::fs::create_dir_all(&bin).unwrap();
    let exe = bin.join("lfit");
    // A hard link where the file system allows it (the binary is large), else a copy.
    if std::fs::hard_link(env!("CARGO_BIN_EXE_lfit"), &exe).is_err() {
        std::fs::copy(env!("CARGO_BIN_EXE_lfit"), &exe).unwrap();
    }
    let elsewhere = tmp.path().join("work");
    std::fs::create_dir_all(&elsewhere).unwrap();
    let repo = std::path::Path::new(env!("CARGO_MANIFEST_DIR"));
    let run = |data_dir: Option<&std::path::Path>| {
        let mut c = std::process::Command::new(&exe);
        c.args(["model", "info", "--model", "models/makehuman-face.npz"])
            .current_dir(&elsewhere)
            .env("RUST_BACKTRACE", "0")
            .env_remove("LFIT_DATA_DIR");
        if let Some(d) = data_dir {
            c.env("LFIT_DATA_DIR", d);
        }
        c.output().unwrap()
    };
    // Nowhere: one line naming the variable and the install folder.
    let out = run(None);
    support::assert_one_line_error(&out, "models/makehuman-face.npz not found");
    let line = String::from_utf8_lossy(&out.stderr).to_string();
    assert!(
        line.contains("LFIT_DATA_DIR") && line.contains("share/lfit"),
        "{line}"
    );
    // Through LFIT_DATA_DIR (here: the checkout).
    let out = run(Some(repo));
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let info: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(
        info["joints"].as_array().unwrap().len(),
        5,
        "the face model"
    );
    // Installed: PREFIX/share/lfit/models next to PREFIX/bin.
    let models = prefix.join("share/lfit/models");
    std::fs::create_dir_all(&models).unwrap();
    std::fs::copy(
        repo.join("models/makehuman-face.npz"),
        models.join("makehuman-face.npz"),
    )
    .unwrap();
    let out = run(None);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let installed: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(installed, info);
}
