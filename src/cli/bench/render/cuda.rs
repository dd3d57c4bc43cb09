//! `lhmpp bench render --device cuda`: the CUDA rasteriser on the same seeded scenes as the CPU
//! table. Per size × count: median GPU frame time (maps left on the GPU, stream synchronised),
//! the upload of the Gaussians and the download of the maps, and the largest difference from
//! the CPU rasteriser's image (the run fails above 2e-3); with `--neural-renderer PRESET` also
//! the rasteriser + DPT head with the features kept on the GPU.

use super::{bench_camera, dpt_preset, neural_renderer_rows, time_runs, RenderBenchArgs};
use anyhow::{Context, Result};
use candle_core::{DType, Device, Tensor};
use lhmpp::model::dpt::NeuralRenderer;
use lhmpp::splat::cuda::{CudaRasterizer, CudaScene};
use lhmpp::splat::synthetic::body_cloud;
use lhmpp::splat::{render_timed, RenderOptions, RenderOutput};
use std::time::Instant;

/// Largest CPU/GPU difference accepted (the GPU build's agreement requirement).
const AGREEMENT: f32 = 2e-3;

fn max_abs_diff(a: &[f32], b: &[f32]) -> f32 {
    if a.len() != b.len() {
        return f32::INFINITY;
    }
    a.iter()
        .zip(b)
        .map(|(x, y)| (x - y).abs())
        .fold(0.0, f32::max)
}

/// Largest difference between the two images' colour, alpha and features (depth is compared
/// where the pixel is at least half covered: elsewhere it is a ratio of two small sums).
fn image_difference(cpu: &RenderOutput, gpu: &RenderOutput) -> (f32, f32) {
    let maps = max_abs_diff(&cpu.rgb, &gpu.rgb)
        .max(max_abs_diff(&cpu.alpha, &gpu.alpha))
        .max(max_abs_diff(&cpu.features, &gpu.features));
    let depth = cpu
        .depth
        .iter()
        .zip(&gpu.depth)
        .zip(&cpu.alpha)
        .filter(|(_, &a)| a >= 0.5)
        .map(|((x, y), _)| (x - y).abs())
        .fold(0.0, f32::max);
    (maps, depth)
}

pub(super) fn run(a: &RenderBenchArgs) -> Result<()> {
    let device = Device::new_cuda(0).context("CUDA device 0")?;
    let mut rasterizer = CudaRasterizer::new(&device)?;
    println!(
        "CUDA splatting (device 0), body-like cloud (seed 42), camera 2.6 m away, median of ≥5 frames; \
         CPU reference on {} thread(s)",
        rayon::current_num_threads()
    );
    println!(
        "| Gaussians | size | GPU ms/frame | FPS | upload ms | download ms | visible | tile pairs | max |Δ| rgb/α/feat | max |Δ| depth |"
    );
    println!("|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|");
    let mut worst = 0.0f32;
    for &count in &a.counts {
        let g = body_cloud(count, a.features, 42);
        let t = Instant::now();
        let scene = CudaScene::from_gaussians(&g, &device)?;
        device.synchronize()?;
        let upload_ms = t.elapsed().as_secs_f64() * 1e3;
        for &size in &a.sizes {
            let cam = bench_camera(size);
            let opts = RenderOptions {
                render_features: a.features > 0,
                ..Default::default()
            };
            let mut failure = None;
            let timing = time_runs(a.seconds, || {
                if let Err(e) = rasterizer
                    .render(&scene, &cam, &opts)
                    .and_then(|_| Ok(device.synchronize()?))
                {
                    failure.get_or_insert(e);
                }
            });
            if let Some(e) = failure {
                return Err(e.into());
            }
            let frame = rasterizer.render(&scene, &cam, &opts)?;
            device.synchronize()?;
            let t = Instant::now();
            let gpu = frame.to_render_output()?;
            let download_ms = t.elapsed().as_secs_f64() * 1e3;
            let (cpu, cpu_times) = render_timed(&g, &cam, &opts);
            let (diff, depth_diff) = image_difference(&cpu, &gpu);
            anyhow::ensure!(
                frame.visible == cpu_times.visible,
                "{count} Gaussians at {size}²: {} visible on the GPU, {} on the CPU",
                frame.visible,
                cpu_times.visible
            );
            worst = worst.max(diff);
            let ms = timing.median.as_secs_f64() * 1e3;
            println!(
                "| {count} | {size}×{size} | {ms:.3} | {:.0} | {upload_ms:.2} | {download_ms:.2} | {} | {} | {diff:.1e} | {depth_diff:.1e} |",
                1e3 / ms,
                frame.visible,
                frame.tile_pairs
            );
        }
    }
    anyhow::ensure!(
        worst <= AGREEMENT,
        "the GPU image differs from the CPU image by {worst:.2e} (> {AGREEMENT:e})"
    );
    println!("CPU/GPU agreement: max |Δ| {worst:.2e} ≤ {AGREEMENT:e}");
    if let Some(preset) = &a.neural_renderer {
        neural_renderer_table(a, preset, &device, &mut rasterizer)?;
    }
    Ok(())
}

/// Rasteriser (features on the GPU) + DPT head on the GPU, f32, median of 5 frames.
fn neural_renderer_table(
    a: &RenderBenchArgs,
    preset: &str,
    device: &Device,
    rasterizer: &mut CudaRasterizer,
) -> Result<()> {
    let cfg = dpt_preset(preset)?;
    let vb = lhmpp::model::checkpoint::seeded_var_builder(1, DType::F32, device);
    let renderer = NeuralRenderer::new(&cfg, vb.pp("neural_renderer"))?;
    println!();
    println!(
        "Neural renderer `{preset}` on the GPU ({} feature channels, patch {}, DPT head f32, random weights), median of 5 frames:",
        cfg.in_channels, cfg.patch_size
    );
    let opts = RenderOptions {
        render_features: true,
        ..Default::default()
    };
    let upload = |g: lhmpp::splat::Gaussians| Ok(CudaScene::from_gaussians(&g, device)?);
    neural_renderer_rows(a, &cfg, 5, upload, |scene, cam, size| {
        let t = Instant::now();
        let frame = rasterizer.render(scene, cam, &opts)?;
        device.synchronize()?;
        let r = t.elapsed().as_secs_f64() * 1e3;
        let t = Instant::now();
        let features: Tensor = frame
            .features
            .context("features were asked for")?
            .permute((2, 0, 1))?
            .unsqueeze(0)?;
        let (rgb, _mask) = renderer.forward(&features)?;
        device.synchronize()?;
        anyhow::ensure!(
            rgb.dims()[2..] == [size, size],
            "DPT output {:?}",
            rgb.dims()
        );
        Ok((r, t.elapsed().as_secs_f64() * 1e3))
    })
}
