//! `lfit render` from the command line: synth → fit → render writes a PNG of the requested size
//! with the fit, the ground truth and the observations in every panel; bare poses and the rest
//! pose; the pictures in bench reports; bad input → one line, non-zero exit, nothing written.

mod support;

use std::path::{Path, PathBuf};

use support::{assert_one_line_error, lfit, lfit_json, path_str};

const BACKGROUND: [u8; 3] = [250, 250, 250];

fn synth(dir: &Path, modality: &str, frames: usize, seed: u64) -> PathBuf {
    let out = dir.join(format!("{modality}_{seed}.npz"));
    lfit_json(&[
        "synth",
        "--modality",
        modality,
        "--frames",
        &frames.to_string(),
        "--seed",
        &seed.to_string(),
        "--out",
        path_str(&out),
        "-q",
    ]);
    out
}

fn fit(dir: &Path, data: &Path, frames: &str) -> PathBuf {
    let stem = data.file_stem().unwrap().to_string_lossy().into_owned();
    let out = dir.join(format!("{stem}_fit.json"));
    lfit_json(&[
        "fit",
        "--data",
        path_str(data),
        "--method",
        "lm",
        "--budget",
        "30",
        "--frames",
        frames,
        "--out",
        path_str(&out),
        "-q",
    ]);
    out
}

/// A decoded RGB image.
struct Image {
    width: u32,
    height: u32,
    rgb: Vec<u8>,
}

impl Image {
    fn load(path: &Path) -> Self {
        let bytes = std::fs::read(path).expect("the PNG exists");
        let decoder = png::Decoder::new(std::io::Cursor::new(bytes));
        let mut reader = decoder.read_info().expect("a valid PNG header");
        let mut buf = vec![0; reader.output_buffer_size()];
        let info = reader.next_frame(&mut buf).expect("valid PNG data");
        assert_eq!(info.color_type, png::ColorType::Rgb);
        assert_eq!(info.bit_depth, png::BitDepth::Eight);
        buf.truncate(info.buffer_size());
        Self {
            width: info.width,
            height: info.height,
            rgb: buf,
        }
    }

    fn get(&self, x: u32, y: u32) -> [u8; 3] {
        let i = 3 * (y as usize * self.width as usize + x as usize);
        [self.rgb[i], self.rgb[i + 1], self.rgb[i + 2]]
    }

    /// Pixels of columns `x0..x1` (below the title band) matching `pred`.
    fn count(&self, x0: u32, x1: u32, pred: impl Fn([u8; 3]) -> bool) -> usize {
        let mut n = 0;
        for y in 30..self.height {
            for x in x0..x1 {
                if pred(self.get(x, y)) {
                    n += 1;
                }
            }
        }
        n
    }
}

/// The fit's blue (shaded): blue well above red.
fn is_fit(c: [u8; 3]) -> bool {
    i32::from(c[2]) > i32::from(c[0]) + 40 && c[2] > 60
}

/// Observation red.
fn is_observed(c: [u8; 3]) -> bool {
    c == [220, 40, 40]
}

/// The ground truth's outline.
fn is_truth_outline(c: [u8; 3]) -> bool {
    c == [70, 70, 70]
}

fn not_background(c: [u8; 3]) -> bool {
    c != BACKGROUND
}

#[test]
fn synth_fit_render_draws_fit_truth_and_markers_in_both_panels() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let data = synth(d, "markers", 3, 3);
    let fitted = fit(d, &data, "0..3");
    let out = d.join("frame1.png");
    let summary = lfit_json(&[
        "render",
        "--data",
        path_str(&data),
        "--fit",
        path_str(&fitted),
        "--frame",
        "1",
        "--size",
        "600x400",
        "--out",
        path_str(&out),
    ]);
    assert_eq!(summary["panels"], 2);
    assert_eq!(summary["method"], "lm");
    assert!(summary["frames"][0]["v2v_mm"].as_f64().unwrap() >= 0.0);
    let img = Image::load(&out);
    assert_eq!((img.width, img.height), (600, 400));
    // Front panel = left half, side panel = right half.
    for (name, x0, x1) in [("front", 0, 300), ("side", 300, 600)] {
        let body = img.count(x0, x1, not_background);
        let fit_px = img.count(x0, x1, is_fit);
        let red = img.count(x0, x1, is_observed);
        let outline = img.count(x0, x1, is_truth_outline);
        assert!(body > 3000, "{name}: {body} non-background pixels");
        assert!(fit_px > 2000, "{name}: {fit_px} fit pixels");
        assert!(red > 30, "{name}: {red} observation pixels");
        assert!(
            outline > 100,
            "{name}: {outline} ground-truth outline pixels"
        );
        // The body is taller than wide in the front view and not cut by the panel edges.
        assert!(body < ((x1 - x0) * 370) as usize / 2, "{name}: {body}");
    }

    // Several frames: one row each, default size 300 × 380 per panel.
    let out2 = d.join("frames.png");
    lfit_json(&[
        "render",
        "--data",
        path_str(&data),
        "--fit",
        path_str(&fitted),
        "--frame",
        "0,2",
        "--out",
        path_str(&out2),
    ]);
    let img2 = Image::load(&out2);
    assert_eq!((img2.width, img2.height), (600, 2 * 380 + 26));
    let top: usize = (30..img2.height / 2)
        .flat_map(|y| (0..300).map(move |x| (x, y)))
        .filter(|&(x, y)| is_fit(img2.get(x, y)))
        .count();
    let bottom: usize = (img2.height / 2..img2.height)
        .flat_map(|y| (0..300).map(move |x| (x, y)))
        .filter(|&(x, y)| is_fit(img2.get(x, y)))
        .count();
    assert!(top > 2000 && bottom > 2000, "{top} {bottom}");

    // The dataset alone: ground truth as the body, no fit colour.
    let out3 = d.join("gt.png");
    lfit_json(&[
        "render",
        "--data",
        path_str(&data),
        "--frame",
        "2",
        "--out",
        path_str(&out3),
    ]);
    let img3 = Image::load(&out3);
    assert_eq!(img3.count(0, img3.width, is_fit), 0);
    assert!(img3.count(0, 300, not_background) > 3000);
    assert!(img3.count(0, 300, is_observed) > 30);
}

