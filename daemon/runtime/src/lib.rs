//! # op3dsg runtime
//!
//! What runs on the robot: the stages of `op3dsgd` and the composition that builds them from a
//! profile. It holds no simulation, no evaluation and no research variant: the synthetic rooms,
//! the oracle detector, the batch runner, the benchmarks, the reasoning ablations and the
//! ConceptGraphs peer fusion are the crate `op3dsg-sim`, which registers its source, detector and
//! fusion here like any other backend ([`backend`]).
//!
//! The crate is read bottom-up, and every import points down (the test command checks it; the
//! rows are declared in this crate's `Cargo.toml`, `[package.metadata.layers]`):
//!
//! | layer | module | what it owns |
//! |---|---|---|
//! | leaf | [`world`] | the up axis and horizontal frame, gravity-aligned boxes, the wall clock |
//! | leaf | [`embedding`] | embeddings, normalise / cosine, the [`embedding::PhraseEmbedder`] trait |
//! | leaf | [`queue`] | bounded queues with named overflow policies, the latest-wins [`queue::Latest`] |
//! | leaf | [`stats`] | stage latency figures, the watchdog's heartbeats, the pose input's counters, the health traits |
//! | leaf | [`install`] | where the model store and the profiles are: a checkout's `.models/`, or installed beside the binary |
//! | leaf | [`persist`] | atomic writes, the directory lock, moving a bad file aside |
//! | leaf | [`graph`] | the in-memory scene graph, node points |
//! | leaf | [`knowledge`] | object → part tables, label resolution and its fallbacks |
//! | leaf | [`onnx`] | ONNX Runtime, model contracts, the text encoders |
//! | leaf | [`flow`] | the items between stages: frames, keyframes, detections, graph versions |
//! | leaf | [`ipc`] | iceoryx2 plumbing: services, the graph codec, the health report |
//! | stage | [`record`] | the MCAP recorder's thread and its sender |
//! | stage | [`prior`] | the prior graph: neighbours, spatial relations, part → object |
//! | stage | [`reasoner`] | the knowledge reasoner, the LLM refiner, [`reasoner::enrich`] |
//! | stage | [`perception`] | detectors, the detection workers |
//! | stage | [`occupancy`] | the occupancy grid, approach poses, its thread and service |
//! | stage | [`fusion`] | the map, its thread, its snapshots |
//! | stage | [`query`] | language queries on `<prefix>/query` |
//! | stage | [`capture`] | the capture thread |
//! | stage | [`keyframe`] | the keyframe gate and its thread |
//! | stage | [`publish`] | the publisher thread |
//! | stage | [`zenoh`] | the graph, its deltas and health for consumers off the robot, over Zenoh |
//! | stage | [`live_view`] | the graph, the camera, the map and health in Foxglove, over its WebSocket protocol |
//! | composition | [`config`] | the profile: the stages' sections and the checks across them |
//! | composition | [`backend`] | source, detector and fusion registries |
//! | composition | [`pipeline`] | the wiring of named stage threads and bounded queues, health, the shutdown ladder |
//! | composition | [`service`] | sd_notify readiness, status and watchdog |
//!
//! Each stage is a folder with its profile section (`config.rs`), its counters, and a `*Thread`
//! struct built from its section with a `run(self)`; a stage imports leaves and lower stages,
//! never the composition nor another stage's thread.
//!
//! ```no_run
//! use std::sync::{Arc, atomic::AtomicBool};
//! use op3dsg_runtime::{backend::Backends, config, pipeline::Pipeline};
//! let profile_path = std::path::Path::new("profiles/replay-icl.toml");
//! let backends = Backends::runtime();
//! let loaded = config::load_with(&backends, Some(profile_path), &["run.max_frames=30".to_owned()]).unwrap();
//! let pipeline = Pipeline::start(&loaded.profile, &backends, Arc::new(AtomicBool::new(false))).unwrap();
//! let summary = pipeline.wait().unwrap();
//! println!("{} keyframes/s", summary.keyframes_per_s());
//! ```

pub mod backend;
pub mod capture;
pub mod config;
pub mod embedding;
pub mod flow;
pub mod fusion;
pub mod graph;
pub mod install;
pub mod ipc;
pub mod keyframe;
pub mod knowledge;
pub mod live_view;
pub mod occupancy;
pub mod onnx;
pub mod perception;
pub mod persist;
pub mod pipeline;
pub mod prior;
pub mod publish;
pub mod query;
pub mod queue;
pub mod reasoner;
pub mod record;
pub mod ros2;
pub mod service;
pub mod stats;
pub mod world;
pub mod zenoh;
