"""The floor-is-ground part of tools/bench_planes.py (`--floor`): gravity from the frames on TUM fr1_xyz, a real
handheld Kinect sequence tilted over a desk, at its 15 Hz and at lower rates (every n-th frame, from the first
frames in turn: the phases), over seeds. FSPF+ defaults, all classes kept, then frontend/gravity.py's tracker and
classes, as `kosmap planes` runs them with `[depth] gravity = "frames"`.

The label comes from the ground-truth poses: the Kinect's accelerometer, turned into the motion-capture frame and
averaged over the sequence (the hand's accelerations cancel), gives up; a floor plane (≥ 2000 px) lies within 10°
of it and 1.3 m or more below the camera (the desk lies 0.5–1.2 m below); "level" is within 5° of the floor planes'
own mean normal (the accelerometer's up lies ~2° off it: its bias). docs/planes.md explains the rules.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from kosmap.frontend.fspf import FspfConfig, fspf_plus
from kosmap.frontend.gravity import GravityTracker, reclassify
from kosmap.frontend.planes import PLANE_CLASSES

GROUND = PLANE_CLASSES.index("ground")


@dataclass
class FloorScore:
    """One run: the floor planes, those classed ground, the ground planes, those floor and those level."""

    floor: int
    floor_ground: int
    ground: int
    ground_floor: int
    ground_level: int

    def shares(self) -> tuple[float, float, float]:
        """(floor planes ground, ground planes floor, ground planes level), NaN without any."""
        g = self.ground if self.ground else np.nan
        return self.floor_ground / (self.floor or np.nan), self.ground_floor / g, self.ground_level / g


class TumLabels:
    """The ground-truth rotation of each TUM fr1_xyz frame and the accelerometer's up in the mocap frame."""

    def __init__(self, folder: Path):
        from scipy.spatial.transform import Rotation

        acc, gt = np.loadtxt(folder / "accelerometer.txt"), np.loadtxt(folder / "groundtruth.txt")
        self.stamps, self.rotations = gt[:, 0], Rotation.from_quat(gt[:, 4:8]).as_matrix()
        up = np.mean([self.rot(a[0]) @ (a[1:] * np.array([-1.0, -1.0, 1.0])) for a in acc[::5]], axis=0)
        self.up = up / np.linalg.norm(up)

    def rot(self, t: float) -> np.ndarray:
        """The rotation of the ground-truth pose nearest in time to t (the earlier of two as near)."""
        i = int(np.clip(np.searchsorted(self.stamps, t), 1, len(self.stamps) - 1))
        return self.rotations[i - 1 if t - self.stamps[i - 1] <= self.stamps[i] - t else i]

    def score(self, rows: list[tuple]) -> FloorScore:
        """rows: (stamp, normal, offset, ground) of the planes ≥ 2000 px."""
        world = np.array([self.rot(t) @ n for t, n, _, _ in rows])
        below = np.array([d for _, _, d, _ in rows])
        ground = np.array([g for *_, g in rows], bool)
        floor = (world @ self.up > np.cos(np.radians(10.0))) & (below > 1.3)
        up = world[floor].sum(axis=0)
        level = world @ (up / np.linalg.norm(up)) > np.cos(np.radians(5.0))
        return FloorScore(int(floor.sum()), int((floor & ground).sum()), int(ground.sum()),
                          int((ground & floor).sum()), int((ground & level).sum()))


def run_floor(folder: Path, labels: TumLabels, seed: int, every: int, phase: int,
              period: float | None = None) -> FloorScore:
    """Gravity from the frames over every `every`-th frame from frame `phase`, FSPF+ at `seed`; with `period`, the
    tracker is told the frames lie that many seconds apart (as a folder of images played at a default rate)."""
    from kosmap.tools.datasets import iter_dataset, read_tum_depth, tum_frames

    cam = next(iter_dataset(folder, 1)).camera
    cfg, tracker, rows = FspfConfig(drop_classes=[]), GravityTracker(), []
    frames = tum_frames(folder)[phase::every]
    for i, (stamp, path) in enumerate(frames):
        depth = read_tum_depth(path)
        p = fspf_plus(depth, cam, cfg, seed=seed)
        told = stamp if period is None else frames[0][0] + i * period
        p = reclassify(p, tracker.update(p, told, depth, cam), tracker.height, cfg)
        big = p.counts >= 2000
        rows += [(stamp, n, d, c == GROUND) for n, d, c in zip(p.normals[big], p.offsets[big], p.classes[big])]
    return labels.score(rows)


def floor_rows(data_dir: Path, seeds=range(5), rates=(1, 2, 3, 4, 6), told=((1, 30.0), (4, 30.0))) -> list[dict]:
    """One row per rate: the range over seeds (and phases, below 7.5 Hz) of the three shares; then the rates of
    `told` (every, fps) with the tracker told the frames come at fps (a folder of images played at 30 fps)."""
    folder = data_dir / "depth" / "tum_fr1_xyz"
    if not folder.is_dir():
        return []
    labels, out = TumLabels(folder), []
    for every, fps in [(e, None) for e in rates] + list(told):
        phases = range(2) if every >= 3 else range(1)
        runs = [run_floor(folder, labels, s, every, ph, None if fps is None else 1.0 / fps) for s in seeds
                for ph in phases]
        sh = np.array([r.shares() for r in runs])
        out.append({"every": every, "hz": 15.0 / every, "told_fps": fps, "runs": len(runs), "seeds": len(seeds),
                    "phases": len(phases),
                    "floor_ground": [float(np.nanmin(sh[:, 0])), float(np.nanmax(sh[:, 0]))],
                    "ground_floor": [float(np.nanmin(sh[:, 1])), float(np.nanmax(sh[:, 1]))],
                    "ground_level": [float(np.nanmin(sh[:, 2])), float(np.nanmax(sh[:, 2]))],
                    "floor_planes": [min(r.floor for r in runs), max(r.floor for r in runs)],
                    "runs_meeting_goals": int(((sh[:, 0] >= 0.90) & (sh[:, 2] >= 0.98)).sum())})
    return out


def floor_markdown(rows: list[dict], load: float) -> list[str]:
    lines = ["# Gravity from the frames: TUM fr1_xyz floor planes (`tools/bench_planes.py --floor`)", "",
             f"Load average {load:.2f} (times do not enter). " + __doc__.split("\n\n")[1].replace("\n", " "), "",
             "| rate | runs (seeds × phases) | floor planes ground | ground planes floor | ground planes level "
             "| floor planes per run | runs meeting ≥ 90 % / ≥ 98 % |", "|---|---|---|---|---|---|---|"]
    pct = "{:.1f}–{:.1f} %".format
    for r in rows:
        told = f", told {r['told_fps']:.0f} fps" if r.get("told_fps") else ""
        lines.append(f"| {r['hz']:.2f} Hz (every {r['every']}){told} | {r['runs']} ({r['seeds']} × {r['phases']}) | "
                     f"{pct(*(100 * np.array(r['floor_ground'])))} | {pct(*(100 * np.array(r['ground_floor'])))} | "
                     f"{pct(*(100 * np.array(r['ground_level'])))} | {r['floor_planes'][0]}–{r['floor_planes'][1]} | "
                     f"{r['runs_meeting_goals']} of {r['runs']} |")
    return lines
