//! Model files in the SMPL-family `.npz` layout (SPEC §3a): a random SMPL-layout model written
//! here (24 joints, B = 10, pose correctives, scipy-sparse J_regressor, Fortran-order f32
//! shapedirs, deflated members, vertices with up to 6 influences) posed by `lfit template pose`
//! against an independent f64 SMPL forward model written in this test; and every bad model file
//! as a one-line error with nothing written.

mod support;

use std::io::Write;
use std::path::{Path, PathBuf};

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use support::{
    assert_one_line_error, lfit, lfit_json, obj_vertices, path_str, skip_unless_required,
};

const J: usize = 24;
const V: usize = 240;
const B: usize = 10;
const PARENTS: [i64; J] = [
    -1, 0, 0, 0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 9, 9, 12, 13, 14, 16, 17, 18, 19, 20, 21,
];

/// One `.npy` member: v1.0 header, little-endian data.
fn npy(descr: &str, fortran: bool, shape: &[usize], data: &[u8]) -> Vec<u8> {
    let dims: Vec<String> = shape.iter().map(|d| d.to_string()).collect();
    let shape = match dims.len() {
        0 => "()".to_string(),
        1 => format!("({},)", dims[0]),
        _ => format!("({})", dims.join(", ")),
    };
    let mut header = format!(
        "{{'descr': '{descr}', 'fortran_order': {}, 'shape': {shape}, }}",
        if fortran { "True" } else { "False" }
    );
    while (10 + header.len() + 1) % 64 != 0 {
        header.push(' ');
    }
    header.push('\n');
    let mut out = b"\x93NUMPY\x01\x00".to_vec();
    out.extend((header.len() as u16).to_le_bytes());
    out.extend(header.as_bytes());
    out.extend(data);
    out
}

fn f64s(v: &[f64]) -> Vec<u8> {
    v.iter().flat_map(|x| x.to_le_bytes()).collect()
}

/// C-order values of shape `shape` laid out in Fortran order.
fn to_fortran(v: &[f64], shape: &[usize]) -> Vec<f64> {
    let n = v.len();
    let mut out = vec![0.0; n];
    for (c_off, &x) in v.iter().enumerate() {
        // multi-index of the C offset
        let mut rem = c_off;
        let mut idx = vec![0; shape.len()];
        for a in (0..shape.len()).rev() {
            idx[a] = rem % shape[a];
            rem /= shape[a];
        }
        let mut f_off = 0;
        let mut stride = 1;
        for (i, &d) in idx.iter().zip(shape) {
            f_off += i * stride;
            stride *= d;
        }
        out[f_off] = x;
    }
    out
}

/// A random SMPL-layout model, as arrays (C order, f64) and its members.
#[derive(Clone)]
struct Model {
    v_template: Vec<f64>,
    shapedirs: Vec<f64>,
    posedirs: Vec<f64>,
    j_regressor: Vec<f64>,
    weights: Vec<f64>,
    faces: Vec<u32>,
    kintree: Vec<u32>,
}

impl Model {
    fn random(seed: u64) -> Self {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let v_template: Vec<f64> = (0..3 * V).map(|_| rng.random_range(-0.9..0.9)).collect();
        let shapedirs: Vec<f64> = (0..3 * V * B)
            .map(|_| rng.random_range(-0.02..0.02))
            .collect();
        let posedirs: Vec<f64> = (0..3 * V * 9 * (J - 1))
            .map(|_| rng.random_range(-0.01..0.01))
            .collect();
        let mut j_regressor = vec![0.0; J * V];
        for j in 0..J {
            let mut total = 0.0;
            let picks: Vec<(usize, f64)> = (0..5)
                .map(|_| (rng.random_range(0..V), rng.random_range(0.1..1.0)))
                .collect();
            for &(_, w) in &picks {
                total += w;
            }
            for (v, w) in picks {
                j_regressor[j * V + v] += w / total;
            }
        }
        let mut weights = vec![0.0; V * J];
        for v in 0..V {
            let n = 1 + v % 6;
            let mut raw = vec![0.0; J];
            for _ in 0..n {
                raw[rng.random_range(0..J)] += rng.random_range(0.05..1.0);
            }
            let total: f64 = raw.iter().sum();
            for j in 0..J {
                weights[v * J + j] = raw[j] / total;
            }
        }
        let mut faces = Vec::new();
        for k in 0..V / 2 {
            let a = (2 * k) as u32;
            faces.extend([a, (a + 1) % V as u32, (a + 2) % V as u32]);
        }
        let mut kintree = vec![0u32; 2 * J];
        for j in 0..J {
            kintree[j] = if PARENTS[j] < 0 {
                u32::MAX
            } else {
                PARENTS[j] as u32
            };
            kintree[J + j] = j as u32;
        }
        Self {
            v_template,
            shapedirs,
            posedirs,
            j_regressor,
            weights,
            faces,
            kintree,
        }
    }

