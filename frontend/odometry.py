"""Scan-matching odometry: scans (KOS or laser) registered against a local submap, fused with wheel odometry.

Two front ends with one interface, `update(stamp_ns, points, odom_pose) -> FrontendResult`, so both can be
measured on every log (tools/bench_slam.py):

- `SubmapOdometry` (the default, written here by hand): each scan is matched against a likelihood field of
  the recent keyframes (Cartographer's two overlapping local submaps, Hess et al. 2016 §IV), starting from
  the wheel-odometry prediction: a small correlative search, then Gauss–Newton coarse to fine with a prior
  towards the prediction. kiss-icp diverges on the sparse 180° benchmark lasers and on narrow depth
  scans (docs/dependencies.md); this matcher reached Cartographer's accuracy on Intel. For a narrow depth scan the prior
  can be made much stronger along the direction of travel (a corridor gives no along-track fix), and the
  correlative search switched off (`search_linear = 0`), as docs/dependencies.md's corridor probe needed.
- `KissIcpOdometry`: kiss-icp on the points lifted to z = 0, the wheel-odometry increment given as its
  motion guess (`last_delta`, docs/dependencies.md), kept as the measured baseline.

Points are in base_link (N×2); poses (x, y, yaw) are in the front end's own drift-prone frame.
"""

from __future__ import annotations

import bisect
import math
from dataclasses import dataclass, field

import numpy as np

from numba import njit

from kosmap.frontend import se2
from kosmap.frontend.params import StageConfig, param


