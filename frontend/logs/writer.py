"""Writing logs: MCAP with ROS 2 (CDR) messages for Foxglove and ROS 2 tools, and ROS 1 bags.

Message definitions come from rosbags' typestore, never hand-written. Output goes to `<name>.partial`
and is renamed only when closed cleanly, so an interrupted run leaves nothing that looks complete.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
from mcap.writer import CompressionType, Writer

from kosmap.frontend.logs import cdrfast, convert
from kosmap.frontend.logs import topics as T
from kosmap.frontend.records import Record, Scan


class _AtomicFile:
    """A `.partial` file that becomes `path` on commit() and disappears on abort()."""

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self.tmp = self.path.with_name(self.path.name + ".partial")

    def commit(self) -> None:
        os.replace(self.tmp, self.path)

    def abort(self) -> None:
        self.tmp.unlink(missing_ok=True)


class LogWriter:
    """Common record API of the MCAP and bag writers; `write_msg` is the per-format primitive."""

    ros_version = 2

    def __init__(self, path: str | Path) -> None:
        self._out = _AtomicFile(path)
        self.ts = convert.typestore(self.ros_version)
        self.path = self._out.path

    # -- records -----------------------------------------------------------------------------------------------
    def write(self, rec: Record, topic: str | None = None) -> None:
        """Write a record on its own topic (or `topic`), stamped with its header time."""
        msgtype, msg = convert.record_msg(self.ts, rec)
        self.write_msg(topic or rec.topic, msgtype, msg, rec.stamp_ns)

    def write_scan(self, topic: str, scan: Scan) -> None:
        self.write(scan, topic)

    def write_pointcloud(self, topic: str, t_ns: int, frame_id: str, points: np.ndarray,
                         extra: dict[str, np.ndarray] | None = None) -> None:
        self.write_msg(topic, "sensor_msgs/msg/PointCloud2", convert.pointcloud_msg(self.ts, t_ns, frame_id, points, extra), t_ns)

    def write_grid(self, topic: str, t_ns: int, frame_id: str, data: np.ndarray, resolution: float, origin) -> None:
        self.write_msg(topic, "nav_msgs/msg/OccupancyGrid",
                       convert.occupancy_grid_msg(self.ts, t_ns, frame_id, data, resolution, origin), t_ns)

    def write_path(self, topic: str, t_ns: int, frame_id: str, poses: np.ndarray, stamps_ns: np.ndarray) -> None:
        self.write_msg(topic, "nav_msgs/msg/Path", convert.path_msg(self.ts, t_ns, frame_id, poses, stamps_ns), t_ns)

    # -- lifecycle -----------------------------------------------------------------------------------------------
    def write_msg(self, topic: str, msgtype: str, msg, t_ns: int) -> None:
        raise NotImplementedError

    def _finish(self) -> None:
        raise NotImplementedError

    def close(self) -> None:
        self._finish()
        self._out.commit()

    def abort(self) -> None:
        try:
            self._finish()
        finally:
            self._out.abort()

    def __enter__(self):
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc_type is None:
            self.close()
        else:
            self.abort()


class McapWriter(LogWriter):
    """MCAP, profile ros2, CDR messages, chunk-compressed (zstd by default; lz4 writes ~4× faster)."""

    ros_version = 2

    def __init__(self, path: str | Path, compression: str = "zstd", chunk_size: int = 4 << 20) -> None:
        super().__init__(path)
        comp = {"zstd": CompressionType.ZSTD, "lz4": CompressionType.LZ4, "none": CompressionType.NONE}[compression]
        self._fh = open(self._out.tmp, "wb")
        self._w = Writer(self._fh, chunk_size=chunk_size, compression=comp)
        self._w.start(profile="ros2", library="kosmap")
        self._schemas: dict[str, int] = {}
        self._channels: dict[str, int] = {}
        self._seq: dict[int, int] = {}

    def _channel(self, topic: str, msgtype: str) -> int:
        if topic not in self._channels:
            if msgtype not in self._schemas:
                text, _ = self.ts.generate_msgdef(msgtype, ros_version=2)
                self._schemas[msgtype] = self._w.register_schema(msgtype, "ros2msg", text.encode())
            self._channels[topic] = self._w.register_channel(topic, "cdr", self._schemas[msgtype])
        return self._channels[topic]

    def write(self, rec: Record, topic: str | None = None) -> None:
        if type(rec) is Scan:  # its CDR written directly (frontend/logs/cdrfast.py): the same bytes, 14 → 3 µs
            self._add(topic or rec.topic, T.LASER_SCAN, cdrfast.laser_scan(rec), rec.stamp_ns)
            return
        super().write(rec, topic)

    def write_msg(self, topic: str, msgtype: str, msg, t_ns: int) -> None:
        self._add(topic, msgtype, bytes(self.ts.serialize_cdr(msg, msgtype)), t_ns)

    def _add(self, topic: str, msgtype: str, data: bytes, t_ns: int) -> None:
        cid = self._channel(topic, msgtype)
        seq = self._seq.get(cid, 0)
        self._seq[cid] = seq + 1
        self._w.add_message(cid, log_time=int(t_ns), data=data, publish_time=int(t_ns), sequence=seq)

    def write_metadata(self, name: str, data: dict[str, str]) -> None:
        """An MCAP metadata record (name → string map), e.g. a simulator's settings and truths."""
        self._w.add_metadata(name, {str(k): str(v) for k, v in data.items()})

    def _finish(self) -> None:
        if not self._fh.closed:
            try:
                self._w.finish()
            finally:
                self._fh.close()


class BagWriter(LogWriter):
    """ROS 1 bag v2.0 via rosbags, with the Noetic typestore (its Header has `seq`; docs/dependencies.md)."""

    ros_version = 1

    def __init__(self, path: str | Path, compression: str | None = None, chunk_bytes: int | None = None) -> None:
        """`compression`: None, "bz2" or "lz4" per chunk; `chunk_bytes`: a chunk's size (rosbags' default 1 MiB)."""
        from rosbags.rosbag1 import Writer as Ros1Writer

        super().__init__(path)
        self._out.abort()  # rosbags refuses to overwrite
        self._w = Ros1Writer(self._out.tmp)
        if compression is not None:
            self._w.set_compression(getattr(Ros1Writer.CompressionFormat, compression.upper()))
        if chunk_bytes is not None:
            self._w.chunk_threshold = chunk_bytes
        self._w.open()
        self._conns: dict[str, object] = {}
        self._open = True

    def write_msg(self, topic: str, msgtype: str, msg, t_ns: int) -> None:
        if topic not in self._conns:
            self._conns[topic] = self._w.add_connection(topic, msgtype, typestore=self.ts,
                                                        latching=1 if topic == "/tf_static" else None)
        self._w.write(self._conns[topic], int(t_ns), self.ts.serialize_ros1(msg, msgtype))

    def _finish(self) -> None:
        if self._open:
            self._open = False
            self._w.close()


def open_writer(path: str | Path, **kw) -> LogWriter:
    """An MCAP writer for `.mcap`, a ROS 1 bag writer for `.bag`."""
    return BagWriter(path) if str(path).endswith(".bag") else McapWriter(path, **kw)