    /// The npz members: SMPL keys, `J_regressor` as scipy-sparse CSR keys, `shapedirs` as
    /// Fortran-order f32 (as many converted SMPL files hold it) rounded here first so the
    /// reference uses the same values.
    fn members(&self) -> Vec<(String, Vec<u8>)> {
        let mut m = Vec::new();
        m.push((
            "v_template".into(),
            npy("<f8", false, &[V, 3], &f64s(&self.v_template)),
        ));
        let sd_f = to_fortran(&self.shapedirs, &[V, 3, B]);
        let sd_bytes: Vec<u8> = sd_f
            .iter()
            .flat_map(|&x| (x as f32).to_le_bytes())
            .collect();
        m.push(("shapedirs".into(), npy("<f4", true, &[V, 3, B], &sd_bytes)));
        m.push((
            "posedirs".into(),
            npy("<f8", false, &[V, 3, 9 * (J - 1)], &f64s(&self.posedirs)),
        ));
        m.push((
            "weights".into(),
            npy("<f8", false, &[V, J], &f64s(&self.weights)),
        ));
        m.push((
            "f".into(),
            npy(
                "<u4",
                false,
                &[self.faces.len() / 3, 3],
                &self
                    .faces
                    .iter()
                    .flat_map(|x| x.to_le_bytes())
                    .collect::<Vec<_>>(),
            ),
        ));
        m.push((
            "kintree_table".into(),
            npy(
                "<u4",
                false,
                &[2, J],
                &self
                    .kintree
                    .iter()
                    .flat_map(|x| x.to_le_bytes())
                    .collect::<Vec<_>>(),
            ),
        ));
        // CSR of J_regressor.
        let (mut data, mut indices, mut indptr) = (Vec::new(), Vec::new(), vec![0i32]);
        for j in 0..J {
            for v in 0..V {
                let w = self.j_regressor[j * V + v];
                if w != 0.0 {
                    data.push(w);
                    indices.push(v as i32);
                }
            }
            indptr.push(indices.len() as i32);
        }
        let fmt: Vec<u8> = "csr"
            .chars()
            .flat_map(|c| (c as u32).to_le_bytes())
            .collect();
        m.push(("J_regressor.format".into(), npy("<U3", false, &[], &fmt)));
        m.push((
            "J_regressor.shape".into(),
            npy(
                "<i8",
                false,
                &[2],
                &[J as i64, V as i64]
                    .iter()
                    .flat_map(|x| x.to_le_bytes())
                    .collect::<Vec<_>>(),
            ),
        ));
        m.push((
            "J_regressor.data".into(),
            npy("<f8", false, &[data.len()], &f64s(&data)),
        ));
        m.push((
            "J_regressor.indices".into(),
            npy(
                "<i4",
                false,
                &[indices.len()],
                &indices
                    .iter()
                    .flat_map(|x| x.to_le_bytes())
                    .collect::<Vec<_>>(),
            ),
        ));
        m.push((
            "J_regressor.indptr".into(),
            npy(
                "<i4",
                false,
                &[indptr.len()],
                &indptr
                    .iter()
                    .flat_map(|x| x.to_le_bytes())
                    .collect::<Vec<_>>(),
            ),
        ));
        m
    }

