//! Labels as the matcher compares them: normalised (lower case, trimmed, inner whitespace
//! collapsed), a ground-truth label split into its `a / b` alternatives, and the deduplicated
//! list of labels a ground-truth node accepts.

/// Lower case, trimmed, inner whitespace collapsed.
pub fn normalise_label(label: &str) -> String {
    label.split_whitespace().collect::<Vec<_>>().join(" ").to_lowercase()
}

/// The alternatives of a ground-truth label written `a / b`, normalised.
pub fn label_alternatives(label: &str) -> impl Iterator<Item = String> + '_ {
    label.split('/').map(normalise_label).filter(|l| !l.is_empty())
}

/// Every alternative of every label in `labels`, normalised, each once, in order.
pub(super) fn accepted_labels<S: AsRef<str>>(labels: impl IntoIterator<Item = S>) -> Vec<String> {
    let mut accepted = Vec::new();
    for label in labels {
        for alternative in label_alternatives(label.as_ref()) {
            push_unique(&mut accepted, alternative);
        }
    }
    accepted
}

fn push_unique(into: &mut Vec<String>, label: String) {
    if !into.contains(&label) {
        into.push(label);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::eval::fusion_match::GtNode;

    #[test]
    fn labels_accept_synonyms_and_alternatives() {
        let scene = op3dsg_synthetic::Scene::generate(op3dsg_synthetic::RoomKind::Kitchen, 1);
        let nodes = GtNode::from_scene(&scene);
        let handle = nodes.iter().find(|n| n.label == "cabinet handle").unwrap();
        assert!(handle.accepts("cupboard handle"), "{:?}", handle.accepted_labels);
        assert!(!handle.accepts("cabinet"));
        assert_eq!(normalise_label("  Cabinet   Handle "), "cabinet handle");
        assert_eq!(label_alternatives("tv / television").collect::<Vec<_>>(), ["tv", "television"]);
        let from_json = GtNode::from_graph_json(&scene.ground_truth());
        assert_eq!(from_json.len(), nodes.len());
        assert_eq!(from_json[0].box_min_m, nodes[0].box_min_m);
    }
}
