//! Every optimizer × strategy on the real energy: exact budgets, poses inside the bounds, fixed
//! DOFs untouched, same seed → same result; and a first check that fitting actually fits.

use std::sync::Arc;

use lfit_fitters::{FitRequest, METHOD_NAMES, Preset, Strategy, build_fitter};
use lfit_model::energy::{Energy, EnergyConfig, Target};
use lfit_model::observe::{Modality, Sensor};
use lfit_model::pose::{Bounds, DofMask, POSE_DIM, Pose, rot_offset};
use lfit_model::{Template, default_template};

fn template() -> Arc<Template> {
    static T: std::sync::OnceLock<Arc<Template>> = std::sync::OnceLock::new();
    T.get_or_init(|| Arc::new(default_template())).clone()
}

fn truth() -> Pose {
    let mut p = [0.0; POSE_DIM];
    p[0] = 0.1;
    p[rot_offset(0) + 1] = 0.3;
    p[rot_offset(5)] = 0.4;
    p[rot_offset(16) + 1] = 0.5;
    p
}

fn markers_energy(config: EnergyConfig) -> Energy {
    let t = template();
    let sensor = Sensor::default_for(Modality::Markers, &t);
    let pred = sensor.predict_sparse(&t, &truth());
    Energy::new(
        t,
        sensor,
        Target::Sparse {
            values: pred.values,
            visible: pred.visible,
        },
        config,
    )
    .unwrap()
}

/// A start 0.1 rad / 5 cm away from the truth on every DOF free in `local43` (the others match
/// the truth, so the truth is reachable).
fn start() -> Pose {
    let mut s = truth();
    for i in DofMask::local43().free {
        s[i] += if i < 3 {
            0.05
        } else {
            0.1 * if i % 2 == 0 { 1.0 } else { -1.0 }
        };
    }
    s
}

#[test]
fn every_method_and_strategy_spends_exactly_its_budget_inside_the_bounds() {
    let mask = DofMask::local43();
    // A box that excludes the truth on some DOFs, so methods push against its faces.
    let s = start();
    let mut bounds = Bounds::around(&s, 0.03, 0.05);
    bounds.upper[rot_offset(5)] = s[rot_offset(5)] + 0.01;
    for method in METHOD_NAMES {
        for strategy in Strategy::ALL {
            for budget in [1usize, 13, 200] {
                let config = if lfit_fitters::uses_gradient(method) {
                    EnergyConfig::default().for_gradient()
                } else {
                    EnergyConfig::default()
                };
                let energy = markers_energy(config);
                let fitter = build_fitter(method, Preset::Nevergrad, strategy).unwrap();
                let request = FitRequest {
                    energy: &energy,
                    start: s.to_vec(),
                    mask: mask.clone(),
                    bounds: bounds.clone(),
                    budget,
                    seed: 7,
                    motion: None,
                };
                let r = fitter
                    .fit(&request)
                    .unwrap_or_else(|e| panic!("{method}/{strategy}/{budget}: {e}"));
                let label = format!("{method}/{strategy} budget {budget}");
                if lfit_fitters::uses_gradient(method) {
                    assert!(
                        r.evaluations <= budget as u64 && r.evaluations >= 1,
                        "{label}: {}",
                        r.evaluations
                    );
                    if method == "lbfgs" {
                        assert_eq!(
                            r.gradient_evaluations + 1,
                            r.evaluations.max(1),
                            "{label}: the start is a value-only evaluation"
                        );
                    } else {
                        // Least squares: a Jacobian at each stage's start and at the points it
                        // accepts, none at the trial points it rejects.
                        assert!(
                            r.gradient_evaluations < r.evaluations.max(1),
                            "{label}: {} Jacobians, {} evaluations",
                            r.gradient_evaluations,
                            r.evaluations
                        );
                    }
                } else {
                    assert_eq!(r.evaluations, budget as u64, "{label}");
                    assert_eq!(r.gradient_evaluations, 0, "{label}");
                }
                assert_eq!(
                    energy.evaluations(),
                    r.evaluations,
                    "{label}: every evaluation goes through the counter"
                );
                for i in 0..POSE_DIM {
                    let v = r.pose[i];
                    assert!(
                        v >= bounds.lower[i] && v <= bounds.upper[i],
                        "{label}: entry {i} = {v} outside [{}, {}]",
                        bounds.lower[i],
                        bounds.upper[i]
                    );
                    if !mask.free.contains(&i) {
                        assert_eq!(v, s[i], "{label}: fixed entry {i} moved");
                    }
                }
                // The reported energy is the energy of the reported pose, never worse than the start.
                let mut p = [0.0; POSE_DIM];
                p.copy_from_slice(&r.pose);
                assert_eq!(energy.inspect(&p).total, r.energy, "{label}");
                assert!(r.energy <= energy.inspect(&s).total + 1e-12, "{label}");
                assert!(
                    r.trace
                        .windows(2)
                        .all(|w| w[1].1 <= w[0].1 && w[1].0 > w[0].0),
                    "{label}: trace {:?}",
                    r.trace
                );
            }
        }
    }
}

