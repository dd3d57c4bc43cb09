//! `lhmpp loadgen`: synthetic camera streams on loopback, bounded in time, for load and soak
//! tests of the node. It publishes N cameras × R Hz × W×H frames of a walking synthetic person,
//! or with `--people K` of K people crossing a room (the crowd scene of `lhmpp synth --people`)
//! (JPEG `CompressedImage` or raw `rgb8` `Image`, each with its `CameraInfo`), on 127.0.0.1
//! only. With `--watch-pid` it samples that process's resident memory every second and
//! reports its maximum and slope; `--report DIR` keeps the samples (`rss.csv`) and the
//! summary (`summary.json`).

use super::udp_buffers;
use super::ExitStatus;
use anyhow::{bail, Context, Result};
use lhmpp::config::ImageQos;
use lhmpp::msgs::{CameraInfo, CompressedImage, Header, Image, RosMessage, Time};
use lhmpp::node::ros::{
    create_context, image_input_qos, resolve_domain_id, type_name, ParticipantOptions,
};
use lhmpp::synth::capture::{camera_info, optical_frame};
use lhmpp::synth::crowd::{render_crowd_stream, CrowdOptions};
use lhmpp::synth::stream::{render_stream, StreamOptions};
use ros2_client::qos::QosProfile;
use ros2_client::{Name, NodeName, NodeOptions};
use serde::Serialize;
use std::io::Write;
use std::net::IpAddr;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

/// Longest run `--seconds` accepts (one hour).
const MAX_SECONDS: u64 = 3600;
/// Exit status when the watched process ended before the load did.
const WATCHED_PROCESS_GONE: u8 = 3;

/// How frames travel.
#[derive(clap::ValueEnum, Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Encoding {
    /// `sensor_msgs/CompressedImage`, JPEG quality 90 (`<topic>/compressed`).
    Jpeg,
    /// `sensor_msgs/Image`, rgb8, uncompressed (6.2 MB per 1080p frame).
    Rgb8,
}

/// Arguments of `lhmpp loadgen`.
#[derive(clap::Args, Debug)]
pub struct LoadgenArgs {
    /// Cameras: topics `<prefix>/camN/image_raw` (+`/compressed` for JPEG) and
    /// `<prefix>/camN/camera_info`.
    #[arg(long, default_value_t = 4, value_parser = clap::value_parser!(u16).range(1..=64))]
    pub cameras: u16,
    /// Frames per second and camera.
    #[arg(long, default_value_t = 30.0)]
    pub rate: f64,
    /// Frame width in pixels.
    #[arg(long, default_value_t = 1920, value_parser = clap::value_parser!(u32).range(16..=8192))]
    pub width: u32,
    /// Frame height in pixels.
    #[arg(long, default_value_t = 1080, value_parser = clap::value_parser!(u32).range(16..=8192))]
    pub height: u32,
    /// How long to publish, seconds (1..=3600).
    #[arg(long, default_value_t = 600, value_parser = clap::value_parser!(u64).range(1..=MAX_SECONDS))]
    pub seconds: u64,
    /// How frames travel.
    #[arg(long, value_enum, default_value_t = Encoding::Jpeg)]
    pub encoding: Encoding,
    /// Distinct frames per camera (the walk cycle sampled evenly; with `--people`, the walk
    /// across the room), cycled.
    #[arg(long, default_value_t = 8, value_parser = clap::value_parser!(u16).range(1..=240))]
    pub frames: u16,
    /// Topic prefix.
    #[arg(long, default_value = "/loadgen")]
    pub prefix: String,
    /// DDS domain (default: `ROS_DOMAIN_ID`, else 0).
    #[arg(long)]
    pub domain: Option<u16>,
    /// Seed of the synthetic person (of the crowd scene with `--people`).
    #[arg(long, default_value_t = 5)]
    pub seed: u64,
    /// Publish this many people walking across a room past one another, seen by fixed room
    /// cameras (as `lhmpp synth --people`), instead of one person on a camera ring. Each cycle
    /// of `--frames` starts the walk again, so the people reappear at its start.
    #[arg(long, value_parser = clap::value_parser!(u8).range(1..=8))]
    pub people: Option<u8>,
    /// Sample this process's resident memory every second (the node under load).
    #[arg(long, value_name = "PID")]
    pub watch_pid: Option<u32>,
    /// Fraction of the run left out of the memory slope fit (start-up and warm-up).
    #[arg(long, default_value_t = 0.2)]
    pub warmup_fraction: f64,
    /// Write `rss.csv` (t_s, rss_mb) and `summary.json` here.
    #[arg(long, value_name = "DIR")]
    pub report: Option<PathBuf>,
    /// Wait at most this long for the first subscriber of every camera (seconds; 0: don't).
    #[arg(long, default_value_t = 30)]
    pub wait_subscribers: u64,
}

