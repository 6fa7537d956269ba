"""Sending poses to the daemon: :class:`PosePublisher` on ``<prefix>/pose``.

The pose service may be created by any side, because the navigation stack may start before the
daemon. :func:`open_or_create_pose_service` follows the Rust ``open_or_create_pose_service``
exactly: it first *opens* the service stating no requirement beyond the payload type
(``op3dsg::PoseStamped``), so a service created with iceoryx2's default QoS (2 publishers,
8 subscribers, buffer 2, safe overflow) is opened as it is; when none exists it *creates* it
with the contract's QoS (safe overflow, subscriber buffer 64, 4 publishers, 4 subscribers). If
another process creates it in between, it is opened instead (a few rounds, 10 ms apart).
"""

from __future__ import annotations

import ctypes
import math
import time
from dataclasses import dataclass
from typing import Optional, Sequence

import iceoryx2 as iox2

from . import _iox
from .errors import Iceoryx2Error, InvalidPoseError
from .wire import (
    DEFAULT_POSE_BUFFER,
    NAME_CAPACITY_BYTES,
    POSE_MAX_PUBLISHERS,
    POSE_MAX_SUBSCRIBERS,
    POSE_WORLD_FROM_BASE,
    POSE_WORLD_FROM_CAMERA,
    QUATERNION_NORM_TOLERANCE,
    SAFE_OVERFLOW,
    PoseStamped,
)

#: Rounds of open, then create, before giving up.
OPEN_OR_CREATE_ATTEMPTS = 20
#: Pause between two rounds, seconds.
OPEN_OR_CREATE_RETRY_S = 0.01


@dataclass
class PoseService:
    """The ``pose`` service as :func:`open_or_create_pose_service` found it."""

    factory: object
    #: This call created the service (with the contract's QoS).
    created: bool
    #: It existed with a smaller subscriber buffer than asked for, and was opened as it is.
    smaller_buffer: bool
    #: It existed without safe overflow: a publisher may block or fail while a buffer is full.
    unsafe_overflow: bool


def open_or_create_pose_service(node, prefix: str, buffer: int = DEFAULT_POSE_BUFFER) -> PoseService:
    """Opens ``<prefix>/pose`` as it is, or creates it with the contract's QoS when it does not
    exist (see the module docs)."""
    service = _iox.service_name(prefix, "pose")
    _iox.validate_prefix(prefix, service)
    name = iox2.ServiceName.new(service)
    last: Optional[BaseException] = None
    for _ in range(OPEN_OR_CREATE_ATTEMPTS):
        try:
            factory = node.service_builder(name).publish_subscribe(PoseStamped).open()
            config = factory.static_config
            config = config() if callable(config) else config
            return PoseService(
                factory,
                created=False,
                smaller_buffer=config.subscriber_max_buffer_size < buffer,
                unsafe_overflow=not config.has_safe_overflow,
            )
        except Exception as e:
            if _iox.reason(e) != "DoesNotExist":
                raise _iox.open_error(service, e, "open") from e
        try:
            factory = (
                node.service_builder(name)
                .publish_subscribe(PoseStamped)
                .enable_safe_overflow(SAFE_OVERFLOW)
                .subscriber_max_buffer_size(buffer)
                .max_publishers(POSE_MAX_PUBLISHERS)
                .max_subscribers(POSE_MAX_SUBSCRIBERS)
                .create()
            )
            return PoseService(factory, created=True, smaller_buffer=False, unsafe_overflow=False)
        except Exception as e:
            if _iox.reason(e) not in ("AlreadyExists", "IsBeingCreatedByAnotherInstance"):
                raise Iceoryx2Error(service, "open or create", f"{type(e).__name__}: {_iox.reason(e)}") from e
            last = e
            time.sleep(OPEN_OR_CREATE_RETRY_S)
    raise Iceoryx2Error(service, "open or create", f"gave up after {OPEN_OR_CREATE_ATTEMPTS} rounds: {_iox.reason(last)}")


def make_pose(
    stamp_ns: int,
    translation_m: Sequence[float],
    rotation_xyzw: Sequence[float],
    kind: int = POSE_WORLD_FROM_CAMERA,
    frame_id: str = "",
) -> PoseStamped:
    """A :class:`~op3dsg.wire.PoseStamped` with every field set (reserved bytes zero)."""
    if len(translation_m) != 3 or len(rotation_xyzw) != 4:
        raise ValueError(f"translation_m needs 3 values, rotation_xyzw 4; got {len(translation_m)} and {len(rotation_xyzw)}")
    pose = PoseStamped()
    pose.stamp_ns = int(stamp_ns)
    pose.kind = int(kind)
    pose.translation_m[:] = [float(v) for v in translation_m]
    pose.rotation_xyzw[:] = [float(v) for v in rotation_xyzw]
    raw = frame_id.encode("utf-8")
    if len(raw) > NAME_CAPACITY_BYTES:
        raise ValueError(f"frame_id is {len(raw)} bytes, longer than {NAME_CAPACITY_BYTES}")
    ctypes.memmove(pose.frame_id, raw, len(raw))
    return pose


