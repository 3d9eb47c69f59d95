"""`kosmap localize`: where a robot was, scan by scan, in a prior map or a blueprint.

Monte Carlo localization with KLD-sampling over the map's likelihood field (backend/mcl.py,
backend/likelihood_field.py), augmented MCL's recovery from a lost or kidnapped pose, and each pose refined by the
scan-to-map matcher (frontend/matcher.py's Gauss–Newton) once the filter has found it: the filter is robust and
global, the matcher precise. The filter updates after `update_min_d` / `update_min_a` of motion as AMCL does; every
scan gets a pose (the filter's moved by the odometry since, then refined).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np

from kosmap.backend import mcl
from kosmap.backend.likelihood_field import MapField, map_field
from kosmap.frontend import se2
from kosmap.frontend.errors import KosmapError
from kosmap.frontend.matcher import correlative_search, gauss_newton, inlier_fraction
from kosmap.mapping.localize_claim import ClaimCheck, jump_test, unique_or_reseed
from kosmap.mapping.localize_config import LocalizeConfig
from kosmap.mapping.localize_search import Verdict, WindowSearch, seed_round, through_floor, z_max_of

SEARCHING, TRACKING, LOST = 0, 1, 2  # per-pose status: not found yet, found, lost after having been found
STATUS_NAMES = ("searching", "tracking", "lost")


class LocalizeError(KosmapError):
    """Input `kosmap localize` cannot work with (a map without free space, an initial pose off it, ...)."""


@dataclass
class Snapshot:
    """A subsample of the particles after one filter update (for Foxglove)."""

    stamp_ns: int
    particles: np.ndarray  # (n, 3) float32


@dataclass
class Stretch:
    """A stretch of the log where the pose was lost; `end_s` is when it was found again (None: never)."""

    start_s: float
    end_s: float | None


PLACE_MIN_P = 0.01  # a search's place is reported while its posterior is at least this


@dataclass
class Places:
    """One window search while no pose was held: the places still in the running, best first, with their posterior
    probabilities (posterior ≥ PLACE_MIN_P). Two or more of them: the scans so far fit each about as well."""

    t_s: float  # log seconds from the first scan
    poses: np.ndarray  # (K, 3)
    prob: np.ndarray  # (K,)
    claim: bool  # the best place was claimed on this search

    @classmethod
    def of(cls, t_s: float, poses: np.ndarray, prob: np.ndarray, claim: bool) -> "Places":
        """A search's places with posterior ≥ PLACE_MIN_P."""
        alive = prob >= PLACE_MIN_P
        return cls(t_s, poses[alive].copy(), prob[alive].copy(), bool(claim))


@dataclass
class LocalizeResult:
    """A pose per scan (base_link in the map frame) with the filter's confidence."""

    stamps_ns: np.ndarray  # (S,)
    poses: np.ndarray  # (S, 3): refined where tracking, else the filter's
    filter_poses: np.ndarray  # (S, 3): the particle filter's mode moved by the odometry since its last update
    spread_xy: np.ndarray  # (S,) m
    spread_yaw: np.ndarray  # (S,) rad
    score: np.ndarray  # (S,) mean matcher field value at the pose (1: every end point on a wall)
    inliers: np.ndarray  # (S,) share of end points within σ_match of a wall
    particles: np.ndarray  # (S,) particle count
    ratio: np.ndarray  # (S,) augmented MCL's w_fast/w_slow
    mode_share: np.ndarray  # (S,) share of the particles' weight in the mode the pose is taken from
    status: np.ndarray  # (S,) int8 SEARCHING / TRACKING / LOST
    snapshots: list[Snapshot] = field(default_factory=list)
    searches: list[Places] = field(default_factory=list)  # the window's searches (depth camera with odometry)
    updates: int = 0
    seconds: float = 0.0

    @property
    def stamps(self) -> np.ndarray:
        return self.stamps_ns * 1e-9

    @property
    def t0(self) -> float:
        return float(self.stamps[0]) if len(self.stamps_ns) else 0.0

    def converged_s(self) -> float | None:
        """Log seconds from the first scan to the filter's first claim of a pose."""
        hit = np.flatnonzero(self.status == TRACKING)
        return float(self.stamps[hit[0]] - self.t0) if len(hit) else None

    def lost_stretches(self) -> list[Stretch]:
        lost = self.status == LOST
        out = []
        i = 0
        while i < len(lost):
            if lost[i]:
                j = i
                while j < len(lost) and lost[j]:
                    j += 1
                out.append(Stretch(float(self.stamps[i] - self.t0),
                                   float(self.stamps[j] - self.t0) if j < len(lost) else None))
                i = j
            else:
                i += 1
        return out


