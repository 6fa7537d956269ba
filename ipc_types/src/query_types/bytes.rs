//! The query request and response as bytes, for transports that carry bytes rather than typed
//! samples (Zenoh: `<prefix>/query`). The bytes are exactly the `#[repr(C)]` layouts iceoryx2
//! carries, little-endian, so one decoder serves both transports; written and read field by
//! field (the layouts have no padding: every gap is a `reserved` field).

use super::{QUERY_MAX_K, QueryHit, QueryRequest, QueryResponse};

/// Bytes of a [`QueryRequest`].
pub const QUERY_REQUEST_BYTES: usize = 272;
/// Bytes of a [`QueryHit`].
pub const QUERY_HIT_BYTES: usize = 192;
/// Bytes of a [`QueryResponse`].
pub const QUERY_RESPONSE_BYTES: usize = 224 + QUERY_MAX_K * QUERY_HIT_BYTES;

struct Reader<'a>(&'a [u8]);

impl Reader<'_> {
    fn take<const N: usize>(&mut self) -> [u8; N] {
        let (head, rest) = self.0.split_at(N);
        self.0 = rest;
        head.try_into().unwrap_or([0; N])
    }
    fn u32(&mut self) -> u32 {
        u32::from_le_bytes(self.take())
    }
    fn u64(&mut self) -> u64 {
        u64::from_le_bytes(self.take())
    }
    fn f32(&mut self) -> f32 {
        f32::from_le_bytes(self.take())
    }
    fn u8(&mut self) -> u8 {
        self.take::<1>()[0]
    }
}

impl QueryRequest {
    /// The request's bytes (the iceoryx2 layout, [`QUERY_REQUEST_BYTES`]).
    pub fn to_bytes(&self) -> Vec<u8> {
        let mut out = Vec::with_capacity(QUERY_REQUEST_BYTES);
        out.extend_from_slice(&self.schema_version.to_le_bytes());
        out.extend_from_slice(&self.k.to_le_bytes());
        out.extend_from_slice(&self.text);
        out.extend_from_slice(&self.node_id.to_le_bytes());
        out.extend_from_slice(&self.reserved.to_le_bytes());
        out
    }

    /// A request from its bytes; `None` unless exactly [`QUERY_REQUEST_BYTES`] long.
    pub fn from_bytes(bytes: &[u8]) -> Option<Self> {
        if bytes.len() != QUERY_REQUEST_BYTES {
            return None;
        }
        let mut r = Reader(bytes);
        Some(Self { schema_version: r.u32(), k: r.u32(), text: r.take(), node_id: r.u32(), reserved: r.u32() })
    }
}

impl QueryHit {
    fn append_to(&self, out: &mut Vec<u8>) {
        out.extend_from_slice(&self.node_id.to_le_bytes());
        out.extend_from_slice(&self.parent_id.to_le_bytes());
        out.extend_from_slice(&[self.kind, self.matched]);
        out.extend_from_slice(&self.reserved);
        out.extend_from_slice(&self.score.to_le_bytes());
        out.extend_from_slice(&self.label);
        out.extend_from_slice(&self.matched_text);
        out.push(self.approach_status);
        out.extend_from_slice(&self.reserved2);
        for v in [
            self.approach_x_m,
            self.approach_y_m,
            self.approach_yaw_rad,
            self.approach_standoff_m,
            self.approach_path_m,
        ] {
            out.extend_from_slice(&v.to_le_bytes());
        }
        for v in self.reserved3 {
            out.extend_from_slice(&v.to_le_bytes());
        }
    }

    fn read(r: &mut Reader<'_>) -> Self {
        Self {
            node_id: r.u32(),
            parent_id: r.u32(),
            kind: r.u8(),
            matched: r.u8(),
            reserved: r.take(),
            score: r.f32(),
            label: r.take(),
            matched_text: r.take(),
            approach_status: r.u8(),
            reserved2: r.take(),
            approach_x_m: r.f32(),
            approach_y_m: r.f32(),
            approach_yaw_rad: r.f32(),
            approach_standoff_m: r.f32(),
            approach_path_m: r.f32(),
            reserved3: [r.u32(), r.u32()],
        }
    }
}

