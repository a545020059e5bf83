//! Pictures in the reports of `lfit bench` and `lfit quickstart`: per method, its best, median
//! and worst frame by V2V (repetition 0 at the largest budget), rendered front and side (and the
//! dataset's camera 0 for camera modalities) into `OUT/pictures/<method>.png` and linked from
//! `report.md`.
//!
//! The fitted poses come from `OUT/poses.jsonl`, which `lfit bench` appends to as runs finish
//! (one JSON object per line: method, strategy, budget, rep, frame, params; only repetition 0 at
//! the largest budget, the runs the pictures draw). A torn last line (a killed run) is ignored;
//! a run recorded twice (a resumed run) keeps its last line.

use std::fmt::Write as _;
use std::path::Path;

use anyhow::{Context, Result};
use lfit_model::skinning::SkinningMethod;
use lfit_model::template::write_atomic;
use lfit_synth::Dataset;

use super::scene::{Scene, draw};
use super::{FrameRow, frame_panels, legend};
use crate::study::bench::{BenchConfig, Run};
use crate::study::poses::{POSES_FILE, read_poses};

/// Folder of the pictures in a bench output directory.
pub const PICTURES_DIR: &str = "pictures";

/// File-name form of a method label.
fn slug(label: &str) -> String {
    let s: String = label
        .chars()
        .map(|c| {
            if c.is_ascii_alphanumeric() {
                c.to_ascii_lowercase()
            } else {
                '-'
            }
        })
        .collect();
    let s = s.trim_matches('-').to_string();
    if s.is_empty() { "method".into() } else { s }
}

