//! The cost model of one evaluation on the MakeHuman body (`docs/results/cost-model.md`), per
//! modality (`markers`, `keypoints2d`, `hmd`), one thread: the energy value, value + gradient,
//! residuals alone, residuals + Jacobian and the normal equations of that Jacobian, each with EP
//! in its capsule form (the default), in the vertex form of papers/000 eq. (8) it replaced
//! (`_vertex_ep`, the reference in the same run) and without EP (`_without_ep`); and the damped
//! Cholesky solve (what one Levenberg–Marquardt iteration and one Gauss-Newton step of the neural
//! fitter pay); and the face's dense landmarks (value, value + gradient, residuals + Jacobian on
//! models/makehuman-face.npz). 32 random parameter vectors
//! (±0.3 rad, translation ±0.3 m, β ~ N(0, 0.5²)) as in the mesh bench.
//!
//! Run with `cargo bench -p lfit-model --bench energy` (Burn-free: builds in minutes).

use std::hint::black_box;
use std::path::Path;
use std::sync::Arc;

use criterion::{Criterion, Throughput, criterion_group, criterion_main};
use lfit_model::energy::{
    Energy, EnergyConfig, JacobianRows, PenetrationForm, RobustForm, Target, damped_step,
    envelope_work, marquardt_scaling,
};
use lfit_model::observe::{Modality, Sensor};
mod support;
use support::params;

