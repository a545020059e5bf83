//! Tests of the network: the LN-GRU cell against a host reference, shapes of every variant,
//! checkpoint round trips and the errors of mismatched checkpoints.

use std::sync::Arc;

use burn::module::Param;
use burn::nn::{LayerNorm, Linear};
use burn::tensor::{Device, Tensor, TensorData};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use crate::checkpoint::{self, checkpoint_files, write_dir};
use crate::config::*;
use crate::features::{FeatureStats, Norm};
use crate::layers::{Dropout, LnGruCell};
use crate::net::NeuralNet;
use crate::tensor::ndarray_device;
use crate::unroll::unroll;
use lfit_model::energy::{Energy, EnergyConfig, Target};
use lfit_model::observe::{Modality, Sensor};
use lfit_model::pose::{POSE_DIM, Pose};
use lfit_model::{Template, default_template};

fn vals(t: Tensor<1>) -> Vec<f64> {
    t.try_into_vec_as::<f32>()
        .expect("read")
        .into_iter()
        .map(f64::from)
        .collect()
}

fn mat(l: &Linear) -> (Vec<f64>, Vec<f64>, [usize; 2]) {
    let w = l.weight.val();
    let dims = w.dims();
    let w = w
        .try_into_vec_as::<f32>()
        .expect("read")
        .into_iter()
        .map(f64::from)
        .collect();
    let b = l
        .bias
        .as_ref()
        .map_or(vec![0.0; dims[1]], |b| vals(b.val()));
    (w, b, dims)
}

/// `x W + b` on the host.
fn affine(l: &Linear, x: &[f64]) -> Vec<f64> {
    let (w, b, [din, dout]) = mat(l);
    (0..dout)
        .map(|j| b[j] + (0..din).map(|i| x[i] * w[i * dout + j]).sum::<f64>())
        .collect()
}

fn ln(l: &LayerNorm, x: &[f64]) -> Vec<f64> {
    let n = x.len() as f64;
    let m = x.iter().sum::<f64>() / n;
    let v = x.iter().map(|a| (a - m) * (a - m)).sum::<f64>() / n;
    let g = vals(l.gamma.val());
    let b = l
        .beta
        .as_ref()
        .map_or(vec![0.0; x.len()], |b| vals(b.val()));
    x.iter()
        .enumerate()
        .map(|(i, a)| (a - m) / (v + 1e-5).sqrt() * g[i] + b[i])
        .collect()
}

fn sig(x: f64) -> f64 {
    1.0 / (1.0 + (-x).exp())
}

fn random_ln(hidden: usize, rng: &mut ChaCha8Rng, device: &Device) -> LayerNorm {
    let mut l = burn::nn::LayerNormConfig::new(hidden).init(device);
    let g: Vec<f32> = (0..hidden).map(|_| rng.random_range(0.5..1.5)).collect();
    let b: Vec<f32> = (0..hidden).map(|_| rng.random_range(-0.5..0.5)).collect();
    l.gamma = Param::from_tensor(Tensor::from_data(TensorData::new(g, [hidden]), device));
    l.beta = Some(Param::from_tensor(Tensor::from_data(
        TensorData::new(b, [hidden]),
        device,
    )));
    l
}

#[test]
fn ln_gru_cell_matches_a_hand_written_reference() {
    let device = ndarray_device();
    let (d_in, hidden, batch) = (7, 5, 3);
    let mut rng = ChaCha8Rng::seed_from_u64(7);
    let mut cell = LnGruCell::new(d_in, hidden, &mut rng, &device);
    // Non-trivial LayerNorm gains and biases, so a mixed-up norm would show.
    cell.ln_wz = random_ln(hidden, &mut rng, &device);
    cell.ln_wr = random_ln(hidden, &mut rng, &device);
    cell.ln_wh = random_ln(hidden, &mut rng, &device);
    cell.ln_uz = random_ln(hidden, &mut rng, &device);
    cell.ln_ur = random_ln(hidden, &mut rng, &device);
    cell.ln_uh = random_ln(hidden, &mut rng, &device);
    let x: Vec<f32> = (0..batch * d_in)
        .map(|_| rng.random_range(-2.0..2.0))
        .collect();
    let h: Vec<f32> = (0..batch * hidden)
        .map(|_| rng.random_range(-1.0..1.0))
        .collect();
    let out = cell.forward(
        Tensor::from_data(TensorData::new(x.clone(), [batch, d_in]), &device),
        Tensor::from_data(TensorData::new(h.clone(), [batch, hidden]), &device),
    );
    let out = out.try_into_vec_as::<f32>().expect("read");

    for b in 0..batch {
        let xb: Vec<f64> = x[b * d_in..(b + 1) * d_in]
            .iter()
            .map(|&v| f64::from(v))
            .collect();
        let hb: Vec<f64> = h[b * hidden..(b + 1) * hidden]
            .iter()
            .map(|&v| f64::from(v))
            .collect();
        let wx = affine(&cell.w, &xb);
        let uzr = affine(&cell.u_zr, &hb);
        let z: Vec<f64> = ln(&cell.ln_wz, &wx[..hidden])
            .iter()
            .zip(ln(&cell.ln_uz, &uzr[..hidden]))
            .map(|(a, c)| sig(a + c))
            .collect();
        let r: Vec<f64> = ln(&cell.ln_wr, &wx[hidden..2 * hidden])
            .iter()
            .zip(ln(&cell.ln_ur, &uzr[hidden..]))
            .map(|(a, c)| sig(a + c))
            .collect();
        let rh: Vec<f64> = r.iter().zip(&hb).map(|(a, c)| a * c).collect();
        let cand: Vec<f64> = ln(&cell.ln_wh, &wx[2 * hidden..])
            .iter()
            .zip(ln(&cell.ln_uh, &affine(&cell.u_h, &rh)))
            .map(|(a, c)| (a + c).tanh())
            .collect();
        for k in 0..hidden {
            let want = (1.0 - z[k]) * hb[k] + z[k] * cand[k];
            let got = f64::from(out[b * hidden + k]);
            assert!(
                (want - got).abs() < 1e-5,
                "batch {b} unit {k}: reference {want}, cell {got}"
            );
        }
    }
}

pub(crate) fn small_config(modality: Modality, residual_dim: usize) -> NetConfig {
    NetConfig {
        modality,
        residual_dim,
        iterations: 2,
        hidden: 16,
        init_width: 8,
        layers: 2,
        dropout: 0.5,
        ..NetConfig::default()
    }
}

