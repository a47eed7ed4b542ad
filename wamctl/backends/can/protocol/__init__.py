"""Barrett's puck CAN protocol: identifiers, message builders and parsers, puck units.

Pure functions and constants only: nothing here opens a bus, sleeps or keeps state. The backend loop
(:mod:`wamctl.backends.can.backend`), the bus tools and the simulated WAM (:mod:`wamctl.backends.can.sim`)
are built on top of it.

What lives here:

- :mod:`.addressing`: the 11-bit identifiers, node ids, broadcast and feedback groups, packed-torque groups,
  :class:`~.addressing.PuckFrameError`.
- :mod:`.properties`: property ids (:class:`~.properties.Prop`), MODE and STAT values, ROLE bits, the firmware
  check, and property get / set / reply messages.
- :mod:`.safety`: the safety module's ids, modes, pendant state (PEN), limits and broadcast.
- :mod:`.configuration`: the arm a session expects (:class:`~.configuration.BusArm` of a robot: the wam7's pucks
  1-7, the wam4's 1-4 with 5-7 absent; groups, POLES, torque frames) and the zeroing counts at its home pose.
- :mod:`.positions`: 22-bit position replies (3 bytes, or 6 with a joint encoder) and the position request.
- :mod:`.torques`: packed 14-bit torque frames and puck torque units (IPNM).

Joint <-> motor <-> encoder-count conversions are the arm's, not the bus's: they live in
:mod:`wamctl.model.transmission` (one formula shared with the simulator's sensors).

Conventions
-----------
- Joints and pucks are numbered 1..n on the bus and in user-facing text (n = 7 on a wam7, 4 on a wam4), 0..n-1
  in arrays; WAM puck ``n`` drives motor ``n``.
- SI units everywhere except on the wire; names carry units: ``q_rad`` (joint angle), ``m_rad`` (motor
  angle), ``counts`` (encoder counts), ``tau_Nm`` (joint torque), ``tau_m_Nm`` (motor torque),
  ``puck_units`` (puck torque command, ``IPNM`` units per N m of motor torque).
- Vectorised functions accept one vector of shape ``(7,)`` or a batch ``(..., 7)``; per-puck constants
  (``cts``, ``ipnm``) may be scalars or ``(7,)`` arrays.
- CAN identifiers are 11-bit: ``[G FFFFF TTTTT]`` = group flag ``0x400``, sender bits ``0x3e0``, target
  bits ``0x01f``; the host is node 0.
- A malformed frame received from the bus raises :class:`~.addressing.PuckFrameError` (a
  :class:`~wamctl.errors.BackendError`: the device misbehaved); bad arguments from calling code raise
  ``ValueError``.

Sources: libbarrett (github.com/BarrettTechnology/libbarrett) ``include/barrett/products/puck.h``,
``puck_group.h``, ``motor_puck.h``, ``detail/puck-inl.h``, ``detail/motor_puck-inl.h``,
``src/products/motor_puck.cpp``, ``src/products/puck.cpp``, ``src/products/property_list.cpp`` and
``config/wam7w.conf``; summarised in the project's WAM parameter notes (CAN bus, motors and transmission).

May import: python-can, numpy, :mod:`wamctl.model` (params, transmission) and :mod:`wamctl.errors`; never
the backend, the bus tools or the simulated pucks.
"""
