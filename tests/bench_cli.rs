//! `lfit bench`: resume after a kill, shards + merge, reports, bad configs.

mod support;

use std::path::Path;
use std::process::Command;
use std::time::{Duration, Instant};

use support::{assert_one_line_error, lfit, lfit_json, path_str, synth_to};

fn config(dir: &Path, name: &str, body: &str) -> std::path::PathBuf {
    let p = dir.join(name);
    std::fs::write(&p, body).expect("config");
    p
}

const SWEEP: &str = r#"
name = "resume test"
methods = ["one-plus-one", "pso", "lbfgs"]
budgets = [300, 600]
repetitions = 2
parallel = false
[synth]
modality = "markers"
frames = 8
seed = 4
"#;

/// runs.csv without the wall-time column (the only column that may differ between runs).
/// The index of column `name` in the header of a runs.csv.
fn column(path: &Path, name: &str) -> usize {
    let text = std::fs::read_to_string(path).expect("csv");
    let header = text.lines().next().expect("header");
    header
        .split(',')
        .position(|c| c == name)
        .unwrap_or_else(|| panic!("no column {name} in {header}"))
}

fn csv_without_time(path: &Path) -> Vec<String> {
    let time = column(path, "time_s");
    std::fs::read_to_string(path)
        .expect("csv")
        .lines()
        .map(|l| {
            l.split(',')
                .enumerate()
                .filter(|(i, _)| *i != time)
                .map(|(_, f)| f)
                .collect::<Vec<_>>()
                .join(",")
        })
        .collect()
}

fn rows(path: &Path) -> usize {
    std::fs::read_to_string(path)
        .map(|t| t.lines().count().saturating_sub(1))
        .unwrap_or(0)
}

