"""Reading a spec: YAML -> the kind's pydantic model (a discriminated union on ``kind``), errors naming the field.

``plant: FILE`` in a spec names a model file (``format: wamctl-model/1``, as ``wamctl diagnose`` writes it).
"""

from __future__ import annotations

from functools import lru_cache
from pathlib import Path
from typing import Annotated, Any, Union

from pydantic import Field, TypeAdapter, ValidationError

from wamctl.errors import SpecError
from wamctl.io import load_yaml, resolve_path
from wamctl.model.urdf import is_urdf
from wamctl.specs.common import Common, PlantSpec, check_files
from wamctl.specs.payload_file import is_payload_file, payload_effect
from wamctl.specs.registry import KINDS, SPEC_KINDS, resolve


def spec_models() -> dict[str, type[Common]]:
    """The spec model of every kind run from a spec."""
    return {kind: resolve(KINDS[kind].spec) for kind in SPEC_KINDS}


@lru_cache(maxsize=1)
def _adapter() -> TypeAdapter:
    models = tuple(spec_models().values())
    return TypeAdapter(Annotated[Union[models], Field(discriminator="kind")])  # noqa: UP007 (a tuple of types)


def format_validation_error(exc: ValidationError, source: str, show_values: bool = True) -> str:
    """One line per problem: ``source: field.path = value: message``. The path is the one a sweep's ``vary``
    names (list items counted from 0: ``q0_rad.3`` is joint 4's); the value the spec gave there is shown when it is
    a single number, word or flag, so that ``rotation.joints.2 = 9`` is not read as joint 2 (``show_values`` False:
    not shown, for a sweep's points, whose description names their values and whose shared problems are told
    once)."""
    lines = []
    for err in exc.errors():
        loc = [str(x) for x in err["loc"]]
        if loc and loc[0] in SPEC_KINDS:
            loc = loc[1:]  # the union's tag, not a field
        msg = err["msg"].removeprefix("Value error, ")
        if err["type"] == "extra_forbidden":
            msg = "unknown key"
        where = ".".join(loc)
        value = err.get("input")
        if (show_values and where and err["type"] != "missing" and isinstance(value, (bool, int, float, str))
                and len(repr(value)) <= 40):
            where += f" = {value!r}" if isinstance(value, str) else f" = {value}"
        lines.append(f"{source}: {where}: {msg}" if where else f"{source}: {msg}")
    return "\n".join(lines)


def parse_spec(data: Any, source: str = "spec", show_values: bool = True) -> Common:
    """Validate a mapping into a spec model, raising :class:`SpecError` naming the field (and the value given
    there: :func:`format_validation_error`)."""
    if not isinstance(data, dict):
        raise SpecError(f"{source}: expected a mapping at the top level")
    if "vary" in data:
        raise SpecError(f"{source}: vary: this spec varies parameters; run it with `wamctl sweep {source}`")
    if data.get("kind") not in SPEC_KINDS:
        raise SpecError(f"{source}: kind: {'missing' if 'kind' not in data else repr(data['kind']) + ' unknown'}; "
                        f"known kinds: {', '.join(sorted(SPEC_KINDS))}")
    try:
        return _adapter().validate_python(data)
    except ValidationError as exc:
        raise SpecError(format_validation_error(exc, source, show_values)) from None



def load_model_file(path: str | Path) -> dict:
    """A model file (``format: wamctl-model/1``): a plant description (``friction``, ``effects``, ``sensors``,
    ``links``) as written by ``wamctl diagnose`` or ``wamctl identify``; usable wherever a spec takes
    ``plant:``. A URDF of the WAM (:mod:`wamctl.model.urdf`) gives its ``links`` (datasheet friction)."""
    if is_urdf(path):
        return {"links": _urdf_links(path)}
    data = load_yaml(path)
    if is_payload_file(data):       # the datasheet arm carrying an identified payload (docs/payload.md)
        return {"effects": {"payload": payload_effect(path, data)}}
    if not isinstance(data, dict):
        raise SpecError(f"{path}: a model file is a mapping with friction/effects/sensors")
    data = {k: v for k, v in data.items() if k in PlantSpec.model_fields}
    return data


def _urdf_links(path) -> dict:
    from wamctl.model.urdf import UrdfError, urdf_links_mapping

    if not Path(path).is_file():
        raise SpecError(f"{path}: no such file")
    try:
        return urdf_links_mapping(path)
    except UrdfError as exc:
        raise SpecError(f"not a URDF of the 7-DOF WAM: {exc}") from None


def load_model_links(path: str | Path) -> dict:
    """The ``links:`` section of a model file (as ``wamctl identify`` writes it), for
    ``controller.declared_links: FILE``; a URDF of the WAM gives its links too."""
    if is_urdf(path):
        return _urdf_links(path)
    data = load_yaml(path)
    if not isinstance(data, dict) or not isinstance(data.get("links"), dict):
        raise SpecError(f"{path}: no links: section; controller.declared_links takes a model file with link "
                        "parameters (e.g. the model.yaml of `wamctl identify`)")
    return data["links"]


def load_spec(path: str | Path) -> Common:
    """Read and validate a spec file. ``plant: FILE`` loads a model file and ``controller.declared_links:
    FILE`` its ``links:`` (both relative to the spec's folder), so the run directory's spec is self-contained."""
    path = Path(path)
    data = load_yaml(path)
    if isinstance(data, dict) and isinstance(data.get("plant"), str):
        data = dict(data, plant=load_model_file(resolve_path(data["plant"], path.parent)))
    ctl = data.get("controller") if isinstance(data, dict) else None
    if isinstance(ctl, dict) and isinstance(ctl.get("declared_links"), str):
        links = load_model_links(resolve_path(ctl["declared_links"], path.parent))
        data = dict(data, controller=dict(ctl, declared_links=links))
    data = _payload_files(data, path.parent)
    spec = parse_spec(data, str(path))
    check_files(spec, path.resolve().parent, str(path))
    return spec


def _payload_files(data, base: Path):
    """``plant.effects.payload: FILE`` and ``controller.declared_payload: FILE`` (payload files, relative to the
    spec's folder) replaced by their ``{mass_kg, com_m}``."""
    if not isinstance(data, dict):
        return data
    plant, ctl = data.get("plant"), data.get("controller")
    fx = plant.get("effects") if isinstance(plant, dict) else None
    if isinstance(fx, dict) and isinstance(fx.get("payload"), str):
        fx = dict(fx, payload=payload_effect(resolve_path(fx["payload"], base)))
        data = dict(data, plant=dict(plant, effects=fx))
    if isinstance(ctl, dict) and isinstance(ctl.get("declared_payload"), str):
        data = dict(data, controller=dict(ctl, declared_payload=payload_effect(
            resolve_path(ctl["declared_payload"], base))))
    return data
