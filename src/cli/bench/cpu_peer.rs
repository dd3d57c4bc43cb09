//! `lhmpp bench cpu-peer`: the pieces of the PyTorch peer benchmark
//! (`scripts/bench-cpu-peer` runs both) timed with our candle code: matmul 1024³, the DINOv2
//! ViT-S/14 and ViT-B/14 with 4 registers (our `DinoEncoder`, random weights) at 224 and
//! 518 px, and one SD3-style joint-attention layer (d = 384, 6 heads, 4,096 point tokens +
//! 256 image tokens per view) written with candle ops and our shared attention; with
//! `--only dpt` the LHM++ neural renderer (our `NeuralRenderer`, random weights) in the tiny and
//! lhmpp-700m shapes at `--dpt-sizes`, with a per-stage breakdown (`dpt-candle` times the same
//! renderer on stock candle ops); `conv3x3` (ours only) times the 3×3 convolution shapes of
//! the lhmpp-700m head through im2col + gemm, Winograd F(2×2) and F(4×4), one after the other.
//!
//! The table uses the peer's piece and config names and columns so the two can be joined.

use std::time::Instant;

use anyhow::Context;
use candle_core::{DType, Device, Module, Tensor};
use candle_nn::VarBuilder;
use clap::Args;

use lhmpp::kernels::conv2d::{Epilogue, PackedConv2d};
use lhmpp::kernels::feature_map::FeatureMap;
use lhmpp::kernels::layer_norm::{layer_norm, LayerNorm};
use lhmpp::kernels::linear::{linear, Linear};
use lhmpp::kernels::winograd::{F2X2, F4X4};
use lhmpp::model::attention::{attention, attention_reference, merge_heads, split_heads};
use lhmpp::model::checkpoint::seeded_var_builder;
use lhmpp::model::config::EncoderConfig;
use lhmpp::model::dpt::{DptConfig, DptStageTimes, NeuralRenderer};
use lhmpp::model::encoder::DinoEncoder;

/// Arguments of `lhmpp bench cpu-peer`.
#[derive(Args, Debug)]
pub struct CpuPeerArgs {
    /// CPU threads (0 = all).
    #[arg(long, default_value_t = 2)]
    threads: usize,
    /// Timed runs per config (the median is printed); one warm-up run precedes them.
    #[arg(long, default_value_t = 3)]
    runs: usize,
    /// Comma list of pieces: matmul, vit, joint, dpt (the peer's), and `attn`, `dpt-candle`,
    /// `conv3x3` (ours only: the fused attention against the plain candle ops at the joint
    /// layer's shape; the neural renderer on stock candle ops; the head's 3×3 convolutions by
    /// each algorithm).
    #[arg(long, value_delimiter = ',', default_value = "matmul,vit,joint")]
    only: Vec<String>,
    /// Square image sizes of the dpt pieces (multiples of 7).
    #[arg(long, value_delimiter = ',', default_value = "588")]
    dpt_sizes: Vec<usize>,
    /// Smallest config of each piece only, 2 timed runs (smoke test).
    #[arg(long)]
    quick: bool,
    /// Weights and activations in `f32` or `bf16` (matmul, vit, joint, attn, dpt; bf16
    /// products with f32 accumulation, as PyTorch's bf16 CPU kernels; the dpt head of a bf16
    /// model runs its convolutions in f32, see `NeuralRenderer::new`).
    #[arg(long, default_value = "f32", value_parser = ["f32", "bf16"])]
    dtype: String,
}

/// One timed config: median and minimum milliseconds over `runs`.
struct Timing {
    median_ms: f64,
    min_ms: f64,
    runs: usize,
}

/// Runs `f` once to warm up, then `runs` times.
fn time_runs(runs: usize, mut f: impl FnMut() -> anyhow::Result<()>) -> anyhow::Result<Timing> {
    f()?;
    let mut t: Vec<f64> = Vec::with_capacity(runs);
    for _ in 0..runs.max(1) {
        let start = Instant::now();
        f()?;
        t.push(start.elapsed().as_secs_f64() * 1e3);
    }
    t.sort_by(f64::total_cmp);
    Ok(Timing {
        median_ms: t[t.len() / 2],
        min_ms: t[0],
        runs: t.len(),
    })
}

