"""SLAM over a log: scans and wheel odometry in one pass → front end → keyframes → loops → pose graph.

`Slam` takes a Scan stream (laser today; KOS virtual scans later: a Scan stream is a Scan stream) one scan
at a time with the wheel odometry interpolated at its stamp; `run_slam` reads a log and feeds it. Every
scan gets an optimised pose through its keyframe (backend/keyframes.py).
"""

from __future__ import annotations

import dataclasses
import math
import time
from array import array
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from kosmap.backend.graph import GraphConfig, PoseGraph
from kosmap.backend.imu import GyroBuffer
from kosmap.backend.keyframes import Keyframe, KeyframeSelector, relative_covariance, scan_poses
from kosmap.backend.loops import LoopCloser, LoopConstraint
from kosmap.backend.manhattan import ManhattanHeading
from kosmap.frontend import se2
from kosmap.frontend.errors import KosmapError, TopicError
from kosmap.frontend.odometry import NARROW_SCAN, OdometryConfig, make_odometry
from kosmap.frontend.records import ImuSamples, Odometry, OdometrySamples, Scan, Transforms
from kosmap.mapping.consistency import consistency, keep_points
from kosmap.mapping.consistency import warning as consistency_warning
from kosmap.mapping.jsonsafe import json_safe
from kosmap.mapping.slamfeed import SlamFeed, laser_mount, laser_period, no_odom_warning, odometry_columns
from kosmap.mapping.slamhealth import HealthTracker
from kosmap.mapping.slamhealth import warnings as stretch_warnings



@dataclass
class SlamResult:
    """Poses of every scan (base_link in the map frame), the keyframes, the graph and where the time went."""

    stamps_ns: np.ndarray  # (S,) scan stamps
    poses: np.ndarray  # (S, 3) optimised
    local_poses: np.ndarray  # (S, 3) front end only
    odom_poses: np.ndarray  # (S, 3) wheel odometry at each scan (NaN where none)
    matched: np.ndarray  # (S,) bool: the scan was matched (not only predicted)
    key_of_scan: np.ndarray  # (S,) keyframe each scan hangs from
    keyframes: list[Keyframe]
    graph: PoseGraph
    loops: list[LoopConstraint]
    timings: dict
    mount: np.ndarray = field(default_factory=lambda: np.zeros(3))  # sensor pose in base_link (x, y, yaw)
    points: list[np.ndarray] | None = None  # per-scan end points (base_link, float32) when kept
    scans: list[Scan] | None = None  # the Scan records, when kept (for the map)
    ground_truth: tuple[np.ndarray, np.ndarray] | None = None  # (stamps s, N×3) from the log's ground-truth topic
    duration_s: float = 0.0  # log time spanned by the scans
    warnings: list[str] = field(default_factory=list)
    recoveries: int = 0
    loop_stats: dict = field(default_factory=dict)
    imu_stats: dict = field(default_factory=dict)  # gyro factors made and intervals skipped (gap, stuck, uncovered)
    heading_stats: dict | None = None  # Manhattan heading priors (backend/manhattan.py), when on
    stretches: dict = field(default_factory=dict)  # where the run had little to go by (mapping/slamhealth.py)
    consistency: dict = field(default_factory=dict)  # does the map agree with itself (mapping/consistency.py)

    @property
    def stamps(self) -> np.ndarray:
        return self.stamps_ns * 1e-9

    def sensor_poses(self) -> np.ndarray:
        """Poses of the scan's own frame (base_link ⊕ mount): what the benchmark relations relate."""
        return se2.compose(self.poses, np.repeat(self.mount[None], len(self.poses), 0))

    @property
    def realtime_factor(self) -> float:
        """Log seconds per second of SLAM: over the run's wall time (run_slam's "total"), else, where SLAM runs
        beside the reading (`kosmap build`, which has no "total"), over the time of its own stages."""
        t = self.timings.get("total") or sum(v for k, v in self.timings.items() if k != "read")
        return self.duration_s / t if t > 0 else float("inf")


