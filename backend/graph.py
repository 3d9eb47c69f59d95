"""The pose graph: gtsam Pose2 nodes, odometry, scan-matching and loop factors, robust kernels, batch LM.

Nodes are keyframes (backend/keyframes.py). Factors, each with its own noise model:
- scan matching: the front end's relative pose between consecutive nodes, σ growing with the distance;
- wheel odometry (optional): the odometry increment between consecutive nodes, looser; in the final solve its
  translation is scaled by an odometry-scale variable (`odom_scale = "estimate"`, a weak prior on 1): loops and
  scans that see along the path make the wheel radius error observable;
- gyro (optional, backend/imu.py): the integrated yaw rate between consecutive nodes, a yaw-only constraint
  (x/y σ huge); in the final solve minus a gyro-bias variable × Δt (`gyro_bias = "estimate"`);
- loops (backend/loops.py): a node's pose in an older submap's anchor frame, under a Cauchy kernel (or
  GNC in the final solve): docs/dependencies.md measured plain Gaussian 11 m, Huber 1.4 m, Cauchy 0.21 m, GNC 0.12 m
  with 25 gross outlier loops among 500.
ISAM2 keeps the estimate current while the loop search runs (candidates are chosen near the current
estimate); one batch Levenberg–Marquardt (or GNC) solve finishes.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import gtsam
import numpy as np

from kosmap.frontend import se2
from kosmap.frontend.params import StageConfig, param


@dataclass
class GraphConfig(StageConfig):
    """[graph]: nodes, the loop search and the robust kernel. Defaults: one set for every benchmark log."""

    section = "graph"
    node_spacing: str = param("derived", choices=("derived", "fixed"), doc="node spacing by the [odometry] keyframe rule "
                              "with 4 cells and 1/18 of a 180° scan's turn for every sensor (backend/keyframes.py derived_spacing: "
                              "0.2 m, 10°; shorter travel for noisy measured odometry), or node_distance and node_angle_deg")
    node_distance: float = param(0.2, lo=0.0, doc="a new graph node after this travel (node_spacing = \"fixed\")", unit="m")
    node_angle_deg: float = param(10.0, lo=0.0, doc="… or after this rotation", unit="deg")
    match_noise: str = param("hessian", choices=("fixed", "hessian"), doc="scan-matching factor σ: fixed below, or from the matches' Gauss–Newton information (+ the fixed part)")
    match_n_eff: float = param(100.0, lo=1.0, doc="hessian noise: at most this many returns count as independent")
    match_sigma_xy: float = param(0.01, lo=0.0, lo_open=True, doc="scan-matching factor σ per node step, plus …", unit="m")
    match_sigma_xy_per_m: float = param(0.02, lo=0.0, doc="… this much per metre travelled", unit="m/m")
    match_sigma_yaw_deg: float = param(0.25, lo=0.0, lo_open=True, doc="scan-matching factor yaw σ per node step", unit="deg")
    odometry_factors: bool = param(True, doc="add wheel-odometry factors between consecutive nodes")
    odom_sigma_xy: float = param(0.05, lo=0.0, lo_open=True, doc="wheel-odometry factor σ, plus …", unit="m")
    odom_sigma_xy_per_m: float = param(0.1, lo=0.0, doc="… this much per metre travelled", unit="m/m")
    odom_sigma_yaw_deg: float = param(2.0, lo=0.0, lo_open=True, doc="wheel-odometry factor yaw σ, plus …", unit="deg")
    odom_sigma_yaw_per_rad: float = param(0.1, lo=0.0, doc="… this fraction of the rotation", unit="rad/rad")
    odom_noise: str = param("measured", choices=("measured", "fixed"), doc="wheel-odometry factor σ, the front end's search window and the loop window's drift from the odometry's noise measured while running against the scan matcher (backend/odomnoise.py; the odom_sigma_* above are its prior), or the odom_sigma_* as given")
    loop_closure: bool = param(True, doc="search for and add loop closures")
    submap_nodes: int = param(40, lo=2, doc="nodes per loop-closure submap")
    loop_search_radius: float = param(4.0, lo=0.0, doc="candidate submaps with a node within this distance, plus 3σ of the pose uncertainty accumulated since the last accepted loop (backend/loops.py DriftModel.radius)", unit="m")
    loop_max_candidates: int = param(8, lo=1, doc="search at most this many candidate submaps per node, nearest first")
    loop_min_separation: int = param(2, lo=1, doc="skip the node's own submap and this many before it")
    loop_search_every: int = param(2, lo=1, doc="search for loops at every n-th node")
    loop_linear_window: float = param(1.0, lo=0.0, doc="branch-and-bound half window in x and y", unit="m")
    loop_max_linear_window: float = param(3.0, lo=0.0, doc="the window grows with the drift since the last loop up to this (backend/loops.py DriftModel)", unit="m")
    loop_drift_per_m: float = param(0.01, lo=0.0, doc="drift of the estimate per metre travelled between loops, before accepted loops measure it", unit="m/m")
    degenerate_ratio: float = param(0.25, lo=0.0, hi=1.0, doc="a wide scan's loop match whose weakest translational information is below this × its strongest must beat its best distinct rival by loop_peak_ratio (a corridor slid along)")
    loop_angular_window_deg: float = param(20.0, lo=0.0, doc="branch-and-bound half window in yaw", unit="deg")
    loop_score: str = param("derived", choices=("derived", "fixed"), doc="the branch-and-bound score a loop must exceed: loop_min_inliers × the score a point on the map's wall is expected to get given both scans' measured range noise and the search's grid (backend/loops.py expected_match_score), or loop_min_score")
    loop_min_score: float = param(0.6, lo=0.0, hi=1.0, doc="branch-and-bound score a loop must exceed (coarse field) when loop_score = \"fixed\"")
    loop_min_inliers: float = param(0.6, lo=0.0, hi=1.0, doc="after refinement, share of points within 1σ of the submap")
    loop_resolution: float = param(0.05, lo=0.0, lo_open=True, doc="loop submap cell size", unit="m")
    loop_sigma: float = param(0.10, lo=0.0, lo_open=True, doc="loop submap field blur for the search", unit="m")
    loop_sigma_fine: float = param(0.03, lo=0.0, lo_open=True, doc="loop submap field blur for the refinement", unit="m")
    loop_sigma_xy: float = param(0.05, lo=0.0, lo_open=True, doc="loop factor σ", unit="m")
    loop_sigma_yaw_deg: float = param(1.0, lo=0.0, lo_open=True, doc="loop factor yaw σ", unit="deg")
    loop_search_range: float = param(15.0, lo=0.0, lo_open=True, doc="query points beyond this range are dropped", unit="m")
    loop_point_voxel: float = param(0.1, lo=0.0, doc="query points thinned to one per cell of this size", unit="m")
    loop_nearest_member: bool = param(True, doc="tie a loop to the submap node nearest the match (else to the first)")
    loop_query: str = param("auto", choices=("auto", "scan", "stack"), doc="loop query: the node's scan, the last loop_query_distance of scans stacked, or auto (stacked for narrow scans, < 144° of bearings)")
    loop_query_distance: float = param(3.0, lo=0.0, doc="stacked query: keyframes within this much travel (front-end poses)", unit="m")
    loop_map_neighbours: int = param(1, lo=0, doc="narrow scans: match against the candidate submap with this many submaps either side")
    loop_min_overlap: float = param(0.9, lo=0.0, hi=1.0, doc="narrow scans: skip a candidate unless this share of the query lies inside its map")
    loop_peak_ratio: float = param(0.99, lo=0.0, hi=1.0, doc="narrow scans: reject when the best distinct rival scores above this × the best (1 = off)")
    loop_peak_misfit: float = param(1.0, lo=1.0, doc="… or fits less than this many times worse than the best, 1 − score (1 = off)")
    loop_peak_exclusion: float = param(0.3, lo=0.0, lo_open=True, doc="a rival lies at least this far from the best", unit="m")
    loop_min_information_ratio: float = param(0.0, lo=0.0, hi=1.0, doc="reject when the match's weakest translational information is below this × the strongest")
    loop_field_cache: int = param(8, lo=1, doc="submap fields and search pyramids kept (LRU); the rest are rebuilt from points")
    robust_kernel: str = param("cauchy", choices=("cauchy", "gnc", "huber", "none"), doc="kernel on loop factors")
    robust_scale: float = param(1.0, lo=0.0, lo_open=True, doc="kernel scale, in σ units")
    optimize_every: int = param(25, lo=1, doc="ISAM2 update every n nodes")
    odom_scale: str = param("estimate", choices=("estimate", "fixed"), doc="wheel-odometry translation scale: a graph variable (final solve) or fixed at 1")
    odom_scale_sigma: float = param(0.05, lo=0.0, lo_open=True, doc="prior σ of the odometry scale around 1")
    gyro_bias_every: int = param(50, lo=0, doc="with a gyro, re-estimate its bias every n nodes while running (0: only in the final solve): an unmodelled bias drifts the running estimate the loop search starts from")
    calibrate_every: int = param(0, lo=0, doc="re-estimate the odometry scale and gyro bias every n nodes while running (0: only in the final solve); the front end's prediction and new factors use them")
    manhattan: bool = param(False, doc="heading priors from walls along the building's two perpendicular axes (backend/manhattan.py): a keyframe whose straight walls lie within manhattan_gate_deg of them is held at that heading; off by itself when the first walls do not share two axes")
    manhattan_sigma_deg: float = param(1.0, lo=0.0, lo_open=True, doc="σ of a heading prior (robust kernel)", unit="deg")
    manhattan_gate_deg: float = param(5.0, lo=0.0, lo_open=True, doc="walls farther than this off the axes make no prior", unit="deg")
    calibrate_rebase: bool = param(True, doc="each calibration while running also re-solves the graph with the new scale and bias and restarts ISAM2 from there (else only later factors use them)")
    imu: bool = param(True, doc="use the log's gyro (sensor_msgs/Imu yaw rate) when it has one")
    imu_frontend: bool = param(False, doc="the front end's motion prediction takes its yaw from the gyro (translation from the wheels); on for KOS (backend/kosprofile.py KOS_GRAPH), off for a laser (simulated office, 40 Hz laser: ATE 0.028 m off, 0.044 m on)")
    gyro_noise_density_deg: float = param(0.01, lo=0.0, lo_open=True, doc="gyro white noise density (consumer MEMS ≈ 0.005–0.015)", unit="deg/s/√Hz")
    gyro_bias: str = param("estimate", choices=("estimate", "fixed"), doc="gyro bias: a graph variable (final solve) or left in the noise")
    gyro_bias_sigma_deg_s: float = param(0.05, lo=0.0, lo_open=True, doc="prior σ of the gyro bias (turn-on bias of a consumer MEMS part)", unit="deg/s")
    gyro_bias_walk_deg_s: float = param(0.002, lo=0.0, doc="gyro bias random walk: the bias is a variable per "
                                        "gyro_bias_block_s, each the previous one ± this·√block (0: one constant bias)",
                                        unit="deg/s/√s")
    # Measured on the simulated office survey (23 min, laser, zero-skew scans, true bias walk 0.0003 °/s/√s): one
    # constant bias bent the map by ±1.2° (laser ATE 0.097 m; 0.019 m without the gyro); a walk of 0.0005 → 0.028 m,
    # 0.002 → 0.017 m (map F1 vs the blueprint 0.974). Looser than the part's own walk: the blocks also absorb what
    # the factors' σ leave out (timing, scale).
    gyro_bias_block_s: float = param(30.0, lo=0.0, lo_open=True, doc="time span of one gyro bias variable", unit="s")
    gyro_sigma_floor_deg: float = param(0.02, lo=0.0, lo_open=True, doc="σ floor of a gyro yaw increment (stamp misalignment)", unit="deg")
    gyro_max_gap_s: float = param(0.1, lo=0.0, lo_open=True, doc="no gyro factor across a gap between samples longer than this", unit="s")
    gyro_stuck_s: float = param(1.0, lo=0.0, lo_open=True, doc="identical gyro outputs for this long: a stuck part, its samples are dropped", unit="s")


@dataclass
class Edge:
    """One factor, kept for the g2o export and for inspection."""

    kind: str  # "match", "odom", "loop", "prior"
    a: int
    b: int
    measurement: np.ndarray  # (3,) pose of b in a's frame
    sigmas: np.ndarray  # (3,) x, y, yaw (square roots of the covariance's diagonal)
    score: float = float("nan")
    cov: np.ndarray | None = None  # (3, 3) full covariance when not diagonal
    dt: float = float("nan")  # gyro: the interval integrated (s)


SCALE_KEY = gtsam.symbol("s", 0)  # the odometry scale (Vector1); node keys are 0 … n−1
BIAS_KEY = gtsam.symbol("b", 0)  # the gyro bias (Vector1, rad/s); block k of a random-walk bias is symbol("b", k)


def bias_key(k: int) -> int:
    """Key of the gyro bias over block k (k = 0 is BIAS_KEY)."""
    return gtsam.symbol("b", k)


def _scale_error(meas: np.ndarray):
    """Wheel odometry a → b with a scale s: e = (s·t_ab − t_meas, wrap(θ_ab − θ_meas)); the wheels report s × the
    true translation (s − 1 is the wheel-radius error)."""

    def f(this, values, H):
        ka, kb, ks = this.keys()
        pa, pb = values.atPose2(ka), values.atPose2(kb)
        s = float(values.atVector(ks)[0])
        if H is None:
            rel = pa.between(pb)
        else:
            H1 = np.zeros((3, 3), order="F")
            H2 = np.zeros((3, 3), order="F")
            rel = pa.between(pb, H1, H2)
        th = rel.theta()
        e = np.array([s * rel.x() - meas[0], s * rel.y() - meas[1], math.remainder(th - meas[2], 2 * math.pi)])
        if H is not None:
            c, sn = math.cos(th), math.sin(th)
            # the translation of rel·Exp(δ) moves by R(θ_rel)·δ_xy (gtsam's right perturbations)
            D = np.array([[s * c, -s * sn, 0.0], [s * sn, s * c, 0.0], [0.0, 0.0, 1.0]])
            H[0] = D @ H1
            H[1] = D @ H2
            H[2] = np.array([[rel.x()], [rel.y()], [0.0]])
        return e

    return f


_D_THETA_A = np.array([[0.0, 0.0, -1.0]])  # ∂e/∂pose a of the gyro factor (constant; gtsam copies what it is given)
_D_THETA_B = np.array([[0.0, 0.0, 1.0]])


def _gyro_error(dyaw: float, dt: float):
    """Gyro a → b with a bias b: the rate integrates to Δθ + b·Δt, so e = wrap(θ_b − θ_a − (dyaw − b·Δt))."""
    d_bias = np.array([[dt]])
    keys: list = []  # this factor's keys, read once (a Python factor is evaluated ~80k times a 10-minute build)

    def f(this, values, H):
        if not keys:
            keys.extend(this.keys())
        ka, kb, kg = keys
        b = values.atVector(kg)[0]
        e = np.array([math.remainder(values.atPose2(kb).theta() - values.atPose2(ka).theta() - dyaw + b * dt, 2 * math.pi)])
        if H is not None:
            H[0] = _D_THETA_A
            H[1] = _D_THETA_B
            H[2] = d_bias
        return e

    return f


@dataclass
class PoseGraph:
    """A Pose2 graph solved incrementally with ISAM2 and finally in batch."""

    cfg: GraphConfig = field(default_factory=GraphConfig)

    def __post_init__(self) -> None:
        self.isam: gtsam.ISAM2 | None = _isam()
        self.pending = gtsam.NonlinearFactorGraph()
        self.pending_values = gtsam.Values()
        self.all_factors = gtsam.NonlinearFactorGraph()
        self.initial = gtsam.Values()
        self.edges: list[Edge] = []
        self._est = np.zeros((1024, 3))  # current estimate of every node, grown by doubling
        self._n = 0
        self.n_pending_nodes = 0
        self.factors: list = []  # the factor of each edge, in order
        self.odom_scale = 1.0  # estimated in the final solve (`odom_scale = "estimate"`)
        # the scale's prior (mean, σ): N(1, odom_scale_sigma), or the scale measured against the scan matcher where
        # it saw the motion on its own (backend/odomnoise.py; set by backend/slam.py)
        self.scale_prior: tuple[float, float] | None = None
        self.gyro_bias = 0.0  # rad/s, estimated in the final solve (`gyro_bias = "estimate"`): the latest block's
        self.gyro_biases = np.zeros(0)  # rad/s per bias block (gyro_bias_block_s) after a solve
        self._chain: dict[int, np.ndarray] = {}  # node i → information (3×3) of the factors between i − 1 and i
        self._chain_from = 1  # nodes below this have been checked (_chain_new_nodes) and are no longer tracked
        self.weak_nodes: list[int] = []  # nodes a weak motion prior chains to the one before (nothing else did)
        self.solver_notes: list[tuple[int | None, str]] = []  # (node or None, what failed and what solved instead)
        self.factorization = "CHOLESKY"  # ISAM2's; QR after an indeterminate system (see _recover)

    def __getstate__(self) -> dict:
        """Pickled (a SLAM run in another process, mapping/runtime/slamproc.py) without gtsam's ISAM2, which does not
        pickle: the copy keeps its factors, edges and estimate but cannot be extended."""
        state = dict(self.__dict__)
        state["isam"] = None
        return state

    # ---- building ---------------------------------------------------------------------------------------------------
    @property
    def n(self) -> int:
        return self._n

    @property
    def est(self) -> np.ndarray:
        """(n, 3) current estimate (a view: rows change in place as the graph is solved)."""
        return self._est[: self._n]

    def add_node(self, guess: np.ndarray) -> int:
        """A new node with an initial guess; the first one is anchored by a tight prior. Returns its id."""
        i = self._n
        if i == len(self._est):
            self._est = np.vstack((self._est, np.zeros_like(self._est)))
        self._est[i] = guess
        self._n += 1
        self.pending_values.insert(i, gtsam.Pose2(*map(float, guess)))
        self.initial.insert(i, gtsam.Pose2(*map(float, guess)))
        if i == 0:
            # with heading priors the building's axes fix the yaw, not the first node (optimize() turns the solution
            # back so that it starts where it was put): held tight, the first node and the axes taken from the first
            # walls would disagree by the error in those (simulated office: 0.3–0.7°)
            yaw_sigma = 1.0 if self.cfg.manhattan else 1e-5
            self._add("prior", 0, 0, np.asarray(guess, dtype=float), np.array([1e-4, 1e-4, yaw_sigma]), robust=False)
        self.n_pending_nodes += 1
        return i

    def _noise(self, sigmas: np.ndarray, robust: bool):
        return self._robust(gtsam.noiseModel.Diagonal.Sigmas(np.asarray(sigmas, dtype=float)), robust)

    def _robust(self, base, robust: bool):
        """`base` under the loop kernel (Cauchy or Huber) when `robust`; GNC and none leave it as it is."""
        if not robust or self.cfg.robust_kernel in ("none", "gnc"):
            return base
        k = self.cfg.robust_scale
        est = (gtsam.noiseModel.mEstimator.Cauchy.Create(k) if self.cfg.robust_kernel == "cauchy"
               else gtsam.noiseModel.mEstimator.Huber.Create(k))
        return gtsam.noiseModel.Robust.Create(est, base)

    def _add(self, kind: str, a: int, b: int, meas: np.ndarray, sigmas: np.ndarray, robust: bool, score: float = float("nan"),
             cov: np.ndarray | None = None, dt: float = float("nan"), online: np.ndarray | None = None):
        if cov is not None:
            cov = _finite_covariance(cov)
        model = self._noise(sigmas, robust) if cov is None else self._robust(gtsam.noiseModel.Gaussian.Covariance(cov), robust)
        if cov is not None:
            sigmas = np.sqrt(np.diag(cov))
        if kind in CHAIN_KINDS and b == a + 1 and b >= self._chain_from:
            info = np.linalg.inv(cov) if cov is not None else np.diag(1.0 / np.asarray(sigmas, dtype=float) ** 2)
            self._chain[b] = self._chain.get(b, 0.0) + info
        fm = meas if online is None else online  # the factor's measurement (calibrated); the edge keeps the raw one
        f = _factor(kind, a, b, fm, model)
        self.pending.add(f)
        self.all_factors.add(f)
        self.factors.append(f)
        self.edges.append(Edge(kind, a, b, np.asarray(meas, dtype=float), np.asarray(sigmas, dtype=float), score, cov, dt))

    def match_sigmas(self, rel: np.ndarray) -> np.ndarray:
        """The fixed part of a scan-matching factor's σ (x, y, yaw) for a relative pose."""
        c = self.cfg
        sxy = c.match_sigma_xy + c.match_sigma_xy_per_m * math.hypot(rel[0], rel[1])
        return np.array([sxy, sxy, math.radians(c.match_sigma_yaw_deg)])

    def add_match(self, a: int, b: int, rel: np.ndarray, sigmas: np.ndarray | None = None, cov: np.ndarray | None = None) -> None:
        """The front end's relative pose a → b (consecutive nodes): fixed σ, or a full covariance `cov`."""
        self._add("match", a, b, rel, self.match_sigmas(rel) if sigmas is None else sigmas, robust=False, cov=cov)

    def odometry_sigmas(self, rel: np.ndarray) -> np.ndarray:
        """The configured wheel-odometry factor σ (x, y, yaw) for an increment: growing with distance and rotation."""
        c = self.cfg
        d = math.hypot(rel[0], rel[1])
        sxy = c.odom_sigma_xy + c.odom_sigma_xy_per_m * d
        syaw = math.radians(c.odom_sigma_yaw_deg) + c.odom_sigma_yaw_per_rad * abs(rel[2])
        return np.array([sxy, sxy, syaw])

    def add_odometry(self, a: int, b: int, rel: np.ndarray, sigmas: np.ndarray | None = None) -> None:
        """The wheel-odometry increment a → b: σ as configured (odometry_sigmas), or `sigmas` (the odometry's noise
        measured while running, backend/odomnoise.py)."""
        sig = self.odometry_sigmas(rel) if sigmas is None else np.asarray(sigmas, dtype=float)
        self._add("odom", a, b, rel, sig, robust=False, online=self._calibrated("odom", rel))

    def gyro_sigma(self, dt: float, bias_estimated: bool) -> float:
        """σ of a gyro yaw increment over dt: N²·Δt + (σ_b·Δt)² (when the bias is not a variable) + floor²."""
        from kosmap.backend.imu import yaw_sigma

        c = self.cfg
        return yaw_sigma(dt, math.radians(c.gyro_noise_density_deg), 0.0 if bias_estimated else math.radians(c.gyro_bias_sigma_deg_s),
                         math.radians(c.gyro_sigma_floor_deg))

    def add_gyro(self, a: int, b: int, dyaw: float, dt: float, rel_xy: np.ndarray | None = None) -> None:
        """The gyro's integrated yaw a → b (bias not removed): a yaw-only constraint. Online (ISAM2) a Pose2
        between factor with x/y σ of a kilometre and the bias in its σ; in the final solve a factor on the bias."""
        xy = np.zeros(2) if rel_xy is None else np.asarray(rel_xy, dtype=float)[:2]
        meas = np.array([xy[0], xy[1], dyaw])
        self._add("gyro", a, b, meas, np.array([1e3, 1e3, self.gyro_sigma(dt, False)]), robust=False, dt=dt,
                  online=self._calibrated("gyro", meas, dt))

    def _calibrated(self, kind: str, meas: np.ndarray, dt: float = float("nan"), bias: float | None = None):
        """What an odometry or gyro factor measures under the current calibration: the wheels' translation over the
        odometry scale, the gyro's yaw less bias·dt (`bias`: its block's; default the latest); None for other kinds."""
        if kind == "odom":
            return np.array([meas[0] / self.odom_scale, meas[1] / self.odom_scale, meas[2]])
        if kind == "gyro":
            return np.array([meas[0], meas[1], meas[2] - (self.gyro_bias if bias is None else bias) * dt])
        return None

    def add_heading(self, a: int, yaw: float) -> None:
        """A heading prior on node a (backend/manhattan.py): yaw only (x, y σ of a kilometre), under the robust kernel."""
        x, y = self.est[a, :2]
        self._add("heading", a, a, np.array([x, y, yaw]), np.array([1e3, 1e3, math.radians(self.cfg.manhattan_sigma_deg)]),
                  robust=True)

    def add_loop(self, a: int, b: int, rel: np.ndarray, score: float = float("nan"), sigmas: np.ndarray | None = None,
                 cov: np.ndarray | None = None) -> None:
        """A loop constraint: pose of b in a's frame, under the robust kernel; `cov` (in b's frame) instead of the
        fixed σ for a match that fixes one direction less (backend/loops.py: a corridor)."""
        if sigmas is None:
            sigmas = np.array([self.cfg.loop_sigma_xy, self.cfg.loop_sigma_xy, math.radians(self.cfg.loop_sigma_yaw_deg)])
        self._add("loop", a, b, rel, sigmas, robust=True, score=score, cov=cov)

    # ---- solving ----------------------------------------------------------------------------------------------------
    def update(self, full: bool = False) -> None:
        """Push pending factors into ISAM2; refresh the estimate of every node when `full` (after a loop). Every new
        node is chained to the one before first (`_chain_new_nodes`); an indeterminate system restarts the solver
        (`_restart`) instead of ending the run."""
        if self.pending.size() == 0 and self.pending_values.size() == 0:
            return
        self._chain_new_nodes()
        new, self.n_pending_nodes = self.n_pending_nodes, 0
        try:
            if self.isam is None:
                raise RuntimeError("no incremental solver")
            self.isam.update(self.pending, self.pending_values)
        except RuntimeError as e:
            if self.isam is not None:
                self.solver_notes.append((_node_of(e), f"ISAM2: {_first_line(e)}"))
            self.pending = gtsam.NonlinearFactorGraph()
            self.pending_values = gtsam.Values()
            if self.isam is not None or full:  # (batch mode: a batch solve only after loops, else the guesses stand)
                self._restart(self._values(), after_failure=self.isam is not None)
            return
        self.pending = gtsam.NonlinearFactorGraph()
        self.pending_values = gtsam.Values()
        if full:  # after loops every node may move
            self._read(self.isam.calculateEstimate())
        else:  # without loops only the new nodes move noticeably
            for i in range(self.n - new, self.n):
                self.est[i] = _xyth(self.isam.calculateEstimatePose2(i))

    def _chain_new_nodes(self) -> None:
        """A weak motion prior (the front end's motion between the guesses, σ WEAK_SIGMAS) between each pending node
        and the one before when the factors between them (match, odometry, gyro) leave a direction unconstrained
        or are not finite: no keyframe is left floating (a node held by a yaw-only gyro factor alone makes ISAM2's
        Cholesky factorisation fail: 'Indeterminate linear system')."""
        for i in range(max(self.n - self.n_pending_nodes, 1), self.n):
            info = self._chain.pop(i, None)
            if info is not None and _strong(info):
                continue
            rel = self.initial.atPose2(i - 1).between(self.initial.atPose2(i))
            self._add("motion", i - 1, i, _xyth(rel), WEAK_SIGMAS, robust=False)
            self._chain.pop(i, None)
            self.weak_nodes.append(i)
        self._chain_from = self.n

    def _values(self) -> gtsam.Values:
        vals = gtsam.Values()
        for i in range(self.n):
            vals.insert(i, gtsam.Pose2(*map(float, self.est[i])))
        return vals

    def _restart(self, values, after_failure: bool = False) -> None:
        """ISAM2 anew over every factor from `values`: with the current factorisation, else QR (which does not
        square the system's condition number as Cholesky does), else no incremental solver at all: a batch
        Levenberg–Marquardt solve now and after each later loop, the front end's guesses in between. `after_failure`:
        the current factorisation has just failed, start with the next."""
        order = ("CHOLESKY", "QR")
        first = order.index(self.factorization) + after_failure if self.factorization in order else len(order)
        for fac in order[first:]:
            isam = _isam(fac)
            try:
                isam.update(self.all_factors, values)
            except RuntimeError as e:
                self.solver_notes.append((_node_of(e), f"ISAM2 ({fac.lower()}): {_first_line(e)}"))
                continue
            if fac != self.factorization:
                self.solver_notes.append((None, f"re-solved with ISAM2's {fac} factorisation"))
            self.isam, self.factorization = isam, fac
            self._read(isam.calculateEstimate())
            return
        if self.factorization != "LM":
            self.solver_notes.append((None, "solved in batch (Levenberg–Marquardt) from there on"))
        self.isam, self.factorization = None, "LM"
        self._read(_levenberg_marquardt(self.all_factors, values))

    def _read(self, values) -> None:
        arr = gtsam.utilities.extractPose2(values)  # rows in key order: keys are 0 … n−1 (Vector keys ignored)
        self.est[: len(arr)] = arr

    def optimize(self, max_iterations: int = 100) -> dict:
        """Batch solve of every factor from the current estimate: LM, or GNC (truncated least squares on loops)."""
        self.update()
        vals = self._values()
        # 1. every factor as added (scale 1, bias in the gyro σ): gtsam's own optimizer, in C++
        before = self.all_factors.error(vals)
        known = [i for i, e in enumerate(self.edges) if e.kind != "loop"]
        outliers: set[int] = set()
        result = None
        if self.cfg.robust_kernel == "gnc":
            params = gtsam.GncLMParams()
            params.setKnownInliers(known)
            try:
                gnc = gtsam.GncLMOptimizer(self.all_factors, vals, params)
                result = gnc.optimize()
                outliers = {i for i, w in enumerate(np.asarray(gnc.getWeights())) if w < 0.5}  # loops GNC rejected
            except RuntimeError as e:
                self.solver_notes.append((_node_of(e), f"GNC: {_first_line(e)}; solved with Levenberg–Marquardt"))
        if result is None:
            result = _levenberg_marquardt(self.all_factors, vals, max_iterations, self.solver_notes)
        graph = self.all_factors
        # 2. with the odometry scale and the gyro bias as variables (Python CustomFactors): damped Gauss–Newton from
        # there. gtsam's optimizers call Python factors ~15× slower than linearize() + optimize() do (measured:
        # 5.7 s vs 0.35 s per iteration on 1664 nodes), so the loop is ours.
        full, _ = self._batch_graph(result, outliers)
        if full is not self.all_factors:
            try:
                result = _gauss_newton(full, result, max_iterations=20)
                graph = full
            except RuntimeError as e:  # the solution without the scale and bias variables stands
                self.solver_notes.append((_node_of(e), f"odometry scale and gyro bias not estimated: {_first_line(e)}"))
        self._read(result)
        if result.exists(SCALE_KEY):
            self.odom_scale = float(result.atVector(SCALE_KEY)[0])
        self._read_biases(result)
        if self.cfg.manhattan and self.n:
            self._regauge()
        return {"error_before": float(before), "error_after": float(graph.error(result))}

    def _regauge(self) -> None:
        """Move the whole solution rigidly so that the first node is where it was put (its prior's pose): the same
        relative poses, in the frame the run started in."""
        start = next(np.asarray(e.measurement, dtype=float) for e in self.edges if e.kind == "prior" and e.a == 0)
        rel = se2.between(np.repeat(self.est[:1], self.n, 0), self.est)
        self.est[:] = se2.compose(np.repeat(start[None], self.n, 0), rel)

    def calibrate(self, max_iterations: int = 5, scale: bool = True, rebase: bool = False) -> None:
        """Re-estimate the odometry scale and the gyro bias from every factor so far (Gauss–Newton from the
        current estimate); later factors and the front end's prediction use them. With `rebase` the running estimate
        becomes that solution too (else it stays as it is)."""
        self.update()
        vals = self._values()
        full, _ = self._batch_graph(vals, use_scale=scale)
        if full is self.all_factors:
            return
        try:
            res = _gauss_newton(full, vals, max_iterations=max_iterations)
        except RuntimeError as e:  # this calibration is skipped; the final solve tries again
            self.solver_notes.append((_node_of(e), f"calibration while running skipped: {_first_line(e)}"))
            return
        if res.exists(SCALE_KEY):
            self.odom_scale = float(res.atVector(SCALE_KEY)[0])
        self._read_biases(res)
        if rebase:
            self._rebase(res)

    def _rebase(self, values) -> None:
        """Restart ISAM2 from a batch solution: every odometry and gyro factor re-made with the scale and the bias
        (of its block) just estimated, the estimate set to the solution. Without it the running estimate keeps the
        yaw the uncalibrated gyro factors put in before (simulated survey, KOS: 16° between the first node and the
        2150th online, 1.3° after the final solve) and the loop search starts from there."""
        blocks = self._bias_blocks()
        biases = self.gyro_biases
        fs = gtsam.NonlinearFactorGraph()
        for i, e in enumerate(self.edges):
            online = self._calibrated(e.kind, e.measurement, e.dt,
                                      biases[blocks[i]] if 0 <= blocks[i] < len(biases) else None)
            if online is not None:
                self.factors[i] = _factor(e.kind, e.a, e.b, online, self.factors[i].noiseModel())
            fs.add(self.factors[i])
        self.all_factors = fs
        poses = gtsam.Values()
        for i in range(self.n):
            poses.insert(i, values.atPose2(i))
        self._restart(poses)

    def _read_biases(self, values) -> None:
        """The gyro bias blocks of a solution; the latest one is what new factors and the front end use."""
        ks = []
        while values.exists(bias_key(len(ks))):
            ks.append(float(values.atVector(bias_key(len(ks)))[0]))
        if ks:
            self.gyro_biases = np.array(ks)
            self.gyro_bias = ks[-1]

    @property
    def gyro_bias_mean(self) -> float:
        """The gyro bias averaged over the run's blocks (rad/s): one number to report."""
        return float(self.gyro_biases.mean()) if len(self.gyro_biases) else self.gyro_bias

    def _bias_blocks(self) -> list[int]:
        """The bias block of each edge (gyro edges by the time integrated before them; other edges −1): the bias
        is a random walk, one variable per gyro_bias_block_s (one block when gyro_bias_walk_deg_s is 0)."""
        c = self.cfg
        out, t = [], 0.0
        for e in self.edges:
            if e.kind != "gyro":
                out.append(-1)
                continue
            out.append(int(t // c.gyro_bias_block_s) if c.gyro_bias_walk_deg_s > 0 else 0)
            t += e.dt
        return out

    def _batch_graph(self, vals, outliers: set[int] = frozenset(), use_scale: bool = True) -> tuple:
        """Every factor for the final solve: odometry factors with the scale variable and gyro factors with the bias
        variable (gtsam CustomFactor) when those are estimated; their priors; and the non-loop factor indices."""
        c = self.cfg
        scale = use_scale and c.odom_scale == "estimate" and any(e.kind == "odom" for e in self.edges)
        bias = c.gyro_bias == "estimate" and any(e.kind == "gyro" for e in self.edges)
        known = [i for i, e in enumerate(self.edges) if e.kind != "loop"]
        if not (scale or bias):
            return self.all_factors, known
        g = gtsam.NonlinearFactorGraph()
        blocks = self._bias_blocks() if bias else []
        for i, (e, f) in enumerate(zip(self.edges, self.factors)):
            if i in outliers:
                continue
            if scale and e.kind == "odom":
                g.add(gtsam.CustomFactor(gtsam.noiseModel.Diagonal.Sigmas(e.sigmas), [e.a, e.b, SCALE_KEY],
                                         _scale_error(e.measurement)))
            elif bias and e.kind == "gyro":
                g.add(gtsam.CustomFactor(gtsam.noiseModel.Isotropic.Sigma(1, self.gyro_sigma(e.dt, True)),
                                         [e.a, e.b, bias_key(blocks[i])], _gyro_error(float(e.measurement[2]), e.dt)))
            else:
                g.add(f)
        if scale:
            known.append(int(g.size()))
            mean, sigma = self.scale_prior or (1.0, c.odom_scale_sigma)
            g.add(gtsam.PriorFactorVector(SCALE_KEY, np.array([mean]), gtsam.noiseModel.Isotropic.Sigma(1, sigma)))
            vals.insert(SCALE_KEY, np.array([self.odom_scale]))
        if bias:
            known.append(int(g.size()))
            g.add(gtsam.PriorFactorVector(BIAS_KEY, np.array([0.0]),
                                          gtsam.noiseModel.Isotropic.Sigma(1, math.radians(c.gyro_bias_sigma_deg_s))))
            # the bias's random walk (bias instability): block k+1 = block k ± walk·√block, as the between-bias
            # factors of IMU preintegration (Forster et al., "On-Manifold Preintegration", T-RO 2017, eq. 40)
            walk = gtsam.noiseModel.Isotropic.Sigma(1, math.radians(c.gyro_bias_walk_deg_s) * math.sqrt(c.gyro_bias_block_s))
            n_blocks = max(blocks) + 1
            for k in range(n_blocks):
                b0 = self.gyro_biases[k] if k < len(self.gyro_biases) else self.gyro_bias
                vals.insert(bias_key(k), np.array([b0]))
                if k:
                    known.append(int(g.size()))
                    g.add(gtsam.BetweenFactorVector(bias_key(k - 1), bias_key(k), np.array([0.0]), walk))
        return g, known

    def loop_residuals(self) -> list[tuple[Edge, float, float]]:
        """(loop edge, translation m, yaw rad) disagreement with the current estimate, per loop."""
        out = []
        for e in self.edges:
            if e.kind == "loop":
                err = se2.between(e.measurement, se2.between(self.est[e.a], self.est[e.b]))
                out.append((e, math.hypot(err[0], err[1]), abs(float(err[2]))))
        return out

    # ---- export -----------------------------------------------------------------------------------------------------
    def write_g2o(self, path: str | Path) -> Path:
        """VERTEX_SE2 / EDGE_SE2 text (g2o's format; information = upper triangle of Σ⁻¹)."""
        from kosmap.backend.trajio import write_g2o

        return write_g2o(path, self.est, [(e.a, e.b, e.measurement, e.sigmas if e.cov is None else e.cov, e.kind)
                                          for e in self.edges if e.kind not in ("prior", "heading")])


def _gauss_newton(graph, values, max_iterations: int = 20, rtol: float = 1e-6):
    """Gauss–Newton with step halving (a step that raises the error is halved, up to 5 times; then stop)."""
    err = graph.error(values)
    for _ in range(max_iterations):
        delta = graph.linearize(values).optimize()
        step, new, new_err = 1.0, None, float("inf")
        for _ in range(6):
            d = delta if step == 1.0 else delta.scale(step)
            new = values.retract(d)
            new_err = graph.error(new)
            if new_err <= err:
                break
            step *= 0.5
        if new_err > err:
            break
        done = err - new_err <= rtol * max(err, 1e-12)
        values, err = new, new_err
        if done:
            break
    return values


def _factor(kind: str, a: int, b: int, meas, model):
    """The gtsam factor of an edge: a prior on node a (prior, heading) or a between factor a → b."""
    if kind in ("prior", "heading"):
        return gtsam.PriorFactorPose2(a, gtsam.Pose2(*map(float, meas)), model)
    return gtsam.BetweenFactorPose2(a, b, gtsam.Pose2(*map(float, meas)), model)


def _isam(factorization: str = "CHOLESKY") -> gtsam.ISAM2:
    p = gtsam.ISAM2Params()
    p.setFactorization(factorization)
    p.setRelinearizeThreshold(0.01)
    p.relinearizeSkip = 1
    return gtsam.ISAM2(p)


def _xyth(p) -> np.ndarray:
    return np.array([p.x(), p.y(), p.theta()])


CHAIN_KINDS = ("match", "odom", "gyro", "motion")  # factors between consecutive nodes that chain them
# The weak motion prior's σ (x, y, yaw): as loose as the loosest match factor alone may be (mapping/slam.py's
# MAX_MATCH_VAR, 1 m / 1 rad), so a node it chains follows the front end's motion unless loops pull it elsewhere.
WEAK_SIGMAS = np.array([1.0, 1.0, 1.0])
CHAIN_MIN_INFO = 0.5  # a chain whose information is below this (m⁻², rad⁻²) in some direction gets the prior
MAX_VAR = 1e2  # m², rad²: a covariance is clipped to this (a non-finite or negative variance becomes it)
MIN_VAR = 1e-8  # m², rad²: … and to at least this (σ 0.1 mm, 0.006°: no scan match is surer)


def _strong(info: np.ndarray) -> bool:
    """The information between two nodes constrains every direction (x, y, yaw) at least CHAIN_MIN_INFO."""
    if not np.all(np.isfinite(info)):
        return False
    return float(np.linalg.eigvalsh(0.5 * (info + info.T))[0]) >= CHAIN_MIN_INFO


def _finite_covariance(cov) -> np.ndarray:
    """A symmetric positive-definite covariance a factor can use: a direction with a non-finite, zero or negative
    variance carries no information (MAX_VAR; an indefinite matrix from a bad inverse is garbage there, not
    certainty), the others are kept within [MIN_VAR, MAX_VAR]. A NaN makes the whole linear system indeterminate;
    a variance of 1e-12 beside ordinary ones makes it too ill-conditioned for ISAM2's Cholesky factorisation."""
    c = np.asarray(cov, dtype=float)
    if np.all(np.isfinite(c)):
        w, v = np.linalg.eigh(0.5 * (c + c.T))
        if w[0] >= MIN_VAR and w[-1] <= MAX_VAR:
            return c
    else:
        c = np.where(np.isfinite(c), c, 0.0) + np.diag(np.where(np.isfinite(np.diag(c)), 0.0, MAX_VAR))
        w, v = np.linalg.eigh(0.5 * (c + c.T))
    w = np.where(w > 0, np.clip(w, MIN_VAR, MAX_VAR), MAX_VAR)
    return (v * w) @ v.T


def _levenberg_marquardt(graph, values, max_iterations: int = 100, notes: list | None = None):
    """gtsam's batch Levenberg–Marquardt from `values` (its damping solves what a plain factorisation finds
    indeterminate); `values` unchanged if even it fails."""
    params = gtsam.LevenbergMarquardtParams()
    params.setMaxIterations(max_iterations)
    try:
        return gtsam.LevenbergMarquardtOptimizer(graph, values, params).optimize()
    except RuntimeError as e:
        if notes is not None:
            notes.append((_node_of(e), f"batch solve failed ({_first_line(e)}): the front end's poses stand"))
        return values


def _node_of(err: Exception) -> int | None:
    """The node gtsam names in an indeterminate-system message ('… near variable 5234 …'), if any."""
    import re

    m = re.search(r"near variable\s+(\d+)", str(err))
    return int(m.group(1)) if m else None


def _first_line(err: Exception) -> str:
    """The gist of a gtsam error: its first sentence, on one line."""
    text = " ".join(str(err).split())
    return (text.split(". ")[0].rstrip(".") if text else type(err).__name__)
