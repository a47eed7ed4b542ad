"""Declarative experiment specs (YAML) as pydantic models.

What lives here: the parts every kind shares (:mod:`.common`: backend, plant, controller, seed), one module
per kind (:mod:`.rotation`, :mod:`.friction_sweep`, :mod:`.ift`, :mod:`.hmi_block`, and :mod:`.sweep` for the
``vary:`` section of a sweep), the one registry of kinds (:mod:`.registry`) and the reader (:mod:`.load`).

May import: :mod:`wamctl.control`, :mod:`wamctl.hmi`, :mod:`wamctl.model`, :mod:`wamctl.io`,
:mod:`wamctl.errors`. Never backends, analysis, experiments, report or the CLI.
"""

from wamctl.specs.common import (  # noqa: F401
                                 BackendSpec,
                                 CanBackendSpec,
                                 Common,
                                 ControllerSpec,
                                 Effects,
                                 FrictionInline,
                                 Joint,
                                 PayloadEffect,
                                 PlantSpec,
                                 SensorSpec,
                                 SimBackendSpec,
                                 Strict,
                                 Vec7,
                                 check_positions,
)
from wamctl.specs.load import format_validation_error, load_model_file, load_spec, parse_spec  # noqa: F401