class Slam:
    """Online core: `add_scan` per scan, `finish` for the batch solve and per-scan poses."""

    def __init__(self, odometry: OdometryConfig | None = None, graph: GraphConfig | None = None,
                 keep_points: bool = False) -> None:
        self.ocfg = odometry or OdometryConfig()
        self.gcfg = graph or GraphConfig()
        self.frontend = make_odometry(self.ocfg)
        self.graph = PoseGraph(self.gcfg)
        self.loops = LoopCloser(self.gcfg)
        self.heading = ManhattanHeading(self.gcfg.manhattan_gate_deg) if self.gcfg.manhattan else None
        self.select = KeyframeSelector(self.gcfg.node_distance, np.radians(self.gcfg.node_angle_deg), self.ocfg.min_points)
        self.keyframes: list[Keyframe] = []
        # per scan, compact (65 bytes a scan; lists of 3-vectors held ~220 more, tests/mapping/test_memory.py): stamp,
        # front-end pose (x y yaw flattened), wheel odometry (NaN where none), matched, keyframe it hangs from
        self.stamps = array("q")
        self.local = array("d")
        self.odom = array("d")
        self.matched = array("b")
        self.key_of_scan = array("q")
        self.points: list[np.ndarray] | None = [] if keep_points else None
        self.t = {"frontend": 0.0, "graph": 0.0, "loops": 0.0}
        self.found: list[LoopConstraint] = []
        self.since_update = 0  # nodes added since the last ISAM2 update
        self.since_loop = 0  # loops added since the last ISAM2 update
        self.calibrations = 0
        # the gyro: samples buffered; a yaw factor per node interval once scans and samples are past its end
        self.gyro = GyroBuffer(self.gcfg.gyro_max_gap_s, self.gcfg.gyro_stuck_s)
        self.expect_imu = False  # the log has an IMU: node intervals wait for its samples
        self.gyro_pending: deque[tuple[int, int, int, int, np.ndarray]] = deque()  # (a, b, t_a, t_b, rel)
        self.imu_stats = {"samples": 0, "factors": 0, "gap": 0, "stuck": 0, "uncovered": 0, "frontend_yaw": 0,
                          "frontend_disagree": 0}
        self.imu_warnings: list[str] = []
        self._prev_scan: tuple[int, np.ndarray] | None = None  # (stamp, raw wheel odometry) of the last scan
        self._fused: np.ndarray | None = None  # wheel translation + gyro yaw, the front end's prediction
        self._deg_seen = (0, 0)  # the front end's degenerate and total matches at the last check
        self._leaning = False  # the front end has leant on the odometry: calibrate at every check from then on
        self.key_points: list[np.ndarray] = []  # per keyframe, a few of its points for the consistency check
        # stretches without scans, odometry or a determined match (the feed sets expect_odom)
        self.health = HealthTracker(False, self.gcfg.node_distance, math.radians(self.gcfg.node_angle_deg))

    def add_imu(self, stamp_ns, yaw_rate: float | None = None) -> None:
        """One gyro sample: an Imu record (its z rate; samples without angular velocity are skipped), or a stamp
        and a yaw rate (rad/s about base_link z). Samples may arrive ahead of the scans: a node interval's factor is
        made at a later scan once the samples cover it (or at finish)."""
        if not self.gcfg.imu:
            return
        if yaw_rate is None:
            rec = stamp_ns
            if not rec.has_angular_velocity:
                return
            stamp_ns, yaw_rate = rec.stamp_ns, rec.yaw_rate
        self.expect_imu = True
        self.gyro.add(int(stamp_ns), float(yaw_rate))
        self.imu_stats["samples"] += 1

    def add_imu_many(self, stamps_ns: np.ndarray, yaw_rates: np.ndarray) -> None:
        """`add_imu(stamp, yaw_rate)` of each sample in order (an ImuSamples' stretch, or a batch from the build)."""
        if not self.gcfg.imu or not len(stamps_ns):
            return
        self.expect_imu = True
        self.gyro.add_many(stamps_ns, yaw_rates)
        self.imu_stats["samples"] += len(stamps_ns)

    def _gyro_settled(self, stamp_ns: int, now_ns: int) -> bool:
        """The scans have reached `gyro_stuck_s` past the stamp and the samples cover it: a stuck run that began
        before it has been seen. Decided at scan times only, never by how far the reader ran ahead of the scans
        (a parallel run reads further ahead than a serial one; both must add the same factors at the same node)."""
        t = stamp_ns + int(self.gcfg.gyro_stuck_s * 1e9)
        return t <= now_ns and self.gyro.covers(t)

    def _flush_gyro(self, final: bool, now_ns: int = 0) -> None:
        """Gyro factors for the node intervals settled at scan time `now_ns` (`final`: all that are left)."""
        t0 = time.perf_counter()
        g = self.graph
        while self.gyro_pending and (final or self._gyro_settled(self.gyro_pending[0][3], now_ns)):
            a, b, ta, tb, rel = self.gyro_pending.popleft()
            inc = self.gyro.integrate(ta, tb)
            if inc.reason == "stuck" and abs(rel[2]) < STILL_YAW:
                inc = self.gyro.integrate(ta, tb, allow_stuck=True)  # constant output, and the scans saw no turn either
            if inc.ok:
                g.add_gyro(a, b, inc.dyaw, inc.dt, rel[:2])
                self.imu_stats["factors"] += 1
            else:
                self.imu_stats[inc.reason] += 1
                if inc.reason == "stuck" and not any("stuck" in w for w in self.imu_warnings):
                    self.imu_warnings.append(f"the gyro's output stayed constant for ≥ {self.gcfg.gyro_stuck_s:g} s while the "
                                             f"robot turned (stuck?), from t = {self.gyro.stuck[0][0] * 1e-9:.1f} s: its "
                                             f"samples there are dropped")
        keep = self.gyro_pending[0][2] if self.gyro_pending else (self.keyframes[-1].stamp_ns if self.keyframes else 0)
        if self._prev_scan is not None:
            keep = min(keep, self._prev_scan[0])
        self.gyro.drop_before(keep - int(1e9))
        self.t["graph"] += time.perf_counter() - t0

    def _predict_with_gyro(self, stamp_ns: int, odom_pose: np.ndarray | None) -> np.ndarray | None:
        """The pose the front end predicts from: the wheel odometry's translation, the gyro's yaw (when the samples
        cover the scan interval; otherwise the wheels' yaw). Identity to the front end when there is no gyro."""
        if odom_pose is None or not ((self.gcfg.imu_frontend and self.expect_imu) or self.gcfg.calibrate_every or self._leaning):
            self._prev_scan = None if odom_pose is None else (int(stamp_ns), np.asarray(odom_pose, dtype=float))
            self._fused = None if odom_pose is None else np.asarray(odom_pose, dtype=float)
            return odom_pose
        odom_pose = np.asarray(odom_pose, dtype=float)
        if self._prev_scan is None or self._fused is None:
            fused = odom_pose.copy()
        else:
            t_prev, o_prev = self._prev_scan
            inc = se2.between(o_prev, odom_pose)
            inc[:2] /= self.graph.odom_scale  # 1 unless calibrated while running
            gi = self.gyro.integrate(t_prev, int(stamp_ns)) if self.expect_imu and self.gcfg.imu_frontend else None
            if gi is not None and gi.ok:
                g = gi.dyaw - self.graph.gyro_bias * gi.dt
                # a stuck run is only flagged once it has lasted gyro_stuck_s: until then a gyro that disagrees with the
                # wheels by more than they can err in one scan step (σ ≈ 0.3° in a turn on the simulator) is not used
                if abs(se2.wrap(g - inc[2])) <= max(FE_GYRO_TOL, 0.25 * abs(inc[2])):
                    inc[2] = g
                    self.imu_stats["frontend_yaw"] += 1
                else:
                    self.imu_stats["frontend_disagree"] += 1
            fused = se2.compose(self._fused, inc)
        self._prev_scan = (int(stamp_ns), odom_pose)
        self._fused = fused
        return fused

    def add_scan(self, stamp_ns: int, points: np.ndarray, odom_pose: np.ndarray | None = None) -> None:
        """One scan: points (N×2, base_link), the wheel odometry at its stamp (or None)."""
        t0 = time.perf_counter()
        if self.gyro_pending and self._gyro_settled(self.gyro_pending[0][3], int(stamp_ns)):
            self._flush_gyro(final=False, now_ns=int(stamp_ns))
        if odom_pose is None and hasattr(self.frontend, "prev_odom"):
            # the next odometry sample after a gap must not be differenced with the last one before it: the front end
            # has moved by matching since, and would count the motion across the gap twice (10 s without odometry on
            # the synthetic ring: ATE 8.7 m)
            self.frontend.prev_odom = None
        res = self.frontend.update(stamp_ns, points, self._predict_with_gyro(stamp_ns, odom_pose))
        t1 = time.perf_counter()
        self.t["frontend"] += t1 - t0
        i = len(self.stamps)
        self.stamps.append(int(stamp_ns))
        self.local.extend(map(float, res.pose))
        self.odom.extend(_NAN3 if odom_pose is None else map(float, odom_pose))
        self.matched.append(bool(res.matched))
        self.health.scan(stamp_ns, len(points) >= self.ocfg.min_points, odom_pose)
        if self.points is not None:
            self.points.append(np.asarray(points, dtype=np.float32))
        if self.select(res.pose, len(points)):
            cov = res.covariance(self.gcfg.match_n_eff) if self.gcfg.match_noise == "hessian" else None
            kf = Keyframe(len(self.keyframes), i, int(stamp_ns), res.pose, np.asarray(points, dtype=float),
                          None if odom_pose is None else np.asarray(odom_pose, dtype=float), res.score, cov)
            self.health.keyframe(stamp_ns, res.pose, kf.points)
            self.key_points.append(keep_points(kf.points))
            self._add_keyframe(kf)
            # the loop closer has taken its thinned float32 copy (backend/loops.py); the full scan is not kept for the
            # whole run (5–17 KB a keyframe as float64: ~10 MB per 5 minutes of the office on both SLAMs)
            kf.points = _NO_POINTS
        self.key_of_scan.append(max(len(self.keyframes) - 1, 0))

    def _add_keyframe(self, kf: Keyframe) -> None:
        g = self.graph
        t0 = time.perf_counter()
        if kf.id == 0:
            g.add_node(np.zeros(3))
        else:
            prev = self.keyframes[-1]
            rel = se2.between(prev.local_pose, kf.local_pose)
            g.add_node(se2.compose(g.est[prev.id], rel))
            if kf.cov is not None and prev.cov is not None:
                # honest: both ends' match covariances (large along what the scans cannot see) + the fixed part
                cov = relative_covariance(prev.local_pose, prev.cov, kf.local_pose, kf.cov) + np.diag(g.match_sigmas(rel) ** 2)
                if not (self.gcfg.odometry_factors and kf.odom_pose is not None and prev.odom_pose is not None):
                    cov = _cap_covariance(cov)  # nothing else ties the nodes: a blind direction must not be singular
                g.add_match(prev.id, kf.id, rel, cov=cov)
            else:
                g.add_match(prev.id, kf.id, rel)
            if self.gcfg.odometry_factors and kf.odom_pose is not None and prev.odom_pose is not None:
                g.add_odometry(prev.id, kf.id, se2.between(prev.odom_pose, kf.odom_pose))
            if self.gcfg.imu and self.expect_imu:
                self.gyro_pending.append((prev.id, kf.id, prev.stamp_ns, kf.stamp_ns, rel))
        if self.heading is not None:
            yaw = self.heading.observe(float(g.est[kf.id, 2]), kf.points)
            if yaw is not None:
                g.add_heading(kf.id, yaw)
        self.keyframes.append(kf)
        t1 = time.perf_counter()
        self.t["graph"] += t1 - t0
        if self.gcfg.loop_closure:
            self.loops.add_node(kf, g)
            if kf.id % self.gcfg.loop_search_every == 0:
                # candidates are chosen, and searched, around the current estimate: the last solved pose
                # composed with the front end's motion since (ISAM2 runs every `optimize_every` nodes)
                for lc in self.loops.search(kf.id, g):
                    g.add_loop(lc.a, lc.b, lc.rel, lc.score, cov=lc.cov)
                    self.found.append(lc)
                    self.since_loop += 1
        t2 = time.perf_counter()
        self.t["loops"] += t2 - t1
        self.since_update += 1
        if self.since_update >= self.gcfg.optimize_every:
            g.update(full=self.since_loop > 0)
            self.since_update = self.since_loop = 0
        every = self.gcfg.calibrate_every
        if (every and kf.id and kf.id % every == 0) or self._leaning_on_odometry(kf.id):
            # the scale and bias while running: the front end pulls its along-track position hard towards the wheel
            # prediction (a narrow scan sees nothing along a corridor), so an uncorrected scale biases the matches
            # themselves and the final estimate towards 1 (synthetic ring, 3 % injected: 1.014 found; the front end
            # fed the true scale: 1.031, ATE 0.13 → 0.02 m)
            g.calibrate(rebase=self.gcfg.calibrate_rebase)
            self.calibrations += 1
        elif (self.gcfg.gyro_bias_every and self.gcfg.gyro_bias == "estimate" and self.imu_stats["factors"]
              and kf.id % self.gcfg.gyro_bias_every == 0):
            # the gyro bias only: later gyro factors and predictions subtract it
            g.calibrate(scale=False, rebase=self.gcfg.calibrate_rebase)
            self.calibrations += 1
        self.t["graph"] += time.perf_counter() - t2

    def _leaning_on_odometry(self, kf_id: int) -> bool:
        """Every [odometry] degenerate_calibrate_every keyframes, once the front end has held ≥ DEGENERATE_SHARE of
        its matches between two checks along the odometry (a corridor: frontend/odometry.py degeneracy_prior): the
        odometry's scale error then goes straight into the map unless it is estimated while running, and every later
        check re-estimates it (simulated long-corridor world, 2 %/2.8 % wheel errors: ATE 0.105 → 0.077 m)."""
        n = self.ocfg.degenerate_calibrate_every
        fe = self.frontend
        if not n or not kf_id or kf_id % n or not hasattr(fe, "degenerate"):
            return False
        share = (fe.degenerate - self._deg_seen[0]) / max(fe.matches - self._deg_seen[1], 1)
        self._deg_seen = (fe.degenerate, fe.matches)
        self._leaning = self._leaning or share >= DEGENERATE_SHARE
        return self._leaning

    def finish(self) -> SlamResult:
        """Batch solve, then a pose for every scan through its keyframe."""
        if not self.keyframes:
            raise KosmapError(f"none of the {len(self.stamps)} scans had {self.ocfg.min_points} or more returns; "
                              f"nothing to map (check the scan topic and [odometry] min_range/max_range)")
        self._flush_gyro(final=True)
        st = self.imu_stats
        if st["gap"] or st["uncovered"]:
            self.imu_warnings.append(f"{st['gap'] + st['uncovered']} of {len(self.keyframes) - 1} node intervals had gyro gaps "
                                     f"(> {self.gcfg.gyro_max_gap_s:g} s without a sample) or lay outside the IMU stream: "
                                     f"no gyro factor there")
        if st["frontend_disagree"] > 0.01 * max(st["frontend_yaw"] + st["frontend_disagree"], 1):
            self.imu_warnings.append(f"the gyro disagreed with the wheel odometry on {st['frontend_disagree']} scan steps "
                                     f"(> {math.degrees(FE_GYRO_TOL):g}° or 25 %): the wheels' yaw was predicted there")
        t0 = time.perf_counter()
        self.graph.optimize()
        self.t["optimize"] = time.perf_counter() - t0
        self.loops.release()
        key_local = np.array([k.local_pose for k in self.keyframes])
        local = np.array(self.local, dtype=float).reshape(-1, 3)
        kos = np.array(self.key_of_scan, dtype=np.int64)
        poses = scan_poses(local, kos, key_local, self.graph.est)
        stamps = np.array(self.stamps, dtype=np.int64)
        st = self.health.finish(np.array([k.stamp_ns for k in self.keyframes], dtype=np.int64), self.graph.weak_nodes,
                                self.graph.solver_notes)
        health = stretch_warnings(st, int(stamps[0]), self.health.expect_odom)
        con = consistency((np.array([k.stamp_ns for k in self.keyframes]) - stamps[0]) * 1e-9, self.graph.est,
                          self.key_points, [r[1] for r in self.graph.loop_residuals()], self.gcfg.loop_sigma_xy)
        bent = consistency_warning(con)
        health += [bent] if bent else []
        return SlamResult(stamps, poses, local, np.array(self.odom, dtype=float).reshape(-1, 3),
                          np.array(self.matched, dtype=bool), kos, self.keyframes, self.graph, list(self.found), dict(self.t),
                          points=self.points, recoveries=getattr(self.frontend, "recoveries", 0),
                          duration_s=float(stamps[-1] - stamps[0]) * 1e-9 if len(stamps) else 0.0,
                          loop_stats=dataclasses.asdict(self.loops.stats), imu_stats=dict(self.imu_stats),
                          heading_stats=None if self.heading is None else dataclasses.asdict(self.heading.stats),
                          warnings=list(self.imu_warnings) + ([self.heading.stats.disabled]
                                                              if self.heading is not None and self.heading.stats.disabled else [])
                          + health, stretches=st.as_dict(int(stamps[0])), consistency=con.as_dict())


