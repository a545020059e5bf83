//! Camera-agnostic keypoints2d networks end to end: `lfit synth --cameras N` and `--camera
//! FILE`, a tiny training run of a pooled network (random rigs), fits of 1- and 3-camera datasets
//! with its checkpoint, and the shipped fixed-rig checkpoint's one-line refusal of the same
//! datasets.

mod support;

use std::path::{Path, PathBuf};

use support::{assert_one_line_error, lfit, lfit_json, path_str};

fn tiny_pooled_config(dir: &Path) -> PathBuf {
    let p = dir.join("pooled.json");
    let text = r#"{"modality": "keypoints2d", "network": {"hidden": 32, "layers": 1, "init_width": 32, "iterations": 3, "start": "mixed", "dropout": 0.0, "views": "pooled"},
        "rigs": {"cameras": [1, 8]},
        "steps": 6, "batch": 8, "val_frames": 8, "val_every": 6, "checkpoint_every": 6, "stats_frames": 16, "seed": 2}"#;
    std::fs::write(&p, text).expect("config");
    p
}

fn synth(out: &Path, cameras: &str) -> serde_json::Value {
    let o = synth_with(out, "keypoints2d", &["--cameras", cameras]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    serde_json::from_slice(&o.stdout).expect("stdout is JSON")
}

fn fit_args<'a>(data: &'a Path, checkpoint: &'a Path, out: &'a Path) -> Vec<&'a str> {
    vec![
        "-q",
        "fit",
        "--data",
        path_str(data),
        "--method",
        "neural",
        "--checkpoint",
        path_str(checkpoint),
        "--budget",
        "6",
        "--device",
        "ndarray",
        "--out",
        path_str(out),
    ]
}

#[test]
fn a_pooled_checkpoint_fits_1_and_3_cameras_where_the_fixed_rig_one_refuses() {
    let tmp = tempfile::tempdir().expect("tmp");
    let d = tmp.path();
    let ck = d.join("ck");
    let summary = lfit_json(&[
        "-q",
        "train",
        "--config",
        path_str(&tiny_pooled_config(d)),
        "--out",
        path_str(&ck),
        "--device",
        "ndarray",
    ]);
    assert_eq!(summary["summary"]["steps"], 6);
    let meta: serde_json::Value =
        serde_json::from_slice(&std::fs::read(ck.join("config.json")).expect("config.json"))
            .expect("json");
    assert_eq!(meta["network"]["views"], "pooled");
    let joints = lfit::model::default_template().rig.num_joints();
    assert_eq!(
        meta["network"]["residual_dim"],
        2 * joints,
        "one camera's residual"
    );

    let shipped = Path::new(env!("CARGO_MANIFEST_DIR")).join("checkpoints/keypoints2d");
    for cameras in [1usize, 3] {
        let data = d.join(format!("k{cameras}.npz"));
        let s = synth(&data, &cameras.to_string());
        assert_eq!(s["cameras"], cameras);
        let dataset = lfit::synth::Dataset::load(&data).expect("dataset");
        assert_eq!(dataset.sensor.cameras().len(), cameras);

        let out = d.join(format!("fit{cameras}.json"));
        lfit_json(&fit_args(&data, &ck, &out));
        let r: serde_json::Value =
            serde_json::from_slice(&std::fs::read(&out).expect("fit")).expect("json");
        let frames = r["frames"].as_array().expect("frames");
        assert_eq!(frames.len(), 4, "{cameras} cameras");
        for f in frames {
            assert_eq!(f["iterations"], 3);
            let pose = f["pose"].as_array().expect("pose");
            assert!(pose.iter().all(|v| v.as_f64().is_some_and(f64::is_finite)));
        }

        // The shipped network was trained on the six-camera rig and refuses the others.
        let refused = d.join("refused.json");
        let out = lfit(&fit_args(&data, &shipped, &refused));
        assert_one_line_error(
            &out,
            &format!(
                "expects a residual of {} values, the data's sensor gives {}",
                6 * 2 * joints,
                cameras * 2 * joints
            ),
        );
        assert!(!refused.exists());
    }

    // --cameras: at least one, and only for keypoints2d.
    assert_one_line_error(
        &lfit(&[
            "-q",
            "synth",
            "--modality",
            "keypoints2d",
            "--cameras",
            "0",
            "--out",
            path_str(&d.join("x.npz")),
        ]),
        "--cameras must be at least 1",
    );
    assert_one_line_error(
        &lfit(&[
            "-q",
            "synth",
            "--modality",
            "markers",
            "--cameras",
            "2",
            "--out",
            path_str(&d.join("x.npz")),
        ]),
        "set the keypoints2d rig",
    );
    // A pooled markers network is refused before training.
    let bad = d.join("bad.json");
    std::fs::write(
        &bad,
        r#"{"modality": "markers", "network": {"views": "pooled"}}"#,
    )
    .expect("write");
    assert_one_line_error(
        &lfit(&[
            "-q",
            "train",
            "--config",
            path_str(&bad),
            "--out",
            path_str(&d.join("t")),
        ]),
        "pools keypoints2d cameras",
    );
}