#[test]
fn a_killed_run_resumes_to_the_same_csv_and_shards_merge_to_the_same_report() {
    let tmp = tempfile::tempdir().expect("tmp");
    let d = tmp.path();
    let cfg = config(d, "b.toml", SWEEP);
    let full = d.join("full");
    let summary = lfit_json(&[
        "-q",
        "bench",
        "--config",
        path_str(&cfg),
        "--out",
        path_str(&full),
    ]);
    assert_eq!(summary["runs"], 3 * 2 * 2 * 8);
    assert_eq!(rows(&full.join("runs.csv")), 96);

    // Kill a run once it has written some rows, then restart it.
    let killed = d.join("killed");
    let mut child = Command::new(env!("CARGO_BIN_EXE_lfit"))
        .args([
            "-q",
            "bench",
            "--config",
            path_str(&cfg),
            "--out",
            path_str(&killed),
        ])
        .spawn()
        .expect("spawn");
    let t0 = Instant::now();
    while rows(&killed.join("runs.csv")) < 10 && t0.elapsed() < Duration::from_secs(60) {
        std::thread::sleep(Duration::from_millis(5));
    }
    child.kill().expect("kill");
    let _ = child.wait();
    let partial = rows(&killed.join("runs.csv"));
    assert!(partial >= 10 && partial < 96, "killed after {partial} rows");
    // A torn last line (as a kill during a write leaves) is dropped on resume.
    let mut text = std::fs::read_to_string(killed.join("runs.csv")).expect("csv");
    text.push_str("pso,holistic,300,1,");
    std::fs::write(killed.join("runs.csv"), text).expect("torn");
    lfit_json(&[
        "-q",
        "bench",
        "--config",
        path_str(&cfg),
        "--out",
        path_str(&killed),
    ]);
    assert_eq!(
        csv_without_time(&killed.join("runs.csv")),
        csv_without_time(&full.join("runs.csv"))
    );

    // Three shards and a merge give the same rows and the same statistics.
    let mut shard_dirs = Vec::new();
    for i in 0..3 {
        let s = d.join(format!("shard{i}"));
        lfit_json(&[
            "-q",
            "bench",
            "--config",
            path_str(&cfg),
            "--out",
            path_str(&s),
            "--shard",
            &format!("{i}/3"),
        ]);
        assert!(rows(&s.join("runs.csv")) == 32, "shard {i}");
        shard_dirs.push(s);
    }
    // Two of the three shards: refused with the count of missing runs, nothing written; with
    // --partial merged, and the report says it is partial.
    let two = d.join("two");
    let mut args = vec!["-q", "bench", "merge", "--out", path_str(&two)];
    args.extend(shard_dirs[..2].iter().map(|s| path_str(s)));
    let out = lfit(&args);
    assert_one_line_error(
        &out,
        "32 of the sweep's 96 runs are in none of the 2 shard directories",
    );
    assert!(!two.exists(), "a refused merge wrote {}", two.display());
    args.push("--partial");
    let partial = lfit_json(&args);
    assert_eq!(partial["missing"], 32, "{partial}");
    assert_eq!(rows(&two.join("runs.csv")), 64);
    let md = std::fs::read_to_string(two.join("report.md")).expect("partial report");
    assert!(
        md.starts_with("> **Partial merge**: 32 of the sweep's 96 runs are missing"),
        "{}",
        &md[..200.min(md.len())]
    );

    let merged = d.join("merged");
    let mut args = vec!["-q", "bench", "merge", "--out", path_str(&merged)];
    args.extend(shard_dirs.iter().map(|s| path_str(s)));
    lfit_json(&args);
    assert_eq!(
        csv_without_time(&merged.join("runs.csv")),
        csv_without_time(&full.join("runs.csv"))
    );
    let a: serde_json::Value =
        serde_json::from_slice(&std::fs::read(full.join("summary.json")).expect("a"))
            .expect("json");
    let b: serde_json::Value =
        serde_json::from_slice(&std::fs::read(merged.join("summary.json")).expect("b"))
            .expect("json");
    assert_eq!(a["wilcoxon"], b["wilcoxon"]);
    assert_eq!(a["friedman"], b["friedman"]);
    // The summary has every pairwise test per budget, and the report the papers' tables.
    assert_eq!(a["wilcoxon"].as_array().map(Vec::len), Some(3 * 2));
    assert_eq!(a["friedman"].as_array().map(Vec::len), Some(2));
    let md = std::fs::read_to_string(full.join("report.md")).expect("report");
    for needle in [
        "papers/000 Table 2",
        "papers/000 Table 3",
        "papers/000 Table 4",
        "papers/001 Table 4",
        "papers/002 Table 2",
        "| pso |",
    ] {
        assert!(md.contains(needle), "report lacks {needle}");
    }

    // Another config in the same directory is refused; a shard of another sweep is not merged.
    let other = config(
        d,
        "other.toml",
        &SWEEP.replace("budgets = [300, 600]", "budgets = [300]"),
    );
    let out = lfit(&[
        "-q",
        "bench",
        "--config",
        path_str(&other),
        "--out",
        path_str(&full),
    ]);
    assert_one_line_error(&out, "different benchmark");
    let o2 = d.join("o2");
    lfit_json(&[
        "-q",
        "bench",
        "--config",
        path_str(&other),
        "--out",
        path_str(&o2),
        "--shard",
        "0/50",
    ]);
    let out = lfit(&[
        "-q",
        "bench",
        "merge",
        "--out",
        path_str(&d.join("m2")),
        path_str(&shard_dirs[0]),
        path_str(&o2),
    ]);
    assert_one_line_error(&out, "another benchmark");
}

