//! `lfit ablate`: trains the SPEC §7 variants of the neural fitter at a reduced size and
//! evaluates them on one held-out set, writing papers/002 Tables 3–6 (HMD, half-space hand
//! visibility) and supp. Table A.1 (2D keypoints) in the papers' form.
//!
//! Every variant differs from its study's base configuration (`configs/hmd.json`,
//! `configs/keypoints2d.json`) in the one switch its table varies. As in papers/002 §4 the
//! networks start from Φ(D) ("regression and 5 iterations of the learned fitter"). Trained
//! variants and their evaluations are kept in `out/`, so a re-run only does what is missing.

use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::sync::Arc;

use anyhow::{Context, Result, bail};
use glam::DVec3;
use lfit_fitters::FitRequest;
use lfit_model::Template;
use lfit_model::metrics::{
    aligned_joint_error_mm, ground_penetration_mm, joint_error_mm, joint_positions, part_vertices,
    v2v_mm, v2v_subset_mm,
};
use lfit_model::observe::{Modality, Sensor};
use lfit_model::pose::{Bounds, DofMask, POSE_DIM, Pose};
use lfit_model::skeleton::{HEAD, L_HAND, R_HAND};
use lfit_model::template::write_atomic;
use lfit_nn::{CoreKind, GammaMode, NetConfig, StartMode, StepShape, UpdateRule};
use lfit_train::TrainConfig;
use serde::{Deserialize, Serialize};
use serde_json::{Value, json};

/// One trained variant: its name, the table rows it fills and how it departs from the base.
#[derive(Debug, Clone)]
pub struct Variant {
    pub name: &'static str,
    pub modality: Modality,
    /// `(table, row label)` for every table the variant appears in.
    pub rows: &'static [(&'static str, &'static str)],
    pub apply: fn(&mut NetConfig),
}

fn base(_: &mut NetConfig) {}

/// The variants of papers/002 Tables 3–6 (HMD) and supp. Table A.1 (keypoints2d). The HMD base is
/// shared weights, two GRU layers, eq. (1), learned vector γ; it is the reference row of every
/// HMD table, as in the paper.
pub const VARIANTS: &[Variant] = &[
    Variant {
        name: "hmd-base",
        modality: Modality::Hmd,
        rows: &[
            ("3", "Shared"),
            ("4", "GRU (H, H)"),
            ("5", "+Eq. 1"),
            ("6", "Learned"),
        ],
        apply: base,
    },
    Variant {
        name: "hmd-per-step",
        modality: Modality::Hmd,
        rows: &[("3", "Per-step")],
        apply: |c| c.per_step_weights = true,
    },
    Variant {
        name: "hmd-resnet",
        modality: Modality::Hmd,
        rows: &[("4", "ResNet")],
        apply: |c| c.core = CoreKind::ResidualMlp,
    },
    Variant {
        name: "hmd-gru1",
        modality: Modality::Hmd,
        rows: &[("4", "GRU (H)")],
        apply: |c| c.layers = 1,
    },
    Variant {
        name: "hmd-delta-only",
        modality: Modality::Hmd,
        rows: &[("5", "+Δθn")],
        apply: |c| c.update = UpdateRule::DeltaOnly,
    },
    Variant {
        name: "hmd-convex",
        modality: Modality::Hmd,
        rows: &[("5", "convex (supp. eq. 10, first)")],
        apply: |c| c.update = UpdateRule::Convex,
    },
    Variant {
        name: "hmd-convex-normalized",
        modality: Modality::Hmd,
        rows: &[("5", "convex normalized (supp. eq. 10, second)")],
        apply: |c| c.update = UpdateRule::ConvexNormalized,
    },
    Variant {
        name: "hmd-gamma-constant",
        modality: Modality::Hmd,
        rows: &[("6", "1e-4")],
        apply: |c| {
            c.gamma = GammaMode::Constant;
            c.gamma_constant = 1e-4;
        },
    },
    Variant {
        name: "kp-vl-sg-separate",
        modality: Modality::Keypoints2d,
        rows: &[("A.1", "✓|✗|✗")],
        apply: |c| {
            c.gamma_shape = Some(StepShape::Scalar);
            c.shared_lambda_gamma = false;
        },
    },
    Variant {
        name: "kp-sl-vg-separate",
        modality: Modality::Keypoints2d,
        rows: &[("A.1", "✗|✓|✗")],
        apply: |c| {
            c.step_shape = StepShape::Scalar;
            c.gamma_shape = Some(StepShape::Vector);
            c.shared_lambda_gamma = false;
        },
    },
    Variant {
        name: "kp-vl-vg-separate",
        modality: Modality::Keypoints2d,
        rows: &[("A.1", "✓|✓|✗")],
        apply: |c| c.shared_lambda_gamma = false,
    },
    Variant {
        name: "kp-vl-vg-shared",
        modality: Modality::Keypoints2d,
        rows: &[("A.1", "✓|✓|✓")],
        apply: base,
    },
];

