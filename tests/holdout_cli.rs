//! `lfit fit --holdout`: observations left out of a fit and scored on it. The fit with markers (2D
//! keypoints of a camera) held out is the fit of the data without them, to the bit — for a
//! capture, the fit of the capture imported without those markers (its starts the rigid
//! alignment of what is left); the held-out error is the distance of the fit's prediction to
//! the observations it was not given; bad items are one-line errors that write nothing.

mod support;

use std::path::{Path, PathBuf};

use lfit::synth::capture::c3d::C3d;
use lfit::synth::{Dataset, Observations};
use serde_json::{Value, json};
use support::{assert_one_line_error, lfit, lfit_json, lm_fit_args, path_str};

/// `lfit synth` of noise-free frames of `modality` in the `local` scenario.
fn synth(dir: &Path, modality: &str, more: &[&str]) -> (PathBuf, Dataset) {
    let out = dir.join(format!("{modality}.npz"));
    let mut a = vec![
        "-q",
        "synth",
        "--modality",
        modality,
        "--scenario",
        "local",
        "--frames",
        "6",
        "--noise",
        "0",
        "--seed",
        "77",
        "--out",
        path_str(&out),
    ];
    a.extend(more);
    lfit_json(&a);
    (out.clone(), Dataset::load(&out).expect("dataset"))
}

/// [`lm_fit_args`] with 300 evaluations, run; the result document.
fn fit(data: &Path, out: &Path, more: &[&str]) -> Value {
    lfit_json(&lm_fit_args(data, out, "300", more));
    serde_json::from_slice(&std::fs::read(out).expect("result")).expect("JSON")
}

/// `data` with the observation groups `held` (marker k, or keypoint c·J + j) unseen and zero.
fn without(data: &Dataset, held: &[usize], group: usize) -> Dataset {
    let Observations::Sparse { values, visible } = &data.observations else {
        panic!("sparse");
    };
    let (mut values, mut visible) = (values.clone(), visible.clone());
    for (v, b) in values.iter_mut().zip(visible.iter_mut()) {
        for &g in held {
            v[g * group..(g + 1) * group].fill(0.0);
            b[g * group..(g + 1) * group].fill(false);
        }
    }
    Dataset {
        observations: Observations::Sparse { values, visible },
        ..data.clone()
    }
}

fn poses(doc: &Value) -> Vec<Value> {
    doc["frames"]
        .as_array()
        .expect("frames")
        .iter()
        .map(|f| json!([f["pose"], f["shape"], f["energy"]]))
        .collect()
}

/// The mean distance (mm, or px) of `pose`'s prediction by `data`'s sensor to the seen
/// observations of groups `held` in `frame`, computed here from the sensor's prediction.
fn held_error(
    data: &Dataset,
    frame: usize,
    pose: &[f64],
    held: &[usize],
    group: usize,
    scale: f64,
) -> f64 {
    let template = lfit::model::default_template();
    let pred = data.sensor.predict_sparse(&template, pose).values;
    let Observations::Sparse { values, visible } = &data.observations else {
        panic!("sparse");
    };
    let d: Vec<f64> = held
        .iter()
        .filter(|&&g| visible[frame][g * group])
        .map(|&g| {
            (0..group)
                .map(|a| (pred[g * group + a] - values[frame][g * group + a]).powi(2))
                .sum::<f64>()
                .sqrt()
                * scale
        })
        .collect();
    d.iter().sum::<f64>() / d.len() as f64
}

fn params(frame: &Value) -> Vec<f64> {
    let mut p: Vec<f64> = serde_json::from_value(frame["pose"].clone()).expect("pose");
    if let Some(shape) = frame.get("shape") {
        p.extend(serde_json::from_value::<Vec<f64>>(shape.clone()).expect("shape"));
    }
    p
}

