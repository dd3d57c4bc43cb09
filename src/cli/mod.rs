//! Command-line interface: one file per subcommand group; this file lists them and dispatches.

use clap::{Parser, Subcommand};

mod bench;
mod config_cmd;
mod shm_echo;

/// LHM++ human-avatar reconstruction node for ROS 2.
///
/// Working today: `config` (validate and print launch configs).
/// Planned (see README status table): run, record, replay, bag, synth, eval, model, render,
/// shm-echo, bench.
#[derive(Parser, Debug)]
#[command(name = "lhmpp", version, about, long_about)]
struct Cli {
    /// Log filter (tracing-subscriber syntax, e.g. `info` or `lhmpp=debug`); RUST_LOG wins.
    #[arg(long, global = true, default_value = "info")]
    log: String,
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand, Debug)]
enum Command {
    /// Validate a launch config (ROS 2 parameter file) and print the resolved parameters.
    Config(config_cmd::ConfigArgs),
    /// Print avatars and frames received over shared memory (iceoryx2), one line each.
    ShmEcho(shm_echo::ShmEchoArgs),
    /// Run a benchmark and print its table (`bench transport`).
    Bench(bench::BenchArgs),
}

/// Parses the command line, sets up logging and runs the subcommand.
pub fn main() -> anyhow::Result<()> {
    let cli = Cli::parse();
    init_logging(&cli.log);
    match cli.command {
        Command::Config(args) => config_cmd::run(args),
        Command::ShmEcho(args) => shm_echo::run(args),
        Command::Bench(args) => bench::run(args),
    }
}

fn init_logging(default: &str) {
    let filter = tracing_subscriber::EnvFilter::try_from_default_env()
        .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new(default));
    tracing_subscriber::fmt()
        .with_env_filter(filter)
        .with_writer(std::io::stderr)
        .init();
}
