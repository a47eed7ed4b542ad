"""The payload file (``format: wamctl-payload/1``, written by ``wamctl identify --payload``; docs/payload.md) as a
spec's payload: ``plant.effects.payload: FILE`` (the simulated arm carries it), ``controller.declared_payload:
FILE`` (gravity compensation and feed-forward know it), ``plant: FILE`` / ``--model FILE`` (a plant that is the
datasheet arm with this payload). The model uses a point mass: ``mass_kg`` and ``com_m`` (link-7 frame); the
file's intervals and inertia are for the reader."""

from __future__ import annotations

from pathlib import Path

from wamctl.errors import SpecError
from wamctl.io import load_yaml

PAYLOAD_FILE_FORMAT = "wamctl-payload/1"


def is_payload_file(raw) -> bool:
    return isinstance(raw, dict) and raw.get("format") == PAYLOAD_FILE_FORMAT


def payload_effect(path: str | Path, raw: dict | None = None) -> dict:
    """``{mass_kg, com_m}`` of a payload file (what ``PayloadEffect`` validates); SpecError naming the file and
    the field for a file that is not one."""
    raw = load_yaml(path) if raw is None else raw
    if not is_payload_file(raw):
        raise SpecError(f"{path}: format: expected {PAYLOAD_FILE_FORMAT!r} (a payload file of `wamctl identify "
                        f"--payload`), got {raw.get('format') if isinstance(raw, dict) else None!r}")
    mass, com = raw.get("mass_kg"), raw.get("com_m")
    if not isinstance(mass, (int, float)) or isinstance(mass, bool):
        raise SpecError(f"{path}: mass_kg: expected a number, got {mass!r}")
    if not (isinstance(com, list) and len(com) == 3 and all(isinstance(v, (int, float)) for v in com)):
        raise SpecError(f"{path}: com_m: expected three numbers (m, link-7 frame), got {com!r}")
    return {"mass_kg": float(mass), "com_m": [float(v) for v in com]}