/// The default template, `n` marker energies of random poses (noise-free targets) and the
/// markers' residual dimension.
fn marker_frames(n: usize, seed: u64) -> (Arc<Template>, Vec<Energy>, usize) {
    let template = Arc::new(default_template());
    let sensor = Sensor::default_for(Modality::Markers, &template);
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let energies = (0..n)
        .map(|_| {
            let mut pose: Pose = [0.0; POSE_DIM];
            for v in pose.iter_mut() {
                *v = rng.random_range(-0.2..0.2);
            }
            let pred = sensor.predict_sparse(&template, &pose);
            Energy::new(
                template.clone(),
                sensor.clone(),
                Target::Sparse {
                    values: pred.values,
                    visible: pred.visible,
                },
                EnergyConfig::default().for_gradient(),
            )
            .expect("energy")
        })
        .collect();
    let dim = sensor.residual_dim(&template);
    (template, energies, dim)
}

fn unit_stats(dim: usize) -> FeatureStats {
    let n = |d: usize| Norm {
        mean: vec![0.0; d],
        std: vec![1.0; d],
    };
    FeatureStats {
        observation: n(2 * dim),
        residual: n(dim),
        gradient: n(POSE_DIM),
        pose: n(POSE_DIM),
    }
}

#[test]
fn every_variant_builds_and_runs_with_the_right_shapes() {
    let device = ndarray_device();
    let (_, energies, dim) = marker_frames(3, 1);
    let refs: Vec<&Energy> = energies.iter().collect();
    let base = small_config(Modality::Markers, dim);
    let mut variants = Vec::new();
    for update in [
        UpdateRule::DeltaOnly,
        UpdateRule::Eq1,
        UpdateRule::Convex,
        UpdateRule::ConvexNormalized,
    ] {
        variants.push(NetConfig {
            update,
            ..base.clone()
        });
    }
    variants.push(NetConfig {
        gamma: GammaMode::Constant,
        ..base.clone()
    });
    variants.push(NetConfig {
        step_shape: StepShape::Scalar,
        ..base.clone()
    });
    variants.push(NetConfig {
        shared_lambda_gamma: false,
        ..base.clone()
    });
    variants.push(NetConfig {
        core: CoreKind::ResidualMlp,
        ..base.clone()
    });
    variants.push(NetConfig {
        layers: 1,
        hidden: 24,
        ..base.clone()
    });
    variants.push(NetConfig {
        per_step_weights: true,
        iterations: 3,
        ..base.clone()
    });
    variants.push(NetConfig {
        step_shape: StepShape::Scalar,
        shared_lambda_gamma: false,
        update: UpdateRule::Convex,
        ..base.clone()
    });
    // supp. Table A.1: λ and γ of different shapes, from one network or two.
    for shared_lambda_gamma in [false, true] {
        variants.push(NetConfig {
            gamma_shape: Some(StepShape::Scalar),
            shared_lambda_gamma,
            ..base.clone()
        });
        variants.push(NetConfig {
            step_shape: StepShape::Scalar,
            gamma_shape: Some(StepShape::Vector),
            shared_lambda_gamma,
            ..base.clone()
        });
    }
    for config in variants {
        let net = NeuralNet::new(&config, 3, &device).expect("net");
        assert_eq!(net.cores.len(), config.weight_sets(), "{config:?}");
        assert_eq!(
            net.steps.len(),
            if config.has_step_network() {
                config.weight_sets()
            } else {
                0
            }
        );
        assert_eq!(net.phi_h.is_some(), config.core == CoreKind::Gru);
        let given = [None, Some(vec![0.05; POSE_DIM]), None];
        let out = unroll(
            &net,
            &unit_stats(dim),
            &refs,
            &given,
            None,
            &device,
            &mut Dropout::off(),
        )
        .expect("unroll");
        assert_eq!(out.poses.len(), config.iterations + 1);
        assert_eq!(out.host.len(), config.iterations + 1);
        for t in &out.poses {
            assert_eq!(t.dims(), [3, POSE_DIM]);
        }
        // The given start is θ0 exactly; the Φ start is not.
        assert!((out.host[0][1][10] - 0.05).abs() < 1e-7);
        assert!(
            out.host.iter().flatten().flatten().all(|v| v.is_finite()),
            "{config:?}"
        );
        // Every variant moves the pose.
        assert_ne!(out.host[0][0], out.host[config.iterations][0], "{config:?}");
        // Step sizes have the configured width.
        let mut state = net
            .initial(Tensor::zeros([3, config.obs_features()], &device))
            .1;
        let sizes = net.step_sizes(
            0,
            Tensor::zeros([3, config.step_inputs()], &device),
            &mut state,
            &mut Dropout::off(),
        );
        if config.has_step_network() {
            assert_eq!(
                sizes.lambda.expect("lambda").dims(),
                [3, config.step_outputs()]
            );
            assert_eq!(
                sizes.gamma.expect("gamma").dims(),
                [3, config.gamma_outputs()]
            );
        }
    }
}

#[test]
fn eq1_update_is_lambda_delta_minus_gamma_grad() {
    let device = ndarray_device();
    let config = small_config(Modality::Markers, 6);
    let net = NeuralNet::new(&config, 1, &device).expect("net");
    let t = |v: Vec<f32>| Tensor::<2>::from_data(TensorData::new(v, [1, POSE_DIM]), &device);
    let delta: Vec<f32> = (0..POSE_DIM).map(|i| i as f32 * 0.01).collect();
    let grad: Vec<f32> = (0..POSE_DIM).map(|i| 1.0 - i as f32 * 0.02).collect();
    let lambda: Vec<f32> = (0..POSE_DIM).map(|i| 0.5 + i as f32 * 0.01).collect();
    let gamma: Vec<f32> = (0..POSE_DIM).map(|i| 0.1 * i as f32).collect();
    let sizes = crate::net::StepSizes {
        lambda: Some(t(lambda.clone())),
        gamma: Some(t(gamma.clone())),
    };
    let u = net
        .update(t(delta.clone()), t(grad.clone()), &sizes)
        .try_into_vec_as::<f32>()
        .expect("read");
    for i in 0..POSE_DIM {
        let want = lambda[i] * delta[i] - gamma[i] * grad[i];
        assert!((u[i] - want).abs() < 1e-6, "{i}: {} vs {want}", u[i]);
    }
    // The convex rule: λΔ + (1 − λ)(−γ g).
    let convex = NeuralNet::new(
        &NetConfig {
            update: UpdateRule::Convex,
            ..config
        },
        1,
        &device,
    )
    .expect("net");
    let u = convex
        .update(t(delta.clone()), t(grad.clone()), &sizes)
        .try_into_vec_as::<f32>()
        .expect("read");
    for i in 0..POSE_DIM {
        let want = lambda[i] * delta[i] - (1.0 - lambda[i]) * gamma[i] * grad[i];
        assert!((u[i] - want).abs() < 1e-6);
    }
}

