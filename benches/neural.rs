//! Neural fitter speed (issue 4's figures): per-frame latency at batch 1 and throughput at
//! batch 256 on ndarray and flex (and wgpu when an adapter exists), against L-BFGS and
//! CMA-ES@4000 on the same frames in the same process. Uses the shipped checkpoint of the
//! modality (`checkpoints/<modality>`), or a freshly initialised network of the same
//! configuration (`configs/<modality>.json`, same cost) when the checkpoint is absent.
//! Run with `cargo bench --bench neural` (LFIT_BENCH_MODALITY=markers|keypoints2d|hmd).
//!
//! Issue 6 adds ONNX Runtime (`ort`, when libonnxruntime is found, see
//! scripts/fetch-onnxruntime.sh) to the same run: whole fits (`fit-*`, the energy included) and
//! the network alone (`network-*`: Φ/Φh and N × (f, fλγ, update) on fixed features, outputs read
//! back to the host), each at batch 1 and 256, for ndarray, flex and ort; and lfit's own host
//! forward (`native`, `--runtime native`).

use std::hint::black_box;
use std::path::Path;
use std::sync::Arc;

use criterion::{BenchmarkId, Criterion, Throughput, criterion_group, criterion_main};
use lfit::fitters::optim::Preset;
use lfit::fitters::{FitRequest, Strategy, build_fitter};
use lfit::infer::onnx::runtime::{SessionOptions, library_path};
use lfit::infer::{NeuralFitter, Start};
use lfit::model::observe::{Modality, Sensor};
use lfit::model::pose::{Bounds, DofMask};
use lfit::nn::Dropout;
use lfit::nn::checkpoint::{Checkpoint, CheckpointMeta};
use lfit::nn::unroll::{core_rows, evaluate, observation_rows, step_rows};
use lfit::nn::{FeatureStats, NeuralNet, RowNetwork};

use burn::tensor::{Tensor, TensorData};
use lfit::model::{Energy, default_template};
use lfit::nn::tensor::{device_from_name, tensor_to_rows, wgpu_available};
use lfit::train::{TrainConfig, base_energy, measure_stats, synth_frames};

fn fitter(modality: Modality, device_name: &str, frames: &lfit::train::Frames) -> NeuralFitter {
    let device = device_from_name(device_name).expect("device");
    let dir = Path::new("checkpoints").join(modality.name());
    if dir.join("config.json").exists() {
        return NeuralFitter::load(&dir, &device, Start::Given).expect("checkpoint");
    }
    let config = TrainConfig::load(&Path::new("configs").join(format!("{}.json", modality.name())))
        .expect("config");
    let template = frames.energies[0].template();
    let mut net = config.network.clone();
    net.modality = modality;
    net.residual_dim = Sensor::default_for(modality, template).residual_dim(template);
    let stats: FeatureStats = measure_stats(frames);
    let meta = CheckpointMeta {
        format: "lfit-checkpoint".into(),
        version: 1,
        template_id: template.id.clone(),
        template_vertices: template.num_vertices(),
        network: net.clone(),
        model: None,
        energy: None,
    };
    let checkpoint = Checkpoint {
        meta,
        stats,
        net: NeuralNet::new(&net, 0, &device).expect("net"),
        metrics: serde_json::Value::Null,
    };
    NeuralFitter::from_checkpoint(checkpoint, &dir, &device, Start::Given)
}

fn requests<'a>(
    energies: &'a [Energy],
    frames: &lfit::train::Frames,
    budget: usize,
) -> Vec<FitRequest<'a>> {
    energies
        .iter()
        .zip(&frames.dataset.start_poses)
        .map(|(energy, start)| FitRequest {
            energy,
            start: start.clone(),
            mask: DofMask::local43(),
            bounds: Bounds::local(start),
            budget,
            seed: 1,
            motion: None,
        })
        .collect()
}

