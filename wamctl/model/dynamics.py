"""The WAM rigid-body model in pinocchio (pinocchio stays inside this module).

Conventions
-----------
* Any arm of :mod:`wamctl.model.robots` (``robot=``, default the wam7; a :class:`LinkParameters` carries its
  robot's name): n joints, n links, the robot's DH table, limits and armature.
* Built in code from the robot's standard DH table (:mod:`wamctl.model.params` for the wam7): pinocchio joint
  ``i`` sits on DH frame ``i-1`` (its z axis is the joint axis); link ``i``'s inertia, given about its COM in DH frame
  ``i``, is moved into joint ``i``'s frame through the fixed part ``Tz(d_i) Tx(a_i) Rx(alpha_i)`` of
  ``A_i``. A frame ``"link7"`` carries the flange: DH frame 7 on the wam7, DH frame 4 moved along its z by
  libbarrett's toolplate (0.36 m, the forearm's end) on the wam4 (``link7_*`` methods: the flange of any arm).
* Reflected rotor inertia is the joint armature (used by pinocchio's CRBA and ABA).
* Gravity is -9.81 m/s^2 along z0; frame 0 is at the shoulder.
* An optional payload (point mass, COM in the flange frame) is added to the last link.
* Link parameters (mass, COM, inertia, armature) come from a :class:`~wamctl.model.params.LinkParameters`,
  the datasheet's by default; ``WamDynamics(links=...)`` builds the arm of a model file (``links:``, e.g. an
  identified arm, :mod:`wamctl.analysis.identification`).
* Standard inertial parameters (the torque regressor's, pinocchio's order): per link ``m, m c_x, m c_y, m c_z,
  I_xx, I_xy, I_yy, I_xz, I_yz, I_zz`` with the first moment and the inertia about the *joint* frame's origin
  in the joint frame's axes (pinocchio joint ``i`` = DH frame ``i-1`` turned by ``q_i``), ``tau = Y pi +
  armature * qdd``. :func:`links_from_standard` maps them back to DH-frame COM and inertia about the COM.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pinocchio as pin

from wamctl.model import params as P
from wamctl.model.robots import Robot, get_robot

N_STANDARD_INERTIAL = 10 * P.N_JOINTS     # standard inertial parameters of the wam7's seven links


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


def _dh_fixed(i: int, robot: Robot | str | None = None) -> pin.SE3:
    """Fixed part of A_i after the joint rotation: Tz(d) Tx(a) Rx(alpha), for 0-based i (the robot's DH table,
    default the wam7)."""
    r = get_robot(robot)
    ca, sa = np.cos(r.dh_alpha_rad[i]), np.sin(r.dh_alpha_rad[i])
    rot = np.array([[1.0, 0.0, 0.0], [0.0, ca, -sa], [0.0, sa, ca]])
    return pin.SE3(rot, np.array([r.dh_a_m[i], 0.0, r.dh_d_m[i]]))


def _link_inertia(i: int, links: P.LinkParameters) -> pin.Inertia:
    """Link ``i``'s (0-based) inertia in DH frame i (about the COM there, as the datasheet gives it)."""
    return pin.Inertia(float(links.mass_kg[i]), np.array(links.com_m[i]), links.inertia_matrix_kg_m2(i))


def build_wam7_model(payload: Payload | None = None, links: P.LinkParameters | None = None) -> pin.Model:
    """Build the 7-DOF WAM as a pinocchio model (:func:`build_model` of the wam7)."""
    return build_model("wam7" if links is None else links.robot, payload, links)


def build_model(robot: Robot | str | None = None, payload: Payload | None = None,
                links: P.LinkParameters | None = None) -> pin.Model:
    """Build a registered arm (:mod:`wamctl.model.robots`, default the wam7) as a pinocchio model.

    Parameters
    ----------
    robot : Robot or its name
    payload : Payload, optional
        Point mass added to the last link, COM in the flange frame.
    links : LinkParameters, optional
        Link masses, COMs, inertias and armature; default the robot's :meth:`LinkParameters.datasheet`; must be
        of the same robot.

    Returns
    -------
    pinocchio.Model with nq = nv = the robot's joints, armature, position, velocity and effort limits set.
    """
    r = get_robot(robot)
    links = links if links is not None else P.LinkParameters.datasheet(r.name)
    if links.robot != r.name:
        raise ValueError(f"links of {links.robot} for a {r.name} model")
    model = pin.Model()
    model.name = r.name
    parent = 0
    placement = pin.SE3.Identity()
    for i in range(r.n_joints):
        jid = model.addJoint(parent, pin.JointModelRZ(), placement, f"joint{i + 1}")
        fixed = _dh_fixed(i, r)
        model.appendBodyToJoint(jid, fixed.act(_link_inertia(i, links)), pin.SE3.Identity())
        parent, placement = jid, fixed
    placement = placement * pin.SE3(np.eye(3), np.array([0.0, 0.0, r.flange_d_m]))
    model.addFrame(pin.Frame("link7", parent, placement, pin.FrameType.OP_FRAME))
    if payload is not None and payload.mass_kg > 0:
        point = pin.Inertia(float(payload.mass_kg), np.asarray(payload.com_m, float), np.zeros((3, 3)))
        model.appendBodyToJoint(parent, placement.act(point), pin.SE3.Identity())
    model.armature = np.array(links.armature_kg_m2)
    model.lowerPositionLimit = np.array(r.q_min_rad)
    model.upperPositionLimit = np.array(r.q_max_rad)
    model.velocityLimit = np.array(r.qd_max_rad_s)
    model.effortLimit = np.array(r.tau_max_Nm)
    model.gravity = pin.Motion(np.array([0.0, 0.0, -P.GRAVITY_M_S2]), np.zeros(3))
    return model


