//! Training data for camera-agnostic keypoints2d networks and markers networks robust to missing
//! markers: random rigs per frame (seeded, 1–8 cameras), marker dropout at the configured rate,
//! pooled feature statistics, and the one-line refusals of settings that do not fit.

use std::sync::Arc;

use lfit_model::energy::{Energy, Target};
use lfit_model::observe::{Modality, Sensor};
use lfit_model::{Template, default_template};
use lfit_nn::{NetConfig, Views};
use lfit_train::{
    Frames, Motions, TrainConfig, base_energy, measure_stats_with, network_residual_dim,
    training_frames,
};

fn template() -> Arc<Template> {
    Arc::new(default_template())
}

fn pooled() -> TrainConfig {
    TrainConfig {
        modality: Modality::Keypoints2d,
        network: NetConfig {
            views: Views::Pooled,
            ..NetConfig::default()
        },
        ..TrainConfig::default()
    }
}

fn frames_of(config: &TrainConfig, n: usize, seed: u64) -> Frames {
    let t = template();
    let sensor = Sensor::default_for(config.modality, &t);
    let base = base_energy(&t, &sensor).expect("energy");
    training_frames(config, &t, &sensor, &base, n, seed, &Motions::default()).expect("frames")
}

fn target(e: &Energy) -> (&[f64], &[bool]) {
    match e.target() {
        Target::Sparse { values, visible } => (values, visible),
        _ => unreachable!("sparse"),
    }
}

#[test]
fn a_pooled_network_trains_on_seeded_random_rigs_of_1_to_8_cameras() {
    let config = pooled();
    let a = frames_of(&config, 48, 11);
    let per = 2 * default_template().rig.num_joints();
    let mut counts = [0usize; 9];
    let (mut seen, mut total) = (0usize, 0usize);
    for e in &a.energies {
        let n = e.sensor().cameras().len();
        counts[n] += 1;
        let (values, visible) = target(e);
        assert_eq!(values.len(), n * per, "a rig of {n} cameras");
        seen += visible.iter().filter(|&&v| v).count();
        total += visible.len();
    }
    assert_eq!(counts[0], 0);
    assert!(
        counts[1..].iter().filter(|&&c| c > 0).count() >= 6,
        "camera counts spread over 1..=8: {counts:?}"
    );
    // The rigs look at the subject: most keypoints are seen.
    let fraction = seen as f64 / total as f64;
    assert!(fraction > 0.6, "visible fraction {fraction}");
    // Same seed, same rigs and observations; another seed, others.
    let b = frames_of(&config, 48, 11);
    let c = frames_of(&config, 48, 12);
    for (x, y) in a.energies.iter().zip(&b.energies) {
        assert_eq!(x.sensor(), y.sensor());
        assert_eq!(target(x), target(y));
    }
    assert!(
        a.energies
            .iter()
            .zip(&c.energies)
            .any(|(x, y)| x.sensor() != y.sensor())
    );
    // The poses are the synthesised ones: only the observation changes.
    let plain = {
        let t = template();
        let sensor = Sensor::default_for(Modality::Keypoints2d, &t);
        let base = base_energy(&t, &sensor).expect("energy");
        lfit_train::synth_frames(&t, &sensor, &base, 48, 11, 1.0).expect("frames")
    };
    assert_eq!(plain.dataset.gt_poses, a.dataset.gt_poses);

    // Pooled statistics have the pooled network's lengths.
    let t = template();
    let mut net = config.network.clone();
    net.modality = Modality::Keypoints2d;
    net.residual_dim =
        network_residual_dim(&net, &Sensor::default_for(Modality::Keypoints2d, &t), &t)
            .expect("dim");
    assert_eq!(net.residual_dim, per);
    let stats = measure_stats_with(&a, &net).expect("stats");
    stats.validate(&net).expect("pooled lengths");
    assert_eq!(stats.observation.mean.len(), net.obs_features());
    // A fixed-rig network's residual is the whole sensor's.
    let fixed = NetConfig::default();
    let six = Sensor::default_for(Modality::Keypoints2d, &t);
    assert_eq!(
        network_residual_dim(&fixed, &six, &t).expect("dim"),
        six.residual_dim(&t)
    );
}

