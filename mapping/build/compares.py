"""The comparisons of a build: KOS vs blueprint, laser vs blueprint (with the maps on the laser's poses), KOS vs
laser, each a job submitted as soon as its maps exist (mapping/compare.py does the aligning and scoring)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from kosmap.mapping.build.jobs import Jobs
from kosmap.mapping.compare import Alignment, CompareError, align, compare, overlay_picture
from kosmap.mapping.config import Config
from kosmap.mapping.grid import OccupancyGrid
from kosmap.mapping.mapio import write_png


def compare_job(a: OccupancyGrid, b: OccupancyGrid, ccfg, more: tuple = ()) -> list[tuple]:
    """A vs B, then each map of `more` vs B through A's alignment (maps made on A's poses share A's frame): per map,
    (metrics, overlay picture, None) or (None, None, why not)."""
    try:
        alignment = align(a, b, ccfg) if ccfg.align else Alignment()
    except CompareError as e:  # A does not align: nor does what shares its frame
        return [(None, None, str(e))] * (1 + len(more))
    out: list[tuple] = []
    for grid in (a, *more):
        try:
            c = compare(grid, b, ccfg, alignment)
        except CompareError as e:
            out.append((None, None, str(e)))
            continue
        out.append((c.metrics, overlay_picture(c), None))
    return out


# Maps made on the laser SLAM's poses share the laser map's frame: compared with the blueprint through the laser map's
# alignment, not one of their own (which could shift a map to hide its errors, and cost ~2 s a map).
ON_LASER_POSES = ("fused", "kos_obstacle_at_laser_poses")


class Compares:
    """KOS vs blueprint, laser vs blueprint (with the maps on the laser's poses), KOS vs laser (and the extra maps vs
    blueprint), one job each, each submitted as soon as its maps exist: the workers compare while this process
    still writes the MCAP (started after every map, they left the workers idle for the MCAP's seconds and this
    process for theirs)."""

    def __init__(self, bp: OccupancyGrid | None, cfg: Config, jobs: Jobs) -> None:
        self.bp, self.cfg, self.jobs = bp, cfg, jobs
        self.pairs: list[tuple[str, str]] = []
        self.joined: dict[tuple[str, str], tuple[str, ...]] = {}  # a job's pair → the maps compared with A's alignment
        self.grids: dict[str, OccupancyGrid] = {}
        self.futures: dict[tuple[str, str], Any] = {}

    def expect(self, names: list[str]) -> None:
        """The maps pass 2 will make, in its order: they fix the pairs and the order of the results."""
        bcfg = self.cfg.build
        kos_main = f"kos_{bcfg.slam_scan}"
        self.pairs = []
        if self.bp is not None:
            for name in names:
                if name == kos_main or name in ("laser", *ON_LASER_POSES) or \
                        (bcfg.compare_levels and name.startswith("kos_")):
                    self.pairs.append((name, "blueprint"))
        if kos_main in names and "laser" in names:
            self.pairs.append((kos_main, "laser"))
        self.joined = {}
        if ("laser", "blueprint") in self.pairs:
            self.joined[("laser", "blueprint")] = tuple(n for n in ON_LASER_POSES if (n, "blueprint") in self.pairs)

    def grid_ready(self, name: str, grid: OccupancyGrid) -> None:
        """Submit every comparison whose maps are now all there."""
        self.grids[name] = grid
        riders = {n for more in self.joined.values() for n in more}
        for a, b in self.pairs:
            more = self.joined.get((a, b), ())
            ready = all(n in self.grids for n in (a, *more)) and (b == "blueprint" or b in self.grids)
            if ready and (a, b) not in self.futures and not (b == "blueprint" and a in riders):
                other = self.bp if b == "blueprint" else self.grids[b]
                self.futures[(a, b)] = self.jobs.submit(compare_job, self.grids[a], other, self.cfg.compare,
                                                        tuple(self.grids[n] for n in more))

    def finish(self, out: Path, files: dict, warnings: list[str]) -> tuple[dict, dict]:
        """Every comparison's metrics and overlay picture (written), in the pairs' order."""
        results = {}
        for pair, fut in self.futures.items():
            got = fut.result()
            for k, (name, res) in enumerate(zip((pair[0], *self.joined.get(pair, ())), got)):
                if k and res[0] is not None:
                    res[0]["alignment"]["from"] = pair[0]  # the map whose alignment it shares
                elif k and got[0][0] is None:  # (its error is the first map's: say whose)
                    res = (None, None, f"the {pair[0]} map, whose alignment it shares, did not align: {res[2]}")
                results[(name, pair[1])] = res
        comparisons, overlays = {}, {}
        for a, b in self.pairs:
            if (a, b) not in results:  # a map that was not made
                continue
            key = f"{a}_vs_{b}"
            metrics, img, err = results[(a, b)]
            if err is not None:
                warnings.append(f"{key}: {err}")
                continue
            comparisons[key] = {"a": a, "b": b, **metrics}
            overlays[key] = files[f"overlay_{key}"] = write_png(img, out / f"overlay_{key}.png")
        return comparisons, overlays
