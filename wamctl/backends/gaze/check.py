"""What is this tracker sending? Try every known format on captured bytes: ``wamctl gaze-check`` and the message
of a session that got no sample.

:func:`identify` runs each candidate decoder (:data:`CANDIDATES`: ASL Serial Out with the standard items and with a
frame counter, ASCII pairs, ASCII timestamped lines) over one capture section, with the recorded arrival times, and
judges each: a candidate *decodes* when it gives at least :data:`MIN_SAMPLES` samples and its errors (cut and bad
frames, corrupt lines) are at most :data:`MAX_ERROR_SHARE` of its frames. Bytes outside frames are counted and
shown, not held against it (a stream with line noise still decodes; ASL items shorter than the tracker's frames are
caught by the framer, which withholds such frames). The best candidate (most samples, then fewest errors) is the
answer, with its sample rate, value ranges, how blinks showed, its framing errors and a spec section; if none
decodes the answer is "no known format", with the first bytes in hex and what they look like. :func:`check_port`
captures a port at each baud rate asked for and identifies each capture.
"""

from __future__ import annotations

import math
import time
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from wamctl.backends.gaze.asl import BAUD_RATE, COUNTER_FIELDS, STANDARD_FIELDS, data_length
from wamctl.backends.gaze.base import Decoded, hex_bytes, stream_problem
from wamctl.backends.gaze.capture import CaptureSection, CaptureWriter, MemoryCapture
from wamctl.backends.gaze.formats import FORMATS, make_decoder
from wamctl.hmi.gaze import BLINK_SENTINEL_PX

MIN_SAMPLES = 3
MAX_ERROR_SHARE = 0.10
#: Baud rates ``gaze-check`` suggests trying when nothing decodes.
COMMON_BAUDS = (57600, 115200, 38400, 19200, 9600)


@dataclass(frozen=True)
class Candidate:
    """A format with its options, as tried by :func:`identify`."""

    label: str
    format: str
    options: dict = field(default_factory=dict)
    short: str = ""


CANDIDATES: tuple[Candidate, ...] = (
    Candidate("asl-serial-out (standard items)", "asl-serial-out", {"fields": list(STANDARD_FIELDS)}, "asl std"),
    Candidate("asl-serial-out (frame counter after the status)", "asl-serial-out",
              {"fields": list(COUNTER_FIELDS)}, "asl counter"),
    Candidate("ascii-pair", "ascii-pair", short="ascii-pair"),
    Candidate("ascii-timestamped", "ascii-timestamped", short="ascii-ts"),
)


@dataclass
class Trial:
    """One candidate run over a capture: its decoded frames, counts and verdict."""

    candidate: Candidate
    decoded: list[Decoded]
    stats: dict
    decodes: bool
    why_not: str = ""

    @property
    def timed(self) -> list[Decoded]:
        return [d for d in self.decoded if d.sample.has_time]


@dataclass
class CheckResult:
    """What :func:`identify` found in one capture section."""

    info: dict
    n_bytes: int
    duration_s: float
    reads: int
    head_hex: str
    looks_like: str
    trials: list[Trial]
    best: Trial | None
    summary: dict = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)

    @property
    def verdict(self) -> str:
        if self.best is None:
            return "no known format" if self.n_bytes else "no bytes"
        return self.best.candidate.label

    def as_dict(self) -> dict:
        return {"settings": self.info, "bytes": self.n_bytes, "duration_s": round(self.duration_s, 3),
                "reads": self.reads, "verdict": self.verdict, "first_bytes_hex": self.head_hex,
                "looks_like": self.looks_like, "summary": self.summary, "notes": self.notes,
                "trials": [{"candidate": t.candidate.label, "format": t.candidate.format, "decodes": t.decodes,
                            "why_not": t.why_not, **{k: t.stats[k] for k in (
                                "samples", "valid", "blink", "corrupt", "garbage_bytes", "cut_frames",
                                "bad_frames", "dropped_frames")}} for t in self.trials]}


def _decode(fmt: str, options: dict, chunks: Sequence[tuple[float, bytes]]):
    decoder = make_decoder(fmt, **options)
    decoded: list[Decoded] = []
    for t_s, data in chunks:
        for frame in decoder.feed(data):
            d = decoder.decode(frame, t_s)
            if d is not None:
                decoded.append(d)
    decoder.flush()
    return decoder, decoded


