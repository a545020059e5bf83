//! Training behaviour: a CI-sized run must learn, resume must continue exactly where a run
//! stopped, and a diverging run must stop with a clear error and an intact checkpoint.

use std::sync::{Arc, Mutex};

use lfit_model::observe::Modality;
use lfit_model::{Template, default_template};
use lfit_nn::checkpoint;
use lfit_nn::tensor::ndarray_device;
use lfit_nn::{NetConfig, StartMode};
use lfit_train::{Event, RunOptions, TrainConfig, TrainError, train};

fn small(steps: usize) -> TrainConfig {
    TrainConfig {
        modality: Modality::Markers,
        network: NetConfig {
            hidden: 48,
            layers: 1,
            init_width: 64,
            iterations: 3,
            start: StartMode::Phi,
            dropout: 0.0,
            ..NetConfig::default()
        },
        steps,
        batch: 16,
        learning_rate: 2e-3,
        lr_decay_at: 1.0,
        val_frames: 32,
        val_every: 10,
        checkpoint_every: 10,
        stats_frames: 32,
        seed: 3,
        ..TrainConfig::default()
    }
}

fn options(out: &std::path::Path, resume: bool) -> RunOptions {
    RunOptions {
        out: out.to_path_buf(),
        device_name: "ndarray".into(),
        resume,
        init: None,
        command: "test".into(),
    }
}

fn template() -> Arc<Template> {
    Arc::new(default_template())
}

/// Trains `config` into `out` and returns the loss of every step.
fn losses_of_run(config: &TrainConfig, out: &std::path::Path) -> Vec<f64> {
    let losses = Mutex::new(Vec::new());
    train(
        config,
        template(),
        &ndarray_device(),
        &options(out, false),
        &|e| {
            if let Event::Step { loss, .. } = e {
                losses.lock().expect("lock").push(loss);
            }
        },
    )
    .expect("train");
    losses.into_inner().expect("losses")
}

#[test]
fn a_short_run_halves_the_validation_error() {
    let tmp = tempfile::tempdir().expect("tmp");
    let out = tmp.path().join("run");
    let events = Mutex::new(Vec::new());
    let summary = train(
        &small(80),
        template(),
        &ndarray_device(),
        &options(&out, false),
        &|e| events.lock().expect("lock").push(e),
    )
    .expect("train");
    let first = *summary.first_validation.v2v_mm.last().expect("v2v");
    let last = *summary.final_validation.v2v_mm.last().expect("v2v");
    eprintln!(
        "validation V2V after the last iteration: {first:.1} mm -> {last:.1} mm ({:.0} samples/s)",
        summary.samples_per_s
    );
    assert!(
        last <= 0.5 * first,
        "training must cut validation V2V by at least half: {first:.1} -> {last:.1} mm"
    );
    // The iterations help: the last iterate beats Φ's θ0.
    assert!(summary.final_validation.v2v_mm[3] < summary.final_validation.v2v_mm[0]);
    // Checkpoint with card, CSV with validation rows, loadable.
    let ck = checkpoint::load(&out, &ndarray_device()).expect("checkpoint");
    assert_eq!(ck.metrics["steps"], 80);
    assert_eq!(
        ck.metrics["validation"]["v2v_mm"].as_array().map(Vec::len),
        Some(4)
    );
    let csv = std::fs::read_to_string(out.join("metrics.csv")).expect("csv");
    assert_eq!(csv.lines().filter(|l| l.contains(",train,")).count(), 80);
    assert_eq!(
        csv.lines().filter(|l| l.contains(",validation,")).count(),
        8
    );
    let events = events.into_inner().expect("events");
    assert_eq!(
        events
            .iter()
            .filter(|e| matches!(e, Event::Checkpoint { .. }))
            .count(),
        8
    );
}

