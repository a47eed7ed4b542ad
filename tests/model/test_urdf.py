"""The WAM as a URDF both ways (wamctl.model.urdf): written URDF loaded by pinocchio's own URDF parser gives
wamctl's dynamics; a URDF of the WAM in other frames (Barrett-description style) reads back to the same links;
what is not a WAM is refused in one line."""

import numpy as np
import pinocchio as pin
import pytest

from wamctl.errors import SpecError
from wamctl.model import params as P
from wamctl.model.dynamics import WamDynamics
from wamctl.model.urdf import UrdfError, _fmt, _inv, _rpy_matrix, _tf, dh_fixed_tf, read_urdf_links, wam_urdf


def _links():
    return P.LinkParameters.datasheet().with_overrides(
        {3: {"mass_kg": 2.5, "com_m": [0.01, 0.2, 0.003]}, 7: {"armature_kg_m2": 0.0005}})


def test_written_urdf_gives_the_same_dynamics_in_pinocchio(tmp_path):
    links = _links()
    path = tmp_path / "model.urdf"
    path.write_text(wam_urdf(links))
    model = pin.buildModelFromUrdf(str(path))
    assert model.nq == 7
    model.armature[:] = read_urdf_links(path).armature_kg_m2     # URDF parsers ignore the armature attribute
    model.gravity.linear[:] = [0.0, 0.0, -P.GRAVITY_M_S2]
    data, dyn = model.createData(), WamDynamics(links=links)
    rng = np.random.default_rng(3)
    for _ in range(10):
        q, qd, qdd = rng.uniform(-2.5, 2.5, (3, 7))
        np.testing.assert_allclose(pin.rnea(model, data, q, qd, qdd), dyn.inverse_dynamics(q, qd, qdd), atol=1e-12)
        m = pin.crba(model, data, q)
        m = np.triu(m) + np.triu(m, 1).T
        np.testing.assert_allclose(m, dyn.mass_matrix(q), atol=1e-12)


def test_written_urdf_reads_back_to_the_same_links():
    links = _links()
    back = read_urdf_links(wam_urdf(links))
    for k in P.LINK_KEYS:
        np.testing.assert_allclose(getattr(back, k), getattr(links, k), atol=1e-14)


