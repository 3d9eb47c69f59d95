"""Whether the place a particle filter is about to claim is the only place in the map its scan fits.

A particle set can collapse, tight and sure, onto one of several look-alike places (a corridor of identical rooms
whose doors repeat at one pitch): a tight set says the particles agree with each other, not that the map holds no
other place like theirs, and once resampling has dropped the others the filter cannot get them back
(Thrun, Burgard & Fox, *Probabilistic Robotics* §8.3.4). So before the filter's own claim (the whole set tight for
`converged_updates`, mapping/localize.py) the scan is searched over the whole map by the window search's correlative
search (backend/globalsearch.py, Olson 2009), the filter's pose competing as one more place, and each place scored
by the likelihood field model over the scan's end points a correlation length (2σ_hit) apart, which are about
independent: the measurement noise and the number of independent readings set how far apart two places' scores
must be before one of them is sure. The claim stands when the posterior over the distinct places gives the filter's
place at least `claim_p` — the test the depth camera's window search claims by (mapping/localize_search.py), here on
one wide scan. Otherwise nothing is claimed and the particles are put back round every place still in the running,
so that the one the data single out later (the corridor's junction in view) is still held.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from kosmap.backend import globalsearch as gs
from kosmap.backend.likelihood_field import MapField
from kosmap.frontend import se2
from kosmap.mapping.localize_config import LocalizeConfig
from kosmap.mapping.localize_search import (Verdict, candidates, polish, profile_places, score_places, through_floor,
                                            z_max_of)


@dataclass
class Uniqueness:
    """One check: the distinct places the scan fits (best first), their posterior, and the claimed place's share."""

    poses: np.ndarray  # (K, 3)
    prob: np.ndarray  # (K,)
    claimed_p: float  # posterior of the place the filter would claim (0: the search lost it)
    unique: bool  # claimed_p ≥ claim_p


class ClaimCheck:
    """The uniqueness test of a claim, on the scan the claim is made at."""

    def __init__(self, f: MapField, cfg: LocalizeConfig) -> None:
        self.f, self.cfg = f, cfg
        self.sf = gs.search_field(f.distance, f.free, f.origin, f.resolution, cfg.search_step, cfg.search_fine)

    def test(self, pts: np.ndarray, pose: np.ndarray, z_max: float) -> Uniqueness:
        """The scan `pts` (N×2, robot frame) over the whole map, the filter's `pose` one of the places."""
        c, f = self.cfg, self.f
        pts = np.asarray(pts, float)[:, :2]
        coarse = pts[gs.thin(pts, c.search_fine)]
        poses = np.array(candidates(self.sf, f, c, coarse) + [polish(f, coarse, pose)])
        views = np.zeros((len(pts), 2))  # one scan, seen from the robot
        poses, prob = score_places(f, c, poses, pts, views, z_max)
        near = (np.hypot(poses[:, 0] - pose[0], poses[:, 1] - pose[1]) < c.search_apart) & (
            np.abs(np.remainder(poses[:, 2] - pose[2] + math.pi, 2 * math.pi) - math.pi) < math.radians(c.search_apart_deg))
        p = float(prob[near].max()) if near.any() else 0.0
        return Uniqueness(poses, prob, p, p >= c.claim_p)


def unique_or_reseed(check: ClaimCheck, flt, pts: np.ndarray, pose: np.ndarray) -> Uniqueness:
    """The test of the filter's claim at `pose`; when it fails, the filter's particles are put back round every place
    the scan fits (mapping/localize.py _Filter.apply), weighted by their posterior."""
    u = check.test(pts, pose, flt.z_max)
    if not u.unique:
        flt.apply(Verdict(u.poses, u.prob, 0.0, False))
    return u


def jump_sure(f: MapField, cfg: LocalizeConfig, pts: np.ndarray, views: np.ndarray, track: np.ndarray,
              mode: np.ndarray, z_max: float) -> bool:
    """Whether the filter's mode, far from the refined track, is the place the data fit, sure over the track's: the
    same posterior as a claim (each pose first brought to its best by Gauss–Newton, then the likelihood field over
    end points 2σ_hit apart, each ray traced from where it was seen). Moving the track to the mode is a new claim;
    a particle set spread over look-alike places (the ward's rooms, the floor's half-turn image) has modes that fit
    as well as the track, and one scan whose readings graze a door's jamb would otherwise hand the track to one."""
    pts = np.asarray(pts, float)[:, :2]
    if len(pts) == 0:
        return False  # no evidence: the track holds
    fine = pts[gs.thin(pts, cfg.search_fine)]
    poses = np.array([polish(f, fine, track), polish(f, fine, mode)])
    keep = gs.thin(pts, 2.0 * cfg.sigma_hit)
    _, ll = profile_places(f, poses, pts[keep], np.asarray(views, float)[keep], through_floor(cfg, z_max),
                           cfg.through_tol)
    return bool(gs.posterior(ll)[1] >= cfg.claim_p)


def jump_test(f: MapField, cfg: LocalizeConfig, window, u: np.ndarray | None):
    """Whether the refined track may be moved to the filter's far mode (None: whenever its own scan refutes it, the
    laser's case: one wide scan is its own evidence). With the depth camera's window of the last `window_m` of scans
    (the poses of the scan at odometry pose `u` moved by the odometry to the window's newest scan): when the window's
    last `check_m` refutes the track too, its readings passing through the walls (the kidnapping check's test: a
    robot carried, the scans since fit nowhere near the track), or when the whole window is sure of the mode over
    the track (`jump_sure`). One scan that refutes the track (taken in a doorway, its rays grazing the jamb) does
    neither, and the track holds."""
    if window is None or not window.odom or u is None:
        return None
    step = se2.between(u, window.odom[-1])  # from the scan's odometry pose to the window's newest
    z_max = z_max_of(f, cfg)

    def test(track: np.ndarray, mode: np.ndarray) -> bool:
        at = se2.compose(track, step)
        recent, views = window.submap(cfg.check_m)
        keep = gs.thin(recent, 2.0 * cfg.sigma_hit)
        if gs.window_through(f, at, recent[keep], views[keep], cfg.through_tol) > cfg.lost_through:
            return True
        sub, views = window.submap()
        return jump_sure(f, cfg, sub, views, at, se2.compose(mode, step), z_max)

    return test
