"""Depth-camera settings and geometry: which depths are usable, the field-of-view fallback, the mount."""

from __future__ import annotations

from dataclasses import dataclass

from frontend.params import StageConfig, param


@dataclass
class DepthConfig(StageConfig):
    """[depth]: thesis Table 5.4 (minDepth, maxDepth, fH, fV) and the mount used when /tf_static lacks one."""

    section = "depth"
    min_depth: float = param(0.5, lo=0.0, doc="nearer pixels are ineligible (thesis minDepth)", unit="m")
    max_depth: float = param(4.5, lo=0.0, lo_open=True, doc="farther pixels are ineligible (thesis maxDepth)", unit="m")
    fov_h_deg: float = param(70.6, lo=1.0, hi=179.0, doc="horizontal field of view when no CameraInfo", unit="deg")
    fov_v_deg: float = param(60.0, lo=1.0, hi=179.0, doc="vertical field of view when no CameraInfo", unit="deg")
    mount_xyz: list = param([0.0, 0.0, 1.0], doc="camera_link in base_link when /tf_static has no mount", unit="m")
    mount_rpy_deg: list = param([0.0, 0.0, 0.0], doc="camera_link roll, pitch, yaw in base_link (pitch > 0 looks down)", unit="deg")

    def __post_init__(self) -> None:
        super().__post_init__()
        from frontend.errors import ConfigError

        if self.max_depth <= self.min_depth:
            raise ConfigError(f"config [depth] max_depth = {self.max_depth} must be greater than min_depth = {self.min_depth}")
        for name in ("mount_xyz", "mount_rpy_deg"):
            if len(getattr(self, name)) != 3:
                raise ConfigError(f"config [depth] {name} = {getattr(self, name)!r} must have 3 numbers")
