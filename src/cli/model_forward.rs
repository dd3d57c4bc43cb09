//! `lhmpp model forward`: one whole forward pass of the network on tensors from a safetensors
//! file, every output written to another: for parity with the PyTorch twin in
//! `scripts/train/lhmpp_torch.py` (`scripts/train/check_parity.py`) and with the official code
//! (`scripts/parity/official/`), whose random draws it replays. Tensor names:
//! docs/model-forward.md.

use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{bail, Context};
use candle_core::{DType, Device, Tensor};
use clap::Args;

use lhmpp::body::BodyTemplate;
use lhmpp::model::config::LhmppConfig;
use lhmpp::model::draws::ForwardDraws;
use lhmpp::model::lhmpp::Lhmpp;
use lhmpp::model::{checkpoint, gs_head, hub, tensor_file};

/// Arguments of `lhmpp model forward`.
#[derive(Args, Debug)]
pub struct ForwardArgs {
    /// Weights: a safetensors file or hub folder, or `random:SEED` for seeded random weights.
    #[arg(long, required_unless_present = "dump_anchors")]
    checkpoint: Option<String>,
    /// Preset (default: the one in the checkpoint's metadata, else `tiny`).
    #[arg(long, alias = "config")]
    preset: Option<String>,
    /// Our network config as JSON (`LhmppConfig`), for a safetensors file at widths that no
    /// preset or official config.json expresses (the official fixture's reduced DINOv2 and DPT).
    #[arg(long, conflicts_with = "preset")]
    config_json: Option<PathBuf>,
    /// Dtype of the weights and activations (`f32` or `bf16`, as `model.dtype`); outputs are
    /// written in f32 either way.
    #[arg(long, default_value = "f32", value_parser = dtype_arg)]
    dtype: DType,
    /// Input safetensors: `images` [V,3,H,W] in [0,1], `anchors` [N,3], `normals` [N,3];
    /// optional part masks `is_rhand`, `is_lhand`, `is_upper_body`, `is_constrain_body` [N]
    /// (BOOL or u8), draws `pooling_orders` [P,4] and `tome_destinations` [B,cells] (integers),
    /// and a splatted `feature_image` [V',C,H',W'] for the neural renderer.
    #[arg(long, alias = "inputs", required_unless_present = "dump_anchors")]
    input: Option<PathBuf>,
    /// Output safetensors: features, colors, scales, rotations, opacities, offsets, positions,
    /// and neural_rgb, neural_mask given a feature image (f32; or `anchors` and `normals` with
    /// --dump-anchors).
    #[arg(short, long)]
    output: PathBuf,
    /// Write the node's body anchors (`anchors`, `normals`: MakeHuman template, --points,
    /// --seed) to OUTPUT instead of running the network.
    #[arg(long)]
    dump_anchors: bool,
    /// Anchor count for --dump-anchors (the node's `model.num_points`).
    #[arg(long, default_value_t = 4096)]
    points: usize,
    /// Anchor sampling seed for --dump-anchors (the node's `model.seed`).
    #[arg(long, default_value_t = 1)]
    seed: u64,
}

/// Runs `lhmpp model forward`.
pub fn run(args: ForwardArgs) -> anyhow::Result<()> {
    if args.dump_anchors {
        return dump_anchors(&args.output, args.points, args.seed);
    }
    let (Some(spec), Some(input)) = (&args.checkpoint, &args.input) else {
        bail!("--checkpoint and --input are required (unless --dump-anchors)");
    };
    let dev = Device::Cpu;
    let model = match &args.config_json {
        Some(file) => build_with_config(spec, file, args.dtype, &dev)?,
        None => build(spec, args.preset.as_deref(), args.dtype, &dev)?,
    };
    let tensors = tensor_file::read_safetensors(input, &dev)?;
    let get = |name: &str| -> anyhow::Result<Tensor> {
        let t = tensors
            .get(name)
            .with_context(|| format!("{}: no tensor `{name}`", input.display()))?;
        Ok(t.to_dtype(DType::F32)?)
    };
    let (images, anchors, normals) = (get("images")?, get("anchors")?, get("normals")?);
    let draws = ForwardDraws::from_tensors(&tensors)
        .with_context(|| format!("{}: draws", input.display()))?;
    let masks = gs_head::part_masks(&tensors)
        .with_context(|| format!("{}: part masks", input.display()))?;
    let (v, _, h, w) = images.dims4()?;
    let start = Instant::now();
    let views = (0..v)
        .map(|i| model.encode_view(&images.get(i)?))
        .collect::<candle_core::Result<Vec<_>>>()?;
    let (feat, _) = model.fuse_with_draws(&anchors, &normals, &views, &draws)?;
    let mut g = model.gs_head().forward(&feat, &anchors)?;
    if let Some((hands, upper)) = &masks {
        g = g.with_part_masks(hands, upper)?;
    }
    let secs = start.elapsed().as_secs_f64();
    let neural = match tensors.get("feature_image") {
        Some(f) => {
            let start = Instant::now();
            let (rgb, mask) = model.neural_renderer().forward(&f.to_dtype(DType::F32)?)?;
            Some((rgb, mask, start.elapsed().as_secs_f64()))
        }
        None => None,
    };
    let mut out: HashMap<String, Tensor> = [
        ("features", g.features),
        ("colors", g.colors),
        ("scales", g.scales),
        ("rotations", g.rotations),
        ("opacities", g.opacities),
        ("offsets", g.offsets),
        ("positions", g.positions),
    ]
    .into_iter()
    .map(|(k, t)| Ok((k.to_string(), t.to_dtype(DType::F32)?)))
    .collect::<candle_core::Result<_>>()?;
    if let Some((rgb, mask, _)) = &neural {
        out.insert("neural_rgb".into(), rgb.to_dtype(DType::F32)?);
        out.insert("neural_mask".into(), mask.to_dtype(DType::F32)?);
    }
    candle_core::safetensors::save(&out, &args.output)
        .with_context(|| format!("writing {}", args.output.display()))?;
    println!(
        "forward `{}`: {v} views {h}x{w}, {} anchors -> {} Gaussians (features {:?}) in {secs:.3} s{}{}{}; wrote {}",
        model.config().preset,
        anchors.dim(0)?,
        out["positions"].dim(0)?,
        out["features"].dims(),
        if draws.is_default() { "" } else { ", replayed draws" },
        if masks.is_some() { ", part masks" } else { "" },
        neural.map_or(String::new(), |(_, _, s)| format!(", neural renderer {s:.3} s")),
        args.output.display()
    );
    Ok(())
}

