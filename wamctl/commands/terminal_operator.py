"""The person at the arm, on the terminal: what a CAN session says (``>>>`` lines on stderr), asks (a yes/no
prompt, or ``--yes``) and counts down (in the progress bar's line, or a line every few seconds)."""

from __future__ import annotations

import sys

import typer

from wamctl.backends.can.operator import short_message
from wamctl.commands.common import err_console

BAR_COLUMNS_WIDTH = 32     # what the bar, its percentage and times, and the seconds left need at least (measured)


class TerminalOperator:
    """A :class:`wamctl.backends.can.operator.Operator` on the terminal.

    Parameters
    ----------
    yes : bool
        Answer every confirmation with yes (``--yes``: the operator has checked beforehand).
    progress : callable, optional
        The progress bar's ``update(done, total, label)``; countdowns show in its line, and the bar is stopped
        while a question waits for an answer.
    label : str
        The bar's own label, shown again when a countdown ends.
    """

    def __init__(self, yes: bool = False, progress=None, label: str = "running") -> None:
        self.yes = yes
        self.progress = progress
        self.label = label
        self._last_print_s: float | None = None

    def _pause(self):
        prog = getattr(self.progress, "progress", None)
        if prog is not None:
            prog.stop()
        return prog

    def say(self, text: str) -> None:
        err_console.print(f"[bold cyan]>>>[/] {text}", highlight=False, soft_wrap=True)

    def confirm(self, question: str) -> bool:
        if self.yes:
            self.say(f"{question} yes (--yes)")
            return True
        if not sys.stdin.isatty():
            self.say(f"{question} [no terminal to answer: run with --yes, or set backend.zeroing_confirmed]")
            return False
        prog = self._pause()
        try:
            err_console.print(f"[bold cyan]>>>[/] {question}", highlight=False, soft_wrap=True)
            return typer.confirm("    type y and Enter when it is", default=False, err=True)
        finally:
            if prog is not None:
                prog.start()

    def countdown(self, text: str, remaining_s: float) -> None:
        if self.progress is not None:
            self.progress(0, None, f"{short_message(text, err_console._get().width - BAR_COLUMNS_WIDTH)}: "
                                   f"{remaining_s:.0f} s")
            return
        if self._last_print_s is None or self._last_print_s - remaining_s >= 5.0:
            self._last_print_s = remaining_s
            err_console.print(f"    {text}: {remaining_s:.0f} s left", highlight=False)

    def done(self) -> None:
        self._last_print_s = None
        if self.progress is not None:
            self.progress(0, None, self.label)
