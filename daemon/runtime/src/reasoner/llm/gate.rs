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

use op3dsg_ipc_types::{AFFORDANCES, FUNCTIONAL_RELATION_BASE, FUNCTIONAL_RELATIONS, NodeKind};
use serde::de::Error as _;
use serde::{Deserialize, Deserializer};
use serde_json::{Map, Value};

use super::plausibility::Plausibility;
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

/// How strictly answers are read (`reasoner.llm.ignore_unknown_fields`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ParseOptions {
    /// Fields the schema does not name (on the answer object or on an item) are ignored;
    /// `false`: such an item (or answer) is `malformed`.
    pub ignore_unknown_fields: bool,
}

impl Default for ParseOptions {
    fn default() -> Self {
        Self { ignore_unknown_fields: true }
    }
}

/// At most `max` characters of `text` (for log lines), on a character boundary.
fn snippet(text: &str, max: usize) -> String {
    let text = text.trim();
    match text.char_indices().nth(max) {
        Some((i, _)) => format!("{}...", &text[..i]),
        None => text.to_owned(),
    }
}

/// Every top-level JSON object in `text`, scanning from each `{` not inside an object found
/// already (prose braces that open no valid JSON are skipped).
fn objects_in(text: &str) -> Vec<Map<String, Value>> {
    let mut found = Vec::new();
    let mut from = 0;
    while let Some(offset) = text[from..].find('{') {
        let start = from + offset;
        let mut stream = serde_json::Deserializer::from_str(&text[start..]).into_iter::<Value>();
        match stream.next() {
            Some(Ok(Value::Object(object))) => {
                found.push(object);
                from = start + stream.byte_offset();
            }
            _ => from = start + 1,
        }
    }
    found
}

/// The contents of each markdown code fence (```` ```json ... ``` ````, the language tag
/// dropped).
fn fenced_blocks(text: &str) -> Vec<&str> {
    let mut blocks = Vec::new();
    let mut rest = text;
    while let Some(open) = rest.find("```") {
        let after = &rest[open + 3..];
        // The language tag runs to the end of the opening line.
        let body_start = after.find('\n').map_or(after.len(), |i| i + 1);
        let tag = &after[..body_start];
        let (body, next) = if tag.trim_start().starts_with('{') {
            // ```{...}``` on one line: no tag.
            (after, 0)
        } else {
            (&after[body_start..], body_start)
        };
        let Some(close) = body.find("```") else { break };
        blocks.push(&body[..close]);
        rest = &after[next + close + 3..];
    }
    blocks
}

/// The one JSON object in a model's answer: the whole answer when it is one; else the one
/// fenced code block holding an object; else the one top-level object in the prose around it.
/// An answer with none, or with several (which one is meant is ambiguous), is an error that
/// says so, with the strict parser's message.
pub fn extract_object(answer: &str) -> Result<Map<String, Value>, String> {
    let text = answer.trim().trim_start_matches('\u{feff}');
    let strict_error = match serde_json::from_str::<Value>(text) {
        Ok(Value::Object(object)) => return Ok(object),
        Ok(other) => {
            let kind = match other {
                Value::Array(_) => "an array",
                Value::String(_) => "a string",
                Value::Number(_) => "a number",
                Value::Bool(_) => "a boolean",
                _ => "null",
            };
            return Err(format!("the answer is {kind}, not a JSON object"));
        }
        Err(e) => e,
    };
    let fenced: Vec<Map<String, Value>> = fenced_blocks(text)
        .into_iter()
        .filter_map(|b| serde_json::from_str::<Map<String, Value>>(b.trim()).ok())
        .collect();
    let mut objects = if fenced.is_empty() { objects_in(text) } else { fenced };
    match objects.len() {
        1 => Ok(objects.remove(0)),
        0 => Err(format!("no JSON object in the answer ({strict_error}): {:?}", snippet(text, 80))),
        n => Err(format!("{n} JSON objects in the answer; which one is meant is ambiguous")),
    }
}

/// A node id: a JSON unsigned integer, an integral number (`5.0`) or a string holding one
/// (`"5"`); anything else (`"five"`, `-5`, `5.5`) is an error.
fn lenient_id<'de, D: Deserializer<'de>>(deserializer: D) -> Result<u32, D::Error> {
    let value = Value::deserialize(deserializer)?;
    let id = match &value {
        Value::Number(n) => n.as_u64().or_else(|| {
            n.as_f64().filter(|f| f.fract() == 0.0 && *f >= 0.0 && *f <= f64::from(u32::MAX)).map(|f| f as u64)
        }),
        Value::String(s) => s.trim().parse::<u32>().ok().map(u64::from),
        _ => None,
    };
    id.and_then(|id| u32::try_from(id).ok())
        .ok_or_else(|| D::Error::custom(format!("expected a node id (an unsigned integer), got {value}")))
}

