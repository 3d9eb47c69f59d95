"""Confirm or replace the particle filter's pose by a global search of the last metres of scans.

A 70° depth camera in a building of look-alike corridors sees, for metres on end, a view that fits two or more
places equally (a floor symmetric under a half turn: the south corridor driven east is the north one driven west).
A particle filter represents such a posterior only while its particles cover every place; one resampling too many
and the right place is gone, and the set converges, tight and sure, on the wrong one. So a pose is claimed only when
a global correlative search of the stitched submap (mapping/localize_window.py, backend/globalsearch.py) is sure of
one place: the posterior over the distinct places the search finds, from the likelihood field model over the
submap's end points a correlation length apart (each ray traced from where it was seen), gives it at least
`claim_p`, its readings do not pass through its walls, and the search one `search_every_m` later is sure of the same
place. While no place wins, particles are put back round every place still in the running, so the filter keeps them
all (Probabilistic Robotics §8.3.4: a filter must be able to recover the hypotheses it has lost).

While a pose is held, the last `check_m` of the window is searched every `check_every_m`: when two checks are sure of
another place and the window's readings pass through the held place's walls, the robot was carried (kidnapped).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from kosmap.backend import globalsearch as gs
from kosmap.backend.likelihood_field import MapField
from kosmap.frontend import se2
from kosmap.frontend.matcher import correlative_search, gauss_newton
from kosmap.mapping.localize_config import LocalizeConfig
from kosmap.mapping.localize_window import ScanWindow


@dataclass
class Verdict:
    """One search's outcome: the places in the running (best first) with their posterior probabilities."""

    poses: np.ndarray  # (K, 3)
    prob: np.ndarray  # (K,)
    through: float  # share of the submap's end points that pass through a wall from the best place
    claim: bool  # the best place is sure enough to claim