/// One camera's publishers and its frames, ready to send.
struct CameraStream {
    /// The image topic (fully qualified).
    topic: String,
    /// `header.frame_id` of its messages (the camera's optical frame).
    frame_id: String,
    image: Publisher,
    info: ros2_client::Publisher<CameraInfo>,
    info_msg: CameraInfo,
    /// Encoded frames (JPEG bytes or raw RGB), cycled.
    frames: Vec<Vec<u8>>,
}

enum Publisher {
    Jpeg(ros2_client::Publisher<CompressedImage>),
    Rgb8(ros2_client::Publisher<Image>),
}

/// Resident-memory samples of the watched process.
#[derive(Debug, Default, Clone, Serialize)]
pub struct RssReport {
    /// Samples taken.
    pub samples: usize,
    /// First sample, MB.
    pub first_mb: f64,
    /// Largest sample, MB.
    pub max_mb: f64,
    /// Last sample, MB.
    pub last_mb: f64,
    /// Least-squares slope over the samples after the warm-up, MB per minute.
    pub slope_mb_per_min: f64,
    /// Where the fit starts, seconds.
    pub fit_from_s: f64,
    /// Set when the process ended during the run.
    pub exited_at_s: Option<f64>,
}

/// What a run did (printed, and `summary.json`).
#[derive(Debug, Serialize)]
pub struct LoadSummary {
    /// People in the scene (`--people`; one on a camera ring without it).
    pub people: u8,
    /// Cameras.
    pub cameras: u16,
    /// Target rate per camera.
    pub rate_hz: f64,
    /// Frame size.
    pub width: u32,
    /// Frame size.
    pub height: u32,
    /// How frames travelled.
    pub encoding: Encoding,
    /// Mean encoded frame size, bytes.
    pub frame_bytes: usize,
    /// Wall time publishing, seconds.
    pub seconds: f64,
    /// Frames published (all cameras).
    pub published: u64,
    /// Frames not sent because the publisher fell a whole period behind.
    pub late: u64,
    /// Frames whose publish call failed.
    pub failed: u64,
    /// Achieved frames per second (all cameras).
    pub achieved_hz: f64,
    /// UDP datagrams the kernel dropped for full receive buffers during the run (all sockets).
    pub udp_receive_buffer_drops: Option<u64>,
    /// The watched process's memory.
    pub rss: Option<RssReport>,
}

