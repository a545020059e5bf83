//! `lfit fit`, `lfit optimize` and `lfit objective-server` from the command line: the result
//! contract, that fitting improves on the start, and the one-line errors on bad input.

mod support;

use std::io::Write;
use std::process::{Command, Stdio};

use support::{assert_one_line_error, lfit, lfit_json, path_str};

fn dataset(
    dir: &std::path::Path,
    modality: &str,
    scenario: &str,
    frames: usize,
) -> std::path::PathBuf {
    let out = dir.join(format!("{modality}_{scenario}.npz"));
    lfit_json(&[
        "synth",
        "--modality",
        modality,
        "--scenario",
        scenario,
        "--frames",
        &frames.to_string(),
        "--seed",
        "3",
        "--out",
        path_str(&out),
        "-q",
    ]);
    out
}

#[test]
fn fit_writes_the_result_contract_and_never_ends_above_the_start() {
    let dir = tempfile::tempdir().unwrap();
    let data = dataset(dir.path(), "markers", "local", 3);
    for (method, budget) in [("cma", 600), ("lbfgs", 60), ("lm", 60)] {
        let out = dir.path().join(format!("{method}.json"));
        lfit_json(&[
            "fit",
            "--data",
            path_str(&data),
            "--method",
            method,
            "--budget",
            &budget.to_string(),
            "--frames",
            "0..2",
            "--out",
            path_str(&out),
            "-q",
        ]);
        let r: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(&out).unwrap()).unwrap();
        // CMA-ES runs with its tuned setting by default, which its name spells out.
        let name = r["method"].as_str().unwrap();
        assert!(
            name == method || (method == "cma" && name.starts_with("cma[")),
            "{name}"
        );
        assert_eq!(r["budget"], budget);
        let frames = r["frames"].as_array().unwrap();
        assert_eq!(frames.len(), 2);
        let mean_pa = frames
            .iter()
            .map(|f| f["pa_mpjpe_mm"].as_f64().unwrap())
            .sum::<f64>()
            / 2.0;
        let summary_pa = r["summary"]["mean_pa_mpjpe_mm"].as_f64().unwrap();
        assert!(
            (summary_pa - mean_pa).abs() <= 1e-9 * mean_pa,
            "{summary_pa} against {mean_pa}"
        );
        for f in frames {
            for key in [
                "frame",
                "pose",
                "energy",
                "terms",
                "v2v_mm",
                "mpjpe_mm",
                "pa_mpjpe_mm",
                "evaluations",
                "time_s",
            ] {
                assert!(f.get(key).is_some(), "{method}: missing {key}");
            }
            // PA-MPJPE: the joints aligned by a similarity first, never far above MPJPE.
            let (pa, mpjpe) = (
                f["pa_mpjpe_mm"].as_f64().unwrap(),
                f["mpjpe_mm"].as_f64().unwrap(),
            );
            assert!(
                pa > 0.0 && pa <= mpjpe * 1.05,
                "{method}: {pa} against {mpjpe}"
            );
            assert_eq!(f["pose"].as_array().unwrap().len(), 57);
            let evals = f["evaluations"].as_u64().unwrap();
            if method == "cma" {
                assert_eq!(evals, budget as u64, "zeroth-order budgets are exact");
            } else if method == "lbfgs" {
                // Evaluation 1 is the start (value only); every later one has its gradient.
                assert!(
                    evals <= budget as u64
                        && f["gradient_evaluations"].as_u64().unwrap() + 1 == evals,
                    "{f}"
                );
            } else {
                // LM: a Jacobian at its start and at each accepted point only.
                let jacobians = f["gradient_evaluations"].as_u64().unwrap();
                assert!(
                    evals <= budget as u64 && jacobians >= 1 && jacobians < evals,
                    "{f}"
                );
            }
            // Never worse than the start (the start is evaluation 1); L-BFGS strictly better.
            let (e, e0) = (
                f["energy"].as_f64().unwrap(),
                f["start_energy"].as_f64().unwrap(),
            );
            assert!(e <= e0, "{method}: {f}");
            if method != "cma" {
                assert!(e < 0.9 * e0, "{method}: {f}");
            }
            assert!(f["terms"]["data"].as_f64().is_some());
        }
    }
}

