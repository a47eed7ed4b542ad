"""The gaze stream formats at the byte level (issue 20): ASL Serial Out, ASCII pairs, ASCII timestamped lines.

Every ASL fixture below is literal hex written by hand from the public description of the Serial Out stream, not
made with our encoder, with its derivation next to it. The description (two independent public readers agree):

* data items most significant byte first; the standard items ``status:u8 pupil:i16 spare:u8 x:i16 y:i16`` (8 data
  bytes, iCub ``MobileEye.cpp``; OGAMA's quote of the ASL manual), or with a ``u16`` frame counter after the status
  (10 data bytes, the Gold lab's ``asl.c``);
* the data bytes go in groups of 7, each group's bytes with bit 7 cleared, then one overflow byte whose bit i is bit 7
  of the group's i-th byte (iCub ``decode_buffer``: ``byte = inp_byte | ((overflow_byte << (7 - i)) & 0x80)``);
* the first wire byte of a frame has bit 7 set (the start mark), cleared before use (``if (i==0) inp_byte &= 0x7F``).

So a frame of 8 data bytes D0..D7 is ``D0|80 D1 .. D6 (low 7 bits) O1 D7 (low 7 bits) O2``: 10 bytes, and of 10 data
bytes ``D0|80 D1..D6 O1 D7 D8 D9 O2``: 12 bytes. The Gold lab's decode of a 12-byte frame (``asl.c``) is transcribed
in :func:`gold_decode` and checks our encoder independently of our decoder.
"""

from __future__ import annotations

import struct

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from wamctl.backends.gaze import asl, formats
from wamctl.backends.gaze.ascii_pair import PairStreamDecoder, format_pair, parse_pair
from wamctl.backends.gaze.asl import (
    COUNTER_FIELDS,
    STANDARD_FIELDS,
    AslLayout,
    AslStreamDecoder,
    data_length,
    wire_length,
)
from wamctl.backends.gaze.line_format import LineStreamDecoder
from wamctl.hmi.gaze import GazeFlag

H = bytes.fromhex

# ---------------------------------------------------------------------------------------------------------- fixtures
# Standard items, N = 8 data bytes, 10 wire bytes.
#
# A: status 0, pupil 40, spare 0, x 384, y 288.
#    D = 00 | 00 28 | 00 | 01 80 | 01 20 (384 = 0x0180, 288 = 0x0120, MSB first)
#    group 1 = D0..D6 = 00 00 28 00 01 80 01: only D5 = 0x80 has bit 7 -> O1 = bit 5 = 0x20; low 7 bits
#    00 00 28 00 01 00 01. Group 2 = D7 = 20 -> O2 = 00. Start mark: 00 | 80 = 80.
WIRE_A = H("80 00 28 00 01 00 01 20 20 00")
# B: status 0, pupil 0, spare 0, x -2000, y -2000: a blink both ways (pupil 0 is the tracker's loss code,
#    (-2000, -2000) the thesis' convention).
#    -2000 = 65536 - 2000 = 63536 = 0xF830. D = 00 00 00 00 F8 30 F8 30.
#    group 1 = 00 00 00 00 F8 30 F8: D4 and D6 have bit 7 -> O1 = 0x10 | 0x40 = 0x50; low bits 00 00 00 00 78 30 78.
#    group 2 = 30 -> O2 = 00.
WIRE_B = H("80 00 00 00 78 30 78 50 30 00")
# C: status 0x30, pupil 200, spare 0, x 700, y 500 (bit 7 in low bytes, and in group 2).
#    200 = 0x00C8, 700 = 0x02BC, 500 = 0x01F4. D = 30 00 C8 00 02 BC 01 F4.
#    group 1: D2 = C8 and D5 = BC -> O1 = 0x04 | 0x20 = 0x24; low bits 30 00 48 00 02 3C 01.
#    group 2: F4 -> O2 = 01, low bits 74. Start: 30 | 80 = B0.
WIRE_C = H("B0 00 48 00 02 3C 01 24 74 01")
# E: status 0x85 (bit 7 set: restored from O1 bit 0 after the start mark is cleared), pupil 40, x -1, y 0.
#    D = 85 00 28 00 FF FF 00 00: bits 7 of D0, D4, D5 -> O1 = 0x01 | 0x10 | 0x20 = 0x31; low bits
#    05 00 28 00 7F 7F 00; start 05 | 80 = 85. Group 2 = 00 -> O2 = 00.
WIRE_E = H("85 00 28 00 7F 7F 00 31 00 00")
# F: status 0, pupil 0, x 384, y 288: the tracker lost the pupil; the gaze is stale (no sentinel).
#    D = 00 00 00 00 01 80 01 20 -> as A but pupil 00 00: O1 = 0x20 (D5), O2 = 00.
WIRE_F = H("80 00 00 00 01 00 01 20 20 00")
# G: status 0, pupil 40, x -2000, y -2000: the sentinel with a pupil seen.
#    D = 00 00 28 00 F8 30 F8 30 -> O1 = 0x50 (D4, D6), low bits 00 00 28 00 78 30 78; group 2 = 30, O2 = 00.
WIRE_G = H("80 00 28 00 78 30 78 50 30 00")

