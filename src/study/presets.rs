//! The built-in benchmark presets (`benches/presets/*.toml`, compiled into the binary): the
//! studies of papers/000 §4.1–4.3, papers/001 §5 and papers/002 Table 2, each at the paper's
//! protocol size and, with `--quick`, at a size that finishes in minutes on a 2-core machine.

use std::path::Path;

use anyhow::{Context, Result, bail};

use crate::study::bench::BenchConfig;

/// `(preset, [(part, TOML)])`: a preset with several parts (one per modality) writes each part
/// into its own subdirectory of `--out`.
pub const PRESETS: &[(&str, &[(&str, &str)])] = &[
    (
        "zeroth-order-local",
        &[(
            "",
            include_str!("../../benches/presets/zeroth-order-local.toml"),
        )],
    ),
    (
        "zeroth-order-global",
        &[(
            "",
            include_str!("../../benches/presets/zeroth-order-global.toml"),
        )],
    ),
    (
        "zeroth-order-sequence",
        &[(
            "",
            include_str!("../../benches/presets/zeroth-order-sequence.toml"),
        )],
    ),
    (
        "ea-vs-pf",
        &[
            (
                "silhouettes",
                include_str!("../../benches/presets/ea-vs-pf-silhouettes.toml"),
            ),
            (
                "keypoints2d",
                include_str!("../../benches/presets/ea-vs-pf-keypoints2d.toml"),
            ),
        ],
    ),
    (
        "learned-vs-classical",
        &[
            (
                "markers",
                include_str!("../../benches/presets/learned-vs-classical-markers.toml"),
            ),
            (
                "keypoints2d",
                include_str!("../../benches/presets/learned-vs-classical-keypoints2d.toml"),
            ),
            (
                "hmd",
                include_str!("../../benches/presets/learned-vs-classical-hmd.toml"),
            ),
        ],
    ),
    (
        "learned-vs-classical-procedural",
        &[
            (
                "markers",
                include_str!("../../benches/presets/learned-vs-classical-procedural-markers.toml"),
            ),
            (
                "keypoints2d",
                include_str!(
                    "../../benches/presets/learned-vs-classical-procedural-keypoints2d.toml"
                ),
            ),
            (
                "hmd",
                include_str!("../../benches/presets/learned-vs-classical-procedural-hmd.toml"),
            ),
        ],
    ),
    (
        "face",
        &[("", include_str!("../../benches/presets/face.toml"))],
    ),
];

/// Preset names, for messages.
pub fn names() -> Vec<&'static str> {
    PRESETS.iter().map(|(n, _)| *n).collect()
}

