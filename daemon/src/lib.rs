//! # op3dsg daemon library
//!
//! The pipeline stages of `op3dsgd` and the pieces the `op3dsg` CLI shares with it:
//!
//! | module | what |
//! |---|---|
//! | [`config`] | the layered, strictly validated TOML profile |
//! | [`pipeline`] | named stage threads, bounded queues, health, the shutdown ladder |
//! | [`keyframe`] | the keyframe gate (pose lookup, motion test), shared by pipeline and batch |
//! | [`batch`] | the deterministic single-thread runner for evaluation and tuning |
//! | [`eval`] | scoring fused graphs against synthetic ground truth |
//! | [`queue`] | bounded queues with latest-wins / block policies and drop counters |
//! | [`perception`] | the `Detector` trait, detections and masks; the synthetic oracle |
//! | [`fusion`] | the map: multi-view association of detections into 3D nodes |
//! | [`graph`] | the in-memory scene graph handed from fusion to publisher and tools |
//! | [`knowledge`] | the knowledge base: objects, parts, affordances, functional-relation templates |
//! | [`prior`] | the prior graph: neighbours through a grid, spatial relations from geometry and gravity |
//! | [`reasoner`] | reasoners over the prior graph; the offline knowledge reasoner |
//! | [`ipc`] | the iceoryx2 services: graph, update event, health, pose input |
//! | [`onnx`] | ONNX Runtime loaded from `.models/` at run time; the label text encoder |
//! | [`stats`] | per-stage counters and latency percentiles |
//! | [`perf`] | `op3dsg bench perf`: pipeline, IPC and fusion-cost figures, JSON / Markdown / PNG |
//!
//! ```no_run
//! use std::sync::{Arc, atomic::AtomicBool};
//! let loaded = op3dsg_daemon::config::load(None, &["run.max_frames=30".to_owned()]).unwrap();
//! let pipeline = op3dsg_daemon::pipeline::Pipeline::start(&loaded.profile, Arc::new(AtomicBool::new(false))).unwrap();
//! let summary = pipeline.wait().unwrap();
//! println!("{} keyframes/s", summary.keyframes_per_s());
//! ```

pub mod batch;
pub mod config;
pub mod eval;
pub mod fusion;
pub mod graph;
pub mod ipc;
pub mod keyframe;
pub mod knowledge;
pub mod onnx;
pub mod perception;
pub mod perf;
pub mod pipeline;
pub mod prior;
pub mod queue;
pub mod reasoner;
pub mod stats;
