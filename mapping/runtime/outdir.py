"""Output folders: checked before any work, and a run's own files told apart from the user's.

A run (build, slam, scan, compare) replaces the files of the previous run of the same command in its folder, and
only those: each run lists what it wrote in a manifest (MANIFEST); a file that it would write under the same name
but that no such run wrote there is the user's (or another command's), and the run refuses to start rather than
delete or overwrite it.
"""

from __future__ import annotations

import json
import os
import shutil
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from kosmap.frontend.errors import KosmapError

MANIFEST = ".kosmap-outputs"
SPILL_PREFIX = ".kosmap-spill-"  # a build's temporary folder inside its output folder (removed when it ends)


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


def previous_outputs(out: Path, command: str = "build") -> set[str] | None:
    """Names of the files the previous run of `command` wrote in `out` (its manifest); {"*"} (every file matching
    its names counts) for a run that was killed while running (its manifest says so) or a build from before
    manifests (metrics.json says "kosmap": "build"); None: no such run's folder. OutputError: another command's."""
    try:
        listed = json.loads((out / MANIFEST).read_text())
        if listed.get("kosmap", "build") != command:
            raise OutputError(f"--out {out} holds the results of `kosmap {listed.get('kosmap')}`; give `kosmap "
                              f"{command}` a folder of its own")
        return {"*"} if listed.get("in_progress") else set(listed["files"])
    except FileNotFoundError:
        pass
    except (OSError, ValueError, KeyError, TypeError):
        return None  # a damaged manifest proves nothing: what it would list is treated as the user's
    try:
        legacy = command == "build" and json.loads((out / "metrics.json").read_text()).get("kosmap") == "build"
    except (OSError, ValueError, AttributeError):
        legacy = False
    return {"*"} if legacy else None


def claim(out: Path, patterns: tuple[str, ...], inputs: tuple = (), command: str = "build") -> None:
    """Make `out` ready for a run of `command` that writes files matching `patterns`: the previous run's files
    there are removed (they must not mix with this run's, nor survive its failure), and so are leftovers of a killed
    build (its temporary folder, `.partial` files); a matching file no such run wrote, or one this run reads
    (`inputs`: the log, --config, a blueprint), stops it, untouched. The manifest then says a run is in progress,
    so that the files of one killed outright are the next run's to replace."""
    out.mkdir(parents=True, exist_ok=True)
    present = sorted({p.name for pat in patterns for p in out.glob(pat) if p.is_file() or p.is_symlink()})
    here = out.resolve()
    for x in inputs:
        if x is not None and Path(x).resolve().parent == here and Path(x).name in present:
            raise OutputError(f"{x} is read by this run but is one of the files it writes in --out {out}; copy it "
                              f"elsewhere or give another folder")
    prev = previous_outputs(out, command) if present else None
    ours = set(present) if prev == {"*"} else (prev or set())
    theirs = [n for n in present if n not in ours]
    if theirs:
        more = f" and {len(theirs) - 3} more" if len(theirs) > 3 else ""
        them = "it" if len(theirs) == 1 else "them"
        raise OutputError(f"--out {out} holds {', '.join(theirs[:3])}{more}, which `kosmap {command}` would overwrite "
                          f"but did not write (another kosmap command's folder? each needs its own); move {them} or "
                          f"give another folder")
    _write_manifest(out, {"kosmap": command, "in_progress": True})
    for name in present:
        (out / name).unlink(missing_ok=True)
    for p in out.glob(SPILL_PREFIX + "*"):
        shutil.rmtree(p, ignore_errors=True)
    for pat in patterns:
        for p in out.glob(pat + ".partial"):
            p.unlink(missing_ok=True)


@contextmanager
def writing(out: Path, patterns: tuple[str, ...], inputs: tuple = (), command: str = "build") -> Iterator[None]:
    """A run of `command` writing into `out`: claimed first, its files listed when the body ends, removed when it
    fails or is interrupted."""
    claim(out, patterns, inputs, command)
    try:
        yield
    except BaseException:
        discard(out, patterns)
        raise
    record(out, patterns, command)


def discard(out: Path, patterns: tuple[str, ...]) -> None:
    """Remove what a failed run wrote (after `claim`, every file matching `patterns` is this run's): no
    half-written result is left looking valid."""
    for pat in patterns:
        for p in out.glob(pat):
            p.unlink(missing_ok=True)
        for p in out.glob(pat + ".partial"):
            p.unlink(missing_ok=True)
    (out / MANIFEST).unlink(missing_ok=True)


def record(out: Path, patterns: tuple[str, ...], command: str = "build") -> Path:
    """List the files of this run (every match of `patterns`) in the manifest, written whole or not at all."""
    names = sorted({p.name for pat in patterns for p in out.glob(pat) if p.is_file()})
    return _write_manifest(out, {"kosmap": command, "files": names})


def _write_manifest(out: Path, doc: dict) -> Path:
    tmp = out / (MANIFEST + ".partial")
    tmp.write_text(json.dumps(doc, indent=1) + "\n")
    os.replace(tmp, out / MANIFEST)
    return out / MANIFEST
