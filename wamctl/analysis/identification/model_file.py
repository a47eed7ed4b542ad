"""The identified arm as a model file (``format: wamctl-model/1``), usable wherever wamctl takes a model.

Layout (a plant description, :class:`wamctl.specs.PlantSpec`, plus what the identification adds)::

    format: wamctl-model/1
    robot:          the arm when it is not the wam7 (``wam4``: links and friction of joints 1-4)
    links:          {joint: {mass_kg, com_m, inertia_kg_m2, armature_kg_m2}}   every joint of the arm, DH frame i
    friction:       {joints: {joint: {fc_pos_Nm, fc_neg_Nm, viscous_pos_Nm_s_rad, viscous_neg_Nm_s_rad}}}
    provenance:     tool, version, git revision, time, the runs and options it came from
    identification: base parameters (rank, condition number, not identified), held-out RMS, notes

``plant: model.yaml`` simulates the identified arm, ``controller.declared_links: model.yaml`` gives it to the
controller's gravity compensation and feed-forward, ``wamctl diagnose --model model.yaml`` looks for effects
on top of it, and ``controller.friction_ff`` / a friction sweep's declared friction read its ``friction``.

The ``links`` are one physically consistent arm that reproduces the identified base parameters; the data
determine only the base combinations, so individual standard parameters (e.g. one link's mass) are not
identified on their own: the declared arm (the datasheet) decides how each combination is split.
"""

from __future__ import annotations

import numpy as np

from wamctl.io import MODEL_FILE_FORMAT


def model_file(est, provenance: dict, held_out: dict | None = None, check: dict | None = None) -> dict:
    """The model file mapping of a fitted :class:`~wamctl.analysis.identification.estimator.
    InertialIdentification`; ``provenance`` is written as given, ``held_out`` ({joint: {model: RMS}}) and the
    held-out check's verdict (``check``) too."""
    links = est.links_.to_mapping()
    fr = est.friction_
    joints = {j + 1: {"fc_pos_Nm": float(fr.fc_pos_Nm[j]), "fc_neg_Nm": float(fr.fc_neg_Nm[j]),
                      "viscous_pos_Nm_s_rad": float(fr.viscous_pos_Nm_s_rad[j]),
                      "viscous_neg_Nm_s_rad": float(fr.viscous_neg_Nm_s_rad[j])} for j in range(fr.n_joints)}
    ident = est.identifiability_
    summary = {
        "base_parameters": int(ident.n_base), "determined": int(ident.rank),
        "condition_number": float(ident.condition_number) if np.isfinite(ident.condition_number) else None,
        "not_identified": ident.undetermined,
        "consistent": bool((est.margin_ > 0).all()),
        "note": ("links: one physically consistent arm reproducing the identified base parameters; only the base "
                 "combinations are identified, the declared arm decides how each is split into link parameters. "
                 "Parameters the data did not determine keep the declared values."),
    }
    if held_out:
        summary["held_out_rms_Nm"] = held_out
    if check:
        summary["held_out_check"] = {"verdict": check["verdict"], "statement": check["statement"],
                                     "ratio": {int(k): float(v) for k, v in check["ratio"].items()}}
    robot = getattr(est.links_, "robot", "wam7")
    head = {"format": MODEL_FILE_FORMAT} if robot == "wam7" else {"format": MODEL_FILE_FORMAT, "robot": robot}
    return {**head, "links": links, "friction": {"joints": joints},
            "provenance": provenance, "identification": summary}
