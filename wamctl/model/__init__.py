"""The WAM itself: physical parameters (:mod:`.params`), rigid-body dynamics (:mod:`.dynamics`, the only module
that imports pinocchio), friction models and their file (:mod:`.friction`), the formulas of the effects a real arm
has (:mod:`.effects`), the transmissions (:mod:`.transmission`: joint <-> motor <-> encoder counts through
J2MP), the simulated plant and its sensors (:mod:`.plant`), and the MJCF export (:mod:`.mjcf`).

May import: io, errors. Nothing above.
"""
