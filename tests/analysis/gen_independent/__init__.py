"""Independent test-data generator for ``wamctl diagnose`` (a second opinion, sharing no code with wamctl).

Nothing here imports ``wamctl``: the WAM's numbers are copied below (sources named per block), the rigid-body
model is built here from the DH table with pinocchio, and the closed loop (plant, sensors, controller, logger)
is this module's own. Each run is written in the measured-run format (``meta.yaml`` + ``data.parquet``,
``wamctl-measured/1``); the truth goes to ``truth.yaml`` beside them, never into ``meta.yaml``.

Plant and integration
=====================

=====================  ===========================================================================================
rigid body             pinocchio model built here from standard DH (libbarrett wam7w.conf), link inertials of
                       Sept 2008, plus the reflected rotor inertia diag(J2MP^T diag(Jm) J2MP) as joint armature.
integration            semi-implicit (symplectic) Euler at 4 kHz (h = 0.25 ms): a = M(q)^-1 (tau - n(q,qd) + f),
                       qd += h a, q += h qd.  M^-1 and n from pinocchio at every physics step.
static friction        Karnopp stick band |qd| < 2e-4 rad/s, plus zero-crossing capture (a joint whose velocity
                       would change sign within a step is tested for sticking).  All stuck joints are solved
                       together through the coupled M^-1 (the stuck set's friction makes their accelerations bring
                       the velocity to zero); a joint whose required friction exceeds its breakaway level is
                       released with friction at that level, worst violator first.  Kinetic friction is explicit.
controller             libbarrett PD + gravity at 500 Hz, zero-order hold: u = kp e + kd (e[n]-e[n-1])/T +
                       g_nominal(q_meas), saturated at (25, 20, 15, 15, 5, 5, 5) N m, e = q_ref - q_meas.  Gravity
                       from the NOMINAL model (what the controller knows), on the MEASURED (quantised, noisy,
                       possibly delayed) positions.  A tick's torque takes effect at the next physics step
                       (ticks jitter by +-0.05 ms with ``jitter: loop``).
sensors                motor encoders 4096 counts/rev through J2MP (quantised in motor space, random bin phase per
                       motor, mapped back with J2MP^-1); optional white position noise; optional actuator torque
                       noise (the applied torque differs from the logged command).  Positions are read at the
                       (jittered) tick time by cubic Hermite interpolation of the 4 kHz physics history.
logger                 500 Hz (every tick) or 250 Hz (every second tick, no anti-alias filter).  ``jitter`` =
                       ``stamp``: ticks are exact, the stamps carry U(+-0.2 ms) jitter;
                       ``loop``: the real-time loop itself jitters, ticks at kT + U(+-0.05 ms), stamped
                       truthfully (the reference still advances by T per tick, as in libbarrett, so the kd term
                       sees v * jitter: torque noise growing with speed).
base friction (truth)  classic per direction, Table 4.1: Fc+- x U(0.85, 1.15), |sigma2+-| x U(0.8, 1.2).
=====================  ===========================================================================================

Effects (what the declared model lacks) and how they differ from a naive copy of the candidates' formulas
========================================================================================================

"Naive copy" = the forms named in the first generator's docstring (Stribeck with delta 2, an exponential
warm-up, a dead band on one joint's encoder, a mass at some distance from the flange) and the simplest textbook
forms a diagnosis would fit (one sinusoid in q, a whole-sample shift of the logged positions).  Sizes are drawn per
case from ``size``
(small / medium / large); the truth (concrete parameters, the effect's torque signature and its SNR against
``NOISE_FLOOR``, observability, identifiability) goes to truth.yaml. ``observable``: the effect's torque (or
position lag, or lost motion crossing the dead band) is at least twice the noise floor. ``identifiable``: also
from that run, at least twice the floor of the effect's torque is left after the best fit the declared model's own
freedom allows (each link's mass, centre of mass and inertia within the declared accuracy, the armatures within
10 %, friction free; ``truth._beyond_declared_model``): a payload moved by one joint is often observable and not
identifiable.

=================  ===================================================  ========================  ======================
effect             formula here (truth)                                 differs from a naive copy    range s / m / l
=================  ===================================================  ========================  ======================
stribeck           f = -sgn(v) [Fc + (Fs-Fc) S(|v|/vs)] - sigma2 v,     shape exponent 1 or 1.5, or  Fs/Fc 1.5-1.65 /
                   S = exp(-x^delta) with delta in {1, 1.5}, or         Lorentzian (never delta=2);  1.65-1.8 / 1.8-2.0
                   S = 1/(1+x^2); Fs is also the Karnopp static         static level and per-        (per direction
                   level, +-3 % between directions.                     direction asymmetry; stick-  +-3 %); vs 0.02-
                                                                        slip under PD is kept.       0.05 rad/s
position_ripple    tau_r = A sum_h c_h sin(2 pi h q/P + phi_h),         2-3 harmonics with random    RMS = 2-3 / 4-7 /
                   h = 1..2 or 1..3, sum c_h^2 = 1 (RMS A/sqrt 2),      weights and phases, period   8-14 x the joint's
                   P = 2 pi/(G_j m), m in 1..4 (a harmonic of one       tied to the motor turn (not  noise floor; A <=
                   motor turn), clipped to 0.02-1 rad.                  a free period); acts inside  0.8 Fc
                                                                        the dynamics, also in stick
payload            rigid body added to link 7: mass, COM (frame 7),     own inertia tensor (box,     .05-.15 / .15-.5 /
                   own inertia (box 4-12 cm, randomly rotated);         rotated), lateral COM        .5-1.5 kg; COM xy
                   meta.payload stays null.                             offset, in the plant's       +-3 cm, z 2-12 cm
                                                                        inertia (not only gravity)
delay              q_meas(t) = q(t - d) read from the 4 kHz history     sub-sample (cubic Hermite),  2-4 / 4-7 / 7-10 ms
                   by cubic Hermite interpolation; the controller       inside the loop (the PD acts
                   and the log see the same delayed signal.             on it), before quantisation
friction_drift     Fc+-, sigma2+- (and Fs+-) of one joint x g(t):       linear ramp or tanh, not     |f| .15-.25/.25-.4
                   g = 1 + f t/T_run (linear ramp) or                   exponential; sign + or -     / .4-.6, f < 0 in
                   g = 1 + f tanh(t/tau_w) (warm-up).                                                3 of 4; tau_w =
                                                                                                     .15-.4 T_run
backlash           two-inertia joint: rotor (J = armature_j) and link   a mechanical dead band in    total gap 2-4 / 4-8
                   coupled by a unilateral spring-damper with dead      the drive with its own       / 8-15 mrad;
                   band +-b, tau_c = k dz(qr - q) + c d/dt(qr - q)      dynamics (impacts, gravity   resonance 60-120
                   only in contact; motor torque on the rotor,          may press one flank: then    Hz, contact zeta
                   friction split rotor / link, ENCODER ON THE ROTOR.   invisible, reported).        .1-.3, link share
                                                                                                     of friction .2-.4
link_parameters    clean runs: the plant's links differ from the        truth of a "none" run;       heavier_3_4: links
                   declared ones ("none" expected, "link_parameters"    never named payload          3, 4 mass, inertia
                   acceptable, "payload" forbidden).                                                 +5..10 %, COM +-5
                                                                                                     %; random_10pct:
                                                                                                     links 2-7 x U(.9,
                                                                                                     1.1), COM <= 10 %
two effects        fixed pairs (``PAIRS``), each drawn as above, on     --                           --
                   the same or two moving joints.
=================  ===================================================  ========================  ======================

The project's own simulator integrates with an implicit, velocity-level stick/slip friction step (2 substeps of
2 ms); here the physics runs explicitly at 4 kHz (8 steps per control tick) with a Karnopp band, so the two share
neither the integration nor the friction logic.  Checked in smoke.py: forward kinematics against a plain DH product,
gravity against the gradient of the potential energy, the integrator against RK45 on pinocchio's ABA, and the
applied torque against M a + n + classic friction over each 2 ms interval of clean runs (no fit).

Excitations: ``sweep`` = constant-velocity runs of one joint at 6 speeds (0.005 .. 1 rad/s, shuffled so that
time and speed are not collinear), each out and back (both directions) with cosine velocity blends and holds,
the other joints held at q0; ``free`` = finite Fourier series (5 harmonics of a 6-12 s base period) on 3-5 joints
at once, faded in/out over 1.5 s, scaled to stay inside the joint limits (0.15 rad margin), below 1.5 rad/s,
below 65 % of the torque limits on the nominal model, Cartesian speed below 0.75 m/s and the wrist above the table.

Cases the loop cannot hold (joint beyond its hard stop, |qd| > 5 rad/s, Cartesian speed > 1 m/s as libbarrett's
safety module, non-finite state) end the run there; the rows up to the trip are written and truth.yaml /
GeneratedRun.status say ``safety_trip`` (or ``diverged``).  They are never redrawn.

Designed runs: ``excitation: designed`` with ``reference`` an excitation spec mapping (wamctl's ``kind:
excitation``, e.g. ``next_experiment.yaml`` written by ``wamctl diagnose``): its Fourier series between two holds is
evaluated here (:class:`.excitation.DesignedRef`, the formula the spec documents; wamctl's own trajectory code is not
used) and followed by the same closed loop; ``follow_up(first_dir, spec_path, out_dir)`` simulates it on the arm of
an earlier run with the same truth (:mod:`.follow`), the noise and jitter drawn anew (``noise_seed``).

API: ``cases(n_effect_runs_per_effect, n_clean, seed)`` (a fixed, deterministic study plan),
``generate(case, out_dir) -> GeneratedRun``; CLI ``python -m gen_independent OUT_DIR --n N`` (from tests/analysis).

Modules: :mod:`.arm` (the WAM's numbers and the pinocchio model), :mod:`.physics` (the 4 kHz kernel and the encoder
kernel), :mod:`.excitation`, :mod:`.effects`, :mod:`.simulate` (the closed loop and the run's files), :mod:`.truth`,
:mod:`.plan` (the study plan and the command line), :mod:`.follow` (a designed further run of the same arm).
Nothing here imports ``wamctl``.
"""

from .arm import EFFECTS, GENERATOR_VERSION, JOINT_EFFECTS, LINK_MODES, PAIRS, SIZES
from .follow import follow_up, follow_up_case
from .plan import cases, main
from .simulate import GeneratedRun, generate

__all__ = ["EFFECTS", "GENERATOR_VERSION", "JOINT_EFFECTS", "LINK_MODES", "PAIRS", "SIZES", "GeneratedRun", "cases",
           "follow_up", "follow_up_case", "generate", "main"]