_NAN3 = (math.nan, math.nan, math.nan)
_NO_POINTS = np.zeros((0, 2))
_NO_POINTS.flags.writeable = False
FE_GYRO_TOL = math.radians(1.0)  # the front end ignores a scan step's gyro yaw this far (or 25 %) from the wheels'
STILL_YAW = math.radians(1.0)  # a node interval whose front-end rotation is below this did not turn (stuck-gyro check)
DEGENERATE_SHARE = 0.2  # a share of degenerate front-end matches that has the odometry scale calibrated while running
MAX_MATCH_VAR = 1.0  # m² / rad²: a match factor alone never claims less than 1 m / 1 rad of information


def _cap_covariance(cov: np.ndarray) -> np.ndarray:
    """`cov` with its eigenvalues clipped to MAX_MATCH_VAR (and to be positive): a narrow scan along a
    corridor has a near-infinite variance along it, which, with no odometry factor beside it, makes the
    graph indeterminate (gtsam IndeterminateSystemException on the simulated office without wheel odometry)."""
    w, v = np.linalg.eigh(0.5 * (cov + cov.T))
    w = np.clip(np.nan_to_num(w, nan=MAX_MATCH_VAR, posinf=MAX_MATCH_VAR), 1e-12, MAX_MATCH_VAR)
    return (v * w) @ v.T