#[test]
fn held_out_markers_are_left_out_of_the_fit_and_scored_on_it() {
    let tmp = tempfile::tempdir().expect("tmp");
    let d = tmp.path();
    let (data, truth) = synth(d, "markers", &[]);
    let names = match &truth.sensor {
        lfit::model::observe::Sensor::Markers(m) => m.names.clone(),
        _ => panic!("markers"),
    };
    let items = ["LFHD", "STRN", "RELB", "LKNE", "RANK"];
    let held: Vec<usize> = items
        .iter()
        .map(|n| names.iter().position(|m| m == n).expect("marker"))
        .collect();
    let with = fit(
        &data,
        &d.join("held.json"),
        &["--holdout", &items.join(",")],
    );
    // The fit is the fit of the data without those markers (with ground truth: same starts).
    let hidden = d.join("hidden.npz");
    without(&truth, &held, 3).save(&hidden).expect("save");
    let plain = fit(&hidden, &d.join("plain.json"), &[]);
    assert_eq!(poses(&with), poses(&plain));
    assert_eq!(with["holdout"], json!(items));
    // Each frame's held-out error is the distance of the fit's prediction to the markers it was
    // not given; noise-free, the pose the other 34 determine predicts them to a few mm.
    let frames = with["frames"].as_array().expect("frames");
    let mut sum = 0.0;
    for f in frames {
        let k = f["frame"].as_u64().expect("frame") as usize;
        let expect = held_error(&truth, k, &params(f), &held, 3, 1000.0);
        let got = f["holdout_error_mm"].as_f64().expect("holdout error");
        assert!(
            (got - expect).abs() <= 1e-9 * expect.max(1.0),
            "{got} against {expect}"
        );
        assert_eq!(f["holdout_seen"].as_u64(), Some(held.len() as u64));
        assert!(got < 10.0, "frame {k}: held-out error {got} mm");
        sum += got;
    }
    let mean = with["summary"]["mean_holdout_error_mm"]
        .as_f64()
        .expect("mean");
    assert!((mean - sum / frames.len() as f64).abs() < 1e-12);
    // Each marker's own mean over the frames that saw it, in the order asked for, computed
    // here from the sensor one marker at a time.
    let by_item = with["summary"]["holdout_by_item"]
        .as_array()
        .expect("holdout_by_item");
    assert_eq!(by_item.len(), items.len());
    let Observations::Sparse { visible, .. } = &truth.observations else {
        panic!("sparse");
    };
    for ((row, item), &g) in by_item.iter().zip(items).zip(&held) {
        let seen: Vec<&Value> = frames
            .iter()
            .filter(|f| visible[f["frame"].as_u64().expect("frame") as usize][3 * g])
            .collect();
        let expect = seen
            .iter()
            .map(|f| {
                let k = f["frame"].as_u64().expect("frame") as usize;
                held_error(&truth, k, &params(f), &[g], 3, 1000.0)
            })
            .sum::<f64>()
            / seen.len() as f64;
        assert_eq!(row["item"], json!(item));
        assert_eq!(row["seen"].as_u64(), Some(seen.len() as u64));
        let got = row["mean_error_mm"].as_f64().expect("item mean");
        assert!(
            (got - expect).abs() <= 1e-9 * expect.max(1.0),
            "{item}: {got} against {expect}"
        );
    }
    // Without --holdout, nothing of it.
    assert!(plain.get("holdout").is_none() && plain["frames"][0].get("holdout_error_mm").is_none());
}

#[test]
fn a_held_out_camera_is_left_out_and_scored_in_pixels() {
    let tmp = tempfile::tempdir().expect("tmp");
    let d = tmp.path();
    let (data, truth) = synth(d, "keypoints2d", &["--cameras", "3"]);
    let nj = lfit::model::default_template().rig.num_joints();
    let held: Vec<usize> = (2 * nj..3 * nj).collect();
    let with = fit(&data, &d.join("held.json"), &["--holdout", "camera:2"]);
    let hidden = d.join("hidden.npz");
    without(&truth, &held, 2).save(&hidden).expect("save");
    let plain = fit(&hidden, &d.join("plain.json"), &[]);
    assert_eq!(poses(&with), poses(&plain));
    for f in with["frames"].as_array().expect("frames") {
        let k = f["frame"].as_u64().expect("frame") as usize;
        let expect = held_error(&truth, k, &params(f), &held, 2, 1.0);
        let got = f["holdout_error_px"].as_f64().expect("holdout error");
        assert!(
            (got - expect).abs() <= 1e-9 * expect.max(1.0),
            "{got} against {expect}"
        );
    }
    assert!(with["summary"]["mean_holdout_error_px"].as_f64().is_some());
    // The camera's item: every seen keypoint of it in every frame, one mean.
    let Observations::Sparse { visible, .. } = &truth.observations else {
        panic!("sparse");
    };
    let (mut sum, mut seen) = (0.0, 0usize);
    for f in with["frames"].as_array().expect("frames") {
        let k = f["frame"].as_u64().expect("frame") as usize;
        for &g in held.iter().filter(|&&g| visible[k][2 * g]) {
            sum += held_error(&truth, k, &params(f), &[g], 2, 1.0);
            seen += 1;
        }
    }
    let row = &with["summary"]["holdout_by_item"][0];
    assert_eq!(row["item"], json!("camera:2"));
    assert_eq!(row["seen"].as_u64(), Some(seen as u64));
    let got = row["mean_error_px"].as_f64().expect("camera mean");
    assert!(
        (got - sum / seen as f64).abs() <= 1e-9 * got.max(1.0),
        "{got}"
    );
}

