"""The supervisor's start of each trial: at once (``start: auto``) or a prompt answered while the arm holds."""

from __future__ import annotations

import logging
import sys
import threading
from collections.abc import Callable

log = logging.getLogger(__name__)


def stdin_prompt(message: str) -> None:
    """The default prompt: the message in the log, answered with a line on standard input."""
    log.warning("%s", message)
    sys.stdin.readline()


#: How a ``prompt`` start asks the supervisor: called in a thread with the message, returns when started. The
#: CLI installs its own (a console prompt) with :func:`set_supervisor_prompt`.
_PROMPT: list[Callable[[str], None]] = [stdin_prompt]


def set_supervisor_prompt(prompt: Callable[[str], None]) -> None:
    """Install the function a ``start: prompt`` block calls (in a thread) and waits for before each trial."""
    _PROMPT[0] = prompt


class Supervisor:
    """The supervisor's start: immediate (``auto``) or a prompt answered while the arm keeps holding."""

    def __init__(self, mode: str) -> None:
        self.mode = mode
        self._done = threading.Event()

    def request(self, message: str) -> None:
        self._done.clear()
        if self.mode == "auto":
            self._done.set()
            return
        prompt = _PROMPT[0]

        def wait() -> None:
            try:
                prompt(message)
            finally:
                self._done.set()

        threading.Thread(target=wait, name="supervisor", daemon=True).start()

    def ready(self) -> bool:
        return self._done.is_set()
