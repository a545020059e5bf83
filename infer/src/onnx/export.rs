//! The neural fitter as standard ONNX (opset 17): three graphs per checkpoint, with everything a
//! foreign runtime needs to run the fitting loop in their metadata.
//!
//! | file | inputs | outputs |
//! |---|---|---|
//! | `init.onnx` | `obs` `[B, 2R]` | `theta0` `[B, 57]`, `h0.l` `[B, H]` per GRU layer of `f` |
//! | `propose.onnx` | `core_in` `[B, R+114+2R]`, `h.l` | `delta` `[B, 57]`, `h_next.l` |
//! | `step.onnx` | `step_in` `[B, 2R]`, `delta`, `grad` `[B, 57]`, `lambda_h.l`, `gamma_h.l` | `update` `[B, 57]`, `lambda`, `gamma`, `lambda_h_next.l`, `gamma_h_next.l` |
//!
//! All inputs are the *normalised* features of [`lfit_nn::features`] (the statistics
//! are in the metadata), except `delta` (the masked output of `propose`) and `grad` (the raw,
//! masked energy gradient). One iteration n of papers/002 Alg. 1 is: R(θ), g(θ) from the energy;
//! `propose`; R(θ + Δθ) from the energy; `step`; θ ← clamp(θ + update). The file list is
//! [`graph_files`].
//!
//! The layer-normalized GRU (supp. eq. 12) is written out with `Gemm`, `LayerNormalization`,
//! `Sigmoid`, `Tanh`, `Mul`, `Sub` and `Add`; Φ/Φh use `Gemm`, `BatchNormalization` (running
//! statistics) and `Relu`.

use std::collections::BTreeMap;
use std::path::Path;

use lfit_model::pose::{DofMask, POSE_DIM, dof_name};
use lfit_nn::checkpoint::{self, CheckpointMeta};
use lfit_nn::config::UpdateRule;
use lfit_nn::features::FeatureStats;
use lfit_nn::layers::{InitMlp, LnGruCell};
use lfit_nn::net::Core;
use lfit_nn::{NetConfig, NeuralNet};
use prost::Message;

use super::graph::{Graph, attr_int};
use super::proto::{ModelProto, OperatorSetIdProto, StringStringEntryProto};
use super::{FORMAT, OPSET, OnnxError, VERSION, keys};

/// The encoded graphs of one checkpoint.
#[derive(Debug, Clone)]
pub struct Exported {
    /// `(file name, ONNX bytes)`, init first.
    pub files: Vec<(String, Vec<u8>)>,
}

/// The graphs of a network configuration as `(role, weight set, file name)`, init first:
/// `init.onnx`, then per weight set `propose` and (with a λ/γ network) `step`, numbered
/// `propose.s.onnx` when there are several sets.
pub fn graph_files(c: &NetConfig) -> Vec<(&'static str, usize, String)> {
    let sets = c.weight_sets();
    let name = |role: &str, s: usize| {
        if sets > 1 {
            format!("{role}.{s}.onnx")
        } else {
            format!("{role}.onnx")
        }
    };
    let mut files = vec![("init", 0, "init.onnx".to_string())];
    for s in 0..sets {
        files.push(("propose", s, name("propose", s)));
        if c.has_step_network() {
            files.push(("step", s, name("step", s)));
        }
    }
    files
}