#[test]
fn bad_bench_configs_fail_before_any_work() {
    let tmp = tempfile::tempdir().expect("tmp");
    let d = tmp.path();
    let base = "name = \"x\"\nbudgets = [100]\n[synth]\nmodality = \"markers\"\nframes = 2\n";
    for (body, needle) in [
        (
            format!("methods = [\"cmaes\"]\n{base}"),
            "unknown method 'cmaes'",
        ),
        (
            format!("methods = [\"cma\"]\n{}", base.replace("[100]", "[100, 0]")),
            "budgets",
        ),
        (
            "methods = [\"cma\"]\nname = \"x\"\nbudgets = [10]\ndata = \"/nonexistent.npz\"\n"
                .to_string(),
            "does not exist",
        ),
        (
            format!("methods = [\"neural\"]\n{base}"),
            "needs checkpoint",
        ),
        (
            format!("methods = [\"cma\"]\nstrategies = [\"sideways\"]\n{base}"),
            "sideways",
        ),
        (format!("methods = [\"cma\"]\nbogus = 1\n{base}"), "bogus"),
        (
            format!("methods = [\"lm\"]\ndofs = \"some\"\n{base}"),
            "unknown dofs 'some'",
        ),
        (
            format!("methods = [\"lm\"]\nneural_iterations = 3\n{base}"),
            "neural_iterations and neural_tolerance are for the neural methods",
        ),
        (
            format!("methods = [\"lm\"]\nneural_tolerance = 1.5\n{base}"),
            "neural_iterations and neural_tolerance are for the neural methods",
        ),
        (
            format!(
                "methods = [\"neural\"]\ncheckpoint = \"{}/checkpoints/markers\"\nneural_tolerance = 1.5\n{base}",
                env!("CARGO_MANIFEST_DIR")
            ),
            "neural_tolerance 1.5: a relative energy decrease between 0 and 1",
        ),
        (
            format!(
                "methods = [\"neural\"]\ncheckpoint = \"{}/checkpoints/markers\"\nneural_iterations = 0\n{base}",
                env!("CARGO_MANIFEST_DIR")
            ),
            "neural_iterations must be at least 1",
        ),
        ("methods = [".to_string(), "malformed bench config"),
    ] {
        let c = config(d, "c.toml", &body);
        let out_dir = d.join("out");
        let out = lfit(&[
            "-q",
            "bench",
            "--config",
            path_str(&c),
            "--out",
            path_str(&out_dir),
        ]);
        assert_one_line_error(&out, needle);
        assert!(
            !out_dir.exists(),
            "{needle}: nothing may be written before the config is valid"
        );
    }
    let out = lfit(&[
        "-q",
        "bench",
        "--config",
        path_str(&d.join("missing.toml")),
        "--out",
        path_str(&d.join("o")),
    ]);
    assert_one_line_error(&out, "cannot read");
    let c = config(d, "ok.toml", &format!("methods = [\"cma\"]\n{base}"));
    let out = lfit(&[
        "-q",
        "bench",
        "--config",
        path_str(&c),
        "--out",
        path_str(&d.join("o")),
        "--shard",
        "3/3",
    ]);
    assert_one_line_error(&out, "--shard");
}

/// `frame,energy` of every row of `method` in a runs.csv.
fn energies(path: &Path, method: &str) -> Vec<(usize, String)> {
    std::fs::read_to_string(path)
        .expect("csv")
        .lines()
        .skip(1)
        .map(|l| l.split(',').collect::<Vec<_>>())
        .filter(|f| f[0] == method)
        .map(|f| (f[4].parse().expect("frame"), f[6].to_string()))
        .collect()
}

/// The bench rows of `method` in `runs` (`count` of them) have, frame by frame, the energies of
/// the `lfit fit` result `fit` to the last digit.
fn same_energies(runs: &Path, method: &str, fit: &Path, count: usize) {
    let fitted: serde_json::Value =
        serde_json::from_slice(&std::fs::read(fit).expect("fit")).expect("json");
    let bench = energies(runs, method);
    assert_eq!(bench.len(), count);
    for (frame, e) in &bench {
        let want = fitted["frames"][*frame]["energy"].as_f64().expect("energy");
        assert_eq!(e.parse::<f64>().expect("e"), want, "frame {frame}");
    }
}

