"""Output folders: checked before any work; a run's files staged apart and put in place only when it completes.

A run (build, slam, scan, compare) writes into a hidden staging folder inside its output folder; only when it has
written everything are its files moved into the output folder, replacing those of the previous run of the same
command, and only those: each run lists what it wrote in a manifest (MANIFEST); a file that it would write under
the same name but that no such run wrote there is the user's (or another command's), and the run refuses to start
rather than delete or overwrite it. A run that fails, is interrupted or killed before that point leaves the
previous run's files as they were (and no folder it created); the moves themselves are journalled in the manifest,
so that a run killed outright (SIGKILL) in the middle of them is undone by the next run in that folder.
"""

from __future__ import annotations

import json
import os
import shutil
import signal
import tempfile
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

from kosmap.frontend.errors import KosmapError

MANIFEST = ".kosmap-outputs"
SPILL_PREFIX = ".kosmap-spill-"  # a build's temporary folder (inside its staging folder)
STAGE_PREFIX = ".kosmap-staging-"  # a run's files until it completes: .kosmap-staging-<pid>-<random>
BACKUP_PREFIX = ".kosmap-previous-"  # the previous run's files while the new ones are moved in
_DEFERRED = (signal.SIGINT, signal.SIGTERM)  # held while the files are moved: a run is replaced whole or not at all


class OutputError(KosmapError):
    """The output folder cannot be written, or holds files of the user's that the run would replace."""


def check_out(out: str | Path, option: str = "--out") -> Path:
    """Fail before any work when `out` cannot become a folder this process writes into: empty, a file, under a file,
    or in a folder without write permission. Returns it as a Path."""
    if not str(out).strip():
        raise OutputError(f"{option} is empty; give a folder for the results")
    out = Path(out)
    if out.is_symlink() and not out.exists():
        raise OutputError(f"{option} {out} is a link to {os.readlink(out)}, which does not exist; give a folder")
    if out.exists() and not out.is_dir():
        raise OutputError(f"{option} {out} is a file; give a folder for the results")
    p = out.absolute()
    while not p.exists():
        p = p.parent
    if not p.is_dir():
        raise OutputError(f"{option} {out}: {p} is a file, so no folder can be made in it; give another folder")
    if not os.access(p, os.W_OK | os.X_OK):
        raise OutputError(f"{option} {out}: no permission to write in {p}; give a folder you can write to")
    return out


def _manifest(out: Path) -> dict | None:
    """The folder's manifest; None when it has none. ValueError/OSError: damaged or unreadable."""
    try:
        doc = json.loads((out / MANIFEST).read_text())
    except FileNotFoundError:
        return None
    if not isinstance(doc, dict):
        raise ValueError("not a JSON object")
    return doc


def previous_outputs(out: Path, command: str = "build") -> set[str] | None:
    """Names of the files the previous run of `command` wrote in `out` (its manifest); {"*"} (every file matching
    its names counts) for a run of an earlier kosmap killed while writing in place (its manifest says so) or a build
    from before manifests (metrics.json says "kosmap": "build"); None: no such run's folder. OutputError: another
    command's."""
    try:
        listed = _manifest(out)
        if listed is not None:
            if listed.get("kosmap", "build") != command:
                raise OutputError(f"--out {out} holds the results of `kosmap {listed.get('kosmap')}`; give `kosmap "
                                  f"{command}` a folder of its own")
            return {"*"} if listed.get("in_progress") else set(listed["files"])
    except (OSError, ValueError, KeyError, TypeError):
        return None  # a damaged manifest proves nothing: what it would list is treated as the user's
    try:
        legacy = command == "build" and json.loads((out / "metrics.json").read_text()).get("kosmap") == "build"
    except (OSError, ValueError, AttributeError):
        legacy = False
    return {"*"} if legacy else None


def holds_complete_run(out: Path, command: str = "build") -> bool:
    """Whether `out` holds the files of a run of `command` that completed (not one interrupted and marked partial)."""
    try:
        doc = _manifest(out)
    except (OSError, ValueError):
        return False
    return (doc is not None and doc.get("kosmap", "build") == command and bool(doc.get("files"))
            and not doc.get("partial") and not doc.get("in_progress"))


