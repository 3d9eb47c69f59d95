"""A build's maps with their full occupancy probabilities, read back from its kosmap.mcap.

The map_server files keep three values (free, occupied, unknown: map_server's trinary mode); the MCAP keeps each
cell's probability (0..100) on /kosmap/map/<name> (nav_msgs/OccupancyGrid), the evidence a merge of runs sums.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from kosmap.frontend.errors import LogError
from kosmap.frontend.logs.convert import typestore
from kosmap.mapping.grid import OccupancyGrid

MAP_TOPIC = "/kosmap/map/"  # + the map's name (mapping/build/mcap.py writes them)


def read_build_grid(mcap_path: str | Path, name: str) -> OccupancyGrid:
    """The map `name` (e.g. "laser", "kos_obstacle") of a build's kosmap.mcap; LogError when it has none."""
    from mcap.exceptions import McapError
    from mcap.reader import make_reader

    ts = typestore(2)
    topic = MAP_TOPIC + name
    try:
        with open(mcap_path, "rb") as fh:
            msg = None
            for _schema, _channel, m in make_reader(fh).iter_messages(topics=[topic]):
                msg = m  # the last one, should a file hold several
    except (OSError, McapError, ValueError) as e:
        raise LogError(f"{mcap_path}: cannot read its maps ({e}); build the log again") from e
    if msg is None:
        raise LogError(f"{mcap_path} holds no map {name!r} (topic {topic}); build the log again")
    g = ts.deserialize_cdr(msg.data, "nav_msgs/msg/OccupancyGrid")
    q = g.info.origin.orientation
    yaw = float(np.arctan2(2.0 * (q.w * q.z + q.x * q.y), 1.0 - 2.0 * (q.y * q.y + q.z * q.z)))
    data = np.asarray(g.data, np.int8).reshape(g.info.height, g.info.width)
    return OccupancyGrid(data.copy(), float(g.info.resolution),
                         (float(g.info.origin.position.x), float(g.info.origin.position.y), yaw), g.header.frame_id)