/// Best, median and worst run by V2V (finite ones; fewer when there are fewer runs).
pub fn best_median_worst<'a>(runs: &[&'a Run]) -> Vec<(&'static str, &'a Run)> {
    let mut sorted: Vec<&Run> = runs
        .iter()
        .copied()
        .filter(|r| r.v2v_mm.is_finite())
        .collect();
    sorted.sort_by(|a, b| a.v2v_mm.total_cmp(&b.v2v_mm).then(a.frame.cmp(&b.frame)));
    let Some(last) = sorted.len().checked_sub(1) else {
        return Vec::new();
    };
    let mut picks: Vec<(&'static str, usize)> =
        vec![("best", 0), ("median", last / 2), ("worst", last)];
    picks.dedup_by_key(|p| p.1);
    picks.into_iter().map(|(n, i)| (n, sorted[i])).collect()
}

/// Renders the pictures of a finished sweep in `out` and returns the report's "Pictures"
/// section (Markdown). Without recorded poses or a dataset the section says so.
pub fn report_pictures(config: &BenchConfig, runs: &[Run], out: &Path) -> Result<String> {
    let mut md = String::from("\n## Pictures\n\n");
    let data = config.data.clone().unwrap_or_else(|| out.join("data.npz"));
    let poses = read_poses(&out.join(POSES_FILE))?;
    let Some(&budget) = config.budgets.iter().max() else {
        return Ok(String::new());
    };
    if poses.is_empty() || !data.is_file() {
        md.push_str(
            "No pictures: this output has no recorded poses (`poses.jsonl`) or no dataset; a new run into a fresh `--out` records them.\n",
        );
        return Ok(md);
    }
    let dataset = Dataset::load(&data).with_context(|| format!("dataset {}", data.display()))?;
    let template = crate::fitting::template_for(&dataset, config.template.as_deref())?;
    let camera = super::view_camera(&dataset, 0).is_some();
    let _ = writeln!(
        md,
        "Best, median and worst frame by V2V of each method at budget {budget} (repetition 0): front, side{} — {}.\n",
        if camera { " and camera 0" } else { "" },
        legend(true, true)
    );
    let dir = out.join(PICTURES_DIR);
    std::fs::create_dir_all(&dir).with_context(|| format!("cannot create {}", dir.display()))?;
    for label in crate::study::report::labels(config, runs) {
        let mine: Vec<&Run> = runs
            .iter()
            .filter(|r| {
                r.budget == budget && r.rep == 0 && crate::study::report::label(config, r) == label
            })
            .collect();
        let mut rows = Vec::new();
        for (which, r) in best_median_worst(&mine) {
            let key = (
                r.method.clone(),
                r.strategy.clone(),
                r.budget,
                r.rep,
                r.frame,
            );
            let Some(params) = poses.get(&key) else {
                continue;
            };
            if params.len() != template.layout().dim() || r.frame >= dataset.len() {
                continue;
            }
            // A pose that does not give the row's V2V is not this run's (a stale file): skip.
            let Some(gt) = dataset.ground_truth(r.frame) else {
                continue;
            };
            let v2v = lfit_model::metrics::v2v_mm(&template, params, gt);
            if (v2v - r.v2v_mm).abs() > 1e-3 * (1.0 + r.v2v_mm.abs()) {
                continue;
            }
            rows.push(FrameRow {
                frame: r.frame,
                fit: Some(params.clone()),
                label: format!("{which}: frame {} · V2V {:.1} mm", r.frame, r.v2v_mm),
            });
        }
        if rows.is_empty() {
            let _ = writeln!(md, "- {label}: no recorded poses\n");
            continue;
        }
        let mut panels = Vec::new();
        for row in &rows {
            panels.extend(frame_panels(
                &template,
                &dataset,
                row,
                0,
                SkinningMethod::Linear,
            ));
        }
        let columns = panels.len() / rows.len();
        // The neural fitter spends its own 2N evaluations, not the sweep's budget.
        let spent = match mine.first() {
            Some(r) if r.method == crate::method::MethodKind::Neural.name() => {
                format!("N = {}, {} evaluations", r.iterations, r.evaluations)
            }
            _ => format!("@{budget}"),
        };
        let scene = Scene {
            title: format!(
                "{label} {spent} · {} · {}",
                dataset.modality(),
                super::view_names(&dataset, 0)
            ),
            columns,
            panels,
        };
        let (w, h) = (220 * columns as u32, 270 * rows.len() as u32 + 22);
        let canvas = draw(&scene, &template.faces, w, h)?;
        let name = format!("{}.png", slug(&label));
        write_atomic(&dir.join(&name), &canvas.to_png()?)?;
        let _ = writeln!(
            md,
            "### {label}\n\n![{label}: best, median and worst V2V frame]({PICTURES_DIR}/{name})\n"
        );
    }
    Ok(md)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn run(frame: usize, v2v: f64) -> Run {
        Run {
            method: "cma".into(),
            strategy: "-".into(),
            budget: 10,
            rep: 0,
            frame,
            seed: 0,
            energy: 0.0,
            start_energy: 0.0,
            v2v_mm: v2v,
            mpjpe_mm: 0.0,
            pa_mpjpe_mm: 0.0,
            hausdorff_mm: 0.0,
            shape_rms: f64::NAN,
            evaluations: 0,
            gradient_evaluations: 0,
            iterations: 0,
            time_s: 0.0,
            trace: Vec::new(),
            v2v_per_iteration: Vec::new(),
            face: None,
            shape_v2v_mm: f64::NAN,
        }
    }

    #[test]
    fn best_median_and_worst_are_picked_by_v2v() {
        let runs: Vec<Run> = [(0, 5.0), (1, 1.0), (2, f64::NAN), (3, 9.0), (4, 3.0)]
            .into_iter()
            .map(|(f, v)| run(f, v))
            .collect();
        let refs: Vec<&Run> = runs.iter().collect();
        let picks: Vec<(&str, usize)> = best_median_worst(&refs)
            .into_iter()
            .map(|(n, r)| (n, r.frame))
            .collect();
        // Finite V2V sorted: 1 (f1), 3 (f4), 5 (f0), 9 (f3); median index 3 / 2 = 1.
        assert_eq!(picks, vec![("best", 1), ("median", 4), ("worst", 3)]);
        let one = [&runs[0]];
        assert_eq!(best_median_worst(&one).len(), 1);
        assert!(best_median_worst(&[]).is_empty());
    }

    #[test]
    fn slugs_are_file_names() {
        assert_eq!(slug("cma (grouped)"), "cma--grouped");
    }
}
