"""The progress bar leaves room for the ``^C`` a terminal echoes on Ctrl-C, and the notice of an interrupt stops
it before its line: at 80 columns the bar filled the width, the echo wrapped to a line of its own, and the bar,
frozen at its last percentage, stayed above the lines printed after it (seen in tmux)."""

from __future__ import annotations

import io
import re

from rich.console import Console

import wamctl.commands.common as common

ANSI = re.compile(r"\x1b\[[0-9;?]*[A-Za-z]")


def test_the_bar_leaves_two_columns_free_at_80_and_the_notice_stops_it_first(monkeypatch):
    out = io.StringIO()
    monkeypatch.setattr(common.err_console, "_console", Console(file=out, force_terminal=True, width=80))
    with common.progress_bar("rotation rotation-pd: a description long enough to fill the line") as progress:
        progress(570, 1000)
        progress.progress.refresh()
        drawn = out.getvalue()
        common.interrupt_notice(progress)("Ctrl-C", 1_312_500)
        assert not progress.progress.live.is_started
    frames = [ANSI.sub("", f) for f in re.split(r"[\r\n]", drawn)]
    bars = [f for f in frames if "57%" in f]
    assert bars and max(len(f) for f in bars) == 80 - common.CTRL_C_ECHO_COLUMNS, bars
    assert ANSI.sub("", out.getvalue()).rstrip().endswith("interrupted by Ctrl-C: saving 1,312,500 samples ...")
