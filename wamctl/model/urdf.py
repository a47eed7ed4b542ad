"""The WAM as a URDF, both ways: :func:`wam_urdf` writes one (plain XML, no pinocchio) from a
:class:`~wamctl.model.params.LinkParameters`, :func:`read_urdf_links` reads a URDF of a 7-DOF WAM back into one.

Writing (mirrors :func:`wamctl.model.dynamics.build_wam7_model`): link ``wam_link{i}`` is DH frame ``i-1`` turned
by ``q_i`` about its z axis; joint ``wam_j{i}_joint`` (revolute, axis ``0 0 1``) sits in link ``i-1`` at the fixed
part of the previous DH transform, ``Tz(d_{i-1}) Tx(a_{i-1}) Rx(alpha_{i-1})``; link ``i``'s COM and inertia
(DH frame ``i`` in wamctl) are mapped into the link frame through the fixed part of ``A_i``. URDF has no rotor
inertia: the armature is written as ``<dynamics armature=...>`` on each joint, an attribute URDF parsers ignore
(pinocchio's too: set ``model.armature`` yourself), and read back by :func:`read_urdf_links`. A fixed joint
``wam_flange_joint`` carries a massless link on DH frame 7 (the wrist flange).

Reading: the chain of the seven movable (revolute/continuous) joints from the root, in order along the chain
(joint names like ``*_j3_joint``, ``joint3``, ``wam_j3`` must agree with that order when they carry numbers).
Links hung on fixed joints are lumped into their moving parent (the root's own mass is the base's, ignored).
The URDF is accepted as a WAM only if its kinematics is wamctl's DH table (within ``tol_m``/``tol_rad``): every
link frame, with its joint axis as z, must be the DH body frame up to a turn about and a shift along that axis
(and the base up to a turn about and a shift along the vertical: gravity is -z in both). A missing ``armature``
keeps the datasheet's (the reflected rotor inertia); a missing ``inertial`` element is a massless link, which
is refused (wamctl's links have mass).
"""

from __future__ import annotations

import re
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np

from wamctl.model import params as P

URDF_SUFFIXES = (".urdf",)
MOVABLE = ("revolute", "continuous")


class UrdfError(ValueError):
    """A URDF that cannot be read as the 7-DOF WAM (the message is one line naming the element)."""


def is_urdf(path) -> bool:
    """True for a ``.urdf`` file, or a file whose text starts with an XML declaration or ``<robot``."""
    p = Path(path)
    if p.suffix.lower() in URDF_SUFFIXES:
        return True
    try:
        with open(p, "rb") as fh:
            head = fh.read(512).lstrip()
    except OSError:
        return False
    return head.startswith(b"<?xml") or head.startswith(b"<robot")


# --- small rigid-body helpers (4x4 homogeneous transforms) ---