# With a frame counter after the status, N = 10 data bytes, 12 wire bytes (the Gold lab's set-up).
# D1: status 0, counter 65535, pupil 40, spare 0, x 384, y 288.
#     D = 00 | FF FF | 00 28 | 00 | 01 80 | 01 20. Group 1 = 00 FF FF 00 28 00 01: D1, D2 -> O1 = 0x02 | 0x04 = 0x06,
#     low bits 00 7F 7F 00 28 00 01. Group 2 = 80 01 20: its byte 0 -> O2 = 0x01, low bits 00 01 20.
WIRE_D1 = H("80 7F 7F 00 28 00 01 06 00 01 20 01")
# D2: counter 0 (the rollover from 65535), pupil 40, x -2000, y -2000.
#     D = 00 | 00 00 | 00 28 | 00 | F8 30 | F8 30. Group 1 = 00 00 00 00 28 00 F8: D6 -> O1 = 0x40, low bits
#     00 00 00 00 28 00 78. Group 2 = 30 F8 30: its byte 1 -> O2 = 0x02, low bits 30 78 30.
WIRE_D2 = H("80 00 00 00 28 00 78 40 30 78 30 02")
# D3: counter 2 (frame 1 never arrived), pupil 40, x 384, y 288.
#     D = 00 | 00 02 | 00 28 | 00 | 01 80 | 01 20. Group 1 = 00 00 02 00 28 00 01: no bit 7 -> O1 = 00.
#     Group 2 = 80 01 20 -> O2 = 01, low bits 00 01 20.
WIRE_D3 = H("80 00 02 00 28 00 01 00 00 01 20 01")


def gold_decode(b: bytes) -> dict:
    """The Gold lab's decode of a 12-byte frame (``asl.c``, read from the public source), transcribed."""
    def s16(v):
        return struct.unpack(">h", struct.pack(">H", v & 0xFFFF))[0]
    return {"pupil": s16((b[3] | (b[7] & 0x08) << 4) << 8 | b[4] | (b[7] & 0x10) << 3),
            "x": s16((b[6] | (b[7] & 0x40) << 1) << 8 | b[8] | (b[11] & 0x01) << 7),
            "y": s16((b[9] | (b[11] & 0x02) << 6) << 8 | b[10] | (b[11] & 0x04) << 5),
            "counter": ((b[1] | (b[7] & 0x02) << 6) << 8 | b[2] | (b[7] & 0x04) << 5)}


def decode_all(decoder, chunks, arrival_s=0.0):
    out = []
    for i, chunk in enumerate(chunks):
        for frame in decoder.feed(chunk):
            d = decoder.decode(frame, arrival_s + i)
            if d is not None:
                out.append(d)
    return out


def test_wire_lengths_follow_the_groups_of_seven():
    assert [wire_length(n) for n in (1, 7, 8, 10, 14, 15)] == [2, 8, 10, 12, 16, 18]
    assert data_length(10) == 8 and data_length(12) == 10 and data_length(9) is None


