"""The daemon's 2D occupancy map: :class:`OccupancyClient` reads ``<prefix>/occupancy`` (iceoryx2,
about once a second) and gives :class:`OccupancyMap`: the header and the cells as a 2-D ``int8``
numpy array, ``cells[row, col]``::

    import op3dsg
    grid = op3dsg.OccupancyClient("op3dsg", timeout=30).wait(10)
    print(grid.width_cells, grid.height_cells, grid.cell_size_m, (grid.cells >= 65).sum(), "occupied cells")

Cell values follow ROS ``nav_msgs/OccupancyGrid``: -1 for a cell never observed, else the
occupancy probability in percent, 0 (certainly free) to 100 (certainly occupied); the daemon's
planner takes ``<= 35`` as free and ``>= 65`` as occupied. Column ``col`` spans the floor plane's
first axis from ``origin_x_m + col * cell_size_m``, row ``row`` the second axis from
``origin_y_m`` (world ``x`` and ``y`` with ``world.up_axis = "z"``, ``x`` and ``z`` with ``y`` up).

:class:`OccupancyHeader` mirrors the Rust ``op3dsg_ipc_types::OccupancyHeader`` (112 bytes,
type name ``op3dsg::OccupancyHeader``); the same header and cells travel over Zenoh
(:func:`op3dsg.remote.remote_occupancy`).
"""

from __future__ import annotations

import ctypes
from typing import Optional, Tuple

import iceoryx2 as iox2
import numpy as np

from . import _iox
from .errors import InvalidGraphError, SchemaVersionError
from .wire import HISTORY_SIZE, _Wire

#: Version of :class:`OccupancyHeader` and the cell encoding (``OCCUPANCY_SCHEMA_VERSION``).
OCCUPANCY_SCHEMA_VERSION = 1
#: Cell value of a cell never observed.
OCCUPANCY_UNKNOWN = -1
#: Cells at or below this probability (percent) are free for the daemon's planner.
OCCUPANCY_FREE_MAX_PERCENT = 35
#: Cells at or above this probability (percent) are obstacles for the daemon's planner.
OCCUPANCY_OCCUPIED_MIN_PERCENT = 65
#: The most cells along one side of the grid.
OCCUPANCY_MAX_SIDE_CELLS = 2048
#: ``OccupancyHeader.up_axis`` values.
UP_AXES = ("z", "y", "-y")
#: Bytes of :class:`OccupancyHeader`.
OCCUPANCY_HEADER_BYTES = 112

_u8, _u32, _u64, _f32 = ctypes.c_uint8, ctypes.c_uint32, ctypes.c_uint64, ctypes.c_float


class OccupancyHeader(_Wire):
    """The header of one occupancy map (112 bytes, alignment 8): ``op3dsg::OccupancyHeader``."""

    _fields_ = [
        ("schema_version", _u32),
        ("width_cells", _u32),
        ("height_cells", _u32),
        ("cell_size_m", _f32),
        ("origin_x_m", _f32),
        ("origin_y_m", _f32),
        ("floor_height_m", _f32),
        ("obstacle_min_height_m", _f32),
        ("obstacle_max_height_m", _f32),
        ("up_axis", _u8),
        ("robot_pose_valid", _u8),
        ("reserved", _u8 * 2),
        ("instance_id", _u64),
        ("stamp_ns", _u64),
        ("publish_time_ns", _u64),
        ("keyframes_integrated", _u64),
        ("keyframes_dropped", _u64),
        ("robot_x_m", _f32),
        ("robot_y_m", _f32),
        ("robot_yaw_rad", _f32),
        ("integrate_p50_us", _u32),
        ("integrate_p99_us", _u32),
        ("free_cells", _u32),
        ("occupied_cells", _u32),
        ("reserved2", _u32),
    ]

    @staticmethod
    def type_name() -> str:
        return "op3dsg::OccupancyHeader"

    def cell_count(self) -> int:
        return int(self.width_cells) * int(self.height_cells)