/// The parts of preset `name`, resolved: `(subdirectory, config)`; `quick` applies the
/// `[quick]` sizes. Relative checkpoint paths are looked up in the working directory, then in
/// the source tree the binary was built from (so a preset runs from anywhere in a checkout).
pub fn load(name: &str, quick: bool) -> Result<Vec<(String, BenchConfig)>> {
    let Some((_, parts)) = PRESETS.iter().find(|(n, _)| *n == name) else {
        bail!(
            "unknown preset '{name}' (expected one of: {})",
            names().join(", ")
        );
    };
    let mut out = Vec::new();
    for (part, text) in parts.iter() {
        let config: BenchConfig = toml::from_str(text)
            .map_err(|e| anyhow::anyhow!("preset {name} {part}: {}", e.message()))?;
        let mut config = config.resolve(quick);
        if let Some(c) = &config.checkpoint {
            config.checkpoint = Some(crate::shipped::locate(c)?);
        }
        if let Some(t) = &config.template {
            config.template = Some(crate::shipped::locate(t)?);
        }
        // An energy file (anything but the names `paper`/`gradient` that
        // `BenchConfig::energy_config` knows), e.g. configs/face-energy.json.
        if let Some(e) = config
            .energy
            .clone()
            .filter(|e| !matches!(e.as_str(), "paper" | "gradient"))
        {
            config.energy = Some(
                crate::shipped::locate(Path::new(&e))?
                    .to_string_lossy()
                    .into_owned(),
            );
        }
        config
            .validate()
            .with_context(|| format!("preset {name} {part}"))?;
        out.push((part.to_string(), config));
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_preset_parses_and_validates_at_both_sizes() {
        for (name, parts) in PRESETS {
            for quick in [false, true] {
                let loaded =
                    load(name, quick).unwrap_or_else(|e| panic!("{name} quick={quick}: {e:#}"));
                assert_eq!(loaded.len(), parts.len());
                for (_, c) in &loaded {
                    assert!(c.quick.is_none(), "{name}: [quick] must be resolved away");
                    assert!(c.synth.is_some(), "{name}: presets synthesise their data");
                }
            }
        }
    }

    #[test]
    fn quick_shrinks_and_full_follows_the_papers() {
        let full = &load("zeroth-order-local", false).unwrap()[0].1;
        let quick = &load("zeroth-order-local", true).unwrap()[0].1;
        // papers/000 §4.1: ten optimizers, budgets 2000/4000/7000, 5 repetitions, 10 performances.
        assert_eq!(full.methods.len(), 10);
        assert_eq!(full.budgets, vec![2000, 4000, 7000]);
        assert_eq!(full.repetitions, 5);
        assert_eq!(full.synth.as_ref().unwrap().frames, 10);
        assert_eq!(quick.budgets, full.budgets);
        assert_eq!(quick.methods, full.methods);
        assert!(
            quick.repetitions * quick.synth.as_ref().unwrap().frames
                < full.repetitions * full.synth.as_ref().unwrap().frames
        );
        let global = &load("zeroth-order-global", false).unwrap()[0].1;
        assert_eq!(global.methods.len(), 9);
        assert_eq!(global.strategies, vec!["grouped".to_string()]);
        let seq = &load("zeroth-order-sequence", false).unwrap()[0].1;
        assert_eq!(
            (seq.methods.len(), seq.budgets.as_slice(), seq.repetitions),
            (5, &[4000][..], 1)
        );
        // papers/002 Table 7 on ≥ 1,000 held-out samples of the face protocol, with the tuned
        // eq. (9) energy.
        let face = &load("face", false).unwrap()[0].1;
        let synth = face.synth.as_ref().unwrap();
        assert!(synth.frames >= 1000);
        assert_eq!(
            (synth.modality.as_str(), synth.source.as_deref()),
            ("landmarks2d", Some("face"))
        );
        assert!(Path::new(face.energy.as_deref().unwrap()).exists());
        assert!(
            face.template
                .as_ref()
                .unwrap()
                .ends_with("makehuman-face.npz")
        );
        assert!(
            face.checkpoint
                .as_ref()
                .unwrap()
                .ends_with("checkpoints/face")
        );
        assert_eq!(
            load("face", true).unwrap()[0]
                .1
                .synth
                .as_ref()
                .unwrap()
                .frames,
            100
        );
        let pf = &load("ea-vs-pf", false).unwrap()[0].1;
        assert_eq!(pf.budgets, vec![500, 1500, 3000]);
        assert_eq!(pf.entries().unwrap().len(), 8);
        // papers/000 and papers/001 fit the pose of the subject's own model: on the MakeHuman
        // body with β given.
        for preset in [
            "zeroth-order-local",
            "zeroth-order-global",
            "zeroth-order-sequence",
            "ea-vs-pf",
        ] {
            for (p, c) in load(preset, true).unwrap() {
                assert_eq!(
                    c.template.as_ref().and_then(|t| t.file_name()),
                    Some(std::ffi::OsStr::new("makehuman-cmu_mb.npz")),
                    "{preset} {p}"
                );
                assert!(c.template.as_ref().unwrap().exists(), "{preset} {p}");
                assert!(c.known_shape, "{preset} {p}");
            }
        }
        // The default study runs on the MakeHuman body with its own fitters (β known for hmd,
        // papers/002 §3.2); the procedural preset keeps the small template's study.
        for (preset, model, suffix) in [
            (
                "learned-vs-classical",
                Some("makehuman-cmu_mb.npz"),
                "-makehuman",
            ),
            ("learned-vs-classical-procedural", None, ""),
        ] {
            let lvc = load(preset, true).unwrap();
            let parts: Vec<&str> = lvc.iter().map(|(p, _)| p.as_str()).collect();
            assert_eq!(parts, ["markers", "keypoints2d", "hmd"]);
            for (p, c) in &lvc {
                let ck = c.checkpoint.as_ref().unwrap();
                assert!(ck.join("config.json").exists(), "{preset} {p}");
                assert!(ck.ends_with(format!("{p}{suffix}")), "{preset} {p}: {ck:?}");
                assert_eq!(
                    c.template.as_ref().and_then(|t| t.file_name()),
                    model.map(std::ffi::OsStr::new),
                    "{preset} {p}"
                );
                assert_eq!(
                    c.known_shape,
                    model.is_some() && *p == "hmd",
                    "{preset} {p}"
                );
            }
        }
    }

    #[test]
    fn unknown_preset_names_the_choices() {
        let e = load("zeroth-order", false).unwrap_err().to_string();
        assert!(
            e.contains("unknown preset 'zeroth-order'") && e.contains("ea-vs-pf"),
            "{e}"
        );
    }
}
