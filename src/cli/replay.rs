//! `lhmpp replay BAG`: run the node on a bag (shorthand for `run` with `replay.bag` set).

use anyhow::Result;
use std::path::PathBuf;

/// Arguments of `lhmpp replay`.
#[derive(clap::Args, Debug)]
pub struct ReplayArgs {
    /// MCAP bag (file or rosbag2 directory) to play into the node.
    bag: PathBuf,
    /// Playback rate relative to the recording (1 = real time).
    #[arg(long, default_value_t = 1.0, conflicts_with = "fast")]
    rate: f64,
    /// Play as fast as the node consumes the messages (no pacing, nothing dropped).
    #[arg(long)]
    fast: bool,
    /// Parameter file for everything else (topics, model, outputs); omitted = built-in defaults.
    #[arg(long)]
    config: Option<PathBuf>,
    /// Override a parameter: `--set outputs.dir=out/replay` (repeatable).
    #[arg(long = "set", value_name = "KEY=VALUE")]
    overrides: Vec<String>,
}

/// Runs the node on the bag and prints the run summary.
pub fn run(args: ReplayArgs) -> Result<()> {
    let mut overrides = args.overrides;
    overrides.push(format!("replay.bag={}", args.bag.display()));
    overrides.push(format!(
        "replay.rate={}",
        if args.fast { 0.0 } else { args.rate }
    ));
    overrides.push("replay.exit_when_done=true".into());
    super::run::run(super::run::RunArgs {
        config: args.config,
        overrides,
        remaps: Vec::new(),
    })
}
