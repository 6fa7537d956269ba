//! [`OccupancySubscriber`]: the planner's reader of `<prefix>/occupancy`, the daemon's 2D
//! occupancy map of the floor ([`occupancy_types`](crate::occupancy_types) has the cell encoding
//! and the grid's geometry), and [`OccupancyMap`], one map with its cells copied out.

use std::time::{Duration, Instant};

use iceoryx2::node::Node as IoxNode;
use iceoryx2::port::subscriber::Subscriber;
use iceoryx2::service::builder::publish_subscribe::PublishSubscribeOpenError;

use crate::client::{ClientError, ErrorCause, Operation, RootUse, await_history, create_node, retry_while_not_serving};
use crate::services::{IpcService, OCCUPANCY_HISTORY_SIZE, ServiceKind, service_name};
use crate::{
    OCCUPANCY_FREE_MAX_PERCENT, OCCUPANCY_MAX_SIDE_CELLS, OCCUPANCY_OCCUPIED_MIN_PERCENT, OCCUPANCY_SCHEMA_VERSION,
    OCCUPANCY_UNKNOWN, OccupancyHeader,
};

/// An occupancy sample that breaks the contract; names the offending field.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum OccupancyError {
    /// The publisher wrote another version of the header and cell encoding.
    SchemaVersion {
        /// Version in the sample.
        found: u32,
        /// [`OCCUPANCY_SCHEMA_VERSION`].
        expected: u32,
    },
    /// A side of the grid is longer than [`OCCUPANCY_MAX_SIDE_CELLS`].
    SideTooLong {
        /// `width_cells` or `height_cells`.
        field: &'static str,
        /// The value found.
        value: u32,
    },
    /// The payload does not hold `width_cells * height_cells` cells.
    CellCount {
        /// Cells in the sample.
        found: usize,
        /// `width_cells`.
        width_cells: u32,
        /// `height_cells`.
        height_cells: u32,
    },
}

impl core::fmt::Display for OccupancyError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            Self::SchemaVersion { found, expected } => {
                write!(f, "header.schema_version: found {found}, this build reads {expected}")
            }
            Self::SideTooLong { field, value } => {
                write!(f, "header.{field}: {value} exceeds {OCCUPANCY_MAX_SIDE_CELLS}")
            }
            Self::CellCount { found, width_cells, height_cells } => write!(
                f,
                "payload: {found} cells, but width_cells * height_cells = {width_cells} * {height_cells} = {}",
                *width_cells as usize * *height_cells as usize
            ),
        }
    }
}

impl std::error::Error for OccupancyError {}

/// Checks an occupancy sample's header against its payload: schema version, each side at most
/// [`OCCUPANCY_MAX_SIDE_CELLS`], exactly `width_cells * height_cells` cells.
pub fn check_occupancy(header: &OccupancyHeader, cells: usize) -> Result<(), OccupancyError> {
    if header.schema_version != OCCUPANCY_SCHEMA_VERSION {
        return Err(OccupancyError::SchemaVersion { found: header.schema_version, expected: OCCUPANCY_SCHEMA_VERSION });
    }
    for (field, value) in [("width_cells", header.width_cells), ("height_cells", header.height_cells)] {
        if value > OCCUPANCY_MAX_SIDE_CELLS {
            return Err(OccupancyError::SideTooLong { field, value });
        }
    }
    if cells != header.cell_count() {
        return Err(OccupancyError::CellCount {
            found: cells,
            width_cells: header.width_cells,
            height_cells: header.height_cells,
        });
    }
    Ok(())
}

/// One occupancy map: the header and the cells, row-major (`cells[row * width_cells + col]`),
/// owned. Cell values: [`OCCUPANCY_UNKNOWN`] (-1) never observed, else the occupancy
/// probability in percent (see [`occupancy_types`](crate::occupancy_types)).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct OccupancyMap {
    header: OccupancyHeader,
    cells: Vec<i8>,
}

impl OccupancyMap {
    /// A map of `header` and `cells`, checked ([`check_occupancy`]).
    pub fn new(header: OccupancyHeader, cells: Vec<i8>) -> Result<Self, OccupancyError> {
        check_occupancy(&header, cells.len())?;
        Ok(Self { header, cells })
    }

    /// The header as received (geometry, the robot's pose, keyframe counts, integration cost).
    pub fn header(&self) -> &OccupancyHeader {
        &self.header
    }

    /// Every cell, row-major.
    pub fn cells(&self) -> &[i8] {
        &self.cells
    }

    /// Cells per row (along the floor plane's first axis).
    pub fn width_cells(&self) -> u32 {
        self.header.width_cells
    }

    /// Rows (along the plane's second axis).
    pub fn height_cells(&self) -> u32 {
        self.header.height_cells
    }

    /// Side of one square cell, metres.
    pub fn cell_size_m(&self) -> f32 {
        self.header.cell_size_m
    }

    /// The daemon's instance when it published this map (a new value: the daemon restarted).
    pub fn instance_id(&self) -> u64 {
        self.header.instance_id
    }

