"""`kosmap demo`: the main job on the bundled default (what `make demo` runs)."""

from __future__ import annotations

import typer

from frontend.errors import KosmapError
from tools.data import data_dir


def register(app: typer.Typer) -> None:
    @app.command()
    def demo() -> None:
        """Show what the Intel Research Lab benchmark log holds (the full pipeline demo replaces this)."""
        from mapping.config import Config
        from tools.commands.info import _print, log_summary

        log = data_dir() / "laser" / "intel" / "intel.orig.bag"
        if not log.is_file():
            raise KosmapError(f"the demo log {log} is missing; set KOSMAP_DATA to the folder that holds laser/intel/")
        _print(log_summary(log, Config()))
