"""wamctl: lab tool for the 7-DOF Barrett WAM.

Data flow, one way: spec -> stages -> backend -> run directory -> analysis -> report.
SI units throughout; every stored column names its unit (``q_rad``, ``tau_Nm``, ``t_s``).
"""

__version__ = "0.1.0"