    /// The shapedirs the file holds (rounded to f32).
    fn shapedirs_as_stored(&self) -> Vec<f64> {
        self.shapedirs
            .iter()
            .map(|&x| f64::from(x as f32))
            .collect()
    }
}

fn write_npz(path: &Path, members: &[(String, Vec<u8>)]) {
    let mut zip = zip::ZipWriter::new(std::io::Cursor::new(Vec::new()));
    for (i, (name, bytes)) in members.iter().enumerate() {
        // Alternate stored and deflated members, as np.savez and np.savez_compressed write them.
        let method = if i % 2 == 0 {
            zip::CompressionMethod::Stored
        } else {
            zip::CompressionMethod::Deflated
        };
        let options = zip::write::SimpleFileOptions::default().compression_method(method);
        zip.start_file(format!("{name}.npy"), options).unwrap();
        zip.write_all(bytes).unwrap();
    }
    std::fs::write(path, zip.finish().unwrap().into_inner()).unwrap();
}

type M3 = [[f64; 3]; 3];

fn rodrigues(r: [f64; 3]) -> M3 {
    let theta = (r[0] * r[0] + r[1] * r[1] + r[2] * r[2]).sqrt();
    if theta < 1e-12 {
        return [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
    }
    let k = [r[0] / theta, r[1] / theta, r[2] / theta];
    let kx = [[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]];
    let (s, c) = theta.sin_cos();
    let mut out = [[0.0; 3]; 3];
    for i in 0..3 {
        for j in 0..3 {
            let kk: f64 = (0..3).map(|m| kx[i][m] * kx[m][j]).sum();
            out[i][j] = f64::from(u8::from(i == j)) + s * kx[i][j] + (1.0 - c) * kk;
        }
    }
    out
}

fn matmul(a: &M3, b: &M3) -> M3 {
    let mut o = [[0.0; 3]; 3];
    for i in 0..3 {
        for j in 0..3 {
            o[i][j] = (0..3).map(|k| a[i][k] * b[k][j]).sum();
        }
    }
    o
}

fn apply(a: &M3, x: [f64; 3]) -> [f64; 3] {
    [0, 1, 2].map(|i| a[i][0] * x[0] + a[i][1] * x[1] + a[i][2] * x[2])
}

/// SMPL's forward model, written out independently of lfit: shaped template, regressed joints,
/// pose correctives, world transforms along the kinematic tree, linear blend skinning, root
/// translation.
fn reference(model: &Model, pose: &[f64], beta: &[f64]) -> Vec<[f64; 3]> {
    let sd = model.shapedirs_as_stored();
    let mut t = model.v_template.clone();
    for r in 0..3 * V {
        for (k, b) in beta.iter().enumerate() {
            t[r] += sd[r * B + k] * b;
        }
    }
    let mut joints = vec![[0.0; 3]; J];
    for j in 0..J {
        for v in 0..V {
            let w = model.j_regressor[j * V + v];
            for a in 0..3 {
                joints[j][a] += w * t[3 * v + a];
            }
        }
    }
    let rots: Vec<M3> = (0..J)
        .map(|j| rodrigues([pose[3 + 3 * j], pose[4 + 3 * j], pose[5 + 3 * j]]))
        .collect();
    let mut feature = Vec::new();
    for r in rots.iter().skip(1) {
        for (i, row) in r.iter().enumerate() {
            for (k, x) in row.iter().enumerate() {
                feature.push(x - f64::from(u8::from(i == k)));
            }
        }
    }
    let np = 9 * (J - 1);
    for r in 0..3 * V {
        t[r] += (0..np)
            .map(|k| model.posedirs[r * np + k] * feature[k])
            .sum::<f64>();
    }
    // G_j = G_parent [R_j | J_j − J_parent]; root [R_0 | J_0].
    let mut g_rot: Vec<M3> = Vec::new();
    let mut g_t: Vec<[f64; 3]> = Vec::new();
    for j in 0..J {
        if PARENTS[j] < 0 {
            g_rot.push(rots[0]);
            g_t.push(joints[0]);
        } else {
            let p = PARENTS[j] as usize;
            let rel = [0, 1, 2].map(|a| joints[j][a] - joints[p][a]);
            let o = apply(&g_rot[p], rel);
            g_rot.push(matmul(&g_rot[p], &rots[j]));
            g_t.push([0, 1, 2].map(|a| g_t[p][a] + o[a]));
        }
    }
    (0..V)
        .map(|v| {
            let mut out = [pose[0], pose[1], pose[2]];
            for j in 0..J {
                let w = model.weights[v * J + j];
                if w == 0.0 {
                    continue;
                }
                let local = [0, 1, 2].map(|a| t[3 * v + a] - joints[j][a]);
                let p = apply(&g_rot[j], local);
                for a in 0..3 {
                    out[a] += w * (p[a] + g_t[j][a]);
                }
            }
            out
        })
        .collect()
}

fn setup(dir: &Path) -> (Model, PathBuf) {
    let model = Model::random(7);
    let path = dir.join("smpl_like.npz");
    write_npz(&path, &model.members());
    (model, path)
}

#[test]
fn smpl_layout_parity_with_an_independent_f64_forward_model() {
    let dir = tempfile::tempdir().unwrap();
    let (model, path) = setup(dir.path());
    let mut rng = ChaCha8Rng::seed_from_u64(11);
    let mut poses = Vec::new();
    let mut shapes = Vec::new();
    for _ in 0..6 {
        let mut pose: Vec<f64> = (0..3 + 3 * J)
            .map(|_| rng.random_range(-1.0..1.0))
            .collect();
        pose[1] += 0.3;
        poses.push(pose);
        shapes.push(
            (0..B)
                .map(|_| rng.random_range(-3.0..3.0))
                .collect::<Vec<f64>>(),
        );
    }
    let pose_file = dir.path().join("p.json");
    std::fs::write(
        &pose_file,
        serde_json::json!({ "poses": poses, "shapes": shapes }).to_string(),
    )
    .unwrap();
    let out = dir.path().join("o.obj");
    let summary = lfit_json(&[
        "template",
        "pose",
        "--template",
        path_str(&path),
        "--pose",
        path_str(&pose_file),
        "--out",
        path_str(&out),
    ]);
    assert_eq!(summary["poses"], 6);
    let mut worst = 0.0f64;
    for (i, (pose, beta)) in poses.iter().zip(&shapes).enumerate() {
        let got = obj_vertices(&dir.path().join(format!("o_{i:04}.obj")));
        let want = reference(&model, pose, beta);
        assert_eq!(got.len(), V);
        for (g, w) in got.iter().zip(&want) {
            let d = ((g[0] - w[0]).powi(2) + (g[1] - w[1]).powi(2) + (g[2] - w[2]).powi(2)).sqrt();
            worst = worst.max(d);
        }
    }
    println!(
        "SMPL-layout parity: worst vertex distance {worst:.3e} m over 6 poses (θ within ±1 rad, β within ±3)"
    );
    assert!(worst <= 1e-6, "worst vertex distance {worst} m");
    // The pose correctives and the shape matter: without them the reference moves by centimetres.
    let zero_beta = reference(&model, &poses[0], &[0.0; B]);
    let with_beta = reference(&model, &poses[0], &shapes[0]);
    let moved = zero_beta
        .iter()
        .zip(&with_beta)
        .map(|(a, b)| {
            (a[0] - b[0])
                .abs()
                .max((a[1] - b[1]).abs())
                .max((a[2] - b[2]).abs())
        })
        .fold(0.0, support::nan_max);
    assert!(moved > 0.01, "{moved}");
}

#[test]
fn the_default_template_exports_as_a_model_file_that_poses_identically() {
    let dir = tempfile::tempdir().unwrap();
    let npz = dir.path().join("default.npz");
    lfit_json(&[
        "template",
        "export",
        "--format",
        "npz",
        "--out",
        path_str(&npz),
    ]);
    let pose_file = dir.path().join("p.json");
    let pose: Vec<f64> = (0..57)
        .map(|i| ((i * 37 % 19) as f64 / 19.0 - 0.5) * 1.2)
        .collect();
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
    ]);
    lfit_json(&[
        "template",
        "pose",
        "--template",
        path_str(&npz),
        "--pose",
        path_str(&pose_file),
        "--out",
        path_str(&b),
    ]);
    let (va, vb) = (obj_vertices(&a), obj_vertices(&b));
    assert_eq!(va.len(), vb.len());
    let worst = va
        .iter()
        .zip(&vb)
        .map(|(x, y)| {
            (0..3)
                .map(|k| (x[k] - y[k]).abs())
                .fold(0.0, support::nan_max)
        })
        .fold(0.0, support::nan_max);
    assert!(worst < 1e-5, "{worst}");
    // A format without its output flag is refused.
    let o = lfit(&[
        "template",
        "export",
        "--format",
        "npz",
        "--out-dir",
        path_str(dir.path()),
    ]);
    assert_one_line_error(&o, "--out");
}

