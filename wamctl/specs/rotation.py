"""The ``rotation`` spec (thesis chapter 3): rotate joints by an amplitude with an LSPB profile."""

from __future__ import annotations

from typing import ClassVar, Literal

import numpy as np
from pydantic import Field, model_validator

from wamctl.model import params as P
from wamctl.model.robots import ROBOTS
from wamctl.specs.common import Common, Joint, Strict, check_positions


class RotationTask(Strict):
    """Thesis chapter 3: rotate joints by ``amplitude_rad`` at ``velocity_rad_s`` (LSPB, t_c = 1 s)."""
    joints: list[Joint] = Field(default_factory=lambda: list(range(1, 8)),
                                description="default: every joint of the robot")
    mode: Literal["one_at_a_time", "all_together"] = "one_at_a_time"
    amplitude_rad: float = Field(P.ROTATION_AMPLITUDE_RAD, description="rotation of each joint, rad (non-zero)")
    velocity_rad_s: float = Field(P.ROTATION_VELOCITY_RAD_S, gt=0.0, le=2.0)
    tc_s: float = Field(P.LSPB_TC_S, gt=0.0)
    settle_s: float = Field(0.5, ge=0.0, description="hold at q0 before each move")
    hold_s: float = Field(1.0, ge=0.0, description="hold at the target after each move")
    return_to_start: bool = Field(True, description="one_at_a_time: move back before the next joint")


class RotationSpec(Common):
    SUPPORTED_ROBOTS: ClassVar[tuple[str, ...]] = tuple(ROBOTS)
    kind: Literal["rotation"]
    rotation: RotationTask = RotationTask()

    @classmethod
    def robot_defaults(cls, data: dict, n_joints: int) -> None:
        rot = data.get("rotation")
        if rot is None or (isinstance(rot, dict) and "joints" not in rot):
            data["rotation"] = dict(rot or {}, joints=list(range(1, n_joints + 1)))

    @model_validator(mode="after")
    def _targets_in_limits(self):
        q0 = np.array(self.q0_rad)
        for j in self.rotation.joints:
            q = q0.copy()
            q[j - 1] += self.rotation.amplitude_rad
            check_positions(q, "rotation.amplitude_rad", self.robot)
        return self