/// A confidence: a JSON number or a string holding exactly one (`"0.9"`); the range is checked
/// by the gate.
fn lenient_number<'de, D: Deserializer<'de>>(deserializer: D) -> Result<f64, D::Error> {
    let value = Value::deserialize(deserializer)?;
    match &value {
        Value::Number(n) => n.as_f64(),
        Value::String(s) => s.trim().parse::<f64>().ok().filter(|f| f.is_finite()),
        _ => None,
    }
    .ok_or_else(|| D::Error::custom(format!("expected a number, got {value}")))
}

#[derive(Deserialize)]
struct LocalItem {
    #[serde(deserialize_with = "lenient_id")]
    part_id: u32,
    #[serde(deserialize_with = "lenient_id")]
    object_id: u32,
    relation: String,
    #[serde(deserialize_with = "lenient_number")]
    confidence: f64,
}

#[derive(Deserialize)]
struct RemoteItem {
    #[serde(deserialize_with = "lenient_id")]
    source_id: u32,
    #[serde(deserialize_with = "lenient_id")]
    target_id: u32,
    relation: String,
    #[serde(deserialize_with = "lenient_number")]
    confidence: f64,
}

#[derive(Deserialize)]
struct AffordanceItem {
    #[serde(deserialize_with = "lenient_id")]
    node_id: u32,
    affordances: Vec<String>,
    #[serde(deserialize_with = "lenient_number")]
    confidence: f64,
}

