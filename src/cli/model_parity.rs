//! `lhmpp model parity`: runs our network blocks on the PyTorch reference fixtures written by
//! `scripts/parity/generate.py` and prints, per block output and dtype, the max abs error and
//! the relative error `max|ours − torch| / max|torch|` against PyTorch's f32 output.
//!
//! A fixture is one safetensors file per block: weights under the official state-dict names,
//! `parity.input.*`, `parity.output.*`, and metadata `block` (kind), `config` (dims, JSON),
//! `torch_bf16` (PyTorch's own bf16 error, JSON). The same command runs on the CPU and, with a
//! binary built by `scripts/build-cuda`, with `--device cuda`.

use std::collections::HashMap;
use std::path::{Path, PathBuf};

use anyhow::{bail, Context};
use candle_core::{DType, Device, Tensor};
use candle_nn::VarBuilder;
use clap::Args;
use serde::Serialize;
use serde_json::Value;

use lhmpp::model::config::{EncoderConfig, GsHeadConfig, ImageBackboneConfig, PitBlockSpec};
use lhmpp::model::dpt::{DptConfig, NeuralRenderer};
use lhmpp::model::encoder::{DinoEncoder, EncoderBlock};
use lhmpp::model::frame_block::{FrameBlock, RopeTables, SPECIAL_TOKENS};
use lhmpp::model::gs_head::GsHead;
use lhmpp::model::joint_block::JointBlock;
use lhmpp::model::point::block::PtBlock;
use lhmpp::model::point::serialization::{serialize_all, SerializationOrder};
use lhmpp::model::point::sparse_conv::{NeighbourMap, SubMConv3d};
use lhmpp::model::shape_head::{ShapeHead, ShapeHeadConfig};

/// A bf16 output passes below `max(--max-rel-bf16, BF16_TORCH_FACTOR × PyTorch's own bf16 error)`.
const BF16_TORCH_FACTOR: f64 = 2.0;

/// Arguments of `lhmpp model parity`.
#[derive(Args, Debug)]
pub struct ParityArgs {
    /// Folder of `<block>.safetensors` fixtures (scripts/parity/generate.py).
    #[arg(long, default_value = "tests/fixtures/parity")]
    fixtures: PathBuf,
    /// Device: cpu or cuda (cuda needs a `--features cuda` build).
    #[arg(long, default_value = "cpu")]
    device: String,
    /// Dtypes to run our blocks in (comma separated): f32, bf16.
    #[arg(long, value_delimiter = ',', default_value = "f32")]
    dtype: Vec<String>,
    /// Only these blocks (repeatable; default: every fixture in the folder).
    #[arg(long)]
    block: Vec<String>,
    /// Relative-error limit in f32.
    #[arg(long, default_value_t = 1e-4)]
    max_rel_f32: f64,
    /// Relative-error limit in bf16 (raised to twice PyTorch's own bf16 error where that is larger).
    #[arg(long, default_value_t = 1e-2)]
    max_rel_bf16: f64,
    /// Print the rows as one JSON array instead of a table.
    #[arg(long)]
    json: bool,
    /// Exit with an error when a row is over its limit.
    #[arg(long)]
    check: bool,
}

/// One compared output.
#[derive(Debug, Serialize)]
struct Row {
    block: String,
    dims: String,
    device: String,
    dtype: String,
    output: String,
    max_abs: f64,
    max_rel: f64,
    /// PyTorch's own bf16 error on this output (bf16 rows only).
    torch_bf16_rel: Option<f64>,
    limit: f64,
    pass: bool,
    /// Why the block could not run in this dtype/device (e.g. an op without a bf16 kernel).
    error: Option<String>,
}

/// A loaded fixture: its kind, dims and tensors (on the CPU, as stored).
struct Fixture {
    path: PathBuf,
    block: String,
    config: Value,
    prefix: String,
    torch_bf16: HashMap<String, f64>,
    tensors: HashMap<String, Tensor>,
}

