//! Linux UDP receive-buffer facts for the DDS benchmark and the load generator: the kernel's cap on `SO_RCVBUF`
//! (`net.core.rmem_max`), the count of datagrams dropped because a socket buffer was full
//! (`RcvbufErrors` in `/proc/net/snmp`), and a guard that raises the cap for one run and
//! restores it afterwards.
//!
//! Why it matters: RustDDS sends a large sample as one burst of 64 KB datagrams; whatever does
//! not fit the reader's socket buffer is dropped by the kernel and must be repaired fragment
//! by fragment, which for a 12.8 MB avatar takes longer than any useful timeout.

use std::path::{Path, PathBuf};

/// Where the kernel's `SO_RCVBUF` cap lives.
pub const RMEM_MAX_PATH: &str = "/proc/sys/net/core/rmem_max";
/// Where the kernel's UDP counters live.
pub const SNMP_PATH: &str = "/proc/net/snmp";

/// Reading or changing a kernel setting failed; names the file.
#[derive(Debug, thiserror::Error)]
pub enum UdpBufferError {
    /// The file could not be read or written (writing needs root).
    #[error("{path}: {message}")]
    Io {
        /// The /proc file.
        path: PathBuf,
        /// What failed.
        message: String,
    },
    /// The file's content was not what Linux writes there.
    #[error("{path}: cannot parse {what}")]
    Parse {
        /// The /proc file.
        path: PathBuf,
        /// What was looked for.
        what: &'static str,
    },
}

fn read(path: &Path) -> Result<String, UdpBufferError> {
    std::fs::read_to_string(path).map_err(|e| UdpBufferError::Io {
        path: path.to_path_buf(),
        message: e.to_string(),
    })
}

/// The current `net.core.rmem_max` in bytes.
pub fn rmem_max() -> Result<usize, UdpBufferError> {
    let path = Path::new(RMEM_MAX_PATH);
    read(path)?
        .trim()
        .parse()
        .map_err(|_| UdpBufferError::Parse {
            path: path.to_path_buf(),
            what: "a byte count",
        })
}

/// UDP datagrams the kernel dropped so far because a receive buffer was full.
pub fn udp_receive_buffer_errors() -> Result<u64, UdpBufferError> {
    let path = Path::new(SNMP_PATH);
    parse_rcvbuf_errors(&read(path)?).ok_or(UdpBufferError::Parse {
        path: path.to_path_buf(),
        what: "Udp RcvbufErrors",
    })
}

/// `RcvbufErrors` from the two `Udp:` lines (names, then values) of `/proc/net/snmp`.
fn parse_rcvbuf_errors(snmp: &str) -> Option<u64> {
    let mut udp = snmp.lines().filter(|l| l.starts_with("Udp:"));
    let names = udp.next()?;
    let values = udp.next()?;
    let column = names
        .split_whitespace()
        .position(|name| name == "RcvbufErrors")?;
    values.split_whitespace().nth(column)?.parse().ok()
}

/// The receive buffer a socket gets when it asks for `requested` bytes: Linux caps the
/// request at `rmem_max` and doubles it for bookkeeping.
pub fn effective_receive_buffer(requested: usize, rmem_max: usize) -> usize {
    2 * requested.min(rmem_max)
}

/// Holds `net.core.rmem_max` raised; the previous value is written back on drop.
#[derive(Debug)]
pub struct RmemMaxRaised {
    previous: usize,
}

impl RmemMaxRaised {
    /// Raises `net.core.rmem_max` to `bytes` if it is lower (needs root); `None` when it
    /// already allows that much.
    pub fn to_at_least(bytes: usize) -> Result<Option<Self>, UdpBufferError> {
        let previous = rmem_max()?;
        if previous >= bytes {
            return Ok(None);
        }
        write_rmem_max(bytes)?;
        tracing::info!(
            previous,
            now = bytes,
            "raised net.core.rmem_max for this run"
        );
        Ok(Some(Self { previous }))
    }

    /// The value restored on drop.
    pub fn previous(&self) -> usize {
        self.previous
    }
}

impl Drop for RmemMaxRaised {
    fn drop(&mut self) {
        match write_rmem_max(self.previous) {
            Ok(()) => tracing::info!(restored = self.previous, "net.core.rmem_max restored"),
            Err(e) => tracing::error!("restoring net.core.rmem_max: {e}"),
        }
    }
}

fn write_rmem_max(bytes: usize) -> Result<(), UdpBufferError> {
    std::fs::write(RMEM_MAX_PATH, bytes.to_string()).map_err(|e| UdpBufferError::Io {
        path: PathBuf::from(RMEM_MAX_PATH),
        message: e.to_string(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    const SNMP: &str = "Ip: Forwarding DefaultTTL\nIp: 1 64\n\
        Udp: InDatagrams NoPorts InErrors OutDatagrams RcvbufErrors SndbufErrors\n\
        Udp: 1339333 16393 303 1356095 299 0\n\
        UdpLite: InDatagrams NoPorts InErrors OutDatagrams RcvbufErrors SndbufErrors\n\
        UdpLite: 0 0 0 0 7 0\n";

    #[test]
    fn rcvbuf_errors_are_read_from_the_udp_value_line() {
        assert_eq!(parse_rcvbuf_errors(SNMP), Some(299));
        assert_eq!(parse_rcvbuf_errors("Ip: a\nIp: 1\n"), None);
    }

    #[test]
    fn receive_buffer_is_capped_by_rmem_max_then_doubled() {
        assert_eq!(effective_receive_buffer(16 << 20, 4 << 20), 8 << 20);
        assert_eq!(effective_receive_buffer(1 << 20, 4 << 20), 2 << 20);
    }

    #[test]
    fn kernel_counters_are_readable_here() {
        // Linux only (the transport is Linux only): both files exist for any process.
        assert!(rmem_max().unwrap() > 0);
        udp_receive_buffer_errors().unwrap();
    }
}
