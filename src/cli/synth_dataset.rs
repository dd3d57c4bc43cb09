//! `lhmpp synth-dataset`: training samples for the default model, written as safetensors shards
//! (see `lhmpp::synth::dataset` for the layout).

use super::synth::RealismArg;
use anyhow::{Context, Result};
use indicatif::{ProgressBar, ProgressStyle};
use lhmpp::synth::dataset::{make_sample, write_shard, DatasetOptions, TRAIN_SEED_START};
use rayon::prelude::*;
use std::path::PathBuf;

/// Arguments of `lhmpp synth-dataset`.
#[derive(clap::Args, Debug)]
pub struct SynthDatasetArgs {
    /// First person seed (training seeds start at 1000000; lower seeds are evaluation people).
    #[arg(long, default_value_t = TRAIN_SEED_START)]
    first_seed: u64,
    /// Number of samples (one person each, consecutive seeds).
    #[arg(long, default_value_t = 2000)]
    samples: u64,
    /// Samples per shard file.
    #[arg(long, default_value_t = 250)]
    shard_size: u64,
    /// Anchor points per person (the node's model.num_points).
    #[arg(long, default_value_t = 4096)]
    points: usize,
    /// Most input views per sample.
    #[arg(long, default_value_t = 8)]
    max_views: usize,
    /// Encoder input height in pixels (the network's image_height).
    #[arg(long, default_value_t = 112)]
    input_height: u32,
    /// Encoder input width in pixels (the network's image_width).
    #[arg(long, default_value_t = 112)]
    input_width: u32,
    /// Fraction of input views cropped to the person by its mask, as the node does when
    /// `inputs.mask_topics` are set (the rest are whole frames).
    #[arg(long, default_value_t = 0.25)]
    mask_fraction: f64,
    /// Target view side in pixels.
    #[arg(long, default_value_t = 96)]
    target_size: u32,
    /// `plain`: the template painted by body part (as the embedded default was trained);
    /// `dressed`: dressed, lit people with camera effects and textured backgrounds, albedo
    /// ground truth and unlit targets, plus `anchor_garment` and `anchor_surface` per sample.
    #[arg(long, value_enum, default_value_t = RealismArg::Plain)]
    realism: RealismArg,
    /// With `--realism dressed`: the fraction of samples (chosen by seed) that are dressed;
    /// the others are plain.
    #[arg(long, default_value_t = 1.0)]
    dressed_fraction: f64,
    /// Fraction of samples (chosen by seed) whose anchors sit on the template of the person's
    /// height with girth 1, where the node puts them when it reads only the height from
    /// calibrated views; the targets stay the true person.
    #[arg(long, default_value_t = 0.0)]
    girth_one_fraction: f64,
    /// Output folder (shard-00000.safetensors, ...); existing complete shards are kept.
    #[arg(short, long)]
    output: PathBuf,
}

/// Writes the shards with a progress bar; a shard already on disk is not made again.
pub fn run(args: SynthDatasetArgs) -> Result<()> {
    anyhow::ensure!(
        args.first_seed >= TRAIN_SEED_START,
        "--first-seed {} is an evaluation seed (training seeds start at {TRAIN_SEED_START})",
        args.first_seed
    );
    anyhow::ensure!(
        (0.0..=1.0).contains(&args.mask_fraction),
        "--mask-fraction {} is not in 0..=1",
        args.mask_fraction
    );
    anyhow::ensure!(args.shard_size >= 1, "--shard-size must be at least 1");
    anyhow::ensure!(
        (0.0..=1.0).contains(&args.dressed_fraction),
        "--dressed-fraction {} is not in 0..=1",
        args.dressed_fraction
    );
    anyhow::ensure!(
        (0.0..=1.0).contains(&args.girth_one_fraction),
        "--girth-one-fraction {} is not in 0..=1",
        args.girth_one_fraction
    );
    std::fs::create_dir_all(&args.output)
        .with_context(|| format!("creating {}", args.output.display()))?;
    let options = DatasetOptions {
        points: args.points,
        max_views: args.max_views,
        input_height: args.input_height,
        input_width: args.input_width,
        target_size: args.target_size,
        mask_fraction: args.mask_fraction,
        realism: args.realism.into(),
        dressed_fraction: args.dressed_fraction,
        girth_one_fraction: args.girth_one_fraction,
        ..DatasetOptions::default()
    };
    let bar = ProgressBar::new(args.samples);
    bar.set_style(
        ProgressStyle::with_template("{bar:40} {pos}/{len} samples {per_sec} eta {eta}")
            .expect("valid template"),
    );
    let shards = args.samples.div_ceil(args.shard_size);
    for shard in 0..shards {
        let path = args.output.join(format!("shard-{shard:05}.safetensors"));
        let start = shard * args.shard_size;
        let end = (start + args.shard_size).min(args.samples);
        if path.exists() {
            bar.inc(end - start);
            continue;
        }
        let samples = (start..end)
            .into_par_iter()
            .map(|k| {
                let s = make_sample(args.first_seed + k, &options);
                bar.inc(1);
                s
            })
            .collect::<Result<Vec<_>, _>>()?;
        // Written under a temporary name first: a killed run leaves no half shard behind.
        let tmp = path.with_extension("partial");
        write_shard(&tmp, &samples)?;
        std::fs::rename(&tmp, &path).with_context(|| format!("renaming {}", tmp.display()))?;
    }
    bar.finish();
    println!(
        "wrote {} samples (seeds {}..{}) in {} shards to {}",
        args.samples,
        args.first_seed,
        args.first_seed + args.samples,
        shards,
        args.output.display()
    );
    Ok(())
}
