"""The uniqueness test of a laser's claim (mapping/localize_claim.py) on a small ward drawn cell by cell: a corridor
between two rows of identical 3 m rooms whose doors repeat every 3 m, closed at both ends, and a 240° 5.6 m scan
ray-cast in it; a pillar near the east end breaks the floor's half-turn symmetry. In the middle of the corridor the scan fits the places one door pitch along as well as the truth
(no claim, at the truth or at a look-alike); 3 m from the east end, the pillar in view, only the truth fits (a
claim)."""

from __future__ import annotations


import numpy as np
import pytest

from kosmap.backend.likelihood_field import map_field
from kosmap.mapping.localize_claim import ClaimCheck
from kosmap.mapping.localize_search import z_max_of
from kosmap.mapping.localize_config import LocalizeConfig

RES = 0.05
W, H = 24.0, 8.0  # the corridor from y = 3.15 to 4.85 along x, rooms 3 × 3 m below and above it


def _cells(x0, x1, y0, y1, data):
    data[int(round(y0 / RES)):int(round(y1 / RES)), int(round(x0 / RES)):int(round(x1 / RES))] = 100


@pytest.fixture(scope="module")
def ward():
    data = np.zeros((int(H / RES), int(W / RES)), np.int8)
    for box in ((0, W, 0, 0.15), (0, W, H - 0.15, H), (0, 0.15, 0, H), (W - 0.15, W, 0, H)):
        _cells(*box, data)
    for y0 in (3.0, 4.85):  # the corridor's walls, a 0.9 m door into each room
        x = 0.0
        for k in range(8):
            door = 1.5 + 3.0 * k
            _cells(x, door - 0.45, y0, y0 + 0.15, data)
            x = door + 0.45
        _cells(x, W, y0, y0 + 0.15, data)
    for k in range(1, 8):  # the rooms' partitions
        _cells(3.0 * k, 3.0 * k + 0.15, 0, 3.0, data)
        _cells(3.0 * k, 3.0 * k + 0.15, 5.0, H, data)
    _cells(22.3, 22.6, 3.85, 4.15, data)  # the pillar
    cfg = LocalizeConfig()
    f = map_field(data, RES, (0.0, 0.0), cfg.sigma_hit, cfg.z_hit, cfg.z_rand, 5.6, cfg.match_sigma)
    return data, f, cfg


def _scan(data, pose, fov_deg=240.0, beams=683, reach=5.6):
    """End points (robot frame) of a ray-cast scan: the first occupied cell along each beam, 1 cm steps."""
    a = np.radians(np.linspace(-fov_deg / 2, fov_deg / 2, beams))
    r = np.arange(0.05, reach, 0.01)
    x = pose[0] + np.cos(pose[2] + a)[:, None] * r[None, :]
    y = pose[1] + np.sin(pose[2] + a)[:, None] * r[None, :]
    ix = np.clip((x / RES).astype(int), 0, data.shape[1] - 1)
    iy = np.clip((y / RES).astype(int), 0, data.shape[0] - 1)
    hit = data[iy, ix] > 50
    first = np.where(hit.any(axis=1), hit.argmax(axis=1), -1)
    ok = first >= 0
    rr = r[first[ok]]
    return np.column_stack((rr * np.cos(a[ok]), rr * np.sin(a[ok])))


def test_a_scan_mid_corridor_is_no_claim_and_one_near_the_end_wall_is(ward):
    data, f, cfg = ward
    z_max = z_max_of(f, cfg)
    check = ClaimCheck(f, cfg)
    mid = np.array([12.0, 4.0, 0.0])
    scan = _scan(data, mid)
    at_truth = check.test(scan, mid, z_max)
    at_look_alike = check.test(scan, mid + np.array([3.0, 0.0, 0.0]), z_max)
    assert not at_truth.unique and not at_look_alike.unique
    # the places one door pitch either way are in the running with the truth
    near = [np.min(np.hypot(at_truth.poses[:, 0] - (mid[0] + dx), at_truth.poses[:, 1] - mid[1])) for dx in (-3, 0, 3)]
    assert max(near) < 0.2, at_truth.poses[:5]
    # three places as good: about a third each, far from a claim
    assert at_truth.claimed_p < 0.5 and at_look_alike.claimed_p < 0.5
    end = np.array([21.0, 4.0, 0.0])  # the pillar 1.3 m ahead: a door pitch back, its readings fall in free space
    u = check.test(_scan(data, end), end, z_max)
    assert u.unique and u.claimed_p >= cfg.claim_p
    assert np.hypot(*(u.poses[0, :2] - end[:2])) < 0.1
