"""The SLAM core: scans (points in base_link) and the wheel odometry and gyro at their stamps, one at a time →
front end (frontend/odometry.py) → keyframes → loops → pose graph (gtsam ISAM2); `finish` solves the graph and gives
every scan an optimised pose through its keyframe (backend/keyframes.py). A Scan stream is a Scan stream: the
laser's or the narrow KOS scan (with the KOS profile, backend/kosprofile.py). mapping/slam.py reads a log into it.
"""

from __future__ import annotations

import dataclasses
import math
import time
from array import array
from collections import deque
from dataclasses import dataclass, field

import numpy as np

from kosmap.backend.consistency import CELL_M, consistency, keep_points, loop_checks
from kosmap.backend.consistency import warning as consistency_warning
from kosmap.backend.graph import GraphConfig, PoseGraph
from kosmap.backend.imu import GyroBuffer
from kosmap.backend.keyframes import (KEY_CELLS, MAX_FOV, NODE_CELLS, FOV_SHARE, NODE_FOV_SHARE, Keyframe, KeyframeSelector,
                                      derived_spacing, relative_covariance, scan_fov, scan_poses)
from kosmap.backend.loops import LoopCloser, LoopConstraint
from kosmap.backend.manhattan import ManhattanHeading
from kosmap.backend.odomnoise import OdomNoiseEstimator, prior_from_factor_sigmas
from kosmap.backend.slamhealth import HealthTracker
from kosmap.backend.slamhealth import warnings as stretch_warnings
from kosmap.frontend import se2
from kosmap.frontend.errors import KosmapError
from kosmap.frontend.odometry import OdometryConfig, held, make_odometry
from kosmap.frontend.records import Scan


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
    stretches: dict = field(default_factory=dict)  # where the run had little to go by (backend/slamhealth.py)
    consistency: dict = field(default_factory=dict)  # does the map agree with itself (backend/consistency.py)
    odom_noise: dict = field(default_factory=dict)  # the wheel odometry's noise measured while running (backend/odomnoise.py)
    spacing: dict = field(default_factory=dict)  # the keyframe and node spacing the run ended with (Slam.spacing)

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
                 keep_points: bool = False, map_cell: float = CELL_M) -> None:
        """`map_cell`: the grid cell the map is drawn at ([grid] resolution), the consistency check's tolerance."""
        self.map_cell = float(map_cell)
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
        # the odometry's noise from matcher-vs-odometry residuals per node interval, the config's factor σ as prior
        g = self.gcfg
        self.odom_noise = OdomNoiseEstimator(prior_from_factor_sigmas(g.odom_sigma_xy_per_m, g.odom_sigma_yaw_per_rad,
                                                                      math.radians(g.odom_sigma_yaw_deg), g.node_distance))
        self._fe_mark = (0, 0, 0)  # the front end's (matches, degenerate, recoveries) at the last keyframe
        self._fov = (0.0, 0.0)  # the widest field of view and its beam step seen over the first FOV_SCANS scans (rad)
        self._fov_scans = 0
        self._spaced_with = None  # the OdomNoise estimate the spacing was last derived with
        o = self.ocfg
        # a front end that holds its pose to the odometry's prediction (the KOS profile) cannot measure its error
        self._measure = not held(o)

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
        if self._fov_scans < FOV_SCANS:
            self._measure_fov(points)
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

    def _measure_odometry(self, prev: Keyframe | None, kf: Keyframe) -> None:
        """One residual for the odometry's noise: the interval prev → kf, when every scan in it was matched on its
        own (none held to the odometry along a corridor, none recovered by the wide search) and both ends have
        odometry; the matcher's motion is then the reference the odometry's is compared with."""
        fe = self.frontend
        mark = (getattr(fe, "matches", 0), getattr(fe, "degenerate", 0), getattr(fe, "recoveries", 0))
        before, self._fe_mark = self._fe_mark, mark
        if (not self._measure or prev is None or prev.odom_pose is None or kf.odom_pose is None
                or not hasattr(fe, "degenerate")):
            return
        if mark[1] != before[1] or mark[2] != before[2] or mark[0] - before[0] != kf.scan_index - prev.scan_index:
            return
        self.odom_noise.add(se2.between(prev.local_pose, kf.local_pose), se2.between(prev.odom_pose, kf.odom_pose))
        noise = self.odom_noise.estimate()
        if noise is not self._spaced_with:
            self._spaced_with = noise  # a new fit: the spacing follows the measured odometry
            self._respace()
        noise = self._measured_noise()
        if noise is not None:
            fe.odom_noise = noise
            if math.isfinite(noise.scale_error_sigma) and noise.scale_error_sigma > 0:
                # the graph's scale variable is otherwise seen only through the loose odometry factors and leans on
                # its prior at 1: along a bare corridor the map then keeps most of the wheels' scale error
                self.graph.scale_prior = (1.0 + noise.scale_error, noise.scale_error_sigma)
            # where the front end leans on the odometry (a corridor), its scale error is the estimate's drift
            self.loops.drift.odometry_rate = abs(noise.scale_error) * mark[1] / max(mark[0], 1)

    def set_sensor(self, fov: float, angle_step: float) -> None:
        """The scanner's own field of view and beam step (rad; a LaserScan's n beams × angle_increment and
        angle_increment): the keyframe spacing is derived from them instead of from the scans' bearings."""
        if fov > 0 and (fov, angle_step) != self._fov:
            self._fov, self._fov_scans = (float(fov), float(angle_step)), FOV_SCANS
            self._respace()

    def _measure_fov(self, points: np.ndarray) -> None:
        """The scan's field of view from the first FOV_SCANS scans with returns, and the spacing derived from it (a
        scan of no declared sensor, e.g. the KOS scan, whose bearings are about base_link)."""
        fov, step = scan_fov(np.asarray(points, dtype=float))
        if fov <= 0:
            return
        self._fov_scans += 1
        if fov > self._fov[0]:
            self._fov = (fov, step)
            self._respace()

    def _respace(self) -> None:
        """Keyframe and node spacing from the scan's field of view and the odometry's measured noise
        (backend/keyframes.py derived_spacing), where [odometry] keyframe_spacing / [graph] node_spacing are derived."""
        if self._fov[0] <= 0:
            return
        noise = self._measured_noise()
        res = self.ocfg.resolution
        if self.ocfg.keyframe_spacing == "derived":
            sp = derived_spacing(self._fov[0], self._fov[1], res, KEY_CELLS, FOV_SHARE, noise, self.ocfg.coarse_resolution)
            self.frontend.key_distance, self.frontend.key_angle = sp.distance, sp.angle
        if self.gcfg.node_spacing == "derived":
            # a node's turn is that of a 180° scan whatever the field of view (backend/keyframes.py NODE_FOV_SHARE)
            sp = derived_spacing(MAX_FOV, self._fov[1], res, NODE_CELLS, NODE_FOV_SHARE, noise,
                                 self.ocfg.coarse_resolution)
            self.select.distance, self.select.angle = sp.distance, sp.angle
        self.loops.sensor_fov = float(self._fov[0])  # what the loop search needs of the sensor (backend/loops.py)

    def spacing(self) -> dict:
        """The keyframe and node spacing in force, where each comes from ("derived" or "fixed"), and the scan's field
        of view it was derived from (metrics.json: the configured distances and angles do not apply when derived)."""
        fe = self.frontend
        return {"keyframe": self.ocfg.keyframe_spacing, "keyframe_distance_m": float(fe.key_distance),
                "keyframe_angle_deg": math.degrees(fe.key_angle), "node": self.gcfg.node_spacing,
                "node_distance_m": float(self.select.distance), "node_angle_deg": math.degrees(self.select.angle),
                "fov_deg": math.degrees(self._fov[0]) if self._fov[0] > 0 else None}

    def _odometry_sigmas(self, rel: np.ndarray) -> np.ndarray | None:
        """The odometry factor's σ: the configured ones, widened to the measured noise where the odometry is worse
        (None: as configured). Never narrowed: the measured σ of one factor cannot say that a scale or heading error
        adds up linearly over consecutive factors, and the match factors' fixed σ are conservative; at the measured σ
        the graph followed the odometry (simulated office, 2.4 % scale and 1.2°/m heading drift: ATE 0.027 → 1.8 m)."""
        noise = self._measured_noise()
        return None if noise is None else np.maximum(self.graph.odometry_sigmas(rel), noise.factor_sigmas(rel))

    def _measured_noise(self):
        """The odometry's noise as measured against the scans (backend/odomnoise.py), where it is measured and
        `[graph] odom_noise = "measured"`; None: the configured σ apply."""
        noise = self.odom_noise.estimate()
        return noise if noise.measured and self.gcfg.odom_noise == "measured" else None

    def _add_keyframe(self, kf: Keyframe) -> None:
        g = self.graph
        self._measure_odometry(self.keyframes[-1] if kf.id else None, kf)
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
                rel_odom = se2.between(prev.odom_pose, kf.odom_pose)
                g.add_odometry(prev.id, kf.id, rel_odom, self._odometry_sigmas(rel_odom))
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
                          self.key_points, loop_checks(self.graph), cell=self.map_cell)
        con.frontend_unsure(getattr(self.frontend, "recoveries", 0), getattr(self.frontend, "matches", 0))
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
                          + health, stretches=st.as_dict(int(stamps[0])), consistency=con.as_dict(),
                          odom_noise=self.odom_noise.estimate(refit=True).as_dict(), spacing=self.spacing())


