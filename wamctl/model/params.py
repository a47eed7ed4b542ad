"""Physical, control and friction parameters of the 7-DOF Barrett WAM, in one place.

Every number here is copied from public sources (named per block) so that nothing reads files outside
the package at run time. Conventions: standard (distal) DH, Spong convention,
``A_i = Rz(theta_i) Tz(d_i) Tx(a_i) Rx(alpha_i)``, no joint offsets; SI units; joints numbered 1..7 in
user-facing text and 0..6 in arrays.
"""

from __future__ import annotations

import numpy as np

N_JOINTS = 7

# --- Kinematics: libbarrett config/wam7w.conf. d7 = 0.0609 m (libbarrett; the WAM manual says 0.06). ---
DH_A_M = np.array([0.0, 0.0, 0.045, -0.045, 0.0, 0.0, 0.0])
DH_ALPHA_RAD = np.array([-np.pi / 2, np.pi / 2, -np.pi / 2, np.pi / 2, -np.pi / 2, np.pi / 2, 0.0])
DH_D_M = np.array([0.0, 0.0, 0.55, 0.0, 0.30, 0.0, 0.0609])
GRAVITY_M_S2 = 9.81  # along -z0
HOME_Q_RAD = np.array([0.0, -2.0, 0.0, 3.13, 0.0, 0.0, 0.0])

# --- Link inertial parameters: libbarrett config/wam7w.conf, "inertial specifications Sept 2008". ---
# COM in DH frame i (the frame at the output of A_i); inertia about the COM, axes of frame i.
LINK_MASS_KG = np.array([10.7677, 3.8749, 1.8023, 2.17266212, 0.35655692, 0.40915886, 0.07548270])
LINK_COM_M = np.array([
    [-0.00443, 0.12189, -0.00066],
    [-0.00237, 0.03106, 0.01542],
    [-0.03826, 0.20751, 0.00003],
    [0.00553408, 0.00006822, 0.11927695],
    [0.00005483, 0.02886286, 0.00148493],
    [-0.00005923, -0.01686123, 0.02419052],
    [0.00014836, 0.00007252, -0.00335185],
])
# Ixx, Iyy, Izz, Ixy, Ixz, Iyz (kg m^2)
LINK_INERTIA_KG_M2 = np.array([
    [0.13488033, 0.11328369, 0.09046330, -0.00213041, -0.00012485, 0.00068555],
    [0.02140958, 0.01377875, 0.01558906, 0.00027172, 0.00002461, -0.00181920],
    [0.05911077, 0.00324550, 0.05927043, -0.00249612, 0.00000738, -0.00001767],
    [0.01067491, 0.01058659, 0.00282036, 0.00004503, -0.00135557, -0.00011002],
    [0.00037112, 0.00019434, 0.00038209, -0.00000008, -0.00000003, -0.00001613],
    [0.00054889, 0.00023846, 0.00045133, 0.00000019, -0.00000010, -0.00004430],
    [0.00003911, 0.00003877, 0.00007614, 0.00000019, 0.0, 0.0],
])

# --- Transmission: motor angle = J2MP @ joint angle (libbarrett config/wam7w.conf; 9.7 for the J5/J6
# differential as libbarrett uses, the manual gives 9.48). ---
J2MP = np.array([
    [-42.0, 0, 0, 0, 0, 0, 0],
    [0, 28.25, -16.8155, 0, 0, 0, 0],
    [0, -28.25, -16.8155, 0, 0, 0, 0],
    [0, 0, 0, -18.0, 0, 0, 0],
    [0, 0, 0, 0, 9.7, -9.7, 0],
    [0, 0, 0, 0, 9.7, 9.7, 0],
    [0, 0, 0, 0, 0, 0, -14.93],
])
ROTOR_INERTIA_KG_M2 = np.array([9.293e-5] * 4 + [1.472e-5] * 2 + [1.349e-6])
# Reflected rotor inertia, diag(J2MP^T diag(Jm) J2MP): the joint armature of the dynamic model.
ARMATURE_KG_M2 = np.array([0.16393, 0.14833, 0.052554, 0.030109, 0.0027700, 0.0027700, 0.00030070])
ENCODER_COUNTS_PER_REV = 4096  # older arms; 40960 on magnetic encoders (puck property CTS)

# --- Limits (libbarrett; 2 rad/s per joint is a common simulation velocity limit). ---
Q_MIN_RAD = np.array([-2.6, -2.0, -2.8, -0.9, -4.76, -1.6, -3.0])
Q_MAX_RAD = np.array([2.6, 2.0, 2.8, 3.1, 1.24, 1.6, 3.0])
TAU_MAX_NM = np.array([25.0, 20.0, 15.0, 15.0, 5.0, 5.0, 5.0])
QD_MAX_RAD_S = np.full(N_JOINTS, 2.0)