/// Fraction of the markers of `frames` that are not seen.
fn hidden_fraction(frames: &Frames) -> f64 {
    let (mut hidden, mut total) = (0usize, 0usize);
    for e in &frames.energies {
        let (values, visible) = target(e);
        for (v, s) in values.chunks(3).zip(visible.chunks(3)) {
            total += 1;
            if !s[0] {
                hidden += 1;
                assert!(s.iter().all(|&b| !b), "a whole marker is hidden");
                assert!(v.iter().all(|&x| x == 0.0), "a hidden marker reads 0");
            }
        }
    }
    hidden as f64 / total as f64
}

#[test]
fn marker_dropout_hides_its_fraction_of_whole_markers_and_0_hides_none() {
    let markers = |rate: f64, noise: f64| TrainConfig {
        modality: Modality::Markers,
        marker_dropout: rate,
        noise,
        ..TrainConfig::default()
    };
    // 200 frames × 53 markers: the standard error of a 15 % rate is 0.35 %.
    let frames = 200;
    let none = frames_of(&markers(0.0, 0.0), frames, 5);
    assert_eq!(
        hidden_fraction(&none),
        0.0,
        "no dropout, no noise: all seen"
    );
    let dropped = frames_of(&markers(0.15, 0.0), frames, 5);
    let f = hidden_fraction(&dropped);
    assert!((f - 0.15).abs() < 0.015, "hidden fraction {f}, rate 0.15");
    // The truth and the seen markers are untouched.
    assert_eq!(none.dataset.gt_poses, dropped.dataset.gt_poses);
    for (a, b) in none.energies.iter().zip(&dropped.energies) {
        let ((va, _), (vb, sb)) = (target(a), target(b));
        for i in 0..va.len() {
            if sb[i] {
                assert_eq!(va[i], vb[i]);
            }
        }
    }
    // Seeded: the same seed hides the same markers, another seed others.
    let again = frames_of(&markers(0.15, 0.0), frames, 5);
    let other = frames_of(&markers(0.15, 0.0), frames, 6);
    assert!(
        dropped
            .energies
            .iter()
            .zip(&again.energies)
            .all(|(a, b)| target(a) == target(b))
    );
    assert!(
        dropped
            .energies
            .iter()
            .zip(&other.energies)
            .any(|(a, b)| target(a).1 != target(b).1)
    );
    // On top of the noise model's own dropouts (5 % at noise 1): 1 − 0.95 · 0.85.
    let noisy = frames_of(&markers(0.15, 1.0), frames, 5);
    let f = hidden_fraction(&noisy);
    assert!(
        (f - (1.0 - 0.95 * 0.85)).abs() < 0.02,
        "hidden fraction {f} with noise"
    );
}

#[test]
fn settings_that_do_not_fit_are_one_line_errors() {
    let cases: Vec<(TrainConfig, &str)> = vec![
        (
            TrainConfig {
                marker_dropout: 0.1,
                ..pooled()
            },
            "marker_dropout",
        ),
        (
            TrainConfig {
                modality: Modality::Markers,
                marker_dropout: 1.0,
                ..TrainConfig::default()
            },
            "must be in [0, 1)",
        ),
        (
            TrainConfig {
                modality: Modality::Markers,
                ..pooled()
            },
            "pools keypoints2d cameras",
        ),
        (
            TrainConfig {
                modality: Modality::Keypoints2d,
                rigs: Some(Default::default()),
                ..TrainConfig::default()
            },
            "set network.views to \"pooled\"",
        ),
        (
            TrainConfig {
                rigs: Some(lfit_model::camera::RigRanges {
                    cameras: [3, 2],
                    ..Default::default()
                }),
                ..pooled()
            },
            "rig ranges: cameras",
        ),
    ];
    for (config, needle) in cases {
        let e = config.validate().expect_err(needle).to_string();
        assert!(e.contains(needle) && !e.contains('\n'), "{needle}: {e}");
    }
    pooled().validate().expect("pooled keypoints2d");
    // The shipped configs parse and validate.
    let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
    for name in ["keypoints2d-pooled", "markers-dropout"] {
        let c = TrainConfig::load(&root.join(format!("configs/{name}.json"))).expect(name);
        assert!(
            c.network.views == Views::Pooled || c.marker_dropout == 0.1,
            "{name}"
        );
    }
    let c = TrainConfig::load(&root.join("configs/keypoints2d-pooled.json")).expect("pooled");
    assert_eq!(c.rigs, Some(lfit_model::camera::RigRanges::default()));
}