fn save_checkpoint(
    dir: &std::path::Path,
    net: &NeuralNet,
    stats: &FeatureStats,
    template: &Template,
) {
    let files = checkpoint_files(
        net,
        stats,
        template,
        None,
        &serde_json::json!({"test": true}),
    )
    .expect("files");
    let files: Vec<(&str, Vec<u8>)> = files.into_iter().collect();
    write_dir(dir, &files).expect("write");
}

#[test]
fn checkpoint_round_trip_gives_identical_outputs_and_mismatches_are_clear_errors() {
    let device = ndarray_device();
    let (template, energies, dim) = marker_frames(2, 5);
    let refs: Vec<&Energy> = energies.iter().collect();
    let config = small_config(Modality::Markers, dim);
    let net = NeuralNet::new(&config, 11, &device).expect("net");
    let mut stats = unit_stats(dim);
    stats.pose.std[0] = 0.5;
    let tmp = tempfile::tempdir().expect("tmp");
    let dir = tmp.path().join("ckpt");
    save_checkpoint(&dir, &net, &stats, &template);

    let loaded = checkpoint::load(&dir, &device).expect("load");
    assert_eq!(loaded.stats, stats);
    assert_eq!(loaded.meta.network, config);
    let starts = [None, None];
    let a = unroll(
        &net,
        &stats,
        &refs,
        &starts,
        None,
        &device,
        &mut Dropout::off(),
    )
    .expect("a");
    let b = unroll(
        &loaded.net,
        &loaded.stats,
        &refs,
        &starts,
        None,
        &device,
        &mut Dropout::off(),
    )
    .expect("b");
    assert_eq!(
        a.host, b.host,
        "a loaded checkpoint must reproduce the saved network exactly"
    );
    loaded
        .check_compatible(&dir, Modality::Markers, dim, &template)
        .expect("compatible");

    // Wrong modality.
    let e = loaded
        .check_compatible(&dir, Modality::Hmd, 42, &template)
        .expect_err("modality");
    assert!(
        e.to_string().contains("trained for markers data, not hmd"),
        "{e}"
    );

    // A config that does not match the weights (hidden size changed).
    let meta_path = dir.join("config.json");
    let text = std::fs::read_to_string(&meta_path).expect("read");
    std::fs::write(&meta_path, text.replace("\"hidden\": 16", "\"hidden\": 32")).expect("write");
    let e = checkpoint::load(&dir, &device).expect_err("mismatch");
    assert!(
        e.to_string().contains("weights do not match")
            || e.to_string().contains("weights lack")
            || e.to_string().contains("weights have"),
        "{e}"
    );
    assert_eq!(e.to_string().lines().count(), 1, "{e}");
    // Another variant: per-step weights expect tensors the file lacks.
    std::fs::write(
        &meta_path,
        text.replace("\"per_step_weights\": false", "\"per_step_weights\": true"),
    )
    .expect("write");
    let e = checkpoint::load(&dir, &device).expect_err("mismatch");
    assert!(e.to_string().contains("weights lack tensor"), "{e}");
    std::fs::write(&meta_path, &text).expect("restore");
    checkpoint::load(&dir, &device).expect("restored");

    // A truncated weights file.
    let w = dir.join("weights.bpk");
    let bytes = std::fs::read(&w).expect("read");
    std::fs::write(&w, &bytes[..bytes.len() / 2]).expect("truncate");
    let e = checkpoint::load(&dir, &device).expect_err("truncated");
    assert!(e.to_string().contains("weights"), "{e}");
    assert_eq!(e.to_string().lines().count(), 1, "{e}");

    // Statistics of the wrong length, a missing directory, malformed JSON.
    std::fs::write(&w, &bytes).expect("restore");
    std::fs::write(
        dir.join("stats.json"),
        serde_json::to_string(&unit_stats(dim + 3)).expect("json"),
    )
    .expect("write");
    assert!(
        checkpoint::load(&dir, &device)
            .expect_err("stats")
            .to_string()
            .contains("feature statistics")
    );
    assert!(
        checkpoint::load(&tmp.path().join("nope"), &device)
            .expect_err("missing")
            .to_string()
            .contains("no such checkpoint")
    );
    std::fs::write(&meta_path, "{").expect("write");
    assert!(
        checkpoint::load(&dir, &device)
            .expect_err("json")
            .to_string()
            .contains("malformed config.json")
    );
}

#[test]
fn same_seed_same_network_and_dropout_is_seeded() {
    let device = ndarray_device();
    let (_, energies, dim) = marker_frames(2, 9);
    let refs: Vec<&Energy> = energies.iter().collect();
    let config = small_config(Modality::Markers, dim);
    let run_net = |seed| {
        let net = NeuralNet::new(&config, seed, &device).expect("net");
        unroll(
            &net,
            &unit_stats(dim),
            &refs,
            &[None, None],
            None,
            &device,
            &mut Dropout::off(),
        )
        .expect("unroll")
        .host
    };
    assert_eq!(run_net(4), run_net(4));
    assert_ne!(run_net(4), run_net(5));
    let x = Tensor::<2>::ones([4, 100], &device);
    let run = |seed| {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        Dropout {
            p: 0.5,
            rng: Some(&mut rng),
        }
        .apply(x.clone())
        .try_into_vec_as::<f32>()
        .expect("read")
    };
    let (d1, d2) = (run(1), run(1));
    assert_eq!(d1, d2);
    let zeros = d1.iter().filter(|&&v| v == 0.0).count();
    assert!(
        (120..280).contains(&zeros),
        "about half dropped, got {zeros}/400"
    );
    assert!(
        d1.iter().all(|&v| v == 0.0 || v == 2.0),
        "kept entries are scaled by 1/(1-p)"
    );
}

/// The same weights on another backend give the same fit: ndarray is the reference; flex always,
/// wgpu when an adapter exists (required in CI).
#[test]
fn backends_agree_on_the_fitting_loop() {
    use crate::tensor::{device_from_name, wgpu_status};
    let (_, energies, dim) = marker_frames(3, 21);
    let refs: Vec<&Energy> = energies.iter().collect();
    let config = small_config(Modality::Markers, dim);
    let reference = ndarray_device();
    let net = NeuralNet::new(&config, 8, &reference).expect("net");
    let bytes = crate::checkpoint::weights_bytes(&net).expect("bytes");
    let starts = [None, Some(vec![0.02; POSE_DIM]), None];
    let want = unroll(
        &net,
        &unit_stats(dim),
        &refs,
        &starts,
        None,
        &reference,
        &mut Dropout::off(),
    )
    .expect("reference")
    .host;
    let mut devices = vec![("flex".to_string(), device_from_name("flex").expect("flex"))];
    match wgpu_status() {
        Ok(adapter) => devices.push((
            format!("wgpu on {adapter}"),
            device_from_name("wgpu").expect("wgpu"),
        )),
        Err(reason) => {
            assert!(
                std::env::var("LFIT_REQUIRE_WGPU").as_deref() != Ok("1"),
                "LFIT_REQUIRE_WGPU=1 but wgpu is unavailable: {reason}"
            );
            println!("skipping wgpu: {reason}");
        }
    }
    for (name, device) in devices {
        let other = crate::checkpoint::net_from_bytes(
            &config,
            bytes.clone(),
            &device,
            std::path::Path::new("mem"),
        )
        .expect("load");
        let got = unroll(
            &other,
            &unit_stats(dim),
            &refs,
            &starts,
            None,
            &device,
            &mut Dropout::off(),
        )
        .expect("unroll")
        .host;
        for (n, (a, b)) in want.iter().zip(&got).enumerate() {
            for (pa, pb) in a.iter().zip(b) {
                for (x, y) in pa.iter().zip(pb) {
                    assert!((x - y).abs() < 2e-3, "{name}, iteration {n}: {x} vs {y}");
                }
            }
        }
    }
}