#[test]
fn resuming_continues_exactly_where_the_run_stopped() {
    let tmp = tempfile::tempdir().expect("tmp");
    let straight = tmp.path().join("straight");
    let split = tmp.path().join("split");
    let device = ndarray_device();
    let config = TrainConfig {
        val_every: 5,
        checkpoint_every: 5,
        ..small(10)
    };
    train(
        &config,
        template(),
        &device,
        &options(&straight, false),
        &|_| {},
    )
    .expect("straight");
    train(
        &TrainConfig {
            steps: 5,
            ..config.clone()
        },
        template(),
        &device,
        &options(&split, false),
        &|_| {},
    )
    .expect("first half");
    let resumed = train(
        &config,
        template(),
        &device,
        &options(&split, true),
        &|_| {},
    )
    .expect("resume");
    let a = checkpoint::load(&straight, &device).expect("a");
    let b = checkpoint::load(&split, &device).expect("b");
    assert_eq!(
        a.metrics["validation"], b.metrics["validation"],
        "same data, same optimizer state: identical results"
    );
    assert_eq!(resumed.steps, 10);
    let csv = std::fs::read_to_string(split.join("metrics.csv")).expect("csv");
    assert_eq!(
        csv.lines().filter(|l| l.contains(",train,")).count(),
        10,
        "{csv}"
    );

    // Resuming with another config, or a finished run, is refused with one line.
    let other = TrainConfig {
        learning_rate: 0.1,
        ..config.clone()
    };
    let e = train(&other, template(), &device, &options(&split, true), &|_| {})
        .expect_err("other config");
    assert!(e.to_string().contains("another config"), "{e}");
    let e = train(
        &config,
        template(),
        &device,
        &options(&split, true),
        &|_| {},
    )
    .expect_err("done");
    assert!(e.to_string().contains("already has 10 steps"), "{e}");
    let e = train(
        &config,
        template(),
        &device,
        &options(&tmp.path().join("none"), true),
        &|_| {},
    )
    .expect_err("missing");
    assert!(matches!(e, TrainError::Resume { .. }), "{e}");
}

#[test]
fn a_diverging_run_stops_and_keeps_its_last_checkpoint() {
    let tmp = tempfile::tempdir().expect("tmp");
    let out = tmp.path().join("run");
    let device = ndarray_device();
    let config = TrainConfig {
        learning_rate: 1e30,
        checkpoint_every: 1,
        val_every: 1000,
        ..small(50)
    };
    let e =
        train(&config, template(), &device, &options(&out, false), &|_| {}).expect_err("must stop");
    let TrainError::NotFinite {
        step, last_good, ..
    } = &e
    else {
        panic!("expected NotFinite, got {e}")
    };
    assert!(*step >= 1 && *last_good == *step, "{e}");
    let text = e.to_string();
    assert!(
        text.contains("training stopped") && text.contains("last good checkpoint"),
        "{text}"
    );
    assert_eq!(text.lines().count(), 1);
    let ck = checkpoint::load(&out, &device).expect("the last checkpoint is intact");
    assert_eq!(ck.metrics["steps"], *last_good);
}

