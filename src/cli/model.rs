//! `lhmpp model`: create seeded checkpoints, print parameter counts, run one forward pass.

use std::path::PathBuf;

use anyhow::Context;
use clap::{Args, Subcommand};

use lhmpp::model::config::{LhmppConfig, ParameterCounts};
use lhmpp::model::{checkpoint, hub};

#[path = "model_forward.rs"]
mod model_forward;

/// Arguments of `lhmpp model`.
#[derive(Args, Debug)]
pub struct ModelArgs {
    #[command(subcommand)]
    command: ModelCommand,
}

#[derive(Subcommand, Debug)]
enum ModelCommand {
    /// Write seeded random weights for a preset to a safetensors file.
    Init {
        /// Preset: tiny, s, m, l, lhmpp-700m.
        #[arg(long, default_value = "tiny")]
        config: String,
        /// Random seed.
        #[arg(long, default_value_t = 1)]
        seed: u64,
        /// Output file.
        #[arg(short, long)]
        output: PathBuf,
    },
    /// Print parameter counts per part: of a checkpoint file, of one preset, or of every preset.
    Info {
        /// A checkpoint to inspect: a safetensors file (validated against the preset in its
        /// metadata or --config) or a hub folder (config.json + model.safetensors).
        file: Option<PathBuf>,
        /// Preset to show (or to validate FILE against).
        #[arg(long)]
        config: Option<String>,
    },
    /// Compare our blocks with PyTorch reference fixtures (scripts/parity): max abs / rel error.
    Parity(super::model_parity::ParityArgs),
    /// Run the whole network on `images`, `anchors`, `normals` (optional part masks, official
    /// draws to replay, a feature image) from a safetensors file and write every output
    /// (parity with the PyTorch twin and the official code; names in docs/model-forward.md).
    Forward(model_forward::ForwardArgs),
}

/// Runs `lhmpp model`.
pub fn run(args: ModelArgs) -> anyhow::Result<()> {
    match args.command {
        ModelCommand::Parity(args) => super::model_parity::run(args),
        ModelCommand::Forward(args) => model_forward::run(args),
        ModelCommand::Init {
            config,
            seed,
            output,
        } => {
            let cfg = LhmppConfig::preset(&config)?;
            let n = checkpoint::init_checkpoint(&cfg, seed, &output)?;
            println!(
                "wrote {} ({} parameters, preset {}, seed {seed})",
                output.display(),
                n,
                cfg.preset
            );
            Ok(())
        }
        ModelCommand::Info {
            file: Some(file),
            config: _,
        } if file.is_dir() => hub_info(&file),
        ModelCommand::Info {
            file: Some(file),
            config,
        } => {
            let (preset, stored) = checkpoint::read_metadata(&file)?;
            let cfg = match (config, stored, preset) {
                (Some(p), _, _) => LhmppConfig::preset(&p)?,
                (None, Some(cfg), _) => cfg,
                (None, None, Some(p)) => LhmppConfig::preset(&p)?,
                (None, None, None) => anyhow::bail!(
                    "{}: no preset in the metadata; pass --config",
                    file.display()
                ),
            };
            checkpoint::load_var_builder(
                &file,
                &cfg,
                candle_core::DType::F32,
                &candle_core::Device::Cpu,
            )
            .with_context(|| format!("validating {}", file.display()))?;
            println!(
                "{}: valid checkpoint for preset `{}`",
                file.display(),
                cfg.preset
            );
            print_table(&[(cfg.preset.clone(), cfg.parameter_count())]);
            Ok(())
        }
        ModelCommand::Info { file: None, config } => {
            let names: Vec<String> = match config {
                Some(p) => vec![p],
                None => LhmppConfig::PRESETS.iter().map(|s| s.to_string()).collect(),
            };
            let rows = names
                .iter()
                .map(|n| Ok((n.clone(), LhmppConfig::preset(n)?.parameter_count())))
                .collect::<anyhow::Result<Vec<_>>>()?;
            print_table(&rows);
            Ok(())
        }
    }
}

/// Prints what a hub folder holds; validates the weights from their headers only.
fn hub_info(dir: &std::path::Path) -> anyhow::Result<()> {
    let hub = hub::HubFolder::open(dir)?;
    let o = &hub.official;
    let pb = &o.transformer_decoder.point_backbone;
    println!("{}: hub folder", dir.display());
    println!(
        "  config.json: {} · {} · PTv3 enc {:?} dec {:?} · {} frame blocks · merge {} · \
         {} query points · {} · renderer {}",
        o.model_name.as_deref().unwrap_or("?"),
        o.encoder_model_name,
        pb.enc_channels,
        pb.dec_channels,
        o.transformer_decoder.image_backbone.depth,
        o.transformer_decoder.merge_ratio,
        o.dense_sample_pts.map_or("?".into(), |n| n.to_string()),
        o.smplx_type.as_deref().unwrap_or("?"),
        o.neural_renderer.kind
    );
    if let Some(sh) = &hub.config.shape_head {
        println!(
            "  shape_head: {} betas from the views' pose tokens ({} trunk blocks, {} steps)",
            sh.target_dim, sh.trunk_depth, sh.num_iterations
        );
    }
    if hub.differences.is_empty() {
        println!("  config: equals preset {}", hub.config.preset);
    } else {
        println!(
            "  config `{}` differs from preset lhmpp-700m:",
            hub.config.preset
        );
        for d in &hub.differences {
            println!("    {d}");
        }
    }
    for w in &hub.weights {
        println!("  weights: {}", w.display());
    }
    let s = hub
        .check()
        .with_context(|| format!("validating {}", dir.display()))?;
    let dtypes: Vec<String> = s.dtypes.iter().map(|(k, v)| format!("{v} {k}")).collect();
    println!(
        "  valid: {} tensors, {} parameters ({})",
        s.tensors,
        millions(s.parameters),
        dtypes.join(", ")
    );
    for (prefix, n, p) in s.ignored.iter().filter(|i| i.1 > 0) {
        println!("  ignored: {prefix}* ({n} tensors, {})", millions(*p));
    }
    print_table(&[(hub.config.preset.clone(), hub.config.parameter_count())]);
    Ok(())
}

fn millions(n: usize) -> String {
    format!("{:.2}M", n as f64 / 1e6)
}

fn print_table(rows: &[(String, ParameterCounts)]) {
    println!(
        "| {:<23} | {:>9} | {:>9} | {:>9} | {:>9} | {:>8} | {:>8} | {:>9} | {:>8} | {:>9} |",
        "preset",
        "encoder",
        "frame",
        "points",
        "PIT",
        "motion",
        "GS head",
        "renderer",
        "shape",
        "total"
    );
    println!(
        "|{:-<25}|{:->11}|{:->11}|{:->11}|{:->11}|{:->10}|{:->10}|{:->11}|{:->10}|{:->11}|",
        "", "", "", "", "", "", "", "", "", ""
    );
    for (name, p) in rows {
        println!(
            "| {:<23} | {:>9} | {:>9} | {:>9} | {:>9} | {:>8} | {:>8} | {:>9} | {:>8} | {:>9} |",
            name,
            millions(p.encoder),
            millions(p.image_backbone),
            millions(p.point_backbone),
            millions(p.pit),
            millions(p.motion_embed),
            millions(p.gs_head),
            millions(p.neural_renderer),
            millions(p.shape_head),
            millions(p.total())
        );
    }
}