def run_candidate(candidate: Candidate, chunks: Sequence[tuple[float, bytes]]) -> Trial:
    """Decode ``chunks`` (``(arrival_s, bytes)``) with a fresh decoder of ``candidate`` and judge the result. A frame
    counter's rate is measured on a first pass and the times rebuilt with it on a second."""
    decoder, decoded = _decode(candidate.format, candidate.options, chunks)
    hz = decoder.stats.extra.get("counter_hz_measured")
    if hz:
        candidate = Candidate(candidate.label, candidate.format, {**candidate.options, "counter_hz": float(hz)},
                              candidate.short)
        decoder, decoded = _decode(candidate.format, candidate.options, chunks)
    st = decoder.stats
    good = st.samples - st.corrupt
    errors = st.errors
    why = ""
    if good < MIN_SAMPLES:
        why = f"{good} sample(s)"
    elif errors > MAX_ERROR_SHARE * (good + errors):
        why = f"{errors} errors for {good} samples"
    return Trial(candidate, decoded, st.as_dict(), not why, why)


def start_mark_spacing(data: bytes) -> tuple[int | None, float]:
    """The most common distance between bytes with bit 7 set, and the share of distances that have it."""
    idx = np.flatnonzero(np.frombuffer(data, np.uint8) >= 0x80)
    if len(idx) < 3:
        return None, 0.0
    gaps = np.diff(idx)
    values, counts = np.unique(gaps, return_counts=True)
    k = int(np.argmax(counts))
    return int(values[k]), float(counts[k] / len(gaps))


def looks_like(data: bytes) -> str:
    """A few words on what bytes look like: nothing, ASCII text, start-marked binary frames, or noise."""
    if not data:
        return "nothing"
    arr = np.frombuffer(data, np.uint8)
    printable = float(np.mean(((arr >= 0x20) & (arr < 0x7F)) | (arr == 0x0A) | (arr == 0x0D) | (arr == 0x09)))
    if printable > 0.95:
        lines = data.replace(b"\r", b"\n").split(b"\n")
        first = next((ln for ln in lines[1:] if ln.strip()), lines[0])[:40]
        return f"ASCII text ({100 * printable:.0f} % printable), e.g. the line {first.decode('ascii', 'replace')!r}"
    spacing, share = start_mark_spacing(data)
    if spacing is not None and share > 0.8:
        n = data_length(spacing)
        what = (f"ASL Serial Out framing with {n} data bytes" if n is not None
                else "no ASL Serial Out frame has that length")
        return f"binary frames: a byte with bit 7 set every {spacing} bytes ({100 * share:.0f} %): {what}"
    return (f"no structure found ({100 * printable:.0f} % printable, {100 * float(np.mean(arr >= 0x80)):.0f} % "
            f"with bit 7 set): noise, e.g. a wrong baud rate, parity or stop bits")


def summarise(trial: Trial) -> dict:
    """Rate, value ranges and blinks of a trial that decodes."""
    timed = trial.timed
    t = np.array([d.sample.t_s for d in timed])
    out: dict = {"format": trial.candidate.format, "samples": len(timed)}
    if len(t) >= 2 and t[-1] > t[0]:
        out["rate_hz"] = round((len(t) - 1) / (t[-1] - t[0]), 2)
        dt = np.diff(t)
        out["period_p50_ms"] = round(1e3 * float(np.median(dt)), 2)
        out["period_jitter_p99_ms"] = round(1e3 * float(np.percentile(np.abs(dt - np.median(dt)), 99)), 2)
    arrival = np.array([d.arrival_s for d in timed])
    if len(arrival) >= 2:
        da = np.diff(arrival)
        out["arrival_jitter_p99_ms"] = round(1e3 * float(np.percentile(np.abs(da - np.median(da)), 99)), 2)
        out["arrival_bursts"] = int(np.sum(da == 0.0))
    seen = [d for d in timed if not d.sample.is_blink]
    if seen:
        xs = np.array([d.sample.x_px for d in seen])
        ys = np.array([d.sample.y_px for d in seen])
        out["x_px"] = [round(float(xs.min()), 1), round(float(xs.max()), 1)]
        out["y_px"] = [round(float(ys.min()), 1), round(float(ys.max()), 1)]
        out["out_of_range"] = trial.stats["out_of_range"]
    for key in ("pupil", "status", "counter"):
        vals = [d.fields[key] for d in timed if key in d.fields]
        if vals:
            out[key] = [min(vals), max(vals)] if key != "status" else sorted(set(vals))[:8]
    pupil_zero = sum(1 for d in timed if d.fields.get("pupil") == 0)
    sentinel = sum(1 for d in timed if d.fields.get("raw_x") == BLINK_SENTINEL_PX
                   and d.fields.get("raw_y") == BLINK_SENTINEL_PX)
    out["blinks"] = {"samples": trial.stats["blink"], "pupil_zero": pupil_zero, "sentinel_-2000": sentinel}
    for k in ("garbage_bytes", "cut_frames", "bad_frames", "corrupt", "dropped_frames", "clock_adjusts"):
        out[k] = trial.stats[k]
    out["examples"] = trial.stats["examples"]
    if "counter_hz_measured" in trial.stats:
        out["counter_hz"] = trial.stats["counter_hz_measured"]
    return out


