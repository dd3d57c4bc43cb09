//! `lhmpp shm-echo`: subscribes to a person's shared-memory streams and prints one line per
//! received avatar or frame (kind, person, revision, counts, FNV-1a 64 checksum, latency).
//!
//! Sleeps on the person's event listener between samples: no polling.

use std::io::Write;
use std::time::{Duration, Instant};

use anyhow::{Context, Result};
use lhmpp::transport::layout::unix_time_ns;
use lhmpp::transport::{PayloadBody, ShmNode, ShmOptions};

/// Arguments of `lhmpp shm-echo`.
#[derive(clap::Args, Debug)]
pub struct ShmEchoArgs {
    /// Person whose streams to read (`lhmpp/<person>/...`).
    #[arg(long, default_value = "person0")]
    person: String,
    /// Camera whose frames to read as well (repeatable); none = avatars only.
    #[arg(long = "camera")]
    cameras: Vec<String>,
    /// Exit after this many samples on every stream (0 = run until the timeout).
    #[arg(long, default_value_t = 0)]
    count: usize,
    /// Exit with an error after this many seconds without finishing (0 = never).
    #[arg(long, default_value_t = 0.0)]
    timeout: f64,
}

/// Prints `ready <services>` once subscribed, then one line per sample:
/// `avatar person=P rev=R gaussians=N sh=S checksum=0x.. latency_us=L` or
/// `frame person=P rev=R 1920x1080x4 alpha=0 depth=0 checksum=0x.. latency_us=L`.
pub fn run(args: ShmEchoArgs) -> Result<()> {
    let node = ShmNode::new(
        &format!("lhmpp-shm-echo-{}", std::process::id()),
        ShmOptions::default(),
    )?;
    let cameras: Vec<&str> = args.cameras.iter().map(String::as_str).collect();
    let mut subscriber = node.subscriber(&args.person, &cameras)?;
    let services: Vec<String> = subscriber.services().map(str::to_owned).collect();
    let mut seen = vec![0usize; services.len()];
    let deadline =
        (args.timeout > 0.0).then(|| Instant::now() + Duration::from_secs_f64(args.timeout));
    let mut out = std::io::stdout().lock();
    writeln!(out, "ready {}", services.join(" "))?;
    out.flush()?;
    let done = |seen: &[usize]| args.count > 0 && seen.iter().all(|&n| n >= args.count);
    while !done(&seen) {
        while let Some(sample) = subscriber.try_receive()? {
            let received_ns = unix_time_ns();
            let index = services
                .iter()
                .position(|s| s == sample.service())
                .unwrap_or(0);
            seen[index] += 1;
            let decoded = sample
                .decode()
                .with_context(|| format!("decoding a sample of {}", sample.service()))?;
            let latency_us = received_ns.saturating_sub(decoded.stamp.timestamp_ns) as f64 / 1e3;
            let counts = match decoded.body {
                PayloadBody::Avatar(a) => format!("gaussians={} sh={}", a.gaussians(), a.sh_coeffs),
                PayloadBody::Frame(f) => format!(
                    "{}x{}x{} alpha={} depth={}",
                    f.width,
                    f.height,
                    f.channels,
                    u8::from(f.alpha.is_some()),
                    u8::from(f.depth.is_some())
                ),
            };
            writeln!(
                out,
                "{} person={} rev={} {} checksum={:#018x} latency_us={:.1}",
                decoded.body.kind().name(),
                decoded.person,
                decoded.stamp.revision,
                counts,
                decoded.body.checksum(),
                latency_us
            )?;
            out.flush()?;
        }
        if done(&seen) {
            break;
        }
        let wait = match deadline {
            Some(deadline) => {
                let left = deadline.saturating_duration_since(Instant::now());
                if left.is_zero() {
                    anyhow::bail!(
                        "shm-echo: timed out after {} s with {:?} samples of {:?}",
                        args.timeout,
                        seen,
                        services
                    );
                }
                left
            }
            None => Duration::from_secs(3600),
        };
        subscriber.wait(wait)?;
    }
    Ok(())
}
