"""The house rules of docs/architecture.md that import-linter cannot see: the registry of kinds resolves to
working parts, and tests reach library code through the library, never through the CLI's command modules."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

from wamctl.specs.common import Common
from wamctl.specs.registry import KINDS, resolve

TESTS = Path(__file__).resolve().parent


@pytest.mark.parametrize("kind", sorted(KINDS))
def test_every_registered_kind_resolves(kind):
    k = KINDS[kind]
    assert callable(resolve(k.report))
    if k.spec is not None:
        model = resolve(k.spec)
        assert issubclass(model, Common)
        assert model.model_fields["kind"].annotation.__args__ == (kind,)
        mod = resolve(k.experiment)
        assert callable(mod.plan) and callable(mod.execute)


# command-layer code a test may reach on purpose: the terminal's own questions (a test checks that a command's
# --yes reaches its operator); it is no library code, and nothing else of the command modules is
COMMAND_LAYER_UNDER_TEST = {"wamctl.commands.terminal_operator"}
# ... and, from one test file only, the terminal's own drawing: the progress bar and the interrupt notice, whose
# widths and order on an 80-column terminal that file checks (common.py holds the commands' shared code too)
TERMINAL_DRAWING_TESTS = {"wamctl.commands.common": {"commands/test_progress_ctrl_c.py"}}


def test_tests_do_not_import_library_code_from_the_command_modules():
    offenders = []
    for path in TESTS.rglob("*.py"):
        for node in ast.walk(ast.parse(path.read_text())):
            names = []
            if isinstance(node, ast.ImportFrom) and node.module:
                names = [node.module]
            elif isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            offenders += [f"{path.relative_to(TESTS)}:{node.lineno} {n}" for n in names
                          if (n == "wamctl.commands" or n.startswith("wamctl.commands."))
                          and n not in COMMAND_LAYER_UNDER_TEST
                          and str(path.relative_to(TESTS)) not in TERMINAL_DRAWING_TESTS.get(n, ())]
    assert not offenders, offenders