@dataclass
class OdometryConfig(StageConfig):
    """[odometry]: the scan-matching front end and its keyframes. Defaults: one set for every benchmark log."""

    section = "odometry"
    matcher: str = param("submap", choices=("submap", "kiss-icp"), doc="scan-to-submap matcher or kiss-icp")
    keyframe_spacing: str = param("derived", choices=("derived", "fixed"), doc="keyframe spacing from the scan's field "
                                  "of view and the fine field's cells, shortened for noisy measured odometry (backend/keyframes.py "
                                  "derived_spacing; a SICK 180°: 0.15 m, 7.5°), or keyframe_distance and keyframe_angle_deg")
    keyframe_distance: float = param(0.15, lo=0.0, doc="insert a scan into the local submap after this travel (keyframe_spacing = \"fixed\")", unit="m")
    keyframe_angle_deg: float = param(7.5, lo=0.0, doc="… or after this rotation", unit="deg")
    voxel_size: float = param(0.1, lo=0.0, lo_open=True, doc="kiss-icp voxel size", unit="m")
    min_range: float = param(0.1, lo=0.0, doc="ignore returns nearer than this", unit="m")
    max_range: float = param(30.0, lo=0.0, lo_open=True, doc="ignore returns farther than this", unit="m")
    use_wheel_odometry: bool = param(True, doc="use the log's wheel odometry as the motion prior")
    deskew: bool = param(True, doc="de-skew a laser scan taken beam by beam (time_increment ≠ 0) with the wheel "
                         "odometry's twist; off for a driver that stamps its scans other than at the first beam")
    resolution: float = param(0.05, lo=0.0, lo_open=True, doc="fine likelihood field cell size", unit="m")
    coarse_resolution: float = param(0.1, lo=0.0, lo_open=True, doc="coarse likelihood field cell size", unit="m")
    submap_size: float = param(30.0, lo=1.0, doc="side of a local submap's square field", unit="m")
    submap_keyframes: int = param(14, lo=1, doc="a new local submap starts every this many keyframes; each holds twice as many")
    sigma_coarse: float = param(0.10, lo=0.0, lo_open=True, doc="field blur for the search and the first Gauss–Newton", unit="m")
    sigma_fine: float = param(0.02, lo=0.0, lo_open=True, doc="field blur for the final Gauss–Newton", unit="m")
    search_linear: float = param(0.1, lo=0.0, doc="correlative search half window in x and y (0 = no search)", unit="m")
    search_linear_step: float = param(0.05, lo=0.0, lo_open=True, doc="correlative search step", unit="m")
    search_angular_deg: float = param(3.0, lo=0.0, doc="correlative search half window in yaw", unit="deg")
    search_angular_step_deg: float = param(1.0, lo=0.0, lo_open=True, doc="correlative search yaw step", unit="deg")
    search_penalty_linear: float = param(0.0, lo=0.0, doc="search score × exp(−this·|Δt|²): prefer the prediction", unit="1/m²")
    search_penalty_angular: float = param(0.0, lo=0.0, doc="search score × exp(−this·Δyaw²)", unit="1/rad²")
    search_no_odom_linear: float = param(0.3, lo=0.0, doc="search half window when there is no wheel odometry", unit="m")
    search_no_odom_angular_deg: float = param(12.0, lo=0.0, doc="yaw half window without wheel odometry", unit="deg")
    prior_weight: float = param(1.0, lo=0.0, doc="Gauss–Newton pull towards the predicted position", unit="1/m²")
    prior_weight_along: float = param(1.0, lo=0.0, doc="… along the direction of travel (≥1000 for a narrow depth scan)", unit="1/m²")
    prior_weight_yaw: float = param(1.0, lo=0.0, doc="… towards the predicted yaw", unit="1/rad²")
    match_cost: str = param("welsch", choices=("welsch", "squared"), doc="Gauss–Newton cost: Σ(1 − M) or hector's Σ(1 − M)²")
    gn_iterations: int = param(10, lo=1, doc="Gauss–Newton iterations per level")
    min_points: int = param(10, lo=1, doc="scans with fewer returns are not matched (pose from the prediction)")
    recovery_ratio: float = param(0.6, lo=0.0, hi=1.0, doc="a match scoring below this × the running mean is retried with the wide search")
    recovery_linear: float = param(1.0, lo=0.0, doc="recovery search half window in x and y", unit="m")
    recovery_angular_deg: float = param(90.0, lo=0.0, doc="recovery search half window in yaw", unit="deg")
    densify_max_gap: float = param(0.3, lo=0.0, doc="fill submap walls between returns up to this far apart (0 = off)", unit="m")
    point_spacing: float = param(0.05, lo=0.0, doc="drop a return nearer than this to the last one kept, in scan order (0 = keep all)", unit="m")
    degenerate_calibrate_every: int = param(100, lo=0, doc="every n keyframes, when ≥ 20 % of the matches since the last "
                                            "check were degenerate (held along the odometry), re-estimate the odometry "
                                            "scale while running (0 = never; [graph] calibrate_every does it always)")
    degenerate_ratio: float = param(0.1, lo=0.0, hi=1.0, doc="a scan whose own surfaces fix one direction less than "
                                    "this × the other (scan_geometry: the returns' normals) is held at the wheel-odometry "
                                    "prediction along that direction (0 = off)")


@dataclass
class FrontendResult:
    """What the front end says about one scan."""

    pose: np.ndarray  # (3,) x, y, yaw in the front end's frame
    keyframe: bool  # the scan was inserted into the local submap
    matched: bool  # False when the scan had too few points (or no map yet): pose is the prediction
    score: float = float("nan")  # mean fine-field value at the scan's points after matching
    info: np.ndarray = field(default_factory=lambda: np.zeros((3, 3)))  # (1/N)·Σ JᵀJ of the match (frame of the map)
    n_points: int = 0  # points the match used

    def covariance(self, n_eff: float, floor: float = 1e-6) -> np.ndarray | None:
        """The match's covariance in the map frame, (n·H)⁻¹ with n = min(n_points, n_eff): returns are not
        independent (one wall gives many), so at most `n_eff` count. Huge along unobserved directions.
        None when the front end gives no information matrix (kiss-icp)."""
        if self.matched and (self.n_points <= 0 or not np.any(self.info)):
            return None
        n = min(float(self.n_points), float(n_eff))
        if not self.matched or n <= 0:
            return np.diag([1.0, 1.0, 0.1])  # unmatched: metres and ~20° (the prediction only)
        h = self.info * n + np.eye(3) * floor
        return np.linalg.inv(h)


