//! The attachment rmw_zenoh puts on every message it publishes (`ros2/rmw_zenoh`,
//! `docs/design.md` "Publishers"; `rmw_zenoh_cpp/src/detail/attachment_helpers.cpp`). An rmw_zenoh
//! subscription drops a sample without one, or with one it cannot parse.
//!
//! Layout, as rmw_zenoh writes it since 0.2.4 on Jazzy (April 2025) and 0.1.2 on Humble (June
//! 2025) ("Change serialization format in attachment_helpers.cpp", rmw_zenoh #601, backported as
//! #605 and #606):
//! the Zenoh extension serialisation (`zenoh::ext::Serializer`) of, in order,
//!
//! | bytes | field |
//! | --- | --- |
//! | 8 | sequence number, `int64` little-endian (a publisher's first message is 1) |
//! | 8 | source timestamp, `int64` little-endian, nanoseconds since the UNIX epoch |
//! | 1 | the GID's length as a LEB128 varint: always 16, so the byte `0x10` |
//! | 16 | the publisher's GID |
//!
//! 33 bytes in all. Humble's rmw_zenoh uses a 16-byte GID as well, although Humble's
//! `RMW_GID_STORAGE_SIZE` is 24 (rmw_zenoh #388).
//!
//! Earlier releases (Jazzy 0.2.0 to 0.2.3, Humble 0.1.0 and 0.1.1) wrote each field after its
//! name as a serialised string: `"sequence_number"`, int64, `"source_timestamp"`, int64,
//! `"source_gid"`, then the GID as a length-prefixed byte buffer. [`Attachment::decode`] accepts
//! both; [`Attachment::encode`] writes the current one, which those older releases cannot read
//! (their subscriptions drop our messages: upgrade rmw_zenoh on the robot).

/// Bytes in a publisher GID.
pub const GID_LEN: usize = 16;

/// Bytes of an encoded attachment.
pub const ENCODED_LEN: usize = 8 + 8 + 1 + GID_LEN;

/// The metadata rmw_zenoh attaches to a published message.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Attachment {
    /// Per publisher, from 1, one more per message.
    pub sequence_number: i64,
    /// When the message was published, nanoseconds since the UNIX epoch (system clock).
    pub source_timestamp_ns: i64,
    /// The publisher's GID (see `keys::gid_of_token`).
    pub source_gid: [u8; GID_LEN],
}

/// Why attachment bytes are not an rmw_zenoh attachment.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum AttachmentError {
    /// Neither layout: the length and the bytes fit neither.
    #[error(
        "rmw_zenoh attachment of {len} bytes is neither the {ENCODED_LEN}-byte layout (sequence number, timestamp, 0x10, 16-byte GID) nor the named-field layout{detail}"
    )]
    Unrecognised {
        /// Bytes received.
        len: usize,
        /// What the named-field reading found.
        detail: String,
    },
}

impl Attachment {
    /// The 33 bytes rmw_zenoh writes (see the module docs).
    pub fn encode(&self) -> [u8; ENCODED_LEN] {
        let mut out = [0u8; ENCODED_LEN];
        out[..8].copy_from_slice(&self.sequence_number.to_le_bytes());
        out[8..16].copy_from_slice(&self.source_timestamp_ns.to_le_bytes());
        out[16] = GID_LEN as u8;
        out[17..].copy_from_slice(&self.source_gid);
        out
    }

    /// Reads either layout (see the module docs).
    pub fn decode(bytes: &[u8]) -> Result<Self, AttachmentError> {
        if bytes.len() == ENCODED_LEN && usize::from(bytes[16]) == GID_LEN {
            return Ok(Self {
                sequence_number: read_i64(&bytes[..8]),
                source_timestamp_ns: read_i64(&bytes[8..16]),
                source_gid: gid(&bytes[17..]),
            });
        }
        decode_named(bytes).map_err(|detail| AttachmentError::Unrecognised { len: bytes.len(), detail })
    }
}

fn read_i64(bytes: &[u8]) -> i64 {
    let mut le = [0u8; 8];
    le.copy_from_slice(bytes);
    i64::from_le_bytes(le)
}

fn gid(bytes: &[u8]) -> [u8; GID_LEN] {
    let mut out = [0u8; GID_LEN];
    out.copy_from_slice(bytes);
    out
}

/// A reader of Zenoh's extension serialisation: little-endian integers, LEB128 lengths.
struct Reader<'a> {
    bytes: &'a [u8],
}

