//! The learned fitter's start choice (`--neural-start best`), `neural+lm` (the network, then LM
//! within one budget) and the sequence shape policy (`--sequence-shape first-pass`), end to end
//! with the shipped MakeHuman markers fitter.

mod support;

use std::path::{Path, PathBuf};

use serde_json::Value;
use support::{assert_one_line_error, lfit, lfit_json, path_str, synth_to};

const MODEL: &str = "models/makehuman-cmu_mb.npz";
const CHECKPOINT: &str = "checkpoints/markers-makehuman";

fn root(p: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join(p)
}

fn synth(dir: &Path, name: &str, scenario: &str, frames: usize, seed: u64) -> PathBuf {
    synth_with(dir, name, scenario, frames, seed, &[])
}

/// [`synth`] with more `lfit synth` arguments.
fn synth_with(
    dir: &Path,
    name: &str,
    scenario: &str,
    frames: usize,
    seed: u64,
    extra: &[&str],
) -> PathBuf {
    synth_modality(dir, name, "markers", scenario, frames, seed, extra)
}

/// [`synth_with`] of another modality.
fn synth_modality(
    dir: &Path,
    name: &str,
    modality: &str,
    scenario: &str,
    frames: usize,
    seed: u64,
    extra: &[&str],
) -> PathBuf {
    let data = dir.join(name);
    let (frames, seed) = (frames.to_string(), seed.to_string());
    let mut args = vec![
        "--modality",
        modality,
        "--scenario",
        scenario,
        "--frames",
        &frames,
        "--seed",
        &seed,
    ];
    args.extend(extra);
    synth_to(&data, &root(MODEL), &args);
    data
}

fn fit(data: &Path, out: &Path, extra: &[&str]) -> Value {
    let (model, ck) = (root(MODEL), root(CHECKPOINT));
    let mut args = vec![
        "-q",
        "fit",
        "--data",
        path_str(data),
        "--template",
        path_str(&model),
        "--checkpoint",
        path_str(&ck),
        "--out",
        path_str(out),
    ];
    args.extend(extra);
    lfit_json(&args);
    serde_json::from_slice(&std::fs::read(out).expect("result")).expect("json")
}

/// `lfit -q fit --data DATA --template MODEL --method lm --budget 50 --out OUT EXTRA...` (the
/// refusals' command line).
fn lm50(data: &Path, out: &Path, extra: &[&str]) -> std::process::Output {
    let model = root(MODEL);
    let mut args = vec![
        "-q",
        "fit",
        "--data",
        path_str(data),
        "--template",
        path_str(&model),
        "--method",
        "lm",
        "--budget",
        "50",
        "--out",
        path_str(out),
    ];
    args.extend(extra);
    lfit(&args)
}

/// [`lm50`] of a sequence with `joint`'s β pass, `--marker-placement placement` and `extra`,
/// written to `out`: the result, after asserting the fit succeeded.
fn lm50_placed(data: &Path, out: &Path, placement: &str, extra: &[&str]) -> Value {
    let mut args = vec!["--sequence-shape", "joint", "--marker-placement", placement];
    args.extend(extra);
    let o = lm50(data, out, &args);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    serde_json::from_slice(&std::fs::read(out).expect("result")).expect("json")
}

fn frames(r: &Value) -> &Vec<Value> {
    r["frames"].as_array().expect("frames")
}

fn num(v: &Value) -> f64 {
    v.as_f64().expect("number")
}

/// Indices of the thumbs' rotation entries in the MakeHuman body's parameter vector (`lfit model
/// info`'s names): no marker lies on a thumb.
fn thumb_entries() -> Vec<usize> {
    let info = lfit_json(&["model", "info", "--model", path_str(&root(MODEL))]);
    let names = info["parameters"]["names"].as_array().expect("names");
    let thumbs: Vec<usize> = names
        .iter()
        .enumerate()
        .filter(|(_, n)| n.as_str().is_some_and(|n| n.contains("Thumb.")))
        .map(|(i, _)| i)
        .collect();
    assert_eq!(thumbs.len(), 6);
    thumbs
}

/// `best` starts from the lower-energy of the given start and Φ(D), and counts the two
/// evaluations the choice costs.
#[test]
fn best_start_takes_the_lower_energy_candidate() {
    let tmp = tempfile::tempdir().expect("tmp");
    let data = synth(tmp.path(), "local.npz", "local", 8, 0x5EED_0001);
    let run = |start: &str| {
        fit(
            &data,
            &tmp.path().join(format!("{start}.json")),
            &[
                "--method",
                "neural",
                "--budget",
                "12",
                "--neural-start",
                start,
            ],
        )
    };
    let (phi, given, best) = (run("phi"), run("given"), run("best"));
    assert_eq!(best["method"], "neural-best");
    let (mut chose_phi, mut chose_given) = (0, 0);
    for ((p, g), b) in frames(&phi).iter().zip(frames(&given)).zip(frames(&best)) {
        let e0 = |f: &Value| num(&f["trace"][0][1]);
        let (ep, eg, eb) = (e0(p), e0(g), e0(b));
        let want = ep.min(eg);
        assert!(
            (eb - want).abs() <= 1e-6 * want.abs().max(1.0),
            "θ0 energy {eb} is not the lower of Φ(D) {ep} and the start {eg}"
        );
        if ep < eg {
            chose_phi += 1;
        } else {
            chose_given += 1;
        }
        assert_eq!(b["evaluations"], num(&g["evaluations"]) as u64 + 2);
        assert_eq!(b["iterations"], g["iterations"]);
    }
    eprintln!("best start: Φ(D) on {chose_phi} frames, the given start on {chose_given}");
    // A budget that covers the iterations but not the choice is refused.
    refused(
        &data,
        tmp.path(),
        "neural",
        &["--neural-start", "best", "--budget", "10"],
        "and the start choice",
    );
}

/// A fit of `data` by the shipped markers fitter's `method` (`neural`, `neural+lm`) with `extra`
/// flags fails with one line containing `reason` and writes nothing.
fn refused(data: &Path, dir: &Path, method: &str, extra: &[&str], reason: &str) {
    let no = dir.join("no.json");
    let (model, ck) = (root(MODEL), root(CHECKPOINT));
    let mut args = vec![
        "-q",
        "fit",
        "--data",
        path_str(data),
        "--template",
        path_str(&model),
        "--checkpoint",
        path_str(&ck),
        "--method",
        method,
        "--out",
        path_str(&no),
    ];
    args.extend(extra);
    assert_one_line_error(&lfit(&args), reason);
    assert!(!no.exists());
}

