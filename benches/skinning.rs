//! Posing throughput of the CPU path (SPEC §3 FK + LBS) on the default template:
//! full meshes per second on one thread and on all threads, and marker sets per second; and on
//! a 24-joint SMPL-layout model (6,890 vertices, B = 10) with and without pose correctives.
//! Run with `cargo bench --bench skinning`.

mod support;

use std::hint::black_box;

use criterion::{BenchmarkId, Criterion, Throughput, criterion_group, criterion_main};
use lfit::model::default_template;
use lfit::model::skinning::{
    SkinningMethod, joint_transforms, pose_vertices_batch, skin_lbs_into, skin_lbs_subset,
};
use rayon::prelude::*;
use support::random_poses;

fn bench(c: &mut Criterion) {
    let template = default_template();
    let markers: Vec<u32> = template.rig.markers.iter().map(|m| m.vertex).collect();
    let poses = random_poses(256, 0.5);
    let threads = rayon::current_num_threads();

    let mut group = c.benchmark_group("full_mesh");
    group.throughput(Throughput::Elements(poses.len() as u64));
    group.bench_function(BenchmarkId::new("lbs", "1_thread"), |b| {
        let mut out = Vec::with_capacity(template.num_vertices());
        b.iter(|| {
            for p in &poses {
                let a = joint_transforms(&template, p);
                skin_lbs_into(&template, &a, &mut out);
                black_box(&out);
            }
        })
    });
    group.bench_function(BenchmarkId::new("lbs", format!("{threads}_threads")), |b| {
        b.iter(|| {
            poses
                .par_chunks(poses.len().div_ceil(threads))
                .for_each(|chunk| {
                    let mut out = Vec::with_capacity(template.num_vertices());
                    for p in chunk {
                        let a = joint_transforms(&template, p);
                        skin_lbs_into(&template, &a, &mut out);
                        black_box(&out);
                    }
                })
        })
    });
    group.bench_function(
        BenchmarkId::new("lbs_batch_api", format!("{threads}_threads")),
        |b| {
            b.iter(|| {
                black_box(pose_vertices_batch(
                    &template,
                    &poses,
                    SkinningMethod::Linear,
                ))
            })
        },
    );
    group.bench_function(
        BenchmarkId::new("dqs_batch_api", format!("{threads}_threads")),
        |b| {
            b.iter(|| {
                black_box(pose_vertices_batch(
                    &template,
                    &poses,
                    SkinningMethod::DualQuaternion,
                ))
            })
        },
    );
    group.finish();

    // The 24-joint SMPL-like test model (lfit_model::body::smpl_like), f64 skinning with β.
    for posedirs in [false, true] {
        let model = lfit::model::body::smpl_like(3, 6890, 10, posedirs);
        let params: Vec<Vec<f64>> = random_poses(64, 0.5)
            .iter()
            .map(|p| {
                let mut v: Vec<f64> = (0..model.layout().pose_dim())
                    .map(|i| p[i % p.len()])
                    .collect();
                v.extend((0..10).map(|k| (k as f64 - 4.5) * 0.4));
                v
            })
            .collect();
        let mut group = c.benchmark_group(format!(
            "smpl24_full_mesh{}",
            if posedirs { "_posedirs" } else { "" }
        ));
        group.throughput(Throughput::Elements(params.len() as u64));
        group.bench_function(BenchmarkId::new("lbs", "1_thread"), |b| {
            let mut out = Vec::with_capacity(model.num_vertices());
            b.iter(|| {
                for p in &params {
                    let a = joint_transforms(&model, p);
                    skin_lbs_into(&model, &a, &mut out);
                    black_box(&out);
                }
            })
        });
        group.finish();
    }

    let mut group = c.benchmark_group("marker_set");
    group.throughput(Throughput::Elements(poses.len() as u64));
    group.bench_function(BenchmarkId::new("lbs", "1_thread"), |b| {
        b.iter(|| {
            for p in &poses {
                let a = joint_transforms(&template, p);
                black_box(skin_lbs_subset(&template, &a, &markers));
            }
        })
    });
    group.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
