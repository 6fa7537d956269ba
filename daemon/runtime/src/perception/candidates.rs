//! Knowledge-guided object/part candidates (paper, "Object/Part Candidates"): the prompt list an
//! open-vocabulary detector is asked for in one frame.
//!
//! An image tagger yields the frame's object tags `C^o_t`. For each tag `c` naming an object
//! category of the knowledge base, the category's interactive parts `K(c)` become part prompts
//! in the object-conditioned form the paper uses (`oven` → `oven button`, `oven handle`), and
//! the final list is `C_t = C^o_t ∪ C^p_t`. A fixed list of small things a tagger tends to miss
//! ([`SMALL_THING_PROMPTS`]: light switches, outlets, remotes; informed by the `small_object`
//! list of the public object-part table in `../shared/data/reference/`) is always added.
//!
//! [`CandidateMode::Generic`] is the paper's ablation "without knowledge-guided part
//! candidates": the part prompts are a fixed generic vocabulary ([`GENERIC_PART_PROMPTS`]:
//! `handle`, `knob`, `button`, `switch`) whatever the tags. [`CandidateMode::All`] asks for
//! nothing in particular: a detector that gets no list reports every part it sees (the oracle's
//! default behaviour).
//!
//! Every [`Prompt`] carries what it names in the knowledge base (part category and, for an
//! object-conditioned prompt, the object category), so a detector that works from categories
//! (the synthetic oracle) and one that works from text (an open-vocabulary ONNX detector) can
//! take the same list.
//!
//! ```
//! use std::sync::Arc;
//! use op3dsg_runtime::knowledge::KnowledgeBase;
//! use op3dsg_runtime::perception::candidates::{CandidateMode, PartCandidates, PromptList};
//! let kb = Arc::new(KnowledgeBase::builtin().unwrap());
//! let candidates = PartCandidates::new(kb, CandidateMode::Knowledge);
//! let mut list = PromptList::default();
//! candidates.prompts(&["cabinet", "stove"], &mut list);
//! assert!(list.texts().any(|t| t == "cabinet handle"));
//! assert!(list.texts().any(|t| t == "stove knob"));
//! ```

use std::sync::Arc;

use op3dsg_ipc_types::NodeKind;
use serde::{Deserialize, Serialize};

use crate::knowledge::{Category, KnowledgeBase, ObjectId, PartId, normalise};

/// The generic part vocabulary of the ablation without knowledge-guided candidates.
pub const GENERIC_PART_PROMPTS: [&str; 4] = ["handle", "knob", "button", "switch"];
/// Small things added to every list (a tagger sees the room, not the switch on its wall).
pub const SMALL_THING_PROMPTS: [&str; 3] = ["light switch", "power outlet", "remote control"];

/// Which part prompts a frame's list gets (`detector.oracle.part_prompts`).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum CandidateMode {
    /// No list: the detector reports every part it sees.
    #[default]
    All,
    /// Tags plus the knowledge base's parts of each tagged object (the paper's method).
    Knowledge,
    /// Tags plus the fixed generic part vocabulary (the paper's ablation).
    Generic,
}

impl CandidateMode {
    /// The name used in profiles and tables.
    pub fn as_str(self) -> &'static str {
        match self {
            CandidateMode::All => "all",
            CandidateMode::Knowledge => "knowledge",
            CandidateMode::Generic => "generic",
        }
    }
}

/// One prompt of a list.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Prompt {
    /// The text a detector is prompted with (normalised: lower case, single spaces).
    pub text: String,
    /// Whether it asks for objects or parts.
    pub kind: NodeKind,
    /// The part category it names (parts only; `None` when the knowledge base does not know it).
    pub part: Option<PartId>,
    /// The object category it names (objects), or conditions on (object-conditioned parts).
    pub object: Option<ObjectId>,
}

/// A frame's prompt list (reused between frames).
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct PromptList {
    /// The prompts, tags first, without duplicate texts.
    pub prompts: Vec<Prompt>,
}

impl PromptList {
    /// The prompt texts in order.
    pub fn texts(&self) -> impl Iterator<Item = &str> {
        self.prompts.iter().map(|p| p.text.as_str())
    }

    /// Whether a prompt has this (normalised) text.
    pub fn contains(&self, text: &str) -> bool {
        self.prompts.iter().any(|p| p.text == text)
    }

    /// Appends `prompt` unless a prompt has its text already.
    pub fn push(&mut self, prompt: Prompt) {
        if !self.contains(&prompt.text) {
            self.prompts.push(prompt);
        }
    }
}