/// An agent's answer object parsed: the list under `list_key`, each item deserialised on its
/// own (a bad item is `malformed` without spoiling the others). `Err`: the answer as a whole is
/// unusable (no object, no list).
fn parse_items<T: serde::de::DeserializeOwned>(
    agent: Agent,
    answer: &str,
    list_key: &str,
    fields: &[&str],
    options: ParseOptions,
    log: &mut RejectionLog,
) -> Result<Vec<T>, ()> {
    let name = agent.name();
    let mut object = match extract_object(answer) {
        Ok(object) => object,
        Err(e) => {
            log.reject(Rejection::Malformed, || format!("{name}: {e}"));
            return Err(());
        }
    };
    if !options.ignore_unknown_fields
        && let Some(extra) = object.keys().find(|k| *k != list_key)
    {
        log.reject(Rejection::Malformed, || format!("{name}: unknown field {extra:?} (ignore_unknown_fields = false)"));
        return Err(());
    }
    let Some(Value::Array(items)) = object.remove(list_key) else {
        log.reject(Rejection::Malformed, || format!("{name}: the answer object has no {list_key:?} list"));
        return Err(());
    };
    let mut parsed = Vec::with_capacity(items.len());
    for (i, item) in items.into_iter().enumerate() {
        if !options.ignore_unknown_fields
            && let Some(extra) = item.as_object().and_then(|o| o.keys().find(|k| !fields.contains(&k.as_str())))
        {
            log.reject(Rejection::Malformed, || {
                format!("{name}: {list_key}[{i}]: unknown field {extra:?} (ignore_unknown_fields = false)")
            });
            continue;
        }
        match serde_json::from_value::<T>(item) {
            Ok(item) => parsed.push(item),
            Err(e) => log.reject(Rejection::Malformed, || format!("{name}: {list_key}[{i}]: {e}")),
        }
    }
    Ok(parsed)
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

/// Checks one agent's answer against the graph version `prompts` was built from; accepted items
/// are added to `output`, rejections to `log`. Returns how many items were accepted, or `None`
/// when the answer as a whole is unusable (no JSON object, no list: counted once as
/// `malformed`), which the refiner treats like a failed call.
#[allow(clippy::too_many_arguments)]
pub fn check(
    agent: Agent,
    answer: &str,
    prior: &PriorGraph,
    prompts: &PromptSet,
    mapper: &mut LabelMapper,
    options: ParseOptions,
    rules: &Plausibility,
    output: &mut ReasonerOutput,
    log: &mut RejectionLog,
) -> Option<u64> {
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

#[cfg(test)]
mod tests {
    use op3dsg_ipc_types::relation_id;

    use super::*;
    use crate::reasoner::llm::prompt::{self, tests::corner_prior};

    fn run(agent: Agent, answer: &str, mapper: &mut LabelMapper) -> (ReasonerOutput, RejectionLog) {
        run_with(agent, answer, mapper, ParseOptions::default()).0
    }

    fn run_with(
        agent: Agent,
        answer: &str,
        mapper: &mut LabelMapper,
        options: ParseOptions,
    ) -> ((ReasonerOutput, RejectionLog), Option<u64>) {
        let (prior, kb) = corner_prior();
        let prompts = prompt::build(&prior, &kb, 400);
        let mut output = ReasonerOutput { graph_version: prior.version, ..ReasonerOutput::default() };
        let mut log = RejectionLog::default();
        let rules = Plausibility::new(&Default::default(), std::sync::Arc::new(kb));
        let accepted = check(agent, answer, &prior, &prompts, mapper, options, &rules, &mut output, &mut log);
        ((output, log), accepted)
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

    const PLAIN: &str =
        r#"{"relations": [{"part_id": 5, "object_id": 1, "relation": "pull to open or close", "confidence": 0.9}]}"#;

    #[test]
    fn answers_as_models_write_them_give_the_same_relations() {
        let mut mapper = LabelMapper::new(None, 0.8);
        let (plain, r) = run(Agent::Local, PLAIN, &mut mapper);
        assert_eq!((plain.functional.len(), r.total()), (1, 0));
        for answer in [
            format!("```json\n{PLAIN}\n```"),
            format!("```\n{PLAIN}\n```"),
            format!("Here are the relations I found:\n\n```json\n{PLAIN}\n```\n\nLet me know if you need more."),
            format!("Sure! {PLAIN} These are all I am confident of."),
            format!("\u{feff}  {PLAIN}\n"),
            r#"{"relations": [{"part_id": 5, "object_id": 1, "relation": "pull to open or close", "confidence": 0.9, "reason": "handles are pulled"}], "notes": "x"}"#.to_owned(),
            r#"{"relations": [{"part_id": "5", "object_id": 1.0, "relation": "pull to open or close", "confidence": "0.9"}]}"#.to_owned(),
        ] {
            let (output, r) = run(Agent::Local, &answer, &mut mapper);
            assert_eq!(output, plain, "{answer}");
            assert_eq!(r.total(), 0, "{answer}: {:?}", r.examples);
        }
    }

    #[test]
    fn no_object_or_several_make_the_answer_unusable_with_the_reason() {
        let mut mapper = LabelMapper::new(None, 0.8);
        for (answer, says) in [
            ("Here are the relations: {relations: [handle -> cabinet]}", "no JSON object"),
            ("", "no JSON object"),
            ("[1, 2]", "an array"),
            (r#"{"relations": []} and also {"relations": []}"#, "2 JSON objects"),
            ("```json\n{\"relations\": []}\n```\n```json\n{\"relations\": []}\n```", "2 JSON objects"),
            (r#"{"answer": []}"#, "no \"relations\" list"),
        ] {
            let ((output, r), accepted) = run_with(Agent::Local, answer, &mut mapper, ParseOptions::default());
            assert!(output.functional.is_empty() && accepted.is_none(), "{answer}");
            assert_eq!((r.get(Rejection::Malformed), r.total()), (1, 1), "{answer}");
            let example = r.examples[Rejection::Malformed as usize].as_deref().unwrap();
            assert!(example.starts_with("local_relations: ") && example.contains(says), "{answer}: {example}");
        }
        // The strict parser's message travels with it.
        let (_, r) = run(Agent::Local, "not json", &mut mapper);
        assert!(r.examples[0].as_deref().unwrap().contains("expected"), "{:?}", r.examples);
    }

    #[test]
    fn a_bad_item_is_malformed_without_spoiling_the_others() {
        let mut mapper = LabelMapper::new(None, 0.8);
        let answer = r#"{"relations": [
            {"part_id": "five", "object_id": 1, "relation": "pull to open or close", "confidence": 0.5},
            {"part_id": -5, "object_id": 1, "relation": "pull to open or close", "confidence": 0.5},
            {"part_id": 5.5, "object_id": 1, "relation": "pull to open or close", "confidence": 0.5},
            {"part_id": 5, "object_id": 1, "relation": "pull to open or close"},
            {"part_id": 5, "object_id": 1, "relation": "pull to open or close", "confidence": "high"},
            {"part_id": 5, "object_id": 1, "relation": "pull to open or close", "confidence": 0.9}
        ]}"#;
        let ((output, r), accepted) = run_with(Agent::Local, answer, &mut mapper, ParseOptions::default());
        assert_eq!((output.functional.len(), accepted), (1, Some(1)));
        assert_eq!((r.get(Rejection::Malformed), r.total()), (5, 5));
        let example = r.examples[0].as_deref().unwrap();
        assert!(example.starts_with("local_relations: relations[0]: expected a node id"), "{example}");
    }

    #[test]
    fn unknown_fields_are_rejected_when_the_profile_says_so() {
        let mut mapper = LabelMapper::new(None, 0.8);
        let strict = ParseOptions { ignore_unknown_fields: false };
        let extra = r#"{"relations": [
            {"part_id": 5, "object_id": 1, "relation": "pull to open or close", "confidence": 0.9, "why": "x"},
            {"part_id": 6, "object_id": 2, "relation": "rotate to adjust the setting or temperature", "confidence": 0.8}
        ]}"#;
        let ((output, r), _) = run_with(Agent::Local, extra, &mut mapper, strict);
        assert_eq!((output.functional.len(), r.get(Rejection::Malformed)), (1, 1));
        assert!(r.examples[0].as_deref().unwrap().contains("unknown field \"why\""), "{:?}", r.examples);
        let ((_, r), accepted) = run_with(Agent::Local, r#"{"relations": [], "notes": ""}"#, &mut mapper, strict);
        assert_eq!((accepted, r.get(Rejection::Malformed)), (None, 1));
        let ((output, r), _) = run_with(Agent::Local, PLAIN, &mut mapper, strict);
        assert_eq!((output.functional.len(), r.total()), (1, 0));
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