def check_occupancy_header(service: str, header: OccupancyHeader, cell_bytes: int) -> None:
    """The header against the contract: schema, side lengths, and ``cell_bytes`` (the payload)
    equal to ``width_cells * height_cells``. Raises :class:`SchemaVersionError` or
    :class:`InvalidGraphError` naming ``service``."""
    if header.schema_version != OCCUPANCY_SCHEMA_VERSION:
        raise SchemaVersionError(service, header.schema_version, OCCUPANCY_SCHEMA_VERSION)
    for field in ("width_cells", "height_cells"):
        value = getattr(header, field)
        if value > OCCUPANCY_MAX_SIDE_CELLS:
            raise InvalidGraphError(service, "receive", f"invalid map: {field}: {value} exceeds {OCCUPANCY_MAX_SIDE_CELLS}")
    if cell_bytes != header.cell_count():
        raise InvalidGraphError(
            service,
            "receive",
            f"invalid map: {cell_bytes} cell bytes, but width_cells * height_cells = "
            f"{header.width_cells} * {header.height_cells} = {header.cell_count()}",
        )


class OccupancyMap:
    """One occupancy map: its :class:`OccupancyHeader` (``header``, also readable as attributes:
    ``grid.width_cells``, ``grid.robot_x_m``, ...) and ``cells``, a read-only ``int8`` array of
    shape ``(height_cells, width_cells)``. ``version`` counts the maps the daemon published over
    Zenoh (``None`` over iceoryx2, which carries no count)."""

    def __init__(self, header: OccupancyHeader, cells: np.ndarray, version: Optional[int] = None):
        self.header = header
        self.cells = cells
        self.version = version

    def __getattr__(self, name: str):
        # The header's fields, read through (only called for names the map itself lacks).
        header = self.__dict__.get("header")
        if header is not None and name in OccupancyHeader.field_names():
            return getattr(header, name)
        raise AttributeError(f"{type(self).__name__} has no attribute {name!r}")

    @property
    def up_axis(self) -> str:
        """``z``, ``y`` or ``-y`` (the daemon's ``world.up_axis``)."""
        value = int(self.header.up_axis)
        return UP_AXES[value] if value < len(UP_AXES) else f"unknown({value})"

    @property
    def robot_pose(self) -> Optional[Tuple[float, float, float]]:
        """``(x_m, y_m, yaw_rad)`` of the robot on the plane, ``None`` before a keyframe."""
        h = self.header
        return (float(h.robot_x_m), float(h.robot_y_m), float(h.robot_yaw_rad)) if h.robot_pose_valid else None

    def free(self) -> np.ndarray:
        """Boolean mask of the cells the daemon's planner takes as free."""
        return (self.cells >= 0) & (self.cells <= OCCUPANCY_FREE_MAX_PERCENT)

    def occupied(self) -> np.ndarray:
        """Boolean mask of the cells the daemon's planner takes as obstacles."""
        return self.cells >= OCCUPANCY_OCCUPIED_MIN_PERCENT

    def unknown(self) -> np.ndarray:
        """Boolean mask of the cells never observed."""
        return self.cells == OCCUPANCY_UNKNOWN

    def cell_of(self, x_m: float, y_m: float) -> Optional[Tuple[int, int]]:
        """``(row, col)`` of the cell holding the plane point ``(x_m, y_m)``, ``None`` off the map."""
        h = self.header
        col = int(np.floor((x_m - h.origin_x_m) / h.cell_size_m))
        row = int(np.floor((y_m - h.origin_y_m) / h.cell_size_m))
        if 0 <= col < h.width_cells and 0 <= row < h.height_cells:
            return row, col
        return None

    def centre_of(self, row: int, col: int) -> Tuple[float, float]:
        """The plane point at the centre of cell ``(row, col)``."""
        h = self.header
        return (float(h.origin_x_m + (col + 0.5) * h.cell_size_m), float(h.origin_y_m + (row + 0.5) * h.cell_size_m))

    def __repr__(self) -> str:
        h = self.header
        return (
            f"OccupancyMap({h.width_cells}x{h.height_cells} cells of {h.cell_size_m:g} m, "
            f"instance_id={h.instance_id:#018x}, keyframes={h.keyframes_integrated}, version={self.version})"
        )


