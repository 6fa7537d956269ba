//! The verification gate: nothing an LLM answers reaches the graph unchecked.
//!
//! 1. **Strict parsing**: the answer must be exactly the agent's JSON object (serde with
//!    `deny_unknown_fields`, no prose, no code fences); otherwise the whole answer counts once as
//!    `malformed`. An item whose confidence is not a number in [0, 1] is `malformed` too.
//! 2. **Endpoints**: every id must exist in the graph version the prompt was built from
//!    (`unknown_node`); a local relation must name a part and its parent object of that version,
//!    a remote relation one of the candidate pairs the prompt offered (`wrong_kind`).
//! 3. **Labels** are mapped onto the canonical tables (`op3dsg_ipc_types::FUNCTIONAL_RELATIONS`,
//!    `AFFORDANCES`): exact, else normalised (case, `_`/`-`, punctuation and spacing ignored),
//!    else — with a text encoder configured — the nearest canonical phrase by embedding cosine
//!    when it reaches `embedding_min_similarity`; else `non_canonical`.
//! 4. **Plausibility** ([`super::plausibility`]): geometry and knowledge-base rules for items
//!    that are canonical but make no sense for their nodes (`implausible_geometry`,
//!    `implausible_relation`, `implausible_affordance`).
//!
//! Each rejection is counted by reason ([`Rejections`], `op3dsg_ipc_types::REFINER_REJECTIONS`).
//!
//! | file | what |
//! |---|---|
//! | `json.rs` | the answer's JSON object and its items |
//! | `labels.rs` | free labels onto the canonical tables ([`LabelMapper`]) |
//! | this file | the checks and the rejection counts ([`check`]) |

mod json;
mod labels;
#[cfg(test)]
mod tests;

use json::{AffordanceItem, LocalItem, RemoteItem, parse_items};
pub use json::{ParseOptions, extract_object};
pub use labels::{LabelMapper, normalise};
use op3dsg_ipc_types::NodeKind;

use super::plausibility::Plausibility;
use super::prompt::{Agent, PromptSet};
use crate::prior::{PriorGraph, PriorNode};
use crate::reasoner::{FunctionalRelation, NodeAffordances, ReasonerOutput};

/// Why an item was rejected (index into `op3dsg_ipc_types::REFINER_REJECTIONS`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Rejection {
    /// Failed strict parsing, or a bad confidence.
    Malformed = 0,
    /// An id not in that graph version.
    UnknownNode = 1,
    /// Endpoints of the wrong kind (not a part-of pair, not an allowed remote pair).
    WrongKind = 2,
    /// A label that maps onto no canonical one.
    NonCanonical = 3,
    /// Nodes gone when the result reached the graph.
    Stale = 4,
    /// Geometry rules it out: a part off its object, a remote pair too far apart, a part too
    /// large for the affordance ([`super::plausibility`]).
    ImplausibleGeometry = 5,
    /// A relation the knowledge base gives none of the categories involved.
    ImplausibleRelation = 6,
    /// An affordance the knowledge base gives none of the categories involved.
    ImplausibleAffordance = 7,
}

/// Rejection counts by reason.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Rejections(pub [u64; op3dsg_ipc_types::REFINER_REJECTIONS.len()]);

impl Rejections {
    /// Counts one rejection.
    pub fn add(&mut self, reason: Rejection) {
        self.0[reason as usize] += 1;
    }
    /// Count for one reason.
    pub fn get(&self, reason: Rejection) -> u64 {
        self.0[reason as usize]
    }
    /// All rejections.
    pub fn total(&self) -> u64 {
        self.0.iter().sum()
    }
}

fn confidence(value: f64) -> Option<f32> {
    (value.is_finite() && (0.0..=1.0).contains(&value)).then_some(value as f32)
}

/// Checks one proposed functional relation `(source, target, phrase, confidence)`, in the order
/// the rejections are counted: confidence in [0, 1], both endpoints in the graph, the agent's
/// kind rule (`allowed`), a canonical phrase. `Err`: the reason and what was wrong.
fn verify_relation<'a>(
    (source_id, target_id, phrase, value): (u32, u32, &str, f64),
    node: &impl Fn(u32) -> Option<&'a PriorNode>,
    allowed: bool,
    remote: bool,
    mapper: &mut LabelMapper,
) -> Result<FunctionalRelation, (Rejection, String)> {
    let confidence =
        confidence(value).ok_or_else(|| (Rejection::Malformed, format!("confidence {value} is not within [0, 1]")))?;
    for id in [source_id, target_id] {
        if node(id).is_none() {
            return Err((Rejection::UnknownNode, format!("node {id} is not in the graph")));
        }
    }
    if !allowed {
        let what = if remote { "not a remote pair the prompt offered" } else { "not a part and its parent object" };
        return Err((Rejection::WrongKind, format!("{source_id} -> {target_id} is {what}")));
    }
    let relation_id = mapper
        .relation(phrase)
        .ok_or_else(|| (Rejection::NonCanonical, format!("{phrase:?} maps onto no canonical relation")))?;
    Ok(FunctionalRelation { source_id, target_id, relation_id, confidence, remote })
}

/// Rejections of one refresh: counts by reason and the first example of each (for the log).
#[derive(Debug, Clone, Default)]
pub struct RejectionLog {
    /// Counts by reason.
    pub counts: Rejections,
    /// What was wrong with the first item rejected for each reason (serde's message for
    /// `malformed`).
    pub examples: [Option<String>; op3dsg_ipc_types::REFINER_REJECTIONS.len()],
}

