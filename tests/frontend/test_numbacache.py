"""numba gets a cache folder it can write: beside the source, the user's cache, or one in the temp directory."""

from __future__ import annotations

import os

from kosmap.frontend.numbacache import numba_cache_dir


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


def test_the_temp_folder_is_private_and_one_another_user_could_have_planted_is_not_used(tmp_path):
    from kosmap.frontend.numbacache import private_dir

    mine = tmp_path / "kosmap-numba-cache-1"
    assert private_dir(str(mine)) == str(mine) and (mine.stat().st_mode & 0o777) == 0o700
    assert private_dir(str(mine)) == str(mine)  # found again: still ours
    planted = tmp_path / "kosmap-numba-cache-2"
    planted.mkdir()
    planted.chmod(0o777)  # anyone may write in it: not used
    other = private_dir(str(planted))
    assert other != str(planted) and "kosmap-numba-cache-" in other and (os.stat(other).st_mode & 0o777) == 0o700
    link = tmp_path / "kosmap-numba-cache-3"
    link.symlink_to(mine)
    assert private_dir(str(link)) != str(link)  # a link (to anywhere) is not a folder of ours
    os.rmdir(other)