#[test]
fn keypoints_are_drawn_in_their_camera_view() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let data = synth(d, "keypoints2d", 2, 5);
    let fitted = fit(d, &data, "0..2");
    let out = d.join("kp.png");
    let summary = lfit_json(&[
        "render",
        "--data",
        path_str(&data),
        "--fit",
        path_str(&fitted),
        "--camera",
        "1",
        "--size",
        "900x400",
        "--out",
        path_str(&out),
    ]);
    assert_eq!(summary["panels"], 3);
    let img = Image::load(&out);
    assert_eq!((img.width, img.height), (900, 400));
    for (name, x0) in [("front", 0), ("side", 300), ("camera", 600)] {
        assert!(img.count(x0, x0 + 300, is_fit) > 500, "{name}: fit");
    }
    // 2D keypoints only in the camera panel.
    assert_eq!(img.count(0, 600, is_observed), 0);
    assert!(img.count(600, 900, is_observed) > 30);
    let e = lfit(&[
        "render",
        "--data",
        path_str(&data),
        "--camera",
        "9",
        "--out",
        path_str(&d.join("bad.png")),
    ]);
    assert_one_line_error(&e, "camera");
    assert!(!d.join("bad.png").exists());
}

#[test]
fn bare_poses_and_the_rest_pose_render() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let rest = d.join("rest.png");
    lfit_json(&["render", "--out", path_str(&rest), "--size", "400x400"]);
    let img = Image::load(&rest);
    assert_eq!((img.width, img.height), (400, 400));
    // Front (left) and side (right): the body in both, the front wider.
    let (front, side) = (
        img.count(0, 200, not_background),
        img.count(200, 400, not_background),
    );
    assert!(
        front > 3000 && side > 1000 && front > side,
        "{front} {side}"
    );

    // Two poses (the second with its root moved up 0.5 m): 2 columns × 2 rows.
    let mut lifted = vec![0.0; 57];
    lifted[1] = 0.5;
    lifted[3 + 3 * 15 + 2] = 1.2; // a raised arm
    let pose = d.join("poses.json");
    std::fs::write(
        &pose,
        serde_json::json!({ "poses": [vec![0.0; 57], lifted] }).to_string(),
    )
    .unwrap();
    let out = d.join("poses.png");
    let s = lfit_json(&["render", "--pose", path_str(&pose), "--out", path_str(&out)]);
    assert_eq!(s["poses"], 2);
    assert_eq!(s["panels"], 4);
    let img = Image::load(&out);
    assert_eq!((img.width, img.height), (600, 2 * 380 + 26));
}

