//! Energy and optimizer throughput (issue 3's benchmark figures):
//! energy evaluations per second per modality on the default template (one thread, all threads),
//! gradient evaluations per second, EJ alone (4 views at 128 px wide), and optimizer overhead per
//! evaluation at d = 43 with a zero-cost function.
//! Run with `cargo bench --bench energy`.

mod support;

use std::hint::black_box;
use std::sync::Arc;

use criterion::{BenchmarkId, Criterion, Throughput, criterion_group, criterion_main};
use lfit::fitters::optim::{self, Method, Preset, Problem};
use lfit::model::energy::{Energy, EnergyConfig, Target};
use lfit::model::observe::{Modality, Sensor};
use lfit::model::scan::{DEFAULT_BOX_SCALE, distance_transform, render_silhouettes};
use lfit::model::skinning::{SkinningMethod, pose_vertices};
use lfit::model::{Template, default_template};
use rayon::prelude::*;
use support::random_poses;

fn energy(template: &Arc<Template>, modality: Modality, config: EnergyConfig) -> Energy {
    let sensor = Sensor::default_for(modality, template);
    let gt = random_poses(1, 0.2)[0];
    let target = match &sensor {
        Sensor::Scan(setup) => {
            let verts = pose_vertices(template, &gt, SkinningMethod::Linear);
            let grid =
                distance_transform(&verts, setup.voxel_size, DEFAULT_BOX_SCALE).expect("grid");
            Target::Scan {
                grid,
                silhouettes: render_silhouettes(&setup.cameras, &verts, &template.faces),
            }
        }
        _ => {
            let p = sensor.predict_sparse(template, &gt);
            Target::Sparse {
                values: p.values,
                visible: p.visible,
            }
        }
    };
    Energy::new(template.clone(), sensor, target, config).expect("energy")
}

fn bench(c: &mut Criterion) {
    let template = Arc::new(default_template());
    let poses = random_poses(64, 0.3);
    let one = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .expect("pool");
    let threads = rayon::current_num_threads();
    let mut group = c.benchmark_group("energy");
    group.throughput(Throughput::Elements(poses.len() as u64));
    let mut no_ej = EnergyConfig::default();
    no_ej.silhouettes = false;
    let cases = [
        (
            "markers",
            energy(&template, Modality::Markers, EnergyConfig::default()),
        ),
        (
            "keypoints2d",
            energy(&template, Modality::Keypoints2d, EnergyConfig::default()),
        ),
        (
            "hmd",
            energy(&template, Modality::Hmd, EnergyConfig::default()),
        ),
        ("scan_without_EJ", energy(&template, Modality::Scan, no_ej)),
        (
            "scan_with_EJ",
            energy(&template, Modality::Scan, EnergyConfig::default()),
        ),
    ];
    for (name, e) in &cases {
        group.bench_function(BenchmarkId::new(*name, "1_thread"), |b| {
            b.iter(|| one.install(|| black_box(e.evaluate_batch(&poses))))
        });
        group.bench_function(BenchmarkId::new(*name, format!("{threads}_threads")), |b| {
            b.iter(|| black_box(e.evaluate_batch(&poses)))
        });
    }
    group.finish();

    let mut group = c.benchmark_group("gradient");
    group.throughput(Throughput::Elements(poses.len() as u64));
    for (name, e) in &cases[..4] {
        let e = Energy::clone(e);
        group.bench_function(BenchmarkId::new(*name, "1_thread"), |b| {
            b.iter(|| {
                for p in &poses {
                    black_box(e.evaluate_with_gradient(p));
                }
            })
        });
        group.bench_function(BenchmarkId::new(*name, format!("{threads}_threads")), |b| {
            b.iter(|| {
                black_box(
                    poses
                        .par_iter()
                        .map(|p| e.evaluate_with_gradient(p).0.total)
                        .sum::<f64>(),
                )
            })
        });
    }
    group.finish();

    // The least-squares form of the sparse energies (gradient variant): residuals alone, and
    // residuals with their exact Jacobian (what one Gauss-Newton / LM evaluation costs), next to
    // the gradient rows above.
    let mut group = c.benchmark_group("jacobian");
    group.throughput(Throughput::Elements(poses.len() as u64));
    for modality in [Modality::Markers, Modality::Keypoints2d, Modality::Hmd] {
        let e = energy(&template, modality, EnergyConfig::default().for_gradient());
        let name = modality.name();
        group.bench_function(BenchmarkId::new(name, "gradient_1_thread"), |b| {
            b.iter(|| {
                for p in &poses {
                    black_box(e.evaluate_with_gradient(p));
                }
            })
        });
        group.bench_function(BenchmarkId::new(name, "residuals_1_thread"), |b| {
            b.iter(|| {
                for p in &poses {
                    black_box(e.least_squares(p, false).expect("residuals"));
                }
            })
        });
        group.bench_function(BenchmarkId::new(name, "jacobian_1_thread"), |b| {
            b.iter(|| {
                for p in &poses {
                    black_box(e.least_squares(p, true).expect("jacobian"));
                }
            })
        });
    }
    group.finish();

    // EJ's own cost is the difference of the scan rows with and without EJ above.
    let mut group = c.benchmark_group("optimizer_overhead_d43");
    let evals = 4_000usize;
    group.throughput(Throughput::Elements(evals as u64));
    for method in [
        Method::RandomSearch,
        Method::OnePlusOne,
        Method::DE,
        Method::PSO,
        Method::CMA,
        Method::TBPSA,
        Method::Powell,
        Method::APF,
    ] {
        group.bench_function(method.as_str(), |b| {
            b.iter(|| {
                let problem = Problem::new(
                    optim::Bounds::uniform(43, -1.0, 1.0).expect("bounds"),
                    vec![0.0; 43],
                    vec![0.1; 43],
                )
                .expect("problem");
                let mut opt = optim::build(method, Preset::Nevergrad, &problem, evals, 1, None)
                    .expect("build");
                let f = |x: &[f64]| x[0] * 0.0;
                black_box(optim::minimize(opt.as_mut(), &f, evals, false).expect("run"))
            })
        });
    }
    group.finish();
}

