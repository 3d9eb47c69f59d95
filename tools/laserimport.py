"""Importers for 2D laser logs in research formats that kosmap does not read directly: each becomes a CARMEN log
of ROBOTLASER1 lines (which carry the beams' start angle, step and maximum range, and the odometry pose), which
`kosmap slam LOG --source laser` and `kosmap build` read.

    .venv/bin/python -m kosmap.tools.laserimport IN OUT.clf [--format auto|breezyslam|dpslam|carmen] [--rate HZ]

- BreezySLAM / CoreSLAM `.dat` (the Mines ParisTech logs, Steux & El Hamzaoui 2010): one scan a line, the time in
  µs, the wheel encoders' ticks, then the ranges in mm of a Hokuyo URG-04LX (682 beams over 240°). The odometry is
  integrated from the ticks as a differential drive (BreezySLAM's examples/mines.py values: 2000 ticks a turn,
  wheel radius 77 mm, half axle 165 mm).
- DP-SLAM text (Eliazar & Parr, Duke): `Odometry x y θ` and `Laser 181 r…` lines in turn, a SICK's 181 beams
  from −90° to +90°, metres; no times.
- CARMEN FLASER logs without usable times (all zero, or not increasing): re-stamped.

A log without usable times gets one scan every 1/`rate` s (only the real-time factor depends on it). The maximum
range is the sensor's saturation value when the log shows one (a reading repeated on many beams at the top of the
range: the SICK's 8 m mode writes 8.183 for no return), else the sensor's nominal range.
"""

from __future__ import annotations

import argparse
import math
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from kosmap.frontend.errors import KosmapError

# BreezySLAM examples/mines.py (Rover) and breezyslam/sensors.py (URG04LX)
MINES_TICKS_PER_TURN = 2000
MINES_WHEEL_RADIUS = 0.077
MINES_HALF_AXLE = 0.165
URG04LX_FOV_DEG = 240.0
URG04LX_RANGE = 4.0  # BreezySLAM's "no detection" distance; readings up to ~5.6 m occur and are kept
SICK_RANGE = 80.0  # the LMS's nominal range (CARMEN logs mark no return at or above it)


@dataclass
class LaserLog:
    """Scans and odometry, one odometry pose per scan, as one sensor recorded them."""

    stamps: np.ndarray  # (S,) s
    ranges: np.ndarray  # (S, N) m, 0 = no return
    angle_min: float  # rad, first beam, counter-clockwise positive
    angle_increment: float  # rad
    max_range: float  # m: readings at or beyond it are no returns
    odometry: np.ndarray  # (S, 3) x, y, yaw
    source: str


def _saturation(ranges: np.ndarray, nominal: float) -> float:
    """The sensor's no-return value when the log shows one, else `nominal`: readings within 1 cm of the largest
    that make up ≥ 0.5 % of all readings are a saturation value (the SICK's 8 m mode writes 8.183–8.191, a 16-bit
    driver 32.767), and the returned range lies just below them."""
    r = ranges[np.isfinite(ranges) & (ranges > 0)]
    if len(r) == 0:
        return nominal
    top = float(r.max())
    return top - 0.01 if np.mean(r >= top - 0.01) >= 0.005 else max(nominal, top + 1e-3)


def _stamps(n: int, rate: float) -> np.ndarray:
    return np.arange(n, dtype=float) / rate


def read_breezyslam(path: Path) -> LaserLog:
    """A BreezySLAM `.dat` log (see the module docstring)."""
    t, ticks, rows = [], [], []
    for k, line in enumerate(path.read_text().splitlines()):
        toks = line.split()
        if not toks:
            continue
        if len(toks) < 26:
            raise KosmapError(f"{path.name} line {k + 1}: {len(toks)} fields where a BreezySLAM scan line has 24 + the "
                              f"ranges; is this a BreezySLAM .dat log?")
        t.append(float(toks[0]) * 1e-6)
        ticks.append((float(toks[2]), float(toks[3])))
        rows.append([float(x) * 1e-3 for x in toks[24:-1]])
    n = {len(r) for r in rows}
    if len(n) != 1:
        raise KosmapError(f"{path.name}: scans of {sorted(n)} beams; a BreezySLAM log has one beam count")
    beams = n.pop()
    tk = np.array(ticks)
    wheel = np.diff(tk, axis=0, prepend=tk[:1]) * (2 * math.pi / MINES_TICKS_PER_TURN) * MINES_WHEEL_RADIUS
    dl, dr = wheel[:, 0], wheel[:, 1]
    odo = np.zeros((len(t), 3))
    for i in range(1, len(t)):  # differential drive, midpoint heading
        d, dth = 0.5 * (dl[i] + dr[i]), (dr[i] - dl[i]) / (2 * MINES_HALF_AXLE)
        th = odo[i - 1, 2] + 0.5 * dth
        odo[i] = odo[i - 1] + (d * math.cos(th), d * math.sin(th), dth)
    ranges = np.array(rows)
    fov = math.radians(URG04LX_FOV_DEG)
    return LaserLog(np.array(t), ranges, -fov / 2, fov / (beams - 1), max(URG04LX_RANGE, float(ranges.max()) + 1e-3),
                    odo, "BreezySLAM .dat")