/// The size of the study.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct AblateSize {
    pub steps: usize,
    pub batch: usize,
    pub hidden: usize,
    pub test_frames: usize,
}

impl AblateSize {
    /// `--quick`: a few minutes per variant on 2 cores. Full: the shipped checkpoints' size
    /// (`configs/*.json`: 1500 steps, batch 64, 128 units).
    pub fn new(quick: bool) -> Self {
        if quick {
            Self {
                steps: 300,
                batch: 32,
                hidden: 64,
                test_frames: 200,
            }
        } else {
            Self {
                steps: 1500,
                batch: 64,
                hidden: 128,
                test_frames: 500,
            }
        }
    }
}

/// Options of `lfit ablate`.
#[derive(Debug, Clone)]
pub struct AblateArgs {
    pub out: PathBuf,
    pub size: AblateSize,
    pub device: String,
    /// Variant names to run (all when empty).
    pub only: Vec<String>,
    pub seed: u64,
}

/// Metrics of one variant on the test set (means over frames).
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct Eval {
    pub variant: String,
    pub frames: usize,
    pub v2v_mm: f64,
    pub head_v2v_mm: f64,
    pub l_hand_v2v_mm: f64,
    pub r_hand_v2v_mm: f64,
    pub mpjpe_mm: f64,
    pub pa_mpjpe_mm: f64,
    pub ground_penetration_mm: f64,
    pub parameters: usize,
    pub train_time_s: f64,
    pub steps: usize,
}

fn base_config(modality: Modality) -> Result<TrainConfig> {
    let text = match modality {
        Modality::Hmd => include_str!("../../configs/hmd.json"),
        Modality::Keypoints2d => include_str!("../../configs/keypoints2d.json"),
        m => bail!("no ablation base for modality {m}"),
    };
    let config: TrainConfig = serde_json::from_str(text).context("base training config")?;
    Ok(config)
}

/// The training config of `variant` at `size`.
pub fn variant_config(variant: &Variant, size: &AblateSize, seed: u64) -> Result<TrainConfig> {
    let mut c = base_config(variant.modality)?;
    c.steps = size.steps;
    c.batch = size.batch;
    c.network.hidden = size.hidden;
    c.network.start = StartMode::Phi;
    c.val_frames = c.val_frames.min(size.test_frames);
    c.val_every = size.steps;
    c.checkpoint_every = size.steps;
    c.seed = seed;
    (variant.apply)(&mut c.network);
    c.validate()?;
    Ok(c)
}

/// The held-out test set of a modality (never used in training: seeds from `TEST_BASE`).
fn test_frames(
    template: &Arc<Template>,
    modality: Modality,
    frames: usize,
) -> Result<lfit_train::Frames> {
    let sensor = Sensor::default_for(modality, template);
    let base = lfit_train::base_energy(template, &sensor)?;
    let seed = lfit_train::seeds::TEST_BASE + 0xAB1A + modality as u64;
    Ok(lfit_train::synth_frames(
        template, &sensor, &base, frames, seed, 1.0,
    )?)
}