#[test]
fn sequences_run_as_warm_started_chains_like_lfit_fit_and_resume_mid_chain() {
    let tmp = tempfile::tempdir().expect("tmp");
    let d = tmp.path();
    let data = d.join("seq.npz");
    lfit_json(&[
        "-q",
        "synth",
        "--modality",
        "markers",
        "--scenario",
        "sequence",
        "--frames",
        "6",
        "--seed",
        "3",
        "--out",
        path_str(&data),
    ]);
    let body = format!(
        "name = \"seq\"\nmethods = [\"cma\", \"pso:hierarchical\"]\nbudgets = [150]\nseed = 7\ndata = \"{}\"\n",
        path_str(&data)
    );
    let cfg = config(d, "seq.toml", &body);
    let full = d.join("full");
    let summary = lfit_json(&[
        "-q",
        "bench",
        "--config",
        path_str(&cfg),
        "--out",
        path_str(&full),
    ]);
    assert_eq!(summary["runs"], 2 * 6);
    // The chain is the same computation as `lfit fit` on the sequence (same seeds): frame k
    // starts from frame k−1's result, so every energy matches to the last digit.
    let fit = d.join("fit.json");
    lfit_json(&[
        "-q",
        "fit",
        "--data",
        path_str(&data),
        "--method",
        "cma",
        "--budget",
        "150",
        "--seed",
        "7",
        "--out",
        path_str(&fit),
    ]);
    same_energies(&full.join("runs.csv"), "cma", &fit, 6);
    // Parallel fits of one frame count their evaluations apart: the budget holds exactly.
    let evaluations = column(&full.join("runs.csv"), "evaluations");
    for line in std::fs::read_to_string(full.join("runs.csv"))
        .expect("csv")
        .lines()
        .skip(1)
    {
        let f: Vec<&str> = line.split(',').collect();
        assert!(
            f[evaluations].parse::<u64>().expect("evaluations") <= 150,
            "{line}"
        );
    }
    // The pinned strategy is in the rows and the labels.
    let csv = std::fs::read_to_string(full.join("runs.csv")).expect("csv");
    assert!(csv.contains("\npso,hierarchical,150,0,0,"), "{csv}");
    let md = std::fs::read_to_string(full.join("report.md")).expect("report");
    assert!(
        md.contains("pso (hierarchical)") && md.contains("cma (holistic)"),
        "{md}"
    );

    // A run stopped after 2 rows of a chain re-fits the chain for its warm starts but keeps the
    // rows it has, and ends with the same CSV.
    let resumed = d.join("resumed");
    std::fs::create_dir_all(&resumed).expect("dir");
    std::fs::copy(full.join("bench.json"), resumed.join("bench.json")).expect("copy");
    let text: Vec<String> = std::fs::read_to_string(full.join("runs.csv"))
        .expect("csv")
        .lines()
        .take(3)
        .map(|l| format!("{l}\n"))
        .collect();
    std::fs::write(resumed.join("runs.csv"), text.concat()).expect("partial");
    // Rows without the record of their inputs are not resumed (nor touched).
    let args = [
        "-q",
        "bench",
        "--config",
        path_str(&cfg),
        "--out",
        path_str(&resumed),
    ];
    assert_one_line_error(&lfit(&args), "without a record of their inputs");
    assert_eq!(
        std::fs::read_to_string(resumed.join("runs.csv")).expect("csv"),
        text.concat()
    );
    std::fs::copy(full.join("inputs.json"), resumed.join("inputs.json")).expect("copy");
    lfit_json(&args);
    assert_eq!(
        csv_without_time(&resumed.join("runs.csv")),
        csv_without_time(&full.join("runs.csv"))
    );
}

#[test]
fn presets_list_validate_and_refuse_bad_names() {
    let list = lfit_json(&["-q", "bench", "presets"]);
    let names: Vec<&str> = list["presets"]
        .as_array()
        .expect("list")
        .iter()
        .map(|p| p["name"].as_str().expect("name"))
        .collect();
    assert_eq!(
        names,
        [
            "zeroth-order-local",
            "zeroth-order-global",
            "zeroth-order-sequence",
            "ea-vs-pf",
            "learned-vs-classical",
            "learned-vs-classical-procedural",
            "face"
        ]
    );
    for p in list["presets"].as_array().expect("list") {
        assert!(
            p["quick"][0]["frames"].as_u64() < p["full"][0]["frames"].as_u64(),
            "{p}"
        );
    }
    let tmp = tempfile::tempdir().expect("tmp");
    let out_dir = tmp.path().join("o");
    let out = lfit(&[
        "-q",
        "bench",
        "--preset",
        "zeroth-order",
        "--out",
        path_str(&out_dir),
    ]);
    assert_one_line_error(&out, "unknown preset 'zeroth-order'");
    assert!(!out_dir.exists());
    let c = config(
        tmp.path(),
        "c.toml",
        "name = \"x\"\nmethods = [\"neural:grouped\"]\nbudgets = [5]\n[synth]\nmodality = \"markers\"\nframes = 2\n",
    );
    let out = lfit(&[
        "-q",
        "bench",
        "--config",
        path_str(&c),
        "--out",
        path_str(&out_dir),
    ]);
    assert_one_line_error(&out, "no strategies");
    let c = config(
        tmp.path(),
        "c.toml",
        "name = \"x\"\nmethods = [\"cma\", \"cma:holistic\"]\nbudgets = [5]\n[synth]\nmodality = \"markers\"\nframes = 2\n",
    );
    let out = lfit(&[
        "-q",
        "bench",
        "--config",
        path_str(&c),
        "--out",
        path_str(&out_dir),
    ]);
    assert_one_line_error(&out, "listed twice");
    assert!(!out_dir.exists());
}