class WindowSearch:
    """The scan window and when to search it: every `search_every_m` of travel while the pose is not held."""

    def __init__(self, f: MapField, cfg: LocalizeConfig) -> None:
        self.f, self.cfg = f, cfg
        self.sf = gs.search_field(f.distance, f.free, f.origin, f.resolution, cfg.search_step, cfg.search_fine)
        self.window = ScanWindow(cfg.window_m)
        self.last = -math.inf
        self.last_odom: np.ndarray | None = None
        self.searches = 0
        self.sure: tuple[np.ndarray, np.ndarray] | None = None  # the last search's sure place and the odometry then
        self.checked = 0.0  # window travel at the last check
        self.sure_check: tuple[np.ndarray, np.ndarray] | None = None  # the same for the checks

    def reset(self) -> None:
        """The robot may have been carried: nothing before now belongs to the same submap."""
        self.window.clear()
        self.last = -math.inf
        self.last_odom = None
        self.sure = self.sure_check = None
        self.checked = 0.0

    def due(self) -> bool:
        """After search_every_m of travel since the last search, or a turn of search_every_deg (a new view)."""
        w, c = self.window, self.cfg
        if w.span_m < c.search_min_m:
            return False
        if w.total_m - self.last >= c.search_every_m or self.last_odom is None:
            return True
        return abs(se2.wrap(w.odom[-1][2] - self.last_odom[2])) >= math.radians(c.search_every_deg)

    def search(self, z_max: float) -> Verdict:
        """The whole window searched over the map (while no pose is held)."""
        self.last = self.window.total_m
        self.last_odom = self.window.odom[-1].copy()
        v, self.sure = self._search(z_max, *self.window.submap(), self.sure)
        if v.claim and self.window.span_m > self.cfg.check_m:
            v = self._rigid(z_max, v)
        if v.claim:  # a later claim (after the pose is lost) needs two sure searches of its own
            self.sure = None
            # the place's pose from the last check_m of scans: over the whole window the wheels' scale error (1 % is
            # 9 cm over 9 m) bends the submap, over 3 m by less than a map cell, and 3 m of travel sees more than two
            # corridor walls more often than one metre does. Its best alignment on the map's cells within the
            # search's fine spacing first: Gauss–Newton alone stops at the nearest bump of the sharp field, and
            # along a corridor the bumps are a door's edges
            recent, _ = self.window.submap(self.cfg.check_m)
            v.poses[0] = _settle(self.f, recent[gs.thin(recent, self.f.resolution)], v.poses[0], self.cfg.search_fine)
        return v

    def _rigid(self, z_max: float, v: Verdict) -> Verdict:
        """The whole window's claim, held against its own last check_m: a rigid submap's recent part fits where the
        whole does, so when that part alone is sure of another place and its readings pass through the walls of the
        whole's place, the window spans a jump the wheels did not see
        (a robot carried, the odometry continuous): its older scans, stitched across the jump, fit a look-alike
        (in a room symmetric under a quarter turn, the place the robot was carried by that turn) better than the
        truth. Then nothing is claimed, the window is cut to the recent part, and that part's place, when its readings
        also keep clear of its walls (the recent part may still hold scans from before the jump), is the sure one the
        next search must confirm."""
        c = self.cfg
        sub, views = self.window.submap(c.check_m)
        recent, sure = self._search(z_max, sub, views, None, v.poses[0])
        if recent.prob[0] < c.claim_p:  # the recent part alone may be unsure: that refutes nothing
            return v
        d = recent.poses[0] - v.poses[0]
        if math.hypot(d[0], d[1]) < c.search_apart and abs(se2.wrap(d[2])) < math.radians(c.search_apart_deg):
            return v
        # and the recent part refutes the whole's place: its readings pass through that place's walls (a few metres
        # of scans can be sure of a look-alike by their own noise, as the checks can: no proof by itself)
        keep = gs.thin(sub, 2.0 * c.sigma_hit)
        if gs.window_through(self.f, v.poses[0], sub[keep], views[keep], c.through_tol) <= c.lost_through:
            return v
        self.window.keep_recent(c.check_m)
        self.sure = sure
        return Verdict(recent.poses, recent.prob, recent.through, False)

    def check_due(self) -> bool:
        w, c = self.window, self.cfg
        return w.span_m >= c.check_m and w.total_m - self.checked >= c.check_every_m

    def check(self, z_max: float, held: np.ndarray) -> bool:
        """While a pose is held: the last check_m of the window searched over the map. True when two checks in a row
        are sure of one place away from `held` (the pose held at the newest scan): the robot was carried there. The
        window is then cut to that stretch, and the next search starts from the checks' verdict."""
        c = self.cfg
        self.checked = self.window.total_m
        v, self.sure_check = self._search(z_max, *self.window.submap(c.check_m), self.sure_check, held)
        if not v.claim:
            return False
        d = v.poses[0] - held
        if math.hypot(d[0], d[1]) < c.search_apart and abs(se2.wrap(d[2])) < math.radians(c.search_apart_deg):
            return False
        # and the held place is refuted: the window's readings pass through its walls (a look-alike that merely
        # fits better, by the noise of a few metres of corridor, is no proof that the robot was carried)
        sub, views = self.window.submap(c.check_m)
        keep = gs.thin(sub, 2.0 * c.sigma_hit)
        if gs.window_through(self.f, held, sub[keep], views[keep], c.through_tol) <= c.lost_through:
            return False
        self.window.keep_recent(c.check_m)
        self.last, self.last_odom, self.sure, self.sure_check = -math.inf, None, self.sure_check, None
        return True

    def _search(self, z_max: float, sub: np.ndarray, views: np.ndarray, prev,
                held: np.ndarray | None = None) -> tuple[Verdict, tuple | None]:
        """The window's places and how sure the best is; `held`, the pose held now, always competes as a place."""
        c, f = self.cfg, self.f
        self.searches += 1
        pts = sub[gs.thin(sub, c.search_fine)]
        cands = candidates(self.sf, f, c, pts)
        if not cands:
            return Verdict(np.zeros((0, 3)), np.zeros(0), 1.0, False), None
        poses = np.array(cands + ([] if held is None else [polish(f, pts, held)]))
        poses, prob = score_places(f, c, poses, sub, views, z_max)
        keep = gs.thin(sub, 2.0 * c.sigma_hit)
        thr = gs.window_through(f, poses[0], sub[keep], views[keep], c.through_tol)
        sure = bool(prob[0] >= c.claim_p and thr <= c.lost_through)
        # claimed when two searches in a row, search_every_m apart, are sure of the same place (the earlier one moved
        # by the odometry since): one sure search can be the noise of one view, a place held over travel is not
        u = self.window.odom[-1]
        again = False
        if sure and prev is not None:
            then = se2.compose(prev[0], se2.between(prev[1], u))
            again = (math.hypot(then[0] - poses[0, 0], then[1] - poses[0, 1]) < c.search_apart
                     and abs(se2.wrap(then[2] - poses[0, 2])) < math.radians(c.search_apart_deg))
        return Verdict(poses, prob, thr, again), ((poses[0].copy(), u.copy()) if sure else None)


def z_max_of(f: MapField, cfg: LocalizeConfig) -> float:
    """The likelihood field's max-range weight (its floor is log(z_rand / z_max))."""
    return math.exp(-f.floor) * cfg.z_rand


def through_floor(cfg: LocalizeConfig, z_max: float) -> float:
    """The log-likelihood of a reading through a wall (−inf with z_through 0: no ray check)."""
    return math.log(cfg.z_through / z_max) if cfg.z_through > 0 else -math.inf


