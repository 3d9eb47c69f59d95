"""`kosmap info` on a real log prints what `rosbag info` would, plus what kosmap will use."""

from __future__ import annotations

import pytest

from tests.conftest import require_data
from kosmap.tools.cli import main


@pytest.mark.data
def test_info_on_the_intel_bag(capsys):
    code = main(["info", str(require_data("laser/intel/intel.orig.bag"))])
    out = capsys.readouterr().out
    assert code == 0
    assert "ROS 1 bag" in out and "2691.3 s" in out
    assert "13631" in out and "26915" in out
    assert "sensor_msgs/msg/LaserScan" in out
    line = next(ln for ln in out.splitlines() if ln.strip().startswith("scan:"))
    assert "/scan" in line