/// Builds prompt lists from tags (see the module docs).
#[derive(Debug, Clone)]
pub struct PartCandidates {
    knowledge: Arc<KnowledgeBase>,
    mode: CandidateMode,
    /// Prompts every list gets after the tags' own.
    fixed: Vec<Prompt>,
}

impl PartCandidates {
    /// Candidates in `mode` from `knowledge`.
    pub fn new(knowledge: Arc<KnowledgeBase>, mode: CandidateMode) -> Self {
        let mut fixed = Vec::new();
        if mode == CandidateMode::Generic {
            fixed.extend(GENERIC_PART_PROMPTS.iter().map(|t| Self::prompt_for(&knowledge, t)));
        }
        if mode != CandidateMode::All {
            fixed.extend(SMALL_THING_PROMPTS.iter().map(|t| Self::prompt_for(&knowledge, t)));
        }
        Self { knowledge, mode, fixed }
    }

    /// The mode.
    pub fn mode(&self) -> CandidateMode {
        self.mode
    }

    /// The knowledge base.
    pub fn knowledge(&self) -> &KnowledgeBase {
        &self.knowledge
    }

    /// A prompt for `text`, resolved against the knowledge base.
    fn prompt_for(knowledge: &KnowledgeBase, text: &str) -> Prompt {
        let text = normalise(text);
        match knowledge.resolve(&text) {
            Some(r) => match r.category {
                Category::Object(object) => Prompt { text, kind: NodeKind::Object, part: None, object: Some(object) },
                Category::Part(part) => Prompt { text, kind: NodeKind::Part, part: Some(part), object: r.object_hint },
            },
            None => Prompt { text, kind: NodeKind::Object, part: None, object: None },
        }
    }

    /// `C_t` for the frame's `tags` into `out` (cleared first). With [`CandidateMode::All`] the
    /// list is the tags alone; a detector given such a list with `All` should not filter parts.
    pub fn prompts(&self, tags: &[&str], out: &mut PromptList) {
        out.prompts.clear();
        for tag in tags {
            out.push(Self::prompt_for(&self.knowledge, tag));
        }
        if self.mode == CandidateMode::Knowledge {
            for tag in tags {
                let tag = normalise(tag);
                let Some(object) = self.knowledge.object_category(&tag) else { continue };
                for pair in self.knowledge.parts_of(object) {
                    let part = self.knowledge.part(pair.part);
                    out.push(Prompt {
                        text: format!("{tag} {}", part.name),
                        kind: NodeKind::Part,
                        part: Some(pair.part),
                        object: Some(object),
                    });
                }
            }
        }
        for prompt in &self.fixed {
            out.push(prompt.clone());
        }
    }
}

