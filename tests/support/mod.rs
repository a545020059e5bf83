//! Shared helpers of the integration tests: run the `lfit` binary, temporary directories.
#![allow(dead_code)]

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

/// Runs `lfit` with `args` and returns its output.
pub fn lfit(args: &[&str]) -> Output {
    lfit_env(args, &[])
}

/// Runs `lfit` with `args` and the environment variables `env` set, and returns its output.
pub fn lfit_env(args: &[&str], env: &[(&str, &str)]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_lfit"))
        .args(args)
        .env("RUST_BACKTRACE", "0")
        .envs(env.iter().copied())
        .output()
        .expect("the lfit binary runs")
}

/// Runs `lfit`, asserts success and returns stdout parsed as JSON.
pub fn lfit_json(args: &[&str]) -> serde_json::Value {
    let out = lfit(args);
    assert!(
        out.status.success(),
        "lfit {args:?} failed: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    serde_json::from_slice(&out.stdout).expect("stdout is JSON")
}

/// `lfit -q synth --template MODEL ARGS --out OUT`: a dataset of the model file `model` written
/// to `out`, asserting success.
pub fn synth_to(out: &Path, model: &Path, args: &[&str]) {
    let mut all = vec!["-q", "synth", "--template", path_str(model)];
    all.extend(args);
    all.extend(["--out", path_str(out)]);
    lfit_json(&all);
}

/// Asserts the failure contract: non-zero exit, exactly one line on stderr that mentions
/// `needle`, no panic.
pub fn assert_one_line_error(out: &Output, needle: &str) {
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(
        !out.status.success(),
        "expected failure, got success; stderr: {stderr}"
    );
    assert_ne!(
        out.status.code(),
        Some(101),
        "exit code 101 is a panic: {stderr}"
    );
    assert!(!stderr.contains("panicked"), "panic: {stderr}");
    let lines: Vec<&str> = stderr.lines().filter(|l| !l.trim().is_empty()).collect();
    assert_eq!(lines.len(), 1, "expected one line, got: {stderr}");
    assert!(
        lines[0].to_lowercase().contains(&needle.to_lowercase()),
        "'{needle}' not in: {}",
        lines[0]
    );
}

/// The `v` lines of an OBJ file, in file order.
pub fn obj_vertices(path: &Path) -> Vec<[f64; 3]> {
    std::fs::read_to_string(path)
        .expect("readable OBJ")
        .lines()
        .filter(|l| l.starts_with("v "))
        .map(|l| {
            let c: Vec<f64> = l
                .split_whitespace()
                .skip(1)
                .map(|x| x.parse().expect("a number"))
                .collect();
            [c[0], c[1], c[2]]
        })
        .collect()
}

/// A test cannot run because a component is missing (`reason`): fails when `CI=true` or the
/// environment variable `require` is set, since CI must run it; otherwise prints why it skips.
pub fn skip_unless_required(reason: &str, require: Option<&str>) {
    let required = std::env::var("CI").as_deref() == Ok("true")
        || require.is_some_and(|v| std::env::var_os(v).is_some());
    assert!(!required, "required here but unavailable: {reason}");
    eprintln!("skipping: {reason}");
}

/// A `python3` command whose `PYTHONPATH` is `LFIT_SCIPY_PYTHONPATH` (numpy and scipy from
/// scripts/fetch-scipy.sh, set by scripts/test.sh) and which imports `modules` (e.g.
/// `"scipy, numpy"`), or why there is none.
pub fn python_with(modules: &str) -> Result<Command, String> {
    let make = || {
        let mut c = Command::new("python3");
        if let Some(p) = std::env::var_os("LFIT_SCIPY_PYTHONPATH") {
            c.env("PYTHONPATH", p);
        }
        c
    };
    match make().args(["-c", &format!("import {modules}")]).output() {
        Ok(o) if o.status.success() => Ok(make()),
        Ok(o) => Err(format!(
            "python3 cannot import {modules} (run scripts/fetch-scipy.sh and set LFIT_SCIPY_PYTHONPATH): {}",
            String::from_utf8_lossy(&o.stderr)
                .lines()
                .last()
                .unwrap_or("")
        )),
        Err(e) => Err(format!("no python3: {e}")),
    }
}

/// `lfit -q fit --data DATA --method lm --budget BUDGET --out OUT` and `more`.
pub fn lm_fit_args<'a>(
    data: &'a Path,
    out: &'a Path,
    budget: &'a str,
    more: &[&'a str],
) -> Vec<&'a str> {
    let mut a = vec![
        "-q",
        "fit",
        "--data",
        path_str(data),
        "--method",
        "lm",
        "--budget",
        budget,
        "--out",
        path_str(out),
    ];
    a.extend(more);
    a
}

