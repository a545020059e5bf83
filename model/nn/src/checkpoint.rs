//! Checkpoints on disk (SPEC §7): a directory with `config.json` (format, template, network
//! configuration), `weights.bpk` (Burn's burnpack), `stats.json` (feature statistics) and
//! `metrics.json` (the metrics card), plus any extra files the trainer keeps for `--resume`.
//!
//! A checkpoint is written into a sibling temporary directory and swapped in by renames, so a
//! crash never leaves a half-written checkpoint under the final name.

use std::path::{Path, PathBuf};

use burn::store::{BurnpackStore, ModuleSnapshot};
use burn::tensor::{Bytes, Device};
use serde::{Deserialize, Serialize};

use crate::config::NetConfig;
use crate::features::FeatureStats;
use crate::net::NeuralNet;
use lfit_model::error::{ModelError, Result};
use lfit_model::observe::Modality;
use lfit_model::template::Template;

pub const FORMAT: &str = "lfit-checkpoint";
pub const VERSION: u32 = 1;
pub const CONFIG_FILE: &str = "config.json";
pub const WEIGHTS_FILE: &str = "weights.bpk";
pub const STATS_FILE: &str = "stats.json";
pub const METRICS_FILE: &str = "metrics.json";

/// `config.json`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CheckpointMeta {
    pub format: String,
    pub version: u32,
    /// Template the network was trained on (`Template::id`) and its vertex count.
    pub template_id: String,
    pub template_vertices: usize,
    pub network: NetConfig,
    /// The model's signature (layout and hash of its arrays); checkpoints written before models
    /// were data have none and are checked by vertex count and parameter length.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub model: Option<lfit_model::template::ModelSignature>,
    /// The energy the network was trained on, when the training config named one (the face's
    /// eq. 9 energy); absent: the gradient variant of the default energy. A fit with another
    /// energy is refused ([`CheckpointMeta::check_energy`]).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub energy: Option<lfit_model::energy::EnergyConfig>,
}

/// A loaded checkpoint.
#[derive(Debug)]
pub struct Checkpoint {
    pub meta: CheckpointMeta,
    pub stats: FeatureStats,
    pub net: NeuralNet,
    /// `metrics.json` as written by the trainer (`null` if absent).
    pub metrics: serde_json::Value,
}

fn err(path: &Path, reason: impl Into<String>) -> ModelError {
    ModelError::Checkpoint {
        path: path.to_path_buf(),
        reason: reason.into(),
    }
}

/// The weights as burnpack bytes.
pub fn weights_bytes(net: &NeuralNet) -> Result<Vec<u8>> {
    let mut store = BurnpackStore::from_bytes(None);
    net.save_into(&mut store)
        .map_err(|e| ModelError::Backend(format!("cannot serialise weights: {e}")))?;
    let bytes = store
        .get_bytes()
        .map_err(|e| ModelError::Backend(format!("cannot serialise weights: {e}")))?;
    Ok(bytes.to_vec())
}

/// Loads burnpack `bytes` into a network built from `config`; every tensor must be present with
/// the configured shape and no extra tensor may remain.
pub fn net_from_bytes(
    config: &NetConfig,
    bytes: Vec<u8>,
    device: &Device,
    path: &Path,
) -> Result<NeuralNet> {
    let mut net = NeuralNet::new(config, 0, device).map_err(|e| err(path, e.to_string()))?;
    // Partial and unvalidated, so that every problem comes back in the result and is reported
    // here as one line naming the first offending tensor.
    let mut store = BurnpackStore::from_bytes(Some(Bytes::from_bytes_vec(bytes)))
        .allow_partial(true)
        .validate(false);
    let result = net.load_from(&mut store).map_err(|e| {
        err(
            path,
            format!(
                "unreadable weights ({}): {}",
                WEIGHTS_FILE,
                first_line(&e.to_string())
            ),
        )
    })?;
    let more = |n: usize| {
        if n > 1 {
            format!(" (and {} more)", n - 1)
        } else {
            String::new()
        }
    };
    if let Some(e) = result.errors.first() {
        return Err(err(
            path,
            format!(
                "weights do not match the network in config.json: {}{}",
                first_line(&e.to_string()),
                more(result.errors.len())
            ),
        ));
    }
    if let Some((m, _)) = result.missing.first() {
        return Err(err(
            path,
            format!(
                "weights lack tensor '{m}' that config.json's network has{}",
                more(result.missing.len())
            ),
        ));
    }
    if let Some(u) = result.unused.first() {
        return Err(err(
            path,
            format!(
                "weights have tensor '{u}' that config.json's network lacks{}",
                more(result.unused.len())
            ),
        ));
    }
    Ok(net)
}

