"""The arm a session expects, as the pucks report it: which motor pucks, their groups, POLES, the torque frames,
and the home pose of the zeroing.

An arm on the bus is one of wamctl's robots (:mod:`wamctl.model.robots`), seen the way libbarrett's
``ProductManager`` sees it: ``verifyWamPucks(dof)`` holds when WAM pucks ``1..dof`` answer and pucks ``dof+1..7``
do not (``foundWam4``: pucks 1-4 and no 5-7; ``foundWam7``: pucks 1-7). :class:`BusArm` carries what the session
needs of it: its motor pucks, the WAM pucks that must be absent, the packed-torque frames (``LowLevelWam``: one
per four pucks, ``ceil(dof / 4)`` groups from group 1 on: the wam7 group 1 (pucks 1-4) and 2 (pucks 5-7), the
wam4 group 1 only), the home pose and the transmission.

- ``wam7``: libbarrett's ``wam7w`` (7-DOF WAM with the wrist): pucks 1-7 answer the whole-WAM position request
  (group 4), pucks 1-4 take their torques from the packed frame to group 1 and pucks 5-7 from group 2, and puck 7
  drives the wrist's last motor (POLES 6; a gimbals arm, libbarrett's ``wam7g``, has POLES 8 there).
- ``wam4``: libbarrett's ``wam4`` (the arm without its wrist): pucks 1-4 answer the position request (group 4)
  and take their torques from the packed frame to group 1; pucks 5-7 are absent (present, the bus holds a 7-DOF
  WAM and a wam4 session is refused). Its home pose is ``calibration_data/wam4/zerocal.conf``'s.

Sources: libbarrett ``product_manager.cpp`` (``verifyWamPucks``, ``foundWam4``, ``foundWam7Wrist``: POLES of puck
7, ``getWam4``: ``wamPucks.resize(4)``), ``low_level_wam-inl.h`` (torque groups, ``definePosition``:
``floor(CTS / 2 pi * J2MP home)``), ``puck_group.h`` (group numbers), ``config/wam7w.conf``, ``config/wam4.conf``
and their ``calibration_data/*/zerocal.conf`` (J2MP, home); Barrett's factory values in btclient ``btutil``.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Collection, Mapping, Sequence

import numpy as np

from wamctl.backends.can.protocol.addressing import (
    GROUP_LOWER_WAM,
    GROUP_UPPER_WAM,
    GROUP_WAM,
    NODE_ID_MASK,
    PUCKS_PER_TORQUE_GROUP,
    WAM_PUCK_IDS,
)
from wamctl.model import params as P
from wamctl.model.robots import ROBOTS, Robot, get_robot
from wamctl.model.transmission import J2MP, counts_per_rad, joint_rad_to_motor_rad

__all__ = [
    "BusArm",
    "FACTORY_GROUPS",
    "FACTORY_POLES",
    "GIMBALS_PUCK7_POLES",
    "HOME_Q_RAD",
    "WAM7_BUS",
    "WRIST_PUCK7_POLES",
    "arm_on_bus",
    "bus_arm",
    "configuration_problems",
    "groups_of",
    "puck_set_problem",
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
# libbarrett LowLevelWam's default torque group ids, in order (one per four pucks)
_TORQUE_GROUP_IDS = (GROUP_LOWER_WAM, GROUP_UPPER_WAM)


@dataclasses.dataclass(frozen=True, eq=False)
class BusArm:
    """The arm a session expects on the bus (see the module docstring); build it with :func:`bus_arm`.

    Attributes
    ----------
    name : str
        The robot (``wam7``, ``wam4``).
    puck_ids : tuple of int
        Its motor pucks, motor order (puck ``i`` drives motor ``i``).
    absent_puck_ids : tuple of int
        WAM pucks (of 1-7) that must not answer (libbarrett ``verifyWamPucks``).
    torque_groups : dict of int to tuple of int
        The packed-torque frames the host sends: group id -> its pucks in slot order.
    default_pidx : dict of int to int
        Each puck's slot (PIDX) in its frame as Barrett configures it.
    home_q_rad : numpy.ndarray, shape (n,)
        The zeroing pose.
    j2mp : numpy.ndarray, shape (n, n)
        Motor angle = ``j2mp @ joint angle``.
    """

    name: str
    puck_ids: tuple[int, ...]
    absent_puck_ids: tuple[int, ...]
    torque_groups: dict[int, tuple[int, ...]]
    default_pidx: dict[int, int]
    home_q_rad: np.ndarray
    j2mp: np.ndarray

    @property
    def n_joints(self) -> int:
        return len(self.puck_ids)

    @property
    def all_replied_mask(self) -> int:
        """Bit ``i - 1`` set for each of its pucks ``i``: every position reply of a cycle is in."""
        return sum(1 << (i - 1) for i in self.puck_ids)

    def pucks_words(self) -> str:
        """``pucks 1-4`` (a contiguous run) or ``pucks 1, 3``."""
        return _pucks_words(self.puck_ids)


def _pucks_words(ids: Sequence[int]) -> str:
    ids = sorted(ids)
    if len(ids) > 2 and ids == list(range(ids[0], ids[-1] + 1)):
        return f"pucks {ids[0]}-{ids[-1]}"
    return ("puck " if len(ids) == 1 else "pucks ") + ", ".join(map(str, ids))


def bus_arm(robot: str | Robot | None = None) -> BusArm:
    """The arm ``robot`` (default the wam7) on the bus: libbarrett's pucks, torque groups, home and transmission.

    Raises
    ------
    ValueError
        Naming an unknown robot, or a robot whose motor pucks are not WAM pucks 1..n (libbarrett's ``wamPucks``
        are ids 1..dof, in order).
    """
    r = get_robot(robot)
    pucks = tuple(int(i) for i in r.puck_ids)
    if pucks != tuple(range(1, len(pucks) + 1)) or len(pucks) > len(WAM_PUCK_IDS):
        raise ValueError(f"robot {r.name}: motor pucks {list(pucks)}; a WAM's are 1..dof (dof <= 7)")
    chunks = [pucks[k:k + PUCKS_PER_TORQUE_GROUP] for k in range(0, len(pucks), PUCKS_PER_TORQUE_GROUP)]
    groups = dict(zip(_TORQUE_GROUP_IDS, chunks))
    pidx = {p: k + 1 for members in chunks for k, p in enumerate(members)}
    return BusArm(name=r.name, puck_ids=pucks, absent_puck_ids=tuple(i for i in WAM_PUCK_IDS if i not in pucks),
                  torque_groups=groups, default_pidx=pidx, home_q_rad=np.array(r.home_q_rad, float),
                  j2mp=np.array(r.j2mp, float))


WAM7_BUS = bus_arm("wam7")


def arm_on_bus(found: Collection[int]) -> str | None:
    """The robot whose motor pucks are exactly the WAM pucks that answered (libbarrett ``verifyWamPucks``: pucks
    ``1..dof`` present and the rest of 1-7 absent), or None if no robot wamctl knows has that set."""
    present = tuple(sorted(i for i in found if i in WAM_PUCK_IDS))
    for name, r in ROBOTS.items():
        if tuple(r.puck_ids) == present:
            return name
    return None


def _robot_words(name: str) -> str:
    r = get_robot(name)
    return f"a {r.n_joints}-DOF WAM (robot: {name}, {_pucks_words(r.puck_ids)})"


def puck_set_problem(arm: BusArm, found: Collection[int]) -> tuple[str, bool] | None:
    """Whether the WAM pucks that answered are the arm's: None if they are, else ``(sentence, refused)``.

    ``refused`` is True when the bus holds another arm (a wam4 spec on a 7-DOF WAM: pucks 5-7 answer; a wam7 spec
    on a 4-DOF WAM: pucks 1-4 only), to be refused like a configuration the model does not describe; False when
    pucks of the arm are missing (power, cabling), a link problem.
    """
    present = sorted(i for i in found if i in WAM_PUCK_IDS)
    missing = [i for i in arm.puck_ids if i not in present]
    extra = [i for i in arm.absent_puck_ids if i in present]
    if not missing and not extra:
        return None
    other = arm_on_bus(present)
    if extra:
        text = (f"robot {arm.name} expects {arm.pucks_words()} and no WAM puck beyond, but WAM pucks {extra} answered"
                + (f": the bus holds {_robot_words(other)}; a {arm.name} session is refused on it (set robot: "
                   f"{other} in the spec if that is the arm)" if other else
                   f" (the WAM pucks on the bus, {present}, are no arm wamctl knows)"))
        return text, True
    text = f"WAM pucks {missing} did not answer"
    if other is not None:
        return (text + f": the bus holds {_robot_words(other)}, not the {arm.name} the spec names; refused (set robot: "
                f"{other} in the spec if that is the arm, else check the power and cabling of {_pucks_words(missing)})",
                True)
    return (text + " (power, cabling, termination? after an E-stop press Shift-Idle so the pucks are powered)",
            False)


def groups_of(grp: Sequence[int]) -> set[int]:
    """The broadcast groups (0..31) a node listens to, from its (GRPA, GRPB, GRPC)."""
    return {int(g) & NODE_ID_MASK for g in grp}


def configuration_problems(groups: Mapping[int, Sequence[int]], poles: Mapping[int, int],
                           arm: BusArm = WAM7_BUS) -> list[str]:
    """What about the arm's pucks the model does not describe (an empty list: the arm is the one expected).

    Parameters
    ----------
    groups : dict of int to (int, int, int)
        (GRPA, GRPB, GRPC) per puck of the arm.
    poles : dict of int to int
        POLES per puck (puck 7 at least, on a wam7).
    arm : BusArm, default the wam7
        The arm expected.

    Returns
    -------
    list of str
        One sentence per problem, naming the puck, the property and what the model needs.
    """
    out: list[str] = []
    if 7 in arm.puck_ids:
        p7 = poles.get(7)
        if p7 is None:
            out.append("puck 7 did not report POLES: cannot tell a wrist from gimbals")
        elif p7 == GIMBALS_PUCK7_POLES:
            out.append(f"puck 7 reports POLES={p7}: a WAM with gimbals (libbarrett's wam7g); wamctl's model is the "
                       f"7-DOF WAM with the wrist (puck 7 POLES={WRIST_PUCK7_POLES})")
        elif p7 != WRIST_PUCK7_POLES:
            out.append(f"puck 7 reports POLES={p7}; the wrist's puck 7 has POLES={WRIST_PUCK7_POLES}")
    torque_group = {p: g for g, members in arm.torque_groups.items() for p in members}
    for puck in arm.puck_ids:
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
        tg = torque_group[puck]
        if tg & NODE_ID_MASK not in member:
            which = f"{tg & NODE_ID_MASK} ({_pucks_words(arm.torque_groups[tg])})"
            out.append(f"puck {puck} is in groups {shown} (GRPA/GRPB/GRPC), not in the torque group {which} that "
                       f"its packed torques are sent to")
    return out


def zeroing_counts(cts: Sequence[float], home_q_rad: Sequence[float] = HOME_Q_RAD,
                   j2mp: np.ndarray = J2MP) -> np.ndarray:
    """The P each of the arm's pucks is set to when the arm is zeroed at ``home_q_rad`` (libbarrett
    ``definePosition``: ``floor(CTS / 2 pi * J2MP @ home)``); the wam7's by default, another arm's with its home
    and ``j2mp`` (:class:`BusArm`).

    Returns
    -------
    numpy.ndarray
        ``int64`` counts, shape (n,); for the wam7w home and CTS 4096: (0, -36833, 36832, -36728, 0, 0, 0); for
        the wam4's home (0, -2, 0, 3.13) and CTS 4096: (0, -36833, 36832, -36728).
    """
    return np.floor(counts_per_rad(np.asarray(cts, float)) * joint_rad_to_motor_rad(home_q_rad, j2mp)
                    ).astype(np.int64)
