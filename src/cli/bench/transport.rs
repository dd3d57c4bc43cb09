//! `lhmpp bench transport`: iceoryx2 publish→receive latency, throughput and shared-memory
//! footprint for a 160K-Gaussian avatar and a 1920×1080 RGBA frame.

use anyhow::Result;
use lhmpp::transport::bench::{render_table, run_case, BenchCase, Iceoryx2Bench};
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
}

/// Runs the iceoryx2 transport benchmark and prints its tables.
pub fn run(args: TransportArgs) -> Result<()> {
    let cases = [
        BenchCase::avatar(args.gaussians),
        BenchCase::frame(1920, 1080, 4),
    ];
    let mut rows = Vec::new();
    let mut footprints = Vec::new();
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
    }
    print!("{}", render_table(&rows));
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