/// Runs `template pose` on a model file made from `members`, with `params` as the pose file;
/// asserts a one-line error mentioning `needle` and that no OBJ was written.
fn refused(dir: &Path, members: &[(String, Vec<u8>)], params: serde_json::Value, needle: &str) {
    let path = dir.join("bad.npz");
    write_npz(&path, members);
    refused_file(dir, &path, params, needle);
}

fn refused_file(dir: &Path, path: &Path, params: serde_json::Value, needle: &str) {
    let pose_file = dir.join("p.json");
    std::fs::write(&pose_file, params.to_string()).unwrap();
    let out = dir.join("never.obj");
    let o = lfit(&[
        "template",
        "pose",
        "--template",
        path_str(path),
        "--pose",
        path_str(&pose_file),
        "--out",
        path_str(&out),
    ]);
    assert_one_line_error(&o, needle);
    assert!(!out.exists(), "{needle}: an output was written");
}

fn replace(members: &[(String, Vec<u8>)], key: &str, bytes: Vec<u8>) -> Vec<(String, Vec<u8>)> {
    members
        .iter()
        .map(|(n, b)| (n.clone(), if n == key { bytes.clone() } else { b.clone() }))
        .collect()
}

#[test]
fn bad_model_files_are_one_line_errors_and_write_nothing() {
    let dir = tempfile::tempdir().unwrap();
    let (model, _) = setup(dir.path());
    let good = model.members();
    let pose = serde_json::json!({ "pose": vec![0.0; 3 + 3 * J] });
    // A missing key.
    let no_weights: Vec<_> = good
        .iter()
        .filter(|(n, _)| n != "weights")
        .cloned()
        .collect();
    refused(
        dir.path(),
        &no_weights,
        pose.clone(),
        "missing key 'weights'",
    );
    // A wrong array shape.
    refused(
        dir.path(),
        &replace(
            &good,
            "v_template",
            npy("<f8", false, &[V, 2], &f64s(&vec![0.0; 2 * V])),
        ),
        pose.clone(),
        "'v_template' has shape",
    );
    // Weights rows that do not sum to 1.
    let mut w = model.weights.clone();
    w[5 * J] += 0.5;
    refused(
        dir.path(),
        &replace(&good, "weights", npy("<f8", false, &[V, J], &f64s(&w))),
        pose.clone(),
        "sum",
    );
    // A J_regressor of the wrong size (dense, 23 rows).
    let dense_bad: Vec<_> = good
        .iter()
        .filter(|(n, _)| !n.starts_with("J_regressor"))
        .cloned()
        .chain([(
            "J_regressor".to_string(),
            npy("<f8", false, &[J - 1, V], &f64s(&vec![0.0; (J - 1) * V])),
        )])
        .collect();
    refused(dir.path(), &dense_bad, pose.clone(), "J_regressor");
    // SMPL's root parent 2³² − 1 in an int64 kintree_table (numpy widens SMPL's so) reads as
    // the unsigned file does: the same model.
    let wide: Vec<u8> = model
        .kintree
        .iter()
        .flat_map(|&x| i64::from(x).to_le_bytes())
        .collect();
    let (as_u4, as_i8) = (dir.path().join("u4.npz"), dir.path().join("i8.npz"));
    write_npz(&as_u4, &good);
    write_npz(
        &as_i8,
        &replace(&good, "kintree_table", npy("<i8", false, &[2, J], &wide)),
    );
    let info = |p: &Path| lfit_json(&["model", "info", "--model", path_str(p)]);
    let (a, b) = (info(&as_u4), info(&as_i8));
    assert_eq!(a["joints"], b["joints"]);
    assert!(a["joints"].as_array().is_some_and(|j| j.len() == J), "{a}");
    // A kintree cycle: joint 1's parent is joint 4, whose parent is joint 1.
    let mut k = model.kintree.clone();
    k[1] = 4;
    refused(
        dir.path(),
        &replace(
            &good,
            "kintree_table",
            npy(
                "<u4",
                false,
                &[2, J],
                &k.iter().flat_map(|x| x.to_le_bytes()).collect::<Vec<_>>(),
            ),
        ),
        pose.clone(),
        "cycle",
    );
    // NaN in an array.
    let mut vt = model.v_template.clone();
    vt[17] = f64::NAN;
    refused(
        dir.path(),
        &replace(&good, "v_template", npy("<f8", false, &[V, 3], &f64s(&vt))),
        pose.clone(),
        "not finite",
    );
    let mut pd = model.posedirs.clone();
    pd[1000] = f64::NAN;
    refused(
        dir.path(),
        &replace(
            &good,
            "posedirs",
            npy("<f8", false, &[V, 3, 9 * (J - 1)], &f64s(&pd)),
        ),
        pose.clone(),
        "'posedirs' value 1000 is not finite",
    );
    // A shape vector longer than B.
    let path = dir.path().join("good.npz");
    write_npz(&path, &good);
    refused_file(
        dir.path(),
        &path,
        serde_json::json!({ "pose": vec![0.0; 3 + 3 * J], "shape": vec![0.1; B + 1] }),
        "only 10",
    );
    // A pose of the wrong length for this skeleton.
    refused_file(
        dir.path(),
        &path,
        serde_json::json!({ "pose": vec![0.0; 57] }),
        "expected 75",
    );
    // A pickled file.
    let pkl = dir.path().join("model.pkl");
    std::fs::write(&pkl, b"\x80\x02}q\x00.").unwrap();
    refused_file(
        dir.path(),
        &pkl,
        pose.clone(),
        "python -m lfit.convert_pkl MODEL.pkl",
    );
    // Sensors the model cannot serve: markers on a model without any, hmd on a model whose joint
    // names map nothing to the papers/000 head and hands.
    let d = dir.path().join("d.npz");
    let o = lfit(&[
        "synth",
        "--modality",
        "markers",
        "--source",
        "uniform",
        "--frames",
        "2",
        "--template",
        path_str(&path),
        "--out",
        path_str(&d),
    ]);
    assert_one_line_error(&o, "has no markers");
    let names: Vec<String> = (0..J).map(|j| format!("bone{j:02}")).collect();
    let bytes: Vec<u8> = names
        .iter()
        .flat_map(|n| n.chars().map(|c| c as u32).flat_map(u32::to_le_bytes))
        .collect();
    let renamed: Vec<_> = good
        .iter()
        .cloned()
        .chain([("joint_names".to_string(), npy("<U6", false, &[J], &bytes))])
        .collect();
    let unmapped = dir.path().join("unmapped.npz");
    write_npz(&unmapped, &renamed);
    let o = lfit(&[
        "synth",
        "--modality",
        "hmd",
        "--source",
        "uniform",
        "--frames",
        "2",
        "--template",
        path_str(&unmapped),
        "--out",
        path_str(&d),
    ]);
    assert_one_line_error(&o, "maps no joint to the papers/000 'head'");
    assert!(!d.exists());
    // Not a zip at all.
    let junk = dir.path().join("junk.npz");
    std::fs::write(&junk, b"not a zip").unwrap();
    refused_file(dir.path(), &junk, pose.clone(), "not an .npz");
    // Synthesis runs on the model; a checkpoint trained on the default template is refused on it.
    let d = dir.path().join("d.npz");
    lfit_json(&[
        "synth",
        "--modality",
        "keypoints2d",
        "--source",
        "uniform",
        "--frames",
        "2",
        "--template",
        path_str(&path),
        "--out",
        path_str(&d),
    ]);
    let ckpt = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("checkpoints/keypoints2d");
    let o = lfit(&[
        "fit",
        "--data",
        path_str(&d),
        "--template",
        path_str(&path),
        "--method",
        "neural",
        "--checkpoint",
        path_str(&ckpt),
        "--budget",
        "10",
        "--out",
        path_str(&dir.path().join("never.json")),
    ]);
    assert_one_line_error(&o, "checkpoint");
    assert!(!dir.path().join("never.json").exists());
}

