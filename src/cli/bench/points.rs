//! `lhmpp bench points`: time of each point-backbone stage (embed, encoder levels, decoder
//! levels) on a seeded synthetic body surface, random weights, f32 or bf16, CPU; prints a
//! table (after one untimed warm-up pass).

use anyhow::{Context, Result};
use candle_core::{DType, Device, Tensor};
use candle_nn::{VarBuilder, VarMap};
use clap::Args;
use lhmpp::model::point::synthetic::body_surface_points;
use lhmpp::model::point::{PointBackbone, PointBackboneConfig};
use std::time::Instant;

/// Arguments of `lhmpp bench points`.
#[derive(Args, Debug)]
pub struct PointsBenchArgs {
    /// Presets: tiny, s, m (= lhmpp-700m sizes), l.
    #[arg(long, value_delimiter = ',', default_value = "tiny,m")]
    presets: Vec<String>,
    /// Input point counts.
    #[arg(long, value_delimiter = ',', default_value = "40000,160000")]
    points: Vec<usize>,
    /// CPU threads (0 = all).
    #[arg(long, default_value_t = 0)]
    threads: usize,
    /// Weights and activations: `f32` or `bf16` (bf16 products with f32 accumulation).
    #[arg(long, default_value = "f32", value_parser = ["f32", "bf16"])]
    dtype: String,
}

/// Prints one row per preset × point count: per-stage milliseconds and tokens per level.
pub fn run(a: PointsBenchArgs) -> Result<()> {
    if a.threads > 0 {
        rayon::ThreadPoolBuilder::new()
            .num_threads(a.threads)
            .build_global()
            .context("thread pool")?;
    }
    let dev = Device::Cpu;
    let dtype = if a.dtype == "bf16" {
        DType::BF16
    } else {
        DType::F32
    };
    println!(
        "| preset | dtype | points | stage | tokens | ms |\n| --- | --- | ---: | --- | ---: | ---: |"
    );
    for preset in &a.presets {
        let cfg = match preset.as_str() {
            "tiny" => PointBackboneConfig::tiny(),
            "s" => PointBackboneConfig::small(),
            "l" => PointBackboneConfig::large(),
            "m" | "lhmpp-700m" => PointBackboneConfig::lhmpp_700m(),
            other => anyhow::bail!("unknown preset `{other}`"),
        };
        let vm = VarMap::new();
        let vb = VarBuilder::from_varmap(&vm, dtype, &dev);
        let bb = PointBackbone::new(&cfg, vb.pp("transformer").pp("point_backbone"))?;
        for &n in &a.points {
            let (p, nrm) = body_surface_points(n, 42);
            let coords = Tensor::from_vec(p.concat(), (n, 3), &dev)?;
            let normals = Tensor::from_vec(nrm.concat(), (n, 3), &dev)?;
            // Warm-up: first-touch allocations and thread start-up are not timed.
            let mut s = bb.embed(&coords, &normals)?;
            for l in 0..cfg.num_levels() {
                s = bb.encoder_stage(l, s)?;
            }
            for l in (0..cfg.num_levels() - 1).rev() {
                s = bb.decoder_stage(l, s)?;
            }
            drop(s);
            let total = Instant::now();
            let row = |stage: &str, tokens: usize, t: Instant| {
                println!(
                    "| {preset} | {} | {n} | {stage} | {tokens} | {:.0} |",
                    a.dtype,
                    t.elapsed().as_secs_f64() * 1e3
                )
            };
            let t = Instant::now();
            let mut s = bb.embed(&coords, &normals)?;
            row("embed", s.len(), t);
            for l in 0..cfg.num_levels() {
                let t = Instant::now();
                s = bb.encoder_stage(l, s)?;
                row(&format!("enc{l}"), s.len(), t);
            }
            for l in (0..cfg.num_levels() - 1).rev() {
                let t = Instant::now();
                s = bb.decoder_stage(l, s)?;
                row(&format!("dec{l}"), s.len(), t);
            }
            let _ = s.to_input_points(s.feat())?;
            row("total", n, total);
        }
    }
    Ok(())
}
