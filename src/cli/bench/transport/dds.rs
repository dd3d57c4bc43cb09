//! DDS under [`TransportBench`]: the same lock-step publish→receive measurement as iceoryx2,
//! over ros2-client 0.12 (RustDDS) on loopback, so `lhmpp bench transport` can compare them.
//!
//! The encoded payload travels as the `data` of a `sensor_msgs/msg/Image` (mono8, one row) on a
//! reliable, keep-last-1 topic. Publisher and subscriber are separate DDS participants in this
//! process, both restricted to 127.0.0.1, so every message goes through RTPS over UDP
//! (fragmented into datagrams, reassembled, deserialised), as it would between two processes.
//! The subscriber's task (on the bench's own tokio runtime) reports one [`Receipt`] per message,
//! read from the payload's own header.

use super::harness::{BenchError, Receipt, TransportBench};
use futures::StreamExt;
use lhmpp::msgs::{Header, Image, RosMessage};
use lhmpp::node::ros::{create_context, ParticipantOptions};
use lhmpp::transport::layout::{read_header, unix_time_ns};
use ros2_client::qos::{History, QosProfile, Reliability, WhenFull};
use ros2_client::{MessageTypeName, Name, NodeName, NodeOptions};
use std::net::IpAddr;
use std::sync::mpsc;
use std::time::{Duration, Instant};

const NAME: &str = "dds";

fn fail(message: impl std::fmt::Display) -> BenchError {
    BenchError::Transport {
        transport: NAME.into(),
        message: message.to_string(),
    }
}

/// Reliable, keep last 1; a full send window blocks the publisher up to 10 s.
fn bench_qos() -> QosProfile {
    QosProfile::subscription_default()
        .history(History::KeepLast { depth: 1 })
        .reliability(Reliability::Reliable {
            when_full: WhenFull::Wait(Duration::from_secs(10)),
        })
}

fn participant(domain_id: u16, receive_buffer: usize) -> ParticipantOptions {
    ParticipantOptions {
        domain_id,
        only_networks: vec![IpAddr::from([127, 0, 0, 1])],
        socket_receive_buffer: receive_buffer,
    }
}

/// `SO_RCVBUF` the bench asks for by default (the kernel caps it at `net.core.rmem_max`).
pub const DEFAULT_RECEIVE_BUFFER: usize = 16 * 1024 * 1024;

fn image_type() -> MessageTypeName {
    MessageTypeName::new("sensor_msgs", "Image")
}

/// ros2-client publisher and subscriber (own participants) on one loopback topic, with their
/// spinners and the subscriber's reading task on a runtime of their own.
pub struct DdsBench {
    publisher: ros2_client::Publisher<Image>,
    receipts: mpsc::Receiver<Result<Receipt, String>>,
    _nodes: [ros2_client::Node; 2],
    runtime: Option<tokio::runtime::Runtime>,
}

impl std::fmt::Debug for DdsBench {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("DdsBench").finish_non_exhaustive()
    }
}

/// A node in its own participant, its spinner running on `runtime`.
fn spinning_node(
    runtime: &tokio::runtime::Runtime,
    domain_id: u16,
    receive_buffer: usize,
    name: &str,
) -> Result<ros2_client::Node, BenchError> {
    let context = create_context(&participant(domain_id, receive_buffer)).map_err(fail)?;
    let mut node = context
        .new_node(
            NodeName::new("/", name).map_err(|e| fail(format!("node {name}: {e:?}")))?,
            NodeOptions::new().enable_rosout(false),
        )
        .map_err(|e| fail(format!("node {name}: {e:?}")))?;
    let spinner = node
        .spinner()
        .map_err(|e| fail(format!("spinner of {name}: {e:?}")))?;
    runtime.spawn(async move {
        if let Err(e) = spinner.spin().await {
            tracing::warn!("bench spinner stopped: {e:?}");
        }
    });
    Ok(node)
}

