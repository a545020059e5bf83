//! `lfit bench`: resume after a kill, shards + merge, reports, bad configs.

mod support;

use std::path::Path;
use std::process::Command;
use std::time::{Duration, Instant};

use support::{assert_one_line_error, lfit, lfit_json, path_str};

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
fn csv_without_time(path: &Path) -> Vec<String> {
    std::fs::read_to_string(path)
        .expect("csv")
        .lines()
        .map(|l| l.split(',').enumerate().filter(|(i, _)| *i != 15).map(|(_, f)| f).collect::<Vec<_>>().join(","))
        .collect()
}

fn rows(path: &Path) -> usize {
    std::fs::read_to_string(path).map(|t| t.lines().count().saturating_sub(1)).unwrap_or(0)
}

#[test]
fn a_killed_run_resumes_to_the_same_csv_and_shards_merge_to_the_same_report() {
    let tmp = tempfile::tempdir().expect("tmp");
    let d = tmp.path();
    let cfg = config(d, "b.toml", SWEEP);
    let full = d.join("full");
    let summary = lfit_json(&["-q", "bench", "--config", path_str(&cfg), "--out", path_str(&full)]);
    assert_eq!(summary["runs"], 3 * 2 * 2 * 8);
    assert_eq!(rows(&full.join("runs.csv")), 96);

    // Kill a run once it has written some rows, then restart it.
    let killed = d.join("killed");
    let mut child = Command::new(env!("CARGO_BIN_EXE_lfit")).args(["-q", "bench", "--config", path_str(&cfg), "--out", path_str(&killed)]).spawn().expect("spawn");
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
    lfit_json(&["-q", "bench", "--config", path_str(&cfg), "--out", path_str(&killed)]);
    assert_eq!(csv_without_time(&killed.join("runs.csv")), csv_without_time(&full.join("runs.csv")));

    // Three shards and a merge give the same rows and the same statistics.
    let mut shard_dirs = Vec::new();
    for i in 0..3 {
        let s = d.join(format!("shard{i}"));
        lfit_json(&["-q", "bench", "--config", path_str(&cfg), "--out", path_str(&s), "--shard", &format!("{i}/3")]);
        assert!(rows(&s.join("runs.csv")) == 32, "shard {i}");
        shard_dirs.push(s);
    }
    let merged = d.join("merged");
    let mut args = vec!["-q", "bench", "merge", "--out", path_str(&merged)];
    args.extend(shard_dirs.iter().map(|s| path_str(s)));
    lfit_json(&args);
    assert_eq!(csv_without_time(&merged.join("runs.csv")), csv_without_time(&full.join("runs.csv")));
    let a: serde_json::Value = serde_json::from_slice(&std::fs::read(full.join("summary.json")).expect("a")).expect("json");
    let b: serde_json::Value = serde_json::from_slice(&std::fs::read(merged.join("summary.json")).expect("b")).expect("json");
    assert_eq!(a["wilcoxon"], b["wilcoxon"]);
    assert_eq!(a["friedman"], b["friedman"]);
    // The summary has every pairwise test per budget, and the report the papers' tables.
    assert_eq!(a["wilcoxon"].as_array().map(Vec::len), Some(3 * 2));
    assert_eq!(a["friedman"].as_array().map(Vec::len), Some(2));
    let md = std::fs::read_to_string(full.join("report.md")).expect("report");
    for needle in ["papers/000 Table 2", "papers/000 Table 3", "papers/000 Table 4", "papers/001 Table 4", "papers/002 Table 2", "| pso |"] {
        assert!(md.contains(needle), "report lacks {needle}");
    }

    // Another config in the same directory is refused; a shard of another sweep is not merged.
    let other = config(d, "other.toml", &SWEEP.replace("budgets = [300, 600]", "budgets = [300]"));
    let out = lfit(&["-q", "bench", "--config", path_str(&other), "--out", path_str(&full)]);
    assert_one_line_error(&out, "different benchmark");
    let o2 = d.join("o2");
    lfit_json(&["-q", "bench", "--config", path_str(&other), "--out", path_str(&o2), "--shard", "0/50"]);
    let out = lfit(&["-q", "bench", "merge", "--out", path_str(&d.join("m2")), path_str(&shard_dirs[0]), path_str(&o2)]);
    assert_one_line_error(&out, "another benchmark");
}

#[test]
fn bad_bench_configs_fail_before_any_work() {
    let tmp = tempfile::tempdir().expect("tmp");
    let d = tmp.path();
    let base = "name = \"x\"\nbudgets = [100]\n[synth]\nmodality = \"markers\"\nframes = 2\n";
    for (body, needle) in [
        (format!("methods = [\"cmaes\"]\n{base}"), "unknown method 'cmaes'"),
        (format!("methods = [\"cma\"]\n{}", base.replace("[100]", "[100, 0]")), "budgets"),
        ("methods = [\"cma\"]\nname = \"x\"\nbudgets = [10]\ndata = \"/nonexistent.npz\"\n".to_string(), "does not exist"),
        (format!("methods = [\"neural\"]\n{base}"), "needs checkpoint"),
        (format!("methods = [\"cma\"]\nstrategies = [\"sideways\"]\n{base}"), "sideways"),
        (format!("methods = [\"cma\"]\nbogus = 1\n{base}"), "bogus"),
        ("methods = [".to_string(), "malformed bench config"),
    ] {
        let c = config(d, "c.toml", &body);
        let out_dir = d.join("out");
        let out = lfit(&["-q", "bench", "--config", path_str(&c), "--out", path_str(&out_dir)]);
        assert_one_line_error(&out, needle);
        assert!(!out_dir.exists(), "{needle}: nothing may be written before the config is valid");
    }
    let out = lfit(&["-q", "bench", "--config", path_str(&d.join("missing.toml")), "--out", path_str(&d.join("o"))]);
    assert_one_line_error(&out, "cannot read");
    let c = config(d, "ok.toml", &format!("methods = [\"cma\"]\n{base}"));
    let out = lfit(&["-q", "bench", "--config", path_str(&c), "--out", path_str(&d.join("o")), "--shard", "3/3"]);
    assert_one_line_error(&out, "--shard");
}
