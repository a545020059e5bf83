//! The report of `lfit bench` (SPEC §9): `report.md` with the papers' tables and `summary.json`
//! with every statistic.
//!
//! - papers/000 Table 2: average final energy per method and budget, sorted, with the relative
//!   performance RP to the best; Table 4: the same for the RMS Hausdorff distance;
//! - papers/000 Table 3: pairwise Wilcoxon signed-rank tests on the per-frame means over
//!   repetitions (+ row better, − row worse, ≈ no significant difference at `alpha`);
//! - papers/001 Table 4: Friedman test over frames with average ranks and Holm's post-hoc test
//!   against the best-ranked method;
//! - papers/002 Table 2: V2V, MPJPE, PA-MPJPE, evaluations and time per frame.

use std::collections::BTreeMap;
use std::fmt::Write as _;

use serde_json::{Value, json};

use crate::study::bench::{BenchConfig, Run};
use crate::study::stats::{friedman, relative_performance, verdict, wilcoxon};

/// The method label of a row: the method, with its strategy when the sweep has several.
pub(crate) fn label(config: &BenchConfig, r: &Run) -> String {
    if config.shows_strategy() && r.strategy != "-" {
        format!("{} ({})", r.method, r.strategy)
    } else {
        r.method.clone()
    }
}

fn mean(v: &[f64]) -> f64 {
    if v.is_empty() {
        f64::NAN
    } else {
        v.iter().sum::<f64>() / v.len() as f64
    }
}

/// Labels in config order.
pub(crate) fn labels(config: &BenchConfig, runs: &[Run]) -> Vec<String> {
    let mut out: Vec<String> = Vec::new();
    for r in runs {
        let l = label(config, r);
        if !out.contains(&l) {
            out.push(l);
        }
    }
    out
}

/// Per label: frame → mean over repetitions of `f`.
fn per_instance(
    config: &BenchConfig,
    runs: &[Run],
    budget: usize,
    f: fn(&Run) -> f64,
) -> BTreeMap<String, BTreeMap<usize, f64>> {
    let mut acc: BTreeMap<String, BTreeMap<usize, Vec<f64>>> = BTreeMap::new();
    for r in runs.iter().filter(|r| r.budget == budget) {
        acc.entry(label(config, r))
            .or_default()
            .entry(r.frame)
            .or_default()
            .push(f(r));
    }
    acc.into_iter()
        .map(|(l, m)| (l, m.into_iter().map(|(k, v)| (k, mean(&v))).collect()))
        .collect()
}

