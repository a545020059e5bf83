//! Speed on the MakeHuman body (issue 15) next to the default template, in the same run:
//! full meshes per second (FK + LBS, one thread), and energy value, value + gradient and
//! residuals + Jacobian evaluations per second for `markers`, `keypoints2d` and `hmd` (one
//! thread). The MakeHuman body is the committed `models/makehuman-cmu_mb.npz` (13,380 vertices,
//! 31 joints, B = 16, 39 markers); parameters are random poses (±0.3 rad, translation ±0.3 m) and
//! β ~ N(0, 0.5²). Report the figures as MakeHuman / default ratios.
//!
//! `neural_speed/<model>`: the shipped `markers` fitters (`checkpoints/markers` on the default
//! template, `checkpoints/markers-makehuman` on the MakeHuman body; N = 5, flex backend, starts
//! given) per frame at batch 1 and per batch of 256 synthetic frames, energy included.
//! Run with `cargo bench --bench makehuman`.

use std::hint::black_box;
use std::path::Path;
use std::sync::Arc;

use criterion::{BenchmarkId, Criterion, Throughput, criterion_group, criterion_main};
use lfit::fitters::FitRequest;
use lfit::infer::{NeuralFitter, Start};
use lfit::model::energy::{Energy, EnergyConfig, Target};
use lfit::model::observe::{Modality, Sensor};
use lfit::model::pose::{Bounds, DofMask, MaskKind};
use lfit::model::skinning::{joint_transforms, skin_lbs_into};
use lfit::model::{Template, default_template};
use lfit::nn::tensor::device_from_name;
use lfit::train::{base_energy, synth_frames};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, StandardNormal};

fn params(template: &Template, n: usize) -> Vec<Vec<f64>> {
    let layout = template.layout();
    let mut rng = ChaCha8Rng::seed_from_u64(42);
    (0..n)
        .map(|_| {
            let mut p: Vec<f64> = (0..layout.pose_dim())
                .map(|_| rng.random_range(-0.3..0.3))
                .collect();
            for _ in 0..layout.shape + layout.expression {
                let z: f64 = StandardNormal.sample(&mut rng);
                p.push(0.5 * z);
            }
            p
        })
        .collect()
}

fn bench(c: &mut Criterion) {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("models/makehuman-cmu_mb.npz");
    let models = [
        ("default", Arc::new(default_template())),
        (
            "makehuman",
            Arc::new(lfit::model::modelfile::load(&path).expect("models/makehuman-cmu_mb.npz")),
        ),
    ];
    let one = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .expect("pool");
    for (name, template) in &models {
        let ps = params(template, 32);
        let mut group = c.benchmark_group(format!("model_speed/{name}"));
        group.throughput(Throughput::Elements(ps.len() as u64));
        group.bench_function("mesh_1_thread", |b| {
            let mut out = Vec::with_capacity(template.num_vertices());
            b.iter(|| {
                one.install(|| {
                    for p in &ps {
                        let a = joint_transforms(template, p);
                        skin_lbs_into(template, &a, &mut out);
                        black_box(&out);
                    }
                })
            })
        });
        for modality in [Modality::Markers, Modality::Keypoints2d, Modality::Hmd] {
            let sensor = Sensor::default_for(modality, template);
            let pred = sensor.predict_sparse(template, &ps[0]);
            let e = Energy::new(
                template.clone(),
                sensor,
                Target::Sparse {
                    values: pred.values,
                    visible: pred.visible,
                },
                EnergyConfig::default().for_gradient(),
            )
            .expect("energy");
            let m = modality.name();
            group.bench_function(BenchmarkId::new(m, "value"), |b| {
                b.iter(|| one.install(|| ps.iter().map(|p| e.evaluate(p).total).sum::<f64>()))
            });
            group.bench_function(BenchmarkId::new(m, "gradient"), |b| {
                b.iter(|| {
                    one.install(|| {
                        ps.iter()
                            .map(|p| e.evaluate_with_gradient(p).0.total)
                            .sum::<f64>()
                    })
                })
            });
            group.bench_function(BenchmarkId::new(m, "jacobian"), |b| {
                b.iter(|| {
                    one.install(|| {
                        ps.iter()
                            .map(|p| e.least_squares(p, true).expect("jacobian").residuals.len())
                            .sum::<usize>()
                    })
                })
            });
        }
        group.finish();
    }
}

