"""Reading the files a user hands over: every way a file can be wrong ends in one error naming the file."""

from __future__ import annotations

import pytest

from wamctl.errors import DataFormatError, SpecError, WamctlError
from wamctl.io import ensure_dir, load_yaml


@pytest.mark.parametrize("raw,message", [
    (b"kind: rotation\nseed: 1\nname: a\nseed: 2\n", "line 4, column 1: duplicate key 'seed' (first given at line 2)"),
    (b"a:\n  b: 1\n  b: 1\n", "line 3, column 3: duplicate key 'b'"),
    (b"\x00\x01\x02binary", "binary data (a NUL byte at offset 0)"),
    (b"kind: caf\xe9\n", "not UTF-8 text (byte 0xe9 on line 1)"),
    (b"kind: [1, 2\n", "YAML syntax error at line 2, column 1"),
    (b"[" * 5000, "YAML"),
])
def test_bad_yaml_is_one_error_naming_the_file(tmp_path, raw, message):
    p = tmp_path / "spec.yaml"
    p.write_bytes(raw)
    with pytest.raises(SpecError) as e:
        load_yaml(p)
    assert str(e.value).startswith(f"{p}: ") and message in str(e.value) and "\n" not in str(e.value)


def test_merge_keys_may_override_and_other_encodings_with_a_mark_are_read(tmp_path):
    p = tmp_path / "a.yaml"
    p.write_text("base: &b {x: 1, y: 2}\nuse:\n  <<: *b\n  y: 3\n")
    assert load_yaml(p)["use"] == {"x": 1, "y": 3}
    p.write_bytes("kind: caf\u00e9\n".encode("utf-16"))
    assert load_yaml(p) == {"kind": "caf\u00e9"}
    p.write_bytes(b"\xef\xbb\xbfkind: rotation\n")
    assert load_yaml(p) == {"kind": "rotation"}


def test_a_directory_or_a_missing_file(tmp_path):
    with pytest.raises(SpecError, match="is a directory; expected a YAML file"):
        load_yaml(tmp_path)
    with pytest.raises(DataFormatError, match="meta.yaml: gone"):
        load_yaml(tmp_path / "meta.yaml", DataFormatError, "gone")


def test_ensure_dir_names_a_file_in_the_way_or_an_impossible_place(tmp_path):
    f = tmp_path / "file"
    f.write_text("x")
    assert ensure_dir(tmp_path / "new" / "deeper").is_dir()
    with pytest.raises(WamctlError, match="is a file"):
        ensure_dir(f)
    with pytest.raises(WamctlError, match=f"{f} is a file"):
        ensure_dir(f / "sub")
    with pytest.raises(WamctlError, match="cannot create"):
        ensure_dir("/proc/no/such/place")