fn bench(c: &mut Criterion) {
    let modality: Modality = std::env::var("LFIT_BENCH_MODALITY")
        .unwrap_or_else(|_| "markers".into())
        .parse()
        .expect("modality");
    let template = Arc::new(default_template());
    let sensor = Sensor::default_for(modality, &template);
    let base = base_energy(&template, &sensor).expect("energy");
    let frames =
        synth_frames(&template, &sensor, &base, 256, 0x7E57_0000_0000_0001, 1.0).expect("frames");
    let energies = frames.energies.clone();
    let all = requests(&energies, &frames, 10);
    let mut devices = vec!["ndarray", "flex"];
    if wgpu_available() {
        devices.push("wgpu");
    }
    let ort_ok = library_path().is_file();
    if !ort_ok {
        eprintln!(
            "ort: skipped, no ONNX Runtime library at {} (scripts/fetch-onnxruntime.sh)",
            library_path().display()
        );
    }
    network_only(c, modality, &frames, &devices, ort_ok);
    let mut group = c.benchmark_group(format!("fit-{}", modality.name()));
    group.sample_size(10);
    let mut engines: Vec<&str> = devices.clone();
    engines.push("native");
    if ort_ok {
        engines.push("ort");
    }
    for name in engines {
        let f = if name == "native" {
            NeuralFitter::load_native(
                &Path::new("checkpoints").join(modality.name()),
                Start::Given,
            )
            .expect("native fitter")
        } else if name == "ort" {
            NeuralFitter::load_ort(
                &Path::new("checkpoints").join(modality.name()),
                Start::Given,
                SessionOptions::default(),
            )
            .expect("ort fitter")
        } else {
            fitter(modality, name, &frames)
        };
        group.throughput(Throughput::Elements(1));
        group.bench_function(BenchmarkId::new(format!("neural-{name}"), "batch1"), |b| {
            let mut i = 0;
            b.iter(|| {
                i = (i + 1) % all.len();
                black_box(f.fit_batch(&all[i..i + 1]).expect("fit"))
            })
        });
        group.throughput(Throughput::Elements(all.len() as u64));
        group.bench_function(
            BenchmarkId::new(format!("neural-{name}"), "batch256"),
            |b| b.iter(|| black_box(f.fit_batch(&all).expect("fit"))),
        );
    }
    group.throughput(Throughput::Elements(1));
    for (method, budget) in [("lbfgs", 1000), ("cma", 4000)] {
        let fitter = build_fitter(method, Preset::Nevergrad, Strategy::Holistic).expect("fitter");
        let reqs = requests(&energies, &frames, budget);
        group.bench_function(BenchmarkId::new(method, format!("budget{budget}")), |b| {
            let mut i = 0;
            b.iter(|| {
                i = (i + 1) % reqs.len();
                black_box(fitter.fit(&reqs[i]).expect("fit"))
            })
        });
    }
    group.finish();
}

/// Features of iteration 0 for every frame (reused for every iteration: the cost of the network
/// does not depend on the values).
struct Inputs {
    obs: Vec<f32>,
    core: Vec<f32>,
    step: Vec<f32>,
    grad: Vec<f32>,
}

fn inputs(f: &NeuralFitter, frames: &lfit::train::Frames) -> Inputs {
    let c = &f.meta.network;
    let energies: Vec<&Energy> = frames.energies.iter().collect();
    let poses: Vec<Vec<f64>> = frames.dataset.start_poses.clone();
    let obs = observation_rows(c, &f.stats, &energies).expect("obs");
    let evals = evaluate(c, &energies, &poses, None).expect("evaluate");
    let core = core_rows(c, &f.stats, &energies, &evals, &poses, &obs).expect("core");
    let delta_poses: Vec<Vec<f64>> = poses.iter().map(|_| vec![1e-3; c.param_dim]).collect();
    let step = step_rows(c, &f.stats, &energies, &poses, &evals, &delta_poses).expect("step");
    let grad = evals
        .iter()
        .flat_map(|(_, g)| g.iter().map(|&v| v as f32))
        .collect();
    Inputs {
        obs: obs.concat(),
        core,
        step,
        grad,
    }
}

fn take(v: &[f32], batch: usize, total: usize) -> Vec<f32> {
    v[..v.len() / total * batch].to_vec()
}