class WheelOdometry:
    """Wheel odometry samples, interpolated at scan times (x, y and unwrapped yaw, linearly)."""

    def __init__(self) -> None:
        self.t: list[int] = []
        self.p: list[tuple[float, float, float]] = []
        self._unwrapped = 0.0

    def __len__(self) -> int:
        return len(self.t)

    def add(self, stamp_ns: int, x: float, y: float, yaw: float) -> None:
        if self.t and stamp_ns <= self.t[-1]:
            if stamp_ns == self.t[-1]:
                return
            # out-of-order sample: keep the buffer sorted
            i = bisect.bisect_left(self.t, stamp_ns)
            if i < len(self.t) and self.t[i] == stamp_ns:
                return
            prev = self.p[i - 1][2] if i else yaw
            self.t.insert(i, stamp_ns)
            self.p.insert(i, (x, y, prev + float(se2.wrap(yaw - prev))))
            return
        if self.p:
            yaw = self.p[-1][2] + float(se2.wrap(yaw - self.p[-1][2]))
        self.t.append(stamp_ns)
        self.p.append((float(x), float(y), float(yaw)))

    def covers(self, stamp_ns: int) -> bool:
        """True when a sample at or after the stamp exists (interpolation needs no more data)."""
        return bool(self.t) and self.t[-1] >= stamp_ns

    def pose_at(self, stamp_ns: int) -> np.ndarray | None:
        """Interpolated pose; held at the first/last sample outside their span; None without samples."""
        if not self.t:
            return None
        i = bisect.bisect_left(self.t, stamp_ns)
        if i == 0:
            p = np.array(self.p[0])
        elif i >= len(self.t):
            p = np.array(self.p[-1])
        else:
            t0, t1 = self.t[i - 1], self.t[i]
            a = (stamp_ns - t0) / (t1 - t0)
            p = (1.0 - a) * np.array(self.p[i - 1]) + a * np.array(self.p[i])
        p[2] = float(se2.wrap(p[2]))
        return p

    def twist_at(self, stamp_ns: int, mount=(0.0, 0.0, 0.0),
                 window_ns: int = 50_000_000) -> tuple[tuple[float, float], float] | None:
        """The twist ((vx, vy) in its own frame, ω) of a sensor mounted at `mount` in base_link over the
        `window_ns` before `stamp_ns`, from the samples (None when they do not span that window): what
        de-skewing a scan stamped then needs (`scan_to_points(..., twist=)`)."""
        if len(self.t) < 2 or self.t[0] > stamp_ns - window_ns or self.t[-1] < stamp_ns:
            return None
        from kosmap.frontend.deskew import sensor_twist

        return sensor_twist(self.pose_at(stamp_ns - window_ns), self.pose_at(stamp_ns), window_ns * 1e-9, mount)

    def drop_before(self, stamp_ns: int) -> None:
        """Forget samples older than the one just before `stamp_ns` (memory stays flat on long logs)."""
        i = bisect.bisect_left(self.t, stamp_ns) - 1
        if i > 0:
            del self.t[:i]
            del self.p[:i]


def voxel_filter(points: np.ndarray, size: float) -> np.ndarray:
    """One point (the first) per square cell of `size` metres, in scan order."""
    if size <= 0 or len(points) == 0:
        return points
    keys = np.floor(points / size).astype(np.int64)
    _, idx = np.unique(keys[:, 0] * 1_000_003 + keys[:, 1], return_index=True)
    return points[np.sort(idx)]


@njit(cache=True)
def _thin(points, spacing):
    keep = np.zeros(points.shape[0], np.bool_)
    lx = np.inf
    ly = np.inf
    s2 = spacing * spacing
    for i in range(points.shape[0]):
        dx = points[i, 0] - lx
        dy = points[i, 1] - ly
        if dx * dx + dy * dy >= s2:
            keep[i] = True
            lx = points[i, 0]
            ly = points[i, 1]
    return keep


def thin(points: np.ndarray, spacing: float) -> np.ndarray:
    """Drop each return nearer than `spacing` to the last one kept (scan order): dense near returns thinned,
    far ones kept, in O(n)."""
    if spacing <= 0 or len(points) == 0:
        return points
    return points[_thin(np.ascontiguousarray(points, dtype=np.float64), float(spacing))]


