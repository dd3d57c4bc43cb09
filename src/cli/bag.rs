//! `lhmpp bag ...`: inspect MCAP bags (`info`, like `ros2 bag info`) and rewrite damaged ones
//! (`recover`).

use anyhow::Result;
use clap::{Args, Subcommand};
use lhmpp::bag::{BagReader, Salvage};
use std::io::Write;
use std::path::PathBuf;
use std::time::{Duration, Instant};

/// Time between progress lines of `bag recover`.
const PROGRESS_PERIOD: Duration = Duration::from_millis(250);

/// Exit status of `bag info` for a damaged bag: it was read, but unreadable ranges were
/// skipped or the file is cut short.
pub const EXIT_DAMAGED: u8 = 3;

/// Arguments of `lhmpp bag`.
#[derive(Args, Debug)]
pub struct BagArgs {
    #[command(subcommand)]
    command: BagCommand,
}

#[derive(Subcommand, Debug)]
enum BagCommand {
    /// Print a bag's topics, types, message counts, duration, size and compression, and what
    /// a damaged bag lost (skipped byte ranges, lost messages, where a cut file ends).
    #[command(
        after_help = "Exit status: 0 complete bag; 3 damaged bag (unreadable ranges \
        skipped or the file cut short; everything readable is counted above); 1 unreadable \
        (not an MCAP file, cannot be opened); 2 bad command line."
    )]
    Info {
        /// The MCAP bag file (or rosbag2 bag directory).
        bag: PathBuf,
    },
    /// Write every readable message of a damaged bag into a clean bag (rosbag2 profile, the
    /// same schemas, channels and metadata records); never over the input.
    Recover {
        /// The damaged MCAP bag file (or rosbag2 bag directory).
        input: PathBuf,
        /// The clean bag: an `.mcap` file, or a bag directory (with `metadata.yaml`).
        #[arg(short, long)]
        output: PathBuf,
    },
}

/// Runs a `bag` subcommand.
pub fn run(args: BagArgs) -> Result<()> {
    match args.command {
        BagCommand::Info { bag } => {
            let reader = BagReader::open(&bag)?;
            print!("{}", info_text(&reader));
            if reader.is_complete() {
                return Ok(());
            }
            Err(super::ExitStatus {
                code: EXIT_DAMAGED,
                message: format!(
                    "bag {} is damaged: {}",
                    reader.path().display(),
                    reader.salvage()
                ),
            }
            .into())
        }
        BagCommand::Recover { input, output } => {
            let mut last = None::<Instant>;
            let recovery = lhmpp::bag::recover(&input, &output, |done, total| {
                // At most four progress lines a second, and the last one.
                if done == total || last.is_none_or(|t| t.elapsed() >= PROGRESS_PERIOD) {
                    last = Some(Instant::now());
                    eprint!("\rrecovering: {done}/{total} messages");
                    let _ = std::io::stderr().flush();
                }
            })?;
            eprintln!();
            println!(
                "recovered {} messages on {} topics into {}; input {}: {}",
                recovery.messages,
                recovery.topics,
                recovery.output.display(),
                input.display(),
                recovery.salvage
            );
            Ok(())
        }
    }
}

fn human_size(bytes: u64) -> String {
    const UNITS: [&str; 4] = ["B", "KiB", "MiB", "GiB"];
    let mut value = bytes as f64;
    let mut unit = 0;
    while value >= 1024.0 && unit + 1 < UNITS.len() {
        value /= 1024.0;
        unit += 1;
    }
    if unit == 0 {
        format!("{bytes} B")
    } else {
        format!("{value:.1} {}", UNITS[unit])
    }
}

fn seconds(ns: u64) -> String {
    format!("{}.{:09}", ns / 1_000_000_000, ns % 1_000_000_000)
}

