//! `lhmpp replay BAG`: run the node on a bag (shorthand for `run` with `replay.bag` set).

use super::config_source::ConfigSource;
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
    /// Everything else (topics, model, outputs).
    #[command(flatten)]
    pub source: ConfigSource,
}

/// Runs the node on the bag and prints the run summary.
pub fn run(args: ReplayArgs) -> Result<()> {
    let mut source = args.source;
    let overrides = &mut source.overrides;
    overrides.push(format!("replay.bag={}", args.bag.display()));
    overrides.push(format!(
        "replay.rate={}",
        if args.fast { 0.0 } else { args.rate }
    ));
    overrides.push("replay.exit_when_done=true".into());
    super::run::run(super::run::RunArgs {
        source,
        remaps: Vec::new(),
    })
}
