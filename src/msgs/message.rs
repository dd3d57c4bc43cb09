//! The [`RosMessage`] trait: type names, definitions and CDR encoding shared by every message.

use super::{registry, MsgError};
use byteorder::{BigEndian, LittleEndian};
use serde::de::DeserializeOwned;
use serde::Serialize;

/// CDR encapsulation header for little-endian plain CDR, as ROS 2 writes it before every body.
pub const CDR_LE_HEADER: [u8; 4] = [0x00, 0x01, 0x00, 0x00];

/// A ROS 2 message type with its `.msg` definition and CDR wire format.
pub trait RosMessage: Serialize + DeserializeOwned {
    /// Full ROS 2 type name, e.g. `sensor_msgs/msg/Image`.
    const TYPE_NAME: &'static str;
    /// The `.msg` definition text of this type alone (no dependencies).
    const DEFINITION: &'static str;

    /// DDS type name, e.g. `sensor_msgs::msg::dds_::Image_`.
    fn dds_type_name() -> String {
        dds_type_name(Self::TYPE_NAME)
    }

    /// The `.msg` definition text of this type.
    fn definition() -> &'static str {
        Self::DEFINITION
    }

    /// Full names of every type this one uses, transitively, in first-use order.
    fn dependencies() -> Vec<&'static str> {
        registry::dependencies_of(Self::TYPE_NAME)
            .expect("every built-in message's definition resolves (checked by tests)")
    }

    /// CDR encoding: the little-endian encapsulation header `00 01 00 00`, then the body.
    ///
    /// # Panics
    /// Only if a sequence or string is longer than `u32::MAX`, which CDR cannot express.
    fn encode_cdr(&self) -> Vec<u8> {
        let mut out = CDR_LE_HEADER.to_vec();
        cdr_encoding::to_writer::<Self, LittleEndian, _>(&mut out, self)
            .expect("CDR encoding of an in-memory message cannot fail below u32::MAX lengths");
        out
    }

    /// Decodes a CDR buffer with its encapsulation header (little or big endian). Truncated or
    /// malformed input is an error, never a panic.
    fn decode_cdr(bytes: &[u8]) -> Result<Self, MsgError> {
        let type_name = Self::TYPE_NAME;
        if bytes.len() < 4 {
            return Err(MsgError::TooShort {
                type_name,
                len: bytes.len(),
            });
        }
        let body = &bytes[4..];
        let decoded = match (bytes[0], bytes[1]) {
            (0x00, 0x01) => cdr_encoding::from_bytes::<Self, LittleEndian>(body),
            (0x00, 0x00) => cdr_encoding::from_bytes::<Self, BigEndian>(body),
            (a, b) => {
                return Err(MsgError::Encapsulation {
                    type_name,
                    found: [a, b],
                })
            }
        };
        let (value, consumed) = decoded.map_err(|source| MsgError::Cdr { type_name, source })?;
        let count = body.len() - consumed;
        if count > 3 {
            return Err(MsgError::TrailingBytes { type_name, count });
        }
        Ok(value)
    }
}

/// DDS type name of a ROS 2 type name: `pkg/msg/Type` becomes `pkg::msg::dds_::Type_`.
pub fn dds_type_name(type_name: &str) -> String {
    match type_name.rsplit_once('/') {
        Some((namespace, name)) => format!("{}::dds_::{name}_", namespace.replace('/', "::")),
        None => format!("{type_name}_"),
    }
}

/// Implements [`RosMessage`] for a type from its package, name and embedded definition.
macro_rules! ros_message {
    ($ty:ty, $package:literal, $name:literal, $definition:expr) => {
        impl $crate::msgs::RosMessage for $ty {
            const TYPE_NAME: &'static str = concat!($package, "/msg/", $name);
            const DEFINITION: &'static str = $definition;
        }
    };
}
pub(crate) use ros_message;

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn dds_name_follows_rosidl_mangling() {
        assert_eq!(
            dds_type_name("sensor_msgs/msg/Image"),
            "sensor_msgs::msg::dds_::Image_"
        );
    }
}
