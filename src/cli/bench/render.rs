//! `lhmpp bench render`: CPU splatting and LBS posing on seeded synthetic scenes.
//!
//! `lhmpp bench render --sizes 592,1176 --counts 40000,160000 --threads 2` renders a body-like
//! Gaussian cloud (seed 42) at every size × count through one reused [`Rasterizer`] and prints
//! the median frame time and FPS, the process CPU time per frame (all threads; on a shared
//! machine it shows the work done even when other processes slow the wall clock), and the
//! median time of each stage; with `--neural-renderer PRESET` also the rasteriser + DPT head
//! (the paper's neural renderer); then the median LBS posing time of each count. With
//! `--device cuda` (a `cuda` build) the same scenes go through the CUDA rasteriser instead
//! ([`cuda`]), checked against the CPU image.

#[cfg(feature = "cuda")]
mod cuda;

use anyhow::{Context, Result};
use clap::Args;
use glam::{Mat4, Quat, Vec3};
use lhmpp::avatar::Avatar;
use lhmpp::body::SkinWeights;
use lhmpp::splat::synthetic::body_cloud;
use lhmpp::splat::{Camera, Intrinsics, RasterStageTimes, Rasterizer, RenderOptions, RenderOutput};
use rand::{Rng, SeedableRng};
use std::time::{Duration, Instant};

/// Options of `lhmpp bench render`.
#[derive(Args, Debug)]
pub struct RenderBenchArgs {
    /// Square image sizes (pixels).
    #[arg(long, value_delimiter = ',', default_value = "592,1176")]
    sizes: Vec<u32>,
    /// Gaussian counts.
    #[arg(long, value_delimiter = ',', default_value = "40000,160000")]
    counts: Vec<usize>,
    /// Worker threads (rayon pool size).
    #[arg(long, default_value_t = 2)]
    threads: usize,
    /// Minimum measuring time per cell (seconds); at least 5 frames are timed.
    #[arg(long, default_value_t = 2.0)]
    seconds: f64,
    /// Feature channels rendered alongside RGB (0 = RGB only).
    #[arg(long, default_value_t = 0)]
    features: usize,
    /// Also time the full neural renderer: the rasteriser producing the renderer's feature
    /// channels, then the DPT head of this preset's `neural_renderer` (`tiny` or `lhmpp-700m`,
    /// seeded random weights, CPU f32) at each size rounded down to a multiple of its patch.
    #[arg(long)]
    neural_renderer: Option<String>,
    /// `cpu`, or `cuda` for the CUDA rasteriser (and DPT head) on GPU 0 (needs a build with the
    /// `cuda` feature: scripts/build-cuda).
    #[arg(long, default_value = "cpu")]
    device: String,
}

/// The benchmark camera: 2.6 m in front of the body-like cloud, square image of `size` pixels.
fn bench_camera(size: u32) -> Camera {
    Camera::orbit(
        0,
        8,
        2.6,
        0.0,
        Vec3::new(0.0, 0.88, 0.0),
        Intrinsics::from_fov_y(size, size, 0.75),
    )
}

/// Wall and CPU time of repeated runs.
struct Timing {
    /// Median wall-clock time of one run.
    median: Duration,
    /// Process CPU time (all threads) per run, averaged over the runs (seconds; `NaN` when
    /// `/proc/self/stat` is unreadable).
    cpu_per_run: f64,
}

/// User + system CPU time of this process so far (seconds), from `/proc/self/stat`.
fn process_cpu_seconds() -> Option<f64> {
    let stat = std::fs::read_to_string("/proc/self/stat").ok()?;
    // Fields after the parenthesised command name; utime and stime are fields 14 and 15.
    let rest = &stat[stat.rfind(')')? + 2..];
    let fields: Vec<&str> = rest.split_whitespace().collect();
    let ticks: f64 = fields.get(11)?.parse::<f64>().ok()? + fields.get(12)?.parse::<f64>().ok()?;
    Some(ticks / 100.0)
}

/// Times `f` (after one warm-up call) until `seconds` have passed and at least 5 runs.
fn time_runs(seconds: f64, mut f: impl FnMut()) -> Timing {
    f();
    let start = Instant::now();
    let cpu_start = process_cpu_seconds();
    let mut times = Vec::new();
    while times.len() < 5 || start.elapsed().as_secs_f64() < seconds {
        let t = Instant::now();
        f();
        times.push(t.elapsed());
    }
    let cpu_per_run = match (cpu_start, process_cpu_seconds()) {
        (Some(a), Some(b)) => (b - a) / times.len() as f64,
        _ => f64::NAN,
    };
    times.sort();
    Timing {
        median: times[times.len() / 2],
        cpu_per_run,
    }
}

