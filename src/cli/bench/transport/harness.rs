//! Publish→receive benchmark of a transport: latency from the header timestamp to receipt
//! (p50/p99) and throughput, printed as one table row per transport and payload.
//!
//! Transports implement [`TransportBench`] over the encoded `lhmpp::transport::layout` bytes, so
//! a second transport (DDS) adds rows to the same table. The harness runs lock-step: stamp the
//! payload, publish, wait for its receipt, repeat. Latency therefore includes writing the
//! payload into the transport (one copy into shared memory for iceoryx2) and waking the
//! receiver, and throughput is that of one message in flight.

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc;
use std::sync::Arc;
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use lhmpp::transport::layout::{
    read_header, unix_time_ns, AvatarView, Encoder, FrameView, PayloadBody, PayloadKind, PersonId,
    Stamp, REVISION_OFFSET, TIMESTAMP_OFFSET,
};
use lhmpp::transport::{ShmError, ShmNode, ShmOptions, ShmPublisher};

/// Errors of a benchmark run; each names the transport.
#[derive(Debug, thiserror::Error)]
pub enum BenchError {
    /// The transport failed.
    #[error("{transport}: {message}")]
    Transport {
        /// Transport name.
        transport: String,
        /// What failed.
        message: String,
    },
    /// Nothing arrived within the timeout.
    #[error("{transport}: payload {case} revision {revision} not received within {timeout:?}")]
    Timeout {
        /// Transport name.
        transport: String,
        /// Payload label.
        case: String,
        /// Revision that was waited for.
        revision: u64,
        /// How long the harness waited.
        timeout: Duration,
    },
}

/// What the receiving side saw of one payload.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Receipt {
    /// Revision from the header.
    pub revision: u64,
    /// Header timestamp (set just before publishing), ns since the Unix epoch.
    pub sent_ns: u64,
    /// Time the receiver held the payload, ns since the Unix epoch.
    pub received_ns: u64,
    /// Payload bytes received.
    pub len: usize,
}

/// A transport under test. `publish` sends one encoded payload; `receive` returns the receipt
/// of the next payload that arrived at the subscriber (which runs in another thread or
/// process), or `None` after `timeout`.
pub trait TransportBench {
    /// Row label (`iceoryx2`, `dds`).
    fn name(&self) -> &str;
    /// Sends one encoded payload.
    fn publish(&mut self, payload: &[u8]) -> Result<(), BenchError>;
    /// Next receipt, or `None` if nothing arrived within `timeout`.
    fn receive(&mut self, timeout: Duration) -> Result<Option<Receipt>, BenchError>;
}

/// One payload to send repeatedly.
#[derive(Debug, Clone)]
pub struct BenchCase {
    /// Row label, e.g. `avatar 160000 G`.
    pub label: String,
    /// Kind of payload.
    pub kind: PayloadKind,
    /// Encoded payload; revision and timestamp are rewritten before every send.
    pub payload: Vec<u8>,
}

fn pattern_f32(n: usize, seed: u32) -> Vec<f32> {
    (0..n as u32)
        .map(|i| (i.wrapping_mul(2_654_435_761) ^ seed) as f32 * 1e-9)
        .collect()
}

impl BenchCase {
    /// A synthetic avatar of `gaussians` Gaussians with RGB colours and skinning.
    pub fn avatar(gaussians: usize) -> Self {
        let positions: Vec<[f32; 3]> = bytemuck::cast_vec(pattern_f32(gaussians * 3, 1));
        let scales: Vec<[f32; 3]> = bytemuck::cast_vec(pattern_f32(gaussians * 3, 2));
        let rotations: Vec<[f32; 4]> = bytemuck::cast_vec(pattern_f32(gaussians * 4, 3));
        let opacities = pattern_f32(gaussians, 4);
        let colours = pattern_f32(gaussians * 3, 5);
        let bones: Vec<[u16; 4]> = (0..gaussians).map(|i| [(i % 55) as u16, 1, 2, 3]).collect();
        let weights: Vec<[f32; 4]> = bytemuck::cast_vec(pattern_f32(gaussians * 4, 6));
        let view = AvatarView {
            positions: &positions,
            scales: &scales,
            rotations: &rotations,
            opacities: &opacities,
            sh_coeffs: 1,
            colours: &colours,
            bones: &bones,
            weights: &weights,
            rgb_latent: false,
        };
        Self::encode(format!("avatar {gaussians} G"), PayloadBody::Avatar(view))
    }