impl<'a> Reader<'a> {
    fn take(&mut self, n: usize, what: &str) -> Result<&'a [u8], String> {
        if self.bytes.len() < n {
            return Err(format!(" (it ends inside {what})"));
        }
        let (head, rest) = self.bytes.split_at(n);
        self.bytes = rest;
        Ok(head)
    }

    fn length(&mut self, what: &str) -> Result<usize, String> {
        let mut value = 0usize;
        for shift in (0..35).step_by(7) {
            let byte = self.take(1, what)?[0];
            value |= usize::from(byte & 0x7f) << shift;
            if byte & 0x80 == 0 {
                return Ok(value);
            }
        }
        Err(format!(" (the length of {what} is not a LEB128 number of at most 5 bytes)"))
    }

    fn name(&mut self, expected: &str) -> Result<(), String> {
        let len = self.length(expected)?;
        let found = self.take(len, expected)?;
        if found != expected.as_bytes() {
            return Err(format!(" (expected the name {expected:?}, found {:?})", String::from_utf8_lossy(found)));
        }
        Ok(())
    }
}

fn decode_named(bytes: &[u8]) -> Result<Attachment, String> {
    let mut reader = Reader { bytes };
    reader.name("sequence_number")?;
    let sequence_number = read_i64(reader.take(8, "the sequence number")?);
    reader.name("source_timestamp")?;
    let source_timestamp_ns = read_i64(reader.take(8, "the source timestamp")?);
    reader.name("source_gid")?;
    let len = reader.length("the GID")?;
    if len != GID_LEN {
        return Err(format!(" (its GID has {len} bytes, not {GID_LEN})"));
    }
    let source_gid = gid(reader.take(GID_LEN, "the GID")?);
    if !reader.bytes.is_empty() {
        return Err(format!(" ({} bytes follow the GID)", reader.bytes.len()));
    }
    Ok(Attachment { sequence_number, source_timestamp_ns, source_gid })
}

#[cfg(test)]
mod tests {
    use super::*;

    const SAMPLE: Attachment = Attachment {
        sequence_number: 7,
        source_timestamp_ns: 1_700_000_000_123_456_789,
        source_gid: [1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15, 16],
    };

    #[test]
    fn current_layout_is_33_bytes_and_round_trips() {
        let bytes = SAMPLE.encode();
        assert_eq!(&bytes[..8], &[7, 0, 0, 0, 0, 0, 0, 0]);
        assert_eq!(&bytes[8..16], &1_700_000_000_123_456_789i64.to_le_bytes());
        assert_eq!(bytes[16], 0x10);
        assert_eq!(&bytes[17..], &SAMPLE.source_gid);
        assert_eq!(Attachment::decode(&bytes), Ok(SAMPLE));
    }

    /// The named-field layout, written here by hand from the older `attachment_helpers.cpp`
    /// (`ze_serializer_serialize_str` and `_buf`: LEB128 length, then the bytes).
    #[test]
    fn named_field_layout_is_read() {
        let mut bytes = Vec::new();
        let name = |bytes: &mut Vec<u8>, n: &str| {
            bytes.push(n.len() as u8);
            bytes.extend_from_slice(n.as_bytes());
        };
        name(&mut bytes, "sequence_number");
        bytes.extend_from_slice(&7i64.to_le_bytes());
        name(&mut bytes, "source_timestamp");
        bytes.extend_from_slice(&SAMPLE.source_timestamp_ns.to_le_bytes());
        name(&mut bytes, "source_gid");
        bytes.push(16);
        bytes.extend_from_slice(&SAMPLE.source_gid);
        assert_eq!(Attachment::decode(&bytes), Ok(SAMPLE));
        // Cut short, and with a wrong name: errors that say where.
        let err = Attachment::decode(&bytes[..45]).unwrap_err().to_string();
        assert!(err.contains("45 bytes") && err.contains("ends inside the source timestamp"), "{err}");
        bytes[1] = b'S';
        let err = Attachment::decode(&bytes).unwrap_err().to_string();
        assert!(err.contains("expected the name \"sequence_number\""), "{err}");
    }

    #[test]
    fn other_bytes_are_refused() {
        for bad in [&[][..], &[0u8; 32][..], &[0u8; 34][..]] {
            assert!(Attachment::decode(bad).is_err(), "{bad:?}");
        }
        let mut wrong_gid_len = SAMPLE.encode();
        wrong_gid_len[16] = 24;
        assert!(Attachment::decode(&wrong_gid_len).is_err());
    }
}