@pytest.mark.parametrize("wire, status, pupil, x, y, flags", [
    (WIRE_A, 0, 40, 384.0, 288.0, GazeFlag(0)),
    (WIRE_B, 0, 0, -2000.0, -2000.0, GazeFlag.BLINK),
    (WIRE_C, 0x30, 200, 700.0, 500.0, GazeFlag(0)),
    (WIRE_E, 0x85, 40, -1.0, 0.0, GazeFlag.OUT_OF_RANGE),
])
def test_standard_frames_decode(wire, status, pupil, x, y, flags):
    (d,) = decode_all(AslStreamDecoder(), [wire])
    assert (d.fields["status"], d.fields["pupil"]) == (status, pupil)
    assert (d.sample.x_px, d.sample.y_px, d.sample.flags) == (x, y, flags)
    assert d.sample.t_s == d.arrival_s == 0.0  # no counter: the sample time is the arrival stamp


@pytest.mark.parametrize("rule, blink_f, blink_g", [
    ("either", True, True), ("pupil-zero", True, False), ("sentinel", False, True)])
def test_blink_rules_pupil_zero_and_sentinel(rule, blink_f, blink_g):
    """F: pupil 0 with a stale gaze; G: (-2000, -2000) with a pupil: a blink or not by the configured rule."""
    f, g = decode_all(AslStreamDecoder(blink=rule), [WIRE_F, WIRE_G])
    assert f.sample.is_blink is blink_f and g.sample.is_blink is blink_g
    if f.sample.is_blink:
        assert (f.sample.x_px, f.sample.y_px) == (-2000.0, -2000.0)  # the HMI's blink convention
    else:
        assert (f.sample.x_px, f.sample.y_px, f.sample.flags) == (384.0, 288.0, GazeFlag(0))
    if not g.sample.is_blink:
        assert g.sample.flags == GazeFlag.OUT_OF_RANGE


def test_counter_rollover_dropped_frame_and_rebuilt_times():
    dec = AslStreamDecoder(fields=COUNTER_FIELDS, counter_hz=30.0)
    # The three frames arrive in one read (a late reader): the counter spreads their times.
    d1, d2, d3 = decode_all(dec, [WIRE_D1 + WIRE_D2 + WIRE_D3], arrival_s=10.0)
    assert [d.fields["counter"] for d in (d1, d2, d3)] == [65535, 0, 2]
    assert [(d.sample.x_px, d.sample.y_px) for d in (d1, d3)] == [(384.0, 288.0)] * 2 and d2.sample.is_blink
    assert d1.sample.t_s == 10.0
    assert d2.sample.t_s == pytest.approx(10.0 + 1 / 30, abs=1e-12)  # 65535 -> 0: the next frame
    # 0 -> 2: one frame dropped. All three came at 10.0, so the anchor (the first arrival) was late: it slews
    # earlier by at most a tenth of a period per frame (CounterClock), which shortens this interval that much.
    assert d3.sample.t_s - d2.sample.t_s == pytest.approx(2 / 30, abs=0.1 / 30 + 1e-9)
    assert dec.stats.dropped_frames == 1
    for wire, d in ((WIRE_D1, d1), (WIRE_D2, d2), (WIRE_D3, d3)):
        assert gold_decode(wire) == {k: d.fields[k] for k in ("pupil", "counter")} | {
            "x": d.fields["raw_x"], "y": d.fields["raw_y"]}


def test_resync_after_garbage_and_a_lost_byte():
    """Garbage, A, B with its wire byte 4 lost, C: A and C come out; the truncated B is dropped whole."""
    stream = H("13 55") + WIRE_A + WIRE_B[:4] + WIRE_B[5:] + WIRE_C
    dec = AslStreamDecoder()
    out = decode_all(dec, [stream])
    assert [(d.fields["status"], d.fields["pupil"], d.sample.x_px, d.sample.y_px) for d in out] == [
        (0, 40, 384.0, 288.0), (0x30, 200, 700.0, 500.0)]
    st_ = dec.stats
    assert (st_.garbage_bytes, st_.cut_frames, st_.bad_frames, st_.frames) == (2, 1, 0, 2)
    assert st_.examples["garbage"] == ["13 55 (bit 7 clear outside a frame)"]
    assert st_.examples["cut"][0].startswith("80 00 00 00 30 78 50 30 00 (9 of 10 bytes")


