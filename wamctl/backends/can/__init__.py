"""The real WAM over CAN (python-can), in a session the way Barrett's safety system expects it.

What lives here: the backend (:mod:`.backend`: :class:`~.backend.CanBackend`, its cycle, trip and shutdown), the
start of a session (:mod:`.session`: safety module, limits, wake, the arm's configuration, zeroing), the waits for
the operator (:mod:`.waits`: start pose, Shift-Activate, Shift-Idle) and the operator itself (:mod:`.operator`),
the position polling and link watchdog (:mod:`.link`), the safety module watched during the run
(:mod:`.monitor`), Barrett's puck protocol (:mod:`.protocol`), the bus tools and ``wamctl bus-check``
(:mod:`.bus_tools`, :mod:`.bus_check`), loop timing (:mod:`.timing`), and the simulated WAM (:mod:`.sim`: pucks,
safety module, pendant, the ``sim-arm`` server; :mod:`.simulated_arm`: the physics behind it and its injectable
faults). Joint <-> motor <-> encoder conversions are the arm's model: :mod:`wamctl.model.transmission`.

May import: python-can, numpy, :mod:`wamctl.backends.base`, :mod:`wamctl.backends.sim` (lazily, for the
simulated arm), specs (the ``sim-arm`` server), model and errors. The protocol modules import none of the other
modules here.
"""
