//! Every bad input gives one line on stderr naming the cause, a non-zero exit and no panic; and
//! nothing the user had on disk is lost.

mod support;

use support::{assert_one_line_error, lfit, lfit_json, path_str};

fn exported(dir: &std::path::Path) -> std::path::PathBuf {
    let tpl = dir.join("tpl");
    lfit_json(&["template", "export", "--out-dir", path_str(&tpl)]);
    tpl
}

fn pose_file(dir: &std::path::Path) -> std::path::PathBuf {
    let p = dir.join("pose.json");
    std::fs::write(&p, serde_json::json!({ "pose": vec![0.0; 57] }).to_string()).unwrap();
    p
}

fn pose_with(tpl: &std::path::Path, dir: &std::path::Path) -> std::process::Output {
    let pose = pose_file(dir);
    lfit(&[
        "template",
        "pose",
        "--pose",
        path_str(&pose),
        "--out",
        path_str(&dir.join("o.obj")),
        "--template",
        path_str(tpl),
    ])
}

fn edit_rig(tpl: &std::path::Path, edit: impl FnOnce(&mut serde_json::Value)) {
    let path = tpl.join("rig.json");
    let mut rig: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&path).unwrap()).unwrap();
    edit(&mut rig);
    std::fs::write(path, rig.to_string()).unwrap();
}

#[test]
fn malformed_obj() {
    let dir = tempfile::tempdir().unwrap();
    let tpl = exported(dir.path());
    std::fs::write(tpl.join("template.obj"), "v 0 0 0\nv 1 0 0\nf 1 2 x\n").unwrap();
    assert_one_line_error(&pose_with(&tpl, dir.path()), "template.obj");
    std::fs::write(
        tpl.join("template.obj"),
        "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 9\n",
    )
    .unwrap();
    assert_one_line_error(&pose_with(&tpl, dir.path()), "template.obj");
}

#[test]
fn rig_with_a_cycle() {
    let dir = tempfile::tempdir().unwrap();
    let tpl = exported(dir.path());
    edit_rig(&tpl, |r| r["joints"][3]["parent"] = serde_json::json!(5));
    assert_one_line_error(&pose_with(&tpl, dir.path()), "joint 3");
    edit_rig(&tpl, |r| r["joints"][3]["parent"] = serde_json::json!(3));
    assert_one_line_error(&pose_with(&tpl, dir.path()), "cycle");
}

#[test]
fn rig_with_bad_weights() {
    let dir = tempfile::tempdir().unwrap();
    let tpl = exported(dir.path());
    edit_rig(&tpl, |r| {
        r["weights"][17] = serde_json::json!([[0, 0.7], [1, 0.7]])
    });
    assert_one_line_error(&pose_with(&tpl, dir.path()), "vertex 17");
    edit_rig(&tpl, |r| {
        r["weights"][17] = serde_json::json!([[0, 1.5], [1, -0.5]])
    });
    assert_one_line_error(&pose_with(&tpl, dir.path()), "negative");
    edit_rig(&tpl, |r| r["weights"][17] = serde_json::json!([[99, 1.0]]));
    assert_one_line_error(&pose_with(&tpl, dir.path()), "out of range");
}

#[test]
fn rig_with_nan() {
    let dir = tempfile::tempdir().unwrap();
    let tpl = exported(dir.path());
    let path = tpl.join("rig.json");
    let text = std::fs::read_to_string(&path).unwrap();
    // JSON has no NaN literal: a NaN written by a careless exporter is a parse error here.
    let broken = text.replacen("\"rest_position\": [", "\"rest_position\": [NaN,", 1);
    assert_ne!(broken, text);
    std::fs::write(&path, broken).unwrap();
    assert_one_line_error(&pose_with(&tpl, dir.path()), "rig.json");
}