def field_for(grid, cfg: LocalizeConfig, z_max: float) -> MapField:
    """The map's likelihood fields; LocalizeError for a map with no free cell or no wall."""
    if abs(grid.origin[2]) > 1e-9:
        raise LocalizeError(f"the map's origin has a yaw of {math.degrees(grid.origin[2]):.1f}°; kosmap localize "
                            f"takes maps whose origin yaw is 0 (rotate the image instead)")
    f = map_field(grid.data, grid.resolution, grid.origin, cfg.sigma_hit, cfg.z_hit, cfg.z_rand, z_max, cfg.match_sigma)
    if not f.free.any():
        raise LocalizeError("the map has no free cell to localize in (free: below map_server's free_thresh); check "
                            "its image and thresholds")
    if not np.isfinite(f.distance).any() or float(f.distance.min()) > 0:
        raise LocalizeError("the map has no occupied cell (no wall) to localize against; check its image and thresholds")
    return f


class _Filter:
    """The particle set, its weights, augmented MCL's averages and the KLD resampling between updates."""

    def __init__(self, f: MapField, cfg: LocalizeConfig, rng: np.random.Generator, initial: np.ndarray | None,
                 windowed: bool = False) -> None:
        self.f, self.cfg, self.rng = f, cfg, rng
        self.z_max = z_max_of(f, cfg)
        self.global_n = int(min(cfg.global_max_particles, max(cfg.min_particles, cfg.global_density * f.free_area)))
        if initial is None:
            # with the window's search the first pose is the search's claim, and the particles are seeded round its
            # places (apply): a global set, most of a searching update's time, would only be replaced
            self.parts = f.sample_free(cfg.min_particles if windowed else self.global_n, rng)
        else:  # AMCL's initial covariance: 0.5 m in x and y, π/12 in heading
            n = cfg.max_particles
            self.parts = initial + rng.normal(0, 1, (n, 3)) * np.array([0.5, 0.5, math.pi / 12])
            self.parts[:, 2] = se2.wrap(self.parts[:, 2])
        self.w = np.full(len(self.parts), 1.0 / len(self.parts))
        self.rec = mcl.Recovery(cfg.alpha_slow, cfg.alpha_fast)
        self.updates = 0
        self.found = False
        self.tight = 0  # filter updates in a row with a tight set
        self.tracking = False  # the last scan's pose was claimed
        self.restarted = False  # a gap in the scans or a wrong pose: the pose is searched for again
        self.bad_since: float | None = None  # log time since which the refined pose's readings pass through walls
        self.lost_since = -1
        self.confirmed = False  # the window's global search has just confirmed a pose
        self.alphas = tuple(float(a) for a in cfg.odom_alpha)
        if len(self.alphas) != 4:
            from kosmap.frontend.errors import ConfigError

            raise ConfigError(f"config [localize] odom_alpha = {cfg.odom_alpha!r} must be four numbers (α1..α4)")

    def restart(self) -> None:
        """The scans stopped for longer than max_gap_s (the robot may have been carried anywhere meanwhile), or the
        tracked pose proved wrong: a global set joins the particles (moved by the odometry at the next update), and
        the pose must be found again: claimed once one mode has held most of the weight for converged_updates."""
        self.parts = np.concatenate((self.parts, self.f.sample_free(self.global_n, self.rng)))
        self.w = np.full(len(self.parts), 1.0 / len(self.parts))
        self.tight = 0
        self.tracking = False
        self.restarted = True
        self.lost_since = self.updates
        self.rec.w_slow = self.rec.w_fast = 0.0

    def apply(self, v: Verdict) -> None:
        """A search's verdict: a sure place replaces the set (particles round it, claimed now); otherwise particles
        join the set round every place still in the running, so that none is lost to resampling."""
        c = self.cfg
        if v.claim:
            self.parts = seed_round(v.poses[:1], np.array([c.max_particles]), 0.5 * c.search_fine, math.radians(2.0),
                                    self.rng)
            self.confirmed = True
            self.rec.w_slow = self.rec.w_fast = 0.0
            self.w = np.full(len(self.parts), 1.0 / len(self.parts))
            return
        alive = v.prob >= 1e-3
        if not alive.any():
            return
        extra = seed_round(v.poses[alive], np.full(int(alive.sum()), c.min_particles), c.search_fine,
                           math.radians(2.0), self.rng)
        if self.found:
            self.parts = np.concatenate((self.parts, extra))
            self.w = np.full(len(self.parts), 1.0 / len(self.parts))
        else:  # the first pose is the search's to claim: the set is its places, weighted by their posterior
            w = np.repeat(v.prob[alive] / c.min_particles, c.min_particles)
            self.parts, self.w = extra, w / w.sum()

    def move(self, u0: np.ndarray, u1: np.ndarray) -> None:
        self.parts = mcl.sample_motion_odometry(self.parts, u0, u1, self.alphas, self.rng)

    def diffuse(self, dt: float) -> None:
        c = self.cfg
        self.parts = mcl.diffuse(self.parts, c.no_odom_sigma_xy * dt, math.radians(c.no_odom_sigma_yaw_deg) * dt, self.rng)

    def measure(self, pts: np.ndarray) -> None:
        c = self.cfg
        beams = mcl.beam_subset(pts, c.max_beams)
        through = through_floor(c, self.z_max)
        searching = not self.found or self.lost_since >= 0
        # while the pose is not found, a reading counts as through a wall only beyond sigma_search: a sparse global
        # set's particle stands for the poses round it
        ll = mcl.log_likelihoods(self.f, self.parts, beams, through, c.sigma_search if searching else c.sigma_hit,
                                 c.through_every)
        q = np.exp(ll / max(len(beams), 1))  # −inf → 0: per-beam geometric mean likelihood of each particle
        self.rec.update(float(np.sum(self.w * q)))
        temper = min(1.0, c.effective_beams / max(len(beams), 1))
        logw = np.log(np.maximum(self.w, 1e-300)) + temper * ll
        self.w = mcl.normalize(logw)
        self.updates += 1
        lost = self.found and self.rec.ratio < c.lost_ratio
        if self.updates % c.resample_interval == 0 or lost:
            self.resample(lost)

    def decide(self, est, update: bool, windowed: bool, conv, unique=None) -> bool:
        """Whether the scan's pose is claimed (tracking), and the filter's state moved on accordingly. `unique`: the
        test a new claim at a pose must pass (mapping/localize_claim.py; None: none)."""
        c = self.cfg
        # a pose is first claimed when the whole set has been tight for converged_updates filter updates in a row;
        # it is held, or claimed again after being lost, while one mode holds most of the weight, tight: augmented
        # MCL's random particles (a share p_random of the set) lie beside it, so the share asked is less by as much
        fits = self.rec.ratio >= c.lost_ratio
        whole = est.spread_xy <= conv.xy and est.spread_yaw <= conv.yaw and fits
        mode = est.mode_weight >= c.converged_share * (1.0 - self.rec.p_random) and fits
        held = mode and est.mode_xy <= conv.xy and est.mode_yaw <= conv.yaw
        if update:
            self.tight = self.tight + 1 if (held if self.found else whole) else 0
        if not windowed:
            claim = self.tight >= c.converged_updates
            if claim and not (held and self.tracking) and unique is not None and not unique(est.pose):
                claim, self.tight = False, 0  # another place fits as well: a look-alike, no claim yet
            converged = (held and self.tracking) or claim
        else:  # claimed first, and after a restart, only where the window's search confirms it. A claimed pose is
            # kept while the scans fit as well as they did (w_fast/w_slow), however the particles spread: along a
            # corridor the narrow scan sees two parallel walls, and the odometry's noise spreads them along it, in
            # one mode or several, until a crossing wall is in view; a wrong pose shows in the measurements, in the
            # readings through walls and in the window's checks
            converged = (fits and self.tracking) or self.confirmed or (
                self.found and not self.restarted and self.tight >= c.converged_updates)
        self.confirmed = False
        self.tracking = converged
        if converged and (not self.found or self.restarted):
            # from here the long-term average is the tracking one, not the search's
            self.restarted = False
            self.rec.w_slow = self.rec.w_fast
        if converged:
            self.found = True
            self.lost_since = -1
        return converged

    def resample(self, lost: bool) -> None:
        c = self.cfg
        searching = not self.found or lost or self.restarted
        n_max = self.global_n if searching else c.max_particles
        parts = mcl.kld_resample(self.parts, self.w, self.rec.p_random, self.f, c.min_particles, n_max, c.kld_err,
                                 c.kld_z, c.bin_xy, math.radians(c.bin_yaw_deg), self.rng)
        if lost and (self.lost_since < 0 or self.updates - self.lost_since >= 10):
            # lost: a global set beside the survivors (re-seeded every 10 updates while lost)
            self.lost_since = self.updates
            parts = np.concatenate((parts, self.f.sample_free(self.global_n, self.rng)))
        self.parts = parts
        self.w = np.full(len(parts), 1.0 / len(parts))