/// Energy evaluations per second on the 24-joint SMPL-like model (6,890 vertices, B = 10, 30
/// markers) with and without pose correctives.
fn bench_smpl24(c: &mut Criterion) {
    for posedirs in [false, true] {
        let model = Arc::new(lfit::model::body::smpl_like(3, 6890, 10, posedirs));
        let dim = model.layout().dim();
        let params: Vec<Vec<f64>> = random_poses(64, 0.3)
            .iter()
            .map(|p| {
                (0..dim)
                    .map(|i| if i < 75 { p[i % p.len()] } else { 0.5 })
                    .collect()
            })
            .collect();
        let sensor = Sensor::default_for(Modality::Markers, &model);
        let pred = sensor.predict_sparse(&model, &params[0]);
        let e = Energy::new(
            model.clone(),
            sensor,
            Target::Sparse {
                values: pred.values,
                visible: pred.visible,
            },
            EnergyConfig::default().for_gradient(),
        )
        .expect("energy");
        let mut group = c.benchmark_group(format!(
            "smpl24_markers{}",
            if posedirs { "_posedirs" } else { "" }
        ));
        group.throughput(Throughput::Elements(params.len() as u64));
        group.bench_function("value", |b| {
            b.iter(|| params.iter().map(|p| e.evaluate(p).total).sum::<f64>())
        });
        group.bench_function("gradient", |b| {
            b.iter(|| {
                params
                    .iter()
                    .map(|p| e.evaluate_with_gradient(p).0.total)
                    .sum::<f64>()
            })
        });
        group.bench_function("jacobian", |b| {
            b.iter(|| {
                params
                    .iter()
                    .map(|p| e.least_squares(p, true).expect("jacobian").residuals.len())
                    .sum::<usize>()
            })
        });
        group.finish();
    }
}

criterion_group! {
    name = benches;
    config = Criterion::default().sample_size(10).warm_up_time(std::time::Duration::from_secs(1)).measurement_time(std::time::Duration::from_secs(3));
    targets = bench, bench_smpl24
}
criterion_main!(benches);
