"""Running many tasks: inline, in a pool of local worker processes (``parallel``), or on the Dask cluster of
``--cluster`` (``cluster``, which loads Dask only when a command is given --cluster). Above the robot side, which
never runs sweeps: .importlinter forbids it this subpackage, and with it Dask."""

from __future__ import annotations

from monodock.compute.cluster import active_client, cluster_session
from monodock.compute.parallel import SINGLE_THREAD_ENV, map_stream, map_with_state, worker_pool

__all__ = ["SINGLE_THREAD_ENV", "active_client", "cluster_session", "map_stream", "map_with_state", "worker_pool"]
