//! `lhmpp bench`: benchmarks that print tables (one file per subject).

use clap::{Args, Subcommand};

mod model;
mod render;

/// Arguments of `lhmpp bench`.
#[derive(Args, Debug)]
pub struct BenchArgs {
    #[command(subcommand)]
    command: BenchCommand,
}

#[derive(Subcommand, Debug)]
enum BenchCommand {
    /// CPU splatting (frames per second) and Gaussian LBS posing.
    Render(render::RenderBenchArgs),
    /// Time image encoding, PIT fusion, the Gaussian head, end to end, and an incremental update.
    Model(model::ModelBenchArgs),
}

/// Runs `lhmpp bench`.
pub fn run(args: BenchArgs) -> anyhow::Result<()> {
    match args.command {
        BenchCommand::Render(a) => render::run(a),
        BenchCommand::Model(a) => model::run(a),
    }
}
