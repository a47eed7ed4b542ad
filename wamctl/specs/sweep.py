"""The ``vary:`` section of a sweep spec, and its expansion into the points of a sweep.

A ``vary:`` section in a spec of any kind names the fields to vary; each point is an ordinary spec (run by
:mod:`wamctl.experiments.sweep`, which indexes the runs in a sweep directory).

The ``vary:`` section
---------------------
(Not ``sweep:``: the friction_sweep kind already has a ``sweep:`` field, its schedule, and a friction sweep
must be sweepable too, e.g. ``vary: {grid: {sweep.joints: [[1], [7]], seed: [0, 1]}}``.)
Fields are named by dotted paths into the spec (``plant.effects.stribeck.breakaway_ratio``, ``seed``,
``q0_rad.3`` for a list element, ``subject.id`` for an hmi block's subject)::

    vary:
      grid:                       # every combination (cartesian product, last key varies fastest)
        plant.effects.stribeck.breakaway_ratio: [1.2, 2.0]
        seed: {range: [0, 50]}    # 0..49; also {range: [stop]}, {range: [start, stop, step]}
      zip:                        # varied together (equal lengths)
        rotation.amplitude_rad: [0.1, 0.2]
        rotation.velocity_rad_s: {linspace: [0.1, 0.3, 2]}
      points:                     # an explicit list of points, each a mapping of path -> value
        - {plant.friction: table_4_1}
        - {plant.friction: none}
      retries: 2                  # re-runs of a point after an unexpected error (not after a spec error)
      reports: true               # write each run's own report (figures: ~1 s per point)
      name: my-sweep              # sweep directory name (default: the spec's name)

The points are ``points x zip x grid`` (each factor absent counts as one empty point). The section is
taken out before the spec's own validation; every expanded point is then validated with
:func:`wamctl.specs.parse_spec`, and an invalid point stops the sweep before anything runs, with an error
naming the point, its values and the field.
"""

from __future__ import annotations

import copy
import itertools
import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from pydantic import Field, ValidationError, model_validator

from wamctl.errors import SpecError
from wamctl.io import load_yaml, resolve_path
from wamctl.specs.common import Strict
from wamctl.specs.load import load_model_file, parse_spec

MAX_POINTS = 100_000
SECTION = "vary"  # the key of the section in a spec
FORBIDDEN_PATHS = ("kind", "out_dir", SECTION)


# ---------------------------------------------------------------------------------------------- the section
class VarySection(Strict):
    """The ``vary:`` section of a spec (see the module docstring)."""

    grid: dict[str, Any] = Field(default_factory=dict, description="path -> values; every combination")
    zip: dict[str, Any] = Field(default_factory=dict, description="path -> values; varied together")
    points: list[dict[str, Any]] = Field(default_factory=list, description="explicit points, path -> value")
    retries: int = Field(2, ge=0, le=20, description="Dask retries of a point after an unexpected error")
    reports: bool = Field(True, description="write each run's own report (with figures)")
    name: str | None = Field(None, pattern=r"^[A-Za-z0-9_.-]+$", description="default: the spec's name")

    @model_validator(mode="after")
    def _not_empty(self):
        if not (self.grid or self.zip or self.points):
            raise ValueError("needs at least one of grid, zip or points")
        return self


def expand_values(value: Any, where: str) -> list:
    """The values of one swept field: a list, ``{range: [start, ]stop[, step]}``, ``{linspace: [a, b, n]}``
    or a single scalar. Raises :class:`SpecError` naming ``where``."""
    if isinstance(value, list):
        if not value:
            raise SpecError(f"{where}: an empty list of values")
        return list(value)
    if isinstance(value, dict):
        if set(value) == {"range"}:
            args = value["range"] if isinstance(value["range"], list) else [value["range"]]
            if not (1 <= len(args) <= 3) or not all(isinstance(a, int) and not isinstance(a, bool) for a in args):
                raise SpecError(f"{where}: range takes 1 to 3 integers: [stop], [start, stop] or "
                                f"[start, stop, step]")
            if len(args) == 3 and args[2] == 0:
                raise SpecError(f"{where}: range step must not be 0")
            out = list(range(*args))
            if not out:
                raise SpecError(f"{where}: range {args} is empty")
            return out
        if set(value) == {"linspace"}:
            args = value["linspace"]
            if (not isinstance(args, list) or len(args) != 3 or not isinstance(args[2], int)
                    or isinstance(args[2], bool) or args[2] < 1):
                raise SpecError(f"{where}: linspace takes [start, stop, n] with an integer n >= 1")
            try:
                return [float(v) for v in np.linspace(float(args[0]), float(args[1]), args[2])]
            except (TypeError, ValueError):
                raise SpecError(f"{where}: linspace start and stop must be numbers") from None
        raise SpecError(f"{where}: give a list of values, {{range: [start, stop, step]}} or "
                        f"{{linspace: [start, stop, n]}}, not a mapping with keys {sorted(value)}")
    return [value]


