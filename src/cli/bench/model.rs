//! `lhmpp bench model`: latency tables for the network on synthetic inputs.

use std::time::Instant;

use anyhow::Context;
use candle_core::{DType, Device, Tensor};
use clap::Args;

use lhmpp::model::cache::ViewTokenCache;
use lhmpp::model::checkpoint::seeded_var_builder;
use lhmpp::model::{Lhmpp, LhmppConfig};

/// Arguments of `lhmpp bench model`.
#[derive(Args, Debug)]
pub struct ModelBenchArgs {
    /// Preset: tiny, s, m, l, lhmpp-700m (seeded random weights).
    #[arg(long, default_value = "tiny")]
    config: String,
    /// Comma-separated view counts.
    #[arg(long, value_delimiter = ',', default_value = "1,4,8")]
    views: Vec<usize>,
    /// Number of anchor points.
    #[arg(long, default_value_t = 4096)]
    points: usize,
    /// `cpu` or `cuda` (needs the `cuda` feature).
    #[arg(long, default_value = "cpu")]
    device: String,
    /// CPU threads (0 = all).
    #[arg(long, default_value_t = 0)]
    threads: usize,
    /// Timed runs per measurement (the median is printed); one warm-up run precedes them.
    #[arg(long, default_value_t = 3)]
    runs: usize,
    /// Weights and activations: `f32` or `bf16` (on the CPU: bf16 products with f32
    /// accumulation, norms and softmax in f32).
    #[arg(long, default_value = "f32", value_parser = ["f32", "bf16"])]
    dtype: String,
    /// Skip the incremental-update and point-backbone rows (at 700M widths they take minutes).
    #[arg(long)]
    skip_incremental: bool,
}

fn median_ms(runs: usize, mut f: impl FnMut() -> anyhow::Result<()>) -> anyhow::Result<f64> {
    f()?; // warm-up
    let mut t = Vec::with_capacity(runs);
    for _ in 0..runs.max(1) {
        let start = Instant::now();
        f()?;
        t.push(start.elapsed().as_secs_f64() * 1e3);
    }
    t.sort_by(f64::total_cmp);
    Ok(t[t.len() / 2])
}

/// A synthetic body-sized point cloud (ellipsoid shell, 1.7 m tall) with outward normals.
fn synthetic_points(n: usize, dev: &Device) -> anyhow::Result<(Tensor, Tensor)> {
    let golden = std::f32::consts::PI * (3.0 - 5f32.sqrt());
    let (mut p, mut nrm) = (Vec::with_capacity(n * 3), Vec::with_capacity(n * 3));
    let radii = [0.25f32, 0.85, 0.15];
    for i in 0..n {
        let y = 1.0 - 2.0 * (i as f32 + 0.5) / n as f32;
        let r = (1.0 - y * y).sqrt();
        let th = golden * i as f32;
        let u = [r * th.cos(), y, r * th.sin()];
        p.extend((0..3).map(|k| u[k] * radii[k]));
        let g: Vec<f32> = (0..3).map(|k| u[k] / radii[k]).collect();
        let len = g.iter().map(|v| v * v).sum::<f32>().sqrt();
        nrm.extend(g.iter().map(|v| v / len));
    }
    Ok((
        Tensor::from_vec(p, (n, 3), dev)?,
        Tensor::from_vec(nrm, (n, 3), dev)?,
    ))
}

pub fn run(a: ModelBenchArgs) -> anyhow::Result<()> {
    if a.threads > 0 {
        std::env::set_var("RAYON_NUM_THREADS", a.threads.to_string());
        rayon::ThreadPoolBuilder::new()
            .num_threads(a.threads)
            .build_global()
            .ok();
    }
    let dev = match a.device.as_str() {
        "cpu" => Device::Cpu,
        "cuda" => Device::new_cuda(0).context("CUDA device (build with --features cuda)")?,
        other => anyhow::bail!("unknown device `{other}` (cpu or cuda)"),
    };
    let cfg = LhmppConfig::preset(&a.config)?;
    let dtype = if a.dtype == "bf16" {
        DType::BF16
    } else {
        DType::F32
    };
    let model = Lhmpp::new(&cfg, seeded_var_builder(1, dtype, &dev))?;
    let (anchors, normals) = synthetic_points(a.points, &dev)?;
    let image = || Tensor::rand(0f32, 1.0, (3, cfg.image_height, cfg.image_width), &dev);
    println!(
        "preset {} | {} | {}x{} images | {} points | device {} | threads {} | median of {} runs (ms)",
        cfg.preset,
        a.dtype,
        cfg.image_height,
        cfg.image_width,
        a.points,
        a.device,
        if a.threads == 0 {
            "all".to_string()
        } else {
            a.threads.to_string()
        },
        a.runs
    );
    println!("| views | image encoding | fusion (PIT) | head | end-to-end |");
    println!("|------:|---------------:|-------------:|-----:|-----------:|");
    for &v in &a.views {
        let images: Vec<Tensor> = (0..v)
            .map(|_| image())
            .collect::<candle_core::Result<_>>()?;
        let views = images
            .iter()
            .map(|i| model.encode_view(i))
            .collect::<candle_core::Result<Vec<_>>>()?;
        let enc = median_ms(a.runs, || {
            for i in &images {
                model.encode_view(i)?;
            }
            dev.synchronize()?;
            Ok(())
        })?;
        let feat = model.fuse(&anchors, &normals, &views)?;
        let fuse = median_ms(a.runs, || {
            model.fuse(&anchors, &normals, &views)?;
            dev.synchronize()?;
            Ok(())
        })?;
        let head = median_ms(a.runs, || {
            model.gs_head().forward(&feat, &anchors)?;
            dev.synchronize()?;
            Ok(())
        })?;
        let e2e = median_ms(a.runs, || {
            let views = images
                .iter()
                .map(|i| model.encode_view(i))
                .collect::<candle_core::Result<Vec<_>>>()?;
            model
                .reconstruct(&anchors, &normals, &views)?
                .to_cpu_arrays()?;
            Ok(())
        })?;
        println!("| {v:>5} | {enc:>14.1} | {fuse:>12.1} | {head:>4.1} | {e2e:>10.1} |");
    }
    if a.skip_incremental {
        return Ok(());
    }
    // Incremental update: one new view joins 7 cached ones.
    let images: Vec<Tensor> = (0..8)
        .map(|_| image())
        .collect::<candle_core::Result<_>>()?;
    let mut cache = ViewTokenCache::new(16);
    for (i, img) in images.iter().take(7).enumerate() {
        cache.get_or_encode(&model, i as u64, img)?;
    }
    let ids: Vec<u64> = (0..8).collect();
    let inc = median_ms(a.runs, || {
        cache.remove(7);
        cache.get_or_encode(&model, 7, &images[7])?;
        let views = cache.views(&ids).context("cached views")?;
        model
            .reconstruct(&anchors, &normals, &views)?
            .to_cpu_arrays()?;
        Ok(())
    })?;
    let pts = median_ms(a.runs, || {
        model.point_backbone().forward(&anchors, &normals)?;
        Ok(())
    })?;
    println!("point backbone alone (embed + encoder + decoder, no PIT blocks): {pts:.1} ms");
    println!("incremental update (1 new view + 7 cached, encode + fuse + head): {inc:.1} ms");
    Ok(())
}