/// `both` fits from the given start and from Φ(D) and keeps the lower-energy result: on single
/// frames (and a sequence's first) it is exactly the better of the `given` and `phi` fits, at
/// their evaluations plus the two results' energies.
#[test]
fn both_starts_keep_the_lower_energy_fit() {
    let tmp = tempfile::tempdir().expect("tmp");
    let data = synth(tmp.path(), "local.npz", "local", 6, 0x5EED_0011);
    let run = |data: &Path, start: &str, budget: &str| {
        fit(
            data,
            &tmp.path().join(format!("{start}-{budget}.json")),
            &[
                "--method",
                "neural",
                "--budget",
                budget,
                "--neural-start",
                start,
            ],
        )
    };
    let (phi, given, both) = (
        run(&data, "phi", "10"),
        run(&data, "given", "10"),
        run(&data, "both", "22"),
    );
    assert_eq!(both["method"], "neural-both");
    let (mut chose_phi, mut chose_given) = (0, 0);
    for ((p, g), b) in frames(&phi).iter().zip(frames(&given)).zip(frames(&both)) {
        let (ep, eg, eb) = (num(&p["energy"]), num(&g["energy"]), num(&b["energy"]));
        let (want, from) = if ep < eg { (ep, p) } else { (eg, g) };
        assert!(
            (eb - want).abs() <= 1e-9 * want.abs().max(1.0),
            "energy {eb} is not the lower of the fits from Φ(D) {ep} and from the start {eg}"
        );
        assert_eq!(b["pose"], from["pose"]);
        if ep < eg {
            chose_phi += 1;
        } else {
            chose_given += 1;
        }
        assert_eq!(b["evaluations"], 2 * (num(&g["evaluations"]) as u64 + 1));
        // Both fits' iterates in the trace, on an evaluation axis ending at the budget used.
        let trace = b["trace"].as_array().expect("trace");
        assert_eq!(trace.len(), 2 * g["trace"].as_array().expect("trace").len());
        assert_eq!(trace.last().expect("last")[0], b["evaluations"]);
    }
    eprintln!("both: the fit from Φ(D) on {chose_phi} frames, from the start on {chose_given}");

    // In a sequence each frame's box is the scenario's around the previous result, so the fits
    // depend on the chain after the first frame; the first frame starts alike in every run.
    let seq = synth(tmp.path(), "seq.npz", "sequence", 6, 0x5EED_0012);
    let (phi, given, both) = (
        run(&seq, "phi", "10"),
        run(&seq, "given", "10"),
        run(&seq, "both", "22"),
    );
    let first = |r: &Value| num(&frames(r)[0]["energy"]);
    let want = first(&phi).min(first(&given));
    assert!((first(&both) - want).abs() <= 1e-9 * want.abs().max(1.0));
    assert!(frames(&both).iter().all(|f| f["evaluations"] == 22));
    // A budget that covers one fit and a half is refused, nothing written.
    refused(
        &data,
        tmp.path(),
        "neural",
        &["--neural-start", "both", "--budget", "21"],
        "twice, and the choice between the two fits",
    );
}

/// `--neural-pick lowest` returns the iterate of lowest energy among θ0 … θN (the last one's
/// energy counted: one more evaluation), never above the last iterate's; `last` is the default
/// and unknown picks or a budget without room for the choice are refused with nothing written.
#[test]
fn lowest_pick_returns_the_lowest_energy_iterate() {
    let tmp = tempfile::tempdir().expect("tmp");
    let data = synth(tmp.path(), "local.npz", "local", 12, 0x5EED_0005);
    let run = |pick: &str, budget: &str| {
        fit(
            &data,
            &tmp.path().join(format!("{pick}.json")),
            &[
                "--method",
                "neural",
                "--budget",
                budget,
                "--neural-start",
                "given",
                "--neural-pick",
                pick,
            ],
        )
    };
    let (last, lowest) = (run("last", "10"), run("lowest", "11"));
    assert_eq!(lowest["method"], "neural-given-lowest");
    assert_eq!(lowest["neural_pick"], "lowest");
    assert!(
        last.get("neural_pick").is_none(),
        "the default leaves no key"
    );
    let mut moved = 0;
    for (a, b) in frames(&last).iter().zip(frames(&lowest)) {
        // The same network run: the same iterates and trace.
        assert_eq!(
            a["trace"].as_array().unwrap().len(),
            b["trace"].as_array().unwrap().len()
        );
        let energies: Vec<f64> = b["trace"]
            .as_array()
            .unwrap()
            .iter()
            .map(|p| num(&p[1]))
            .collect();
        let min = energies.iter().copied().fold(f64::INFINITY, f64::min);
        let (ea, eb) = (num(&a["energy"]), num(&b["energy"]));
        assert!(
            (eb - min).abs() <= 1e-9 * min.abs().max(1.0),
            "{eb} is not the lowest {min}"
        );
        assert!(eb <= ea);
        assert!((ea - energies[energies.len() - 1]).abs() <= 1e-9 * ea.abs().max(1.0));
        assert_eq!(b["evaluations"], num(&a["evaluations"]) as u64 + 1);
        moved += usize::from(eb < ea);
    }
    eprintln!("lowest pick: an earlier iterate on {moved} of 12 frames");
    assert!(
        moved > 0,
        "no frame where an earlier iterate is lower: the check saw nothing"
    );
    for (extra, want) in [
        (
            ["--neural-pick", "best", "--budget", "11"],
            "unknown neural pick 'best'",
        ),
        (
            ["--neural-pick", "lowest", "--budget", "10"],
            "and the iterate choice",
        ),
    ] {
        let mut args = vec!["--neural-start", "given"];
        args.extend(extra);
        refused(&data, tmp.path(), "neural", &args, want);
    }
}

