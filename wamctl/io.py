"""Reading the files a user hands to wamctl: YAML documents and the format tags of wamctl's own files.

Imports nothing of wamctl but :mod:`wamctl.errors`, so every layer may use it.

A file that is not what it should be ends in one error naming the file and what is wrong with it: a directory
given as a file, bytes that are not text (binary garbage, another encoding), a YAML syntax error (with its line
and column), and a key given twice in one mapping (YAML's specification forbids it; PyYAML would silently keep
the last one, so a typo'd copy-paste would change an experiment without a word).
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import yaml

from wamctl.errors import SpecError, WamctlError

MODEL_FILE_FORMAT = "wamctl-model/1"        # a plant description (friction, effects, sensors), `plant: FILE`


def resolve_path(path: str | Path, base_dir: str | Path | None) -> Path:
    """A path written in a spec: as given when it is absolute or exists from the working directory, else
    relative to the spec's folder ``base_dir``."""
    p = Path(path)
    if not p.is_absolute() and base_dir is not None and not p.exists():
        p = Path(base_dir) / p
    return p


class _UniqueKeyLoader(getattr(yaml, "CSafeLoader", yaml.SafeLoader)):
    """PyYAML's safe loader (libyaml's parser when PyYAML has it), refusing a mapping that gives the same key
    twice."""


def _construct_mapping(loader: _UniqueKeyLoader, node: yaml.MappingNode, deep: bool = False):
    seen: dict = {}
    for key_node, _ in node.value:     # the keys written here: one merged in by `<<` may be overridden
        if key_node.tag == "tag:yaml.org,2002:merge":
            continue
        try:
            key = loader.construct_object(key_node, deep=True)
            hash(key)
        except TypeError:
            continue   # an unhashable key: PyYAML's own check reports it below
        if key in seen:
            raise yaml.constructor.ConstructorError(
                None, None, f"duplicate key {key!r} (first given at line {seen[key].line + 1})", key_node.start_mark)
        seen[key] = key_node.start_mark
    return yaml.constructor.SafeConstructor.construct_mapping(loader, node, deep)


_UniqueKeyLoader.add_constructor(yaml.resolver.BaseResolver.DEFAULT_MAPPING_TAG, _construct_mapping)


def read_text(path: str | Path, error: type[WamctlError] = SpecError, missing: str = "no such file",
              what: str = "a text file") -> str:
    """The text of ``path`` (UTF-8, with or without a byte-order mark; UTF-16 with one), or ``error`` naming
    the file: missing, a directory, unreadable, binary, or not UTF-8."""
    path = Path(path)
    if path.is_dir():
        raise error(f"{path}: is a directory; expected {what}")
    if not path.is_file():
        raise error(f"{path}: {missing}")
    try:
        raw = path.read_bytes()
    except OSError as exc:
        raise error(f"{path}: cannot be read ({exc.strerror or exc})") from None
    if raw.startswith((b"\xff\xfe", b"\xfe\xff")):
        try:
            return raw.decode("utf-16")
        except UnicodeDecodeError:
            raise error(f"{path}: not valid UTF-16 text despite its byte-order mark") from None
    if b"\x00" in raw:
        raise error(f"{path}: binary data (a NUL byte at offset {raw.index(bytes(1))}); expected {what}")
    try:
        return raw.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        line = raw[: exc.start].count(b"\n") + 1
        raise error(f"{path}: not UTF-8 text (byte 0x{raw[exc.start]:02x} on line {line}); expected {what} "
                    "saved as UTF-8") from None


def parse_yaml(text: str, source: str, error: type[WamctlError] = SpecError) -> Any:
    """The YAML document in ``text``; ``error`` naming ``source`` and the line and column of a syntax error
    or a duplicate key."""
    try:
        return yaml.load(text, Loader=_UniqueKeyLoader)   # noqa: S506 - a SafeLoader subclass
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f"line {mark.line + 1}, column {mark.column + 1}: " if mark else ""
        problem = getattr(exc, "problem", None) or str(exc).splitlines()[0]
        kind = "duplicate key" if problem.startswith("duplicate key") else "YAML syntax error"
        if kind == "duplicate key":
            raise error(f"{source}: {where}{problem}") from None
        raise error(f"{source}: {kind} at {where}{problem}") from None
    except RecursionError:
        raise error(f"{source}: YAML nested too deeply") from None


def load_yaml(path: str | Path, error: type[WamctlError] = SpecError, missing: str = "no such file") -> Any:
    """The YAML document in ``path``; ``error`` (a spec's or a data file's) naming the file and what is wrong:
    missing (``missing``), a directory, not UTF-8 text, a syntax error or a duplicate key (line and column)."""
    return parse_yaml(read_text(path, error, missing, "a YAML file"), str(path), error)


def ensure_dir(path: str | Path, what: str = "output directory") -> Path:
    """``path`` as an existing, writable directory (created with its parents when missing), or a
    :class:`WamctlError` naming it: a file in the way, or a place that cannot be written."""
    path = Path(path)
    for p in (path, *path.parents):
        if p.exists() and not p.is_dir():
            raise WamctlError(f"{path}: {'is a file' if p == path else f'{p} is a file'}; the {what} must be a "
                              "directory")
        if p.exists():
            break
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise WamctlError(f"{path}: cannot create the {what} ({exc.strerror or exc})") from None
    if not os.access(path, os.W_OK | os.X_OK):
        raise WamctlError(f"{path}: the {what} is not writable")
    return path