/// Collects rows and prints them as the peer script does.
struct Table {
    rows: Vec<(String, String, Timing, f64)>,
}

impl Table {
    fn report(&mut self, piece: &str, config: String, gflop: f64, t: Timing) {
        eprintln!("  done: {piece:14} {config:36} {:10.2} ms", t.median_ms);
        self.rows.push((piece.to_string(), config, t, gflop));
    }

    fn print(&self) {
        println!(
            "{:14} {:36} {:>10} {:>10} {:>4} {:>8} {:>8}",
            "piece", "config", "ms(med)", "ms(min)", "runs", "GFLOP", "GFLOP/s"
        );
        for (piece, config, t, gflop) in &self.rows {
            println!(
                "{piece:14} {config:36} {:10.2} {:10.2} {:4} {:8.2} {:8.1}",
                t.median_ms,
                t.min_ms,
                t.runs,
                gflop,
                gflop / (t.median_ms / 1e3)
            );
        }
    }
}

/// A DINOv2-style encoder config with 4 registers and a 37×37 position table.
fn vit_config(dim: usize, heads: usize) -> EncoderConfig {
    EncoderConfig {
        embed_dim: dim,
        depth: 12,
        num_heads: heads,
        patch_size: 14,
        num_register_tokens: 4,
        pos_embed_grid: 37,
        mlp_ratio: 4.0,
        layer_norm_eps: 1e-6,
    }
}

/// Matmul and attention GFLOP of a ViT forward (the peer's count).
fn vit_gflop(dim: usize, depth: usize, patches: usize, views: usize) -> f64 {
    let t = (1 + 4 + patches) as f64;
    let d = dim as f64;
    let per_block = 24.0 * t * d * d + 4.0 * t * t * d;
    views as f64 * (depth as f64 * per_block + 2.0 * patches as f64 * 3.0 * 196.0 * d) / 1e9
}

/// One modality's weights of the peer's joint-attention layer.
struct Modality {
    ln1: LayerNorm,
    qkv: Linear,
    out: Linear,
    ln2: LayerNorm,
    fc1: Linear,
    fc2: Linear,
}

impl Modality {
    fn new(d: usize, vb: VarBuilder) -> candle_core::Result<Self> {
        Ok(Self {
            ln1: layer_norm(d, 1e-6, vb.pp("ln1"))?,
            qkv: linear(d, 3 * d, vb.pp("qkv"))?,
            out: linear(d, d, vb.pp("out"))?,
            ln2: layer_norm(d, 1e-6, vb.pp("ln2"))?,
            fc1: linear(d, 4 * d, vb.pp("fc1"))?,
            fc2: linear(4 * d, d, vb.pp("fc2"))?,
        })
    }

    /// `x + fc2(gelu(fc1(ln2(x + out(o)))))` after the attention output `o`.
    fn finish(&self, x: &Tensor, o: &Tensor) -> candle_core::Result<Tensor> {
        let x = self.out.forward_residual(o, x, None)?;
        let h = self.fc1.forward_gelu(&self.ln2.forward(&x)?)?;
        self.fc2.forward_residual(&h, &x, None)
    }
}

/// The peer's SD3-style joint layer: per-modality LN + qkv, one softmax over
/// [points; image], per-modality output projection, LN + MLP ×4.
fn joint_forward(
    pt: &Modality,
    im: &Modality,
    xp: &Tensor,
    xi: &Tensor,
    heads: usize,
) -> candle_core::Result<(Tensor, Tensor)> {
    let p = xp.dim(1)?;
    let qkv = Tensor::cat(
        &[
            pt.qkv.forward(&pt.ln1.forward(xp)?)?,
            im.qkv.forward(&im.ln1.forward(xi)?)?,
        ],
        1,
    )?;
    let d = xp.dim(2)?;
    let part = |i: usize| split_heads(&qkv.narrow(2, i * d, d)?, heads);
    let o = merge_heads(&attention(&part(0)?, &part(1)?, &part(2)?, None)?)?;
    let t = o.dim(1)?;
    Ok((
        pt.finish(xp, &o.narrow(1, 0, p)?)?,
        im.finish(xi, &o.narrow(1, p, t - p)?)?,
    ))
}