def localize(inp, f: MapField, cfg: LocalizeConfig, initial_pose: np.ndarray | None = None,
             progress=None) -> LocalizeResult:
    """Localize every scan of `inp` (mapping/locinput.py LocalizationInput) in the map `f`."""
    t_start = time.perf_counter()
    rng = np.random.default_rng(cfg.seed)
    # the window widens a narrow depth camera's view; a laser's scan is wide by itself, and its filter's own claim
    # (the whole set tight for converged_updates) stands once the scan fits no other place (mapping/localize_claim.py)
    ws = WindowSearch(f, cfg) if inp.has_odom and initial_pose is None and inp.source == "kos" else None
    flt = _Filter(f, cfg, rng, None if initial_pose is None else np.asarray(initial_pose, float), ws is not None)
    # a laser's tight set may hold a look-alike: its claim must be the one place the scan fits (a narrow camera's
    # single view without odometry is that rarely; with odometry its window's search decides)
    uq = ClaimCheck(f, cfg) if ws is None and initial_pose is None and inp.source == "laser" else None
    n = len(inp.stamps_ns)
    out = {k: np.zeros(n) for k in ("sx", "sy", "share", "score", "inl", "np", "ratio")}
    poses = np.zeros((n, 3))
    fposes = np.zeros((n, 3))
    status = np.zeros(n, np.int8)
    snaps: list[Snapshot] = []
    searches: list[Places] = []
    min_a = math.radians(cfg.update_min_a_deg)
    conv = _Tight(cfg, inp.has_odom)
    est = mcl.estimate(flt.parts, flt.w)
    u_last = inp.odom[0] if inp.has_odom else None
    t_last = inp.stamps[0]
    tracked: np.ndarray | None = None
    for i in range(n):
        pts = inp.points[i]
        u = inp.odom[i] if inp.has_odom else None
        gap = i > 0 and inp.stamps[i] - inp.stamps[i - 1] > cfg.max_gap_s
        if gap:
            flt.restart()
            if ws is not None:  # the window is kept (the wheel odometry bridges the gap; were the robot carried
                ws.sure = None  # meanwhile, it fits nowhere), but the place must be found sure twice anew
        if inp.has_odom:
            d = se2.between(u_last, u)
            update = i == 0 or gap or math.hypot(d[0], d[1]) >= cfg.update_min_d or abs(d[2]) >= min_a
        else:  # no odometry: an update every no_odom_period_s, the particles diffused for the time since
            update = i == 0 or gap or inp.stamps[i] - t_last >= cfg.no_odom_period_s
        if update and len(pts) >= cfg.min_points:
            if inp.has_odom:
                flt.move(u_last, u)
                u_last = u
            else:
                flt.diffuse(inp.stamps[i] - t_last)
            t_last = inp.stamps[i]
            est, tracked, v = _update(flt, ws, pts, u, tracked)
            if v is not None:
                searches.append(Places.of(float(inp.stamps[i] - inp.stamps[0]), v.poses, v.prob, v.claim))
            if cfg.mcap_particles:
                k = min(cfg.mcap_particles, len(flt.parts))
                sel = mcl.low_variance(flt.w, k, rng)  # drawn by weight: what the posterior looks like
                snaps.append(Snapshot(int(inp.stamps_ns[i]), flt.parts[sel].astype(np.float32)))
        pose_f = se2.compose(est.pose, se2.between(u_last, u)) if inp.has_odom else est.pose.copy()
        converged = flt.decide(est, update, ws is not None, conv,
                               None if uq is None else (lambda p, pts=pts, t=float(inp.stamps[i] - inp.stamps[0]):
                                                         _claim_unique(uq, flt, pts, p, searches, t)))
        status[i] = TRACKING if converged else (LOST if flt.found else SEARCHING)
        pose = pose_f
        if converged and cfg.refine and len(pts) >= cfg.min_points:
            pose, tracked, lost = _track(f, cfg, flt, inp, i, pose_f, est, tracked, conv, jump_test(
                f, cfg, None if ws is None else ws.window, u))
            if lost:
                ws.reset() if ws is not None else None
                status[i] = LOST
        elif converged and cfg.refine and tracked is not None and inp.has_odom and i > 0:
            # too few end points to match (a camera facing open space beyond its range): the track moved on by the
            # odometry, as the filter's pose is; restarted at the filter's pose it took that pose's error (the
            # atrium test world: single scans 0.3-1 m and 7-55 degrees off)
            tracked = se2.compose(tracked, se2.between(inp.odom[i - 1], u))
            pose = tracked
        else:
            tracked = None
        poses[i], fposes[i] = pose, pose_f
        p64 = np.ascontiguousarray(pts, dtype=np.float64)
        out["score"][i] = f_score(f, p64, pose)
        out["inl"][i] = inlier_fraction(f.match, f.origin[0], f.origin[1], f.resolution, p64, pose, math.exp(-0.5)) if len(p64) else 0.0
        out["sx"][i], out["sy"][i], out["share"][i] = est.spread_xy, est.spread_yaw, est.mode_weight
        out["np"][i], out["ratio"][i] = len(flt.parts), flt.rec.ratio
        if progress is not None:
            progress(float(inp.stamps[i] - inp.stamps[0]), inp.duration_s)
    return LocalizeResult(inp.stamps_ns, poses, fposes, out["sx"], out["sy"], out["score"], out["inl"],
                          out["np"].astype(int), out["ratio"], out["share"], status, snaps, searches, flt.updates,
                          time.perf_counter() - t_start)