/// `--neural-iterations K` stops the network after its first K iterations: each frame's
/// iterates are the full fit's first K + 1 (Burn and the native forward alike), at 2K
/// evaluations, the method's name and the result saying so; `neural+lm` then runs LM from θK
/// within the budget; K outside 1..=N, a budget short of 2K, and the flag on a classical method
/// are refused with one line and nothing written. `--neural-tolerance` stops each frame on its
/// energy, and refuses what it cannot serve.
#[test]
fn an_early_exit_runs_the_first_iterations_of_the_full_fit() {
    let tmp = tempfile::tempdir().expect("tmp");
    let data = synth(tmp.path(), "local.npz", "local", 8, 0x5EED_0012);
    for runtime in ["burn", "native"] {
        let run = |name: &str, extra: &[&str]| {
            let mut args = vec!["--neural-start", "given", "--runtime", runtime];
            args.extend(extra);
            fit(
                &data,
                &tmp.path().join(format!("{runtime}-{name}.json")),
                &args,
            )
        };
        let full = run("full", &["--method", "neural", "--budget", "10"]);
        let early = run(
            "early",
            &[
                "--method",
                "neural",
                "--budget",
                "4",
                "--neural-iterations",
                "2",
            ],
        );
        let suffix = if runtime == "native" { "-native" } else { "" };
        assert_eq!(early["method"], format!("neural-given-n2{suffix}"));
        assert_eq!(full["method"], format!("neural-given{suffix}"));
        assert_eq!(early["neural_iterations"], 2);
        assert!(full.get("neural_iterations").is_none(), "no key by default");
        for (a, b) in frames(&full).iter().zip(frames(&early)) {
            assert_eq!(
                (a["iterations"].clone(), b["iterations"].clone()),
                (5.into(), 2.into())
            );
            assert_eq!(
                (a["evaluations"].clone(), b["evaluations"].clone()),
                (10.into(), 4.into())
            );
            let per = |r: &Value| -> Vec<f64> {
                r["v2v_mm_per_iteration"]
                    .as_array()
                    .expect("per iteration")
                    .iter()
                    .map(num)
                    .collect()
            };
            let (pa, pb) = (per(a), per(b));
            assert_eq!(pa.len(), 6);
            assert_eq!(
                pb,
                pa[..3].to_vec(),
                "{runtime}: θ0 … θ2 are the full fit's"
            );
            assert_eq!(num(&b["v2v_mm"]), pa[2]);
        }
        let mean = |r: &Value| num(&r["summary"]["mean_v2v_mm"]);
        assert!(
            mean(&full) < mean(&early),
            "{runtime}: the later iterations still refine"
        );
        let refined = run(
            "nlm",
            &[
                "--method",
                "neural+lm",
                "--budget",
                "60",
                "--neural-iterations",
                "2",
            ],
        );
        assert_eq!(
            refined["method"],
            format!("neural-given-n2{suffix}+lm-anchored-5deg")
        );
        for (a, b) in frames(&early).iter().zip(frames(&refined)) {
            assert!(num(&b["energy"]) <= num(&a["energy"]));
            let evaluations = num(&b["evaluations"]);
            assert!(evaluations > 4.0 && evaluations <= 60.0, "{evaluations}");
        }
    }
    for (extra, want) in [
        (
            ["--neural-iterations", "0", "--budget", "10"],
            "0 iterations asked of a network trained for 5: choose 1 to 5",
        ),
        (
            ["--neural-iterations", "6", "--budget", "20"],
            "6 iterations asked of a network trained for 5: choose 1 to 5",
        ),
        (
            ["--neural-iterations", "2", "--budget", "3"],
            "budget 3 is below the 4 evaluations of 2 iterations",
        ),
    ] {
        let mut args = vec!["--neural-start", "given"];
        args.extend(extra);
        refused(&data, tmp.path(), "neural", &args, want);
    }
    // The energy rule: each frame stops at the first θk (k ≥ 2) whose step lowered the energy
    // by less than the tolerance of it, at 2k + 1 evaluations (10 when it runs all 5) and k
    // Gauss-Newton directions: where the rule can stop, θk's energy comes from its residuals
    // alone and the Jacobian, normal equations and solve only if the loop goes on.
    let tol = fit(
        &data,
        &tmp.path().join("tol.json"),
        &[
            "--method",
            "neural",
            "--budget",
            "10",
            "--neural-start",
            "given",
            "--neural-tolerance",
            "0.2",
        ],
    );
    assert_eq!(tol["method"], "neural-given-tol0.2");
    assert_eq!(tol["neural_tolerance"], 0.2);
    let mut stopped = 0;
    for f in frames(&tol) {
        let k = num(&f["iterations"]) as u64;
        assert!((2..=5).contains(&k), "{k}");
        let want = if k < 5 { 2 * k + 1 } else { 10 };
        assert_eq!(f["evaluations"], want);
        assert_eq!(f["gradient_evaluations"], k);
        stopped += usize::from(k < 5);
    }
    assert!(stopped > 0, "no frame stopped early");
    for (extra, want) in [
        (
            vec!["--neural-tolerance", "0", "--budget", "10"],
            "neural tolerance 0: a relative energy decrease between 0 and 1 (exclusive)",
        ),
        (
            vec![
                "--neural-tolerance",
                "0.1",
                "--budget",
                "11",
                "--neural-pick",
                "lowest",
            ],
            "not with --neural-start both or --neural-pick lowest",
        ),
    ] {
        let mut args = vec!["--neural-start", "given"];
        args.extend(extra);
        refused(&data, tmp.path(), "neural", &args, want);
    }
    for flag in ["--neural-iterations", "--neural-tolerance"] {
        let no = tmp.path().join("lm.json");
        let value = if flag == "--neural-tolerance" {
            "0.1"
        } else {
            "2"
        };
        assert_one_line_error(
            &lm50(&data, &no, &[flag, value]),
            "--neural-iterations and --neural-tolerance are only for --method neural or neural+lm",
        );
        assert!(!no.exists());
    }
}

/// `neural+lm` spends the network's evaluations, then LM's from the network's result: its
/// energy is never above the network's alone, its evaluations add up and stay within the budget,
/// and its iterates are the network's followed by the final pose. By default (`--dofs
/// anchored:5` on markers from the given start, `anchored` from Φ(D)) LM moves every entry with the rotations pulled toward the network's
/// values: less far from them than with `--dofs all`, the energy reported without the pull.
/// With `--dofs observed` LM keeps the network's β and the rotations the markers do not
/// determine (the thumbs) and spends one evaluation on the data's information; with `--dofs
/// all` it moves every entry, the thumbs included, and ends further from the truth.
#[test]
fn neural_then_lm_refines_the_network_within_one_budget() {
    let tmp = tempfile::tempdir().expect("tmp");
    let data = synth(tmp.path(), "local.npz", "local", 6, 0x5EED_0002);
    let common = ["--neural-start", "given", "--budget", "300"];
    let nn = fit(
        &data,
        &tmp.path().join("nn.json"),
        &[&["--method", "neural"][..], &common[..]].concat(),
    );
    let anchored = fit(
        &data,
        &tmp.path().join("anchored.json"),
        &[&["--method", "neural+lm"][..], &common[..]].concat(),
    );
    let both = fit(
        &data,
        &tmp.path().join("both.json"),
        &[
            &["--method", "neural+lm", "--dofs", "observed"][..],
            &common[..],
        ]
        .concat(),
    );
    let all = fit(
        &data,
        &tmp.path().join("all.json"),
        &[&["--method", "neural+lm", "--dofs", "all"][..], &common[..]].concat(),
    );
    assert_eq!(anchored["method"], "neural-given+lm-anchored-5deg");
    assert_eq!(anchored["dofs"], "anchored:5");
    // From Φ(D) the network's result is further from the truth: the default pull is looser
    // (round 28's 15°, `anchored`), where from the given start it is 5°.
    let from_phi = fit(
        &data,
        &tmp.path().join("phi.json"),
        &[
            "--method",
            "neural+lm",
            "--neural-start",
            "phi",
            "--budget",
            "300",
        ],
    );
    assert_eq!(from_phi["method"], "neural+lm-anchored");
    assert_eq!(from_phi["dofs"], "anchored");
    assert_eq!(both["method"], "neural-given+lm-observed");
    assert_eq!(both["dofs"], "observed");
    assert_eq!(all["method"], "neural-given+lm");
    assert!(all.get("dofs").is_none());
    // Anchored: every entry moves, less far from the network's values than with `all`; the
    // energy reported is the energy (never above the network's), not the anchored objective.
    let away = |r: &Value| -> f64 {
        frames(r)
            .iter()
            .zip(frames(&nn))
            .map(|(f, n)| {
                (3..f["pose"].as_array().expect("pose").len())
                    .map(|i| (num(&f["pose"][i]) - num(&n["pose"][i])).abs())
                    .sum::<f64>()
            })
            .sum()
    };
    assert!(
        away(&anchored) > 0.0 && away(&anchored) < away(&all),
        "anchored moved {} from the network, all {}",
        away(&anchored),
        away(&all)
    );
    for (a, n) in frames(&anchored).iter().zip(frames(&nn)) {
        assert!(num(&a["energy"]) <= num(&n["energy"]));
        let evals = a["evaluations"].as_u64().expect("evaluations");
        assert!(evals > 10 && evals <= 300, "evaluations {evals}");
    }
    let thumbs = thumb_entries();
    let (mut lower, mut thumbs_moved) = (0, 0);
    for ((a, b), c) in frames(&nn).iter().zip(frames(&both)).zip(frames(&all)) {
        let (ea, eb) = (num(&a["energy"]), num(&b["energy"]));
        assert!(eb <= ea, "neural+lm {eb} above the network alone {ea}");
        assert!(num(&c["energy"]) <= ea);
        if eb < 0.99 * ea {
            lower += 1;
        }
        // Observed: the network's β and thumbs, exactly.
        assert_eq!(b["shape"], a["shape"], "β is the network's");
        for &i in &thumbs {
            assert_eq!(
                b["pose"][i], a["pose"][i],
                "thumb entry {i} is the network's"
            );
            if c["pose"][i] != a["pose"][i] {
                thumbs_moved += 1;
            }
        }
        let evals = b["evaluations"].as_u64().expect("evaluations");
        assert!(evals > 11 && evals <= 300, "evaluations {evals}");
        assert_eq!(
            b["trace"][0][0].as_u64(),
            a["trace"][0][0].as_u64(),
            "the trace starts with the network's"
        );
        let iterates = b["v2v_mm_per_iteration"].as_array().expect("iterates");
        assert_eq!(
            iterates.len(),
            5 + 2,
            "θ0, 5 network iterations, LM's result"
        );
        // The network's part is the network's: same iterates.
        for k in 0..6 {
            assert!(
                (num(&iterates[k]) - num(&a["v2v_mm_per_iteration"][k])).abs() < 1e-9,
                "iterate {k}"
            );
        }
        assert!((num(&iterates[6]) - num(&b["v2v_mm"])).abs() < 1e-9);
    }
    assert!(
        lower >= 4,
        "LM lowered the energy of only {lower} of 6 frames"
    );
    assert!(thumbs_moved > 0, "--dofs all left every thumb where it was");
    let v2v = |r: &Value| num(&r["summary"]["mean_v2v_mm"]);
    assert!(
        v2v(&both) < v2v(&all),
        "observed {} not below all {}",
        v2v(&both),
        v2v(&all)
    );
    // A budget the network alone uses up is refused, and nothing is written; with --dofs
    // observed the data information costs one more, so 11 is refused too.
    for (extra, want) in [
        (&["--budget", "10"][..], "leaves LM nothing"),
        (
            &["--budget", "11", "--dofs", "observed"][..],
            "needs at least 12 (with --dofs observed",
        ),
    ] {
        refused(&data, tmp.path(), "neural+lm", extra, want);
    }
    let out_path = tmp.path().join("no.json");
    let out = lfit(&[
        "-q",
        "fit",
        "--data",
        path_str(&data),
        "--template",
        path_str(&root(MODEL)),
        "--method",
        "neural+lm",
        "--budget",
        "100",
        "--out",
        path_str(&out_path),
    ]);
    assert_one_line_error(&out, "--method neural+lm needs --checkpoint");
    assert!(!out_path.exists());
}