/// `--dtype` values, as `lhmpp model parity --dtype` reads them.
fn dtype_arg(s: &str) -> Result<DType, String> {
    crate::cli::model_parity::parse_dtype(s).map_err(|e| e.to_string())
}

/// The network for `spec` (`random:SEED` or a checkpoint path) in `dtype` on `dev`.
fn build(spec: &str, preset: Option<&str>, dtype: DType, dev: &Device) -> anyhow::Result<Lhmpp> {
    if let Some(seed) = spec.strip_prefix("random:") {
        let seed: u64 = seed
            .parse()
            .with_context(|| format!("bad seed in `{spec}`"))?;
        let cfg = LhmppConfig::preset(preset.unwrap_or("tiny"))?;
        return Ok(Lhmpp::new(
            &cfg,
            checkpoint::seeded_var_builder(seed, dtype, dev),
        )?);
    }
    let path = Path::new(spec);
    let name = match preset {
        Some(p) => p.to_string(),
        None if path.is_file() => checkpoint::read_metadata(path)?
            .0
            .unwrap_or_else(|| "tiny".into()),
        None => "tiny".into(),
    };
    let loaded = hub::load_checkpoint(path, &LhmppConfig::preset(&name)?, dtype, dev)
        .with_context(|| format!("loading {spec}"))?;
    Ok(Lhmpp::new(&loaded.config, loaded.var_builder)?)
}

/// The network of `config` (an `LhmppConfig` JSON file) with the weights of file `spec`, in
/// `dtype`.
fn build_with_config(
    spec: &str,
    config: &Path,
    dtype: DType,
    dev: &Device,
) -> anyhow::Result<Lhmpp> {
    let text =
        std::fs::read_to_string(config).with_context(|| format!("reading {}", config.display()))?;
    let cfg: LhmppConfig =
        serde_json::from_str(&text).with_context(|| format!("parsing {}", config.display()))?;
    let loaded = hub::load_checkpoint(Path::new(spec), &cfg, dtype, dev)
        .with_context(|| format!("loading {spec}"))?;
    Ok(Lhmpp::new(&loaded.config, loaded.var_builder)?)
}

/// Writes `anchors` and `normals` `[n, 3]` sampled as the node does.
fn dump_anchors(output: &Path, n: usize, seed: u64) -> anyhow::Result<()> {
    let a = BodyTemplate::load_default()?.sample_anchors(n, seed);
    let rows = |v: &[glam::Vec3]| v.iter().flat_map(|p| p.to_array()).collect::<Vec<f32>>();
    let dev = Device::Cpu;
    let n = a.positions.len();
    let out = HashMap::from([
        (
            "anchors".to_string(),
            Tensor::from_vec(rows(&a.positions), (n, 3), &dev)?,
        ),
        (
            "normals".to_string(),
            Tensor::from_vec(rows(&a.normals), (n, 3), &dev)?,
        ),
    ]);
    candle_core::safetensors::save(&out, output)
        .with_context(|| format!("writing {}", output.display()))?;
    println!(
        "wrote {} anchors (MakeHuman template, seed {seed}) to {}",
        n,
        output.display()
    );
    Ok(())
}
