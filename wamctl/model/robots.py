"""The arms wamctl knows, one :class:`Robot` each: a third configuration (a WAM with a hand, gimbals) is one
more entry in :data:`ROBOTS`.

A description holds what the model, the simulator, the controllers and the CAN session need of an arm: joint
count, standard DH table (Spong, ``A_i = Rz(theta_i) Tz(d_i) Tx(a_i) Rx(alpha_i)``, as :mod:`wamctl.model.
params`), link masses, COMs (in DH frame i) and inertias (about the COM, axes of frame i), joint armature
(reflected rotor inertia), joint, velocity and torque limits, libbarrett's joint-position gains, the home pose,
the motor-joint transmission (motor angle = ``j2mp`` @ joint angle) and the CAN ids of the motor pucks.

* ``wam7``: the 7-DOF WAM with its wrist: exactly the numbers of :mod:`wamctl.model.params` (libbarrett
  ``config/wam7w.conf``).
* ``wam4``: the 4-DOF WAM (the arm without its wrist), libbarrett ``config/wam4.conf``, its
  ``calibration_data/wam4/zerocal.conf`` (home) at BarrettTechnology/libbarrett commit
  109faf6066b3961426f95fd9748a028cef5fcf16. Links 1-3, the shoulder/elbow transmission and pucks 1-4 are the
  7-DOF's; link 4 is the elbow link ending at the forearm's end (libbarrett's own mass 1.0651 kg, COM and
  inertia, not the wam7's link 4), toolplate 0.36 m beyond frame 4 along z4. A wrist or a hand on a WAM4 is a
  payload. Its armature is the reflected rotor inertia of the same four motors (the 4x4 block of the wam7's
  j2mp and rotors, so the same numbers); its limits are the wam7's joints 1-4 (same joints and pucks;
  ``control_signal_limit = (25, 20, 15, 15)`` in wam4.conf).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from wamctl.model import params as P


def _frozen(a) -> np.ndarray:
    arr = np.array(a, dtype=float)
    arr.setflags(write=False)
    return arr


@dataclass(frozen=True, eq=False)
class Robot:
    """One arm's description (arrays read-only, joints 0-based in arrays, 1-based in text)."""

    name: str
    n_joints: int
    dh_a_m: np.ndarray
    dh_alpha_rad: np.ndarray
    dh_d_m: np.ndarray
    link_mass_kg: np.ndarray
    link_com_m: np.ndarray             # (n, 3) in DH frame i
    link_inertia_kg_m2: np.ndarray     # (n, 6) Ixx, Iyy, Izz, Ixy, Ixz, Iyz about the COM
    armature_kg_m2: np.ndarray
    q_min_rad: np.ndarray
    q_max_rad: np.ndarray
    qd_max_rad_s: np.ndarray
    tau_max_Nm: np.ndarray
    kp: np.ndarray
    kd: np.ndarray
    ki: np.ndarray
    home_q_rad: np.ndarray
    j2mp: np.ndarray                   # (n, n) motor angle = j2mp @ joint angle
    puck_ids: tuple[int, ...]          # CAN ids of the motor pucks, motor order
    flange_d_m: float = 0.0            # the tool plate beyond the last DH frame along its z (libbarrett toolplate)
    source: str = ""
    notes: tuple[str, ...] = field(default_factory=tuple)

    def __post_init__(self):
        n = self.n_joints
        shapes = {"dh_a_m": (n,), "dh_alpha_rad": (n,), "dh_d_m": (n,), "link_mass_kg": (n,),
                  "link_com_m": (n, 3), "link_inertia_kg_m2": (n, 6), "armature_kg_m2": (n,), "q_min_rad": (n,),
                  "q_max_rad": (n,), "qd_max_rad_s": (n,), "tau_max_Nm": (n,), "kp": (n,), "kd": (n,),
                  "ki": (n,), "home_q_rad": (n,), "j2mp": (n, n)}
        for key, shape in shapes.items():
            arr = _frozen(getattr(self, key))
            if arr.shape != shape:
                raise ValueError(f"robot {self.name}: {key} has shape {arr.shape}, expected {shape}")
            object.__setattr__(self, key, arr)
        if len(self.puck_ids) != n:
            raise ValueError(f"robot {self.name}: {len(self.puck_ids)} puck ids for {n} joints")
        if (self.q_min_rad >= self.q_max_rad).any():
            raise ValueError(f"robot {self.name}: a joint's lower limit is not below its upper limit")

    @property
    def rotor_count(self) -> int:
        return len(self.puck_ids)