def _check_path(path: Any, where: str) -> str:
    if not isinstance(path, str) or not path or any(not c for c in path.split(".")):
        raise SpecError(f"{where}: {path!r} is not a dotted path (e.g. plant.effects.stribeck.breakaway_ratio)")
    if path.split(".")[0] in FORBIDDEN_PATHS:
        raise SpecError(f"{where}: {path}: `{path.split('.')[0]}` cannot be swept")
    return path



def expand_section(section: VarySection) -> list[dict[str, Any]]:
    """Every point of a section as a mapping ``path -> value``, in order (points x zip x grid)."""
    seen: dict[str, str] = {}

    def claim(path, part):
        if path in seen and seen[path] != part:
            raise SpecError(f"{SECTION}: {path} is varied in both {seen[path]} and {part}")
        seen[path] = part

    listed = []
    for i, p in enumerate(section.points):
        point = {}
        for path, v in p.items():
            claim(_check_path(path, f"{SECTION}.points[{i}]"), "points")
            point[path] = v
        listed.append(point)
    listed = listed or [{}]

    zipped = [{}]
    if section.zip:
        cols = _value_columns(section.zip, "zip", claim)
        lengths = {p: len(v) for p, v in cols.items()}
        if len(set(lengths.values())) > 1:
            raise SpecError(f"{SECTION}.zip: the lists must have equal lengths: "
                            + ", ".join(f"{p} has {n}" for p, n in lengths.items()))
        zipped = [dict(zip(cols, vals)) for vals in zip(*cols.values())]

    grid = [{}]
    if section.grid:
        cols = _value_columns(section.grid, "grid", claim)
        n = math.prod(len(v) for v in cols.values())
        if n * len(listed) * len(zipped) > MAX_POINTS:
            raise SpecError(f"{SECTION}: {n * len(listed) * len(zipped)} points, more than {MAX_POINTS}")
        grid = [dict(zip(cols, vals)) for vals in itertools.product(*cols.values())]

    n = len(listed) * len(zipped) * len(grid)
    if n > MAX_POINTS:
        raise SpecError(f"{SECTION}: {n} points, more than {MAX_POINTS}")
    return [{**a, **b, **c} for a in listed for b in zipped for c in grid]


def _value_columns(part: dict[str, Any], name: str, claim) -> dict[str, list]:
    """path -> its list of values, for the ``zip`` or ``grid`` part of a section (``claim(path, name)`` refuses
    a path varied in two parts)."""
    cols = {}
    for path, v in part.items():
        claim(_check_path(path, f"{SECTION}.{name}"), name)
        cols[path] = expand_values(v, f"{SECTION}.{name}.{path}")
    return cols


def set_path(data: dict, path: str, value: Any, where: str = SECTION) -> None:
    """Set ``path`` (dotted; integer components index lists, or match integer mapping keys) in place,
    creating missing mappings. Raises :class:`SpecError` naming ``where`` and the path."""
    parts = path.split(".")
    node: Any = data
    for depth, part in enumerate(parts):
        last = depth == len(parts) - 1
        here = ".".join(parts[: depth + 1])
        if isinstance(node, list):
            try:
                i = int(part)
            except ValueError:
                raise SpecError(f"{where}: {path}: {'.'.join(parts[:depth]) or 'the spec'} is a list; "
                                f"{part!r} is not an index") from None
            if not -len(node) <= i < len(node):
                raise SpecError(f"{where}: {path}: index {i} outside the list of {len(node)}")
            if last:
                node[i] = copy.deepcopy(value)
            else:
                if node[i] is None:
                    node[i] = {}
                node = node[i]
        elif isinstance(node, dict):
            key: Any = part
            if part not in node and part.lstrip("-").isdigit() and int(part) in node:
                key = int(part)  # YAML mappings keyed by joint number: {1: {...}}
            if last:
                node[key] = copy.deepcopy(value)
            else:
                if node.get(key) is None:
                    node[key] = {}
                node = node[key]
        else:
            raise SpecError(f"{where}: {path}: cannot go into {'.'.join(parts[:depth])} = {node!r} "
                            f"(not a mapping or list) to set {here}")


def apply_values(base: dict, values: dict[str, Any], where: str = SECTION) -> dict:
    """A deep copy of ``base`` with every ``path -> value`` of ``values`` set."""
    data = copy.deepcopy(base)
    for path, value in values.items():
        set_path(data, path, value, where)
    return data


def describe_values(values: dict[str, Any], width: int = 100) -> str:
    s = ", ".join(f"{p}={_short(v)}" for p, v in values.items())
    return s if len(s) <= width else s[: width - 3] + "..."