impl Fixture {
    fn load(path: &Path) -> anyhow::Result<Self> {
        let data = std::fs::read(path).with_context(|| format!("reading {}", path.display()))?;
        let (_, meta) = safetensors::SafeTensors::read_metadata(&data)
            .with_context(|| format!("{}: not a safetensors file", path.display()))?;
        let meta = meta.metadata().clone().unwrap_or_default();
        let get = |k: &str| {
            meta.get(k)
                .cloned()
                .with_context(|| format!("{}: metadata key `{k}` missing", path.display()))
        };
        let config: Value = serde_json::from_str(&get("config")?)
            .with_context(|| format!("{}: metadata `config` is not JSON", path.display()))?;
        let torch_bf16 = match meta.get("torch_bf16") {
            Some(s) => serde_json::from_str(s)
                .with_context(|| format!("{}: metadata `torch_bf16`", path.display()))?,
            None => HashMap::new(),
        };
        let tensors = candle_core::safetensors::load_buffer(&data, &Device::Cpu)
            .with_context(|| format!("loading tensors of {}", path.display()))?;
        Ok(Self {
            path: path.to_path_buf(),
            block: get("block")?,
            prefix: get("prefix")?.trim_end_matches('.').to_string(),
            config,
            torch_bf16,
            tensors,
        })
    }

    fn usize(&self, key: &str) -> anyhow::Result<usize> {
        self.config[key]
            .as_u64()
            .map(|v| v as usize)
            .with_context(|| format!("{}: config key `{key}` missing", self.path.display()))
    }

    fn f64(&self, key: &str) -> anyhow::Result<f64> {
        self.config[key]
            .as_f64()
            .with_context(|| format!("{}: config key `{key}` missing", self.path.display()))
    }

    /// Short description of the dims for the table (`key=value` of the scalar config entries).
    fn dims(&self) -> String {
        self.config
            .as_object()
            .map(|o| {
                o.iter()
                    .map(|(k, v)| format!("{k}={v}"))
                    .collect::<Vec<_>>()
                    .join(" ")
            })
            .unwrap_or_default()
    }

    /// The weights (everything but `parity.*`) as a var builder rooted at the block's prefix.
    fn var_builder(&self, dtype: DType, dev: &Device) -> anyhow::Result<VarBuilder<'static>> {
        let mut weights = HashMap::new();
        for (k, t) in &self.tensors {
            if !k.starts_with("parity.") {
                weights.insert(k.clone(), t.to_device(dev)?);
            }
        }
        Ok(VarBuilder::from_tensors(weights, dtype, dev).pp(&self.prefix))
    }

    /// Input `name` on `dev`, floating inputs cast to `dtype`.
    fn input(&self, name: &str, dtype: DType, dev: &Device) -> anyhow::Result<Tensor> {
        let key = format!("parity.input.{name}");
        let t = self
            .tensors
            .get(&key)
            .with_context(|| format!("{}: tensor `{key}` missing", self.path.display()))?;
        let t = if t.dtype().is_float() {
            t.to_dtype(dtype)?
        } else {
            t.clone()
        };
        Ok(t.to_device(dev)?)
    }

    /// The voxel cells of input `grid` (`[N, 3]` integers).
    fn grid(&self) -> anyhow::Result<Vec<[u32; 3]>> {
        Ok(self
            .input("grid", DType::F32, &Device::Cpu)?
            .to_dtype(DType::I64)?
            .to_vec2::<i64>()?
            .into_iter()
            .map(|r| [r[0] as u32, r[1] as u32, r[2] as u32])
            .collect())
    }

    /// PyTorch's output `name` (f32, CPU).
    fn expected(&self, name: &str) -> anyhow::Result<&Tensor> {
        let key = format!("parity.output.{name}");
        self.tensors
            .get(&key)
            .with_context(|| format!("{}: tensor `{key}` missing", self.path.display()))
    }
}

