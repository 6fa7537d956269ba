use std::time::Instant;

use rustc_hash::FxHashMap;

use super::worker::{REJECTION_LOG_INTERVAL, changed_nodes};
use super::*;
use crate::prior::PriorNode;
use crate::reasoner::llm::gate::{Rejection, RejectionLog, Rejections};

fn prior(nodes: &[(u32, &str)]) -> PriorGraph {
    PriorGraph {
        nodes: nodes
            .iter()
            .map(|&(id, label)| PriorNode {
                id,
                kind: op3dsg_ipc_types::NodeKind::Object,
                parent_id: None,
                label: label.to_owned(),
                category: None,
                by_embedding: false,
                confidence: 1.0,
                centre_m: glam::Vec3::ZERO,
                box_min_m: glam::Vec3::ZERO,
                box_max_m: glam::Vec3::ZERO,
            })
            .collect(),
        ..PriorGraph::default()
    }
}

#[test]
fn change_counts_added_removed_and_relabelled_nodes() {
    let before: FxHashMap<u32, String> =
        [(1, "cabinet"), (2, "stove"), (3, "tv")].iter().map(|&(id, l)| (id, l.to_owned())).collect();
    assert_eq!(changed_nodes(&before, &prior(&[(1, "cabinet"), (2, "stove"), (3, "tv")])), 0);
    // 2 relabelled, 3 removed, 4 added.
    assert_eq!(changed_nodes(&before, &prior(&[(1, "cabinet"), (2, "oven"), (4, "sink")])), 3);
}

#[test]
fn rejections_are_logged_once_per_interval_per_reason() {
    let mut limiter = RateLimitedRejections::default();
    let mut log = RejectionLog::default();
    log.reject(Rejection::Malformed, || "local_relations: no JSON object".to_owned());
    log.reject(Rejection::UnknownNode, || "affordances: node 9 is not in the graph".to_owned());
    assert_eq!(limiter.report(1, &log), 2, "one line per reason");
    assert_eq!(limiter.report(2, &log), 0, "within the interval: carried over");
    assert_eq!(limiter.pending[Rejection::Malformed as usize], 1);
    limiter.last[Rejection::Malformed as usize] = Instant::now().checked_sub(REJECTION_LOG_INTERVAL);
    assert_eq!(limiter.report(3, &log), 1, "the interval passed for malformed only");
    assert_eq!(limiter.pending[Rejection::Malformed as usize], 0);
    assert_eq!(limiter.pending[Rejection::UnknownNode as usize], 2);
}

#[test]
fn health_reports_the_state_and_the_rejections() {
    let stats = RefinerStats::default();
    assert_eq!(stats.health().state, RefinerState::Off as u8);
    stats.set_state(RefinerState::BreakerOpen);
    let mut rejections = Rejections::default();
    rejections.add(Rejection::NonCanonical);
    rejections.add(Rejection::NonCanonical);
    stats.add_rejections(&rejections);
    let h = stats.health();
    assert_eq!(op3dsg_ipc_types::REFINER_STATES[h.state as usize], "breaker_open");
    assert_eq!(h.rejections[..5], [0, 0, 0, 2, 0]);
    assert_eq!(op3dsg_ipc_types::REFINER_REJECTIONS[3], "non_canonical");
}
