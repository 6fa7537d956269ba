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
//!
//! Each rejection is counted by reason ([`Rejections`], `op3dsg_ipc_types::REFINER_REJECTIONS`).

use op3dsg_ipc_types::{AFFORDANCES, FUNCTIONAL_RELATION_BASE, FUNCTIONAL_RELATIONS, NodeKind};
use serde::Deserialize;

use super::prompt::{Agent, PromptSet};
use crate::onnx::text_encoder::{Embedding, TextEncoder, cosine};
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

/// Embeds phrases for the nearest-canonical-phrase mapping.
pub trait PhraseEmbedder: Send {
    /// Unit-length embeddings of `phrases`, in order.
    fn embed(&mut self, phrases: &[&str]) -> Result<Vec<Embedding>, String>;
}

impl PhraseEmbedder for TextEncoder {
    fn embed(&mut self, phrases: &[&str]) -> Result<Vec<Embedding>, String> {
        self.encode_batch(phrases).map_err(|e| e.to_string())
    }
}

/// Lower case; `_`, `-` and punctuation as spaces; whitespace collapsed.
pub fn normalise(label: &str) -> String {
    let cleaned: String = label.to_lowercase().chars().map(|c| if c.is_alphanumeric() { c } else { ' ' }).collect();
    cleaned.split_whitespace().collect::<Vec<_>>().join(" ")
}

/// One canonical table with its normalised forms and (lazily) its embeddings.
struct Table {
    phrases: &'static [&'static str],
    normalised: Vec<String>,
    embeddings: Option<Vec<Embedding>>,
}

impl Table {
    fn new(phrases: &'static [&'static str]) -> Self {
        Self { phrases, normalised: phrases.iter().map(|p| normalise(p)).collect(), embeddings: None }
    }
}

/// Maps free labels onto the canonical tables.
pub struct LabelMapper {
    relations: Table,
    affordances: Table,
    embedder: Option<Box<dyn PhraseEmbedder>>,
    min_similarity: f32,
}

impl std::fmt::Debug for LabelMapper {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("LabelMapper")
            .field("embedder", &self.embedder.is_some())
            .field("min_similarity", &self.min_similarity)
            .finish()
    }
}

impl LabelMapper {
    /// A mapper; `embedder` enables the nearest-phrase fallback at `min_similarity`.
    pub fn new(embedder: Option<Box<dyn PhraseEmbedder>>, min_similarity: f32) -> Self {
        Self {
            relations: Table::new(&FUNCTIONAL_RELATIONS),
            affordances: Table::new(&AFFORDANCES),
            embedder,
            min_similarity,
        }
    }

    fn map(table: &mut Table, embedder: &mut Option<Box<dyn PhraseEmbedder>>, min: f32, label: &str) -> Option<usize> {
        if let Some(i) = table.phrases.iter().position(|p| *p == label) {
            return Some(i);
        }
        let key = normalise(label);
        if let Some(i) = table.normalised.iter().position(|p| *p == key) {
            return Some(i);
        }
        let embedder = embedder.as_mut()?;
        if key.is_empty() {
            return None;
        }
        if table.embeddings.is_none() {
            // Embedded as normalised text ("hook pull"), like the labels compared with them.
            let phrases: Vec<&str> = table.normalised.iter().map(String::as_str).collect();
            match embedder.embed(&phrases) {
                Ok(e) if e.len() == phrases.len() => table.embeddings = Some(e),
                Ok(_) | Err(_) => return None,
            }
        }
        let embedded = embedder.embed(&[key.as_str()]).ok()?;
        let query = embedded.first()?;
        let (best, similarity) = table
            .embeddings
            .as_ref()?
            .iter()
            .enumerate()
            .map(|(i, e)| (i, cosine(query, e)))
            .max_by(|a, b| a.1.total_cmp(&b.1))?;
        (similarity >= min).then_some(best)
    }