fn gru_cell(
    g: &mut Graph,
    x: &str,
    h: &str,
    cell: &LnGruCell,
    p: &str,
) -> Result<String, OnnxError> {
    let hd = cell.hidden;
    let wz = g.linear_cols(x, &cell.w, 0, hd, &format!("{p}.w_z"))?;
    let wr = g.linear_cols(x, &cell.w, hd, hd, &format!("{p}.w_r"))?;
    let wh = g.linear_cols(x, &cell.w, 2 * hd, hd, &format!("{p}.w_h"))?;
    let uz = g.linear_cols(h, &cell.u_zr, 0, hd, &format!("{p}.u_z"))?;
    let ur = g.linear_cols(h, &cell.u_zr, hd, hd, &format!("{p}.u_r"))?;
    let (a, b) = (
        g.layer_norm(&wz, &cell.ln_wz, &format!("{p}.ln_wz"))?,
        g.layer_norm(&uz, &cell.ln_uz, &format!("{p}.ln_uz"))?,
    );
    let s = g.add(&a, &b);
    let z = g.unary("Sigmoid", &s);
    let (a, b) = (
        g.layer_norm(&wr, &cell.ln_wr, &format!("{p}.ln_wr"))?,
        g.layer_norm(&ur, &cell.ln_ur, &format!("{p}.ln_ur"))?,
    );
    let s = g.add(&a, &b);
    let r = g.unary("Sigmoid", &s);
    let rh = g.mul(&r, h);
    let uh = g.linear(&rh, &cell.u_h, &format!("{p}.u_h"))?;
    let (a, b) = (
        g.layer_norm(&wh, &cell.ln_wh, &format!("{p}.ln_wh"))?,
        g.layer_norm(&uh, &cell.ln_uh, &format!("{p}.ln_uh"))?,
    );
    let s = g.add(&a, &b);
    let cand = g.unary("Tanh", &s);
    let one = g.scalar(1.0);
    let one_minus_z = g.sub(&one, &z);
    let keep = g.mul(&one_minus_z, h);
    let take = g.mul(&z, &cand);
    Ok(g.add(&keep, &take))
}

/// The core on `x` with the given states (GRU: one per layer); returns the output and the new
/// states.
fn core(
    g: &mut Graph,
    x: &str,
    states: &[String],
    core: &Core,
    p: &str,
) -> Result<(String, Vec<String>), OnnxError> {
    match (&core.gru, &core.mlp) {
        (Some(gru), _) => {
            let mut input = x.to_string();
            let mut next = Vec::new();
            for (l, (cell, h)) in gru.cells.iter().zip(states).enumerate() {
                input = gru_cell(g, &input, h, cell, &format!("{p}.gru{l}"))?;
                next.push(input.clone());
            }
            Ok((input, next))
        }
        (None, Some(mlp)) => {
            let y = g.linear(x, &mlp.input, &format!("{p}.mlp_in"))?;
            let mut y = g.unary("Relu", &y);
            for (l, block) in mlp.blocks.iter().enumerate() {
                let b = g.linear(&y, block, &format!("{p}.mlp{l}"))?;
                let b = g.unary("Relu", &b);
                y = g.add(&y, &b);
            }
            Ok((y, Vec::new()))
        }
        (None, None) => Err(OnnxError::Export("a core without GRU or MLP".into())),
    }
}

fn state_inputs(g: &mut Graph, prefix: &str, layers: usize, hidden: usize) -> Vec<String> {
    (0..layers)
        .map(|l| {
            g.input(
                &format!("{prefix}.{l}"),
                hidden,
                "GRU state of this layer (zeros before the first iteration of fλγ)",
            )
        })
        .collect()
}

fn init_graph(net: &NeuralNet) -> Result<Graph, OnnxError> {
    let c = &net.config;
    let mut g = Graph::new("lfit_init");
    let obs = g.input("obs", c.obs_features(), "normalised observation features D");
    let mlp = |g: &mut Graph, m: &InitMlp, p: &str| -> Result<(String, String), OnnxError> {
        let y = g.linear(&obs, &m.l1, &format!("{p}.l1"))?;
        let y = g.batch_norm(&y, &m.bn1, &format!("{p}.bn1"))?;
        let y = g.unary("Relu", &y);
        let y = g.linear(&y, &m.l2, &format!("{p}.l2"))?;
        let y = g.batch_norm(&y, &m.bn2, &format!("{p}.bn2"))?;
        Ok((g.unary("Relu", &y), p.to_string()))
    };
    let (y, p) = mlp(&mut g, &net.phi, "phi")?;
    let theta0 = g.linear(&y, &net.phi.out, &format!("{p}.out"))?;
    g.output(&theta0, "theta0", c.param_dim, "θ0 = Φ(D)");
    if let Some(phi_h) = &net.phi_h {
        let (y, p) = mlp(&mut g, phi_h, "phi_h")?;
        for l in 0..c.layers {
            let h = g.linear_cols(
                &y,
                &phi_h.out,
                l * c.hidden,
                c.hidden,
                &format!("{p}.out{l}"),
            )?;
            g.output(
                &h,
                &format!("h0.{l}"),
                c.hidden,
                "initial state of this GRU layer of f, Φh(D)",
            );
        }
    }
    Ok(g)
}

