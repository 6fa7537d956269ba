//! The LLM side of the reasoner (paper: "Geometry-anchored LLM-based Reasoning"): three agents
//! against any OpenAI-compatible chat-completions endpoint, behind a verification gate, run by
//! an asynchronous refiner that never slows the hot path.
//!
//! - [`config`]: `[reasoner.llm]` (endpoint, key source, timeouts, retries, breaker, budget,
//!   refresh policy);
//! - [`prompt`]: one prompt per agent per refresh from a prior-graph version (local relations
//!   over part-of pairs, remote relations over remotable candidates, affordances per node);
//! - [`client`]: the HTTP client (reqwest on tokio, structured JSON output);
//! - [`gate`]: strict parsing, endpoint and kind checks, canonical label mapping, rejections
//!   counted by reason;
//! - [`plausibility`]: the gate's geometry and knowledge-base rules for canonical but
//!   implausible items;
//! - [`refiner`]: the refiner thread (latest snapshot in, verified results out);
//! - [`result`]: each agent's last accepted result, kept per agent and re-checked against the
//!   graph it is applied to.
//!
//! With `reasoner.kind = "llm"` the knowledge reasoner still runs on every published graph; the
//! refiner's latest verified result is applied on top ([`crate::reasoner::apply`], origin
//! `llm`, or `knowledge+llm` where both agree), to the nodes that still exist with the kind they
//! had.

pub mod client;
pub mod config;
pub mod gate;
pub mod plausibility;
pub mod prompt;
pub mod refiner;
pub mod result;

pub use config::{LlmConfig, PlausibilityConfig, ResponseFormat};
pub use refiner::{LlmRefiner, RefinerParts, RefinerState, RefinerStats};
pub use result::{AgentResult, LlmResult};
