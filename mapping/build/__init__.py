"""`kosmap build`: a log → FSPF+ → KOS → SLAM → occupancy grids → comparisons → report, in one streaming pass.

The stages, in the order `build` (run.py) runs them:

1. readpass.py — pass 1 reads the log once. Depth frames go to the frame pool (mapping/runtime/framepool.py:
   FSPF+ and every KOS level per frame, seeded by the frame's index, so the results equal a serial run's); the
   per-step KOS scans come back in order, cameras merged (mapping/kosstream.py).
2. slams.py — the chosen KOS scan goes to one SLAM and, when the log has one, the laser to another, each with the
   wheel odometry interpolated at its stamps (mapping/slamfeed.py, backend/slam.py), each in a process of its
   own when the build runs in parallel; solved once the log is read.
3. spill.py — everything a map needs later is appended to files in a temporary folder during pass 1, never kept
   in memory, so memory stays flat however long the log.
4. grids.py, jobs.py — pass 2 reads the spill back and builds the grid of every source and level from the
   optimised poses, one job per map in the worker processes; maps and trajectories are written.
5. mcap.py — meanwhile this process writes kosmap.mcap for Foxglove.
6. compares.py — each map is compared (KOS vs laser vs blueprint) as soon as its pair exists.
7. metrics.py — metrics.json; then the report (mapping/report.py).

Ctrl-C (or a KeyboardInterrupt from `on_progress`) stops reading; what was read is mapped and written as
usual, marked partial in metrics.json and the report.
"""

from kosmap.mapping.build.readpass import Progress
from kosmap.mapping.build.run import BUILD_FILES, BuildInterrupted, BuildResult, build

__all__ = ["BUILD_FILES", "BuildInterrupted", "BuildResult", "Progress", "build"]
