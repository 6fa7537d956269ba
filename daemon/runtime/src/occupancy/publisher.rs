//! `<prefix>/occupancy`: the map as a slice of cells with an [`OccupancyHeader`], created with
//! the contract's QoS (`op3dsg_ipc_types::services`).

use iceoryx2::port::publisher::Publisher;
use iceoryx2::port::update_connections::UpdateConnections;
use op3dsg_ipc_types::OccupancyHeader;
use op3dsg_ipc_types::services::{
    OCCUPANCY_HISTORY_SIZE, OCCUPANCY_MAX_NODES, OCCUPANCY_MAX_PUBLISHERS, OCCUPANCY_MAX_SUBSCRIBERS,
    OCCUPANCY_SUBSCRIBER_BUFFER, OCCUPANCY_SUBSCRIBER_MAX_BORROWED_SAMPLES, SAFE_OVERFLOW, occupancy_service_name,
};
use tracing::info;

use super::OccupancyGrid;
use crate::ipc::{IpcConfig, IpcError, IpcService, create_node, new_instance_id, service_err, service_name};

/// The occupancy publisher: its own iceoryx2 node, service and publisher.
#[derive(Debug)]
pub struct OccupancyPublisher {
    publisher: Publisher<IpcService, [i8], OccupancyHeader>,
    service: String,
    instance_id: u64,
    _node: iceoryx2::node::Node<IpcService>,
}

impl OccupancyPublisher {
    /// Creates `<prefix>/occupancy` with the contract's QoS and a publisher for `cells` cells.
    pub fn open(ipc: &IpcConfig, cells: usize) -> Result<Self, IpcError> {
        let prefix = ipc.prefix.as_str();
        let full = occupancy_service_name(prefix);
        let name = service_name(prefix, &full)?;
        let node = create_node(&ipc.ipc_root(), "op3dsgd-occupancy")?;
        let service = node
            .service_builder(&name)
            .publish_subscribe::<[i8]>()
            .user_header::<OccupancyHeader>()
            .history_size(OCCUPANCY_HISTORY_SIZE)
            .enable_safe_overflow(SAFE_OVERFLOW)
            .subscriber_max_buffer_size(OCCUPANCY_SUBSCRIBER_BUFFER)
            .subscriber_max_borrowed_samples(OCCUPANCY_SUBSCRIBER_MAX_BORROWED_SAMPLES)
            .max_subscribers(OCCUPANCY_MAX_SUBSCRIBERS)
            .max_publishers(OCCUPANCY_MAX_PUBLISHERS)
            .max_nodes(OCCUPANCY_MAX_NODES)
            .open_or_create()
            .map_err(|e| service_err(&full, "open or create", e))?;
        let publisher = service
            .publisher_builder()
            .max_loaned_samples(1)
            .initial_max_slice_len(cells)
            .create()
            .map_err(|e| service_err(&full, "create publisher", e))?;
        info!(service = %full, cells, "publishing the occupancy map");
        Ok(Self { publisher, service: full, instance_id: new_instance_id(), _node: node })
    }

    /// The instance id stamped into every header (drawn at start).
    pub fn instance_id(&self) -> u64 {
        self.instance_id
    }

    /// Connects subscribers that joined since the last call and hands them the newest map (the
    /// history), so a planner attaching between two publishes has it at once.
    pub fn update_connections(&self) -> Result<(), IpcError> {
        self.publisher.update_connections().map_err(|e| service_err(&self.service, "update connections", e))
    }

    /// Publishes `grid` with `header` as the caller made it (instance id, send time, the period's
    /// `integrate_*` figures); the free and occupied counts are those of the cells written.
    pub fn publish(&self, grid: &OccupancyGrid, mut header: OccupancyHeader) -> Result<(), IpcError> {
        let cells = grid.geometry().cell_count();
        let mut sample = self.publisher.loan_slice(cells).map_err(|e| service_err(&self.service, "loan", e))?;
        let (free, occupied) = grid.write_cells(sample.payload_mut());
        header.free_cells = free;
        header.occupied_cells = occupied;
        *sample.user_header_mut() = header;
        sample.send().map(|_| ()).map_err(|e| service_err(&self.service, "send", e))
    }
}
