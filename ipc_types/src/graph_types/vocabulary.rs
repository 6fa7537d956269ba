//! The graph's vocabulary: the kinds of nodes and edges, where an edge or an affordance came
//! from, and the canonical affordances and relations that [`Node`](super::Node) and
//! [`Edge`](super::Edge) index.

/// The 9 canonical affordances (the SceneFun3D set used by UniGraph3D), in bit order:
/// bit `i` of [`Node::affordance_bits`](crate::Node::affordance_bits) is `AFFORDANCES[i]`.
pub const AFFORDANCES: [&str; 9] =
    ["rotate", "key_press", "tip_push", "hook_pull", "pinch_pull", "hook_turn", "foot_push", "plug_in", "unplug"];

/// The 11 canonical functional relations of UniGraph3D. A functional [`Edge`](crate::Edge)'s
/// `relation_id` is `FUNCTIONAL_RELATIONS` index + [`FUNCTIONAL_RELATION_BASE`].
pub const FUNCTIONAL_RELATIONS: [&str; 11] = [
    "pull to open or close",
    "control the water flow",
    "rotate to adjust the setting or temperature",
    "press to start and operate",
    "turn on or turn off",
    "remote to control",
    "press to flush",
    "provide power",
    "push or press to open",
    "operate or adjust the flow or setting",
    "rotate to open or close",
];

/// The canonical spatial relations. A spatial [`Edge`](crate::Edge)'s `relation_id` is the index
/// here.
pub const SPATIAL_RELATIONS: [&str; 7] = ["part of", "on", "under", "above", "below", "next to", "inside"];

/// Offset of functional relation ids, so that every relation id is unique across kinds.
pub const FUNCTIONAL_RELATION_BASE: u16 = 100;

/// Canonical relation id for a phrase of [`SPATIAL_RELATIONS`] or [`FUNCTIONAL_RELATIONS`].
pub fn relation_id(phrase: &str) -> Option<(EdgeKind, u16)> {
    if let Some(i) = SPATIAL_RELATIONS.iter().position(|p| *p == phrase) {
        return Some((EdgeKind::Spatial, i as u16));
    }
    FUNCTIONAL_RELATIONS
        .iter()
        .position(|p| *p == phrase)
        .map(|i| (EdgeKind::Functional, FUNCTIONAL_RELATION_BASE + i as u16))
}

/// The canonical phrase of a relation id (inverse of [`relation_id`]).
pub fn relation_phrase(id: u16) -> Option<&'static str> {
    if id >= FUNCTIONAL_RELATION_BASE {
        FUNCTIONAL_RELATIONS.get((id - FUNCTIONAL_RELATION_BASE) as usize).copied()
    } else {
        SPATIAL_RELATIONS.get(id as usize).copied()
    }
}

/// Bit set over [`AFFORDANCES`] for the given names; unknown names give `Err(name)`.
pub fn affordance_bits<'a>(names: impl IntoIterator<Item = &'a str>) -> Result<u16, &'a str> {
    let mut bits = 0u16;
    for name in names {
        let i = AFFORDANCES.iter().position(|a| *a == name).ok_or(name)?;
        bits |= 1 << i;
    }
    Ok(bits)
}

/// Names of the affordances set in `bits`, in canonical order.
pub fn affordance_names(bits: u16) -> impl Iterator<Item = &'static str> {
    AFFORDANCES.iter().enumerate().filter(move |(i, _)| bits & (1 << i) != 0).map(|(_, a)| *a)
}

/// Kind of a graph node.
#[repr(u8)]
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum NodeKind {
    /// A physical object (cabinet, stove, TV, ...).
    #[default]
    Object = 0,
    /// An interactive part of an object (handle, knob, button, switch, ...).
    Part = 1,
}

impl NodeKind {
    /// Decodes the wire value of [`Node::kind`](crate::Node::kind).
    pub fn from_u8(value: u8) -> Option<Self> {
        match value {
            0 => Some(Self::Object),
            1 => Some(Self::Part),
            _ => None,
        }
    }
    /// Lower-case name as used in the JSON form ("object", "part").
    pub fn as_str(self) -> &'static str {
        match self {
            Self::Object => "object",
            Self::Part => "part",
        }
    }
}

/// Kind of a graph edge.
#[repr(u8)]
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum EdgeKind {
    /// Geometric relation ([`SPATIAL_RELATIONS`]), including `part of`.
    #[default]
    Spatial = 0,
    /// Functional relation ([`FUNCTIONAL_RELATIONS`]): the source acts on the target.
    Functional = 1,
}

impl EdgeKind {
    /// Decodes the wire value of [`Edge::kind`](crate::Edge::kind).
    pub fn from_u8(value: u8) -> Option<Self> {
        match value {
            0 => Some(Self::Spatial),
            1 => Some(Self::Functional),
            _ => None,
        }
    }
    /// Lower-case name as used in the JSON form ("spatial", "functional").
    pub fn as_str(self) -> &'static str {
        match self {
            Self::Spatial => "spatial",
            Self::Functional => "functional",
        }
    }
}

/// Where an edge came from.
#[repr(u8)]
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum EdgeOrigin {
    /// Derived from fused geometry (spatial rules, part-of attachment).
    #[default]
    Geometry = 0,
    /// The offline knowledge reasoner.
    Knowledge = 1,
    /// An LLM agent, after the verification gate.
    Llm = 2,
    /// The knowledge reasoner and an LLM agent agree.
    KnowledgeAndLlm = 3,
}

impl EdgeOrigin {
    /// Decodes the wire value of [`Edge::origin`](crate::Edge::origin).
    pub fn from_u8(value: u8) -> Option<Self> {
        match value {
            0 => Some(Self::Geometry),
            1 => Some(Self::Knowledge),
            2 => Some(Self::Llm),
            3 => Some(Self::KnowledgeAndLlm),
            _ => None,
        }
    }
    /// Lower-case name as used in the JSON form.
    pub fn as_str(self) -> &'static str {
        match self {
            Self::Geometry => "geometry",
            Self::Knowledge => "knowledge",
            Self::Llm => "llm",
            Self::KnowledgeAndLlm => "knowledge+llm",
        }
    }
}

/// The origin of affordance `AFFORDANCES[index]` from a node's three masks
/// ([`Node`](crate::Node)'s docs): `None` when `bits` lacks it, else knowledge, llm, knowledge+llm
/// or geometry.
pub fn affordance_origin(bits: u16, knowledge_bits: u16, llm_bits: u16, index: usize) -> Option<EdgeOrigin> {
    if index >= AFFORDANCES.len() {
        return None;
    }
    let bit = 1u16 << index;
    if bits & bit == 0 {
        return None;
    }
    Some(match (knowledge_bits & bit != 0, llm_bits & bit != 0) {
        (true, true) => EdgeOrigin::KnowledgeAndLlm,
        (true, false) => EdgeOrigin::Knowledge,
        (false, true) => EdgeOrigin::Llm,
        (false, false) => EdgeOrigin::Geometry,
    })
}

/// Each affordance in `bits` with its origin (see [`affordance_origin`]), in canonical order.
pub fn affordance_origins(
    bits: u16,
    knowledge_bits: u16,
    llm_bits: u16,
) -> impl Iterator<Item = (&'static str, EdgeOrigin)> {
    AFFORDANCES
        .iter()
        .enumerate()
        .filter_map(move |(i, name)| affordance_origin(bits, knowledge_bits, llm_bits, i).map(|o| (*name, o)))
}
