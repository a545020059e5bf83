//! `lfit synth --motions FILE...` and training configs with `"motions"` end to end (issue 15,
//! "Imported motions feed `lfit synth` and training configs"): a motion written here (a smooth
//! walk off the capture floor, with frames past the default model's joint limits) goes through
//! BVH export → `lfit motion import` → `lfit synth`, and the dataset's ground truth is exactly
//! the motion file's frames (root x/z moved onto the floor, clamped into the model's bounds where
//! outside, named `file:frame (clamped)`); same seed same bytes; the library mixes in with
//! `--with-library`; motions for other models and bad settings are one-line errors that write
//! nothing; a training config with `"motions"` trains.

#![allow(clippy::unwrap_used)]

mod support;

use std::path::{Path, PathBuf};
use std::process::Command;

use lfit::model::default_template;
use lfit::model::pose::Bounds;
use lfit::model::template::Template;
use lfit::synth::Dataset;
use lfit::synth::motion::file::MotionClip;
use support::{assert_one_line_error, lfit, lfit_json, path_str};

const FPS: f64 = 60.0;
const FRAMES: usize = 120;
/// Frames whose root yaw (±50° on the default model) is 69°.
const TURNED: std::ops::Range<usize> = 40..52;

/// A walk along x from 2 m (off the ±1.25 m floor box), every rotation moving smoothly within
/// ±0.15 rad (inside every limit of the default model: the ankles bend back to 10°), the root
/// turned past its limit in [`TURNED`].
fn walk(template: &Template) -> MotionClip {
    let dim = template.layout().dim();
    let poses = (0..FRAMES)
        .map(|f| {
            let t = f as f64 / FPS;
            let mut p: Vec<f64> = (0..dim)
                .map(|k| 0.15 * (2.1 * t + 0.9 * k as f64).sin())
                .collect();
            p[0] = 2.0 + 1.3 * t;
            p[1] = 0.03 * (9.0 * t).sin();
            p[2] = -0.7 + 0.1 * t;
            if TURNED.contains(&f) {
                p[4] = 1.2;
            }
            p
        })
        .collect();
    MotionClip {
        poses,
        fps: FPS,
        source: "synth_motions_cli test walk".into(),
        model: template.signature(),
    }
}

/// The walk written, exported as BVH and imported again (identity map, the default model): the
/// motion file `lfit synth` reads.
fn imported_walk(dir: &Path) -> PathBuf {
    let written = dir.join("written.npz");
    walk(&default_template()).write(&written).unwrap();
    let bvh = dir.join("walk.bvh");
    lfit_json(&[
        "motion",
        "export",
        "--format",
        "bvh",
        "--motion",
        path_str(&written),
        "--out",
        path_str(&bvh),
    ]);
    let imported = dir.join("walk.npz");
    lfit_json(&[
        "motion",
        "import",
        "--bvh",
        path_str(&bvh),
        "--out",
        path_str(&imported),
    ]);
    imported
}

fn synth(
    out: &Path,
    scenario: &str,
    frames: &str,
    seed: &str,
    extra: &[&str],
) -> serde_json::Value {
    let mut args = vec![
        "synth",
        "--quiet",
        "--modality",
        "markers",
        "--scenario",
        scenario,
        "--frames",
        frames,
        "--seed",
        seed,
        "--out",
        path_str(out),
    ];
    args.extend_from_slice(extra);
    lfit_json(&args)
}

/// (file frame, clamped) of a `frame_motions` entry `walk.npz:17` / `walk.npz:17 (clamped)`.
fn file_frame(name: &str) -> (usize, bool) {
    let rest = name
        .strip_prefix("walk.npz:")
        .unwrap_or_else(|| panic!("'{name}' is not a frame of walk.npz"));
    let clamped = rest.ends_with(" (clamped)");
    (
        rest.trim_end_matches(" (clamped)").parse().unwrap(),
        clamped,
    )
}