/// Multiply-add GFLOP (2 per MAC) of the renderer's Linear, convolutions and transposed
/// convolutions at a square `size` (the peer's count).
fn dpt_gflop(cfg: &DptConfig, size: usize) -> f64 {
    let hh = size / cfg.patch_size;
    let n0 = (hh * hh) as f64;
    let conv = |px: f64, cin: usize, cout: usize, k: usize| 2.0 * px * (cin * cout * k * k) as f64;
    let (oc, f) = (cfg.out_channels, cfg.features);
    let p2c = cfg.patch_size * cfg.patch_size * cfg.in_channels;
    let mut g = 2.0 * n0 * (p2c * cfg.embed_dim) as f64;
    g += oc
        .iter()
        .map(|&o| conv(n0, cfg.head_dim(), o, 1))
        .sum::<f64>();
    g += conv(n0, oc[0], oc[0] * 16, 1) + conv(n0, oc[1], oc[1] * 4, 1);
    g += conv(hh.div_ceil(2).pow(2) as f64, oc[3], oc[3], 3);
    let sides = [4 * hh, 2 * hh, hh, hh.div_ceil(2)];
    for (i, (&s, &o)) in sides.iter().zip(&oc).enumerate() {
        let px = (s * s) as f64;
        g += conv(px, o, f, 3);
        g += if i != 3 { 2.0 } else { 1.0 } * 2.0 * conv(px, f, f, 3);
        let up = if i == 0 { 2 * s } else { sides[i - 1] };
        g += conv((up * up) as f64, f, f, 1);
    }
    g += conv(((8 * hh) * (8 * hh)) as f64, f, f / 2, 3);
    g += conv((size * size) as f64, f / 2, 32, 3) + conv((size * size) as f64, 32, 4, 1);
    g / 1e9
}

/// Times the neural renderer for each preset and size, then prints the per-stage breakdown of
/// one more forward as `#` lines.
fn dpt_piece(
    table: &mut Table,
    piece: &str,
    sizes: &[usize],
    quick: bool,
    runs: usize,
    dtype: DType,
) -> anyhow::Result<()> {
    let dev = Device::Cpu;
    let presets: &[(&str, DptConfig)] = if quick {
        &[("tiny", DptConfig::tiny())][..]
    } else {
        &[
            ("tiny", DptConfig::tiny()),
            ("lhmpp-700m", DptConfig::lhmpp_700m()),
        ][..]
    };
    for (name, cfg) in presets {
        let vb = seeded_var_builder(7, dtype, &dev);
        let renderer = NeuralRenderer::new(cfg, vb.pp("neural_renderer"))?;
        let renderer = if piece == "dpt-candle" {
            renderer.with_candle_ops()
        } else {
            renderer
        };
        for &size in sizes {
            let feats = Tensor::randn(0f32, 1.0, (1, cfg.in_channels, size, size), &dev)?
                .to_dtype(dtype)?;
            let t = time_runs(runs, || Ok(renderer.forward(&feats).map(|_| ())?))?;
            table.report(
                piece,
                format!("{name} {size}x{size}"),
                dpt_gflop(cfg, size),
                t,
            );
            let mut times = DptStageTimes::default();
            renderer.forward_timed(&feats, &mut times)?;
            let total: f64 = times.stages.iter().map(|(_, d)| d.as_secs_f64()).sum();
            println!(
                "# {piece} {name} {size}x{size} stages of one forward ({:.1} ms):",
                total * 1e3
            );
            for (stage, d) in &times.stages {
                let ms = d.as_secs_f64() * 1e3;
                println!(
                    "#   {stage:32} {ms:9.1} ms {:5.1}%",
                    100.0 * ms / (total * 1e3)
                );
            }
        }
    }
    Ok(())
}

