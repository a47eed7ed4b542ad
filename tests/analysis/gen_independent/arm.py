"""The WAM's numbers (copied, not imported: each block names its source), this generator's simulation constants,
and the rigid-body model built with pinocchio from the DH table."""

from __future__ import annotations

import math

import numpy as np
import pinocchio as pin

GENERATOR_VERSION = "gen2-independent/1"
N = 7

# ----------------------------------------------------------------------------------------------------------------
# WAM numbers, copied (not imported).
# Kinematics: standard DH, libbarrett config/wam7w.conf (via /work/shared/reference/wam7-params.md), d7 = 0.0609.
DH_A = np.array([0.0, 0.0, 0.045, -0.045, 0.0, 0.0, 0.0])
DH_ALPHA = np.array([-0.5, 0.5, -0.5, 0.5, -0.5, 0.5, 0.0]) * np.pi
DH_D = np.array([0.0, 0.0, 0.55, 0.0, 0.30, 0.0, 0.0609])
G0 = 9.81
# Link inertials: libbarrett wam7w.conf "inertial specifications Sept 2008" (wam7-params.md); COM in DH frame i,
# inertia tensor about the COM in frame-i axes: Ixx, Iyy, Izz, Ixy, Ixz, Iyz.
LINK_MASS = np.array([10.7677, 3.8749, 1.8023, 2.17266212, 0.35655692, 0.40915886, 0.07548270])
LINK_COM = np.array([
    [-0.00443, 0.12189, -0.00066],
    [-0.00237, 0.03106, 0.01542],
    [-0.03826, 0.20751, 0.00003],
    [0.00553408, 0.00006822, 0.11927695],
    [0.00005483, 0.02886286, 0.00148493],
    [-0.00005923, -0.01686123, 0.02419052],
    [0.00014836, 0.00007252, -0.00335185],
])
LINK_INERTIA = np.array([
    [0.13488033, 0.11328369, 0.09046330, -0.00213041, -0.00012485, 0.00068555],
    [0.02140958, 0.01377875, 0.01558906, 0.00027172, 0.00002461, -0.00181920],
    [0.05911077, 0.00324550, 0.05927043, -0.00249612, 0.00000738, -0.00001767],
    [0.01067491, 0.01058659, 0.00282036, 0.00004503, -0.00135557, -0.00011002],
    [0.00037112, 0.00019434, 0.00038209, -0.00000008, -0.00000003, -0.00001613],
    [0.00054889, 0.00023846, 0.00045133, 0.00000019, -0.00000010, -0.00004430],
    [0.00003911, 0.00003877, 0.00007614, 0.00000019, 0.0, 0.0],
])
# Transmission: motor angle = J2MP @ joint angle (libbarrett wam7w.conf, 9.7 for the J5/J6 differential).
J2MP = np.array([
    [-42.0, 0, 0, 0, 0, 0, 0],
    [0, 28.25, -16.8155, 0, 0, 0, 0],
    [0, -28.25, -16.8155, 0, 0, 0, 0],
    [0, 0, 0, -18.0, 0, 0, 0],
    [0, 0, 0, 0, 9.7, -9.7, 0],
    [0, 0, 0, 0, 9.7, 9.7, 0],
    [0, 0, 0, 0, 0, 0, -14.93],
])
J2MP_INV = np.linalg.inv(J2MP)
GEAR = np.array([42.0, 28.25, 16.8155, 18.0, 9.7, 9.7, 14.93])  # per-joint motor turns per joint turn (magnitude)
ROTOR_J = np.array([9.293e-5] * 4 + [1.472e-5] * 2 + [1.349e-6])  # wam7-params.md, "Motors and transmission"
ARMATURE = np.diag(J2MP.T @ np.diag(ROTOR_J) @ J2MP).copy()        # = 0.16393, 0.14833, 0.052554, ... (listed)
ENCODER_CPR = 4096                                                  # older arms (puck property CTS)
# Limits (wam7-params.md "Limits").
Q_MIN = np.array([-2.6, -2.0, -2.8, -0.9, -4.76, -1.6, -3.0])
Q_MAX = np.array([2.6, 2.0, 2.8, 3.1, 1.24, 1.6, 3.0])
TAU_MAX = np.array([25.0, 20.0, 15.0, 15.0, 5.0, 5.0, 5.0])
# Control: libbarrett wam7w.conf joint_position_control, 500 Hz.
KP = np.array([900.0, 2500.0, 600.0, 500.0, 50.0, 50.0, 8.0])
KD = np.array([10.0, 20.0, 5.0, 2.0, 0.5, 0.5, 0.05])
T_CTRL = 1.0 / 500.0
# Friction, Table 4.1 of the thesis (wam-thesis.md / wam7-params.md); magnitudes of the viscous figures.
T41_FC_POS = np.array([4.4748, 2.6385, 1.7399, 1.5414, 0.2798, 0.4834, 0.0538])
T41_FC_NEG = np.array([4.3609, 3.5643, 2.3529, 0.7342, 0.1172, 0.4417, 0.1370])
T41_B_POS = np.abs(np.array([1.3348, 3.5572, 0.3944, -2.7045, -0.1972, 0.8291, 1.0689]))
T41_B_NEG = np.abs(np.array([0.8266, -2.3951, 1.2075, -1.0969, 1.4670, 0.1836, 0.7954]))
# Safety (wam7-params.md: safety module faults at 1.0 m/s Cartesian speed).
CART_SPEED_FAULT = 1.0

