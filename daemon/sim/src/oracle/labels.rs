//! The labels an instance may be given: [`possible_labels`] (canonical, own synonyms, parent-based
//! synonyms), the word-boundary search they rest on, and the instance kind → node kind map.

use op3dsg_ipc_types::NodeKind;
use op3dsg_synthetic::{InstanceInfo, InstanceKind};

/// Every label the oracle may give a detection of `instance` (one of `instances`): its
/// canonical label, its own synonyms, and for a part its label with the parent's label replaced
/// by each of the parent's synonyms (`cupboard handle` for `cabinet handle`), in that order,
/// without duplicates. Evaluation accepts these as a correct label; the test
/// `synonyms_follow_the_rate_and_the_instance_and_parent_lists` keeps it in step with
/// [`OracleDetector`](super::OracleDetector).
pub fn possible_labels(instances: &[InstanceInfo], instance: &InstanceInfo) -> Vec<String> {
    let mut labels = vec![instance.label.clone()];
    let mut add = |label: String| {
        if !labels.contains(&label) {
            labels.push(label);
        }
    };
    for synonym in &instance.synonyms {
        add(synonym.clone());
    }
    // The first instance with the parent's id, as `OracleDetector::new` resolves it.
    let parent = instance.parent.filter(|id| *id != 0).and_then(|id| instances.iter().find(|i| i.id == id));
    if let Some(parent) = parent
        && let Some(at) = find_word(&instance.label, &parent.label)
    {
        for synonym in &parent.synonyms {
            add(format!("{}{}{}", &instance.label[..at], synonym, &instance.label[at + parent.label.len()..]));
        }
    }
    labels
}

pub(super) fn node_kind(kind: InstanceKind) -> NodeKind {
    match kind {
        InstanceKind::Object => NodeKind::Object,
        InstanceKind::Part => NodeKind::Part,
    }
}

/// Byte offset of `word` inside `text` where it starts and ends at word boundaries (spaces or the
/// ends of `text`).
pub(super) fn find_word(text: &str, word: &str) -> Option<usize> {
    if word.is_empty() {
        return None;
    }
    text.match_indices(word).map(|(at, _)| at).find(|&at| {
        let before = at == 0 || text[..at].ends_with(' ');
        let end = at + word.len();
        let after = end == text.len() || text[end..].starts_with(' ');
        before && after
    })
}
