//! Shape recovery on the morphable default template (8 PCA shape directions): noise-free
//! `markers` frames with random β ~ N(0, I) and random local-scenario poses, fitted by L-BFGS
//! with β free from the mean shape. The fit must reach sub-millimetre V2V and recover β far
//! below the prior's own error (the RMS of β itself, ≈ 1).

mod support;

use support::{lfit_json, path_str};

#[test]
fn lbfgs_with_shape_free_recovers_pose_and_shape_from_markers() {
    let dir = tempfile::tempdir().unwrap();
    let data = dir.path().join("m.npz");
    lfit_json(&["synth", "--modality", "markers", "--scenario", "local", "--shape", "morphable", "--noise", "0", "--frames", "6", "--seed", "4", "--out", path_str(&data)]);
    let out = dir.path().join("r.json");
    lfit_json(&["fit", "--data", path_str(&data), "--method", "lbfgs", "--budget", "1500", "--out", path_str(&out)]);
    let r: serde_json::Value = serde_json::from_slice(&std::fs::read(&out).unwrap()).unwrap();
    assert_eq!(r["mask"], "local51", "43 pose DOFs and 8 shape coefficients are free");
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
    let v2v = r["summary"]["mean_v2v_mm"].as_f64().unwrap();
    let shape = r["summary"]["mean_shape_rms"].as_f64().unwrap();
    println!("L-BFGS, β free, 6 noise-free markers frames: mean V2V {v2v:.3} mm, mean β RMS error {shape:.4} (prior: {prior_rms:.3})");
    assert!(v2v <= 1.0, "mean V2V {v2v} mm");
    assert!(shape <= prior_rms / 10.0, "β RMS error {shape} vs the prior's {prior_rms}");
}
