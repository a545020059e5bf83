//! The fitting loop of papers/002 Alg. 1 with the network executed by ONNX Runtime (`ort`,
//! `load-dynamic`): the energy side (residuals, gradients, features, masks, bounds) is the very
//! code of the Burn loop ([`lfit_nn::unroll`]'s helpers); only the three network
//! calls go to ONNX Runtime sessions of the graphs from [`super::export`].

use std::path::{Path, PathBuf};
use std::sync::OnceLock;

use lfit_nn::NetConfig;
use lfit_nn::checkpoint::{self, CheckpointMeta};
use lfit_nn::features::FeatureStats;
pub use lfit_nn::unroll::StepOut;
use lfit_nn::unroll::{RowNetwork, RowState};
use ort::environment::Environment;
use ort::session::Session;
use ort::session::builder::GraphOptimizationLevel;
use ort::value::Tensor;
use prost::Message;

use super::export::{Exported, graph_files};
use super::proto::ModelProto;
use super::{FORMAT, ORT_RELEASE, OnnxError, VERSION, keys};

/// Where the ONNX Runtime library is looked for: `ORT_DYLIB_PATH`, else where
/// `scripts/fetch-onnxruntime.sh` puts it (`$LFIT_TOOLS_DIR` or `~/.cache/lfit-tools`).
pub fn library_path() -> PathBuf {
    if let Some(p) = std::env::var_os("ORT_DYLIB_PATH") {
        return PathBuf::from(p);
    }
    let tools = std::env::var_os("LFIT_TOOLS_DIR")
        .map(PathBuf::from)
        .or_else(|| std::env::var_os("HOME").map(|h| PathBuf::from(h).join(".cache/lfit-tools")))
        .unwrap_or_else(|| PathBuf::from(".cache/lfit-tools"));
    tools
        .join(format!("onnxruntime-{ORT_RELEASE}"))
        .join(format!("libonnxruntime.so.{ORT_RELEASE}"))
}

static ENVIRONMENT: OnceLock<Result<Environment, String>> = OnceLock::new();

/// The process-wide ONNX Runtime environment, loading the library on first use.
pub fn environment() -> Result<&'static Environment, OnnxError> {
    let result = ENVIRONMENT.get_or_init(|| {
        let path = library_path();
        let how = format!("get it with scripts/fetch-onnxruntime.sh (the onnxruntime=={ORT_RELEASE} wheel from PyPI) or set ORT_DYLIB_PATH to libonnxruntime.so");
        if !path.is_file() {
            return Err(format!("ONNX Runtime library not found at {}: {how}", path.display()));
        }
        let builder = ort::init_from(&path).map_err(|e| format!("cannot load the ONNX Runtime library {}: {e}; {how}", path.display()))?;
        builder.with_name("lfit").with_telemetry(false).build().map_err(|e| format!("cannot start ONNX Runtime: {e}"))
    });
    result.as_ref().map_err(|e| OnnxError::Library(e.clone()))
}

/// Metadata of one exported graph, checked against this build's format and version.
#[derive(Debug, Clone)]
pub struct GraphInfo {
    pub role: String,
    pub weight_set: usize,
    pub checkpoint: String,
    pub stats: String,
}

/// Reads and checks the metadata of an ONNX file's bytes (`origin` names it in errors).
pub fn graph_info(bytes: &[u8], origin: &Path) -> Result<GraphInfo, OnnxError> {
    let model = ModelProto::decode(bytes)
        .map_err(|e| OnnxError::model(origin, format!("not an ONNX model: {e}")))?;
    let get = |k: &str| {
        model
            .metadata_props
            .iter()
            .find(|p| p.key == k)
            .map(|p| p.value.clone())
    };
    match get(keys::FORMAT) {
        Some(f) if f == FORMAT => {}
        Some(f) => {
            return Err(OnnxError::model(
                origin,
                format!("metadata {} is '{f}', not '{FORMAT}'", keys::FORMAT),
            ));
        }
        None => {
            return Err(OnnxError::model(
                origin,
                format!("not an lfit export (no {} metadata)", keys::FORMAT),
            ));
        }
    }
    let version = get(keys::VERSION).unwrap_or_default();
    if version != VERSION.to_string() {
        return Err(OnnxError::model(
            origin,
            format!(
                "lfit ONNX version '{version}' is not supported (this build reads version {VERSION})"
            ),
        ));
    }
    let field =
        |k: &str| get(k).ok_or_else(|| OnnxError::model(origin, format!("metadata lacks {k}")));
    let weight_set = field(keys::WEIGHT_SET)?.parse().map_err(|_| {
        OnnxError::model(
            origin,
            format!("metadata {} is not a number", keys::WEIGHT_SET),
        )
    })?;
    Ok(GraphInfo {
        role: field(keys::ROLE)?,
        weight_set,
        checkpoint: field(keys::CHECKPOINT)?,
        stats: field(keys::FEATURE_STATS)?,
    })
}

