//! Shared helpers of the integration tests: run the `lfit` binary, temporary directories.
#![allow(dead_code)]

use std::path::Path;
use std::process::{Command, Output};

/// Runs `lfit` with `args` and returns its output.
pub fn lfit(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_lfit")).args(args).env("RUST_BACKTRACE", "0").output().expect("the lfit binary runs")
}

/// Runs `lfit`, asserts success and returns stdout parsed as JSON.
pub fn lfit_json(args: &[&str]) -> serde_json::Value {
    let out = lfit(args);
    assert!(out.status.success(), "lfit {args:?} failed: {}", String::from_utf8_lossy(&out.stderr));
    serde_json::from_slice(&out.stdout).expect("stdout is JSON")
}

/// Asserts the failure contract: non-zero exit, exactly one line on stderr that mentions
/// `needle`, no panic.
pub fn assert_one_line_error(out: &Output, needle: &str) {
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success(), "expected failure, got success; stderr: {stderr}");
    assert_ne!(out.status.code(), Some(101), "exit code 101 is a panic: {stderr}");
    assert!(!stderr.contains("panicked"), "panic: {stderr}");
    let lines: Vec<&str> = stderr.lines().filter(|l| !l.trim().is_empty()).collect();
    assert_eq!(lines.len(), 1, "expected one line, got: {stderr}");
    assert!(lines[0].to_lowercase().contains(&needle.to_lowercase()), "'{needle}' not in: {}", lines[0]);
}

pub fn path_str(p: &Path) -> &str {
    p.to_str().expect("utf-8 temp path")
}