/// `report.md` and `summary.json`.
pub fn report(
    config: &BenchConfig,
    runs: &[Run],
    energy_name: &str,
    command: &str,
) -> (String, Value) {
    let mut md = String::new();
    let labels = labels(config, runs);
    let frames: Vec<usize> = {
        let mut f: Vec<usize> = runs.iter().map(|r| r.frame).collect();
        f.sort_unstable();
        f.dedup();
        f
    };
    let _ = writeln!(md, "# {}\n", config.name);
    let _ = writeln!(md, "Command: `{command}`\n");
    let _ = writeln!(
        md,
        "{} runs: methods {:?} × strategies {:?} × budgets {:?} × {} repetition(s) × {} frames; energy: {energy_name}; α = {}.\n",
        runs.len(),
        config
            .methods
            .iter()
            .map(ToString::to_string)
            .collect::<Vec<_>>(),
        config.strategies,
        config.budgets,
        config.repetitions,
        frames.len(),
        config.alpha
    );
    let mut table = Vec::new();
    let mut wil = Vec::new();
    let mut fried = Vec::new();

    // papers/000 Table 2 and Table 4.
    for (title, what, f) in [
        (
            "Average final energy (papers/000 Table 2)",
            "energy",
            (|r: &Run| r.energy) as fn(&Run) -> f64,
        ),
        (
            "RMS Hausdorff distance, mm (papers/000 Table 4)",
            "hausdorff_mm",
            |r: &Run| r.hausdorff_mm,
        ),
    ] {
        let _ = writeln!(md, "## {title}\n");
        for &b in &config.budgets {
            let mut rows: Vec<(String, f64)> = labels
                .iter()
                .map(|l| {
                    (
                        l.clone(),
                        mean(
                            &runs
                                .iter()
                                .filter(|r| r.budget == b && label(config, r) == *l)
                                .map(f)
                                .collect::<Vec<_>>(),
                        ),
                    )
                })
                .filter(|(_, v)| v.is_finite())
                .collect();
            rows.sort_by(|a, b| a.1.total_cmp(&b.1));
            let Some(best) = rows.first().map(|r| r.1) else {
                continue;
            };
            let _ = writeln!(md, "B = {b}\n\n| method | RP | {what} |\n|---|---|---|");
            for (l, v) in &rows {
                let _ = writeln!(
                    md,
                    "| {l} | {:+.2}% | {v:.5} |",
                    100.0 * relative_performance(*v, best)
                );
            }
            md.push('\n');
        }
    }

    // papers/002 Table 2 form.
    let _ = writeln!(
        md,
        "## Errors, evaluations and time per frame (papers/002 Table 2)\n"
    );
    // A model with shape coefficients adds their RMS error (β estimated or given) and, where
    // the rows carry it (runs.csv from this version on), the rest meshes' shape error (PVE-T).
    let shaped = runs.iter().any(|r| r.shape_rms.is_finite());
    let shape_mesh = shaped && runs.iter().any(|r| r.shape_v2v_mm.is_finite());
    let _ = writeln!(
        md,
        "| method | budget | V2V (mm) | MPJPE (mm) | PA-MPJPE (mm) | RMS Hausdorff (mm) |{}{} energy | evaluations | time / frame (ms) |\n|---|---|---|---|---|---|{}{}---|---|---|",
        if shaped { " shape RMS |" } else { "" },
        if shape_mesh { " shape V2V (mm) |" } else { "" },
        if shaped { "---|" } else { "" },
        if shape_mesh { "---|" } else { "" }
    );
    for &b in &config.budgets {
        for l in &labels {
            let rs: Vec<&Run> = runs
                .iter()
                .filter(|r| r.budget == b && label(config, r) == *l)
                .collect();
            if rs.is_empty() {
                continue;
            }
            let m = |f: fn(&Run) -> f64| mean(&rs.iter().map(|r| f(r)).collect::<Vec<_>>());
            let mut row = json!({"method": l, "budget": b, "runs": rs.len(), "v2v_mm": m(|r| r.v2v_mm), "mpjpe_mm": m(|r| r.mpjpe_mm),
                "pa_mpjpe_mm": m(|r| r.pa_mpjpe_mm), "hausdorff_mm": m(|r| r.hausdorff_mm), "energy": m(|r| r.energy),
                "evaluations": m(|r| r.evaluations as f64), "time_ms": 1000.0 * m(|r| r.time_s)});
            let mut shape = if shaped {
                let v = m(|r| r.shape_rms);
                row["shape_rms"] = json!(v);
                format!(" {v:.3} |")
            } else {
                String::new()
            };
            if shape_mesh {
                let v = m(|r| r.shape_v2v_mm);
                row["shape_v2v_mm"] = json!(v);
                shape.push_str(&format!(" {v:.1} |"));
            }
            let _ = writeln!(
                md,
                "| {l} | {b} | {:.1} | {:.1} | {:.1} | {:.1} |{shape} {:.4} | {:.0} | {:.2} |",
                row["v2v_mm"].as_f64().unwrap_or(f64::NAN),
                row["mpjpe_mm"].as_f64().unwrap_or(f64::NAN),
                row["pa_mpjpe_mm"].as_f64().unwrap_or(f64::NAN),
                row["hausdorff_mm"].as_f64().unwrap_or(f64::NAN),
                row["energy"].as_f64().unwrap_or(f64::NAN),
                row["evaluations"].as_f64().unwrap_or(f64::NAN),
                row["time_ms"].as_f64().unwrap_or(f64::NAN)
            );
            table.push(row);
        }
    }
    md.push('\n');
    // papers/002 Table 7: a face model's errors.
    let mut face_table = Vec::new();
    if runs.iter().any(|r| r.face.is_some()) {
        let _ = writeln!(
            md,
            "## Face fitting to 2D landmarks (papers/002 Table 7)\n\nV2V over the face region and the whole head, LdmkErr over the landmarks (mean 3D distance), in mm; PA: after Procrustes alignment (rotation, scale, translation) on the same vertices.\n\n| method | budget | V2V face | V2V head | LdmkErr | PA-V2V face | PA-V2V head | PA-LdmkErr | time / fit (ms) |\n|---|---|---|---|---|---|---|---|---|"
        );
        for &b in &config.budgets {
            for l in &labels {
                let rs: Vec<&Run> = runs
                    .iter()
                    .filter(|r| r.budget == b && label(config, r) == *l && r.face.is_some())
                    .collect();
                if rs.is_empty() {
                    continue;
                }
                let cols: [f64; 6] = std::array::from_fn(|k| {
                    mean(
                        &rs.iter()
                            .filter_map(|r| r.face.map(|f| f.to_array()[k]))
                            .collect::<Vec<_>>(),
                    )
                });
                let time_ms = 1000.0 * mean(&rs.iter().map(|r| r.time_s).collect::<Vec<_>>());
                let _ = writeln!(
                    md,
                    "| {l} | {b} | {} | {time_ms:.2} |",
                    cols.iter()
                        .map(|v| format!("{v:.1}"))
                        .collect::<Vec<_>>()
                        .join(" | ")
                );
                let errors = lfit_model::metrics::FaceErrors::from_array(cols);
                face_table.push(json!({"method": l, "budget": b, "runs": rs.len(), "errors": errors, "time_ms": time_ms}));
            }
        }
        md.push('\n');
    }
    // Neural error per iteration.
    let neural: Vec<&Run> = runs
        .iter()
        .filter(|r| !r.v2v_per_iteration.is_empty())
        .collect();
    if let Some(first) = neural.first() {
        let k = first.v2v_per_iteration.len();
        let per: Vec<f64> = (0..k)
            .map(|i| {
                mean(
                    &neural
                        .iter()
                        .filter_map(|r| r.v2v_per_iteration.get(i).copied())
                        .collect::<Vec<_>>(),
                )
            })
            .collect();
        let _ = writeln!(
            md,
            "Neural fitter V2V (mm) after each iteration (θ0 first; papers/002 Fig. 4): {}\n",
            per.iter()
                .map(|v| format!("{v:.1}"))
                .collect::<Vec<_>>()
                .join(" → ")
        );
    }

    // papers/000 Table 3: Wilcoxon matrix on per-frame means over repetitions.
    let _ = writeln!(
        md,
        "## Wilcoxon signed-rank tests on per-frame mean energies (papers/000 Table 3)\n"
    );
    let _ = writeln!(
        md,
        "Cell: the row method is better (+), worse (−) or not significantly different (≈) than the column method at α = {}.\n",
        config.alpha
    );
    for &b in &config.budgets {
        let inst = per_instance(config, runs, b, |r| r.energy);
        let present: Vec<&String> = labels.iter().filter(|l| inst.contains_key(*l)).collect();
        let paired = |a: &str, c: &str| -> (Vec<f64>, Vec<f64>) {
            let (ma, mc) = (&inst[a], &inst[c]);
            ma.iter()
                .filter_map(|(f, va)| mc.get(f).map(|vc| (*va, *vc)))
                .unzip()
        };
        let _ = writeln!(
            md,
            "B = {b}\n\n| | {} |\n|---|{}",
            present
                .iter()
                .map(|s| s.as_str())
                .collect::<Vec<_>>()
                .join(" | "),
            "---|".repeat(present.len())
        );
        for a in &present {
            let mut line = format!("| {a} |");
            for c in &present {
                if a == c {
                    line.push_str(" N/A |");
                    continue;
                }
                let (x, y) = paired(a, c);
                let (v, p) = verdict(&x, &y, config.alpha);
                let _ = write!(line, " {} |", if v == "-" { "−" } else { v });
                if a < c {
                    let w = wilcoxon(&x, &y);
                    wil.push(json!({"a": a, "b": c, "budget": b, "p": p, "verdict": v, "n": w.map(|w| w.n), "exact": w.map(|w| w.exact)}));
                }
            }
            let _ = writeln!(md, "{line}");
        }
        md.push('\n');

        // papers/001 Table 4: Friedman + Holm over the frames every method has.
        let common: Vec<usize> = frames
            .iter()
            .copied()
            .filter(|f| present.iter().all(|l| inst[*l].contains_key(f)))
            .collect();
        let blocks: Vec<Vec<f64>> = common
            .iter()
            .map(|f| present.iter().map(|l| inst[*l][f]).collect())
            .collect();
        if let Some(fr) = friedman(&blocks, config.alpha) {
            let _ = writeln!(
                md,
                "Friedman test (papers/001 Table 4), B = {b}: statistic {:.3} (χ² with {} d.o.f.), p = {:.3e}, over {} frames.\n",
                fr.statistic,
                present.len() - 1,
                fr.p,
                common.len()
            );
            let _ = writeln!(
                md,
                "| method | rank | p-value | Holm-adjusted p | α/(position−1) | significant |\n|---|---|---|---|---|---|"
            );
            let _ = writeln!(
                md,
                "| {} (control) | {:.3} | - | - | - | - |",
                present[fr.control], fr.ranks[fr.control]
            );
            for h in &fr.holm {
                let _ = writeln!(
                    md,
                    "| {} | {:.3} | {:.3e} | {:.3e} | {:.4} | {} |",
                    present[h.method],
                    h.rank,
                    h.p,
                    h.p_adjusted,
                    h.threshold,
                    if h.significant { "yes" } else { "no" }
                );
            }
            md.push('\n');
            fried.push(json!({
                "budget": b, "statistic": fr.statistic, "p": fr.p, "frames": common.len(),
                "ranks": present.iter().zip(&fr.ranks).map(|(l, r)| (l.to_string(), json!(r))).collect::<serde_json::Map<_, _>>(),
                "control": present[fr.control],
                "holm": fr.holm.iter().map(|h| json!({"method": present[h.method], "rank": h.rank, "p": h.p, "p_adjusted": h.p_adjusted, "threshold": h.threshold, "significant": h.significant})).collect::<Vec<_>>(),
            }));
        }
    }
    let mut summary = json!({
        "name": config.name,
        "energy": energy_name,
        "runs": runs.len(),
        "methods": labels,
        "budgets": config.budgets,
        "table": table,
        "wilcoxon": wil,
        "friedman": fried,
    });
    if !face_table.is_empty() {
        summary["face_table"] = json!(face_table);
    }
    (md, summary)
}
