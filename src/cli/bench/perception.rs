//! `lhmpp bench perception`: latency of the BlazePose networks (person detector, lite, full
//! and, when its weights exist, heavy landmark models) on our CPU kernels, per rayon thread
//! count; `--profile` adds each network's slowest steps. `scripts/perception/bench` runs it
//! next to the LiteRT/XNNPACK peer.

use std::collections::BTreeMap;
use std::path::PathBuf;
use std::time::{Duration, Instant};

use anyhow::{Context, Result};
use clap::Args;
use lhmpp::perception::network::Network;
use lhmpp::perception::weights::{self, LandmarkModel, HEAVY_DEFAULT_PATH};

/// Arguments of `lhmpp bench perception`.
#[derive(Args, Debug)]
pub struct PerceptionBenchArgs {
    /// Rayon thread counts to time at.
    #[arg(long, value_delimiter = ',', default_value = "1,2")]
    threads: Vec<usize>,
    /// Timed runs per network and thread count (after the warm-up runs).
    #[arg(long, default_value_t = 50)]
    runs: usize,
    /// Untimed runs first.
    #[arg(long, default_value_t = 5)]
    warmup: usize,
    /// Networks: detector, lite, full, heavy (heavy is skipped when its weights are missing).
    #[arg(
        long,
        value_delimiter = ',',
        default_value = "detector,lite,full,heavy"
    )]
    only: Vec<String>,
    /// The heavy landmark model's converted weights.
    #[arg(long, default_value = HEAVY_DEFAULT_PATH)]
    heavy: PathBuf,
    /// Also print, per network and thread count, the slowest steps and the time per kind.
    #[arg(long)]
    profile: bool,
    /// Steps listed per profile.
    #[arg(long, default_value_t = 15)]
    top: usize,
    /// Instead of the networks, time the 1×1-convolution product kernel alone on
    /// representative shapes (pixels×in→out, one thread) and print GMAC/s.
    #[arg(long)]
    kernels: bool,
}

/// GMAC/s of the packed product kernel on one thread, shapes from the landmark models.
fn bench_kernels(runs: usize) {
    use lhmpp::kernels::nhwc::Epilogue;
    use lhmpp::kernels::pointwise::PackedGemm;
    println!(
        "{:<22} {:>10} {:>8}",
        "pixels×in→out", "median_us", "GMAC/s"
    );
    for (m, k, n) in [
        (16384, 16, 64),
        (4096, 24, 144),
        (4096, 144, 24),
        (256, 88, 528),
        (256, 528, 88),
        (64, 864, 288),
        (1200, 256, 256),
        (65536, 8, 8),
    ] {
        let a: Vec<f32> = (0..m * k).map(|i| (i % 17) as f32 * 0.01).collect();
        let w: Vec<f32> = (0..n * k).map(|i| (i % 13) as f32 * 0.01).collect();
        let packed = PackedGemm::from_rows(&w, k, n, &vec![0.0; n]);
        let mut out = vec![0.0; m * n];
        let mut times: Vec<Duration> = (0..runs.max(3))
            .map(|_| {
                let t = Instant::now();
                packed.run_serial(&a, k, m, Epilogue::default(), &mut out);
                t.elapsed()
            })
            .collect();
        times.sort();
        let t = times[times.len() / 2];
        let label = format!("{m}×{k}→{n}");
        println!(
            "{label:<22} {:>10.1} {:>8.1}",
            t.as_secs_f64() * 1e6,
            (m * k * n) as f64 / t.as_secs_f64() / 1e9
        );
    }
}

/// A deterministic input in the network's range (values do not change the work done).
fn input_for(net: &Network, signed: bool) -> Vec<f32> {
    let n: usize = net.input_shape().iter().product();
    let mut s = 0x2545_f491u32;
    (0..n)
        .map(|_| {
            s ^= s << 13;
            s ^= s >> 17;
            s ^= s << 5;
            let v = (s % 256) as f32 / 255.0;
            if signed {
                v * 2.0 - 1.0
            } else {
                v
            }
        })
        .collect()
}

fn ms(d: Duration) -> f64 {
    d.as_secs_f64() * 1e3
}

