//! `[reasoner]`: the prior graph and the reasoner run on each published graph.

use serde::{Deserialize, Serialize};

use crate::prior::PriorConfig;
use crate::world::UpAxis;

/// Reasoner kinds (`reasoner.kind`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ReasonerKind {
    /// Published graphs carry fusion's nodes and part-of edges only.
    None,
    /// Prior graph (spatial relations) + the offline knowledge reasoner (functional relations,
    /// affordances); see `crate::reasoner::knowledge`.
    Knowledge,
    /// `knowledge` on every published graph, plus the asynchronous LLM refiner
    /// (`[reasoner.llm]`, `crate::reasoner::llm`): verified LLM edges are added as they arrive.
    Llm,
}

/// `[reasoner]`: the prior graph (`crate::prior`) and the reasoner applied to each published
/// graph.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ReasonerConfig {
    /// Which reasoner runs.
    pub kind: ReasonerKind,
    /// Folder with `objects.toml`, `parts.toml`, `remote.toml` replacing the built-in knowledge
    /// base (relative to the profile file that sets it).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub knowledge_dir: Option<String>,
    /// Nodes whose centres are this close are neighbours, metres.
    pub neighbour_radius_m: f32,
    /// `on` / `under` when the vertical gap is at most this, metres.
    pub contact_tolerance_m: f32,
    /// `next to` when footprints are at most this far apart, metres.
    pub next_to_gap_m: f32,
    /// Footprint overlap (fraction of the smaller footprint) for `on`/`under`/`above`/`below`.
    pub min_footprint_overlap: f32,
    /// Slack for `inside`, metres.
    pub inside_tolerance_m: f32,
    /// The LLM endpoint and the refiner's policies (used with `kind = "llm"`).
    #[serde(default)]
    pub llm: super::llm::LlmConfig,
}

impl ReasonerConfig {
    /// Range checks, and `[reasoner.llm]` (required with `kind = "llm"`); messages start with
    /// `path.field`.
    pub fn validate(&self, path: &str) -> Result<(), String> {
        if !(self.neighbour_radius_m > 0.0 && self.neighbour_radius_m <= 10.0) {
            return Err(format!(
                "{path}.neighbour_radius_m: must be within (0, 10] metres, got {}",
                self.neighbour_radius_m
            ));
        }
        for (name, v) in [
            ("contact_tolerance_m", self.contact_tolerance_m),
            ("next_to_gap_m", self.next_to_gap_m),
            ("inside_tolerance_m", self.inside_tolerance_m),
        ] {
            if !(0.0..=1.0).contains(&v) {
                return Err(format!("{path}.{name}: must be within [0, 1] metres, got {v}"));
            }
        }
        if !(0.0..=1.0).contains(&self.min_footprint_overlap) {
            return Err(format!(
                "{path}.min_footprint_overlap: must be within [0, 1], got {}",
                self.min_footprint_overlap
            ));
        }
        self.llm.validate(&format!("{path}.llm"), self.kind == ReasonerKind::Llm)
    }

    /// The prior graph's tolerances, in a world whose up axis is `up_axis`.
    pub fn prior(&self, up_axis: UpAxis) -> PriorConfig {
        PriorConfig {
            up_axis,
            neighbour_radius_m: self.neighbour_radius_m,
            contact_tolerance_m: self.contact_tolerance_m,
            next_to_gap_m: self.next_to_gap_m,
            min_footprint_overlap: self.min_footprint_overlap,
            inside_tolerance_m: self.inside_tolerance_m,
        }
    }
}