@njit(cache=True)
def _scan_points(ranges, angle_min, inc, lo, hi, mx, my, myaw, w_dt, vx_dt, vy_dt):
    """Beam end points in base_link; beam i de-skewed into the sensor frame at the stamp by the sensor's turn
    (w_dt = ω·time_increment) and motion (v·time_increment) over its i·time_increment (frontend/deskew.py; all
    three 0 for an instantaneous scan)."""
    n = ranges.shape[0]
    out = np.empty((n, 2))
    m = 0
    c = math.cos(myaw)
    s = math.sin(myaw)
    for i in range(n):
        r = ranges[i]
        if not (r >= lo and r <= hi):  # also drops NaN and ±inf
            continue
        a = angle_min + i * inc + i * w_dt
        x = r * math.cos(a) + i * vx_dt
        y = r * math.sin(a) + i * vy_dt
        out[m, 0] = mx + c * x - s * y
        out[m, 1] = my + s * x + c * y
        m += 1
    return out[:m]


def scan_to_points(scan, mount: np.ndarray | None, min_range: float, max_range: float, twist=None) -> np.ndarray:
    """End points (N×2, base_link) of the beams of a Scan that returned within [min_range, max_range]
    (and within the scan's own [range_min, range_max)); `mount` = the sensor's pose in base_link. With `twist`
    ((vx, vy), ω: the sensor's velocity in its own frame, `frontend.deskew.sensor_twist`) a scan taken beam by
    beam (time_increment ≠ 0) is de-skewed."""
    lo = max(float(min_range), float(scan.range_min))
    hi = min(float(max_range), math.nextafter(float(scan.range_max), 0.0))
    m = np.zeros(3) if mount is None else np.asarray(mount, dtype=float)
    dt = float(scan.time_increment) if twist is not None else 0.0
    (vx, vy), w = twist if twist is not None else ((0.0, 0.0), 0.0)
    return _scan_points(np.asarray(scan.ranges), float(scan.angle_min), float(scan.angle_increment), lo, hi,
                        float(m[0]), float(m[1]), float(m[2]), float(w) * dt, float(vx) * dt, float(vy) * dt)


# a prior weight (1/m², 1/rad²) above this holds the pose to the odometry's prediction: σ = 1/√w ≈ 0.3 m is what a
# scan match's centimetres override; the KOS profile's 100–300 (0.06–0.1 m) is not (backend/kosprofile.py)
HELD_WEIGHT = 10.0


def held(cfg: "OdometryConfig") -> bool:
    """Whether the front end holds every match to the odometry's prediction (a prior weight above HELD_WEIGHT)."""
    return max(cfg.prior_weight, cfg.prior_weight_along, cfg.prior_weight_yaw) > HELD_WEIGHT


def prior_weight_matrix(yaw: float, w_across: float, w_along: float, w_yaw: float) -> np.ndarray:
    """W = w_along·uuᵀ + w_across·(I − uuᵀ) in x, y (u the heading), w_yaw on yaw."""
    u = np.array([math.cos(yaw), math.sin(yaw)])
    W = np.zeros((3, 3))
    W[:2, :2] = w_along * np.outer(u, u) + w_across * (np.eye(2) - np.outer(u, u))
    W[2, 2] = w_yaw
    return W


NORMAL_BASELINE = 0.1  # m: a normal from neighbours this far apart; a laser's ~1 cm range noise tilts it by < 10°


def scan_geometry(points: np.ndarray, max_gap: float = 0.3) -> tuple[float, np.ndarray]:
    """How well the scan's own surfaces fix its translation: the normals of its returns (from each return's two
    neighbours in scan order, where both lie within `max_gap`) summed as Σ n nᵀ; returns (smallest / largest
    eigenvalue, the weakest direction in the scan's frame). A bare corridor's walls all face across it: ratio ≈ 0
    along it, whatever the field's gradients say where the walls' returns end (Censi 2008's point-to-line view)."""
    points = thin(points, NORMAL_BASELINE / 2)
    if len(points) < 3:
        return 0.0, np.array([1.0, 0.0])
    d = points[2:] - points[:-2]
    ok = (np.hypot(*(points[1:-1] - points[:-2]).T) <= max_gap) & (np.hypot(*(points[2:] - points[1:-1]).T) <= max_gap)
    d = d[ok]
    nrm = np.hypot(d[:, 0], d[:, 1])
    d = d[nrm > 1e-9] / nrm[nrm > 1e-9, None]
    if len(d) < 3:
        return 0.0, np.array([1.0, 0.0])
    n = np.column_stack((-d[:, 1], d[:, 0]))
    w, v = np.linalg.eigh(n.T @ n)
    return float(max(w[0], 0.0) / w[1]) if w[1] > 0 else 0.0, v[:, 0]