#[test]
fn bench_reports_link_best_median_and_worst_pictures() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let cfg = d.join("b.toml");
    std::fs::write(
        &cfg,
        "name = \"pics\"\nmethods = [\"lm\", \"cma\"]\nbudgets = [10, 30]\n[synth]\nmodality = \"markers\"\nframes = 4\nseed = 2\n",
    )
    .unwrap();
    let out = d.join("bench");
    lfit_json(&[
        "-q",
        "bench",
        "--config",
        path_str(&cfg),
        "--out",
        path_str(&out),
    ]);
    let md = std::fs::read_to_string(out.join("report.md")).unwrap();
    assert!(md.contains("## Pictures"), "{md}");
    for m in ["lm", "cma"] {
        assert!(
            md.contains(&format!("](pictures/{m}.png)")),
            "no link to {m}"
        );
        let img = Image::load(&out.join("pictures").join(format!("{m}.png")));
        // Three rows (best, median, worst) of front and side.
        assert_eq!((img.width, img.height), (440, 3 * 270 + 22));
        for row in 0..3 {
            let y0 = 22 + row * 270;
            let n = (y0..y0 + 270)
                .flat_map(|y| (0..220).map(move |x| (x, y)))
                .filter(|&(x, y)| is_fit(img.get(x, y)))
                .count();
            assert!(n > 300, "{m} row {row}: {n} fit pixels");
        }
    }
    // Poses are recorded for repetition 0 at the largest budget only: 2 methods × 4 frames.
    let poses = std::fs::read_to_string(out.join("poses.jsonl")).unwrap();
    assert_eq!(poses.lines().count(), 8);
    assert!(poses.lines().all(|l| l.contains("\"budget\":30")));
}

#[test]
fn bad_input_exits_with_one_line_and_writes_nothing() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let data = synth(d, "markers", 3, 3);
    let other = synth(d, "markers", 3, 4);
    let kp = synth(d, "keypoints2d", 3, 3);
    let fitted = fit(d, &data, "0..2");
    let out = d.join("out.png");
    let p = |x: &Path| path_str(x).to_string();
    let base = |extra: &[&str]| -> Vec<String> {
        let mut v: Vec<String> = vec!["render".into(), "--out".into(), p(&out)];
        v.extend(extra.iter().map(|s| s.to_string()));
        v
    };
    let check = |args: Vec<String>, needle: &str| {
        let refs: Vec<&str> = args.iter().map(String::as_str).collect();
        let o = lfit(&refs);
        assert_one_line_error(&o, needle);
        assert!(!out.exists(), "{args:?} wrote {}", out.display());
        // No temporary file left behind either.
        let leftovers: Vec<_> = std::fs::read_dir(d)
            .unwrap()
            .filter_map(|e| e.ok())
            .filter(|e| e.file_name().to_string_lossy().contains(".tmp"))
            .collect();
        assert!(leftovers.is_empty(), "{leftovers:?}");
    };
    let (data_s, other_s, kp_s, fit_s) = (p(&data), p(&other), p(&kp), p(&fitted));
    // Frame out of range of the dataset, and a frame the fit does not have.
    check(base(&["--data", &data_s, "--frame", "3"]), "out of range");
    check(
        base(&["--data", &data_s, "--fit", &fit_s, "--frame", "2"]),
        "no fit of frame 2",
    );
    // A fit of another dataset (same model and modality), of another modality.
    check(
        base(&["--data", &other_s, "--fit", &fit_s]),
        "another dataset",
    );
    check(base(&["--data", &kp_s, "--fit", &fit_s]), "modality");
    // A fit with other parameter dimensions, or a recorded model signature of another model.
    let mut value: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&fitted).unwrap()).unwrap();
    let mut short = value.clone();
    short["frames"][0]["pose"] = serde_json::json!(vec![0.0; 50]);
    let short_path = d.join("short.json");
    std::fs::write(&short_path, short.to_string()).unwrap();
    check(
        base(&["--data", &data_s, "--fit", &p(&short_path)]),
        "expected 57",
    );
    value["model"] = serde_json::json!({
        "id": "default", "layout": { "joints": ["root"], "shape": 0, "expression": 0 },
        "hash": "0000000000000000"
    });
    let sig_path = d.join("sig.json");
    std::fs::write(&sig_path, value.to_string()).unwrap();
    check(
        base(&["--data", &data_s, "--fit", &p(&sig_path)]),
        "signature",
    );
    // A model other than the dataset's.
    let tall = d.join("tall");
    lfit_json(&[
        "template",
        "export",
        "--out-dir",
        path_str(&tall),
        "--shape",
        "tall",
    ]);
    check(base(&["--data", &data_s, "--model", &p(&tall)]), "template");
    // Bad sizes, flags and files.
    check(base(&["--size", "10x10"]), "--size");
    check(base(&["--size", "wide"]), "--size");
    check(base(&["--fit", &fit_s]), "--fit needs --data");
    check(base(&["--data", &p(&d.join("missing.npz"))]), "missing.npz");
    check(
        base(&["--pose", &p(&d.join("missing.json"))]),
        "missing.json",
    );
    check(base(&["--skinning", "xyz"]), "skinning");
    // An unwritable output, and a name that is not a PNG.
    let o = lfit(&["render", "--out", path_str(&d.join("no/such/dir/x.png"))]);
    assert_one_line_error(&o, "x.png");
    let o = lfit(&["render", "--out", path_str(&d.join("x.jpg"))]);
    assert_one_line_error(&o, ".png");
    assert!(!d.join("x.jpg").exists());
}
