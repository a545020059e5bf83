//! `lfit data import` end to end: a C3D file and COCO keypoint files written by the test from
//! known observations (those of `lfit synth` frames) import to the same values; LM and the
//! shipped neural fitters then fit the imported datasets, which have no ground truth, and report
//! energies and observation errors instead of V2V/MPJPE; bad input is a one-line error and
//! writes nothing.

mod support;

use std::path::{Path, PathBuf};

use lfit::synth::capture::c3d::{C3d, C3dPoint, Processor};
use lfit::synth::capture::keypoints::{COCO17, Distortion, KeypointLayout, cameras_json};
use lfit::synth::capture::trc::to_trc;
use lfit::synth::{Dataset, Observations};
use serde_json::{Value, json};
use support::{assert_one_line_error, lfit, lfit_json, lm_fit_args, path_str};

fn synth(dir: &Path, modality: &str, frames: usize, seed: u64) -> (PathBuf, Dataset) {
    synth_in(dir, modality, "sequence", frames, seed)
}

/// `lfit synth` of noise-free frames of `modality` in `scenario` into `DIR/<modality>.npz`.
fn synth_in(
    dir: &Path,
    modality: &str,
    scenario: &str,
    frames: usize,
    seed: u64,
) -> (PathBuf, Dataset) {
    let out = dir.join(format!("{modality}.npz"));
    lfit_json(&[
        "-q",
        "synth",
        "--modality",
        modality,
        "--scenario",
        scenario,
        "--frames",
        &frames.to_string(),
        "--noise",
        "0",
        "--seed",
        &seed.to_string(),
        "--out",
        path_str(&out),
    ]);
    let d = Dataset::load(&out).expect("synth dataset");
    (out, d)
}

fn sparse(d: &Dataset) -> (&Vec<Vec<f64>>, &Vec<Vec<bool>>) {
    match &d.observations {
        Observations::Sparse { values, visible } => (values, visible),
        _ => panic!("sparse observations expected"),
    }
}

/// Borrowed argument strings.
fn args(a: &[String]) -> Vec<&str> {
    a.iter().map(String::as_str).collect()
}

fn read_json(p: &Path) -> Value {
    serde_json::from_slice(&std::fs::read(p).expect("result file")).expect("JSON")
}

fn checkpoint(name: &str) -> String {
    format!("{}/checkpoints/{name}", env!("CARGO_MANIFEST_DIR"))
}

/// Fits `data` with LM and the shipped neural fitter `ck`; checks the no-ground-truth contract
/// and returns per method (LM, neural) the mean energy, the mean observation error and the last
/// frame's and the first frame's observation errors (the sequence starts from the rigidly placed
/// rest pose, searched in the global box around it; every later frame from the previous fit).
fn fit_both(dir: &Path, data: &Path, ck: &str, unit: &str) -> [[f64; 4]; 2] {
    let mut out = [[0.0; 4]; 2];
    for (i, method) in ["lm", "neural"].into_iter().enumerate() {
        let res = dir.join(format!("{method}_{ck}.json"));
        let mut args = vec![
            "-q",
            "fit",
            "--data",
            path_str(data),
            "--method",
            method,
            "--out",
            path_str(&res),
        ];
        let ck_dir = checkpoint(ck);
        if method == "neural" {
            args.extend([
                "--checkpoint",
                &ck_dir,
                "--budget",
                "10",
                "--device",
                "ndarray",
            ]);
        } else {
            args.extend(["--budget", "100"]);
        }
        let summary = lfit_json(&args);
        let r = read_json(&res);
        assert_eq!(r["ground_truth"], false);
        assert_eq!(summary["summary"]["ground_truth"], false);
        assert!(summary["summary"].get("mean_v2v_mm").is_none());
        let key = format!("observation_error_{unit}");
        let frames = r["frames"].as_array().expect("frames");
        for f in frames {
            assert!(
                f.get("v2v_mm").is_none()
                    && f.get("mpjpe_mm").is_none()
                    && f.get("pa_mpjpe_mm").is_none()
            );
            let e = f["energy"].as_f64().expect("energy");
            let s = f["start_energy"].as_f64().expect("start energy");
            let o = f[&key].as_f64().expect("observation error");
            assert!(e.is_finite() && o.is_finite() && e >= 0.0, "{f}");
            if method == "lm" {
                assert!(e <= s, "LM never ends above its start: {e} > {s}");
            } else {
                let per = f["energy_per_iteration"].as_array().expect("per iteration");
                assert!(per.len() >= 2);
                assert!(per.iter().all(|x| x.as_f64().is_some_and(f64::is_finite)));
            }
        }
        let per_frame: Vec<String> = frames
            .iter()
            .map(|f| format!("{:.2}", f[&key].as_f64().unwrap_or(f64::NAN)))
            .collect();
        eprintln!("{ck} {method}: {key} per frame [{}]", per_frame.join(", "));
        let mean = summary["summary"]["mean_energy"].as_f64().expect("mean");
        let obs = summary["summary"][format!("mean_observation_error_{unit}")]
            .as_f64()
            .expect("mean observation error");
        eprintln!(
            "{ck} {method}: mean energy {mean:.4}, mean observation error {obs:.3} {unit} over {} frames",
            frames.len()
        );
        let last = frames
            .last()
            .and_then(|f| f[&key].as_f64())
            .expect("last frame");
        let first = frames[0][&key].as_f64().expect("first frame");
        out[i] = [mean, obs, last, first];
    }
    out
}

/// A C3D file of a markers dataset's observations: labels `S1:<marker>` plus an unmapped
/// `EXTRA` point, millimetres, the given scale (negative: floats), one gap.
fn c3d_of(d: &Dataset, scale: f64) -> (C3d, Vec<(String, String)>) {
    let names = match &d.sensor {
        lfit::model::observe::Sensor::Markers(m) => m.names.clone(),
        _ => panic!("markers"),
    };
    let (values, visible) = sparse(d);
    let mut labels: Vec<String> = names.iter().map(|n| format!("S1:{n}")).collect();
    labels.push("EXTRA".into());
    let frames = values
        .iter()
        .zip(visible)
        .enumerate()
        .map(|(f, (v, b))| {
            let mut row: Vec<Option<C3dPoint>> = (0..names.len())
                .map(|k| {
                    (b[3 * k] && !(f == 2 && k == 5)).then(|| C3dPoint {
                        position: [v[3 * k] * 1e3, v[3 * k + 1] * 1e3, v[3 * k + 2] * 1e3],
                        residual: 0.4,
                        cameras: 6,
                    })
                })
                .collect();
            row.push(Some(C3dPoint {
                position: [1.0, 2.0, 3.0],
                residual: 0.0,
                cameras: 1,
            }));
            row
        })
        .collect();
    let map = names
        .iter()
        .map(|n| (format!("S1:{n}"), n.clone()))
        .collect();
    (
        C3d {
            processor: Processor::Intel,
            labels,
            units: "mm".into(),
            scale,
            rate: 120.0,
            first_frame: 1,
            analog_per_frame: 0,
            frames,
            non_finite: 0,
        },
        map,
    )
}

/// `lfit data import --c3d FILE --label-map MAP --out OUT`; its JSON summary.
fn import_c3d(file: &Path, map: &Path, out: &Path) -> Value {
    support::import_c3d_with(file, out, &["--label-map", path_str(map)])
}

fn write_map(path: &Path, map: &[(String, String)]) {
    let obj: serde_json::Map<String, Value> =
        map.iter().map(|(a, b)| (a.clone(), json!(b))).collect();
    std::fs::write(path, Value::Object(obj).to_string()).expect("map");
}

