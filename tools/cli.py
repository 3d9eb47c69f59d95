"""The `kosmap` command: parse arguments, call the core, print. Errors become one line and a non-zero exit.

Each module in tools/commands/ adds its command(s) through `register(app)`, so commands live apart. The command
line's libraries (typer, and through the commands numpy, numba, gtsam...) are imported inside `main`, after its
signal handlers are in place: Ctrl-C or SIGTERM stops a run from its first instant with one line, never a
traceback from the middle of an import.
"""

from __future__ import annotations

import os
import signal
import sys

from kosmap.frontend.errors import KosmapError  # (a small module: the libraries come later, in `main`)


class _Signals:
    """SIGINT and SIGTERM while `main` runs: Ctrl-C raises KeyboardInterrupt (also when the process was started
    with SIGINT ignored, as a shell does for a background job: a run that honoured it only once reading began
    would ignore it in its first seconds); SIGTERM (`kill`, a supervisor) stops a run like an error, so that its
    `finally` blocks remove what it half wrote (without this, Python dies at once and leaves a staging folder).
    `got` remembers the signal: an import cut short by it fails with an ImportError, not a KeyboardInterrupt."""

    def __init__(self) -> None:
        self.got: int | None = None
        self.old = {s: signal.signal(s, self._on) for s in (signal.SIGINT, signal.SIGTERM)}

    def _on(self, signum, _frame):
        self.got = signum
        if signum == signal.SIGTERM:
            print("kosmap: terminated", file=sys.stderr)
            raise SystemExit(128 + signum)
        raise KeyboardInterrupt

    def restore(self) -> None:
        for s, h in self.old.items():
            signal.signal(s, h)


def _default_in_child() -> None:
    """A forked worker or SLAM process dies at SIGTERM at once: a Python handler would wait for the C call it runs
    (a gtsam solve, a numba kernel) to end before it could act."""
    h = signal.getsignal(signal.SIGTERM)
    if isinstance(getattr(h, "__self__", None), _Signals):  # (a child forked from any thread is its main thread)
        signal.signal(signal.SIGTERM, signal.SIG_DFL)


os.register_at_fork(after_in_child=_default_in_child)


def make_app():
    """The typer application with every command of tools/commands/."""
    import importlib
    import pkgutil

    import typer

    from kosmap.tools import commands

    app = typer.Typer(name="kosmap", no_args_is_help=True, add_completion=False, pretty_exceptions_enable=False,
                      help="2D maps from depth-camera robot logs: FSPF+ planes, the Kinect Obstacle Scan, SLAM, map export and comparison.")
    for mod in sorted(pkgutil.iter_modules(commands.__path__), key=lambda m: m.name):
        importlib.import_module(f"kosmap.tools.commands.{mod.name}").register(app)
    return app


def _usage_error(e) -> int:
    """A click usage error (bad option value, missing argument, unknown command) as one line naming the command's
    help; `kosmap` or a command group without arguments shows its help, as before."""
    ctx = getattr(e, "ctx", None)
    if type(e).__name__ == "NoArgsIsHelpError" and ctx is not None:
        print(ctx.get_help())
        return 2
    where = ctx.command_path if ctx is not None else "kosmap"
    msg = " ".join(e.format_message().split()).rstrip(".")
    print(f"kosmap: error: {msg}; see `{where} --help`", file=sys.stderr)
    return getattr(e, "exit_code", 2)


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
    sig = _Signals()
    try:
        return _run(argv, sig)
    finally:
        sig.restore()


def _invoke(argv: list[str] | None) -> int:
    """The command line run by typer; its exit code."""
    import typer  # (here, not at the top: a Ctrl-C while it loads is an interruption like any other)

    try:
        code = make_app()(args=argv, prog_name="kosmap", standalone_mode=False)  # the exit code, or None
    except typer.TyperException as e:  # a usage error: one line (click's is a box of six or more)
        return _usage_error(e)
    if isinstance(code, int) and not isinstance(code, bool) and code:
        if code == 130:  # typer's answer to a KeyboardInterrupt in a command (it prints nothing)
            print("kosmap: interrupted", file=sys.stderr)
        return code
    return 0


def _run(argv: list[str] | None, sig: _Signals) -> int:
    try:
        return _invoke(argv)
    except SystemExit as e:
        if e.code == 130:  # typer's answer to a KeyboardInterrupt in a command (it prints nothing)
            print("kosmap: interrupted", file=sys.stderr)
        return e.code if isinstance(e.code, int) else (0 if e.code is None else 1)
    except KeyboardInterrupt:
        print("kosmap: interrupted", file=sys.stderr)
        return 130
    except Exception as e:
        if sig.got == signal.SIGTERM:  # cut short inside an import or a compiled call: the signal, not the error
            return 128 + signal.SIGTERM
        if sig.got is not None or _caused_by_interrupt(e):  # Ctrl-C inside a compiled kernel or an import
            print("kosmap: interrupted", file=sys.stderr)
            return 130
        if isinstance(e, KosmapError):  # (one stopped by Ctrl-C, exit 130, says so itself: not an error)
            print(f"kosmap: {'' if e.exit_code == 130 else 'error: '}{e}", file=sys.stderr)
            return e.exit_code
        if isinstance(e, OSError) and e.filename is not None:
            # a path the system refuses (a read-only place, a file where a folder must be): one line, like ours
            where = e.filename.removesuffix(".partial") if isinstance(e.filename, str) else e.filename
            print(f"kosmap: error: {where}: {e.strerror or e}; check the path and its permissions", file=sys.stderr)
            return 2
        raise  # not about the user's input: a bug, with its traceback
    return 0


if __name__ == "__main__":
    sys.exit(main())
