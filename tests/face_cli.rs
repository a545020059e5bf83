//! The face of issue 16 through the CLI, on the committed models/makehuman-face.npz: `lfit synth
//! --modality landmarks2d --source face` (deterministic, the papers/002 camera, pixel noise), a
//! Levenberg–Marquardt fit with the face energy (configs/face-energy.json) that lowers the
//! energy and reports papers/002 Table 7's errors, and the bad inputs of the issue as one-line
//! errors: a landmark set naming vertices outside the model, identity/expression vectors longer
//! than the model's, a body model without landmarks, a face-protocol sequence, the shipped face
//! fitter run on another energy than its own.

mod support;

use std::path::{Path, PathBuf};

use support::{assert_one_line_error, lfit, lfit_json, path_str};

fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

fn face_model() -> PathBuf {
    root().join("models/makehuman-face.npz")
}

fn synth(out: &Path, seed: &str, noise: &str) -> serde_json::Value {
    lfit_json(&[
        "synth",
        "-q",
        "--modality",
        "landmarks2d",
        "--source",
        "face",
        "--scenario",
        "global",
        "--frames",
        "12",
        "--seed",
        seed,
        "--noise",
        noise,
        "--template",
        path_str(&face_model()),
        "--out",
        path_str(out),
    ])
}

#[test]
fn face_data_is_deterministic_and_lm_fits_it() {
    let dir = tempfile::tempdir().unwrap();
    let (a, b) = (dir.path().join("a.npz"), dir.path().join("b.npz"));
    let info = synth(&a, "5", "1");
    synth(&b, "5", "1");
    assert_eq!(std::fs::read(&a).unwrap(), std::fs::read(&b).unwrap());
    assert_eq!(info["template"], "makehuman-face");
    // A head turned within half its limits shows about two thirds of its landmarks.
    let seen = info["visible_fraction"].as_f64().unwrap();
    assert!((0.4..0.95).contains(&seen), "{seen}");
    let data = lfit::synth::Dataset::load(&a).unwrap();
    let lfit::model::observe::Sensor::Landmarks2d(setup) = &data.sensor else {
        panic!("not a landmarks2d dataset")
    };
    assert_eq!(setup.vertices.len(), 669);
    assert_eq!(
        (setup.camera.fx, setup.camera.cx, setup.camera.width),
        (512.0, 256.0, 512)
    );
    // Targets vary pose, identity and expression; starts are the rest.
    let gt = &data.gt_poses;
    assert_eq!(gt[0].len(), 114);
    assert!(gt.iter().all(|g| g[18..].iter().any(|&x| x != 0.0)));
    assert!(data.start_poses.iter().all(|s| s.iter().all(|&x| x == 0.0)));
    // Without noise the observation at the truth is the projection: LM from the rest pose
    // lowers the energy and the errors come with the face columns.
    let clean = dir.path().join("clean.npz");
    synth(&clean, "6", "0");
    let fit = dir.path().join("lm.json");
    let out = lfit_json(&[
        "fit",
        "-q",
        "--data",
        path_str(&clean),
        "--template",
        path_str(&face_model()),
        "--energy",
        path_str(&root().join("configs/face-energy.json")),
        "--method",
        "lm",
        "--budget",
        "100",
        "--out",
        path_str(&fit),
    ]);
    let result: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&fit).unwrap()).unwrap();
    let frames = result["frames"].as_array().unwrap();
    assert_eq!(frames.len(), 12);
    // papers/002 Table 7's errors, mean over the frames: at most LM's in docs/results/face.md
    // (1,000 noisy frames, LM @4000: 23.6, 26.1, 23.6, 3.3, 8.1, 3.0 mm); these frames are
    // noise-free, so LM fits them at least as well (measured 2026-12-02: 10.7, 12.5, 10.3, 2.5,
    // 5.7, 2.0 mm).
    for (k, table7) in [
        ("v2v_face_mm", 23.6),
        ("v2v_head_mm", 26.1),
        ("ldmk_mm", 23.6),
        ("pa_v2v_face_mm", 3.3),
        ("pa_v2v_head_mm", 8.1),
        ("pa_ldmk_mm", 3.0),
    ] {
        let mean = frames
            .iter()
            .map(|f| f["face"][k].as_f64().unwrap())
            .sum::<f64>()
            / frames.len() as f64;
        assert!(
            mean <= table7,
            "{k}: mean {mean:.2} mm > LM's {table7} mm in Table 7"
        );
    }
    for f in frames {
        let (e, e0) = (
            f["energy"].as_f64().unwrap(),
            f["start_energy"].as_f64().unwrap(),
        );
        assert!(e < 0.05 * e0, "frame {}: {e} from {e0}", f["frame"]);
        let face = &f["face"];
        for k in [
            "v2v_face_mm",
            "v2v_head_mm",
            "ldmk_mm",
            "pa_v2v_face_mm",
            "pa_v2v_head_mm",
            "pa_ldmk_mm",
        ] {
            assert!(face[k].as_f64().unwrap().is_finite(), "{k}");
        }
        // Alignment can only help.
        assert!(face["pa_ldmk_mm"].as_f64().unwrap() <= face["ldmk_mm"].as_f64().unwrap() + 1e-9);
    }
    assert!(
        out["summary"]["mean_v2v_mm"].as_f64().unwrap() < 60.0,
        "{out}"
    );
}