    /// Canonical functional relation id for `label`.
    pub fn relation(&mut self, label: &str) -> Option<u16> {
        Self::map(&mut self.relations, &mut self.embedder, self.min_similarity, label)
            .map(|i| FUNCTIONAL_RELATION_BASE + i as u16)
    }

    /// Affordance bit index for `label`.
    pub fn affordance(&mut self, label: &str) -> Option<usize> {
        Self::map(&mut self.affordances, &mut self.embedder, self.min_similarity, label)
    }
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct LocalAnswer {
    relations: Vec<LocalItem>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct LocalItem {
    part_id: u32,
    object_id: u32,
    relation: String,
    confidence: f64,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RemoteAnswer {
    relations: Vec<RemoteItem>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RemoteItem {
    source_id: u32,
    target_id: u32,
    relation: String,
    confidence: f64,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct AffordanceAnswer {
    affordances: Vec<AffordanceItem>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct AffordanceItem {
    node_id: u32,
    affordances: Vec<String>,
    confidence: f64,
}

fn confidence(value: f64) -> Option<f32> {
    (value.is_finite() && (0.0..=1.0).contains(&value)).then_some(value as f32)
}

/// Checks one proposed functional relation `(source, target, phrase, confidence)`, in the order
/// the rejections are counted: confidence in [0, 1], both endpoints in the graph, the agent's
/// kind rule (`allowed`), a canonical phrase.
fn verify_relation<'a>(
    (source_id, target_id, phrase, value): (u32, u32, &str, f64),
    node: &impl Fn(u32) -> Option<&'a PriorNode>,
    allowed: bool,
    remote: bool,
    mapper: &mut LabelMapper,
) -> Result<FunctionalRelation, Rejection> {
    let confidence = confidence(value).ok_or(Rejection::Malformed)?;
    if node(source_id).is_none() || node(target_id).is_none() {
        return Err(Rejection::UnknownNode);
    }
    if !allowed {
        return Err(Rejection::WrongKind);
    }
    let relation_id = mapper.relation(phrase).ok_or(Rejection::NonCanonical)?;
    Ok(FunctionalRelation { source_id, target_id, relation_id, confidence, remote })
}

/// Checks one agent's answer against the graph version `prompts` was built from; accepted items
/// are added to `output`, rejections to `rejections`. Returns how many items were accepted.
pub fn check(
    agent: Agent,
    answer: &str,
    prior: &PriorGraph,
    prompts: &PromptSet,
    mapper: &mut LabelMapper,
    output: &mut ReasonerOutput,
    rejections: &mut Rejections,
) -> u64 {
    debug_assert_eq!(prior.version, prompts.graph_version);
    let node = |id: u32| prior.index_of(id).map(|i| &prior.nodes[i]);
    let mut accepted = 0;
    match agent {
        Agent::Local => {
            let Ok(answer) = serde_json::from_str::<LocalAnswer>(answer) else {
                rejections.add(Rejection::Malformed);
                return 0;
            };
            for item in answer.relations {
                // Local relations only on the graph's part-of pairs.
                let allowed = node(item.part_id)
                    .is_some_and(|part| part.kind == NodeKind::Part && part.parent_id == Some(item.object_id));
                let proposal = (item.part_id, item.object_id, item.relation.as_str(), item.confidence);
                match verify_relation(proposal, &node, allowed, false, mapper) {
                    Ok(relation) => {
                        output.functional.push(relation);
                        accepted += 1;
                    }
                    Err(reason) => rejections.add(reason),
                }
            }
        }
        Agent::Remote => {
            let Ok(answer) = serde_json::from_str::<RemoteAnswer>(answer) else {
                rejections.add(Rejection::Malformed);
                return 0;
            };
            for item in answer.relations {
                // Remote relations only on the pairs the prompt offered.
                let allowed = prompts.remote_candidates.contains(&(item.source_id, item.target_id));
                let proposal = (item.source_id, item.target_id, item.relation.as_str(), item.confidence);
                match verify_relation(proposal, &node, allowed, true, mapper) {
                    Ok(relation) => {
                        output.functional.push(relation);
                        accepted += 1;
                    }
                    Err(reason) => rejections.add(reason),
                }
            }
        }
        Agent::Affordances => {
            let Ok(answer) = serde_json::from_str::<AffordanceAnswer>(answer) else {
                rejections.add(Rejection::Malformed);
                return 0;
            };
            for item in answer.affordances {
                let Some(confidence) = confidence(item.confidence) else {
                    rejections.add(Rejection::Malformed);
                    continue;
                };
                if node(item.node_id).is_none() {
                    rejections.add(Rejection::UnknownNode);
                    continue;
                }
                let mut bits = 0u16;
                for label in &item.affordances {
                    match mapper.affordance(label) {
                        Some(i) => bits |= 1 << i,
                        None => rejections.add(Rejection::NonCanonical),
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
    accepted
}

#[cfg(test)]
mod tests {
    use op3dsg_ipc_types::relation_id;

    use super::*;
    use crate::reasoner::llm::prompt::{self, tests::corner_prior};

    fn run(agent: Agent, answer: &str, mapper: &mut LabelMapper) -> (ReasonerOutput, Rejections) {
        let (prior, kb) = corner_prior();
        let prompts = prompt::build(&prior, &kb, 400);
        let mut output = ReasonerOutput { graph_version: prior.version, ..ReasonerOutput::default() };
        let mut rejections = Rejections::default();
        check(agent, answer, &prior, &prompts, mapper, &mut output, &mut rejections);
        (output, rejections)
    }

    fn id(phrase: &str) -> u16 {
        relation_id(phrase).unwrap().1
    }

    #[test]
    fn good_local_answers_pass_and_labels_are_normalised() {
        let mut mapper = LabelMapper::new(None, 0.8);
        let answer = r#"{"relations": [
            {"part_id": 5, "object_id": 1, "relation": "pull to open or close", "confidence": 0.9},
            {"part_id": 6, "object_id": 2, "relation": "Rotate to adjust the setting or temperature.", "confidence": 0.8}
        ]}"#;
        let (output, rejections) = run(Agent::Local, answer, &mut mapper);
        assert_eq!(rejections.total(), 0);
        let got: Vec<(u32, u32, u16, bool)> =
            output.functional.iter().map(|r| (r.source_id, r.target_id, r.relation_id, r.remote)).collect();
        assert_eq!(
            got,
            [
                (5, 1, id("pull to open or close"), false),
                (6, 2, id("rotate to adjust the setting or temperature"), false)
            ]
        );
    }

    #[test]
    fn each_bad_item_is_rejected_for_its_reason() {
        let mut mapper = LabelMapper::new(None, 0.8);
        let answer = r#"{"relations": [
            {"part_id": 99, "object_id": 1, "relation": "pull to open or close", "confidence": 0.9},
            {"part_id": 5, "object_id": 2, "relation": "pull to open or close", "confidence": 0.9},
            {"part_id": 1, "object_id": 2, "relation": "pull to open or close", "confidence": 0.9},
            {"part_id": 5, "object_id": 1, "relation": "yank it", "confidence": 0.9},
            {"part_id": 5, "object_id": 1, "relation": "pull to open or close", "confidence": 1.5}
        ]}"#;
        let (output, r) = run(Agent::Local, answer, &mut mapper);
        assert!(output.functional.is_empty());
        assert_eq!(
            (
                r.get(Rejection::UnknownNode),
                r.get(Rejection::WrongKind),
                r.get(Rejection::NonCanonical),
                r.get(Rejection::Malformed)
            ),
            (1, 2, 1, 1)
        );
    }

    #[test]
    fn anything_but_the_exact_object_is_malformed() {
        let mut mapper = LabelMapper::new(None, 0.8);
        for answer in [
            "Sure! Here are the relations: {}",
            "```json\n{\"relations\": []}\n```",
            r#"{"relations": [], "notes": "extra"}"#,
            r#"{"relations": [{"part_id": "5", "object_id": 1, "relation": "x", "confidence": 0.5}]}"#,
            r#"{"relations": [{"part_id": 5, "object_id": 1, "relation": "pull to open or close"}]}"#,
            r#"{"relations": [{"part_id": -5, "object_id": 1, "relation": "pull to open or close", "confidence": 0.5}]}"#,
        ] {
            let (output, r) = run(Agent::Local, answer, &mut mapper);
            assert!(output.functional.is_empty(), "{answer}");
            assert_eq!(r.get(Rejection::Malformed), 1, "{answer}");
        }
    }

    #[test]
    fn remote_relations_only_between_offered_candidates() {
        let mut mapper = LabelMapper::new(None, 0.8);
        let answer = r#"{"relations": [
            {"source_id": 4, "target_id": 3, "relation": "remote to control", "confidence": 0.9},
            {"source_id": 4, "target_id": 7, "relation": "remote to control", "confidence": 0.9},
            {"source_id": 5, "target_id": 2, "relation": "turn on or turn off", "confidence": 0.9}
        ]}"#;
        let (output, r) = run(Agent::Remote, answer, &mut mapper);
        assert_eq!(output.functional.len(), 1);
        assert_eq!((output.functional[0].source_id, output.functional[0].target_id), (4, 3));
        assert!(output.functional[0].remote);
        assert_eq!(r.get(Rejection::WrongKind), 2);
    }

    #[test]
    fn affordances_keep_the_canonical_labels_only() {
        let mut mapper = LabelMapper::new(None, 0.8);
        let answer = r#"{"affordances": [
            {"node_id": 5, "affordances": ["hook pull", "lick"], "confidence": 0.9},
            {"node_id": 6, "affordances": ["rotate"], "confidence": 0.7},
            {"node_id": 42, "affordances": ["rotate"], "confidence": 0.7}
        ]}"#;
        let (output, r) = run(Agent::Affordances, answer, &mut mapper);
        let got: Vec<(u32, Vec<&str>)> = output
            .affordances
            .iter()
            .map(|a| (a.node_id, op3dsg_ipc_types::affordance_names(a.affordance_bits).collect()))
            .collect();
        assert_eq!(got, [(5, vec!["hook_pull"]), (6, vec!["rotate"])]);
        assert_eq!((r.get(Rejection::NonCanonical), r.get(Rejection::UnknownNode)), (1, 1));
    }

    /// A stand-in embedder: bag of letters, so "pull open or close" lands nearest "pull to open or
    /// close" and nonsense lands below the threshold.
    struct Letters;
    impl PhraseEmbedder for Letters {
        fn embed(&mut self, phrases: &[&str]) -> Result<Vec<Embedding>, String> {
            Ok(phrases
                .iter()
                .map(|p| {
                    let mut e = [0.0f32; crate::onnx::text_encoder::EMBEDDING_DIM];
                    for w in p.split_whitespace() {
                        let h = w.bytes().fold(7u32, |h, b| h.wrapping_mul(31).wrapping_add(u32::from(b)));
                        e[h as usize % e.len()] += 1.0;
                    }
                    let n = e.iter().map(|x| x * x).sum::<f32>().sqrt().max(1e-6);
                    e.iter_mut().for_each(|x| *x /= n);
                    e
                })
                .collect())
        }
    }

    #[test]
    fn the_nearest_phrase_by_embedding_when_an_encoder_is_configured() {
        let mut mapper = LabelMapper::new(Some(Box::new(Letters)), 0.8);
        assert_eq!(mapper.relation("pull to open or to close"), Some(id("pull to open or close")));
        assert_eq!(mapper.relation("dance wildly"), None);
        let mut plain = LabelMapper::new(None, 0.8);
        assert_eq!(plain.relation("pull to open or to close"), None);
    }
}
