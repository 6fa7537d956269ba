//! What the refiner hands the fusion thread: each agent's last accepted result, kept per agent.
//!
//! An agent's result is replaced only when that agent answers again (with a usable answer) for
//! a graph version at least as new; a failed call, a refused one (breaker, budget) or an
//! unusable answer changes nothing accepted. Every result names the graph version it was
//! computed on and the kind (and parent) each node it names had then; before it is applied to
//! a later graph, each item is re-checked against that graph ([`AgentResult::retain_valid`]):
//! its nodes must still be there with the same kind, and a local relation's part must still be
//! a part of its object. Items that fail are dropped for good (counted `stale`).

use op3dsg_ipc_types::NodeKind;
use rustc_hash::FxHashMap;

use super::prompt::Agent;
use crate::prior::PriorGraph;
use crate::reasoner::ReasonerOutput;

/// A node as an item saw it: its kind and parent.
pub type NodeFacts = (NodeKind, Option<u32>);

/// One agent's accepted items.
#[derive(Debug, Clone, PartialEq)]
pub struct AgentResult {
    /// The agent.
    pub agent: Agent,
    /// Version of the graph its prompt was built from.
    pub graph_version: u64,
    /// Its accepted items (functional relations, or affordances).
    pub output: ReasonerOutput,
    /// Kind and parent of every node its items name, in that graph version.
    pub nodes: FxHashMap<u32, NodeFacts>,
}

impl AgentResult {
    /// `output` as computed on `prior`, with the facts of the nodes it names.
    pub fn new(agent: Agent, prior: &PriorGraph, output: ReasonerOutput) -> Self {
        let mut nodes = FxHashMap::default();
        let ids = output
            .functional
            .iter()
            .flat_map(|r| [r.source_id, r.target_id])
            .chain(output.affordances.iter().map(|a| a.node_id));
        for id in ids {
            if let Some(i) = prior.index_of(id) {
                nodes.insert(id, (prior.nodes[i].kind, prior.nodes[i].parent_id));
            }
        }
        Self { agent, graph_version: prior.version, output, nodes }
    }

    /// Keeps the items whose nodes `now` still knows with the kind they had (and, for a local
    /// relation, the part still a part of its object); returns how many were dropped.
    pub fn retain_valid(&mut self, now: impl Fn(u32) -> Option<NodeFacts>) -> usize {
        let same_kind = |id: u32| match (self.nodes.get(&id), now(id)) {
            (Some(then), Some(now)) => then.0 == now.0,
            _ => false,
        };
        let before = self.output.functional.len() + self.output.affordances.len();
        self.output.functional.retain(|r| {
            same_kind(r.source_id)
                && same_kind(r.target_id)
                && (r.remote || now(r.source_id).is_some_and(|(_, parent)| parent == Some(r.target_id)))
        });
        self.output.affordances.retain(|a| same_kind(a.node_id));
        before - self.output.functional.len() - self.output.affordances.len()
    }

    /// Items held.
    pub fn len(&self) -> usize {
        self.output.functional.len() + self.output.affordances.len()
    }

    /// No items held.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }
}

/// Every agent's last accepted result (at most one per agent).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct LlmResult {
    /// Version of the graph the refresh that sent it was for (the newest prompt built).
    pub graph_version: u64,
    /// Per agent, in [`Agent::ALL`] order of arrival; at most one each.
    pub agents: Vec<AgentResult>,
}

impl LlmResult {
    /// Takes `result` as its agent's new result, unless the one held was computed on a newer
    /// graph version.
    pub fn accept(&mut self, result: AgentResult) {
        match self.agents.iter_mut().find(|a| a.agent == result.agent) {
            Some(held) if held.graph_version > result.graph_version => {}
            Some(held) => *held = result,
            None => self.agents.push(result),
        }
    }

    /// [`AgentResult::retain_valid`] on every agent's result; how many items were dropped.
    pub fn retain_valid(&mut self, now: impl Fn(u32) -> Option<NodeFacts>) -> usize {
        self.agents.iter_mut().map(|a| a.retain_valid(&now)).sum()
    }

    /// Every agent's items as one output (named after [`LlmResult::graph_version`]).
    pub fn merged(&self) -> ReasonerOutput {
        let mut output = ReasonerOutput { graph_version: self.graph_version, ..ReasonerOutput::default() };
        for a in &self.agents {
            output.functional.extend(a.output.functional.iter().cloned());
            output.affordances.extend(a.output.affordances.iter().cloned());
            output.spatial_corrections.extend(a.output.spatial_corrections.iter().cloned());
        }
        output
    }

    /// The result held for `agent`.
    pub fn agent(&self, agent: Agent) -> Option<&AgentResult> {
        self.agents.iter().find(|a| a.agent == agent)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::reasoner::llm::prompt::tests::corner_prior;
    use crate::reasoner::{FunctionalRelation, NodeAffordances};

    fn local(version: u64, relation_id: u16) -> AgentResult {
        let (mut prior, _) = corner_prior();
        prior.version = version;
        let output = ReasonerOutput {
            functional: vec![FunctionalRelation {
                source_id: 5,
                target_id: 1,
                relation_id,
                confidence: 0.9,
                remote: false,
            }],
            affordances: vec![NodeAffordances { node_id: 5, affordance_bits: 1, confidence: 0.9 }],
            ..ReasonerOutput::default()
        };
        AgentResult::new(Agent::Local, &prior, output)
    }

    #[test]
    fn an_agent_result_is_replaced_only_by_one_at_least_as_new() {
        let mut held = LlmResult::default();
        held.accept(local(7, 100));
        held.accept(local(5, 101));
        assert_eq!(held.agent(Agent::Local).unwrap().output.functional[0].relation_id, 100, "older loses");
        held.accept(local(9, 102));
        assert_eq!(held.agents.len(), 1);
        assert_eq!(held.agent(Agent::Local).unwrap().output.functional[0].relation_id, 102);
    }

    #[test]
    fn items_are_rechecked_against_the_graph_they_are_applied_to() {
        let (prior, _) = corner_prior();
        let facts = |id: u32| prior.index_of(id).map(|i| (prior.nodes[i].kind, prior.nodes[i].parent_id));
        let mut r = local(7, 100);
        assert_eq!(r.retain_valid(facts), 0);
        assert_eq!(r.len(), 2);
        // The handle became an object: its relation and its affordance are both dropped.
        let relabelled = |id: u32| if id == 5 { Some((NodeKind::Object, None)) } else { facts(id) };
        assert_eq!(r.clone().retain_valid(relabelled), 2);
        // The handle now hangs off another object: the local relation goes, the affordance stays.
        let moved = |id: u32| if id == 5 { Some((NodeKind::Part, Some(2))) } else { facts(id) };
        let mut m = r.clone();
        assert_eq!(m.retain_valid(moved), 1);
        assert_eq!((m.output.functional.len(), m.output.affordances.len()), (0, 1));
        // The cabinet is gone.
        let gone = |id: u32| if id == 1 { None } else { facts(id) };
        assert_eq!(r.retain_valid(gone), 1);
    }
}
