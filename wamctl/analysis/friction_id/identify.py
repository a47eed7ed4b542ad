"""The identification result: per joint the friction-velocity map, the fitted models and their selection,
and the chosen models as one :class:`~wamctl.model.friction.FrictionModel`."""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field

import numpy as np
import pandas as pd

from wamctl.analysis.friction_id.models import MODEL_NAMES
from wamctl.analysis.friction_id.selection import select_model
from wamctl.analysis.friction_id.velocity_map import MapOptions, friction_map
from wamctl.errors import DataFormatError
from wamctl.model import params as P
from wamctl.model.controller_torque import constant_gravity
from wamctl.model.friction import FrictionModel

log = logging.getLogger(__name__)


@dataclass
class JointIdentification:
    """One joint's result: the chosen model's name, the selection table and every fitted model."""

    joint: int
    chosen: str
    selection: pd.DataFrame
    fits: dict            # model name -> fitted estimator
    n_segments: int
    n_rejected: int


@dataclass
class FrictionIdentification:
    """Everything the identification produced: the map, per-joint fits and selection, the chosen model."""

    map: pd.DataFrame
    joints: dict[int, JointIdentification] = field(default_factory=dict)
    model: FrictionModel = field(default_factory=FrictionModel.zero)
    options: dict = field(default_factory=dict)
    n_joints: int = P.N_JOINTS      # the robot's joints (4 on a wam4): the joints a model could be given for
    refused: dict[int, str] = field(default_factory=dict)    # joints swept but not used, and why

    def table_4_1(self, model: str | None = None) -> pd.DataFrame:
        """Table 4.1 layout per joint (Fc+/Fc-, sigma2+/sigma2- with standard errors) of the chosen model, or
        of ``model`` for every joint."""
        rows = []
        for j, ji in sorted(self.joints.items()):
            name = model or ji.chosen
            est = ji.fits.get(name)
            if est is None:
                continue
            row = {"joint": j, "model": name,
                   "fc_pos_Nm": est.fc_pos_, "fc_pos_std_Nm": est.fc_pos_std_,
                   "fc_neg_Nm": est.fc_neg_, "fc_neg_std_Nm": est.fc_neg_std_,
                   "sigma2_pos_Nm_s_rad": est.sigma2_pos_, "sigma2_pos_std": est.sigma2_pos_std_,
                   "sigma2_neg_Nm_s_rad": est.sigma2_neg_, "sigma2_neg_std": est.sigma2_neg_std_}
            if name == "stribeck":
                row.update(fs_pos_Nm=est.fs_pos_, fs_neg_Nm=est.fs_neg_, vs_rad_s=est.vs_, delta=est.delta_)
            rows.append(row)
        return pd.DataFrame(rows).set_index("joint") if rows else pd.DataFrame()

    def selection_table(self) -> pd.DataFrame:
        frames = [ji.selection.reset_index().assign(joint=j) for j, ji in sorted(self.joints.items())]
        if not frames:
            return pd.DataFrame()
        return pd.concat(frames, ignore_index=True).set_index(["joint", "model"])

    def file_extra(self) -> dict:
        """Extra keys of ``friction_model.yaml``: per joint the chosen model, standard errors, segments."""
        out = {}
        for j, ji in sorted(self.joints.items()):
            est = ji.fits[ji.chosen]
            out[j] = {"model": ji.chosen, "n_segments": ji.n_segments,
                      "std": {k: (float(s) if np.isfinite(s) else None) for k, s in est.params_std().items()}}
        return {"identification": {"criterion": self.options.get("criterion", "bic"),
                                   "loss": self.options.get("loss", "linear"), "joints": out}}

    def not_identified(self) -> dict[int, str]:
        """Joints without an identified model, and why: not swept (no move of theirs in the data), or too few
        usable constant-velocity segments to fit."""
        in_map = {int(j) for j in self.map["joint"].unique()} if len(self.map) else set()
        out = {}
        for j in range(1, self.n_joints + 1):
            if j in self.joints:
                continue
            if j in self.refused:
                out[j] = self.refused[j]
                continue
            if j not in in_map:
                out[j] = "not swept"
                continue
            mj = self.map[self.map["joint"] == j]
            out[j] = (f"too few usable constant-velocity segments to fit and check a model ({int(mj['accepted'].sum())}"
                      f" of {len(mj)} moves; the others' reasons are in the rejected segments)")
        return out

    def model_file(self) -> tuple[dict, str]:
        """``friction_model.yaml`` as (mapping, header comment): the identified joints' parameters (format
        wamctl-friction/1), their identification details, and the joints not identified with the reason. A
        joint not identified has no parameters (not zeros): a model or feed-forward read from the file treats
        it as frictionless, and the file says so."""
        d = self.model.to_dict()
        d["joints"] = {j: v for j, v in d["joints"].items() if j in self.joints}
        d.update(self.file_extra())
        missing = self.not_identified()
        if missing:
            d["not_identified"] = missing
        header = ""
        if missing:
            why = "; ".join(sorted(set(missing.values())))
            header = (f"# joints {', '.join(map(str, missing))} not identified ({why}): no friction is given for "
                      "them,\n# and whatever reads this file treats them as frictionless.\n")
        return d, header

    def to_dict(self) -> dict:
        return {"options": self.options,
                "joints": {str(j): {"chosen": ji.chosen, "n_segments": ji.n_segments, "n_rejected": ji.n_rejected,
                                    "selection": json_records(ji.selection.reset_index()),
                                    "fits": {k: est.to_dict() for k, est in ji.fits.items()}}
                           for j, ji in sorted(self.joints.items())},
                "model": self.model.to_dict()}


