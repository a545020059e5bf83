//! The subject's shape β given rather than estimated (papers/002 §3.2: the HMD fitter is given
//! β): `lfit fit --known-shape truth|β…` freezes the shape entries of every method at the given
//! values, a network trained with `"known_shape": true` is clamped onto the true β during
//! training and refuses a fit that would let β move, and bench configs say `known_shape = true`.
//! On the morphable default template (8 shape components), tiny sizes.

mod support;

use support::{assert_one_line_error, lfit, lfit_json, path_str};

const B: usize = 8;

fn read(path: &std::path::Path) -> serde_json::Value {
    serde_json::from_slice(&std::fs::read(path).expect("result")).expect("json")
}

fn shapes(result: &serde_json::Value) -> Vec<Vec<f64>> {
    result["frames"]
        .as_array()
        .expect("frames")
        .iter()
        .map(|f| {
            f["shape"]
                .as_array()
                .expect("shape")
                .iter()
                .map(|v| v.as_f64().expect("number"))
                .collect()
        })
        .collect()
}

#[test]
fn a_known_shape_is_frozen_for_every_method_and_required_by_a_known_shape_network() {
    let tmp = tempfile::tempdir().expect("tmp");
    let d = tmp.path();
    let data = d.join("hmd.npz");
    lfit_json(&[
        "-q",
        "synth",
        "--modality",
        "hmd",
        "--shape",
        "morphable",
        "--frames",
        "5",
        "--seed",
        "3",
        "--out",
        path_str(&data),
    ]);
    let dataset =
        lfit::synth::Dataset::from_npz(&std::fs::read(&data).expect("data")).expect("dataset");
    let truth: Vec<Vec<f64>> = dataset.gt_poses.iter().map(|g| g[57..].to_vec()).collect();
    assert!(truth.iter().flatten().any(|b| b.abs() > 0.1), "random β");

    // A tiny known-shape hmd network.
    let config = d.join("hmd.json");
    std::fs::write(
        &config,
        r#"{"modality": "hmd", "network": {"hidden": 16, "layers": 1, "init_width": 16, "iterations": 3, "start": "mixed", "dropout": 0.0, "known_shape": true},
            "steps": 3, "batch": 4, "val_frames": 4, "val_every": 3, "checkpoint_every": 3, "stats_frames": 8, "seed": 2}"#,
    )
    .expect("config");
    let ck = d.join("ck");
    lfit_json(&[
        "-q",
        "train",
        "--config",
        path_str(&config),
        "--shape",
        "morphable",
        "--out",
        path_str(&ck),
        "--device",
        "ndarray",
    ]);
    assert_eq!(
        read(&ck.join("config.json"))["network"]["known_shape"],
        true
    );

    let fit = |method: &str, known: Option<&str>, name: &str| {
        let out = d.join(name);
        let neural = method == "neural";
        let mut args = vec![
            "-q",
            "fit",
            "--data",
            path_str(&data),
            "--method",
            method,
            "--budget",
            if neural { "10" } else { "200" },
            "--out",
            path_str(&out),
        ];
        if neural {
            args.extend(["--checkpoint", path_str(&ck), "--device", "ndarray"]);
        }
        if let Some(k) = known {
            args.extend(["--known-shape", k]);
        }
        (lfit(&args), out)
    };

    // β = the truth, to the bit, for a classical and the neural fitter (from Φ(D) and given).
    for (method, name) in [
        ("lm", "lm.json"),
        ("lbfgs", "lbfgs.json"),
        ("neural", "nn.json"),
    ] {
        let (o, out) = fit(method, Some("truth"), name);
        assert!(
            o.status.success(),
            "{method}: {}",
            String::from_utf8_lossy(&o.stderr)
        );
        let r = read(&out);
        assert_eq!(r["mask"], "local51-known-shape", "{method}");
        assert_eq!(shapes(&r), truth, "{method}: β must stay the truth");
        for f in r["frames"].as_array().expect("frames") {
            assert_eq!(f["shape_rms"], 0.0, "{method}");
            assert_eq!(f["shape_v2v_mm"], 0.0, "{method}");
        }
        assert_eq!(r["summary"]["mean_shape_v2v_mm"], 0.0, "{method}");
        // Single frames (the local scenario): no acceleration error.
        assert!(
            r["summary"].get("mean_accel_error_mm").is_none(),
            "{method}"
        );
    }
    // Without --known-shape LM moves β (so the equality above is the flag's doing), and the
    // rest-pose surface with it.
    let (o, out) = fit("lm", None, "lm-free.json");
    assert!(o.status.success());
    let free = read(&out);
    assert_ne!(shapes(&free), truth);
    for f in free["frames"].as_array().expect("frames") {
        let d = f["shape_v2v_mm"].as_f64().expect("shape_v2v_mm");
        assert!(d > 0.0 && d.is_finite(), "{d}");
    }
    // One β for every frame; a first entry below zero is a value, not a flag.
    let given = "-0.5,0.25,0,0,0,0,0,1";
    let (o, out) = fit("lm", Some(given), "lm-given.json");
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let want: Vec<f64> = given.split(',').map(|v| v.parse().unwrap()).collect();
    assert!(shapes(&read(&out)).iter().all(|s| *s == want));

    // The known-shape network refuses a fit that frees β; bad values are one-line errors.
    let (o, out) = fit("neural", None, "nn-free.json");
    assert_one_line_error(&o, "--known-shape");
    assert!(!out.exists());
    let (o, _) = fit("lm", Some("0.1,0.2"), "x.json");
    assert_one_line_error(&o, &format!("{B} shape parameters"));
    let (o, _) = fit("lm", Some("0.1,nan,0,0,0,0,0,0"), "x.json");
    assert_one_line_error(&o, "not a finite number");
    let (o, _) = fit("lm", Some("tall"), "x.json");
    assert_one_line_error(&o, "'tall'");
    let out = lfit(&[
        "-q",
        "fit",
        "--data",
        path_str(&data),
        "--method",
        "lbfgs",
        "--strategy",
        "shape-first",
        "--known-shape",
        "truth",
        "--budget",
        "50",
        "--out",
        path_str(&d.join("x.json")),
    ]);
    assert_one_line_error(&out, "shape-first");
    assert!(!d.join("x.json").exists());

    // A model without shape parameters: nothing to give, for fit and for training.
    let plain = d.join("plain.npz");
    lfit_json(&[
        "-q",
        "synth",
        "--modality",
        "hmd",
        "--frames",
        "2",
        "--out",
        path_str(&plain),
    ]);
    let out = lfit(&[
        "-q",
        "fit",
        "--data",
        path_str(&plain),
        "--method",
        "lm",
        "--known-shape",
        "truth",
        "--budget",
        "50",
        "--out",
        path_str(&d.join("x.json")),
    ]);
    assert_one_line_error(&out, "no shape parameters");
    let out = lfit(&[
        "-q",
        "train",
        "--config",
        path_str(&config),
        "--out",
        path_str(&d.join("t")),
        "--device",
        "ndarray",
    ]);
    assert_one_line_error(&out, "no shape parameters");
    assert!(!d.join("t").join("config.json").exists());

    // A bench with the known-shape checkpoint must give β.
    let bench_with = |known: bool, extra: &str, name: &str| {
        let toml = d.join(format!("bench-{name}.toml"));
        std::fs::write(
            &toml,
            format!(
                "name = \"k\"\ndata = \"{}\"\nmethods = [\"neural\", \"lm\"]\nbudgets = [50]\ncheckpoint = \"{}\"\nneural_start = \"given\"\nknown_shape = {known}\nframes = \"0-1\"\n{extra}",
                path_str(&data),
                path_str(&ck)
            ),
        )
        .expect("toml");
        lfit(&[
            "-q",
            "bench",
            "--config",
            path_str(&toml),
            "--out",
            path_str(&d.join(format!("b-{name}"))),
        ])
    };
    let bench = |known: bool| bench_with(known, "", &known.to_string());
    assert_one_line_error(&bench(false), "known_shape = true");
    // The network's runtime is a bench key too: native gives Burn's fits (to f32 rounding of the
    // network's outputs); an unknown one is refused before anything runs.
    assert_one_line_error(
        &bench_with(true, "runtime = \"cuda\"\n", "cuda"),
        "unknown runtime 'cuda'",
    );
    assert!(!d.join("b-cuda").join("runs.csv").exists());
    let o = bench_with(true, "runtime = \"native\"\n", "native");
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let o = bench(true);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let csv = std::fs::read_to_string(d.join("b-true/runs.csv")).expect("runs.csv");
    let header: Vec<&str> = csv.lines().next().expect("header").split(',').collect();
    let col = header
        .iter()
        .position(|h| *h == "shape_rms")
        .expect("shape_rms");
    let rows: Vec<&str> = csv.lines().skip(1).collect();
    assert_eq!(rows.len(), 4);
    // β given: the rest meshes agree too.
    let mesh = header
        .iter()
        .position(|h| *h == "shape_v2v_mm")
        .expect("shape_v2v_mm");
    for row in &rows {
        assert_eq!(row.split(',').nth(col), Some("0.00000"), "{row}");
        assert_eq!(row.split(',').nth(mesh), Some("0.0000"), "{row}");
    }
    let native = std::fs::read_to_string(d.join("b-native/runs.csv")).expect("runs.csv");
    let v2v = header.iter().position(|h| *h == "v2v_mm").expect("v2v_mm");
    let key = |row: &str| -> (String, String) {
        let f: Vec<&str> = row.split(',').collect();
        // The method column names the runtime ("neural-given-native"): compare by family.
        let family = f[0].split('-').next().unwrap_or_default().to_string();
        (family, f[4].to_string())
    };
    let mut compared = 0;
    for n in native.lines().skip(1) {
        let b = rows
            .iter()
            .find(|r| key(r) == key(n))
            .unwrap_or_else(|| panic!("no Burn row for {n}"));
        let (x, y): (f64, f64) = (
            n.split(',').nth(v2v).expect("v2v").parse().expect("number"),
            b.split(',').nth(v2v).expect("v2v").parse().expect("number"),
        );
        assert!((x - y).abs() < 1e-2, "native {n} vs burn {b}");
        compared += 1;
    }
    assert_eq!(compared, 4);

    // Re-running into the same directory resumes (nothing left to fit) only while the inputs
    // are the ones its rows were fitted with: a checkpoint changed in place (here its feature
    // statistics, rewritten with other bytes) is refused, the rows kept; restored, it resumes.
    let o = bench(true);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert_eq!(
        std::fs::read_to_string(d.join("b-true/runs.csv")).expect("runs.csv"),
        csv
    );
    let stats = ck.join("stats.json");
    let original = std::fs::read(&stats).expect("stats");
    let mut changed = original.clone();
    changed.extend_from_slice(b"\n");
    std::fs::write(&stats, &changed).expect("stats");
    assert_one_line_error(&bench(true), "other inputs (checkpoint changed since");
    assert_eq!(
        std::fs::read_to_string(d.join("b-true/runs.csv")).expect("runs.csv"),
        csv
    );
    std::fs::write(&stats, &original).expect("stats");
    let o = bench(true);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    // Rows of a build whose fitters were others under the same config (their names, e.g.
    // `neural+lm` before its LM stage kept to the observed entries) are refused as well.
    let record = d.join("b-true/inputs.json");
    let kept = std::fs::read(&record).expect("inputs.json");
    let mut inputs: serde_json::Value = serde_json::from_slice(&kept).expect("json");
    assert!(inputs["fitters"].is_string(), "{inputs}");
    inputs["fitters"] = serde_json::json!("0000000000000000");
    std::fs::write(&record, serde_json::to_vec(&inputs).expect("json")).expect("write");
    assert_one_line_error(&bench(true), "other inputs (fitters changed since");
    assert_eq!(
        std::fs::read_to_string(d.join("b-true/runs.csv")).expect("runs.csv"),
        csv
    );
    std::fs::write(&record, &kept).expect("restore");
    let o = bench(true);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
}