#[test]
fn ground_truth_poses_are_frames_of_the_motion_file_clamped_into_the_bounds() {
    let tmp = tempfile::tempdir().unwrap();
    let motion = imported_walk(tmp.path());
    let clip = MotionClip::read(&motion).unwrap();
    assert_eq!(clip.poses.len(), FRAMES);
    let global = Bounds::global();
    for scenario in ["local", "global"] {
        let out = tmp.path().join(format!("{scenario}.npz"));
        let summary = synth(
            &out,
            scenario,
            "200",
            "4",
            &["--motions", path_str(&motion)],
        );
        let data = Dataset::load(&out).unwrap();
        let (mut clamped_frames, mut exact_frames) = (0, 0);
        for i in 0..200 {
            let (f, clamped) = file_frame(&data.meta.frame_motions[i]);
            let gt = &data.gt_poses[i];
            // The root's x/z is put on the floor as the library's; the rest is the file's frame.
            assert!(
                gt[0].abs() <= 0.6 && gt[2].abs() <= 0.6,
                "frame {i}: {gt:?}"
            );
            let mut want = clip.poses[f].clone();
            want[0] = gt[0];
            want[2] = gt[2];
            let mut inside = want.clone();
            global.clamp(&mut inside);
            assert_eq!(clamped, inside != want, "frame {i} ({f})");
            assert_eq!(gt, &inside, "{scenario} frame {i} is file frame {f}");
            if clamped {
                clamped_frames += 1;
                // Only the turned root left the bounds: its yaw is held at the 50° limit.
                let moved: Vec<usize> = (0..want.len()).filter(|&k| inside[k] != want[k]).collect();
                assert!(TURNED.contains(&f), "frame {f} clamped: entries {moved:?}");
                assert_eq!(gt[4], 50f64.to_radians());
            } else {
                exact_frames += 1;
                assert_eq!(&gt[3..], &clip.poses[f][3..]);
            }
            let start = &data.start_poses[i];
            match scenario {
                "local" => {
                    assert!(Bounds::local(start).contains(gt), "frame {i}");
                    assert_ne!(start, gt, "the start is an earlier frame");
                }
                _ => assert!(start.iter().all(|&v| v == 0.0)),
            }
        }
        assert!(
            clamped_frames > 0 && exact_frames > 100,
            "{clamped_frames} {exact_frames}"
        );
        assert_eq!(summary["frames_from_files"], 200);
        assert_eq!(summary["frames_clamped"], clamped_frames);
        assert_eq!(summary["motion_files"][0]["frames"], FRAMES);
        assert_eq!(
            data.meta.config.motion_files[0].path,
            path_str(&motion),
            "the metadata names the file"
        );
        println!(
            "{scenario}: 200 frames of the imported walk, {clamped_frames} clamped into the bounds"
        );
    }

    // A sequence: consecutive frames of the file, every 2nd at --fps 30 from 60 Hz.
    let out = tmp.path().join("sequence.npz");
    let summary = synth(
        &out,
        "sequence",
        "40",
        "4",
        &["--motions", path_str(&motion)],
    );
    // The imported file runs at 1 / 0.01666667 s (BVH frame times have 8 decimals).
    assert!((summary["fps"].as_f64().unwrap() - 30.0).abs() < 1e-6);
    let data = Dataset::load(&out).unwrap();
    assert_eq!(data.meta.config.fps, clip.fps / 2.0);
    let first = file_frame(&data.meta.frame_motions[0]).0;
    let mut limits = Bounds::global();
    limits.lower.drain(..3);
    limits.upper.drain(..3);
    for i in 0..40 {
        let (f, clamped) = file_frame(&data.meta.frame_motions[i]);
        assert_eq!(f, first + 2 * i);
        let gt = &data.gt_poses[i];
        let mut want = clip.poses[f][3..].to_vec();
        limits.clamp(&mut want);
        assert_eq!(clamped, want[..] != clip.poses[f][3..]);
        assert_eq!(&gt[3..], &want[..], "rotations of frame {f}");
        assert_eq!(gt[1], clip.poses[f][1]);
        if i > 0 {
            // The path is the file's, centred on the floor.
            let prev = &data.gt_poses[i - 1];
            let step = &clip.poses[f - 2];
            for k in [0, 2] {
                let d = (gt[k] - prev[k]) - (clip.poses[f][k] - step[k]);
                assert!(d.abs() < 1e-12, "step {i} axis {k}: {d}");
            }
            assert_eq!(&data.start_poses[i], prev);
        }
    }
}

