//! The vocabularies texts are ranked in: the canonical relation and affordance phrases plus the
//! labels, relations and affordances of ground-truth graphs (see the [`recall`](super) docs).

use op3dsg_drivers::graph_json::GraphJson;
use serde::Serialize;

use crate::eval::fusion_match::{label_alternatives, normalise_label};

/// The vocabularies texts are ranked in (see the [`recall`](super) docs).
#[derive(Debug, Clone, Default, PartialEq, Serialize)]
pub struct Vocabulary {
    /// Node labels (normalised, alternatives split), objects and parts together.
    pub node_labels: Vec<String>,
    /// Functional relation phrases.
    pub functional: Vec<String>,
    /// Spatial relation phrases.
    pub spatial: Vec<String>,
    /// Affordance phrases (`hook pull`).
    pub affordances: Vec<String>,
}

fn push_unique(into: &mut Vec<String>, text: String) {
    if !text.is_empty() && !into.contains(&text) {
        into.push(text);
    }
}

/// `hook_pull` → `hook pull`.
pub fn affordance_phrase(name: &str) -> String {
    normalise_label(&name.replace('_', " "))
}

impl Vocabulary {
    /// The canonical relation and affordance vocabularies with no node labels.
    pub fn canonical() -> Self {
        let mut v = Self::default();
        for p in op3dsg_ipc_types::FUNCTIONAL_RELATIONS {
            push_unique(&mut v.functional, normalise_label(p));
        }
        for p in op3dsg_ipc_types::SPATIAL_RELATIONS {
            push_unique(&mut v.spatial, normalise_label(p));
        }
        for a in op3dsg_ipc_types::AFFORDANCES {
            push_unique(&mut v.affordances, affordance_phrase(a));
        }
        v
    }

    /// Adds the labels, relation phrases and affordances of a ground-truth graph.
    pub fn add_ground_truth(&mut self, gt: &GraphJson) {
        for node in &gt.nodes {
            for alternative in label_alternatives(&node.label) {
                push_unique(&mut self.node_labels, alternative);
            }
            for a in &node.affordances {
                push_unique(&mut self.affordances, affordance_phrase(a));
            }
        }
        for edge in &gt.edges {
            let phrase = normalise_label(&edge.relation);
            match edge.kind.as_str() {
                "functional" => push_unique(&mut self.functional, phrase),
                _ => push_unique(&mut self.spatial, phrase),
            }
        }
    }

    /// Adds node labels (each split into its alternatives).
    pub fn add_node_labels<'a>(&mut self, labels: impl IntoIterator<Item = &'a str>) {
        for label in labels {
            for alternative in label_alternatives(label) {
                push_unique(&mut self.node_labels, alternative);
            }
        }
    }

    /// The canonical vocabularies plus everything in `gts`.
    pub fn from_ground_truths<'a>(gts: impl IntoIterator<Item = &'a GraphJson>) -> Self {
        let mut v = Self::canonical();
        for gt in gts {
            v.add_ground_truth(gt);
        }
        v
    }
}
