//! The ground truth as the matcher sees it: [`GtNode`]s from a synthetic scene (with every label
//! the oracle detector may use) or from a ground-truth graph JSON (the label and its `a / b`
//! alternatives).

use glam::Vec3;
use op3dsg_drivers::graph_json::GraphJson;
use op3dsg_ipc_types::NodeKind;
use op3dsg_synthetic::{InstanceKind, Scene};

use super::labels::accepted_labels;
use crate::oracle::possible_labels;

/// One ground-truth node as the matcher sees it.
#[derive(Debug, Clone, PartialEq)]
pub struct GtNode {
    /// Ground-truth id (the synthetic instance id).
    pub id: u32,
    /// Object or part.
    pub kind: NodeKind,
    /// The canonical label as written in the ground truth (may be `a / b`).
    pub label: String,
    /// Every label accepted for it, normalised (lower case, trimmed).
    pub accepted_labels: Vec<String>,
    /// Axis-aligned world box, metres.
    pub box_min_m: Vec3,
    /// Axis-aligned world box, metres.
    pub box_max_m: Vec3,
    /// Material name, when known (synthetic scenes).
    pub material: Option<String>,
}

impl GtNode {
    /// Every instance of a synthetic scene, with the labels the oracle detector may use.
    pub fn from_scene(scene: &Scene) -> Vec<GtNode> {
        let instances = scene.instances();
        instances
            .iter()
            .map(|info| {
                let accepted_labels = accepted_labels(possible_labels(instances, info));
                GtNode {
                    id: u32::from(info.id),
                    kind: match info.kind {
                        InstanceKind::Object => NodeKind::Object,
                        InstanceKind::Part => NodeKind::Part,
                    },
                    label: info.label.clone(),
                    accepted_labels,
                    box_min_m: info.box_min_m,
                    box_max_m: info.box_max_m,
                    material: Some(info.material.clone()),
                }
            })
            .collect()
    }

    /// The nodes of a ground-truth graph JSON (labels: the label and its `a / b` alternatives;
    /// nodes of another kind than `object` / `part` are skipped).
    pub fn from_graph_json(gt: &GraphJson) -> Vec<GtNode> {
        gt.nodes
            .iter()
            .filter_map(|node| {
                let kind = match node.kind.as_str() {
                    "object" => NodeKind::Object,
                    "part" => NodeKind::Part,
                    _ => return None,
                };
                let accepted_labels = accepted_labels([node.label.as_str()]);
                Some(GtNode {
                    id: node.id,
                    kind,
                    label: node.label.clone(),
                    accepted_labels,
                    box_min_m: Vec3::from(node.box_min_m),
                    box_max_m: Vec3::from(node.box_max_m),
                    material: None,
                })
            })
            .collect()
    }

    /// Whether it accepts `normalised_label` ([`normalise_label`](super::normalise_label)d).
    pub(super) fn accepts(&self, normalised_label: &str) -> bool {
        self.accepted_labels.iter().any(|l| l == normalised_label)
    }

    /// Centre of its box, metres.
    pub(super) fn centre(&self) -> Vec3 {
        (self.box_min_m + self.box_max_m) * 0.5
    }
}
