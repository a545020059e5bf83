//! papers/002 Table 7's runtime comparison on the face (issue 16): the time of one **parameter
//! update** given what the update needs — for Levenberg–Marquardt the normal equations `JᵀJ`,
//! `Jᵀr` from the residuals and Jacobian, then the damped Cholesky solve
//! ([`lfit::fitters::least_squares::damped_step`]); for the neural fitter one iteration of the
//! network (f, fλγ and the update of eq. 1) on features already computed — at 114 variables
//! (3 + 3·5 + 64 + 32) on models/makehuman-face.npz, in the same process. The paper: neural 12 ms
//! (GPU) vs LM 34.7 ms at 504 variables (0.8 ms for LM on a laptop CPU at 100 variables).
//!
//! Also the energy evaluations an update needs (`residuals+jacobian` for LM,
//! `residuals+gradient` for the neural fitter), so the update can be put next to the whole
//! iteration. Uses the shipped checkpoints/face (or, without it, a freshly initialised network
//! of configs/face.json: the same cost). Run with `cargo bench --bench face`.

use std::hint::black_box;
use std::path::Path;
use std::sync::Arc;

use burn::tensor::{Tensor, TensorData};
use criterion::{BenchmarkId, Criterion, criterion_group, criterion_main};
use lfit::fitters::least_squares::damped_step;
use lfit::infer::{NeuralFitter, Start};
use lfit::model::Energy;
use lfit::model::energy::marquardt_scaling;
use lfit::model::observe::{Modality, Sensor};
use lfit::nn::Dropout;
use lfit::nn::checkpoint::{Checkpoint, CheckpointMeta};
use lfit::nn::tensor::{device_from_name, tensor_to_rows};
use lfit::nn::unroll::{core_rows, evaluate, observation_rows, step_rows};
use lfit::nn::{FeatureStats, NeuralNet};
use lfit::synth::PoseSource;
use lfit::train::{Motions, TrainConfig, base_energy_with, measure_stats, synth_frames_with};

fn fitter(frames: &lfit::train::Frames, config: &TrainConfig, device: &str) -> NeuralFitter {
    let device = device_from_name(device).expect("device");
    let dir = Path::new("checkpoints/face");
    if dir.join("config.json").exists() {
        return NeuralFitter::load(dir, &device, Start::Given).expect("checkpoint");
    }
    eprintln!("checkpoints/face absent: a fresh network of configs/face.json (the same cost)");
    let template = frames.energies[0].template();
    let mut net = config.network.clone();
    net.modality = Modality::Landmarks2d;
    net.residual_dim = Sensor::default_for(Modality::Landmarks2d, template).residual_dim(template);
    net.param_dim = template.param_dim();
    let stats: FeatureStats = measure_stats(frames);
    let checkpoint = Checkpoint {
        meta: CheckpointMeta {
            energy: config.energy.clone(),
            ..CheckpointMeta::new(template, net.clone())
        },
        stats,
        net: NeuralNet::new(&net, 0, &device).expect("net"),
        metrics: serde_json::Value::Null,
    };
    NeuralFitter::from_checkpoint(checkpoint, dir, &device, Start::Given)
}

fn bench(c: &mut Criterion) {
    let template = Arc::new(
        lfit::model::modelfile::load(Path::new("models/makehuman-face.npz")).expect("face model"),
    );
    let config = TrainConfig::load(Path::new("configs/face.json")).expect("configs/face.json");
    let sensor = Sensor::default_for(Modality::Landmarks2d, &template);
    let energy = config
        .energy
        .clone()
        .expect("configs/face.json names its energy");
    let base = base_energy_with(&template, &sensor, energy).expect("energy");
    let motions = Motions {
        source: PoseSource::Face,
        ..Motions::default()
    };
    let frames = synth_frames_with(
        &template,
        &sensor,
        &base,
        64,
        0x7E57_0000_0000_F00D,
        1.0,
        &motions,
    )
    .expect("frames");
    let dim = template.param_dim();
    let dofs: Vec<usize> = (0..dim).collect();
    let mut group = c.benchmark_group("face-update");
    group.sample_size(30);

    // LM: the update from the residuals and Jacobian of the start pose.
    let energies: Vec<&Energy> = frames.energies.iter().collect();
    let starts = &frames.dataset.start_poses;
    let ls: Vec<_> = energies
        .iter()
        .zip(starts)
        .map(|(e, x)| e.least_squares(x, true).expect("least squares"))
        .collect();
    // The system in the elimination order LM solves it in.
    let rank = template.elimination_rank();
    let mut ordered = dofs.clone();
    ordered.sort_by_key(|&p| rank[p]);
    group.bench_function(BenchmarkId::new("lm-update", dim), |b| {
        let mut i = 0;
        b.iter(|| {
            i = (i + 1) % ls.len();
            let (a, g) = ls[i].normal_equations(&dofs);
            let (diag, max_diag) = marquardt_scaling(&a, &ordered);
            black_box(damped_step(&a, &g, &ordered, &diag, 1e-4, max_diag))
        })
    });
    group.bench_function(BenchmarkId::new("residuals+jacobian", dim), |b| {
        let mut i = 0;
        b.iter(|| {
            i = (i + 1) % energies.len();
            black_box(energies[i].least_squares(&starts[i], true).expect("ls"))
        })
    });
    group.bench_function(BenchmarkId::new("residuals+gradient", dim), |b| {
        let mut i = 0;
        b.iter(|| {
            i = (i + 1) % energies.len();
            black_box((
                energies[i].residual(&starts[i]),
                energies[i].evaluate_with_gradient(&starts[i]),
            ))
        })
    });

    // Neural: one iteration of the network at batch 1 on precomputed features.
    for name in ["ndarray", "flex"] {
        let f = fitter(&frames, &config, name);
        let c = &f.meta.network;
        let one: Vec<&Energy> = energies[..1].to_vec();
        let poses = vec![starts[0].clone()];
        let obs = observation_rows(c, &f.stats, &one).expect("obs");
        let evals = evaluate(c, &one, &poses, None).expect("evaluate");
        let core = core_rows(c, &f.stats, &one, &evals, &poses, &obs).expect("core");
        let delta = vec![vec![1e-3; c.param_dim]];
        let step = step_rows(c, &f.stats, &one, &poses, &evals, &delta).expect("step");
        let grad: Vec<f32> = evals[0].1.iter().map(|&v| v as f32).collect();
        let net = f.burn_net().expect("burn");
        let device = device_from_name(name).expect("device");
        let row = |v: Vec<f32>| {
            let d = v.len();
            Tensor::<2>::from_data(TensorData::new(v, [1, d]), &device)
        };
        let (obs, core, step, grad) = (row(obs.concat()), row(core), row(step), row(grad));
        let (_, state0) = net.initial(obs);
        group.bench_function(
            BenchmarkId::new(format!("neural-update-{name}"), dim),
            |b| {
                b.iter(|| {
                    let mut state = state0.clone();
                    let d = net.propose(0, core.clone(), &mut state, &mut Dropout::off());
                    let sizes = net.step_sizes(0, step.clone(), &mut state, &mut Dropout::off());
                    black_box(tensor_to_rows(net.update(d, grad.clone(), &sizes)).expect("rows"))
                })
            },
        );
    }
    group.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