def read_dpslam(path: Path, rate: float) -> LaserLog:
    """A DP-SLAM text log (see the module docstring); each Laser line takes the Odometry line before it."""
    odo, rows, last = [], [], None
    for k, line in enumerate(path.read_text().splitlines()):
        toks = line.split()
        if not toks:
            continue
        if toks[0] == "Odometry" and len(toks) >= 4:
            last = tuple(float(x) for x in toks[1:4])
        elif toks[0] == "Laser" and len(toks) >= 2:
            n = int(toks[1])
            if len(toks) < 2 + n:
                raise KosmapError(f"{path.name} line {k + 1}: a Laser line of {n} beams has {len(toks) - 2}")
            if last is not None:
                rows.append([float(x) for x in toks[2:2 + n]])
                odo.append(last)
        else:
            raise KosmapError(f"{path.name} line {k + 1} starts with {toks[0]!r}; a DP-SLAM log has Odometry and Laser lines")
    if not rows:
        raise KosmapError(f"{path.name} has no Laser line after an Odometry line; is this a DP-SLAM log?")
    ranges = np.array(rows)
    beams = ranges.shape[1]
    return LaserLog(_stamps(len(rows), rate), ranges, -math.pi / 2, math.pi / (beams - 1), _saturation(ranges, SICK_RANGE),
                    np.array(odo), "DP-SLAM text")


def read_carmen_flaser(path: Path, rate: float) -> LaserLog:
    """A CARMEN log's FLASER lines (180° evenly, the odometry pose they carry), re-stamped at `rate`."""
    odo, rows = [], []
    for line in path.read_text(errors="replace").splitlines():
        toks = line.split()
        if not toks or toks[0] != "FLASER":
            continue
        n = int(toks[1])
        if len(toks) < 8 + n:
            continue  # a truncated line
        rows.append([float(x) for x in toks[2:2 + n]])
        odo.append([float(x) for x in toks[5 + n:8 + n]])
    if not rows:
        raise KosmapError(f"{path.name} has no FLASER line; is this a CARMEN laser log?")
    n = {len(r) for r in rows}
    if len(n) != 1:
        raise KosmapError(f"{path.name}: FLASER lines of {sorted(n)} beams; expected one beam count")
    ranges = np.array(rows)
    return LaserLog(_stamps(len(rows), rate), ranges, -math.pi / 2, math.pi / (ranges.shape[1] - 1),
                    _saturation(ranges, SICK_RANGE), np.array(odo), "CARMEN FLASER, re-stamped")


def write_robotlaser(log: LaserLog, out: Path) -> Path:
    """The log as CARMEN ROBOTLASER1 lines (laser pose = robot pose: the mount is not known) into `out`."""
    n = log.ranges.shape[1]
    fov = log.angle_increment * (n - 1)
    tmp = out.with_name(out.name + ".partial")
    with open(tmp, "w") as f:
        f.write(f"# imported by kosmap.tools.laserimport from {log.source}\n")
        for t, r, (x, y, th) in zip(log.stamps, log.ranges, log.odometry):
            rr = np.where(np.isfinite(r) & (r > 0) & (r < log.max_range), r, log.max_range)
            f.write(f"ROBOTLASER1 0 {log.angle_min:.6f} {fov:.6f} {log.angle_increment:.8f} {log.max_range:.3f} 0.01 0 {n} "
                    + " ".join(f"{v:.3f}" for v in rr)
                    + f" 0 {x:.5f} {y:.5f} {th:.6f} {x:.5f} {y:.5f} {th:.6f} 0 0 0 0 0 {t:.6f} kosmap {t:.6f}\n")
    tmp.replace(out)
    return out


def detect(path: Path) -> str:
    """breezyslam, dpslam or carmen, from the first non-empty line."""
    with open(path, errors="replace") as f:
        for line in f:
            toks = line.split()
            if not toks or toks[0].startswith("#"):
                continue
            if toks[0] in ("Odometry", "Laser"):
                return "dpslam"
            if toks[0].isupper():
                return "carmen"
            if toks[0].isdigit() and len(toks) > 26:
                return "breezyslam"
            break
    raise KosmapError(f"{path.name} is none of the formats this importer knows (BreezySLAM .dat, DP-SLAM text, CARMEN "
                      f"FLASER); give --format")


def import_log(path: str | Path, out: str | Path, fmt: str = "auto", rate: float = 5.0) -> LaserLog:
    p, o = Path(path), Path(out)
    if not p.is_file():
        raise KosmapError(f"{p} does not exist; give a laser log file")
    if not (rate > 0 and math.isfinite(rate)):
        raise KosmapError(f"--rate {rate} must be a positive scan rate in Hz")
    fmt = detect(p) if fmt == "auto" else fmt
    log = {"breezyslam": lambda: read_breezyslam(p), "dpslam": lambda: read_dpslam(p, rate),
           "carmen": lambda: read_carmen_flaser(p, rate)}[fmt]()
    write_robotlaser(log, o)
    return log


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("log", type=Path)
    ap.add_argument("out", type=Path, help="the CARMEN log to write (.clf)")
    ap.add_argument("--format", default="auto", choices=("auto", "breezyslam", "dpslam", "carmen"))
    ap.add_argument("--rate", type=float, default=5.0, help="scan rate for a log without usable times (Hz)")
    a = ap.parse_args(argv)
    try:
        log = import_log(a.log, a.out, a.format, a.rate)
    except (KosmapError, ValueError, OSError) as e:
        print(f"laserimport: error: {e}", file=sys.stderr)
        return 2
    print(f"{a.log.name} ({log.source}): {len(log.stamps)} scans of {log.ranges.shape[1]} beams over "
          f"{math.degrees(log.angle_increment * (log.ranges.shape[1] - 1)):.0f}°, max range {log.max_range:.2f} m → {a.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
