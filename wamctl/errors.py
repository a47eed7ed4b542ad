"""Errors a user can cause. The CLI maps each to one line and exit code 2 (no traceback).

Programming errors are ordinary exceptions and may raise with a traceback.
"""


class WamctlError(Exception):
    """Base of every error a user can cause."""

    exit_code = 2


class SpecError(WamctlError):
    """A spec (YAML) is malformed or violates a limit. The message names the field."""


class DataFormatError(WamctlError):
    """A data file (measured run, gaze log, results CSV) is malformed. The message names the key, column or row."""


class BackendError(WamctlError):
    """A device could not be reached or misbehaved (CAN bus, serial port)."""


class ConfigurationRefused(BackendError):
    """The device on the bus is not one wamctl's model describes (firmware, puck roles, groups, POLES): refused
    before anything moved. Like a bad spec, a run refused this way exits with code 2 (not 1, a run that failed)."""


class SafetyLimitError(WamctlError):
    """A setpoint or a measured state would break a safety limit (torque, position, velocity, watchdog)."""
