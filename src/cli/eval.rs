//! `lhmpp eval BAG`: held-out-view PSNR / SSIM / mask IoU of reconstructions from a synthetic bag.

use super::config_source::ConfigSource;
use anyhow::{Context, Result};
use lhmpp::body::MakeHumanShape;
use lhmpp::eval::heldout::{evaluate_bag, ColourSource, EvalStages, InputCrop, ShapeSource};
use std::path::PathBuf;

/// Arguments of `lhmpp eval`.
#[derive(clap::Args, Debug)]
pub struct EvalArgs {
    /// Bags made by `lhmpp synth` (input views, held-out views with masks, pose, tf).
    #[arg(required = true)]
    bags: Vec<PathBuf>,
    /// Input view counts to reconstruct from (N views spread evenly over each bag's views).
    #[arg(long, value_delimiter = ',', default_value = "1,4,8")]
    views: Vec<usize>,
    /// Write a picture of the first bag's largest view count: input views | held-out ground
    /// truth | our render from the held-out camera (PNG).
    #[arg(long)]
    picture: Option<PathBuf>,
    /// Feed whole input frames to the encoder (the node without `inputs.mask_topics`). By
    /// default each input view is cropped to the person by its `/camN/mask` in the bag, as the
    /// node does when `inputs.mask_topics` are set.
    #[arg(long)]
    full_frame: bool,
    /// Body shape to reconstruct on: `estimate` (read by perception from the calibrated input
    /// views, as the node does by default, without a shape topic), `bag` (the bag's BodyShape
    /// when it has one, as the node with a shape topic), `template` (the template's own shape)
    /// or `H,G` (MakeHuman height and girth scales).
    #[arg(long, default_value = "estimate")]
    shape: String,
    /// Keep the network's colours instead of recolouring each avatar from its input views as
    /// the node does by default (`perception.colours_from_views`: perception reads the person
    /// in each input view; the bag's masks cut them out).
    #[arg(long)]
    network_colours: bool,
    /// Accepted for older command lines: colours from the views are the default.
    #[arg(long, hide = true)]
    colours_from_views: bool,
    /// Refine each avatar against its input views, as the node does by default
    /// (`refine.enabled`); `--no-refine` scores the network's avatar.
    #[arg(long, overrides_with = "no_refine")]
    refine: bool,
    /// Score the network's avatar without refinement.
    #[arg(long)]
    no_refine: bool,
    /// The model settings (`--set model.checkpoint=x.safetensors`).
    #[command(flatten)]
    pub source: ConfigSource,
}

/// Prints one table row per bag and view count.
pub fn run(args: EvalArgs) -> Result<()> {
    let config = args.source.load()?;
    let crop = if args.full_frame {
        InputCrop::FullFrame
    } else {
        InputCrop::Mask
    };
    let colours = match args.network_colours {
        true => ColourSource::Network,
        false => ColourSource::Views(config.perception.delight),
    };
    let refine = (!args.no_refine).then(|| config.refine.fit_config());
    let stages = EvalStages {
        crop,
        shape: parse_shape(&args.shape)?,
        colours,
        refine,
    };
    println!("stages: {}", describe(&stages, &args.shape));
    println!(
        "| bag | input views | held-out views | PSNR (dB) | SSIM | mask IoU |\n| --- | ---: | ---: | ---: | ---: | ---: |"
    );
    for (b, bag) in args.bags.iter().enumerate() {
        let rows = evaluate_bag(bag, &config.model, &args.views, &stages)?;
        if let (0, Some(path), Some(last)) = (b, &args.picture, rows.last()) {
            last.picture
                .save(path)
                .with_context(|| format!("writing {}", path.display()))?;
        }
        for row in rows {
            let (p, s, i) = row.means();
            println!(
                "| {} | {} | {} | {p:.2} | {s:.4} | {i:.4} |",
                bag.display(),
                row.views,
                row.per_view.len()
            );
            if let Some(r) = &row.refine {
                tracing::info!(
                    bag = %bag.display(),
                    views = row.views,
                    iterations = r.iterations,
                    best = r.best_iteration,
                    stop = ?r.stop,
                    improved = r.improved,
                    held = ?r.held,
                    loss = ?r.loss,
                    gaussians = ?r.gaussians,
                    grown = r.grown,
                    seconds = r.elapsed.as_secs_f32(),
                    times = ?r.times,
                    "refinement"
                );
            }
        }
    }
    println!(
        "inputs: {}",
        if args.full_frame {
            "whole frames"
        } else {
            "cropped to the person by the bag's /camN/mask"
        }
    );
    println!(
        "model: preset {}, {}",
        config.model.preset,
        if config.model.checkpoint.is_empty() {
            "embedded default weights (trained on synthetic people; `random` for seeded random)"
                .to_string()
        } else {
            config.model.checkpoint.clone()
        }
    );
    Ok(())
}

/// One line naming the stages that run.
fn describe(stages: &EvalStages, shape: &str) -> String {
    let crop = match stages.crop {
        InputCrop::Mask => "inputs cropped by the bag's masks",
        InputCrop::FullFrame => "whole input frames",
    };
    let colours = match stages.colours {
        ColourSource::Network => "the network's colours",
        ColourSource::Views(_) => "colours from the views",
    };
    let refine = match &stages.refine {
        Some(c) => format!("refinement (budget {:.1} s)", c.budget.as_secs_f32()),
        None => "no refinement".into(),
    };
    format!("{crop}; shape {shape}; {colours}; {refine}")
}

/// `--shape`: `bag`, `template`, `estimate` or `H,G`.
fn parse_shape(spec: &str) -> Result<ShapeSource> {
    match spec {
        "bag" => Ok(ShapeSource::Bag),
        "template" => Ok(ShapeSource::Template),
        "estimate" => Ok(ShapeSource::Estimate),
        _ => {
            let values: Vec<f32> = spec
                .split(',')
                .map(|v| v.trim().parse::<f32>())
                .collect::<Result<_, _>>()
                .with_context(|| {
                    format!("--shape `{spec}`: expected bag, template, estimate or H,G")
                })?;
            MakeHumanShape::from_params(&values)
                .map(ShapeSource::Fixed)
                .with_context(|| {
                    format!("--shape `{spec}`: expected two scales in 0.5..=2 (height, girth)")
                })
        }
    }
}