def degeneracy_prior(info: np.ndarray, ratio: float, geometry: tuple[float, np.ndarray], yaw: float) -> np.ndarray | None:
    """The prior that holds a degenerate match's weak direction towards the motion prediction (Zhang, Kaess & Singh
    2016, "On degeneracy of optimization-based state estimation problems": leave the directions the measurements
    do not fix to the prediction).

    Along a bare corridor the scan fixes the lateral position and the heading; along the corridor the field's only
    pull comes from where the walls' returns end, which moves with the sensor (the range or grazing-angle limit),
    so matching drags every scan back onto the map it already has and the corridor shrinks (the simulated
    long-corridor world: 41 m of corridor mapped as 8–12 m). The scan's own surfaces (`geometry`, scan_geometry:
    g = weakest / strongest, and the weakest direction v in the scan frame) say how far to trust the match along v:
    with g below `ratio` the prediction is weighted there by λ_hi · (ratio / g − 1) (λ_hi: the match's strongest
    translational information), nothing at g = ratio, a constraint as g → 0. None when g ≥ ratio."""
    from kosmap.frontend.matcher import translation_information

    g, v_scan = geometry
    if g >= ratio:
        return None
    _, hi, _ = translation_information(info)
    c, s = math.cos(yaw), math.sin(yaw)
    v = np.array([c * v_scan[0] - s * v_scan[1], s * v_scan[0] + c * v_scan[1]])
    extra = np.zeros((3, 3))
    extra[:2, :2] = hi * (ratio / max(g, 1e-3) - 1.0) * np.outer(v, v)
    return extra


class _LocalSubmap:
    """A local submap: a coarse and a fine likelihood field around where it started, and its keyframe count."""

    def __init__(self, center, cfg: OdometryConfig) -> None:
        from kosmap.frontend.likelihood import LikelihoodField

        self.coarse = LikelihoodField.around(center, cfg.submap_size, cfg.coarse_resolution, cfg.sigma_coarse)
        self.fine = LikelihoodField.around(center, cfg.submap_size, cfg.resolution, cfg.sigma_fine)
        self.count = 0

    def insert(self, pts_world: np.ndarray) -> None:
        self.coarse.insert(pts_world)
        self.fine.insert(pts_world)
        self.count += 1