#[test]
fn c3d_markers_import_exactly_and_fit_with_lm_and_the_neural_fitter() {
    let tmp = tempfile::tempdir().expect("tmp");
    let d = tmp.path();
    let (_, truth) = synth(d, "markers", 8, 41);
    let (c3d, map) = c3d_of(&truth, -0.1);
    let file = d.join("capture.c3d");
    std::fs::write(&file, c3d.to_bytes().expect("C3D bytes")).expect("write");
    let map_file = d.join("labels.json");
    write_map(&map_file, &map);
    let out = d.join("imported.npz");
    let summary = import_c3d(&file, &map_file, &out);
    assert_eq!(summary["ground_truth"], false);
    assert_eq!(summary["frames"], 8);
    assert_eq!(summary["import"]["ignored_c3d_labels"], json!(["EXTRA"]));

    let imported = Dataset::load(&out).expect("imported dataset");
    assert!(!imported.has_ground_truth());
    assert_eq!(imported.meta.config.fps, 120.0);
    let (tv, tb) = sparse(&truth);
    let (iv, ib) = sparse(&imported);
    let mut max_err: f64 = 0.0;
    for f in 0..tv.len() {
        for k in 0..tv[f].len() / 3 {
            let gap = f == 2 && k == 5;
            assert_eq!(ib[f][3 * k], tb[f][3 * k] && !gap, "frame {f} marker {k}");
            if ib[f][3 * k] {
                for a in 0..3 {
                    max_err = max_err.max((iv[f][3 * k + a] - tv[f][3 * k + a]).abs());
                }
            }
        }
    }
    eprintln!("C3D (float) import: max coordinate error {max_err:.3e} m");
    assert!(max_err <= 1e-6, "imported positions differ by {max_err} m");

    // Integer points: within half a quantisation step (0.1 mm scale → 0.05 mm).
    let (c3d_int, _) = c3d_of(&truth, 0.1);
    let file_int = d.join("capture_int.c3d");
    std::fs::write(&file_int, c3d_int.to_bytes().expect("C3D bytes")).expect("write");
    let out_int = d.join("imported_int.npz");
    import_c3d(&file_int, &map_file, &out_int);
    let int = Dataset::load(&out_int).expect("imported");
    let (jv, jb) = sparse(&int);
    let mut max_int: f64 = 0.0;
    for f in 0..tv.len() {
        for i in 0..tv[f].len() {
            if jb[f][i] {
                max_int = max_int.max((jv[f][i] - tv[f][i]).abs());
            }
        }
    }
    eprintln!("C3D (integer, 0.1 mm) import: max coordinate error {max_int:.3e} m");
    assert!(max_int <= 5.1e-5);

    // The same points as an OpenSim TRC file (`--trc`): the C3D import's dataset to the bit; the
    // summary says which format; `--label-map` without a marker file and both files refused.
    let trc = d.join("capture.trc");
    // (Written from the C3D as read: its float points are f32.)
    let as_read = C3d::read(&file).expect("C3D");
    std::fs::write(&trc, to_trc(&as_read, "capture.trc")).expect("write");
    let out_trc = d.join("imported_trc.npz");
    assert_eq!(summary["import"]["format"], "c3d");
    let t = lfit_json(&[
        "-q",
        "data",
        "import",
        "--trc",
        path_str(&trc),
        "--label-map",
        path_str(&map_file),
        "--out",
        path_str(&out_trc),
    ]);
    assert_eq!(t["import"]["format"], "trc");
    assert!(t["import"].get("point_format").is_none());
    assert_eq!(t["source"]["trc"], path_str(&trc));
    assert_eq!(t["import"]["map"], summary["import"]["map"]);
    let from_trc = Dataset::load(&out_trc).expect("imported");
    assert_eq!(sparse(&from_trc), sparse(&imported));
    assert_eq!(from_trc.start_poses, imported.start_poses);
    for (extra, needle) in [
        (
            vec!["--trc", path_str(&trc), "--c3d", path_str(&file)],
            "cannot be used with",
        ),
        (
            vec!["--label-map", path_str(&map_file)],
            "--label-map maps a marker file's labels",
        ),
        (
            vec!["--trc", path_str(&trc), "--camera-names", "a"],
            "cannot be used with",
        ),
        (
            vec!["--c3d", path_str(&file), "--camera-units", "mm"],
            "cannot be used with",
        ),
    ] {
        let never = d.join("never.npz");
        let mut a = vec!["data", "import", "--out", path_str(&never)];
        a.extend(extra);
        let o = lfit(&a);
        assert_one_line_error(&o, needle);
        assert!(!never.exists());
    }
    // A TRC's errors speak of its labels, not of a C3D's.
    let bad_map = d.join("bad-trc-map.json");
    write_map(&bad_map, &[("NOSUCH".into(), map[0].1.clone())]);
    let o = lfit(&[
        "data",
        "import",
        "--trc",
        path_str(&trc),
        "--label-map",
        path_str(&bad_map),
        "--out",
        path_str(&d.join("never.npz")),
    ]);
    assert_one_line_error(&o, "label map: label 'NOSUCH' is not in the file");
    let text = String::from_utf8_lossy(&o.stderr);
    assert!(text.contains("TRC file") && !text.contains("C3D"), "{text}");

    let [lm, nn] = fit_both(d, &out, "markers", "mm");
    // Noise-free markers: LM explains them to under a mm, from the first frame on (its start the
    // rigidly placed rest pose; in the sequence box around it the first frames were centimetres
    // off and the sequence caught up over several frames).
    assert!(
        lm[2] < 1.0 && lm[3] < 1.0,
        "LM marker error on the last frame {} mm, on the first {} mm",
        lm[2],
        lm[3]
    );
    assert!(
        nn[2] < 10.0,
        "neural marker error on the last frame {} mm",
        nn[2]
    );

    // lfit bench refuses a dataset without ground truth.
    let cfg = d.join("bench.toml");
    std::fs::write(
        &cfg,
        format!(
            "name = \"imported\"\ndata = \"{}\"\nmethods = [\"lm\"]\nbudgets = [10]\n",
            path_str(&out)
        ),
    )
    .expect("config");
    let b = lfit(&[
        "-q",
        "bench",
        "--config",
        path_str(&cfg),
        "--out",
        path_str(&d.join("bench")),
    ]);
    assert_one_line_error(&b, "no ground truth");
}

/// COCO keypoint files, one per camera, from a keypoints2d dataset's observations.
fn coco_files(dir: &Path, d: &Dataset, nj: usize) -> Vec<PathBuf> {
    let (values, visible) = sparse(d);
    let layout = KeypointLayout::Coco17;
    let map = layout.default_map();
    let cams = d.sensor.cameras();
    (0..cams.len())
        .map(|c| {
            let images: Vec<Value> = (0..values.len())
                .map(|f| json!({"id": 100 + f, "width": cams[c].width, "height": cams[c].height, "file_name": format!("c{c}_{f:04}.png")}))
                .collect();
            let annotations: Vec<Value> = (0..values.len())
                .map(|f| {
                    let mut kp = vec![0.0; 3 * COCO17.len()];
                    for &(j, name) in &map {
                        let i = 2 * (c * nj + j);
                        let k = layout.index(name).expect("keypoint");
                        if visible[f][i] {
                            kp[3 * k..3 * k + 3].copy_from_slice(&[values[f][i], values[f][i + 1], 2.0]);
                        }
                    }
                    json!({"id": f + 1, "image_id": 100 + f, "category_id": 1, "keypoints": kp, "num_keypoints": 12})
                })
                .collect();
            let p = dir.join(format!("cam{c}.json"));
            std::fs::write(
                &p,
                json!({"images": images, "annotations": annotations, "categories": [{"id": 1, "name": "person"}]}).to_string(),
            )
            .expect("coco file");
            p
        })
        .collect()
}

