//! Checkpoints: one naming scheme (the official LHM++ state-dict keys), seeded initialisation
//! and validated loading.
//!
//! Naming: every tensor is named by the path of `vb.pp(..)` segments that builds it, which
//! mirrors the official `state_dict` (`encoder.model.blocks.3.attn.qkv.weight`,
//! `transformer.pi_transformer_enc.0.norm1.linear.weight`, `renderer.gs_net.out_layers.xyz.bias`,
//! ...). The expected list for a config is obtained by building the network against a
//! recording backend, so it can never drift from the modules.
//!
//! Initialisation (`init_checkpoint`): each tensor is drawn from its own ChaCha8 stream seeded
//! by `seed` and the FNV-1a hash of its name (order-independent). Hints from the modules are
//! honoured: Kaiming-normal weights use gain 1 (`std = 1/sqrt(fan_in)`), LayerNorm 1/0,
//! LayerScale small constants, AdaLN modulation `N(0, 0.02)` with zero bias, GS-head biases as
//! the official training init (scaling −6, opacity logit(0.1), rotation w = 1).
//!
//! Loading: every file tensor is checked against the expected list; missing, unexpected,
//! wrong-shape and wrong-dtype tensors are all reported in one error naming the file. f32, f16
//! and bf16 are accepted and converted to the requested dtype. Official-checkpoint extras that
//! inference does not use (`renderer.smplx_model.*`, `neural_renderer.transformer_block.*`) are
//! ignored.

use std::collections::{BTreeMap, HashMap};
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex};

use candle_core::{DType, Device, Shape, Tensor};
use candle_nn::var_builder::SimpleBackend;
use candle_nn::{Init, VarBuilder};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use super::config::{LhmppConfig, ModelConfigError};

/// Key prefixes present in official checkpoints but unused at inference; ignored on load.
/// `shape_head.*` is the betas head of the GS-supervised releases (LHMPP-700M-PixelShuffle,
/// -SMPLX-FREE), which this network does not run: their betas come from the shape topic.
pub const IGNORED_PREFIXES: [&str; 3] = [
    "renderer.smplx_model.",
    "neural_renderer.transformer_block.",
    "shape_head.",
];

/// Safetensors metadata key holding the preset name.
pub const META_PRESET: &str = "lhmpp.preset";
/// Safetensors metadata key holding the config JSON.
pub const META_CONFIG: &str = "lhmpp.config";