    /// Wall-clock time of the send, nanoseconds since the Unix epoch.
    pub fn publish_time_ns(&self) -> u64 {
        self.header.publish_time_ns
    }

    /// The value of cell `(row, col)`; `None` off the grid.
    pub fn cell(&self, row: u32, col: u32) -> Option<i8> {
        let (w, h) = (self.header.width_cells, self.header.height_cells);
        (row < h && col < w).then(|| self.cells[row as usize * w as usize + col as usize])
    }

    /// `(row, col)` of the cell holding the plane point `(x_m, y_m)`; `None` off the grid.
    pub fn cell_of(&self, x_m: f32, y_m: f32) -> Option<(u32, u32)> {
        let h = &self.header;
        let col = ((x_m - h.origin_x_m) / h.cell_size_m).floor();
        let row = ((y_m - h.origin_y_m) / h.cell_size_m).floor();
        let inside = |v: f32, n: u32| v >= 0.0 && v < n as f32;
        (inside(col, h.width_cells) && inside(row, h.height_cells)).then_some((row as u32, col as u32))
    }

    /// The plane point at the centre of cell `(row, col)`, metres.
    pub fn centre_of(&self, row: u32, col: u32) -> (f32, f32) {
        let h = &self.header;
        (h.origin_x_m + (col as f32 + 0.5) * h.cell_size_m, h.origin_y_m + (row as f32 + 0.5) * h.cell_size_m)
    }

    /// The robot's latest `(x_m, y_m, yaw_rad)` on the plane; `None` before a keyframe.
    pub fn robot_pose(&self) -> Option<(f32, f32, f32)> {
        let h = &self.header;
        (h.robot_pose_valid != 0).then_some((h.robot_x_m, h.robot_y_m, h.robot_yaw_rad))
    }

    /// The world's up axis the plane is normal to: `z`, `y` or `-y` (`unknown` for a value this
    /// build does not know).
    pub fn up_axis(&self) -> &'static str {
        ["z", "y", "-y"].get(usize::from(self.header.up_axis)).copied().unwrap_or("unknown")
    }

    /// `true` for a cell value the daemon's planner takes as free (observed, at most
    /// [`OCCUPANCY_FREE_MAX_PERCENT`]).
    pub fn is_free(value: i8) -> bool {
        (0..=OCCUPANCY_FREE_MAX_PERCENT).contains(&value)
    }

    /// `true` for a cell value the daemon's planner takes as an obstacle (at least
    /// [`OCCUPANCY_OCCUPIED_MIN_PERCENT`]).
    pub fn is_occupied(value: i8) -> bool {
        value >= OCCUPANCY_OCCUPIED_MIN_PERCENT
    }

    /// `true` for a cell never observed.
    pub fn is_unknown(value: i8) -> bool {
        value == OCCUPANCY_UNKNOWN
    }
}

/// Reads the daemon's occupancy map (`<prefix>/occupancy`, about once a second): [`Self::latest`]
/// copies the newest map out of its sample into an [`OccupancyMap`] it keeps. Opening waits for
/// the service's history, the daemon's newest map (up to
/// [`ATTACH_HISTORY_WAIT`](crate::services::ATTACH_HISTORY_WAIT)), so the first [`Self::latest`]
/// after opening returns it. A daemon with `occupancy.enabled =
/// false` has no such service: opening it is a "not serving" error.
#[derive(Debug)]
pub struct OccupancySubscriber {
    prefix: String,
    subscriber: Subscriber<IpcService, [i8], OccupancyHeader>,
    latest: Option<OccupancyMap>,
    node: IoxNode<IpcService>,
}

impl OccupancySubscriber {
    /// Opens the daemon's `occupancy` under `prefix` as iceoryx2 node `node_name`; fails with a
    /// "not serving" error ([`ClientError::is_not_serving`]) when no daemon has created it.
    pub fn open(prefix: &str, node_name: &str) -> Result<Self, ClientError> {
        let node = create_node(prefix, ServiceKind::Occupancy, node_name, RootUse::Existing)?;
        let subscriber = open_subscriber(&node, prefix)?;
        await_history(|| subscriber.has_samples().unwrap_or(true));
        Ok(Self { prefix: prefix.to_owned(), subscriber, latest: None, node })
    }

    /// Like [`Self::open`], but while no daemon serves `prefix` retries every
    /// [`OPEN_RETRY_INTERVAL`](crate::services::OPEN_RETRY_INTERVAL), up to `timeout`.
    pub fn open_wait(prefix: &str, node_name: &str, timeout: Duration) -> Result<Self, ClientError> {
        let deadline = Instant::now() + timeout;
        let node = retry_while_not_serving(timeout, || {
            create_node(prefix, ServiceKind::Occupancy, node_name, RootUse::Existing)
        })?;
        let timeout = deadline.saturating_duration_since(Instant::now());
        let subscriber = retry_while_not_serving(timeout, || open_subscriber(&node, prefix))?;
        await_history(|| subscriber.has_samples().unwrap_or(true));
        Ok(Self { prefix: prefix.to_owned(), subscriber, latest: None, node })
    }