/// Renders the frames, publishes them for `--seconds`, reports.
pub fn run(args: LoadgenArgs) -> Result<()> {
    if !(args.rate > 0.0 && args.rate <= 1000.0) {
        bail!(
            "--rate {}: expected frames per second in (0, 1000]",
            args.rate
        );
    }
    if !(0.0..0.9).contains(&args.warmup_fraction) {
        bail!(
            "--warmup-fraction {}: expected 0..0.9",
            args.warmup_fraction
        );
    }
    let domain = resolve_domain_id(
        args.domain.map_or(-1, i32::from),
        std::env::var("ROS_DOMAIN_ID").ok().as_deref(),
    )?;
    let prefix = args.prefix.trim_end_matches('/');
    if !prefix.starts_with('/') {
        bail!(
            "--prefix `{}`: expected an absolute name such as /loadgen",
            args.prefix
        );
    }
    eprintln!(
        "rendering {} frames × {} cameras at {}×{} ...",
        args.frames, args.cameras, args.width, args.height
    );
    let progress = |done, total| eprint!("\r  frame {done}/{total}");
    let stream = match args.people {
        None => render_stream(
            &StreamOptions {
                seed: args.seed,
                cameras: args.cameras.into(),
                frames: args.frames.into(),
                width: args.width,
                height: args.height,
                points: 30_000,
            },
            progress,
        )
        .context("rendering the synthetic person")?,
        Some(people) => render_crowd_stream(
            &CrowdOptions {
                seed: args.seed,
                people: people.into(),
                cameras: args.cameras.into(),
                frames: args.frames.into(),
                fps: args.rate as f32,
                width: args.width,
                height: args.height,
                ..CrowdOptions::default()
            },
            progress,
        )
        .context("rendering the crowd scene")?,
    };
    eprintln!();
    let encoded: Vec<Vec<Vec<u8>>> = (0..stream.cameras.len())
        .map(|c| {
            stream
                .images
                .iter()
                .map(|frames| encode(&frames[c], args.encoding))
                .collect::<Result<Vec<_>>>()
        })
        .collect::<Result<_>>()?;
    drop(stream.images);
    let frame_bytes = encoded.iter().flatten().map(Vec::len).sum::<usize>()
        / encoded.iter().map(Vec::len).sum::<usize>().max(1);

    let runtime = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(1)
        .enable_all()
        .build()
        .context("tokio runtime")?;
    let context = create_context(&ParticipantOptions {
        domain_id: domain,
        only_networks: vec![IpAddr::from([127, 0, 0, 1])],
        socket_receive_buffer: 0,
    })?;
    let mut node = context
        .new_node(
            NodeName::new("/", "lhmpp_loadgen").context("node name")?,
            NodeOptions::new().enable_rosout(false),
        )
        .context("ROS 2 node lhmpp_loadgen")?;
    let spinner = node.spinner().context("node spinner")?;
    runtime.spawn(async move {
        if let Err(e) = spinner.spin().await {
            tracing::warn!("loadgen spinner stopped: {e:?}");
        }
    });
    let qos = image_input_qos(ImageQos::SensorData);
    let mut cameras = Vec::new();
    for (rig, frames) in stream.cameras.iter().zip(encoded) {
        let base = format!("{prefix}/{}/image_raw", rig.name);
        let (topic, image) = match args.encoding {
            Encoding::Jpeg => {
                let topic = format!("{base}/compressed");
                let p = publisher(&mut node, &topic, &qos)?;
                (topic, Publisher::Jpeg(p))
            }
            Encoding::Rgb8 => (
                base.clone(),
                Publisher::Rgb8(publisher(&mut node, &base, &qos)?),
            ),
        };
        let info_topic = format!("{prefix}/{}/camera_info", rig.name);
        cameras.push(CameraStream {
            topic,
            frame_id: optical_frame(&rig.name),
            image,
            info: publisher(&mut node, &info_topic, &qos)?,
            info_msg: camera_info(rig, 0),
            frames,
        });
    }
    if args.wait_subscribers > 0 {
        wait_for_subscribers(&node, &cameras, Duration::from_secs(args.wait_subscribers))?;
    }

    let stop = Arc::new(AtomicBool::new(false));
    let sampler = args.watch_pid.map(|pid| {
        let stop = stop.clone();
        std::thread::spawn(move || sample_rss(pid, &stop))
    });
    let drops_before = udp_buffers::udp_receive_buffer_errors().ok();
    eprintln!(
        "publishing {} cameras × {} Hz × {}×{} {:?} ({} KB per frame) for {} s on 127.0.0.1, domain {domain}",
        args.cameras,
        args.rate,
        args.width,
        args.height,
        args.encoding,
        frame_bytes / 1024,
        args.seconds
    );
    let counts = publish_for(
        &cameras,
        args.rate,
        Duration::from_secs(args.seconds),
        || {
            args.watch_pid
                .is_some_and(|pid| !Path::new(&format!("/proc/{pid}")).exists())
        },
    );
    stop.store(true, Ordering::SeqCst);
    let samples = sampler
        .map(|s| s.join().expect("memory sampler panicked"))
        .unwrap_or_default();
    let summary = LoadSummary {
        people: args.people.unwrap_or(1),
        cameras: args.cameras,
        rate_hz: args.rate,
        width: args.width,
        height: args.height,
        encoding: args.encoding,
        frame_bytes,
        seconds: counts.wall.as_secs_f64(),
        published: counts.published,
        late: counts.late,
        failed: counts.failed,
        achieved_hz: counts.published as f64 / counts.wall.as_secs_f64().max(1e-9),
        udp_receive_buffer_drops: drops_before.and_then(|before| {
            udp_buffers::udp_receive_buffer_errors()
                .ok()
                .map(|after| after.saturating_sub(before))
        }),
        rss: args
            .watch_pid
            .map(|_| rss_report(&samples, args.warmup_fraction, counts.wall.as_secs_f64())),
    };
    print_summary(&summary, args.watch_pid);
    if let Some(dir) = &args.report {
        write_report(dir, &summary, &samples)?;
        println!("report in {}/", dir.display());
    }
    drop(cameras);
    drop(node);
    runtime.shutdown_timeout(Duration::from_secs(2));
    if let (Some(pid), Some(rss)) = (args.watch_pid, &summary.rss) {
        if let Some(t) = rss.exited_at_s {
            return Err(ExitStatus {
                code: WATCHED_PROCESS_GONE,
                message: format!("watched process {pid} ended {t:.0} s into the run"),
            }
            .into());
        }
    }
    Ok(())
}

