"""The real WAM over CAN (python-can).

What lives here: the backend (:mod:`.backend`: :class:`~.backend.CanBackend`, its start-up, cycle, link
watchdog and shutdown), Barrett's puck protocol (:mod:`.protocol`: ids, groups, properties, packed positions
and torques), the bus tools shared with ``wamctl bus-check`` (:mod:`.bus_tools`: open a bus, read
properties, probe pucks, bus load), loop timing (:mod:`.timing`), simulated pucks (:mod:`.puck_sim`) and the
simulated arm behind them with its injectable faults (:mod:`.simulated_arm`). Joint <-> motor <-> encoder
conversions are the arm's model: :mod:`wamctl.model.transmission`.

May import: python-can, numpy, :mod:`wamctl.backends.base`, :mod:`wamctl.backends.sim` (lazily, for the
simulated arm), model and errors. The protocol modules import none of the other modules here.
"""