/// The β of a sequence's β pass (`summary.shape_pass.beta`, 16 numbers), asserted to be every
/// frame's β.
fn sequence_beta(r: &Value) -> Vec<f64> {
    let numbers =
        |v: &Value, what: &str| -> Vec<f64> { v.as_array().expect(what).iter().map(num).collect() };
    let beta = numbers(&r["summary"]["shape_pass"]["beta"], "beta");
    assert_eq!(beta.len(), 16);
    for f in frames(r) {
        assert_eq!(
            numbers(&f["shape"], "shape"),
            beta,
            "frame {}: β is not the sequence's",
            f["frame"]
        );
    }
    beta
}

/// `--sequence-shape first-pass`: one β for the whole sequence, the median of the first pass,
/// and one-line refusals where it cannot apply.
#[test]
fn first_pass_gives_a_sequence_one_shape() {
    let tmp = tempfile::tempdir().expect("tmp");
    let seq = synth(tmp.path(), "seq.npz", "sequence", 8, 0x5EED_0003);
    let r = fit(
        &seq,
        &tmp.path().join("seq.json"),
        &[
            "--method",
            "neural",
            "--budget",
            "12",
            "--neural-start",
            "best",
            "--sequence-shape",
            "first-pass",
        ],
    );
    assert_eq!(r["sequence_shape"], "first-pass");
    let pass = &r["summary"]["shape_pass"];
    assert_eq!(pass["frames"].as_array().map(Vec::len), Some(8));
    sequence_beta(&r);
    assert!(pass["evaluations"].as_u64().expect("evaluations") >= 8 * 12);
    // Per frame (the default), β moves from frame to frame.
    let free = fit(
        &seq,
        &tmp.path().join("free.json"),
        &[
            "--method",
            "neural",
            "--budget",
            "12",
            "--neural-start",
            "best",
        ],
    );
    let shapes: Vec<&Value> = frames(&free).iter().map(|f| &f["shape"]).collect();
    assert!(shapes.windows(2).any(|w| w[0] != w[1]));

    // Refusals: not a sequence, an unknown policy, β already given.
    let local = synth(tmp.path(), "local.npz", "local", 2, 0x5EED_0004);
    let out_path = tmp.path().join("no.json");
    let run = |data: &Path, extra: &[&str]| lm50(data, &out_path, extra);
    assert_one_line_error(
        &run(&local, &["--sequence-shape", "first-pass"]),
        "needs a sequence dataset",
    );
    assert_one_line_error(
        &run(&seq, &["--sequence-shape", "median"]),
        "unknown sequence shape policy 'median'",
    );
    assert_one_line_error(
        &run(
            &seq,
            &["--sequence-shape", "first-pass", "--known-shape", "truth"],
        ),
        "needs a sequence dataset",
    );
    assert!(!out_path.exists());
}

/// `--method neural --dofs anchored:DEG`: the network fits each frame on the energy plus the pull
/// toward its start (in a sequence, the previous frame's fit; the networks fine-tuned with
/// `"starts": {"anchor_deg": …}`): a pull too weak to matter gives the plain network's poses,
/// a 4° one other poses, and the reported energy is the plain energy at the pose (the anchor
/// subtracted), as for LM.
#[test]
fn the_network_fits_a_sequence_on_the_anchored_energy() {
    let tmp = tempfile::tempdir().expect("tmp");
    let seq = synth(tmp.path(), "seq.npz", "sequence", 5, 0x5EED_0031);
    let run = |name: &str, dofs: &str| {
        fit(
            &seq,
            &tmp.path().join(name),
            &[
                "--method",
                "neural",
                "--budget",
                "10",
                "--neural-start",
                "given",
                "--dofs",
                dofs,
            ],
        )
    };
    let plain = run("plain.json", "all");
    let weak = run("weak.json", "anchored:1000000,100000000");
    let four = run("four.json", "anchored:4");
    assert_eq!(four["method"], "neural-given-anchored-4deg");
    let poses = |r: &Value| -> Vec<Vec<f64>> {
        frames(r)
            .iter()
            .map(|f| {
                f["pose"]
                    .as_array()
                    .expect("pose")
                    .iter()
                    .map(num)
                    .collect()
            })
            .collect()
    };
    let gap = |a: &Value, b: &Value| {
        poses(a)
            .iter()
            .zip(poses(b))
            .flat_map(|(p, q)| {
                p.iter()
                    .zip(q)
                    .map(|(x, y)| (x - y).abs())
                    .collect::<Vec<_>>()
            })
            .fold(0.0_f64, f64::max)
    };
    assert_eq!(frames(&four).len(), 5);
    assert!(gap(&plain, &weak) < 1e-4, "{}", gap(&plain, &weak));
    assert!(gap(&plain, &four) > 1e-3, "{}", gap(&plain, &four));
    // The energy reported is the plain energy at the anchored fit's pose.
    let model =
        std::sync::Arc::new(lfit::data::load_model(Some(&root(MODEL)), "fixed").expect("model"));
    let dataset = lfit::synth::Dataset::load(&seq).expect("dataset");
    for (k, (f, mut pose)) in frames(&four).iter().zip(poses(&four)).enumerate() {
        // The result's pose is θ without β; the energy reads both.
        pose.extend(f["shape"].as_array().expect("shape").iter().map(num));
        let energy = lfit::fitting::energy_for_frame(
            &dataset,
            model.clone(),
            k,
            lfit::model::energy::EnergyConfig::default().for_gradient(),
        )
        .expect("energy");
        let want = energy.inspect(&pose).total;
        assert!(
            (num(&f["energy"]) - want).abs() <= 1e-9 * want.max(1.0),
            "frame {k}: {} against {want}",
            f["energy"]
        );
    }
}

