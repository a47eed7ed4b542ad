"""Identification of the WAM's own inertial parameters (``wamctl identify``; issue 18).

* :mod:`.base`: the standard regressor (rigid body from pinocchio + armature + classic per-direction friction),
  the numerical base parameters, and what given data determine. A stable API other analyses build on.

No I/O. May import: model, control, specs, runs (the measured-run data type), io, errors.
"""