def _rz(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def _barrett_style_urdf(hand_kg=0.0, d3_m=P.DH_D_M[2], flip_axis=None, n=7):
    """A WAM URDF laid out as Barrett-style descriptions are (written by this code, not copied: the layout of
    the jhu-lcsr/barrett_model and barrett-ros2-pkg wam_description URDFs, 'wam/base_link', 'wam/j1_joint' ...,
    the base on a pedestal, link frames turned about and shifted along their joint axes, joint axes not z in
    the joint frame, a hand on a fixed joint): the links are the datasheet's, moved into those frames."""
    rng = np.random.default_rng(7)
    ds = P.LinkParameters.datasheet()
    base = _tf(_rz(0.7), [0.22, 0.14, 0.346])          # pedestal: a turn about and a shift along the vertical
    zs = [_tf(_rz(a), [0, 0, h]) for a, h in zip(rng.uniform(-3, 3, 7), rng.uniform(-0.1, 0.1, 7))]
    ss = [_tf(_rpy_matrix(rng.uniform(-3, 3, 3)), [0, 0, 0]) for _ in range(7)]   # joint-frame axis S_i e_z
    out = ['<?xml version="1.0"?>', '<robot name="wam">', '<link name="wam/base_link"/>']
    prev_u, parent = np.eye(4), "wam/base_link"
    d_tf = np.eye(4)
    for i in range(n):
        g_prev = dh_fixed_tf(i - 1) if i else np.eye(4)
        if i == 3:                                      # a modified joint-3 length (d3) moves joint 4
            g_prev = _tf(g_prev[:3, :3], [g_prev[0, 3], 0.0, d3_m])
        d_tf = d_tf @ g_prev
        u = base @ d_tf @ zs[i] @ _inv(ss[i])           # URDF link frame at q = 0
        t = _inv(prev_u) @ u
        rpy = _rpy_from(t[:3, :3])
        axis = ss[i][:3, 2] * (-1 if flip_axis == i + 1 else 1)
        name = f"wam/link{i + 1}"
        out += [f'<joint name="wam/j{i + 1}_joint" type="revolute"><origin xyz="{_fmt(t[:3, 3])}" '
                f'rpy="{_fmt(rpy)}"/><parent link="{parent}"/><child link="{name}"/><axis xyz="{_fmt(axis)}"/>'
                '<limit lower="-2" upper="2" effort="30" velocity="2"/></joint>']
        dh_i = _inv(zs[i] @ _inv(ss[i])) @ dh_fixed_tf(i)     # DH frame i in the URDF link frame
        rot = dh_i[:3, :3]
        com = rot @ ds.com_m[i] + dh_i[:3, 3]
        inertia = rot @ ds.inertia_matrix_kg_m2(i) @ rot.T
        out += [f'<link name="{name}"><inertial><origin xyz="{_fmt(com)}" rpy="0 0 0"/>'
                f'<mass value="{float(ds.mass_kg[i])!r}"/><inertia '
                + " ".join(f'{k}="{float(inertia[a, b])!r}"' for k, (a, b) in (
                    ("ixx", (0, 0)), ("ixy", (0, 1)), ("ixz", (0, 2)), ("iyy", (1, 1)), ("iyz", (1, 2)),
                    ("izz", (2, 2))))
                + '/></inertial></link>']
        prev_u, parent = u, name
    if hand_kg:
        flange = _inv(zs[6] @ _inv(ss[6])) @ dh_fixed_tf(6)
        out += [f'<joint name="wam/hand_joint" type="fixed"><origin xyz="{_fmt(flange[:3, 3])}" '
                f'rpy="{_fmt(_rpy_from(flange[:3, :3]))}"/><parent link="{parent}"/><child link="wam/hand"/></joint>',
                f'<link name="wam/hand"><inertial><origin xyz="0 0 0.08" rpy="0 0 0"/><mass value="{hand_kg}"/>'
                '<inertia ixx="0.002" ixy="0" ixz="0" iyy="0.002" iyz="0" izz="0.001"/></inertial></link>']
    return "\n".join(out + ["</robot>", ""])


def _rpy_from(rot):
    from wamctl.model.urdf import _matrix_rpy
    r = _matrix_rpy(rot)
    np.testing.assert_allclose(_rpy_matrix(r), rot, atol=1e-12)
    return r


def test_barrett_style_urdf_reads_as_the_datasheet_arm():
    back = read_urdf_links(_barrett_style_urdf())
    ds = P.LinkParameters.datasheet()
    for k in P.LINK_KEYS:
        np.testing.assert_allclose(getattr(back, k), getattr(ds, k), atol=1e-12)


def test_a_hand_on_a_fixed_joint_is_lumped_into_link_7():
    back = read_urdf_links(_barrett_style_urdf(hand_kg=1.2))
    ds = P.LinkParameters.datasheet()
    assert back.mass_kg[6] == pytest.approx(ds.mass_kg[6] + 1.2, abs=1e-12)
    # the hand's COM 0.08 m along the flange z: the lumped COM moves there by its mass share
    expect = (ds.mass_kg[6] * ds.com_m[6] + 1.2 * np.array([0, 0, 0.08])) / (ds.mass_kg[6] + 1.2)
    np.testing.assert_allclose(back.com_m[6], expect, atol=1e-12)
    np.testing.assert_allclose(back.mass_kg[:6], ds.mass_kg[:6], atol=1e-12)


@pytest.mark.parametrize("kw, words", [
    ({"n": 6}, "6 revolute joints; the WAM has 7"),
    ({"d3_m": 0.56}, "joint 4): axis 0.01 m off the DH table"),
    ({"flip_axis": 5}, "joint 5): axis 3.14 rad off the DH table's (tolerance 0.001 rad); reversed?"),
])
def test_not_a_wam_is_refused_in_one_line(kw, words):
    with pytest.raises(UrdfError) as exc:
        read_urdf_links(_barrett_style_urdf(**kw))
    assert words in str(exc.value) and "\n" not in str(exc.value)


def test_joint_numbers_out_of_order_are_refused():
    text = _barrett_style_urdf().replace("wam/j2_joint", "wam/jX").replace("wam/j3_joint", "wam/j2_joint") \
        .replace("wam/jX", "wam/j3_joint")
    with pytest.raises(UrdfError, match="not 1..7 in order"):
        read_urdf_links(text)


def test_a_urdf_is_a_declared_arm_and_a_plant(tmp_path):
    from wamctl.experiments.common import declared_links
    from wamctl.specs.load import load_model_file

    links = _links()
    (tmp_path / "arm.urdf").write_text(wam_urdf(links))
    got = declared_links("arm.urdf", tmp_path)
    np.testing.assert_allclose(got.com_m, links.com_m, atol=1e-14)
    plant = load_model_file(tmp_path / "arm.urdf")
    assert plant["links"][3]["mass_kg"] == pytest.approx(2.5, abs=1e-14)
    (tmp_path / "six.urdf").write_text(_barrett_style_urdf(n=6))
    with pytest.raises(SpecError, match="not a URDF of the 7-DOF WAM: .*6 revolute joints"):
        declared_links("six.urdf", tmp_path)


def test_identify_and_diagnose_take_a_urdf_as_the_declared_arm(tmp_path):
    from wamctl.experiments.diagnose import declared_model
    from wamctl.experiments.identify import declared_arm

    links = _links()
    path = tmp_path / "arm.urdf"
    path.write_text(wam_urdf(links))
    dyn, friction, described = declared_arm(path, None)
    q = np.linspace(-1.0, 1.0, 7)
    np.testing.assert_allclose(dyn.gravity(q), WamDynamics(links=links).gravity(q), atol=1e-12)
    assert "arm.urdf" in described
    decl = declared_model(path)
    np.testing.assert_allclose(decl.links.mass_kg, links.mass_kg, atol=1e-14)


def test_a_spec_declaring_a_non_wam_urdf_is_refused_in_one_line(tmp_path):
    import yaml
    from cli_runs import wamctl_completed

    (tmp_path / "six.urdf").write_text(_barrett_style_urdf(n=6))
    (tmp_path / "good.urdf").write_text(wam_urdf())          # the datasheet arm
    from pathlib import Path

    spec = yaml.safe_load((Path(__file__).resolve().parents[2] / "configs" / "rotation.yaml").read_text())
    spec.update(plant="good.urdf", controller=dict(spec.get("controller") or {}, declared_links="six.urdf"))
    (tmp_path / "spec.yaml").write_text(yaml.safe_dump(spec))
    r = wamctl_completed("validate", tmp_path / "spec.yaml")
    assert r.returncode == 2 and "Traceback" not in r.stderr, r.stderr
    assert r.stderr.strip().count("\n") == 0 and "6 revolute joints; the WAM has 7" in r.stderr
    spec["controller"]["declared_links"] = "good.urdf"
    (tmp_path / "spec.yaml").write_text(yaml.safe_dump(spec))
    r = wamctl_completed("validate", tmp_path / "spec.yaml")
    assert r.returncode == 0, r.stderr


# jhu-lcsr/barrett_model, models/components.urdf.xacro (commit 00f07a7f, RE2's WAM description, macros wam_base to
# wam_palm): joint name, origin xyz, origin roll (pitch = yaw = 0, axis 0 0 1 each), child link, its inertial mass
# and origin. Only these numbers are taken; the XML is written below.
BARRETT_MODEL = [
    ("base_yaw_joint", (0, 0, 0.346), 0.0, "shoulder_yaw_link", 5.0, (-.00443422, -.00066489, -0.1289039)),
    ("shoulder_pitch_joint", (0, 0, 0), -np.pi / 2, "shoulder_pitch_link", 3.87493756,
     (-.00236981, -.01542114, .03105614)),
    ("shoulder_yaw_joint", (0, 0, 0), np.pi / 2, "upper_arm_link", 1.80228141, (0.0068325858, 0.00003309, 0.3424923)),
    ("elbow_pitch_joint", (0.045, 0, 0.55), -np.pi / 2, "forearm_link", 1.00016804,
     (-0.04001488, -.12271662, -.00022942)),
    ("wrist_yaw_joint", (-0.045, -0.3, 0), np.pi / 2, "wrist_yaw_link", 1.12376019,
     (0.00008921, 0.00435824, -0.00511217)),
    ("wrist_pitch_joint", (0, 0, 0), -np.pi / 2, "wrist_pitch_link", 0.51797364,
     (-0.00012262, -0.02468336, -0.01703194)),
    ("palm_yaw_joint", (0, 0, 0), np.pi / 2, "wrist_palm_link", 0.08286134, (0.0, 0.0, 0.0)),
]
# the same file's inertia of the upper arm (ixx, iyy, izz) and of the shoulder pitch link, in their link frames
BARRETT_MODEL_DIAG = {"upper_arm_link": (.05911077, 0.05927043, 0.0032455),
                      "shoulder_pitch_link": (0.02140958, 0.015589060, 0.01377875)}


def _barrett_model_urdf(prefix="wam"):
    out = ['<?xml version="1.0"?>', '<robot name="wam7">', '<link name="world"/>',
           f'<joint name="{prefix}/wam_fixed_joint" type="fixed"><parent link="world"/>'
           f'<child link="{prefix}/base_link"/><origin xyz="0 0 0" rpy="0 0 0"/></joint>',
           f'<link name="{prefix}/base_link"><inertial><origin xyz="0 0 0"/><mass value="1"/>'
           '<inertia ixx="0.1" ixy="0" ixz="0" iyy="0.1" iyz="0" izz="0.1"/></inertial></link>']
    parent = f"{prefix}/base_link"
    for joint, xyz, roll, link, mass, com in BARRETT_MODEL:
        ixx, iyy, izz = BARRETT_MODEL_DIAG.get(link, (1e-4, 1e-4, 1e-4))
        out += [f'<joint name="{prefix}/{joint}" type="revolute"><parent link="{parent}"/>'
                f'<child link="{prefix}/{link}"/><origin xyz="{_fmt(xyz)}" rpy="{roll!r} 0 0"/><axis xyz="0 0 1"/>'
                '<limit effort="5" lower="-2" upper="2" velocity="0.5"/><dynamics damping="5.5" friction="1"/></joint>',
                f'<link name="{prefix}/{link}"><inertial><origin xyz="{_fmt(com)}"/><mass value="{mass!r}"/>'
                f'<inertia ixx="{ixx!r}" ixy="0" ixz="0" iyy="{iyy!r}" iyz="0" izz="{izz!r}"/></inertial></link>']
        parent = f"{prefix}/{link}"
    return "\n".join(out + ["</robot>", ""])


def test_the_barrett_model_description_reads_as_a_wam_and_its_upper_arm_is_the_datasheets():
    """RE2's / jhu-lcsr's WAM description (named joints, a 0.346 m pedestal, the wrist frame 0.3 m along the
    forearm axis instead of at the elbow) is the DH table's arm; its shoulder-pitch and upper-arm inertials, moved
    into DH frames 2 and 3, are libbarrett's datasheet numbers (wam7w.conf) to 0.1 mm and 1e-8 kg m^2."""
    links = read_urdf_links(_barrett_model_urdf())
    ds = P.LinkParameters.datasheet()
    np.testing.assert_allclose(links.mass_kg, [m for *_, m, _ in BARRETT_MODEL], atol=1e-12)
    for i in (1, 2):                     # links 2 and 3
        assert links.mass_kg[i] == pytest.approx(ds.mass_kg[i], abs=1e-4)
        # to 0.1 mm: the description's upper-arm COM x is 0.09 mm off wam7w.conf's (-0.038167 vs -0.03826 m)
        np.testing.assert_allclose(links.com_m[i], ds.com_m[i], atol=1e-4)
        np.testing.assert_allclose(sorted(links.inertia_kg_m2[i][:3]), sorted(ds.inertia_kg_m2[i][:3]), atol=1e-8)
    np.testing.assert_allclose(links.armature_kg_m2, ds.armature_kg_m2)     # no armature in the file: datasheet's
    # a base that is not upright (the pedestal tilted by 0.01 rad) is no longer the WAM standing on its base
    tilted = _barrett_model_urdf().replace('<child link="wam/base_link"/><origin xyz="0 0 0" rpy="0 0 0"/>',
                                           '<child link="wam/base_link"/><origin xyz="0 0 0" rpy="0.01 0 0"/>')
    with pytest.raises(UrdfError, match="joint 'wam/base_yaw_joint' .joint 1.: axis not vertical up"):
        read_urdf_links(tilted)