#[test]
fn same_seed_same_fit_different_seed_different_fit() {
    for method in ["cma", "pso", "de", "apf"] {
        let run = |seed| {
            let energy = markers_energy(EnergyConfig::default());
            let fitter = build_fitter(method, Preset::Nevergrad, Strategy::Holistic).unwrap();
            let request = FitRequest {
                energy: &energy,
                start: start().to_vec(),
                mask: DofMask::local43(),
                bounds: Bounds::local(&start()),
                budget: 300,
                seed,
                motion: None,
            };
            fitter.fit(&request).unwrap()
        };
        let (a, b, c) = (run(1), run(1), run(2));
        assert_eq!(a.pose, b.pose, "{method}");
        assert_eq!(a.trace, b.trace, "{method}");
        assert_ne!(a.pose, c.pose, "{method}");
    }
}

#[test]
fn cma_lbfgs_lm_and_gn_recover_the_truth_from_a_nearby_start() {
    let energy = markers_energy(EnergyConfig::default());
    let fitter = build_fitter("cma", Preset::Nevergrad, Strategy::Holistic).unwrap();
    let request = FitRequest {
        energy: &energy,
        start: start().to_vec(),
        mask: DofMask::local43(),
        bounds: Bounds::local(&start()),
        budget: 4000,
        seed: 3,
        motion: None,
    };
    let r = fitter.fit(&request).unwrap();
    let mut pose = [0.0; POSE_DIM];
    pose.copy_from_slice(&r.pose);
    let v2v = lfit_model::metrics::v2v_mm(&template(), &pose, &truth());
    let v2v0 = lfit_model::metrics::v2v_mm(&template(), &start(), &truth());
    assert!(v2v < 0.25 * v2v0, "cma: V2V {v2v:.1} mm from {v2v0:.1} mm");

    let energy = markers_energy(EnergyConfig::default().for_gradient());
    let fitter = build_fitter("lbfgs", Preset::Nevergrad, Strategy::Holistic).unwrap();
    let request = FitRequest {
        energy: &energy,
        start: start().to_vec(),
        mask: DofMask::local43(),
        bounds: Bounds::local(&start()),
        budget: 300,
        seed: 3,
        motion: None,
    };
    let r = fitter.fit(&request).unwrap();
    pose.copy_from_slice(&r.pose);
    let v2v = lfit_model::metrics::v2v_mm(&template(), &pose, &truth());
    assert!(v2v < 2.0, "lbfgs: V2V {v2v:.2} mm");
    let e0 = energy.inspect(&start()).total;
    assert!(
        r.energy < 1e-3 * e0,
        "lbfgs: energy {} from {e0} after {} evaluations",
        r.energy,
        r.evaluations
    );

    // Gauss-Newton and Levenberg–Marquardt on the least-squares form: to the noise-free truth in
    // a few dozen residual + Jacobian evaluations where L-BFGS needs hundreds.
    for method in ["lm", "lm-triggs", "gn"] {
        let energy = markers_energy(EnergyConfig::default().for_gradient());
        let fitter = build_fitter(method, Preset::Nevergrad, Strategy::Holistic).unwrap();
        let request = FitRequest {
            energy: &energy,
            start: start().to_vec(),
            mask: DofMask::local43(),
            bounds: Bounds::local(&start()),
            budget: 60,
            seed: 3,
            motion: None,
        };
        let r = fitter.fit(&request).unwrap();
        pose.copy_from_slice(&r.pose);
        let v2v = lfit_model::metrics::v2v_mm(&template(), &pose, &truth());
        assert!(
            v2v < 0.1,
            "{method}: V2V {v2v:.3} mm after {} evaluations",
            r.evaluations
        );
        assert!(
            r.energy < 1e-8 * e0,
            "{method}: energy {} from {e0}",
            r.energy
        );
        assert!(
            r.evaluations < 40,
            "{method}: {} evaluations (it stops on its tolerances)",
            r.evaluations
        );
        // Rejected trial points cost no Jacobian.
        assert!(
            r.gradient_evaluations >= 1 && r.gradient_evaluations < r.evaluations,
            "{method}: {} Jacobians, {} evaluations",
            r.gradient_evaluations,
            r.evaluations
        );
    }
}