/// Runs `lhmpp bench perception`.
pub fn run(a: PerceptionBenchArgs) -> Result<()> {
    if a.kernels {
        bench_kernels(a.runs);
        return Ok(());
    }
    let mut nets: Vec<(&str, Network, bool)> = Vec::new();
    for name in &a.only {
        let (net, signed) = match name.as_str() {
            "detector" => (weights::pose_detector()?, true),
            "heavy" if !a.heavy.is_file() => {
                println!("# heavy: no weights at {} (skipped)", a.heavy.display());
                continue;
            }
            other => {
                let model = LandmarkModel::from_name(other)
                    .with_context(|| format!("unknown network `{other}`"))?;
                (model.load(Some(&a.heavy))?, false)
            }
        };
        nets.push((name.as_str(), net, signed));
    }
    println!(
        "# lhmpp bench perception: {} timed runs after {} warm-up runs",
        a.runs, a.warmup
    );
    println!(
        "{:<10} {:>7} {:>10} {:>10}",
        "network", "threads", "median_ms", "min_ms"
    );
    let mut profiles = Vec::new();
    for &threads in &a.threads {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .context("thread pool")?;
        for (name, net, signed) in &nets {
            let input = input_for(net, *signed);
            let mut out = Default::default();
            let mut times = Vec::with_capacity(a.runs);
            pool.install(|| -> Result<()> {
                for _ in 0..a.warmup {
                    net.run_into(&input, &mut out)?;
                }
                for _ in 0..a.runs.max(1) {
                    let t = Instant::now();
                    net.run_into(&input, &mut out)?;
                    times.push(t.elapsed());
                }
                Ok(())
            })?;
            times.sort();
            println!(
                "{name:<10} {threads:>7} {:>10.2} {:>10.2}",
                ms(times[times.len() / 2]),
                ms(times[0])
            );
            if a.profile {
                let runs = a.runs.clamp(1, 20);
                let mut steps: Vec<(String, Duration)> = Vec::new();
                pool.install(|| -> Result<()> {
                    for _ in 0..runs {
                        let (_, st) = net.run_profiled(&input)?;
                        if steps.is_empty() {
                            steps = st
                                .iter()
                                .map(|s| (s.label.clone(), Duration::ZERO))
                                .collect();
                        }
                        for (acc, s) in steps.iter_mut().zip(&st) {
                            acc.1 += s.time;
                        }
                    }
                    Ok(())
                })?;
                profiles.push((name.to_string(), threads, runs, steps));
            }
        }
    }
    for (name, threads, runs, steps) in profiles {
        print_profile(&name, threads, runs, &steps, a.top);
    }
    Ok(())
}

/// The slowest steps (mean ms per run) and the time per kind of step.
fn print_profile(
    name: &str,
    threads: usize,
    runs: usize,
    steps: &[(String, Duration)],
    top: usize,
) {
    let per_run = |d: Duration| ms(d) / runs as f64;
    let total: f64 = steps.iter().map(|s| per_run(s.1)).sum();
    println!(
        "\n# profile: {name}, {threads} thread(s), mean of {runs} runs, {total:.2} ms in {} steps",
        steps.len()
    );
    let mut kinds: BTreeMap<String, (f64, usize)> = BTreeMap::new();
    for (label, d) in steps {
        let mut words = label.split_whitespace();
        let kind = match words.next() {
            Some("conv") => format!("conv {}", words.next().unwrap_or("")),
            Some("depthwise") => format!("depthwise {}", words.next().unwrap_or("")),
            Some(other) => other.to_string(),
            None => String::new(),
        };
        let e = kinds.entry(kind).or_default();
        e.0 += per_run(*d);
        e.1 += 1;
    }
    let mut kinds: Vec<_> = kinds.into_iter().collect();
    kinds.sort_by(|a, b| b.1 .0.total_cmp(&a.1 .0));
    for (kind, (t, n)) in kinds {
        println!(
            "  {kind:<20} {n:>4} steps {t:>8.3} ms {:>5.1}%",
            100.0 * t / total
        );
    }
    let mut order: Vec<usize> = (0..steps.len()).collect();
    order.sort_by(|&a, &b| steps[b].1.cmp(&steps[a].1));
    for &i in order.iter().take(top) {
        println!(
            "  #{i:<4} {:<48} {:>8.3} ms",
            steps[i].0,
            per_run(steps[i].1)
        );
    }
}