    /// A synthetic frame of `width`×`height` pixels with `channels` (3 or 4) bytes each.
    pub fn frame(width: u32, height: u32, channels: u32) -> Self {
        let pixels: Vec<u8> = (0..(width * height * channels) as usize)
            .map(|i| (i * 31 % 251) as u8)
            .collect();
        let view = FrameView {
            width,
            height,
            channels,
            pixels: &pixels,
            alpha: None,
            depth: None,
        };
        let format = if channels == 4 { "rgba8" } else { "rgb8" };
        Self::encode(
            format!("frame {width}x{height} {format}"),
            PayloadBody::Frame(view),
        )
    }

    fn encode(label: String, body: PayloadBody<'_>) -> Self {
        let person = PersonId::new("bench").expect("valid id");
        let payload = Encoder::new(&person, Stamp::now(0), &body)
            .expect("consistent synthetic payload")
            .to_vec();
        Self {
            label,
            kind: body.kind(),
            payload,
        }
    }

    fn stamp(&mut self, revision: u64) {
        self.payload[REVISION_OFFSET..REVISION_OFFSET + 8].copy_from_slice(&revision.to_le_bytes());
        let now = unix_time_ns();
        self.payload[TIMESTAMP_OFFSET..TIMESTAMP_OFFSET + 8].copy_from_slice(&now.to_le_bytes());
    }
}

/// Measured figures of one transport and payload.
#[derive(Debug, Clone, PartialEq)]
pub struct BenchRow {
    /// Transport name.
    pub transport: String,
    /// Payload label.
    pub case: String,
    /// Payload bytes.
    pub bytes: usize,
    /// Payloads measured.
    pub samples: usize,
    /// Median latency in microseconds.
    pub p50_us: f64,
    /// 99th-percentile latency in microseconds.
    pub p99_us: f64,
    /// Payloads per second (one in flight).
    pub msgs_per_s: f64,
    /// Payload megabytes (10^6) per second.
    pub mb_per_s: f64,
    /// UDP datagrams the kernel dropped for full receive buffers during the run (DDS rows;
    /// `None` where not measured).
    pub udp_drops: Option<u64>,
}

/// The `q` quantile (0..=1) of sorted values, nearest rank.
pub fn quantile(sorted: &[f64], q: f64) -> f64 {
    if sorted.is_empty() {
        return f64::NAN;
    }
    let rank = (q * sorted.len() as f64).ceil() as usize;
    sorted[rank.clamp(1, sorted.len()) - 1]
}

/// Sends `case` `warmup + iterations` times in lock-step and measures the last `iterations`.
pub fn run_case(
    transport: &mut dyn TransportBench,
    case: &mut BenchCase,
    iterations: usize,
    warmup: usize,
) -> Result<BenchRow, BenchError> {
    let timeout = Duration::from_secs(10);
    let mut latencies = Vec::with_capacity(iterations);
    let mut started = Instant::now();
    for i in 0..warmup + iterations {
        if i == warmup {
            started = Instant::now();
        }
        let revision = i as u64 + 1;
        case.stamp(revision);
        transport.publish(&case.payload)?;
        let receipt = loop {
            match transport.receive(timeout)? {
                Some(r) if r.revision == revision => break r,
                Some(_) => continue, // a late copy of an earlier revision
                None => {
                    return Err(BenchError::Timeout {
                        transport: transport.name().to_owned(),
                        case: case.label.clone(),
                        revision,
                        timeout,
                    })
                }
            }
        };
        if i >= warmup {
            latencies.push(receipt.received_ns.saturating_sub(receipt.sent_ns) as f64 / 1e3);
        }
    }
    let elapsed = started.elapsed().as_secs_f64();
    latencies.sort_by(f64::total_cmp);
    let msgs_per_s = iterations as f64 / elapsed;
    Ok(BenchRow {
        transport: transport.name().to_owned(),
        case: case.label.clone(),
        bytes: case.payload.len(),
        samples: iterations,
        p50_us: quantile(&latencies, 0.5),
        p99_us: quantile(&latencies, 0.99),
        msgs_per_s,
        mb_per_s: msgs_per_s * case.payload.len() as f64 / 1e6,
        udp_drops: None,
    })
}

