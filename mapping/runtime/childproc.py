"""The build's child processes (frame workers, SLAM processes) die with the build: a parent killed outright (SIGKILL,
the out-of-memory killer) closes no pipe the children would notice, since their siblings hold copies of its ends,
so without this they would wait for ever."""

from __future__ import annotations

import os
import signal


def _prctl(option: int, arg) -> None:
    try:
        import ctypes

        ctypes.CDLL(None).prctl(option, arg, 0, 0, 0)
    except (OSError, AttributeError):  # not Linux: nothing
        pass


def die_with_parent(parent_pid: int) -> None:
    """Linux: SIGKILL this process when its parent dies (PR_SET_PDEATHSIG); exit now if it already has."""
    _prctl(1, int(signal.SIGKILL))
    if os.getppid() != parent_pid:  # the parent died before the line above
        os._exit(1)


def set_name(name: str) -> None:
    """Linux: show the process as `name` in top, ps and /proc/PID/comm (PR_SET_NAME, 15 bytes)."""
    _prctl(15, name.encode()[:15])