fn first_line(s: &str) -> String {
    s.lines()
        .find(|l| !l.trim().is_empty())
        .unwrap_or(s)
        .trim()
        .to_string()
}

/// Writes a checkpoint directory: `files` are `(name, bytes)` pairs (config, weights, stats,
/// metrics and anything else); the directory appears complete or not at all.
pub fn write_dir(dir: &Path, files: &[(&str, Vec<u8>)]) -> Result<()> {
    let parent = match dir.parent() {
        Some(p) if !p.as_os_str().is_empty() => p.to_path_buf(),
        _ => PathBuf::from("."),
    };
    std::fs::create_dir_all(&parent).map_err(|e| ModelError::io(&parent, e))?;
    let name = dir
        .file_name()
        .map_or_else(|| "checkpoint".into(), |n| n.to_string_lossy().into_owned());
    let tmp = parent.join(format!(".{name}.tmp{}", std::process::id()));
    let old = parent.join(format!(".{name}.old{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&tmp);
    let result = (|| -> std::io::Result<()> {
        std::fs::create_dir_all(&tmp)?;
        for (file, bytes) in files {
            use std::io::Write;
            let mut f = std::fs::File::create(tmp.join(file))?;
            f.write_all(bytes)?;
            f.sync_all()?;
        }
        if dir.exists() {
            std::fs::rename(dir, &old)?;
        }
        std::fs::rename(&tmp, dir)?;
        let _ = std::fs::remove_dir_all(&old);
        Ok(())
    })();
    if let Err(e) = result {
        let _ = std::fs::remove_dir_all(&tmp);
        if !dir.exists() && old.exists() {
            let _ = std::fs::rename(&old, dir);
        }
        return Err(ModelError::io(dir, e));
    }
    Ok(())
}

/// The files of a checkpoint (config, weights, stats, metrics).
pub fn checkpoint_files(
    net: &NeuralNet,
    stats: &FeatureStats,
    template: &Template,
    energy: Option<&lfit_model::energy::EnergyConfig>,
    metrics: &serde_json::Value,
) -> Result<Vec<(&'static str, Vec<u8>)>> {
    let mut meta = CheckpointMeta::new(template, net.config.clone());
    meta.energy = energy.cloned();
    let json = |v: serde_json::Result<String>| {
        v.map(String::into_bytes)
            .map_err(|e| ModelError::Backend(format!("cannot serialise checkpoint: {e}")))
    };
    Ok(vec![
        (CONFIG_FILE, json(serde_json::to_string_pretty(&meta))?),
        (WEIGHTS_FILE, weights_bytes(net)?),
        (STATS_FILE, json(serde_json::to_string(stats))?),
        (METRICS_FILE, json(serde_json::to_string_pretty(metrics))?),
    ])
}

fn read(dir: &Path, file: &str) -> Result<Vec<u8>> {
    let path = dir.join(file);
    std::fs::read(&path).map_err(|e| err(dir, format!("cannot read {file}: {e}")))
}

/// Loads a checkpoint onto `device`, checking format, version, statistics and weights.
pub fn load(dir: &Path, device: &Device) -> Result<Checkpoint> {
    if !dir.is_dir() {
        return Err(err(dir, "no such checkpoint directory"));
    }
    let meta: CheckpointMeta = serde_json::from_slice(&read(dir, CONFIG_FILE)?)
        .map_err(|e| err(dir, format!("malformed {CONFIG_FILE}: {e}")))?;
    if meta.format != FORMAT {
        return Err(err(
            dir,
            format!(
                "{CONFIG_FILE} has format '{}', expected '{FORMAT}'",
                meta.format
            ),
        ));
    }
    if meta.version != VERSION {
        return Err(err(
            dir,
            format!(
                "checkpoint version {} is not supported (expected {VERSION})",
                meta.version
            ),
        ));
    }
    meta.network
        .validate()
        .map_err(|e| err(dir, e.to_string()))?;
    let stats: FeatureStats = serde_json::from_slice(&read(dir, STATS_FILE)?)
        .map_err(|e| err(dir, format!("malformed {STATS_FILE}: {e}")))?;
    stats
        .validate(&meta.network)
        .map_err(|e| err(dir, e.to_string()))?;
    let net = net_from_bytes(&meta.network, read(dir, WEIGHTS_FILE)?, device, dir)?;
    let metrics = match std::fs::read(dir.join(METRICS_FILE)) {
        Ok(b) => serde_json::from_slice(&b)
            .map_err(|e| err(dir, format!("malformed {METRICS_FILE}: {e}")))?,
        Err(_) => serde_json::Value::Null,
    };
    Ok(Checkpoint {
        meta,
        stats,
        net,
        metrics,
    })
}

impl Checkpoint {
    /// Checks that this checkpoint fits data of `modality` with a residual of `residual_dim`
    /// entries on `template`.
    pub fn check_compatible(
        &self,
        dir: &Path,
        modality: Modality,
        residual_dim: usize,
        template: &Template,
    ) -> Result<()> {
        self.meta
            .check_compatible(dir, modality, residual_dim, template)
    }
}

impl CheckpointMeta {
    /// The metadata of a network trained on `template`.
    pub fn new(template: &Template, network: NetConfig) -> Self {
        Self {
            format: FORMAT.into(),
            version: VERSION,
            template_id: template.id.clone(),
            template_vertices: template.num_vertices(),
            network,
            model: Some(template.signature()),
            energy: None,
        }
    }

    /// Checks that a fit minimises the energy the network was trained on, when the checkpoint
    /// records one (the network learned its residuals, gradient and scale).
    pub fn check_energy(
        &self,
        dir: &Path,
        config: &lfit_model::energy::EnergyConfig,
    ) -> Result<()> {
        match &self.energy {
            Some(trained) if trained != config => Err(err(
                dir,
                format!(
                    "was trained on another energy than this fit's (weights {}, robust {:?}): pass it with --energy (bench: energy = \"FILE\"), e.g. the training config's",
                    serde_json::to_string(&trained.weights).unwrap_or_default(),
                    trained.robust
                ),
            )),
            _ => Ok(()),
        }
    }

    /// Checks that the network fits data of `modality` with a residual of `residual_dim`
    /// entries on `template` (`dir` names the checkpoint in errors). A pooled network
    /// ([`crate::Views::Pooled`]) fits `keypoints2d` data of any number of cameras: a residual of
    /// a positive multiple of its per-camera length.
    pub fn check_compatible(
        &self,
        dir: &Path,
        modality: Modality,
        residual_dim: usize,
        template: &Template,
    ) -> Result<()> {
        let n = &self.network;
        if let Some(sig) = &self.model {
            let here = template.signature();
            if *sig != here {
                return Err(err(
                    dir,
                    format!(
                        "was trained on model '{}' ({} parameters, hash {}), not '{}' ({} parameters, hash {})",
                        sig.id,
                        sig.layout.dim(),
                        sig.hash,
                        here.id,
                        here.layout.dim(),
                        here.hash
                    ),
                ));
            }
        }
        if n.param_dim != template.param_dim() {
            return Err(err(
                dir,
                format!(
                    "predicts {} parameters, the model '{}' has {}",
                    n.param_dim,
                    template.id,
                    template.param_dim()
                ),
            ));
        }
        if n.modality != modality {
            return Err(err(
                dir,
                format!("was trained for {} data, not {modality}", n.modality),
            ));
        }
        if n.views == crate::Views::Pooled {
            if residual_dim == 0 || residual_dim % n.residual_dim != 0 {
                return Err(err(
                    dir,
                    format!(
                        "fits keypoints2d rigs of {} keypoints per camera ({} values each), the data's sensor gives {residual_dim} values",
                        n.keypoints(),
                        n.residual_dim
                    ),
                ));
            }
        } else if n.residual_dim != residual_dim {
            return Err(err(
                dir,
                format!(
                    "expects a residual of {} values, the data's sensor gives {residual_dim}",
                    n.residual_dim
                ),
            ));
        }
        if self.template_vertices != template.num_vertices() {
            return Err(err(
                dir,
                format!(
                    "was trained on template '{}' ({} vertices), not '{}' ({} vertices)",
                    self.template_id,
                    self.template_vertices,
                    template.id,
                    template.num_vertices()
                ),
            ));
        }
        Ok(())
    }
}
