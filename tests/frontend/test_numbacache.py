"""numba gets a cache folder it can write (beside the source, the user's cache, or one in the temp directory), named
for the source its kernels are compiled from: a change to a kernel's module, or to a module it imports (a callee, a
constant), means a fresh folder; a change to a module no kernel reaches keeps the compiled kernels."""

from __future__ import annotations

import os

from kosmap.frontend.numbacache import numba_cache_dir


def _package(root):
    pkg = root / "frontend"
    pkg.mkdir(parents=True)
    (pkg / "kernels.py").write_text("from numba import njit\n\nfrom kosmap.tools import (\n    callee,\n)\n"
                                    "from .consts import K\n\n\n@njit(cache=True)\ndef helper(x):\n    return x + K\n")
    (pkg / "consts.py").write_text("K = 1\n")
    (root / "tools").mkdir()
    (root / "tools" / "callee.py").write_text("X = 2\n")
    (root / "tools" / "report.py").write_text("Y = 2\n")
    return pkg


def test_the_folder_is_beside_the_source_and_named_for_it(tmp_path):
    pkg = _package(tmp_path / "kosmap")
    first = numba_cache_dir({"HOME": str(tmp_path)}, pkg)
    assert first is not None and first.startswith(str(pkg / "__pycache__" / "numba-"))
    assert numba_cache_dir({"HOME": str(tmp_path)}, pkg) == first  # the same source: the same folder
    (tmp_path / "kosmap" / "tools" / "report.py").write_text("Y = 3\n")  # no kernel reaches it
    assert numba_cache_dir({"HOME": str(tmp_path)}, pkg) == first
    (tmp_path / "kosmap" / "tools" / "callee.py").write_text("X = 3\n")  # a kernel's module imports it
    second = numba_cache_dir({"HOME": str(tmp_path)}, pkg)
    assert second != first
    (pkg / "consts.py").write_text("K = 2\n")  # a relative import of the kernel's module
    assert numba_cache_dir({"HOME": str(tmp_path)}, pkg) not in (first, second)
    assert numba_cache_dir({"NUMBA_CACHE_DIR": "/somewhere"}, pkg) is None  # the user's choice stands


def test_an_install_the_user_cannot_write_gets_the_users_cache_or_a_temp_folder(tmp_path, monkeypatch):
    ro = tmp_path / "readonly"
    pkg = _package(ro / "kosmap")
    home = tmp_path / "home"
    home.mkdir()
    real = os.access
    monkeypatch.setattr(os, "access", lambda p, mode: False if str(p).startswith(str(ro)) else real(p, mode))
    assert numba_cache_dir({"HOME": str(home)}, pkg).startswith(str(home / ".cache" / "kosmap" / "numba-"))
    d = numba_cache_dir({"HOME": "/nonexistent"}, pkg)  # a service account: no home either
    if os.access("/", os.W_OK):  # (root may write at / : then /nonexistent/.cache can be made)
        assert d.startswith("/nonexistent/.cache/kosmap/numba-")
    else:
        assert "kosmap-numba-cache-" in d
    assert "kosmap-numba-cache-" in numba_cache_dir({"HOME": str(ro)}, pkg)  # a home it cannot write


def test_kosmap_sets_the_folder_for_its_source_before_numba_is_imported():
    import subprocess
    import sys

    from kosmap.frontend.numbacache import source_digest

    env = {k: v for k, v in os.environ.items() if k != "NUMBA_CACHE_DIR"}
    code = "import os, sys, kosmap.frontend; print(os.environ['NUMBA_CACHE_DIR'], 'numba' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True).stdout
    folder, numba_imported = out.split()
    assert folder.endswith(f"numba-{source_digest()}") and numba_imported == "False"


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
