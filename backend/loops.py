"""Loop closure: submaps of keyframes, candidates near the current estimate but far back in the sequence,
verified by an exact branch-and-bound search, refined by Gauss–Newton, accepted by a fitness test and by
look-alike tests.

Every `submap_nodes` keyframes form a submap: their scans, placed at the nodes' current estimates relative to
the first node (the anchor). A submap keeps only these points (float32); its likelihood fields and search
pyramid are rebuilt from them when a search needs them and kept in a small LRU cache (`loop_field_cache`), so
memory stays flat however long the log (the fields are a pure function of the points: same results).
When a new node's estimate lies within `loop_search_radius` of a node an older submap was built at, widened by 3σ
of the pose uncertainty the graph's own factors accumulated since the last accepted loop (DriftModel.radius), a
query is searched over a window of ±`loop_linear_window` and ±`loop_angular_window_deg` around that estimate (Hess et al. 2016,
§V: branch and bound on precomputed max grids, exact, so a poor guess inside the window is no problem),
refined on a sharper field, and accepted when the search score and the share of points within 1σ of the
submap both pass, and the match is not a look-alike (backend/ambiguity.py): no distinct second peak nearly as
good (`loop_peak_ratio`), information in every translational direction (`loop_min_information_ratio`).
The query is the node's scan, or for a narrow scan (`loop_query`) the scans of the last
`loop_query_distance` metres of travel stacked in the node's frame by the front end's poses (accurate over
a few metres): a 70° scan of a corridor wall fits many places, a few metres of corridor with its doors fewer.
The constraint is the node's pose in a submap member's frame (a gtsam BetweenFactorPose2 under a robust kernel).
"""

from __future__ import annotations

import math
import time
from collections import OrderedDict, deque
from dataclasses import dataclass, field

import numpy as np

from kosmap.backend.ambiguity import search_two_peaks, translation_information
from kosmap.backend.consistency import scan_noise
from kosmap.backend.graph import GraphConfig, PoseGraph
from kosmap.backend.keyframes import Keyframe
from kosmap.frontend import se2
from kosmap.frontend.likelihood import LikelihoodField
from kosmap.frontend.matcher import SearchGrids, gauss_newton, inlier_fraction
from kosmap.frontend.odometry import scan_geometry, voxel_filter

LOOSE_SIGMA = 10.0  # m: a degenerate wide loop match's σ along the direction its scan does not fix
NARROW_COVERAGE = 0.4  # a scan whose returns cover less than this share of 10° bearing sectors (144°) is narrow

# Measured on the simulated office (361 s, one front camera, KOS scans replayed, no IMU, 10 Hz depth; loop precision
# against ground truth at 0.1 m / 2°), single-scan search → these defaults: seed 0 ATE 0.149 → 0.107 m, loops 21
# (38 % right) → 6 (100 %); seed 1 0.299 → 0.084 m, 18 (39 %) → 7 (100 %). The rival test decides most of it (the
# wrong loops slid along a corridor: rival ≥ 0.998 × best, right ones ≤ 0.995 ×); the information ratio did not
# separate right from wrong there (0.11–0.21 vs 0.10–0.17), so it is off. Laser logs take none of this (wide scans):
# Intel, FR079, CSAIL give the same loops and relations error to the last digit.


def expected_match_score(noise_query: float, sigma: float, resolution: float) -> float:
    """The branch-and-bound score a query point that does lie on the map's wall is expected to get: the field is
    exp(−d²/2σ²) of the distance d to the nearest map point, and d scatters by the query's range noise and by the
    point's rounding to a cell (res²/12); for d ~ N(0, v), E[exp(−d²/2σ²)] = σ/√(σ² + v). The map's own noise hardly
    counts (the nearest of many scans' noisy points lies about as near as the wall), nor does the pose's rounding (the
    best grid pose is taken). Measured on a simulated corridor (270°): 0.987, 0.978, 0.942 for σ 0.5, 2, 4 cm against 0.989, 0.983,
    0.974 predicted from the scan's own measured scatter (tests/backend/test_loop_score.py)."""
    n_q = noise_query if math.isfinite(noise_query) else 0.0
    return float(sigma / math.sqrt(sigma ** 2 + n_q ** 2 + resolution ** 2 / 12.0))