fn encode(image: &image::RgbImage, encoding: Encoding) -> Result<Vec<u8>> {
    Ok(match encoding {
        Encoding::Rgb8 => image.as_raw().clone(),
        Encoding::Jpeg => {
            let mut out = Vec::new();
            image::codecs::jpeg::JpegEncoder::new_with_quality(&mut out, 90)
                .encode_image(image)
                .context("JPEG encoding")?;
            out
        }
    })
}

fn publisher<M: RosMessage + 'static>(
    node: &mut ros2_client::Node,
    topic: &str,
    qos: &QosProfile,
) -> Result<ros2_client::Publisher<M>> {
    let name = Name::parse(topic).map_err(|e| anyhow::anyhow!("topic {topic}: {e:?}"))?;
    let t = node
        .create_topic(&name, type_name::<M>(), qos)
        .with_context(|| format!("topic {topic}"))?;
    node.create_publisher::<M>(&t, Some(qos.clone()))
        .with_context(|| format!("publisher on {topic}"))
}

fn wait_for_subscribers(
    node: &ros2_client::Node,
    cameras: &[CameraStream],
    timeout: Duration,
) -> Result<()> {
    let deadline = Instant::now() + timeout;
    loop {
        let waiting = cameras
            .iter()
            .filter(|c| node.subscription_count(&c.topic) == 0)
            .count();
        if waiting == 0 {
            // Discovery precedes matching: give the writers a moment to match the readers.
            std::thread::sleep(Duration::from_millis(500));
            return Ok(());
        }
        if Instant::now() > deadline {
            bail!(
                "{waiting} of {} camera topics have no subscriber after {} s (is the node running \
                 on this domain with these topics? --wait-subscribers 0 publishes anyway)",
                cameras.len(),
                timeout.as_secs()
            );
        }
        std::thread::sleep(Duration::from_millis(50));
    }
}

struct Counts {
    published: u64,
    late: u64,
    failed: u64,
    wall: Duration,
}

