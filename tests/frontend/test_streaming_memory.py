"""Reading keeps memory flat in the log's length: frames are streamed, not collected."""

from __future__ import annotations

import tracemalloc

import numpy as np
import pytest

from kosmap.frontend.logs import open_log
from kosmap.frontend.logs.writer import open_writer
from kosmap.frontend.records import DepthFrame

W, H = 512, 424


def _write(path, n: int) -> int:
    yy, xx = np.mgrid[0:H, 0:W]
    base = (1000 + 3 * xx + 2 * yy).astype(np.uint16)  # smooth, so chunks compress like real depth
    with open_writer(path) as w:
        for i in range(n):
            w.write(DepthFrame(10**18 + i * 33_333_333, base + np.uint16(i), "16UC1", "cam", "/kinect2/sd/image_depth_rect"))
    return n * W * H * 2


@pytest.mark.slow
@pytest.mark.parametrize("suffix", [".mcap", ".bag"])
def test_peak_memory_does_not_grow_with_log_length(tmp_path, suffix):
    peaks = []
    for n in (30, 150):
        path = tmp_path / f"log{n}{suffix}"
        decoded = _write(path, n)
        tracemalloc.start()
        count = 0
        with open_log(path) as log:
            for rec in log.read():
                count += 1
                assert rec.image[0, 0] == 1000 + (count - 1)
        _, peak = tracemalloc.get_traced_memory()
        tracemalloc.stop()
        assert count == n
        peaks.append(peak)
        assert peak < 0.25 * decoded or n == 30
    # Five times the frames may not cost more than a chunk's worth (a few MB) of extra peak memory.
    print(f"peak {suffix}: {[p >> 20 for p in peaks]} MB for 30 and 150 frames")
    assert peaks[1] - peaks[0] < 8 << 20, peaks
