"""The simulated pendant: what the operator does, as a script.

A script is a comma-separated list of ``action@t_s`` (or ``never``: the operator does nothing)::

    activate@1.0                 Shift-Activate 1 s after the host starts polling positions
    activate@0.5,idle@4          ... then Shift-Idle
    move@0.2,activate@1.0        first put the arm at its start pose by hand (while idle), then activate
    activate@0.5,estop@2.5       an E-stop mid-run (idle@t after it: released, then Shift-Idle)

Actions: ``activate`` (Shift-Activate), ``idle`` (Shift-Idle; after an E-stop it also releases the button),
``estop`` (press the E-stop) and ``move`` (the simulated operator moves the idle arm to its start pose).
``idle@end`` is Shift-Idle :data:`END_DELAY_S` after the host has put the pucks IDLE at the end of its
session (what the operator does when the terminal says "Press Shift-Idle"). A scripted ``activate`` while the
safety module shows a fault is preceded by Shift-Idle, as the terminal tells the operator to do.

Times count from the start of the host's position polling (the heartbeat, when the terminal would say
"Press Shift-Activate"): the first position request after at least :data:`SESSION_GAP_S` without one. A new
polling run (the next session on the same simulated arm) starts the script again; while the host does not poll,
nothing happens.
"""

from __future__ import annotations

import dataclasses
import math

__all__ = ["ACTIONS", "END_DELAY_S", "Pendant", "PendantEvent", "SESSION_GAP_S", "parse_pendant_script"]

ACTIONS = ("activate", "idle", "estop", "move")
SESSION_GAP_S = 0.5  # a pause in the position polling this long ends a session (the script starts again)
END_DELAY_S = 0.1
END = "end"


@dataclasses.dataclass(frozen=True)
class PendantEvent:
    """One action of the operator, ``t_s`` seconds after the polling started."""

    action: str
    t_s: float  # inf for ``idle@end``

    def __str__(self) -> str:
        return f"{self.action}@{END if math.isinf(self.t_s) else format(self.t_s, 'g')}"


def parse_pendant_script(text: str) -> tuple[PendantEvent, ...]:
    """Parse ``"activate@1.0,idle@5"`` (or ``never``/empty) into events sorted by time.

    Raises
    ------
    ValueError
        Naming the item that is not ``action@seconds`` with a known action and a time >= 0.
    """
    text = (text or "").strip()
    if text in ("", "never"):
        return ()
    events = []
    for item in text.split(","):
        action, sep, t = item.strip().partition("@")
        try:
            t_s = math.inf if (action, t.strip()) == ("idle", END) else float(t)
        except ValueError:
            t_s = math.nan
        if not sep or action not in ACTIONS or math.isnan(t_s) or t_s < 0 or (math.isinf(t_s) and t != END):
            raise ValueError(f"pendant script item {item.strip()!r}: expected action@seconds with action one of "
                             f"{', '.join(ACTIONS)} and seconds >= 0, or idle@end (or 'never')")
        events.append(PendantEvent(action, t_s))
    return tuple(sorted(events, key=lambda e: e.t_s))


class Pendant:
    """Plays a script against the host's polling (not thread-safe: the simulator's thread only).

    Parameters
    ----------
    script : str or sequence of PendantEvent
    """

    def __init__(self, script: str | tuple[PendantEvent, ...] = "never") -> None:
        self.events = parse_pendant_script(script) if isinstance(script, str) else tuple(script)
        self._t_start: float | None = None
        self._last_poll: float | None = None
        self._next = 0
        self._end_at: float | None = None
        self.sessions = 0

    def __str__(self) -> str:
        return ",".join(str(e) for e in self.events) or "never"

    def position_request(self, now_s: float) -> None:
        """The host asked for positions at ``now_s`` (monotonic): a pause of SESSION_GAP_S starts a session."""
        if self._last_poll is None or now_s - self._last_poll >= SESSION_GAP_S:
            self._t_start = now_s
            self._next = 0
            self._end_at = None
            self.sessions += 1
        self._last_poll = now_s

    def activated(self) -> None:
        """The module went active: the next time the host idles the pucks, ``idle@end`` follows again."""
        self._end_at = None

    def host_idled(self, now_s: float) -> None:
        """The host put the pucks IDLE (the end of its session): ``idle@end`` follows."""
        if self._end_at is None and any(math.isinf(e.t_s) for e in self.events):
            self._end_at = now_s + END_DELAY_S

    def due(self, now_s: float) -> list[str]:
        """The actions whose time has come (each once per session, and only while the host is polling: no
        operator presses Shift-Activate for a program that has stopped)."""
        if self._t_start is None or now_s - self._last_poll >= SESSION_GAP_S:
            return []
        out = []
        while self._next < len(self.events) and now_s - self._t_start >= self.events[self._next].t_s:
            out.append(self.events[self._next].action)
            self._next += 1
        if self._end_at is not None and now_s >= self._end_at:
            out.append("idle")
            self._end_at = math.inf  # once per activation
        return out
