"""op3dsg: the Python client of ``op3dsgd``, the live 3D scene graph daemon.

Two lines read the graph as numpy views of the daemon's shared memory (no copy)::

    import op3dsg
    graph = op3dsg.GraphClient("op3dsg", timeout=30).latest()   # None until the first graph

- :class:`GraphClient` — ``latest()``, ``latest_if_newer(version)``, ``wait_for_update(timeout)``,
  ``restarted``; returns :class:`GraphView` (``nodes`` / ``edges`` structured arrays viewing the
  sample, the lookups of the Rust ``GraphView`` by index: ``node(id)``, ``index_of``,
  ``parts_of``, ``parent_of``, ``edges_from``, ``edges_to``, ``find_by_label``,
  ``find_by_label_containing``, ``find_by_affordance``; ``copy()`` to an owned :class:`Graph`,
  labels decoded on demand; ``with`` gives the sample back at the end).
- Every client takes ``prefix=None`` as ``$OP3DSG_PREFIX``, else ``op3dsg`` (:func:`default_prefix`),
  as the ``op3dsg`` command does.
- :class:`PosePublisher` — sends poses on ``<prefix>/pose`` (creates the service if nobody has).
- :func:`query` / :class:`QueryClient` — the nodes that serve a need in words ("somewhere to
  wash my hands"), from ``<prefix>/query`` (needs the daemon's text encoder), each with its
  approach pose.
- :func:`goal` — where to stand to reach a node (by id, or the top hit of a need in words): an
  approach pose on the daemon's occupancy map, reachable from the robot's pose.
- :func:`health` / :class:`HealthClient` — the daemon's health record, without a graph subscriber.
- :class:`OccupancyClient` — the daemon's 2D occupancy map (:class:`OccupancyMap`: header and
  ``int8`` cells ``[row, col]``).
- :mod:`op3dsg.wire` — the ctypes mirror of the Rust wire types, numpy dtypes, constants.
- :mod:`op3dsg.remote` — the same from another computer, over Zenoh (``pip install
  "op3dsg[zenoh]"``): :class:`RemoteGraphClient` follows the graph (full graphs and deltas) and
  hands out :class:`Graph`; :class:`RemoteQueryClient` / :func:`remote_query` /
  :func:`remote_goal`, :func:`remote_health`, :class:`RemoteOccupancyClient` /
  :func:`remote_occupancy`::

      remote = op3dsg.RemoteGraphClient("tcp/192.168.1.20:7447", "op3dsg/stretch-1", timeout=30)
      graph = remote.wait_for_graph(30)

Same iceoryx2 as the daemon: PyPI ``iceoryx2==0.10.0``. Zenoh (PyPI ``eclipse-zenoh``) is
imported only when a remote client is made.
"""

from .errors import (
    AccessDeniedError,
    Iceoryx2Error,
    InvalidEndpointError,
    InvalidGraphError,
    InvalidPoseError,
    InvalidPrefixError,
    InvalidRemoteMessageError,
    NotServingError,
    Op3dsgError,
    RemoteError,
    RemoteTimeoutError,
    SampleReleasedError,
    SchemaVersionError,
    SubscriberSlotsFullError,
)
from ._iox import default_prefix
from .graph import Graph, GraphClient, GraphView, wait_for_graph
from .health import HealthClient, health
from .occupancy import OccupancyClient, OccupancyHeader, OccupancyMap
from .query import Approach, Goal, GoalError, Hit, QueryClient, QueryError, QueryResult, goal, query
from .remote import (
    RemoteFollower,
    RemoteGraphClient,
    RemoteHealth,
    RemoteOccupancyClient,
    RemoteQueryClient,
    remote_goal,
    remote_health,
    remote_occupancy,
    remote_query,
)
from .pose import PosePublisher, PoseService, check_pose, make_pose, open_or_create_pose_service
from .wire import (
    AFFORDANCES,
    DEFAULT_PREFIX,
    EDGE_DTYPE,
    FUNCTIONAL_RELATIONS,
    NO_NODE,
    NODE_DTYPE,
    POSE_SOURCES,
    POSE_WORLD_FROM_BASE,
    POSE_WORLD_FROM_CAMERA,
    PREFIX_ENV,
    SCHEMA_VERSION,
    SOURCE_KINDS,
    SPATIAL_RELATIONS,
    GraphHeader,
    Health,
    PoseStamped,
    affordance_names,
    affordance_origin,
    affordance_origins,
    fixed_str,
    relation_phrase,
)

__version__ = "0.1.0"

__all__ = [
    "Approach",
    "Goal",
    "GoalError",
    "goal",
    "Hit",
    "QueryClient",
    "QueryError",
    "QueryResult",
    "query",
    "AFFORDANCES",
    "DEFAULT_PREFIX",
    "EDGE_DTYPE",
    "FUNCTIONAL_RELATIONS",
    "Graph",
    "GraphClient",
    "GraphHeader",
    "GraphView",
    "Health",
    "HealthClient",
    "Iceoryx2Error",
    "InvalidEndpointError",
    "InvalidGraphError",
    "InvalidPoseError",
    "InvalidPrefixError",
    "InvalidRemoteMessageError",
    "NODE_DTYPE",
    "NO_NODE",
    "NotServingError",
    "OccupancyClient",
    "OccupancyHeader",
    "OccupancyMap",
    "Op3dsgError",
    "POSE_WORLD_FROM_BASE",
    "POSE_WORLD_FROM_CAMERA",
    "PREFIX_ENV",
    "PosePublisher",
    "PoseService",
    "PoseStamped",
    "RemoteError",
    "RemoteFollower",
    "RemoteGraphClient",
    "RemoteHealth",
    "RemoteOccupancyClient",
    "RemoteQueryClient",
    "RemoteTimeoutError",
    "SCHEMA_VERSION",
    "POSE_SOURCES",
    "SOURCE_KINDS",
    "SPATIAL_RELATIONS",
    "SampleReleasedError",
    "SchemaVersionError",
    "SubscriberSlotsFullError",
    "affordance_names",
    "affordance_origin",
    "affordance_origins",
    "check_pose",
    "default_prefix",
    "fixed_str",
    "health",
    "make_pose",
    "open_or_create_pose_service",
    "relation_phrase",
    "remote_goal",
    "remote_health",
    "remote_occupancy",
    "remote_query",
    "wait_for_graph",
]