def _notes(result: CheckResult) -> list[str]:
    notes = []
    s = result.summary
    info = result.info
    if result.best is None:
        if not result.n_bytes:
            notes.append("nothing arrived: is the tracker streaming (ASL: Serial Out in streaming mode), is the "
                         "cable on its SERIAL OUT port (null-modem between two PC-style ports), is it the right port "
                         "(ls /dev/serial/by-id), does another program hold it?")
        elif "ASCII text" in result.looks_like:
            notes.append("the bytes are text but not 'x,y' nor 't_ms,x_px,y_px' lines: check the relay program's "
                         "output format")
        elif "binary frames" in result.looks_like and "ASL" in result.looks_like:
            notes.append("ASL framing with other items than the standard ones: set asl.fields to the items checked "
                         "in the tracker's Serial Out Format dialog (x and y named x, y), then check again")
        else:
            bauds = ", ".join(str(b) for b in COMMON_BAUDS if b != info.get("baudrate"))
            notes.append(f"try other baud rates (--baud {bauds}; ASL Serial Out runs at {BAUD_RATE} Bd 8N1) and "
                         f"check parity, stop bits and the cable")
        return notes
    if s.get("blinks", {}).get("samples", 0) == 0:
        notes.append("no blink seen: close the eyes for a second during the check to see how the tracker signals "
                     "them")
    stamped = result.best.candidate.format != "ascii-timestamped" and "counter" not in s
    if s.get("arrival_jitter_p99_ms", 0) > 5.0 and stamped:
        notes.append(f"reads arrive in bursts (inter-arrival jitter p99 {s['arrival_jitter_p99_ms']} ms): samples "
                     f"stamped on arrival inherit it. A USB serial adapter holds bytes up to its latency timer "
                     f"(FTDI: 16 ms); set it to 1 ms (see the README)")
    if s.get("dropped_frames"):
        notes.append(f"the frame counter skipped {s['dropped_frames']} frame(s)")
    if "counter_hz" in s:
        notes.append(f"counter: {s['counter_hz']} counts/s measured; set asl.counter_hz to the tracker's rate")
    return notes


def identify(section: CaptureSection, candidates: Sequence[Candidate] = CANDIDATES) -> CheckResult:
    """Try every candidate on one capture section; the best one that decodes, or none."""
    data = section.data
    trials = [run_candidate(c, section.chunks) for c in candidates]
    ok = [t for t in trials if t.decodes]
    best = max(ok, key=lambda t: (len(t.timed), -t.stats["corrupt"] - t.stats["cut_frames"]
                                  - t.stats["bad_frames"])) if ok else None
    result = CheckResult(section.info, len(data), section.duration_s, len(section.chunks), hex_bytes(data, 64),
                         looks_like(data), trials, best, summarise(best) if best else {})
    result.notes = _notes(result)
    return result


def suggested_spec(result: CheckResult) -> str:
    """The ``source:`` section of an ``hmi_block`` spec for what was found (YAML text), or '' if nothing decodes."""
    if result.best is None:
        return ""
    info, cand, s = result.info, result.best.candidate, result.summary
    lines = ["source:", "  kind: serial", f"  url: {info.get('url', '/dev/ttyUSB0')}",
             f"  baudrate: {info.get('baudrate', BAUD_RATE)}"]
    if info.get("parity", "N") != "N":
        lines.append(f"  parity: {({'E': 'even', 'O': 'odd', 'M': 'mark', 'S': 'space'})[info['parity']]}")
    if info.get("stopbits", 1) != 1:
        lines.append(f"  stopbits: {info['stopbits']}")
    lines.append(f"  format: {cand.format}")
    if cand.format == "asl-serial-out":
        blinks = s.get("blinks", {})
        seen = ("pupil 0 seen" if blinks.get("pupil_zero") else "no pupil 0 seen") + ", " + (
            "(-2000, -2000) seen" if blinks.get("sentinel_-2000") else "no (-2000, -2000) seen")
        lines += ["  asl:", f"    fields: [{', '.join(cand.options['fields'])}]",
                  f"    blink: either   # {seen}"]
        if "counter" in ",".join(cand.options["fields"]):
            hz = s.get("counter_hz") or s.get("rate_hz") or 30.0
            lines.append(f"    counter_hz: {round(float(hz))}   # measured {hz}")
    return "\n".join(lines) + "\n"


