use op3dsg_ipc_types::relation_id;

use super::*;
use crate::embedding::{Embedding, PhraseEmbedder};
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
    let against = Against { prior: &prior, prompts: &prompts, rules: &rules, options };
    let accepted = check(agent, answer, against, mapper, &mut output, &mut log);
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
        [(5, 1, id("pull to open or close"), false), (6, 2, id("rotate to adjust the setting or temperature"), false)]
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
                let mut e = [0.0f32; crate::embedding::EMBEDDING_DIM];
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
