"""Faults the simulated pucks can be made to show (the link watchdog's tests): dropped replies, silent pucks,
malformed ("garbage") frames, pucks that stop answering. A mixin of :class:`~.simulator.PuckSimulator`, whose
replies all go through :meth:`FaultInjection._reply`.
"""

from __future__ import annotations

import can

from wamctl.backends.can.protocol.addressing import (
    FEEDBACK_OTHER,
    FEEDBACK_POSITION,
    FEEDBACK_POSITION_TARGET,
    decode_bus_id,
    encode_bus_id,
)

__all__ = ["FaultInjection"]


class FaultInjection:
    """Fault switches and the reply path they act on (mixed into :class:`~.simulator.PuckSimulator`)."""

    def drop_replies(self, probability: float = 1.0, *, after_s: float | None = None) -> None:
        """Drop replies (position and property) with ``probability``, optionally only after ``after_s``."""
        if not 0.0 <= probability <= 1.0:
            raise ValueError(f"probability must be in [0, 1], got {probability}")
        self._drop_probability = float(probability)
        self._drop_after_s = None if after_s is None else float(after_s)

    def set_silent(self, puck_id: int, silent: bool = True) -> None:
        """Make a puck silent (it neither answers nor obeys, like a puck off the bus) or bring it back."""
        if puck_id not in self._pucks:
            raise ValueError(f"no simulated puck {puck_id}")
        (self._silent.add if silent else self._silent.discard)(puck_id)

    def inject_garbage(self, probability: float) -> None:
        """Replace each reply, with this probability, by a malformed frame (same id, wrong length)."""
        if not 0.0 <= probability <= 1.0:
            raise ValueError(f"probability must be in [0, 1], got {probability}")
        self._garbage_probability = float(probability)

    def send_garbage(self, count: int = 1) -> None:
        """Send ``count`` malformed frames now: puck -> feedback group frames of the wrong length."""
        for _ in range(count):
            puck_id = self._rng.choice(sorted(self._pucks))
            group = self._rng.choice((FEEDBACK_POSITION, FEEDBACK_OTHER))
            self._send(self._garble(encode_bus_id(puck_id, group)), counter="garbage_sent")

    def stop_answering(self) -> None:
        """Stop sending anything (commands are still obeyed)."""
        self._answering = False

    def resume_answering(self) -> None:
        self._answering = True

    def clear_faults(self) -> None:
        self._drop_probability = 0.0
        self._drop_after_s = None
        self._garbage_probability = 0.0
        self._silent.clear()
        self._answering = True

    def _garble(self, arbitration_id: int) -> can.Message:
        bid = decode_bus_id(arbitration_id)
        valid = (3, 6) if bid.target == FEEDBACK_POSITION_TARGET else (4, 6)
        length = self._rng.choice([n for n in range(9) if n not in valid])
        data = bytes(self._rng.getrandbits(8) for _ in range(length))
        return can.Message(arbitration_id=arbitration_id, data=data, is_extended_id=False)

    def _reply(self, msg: can.Message) -> None:
        if not self._answering:
            self._count("replies_dropped")
            return
        dropping = self._drop_probability > 0.0 and (
            self._drop_after_s is None or self.elapsed_s() >= self._drop_after_s)
        if dropping and (self._drop_probability >= 1.0 or self._rng.random() < self._drop_probability):
            self._count("replies_dropped")
            return
        if self._garbage_probability > 0.0 and self._rng.random() < self._garbage_probability:
            self._send(self._garble(msg.arbitration_id), counter="replies_garbled")
            return
        self._send(msg, counter="replies_sent")