_NAN3 = (math.nan, math.nan, math.nan)
_NO_POINTS = np.zeros((0, 2))
_NO_POINTS.flags.writeable = False
FE_GYRO_TOL = math.radians(1.0)  # the front end ignores a scan step's gyro yaw this far (or 25 %) from the wheels'
STILL_YAW = math.radians(1.0)  # a node interval whose front-end rotation is below this did not turn (stuck-gyro check)
FOV_SCANS = 50  # scans whose widest bearing span is taken as the sensor's field of view
DEGENERATE_SHARE = 0.2  # a share of degenerate front-end matches that has the odometry scale calibrated while running
MAX_MATCH_VAR = 1.0  # m² / rad²: a match factor alone never claims less than 1 m / 1 rad of information


def _cap_covariance(cov: np.ndarray) -> np.ndarray:
    """`cov` with its eigenvalues clipped to MAX_MATCH_VAR (and to be positive): a narrow scan along a
    corridor has a near-infinite variance along it, which, with no odometry factor beside it, makes the
    graph indeterminate (gtsam IndeterminateSystemException on the simulated office without wheel odometry)."""
    w, v = np.linalg.eigh(0.5 * (cov + cov.T))
    w = np.clip(np.nan_to_num(w, nan=MAX_MATCH_VAR, posinf=MAX_MATCH_VAR), 1e-12, MAX_MATCH_VAR)
    return (v * w) @ v.T
