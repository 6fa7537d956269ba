//! # op3dsg simulation and evaluation
//!
//! Everything that needs ground truth, kept out of the runtime (`op3dsg-runtime`), which it
//! builds on and never the other way round:
//!
//! | module | what |
//! |---|---|
//! | [`annotate`] | `op3dsg annotate`: ground truth for a recorded sequence from hand-drawn 2D boxes, lifted with its depth and poses |
//! | [`backends`] | the `synthetic` source and the `oracle` detector, registered with the runtime like any other backend; their profile sections |
//! | [`oracle`] | the oracle detector: the synthetic renderer's instance ids (from the ground-truth side channel) with configurable noise |
//! | [`batch`] | the deterministic single-thread runner: source → keyframe gate → the runtime's keyframe path, with ground-truth counts |
//! | [`eval`] | scoring fused graphs against ground truth: the benchmark's recall protocol, fusion matching, the quality benchmark |
//! | [`perf`] | `op3dsg bench perf`: pipeline, IPC and fusion-cost figures, JSON / Markdown / PNG |
//! | [`plot`] | what the PNG plots share (font, series, legend, file) |
//! | [`workload`] | reproducible fusion workloads (real kitchen keyframes, maps of a chosen size) for benches |
//! | [`conceptgraphs`] | ConceptGraphs' association and merging: the benchmark's peer fusion, registered as fusion `conceptgraphs` |
//! | [`reasoning_ablation`] | the paper's ablations of the reasoning stage, as variants of the runtime's enricher |
//! | [`knowledge_variants`] | knowledge bases derived for the evaluation (leave one category out, a short remote reach) |
//!
//! ```no_run
//! let loaded = op3dsg_sim::load_profile(None, &["source.synthetic.frame_count=300".to_owned()]).unwrap();
//! let run = op3dsg_sim::batch::run(&loaded.profile, &Default::default()).unwrap();
//! println!("{} keyframes, {} nodes", run.keyframes, run.graph.nodes.len());
//! ```

pub mod annotate;
pub mod backends;
pub mod batch;
pub mod conceptgraphs;
pub mod eval;
pub mod knowledge_variants;
pub mod oracle;
pub mod perf;
pub mod plot;
pub mod reasoning_ablation;
pub mod workload;

pub use backends::{backends, load_profile};
