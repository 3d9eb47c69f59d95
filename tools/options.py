"""CLI options shared by the commands: --config, --set and the topic overrides, folded into one Config."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Optional

import typer

from kosmap.mapping.config import Config, load_config, parse_override

def out_folder(text: str | Path) -> Path:
    """--out as typed: an empty one is refused (as a Path it would silently be the current folder)."""
    if not str(text).strip():
        raise typer.BadParameter("is empty; give a folder for the results (. for the current one)")
    return Path(text)


ConfigOpt = Annotated[Optional[Path], typer.Option("--config", "-c", help="TOML config file (a section per stage).")]
SetOpt = Annotated[Optional[list[str]], typer.Option("--set", "-s", help="Override a config value: section.key=value (repeatable).")]
DepthTopicOpt = Annotated[Optional[list[str]], typer.Option("--depth-topic", help="Depth image topic (repeat for several cameras).")]
InfoTopicOpt = Annotated[Optional[list[str]], typer.Option("--info-topic", help="Camera info topic, one per depth topic.")]
ScanTopicOpt = Annotated[Optional[str], typer.Option("--scan-topic", help="Laser scan topic.")]
OdomTopicOpt = Annotated[Optional[str], typer.Option("--odom-topic", help="Wheel odometry topic.")]
ImuTopicOpt = Annotated[Optional[str], typer.Option("--imu-topic", help="IMU topic (sensor_msgs/Imu); 'none' ignores the log's IMU.")]


def make_config(config: Path | None, sets: list[str] | None, depth_topic: list[str] | None = None,
                info_topic: list[str] | None = None, scan_topic: str | None = None, odom_topic: str | None = None,
                imu_topic: str | None = None) -> Config:
    """File ← --set ← topic flags (the most specific wins)."""
    overrides: dict = {}
    for s in sets or []:
        k, v = parse_override(s)
        overrides[k] = v
    if depth_topic:
        overrides["topics.depth"] = list(depth_topic)
    if info_topic:
        overrides["topics.info"] = list(info_topic)
    if scan_topic:
        overrides["topics.scan"] = scan_topic
    if odom_topic:
        overrides["topics.odom"] = odom_topic
    if imu_topic:
        overrides["topics.imu"] = imu_topic
    return load_config(config, overrides)
