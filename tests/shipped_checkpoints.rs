//! The checkpoints shipped in `checkpoints/`: one per sparse modality on the default template and
//! on the committed MakeHuman body (its `hmd` fitter given β, papers/002 §3.2), each at most
//! 10 MB, with config, weights, statistics and a metrics card, loading on their model and fitting
//! held-out frames well below their start error.

mod support;

use std::path::Path;

use support::{lfit_json, path_str};

/// Checkpoint directory, modality, model file (`None`: the default template).
const CHECKPOINTS: [(&str, &str, Option<&str>); 6] = [
    ("markers", "markers", None),
    ("keypoints2d", "keypoints2d", None),
    ("hmd", "hmd", None),
    (
        "markers-makehuman",
        "markers",
        Some("models/makehuman-cmu_mb.npz"),
    ),
    (
        "keypoints2d-makehuman",
        "keypoints2d",
        Some("models/makehuman-cmu_mb.npz"),
    ),
    ("hmd-makehuman", "hmd", Some("models/makehuman-cmu_mb.npz")),
];

#[test]
fn every_shipped_checkpoint_is_complete_small_and_fits_its_modality() {
    let tmp = tempfile::tempdir().expect("tmp");
    for (name, modality, model) in CHECKPOINTS {
        let m = name;
        let dir = Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("checkpoints")
            .join(name);
        let model = model.map(|f| Path::new(env!("CARGO_MANIFEST_DIR")).join(f));
        let template: Vec<&str> = match &model {
            Some(f) => vec!["--template", path_str(f)],
            None => Vec::new(),
        };
        for f in [
            "config.json",
            "weights.bpk",
            "stats.json",
            "metrics.json",
            "train.json",
        ] {
            assert!(dir.join(f).is_file(), "{m}/{f} is missing");
        }
        // The whole checkpoint directory, every file counted once, is at most 10 MB.
        let size: u64 = std::fs::read_dir(&dir)
            .expect("dir")
            .flatten()
            .map(|e| e.metadata().map(|x| x.len()).unwrap_or(0))
            .sum();
        assert!(size <= 10_000_000, "{m}: {size} bytes");
        let weights = std::fs::metadata(dir.join("weights.bpk"))
            .expect("weights")
            .len();
        assert!(
            weights <= 10_000_000,
            "{m}: weights {weights} bytes > 10 MB"
        );
        let card: serde_json::Value =
            serde_json::from_slice(&std::fs::read(dir.join("metrics.json")).expect("card"))
                .expect("json");
        for key in ["command", "seed", "steps", "time_s", "device", "validation"] {
            assert!(!card[key].is_null(), "{m}: metrics card lacks {key}");
        }
        let v2v = card["validation"]["v2v_mm"].as_array().expect("v2v");
        assert_eq!(v2v.len(), 6, "{m}: N = 5 iterations plus θ0");
        let config: serde_json::Value =
            serde_json::from_slice(&std::fs::read(dir.join("config.json")).expect("config"))
                .expect("json");
        // The MakeHuman hmd fitter is the one given β (the others estimate it, or have none).
        let known = config["network"]["known_shape"] == true;
        assert_eq!(known, name == "hmd-makehuman", "{m}: known_shape");

        // Held-out frames (a seed no training run uses): the fit from the start pose ends far
        // below the start error.
        let data = tmp.path().join(format!("{m}.npz"));
        let mut args = vec![
            "-q",
            "synth",
            "--modality",
            modality,
            "--frames",
            "24",
            "--seed",
            "9100",
            "--out",
            path_str(&data),
        ];
        args.extend(&template);
        lfit_json(&args);
        let out = tmp.path().join(format!("{m}.json"));
        let mut args = vec![
            "-q",
            "fit",
            "--data",
            path_str(&data),
            "--method",
            "neural",
            "--neural-start",
            "given",
            "--checkpoint",
            path_str(&dir),
            "--budget",
            "10",
            "--out",
            path_str(&out),
        ];
        args.extend(&template);
        if known {
            args.extend(["--known-shape", "truth"]);
        }
        lfit_json(&args);
        let r: serde_json::Value =
            serde_json::from_slice(&std::fs::read(&out).expect("result")).expect("json");
        let frames = r["frames"].as_array().expect("frames");
        let mean = |k: usize| {
            frames
                .iter()
                .map(|f| f["v2v_mm_per_iteration"][k].as_f64().expect("v2v"))
                .sum::<f64>()
                / frames.len() as f64
        };
        let (start, end) = (mean(0), mean(5));
        eprintln!("{m}: V2V {start:.1} mm at the start pose -> {end:.1} mm after 5 iterations");
        assert!(
            end < 0.7 * start,
            "{m}: the shipped fitter must cut V2V by 30 %: {start:.1} -> {end:.1}"
        );
    }
}
