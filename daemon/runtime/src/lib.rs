//! # op3dsg runtime
//!
//! What runs on the robot: the stages of `op3dsgd` and the composition that builds them from a
//! profile. It holds no simulation and no evaluation: the synthetic rooms, the oracle detector,
//! the batch runner and the benchmarks are the crate `op3dsg-sim`, which registers its source
//! and detector here like any other backend ([`backend`]).
//!
//! | stage | module | what |
//! |---|---|---|
//! | profile | [`config`] | the layered, strictly validated TOML profile |
//! | composition | [`backend`], [`pipeline`] | backends by name; the wiring of named stage threads and bounded queues, health, the shutdown ladder |
//! | capture | `capture/` | the capture thread over a [`op3dsg_drivers::source::FrameSource`], frame pool |
//! | keyframe | [`keyframe`] | the keyframe gate (pose lookup, motion test) and its thread |
//! | keyframe path | [`keyframe_path`] | detection → fusion → prior graph → reasoner, as the pipeline and the batch runner both run it |
//! | perception | [`perception`], [`onnx`] | the `Detector` trait, detections and masks; YOLOX and open-vocabulary detectors on ONNX Runtime; the text encoder; the detection workers |
//! | fusion | [`fusion`] | the map: multi-view association of detections into 3D nodes; the fusion thread |
//! | prior graph | [`prior`] | neighbours through a grid, spatial relations from geometry and gravity |
//! | reasoning | [`reasoner`], [`knowledge`] | the offline knowledge reasoner, the asynchronous LLM refiner, their tables |
//! | occupancy, navigation | [`occupancy`] | the 2D occupancy map from keyframes' depth (own thread, `<prefix>/occupancy`), approach poses and A* on it |
//! | queries | [`query`] | language queries on `<prefix>/query`, with approach poses |
//! | publish | [`ipc`] | the iceoryx2 server: graph, update event, health, pose input; the publisher thread |
//! | service | [`service`] | sd_notify readiness, status and watchdog from stage heartbeats; map snapshots and their restoration |
//! | support | [`graph`], [`queue`], [`stats`] | the in-memory scene graph; bounded queues with drop counters; per-stage latency percentiles |
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
pub(crate) mod capture;
pub mod config;
pub mod fusion;
pub mod graph;
pub mod ipc;
pub mod keyframe;
pub mod keyframe_path;
pub mod knowledge;
pub mod occupancy;
pub mod onnx;
pub mod perception;
pub mod pipeline;
pub mod prior;
pub mod query;
pub mod queue;
pub mod reasoner;
pub mod record;
pub mod service;
pub mod stats;