def _mount(statics: dict[str, tuple[str, np.ndarray]], base: str, frame: str) -> np.ndarray | None:
    """Planar pose of `frame` in `base` from static transforms (child → (parent, x y yaw)); None if unlinked."""
    pose = np.zeros(3)
    f = frame.lstrip("/")
    for _ in range(32):
        if f == base:
            return pose
        if f not in statics:
            return None
        parent, p = statics[f]
        pose = se2.compose(p, pose)
        f = parent
    return None


def run_slam(path: str | Path, cfg=None, source: str = "laser", progress: Callable[[float, float], None] | None = None,
             keep_scans: bool = False, max_seconds: float | None = None, workers: int = 0) -> SlamResult:
    """Read a log in one pass and run SLAM on its laser scans (`source="laser"`) or on the KOS scans of its
    depth camera(s) (`source="kos"`: FSPF+ → KOS per frame in `workers` processes, 0 = here), with its
    wheel odometry.

    `cfg` is a mapping.config.Config (defaults when None); `progress(done_s, total_s)` is called as log time
    advances; `keep_scans` keeps the Scan records (for the map); `max_seconds` stops after that much log
    time (for slices).
    """
    from kosmap.frontend.logs import detect_topics, open_log
    from kosmap.mapping.config import Config

    cfg = cfg or Config()
    if source == "kos":
        return _run_slam_kos(path, cfg, progress, keep_scans, max_seconds, workers)
    if source != "laser":
        raise KosmapError(f"unknown source '{source}'; use laser or kos")
    t_start = time.perf_counter()
    ocfg: OdometryConfig = cfg.odometry
    slam = Slam(ocfg, cfg.graph)
    kept: list[Scan] | None = [] if keep_scans else None
    warnings: list[str] = []
    with open_log(path, cfg.topics.on_damage) as log:
        info = log.info()
        det = detect_topics(info.types(), cfg.topics)
        if not det.scan:
            raise TopicError(f"{Path(path).name} has no sensor_msgs/LaserScan topic; --source laser needs one (see `kosmap info`)")
        use_odom = bool(det.odom) and ocfg.use_wheel_odometry
        feed = SlamFeed(slam, use_odom, bool(det.imu))  # the build's feed (mapping/slamfeed.py): the same inputs
        topics = [det.scan] + ([det.odom] if det.odom else []) + ([det.tf_static] if det.tf_static else [])
        topics += [det.ground_truth] if det.ground_truth else []  # read for scoring only, never used by SLAM
        topics += [det.imu] if feed.use_imu else []
        period = laser_period(cfg.build.laser_rate, info.count(det.scan), float(info.duration))
        gt: list[np.ndarray] = []
        statics: list[Transforms] = []
        st = {"base": "base_link", "mount": None, "last": None, "first": None, "now": None}
        total = info.duration
        for rec in log.read_batched(topics):
            if rec.stamp_ns and (st["now"] is None or rec.stamp_ns > st["now"]):
                st["now"] = rec.stamp_ns
            if isinstance(rec, (Odometry, OdometrySamples)):
                cols = odometry_columns(rec)
                if rec.topic == det.ground_truth:
                    gt.append(np.column_stack(cols))
                    continue
                if rec.topic == det.odom:
                    if st["base"] == "base_link" and rec.child_frame_id:
                        st["base"] = rec.child_frame_id.lstrip("/") or "base_link"
                    feed.wheel_samples(*cols)
            elif isinstance(rec, ImuSamples):
                ok = rec.has_angular_velocity
                feed.gyro_samples(rec.stamps_ns[ok], rec.yaw_rate[ok])
            elif isinstance(rec, Transforms):
                if rec.static:
                    statics.append(rec)
            elif rec.topic == det.imu:
                feed.imu(rec)
            elif isinstance(rec, Scan):
                if st["first"] is None:
                    st["first"] = rec.stamp_ns
                if max_seconds is not None and (rec.stamp_ns - st["first"]) * 1e-9 > max_seconds:
                    break
                if st["last"] is None or rec.stamp_ns - st["last"] >= period - 1_000_000:
                    if st["mount"] is None:
                        st["mount"], w = laser_mount(statics, st["base"], rec.frame_id)
                        warnings.extend([w] if w else [])
                    feed.push_laser(rec, st["mount"])
                    st["last"] = rec.stamp_ns
                    if kept is not None:
                        kept.append(rec)
                if progress is not None:
                    progress((rec.stamp_ns - st["first"]) * 1e-9, total)
            feed.advance(st["now"])
        feed.end()
        warnings.extend(log.warnings)
    result = feed.result()
    if result is None:
        raise KosmapError(nothing_reached_slam(path, "laser scan", warnings))
    result.timings["total"] = time.perf_counter() - t_start
    result.timings["read"] = result.timings["total"] - sum(v for k, v in result.timings.items() if k != "total")
    result.mount = st["mount"] if st["mount"] is not None else np.zeros(3)
    result.duration_s = (result.stamps_ns[-1] - result.stamps_ns[0]) * 1e-9 if len(result.stamps_ns) else 0.0
    empty = result.stretches.get("unusable_scans", 0)
    if empty:
        warnings.append(f"{empty} scan(s) had fewer than {ocfg.min_points} returns: posed from odometry only")
    w = no_odom_warning(feed.no_odom, result.stretches, "laser")
    warnings.extend([w] if w else [])
    result.warnings = warnings + result.warnings
    result.scans = kept
    if gt:
        g = np.concatenate(gt)
        result.ground_truth = (g[:, 0] * 1e-9, g[:, 1:4])
    return result