# --- Control (libbarrett defaults): 500 Hz; I += ki*T*e[n-1]; u = kp*e + I + kd*(e - e[n-1])/T. ---
CONTROL_RATE_HZ = 500.0
KP = np.array([900.0, 2500.0, 600.0, 500.0, 50.0, 50.0, 8.0])
KD = np.array([10.0, 20.0, 5.0, 2.0, 0.5, 0.5, 0.05])
KI = np.array([2.5, 5.0, 2.0, 0.5, 0.5, 0.5, 0.1])

# --- Friction measured on the thesis' arm: Table 4.1 (classic model, one parameter set per direction). ---
# Coulomb levels as magnitudes. Several published viscous figures are negative (a fit artefact of few
# low-speed points); a simulated plant uses their absolute value (TABLE_4_1_VISCOUS_ABS) as its truth.
TABLE_4_1_FC_POS_NM = np.array([4.4748, 2.6385, 1.7399, 1.5414, 0.2798, 0.4834, 0.0538])
TABLE_4_1_FC_NEG_NM = np.array([4.3609, 3.5643, 2.3529, 0.7342, 0.1172, 0.4417, 0.1370])
TABLE_4_1_VISCOUS_POS = np.array([1.3348, 3.5572, 0.3944, -2.7045, -0.1972, 0.8291, 1.0689])
TABLE_4_1_VISCOUS_NEG = np.array([0.8266, -2.3951, 1.2075, -1.0969, 1.4670, 0.1836, 0.7954])

# --- Thesis RPE figures (%) of the rotation test, for side-by-side columns in reports. ---
THESIS_RPE_PCT = {
    "pd_g": np.array([1.0876, 0.2342, 0.8666, 0.2912, 1.3592, 3.2848, 5.4132]),        # ch. 3, one at a time
    "pd_g_all": np.array([1.0656, 0.2016, 0.1732, 0.2400, 0.3884, 2.6214, 3.6664]),    # ch. 3, all together
    "pd_g_ff": np.array([1.1198, 0.2244, 0.8988, 0.4398, 1.2426, 1.7974, 7.2360]),     # ch. 4.4
}

# Thesis rotation task (chapter 3): 0.5 rad at 0.083 rad/s, LSPB with t_c = 1 s.
ROTATION_AMPLITUDE_RAD = 0.5
ROTATION_VELOCITY_RAD_S = 0.083
LSPB_TC_S = 1.0


# --- Link parameters as one value: the datasheet's by default, or a model file's (e.g. `wamctl identify`). ---
LINK_KEYS = ("mass_kg", "com_m", "inertia_kg_m2", "armature_kg_m2")