/// Formats rows as a fixed-width text table.
pub fn render_table(rows: &[BenchRow]) -> String {
    let mut out = format!(
        "{:<14} {:<24} {:>12} {:>6} {:>10} {:>10} {:>9} {:>9} {:>9}\n",
        "transport", "payload", "bytes", "n", "p50 µs", "p99 µs", "msg/s", "MB/s", "UDP drops"
    );
    for r in rows {
        let drops = r.udp_drops.map_or("-".to_owned(), |d| d.to_string());
        out.push_str(&format!(
            "{:<14} {:<24} {:>12} {:>6} {:>10.1} {:>10.1} {:>9.1} {:>9.1} {:>9}\n",
            r.transport,
            r.case,
            r.bytes,
            r.samples,
            r.p50_us,
            r.p99_us,
            r.msgs_per_s,
            r.mb_per_s,
            drops
        ));
    }
    out
}

/// How the iceoryx2 bench puts a payload into shared memory.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ShmWrite {
    /// `publish_encoded`: stamped in the producer's buffer, then copied into a loaned sample,
    /// so latency includes that copy (row `iceoryx2`).
    Copy,
    /// `loan_bytes`: the producer writes the payload into the loaned sample (as the node
    /// writes frames), stamps it there and sends it, so latency is send → receive alone (row
    /// `iceoryx2 loan`).
    Loan,
}

/// iceoryx2 under [`TransportBench`]: a publisher in the calling thread and a subscriber in a
/// second thread (own node), which stamps each sample's arrival and reports it on a channel.
#[derive(Debug)]
pub struct Iceoryx2Bench {
    write: ShmWrite,
    publisher: ShmPublisher,
    receipts: mpsc::Receiver<Result<Receipt, String>>,
    stop: Arc<AtomicBool>,
    thread: Option<JoinHandle<()>>,
    _node: ShmNode,
}

impl Iceoryx2Bench {
    /// Opens `person`'s stream of `kind` (camera `bench` for frames) with `options`, and starts
    /// the subscriber thread; returns once the subscriber is connected.
    pub fn new(
        person: &str,
        kind: PayloadKind,
        options: ShmOptions,
        write: ShmWrite,
    ) -> Result<Self, BenchError> {
        let fail = |e: ShmError| BenchError::Transport {
            transport: "iceoryx2".into(),
            message: e.to_string(),
        };
        let stop = Arc::new(AtomicBool::new(false));
        let (tx, receipts) = mpsc::channel();
        let (ready_tx, ready_rx) = mpsc::channel();
        let thread = {
            let (person, options, stop) = (person.to_owned(), options.clone(), stop.clone());
            std::thread::spawn(move || {
                subscriber_loop(&person, kind, options, &stop, &tx, &ready_tx)
            })
        };
        match ready_rx.recv() {
            Ok(Ok(())) => {}
            Ok(Err(message)) => {
                return Err(BenchError::Transport {
                    transport: "iceoryx2".into(),
                    message,
                })
            }
            Err(_) => {
                return Err(BenchError::Transport {
                    transport: "iceoryx2".into(),
                    message: "subscriber thread ended before it was ready".into(),
                })
            }
        }
        let node = ShmNode::new(&format!("{person}-bench-pub"), options).map_err(fail)?;
        let publisher = match kind {
            PayloadKind::Avatar => node.avatar_publisher(person),
            PayloadKind::Frame => node.frame_publisher(person, "bench"),
        }
        .map_err(fail)?;
        Ok(Self {
            write,
            publisher,
            receipts,
            stop,
            thread: Some(thread),
            _node: node,
        })
    }
}