@dataclass
class SubmapFields:
    """What a search needs of a submap, rebuilt from its points: the search and refinement fields, the pyramid."""

    coarse: LikelihoodField
    fine: LikelihoodField
    grids: SearchGrids
    lo: np.ndarray = field(default_factory=lambda: np.zeros(2))  # bounding box of the points (anchor frame)
    hi: np.ndarray = field(default_factory=lambda: np.zeros(2))

    def inside(self, pts: np.ndarray, pose: np.ndarray) -> float:
        """Share of the points (scan frame) placed at `pose` that lie within the map's bounding box."""
        q = se2.transform_points(pose, pts)
        return float(np.mean(np.all((q >= self.lo) & (q <= self.hi), axis=1))) if len(q) else 0.0

    @property
    def nbytes(self) -> int:
        return int(self.coarse.values.nbytes + self.fine.values.nbytes + self.grids.nbytes)


@dataclass
class LoopSubmap:
    """A finished submap in its anchor node's frame: the member scans' points, placed (float32)."""

    index: int
    node_ids: list[int]
    points: np.ndarray  # (N, 2) float32, anchor frame
    centre: np.ndarray  # (2,) mean node position, anchor frame
    member_poses: np.ndarray  # (n, 3) the member nodes' poses in the anchor frame when the submap was built

    @property
    def anchor(self) -> int:
        return self.node_ids[0]

    @property
    def nbytes(self) -> int:
        return int(self.points.nbytes + self.member_poses.nbytes + self.centre.nbytes)


@dataclass
class LoopConstraint:
    """An accepted loop: pose of node `b` in the frame of node `a` (a submap member)."""

    a: int
    b: int
    rel: np.ndarray
    score: float
    inliers: float
    submap: int
    second: float = 0.0  # best distinct rival's score (0: none above loop_peak_ratio · score)
    info_ratio: float = float("nan")  # smallest / largest translational information of the match
    cov: np.ndarray | None = None  # (3, 3) in b's frame for a degenerate wide match (loose along the weak direction)


@dataclass
class LoopStats:
    searches: int = 0
    accepted: int = 0
    rejected_score: int = 0
    rejected_inliers: int = 0
    rejected_ambiguous: int = 0  # a distinct second peak nearly as good (ratio test)
    rejected_degenerate: int = 0  # a direction the match does not fix
    rejected_edge: int = 0  # the best pose lay on the search window's edge (the true peak may lie outside)
    stacked_queries: int = 0
    widened: int = 0  # searches whose window the drift since the last loop widened beyond loop_linear_window
    widest_window: float = 0.0  # the widest linear half window searched (m)
    widest_radius: float = 0.0  # the widest candidate radius round a submap's centre (m)
    drift_per_m: float = 0.0  # the drift rate the last accepted loops measured (m of correction per m travelled)
    skipped_outside: int = 0  # candidates skipped: the narrow query reaches past the candidate map (loop_min_overlap)
    min_score_lo: float = float("nan")  # the lowest and highest score a loop had to reach (loop_score = "derived")
    min_score_hi: float = float("nan")
    seconds: float = 0.0
    grid_bytes: int = 0  # pyramids built over the run (cumulative)
    field_builds: int = 0  # submap fields (re)built from points
    cache_bytes_peak: int = 0  # largest total of the cached fields and pyramids at any time
    points_bytes: int = 0  # the submaps' kept points


def bearing_coverage(points: np.ndarray) -> float:
    """Share of the 36 10° bearing sectors around the sensor that hold at least one return."""
    if len(points) == 0:
        return 0.0
    b = np.floor((np.arctan2(points[:, 1], points[:, 0]) + math.pi) / (2 * math.pi) * 36).astype(np.int64)
    return float(len(np.unique(np.clip(b, 0, 35)))) / 36.0


