//! op3dsg-sim's integration tests: the pipeline on the synthetic scenes and recordings, quality
//! against ground truth, the knowledge catalogue and the reasoners. One test binary, a module per
//! area; the fusion's allocation count is its own binary (`fusion_allocations.rs`: a counting
//! global allocator counts every thread of its process).

mod annotate_icl;
mod batch_determinism;
mod bench_quality;
mod change_bench;
mod colour_ablation;
mod fusion_quality;
mod knowledge_catalog;
mod knowledge_reasoner;
mod llm_refiner;
mod model_families;
mod open_vocab;
mod replay_icl_yolox;
mod replay_pipeline;
mod unified_graph;