/// Runs our block of the fixture's kind; returns `(output name, tensor)` pairs.
fn run_block(fx: &Fixture, dtype: DType, dev: &Device) -> anyhow::Result<Vec<(String, Tensor)>> {
    let vb = fx.var_builder(dtype, dev)?;
    let encoder_cfg = |depth: usize| -> anyhow::Result<EncoderConfig> {
        Ok(EncoderConfig {
            embed_dim: fx.usize("dim")?,
            depth,
            num_heads: fx.usize("heads")?,
            patch_size: fx.usize("patch").unwrap_or(14),
            num_register_tokens: fx.usize("registers").unwrap_or(4),
            pos_embed_grid: fx.usize("grid").unwrap_or(37),
            mlp_ratio: fx.f64("mlp_ratio")?,
            layer_norm_eps: 1e-6,
        })
    };
    let out = |name: &str, t: Tensor| (name.to_string(), t);
    Ok(match fx.block.as_str() {
        "dino_block" => {
            let block = EncoderBlock::new(&encoder_cfg(1)?, vb)?;
            vec![out("y", block.forward(&fx.input("x", dtype, dev)?)?)]
        }
        "dino_encoder" => {
            let enc = DinoEncoder::new(&encoder_cfg(fx.usize("depth")?)?, vb)?;
            let o = enc.forward(&fx.input("images", dtype, dev)?)?;
            vec![out("cls", o.cls), out("patch_tokens", o.patch_tokens)]
        }
        "frame_block" => {
            let dim = fx.usize("dim")?;
            let heads = fx.usize("heads")?;
            let cfg = ImageBackboneConfig {
                depth: 1,
                num_heads: heads,
                mlp_ratio: fx.f64("mlp_ratio")?,
                rope_base: fx.f64("rope_base")?,
                qk_norm: true,
                init_values: 0.01,
            };
            let block = FrameBlock::new(dim, &cfg, vb)?;
            let rope = RopeTables::new(
                dim / heads,
                fx.usize("h")?,
                fx.usize("w")?,
                SPECIAL_TOKENS,
                cfg.rope_base,
                dtype,
                dev,
            )?;
            let (y, metric) = block.forward(&fx.input("x", dtype, dev)?, &rope)?;
            vec![out("y", y), out("metric", metric)]
        }
        "joint_block" | "joint_block_pre_only" => {
            let spec = PitBlockSpec {
                point_dim: fx.usize("pv")?,
                context_pre_only: fx.block == "joint_block_pre_only",
            };
            let block = JointBlock::new(
                spec,
                fx.usize("dim")?,
                fx.usize("heads")?,
                fx.usize("context_dim")?,
                vb,
            )?;
            let (points, image) = block.forward(
                &fx.input("points", dtype, dev)?,
                &fx.input("image", dtype, dev)?,
                &fx.input("temb", dtype, dev)?,
            )?;
            let mut v = vec![out("points", points)];
            if let Some(image) = image {
                v.push(out("image", image));
            }
            v
        }
        "sparse_conv" => {
            let conv = SubMConv3d::new(fx.usize("c_in")?, fx.usize("c_out")?, vb)?;
            let map = NeighbourMap::new(&fx.grid()?, dev)?;
            vec![out("y", conv.forward(&fx.input("x", dtype, dev)?, &map)?)]
        }
        "ptv3_block" => {
            let block = PtBlock::new(
                fx.usize("c")?,
                fx.usize("heads")?,
                fx.usize("patch")?,
                fx.f64("mlp_ratio")?,
                fx.usize("order_index")?,
                vb,
            )?;
            let grid = fx.grid()?;
            let orders = serialize_all(&grid, &SerializationOrder::official());
            let map = NeighbourMap::new(&grid, dev)?;
            let y = block.forward(&fx.input("x", dtype, dev)?, &orders, &map)?;
            let mut v = vec![out("y", y)];
            for (name, o) in ["z", "z_trans", "hilbert", "hilbert_trans"]
                .iter()
                .zip(&orders)
            {
                let perm: Vec<i64> = o.order.iter().map(|&i| i64::from(i)).collect();
                let n = perm.len();
                v.push(out(
                    &format!("order_{name}"),
                    Tensor::from_vec(perm, n, &Device::Cpu)?,
                ));
            }
            v
        }
        "gs_head" => {
            let cfg = GsHeadConfig {
                gs_query_dim: fx.usize("q")?,
                n_neurons: fx.usize("n")?,
                n_hidden_layers: fx.usize("hidden_layers")?,
                use_rgb: true,
                clip_scaling: fx.f64("clip_scaling")?,
                xyz_offset_max_step: fx.f64("max_step")?,
                background_dim: None,
            };
            let head = GsHead::new(&cfg, vb)?;
            let g = head.forward(
                &fx.input("features", dtype, dev)?,
                &fx.input("anchors", dtype, dev)?,
            )?;
            vec![
                out("colors", g.colors),
                out("scales", g.scales),
                out("offsets", g.offsets),
                out("positions", g.positions),
                out("opacities", g.opacities),
                out("rotations", g.rotations),
            ]
        }
        "dpt" | "dpt_pixelshuffle" | "dpt_shared" => {
            let oc = fx.config["oc"]
                .as_array()
                .filter(|a| a.len() == 4)
                .with_context(|| {
                    format!("{}: config `oc` must have 4 entries", fx.path.display())
                })?;
            let oc: Vec<usize> = oc
                .iter()
                .filter_map(|v| v.as_u64())
                .map(|v| v as usize)
                .collect();
            let cfg = DptConfig {
                in_channels: fx.usize("c")?,
                patch_size: fx.usize("patch")?,
                embed_dim: fx.usize("embed")?,
                features: fx.usize("features")?,
                out_channels: [oc[0], oc[1], oc[2], oc[3]],
                pixel_shuffle: match fx.block.as_str() {
                    "dpt_pixelshuffle" => Some(fx.usize("pixel_shuffle")?),
                    _ => None,
                },
                shared_tokens: fx.block == "dpt_shared",
            };
            let r = NeuralRenderer::new(&cfg, vb)?;
            let (rgb, mask) = r.forward(&fx.input("features", dtype, dev)?)?;
            vec![out("rgb", rgb), out("mask", mask)]
        }
        "shape_head" => {
            let cfg = ShapeHeadConfig {
                dim_in: fx.usize("dim")?,
                target_dim: fx.usize("target")?,
                trunk_depth: fx.usize("trunk_depth")?,
                num_heads: fx.usize("heads")?,
                mlp_ratio: fx.f64("mlp_ratio")?,
                init_values: 0.01,
                num_iterations: fx.usize("iterations")?,
                shape_token_idx: 0,
            };
            let head = ShapeHead::new(&cfg, vb)?;
            let tokens = fx.input("tokens", dtype, dev)?;
            let slot = tokens.narrow(1, 0, 1)?.squeeze(1)?.mean_keepdim(0)?;
            let steps = Tensor::cat(&head.forward(&slot)?, 0)?;
            vec![out("betas", head.predict(&tokens)?), out("steps", steps)]
        }
        other => bail!("{}: unknown block kind `{other}`", fx.path.display()),
    })
}