fn propose_graph(net: &NeuralNet, set: usize) -> Result<Graph, OnnxError> {
    let c = &net.config;
    let mut g = Graph::new("lfit_propose");
    let x = g.input("core_in", c.core_inputs(), "normalised [R(θ), g(θ), θ, D]");
    let states = state_inputs(&mut g, "h", c.recurrent_layers(), c.hidden);
    let (out, next) = core(&mut g, &x, &states, &net.cores[set], "f")?;
    let delta = g.linear(&out, &net.delta_heads[set], "delta_head")?;
    g.output(
        &delta,
        "delta",
        c.param_dim,
        "Δθ (multiply by the DOF mask before using it)",
    );
    for (l, h) in next.iter().enumerate() {
        g.output(
            h,
            &format!("h_next.{l}"),
            c.hidden,
            "new state of this GRU layer of f",
        );
    }
    Ok(g)
}

fn step_graph(net: &NeuralNet, set: usize) -> Result<Graph, OnnxError> {
    let c = &net.config;
    let step = &net.steps[set];
    let (k, kg) = (c.step_outputs(), c.gamma_outputs());
    let mut g = Graph::new("lfit_step");
    let x = g.input("step_in", c.step_inputs(), "normalised [R(θ), R(θ + Δθ)]");
    let delta = g.input("delta", c.param_dim, "Δθ from propose, masked");
    let grad = g.input("grad", c.param_dim, "energy gradient g(θ), raw, masked");
    let layers = c.recurrent_layers();
    let lambda_states = state_inputs(&mut g, "lambda_h", layers, c.hidden);
    let separate = c.separate_gamma_network();
    let gamma_states = if separate {
        state_inputs(&mut g, "gamma_h", layers, c.hidden)
    } else {
        Vec::new()
    };

    let (out, lambda_next) = core(&mut g, &x, &lambda_states, &step.lambda_core, "f_lambda")?;
    let (a, b, gamma_next) = match (&step.gamma_core, &step.gamma_head) {
        (Some(gc), Some(gh)) => {
            let a = g.linear(&out, &step.lambda_head, "lambda_head")?;
            let (gout, next) = core(&mut g, &x, &gamma_states, gc, "f_gamma")?;
            (a, Some(g.linear(&gout, gh, "gamma_head")?), next)
        }
        _ if c.learns_gamma() => (
            g.linear_cols(&out, &step.lambda_head, 0, k, "lambda_head")?,
            Some(g.linear_cols(&out, &step.lambda_head, k, kg, "gamma_head")?),
            Vec::new(),
        ),
        _ => (
            g.linear(&out, &step.lambda_head, "lambda_head")?,
            None,
            Vec::new(),
        ),
    };
    let lambda = match c.update {
        UpdateRule::Eq1 => {
            let one = g.scalar(1.0);
            g.add(&a, &one)
        }
        _ => g.unary("Sigmoid", &a),
    };
    let gamma = match b {
        Some(b) => {
            let sp = g.unary("Softplus", &b);
            let scale = g.scalar((c.gamma_init / std::f64::consts::LN_2) as f32);
            g.mul(&sp, &scale)
        }
        None => {
            // γ = constant, expanded to [B, kg].
            let shape = g.node("Shape", &[&x], vec![]);
            let (s0, s1) = (g.init_i64("zero", &[0]), g.init_i64("one", &[1]));
            let batch = g.node("Slice", &[&shape, &s0, &s1], vec![]);
            let width = g.init_i64("gamma_width", &[kg as i64]);
            let target = g.node("Concat", &[&batch, &width], vec![attr_int("axis", 0)]);
            let value = g.init(
                "gamma_constant",
                &[1, kg],
                &vec![c.gamma_constant as f32; kg],
            );
            g.node("Expand", &[&value, &target], vec![])
        }
    };
    let update = match c.update {
        UpdateRule::DeltaOnly => {
            return Err(OnnxError::Export(
                "the Δθ-only rule has no step network".into(),
            ));
        }
        UpdateRule::Eq1 => {
            let ld = g.mul(&lambda, &delta);
            let gg = g.mul(&gamma, &grad);
            g.sub(&ld, &gg)
        }
        UpdateRule::Convex => {
            let one = g.scalar(1.0);
            let om = g.sub(&one, &lambda);
            let ld = g.mul(&lambda, &delta);
            let omg = g.mul(&om, &gamma);
            let gg = g.mul(&omg, &grad);
            g.sub(&ld, &gg)
        }
        UpdateRule::ConvexNormalized => {
            let axes = g.init_i64("axes", &[1]);
            let eps = g.scalar(1e-12);
            let unit = |g: &mut Graph, v: &str| {
                let sq = g.mul(v, v);
                let sum = g.node("ReduceSum", &[&sq, &axes], vec![attr_int("keepdims", 1)]);
                let sum = g.add(&sum, &eps);
                let norm = g.unary("Sqrt", &sum);
                g.node("Div", &[v, &norm], vec![])
            };
            let ud = unit(&mut g, &delta);
            let ug = unit(&mut g, &grad);
            let one = g.scalar(1.0);
            let om = g.sub(&one, &lambda);
            let ld = g.mul(&lambda, &ud);
            let og = g.mul(&om, &ug);
            let diff = g.sub(&ld, &og);
            g.mul(&gamma, &diff)
        }
    };
    g.output(
        &update,
        "update",
        c.param_dim,
        "θn − θ(n−1) before clamping to the bounds",
    );
    g.output(&lambda, "lambda", k, "λ");
    g.output(&gamma, "gamma", kg, "γ");
    for (l, h) in lambda_next.iter().enumerate() {
        g.output(
            h,
            &format!("lambda_h_next.{l}"),
            c.hidden,
            "new state of this GRU layer of fλ(γ)",
        );
    }
    for (l, h) in gamma_next.iter().enumerate() {
        g.output(
            h,
            &format!("gamma_h_next.{l}"),
            c.hidden,
            "new state of this GRU layer of fγ",
        );
    }
    Ok(g)
}

