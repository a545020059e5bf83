//! `lfit train` and `lfit fit --method neural` end to end: a tiny training run, fitting with its
//! checkpoint per frame, batched and along a sequence, and the errors of bad checkpoints.

mod support;

use support::{assert_one_line_error, lfit, lfit_json, path_str};

fn tiny_config(dir: &std::path::Path, modality: &str) -> std::path::PathBuf {
    let p = dir.join(format!("{modality}.json"));
    let text = format!(
        r#"{{"modality": "{modality}", "network": {{"hidden": 32, "layers": 1, "init_width": 32, "iterations": 3, "start": "mixed", "dropout": 0.0}},
            "steps": 12, "batch": 8, "val_frames": 8, "val_every": 6, "checkpoint_every": 6, "stats_frames": 16, "seed": 2}}"#
    );
    std::fs::write(&p, text).expect("config");
    p
}

#[test]
fn train_then_fit_with_the_checkpoint() {
    let tmp = tempfile::tempdir().expect("tmp");
    let d = tmp.path();
    let ck = d.join("ck");
    let summary = lfit_json(&[
        "-q",
        "train",
        "--config",
        path_str(&tiny_config(d, "markers")),
        "--out",
        path_str(&ck),
        "--device",
        "ndarray",
    ]);
    assert_eq!(summary["summary"]["steps"], 12);
    for f in [
        "config.json",
        "weights.bpk",
        "stats.json",
        "metrics.json",
        "metrics.csv",
    ] {
        assert!(ck.join(f).exists(), "{f}");
    }
    let data = d.join("m.npz");
    lfit_json(&[
        "-q",
        "synth",
        "--modality",
        "markers",
        "--frames",
        "6",
        "--seed",
        "9",
        "--out",
        path_str(&data),
    ]);

    // Per frame and batched give the same poses (one network, inference mode).
    let one = d.join("one.json");
    let many = d.join("many.json");
    let common = [
        "-q",
        "fit",
        "--data",
        path_str(&data),
        "--method",
        "neural",
        "--checkpoint",
        path_str(&ck),
        "--budget",
        "6",
        "--device",
        "ndarray",
    ];
    lfit_json(&[&common[..], &["--out", path_str(&one)]].concat());
    lfit_json(&[&common[..], &["--out", path_str(&many), "--batch", "4"]].concat());
    let a: serde_json::Value =
        serde_json::from_slice(&std::fs::read(&one).expect("one")).expect("json");
    let b: serde_json::Value =
        serde_json::from_slice(&std::fs::read(&many).expect("many")).expect("json");
    assert_eq!(a["method"], "neural");
    let frames = a["frames"].as_array().expect("frames");
    assert_eq!(frames.len(), 6);
    for (fa, fb) in frames.iter().zip(b["frames"].as_array().expect("frames")) {
        let (pa, pb) = (
            fa["pose"].as_array().expect("pose"),
            fb["pose"].as_array().expect("pose"),
        );
        for (x, y) in pa.iter().zip(pb) {
            assert!(
                (x.as_f64().expect("x") - y.as_f64().expect("y")).abs() < 1e-4,
                "batched and per-frame fits differ"
            );
        }
        assert_eq!(fa["iterations"], 3);
        assert_eq!(fa["evaluations"], 6, "2 evaluations per iteration");
        assert_eq!(fa["gradient_evaluations"], 3);
        assert_eq!(fa["v2v_mm_per_iteration"].as_array().map(Vec::len), Some(4));
        assert_eq!(fa["trace"].as_array().map(Vec::len), Some(4));
    }
    assert_eq!(b["batch"], 4);

    // From the scenario's start pose, the fit stays in the local box.
    let given = d.join("given.json");
    lfit_json(
        &[
            &common[..],
            &["--out", path_str(&given), "--neural-start", "given"],
        ]
        .concat(),
    );

    // Sequences go frame by frame, each starting from the previous result (a frame's start
    // energy is then the energy of the previous frame's pose on this frame, not the dataset's
    // start pose).
    let seq = d.join("seq.npz");
    lfit_json(&[
        "-q",
        "synth",
        "--modality",
        "markers",
        "--scenario",
        "sequence",
        "--frames",
        "4",
        "--seed",
        "5",
        "--out",
        path_str(&seq),
    ]);
    let seq_out = d.join("seq.json");
    lfit_json(&[
        "-q",
        "fit",
        "--data",
        path_str(&seq),
        "--method",
        "neural",
        "--neural-start",
        "given",
        "--checkpoint",
        path_str(&ck),
        "--budget",
        "6",
        "--device",
        "ndarray",
        "--batch",
        "4",
        "--out",
        path_str(&seq_out),
    ]);
    let s: serde_json::Value =
        serde_json::from_slice(&std::fs::read(&seq_out).expect("seq")).expect("json");
    assert_eq!(s["batch"], 1, "sequences are fitted one frame at a time");
    assert_eq!(s["method"], "neural-given");
    let sf = s["frames"].as_array().expect("frames");
    let dataset = lfit::synth::Dataset::load(&seq).expect("dataset");
    let template = lfit::model::default_template();
    for k in 1..sf.len() {
        // θ0 of frame k is frame k−1's result: the error of the first iterate is that pose's.
        let mut prev = [0.0; lfit::model::POSE_DIM];
        for (p, v) in prev
            .iter_mut()
            .zip(sf[k - 1]["pose"].as_array().expect("pose"))
        {
            *p = v.as_f64().expect("number");
        }
        let want = lfit::model::metrics::v2v_mm(&template, &prev, &dataset.gt_poses[k]);
        let got = sf[k]["v2v_mm_per_iteration"][0].as_f64().expect("v2v");
        assert!(
            (want - got).abs() < 0.05,
            "frame {k}: θ0 error {got} mm, previous result's {want} mm"
        );
    }

    // Errors: budget below N iterations, wrong modality, missing and broken checkpoints.
    let out = lfit(&[
        "-q",
        "fit",
        "--data",
        path_str(&data),
        "--method",
        "neural",
        "--checkpoint",
        path_str(&ck),
        "--budget",
        "2",
        "--out",
        path_str(&d.join("x.json")),
    ]);
    assert_one_line_error(&out, "budget 2 is below");
    let hmd = d.join("h.npz");
    lfit_json(&[
        "-q",
        "synth",
        "--modality",
        "hmd",
        "--frames",
        "2",
        "--out",
        path_str(&hmd),
    ]);
    let out = lfit(&[
        "-q",
        "fit",
        "--data",
        path_str(&hmd),
        "--method",
        "neural",
        "--checkpoint",
        path_str(&ck),
        "--budget",
        "10",
        "--out",
        path_str(&d.join("x.json")),
    ]);
    assert_one_line_error(&out, "trained for markers data, not hmd");
    let out = lfit(&[
        "-q",
        "fit",
        "--data",
        path_str(&data),
        "--method",
        "neural",
        "--budget",
        "10",
        "--out",
        path_str(&d.join("x.json")),
    ]);
    assert_one_line_error(&out, "needs --checkpoint");
    let out = lfit(&[
        "-q",
        "fit",
        "--data",
        path_str(&data),
        "--method",
        "neural",
        "--checkpoint",
        path_str(&d.join("nope")),
        "--budget",
        "10",
        "--out",
        path_str(&d.join("x.json")),
    ]);
    assert_one_line_error(&out, "no such checkpoint");
    let w = ck.join("weights.bpk");
    let bytes = std::fs::read(&w).expect("weights");
    std::fs::write(&w, &bytes[..bytes.len() / 3]).expect("truncate");
    let out = lfit(&[
        "-q",
        "fit",
        "--data",
        path_str(&data),
        "--method",
        "neural",
        "--checkpoint",
        path_str(&ck),
        "--budget",
        "10",
        "--out",
        path_str(&d.join("x.json")),
    ]);
    assert_one_line_error(&out, "weights");
    assert!(
        !d.join("x.json").exists(),
        "no result file is written on error"
    );
    let out = lfit(&[
        "-q",
        "fit",
        "--data",
        path_str(&data),
        "--method",
        "neural",
        "--checkpoint",
        path_str(&ck),
        "--neural-start",
        "middle",
        "--budget",
        "10",
        "--out",
        path_str(&d.join("x.json")),
    ]);
    assert_one_line_error(&out, "unknown neural start");

    // Bad training inputs.
    let out = lfit(&[
        "-q",
        "train",
        "--config",
        path_str(&d.join("missing.json")),
        "--out",
        path_str(&d.join("t")),
    ]);
    assert_one_line_error(&out, "cannot read");
    let out = lfit(&[
        "-q",
        "train",
        "--config",
        path_str(&tiny_config(d, "markers")),
        "--out",
        path_str(&d.join("t")),
        "--device",
        "tpu",
    ]);
    assert_one_line_error(&out, "tpu");
    let out = lfit(&[
        "-q",
        "train",
        "--config",
        path_str(&tiny_config(d, "scan")),
        "--out",
        path_str(&d.join("t")),
    ]);
    assert_one_line_error(&out, "scan");
}