impl DdsBench {
    /// Creates both ends on topic `/lhmpp_bench/<topic>` in `domain_id`, their UDP sockets
    /// asking for `receive_buffer` bytes of `SO_RCVBUF`, and returns once the publisher has
    /// matched the subscriber (at most 10 s).
    pub fn new(domain_id: u16, topic: &str, receive_buffer: usize) -> Result<Self, BenchError> {
        let runtime = tokio::runtime::Builder::new_multi_thread()
            .worker_threads(2)
            .enable_all()
            .build()
            .map_err(|e| fail(format!("tokio runtime: {e}")))?;
        let name = Name::new("/lhmpp_bench", topic).map_err(|e| fail(format!("{e:?}")))?;
        let mut sub_node = spinning_node(&runtime, domain_id, receive_buffer, "lhmpp_bench_sub")?;
        let t = sub_node
            .create_topic(&name, image_type(), &bench_qos())
            .map_err(|e| fail(format!("topic {topic}: {e}")))?;
        let sub = sub_node
            .create_subscription::<Image>(&t, Some(bench_qos()))
            .map_err(|e| fail(format!("subscription to {topic}: {e}")))?;
        let (tx, receipts) = mpsc::channel();
        runtime.spawn(read_receipts(sub, tx));

        let mut pub_node = spinning_node(&runtime, domain_id, receive_buffer, "lhmpp_bench_pub")?;
        let t = pub_node
            .create_topic(&name, image_type(), &bench_qos())
            .map_err(|e| fail(format!("topic {topic}: {e}")))?;
        let publisher = pub_node
            .create_publisher::<Image>(&t, Some(bench_qos()))
            .map_err(|e| fail(format!("publisher on {topic}: {e}")))?;
        let deadline = Instant::now() + Duration::from_secs(10);
        while publisher.get_subscription_count(&pub_node) == 0 {
            if Instant::now() > deadline {
                return Err(fail(format!("no subscriber matched {topic} within 10 s")));
            }
            std::thread::sleep(Duration::from_millis(20));
        }
        // Matching is symmetric but not simultaneous: give the reader a moment to match too.
        std::thread::sleep(Duration::from_millis(200));
        Ok(Self {
            publisher,
            receipts,
            _nodes: [sub_node, pub_node],
            runtime: Some(runtime),
        })
    }
}

/// Turns every received message into a [`Receipt`] (read from the payload's header).
async fn read_receipts(
    sub: ros2_client::Subscription<Image>,
    tx: mpsc::Sender<Result<Receipt, String>>,
) {
    let stream = sub.async_stream();
    futures::pin_mut!(stream);
    while let Some(item) = stream.next().await {
        let receipt = match item {
            Ok((msg, _)) => {
                let received_ns = unix_time_ns();
                read_header(&msg.data)
                    .map(|h| Receipt {
                        revision: h.revision,
                        sent_ns: h.timestamp_ns,
                        received_ns,
                        len: msg.data.len(),
                    })
                    .map_err(|e| e.to_string())
            }
            Err(e) => Err(format!("read: {e}")),
        };
        if tx.send(receipt).is_err() {
            break;
        }
    }
}

impl TransportBench for DdsBench {
    fn name(&self) -> &str {
        NAME
    }

    fn publish(&mut self, payload: &[u8]) -> Result<(), BenchError> {
        let msg = Image {
            header: Header::default(),
            height: 1,
            width: payload.len() as u32,
            encoding: "mono8".into(),
            is_bigendian: 0,
            step: payload.len() as u32,
            data: payload.to_vec(),
        };
        self.publisher
            .publish(msg)
            .map_err(|e| fail(format!("publish {}: {e:?}", Image::TYPE_NAME)))
    }

    fn receive(&mut self, timeout: Duration) -> Result<Option<Receipt>, BenchError> {
        match self.receipts.recv_timeout(timeout) {
            Ok(Ok(receipt)) => Ok(Some(receipt)),
            Ok(Err(message)) => Err(fail(message)),
            Err(mpsc::RecvTimeoutError::Timeout) => Ok(None),
            Err(mpsc::RecvTimeoutError::Disconnected) => Err(fail("subscriber thread ended")),
        }
    }
}

impl Drop for DdsBench {
    fn drop(&mut self) {
        for node in &self._nodes {
            node.stop_spinner();
        }
        if let Some(runtime) = self.runtime.take() {
            runtime.shutdown_timeout(Duration::from_secs(1));
        }
    }
}

#[cfg(test)]
mod tests {
    use super::super::harness::{run_case, BenchCase};
    use super::*;

    #[test]
    fn dds_bench_delivers_every_revision_in_lock_step() {
        let domain = 221 + (std::process::id() % 12) as u16;
        let mut bench = DdsBench::new(domain, "unit", DEFAULT_RECEIVE_BUFFER).unwrap();
        let mut case = BenchCase::frame(64, 32, 4);
        let row = run_case(&mut bench, &mut case, 20, 2).unwrap();
        assert_eq!(row.transport, "dds");
        assert_eq!(row.samples, 20);
        assert!(row.p50_us > 0.0 && row.p50_us <= row.p99_us);
    }
}
