//! `lfit quickstart` and `lfit ablate` end to end, at tiny sizes.

mod support;

use support::{
    assert_one_line_error, lfit, lfit_json, mocapbank_clip, path_str, skip_unless_required,
};

#[test]
fn quickstart_compares_every_method_on_every_sparse_modality() {
    let tmp = tempfile::tempdir().expect("tmp");
    let out_dir = tmp.path().join("qs");
    let out = lfit(&[
        "-q",
        "quickstart",
        "--out",
        path_str(&out_dir),
        "--frames",
        "3",
        "--budget",
        "60",
    ]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let table = String::from_utf8_lossy(&out.stdout);
    // The default study subject is the MakeHuman body, with its own fitters; hmd is given β.
    assert!(table.starts_with("Model: makehuman-cmu_mb.npz."), "{table}");
    for m in ["markers", "keypoints2d", "hmd"] {
        for method in [
            "| neural (checkpoints/MOD-makehuman, N = 5) |",
            "| neural+lm (checkpoints/MOD-makehuman, then LM) @60 |",
            "| lbfgs @60 |",
            "| lm @60 |",
            "| cma @60 |",
            "| pso @60 |",
        ] {
            let method = method.replace("MOD", m);
            let row = table
                .lines()
                .find(|l| l.starts_with(&format!("| {m} (3 frames) |")) && l.contains(&method));
            let Some(row) = row else {
                panic!("{m} {method}:\n{table}")
            };
            // Columns: data, method, V2V, MPJPE, PA-MPJPE, shape RMS, energy, evaluations, time.
            let cells: Vec<&str> = row.split('|').map(str::trim).collect();
            let shape = cells[6];
            if m == "hmd" {
                assert_eq!(shape, "given", "{row}");
            } else {
                assert!(shape.parse::<f64>().is_ok_and(|v| v > 0.0), "{row}");
            }
            for c in &cells[3..6] {
                assert!(c.parse::<f64>().is_ok_and(f64::is_finite), "{row}");
            }
        }
        // LM with the pose prior of the CMU training clips, at the modality's default weight
        // (none for hmd: no weight helped there).
        let w = if m == "keypoints2d" { "0.001" } else { "0.01" };
        let want = format!("| {m} (3 frames) | lm + pose prior (CMU train, weight {w}) @60 |");
        let prior = out_dir.join(format!("{m}-prior"));
        if m == "hmd" {
            assert!(!table.contains("| hmd (3 frames) | lm + pose prior") && !prior.exists());
        } else {
            assert!(
                table.lines().any(|l| l.starts_with(&want)),
                "{want}:\n{table}"
            );
            let nlm = format!(
                "| {m} (3 frames) | neural+lm (checkpoints/{m}-makehuman, then LM) + pose prior (CMU train, weight {w}) @60 |"
            );
            assert!(
                table.lines().any(|l| l.starts_with(&nlm)),
                "{nlm}:\n{table}"
            );
            let csv =
                std::fs::read_to_string(out_dir.join(format!("{m}-prior/runs.csv"))).expect("csv");
            assert_eq!(csv.lines().count(), 1 + 2 * 3);
        }
        // The network stopped after its first 3 iterations: its own part, one run per frame at
        // 6 evaluations.
        let early =
            format!("| {m} (3 frames) | neural (checkpoints/{m}-makehuman, first 3 iterations) |");
        let row = table.lines().find(|l| l.starts_with(&early));
        let Some(row) = row else {
            panic!("{early}:\n{table}")
        };
        let cells: Vec<&str> = row.split('|').map(str::trim).collect();
        assert_eq!(cells[8], "6", "{row}");
        let csv =
            std::fs::read_to_string(out_dir.join(format!("{m}-early/runs.csv"))).expect("csv");
        assert_eq!(csv.lines().count(), 1 + 3);
        let dir = out_dir.join(m);
        let md = std::fs::read_to_string(dir.join("report.md")).expect("report");
        assert!(md.contains("papers/002 Table 2"), "{md}");
        let csv = std::fs::read_to_string(dir.join("runs.csv")).expect("csv");
        assert_eq!(csv.lines().count(), 1 + 6 * 3);
        assert!(
            dir.join("plots/energy_vs_evaluations.svg").exists()
                && dir.join("plots/energy_vs_evaluations.png").exists()
        );
        assert!(dir.join("plots/neural_error_per_iteration.png").exists());
        // Best, median and worst frame of every method, rendered and linked (src/render).
        for method in ["neural", "neural+lm", "lbfgs", "lm", "cma", "pso"] {
            // File names are the method's slug (`neural+lm` -> `neural-lm.png`).
            let file = method.replace('+', "-");
            assert!(
                md.contains(&format!("](pictures/{file}.png)"))
                    && dir.join(format!("pictures/{file}.png")).is_file(),
                "{m}: no picture of {method}"
            );
        }
    }
    // The keypoints2d frames seen by one phone camera (configs/rigs/phone-1.json): every method,
    // the prior and early-exit twins, one camera in the data.
    for method in [
        "neural (checkpoints/keypoints2d-makehuman, N = 5)",
        "neural+lm (checkpoints/keypoints2d-makehuman, then LM) @60",
        "lm @60",
        "cma @60",
        "lm + pose prior (CMU train, weight 0.001) @60",
        "neural (checkpoints/keypoints2d-makehuman, first 3 iterations)",
    ] {
        let want = format!("| keypoints2d, one phone camera (3 frames) | {method} |");
        assert!(
            table.lines().any(|l| l.starts_with(&want)),
            "{want}:\n{table}"
        );
    }
    let phone = lfit::synth::Dataset::load(&out_dir.join("keypoints2d-phone/data.npz"))
        .expect("phone data");
    let rig = lfit::synth::capture::keypoints::read_cameras(
        &std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("configs/rigs/phone-1.json"),
    )
    .expect("rig");
    assert_eq!(phone.sensor.cameras(), &rig[..]);
    assert!(!out_dir.join("markers-phone").exists() && !out_dir.join("hmd-phone").exists());
    // The phone frames again with each subject's height as a prior, and again with the floor
    // the subjects stand on as a measurement (the lowest sole in contact): the network,
    // neural+lm and LM, on the same data, each fit another (its energy has the extra row); each
    // twin's bench.json has its key and not the other's.
    let cell = |row: &str, i: usize| row.split('|').map(str::trim).nth(i).map(str::to_string);
    for (part, label, key, value, other) in [
        (
            "height",
            "the subject's height as a prior (--height-prior truth)",
            "height_prior",
            "truth",
            "floor",
        ),
        (
            "floor",
            "the floor as a measurement (--floor contact:truth)",
            "floor",
            "contact:truth",
            "height_prior",
        ),
    ] {
        for method in [
            "neural (checkpoints/keypoints2d-makehuman, N = 5)",
            "neural+lm (checkpoints/keypoints2d-makehuman, then LM) @60",
            "lm @60",
        ] {
            let plain = format!("| keypoints2d, one phone camera (3 frames) | {method} |");
            let want = format!("| keypoints2d, one phone camera (3 frames) | {method}, {label} |");
            let Some(row) = table.lines().find(|l| l.starts_with(&want)) else {
                panic!("{want}:\n{table}")
            };
            let base = table
                .lines()
                .find(|l| l.starts_with(&plain))
                .expect("the row without");
            assert_ne!(cell(row, 7), cell(base, 7), "{row}\n{base}");
        }
        let dir = out_dir.join(format!("keypoints2d-phone-{part}"));
        let csv = std::fs::read_to_string(dir.join("runs.csv")).expect("csv");
        assert_eq!(csv.lines().count(), 1 + 3 * 3);
        assert_eq!(
            std::fs::read(dir.join("data.npz")).expect("data"),
            std::fs::read(out_dir.join("keypoints2d-phone/data.npz")).expect("data"),
            "the same frames"
        );
        let bench: serde_json::Value =
            serde_json::from_slice(&std::fs::read(dir.join("bench.json")).expect("bench"))
                .expect("json");
        assert_eq!(bench[key], value);
        assert!(bench.get(other).is_none(), "{part}: {bench}");
    }
    assert_eq!(
        std::fs::read_to_string(out_dir.join("comparison.md"))
            .expect("comparison")
            .trim(),
        table.trim()
    );
    let out = lfit(&[
        "-q",
        "quickstart",
        "--out",
        path_str(&tmp.path().join("z")),
        "--frames",
        "0",
    ]);
    assert_one_line_error(&out, "--frames");
}

#[test]
fn quickstart_repeats_markers_and_keypoints_on_a_captured_clip() {
    let Some(clip) = mocapbank_clip() else {
        return skip_unless_required(
            "the MocapBank clip is not fetched (scripts/fetch-mocapbank.sh, LFIT_MOCAPBANK_BVH)",
            Some("LFIT_MOCAPBANK_BVH"),
        );
    };
    let tmp = tempfile::tempdir().expect("tmp");
    let out_dir = tmp.path().join("qs");
    let out = lfit(&[
        "-q",
        "quickstart",
        "--out",
        path_str(&out_dir),
        "--frames",
        "2",
        "--budget",
        "40",
        "--clip",
        path_str(&clip),
        "--clip-frames",
        "4",
    ]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let table = String::from_utf8_lossy(&out.stdout);
    for m in ["markers", "keypoints2d"] {
        for method in [
            "neural (checkpoints/MOD-makehuman, N = 5)",
            "neural (checkpoints/MOD-makehuman, first 3 iterations)",
            "lbfgs @40",
            "lm @40",
            "cma @40",
            "pso @40",
            "lm + pose prior (CMU train, weight W) @40",
            "neural+lm (checkpoints/MOD-makehuman, then LM) + pose prior (CMU train, weight W) @40",
            "lm anchored at the previous frame (--dofs anchored:D) @40",
            "neural (checkpoints/SEQ, N = 5) anchored at the previous frame (--dofs observed:30+anchored:D)",
        ] {
            // The sequence network of each sensor (lfit::cli::commands::sequence_network).
            let seq = if m == "markers" {
                "markers-makehuman-chord2-sequence"
            } else {
                "keypoints2d-makehuman-sequence"
            };
            let w = if m == "keypoints2d" { "0.001" } else { "0.01" };
            let d = if m == "keypoints2d" { "5" } else { "4" };
            let want = format!(
                "| {m}, captured clip (4 frames) | {} |",
                method
                    .replace("MOD", m)
                    .replace("SEQ", seq)
                    .replace(" W)", &format!(" {w})"))
                    .replace(":D)", &format!(":{d})"))
            );
            assert!(
                table.lines().any(|l| l.starts_with(&want)),
                "{want}:\n{table}"
            );
        }
        // A sequence over the clip's frames 1..=4, every method on every frame.
        let dir = out_dir.join(format!("{m}-clip"));
        let data =
            lfit::synth::Dataset::from_npz(&std::fs::read(dir.join("data.npz")).expect("data"))
                .expect("dataset");
        assert_eq!(data.len(), 4);
        assert_eq!(data.meta.config.scenario.to_string(), "sequence");
        assert!(
            data.meta
                .frame_motions
                .iter()
                .all(|f| f.contains("clip-motion")),
            "{:?}",
            data.meta.frame_motions
        );
        let csv = std::fs::read_to_string(dir.join("runs.csv")).expect("csv");
        assert_eq!(csv.lines().count(), 1 + 6 * 4);
        // One subject, one β (`joint:64`): each method's β error and rest-mesh shape error are
        // the same in every frame of the clip, the shape error a positive number of mm (β is
        // estimated).
        let header: Vec<&str> = csv.lines().next().expect("header").split(',').collect();
        let col = |name: &str| header.iter().position(|h| *h == name).expect(name);
        let (method, shape, mesh) = (col("method"), col("shape_rms"), col("shape_v2v_mm"));
        let mut by_method: std::collections::BTreeMap<String, Vec<(String, String)>> =
            Default::default();
        for line in csv.lines().skip(1) {
            let cells: Vec<&str> = line.split(',').collect();
            by_method
                .entry(cells[method].to_string())
                .or_default()
                .push((cells[shape].to_string(), cells[mesh].to_string()));
        }
        assert_eq!(by_method.len(), 6);
        for (name, rows) in &by_method {
            assert!(
                rows.windows(2).all(|w| w[0] == w[1]),
                "{m} {name}: {rows:?}"
            );
            let mm: f64 = rows[0].1.parse().expect("shape_v2v_mm");
            assert!(mm > 0.0 && mm < 200.0, "{m} {name}: {mm}");
        }
    }
    // The temporally anchored LM: one part per clip, LM alone, its fitter the anchored one; its
    // sequence is not LM's (the pull changes the fits).
    for (m, d) in [("markers", "4"), ("keypoints2d", "5")] {
        let dir = out_dir.join(format!("{m}-clip-anchored"));
        let csv = std::fs::read_to_string(dir.join("runs.csv")).expect("csv");
        assert_eq!(csv.lines().count(), 1 + 4, "{m}");
        let config = std::fs::read_to_string(dir.join("bench.json")).expect("bench.json");
        assert!(config.contains(&format!("anchored:{d}")), "{config}");
        let energy = |csv: &str| -> Vec<String> {
            let header: Vec<&str> = csv.lines().next().expect("header").split(',').collect();
            let (mc, ec) = (
                header.iter().position(|h| *h == "method").expect("method"),
                header.iter().position(|h| *h == "energy").expect("energy"),
            );
            csv.lines()
                .skip(1)
                .map(|l| l.split(',').collect::<Vec<_>>())
                .filter(|c| c[mc] == "lm")
                .map(|c| c[ec].to_string())
                .collect()
        };
        let plain =
            std::fs::read_to_string(out_dir.join(format!("{m}-clip/runs.csv"))).expect("csv");
        assert_eq!(energy(&csv).len(), 4);
        assert_ne!(
            energy(&csv),
            energy(&plain),
            "{m}: the anchor changed nothing"
        );
    }
    // The network fine-tuned on the anchor: one part per clip, the network alone from the
    // previous frame's fit on the anchored energy with what the data leave held.
    for (m, d, seq) in [
        ("markers", "4", "markers-makehuman-chord2-sequence"),
        ("keypoints2d", "5", "keypoints2d-makehuman-sequence"),
    ] {
        let dir = out_dir.join(format!("{m}-clip-anchored-sequence-net"));
        let csv = std::fs::read_to_string(dir.join("runs.csv")).expect("csv");
        assert_eq!(csv.lines().count(), 1 + 4, "{m}");
        let config = std::fs::read_to_string(dir.join("bench.json")).expect("bench.json");
        assert!(
            config.contains(&format!("observed:30+anchored:{d}")) && config.contains(seq),
            "{config}"
        );
    }
    assert!(!out_dir.join("markers-sequence-net").exists());
    assert!(!out_dir.join("markers-clip-sequence-net").exists());
    assert!(!out_dir.join("markers-clip-prior-anchored").exists());
    assert!(!out_dir.join("markers-clip-early-anchored").exists());
    assert!(!out_dir.join("markers-anchored").exists());
    assert!(!table.contains("hmd, captured clip"));
    // A clip that is not there: one line, before any fit.
    let out = lfit(&[
        "-q",
        "quickstart",
        "--out",
        path_str(&tmp.path().join("z")),
        "--frames",
        "1",
        "--clip",
        path_str(&tmp.path().join("missing.bvh")),
    ]);
    assert_one_line_error(&out, "missing.bvh");
}

#[test]
fn ablate_trains_each_variant_once_and_writes_the_papers_tables() {
    let tmp = tempfile::tempdir().expect("tmp");
    let out_dir = tmp.path().join("abl");
    let args = [
        "-q",
        "ablate",
        "--out",
        path_str(&out_dir),
        "--steps",
        "2",
        "--batch",
        "4",
        "--hidden",
        "8",
        "--test-frames",
        "6",
        "--device",
        "ndarray",
        "--only",
        "hmd-base,hmd-delta-only,kp-vl-sg-separate",
    ];
    let summary = lfit_json(&args);
    assert_eq!(summary["variants"], 3);
    let md = std::fs::read_to_string(out_dir.join("ablation.md")).expect("md");
    for needle in [
        "Table 5 (HMD)",
        "| +Δθn |",
        "| +Eq. 1 |",
        "| Shared |",
        "Table A.1",
        "| ✓ | ✗ | ✗ |",
        "2 steps × batch 4",
    ] {
        assert!(md.contains(needle), "{needle}:\n{md}");
    }
    assert!(
        !md.contains("| ResNet |"),
        "only the variants run have rows"
    );
    let json: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out_dir.join("ablation.json")).expect("json"))
            .expect("json");
    let v = json["variants"].as_array().expect("variants");
    assert_eq!(v.len(), 3);
    // Δθ-only has no λ/γ network, so fewer parameters than the base.
    let params = |name: &str| {
        v.iter()
            .find(|e| e["variant"] == name)
            .and_then(|e| e["parameters"].as_u64())
            .expect("parameters")
    };
    assert!(params("hmd-delta-only") < params("hmd-base"));
    // A re-run trains nothing: the weights are untouched.
    let weights = out_dir.join("hmd-base/weights.bpk");
    let before = std::fs::metadata(&weights)
        .and_then(|m| m.modified())
        .expect("mtime");
    lfit_json(&args);
    assert_eq!(
        std::fs::metadata(&weights)
            .and_then(|m| m.modified())
            .expect("mtime"),
        before
    );
    // Another size in the same directory, or an unknown variant, is refused.
    let mut other = args.to_vec();
    other[5] = "3";
    assert_one_line_error(&lfit(&other), "another size");
    let out = lfit(&[
        "-q",
        "ablate",
        "--out",
        path_str(&tmp.path().join("x")),
        "--only",
        "hmd-bogus",
    ]);
    assert_one_line_error(&out, "unknown variant 'hmd-bogus'");
    let bad_device = tmp.path().join("dev");
    assert_one_line_error(
        &lfit(&[
            "-q",
            "ablate",
            "--out",
            path_str(&bad_device),
            "--device",
            "tpu",
        ]),
        "tpu",
    );
    assert!(
        !bad_device.exists(),
        "nothing is written before the arguments are valid"
    );
}