#[test]
fn coco_keypoints_import_exactly_and_fit_with_lm_and_the_neural_fitter() {
    let tmp = tempfile::tempdir().expect("tmp");
    let d = tmp.path();
    let (_, truth) = synth(d, "keypoints2d", 6, 43);
    let nj = 18;
    let files = coco_files(d, &truth, nj);
    let cams = d.join("cameras.json");
    std::fs::write(&cams, cameras_json(truth.sensor.cameras())).expect("cameras");
    let out = d.join("kp.npz");
    // `lfit data import` of the COCO files `kps` seen by the camera file `cams` into `out`.
    let run = |cams: &Path, out: &Path, extra: &[&str], kps: &[PathBuf]| {
        let mut args = vec!["-q", "data", "import", "--layout", "coco17", "--camera"];
        args.extend([path_str(cams), "--out", path_str(out)]);
        args.extend(extra);
        args.push("--keypoints");
        args.extend(kps.iter().map(|f| path_str(f)));
        lfit(&args)
    };
    // The same, expected to succeed: its summary; `import` of the six cameras' files.
    let import_files = |cams: &Path, out: &Path, extra: &[&str], kps: &[PathBuf]| -> Value {
        let o = run(cams, out, extra, kps);
        assert!(
            o.status.success(),
            "lfit data import failed: {}",
            String::from_utf8_lossy(&o.stderr)
        );
        serde_json::from_slice(&o.stdout).expect("stdout is JSON")
    };
    let import = |cams: &Path, out: &Path, extra: &[&str]| import_files(cams, out, extra, &files);
    let summary = import(&cams, &out, &[]);
    assert_eq!(summary["modality"], "keypoints2d");
    assert_eq!(summary["import"]["cameras"], 6);
    let imported = Dataset::load(&out).expect("imported");
    assert!(!imported.has_ground_truth());
    assert_eq!(imported.sensor.cameras(), truth.sensor.cameras());
    let (tv, tb) = sparse(&truth);
    let (iv, ib) = sparse(&imported);
    let mapped: Vec<usize> = KeypointLayout::Coco17
        .default_map()
        .iter()
        .map(|m| m.0)
        .collect();
    let mut max_err: f64 = 0.0;
    let mut seen = 0;
    for f in 0..tv.len() {
        for c in 0..6 {
            for j in 0..nj {
                let i = 2 * (c * nj + j);
                let expect = tb[f][i] && mapped.contains(&j);
                assert_eq!(ib[f][i], expect, "frame {f} camera {c} joint {j}");
                if expect {
                    seen += 1;
                    max_err = max_err
                        .max((iv[f][i] - tv[f][i]).abs())
                        .max((iv[f][i + 1] - tv[f][i + 1]).abs());
                }
            }
        }
    }
    eprintln!("COCO import: {seen} keypoints, max pixel error {max_err:.3e} px");
    assert!(seen > 0 && max_err <= 1e-9);
    // The same keypoints written as fractions of the image (MediaPipe's x / W) and as OpenPose's
    // --keypoint_scale 3 and 4, imported with --keypoint-scale: the pixel import's keypoints.
    let scaled_import = |scale: &str, to: &dyn Fn(f64, f64) -> f64, extra: &[&str]| {
        let dir = d.join(format!("scale-{scale}"));
        std::fs::create_dir_all(&dir).expect("dir");
        let mut kps = Vec::new();
        for (c, f) in files.iter().enumerate() {
            let mut coco = read_json(f);
            let cam = &truth.sensor.cameras()[c];
            let (w, h) = (f64::from(cam.width), f64::from(cam.height));
            for a in coco["annotations"].as_array_mut().expect("annotations") {
                for p in a["keypoints"]
                    .as_array_mut()
                    .expect("keypoints")
                    .chunks_exact_mut(3)
                {
                    if p[2].as_f64().expect("v") > 0.0 {
                        p[0] = json!(to(p[0].as_f64().expect("x"), w));
                        p[1] = json!(to(p[1].as_f64().expect("y"), h));
                    }
                }
            }
            let file = dir.join(format!("cam{c}.json"));
            std::fs::write(&file, coco.to_string()).expect("coco");
            kps.push(file);
        }
        run(&cams, &dir.join("kp.npz"), extra, &kps)
    };
    let forms: [(&str, &dyn Fn(f64, f64) -> f64); 3] = [
        ("image", &|x, w| x / w),
        ("openpose3", &|x, w| x / (w - 1.0)),
        ("openpose4", &|x, w| 2.0 * x / (w - 1.0) - 1.0),
    ];
    for (scale, to) in forms {
        let ran = scaled_import(scale, to, &["--keypoint-scale", scale]);
        assert!(
            ran.status.success(),
            "{}",
            String::from_utf8_lossy(&ran.stderr)
        );
        let summary: Value = serde_json::from_slice(&ran.stdout).expect("summary");
        assert_eq!(summary["source"]["keypoint_scale"], scale);
        let back = Dataset::load(&d.join(format!("scale-{scale}/kp.npz"))).expect("imported");
        let ((bv, bb), (iv, ib)) = (sparse(&back), sparse(&imported));
        assert_eq!(bb, ib);
        for (b, i) in bv.iter().flatten().zip(iv.iter().flatten()) {
            assert!((b - i).abs() < 1e-9, "{scale}: {b} vs {i} px");
        }
    }
    // Read as pixels they are refused, naming the option; an unknown scale is one line.
    let as_pixels = scaled_import("openpose4", &|x, w| 2.0 * x / (w - 1.0) - 1.0, &[]);
    assert_one_line_error(&as_pixels, "--keypoint-scale image|openpose3|openpose4");
    let bad = scaled_import("image", &|x, w| x / w, &["--keypoint-scale", "percent"]);
    assert_one_line_error(
        &bad,
        "--keypoint-scale percent: expected pixels, image, openpose3 or openpose4",
    );
    // The six cameras inside a CMU Panoptic calibration file (translations in centimetres,
    // `distCoef` all zeros, in reverse order among three VGA cameras the keypoints are not
    // from), chosen with `--camera-names` in the keypoints' order: the same dataset.
    let ring = lfit::model::camera::default_ring(3);
    let panoptic = |c: &lfit::model::camera::Camera, name: String, kind: &str| {
        json!({
            "name": name, "type": kind, "panel": 0, "node": 0,
            "resolution": [c.width, c.height],
            "K": [[c.fx, 0.0, c.cx], [0.0, c.fy, c.cy], [0.0, 0.0, 1.0]],
            "distCoef": [0.0, 0.0, 0.0, 0.0, 0.0],
            "R": c.rotation, "t": c.translation.map(|x| [x * 100.0]),
        })
    };
    let mut list = vec![panoptic(&ring[0], "01_01".into(), "vga")];
    for (c, cam) in truth.sensor.cameras().iter().enumerate().rev() {
        list.push(panoptic(cam, format!("00_{:02}", 3 * c), "hd"));
    }
    list.extend([1, 2].map(|k| panoptic(&ring[k], format!("0{k}_02"), "vga")));
    let cams_p = d.join("calibration_171204_pose1.json");
    std::fs::write(
        &cams_p,
        json!({ "calibDataSource": "171204_calib", "cameras": list }).to_string(),
    )
    .expect("cameras");
    let chosen = "00_00,00_03,00_06,00_09,00_12,00_15";
    let out_p = d.join("kp-panoptic.npz");
    let summary_p = import(&cams_p, &out_p, &["--camera-names", chosen]);
    assert_eq!(
        summary_p["source"]["camera_names"],
        json!(chosen.split(',').collect::<Vec<_>>()),
        "{summary_p}"
    );
    let from_p = Dataset::load(&out_p).expect("imported");
    assert_eq!(sparse(&from_p), sparse(&imported));
    for (a, b) in from_p.sensor.cameras().iter().zip(truth.sensor.cameras()) {
        assert_eq!((a.rotation, a.fx, a.cy), (b.rotation, b.fx, b.cy));
        assert!((a.center() - b.center()).length() < 1e-12, "{a:?} vs {b:?}");
    }
    // Without a choice the nine cameras do not match two keypoint files; a name not in the
    // file. Both refused in one line, the dataset already at --out untouched.
    let kept = std::fs::read(&out_p).expect("written");
    // `lfit data import` of the first `n` COCO files with `cams` and `extra`, expected to fail.
    let refused =
        |cams: &Path, extra: &[&str], n: usize, out: &Path| run(cams, out, extra, &files[..n]);
    let no_pick = refused(&cams_p, &[], 2, &out_p);
    assert_one_line_error(&no_pick, "2 keypoint paths for 9 cameras");
    assert_one_line_error(&no_pick, "--camera-names");
    let unknown = refused(&cams_p, &["--camera-names", "00_03,00_04"], 2, &out_p);
    assert_one_line_error(
        &unknown,
        "no camera named '00_04' in the camera file (its 9 names: 01_01, 00_15",
    );
    assert_eq!(
        std::fs::read(&out_p).expect("kept"),
        kept,
        "a refused import left the earlier dataset as it was"
    );
    // The six cameras as an anipose / Pose2Sim calibration.toml in millimetres (rotation
    // vectors, size as floats, no distortion), imported with --camera-units mm: the same.
    let mut toml = String::new();
    for (c, cam) in truth.sensor.cameras().iter().enumerate() {
        let (axis, angle) = glam::DQuat::from_mat3(&cam.rot()).to_axis_angle();
        let r = (axis * angle).to_array();
        let t = cam.translation.map(|x| x * 1000.0);
        toml += &format!(
            "[cam_{c:02}]\nname = \"cam_{c:02}\"\nsize = [ {:?}, {:?}]\nmatrix = [ [ {:?}, 0.0, {:?}], [ 0.0, {:?}, {:?}], [ 0.0, 0.0, 1.0]]\ndistortions = [ 0.0, 0.0, 0.0, 0.0]\nrotation = [ {:?}, {:?}, {:?}]\ntranslation = [ {:?}, {:?}, {:?}]\nfisheye = false\n\n",
            f64::from(cam.width),
            f64::from(cam.height),
            cam.fx,
            cam.cx,
            cam.fy,
            cam.cy,
            r[0],
            r[1],
            r[2],
            t[0],
            t[1],
            t[2]
        );
    }
    let cams_t = d.join("calibration.toml");
    std::fs::write(
        &cams_t,
        toml + "[metadata]\nadjusted = false\nerror = 0.0\n",
    )
    .expect("toml");
    let out_t = d.join("kp-toml.npz");
    let summary_t = import(&cams_t, &out_t, &["--camera-units", "mm"]);
    assert_eq!(summary_t["source"]["camera_units"], "mm", "{summary_t}");
    let from_t = Dataset::load(&out_t).expect("imported");
    assert_eq!(sparse(&from_t), sparse(&imported));
    for (a, b) in from_t.sensor.cameras().iter().zip(truth.sensor.cameras()) {
        assert_eq!((a.fx, a.cy, a.width), (b.fx, b.cy, b.width));
        assert!((a.center() - b.center()).length() < 1e-12, "{a:?} vs {b:?}");
        for (x, y) in a.rotation.iter().flatten().zip(b.rotation.iter().flatten()) {
            assert!((x - y).abs() < 1e-12, "{a:?} vs {b:?}");
        }
    }
    // The six cameras as an EasyMocap folder (intri.yml + extri.yml, OpenCV's YAML; sizes
    // given): the same dataset, read from the folder.
    let easy = d.join("easymocap");
    std::fs::create_dir_all(&easy).expect("dir");
    let cams6 = truth.sensor.cameras();
    let names: String = (0..cams6.len())
        .map(|c| format!("  - \"{c:02}\"\r\n"))
        .collect();
    let mat = |key: String, r: usize, c: usize, v: &[f64]| {
        let v: Vec<String> = v.iter().map(|x| format!("{x:?}")).collect();
        format!(
            "{key}: !!opencv-matrix\r\n  rows: {r}\r\n  cols: {c}\r\n  dt: d\r\n  data: [{}]\r\n",
            v.join(", ")
        )
    };
    let (mut intri, mut extri) = (
        format!("%YAML:1.0\r\n---\r\nnames:\r\n{names}"),
        format!("%YAML:1.0\r\n---\r\nnames:\r\n{names}"),
    );
    for (c, cam) in cams6.iter().enumerate() {
        let k = [cam.fx, 0.0, cam.cx, 0.0, cam.fy, cam.cy, 0.0, 0.0, 1.0];
        intri += &mat(format!("K_{c:02}"), 3, 3, &k);
        intri += &format!("W_{c:02}: {}\r\nH_{c:02}: {}\r\n", cam.width, cam.height);
        let r: Vec<f64> = cam.rotation.iter().flatten().copied().collect();
        extri += &mat(format!("Rot_{c:02}"), 3, 3, &r);
        extri += &mat(format!("T_{c:02}"), 3, 1, &cam.translation);
    }
    std::fs::write(easy.join("intri.yml"), intri).expect("intri");
    std::fs::write(easy.join("extri.yml"), extri).expect("extri");
    let out_e = d.join("kp-easymocap.npz");
    let summary_e = import(&easy, &out_e, &[]);
    assert!(
        summary_e["source"]
            .get("image_size_from_principal_point")
            .is_none(),
        "{summary_e}"
    );
    let from_e = Dataset::load(&out_e).expect("imported");
    assert_eq!(sparse(&from_e), sparse(&imported));
    assert_eq!(from_e.sensor.cameras(), truth.sensor.cameras());
    // The same TOML read as metres: a body a thousand times the model's, refused naming the
    // unit; the right unit's body is the model's size within the subject's shape.
    let size = summary_t["import"]["triangulated_size"]
        .as_f64()
        .expect("triangulated_size");
    assert!((0.8..1.25).contains(&size), "{size}");
    let as_metres = refused(&cams_t, &[], 6, &out_t);
    assert_one_line_error(&as_metres, "--camera-units");
    let text = String::from_utf8_lossy(&as_metres.stderr);
    let times: f64 = text
        .split("triangulate to a body ")
        .nth(1)
        .and_then(|t| t.split('×').next())
        .and_then(|t| t.parse().ok())
        .expect("the body's size in the error");
    assert!((800.0..1250.0).contains(&times), "{text}");
    let bad_unit = refused(&cams_t, &["--camera-units", "inch"], 1, &out_t);
    assert_one_line_error(&bad_unit, "--camera-units inch: expected m, cm or mm");
    // The same cameras calibrated in a Z-up world (a board on the floor), imported with
    // `--up z`: turned back into lfit's Y-up world (the cameras within rounding), the same
    // keypoints.
    // The truth's cameras written in a world turned by `r`, imported with `--up UP`: those
    // cameras, the summary and the dataset.
    let turned_import = |r: glam::DMat3, name: &str, up: &str| {
        let cams: Vec<_> = truth
            .sensor
            .cameras()
            .iter()
            .map(|c| c.in_rotated_world(r))
            .collect();
        let file = d.join(format!("cameras-{name}.json"));
        std::fs::write(&file, cameras_json(&cams)).expect("cameras");
        let out = d.join(format!("kp-{name}.npz"));
        let summary = import(&file, &out, &["--up", up]);
        (cams, summary, Dataset::load(&out).expect("imported"))
    };
    let to_z_up = lfit::synth::motion::retarget::Up::Z.to_lfit().transpose();
    let (z_up, _, turned) = turned_import(to_z_up, "z", "z");
    assert_eq!(sparse(&turned), sparse(&imported));
    for (a, b) in turned.sensor.cameras().iter().zip(truth.sensor.cameras()) {
        assert!((a.center() - b.center()).length() < 1e-12, "{a:?} vs {b:?}");
        for (x, y) in a.rotation.iter().flatten().zip(b.rotation.iter().flatten()) {
            assert!((x - y).abs() < 1e-12, "{a:?} vs {b:?}");
        }
    }
    assert!(
        z_up.iter()
            .zip(truth.sensor.cameras())
            .any(|(a, b)| (a.center() - b.center()).length() > 0.5),
        "the Z-up file's cameras are elsewhere"
    );
    // The same cameras in a tilted world whose up is the direction u (a board on a wall, or
    // gravity from a phone's IMU), imported with `--up ux,uy,uz`: turned onto lfit's +y, the
    // cameras are the original ones turned about +y only — each at its height above the floor,
    // seeing the floor's normal where it did — and the keypoints the same.
    let tilt = glam::DMat3::from_axis_angle(glam::DVec3::new(1.0, 0.0, 0.5).normalize(), 0.45)
        * glam::DMat3::from_rotation_y(0.7);
    let u = tilt * glam::DVec3::Y;
    let up = format!("{},{},{}", u.x, u.y, u.z);
    let (_, summary_t, turned) = turned_import(tilt, "tilted", &up);
    assert_eq!(summary_t["modality"], "keypoints2d");
    assert_eq!(sparse(&turned), sparse(&imported));
    let mut yawed = false;
    for (a, b) in turned.sensor.cameras().iter().zip(truth.sensor.cameras()) {
        let (ca, cb) = (a.center(), b.center());
        assert!((ca.y - cb.y).abs() < 1e-9, "height {} vs {}", ca.y, cb.y);
        let horizontal = |c: glam::DVec3| (c.x * c.x + c.z * c.z).sqrt();
        assert!((horizontal(ca) - horizontal(cb)).abs() < 1e-9);
        let up_in = |r: &[[f64; 3]; 3]| glam::DVec3::new(r[0][1], r[1][1], r[2][1]);
        assert!(
            (up_in(&a.rotation) - up_in(&b.rotation)).length() < 1e-9,
            "{a:?} vs {b:?}"
        );
        yawed |= (ca - cb).length() > 0.1;
    }
    assert!(
        yawed,
        "the shortest rotation leaves a yaw: the cameras moved about +y"
    );
    // Keypoints seen through lenses with distortion (OpenCV's model: a barrel and a pincushion
    // lens, the camera file's `dist`), imported with it: undistorted back to the pinhole
    // cameras' keypoints (within 1e-6 px) — without it they sit up to pixels away.
    let lenses = [
        [-0.28, 0.07, 1e-4, -2e-4, -0.008],
        [0.12, -0.03, -2e-4, 1e-4, 0.0],
    ];
    let mut bent = truth.clone();
    if let Observations::Sparse { values, visible } = &mut bent.observations {
        for (v, b) in values.iter_mut().zip(visible.iter()) {
            for (c, cam) in truth.sensor.cameras().iter().enumerate() {
                let lens = Distortion::from_opencv(&lenses[c % 2])
                    .expect("lens")
                    .expect("bent");
                for j in 0..nj {
                    let i = 2 * (c * nj + j);
                    if b[i] {
                        let (x, y) = ((v[i] - cam.cx) / cam.fx, (v[i + 1] - cam.cy) / cam.fy);
                        let (xd, yd) = lens.distort(x, y);
                        v[i] = cam.fx * xd + cam.cx;
                        v[i + 1] = cam.fy * yd + cam.cy;
                    }
                }
            }
        }
    }
    let bent_dir = d.join("bent");
    std::fs::create_dir_all(&bent_dir).expect("dir");
    let bent_files = coco_files(&bent_dir, &bent, nj);
    let mut with_lens: Value =
        serde_json::from_str(&cameras_json(truth.sensor.cameras())).expect("json");
    for (c, cam) in with_lens["cameras"]
        .as_array_mut()
        .expect("cameras")
        .iter_mut()
        .enumerate()
    {
        cam["dist"] = json!(lenses[c % 2]);
    }
    let cams_l = d.join("cameras-lens.json");
    std::fs::write(&cams_l, with_lens.to_string()).expect("cameras");
    let import_bent = |cams: &Path, out: &Path| import_files(cams, out, &[], &bent_files);
    let out_l = d.join("kp-lens.npz");
    let summary_l = import_bent(&cams_l, &out_l);
    assert_eq!(summary_l["source"]["undistorted_cameras"], 6, "{summary_l}");
    let undone = Dataset::load(&out_l).expect("imported");
    let (uv, ub) = sparse(&undone);
    assert_eq!(ub, ib);
    let mut worst: f64 = 0.0;
    for (a, b) in uv.iter().flatten().zip(iv.iter().flatten()) {
        worst = worst.max((a - b).abs());
    }
    assert!(
        worst < 1e-6,
        "undistorted keypoints {worst:e} px from the pinhole ones"
    );
    let out_n = d.join("kp-nolens.npz");
    import_bent(&cams, &out_n);
    let plain = Dataset::load(&out_n).expect("imported");
    let (nv, _) = sparse(&plain);
    let mut off: f64 = 0.0;
    for (a, b) in nv.iter().flatten().zip(iv.iter().flatten()) {
        off = off.max((a - b).abs());
    }
    assert!(off > 1.0, "the lenses bend the keypoints by {off} px only");
    let [lm, nn] = fit_both(d, &out, "keypoints2d", "px");
    assert!(
        lm[2] < 0.5,
        "LM keypoint error on the last frame {} px",
        lm[2]
    );
    assert!(
        nn[2] < 10.0,
        "neural keypoint error on the last frame {} px",
        nn[2]
    );
}