def json_records(df: pd.DataFrame) -> list[dict]:
    out = []
    for rec in df.to_dict(orient="records"):
        out.append({k: (None if isinstance(v, float) and not math.isfinite(v) else
                        (v.item() if hasattr(v, "item") else v)) for k, v in rec.items()})
    return out


def identify_from_map(fmap: pd.DataFrame, models=MODEL_NAMES, folds: int = 5, criterion: str = "bic",
                      loss: str = "linear", weighting: str = "se", n_joints: int = P.N_JOINTS
                      ) -> FrictionIdentification:
    """Fit and select per joint on an existing map; the chosen models as one :class:`FrictionModel`
    (joints without enough segments keep zero friction; on a robot of fewer joints than the wam7, the entries
    beyond ``n_joints`` stay zero and are never written)."""
    result = FrictionIdentification(fmap, options={"models": list(models), "folds": folds,
                                                   "criterion": criterion, "loss": loss, "weighting": weighting},
                                    n_joints=n_joints)
    arrays = {k: np.zeros(P.N_JOINTS) for k in ("fc_pos_Nm", "fc_neg_Nm", "viscous_pos_Nm_s_rad",
                                                 "viscous_neg_Nm_s_rad")}
    arrays.update({k: np.full(P.N_JOINTS, np.nan) for k in ("fs_pos_Nm", "fs_neg_Nm", "vs_rad_s")})
    arrays["stribeck_delta"] = np.full(P.N_JOINTS, 2.0)
    for j in sorted(fmap["joint"].unique()) if len(fmap) else []:
        mj = fmap[(fmap["joint"] == j)]
        acc = mj[mj["accepted"] & mj["friction_Nm"].notna()]
        try:
            table, chosen, fitted = select_model(acc, models, folds, criterion, loss, weighting)
        except ValueError as exc:
            log.info("joint %d: %s", j, exc)
            continue
        result.joints[int(j)] = JointIdentification(int(j), chosen, table, fitted, len(acc), len(mj) - len(acc))
        for k, val in fitted[chosen].joint_params().items():
            arrays[k][int(j) - 1] = val
    result.model = FrictionModel(**arrays)
    return result


def identify(run, options: dict | None = None, map_options: MapOptions | None = None,
             dynamics=None) -> FrictionIdentification:
    """Identify friction from a recorded sweep (:class:`~wamctl.runs.measured.RunData`): map, fits, selection.

    ``options``: ``loss``, ``criterion``, ``folds``, ``models`` (as the spec's ``identification`` section).
    ``dynamics``: the declared rigid body (a WamDynamics, e.g. an identified arm); default the datasheet arm
    of the robot the run names (:mod:`wamctl.model.robots`) with the payload the metadata declare.
    """
    from wamctl.model.dynamics import Payload, WamDynamics

    o = {"loss": "linear", "criterion": "bic", "folds": 5, "models": list(MODEL_NAMES), "weighting": "se"}
    o.update(options or {})
    meta = run.meta
    n = run.n_joints if hasattr(run, "n_joints") else P.N_JOINTS
    joints = list(meta.experiment.joints) or list(range(1, n + 1))
    pl = meta.payload
    dyn = dynamics if dynamics is not None else \
        WamDynamics(Payload(pl.mass_kg, tuple(pl.com_m)) if pl and pl.mass_kg > 0 else None, robot=meta.robot)
    if getattr(dyn, "n_joints", n) != n:
        raise DataFormatError(f"{run.source}: the model has {dyn.n_joints} joints, the run's {meta.robot} {n}")
    q_ref = run.col("q_ref")[:, :n]
    q, tau = run.col("q")[:, :n], run.col("tau")[:, :n]
    refused: dict[int, str] = {}
    if getattr(meta, "torque_kind", "total") == "controller":
        # gravity compensation was added downstream and not logged: only a joint whose gravity torque is constant
        # over the whole run (a vertical axis; wamctl.model.controller_torque) has its whole torque in the log,
        # once the declared gravity is added back
        g, varies = constant_gravity(dyn, q)
        refused = {j: varies[j - 1] for j in joints if j - 1 in varies}
        joints = [j for j in joints if j not in refused]
        if not joints:
            raise DataFormatError(f"{run.source}: no joint left to identify ("
                                  + "; ".join(f"joint {j}: {why}" for j, why in refused.items()) + ")")
        for j, why in refused.items():
            log.warning("joint %d not identified: %s", j, why)
        tau = tau + g     # constant on the joints kept; the others are not read
    fmap = friction_map(run.t_s, q, tau, q_ref, joints, dyn, map_options)
    if not len(fmap) or not fmap["accepted"].any():
        raise DataFormatError(f"{run.source}: no constant-velocity stage found in the data of joints {joints}; "
                              "is this a friction sweep (moves at constant velocities)?")
    result = identify_from_map(fmap, o["models"], o["folds"], o["criterion"], o["loss"], o["weighting"], n)
    result.refused = refused
    return result
