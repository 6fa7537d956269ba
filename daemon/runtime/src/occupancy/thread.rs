//! The occupancy thread `op3dsg-occupancy`: keyframes' depth in, the map out on
//! `<prefix>/occupancy` and to the query service.
//!
//! ```text
//! keyframe gate ──[scans: bounded, occupancy.queue_capacity, drop when full]──► occupancy ──► <prefix>/occupancy (1 Hz)
//!        ▲                                                                          │  └───► LatestOccupancy (query worker, Zenoh)
//!        └──────────────────[free scan buffers: the same capacity]─────────────────┘
//! ```
//!
//! The keyframe gate copies every keyframe's subsampled depth (`occupancy.pixel_stride`; 4,800
//! values at 640 × 480 and stride 8) into a scan buffer taken from a pool made at start
//! ([`OccupancyFeed::offer`]). No buffer free (the thread is behind) means the keyframe is not
//! integrated, counted, never waited for: the fusion path never waits on the map. The thread
//! integrates, returns the buffer, and every `occupancy.publish_period_ms` publishes the whole
//! grid (a slice loaned once per period; the publisher reserves the grid's size at start) and
//! copies it into [`LatestOccupancy`] for the query worker's approach poses.
//!
//! It ends with the stop flag, or when the gate has ended (its feed dropped) and the daemon
//! exits at the end of its source (`run.exit_at_end`), after a last publish; otherwise it keeps
//! serving the last map until the stop.

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::time::{Duration, Instant};

use crossbeam_channel::{Receiver, RecvTimeoutError, Sender};
use op3dsg_drivers::frame::Frame;
use op3dsg_drivers::pose::Isometry;
use op3dsg_ipc_types::OccupancyHeader;
use tracing::{debug, warn};

use super::persist::OccupancyStore;
use super::{DepthScan, GridGeometry, OccupancyGrid, OccupancyPublisher, RobotPose};
use crate::queue::Latest;
use crate::stats::StageStats;
use crate::world::clock::wall_clock_ns;
use crate::world::{OrientedBox, UpAxis, horizontal_frame};

/// How long the thread waits for a scan before it checks the clock and the stop flag.
const POLL: Duration = Duration::from_millis(20);

/// The keyframe gate's end of the scan queue.
#[derive(Debug)]
pub struct OccupancyFeed {
    scans: Sender<DepthScan>,
    free: Receiver<DepthScan>,
    dropped: Arc<AtomicU64>,
}

impl OccupancyFeed {
    /// Copies `frame`'s subsampled depth with `world_from_camera` into a pooled buffer and
    /// queues it; when no buffer is free the keyframe is counted as dropped. Never blocks.
    pub fn offer(&self, frame: &Frame, world_from_camera: &Isometry) {
        let Ok(mut scan) = self.free.try_recv() else {
            let dropped = self.dropped.fetch_add(1, Ordering::Relaxed) + 1;
            if dropped.is_power_of_two() {
                warn!(dropped, "occupancy map behind: keyframe not integrated (occupancy.queue_capacity)");
            }
            return;
        };
        scan.fill(&frame.depth, &frame.intrinsics, frame.depth_units_per_m, world_from_camera, frame.stamp_ns);
        if self.scans.try_send(scan).is_err() {
            self.dropped.fetch_add(1, Ordering::Relaxed);
        }
    }
}

/// The occupancy thread's end.
#[derive(Debug)]
pub struct OccupancyIntake {
    scans: Receiver<DepthScan>,
    free: Sender<DepthScan>,
    dropped: Arc<AtomicU64>,
}

/// The scan queue and its pool of `capacity` buffers for frames of `intrinsics`.
pub fn scan_queue(
    capacity: usize,
    intrinsics: &op3dsg_drivers::frame::Intrinsics,
    stride: u32,
) -> (OccupancyFeed, OccupancyIntake) {
    let (scans_tx, scans_rx) = crossbeam_channel::bounded(capacity);
    let (free_tx, free_rx) = crossbeam_channel::bounded(capacity);
    for _ in 0..capacity {
        let _ = free_tx.try_send(DepthScan::with_capacity(intrinsics, stride));
    }
    let dropped = Arc::new(AtomicU64::new(0));
    (
        OccupancyFeed { scans: scans_tx, free: free_rx, dropped: dropped.clone() },
        OccupancyIntake { scans: scans_rx, free: free_tx, dropped },
    )
}

/// A copy of the map as published.
#[derive(Debug, Clone, PartialEq)]
pub struct MapCopy {
    /// Increases with every copy.
    pub version: u64,
    /// Geometry.
    pub geometry: GridGeometry,
    /// Cells (-1 unknown, else percent).
    pub cells: Vec<i8>,
    /// The robot's latest pose.
    pub robot: Option<RobotPose>,
    /// The header the map was published with (`<prefix>/occupancy`; its free and occupied counts
    /// are those of `cells`).
    pub header: OccupancyHeader,
}

impl MapCopy {
    /// The grid's corner on the floor in world coordinates, and the rotation that turns the
    /// grid's rows and columns onto the world's horizontal axes (how viewers place the map).
    pub fn corner_pose(&self) -> (glam::DVec3, glam::DQuat) {
        let h = &self.header;
        let up_axis = match h.up_axis {
            1 => UpAxis::Y,
            2 => UpAxis::NegY,
            _ => UpAxis::Z,
        };
        let [first, second, up] = horizontal_frame(up_axis).map(|v| v.as_dvec3());
        let corner =
            first * f64::from(h.origin_x_m) + second * f64::from(h.origin_y_m) + up * f64::from(h.floor_height_m);
        (corner, OrientedBox::default().rotation(up_axis).0)
    }
}