def test_last_overflow_byte_with_bits_beyond_its_group_is_bad():
    """The last group of A holds one byte, so its overflow byte may only use bit 0: 0x02 there is a bad frame."""
    bad = WIRE_A[:9] + H("02")
    dec = AslStreamDecoder()
    assert decode_all(dec, [bad + WIRE_C]) and dec.stats.bad_frames == 1
    assert [d.fields["pupil"] for d in decode_all(AslStreamDecoder(), [bad + WIRE_C])] == [200]


def test_a_frame_split_across_reads_at_every_point():
    stream = H("13") + WIRE_A + H("55 07") + WIRE_C + WIRE_E
    expected = [(d.fields["pupil"], d.sample.x_px) for d in decode_all(AslStreamDecoder(), [stream])]
    assert expected == [(40, 384.0), (200, 700.0), (40, -1.0)]
    for cut in range(1, len(stream)):
        got = decode_all(AslStreamDecoder(), [stream[:cut], stream[cut:]])
        assert [(d.fields["pupil"], d.sample.x_px) for d in got] == expected, cut
    one_by_one = decode_all(AslStreamDecoder(), [bytes([b]) for b in stream])
    assert [(d.fields["pupil"], d.sample.x_px) for d in one_by_one] == expected


def test_flush_reports_an_unfinished_frame():
    dec = AslStreamDecoder()
    assert dec.feed(WIRE_A + WIRE_C[:6]) and dec.flush() and dec.stats.cut_frames == 1
    assert not AslStreamDecoder().flush()


def test_our_encoder_matches_the_hand_fixtures_and_the_gold_decode():
    std, cnt = AslLayout.parse(STANDARD_FIELDS), AslLayout.parse(COUNTER_FIELDS)
    assert std.encode({"status": 0, "pupil": 40, "x": 384, "y": 288}) == WIRE_A
    assert std.encode({"pupil": 0, "x": -2000, "y": -2000}) == WIRE_B
    assert std.encode({"status": 0x30, "pupil": 200, "x": 700, "y": 500}) == WIRE_C
    assert std.encode({"status": 0x85, "pupil": 40, "x": -1, "y": 0}) == WIRE_E
    assert cnt.encode({"counter": 65535, "pupil": 40, "x": 384, "y": 288}) == WIRE_D1
    assert cnt.encode({"counter": 0, "pupil": 40, "x": -2000, "y": -2000}) == WIRE_D2


@given(st.integers(0, 65535), st.integers(-32768, 32767), st.integers(-32768, 32767), st.integers(-32768, 32767))
@settings(max_examples=300, deadline=None)
def test_encoder_round_trips_through_the_gold_decode(counter, pupil, x, y):
    wire = AslLayout.parse(COUNTER_FIELDS).encode({"counter": counter, "pupil": pupil, "x": x, "y": y})
    assert gold_decode(wire) == {"counter": counter, "pupil": pupil, "x": x, "y": y}
    assert wire[0] & 0x80 and not any(b & 0x80 for b in wire[1:])


frames_st = st.lists(st.tuples(st.integers(0, 255), st.integers(-32768, 32767), st.integers(-32768, 32767),
                               st.integers(-32768, 32767)), min_size=1, max_size=20)


def _common_subsequence(a: list, b: list) -> int:
    """Length of the longest common subsequence of ``a`` and ``b``."""
    row = [0] * (len(b) + 1)
    for x in a:
        prev = 0
        for k, y in enumerate(b):
            prev, row[k + 1] = row[k + 1], prev + 1 if x == y else max(row[k + 1], row[k])
    return row[-1]