#[test]
fn a_24_joint_model_runs_end_to_end_synth_fit_train_neural_export() {
    let dir = tempfile::tempdir().unwrap();
    let (_, model) = setup(dir.path());
    let m = path_str(&model);
    let data = dir.path().join("d.npz");
    lfit_json(&[
        "synth",
        "--modality",
        "keypoints2d",
        "--source",
        "uniform",
        "--frames",
        "6",
        "--seed",
        "3",
        "--template",
        m,
        "--out",
        path_str(&data),
    ]);
    // Every classical method on the same energy.
    let d = path_str(&data);
    for method in lfit::fitters::METHOD_NAMES {
        let out = dir.path().join(format!("{method}.json"));
        let s = lfit_json(&[
            "fit",
            "--data",
            d,
            "--template",
            m,
            "--method",
            method,
            "--budget",
            "40",
            "--frames",
            "0..2",
            "--out",
            path_str(&out),
        ]);
        let r: serde_json::Value = serde_json::from_slice(&std::fs::read(&out).unwrap()).unwrap();
        assert_eq!(
            r["frames"][0]["pose"].as_array().unwrap().len(),
            3 + 3 * J,
            "{method}"
        );
        assert_eq!(
            r["frames"][0]["shape"].as_array().unwrap().len(),
            B,
            "{method}"
        );
        assert!(
            s["summary"]["mean_energy"].as_f64().unwrap().is_finite(),
            "{method}"
        );
    }
    // A short training run on this model, then the neural fitter with its checkpoint.
    let config = dir.path().join("train.json");
    std::fs::write(&config, serde_json::json!({
        "modality": "keypoints2d",
        "network": {"hidden": 32, "layers": 1, "init_width": 32, "iterations": 3, "start": "mixed", "dropout": 0.0},
        "steps": 60, "batch": 8, "val_frames": 8, "val_every": 30, "checkpoint_every": 30, "stats_frames": 32, "seed": 1
    }).to_string()).unwrap();
    let ckpt = dir.path().join("ckpt");
    lfit_json(&[
        "--quiet",
        "train",
        "--config",
        path_str(&config),
        "--template",
        m,
        "--device",
        "ndarray",
        "--out",
        path_str(&ckpt),
    ]);
    let meta: serde_json::Value =
        serde_json::from_slice(&std::fs::read(ckpt.join("config.json")).unwrap()).unwrap();
    assert_eq!(meta["network"]["param_dim"], 3 + 3 * J + B);
    assert_eq!(meta["model"]["layout"]["shape"], B);
    let results = dir.path().join("neural.json");
    lfit_json(&[
        "fit",
        "--data",
        d,
        "--template",
        m,
        "--method",
        "neural",
        "--checkpoint",
        path_str(&ckpt),
        "--device",
        "ndarray",
        "--budget",
        "6",
        "--out",
        path_str(&results),
    ]);
    // The same checkpoint through ONNX: exported graphs of 85 parameters, run in ONNX Runtime,
    // give the Burn fit (when the library is at hand; required in CI).
    let onnx = dir.path().join("onnx");
    lfit_json(&[
        "export-onnx",
        "--checkpoint",
        path_str(&ckpt),
        "--out",
        path_str(&onnx),
    ]);
    if lfit::infer::onnx::runtime::library_path().is_file() {
        let ort_results = dir.path().join("ort.json");
        lfit_json(&[
            "fit",
            "--data",
            d,
            "--template",
            m,
            "--method",
            "neural",
            "--runtime",
            "ort",
            "--checkpoint",
            path_str(&onnx),
            "--budget",
            "6",
            "--out",
            path_str(&ort_results),
        ]);
        let a: serde_json::Value =
            serde_json::from_slice(&std::fs::read(&results).unwrap()).unwrap();
        let b: serde_json::Value =
            serde_json::from_slice(&std::fs::read(&ort_results).unwrap()).unwrap();
        let mut worst = 0.0f64;
        for (fa, fb) in a["frames"]
            .as_array()
            .unwrap()
            .iter()
            .zip(b["frames"].as_array().unwrap())
        {
            for key in ["pose", "shape"] {
                for (x, y) in fa[key]
                    .as_array()
                    .unwrap()
                    .iter()
                    .zip(fb[key].as_array().unwrap())
                {
                    worst = worst.max((x.as_f64().unwrap() - y.as_f64().unwrap()).abs());
                }
            }
        }
        println!("24-joint model, Burn vs ONNX Runtime: worst parameter difference {worst:.2e}");
        assert!(worst < 1e-3, "{worst}");
    } else {
        skip_unless_required(
            "ONNX Runtime library not found (run scripts/fetch-onnxruntime.sh or set ORT_DYLIB_PATH)",
            Some("LFIT_REQUIRE_ORT"),
        );
    }
    // The checkpoint refuses another model with one line (here the default template's data).
    let other = dir.path().join("default.npz");
    lfit_json(&[
        "synth",
        "--modality",
        "keypoints2d",
        "--frames",
        "2",
        "--out",
        path_str(&other),
    ]);
    let o = lfit(&[
        "fit",
        "--data",
        path_str(&other),
        "--method",
        "neural",
        "--checkpoint",
        path_str(&ckpt),
        "--device",
        "ndarray",
        "--budget",
        "6",
        "--out",
        path_str(&dir.path().join("never.json")),
    ]);
    assert_one_line_error(&o, "was trained on model 'smpl_like'");
    // glTF of the fitted motion on the 24-joint skeleton and the subject's shape.
    let gltf = dir.path().join("gltf");
    lfit_json(&[
        "export",
        "--data",
        d,
        "--template",
        m,
        "--poses",
        path_str(&results),
        "--format",
        "gltf",
        "--out",
        path_str(&gltf),
    ]);
    match support::gltf_validator() {
        Ok(prefix) => {
            let (report, stdout) = support::validate_glb(&prefix, &gltf.join("neural.glb"));
            let issues = &report["issues"];
            println!(
                "24-joint model glTF: gltf-validator {}: {} errors, {} warnings",
                report["validatorVersion"], issues["numErrors"], issues["numWarnings"]
            );
            assert_eq!(issues["numErrors"], 0, "{stdout}");
            assert_eq!(report["info"]["hasSkins"], true);
        }
        Err(reason) => skip_unless_required(
            &format!("the glTF validator is unavailable: {reason}"),
            None,
        ),
    }
}