#[test]
fn same_seed_same_bytes_and_the_library_mixes_in() {
    let tmp = tempfile::tempdir().unwrap();
    let motion = imported_walk(tmp.path());
    let m = path_str(&motion);
    for scenario in ["local", "sequence"] {
        let path = |name: &str| tmp.path().join(format!("{scenario}_{name}.npz"));
        synth(&path("a"), scenario, "30", "11", &["--motions", m]);
        synth(
            &path("b"),
            scenario,
            "30",
            "11",
            &["--motions", m, "--threads", "1"],
        );
        synth(&path("c"), scenario, "30", "12", &["--motions", m]);
        let [a, b, c] = ["a", "b", "c"].map(|n| std::fs::read(path(n)).unwrap());
        assert_eq!(a, b, "{scenario}: same seed, same bytes");
        assert_ne!(a, c, "{scenario}: another seed, other frames");
    }
    // With the library: both kinds of frame, reproducibly.
    let mixed = |name: &str| {
        let out = tmp.path().join(name);
        synth(
            &out,
            "local",
            "80",
            "5",
            &["--motions", m, "--with-library"],
        );
        out
    };
    let (x, y) = (mixed("x.npz"), mixed("y.npz"));
    assert_eq!(std::fs::read(&x).unwrap(), std::fs::read(&y).unwrap());
    let names = Dataset::load(&x).unwrap().meta.frame_motions;
    let from_file = names.iter().filter(|n| n.starts_with("walk.npz:")).count();
    assert!(
        (20..60).contains(&from_file),
        "{from_file} of 80 from the file"
    );
    let library = [
        "walk", "jog", "wave", "squat", "reach", "punch", "kick", "jump", "turn",
    ];
    assert!(
        names
            .iter()
            .all(|n| n.starts_with("walk.npz:") || library.contains(&n.as_str()))
    );
    // Augmented: reproducible, and other frames than the plain draws (--mirror, --heading).
    let augmented = |name: &str, extra: &[&str]| {
        let out = tmp.path().join(name);
        let mut args = vec!["--motions", m];
        args.extend(extra);
        synth(&out, "local", "40", "5", &args);
        std::fs::read(&out).unwrap()
    };
    let plain = augmented("plain.npz", &[]);
    let turned = augmented(
        "turned.npz",
        &["--mirror", "--heading", "--jitter-deg", "3"],
    );
    assert_eq!(
        turned,
        augmented(
            "turned2.npz",
            &["--mirror", "--heading", "--jitter-deg", "3"]
        )
    );
    assert_ne!(turned, plain, "augmentation changes the frames");
    // Without --motions the library is what it was: library names only, and --library-motions
    // (formerly --motions LIST) restricts it.
    let out = tmp.path().join("lib.npz");
    synth(
        &out,
        "local",
        "20",
        "5",
        &["--library-motions", "squat,kick"],
    );
    let names = Dataset::load(&out).unwrap().meta.frame_motions;
    assert!(
        names.iter().all(|n| n == "squat" || n == "kick"),
        "{names:?}"
    );
    // The extended kinds join by name, and the default stays the papers' nine.
    let out = tmp.path().join("ext.npz");
    synth(
        &out,
        "local",
        "120",
        "5",
        &[
            "--library-motions",
            "sit,crouch,kneel,pickup,throw,overhead,lie,crawl,fall,stairs,spin,circle,flight",
        ],
    );
    let names = Dataset::load(&out).unwrap().meta.frame_motions;
    let extended = [
        "sit", "crouch", "kneel", "pickup", "throw", "overhead", "lie", "crawl", "fall", "stairs",
        "spin", "circle", "flight",
    ];
    assert!(
        names.iter().all(|n| extended.contains(&n.as_str())),
        "{names:?}"
    );
    assert!(
        extended.iter().all(|k| names.iter().any(|n| n == k)),
        "{names:?}"
    );
    let out = tmp.path().join("default.npz");
    synth(&out, "local", "200", "5", &[]);
    let names = Dataset::load(&out).unwrap().meta.frame_motions;
    assert!(
        names.iter().all(|n| library.contains(&n.as_str())),
        "{names:?}"
    );
}

