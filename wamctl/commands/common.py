"""Shared CLI helpers: output modes and progress bars."""

from __future__ import annotations

import json
import sys
from contextlib import contextmanager

from rich.console import Console
from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn, TimeRemainingColumn

console = Console()
err_console = Console(stderr=True)


@contextmanager
def progress_bar(description: str, enabled: bool = True):
    """Yields a callback ``progress(done, total)`` drawing a rich bar on stderr (a no-op when disabled)."""
    if not enabled:
        yield None
        return
    with Progress(TextColumn("{task.description}"), BarColumn(), TextColumn("{task.percentage:>3.0f}%"),
                  TimeElapsedColumn(), TimeRemainingColumn(), console=err_console, transient=True) as prog:
        task = prog.add_task(description, total=None)

        def update(done: int, total: int, label: str | None = None):
            prog.update(task, completed=done, total=total, **({"description": label} if label else {}))
        yield update


def emit_json(obj) -> None:
    sys.stdout.write(json.dumps(obj, indent=2, default=str) + "\n")