#[test]
fn nan_and_wrong_length_in_pose_files() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("p.json");
    std::fs::write(&p, r#"{"pose": [1, 2, 3]}"#).unwrap();
    let out = lfit(&[
        "template",
        "pose",
        "--pose",
        path_str(&p),
        "--out",
        path_str(&dir.path().join("o.obj")),
    ]);
    assert_one_line_error(&out, "57");
    std::fs::write(&p, r#"{"pose": [1, 2, "x"]}"#).unwrap();
    let out = lfit(&[
        "template",
        "pose",
        "--pose",
        path_str(&p),
        "--out",
        path_str(&dir.path().join("o.obj")),
    ]);
    assert_one_line_error(&out, "not a number");
    std::fs::write(&p, "{\"pose\": [").unwrap();
    let out = lfit(&[
        "template",
        "pose",
        "--pose",
        path_str(&p),
        "--out",
        path_str(&dir.path().join("o.obj")),
    ]);
    assert_one_line_error(&out, "malformed pose json");
}

#[test]
fn unknown_modality_scenario_and_flags() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("d.npz");
    let o = lfit(&[
        "synth",
        "--modality",
        "lidar",
        "--frames",
        "2",
        "--out",
        path_str(&out),
    ]);
    assert_one_line_error(&o, "unknown modality 'lidar'");
    let o = lfit(&[
        "synth",
        "--modality",
        "markers",
        "--scenario",
        "orbit",
        "--frames",
        "2",
        "--out",
        path_str(&out),
    ]);
    assert_one_line_error(&o, "unknown scenario 'orbit'");
    let o = lfit(&[
        "synth",
        "--modality",
        "markers",
        "--frames",
        "0",
        "--out",
        path_str(&out),
    ]);
    assert_one_line_error(&o, "frames");
    let o = lfit(&[
        "synth",
        "--modality",
        "markers",
        "--frames",
        "2",
        "--noise=-1",
        "--out",
        path_str(&out),
    ]);
    assert_one_line_error(&o, "noise");
    let o = lfit(&["synth", "--modality", "markers", "--bogus-flag"]);
    assert_one_line_error(&o, "bogus-flag");
    // clap's errors keep what their later lines say, on one line: the valid values and the
    // suggestion, the missing flags and the usage.
    let o = lfit(&[
        "fit", "--data", "x.npz", "--method", "cmaa", "--budget", "3",
    ]);
    assert_one_line_error(&o, "[possible values: random,");
    assert_one_line_error(&o, "a similar value exists: 'cma'");
    let o = lfit(&[
        "fit", "--data", "x.npz", "--method", "lm", "--out", "x.json",
    ]);
    assert_one_line_error(&o, "not provided: --budget <BUDGET> (usage: lfit fit ");
    assert!(!String::from_utf8_lossy(&o.stderr).contains("For more information"));
    let o = lfit(&[
        "template",
        "export",
        "--out-dir",
        path_str(dir.path()),
        "--shape",
        "giant",
    ]);
    assert_one_line_error(&o, "giant");
    assert!(!out.exists(), "nothing written on a refused command");
    // One flag name for the model everywhere: --model, with --template as its alias, on every
    // subcommand that takes a model (a missing model file is named whichever spelling is used).
    for command in [
        &[
            "fit", "--data", "x.npz", "--method", "lm", "--budget", "3", "--out", "x.json",
        ][..],
        &[
            "synth",
            "--modality",
            "markers",
            "--frames",
            "2",
            "--out",
            "x.npz",
        ][..],
        &["data", "import", "--c3d", "x.c3d", "--out", "x.npz"][..],
        &["render", "--data", "x.npz", "--out", "x.png"][..],
        &[
            "export", "--data", "x.npz", "--poses", "x.json", "--format", "obj", "--out", "x",
        ][..],
        &["motion", "import", "--bvh", "x.bvh", "--out", "x.npz"][..],
    ] {
        for flag in ["--model", "--template"] {
            let mut args: Vec<&str> = command.to_vec();
            args.extend([flag, "/nonexistent/body.npz"]);
            let o = lfit(&args);
            let err = String::from_utf8_lossy(&o.stderr);
            assert!(
                !err.contains("unexpected argument"),
                "{} {flag}: {err}",
                command[..2].join(" ")
            );
            assert!(
                !o.status.success(),
                "{} {flag} succeeded",
                command[..2].join(" ")
            );
        }
    }
}

#[test]
fn missing_files() {
    let dir = tempfile::tempdir().unwrap();
    let o = lfit(&[
        "template",
        "pose",
        "--pose",
        "/nonexistent/pose.json",
        "--out",
        path_str(&dir.path().join("o.obj")),
    ]);
    assert_one_line_error(&o, "/nonexistent/pose.json");
    let pose = pose_file(dir.path());
    let o = lfit(&[
        "template",
        "pose",
        "--pose",
        path_str(&pose),
        "--out",
        path_str(&dir.path().join("o.obj")),
        "--template",
        "/nonexistent/tpl",
    ]);
    assert_one_line_error(&o, "/nonexistent/tpl");
}

#[test]
fn a_failed_write_keeps_the_old_file() {
    let dir = tempfile::tempdir().unwrap();
    let target = dir.path().join("keep.obj");
    std::fs::write(&target, "old content").unwrap();
    let p = dir.path().join("p.json");
    std::fs::write(&p, r#"{"pose": [1, 2, 3]}"#).unwrap();
    let o = lfit(&[
        "template",
        "pose",
        "--pose",
        path_str(&p),
        "--out",
        path_str(&target),
    ]);
    assert!(!o.status.success());
    assert_eq!(std::fs::read_to_string(&target).unwrap(), "old content");
}
