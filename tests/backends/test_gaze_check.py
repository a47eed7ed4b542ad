"""``wamctl gaze-check`` (issue 20): it names the right format and rate for captures of each kind, and says "no
known format" (with the hex) for random bytes.

The captures are made by code: frames from the library's encoders (checked against the hand fixtures in
test_gaze_formats.py), read times with jitter and with USB-adapter-like bursts (several frames in one read). The
rate must come out within 1 % of the true one, a tolerance chosen before running (the rate is counted over 5 s;
one frame more or less is 0.7 % at 30 Hz).
"""

from __future__ import annotations

import json
import os
import threading
import time
import tty
from pathlib import Path

import numpy as np
import pytest
import yaml
from cli_runs import wamctl_completed

from wamctl.backends.gaze import tracker_sim
from wamctl.backends.gaze.ascii_pair import format_pair
from wamctl.backends.gaze.asl import COUNTER_FIELDS, STANDARD_FIELDS, AslLayout
from wamctl.backends.gaze.capture import CaptureSection, CaptureWriter, read_capture
from wamctl.backends.gaze.check import identify, suggested_spec
from wamctl.backends.gaze.line_format import format_line
from wamctl.specs import parse_spec

ROOT = Path(__file__).resolve().parents[2]
INFO = {"url": "/dev/ttyUSB0", "baudrate": 57600, "bytesize": 8, "parity": "N", "stopbits": 1}


def _capture(frames: list[bytes], rate_hz: float, seed: int = 0, burst_every: int = 7) -> CaptureSection:
    """Frames read at ``rate_hz`` with 0-2 ms of jitter; every ``burst_every``-th read holds two frames."""
    rng = np.random.default_rng(seed)
    chunks, k = [], 0
    while k < len(frames):
        n = 2 if k % burst_every == 3 else 1
        t = 500.0 + (k + n - 1) / rate_hz + float(rng.uniform(0.0, 0.002))
        chunks.append((t, b"".join(frames[k:k + n])))
        k += n
    return CaptureSection(dict(INFO), chunks)


def _points(n, seed=1, blinks=range(40, 55)):
    rng = np.random.default_rng(seed)
    return [None if k in blinks else (int(rng.integers(0, 768)), int(rng.integers(0, 576))) for k in range(n)]


def _asl_standard(rate_hz=30.0, seconds=5.0):
    layout = AslLayout.parse(STANDARD_FIELDS)
    return [layout.encode({"status": 0, "pupil": 0 if p is None else 35, "x": 0 if p is None else p[0],
                           "y": 0 if p is None else p[1]}) for p in _points(round(rate_hz * seconds))]


def _asl_counter(rate_hz=60.0, seconds=5.0):
    layout = AslLayout.parse(COUNTER_FIELDS)
    return [layout.encode({"status": 0, "counter": (65400 + k) % 65536, "pupil": 0 if p is None else 35,
                           "x": 0 if p is None else p[0], "y": 0 if p is None else p[1]})
            for k, p in enumerate(_points(round(rate_hz * seconds)))]


def _pairs(rate_hz=25.0, seconds=5.0):
    return [format_pair(*(p if p else (-2000.0, -2000.0))) for p in _points(round(rate_hz * seconds))]


def _lines(rate_hz=30.0, seconds=5.0):
    return [format_line(k / rate_hz, *(p if p else (-2000.0, -2000.0)))
            for k, p in enumerate(_points(round(rate_hz * seconds)))]


@pytest.mark.parametrize("make, rate_hz, label, blinks", [
    (_asl_standard, 30.0, "asl-serial-out (standard items)", {"pupil_zero": 15, "sentinel_-2000": 0}),
    (_asl_counter, 60.0, "asl-serial-out (frame counter after the status)", {"pupil_zero": 15, "sentinel_-2000": 0}),
    (_pairs, 25.0, "ascii-pair", {"pupil_zero": 0, "sentinel_-2000": 15}),
    (_lines, 30.0, "ascii-timestamped", {"pupil_zero": 0, "sentinel_-2000": 15}),
])
def test_names_the_format_and_the_rate(make, rate_hz, label, blinks):
    result = identify(_capture(make(rate_hz=rate_hz), rate_hz))
    assert result.verdict == label
    s = result.summary
    assert s["rate_hz"] == pytest.approx(rate_hz, rel=0.01)
    assert s["blinks"]["samples"] == 15 and {k: s["blinks"][k] for k in blinks} == blinks
    assert 0 <= s["x_px"][0] < s["x_px"][1] <= 768 and s["out_of_range"] == 0
    assert sum(t.decodes for t in result.trials) == 1  # the other candidates do not decode
    if "counter" in label:
        assert s["counter_hz"] == pytest.approx(60.0, rel=0.01) and s["dropped_frames"] == 0
    spec = yaml.safe_load(suggested_spec(result))  # the suggestion is a valid source section
    h = parse_spec({"kind": "hmi_block", "name": "x", "hmi": spec}).hmi
    assert h.source.format == make.__name__.replace("_asl_standard", "asl-serial-out").replace(
        "_asl_counter", "asl-serial-out").replace("_pairs", "ascii-pair").replace("_lines", "ascii-timestamped")
    if "counter" in label:
        assert h.source.asl.fields == list(COUNTER_FIELDS) and h.source.asl.counter_hz == 60.0


def test_framing_errors_are_counted_with_examples():
    frames = _asl_standard()
    frames[10] = frames[10][:7]  # three bytes lost
    frames[20] = b"\x13\x55" + frames[20]  # line noise
    s = identify(_capture(frames, 30.0)).summary
    assert (s["cut_frames"], s["garbage_bytes"]) == (1, 2)
    assert s["examples"]["garbage"] == ["13 55 (bit 7 clear outside a frame)"]