/// Errors from writing or reading checkpoints.
#[derive(Debug, thiserror::Error)]
pub enum CheckpointError {
    /// Reading or writing the file failed.
    #[error("checkpoint {path}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The I/O error.
        source: std::io::Error,
    },
    /// The file is not valid safetensors.
    #[error("checkpoint {path}: not a valid safetensors file: {reason}")]
    Format {
        /// The file.
        path: PathBuf,
        /// Parser message.
        reason: String,
    },
    /// Tensors do not match the config.
    #[error("checkpoint {path} does not match config `{preset}` ({} problems):\n  {}", problems.len(), problems.join("\n  "))]
    Mismatch {
        /// The file.
        path: PathBuf,
        /// Preset of the expected config.
        preset: String,
        /// One line per missing, unexpected, wrong-shape or wrong-dtype tensor.
        problems: Vec<String>,
    },
    /// The config is invalid.
    #[error(transparent)]
    Config(#[from] ModelConfigError),
    /// A tensor operation failed.
    #[error("checkpoint tensor operation failed: {0}")]
    Candle(#[from] candle_core::Error),
}

/// FNV-1a hash of a tensor name.
fn fnv1a(name: &str) -> u64 {
    name.bytes().fold(0xcbf2_9ce4_8422_2325u64, |h, b| {
        (h ^ b as u64).wrapping_mul(0x0100_0000_01b3)
    })
}

/// Standard normal sample (Box–Muller).
fn normal(rng: &mut ChaCha8Rng) -> f64 {
    let u1: f64 = rng.gen::<f64>().max(f64::MIN_POSITIVE);
    let u2: f64 = rng.gen();
    (-2.0 * u1.ln()).sqrt() * (2.0 * std::f64::consts::PI * u2).cos()
}

/// Values of one freshly initialised tensor.
fn init_values(seed: u64, name: &str, shape: &Shape, hint: Init) -> Vec<f32> {
    let n = shape.elem_count();
    if name.ends_with("gs_net.out_layers.rotation.bias") {
        let mut v = vec![0f32; n];
        if n > 0 {
            v[0] = 1.0;
        }
        return v;
    }
    let mut rng = ChaCha8Rng::seed_from_u64(seed ^ fnv1a(name));
    match hint {
        Init::Const(c) => vec![c as f32; n],
        Init::Randn { mean, stdev } => (0..n)
            .map(|_| (mean + stdev * normal(&mut rng)) as f32)
            .collect(),
        Init::Uniform { lo, up } => (0..n)
            .map(|_| rng.gen_range(lo..up.max(lo + f64::EPSILON)) as f32)
            .collect(),
        Init::Kaiming { fan, .. } => {
            let std = 1.0 / (fan.for_shape(shape).max(1) as f64).sqrt();
            (0..n).map(|_| (std * normal(&mut rng)) as f32).collect()
        }
    }
}

/// Backend that creates seeded tensors on request.
struct SeededInit {
    seed: u64,
    /// Round every value to bf16 first (then convert to the requested dtype).
    bf16_values: bool,
}

impl SimpleBackend for SeededInit {
    fn get(
        &self,
        s: Shape,
        name: &str,
        h: Init,
        dtype: DType,
        dev: &Device,
    ) -> candle_core::Result<Tensor> {
        let v = init_values(self.seed, name, &s, h);
        let t = Tensor::from_vec(v, s, &Device::Cpu)?;
        let t = if self.bf16_values {
            t.to_dtype(DType::BF16)?
        } else {
            t
        };
        t.to_dtype(dtype)?.to_device(dev)
    }

    fn get_unchecked(&self, name: &str, _: DType, _: &Device) -> candle_core::Result<Tensor> {
        candle_core::bail!("seeded init cannot create `{name}` without a shape")
    }

    fn contains_tensor(&self, _: &str) -> bool {
        false
    }
}

/// Name → (shape, init hint) of every tensor the network requests.
type Recorded = BTreeMap<String, (Vec<usize>, Init)>;

/// Backend that records every requested name, shape and init hint; returns zero-cost zeros.
struct Recorder {
    seen: Arc<Mutex<Recorded>>,
}

impl SimpleBackend for Recorder {
    fn get(
        &self,
        s: Shape,
        name: &str,
        h: Init,
        dtype: DType,
        dev: &Device,
    ) -> candle_core::Result<Tensor> {
        if let Ok(mut seen) = self.seen.lock() {
            seen.insert(name.to_string(), (s.dims().to_vec(), h));
        }
        Tensor::zeros(vec![1usize; s.rank()], dtype, dev)?.broadcast_as(s)
    }

    fn get_unchecked(&self, name: &str, _: DType, _: &Device) -> candle_core::Result<Tensor> {
        candle_core::bail!("shape recorder cannot create `{name}` without a shape")
    }

    fn contains_tensor(&self, _: &str) -> bool {
        false
    }
}

/// Builds the network for `cfg` against a [`Recorder`].
fn record(cfg: &LhmppConfig) -> Result<Recorded, CheckpointError> {
    cfg.validate()?;
    let seen = Arc::new(Mutex::new(BTreeMap::new()));
    let vb = VarBuilder::from_backend(
        Box::new(Recorder { seen: seen.clone() }),
        DType::F32,
        Device::Cpu,
    );
    super::build_network(cfg, vb)?;
    let out = seen.lock().map(|m| m.clone()).unwrap_or_default();
    Ok(out)
}

/// A `VarBuilder` whose tensors are seeded random values (see the module doc).
pub fn seeded_var_builder(seed: u64, dtype: DType, dev: &Device) -> VarBuilder<'static> {
    VarBuilder::from_backend(
        Box::new(SeededInit {
            seed,
            bf16_values: false,
        }),
        dtype,
        dev.clone(),
    )
}

/// [`seeded_var_builder`] with every value rounded to bf16 before it is converted to `dtype`:
/// an f32 network with exactly the weights of the bf16 one (for comparing the two dtypes'
/// arithmetic alone).
pub fn seeded_bf16_valued_var_builder(
    seed: u64,
    dtype: DType,
    dev: &Device,
) -> VarBuilder<'static> {
    VarBuilder::from_backend(
        Box::new(SeededInit {
            seed,
            bf16_values: true,
        }),
        dtype,
        dev.clone(),
    )
}