/// LM's scaling floor (`LeastSquaresOptions::scaling_floor`) is what LM runs with: the same
/// frame with and without it takes a different path and both reach the noise-free truth.
#[test]
fn lm_runs_with_its_scaling_floor() {
    use lfit_fitters::{Fitter, LeastSquaresFitter, LeastSquaresMethod};
    let energy = markers_energy(EnergyConfig::default().for_gradient());
    let request = FitRequest {
        energy: &energy,
        start: start().to_vec(),
        mask: DofMask::local43(),
        bounds: Bounds::local(&start()),
        budget: 60,
        seed: 3,
        motion: None,
    };
    let mut results = Vec::new();
    for floor in [0.0, 3e-3, 0.1] {
        let mut lm = LeastSquaresFitter::new(LeastSquaresMethod::Lm, Strategy::Holistic);
        assert_eq!(lm.options.scaling_floor, 3e-3, "the default floor");
        lm.options.scaling_floor = floor;
        let r = lm.fit(&request).unwrap();
        let mut pose = [0.0; POSE_DIM];
        pose.copy_from_slice(&r.pose);
        let v2v = lfit_model::metrics::v2v_mm(&template(), &pose, &truth());
        assert!(v2v < 0.1, "floor {floor}: V2V {v2v:.3} mm");
        results.push(r);
    }
    assert_ne!(
        results[0].pose, results[1].pose,
        "the floor changes LM's path"
    );
    assert_ne!(
        results[1].pose, results[2].pose,
        "the floor's value changes LM's path"
    );
    // The default LM (`build_fitter("lm")`) is the one with the floor.
    let lm = build_fitter("lm", Preset::Nevergrad, Strategy::Holistic).unwrap();
    assert_eq!(lm.fit(&request).unwrap().pose, results[1].pose);
}

/// The anchored tests' request: 80 evaluations from `s` in its local box, seed 3.
fn anchored_request<'a>(
    energy: &'a Energy,
    s: &[f64],
    mask: &DofMask,
    motion: Option<Vec<f64>>,
) -> FitRequest<'a> {
    FitRequest {
        energy,
        start: s.to_vec(),
        mask: mask.clone(),
        bounds: Bounds::local(s),
        budget: 80,
        seed: 3,
        motion,
    }
}

