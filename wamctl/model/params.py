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
