"""The command line's commands, one module per command group, each thin: parse the options, call the library,
print. Each module has ``register(app)``, called by :mod:`wamctl.cli`; shared output helpers live in
:mod:`.common`.

May import anything below it (experiments, report, specs, runs, ...). Nothing imports a command module but the
CLI, and tests never take library code from here.
"""

# command modules, in the order their commands appear in ``wamctl --help``
COMMAND_MODULES = ("data", "report", "runs", "run", "friction", "diagnose", "identify", "ift", "hmi", "gaze", "bus",
                   "sim_arm", "sweep")