class LinkParameters:
    """Inertial parameters of the seven links and the joint armature: what :class:`wamctl.model.dynamics.
    WamDynamics` builds the rigid body from. :meth:`datasheet` (the default everywhere) holds the numbers above.

    Attributes (copies, arrays in link order 1..7 at rows 0..6)
    ----------
    mass_kg : (7,)
    com_m : (7, 3), centre of mass in DH frame i (the frame at the output of ``A_i``).
    inertia_kg_m2 : (7, 6), ``Ixx, Iyy, Izz, Ixy, Ixz, Iyz`` about the COM, axes of DH frame i.
    armature_kg_m2 : (7,), reflected rotor inertia of joint i (drives link i).

    The mapping form (:meth:`to_mapping`, :meth:`with_overrides`, the ``links:`` section of a model file) is
    ``{joint: {mass_kg, com_m: [x, y, z], inertia_kg_m2: [Ixx, Iyy, Izz, Ixy, Ixz, Iyz], armature_kg_m2}}``
    with 1-based joint numbers; keys left out keep the datasheet's value.
    """

    __slots__ = ("mass_kg", "com_m", "inertia_kg_m2", "armature_kg_m2", "robot")

    def __init__(self, mass_kg, com_m, inertia_kg_m2, armature_kg_m2, robot: str = "wam7"):
        from wamctl.model.robots import get_robot  # robots builds the wam7 from this module's numbers

        n = get_robot(robot).n_joints
        object.__setattr__(self, "robot", get_robot(robot).name)
        shapes = {"mass_kg": (n,), "com_m": (n, 3), "inertia_kg_m2": (n, 6), "armature_kg_m2": (n,)}
        for name, value in zip(LINK_KEYS, (mass_kg, com_m, inertia_kg_m2, armature_kg_m2)):
            arr = np.array(value, dtype=float)
            if arr.shape != shapes[name]:
                raise ValueError(f"{name}: expected shape {shapes[name]}, got {arr.shape}")
            if not np.isfinite(arr).all():
                raise ValueError(f"{name}: non-finite value")
            arr.setflags(write=False)
            object.__setattr__(self, name, arr)

    def __setattr__(self, name, value):
        raise AttributeError("LinkParameters is immutable; use with_overrides()")

    def __reduce__(self):
        """Pickled (a sweep's worker, a test shared between processes) as its constructor's arguments: the
        default pickling of slots sets them one by one, which ``__setattr__`` refuses."""
        return (type(self), (self.mass_kg, self.com_m, self.inertia_kg_m2, self.armature_kg_m2, self.robot))

    @classmethod
    def datasheet(cls, robot=None) -> LinkParameters:
        """The robot's datasheet links (default the wam7: libbarrett wam7w.conf, Sept 2008) and the reflected
        rotor inertia (:mod:`wamctl.model.robots`)."""
        from wamctl.model.robots import get_robot

        r = get_robot(robot)
        return cls(r.link_mass_kg, r.link_com_m, r.link_inertia_kg_m2, r.armature_kg_m2, robot=r.name)

    @property
    def n_joints(self) -> int:
        return len(self.mass_kg)

    def __eq__(self, other) -> bool:
        return isinstance(other, LinkParameters) and self.robot == other.robot and all(
            np.array_equal(getattr(self, k), getattr(other, k)) for k in LINK_KEYS)

    def __hash__(self) -> int:
        return hash((self.robot,) + tuple(getattr(self, k).tobytes() for k in LINK_KEYS))

    def __repr__(self) -> str:
        changed = sorted(self.to_mapping(changed_only=True))
        return f"LinkParameters({'datasheet' if not changed else 'links ' + str(changed) + ' changed'})"

    def with_overrides(self, links: dict | None) -> LinkParameters:
        """A copy with the values of ``links`` ({joint: {key: value}}, 1-based joints; None values and absent
        keys keep this one's) in place of these.

        Raises ValueError naming ``links.<joint>.<key>`` for an unknown key, a wrong length or a mass <= 0."""
        if not links:
            return self
        out = {k: np.array(getattr(self, k)) for k in LINK_KEYS}
        for key, entry in links.items():
            j = int(key)
            if not 1 <= j <= self.n_joints:
                raise ValueError(f"links.{key}: joint numbers of {self.robot} are 1..{self.n_joints}")
            if hasattr(entry, "model_dump"):        # a validated spec entry
                entry = entry.model_dump()
            for name, value in (entry or {}).items():
                if value is None:
                    continue
                if name not in LINK_KEYS:
                    raise ValueError(f"links.{key}.{name}: unknown key (known: {', '.join(LINK_KEYS)})")
                want = out[name][j - 1].shape
                arr = np.asarray(value, dtype=float)
                if arr.shape != want:
                    raise ValueError(f"links.{key}.{name}: expected {int(np.prod(want)) or 1} value(s)")
                out[name][j - 1] = arr
        if (out["mass_kg"] <= 0).any():
            raise ValueError(f"links.{int(np.argmax(out['mass_kg'] <= 0)) + 1}.mass_kg: must be > 0")
        if (out["armature_kg_m2"] < 0).any():
            raise ValueError(f"links.{int(np.argmax(out['armature_kg_m2'] < 0)) + 1}.armature_kg_m2: must be >= 0")
        return LinkParameters(**out, robot=self.robot)

    def to_mapping(self, changed_only: bool = False) -> dict:
        """``{joint: {key: value}}`` (1-based, plain floats and lists); ``changed_only``: only the entries that
        differ from the datasheet."""
        ref = LinkParameters.datasheet(self.robot)
        out = {}
        for j in range(self.n_joints):
            entry = {}
            for name in LINK_KEYS:
                v = getattr(self, name)[j]
                if changed_only and np.allclose(v, getattr(ref, name)[j], rtol=1e-12, atol=1e-15):
                    continue
                entry[name] = float(v) if np.ndim(v) == 0 else [float(x) for x in v]
            if entry:
                out[j + 1] = entry
        return out

    def inconsistent_links(self, rel_tol: float = 1e-9) -> dict[int, str]:
        """``{joint (1-based): why}`` for every link that is not a physical body: mass <= 0, or an inertia
        about the COM that is not positive semidefinite or breaks the triangle inequality (each principal
        moment at most the sum of the other two); together these are exactly a positive semidefinite
        pseudo-inertia (Wensing, Kim and Slotine, 2017)."""
        out = {}
        for i in range(self.n_joints):
            if not self.mass_kg[i] > 0:
                out[i + 1] = f"mass {self.mass_kg[i]:g} kg"
                continue
            ev = np.linalg.eigvalsh(self.inertia_matrix_kg_m2(i))
            tol = rel_tol * max(ev.max(), 1e-12)
            if ev.min() < -tol:
                out[i + 1] = f"inertia about the COM has a negative principal moment ({ev.min():.3g} kg m^2)"
            elif ev.max() > ev.sum() - ev.max() + tol:
                out[i + 1] = (f"principal moments {', '.join(f'{e:.3g}' for e in ev)} kg m^2 break the triangle "
                              "inequality")
        return out

    def inertia_matrix_kg_m2(self, i: int) -> np.ndarray:
        """Link ``i``'s (0-based) inertia tensor about its COM, (3, 3) in DH frame i axes."""
        ixx, iyy, izz, ixy, ixz, iyz = self.inertia_kg_m2[i]
        return np.array([[ixx, ixy, ixz], [ixy, iyy, iyz], [ixz, iyz, izz]])