impl GraphInfo {
    /// The checkpoint's `config.json` carried in the metadata (`origin` names the file).
    pub fn meta(&self, origin: &Path) -> Result<CheckpointMeta, OnnxError> {
        serde_json::from_str(&self.checkpoint).map_err(|e| {
            OnnxError::model(
                origin,
                format!("malformed {} metadata: {e}", keys::CHECKPOINT),
            )
        })
    }
}

/// The exported graphs of one checkpoint in ONNX Runtime sessions.
#[derive(Debug)]
pub struct OrtNetwork {
    pub meta: CheckpointMeta,
    pub stats: FeatureStats,
    init: Session,
    propose: Vec<Session>,
    step: Vec<Session>,
}

/// Recurrent state of a batch: per GRU layer of `f`, of fλ(γ) and of a separate fγ.
pub type OrtState = RowState;

fn runtime(e: impl std::fmt::Display) -> OnnxError {
    OnnxError::Runtime(e.to_string())
}

/// Settings of the ONNX Runtime sessions.
#[derive(Debug, Clone, Copy, Default)]
pub struct SessionOptions {
    /// Intra-op threads (`None`: ONNX Runtime's default, one per core).
    pub threads: Option<usize>,
}

fn session(bytes: &[u8], options: SessionOptions) -> Result<Session, OnnxError> {
    let env = environment()?;
    let mut builder = Session::builder(env)
        .map_err(runtime)?
        .with_optimization_level(GraphOptimizationLevel::All)
        .map_err(runtime)?;
    if let Some(t) = options.threads {
        builder = builder.with_intra_threads(t).map_err(runtime)?;
    }
    builder.commit_from_memory(bytes).map_err(runtime)
}

impl OrtNetwork {
    /// Sessions of exported graphs (`origin`: where they came from, for errors).
    pub fn from_exported(
        exported: &Exported,
        origin: &Path,
        options: SessionOptions,
    ) -> Result<Self, OnnxError> {
        let mut infos = Vec::new();
        for (name, bytes) in &exported.files {
            infos.push((name.clone(), graph_info(bytes, &origin.join(name))?));
        }
        let init_info = infos
            .iter()
            .find(|(_, i)| i.role == "init")
            .map(|(_, i)| i.clone())
            .ok_or_else(|| OnnxError::model(origin, "no init.onnx"))?;
        let meta = init_info.meta(&origin.join("init.onnx"))?;
        if meta.format != checkpoint::FORMAT || meta.version != checkpoint::VERSION {
            return Err(OnnxError::model(
                origin,
                format!(
                    "exported from checkpoint version {} of format '{}', this build reads {} version {}",
                    meta.version,
                    meta.format,
                    checkpoint::FORMAT,
                    checkpoint::VERSION
                ),
            ));
        }
        meta.network
            .validate()
            .map_err(|e| OnnxError::model(origin, e.to_string()))?;
        let stats: FeatureStats = serde_json::from_str(&init_info.stats).map_err(|e| {
            OnnxError::model(
                origin,
                format!("malformed {} metadata: {e}", keys::FEATURE_STATS),
            )
        })?;
        stats
            .validate(&meta.network)
            .map_err(|e| OnnxError::model(origin, e.to_string()))?;
        for (name, info) in &infos {
            if info.checkpoint != init_info.checkpoint || info.stats != init_info.stats {
                return Err(OnnxError::model(
                    &origin.join(name),
                    "exported from another checkpoint than init.onnx",
                ));
            }
        }
        let (mut init, mut propose, mut step) = (None, Vec::new(), Vec::new());
        for (role, s, name) in graph_files(&meta.network) {
            let bytes = exported
                .files
                .iter()
                .zip(&infos)
                .find(|((n, _), (_, i))| *n == name && i.role == role && i.weight_set == s)
                .map(|((_, b), _)| b.as_slice())
                .ok_or_else(|| OnnxError::model(origin, format!("missing {name}")))?;
            let session = session(bytes, options)?;
            match role {
                "init" => init = Some(session),
                "propose" => propose.push(session),
                _ => step.push(session),
            }
        }
        let init = init.ok_or_else(|| OnnxError::model(origin, "no init.onnx"))?;
        Ok(Self {
            meta,
            stats,
            init,
            propose,
            step,
        })
    }

    /// Sessions of a directory written by `lfit export-onnx`.
    pub fn load_dir(dir: &Path, options: SessionOptions) -> Result<Self, OnnxError> {
        let init = dir.join("init.onnx");
        let bytes = std::fs::read(&init)
            .map_err(|e| OnnxError::model(&init, format!("cannot read: {e}")))?;
        let meta = graph_info(&bytes, &init)?.meta(&init)?;
        let mut files = vec![("init.onnx".to_string(), bytes)];
        for (_, _, name) in graph_files(&meta.network).into_iter().skip(1) {
            let path = dir.join(&name);
            files.push((
                name,
                std::fs::read(&path)
                    .map_err(|e| OnnxError::model(&path, format!("cannot read: {e}")))?,
            ));
        }
        Self::from_exported(&Exported { files }, dir, options)
    }
}