def check_port(url: str, *, seconds: float = 5.0, bauds: Sequence[int] = (BAUD_RATE,),
               candidates: Sequence[Candidate] = CANDIDATES, capture_path=None, progress=None,
               **port_options) -> list[CheckResult]:
    """Capture ``seconds`` of bytes from ``url`` at each baud rate and identify each capture.

    ``port_options`` go to :class:`~wamctl.backends.gaze.serial.SerialGazeSource` (bytesize, parity, stopbits,
    flow_control); ``capture_path`` also writes the captures to a file (one section per baud rate);
    ``progress(k, n, label)`` is called before each baud rate.
    """
    from wamctl.backends.gaze.serial import SerialGazeSource

    results = []
    for k, baud in enumerate(bauds):
        if progress is not None:
            progress(k, len(bauds), f"{url} at {baud} Bd")
        source = SerialGazeSource(url, baudrate=baud, timeout_s=0.05, **port_options)
        info = {**source.settings, "format": None, "seconds": seconds}
        writer = CaptureWriter(capture_path, info) if capture_path is not None else None
        memory = MemoryCapture(info, writer)
        source.capture = memory
        with source:
            end = time.monotonic() + seconds
            while (left := end - time.monotonic()) > 0 and not source.exhausted:
                source.read_decoded(min(left, 0.1))
        results.append(identify(memory.section, candidates))
    if progress is not None:
        progress(len(bauds), len(bauds), url)
    return results


def best_of(results: Sequence[CheckResult]) -> CheckResult | None:
    """The result that decodes the most samples, or None."""
    ok = [r for r in results if r.best is not None]
    return max(ok, key=lambda r: len(r.best.timed)) if ok else None


def describe_silence(source, waited_s: float) -> str:
    """Why no usable gaze stream came from a serial source in ``waited_s``: what arrived and what to try.

    ``source`` is a :class:`~wamctl.backends.gaze.serial.SerialGazeSource` (its settings, the bytes it kept from the
    start of the stream and its decoder's counts).
    """
    st = source.stats
    info = source.settings
    where = f"{info['url']} at {info['baudrate']} Bd {info['bytesize']}{info['parity']}{info['stopbits']:g}"
    if not st.bytes:
        return (f"no gaze sample within {waited_s:g} s: no byte arrived on {where}. Check that the tracker streams "
                f"(ASL: Serial Out enabled, streaming mode), the cable (the tracker's SERIAL OUT port; null modem "
                f"between two PC-style ports) and the port name; then run `wamctl gaze-check --port {info['url']}`.")
    good = st.samples - st.corrupt
    what = ("no gaze sample" if good == 0 else
            f"no usable gaze stream ({stream_problem(st) or 'too few samples'})")
    rate = st.bytes / max(waited_s, 1e-9)
    counts = (f"{st.frames} frame(s) of {info['format']}, {good} sample(s), {st.garbage_bytes} byte(s) outside "
              f"frames, {st.cut_frames} cut frame(s), {st.bad_frames} bad frame(s), {st.corrupt} corrupt")
    head = CaptureSection(info, list(source.head))
    found = identify(head)
    if found.best is not None and found.best.candidate.format != info["format"]:
        c = found.best.candidate
        fields = f" with asl.fields [{', '.join(c.options['fields'])}]" if "fields" in c.options else ""
        todo = f"these bytes decode as {c.label}: set source.format: {c.format}{fields}"
    elif found.best is not None:
        c = found.best.candidate
        todo = f"these bytes decode as {c.label}: set asl.fields [{', '.join(c.options.get('fields', []))}]"
    else:
        todo = f"they look like {found.looks_like}; " + " ".join(found.notes)
    bad = next((f" First {k} frame: {v[0]}." for k, v in st.examples.items() if v and k in ("bad", "cut")), "")
    return (f"{what} within {waited_s:g} s from {where}, format {info['format']}: {st.bytes} bytes arrived "
            f"({rate:.0f} B/s, {source.reads} reads): {counts}. First bytes: {hex_bytes(head.data, 48)}.{bad} "
            f"What to try: {todo}; `wamctl gaze-check --port {info['url']}` tries every format and baud rate.")


def rate_text(summary: dict) -> str:
    hz = summary.get("rate_hz")
    return "?" if hz is None or not math.isfinite(hz) else f"{hz:g} Hz"


__all__ = ["CANDIDATES", "Candidate", "CheckResult", "FORMATS", "best_of", "check_port", "describe_silence",
           "identify", "suggested_spec", "summarise"]
