"""The spill: what pass 2 needs of every time step (KOS scans of every band, laser scans, fused scans, plane
points), appended to files in a temporary folder during the read pass and read back in chunks, so memory stays
flat however long the log."""

from __future__ import annotations

from array import array
from pathlib import Path

import numpy as np

from kosmap.frontend.records import Scan


class Series:
    """Fixed-width float32 rows appended to a file, with a stamp per row added by `add` (8 bytes a scan: all the
    series keeps in memory); read back in chunks (`RowReader`)."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self.fh = open(path, "wb")
        self.stamps = array("q")
        self.rows = 0
        self.width = 0
        self.meta: dict = {}

    def add(self, stamp_ns: int, row: np.ndarray) -> bool:
        row = np.ascontiguousarray(row, np.float32).reshape(-1)
        if self.width == 0:
            self.width = row.size
        elif row.size != self.width:
            return False  # a scan of another shape (a changed laser configuration): skipped
        self.fh.write(row.tobytes())
        self.stamps.append(int(stamp_ns))
        self.rows += 1
        return True

    def add_rows(self, rows: np.ndarray) -> int:
        """Several rows at once, without stamps (the caller indexes them: Spill.cloud_index); returns the first
        row's number. A stamp per row here cost 8 bytes per plane point, 19 MB over a 10-minute log."""
        rows = np.ascontiguousarray(rows, np.float32)
        if self.width == 0:
            self.width = rows.shape[1]
        self.fh.write(rows.tobytes())
        first = self.rows
        self.rows += len(rows)
        return first

    def __len__(self) -> int:
        return self.rows

    def close(self) -> None:
        if not self.fh.closed:
            self.fh.close()

    def reader(self) -> RowReader:
        self.close()
        return RowReader(self.path, max(self.width, 1))


class RowReader:
    """Rows of a spill file, read forward in chunks: no memory map, whose touched pages would count as resident
    memory growing with the log."""

    def __init__(self, path: Path | str, width: int, chunk: int = 512) -> None:
        self.fh = open(path, "rb")
        self.width, self.chunk = int(width), chunk
        self.lo = 0
        self.buf = np.zeros((0, self.width), np.float32)

    def get(self, i: int) -> np.ndarray:
        if not self.lo <= i < self.lo + len(self.buf):
            self.fh.seek(4 * i * self.width)
            self.buf = np.fromfile(self.fh, np.float32, count=self.chunk * self.width).reshape(-1, self.width)
            self.lo = i
        return self.buf[i - self.lo]

    def block(self, first: int, n: int) -> np.ndarray:
        self.fh.seek(4 * first * self.width)
        return np.fromfile(self.fh, np.float32, count=n * self.width).reshape(-1, self.width)

    def close(self) -> None:
        self.fh.close()


class Spill:
    """Temporary files for pass 2: KOS steps (every band, NaN out of view), laser scans, fused scans, plane points."""

    def __init__(self, folder: Path, bands: list[str]) -> None:
        self.folder = folder
        self.bands = bands  # the KOS scans of a step, in a row of `kos` in this order
        self.kos = Series(folder / "kos.f32")
        self.laser = Series(folder / "laser.f32")
        self.fused = Series(folder / "fused.f32")
        self.planes = Series(folder / "planes.f32")  # rows of 4: x y z class (base_link); one cloud per index entry
        self.cloud_index: list[tuple[int, int, int]] = []  # (stamp, first row, rows): one cloud a second

    def add_cloud(self, stamp_ns: int, pts: np.ndarray, cls: np.ndarray) -> None:
        first = self.planes.add_rows(np.column_stack((pts, cls)).astype(np.float32))
        self.cloud_index.append((int(stamp_ns), first, len(pts)))

    def close(self) -> None:
        for s in (self.kos, self.laser, self.fused, self.planes):
            s.close()


def scan_of(meta: dict, stamp: int, ranges: np.ndarray, topic: str = "") -> Scan:
    """A Scan of spilled ranges with its series' `meta` (angles, range limits, frame)."""
    return Scan(int(stamp), np.asarray(ranges, np.float32), meta["angle_min"], meta["angle_increment"],
                meta["range_min"], meta["range_max"], meta.get("frame_id", ""), topic,
                time_increment=meta.get("time_increment", 0.0))

