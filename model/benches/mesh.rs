//! Full meshes per second on one thread (FK + LBS of every vertex): the f32 loop
//! (`skin_lbs_into`, what rendering, export, synthesis and the silhouettes model use) against the
//! f64 reference it replaced for morphable and wide-influence models (`skin_lbs_f64`: each
//! vertex shaped by a dot product per axis, its influences read from the rig's lists), in the
//! same run. Models: the committed MakeHuman body (`models/makehuman-cmu_mb.npz`: 13,380
//! vertices, 31 joints, B = 16, up to 7 influences), the default template and an SMPL-like model
//! with pose correctives; 32 random parameter vectors (±0.3 rad, translation ±0.3 m,
//! β ~ N(0, 0.5²)) as in the root package's `makehuman` bench. Report f32 / f64 ratios;
//! `f32_rest_mesh_only` is the f32 loop's shape pass (FK included) without the skinning;
//! `f32_one_shape` the f32 loop on poses that share one β (a sequence of one subject).
//!
//! Run with `cargo bench -p lfit-model --bench mesh` (Burn-free: builds in minutes).

use std::hint::black_box;
use std::path::Path;

use criterion::{Criterion, Throughput, criterion_group, criterion_main};
use lfit_model::body::{default_template, smpl_like};
use lfit_model::skinning::{joint_transforms, skin_lbs_f64, skin_lbs_into};
mod support;
use support::params;

fn bench(c: &mut Criterion) {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../models/makehuman-cmu_mb.npz");
    let models = [
        (
            "makehuman",
            lfit_model::modelfile::load(&path).expect("models/makehuman-cmu_mb.npz"),
        ),
        ("default", default_template()),
        ("smpl_like_6890_posedirs", smpl_like(1, 6890, 10, true)),
    ];
    let one = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .expect("pool");
    for (name, template) in &models {
        let ps = params(template, 32);
        let mut group = c.benchmark_group(format!("mesh/{name}"));
        group.throughput(Throughput::Elements(ps.len() as u64));
        // One subject: the 32 poses share the first vector's β (rendering or exporting a
        // sequence fitted with one β), so the shape offsets are computed once.
        let pose_dim = template.layout().pose_dim();
        let one_shape: Vec<Vec<f64>> = ps
            .iter()
            .map(|p| {
                let mut q = p.clone();
                q[pose_dim..].copy_from_slice(&ps[0][pose_dim..]);
                q
            })
            .collect();
        for (label, list) in [("f32", &ps), ("f32_one_shape", &one_shape)] {
            group.bench_function(label, |b| {
                let mut out = Vec::with_capacity(template.num_vertices());
                b.iter(|| {
                    one.install(|| {
                        for p in list {
                            let a = joint_transforms(template, p);
                            skin_lbs_into(template, &a, &mut out);
                            black_box(&out);
                        }
                    })
                })
            });
        }
        // The shape pass alone (what the f32 loop spends before skinning).
        group.bench_function("f32_rest_mesh_only", |b| {
            let mut rest = Vec::new();
            b.iter(|| {
                one.install(|| {
                    for p in &ps {
                        let a = joint_transforms(template, p);
                        template.morph.rest_mesh_f32(
                            &template.vertices,
                            &a.coeffs,
                            &a.pose_feature,
                            &mut rest,
                        );
                        black_box(&rest);
                    }
                })
            })
        });
        group.bench_function("f64_reference", |b| {
            b.iter(|| {
                one.install(|| {
                    for p in &ps {
                        let a = joint_transforms(template, p);
                        black_box(skin_lbs_f64(template, &a));
                    }
                })
            })
        });
        group.finish();
    }
}

criterion_group!(benches, bench);
criterion_main!(benches);
