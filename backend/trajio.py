"""Trajectory and graph files: TUM (`t x y z qx qy qz qw`, what evo reads) and g2o (VERTEX_SE2 / EDGE_SE2)."""

from __future__ import annotations

import math
import os
from pathlib import Path

import numpy as np

from kosmap.frontend.errors import KosmapError


class TrajectoryError(KosmapError):
    """A trajectory or graph file that cannot be read."""


def _atomic_write(path: Path, text: str) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".partial")
    tmp.write_text(text)
    os.replace(tmp, path)
    return path


def write_tum(path: str | Path, stamps_s, poses) -> Path:
    """Planar poses (N×3) at stamps (s) as a TUM file, z = 0, yaw as a quaternion about z."""
    poses = np.asarray(poses, dtype=float).tolist()  # Python floats: numpy scalars format ~3× slower, the same text
    lines = [f"{t:.9f} {p[0]:.6f} {p[1]:.6f} 0 0 0 {math.sin(p[2] / 2):.9f} {math.cos(p[2] / 2):.9f}"
             for t, p in zip(np.asarray(stamps_s, dtype=float).tolist(), poses)]
    return _atomic_write(Path(path), "# timestamp tx ty tz qx qy qz qw\n" + "\n".join(lines) + "\n")


def read_tum(path: str | Path) -> tuple[np.ndarray, np.ndarray]:
    """(stamps s, N×3 planar poses) from a TUM file; yaw taken from the quaternion."""
    p = Path(path)
    if not p.is_file():
        raise TrajectoryError(f"trajectory file {p} does not exist; give a TUM file (t x y z qx qy qz qw)")
    rows = []
    for lineno, line in enumerate(p.read_text().splitlines(), 1):
        f = line.split()
        if not f or f[0].startswith("#"):
            continue
        if len(f) != 8:
            raise TrajectoryError(f"{p}:{lineno}: a TUM line has 8 fields (t x y z qx qy qz qw), this one {len(f)}")
        try:
            t, x, y, _z, qx, qy, qz, qw = map(float, f)
        except ValueError as e:
            raise TrajectoryError(f"{p}:{lineno}: not a number ({e})") from e
        yaw = math.atan2(2.0 * (qw * qz + qx * qy), 1.0 - 2.0 * (qy * qy + qz * qz))
        rows.append((t, x, y, yaw))
    if not rows:
        raise TrajectoryError(f"{p} holds no poses")
    a = np.array(rows)
    return a[:, 0], a[:, 1:]


def write_g2o(path: str | Path, poses, edges) -> Path:
    """g2o SE2 graph: `VERTEX_SE2 id x y θ`, `EDGE_SE2 a b dx dy dθ I11 I12 I13 I22 I23 I33` (edges:
    (a, b, measurement, σ per axis or a 3×3 covariance, kind); information = its inverse); the edge kind goes in a comment line
    before each loop so other tools still parse the file."""
    out = []
    for i, p in enumerate(np.asarray(poses, dtype=float)):
        out.append(f"VERTEX_SE2 {i} {p[0]:.6f} {p[1]:.6f} {p[2]:.9f}")
    if len(poses):
        out.append("FIX 0")
    for a, b, m, s, kind in edges:
        s = np.asarray(s, dtype=float)
        info = np.linalg.inv(s) if s.ndim == 2 else np.diag(1.0 / s ** 2)  # a covariance, or σ per axis
        if kind == "loop":
            out.append("# loop")
        out.append(f"EDGE_SE2 {a} {b} {m[0]:.6f} {m[1]:.6f} {m[2]:.9f} {info[0, 0]:.6g} {info[0, 1]:.6g} {info[0, 2]:.6g} "
                   f"{info[1, 1]:.6g} {info[1, 2]:.6g} {info[2, 2]:.6g}")
    return _atomic_write(Path(path), "\n".join(out) + "\n")


def read_g2o(path: str | Path) -> tuple[np.ndarray, list[tuple[int, int, np.ndarray, np.ndarray]]]:
    """(N×3 vertices, [(a, b, measurement, 3×3 information)]) from a g2o SE2 file."""
    verts: dict[int, tuple[float, float, float]] = {}
    edges = []
    for line in Path(path).read_text().splitlines():
        f = line.split()
        if not f:
            continue
        if f[0] == "VERTEX_SE2":
            verts[int(f[1])] = (float(f[2]), float(f[3]), float(f[4]))
        elif f[0] == "EDGE_SE2":
            a, b = int(f[1]), int(f[2])
            m = np.array(list(map(float, f[3:6])))
            u = list(map(float, f[6:12]))
            info = np.array([[u[0], u[1], u[2]], [u[1], u[3], u[4]], [u[2], u[4], u[5]]])
            edges.append((a, b, m, info))
    n = max(verts) + 1 if verts else 0
    v = np.zeros((n, 3))
    for i, p in verts.items():
        v[i] = p
    return v, edges