#[test]
fn bad_input_is_one_line_and_writes_nothing() {
    let tmp = tempfile::tempdir().expect("tmp");
    let d = tmp.path();
    let (_, truth) = synth(d, "markers", 3, 5);
    let (c3d, map) = c3d_of(&truth, -0.1);
    let good = c3d.to_bytes().expect("bytes");
    let map_file = d.join("labels.json");
    write_map(&map_file, &map);
    let out = d.join("never.npz");
    let run_c3d_with = |bytes: &[u8], map: &Path, extra: &[&str], needle: &str| {
        let f = d.join("bad.c3d");
        std::fs::write(&f, bytes).expect("write");
        let mut args = vec![
            "data",
            "import",
            "--c3d",
            path_str(&f),
            "--label-map",
            path_str(map),
            "--out",
            path_str(&out),
        ];
        args.extend_from_slice(extra);
        let o = lfit(&args);
        assert_one_line_error(&o, needle);
        assert!(!out.exists(), "{needle}: output written");
    };
    let run_c3d = |bytes: &[u8], map: &Path, needle: &str| run_c3d_with(bytes, map, &[], needle);
    // An unknown up axis.
    run_c3d_with(&good, &map_file, &["--up", "x"], "unknown up axis 'x'");
    // A label-map entry whose C3D label is not in the file; one whose model marker is unknown.
    let mut bad = map.clone();
    bad[3].0 = "S1:NOSUCH".into();
    let bad_map = d.join("bad_labels.json");
    write_map(&bad_map, &bad);
    run_c3d(&good, &bad_map, "'S1:NOSUCH' is not in the file");
    let mut bad = map.clone();
    bad[3].1 = "NOSUCH".into();
    write_map(&bad_map, &bad);
    run_c3d(&good, &bad_map, "'NOSUCH' is not a marker");
    // Truncated data, a cut header, wrong magic, a wrong parameter-section key.
    run_c3d(&good[..good.len() - 700], &map_file, "truncated");
    run_c3d(&good[..200], &map_file, "truncated");
    let mut b = good.clone();
    b[1] = 0;
    run_c3d(&b, &map_file, "not a C3D file");
    // The parameter section's two reserved bytes are ignored, as the C3D guide says (the `c3d`
    // package on PyPI writes 0x00 0x00): such a file imports.
    let mut b = good.clone();
    b[512] = 0;
    b[513] = 0;
    let reserved = d.join("reserved.c3d");
    std::fs::write(&reserved, &b).expect("write");
    let imported = d.join("reserved.npz");
    lfit_json(&[
        "data",
        "import",
        "--c3d",
        path_str(&reserved),
        "--label-map",
        path_str(&map_file),
        "--out",
        path_str(&imported),
    ]);
    assert!(imported.is_file());
    // NaN coordinates in a sample are a gap (kineticstoolkit's files mark gaps so), counted.
    let mut b = good.clone();
    let start = (u16::from_le_bytes([b[16], b[17]]) as usize - 1) * 512;
    b[start..start + 4].copy_from_slice(&f32::NAN.to_le_bytes());
    let nan_file = d.join("nan.c3d");
    std::fs::write(&nan_file, &b).expect("write");
    let nan_out = d.join("nan.npz");
    let s = import_c3d(&nan_file, &map_file, &nan_out);
    assert_eq!(s["import"]["non_finite_samples"], 1);
    let nan = Dataset::load(&nan_out).expect("imported");
    let (_, seen) = sparse(&nan);
    assert!(
        !seen[0][0] && seen[1][0],
        "frame 0's first marker is a gap, frame 1's is not"
    );

    // Keypoints: the wrong number of values, a missing camera, an unreadable camera file.
    let kp = d.join("kp.json");
    std::fs::write(
        &kp,
        json!({"images": [{"id": 1}], "annotations": [{"image_id": 1, "keypoints": vec![1.0; 50]}]})
            .to_string(),
    )
    .expect("write");
    let cams = d.join("cams.json");
    std::fs::write(&cams, cameras_json(&lfit::model::camera::default_ring(1))).expect("write");
    let o = lfit(&[
        "data",
        "import",
        "--keypoints",
        path_str(&kp),
        "--layout",
        "coco17",
        "--camera",
        path_str(&cams),
        "--out",
        path_str(&out),
    ]);
    assert_one_line_error(&o, "50 values, expected 51");
    let o = lfit(&[
        "data",
        "import",
        "--keypoints",
        path_str(&kp),
        "--layout",
        "coco17",
        "--out",
        path_str(&out),
    ]);
    assert_one_line_error(&o, "--camera");
    let o = lfit(&[
        "data",
        "import",
        "--keypoints",
        path_str(&kp),
        "--layout",
        "coco17",
        "--camera",
        path_str(&d.join("missing.json")),
        "--out",
        path_str(&out),
    ]);
    assert_one_line_error(&o, "cannot read");
    let o = lfit(&[
        "data",
        "import",
        "--keypoints",
        path_str(&kp),
        "--layout",
        "coco19",
        "--camera",
        path_str(&cams),
        "--out",
        path_str(&out),
    ]);
    assert_one_line_error(&o, "unknown keypoint layout");
    assert!(!out.exists());
}

