"""The simulated WAM the CAN backend is tested against: motor pucks (:mod:`.pucks`), the safety module
(:mod:`.safety_module`) and its pendant (:mod:`.pendant`) on a python-can bus (:mod:`.simulator`), and the
server behind ``wamctl sim-arm`` (:mod:`.serve`). The physics behind the pucks is
:class:`wamctl.backends.can.simulated_arm.SimulatedArm` (or a :class:`~.pucks.StaticPlant`).

Nothing is imported here (the safety module's kinematics load pinocchio): import the modules.

May import: python-can, numpy, :mod:`wamctl.backends.can.protocol`, :mod:`wamctl.model`; never the backend.
"""
