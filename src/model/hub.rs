//! Hub folders: the layout of the released LHM++ checkpoints (`3DAIGC/LHMPP-700M`), a folder
//! holding `config.json` (the HuggingFace `PyTorchModelHubMixin` config, i.e. the YAML
//! `model:` section of `configs/train/LHMPP-any-view.yaml`) and `model.safetensors` (or a
//! sharded `model.safetensors.index.json` with its shards).
//!
//! `config.json` is parsed into [`OfficialModelConfig`] (only the fields the network needs;
//! the others are ignored) and turned into an [`LhmppConfig`] starting from the `lhmpp-700m`
//! preset: every field the file sets is checked against what our network supports
//! (unsupported values are errors naming the field and the file) and every value that differs
//! from the preset is reported by its official name. The weights are then validated against the
//! derived config (all mismatches at once) and memory-mapped.
//!
//! The reading is in `official`, the derivation subtree by subtree in `derive`.

mod derive;
mod official;

pub use derive::{derive_config, derive_config_with_encoder};
pub use official::{
    parse_config, ClipScaling, OfficialGsMlp, OfficialImageBackbone, OfficialModelConfig,
    OfficialNeuralRenderer, OfficialPointBackbone, OfficialTransformerDecoder,
    DEFAULT_PIXEL_SHUFFLE_FACTOR, DPT_RENDERER_TYPE, PIXEL_SHUFFLE_RENDERER_TYPE,
    SHARED_DPT_RENDERER_TYPE,
};

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

use candle_core::{DType, Device};
use candle_nn::VarBuilder;

use super::checkpoint::{
    check_files, load_var_builder, load_var_builder_from_files, CheckpointError, CheckpointSummary,
};
use super::config::LhmppConfig;
use super::rgb_kind::RgbKind;
use official::read_json;

/// Config file of a hub folder.
pub const CONFIG_FILE: &str = "config.json";
/// Single-file weights of a hub folder.
pub const WEIGHTS_FILE: &str = "model.safetensors";
/// Index of sharded weights of a hub folder.
pub const INDEX_FILE: &str = "model.safetensors.index.json";

/// Errors from opening a hub folder.
#[derive(Debug, thiserror::Error)]
pub enum HubError {
    /// A required file is absent.
    #[error("hub folder {folder}: missing {what}")]
    Missing {
        /// The folder.
        folder: PathBuf,
        /// What is missing (file names).
        what: String,
    },
    /// The checkpoint path does not exist.
    #[error(
        "checkpoint {0} does not exist (expected a safetensors file, or a hub folder with \
             config.json and model.safetensors); the released weights: \
             `huggingface-cli download 3DAIGC/LHMPP-700M --local-dir {0}` \
             (docs/model.md, \"Official LHM++ weights\")"
    )]
    NotFound(PathBuf),
    /// Reading a file failed.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The I/O error.
        source: std::io::Error,
    },
    /// A JSON file is malformed or lacks a field; `key` is the path of the offending field.
    #[error("{path}: key `{key}`: {reason}")]
    Json {
        /// The file.
        path: PathBuf,
        /// Path of the offending key (`transformer_decoder.point_backbone.stride`).
        key: String,
        /// What is wrong.
        reason: String,
    },
    /// The config asks for something our network does not implement.
    #[error("{path}: unsupported by this network:\n  {}", fields.join("\n  "))]
    Unsupported {
        /// The config file.
        path: PathBuf,
        /// One line per unsupported field, naming it and its value.
        fields: Vec<String>,
    },
    /// The derived config is invalid, or the weights do not match it.
    #[error(transparent)]
    Checkpoint(#[from] CheckpointError),
}

/// An opened hub folder: parsed config, derived network config and the weight files.
#[derive(Debug, Clone)]
pub struct HubFolder {
    /// The folder.
    pub dir: PathBuf,
    /// `config.json` as parsed.
    pub official: OfficialModelConfig,
    /// Our network config derived from it.
    pub config: LhmppConfig,
    /// Fields that differ from the `lhmpp-700m` preset: `name: file value (preset value)`.
    pub differences: Vec<String>,
    /// Weight files (one, or the shards in index order).
    pub weights: Vec<PathBuf>,
}

impl HubFolder {
    /// Opens `dir`: parses `config.json`, derives the network config and finds the weights.
    /// A folder without `config.json` but with `step_N/` checkpoints (the LHM release layout)
    /// opens the highest step.
    pub fn open(dir: &Path) -> Result<Self, HubError> {
        let resolved = latest_step(dir);
        let dir = resolved.as_deref().unwrap_or(dir);
        let config_path = dir.join(CONFIG_FILE);
        if !config_path.is_file() {
            return Err(HubError::Missing {
                folder: dir.to_path_buf(),
                what: CONFIG_FILE.into(),
            });
        }
        let official = parse_config(&config_path)?;
        let (config, differences) = derive_config(&official, &config_path, dir)?;
        let weights = find_weights(dir)?;
        Ok(Self {
            dir: dir.to_path_buf(),
            official,
            config,
            differences,
            weights,
        })
    }

    /// Validates the weights against the derived config from their headers only and
    /// summarises them (tensor and parameter counts, ignored extras, stored dtypes).
    pub fn check(&self) -> Result<CheckpointSummary, HubError> {
        Ok(check_files(&self.weights, &self.dir, &self.config)?)
    }

    /// Validates the weights against the derived config (all mismatches at once) and returns a
    /// `VarBuilder` over them in `dtype` on `device`.
    pub fn var_builder(
        &self,
        dtype: DType,
        device: &Device,
    ) -> Result<VarBuilder<'static>, HubError> {
        Ok(load_var_builder_from_files(
            &self.weights,
            &self.dir,
            &self.config,
            dtype,
            device,
        )?)
    }
}