def point_problems(source: str, problems: list[tuple[str, dict, str]], total: int, what: str,
                   max_lines: int = 20) -> str:
    """The message for the points of a sweep that a check refused: ``problems`` holds (point id, swept values,
    the problem without the point's name). Points with the same problem share one line (a mistake in the spec
    every point inherits is said once, not once per point)."""
    groups: dict[str, list[tuple[str, dict]]] = {}
    for pid, vals, core in problems:
        groups.setdefault(core, []).append((pid, vals))
    lines = []
    for core, pts in groups.items():
        if len(pts) == total > 1:
            lines.append(f"{source}: all {total} points: {core}")
        elif len(pts) == 1:
            lines.append(f"{source}: point {pts[0][0]} ({describe_values(pts[0][1], 80)}): {core}")
        else:
            named = ", ".join(f"{pid} ({describe_values(v, 40)})" for pid, v in pts[:5])
            more = f" and {len(pts) - 5} more" if len(pts) > 5 else ""
            lines.append(f"{source}: points {named}{more}: {core}")
    more = f"\n... and {len(lines) - max_lines} more problems" if len(lines) > max_lines else ""
    return f"{len(problems)} of {total} sweep points {what}:\n" + "\n".join(lines[:max_lines]) + more


def _short(v: Any) -> str:
    return json.dumps(v, default=str) if isinstance(v, (list, dict)) else str(v)


# ---------------------------------------------------------------------------------------------- the sweep
@dataclass
class SweepPoint:
    """One point: its id (``p0000``...), the swept values (path -> value) and its full spec mapping."""

    point_id: str
    values: dict[str, Any]
    spec: dict


@dataclass
class Sweep:
    """A parsed sweep: the spec as given (``raw``, with its vary section), the section, the points."""

    source: str
    raw: dict
    section: VarySection
    points: list[SweepPoint]
    base_dir: Path | None
    kind: str
    name: str

    @property
    def parameters(self) -> list[str]:
        out: list[str] = []
        for p in self.points:
            out += [k for k in p.values if k not in out]
        return out

    def point(self, point_id: str) -> SweepPoint:
        for p in self.points:
            if p.point_id == point_id:
                return p
        raise KeyError(point_id)


def point_ids(n: int) -> list[str]:
    width = max(4, len(str(n - 1)))
    return [f"p{i:0{width}d}" for i in range(n)]


def sweep_from_mapping(raw: Any, source: str = "spec", base_dir: Path | None = None) -> Sweep:
    """Parse a spec mapping with a ``vary:`` section: expand and validate every point.

    Raises :class:`SpecError` (every invalid point, one line per problem, at most 20 points reported).
    """
    if not isinstance(raw, dict):
        raise SpecError(f"{source}: expected a mapping at the top level")
    if SECTION not in raw:
        raise SpecError(f"{source}: {SECTION}: missing (a sweep spec has a `{SECTION}:` section with grid, zip "
                        f"or points; `wamctl run` runs a single spec)")
    body = {k: v for k, v in raw.items() if k != SECTION}
    section = _parse_section(raw[SECTION], source)
    if isinstance(body.get("plant"), str):
        body["plant"] = load_model_file(resolve_path(body["plant"], base_dir))
    values = expand_section(section)
    ids = point_ids(len(values))
    points, problems, first = [], [], None
    for pid, vals in zip(ids, values):
        where = f"{source}: point {pid} ({describe_values(vals, 80)})"
        try:
            data = apply_values(body, vals, where)
            if isinstance(data.get("plant"), str):
                data["plant"] = load_model_file(resolve_path(data["plant"], base_dir))
            spec = parse_spec(data, where, show_values=False)      # the point's description names its values
        except SpecError as exc:
            msg = str(exc)
            problems.append((pid, vals, msg[len(where) + 2:] if msg.startswith(where + ": ") else msg))
            continue
        points.append(SweepPoint(pid, vals, data))
        first = first or spec
    if problems:
        raise SpecError(point_problems(source, problems, len(values), "are invalid (nothing was run)"))
    return Sweep(source, raw, section, points, base_dir, first.kind, section.name or first.name)


def _parse_section(raw_section: Any, source: str) -> VarySection:
    """The validated ``vary:`` section; its errors name ``source`` and the field (``vary.grid``...)."""
    try:
        return VarySection.model_validate(raw_section if raw_section is not None else {})
    except ValidationError as exc:
        lines = []
        for err in exc.errors():
            loc = ".".join(str(x) for x in err["loc"])
            msg = "unknown key" if err["type"] == "extra_forbidden" else err["msg"].removeprefix("Value error, ")
            lines.append(f"{source}: {SECTION}{'.' + loc if loc else ''}: {msg}")
        raise SpecError("\n".join(lines)) from None


def load_sweep(path: str | Path) -> Sweep:
    """Read a spec file with a ``vary:`` section (paths in it are relative to its folder)."""
    path = Path(path)
    return sweep_from_mapping(load_yaml(path), str(path), path.resolve().parent)