/// Metadata common to every graph of a checkpoint.
fn metadata(
    meta: &CheckpointMeta,
    stats: &FeatureStats,
    role: &str,
    set: usize,
) -> Result<Vec<StringStringEntryProto>, OnnxError> {
    let c = &meta.network;
    let json = |v: serde_json::Result<String>| {
        v.map_err(|e| OnnxError::Export(format!("cannot serialise metadata: {e}")))
    };
    // Entry names from the model's layout; checkpoints without a model signature are of the
    // default template (57 entries).
    let names: Vec<String> = match &meta.model {
        Some(sig) => sig.layout.names(),
        None => (0..POSE_DIM).map(dof_name).collect(),
    };
    let mask = if c.param_dim == POSE_DIM
        && meta
            .model
            .as_ref()
            .is_none_or(|m| m.layout.shape + m.layout.expression == 0)
    {
        DofMask::full57()
    } else if let Some(sig) = meta.model.as_ref().filter(|_| c.known_shape) {
        // Trained with the shape known (papers/002 §3.2): β is an input held fixed.
        let shape = sig.layout.range(lfit_model::Block::Shape);
        DofMask {
            name: format!("full{}-known-shape", c.param_dim),
            free: (0..c.param_dim).filter(|i| !shape.contains(i)).collect(),
        }
    } else {
        DofMask {
            name: format!("full{}", c.param_dim),
            free: (0..c.param_dim).collect(),
        }
    };
    let note = if c.known_shape {
        "the network updates the pose; the shape β is known: set it in θ0, freeze it (mask 0) and bound it to itself (lower = upper = β); a fit multiplies Δθ and g by its mask of free DOFs (1 free, 0 frozen) and clamps θ into its bounds after each update"
    } else {
        "the network updates every pose parameter; a fit multiplies Δθ and g by its own mask of free DOFs (1 free, 0 frozen) and clamps θ into its bounds after each update"
    };
    let dof = serde_json::json!({
        "mask": mask.name,
        "free": mask.free,
        "names": names,
        "note": note,
    });
    let entries: BTreeMap<&str, String> = BTreeMap::from([
        (keys::FORMAT, FORMAT.to_string()),
        (keys::VERSION, VERSION.to_string()),
        (keys::ROLE, role.to_string()),
        (keys::WEIGHT_SET, set.to_string()),
        (keys::WEIGHT_SETS, c.weight_sets().to_string()),
        (keys::MODALITY, c.modality.to_string()),
        (keys::ITERATIONS, c.iterations.to_string()),
        (keys::RESIDUAL_DIM, c.residual_dim.to_string()),
        (keys::DOF_MASK, json(serde_json::to_string(&dof))?),
        (keys::CHECKPOINT, json(serde_json::to_string(meta))?),
        (keys::FEATURE_STATS, json(serde_json::to_string(stats))?),
        (keys::FEATURE_CLIP, c.feature_clip.to_string()),
    ]);
    Ok(entries
        .into_iter()
        .map(|(key, value)| StringStringEntryProto {
            key: key.into(),
            value,
        })
        .collect())
}

