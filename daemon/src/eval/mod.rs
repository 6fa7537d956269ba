//! Evaluation against synthetic ground truth.
//!
//! | module | what |
//! |---|---|
//! | [`fusion_match`] | fused nodes ↔ ground-truth nodes: matched fraction, fragmentation, wrong merges, false positives, and which stage lost each missed node |
//! | [`ablation`] | the colour-feature ablation on the `colour_panel` scene |
//!
//! The benchmark's evaluator (node / part / affordance / triplet recall at K) will live here too.

pub mod ablation;
pub mod fusion_match;