/// A loaded checkpoint: its network config, its tensors and a description for logs.
pub struct LoadedCheckpoint {
    /// The network config (the preset's, or derived from a hub folder's `config.json`).
    pub config: LhmppConfig,
    /// The validated tensors.
    pub var_builder: VarBuilder<'static>,
    /// Where the weights came from.
    pub description: String,
    /// The official `neural_renderer.type` of a hub folder (`None` for a single file).
    pub neural_renderer_type: Option<String>,
    /// Whether the hub folder's network carries the betas `shape_head` of the GS-supervised
    /// releases (LHMPP-700M-PixelShuffle, -SMPLX-FREE); false for a single file.
    pub shape_head: bool,
}

impl LoadedCheckpoint {
    /// What the Gaussians' RGB of this checkpoint is: by `neural_renderer.type` and `shape_head`
    /// for a hub folder ([`RgbKind::of_hub`]), by preset for a single file.
    pub fn rgb_kind(&self) -> RgbKind {
        match &self.neural_renderer_type {
            Some(kind) => RgbKind::of_hub(kind, self.shape_head),
            None => RgbKind::of_preset(&self.config.preset),
        }
    }
}

/// Loads `path` the way the node does: a hub folder (config from its `config.json`) or a
/// single safetensors file validated against `preset`.
pub fn load_checkpoint(
    path: &Path,
    preset: &LhmppConfig,
    dtype: DType,
    device: &Device,
) -> Result<LoadedCheckpoint, HubError> {
    if !path.exists() {
        return Err(HubError::NotFound(path.to_path_buf()));
    }
    if path.is_dir() {
        let hub = HubFolder::open(path)?;
        if hub.official.has_shape_head() {
            tracing::info!(
                "{}: the checkpoint's shape_head predicts the SMPL-X betas from the image tokens",
                path.join(CONFIG_FILE).display()
            );
        }
        for d in &hub.differences {
            tracing::warn!(
                "{}: differs from the lhmpp-700m preset: {d}",
                path.join(CONFIG_FILE).display()
            );
        }
        if hub.config.preset != preset.preset {
            tracing::info!(
                "{}: using the config of the hub folder (`{}`) instead of preset `{}`",
                path.display(),
                hub.config.preset,
                preset.preset
            );
        }
        let var_builder = hub.var_builder(dtype, device)?;
        return Ok(LoadedCheckpoint {
            description: format!(
                "{} (hub folder, {} weight file(s))",
                path.display(),
                hub.weights.len()
            ),
            neural_renderer_type: Some(hub.official.neural_renderer.kind.clone()),
            shape_head: hub.official.has_shape_head(),
            config: hub.config,
            var_builder,
        });
    }
    let var_builder = load_var_builder(path, preset, dtype, device)?;
    Ok(LoadedCheckpoint {
        config: preset.clone(),
        var_builder,
        description: path.display().to_string(),
        neural_renderer_type: None,
        shape_head: false,
    })
}

/// The weight files of `dir`: `model.safetensors`, or the shards named by the index.
pub fn find_weights(dir: &Path) -> Result<Vec<PathBuf>, HubError> {
    let single = dir.join(WEIGHTS_FILE);
    if single.is_file() {
        return Ok(vec![single]);
    }
    let index = dir.join(INDEX_FILE);
    if !index.is_file() {
        return Err(HubError::Missing {
            folder: dir.to_path_buf(),
            what: format!("weights ({WEIGHTS_FILE} or {INDEX_FILE})"),
        });
    }
    let value = read_json(&index)?;
    let map: BTreeMap<String, String> = value
        .get("weight_map")
        .cloned()
        .ok_or_else(|| HubError::Json {
            path: index.clone(),
            key: "weight_map".into(),
            reason: "missing field `weight_map`".into(),
        })
        .and_then(|v| {
            serde_path_to_error::deserialize(v).map_err(|e| HubError::Json {
                path: index.clone(),
                key: format!("weight_map.{}", e.path()),
                reason: e.into_inner().to_string(),
            })
        })?;
    let shards: BTreeSet<&String> = map.values().collect();
    if shards.is_empty() {
        return Err(HubError::Json {
            path: index,
            key: "weight_map".into(),
            reason: "names no shard".into(),
        });
    }
    let missing: Vec<&str> = shards
        .iter()
        .filter(|s| !dir.join(s.as_str()).is_file())
        .map(|s| s.as_str())
        .collect();
    if !missing.is_empty() {
        return Err(HubError::Missing {
            folder: dir.to_path_buf(),
            what: format!("shard(s) named by {INDEX_FILE}: {}", missing.join(", ")),
        });
    }
    Ok(shards.into_iter().map(|s| dir.join(s)).collect())
}

/// The `step_N` subfolder of `dir` with the highest N holding a `config.json`, when `dir`
/// itself has none.
fn latest_step(dir: &Path) -> Option<PathBuf> {
    if dir.join(CONFIG_FILE).is_file() {
        return None;
    }
    std::fs::read_dir(dir)
        .ok()?
        .filter_map(|e| e.ok())
        .filter_map(|e| {
            let name = e.file_name().to_string_lossy().into_owned();
            let step: u64 = name.strip_prefix("step_")?.parse().ok()?;
            let path = e.path();
            path.join(CONFIG_FILE).is_file().then_some((step, path))
        })
        .max_by_key(|(step, _)| *step)
        .map(|(_, path)| path)
}