#[test]
fn bad_configs_are_one_line_errors() {
    let tmp = tempfile::tempdir().expect("tmp");
    let p = tmp.path().join("c.json");
    for (text, want) in [
        ("{", "malformed JSON"),
        (r#"{"batch": 1}"#, "batch"),
        (r#"{"steps": 0}"#, "steps"),
        (r#"{"modality": "scan"}"#, "scan"),
        (r#"{"learning_rate": -1}"#, "learning_rate"),
        (r#"{"bogus": 1}"#, "unknown field"),
        // The face's inputs (issue 16): a pose source, an energy.
        (r#"{"source": "uniform"}"#, "source"),
        (
            r#"{"source": "face", "motions": ["clip.npz"]}"#,
            "drop \"motions\"",
        ),
        (
            r#"{"energy": {"angle_prior": "binary"}}"#,
            "gradient variant",
        ),
        (r#"{"energy": {"weights": {"pose": -1}}}"#, "weights.pose"),
        (r#"{"network": {"dropout": 1.5}}"#, ""),
        // The start mix: weights, radii, chains, and the batch's share.
        (r#"{"starts": {"phi": -1}}"#, "non-negative"),
        (r#"{"starts": {"radii_deg": []}}"#, "radii"),
        (r#"{"starts": {"chain": 0}}"#, "frame before"),
        (
            r#"{"starts": {"phi": 0, "scenario": 0, "perturbed": 0, "rest": 0, "previous": 0}}"#,
            "at least one weight",
        ),
        (
            r#"{"source": "face", "starts": {}}"#,
            "face protocol has no sequences",
        ),
        (r#"{"starts": {"bogus": 1}}"#, "unknown field"),
        // The temporal anchor of the previous-frame windows: a positive σ, and windows to use it.
        (r#"{"starts": {"anchor_deg": 0}}"#, "finite and positive"),
        (r#"{"starts": {"anchor_deg": -4}}"#, "finite and positive"),
        (
            r#"{"starts": {"anchor_deg": 4, "previous": 0}}"#,
            "set \"previous\" above 0",
        ),
        (r#"{"starts": {"fps": [30, 0]}}"#, "frame rates"),
        // Data-parallel shards: at least one, each with two rows for BatchNorm.
        (r#"{"shards": 0}"#, "shards"),
        (r#"{"batch": 8, "shards": 5}"#, "shards"),
        (r#"{"shards": 17}"#, "shards"),
        // Motion-file augmentation: needs files, a jitter in [0, 45] degrees, known keys.
        (r#"{"motion_augment": {"mirror": true}}"#, "list them in"),
        (
            r#"{"motions": ["a.npz"], "motion_augment": {"jitter_deg": 90}}"#,
            "jitter_deg",
        ),
        (
            r#"{"motions": ["a.npz"], "motion_augment": {"flip": true}}"#,
            "unknown field",
        ),
        // The library's kinds: named ones, at least one, and only where the library is drawn.
        (r#"{"library_motions": []}"#, "names no motion kind"),
        (r#"{"library_motions": ["moonwalk"]}"#, "moonwalk"),
        (
            r#"{"motions": ["a.npz"], "library_motions": ["sit"]}"#,
            "with_library",
        ),
    ] {
        std::fs::write(&p, text).expect("write");
        let r = TrainConfig::load(&p);
        if want.is_empty() {
            // Network settings are checked when the run starts.
            let config = r.expect("parses");
            let e = train(
                &config,
                template(),
                &ndarray_device(),
                &options(&tmp.path().join("x"), false),
                &|_| {},
            )
            .expect_err("dropout");
            assert!(e.to_string().contains("dropout"), "{e}");
            continue;
        }
        let e = r.expect_err(text);
        assert!(e.to_string().contains(want), "{text}: {e}");
        assert_eq!(e.to_string().lines().count(), 1);
    }
    assert!(
        TrainConfig::load(&tmp.path().join("missing.json"))
            .expect_err("missing")
            .to_string()
            .contains("cannot read")
    );
}

/// The tensor loss against a host computation of the same terms with the CPU skinning.
#[test]
fn tensor_loss_matches_a_cpu_computation() {
    use lfit_model::pose::{POSE_DIM, Pose};
    use lfit_model::skinning::{joint_transforms, skin_lbs_into};
    use lfit_nn::tensor::poses_to_tensor;
    use lfit_train::{Loss, LossWeights};
    use rand::{Rng, SeedableRng};
    let template = default_template();
    let device = ndarray_device();
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(4);
    let mut pose = || -> Pose { std::array::from_fn(|_| rng.random_range(-0.4..0.4)) };
    let (pred, truth) = ([pose(), pose()], [pose(), pose()]);
    let only = |v: f64, e: f64, t: f64, r: f64, tr: f64| LossWeights {
        vertices: v,
        edges: e,
        transforms: t,
        rotations: r,
        translation: tr,
    };
    let value = |w: LossWeights| -> f64 {
        let loss = Loss::new(&template, w, &device);
        let t = loss.truth(poses_to_tensor(&truth, &device));
        f64::from(
            loss.step(poses_to_tensor(&pred, &device), &t)
                .into_scalar::<f32>(),
        )
    };
    let skin = |p: &Pose| {
        let mut v = Vec::new();
        skin_lbs_into(&template, &joint_transforms(&template, p), &mut v);
        v
    };
    // Vertices: mean |Δ| over B × V × 3 entries.
    let (mut sum, mut n) = (0.0, 0.0);
    let edges = lfit_train::loss::mesh_edges(&template);
    let (mut esum, mut en) = (0.0, 0.0);
    let (mut jsum, mut jn) = (0.0, 0.0);
    for (p, g) in pred.iter().zip(&truth) {
        let (a, b) = (skin(p), skin(g));
        for (x, y) in a.iter().zip(&b) {
            sum += f64::from((*x - *y).abs().element_sum());
            n += 3.0;
        }
        for &(i, j) in &edges {
            let d = (a[i as usize] - a[j as usize]) - (b[i as usize] - b[j as usize]);
            esum += f64::from(d.abs().element_sum());
            en += 3.0;
        }
        let (ja, jb) = (
            joint_transforms(&template, p).joints,
            joint_transforms(&template, g).joints,
        );
        for (x, y) in ja.iter().zip(&jb) {
            jsum += (*x - *y).abs().element_sum();
            jn += 3.0;
        }
    }
    let close = |got: f64, want: f64, what: &str| {
        assert!(
            (got - want).abs() <= 1e-4 * want.abs().max(1.0),
            "{what}: tensor {got} vs cpu {want}"
        )
    };
    close(value(only(1.0, 0.0, 0.0, 0.0, 0.0)), sum / n, "vertices");
    close(value(only(0.0, 1.0, 0.0, 0.0, 0.0)), esum / en, "edges");
    let tr: f64 = pred
        .iter()
        .zip(&truth)
        .map(|(p, g)| (0..3).map(|k| (p[k] - g[k]).abs()).sum::<f64>())
        .sum::<f64>()
        / 6.0;
    close(value(only(0.0, 0.0, 0.0, 0.0, 1.0)), tr, "translation");
    // Transforms = world rotations + joint positions; check the sum is at least the joint part.
    let t = value(only(0.0, 0.0, 1.0, 0.0, 0.0));
    assert!(
        t > jsum / jn && t.is_finite(),
        "{t} vs joints {}",
        jsum / jn
    );
    assert!(POSE_DIM == 57);
}

/// Every float of `module` (parameters and BatchNorm running statistics), in module order.
fn floats_of<M: burn::module::Module>(module: &M) -> Vec<f32> {
    use burn::module::{ModuleVisitor, Param};
    use burn::tensor::Tensor;
    struct Floats(Vec<f32>);
    impl ModuleVisitor for Floats {
        fn visit_float<const D: usize>(&mut self, param: &Param<Tensor<D>>) {
            self.0.extend(
                param
                    .val()
                    .into_data()
                    .try_to_vec::<f32>()
                    .expect("f32 weights"),
            );
        }
    }
    let mut v = Floats(Vec::new());
    module.visit(&mut v);
    v.0
}

/// Every float parameter of a checkpoint's network, in module order (the burnpack file also holds
/// per-run parameter ids, so its bytes differ between equal runs).
fn weights_of(dir: &std::path::Path) -> Vec<f32> {
    let v = floats_of(
        &checkpoint::load(dir, &ndarray_device())
            .expect("checkpoint")
            .net,
    );
    assert!(!v.is_empty());
    v
}

/// A run with the start mix (`"starts"`): every source, including the network's own results fed
/// forward over consecutive frames, trains; the same seed gives the same weights; without
/// `"starts"` the config is what it was (resume equality, serialised form).
#[test]
fn the_start_mix_trains_and_is_deterministic() {
    let tmp = tempfile::tempdir().expect("tmp");
    let mut config = small(6);
    config.val_every = 3;
    config.checkpoint_every = 6;
    config.starts = Some(lfit_train::StartMix::default());
    let run = |dir: &str| {
        let out = tmp.path().join(dir);
        let losses = losses_of_run(&config, &out);
        (weights_of(&out), losses)
    };
    let (a, la) = run("a");
    let (b, lb) = run("b");
    assert_eq!(la.len(), 6);
    assert!(la.iter().all(|l| l.is_finite()), "{la:?}");
    assert_eq!(la, lb, "same seed, same losses");
    assert_eq!(a, b, "same seed, same weights");
    // The mix changes what the network is trained on.
    let mut plain = small(6);
    plain.val_every = 3;
    plain.checkpoint_every = 6;
    assert_ne!(losses_of_run(&plain, &tmp.path().join("plain")), la);
    let text = serde_json::to_string(&plain).expect("json");
    assert!(!text.contains("starts"), "{text}");
}

/// Every float of the network's recurrent cores, Δθ heads and λ/γ networks (no BatchNorm
/// running statistics: those are what data-parallel shards compute differently by design).
fn core_weights_of(dir: &std::path::Path) -> Vec<f32> {
    let net = checkpoint::load(dir, &ndarray_device())
        .expect("checkpoint")
        .net;
    let mut v = floats_of(&net.cores);
    v.extend(floats_of(&net.delta_heads));
    v.extend(floats_of(&net.steps));
    assert!(!v.is_empty());
    v
}

/// `"shards": 2` splits each batch over two threads and sums the shards' gradients weighted by
/// rows. Where no BatchNorm lies on the path (given starts, the memory-less residual-MLP core),
/// that is the whole batch's gradient: the same loss and, after the optimiser's steps, the same
/// weights as one shard up to float summation order. With BatchNorm on the path (Φ's θ0) the
/// runs differ from one shard, and two sharded runs with one seed are equal.
#[test]
fn data_parallel_shards_sum_to_the_whole_batch_gradient() {
    let tmp = tempfile::tempdir().expect("tmp");
    let run = |config: &TrainConfig, dir: &str| {
        let out = tmp.path().join(dir);
        let losses = losses_of_run(config, &out);
        (out, losses)
    };
    let mut whole = small(3);
    whole.val_every = 3;
    whole.checkpoint_every = 3;
    whole.network.start = StartMode::Given;
    whole.network.core = lfit_nn::CoreKind::ResidualMlp;
    let sharded = TrainConfig {
        shards: 2,
        ..whole.clone()
    };
    let (dw, lw) = run(&whole, "whole");
    let (ds, ls) = run(&sharded, "sharded");
    assert_eq!(lw.len(), 3);
    for (a, b) in lw.iter().zip(&ls) {
        assert!((a - b).abs() <= 1e-4 * a.abs(), "losses {lw:?} vs {ls:?}");
    }
    let (a, b) = (core_weights_of(&dw), core_weights_of(&ds));
    assert_eq!(a.len(), b.len());
    let worst = a
        .iter()
        .zip(&b)
        .map(|(x, y)| (x - y).abs())
        .fold(0.0f32, f32::max);
    // Adam moves each weight by about the learning rate (2e-3) per step: a wrongly weighted
    // or missing shard moves many of them by that much.
    assert!(worst < 2e-5, "weights differ by up to {worst}");

    // BatchNorm on the path: a different run, deterministic for its shard count.
    let mut phi = small(3);
    phi.val_every = 3;
    phi.checkpoint_every = 3;
    let phi2 = TrainConfig {
        shards: 2,
        ..phi.clone()
    };
    let (_, l1) = run(&phi, "phi1");
    let (d2, l2) = run(&phi2, "phi2");
    let (d3, l3) = run(&phi2, "phi3");
    assert_eq!(l2, l3, "same seed and shards, same losses");
    assert_eq!(
        weights_of(&d2),
        weights_of(&d3),
        "same seed and shards, same weights"
    );
    assert_ne!(l1, l2);
    let text = serde_json::to_string(&phi).expect("json");
    assert!(!text.contains("shards"), "{text}");
}

/// `RunOptions::init` (`lfit train --init`): the run starts from the checkpoint's weights and
/// statistics (its first validation is the checkpoint's last, on the same seed's frames), then
/// trains on; a checkpoint of another network, `--init` with `--resume`, and `--out` the
/// checkpoint itself are refused with one line, the checkpoint untouched.
#[test]
fn fine_tuning_starts_from_the_checkpoint() {
    let tmp = tempfile::tempdir().expect("tmp");
    let device = ndarray_device();
    let base = tmp.path().join("base");
    let config = small(4);
    let trained = train(
        &config,
        template(),
        &device,
        &options(&base, false),
        &|_| {},
    )
    .expect("base");
    let before = weights_of(&base);
    let tuned = tmp.path().join("tuned");
    let init = |out: &std::path::Path, resume: bool| RunOptions {
        init: Some(base.clone()),
        ..options(out, resume)
    };
    let summary =
        train(&config, template(), &device, &init(&tuned, false), &|_| {}).expect("fine-tune");
    assert_eq!(summary.first_validation, trained.final_validation);
    assert_eq!(summary.steps, 4);
    assert_ne!(weights_of(&tuned), before, "it trains on");
    // A fresh run of the same config starts elsewhere.
    let fresh = train(
        &config,
        template(),
        &device,
        &options(&tmp.path().join("fresh"), false),
        &|_| {},
    )
    .expect("fresh");
    assert_ne!(fresh.first_validation, trained.final_validation);

    let mut other = small(4);
    other.network.hidden = 32;
    for (config, out, resume, want) in [
        (&other, tmp.path().join("o"), false, "network differs"),
        (&config, tmp.path().join("r"), true, "not both"),
        (&config, base.clone(), false, "the checkpoint itself"),
    ] {
        let e = train(config, template(), &device, &init(&out, resume), &|_| {}).expect_err(want);
        assert!(matches!(e, TrainError::Init { .. }), "{e}");
        assert!(e.to_string().contains(want), "{e}");
        assert_eq!(e.to_string().lines().count(), 1);
    }
    assert_eq!(weights_of(&base), before, "the checkpoint is untouched");
    let e = train(
        &config,
        template(),
        &device,
        &RunOptions {
            init: Some(tmp.path().join("missing")),
            ..options(&tmp.path().join("m"), false)
        },
        &|_| {},
    )
    .expect_err("missing");
    assert!(e.to_string().contains("missing"), "{e}");
}

/// `"starts": {"anchor_deg": …}`: the previous-frame windows are fitted on the energy with the
/// temporal anchor, so the run trains on other directions than without it (same seed), and
/// stays deterministic; `"fps"` synthesises the windows at another frame rate.
#[test]
fn the_temporal_anchor_changes_what_the_previous_frame_share_trains_on() {
    let tmp = tempfile::tempdir().expect("tmp");
    let mut config = small(3);
    config.val_every = 3;
    config.checkpoint_every = 3;
    config.starts = Some(lfit_train::StartMix {
        previous: 0.5,
        ..lfit_train::StartMix::default()
    });
    let plain = losses_of_run(&config, &tmp.path().join("plain"));
    if let Some(mix) = config.starts.as_mut() {
        mix.anchor_deg = Some(4.0);
    }
    let a = losses_of_run(&config, &tmp.path().join("a"));
    let b = losses_of_run(&config, &tmp.path().join("b"));
    assert_eq!(a, b, "same seed, same losses");
    assert!(a.iter().all(|l| l.is_finite()), "{a:?}");
    assert_ne!(a, plain, "the anchor changes the windows' energies");
    // Windows at another frame rate: other frames, other losses.
    if let Some(mix) = config.starts.as_mut() {
        mix.fps = vec![10.0];
    }
    let slow = losses_of_run(&config, &tmp.path().join("slow"));
    assert_ne!(slow, a, "the windows' frame rate changes their frames");
    let text = serde_json::to_string(&config).expect("json");
    assert!(text.contains("\"anchor_deg\":4.0"), "{text}");
}