@given(frames_st, st.lists(st.binary(max_size=12), min_size=20, max_size=20), st.randoms(use_true_random=False))
@settings(max_examples=200, deadline=None)
def test_every_frame_survives_garbage_between_frames_and_any_chunking(frames, junk, rnd):
    """Garbage of any bytes between frames (not after two frames in a row: that is the signature of frames too
    short for the stream, see the next test): each real frame decodes, whatever the chunking (its start mark opens
    a new frame; garbage with bit 7 set may decode as frames of its own, there is no checksum to tell).

    A frame the garbage makes is a frame to the framer: a real frame followed by garbage, then a garbage frame
    followed by as many bytes, is the too-short signature, and the next real frame is withheld (found by a loaded
    run's random search: junk ``00 80 00*8 01 00``). Such a frame is not lost silently: it is counted bad with the
    reason. Garbage without start marks makes no frames, and then every real frame decodes."""
    layout = AslLayout.parse(STANDARD_FIELDS)
    stream = b"".join((junk[i] if i % 2 else b"") + layout.encode({"status": s, "pupil": p, "x": x, "y": y})
                      for i, (s, p, x, y) in enumerate(frames))
    cuts = sorted(rnd.sample(range(len(stream) + 1), min(5, len(stream) + 1)))
    chunks = [stream[a:b] for a, b in zip([0] + cuts, cuts + [len(stream)])]
    dec = AslStreamDecoder()
    got = [(d.fields["status"], d.fields["pupil"], d.fields["raw_x"], d.fields["raw_y"])
           for d in decode_all(dec, chunks)]
    missing = len(frames) - _common_subsequence(frames, got)   # real frames not among the decoded, in order
    assert missing <= dec.stats.bad_frames
    if not any(b & 0x80 for b in b"".join(junk)):
        assert missing == 0 and dec.stats.bad_frames == 0


def test_a_garbage_frame_can_make_the_too_short_signature():
    """The case the random search found: the real frame after it is withheld and counted bad, not lost silently."""
    layout = AslLayout.parse(STANDARD_FIELDS)
    wire = layout.encode({"status": 0, "pupil": 0, "x": 0, "y": 0})
    dec = AslStreamDecoder()
    out = decode_all(dec, [wire + bytes.fromhex("0080") + bytes(8) + bytes.fromhex("0100") + wire + wire])
    assert len(out) == 3 and dec.stats.bad_frames == 1      # real, garbage, real: the second real frame held
    assert "followed by 1 bytes without a start mark" in dec.stats.examples["bad"][0]


def test_frames_too_short_for_the_stream_are_withheld():
    """The counter frames D1, D2, D3, D1 read with the standard items (10 of their 12 bytes). D1 decodes to
    nonsense; D2's 10th byte (0x78) fails the last-overflow check; both are followed by 2 bytes without a start
    mark, so from then on frames are withheld as bad (D3, D1, and A, which still comes right after 2 such bytes)
    until a frame is followed directly by a start mark again (A is: C and E decode)."""
    dec = AslStreamDecoder()
    out = decode_all(dec, [WIRE_D1 + WIRE_D2 + WIRE_D3 + WIRE_D1, WIRE_A + WIRE_C + WIRE_E])
    assert [d.fields["pupil"] for d in out] == [-1, 200, 40]  # D1 read as pupil 0xFFFF, then C and E
    assert dec.stats.bad_frames == 4 and dec.stats.garbage_bytes == 8
    assert "the tracker's frames are 12 bytes (10 data bytes), not 10" in dec.stats.examples["bad"][1]


@pytest.mark.parametrize("fields, byte_order, values", [
    (["x:i16", "y:i16"], "big", {"x": 300, "y": -5}),
    (["status:u8", "counter:u32", "x:f32", "y:f32", "scene:u8"], "big", {"counter": 70000, "x": 1.5, "y": 2.25}),
    (["x:i16", "y:i16", "pupil:u16"], "little", {"x": 384, "y": 288, "pupil": 7}),
])
def test_configurable_items_and_byte_order(fields, byte_order, values):
    layout = AslLayout.parse(fields, byte_order)
    (d,) = decode_all(AslStreamDecoder(fields=fields, byte_order=byte_order), [layout.encode(values)])
    assert d.fields["raw_x"] == values["x"] and d.fields["raw_y"] == values["y"]


def test_little_endian_reads_the_hand_fixture_byte_swapped():
    """A read as little-endian: x = 0x8001 (-32767), y = 0x2001 (8193): the option does what it says."""
    (d,) = decode_all(AslStreamDecoder(byte_order="little"), [WIRE_A])
    assert (d.fields["raw_x"], d.fields["raw_y"], d.fields["pupil"]) == (-32767, 8193, 0x2800)