/// Times the 3×3 stride-1 convolutions of the lhmpp-700m head at 588 px (and the tiny head's
/// widest) through each algorithm; GFLOP are those of direct convolution.
fn conv3x3_piece(table: &mut Table, quick: bool, runs: usize) -> anyhow::Result<()> {
    let dev = Device::Cpu;
    // (c_in, c_out, side): fusion units at 336/84, layer3_rn, output_conv1, output_conv2.0, tiny
    let shapes: &[(usize, usize, usize)] = if quick {
        &[(128, 128, 84)]
    } else {
        &[
            (128, 128, 336),
            (128, 128, 84),
            (512, 128, 84),
            (128, 64, 672),
            (64, 32, 588),
            (16, 16, 336),
        ]
    };
    for &(c_in, c_out, side) in shapes {
        let w = Tensor::randn(0f32, 0.05, (c_out, c_in, 3, 3), &dev)?;
        let b = Tensor::randn(0f32, 0.1, c_out, &dev)?;
        let x = FeatureMap::from_nchw(&Tensor::randn(0f32, 1.0, (1, c_in, side, side), &dev)?)?;
        let conv = PackedConv2d::new(&w, Some(&b), 1, 1)?;
        let gflop = 2.0 * (side * side * c_in * c_out * 9) as f64 / 1e9;
        let config = format!("{c_in}->{c_out} {side}x{side}");
        for (piece, variant) in [
            ("conv3x3-im2col", None),
            ("conv3x3-wino2", Some(F2X2)),
            ("conv3x3-wino4", Some(F4X4)),
        ] {
            let c = conv.clone().with_winograd(variant);
            let t = time_runs(runs.max(5), || {
                Ok(c.forward(&x, Epilogue::default()).map(|_| ())?)
            })?;
            table.report(piece, config.clone(), gflop, t);
        }
    }
    Ok(())
}