/// `lfit train --init` fine-tunes a checkpoint whose network is the config's; a Gauss-Newton
/// network may change to the chord direction (the written checkpoint says so), anything else
/// that differs is refused with a one-line error.
#[test]
fn init_fine_tunes_a_gauss_newton_network_for_the_chord_direction() {
    let tmp = tempfile::tempdir().expect("tmp");
    let d = tmp.path();
    let config = |name: &str, network: &str| {
        let p = d.join(format!("{name}.json"));
        let text = format!(
            r#"{{"modality": "markers", "network": {{"layers": 1, "init_width": 16, "iterations": 2, "start": "mixed", "dropout": 0.0, {network}}},
                "steps": 4, "batch": 4, "val_frames": 4, "val_every": 4, "checkpoint_every": 4, "stats_frames": 8, "seed": 3}}"#
        );
        std::fs::write(&p, text).expect("config");
        p
    };
    let train = |cfg: &std::path::Path, out: &std::path::Path, init: Option<&std::path::Path>| {
        let mut args = vec![
            "-q",
            "train",
            "--config",
            path_str(cfg),
            "--out",
            path_str(out),
            "--device",
            "ndarray",
        ];
        if let Some(i) = init {
            args.extend(["--init", path_str(i)]);
        }
        lfit(&args)
    };
    let gn = d.join("gn");
    let out = train(
        &config("gn", r#""hidden": 16, "direction": "gauss-newton""#),
        &gn,
        None,
    );
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let chord = d.join("chord");
    let cfg = config(
        "chord",
        r#""hidden": 16, "direction": "gauss-newton-chord", "chord_factorisations": 2"#,
    );
    let out = train(&cfg, &chord, Some(&gn));
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let written = std::fs::read_to_string(chord.join("config.json")).expect("config.json");
    assert!(
        written.contains("\"direction\": \"gauss-newton-chord\"")
            && written.contains("\"chord_factorisations\": 2"),
        "{written}"
    );
    // Another width, or the gradient direction, is another network.
    for (name, network) in [
        ("wide", r#""hidden": 24, "direction": "gauss-newton-chord""#),
        ("gradient", r#""hidden": 16"#),
    ] {
        let out = train(&config(name, network), &d.join(name), Some(&gn));
        assert_one_line_error(&out, "its network differs from the config's");
        assert!(!d.join(name).join("weights.bpk").exists());
    }
}