#[test]
fn sequence_fitting_warm_starts_from_the_previous_frame() {
    let dir = tempfile::tempdir().unwrap();
    let data = dataset(dir.path(), "hmd", "sequence", 3);
    let out = dir.path().join("seq.json");
    lfit_json(&[
        "fit",
        "--data",
        path_str(&data),
        "--method",
        "lbfgs",
        "--budget",
        "40",
        "--out",
        path_str(&out),
        "-q",
    ]);
    let r: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&out).unwrap()).unwrap();
    assert_eq!(r["scenario"], "sequence");
    assert_eq!(r["frames"].as_array().unwrap().len(), 3);
}

#[test]
fn optimize_reports_value_point_and_trace() {
    let r = lfit_json(&[
        "optimize",
        "--function",
        "sphere",
        "--dim",
        "10",
        "--method",
        "cma",
        "--budget",
        "3000",
        "--seed",
        "1",
        "--json",
    ]);
    assert!(r["best_value"].as_f64().unwrap() < 1e-8, "{r}");
    assert_eq!(r["evaluations"], 3000);
    let x = r["best_x"].as_array().unwrap();
    assert!(x.iter().all(|v| (v.as_f64().unwrap() - 1.0).abs() < 1e-3));
    let trace = r["trace"].as_array().unwrap();
    assert!(
        trace
            .windows(2)
            .all(|w| w[1][1].as_f64() <= w[0][1].as_f64())
    );
    let again = lfit_json(&[
        "optimize",
        "--function",
        "sphere",
        "--dim",
        "10",
        "--method",
        "cma",
        "--budget",
        "3000",
        "--seed",
        "1",
        "--json",
    ]);
    assert_eq!(r, again, "same seed, same result");
}

#[test]
fn bad_input_to_fit_and_optimize() {
    let dir = tempfile::tempdir().unwrap();
    let data = dataset(dir.path(), "markers", "local", 1);
    let out = dir.path().join("r.json");
    let fit = |extra: &[&str]| {
        let mut args = vec!["fit", "--data", path_str(&data), "--out", path_str(&out)];
        args.extend_from_slice(extra);
        lfit(&args)
    };
    assert_one_line_error(
        &fit(&["--method", "gradient-descent", "--budget", "10"]),
        "invalid value 'gradient-descent' for '--method",
    );
    assert_one_line_error(&fit(&["--method", "cma", "--budget", "0"]), "budget");
    assert_one_line_error(
        &fit(&["--method", "cma", "--budget", "10", "--strategy", "greedy"]),
        "unknown strategy",
    );
    assert_one_line_error(
        &fit(&["--method", "cma", "--budget", "10", "--frames", "0..5"]),
        "frames",
    );
    assert!(!out.exists(), "no result file after a failed run");
    let missing = lfit(&[
        "fit",
        "--data",
        "/nonexistent/x.npz",
        "--method",
        "cma",
        "--budget",
        "10",
        "--out",
        path_str(&out),
    ]);
    assert_one_line_error(&missing, "x.npz");
    assert_one_line_error(
        &lfit(&[
            "optimize",
            "--function",
            "himmelblau",
            "--dim",
            "3",
            "--method",
            "cma",
            "--budget",
            "10",
        ]),
        "unknown function",
    );
    assert_one_line_error(
        &lfit(&[
            "optimize",
            "--function",
            "sphere",
            "--dim",
            "3",
            "--method",
            "nope",
            "--budget",
            "10",
        ]),
        "unknown method",
    );
    assert_one_line_error(
        &lfit(&[
            "optimize",
            "--function",
            "sphere",
            "--dim",
            "3",
            "--method",
            "cma",
            "--budget",
            "0",
        ]),
        "budget",
    );
}

