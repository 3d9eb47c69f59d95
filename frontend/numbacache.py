"""Where numba keeps the compiled kernels, in a folder named for the kernels' source.

numba checks a cached kernel only against the time stamp of the file that defines it, not of the files its callees
come from: a kernel inlining a helper of another module (FSPF+'s main loop and fspf_kernels.py, say) would keep
running the helper's old code after that module changed. So the cache folder is named for a digest of the source
kernels are compiled from: every module of the package that defines a compiled function, and every kosmap module
those import (a callee or a constant numba freezes in), followed through their imports. A change there means a fresh
folder; a change elsewhere (a report, a command) keeps the compiled kernels. The folder lies beside the source,
else in the user's cache folder, else (an install owned by another user, a service account without a home) in a
per-user folder in the temporary directory. A NUMBA_CACHE_DIR the user set is kept as it is."""

from __future__ import annotations

import hashlib
import os
import re
import shutil
import stat
import tempfile
import time
from pathlib import Path

_PACKAGE = Path(__file__).resolve().parent
_SOURCE_FOLDERS = ("frontend", "backend", "mapping", "tools")  # kosmap's packages (pyproject.toml)


def _writable(path: Path) -> bool:
    """Could this process create `path` (or write in it): its nearest existing ancestor is a writable folder."""
    while not path.exists():
        if path.parent == path:
            return False
        path = path.parent
    return path.is_dir() and os.access(path, os.W_OK | os.X_OK)


_KERNEL = re.compile(r"@(numba\.)?(njit|jit|vectorize|guvectorize|cfunc|stencil)\b|\bnjit\(")


_FROM = re.compile(r"^[ \t]*from[ \t]+(\.*)([\w.]*)[ \t]+import[ \t]+(\([^)]*\)|[^\n]*)", re.M)
_IMPORT = re.compile(r"^[ \t]*import[ \t]+([\w., \t]+)", re.M)


def _kosmap_imports(path: Path, root: Path) -> set[Path]:
    """The modules of the package (under `root`) that the module at `path` imports, absolute or relative. A regular
    expression rather than `ast`: this runs on every start, and parsing the kernels' modules costs ~0.2 s."""
    text = path.read_text(errors="replace")
    here = list(path.relative_to(root).parent.parts)
    names = [n.split(" as ")[0].strip() for m in _IMPORT.finditer(text) for n in m.group(1).split(",")]
    for dots, module, what in _FROM.findall(text):
        base = module.split(".") if module else []
        if dots:
            base = here[: len(here) - len(dots) + 1] + base
        elif base[:1] != ["kosmap"]:
            continue
        names.append(".".join(base))
        names += [".".join(base + [w.split(" as ")[0].strip()]) for w in what.strip("()").replace("\n", ",").split(",")]
    found = set()
    for name in names:
        parts = [x for x in name.split(".") if x]
        if parts[:1] == ["kosmap"]:
            parts = parts[1:]
        for cand in (root.joinpath(*parts).with_suffix(".py"), root.joinpath(*parts, "__init__.py")):
            if parts and cand.is_file():
                found.add(cand)
    return found


def kernel_sources(package: Path = _PACKAGE) -> list[Path]:
    """The modules compiled kernels come from: those defining one, and the package modules they import, followed
    through their own imports."""
    root = package.parent
    todo = [p for folder in _SOURCE_FOLDERS for p in sorted((root / folder).rglob("*.py"))
            if _KERNEL.search(p.read_text(errors="replace"))]
    seen: set[Path] = set()
    while todo:
        p = todo.pop()
        if p not in seen:
            seen.add(p)
            todo += _kosmap_imports(p, root) - seen
    return sorted(seen)


def source_digest(package: Path = _PACKAGE) -> str:
    """A digest of the modules compiled kernels come from (`kernel_sources`)."""
    h = hashlib.sha1()
    for p in kernel_sources(package):
        h.update(p.relative_to(package.parent).as_posix().encode())
        h.update(p.read_bytes())
    return h.hexdigest()[:12]


def numba_cache_dir(environ: dict | os._Environ = os.environ, package: Path = _PACKAGE) -> str | None:
    """The NUMBA_CACHE_DIR to set (None: the user chose one)."""
    if environ.get("NUMBA_CACHE_DIR"):
        return None
    name = f"numba-{source_digest(package)}"
    if _writable(package / "__pycache__"):
        return str(package / "__pycache__" / name)
    home = environ.get("XDG_CACHE_HOME") or os.path.join(environ.get("HOME") or "/nonexistent", ".cache")
    if _writable(Path(home) / "kosmap"):
        return os.path.join(home, "kosmap", name)
    uid = os.getuid() if hasattr(os, "getuid") else 0
    return os.path.join(tempfile.gettempdir(), f"kosmap-numba-cache-{uid}", name)


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
    """Set NUMBA_CACHE_DIR (before numba is first imported) to the folder for this source, made private where it
    lies in the shared temporary directory."""
    d = numba_cache_dir()
    if d is None:
        return
    parent = Path(d).parent
    if parent.name.startswith("kosmap-numba-cache-"):
        parent = Path(private_dir(str(parent)))
    if parent == _PACKAGE / "__pycache__":  # this checkout's own: its earlier sources' kernels, unused for a day, go
        for old in parent.glob("numba-*"):  # (not at once: a process still running the earlier source writes there)
            if old.name != Path(d).name and time.time() - old.stat().st_mtime > 86400:
                shutil.rmtree(old, ignore_errors=True)
    os.environ["NUMBA_CACHE_DIR"] = str(parent / Path(d).name)
