//! The `tuned` preset: per method and modality, the factor on the initial steps (and for CMA-ES
//! the update variant: diagonal, elitist, population) that a recorded sweep on validation frames
//! chose (`configs/tuned.json`, written by
//! `docs/results/tuning.py`; the sweep and its choices are in `docs/results/tuning.md`). The
//! validation frames come from their own seeds, never from a test set.

use anyhow::{Context, Result, bail};
use lfit_fitters::optim::cma::CmaVariant;
use serde_json::Value;

const TUNED: &str = include_str!("../../configs/tuned.json");

/// What the `tuned` preset sets for one method on one modality.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Tuned {
    /// Factor on papers/000's initial steps.
    pub step_scale: f64,
    /// CMA-ES's update variant (default for other methods).
    pub cma: CmaVariant,
}

/// The settings table of configs/tuned.json.
fn settings() -> Result<serde_json::Map<String, Value>> {
    let table: Value = serde_json::from_str(TUNED).context("configs/tuned.json")?;
    table
        .get("settings")
        .and_then(Value::as_object)
        .cloned()
        .context("configs/tuned.json has no \"settings\"")
}

/// The recorded setting of `method` on `modality`, or `None` when the sweep recorded none (the
/// gradient methods, the neural fitter, zeroth-order methods it did not sweep, modalities it did
/// not cover): the default of `lfit fit` and `lfit bench` — each baseline at its best where a
/// setting was measured, papers/000's (nevergrad's) initial steps elsewhere.
pub fn recorded(method: &str, modality: &str) -> Result<Option<Tuned>> {
    let settings = settings()?;
    let Some(entry) = settings.get(modality).and_then(|m| m.get(method)) else {
        return Ok(None);
    };
    let step_scale = entry
        .get("step_scale")
        .and_then(Value::as_f64)
        .with_context(|| format!("configs/tuned.json: {method} on {modality} has no step_scale"))?;
    let mut cma = CmaVariant::default();
    if let Some(c) = entry.get("cma") {
        cma.diagonal = c.get("diagonal").and_then(Value::as_bool).unwrap_or(false);
        cma.elitist = c.get("elitist").and_then(Value::as_bool).unwrap_or(false);
        cma.popsize = c.get("popsize").and_then(Value::as_u64).map(|p| p as usize);
    }
    Ok(Some(Tuned { step_scale, cma }))
}

/// The recorded setting of `method` on `modality` (`--preset tuned`: an error naming the
/// recorded pairs when there is none).
pub fn setting(method: &str, modality: &str) -> Result<Tuned> {
    if let Some(t) = recorded(method, modality)? {
        return Ok(t);
    }
    let mut known: Vec<String> = settings()?
        .iter()
        .flat_map(|(m, v)| {
            v.as_object()
                .into_iter()
                .flat_map(move |o| o.keys().map(move |k| format!("{k} on {m}")))
        })
        .collect();
    known.sort();
    bail!(
        "no tuned setting for {method} on {modality} (configs/tuned.json has: {})",
        known.join(", ")
    )
}

#[cfg(test)]
mod tests {
    #[test]
    fn every_recorded_setting_is_a_positive_factor_and_unknown_pairs_say_what_exists() {
        let table: serde_json::Value = serde_json::from_str(super::TUNED).unwrap();
        let settings = table["settings"].as_object().unwrap();
        assert!(!settings.is_empty());
        for (modality, methods) in settings {
            for (method, s) in methods.as_object().unwrap() {
                let t = super::setting(method, modality).unwrap();
                assert!(
                    t.step_scale.is_finite() && t.step_scale > 0.0,
                    "{method} on {modality}: {s}"
                );
                assert!(
                    method == "cma" || t.cma == Default::default(),
                    "{method} on {modality}: {s}"
                );
            }
        }
        let err = super::setting("lbfgs", "markers").unwrap_err().to_string();
        assert!(
            err.contains("no tuned setting for lbfgs on markers") && err.contains("cma on markers"),
            "{err}"
        );
        // The default: the recorded setting where there is one, none (not an error) elsewhere.
        assert_eq!(
            super::recorded("cma", "markers").unwrap(),
            Some(super::setting("cma", "markers").unwrap())
        );
        assert_eq!(super::recorded("lbfgs", "markers").unwrap(), None);
        assert_eq!(super::recorded("cma", "no-such-modality").unwrap(), None);
    }
}

/// The one rule by which `lfit fit` and `lfit bench` choose a zeroth-order method's steps:
/// `preset` `tuned` takes the recorded setting (an error where none is recorded), another preset
/// its own steps (`None` here), and no preset the recorded setting where there is one.
/// `modality` is asked for only when a recorded setting may apply.
pub fn choose(
    preset: Option<&str>,
    method: &str,
    modality: &mut dyn FnMut() -> Result<String>,
) -> Result<Option<Tuned>> {
    match preset {
        Some("tuned") => setting(method, &modality()?).map(Some),
        Some(_) => Ok(None),
        None => recorded(method, &modality()?),
    }
}