def _rot_x(a: float) -> np.ndarray:
    c, s = np.cos(a), np.sin(a)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def _rpy_matrix(rpy) -> np.ndarray:
    """URDF's fixed-axis roll, pitch, yaw: R = Rz(yaw) Ry(pitch) Rx(roll)."""
    r, p, y = rpy
    cr, sr, cp, sp, cy, sy = np.cos(r), np.sin(r), np.cos(p), np.sin(p), np.cos(y), np.sin(y)
    return np.array([[cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
                     [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
                     [-sp, cp * sr, cp * cr]])


def _matrix_rpy(rot: np.ndarray) -> np.ndarray:
    """Roll, pitch, yaw of ``rot`` (the inverse of :func:`_rpy_matrix`)."""
    pitch = np.arctan2(-rot[2, 0], np.hypot(rot[0, 0], rot[1, 0]))
    if np.hypot(rot[0, 0], rot[1, 0]) < 1e-12:           # gimbal lock: put all of the turn in roll
        return np.array([np.arctan2(-rot[1, 2], rot[1, 1]), pitch, 0.0])
    return np.array([np.arctan2(rot[2, 1], rot[2, 2]), pitch, np.arctan2(rot[1, 0], rot[0, 0])])


def _tf(rot: np.ndarray, trans) -> np.ndarray:
    t = np.eye(4)
    t[:3, :3] = rot
    t[:3, 3] = trans
    return t


def _inv(t: np.ndarray) -> np.ndarray:
    r = t[:3, :3].T
    return _tf(r, -r @ t[:3, 3])


def dh_fixed_tf(i: int) -> np.ndarray:
    """``Tz(d_i) Tx(a_i) Rx(alpha_i)`` for 0-based joint ``i``, 4x4."""
    return _tf(_rot_x(P.DH_ALPHA_RAD[i]), [P.DH_A_M[i], 0.0, P.DH_D_M[i]])


def _fmt(v) -> str:
    return " ".join(repr(float(x)) for x in np.ravel(v))


# --- writing ---

def wam_urdf(links: P.LinkParameters | None = None, name: str = "wam7", comment: str | None = None) -> str:
    """The 7-DOF WAM with ``links`` (default: the datasheet's) as a URDF document (a string)."""
    links = links if links is not None else P.LinkParameters.datasheet()
    robot = ET.Element("robot", name=name)
    if comment:
        robot.append(ET.Comment(" " + comment.replace("--", "- -") + " "))
    ET.SubElement(robot, "link", name="wam_base_link")
    parent = "wam_base_link"
    for i in range(P.N_JOINTS):
        child = f"wam_link{i + 1}"
        joint = ET.SubElement(robot, "joint", name=f"wam_j{i + 1}_joint", type="revolute")
        if i == 0:
            xyz, rpy = np.zeros(3), np.zeros(3)
        else:
            xyz, rpy = [P.DH_A_M[i - 1], 0.0, P.DH_D_M[i - 1]], [P.DH_ALPHA_RAD[i - 1], 0.0, 0.0]
        ET.SubElement(joint, "origin", xyz=_fmt(xyz), rpy=_fmt(rpy))
        ET.SubElement(joint, "parent", link=parent)
        ET.SubElement(joint, "child", link=child)
        ET.SubElement(joint, "axis", xyz="0 0 1")
        ET.SubElement(joint, "limit", lower=repr(float(P.Q_MIN_RAD[i])), upper=repr(float(P.Q_MAX_RAD[i])),
                      effort=repr(float(P.TAU_MAX_NM[i])), velocity=repr(float(P.QD_MAX_RAD_S[i])))
        ET.SubElement(joint, "dynamics", damping="0", friction="0", armature=repr(float(links.armature_kg_m2[i])))
        fixed = dh_fixed_tf(i)
        rot, trans = fixed[:3, :3], fixed[:3, 3]
        com = rot @ links.com_m[i] + trans
        inertia = rot @ links.inertia_matrix_kg_m2(i) @ rot.T
        link = ET.SubElement(robot, "link", name=child)
        inertial = ET.SubElement(link, "inertial")
        ET.SubElement(inertial, "origin", xyz=_fmt(com), rpy="0 0 0")
        ET.SubElement(inertial, "mass", value=repr(float(links.mass_kg[i])))
        ET.SubElement(inertial, "inertia", ixx=repr(float(inertia[0, 0])), ixy=repr(float(inertia[0, 1])),
                      ixz=repr(float(inertia[0, 2])), iyy=repr(float(inertia[1, 1])), iyz=repr(float(inertia[1, 2])),
                      izz=repr(float(inertia[2, 2])))
        parent = child
    flange = ET.SubElement(robot, "joint", name="wam_flange_joint", type="fixed")
    last = dh_fixed_tf(P.N_JOINTS - 1)
    ET.SubElement(flange, "origin", xyz=_fmt(last[:3, 3]), rpy=_fmt([P.DH_ALPHA_RAD[-1], 0.0, 0.0]))
    ET.SubElement(flange, "parent", link=parent)
    ET.SubElement(flange, "child", link="wam_flange")
    ET.SubElement(robot, "link", name="wam_flange")
    ET.indent(robot)
    return '<?xml version="1.0"?>\n' + ET.tostring(robot, encoding="unicode") + "\n"


# --- reading ---

def _floats(el, attr: str, n: int, default, where: str) -> np.ndarray:
    if el is None or el.get(attr) is None:
        return np.array(default, float)
    try:
        v = np.array([float(x) for x in el.get(attr).split()])
    except ValueError:
        raise UrdfError(f"{where} {attr}={el.get(attr)!r}: not {n} numbers") from None
    if v.shape != (n,) or not np.isfinite(v).all():
        raise UrdfError(f"{where} {attr}={el.get(attr)!r}: not {n} finite numbers")
    return v


def _origin(el, where: str) -> np.ndarray:
    o = el.find("origin") if el is not None else None
    return _tf(_rpy_matrix(_floats(o, "rpy", 3, [0, 0, 0], where + " origin")),
               _floats(o, "xyz", 3, [0, 0, 0], where + " origin"))


def _inertial(link, where: str):
    """(mass, COM (3,), inertia about the COM (3, 3)) in the link frame; None without an inertial element."""
    el = link.find("inertial")
    if el is None:
        return None
    t = _origin(el, where + " inertial")
    m_el = el.find("mass")
    mass = float(_floats(m_el, "value", 1, [np.nan], where + " inertial mass")[0])
    i_el = el.find("inertia")
    vals = {k: float(_floats(i_el, k, 1, [0.0], where + " inertia")[0])
            for k in ("ixx", "ixy", "ixz", "iyy", "iyz", "izz")}
    if not np.isfinite(mass):
        raise UrdfError(f"{where}: inertial without a mass value")
    inertia = np.array([[vals["ixx"], vals["ixy"], vals["ixz"]], [vals["ixy"], vals["iyy"], vals["iyz"]],
                        [vals["ixz"], vals["iyz"], vals["izz"]]])
    rot = t[:3, :3]
    return mass, t[:3, 3], rot @ inertia @ rot.T


def _combine(a, b):
    """Two bodies (mass, com, inertia about com) in one frame as one."""
    if a is None:
        return b
    if b is None:
        return a
    (ma, ca, ia), (mb, cb, ib) = a, b
    m = ma + mb
    if m <= 0:
        return (m, (ca + cb) / 2, ia + ib)
    c = (ma * ca + mb * cb) / m

    def shift(mass, com, inertia):
        d = com - c
        return inertia + mass * (d @ d * np.eye(3) - np.outer(d, d))
    return m, c, shift(ma, ca, ia) + shift(mb, cb, ib)


def _moved(body, t: np.ndarray):
    """A body given in frame B moved into frame A, with ``t`` = pose of B in A."""
    if body is None:
        return None
    m, c, i = body
    r = t[:3, :3]
    return m, r @ c + t[:3, 3], r @ i @ r.T


_NUMBERED = re.compile(r"(?:^|[^a-z])(?:j|joint)_?(\d+)(?:_joint)?$", re.IGNORECASE)


def _axis_frame(axis: np.ndarray) -> np.ndarray:
    """A rotation whose z column is ``axis`` (unit)."""
    z = axis / np.linalg.norm(axis)
    helper = np.array([1.0, 0.0, 0.0]) if abs(z[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    x = np.cross(helper, z)
    x /= np.linalg.norm(x)
    return np.column_stack([x, np.cross(z, x), z])


def _first_link_gauge(t2: np.ndarray, s1: np.ndarray, s2: np.ndarray) -> np.ndarray:
    """``Z_1 = Rz(phi) Tz(h)``: link 1's frame (axis 1 as z) relative to the DH body frame 1, the turn and shift
    that put joint 2's axis where the DH table has it (the base's own turn about and shift along the vertical
    do not change a joint torque, so only this relative placement is fixed)."""
    k2 = _inv(s1) @ t2 @ s2
    g = dh_fixed_tf(0)
    a, ga = k2[:3, 2], g[:3, 2]
    phi = 0.0
    if np.hypot(a[0], a[1]) > 1e-9 and np.hypot(ga[0], ga[1]) > 1e-9:
        phi = np.arctan2(ga[1], ga[0]) - np.arctan2(a[1], a[0])
    c, s_ = np.cos(phi), np.sin(phi)
    rz = np.array([[c, -s_, 0.0], [s_, c, 0.0], [0.0, 0.0, 1.0]])
    rg_t = g[:3, :3].T
    v = rg_t @ (rz @ k2[:3, 3] - g[:3, 3])
    w = rg_t @ np.array([0.0, 0.0, 1.0])
    h = -float(v[:2] @ w[:2]) / float(w[:2] @ w[:2]) if w[:2] @ w[:2] > 1e-12 else 0.0
    return _tf(rz, [0.0, 0.0, h])


def read_urdf_links(source, tol_m: float = 1e-4, tol_rad: float = 1e-3) -> P.LinkParameters:
    """:class:`LinkParameters` of a URDF of the 7-DOF WAM (a path or the XML text); raises :class:`UrdfError`
    (one line) when it is not one: joint count, axes or kinematics not wamctl's DH table within
    ``tol_m``/``tol_rad``."""
    where = str(source) if not (isinstance(source, str) and source.lstrip().startswith("<")) else "URDF"
    try:
        root = ET.fromstring(source) if where == "URDF" else ET.parse(source).getroot()
    except ET.ParseError as exc:
        raise UrdfError(f"{where}: not XML ({exc})") from None
    except OSError as exc:
        raise UrdfError(f"{where}: {exc.strerror or exc}") from None
    if root.tag != "robot":
        raise UrdfError(f"{where}: root element is <{root.tag}>, a URDF's is <robot>")
    link_el = {el.get("name"): el for el in root.findall("link")}
    joints = root.findall("joint")
    children: dict[str, list] = {}
    child_names = set()
    for j in joints:
        jn = j.get("name", "?")
        p, c = j.find("parent"), j.find("child")
        if p is None or c is None or p.get("link") not in link_el or c.get("link") not in link_el:
            raise UrdfError(f"{where}: joint {jn!r}: parent or child link missing")
        children.setdefault(p.get("link"), []).append(j)
        child_names.add(c.get("link"))
    roots = [n for n in link_el if n not in child_names]
    if len(roots) != 1:
        raise UrdfError(f"{where}: {len(roots)} root links ({', '.join(map(str, roots))}); a URDF tree has one")
    movable = [j for j in joints if j.get("type") in MOVABLE]
    other = [j for j in joints if j.get("type") not in MOVABLE + ("fixed",)]
    if other:
        raise UrdfError(f"{where}: joint {other[0].get('name')!r} is {other[0].get('type')}; the WAM has "
                        "revolute joints only")
    if len(movable) != P.N_JOINTS:
        raise UrdfError(f"{where}: {len(movable)} revolute joints; the WAM has {P.N_JOINTS}")

    # walk the tree: poses (zero configuration, relative) and which moving body each link belongs to
    chain: list = []                    # movable joints in order along the chain
    body = {}                           # link name -> (index of moving body or -1 for the base, pose in it)

    def walk(link: str, owner: int, pose: np.ndarray):
        body[link] = (owner, pose)
        for j in children.get(link, []):
            c = j.find("child").get("link")
            t = pose @ _origin(j, f"{where}: joint {j.get('name')!r}")
            if j.get("type") in MOVABLE:
                if owner != len(chain) - 1:
                    raise UrdfError(f"{where}: joint {j.get('name')!r} branches off the chain; the WAM is one "
                                    "serial chain")
                chain.append((j, t))
                walk(c, len(chain) - 1, np.eye(4))
            else:
                walk(c, owner, t)
    walk(roots[0], -1, np.eye(4))
    names = [j.get("name", "") for j, _ in chain]
    numbers = [_NUMBERED.search(n) for n in names]
    if all(numbers) and [int(m.group(1)) for m in numbers] != list(range(1, P.N_JOINTS + 1)):
        raise UrdfError(f"{where}: joints along the chain are {', '.join(names)}; their numbers are not 1..7 "
                        "in order")

    # kinematics: F_i = F_{i-1} K_i Rz(q_i), K_i = (pose of joint i in body i-1) S_i, S_i: z -> axis
    s_prev = np.eye(4)
    z_prev = None
    zs = []
    for i, (j, t) in enumerate(chain):
        axis = _floats(j.find("axis"), "xyz", 3, [1.0, 0.0, 0.0], f"{where}: joint {names[i]!r} axis")
        if np.linalg.norm(axis) < 1e-9:
            raise UrdfError(f"{where}: joint {names[i]!r}: zero axis")
        s = _tf(_axis_frame(axis), np.zeros(3))
        k = _inv(s_prev) @ t @ s
        if i == 0:
            if abs(k[2, 2] - 1) > tol_rad ** 2 / 2:
                raise UrdfError(f"{where}: joint {names[0]!r} (joint 1): axis not vertical up; the WAM's joint 1 "
                                "turns about +z (gravity is -z)")
            axis2 = _floats(chain[1][0].find("axis"), "xyz", 3, [1.0, 0.0, 0.0], f"{where}: joint {names[1]!r} axis")
            z = _first_link_gauge(chain[1][1], s, _tf(_axis_frame(axis2), np.zeros(3)))
        else:
            z = _inv(dh_fixed_tf(i - 1)) @ z_prev @ k
            err_rot = float(np.arccos(np.clip(z[2, 2], -1.0, 1.0)))
            err_m = float(np.hypot(z[0, 3], z[1, 3]))
            if err_rot > tol_rad:
                raise UrdfError(f"{where}: joint {names[i]!r} (joint {i + 1}): axis {err_rot:.3g} rad off the DH "
                                f"table's (tolerance {tol_rad:g} rad)"
                                + ("; reversed?" if err_rot > np.pi - tol_rad else ""))
            if err_m > tol_m:
                raise UrdfError(f"{where}: joint {names[i]!r} (joint {i + 1}): axis {err_m:.3g} m off the DH "
                                f"table's (tolerance {tol_m:g} m)")
        zs.append((z, s))
        z_prev, s_prev = z, s

    # inertias: lump every link of moving body i into its frame, then into DH frame i
    bodies = [None] * P.N_JOINTS
    for name, (owner, pose) in body.items():
        if owner < 0:
            continue
        bodies[owner] = _combine(bodies[owner], _moved(_inertial(link_el[name], f"{where}: link {name!r}"), pose))
    mass, com, inertia, armature = [], [], [], []
    ref = P.LinkParameters.datasheet()
    for i, (z, s) in enumerate(zs):
        b = bodies[i]
        if b is None or not b[0] > 0:
            raise UrdfError(f"{where}: the body of joint {names[i]!r} (link {i + 1}) has no mass")
        # URDF link frame U_i = F_i S_i^T = B D_i Z_i S_i^T; DH frame i = B D_i G_i
        to_dh = _inv(dh_fixed_tf(i)) @ z @ _inv(s)     # pose of the URDF link frame in DH frame i
        m, c, inr = _moved(b, to_dh)
        mass.append(m)
        com.append(c)
        inertia.append([inr[0, 0], inr[1, 1], inr[2, 2], inr[0, 1], inr[0, 2], inr[1, 2]])
        dyn = chain[i][0].find("dynamics")
        arm = dyn.get("armature") if dyn is not None else None
        try:
            armature.append(float(arm) if arm is not None else float(ref.armature_kg_m2[i]))
        except ValueError:
            raise UrdfError(f"{where}: joint {names[i]!r} dynamics armature={arm!r}: not a number") from None
    try:
        return P.LinkParameters(mass, com, inertia, armature)
    except ValueError as exc:
        raise UrdfError(f"{where}: {exc}") from None


def urdf_links_mapping(path) -> dict:
    """The ``links:`` mapping (1-based joints) of a WAM URDF, as a model file holds it."""
    return read_urdf_links(path).to_mapping()
