"""A global correlative search of a local submap (several scans stitched by odometry) over a whole map.

Olson, "Real-time correlative scan matching" (ICRA 2009), its multi-resolution form: every pose on a coarse grid over
the map's free cells and all headings is scored against a field blurred to the grid's spacing (so that the right pose
cannot fall between grid points unscored), the best distinct local maxima are kept, and each is re-searched on a fine
grid with a sharp field around it. A narrow depth camera's single scan fits many places of a building; a submap of
several metres of travel is a wider view, and the search over it sees every place it fits, where a particle filter
keeps only the places its particles happen to cover.

Written here rather than taken from `backend/loops.py`: that search matches a scan against one SLAM submap within a
window around a guess; this one scores a submap against the whole map with no guess.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numba import njit

from kosmap.backend.mcl import _through_wall, log_likelihoods


@dataclass
class SearchField:
    """exp(−d²/2σ²) of the distance d to the nearest wall at three blurs over the map's cells; the poses allowed."""

    coarsest: np.ndarray  # H×W float32, σ = twice the coarse grid's spacing (the first, widest pass)
    coarse: np.ndarray  # H×W float32, σ = the coarse grid's spacing
    fine: np.ndarray  # H×W float32, σ = the fine grid's spacing
    free: np.ndarray  # H×W bool
    origin: tuple[float, float]
    resolution: float
    step_xy: float  # the coarse grid's spacing, m


def search_field(distance: np.ndarray, free: np.ndarray, origin, resolution: float, step_xy: float,
                 fine_xy: float) -> SearchField:
    d = np.minimum(distance, 1e3)
    coarse = np.exp(-0.5 * (d / step_xy) ** 2).astype(np.float32)
    coarsest = np.exp(-0.5 * (d / (2 * step_xy)) ** 2).astype(np.float32)
    fine = np.exp(-0.5 * (d / fine_xy) ** 2).astype(np.float32)
    return SearchField(np.ascontiguousarray(coarsest), np.ascontiguousarray(coarse), np.ascontiguousarray(fine), free,
                       (float(origin[0]), float(origin[1])), float(resolution), float(step_xy))


@njit(cache=True)
def _score_grid(field, ox, oy, res, xs, ys, yaws, pts, out):
    """out[a, j] = mean field value of `pts` rotated by yaws[a] and moved to (xs[j], ys[j])."""
    h, w = field.shape
    n = pts.shape[0]
    rot = np.empty((n, 2))
    for a in range(len(yaws)):
        c = math.cos(yaws[a])
        s = math.sin(yaws[a])
        for k in range(n):
            rot[k, 0] = c * pts[k, 0] - s * pts[k, 1]
            rot[k, 1] = s * pts[k, 0] + c * pts[k, 1]
        for j in range(len(xs)):
            acc = 0.0
            for k in range(n):
                ix = int(math.floor((xs[j] + rot[k, 0] - ox) / res))
                iy = int(math.floor((ys[j] + rot[k, 1] - oy) / res))
                if ix >= 0 and iy >= 0 and ix < w and iy < h:
                    acc += field[iy, ix]
            out[a, j] = acc / max(n, 1)


@njit(cache=True)
def _score_poses(field, ox, oy, res, poses, pts, out):
    """out[j] = mean field value of `pts` at poses[j]."""
    h, w = field.shape
    n = pts.shape[0]
    for j in range(poses.shape[0]):
        c = math.cos(poses[j, 2])
        s = math.sin(poses[j, 2])
        acc = 0.0
        for k in range(n):
            ix = int(math.floor((poses[j, 0] + c * pts[k, 0] - s * pts[k, 1] - ox) / res))
            iy = int(math.floor((poses[j, 1] + s * pts[k, 0] + c * pts[k, 1] - oy) / res))
            if ix >= 0 and iy >= 0 and ix < w and iy < h:
                acc += field[iy, ix]
        out[j] = acc / max(n, 1)


