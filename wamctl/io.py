"""Reading the files a user hands to wamctl: YAML documents and the format tags of wamctl's own files.

Imports nothing of wamctl but :mod:`wamctl.errors`, so every layer may use it.
"""

from __future__ import annotations

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


def load_yaml(path: str | Path, error: type[WamctlError] = SpecError, missing: str = "no such file") -> Any:
    """The YAML document in ``path``; ``error`` (a spec's or a data file's) naming the line and column of a
    syntax error, or ``missing`` when there is no such file."""
    path = Path(path)
    if not path.is_file():
        raise error(f"{path}: {missing}")
    try:
        return yaml.safe_load(path.read_text())
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f"line {mark.line + 1}, column {mark.column + 1}: " if mark else ""
        problem = getattr(exc, "problem", None) or str(exc)
        raise error(f"{path}: YAML syntax error at {where}{problem}") from None
