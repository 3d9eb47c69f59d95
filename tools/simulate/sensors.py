"""Sensor noise: the Kinect v2 depth camera and the Hokuyo UTM-30LX, applied to exact ray-cast geometry.

Kinect v2 (time of flight), after Fankhauser et al., "Kinect v2 for mobile robot navigation: evaluation and
modeling" (ICAR 2015): the axial noise grows with depth and with the incidence angle θ,
σ(z, θ) = σ₁·z^p + σ_θ·z^1.5·θ²/(π/2 − θ)², with σ₁·z^p through ~1.5 mm at 1 m and ~1 cm at 4 m (Fankhauser et al.'s
figures; p = log(σ₄/σ₁)/log 4 ≈ 1.37). Pixels drop out at grazing incidence, at random, beyond the
8 m the sensor reports and in the corners the rectification leaves empty; at depth edges the sensor mixes
foreground and background into "flying pixels" that lie on no surface.
Hokuyo UTM-30LX datasheet: repeatability σ < 10 mm below 10 m (accuracy ±30 mm), ±50 mm to 30 m.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache

import numpy as np
from numba import njit

from kosmap.tools.simulate.world import FLYING_ID


@dataclass(frozen=True)
class DepthNoise:
    """Kinect v2 depth noise and validity (defaults: the sensor's behaviour, not a flattering ideal)."""

    sigma_1m: float = 0.0015  # axial σ at 1 m (m)
    sigma_4m: float = 0.010  # axial σ at 4 m (m)
    sigma_angle: float = 0.0001  # incidence term σ_θ (m), Fankhauser et al.
    min_range: float = 0.5  # nearer returns are invalid (0)
    max_range: float = 8.0  # farther returns are invalid (0)
    dropout: float = 0.005  # probability that any pixel is invalid
    grazing_start_deg: float = 70.0  # incidence angle where grazing dropouts begin …
    grazing_end_deg: float = 85.0  # … and where every pixel drops out
    flying_prob: float = 0.5  # probability that a pixel at a depth edge becomes a flying pixel
    flying_edge: float = 0.05  # a depth jump to a 4-neighbour larger than this (m) or 3 % of depth is an edge
    corner_radius: float = 1.3  # pixels beyond this normalised radius (corner = √2) are empty (rectification)

    @property
    def exponent(self) -> float:
        if self.sigma_1m <= 0 or self.sigma_4m <= 0:
            return 1.0
        return math.log(self.sigma_4m / self.sigma_1m) / math.log(4.0)

    def sigma(self, z: np.ndarray, cos_inc: np.ndarray | None = None) -> np.ndarray:
        """Axial σ (m) at depth z (m) and incidence |cos θ|."""
        z = np.asarray(z, dtype=np.float32)
        s = np.float32(self.sigma_1m) * np.power(np.maximum(z, np.float32(1e-3)), np.float32(self.exponent))
        if cos_inc is not None and self.sigma_angle > 0:
            th = np.arccos(np.clip(cos_inc, 0.0, 1.0)).astype(np.float32)
            th = np.minimum(th, np.float32(math.radians(89.0)))
            s = s + np.float32(self.sigma_angle) * z * np.sqrt(z) * th * th / (np.float32(math.pi / 2) - th) ** 2
        return s


@dataclass(frozen=True)
class LaserNoise:
    """Hokuyo UTM-30LX: σ 1 cm below `far`, 3 cm beyond; rare random no-returns."""

    sigma: float = 0.01
    sigma_far: float = 0.03
    far: float = 10.0
    dropout: float = 0.001
    grazing_end_deg: float = 88.0  # beams at more oblique incidence return nothing


def corner_mask(width: int, height: int, radius: float) -> np.ndarray:
    """Pixels a rectified Kinect v2 image leaves empty: beyond `radius` in coordinates normalised so the
    image's edge midpoints are at 1 and its corners at √2."""
    u = (np.arange(width) - (width - 1) / 2) / (width / 2)
    v = (np.arange(height) - (height - 1) / 2) / (height / 2)
    return (u[None, :] ** 2 + v[:, None] ** 2) > radius * radius


_Z_STEP = 0.001  # the σ(z) table's step (m)
_COS_STEPS = 4096  # the incidence term's table over |cos θ| ∈ [0, 1]


@lru_cache(maxsize=8)
def _tables(noise: DepthNoise, width: int, height: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """σ₁·z^p on a 1 mm grid to past max_range, σ_θ·θ²/(π/2 − θ)² on a |cos θ| grid, and the corner mask."""
    z = np.arange(0.0, noise.max_range * 1.5 + 1.0, _Z_STEP)
    sz = noise.sigma_1m * np.power(np.maximum(z, 1e-3), noise.exponent) if noise.sigma_1m > 0 else np.zeros_like(z)
    th = np.minimum(np.arccos(np.linspace(0.0, 1.0, _COS_STEPS + 1)), math.radians(89.0))
    sa = noise.sigma_angle * th * th / (math.pi / 2 - th) ** 2
    return sz, sa, corner_mask(width, height, noise.corner_radius)


@njit(cache=True, error_model="numpy")
def _noise_kernel(z, cos_inc, sid, normal, raw, corner, sz, sa, min_r, max_r, p_drop, cos_start, cos_end, p_fly,
                  edge_abs, flying_id, out_z, out_id, out_mm):
    """Per pixel: flying-pixel blend at depth edges, axial noise σ(z, θ), dropouts, range limits; also the
    16UC1 millimetres. The neighbourhood is symmetric, so it runs on transposed (column-major) images too."""
    H, W = z.shape
    inv24 = 1.0 / 16777216.0
    zstep_inv = 1.0 / 0.001
    nz = sz.shape[0]
    nc = sa.shape[0] - 1
    for v in range(H):
        for u in range(W):
            zz = np.float64(z[v, u])
            if zz <= 0.0 or corner[v, u]:
                out_z[v, u] = 0.0
                out_id[v, u] = 0
                out_mm[v, u] = 0
                continue
            r = raw[v, u]
            u1 = np.float64(r >> np.uint64(40)) * inv24
            u2 = np.float64(r & np.uint64(0xFFFFFF)) * inv24
            sid_v = sid[v, u]
            # flying pixel: blend with the 4-neighbour across the largest depth jump (mixed ToF returns); the
            # jump is found branch-free; border pixels get no flying-pixel test
            zf = z[v, u]
            jump = np.float32(0.0)
            if 0 < v < H - 1 and 0 < u < W - 1:
                n0, n1, n2, n3 = z[v, u + 1], z[v, u - 1], z[v + 1, u], z[v - 1, u]
                jump = max(max(abs(n0 - zf) * (n0 > 0), abs(n1 - zf) * (n1 > 0)),
                           max(abs(n2 - zf) * (n2 > 0), abs(n3 - zf) * (n3 > 0)))
            fly = jump > max(edge_abs, 0.03 * zz) and u2 < p_fly
            if fly:
                other = zz
                for nb in (z[v, u + 1], z[v, u - 1], z[v + 1, u], z[v - 1, u]):
                    if nb > 0 and abs(nb - zf) == jump:
                        other = np.float64(nb)
                        break
                zz = zz + (u2 / p_fly) * (other - zz)
                sid_v = flying_id
            c = min(max(np.float64(cos_inc[v, u]), 0.0), 1.0)
            iz = min(int(zz * zstep_inv + 0.5), nz - 1)
            sigma = sz[iz] + sa[int(c * nc + 0.5)] * zz * math.sqrt(zz)
            zn = zz + sigma * normal[v, u]
            drop = u1 < p_drop
            if not fly and c < cos_start:
                drop = drop or u1 < (cos_start - c) / max(cos_start - cos_end, 1e-6)
            if drop or zn < min_r or zn > max_r or zn > 65.535:
                out_z[v, u] = 0.0
                out_id[v, u] = 0
                out_mm[v, u] = 0
            else:
                out_z[v, u] = zn
                out_id[v, u] = sid_v
                out_mm[v, u] = np.uint16(zn * 1000.0 + 0.5)


def apply_depth_noise(depth: np.ndarray, sid: np.ndarray, cos_inc: np.ndarray, noise: DepthNoise,
                      rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Noisy depth (float32 m, 0 = invalid) and surface ids (0 where invalid, FLYING_ID for flying pixels)
    from exact optical depth, ids and incidence |cos θ|."""
    z, out_id, _ = depth_noise_mm(depth, sid, cos_inc, noise, rng)
    return z, out_id


def depth_noise_mm(depth: np.ndarray, sid: np.ndarray, cos_inc: np.ndarray, noise: DepthNoise,
                   rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """apply_depth_noise plus the image in millimetres (uint16, as 16UC1). Draws a fixed amount of
    randomness per call (one normal and 64 random bits per pixel), so a seeded stream stays reproducible.
    Images that arrive transposed (column-major, as the column renderer makes them) are processed in that
    order and returned the same way (a transposed view), which saves three copies per frame."""
    H, W = depth.shape
    flip = not depth.flags.c_contiguous and depth.T.flags.c_contiguous
    z, c, i = (depth.T, cos_inc.T, sid.T) if flip else (depth, cos_inc, sid)
    z = np.ascontiguousarray(z, dtype=np.float32)
    c = np.ascontiguousarray(c, dtype=np.float32)
    i = np.ascontiguousarray(i, dtype=np.uint16)
    normal = rng.standard_normal(z.shape, dtype=np.float32)
    raw = rng.bit_generator.random_raw(z.size).reshape(z.shape)
    sz, sa, corner = _tables(noise, W, H)
    if flip:
        corner = _corner_t(noise, W, H)
    out_z = np.empty(z.shape, np.float32)
    out_id = np.empty(z.shape, np.uint16)
    out_mm = np.empty(z.shape, np.uint16)
    _noise_kernel(z, c, i, normal, raw, corner, sz, sa, noise.min_range, noise.max_range, noise.dropout,
                  math.cos(math.radians(noise.grazing_start_deg)), math.cos(math.radians(noise.grazing_end_deg)),
                  noise.flying_prob, noise.flying_edge, FLYING_ID, out_z, out_id, out_mm)
    if flip:
        return out_z.T, out_id.T, out_mm.T
    return out_z, out_id, out_mm


@lru_cache(maxsize=8)
def _corner_t(noise: DepthNoise, width: int, height: int) -> np.ndarray:
    return np.ascontiguousarray(_tables(noise, width, height)[2].T)


def apply_laser_noise(ranges: np.ndarray, cos_inc: np.ndarray, noise: LaserNoise, range_min: float,
                      range_max: float, rng: np.random.Generator) -> np.ndarray:
    """Noisy ranges (float32; +inf = no return, −inf = too close, REP 117) from exact ranges (+inf where nothing was hit)."""
    r = np.asarray(ranges, dtype=np.float64)
    n = len(r)
    normal = rng.standard_normal(n)
    u = rng.random(n)
    hit = np.isfinite(r)
    sigma = np.where(r < noise.far, noise.sigma, noise.sigma_far)
    out = np.where(hit, r + sigma * normal, np.inf)
    graze = hit & (cos_inc < math.cos(math.radians(noise.grazing_end_deg)))
    out[(u < noise.dropout) | graze | (out >= range_max)] = np.inf
    out[hit & (out < range_min)] = -np.inf  # too close to measure (REP 117)
    return out.astype(np.float32)
