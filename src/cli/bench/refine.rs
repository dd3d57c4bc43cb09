//! `lhmpp bench refine`: how fast refinement reaches its gain. For each dressed person (bags
//! given, or made here with `lhmpp synth --realism dressed` settings), the node's default
//! reconstruction (shape estimated, colours from the views) is refined against its input
//! views at the node's settings, on a pool of `--threads` threads; the table gives the time to
//! 90 % of the held-out gain the fit kept, the whole fit's time and why it stopped, the time per
//! step by stage, and the held-out PSNR before and after.

use super::super::config_source::ConfigSource;
use anyhow::{Context, Result};
use clap::Args;
use lhmpp::eval::heldout::{evaluate_bag, ColourSource, EvalStages, InputCrop, ShapeSource};
use lhmpp::synth::{write_bag, CameraMode, Realism, SynthOptions, SynthPose};
use std::path::PathBuf;

/// Options of `lhmpp bench refine`.
#[derive(Args, Debug)]
pub struct RefineBenchArgs {
    /// Bags made by `lhmpp synth` (default: dressed people made here from `--seeds`).
    bags: Vec<PathBuf>,
    /// Seeds of the dressed people made when no bag is given (12 views, 4 held out, 256²).
    #[arg(long, value_delimiter = ',', default_value = "40,41")]
    seeds: Vec<u64>,
    /// Input views fitted (one of them held out by the fit to stop it).
    #[arg(long, default_value_t = 8)]
    views: usize,
    /// Worker threads (rayon pool size).
    #[arg(long, default_value_t = 2)]
    threads: usize,
    /// The node's settings (`--set refine.max_side=256`).
    #[command(flatten)]
    source: ConfigSource,
}

/// Runs `lhmpp bench refine`.
pub fn run(args: RefineBenchArgs) -> Result<()> {
    let config = args.source.load()?;
    let fit = config.refine.fit_config();
    let dir = std::env::temp_dir().join(format!("lhmpp-bench-refine-{}", std::process::id()));
    let bags: Vec<PathBuf> = if args.bags.is_empty() {
        let mut made = Vec::new();
        for seed in &args.seeds {
            std::fs::create_dir_all(&dir).with_context(|| format!("creating {}", dir.display()))?;
            let path = dir.join(format!("dressed_{seed}.mcap"));
            let options = SynthOptions {
                seed: *seed,
                views: 12,
                heldout: 4,
                size: 256,
                pose: if seed % 2 == 0 {
                    SynthPose::Random
                } else {
                    SynthPose::Walk((seed * 5) as f32)
                },
                camera: CameraMode::Ring,
                ..SynthOptions::default()
            };
            eprintln!("making a dressed person, seed {seed} ...");
            write_bag(&path, &options, Realism::Dressed)
                .with_context(|| format!("writing {}", path.display()))?;
            made.push(path);
        }
        made
    } else {
        args.bags.clone()
    };
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(args.threads)
        .build()
        .context("building the rayon thread pool")?;
    println!(
        "refinement, {} thread(s), {} input views, views at most {} px, budget {} ms, at most {} steps",
        args.threads,
        args.views,
        fit.max_side,
        fit.budget.as_millis(),
        fit.max_iterations
    );
    println!(
        "| bag | Gaussians | steps | to 90 % of gain (s) | fit (s) | stop | ms/step: render | loss | backward | update | checks (s) | PSNR before | PSNR after |"
    );
    println!("|---|---:|---:|---:|---:|---|---:|---:|---:|---:|---:|---:|---:|");
    for bag in &bags {
        let stages = |refine| EvalStages {
            crop: InputCrop::Mask,
            shape: ShapeSource::Estimate,
            colours: ColourSource::Views(config.perception.delight),
            refine,
        };
        let name = bag
            .file_name()
            .map_or_else(|| bag.display().to_string(), |n| n.to_string_lossy().into());
        eprintln!("{name}: the network's avatar ...");
        let before =
            pool.install(|| evaluate_bag(bag, &config.model, &[args.views], &stages(None)))?;
        eprintln!("{name}: refining ...");
        let after = pool.install(|| {
            evaluate_bag(
                bag,
                &config.model,
                &[args.views],
                &stages(Some(fit.clone())),
            )
        })?;
        let (Some(before), Some(after)) = (before.first(), after.first()) else {
            anyhow::bail!("{name}: no reconstruction");
        };
        let Some(r) = &after.refine else {
            anyhow::bail!(
                "{name}: refinement did not run (fewer than 3 calibrated views with masks?)"
            );
        };
        let steps = r.iterations.max(1) as f64;
        let ms = |s: f64| format!("{:.1}", s * 1e3 / steps);
        println!(
            "| {name} | {} → {} | {} | {} | {:.1} | {:?} | {} | {} | {} | {} | {:.2} | {:.2} | {:.2} |",
            r.gaussians.0,
            r.gaussians.1,
            r.iterations,
            r.time_to_gain(0.9)
                .map_or_else(|| "no gain".into(), |t| format!("{t:.1}")),
            r.elapsed.as_secs_f64(),
            r.stop,
            ms(r.times.pose + r.times.render),
            ms(r.times.loss),
            ms(r.times.backward),
            ms(r.times.update),
            r.times.check,
            before.means().0,
            after.means().0,
        );
    }
    if dir.exists() {
        std::fs::remove_dir_all(&dir).with_context(|| format!("removing {}", dir.display()))?;
    }
    Ok(())
}