impl QueryResponse {
    /// The response's bytes (the iceoryx2 layout, [`QUERY_RESPONSE_BYTES`]).
    pub fn to_bytes(&self) -> Vec<u8> {
        let mut out = Vec::with_capacity(QUERY_RESPONSE_BYTES);
        out.extend_from_slice(&self.schema_version.to_le_bytes());
        out.push(self.status);
        out.extend_from_slice(&self.reserved);
        for v in [self.graph_version, self.instance_id] {
            out.extend_from_slice(&v.to_le_bytes());
        }
        for v in [self.hit_count, self.queue_capacity] {
            out.extend_from_slice(&v.to_le_bytes());
        }
        for v in [self.served_count, self.refused_count] {
            out.extend_from_slice(&v.to_le_bytes());
        }
        for v in [self.encode_us, self.score_us, self.scored_node_count, self.reserved2] {
            out.extend_from_slice(&v.to_le_bytes());
        }
        out.extend_from_slice(&self.message);
        for hit in &self.hits {
            hit.append_to(&mut out);
        }
        out
    }

    /// A response from its bytes; `None` unless exactly [`QUERY_RESPONSE_BYTES`] long.
    pub fn from_bytes(bytes: &[u8]) -> Option<Self> {
        if bytes.len() != QUERY_RESPONSE_BYTES {
            return None;
        }
        let mut r = Reader(bytes);
        let mut out = Self {
            schema_version: r.u32(),
            status: r.u8(),
            reserved: r.take(),
            graph_version: r.u64(),
            instance_id: r.u64(),
            hit_count: r.u32(),
            queue_capacity: r.u32(),
            served_count: r.u64(),
            refused_count: r.u64(),
            encode_us: r.u32(),
            score_us: r.u32(),
            scored_node_count: r.u32(),
            reserved2: r.u32(),
            message: r.take(),
            ..Self::default()
        };
        for hit in &mut out.hits {
            *hit = QueryHit::read(&mut r);
        }
        Some(out)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::NodeKind;
    use crate::text::write_fixed_str;

    #[test]
    fn bytes_have_the_layout_sizes_and_round_trip() {
        assert_eq!(QUERY_REQUEST_BYTES, size_of::<QueryRequest>());
        assert_eq!(QUERY_RESPONSE_BYTES, size_of::<QueryResponse>());
        let request = QueryRequest::new("somewhere to wash my hands", 3).expect("fits");
        let bytes = request.to_bytes();
        assert_eq!(bytes.len(), QUERY_REQUEST_BYTES);
        assert_eq!(&bytes[264..268], &crate::NO_NODE.to_le_bytes());
        let back = QueryRequest::from_bytes(&bytes).expect("request");
        assert_eq!((back.text_str(), back.k, back.asked_node()), ("somewhere to wash my hands", 3, None));
        assert!(QueryRequest::from_bytes(&bytes[1..]).is_none());

        let mut response = QueryResponse { graph_version: 7, instance_id: 0xabc, hit_count: 2, ..Default::default() };
        response.hits[1].node_id = 42;
        response.hits[1].kind = NodeKind::Part as u8;
        response.hits[1].approach_path_m = 2.5;
        write_fixed_str(&mut response.hits[1].label, "knob");
        write_fixed_str(&mut response.message, "fine");
        let bytes = response.to_bytes();
        assert_eq!(bytes.len(), QUERY_RESPONSE_BYTES);
        // The documented offsets: graph_version at 8, message at 64, hit 1's label at 224 + 192 + 16.
        assert_eq!(&bytes[8..16], &7u64.to_le_bytes());
        assert_eq!(&bytes[64..68], b"fine");
        assert_eq!(&bytes[224 + 192 + 16..224 + 192 + 20], b"knob");
        assert_eq!(&bytes[224 + 192 + 180..224 + 192 + 184], &2.5f32.to_le_bytes());
        let back = QueryResponse::from_bytes(&bytes).expect("response");
        assert_eq!(back.to_bytes(), bytes);
        assert_eq!((back.hits()[1].label_str(), back.message_str(), back.instance_id), ("knob", "fine", 0xabc));
    }
}
