"""Which depth frames `kosmap localize` reads (mapping/locinput.py): as AMCL takes a scan only after update_min_d or
update_min_a of motion, a frame is read once the wheels moved 0.2 m or turned 15° since the last one read, and at
least every frame_max_period_s; every frame without odometry or with read_at_updates off."""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np

from kosmap.mapping.localize_config import LocalizeConfig
from kosmap.mapping.locinput import _FrameGate, _Motion


def _kept(lc: LocalizeConfig, speed: float, turn_deg_s: float, seconds: float = 10.0, odom: bool = True) -> np.ndarray:
    """Stamps (s) of the 10 Hz frames the gate keeps while the wheels report `speed` m/s and `turn_deg_s` °/s
    (odometry at 50 Hz, interleaved with the frames as in a log)."""
    motion = _Motion()
    gate = _FrameGate(lc, motion)
    kept = []
    for k in range(int(seconds * 50)):
        t = k / 50.0
        if odom:
            motion.odometry(SimpleNamespace(stamp_ns=int(t * 1e9), x=speed * t, y=0.0,
                                            yaw=math.remainder(math.radians(turn_deg_s) * t, 2 * math.pi)))
        if k % 5 == 0 and gate(SimpleNamespace(topic="/camera/depth", stamp_ns=int(t * 1e9))):
            kept.append(t)
    return np.array(kept)


def test_frames_are_read_after_the_filters_update_distance_or_turn():
    lc = LocalizeConfig()
    # driving at 0.55 m/s: 0.055 m a frame, one frame in four read (0.22 m apart)
    drive = _kept(lc, 0.55, 0.0)
    assert np.allclose(np.diff(drive), 0.4, atol=1e-6), np.diff(drive)
    # turning in place at 40°/s: 4° a frame, one in four read (16° apart)
    turn = _kept(lc, 0.0, 40.0)
    assert np.allclose(np.diff(turn), 0.4, atol=1e-6), np.diff(turn)
    # standing: a frame every frame_max_period_s (0.5 s), well within max_gap_s, so no gap is seen where none is
    stand = _kept(lc, 0.0, 0.0)
    assert np.allclose(np.diff(stand), lc.frame_max_period_s, atol=1e-6) and lc.frame_max_period_s < lc.max_gap_s
    # creeping at 0.1 m/s: the period rules (0.05 m between frames read)
    assert np.allclose(np.diff(_kept(lc, 0.1, 0.0)), 0.5, atol=1e-6)


def test_every_frame_is_read_without_odometry_or_with_the_rule_off():
    lc = LocalizeConfig()
    assert len(_kept(lc, 0.5, 0.0, odom=False)) == 100
    lc.read_at_updates = False
    assert len(_kept(lc, 0.5, 0.0)) == 100