def candidates(sf, f: MapField, cfg: LocalizeConfig, pts: np.ndarray) -> list[np.ndarray]:
    """The correlative search's places for the end points `pts` over the whole map (backend/globalsearch.py, Olson
    2009), each brought to its best (`polish`)."""
    cands = gs.global_search(sf, pts, cfg.search_keep, cfg.search_apart, math.radians(cfg.search_apart_deg),
                             cfg.search_fine)
    return [polish(f, pts, k.pose) for k in cands]


def score_places(f: MapField, cfg: LocalizeConfig, poses: np.ndarray, sub: np.ndarray, views: np.ndarray,
                 z_max: float) -> tuple[np.ndarray, np.ndarray]:
    """The places' posterior (best first, one place counted once): the likelihood field model over end points a
    correlation length (2σ_hit) apart, which are about independent where a submap sees each piece of wall from many
    scans, each ray traced from where it was seen (`views`)."""
    keep = gs.thin(sub, 2.0 * cfg.sigma_hit)
    poses, ll = profile_places(f, poses, sub[keep], views[keep], through_floor(cfg, z_max), cfg.through_tol)
    return _merge(poses, gs.posterior(ll), cfg.search_apart, math.radians(cfg.search_apart_deg))


def _merge(poses: np.ndarray, prob: np.ndarray, apart_xy: float, apart_yaw: float) -> tuple[np.ndarray, np.ndarray]:
    """Places best first, those that the fine search and Gauss–Newton brought together counted as one (their
    probabilities summed into the best of them)."""
    order = np.argsort(-prob)
    keep: list[int] = []
    total: list[float] = []
    for k in order:
        for m, j in enumerate(keep):
            if (math.hypot(poses[k, 0] - poses[j, 0], poses[k, 1] - poses[j, 1]) < apart_xy
                    and abs(math.remainder(poses[k, 2] - poses[j, 2], 2 * math.pi)) < apart_yaw):
                total[m] += float(prob[k])
                break
        else:
            keep.append(int(k))
            total.append(float(prob[k]))
    return poses[keep], np.array(total)


def polish(f: MapField, pts: np.ndarray, pose: np.ndarray) -> np.ndarray:
    """The search's pose to the map's cell: Gauss–Newton, coarse to fine, without a prior (frontend/matcher.py):
    the likelihood of a wide submap changes over a few centimetres, and the places must be compared at their best."""
    p64 = np.ascontiguousarray(pts, dtype=np.float64)
    pose = np.asarray(pose, float)
    w = np.zeros((3, 3))
    for fld, sigma in zip((f.match_coarse, f.match), (2 * f.match_sigma, f.match_sigma)):
        pose, _, _ = gauss_newton(fld, f.origin[0], f.origin[1], f.resolution, p64, pose, pose.copy(), w, 10, True,
                                  sigma)
    return pose


def _settle(f: MapField, pts: np.ndarray, pose: np.ndarray, window: float) -> np.ndarray:
    """The best pose of `pts` on the map's cells within ±window and on half degrees within ±1° of `pose` (Olson's
    correlative search, frontend/matcher.py, on the matcher's sharp field), then Gauss–Newton from there."""
    p64 = np.ascontiguousarray(pts, dtype=np.float64)
    best, _ = correlative_search(f.match, f.origin[0], f.origin[1], f.resolution, p64, np.asarray(pose, float), window,
                                 f.resolution, math.radians(1.0), math.radians(0.5), 0.0, 0.0)
    return polish(f, p64, best)


def profile_places(f: MapField, poses: np.ndarray, pts: np.ndarray, views: np.ndarray, through: float,
             tol: float) -> tuple[np.ndarray, np.ndarray]:
    """Each place's best log-likelihood within a map cell and a degree of it (the profile likelihood): the
    through-wall test of a grazing reading flips over a few centimetres, so places are compared at their best."""
    d = np.array([-1.0, 0.0, 1.0])
    off = np.stack(np.meshgrid(d * f.resolution, d * f.resolution, d * math.radians(1.0), indexing="ij"), -1)
    off = off.reshape(-1, 3)
    grid = (poses[:, None, :] + off[None, :, :]).reshape(-1, 3)
    ll = gs.window_loglik(f, grid, pts, views, through, tol).reshape(len(poses), len(off))
    best = np.argmax(ll, axis=1)
    return grid.reshape(len(poses), len(off), 3)[np.arange(len(poses)), best], ll[np.arange(len(poses)), best]


def seed_round(poses: np.ndarray, counts: np.ndarray, sigma_xy: float, sigma_yaw: float,
               rng: np.random.Generator) -> np.ndarray:
    """Particles scattered round each pose (counts[k] of them round poses[k])."""
    if len(poses) == 0 or counts.sum() == 0:
        return np.zeros((0, 3))
    base = np.repeat(poses, counts, axis=0)
    out = base + rng.normal(0.0, 1.0, base.shape) * np.array([sigma_xy, sigma_xy, sigma_yaw])
    out[:, 2] = np.arctan2(np.sin(out[:, 2]), np.cos(out[:, 2]))
    return out