fn subscriber_loop(
    person: &str,
    kind: PayloadKind,
    options: ShmOptions,
    stop: &AtomicBool,
    tx: &mpsc::Sender<Result<Receipt, String>>,
    ready: &mpsc::Sender<Result<(), String>>,
) {
    let cameras: &[&str] = if kind == PayloadKind::Frame {
        &["bench"]
    } else {
        &[]
    };
    let opened = ShmNode::new(&format!("{person}-bench-sub"), options)
        .and_then(|node| node.subscriber(person, cameras).map(|sub| (node, sub)));
    let (_node, mut subscriber) = match opened {
        Ok(v) => {
            let _ = ready.send(Ok(()));
            v
        }
        Err(e) => {
            let _ = ready.send(Err(e.to_string()));
            return;
        }
    };
    while !stop.load(Ordering::Relaxed) {
        loop {
            match subscriber.try_receive() {
                Ok(Some(sample)) => {
                    let received_ns = unix_time_ns();
                    let receipt = read_header(sample.bytes())
                        .map(|h| Receipt {
                            revision: h.revision,
                            sent_ns: h.timestamp_ns,
                            received_ns,
                            len: sample.bytes().len(),
                        })
                        .map_err(|e| e.to_string());
                    if tx.send(receipt).is_err() {
                        return;
                    }
                }
                Ok(None) => break,
                Err(e) => {
                    let _ = tx.send(Err(e.to_string()));
                    return;
                }
            }
        }
        // The timeout only bounds how long shutdown takes; samples wake the wait at once.
        if let Err(e) = subscriber.wait(Duration::from_millis(200)) {
            let _ = tx.send(Err(e.to_string()));
            return;
        }
    }
}

impl TransportBench for Iceoryx2Bench {
    fn name(&self) -> &str {
        match self.write {
            ShmWrite::Copy => "iceoryx2",
            ShmWrite::Loan => "iceoryx2 loan",
        }
    }

    fn publish(&mut self, payload: &[u8]) -> Result<(), BenchError> {
        let sent = match self.write {
            ShmWrite::Copy => self.publisher.publish_encoded(payload),
            ShmWrite::Loan => self
                .publisher
                .loan_bytes(payload.len())
                .and_then(|mut loan| {
                    let bytes = loan.bytes_mut();
                    bytes.copy_from_slice(payload);
                    bytes[TIMESTAMP_OFFSET..TIMESTAMP_OFFSET + 8]
                        .copy_from_slice(&unix_time_ns().to_le_bytes());
                    loan.send()
                }),
        };
        sent.map(drop).map_err(|e| BenchError::Transport {
            transport: self.name().to_owned(),
            message: e.to_string(),
        })
    }

    fn receive(&mut self, timeout: Duration) -> Result<Option<Receipt>, BenchError> {
        match self.receipts.recv_timeout(timeout) {
            Ok(Ok(receipt)) => Ok(Some(receipt)),
            Ok(Err(message)) => Err(BenchError::Transport {
                transport: "iceoryx2".into(),
                message,
            }),
            Err(mpsc::RecvTimeoutError::Timeout) => Ok(None),
            Err(mpsc::RecvTimeoutError::Disconnected) => Err(BenchError::Transport {
                transport: "iceoryx2".into(),
                message: "subscriber thread ended".into(),
            }),
        }
    }
}

impl Drop for Iceoryx2Bench {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        if let Some(thread) = self.thread.take() {
            let _ = thread.join();
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn quantile_uses_nearest_rank() {
        let v: Vec<f64> = (1..=100).map(f64::from).collect();
        assert_eq!(quantile(&v, 0.5), 50.0);
        assert_eq!(quantile(&v, 0.99), 99.0);
        assert_eq!(quantile(&v[..1], 0.99), 1.0);
    }

    #[test]
    fn stamping_rewrites_revision_and_time_in_the_header() {
        let mut case = BenchCase::frame(4, 2, 3);
        case.stamp(77);
        let h = read_header(&case.payload).unwrap();
        assert_eq!(h.revision, 77);
        assert!(h.timestamp_ns > 0);
    }

    #[test]
    fn iceoryx2_bench_delivers_every_revision_in_lock_step() {
        let person = format!("benchtest{}", std::process::id());
        for write in [ShmWrite::Copy, ShmWrite::Loan] {
            let options = ShmOptions::default();
            let mut bench =
                Iceoryx2Bench::new(&person, PayloadKind::Frame, options, write).unwrap();
            let mut case = BenchCase::frame(64, 32, 4);
            let row = run_case(&mut bench, &mut case, 20, 2).unwrap();
            assert_eq!(row.samples, 20);
            assert!(row.p50_us > 0.0 && row.p50_us <= row.p99_us);
            assert!(render_table(&[row]).contains("frame 64x32 rgba8"));
        }
    }
}
