"""The serial gaze source (issue 20): arrival stamps, port settings, raw captures and their replay, the counter
clock, and what the source says when nothing decodes."""

from __future__ import annotations

import os
import socket
import threading
import time
import tty

import numpy as np
import pytest

from wamctl.backends.gaze import tracker_sim
from wamctl.backends.gaze.asl import COUNTER_FIELDS, AslLayout, AslStreamDecoder, CounterClock
from wamctl.backends.gaze.base import DecodeStats, stream_problem
from wamctl.backends.gaze.capture import CaptureWriter, read_capture
from wamctl.backends.gaze.check import describe_silence
from wamctl.backends.gaze.formats import make_decoder
from wamctl.backends.gaze.replay import PtyReplaySource, RawReplaySource
from wamctl.backends.gaze.serial import SerialGazeSource
from wamctl.errors import BackendError, DataFormatError
from wamctl.hmi.gaze import GazeFlag

WIRE_A = bytes.fromhex("80 00 28 00 01 00 01 20 20 00")  # status 0, pupil 40, (384, 288): test_gaze_formats.py
SETTINGS = {"url": "test", "baudrate": 57600, "bytesize": 8, "parity": "N", "stopbits": 1}


def _read_all(source, timeout_s=0.05):
    out = []
    while (d := source.read_decoded(timeout_s)) is not None or not source.exhausted:
        if d is not None:
            out.append(d)
    return out


@pytest.fixture
def pty_pair():
    master, slave = os.openpty()
    tty.setraw(slave)
    yield master, os.ttyname(slave)
    for fd in (master, slave):
        try:
            os.close(fd)
        except OSError:
            pass


@pytest.mark.parametrize("fmt, reader", [("asl-serial-out", "thread"), ("ascii-pair", "thread"),
                                         ("asl-serial-out", "process")])
def test_arrival_stamp_is_taken_when_the_bytes_are_there(pty_pair, fmt, reader):
    """A frame written 50 ms after the reader starts waiting is stamped after the write started, not when the read
    began; for formats without a tracker clock the stamp is the sample's time. The same with the port read in a
    child process."""
    master, slave = pty_pair
    data = tracker_sim.frame(fmt, 0, (384, 288))
    written = []

    def write():
        tracker_sim.wait_for_reader(slave, 57600)
        time.sleep(0.05)
        written.append(time.monotonic())
        os.write(master, data)

    with SerialGazeSource(slave, format=fmt, timeout_s=5.0, reader=reader) as src:
        threading.Thread(target=write, daemon=True).start()
        d = src.read_decoded(5.0)
    assert d is not None and written
    assert d.arrival_s >= written[0]
    assert d.sample.t_s == d.arrival_s and (d.sample.x_px, d.sample.y_px) == (384.0, 288.0)


def test_port_settings_reach_pyserial():
    with SerialGazeSource("loop://", baudrate=9600, bytesize=7, parity="even", stopbits=2,
                          flow_control="rtscts") as src:
        p = src.port
        assert (p.baudrate, p.bytesize, p.parity, p.stopbits, p.rtscts, p.xonxoff) == (9600, 7, "E", 2, True, False)
        assert src.settings["format"] == "asl-serial-out"  # the default
    with SerialGazeSource("loop://") as src:
        assert (src.port.baudrate, src.port.parity, src.port.rtscts) == (57600, "N", False)
    with pytest.raises(ValueError, match="parity"):
        SerialGazeSource("loop://", parity="odd-ish")


def test_process_reader_reports_open_failures_and_the_end_of_the_stream(pty_pair):
    with pytest.raises(BackendError, match="cannot open serial port '/dev/does-not-exist-gaze'"):
        SerialGazeSource("/dev/does-not-exist-gaze", reader="process")
    master, slave = pty_pair
    with SerialGazeSource(slave, format="ascii-pair", reader="process", timeout_s=0.1) as src:
        tracker_sim.wait_for_reader(slave, 57600)
        time.sleep(0.2)
        os.write(master, b"1,2\n3,4\n5,")
        first = src.read_decoded(5.0)
        os.close(master)  # the tracker hangs up: the child reads EIO and says so
        rest = _read_all(src)
    assert first.sample.x_px == 1.0 and len(rest) == 2
    assert rest[0].sample.x_px == 3.0 and rest[1].sample.flags == GazeFlag.CORRUPT  # "5," cut by the hang-up
    assert src.exhausted and src.port is None


