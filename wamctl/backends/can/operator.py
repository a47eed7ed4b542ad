"""The person at the arm: what the CAN session tells them, asks them, and counts down for them.

The session (:mod:`.session`) never prints or reads a terminal: it talks to an :class:`Operator`. The CLI
installs a terminal one (:func:`use_operator`); without one the session uses :class:`LogOperator` (messages to
the log, questions answered by the spec's ``zeroing_confirmed``), and tests use :class:`ScriptedOperator`.

The session's messages (``say``), in the order they come::

    Safety module: Shift-idle, not zeroed; limits: velocity 0.50 / 1.00 m/s, torque 4731 / 5204 units
    The WAM needs to be zeroed: ...                       (confirm: the arm is at its home pose)
    Move the arm by hand to the start pose: ...           (countdown while it is not there)
    Press Shift-Activate on the pendant                   (countdown)
    Session ended: ... Press Shift-Idle on the pendant    (countdown, after the run)
"""

from __future__ import annotations

import contextlib
import contextvars
import logging
import re
from collections.abc import Callable, Iterator
from typing import Protocol, runtime_checkable

logger = logging.getLogger(__name__)

__all__ = ["LogOperator", "Operator", "ScriptedOperator", "current_operator", "short_message", "use_operator"]


def short_message(text: str, width: int) -> str:
    """One of the session's messages in at most ``width`` characters (at least 16), for a line that shows it beside
    other things (a progress bar): without its parenthesis, then only what follows its first colon (the joint and
    the numbers of the start pose), cut with an ellipsis."""
    width = max(width, 16)
    short = re.sub(r"\s*\([^)]*\)", "", text).strip()
    if len(short) > width and ": " in short:
        short = short.split(": ", 1)[1]
    return short if len(short) <= width else short[:width - 1] + "\u2026"


@runtime_checkable
class Operator(Protocol):
    """What the session needs from the person at the arm."""

    def say(self, text: str) -> None:
        """Tell them something (one line, or a few)."""
        ...

    def confirm(self, question: str) -> bool:
        """Ask a yes/no question; True only on an explicit yes."""
        ...

    def countdown(self, text: str, remaining_s: float) -> None:
        """Show ``text`` with the time left (called about every 0.5 s while waiting; the last call has 0 left
        or the wait ended early)."""
        ...

    def done(self) -> None:
        """The wait the countdowns were for is over."""
        ...


class LogOperator:
    """No terminal: messages go to the log, and ``confirm`` answers ``assume_yes`` (the spec's
    ``zeroing_confirmed`` or ``--yes``)."""

    def __init__(self, assume_yes: bool = False) -> None:
        self.assume_yes = bool(assume_yes)
        self._last_whole_s: int | None = None

    def say(self, text: str) -> None:
        logger.warning("%s", text)

    def confirm(self, question: str) -> bool:
        logger.warning("%s -> %s", question, "yes (confirmed in advance)" if self.assume_yes else "no")
        return self.assume_yes

    def countdown(self, text: str, remaining_s: float) -> None:
        whole = int(remaining_s) // 10
        if whole != self._last_whole_s:
            self._last_whole_s = whole
            logger.warning("%s (%.0f s left)", text, remaining_s)

    def done(self) -> None:
        self._last_whole_s = None


class ScriptedOperator:
    """An operator for tests: records everything, answers ``confirm`` with ``answers`` in turn (then
    ``default``), and runs ``on_say[substring](text)`` when a message contains the substring (e.g. the
    simulated operator moving the arm when asked to)."""

    def __init__(self, answers: tuple[bool, ...] = (), default: bool = False,
                 on_say: dict[str, Callable[[str], None]] | None = None) -> None:
        self.answers = list(answers)
        self.default = default
        self.on_say = dict(on_say or {})
        self.said: list[str] = []
        self.questions: list[str] = []
        self.countdowns: list[tuple[str, float]] = []

    def say(self, text: str) -> None:
        self.said.append(text)
        for key, hook in list(self.on_say.items()):
            if key in text:
                hook(text)

    def confirm(self, question: str) -> bool:
        self.questions.append(question)
        return self.answers.pop(0) if self.answers else self.default

    def countdown(self, text: str, remaining_s: float) -> None:
        self.countdowns.append((text, remaining_s))

    def done(self) -> None:
        pass


_CURRENT: contextvars.ContextVar[Operator | None] = contextvars.ContextVar("wamctl_can_operator", default=None)


def current_operator(assume_yes: bool = False) -> Operator:
    """The operator installed by :func:`use_operator`, else a :class:`LogOperator`."""
    op = _CURRENT.get()
    return op if op is not None else LogOperator(assume_yes)


@contextlib.contextmanager
def use_operator(operator: Operator) -> Iterator[Operator]:
    """Within the block, CAN sessions talk to ``operator`` (the CLI's terminal, a test's script)."""
    token = _CURRENT.set(operator)
    try:
        yield operator
    finally:
        _CURRENT.reset(token)
