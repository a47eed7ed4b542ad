"""The WAM rigid-body model in pinocchio (pinocchio stays inside this module).

Conventions
-----------
* Built in code from the standard DH table of :mod:`wamctl.model.params`: pinocchio joint ``i`` sits on
  DH frame ``i-1`` (its z axis is the joint axis); link ``i``'s inertia, given about its COM in DH frame
  ``i``, is moved into joint ``i``'s frame through the fixed part ``Tz(d_i) Tx(a_i) Rx(alpha_i)`` of
  ``A_i``. A frame ``"link7"`` carries DH frame 7 (the wrist flange).
* Reflected rotor inertia is the joint armature (used by pinocchio's CRBA and ABA).
* Gravity is -9.81 m/s^2 along z0; frame 0 is at the shoulder.
* An optional payload (point mass, COM in the link-7 frame) is added to link 7.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pinocchio as pin

from wamctl.model import params as P


@dataclass(frozen=True)
class Payload:
    """A point mass rigidly attached to link 7.

    Parameters
    ----------
    mass_kg : float
    com_m : (3,) array, centre of mass in the link-7 (DH frame 7) frame.
    """

    mass_kg: float
    com_m: tuple[float, float, float] = (0.0, 0.0, 0.0)


def _dh_fixed(i: int) -> pin.SE3:
    """Fixed part of A_i after the joint rotation: Tz(d) Tx(a) Rx(alpha), for 0-based i."""
    ca, sa = np.cos(P.DH_ALPHA_RAD[i]), np.sin(P.DH_ALPHA_RAD[i])
    rot = np.array([[1.0, 0.0, 0.0], [0.0, ca, -sa], [0.0, sa, ca]])
    return pin.SE3(rot, np.array([P.DH_A_M[i], 0.0, P.DH_D_M[i]]))


def _link_inertia(i: int) -> pin.Inertia:
    ixx, iyy, izz, ixy, ixz, iyz = P.LINK_INERTIA_KG_M2[i]
    inertia = np.array([[ixx, ixy, ixz], [ixy, iyy, iyz], [ixz, iyz, izz]])
    return pin.Inertia(float(P.LINK_MASS_KG[i]), P.LINK_COM_M[i].copy(), inertia)


def build_wam7_model(payload: Payload | None = None) -> pin.Model:
    """Build the 7-DOF WAM as a pinocchio model.

    Parameters
    ----------
    payload : Payload, optional
        Point mass added to link 7.

    Returns
    -------
    pinocchio.Model with nq = nv = 7, armature, position, velocity and effort limits set.
    """
    model = pin.Model()
    model.name = "wam7"
    parent = 0
    placement = pin.SE3.Identity()
    for i in range(P.N_JOINTS):
        jid = model.addJoint(parent, pin.JointModelRZ(), placement, f"joint{i + 1}")
        fixed = _dh_fixed(i)
        model.appendBodyToJoint(jid, fixed.act(_link_inertia(i)), pin.SE3.Identity())
        parent, placement = jid, fixed
    model.addFrame(pin.Frame("link7", parent, placement, pin.FrameType.OP_FRAME))
    if payload is not None and payload.mass_kg > 0:
        point = pin.Inertia(float(payload.mass_kg), np.asarray(payload.com_m, float), np.zeros((3, 3)))
        model.appendBodyToJoint(parent, placement.act(point), pin.SE3.Identity())
    model.armature = P.ARMATURE_KG_M2.copy()
    model.lowerPositionLimit = P.Q_MIN_RAD.copy()
    model.upperPositionLimit = P.Q_MAX_RAD.copy()
    model.velocityLimit = P.QD_MAX_RAD_S.copy()
    model.effortLimit = P.TAU_MAX_NM.copy()
    model.gravity = pin.Motion(np.array([0.0, 0.0, -P.GRAVITY_M_S2]), np.zeros(3))
    return model


class WamDynamics:
    """Rigid-body dynamics of the WAM: a pinocchio model and its workspace, with snake_case methods.

    All arrays are (7,) in radians, rad/s, rad/s^2 and N m; matrices (7, 7).
    """

    def __init__(self, payload: Payload | None = None):
        self.payload = payload
        self.model = build_wam7_model(payload)
        self.data = self.model.createData()
        self._link7 = self.model.getFrameId("link7")

    def gravity(self, q: np.ndarray) -> np.ndarray:
        """Gravity torque g(q), N m."""
        return pin.computeGeneralizedGravity(self.model, self.data, q).copy()

    def gravity_view(self, q: np.ndarray) -> np.ndarray:
        """g(q) as a view into the workspace, valid until the next call (the control loop's hot path)."""
        return pin.computeGeneralizedGravity(self.model, self.data, q)

    def mass_matrix(self, q: np.ndarray) -> np.ndarray:
        """Joint-space inertia B(q) including armature, symmetric (7, 7)."""
        m = pin.crba(self.model, self.data, q)
        return np.triu(m) + np.triu(m, 1).T

    def mass_matrix_inverse(self, q: np.ndarray) -> np.ndarray:
        """B(q)^-1 (7, 7)."""
        m = pin.computeMinverse(self.model, self.data, q)
        return np.triu(m) + np.triu(m, 1).T

    def mass_matrix_inverse_upper_view(self, q: np.ndarray) -> np.ndarray:
        """B(q)^-1 with only its upper triangle filled, a view into the workspace valid until the next call (the
        physics kernel's hot path reads the upper triangle)."""
        return pin.computeMinverse(self.model, self.data, q)

    def nonlinear_effects_view(self, q: np.ndarray, qd: np.ndarray) -> np.ndarray:
        """C(q, qd) qd + g(q) as a view into the workspace, valid until the next call (hot path)."""
        return pin.nonLinearEffects(self.model, self.data, q, qd)

    def inverse_dynamics(self, q: np.ndarray, qd: np.ndarray, qdd: np.ndarray) -> np.ndarray:
        """tau = B(q) qdd + C(q, qd) qd + g(q), N m (no friction)."""
        return pin.rnea(self.model, self.data, q, qd, qdd).copy()

    def forward_dynamics(self, q: np.ndarray, qd: np.ndarray, tau: np.ndarray) -> np.ndarray:
        """qdd = B^-1 (tau - C qd - g), rad/s^2 (no friction)."""
        return pin.aba(self.model, self.data, q, qd, tau).copy()

    def link7_pose(self, q: np.ndarray) -> np.ndarray:
        """Homogeneous transform (4, 4) of DH frame 7 in frame 0."""
        pin.framesForwardKinematics(self.model, self.data, q)
        return self.data.oMf[self._link7].homogeneous.copy()

    def link7_jacobian(self, q: np.ndarray) -> np.ndarray:
        """Geometric Jacobian (6, 7) of the link-7 origin, world-aligned axes: rows vx vy vz wx wy wz."""
        pin.computeJointJacobians(self.model, self.data, q)
        pin.framesForwardKinematics(self.model, self.data, q)
        return pin.getFrameJacobian(self.model, self.data, self._link7, pin.LOCAL_WORLD_ALIGNED).copy()

    def regressor_basis(self, q: np.ndarray, qd: np.ndarray, qdd: np.ndarray) -> np.ndarray:
        """Joint torque regressor Y (7, 70) with tau = Y @ pi for the standard inertial parameters."""
        return pin.computeJointTorqueRegressor(self.model, self.data, q, qd, qdd).copy()