/// Every tensor name and shape the network for `cfg` expects, sorted by name.
pub fn expected_tensors(
    cfg: &LhmppConfig,
) -> Result<BTreeMap<String, Vec<usize>>, CheckpointError> {
    Ok(record(cfg)?
        .into_iter()
        .map(|(k, (dims, _))| (k, dims))
        .collect())
}

/// Writes seeded random weights for `cfg` to `path` (f32 safetensors with the preset name
/// and config JSON in the metadata). Returns the number of parameters written.
pub fn init_checkpoint(
    cfg: &LhmppConfig,
    seed: u64,
    path: &Path,
) -> Result<usize, CheckpointError> {
    let format_err = |reason: String| CheckpointError::Format {
        path: path.to_path_buf(),
        reason,
    };
    let recorded = record(cfg)?;
    let data: Vec<(String, Vec<u8>, Vec<usize>)> = recorded
        .into_iter()
        .map(|(name, (dims, hint))| {
            let v = init_values(seed, &name, &Shape::from_dims(&dims), hint);
            (name, bytemuck::cast_slice(&v).to_vec(), dims)
        })
        .collect();
    let total = data.iter().map(|(_, b, _)| b.len() / 4).sum();
    let views = data
        .iter()
        .map(|(n, bytes, dims)| {
            safetensors::tensor::TensorView::new(safetensors::Dtype::F32, dims.clone(), bytes)
                .map(|v| (n.clone(), v))
                .map_err(|e| format_err(e.to_string()))
        })
        .collect::<Result<Vec<_>, _>>()?;
    let config_json = serde_json::to_string(cfg).map_err(|e| format_err(e.to_string()))?;
    let meta = HashMap::from([
        (META_PRESET.to_string(), cfg.preset.clone()),
        (META_CONFIG.to_string(), config_json),
    ]);
    safetensors::serialize_to_file(views, Some(meta), path)
        .map_err(|e| format_err(e.to_string()))?;
    Ok(total)
}

/// Preset name and config JSON stored in a checkpoint's metadata, if any.
pub fn read_metadata(
    path: &Path,
) -> Result<(Option<String>, Option<LhmppConfig>), CheckpointError> {
    let bytes = std::fs::read(path).map_err(|source| CheckpointError::Io {
        path: path.to_path_buf(),
        source,
    })?;
    let (_, meta) =
        safetensors::SafeTensors::read_metadata(&bytes).map_err(|e| CheckpointError::Format {
            path: path.to_path_buf(),
            reason: e.to_string(),
        })?;
    let m = meta.metadata().clone().unwrap_or_default();
    let cfg = m
        .get(META_CONFIG)
        .and_then(|j| serde_json::from_str(j).ok());
    Ok((m.get(META_PRESET).cloned(), cfg))
}

/// Validates `path` against `cfg` and returns a `VarBuilder` over its tensors in `dtype` on
/// `device`. All problems are reported at once.
pub fn load_var_builder(
    path: &Path,
    cfg: &LhmppConfig,
    dtype: DType,
    device: &Device,
) -> Result<VarBuilder<'static>, CheckpointError> {
    load_var_builder_from_files(&[path.to_path_buf()], path, cfg, dtype, device)
}

/// Validates the union of the tensors in `files` (one file, or the shards of a sharded
/// checkpoint; memory-mapped) against `cfg` and returns a `VarBuilder` over them in `dtype`
/// on `device`. Every missing, unexpected, duplicated, wrong-shape or wrong-dtype tensor is
/// reported at once in one error naming `origin` (the file or hub folder).
pub fn load_var_builder_from_files(
    files: &[PathBuf],
    origin: &Path,
    cfg: &LhmppConfig,
    dtype: DType,
    device: &Device,
) -> Result<VarBuilder<'static>, CheckpointError> {
    let (tensors, _) = scan_files(files, origin, cfg, Some((dtype, device)))?;
    Ok(VarBuilder::from_tensors(tensors, dtype, device))
}

/// What a checkpoint holds (from the file headers only).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct CheckpointSummary {
    /// Tensors the network uses.
    pub tensors: usize,
    /// Their parameters.
    pub parameters: usize,
    /// Ignored official extras: (prefix, tensors, parameters) per [`IGNORED_PREFIXES`] entry.
    pub ignored: Vec<(String, usize, usize)>,
    /// Used tensors per stored dtype (`BF16`, `F32`, ...).
    pub dtypes: BTreeMap<String, usize>,
}

