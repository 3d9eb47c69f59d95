"""Where numba keeps the compiled kernels: beside their source, else in the user's cache folder; where neither can be
written (an install owned by another user, a service account without a home) numba refuses to import a module with a
cached kernel at all, so a per-user folder in the temporary directory is named instead."""

from __future__ import annotations

import os
import stat
import tempfile
from pathlib import Path

_PACKAGE = Path(__file__).resolve().parent


def _writable(path: Path) -> bool:
    """Could this process create `path` (or write in it): its nearest existing ancestor is a writable folder."""
    while not path.exists():
        if path.parent == path:
            return False
        path = path.parent
    return path.is_dir() and os.access(path, os.W_OK | os.X_OK)


def numba_cache_dir(environ: dict | os._Environ = os.environ, package: Path = _PACKAGE) -> str | None:
    """The NUMBA_CACHE_DIR to set (None: numba's own places work, or the user chose one)."""
    if environ.get("NUMBA_CACHE_DIR"):
        return None
    if _writable(package / "__pycache__"):
        return None
    home = environ.get("XDG_CACHE_HOME") or os.path.join(environ.get("HOME") or "/nonexistent", ".cache")
    if _writable(Path(home) / "numba"):
        return None
    uid = os.getuid() if hasattr(os, "getuid") else 0
    return os.path.join(tempfile.gettempdir(), f"kosmap-numba-cache-{uid}")


def private_dir(path: str) -> str:
    """`path` made (0700) or found as a folder of this user's that no one else may write, else a fresh one: numba
    unpickles what its cache folder holds, so a folder another user made first in the shared temporary directory
    must not be used."""
    try:
        os.mkdir(path, 0o700)
    except FileExistsError:
        pass
    except OSError:
        return tempfile.mkdtemp(prefix="kosmap-numba-cache-")
    st = os.lstat(path)
    uid = os.getuid() if hasattr(os, "getuid") else st.st_uid
    if stat.S_ISDIR(st.st_mode) and st.st_uid == uid and not st.st_mode & 0o022:
        return path
    return tempfile.mkdtemp(prefix="kosmap-numba-cache-")


def ensure() -> None:
    """Set NUMBA_CACHE_DIR when numba would find nowhere to cache; before numba is first imported."""
    d = numba_cache_dir()
    if d is not None:
        os.environ["NUMBA_CACHE_DIR"] = private_dir(d)
