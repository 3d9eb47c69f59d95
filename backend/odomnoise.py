"""The wheel odometry's noise, measured while running: the odometry's motion between consecutive graph nodes against
the scan matcher's, where the matcher saw the motion on its own (no direction held to the odometry, no recovery).

Model (Thrun et al., Probabilistic Robotics §5.4, the odometry motion model; Borenstein & Feng 1996, UMBmark, for the
systematic part): over a node interval the matcher moved d metres and turned Δθ; the odometry's along-track translation
is off by s·d + n_t with n_t ~ N(0, σ_t²·d), and its yaw by h·d + k·Δθ + n_θ with n_θ ~ N(0, σ_θ²·d + σ_r²·|Δθ|):
s the scale error (wheel radius), h the heading drift per metre (unequal wheels, a heading bias), k the rotation scale
error (wheel base), σ_t, σ_θ, σ_r the random parts per √m and √rad (a random walk over the distance, so per √m).

Robust over a sliding window of the latest WINDOW intervals: the systematic parts are medians (s) and a Cauchy-loss fit
(h, k; scipy's least_squares), the random parts 1.4826 × the median absolute deviation of the normalised residuals,
so slips and the matcher's rare failures do not count. Until MIN_SAMPLES intervals are in, the estimate is the prior
(the config's odometry factor σ read as these quantities).
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import asdict, dataclass

import numpy as np

WINDOW = 400  # intervals (≈ 80 m at 0.2 m nodes): long enough for a median of a few %, short enough to follow a floor
MIN_SAMPLES = 40  # intervals before the measurement replaces the prior (≈ 8 m of travel)
REFIT_EVERY = 25  # intervals between fits while running (the graph's ISAM2 cadence)
MIN_STEP = 0.02  # m: an interval shorter than this tells nothing per metre (turning on the spot) for s and σ_t
MAD_SIGMA = 1.4826  # σ of a normal distribution per median absolute deviation
MEDIAN_SE = 1.2533  # standard error of a normal sample's median per σ/√n (√(π/2))
STRAIGHT = math.radians(1.0)  # an interval turning less than this measures the yaw noise per metre driven
TURNING = math.radians(2.0)  # … more than this, the yaw noise per radian turned


@dataclass(frozen=True)
class OdomNoise:
    """The odometry's error per metre driven and per radian turned (see the module docstring)."""

    scale_error: float  # s: the odometry reports (1 + s) × the distance the scans saw (signed)
    trans_sigma: float  # σ_t: random along-track error per √m (m/√m)
    heading_drift: float  # h: yaw error per metre driven (rad/m, signed)
    rot_scale_error: float  # k: yaw error per radian turned (signed)
    yaw_sigma: float  # σ_θ: random yaw error per √m driven (rad/√m)
    turn_sigma: float  # σ_r: random yaw error per √rad turned (rad/√rad)
    samples: int = 0  # intervals measured
    measured: bool = False  # False: the prior (too few intervals yet)
    scale_error_sigma: float = float("nan")  # standard error of s (the median's: 1.2533 × σ / √n)

    def translation_sigma(self, d: float) -> float:
        """σ of the odometry's translation over d metres: the random walk and the scale error's share, together."""
        return math.sqrt(self.trans_sigma ** 2 * d + (self.scale_error * d) ** 2)

    def yaw_sigma_of(self, d: float, dyaw: float) -> float:
        """σ of the odometry's yaw over d metres and a turn of dyaw radians: random parts and systematic ones."""
        return math.sqrt(self.yaw_sigma ** 2 * d + self.turn_sigma ** 2 * abs(dyaw)
                         + (self.heading_drift * d) ** 2 + (self.rot_scale_error * dyaw) ** 2)

    def factor_sigmas(self, rel: np.ndarray) -> np.ndarray:
        """σ (x, y, yaw) of an odometry factor over the increment `rel`, floored at the noise of a MIN_STEP move (a
        turn on the spot is not known to the millimetre)."""
        d = math.hypot(rel[0], rel[1])
        floor = math.sqrt(MIN_STEP)
        sxy = max(self.translation_sigma(d), self.trans_sigma * floor)
        return np.array([sxy, sxy, max(self.yaw_sigma_of(d, float(rel[2])), self.yaw_sigma * floor)])

    def as_dict(self) -> dict:
        return asdict(self)