# The front end for a narrow KOS scan, before [build] kos_odometry: NARROW_SCAN plus a stronger pull to the wheel
# odometry's yaw. Measured on simulated logs (10 Hz depth, one front camera, seed 0), ATE RMSE:
#   room 30 s: [build] kos_odometry alone 0.067 m, + NARROW_SCAN 0.029 m, + prior_weight_yaw 100 0.017 m (odometry 0.053)
#   office 361 s: NARROW_SCAN 0.485 m (19 loops, all wrong), without loops 0.332 m; + prior_weight_yaw 100: 0.156 m
#   without loops, 0.104 m with (21 loops, 38 % right); prior_weight_yaw 1000 without loops 0.256 m (odometry 0.256 m)
KOS_FRONTEND = {**NARROW_SCAN, "prior_weight_yaw": 100.0}


def _with_overrides(base, defaults: dict, overrides: dict, what: str):
    """`base` with `defaults`, then the user's [build] `what` table, applied; an unknown key is a config error."""
    known = {f.name for f in dataclasses.fields(base)}
    bad = [k for k in overrides if k not in known]
    if bad:
        from kosmap.frontend.errors import ConfigError

        raise ConfigError(f"config [build] {what} has unknown key(s) {', '.join(bad)}; known: {', '.join(sorted(known))}")
    return dataclasses.replace(base, **{**defaults, **overrides})


