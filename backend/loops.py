"""Loop closure: submaps of keyframes, candidates near the current estimate but far back in the sequence,
verified by an exact branch-and-bound search, refined by Gauss–Newton, accepted by a fitness test.

Every `submap_nodes` keyframes form a submap: their scans, placed at the nodes' current estimates relative to
the first node (the anchor), splatted into a likelihood field in the anchor's frame. When a new node's
estimate lies within `loop_search_radius` of an older submap's centre, its scan is searched over a window of
±`loop_linear_window` and ±`loop_angular_window_deg` around that estimate (Hess et al. 2016, §V: branch and
bound on precomputed max grids, exact, so a poor guess inside the window is no problem), refined on a
sharper field, and accepted when the search score and the share of points within 1σ of the submap both pass.
The constraint is the node's pose in the anchor's frame (a gtsam BetweenFactorPose2 under a robust kernel).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from backend.graph import GraphConfig, PoseGraph
from backend.keyframes import Keyframe
from frontend import se2
from frontend.likelihood import LikelihoodField
from frontend.matcher import SearchGrids, gauss_newton, inlier_fraction
from frontend.odometry import voxel_filter


@dataclass
class LoopSubmap:
    """A finished submap in its anchor node's frame."""

    index: int
    node_ids: list[int]
    coarse: LikelihoodField
    fine: LikelihoodField
    centre: np.ndarray  # (2,) mean node position, anchor frame
    member_poses: np.ndarray  # (n, 3) the member nodes' poses in the anchor frame when the submap was built
    grids: SearchGrids | None = None

    @property
    def anchor(self) -> int:
        return self.node_ids[0]


@dataclass
class LoopConstraint:
    """An accepted loop: pose of node `b` in the frame of node `a` (a submap anchor)."""

    a: int
    b: int
    rel: np.ndarray
    score: float
    inliers: float
    submap: int


@dataclass
class LoopStats:
    searches: int = 0
    accepted: int = 0
    rejected_score: int = 0
    rejected_inliers: int = 0
    seconds: float = 0.0
    grid_bytes: int = 0