# ----------------------------------------------------------------------------------------------------------------
# Simulation constants of this generator.
H_PHYS = 1.0 / 4000.0
STICK_BAND = 2e-4          # rad/s, Karnopp band
JITTER_S = 0.2e-3          # time-stamp jitter of the logger (jitter = "stamp")
LOOP_JITTER_S = 0.05e-3    # real-time loop jitter (jitter = "loop"): the tick really happens late or early
NOISE_PROFILES = {
    # white position noise (rad) on top of quantisation; actuator torque noise (N m, per tick)
    "quiet": {"pos_sigma": np.zeros(N), "tau_sigma": np.zeros(N)},
    "noisy": {"pos_sigma": np.full(N, 2e-5),
              "tau_sigma": np.array([0.05, 0.05, 0.03, 0.03, 0.008, 0.008, 0.003])},
}
# Torque noise floor per joint (N m): RMS of the residual of a classic-friction least-squares fit on clean runs
# (smoke.fit_classic: zero-phase 4th-order 15 Hz Butterworth on q and tau, nominal inverse dynamics, samples with
# |qd| > 0.02 rad/s and no reversal within 40 ms), median over ~16 clean runs per joint and profile (sweep and free,
# 500 and 250 Hz), measured by calibrate_floor.py; the 90th percentile is about 2-4x the median.  Used only to
# scale the ripple amplitude and to report an SNR in truth.yaml.
NOISE_FLOOR = {
    "quiet": np.array([0.016, 0.032, 0.010, 0.0074, 0.0010, 0.0008, 0.0007]),
    "noisy": np.array([0.023, 0.049, 0.0135, 0.012, 0.0022, 0.0021, 0.0011]),
}

EFFECTS = ("stribeck", "position_ripple", "payload", "delay", "friction_drift", "backlash")
JOINT_EFFECTS = ("stribeck", "position_ripple", "friction_drift", "backlash")
SIZES = ("small", "medium", "large")
PAIRS = (
    ("stribeck", "payload"),
    ("position_ripple", "friction_drift"),
    ("delay", "stribeck"),
    ("backlash", "payload"),
    ("friction_drift", "payload"),
    ("position_ripple", "delay"),
    ("stribeck", "position_ripple"),
)
LINK_MODES = ("nominal", "heavier_3_4", "random_10pct")


# ----------------------------------------------------------------------------------------------------------------
# Rigid-body model construction (own code, from the DH table).

def _inertia_matrix(row):
    ixx, iyy, izz, ixy, ixz, iyz = row
    return np.array([[ixx, ixy, ixz], [ixy, iyy, iyz], [ixz, iyz, izz]])


def _rx(a):
    c, s = math.cos(a), math.sin(a)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def dh_tail(i):
    """Tz(d_i) Tx(a_i) Rx(alpha_i): DH frame i seen from the rotated frame of joint i."""
    return pin.SE3(_rx(DH_ALPHA[i]), np.array([DH_A[i], 0.0, DH_D[i]]))


def build_model(mass=LINK_MASS, com=LINK_COM, inertia=LINK_INERTIA, armature=ARMATURE, payload=None):
    """pinocchio model of the WAM: joint i = revolute about z_{i-1} of DH; link i's inertia given in DH frame i.

    ``payload``: dict(mass, com (frame 7), inertia 3x3 about its COM in frame-7 axes), rigidly added to link 7.
    Frames ``dh1``..``dh7`` are the DH frames.
    """
    model = pin.Model()
    model.name = "wam7_gen2"
    parent = 0
    placement = pin.SE3.Identity()
    parent_frame = 0
    for i in range(N):
        jid = model.addJoint(parent, pin.JointModelRZ(), placement, f"j{i + 1}",
                             np.array([TAU_MAX[i]]), np.array([5.0]), np.array([Q_MIN[i]]), np.array([Q_MAX[i]]))
        tail = dh_tail(i)
        inertia_dh = pin.Inertia(float(mass[i]), np.asarray(com[i], float), _inertia_matrix(inertia[i]))
        model.appendBodyToJoint(jid, tail.act(inertia_dh), pin.SE3.Identity())
        if i == N - 1 and payload is not None:
            ip = pin.Inertia(float(payload["mass"]), np.asarray(payload["com"], float),
                             np.asarray(payload["inertia"], float))
            model.appendBodyToJoint(jid, tail.act(ip), pin.SE3.Identity())
        fid = model.addFrame(pin.Frame(f"dh{i + 1}", jid, parent_frame, tail, pin.FrameType.OP_FRAME))
        parent_frame = fid
        parent, placement = jid, tail
    model.armature = np.asarray(armature, float).copy()
    model.gravity.linear = np.array([0.0, 0.0, -G0])
    return model


def dh_fk_numpy(q):
    """Plain DH product (no pinocchio), 4x4 transforms of frames 1..7: for self-checks."""
    T = np.eye(4)
    out = []
    for i in range(N):
        c, s = math.cos(q[i]), math.sin(q[i])
        ca, sa = math.cos(DH_ALPHA[i]), math.sin(DH_ALPHA[i])
        A = np.array([[c, -s * ca, s * sa, DH_A[i] * c],
                      [s, c * ca, -c * sa, DH_A[i] * s],
                      [0, sa, ca, DH_D[i]],
                      [0, 0, 0, 1.0]])
        T = T @ A
        out.append(T.copy())
    return out


