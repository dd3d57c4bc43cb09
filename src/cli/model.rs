//! `lhmpp model`: create seeded checkpoints and print parameter counts.

use std::path::PathBuf;

use anyhow::Context;
use clap::{Args, Subcommand};

use lhmpp::model::checkpoint;
use lhmpp::model::config::{LhmppConfig, ParameterCounts};

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
        /// A checkpoint to inspect (validated against the preset in its metadata or --config).
        file: Option<PathBuf>,
        /// Preset to show (or to validate FILE against).
        #[arg(long)]
        config: Option<String>,
    },
    /// Compare our blocks with PyTorch reference fixtures (scripts/parity): max abs / rel error.
    Parity(super::model_parity::ParityArgs),
}

/// Runs `lhmpp model`.
pub fn run(args: ModelArgs) -> anyhow::Result<()> {
    match args.command {
        ModelCommand::Parity(args) => super::model_parity::run(args),
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

fn millions(n: usize) -> String {
    format!("{:.2}M", n as f64 / 1e6)
}

fn print_table(rows: &[(String, ParameterCounts)]) {
    println!(
        "| {:<10} | {:>9} | {:>9} | {:>9} | {:>9} | {:>8} | {:>8} | {:>9} | {:>9} |",
        "preset", "encoder", "frame", "points", "PIT", "motion", "GS head", "renderer", "total"
    );
    println!(
        "|{:-<12}|{:->11}|{:->11}|{:->11}|{:->11}|{:->10}|{:->10}|{:->11}|{:->11}|",
        "", "", "", "", "", "", "", "", ""
    );
    for (name, p) in rows {
        println!(
            "| {:<10} | {:>9} | {:>9} | {:>9} | {:>9} | {:>8} | {:>8} | {:>9} | {:>9} |",
            name,
            millions(p.encoder),
            millions(p.image_backbone),
            millions(p.point_backbone),
            millions(p.pit),
            millions(p.motion_embed),
            millions(p.gs_head),
            millions(p.neural_renderer),
            millions(p.total())
        );
    }
}
