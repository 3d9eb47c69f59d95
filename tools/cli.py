"""The `kosmap` command: parse arguments, call the core, print. Errors become one line and a non-zero exit.

Each module in tools/commands/ adds its command(s) through `register(app)`, so commands live apart.
"""

from __future__ import annotations

import importlib
import os
import pkgutil
import signal
import sys

import typer

from kosmap.frontend.errors import KosmapError
from kosmap.tools import commands

app = typer.Typer(name="kosmap", no_args_is_help=True, add_completion=False, pretty_exceptions_enable=False,
                  help="2D maps from depth-camera robot logs: FSPF+ planes, the Kinect Obstacle Scan, SLAM, map export and comparison.")

for mod in sorted(pkgutil.iter_modules(commands.__path__), key=lambda m: m.name):
    importlib.import_module(f"kosmap.tools.commands.{mod.name}").register(app)


def _on_sigterm(signum, _frame):
    """SIGTERM (`kill`, a supervisor) stops a run like an error: its `finally` blocks remove what it half wrote
    (without this, Python dies at once and leaves a build's temporary folder behind)."""
    print("kosmap: terminated", file=sys.stderr)
    raise SystemExit(128 + signum)


def _default_in_child() -> None:
    """A forked worker or SLAM process dies at SIGTERM at once: a Python handler would wait for the C call it runs
    (a gtsam solve, a numba kernel) to end before it could act."""
    if signal.getsignal(signal.SIGTERM) is _on_sigterm:  # (a child forked from any thread is its main thread)
        signal.signal(signal.SIGTERM, signal.SIG_DFL)


os.register_at_fork(after_in_child=_default_in_child)


def _caused_by_interrupt(e: BaseException) -> bool:
    """A KeyboardInterrupt somewhere in the exception's chain."""
    seen = set()
    while e is not None and id(e) not in seen:
        if isinstance(e, KeyboardInterrupt):
            return True
        seen.add(id(e))
        e = e.__cause__ or e.__context__
    return False


def main(argv: list[str] | None = None) -> int:
    """Entry point of the console script: usage errors are click's; our errors are one line, exit 2."""
    old = signal.signal(signal.SIGTERM, _on_sigterm)
    try:
        app(args=argv, prog_name="kosmap")  # standalone: click prints usage errors and exits
    except SystemExit as e:
        if e.code == 130:  # typer's answer to a KeyboardInterrupt in a command (it prints nothing)
            print("kosmap: interrupted", file=sys.stderr)
        return e.code if isinstance(e.code, int) else (0 if e.code is None else 1)
    except SystemError as e:  # Ctrl-C inside a compiled kernel comes out as "returned a result with an exception set"
        if not _caused_by_interrupt(e):
            raise
        print("kosmap: interrupted", file=sys.stderr)
        return 130
    except KosmapError as e:
        print(f"kosmap: error: {e}", file=sys.stderr)
        return e.exit_code
    except OSError as e:
        if e.filename is None:  # not about a path the user gave: a bug, with its traceback
            raise
        # a path the system refuses (a read-only place, a file where a folder must be): one line, like ours
        where = e.filename.removesuffix(".partial") if isinstance(e.filename, str) else e.filename
        print(f"kosmap: error: {where}: {e.strerror or e}; check the path and its permissions", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("kosmap: interrupted", file=sys.stderr)
        return 130
    finally:
        signal.signal(signal.SIGTERM, old)
    return 0


if __name__ == "__main__":
    sys.exit(main())