/// Validates `files` against `cfg` like [`load_var_builder_from_files`] but reads only the
/// headers (no tensor data), and summarises what they hold.
pub fn check_files(
    files: &[PathBuf],
    origin: &Path,
    cfg: &LhmppConfig,
) -> Result<CheckpointSummary, CheckpointError> {
    Ok(scan_files(files, origin, cfg, None)?.1)
}

/// Checks every tensor of `files` against `cfg`; loads them when `load` gives a dtype and
/// device.
fn scan_files(
    files: &[PathBuf],
    origin: &Path,
    cfg: &LhmppConfig,
    load: Option<(DType, &Device)>,
) -> Result<(HashMap<String, Tensor>, CheckpointSummary), CheckpointError> {
    let mut maps = Vec::with_capacity(files.len());
    for file in files {
        if let Err(source) = std::fs::metadata(file) {
            return Err(CheckpointError::Io {
                path: file.clone(),
                source,
            });
        }
        // SAFETY: the file is only read; a concurrent writer could change the mapped bytes,
        // which safetensors' bounds checks turn into a format error at worst.
        let map = unsafe { candle_core::safetensors::MmapedFile::new(file) }.map_err(|e| {
            CheckpointError::Format {
                path: file.clone(),
                reason: e.to_string(),
            }
        })?;
        maps.push((file, map));
    }
    let mut parsed = Vec::with_capacity(maps.len());
    for (file, map) in &maps {
        let st = map.deserialize().map_err(|e| CheckpointError::Format {
            path: file.to_path_buf(),
            reason: with_layout_detail(e.to_string(), file),
        })?;
        parsed.push((file.as_path(), st));
    }
    scan_tensors(&parsed, origin, cfg, load)
}

/// `reason` followed by the sizes behind it, read from the file's safetensors framing (an
/// 8-byte little-endian header length, the JSON header, the tensor data): how many bytes the
/// header length and the tensors' offsets need against how many the file has.
fn with_layout_detail(reason: String, file: &Path) -> String {
    match layout_detail(file) {
        Some(detail) => format!("{reason} ({detail})"),
        None => reason,
    }
}

fn layout_detail(file: &Path) -> Option<String> {
    use std::io::Read;
    let mut f = std::fs::File::open(file).ok()?;
    let len = f.metadata().ok()?.len();
    let mut prefix = [0u8; 8];
    if f.read_exact(&mut prefix).is_err() {
        return Some(format!(
            "the file has {len} bytes, fewer than the 8-byte header length"
        ));
    }
    let header_len = u64::from_le_bytes(prefix);
    if header_len > len.saturating_sub(8) {
        return Some(format!(
            "the header length says {header_len} bytes, the file has {len} bytes in all"
        ));
    }
    let mut header = vec![0u8; header_len as usize];
    f.read_exact(&mut header).ok()?;
    let json: serde_json::Value = serde_json::from_slice(&header).ok()?;
    let data_end = json
        .as_object()?
        .iter()
        .filter(|(name, _)| name.as_str() != "__metadata__")
        .filter_map(|(_, t)| t.get("data_offsets")?.get(1)?.as_u64())
        .max()
        .unwrap_or(0);
    let needed = 8 + header_len + data_end;
    (needed != len).then(|| {
        format!(
            "header and tensors need {needed} bytes, the file has {len}{}",
            if len < needed { ": truncated" } else { "" }
        )
    })
}

/// Validates embedded safetensors `bytes` (named `origin` in errors) against `cfg` like a
/// checkpoint file, and returns a `VarBuilder` over its tensors in `dtype` on `device`.
pub fn load_var_builder_from_bytes(
    bytes: &[u8],
    origin: &Path,
    cfg: &LhmppConfig,
    dtype: DType,
    device: &Device,
) -> Result<VarBuilder<'static>, CheckpointError> {
    let st = safetensors::SafeTensors::deserialize(bytes).map_err(|e| CheckpointError::Format {
        path: origin.to_path_buf(),
        reason: e.to_string(),
    })?;
    let (tensors, _) = scan_tensors(&[(origin, st)], origin, cfg, Some((dtype, device)))?;
    Ok(VarBuilder::from_tensors(tensors, dtype, device))
}

