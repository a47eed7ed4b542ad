"""The gaze source section of an ``hmi_block`` spec (issue 20): defaults, every option reaching the source, and bad
values named by their field."""

from __future__ import annotations

import pytest

from wamctl.errors import SpecError
from wamctl.experiments.hmi_block.feeds import open_feed
from wamctl.specs import parse_spec


def _source(src: dict):
    return parse_spec({"kind": "hmi_block", "name": "t", "hmi": {"source": src}}).hmi


def test_serial_defaults_are_the_asl_serial_out_settings():
    src = _source({"kind": "serial", "url": "/dev/ttyUSB0"}).source
    assert (src.baudrate, src.bytesize, src.parity, src.stopbits, src.flow_control) == (57600, 8, "none", 1, "none")
    assert src.format == "asl-serial-out" and src.start_timeout_s == 30.0
    assert src.decoder_options() == {"fields": ["status:u8", "pupil:i16", "spare:u8", "x:i16", "y:i16"],
                                     "byte_order": "big", "blink": "either", "scale": (1.0, 1.0),
                                     "offset_px": (0.0, 0.0), "counter_hz": 30.0}
    assert _source({"kind": "serial", "url": "x", "format": "ascii-pair"}).source.decoder_options() == {}


def test_every_option_reaches_the_source(tmp_path):
    h = _source({"kind": "serial", "url": "loop://", "baudrate": 9600, "bytesize": 7, "parity": "odd",
                 "stopbits": 2, "flow_control": "xonxoff", "format": "asl-serial-out",
                 "asl": {"fields": ["status:u8", "counter:u16", "x:i16", "y:i16"], "byte_order": "little",
                         "blink": "sentinel", "scale": [0.5, 2.0], "offset_px": [1, 2], "counter_hz": 60}})
    feed = open_feed(h, tmp_path, tmp_path)
    try:
        src = feed.source
        assert src.settings == {"url": "loop://", "baudrate": 9600, "bytesize": 7, "parity": "O", "stopbits": 2,
                                "flow_control": "xonxoff", "format": "asl-serial-out"}
        assert src.port is None  # read in a child process (the port settings reaching pyserial: test_gaze_serial)
        dec = src.decoder
        assert dec.layout.names == ("status", "counter", "x", "y") and dec.layout.byte_order == "little"
        assert (dec.blink, dec.scale, dec.offset_px, dec.clock.counter_hz) == ("sentinel", (0.5, 2.0), (1.0, 2.0),
                                                                              60.0)
    finally:
        feed.close()
    assert (tmp_path / "gaze_capture.txt").is_file() and (tmp_path / "gaze_stream.json").is_file()


@pytest.mark.parametrize("src, match", [
    ({"kind": "serial", "url": "x", "asl": {"fields": ["x:i16", "y:int"]}},
     r"hmi.source.serial.asl: fields\[1\]: 'y:int' is not NAME:TYPE"),
    ({"kind": "serial", "url": "x", "asl": {"fields": ["status:u8", "x:i16"]}}, r"asl: fields: no 'y' item"),
    ({"kind": "serial", "url": "x", "asl": {"fields": ["x:i16", "y:i16", "counter:i16"]}}, "must be unsigned"),
    ({"kind": "serial", "url": "x", "asl": {"blink": "pupil-zero", "fields": ["x:i16", "y:i16"]}},
     "pupil-zero needs a pupil item"),
    ({"kind": "serial", "url": "x", "format": "ascii-pair", "asl": {}}, "asl: options of the asl-serial-out format"),
    ({"kind": "serial", "url": "x", "format": "binary"}, r"hmi.source.serial.format"),
    ({"kind": "serial", "url": "x", "parity": "odd-ish"}, r"hmi.source.serial.parity"),
    ({"kind": "serial", "url": "x", "stopbits": 3}, r"hmi.source.serial.stopbits"),
    ({"kind": "replay-raw", "path": "c.txt", "via": "tcp"}, r"hmi.source.replay-raw.via"),
])
def test_bad_source_values_name_the_field(src, match):
    with pytest.raises(SpecError, match=match):
        _source(src)