/// The newest published map, for the query worker and the Zenoh stage (copied in place; no
/// allocation after the first copy).
pub type LatestOccupancy = Latest<MapCopy>;

/// Replaces the map in `latest` with `grid`'s cells and the `header` they are published with.
fn share(latest: &LatestOccupancy, grid: &OccupancyGrid, header: OccupancyHeader) {
    latest.update(|slot| {
        let copy = slot.get_or_insert_with(|| MapCopy {
            version: 0,
            geometry: grid.geometry(),
            cells: vec![0; grid.geometry().cell_count()],
            robot: None,
            header,
        });
        copy.version += 1;
        copy.geometry = grid.geometry();
        copy.cells.resize(grid.geometry().cell_count(), 0);
        let (free, occupied) = grid.write_cells(&mut copy.cells);
        copy.robot = grid.robot();
        copy.header = OccupancyHeader { free_cells: free, occupied_cells: occupied, ..header };
    });
}

/// Copies the map of `latest` into `out` when it is newer than `out` (by version); returns
/// whether a map exists at all.
pub fn copy_if_newer(latest: &LatestOccupancy, out: &mut Option<MapCopy>) -> bool {
    latest.read(|map| {
        let Some(map) = map else { return out.is_some() };
        match out {
            Some(copy) if copy.version == map.version => {}
            Some(copy) => {
                copy.version = map.version;
                copy.geometry = map.geometry;
                copy.cells.clear();
                copy.cells.extend_from_slice(&map.cells);
                copy.robot = map.robot;
                copy.header = map.header;
            }
            None => *out = Some(map.clone()),
        }
        true
    })
}
/// The occupancy thread, built by the composition; [`OccupancyThread::run`] is its body.
#[derive(Debug)]
pub struct OccupancyThread {
    /// The grid (allocated at start).
    pub grid: OccupancyGrid,
    /// Scans in, buffers back.
    pub intake: OccupancyIntake,
    /// Where the map goes (created before the thread starts).
    pub publisher: OccupancyPublisher,
    /// The query service's copy, when it runs.
    pub latest: Option<Arc<LatestOccupancy>>,
    /// Publish period.
    pub period: Duration,
    /// End with the gate at the end of a finite source.
    pub exit_at_end: bool,
    /// Integration cost per keyframe.
    pub cost: Arc<StageStats>,
    /// Where the map is saved (the snapshot directory), `None` with snapshots off.
    pub store: Option<OccupancyStore>,
    /// How often a changing map is saved (`snapshot.period_s`; `None`: only at the end).
    pub save_period: Option<Duration>,
    /// The daemon's stop flag.
    pub stop: Arc<AtomicBool>,
}

impl OccupancyThread {
    /// Integrates scans and publishes the map every period until the stop flag (or, with
    /// `exit_at_end`, until the gate has ended), then publishes and saves it once more.
    pub fn run(self) {
        run(self);
    }
}

fn run(mut thread: OccupancyThread) {
    let mut last_publish = Instant::now();
    let mut last_save = Instant::now();
    let mut publish_errors = 0u64;
    let mut save_errors = 0u64;
    let mut fed = true;
    let mut dirty = false;
    let mut unsaved = false;
    loop {
        if thread.stop.load(Ordering::Relaxed) {
            break;
        }
        if fed {
            match thread.intake.scans.recv_timeout(POLL) {
                Ok(scan) => {
                    let started = Instant::now();
                    thread.grid.integrate(&scan);
                    thread.cost.record(started);
                    let _ = thread.intake.free.try_send(scan);
                    dirty = true;
                    unsaved = true;
                }
                Err(RecvTimeoutError::Timeout) => {}
                Err(RecvTimeoutError::Disconnected) => fed = false,
            }
        } else {
            if thread.exit_at_end {
                break;
            }
            std::thread::sleep(POLL);
        }
        // A late joiner gets the history sample when the publisher updates its connections: on
        // every tick, not only once a period.
        if let Err(e) = thread.publisher.update_connections() {
            debug!(error = %e, "occupancy: update connections failed");
        }
        if last_publish.elapsed() >= thread.period {
            last_publish = Instant::now();
            publish(&mut thread, &mut publish_errors, dirty);
            dirty = false;
        }
        if unsaved && thread.save_period.is_some_and(|period| last_save.elapsed() >= period) {
            last_save = Instant::now();
            save(&mut thread, &mut save_errors);
            unsaved = false;
        }
    }
    publish(&mut thread, &mut publish_errors, true);
    if unsaved {
        save(&mut thread, &mut save_errors);
    }
}

fn save(thread: &mut OccupancyThread, errors: &mut u64) {
    let Some(store) = thread.store.as_mut() else { return };
    if let Err(e) = store.save(&thread.grid) {
        *errors += 1;
        if errors.is_power_of_two() {
            warn!(path = %store.path().display(), error = %e, save_errors = *errors, "occupancy map not saved");
        }
    }
}

fn publish(thread: &mut OccupancyThread, errors: &mut u64, changed: bool) {
    let figures = thread.cost.take_figures();
    let mut header = thread.grid.header();
    header.keyframes_dropped = thread.intake.dropped.load(Ordering::Relaxed);
    header.integrate_p50_us = figures.p50_us as u32;
    header.integrate_p99_us = figures.p99_us as u32;
    header.instance_id = thread.publisher.instance_id();
    header.publish_time_ns = wall_clock_ns();
    if changed && let Some(latest) = &thread.latest {
        share(latest, &thread.grid, header);
    }
    if let Err(e) = thread.publisher.publish(&thread.grid, header) {
        *errors += 1;
        if errors.is_power_of_two() {
            warn!(error = %e, publish_errors = *errors, "occupancy map not published");
        }
    }
}