/// A checkpoint that records its training energy refuses a fit with another one (the face's
/// eq. 9 energy is not the default); one without a record accepts any (older checkpoints).
#[test]
fn a_recorded_training_energy_must_match_the_fit() {
    let template = default_template();
    let mut meta = checkpoint::CheckpointMeta::new(&template, NetConfig::default());
    let dir = std::path::Path::new("checkpoints/x");
    let default = EnergyConfig::default().for_gradient();
    let mut face = default.clone();
    face.weights.expression = 1.0;
    face.weights.ep = 0.0;
    assert!(meta.check_energy(dir, &face).is_ok());
    meta.energy = Some(face.clone());
    assert!(meta.check_energy(dir, &face).is_ok());
    let e = meta.check_energy(dir, &default).unwrap_err().to_string();
    assert!(
        e.contains("checkpoints/x") && e.contains("another energy") && !e.contains('\n'),
        "{e}"
    );
    // It survives config.json.
    let back: checkpoint::CheckpointMeta =
        serde_json::from_str(&serde_json::to_string(&meta).unwrap()).unwrap();
    assert_eq!(back, meta);
}

/// Unit statistics of the features of `config`.
fn unit_stats_for(config: &NetConfig) -> FeatureStats {
    let n = |d: usize| Norm {
        mean: vec![0.0; d],
        std: vec![1.0; d],
    };
    FeatureStats {
        observation: n(config.obs_features()),
        residual: n(config.residual_features()),
        gradient: n(config.param_dim),
        pose: n(config.param_dim),
    }
}

/// A pooled keypoints2d network's config on `template`.
fn pooled_config(template: &Template) -> NetConfig {
    NetConfig {
        views: Views::Pooled,
        ..small_config(Modality::Keypoints2d, 2 * template.rig.num_joints())
    }
}

/// A keypoints2d energy of `cameras` at `pose`, observations noisy with dropouts (seeded by the
/// camera, so the same per camera whatever its place in the rig).
fn rig_energy(
    template: &Arc<Template>,
    cameras: &[lfit_model::camera::Camera],
    pose: &Pose,
) -> Energy {
    let sensor = Sensor::Keypoints2d(lfit_model::observe::KeypointSetup::new(cameras.to_vec()));
    let pred = sensor.predict_sparse(template, pose);
    let (mut values, mut visible) = (pred.values, pred.visible);
    // Noise and dropouts that depend on the camera, not on its place in the rig.
    let per = 2 * template.rig.num_joints();
    for (c, cam) in cameras.iter().enumerate() {
        let mut rng = ChaCha8Rng::seed_from_u64(cam.fx.to_bits() ^ cam.translation[0].to_bits());
        for i in (0..per).step_by(2) {
            let k = c * per + i;
            values[k] += rng.random_range(-2.0..2.0);
            values[k + 1] += rng.random_range(-2.0..2.0);
            if rng.random_bool(0.25) {
                visible[k] = false;
                visible[k + 1] = false;
            }
        }
    }
    Energy::new(
        template.clone(),
        sensor,
        Target::Sparse { values, visible },
        EnergyConfig::default().for_gradient(),
    )
    .expect("energy")
}

fn eight_cameras(seed: u64) -> Vec<lfit_model::camera::Camera> {
    let ranges = lfit_model::camera::RigRanges {
        cameras: [8, 8],
        ..Default::default()
    };
    ranges.sample(
        &mut ChaCha8Rng::seed_from_u64(seed),
        glam::DVec3::new(0.0, 1.0, 0.0),
    )
}

fn random_pose(seed: u64) -> Pose {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut pose: Pose = [0.0; POSE_DIM];
    for v in pose.iter_mut() {
        *v = rng.random_range(-0.2..0.2);
    }
    pose
}

#[test]
fn pooled_features_ignore_the_camera_order_and_have_one_length_for_1_3_and_8_cameras() {
    use crate::features::{observation_features, observation_features_for, residual_features};
    let template = Arc::new(default_template());
    let config = pooled_config(&template);
    let cams = eight_cameras(3);
    let truth = random_pose(4);
    let at = random_pose(5);
    let close = |a: &[f64], b: &[f64], what: &str| {
        assert_eq!(a.len(), b.len(), "{what}");
        for (i, (x, y)) in a.iter().zip(b).enumerate() {
            assert!(
                (x - y).abs() <= 1e-12 * (1.0 + x.abs()),
                "{what} {i}: {x} vs {y}"
            );
        }
    };
    let features = |cameras: &[lfit_model::camera::Camera]| {
        let e = rig_energy(&template, cameras, &truth);
        let obs = observation_features_for(&config, &e).expect("obs");
        let res = residual_features(&config, &e, &e.residual(&at))
            .expect("res")
            .into_owned();
        (e, obs, res)
    };
    let mut lengths = Vec::new();
    for n in [1, 3, 8] {
        let (e, obs, res) = features(&cams[..n]);
        assert_eq!(obs.len(), config.obs_features(), "{n} cameras");
        assert_eq!(res.len(), config.residual_features(), "{n} cameras");
        assert_eq!(*obs.last().expect("count"), n as f64, "camera count");
        // The fixed-rig features grow with the rig; the pooled ones do not.
        lengths.push((observation_features(&e).len(), obs.len(), res.len()));
        // Every permutation of the cameras gives the same features.
        let mut reversed = cams[..n].to_vec();
        reversed.reverse();
        let mut rotated = cams[..n].to_vec();
        rotated.rotate_left(n / 2);
        for (what, order) in [("reversed", reversed), ("rotated", rotated)] {
            let (_, o, r) = features(&order);
            close(&obs, &o, &format!("{n} cameras {what}: observation"));
            close(&res, &r, &format!("{n} cameras {what}: residual"));
        }
    }
    assert!(lengths[0].0 < lengths[1].0 && lengths[1].0 < lengths[2].0);
    assert!(
        lengths
            .iter()
            .all(|l| (l.1, l.2) == (lengths[0].1, lengths[0].2))
    );

    // One camera: the mean and the maximum are that camera's normalised coordinates, the
    // fractions its visibility, and the residual pools are its residual over the focal length.
    let (e, obs, res) = features(&cams[..1]);
    let Target::Sparse { values, visible } = e.target() else {
        unreachable!()
    };
    let (k, per, c) = (config.keypoints(), config.residual_dim, &cams[0]);
    let r = e.residual(&at);
    for i in 0..per {
        let (f, p) = if i % 2 == 0 {
            (c.fx, c.cx)
        } else {
            (c.fy, c.cy)
        };
        let want = if visible[i] { (values[i] - p) / f } else { 0.0 };
        assert!((obs[i] - want).abs() < 1e-12 && (obs[per + i] - want).abs() < 1e-12);
        assert!((res[i] - r[i] / f).abs() < 1e-12);
        assert!((res[per + i] - (r[i] / f).abs()).abs() < 1e-12);
    }
    for j in 0..k {
        assert_eq!(obs[2 * per + j], if visible[2 * j] { 1.0 } else { 0.0 });
    }
    // Three cameras pool to something else than the first alone.
    let (_, obs3, _) = features(&cams[..3]);
    assert!(obs.iter().zip(&obs3).any(|(a, b)| (a - b).abs() > 1e-3));
}