def propagate(cov: np.ndarray, rel: np.ndarray, sigmas: np.ndarray) -> np.ndarray:
    """A pose's covariance (its own frame, x y yaw) carried one step `rel` further along a chain whose step has
    independent noise `sigmas`: Ad(rel⁻¹)·Σ·Ad(rel⁻¹)ᵀ + diag(σ²), Ad the SE(2) adjoint (a yaw error at the old
    pose becomes a sideways error at the new one, growing with the distance)."""
    c, s = math.cos(rel[2]), math.sin(rel[2])
    x, y = float(rel[0]), float(rel[1])
    # inverse of rel: R' = Rᵀ, t' = −Rᵀt; Ad(R', t') = [[R', (t'_y, −t'_x)ᵀ], [0, 1]]
    tx, ty = -(c * x + s * y), -(-s * x + c * y)
    A = np.array([[c, s, ty], [-s, c, -tx], [0.0, 0.0, 1.0]])
    return A @ cov @ A.T + np.diag(np.asarray(sigmas, dtype=float) ** 2)


class DriftModel:
    """How far the current estimate may have drifted since the last accepted loop, so the search looks there.

    Between loops nothing but the front end (and the wheels) places the robot, and its error grows with the
    travel: σ = rate · travel. `rate` starts at `loop_drift_per_m` and follows what accepted loops measure (the
    distance from the estimate to where the match put the node, over the travel since the previous loop:
    Olson 2009's "how far could we be" argument for the loop search's window), and is never below the drift the
    wheel odometry puts in where the front end leans on it (`odometry_rate`: the share of matches held to the
    odometry × its measured scale error, backend/odomnoise.py). The search's half window is 3σ,
    never below `loop_linear_window` nor above `loop_max_linear_window`. The candidates' radius grows with the
    pose's covariance carried along the chain of node steps since the last loop (`propagate`, the graph's match factor
    σ per step): a yaw error far back is a sideways error here, so 45 m of corridor give 4 m + 3 × 1.9 m."""

    def __init__(self, cfg: GraphConfig) -> None:
        self.cfg = cfg
        self.rate = float(cfg.loop_drift_per_m)
        self.travel = 0.0  # metres of front-end travel since the last accepted loop
        self._worst = 0.0  # largest correction among this search's accepted loops
        self.odometry_rate = 0.0  # drift per metre the odometry puts in where the front end leans on it (set by Slam)
        self._pose: np.ndarray | None = None  # front-end pose of the last node
        self.cov = self._loop_cov()  # the current node's pose uncertainty since the last accepted loop (its frame)

    def travel_to(self, pose: np.ndarray) -> None:
        if self._pose is not None:
            self.travel += math.hypot(pose[0] - self._pose[0], pose[1] - self._pose[1])
            rel = se2.between(self._pose, pose)
            self.cov = propagate(self.cov, rel, self._step_sigmas(rel))
        self._pose = np.asarray(pose, dtype=float).copy()

    def _step_sigmas(self, rel: np.ndarray) -> np.ndarray:
        """σ (x, y, yaw) the graph gives a node step's scan-matching factor (its fixed part: the least it claims)."""
        c = self.cfg
        sxy = c.match_sigma_xy + c.match_sigma_xy_per_m * math.hypot(rel[0], rel[1])
        return np.array([sxy, sxy, math.radians(c.match_sigma_yaw_deg)])

    def _loop_cov(self) -> np.ndarray:
        c = self.cfg
        return np.diag([c.loop_sigma_xy ** 2, c.loop_sigma_xy ** 2, math.radians(c.loop_sigma_yaw_deg) ** 2])

    def position_sigma(self) -> float:
        """σ of the current node's position along its worst direction, accumulated since the last accepted loop."""
        return float(math.sqrt(max(np.linalg.eigvalsh(self.cov[:2, :2])[-1], 0.0)))

    def radius(self) -> float:
        """How far from a submap's centre a node may lie and still be searched against it: the submap's own reach
        (`loop_search_radius`) plus 3σ of the position uncertainty the graph's own factors accumulated since the last
        accepted loop (Olson 2009: search where the robot could be), at least the window's growth, at most
        `loop_search_range` beyond the reach (no query point sees further)."""
        c = self.cfg
        grow = max(3.0 * self.position_sigma(), self.window() - c.loop_linear_window)
        return float(c.loop_search_radius + min(grow, c.loop_search_range))

    def window(self) -> float:
        c = self.cfg
        rate = max(self.rate, self.odometry_rate)
        return float(min(max(c.loop_linear_window, 3.0 * rate * self.travel), max(c.loop_max_linear_window,
                                                                                           c.loop_linear_window)))

    def corrected(self, pose: np.ndarray, guess: np.ndarray) -> None:
        self._worst = max(self._worst, math.hypot(pose[0] - guess[0], pose[1] - guess[1]))

    def worst(self) -> float:
        """The largest correction among the accepted loops since the last reset (the search's so far)."""
        return self._worst

    def forget_corrections(self, worst: float) -> None:
        """Back to `worst` (a value of `worst()`): the corrections of loops rejected together are not drift."""
        self._worst = worst

    def reset(self) -> None:
        """A loop was accepted: the rate moves towards what it measured (over at least 10 m of travel, so that a
        loop right after another does not read its matching noise as drift), the travel starts again."""
        if self.travel >= 10.0:
            sample = self._worst / self.travel
            self.rate = float(max(0.5 * self.cfg.loop_drift_per_m, 0.8 * self.rate + 0.2 * sample))
        self.travel = 0.0
        self._worst = 0.0
        self.cov = self._loop_cov()