#[test]
fn a_capture_with_markers_held_out_fits_as_its_import_without_them() {
    let tmp = tempfile::tempdir().expect("tmp");
    let d = tmp.path();
    let (data, _) = synth(d, "markers", &[]);
    let c3d = d.join("capture.c3d");
    support::export_c3d(&data, &c3d);
    let file = C3d::read(&c3d).expect("C3D");
    let held = ["C7", "LWRA", "RTHI", "LTOE"];
    let import = |out: &Path, labels: Vec<&String>| {
        let map: serde_json::Map<String, Value> =
            labels.into_iter().map(|l| (l.clone(), json!(l))).collect();
        let map_file = d.join("map.json");
        std::fs::write(&map_file, Value::Object(map).to_string()).expect("map");
        support::import_c3d_with(&c3d, out, &["--label-map", path_str(&map_file)]);
    };
    let all = d.join("all.npz");
    import(&all, file.labels.iter().collect());
    let fewer = d.join("fewer.npz");
    import(
        &fewer,
        file.labels
            .iter()
            .filter(|l| !held.contains(&l.as_str()))
            .collect(),
    );
    let with = fit(&all, &d.join("held.json"), &["--holdout", &held.join(",")]);
    let plain = fit(&fewer, &d.join("plain.json"), &[]);
    // The starts too: the rigid alignment of the markers that are left, not of all of them.
    assert_eq!(poses(&with), poses(&plain));
    let imported = Dataset::load(&all).expect("imported");
    let names = match &imported.sensor {
        lfit::model::observe::Sensor::Markers(m) => m.names.clone(),
        _ => panic!("markers"),
    };
    let idx: Vec<usize> = held
        .iter()
        .map(|n| names.iter().position(|m| m == n).expect("marker"))
        .collect();
    for f in with["frames"].as_array().expect("frames") {
        let k = f["frame"].as_u64().expect("frame") as usize;
        let expect = held_error(&imported, k, &params(f), &idx, 3, 1000.0);
        let got = f["holdout_error_mm"].as_f64().expect("holdout error");
        assert!(
            (got - expect).abs() <= 1e-9 * expect.max(1.0),
            "{got} against {expect}"
        );
        // The fitted markers' distance leaves the held-out ones out.
        assert!(
            f["observations_seen"].as_u64().expect("seen") <= (names.len() - held.len()) as u64
        );
    }
}

#[test]
fn bad_holdout_items_are_one_line_errors_that_write_nothing() {
    let tmp = tempfile::tempdir().expect("tmp");
    let d = tmp.path();
    let (markers, truth) = synth(d, "markers", &[]);
    let (keypoints, _) = synth(d, "keypoints2d", &["--cameras", "2"]);
    let (hmd, _) = synth(d, "hmd", &[]);
    let all = match &truth.sensor {
        lfit::model::observe::Sensor::Markers(m) => m.names.join(","),
        _ => panic!("markers"),
    };
    let out = d.join("never.json");
    for (data, items, needle) in [
        (&markers, "LFHD,NOPE", "'NOPE' is not a marker of the data"),
        (&markers, "LFHD,LFHD", "'LFHD' is named twice"),
        (&markers, ",", "no markers, cameras or keypoints named"),
        (&markers, all.as_str(), "leaves nothing seen to fit"),
        (&keypoints, "camera:2", "the data has 2 camera(s)"),
        (&keypoints, "camera:x", "camera:K needs a camera index"),
        (&keypoints, "Elbow", "is neither camera:K nor a joint"),
        (&hmd, "LFHD", "the data's modality is hmd"),
    ] {
        let o = lfit(&lm_fit_args(data, &out, "20", &["--holdout", items]));
        assert_one_line_error(&o, needle);
        assert!(!out.exists(), "{items}: nothing is written");
    }
}
