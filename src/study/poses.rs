//! The fitted poses of a bench run (`poses.jsonl` in its output directory): which runs
//! `lfit bench` records, and the file's lines, written as runs finish and read back by
//! `bench merge` and the report's pictures ([`crate::render::pictures`]).

use std::collections::HashMap;
use std::path::Path;

use anyhow::{Context, Result};
use lfit_model::template::write_atomic;
use serde_json::{Value, json};

/// File of fitted poses in a bench output directory.
pub const POSES_FILE: &str = "poses.jsonl";
/// Key of a run: method, strategy, budget, repetition, frame.
pub type RunKey = (String, String, usize, usize, usize);

/// Whether `lfit bench` records the pose of a run: repetition 0 at the largest of the sweep's
/// `budgets`.
pub fn records_pose(budgets: &[usize], budget: usize, rep: usize) -> bool {
    rep == 0 && budgets.iter().max() == Some(&budget)
}

/// One line of `poses.jsonl` (with its newline).
pub fn pose_line(key: &RunKey, params: &[f64]) -> String {
    let (method, strategy, budget, rep, frame) = key;
    let mut line = json!({
        "method": method, "strategy": strategy, "budget": budget, "rep": rep, "frame": frame,
        "params": params,
    })
    .to_string();
    line.push('\n');
    line
}

/// Reads `poses.jsonl` (missing file: empty). Complete lines only; a later line replaces an
/// earlier one of the same run.
pub fn read_poses(path: &Path) -> Result<HashMap<RunKey, Vec<f64>>> {
    let text = match std::fs::read_to_string(path) {
        Ok(t) => t,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(HashMap::new()),
        Err(e) => return Err(e).with_context(|| format!("cannot read {}", path.display())),
    };
    let mut lines: Vec<&str> = text.split('\n').collect();
    // Only lines ended by '\n' are complete.
    lines.pop();
    let mut out = HashMap::new();
    for (i, line) in lines.iter().enumerate() {
        let parsed = (|| -> Option<(RunKey, Vec<f64>)> {
            let v: Value = serde_json::from_str(line).ok()?;
            let n = |k: &str| v.get(k)?.as_u64().and_then(|x| usize::try_from(x).ok());
            let key = (
                v.get("method")?.as_str()?.to_string(),
                v.get("strategy")?.as_str()?.to_string(),
                n("budget")?,
                n("rep")?,
                n("frame")?,
            );
            let params = v
                .get("params")?
                .as_array()?
                .iter()
                .map(Value::as_f64)
                .collect::<Option<Vec<f64>>>()?;
            Some((key, params))
        })();
        let (key, params) =
            parsed.with_context(|| format!("{}: malformed line {}", path.display(), i + 1))?;
        out.insert(key, params);
    }
    Ok(out)
}

/// Writes `poses` as `poses.jsonl` (sorted, for stable bytes).
pub fn write_poses(path: &Path, poses: &HashMap<RunKey, Vec<f64>>) -> Result<()> {
    let mut keys: Vec<&RunKey> = poses.keys().collect();
    keys.sort();
    let text: String = keys.iter().map(|k| pose_line(k, &poses[*k])).collect();
    write_atomic(path, text.as_bytes())?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn poses_round_trip_and_a_torn_line_is_ignored() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join(POSES_FILE);
        let k1: RunKey = ("cma".into(), "-".into(), 10, 0, 3);
        let k2: RunKey = ("lm".into(), "-".into(), 10, 0, 1);
        let mut text = pose_line(&k1, &[0.0, 1.5]);
        text.push_str(&pose_line(&k2, &[2.0]));
        text.push_str(&pose_line(&k1, &[7.0, 8.0]));
        text.push_str("{\"method\": \"cm");
        std::fs::write(&path, &text).unwrap();
        let poses = read_poses(&path).unwrap();
        assert_eq!(poses.len(), 2);
        assert_eq!(poses[&k1], vec![7.0, 8.0], "the later line wins");
        write_poses(&path, &poses).unwrap();
        assert_eq!(read_poses(&path).unwrap(), poses);
        std::fs::write(&path, "not json\n").unwrap();
        assert!(read_poses(&path).is_err());
        assert!(read_poses(&dir.path().join("none")).unwrap().is_empty());
    }
}