def occupancy_map(service: str, header_bytes: bytes, cells, version: Optional[int] = None) -> OccupancyMap:
    """An :class:`OccupancyMap` from the header's 112 bytes and the cells (a buffer of
    ``width_cells * height_cells`` bytes, viewed, not copied), checked."""
    header = OccupancyHeader.from_buffer_copy(header_bytes)
    cells = np.frombuffer(cells, dtype=np.int8)
    check_occupancy_header(service, header, cells.size)
    grid = cells.reshape(int(header.height_cells), int(header.width_cells))
    grid.flags.writeable = False
    return OccupancyMap(header, grid, version)


class OccupancyClient(_iox.LatestClient):
    """Reads ``<prefix>/occupancy`` over iceoryx2: :meth:`latest` gives the newest map as an
    :class:`OccupancyMap` with cells of its own (copied out of the shared memory, so it stays
    valid). The constructor waits for the service's history, the daemon's newest map (up to
    one second; it comes within 20 ms), so the first :meth:`latest` returns it. ``timeout`` (seconds): how long the constructor waits for a daemon that is not up yet;
    a daemon with ``occupancy.enabled = false`` has no such service
    (:class:`~op3dsg.errors.NotServingError`)."""

    def __init__(self, prefix: Optional[str] = None, timeout: float = 0.0, node_name: Optional[str] = None):
        self.prefix = prefix = _iox.resolve_prefix(prefix)
        self.service = _iox.service_name(prefix, "occupancy")
        deadline = _iox.deadline_after(timeout)
        name = node_name or _iox.default_node_name("occupancy")
        self._node = _iox.retry_while_not_serving(timeout, lambda: _iox.create_node(prefix, self.service, name))
        self._subscriber = _iox.retry_while_not_serving(_iox.left_until(deadline), self._open)
        _iox.await_history(self.service, self._subscriber)
        self._latest: Optional[OccupancyMap] = None

    def _open(self):
        try:
            service = (
                self._node.service_builder(iox2.ServiceName.new(self.service))
                .publish_subscribe(iox2.Slice[ctypes.c_int8])
                .user_header(OccupancyHeader)
                .open()
            )
        except Exception as e:
            raise _iox.open_error(self.service, e) from e
        try:
            return service.subscriber_builder().history_request(HISTORY_SIZE).create()
        except Exception as e:
            raise _iox.open_error(self.service, e, "create subscriber") from e

    def latest(self) -> Optional[OccupancyMap]:
        """Takes every queued map and returns the newest received so far (``None`` while none
        came). A map that breaks the contract raises :class:`~op3dsg.errors.SchemaVersionError`
        or :class:`~op3dsg.errors.InvalidGraphError`."""
        while True:
            try:
                sample = self._subscriber.receive()
            except Exception as e:
                raise _iox.open_error(self.service, e, "receive") from e
            if sample is None:
                return self._latest
            try:
                header = ctypes.string_at(sample.user_header_ptr, OCCUPANCY_HEADER_BYTES)
                length = int(sample.header.number_of_elements)
                cells = ctypes.string_at(sample.payload_ptr, length) if length else b""
            finally:
                sample.delete()
            self._latest = occupancy_map(self.service, header, cells)

    def wait(self, timeout: float, newer_than_ns: int = 0) -> OccupancyMap:
        """The newest map published after ``newer_than_ns`` (its ``publish_time_ns``), waiting up
        to ``timeout`` seconds; ``TimeoutError`` naming the service otherwise."""
        return self._wait_newer(
            timeout,
            newer_than_ns,
            lambda grid: grid.header.publish_time_ns,
            f"occupancy map within {timeout:.1f} s (is op3dsgd running with occupancy.enabled?)",
        )

    def __repr__(self) -> str:
        return f"OccupancyClient(prefix={self.prefix!r})"


__all__ = [
    "OCCUPANCY_FREE_MAX_PERCENT",
    "OCCUPANCY_OCCUPIED_MIN_PERCENT",
    "OCCUPANCY_SCHEMA_VERSION",
    "OCCUPANCY_UNKNOWN",
    "OccupancyClient",
    "OccupancyHeader",
    "OccupancyMap",
    "occupancy_map",
]