class SubmapOdometry:
    """Scan-to-submap matching with a wheel-odometry prior (see the module docstring)."""

    def __init__(self, cfg: OdometryConfig | None = None) -> None:
        self.cfg = cfg or OdometryConfig()
        self.submaps: list[_LocalSubmap] = []
        self.pose: np.ndarray | None = None
        self.prev_odom: np.ndarray | None = None
        self.velocity = np.zeros(3)  # last increment, for a constant-velocity guess without odometry
        self.last_key: np.ndarray | None = None
        # keyframe spacing (m, rad): the config's, replaced by the SLAM core's derived one (backend/keyframes.py)
        self.key_distance, self.key_angle = self.cfg.keyframe_distance, math.radians(self.cfg.keyframe_angle_deg)
        self.score_ema = 0.0  # running mean of the fine match score, for failure detection
        self.recoveries = 0
        self.matches = 0  # scans matched
        self.degenerate = 0  # … of which degenerate (the odometry held one direction)
        # the odometry's measured noise (backend/odomnoise.py OdomNoise, set by the SLAM core once measured): any
        # object with translation_sigma(d) and yaw_sigma_of(d, dyaw); the search window then covers 3σ of the
        # prediction's error over the scan step when that exceeds search_linear / search_angular_deg
        self.odom_noise = None

    def _predict(self, odom_pose: np.ndarray | None) -> tuple[np.ndarray, bool]:
        if odom_pose is not None and self.prev_odom is not None:
            return se2.compose(self.pose, se2.between(self.prev_odom, odom_pose)), True
        return se2.compose(self.pose, self.velocity), False

    def _insert(self, pose: np.ndarray, pts: np.ndarray) -> None:
        from kosmap.frontend.likelihood import densify

        cfg = self.cfg
        if not self.submaps or self.submaps[-1].count >= cfg.submap_keyframes:
            self.submaps.append(_LocalSubmap(pose[:2], cfg))
        world = se2.transform_points(pose, densify(pts, cfg.resolution, cfg.densify_max_gap))
        for sm in self.submaps:
            sm.insert(world)
        if self.submaps[0].count >= 2 * cfg.submap_keyframes and len(self.submaps) > 1:
            self.submaps.pop(0)
        self.last_key = pose.copy()

    def _is_keyframe(self, pose: np.ndarray) -> bool:
        if self.last_key is None:
            return True
        d = se2.between(self.last_key, pose)
        return bool(math.hypot(d[0], d[1]) >= self.key_distance or abs(d[2]) >= self.key_angle)

    def _match(self, pts: np.ndarray, pred: np.ndarray, has_odom: bool) -> tuple[np.ndarray, float, np.ndarray]:
        """Correlative search around the prediction, then Gauss–Newton on the coarse and the fine field."""
        from kosmap.frontend.matcher import correlative_search, gauss_newton

        cfg = self.cfg
        sm = self.submaps[0]
        c = sm.coarse
        pts64 = np.ascontiguousarray(pts, dtype=np.float64)
        lin = cfg.search_linear if has_odom else cfg.search_no_odom_linear
        ang = math.radians(cfg.search_angular_deg if has_odom else cfg.search_no_odom_angular_deg)
        if has_odom and self.odom_noise is not None and (lin > 0 or ang > 0):
            lin, ang = self._noise_window(pred, lin, ang)
        start = pred
        if lin > 0 or ang > 0:
            start, _ = correlative_search(c.values, c.origin[0], c.origin[1], c.resolution, pts64, pred, lin,
                                          cfg.search_linear_step, ang, math.radians(cfg.search_angular_step_deg),
                                          cfg.search_penalty_linear if has_odom else 0.0,
                                          cfg.search_penalty_angular if has_odom else 0.0)
        # the prior pulls towards the odometry prediction; without odometry towards the search's answer
        prior = pred if has_odom else start
        W = prior_weight_matrix(prior[2], cfg.prior_weight, cfg.prior_weight_along if has_odom else cfg.prior_weight,
                                cfg.prior_weight_yaw)
        welsch = cfg.match_cost == "welsch"
        p1, _, _ = gauss_newton(c.values, c.origin[0], c.origin[1], c.resolution, pts64, start, prior, W, cfg.gn_iterations,
                                welsch, c.sigma)
        f = sm.fine
        pose, info, score = gauss_newton(f.values, f.origin[0], f.origin[1], f.resolution, pts64, p1, prior, W,
                                         cfg.gn_iterations, welsch, f.sigma)
        if has_odom and cfg.degenerate_ratio > 0:
            geometry = scan_geometry(pts, cfg.densify_max_gap)
            extra = degeneracy_prior(info, cfg.degenerate_ratio, geometry, float(pred[2]))
            if extra is not None:  # a corridor: solve again from the prediction, the odometry holding the weak direction
                self.degenerate += 1
                W = W + extra
                p1, _, _ = gauss_newton(c.values, c.origin[0], c.origin[1], c.resolution, pts64, prior, prior, W,
                                        cfg.gn_iterations, welsch, c.sigma)
                pose, info, score = gauss_newton(f.values, f.origin[0], f.origin[1], f.resolution, pts64, p1, prior,
                                                 W, cfg.gn_iterations, welsch, f.sigma)
                # a free front end's match tells the graph nothing along the weak direction: its pose there is the
                # odometry's prediction, which the graph has as its own factor with the scale variable. Kept as the
                # scan's geometric share, that information carried the prediction's scale error a second time,
                # unscaled: on the simulated corridor ring with 2-3 % wheel errors the final solve kept the 42 m
                # corridors 0.6-1 % long (scale 1.015 found against 1.024; docs/benchmarks.md). A held front end (the
                # KOS profile, every match pulled to the prediction) keeps the geometric share: without it the
                # simulated office with a gyro found the wheels' scale 0.67 % long, against 0.3 % with it
                v = np.linalg.eigh(extra[:2, :2])[1][:, 1]
                share = geometry[0] / cfg.degenerate_ratio if held(cfg) else 0.0
                info = info.copy()
                if share > 0.0:
                    info[:2, :2] -= (1.0 - share) * float(v @ info[:2, :2] @ v) * np.outer(v, v)
                else:
                    P = np.eye(3)
                    P[:2, :2] -= np.outer(v, v)  # the projection that leaves the weak direction out (stays PSD)
                    info = P @ info @ P
        return np.asarray(pose, dtype=float), float(score), info

    def _noise_window(self, pred: np.ndarray, lin: float, ang: float) -> tuple[float, float]:
        """The search half windows widened to 3σ of the odometry's measured error over this scan step (the
        prediction's increment), up to the windows used without odometry; never narrower than configured."""
        step = se2.between(self.pose, pred)
        d = math.hypot(step[0], step[1])
        n = self.odom_noise
        cap_lin, cap_ang = self.cfg.search_no_odom_linear, math.radians(self.cfg.search_no_odom_angular_deg)
        return (max(lin, min(3.0 * n.translation_sigma(d), cap_lin)) if lin > 0 else 0.0,
                max(ang, min(3.0 * n.yaw_sigma_of(d, float(step[2])), cap_ang)) if ang > 0 else 0.0)

    def _recover(self, pts: np.ndarray, pred: np.ndarray) -> tuple[np.ndarray, float, np.ndarray]:
        """Branch-and-bound search over ±recovery_linear, ±recovery_angular_deg, then Gauss–Newton."""
        from kosmap.frontend.matcher import SearchGrids, gauss_newton

        cfg = self.cfg
        sm = self.submaps[0]
        grids = SearchGrids(sm.coarse, depth=4)
        pts64 = np.ascontiguousarray(pts, dtype=np.float64)
        start, _ = grids.search(pts64, pred, cfg.recovery_linear, math.radians(cfg.recovery_angular_deg), 0.0)
        if start is None:
            return pred, 0.0, np.zeros((3, 3))
        W = prior_weight_matrix(start[2], cfg.prior_weight, cfg.prior_weight, cfg.prior_weight_yaw)
        c, f = sm.coarse, sm.fine
        welsch = cfg.match_cost == "welsch"
        p1, _, _ = gauss_newton(c.values, c.origin[0], c.origin[1], c.resolution, pts64, start, start, W, cfg.gn_iterations,
                                welsch, c.sigma)
        pose, info, score = gauss_newton(f.values, f.origin[0], f.origin[1], f.resolution, pts64, p1, start, W,
                                         cfg.gn_iterations, welsch, f.sigma)
        return np.asarray(pose, dtype=float), float(score), info

    def update(self, stamp_ns: int, points: np.ndarray, odom_pose: np.ndarray | None) -> FrontendResult:
        cfg = self.cfg
        if not cfg.use_wheel_odometry:
            odom_pose = None
        pts = thin(points, cfg.point_spacing)
        if self.pose is None:
            self.pose = np.zeros(3)
            self.prev_odom = odom_pose
            if len(pts) >= cfg.min_points:
                self._insert(self.pose, pts)
            return FrontendResult(self.pose.copy(), len(pts) >= cfg.min_points, False)
        pred, has_odom = self._predict(odom_pose)
        if len(pts) < cfg.min_points or not self.submaps:
            pose, matched, score, info = pred, False, float("nan"), np.zeros((3, 3))
        else:
            pose, score, info = self._match(pts, pred, has_odom)
            matched = True
            self.matches += 1
            if score < cfg.recovery_ratio * self.score_ema:
                # A poor match: the prediction may be wrong (stale odometry that then jumps, as in MIT CSAIL;
                # scans out of order or a wheel slip, as in Intel). Search the submap exhaustively over a wide
                # window (branch and bound) around the prediction; keep the answer if it matches better.
                p2, s2, i2 = self._recover(pts, pred)
                if s2 > score:
                    pose, score, info = p2, s2, i2
                self.recoveries += 1
            self.score_ema += 0.1 * (score - self.score_ema) if self.score_ema > 0 else score
        pose = np.asarray(pose, dtype=float)
        self.velocity = se2.between(self.pose, pose)
        self.pose = pose
        if odom_pose is not None:
            self.prev_odom = odom_pose
        key = len(pts) >= cfg.min_points and self._is_keyframe(pose)
        if key:
            self._insert(pose, pts)
        return FrontendResult(pose.copy(), key, matched, float(score), info, len(pts))


