"""The KOS SLAM profile: the front-end and graph settings for the narrow KOS scan (≈ 70°, ≤ 4.5 m, one depth
camera), applied over [odometry] and [graph] and under the user's [build] kos_odometry and kos_graph. `kosmap
build` and `kosmap slam --source kos` both take their KOS SLAM from here. The measurements behind the values are
in docs/bench/kos_slam.md (tools/bench_kos_slam.py).
"""

from __future__ import annotations

import dataclasses

from kosmap.backend.graph import GraphConfig
from kosmap.frontend.errors import ConfigError
from kosmap.frontend.odometry import OdometryConfig

# The front end. A narrow scan sees one wall at a time and nothing along a corridor, so its position is held to the
# wheel odometry (prior_weight across, prior_weight_along along the direction of travel, prior_weight_yaw on the
# heading), and there is no correlative search or recovery search (search_*, recovery_ratio): over ±1 m and ±90°
# they lock a narrow scan onto the wrong wall (docs/dependencies.md, "The narrow depth camera in a corridor loop").
# Along-track it is held hard only where the scan's own surfaces leave that direction open (degenerate_ratio, the
# laser front end's rule): held there always, the matches repeat the wheels' scale error and a 2 % error stays in
# the map along bare corridors; free where corners and rooms fix it, they measure the scale (docs/benchmarks.md,
# "KOS SLAM with harsh wheel odometry"). Free matches need unbiased ranges: [kos] nearest = surface.
KOS_FRONTEND = {"prior_weight": 100.0, "prior_weight_along": 300.0, "prior_weight_yaw": 100.0,
                "search_linear": 0.0, "search_angular_deg": 0.0, "recovery_ratio": 0.0, "degenerate_ratio": 0.1}

# The graph.
# - odom_sigma_xy 5 mm + odom_sigma_xy_per_m 2 %: the wheels of an indoor robot on a flat floor (the [graph]
#   defaults, 5 cm + 10 %, are for the slipping laser benchmark robots); along a corridor the wheels are all that
#   fixes the position, and the odometry scale is observable only if they are not declared worse than they are.
# - calibrate_every 300: the scale and gyro bias fed back to the front end while running; the front end's pull
#   towards the wheels otherwise biases the scale towards 1.
# - imu_frontend: the gyro's yaw in the front end's prediction; gyro_bias_every 0: the bias is re-estimated with
#   the scale only (alone, a poorly determined early bias reaches the front end's yaw).
# - gyro_bias_walk_deg_s 0.0005 (the laser's 0.002 lets the bias follow the narrow scan's weak yaw).
# - manhattan: heading priors from the walls (backend/manhattan.py); off for a laser, whose wide scans close loops
#   and keep their heading already.
KOS_GRAPH = {"odom_sigma_xy": 0.005, "odom_sigma_xy_per_m": 0.02, "calibrate_every": 300, "imu_frontend": True,
             "gyro_bias_every": 0, "gyro_bias_walk_deg_s": 0.0005, "manhattan": True}


def _with_overrides(base, defaults: dict, overrides: dict, what: str):
    """`base` with `defaults`, then the user's [build] `what` table, applied; an unknown key is a config error."""
    known = {f.name for f in dataclasses.fields(base)}
    bad = [k for k in overrides if k not in known]
    if bad:
        raise ConfigError(f"config [build] {what} has unknown key(s) {', '.join(bad)}; known: {', '.join(sorted(known))}")
    return dataclasses.replace(base, **{**defaults, **overrides})


def kos_odometry_config(cfg) -> OdometryConfig:
    """The front end for a narrow KOS scan: `cfg`'s [odometry] with KOS_FRONTEND, then [build] kos_odometry."""
    return _with_overrides(cfg.odometry, KOS_FRONTEND, cfg.build.kos_odometry, "kos_odometry")


def kos_graph_config(cfg) -> GraphConfig:
    """The graph for a narrow KOS scan: `cfg`'s [graph] with KOS_GRAPH, then [build] kos_graph."""
    return _with_overrides(cfg.graph, KOS_GRAPH, cfg.build.kos_graph, "kos_graph")