/// Fits the test set with the checkpoint in `dir` from Φ(D) and measures it.
fn evaluate(
    dir: &Path,
    name: &str,
    frames: &lfit_train::Frames,
    template: &Arc<Template>,
    device: &burn::tensor::Device,
) -> Result<Eval> {
    let fitter = lfit_infer::NeuralFitter::load(dir, device, lfit_infer::Start::Phi)?;
    let n = frames.energies.len();
    let requests: Vec<FitRequest<'_>> = frames
        .energies
        .iter()
        .enumerate()
        .map(|(i, e)| FitRequest {
            energy: e,
            start: frames.dataset.start_poses[i].clone(),
            mask: DofMask::full57(),
            bounds: Bounds::global(),
            budget: usize::MAX,
            seed: i as u64,
            motion: None,
        })
        .collect();
    let mut poses: Vec<Pose> = Vec::with_capacity(n);
    for chunk in requests.chunks(64) {
        for r in fitter.fit_batch(chunk)? {
            let mut p = [0.0; POSE_DIM];
            p.copy_from_slice(&r.pose);
            poses.push(p);
        }
    }
    let parts = [
        part_vertices(template, HEAD),
        part_vertices(template, L_HAND),
        part_vertices(template, R_HAND),
    ];
    let gt = &frames.dataset.gt_poses;
    let mean = |f: &dyn Fn(&Pose, &[f64]) -> f64| {
        poses.iter().zip(gt).map(|(p, g)| f(p, g)).sum::<f64>() / n.max(1) as f64
    };
    // Each frame's fitted and true joints, posed once for MPJPE and PA-MPJPE.
    let joints: Vec<_> = poses
        .iter()
        .zip(gt)
        .map(|(p, g)| (joint_positions(template, p), joint_positions(template, g)))
        .collect();
    let mean_joints = |f: &dyn Fn(&[DVec3], &[DVec3]) -> f64| {
        joints.iter().map(|(p, g)| f(p, g)).sum::<f64>() / n.max(1) as f64
    };
    let card: Value = serde_json::from_slice(
        &std::fs::read(dir.join("metrics.json"))
            .with_context(|| format!("{}/metrics.json", dir.display()))?,
    )?;
    Ok(Eval {
        variant: name.to_string(),
        frames: n,
        v2v_mm: mean(&|p, g| v2v_mm(template, p, g)),
        head_v2v_mm: mean(&|p, g| v2v_subset_mm(template, p, g, &parts[0])),
        l_hand_v2v_mm: mean(&|p, g| v2v_subset_mm(template, p, g, &parts[1])),
        r_hand_v2v_mm: mean(&|p, g| v2v_subset_mm(template, p, g, &parts[2])),
        mpjpe_mm: mean_joints(&joint_error_mm),
        pa_mpjpe_mm: mean_joints(&aligned_joint_error_mm),
        ground_penetration_mm: mean(&|p, _| ground_penetration_mm(template, p)),
        parameters: card["parameters"].as_u64().unwrap_or(0) as usize,
        train_time_s: card["time_s"].as_f64().unwrap_or(f64::NAN),
        steps: card["steps"].as_u64().unwrap_or(0) as usize,
    })
}

