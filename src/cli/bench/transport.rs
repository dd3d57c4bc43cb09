//! `lhmpp bench transport`: iceoryx2 and DDS (ros2-client on loopback) publish→receive latency
//! and throughput, their ratio, and the shared-memory footprint, for a 160K-Gaussian avatar and
//! a 1920×1080 RGBA frame.

use anyhow::Result;
use lhmpp::transport::bench::{render_table, run_case, BenchCase, BenchRow, Iceoryx2Bench};
use lhmpp::transport::dds_bench::DdsBench;
use lhmpp::transport::footprint::ShmSnapshot;
use lhmpp::transport::ShmOptions;

/// Arguments of `lhmpp bench transport`.
#[derive(clap::Args, Debug)]
pub struct TransportArgs {
    /// Measured round trips per payload (after 10 warm-up ones).
    #[arg(long, default_value_t = 200)]
    iterations: usize,
    /// Gaussians in the avatar payload.
    #[arg(long, default_value_t = 160_000)]
    gaussians: usize,
    /// Measured round trips per payload over DDS (default: as `--iterations`).
    #[arg(long)]
    dds_iterations: Option<usize>,
    /// Skip the DDS rows.
    #[arg(long)]
    no_dds: bool,
    /// DDS domain of the benchmark (loopback only).
    #[arg(long, default_value_t = 77)]
    dds_domain: u16,
}

/// Runs the iceoryx2 and DDS transport benchmarks and prints their tables.
pub fn run(args: TransportArgs) -> Result<()> {
    let cases = [
        BenchCase::avatar(args.gaussians),
        BenchCase::frame(1920, 1080, 4),
    ];
    let mut rows = Vec::new();
    let mut footprints = Vec::new();
    let mut dds_failures = Vec::new();
    for (i, mut case) in cases.into_iter().enumerate() {
        let options = ShmOptions {
            initial_capacity: case.payload.len(),
            ..ShmOptions::default()
        };
        let before = ShmSnapshot::take();
        let person = format!("bench{}x{i}", std::process::id());
        let kind = case.kind;
        let mut transport = Iceoryx2Bench::new(&person, kind, options.clone())?;
        rows.push(run_case(&mut transport, &mut case, args.iterations, 10)?);
        let grown = ShmSnapshot::take().growth_since(&before);
        footprints.push((
            case.label.clone(),
            case.payload.len(),
            options.preallocated_samples(kind),
            grown,
        ));
        drop(transport);
        if !args.no_dds {
            let mut dds = DdsBench::new(args.dds_domain, &format!("bench{i}"))?;
            let n = args.dds_iterations.unwrap_or(args.iterations);
            // A payload DDS cannot deliver in time is a result, not the end of the table.
            match run_case(&mut dds, &mut case, n, 10) {
                Ok(row) => rows.push(row),
                Err(e) => dds_failures.push(format!("{}: {e}", case.label)),
            }
        }
    }
    print!("{}", render_table(&rows));
    for failure in &dds_failures {
        println!("dds failed: {failure}");
    }
    if !args.no_dds {
        println!();
        print!("{}", render_ratios(&rows));
    }
    println!();
    println!(
        "{:<24} {:>12} {:>8} {:>6} {:>14} {:>14}",
        "shared memory", "payload B", "samples", "files", "reserved MB", "resident MB"
    );
    for (label, bytes, samples, f) in footprints {
        println!(
            "{:<24} {:>12} {:>8} {:>6} {:>14.1} {:>14.1}",
            label,
            bytes,
            samples,
            f.files,
            f.reserved as f64 / 1e6,
            f.resident as f64 / 1e6
        );
    }
    Ok(())
}

/// DDS ÷ iceoryx2 for each payload measured on both.
fn render_ratios(rows: &[BenchRow]) -> String {
    let mut out = format!(
        "{:<24} {:>12} {:>12} {:>12}\n",
        "dds / iceoryx2", "p50 latency", "p99 latency", "throughput"
    );
    for dds in rows.iter().filter(|r| r.transport == "dds") {
        let Some(shm) = rows
            .iter()
            .find(|r| r.transport == "iceoryx2" && r.case == dds.case)
        else {
            continue;
        };
        out.push_str(&format!(
            "{:<24} {:>11.1}x {:>11.1}x {:>11.3}x\n",
            dds.case,
            dds.p50_us / shm.p50_us,
            dds.p99_us / shm.p99_us,
            dds.msgs_per_s / shm.msgs_per_s
        ));
    }
    out
}