impl RejectionLog {
    /// Counts one rejection; `detail` is asked for the first of each reason only.
    pub fn reject(&mut self, reason: Rejection, detail: impl FnOnce() -> String) {
        self.counts.add(reason);
        let slot = &mut self.examples[reason as usize];
        if slot.is_none() {
            *slot = Some(detail());
        }
    }
    /// Count for one reason.
    pub fn get(&self, reason: Rejection) -> u64 {
        self.counts.get(reason)
    }
    /// All rejections.
    pub fn total(&self) -> u64 {
        self.counts.total()
    }
}

/// What an answer is checked against: the graph version its prompts were built from, the
/// prompts, the plausibility rules and how strictly the answer is read.
#[derive(Debug, Clone, Copy)]
pub struct Against<'a> {
    /// The prior graph the prompts were built from.
    pub prior: &'a PriorGraph,
    /// The refresh's prompts (which pairs were offered).
    pub prompts: &'a PromptSet,
    /// Geometry and knowledge-base rules.
    pub rules: &'a Plausibility,
    /// How strictly answers are read.
    pub options: ParseOptions,
}

/// Checks one agent's answer against what its prompt offered; accepted items are added to
/// `output`, rejections to `log`. Returns how many items were accepted, or `None` when the
/// answer as a whole is unusable (no JSON object, no list: counted once as `malformed`), which
/// the refiner treats like a failed call.
pub fn check(
    agent: Agent,
    answer: &str,
    against: Against<'_>,
    mapper: &mut LabelMapper,
    output: &mut ReasonerOutput,
    log: &mut RejectionLog,
) -> Option<u64> {
    let Against { prior, prompts, rules, options } = against;
    debug_assert_eq!(prior.version, prompts.graph_version);
    let node = |id: u32| prior.index_of(id).map(|i| &prior.nodes[i]);
    let name = agent.name();
    let mut accepted = 0;
    let mut keep = |verdict: Result<FunctionalRelation, (Rejection, String)>, log: &mut RejectionLog| match verdict {
        Ok(relation) => {
            output.functional.push(relation);
            accepted += 1;
        }
        Err((reason, detail)) => log.reject(reason, || format!("{name}: {detail}")),
    };
    match agent {
        Agent::Local => {
            const FIELDS: [&str; 4] = ["part_id", "object_id", "relation", "confidence"];
            let items: Vec<LocalItem> = parse_items(agent, answer, "relations", &FIELDS, options, log).ok()?;
            for item in items {
                // Local relations only on the graph's part-of pairs.
                let allowed = node(item.part_id)
                    .is_some_and(|part| part.kind == NodeKind::Part && part.parent_id == Some(item.object_id));
                let proposal = (item.part_id, item.object_id, item.relation.as_str(), item.confidence);
                let verdict = verify_relation(proposal, &node, allowed, false, mapper).and_then(|relation| {
                    match (node(relation.source_id), node(relation.target_id)) {
                        (Some(part), Some(object)) => {
                            rules.local(part, object, relation.relation_id).map(|()| relation)
                        }
                        _ => Ok(relation),
                    }
                });
                keep(verdict, log);
            }
        }
        Agent::Remote => {
            const FIELDS: [&str; 4] = ["source_id", "target_id", "relation", "confidence"];
            let items: Vec<RemoteItem> = parse_items(agent, answer, "relations", &FIELDS, options, log).ok()?;
            for item in items {
                // Remote relations only on the pairs the prompt offered.
                let allowed = prompts.remote_candidates.contains(&(item.source_id, item.target_id));
                let proposal = (item.source_id, item.target_id, item.relation.as_str(), item.confidence);
                let verdict = verify_relation(proposal, &node, allowed, true, mapper).and_then(|relation| {
                    match (node(relation.source_id), node(relation.target_id)) {
                        (Some(source), Some(target)) => {
                            rules.remote(source, target, relation.relation_id).map(|()| relation)
                        }
                        _ => Ok(relation),
                    }
                });
                keep(verdict, log);
            }
        }
        Agent::Affordances => {
            const FIELDS: [&str; 3] = ["node_id", "affordances", "confidence"];
            let items: Vec<AffordanceItem> = parse_items(agent, answer, "affordances", &FIELDS, options, log).ok()?;
            for item in items {
                let Some(confidence) = confidence(item.confidence) else {
                    log.reject(Rejection::Malformed, || {
                        format!("{name}: confidence {} is not within [0, 1]", item.confidence)
                    });
                    continue;
                };
                let Some(target) = node(item.node_id) else {
                    log.reject(Rejection::UnknownNode, || format!("{name}: node {} is not in the graph", item.node_id));
                    continue;
                };
                let mut bits = 0u16;
                for label in &item.affordances {
                    match mapper.affordance(label) {
                        Some(i) => match rules.affordance(prior, target, i) {
                            Ok(()) => bits |= 1 << i,
                            Err((reason, detail)) => log.reject(reason, || format!("{name}: {detail}")),
                        },
                        None => {
                            log.reject(Rejection::NonCanonical, || {
                                format!("{name}: {label:?} maps onto no canonical affordance")
                            });
                        }
                    }
                }
                if bits != 0 {
                    output.affordances.push(NodeAffordances {
                        node_id: item.node_id,
                        affordance_bits: bits,
                        confidence,
                    });
                    accepted += 1;
                }
            }
        }
    }
    Some(accepted)
}