def kos_odometry_config(cfg) -> OdometryConfig:
    """The front end for a narrow KOS scan: [odometry] with KOS_FRONTEND, then [build] kos_odometry applied."""
    return _with_overrides(cfg.odometry, KOS_FRONTEND, cfg.build.kos_odometry, "kos_odometry")


# The graph for a narrow KOS scan, before [build] kos_graph: wheel-odometry factors closer to what a wheeled indoor robot
# on a flat floor does (σ 5 mm + 2 % of the step; the [graph] defaults, 5 cm + 10 %, are for the slipping laser
# benchmark robots). Along a corridor the wheels are all that fixes the position, and the odometry scale is
# observable only if the wheels are not declared worse than they are. Measured on the simulated office (361 s, one
# front camera, 10 Hz depth, replayed KOS scans, ATE RMSE): with the gyro 0.056 → 0.045 m (seed 0), 0.065 → 0.039 m
# (seed 1); scale estimate 1.0071 → 1.0086 (seed 0, truth 1.0100); without the gyro seed 1 0.104 → 0.081 m.
# calibrate_every 300: the front end's along-track pull towards the wheels biases the final scale estimate towards 1
# (office with the simulator's IMU, seeds 0/1/2, truth 1.0105: −0.10/−0.18/−0.21 % at 10 Hz, −0.4 % at 5 Hz); the
# scale fed back to the front end twice a run: +0.15/+0.03/+0.09 % and ATE 0.038/0.037/0.032 → 0.032/0.034/0.025 m
# (5 Hz: 0.062/0.072/0.051 → 0.037/0.054/0.038 m, scale −0.14/−0.28/−0.23 %). Every 100 nodes overshoots (+0.2…+0.5 %
# at 10 Hz): the front end then follows the estimate and the graph reads its own correction back. Chosen on these
# three seeds (tools/bench_kos_slam.py, docs/bench/kos_slam.md).
# imu_frontend: the gyro's yaw in the front end's prediction (old office logs, synthetic gyro, seed 0: 0.060 → 0.056 m).
# gyro_bias_every 0: the scale-and-bias calibration above serves; re-estimating the bias every 50 nodes feeds a poorly
# determined early bias into the front end's yaw (office 90 s slice: ATE 0.021 → 0.039 m; whole office mixed).
# gyro_bias_walk_deg_s 0.0005 (the laser's 0.002 lets the bias follow the narrow scans' weak yaw): replayed KOS scans
# (tools/bench_kos_slam.py), 10 Hz, ATE with a walk of 0.002 → 0.0005 °/s/√s: office seed 0 0.030 → 0.036 m, seed 1
# 0.032 → 0.026 m, the 23-minute office survey 0.76 → 0.25 m (full build runs: seed 0 0.039 m, survey 0.218 m). Wider loop windows (3 m, radius 8 m) took the survey to 0.09 m but
# doubled seed 0's error (0.066 m): left as they are.
# manhattan: heading priors from the walls (backend/manhattan.py). Replayed KOS scans with the running rebase, ATE
# without → with: survey 0.081 → 0.044 m (no loops at all: 0.64 → 0.06 m), office seed 0 0.037 → 0.032 m, seed 1
# 0.035 → 0.032 m, demo 0.041 → 0.039 m. Off for a laser: its wide scans close loops and keep their heading already.
KOS_GRAPH = {"odom_sigma_xy": 0.005, "odom_sigma_xy_per_m": 0.02, "calibrate_every": 300, "imu_frontend": True,
             "gyro_bias_every": 0, "gyro_bias_walk_deg_s": 0.0005, "manhattan": True}


def kos_graph_config(cfg) -> GraphConfig:
    """The graph for a narrow KOS scan: [graph] with KOS_GRAPH, then [build] kos_graph applied."""
    return _with_overrides(cfg.graph, KOS_GRAPH, cfg.build.kos_graph, "kos_graph")


def nothing_reached_slam(path, what: str, warnings: list[str]) -> str:
    """The error of a run where no scan reached SLAM, with the first thing the reading skipped (the reason, when
    the log's scans or frames could not be used) rather than a count of zero scans."""
    first = next((w for w in warnings if "skipped" in w), warnings[0] if warnings else None)
    why = f": {first.removeprefix(Path(path).name + ': ')}" if first else " (every scan was empty?)"
    return f"{Path(path).name}: no {what} reached SLAM{why}; nothing to map"