/// `lfit -q data export-c3d --data DATA --out OUT`: a markers dataset's observations as a C3D
/// file, asserting success; the summary.
pub fn export_c3d(data: &Path, out: &Path) -> serde_json::Value {
    lfit_json(&[
        "-q",
        "data",
        "export-c3d",
        "--data",
        path_str(data),
        "--out",
        path_str(out),
    ])
}

/// `lfit -q data import --c3d C3D MORE --out OUT` (a label map, a model, ...), asserting
/// success; the summary.
pub fn import_c3d_with(c3d: &Path, out: &Path, more: &[&str]) -> serde_json::Value {
    let mut a = vec!["-q", "data", "import", "--c3d", path_str(c3d)];
    a.extend(more);
    a.extend(["--out", path_str(out)]);
    lfit_json(&a)
}

pub fn path_str(p: &Path) -> &str {
    p.to_str().expect("utf-8 temp path")
}

/// The npm prefix holding gltf-validator: `LFIT_GLTF_VALIDATOR` (set by scripts/test.sh), else
/// the default of scripts/fetch-gltf-validator.sh; `Err(reason)` when it or node is missing.
pub fn gltf_validator() -> Result<PathBuf, String> {
    let prefix = match std::env::var_os("LFIT_GLTF_VALIDATOR") {
        Some(p) => PathBuf::from(p),
        None => {
            let tools = std::env::var_os("LFIT_TOOLS_DIR")
                .map(PathBuf::from)
                .or_else(|| {
                    std::env::var_os("HOME").map(|h| Path::new(&h).join(".cache/lfit-tools"))
                });
            tools
                .ok_or("neither LFIT_GLTF_VALIDATOR nor HOME is set")?
                .join("gltf-validator")
        }
    };
    if !prefix
        .join("node_modules/gltf-validator/package.json")
        .is_file()
    {
        return Err(format!(
            "gltf-validator is not installed under {} (run scripts/fetch-gltf-validator.sh)",
            prefix.display()
        ));
    }
    match Command::new("node").arg("--version").output() {
        Ok(o) if o.status.success() => Ok(prefix),
        _ => Err("node is not installed".into()),
    }
}

/// Runs the Khronos validator (scripts/validate-gltf.mjs) on `glb`: its JSON report and stdout.
pub fn validate_glb(prefix: &Path, glb: &Path) -> (serde_json::Value, String) {
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("scripts/validate-gltf.mjs");
    let run = Command::new("node")
        .arg(&script)
        .arg(glb)
        .env("LFIT_GLTF_VALIDATOR", prefix)
        .output()
        .expect("node runs");
    let stdout = String::from_utf8_lossy(&run.stdout).into_owned();
    assert!(
        run.status.code() == Some(0) || run.status.code() == Some(1),
        "validator failed to run: {}",
        String::from_utf8_lossy(&run.stderr)
    );
    (
        serde_json::from_str(&stdout).expect("the validator prints a JSON report"),
        stdout,
    )
}

/// The MocapBank BVH clip (scripts/fetch-mocapbank.sh): `LFIT_MOCAPBANK_BVH`, else where the
/// script puts it; `None` when it is not fetched.
pub fn mocapbank_clip() -> Option<PathBuf> {
    if let Some(p) = std::env::var_os("LFIT_MOCAPBANK_BVH") {
        return Some(PathBuf::from(p));
    }
    let tools = std::env::var_os("LFIT_TOOLS_DIR")
        .map(PathBuf::from)
        .or_else(|| std::env::var_os("HOME").map(|h| Path::new(&h).join(".cache/lfit-tools")))?;
    let p = tools.join("mocapbank/test_mocapbank.bvh");
    p.is_file().then_some(p)
}

/// `max` for folding differences that is NaN as soon as one entry is (`f64::max` drops NaN, so
/// an all-NaN output would fold to 0 and pass a tolerance).
#[allow(dead_code)]
pub fn nan_max(a: f64, b: f64) -> f64 {
    if a.is_nan() || b.is_nan() {
        f64::NAN
    } else {
        a.max(b)
    }
}