pub fn run(a: RenderBenchArgs) -> Result<()> {
    match a.device.as_str() {
        "cpu" => {}
        #[cfg(feature = "cuda")]
        "cuda" => {
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(a.threads)
                .build()
                .context("building the rayon thread pool")?;
            return pool.install(|| cuda::run(&a));
        }
        #[cfg(not(feature = "cuda"))]
        "cuda" => anyhow::bail!(
            "--device cuda: this binary was built without the `cuda` feature (build it with scripts/build-cuda)"
        ),
        other => anyhow::bail!("--device: unknown device `{other}` (cpu, cuda)"),
    }
    let neural = match &a.neural_renderer {
        Some(preset) => Some((preset.as_str(), dpt_preset(preset)?)),
        None => None,
    };
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(a.threads)
        .build()
        .context("building the rayon thread pool")?;
    println!(
        "CPU splatting, {} thread(s), blend in {}, body-like cloud (seed 42), camera 2.6 m away, median of ≥5 frames",
        a.threads,
        lhmpp::splat::blend_instruction_set()
    );
    println!(
        "| Gaussians | size | ms/frame | FPS | CPU ms/frame | project ms | bin+sort ms | blend ms | tile pairs |"
    );
    println!("|---:|---:|---:|---:|---:|---:|---:|---:|---:|");
    for &count in &a.counts {
        let g = body_cloud(count, a.features, 42);
        for &size in &a.sizes {
            let cam = bench_camera(size);
            let opts = RenderOptions {
                render_features: a.features > 0,
                ..Default::default()
            };
            let mut stages = Vec::new();
            let t = pool.install(|| {
                let mut rasterizer = Rasterizer::new();
                let mut frame = RenderOutput::default();
                time_runs(a.seconds, || {
                    stages.push(rasterizer.render_into(&g, &cam, &opts, &mut frame))
                })
            });
            let ms = t.median.as_secs_f64() * 1e3;
            let median = |f: fn(&RasterStageTimes) -> f64| {
                let mut v: Vec<f64> = stages.iter().map(f).collect();
                v.sort_by(f64::total_cmp);
                v[v.len() / 2] * 1e3
            };
            println!(
                "| {count} | {size}×{size} | {ms:.1} | {:.1} | {:.1} | {:.1} | {:.1} | {:.1} | {} |",
                1e3 / ms,
                t.cpu_per_run * 1e3,
                median(|s| s.project),
                median(|s| s.bin_sort),
                median(|s| s.blend),
                stages[0].tile_pairs
            );
        }
    }
    if let Some((preset, cfg)) = &neural {
        pool.install(|| neural_renderer_table(&a, preset, cfg))?;
    }
    println!();
    println!(
        "Gaussian LBS posing ({} thread(s), 4 influences 0.4/0.3/0.2/0.1 on random bones of 55, bone rotations up to 0.87 rad), median:",
        a.threads
    );
    println!("| Gaussians | ms/pose | CPU ms/pose |");
    println!("|---:|---:|---:|");
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(42);
    let bones: Vec<Mat4> = (0..55)
        .map(|_| {
            let q = Quat::from_scaled_axis(Vec3::new(
                rng.gen_range(-0.5..0.5),
                rng.gen_range(-0.5..0.5),
                rng.gen_range(-0.5..0.5),
            ));
            Mat4::from_rotation_translation(
                q,
                Vec3::new(rng.gen_range(-0.1..0.1), rng.gen_range(-0.1..0.1), 0.0),
            )
        })
        .collect();
    for &count in &a.counts {
        let g = body_cloud(count, 0, 42);
        let mut skin = SkinWeights::default();
        for _ in 0..count {
            let w: [f32; 4] = [0.4, 0.3, 0.2, 0.1];
            skin.bones
                .push(std::array::from_fn(|_| rng.gen_range(0..55)));
            skin.weights.push(w);
        }
        let avatar = Avatar::new(g.clone(), skin, "synthetic")?;
        let mut posed = g;
        let t = pool.install(|| {
            time_runs(a.seconds.min(1.0), || {
                avatar.animate_into(&bones, &mut posed)
            })
        });
        println!(
            "| {count} | {:.2} | {:.2} |",
            t.median.as_secs_f64() * 1e3,
            t.cpu_per_run * 1e3
        );
    }
    Ok(())
}

