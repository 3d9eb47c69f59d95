"""Monte Carlo localization: the particle filter's pieces as pure functions over arrays (particles N×3 x, y, yaw).

After Thrun, Burgard & Fox, *Probabilistic Robotics* (2005) and ROS's AMCL, which implements it:
- `sample_motion_odometry`: the odometry motion model (Table 5.6), noise as AMCL's diff model (variances
  α1·δrot² + α2·δtrans² and α3·δtrans² + α4·(δrot1² + δrot2²), the rotations taken modulo a reversal).
- `log_likelihoods`: the likelihood field model (§6.4, Table 6.3) summed in log space over the end points, with the
  pose itself given zero likelihood off the map's free cells (a robot stands in free space), and a reading that
  passes through a wall (longer than the map allows, §6.3's beam model without its short-reading term) charged
  as a near-impossible one: a blueprint lacks the furniture, so short readings prove nothing, long ones do.
- `kld_resample`: KLD-sampling (Fox, "Adapting the sample size in particle filters through KLD-sampling", IJRR
  2003): draw until n ≥ (k−1)/2ε·(1 − 2/9(k−1) + √(2/9(k−1))·z)³ for the k histogram bins the draws occupy,
  each draw a uniform random pose with probability `p_random` (augmented MCL, Table 8.3) or a low-variance draw
  from the weighted set (Table 4.4).
- `Recovery`: augmented MCL's short- and long-term averages of the measurement likelihood, w_fast and w_slow.
- `estimate`: the pose of the heaviest mode (a weighted mean shift from the heaviest coarse cell), and the spread.

Written here rather than taken from a library: no maintained Python MCL offers KLD-sampling over a likelihood
field, and the inner loop (particles × end points) needs a compiled kernel to run ≥ 20× real time.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numba import njit
from scipy.stats import norm

from kosmap.frontend import se2


@njit(cache=True)
def _through_wall(dist, ox, oy, res, x, y, qx, qy, length):
    """True when the ray from (x, y) towards (qx, qy) meets an occupied cell within `length` metres: sphere
    tracing on the distance field (each step as long as the distance to the nearest wall, at least one cell)."""
    h, w = dist.shape
    r = math.hypot(qx - x, qy - y)
    if r <= 0.0 or length <= 0.0:
        return False
    dx = (qx - x) / r
    dy = (qy - y) / r
    t = 0.0
    for _ in range(256):
        if t >= length:
            return False
        ix = int(math.floor((x + t * dx - ox) / res))
        iy = int(math.floor((y + t * dy - oy) / res))
        if ix < 0 or iy < 0 or ix >= w or iy >= h:
            return False
        d = dist[iy, ix]
        if d <= 0.0:
            return True
        t += max(d, res)  # a wall is at least a cell thick: a step of one cell lands in it or short of it
    return False


@njit(cache=True)
def _log_likelihoods(table, dist, free, ox, oy, res, floor, through, tol, every, parts, pts, views, out):
    """out[p] = Σ_k log p(z_k | parts[p]): the field's value at each end point, `through` where the end point's ray
    meets a wall more than `tol` before it (traced for every `every`-th point), −inf off the free cells. The ray starts
    at the pose, or, with `views` (N×2, one row per point; an empty array: none), at views[k] in the pose's frame:
    where that point was seen from, for a submap of several scans (backend/globalsearch.py)."""
    h, w = table.shape
    n = pts.shape[0]
    has_views = views.shape[0] == n and n > 0
    for p in range(parts.shape[0]):
        x = parts[p, 0]
        y = parts[p, 1]
        cx = int(math.floor((x - ox) / res))
        cy = int(math.floor((y - oy) / res))
        if cx < 0 or cy < 0 or cx >= w or cy >= h or not free[cy, cx]:
            out[p] = -np.inf
            continue
        c = math.cos(parts[p, 2])
        s = math.sin(parts[p, 2])
        acc = 0.0
        for k in range(n):
            qx = x + c * pts[k, 0] - s * pts[k, 1]
            qy = y + s * pts[k, 0] + c * pts[k, 1]
            if through > -np.inf and k % every == 0:
                if has_views:
                    vx = x + c * views[k, 0] - s * views[k, 1]
                    vy = y + s * views[k, 0] + c * views[k, 1]
                    length = math.hypot(qx - vx, qy - vy) - tol
                else:
                    vx = x
                    vy = y
                    length = math.hypot(pts[k, 0], pts[k, 1]) - tol
                if _through_wall(dist, ox, oy, res, vx, vy, qx, qy, length):
                    acc += through
                    continue
            ix = int(math.floor((qx - ox) / res))
            iy = int(math.floor((qy - oy) / res))
            if ix >= 0 and iy >= 0 and ix < w and iy < h:
                acc += table[iy, ix]
            else:
                acc += floor
        out[p] = acc


@njit(cache=True)
def _through_fraction(dist, ox, oy, res, pose, pts, tol):
    c = math.cos(pose[2])
    s = math.sin(pose[2])
    n = pts.shape[0]
    bad = 0
    for k in range(n):
        qx = pose[0] + c * pts[k, 0] - s * pts[k, 1]
        qy = pose[1] + s * pts[k, 0] + c * pts[k, 1]
        if _through_wall(dist, ox, oy, res, pose[0], pose[1], qx, qy, math.hypot(pts[k, 0], pts[k, 1]) - tol):
            bad += 1
    return bad / max(n, 1)


def through_fraction(field, pose: np.ndarray, pts: np.ndarray, tol: float) -> float:
    """Share of the end points whose ray passes more than `tol` metres through a wall from `pose`: at the right pose
    next to none (a glass pane, an opening the map lacks), at a wrong one many."""
    if len(pts) == 0:
        return 0.0
    return float(_through_fraction(field.distance, field.origin[0], field.origin[1], field.resolution,
                                   np.asarray(pose, dtype=np.float64), np.ascontiguousarray(pts, dtype=np.float64),
                                   float(tol)))


_NO_VIEWS = np.zeros((0, 2))


def log_likelihoods(field, parts: np.ndarray, pts: np.ndarray, through: float = -np.inf, tol: float = 0.0,
                    every: int = 1, views: np.ndarray | None = None) -> np.ndarray:
    """Σ_k log p(z_k | x_p, m) of each particle (−inf where the particle is off the free cells). With `through`
    finite, an end point whose ray meets a wall more than `tol` before it (a reading longer than the map allows:
    the pose is wrong, or the map lacks an opening) scores `through` instead of the field's value; a reading shorter
    than the map allows (furniture, people) costs only the field's floor. The ray starts at the particle, or with
    `views` (N×2, in the particle's frame like `pts`) where each point was seen from."""
    out = np.empty(len(parts))
    v = _NO_VIEWS if views is None else np.ascontiguousarray(views, dtype=np.float64)
    if views is not None and v.shape != (len(pts), 2):
        raise ValueError(f"views must be one (x, y) per end point: {v.shape} for {len(pts)} points")
    _log_likelihoods(field.log_table, field.distance, field.free, field.origin[0], field.origin[1], field.resolution,
                     field.floor, float(through), float(tol), max(int(every), 1), np.ascontiguousarray(parts, dtype=np.float64),
                     np.ascontiguousarray(pts, dtype=np.float64), v, out)
    return out


def beam_subset(pts: np.ndarray, max_beams: int) -> np.ndarray:
    """At most `max_beams` end points spread evenly over the scan's order (AMCL's laser_max_beams)."""
    if len(pts) <= max_beams:
        return pts
    return pts[np.linspace(0, len(pts) - 1, max_beams).round().astype(int)]


def sample_motion_odometry(parts: np.ndarray, u0: np.ndarray, u1: np.ndarray, alphas: tuple[float, float, float, float],
                           rng: np.random.Generator) -> np.ndarray:
    """Each particle moved by the odometry step u0 → u1 with noise drawn per particle (Table 5.6, AMCL's variances)."""
    a1, a2, a3, a4 = alphas
    dx, dy = u1[0] - u0[0], u1[1] - u0[1]
    trans = math.hypot(dx, dy)
    rot1 = 0.0 if trans < 0.01 else float(se2.wrap(math.atan2(dy, dx) - u0[2]))  # AMCL: no heading of a tiny step
    rot2 = float(se2.wrap(u1[2] - u0[2] - rot1))
    # a step backwards is a small rotation and a reversal, not a half turn (AMCL's diff model)
    r1n = min(abs(rot1), abs(se2.wrap(rot1 - math.pi)))
    r2n = min(abs(rot2), abs(se2.wrap(rot2 - math.pi)))
    n = len(parts)
    rot1_h = rot1 - rng.normal(0.0, math.sqrt(a1 * r1n ** 2 + a2 * trans ** 2), n)
    trans_h = trans - rng.normal(0.0, math.sqrt(a3 * trans ** 2 + a4 * (r1n ** 2 + r2n ** 2)), n)
    rot2_h = rot2 - rng.normal(0.0, math.sqrt(a1 * r2n ** 2 + a2 * trans ** 2), n)
    out = np.empty_like(parts)
    h = parts[:, 2] + rot1_h
    out[:, 0] = parts[:, 0] + trans_h * np.cos(h)
    out[:, 1] = parts[:, 1] + trans_h * np.sin(h)
    out[:, 2] = se2.wrap(h + rot2_h)
    return out


def diffuse(parts: np.ndarray, sigma_xy: float, sigma_yaw: float, rng: np.random.Generator) -> np.ndarray:
    """A random walk: the motion model of a log without odometry."""
    out = parts + rng.normal(0.0, 1.0, parts.shape) * np.array([sigma_xy, sigma_xy, sigma_yaw])
    out[:, 2] = se2.wrap(out[:, 2])
    return out


def normalize(logw: np.ndarray) -> np.ndarray:
    """Weights summing to one from log weights (all −inf → uniform)."""
    m = np.max(logw)
    if not np.isfinite(m):
        return np.full(len(logw), 1.0 / len(logw))
    w = np.exp(logw - m)
    return w / w.sum()


def kld_bound(k: np.ndarray, err: float, z: float) -> np.ndarray:
    """Fox 2003, eq. 13: samples needed so that the K–L divergence to the true posterior stays below `err` with
    probability `z` when the samples occupy k bins (the Wilson–Hilferty approximation of the χ² quantile)."""
    k = np.asarray(k, float)
    zq = norm.ppf(z)
    km = np.maximum(k - 1.0, 1.0)
    a = 2.0 / (9.0 * km)
    return np.where(k > 1, km / (2.0 * err) * (1.0 - a + np.sqrt(a) * zq) ** 3, 1.0)


def bins_of(parts: np.ndarray, bin_xy: float, bin_yaw: float) -> np.ndarray:
    """A histogram bin id per particle (AMCL's pf bins: 0.5 m × 0.5 m × 10° by default)."""
    ix = np.floor(parts[:, 0] / bin_xy).astype(np.int64)
    iy = np.floor(parts[:, 1] / bin_xy).astype(np.int64)
    it = np.floor((parts[:, 2] + math.pi) / bin_yaw).astype(np.int64)
    return (ix * 1_000_003 + iy) * 1009 + it


def low_variance(weights: np.ndarray, n: int, rng: np.random.Generator) -> np.ndarray:
    """n indices drawn by low-variance (systematic) resampling (Table 4.4)."""
    cum = np.cumsum(weights)
    cum[-1] = 1.0
    u = (rng.random() + np.arange(n)) / n
    return np.searchsorted(cum, u)


def kld_resample(parts: np.ndarray, weights: np.ndarray, p_random: float, field, n_min: int, n_max: int,
                 err: float, z: float, bin_xy: float, bin_yaw: float, rng: np.random.Generator) -> np.ndarray:
    """A new, equally weighted set whose size KLD-sampling chooses (between n_min and n_max); each draw is a
    uniform random pose on the free cells with probability p_random, else a draw from the weighted set."""
    idx = low_variance(weights, n_max, rng)
    cand = parts[idx[rng.permutation(n_max)]]
    if p_random > 0:
        rand = rng.random(n_max) < p_random
        if rand.any():
            cand[rand] = field.sample_free(int(rand.sum()), rng)
    _, first = np.unique(bins_of(cand, bin_xy, bin_yaw), return_index=True)
    new_bin = np.zeros(n_max, bool)
    new_bin[first] = True
    k = np.cumsum(new_bin)  # bins occupied by the first i + 1 draws
    need = np.maximum(kld_bound(k, err, z), n_min)
    ok = np.flatnonzero(np.arange(1, n_max + 1) >= need)
    n = int(ok[0]) + 1 if len(ok) else n_max
    return cand[:n].copy()


@dataclass
class Estimate:
    """The filter's pose and how sure it is."""

    pose: np.ndarray  # (3,) weighted mean of the heaviest mode
    spread_xy: float  # √(trace of the whole set's position covariance), m
    spread_yaw: float  # circular standard deviation of the whole set's headings, rad
    mode_weight: float  # share of the weight in the mode
    mode_xy: float = 0.0  # √(trace of the mode's position covariance), m
    mode_yaw: float = 0.0  # standard deviation of the mode's headings, rad


def estimate(parts: np.ndarray, weights: np.ndarray, radius: float = 0.5, yaw_radius: float = math.radians(30),
             cell: float = 1.0) -> Estimate:
    """The heaviest mode's weighted mean (mean shift started at the heaviest `cell`-metre cell) and the spread."""
    w = weights / weights.sum()
    mx, my = np.sum(w * parts[:, 0]), np.sum(w * parts[:, 1])
    spread_xy = math.sqrt(max(np.sum(w * ((parts[:, 0] - mx) ** 2 + (parts[:, 1] - my) ** 2)), 0.0))
    rbar = math.hypot(np.sum(w * np.cos(parts[:, 2])), np.sum(w * np.sin(parts[:, 2])))
    spread_yaw = math.sqrt(-2.0 * math.log(min(max(rbar, 1e-12), 1.0)))
    key = np.floor(parts[:, :2] / cell).astype(np.int64)
    uk, inv = np.unique(key[:, 0] * 1_000_003 + key[:, 1], return_inverse=True)
    best = np.argmax(np.bincount(inv.ravel(), weights=w, minlength=len(uk)))
    sel = inv.ravel() == best
    yaw0 = math.atan2(np.sum(w[sel] * np.sin(parts[sel, 2])), np.sum(w[sel] * np.cos(parts[sel, 2])))
    c = np.array([np.sum(w[sel] * parts[sel, 0]) / w[sel].sum(), np.sum(w[sel] * parts[sel, 1]) / w[sel].sum(), yaw0])
    share = 0.0
    near = np.zeros(len(w), bool)
    for _ in range(5):
        near = ((parts[:, 0] - c[0]) ** 2 + (parts[:, 1] - c[1]) ** 2 <= radius ** 2) & \
               (np.abs(se2.wrap(parts[:, 2] - c[2])) <= yaw_radius)
        wn = w[near]
        if wn.sum() <= 0:
            break
        share = float(wn.sum())
        yaw = c[2] + math.atan2(np.sum(wn * np.sin(parts[near, 2] - c[2])), np.sum(wn * np.cos(parts[near, 2] - c[2])))
        c = np.array([np.sum(wn * parts[near, 0]) / share, np.sum(wn * parts[near, 1]) / share, float(se2.wrap(yaw))])
    mode_xy = mode_yaw = 0.0
    if share > 0:
        wn = w[near] / share
        mode_xy = math.sqrt(max(np.sum(wn * ((parts[near, 0] - c[0]) ** 2 + (parts[near, 1] - c[1]) ** 2)), 0.0))
        mode_yaw = math.sqrt(max(np.sum(wn * se2.wrap(parts[near, 2] - c[2]) ** 2), 0.0))
    return Estimate(c, spread_xy, spread_yaw, share, mode_xy, mode_yaw)


@dataclass
class Recovery:
    """Augmented MCL (Table 8.3): long- and short-term averages of the measurement likelihood; a random pose is
    drawn with probability max(0, 1 − w_fast/w_slow). AMCL's recovery_alpha_slow/fast."""

    alpha_slow: float
    alpha_fast: float
    w_slow: float = 0.0
    w_fast: float = 0.0

    def update(self, w_avg: float) -> None:
        if self.w_slow == 0.0:  # AMCL starts both at the first average
            self.w_slow = self.w_fast = w_avg
            return
        self.w_slow += self.alpha_slow * (w_avg - self.w_slow)
        self.w_fast += self.alpha_fast * (w_avg - self.w_fast)

    @property
    def ratio(self) -> float:
        return self.w_fast / self.w_slow if self.w_slow > 0 else 1.0

    @property
    def p_random(self) -> float:
        return max(0.0, 1.0 - self.ratio)