#[test]
fn a_pooled_network_fits_a_batch_of_rigs_of_1_3_and_8_cameras() {
    let device = ndarray_device();
    let template = Arc::new(default_template());
    let config = pooled_config(&template);
    config.validate().expect("config");
    let cams = eight_cameras(6);
    let pose = random_pose(7);
    let energies: Vec<Energy> = [1, 3, 8]
        .iter()
        .map(|&n| rig_energy(&template, &cams[..n], &pose))
        .collect();
    let refs: Vec<&Energy> = energies.iter().collect();
    let stats = unit_stats_for(&config);
    stats.validate(&config).expect("stats");
    let net = NeuralNet::new(&config, 1, &device).expect("net");
    let out = unroll(
        &net,
        &stats,
        &refs,
        &[None, None, None],
        None,
        &device,
        &mut Dropout::off(),
    )
    .expect("unroll");
    assert_eq!(out.host.len(), config.iterations + 1);
    assert!(out.host.iter().flatten().flatten().all(|v| v.is_finite()));
    // The fixed-rig statistics do not fit the pooled network.
    let e = unit_stats(config.residual_dim)
        .validate(&config)
        .expect_err("fixed stats");
    assert!(e.to_string().contains("observation"), "{e}");
    // Frames of another sensor are refused with one line.
    let (_, markers, _) = marker_frames(1, 2);
    let e = unroll(
        &net,
        &stats,
        &[&markers[0]],
        &[None],
        None,
        &device,
        &mut Dropout::off(),
    )
    .expect_err("markers");
    assert!(!e.to_string().contains('\n'), "{e}");
    // A pooled network needs keypoints2d.
    let e = NetConfig {
        views: Views::Pooled,
        ..small_config(Modality::Markers, 3 * 53)
    }
    .validate()
    .expect_err("pooled markers");
    assert!(e.to_string().contains("pooled needs keypoints2d"), "{e}");
}

#[test]
fn a_pooled_checkpoint_accepts_any_camera_count_and_a_fixed_one_only_its_rig() {
    let template = Arc::new(default_template());
    let dir = std::path::Path::new("ck");
    let per = 2 * template.rig.num_joints();
    let pooled = checkpoint::CheckpointMeta::new(&template, pooled_config(&template));
    for cameras in [1, 2, 3, 6, 8, 11] {
        pooled
            .check_compatible(dir, Modality::Keypoints2d, cameras * per, &template)
            .expect("any rig");
    }
    for dim in [0, per + 2, 3 * per - 4] {
        let e = pooled
            .check_compatible(dir, Modality::Keypoints2d, dim, &template)
            .expect_err("other keypoints")
            .to_string();
        assert!(
            e.contains(&format!(
                "fits keypoints2d rigs of {} keypoints per camera",
                per / 2
            )) && !e.contains('\n'),
            "{e}"
        );
    }
    let fixed =
        checkpoint::CheckpointMeta::new(&template, small_config(Modality::Keypoints2d, 6 * per));
    fixed
        .check_compatible(dir, Modality::Keypoints2d, 6 * per, &template)
        .expect("its own rig");
    let e = fixed
        .check_compatible(dir, Modality::Keypoints2d, 2 * per, &template)
        .expect_err("two cameras")
        .to_string();
    assert!(
        e.contains(&format!(
            "expects a residual of {} values, the data's sensor gives {}",
            6 * per,
            2 * per
        )),
        "{e}"
    );
    // The fixed default does not appear in config.json; pooled does.
    let text = serde_json::to_string(&fixed.network).expect("json");
    assert!(!text.contains("views"), "{text}");
    let text = serde_json::to_string(&pooled.network).expect("json");
    assert!(text.contains("\"views\":\"pooled\""), "{text}");
}

/// The largest entry of `(JᵀJ + μ D + 1e-12 max(D) I) h + b(c)` over the columns `cols`: the
/// damped system of LM and the Gauss-Newton directions (`D = diag(JᵀJ)` clamped to
/// `[1e-6, 1e32]`), built densely from `ls`'s Jacobian rows, independently of the sparse normal
/// equations and the envelope factorisation; `h` a full parameter vector.
fn dense_damped_system_residual(
    ls: &lfit_model::energy::LeastSquares,
    cols: &[usize],
    damping: f64,
    h: &[f64],
    b: impl Fn(usize) -> f64,
) -> f64 {
    let (m, n) = (ls.residuals.len(), h.len());
    let jtj = |a: usize, b: usize| -> f64 {
        (0..m)
            .map(|i| ls.jacobian[i * n + a] * ls.jacobian[i * n + b])
            .sum()
    };
    let max_diag = cols
        .iter()
        .map(|&c| jtj(c, c).clamp(1e-6, 1e32))
        .fold(0.0, f64::max);
    cols.iter()
        .map(|&a| {
            let lhs: f64 = cols
                .iter()
                .map(|&c| {
                    let mut v = jtj(a, c);
                    if a == c {
                        v += damping * jtj(a, a).clamp(1e-6, 1e32) + 1e-12 * max_diag;
                    }
                    v * h[c]
                })
                .sum();
            (lhs + b(a)).abs()
        })
        .fold(0.0, f64::max)
}