def _claim_unique(uq: ClaimCheck, flt: _Filter, pts: np.ndarray, pose: np.ndarray, searches: list, t_s: float) -> bool:
    """The laser claim's uniqueness test (mapping/localize_claim.py), its places reported with the window's searches.
    A scan with fewer than min_points end points (one the filter does not weigh) cannot single out a place: no claim
    on it."""
    if len(pts) < uq.cfg.min_points:
        return False
    u = unique_or_reseed(uq, flt, pts, pose)
    searches.append(Places.of(t_s, u.poses, u.prob, u.unique))
    return u.unique


class _Tight:
    """How tight the particles must be for a pose to count as found."""

    def __init__(self, cfg: LocalizeConfig, has_odom: bool) -> None:
        self.yaw = math.radians(cfg.converged_yaw_deg)
        self.xy = cfg.converged_xy
        if not has_odom:  # a set diffused by the random walk at each update is at least that wide (√2 σ in x and y)
            self.xy = math.hypot(self.xy, math.sqrt(2.0) * cfg.no_odom_sigma_xy * cfg.no_odom_period_s)


def _update(flt: _Filter, ws: WindowSearch | None, pts: np.ndarray, u, tracked):
    """One filter update on a scan (the particles already moved): the measurement, and with the window, its search
    while no pose is held or its check while one is. The new estimate, the refined track (None: restarted) and the
    search's verdict (None: no search)."""
    if ws is None or flt.found:  # the first pose is the window search's claim: until then the set is its places
        flt.measure(pts)  # (Filter.apply), and weighing them by one scan would add nothing
    est = mcl.estimate(flt.parts, flt.w)
    v = None
    if ws is not None:
        ws.window.add(u, pts)
        if not flt.tracking and ws.due():
            v = ws.search(flt.z_max)
            flt.apply(v)
            est = mcl.estimate(flt.parts, flt.w)
        elif flt.tracking and ws.check_due() and ws.check(flt.z_max, est.pose if tracked is None else tracked):
            flt.restart()  # carried: the next search, due now, claims the checks' place if sure again
            tracked = None
    return est, tracked, v