fn bench(c: &mut Criterion) {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../models/makehuman-cmu_mb.npz");
    let template =
        Arc::new(lfit_model::modelfile::load(&path).expect("models/makehuman-cmu_mb.npz"));
    let one = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .expect("pool");
    // One thread: each measurement runs inside this pool (entered once per measurement, not
    // per batch of 32 systems: a batch handed to the pool's thread and waited for costs a
    // wake-up of the order of a whole evaluation, which is the harness's, not the energy's).
    let ps = params(&template, 32);
    for modality in [Modality::Markers, Modality::Keypoints2d, Modality::Hmd] {
        let sensor = Sensor::default_for(modality, &template);
        let pred = sensor.predict_sparse(&template, &ps[0]);
        let target = Target::Sparse {
            values: pred.values,
            visible: pred.visible,
        };
        // The capsule form of EP (the default), the vertex form of papers/000 eq. (8) it
        // replaced (the reference: the code before issue 26's change), and EP's weight 0.
        let config = EnergyConfig::default().for_gradient();
        let vertex = EnergyConfig {
            penetration: PenetrationForm::Vertices,
            ..config.clone()
        };
        let mut no_ep = config.clone();
        no_ep.weights.ep = 0.0;
        let forms = [("", config), ("_vertex_ep", vertex), ("_without_ep", no_ep)].map(
            |(label, config)| {
                let e = Energy::new(template.clone(), sensor.clone(), target.clone(), config)
                    .expect("energy");
                (label, e)
            },
        );
        let dofs: Vec<usize> = (0..forms[0].1.dim()).collect();
        let mut group = c.benchmark_group(format!("cost_model/makehuman/{modality}"));
        group.throughput(Throughput::Elements(ps.len() as u64));
        for (label, e) in &forms {
            group.bench_function(format!("value{label}"), |b| {
                one.install(|| b.iter(|| ps.iter().map(|p| e.evaluate(p).total).sum::<f64>()))
            });
            group.bench_function(format!("value_and_gradient{label}"), |b| {
                one.install(|| {
                    b.iter(|| {
                        ps.iter()
                            .map(|p| e.evaluate_with_gradient(p).1[0])
                            .sum::<f64>()
                    })
                })
            });
            group.bench_function(format!("residuals{label}"), |b| {
                one.install(|| {
                    b.iter(|| {
                        ps.iter()
                            .map(|p| e.least_squares(p, false).expect("residuals").energy)
                            .sum::<f64>()
                    })
                })
            });
            group.bench_function(format!("jacobian{label}"), |b| {
                one.install(|| {
                    b.iter(|| {
                        ps.iter()
                            .map(|p| e.least_squares(p, true).expect("jacobian").energy)
                            .sum::<f64>()
                    })
                })
            });
            // As LM asks: factored data rows where the sensor has them, prior rows as entries.
            group.bench_function(format!("jacobian_factored{label}"), |b| {
                one.install(|| {
                    b.iter(|| {
                        ps.iter()
                            .map(|p| {
                                e.least_squares_with(
                                    p,
                                    true,
                                    RobustForm::Folded,
                                    JacobianRows::Factored,
                                )
                                .expect("jacobian")
                                .energy
                            })
                            .sum::<f64>()
                    })
                })
            });
            let systems: Vec<_> = ps
                .iter()
                .map(|p| e.least_squares(p, true).expect("jacobian"))
                .collect();
            let factored: Vec<_> = ps
                .iter()
                .map(|p| {
                    e.least_squares_with(p, true, RobustForm::Folded, JacobianRows::Factored)
                        .expect("jacobian")
                })
                .collect();
            group.bench_function(format!("normal_equations_factored{label}"), |b| {
                b.iter(|| {
                    factored
                        .iter()
                        .map(|ls| ls.normal_equations(&dofs).1[0])
                        .sum::<f64>()
                })
            });
            group.bench_function(format!("normal_equations{label}"), |b| {
                b.iter(|| {
                    systems
                        .iter()
                        .map(|ls| ls.normal_equations(&dofs).1[0])
                        .sum::<f64>()
                })
            });
            // The row-by-row reference (the code before the rows of one pattern were grouped).
            if label.is_empty() {
                group.bench_function("normal_equations_by_row", |b| {
                    b.iter(|| {
                        systems
                            .iter()
                            .map(|ls| ls.normal_equations_by_row(&dofs).1[0])
                            .sum::<f64>()
                    })
                });
            }
        }
        let normal: Vec<_> = ps
            .iter()
            .map(|p| {
                forms[0]
                    .1
                    .least_squares(p, true)
                    .expect("jacobian")
                    .normal_equations(&dofs)
            })
            .collect();
        // The parameters in the elimination order LM solves in (children before parents).
        let rank = template.elimination_rank();
        let mut ordered = dofs.clone();
        ordered.sort_by_key(|&p| rank[p]);
        // The work each piece does (multiply-adds, mean over the 32 systems), printed for the
        // cost model (docs/results/cost-model.md): the Jacobian's nonzero and stored entries,
        // the normal equations' multiply-adds, the Cholesky factorisation's (dense, envelope in
        // the parameters' order, envelope in the elimination order) and the two triangular
        // solves'.
        {
            let n = dofs.len();
            let (mut jnz, mut jall, mut ne) = (0usize, 0usize, 0usize);
            let (mut natural, mut tree, mut solves) = (0usize, 0usize, 0usize);
            for (p, (a, _)) in ps.iter().zip(&normal) {
                let ls = forms[0].1.least_squares(p, true).expect("jacobian");
                jall += ls.residuals.len() * n;
                for i in 0..ls.residuals.len() {
                    if ls.zero_rows.get(i).copied().unwrap_or(false) {
                        continue;
                    }
                    let nz = ls.row(i).iter().filter(|v| **v != 0.0).count();
                    jnz += nz;
                    ne += nz * (nz + 1) / 2 + nz;
                }
                natural += envelope_work(a, &dofs).0;
                let (t, s) = envelope_work(a, &ordered);
                tree += t;
                solves += s;
            }
            let k = ps.len();
            println!(
                "cost_model/makehuman/{modality} work per system (multiply-adds): Jacobian {} nonzero of {} stored entries; normal equations {}; Cholesky dense {}, envelope {} (parameter order), {} (elimination order); triangular solves {}",
                jnz / k,
                jall / k,
                ne / k,
                n * (n * n - 1) / 6,
                natural / k,
                tree / k,
                solves / k
            );
        }
        // The Cholesky solve before the envelope form (nalgebra's dense factorisation), the
        // envelope form in the parameters' own order, and in the elimination order.
        group.bench_function("damped_solve_dense_reference", |b| {
            b.iter(|| {
                black_box(
                    normal
                        .iter()
                        .map(|(a, g)| {
                            let (diag, max_diag) = marquardt_scaling(a, &dofs);
                            let mut sys = a.clone();
                            for (k, dk) in diag.iter().enumerate() {
                                sys[(k, k)] += 1e-2 * dk + 1e-12 * max_diag;
                            }
                            sys.cholesky().map_or(0.0, |c| c.solve(&(-g))[0])
                        })
                        .sum::<f64>(),
                )
            })
        });
        for (label, order) in [
            ("damped_solve", &dofs),
            ("damped_solve_tree_order", &ordered),
        ] {
            group.bench_function(label, |b| {
                b.iter(|| {
                    black_box(
                        normal
                            .iter()
                            .map(|(a, g)| {
                                let (diag, max_diag) = marquardt_scaling(a, order);
                                damped_step(a, g, order, &diag, 1e-2, max_diag)
                                    .map_or(0.0, |h| h[0])
                            })
                            .sum::<f64>(),
                    )
                })
            });
        }
        group.finish();
    }
    // The face (models/makehuman-face.npz): its dense 2D landmarks, each shaped by identity β and
    // expression ψ, one camera.
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../models/makehuman-face.npz");
    let face = Arc::new(lfit_model::modelfile::load(&path).expect("models/makehuman-face.npz"));
    let fs = params(&face, 32);
    let sensor = Sensor::default_for(Modality::Landmarks2d, &face);
    let pred = sensor.predict_sparse(&face, &fs[0]);
    let target = Target::Sparse {
        values: pred.values,
        visible: pred.visible,
    };
    let e = Energy::new(
        face.clone(),
        sensor,
        target,
        EnergyConfig::default().for_gradient(),
    )
    .expect("face energy");
    let mut group = c.benchmark_group("cost_model/face/landmarks2d");
    group.throughput(Throughput::Elements(fs.len() as u64));
    group.bench_function("value", |b| {
        one.install(|| b.iter(|| fs.iter().map(|p| e.evaluate(p).total).sum::<f64>()))
    });
    group.bench_function("value_and_gradient", |b| {
        one.install(|| {
            b.iter(|| {
                fs.iter()
                    .map(|p| e.evaluate_with_gradient(p).1[0])
                    .sum::<f64>()
            })
        })
    });
    group.bench_function("jacobian", |b| {
        one.install(|| {
            b.iter(|| {
                fs.iter()
                    .map(|p| e.least_squares(p, true).expect("jacobian").energy)
                    .sum::<f64>()
            })
        })
    });
    group.finish();
}

criterion_group! {
    name = benches;
    config = Criterion::default().sample_size(10).warm_up_time(std::time::Duration::from_secs(1)).measurement_time(std::time::Duration::from_secs(2));
    targets = bench
}
criterion_main!(benches);