class WamDynamics:
    """Rigid-body dynamics of the WAM: a pinocchio model and its workspace, with snake_case methods.

    All arrays are (n,) in radians, rad/s, rad/s^2 and N m; matrices (n, n); n the robot's joints (7 for the
    default wam7). ``robot`` names the arm (:mod:`wamctl.model.robots`); ``links`` of another robot are refused.
    """

    def __init__(self, payload: Payload | None = None, links: P.LinkParameters | None = None,
                 robot: Robot | str | None = None):
        if robot is None and links is not None:
            robot = links.robot
        self.robot = get_robot(robot)
        self.n_joints = self.robot.n_joints
        self.payload = payload
        self.links = links if links is not None else P.LinkParameters.datasheet(self.robot.name)
        self.model = build_model(self.robot, payload, self.links)
        self.data = self.model.createData()
        self._link7 = self.model.getFrameId("link7")

    @property
    def n_standard(self) -> int:
        """Standard inertial parameters of this arm: 10 per link."""
        return 10 * self.n_joints

    def gravity(self, q: np.ndarray) -> np.ndarray:
        """Gravity torque g(q), N m."""
        return pin.computeGeneralizedGravity(self.model, self.data, q).copy()

    def gravity_view(self, q: np.ndarray) -> np.ndarray:
        """g(q) as a view into the workspace, valid until the next call (the control loop's hot path)."""
        return pin.computeGeneralizedGravity(self.model, self.data, q)

    def mass_matrix(self, q: np.ndarray) -> np.ndarray:
        """Joint-space inertia B(q) including armature, symmetric (n, n)."""
        m = pin.crba(self.model, self.data, q)
        return np.triu(m) + np.triu(m, 1).T

    def mass_matrix_inverse(self, q: np.ndarray) -> np.ndarray:
        """B(q)^-1 (n, n)."""
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

    def link7_speed_m_s(self, q: np.ndarray, qd: np.ndarray) -> np.ndarray:
        """Linear speed of the link-7 origin (the wrist flange), m/s, for states (n, 7): (n,)."""
        q, qd = np.atleast_2d(q), np.atleast_2d(qd)
        out = np.empty(len(q))
        for k in range(len(q)):
            pin.forwardKinematics(self.model, self.data, q[k], qd[k])
            pin.updateFramePlacement(self.model, self.data, self._link7)
            v = pin.getFrameVelocity(self.model, self.data, self._link7, pin.LOCAL_WORLD_ALIGNED)
            out[k] = np.linalg.norm(v.linear)
        return out

    # ------------------------------------------------------------------------------------------ batches
    # Along a trajectory, states (n, 7): one pinocchio call per sample, without the per-call copies.
    def inverse_dynamics_many(self, q: np.ndarray, qd: np.ndarray, qdd: np.ndarray) -> np.ndarray:
        """:meth:`inverse_dynamics` of states (n, 7): (n, 7)."""
        q, qd, qdd = (np.ascontiguousarray(np.atleast_2d(x), dtype=float) for x in (q, qd, qdd))
        out = np.empty((len(q), self.n_joints))
        model, data, rnea = self.model, self.data, pin.rnea
        for k in range(len(q)):
            out[k] = rnea(model, data, q[k], qd[k], qdd[k])
        return out

    def gravity_many(self, q: np.ndarray) -> np.ndarray:
        """:meth:`gravity` of positions (n, 7): (n, 7)."""
        q = np.ascontiguousarray(np.atleast_2d(q), dtype=float)
        out = np.empty((len(q), self.n_joints))
        model, data, grav = self.model, self.data, pin.computeGeneralizedGravity
        for k in range(len(q)):
            out[k] = grav(model, data, q[k])
        return out

    def regressor_basis(self, q: np.ndarray, qd: np.ndarray, qdd: np.ndarray) -> np.ndarray:
        """Joint torque regressor Y (n, 10 n), (7, 70) on the wam7, with tau = Y @ pi for the standard inertial
        parameters."""
        return pin.computeJointTorqueRegressor(self.model, self.data, q, qd, qdd).copy()

    def torque_regressor(self, q: np.ndarray, qd: np.ndarray, qdd: np.ndarray) -> np.ndarray:
        """:meth:`regressor_basis` along a trajectory: (k, n, 10 n) for states (k, n). The regressor depends on
        the kinematics only, never on the link parameters or the payload."""
        q, qd, qdd = (np.atleast_2d(np.asarray(x, float)) for x in (q, qd, qdd))
        out = np.empty((len(q), self.n_joints, self.n_standard))
        for k in range(len(q)):
            out[k] = pin.computeJointTorqueRegressor(self.model, self.data, q[k], qd[k], qdd[k])
        return out

    def standard_parameters(self) -> np.ndarray:
        """(10 n,) standard inertial parameters of this arm (payload included in the last link), see the module
        doc."""
        return np.concatenate([self.model.inertias[i + 1].toDynamicParameters() for i in range(self.n_joints)])

    @property
    def armature_kg_m2(self) -> np.ndarray:
        """(n,) joint armature (reflected rotor inertia) of this model."""
        return np.array(self.model.armature)

    def joint_frames(self, q: np.ndarray) -> np.ndarray:
        """Homogeneous transforms of DH frames 0..7 in frame 0 (frame i at the output of ``A_i``; frame 0 the
        shoulder): (8, 4, 4) for q (7,), (n, 8, 4, 4) for states (n, 7)."""
        qs = np.atleast_2d(np.asarray(q, float))
        out = np.empty((len(qs), self.n_joints + 1, 4, 4))
        out[:, 0] = np.eye(4)
        fixed = [_dh_fixed(i, self.robot) for i in range(self.n_joints)]
        for k, qk in enumerate(qs):
            pin.forwardKinematics(self.model, self.data, qk)
            for i in range(self.n_joints):
                out[k, i + 1] = (self.data.oMi[i + 1] * fixed[i]).homogeneous
        return out[0] if np.ndim(q) == 1 else out

    def chain_arrays(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """The model as arrays for :mod:`wamctl.model.chain_kernels` (payload included): joint placements in
        the parent joint's frame, rotations (n, 3, 3) and translations (n, 3); spatial inertias (n, 6, 6) about
        each joint's origin, linear first; armature (n,); gravity (3,), m/s^2."""
        n = self.model.njoints - 1
        rot = np.array([self.model.jointPlacements[i + 1].rotation for i in range(n)])
        trans = np.array([self.model.jointPlacements[i + 1].translation for i in range(n)])
        inertia = np.array([self.model.inertias[i + 1].matrix() for i in range(n)])
        return rot, trans, inertia, np.array(self.model.armature), np.array(self.model.gravity.linear)


def links_from_standard(pi: np.ndarray, armature_kg_m2: np.ndarray,
                        robot: Robot | str | None = None) -> P.LinkParameters:
    """The :class:`LinkParameters` (DH-frame COM, inertia about the COM) of standard inertial parameters.

    Parameters
    ----------
    pi : (10 n,) standard parameters in the order of :meth:`WamDynamics.standard_parameters`; each link's mass
        must be positive.
    armature_kg_m2 : (n,)
    robot : the arm (default the wam7)

    ``WamDynamics(links=links_from_standard(pi, a)).standard_parameters()`` gives ``pi`` back (to rounding).
    """
    r = get_robot(robot)
    n = r.n_joints
    pi = np.asarray(pi, float).reshape(n, 10)
    mass, com, inertia = np.zeros(n), np.zeros((n, 3)), np.zeros((n, 6))
    for i in range(n):
        if not pi[i, 0] > 0:
            raise ValueError(f"link {i + 1}: mass {pi[i, 0]:g} kg; standard parameters need a positive mass")
        body = _dh_fixed(i, r).actInv(pin.Inertia.FromDynamicParameters(pi[i]))
        mass[i], com[i] = body.mass, body.lever
        m = body.inertia
        inertia[i] = [m[0, 0], m[1, 1], m[2, 2], m[0, 1], m[0, 2], m[1, 2]]
    return P.LinkParameters(mass, com, inertia, armature_kg_m2, robot=r.name)