/// `(max |a − b|, max |a − b| / max |b|)` over all elements, in f64.
fn errors(ours: &Tensor, torch: &Tensor) -> anyhow::Result<(f64, f64)> {
    if ours.dims() != torch.dims() {
        bail!(
            "shape {:?} where PyTorch has {:?}",
            ours.dims(),
            torch.dims()
        );
    }
    let a = ours
        .to_device(&Device::Cpu)?
        .to_dtype(DType::F64)?
        .flatten_all()?;
    let b = torch.to_dtype(DType::F64)?.flatten_all()?;
    let max_abs = (&a - &b)?.abs()?.max(0)?.to_scalar::<f64>()?;
    let scale = b.abs()?.max(0)?.to_scalar::<f64>()?;
    if !max_abs.is_finite() {
        return Ok((f64::INFINITY, f64::INFINITY));
    }
    Ok((max_abs, max_abs / scale.max(1e-30)))
}

fn parse_device(name: &str) -> anyhow::Result<Device> {
    Ok(match name {
        "cpu" => Device::Cpu,
        "cuda" => Device::new_cuda(0).context("CUDA device (build with --features cuda)")?,
        other => bail!("unknown device `{other}` (cpu or cuda)"),
    })
}

/// A `--dtype` value: `f32` or `bf16`.
pub(crate) fn parse_dtype(name: &str) -> anyhow::Result<DType> {
    Ok(match name {
        "f32" => DType::F32,
        "bf16" => DType::BF16,
        other => bail!("unknown dtype `{other}` (f32 or bf16)"),
    })
}

