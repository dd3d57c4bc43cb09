//! The embedded default checkpoint: the `tiny` network trained on synthetic people by
//! `scripts/train/run` (how, on what and with which losses: `assets/model/README.md`).
//!
//! `model.checkpoint` empty selects it for the `tiny` preset; `random` or `random:SEED`
//! selects seeded random weights instead (tests and benchmarks that need them).

use candle_core::{DType, Device};
use candle_nn::VarBuilder;
use std::path::Path;

use super::checkpoint::{load_var_builder_from_bytes, CheckpointError};
use super::config::LhmppConfig;

/// Where the embedded default was read from at build time (for messages).
pub const DEFAULT_CHECKPOINT_PATH: &str = "assets/model/lhmpp-tiny-synthetic.safetensors";

/// The bytes of the embedded default checkpoint (safetensors, our layout, f16).
pub static DEFAULT_CHECKPOINT: &[u8] =
    include_bytes!("../../assets/model/lhmpp-tiny-synthetic.safetensors");

/// Preset the embedded default was trained for.
pub const DEFAULT_PRESET: &str = "tiny";

/// Seed of the random weights used when asked for (`random`) or when a preset has no trained
/// default.
pub const RANDOM_WEIGHTS_SEED: u64 = 1;

/// Which weights a `model.checkpoint` value names.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum WeightsSource {
    /// The embedded trained default (empty value).
    Embedded,
    /// Seeded random weights (`random` or `random:SEED`).
    Random(u64),
    /// A safetensors file or hub folder.
    Path(String),
}

impl WeightsSource {
    /// Parses a `model.checkpoint` value; `None` for a malformed `random:` seed.
    pub fn parse(value: &str) -> Option<Self> {
        match value {
            "" => Some(Self::Embedded),
            "random" => Some(Self::Random(RANDOM_WEIGHTS_SEED)),
            v => match v.strip_prefix("random:") {
                Some(seed) => seed.parse().ok().map(Self::Random),
                None => Some(Self::Path(v.to_string())),
            },
        }
    }
}

/// The embedded default's network config (the `tiny` preset as stored in its metadata).
pub fn default_config() -> Result<LhmppConfig, CheckpointError> {
    let bad = |reason: String| CheckpointError::Format {
        path: DEFAULT_CHECKPOINT_PATH.into(),
        reason,
    };
    let (_, meta) = safetensors::SafeTensors::read_metadata(DEFAULT_CHECKPOINT)
        .map_err(|e| bad(e.to_string()))?;
    let json = meta
        .metadata()
        .as_ref()
        .and_then(|m| m.get(super::checkpoint::META_CONFIG).cloned())
        .ok_or_else(|| bad("no network config in the metadata".into()))?;
    serde_json::from_str(&json).map_err(|e| bad(e.to_string()))
}

/// The embedded default weights in `dtype` on `device`, with their config.
pub fn default_var_builder(
    dtype: DType,
    device: &Device,
) -> Result<(LhmppConfig, VarBuilder<'static>), CheckpointError> {
    let cfg = default_config()?;
    let vb = load_var_builder_from_bytes(
        DEFAULT_CHECKPOINT,
        Path::new(DEFAULT_CHECKPOINT_PATH),
        &cfg,
        dtype,
        device,
    )?;
    Ok((cfg, vb))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn checkpoint_values_name_their_source() {
        assert_eq!(WeightsSource::parse(""), Some(WeightsSource::Embedded));
        assert_eq!(
            WeightsSource::parse("random"),
            Some(WeightsSource::Random(RANDOM_WEIGHTS_SEED))
        );
        assert_eq!(
            WeightsSource::parse("random:7"),
            Some(WeightsSource::Random(7))
        );
        assert_eq!(WeightsSource::parse("random:x"), None);
        assert_eq!(
            WeightsSource::parse("a.safetensors"),
            Some(WeightsSource::Path("a.safetensors".into()))
        );
    }

    #[test]
    fn embedded_default_loads_as_the_tiny_network() {
        let (cfg, vb) = default_var_builder(DType::F32, &Device::Cpu).unwrap();
        assert_eq!(cfg.preset, DEFAULT_PRESET);
        crate::model::Lhmpp::new(&cfg, vb).unwrap();
    }
}
