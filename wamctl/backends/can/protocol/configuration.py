"""The arm wamctl's model describes, as the pucks report it: groups, POLES, and the home pose of the zeroing.

wamctl's model is libbarrett's ``wam7w`` (7-DOF WAM with the wrist): pucks 1-7 answer the whole-WAM position
request (group 4), pucks 1-4 take their torques from the packed frame to group 1 and pucks 5-7 from group 2, and
puck 7 drives the wrist's last motor (POLES 6; a gimbals arm, libbarrett's ``wam7g``, has POLES 8 there).
Sources: libbarrett ``product_manager.cpp`` (``foundWam7Wrist``: POLES of puck 7), ``puck_group.h`` (group
numbers), ``config/wam7w.conf`` and ``calibration_data/wam7w/zerocal.conf`` (J2MP, home), ``low_level_wam-inl.h``
(``definePosition``: ``floor(CTS / 2 pi * J2MP home)``); Barrett's factory values in btclient ``btutil``.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np

from wamctl.backends.can.protocol.addressing import (
    GROUP_LOWER_WAM,
    GROUP_WAM,
    NODE_ID_MASK,
    TORQUE_GROUPS,
    WAM_PUCK_IDS,
)
from wamctl.model import params as P
from wamctl.model.transmission import J2MP, counts_per_rad, joint_rad_to_motor_rad

__all__ = [
    "FACTORY_GROUPS",
    "FACTORY_POLES",
    "GIMBALS_PUCK7_POLES",
    "HOME_Q_RAD",
    "WRIST_PUCK7_POLES",
    "configuration_problems",
    "groups_of",
    "zeroing_counts",
]

WRIST_PUCK7_POLES = 6  # libbarrett foundWam7Wrist(): POLES of puck 7 == 6
GIMBALS_PUCK7_POLES = 8  # foundWam7Gimbals(): == 8
FACTORY_POLES = {1: 12, 2: 12, 3: 12, 4: 12, 5: 8, 6: 8, 7: 6}  # btutil paramDefaults
# (GRPA, GRPB, GRPC) as Barrett sets them (btutil): pucks 1-4 in groups 0, 1, 4; pucks 5-7 in 0, 2, 4; the
# safety module in 1, 2, 3 (it hears both torque frames and the position replies).
FACTORY_GROUPS = {**dict.fromkeys((1, 2, 3, 4), (0, 1, 4)), **dict.fromkeys((5, 6, 7), (0, 2, 4)), 10: (1, 2, 3)}
# libbarrett's wam7w home pose (zerocal.conf): the arm folded against its stops, rad.
HOME_Q_RAD = np.asarray(P.HOME_Q_RAD, float)


def groups_of(grp: Sequence[int]) -> set[int]:
    """The broadcast groups (0..31) a node listens to, from its (GRPA, GRPB, GRPC)."""
    return {int(g) & NODE_ID_MASK for g in grp}


def configuration_problems(groups: Mapping[int, Sequence[int]], poles: Mapping[int, int]) -> list[str]:
    """What about pucks 1-7 the model does not describe (an empty list: the arm is a wam7 with wrist).

    Parameters
    ----------
    groups : dict of int to (int, int, int)
        (GRPA, GRPB, GRPC) per puck 1..7.
    poles : dict of int to int
        POLES per puck 1..7 (puck 7 at least).

    Returns
    -------
    list of str
        One sentence per problem, naming the puck, the property and what the model needs.
    """
    out: list[str] = []
    p7 = poles.get(7)
    if p7 is None:
        out.append("puck 7 did not report POLES: cannot tell a wrist from gimbals")
    elif p7 == GIMBALS_PUCK7_POLES:
        out.append(f"puck 7 reports POLES={p7}: a WAM with gimbals (libbarrett's wam7g); wamctl's model is the "
                   f"7-DOF WAM with the wrist (puck 7 POLES={WRIST_PUCK7_POLES})")
    elif p7 != WRIST_PUCK7_POLES:
        out.append(f"puck 7 reports POLES={p7}; the wrist's puck 7 has POLES={WRIST_PUCK7_POLES}")
    torque_group = {p: g for g, members in TORQUE_GROUPS.items() for p in members}
    for puck in WAM_PUCK_IDS:
        grp = groups.get(puck)
        if grp is None:
            out.append(f"puck {puck} did not report its groups (GRPA/GRPB/GRPC)")
            continue
        member = groups_of(grp)
        shown = "/".join(str(int(g)) for g in grp)
        if GROUP_WAM & NODE_ID_MASK not in member:
            out.append(f"puck {puck} is in groups {shown} (GRPA/GRPB/GRPC), not in group 4 that the position "
                       f"requests address (Barrett's 2008 manual puts pucks 5-7 in group 5; libbarrett and wamctl "
                       f"need group 4)")
        tg = torque_group[puck] & NODE_ID_MASK
        if tg not in member:
            which = "1 (pucks 1-4)" if torque_group[puck] == GROUP_LOWER_WAM else "2 (pucks 5-7)"
            out.append(f"puck {puck} is in groups {shown} (GRPA/GRPB/GRPC), not in the torque group {which} that "
                       f"its packed torques are sent to")
    return out


def zeroing_counts(cts: Sequence[float], home_q_rad: Sequence[float] = HOME_Q_RAD,
                   j2mp: np.ndarray = J2MP) -> np.ndarray:
    """The P each puck 1..7 is set to when the arm is zeroed at ``home_q_rad`` (libbarrett ``definePosition``:
    ``floor(CTS / 2 pi * J2MP @ home)``).

    Returns
    -------
    numpy.ndarray
        ``int64`` counts, shape (7,); for the wam7w home and CTS 4096: (0, -36833, 36832, -36728, 0, 0, 0).
    """
    return np.floor(counts_per_rad(np.asarray(cts, float)) * joint_rad_to_motor_rad(home_q_rad, j2mp)
                    ).astype(np.int64)