/// How a detector working from categories decides whether a prompt list asks for a part
/// instance, and under which label it reports it.
///
/// A part with canonical label `label`, knowledge-base part category `part` and parent object
/// category `parent` is asked for when, first match wins:
/// 1. a prompt's text is one of `accepted_labels` (its own name or a synonym): reported under
///    its own label;
/// 2. an object-conditioned prompt names its part category and its parent's category
///    (`nightstand knob` for the knob of a nightstand; a parentless part matches a prompt with
///    no object): reported under the prompt's text;
/// 3. a prompt without object names its part category, or is its label's last word (`switch`
///    for `lamp switch`): reported under the prompt's text (the generic vocabulary).
///
/// Otherwise the detector does not find it. `None` means not asked for; `Some(None)` asked for
/// under its own label; `Some(Some(text))` under `text`.
pub fn match_part<'a>(
    list: &'a PromptList,
    accepted_labels: &[String],
    part: Option<PartId>,
    parent: Option<ObjectId>,
    label: &str,
) -> Option<Option<&'a str>> {
    if list.prompts.iter().any(|p| accepted_labels.contains(&p.text)) {
        return Some(None);
    }
    if let Some(part) = part
        && let Some(p) = list.prompts.iter().find(|p| p.part == Some(part) && p.object == parent)
    {
        return Some(Some(p.text.as_str()));
    }
    let head = label.rsplit(' ').next().unwrap_or(label);
    list.prompts
        .iter()
        .find(|p| {
            p.kind == NodeKind::Part && p.object.is_none() && ((part.is_some() && p.part == part) || p.text == head)
        })
        .map(|p| Some(p.text.as_str()))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn candidates(mode: CandidateMode) -> PartCandidates {
        PartCandidates::new(Arc::new(KnowledgeBase::builtin().unwrap()), mode)
    }

    fn texts(list: &PromptList) -> Vec<&str> {
        list.texts().collect()
    }

    #[test]
    fn knowledge_expands_each_tag_into_its_parts() {
        let c = candidates(CandidateMode::Knowledge);
        let mut list = PromptList::default();
        c.prompts(&["cabinet", "stove", "sofa"], &mut list);
        let t = texts(&list);
        assert_eq!(&t[..3], ["cabinet", "stove", "sofa"], "tags first");
        for expected in ["cabinet handle", "cabinet knob", "stove knob", "stove handle", "light switch", "power outlet"]
        {
            assert!(t.contains(&expected), "{expected} missing from {t:?}");
        }
        assert!(!t.contains(&"handle"), "no generic prompts: {t:?}");
        // Object-conditioned prompts carry both categories.
        let knob = list.prompts.iter().find(|p| p.text == "stove knob").unwrap();
        assert_eq!(knob.kind, NodeKind::Part);
        assert_eq!(knob.object, c.knowledge().object_category("stove"));
        assert_eq!(knob.part, c.knowledge().resolve("knob").and_then(|r| r.part()));
        // No duplicates when a tag repeats.
        let before = list.prompts.len();
        c.prompts(&["cabinet", "stove", "sofa", "cabinet"], &mut list);
        assert_eq!(list.prompts.len(), before);
    }

    #[test]
    fn generic_mode_uses_the_fixed_vocabulary() {
        let c = candidates(CandidateMode::Generic);
        let mut list = PromptList::default();
        c.prompts(&["cabinet", "stove"], &mut list);
        let t = texts(&list);
        for expected in GENERIC_PART_PROMPTS {
            assert!(t.contains(&expected), "{expected} missing from {t:?}");
        }
        assert!(!t.contains(&"cabinet handle") && !t.contains(&"stove knob"), "{t:?}");
        // All: tags only.
        candidates(CandidateMode::All).prompts(&["cabinet"], &mut list);
        assert_eq!(texts(&list), ["cabinet"]);
    }

    #[test]
    fn parts_are_matched_by_label_category_or_generic_head() {
        let kb = KnowledgeBase::builtin().unwrap();
        let cat = |l: &str| kb.resolve(l).and_then(|r| r.part());
        let obj = |l: &str| kb.object_category(l);
        let labels = |l: &[&str]| l.iter().map(|s| (*s).to_owned()).collect::<Vec<_>>();
        let knowledge = candidates(CandidateMode::Knowledge);
        let mut list = PromptList::default();
        knowledge.prompts(&["cabinet", "nightstand", "sink"], &mut list);
        // Exact label: own label.
        let m =
            match_part(&list, &labels(&["cabinet handle"]), cat("cabinet handle"), obj("cabinet"), "cabinet handle");
        assert_eq!(m, Some(None));
        // The knob of a nightstand, called "drawer knob": found by the nightstand's prompt.
        let m = match_part(&list, &labels(&["drawer knob"]), cat("drawer knob"), obj("nightstand"), "drawer knob");
        assert_eq!(m, Some(Some("nightstand knob")));
        // A faucet on the sink.
        let m = match_part(&list, &labels(&["faucet", "tap"]), cat("faucet"), obj("sink"), "faucet");
        assert_eq!(m, Some(Some("sink faucet")));
        // A stove knob with no stove tagged: not asked for.
        let m = match_part(&list, &labels(&["stove knob"]), cat("stove knob"), obj("stove"), "stove knob");
        assert_eq!(m, None);
        // A wall switch: the small-thing prompt.
        let m = match_part(&list, &labels(&["light switch"]), cat("light switch"), None, "light switch");
        assert_eq!(m, Some(None));

        let generic = candidates(CandidateMode::Generic);
        generic.prompts(&["cabinet", "stove", "sink"], &mut list);
        let m =
            match_part(&list, &labels(&["cabinet handle"]), cat("cabinet handle"), obj("cabinet"), "cabinet handle");
        assert_eq!(m, Some(Some("handle")));
        let m = match_part(&list, &labels(&["stove knob"]), cat("stove knob"), obj("stove"), "stove knob");
        assert_eq!(m, Some(Some("knob")));
        let m = match_part(&list, &labels(&["lamp switch"]), cat("lamp switch"), obj("lamp"), "lamp switch");
        assert_eq!(m, Some(Some("switch")));
        // No generic word for a faucet: missed.
        let m = match_part(&list, &labels(&["faucet"]), cat("faucet"), obj("sink"), "faucet");
        assert_eq!(m, None);
    }
}