/// The Gauss-Newton direction solves LM's damped normal equations `(JᵀJ + μ D) h = −Jᵀr` (built
/// here densely from the Jacobian, independently of the sparse normal equations), is zero on
/// frozen entries, and stepping along it fits a frame far better in three steps than the
/// gradient direction at any fixed step.
#[test]
fn the_gauss_newton_direction_solves_the_damped_system_and_fits_where_the_gradient_crawls() {
    use crate::unroll::direction;
    let (_, energies, _) = marker_frames(3, 0x6E00);
    // Without the trust region first; the capped direction is checked against it below.
    let gn = NetConfig {
        direction: Direction::GaussNewton,
        gn_damping: 1e-2,
        gn_max_step: 1e9,
        ..NetConfig::default()
    };
    let capped = NetConfig {
        gn_max_step: 0.05,
        ..gn.clone()
    };
    for e in &energies {
        let start = vec![0.0; POSE_DIM];
        let ls = e.least_squares(&start, true).expect("least squares");
        let (m, n) = (ls.residuals.len(), POSE_DIM);
        // Frozen: the translation and the first joint; dense JᵀJ and Jᵀr on the free columns.
        let free: Vec<bool> = (0..n).map(|i| i >= 6).collect();
        let cols: Vec<usize> = (6..n).collect();
        let d = direction(&gn, e, &start, Some(&free)).expect("direction");
        assert!(
            d[..6].iter().all(|&v| v == 0.0),
            "frozen entries move: {:?}",
            &d[..6]
        );
        let jt_r = |c: usize| -> f64 {
            (0..m)
                .map(|i| ls.jacobian[i * n + c] * ls.residuals[i])
                .sum()
        };
        let scale = cols.iter().fold(0.0f64, |s, &c| s.max(jt_r(c).abs()));
        assert!(scale > 1e-6, "the frame is already fitted");
        // (JᵀJ + μ D + ridge) h = −Jᵀr with h = −d.
        let h: Vec<f64> = d.iter().map(|v| -v).collect();
        let worst = dense_damped_system_residual(&ls, &cols, gn.gn_damping, &h, jt_r);
        assert!(
            worst <= 1e-8 * scale,
            "system residual {worst:e} (scale {scale:e})"
        );
        // The trust region clips each entry, leaving the others as they are.
        let c = direction(&capped, e, &start, Some(&free)).expect("direction");
        assert!(
            d.iter().any(|v| v.abs() > 0.05) && d.iter().any(|v| v.abs() < 0.05 && *v != 0.0),
            "the cap is not exercised"
        );
        for (a, b) in c.iter().zip(&d) {
            assert_eq!(*a, b.clamp(-0.05, 0.05));
        }

        // Three steps along each direction from the rest pose, all entries free. Half steps
        // along Gauss-Newton: far from the target the Huber loss is in its linear part, where
        // the folded residual grows like √s and its linearisation puts the zero twice as far.
        let descend = |config: &NetConfig, step: f64| {
            let mut x = start.clone();
            for _ in 0..3 {
                let d = direction(config, e, &x, None).expect("direction");
                for (xi, di) in x.iter_mut().zip(&d) {
                    *xi -= step * di;
                }
            }
            e.evaluate(&x).total
        };
        let e0 = e.evaluate(&start).total;
        let by_gn = descend(&gn, 0.5);
        let by_gradient = [1e-5, 1e-4, 1e-3, 1e-2]
            .iter()
            .map(|&s| descend(&NetConfig::default(), s))
            .fold(f64::INFINITY, f64::min);
        assert!(by_gn < 0.02 * e0, "Gauss-Newton: {e0} -> {by_gn}");
        assert!(
            by_gn < 0.1 * by_gradient,
            "Gauss-Newton {by_gn} vs gradient {by_gradient}"
        );
    }
}

/// The chord direction: its first direction is the Gauss-Newton direction to the bit, and the
/// system it keeps solves `(J₀ᵀJ₀ + μ D₀) h = −∇E(θ)/2` at a later point θ (checked against the
/// system built densely from θ0's Jacobian and θ's gradient, independently of the envelope
/// factorisation); at θ0 that is the Gauss-Newton step again (`∇E/2 = Jᵀr`), and at the later
/// point it is not the Gauss-Newton step there.
#[test]
fn the_chord_direction_solves_the_first_points_system_with_the_later_points_gradient() {
    use crate::unroll::direction;
    let (template, energies, _) = marker_frames(2, 0xC40D);
    let gn = NetConfig {
        direction: Direction::GaussNewton,
        gn_max_step: 1e9,
        ..NetConfig::default()
    };
    let chord = NetConfig {
        direction: Direction::GaussNewtonChord,
        ..gn.clone()
    };
    let rank = template.elimination_rank();
    let mut rng = ChaCha8Rng::seed_from_u64(7);
    for e in &energies {
        let start = vec![0.0; POSE_DIM];
        assert_eq!(
            direction(&chord, e, &start, None).expect("chord"),
            direction(&gn, e, &start, None).expect("gn"),
            "the stateless chord direction is Gauss-Newton's"
        );
        let ls = e.least_squares(&start, true).expect("least squares");
        let dofs: Vec<usize> = (6..POSE_DIM).collect();
        let (h0, system) = ls
            .damped_gauss_newton_chord(&dofs, gn.gn_damping, &rank)
            .expect("factorised");
        assert_eq!(
            Some(h0.clone()),
            ls.damped_gauss_newton(&dofs, gn.gn_damping, &rank)
        );
        let mut sorted = system.entries().to_vec();
        sorted.sort_unstable();
        assert_eq!(sorted, dofs, "the system spans the free entries");
        // At θ0 with the energy's own gradient: the Gauss-Newton step within rounding.
        let (_, g0) = e.evaluate_with_gradient(&start);
        let again = system.step(&g0).expect("step");
        let scale = h0.iter().fold(0.0f64, |s, v| s.max(v.abs()));
        for (a, b) in again.iter().zip(&h0) {
            assert!((a - b).abs() <= 1e-9 * scale, "{a} vs {b}");
        }
        // At a later point: θ0's system, θ's gradient.
        let later: Vec<f64> = start
            .iter()
            .zip(&h0)
            .map(|(s, h)| s + 0.5 * h + rng.random_range(-0.02..0.02))
            .collect();
        let (_, g) = e.evaluate_with_gradient(&later);
        let h = system.step(&g).expect("step");
        assert!(h[..6].iter().all(|&v| v == 0.0), "frozen entries move");
        let scale = g.iter().fold(0.0f64, |s, v| s.max(v.abs()));
        let worst = dense_damped_system_residual(&ls, &dofs, gn.gn_damping, &h, |a| 0.5 * g[a]);
        assert!(
            worst <= 1e-8 * scale,
            "system residual {worst:e} ({scale:e})"
        );
        let fresh = e
            .least_squares(&later, true)
            .expect("least squares")
            .damped_gauss_newton(&dofs, gn.gn_damping, &rank)
            .expect("gn");
        let apart = h
            .iter()
            .zip(&fresh)
            .fold(0.0f64, |s, (a, b)| s.max((a - b).abs()));
        assert!(
            apart > 1e-6,
            "the chord step is the fresh Gauss-Newton step"
        );
        // A gradient of another length is refused, not read past.
        assert!(system.step(&g[..10]).is_none());
    }
}