def test_random_bytes_are_no_known_format_with_the_hex():
    rng = np.random.default_rng(11)
    data = bytes(rng.integers(0, 256, 1500, dtype=np.uint8))
    section = CaptureSection(dict(INFO), [(1.0 + k / 30, data[k * 10:(k + 1) * 10]) for k in range(150)])
    result = identify(section)
    assert result.best is None and result.verdict == "no known format"
    assert result.head_hex.startswith(data[:8].hex(" ")) and "(+1436 bytes)" in result.head_hex
    assert "noise" in result.looks_like and any("--baud 115200" in n for n in result.notes)
    assert suggested_spec(result) == ""


def test_asl_framing_with_unknown_items_is_recognised_but_not_guessed():
    layout = AslLayout.parse(["status:u8", "counter:u16", "pupil:i16", "spare:u8", "x:i16", "y:i16", "xdat:u16"])
    result = identify(_capture([layout.encode({"counter": k, "x": 5, "y": 6}) for k in range(150)], 30.0))
    assert result.best is None
    assert "a byte with bit 7 set every 14 bytes (100 %): ASL Serial Out framing with 12 data bytes" in \
        result.looks_like
    assert any("set asl.fields" in n for n in result.notes)


def test_nothing_at_all():
    result = identify(CaptureSection(dict(INFO), []))
    assert result.verdict == "no bytes" and "nothing arrived" in result.notes[0]


def _wamctl(*args):
    """``wamctl ARGS`` in this process (tests/cli_runs.py), as ``subprocess.run`` returns it."""
    return wamctl_completed(*args)


def test_cli_from_captures(tmp_path):
    good, noise = tmp_path / "asl.txt", tmp_path / "noise.txt"
    for path, section in ((good, _capture(_asl_counter(), 60.0)),
                          (noise, CaptureSection(INFO, [(1.0, bytes(range(0, 256, 3)) * 4)]))):
        w = CaptureWriter(path, section.info)
        for t, data in section.chunks:
            w.write(t, data)
        w.close()
    r = _wamctl("gaze-check", "--from-capture", good)
    assert r.returncode == 0, r.stderr
    text = " ".join(r.stdout.split())
    assert "asl-serial-out (frame counter after the status) at 57600 Bd: 300 samples at 60.0" in text
    assert "counter_hz: 60 # measured 59.99" in text
    r = _wamctl("gaze-check", "--from-capture", noise)
    assert r.returncode == 1
    assert "no known format in 344 bytes; first bytes: 00 03 06 09 0c 0f" in " ".join(r.stderr.split())
    r = _wamctl("gaze-check")
    assert r.returncode == 2 and "give --port URL or --from-capture FILE" in r.stderr
    r = _wamctl("gaze-check", "--port", "loop://", "--parity", "bogus")
    assert r.returncode == 2 and "--parity: 'bogus' is not one of none, even" in r.stderr
    assert "Traceback" not in r.stderr
    r = _wamctl("gaze-check", "--port", "/dev/does-not-exist-gaze", "--seconds", 0.5)
    assert r.returncode == 2 and "cannot open serial port" in r.stderr and "Traceback" not in r.stderr


def test_cli_on_a_live_port_writes_a_capture(tmp_path):
    """A tracker streaming 'x,y' lines into a pty at 30 Hz; gaze-check reads 2 s at two baud rates (a pty ignores
    the rate: both decode) and writes both captures to one file."""
    master, slave_fd = os.openpty()
    tty.setraw(slave_fd)
    slave = os.ttyname(slave_fd)
    stop = threading.Event()

    def stream():
        tracker_sim.wait_for_reader(slave, 57600)
        k = 0
        t0 = time.monotonic()
        while not stop.is_set():
            os.write(master, tracker_sim.frame("ascii-pair", k, (100 + k % 500, 200)))
            k += 1
            time.sleep(max(0.0, t0 + k / 30.0 - time.monotonic()))

    thread = threading.Thread(target=stream, daemon=True)
    thread.start()
    try:
        r = _wamctl("gaze-check", "--port", slave, "--seconds", 2, "--baud", 57600, "--baud", 115200,
                    "--capture", tmp_path / "cap.txt", "--json")
    finally:
        stop.set()
        thread.join(2.0)
        os.close(master)
        os.close(slave_fd)
    assert r.returncode == 0, r.stderr
    out = json.loads(r.stdout)
    assert out["verdict"] == "ascii-pair" and "format: ascii-pair" in out["suggested_spec"]
    assert [x["settings"]["baudrate"] for x in out["results"]] == [57600, 115200]
    assert all(x["verdict"] == "ascii-pair" for x in out["results"])
    assert 25.0 < out["results"][0]["summary"]["rate_hz"] < 35.0  # live: whatever the machine's load
    sections = read_capture(tmp_path / "cap.txt")
    assert [s.info["baudrate"] for s in sections] == [57600, 115200]
    assert identify(sections[0]).verdict == "ascii-pair"


def test_line_noise_between_frames_still_decodes_and_is_shown():
    """Noise before every third frame (about 10 % of the bytes outside frames): the stream still decodes, and the
    noise is counted with its first bytes."""
    frames = _asl_standard()
    frames = [(b"\x01\x02\x03" if k % 3 == 1 else b"") + f for k, f in enumerate(frames)]
    result = identify(_capture(frames, 30.0))
    assert result.verdict == "asl-serial-out (standard items)" and result.summary["samples"] == 150
    assert result.summary["garbage_bytes"] == 150 and result.summary["examples"]["garbage"][0].startswith("01 02 03")