/// Runs the study (or the `only` variants) and writes `ablation.md` and `ablation.json`.
pub fn run(args: &AblateArgs, progress: &(dyn Fn(&str) + Sync)) -> Result<Value> {
    for o in &args.only {
        if !VARIANTS.iter().any(|v| v.name == o) {
            bail!(
                "unknown variant '{o}' (expected one of: {})",
                VARIANTS
                    .iter()
                    .map(|v| v.name)
                    .collect::<Vec<_>>()
                    .join(", ")
            );
        }
    }
    if args.size.steps == 0
        || args.size.batch == 0
        || args.size.hidden == 0
        || args.size.test_frames == 0
    {
        bail!("--steps, --batch, --hidden and --test-frames must be at least 1");
    }
    let selected: Vec<&Variant> = VARIANTS
        .iter()
        .filter(|v| args.only.is_empty() || args.only.iter().any(|o| o == v.name))
        .collect();
    // Every config is checked before any training starts.
    let configs: Vec<TrainConfig> = selected
        .iter()
        .map(|v| variant_config(v, &args.size, args.seed))
        .collect::<Result<_>>()?;
    let device = lfit_nn::tensor::device_from_name(&args.device)?;
    std::fs::create_dir_all(&args.out)
        .with_context(|| format!("cannot create {}", args.out.display()))?;
    let size_file = args.out.join("size.json");
    let size_json = serde_json::to_vec_pretty(&json!({ "size": args.size, "seed": args.seed }))?;
    match std::fs::read(&size_file) {
        Ok(prev) if prev != size_json => bail!(
            "{} holds an ablation of another size or seed (size.json differs); use another --out",
            args.out.display()
        ),
        _ => write_atomic(&size_file, &size_json)?,
    }
    let template = Arc::new(crate::data::load_model(None, "default")?);
    let mut sets: BTreeMap<String, lfit_train::Frames> = BTreeMap::new();
    let mut evals: Vec<Eval> = Vec::new();
    for (variant, config) in selected.iter().zip(&configs) {
        let dir = args.out.join(variant.name);
        let eval_file = dir.join("eval.json");
        if let Ok(bytes) = std::fs::read(&eval_file) {
            evals.push(
                serde_json::from_slice(&bytes)
                    .with_context(|| format!("malformed {}", eval_file.display()))?,
            );
            progress(&format!("{}: done earlier", variant.name));
            continue;
        }
        let finished = std::fs::read(dir.join("metrics.json"))
            .ok()
            .and_then(|b| serde_json::from_slice::<Value>(&b).ok())
            .is_some_and(|m| m["steps"].as_u64() == Some(config.steps as u64));
        if !finished {
            progress(&format!(
                "{}: training {} steps",
                variant.name, config.steps
            ));
            let options = lfit_train::RunOptions {
                out: dir.clone(),
                device_name: args.device.clone(),
                resume: dir.join("config.json").exists(),
                init: None,
                command: std::env::args().collect::<Vec<_>>().join(" "),
            };
            lfit_train::train(config, template.clone(), &device, &options, &|_| {})
                .with_context(|| format!("training {}", variant.name))?;
        }
        progress(&format!("{}: evaluating", variant.name));
        let key = variant.modality.to_string();
        if !sets.contains_key(&key) {
            sets.insert(
                key.clone(),
                test_frames(&template, variant.modality, args.size.test_frames)?,
            );
        }
        let eval = evaluate(&dir, variant.name, &sets[&key], &template, &device)?;
        write_atomic(&eval_file, &serde_json::to_vec_pretty(&eval)?)?;
        evals.push(eval);
    }
    let md = tables(&evals, &args.size, &args.device);
    write_atomic(&args.out.join("ablation.md"), md.as_bytes())?;
    let summary = json!({ "size": args.size, "device": args.device, "variants": evals });
    write_atomic(
        &args.out.join("ablation.json"),
        &serde_json::to_vec_pretty(&summary)?,
    )?;
    Ok(json!({ "out": args.out, "report": args.out.join("ablation.md"), "variants": evals.len() }))
}

