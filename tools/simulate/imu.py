"""A MEMS IMU on base_link: gyro and accelerometer samples from the true trajectory, with white noise and biases.

Gyro: the true body rates (yaw rate from the trajectory; roll and pitch rates are zero on a flat floor) plus
white noise of density N (angle random walk; σ per sample N·√rate) plus a bias: a turn-on bias drawn once
(what a start-up calibration leaves) and a rate random walk of K (the bias wanders by K·√T in T seconds; its
Allan deviation is K·√(τ/3), so 0.0003 °/s/√s reaches ~10 °/h at τ = 300 s), the usual three-term MEMS model
(IEEE Std 952; Woodman, "An introduction to inertial navigation", 2007, §4).
Accelerometer: specific force in the body frame, f = a − g: forward acceleration, centripetal v·ω to the
left and +g up (a resting IMU reads +9.81 m/s² on z, as sensor_msgs/Imu expects), plus white noise and a
constant bias. No orientation is estimated: orientation_covariance[0] = −1, as a raw MEMS driver publishes.
Every sample is computed at once with numpy (no per-sample Python work).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from kosmap.tools.simulate.motion import Trajectory

G = 9.80665  # standard gravity (m/s²)


@dataclass(frozen=True)
class ImuNoise:
    """A consumer MEMS IMU (BMI088 / ICM-20948 class); units as the SimConfig fields that set them."""

    rate: float = 200.0  # Hz
    gyro_noise_density: float = 0.005  # °/s/√Hz
    gyro_bias_sigma: float = 0.02  # °/s, turn-on bias σ per axis
    gyro_bias_walk: float = 0.0003  # °/s/√s, bias rate random walk
    accel_noise_density: float = 150e-6  # g/√Hz
    accel_bias_sigma: float = 0.02  # m/s², constant bias σ per axis

    @property
    def gyro_sigma(self) -> float:
        """σ of one gyro sample's white noise (rad/s)."""
        return math.radians(self.gyro_noise_density) * math.sqrt(self.rate)

    @property
    def accel_sigma(self) -> float:
        """σ of one accelerometer sample's white noise (m/s²)."""
        return self.accel_noise_density * G * math.sqrt(self.rate)


@dataclass(frozen=True)
class ImuStream:
    """IMU samples at times t (s from the start); the true rates and biases beside the measurements."""

    t: np.ndarray  # (N,) s
    gyro: np.ndarray  # (N, 3) rad/s, measured
    accel: np.ndarray  # (N, 3) m/s², measured
    true_gyro: np.ndarray  # (N, 3) rad/s
    true_accel: np.ndarray  # (N, 3) m/s², specific force without noise or bias
    gyro_bias: np.ndarray  # (N, 3) rad/s, the bias in each sample
    accel_bias: np.ndarray  # (3,) m/s²
    keep: np.ndarray  # (N,) bool: False inside an imu_gaps interval (no message written)


def _in(t: np.ndarray, intervals) -> np.ndarray:
    m = np.zeros(len(t), bool)
    for t0, t1 in intervals:
        m |= (t >= t0) & (t <= t1)
    return m


def imu_stream(traj: Trajectory, t: np.ndarray, noise: ImuNoise, rng: np.random.Generator,
               gaps=(), stuck=()) -> ImuStream:
    """IMU samples at times t (s since the start). `gaps`: [t0, t1] intervals without messages (the bias keeps
    wandering through them); `stuck`: intervals where the gyro repeats its last output before t0."""
    t = np.asarray(t, float)
    n = len(t)
    v, w, a, _ = traj.rates(t)
    true_gyro = np.zeros((n, 3))
    true_gyro[:, 2] = w
    true_accel = np.column_stack((a, v * w, np.full(n, G)))
    # draws in a fixed order (same seed → same samples): turn-on bias, walk, gyro noise, accel bias, accel noise
    b0 = rng.normal(0.0, math.radians(noise.gyro_bias_sigma), 3)
    dt = np.diff(t, prepend=t[0] if n else 0.0)
    steps = rng.standard_normal((n, 3)) * (math.radians(noise.gyro_bias_walk) * np.sqrt(dt))[:, None]
    bias = b0 + np.cumsum(steps, axis=0)
    gyro = true_gyro + bias + rng.standard_normal((n, 3)) * noise.gyro_sigma
    accel_bias = rng.normal(0.0, noise.accel_bias_sigma, 3)
    accel = true_accel + accel_bias + rng.standard_normal((n, 3)) * noise.accel_sigma
    for t0, t1 in stuck:
        idx = np.flatnonzero((t >= t0) & (t <= t1))
        if len(idx):
            gyro[idx] = gyro[idx[0] - 1] if idx[0] > 0 else gyro[idx[0]]
    return ImuStream(t, gyro, accel, true_gyro, true_accel, bias, accel_bias, ~_in(t, gaps))


def imu_truth(s: ImuStream, noise: ImuNoise) -> dict:
    """The gyro's and accelerometer's true biases and noise levels (JSON-ready; rates in °/s)."""
    deg = np.degrees
    return {
        "rate_hz": noise.rate,
        "gyro_bias_initial_dps": deg(s.gyro_bias[0]).tolist() if len(s.t) else [0.0, 0.0, 0.0],
        "gyro_bias_final_dps": deg(s.gyro_bias[-1]).tolist() if len(s.t) else [0.0, 0.0, 0.0],
        "gyro_bias_mean_dps": deg(s.gyro_bias.mean(axis=0)).tolist() if len(s.t) else [0.0, 0.0, 0.0],
        "gyro_sigma_per_sample_dps": math.degrees(noise.gyro_sigma),
        "gyro_noise_density_dps_rthz": noise.gyro_noise_density,
        "gyro_bias_walk_dps_rts": noise.gyro_bias_walk,
        "accel_bias": s.accel_bias.tolist(),
        "accel_sigma_per_sample": noise.accel_sigma,
    }