#[test]
fn objective_server_answers_and_survives_bad_lines() {
    let dir = tempfile::tempdir().unwrap();
    let data = dataset(dir.path(), "markers", "local", 2);
    let x43 = serde_json::to_string(&vec![0.0; 43]).unwrap();
    let lines = [
        r#"{"describe": true}"#.to_string(),
        "not json".to_string(),
        r#"{"x": [1, 2, 3]}"#.to_string(),
        r#"{"x": [0.0, "NaN"]}"#.to_string(),
        format!(r#"{{"x": {}}}"#, x43.replacen("0.0", "null", 1)),
        format!(r#"{{"x": {x43}}}"#),
    ];
    let answers = serve(&["--data", path_str(&data), "--frame", "1"], &lines);
    let d = &answers[0];
    assert_eq!(d["dim"], 43);
    assert_eq!(d["lower"].as_array().unwrap().len(), 43);
    assert_eq!(d["names"][0], "t_x");
    assert!(
        answers[1]["error"]
            .as_str()
            .unwrap()
            .contains("malformed JSON")
    );
    assert!(
        answers[2]["error"]
            .as_str()
            .unwrap()
            .contains("expected 43")
    );
    assert!(
        answers[3]["error"]
            .as_str()
            .unwrap()
            .contains("expected 43")
    );
    assert!(
        answers[4]["error"]
            .as_str()
            .unwrap()
            .contains("x[0] is not a finite number")
    );
    let e = answers[5]["energy"].as_f64().unwrap();
    assert!(e.is_finite() && answers[5]["terms"]["data"].is_number());
    // The start pose's energy equals what `fit` reports as start_energy for that frame.
    let start = serde_json::to_string(&d["start"]).unwrap();
    let mut child = Command::new(env!("CARGO_BIN_EXE_lfit"))
        .args([
            "objective-server",
            "--data",
            path_str(&data),
            "--frame",
            "1",
            "--budget",
            "1",
        ])
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .spawn()
        .unwrap();
    let mut stdin = child.stdin.take().unwrap();
    writeln!(stdin, r#"{{"x": {start}}}"#).unwrap();
    writeln!(stdin, r#"{{"x": {start}}}"#).unwrap();
    drop(stdin);
    let out = child.wait_with_output().unwrap();
    let answers: Vec<serde_json::Value> = String::from_utf8(out.stdout)
        .unwrap()
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect();
    let fit_out = dir.path().join("f.json");
    lfit_json(&[
        "fit",
        "--data",
        path_str(&data),
        "--method",
        "random",
        "--budget",
        "1",
        "--frames",
        "1",
        "--out",
        path_str(&fit_out),
        "-q",
    ]);
    let r: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&fit_out).unwrap()).unwrap();
    assert_eq!(answers[0]["energy"], r["frames"][0]["start_energy"]);
    assert!(
        answers[1]["error"].as_str().unwrap().contains("budget"),
        "{}",
        answers[1]
    );
    let bad = lfit(&[
        "objective-server",
        "--data",
        path_str(&data),
        "--frame",
        "7",
    ]);
    assert_one_line_error(&bad, "frame 7 is out of range");
}

/// Runs `lfit objective-server` with `args`, sends `lines`, returns one JSON answer per line.
fn serve(args: &[&str], lines: &[String]) -> Vec<serde_json::Value> {
    let mut child = Command::new(env!("CARGO_BIN_EXE_lfit"))
        .arg("objective-server")
        .args(args)
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let mut stdin = child.stdin.take().unwrap();
    for l in lines {
        writeln!(stdin, "{l}").unwrap();
    }
    drop(stdin);
    let out = child.wait_with_output().unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let answers: Vec<serde_json::Value> = String::from_utf8(out.stdout)
        .unwrap()
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect();
    assert_eq!(answers.len(), lines.len());
    answers
}

#[test]
fn objective_server_answers_residuals_and_their_jacobian() {
    let dir = tempfile::tempdir().unwrap();
    let data = dataset(dir.path(), "markers", "local", 2);
    let describe = serve(
        &["--data", path_str(&data), "--frame", "1"],
        &[r#"{"describe": true}"#.to_string()],
    );
    let start = serde_json::to_string(&describe[0]["start"]).unwrap();
    let m = describe[0]["residuals"]
        .as_u64()
        .expect("describe says how many residuals") as usize;
    let mut bad = describe[0]["start"].clone();
    bad[0] = serde_json::json!("NaN");
    let lines = [
        format!(r#"{{"x": {start}, "residuals": true, "jacobian": true}}"#),
        format!(r#"{{"x": {start}, "residuals": true}}"#),
        format!(r#"{{"x": {start}, "jacobian": "yes"}}"#),
        r#"{"x": [1, 2], "residuals": true, "jacobian": true}"#.to_string(),
        format!(r#"{{"x": {bad}, "residuals": true}}"#),
        format!(r#"{{"x": {start}, "gradient": true}}"#),
    ];
    for (flags, gradient_energy) in [(vec![], false), (vec!["--gradient"], true)] {
        let mut args = vec!["--data", path_str(&data), "--frame", "1"];
        args.extend(flags);
        let a = serve(&args, &lines);
        let r: Vec<f64> = a[0]["residuals"]
            .as_array()
            .unwrap()
            .iter()
            .map(|v| v.as_f64().unwrap())
            .collect();
        let j: Vec<Vec<f64>> = a[0]["jacobian"]
            .as_array()
            .unwrap()
            .iter()
            .map(|row| {
                row.as_array()
                    .unwrap()
                    .iter()
                    .map(|v| v.as_f64().unwrap())
                    .collect()
            })
            .collect();
        assert_eq!(r.len(), m);
        assert_eq!(j.len(), m, "one Jacobian row per residual");
        assert!(
            j.iter().all(|row| row.len() == 43),
            "columns are the 43 free entries"
        );
        let e = a[0]["energy"].as_f64().unwrap();
        let sum: f64 = r.iter().map(|v| v * v).sum();
        assert!((e - sum).abs() <= 1e-12 * e, "energy = Σ r²: {e} vs {sum}");
        assert_eq!(a[1]["energy"], a[0]["energy"]);
        assert!(a[1].get("jacobian").is_none());
        assert!(
            a[2]["error"]
                .as_str()
                .unwrap()
                .contains("\"jacobian\" must be true or false"),
            "{}",
            a[2]
        );
        assert!(
            a[3]["error"].as_str().unwrap().contains("expected 43"),
            "{}",
            a[3]
        );
        assert!(
            a[4]["error"]
                .as_str()
                .unwrap()
                .contains("x[0] is not a finite number"),
            "{}",
            a[4]
        );
        // The server kept serving after the errors; the gradient answer is of the plain energy.
        let g: Vec<f64> = a[5]["gradient"]
            .as_array()
            .unwrap()
            .iter()
            .map(|v| v.as_f64().unwrap())
            .collect();
        if gradient_energy {
            // Same energy: its gradient is 2 Jᵀ r.
            assert!((a[5]["energy"].as_f64().unwrap() - e).abs() <= 1e-12 * e);
            for c in 0..43 {
                let jtr: f64 = (0..m).map(|i| 2.0 * j[i][c] * r[i]).sum();
                assert!(
                    (jtr - g[c]).abs() <= 1e-9 * g.iter().fold(1e-12f64, |s, v| s.max(v.abs())),
                    "column {c}: {jtr} vs {}",
                    g[c]
                );
            }
        } else {
            // Without --energy, residual answers serve LM's (gradient) energy, not the paper energy
            // that plain answers serve: both are answered.
            assert!(a[5]["energy"].as_f64().unwrap().is_finite());
        }
    }
    // A scan energy has no sum of squares: a one-line reason, and the server keeps serving.
    let scan = dataset(dir.path(), "scan", "local", 1);
    let x = serde_json::to_string(&vec![0.0; 43]).unwrap();
    let a = serve(
        &["--data", path_str(&scan), "--frame", "0"],
        &[
            format!(r#"{{"x": {x}, "jacobian": true}}"#),
            format!(r#"{{"x": {x}}}"#),
        ],
    );
    let err = a[0]["error"].as_str().unwrap();
    assert!(
        err.contains("not a sum of squares") && !err.contains('\n'),
        "{err}"
    );
    assert!(a[1]["energy"].as_f64().unwrap().is_finite());
    // LM and GN refuse it with one line too.
    let out = support::lfit(&[
        "fit",
        "--data",
        path_str(&scan),
        "--method",
        "lm",
        "--budget",
        "10",
        "--out",
        path_str(&dir.path().join("scan_lm.json")),
        "-q",
    ]);
    assert_one_line_error(&out, "not a sum of squares");
    assert!(!dir.path().join("scan_lm.json").exists());
}

#[test]
fn tuned_preset_uses_the_recorded_setting_and_refuses_what_it_cannot_set() {
    let dir = tempfile::tempdir().unwrap();
    let data = dataset(dir.path(), "markers", "local", 1);
    let table: serde_json::Value =
        serde_json::from_str(include_str!("../configs/tuned.json")).unwrap();
    let chosen = &table["settings"]["markers"]["cma"];
    let out = dir.path().join("tuned.json");
    let summary = lfit_json(&[
        "fit",
        "--data",
        path_str(&data),
        "--method",
        "cma",
        "--preset",
        "tuned",
        "--budget",
        "50",
        "--out",
        path_str(&out),
        "-q",
    ]);
    assert!(
        summary["summary"]["frames"].as_u64() == Some(1),
        "{summary}"
    );
    let r: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&out).unwrap()).unwrap();
    assert_eq!(r["preset"], "tuned");
    assert_eq!(r["step_scale"], chosen["step_scale"]);
    for key in ["diagonal", "elitist"] {
        assert_eq!(
            r["cma_variant"][key].as_bool().unwrap_or(false),
            chosen["cma"][key].as_bool().unwrap_or(false),
            "{key}"
        );
    }
    assert_eq!(r["frames"][0]["evaluations"], 50, "the budget stays exact");
    // The same run through the explicit flags gives the identical fit (same seed).
    let mut flags = vec![
        "fit".to_string(),
        "--data".into(),
        path_str(&data).into(),
        "--method".into(),
        "cma".into(),
        "--budget".into(),
        "50".into(),
        "-q".into(),
    ];
    flags.extend(["--step-scale".to_string(), chosen["step_scale"].to_string()]);
    if chosen["cma"]["diagonal"] == true {
        flags.push("--cma-diagonal".into());
    }
    if chosen["cma"]["elitist"] == true {
        flags.push("--cma-elitist".into());
    }
    if let Some(p) = chosen["cma"]["popsize"].as_u64() {
        flags.extend(["--cma-popsize".to_string(), p.to_string()]);
    }
    let explicit = dir.path().join("explicit.json");
    flags.extend(["--out".to_string(), path_str(&explicit).into()]);
    let args: Vec<&str> = flags.iter().map(String::as_str).collect();
    lfit_json(&args);
    let e: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&explicit).unwrap()).unwrap();
    assert_eq!(e["frames"][0]["pose"], r["frames"][0]["pose"]);
    assert_eq!(
        e["preset"], "nevergrad",
        "explicit steps are not the tuned preset"
    );
    // Without --preset the recorded setting is the default: the same fit as --preset tuned; a
    // method without a recorded setting runs with nevergrad's.
    let default = dir.path().join("default.json");
    lfit_json(&[
        "fit",
        "--data",
        path_str(&data),
        "--method",
        "cma",
        "--budget",
        "50",
        "--out",
        path_str(&default),
        "-q",
    ]);
    let d: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&default).unwrap()).unwrap();
    assert_eq!(d["preset"], "tuned");
    assert_eq!(d["step_scale"], chosen["step_scale"]);
    assert_eq!(d["frames"][0]["pose"], r["frames"][0]["pose"]);
    let papers = dir.path().join("nevergrad.json");
    lfit_json(&[
        "fit",
        "--data",
        path_str(&data),
        "--method",
        "cma",
        "--preset",
        "nevergrad",
        "--budget",
        "50",
        "--out",
        path_str(&papers),
        "-q",
    ]);
    let n: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&papers).unwrap()).unwrap();
    assert_eq!(n["preset"], "nevergrad");
    assert_eq!(n["step_scale"].as_f64(), Some(1.0));
    assert_eq!(n["cma_variant"]["diagonal"], false);
    let fit = |extra: &[&str]| {
        let mut a = vec![
            "fit",
            "--data",
            path_str(&data),
            "--budget",
            "10",
            "--out",
            path_str(&out),
        ];
        a.extend_from_slice(extra);
        support::lfit(&a)
    };
    assert_one_line_error(
        &fit(&["--method", "cma", "--preset", "tuned", "--step-scale", "2"]),
        "--preset tuned sets the steps",
    );
    assert_one_line_error(
        &fit(&["--method", "lbfgs", "--preset", "tuned"]),
        "no tuned setting for lbfgs on markers",
    );
    assert_one_line_error(
        &fit(&["--method", "pso", "--cma-diagonal"]),
        "CMA-ES options",
    );
    assert_one_line_error(
        &fit(&["--method", "lm", "--step-scale", "2"]),
        "no initial steps",
    );
    assert_one_line_error(
        &fit(&["--method", "cma", "--step-scale", "0"]),
        "step scale must be a positive number",
    );
}

#[test]
fn silhouettes_fit_with_zeroth_order_methods_and_gradient_methods_refuse() {
    let dir = tempfile::tempdir().unwrap();
    let data = dataset(dir.path(), "silhouettes", "local", 2);
    // numpy layout: one [N, K, H, W] uint8 mask array.
    let out = dir.path().join("cma.json");
    lfit_json(&[
        "fit",
        "--data",
        path_str(&data),
        "--method",
        "cma",
        "--budget",
        "60",
        "--out",
        path_str(&out),
        "-q",
    ]);
    let r: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&out).unwrap()).unwrap();
    for f in r["frames"].as_array().unwrap() {
        let (e, e0) = (
            f["energy"].as_f64().unwrap(),
            f["start_energy"].as_f64().unwrap(),
        );
        assert!(
            e <= e0 && (0.0..=1.0 + 1e-9).contains(&f["terms"]["data"].as_f64().unwrap()),
            "{f}"
        );
        assert_eq!(f["evaluations"], 60);
    }
    for method in ["lbfgs", "lm", "gn"] {
        let o = dir.path().join(format!("{method}.json"));
        let res = support::lfit(&[
            "fit",
            "--data",
            path_str(&data),
            "--method",
            method,
            "--budget",
            "10",
            "--out",
            path_str(&o),
            "-q",
        ]);
        assert_one_line_error(&res, "no gradient");
        assert!(!o.exists());
    }
    let x = serve(
        &["--data", path_str(&data), "--frame", "0"],
        &[r#"{"describe": true}"#.to_string()],
    );
    let start = serde_json::to_string(&x[0]["start"]).unwrap();
    let a = serve(
        &["--data", path_str(&data), "--frame", "0"],
        &[
            format!(r#"{{"x": {start}, "jacobian": true}}"#),
            format!(r#"{{"x": {start}}}"#),
        ],
    );
    assert!(
        a[0]["error"].as_str().unwrap().contains("no gradient"),
        "{}",
        a[0]
    );
    assert!(
        a[1]["energy"].as_f64().unwrap().is_finite(),
        "the server keeps serving"
    );
}

#[test]
fn a_dataset_of_a_shipped_model_needs_no_model_flag_and_others_say_which_flag() {
    let dir = tempfile::tempdir().unwrap();
    let mh = "models/makehuman-cmu_mb.npz";
    let data = dir.path().join("mh.npz");
    lfit_json(&[
        "synth",
        "--modality",
        "markers",
        "--model",
        mh,
        "--frames",
        "2",
        "--seed",
        "5",
        "--out",
        path_str(&data),
        "-q",
    ]);
    // Found by the dataset's model id (models/<id>.npz): the same fit as with --model.
    let fit = |extra: &[&str], out: &str| {
        let out = dir.path().join(out);
        let mut args = vec![
            "fit",
            "--data",
            path_str(&data),
            "--method",
            "lm",
            "--budget",
            "30",
            "--out",
            path_str(&out),
            "-q",
        ];
        args.extend_from_slice(extra);
        lfit_json(&args);
        let doc: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(&out).unwrap()).unwrap();
        doc["frames"]
            .as_array()
            .unwrap()
            .iter()
            .map(|f| f["energy"].as_f64().unwrap())
            .collect::<Vec<f64>>()
    };
    let found = fit(&[], "found.json");
    assert_eq!(found, fit(&["--model", mh], "given.json"));
    assert_eq!(found.len(), 2);
    // A model that is not shipped: one line naming --model, nothing written.
    let own = dir.path().join("mybody.npz");
    std::fs::copy(mh, &own).unwrap();
    let data2 = dir.path().join("own.npz");
    lfit_json(&[
        "synth",
        "--modality",
        "markers",
        "--model",
        path_str(&own),
        "--frames",
        "1",
        "--out",
        path_str(&data2),
        "-q",
    ]);
    let never = dir.path().join("never.json");
    let out = lfit(&[
        "fit",
        "--data",
        path_str(&data2),
        "--method",
        "lm",
        "--budget",
        "10",
        "--out",
        path_str(&never),
    ]);
    assert_one_line_error(
        &out,
        "made with model 'mybody', which is not a shipped one: pass it with --model",
    );
    assert!(!never.exists());
    // A relative checkpoint found nowhere names the places searched.
    let out = Command::new(env!("CARGO_BIN_EXE_lfit"))
        .current_dir(dir.path())
        .env_remove("LFIT_DATA_DIR")
        .args([
            "fit",
            "--data",
            "mh.npz",
            "--method",
            "neural",
            "--checkpoint",
            "checkpoints/no-such-fitter",
            "--budget",
            "10",
            "--out",
            "n.json",
        ])
        .output()
        .unwrap();
    assert_one_line_error(
        &out,
        "checkpoint checkpoints/no-such-fitter not found in the working directory, LFIT_DATA_DIR (unset)",
    );
    assert!(!dir.path().join("n.json").exists());
}
