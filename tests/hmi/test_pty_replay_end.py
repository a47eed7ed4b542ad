"""A ``replay-raw`` source ``via: pty`` ends when its capture has been played, not at the first silence.

The serial source ends a stream after ``eof_idle_s`` without a byte. Through the pty, the player that writes the
capture runs in the block's own process: when that process lost the CPU or the GIL for longer than ``eof_idle_s``
(building the arm's model under load), the reader found a silence and ended the stream a few samples in, and the
replay's block went home without a trial (seen once in 12 runs of tests/hmi/test_gaze_e2e.py under load: 6 samples
where the capture held 192). Here the silence is in the capture itself: a pause of 3 ``eof_idle_s`` between two
bursts of frames; every frame must come through, and the stream must still end ``eof_idle_s`` after the last.
"""

from __future__ import annotations

from wamctl.backends.gaze import tracker_sim
from wamctl.backends.gaze.capture import CaptureWriter, read_capture
from wamctl.backends.gaze.replay import PtyReplaySource

EOF_IDLE_S = 0.3


def test_a_pause_while_the_player_still_has_bytes_is_not_the_end(tmp_path):
    path = tmp_path / "cap.txt"
    w = CaptureWriter(path, {"url": "test", "baudrate": 57600, "bytesize": 8, "parity": "N", "stopbits": 1})
    times = [100.0 + k / 30.0 for k in range(6)] + [101.2 + k / 30.0 for k in range(6)]  # a 1 s pause between
    for k, t_s in enumerate(times):
        w.write(t_s, tracker_sim.frame("ascii-pair", k, (k, 2 * k)))
    w.close()
    got = []
    with PtyReplaySource(read_capture(path), format="ascii-pair", eof_idle_s=EOF_IDLE_S) as src:
        while (d := src.read_decoded(0.05)) is not None or not src.exhausted:
            if d is not None:
                got.append(d)
    assert [(d.sample.x_px, d.sample.y_px) for d in got] == [(float(k), 2.0 * k) for k in range(12)]
    pause_s = got[6].arrival_s - got[5].arrival_s
    assert pause_s > 3 * EOF_IDLE_S  # the pause was played (as recorded: 1 s), and did not end the stream