/// The checks of [`scan_files`] over already parsed files.
fn scan_tensors(
    parsed: &[(&Path, safetensors::SafeTensors<'_>)],
    origin: &Path,
    cfg: &LhmppConfig,
    load: Option<(DType, &Device)>,
) -> Result<(HashMap<String, Tensor>, CheckpointSummary), CheckpointError> {
    let mut summary = CheckpointSummary {
        ignored: IGNORED_PREFIXES
            .iter()
            .map(|p| (p.to_string(), 0, 0))
            .collect(),
        ..Default::default()
    };
    let expected = expected_tensors(cfg)?;
    let mut problems = Vec::new();
    let mut tensors = HashMap::with_capacity(expected.len());
    let mut seen: HashMap<String, &Path> = HashMap::new();
    for (file, st) in parsed {
        let file = *file;
        let mut names: Vec<String> = st.names().into_iter().map(str::to_string).collect();
        names.sort();
        for name in names {
            if let Some(first) = seen.insert(name.clone(), file) {
                problems.push(format!(
                    "tensor `{name}` is in both {} and {}",
                    first.display(),
                    file.display()
                ));
                continue;
            }
            let view = st.tensor(&name).map_err(|e| CheckpointError::Format {
                path: file.to_path_buf(),
                reason: e.to_string(),
            })?;
            let count = view.shape().iter().product::<usize>();
            if let Some(k) = IGNORED_PREFIXES.iter().position(|p| name.starts_with(p)) {
                if !expected.contains_key(&name) {
                    summary.ignored[k].1 += 1;
                    summary.ignored[k].2 += count;
                    continue;
                }
            }
            let Some(want) = expected.get(&name) else {
                problems.push(format!("unexpected tensor `{name}` {:?}", view.shape()));
                continue;
            };
            let mut ok = true;
            if view.shape() != want.as_slice() {
                problems.push(format!(
                    "wrong shape for `{name}`: file {:?}, expected {:?}",
                    view.shape(),
                    want
                ));
                ok = false;
            }
            let dt = view.dtype();
            if !matches!(
                dt,
                safetensors::Dtype::F32 | safetensors::Dtype::F16 | safetensors::Dtype::BF16
            ) {
                problems.push(format!(
                    "wrong dtype for `{name}`: file {dt:?}, expected F32, F16 or BF16"
                ));
                ok = false;
            }
            if ok {
                summary.tensors += 1;
                summary.parameters += count;
                *summary.dtypes.entry(format!("{dt:?}")).or_default() += 1;
                if let Some((dtype, device)) = load {
                    let t = candle_core::safetensors::Load::load(&view, &Device::Cpu)?
                        .to_dtype(dtype)?
                        .to_device(device)?;
                    tensors.insert(name, t);
                }
            }
        }
    }
    for (name, dims) in &expected {
        if !seen.contains_key(name) {
            problems.push(format!("missing tensor `{name}` {dims:?}"));
        }
    }
    if !problems.is_empty() {
        return Err(CheckpointError::Mismatch {
            path: origin.to_path_buf(),
            preset: cfg.preset.clone(),
            problems,
        });
    }
    Ok((tensors, summary))
}

/// Loads a validated checkpoint into a ready network (see [`load_var_builder`]).
pub fn load(
    path: &Path,
    cfg: &LhmppConfig,
    dtype: DType,
    device: &Device,
) -> Result<super::Lhmpp, CheckpointError> {
    let vb = load_var_builder(path, cfg, dtype, device)?;
    Ok(super::Lhmpp::new(cfg, vb)?)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn seeded_init_is_reproducible_and_seed_dependent() {
        let s = Shape::from_dims(&[4, 5]);
        let a = init_values(1, "x.weight", &s, candle_nn::init::DEFAULT_KAIMING_NORMAL);
        let b = init_values(1, "x.weight", &s, candle_nn::init::DEFAULT_KAIMING_NORMAL);
        let c = init_values(2, "x.weight", &s, candle_nn::init::DEFAULT_KAIMING_NORMAL);
        let d = init_values(1, "y.weight", &s, candle_nn::init::DEFAULT_KAIMING_NORMAL);
        assert_eq!(a, b);
        assert_ne!(a, c);
        assert_ne!(a, d);
    }

    #[test]
    fn gs_biases_follow_the_official_training_init() {
        let s3 = Shape::from_dims(&[3]);
        let rot = init_values(
            7,
            "renderer.gs_net.out_layers.rotation.bias",
            &Shape::from_dims(&[4]),
            Init::Const(0.0),
        );
        assert_eq!(rot, vec![1.0, 0.0, 0.0, 0.0]);
        let scaling = init_values(
            7,
            "renderer.gs_net.out_layers.scaling.bias",
            &s3,
            Init::Const(-6.0),
        );
        assert_eq!(scaling, vec![-6.0; 3]);
    }
}
