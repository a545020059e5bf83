//! A sensor defined outside lfit (the IMU suit of `examples/imu_sensor.rs`) goes through
//! synthesis, the energy, its Jacobian and gradient, LM and neural training without any change
//! to lfit's own types.

use std::sync::Arc;

use lfit::model::observe::{Modality, Sensor};
use lfit::model::{Energy, EnergyConfig, Target, default_template};
use lfit::synth::{Observations, Scenario, SynthConfig, synthesize};

#[allow(dead_code)]
#[path = "../examples/imu_sensor.rs"]
mod imu_sensor;

fn suit_energy(seed: u64) -> (Energy, Vec<f64>) {
    let t = Arc::new(default_template());
    let sensor = Sensor::Custom(Arc::new(imu_sensor::ImuSuit::new(&t).expect("suit")));
    let data = synthesize(
        &SynthConfig::new(Modality::Custom, Scenario::Local, 1, seed),
        &t,
        &sensor,
        &|_| {},
    )
    .expect("synth");
    let Observations::Sparse { values, visible } = data.observations else {
        panic!("a vector sensor gives sparse observations")
    };
    let e = Energy::new(
        t,
        sensor,
        Target::Sparse {
            values: values[0].clone(),
            visible: visible[0].clone(),
        },
        EnergyConfig::default().for_gradient(),
    )
    .expect("energy");
    (e, data.start_poses[0].clone())
}

#[test]
fn the_custom_jacobian_matches_central_differences_and_the_default_gradient_is_2_jt_r() {
    for seed in [1, 2, 3] {
        let (e, x) = suit_energy(seed);
        let ls = e.least_squares(&x, true).expect("least squares");
        let (m, d) = (ls.residuals.len(), ls.dim);
        assert_eq!(m, e.residual_count());
        // Five-point differences, the criterion of the built-in modalities' test.
        let h = 1e-4;
        let mut col_max = vec![0.0f64; d];
        let mut fd = vec![0.0; m * d];
        for c in 0..d {
            let at = |s: f64| {
                let mut y = x.clone();
                y[c] += s * h;
                e.least_squares(&y, false).expect("ls").residuals
            };
            let (p2, p1, m1, m2) = (at(2.0), at(1.0), at(-1.0), at(-2.0));
            for i in 0..m {
                fd[i * d + c] = (-p2[i] + 8.0 * p1[i] - 8.0 * m1[i] + m2[i]) / (12.0 * h);
                col_max[c] = col_max[c].max(ls.jacobian[i * d + c].abs());
            }
        }
        for i in 0..m {
            for c in 0..d {
                let (a, b) = (ls.jacobian[i * d + c], fd[i * d + c]);
                let scale = a.abs().max(1e-3 * col_max[c]).max(1e-12);
                assert!(
                    (a - b).abs() <= 1e-5 * scale + 1e-8,
                    "seed {seed}: J[{i}][{c}] = {a}, differences {b}"
                );
            }
        }
        // The energy's gradient goes through the trait's default reverse mode (Jᵀ g).
        let (ev, g) = e.evaluate_with_gradient(&x);
        assert!((ev.total - ls.value()).abs() <= 1e-10 * ev.total.max(1.0));
        for (a, b) in g.iter().zip(ls.gradient()) {
            assert!((a - b).abs() <= 1e-9 * (1.0 + b.abs()), "{a} vs {b}");
        }
        assert!(
            g.iter().any(|v| v.abs() > 1e-6),
            "a gradient that is not zero"
        );
    }
}

#[test]
fn a_custom_sensor_synthesises_fits_with_lm_and_trains_but_is_not_written_to_disk() {
    let tmp = tempfile::tempdir().expect("tmp");
    let t = Arc::new(default_template());
    let r = imu_sensor::run(t.clone(), 24, 40, &tmp.path().join("run")).expect("example");
    eprintln!("{r:?}");
    assert!(
        r.lm_v2v_mm < 0.5 * r.start_v2v_mm,
        "LM must at least halve the start error: {:.1} -> {:.1} mm",
        r.start_v2v_mm,
        r.lm_v2v_mm
    );
    let first = *r.training.first_validation.v2v_mm.last().expect("v2v");
    let last = *r.training.final_validation.v2v_mm.last().expect("v2v");
    assert!(
        last < first,
        "training must lower validation V2V: {first:.1} -> {last:.1} mm"
    );
    let ck =
        lfit::nn::checkpoint::load(&tmp.path().join("run"), &lfit::nn::tensor::ndarray_device())
            .expect("checkpoint");
    assert_eq!(ck.meta.network.modality, Modality::Custom);

    // Its datasets live in memory only: writing one is a one-line error naming the model.
    let sensor = Sensor::Custom(Arc::new(imu_sensor::ImuSuit::new(&t).expect("suit")));
    let data = synthesize(
        &SynthConfig::new(Modality::Custom, Scenario::Local, 2, 1),
        &t,
        &sensor,
        &|_| {},
    )
    .expect("synth");
    let path = tmp.path().join("imu.npz");
    let err = data
        .save(&path)
        .expect_err("custom datasets are not written")
        .to_string();
    assert!(err.contains("imu-suit") && !err.contains('\n'), "{err}");
    assert!(!path.exists(), "nothing half-written");
    // And a custom modality has no default setup.
    let none = Sensor::default_for(Modality::Custom, &t);
    assert!(
        none.validate(&t)
            .unwrap_err()
            .to_string()
            .contains("no default setup")
    );
}