/// Publishes every camera's next frame once per period for `duration`; a tick more than one
/// period late is skipped and counted (the generator never bursts to catch up).
fn publish_for(
    cameras: &[CameraStream],
    rate: f64,
    duration: Duration,
    abort: impl Fn() -> bool,
) -> Counts {
    let period = Duration::from_secs_f64(1.0 / rate);
    let start = Instant::now();
    let (mut published, mut late, mut failed) = (0u64, 0u64, 0u64);
    let mut tick = 0u64;
    let mut last_check = start;
    while start.elapsed() < duration {
        let due = start + period.mul_f64(tick as f64);
        let now = Instant::now();
        if now < due {
            std::thread::sleep(due - now);
        } else if now - due > period {
            let behind = ((now - due).as_secs_f64() / period.as_secs_f64()) as u64;
            late += behind * cameras.len() as u64;
            tick += behind;
            continue;
        }
        let stamp = Time::from_nanos(
            SystemTime::now()
                .duration_since(UNIX_EPOCH)
                .map_or(0, |d| d.as_nanos() as i64),
        );
        for cam in cameras {
            let frame = &cam.frames[tick as usize % cam.frames.len()];
            let header = Header {
                stamp,
                frame_id: cam.frame_id.clone(),
            };
            let ok = match &cam.image {
                Publisher::Jpeg(p) => p
                    .publish(CompressedImage {
                        header: header.clone(),
                        format: "jpeg".into(),
                        data: frame.clone(),
                    })
                    .is_ok(),
                Publisher::Rgb8(p) => {
                    let info = &cam.info_msg;
                    p.publish(Image {
                        header: header.clone(),
                        height: info.height,
                        width: info.width,
                        encoding: "rgb8".into(),
                        is_bigendian: 0,
                        step: 3 * info.width,
                        data: frame.clone(),
                    })
                    .is_ok()
                }
            };
            let info = CameraInfo {
                header,
                ..cam.info_msg.clone()
            };
            if ok && cam.info.publish(info).is_ok() {
                published += 1;
            } else {
                failed += 1;
            }
        }
        tick += 1;
        if last_check.elapsed() >= Duration::from_secs(1) {
            last_check = Instant::now();
            if abort() {
                break;
            }
            eprint!(
                "\r  {:>4.0} s  published {published}  late {late}  failed {failed}",
                start.elapsed().as_secs_f64()
            );
        }
    }
    eprintln!();
    Counts {
        published,
        late,
        failed,
        wall: start.elapsed(),
    }
}

/// One resident-memory sample: seconds since the sampler started, MB; `None` MB once the
/// process is gone.
type Sample = (f64, Option<f64>);

/// Samples `/proc/PID/status` VmRSS every second until `stop` (or the process ends).
fn sample_rss(pid: u32, stop: &AtomicBool) -> Vec<Sample> {
    let start = Instant::now();
    let mut samples = Vec::new();
    let mut next = start;
    while !stop.load(Ordering::SeqCst) {
        let rss = read_rss_mb(pid);
        samples.push((start.elapsed().as_secs_f64(), rss));
        if rss.is_none() {
            break;
        }
        next += Duration::from_secs(1);
        while Instant::now() < next && !stop.load(Ordering::SeqCst) {
            std::thread::sleep(Duration::from_millis(50));
        }
    }
    samples
}

/// VmRSS of `pid` in MB (10⁶ bytes), `None` if the process is gone.
pub fn read_rss_mb(pid: u32) -> Option<f64> {
    let status = std::fs::read_to_string(format!("/proc/{pid}/status")).ok()?;
    parse_vm_rss_kb(&status).map(|kb| kb as f64 * 1024.0 / 1e6)
}

fn parse_vm_rss_kb(status: &str) -> Option<u64> {
    let line = status.lines().find(|l| l.starts_with("VmRSS:"))?;
    line.split_whitespace().nth(1)?.parse().ok()
}

/// Maximum, ends and the least-squares slope after `warmup` of `run_s`.
fn rss_report(samples: &[Sample], warmup: f64, run_s: f64) -> RssReport {
    let alive: Vec<(f64, f64)> = samples
        .iter()
        .filter_map(|(t, mb)| mb.map(|mb| (*t, mb)))
        .collect();
    let fit_from_s = warmup * run_s;
    let fit: Vec<(f64, f64)> = alive
        .iter()
        .copied()
        .filter(|(t, _)| *t >= fit_from_s)
        .collect();
    RssReport {
        samples: alive.len(),
        first_mb: alive.first().map_or(0.0, |s| s.1),
        max_mb: alive.iter().map(|s| s.1).fold(0.0, f64::max),
        last_mb: alive.last().map_or(0.0, |s| s.1),
        slope_mb_per_min: 60.0 * least_squares_slope(&fit),
        fit_from_s,
        exited_at_s: samples.iter().find(|(_, mb)| mb.is_none()).map(|s| s.0),
    }
}