class LoopCloser:
    """Builds submaps from keyframes and finds loop constraints for new keyframes."""

    def __init__(self, cfg: GraphConfig | None = None) -> None:
        self.cfg = cfg or GraphConfig()
        self.submaps: list[LoopSubmap] = []
        self.open_nodes: list[int] = []
        self.points: dict[int, np.ndarray] = {}  # node id → thinned scan points (base_link)
        self.stats = LoopStats()
        self.loops: list[LoopConstraint] = []
        self._centres = np.zeros((0, 3))
        self._anchors = np.zeros(0, np.int64)

    def add_node(self, kf: Keyframe, graph: PoseGraph) -> None:
        """Register a keyframe (after the graph has its node); finish a submap every `submap_nodes` nodes."""
        c = self.cfg
        pts = kf.points
        if len(pts):
            pts = pts[np.hypot(pts[:, 0], pts[:, 1]) <= c.loop_search_range]
        self.points[kf.id] = voxel_filter(pts, c.loop_point_voxel)
        self.open_nodes.append(kf.id)
        if len(self.open_nodes) >= c.submap_nodes:
            self._finish(graph)

    def _finish(self, graph: PoseGraph) -> None:
        c = self.cfg
        ids = self.open_nodes
        anchor = graph.est[ids[0]]
        rel = se2.between(np.repeat(anchor[None], len(ids), 0), graph.est[ids])
        pts = [se2.transform_points(r, self.points[i]) for r, i in zip(rel, ids) if len(self.points[i])]
        allp = np.vstack(pts) if pts else np.zeros((0, 2))
        coarse = LikelihoodField.covering(allp, c.loop_resolution, c.loop_sigma)
        fine = LikelihoodField(coarse.origin, coarse.resolution, coarse.shape[1], coarse.shape[0], c.loop_sigma_fine)
        fine.insert(allp)
        self.submaps.append(LoopSubmap(len(self.submaps), list(ids), coarse, fine, rel[:, :2].mean(axis=0), rel))
        self.open_nodes = []

    def candidates(self, node: int, graph: PoseGraph) -> list[LoopSubmap]:
        """Finished submaps, not among the last `loop_min_separation`, whose centre is near the node's estimate."""
        c = self.cfg
        last = len(self.submaps) - c.loop_min_separation
        if last <= 0:
            return []
        p = graph.est[node]
        if len(self._centres) < len(self.submaps):
            self._centres = np.array([[*sm.centre, 0.0] for sm in self.submaps])
            self._anchors = np.array([sm.anchor for sm in self.submaps])
        world = se2.compose(graph.est[self._anchors[:last]], self._centres[:last])
        dist = np.hypot(world[:, 0] - p[0], world[:, 1] - p[1])
        near = np.flatnonzero(dist <= c.loop_search_radius)
        near = near[np.argsort(dist[near])][: c.loop_max_candidates]
        return [self.submaps[i] for i in near]

    def search(self, node: int, graph: PoseGraph) -> list[LoopConstraint]:
        """Verify every candidate submap for this node; return the accepted constraints (not yet in the graph)."""
        import time

        t0 = time.perf_counter()
        pts = self.points.get(node)
        found: list[LoopConstraint] = []
        if pts is None or len(pts) < 10:
            return found
        for sm in self.candidates(node, graph):
            guess = se2.between(graph.est[sm.anchor], graph.est[node])
            lc = self.verify(sm, pts, guess)
            if lc is not None:
                # Tie the loop to the member whose pose is nearest the match, not to the anchor: the submap is
                # only as rigid as the front end was while it was built, so the constraint is truest nearby.
                j = int(np.argmin(np.hypot(*(sm.member_poses[:, :2] - lc[0][:2]).T))) if self.cfg.loop_nearest_member else 0
                rel = se2.between(sm.member_poses[j], lc[0])
                found.append(LoopConstraint(sm.node_ids[j], node, rel, lc[1], lc[2], sm.index))
        self.loops.extend(found)
        self.stats.seconds += time.perf_counter() - t0
        return found

    def verify(self, sm: LoopSubmap, pts: np.ndarray, guess: np.ndarray) -> tuple[np.ndarray, float, float] | None:
        """Branch and bound around the guess, Gauss–Newton refinement, fitness test → (pose in anchor frame, score, inliers)."""
        c = self.cfg
        self.stats.searches += 1
        if sm.grids is None:
            w = int(math.ceil(c.loop_linear_window / c.loop_resolution))
            sm.grids = SearchGrids(sm.coarse, depth=1 + max(1, int(math.ceil(math.log2(w + 1)))))
            self.stats.grid_bytes += sm.grids.nbytes
        pose, score = sm.grids.search(pts, guess, c.loop_linear_window, math.radians(c.loop_angular_window_deg),
                                      c.loop_min_score)
        if pose is None:
            self.stats.rejected_score += 1
            return None
        pts64 = np.ascontiguousarray(pts, dtype=np.float64)
        W = np.diag([1.0, 1.0, 1.0])
        co, fi = sm.coarse, sm.fine
        p1, _, _ = gauss_newton(co.values, co.origin[0], co.origin[1], co.resolution, pts64, pose, pose, W, 20)
        p2, _, _ = gauss_newton(fi.values, fi.origin[0], fi.origin[1], fi.resolution, pts64, p1, p1, W, 20)
        inl = inlier_fraction(fi.values, fi.origin[0], fi.origin[1], fi.resolution, pts64, p2, math.exp(-0.5))
        if inl < c.loop_min_inliers:
            self.stats.rejected_inliers += 1
            return None
        self.stats.accepted += 1
        return np.asarray(p2, dtype=float), float(score), float(inl)

    def release(self) -> None:
        """Drop the search pyramids (memory) once the run is over."""
        for sm in self.submaps:
            sm.grids = None


@dataclass
class LoopReport:
    """Accepted loops checked against a reference (ground truth) where one exists."""

    total: int = 0
    checked: int = 0
    correct: int = 0
    details: list = field(default_factory=list)

    @property
    def precision(self) -> float:
        return self.correct / self.checked if self.checked else float("nan")