/// `Dofs::Anchored` (`--dofs anchored`): LM minimises the energy plus a Gaussian pull of the free
/// rotations and root translation toward the start, each with its own standard deviation. Its
/// result reports the energy itself (the anchor subtracted) and its terms without the anchor; the
/// request's energy counts the anchored copy's evaluations within the budget; a tight rotation
/// anchor keeps the rotations at the start where a loose translation anchor lets the translation
/// move, tight on both keeps the translation too, loose on both is LM's fit, and one in between
/// lands between the two. Both with `observed` (`observed+anchored:DEG`): the entries it holds
/// stay at the start, the others are pulled toward it.
#[test]
fn anchored_dofs_pull_toward_the_start_and_report_the_energy() {
    use lfit_fitters::Dofs;
    let s = start();
    let mask = DofMask::local43();
    let fit = |dofs: Dofs| {
        let energy = markers_energy(EnergyConfig::default().for_gradient());
        let lm = build_fitter("lm", Preset::Nevergrad, Strategy::Holistic).unwrap();
        let fitter = dofs.wrap(lm);
        let r = fitter
            .fit(&anchored_request(&energy, &s, &mask, None))
            .unwrap();
        assert_eq!(
            r.method,
            format!(
                "lm{}",
                match dofs {
                    Dofs::All => String::new(),
                    d => format!("-{}", d.suffix()),
                }
            )
        );
        assert!(
            r.evaluations <= 80,
            "{}: {} evaluations",
            r.method,
            r.evaluations
        );
        assert_eq!(energy.evaluations(), r.evaluations, "{}", r.method);
        assert_eq!(
            energy.gradient_evaluations(),
            r.gradient_evaluations,
            "{}",
            r.method
        );
        let at = energy.inspect(&r.pose);
        assert!(
            (r.energy - at.total).abs() <= 1e-9 * at.total.max(1e-12),
            "{}: reported {} against the energy's {}",
            r.method,
            r.energy,
            at.total
        );
        assert!(r.terms.iter().all(|(n, _)| *n != "anchor"), "{:?}", r.terms);
        assert!(r.energy <= energy.inspect(&s).total);
        r
    };
    let rot = |p: &[f64]| -> f64 {
        mask.free
            .iter()
            .filter(|&&i| i >= 3)
            .map(|&i| (p[i] - s[i]).abs())
            .fold(0.0, f64::max)
    };
    let free = fit(Dofs::All);
    let anchored = |std_deg, translation_std_mm| Dofs::Anchored {
        std_deg,
        translation_std_mm: Some(translation_std_mm),
    };
    let tight = fit(anchored(1e-4, 1e9));
    let held = fit(anchored(1e-4, 1e-4));
    let loose = fit(anchored(1e6, 1e9));
    let mid = fit(Dofs::anchored(2.0));
    assert!(
        rot(&free.pose) > 0.05,
        "LM moved the rotations by {}",
        rot(&free.pose)
    );
    assert!(
        rot(&tight.pose) < 1e-3,
        "a tight anchor let them move {}",
        rot(&tight.pose)
    );
    assert!(
        (0..3).any(|i| (tight.pose[i] - s[i]).abs() > 1e-3),
        "a loose translation anchor holds the translation"
    );
    let moved = (0..3).fold(0.0f64, |m, i| m.max((held.pose[i] - s[i]).abs()));
    assert!(moved < 1e-5, "a tight one let it move {moved} m");
    assert!(rot(&held.pose) < 1e-3);
    let gap = free
        .pose
        .iter()
        .zip(&loose.pose)
        .fold(0.0f64, |m, (a, b)| m.max((a - b).abs()));
    assert!(gap < 1e-4, "a loose anchor is LM: {gap}");
    assert!(
        mid.energy > free.energy && mid.energy < tight.energy,
        "{} {} {}",
        free.energy,
        mid.energy,
        tight.energy
    );
    let (r_mid, r_free) = (rot(&mid.pose), rot(&free.pose));
    assert!(r_mid < r_free && r_mid > 1e-3, "{r_mid} against {r_free}");
    // Both (`observed+anchored:2`): what `observed` holds stays at the start, the rest is
    // pulled toward it.
    let observed = fit(Dofs::OBSERVED);
    let both = fit(Dofs::ObservedAnchored {
        max_std_deg: lfit_fitters::OBSERVED_MAX_STD_DEG,
        std_deg: 2.0,
        translation_std_mm: Some(1e9),
    });
    let held: Vec<usize> = mask
        .free
        .iter()
        .copied()
        .filter(|&i| i >= 3 && observed.pose[i] == s[i])
        .collect();
    assert!(!held.is_empty(), "observed holds some rotations");
    assert!(held.iter().all(|&i| both.pose[i] == s[i]), "{held:?}");
    let moved = |p: &[f64]| -> f64 {
        mask.free
            .iter()
            .filter(|&&i| i >= 3)
            .map(|&i| (p[i] - s[i]).powi(2))
            .sum()
    };
    assert!(
        moved(&both.pose) < moved(&observed.pose) && moved(&both.pose) > 0.0,
        "{} against {}",
        moved(&both.pose),
        moved(&observed.pose)
    );
}

