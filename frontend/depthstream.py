"""Depth frames made ready for the per-frame stage: metres, the camera model and the mount, per frame.

Fed every record of a log in order, it absorbs camera infos and /tf_static and turns each depth image into
a `DepthItem`; `kosmap planes`, `kosmap scan` and the pipeline all resolve frames this way.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from kosmap.frontend.camera import DepthConfig, camera_for, camera_mount
from kosmap.frontend.logs.topics import DetectedTopics
from kosmap.frontend.records import CameraModel, DepthFrame, Transform, Transforms


@dataclass
class DepthItem:
    """One depth frame ready to filter: depth in metres (0/NaN invalid), its camera, its mount in base_link."""

    index: int  # per log, over all depth topics, in time order: the frame's seed offset
    stamp_ns: int
    depth: np.ndarray
    camera: CameraModel
    mount: Transform  # base_link ← the image's optical frame
    topic: str
    frame_id: str
    mount_source: str = "config"  # "tf_static" or "config"


class DepthResolver:
    """Turns DepthFrame records into DepthItems, remembering camera infos and static transforms seen so far."""

    def __init__(self, det: DetectedTopics, depth_cfg: DepthConfig) -> None:
        self.det = det
        self.cfg = depth_cfg
        self.infos: dict[str, CameraModel] = {}
        self.statics: list[Transforms] = []
        self._mounts: dict[str, tuple[Transform, str]] = {}
        self.count = 0

    def observe(self, rec) -> DepthItem | None:
        """A DepthItem for a depth frame of a detected topic; None for anything else (which it may absorb)."""
        if isinstance(rec, Transforms):
            if rec.static:
                self.statics.append(rec)
                self._mounts.clear()
            return None
        if isinstance(rec, CameraModel):
            self.infos[rec.topic] = rec
            return None
        if not isinstance(rec, DepthFrame) or rec.topic not in self.det.depth:
            return None
        depth = rec.meters()
        info = self.infos.get(self.det.info.get(rec.topic) or "")
        cam = camera_for(depth.shape, info, self.cfg, rec.frame_id)
        if rec.frame_id not in self._mounts:
            self._mounts[rec.frame_id] = camera_mount(self.statics, rec.frame_id, self.cfg)
        mount, source = self._mounts[rec.frame_id]
        item = DepthItem(self.count, rec.stamp_ns, depth, cam, mount, rec.topic, rec.frame_id or "camera", source)
        self.count += 1
        return item