def _run_slam_kos(path, cfg, progress, keep_scans: bool, max_seconds: float | None, workers: int) -> SlamResult:
    """SLAM on the KOS scan named by [build] slam_scan (obstacle by default) of every time step
    (mapping/kosscan.py's KosStream), with the log's wheel odometry; the ground-truth topic is read for scoring."""
    from kosmap.frontend.logs import detect_topics, open_log
    from kosmap.frontend.odometry import scan_points_base
    from kosmap.mapping.framepool import FramePool
    from kosmap.mapping.kosscan import KosStream, ScanRun

    t_start = time.perf_counter()
    bands = [b[0] for b in cfg.kos.bands()]
    name = cfg.build.slam_scan
    if name not in bands:
        from kosmap.frontend.errors import ConfigError

        raise ConfigError(f"config [build] slam_scan = {name!r} is not a KOS scan of this config; choose one of {', '.join(bands)}")
    ocfg = kos_odometry_config(cfg)
    gcfg = kos_graph_config(cfg)
    slam = Slam(ocfg, gcfg)
    kept: list[Scan] | None = [] if keep_scans else None
    warnings: list[str] = []
    gt_t: list[float] = []
    gt_p: list[tuple[float, float, float]] = []
    state = {"t0": None, "empty": 0, "stop": False}
    with open_log(path, cfg.topics.on_damage) as log:
        info = log.info()
        det = detect_topics(info.types(), cfg.topics)
        if not det.depth:
            raise TopicError(f"{Path(path).name} has no depth image topic; --source kos needs one (see `kosmap info`; "
                             f"name it with --depth-topic)")
        use_odom = bool(det.odom) and ocfg.use_wheel_odometry
        use_imu = bool(det.imu) and gcfg.imu
        feed = SlamFeed(slam, use_odom, use_imu)
        run = ScanRun()
        total = info.duration
        min_period = int(1e9 / cfg.build.depth_rate) if cfg.build.depth_rate > 0 else 0

        def on_step(step) -> None:
            if state["t0"] is None:
                state["t0"] = step.stamp_ns
            if max_seconds is not None and (step.stamp_ns - state["t0"]) * 1e-9 > max_seconds:
                state["stop"] = True
                return
            sc = step.scans[name]
            pts = scan_points_base(sc.ranges, sc.angles, sc.valid(), None, ocfg.min_range, ocfg.max_range)
            if len(pts) < ocfg.min_points:
                state["empty"] += 1
            feed.push(step.stamp_ns, pts)
            if kept is not None:
                kept.append(sc)
            if progress is not None:
                progress((step.stamp_ns - state["t0"]) * 1e-9, total)

        topics = det.wanted()
        with FramePool(cfg.fspf, cfg.depth, cfg.kos, workers) as pool:
            stream = KosStream(det, cfg, run, pool, min_period_ns=min_period, fuse=False)
            now = None
            for rec in log.read(topics):
                if rec.stamp_ns and (now is None or rec.stamp_ns > now):
                    now = rec.stamp_ns
                if isinstance(rec, Odometry):
                    if rec.topic == det.ground_truth:  # scoring only, never used by SLAM
                        gt_t.append(rec.stamp)
                        gt_p.append((rec.x, rec.y, rec.yaw))
                        continue
                    if rec.topic == det.odom:
                        feed.odom(rec)
                elif use_imu and rec.topic == det.imu:
                    feed.imu(rec)
                for step in stream.feed(rec):
                    on_step(step)
                feed.advance(now)
                if state["stop"]:
                    break
            if not state["stop"]:
                for step in stream.flush():
                    on_step(step)
        feed.advance(None)
        warnings.extend(run.warnings)
        warnings.extend(log.warnings)
    if not slam.stamps:
        raise KosmapError(nothing_reached_slam(path, "KOS scan", warnings))
    result = slam.finish()
    result.timings["total"] = time.perf_counter() - t_start
    result.timings["read"] = result.timings["total"] - sum(v for k, v in result.timings.items() if k != "total")
    result.mount = np.zeros(3)  # KOS scans are in base_link
    result.duration_s = (result.stamps_ns[-1] - result.stamps_ns[0]) * 1e-9 if len(result.stamps_ns) else 0.0
    if state["empty"]:
        warnings.append(f"{state['empty']} KOS scan(s) had fewer than {ocfg.min_points} returns: posed from odometry only")
    w = no_odom_warning(feed.no_odom, result.stretches, "KOS")
    warnings.extend([w] if w else [])
    result.warnings = warnings + result.warnings
    result.scans = kept
    if gt_t:
        result.ground_truth = (np.array(gt_t), np.array(gt_p))
    return result