/// The neural-renderer config of `preset`.
fn dpt_preset(preset: &str) -> Result<lhmpp::model::dpt::DptConfig> {
    use lhmpp::model::dpt::DptConfig;
    Ok(match preset {
        "tiny" => DptConfig::tiny(),
        "lhmpp-700m" => DptConfig::lhmpp_700m(),
        other => anyhow::bail!("--neural-renderer: unknown preset `{other}` (tiny, lhmpp-700m)"),
    })
}

/// The neural-renderer table: for every count × size (rounded down to the renderer's patch),
/// the medians of `runs` timed frames after one warm-up. `prepare` turns each count's Gaussian
/// cloud (with the renderer's feature channels) into what `frame` renders; `frame` renders one
/// frame at the given camera and size and returns (rasteriser ms, DPT head ms).
fn neural_renderer_rows<S>(
    a: &RenderBenchArgs,
    cfg: &lhmpp::model::dpt::DptConfig,
    runs: usize,
    mut prepare: impl FnMut(lhmpp::splat::Gaussians) -> Result<S>,
    mut frame: impl FnMut(&S, &Camera, usize) -> Result<(f64, f64)>,
) -> Result<()> {
    println!("| Gaussians | size | rasteriser ms | DPT head ms | total ms | FPS |");
    println!("|---:|---:|---:|---:|---:|---:|");
    let p = cfg.patch_size as u32;
    for &count in &a.counts {
        let scene = prepare(body_cloud(count, cfg.in_channels, 42))?;
        for &size in &a.sizes {
            let size = size - size % p;
            if size == 0 {
                continue;
            }
            let cam = bench_camera(size);
            frame(&scene, &cam, size as usize)?; // warm-up
            let (mut raster_ms, mut head_ms) = (Vec::new(), Vec::new());
            for _ in 0..runs {
                let (r, d) = frame(&scene, &cam, size as usize)?;
                raster_ms.push(r);
                head_ms.push(d);
            }
            let median = |v: &mut Vec<f64>| {
                v.sort_by(f64::total_cmp);
                v[v.len() / 2]
            };
            let (r, d) = (median(&mut raster_ms), median(&mut head_ms));
            println!(
                "| {count} | {size}×{size} | {r:.2} | {d:.2} | {:.2} | {:.2} |",
                r + d,
                1e3 / (r + d)
            );
        }
    }
    Ok(())
}

/// Rasteriser (feature channels) + DPT head on the CPU: median of 3 frames after one warm-up
/// (the head is seconds per frame at the released sizes on a CPU).
fn neural_renderer_table(
    a: &RenderBenchArgs,
    preset: &str,
    cfg: &lhmpp::model::dpt::DptConfig,
) -> Result<()> {
    use candle_core::{DType, Device, Tensor};
    use lhmpp::model::dpt::NeuralRenderer;
    let dev = Device::Cpu;
    let vb = lhmpp::model::checkpoint::seeded_var_builder(1, DType::F32, &dev);
    let renderer = NeuralRenderer::new(cfg, vb.pp("neural_renderer"))?;
    println!();
    println!(
        "Neural renderer `{preset}` ({} feature channels, patch {}, DPT head, CPU f32, random weights), median of 3 frames:",
        cfg.in_channels, cfg.patch_size
    );
    let opts = RenderOptions {
        render_features: true,
        ..Default::default()
    };
    let mut rasterizer = Rasterizer::new();
    let mut frame = RenderOutput::default();
    neural_renderer_rows(a, cfg, 3, Ok, |g, cam, size| {
        let t = Instant::now();
        rasterizer.render_into(g, cam, &opts, &mut frame);
        let r = t.elapsed().as_secs_f64() * 1e3;
        let t = Instant::now();
        let features = Tensor::from_slice(&frame.features, (size, size, cfg.in_channels), &dev)?
            .permute((2, 0, 1))?
            .unsqueeze(0)?;
        let (rgb, _mask) = renderer.forward(&features)?;
        anyhow::ensure!(
            rgb.dims() == [1, 3, size, size],
            "DPT output {:?}",
            rgb.dims()
        );
        Ok((r, t.elapsed().as_secs_f64() * 1e3))
    })
}