/// Writes to `data` 30 frames at 30 fps of the held-out CMU subject 6's first clip on the
/// MakeHuman body, keypoints2d seen by `configs/rigs/RIG.json`, drawn with `seed` (its β).
fn validation_sequence(data: &std::path::Path, rig: &str, seed: &str) {
    let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR"));
    support::synth_to(
        data,
        &root.join("models/makehuman-cmu_mb.npz"),
        &[
            "--modality",
            "keypoints2d",
            "--scenario",
            "sequence",
            "--frames",
            "30",
            "--fps",
            "30",
            "--seed",
            seed,
            "--motions",
            path_str(&root.join("data/motions/cmu/validation/006_01.npz")),
            "--camera",
            path_str(&root.join(format!("configs/rigs/{rig}.json"))),
        ],
    );
}

/// A β estimated per frame that runs to its box is reported: the summary's
/// `shape_at_bound_frames` counts the frames whose β has an entry at ±3 (checked here against
/// the rows), `shape_hint` and one warning line on stderr say how to fix β. One phone camera
/// (`configs/rigs/phone-1.json`) seeing 30 frames of the MakeHuman body's keypoints2d: LM with
/// the temporal anchor holding the root by 30 mm (`anchored:5,30`, round 33's default) lets size
/// and depth trade off until the box stops β (8 frames at this seed); the sequence's default pull
/// (`anchored:5`: 300 mm) lets the depth follow the subject and ends far closer; two cameras
/// (`tripods-2.json`) pin the size (none); with β given nothing is counted.
#[test]
fn a_shape_run_to_its_box_is_counted_and_hinted() {
    let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR"));
    let model = root.join("models/makehuman-cmu_mb.npz");
    let tmp = tempfile::tempdir().expect("tmp");
    // The tight pull of the translation that lets β run to its box on one camera.
    const TIGHT: &str = "anchored:5,30";
    let fit = |rig: &str, dofs: &str, extra: &[&str]| {
        let data = tmp.path().join(format!("{rig}.npz"));
        if !data.exists() {
            validation_sequence(&data, rig, "11");
        }
        let out = tmp.path().join("fit.json");
        let mut more = vec!["--template", path_str(&model), "--dofs", dofs];
        more.extend(extra);
        let args = support::lm_fit_args(&data, &out, "4000", &more);
        let run = lfit(&args);
        assert!(
            run.status.success(),
            "{rig}: {}",
            String::from_utf8_lossy(&run.stderr)
        );
        (
            read(&out),
            String::from_utf8_lossy(&run.stderr).into_owned(),
        )
    };
    let (phone, stderr) = fit("phone-1", TIGHT, &[]);
    let at_box = shapes(&phone)
        .iter()
        .filter(|b| b.iter().any(|v| v.abs() >= 3.0 - 1e-9))
        .count();
    let summary = &phone["summary"];
    assert!(at_box > 0, "{summary}");
    assert_eq!(summary["shape_at_bound_frames"], at_box, "{summary}");
    let hint = summary["shape_hint"].as_str().expect("a hint");
    assert!(
        hint.contains(&format!("in {at_box} of 30 frames"))
            && hint.contains("--known-shape height:M")
            && hint.contains("--floor contact:HEIGHT")
            && hint.contains("--sequence-shape joint:64"),
        "{hint}"
    );
    // With a floor given (one under every sole: the same fit) the hint does not suggest it again.
    let (floored, _) = fit("phone-1", TIGHT, &["--floor", "above:-1"]);
    assert_eq!(floored["summary"]["shape_at_bound_frames"], at_box);
    let again = floored["summary"]["shape_hint"].as_str().expect("a hint");
    assert!(
        !again.contains("--floor") && again.contains("--known-shape height:M"),
        "{again}"
    );
    let warnings: Vec<&str> = stderr
        .lines()
        .filter(|l| l.starts_with("warning:"))
        .collect();
    assert_eq!(warnings, [format!("warning: {hint}")], "{stderr}");
    let v2v = |r: &serde_json::Value| r["summary"]["mean_v2v_mm"].as_f64().expect("v2v");
    // The sequence's default pull on the translation lets the depth follow: under half the
    // tight pull's V2V, no more frames at the box.
    let (followed, _) = fit("phone-1", "anchored:5", &[]);
    assert!(
        v2v(&followed) < 0.5 * v2v(&phone),
        "anchored:5 {} mm, anchored:5,30 {} mm",
        v2v(&followed),
        v2v(&phone)
    );
    assert!(
        followed["summary"]["shape_at_bound_frames"].as_u64() <= Some(at_box as u64),
        "{}",
        followed["summary"]
    );
    // The price: the looser pull lets one camera's depth jitter, which the sequence's
    // acceleration error (mm per frame², against the truth's motion) shows — the tight pull's
    // is under the default's.
    let accel = |r: &serde_json::Value| r["summary"]["mean_accel_error_mm"].as_f64();
    let (tight_accel, loose_accel) = (accel(&phone).expect("a"), accel(&followed).expect("a"));
    assert!(
        tight_accel > 0.0 && tight_accel < 0.8 * loose_accel,
        "acceleration error {tight_accel} (30 mm) against {loose_accel} (default)"
    );

    let (two, stderr) = fit("tripods-2", TIGHT, &[]);
    assert_eq!(
        two["summary"]["shape_at_bound_frames"], 0,
        "{}",
        two["summary"]
    );
    assert!(two["summary"].get("shape_hint").is_none() && !stderr.contains("warning:"));

    let (given, stderr) = fit("phone-1", TIGHT, &["--known-shape", "truth"]);
    let summary = &given["summary"];
    assert!(
        summary.get("shape_at_bound_frames").is_none() && summary.get("shape_hint").is_none(),
        "{summary}"
    );
    assert!(!stderr.contains("warning:"), "{stderr}");

    // The subject's height instead of β (`--known-shape height:M`): the β of least norm that
    // tall, given to every frame and written to the result; it fixes the depth one camera
    // leaves open as β itself does, far closer than the per-frame β run to its box.
    let template = lfit::model::modelfile::load(&model).expect("model");
    let truth = lfit::synth::Dataset::load(&tmp.path().join("phone-1.npz")).expect("data");
    let shape = template.layout().range(lfit::model::layout::Block::Shape);
    let (height, ..) = lfit::model::stature::rest_height(&template, &truth.gt_poses[0][shape]);
    let (tall, stderr) = fit(
        "phone-1",
        TIGHT,
        &["--known-shape", &format!("height:{height}")],
    );
    let beta: Vec<f64> = tall["known_shape"]["beta"]
        .as_array()
        .expect("the β used")
        .iter()
        .map(|v| v.as_f64().expect("number"))
        .collect();
    assert_eq!(
        beta,
        lfit::model::stature::shape_for_height(&template, height).expect("β")
    );
    assert_eq!(tall["known_shape"]["height_m"], height);
    assert!(shapes(&tall).iter().all(|b| *b == beta));
    assert!((lfit::model::stature::rest_height(&template, &beta).0 - height).abs() < 1e-9);
    assert!(
        v2v(&tall) < 0.5 * v2v(&phone) && v2v(&tall) < 2.0 * v2v(&given),
        "height {} mm, per-frame β {} mm, β given {} mm",
        v2v(&tall),
        v2v(&phone),
        v2v(&given)
    );
    assert!(!stderr.contains("warning:"), "{stderr}");
    for (bad, want) in [
        ("height:0", "positive number of metres"),
        ("height:tall", "positive number of metres"),
        ("height:2.6", "out of reach"),
    ] {
        let (data, bad_out) = (tmp.path().join("phone-1.npz"), tmp.path().join("bad.json"));
        let more = ["--template", path_str(&model), "--known-shape", bad];
        let out = lfit(&support::lm_fit_args(&data, &bad_out, "10", &more));
        assert_one_line_error(&out, want);
        assert!(!tmp.path().join("bad.json").exists());
    }

    // The height as a soft measurement (`--height-prior M[:STD]`): β stays estimated in each
    // frame, its rest height held near M (every row's `rest_height_m` measured again from its
    // β), and the size one camera leaves open closes as with the height given; a wider STD
    // holds it less tightly.
    let heights = |r: &serde_json::Value| -> Vec<f64> {
        let got: Vec<f64> = r["frames"]
            .as_array()
            .expect("frames")
            .iter()
            .map(|f| f["rest_height_m"].as_f64().expect("rest_height_m"))
            .collect();
        for (h, b) in got.iter().zip(shapes(r)) {
            assert_eq!(*h, lfit::model::stature::rest_height(&template, &b).0);
        }
        got
    };
    let off = |hs: &[f64]| hs.iter().map(|h| (h - height).abs()).sum::<f64>() / hs.len() as f64;
    let (soft, stderr) = fit("phone-1", TIGHT, &["--height-prior", &height.to_string()]);
    assert_eq!(soft["height_prior"]["height_m"], height);
    assert_eq!(soft["height_prior"]["std_m"], 0.01);
    let held = heights(&soft);
    let mean = soft["summary"]["mean_rest_height_m"]
        .as_f64()
        .expect("mean");
    assert!((mean - held.iter().sum::<f64>() / 30.0).abs() < 1e-12);
    assert!(off(&held) < 0.02, "rest heights {held:?} against {height}");
    let betas = shapes(&soft);
    assert!(
        betas.iter().any(|b| *b != betas[0]),
        "β estimated per frame"
    );
    assert!(
        v2v(&soft) < 0.5 * v2v(&phone),
        "height prior {} mm, per-frame β {} mm",
        v2v(&soft),
        v2v(&phone)
    );
    let bound = |r: &serde_json::Value| r["summary"]["shape_at_bound_frames"].as_u64();
    assert!(bound(&soft) < bound(&phone), "{}", soft["summary"]);
    assert!(
        !stderr.contains("warning:") || bound(&soft) > Some(0),
        "{stderr}"
    );
    let (loose, _) = fit(
        "phone-1",
        TIGHT,
        &["--height-prior", &format!("{height}:0.05")],
    );
    assert_eq!(loose["height_prior"]["std_m"], 0.05);
    assert!(
        off(&heights(&loose)) > off(&held),
        "σ 5 cm holds less than 1 cm"
    );
    // A prior too wide to hold the size: the hint says so and asks for a tighter one or β.
    let (wide, stderr) = fit(
        "phone-1",
        TIGHT,
        &["--height-prior", &format!("{height}:1")],
    );
    assert!(bound(&wide) > Some(0), "{}", wide["summary"]);
    let hint = wide["summary"]["shape_hint"].as_str().expect("a hint");
    assert!(
        hint.contains("the height prior did not hold it")
            && hint.contains("a smaller --height-prior STD")
            && stderr.contains(hint),
        "{hint}"
    );
    for (bad, want) in [
        ("tall", "--height-prior 'tall'"),
        ("1.7:0", "positive numbers of metres"),
        ("0", "positive numbers of metres"),
    ] {
        let (data, bad_out) = (tmp.path().join("phone-1.npz"), tmp.path().join("bad.json"));
        let more = ["--template", path_str(&model), "--height-prior", bad];
        let out = lfit(&support::lm_fit_args(&data, &bad_out, "10", &more));
        assert_one_line_error(&out, want);
        assert!(!bad_out.exists());
    }
    let (data, bad_out) = (tmp.path().join("phone-1.npz"), tmp.path().join("bad.json"));
    let more = [
        "--template",
        path_str(&model),
        "--height-prior",
        "1.7",
        "--known-shape",
        "truth",
    ];
    let out = lfit(&support::lm_fit_args(&data, &bad_out, "10", &more));
    assert_one_line_error(&out, "use one");
    assert!(!bad_out.exists());
}