def evaluate(result: SlamResult, relations: str | Path | np.ndarray | None = None,
             ground_truth: str | Path | tuple[np.ndarray, np.ndarray] | None = None) -> dict:
    """Accuracy of a run: the relations metric (in the scan's frame, which the relations relate) and the
    loops' precision against the trajectory the relations describe; ATE, RPE and loop precision against a
    TUM ground truth (base_link), or against the log's own ground-truth topic when no file is given."""
    from kosmap.backend import metrics as M
    from kosmap.backend.trajio import read_tum

    out: dict = {}
    mount = np.repeat(result.mount[None], max(len(result.loops), 1), 0)[: len(result.loops)]
    kstamp = np.array([k.stamp_ns for k in result.keyframes]) * 1e-9
    la = np.array([lc.a for lc in result.loops], dtype=int)
    lb = np.array([lc.b for lc in result.loops], dtype=int)
    meas = np.array([lc.rel for lc in result.loops]).reshape(-1, 3)
    if relations is not None:
        rel = M.read_relations(relations) if not isinstance(relations, np.ndarray) else relations
        sensor = result.sensor_poses()
        out["relations"] = M.relations_metric(result.stamps, sensor, rel)
        out["relations_split_30s"] = M.relations_metric_split(result.stamps, sensor, rel)
        if len(meas):
            ref = M.reference_from_relations(rel)
            local = se2.compose(result.local_poses, np.repeat(result.mount[None], len(result.local_poses), 0))
            pa, ca = ref.at(kstamp[la], result.stamps, local)
            pb, cb = ref.at(kstamp[lb], result.stamps, local)
            meas_s = se2.compose(se2.compose(se2.inverse(mount), meas), mount)  # base → sensor frame
            out["loop_precision"] = M.loop_precision(meas_s, pa, pb, ca, cb)
            out["loop_precision"]["reference"] = "trajectory solved from the relations, carried by the front end"
    if ground_truth is None and result.ground_truth is not None:
        ground_truth = result.ground_truth
    if ground_truth is not None:
        tg, pg = read_tum(ground_truth) if not isinstance(ground_truth, tuple) else ground_truth
        out["ate"] = M.ate(result.stamps, result.poses, tg, pg)
        out["rpe"] = M.rpe(result.stamps, result.poses, tg, pg)
        out["ate_frontend"] = M.ate(result.stamps, result.local_poses, tg, pg)
        has_odom = np.all(np.isfinite(result.odom_poses), axis=1) if len(result.odom_poses) else np.zeros(0, bool)
        if has_odom.sum() >= 2:  # the baseline SLAM must beat: the log's wheel odometry at the same stamps
            out["ate_odometry"] = M.ate(result.stamps[has_odom], result.odom_poses[has_odom], tg, pg)
        if len(meas):
            ref = M.Reference(np.asarray(tg, dtype=float), np.asarray(pg, dtype=float), np.zeros(len(tg), int))
            order = np.argsort(ref.t)
            ref = M.Reference(ref.t[order], ref.poses[order], ref.comp)
            pa, ca = ref.at(kstamp[la], max_diff=0.1)
            pb, cb = ref.at(kstamp[lb], max_diff=0.1)
            out["loop_precision_gt"] = M.loop_precision(meas, pa, pb, ca, cb)
    return out


def build_map(result: SlamResult, grid_cfg=None):
    """The log-odds occupancy grid (mapping/grid.py) of the kept scans at their optimised poses."""
    from kosmap.mapping.grid import GridBuilder

    if not result.scans:
        raise KosmapError("the run kept no scans; call run_slam(..., keep_scans=True) to build a map")
    b = GridBuilder(grid_cfg, mount=tuple(result.mount))
    for pose, scan in zip(result.poses, result.scans):
        b.add(pose, scan)
    return b.to_occupancy()




def summary(result: SlamResult) -> dict:
    """Counts and timings of a run (what metrics.json holds besides the accuracy)."""
    edges = result.graph.edges
    kinds = {e.kind for e in edges}
    return {"scans": int(len(result.stamps_ns)), "matched_scans": int(result.matched.sum()),
            "keyframes": len(result.keyframes), "loops": len(result.loops),
            "factors": {k: sum(e.kind == k for e in edges) for k in ("match", "odom", "gyro", "loop", "heading", "motion")},
            "stretches": result.stretches, "consistency": result.consistency,
            "heading": result.heading_stats,
            "recoveries": int(result.recoveries), "duration_s": result.duration_s,
            "seconds": dict(result.timings), "realtime_factor": result.realtime_factor,
            "mount": result.mount.tolist(), "loop_search": result.loop_stats,
            "odometry_scale": result.graph.odom_scale if "odom" in kinds and result.graph.cfg.odom_scale == "estimate" else None,
            "gyro_bias_deg_s": (math.degrees(result.graph.gyro_bias_mean) if "gyro" in kinds and result.graph.cfg.gyro_bias == "estimate"
                                else None),
            "imu": result.imu_stats, "warnings": list(result.warnings)}


def save_run(result: SlamResult, out: str | Path, cfg=None, metrics: dict | None = None, grid=None) -> dict[str, Path]:
    """Write trajectory.tum (every scan, base_link), keyframes.tum, graph.g2o, metrics.json, map.png +
    map.pgm/map.yaml (when a grid is given) and config.toml into `out`; returns the paths."""
    import json
    import os

    from kosmap.backend.trajio import write_tum
    from kosmap.mapping.config import write_config

    d = Path(out)
    d.mkdir(parents=True, exist_ok=True)
    paths = {"trajectory": write_tum(d / "trajectory.tum", result.stamps, result.poses),
             "keyframes": write_tum(d / "keyframes.tum", np.array([k.stamp_ns for k in result.keyframes]) * 1e-9,
                                    result.graph.est),
             "graph": result.graph.write_g2o(d / "graph.g2o")}
    doc = {"run": summary(result), **(metrics or {})}
    tmp = d / "metrics.json.partial"
    tmp.write_text(json.dumps(json_safe(doc), indent=2))
    os.replace(tmp, d / "metrics.json")
    paths["metrics"] = d / "metrics.json"
    if grid is not None:
        from kosmap.mapping.mapio import grid_picture, write_map_server, write_png

        paths["map_png"] = write_png(grid_picture(grid, result.poses), d / "map.png")
        paths["map_yaml"] = write_map_server(grid, d / "map.yaml")
    if cfg is not None:
        paths["config"] = write_config(cfg, d / "config.toml")
    return paths