def test_scale_and_offset():
    (d,) = decode_all(AslStreamDecoder(scale=(0.1, 0.5), offset_px=(10.0, 0.0)), [WIRE_C])
    assert (d.sample.x_px, d.sample.y_px) == (80.0, 250.0)


@pytest.mark.parametrize("fields, match", [
    (["x:i16"], "no 'y' item"), (["x:i16", "y:int"], r"fields\[1\]"), (["x:i16", "y:i16", "x:u8"], "twice"),
    (["x:i16", "y:i16", "counter:i16"], "unsigned"),
])
def test_bad_layouts_name_the_item(fields, match):
    with pytest.raises(ValueError, match=match):
        AslStreamDecoder(fields=fields)


# ------------------------------------------------------------------------------------------------------------ ASCII
@pytest.mark.parametrize("line, xy, flags", [
    (b"384,288", (384.0, 288.0), GazeFlag(0)), (b"384 288", (384.0, 288.0), GazeFlag(0)),
    (b" 412.5 ,\t300 ", (412.5, 300.0), GazeFlag(0)), (b"-2000,-2000", (-2000.0, -2000.0), GazeFlag.BLINK),
    (b"900,10", (900.0, 10.0), GazeFlag.OUT_OF_RANGE),
])
def test_ascii_pair_lines(line, xy, flags):
    s = parse_pair(line, 1.5)
    assert (s.t_s, s.x_px, s.y_px, s.flags) == (1.5, *xy, flags)


@pytest.mark.parametrize("line", [b"1033,412.5,300", b"412", b"1e3,4", b"nan,1", b"4,\xff", b"1,2,", b",1"])
def test_ascii_pair_rejects(line):
    assert parse_pair(line, 0.0).flags == GazeFlag.CORRUPT


def test_ascii_pair_stream_stamps_each_line_with_its_arrival():
    dec = PairStreamDecoder()
    out = decode_all(dec, [b"# comment\r\n384,2", b"88\r\n-2000 -2000\n\n1,2,3\n", b"10,20"], arrival_s=5.0)
    assert [(d.sample.t_s, d.sample.x_px, d.sample.flags) for d in out] == [
        (6.0, 384.0, GazeFlag(0)), (6.0, -2000.0, GazeFlag.BLINK), (6.0, float("nan"), GazeFlag.CORRUPT)][:2] + [
        (out[2].sample.t_s, out[2].sample.x_px, GazeFlag.CORRUPT)]
    assert dec.flush() and dec.stats.cut_frames == 1 and dec.stats.corrupt == 1
    assert format_pair(384.0, 288.0) == b"384.0,288.0\n" and format_pair(-2000.0, -2000.0) == b"-2000,-2000\n"


def test_ascii_timestamped_keeps_the_tracker_time_and_the_arrival():
    (d,) = decode_all(LineStreamDecoder(), [b"1033,412.5,300.0\n"], arrival_s=7.0)
    assert (d.sample.t_s, d.arrival_s, d.sample.x_px) == (1.033, 7.0, 412.5)


def test_formats_do_not_read_each_other():
    """Each decoder turns the other formats into errors, not samples (what gaze-check relies on)."""
    streams = {"asl-serial-out": WIRE_A + WIRE_C, "ascii-pair": b"384,288\n700,500\n",
               "ascii-timestamped": b"33,384,288\n66,700,500\n"}
    for fmt in formats.FORMAT_NAMES:
        for other, data in streams.items():
            out = decode_all(formats.make_decoder(fmt), [data])
            good = [d for d in out if d.sample.has_time]
            assert len(good) == (2 if fmt == other else 0), (fmt, other)


def test_the_specs_lists_match_the_decoders():
    from wamctl.specs import hmi_block

    assert hmi_block.STREAM_FORMATS == formats.FORMAT_NAMES
    assert hmi_block.ASL_FIELD_TYPES == tuple(asl.FIELD_TYPES)
    assert hmi_block.ASL_STANDARD_FIELDS == asl.STANDARD_FIELDS
    assert formats.DEFAULT_FORMAT == hmi_block.SerialSourceSpec.model_fields["format"].default
