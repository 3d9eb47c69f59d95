"""numba gets a cache folder it can write: beside the source, the user's cache, or one in the temp directory."""

from __future__ import annotations

import os

from frontend.numbacache import numba_cache_dir


def test_numbas_own_places_are_kept_when_writable(tmp_path):
    pkg = tmp_path / "pkg"
    pkg.mkdir()
    assert numba_cache_dir({"HOME": str(tmp_path)}, pkg) is None
    assert numba_cache_dir({"NUMBA_CACHE_DIR": "/somewhere"}, pkg) is None  # the user's choice stands


def test_an_install_the_user_cannot_write_gets_a_temp_folder(tmp_path, monkeypatch):
    ro = tmp_path / "readonly"
    (ro / "pkg").mkdir(parents=True)
    home = tmp_path / "home"
    home.mkdir()
    real = os.access
    monkeypatch.setattr(os, "access", lambda p, mode: False if str(p).startswith(str(ro)) else real(p, mode))
    assert numba_cache_dir({"HOME": str(home)}, ro / "pkg") is None  # ~/.cache/numba can be made
    d = numba_cache_dir({"HOME": "/nonexistent"}, ro / "pkg")  # a service account: no home either
    if os.access("/", os.W_OK):  # (root may write at / : then numba's user-wide folder would work)
        assert d is None
    else:
        assert d is not None and "kosmap-numba-cache" in d
    assert numba_cache_dir({"HOME": str(ro)}, ro / "pkg") is not None  # a home it cannot write