/// The network alone: Φ/Φh, then N × (f, fλγ, update), at batch 1 and 256, per engine.
fn network_only(
    c: &mut Criterion,
    modality: Modality,
    frames: &lfit::train::Frames,
    devices: &[&str],
    ort_ok: bool,
) {
    let total = frames.energies.len();
    let mut group = c.benchmark_group(format!("network-{}", modality.name()));
    group.sample_size(20);
    for name in devices {
        let f = fitter(modality, name, frames);
        let input = inputs(&f, frames);
        let net = f.burn_net().expect("burn");
        let device = device_from_name(name).expect("device");
        for batch in [1usize, total] {
            let rows = |v: &[f32]| {
                let data = take(v, batch, total);
                let d = data.len() / batch;
                Tensor::<2>::from_data(TensorData::new(data, [batch, d]), &device)
            };
            let (obs, core, step, grad) = (
                rows(&input.obs),
                rows(&input.core),
                rows(&input.step),
                rows(&input.grad),
            );
            group.throughput(Throughput::Elements(batch as u64));
            group.bench_function(
                BenchmarkId::new(format!("neural-{name}"), format!("batch{batch}")),
                |b| {
                    b.iter(|| {
                        let (theta0, mut state) = net.initial(obs.clone());
                        let mut out = tensor_to_rows(theta0).expect("rows");
                        for n in 0..net.config.iterations {
                            // As in the fitting loop: Δθ and θ come back to the host every iteration.
                            let d = net.propose(n, core.clone(), &mut state, &mut Dropout::off());
                            black_box(tensor_to_rows(d.clone()).expect("rows"));
                            let sizes =
                                net.step_sizes(n, step.clone(), &mut state, &mut Dropout::off());
                            out =
                                tensor_to_rows(net.update(d, grad.clone(), &sizes)).expect("rows");
                        }
                        black_box(out)
                    })
                },
            );
        }
    }
    // lfit's own forward on the host (`--runtime native`), from the flex fitter's weights.
    let f = fitter(modality, "flex", frames);
    let input = inputs(&f, frames);
    let host = lfit::nn::HostNet::new(f.burn_net().expect("burn"), f.stats.clone()).expect("host");
    rows_network(&mut group, "neural-native", &mut &host, &input, total);
    if ort_ok {
        let f = NeuralFitter::load_ort(
            &Path::new("checkpoints").join(modality.name()),
            Start::Given,
            SessionOptions::default(),
        )
        .expect("ort fitter");
        let input = inputs(&f, frames);
        let lfit::infer::Engine::Ort(network) = &f.engine else {
            panic!("ort engine")
        };
        let mut ort = network.lock().expect("sessions");
        rows_network(&mut group, "neural-ort", &mut *ort, &input, total);
    }
    group.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);

/// A host-row network (ONNX Runtime or native): Φ/Φh, then N × (f, fλγ, update), at batch 1
/// and `total`.
fn rows_network<N: RowNetwork>(
    group: &mut criterion::BenchmarkGroup<'_, criterion::measurement::WallTime>,
    name: &str,
    net: &mut N,
    input: &Inputs,
    total: usize,
) where
    N::Error: std::fmt::Debug,
{
    let iterations = net.config().iterations;
    for batch in [1usize, total] {
        let (obs, core, step, grad) = (
            take(&input.obs, batch, total),
            take(&input.core, batch, total),
            take(&input.step, batch, total),
            take(&input.grad, batch, total),
        );
        group.throughput(Throughput::Elements(batch as u64));
        group.bench_function(BenchmarkId::new(name, format!("batch{batch}")), |b| {
            b.iter(|| {
                let (theta0, mut state) = net.initial(&obs, batch).expect("init");
                let mut out = theta0;
                for n in 0..iterations {
                    let d = net.propose(n, &core, batch, &mut state).expect("propose");
                    out = net
                        .step(n, &step, &d, &grad, batch, &mut state)
                        .expect("step")
                        .update;
                }
                black_box(out)
            })
        });
    }
}