/// `"noise_spread"` reaches the frames through [`Motions`] and the random rigs of a pooled
/// network observe each frame with the noise it was synthesised with: each subject's own factor
/// of the set's noise (`lfit_synth::frame_noise`), not the set's noise for all.
#[test]
fn a_noise_spread_gives_each_frame_its_own_noise_in_random_rigs() {
    let config = TrainConfig {
        noise_spread: 0.9,
        ..pooled()
    };
    config
        .validate()
        .expect("a pooled config with a noise spread");
    let t = template();
    let sensor = Sensor::default_for(Modality::Keypoints2d, &t);
    let base = base_energy(&t, &sensor).expect("energy");
    let motions = Motions::load(&config, &t).expect("motions");
    let frames = training_frames(&config, &t, &sensor, &base, 40, 11, &motions).expect("frames");
    let synthesised = &frames.dataset.meta.config;
    assert_eq!(synthesised.noise_spread, 0.9);
    let pixel = lfit_model::noise::NoiseConfig::default().pixel_sigma;
    let mut factors = Vec::new();
    for (i, (e, gt)) in frames
        .energies
        .iter()
        .zip(&frames.dataset.gt_poses)
        .enumerate()
    {
        let sigma = lfit_synth::frame_noise(synthesised, i).pixel_sigma;
        let clean = e.sensor().predict_sparse(&t, gt).values;
        let (values, visible) = target(e);
        let mut dev: Vec<f64> = values
            .iter()
            .zip(&clean)
            .zip(visible)
            .filter(|(_, seen)| **seen)
            .map(|((o, c), _)| (o - c).abs())
            .collect();
        if dev.len() < 20 {
            continue;
        }
        dev.sort_by(f64::total_cmp);
        let ratio = dev[dev.len() / 2] / (0.6745 * sigma);
        assert!(
            (0.5..1.7).contains(&ratio),
            "frame {i}: σ {sigma} px, {ratio}"
        );
        factors.push(sigma / pixel);
    }
    assert!(
        factors.len() >= 30,
        "{} frames with 20 keypoints",
        factors.len()
    );
    let lo = factors.iter().copied().fold(f64::INFINITY, f64::min);
    let hi = factors.iter().copied().fold(0.0, f64::max);
    assert!(lo < 0.4 && hi > 0.8, "factors {lo}..{hi}");
    // A sequence window gets the spread too.
    let mut window =
        lfit_synth::SynthConfig::new(Modality::Keypoints2d, lfit_synth::Scenario::Sequence, 4, 1);
    motions.apply_to(&mut window);
    assert_eq!(window.noise_spread, 0.9);
    for bad in [-0.5, 2.0, f64::NAN] {
        let e = TrainConfig {
            noise_spread: bad,
            ..pooled()
        }
        .validate()
        .unwrap_err()
        .to_string();
        assert!(e.contains("noise_spread"), "{e}");
    }
}

/// Every training config in `configs/` (a JSON object with `"modality"` and `"steps"`) reads and
/// validates with today's fields, and the motion files it names are in the repository, so any
/// recipe a results page cites can be trained from a clean checkout.
#[test]
fn every_training_config_in_the_repository_loads() {
    let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
    let mut checked = Vec::new();
    let mut entries: Vec<_> = std::fs::read_dir(root.join("configs"))
        .expect("configs/")
        .map(|e| e.expect("entry").path())
        .filter(|p| p.extension().is_some_and(|x| x == "json"))
        .collect();
    entries.sort();
    for path in entries {
        let json: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(&path).expect("read")).expect("JSON");
        if json.get("modality").is_none() || json.get("steps").is_none() {
            continue;
        }
        let config = TrainConfig::load(&path).unwrap_or_else(|e| panic!("{e}"));
        for m in &config.motions {
            assert!(
                root.join(m).is_file(),
                "{}: no motion file {}",
                path.display(),
                m.display()
            );
        }
        checked.push(path.file_name().unwrap().to_string_lossy().into_owned());
    }
    assert!(
        checked
            .iter()
            .any(|n| n == "markers-captured-floor-u10-chain.json")
            && checked.len() >= 20,
        "{checked:?}"
    );
}