/// Runs `lhmpp bench cpu-peer`.
pub fn run(a: CpuPeerArgs) -> anyhow::Result<()> {
    if a.threads > 0 {
        std::env::set_var("RAYON_NUM_THREADS", a.threads.to_string());
        rayon::ThreadPoolBuilder::new()
            .num_threads(a.threads)
            .build_global()
            .ok();
    }
    let runs = if a.quick { a.runs.min(2) } else { a.runs };
    let dev = Device::Cpu;
    let has = |p: &str| a.only.iter().any(|o| o == p);
    let dtype = if a.dtype == "bf16" {
        DType::BF16
    } else {
        DType::F32
    };
    if dtype != DType::F32 && ["dpt-candle", "conv3x3"].iter().any(|p| has(p)) {
        anyhow::bail!("bench cpu-peer: the dpt-candle and conv3x3 pieces run in f32 only");
    }
    println!(
        "# lhmpp bench cpu-peer: candle 0.11.1, {}, random weights, {} rayon threads, gemm avx512 kernels {}, bf16 kernel {:?}",
        a.dtype,
        rayon::current_num_threads(),
        if cfg!(feature = "avx512") { "compiled in" } else { "not compiled" },
        lhmpp::kernels::bf16::Kernel::detect()
    );
    let mut table = Table { rows: Vec::new() };
    if has("matmul") {
        let n = 1024;
        let x = Tensor::randn(0f32, 1.0, (n, n), &dev)?.to_dtype(dtype)?;
        let y = Tensor::randn(0f32, 1.0, (n, n), &dev)?.to_dtype(dtype)?;
        let gflop = 2.0 * (n as f64).powi(3) / 1e9;
        if dtype == DType::F32 {
            let t = time_runs(runs.max(5), || Ok(x.matmul(&y).map(|_| ())?))?;
            table.report("matmul", format!("{n}x{n}x{n} f32"), gflop, t);
        } else {
            // Our bf16 product takes its right operand packed: a linear layer packs its weight
            // once; `matmul-pack` times the packing inside the loop as well.
            let layer = Linear::new(y.t()?.contiguous()?, None);
            let t = time_runs(runs.max(5), || Ok(layer.forward(&x).map(|_| ())?))?;
            table.report("matmul", format!("{n}x{n}x{n} bf16"), gflop, t);
            let t = time_runs(runs.max(5), || {
                let layer = Linear::new(y.t()?.contiguous()?, None);
                Ok(layer.forward(&x).map(|_| ())?)
            })?;
            table.report("matmul-pack", format!("{n}x{n}x{n} bf16"), gflop, t);
        }
    }
    if has("vit") {
        let (sizes, views): (&[usize], &[usize]) = if a.quick {
            (&[224], &[1])
        } else {
            (&[224, 518], &[1, 4])
        };
        for (name, dim, heads) in [("ViT-S/14+reg4", 384, 6), ("ViT-B/14+reg4", 768, 12)] {
            let enc = DinoEncoder::new(&vit_config(dim, heads), seeded_var_builder(3, dtype, &dev))
                .with_context(|| format!("building {name}"))?;
            for &res in sizes {
                let patches = (res / 14) * (res / 14);
                for &v in views {
                    let img = Tensor::rand(0f32, 1.0, (v, 3, res, res), &dev)?;
                    let t = time_runs(runs, || Ok(enc.forward(&img).map(|_| ())?))?;
                    table.report(
                        name,
                        format!("{res}px views={v} tokens={}", 1 + 4 + patches),
                        vit_gflop(dim, 12, patches, v),
                        t,
                    );
                }
            }
        }
    }
    if has("joint") {
        let (d, heads, p) = (384usize, 6usize, 4096usize);
        let vb = seeded_var_builder(5, dtype, &dev);
        let pt = Modality::new(d, vb.pp("pt"))?;
        let im = Modality::new(d, vb.pp("im"))?;
        let views: &[usize] = if a.quick { &[1] } else { &[1, 4, 8] };
        for &v in views {
            let i = 256 * v;
            let xp = Tensor::randn(0f32, 1.0, (1, p, d), &dev)?.to_dtype(dtype)?;
            let xi = Tensor::randn(0f32, 1.0, (1, i, d), &dev)?.to_dtype(dtype)?;
            let t = time_runs(runs, || {
                Ok(joint_forward(&pt, &im, &xp, &xi, heads).map(|_| ())?)
            })?;
            let tokens = (p + i) as f64;
            let gflop = (24.0 * tokens * (d * d) as f64 + 4.0 * tokens * tokens * d as f64) / 1e9;
            table.report(
                "joint-attn",
                format!("d={d} h={heads} P={p} I={i} (views={v})"),
                gflop,
                t,
            );
        }
    }
    if has("attn") {
        let views: &[usize] = if a.quick { &[1] } else { &[1, 4, 8] };
        for &v in views {
            let l = 4096 + 256 * v;
            let q = Tensor::randn(0f32, 1.0, (1, 6, l, 64), &dev)?.to_dtype(dtype)?;
            let k = Tensor::randn(0f32, 1.0, (1, 6, l, 64), &dev)?.to_dtype(dtype)?;
            let w = Tensor::randn(0f32, 1.0, (1, 6, l, 64), &dev)?.to_dtype(dtype)?;
            let gflop = 4.0 * 6.0 * (l * l * 64) as f64 / 1e9;
            let t = time_runs(runs, || Ok(attention(&q, &k, &w, None).map(|_| ())?))?;
            table.report("attn-fused", format!("B=1 H=6 L={l} D=64"), gflop, t);
            let t = time_runs(runs, || {
                Ok(attention_reference(&q, &k, &w, None).map(|_| ())?)
            })?;
            table.report("attn-candle", format!("B=1 H=6 L={l} D=64"), gflop, t);
        }
    }
    if has("conv3x3") {
        conv3x3_piece(&mut table, a.quick, runs)?;
    }
    for piece in ["dpt", "dpt-candle"] {
        if has(piece) {
            dpt_piece(&mut table, piece, &a.dpt_sizes, a.quick, runs, dtype)?;
        }
    }
    println!();
    table.print();
    Ok(())
}