/// The loop of [`lfit_nn::unroll::unroll_rows`] with the network in these sessions.
impl RowNetwork for OrtNetwork {
    type Error = OnnxError;

    fn config(&self) -> &NetConfig {
        &self.meta.network
    }

    fn stats(&self) -> &FeatureStats {
        &self.stats
    }

    /// θ0 = Φ(D) `[B, param_dim]` and the initial state, from normalised observations `[B, 2R]`.
    fn initial(&mut self, obs: &[f32], batch: usize) -> Result<(Vec<f32>, OrtState), OnnxError> {
        let c = &self.meta.network;
        let layers = c.recurrent_layers();
        let inputs = vec![("obs".to_string(), tensor(obs, batch, c.obs_features())?)];
        let mut out = self.init.run(inputs).map_err(runtime)?;
        let theta0 = extract(&mut out, "theta0", batch * c.param_dim)?;
        let core = (0..layers)
            .map(|l| extract(&mut out, &format!("h0.{l}"), batch * c.hidden))
            .collect::<Result<Vec<_>, _>>()?;
        Ok((theta0, RowState::zeros(c, batch, core)))
    }

    /// Δθ of iteration `n` from the normalised core inputs; updates the core state.
    fn propose(
        &mut self,
        n: usize,
        core_in: &[f32],
        batch: usize,
        state: &mut OrtState,
    ) -> Result<Vec<f32>, OnnxError> {
        let c = &self.meta.network;
        let s = c.weight_set(n);
        let mut inputs = vec![(
            "core_in".to_string(),
            tensor(core_in, batch, c.core_inputs())?,
        )];
        for (l, h) in state.core.iter().enumerate() {
            inputs.push((format!("h.{l}"), tensor(h, batch, c.hidden)?));
        }
        let mut out = self.propose[s].run(inputs).map_err(runtime)?;
        let delta = extract(&mut out, "delta", batch * c.param_dim)?;
        for l in 0..state.core.len() {
            state.core[l] = extract(&mut out, &format!("h_next.{l}"), batch * c.hidden)?;
        }
        Ok(delta)
    }

    /// λ, γ and the update of iteration `n`; updates the λ/γ states. `delta` and `grad` are
    /// already masked.
    fn step(
        &mut self,
        n: usize,
        step_in: &[f32],
        delta: &[f32],
        grad: &[f32],
        batch: usize,
        state: &mut OrtState,
    ) -> Result<StepOut, OnnxError> {
        let c = &self.meta.network;
        let s = c.weight_set(n);
        let mut inputs = vec![
            (
                "step_in".to_string(),
                tensor(step_in, batch, c.step_inputs())?,
            ),
            ("delta".to_string(), tensor(delta, batch, c.param_dim)?),
            ("grad".to_string(), tensor(grad, batch, c.param_dim)?),
        ];
        for (l, h) in state.lambda.iter().enumerate() {
            inputs.push((format!("lambda_h.{l}"), tensor(h, batch, c.hidden)?));
        }
        for (l, h) in state.gamma.iter().enumerate() {
            inputs.push((format!("gamma_h.{l}"), tensor(h, batch, c.hidden)?));
        }
        let mut out = self.step[s].run(inputs).map_err(runtime)?;
        let result = StepOut {
            update: extract(&mut out, "update", batch * c.param_dim)?,
            lambda: extract(&mut out, "lambda", batch * c.step_outputs())?,
            gamma: extract(&mut out, "gamma", batch * c.gamma_outputs())?,
        };
        for l in 0..state.lambda.len() {
            state.lambda[l] = extract(&mut out, &format!("lambda_h_next.{l}"), batch * c.hidden)?;
        }
        for l in 0..state.gamma.len() {
            state.gamma[l] = extract(&mut out, &format!("gamma_h_next.{l}"), batch * c.hidden)?;
        }
        Ok(result)
    }
}

fn tensor(values: &[f32], batch: usize, width: usize) -> Result<Tensor<f32>, OnnxError> {
    if values.len() != batch * width {
        return Err(OnnxError::Runtime(format!(
            "input of {} values for a [{batch}, {width}] tensor",
            values.len()
        )));
    }
    Tensor::from_array(([batch, width], values.to_vec())).map_err(runtime)
}

fn extract(
    out: &mut ort::session::SessionOutputs<'_>,
    name: &str,
    len: usize,
) -> Result<Vec<f32>, OnnxError> {
    let value = out
        .get(name)
        .ok_or_else(|| OnnxError::Runtime(format!("the graph has no output '{name}'")))?;
    let (_, data) = value.try_extract_tensor::<f32>().map_err(runtime)?;
    if data.len() != len {
        return Err(OnnxError::Runtime(format!(
            "output '{name}' has {} values, expected {len}",
            data.len()
        )));
    }
    Ok(data.to_vec())
}