/// `--floor FORM:HEIGHT[,MM]` on one phone camera (the validation subject, 30 frames; at seed 12
/// LM anchored without a floor ends ~130 mm off, with it ~45): the
/// floor at `truth` is the median over the frames of the ground truth's lowest sole (measured here again from
/// the posed mesh); `contact` holds every frame's lowest sole on it and fixes the depth one
/// camera leaves open (V2V well under the fit without it); `above` keeps the soles off the
/// floor's underside; a floor below every sole changes nothing; bad forms refused with one line
/// and nothing written.
#[test]
fn a_floor_holds_the_soles_and_fixes_one_cameras_depth() {
    let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR"));
    let model = root.join("models/makehuman-cmu_mb.npz");
    let tmp = tempfile::tempdir().expect("tmp");
    let data = tmp.path().join("phone.npz");
    validation_sequence(&data, "phone-1", "12");
    let fit = |extra: &[&str]| {
        let out = tmp.path().join("fit.json");
        let mut more = vec!["--template", path_str(&model), "--dofs", "anchored:5"];
        more.extend(extra);
        let run = lfit(&support::lm_fit_args(&data, &out, "4000", &more));
        assert!(
            run.status.success(),
            "{extra:?}: {}",
            String::from_utf8_lossy(&run.stderr)
        );
        read(&out)
    };
    let v2v = |r: &serde_json::Value| r["summary"]["mean_v2v_mm"].as_f64().expect("v2v");
    let soles = |r: &serde_json::Value| -> Vec<f64> {
        r["frames"]
            .as_array()
            .expect("frames")
            .iter()
            .map(|f| f["lowest_sole_m"].as_f64().expect("lowest_sole_m"))
            .collect()
    };
    let template = lfit::model::modelfile::load(&model).expect("model");
    let truth = lfit::synth::Dataset::load(&data).expect("data");
    let candidates = lfit::model::energy::sole_vertices(&template);
    let mut lowest: Vec<f64> = truth
        .gt_poses
        .iter()
        .map(|gt| {
            let posed = lfit::model::skinning::pose_vertices(
                &template,
                gt,
                lfit::model::skinning::SkinningMethod::Linear,
            );
            candidates
                .iter()
                .map(|&v| f64::from(posed[v].y))
                .fold(f64::INFINITY, f64::min)
        })
        .collect();
    lowest.sort_by(f64::total_cmp);
    // 30 frames: the mean of the middle two.
    let lowest_true = 0.5 * (lowest[14] + lowest[15]);

    let plain = fit(&[]);
    assert!(plain.get("floor").is_none() && plain["summary"].get("mean_lowest_sole_m").is_none());
    let contact = fit(&["--floor", "contact:truth"]);
    let floor = &contact["floor"];
    assert_eq!(
        (&floor["form"], &floor["height_m"], &floor["std_m"]),
        (&"contact".into(), &"truth".into(), &0.02.into()),
        "{floor}"
    );
    let at = floor["at_m"].as_f64().expect("at_m");
    assert!((at - lowest_true).abs() < 1e-5, "{at} vs {lowest_true}");
    let held = soles(&contact);
    assert!(
        held.iter().all(|h| (h - at).abs() < 0.02),
        "{held:?} against {at}"
    );
    let mean = contact["summary"]["mean_lowest_sole_m"]
        .as_f64()
        .expect("mean");
    assert!((mean - held.iter().sum::<f64>() / held.len() as f64).abs() < 1e-12);
    assert!(
        v2v(&contact) < 0.5 * v2v(&plain),
        "contact {} mm, without {} mm",
        v2v(&contact),
        v2v(&plain)
    );
    // A floor under every sole: the term is zero, the fit the plain one.
    let under = fit(&["--floor", "above:-1"]);
    assert_eq!(v2v(&under), v2v(&plain));
    let above = fit(&["--floor", "above:truth,5"]);
    let (min_above, min_free) = (
        soles(&above).into_iter().fold(f64::INFINITY, f64::min),
        soles(&under).into_iter().fold(f64::INFINITY, f64::min),
    );
    assert!(
        min_free < at - 0.005 && min_above > min_free && min_above > at - 0.005,
        "lowest sole {min_above} (above the floor at {at}) vs {min_free} (free)"
    );
    for bad in [
        "contact",
        "down:0",
        "contact:0,-5",
        "contact:high",
        "above:inf",
    ] {
        let bad_out = tmp.path().join("bad.json");
        let more = ["--template", path_str(&model), "--floor", bad];
        let out = lfit(&support::lm_fit_args(&data, &bad_out, "10", &more));
        assert_one_line_error(&out, &format!("--floor '{bad}'"));
        assert!(!bad_out.exists());
    }
}