WAM7 = Robot(
    name="wam7", n_joints=P.N_JOINTS,
    dh_a_m=P.DH_A_M, dh_alpha_rad=P.DH_ALPHA_RAD, dh_d_m=P.DH_D_M,
    link_mass_kg=P.LINK_MASS_KG, link_com_m=P.LINK_COM_M, link_inertia_kg_m2=P.LINK_INERTIA_KG_M2,
    armature_kg_m2=P.ARMATURE_KG_M2,
    q_min_rad=P.Q_MIN_RAD, q_max_rad=P.Q_MAX_RAD, qd_max_rad_s=P.QD_MAX_RAD_S, tau_max_Nm=P.TAU_MAX_NM,
    kp=P.KP, kd=P.KD, ki=P.KI, home_q_rad=P.HOME_Q_RAD, j2mp=P.J2MP, puck_ids=(1, 2, 3, 4, 5, 6, 7),
    flange_d_m=0.0, source="libbarrett config/wam7w.conf (wamctl.model.params)",
)

# libbarrett config/wam4.conf (BarrettTechnology/libbarrett 109faf6): "dynamics: From inertial specifications
# Sept 2008", link 4 = the elbow link to the forearm's end: mass 1.0651 kg, com (10.95e-3, -0.03e-3, 140.54e-3) m,
# I = ((18485.77, 2.19, -1608.68), (2.19, 18916.58, 5.15), (-1608.68, 5.15, 1975.17)) e-6 kg m^2.
WAM4 = Robot(
    name="wam4", n_joints=4,
    dh_a_m=[0.0, 0.0, 0.045, -0.045], dh_alpha_rad=[-np.pi / 2, np.pi / 2, -np.pi / 2, np.pi / 2],
    dh_d_m=[0.0, 0.0, 0.55, 0.0],
    link_mass_kg=[10.7677, 3.8749, 1.8023, 1.0651],
    link_com_m=[P.LINK_COM_M[0], P.LINK_COM_M[1], P.LINK_COM_M[2], [0.01095, -0.00003, 0.14054]],
    link_inertia_kg_m2=[P.LINK_INERTIA_KG_M2[0], P.LINK_INERTIA_KG_M2[1], P.LINK_INERTIA_KG_M2[2],
                        [0.01848577, 0.01891658, 0.00197517, 0.00000219, -0.00160868, 0.00000515]],
    # diag(j2mp^T diag(Jm) j2mp) of the same four motors: the wam7's first four entries
    armature_kg_m2=P.ARMATURE_KG_M2[:4],
    q_min_rad=P.Q_MIN_RAD[:4], q_max_rad=P.Q_MAX_RAD[:4], qd_max_rad_s=P.QD_MAX_RAD_S[:4],
    tau_max_Nm=[25.0, 20.0, 15.0, 15.0],                       # wam4.conf control_signal_limit
    kp=[900.0, 2500.0, 600.0, 500.0], ki=[2.5, 5.0, 2.5, 0.5], kd=[10.0, 20.0, 10.0, 2.5],   # wam4.conf
    home_q_rad=[0.0, -2.0, 0.0, 3.13],                         # calibration_data/wam4/zerocal.conf
    j2mp=P.J2MP[:4, :4], puck_ids=(1, 2, 3, 4),
    flange_d_m=0.36,                                           # wam4.conf toolplate d
    source="libbarrett config/wam4.conf, calibration_data/wam4/zerocal.conf (BarrettTechnology/libbarrett "
           "109faf6066b3961426f95fd9748a028cef5fcf16)",
    notes=("a wrist or hand on a WAM4 is a payload",),
)

ROBOTS: dict[str, Robot] = {r.name: r for r in (WAM7, WAM4)}
DEFAULT_ROBOT = "wam7"


def get_robot(robot: str | Robot | None = None) -> Robot:
    """The description named ``robot`` (a :class:`Robot` is returned as is; None: the wam7).

    Raises ValueError naming the robot and the known ones."""
    if isinstance(robot, Robot):
        return robot
    name = DEFAULT_ROBOT if robot is None else str(robot)
    try:
        return ROBOTS[name]
    except KeyError:
        raise ValueError(f"robot {name!r}: unknown (known: {', '.join(ROBOTS)})") from None


def robot_names() -> tuple[str, ...]:
    return tuple(ROBOTS)