/// The network's fit of `seq` (12 evaluations a frame, the better start) with the joint β
/// `policy`, asserted to have solved one β for the whole sequence: the summed energy no higher
/// than before the solve, at least one iteration, β inside the shape box and in every frame.
fn joint_pass(seq: &Path, out: &Path, policy: &str) -> Value {
    let r = fit(
        seq,
        out,
        &[
            "--method",
            "neural",
            "--budget",
            "12",
            "--neural-start",
            "best",
            "--sequence-shape",
            policy,
        ],
    );
    assert_eq!(r["sequence_shape"], policy);
    let joint = &r["summary"]["shape_pass"]["joint"];
    let (before, after) = (num(&joint["energy_before"]), num(&joint["energy_after"]));
    assert!(
        after.is_finite() && after <= before,
        "the β solve raised the summed energy: {before} -> {after}"
    );
    assert!(joint["iterations"].as_u64().expect("iterations") >= 1);
    let beta = sequence_beta(&r);
    assert!(beta.iter().all(|b| b.abs() <= 3.0), "inside the shape box");
    r
}

/// `--sequence-shape joint`: the sequence fitted once, one β solved with the poses of all its
/// frames (the sequence's energy no higher than before the solve), then every frame fitted with
/// that β; refused outside sequences, and `joint:0` and `joint:x` refused.
#[test]
fn joint_shape_gives_a_sequence_the_beta_of_its_summed_energy() {
    let tmp = tempfile::tempdir().expect("tmp");
    let seq = synth(tmp.path(), "seq.npz", "sequence", 8, 0x5EED_0005);
    let r = joint_pass(&seq, &tmp.path().join("seq.json"), "joint");
    let pass = &r["summary"]["shape_pass"];
    assert_eq!(
        pass["frames"].as_array().map(Vec::len),
        Some(8),
        "every frame"
    );
    // The first pass (8 frames × 12) and the solve are counted apart from the frames' own.
    assert!(pass["evaluations"].as_u64().expect("evaluations") > 8 * 12);
    // Outside a sequence, and frame counts that are none: one line, nothing written.
    let local = synth(tmp.path(), "local.npz", "local", 2, 0x5EED_0006);
    let out_path = tmp.path().join("no.json");
    for (data, policy, want) in [
        (
            &local,
            "joint",
            "--sequence-shape joint needs a sequence dataset",
        ),
        (&seq, "joint:0", "unknown sequence shape policy 'joint:0'"),
        (&seq, "joint:x", "unknown sequence shape policy 'joint:x'"),
    ] {
        assert_one_line_error(&lm50(data, &out_path, &["--sequence-shape", policy]), want);
    }
    assert!(!out_path.exists());
}

/// `--sequence-shape joint:N`: the sequence fitted once, one β solved over N of its frames
/// spread evenly (the summed energy no higher than before the solve), held in every frame of the
/// second pass (`joint:0` and malformed counts: the joint test above).
#[test]
fn joint_over_n_frames_solves_beta_over_spread_frames() {
    let tmp = tempfile::tempdir().expect("tmp");
    let n = 70;
    let seq = synth(tmp.path(), "seq.npz", "sequence", n, 0x5EED_000A);
    let r = joint_pass(&seq, &tmp.path().join("seq.json"), "joint:64");
    let pass = &r["summary"]["shape_pass"];
    let picked: Vec<u64> = pass["frames"]
        .as_array()
        .expect("frames")
        .iter()
        .map(|f| f.as_u64().expect("frame"))
        .collect();
    // 64 of the 70, the i-th the middle of its share.
    let want: Vec<u64> = (0..64u64).map(|i| (2 * i + 1) * n as u64 / 128).collect();
    assert_eq!(picked, want);
    // The first pass (every frame, 12 each) and the solve, apart from the frames' own.
    let solve = pass["joint"]["evaluations"]
        .as_u64()
        .expect("solve evaluations");
    assert!(solve > 0);
    assert_eq!(
        pass["evaluations"].as_u64().expect("evaluations"),
        n as u64 * 12 + solve
    );
}

