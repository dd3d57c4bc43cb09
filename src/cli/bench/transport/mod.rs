//! `lhmpp bench transport`: iceoryx2 (copied into, or written in, a loaned sample) and DDS
//! (ros2-client on loopback) publish→receive latency and throughput, their ratios, the kernel's
//! UDP receive-buffer drops and the shared-memory footprint, for a 160K-Gaussian avatar and a
//! 1920×1080 RGBA frame.

use anyhow::{Context, Result};
mod dds;
mod harness;

use crate::cli::udp_buffers::{self, RmemMaxRaised};
use dds::{DdsBench, DEFAULT_RECEIVE_BUFFER};
use harness::{render_table, run_case, BenchCase, BenchRow, Iceoryx2Bench, ShmWrite};
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
    /// SO_RCVBUF every DDS socket asks for, in bytes (default: twice the largest payload, at
    /// least 16 MiB). Linux caps it at net.core.rmem_max.
    #[arg(long)]
    dds_receive_buffer: Option<usize>,
    /// Raise net.core.rmem_max to the DDS receive buffer for this run and restore it
    /// afterwards (needs root). Without it, payloads larger than the capped buffer lose
    /// datagrams and wait for RustDDS's slow fragment repair.
    #[arg(long)]
    raise_rmem_max: bool,
}

/// Runs the iceoryx2 and DDS transport benchmarks and prints their tables.
pub fn run(args: TransportArgs) -> Result<()> {
    let cases = [
        BenchCase::avatar(args.gaussians),
        BenchCase::frame(1920, 1080, 4),
    ];
    let largest = cases.iter().map(|c| c.payload.len()).max().unwrap_or(0);
    let receive_buffer = args
        .dds_receive_buffer
        .unwrap_or((2 * largest).max(DEFAULT_RECEIVE_BUFFER));
    let _raised = if args.raise_rmem_max && !args.no_dds {
        RmemMaxRaised::to_at_least(receive_buffer).context("--raise-rmem-max")?
    } else {
        None
    };
    if !args.no_dds {
        print_receive_buffer(receive_buffer, largest, _raised.as_ref());
    }
    let mut rows = Vec::new();
    let mut footprints = Vec::new();
    let mut dds_failures = Vec::new();
    for (i, mut case) in cases.into_iter().enumerate() {
        let options = ShmOptions {
            initial_capacity: case.payload.len(),
            ..ShmOptions::default()
        };
        let kind = case.kind;
        for write in [ShmWrite::Copy, ShmWrite::Loan] {
            let before = ShmSnapshot::take();
            let person = format!("bench{}x{i}{}", std::process::id(), write as u8);
            let mut transport = Iceoryx2Bench::new(&person, kind, options.clone(), write)?;
            rows.push(run_case(&mut transport, &mut case, args.iterations, 10)?);
            if write == ShmWrite::Copy {
                let grown = ShmSnapshot::take().growth_since(&before);
                footprints.push((
                    case.label.clone(),
                    case.payload.len(),
                    options.preallocated_samples(kind),
                    grown,
                ));
            }
        }
        if !args.no_dds {
            let n = args.dds_iterations.unwrap_or(args.iterations);
            let topic = format!("bench{i}");
            match dds_row(args.dds_domain, &topic, receive_buffer, &mut case, n) {
                Ok(row) => rows.push(row),
                Err(e) => {
                    dds_failures.push(format!("{}: {e}", case.label));
                    // A payload DDS cannot deliver in time is a result: find what it carries.
                    if let Some(row) = largest_carried(&args, receive_buffer, case.payload.len()) {
                        rows.push(row);
                    }
                }
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

/// Prints the DDS sockets' receive buffer and warns when the largest payload does not fit.
fn print_receive_buffer(requested: usize, largest: usize, raised: Option<&RmemMaxRaised>) {
    match udp_buffers::rmem_max() {
        Ok(cap) => {
            let effective = udp_buffers::effective_receive_buffer(requested, cap);
            let raised = raised.map_or(String::new(), |r| {
                format!(" (raised from {} for this run)", r.previous())
            });
            println!(
                "dds: SO_RCVBUF requested {requested} B, net.core.rmem_max {cap} B{raised}, \
                 effective {effective} B"
            );
            if effective < largest {
                println!(
                    "dds: a {largest} B payload overflows that buffer; expect UDP drops and slow \
                     repair (use --raise-rmem-max as root, or sysctl -w net.core.rmem_max={requested})"
                );
            }
        }
        Err(e) => println!("dds: receive buffer unknown ({e})"),
    }
    println!();
}

/// Measures `case` over DDS, with the kernel's UDP receive-buffer drops during the run.
fn dds_row(
    domain: u16,
    topic: &str,
    receive_buffer: usize,
    case: &mut BenchCase,
    iterations: usize,
) -> Result<BenchRow> {
    let mut dds = DdsBench::new(domain, topic, receive_buffer)?;
    let drops_before = udp_buffers::udp_receive_buffer_errors().ok();
    let mut row = run_case(&mut dds, case, iterations, 10)?;
    row.udp_drops = drops_before.and_then(|before| {
        udp_buffers::udp_receive_buffer_errors()
            .ok()
            .map(|after| after.saturating_sub(before))
    });
    Ok(row)
}

/// The largest payload below `failed_bytes` that DDS delivers in lock-step (halving from
/// `failed_bytes / 2` down to 64 KiB), measured as a row of its own.
fn largest_carried(
    args: &TransportArgs,
    receive_buffer: usize,
    failed_bytes: usize,
) -> Option<BenchRow> {
    let n = args.dds_iterations.unwrap_or(args.iterations).min(50);
    let mut rows = (failed_bytes / 2) / (1024 * 4);
    let mut probe = 0;
    while rows >= 16 {
        let mut case = BenchCase::frame(1024, rows as u32, 4);
        case.label = format!("probe {} MB", case.payload.len() / 1_000_000);
        let topic = format!("probe{probe}");
        match dds_row(args.dds_domain, &topic, receive_buffer, &mut case, n) {
            Ok(row) => return Some(row),
            Err(e) => println!("dds probe {} B failed: {e}", case.payload.len()),
        }
        rows /= 2;
        probe += 1;
    }
    None
}

/// DDS ÷ iceoryx2 (both ways of writing) for each payload measured on both.
fn render_ratios(rows: &[BenchRow]) -> String {
    let mut out = format!(
        "{:<24} {:<14} {:>12} {:>12} {:>12}\n",
        "dds ÷", "iceoryx2 row", "p50 latency", "p99 latency", "throughput"
    );
    for dds in rows.iter().filter(|r| r.transport == "dds") {
        for shm in rows
            .iter()
            .filter(|r| r.transport.starts_with("iceoryx2") && r.case == dds.case)
        {
            out.push_str(&format!(
                "{:<24} {:<14} {:>11.1}x {:>11.1}x {:>11.3}x\n",
                dds.case,
                shm.transport,
                dds.p50_us / shm.p50_us,
                dds.p99_us / shm.p99_us,
                dds.msgs_per_s / shm.msgs_per_s
            ));
        }
    }
    out
}