def _track(f: MapField, cfg: LocalizeConfig, flt: _Filter, inp, i: int, pose_f: np.ndarray, est, tracked, conv: _Tight,
           jump=None):
    """The refined pose of scan i (the filter holds a pose): from the track's own prediction while it stays within
    refine_gate_sigmas of the filter's, else restarted at the filter's. Also (pose, track, lost): lost when its
    readings have passed through the map's walls for lost_through_s (kidnapped, or wrong from the start)."""
    pts, u = inp.points[i], (inp.odom[i] if inp.has_odom else None)
    pred, coarse = pose_f, True
    if tracked is not None:
        pt = se2.compose(tracked, se2.between(inp.odom[i - 1], u)) if inp.has_odom else tracked
        gate_xy = max(cfg.refine_gate_sigmas * est.mode_xy, cfg.converged_xy)
        gate_yaw = max(cfg.refine_gate_sigmas * est.mode_yaw, conv.yaw)
        near = math.hypot(pt[0] - pose_f[0], pt[1] - pose_f[1]) <= gate_xy and abs(se2.wrap(pt[2] - pose_f[2])) <= gate_yaw
        # and, with the window, moved to the filter's mode only where more than one scan refutes the track or the window
        # is sure of the mode (mapping/localize_claim.py jump_test)
        if near or _track_holds(f, cfg, pts, pt) or (jump is not None and not jump(pt, pose_f)):
            pred, coarse = pt, False
    pose = _refine(f, cfg, pts, pred, _moving(inp.odom[i - 1], u) if u is not None and i > 0 else None, coarse,
                   cfg.refine_prior_laser if inp.source == "laser" else None)
    if cfg.lost_through < 1.0 and mcl.through_fraction(f, pose, pts, cfg.through_tol) > cfg.lost_through:
        flt.bad_since = inp.stamps[i] if flt.bad_since is None else flt.bad_since
        if inp.stamps[i] - flt.bad_since >= cfg.lost_through_s:
            flt.restart()
            flt.bad_since = None
            return pose, None, True
    else:
        flt.bad_since = None
    return pose, pose, False


