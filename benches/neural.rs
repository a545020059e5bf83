//! Neural fitter speed (issue 4's figures): per-frame latency at batch 1 and throughput at
//! batch 256 on ndarray and flex (and wgpu when an adapter exists), against L-BFGS and
//! CMA-ES@4000 on the same frames in the same process. Uses the shipped checkpoint of the
//! modality (`checkpoints/<modality>`), or a freshly initialised network of the same
//! configuration (`configs/<modality>.json`, same cost) when the checkpoint is absent.
//! Run with `cargo bench --bench neural` (LFIT_BENCH_MODALITY=markers|keypoints2d|hmd).

use std::hint::black_box;
use std::path::Path;
use std::sync::Arc;

use criterion::{BenchmarkId, Criterion, Throughput, criterion_group, criterion_main};
use lfit::fitters::optim::Preset;
use lfit::fitters::{FitRequest, Strategy, build_fitter};
use lfit::infer::{NeuralFitter, Start};
use lfit::model::network::checkpoint::{Checkpoint, CheckpointMeta};
use lfit::model::network::{FeatureStats, NeuralNet};
use lfit::model::observe::{Modality, Sensor};
use lfit::model::pose::{Bounds, DofMask};
use lfit::model::tensor::{device_from_name, wgpu_available};
use lfit::model::{Energy, default_template};
use lfit::train::{TrainConfig, base_energy, measure_stats, synth_frames};

fn fitter(modality: Modality, device_name: &str, frames: &lfit::train::Frames) -> NeuralFitter {
    let device = device_from_name(device_name).expect("device");
    let dir = Path::new("checkpoints").join(modality.name());
    if dir.join("config.json").exists() {
        return NeuralFitter::load(&dir, &device, Start::Given).expect("checkpoint");
    }
    let config = TrainConfig::load(&Path::new("configs").join(format!("{}.json", modality.name()))).expect("config");
    let template = frames.energies[0].template();
    let mut net = config.network.clone();
    net.modality = modality;
    net.residual_dim = Sensor::default_for(modality, template).residual_dim(template);
    let stats: FeatureStats = measure_stats(frames);
    let meta = CheckpointMeta { format: "lfit-checkpoint".into(), version: 1, template_id: template.id.clone(), template_vertices: template.num_vertices(), network: net.clone() };
    let checkpoint = Checkpoint { meta, stats, net: NeuralNet::new(&net, 0, &device).expect("net"), metrics: serde_json::Value::Null };
    NeuralFitter::from_checkpoint(checkpoint, &dir, &device, Start::Given)
}

fn requests<'a>(energies: &'a [Energy], frames: &lfit::train::Frames, budget: usize) -> Vec<FitRequest<'a>> {
    energies
        .iter()
        .zip(&frames.dataset.start_poses)
        .map(|(energy, &start)| FitRequest { energy, start, mask: DofMask::local43(), bounds: Bounds::local(&start), budget, seed: 1 })
        .collect()
}

fn bench(c: &mut Criterion) {
    let modality: Modality = std::env::var("LFIT_BENCH_MODALITY").unwrap_or_else(|_| "markers".into()).parse().expect("modality");
    let template = Arc::new(default_template());
    let sensor = Sensor::default_for(modality, &template);
    let base = base_energy(&template, &sensor).expect("energy");
    let frames = synth_frames(&template, &sensor, &base, 256, 0x7E57_0000_0000_0001, 1.0).expect("frames");
    let energies = frames.energies.clone();
    let all = requests(&energies, &frames, 10);
    let mut devices = vec!["ndarray", "flex"];
    if wgpu_available() {
        devices.push("wgpu");
    }
    let mut group = c.benchmark_group(format!("fit-{}", modality.name()));
    group.sample_size(10);
    for name in devices {
        let f = fitter(modality, name, &frames);
        group.throughput(Throughput::Elements(1));
        group.bench_function(BenchmarkId::new(format!("neural-{name}"), "batch1"), |b| {
            let mut i = 0;
            b.iter(|| {
                i = (i + 1) % all.len();
                black_box(f.fit_batch(&all[i..i + 1]).expect("fit"))
            })
        });
        group.throughput(Throughput::Elements(all.len() as u64));
        group.bench_function(BenchmarkId::new(format!("neural-{name}"), "batch256"), |b| b.iter(|| black_box(f.fit_batch(&all).expect("fit"))));
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

criterion_group!(benches, bench);
criterion_main!(benches);