    /// The prefix served.
    pub fn prefix(&self) -> &str {
        &self.prefix
    }

    /// The client's iceoryx2 node.
    pub fn node(&self) -> &IoxNode<IpcService> {
        &self.node
    }

    /// Takes every queued map and returns the newest received so far (its cells copied out, so
    /// it stays valid); `None` while none came. A map that breaks the contract (another schema
    /// version, a side too long, a cell count other than width × height) is an error naming
    /// it, and the previous map stays.
    pub fn latest(&mut self) -> Result<Option<&OccupancyMap>, ClientError> {
        let fail = |operation, cause| ClientError::new(&self.prefix, ServiceKind::Occupancy, operation, cause);
        // Each map is copied out at once: a subscriber may borrow one sample at a time.
        while let Some(sample) =
            self.subscriber.receive().map_err(|e| fail(Operation::Receive, ErrorCause::Receive(e)))?
        {
            let header = *sample.user_header();
            check_occupancy(&header, sample.payload().len())
                .map_err(|e| fail(Operation::Receive, ErrorCause::InvalidOccupancy(e)))?;
            let map = self.latest.get_or_insert_with(OccupancyMap::default);
            map.header = header;
            map.cells.clear();
            map.cells.extend_from_slice(sample.payload());
        }
        Ok(self.latest.as_ref())
    }
}

fn open_subscriber(
    node: &IoxNode<IpcService>,
    prefix: &str,
) -> Result<Subscriber<IpcService, [i8], OccupancyHeader>, ClientError> {
    let fail = |operation, cause| ClientError::new(prefix, ServiceKind::Occupancy, operation, cause);
    let name = service_name(prefix, ServiceKind::Occupancy)
        .map_err(|e| fail(Operation::Open, ErrorCause::InvalidPrefix(e)))?;
    let service = match node.service_builder(&name).publish_subscribe::<[i8]>().user_header::<OccupancyHeader>().open()
    {
        Ok(service) => service,
        Err(PublishSubscribeOpenError::DoesNotExist) => return Err(fail(Operation::Open, ErrorCause::NotServing)),
        Err(e) => return Err(fail(Operation::Open, ErrorCause::OpenPublishSubscribe(e))),
    };
    service
        .subscriber_builder()
        .history_request(OCCUPANCY_HISTORY_SIZE)
        .create()
        .map_err(|e| fail(Operation::CreateSubscriber, ErrorCause::CreateSubscriber(e)))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn header(width: u32, height: u32) -> OccupancyHeader {
        OccupancyHeader {
            schema_version: OCCUPANCY_SCHEMA_VERSION,
            width_cells: width,
            height_cells: height,
            cell_size_m: 0.5,
            origin_x_m: -1.0,
            origin_y_m: 2.0,
            ..OccupancyHeader::default()
        }
    }

    #[test]
    fn cells_are_found_by_plane_point_and_read_row_major() {
        let mut cells = vec![OCCUPANCY_UNKNOWN; 4 * 3];
        cells[2 * 4 + 1] = 90; // row 2, col 1
        cells[0] = 10;
        let map = OccupancyMap::new(header(4, 3), cells).expect("valid map");
        assert_eq!(map.cell_of(-0.6, 3.2), Some((2, 0)));
        assert_eq!(map.cell_of(-0.4, 3.2), Some((2, 1)));
        assert_eq!(map.cell(2, 1), Some(90));
        assert!(OccupancyMap::is_occupied(90) && OccupancyMap::is_free(10) && OccupancyMap::is_unknown(-1));
        assert!(!OccupancyMap::is_free(-1) && !OccupancyMap::is_occupied(50));
        assert_eq!(map.cell(3, 0), None);
        assert_eq!(map.cell_of(-1.1, 2.0), None);
        assert_eq!(map.cell_of(1.0, 2.0), None, "the grid's far edge is outside");
        assert_eq!(map.centre_of(2, 1), (-0.25, 3.25));
        assert_eq!((map.up_axis(), map.robot_pose()), ("z", None));
    }

    #[test]
    fn bad_maps_are_refused_naming_the_field() {
        assert_eq!(
            OccupancyMap::new(header(4, 3), vec![0; 11]).expect_err("short").to_string(),
            "payload: 11 cells, but width_cells * height_cells = 4 * 3 = 12"
        );
        let mut other = header(1, 1);
        other.schema_version = 2;
        assert_eq!(
            check_occupancy(&other, 1).expect_err("schema").to_string(),
            "header.schema_version: found 2, this build reads 1"
        );
        assert_eq!(
            check_occupancy(&header(OCCUPANCY_MAX_SIDE_CELLS + 1, 1), 2049).expect_err("wide").to_string(),
            "header.width_cells: 2049 exceeds 2048"
        );
    }
}