/// `--dofs observed` for a classical method: LM from the dataset's start keeps the thumbs (which
/// no marker determines) at the start's values and moves the rest, and counts the one evaluation
/// the data information costs; bad `--dofs` values, and `--dofs observed` for the network with
/// no evaluation left for that information (budget 10, its 5 iterations' 10), are refused with
/// one line and nothing written.
#[test]
fn observed_dofs_keep_what_the_markers_do_not_see() {
    let tmp = tempfile::tempdir().expect("tmp");
    let data = synth(tmp.path(), "local.npz", "local", 4, 0x5EED_0009);
    let model = root(MODEL);
    let lm = |out: &Path, extra: &[&str]| {
        let mut args = vec![
            "-q",
            "fit",
            "--data",
            path_str(&data),
            "--template",
            path_str(&model),
            "--method",
            "lm",
            "--out",
            path_str(out),
        ];
        args.extend(extra);
        lfit(&args)
    };
    // A fit that succeeds, its result.
    let fitted = |name: &str, dofs: &str| -> Value {
        let path = tmp.path().join(name);
        let out = lm(&path, &["--dofs", dofs, "--budget", "200"]);
        assert!(
            out.status.success(),
            "{}",
            String::from_utf8_lossy(&out.stderr)
        );
        serde_json::from_slice(&std::fs::read(&path).expect("result")).expect("json")
    };
    let obs = fitted("obs.json", "observed");
    assert_eq!(obs["method"], "lm-observed");
    assert_eq!(obs["dofs"], "observed");
    let dataset = lfit::synth::Dataset::load(&data).expect("dataset");
    let thumbs = thumb_entries();
    let mut moved = 0;
    for f in frames(&obs) {
        let k = f["frame"].as_u64().expect("frame") as usize;
        let start = &dataset.start_poses[k];
        for &i in &thumbs {
            assert_eq!(
                num(&f["pose"][i]),
                start[i],
                "frame {k}: thumb entry {i} moved"
            );
        }
        // The hips' rotation is seen by every marker: it moved.
        if num(&f["pose"][3]) != start[3] {
            moved += 1;
        }
        assert!(num(&f["energy"]) <= num(&f["start_energy"]));
        let evals = f["evaluations"].as_u64().expect("evaluations");
        assert!((2..=200).contains(&evals), "evaluations {evals}");
    }
    assert!(moved >= 3, "the hips moved in only {moved} of 4 frames");
    // Anchored by name: every entry free, the rotations pulled toward the start.
    let anchored = fitted("anchored.json", "anchored:3");
    assert_eq!(anchored["method"], "lm-anchored-3deg");
    assert_eq!(anchored["dofs"], "anchored:3");
    for f in frames(&anchored) {
        assert!(num(&f["energy"]) <= num(&f["start_energy"]));
        let evals = f["evaluations"].as_u64().expect("evaluations");
        assert!((1..=200).contains(&evals), "evaluations {evals}");
    }
    // The translation's standard deviation by name (millimetres): 0.001 mm holds the root
    // translation at the start, where the default 30 mm lets the data move it.
    let held = fitted("held.json", "anchored:3,0.001");
    assert_eq!(held["method"], "lm-anchored-3deg-0.001mm");
    assert_eq!(held["dofs"], "anchored:3,0.001");
    let shift = |r: &Value| {
        frames(r)
            .iter()
            .map(|f| {
                let k = f["frame"].as_u64().expect("frame") as usize;
                (0..3)
                    .map(|i| (num(&f["pose"][i]) - dataset.start_poses[k][i]).abs())
                    .fold(0.0f64, f64::max)
            })
            .fold(0.0f64, f64::max)
    };
    assert!(
        shift(&held) < 1e-5,
        "held translation moved {} m",
        shift(&held)
    );
    assert!(
        shift(&anchored) > 1e-4,
        "the default translation anchor moved it only {} m",
        shift(&anchored)
    );
    // Another threshold by name: its fitter's name and the result say it.
    let loose = fitted("obs30.json", "observed:30");
    assert_eq!(loose["method"], "lm-observed-30deg");
    assert_eq!(loose["dofs"], "observed:30");
    let thumbs_moved = frames(&loose)
        .iter()
        .filter(|f| {
            let k = f["frame"].as_u64().expect("frame") as usize;
            thumbs
                .iter()
                .any(|&i| num(&f["pose"][i]) != dataset.start_poses[k][i])
        })
        .count();
    assert_eq!(
        thumbs_moved, 0,
        "30° still keeps the thumbs (std in the hundreds of degrees)"
    );
    // A zeroth-order method on its own energy (the binary angle prior, which has no
    // least-squares form; the data rows do): its exact budget holds, the information counted in
    // it, and the thumbs stay.
    let path = tmp.path().join("cma.json");
    let out = lfit(&[
        "-q",
        "fit",
        "--data",
        path_str(&data),
        "--template",
        path_str(&model),
        "--method",
        "cma",
        "--dofs",
        "observed",
        "--budget",
        "60",
        "--out",
        path_str(&path),
    ]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let cma: Value = serde_json::from_slice(&std::fs::read(&path).expect("result")).expect("json");
    for f in frames(&cma) {
        let k = f["frame"].as_u64().expect("frame") as usize;
        assert_eq!(f["evaluations"].as_u64(), Some(60), "frame {k}");
        for &i in &thumbs {
            assert_eq!(
                num(&f["pose"][i]),
                dataset.start_poses[k][i],
                "frame {k}, entry {i}"
            );
        }
    }
    for (extra, want) in [
        (
            &["--dofs", "some", "--budget", "200"][..],
            "unknown dofs 'some' (expected all, observed, observed:DEG, anchored, anchored:DEG, anchored:DEG,MM or observed[:DEG]+anchored[:DEG[,MM]])",
        ),
        (
            &["--dofs", "observed", "--budget", "1"][..],
            "budget of at least 2",
        ),
        (
            &["--dofs", "observed:0", "--budget", "200"][..],
            "positive number of degrees",
        ),
        (
            &["--dofs", "anchored:-2", "--budget", "200"][..],
            "the standard deviation after anchored: must be a positive number of degrees",
        ),
        (
            &["--dofs", "anchored:5,0", "--budget", "200"][..],
            "the translation's standard deviation after anchored:DEG, must be a positive number of millimetres",
        ),
    ] {
        let path = tmp.path().join("no.json");
        let out = lm(&path, extra);
        assert_one_line_error(&out, want);
        assert!(!path.exists());
    }
    refused(
        &data,
        tmp.path(),
        "neural",
        &["--budget", "10", "--dofs", "observed"],
        "budget 9 is below the 10 evaluations of 5 iterations (--dofs observed spent 1 of the budget's 10 on the data's information)",
    );
}

/// `neural+lm`'s default `--dofs` follows the sensor: `anchored` on the sparse body sensors
/// (above), `all` on dense face landmarks, which determine every entry (the face network's β is
/// not the better estimate there); `--dofs observed` still asks for it by name.
#[test]
fn dense_face_landmarks_keep_every_entry_by_default() {
    let tmp = tempfile::tempdir().expect("tmp");
    let (model, data) = (
        root("models/makehuman-face.npz"),
        tmp.path().join("face.npz"),
    );
    let (ck, energy) = (root("checkpoints/face"), root("configs/face-energy.json"));
    lfit_json(&[
        "-q",
        "synth",
        "--modality",
        "landmarks2d",
        "--source",
        "face",
        "--frames",
        "2",
        "--seed",
        "7",
        "--template",
        path_str(&model),
        "--out",
        path_str(&data),
    ]);
    let run = |name: &str, extra: &[&str]| -> Value {
        let out = tmp.path().join(name);
        let mut args = vec![
            "-q",
            "fit",
            "--data",
            path_str(&data),
            "--template",
            path_str(&model),
            "--method",
            "neural+lm",
            "--checkpoint",
            path_str(&ck),
            "--energy",
            path_str(&energy),
            "--budget",
            "40",
            "--out",
            path_str(&out),
        ];
        args.extend(extra);
        lfit_json(&args);
        serde_json::from_slice(&std::fs::read(&out).expect("result")).expect("json")
    };
    let default = run("default.json", &[]);
    assert_eq!(default["method"], "neural+lm");
    assert!(default.get("dofs").is_none());
    let observed = run("observed.json", &["--dofs", "observed"]);
    assert_eq!(observed["method"], "neural+lm-observed");
    assert_eq!(observed["dofs"], "observed");
}

/// `--marker-placement solve`: markers observed 20 mm off the model's marker set (`lfit synth
/// --marker-slip-mm 20`, noise-free), fitted as a sequence with the joint β pass, get each
/// marker's offset solved (written to the summary) and explain the observations better than
/// with the markers on the model's vertices; one-line refusals where it cannot apply.
#[test]
fn solved_marker_placement_explains_slipped_markers() {
    let tmp = tempfile::tempdir().expect("tmp");
    let slip = ["--noise", "0", "--marker-slip-mm", "20"];
    let seq = synth_with(tmp.path(), "slip.npz", "sequence", 24, 2517, &slip);
    let lm =
        |name: &str, placement: &str| lm50_placed(&seq, &tmp.path().join(name), placement, &[]);
    let model = lm("model.json", "model");
    let solved = lm("solved.json", "solve");
    assert_eq!(model["marker_placement"], "model");
    assert_eq!(solved["marker_placement"], "solve");
    assert!(model["summary"]["shape_pass"]["marker_offsets"].is_null());
    let offsets = solved["summary"]["shape_pass"]["marker_offsets"]
        .as_array()
        .expect("offsets");
    assert_eq!(
        offsets.len(),
        39,
        "one offset per marker of the MakeHuman set"
    );
    let squares: Vec<f64> = offsets
        .iter()
        .flat_map(|d| d.as_array().expect("offset").iter().map(num))
        .map(|x| x * x)
        .collect();
    let rms = (squares.iter().sum::<f64>() / offsets.len() as f64).sqrt();
    assert!(
        (0.005..0.06).contains(&rms),
        "offsets of markers slipped 20 mm per axis: RMS {rms} m"
    );
    sequence_beta(&solved);
    let energy = |r: &Value| num(&r["summary"]["mean_energy"]);
    assert!(
        energy(&solved) < 0.3 * energy(&model),
        "solved placement explains the slipped markers: {} vs {}",
        energy(&solved),
        energy(&model)
    );
    // β given (a measured subject): the sequence fitted with it, the poses alone solved beside
    // the offsets; β stays the given one.
    let known = ["--known-shape", "truth"];
    let out = tmp.path().join("known-model.json");
    let o = lm50(&seq, &out, &known);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let known_model: Value =
        serde_json::from_slice(&std::fs::read(&out).expect("result")).expect("json");
    let known_solved = lm50_placed(&seq, &tmp.path().join("known.json"), "solve", &known);
    assert!(known_model["summary"]["shape_pass"].is_null());
    let pass = &known_solved["summary"]["shape_pass"];
    assert_eq!(pass["marker_offsets"].as_array().map(Vec::len), Some(39));
    // Every frame with the given β, which the pass reports.
    sequence_beta(&known_solved);
    assert!(
        energy(&known_solved) < 0.3 * energy(&known_model),
        "with β given the solved placement explains the slipped markers: {} vs {}",
        energy(&known_solved),
        energy(&known_model)
    );
    // The network fits with the markers where the solve put them too (its residual features
    // come from the same observation model), and its sequence explains them better as well.
    let net = |name: &str, placement: &str| -> Value {
        let args = [
            "--method",
            "neural",
            "--budget",
            "24",
            "--neural-start",
            "both",
            "--sequence-shape",
            "joint",
            "--marker-placement",
            placement,
        ];
        fit(&seq, &tmp.path().join(name), &args)
    };
    let (net_model, net_solved) = (
        net("net-model.json", "model"),
        net("net-solved.json", "solve"),
    );
    assert_eq!(
        net_solved["summary"]["shape_pass"]["marker_offsets"]
            .as_array()
            .map(Vec::len),
        Some(39)
    );
    assert!(
        energy(&net_solved) < energy(&net_model),
        "the network with the solved placement: {} vs {}",
        energy(&net_solved),
        energy(&net_model)
    );
    // The same markers as a C3D capture (no ground truth): the distances to the observations
    // are measured with the markers where the fit put them.
    let c3d = tmp.path().join("slip.c3d");
    let imported = tmp.path().join("imported.npz");
    support::export_c3d(&seq, &c3d);
    support::import_c3d_with(&c3d, &imported, &["--model", path_str(&root(MODEL))]);
    let observed = |placement: &str| -> f64 {
        let out = tmp.path().join(format!("imported-{placement}.json"));
        num(&lm50_placed(&imported, &out, placement, &[])["summary"]["mean_observation_error_mm"])
    };
    let (on_model, placed) = (observed("model"), observed("solve"));
    assert!(
        placed < 0.5 * on_model,
        "markers 20 mm off the model's set: {placed} mm from the observations with the placement solved, {on_model} mm without"
    );
    // The placement reused (`--offsets`, e.g. solved on one trial, used on the next of the same
    // subject): the sequence fitted per frame with the solve's offsets explains the markers
    // better than on the model's set; a bare list of the same offsets gives the same fit.
    let per_frame = |name: &str, extra: &[&str]| -> Value {
        let out = tmp.path().join(name);
        let o = lm50(&seq, &out, extra);
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        serde_json::from_slice(&std::fs::read(&out).expect("result")).expect("json")
    };
    let solved_path = tmp.path().join("solved.json");
    let (plain, reused) = (
        per_frame("plain.json", &[]),
        per_frame("reused.json", &["--offsets", path_str(&solved_path)]),
    );
    assert!(
        energy(&reused) < 0.3 * energy(&plain),
        "per frame with the solved offsets: {} vs {}",
        energy(&reused),
        energy(&plain)
    );
    assert_eq!(
        reused["offsets"]["values"],
        solved["summary"]["shape_pass"]["marker_offsets"]
    );
    let list = tmp.path().join("list.json");
    std::fs::write(
        &list,
        solved["summary"]["shape_pass"]["marker_offsets"].to_string(),
    )
    .expect("write");
    let from_list = per_frame("from-list.json", &["--offsets", path_str(&list)]);
    assert_eq!(energy(&from_list), energy(&reused));
    // Refusals: per frame, another modality, an unknown placement, unusable offsets; nothing
    // written.
    let out_path = tmp.path().join("no.json");
    let bad = |name: &str, text: &str| -> PathBuf {
        let p = tmp.path().join(name);
        std::fs::write(&p, text).expect("write");
        p
    };
    for (file, needle) in [
        (tmp.path().join("absent.json"), "--offsets"),
        (bad("text.json", "not json"), "not JSON"),
        (
            bad("empty.json", "{}"),
            "neither a list of [x, y, z] offsets",
        ),
        (
            bad("words.json", r#"[["a", 0, 0]]"#),
            "not a list of [x, y, z] numbers",
        ),
        (bad("short.json", "[[0, 0, 0]]"), "marker offsets"),
        (
            bad(
                "kp.json",
                r#"{"summary": {"shape_pass": {"keypoint_offsets": [[0, 0, 0]]}}}"#,
            ),
            "the file holds keypoint offsets, the data's modality is markers",
        ),
        (
            bad(
                "nan.json",
                &format!("[{}]", vec!["[0, 0, 1e999]"; 39].join(",")),
            ),
            "offsets",
        ),
    ] {
        assert_one_line_error(
            &lm50(&seq, &out_path, &["--offsets", path_str(&file)]),
            needle,
        );
    }
    assert_one_line_error(
        &lm50(&seq, &out_path, &["--marker-placement", "solve"]),
        "--marker-placement solve runs in the β pass of --sequence-shape joint[:N]",
    );
    assert_one_line_error(
        &lm50(&seq, &out_path, &["--marker-placement", "sometimes"]),
        "unknown marker placement 'sometimes'",
    );
    let hmd = synth_modality(tmp.path(), "hmd.npz", "hmd", "sequence", 3, 1, &[]);
    assert_one_line_error(
        &lm50(
            &hmd,
            &out_path,
            &["--sequence-shape", "joint", "--marker-placement", "solve"],
        ),
        "--marker-placement solve places markers or 2D keypoints: the data's modality is hmd",
    );
    assert!(!out_path.exists());
}

/// `--marker-placement solve` on 2D keypoints observed off the joint centres (`lfit synth
/// --keypoint-bias-mm 20`, noise-free, as a detector's keypoints are): each keypoint's offset
/// solved (written to the summary, one per joint) explains the observations better than the
/// joint centres do.
#[test]
fn solved_keypoint_placement_explains_biased_keypoints() {
    let tmp = tempfile::tempdir().expect("tmp");
    let bias = ["--noise", "0", "--keypoint-bias-mm", "20"];
    let seq = synth_modality(
        tmp.path(),
        "kp.npz",
        "keypoints2d",
        "sequence",
        16,
        2518,
        &bias,
    );
    let lm =
        |name: &str, placement: &str| lm50_placed(&seq, &tmp.path().join(name), placement, &[]);
    let (model, solved) = (lm("model.json", "model"), lm("solved.json", "solve"));
    assert!(model["summary"]["shape_pass"]["keypoint_offsets"].is_null());
    assert!(solved["summary"]["shape_pass"]["marker_offsets"].is_null());
    let offsets = solved["summary"]["shape_pass"]["keypoint_offsets"]
        .as_array()
        .expect("offsets");
    assert_eq!(
        offsets.len(),
        31,
        "one offset per joint of the MakeHuman rig"
    );
    let energy = |r: &Value| num(&r["summary"]["mean_energy"]);
    assert!(
        energy(&solved) < 0.3 * energy(&model),
        "solved keypoint offsets explain the biased keypoints: {} vs {}",
        energy(&solved),
        energy(&model)
    );
}

/// `lfit calibrate` (a detector's keypoint offsets solved once at known poses) recovers the
/// synthetic detector's offsets from a calibration recording, and `lfit fit --offsets` with them
/// explains other subjects' keypoints from the same detector better than the joint centres; bad
/// inputs are refused with one line and nothing written.
#[test]
fn a_calibrated_detector_serves_other_subjects() {
    let tmp = tempfile::tempdir().expect("tmp");
    let detector = ["--keypoint-bias-mm", "20", "--keypoint-detector", "5"];
    let with_noise = |noise: &'static str| {
        let mut a = vec!["--noise", noise];
        a.extend(detector);
        a
    };
    let cal = synth_modality(
        tmp.path(),
        "cal.npz",
        "keypoints2d",
        "local",
        12,
        101,
        &with_noise("0"),
    );
    let cal_json = tmp.path().join("cal.json");
    let model = root(MODEL);
    let calibrate = |extra: &[&str], out: &Path| {
        let mut args = vec![
            "-q",
            "calibrate",
            "--model",
            path_str(&model),
            "--out",
            path_str(out),
        ];
        args.extend(extra);
        lfit(&args)
    };
    let o = calibrate(&["--data", path_str(&cal)], &cal_json);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let doc: Value = serde_json::from_slice(&std::fs::read(&cal_json).expect("cal")).expect("json");
    let c = &doc["calibration"];
    assert_eq!(num(&c["frames"]), 12.0);
    assert!(
        num(&c["data_term_after"]) < 1e-3 * num(&c["data_term_before"]),
        "noise-free keypoints at their true poses: {c}"
    );
    // The detector's own offsets, pulled a little towards the joint centres by the prior (30 mm);
    // with a prior 1 m wide, within 0.1 mm.
    let truth = lfit_synth::detector_offsets(5, 0.02, 31);
    let norm = |v: [f64; 3]| (0..3).map(|a| v[a] * v[a]).sum::<f64>().sqrt();
    let offsets = |doc: &Value| -> Vec<[f64; 3]> {
        let solved: Vec<[f64; 3]> =
            serde_json::from_value(doc["keypoint_offsets"].clone()).expect("offsets");
        assert_eq!(solved.len(), truth.len());
        solved
    };
    for (j, (s, t)) in offsets(&doc).iter().zip(&truth).enumerate() {
        let d = norm([s[0] - t[0], s[1] - t[1], s[2] - t[2]]);
        assert!(
            d < 0.05 * norm(*t) && norm(*s) < norm(*t),
            "joint {j}: {s:?} vs {t:?}"
        );
    }
    let wide_json = tmp.path().join("wide.json");
    let o = calibrate(
        &["--data", path_str(&cal), "--prior-mm", "1000"],
        &wide_json,
    );
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let wide: Value =
        serde_json::from_slice(&std::fs::read(&wide_json).expect("wide")).expect("json");
    assert_eq!(num(&wide["calibration"]["prior_mm"]), 1000.0);
    for (j, (s, t)) in offsets(&wide).iter().zip(&truth).enumerate() {
        let d = norm([s[0] - t[0], s[1] - t[1], s[2] - t[2]]);
        assert!(d < 1e-4, "joint {j}, wide prior: {s:?} vs {t:?}");
    }
    // Other subjects and poses, the same detector, default noise: LM per frame with the
    // calibration against the joint centres.
    let eval = synth_modality(
        tmp.path(),
        "eval.npz",
        "keypoints2d",
        "local",
        8,
        202,
        &with_noise("1"),
    );
    let fit = |name: &str, extra: &[&str]| {
        let out = tmp.path().join(name);
        let o = lm50(&eval, &out, extra);
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        let r: Value = serde_json::from_slice(&std::fs::read(&out).expect("fit")).expect("json");
        (
            num(&r["summary"]["mean_energy"]),
            num(&r["summary"]["mean_v2v_mm"]),
        )
    };
    let (bare, calibrated) = (
        fit("bare.json", &[]),
        fit("calibrated.json", &["--offsets", path_str(&cal_json)]),
    );
    assert!(
        calibrated.0 < 0.8 * bare.0 && calibrated.1 < 0.6 * bare.1,
        "(energy, V2V) with the calibration {calibrated:?}, joint centres {bare:?}"
    );
    // Refusals, nothing written.
    let hmd = synth_modality(tmp.path(), "hmd.npz", "hmd", "local", 2, 3, &[]);
    let never = tmp.path().join("never.json");
    for (extra, needle) in [
        (vec!["--data", path_str(&hmd)], "markers or 2D keypoints"),
        (
            vec!["--data", path_str(&cal), "--prior-mm=-1"],
            "--prior-mm",
        ),
        (
            vec!["--data", path_str(&cal), "--prior-mm", "0"],
            "--prior-mm",
        ),
        (
            vec!["--data", path_str(&cal), "--poses", path_str(&never)],
            "cannot read",
        ),
        (vec!["--data", "no-such.npz"], "no-such.npz"),
    ] {
        assert_one_line_error(&calibrate(&extra, &never), needle);
        assert!(!never.exists(), "{extra:?} wrote its output");
    }
    // Poses of frames the recording does not have.
    let late = tmp.path().join("late.json");
    std::fs::write(
        &late,
        serde_json::json!({"frames": [{"frame": 40, "pose": vec![0.0; 96]}]}).to_string(),
    )
    .expect("write");
    assert_one_line_error(
        &calibrate(
            &["--data", path_str(&cal), "--poses", path_str(&late)],
            &never,
        ),
        "out of range",
    );
    assert!(!never.exists());
}