/// In the fitting loop a chord network factorises each frame's system once: with a network
/// whose update is the direction itself (Δθ = 0, γ = 1), every iterate after the first steps
/// by the solve of θ0's system with the gradient at that iterate, and the loop counts one
/// evaluation and one gradient evaluation per iteration, as the Gauss-Newton loop does.
#[test]
fn the_fitting_loop_keeps_each_frames_chord_system_from_its_first_iterate() {
    use crate::unroll::{RowNetwork, RowState, StepOut, unroll_rows};
    struct Direct {
        config: NetConfig,
        stats: FeatureStats,
    }
    impl RowNetwork for Direct {
        type Error = lfit_model::ModelError;
        fn config(&self) -> &NetConfig {
            &self.config
        }
        fn stats(&self) -> &FeatureStats {
            &self.stats
        }
        fn initial(
            &mut self,
            _obs: &[f32],
            batch: usize,
        ) -> std::result::Result<(Vec<f32>, RowState), Self::Error> {
            Ok((
                vec![0.0; batch * self.config.param_dim],
                RowState::default(),
            ))
        }
        fn propose(
            &mut self,
            _n: usize,
            _core_in: &[f32],
            batch: usize,
            _state: &mut RowState,
        ) -> std::result::Result<Vec<f32>, Self::Error> {
            Ok(vec![0.0; batch * self.config.param_dim])
        }
        fn step(
            &mut self,
            _n: usize,
            _step_in: &[f32],
            _delta: &[f32],
            grad: &[f32],
            _batch: usize,
            _state: &mut RowState,
        ) -> std::result::Result<StepOut, Self::Error> {
            Ok(StepOut {
                update: grad.iter().map(|g| -g).collect(),
                lambda: Vec::new(),
                gamma: Vec::new(),
            })
        }
    }
    let (template, energies, dim) = marker_frames(2, 0xC40E);
    let rank = template.elimination_rank();
    let all: Vec<usize> = (0..POSE_DIM).collect();
    let refs: Vec<&Energy> = energies.iter().collect();
    let starts = vec![Some(vec![0.0; POSE_DIM]); refs.len()];
    for factorisations in [1, 2] {
        let config = NetConfig {
            direction: Direction::GaussNewtonChord,
            iterations: 4,
            chord_factorisations: factorisations,
            ..small_config(Modality::Markers, dim)
        };
        let mut net = Direct {
            stats: unit_stats_for(&config),
            config: config.clone(),
        };
        let before: Vec<(u64, u64)> = energies
            .iter()
            .map(|e| (e.evaluations(), e.gradient_evaluations()))
            .collect();
        let host = unroll_rows(&mut net, &refs, &starts, None).expect("unroll");
        let cap = |h: Vec<f64>| -> Vec<f64> {
            h.iter()
                .map(|v| v.clamp(-config.gn_max_step, config.gn_max_step))
                .collect()
        };
        for (i, e) in energies.iter().enumerate() {
            assert_eq!(
                (e.evaluations(), e.gradient_evaluations()),
                (before[i].0 + 4, before[i].1 + 4)
            );
            let theta: Vec<&Vec<f64>> = host.iter().map(|step| &step[i]).collect();
            // The system of the last iterate that factorised.
            let system = e
                .least_squares(theta[factorisations - 1], true)
                .expect("least squares")
                .damped_gauss_newton_chord(&all, config.gn_damping, &rank)
                .expect("factorised")
                .1;
            let mut moved_apart = 0.0f64;
            for k in 0..theta.len() - 1 {
                let fresh = cap(e
                    .least_squares(theta[k], true)
                    .expect("least squares")
                    .damped_gauss_newton(&all, config.gn_damping, &rank)
                    .expect("gn"));
                let want = if k < factorisations {
                    fresh.clone()
                } else {
                    let (_, g) = e.evaluate_with_gradient(theta[k]);
                    cap(system.step(&g).expect("step"))
                };
                let scale = want.iter().fold(1e-3f64, |s, v| s.max(v.abs()));
                for (j, w) in want.iter().enumerate() {
                    let got = theta[k + 1][j] - theta[k][j];
                    // θ is carried in f32 between iterations, as in the Burn loop.
                    assert!(
                        (got - w).abs() <= 1e-5 * scale + 1e-6,
                        "{factorisations} factorisations, frame {i}, iteration {k}, entry {j}: {got} vs {w}"
                    );
                    moved_apart = moved_apart.max((w - fresh[j]).abs());
                }
            }
            assert!(
                moved_apart > 1e-5,
                "frame {i}: every step is the fresh Gauss-Newton step"
            );
        }
    }
}

/// A chord network's config round-trips through JSON with its direction and factorisations;
/// factorisations outside 1..=N are refused by name, and the default's is not written.
#[test]
fn the_chord_config_round_trips_and_bad_factorisations_are_refused() {
    let chord = NetConfig {
        residual_dim: 6,
        direction: Direction::GaussNewtonChord,
        chord_factorisations: 2,
        ..NetConfig::default()
    };
    let text = serde_json::to_string(&chord).expect("json");
    assert!(
        text.contains("\"direction\":\"gauss-newton-chord\"")
            && text.contains("\"chord_factorisations\":2"),
        "{text}"
    );
    assert_eq!(
        serde_json::from_str::<NetConfig>(&text).expect("read"),
        chord
    );
    let one = serde_json::to_string(&NetConfig {
        chord_factorisations: 1,
        ..chord.clone()
    })
    .expect("json");
    assert!(!one.contains("chord_factorisations"), "{one}");
    assert!(chord.validate().is_ok());
    for bad in [0, chord.iterations + 1] {
        let err = NetConfig {
            chord_factorisations: bad,
            ..chord.clone()
        }
        .validate()
        .expect_err("factorisations outside 1..=N")
        .to_string();
        assert!(err.contains("chord_factorisations"), "{err}");
    }
}