#[test]
fn openpose_body25_folder_of_one_camera_imports_and_fits_with_lm() {
    let tmp = tempfile::tempdir().expect("tmp");
    let d = tmp.path();
    let (_, truth) = synth(d, "keypoints2d", 5, 47);
    let (values, visible) = sparse(&truth);
    let layout = KeypointLayout::Body25;
    let map = layout.default_map();
    // Camera 0 only; frames as OpenPose writes them, one file each, plus a second, less
    // confident person in frame 1.
    let folder = d.join("openpose");
    std::fs::create_dir(&folder).expect("dir");
    for f in 0..values.len() {
        let mut kp = vec![0.0; 75];
        for &(j, name) in &map {
            let k = layout.index(name).expect("keypoint");
            if visible[f][2 * j] {
                kp[3 * k..3 * k + 3].copy_from_slice(&[
                    values[f][2 * j],
                    values[f][2 * j + 1],
                    0.8,
                ]);
            }
        }
        let mut people = vec![json!({"person_id": [-1], "pose_keypoints_2d": kp})];
        if f == 1 {
            people.push(json!({"person_id": [-1], "pose_keypoints_2d": vec![0.01; 75]}));
        }
        std::fs::write(
            folder.join(format!("clip_{f:012}_keypoints.json")),
            json!({"version": 1.3, "people": people}).to_string(),
        )
        .expect("frame");
    }
    let cams = d.join("camera0.json");
    std::fs::write(&cams, cameras_json(&truth.sensor.cameras()[..1])).expect("camera");
    let out = d.join("op.npz");
    let summary = lfit_json(&[
        "-q",
        "data",
        "import",
        "--keypoints",
        path_str(&folder),
        "--layout",
        "body25",
        "--camera",
        path_str(&cams),
        "--fps",
        "25",
        "--out",
        path_str(&out),
    ]);
    assert_eq!(summary["import"]["format"], "openpose");
    assert_eq!(summary["import"]["crowded_frames"], 1);
    assert_eq!(summary["import"]["single_view_starts"], 5);
    let imported = Dataset::load(&out).expect("imported");
    assert_eq!(imported.len(), 5);
    assert_eq!(imported.meta.config.fps, 25.0);
    let (iv, ib) = sparse(&imported);
    for f in 0..values.len() {
        for &(j, _) in &map {
            assert_eq!(ib[f][2 * j], visible[f][2 * j]);
            if ib[f][2 * j] {
                assert_eq!(iv[f][2 * j], values[f][2 * j]);
                assert_eq!(iv[f][2 * j + 1], values[f][2 * j + 1]);
            }
        }
    }
    let res = d.join("lm.json");
    let s = lfit_json(&[
        "-q",
        "fit",
        "--data",
        path_str(&out),
        "--method",
        "lm",
        "--budget",
        "100",
        "--out",
        path_str(&res),
    ]);
    let e = s["summary"]["mean_observation_error_px"]
        .as_f64()
        .expect("px");
    eprintln!("OpenPose one camera, LM: mean keypoint error {e:.3} px");
    assert!(e.is_finite());
    // The shipped keypoints2d fitter was trained on six cameras: one is a one-line error.
    let o = lfit(&[
        "fit",
        "--data",
        path_str(&out),
        "--method",
        "neural",
        "--checkpoint",
        &checkpoint("keypoints2d"),
        "--budget",
        "10",
        "--device",
        "ndarray",
        "--out",
        path_str(&d.join("n.json")),
    ]);
    assert_one_line_error(&o, "keypoints2d");
    assert!(!d.join("n.json").exists());
}

#[test]
fn export_c3d_round_trips_through_data_import() {
    let tmp = tempfile::tempdir().expect("tmp");
    let d = tmp.path();
    // With the default noise model: noisy positions and occluded markers (gaps in the C3D).
    let data = d.join("noisy.npz");
    lfit_json(&[
        "-q",
        "synth",
        "--modality",
        "markers",
        "--scenario",
        "sequence",
        "--frames",
        "6",
        "--seed",
        "12",
        "--out",
        path_str(&data),
    ]);
    let truth = Dataset::load(&data).expect("dataset");
    let c3d = d.join("noisy.c3d");
    // `lfit data export-c3d --data DATA --out OUT` and more arguments.
    let export = |out: &Path, more: &[&str]| -> Vec<String> {
        let mut a: Vec<String> = ["data", "export-c3d", "--data", path_str(&data), "--out"]
            .map(String::from)
            .to_vec();
        a.push(path_str(out).to_string());
        a.extend(more.iter().map(|s| s.to_string()));
        a
    };
    let mut quiet = vec!["-q".to_string()];
    quiet.extend(export(&c3d, &["--label-prefix", "S1:"]));
    let s = lfit_json(&args(&quiet));
    assert_eq!(s["frames"], 6);
    let (tv, tb) = sparse(&truth);
    let hidden = tb.iter().flatten().step_by(3).filter(|b| !**b).count();
    assert!(hidden > 0, "the noise model hides some markers");
    assert_eq!(s["gaps"], hidden);
    let file = C3d::read(&c3d).expect("C3D");
    assert!(file.labels.iter().all(|l| l.starts_with("S1:")));
    assert_eq!(file.rate, truth.meta.config.fps);
    // Back through lfit data import (labels without the prefix: a map).
    let names: Vec<String> = file.labels.iter().map(|l| l[3..].to_string()).collect();
    let map: Vec<(String, String)> = names
        .iter()
        .map(|n| (format!("S1:{n}"), n.clone()))
        .collect();
    let map_file = d.join("map.json");
    write_map(&map_file, &map);
    let back = d.join("back.npz");
    import_c3d(&c3d, &map_file, &back);
    let imported = Dataset::load(&back).expect("imported");
    let (iv, ib) = sparse(&imported);
    let mut max_err: f64 = 0.0;
    for f in 0..tv.len() {
        assert_eq!(ib[f], tb[f], "frame {f} visibility");
        for i in 0..tv[f].len() {
            if tb[f][i] {
                max_err = max_err.max((iv[f][i] - tv[f][i]).abs());
            }
        }
    }
    assert!(max_err <= 1e-6, "round trip differs by {max_err} m");

    // --translate moves every point (a capture away from the lab's origin).
    let moved = d.join("moved.c3d");
    let mut quiet = vec!["-q".to_string()];
    quiet.extend(export(&moved, &["--translate", "3,0,-2"]));
    let s = lfit_json(&args(&quiet));
    assert_eq!(s["translate_m"], json!([3.0, 0.0, -2.0]));
    let (a, b) = (
        C3d::read(&c3d).expect("C3D"),
        C3d::read(&moved).expect("C3D"),
    );
    for (ra, rb) in a.frames.iter().zip(&b.frames) {
        for (pa, pb) in ra.iter().zip(rb) {
            match (pa, pb) {
                (Some(pa), Some(pb)) => {
                    for (k, off) in [3000.0, 0.0, -2000.0].into_iter().enumerate() {
                        let e = (pb.position[k] - pa.position[k] - off).abs();
                        assert!(e < 1e-3, "moved by {off} mm ± {e}");
                    }
                }
                (None, None) => {}
                _ => panic!("a gap moved"),
            }
        }
    }
    for bad in ["3,0", "a,b,c", "nan,0,0", "1,2,3,4"] {
        let out = d.join("bad.c3d");
        assert_one_line_error(
            &lfit(&args(&export(&out, &["--translate", bad]))),
            "--translate",
        );
        assert!(!out.exists());
    }

    // Bad input: a keypoints dataset, a missing dataset, a directory as --out; nothing written.
    let (kp, _) = synth(d, "keypoints2d", 2, 3);
    let out = d.join("kp.c3d");
    assert_one_line_error(
        &lfit(&[
            "data",
            "export-c3d",
            "--data",
            path_str(&kp),
            "--out",
            path_str(&out),
        ]),
        "only a markers dataset",
    );
    assert!(!out.exists());
    assert_one_line_error(
        &lfit(&[
            "data",
            "export-c3d",
            "--data",
            path_str(&d.join("none.npz")),
            "--out",
            path_str(&out),
        ]),
        "none.npz",
    );
    assert!(!out.exists());
    assert_one_line_error(
        &lfit(&[
            "data",
            "export-c3d",
            "--data",
            path_str(&data),
            "--out",
            path_str(d),
        ]),
        "directory",
    );
}

