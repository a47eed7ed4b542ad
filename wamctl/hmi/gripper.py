"""The BarrettHand as the HMI drives it: a simulated hand whose fingers close and open at a constant rate."""

from __future__ import annotations

#: Closing / opening time of the BarrettHand (BH-280 fingers: about 1 s from open to closed).
HAND_CLOSE_S = 1.0
HAND_OPEN_S = 1.0


class BarrettHandSim:
    """A simulated BarrettHand: finger closure from 0 (open) to 1 (closed) at a constant rate.

    Parameters
    ----------
    close_time_s, open_time_s : float
        Time from fully open to fully closed and back.
    """

    def __init__(self, *, close_time_s: float = HAND_CLOSE_S, open_time_s: float = HAND_OPEN_S) -> None:
        if close_time_s <= 0 or open_time_s <= 0:
            raise ValueError("close_time_s and open_time_s must be > 0")
        self.close_time_s = close_time_s
        self.open_time_s = open_time_s
        self.closure = 0.0
        self.target = 0.0
        self._t_s: float | None = None

    def close(self, t_s: float) -> None:
        self.update(t_s)
        self.target = 1.0

    def open(self, t_s: float) -> None:
        self.update(t_s)
        self.target = 0.0

    def update(self, t_s: float) -> None:
        """Advance the fingers to time ``t_s``."""
        if self._t_s is not None and t_s > self._t_s:
            dt = t_s - self._t_s
            if self.target > self.closure:
                self.closure = min(self.target, self.closure + dt / self.close_time_s)
            elif self.target < self.closure:
                self.closure = max(self.target, self.closure - dt / self.open_time_s)
        self._t_s = t_s

    @property
    def moving(self) -> bool:
        return self.closure != self.target

    @property
    def is_closed(self) -> bool:
        return self.closure >= 1.0

    @property
    def is_open(self) -> bool:
        return self.closure <= 0.0