def check_pose(pose: PoseStamped) -> Optional[str]:
    """The Rust ``check_pose``: ``None`` for a pose the daemon accepts on the wire, else why not."""
    if pose.kind not in (POSE_WORLD_FROM_CAMERA, POSE_WORLD_FROM_BASE):
        return f"unknown kind {pose.kind} (0 world_from_camera, 1 world_from_base)"
    translation = list(pose.translation_m)
    if not all(math.isfinite(v) for v in translation):
        return f"non-finite translation {translation} m"
    rotation = list(pose.rotation_xyzw)
    if not all(math.isfinite(v) for v in rotation):
        return f"non-finite quaternion {rotation} (xyzw)"
    norm = math.sqrt(sum(v * v for v in rotation))
    if abs(norm - 1.0) > QUATERNION_NORM_TOLERANCE:
        return f"quaternion norm {norm} is not 1 (tolerance {QUATERNION_NORM_TOLERANCE})"
    return None


class PosePublisher:
    """Sends camera or base poses to the daemon on ``<prefix>/pose``.

    Works before the daemon starts (it creates the service then); poses sent while no daemon
    listens are lost (no history). Every pose is checked first: one the daemon would drop
    (non-finite, non-unit quaternion, unknown kind) raises :class:`~op3dsg.errors.InvalidPoseError`.
    Stamps are nanoseconds on the camera frames' clock (see the daemon's pose docs)::

        poses = op3dsg.PosePublisher("op3dsg")
        poses.publish(stamp_ns, [x, y, 0.0], [0, 0, sin(yaw / 2), cos(yaw / 2)], kind=op3dsg.POSE_WORLD_FROM_BASE)
    """

    def __init__(self, prefix: Optional[str] = None, node_name: Optional[str] = None):
        self.prefix = prefix = _iox.resolve_prefix(prefix)
        self.service = _iox.service_name(prefix, "pose")
        self._node = _iox.create_node(
            prefix, self.service, node_name or _iox.default_node_name("pose"), make_root=True
        )
        self.pose_service = open_or_create_pose_service(self._node, prefix, DEFAULT_POSE_BUFFER)
        try:
            self._publisher = self.pose_service.factory.publisher_builder().create()
        except Exception as e:
            why = _iox.reason(e)
            hint = ": every publisher slot of the service is taken" if why == "ExceedsMaxSupportedPublishers" else ""
            raise Iceoryx2Error(self.service, "create publisher", f"{type(e).__name__}: {why}{hint}") from e

    @property
    def created(self) -> bool:
        """This publisher created the service (nobody had before)."""
        return self.pose_service.created

    def publish(
        self,
        stamp_ns: int,
        translation_m: Sequence[float],
        rotation_xyzw: Sequence[float],
        kind: int = POSE_WORLD_FROM_CAMERA,
        frame_id: str = "",
    ) -> int:
        """Sends ``world_from_camera`` (or ``world_from_base`` with ``kind=POSE_WORLD_FROM_BASE``)
        valid at ``stamp_ns``. Returns the number of subscribers reached (0 while no daemon listens)."""
        try:
            pose = make_pose(stamp_ns, translation_m, rotation_xyzw, kind, frame_id)
        except ValueError as e:
            raise InvalidPoseError(self.service, "publish", f"invalid pose: {e}") from e
        return self.publish_stamped(pose)

    def publish_stamped(self, pose: PoseStamped) -> int:
        """Sends a pose built by the caller, after the same checks as :meth:`publish`."""
        problem = check_pose(pose)
        if problem is not None:
            raise InvalidPoseError(self.service, "publish", f"invalid pose: {problem}")
        return self.publish_unchecked(pose)

    def publish_unchecked(self, pose: PoseStamped) -> int:
        """Sends ``pose`` as it is, without the checks (for tests of the daemon's own checks)."""
        try:
            reached = self._publisher.send_copy(pose)
        except Exception as e:
            raise Iceoryx2Error(self.service, "publish", f"{type(e).__name__}: {_iox.reason(e)}") from e
        return int(reached) if reached is not None else 0

    def close(self) -> None:
        if getattr(self, "_publisher", None) is not None:
            self._publisher.delete()
            self._publisher = None

    def __enter__(self) -> "PosePublisher":
        return self

    def __exit__(self, *exc) -> None:
        self.close()