def test_capture_round_trip_sections_and_a_torn_last_line(tmp_path):
    path = tmp_path / "cap.txt"
    w = CaptureWriter(path, {**SETTINGS, "baudrate": 57600})
    w.write(1.0, WIRE_A)
    w.write(1.5, b"\x13\x55")
    w.close()
    w = CaptureWriter(path, {**SETTINGS, "baudrate": 115200})  # a second opening: a new section
    w.write(9.0, b"384,288\n")
    w.close()
    with path.open("a") as fh:
        fh.write("9.5 3834")  # a crash while writing this line
    sections = read_capture(path)
    assert [s.info["baudrate"] for s in sections] == [57600, 115200]
    assert sections[0].chunks == [(1.0, WIRE_A), (1.5, b"\x13\x55")] and sections[1].chunks == [(9.0, b"384,288\n")]
    assert sections[0].data == WIRE_A + b"\x13\x55" and sections[0].duration_s == 0.5
    bad = tmp_path / "bad.txt"
    bad.write_text(path.read_text().replace("9.0 ", "nine "))
    with pytest.raises(DataFormatError, match=r"bad.txt, line 6: not 'TIME HEX'"):
        read_capture(bad)
    (tmp_path / "other.txt").write_text("t_s,x_px,y_px\n")
    with pytest.raises(DataFormatError, match="line 1: not a gaze capture"):
        read_capture(tmp_path / "other.txt")


def test_raw_replay_gives_exactly_the_live_samples(tmp_path):
    """What a live source decoded, with the capture it wrote, replays in-process to the same records."""
    layout = AslLayout.parse(COUNTER_FIELDS)
    chunks = []
    for k in range(60):
        frame = layout.encode({"counter": (65530 + k) % 65536, "pupil": 0 if 20 <= k < 30 else 40,
                               "x": 10 * k, "y": 5 * k})
        chunks.append((b"\x13\x07" if k % 9 == 4 else b"") + frame)
    chunks[30] = chunks[30][:6]  # bytes lost on the line
    options = {"fields": list(COUNTER_FIELDS), "counter_hz": 30.0}
    live = []
    with SerialGazeSource("loop://", decoder=make_decoder("asl-serial-out", **options), timeout_s=0.05,
                          eof_idle_s=0.2, capture=tmp_path / "cap.txt") as src:
        for k, chunk in enumerate(chunks):
            src.port.write(chunk)
            if k % 3 == 2:  # several frames per read, sometimes
                live.extend(_read_all_now(src))
        live.extend(_read_all(src))
        live_stats = src.stats.as_dict()
    replay = RawReplaySource.from_capture(tmp_path / "cap.txt", lambda: make_decoder("asl-serial-out", **options))
    again = _read_all(replay)
    assert [d.record() for d in again] == [d.record() for d in live]
    assert replay.stats.as_dict() == live_stats
    # frame 31's garbage fell into the cut frame 30: 6 garbage runs of 2 bytes outside frames
    assert len(live) == 59 and live_stats["cut_frames"] == 1 and live_stats["garbage_bytes"] == 2 * 6
    assert live_stats["dropped_frames"] == 1  # frame 30 was cut: the counter skips it


def _read_all_now(src):
    out = []
    while (d := src.read_decoded(0.0)) is not None:
        out.append(d)
    return out


def test_pty_replay_plays_the_capture_through_a_serial_port(tmp_path):
    path = tmp_path / "cap.txt"
    w = CaptureWriter(path, SETTINGS)
    for k in range(12):
        w.write(100.0 + k / 30.0, tracker_sim.frame("ascii-pair", k, (k, 2 * k)))
    w.close()
    with PtyReplaySource(read_capture(path), format="ascii-pair", eof_idle_s=0.5) as src:
        got = _read_all(src)
    assert [(d.sample.x_px, d.sample.y_px) for d in got] == [(float(k), 2.0 * k) for k in range(12)]
    span = got[-1].arrival_s - got[0].arrival_s
    assert span > 0.25  # paced as recorded (11 periods, 0.37 s), not written at once


# ---------------------------------------------------------------------------------------------- the counter clock
def _clock_run(true_hz, n, latency_s, counter_hz=30.0, modulus=65536, start=65000):
    stats = DecodeStats()
    clock = CounterClock(counter_hz, modulus, stats)
    true_t = np.arange(n) / true_hz
    times = [clock.time((start + k) % modulus, 1000.0 + true_t[k] + latency_s[k]) for k in range(n)]
    return np.array(times) - 1000.0, true_t, stats


def test_counter_clock_follows_a_tracker_slightly_off_its_nominal_rate():
    """A tracker at 30.03 Hz read with 0.5 ms + exponential (2 ms) latency, with a 40 ms stall every 50 frames
    (the next frames arrive in a burst): the rebuilt times follow the true ones within 2 ms after the first 2 s,
    chosen before running (the minimum-latency anchor is within a fraction of a ms of the true one, slewing adds
    at most 3.3 ms per frame and is rarely needed). The arrival stamps themselves are off by up to 40 ms."""
    rng = np.random.default_rng(5)
    n = 1800
    lat = 0.0005 + rng.exponential(0.002, n)
    for k in range(50, n, 50):
        lat[k:k + 2] = np.maximum(lat[k:k + 2], 0.040 - np.arange(2) / 30.03)
    t, true_t, stats = _clock_run(30.03, n, lat)
    err = (t - true_t)[60:]
    assert np.abs(err - np.median(err)).max() < 0.002
    assert abs(np.median(err)) < 0.002
    assert np.all(np.diff(t) > 0) and stats.dropped_frames == 0 and stats.clock_adjusts == 0


