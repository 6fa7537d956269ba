//! Evaluation against synthetic ground truth.
//!
//! | module | what |
//! |---|---|
//! | [`fusion_match`] | fused nodes ↔ ground-truth nodes: matched fraction, fragmentation, wrong merges, false positives, and which stage lost each missed node |
//! | [`agreement`] | how often the knowledge base gives the synthetic ground truth's functional relations and affordances (reasoner on ground-truth nodes) |
//! | [`ablation`] | the colour-feature ablation on the `colour_panel` scene |
//! | [`curves`] | `bench quality --curves`: the full row's R@3 against pose drift and against category confusion |
//! | [`benchmark`] | the synthetic quality benchmark (`op3dsg bench quality`): scenes, ablation rows, where recall is lost |
//! | [`nav_bench`] | the navigation check (`op3dsg bench nav`): approach poses of every mapped node against the rooms' true geometry; occupancy cost and memory |
//! | [`recall`] | the benchmark's protocol: node, affordance, triplet and associated-node recall at K |

pub mod ablation;
pub mod agreement;
pub mod benchmark;
pub mod change_bench;
pub mod coverage;
pub mod curves;
pub mod fusion_match;
pub mod nav_bench;
pub mod parallel;
pub mod query_bench;
pub mod recall;
