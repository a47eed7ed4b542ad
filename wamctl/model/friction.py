"""Joint friction models and the friction model file (``friction_model.yaml``).

Sign convention
---------------
``friction_torque(qd)`` is the torque friction *absorbs*: positive for positive velocity, so the motor must
supply it to keep moving (the friction-velocity map of thesis ch. 4). All level parameters are magnitudes.

Models
------
* classic per direction (thesis eq. 4.1, Table 4.1 layout):
  ``F = fc_pos + b_pos qd`` for ``qd > 0``, ``F = -fc_neg + b_neg qd`` for ``qd < 0``.
* Stribeck (thesis eq. 2.8), per direction: the Coulomb level is replaced by
  ``fc + (fs - fc) exp(-|qd / vs|^delta)``.

Simulation of stiction
----------------------
The simulator does not integrate ``sign(qd)`` explicitly (that chatters at zero velocity). It treats
friction as an implicit, velocity-level constraint per joint (a time-stepping scheme in the spirit of
Karnopp's stick band, with a band width that shrinks with the step): over one physics step of length
``dt`` and effective inertia ``m = 1 / (B^-1)_ii``, if the friction impulse available, ``dt * F_break``,
can stop the joint, it sticks (``qd = 0`` exactly); otherwise it slides and the viscous part is integrated
implicitly, ``qd+ = (qd_free - dt F_level / m) / (1 + dt b / m)``, which stays stable for any viscous
coefficient. See :func:`implicit_friction_step`.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import yaml
from numba import njit

from wamctl.errors import DataFormatError
from wamctl.io import load_yaml
from wamctl.model import params as P

FRICTION_FILE_FORMAT = "wamctl-friction/1"


@dataclass
class FrictionModel:
    """Per-joint friction parameters, arrays of shape (n,), one entry per joint of the arm (7 on the wam7, 4 on
    the wam4: the length of ``fc_pos_Nm``). Levels are magnitudes (N m, N m s/rad).

    ``fs_*`` (breakaway levels) and ``vs_rad_s`` are NaN/zero where the joint has no Stribeck term (None: no
    Stribeck term on any joint, ``stribeck_delta`` None: 2 on every joint).
    """

    fc_pos_Nm: np.ndarray
    fc_neg_Nm: np.ndarray
    viscous_pos_Nm_s_rad: np.ndarray
    viscous_neg_Nm_s_rad: np.ndarray
    fs_pos_Nm: np.ndarray | None = None
    fs_neg_Nm: np.ndarray | None = None
    vs_rad_s: np.ndarray | None = None
    stribeck_delta: np.ndarray | None = None

    def __post_init__(self):
        n = np.asarray(self.fc_pos_Nm, dtype=float).size
        for name in self.__dataclass_fields__:
            value = getattr(self, name)
            if value is None:
                value = np.full(n, 2.0 if name == "stribeck_delta" else np.nan)
            arr = np.asarray(value, dtype=float).reshape(-1).copy()
            if arr.shape != (n,):
                raise ValueError(f"{name} must have {n} values (one per joint, as fc_pos_Nm), got {arr.shape[0]}")
            setattr(self, name, arr)

    # --- constructors -------------------------------------------------------------------------
    @classmethod
    def zero(cls, n_joints: int = P.N_JOINTS) -> FrictionModel:
        z = np.zeros(n_joints)
        return cls(z, z, z, z)

    @classmethod
    def table_4_1(cls, n_joints: int = P.N_JOINTS) -> FrictionModel:
        """Thesis Table 4.1, with the absolute value of the viscous figures (some are printed negative).

        ``n_joints`` < 7: the table's first joints (the wam4's joints 1-4 are the wam7's shoulder and elbow,
        same pucks and transmission: :mod:`wamctl.model.robots`)."""
        if not 1 <= n_joints <= P.N_JOINTS:
            raise ValueError(f"Table 4.1 gives friction for joints 1..{P.N_JOINTS}, not {n_joints}")
        return cls(P.TABLE_4_1_FC_POS_NM[:n_joints], P.TABLE_4_1_FC_NEG_NM[:n_joints],
                   np.abs(P.TABLE_4_1_VISCOUS_POS[:n_joints]), np.abs(P.TABLE_4_1_VISCOUS_NEG[:n_joints]))

    @property
    def n_joints(self) -> int:
        return len(self.fc_pos_Nm)

    def for_joints(self, n_joints: int, source: str = "friction model") -> FrictionModel:
        """This model on an arm of ``n_joints``: the first ``n_joints`` entries. Raises ValueError naming the
        first joint beyond ``n_joints`` that has friction (a model of another arm), or when the model has fewer
        joints than asked."""
        if n_joints == self.n_joints:
            return self
        if n_joints > self.n_joints:
            raise ValueError(f"{source}: friction for {self.n_joints} joints, the arm has {n_joints}")
        extra = np.vstack([self.fc_pos_Nm, self.fc_neg_Nm, self.viscous_pos_Nm_s_rad, self.viscous_neg_Nm_s_rad,
                           np.nan_to_num(self.fs_pos_Nm), np.nan_to_num(self.fs_neg_Nm)])[:, n_joints:]
        if (extra != 0).any():
            j = n_joints + 1 + int(np.argmax((extra != 0).any(axis=0)))
            raise ValueError(f"{source}: joints.{j}: friction given for joint {j}, the arm has joints 1..{n_joints}")
        return FrictionModel(**{k: getattr(self, k)[:n_joints] for k in self.__dataclass_fields__})

    # --- derived ------------------------------------------------------------------------------
    @property
    def has_stribeck(self) -> np.ndarray:
        """(7,) bool: joints with a Stribeck term."""
        return np.isfinite(self.fs_pos_Nm) & np.isfinite(self.vs_rad_s) & (np.nan_to_num(self.vs_rad_s) > 0)

    def scaled(self, factor: np.ndarray | float) -> FrictionModel:
        """Every level and coefficient multiplied by ``factor`` (scalar or (7,)), e.g. friction drift."""
        f = np.broadcast_to(np.asarray(factor, float), (self.n_joints,))
        return replace(self, fc_pos_Nm=self.fc_pos_Nm * f, fc_neg_Nm=self.fc_neg_Nm * f,
                       viscous_pos_Nm_s_rad=self.viscous_pos_Nm_s_rad * f,
                       viscous_neg_Nm_s_rad=self.viscous_neg_Nm_s_rad * f,
                       fs_pos_Nm=self.fs_pos_Nm * f, fs_neg_Nm=self.fs_neg_Nm * f)

    def with_stribeck(self, fs_pos_Nm, fs_neg_Nm, vs_rad_s, delta=2.0) -> FrictionModel:
        return replace(self, fs_pos_Nm=np.asarray(fs_pos_Nm, float), fs_neg_Nm=np.asarray(fs_neg_Nm, float),
                       vs_rad_s=np.asarray(vs_rad_s, float),
                       stribeck_delta=np.broadcast_to(np.asarray(delta, float), (self.n_joints,)).copy())

    def as_array(self) -> np.ndarray:
        """(8, n) packed parameters for the numba kernels (rows in dataclass field order)."""
        return np.stack([self.fc_pos_Nm, self.fc_neg_Nm, self.viscous_pos_Nm_s_rad, self.viscous_neg_Nm_s_rad,
                         self.fs_pos_Nm, self.fs_neg_Nm, self.vs_rad_s, self.stribeck_delta])

    def friction_torque(self, qd: np.ndarray) -> np.ndarray:
        """Sliding friction torque F(qd) (absorbed, sign of qd); 0 at qd == 0. Shape of ``qd`` ((n_joints,) or
        (k, n_joints))."""
        qd = np.asarray(qd, float)
        flat = np.ascontiguousarray(qd.reshape(-1, self.n_joints))
        out = np.empty_like(flat)
        _friction_torque_kernel(flat, self.as_array(), out)
        return out.reshape(qd.shape)

    # --- file ---------------------------------------------------------------------------------
    def to_dict(self) -> dict:
        joints = {}
        for j in range(self.n_joints):
            d = {"fc_pos_Nm": float(self.fc_pos_Nm[j]), "fc_neg_Nm": float(self.fc_neg_Nm[j]),
                 "viscous_pos_Nm_s_rad": float(self.viscous_pos_Nm_s_rad[j]),
                 "viscous_neg_Nm_s_rad": float(self.viscous_neg_Nm_s_rad[j])}
            if self.has_stribeck[j]:
                d.update(fs_pos_Nm=float(self.fs_pos_Nm[j]), fs_neg_Nm=float(self.fs_neg_Nm[j]),
                         vs_rad_s=float(self.vs_rad_s[j]), stribeck_delta=float(self.stribeck_delta[j]))
            joints[j + 1] = d
        return {"format": FRICTION_FILE_FORMAT, "joints": joints}

    @classmethod
    def from_dict(cls, data: dict, source: str = "friction model", n_joints: int = P.N_JOINTS) -> FrictionModel:
        """Read the ``joints`` mapping (1-based joint numbers 1..``n_joints``, the arm's); joints not listed have
        zero friction."""
        if not isinstance(data, dict) or not isinstance(data.get("joints"), dict):
            raise DataFormatError(f"{source}: expected a mapping with a 'joints' key")
        n = int(n_joints)
        out = {k: np.zeros(n) for k in ("fc_pos_Nm", "fc_neg_Nm", "viscous_pos_Nm_s_rad", "viscous_neg_Nm_s_rad")}
        out.update({k: np.full(n, np.nan) for k in ("fs_pos_Nm", "fs_neg_Nm", "vs_rad_s")})
        out["stribeck_delta"] = np.full(n, 2.0)
        for key, vals in data["joints"].items():
            try:
                j = int(key)
            except (TypeError, ValueError):
                raise DataFormatError(f"{source}: joints.{key}: joint numbers are 1..{n}") from None
            if not 1 <= j <= n:
                raise DataFormatError(f"{source}: joints.{key}: joint numbers are 1..{n}")
            if not isinstance(vals, dict):
                raise DataFormatError(f"{source}: joints.{key}: expected a mapping of parameters")
            for name, v in vals.items():
                if name not in out:
                    continue  # unknown keys (e.g. uncertainties) are kept in the file and ignored here
                try:
                    out[name][j - 1] = float(v)
                except (TypeError, ValueError):
                    raise DataFormatError(f"{source}: joints.{key}.{name}: not a number: {v!r}") from None
        for name in ("fc_pos_Nm", "fc_neg_Nm", "viscous_pos_Nm_s_rad", "viscous_neg_Nm_s_rad"):
            if (out[name] < 0).any():
                j = int(np.argmax(out[name] < 0)) + 1
                raise DataFormatError(f"{source}: joints.{j}.{name}: must be a magnitude (>= 0)")
        return cls(**out)

    def save(self, path: Path, extra: dict | None = None) -> None:
        d = self.to_dict()
        if extra:
            d.update(extra)
        Path(path).write_text(yaml.safe_dump(d, sort_keys=False))

    @classmethod
    def load(cls, path: Path, n_joints: int = P.N_JOINTS) -> FrictionModel:
        data = load_yaml(path, DataFormatError, "friction model file not found")
        # a model file written by `diagnose` nests the friction under `friction`
        if isinstance(data, dict) and "friction" in data and "joints" not in data:
            data = data["friction"]
        return cls.from_dict(data, str(path), n_joints)


def classic_friction_columns(qd: np.ndarray) -> np.ndarray:
    """Regressor of the classic per-direction model (thesis eq. 4.1), (n, 4): ``F = X @ [fc_pos, fc_neg, b_pos,
    b_neg]`` with the levels as magnitudes. The one copy: the identification and the diagnosis both fit it."""
    qd = np.asarray(qd, float)
    out = np.empty((4, len(qd)))       # filled row by row (contiguous writes), returned transposed
    np.greater(qd, 0, out=out[0])
    np.less(qd, 0, out=out[1])
    np.multiply(qd, out[0], out=out[2])
    np.multiply(qd, out[1], out=out[3])
    np.negative(out[1], out=out[1])
    return out.T


@njit(cache=True)
def stribeck_decay(v, vs_rad_s, delta):
    """``exp(-|v / vs|^delta)``: the share of the breakaway excess ``fs - fc`` left at speed ``v`` (thesis eq. 2.8).

    Scalars or arrays (broadcast). The one copy of the Stribeck shape: the simulator's friction, the
    identification's fits and the diagnosis' regressors all call it."""
    a = np.abs(v / vs_rad_s)
    if delta == 2.0:               # the common exponents without pow (three times faster on long arrays)
        return np.exp(-(a * a))
    if delta == 1.0:
        return np.exp(-a)
    return np.exp(-a ** delta)


@njit(cache=True)
def _level(v, j, positive, prm):
    """Coulomb (+ Stribeck, eq. 2.8) level magnitude of joint j at speed v; prm is FrictionModel.as_array()."""
    fc = prm[0, j] if positive else prm[1, j]
    vs = prm[6, j]
    if vs > 0.0:  # NaN compares False: no Stribeck term
        fs = prm[4, j] if positive else prm[5, j]
        if fs == fs:
            return fc + (fs - fc) * stribeck_decay(v, vs, prm[7, j])
    return fc


@njit(cache=True)
def _friction_torque_kernel(qd, prm, out):
    for i in range(qd.shape[0]):
        for j in range(qd.shape[1]):
            v = qd[i, j]
            # the direction as a bool variable, not the constants True / False: numba compiles a kernel once per
            # literal argument, and _level with a runtime bool is the one the simulator's friction already uses
            pos = v > 0.0
            if pos or v < 0.0:
                level = _level(v, j, pos, prm)
                out[i, j] = level + prm[2, j] * v if pos else -level + prm[3, j] * v
            else:
                out[i, j] = 0.0


@njit(cache=True)
def implicit_friction_1(vf, v_now, inv_m, dt_s, j, prm, scale):
    """Friction torque on joint j over one step by the implicit stick/slip rule (scalar kernel).

    Parameters
    ----------
    vf : velocity the joint would reach over the step without its own friction, rad/s.
    v_now : velocity at the start of the step (sets the Stribeck level), rad/s.
    inv_m : (B^-1)_jj, the inverse effective inertia, 1/(kg m^2).
    dt_s : step, s.
    prm : (8, n) ``FrictionModel.as_array()``; scale : multiplier on every parameter (friction drift).

    Returns
    -------
    The torque absorbed (sign convention of ``friction_torque``). ``vf - dt * inv_m * f`` is zero when the
    joint sticks (the available impulse ``dt * level`` can stop it), else the implicit solution with viscous
    damping ``(vf - dt inv_m level sign(vf)) / (1 + dt inv_m b)``, stable for any coefficient.
    """
    pos = vf > 0.0
    level = scale * _level(v_now, j, pos, prm)
    b = scale * (prm[2, j] if pos else prm[3, j])
    k = dt_s * inv_m
    if abs(vf) <= k * level:
        return vf / k
    vn = (vf - np.sign(vf) * k * level) / (1.0 + k * b)
    return (vf - vn) / k


@njit(cache=True)
def implicit_friction_step(qd_free, qd_now, inv_mass_diag, dt_s, prm, scale, out):
    """:func:`implicit_friction_1` for every joint, each on its own (no coupling), written to ``out`` (n,)."""
    for j in range(qd_free.shape[0]):
        out[j] = implicit_friction_1(qd_free[j], qd_now[j], inv_mass_diag[j], dt_s, j, prm, scale[j])