@dataclass
class Stage:
    """A run's staging folder (`dir`, inside `out`) and what putting its files in place will replace."""

    out: Path
    dir: Path
    patterns: tuple[str, ...]
    command: str
    replaces: list[str]  # the previous run's files (names in `out`)
    previous: str | None  # the previous manifest's text, put back when a run stopped while moving its files is undone
    made: Path | None  # the outermost folder this run created for `out` (removed again if the run fails)


def claim(out: Path, patterns: tuple[str, ...], inputs: tuple = (), command: str = "build") -> Stage:
    """Make a staging folder in `out` for a run of `command` that writes files matching `patterns`. Nothing in
    `out` is replaced yet; a matching file no such run wrote, or one this run reads (`inputs`: the log, --config, a
    blueprint), stops it here. Leftovers of killed runs are cleared first: their staging folders (of processes
    that are gone), and a run killed while moving its files in is undone."""
    made = None
    p = out.absolute()
    while not p.exists():
        made, p = p, p.parent
    out.mkdir(parents=True, exist_ok=True)
    try:
        _recover(out)
        for pat in patterns:  # half-written files of a build of an earlier kosmap that wrote in place
            for p in out.glob(pat + ".partial"):
                p.unlink(missing_ok=True)
        present = _matching(out, patterns, links=True)
        here = out.resolve()
        for x in inputs:
            if x is not None and Path(x).resolve().parent == here and Path(x).name in present:
                raise OutputError(f"{x} is read by this run but is one of the files it writes in --out {out}; copy "
                                  f"it elsewhere or give another folder")
        prev = previous_outputs(out, command) if present else None
        ours = set(present) if prev == {"*"} else (prev or set())
        theirs = [n for n in present if n not in ours]
        if theirs:
            more = f" and {len(theirs) - 3} more" if len(theirs) > 3 else ""
            them = "it" if len(theirs) == 1 else "them"
            raise OutputError(f"--out {out} holds {', '.join(theirs[:3])}{more}, which `kosmap {command}` would "
                              f"overwrite but did not write (another kosmap command's folder? each needs its own); "
                              f"move {them} or give another folder")
        try:
            previous = (out / MANIFEST).read_text()
        except (OSError, ValueError):
            previous = None
        stage = Path(tempfile.mkdtemp(prefix=f"{STAGE_PREFIX}{os.getpid()}-", dir=out))
    except BaseException:
        _remove_made(out, made)
        raise
    return Stage(out, stage, tuple(patterns), command, present, previous, made)


def commit(stage: Stage, partial: bool = False) -> Path:
    """Put the staged files in place of the previous run's: the old ones are moved aside, the new ones in, the
    manifest written (the moment the new run replaces the old), the old ones deleted. SIGINT and SIGTERM wait until
    it is done; one that came meanwhile undoes it (the run was stopped: the previous files stay). Returns the
    manifest. `partial`: an interrupted run's outputs (a later run never keeps them in preference to its own)."""
    out = stage.out
    new = _matching(stage.dir, stage.patterns)
    backup = stage.dir.with_name(BACKUP_PREFIX + stage.dir.name.removeprefix(STAGE_PREFIX))
    final = {"kosmap": stage.command, "files": new, **({"partial": True} if partial else {})}
    with _signals_held() as held:
        backup.mkdir()
        _write_manifest(out, {"kosmap": stage.command, "committing": stage.dir.name, "backup": backup.name,
                              "files": new, "replaces": stage.replaces, "previous": stage.previous})
        for n in stage.replaces:
            if (out / n).exists() or (out / n).is_symlink():
                _move(out / n, backup / n)
        for n in new:
            _move(stage.dir / n, out / n)
        if held:  # stopped while moving: the previous run's files go back
            _undo(out, _manifest(out))
        else:
            _write_manifest(out, final)
        shutil.rmtree(backup, ignore_errors=True)
        shutil.rmtree(stage.dir, ignore_errors=True)
    return out / MANIFEST


def discard(stage: Stage) -> None:
    """Remove what a failed or interrupted run wrote (its staging folder) and the folders it created for `out`
    (when nothing else is in them): the previous run's files are as they were."""
    shutil.rmtree(stage.dir, ignore_errors=True)
    _remove_made(stage.out, stage.made)


def abandon(out: Path, stage: Stage | None) -> None:
    """`discard` for a run stopped anywhere from its `claim` on: with no `stage` yet (interrupted inside `claim` or
    before its result was kept), this process's staging folders in `out` go."""
    if stage is not None:
        discard(stage)
        return
    for p in Path(out).glob(f"{STAGE_PREFIX}{os.getpid()}-*"):
        shutil.rmtree(p, ignore_errors=True)