fn model(graph: Graph, metadata: Vec<StringStringEntryProto>, doc: &str) -> Vec<u8> {
    ModelProto {
        ir_version: 8,
        opset_import: vec![OperatorSetIdProto {
            domain: String::new(),
            version: OPSET,
        }],
        producer_name: "lfit".into(),
        producer_version: env!("CARGO_PKG_VERSION").into(),
        model_version: i64::from(VERSION),
        doc_string: doc.into(),
        graph: Some(graph.proto),
        metadata_props: metadata,
        ..Default::default()
    }
    .encode_to_vec()
}

/// The ONNX graphs of a network with its checkpoint metadata and feature statistics.
pub fn export(
    net: &NeuralNet,
    meta: &CheckpointMeta,
    stats: &FeatureStats,
) -> Result<Exported, OnnxError> {
    if meta.format != checkpoint::FORMAT || meta.version != checkpoint::VERSION {
        return Err(OnnxError::Export(format!(
            "checkpoint version {} of format '{}' is not supported (expected {} version {})",
            meta.version,
            meta.format,
            checkpoint::FORMAT,
            checkpoint::VERSION
        )));
    }
    if meta.network != net.config {
        return Err(OnnxError::Export(
            "the network does not match the checkpoint's config.json".into(),
        ));
    }
    let mut files = Vec::new();
    for (role, s, name) in graph_files(&net.config) {
        let (graph, doc) = match role {
            "init" => (
                init_graph(net)?,
                "lfit neural fitter: θ0 = Φ(D), h0 = Φh(D) (papers/002 §3.5)",
            ),
            "propose" => (
                propose_graph(net, s)?,
                "lfit neural fitter: Δθn, hn = f([R, g, θ, D], h(n−1)) (papers/002 Alg. 1)",
            ),
            _ => (
                step_graph(net, s)?,
                "lfit neural fitter: λ, γ = fλγ(R(θ), R(θ + Δθ)) and the update u (papers/002 eq. 1–2)",
            ),
        };
        files.push((name, model(graph, metadata(meta, stats, role, s)?, doc)));
    }
    Ok(Exported { files })
}

/// Loads the checkpoint in `dir` (on the ndarray backend) and exports it; returns its metadata
/// with the graphs.
pub fn export_checkpoint(dir: &Path) -> Result<(CheckpointMeta, Exported), OnnxError> {
    let ckpt = checkpoint::load(dir, &lfit_nn::tensor::ndarray_device())
        .map_err(|e| OnnxError::Io(e.to_string()))?;
    let exported = export(&ckpt.net, &ckpt.meta, &ckpt.stats)?;
    Ok((ckpt.meta, exported))
}

/// Writes the exported files into `dir` (created if missing); each file appears complete or not
/// at all.
pub fn write(dir: &Path, exported: &Exported) -> Result<(), OnnxError> {
    std::fs::create_dir_all(dir).map_err(|e| OnnxError::Io(format!("{}: {e}", dir.display())))?;
    for (name, bytes) in &exported.files {
        lfit_model::template::write_atomic(&dir.join(name), bytes)
            .map_err(|e| OnnxError::Io(e.to_string()))?;
    }
    Ok(())
}
