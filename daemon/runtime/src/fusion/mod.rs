//! Multi-view fusion: detections of each keyframe become 3D nodes of one map.
//!
//! The fusion thread ([`FusionThread`]) is the only owner of the map ([`Fusion`]); other
//! threads see it only through the [`crate::graph::SceneGraph`] versions it builds.
//! [`multiview::MultiViewFusion`] is the method of the OP3DSG paper (geometry, semantics and, for
//! parts, colour distribution); its module documents every formula and choice. Fusion saves and
//! restores its own map ([`snapshot`]).
//!
//! A keyframe's path through this stage, the same in the pipeline's thread and in the batch
//! runner of `op3dsg-sim`: [`fuse`] its detections into the map, and when the map changed, take
//! the graph of the map as it stands ([`map_graph`]) and enrich it (`crate::reasoner::enrich`).
//!
//! ```
//! use op3dsg_runtime::fusion;
//! let profile = op3dsg_runtime::config::load(None, &[]).unwrap().profile;
//! let mut map = fusion::build(&profile.fusion, profile.world.up_axis);
//! let frame = op3dsg_drivers::frame::Frame::new(op3dsg_drivers::frame::Intrinsics::d435i_640x480());
//! let world_from_camera = op3dsg_drivers::pose::Isometry::IDENTITY;
//! let changed = fusion::fuse(map.as_mut(), &frame, &world_from_camera, &[]).changed();
//! assert!(!changed, "no detections, no new graph version");
//! let graph = fusion::map_graph(map.as_ref(), 1, frame.stamp_ns);
//! assert_eq!(graph.version, 1);
//! ```
//!
//! | file | what |
//! |---|---|
//! | `config.rs` | `[fusion]` ([`FusionConfig`]) |
//! | `change/` | `[fusion.change]`: removals, moves and appearances from each keyframe's depth |
//! | `multiview/`, `colour.rs` | the OP3DSG fusion and its colour features |
//! | `snapshot/` | `[snapshot]`: the map's file, its directory, its writer thread |
//! | `counters.rs` | [`FusionCounters`] |
//! | `thread.rs` | [`FusionThread`] |

use op3dsg_drivers::frame::Frame;
use op3dsg_drivers::pose::Isometry;

use crate::flow::Detection;
use crate::graph::{NodePoint, SceneGraph};
use crate::world::UpAxis;

pub mod change;
pub mod colour;
mod config;
mod counters;
pub mod multiview;
pub mod snapshot;
mod thread;

pub use config::{FusionConfig, OP3DSG_FUSION};
pub use counters::FusionCounters;
pub use thread::{FusionThread, Resume};

/// What one keyframe did to the map.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct FusionReport {
    /// Detections merged into existing nodes.
    pub merged: u32,
    /// New nodes created.
    pub created: u32,
    /// Detections ignored (too few valid points).
    pub ignored: u32,
    /// Nodes merged into others by maintenance.
    pub maintenance_merged: u32,
    /// Unconfirmed nodes pruned by maintenance.
    pub pruned: u32,
    /// Nodes removed on change evidence (`[fusion.change]`), parts with their objects included.
    pub removed: u32,
    /// Nodes that became missing, or present again, in this keyframe.
    pub state_changes: u32,
    /// Time of the evidence step (`[fusion.change]`), nanoseconds.
    pub evidence_ns: u64,
}

/// A map that fuses keyframe detections.
pub trait Fusion: Send {
    /// Fuses the detections of one keyframe taken at `world_from_camera`.
    fn integrate(&mut self, frame: &Frame, world_from_camera: &Isometry, detections: &[Detection]) -> FusionReport;

    /// Fills `out` with the confirmed nodes and their geometric edges (version and stamp are
    /// set by the caller).
    fn build_graph(&self, out: &mut SceneGraph);

    /// Nodes in the map, confirmed or not.
    fn node_count(&self) -> usize;

    /// Heap bytes the map holds (capacity, not length), for health and memory benchmarks.
    fn memory_bytes(&self) -> usize;

    /// Appends the points of the nodes [`Fusion::build_graph`] publishes, at most
    /// `max_per_node` of each (evenly spaced through its cloud). Default: none.
    fn node_points(&self, max_per_node: usize, out: &mut Vec<NodePoint>) {
        let _ = (max_per_node, out);
    }

    /// The map's saved form for a snapshot (`crate::fusion::snapshot`); `None` when this
    /// fusion cannot be saved.
    fn export_state(&self) -> Option<multiview::MapState> {
        None
    }

    /// Turns change handling (`[fusion.change] enabled`) on or off from the next keyframe on,
    /// for measuring its cost on one map. Default: nothing to turn.
    fn set_change_handling(&mut self, on: bool) {
        let _ = on;
    }

    /// Moves the changes found since the last call (`[fusion.change]`) into `out`, oldest
    /// first. Default: none.
    fn take_changes(&mut self, out: &mut Vec<change::ChangeEvent>) {
        let _ = out;
    }

    /// The removed nodes it remembers, oldest first. Default: none.
    fn removed_nodes(&self) -> Vec<change::RemovedNode> {
        Vec::new()
    }

    /// Replaces the map with a saved one; the message says why it does not fit.
    fn restore_state(&mut self, state: &multiview::MapState) -> Result<(), String> {
        let _ = state;
        Err("this fusion cannot restore a map snapshot".to_owned())
    }
}

/// The OP3DSG fusion of `config` (whatever `config.method` says: the composition picks the
/// method); `up_axis` (`world.up_axis`) orients the nodes' boxes.
pub fn build(config: &FusionConfig, up_axis: UpAxis) -> Box<dyn Fusion> {
    Box::new(multiview::MultiViewFusion::new(config.clone()).with_up_axis(up_axis))
}

/// What fusing one keyframe did to the map.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Fused {
    /// Fusion's own report.
    pub report: FusionReport,
}

impl Fused {
    /// Whether the map gained or updated a node, so that a new graph version is due.
    pub fn changed(&self) -> bool {
        self.report.merged + self.report.created + self.report.removed + self.report.state_changes > 0
    }
}

/// Integrates one keyframe's detections into the map.
pub fn fuse(fusion: &mut dyn Fusion, frame: &Frame, world_from_camera: &Isometry, detections: &[Detection]) -> Fused {
    Fused { report: fusion.integrate(frame, world_from_camera, detections) }
}

/// The graph of the map as it stands: fusion's confirmed nodes and `part of` edges, with its
/// version and stamp. The reasoner's enrichment adds the rest.
pub fn map_graph(fusion: &dyn Fusion, version: u64, stamp_ns: u64) -> SceneGraph {
    let mut graph = SceneGraph::default();
    fusion.build_graph(&mut graph);
    graph.version = version;
    graph.stamp_ns = stamp_ns;
    graph
}