#[test]
fn quick_sizes_apply_to_user_configs_too() {
    let tmp = tempfile::tempdir().expect("tmp");
    let d = tmp.path();
    let c = config(
        d,
        "q.toml",
        "name = \"q\"\nmethods = [\"pso\"]\nbudgets = [400]\n[synth]\nmodality = \"markers\"\nframes = 5\n[quick]\nframes = 2\nbudgets = [50]\n",
    );
    let quick = lfit_json(&[
        "-q",
        "bench",
        "--config",
        path_str(&c),
        "--quick",
        "--out",
        path_str(&d.join("quick")),
    ]);
    assert_eq!(quick["runs"], 2);
    let csv = std::fs::read_to_string(d.join("quick/runs.csv")).expect("csv");
    assert!(csv.contains("\npso,holistic,50,0,1,"), "{csv}");
    let full = lfit_json(&[
        "-q",
        "bench",
        "--config",
        path_str(&c),
        "--out",
        path_str(&d.join("full")),
    ]);
    assert_eq!(full["runs"], 5);
    // --quick on a config without a [quick] section is a bad flag, not a silent full-size run.
    let plain = config(
        d,
        "p.toml",
        "name = \"p\"\nmethods = [\"pso\"]\nbudgets = [40]\n[synth]\nmodality = \"markers\"\nframes = 2\n",
    );
    let out_dir = d.join("plain");
    assert_one_line_error(
        &lfit(&[
            "-q",
            "bench",
            "--config",
            path_str(&plain),
            "--quick",
            "--out",
            path_str(&out_dir),
        ]),
        "no [quick] section",
    );
    assert!(!out_dir.exists());
}

/// `marker_placement = "solve"` in a bench config: the same computation as `lfit fit
/// --sequence-shape joint --marker-placement solve` on a MakeHuman markers sequence whose markers
/// sit 15 mm off the model's set (every frame's energy to the last digit); an unknown value is
/// refused with one line before anything runs.
#[test]
fn bench_solves_the_marker_placement_like_lfit_fit() {
    let tmp = tempfile::tempdir().expect("tmp");
    let d = tmp.path();
    let model = Path::new(env!("CARGO_MANIFEST_DIR")).join("models/makehuman-cmu_mb.npz");
    let data = d.join("slip.npz");
    synth_to(
        &data,
        &model,
        &[
            "--modality",
            "markers",
            "--scenario",
            "sequence",
            "--frames",
            "5",
            "--seed",
            "4",
            "--marker-slip-mm",
            "15",
        ],
    );
    let body = |placement: &str| {
        format!(
            "name = \"placed\"\nmethods = [\"lm\"]\nbudgets = [60]\nseed = 5\ndata = \"{}\"\ntemplate = \"{}\"\nsequence_shape = \"joint\"\nmarker_placement = \"{placement}\"\n",
            path_str(&data),
            path_str(&model)
        )
    };
    let out = d.join("bench");
    let cfg = config(d, "placed.toml", &body("solve"));
    lfit_json(&[
        "-q",
        "bench",
        "--config",
        path_str(&cfg),
        "--out",
        path_str(&out),
    ]);
    let fit = d.join("fit.json");
    lfit_json(&[
        "-q",
        "fit",
        "--data",
        path_str(&data),
        "--template",
        path_str(&model),
        "--method",
        "lm",
        "--budget",
        "60",
        "--seed",
        "5",
        "--sequence-shape",
        "joint",
        "--marker-placement",
        "solve",
        "--out",
        path_str(&fit),
    ]);
    same_energies(&out.join("runs.csv"), "lm", &fit, 5);
    let bad = config(d, "bad.toml", &body("nearby"));
    let never = d.join("never");
    assert_one_line_error(
        &lfit(&[
            "bench",
            "--config",
            path_str(&bad),
            "--out",
            path_str(&never),
        ]),
        "unknown marker placement 'nearby'",
    );
    assert!(!never.join("runs.csv").exists());
}