/// `lfit -q synth --modality MODALITY` (4 frames, seed 3) with the rig flags `rig`.
fn synth_with(out: &Path, modality: &str, rig: &[&str]) -> std::process::Output {
    let mut args = vec![
        "-q",
        "synth",
        "--modality",
        modality,
        "--frames",
        "4",
        "--seed",
        "3",
        "--out",
        path_str(out),
    ];
    args.extend_from_slice(rig);
    lfit(&args)
}

/// `lfit synth --camera FILE`: the keypoints2d of a user's own rig (`lfit data import`'s camera
/// file). The default ring's cameras written as a file give `--cameras N`'s data exactly; the
/// repository's example rigs (`configs/rigs/`) are read camera for camera; bad files and
/// flags are refused in one line with nothing written.
#[test]
fn synth_observes_keypoints_with_the_cameras_of_a_camera_file() {
    use lfit::synth::Dataset;
    use lfit::synth::capture::keypoints::{cameras_json, read_cameras};
    let tmp = tempfile::tempdir().expect("tmp");
    let d = tmp.path();
    let ring = d.join("ring3.json");
    std::fs::write(&ring, cameras_json(&lfit::model::camera::default_ring(3))).expect("write");
    let (by_count, by_file) = (d.join("count.npz"), d.join("file.npz"));
    for (out, rig) in [
        (&by_count, vec!["--cameras", "3"]),
        (&by_file, vec!["--camera", path_str(&ring)]),
    ] {
        let o = synth_with(out, "keypoints2d", &rig);
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    }
    let (a, b) = (
        Dataset::load(&by_count).expect("count"),
        Dataset::load(&by_file).expect("file"),
    );
    assert_eq!(a.sensor.cameras(), b.sensor.cameras());
    let sparse = |d: &Dataset| match &d.observations {
        lfit::synth::Observations::Sparse { values, visible } => (values.clone(), visible.clone()),
        _ => panic!("keypoints2d data are sparse"),
    };
    assert_eq!(sparse(&a), sparse(&b));
    assert_eq!(a.gt_poses, b.gt_poses);

    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    for (name, count) in [("phone-1", 1), ("tripods-2", 2), ("studio-3", 3)] {
        let file = root.join(format!("configs/rigs/{name}.json"));
        let out = d.join(format!("{name}.npz"));
        let o = synth_with(&out, "keypoints2d", &["--camera", path_str(&file)]);
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        let data = Dataset::load(&out).expect("dataset");
        let want = read_cameras(&file).expect("cameras");
        assert_eq!(want.len(), count);
        assert_eq!(data.sensor.cameras(), &want[..], "{name}");
        // The subject is in view: most keypoints of every frame are seen.
        let lfit::synth::Observations::Sparse { visible, .. } = &data.observations else {
            panic!("{name}: keypoints2d data are sparse");
        };
        let flags: Vec<bool> = visible.iter().flatten().copied().collect();
        let seen = flags.iter().filter(|&&v| v).count() as f64 / flags.len() as f64;
        assert!(seen > 0.5, "{name}: {seen} of the keypoints seen");
    }

    let x = d.join("x.npz");
    let missing = d.join("missing.json");
    let bad = d.join("bad.json");
    std::fs::write(&bad, r#"{"cameras": []}"#).expect("write");
    for (modality, rig, want) in [
        (
            "keypoints2d",
            vec!["--camera", path_str(&missing)],
            "missing.json",
        ),
        (
            "keypoints2d",
            vec!["--camera", path_str(&bad)],
            "no cameras",
        ),
        (
            "keypoints2d",
            vec!["--cameras", "2", "--camera", path_str(&ring)],
            "cannot be used with",
        ),
        (
            "markers",
            vec!["--camera", path_str(&ring)],
            "set the keypoints2d rig",
        ),
    ] {
        assert_one_line_error(&synth_with(&x, modality, &rig), want);
        assert!(!x.exists());
    }
}