/// A capture whose subject stands 3.6 m from the lab's origin (a 4 × 6 m volume has them there)
/// fits as the same capture at the origin: single frames imported in the global scenario are
/// searched within ±1.25 m of their rigid alignment, not of the origin (where such a frame was
/// clamped into the box and ended 1.4 m off), and LM's result moves with the data.
#[test]
fn a_capture_far_from_the_lab_origin_fits_as_the_same_capture_at_it() {
    let tmp = tempfile::tempdir().expect("tmp");
    let d = tmp.path();
    let (_, truth) = synth_in(d, "markers", "local", 4, 5);
    let (near, map) = c3d_of(&truth, -0.1);
    let mut far = near.clone();
    for row in &mut far.frames {
        for p in row.iter_mut().flatten() {
            p.position[0] += 3000.0;
            p.position[2] -= 2000.0;
        }
    }
    let map_file = d.join("labels.json");
    write_map(&map_file, &map);
    let mut errors = Vec::new();
    for (name, c3d) in [("near", &near), ("far", &far)] {
        let file = d.join(format!("{name}.c3d"));
        std::fs::write(&file, c3d.to_bytes().expect("C3D bytes")).expect("write");
        let imported = d.join(format!("{name}.npz"));
        lfit_json(&[
            "-q",
            "data",
            "import",
            "--c3d",
            path_str(&file),
            "--label-map",
            path_str(&map_file),
            "--scenario",
            "global",
            "--out",
            path_str(&imported),
        ]);
        let res = d.join(format!("{name}.json"));
        lfit_json(&[
            "-q",
            "fit",
            "--data",
            path_str(&imported),
            "--method",
            "lm",
            "--budget",
            "400",
            "--out",
            path_str(&res),
        ]);
        let frames: Vec<f64> = read_json(&res)["frames"]
            .as_array()
            .expect("frames")
            .iter()
            .map(|f| {
                f["observation_error_mm"]
                    .as_f64()
                    .expect("observation error")
            })
            .collect();
        eprintln!("{name}: marker error per frame {frames:?} mm");
        errors.push(frames);
    }
    let mean = errors[0].iter().sum::<f64>() / errors[0].len() as f64;
    assert!(
        mean < 5.0,
        "near the origin LM fits the noise-free frames: {mean} mm"
    );
    for (f, (a, b)) in errors[0].iter().zip(&errors[1]).enumerate() {
        assert!(
            (a - b).abs() < 0.01,
            "frame {f}: {a} mm at the origin, {b} mm 3.6 m away"
        );
    }
}

