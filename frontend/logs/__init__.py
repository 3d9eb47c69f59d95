"""Reading and writing robot logs: MCAP (ROS 2), ROS 1 bags and CARMEN text logs behind one interface."""

from __future__ import annotations

from pathlib import Path

from kosmap.frontend.errors import LogError
from kosmap.frontend.logs.base import LogInfo, LogReader, TopicInfo
from kosmap.frontend.logs.topics import DetectedTopics, TopicsConfig, detect_topics

MCAP_MAGIC = b"\x89MCAP0\r\n"
BAG_MAGIC = b"#ROSBAG V2.0\n"

__all__ = ["open_log", "LogReader", "LogInfo", "TopicInfo", "DetectedTopics", "TopicsConfig", "detect_topics"]


def open_log(path: str | Path, on_damage: str = "skip") -> LogReader:
    """Open an MCAP, ROS 1 bag or CARMEN log by its content (not its name); LogError says what is wrong.
    `on_damage` ([topics] on_damage): what a read does with a damaged chunk ("skip", "read" or "fail")."""
    log = _open(Path(path))
    log.on_damage = on_damage
    return log


def _open(p: Path) -> LogReader:
    if not p.exists():
        raise LogError(f"{p} does not exist; give the path of a log (.mcap, .bag or .clf)")
    if p.is_dir():
        mcaps = sorted(p.glob("*.mcap"))
        hint = f"; for a rosbag2 folder pass the file inside, e.g. {mcaps[0]}" if mcaps else ""
        raise LogError(f"{p} is a directory; give the path of a log file (.mcap, .bag or .clf){hint}")
    try:
        with open(p, "rb") as f:
            head = f.read(4096)
    except OSError as e:
        raise LogError(f"cannot read {p}: {e.strerror}; check its permissions") from e
    if not head:
        raise LogError(f"{p} is empty; the recording may have failed")
    if head.startswith(MCAP_MAGIC):
        from kosmap.frontend.logs.mcap import McapLog

        return McapLog(p)
    if head.startswith(BAG_MAGIC):
        from kosmap.frontend.logs.rosbag import Ros1Bag

        return Ros1Bag(p)
    if head.startswith(b"#ROSBAG"):
        raise LogError(f"{p} is a ROS bag of version {head[8:12].decode(errors='replace').strip()}; kosmap reads version 2.0 (ROS 1)")
    from kosmap.frontend.logs.carmen import CarmenLog, looks_like_carmen

    if looks_like_carmen(head):
        return CarmenLog(p)
    if p.suffix == ".db3" or head.startswith(b"SQLite format 3"):
        raise LogError(f"{p} is a rosbag2 SQLite file; convert it to MCAP (`ros2 bag convert`) and pass that")
    raise LogError(f"{p} is not a log kosmap reads (MCAP, ROS 1 bag v2.0 or CARMEN .clf); check the file")