def _track_holds(f: MapField, cfg: LocalizeConfig, pts: np.ndarray, track: np.ndarray) -> bool:
    """Whether the track's pose still holds though the filter's mode lies far from it: its readings do not pass
    through the map's walls (lost_through at through_tol, the kidnapping test). The particles spread along a corridor
    or over a look-alike place in several modes, and the heaviest one can jump between them on one scan's noise;
    the track follows it only when its own readings refute it. With the walls test off (lost_through = 1) nothing
    refutes it and the track follows the mode."""
    return cfg.lost_through < 1.0 and mcl.through_fraction(f, track, pts, cfg.through_tol) <= cfg.lost_through


def _moving(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The direction of travel between two odometry poses, or None when the robot turned in place."""
    d = se2.between(a, b)
    return d if math.hypot(d[0], d[1]) > 1e-3 else None


def _refine(f: MapField, cfg: LocalizeConfig, pts: np.ndarray, pred: np.ndarray, step, coarse: bool = True,
            uniform: float | None = None) -> np.ndarray:
    """Gauss–Newton of the scan against the map's field from `pred`, pulled towards it: refine_prior_along along the
    direction of travel (refine_prior_xy when turning in place), refine_prior_xy across it. `coarse`: from the
    filter's pose, a correlative search first, then the pose whose rays pass through the fewest walls; from the
    track's own prediction, which the odometry of one step hardly moves, directly; both at the fine levels only
    (2σ, σ), so that furniture the map lacks has less pull. `uniform`: this weight in every direction instead."""
    yaw = pred[2] + (math.atan2(step[1], step[0]) if step is not None else 0.0)
    c, s = math.cos(yaw), math.sin(yaw)
    along = cfg.refine_prior_along if step is not None else cfg.refine_prior_xy
    r = np.array([[c, -s], [s, c]])
    w = np.zeros((3, 3))
    w[:2, :2] = r @ np.diag([along, cfg.refine_prior_xy]) @ r.T
    w[2, 2] = cfg.refine_prior_yaw
    if uniform is not None:  # a wide scan: the same weak pull in every direction
        w = np.eye(3) * uniform
    p64 = np.ascontiguousarray(pts, dtype=np.float64)
    pose = np.asarray(pred, float)
    if coarse and cfg.refine_search > 0:
        # from the filter's pose, a few particles' spacing off: the best alignment within ±refine_search first
        # (Olson's correlative search, frontend/matcher.py), then Gauss–Newton from there
        pose, _ = correlative_search(f.match_coarse, f.origin[0], f.origin[1], f.resolution, p64, pose,
                                     cfg.refine_search, f.resolution, math.radians(cfg.refine_search_deg),
                                     math.radians(1.0), 0.0, 0.0)
    fine = ((f.match_coarse, 2 * cfg.match_sigma), (f.match, cfg.match_sigma))  # the fine levels (2σ, σ)

    def match(pose: np.ndarray, towards: np.ndarray = np.asarray(pred, float)) -> np.ndarray:
        for fld, sigma in fine:
            pose, _, _ = gauss_newton(fld, f.origin[0], f.origin[1], f.resolution, p64, pose, towards, w, 10, True,
                                      sigma)
        return pose

    if coarse:  # a (re)started track: from the pose whose rays pass through the fewest walls
        pose = _near_face(f, cfg, p64, pose)
    pose = match(pose)
    # the matcher's field peaks at both faces of a wall (a blueprint's wall is a band of cells): a pose a wall's
    # thickness off fits it about as well, its rays ending on the far face, and the prior towards the prediction
    # holds it there. When more than lost_through of the rays pass a map cell through a wall, the match starts
    # again from the nearby pose whose rays pass through the fewest walls
    if mcl.through_fraction(f, pose, p64, f.resolution) > cfg.lost_through:
        start = _near_face(f, cfg, p64, pose)
        pose = match(start)
        if uniform is None and mcl.through_fraction(f, pose, p64, f.resolution) > cfg.lost_through:
            # the narrow scan's pull towards the prediction (refine_prior_xy) holds the match on the far face still:
            # a pose whose readings pass through the walls is impossible whatever the prediction, so the match is
            # pulled towards the pose whose rays pass through the fewest walls instead. A wide scan's weak pull
            # (`uniform`) holds nothing there, and in a map built by SLAM, with cells a laser sees through, pulling
            # towards that pose moved the Intel log's track up to 1 m
            pose = match(start, start)
    return pose


def _near_face(f: MapField, cfg: LocalizeConfig, pts: np.ndarray, pose: np.ndarray) -> np.ndarray:
    """The pose within ±refine_search (map cells apart, ±2°) whose rays pass through the fewest walls (the likelihood
    field with each ray traced, a cell's tolerance): the matcher's field peaks at both faces of a wall, and a pose a
    wall's thickness off fits it as well, its rays ending on the far face."""
    k = int(round(cfg.refine_search / f.resolution))
    d = np.arange(-k, k + 1) * f.resolution
    a = np.radians(np.arange(-2.0, 2.5, 1.0))
    gx, gy, ga = np.meshgrid(d, d, a, indexing="ij")
    grid = pose + np.column_stack((gx.ravel(), gy.ravel(), ga.ravel()))
    ll = mcl.log_likelihoods(f, grid, mcl.beam_subset(pts, 4 * cfg.max_beams), through_floor(cfg, z_max_of(f, cfg)),
                             f.resolution)
    best = np.flatnonzero(ll >= ll.max() - 1e-9)
    return grid[best[np.argmin(np.hypot(grid[best, 0] - pose[0], grid[best, 1] - pose[1]))]]


def f_score(f: MapField, pts: np.ndarray, pose: np.ndarray) -> float:
    """Mean matcher field value of the end points at `pose`."""
    from kosmap.frontend.matcher import mean_score

    return float(mean_score(f.match, f.origin[0], f.origin[1], f.resolution, pts, np.asarray(pose, float))) if len(pts) else 0.0


def load_map(path, scale: float | None = None):
    """A map_server YAML (a build's map_*.yaml, any map_saver map) or a plain blueprint image with `scale` m/pixel."""
    from pathlib import Path

    from kosmap.mapping.mapio import read_blueprint, read_map_server

    p = Path(path)
    if p.suffix.lower() in (".yaml", ".yml"):
        if scale is not None:
            raise LocalizeError(f"{p} is a map_server YAML with its own resolution; drop --map-scale")
        return read_map_server(p)
    if scale is None and p.is_file():
        raise LocalizeError(f"--map {p} is a plain image: give its scale in metres per pixel with --map-scale, or a "
                            f"map_server .yaml that names it with its resolution")
    return read_blueprint(p, scale)


def parse_pose(text: str) -> np.ndarray:
    """"x,y,yaw" (metres, metres, degrees) → (x, y, yaw in radians)."""
    try:
        v = [float(t) for t in text.split(",")]
    except ValueError:
        v = []
    if len(v) != 3 or not all(math.isfinite(t) for t in v):
        raise LocalizeError(f"--initial-pose {text!r} must be x,y,yaw: metres, metres and degrees, e.g. 1.2,1.4,0")
    return np.array([v[0], v[1], math.radians(v[2])])


def check_initial_pose(f: MapField, pose: np.ndarray) -> None:
    if not f.is_free(pose[None, :2])[0]:
        where = "in a wall" if f.is_occupied(pose[None, :2])[0] else "outside the map's free space"
        raise LocalizeError(f"--initial-pose ({pose[0]:g}, {pose[1]:g}) lies {where}; give a pose in the map's frame "
                            f"where the robot stood at the log's start")


TRUTH_IN_MAP_MIN = 0.8  # share of the ground truth that must lie in the map's free space (or near its walls)


def check_truth_frame(f: MapField, truth) -> None:
    """The log's ground truth must lie in the map's free space: a map in another frame (a SLAM map starts at the
    robot's first pose, the truth in the building's) would be scored against the wrong poses."""
    _, pg = truth
    xy = np.asarray(pg)[:, :2][:: max(1, len(pg) // 500)]
    inside = f.is_free(xy) | f.is_occupied(xy)
    if inside.mean() < TRUTH_IN_MAP_MIN:
        raise LocalizeError(f"the log's ground truth lies outside the map's free space at {100 * (1 - inside.mean()):.0f} % "
                            f"of its poses: the map is in another frame than the truth; give a map in the truth's "
                            f"(building's) frame, or --no-truth to localize without scoring")