fn neural(c: &mut Criterion) {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("models/makehuman-cmu_mb.npz");
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("checkpoints");
    let models = [
        (
            "default",
            Arc::new(default_template()),
            root.join("markers"),
        ),
        (
            "makehuman",
            Arc::new(lfit::model::modelfile::load(&path).expect("models/makehuman-cmu_mb.npz")),
            root.join("markers-makehuman"),
        ),
    ];
    let device = device_from_name("flex").expect("flex");
    for (name, template, checkpoint) in &models {
        let sensor = Sensor::default_for(Modality::Markers, template);
        let base = base_energy(template, &sensor).expect("energy");
        let frames = synth_frames(template, &sensor, &base, 256, 0x7E57_0000_0000_0002, 1.0)
            .expect("frames");
        let fitter = NeuralFitter::load(checkpoint, &device, Start::Given).expect("checkpoint");
        let mask = DofMask::standard(MaskKind::Full, template, true);
        let requests: Vec<FitRequest<'_>> = frames
            .energies
            .iter()
            .zip(&frames.dataset.start_poses)
            .map(|(energy, start)| FitRequest {
                energy,
                start: start.clone(),
                mask: mask.clone(),
                bounds: Bounds::global_for(template),
                budget: 10,
                seed: 1,
                motion: None,
            })
            .collect();
        let mut group = c.benchmark_group(format!("neural_speed/{name}"));
        group.throughput(Throughput::Elements(1));
        group.bench_function("batch1", |b| {
            let mut i = 0;
            b.iter(|| {
                i = (i + 1) % requests.len();
                black_box(fitter.fit_batch(&requests[i..i + 1]).expect("fit"))
            })
        });
        group.throughput(Throughput::Elements(requests.len() as u64));
        group.bench_function("batch256", |b| {
            b.iter(|| black_box(fitter.fit_batch(&requests).expect("fit")))
        });
        group.finish();
    }
}

/// The cost model of one markers evaluation on the MakeHuman body (docs/results/cost-model.md):
/// the value with and without EP (EP's share), residuals alone, residuals + Jacobian, the normal
/// equations of that Jacobian and the damped Cholesky solve, one thread, same random poses as
/// `model_speed`.
fn cost_model(c: &mut Criterion) {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("models/makehuman-cmu_mb.npz");
    let template =
        Arc::new(lfit::model::modelfile::load(&path).expect("models/makehuman-cmu_mb.npz"));
    let one = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .expect("pool");
    let ps = params(&template, 32);
    let sensor = Sensor::default_for(Modality::Markers, &template);
    let pred = sensor.predict_sparse(&template, &ps[0]);
    let target = Target::Sparse {
        values: pred.values,
        visible: pred.visible,
    };
    let config = EnergyConfig::default().for_gradient();
    let mut no_ep = config.clone();
    no_ep.weights.ep = 0.0;
    let e = Energy::new(template.clone(), sensor.clone(), target.clone(), config).expect("energy");
    let e0 = Energy::new(template.clone(), sensor, target, no_ep).expect("energy");
    let dofs: Vec<usize> = (0..e.dim()).collect();
    let systems: Vec<_> = ps
        .iter()
        .map(|p| e.least_squares(p, true).expect("jacobian"))
        .collect();
    let normal: Vec<_> = systems
        .iter()
        .map(|ls| ls.normal_equations(&dofs))
        .collect();
    let mut group = c.benchmark_group("cost_model/makehuman/markers");
    group.throughput(Throughput::Elements(ps.len() as u64));
    group.bench_function("value", |b| {
        b.iter(|| one.install(|| ps.iter().map(|p| e.evaluate(p).total).sum::<f64>()))
    });
    group.bench_function("value_without_ep", |b| {
        b.iter(|| one.install(|| ps.iter().map(|p| e0.evaluate(p).total).sum::<f64>()))
    });
    group.bench_function("residuals", |b| {
        b.iter(|| {
            one.install(|| {
                ps.iter()
                    .map(|p| e.least_squares(p, false).expect("residuals").energy)
                    .sum::<f64>()
            })
        })
    });
    group.bench_function("jacobian", |b| {
        b.iter(|| {
            one.install(|| {
                ps.iter()
                    .map(|p| e.least_squares(p, true).expect("jacobian").energy)
                    .sum::<f64>()
            })
        })
    });
    group.bench_function("jacobian_without_ep", |b| {
        b.iter(|| {
            one.install(|| {
                ps.iter()
                    .map(|p| e0.least_squares(p, true).expect("jacobian").energy)
                    .sum::<f64>()
            })
        })
    });
    group.bench_function("normal_equations", |b| {
        b.iter(|| {
            systems
                .iter()
                .map(|ls| ls.normal_equations(&dofs).1[0])
                .sum::<f64>()
        })
    });
    // In the elimination order LM solves in (children before parents: no fill).
    let rank = template.elimination_rank();
    let mut ordered = dofs.clone();
    ordered.sort_by_key(|&p| rank[p]);
    group.bench_function("damped_solve", |b| {
        b.iter(|| {
            normal
                .iter()
                .map(|(a, g)| {
                    let (diag, max_diag) = lfit::model::energy::marquardt_scaling(a, &ordered);
                    lfit::model::energy::damped_step(a, g, &ordered, &diag, 1e-2, max_diag)
                        .map_or(0.0, |h| h[0])
                })
                .sum::<f64>()
        })
    });
    group.finish();
}

criterion_group! {
    name = benches;
    config = Criterion::default().sample_size(10).warm_up_time(std::time::Duration::from_secs(1)).measurement_time(std::time::Duration::from_secs(3));
    targets = bench, neural, cost_model
}
criterion_main!(benches);
