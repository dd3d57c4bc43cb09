//! The error type of the message module: CDR decoding, `.msg` parsing, type look-ups and
//! Gaussian point-cloud layouts.

/// Why a message could not be decoded, parsed, looked up or converted; names the type or field.
#[derive(Debug, thiserror::Error)]
pub enum MsgError {
    /// The buffer is shorter than the 4-byte CDR encapsulation header.
    #[error("{type_name}: buffer of {len} bytes is too short for a CDR encapsulation header")]
    TooShort {
        /// ROS 2 type being decoded.
        type_name: &'static str,
        /// Length of the buffer.
        len: usize,
    },
    /// The encapsulation header is not plain CDR (big or little endian).
    #[error("{type_name}: unsupported CDR encapsulation {found:02X?} (expected 00 00 or 00 01)")]
    Encapsulation {
        /// ROS 2 type being decoded.
        type_name: &'static str,
        /// The first two bytes found.
        found: [u8; 2],
    },
    /// The CDR body is truncated or malformed.
    #[error("{type_name}: malformed CDR body: {source}")]
    Cdr {
        /// ROS 2 type being decoded or encoded.
        type_name: &'static str,
        /// The decoder's error.
        source: cdr_encoding::Error,
    },
    /// More bytes follow the message than CDR padding allows.
    #[error(
        "{type_name}: {count} unexpected bytes after the message (at most 3 bytes of padding)"
    )]
    TrailingBytes {
        /// ROS 2 type being decoded.
        type_name: &'static str,
        /// Bytes left over.
        count: usize,
    },
    /// A `.msg` definition does not parse.
    #[error("message definition, line {line}: {message}")]
    Definition {
        /// 1-based line number in the definition text.
        line: usize,
        /// What is wrong.
        message: String,
    },
    /// A type name is not among the definitions this crate knows.
    #[error("unknown message type `{0}` (known: builtin_interfaces, std_msgs, sensor_msgs, geometry_msgs, tf2_msgs, lhmpp_msgs types listed in msgs::registry)")]
    UnknownType(String),
    /// A message's parts do not agree (a point cloud lacks a field or has the wrong size, lists
    /// of different lengths that must match).
    #[error("inconsistent message: {0}")]
    Inconsistent(String),
}