/// papers/002 Tables 3–6 and A.1 from the evaluations present.
pub fn tables(evals: &[Eval], size: &AblateSize, device: &str) -> String {
    let mut md = String::new();
    let _ = writeln!(
        md,
        "# Ablations of the neural fitter (papers/002 Tables 3–6, A.1)\n"
    );
    let _ = writeln!(
        md,
        "Command: `{}`\n",
        std::env::args().collect::<Vec<_>>().join(" ")
    );
    let _ = writeln!(
        md,
        "Training budget per variant: {} steps × batch {} = {} synthetic frames, GRU/MLP width H = {}, on `{device}` (papers/002: width 1024, batch 512 on 4 GPUs, 400+ epochs). \
Every variant starts from Φ(D) and runs N = 5 iterations; test set: {} held-out frames (local scenario, noise and occlusion on). \
Errors are means over the test frames; V2V FB = full body, H = head, L / R = hands (vertices whose largest skinning weight is that joint's), \
JntErr = MPJPE, GrPe = mean depth of the vertices below the floor.\n",
        size.steps,
        size.batch,
        size.steps * size.batch,
        size.hidden,
        size.test_frames
    );
    let find = |table: &str| -> Vec<(&str, &Eval)> {
        let mut rows = Vec::new();
        for v in VARIANTS {
            for (t, label) in v.rows {
                if *t == table
                    && let Some(e) = evals.iter().find(|e| e.variant == v.name)
                {
                    rows.push((*label, e));
                }
            }
        }
        rows
    };
    let hmd = [
        (
            "3",
            "Weights",
            "Table 3 (HMD): shared vs per-step network weights.",
        ),
        (
            "4",
            "Network structure",
            "Table 4 (HMD): residual MLP (ResNet) vs GRU with one or two layers of H units.",
        ),
        (
            "5",
            "Update rule",
            "Table 5 (HMD): the network's Δθ alone (LGD) vs eq. (1); the two convex rules of supp. eq. (10) for completeness.",
        ),
        (
            "6",
            "Learning rate γ",
            "Table 6 (HMD): constant γ = 1e-4 vs learned.",
        ),
    ];
    for (t, head, caption) in hmd {
        let rows = find(t);
        if rows.is_empty() {
            continue;
        }
        let _ = writeln!(md, "## {caption}\n");
        let _ = writeln!(
            md,
            "| {head} | V2V FB (mm) ↓ | H | L / R | JntErr (mm) ↓ | GrPe (mm) ↓ | parameters | train time (s) |"
        );
        let _ = writeln!(md, "|---|---|---|---|---|---|---|---|");
        for (label, e) in rows {
            let _ = writeln!(
                md,
                "| {label} | {:.1} | {:.1} | {:.1} / {:.1} | {:.1} | {:.2} | {} | {:.0} |",
                e.v2v_mm,
                e.head_v2v_mm,
                e.l_hand_v2v_mm,
                e.r_hand_v2v_mm,
                e.mpjpe_mm,
                e.ground_penetration_mm,
                e.parameters,
                e.train_time_s
            );
        }
        let _ = writeln!(md);
    }
    let rows = find("A.1");
    if !rows.is_empty() {
        let _ = writeln!(
            md,
            "## Table A.1 (2D keypoints): vector vs scalar λ and γ, one network for both or two.\n"
        );
        let _ = writeln!(
            md,
            "| Vector λ | Vector γ | Shared network for λ, γ | PA-MPJPE (mm) | V2V (mm) | parameters |"
        );
        let _ = writeln!(md, "|---|---|---|---|---|---|");
        for (label, e) in rows {
            let cells = label.replace('|', " | ");
            let _ = writeln!(
                md,
                "| {cells} | {:.1} | {:.1} | {} |",
                e.pa_mpjpe_mm, e.v2v_mm, e.parameters
            );
        }
        let _ = writeln!(md);
    }
    md
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_variant_changes_only_its_switch_and_builds() {
        let size = AblateSize {
            steps: 3,
            batch: 2,
            hidden: 8,
            test_frames: 4,
        };
        let hmd_base = variant_config(&VARIANTS[0], &size, 1).unwrap().network;
        let mut seen = std::collections::HashSet::new();
        for v in VARIANTS {
            assert!(seen.insert(v.name), "{} twice", v.name);
            let c = variant_config(v, &size, 1).unwrap();
            assert_eq!(c.modality, v.modality);
            assert_eq!(
                (c.steps, c.batch, c.network.hidden, c.network.start),
                (3, 2, 8, StartMode::Phi)
            );
            if v.modality == Modality::Hmd && v.name != "hmd-base" {
                assert_ne!(c.network, hmd_base, "{} must differ from the base", v.name);
            }
        }
        // Table A.1's four rows are four different networks.
        let a1: Vec<NetConfig> = VARIANTS
            .iter()
            .filter(|v| v.rows.iter().any(|(t, _)| *t == "A.1"))
            .map(|v| variant_config(v, &size, 1).unwrap().network)
            .collect();
        assert_eq!(a1.len(), 4);
        for i in 0..4 {
            for j in 0..i {
                assert_ne!(a1[i], a1[j]);
            }
        }
    }

    #[test]
    fn tables_put_each_variant_in_its_rows() {
        let e = |name: &str, v2v: f64| Eval {
            variant: name.into(),
            frames: 10,
            v2v_mm: v2v,
            head_v2v_mm: 1.0,
            l_hand_v2v_mm: 2.0,
            r_hand_v2v_mm: 3.0,
            mpjpe_mm: 4.0,
            pa_mpjpe_mm: 5.0,
            ground_penetration_mm: 0.5,
            parameters: 100,
            train_time_s: 1.0,
            steps: 3,
        };
        let md = tables(
            &[
                e("hmd-base", 11.0),
                e("hmd-per-step", 12.0),
                e("kp-vl-vg-shared", 13.0),
            ],
            &AblateSize::new(true),
            "flex",
        );
        assert!(
            md.contains("| Shared | 11.0 |") && md.contains("| Per-step | 12.0 |"),
            "{md}"
        );
        // The base is the reference row of Tables 4–6 too.
        assert!(
            md.contains("| +Eq. 1 | 11.0 |") && md.contains("| Learned | 11.0 |"),
            "{md}"
        );
        assert!(md.contains("| ✓ | ✓ | ✓ | 5.0 | 13.0 |"), "{md}");
        assert!(!md.contains("| ResNet |"), "variants not run have no row");
    }
}