/// The sequence's motion (`FitRequest::motion`) widens the temporal anchor per entry by
/// `lfit_fitters::widened_std`: no motion is the plain anchor (bit for bit), a motion far above
/// the anchor's σ stops at the cap (the rotations' anchor at `ANCHOR_MOTION_CAP` times its σ;
/// the translation's is not widened), a moderate one lands between, and a motion of the wrong length or with a NaN is
/// refused naming it. Fitters that are not anchored ignore it.
#[test]
fn the_sequences_motion_widens_the_anchor_up_to_its_cap() {
    use lfit_fitters::{ANCHOR_MOTION_CAP, Dofs, widened_std};
    let s = start();
    let mask = DofMask::local43();
    let energy = markers_energy(EnergyConfig::default().for_gradient());
    let dim = s.len();
    let fit = |dofs: Dofs, motion: Option<Vec<f64>>| {
        let energy = markers_energy(EnergyConfig::default().for_gradient());
        let lm = build_fitter("lm", Preset::Nevergrad, Strategy::Holistic).unwrap();
        dofs.wrap(lm)
            .fit(&anchored_request(&energy, &s, &mask, motion))
    };
    let anchored = |std_deg, translation_std_mm| Dofs::Anchored {
        std_deg,
        translation_std_mm: Some(translation_std_mm),
    };
    let plain = fit(anchored(2.0, 10.0), None).unwrap();
    let still = fit(anchored(2.0, 10.0), Some(vec![0.0; dim])).unwrap();
    assert_eq!(plain.pose, still.pose, "no motion is the plain anchor");
    // Without `,MM` the translation's σ is the start's: an estimate's (no motion: a frame on its
    // own, `neural+lm`'s network result) or the previous frame's fit in a sequence (a motion,
    // zero at the chain's second frame), each what the explicit σ gives.
    let by_start = |motion: Option<Vec<f64>>| fit(Dofs::anchored(2.0), motion).unwrap().pose;
    for (motion, mm) in [
        (None, lfit_fitters::ANCHOR_TRANSLATION_STD_MM),
        (
            Some(vec![0.0; dim]),
            lfit_fitters::SEQUENCE_ANCHOR_TRANSLATION_STD_MM,
        ),
    ] {
        let explicit = fit(anchored(2.0, mm), motion.clone()).unwrap().pose;
        assert_eq!(by_start(motion), explicit, "{mm} mm");
    }
    assert_ne!(
        by_start(None),
        by_start(Some(vec![0.0; dim])),
        "the two defaults pull the translation apart"
    );
    let fast = fit(anchored(2.0, 10.0), Some(vec![10.0; dim])).unwrap();
    let capped = fit(anchored(ANCHOR_MOTION_CAP * 2.0, 10.0), None).unwrap();
    let gap = fast
        .pose
        .iter()
        .zip(&capped.pose)
        .fold(0.0f64, |m, (a, b)| m.max((a - b).abs()));
    assert!(gap < 1e-9, "a fast motion is the capped anchor: {gap}");
    // A moderate motion: the anchor's σ widened by it, as a plain anchor of that σ.
    let m = 0.5f64.to_radians();
    let moderate = fit(anchored(2.0, 10.0), Some(vec![m; dim])).unwrap();
    let sigma = widened_std(2.0f64.to_radians(), m);
    assert!(sigma > 2.0f64.to_radians() && sigma < ANCHOR_MOTION_CAP * 2.0f64.to_radians());
    let moved = |p: &[f64]| -> f64 {
        mask.free
            .iter()
            .filter(|&&i| i >= 3)
            .map(|&i| (p[i] - s[i]).abs())
            .fold(0.0, f64::max)
    };
    let (a, b, c) = (moved(&plain.pose), moved(&moderate.pose), moved(&fast.pose));
    assert!(
        a < b && b < c,
        "the pull loosens with the motion: {a} {b} {c}"
    );
    for bad in [vec![0.0; dim - 1], {
        let mut v = vec![0.0; dim];
        v[5] = f64::NAN;
        v
    }] {
        let e = fit(anchored(2.0, 10.0), Some(bad)).unwrap_err().to_string();
        assert!(e.contains("motion"), "{e}");
    }
    // LM itself ignores the motion.
    let lm = build_fitter("lm", Preset::Nevergrad, Strategy::Holistic).unwrap();
    let with = |motion| {
        lm.fit(&anchored_request(&energy, &s, &mask, motion))
            .unwrap()
            .pose
    };
    assert_eq!(with(None), with(Some(vec![1.0; dim])));
}

/// `SequenceMotion` against its definition: the first change is its own mean square, later
/// ones enter with weight `SEQUENCE_MOTION_WEIGHT`; a non-finite change counts as none; a
/// change of another length restarts it; `reset` forgets it.
#[test]
fn the_sequence_motion_is_an_exponential_average_of_squared_changes() {
    use lfit_fitters::{SEQUENCE_MOTION_WEIGHT as W, SequenceMotion};
    let mut m = SequenceMotion::default();
    assert_eq!(m.rms(), None);
    m.update(&[0.0, 1.0, 2.0], &[0.3, 1.0, f64::NAN]);
    assert_eq!(m.rms(), Some(vec![0.3, 0.0, 0.0]));
    m.update(&[0.3, 1.0, 0.0], &[0.3, 0.6, 0.1]);
    let want = [
        ((1.0 - W) * 0.09f64).sqrt(),
        (W * 0.16f64).sqrt(),
        (W * 0.01f64).sqrt(),
    ];
    let got = m.rms().unwrap();
    for (g, w) in got.iter().zip(want) {
        assert!((g - w).abs() < 1e-12, "{got:?} against {want:?}");
    }
    m.update(&[0.0, 0.0], &[0.5, 0.0]);
    assert_eq!(m.rms(), Some(vec![0.5, 0.0]));
    m.reset();
    assert_eq!(m.rms(), None);
}