/// A C3D file written by an independent writer, the `c3d` package on PyPI (0.6.0, installed by
/// scripts/fetch-scipy.sh): float points in mm, a gap (residual −1), and the parameter section's
/// reserved bytes as that package writes them (0x00 0x00, which the format guide says readers
/// ignore). It imports to the positions written, within 1e-6 m.
#[test]
fn c3d_written_by_the_c3d_package_on_pypi_imports_to_a_micrometre() {
    let mut python = match support::python_with("numpy, c3d") {
        Ok(p) => p,
        Err(reason) => {
            support::skip_unless_required(&reason, None);
            return;
        }
    };
    let tmp = tempfile::tempdir().expect("tmp");
    let d = tmp.path();
    let (_, truth) = synth(d, "markers", 4, 77);
    let names = match &truth.sensor {
        lfit::model::observe::Sensor::Markers(m) => m.names.clone(),
        _ => panic!("markers"),
    };
    let (tv, tb) = sparse(&truth);
    // Frame 1, marker 3: a gap.
    let gap = |f: usize, k: usize| f == 1 && k == 3;
    let frames: Vec<Vec<Value>> = tv
        .iter()
        .zip(tb)
        .enumerate()
        .map(|(f, (v, b))| {
            (0..names.len())
                .map(|k| {
                    if b[3 * k] && !gap(f, k) {
                        json!([v[3 * k] * 1e3, v[3 * k + 1] * 1e3, v[3 * k + 2] * 1e3, 0.5])
                    } else {
                        json!([0.0, 0.0, 0.0, -1.0])
                    }
                })
                .collect()
        })
        .collect();
    let labels: Vec<String> = names.iter().map(|n| format!("S1:{n}")).collect();
    let input = d.join("points.json");
    std::fs::write(
        &input,
        json!({"labels": labels, "frames": frames}).to_string(),
    )
    .expect("json");
    let file = d.join("pypi.c3d");
    let script = r#"
import json, sys, warnings
import numpy as np
import c3d
spec = json.load(open(sys.argv[1]))
w = c3d.Writer(point_rate=100.0, point_units='mm  ')
w.set_point_labels(spec['labels'])
frames = []
for f in spec['frames']:
    p = np.zeros((len(f), 5), np.float32)
    p[:, :4] = np.array(f, np.float64)
    p[:, 4] = 0x3F
    frames.append((p, np.zeros((0, 0), np.float32)))
w.add_frames(frames)
with warnings.catch_warnings():
    warnings.simplefilter('ignore')
    with open(sys.argv[2], 'wb') as h:
        w.write(h)
"#;
    let out = python
        .args(["-c", script, path_str(&input), path_str(&file)])
        .output()
        .expect("python3");
    assert!(
        out.status.success(),
        "the c3d package failed: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    let bytes = std::fs::read(&file).expect("written C3D");
    let parameters = (usize::from(bytes[0]) - 1) * 512;
    assert_eq!(
        &bytes[parameters..parameters + 2],
        &[0, 0],
        "the package writes 0x00 0x00 in the reserved bytes"
    );
    let map_file = d.join("labels.json");
    let map: Vec<(String, String)> = labels.iter().cloned().zip(names.iter().cloned()).collect();
    write_map(&map_file, &map);
    let imported_file = d.join("imported.npz");
    let summary = import_c3d(&file, &map_file, &imported_file);
    assert_eq!(summary["frames"], 4);
    let imported = Dataset::load(&imported_file).expect("imported");
    assert_eq!(imported.meta.config.fps, 100.0);
    let (iv, ib) = sparse(&imported);
    let mut max_err = 0.0;
    for f in 0..tv.len() {
        for k in 0..names.len() {
            assert_eq!(
                ib[f][3 * k],
                tb[f][3 * k] && !gap(f, k),
                "frame {f} marker {k}"
            );
            if ib[f][3 * k] {
                for a in 0..3 {
                    max_err =
                        support::nan_max(max_err, (iv[f][3 * k + a] - tv[f][3 * k + a]).abs());
                }
            }
        }
    }
    eprintln!("C3D of the c3d package (PyPI 0.6.0): max coordinate error {max_err:.3e} m");
    assert!(max_err <= 1e-6, "imported positions differ by {max_err} m");
}

/// A DEC file (VAX floats, as Vicon's 370 wrote) written by lfit's writer reads back, through
/// `lfit data import`, to the observations of the same capture written for Intel, bit for bit;
/// and the `c3d` package on PyPI (its own DEC conversion) reads the same coordinates from it.
#[test]
fn a_dec_c3d_imports_as_its_intel_copy_and_as_the_c3d_package_reads_it() {
    let tmp = tempfile::tempdir().expect("tmp");
    let d = tmp.path();
    let (_, truth) = synth(d, "markers", 5, 19);
    let map_file = d.join("labels.json");
    let mut imported = Vec::new();
    for (name, processor) in [("intel", Processor::Intel), ("dec", Processor::Dec)] {
        for scale in [-0.1, 0.1] {
            let (mut c3d, map) = c3d_of(&truth, scale);
            c3d.processor = processor;
            write_map(&map_file, &map);
            let file = d.join(format!("{name}{scale}.c3d"));
            std::fs::write(&file, c3d.to_bytes().expect("C3D bytes")).expect("write");
            let bytes = std::fs::read(&file).expect("C3D");
            let parameters = (usize::from(bytes[0]) - 1) * 512;
            assert_eq!(bytes[parameters + 3], if name == "dec" { 85 } else { 84 });
            let out = d.join(format!("{name}{scale}.npz"));
            import_c3d(&file, &map_file, &out);
            imported.push((file, Dataset::load(&out).expect("imported")));
        }
    }
    // Intel floats = DEC floats, Intel integers = DEC integers.
    assert_eq!(sparse(&imported[0].1), sparse(&imported[2].1));
    assert_eq!(sparse(&imported[1].1), sparse(&imported[3].1));
    assert_eq!(imported[2].1.meta.config.fps, 120.0);

    let mut python = match support::python_with("numpy, c3d") {
        Ok(p) => p,
        Err(reason) => {
            support::skip_unless_required(&reason, None);
            return;
        }
    };
    let script = r#"
import json, sys, warnings
import c3d
with warnings.catch_warnings():
    warnings.simplefilter('ignore')
    r = c3d.Reader(open(sys.argv[1], 'rb'))
    frames = [p[:, :4].tolist() for _, p, _ in r.read_frames()]
print(json.dumps({"proc": r.proc_type, "rate": float(r.point_rate), "frames": frames}))
"#;
    // Its DEC file, and the Intel one (which the package refused while lfit wrote an
    // ANALOG:RATE that contradicted the header).
    let mut compared = 0;
    for (k, proc) in [(2, "DEC"), (0, "INTEL")] {
        let out = python
            .args(["-c", script, path_str(&imported[k].0)])
            .output()
            .expect("python3");
        assert!(
            out.status.success(),
            "the c3d package failed on the {proc} file: {}",
            String::from_utf8_lossy(&out.stderr)
        );
        let theirs: Value = serde_json::from_slice(&out.stdout).expect("JSON");
        assert_eq!(theirs["proc"], proc);
        assert_eq!(theirs["rate"], 120.0);
        let ours = C3d::read(&imported[k].0).expect("our reader");
        let frames = theirs["frames"].as_array().expect("frames");
        assert_eq!(frames.len(), ours.frames.len());
        for (row, mine) in frames.iter().zip(&ours.frames) {
            for (point, m) in row.as_array().expect("points").iter().zip(mine) {
                let p: Vec<f64> = serde_json::from_value(point.clone()).expect("point");
                match m {
                    // Their gap: a negative residual.
                    None => assert!(p[3] < 0.0, "{p:?}"),
                    Some(m) => {
                        for a in 0..3 {
                            assert_eq!(p[a], m.position[a], "{p:?} against {:?}", m.position);
                        }
                        compared += 1;
                    }
                }
            }
        }
        python = support::python_with("numpy, c3d").expect("python");
    }
    assert!(compared > 100, "{compared} points compared");
}

/// A capture whose markers sit off the model's marker set (synthetic frames slipped by 40 mm, as
/// C3D) fitted on the set gets the summary's `hint` to solve their placement; solved, or markers
/// on the set, it does not.
#[test]
fn a_capture_with_markers_off_the_set_is_told_to_solve_their_placement() {
    let tmp = tempfile::tempdir().expect("tmp");
    let d = tmp.path();
    // The MakeHuman body: a placement solve needs shape parameters.
    let model = format!("{}/models/makehuman-cmu_mb.npz", env!("CARGO_MANIFEST_DIR"));
    let fit = |data: &Path, name: &str, more: &[&str]| -> Value {
        let out = d.join(format!("{name}.json"));
        let mut with_model = vec!["--model", model.as_str()];
        with_model.extend(more);
        lfit_json(&support::lm_fit_args(data, &out, "200", &with_model))["summary"].clone()
    };
    let mut hints = Vec::new();
    for (name, slip) in [("on", "0"), ("off", "40")] {
        let data = d.join(format!("{name}.npz"));
        support::synth_to(
            &data,
            Path::new(&model),
            &[
                "--modality",
                "markers",
                "--scenario",
                "sequence",
                "--frames",
                "10",
                "--noise",
                "0",
                "--seed",
                "5",
                "--marker-slip-mm",
                slip,
            ],
        );
        let c3d = d.join(format!("{name}.c3d"));
        support::export_c3d(&data, &c3d);
        let imported = d.join(format!("{name}-imported.npz"));
        support::import_c3d_with(&c3d, &imported, &["--model", &model]);
        let on_set = fit(&imported, name, &[]);
        let solved = fit(
            &imported,
            &format!("{name}-solved"),
            &[
                "--sequence-shape",
                "joint:64",
                "--marker-placement",
                "solve",
            ],
        );
        assert!(solved.get("hint").is_none(), "{name}: {solved}");
        hints.push((
            on_set["mean_observation_error_mm"].as_f64().expect("error"),
            on_set.get("hint").cloned(),
        ));
    }
    let (on, off) = (&hints[0], &hints[1]);
    assert!(on.0 < 10.0 && on.1.is_none(), "markers on the set: {on:?}");
    assert!(off.0 > 10.0, "markers 40 mm off the set: {off:?}");
    let hint = off.1.as_ref().and_then(Value::as_str).expect("a hint");
    assert!(hint.contains("--marker-placement solve"), "{hint}");
}

/// `lfit data cameras`: a CMU Panoptic file's chosen cameras (centimetres, lens distortion) in
/// lfit's own JSON — read back as the same cameras, names and lenses; the summary places each
/// camera (the ring's 1.3 m height, 4 m away, tilted down at the subject); `--pinhole` leaves
/// the lenses out, and `lfit synth --camera` takes that file (and refuses the one with lenses).
#[test]
fn a_camera_file_converts_to_lfit_json_and_drives_synth() {
    let tmp = tempfile::tempdir().expect("tmp");
    let d = tmp.path();
    let ring = lfit::model::camera::default_ring(4);
    let list: Vec<Value> = ring
        .iter()
        .enumerate()
        .map(|(i, c)| {
            json!({
                "name": format!("00_{i:02}"), "type": "hd", "panel": 0, "node": i,
                "resolution": [c.width, c.height],
                "K": [[c.fx, 0.0, c.cx], [0.0, c.fy, c.cy], [0.0, 0.0, 1.0]],
                "distCoef": [-0.2 + 0.01 * i as f64, 0.05, 0.0, 0.0, 0.01],
                "R": c.rotation, "t": c.translation.map(|x| [x * 100.0]),
            })
        })
        .collect();
    let panoptic = d.join("calibration_x.json");
    std::fs::write(
        &panoptic,
        json!({ "calibDataSource": "x", "cameras": list }).to_string(),
    )
    .expect("write");
    let rig = d.join("rig.json");
    let s = lfit_json(&[
        "data",
        "cameras",
        "--camera",
        path_str(&panoptic),
        "--camera-names",
        "00_03,00_01",
        "--out",
        path_str(&rig),
    ]);
    assert_eq!(s["count"], 2, "{s}");
    for (k, want) in [(0, &ring[3]), (1, &ring[1])] {
        let cam = &s["cameras"][k];
        let height = cam["height_m"].as_f64().expect("height");
        let distance = cam["distance_m"].as_f64().expect("distance");
        let tilt = cam["tilt_deg"].as_f64().expect("tilt");
        assert!((height - want.center().y).abs() < 1e-9, "{cam}");
        assert!(
            (height - 1.3).abs() < 1e-9 && (distance - 4.0).abs() < 1e-9,
            "{cam}"
        );
        assert!(
            (-10.0..0.0).contains(&tilt),
            "looks down at the subject: {cam}"
        );
    }
    let back = lfit::synth::capture::keypoints::read_camera_file(&rig).expect("rig");
    let chosen = lfit::synth::capture::keypoints::read_camera_file(&panoptic)
        .expect("panoptic")
        .select(&["00_03".into(), "00_01".into()])
        .expect("chosen");
    assert_eq!(back, chosen);
    assert!(back.distortion.iter().all(Option::is_some));
    // Synthesis refuses lenses; the --pinhole file is the same rig without them.
    let out = d.join("syn.npz");
    let synth_with = |rig: &Path| {
        lfit(&[
            "-q",
            "synth",
            "--modality",
            "keypoints2d",
            "--frames",
            "2",
            "--camera",
            path_str(rig),
            "--out",
            path_str(&out),
        ])
    };
    assert_one_line_error(&synth_with(&rig), "has a lens distortion");
    assert_one_line_error(&synth_with(&rig), "lfit data cameras --camera");
    let pinhole = d.join("rig-pinhole.json");
    lfit_json(&[
        "data",
        "cameras",
        "--camera",
        path_str(&panoptic),
        "--camera-names",
        "00_03,00_01",
        "--pinhole",
        "--out",
        path_str(&pinhole),
    ]);
    assert!(synth_with(&pinhole).status.success());
    let syn = Dataset::load(&out).expect("synth");
    assert_eq!(syn.sensor.cameras(), &chosen.cameras[..]);
    // Bad flags: one line each, nothing written.
    let never = d.join("never.json");
    for (extra, needle) in [
        (
            vec!["--camera-units", "inch"],
            "--camera-units inch: expected m, cm or mm",
        ),
        (vec!["--camera-names", "00_09"], "no camera named '00_09'"),
        (vec!["--up", "q"], "up"),
    ] {
        let mut a = vec![
            "data",
            "cameras",
            "--camera",
            path_str(&panoptic),
            "--out",
            path_str(&never),
        ];
        a.extend(extra);
        assert_one_line_error(&lfit(&a), needle);
        assert!(!never.exists());
    }
}

/// Writes frame `f`'s Panoptic 3D skeleton file (`body3DScene_XXXXXXXX.json`, centimetres) into
/// `folder`: `bodies` as (id, 19 × [x, y, z, confidence] in metres).
fn panoptic_frame(folder: &Path, f: usize, bodies: &[(i64, Vec<[f64; 4]>)]) {
    let bodies: Vec<Value> = bodies
        .iter()
        .map(|(id, joints)| {
            let flat: Vec<f64> = joints
                .iter()
                .flat_map(|p| [100.0 * p[0], 100.0 * p[1], 100.0 * p[2], p[3]])
                .collect();
            json!({"id": id, "joints19": flat})
        })
        .collect();
    std::fs::write(
        folder.join(format!("body3DScene_{f:08}.json")),
        json!({"version": 0.7, "univTime": 1000.0 + f as f64, "fpsType": "hd_29_97", "bodies": bodies}).to_string(),
    )
    .expect("panoptic frame");
}

/// A Panoptic-style reference of the truth's joints, in a y-down centimetre world as the
/// studio's files are (the cameras turned with it), imports with `--up 0,-1,0` onto the model's
/// joints and scores the LM fit of the same frames' keypoints; a reference moved 10 cm scores
/// the same fit 10 cm worse by MPJPE and the same by PA-MPJPE. Frames with two bodies need
/// `--reference-person`; a reference of another length is refused. Nothing is written on error.
#[test]
fn a_panoptic_reference_scores_the_fit_of_the_same_frames_keypoints() {
    use lfit::synth::motion::retarget::Up;
    let tmp = tempfile::tempdir().expect("tmp");
    let d = tmp.path();
    let frames = 6;
    let (_, truth) = synth(d, "keypoints2d", frames, 51);
    let template = lfit::data::load_model(None, "default").expect("model");
    let nj = template.rig.num_joints();
    let files = coco_files(d, &truth, nj);
    let up: Up = "0,-1,0".parse().expect("up");
    let to_file = up.to_lfit().transpose();
    let cams: Vec<_> = truth
        .sensor
        .cameras()
        .iter()
        .map(|c| c.in_rotated_world(to_file))
        .collect();
    let cam_file = d.join("cameras.json");
    std::fs::write(&cam_file, cameras_json(&cams)).expect("cameras");
    let layout = KeypointLayout::Panoptic19;
    let map = layout.default_map();
    let joint_map = &template.info.joint_map;
    // The truth's joints as Panoptic keypoints in the file's world, `shift` metres added there;
    // frame 2's left wrist not found (confidence −1); a second body in frame 4.
    let write_reference = |folder: &Path, count: usize, shift: [f64; 3]| {
        std::fs::create_dir_all(folder).expect("dir");
        for f in 0..count {
            let joints = lfit::model::metrics::joint_positions(&template, &truth.gt_poses[f]);
            let mut kp = vec![[0.5, -1.0, 0.2, 0.3]; layout.count()];
            for &(p, name) in &map {
                let j = joint_map[p].expect("mapped joint");
                let q = to_file * joints[j] + glam::DVec3::from_array(shift);
                let c = if f == 2 && name == "lWrist" {
                    -1.0
                } else {
                    0.7
                };
                kp[layout.index(name).expect("keypoint")] = [q.x, q.y, q.z, c];
            }
            let mut bodies = vec![(3, kp.clone())];
            if f == 4 {
                let other = kp.iter().map(|p| [p[0] + 1.0, p[1], p[2], p[3]]).collect();
                bodies.insert(0, (7, other));
            }
            panoptic_frame(folder, f, &bodies);
        }
    };
    let reference = d.join("hdPose3d_stage1_coco19");
    write_reference(&reference, frames, [0.0; 3]);
    let import = |reference: &Path, out: &Path, extra: &[&str]| {
        let mut a = vec![
            "-q", "data", "import", "--layout", "coco17", "--up", "0,-1,0",
        ];
        a.extend(["--camera", path_str(&cam_file), "--out", path_str(out)]);
        a.extend(["--reference", path_str(reference)]);
        a.extend(extra);
        a.push("--keypoints");
        a.extend(files.iter().map(|f| path_str(f)));
        lfit(&a)
    };
    // Frame 4 holds two bodies: the one to score is chosen by id.
    let out = d.join("kp.npz");
    let o = import(&reference, &out, &[]);
    assert_one_line_error(&o, "--reference-person");
    assert!(!out.exists());
    let o = import(&reference, &out, &["--reference-person", "9"]);
    assert_one_line_error(&o, "the files' ids: 3, 7");
    assert!(!out.exists());
    let o = import(&reference, &out, &["--reference-person", "3"]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let summary: Value = serde_json::from_slice(&o.stdout).expect("summary");
    let r = &summary["import"]["reference"];
    assert_eq!(r["format"], "panoptic");
    assert_eq!(r["frames"], frames);
    assert_eq!(r["person"], 3);
    assert_eq!(r["mapped_joints"], map.len());
    let seen = r["seen_fraction"].as_f64().expect("seen");
    let expected = 1.0 - 1.0 / (frames * map.len()) as f64;
    assert!((seen - expected).abs() < 1e-12, "{seen} vs {expected}");
    // The rigid starts of noise-free keypoints lie within a body's size of the reference.
    let start = r["start_distance_m"].as_f64().expect("start distance");
    assert!(start < 0.5, "start {start} m from the reference");
    // Stored in lfit's world: the truth's joints again, where seen.
    let imported = Dataset::load(&out).expect("imported");
    let stored = imported.reference.as_ref().expect("reference");
    for f in 0..frames {
        let joints = lfit::model::metrics::joint_positions(&template, &truth.gt_poses[f]);
        let held = stored.seen(f);
        assert_eq!(held.len(), map.len() - usize::from(f == 2), "frame {f}");
        for (j, p) in held {
            assert!(p.distance(joints[j]) < 1e-9, "frame {f} joint {j}");
        }
        // The truth scores zero against it.
        let e = stored
            .errors(&template, f, &truth.gt_poses[f])
            .expect("errors");
        assert!(e.mpjpe_mm < 1e-6 && e.pa_mpjpe_mm.expect("pa") < 1e-6);
    }
    // The LM fit of the keypoints, scored against the reference.
    let fit = |data: &Path| -> Value {
        let res = d.join("fit.json");
        lfit_json(&lm_fit_args(data, &res, "200", &[]));
        read_json(&res)
    };
    let s = fit(&out);
    let m = s["summary"]["mean_reference_mpjpe_mm"]
        .as_f64()
        .expect("mpjpe");
    let pa = s["summary"]["mean_reference_pa_mpjpe_mm"]
        .as_f64()
        .expect("pa-mpjpe");
    eprintln!(
        "Panoptic-style reference, LM on six noise-free cameras: MPJPE {m:.2} mm, PA {pa:.2} mm"
    );
    assert_eq!(s["summary"]["reference_frames"], frames);
    // (PA-MPJPE's alignment minimises the squared distances, not their mean: it may end a
    // little above MPJPE.)
    assert!(m < 40.0 && pa < 40.0, "{m} {pa}");
    let rows = s["frames"].as_array().expect("rows");
    assert_eq!(rows[2]["reference_joints_seen"], map.len() - 1);
    // The reference moved 10 cm along the file's x: the same fit, 10 cm off by MPJPE (within
    // the fit's own error), equal by PA-MPJPE.
    let moved = d.join("moved");
    write_reference(&moved, frames, [0.1, 0.0, 0.0]);
    let out2 = d.join("kp2.npz");
    let o = import(&moved, &out2, &["--reference-person", "3"]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let s2 = fit(&out2);
    let m2 = s2["summary"]["mean_reference_mpjpe_mm"]
        .as_f64()
        .expect("mpjpe");
    let pa2 = s2["summary"]["mean_reference_pa_mpjpe_mm"]
        .as_f64()
        .expect("pa");
    assert!((m2 - 100.0).abs() <= m + 1e-6, "{m2} vs 100 ± {m}");
    assert!((pa2 - pa).abs() < 1e-6, "{pa2} vs {pa}");
    // A sequence: the acceleration error against the reference, which a constant offset
    // leaves as it is.
    let acc = s["summary"]["mean_reference_accel_error_mm"]
        .as_f64()
        .expect("accel");
    let acc2 = s2["summary"]["mean_reference_accel_error_mm"]
        .as_f64()
        .expect("accel");
    assert!(
        acc.is_finite() && (acc - acc2).abs() < 1e-6,
        "{acc} vs {acc2}"
    );
    // The same joints as 3D keypoints in a TRC file (millimetres, the labels as Pose2Sim names
    // COCO-17's points: RHip, LKnee, …), read in the import's layout: the limbs' joints held,
    // where Panoptic's also gave the root and the head.
    let coco = KeypointLayout::Coco17;
    // Pose2Sim names COCO-17's points as OpenPose does: BODY_25's name of each joint.
    let body25 = KeypointLayout::Body25.default_map();
    let labels: Vec<String> = coco
        .default_map()
        .iter()
        .map(|(p, _)| {
            let (_, name) = body25.iter().find(|m| m.0 == *p).expect("a BODY_25 name");
            name.to_string()
        })
        .collect();
    assert!(labels.iter().any(|l| l == "RHip"), "{labels:?}");
    let frames_pts = (0..frames)
        .map(|f| {
            let joints = lfit::model::metrics::joint_positions(&template, &truth.gt_poses[f]);
            coco.default_map()
                .iter()
                .map(|&(p, _)| {
                    let q = to_file * joints[joint_map[p].expect("mapped")];
                    Some(C3dPoint {
                        position: [1000.0 * q.x, 1000.0 * q.y, 1000.0 * q.z],
                        residual: 0.0,
                        cameras: 0,
                    })
                })
                .collect()
        })
        .collect();
    let trc_points = C3d {
        processor: Processor::Intel,
        labels,
        units: "mm".into(),
        scale: -1.0,
        rate: 30.0,
        first_frame: 1,
        analog_per_frame: 0,
        frames: frames_pts,
        non_finite: 0,
    };
    let trc = d.join("pose2sim.trc");
    std::fs::write(&trc, to_trc(&trc_points, "pose2sim.trc")).expect("trc");
    let out4 = d.join("kp4.npz");
    let o = import(&trc, &out4, &[]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let summary: Value = serde_json::from_slice(&o.stdout).expect("summary");
    assert_eq!(summary["import"]["reference"]["format"], "trc");
    assert_eq!(summary["import"]["reference"]["mapped_joints"], 12);
    let from_trc = Dataset::load(&out4)
        .expect("imported")
        .reference
        .expect("reference");
    for f in 0..frames {
        let joints = lfit::model::metrics::joint_positions(&template, &truth.gt_poses[f]);
        let held = from_trc.seen(f);
        assert_eq!(held.len(), 12);
        for (j, p) in held {
            assert!(p.distance(joints[j]) < 1e-8, "frame {f} joint {j}");
        }
    }
    let o = import(&trc, &out4, &["--reference-person", "3"]);
    assert_one_line_error(&o, "holds one subject");
    // Points of another skeleton's names (J<papers/000 joint>), six of them named onto model
    // joints by --reference-map: those six held, where they are.
    let mut other = trc_points.clone();
    other.labels = coco
        .default_map()
        .iter()
        .map(|(p, _)| format!("J{p}"))
        .collect();
    let trc2 = d.join("other.trc");
    std::fs::write(&trc2, to_trc(&other, "other.trc")).expect("trc");
    let chosen: Vec<(usize, String)> = coco.default_map()[..6]
        .iter()
        .map(|(p, _)| (joint_map[*p].expect("mapped"), format!("J{p}")))
        .collect();
    let map_file = d.join("reference-map.json");
    let map_json: serde_json::Map<String, Value> = chosen
        .iter()
        .map(|(j, l)| (template.rig.joints[*j].name.clone(), json!(l)))
        .collect();
    std::fs::write(&map_file, Value::Object(map_json).to_string()).expect("map");
    let out5 = d.join("kp5.npz");
    let o = import(&trc2, &out5, &["--reference-map", path_str(&map_file)]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let summary: Value = serde_json::from_slice(&o.stdout).expect("summary");
    assert_eq!(summary["import"]["reference"]["mapped_joints"], 6);
    assert_eq!(summary["import"]["reference"]["reference_map"], true);
    let mapped = Dataset::load(&out5)
        .expect("imported")
        .reference
        .expect("reference");
    for f in 0..frames {
        let joints = lfit::model::metrics::joint_positions(&template, &truth.gt_poses[f]);
        let held = mapped.seen(f);
        let mut expect: Vec<usize> = chosen.iter().map(|c| c.0).collect();
        expect.sort_unstable();
        assert_eq!(held.iter().map(|h| h.0).collect::<Vec<_>>(), expect);
        for (j, p) in held {
            assert!(p.distance(joints[j]) < 1e-8, "frame {f} joint {j}");
        }
    }
    // Without the map these labels name nothing; a map naming a point the file lacks, or
    // given with --reference-layout: one line.
    let out6 = d.join("kp6.npz");
    assert_one_line_error(&import(&trc2, &out6, &[]), "--reference-layout");
    std::fs::write(&map_file, json!({"nope": "J0"}).to_string()).expect("map");
    assert_one_line_error(
        &import(&trc2, &out6, &["--reference-map", path_str(&map_file)]),
        "is not a joint of model",
    );
    let root = template.rig.joints[0].name.clone();
    std::fs::write(&map_file, json!({root: "Pelvis"}).to_string()).expect("map");
    assert_one_line_error(
        &import(&trc2, &out6, &["--reference-map", path_str(&map_file)]),
        "'Pelvis' is not a point of the reference",
    );
    let o = import(
        &trc2,
        &out6,
        &[
            "--reference-map",
            path_str(&map_file),
            "--reference-layout",
            "coco17",
        ],
    );
    assert_one_line_error(&o, "--reference-layout");
    assert!(!out6.exists());
    // A reference of another length than the keypoints: refused, nothing written.
    let short = d.join("short");
    write_reference(&short, frames - 1, [0.0; 3]);
    let out3 = d.join("kp3.npz");
    let o = import(&short, &out3, &["--reference-person", "3"]);
    assert_one_line_error(&o, "the reference has 5 frames, the keypoints 6");
    assert!(!out3.exists());
}