#[test]
fn bad_face_inputs_are_one_line_errors() {
    let dir = tempfile::tempdir().unwrap();
    // A landmark set naming a vertex outside the model.
    let mut t = lfit::model::modelfile::load(&face_model()).unwrap();
    let v = t.num_vertices() as u32;
    t.info.landmark_vertices[7] = v + 3;
    let bad = dir.path().join("bad.npz");
    lfit::model::modelfile::save(&t, &bad).unwrap();
    let out = dir.path().join("x.npz");
    let run_synth = |model: &Path, extra: &[&str]| {
        let mut args = vec![
            "synth",
            "-q",
            "--modality",
            "landmarks2d",
            "--source",
            "face",
            "--frames",
            "3",
            "--template",
            path_str(model),
            "--out",
            path_str(&out),
        ];
        args.extend_from_slice(extra);
        lfit(&args)
    };
    let global: &[&str] = &["--scenario", "global"];
    assert_one_line_error(&run_synth(&bad, global), &format!("vertex {}", v + 3));
    // A body model has no landmarks.
    assert_one_line_error(
        &run_synth(&root().join("models/makehuman-cmu_mb.npz"), global),
        "no landmarks",
    );
    // The face protocol draws independent samples, not sequences.
    let out_seq = run_synth(&face_model(), &["--scenario", "sequence"]);
    assert_one_line_error(&out_seq, "sequences need smooth motion");
    assert!(!out.exists(), "nothing may be written");
    // The shipped face fitter with another energy than the one it was trained on.
    let data = dir.path().join("face.npz");
    synth(&data, "3", "1");
    let fit = dir.path().join("fit.json");
    assert_one_line_error(
        &lfit(&[
            "fit",
            "-q",
            "--data",
            path_str(&data),
            "--template",
            path_str(&face_model()),
            "--method",
            "neural",
            "--checkpoint",
            path_str(&root().join("checkpoints/face")),
            "--budget",
            "10",
            "--out",
            path_str(&fit),
        ]),
        "another energy",
    );
    assert!(!fit.exists());
    // Identity and expression vectors longer than the model's.
    let pose = dir.path().join("pose.json");
    let obj = dir.path().join("p.obj");
    for (key, n, needle) in [("shape", 65, "only 64"), ("expression", 33, "only 32")] {
        let v = serde_json::json!({ "pose": vec![0.0; 18], key: vec![0.1; n] });
        std::fs::write(&pose, v.to_string()).unwrap();
        assert_one_line_error(
            &lfit(&[
                "template",
                "pose",
                "--template",
                path_str(&face_model()),
                "--pose",
                path_str(&pose),
                "--out",
                path_str(&obj),
            ]),
            needle,
        );
    }
    assert!(!obj.exists());
}
