//! The graph's wire types: [`GraphHeader`] and the byte payload of [`Node`] and [`Edge`] records
//! ([`GraphMessage`] borrows one), the node and edge kinds, and
//! the canonical affordance and relation vocabularies they index.
//!
//! Three parts: the [`vocabulary`] (node and edge kinds, edge origins, the canonical affordances
//! and relations), the [`records`] of the payload ([`Node`], [`Edge`] and their byte form) and
//! the [`sample`] they travel in ([`GraphHeader`], [`GraphMessage`]).

mod records;
mod sample;
#[cfg(test)]
mod tests;
mod vocabulary;

pub use records::{EDGE_BYTES, Edge, LABEL_CAPACITY_BYTES, NO_NODE, NODE_BYTES, Node, PHRASE_CAPACITY_BYTES};
pub use sample::{GraphHeader, GraphMessage, MAX_EDGES, MAX_NODES, SOURCE_KINDS, SourceKind, graph_payload_bytes};
pub use vocabulary::{
    AFFORDANCES, EdgeKind, EdgeOrigin, FUNCTIONAL_RELATION_BASE, FUNCTIONAL_RELATIONS, NodeKind, SPATIAL_RELATIONS,
    affordance_bits, affordance_names, affordance_origin, affordance_origins, relation_id, relation_phrase,
};