def prior_from_factor_sigmas(sigma_xy_per_m: float, sigma_yaw_per_rad: float, sigma_yaw: float,
                             node_distance: float) -> OdomNoise:
    """The prior: the config's odometry factor σ (per metre, per radian, and the yaw σ of one node step) read as
    the model's random parts, with no systematic error."""
    d = max(node_distance, MIN_STEP)
    return OdomNoise(0.0, sigma_xy_per_m * math.sqrt(d), 0.0, 0.0, sigma_yaw / math.sqrt(d), sigma_yaw_per_rad, 0, False)


class OdomNoiseEstimator:
    """Accumulates matcher-vs-odometry residuals per node interval; `estimate()` gives the current OdomNoise."""

    def __init__(self, prior: OdomNoise, window: int = WINDOW, min_samples: int = MIN_SAMPLES,
                 refit_every: int = REFIT_EVERY) -> None:
        self.prior = prior
        self.min_samples = int(min_samples)
        self.refit_every = max(int(refit_every), 1)
        self._rows: deque[tuple[float, float, float, float]] = deque(maxlen=int(window))  # d, Δθ, e_along, e_yaw
        self.total = 0
        self._since = 0  # intervals added since the last fit
        self._cached: OdomNoise | None = None

    def add(self, matched: np.ndarray, odometry: np.ndarray) -> None:
        """One interval: the matcher's relative pose (x, y, yaw in the first node's frame) and the odometry's."""
        m = np.asarray(matched, float)
        o = np.asarray(odometry, float)
        if not (np.all(np.isfinite(m)) and np.all(np.isfinite(o))):
            return
        d = math.hypot(m[0], m[1])
        along = (o[:2] - m[:2]) @ (m[:2] / d) if d > 1e-9 else 0.0
        e_yaw = math.remainder(o[2] - m[2], 2 * math.pi)
        self._rows.append((d, float(m[2]), float(along), e_yaw))
        self.total += 1
        self._since += 1

    def estimate(self, refit: bool = False) -> OdomNoise:
        """The measured noise over the window, or the prior while it holds fewer than `min_samples` intervals. Fitted
        again every `refit_every` intervals (or when `refit`): a fit takes about a millisecond."""
        if self._cached is None or refit or self._since >= self.refit_every or (
                not self._cached.measured and len(self._rows) >= self.min_samples):
            self._cached = self._fit()
            self._since = 0
        return self._cached

    def _fit(self) -> OdomNoise:
        if len(self._rows) < self.min_samples:
            return self.prior
        r = np.array(self._rows)
        d, dth, ea, ey = r.T
        moving = d >= MIN_STEP
        if moving.sum() < self.min_samples // 2:
            return self.prior
        per_m = ea[moving] / d[moving]
        s = float(np.median(per_m))
        s_se = MEDIAN_SE * _mad(per_m) / math.sqrt(len(per_m))
        trans = _mad((ea[moving] - s * d[moving]) / np.sqrt(d[moving]))  # turns in place (d 0) left out
        h, k = _yaw_fit(d, dth, ey)
        res = ey - h * d - k * dth
        straight = moving & (np.abs(dth) < STRAIGHT)
        pick = straight if straight.sum() >= 10 else moving
        yaw_sig = _mad(res[pick] / np.sqrt(d[pick]))
        turning = np.abs(dth) >= TURNING
        turn_sig = 0.0
        if turning.sum() >= 10:  # var(res) = σ_θ²·d + σ_r²·|Δθ|: the turn's share of the normalised spread
            a = np.abs(dth[turning])
            turn_sig = math.sqrt(max(_mad(res[turning] / np.sqrt(a)) ** 2 - float(np.median(yaw_sig ** 2 * d[turning] / a)), 0.0))
        return OdomNoise(s, trans, float(h), float(k), yaw_sig, turn_sig, len(r), True, s_se)


def _mad(x: np.ndarray) -> float:
    """Robust σ: 1.4826 × the median absolute deviation from the median."""
    if len(x) == 0:
        return 0.0
    return float(MAD_SIGMA * np.median(np.abs(x - np.median(x))))


def _yaw_fit(d: np.ndarray, dth: np.ndarray, ey: np.ndarray) -> tuple[float, float]:
    """Heading drift h (rad/m) and rotation scale error k in e_yaw = h·d + k·Δθ, robustly (Cauchy loss, scale the
    residuals' own MAD): a slip's yaw jump weighs little."""
    from scipy.optimize import least_squares

    A = np.column_stack((d, dth))
    x0, *_ = np.linalg.lstsq(A, ey, rcond=None)
    scale = max(_mad(ey - A @ x0), 1e-5)
    sol = least_squares(lambda x: A @ x - ey, x0, loss="cauchy", f_scale=scale)
    return float(sol.x[0]), float(sol.x[1])