/// The `Skipped:` line of each unreadable range and a `Damaged:` total.
fn damage_lines(salvage: &Salvage, read: usize, line: &mut impl FnMut(&str, String)) {
    for (i, s) in salvage.skipped.iter().enumerate() {
        line(if i == 0 { "Skipped:" } else { "" }, s.to_string());
    }
    if !salvage.skipped.is_empty() || salvage.unknown_channel > 0 {
        let expected = salvage
            .expected_messages
            .map_or(String::new(), |n| format!(" of {n} (summary statistics)"));
        line(
            "Damaged:",
            format!("{salvage}; read {read} messages{expected}"),
        );
    }
}

/// The report `ros2 bag info` would print, in the same shape.
fn info_text(bag: &BagReader) -> String {
    let mut out = String::new();
    let mut line = |key: &str, value: String| out.push_str(&format!("{key:<19}{value}\n"));
    line("Files:", bag.path().display().to_string());
    line(
        "Bag size:",
        format!(
            "{} ({} bytes)",
            human_size(bag.file_size()),
            bag.file_size()
        ),
    );
    line("Storage id:", "mcap".into());
    line("Profile:", bag.profile().to_string());
    let (duration, start, end) = match bag.time_range() {
        Some((start, end)) => (seconds(end - start) + "s", seconds(start), seconds(end)),
        None => ("0s".into(), "-".into(), "-".into()),
    };
    line("Duration:", duration);
    line("Start:", start);
    line("End:", end);
    line("Messages:", bag.messages().len().to_string());
    let compression = bag.compression();
    line(
        "Compression:",
        if compression.is_empty() {
            "none".into()
        } else {
            format!("{} ({} chunks)", compression.join(", "), bag.chunk_count())
        },
    );
    if let Some(t) = bag.truncation() {
        line(
            "Incomplete:",
            format!("read up to byte {}: {}", t.offset, t.reason),
        );
    }
    damage_lines(bag.salvage(), bag.messages().len(), &mut line);
    let topics = bag.topics();
    let name_width = topics.iter().map(|t| t.name.len()).max().unwrap_or(0);
    let type_width = topics.iter().map(|t| t.type_name.len()).max().unwrap_or(0);
    for (i, t) in topics.iter().enumerate() {
        let key = if i == 0 { "Topic information:" } else { "" };
        line(
            key,
            format!(
                "Topic: {:<name_width$} | Type: {:<type_width$} | Count: {} | Serialization Format: {}",
                t.name, t.type_name, t.message_count, t.message_encoding
            ),
        );
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use lhmpp::bag::BagWriter;
    use lhmpp::msgs::Time;

    #[test]
    fn info_lists_topics_counts_duration_and_compression() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("info.mcap");
        let mut writer = BagWriter::create(&path).unwrap();
        for i in 0..3u64 {
            writer
                .write(
                    "/clock_like",
                    1_000_000_000 + i * 500_000_000,
                    &Time::default(),
                )
                .unwrap();
        }
        writer.finish().unwrap();
        let text = info_text(&BagReader::open(&path).unwrap());
        assert!(text.contains("Duration:          1.000000000s"), "{text}");
        assert!(text.contains("Messages:          3"), "{text}");
        assert!(
            text.contains("Compression:       zstd (1 chunks)"),
            "{text}"
        );
        assert!(
            text.contains("Topic: /clock_like | Type: builtin_interfaces/msg/Time | Count: 3 | Serialization Format: cdr"),
            "{text}"
        );
    }

    #[test]
    fn info_of_a_cut_bag_says_where_reading_stopped() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("cut.mcap");
        let mut writer = BagWriter::create(&path).unwrap();
        writer.write("/t", 5, &Time::default()).unwrap();
        writer.finish().unwrap();
        let bytes = std::fs::read(&path).unwrap();
        let bag = BagReader::from_bytes(path.clone(), &bytes[..bytes.len() - 20]).unwrap();
        let text = info_text(&bag);
        assert!(
            text.contains("Incomplete:        read up to byte"),
            "{text}"
        );
        assert!(text.contains("Count: 1"), "{text}");
    }
}