@contextmanager
def writing(out: Path, patterns: tuple[str, ...], inputs: tuple = (), command: str = "build") -> Iterator[Path]:
    """A run of `command` writing its files into the staging folder this yields; they replace the previous run's
    in `out` when the body ends, and are removed when it fails or is interrupted."""
    stage = None
    try:
        stage = claim(out, patterns, inputs, command)
        yield stage.dir
        commit(stage)
    except BaseException:
        abandon(out, stage)
        raise


@contextmanager
def _signals_held() -> Iterator[list]:
    """SIGINT and SIGTERM during the block are noted (the list it yields) and handled when it ends, by the handlers
    in place before it (which stop the run)."""
    held: list[int] = []
    old = {}
    if threading.current_thread() is threading.main_thread():
        old = {s: signal.signal(s, lambda n, _f: held.append(n)) for s in _DEFERRED}
    try:
        yield held
    finally:
        for s, h in old.items():
            signal.signal(s, h)
        for s in dict.fromkeys(held):
            signal.raise_signal(s)


def _recover(out: Path) -> None:
    """Clear what killed runs left in `out`: undo one killed while moving its files in (its manifest says
    "committing"), remove the staging folders of processes that are gone, and the spill folder of a build of an
    earlier kosmap that wrote in place."""
    try:
        doc = _manifest(out)
    except (OSError, ValueError):
        doc = None
    if doc is not None and doc.get("committing"):
        _undo(out, doc)
    for p in list(out.glob(STAGE_PREFIX + "*")) + list(out.glob(BACKUP_PREFIX + "*")):
        if not _alive(p.name):
            shutil.rmtree(p, ignore_errors=True)
    for p in out.glob(SPILL_PREFIX + "*"):
        shutil.rmtree(p, ignore_errors=True)


def _undo(out: Path, doc: dict) -> None:
    """Put back the previous run's files of an interrupted commit (journalled in `doc`) and its manifest."""
    backup = out / doc["backup"]
    old = set(doc.get("replaces", []))
    for n in doc.get("files", []):
        if n not in old:
            (out / n).unlink(missing_ok=True)  # a new file: no older one of that name to keep
    if backup.is_dir():
        for p in sorted(backup.rglob("*")):
            if not p.is_dir():
                _move(p, out / p.relative_to(backup))
    prev = doc.get("previous")
    if isinstance(prev, str):
        _write_text(out / MANIFEST, prev)
    else:
        (out / MANIFEST).unlink(missing_ok=True)
    shutil.rmtree(backup, ignore_errors=True)
    shutil.rmtree(out / doc["committing"], ignore_errors=True)


def _matching(folder: Path, patterns: tuple[str, ...], links: bool = False) -> list[str]:
    """The files in `folder` that match `patterns`, as paths relative to it ("stats.csv", "planes/000000.npz": a
    pattern may name a subfolder's files)."""
    return sorted({p.relative_to(folder).as_posix() for pat in patterns for p in folder.glob(pat)
                   if p.is_file() or (links and p.is_symlink())})


def _move(src: Path, dest: Path) -> None:
    """Move one file, making the subfolder it goes into when the pattern named one."""
    dest.parent.mkdir(parents=True, exist_ok=True)
    os.replace(src, dest)


def _alive(name: str) -> bool:
    """Whether the process that made a staging or backup folder (its pid is in the name) still runs."""
    try:
        pid = int(name.split("-")[3])  # .kosmap-staging-<pid>-…
    except (IndexError, ValueError):
        return False
    if pid == os.getpid():
        return False
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def _remove_made(out: Path, made: Path | None) -> None:
    """Remove the folders a run created for `out`, innermost first, as long as they are empty."""
    if made is None:
        return
    p = out.absolute()
    top = made.absolute()
    while True:
        try:
            p.rmdir()
        except OSError:
            return
        if p == top:
            return
        p = p.parent


def _write_manifest(out: Path, doc: dict) -> Path:
    return _write_text(out / MANIFEST, json.dumps(doc, indent=1) + "\n")


def _write_text(path: Path, text: str) -> Path:
    """`path` written whole or not at all."""
    tmp = path.with_name(path.name + ".partial")
    tmp.write_text(text)
    os.replace(tmp, path)
    return path