def _poses_on_grid(sf: SearchField, step: float) -> tuple[np.ndarray, np.ndarray]:
    """Centres of a `step` grid over the map whose cell is free."""
    h, w = sf.free.shape
    k = max(int(round(step / sf.resolution)), 1)
    rows = np.arange(k // 2, h, k)
    cols = np.arange(k // 2, w, k)
    rr, cc = np.meshgrid(rows, cols, indexing="ij")
    ok = sf.free[rr, cc]
    xs = sf.origin[0] + (cc[ok] + 0.5) * sf.resolution
    ys = sf.origin[1] + (rr[ok] + 0.5) * sf.resolution
    return xs.astype(np.float64), ys.astype(np.float64)


@dataclass
class Candidate:
    pose: np.ndarray  # (3,) x, y, yaw in the map
    score: float  # mean fine-field value of the submap at the pose


def yaw_step_for(pts: np.ndarray, step_xy: float) -> float:
    """The heading step that moves the submap's farthest point by at most one grid spacing."""
    r = float(np.max(np.hypot(pts[:, 0], pts[:, 1]))) if len(pts) else 1.0
    return min(step_xy / max(r, step_xy), math.radians(10.0))


def global_search(sf: SearchField, pts: np.ndarray, keep: int, apart_xy: float, apart_yaw: float,
                  fine_xy: float) -> list[Candidate]:
    """The `keep` best distinct poses of the submap `pts` (N×2 in its own frame) over the whole map, best first.

    Pass 1 scores a grid of twice the coarse spacing (and a field blurred by as much, so one submap point per square of
    that size: nearer ones add nothing the blur tells apart) over every free cell and every heading (the step that
    moves the submap's farthest point by one coarse spacing); pass 2 re-scores the
    neighbourhoods of its best `keep`·50 poses at the coarse spacing and keeps the best that lie at least `apart_xy`
    or `apart_yaw` from every better one; each is then searched on a `fine_xy` grid (Olson 2009's multi-resolution
    search, without its guarantee: a blurred field ranks poses, it does not bound them)."""
    p = np.ascontiguousarray(pts, dtype=np.float64)
    if len(p) == 0:
        return []
    step = sf.step_xy
    xs, ys = _poses_on_grid(sf, 2 * step)
    dyaw = yaw_step_for(p, step)
    yaws = np.arange(-math.pi, math.pi, dyaw)
    s1 = np.empty((len(yaws), len(xs)))
    _score_grid(sf.coarsest, sf.origin[0], sf.origin[1], sf.resolution, xs, ys, yaws,
                np.ascontiguousarray(p[thin(p, 2 * step)]), s1)
    a, j = np.divmod(np.argsort(s1, axis=None)[::-1][: keep * 50], len(xs))
    d = np.array([-1.0, 0.0, 1.0])
    off = np.stack(np.meshgrid(d * 0.5 * step, d * 0.5 * step, d * 0.5 * dyaw, indexing="ij"), -1).reshape(-1, 3)
    cand = (np.column_stack((xs[j], ys[j], yaws[a]))[:, None, :] + off[None]).reshape(-1, 3)
    cand = cand[_free_at(sf, cand)]
    s2 = np.empty(len(cand))
    _score_poses(sf.coarse, sf.origin[0], sf.origin[1], sf.resolution, cand,
                 np.ascontiguousarray(p[thin(p, 0.5 * step)]), s2)
    fy = yaw_step_for(p, fine_xy)
    out = [_fine(sf, p, c, fine_xy, fy, 0.5 * dyaw) for c in _distinct(cand, s2, keep, apart_xy, apart_yaw)]
    out.sort(key=lambda k: -k.score)
    return out


def _distinct(cand: np.ndarray, score: np.ndarray, keep: int, apart_xy: float, apart_yaw: float) -> list[np.ndarray]:
    """The best-scoring poses, each at least apart_xy or apart_yaw from every better one kept (non-maximum
    suppression), at most `keep`."""
    c = np.ascontiguousarray(cand[np.argsort(score)[::-1]], dtype=np.float64)
    return list(c[_suppress(c, keep, apart_xy, apart_yaw)])


@njit(cache=True)
def _suppress(c, keep, apart_xy, apart_yaw):
    """Indices (into c, best first) of the poses kept by non-maximum suppression."""
    out = np.empty(keep, np.int64)
    m = 0
    for i in range(c.shape[0]):
        ok = True
        for k in range(m):
            j = out[k]
            dyaw = abs((c[i, 2] - c[j, 2] + math.pi) % (2 * math.pi) - math.pi)
            if math.hypot(c[i, 0] - c[j, 0], c[i, 1] - c[j, 1]) < apart_xy and dyaw < apart_yaw:
                ok = False
                break
        if ok:
            out[m] = i
            m += 1
            if m >= keep:
                break
    return out[:m]


def _free_at(sf: SearchField, poses: np.ndarray) -> np.ndarray:
    c = np.floor((poses[:, 0] - sf.origin[0]) / sf.resolution).astype(np.int64)
    r = np.floor((poses[:, 1] - sf.origin[1]) / sf.resolution).astype(np.int64)
    h, w = sf.free.shape
    ok = (c >= 0) & (r >= 0) & (c < w) & (r < h)
    ok[ok] = sf.free[r[ok], c[ok]]
    return ok


def _fine(sf: SearchField, p: np.ndarray, c: np.ndarray, step: float, dyaw: float, yaw_window: float) -> Candidate:
    n = int(math.ceil(0.5 * sf.step_xy / step))
    off = np.arange(-n, n + 1) * step
    gx, gy = np.meshgrid(c[0] + off, c[1] + off, indexing="ij")
    xs, ys = gx.ravel().astype(np.float64), gy.ravel().astype(np.float64)
    na = int(math.ceil(yaw_window / dyaw))
    yaws = c[2] + np.arange(-na, na + 1) * dyaw
    scores = np.empty((len(yaws), len(xs)))
    _score_grid(sf.fine, sf.origin[0], sf.origin[1], sf.resolution, xs, ys, yaws, p, scores)
    a, j = np.unravel_index(int(np.argmax(scores)), scores.shape)
    return Candidate(np.array([xs[j], ys[j], math.remainder(yaws[a], 2 * math.pi)]), float(scores[a, j]))


def posterior(loglik: np.ndarray) -> np.ndarray:
    """Normalised probabilities of candidates from their (tempered) log-likelihoods."""
    ll = np.asarray(loglik, float)
    m = np.max(ll)
    if not np.isfinite(m):
        return np.full(len(ll), 1.0 / max(len(ll), 1))
    w = np.exp(ll - m)
    return w / w.sum()


def thin(pts: np.ndarray, cell: float) -> np.ndarray:
    """Indices of one point per `cell`-metre square (the first in order): a submap whose overlapping scans see a wall
    many times counts each piece of wall once."""
    if len(pts) == 0:
        return np.zeros(0, np.int64)
    key = np.floor(np.asarray(pts)[:, :2] / cell).astype(np.int64)
    _, first = np.unique(key[:, 0] * 1_000_003 + key[:, 1], return_index=True)
    return np.sort(first)


def window_loglik(field, poses: np.ndarray, pts: np.ndarray, views: np.ndarray, through: float,
                  tol: float) -> np.ndarray:
    """The likelihood field model's Σ log p of a submap's end points `pts` at each pose, each point's ray traced for
    the through-wall test from where it was seen (`views`, the sensor's position per point in the submap's frame):
    mcl.log_likelihoods with the rays of several scans (its kernel, every point traced)."""
    return log_likelihoods(field, poses, pts, through, tol, views=views)


@njit(cache=True)
def _window_through(dist, ox, oy, res, pose, pts, views, tol):
    c = math.cos(pose[2])
    s = math.sin(pose[2])
    bad = 0
    for k in range(pts.shape[0]):
        qx = pose[0] + c * pts[k, 0] - s * pts[k, 1]
        qy = pose[1] + s * pts[k, 0] + c * pts[k, 1]
        vx = pose[0] + c * views[k, 0] - s * views[k, 1]
        vy = pose[1] + s * views[k, 0] + c * views[k, 1]
        if _through_wall(dist, ox, oy, res, vx, vy, qx, qy, math.hypot(qx - vx, qy - vy) - tol):
            bad += 1
    return bad / max(pts.shape[0], 1)


def window_through(field, pose: np.ndarray, pts: np.ndarray, views: np.ndarray, tol: float) -> float:
    """Share of the submap's end points whose ray (from where each was seen) passes more than `tol` through a wall."""
    if len(pts) == 0:
        return 0.0
    return float(_window_through(field.distance, field.origin[0], field.origin[1], field.resolution,
                                 np.asarray(pose, dtype=np.float64), np.ascontiguousarray(pts, dtype=np.float64),
                                 np.ascontiguousarray(views, dtype=np.float64), float(tol)))
