"""Scan-matching odometry: scans (KOS or laser) registered against a local submap, fused with wheel odometry."""

from __future__ import annotations

from dataclasses import dataclass

from frontend.params import StageConfig, param


@dataclass
class OdometryConfig(StageConfig):
    """[odometry]: the scan-matching front end and its keyframes."""

    section = "odometry"
    matcher: str = param("submap", choices=("submap", "kiss-icp"), doc="scan-to-submap matcher or kiss-icp")
    keyframe_distance: float = param(0.1, lo=0.0, doc="new keyframe after this travel", unit="m")
    keyframe_angle_deg: float = param(5.0, lo=0.0, doc="new keyframe after this rotation", unit="deg")
    voxel_size: float = param(0.1, lo=0.0, lo_open=True, doc="kiss-icp voxel size", unit="m")
    min_range: float = param(0.1, lo=0.0, doc="ignore returns nearer than this", unit="m")
    max_range: float = param(30.0, lo=0.0, lo_open=True, doc="ignore returns farther than this", unit="m")
    use_wheel_odometry: bool = param(True, doc="use the log's wheel odometry as the motion prior")