/// The fixture files of `dir`, sorted, filtered to `blocks` when given.
fn fixture_paths(dir: &Path, blocks: &[String]) -> anyhow::Result<Vec<PathBuf>> {
    let mut paths: Vec<PathBuf> = std::fs::read_dir(dir)
        .with_context(|| format!("reading fixture folder {}", dir.display()))?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.extension().is_some_and(|e| e == "safetensors"))
        .filter(|p| {
            blocks.is_empty()
                || p.file_stem()
                    .and_then(|s| s.to_str())
                    .is_some_and(|s| blocks.iter().any(|b| b == s))
        })
        .collect();
    paths.sort();
    if paths.is_empty() {
        bail!("no fixtures {blocks:?} in {}", dir.display());
    }
    Ok(paths)
}

/// Runs `lhmpp model parity`.
pub fn run(args: ParityArgs) -> anyhow::Result<()> {
    let dev = parse_device(&args.device)?;
    let dtypes = args
        .dtype
        .iter()
        .map(|d| parse_dtype(d).map(|t| (d.clone(), t)))
        .collect::<anyhow::Result<Vec<_>>>()?;
    let mut rows = Vec::new();
    for path in fixture_paths(&args.fixtures, &args.block)? {
        let fx = Fixture::load(&path)?;
        for (dname, dtype) in &dtypes {
            let limit = if *dtype == DType::F32 {
                args.max_rel_f32
            } else {
                args.max_rel_bf16
            };
            let outputs = match run_block(&fx, *dtype, &dev) {
                Ok(o) => o,
                Err(e) => {
                    rows.push(Row {
                        block: fx.block.clone(),
                        dims: fx.dims(),
                        device: args.device.clone(),
                        dtype: dname.clone(),
                        output: "-".into(),
                        max_abs: f64::NAN,
                        max_rel: f64::NAN,
                        torch_bf16_rel: None,
                        limit,
                        pass: false,
                        error: Some(format!("{e:#}").lines().next().unwrap_or("").to_string()),
                    });
                    continue;
                }
            };
            for (name, ours) in outputs {
                let (max_abs, max_rel) = errors(&ours, fx.expected(&name)?)
                    .with_context(|| format!("{}: output `{name}`", path.display()))?;
                let torch_bf16_rel = (*dtype != DType::F32)
                    .then(|| fx.torch_bf16.get(&name).copied())
                    .flatten();
                // Where PyTorch's own bf16 run is further off than the limit (normalised
                // quaternions of short vectors, exp-clamped scales), allow twice its error.
                let limit = torch_bf16_rel.map_or(limit, |t| limit.max(BF16_TORCH_FACTOR * t));
                rows.push(Row {
                    block: fx.block.clone(),
                    dims: fx.dims(),
                    device: args.device.clone(),
                    dtype: dname.clone(),
                    torch_bf16_rel,
                    output: name,
                    max_abs,
                    max_rel,
                    limit,
                    pass: max_rel < limit,
                    error: None,
                });
            }
        }
    }
    if args.json {
        println!("{}", serde_json::to_string_pretty(&rows)?);
    } else {
        print_table(&rows);
    }
    let failed: Vec<String> = rows
        .iter()
        .filter(|r| !r.pass)
        .map(|r| format!("{}.{} ({})", r.block, r.output, r.dtype))
        .collect();
    if args.check && !failed.is_empty() {
        bail!("over the limit: {}", failed.join(", "));
    }
    Ok(())
}

fn print_table(rows: &[Row]) {
    println!(
        "{:<22} {:<6} {:<5} {:<19} {:>11} {:>11} {:>11} {:>9} {:>5}",
        "block", "device", "dtype", "output", "max abs", "max rel", "torch bf16", "limit", "ok"
    );
    let mut last_block = String::new();
    for r in rows {
        if r.block != last_block {
            println!("  # {}: {}", r.block, r.dims);
            last_block = r.block.clone();
        }
        let torch = r
            .torch_bf16_rel
            .map_or_else(|| "-".to_string(), |v| format!("{v:.3e}"));
        println!(
            "{:<22} {:<6} {:<5} {:<19} {:>11.3e} {:>11.3e} {:>11} {:>9.1e} {:>5}",
            r.block,
            r.device,
            r.dtype,
            r.output,
            r.max_abs,
            r.max_rel,
            torch,
            r.limit,
            if r.pass { "yes" } else { "NO" }
        );
        if let Some(e) = &r.error {
            println!("    error: {e}");
        }
    }
    println!("relative error = max|ours - torch| / max|torch| against PyTorch's f32 output");
}
