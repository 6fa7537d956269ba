//! Reading a model's answer: the one JSON object in it (whole, fenced, or in prose), and each
//! agent's items deserialised leniently one by one.

use serde::de::Error as _;
use serde::{Deserialize, Deserializer};
use serde_json::{Map, Value};

use super::super::prompt::Agent;
use super::{Rejection, RejectionLog};

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
pub(super) fn snippet(text: &str, max: usize) -> String {
    let text = text.trim();
    match text.char_indices().nth(max) {
        Some((i, _)) => format!("{}...", &text[..i]),
        None => text.to_owned(),
    }
}

/// Every top-level JSON object in `text`, scanning from each `{` not inside an object found
/// already (prose braces that open no valid JSON are skipped).
pub(super) fn objects_in(text: &str) -> Vec<Map<String, Value>> {
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
pub(super) fn fenced_blocks(text: &str) -> Vec<&str> {
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
pub(super) fn lenient_id<'de, D: Deserializer<'de>>(deserializer: D) -> Result<u32, D::Error> {
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
pub(super) fn lenient_number<'de, D: Deserializer<'de>>(deserializer: D) -> Result<f64, D::Error> {
    let value = Value::deserialize(deserializer)?;
    match &value {
        Value::Number(n) => n.as_f64(),
        Value::String(s) => s.trim().parse::<f64>().ok().filter(|f| f.is_finite()),
        _ => None,
    }
    .ok_or_else(|| D::Error::custom(format!("expected a number, got {value}")))
}

/// A local relation as an agent answers it.
#[derive(Deserialize)]
pub(super) struct LocalItem {
    #[serde(deserialize_with = "lenient_id")]
    pub(super) part_id: u32,
    #[serde(deserialize_with = "lenient_id")]
    pub(super) object_id: u32,
    pub(super) relation: String,
    #[serde(deserialize_with = "lenient_number")]
    pub(super) confidence: f64,
}

/// A remote relation as an agent answers it.
#[derive(Deserialize)]
pub(super) struct RemoteItem {
    #[serde(deserialize_with = "lenient_id")]
    pub(super) source_id: u32,
    #[serde(deserialize_with = "lenient_id")]
    pub(super) target_id: u32,
    pub(super) relation: String,
    #[serde(deserialize_with = "lenient_number")]
    pub(super) confidence: f64,
}

/// A node's affordances as an agent answers them.
#[derive(Deserialize)]
pub(super) struct AffordanceItem {
    #[serde(deserialize_with = "lenient_id")]
    pub(super) node_id: u32,
    pub(super) affordances: Vec<String>,
    #[serde(deserialize_with = "lenient_number")]
    pub(super) confidence: f64,
}

/// An agent's answer object parsed: the list under `list_key`, each item deserialised on its
/// own (a bad item is `malformed` without spoiling the others). `Err`: the answer as a whole is
/// unusable (no object, no list).
pub(super) fn parse_items<T: serde::de::DeserializeOwned>(
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