/// A Gauss-Newton network's config round-trips through JSON, a gradient network's config has
/// no `direction` field (checkpoints written before the switch read as before), and a damping
/// that is not positive is refused by name.
#[test]
fn the_direction_switch_round_trips_and_a_bad_damping_is_refused() {
    let gn = NetConfig {
        residual_dim: 6,
        direction: Direction::GaussNewton,
        gn_damping: 0.1,
        ..NetConfig::default()
    };
    let text = serde_json::to_string(&gn).expect("json");
    assert!(text.contains("\"direction\":\"gauss-newton\"") && text.contains("\"gn_damping\":0.1"));
    assert_eq!(serde_json::from_str::<NetConfig>(&text).expect("read"), gn);
    let plain = serde_json::to_string(&NetConfig::default()).expect("json");
    assert!(
        !plain.contains("direction") && !plain.contains("gn_damping"),
        "{plain}"
    );
    for bad in [0.0, -1.0, f64::NAN] {
        let err = NetConfig {
            gn_damping: bad,
            ..gn.clone()
        }
        .validate()
        .unwrap_err()
        .to_string();
        assert!(err.contains("gn_damping"), "{err}");
    }
}

/// The native forward refuses weights that do not match the configuration they came with (a
/// checkpoint edited by hand, or of another build), with a one-line error naming the layer,
/// instead of reading past a row later.
#[test]
fn the_host_forward_refuses_weights_of_another_shape() {
    let config = small_config(Modality::Markers, 39 * 3);
    let mut net = NeuralNet::new(&config, 3, &ndarray_device()).expect("net");
    let stats = unit_stats_for(&config);
    assert!(crate::host::HostNet::new(&net, stats.clone()).is_ok());
    // The same weights under a configuration with another hidden width.
    net.config.hidden = config.hidden + 8;
    let err = crate::host::HostNet::new(&net, stats.clone())
        .expect_err("a hidden width the weights do not have")
        .to_string();
    assert!(err.contains("network layer"), "{err}");
    assert!(!err.contains('\n'), "one line: {err}");
    // And under one with another parameter count (Φ's output no longer matches).
    net.config.hidden = config.hidden;
    net.config.init_width = config.init_width * 2;
    let err = crate::host::HostNet::new(&net, stats)
        .expect_err("an initializer width the weights do not have")
        .to_string();
    assert!(err.contains("Φ.l1"), "{err}");
}

/// The native forward's per-frame observation term (`RowState::constant`): `initial` fills one
/// per weight set, `propose` gives the same Δθ with it as without it (computed from the rows' D
/// columns then), and a term of another length is a one-line error, not a panic.
#[test]
fn the_native_forward_keeps_the_observation_term_for_the_frame() {
    use crate::unroll::RowNetwork;
    let config = small_config(Modality::Markers, 39 * 3);
    let net = NeuralNet::new(&config, 3, &ndarray_device()).expect("net");
    let host = crate::host::HostNet::new(&net, unit_stats_for(&config)).expect("host");
    let batch = 3;
    let obs: Vec<f32> = (0..batch * config.obs_features())
        .map(|i| ((i * 37 % 101) as f32 / 50.0 - 1.0) * 0.7)
        .collect();
    let core_in: Vec<f32> = (0..batch)
        .flat_map(|b| {
            let head = config.core_inputs() - config.obs_features();
            (0..head)
                .map(move |i| (((b * 131 + i) * 53 % 97) as f32 / 48.0 - 1.0) * 0.5)
                .chain(obs[b * config.obs_features()..(b + 1) * config.obs_features()].to_vec())
        })
        .collect();
    let (_, state) = (&host).initial(&obs, batch).expect("initial");
    assert_eq!(state.constant.len(), config.weight_sets());
    assert_eq!(state.constant[0].len(), batch * 3 * config.hidden);
    let with = (&host)
        .propose(0, &core_in, batch, &mut state.clone())
        .expect("with the term");
    let mut without = state.clone();
    without.constant.clear();
    assert_eq!(
        with,
        (&host)
            .propose(0, &core_in, batch, &mut without)
            .expect("without")
    );
    let mut bad = state;
    bad.constant[0].pop();
    let err = (&host)
        .propose(0, &core_in, batch, &mut bad)
        .expect_err("a term of another length")
        .to_string();
    assert!(
        err.contains("observation term") && !err.contains('\n'),
        "{err}"
    );
}

/// The energy rule reads θk's energy from its residuals alone where it can stop the loop
/// (`Running::evaluate`), and from the Gauss-Newton evaluation elsewhere: the two must be the
/// same number, or a frame would stop where the full evaluation would have gone on. Markers,
/// keypoints2d and hmd, away from their targets (joint limits and EP rows active), with and
/// without a robust loss; the value counts one evaluation and no gradient, the Jacobian at the
/// same point (`jacobian_with`) one gradient and no evaluation.
#[test]
fn residuals_alone_give_the_energy_the_gauss_newton_evaluation_gives() {
    use crate::unroll::gauss_newton_value;
    use lfit_model::energy::{JacobianRows, RobustForm};
    let template = Arc::new(default_template());
    let mut checked = 0;
    for (m, modality) in [Modality::Markers, Modality::Keypoints2d, Modality::Hmd]
        .into_iter()
        .enumerate()
    {
        let sensor = Sensor::default_for(modality, &template);
        for robust in [false, true] {
            for k in 0..6u64 {
                let truth = random_pose(100 * m as u64 + k);
                let pred = sensor.predict_sparse(&template, &truth);
                let mut config = EnergyConfig::default().for_gradient();
                if robust {
                    config.robust = lfit_model::energy::Robust::Cauchy { c: 1.0 };
                }
                let e = Energy::new(
                    template.clone(),
                    sensor.clone(),
                    Target::Sparse {
                        values: pred.values,
                        visible: pred.visible,
                    },
                    config,
                )
                .expect("energy");
                // Far from the target: large residuals, limbs past their limits.
                let mut pose = random_pose(7 + 100 * m as u64 + k);
                for v in pose.iter_mut().skip(6) {
                    *v *= 8.0;
                }
                let (ev, gv) = (e.evaluations(), e.gradient_evaluations());
                let value = gauss_newton_value(&e, &pose).expect("value");
                assert_eq!(
                    (e.evaluations() - ev, e.gradient_evaluations() - gv),
                    (1, 0)
                );
                let full = e
                    .least_squares_with(&pose, true, RobustForm::Folded, JacobianRows::Factored)
                    .expect("least squares")
                    .value();
                assert!(value > 0.0);
                assert_eq!(
                    value.to_bits(),
                    full.to_bits(),
                    "{modality:?} robust {robust} pose {k}: {value} against {full}"
                );
                let (ev, gv) = (e.evaluations(), e.gradient_evaluations());
                let again = e
                    .jacobian_with(&pose, RobustForm::Folded, JacobianRows::Factored)
                    .expect("jacobian")
                    .value();
                assert_eq!(again.to_bits(), full.to_bits());
                assert_eq!(
                    (e.evaluations() - ev, e.gradient_evaluations() - gv),
                    (0, 1)
                );
                checked += 1;
            }
        }
    }
    assert_eq!(checked, 36);
}
