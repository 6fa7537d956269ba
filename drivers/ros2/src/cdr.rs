//! The CDR envelope of a ROS 2 message: a 4-byte encapsulation header, then the message in plain
//! CDR (OMG CDR / XCDR1, as ROS 2's DDS and Zenoh middlewares put it on the wire), through the
//! `cdr-encoding` serde crate.
//!
//! Header (DDS-RTPS 10.5 "SerializedPayloadHeader"): two bytes of representation identifier,
//! `00 01` little-endian CDR (`CDR_LE`, what every ROS 2 middleware on a little-endian host sends
//! and what [`encode`] writes) or `00 00` big-endian CDR (`CDR_BE`, accepted), then two bytes of
//! options (ignored). Alignment of the body is counted from the first byte after the header.
//!
//! Trailing bytes: a writer may pad the body to a multiple of 4 bytes (XTypes 7.6.3.1.2 keeps
//! the padding count in the options), so up to 3 bytes after the message are accepted; more are
//! refused ([`CdrError::TrailingBytes`]): they mean the payload is of another type or version.

use byteorder::{BigEndian, LittleEndian};
use serde::Serialize;
use serde::de::DeserializeOwned;

/// The names and the type hash that identify a ROS 2 message type on the wire.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct MessageType {
    /// The ROS 2 type name: `tf2_msgs/msg/TFMessage`.
    pub ros_name: &'static str,
    /// The type name as declared in DDS (and in rmw_zenoh's key expressions):
    /// `tf2_msgs::msg::dds_::TFMessage_`.
    pub dds_name: &'static str,
    /// The REP-2016 type hash (`RIHS01_` and 64 hex digits) of the type description, as ROS 2
    /// Jazzy and later compute it (Iron's rosidl; unchanged in Kilted). Humble has none.
    pub rihs01: &'static str,
}

/// A ROS 2 message type of this crate.
pub trait RosMessage: Serialize + DeserializeOwned {
    /// Its names and type hash.
    const TYPE: MessageType;
}

/// Why a payload is not a message of the expected type.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum CdrError {
    /// Fewer bytes than the 4-byte encapsulation header.
    #[error("{type_name}: payload of {len} bytes is shorter than the 4-byte CDR encapsulation header")]
    ShortPayload {
        /// The expected ROS 2 type.
        type_name: &'static str,
        /// Bytes received.
        len: usize,
    },
    /// The representation identifier is not plain CDR.
    #[error(
        "{type_name}: encapsulation header {header:02x?} is not plain CDR (00 01 little-endian or 00 00 big-endian){hint}",
        hint = header_hint(*header)
    )]
    BadHeader {
        /// The expected ROS 2 type.
        type_name: &'static str,
        /// The four header bytes.
        header: [u8; 4],
    },
    /// The body does not decode as the type (too short, a bad boolean, a string that is not
    /// UTF-8, ...).
    #[error("{type_name}: CDR body of {body_len} bytes does not decode: {detail}")]
    Malformed {
        /// The expected ROS 2 type.
        type_name: &'static str,
        /// Bytes after the header.
        body_len: usize,
        /// What the decoder found.
        detail: String,
    },
    /// More than 3 bytes (padding) follow the decoded message.
    #[error("{type_name}: {count} bytes left after the message (at most 3 bytes of padding are allowed)")]
    TrailingBytes {
        /// The expected ROS 2 type.
        type_name: &'static str,
        /// Bytes left over.
        count: usize,
    },
}

fn header_hint(header: [u8; 4]) -> &'static str {
    match [header[0], header[1]] {
        [0x00, 0x02] | [0x00, 0x03] => " (it is parameter-list CDR, PL_CDR)",
        [0x00, 0x06..=0x0b] => " (it is XCDR2, which ROS 2 does not use for messages)",
        _ => "",
    }
}

/// The encapsulation header [`encode`] writes: little-endian CDR, no options.
pub const CDR_LE_HEADER: [u8; 4] = [0x00, 0x01, 0x00, 0x00];

/// Serialises a message: [`CDR_LE_HEADER`], then the little-endian CDR body (no trailing padding).
///
/// Panics only for a sequence longer than `u32::MAX` elements, which CDR cannot carry.
pub fn encode<T: RosMessage>(message: &T) -> Vec<u8> {
    let mut out = Vec::with_capacity(64);
    out.extend_from_slice(&CDR_LE_HEADER);
    // cdr-encoding fails only on a sequence of unknown length (none in these types) and on its
    // writer's I/O (a Vec here); a sequence over u32::MAX elements cannot be put in CDR at all.
    let body = cdr_encoding::to_vec::<T, LittleEndian>(message)
        .unwrap_or_else(|e| panic!("{}: CDR serialisation failed: {e}", T::TYPE.ros_name));
    out.extend_from_slice(&body);
    out
}

/// Deserialises a message of type `T` from a payload with its encapsulation header (see the
/// module docs for what is accepted).
pub fn decode<T: RosMessage>(payload: &[u8]) -> Result<T, CdrError> {
    let type_name = T::TYPE.ros_name;
    let Some((header, body)) = payload.split_first_chunk::<4>() else {
        return Err(CdrError::ShortPayload { type_name, len: payload.len() });
    };
    let decoded = match [header[0], header[1]] {
        [0x00, 0x01] => cdr_encoding::from_bytes::<T, LittleEndian>(body),
        [0x00, 0x00] => cdr_encoding::from_bytes::<T, BigEndian>(body),
        _ => return Err(CdrError::BadHeader { type_name, header: *header }),
    };
    let (message, consumed) = decoded.map_err(|e| CdrError::Malformed {
        type_name,
        body_len: body.len(),
        detail: match e {
            cdr_encoding::Error::Eof => "the payload ends inside the message".to_string(),
            other => other.to_string(),
        },
    })?;
    let count = body.len().saturating_sub(consumed);
    if count > 3 {
        return Err(CdrError::TrailingBytes { type_name, count });
    }
    Ok(message)
}