#[test]
fn motions_for_other_models_and_bad_settings_are_refused_with_nothing_written() {
    let tmp = tempfile::tempdir().unwrap();
    let motion = imported_walk(tmp.path());
    let m = path_str(&motion);
    let out = tmp.path().join("never.npz");
    let o = path_str(&out);
    // A motion made for the morphable body, and the default model's motion on it.
    let (morphable, _) = lfit::model::body::morphable_default_template().unwrap();
    let other = tmp.path().join("morphable.npz");
    walk(&morphable).write(&other).unwrap();
    let base = ["synth", "--modality", "markers", "--out", o];
    let cases: Vec<(Vec<&str>, &str)> = vec![
        (vec!["--motions", path_str(&other)], "made for model"),
        (
            vec!["--motions", m, "--shape", "morphable"],
            "the motion was made for model",
        ),
        (vec!["--motions", m, path_str(&other)], "morphable"),
        (vec!["--motions", "no/such/file.npz"], "no/such/file.npz"),
        (vec!["--motions", "walk,jog"], "--library-motions walk,jog"),
        (
            vec!["--motions", m, "--source", "uniform"],
            "--source motion",
        ),
        (vec!["--with-library"], "--motions"),
        (vec!["--mirror"], "--motions FILE"),
        (vec!["--motions", m, "--jitter-deg", "90"], "jitter_deg"),
        (vec!["--motions", m, "--jitter-deg", "nan"], "jitter_deg"),
        (
            vec!["--motions", m, "--scenario", "sequence", "--frames", "100"],
            "longest file has 120",
        ),
        (vec!["--motions", o], "cannot read"),
        (vec!["--motions", "Cargo.toml"], "Cargo.toml"),
        (vec!["--uniform-share", "1.5"], "uniform_share"),
        (vec!["--uniform-share", "nan"], "uniform_share"),
        (
            vec!["--uniform-share", "0.3", "--source", "face"],
            "uniform_share",
        ),
        (
            vec!["--uniform-share", "0.3", "--scenario", "sequence"],
            "uniform_share",
        ),
    ];
    for (extra, needle) in cases {
        let mut args = base.to_vec();
        if !extra.contains(&"--frames") {
            args.extend(["--frames", "5"]);
        }
        args.extend(extra);
        assert_one_line_error(&lfit(&args), needle);
        assert!(!out.exists(), "{args:?} wrote {o}");
    }
}

/// A tiny training config, `motions` relative to the directory it runs in.
fn train_config(dir: &Path, name: &str, motions: &str) -> PathBuf {
    let p = dir.join(name);
    let text = format!(
        r#"{{"modality": "markers", "network": {{"hidden": 16, "layers": 1, "init_width": 16, "iterations": 2, "dropout": 0.0}},
            "steps": 20, "batch": 4, "val_frames": 4, "val_every": 1, "checkpoint_every": 2, "stats_frames": 8, "seed": 3{motions}}}"#
    );
    std::fs::write(&p, text).unwrap();
    p
}

fn train_in(dir: &Path, config: &Path, out: &str) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_lfit"))
        .current_dir(dir)
        .args(["-q", "train", "--config", path_str(config), "--out", out])
        .args(["--steps", "2", "--device", "ndarray"])
        .env("RUST_BACKTRACE", "0")
        .output()
        .unwrap()
}

#[test]
fn a_training_config_with_motions_trains_on_them() {
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path();
    let motion = imported_walk(d);
    assert_eq!(motion, d.join("walk.npz"));
    // Old configs (no "motions") stay valid; "motions" is relative to the working directory.
    let plain = train_config(d, "plain.json", "");
    let with = train_config(d, "with.json", r#", "motions": ["walk.npz"]"#);
    for (config, out) in [(&plain, "ck_plain"), (&with, "ck_motions")] {
        let run = train_in(d, config, out);
        assert!(
            run.status.success(),
            "{}",
            String::from_utf8_lossy(&run.stderr)
        );
        let summary: serde_json::Value = serde_json::from_slice(&run.stdout).unwrap();
        assert_eq!(summary["summary"]["steps"], 2);
    }
    let card = |out: &str| -> serde_json::Value {
        serde_json::from_slice(&std::fs::read(d.join(out).join("metrics.json")).unwrap()).unwrap()
    };
    let (plain_card, motions_card) = (card("ck_plain"), card("ck_motions"));
    assert_eq!(motions_card["train_config"]["motions"][0], "walk.npz");
    assert!(plain_card["train_config"].get("motions").is_none());
    // The validation set is other poses: the walk's, not the library's.
    assert_ne!(
        plain_card["validation"]["v2v_mm"],
        motions_card["validation"]["v2v_mm"]
    );
    // A missing file, a motion for another model, with_library alone: one line, nothing written.
    let (morphable, _) = lfit::model::body::morphable_default_template().unwrap();
    walk(&morphable).write(&d.join("morphable.npz")).unwrap();
    for (extra, needle) in [
        (r#", "motions": ["missing.npz"]"#, "missing.npz"),
        (r#", "motions": ["morphable.npz"]"#, "made for model"),
        (r#", "with_library": true"#, "motions"),
    ] {
        let config = train_config(d, "bad.json", extra);
        assert_one_line_error(&train_in(d, &config, "ck_bad"), needle);
        assert!(!d.join("ck_bad").exists());
    }
}
