//! Speed on the MakeHuman body (issue 15) next to the default template, in the same run:
//! full meshes per second (FK + LBS, one thread), and energy value, value + gradient and
//! residuals + Jacobian evaluations per second for `markers`, `keypoints2d` and `hmd` (one
//! thread). The MakeHuman body is the committed `models/makehuman-cmu_mb.npz` (13,380 vertices,
//! 31 joints, B = 16, 39 markers); parameters are random poses (±0.3 rad, translation ±0.3 m) and
//! β ~ N(0, 0.5²). Report the figures as MakeHuman / default ratios.
//! Run with `cargo bench --bench makehuman`.

use std::hint::black_box;
use std::path::Path;
use std::sync::Arc;

use criterion::{BenchmarkId, Criterion, Throughput, criterion_group, criterion_main};
use lfit::model::energy::{Energy, EnergyConfig, Target};
use lfit::model::observe::{Modality, Sensor};
use lfit::model::skinning::{joint_transforms, skin_lbs_into};
use lfit::model::{Template, default_template};
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

criterion_group! {
    name = benches;
    config = Criterion::default().sample_size(10).warm_up_time(std::time::Duration::from_secs(1)).measurement_time(std::time::Duration::from_secs(3));
    targets = bench
}
criterion_main!(benches);
