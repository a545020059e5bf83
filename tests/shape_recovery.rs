//! Shape recovery on the morphable default template (8 PCA shape directions): noise-free
//! `markers` frames with random β ~ N(0, I) and random local-scenario poses, fitted by L-BFGS
//! with β free from the mean shape, in two stages (`--strategy shape-first`: translation and β
//! with the pose at its start, then everything). Fitting everything at once from the mean shape
//! stops in local minima on more frames (root height, body height and joints pressed against
//! the ±15° local box trade off for a tall subject): on 200 frames 91 reach ≤ 1 mm holistically,
//! 116 shape-first. The test asserts the median V2V, the share of frames within 1 mm and the
//! median β error, and prints every frame.

mod support;

use support::{lfit_json, path_str};

#[test]
fn lbfgs_with_shape_free_recovers_pose_and_shape_from_markers() {
    let dir = tempfile::tempdir().unwrap();
    let data = dir.path().join("m.npz");
    lfit_json(&[
        "synth",
        "--modality",
        "markers",
        "--scenario",
        "local",
        "--shape",
        "morphable",
        "--noise",
        "0",
        "--frames",
        "10",
        "--seed",
        "4",
        "--out",
        path_str(&data),
    ]);
    let out = dir.path().join("r.json");
    lfit_json(&[
        "fit",
        "--data",
        path_str(&data),
        "--method",
        "lbfgs",
        "--strategy",
        "shape-first",
        "--budget",
        "1500",
        "--out",
        path_str(&out),
    ]);
    let r: serde_json::Value = serde_json::from_slice(&std::fs::read(&out).unwrap()).unwrap();
    assert_eq!(
        r["mask"], "local51",
        "43 pose DOFs and 8 shape coefficients are free"
    );
    let frames = r["frames"].as_array().unwrap();
    let mut prior_rms = 0.0;
    for f in frames {
        assert_eq!(f["shape"].as_array().unwrap().len(), 8);
        assert_eq!(f["pose"].as_array().unwrap().len(), 57);
    }
    // The prior's error: fitting nothing leaves β at 0, off by the RMS of the true β.
    let npz = std::fs::read(&data).unwrap();
    let dataset = lfit::synth::Dataset::from_npz(&npz).unwrap();
    for gt in &dataset.gt_poses {
        prior_rms += (gt[57..].iter().map(|b| b * b).sum::<f64>() / 8.0).sqrt();
    }
    prior_rms /= dataset.len() as f64;
    let mut v2v: Vec<f64> = frames
        .iter()
        .map(|f| f["v2v_mm"].as_f64().unwrap())
        .collect();
    let mut shape: Vec<f64> = frames
        .iter()
        .map(|f| f["shape_rms"].as_f64().unwrap())
        .collect();
    println!(
        "per frame (V2V mm, β RMS error): {:?}",
        v2v.iter()
            .zip(&shape)
            .map(|(a, b)| (format!("{a:.2}"), format!("{b:.3}")))
            .collect::<Vec<_>>()
    );
    let good = v2v.iter().filter(|&&v| v <= 1.0).count();
    v2v.sort_by(f64::total_cmp);
    shape.sort_by(f64::total_cmp);
    let (mv, ms) = (v2v[v2v.len() / 2], shape[shape.len() / 2]);
    println!(
        "L-BFGS, β free, {} noise-free markers frames: median V2V {mv:.3} mm, {good} frames ≤ 1 mm; median β RMS error {ms:.4} (prior: {prior_rms:.3})",
        v2v.len()
    );
    assert!(mv <= 1.0, "median V2V {mv} mm");
    assert!(good >= 6, "{good} of {} frames within 1 mm", v2v.len());
    assert!(
        ms <= prior_rms / 5.0,
        "median β RMS error {ms} vs the prior's {prior_rms}"
    );
    // Where the fit converges, β is recovered: at least 5× below the prior's error.
    for f in frames
        .iter()
        .filter(|f| f["v2v_mm"].as_f64().unwrap() <= 1.0)
    {
        let e = f["shape_rms"].as_f64().unwrap();
        assert!(
            e <= prior_rms / 5.0,
            "frame {}: β RMS error {e} vs the prior's {prior_rms}",
            f["frame"]
        );
    }
}

#[test]
fn the_shipped_morphable_markers_fitter_estimates_shape_three_times_better_than_the_prior() {
    let dir = tempfile::tempdir().unwrap();
    let data = dir.path().join("m.npz");
    lfit_json(&[
        "synth",
        "--modality",
        "markers",
        "--scenario",
        "local",
        "--shape",
        "morphable",
        "--noise",
        "0",
        "--frames",
        "48",
        "--seed",
        "77",
        "--out",
        path_str(&data),
    ]);
    let ckpt =
        std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("checkpoints/markers-morphable");
    let npz = std::fs::read(&data).unwrap();
    let dataset = lfit::synth::Dataset::from_npz(&npz).unwrap();
    let prior: f64 = dataset
        .gt_poses
        .iter()
        .map(|g| (g[57..].iter().map(|b| b * b).sum::<f64>() / 8.0).sqrt())
        .sum::<f64>()
        / dataset.len() as f64;
    for start in ["phi", "given"] {
        let out = dir.path().join(format!("{start}.json"));
        let s = lfit_json(&[
            "fit",
            "--data",
            path_str(&data),
            "--method",
            "neural",
            "--neural-start",
            start,
            "--checkpoint",
            path_str(&ckpt),
            "--device",
            "ndarray",
            "--budget",
            "10",
            "--batch",
            "48",
            "--out",
            path_str(&out),
        ]);
        let shape = s["summary"]["mean_shape_rms"].as_f64().unwrap();
        let v2v = s["summary"]["mean_v2v_mm"].as_f64().unwrap();
        println!(
            "shipped markers-morphable, start {start}: β RMS error {shape:.3} vs the prior's {prior:.3} ({:.1}× lower), V2V {v2v:.1} mm",
            prior / shape
        );
        assert!(
            shape * 3.0 <= prior,
            "{start}: β RMS error {shape} vs the prior's {prior}"
        );
    }
}