def test_counter_clock_counts_drops_across_a_gap_longer_than_a_wrap():
    stats = DecodeStats()
    clock = CounterClock(30.0, 65536, stats)
    clock.time(100, 0.0)
    t = clock.time((100 + 70000) % 65536, 70000 / 30.0)  # 39 minutes without a frame: more than one wrap
    assert stats.dropped_frames == 69999 and t == pytest.approx(70000 / 30.0, abs=1e-6)


def test_counter_clock_restart_duplicate_and_monotone_times():
    stats = DecodeStats()
    clock = CounterClock(30.0, 65536, stats)
    times = [clock.time(c, a, b"\x80") for c, a in ((500, 0.0), (501, 1 / 30), (501, 1 / 30 + 0.001))]
    assert times[2] is None and stats.bad_frames == 1  # the same frame twice
    t3 = clock.time(0, 2 / 30)  # the tracker restarted its counter
    t4 = clock.time(1, 3 / 30)
    assert stats.clock_adjusts == 1 and stats.dropped_frames == 0
    assert times[0] < times[1] < t3 < t4
    assert stats.examples["clock"][0].endswith("(counter went from 501 to 0 in 0.033 s)")


# -------------------------------------------------------------------------------------- when nothing decodes
def _serve(data: bytes):
    server = socket.create_server(("127.0.0.1", 0))

    def run():
        conn, _ = server.accept()
        time.sleep(0.3)  # pyserial flushes its input when it opens
        with conn:
            conn.sendall(data)
            time.sleep(1.0)
        server.close()

    threading.Thread(target=run, daemon=True).start()
    return f"socket://127.0.0.1:{server.getsockname()[1]}"


def _silent(url, fmt="asl-serial-out", seconds=0.8):
    with SerialGazeSource(url, format=fmt, timeout_s=0.05) as src:
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            src.read_decoded(0.05)
        assert stream_problem(src.stats) is not None
        return describe_silence(src, seconds)


def test_silence_with_no_byte_says_so_and_what_to_check():
    msg = _silent("loop://")
    assert "no byte arrived on loop:// at 57600 Bd 8N1" in msg and "wamctl gaze-check --port loop://" in msg


def test_silence_with_ascii_pairs_on_an_asl_source_names_the_format():
    msg = _silent(_serve(b"".join(tracker_sim.frame("ascii-pair", k, (100 + k, 200)) for k in range(30))))
    assert "format asl-serial-out: 360 bytes arrived" in msg
    assert "0 frame(s) of asl-serial-out" in msg and "360 byte(s) outside frames" in msg
    assert "First bytes: 31 30 30 2e 30 2c 32 30 30 2e 30 0a" in msg  # "100.0,200.0\n"
    assert "these bytes decode as ascii-pair: set source.format: ascii-pair" in msg


def test_silence_with_asl_frames_of_other_items_suggests_the_fields():
    """Frames with a 14-byte item list (12 data bytes) on a standard source: every frame is cut; the message says
    what the framing is and to set the items."""
    layout = AslLayout.parse(["status:u8", "counter:u16", "pupil:i16", "spare:u8", "x:i16", "y:i16", "xdat:u16"])
    data = b"".join(layout.encode({"counter": k, "pupil": 40, "x": 384, "y": 288}) for k in range(30))
    msg = _silent(_serve(data))
    assert msg.startswith("no usable gaze stream (") and "2 sample(s)" in msg and "28 bad frame(s)" in msg
    assert "First bad frame: 80 00 02 00 28 00 01 00 00 01 (frames are followed by 4 bytes without a start mark: " \
           "the tracker's frames are 14 bytes (12 data bytes), not 10" in msg
    assert "a byte with bit 7 set every 14 bytes" in msg and "ASL Serial Out framing with 12 data bytes" in msg
    assert "set asl.fields to the items" in msg


def test_silence_with_noise_suggests_baud_rates():
    rng = np.random.default_rng(3)
    msg = _silent(_serve(bytes(rng.integers(0, 256, 600, dtype=np.uint8))))
    assert "600 bytes arrived" in msg and "noise" in msg and "--baud 115200" in msg


def test_a_blink_from_pupil_zero_reaches_the_sample_flags():
    dec = AslStreamDecoder()
    (frame,) = dec.feed(tracker_sim.frame("asl-serial-out", 0, None))
    assert dec.decode(frame, 0.0).sample.flags == GazeFlag.BLINK