/// Slope of the least-squares line through `points` (0 for fewer than two).
fn least_squares_slope(points: &[(f64, f64)]) -> f64 {
    let n = points.len() as f64;
    if points.len() < 2 {
        return 0.0;
    }
    let mx = points.iter().map(|p| p.0).sum::<f64>() / n;
    let my = points.iter().map(|p| p.1).sum::<f64>() / n;
    let sxy: f64 = points.iter().map(|p| (p.0 - mx) * (p.1 - my)).sum();
    let sxx: f64 = points.iter().map(|p| (p.0 - mx).powi(2)).sum();
    if sxx > 0.0 {
        sxy / sxx
    } else {
        0.0
    }
}

fn print_summary(s: &LoadSummary, pid: Option<u32>) {
    println!(
        "published {} frames in {:.1} s ({:.1} Hz of {:.0} asked), late {}, failed {}, {} KB per frame",
        s.published,
        s.seconds,
        s.achieved_hz,
        s.rate_hz * f64::from(s.cameras),
        s.late,
        s.failed,
        s.frame_bytes / 1024
    );
    if let Some(drops) = s.udp_receive_buffer_drops {
        println!("UDP receive-buffer drops during the run (whole machine): {drops}");
    }
    if let (Some(pid), Some(r)) = (pid, &s.rss) {
        println!(
            "process {pid} RSS: first {:.1} MB, max {:.1} MB, last {:.1} MB, slope {:+.2} MB/min \
             after {:.0} s ({} samples)",
            r.first_mb, r.max_mb, r.last_mb, r.slope_mb_per_min, r.fit_from_s, r.samples
        );
    }
}

fn write_report(dir: &Path, summary: &LoadSummary, samples: &[Sample]) -> Result<()> {
    std::fs::create_dir_all(dir).with_context(|| format!("report directory {}", dir.display()))?;
    let csv = dir.join("rss.csv");
    let mut f = std::io::BufWriter::new(
        std::fs::File::create(&csv).with_context(|| format!("{}", csv.display()))?,
    );
    writeln!(f, "t_s,rss_mb")?;
    for (t, mb) in samples {
        if let Some(mb) = mb {
            writeln!(f, "{t:.2},{mb:.2}")?;
        }
    }
    f.flush().with_context(|| format!("{}", csv.display()))?;
    let json = dir.join("summary.json");
    std::fs::write(&json, serde_json::to_string_pretty(summary)?)
        .with_context(|| format!("{}", json.display()))?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn vm_rss_is_read_from_proc_status() {
        let status = "Name:\tlhmpp\nVmPeak:\t 2000 kB\nVmRSS:\t  123456 kB\nThreads:\t4\n";
        assert_eq!(parse_vm_rss_kb(status), Some(123_456));
        assert_eq!(parse_vm_rss_kb("Name:\tx\n"), None);
        let own = read_rss_mb(std::process::id()).expect("this process has an RSS");
        assert!(own > 1.0, "{own} MB");
    }

    #[test]
    fn slope_fits_after_the_warm_up_and_flags_an_exit() {
        // 100 MB rising 1 MB/s for 20 s of warm-up, then flat at 120 MB for 80 s, then gone.
        let mut samples: Vec<Sample> = (0..100)
            .map(|t| (t as f64, Some(100.0 + (t.min(20)) as f64)))
            .collect();
        samples.push((100.0, None));
        let r = rss_report(&samples, 0.2, 100.0);
        assert!(r.slope_mb_per_min.abs() < 1e-9, "{}", r.slope_mb_per_min);
        assert_eq!(r.max_mb, 120.0);
        assert_eq!(r.exited_at_s, Some(100.0));
        let rising = rss_report(&samples, 0.0, 100.0);
        assert!(rising.slope_mb_per_min > 1.0, "{}", rising.slope_mb_per_min);
    }
}
