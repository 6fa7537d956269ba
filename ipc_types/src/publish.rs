//! Writing graph samples: [`send_graph`] loans a sample sized to the graph from the `graph`
//! publisher, writes the header and payload in place and sends it; [`GraphBuffer`] builds a graph
//! on the heap (tools, test publishers, planner tests against [`Graph`](crate::Graph)).

use iceoryx2::port::publisher::Publisher;
use iceoryx2::port::{LoanError, SendError};

use crate::{Edge, GraphHeader, GraphMessage, Node};

/// The payload type of `<prefix>/graph`: bytes (nodes, then edges), with a [`GraphHeader`] as
/// the iceoryx2 user header.
pub type GraphPayload = [u8];

/// Why [`send_graph`] failed.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum GraphSendError {
    /// No sample of that size could be loaned (more than the publisher's maximum, or every
    /// sample is loaned or held by subscribers).
    Loan(LoanError),
    /// The sample could not be delivered.
    Send(SendError),
}

impl core::fmt::Display for GraphSendError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            Self::Loan(e) => write!(f, "loan: {e:?}"),
            Self::Send(e) => write!(f, "send: {e:?}"),
        }
    }
}

impl std::error::Error for GraphSendError {}

/// Loans a sample of `payload.len()` bytes, writes `header` into its user header and copies
/// `payload` in, then sends it. The sample in shared memory is exactly as large as the graph.
/// Returns the number of subscribers it reached.
pub fn send_graph<S: iceoryx2::service::Service>(
    publisher: &Publisher<S, GraphPayload, GraphHeader>,
    header: &GraphHeader,
    payload: &[u8],
) -> Result<usize, GraphSendError> {
    debug_assert_eq!(header.payload_bytes(), payload.len(), "header counts and payload disagree");
    let mut sample = publisher.loan_slice_uninit(payload.len()).map_err(GraphSendError::Loan)?;
    *sample.user_header_mut() = *header;
    sample.write_from_slice(payload).send().map_err(GraphSendError::Send)
}

/// A graph on the heap: the header and typed nodes and edges, encoded into the wire payload by
/// [`Self::encode`] (into a buffer it keeps and reuses).
#[derive(Debug, Clone, Default)]
pub struct GraphBuffer {
    /// The header; [`Self::encode`] sets its `node_count` and `edge_count` from the lists.
    pub header: GraphHeader,
    /// The nodes, sorted by id (the contract's order).
    pub nodes: Vec<Node>,
    /// The edges.
    pub edges: Vec<Edge>,
    payload: Vec<u8>,
}

impl GraphBuffer {
    /// An empty graph with a default header.
    pub fn new() -> Self {
        Self::default()
    }

    /// Sets the counts in the header from the lists, encodes the payload and returns the
    /// message as a subscriber would see it.
    pub fn encode(&mut self) -> GraphMessage<'_> {
        self.header.node_count = self.nodes.len() as u32;
        self.header.edge_count = self.edges.len() as u32;
        self.payload.clear();
        self.payload.reserve(self.header.payload_bytes());
        for node in &self.nodes {
            node.append_bytes(&mut self.payload);
        }
        for edge in &self.edges {
            edge.append_bytes(&mut self.payload);
        }
        GraphMessage::new(&self.header, &self.payload)
    }

    /// [`Self::encode`], then [`send_graph`].
    pub fn send<S: iceoryx2::service::Service>(
        &mut self,
        publisher: &Publisher<S, GraphPayload, GraphHeader>,
    ) -> Result<usize, GraphSendError> {
        self.encode();
        send_graph(publisher, &self.header, &self.payload)
    }
}
