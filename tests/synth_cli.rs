//! `lfit synth` end to end: determinism, seeds, and that the file holds what the observation
//! models predict for the ground-truth poses.

mod support;

use lfit::model::default_template;
use lfit::model::observe::Sensor;
use lfit::synth::{Dataset, Observations};
use support::{lfit_json, path_str};

fn synth(
    dir: &std::path::Path,
    name: &str,
    modality: &str,
    scenario: &str,
    frames: &str,
    seed: &str,
    extra: &[&str],
) -> std::path::PathBuf {
    let out = dir.join(name);
    let mut args = vec![
        "synth",
        "--quiet",
        "--modality",
        modality,
        "--scenario",
        scenario,
        "--frames",
        frames,
        "--seed",
        seed,
        "--out",
        path_str(&out),
    ];
    args.extend_from_slice(extra);
    let summary = lfit_json(&args);
    assert_eq!(summary["frames"].as_u64().unwrap().to_string(), frames);
    out
}

#[test]
fn same_seed_same_bytes_other_seed_other_data() {
    let dir = tempfile::tempdir().unwrap();
    for (modality, scenario) in [
        ("markers", "local"),
        ("keypoints2d", "global"),
        ("hmd", "sequence"),
        ("scan", "local"),
    ] {
        let frames = if modality == "scan" { "2" } else { "12" };
        let a = synth(
            dir.path(),
            &format!("{modality}_a.npz"),
            modality,
            scenario,
            frames,
            "7",
            &[],
        );
        let b = synth(
            dir.path(),
            &format!("{modality}_b.npz"),
            modality,
            scenario,
            frames,
            "7",
            &["--threads", "1"],
        );
        let c = synth(
            dir.path(),
            &format!("{modality}_c.npz"),
            modality,
            scenario,
            frames,
            "8",
            &[],
        );
        let (a, b, c) = (
            std::fs::read(a).unwrap(),
            std::fs::read(b).unwrap(),
            std::fs::read(c).unwrap(),
        );
        assert_eq!(
            a, b,
            "{modality}: same seed must give identical bytes (any thread count)"
        );
        assert_ne!(a, c, "{modality}: another seed must give other data");
        let (da, dc) = (
            Dataset::from_npz(&a).unwrap(),
            Dataset::from_npz(&c).unwrap(),
        );
        assert_ne!(da.gt_poses, dc.gt_poses);
    }
}

#[test]
fn noise_free_sparse_observations_equal_the_observation_model_of_the_ground_truth() {
    let dir = tempfile::tempdir().unwrap();
    let template = default_template();
    for (modality, scenario) in [
        ("markers", "local"),
        ("keypoints2d", "sequence"),
        ("hmd", "global"),
    ] {
        let path = synth(
            dir.path(),
            &format!("{modality}.npz"),
            modality,
            scenario,
            "9",
            "3",
            &["--noise", "0"],
        );
        let data = Dataset::load(&path).unwrap();
        assert_eq!(data.len(), 9);
        assert_eq!(data.meta.config.seed, 3);
        assert_eq!(data.meta.template_id, "default");
        let sensor = Sensor::default_for(data.modality(), &template);
        assert_eq!(data.sensor, sensor);
        let Observations::Sparse { values, visible } = &data.observations else {
            panic!("sparse")
        };
        for (i, pose) in data.gt_poses.iter().enumerate() {
            let pred = sensor.predict_sparse(&template, pose);
            assert_eq!(values[i].len(), sensor.residual_dim(&template));
            assert_eq!(
                visible[i], pred.visible,
                "{modality} frame {i}: visibility is the geometric one"
            );
            for (k, (o, p)) in values[i].iter().zip(&pred.values).enumerate() {
                let expect = if pred.visible[k] { *p } else { 0.0 };
                assert!(
                    (o - expect).abs() < 1e-12,
                    "{modality} frame {i} entry {k}: {o} vs {expect}"
                );
            }
        }
    }
}

#[test]
fn noisy_observations_differ_from_the_model_by_about_the_noise() {
    let dir = tempfile::tempdir().unwrap();
    let template = default_template();
    let path = synth(dir.path(), "m.npz", "markers", "local", "20", "11", &[]);
    let data = Dataset::load(&path).unwrap();
    let sensor = Sensor::default_for(data.modality(), &template);
    let Observations::Sparse { values, visible } = &data.observations else {
        panic!("sparse")
    };
    let mut sq = Vec::new();
    let mut hidden = 0;
    for (i, pose) in data.gt_poses.iter().enumerate() {
        let pred = sensor.predict_sparse(&template, pose);
        for k in 0..values[i].len() {
            if visible[i][k] {
                sq.push((values[i][k] - pred.values[k]).abs());
            } else {
                hidden += 1;
            }
        }
    }
    sq.sort_by(f64::total_cmp);
    let median = sq[sq.len() / 2];
    // Median |N(0, 5 mm)| is 3.4 mm.
    assert!(
        (0.002..0.005).contains(&median),
        "median deviation {median}"
    );
    assert!(hidden > 0, "5 % of markers are dropped");
}

#[test]
fn scan_dataset_holds_points_distance_transform_and_silhouettes() {
    let dir = tempfile::tempdir().unwrap();
    let template = default_template();
    let path = synth(
        dir.path(),
        "scan.npz",
        "scan",
        "global",
        "2",
        "5",
        &["--noise", "0"],
    );
    let data = Dataset::load(&path).unwrap();
    let sensor = Sensor::default_for(data.modality(), &template);
    let Observations::Scan {
        points,
        visible,
        grids,
        silhouettes,
    } = &data.observations
    else {
        panic!("scan")
    };
    for (i, pose) in data.gt_poses.iter().enumerate() {
        let pred = sensor.predict_scan(&template, pose).unwrap();
        assert_eq!(
            points[i], pred.vertices,
            "noise-free points are the posed vertices"
        );
        assert!(visible[i].iter().all(|&b| b), "no holes without noise");
        for (m, p) in silhouettes[i].iter().zip(&pred.silhouettes) {
            assert_eq!(m.data, p.data);
        }
        // The distance transform is ~0 at the points and grows away from them.
        let g = &grids[i];
        let at = pred.vertices[100].as_dvec3();
        assert!(g.sample(at) < 4e-4, "S at a surface point {}", g.sample(at));
        let far = at + glam::DVec3::new(0.0, 0.0, 0.3);
        assert!(g.sample_extrapolated(far) > g.sample(at));
    }
}