class LoopCloser:
    """Builds submaps from keyframes and finds loop constraints for new keyframes."""

    def __init__(self, cfg: GraphConfig | None = None) -> None:
        self.cfg = cfg or GraphConfig()
        self.submaps: list[LoopSubmap] = []
        self.open_nodes: list[int] = []
        self.points: dict[int, np.ndarray] = {}  # node id → thinned scan points (base_link), open submap only
        self.stats = LoopStats()
        self.loops: list[LoopConstraint] = []
        self._centres = np.zeros((0, 3))  # each submap's centre (anchor frame) and anchor, for narrow scans
        self._anchors = np.zeros(0, np.int64)
        self._node_ids = np.zeros(0, np.int64)  # the eligible submaps' nodes, concatenated, and where each submap starts
        self._node_starts = np.zeros(0, np.int64)
        self._cache: OrderedDict[tuple[int, int], SubmapFields] = OrderedDict()  # (submap, neighbours) → fields
        # recent keyframes for stacked queries: (id, front-end pose, thinned points, narrow)
        self._recent: deque[tuple[int, np.ndarray, np.ndarray, bool]] = deque()
        self.drift = DriftModel(self.cfg)
        self.noise: dict[int, float] = {}  # node id → its scan's range scatter (scan_noise), open submap only
        # the sensor's field of view (rad; Slam sets it: a laser's beams × angle_increment, else its returns' span):
        # a scan of a wide sensor is wide whatever share of its bearings returned (an open room beyond a 4 m URG)
        self.sensor_fov = 0.0

    def add_node(self, kf: Keyframe, graph: PoseGraph) -> None:
        """Register a keyframe (after the graph has its node); finish a submap every `submap_nodes` nodes."""
        c = self.cfg
        for i in [i for i in self.points if i not in self.open_nodes]:
            del self.points[i]  # the last node of a finished submap: its own search is done
            self.noise.pop(i, None)
        # the scan's scatter about its own lines, across them (what the field's distance sees), as the consistency
        # check measures it; beams much denser than the noise under-read it, which only raises the score asked
        self.noise[kf.id] = scan_noise(kf.points) if len(kf.points) else float("nan")
        pts = kf.points
        if len(pts):
            pts = pts[np.hypot(pts[:, 0], pts[:, 1]) <= c.loop_search_range]
        pts = voxel_filter(pts, c.loop_point_voxel)
        self.points[kf.id] = pts
        narrow = c.loop_query == "stack" or (bearing_coverage(kf.points) < NARROW_COVERAGE
                                             and self.sensor_fov < NARROW_COVERAGE * 2 * math.pi)
        self.drift.travel_to(np.asarray(kf.local_pose, dtype=float))
        self._recent.append((kf.id, np.asarray(kf.local_pose, dtype=float), pts, narrow))
        self._trim_recent()
        self.open_nodes.append(kf.id)
        if len(self.open_nodes) >= c.submap_nodes:
            self._finish(graph)

    def _trim_recent(self) -> None:
        """Keep the keyframes within loop_query_distance of travel of the newest (front-end poses)."""
        dist_max = self.cfg.loop_query_distance
        travel = 0.0
        keep = 1
        items = list(self._recent)
        for k in range(len(items) - 1, 0, -1):
            travel += math.hypot(*(items[k][1][:2] - items[k - 1][1][:2]))
            if travel > dist_max:
                break
            keep += 1
        while len(self._recent) > keep:
            self._recent.popleft()

    def query(self, node: int) -> np.ndarray | None:
        """The points to match for `node`: its scan, or for a narrow scan the recent keyframes' scans stacked in
        its frame by the front end's poses (ℓ_node⁻¹ ⊕ ℓ_k), thinned to one per loop_point_voxel."""
        pts = self.points.get(node)
        if pts is None:
            return None
        if (self.cfg.loop_query == "scan" or not self._recent or self._recent[-1][0] != node
                or not self._recent[-1][3] or len(self._recent) < 2):
            return pts
        here = self._recent[-1][1]
        stack = [pts]
        for _, pose, p, _ in list(self._recent)[:-1]:
            if len(p):
                stack.append(se2.transform_points(se2.between(here, pose), p))
        self.stats.stacked_queries += 1
        return voxel_filter(np.vstack(stack), self.cfg.loop_point_voxel)

    def _finish(self, graph: PoseGraph) -> None:
        ids = self.open_nodes
        anchor = graph.est[ids[0]]
        rel = se2.between(np.repeat(anchor[None], len(ids), 0), graph.est[ids])
        pts = [se2.transform_points(r, self.points[i]) for r, i in zip(rel, ids) if len(self.points[i])]
        allp = (np.vstack(pts) if pts else np.zeros((0, 2))).astype(np.float32)
        sm = LoopSubmap(len(self.submaps), list(ids), allp, rel[:, :2].mean(axis=0), rel)
        self.submaps.append(sm)
        self.stats.points_bytes += sm.nbytes
        self.points = {ids[-1]: self.points[ids[-1]]}  # the others are in the submap (and in _recent for queries)
        self.noise = {ids[-1]: self.noise.get(ids[-1], float("nan"))}
        self.open_nodes = []

    def fields(self, sm: LoopSubmap, graph: PoseGraph | None = None, neighbours: int = 0) -> SubmapFields:
        """The submap's fields and pyramid, from the LRU cache or rebuilt from its points; with `neighbours` > 0
        the submaps that many before and after it join, placed by the graph's current estimate of their anchors
        (the map around the candidate: a query near the submap's edge then meets the place it really is, not
        only the look-alike that lies inside the submap). A cached union keeps the placement it was built with;
        loops bend the old stretch little between neighbouring anchors."""
        key = (sm.index, neighbours)
        f = self._cache.get(key)
        if f is not None:
            self._cache.move_to_end(key)
            return f
        c = self.cfg
        parts = [sm.points.astype(np.float64)]
        if neighbours > 0 and graph is not None:
            last = len(self.submaps) - c.loop_min_separation  # never the query's own recent submaps
            for j in range(max(0, sm.index - neighbours), min(last, sm.index + neighbours + 1)):
                if j != sm.index:
                    o = self.submaps[j]
                    parts.append(se2.transform_points(se2.between(graph.est[sm.anchor], graph.est[o.anchor]), o.points))
        allp = np.vstack(parts)
        coarse = LikelihoodField.covering(allp, c.loop_resolution, c.loop_sigma)
        fine = LikelihoodField(coarse.origin, coarse.resolution, coarse.shape[1], coarse.shape[0], c.loop_sigma_fine)
        fine.insert(allp)
        w = int(math.ceil(max(c.loop_linear_window, c.loop_max_linear_window) / c.loop_resolution))
        grids = SearchGrids(coarse, depth=1 + max(1, int(math.ceil(math.log2(w + 1)))))
        f = SubmapFields(coarse, fine, grids, allp.min(axis=0) if len(allp) else np.zeros(2),
                         allp.max(axis=0) if len(allp) else np.zeros(2))
        self.stats.field_builds += 1
        self.stats.grid_bytes += grids.nbytes
        self._cache[key] = f
        while len(self._cache) > max(1, int(self.cfg.loop_field_cache)):
            self._cache.popitem(last=False)
        self.stats.cache_bytes_peak = max(self.stats.cache_bytes_peak, self.cache_bytes)
        return f

    @property
    def cache_bytes(self) -> int:
        return sum(f.nbytes for f in self._cache.values())

    @property
    def nbytes(self) -> int:
        """Memory the loop closer holds now: submap points, cached fields, open scans."""
        return (sum(sm.nbytes for sm in self.submaps) + self.cache_bytes
                + sum(p.nbytes for p in self.points.values()))

    def candidates(self, node: int, graph: PoseGraph) -> list[LoopSubmap]:
        """Finished submaps, not among the last `loop_min_separation`, with a node near the node's estimate (within
        the drift model's radius, DriftModel.radius), nearest first."""
        c = self.cfg
        last = len(self.submaps) - c.loop_min_separation
        if last <= 0:
            return []
        p = graph.est[node]
        if self._recent and self._recent[-1][0] == node and self._recent[-1][3]:
            # a narrow scan: round each submap's centre, as far as the window's growth reaches. Its stacked query fits
            # look-alikes too readily for the wider reach (simulated office, KOS SLAM: ATE 0.127 m, against ≤ 0.08 m
            # with this reach; tests/backend/test_consistency.py)
            if len(self._centres) < len(self.submaps):
                self._centres = np.array([[*sm.centre, 0.0] for sm in self.submaps])
                self._anchors = np.array([sm.anchor for sm in self.submaps])
            world = se2.compose(graph.est[self._anchors[:last]], self._centres[:last])
            dist = np.hypot(world[:, 0] - p[0], world[:, 1] - p[1])
            radius = c.loop_search_radius + self.drift.window() - c.loop_linear_window
        else:
            # the distance to the nearest node the submap was built at (current estimates): a submap is a stretch of
            # travel, and its centre can lie metres from where a robot coming back meets that stretch
            if len(self._node_starts) != last:
                self._node_ids = np.concatenate([self.submaps[i].node_ids for i in range(last)])
                self._node_starts = np.cumsum([0] + [len(self.submaps[i].node_ids) for i in range(last - 1)])
            est = graph.est[self._node_ids]
            dist = np.minimum.reduceat(np.hypot(est[:, 0] - p[0], est[:, 1] - p[1]), self._node_starts)
            radius = self.drift.radius()
        self.stats.widest_radius = max(self.stats.widest_radius, radius)
        near = np.flatnonzero(dist <= radius)
        near = near[np.argsort(dist[near])][: c.loop_max_candidates]
        return [self.submaps[i] for i in near]

    def search(self, node: int, graph: PoseGraph) -> list[LoopConstraint]:
        """Verify every candidate submap for this node; return the accepted constraints (not yet in the graph)."""
        t0 = time.perf_counter()
        found: list[LoopConstraint] = []
        worst = self.drift.worst()
        cands = self.candidates(node, graph)
        pts = self.query(node) if cands else None
        if pts is None or len(pts) < 10:
            self.stats.seconds += time.perf_counter() - t0
            return found
        narrow = bool(self._recent) and self._recent[-1][0] == node and self._recent[-1][3]
        nb = int(self.cfg.loop_map_neighbours) if narrow else 0
        for sm in cands:
            guess = se2.between(graph.est[sm.anchor], graph.est[node])
            f = self.fields(sm, graph, nb)
            if narrow and f.inside(pts, guess) < self.cfg.loop_min_overlap:
                # the query reaches past the map it would be matched to: where that map's walls end it cannot
                # tell a real end from an unseen one, and a slid look-alike scores best (narrow scans only)
                self.stats.skipped_outside += 1
                continue
            lc = self.verify(sm, pts, guess, f, narrow, self.noise.get(node, float("nan")))
            if lc is not None:
                self.drift.corrected(lc[0], guess)
                # Tie the loop to the member whose pose is nearest the match, not to the anchor: the submap is
                # only as rigid as the front end was while it was built, so the constraint is truest nearby.
                pose = lc[0]
                j = int(np.argmin(np.hypot(*(sm.member_poses[:, :2] - pose[:2]).T))) if self.cfg.loop_nearest_member else 0
                rel = se2.between(sm.member_poses[j], pose)
                found.append(LoopConstraint(sm.node_ids[j], node, rel, lc[1], lc[2], sm.index, lc[3], lc[4],
                                            self.loose_covariance(lc[5])))
        found = self._consistent(found, graph)
        if found:
            self.drift.reset()
        else:
            self.drift.forget_corrections(worst)
        self.stats.drift_per_m = self.drift.rate
        self.loops.extend(found)
        self.stats.seconds += time.perf_counter() - t0
        return found

    def _consistent(self, found: list[LoopConstraint], graph: PoseGraph) -> list[LoopConstraint]:
        """The node's loops, or none when two of them put it at distinct places (further apart than a distinct peak,
        `loop_peak_exclusion`): a rival across submaps. Each submap's best fit is then a look-alike's for one of
        them. A submap that covers only part of what the query sees scores a slid look-alike that overlaps it more
        above the true place (doors every 3 m, a corridor seen 30 m back, the scene of
        tests/backend/test_loop_radius.py: measured 0.991 at the look-alike against 0.957 in the next submap at the
        true place)."""
        if len(found) < 2 or self.cfg.loop_peak_ratio >= 1.0:  # the rival test off (loop_peak_ratio = 1): this one too
            return found
        at = np.array([se2.compose(graph.est[lc.a], lc.rel)[:2] for lc in found])
        spread = np.hypot(*(at[:, None, :] - at[None, :, :]).transpose(2, 0, 1)).max()
        if spread <= self.cfg.loop_peak_exclusion:
            return found
        self.stats.rejected_ambiguous += len(found)
        self.stats.accepted -= len(found)
        return []

    def min_score(self, noise_query: float) -> float:
        """The score a loop must reach: `loop_min_inliers` (the share of the query that must lie on the submap's
        walls) × the score such a point is expected to get (expected_match_score: the query's own range noise and the
        search's cells), or the configured `loop_min_score` (loop_score = "fixed"). A 1 cm laser: 0.6 × 0.985 ≈ 0.59;
        4 cm: 0.6 × 0.92 ≈ 0.55."""
        c = self.cfg
        if c.loop_score == "fixed":
            return float(c.loop_min_score)
        t = c.loop_min_inliers * expected_match_score(noise_query, c.loop_sigma, c.loop_resolution)
        st = self.stats
        st.min_score_lo = t if not math.isfinite(st.min_score_lo) else min(st.min_score_lo, t)
        st.min_score_hi = t if not math.isfinite(st.min_score_hi) else max(st.min_score_hi, t)
        return t

    def verify(self, sm: LoopSubmap, pts: np.ndarray, guess: np.ndarray, f: SubmapFields | None = None,
               narrow: bool = False, noise_query: float = float("nan")):
        """Branch and bound around the guess (best and best distinct rival), Gauss–Newton refinement, fitness and
        look-alike tests → (pose in anchor frame, score, inliers, rival score, information ratio) or None."""
        c = self.cfg
        self.stats.searches += 1
        min_score = self.min_score(noise_query)
        f = f if f is not None else self.fields(sm)
        # narrow scans: reject a rival scoring above ratio · best, or fitting less than `misfit` times worse
        # (misfit = 1 − score); the rival need only be searched above the lower of the two scores that reject.
        # A wide scan's rival is searched too, but rejects only a degenerate match (below): a corridor slid along
        ratio = c.loop_peak_ratio if narrow or c.degenerate_ratio > 0 else 1.0
        misfit = c.loop_peak_misfit if narrow else 1.0
        floor = (lambda best: min(ratio * best, 1.0 - misfit * (1.0 - best))) if (ratio < 1.0 or misfit > 1.0) else None
        window = self.drift.window()
        if window > c.loop_linear_window:
            self.stats.widened += 1
        self.stats.widest_window = max(self.stats.widest_window, window)
        pose, score, second = search_two_peaks(f.grids, pts, guess, window,
                                               math.radians(c.loop_angular_window_deg), min_score,
                                               c.loop_peak_exclusion, floor)
        if pose is None:
            self.stats.rejected_score += 1
            return None
        if window - np.max(np.abs(np.asarray(pose[:2]) - guess[:2])) < c.loop_resolution:
            # the best pose lies on the window's edge: the place the scan fits best may lie outside it, and what the
            # window holds there is a look-alike's shoulder, not a verified maximum (a node 116 m past its last loop
            # on the simulated corridor ring: 3.2 m off, score 0.69 against 0.98 for the true loops)
            self.stats.rejected_edge += 1
            return None
        pts64 = np.ascontiguousarray(pts, dtype=np.float64)
        W = np.diag([1.0, 1.0, 1.0])
        co, fi = f.coarse, f.fine
        p1, _, _ = gauss_newton(co.values, co.origin[0], co.origin[1], co.resolution, pts64, pose, pose, W, 20)
        p2, h, _ = gauss_newton(fi.values, fi.origin[0], fi.origin[1], fi.resolution, pts64, p1, p1, W, 20)
        inl = inlier_fraction(fi.values, fi.origin[0], fi.origin[1], fi.resolution, pts64, p2, math.exp(-0.5))
        if inl < c.loop_min_inliers:
            self.stats.rejected_inliers += 1
            return None
        lo, hi, _ = translation_information(h)
        info_ratio = lo / hi if hi > 0 else 0.0
        # a wide scan's match faces its rival only when degenerate, as its own surfaces tell (frontend/odometry.py
        # scan_geometry; the field's information is no guide along a corridor, where the walls' ends pull): on the
        # simulated corridor ring driven both ways with a 180° laser, 74 of 95 loops slid 1–3 m along a corridor
        geo, weak = scan_geometry(pts64, c.loop_point_voxel * 3.0)
        rival = narrow or geo < c.degenerate_ratio
        if rival and second > 0.0 and ((ratio < 1.0 and second > ratio * score)
                                       or (misfit > 1.0 and (1.0 - second) < misfit * (1.0 - score))):
            self.stats.rejected_ambiguous += 1
            return None
        if info_ratio < c.loop_min_information_ratio:
            self.stats.rejected_degenerate += 1
            return None
        self.stats.accepted += 1
        return (np.asarray(p2, dtype=float), float(score), float(inl), float(second), float(info_ratio),
                weak if (not narrow and geo < c.degenerate_ratio) else None)

    def loose_covariance(self, weak: np.ndarray | None) -> np.ndarray | None:
        """A degenerate wide match's loop covariance in the query's (node b's) frame: the loop σ across, LOOSE_SIGMA
        along the direction its surfaces do not fix (`weak`, from scan_geometry), the loop yaw σ; None for a match
        that fixes both. Along a corridor the best score is where the query overlaps the submap's walls most, not
        where it is: on the simulated corridor ring driven both ways with a 180° laser, 76 of 97 such loops lay
        1–3 m along the corridor from the truth."""
        if weak is None:
            return None
        c = self.cfg
        s2 = c.loop_sigma_xy ** 2
        cov = np.zeros((3, 3))
        cov[:2, :2] = s2 * np.eye(2) + (LOOSE_SIGMA ** 2 - s2) * np.outer(weak, weak)
        cov[2, 2] = math.radians(c.loop_sigma_yaw_deg) ** 2
        return cov

    def release(self) -> None:
        """Drop the cached fields and pyramids (memory) once the run is over."""
        self._cache.clear()

