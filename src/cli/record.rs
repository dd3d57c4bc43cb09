//! `lhmpp record`: record the node's input and output topics into an MCAP bag until
//! SIGINT/SIGTERM or `--duration`.

use super::config_source::ConfigSource;
use anyhow::{Context, Result};
use lhmpp::bag::{BagWriter, BagWriterOptions};
use lhmpp::node::record::{self, RecordOptions};
use lhmpp::node::ros::{ResolvedTopics, RosNodeOptions};
use std::collections::BTreeMap;
use std::io::Write;
use std::path::PathBuf;
use std::time::Duration;

/// Arguments of `lhmpp record`.
#[derive(clap::Args, Debug)]
pub struct RecordArgs {
    /// The parameters naming the topics and the domain.
    #[command(flatten)]
    pub source: ConfigSource,
    /// Bag to write: a `.mcap` file, or a rosbag2 directory (default `lhmpp_<unix time>`).
    #[arg(short = 'o', long = "output")]
    output: Option<PathBuf>,
    /// Record only these topics (fully qualified, as `lhmpp record` lists them at start).
    #[arg(long, num_args = 1..)]
    topics: Vec<String>,
    /// Stop after this many seconds (default: until SIGINT/SIGTERM).
    #[arg(long)]
    duration: Option<f64>,
    /// Seconds between progress lines.
    #[arg(long, default_value_t = 5.0)]
    progress: f64,
    /// Restrict DDS to loopback (127.0.0.1).
    #[arg(long)]
    loopback: bool,
}

fn seconds(value: f64, flag: &str) -> Result<Duration> {
    Duration::try_from_secs_f64(value)
        .ok()
        .filter(|d| !d.is_zero())
        .with_context(|| format!("{flag} {value}: expected a positive number of seconds"))
}

/// Records until stopped and prints the messages written per topic.
pub fn run(args: RecordArgs) -> Result<()> {
    let config = args.source.load()?;
    let domain_env = std::env::var("ROS_DOMAIN_ID").ok();
    let mut ros = RosNodeOptions::from_config(&config, BTreeMap::new(), domain_env.as_deref())?;
    if args.loopback {
        ros = ros.loopback_only();
    }
    let resolved = ResolvedTopics::from_options(&ros)?;
    let topics = record::select(
        record::plan(&resolved, config.inputs.image_qos),
        &args.topics,
    )?;
    let options = RecordOptions {
        flush_interval: Duration::from_secs(1),
        progress_period: seconds(args.progress, "--progress")?,
        duration: args
            .duration
            .map(|d| seconds(d, "--duration"))
            .transpose()?,
    };
    let output = args.output.unwrap_or_else(|| {
        let secs = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map_or(0, |d| d.as_secs());
        PathBuf::from(format!("lhmpp_{secs}"))
    });
    let writer_options = BagWriterOptions {
        flush_interval: Some(options.flush_interval),
        ..BagWriterOptions::default()
    };
    let bag = BagWriter::create_with(&output, writer_options)?;
    let runtime = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
        .context("tokio runtime")?;
    let summary = runtime.block_on(record::record(
        &ros.participant,
        &topics,
        bag,
        &options,
        lhmpp::node::signal::interrupt_or_terminate(),
    ))?;
    // The bag is complete at this point: a closed stdout (e.g. `| head`) must not turn the
    // summary into a panic, so write errors are ignored.
    let mut out = std::io::stdout().lock();
    let _ = writeln!(
        out,
        "recorded {} messages in {:.1} s into {}",
        summary.total,
        summary.elapsed.as_secs_f64(),
        output.display()
    );
    for (topic, n) in &summary.per_topic {
        let _ = writeln!(out, "  {topic}: {n}");
    }
    Ok(())
}
