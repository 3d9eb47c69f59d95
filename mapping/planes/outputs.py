"""The planes run's per-frame outputs: the plane points as npz, the processed depth as 16-bit PNG, and the plane
points and normals in planes.mcap (with each camera's mount on /tf_static, for Foxglove)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from kosmap.frontend.planes import Planes
from kosmap.frontend.records import Transform, Transforms
from kosmap.mapping.planes.frames import Item

CLOUD_TOPIC = "/kosmap/planes/points"
NORMALS_TOPIC = "/kosmap/planes/normals"


def normal_quaternions(normals: np.ndarray) -> np.ndarray:
    """Quaternions (x, y, z, w) turning the x axis onto each normal (arrows in Foxglove's PoseArray)."""
    n = np.asarray(normals, float)
    q = np.column_stack((np.zeros(len(n)), -n[:, 2], n[:, 1], 1.0 + n[:, 0]))
    bad = q[:, 3] < 1e-9  # normal along −x: half a turn about z
    q[bad] = [0.0, 0.0, 1.0, 0.0]
    return q / np.linalg.norm(q, axis=1, keepdims=True)


def save_npz(path: Path, planes: Planes, item: Item) -> None:
    """The frame's plane points, their planes and pixels, the planes' normals, offsets, classes and counts, with
    the frame's stamp, camera and mount."""
    np.savez_compressed(path, points=planes.points, plane=planes.plane.astype(np.int32),
                        pixels=planes.pixels.astype(np.uint16), normals=planes.normals, offsets=planes.offsets,
                        classes=planes.classes, counts=planes.counts, stamp_ns=np.int64(item.stamp_ns),
                        shape=np.array(planes.shape), frame_id=np.array(item.frame_id), source=np.array(item.source),
                        K=item.camera.K, mount=item.mount.matrix())


def save_depth_png(path: Path, planes: Planes) -> None:
    """The processed depth (plane points only) as a 16-bit PNG in millimetres."""
    import cv2

    mm = np.clip(np.round(planes.depth_image() * 1000.0), 0, 65535).astype(np.uint16)
    cv2.imwrite(str(path), mm)


class PlanesMcap:
    """planes.mcap: per frame ≤ `max_points` plane points (a random subset, seeded by the frame) as a PointCloud2
    with their plane, class and depth, and the planes' centroids and normals as a PoseArray; each camera's mount
    once on /tf_static."""

    def __init__(self, path: Path, max_points: int) -> None:
        from kosmap.frontend.logs.writer import McapWriter

        self.writer = McapWriter(path)
        self.max_points = max_points
        self.mounts_written: set[str] = set()

    def write(self, planes: Planes, item: Item, seed: int) -> None:
        if item.frame_id not in self.mounts_written:
            tf = Transform(item.mount.parent, item.frame_id, item.mount.translation, item.mount.rotation,
                           item.stamp_ns)
            self.writer.write(Transforms(item.stamp_ns, (tf,), True, "/tf_static"))
            self.mounts_written.add(item.frame_id)
        self._frame(planes, item, seed)

    def _frame(self, planes: Planes, item: Item, seed: int) -> None:
        from kosmap.frontend.logs import convert

        p, idx = planes.points, planes.plane
        if len(p) > self.max_points:
            sel = np.sort(np.random.default_rng(seed).choice(len(p), self.max_points, replace=False))
            p, idx = p[sel], idx[sel]
        cls = planes.classes[idx] if len(idx) else np.zeros(0)
        t = item.stamp_ns
        self.writer.write_pointcloud(CLOUD_TOPIC, t, item.frame_id, p,
                                     {"plane": idx.astype(np.float32), "class": cls.astype(np.float32),
                                      "depth": p[:, 2]})
        centroids = np.zeros((len(planes), 3))
        if len(planes):
            for k in range(3):
                centroids[:, k] = np.bincount(planes.plane, planes.points[:, k], minlength=len(planes))
            centroids /= np.maximum(planes.counts, 1)[:, None]
        msg = convert.pose_array_msg(self.writer.ts, t, item.frame_id, centroids, normal_quaternions(planes.normals))
        self.writer.write_msg(NORMALS_TOPIC, "geometry_msgs/msg/PoseArray", msg, t)

    def close(self) -> None:
        self.writer.close()

    def abort(self) -> None:
        self.writer.abort()