class KissIcpOdometry:
    """kiss-icp on scan points lifted to z = 0 (deskew off), the wheel-odometry increment as its guess."""

    def __init__(self, cfg: OdometryConfig | None = None) -> None:
        from kiss_icp.config import load_config
        from kiss_icp.kiss_icp import KissICP

        self.cfg = cfg or OdometryConfig()
        kc = load_config(None)
        kc.data.max_range = self.cfg.max_range
        kc.data.min_range = self.cfg.min_range
        kc.data.deskew = False
        kc.mapping.voxel_size = self.cfg.voxel_size  # always set: load_config derives it once from max_range
        self.kiss = KissICP(kc)
        self.prev_odom: np.ndarray | None = None
        self.last_key: np.ndarray | None = None
        self.key_distance, self.key_angle = self.cfg.keyframe_distance, math.radians(self.cfg.keyframe_angle_deg)

    def update(self, stamp_ns: int, points: np.ndarray, odom_pose: np.ndarray | None) -> FrontendResult:
        if not self.cfg.use_wheel_odometry:
            odom_pose = None
        if odom_pose is not None and self.prev_odom is not None:
            d = se2.between(self.prev_odom, odom_pose)
            m = np.eye(4)
            m[:2, :2] = [[math.cos(d[2]), -math.sin(d[2])], [math.sin(d[2]), math.cos(d[2])]]
            m[:2, 3] = d[:2]
            self.kiss.last_delta = m  # not an official API: the motion guess kiss-icp composes with its last pose
        if odom_pose is not None:
            self.prev_odom = odom_pose
        matched = len(points) >= self.cfg.min_points
        if matched:
            p3 = np.zeros((len(points), 3))
            p3[:, :2] = points
            self.kiss.register_frame(p3, np.empty(0))
        else:
            self.kiss.last_pose = self.kiss.last_pose @ self.kiss.last_delta
        m = self.kiss.last_pose
        pose = np.array([m[0, 3], m[1, 3], math.atan2(m[1, 0], m[0, 0])])
        d = None if self.last_key is None else se2.between(self.last_key, pose)
        key = d is None or bool(math.hypot(d[0], d[1]) >= self.key_distance or abs(d[2]) >= self.key_angle)
        if key:
            self.last_key = pose.copy()
        return FrontendResult(pose, key, matched)


def make_odometry(cfg: OdometryConfig | None = None):
    """The front end the config names."""
    cfg = cfg or OdometryConfig()
    return KissIcpOdometry(cfg) if cfg.matcher == "kiss-icp" else SubmapOdometry(cfg)


def scan_points_base(ranges: np.ndarray, angles: np.ndarray, valid: np.ndarray, mount: np.ndarray | None,
                     min_range: float, max_range: float) -> np.ndarray:
    """End points (N×2, base_link) of the valid beams within [min_range, max_range]; `mount` = laser pose in base_link."""
    r = ranges.astype(np.float64)
    ok = valid & (r >= min_range) & (r <= max_range)
    pts = np.column_stack((r[ok] * np.cos(angles[ok]), r[ok] * np.sin(angles[ok])))
    if mount is not None and np.any(mount != 0):
        pts = se2.transform_points(mount, pts)
    return pts
