"""A block of gaze-controlled reach-and-grasp trials (thesis 6.3.3, 6.4.3, 6.5; issue 7): ``kind: hmi_block``.

The set-up (thesis 6.1, 6.3.3, Figures 6.18-6.20, 6.27)
-------------------------------------------------------
The WAM stands on a table; the subject, wearing the head-mounted gaze tracker, sits at the arm's left side and
looks at the workspace. The hand starts each trial palm down over the start cross; an object is placed on one of
eight marked spots; the subject steers the hand with the gaze (four-directional or vector control, a velocity
profile) and closes the hand with a voluntary blink. A trial is a **hit** when the hand closes with its grasp
centre within ``hit_radius_m`` of the object before ``timeout_s``; the **execution time** is the time from the
start of the trial to the hand closed on the object (the grasp). The thesis ran 10 attempts per spot with one
subject (Tables 6.2-6.8) and one attempt per spot with nine subjects (Table 6.10).

The eight spots are given in metres on the table plane (frame-0 x forward, y to the arm's left; see
:mod:`wamctl.hmi.arm`). The thesis shows them only in photographs (Figures 6.19 and 6.27), so the default layout
:data:`wamctl.specs.hmi_block.DEFAULT_TARGETS_M` is ours, chosen to match what the thesis says and measures: all
spots inside the simulated arm's palm-down workspace (within 0.5 m of the shoulder axis, where joint 2 can carry the
arm: see :data:`wamctl.hmi.arm.TABLE_Z_M`) around the start cross at (0.35, 0.00) m; spot 2 near the arm's base, on
the far side from the subject (the thesis notes its view was obstructed by the base); distances from the start
ordered as the thesis' execution times suggest (Tables 6.3, 6.4: P4 and P1 quickest, then P8, P5, then P2, P3, P6,
and P7 the longest):

====  =============  ====================
spot  (x, y) m       distance from start
====  =============  ====================
P1    (0.35, 0.10)   0.10 m, towards the subject
P2    (0.24, -0.14)  0.18 m, by the base, far side
P3    (0.45, -0.15)  0.18 m, far side, away from the base
P4    (0.42, 0.05)   0.09 m
P5    (0.26, 0.13)   0.16 m, near side, by the base
P6    (0.44, 0.17)   0.19 m, near side
P7    (0.35, -0.22)  0.22 m, far side
P8    (0.29, -0.11)  0.13 m
====  =============  ====================

A trial
-------
1. The hand opens and the arm moves (LSPB in joint space) to the start pose: palm down over the start cross, the
   grasp centre ``grasp_height_m`` above the table.
2. The supervisor starts the trial: at once in simulation (``start: auto``), on Enter with a live tracker
   (``start: prompt``, the default for a serial source).
3. The gaze drives the hand (:class:`~wamctl.hmi.arm.HandArm`) until the hand has closed or the time-out. With the
   virtual subject, a :class:`~wamctl.hmi.policy.ReachPolicy` decides where it looks, closed-loop on the
   simulated hand seen through the scene camera.
4. The trial's row is written (``trials.csv``/``.parquet``), with its events (``hmi_events.csv``) and its hand
   trajectory (``trajectory/part-NNNNN.parquet``, one row per gaze sample). The parts are joined into
   ``trajectory.parquet/.csv`` whenever the session ends, and removed once every trial is done.

Three voluntary blinks in a row end the session: the arm goes home (LSPB to ``home_q_rad``, by default the start
pose) and no further trial starts; a trial that had not been decided is not recorded. After the last trial the arm
goes home too. An interrupted block (Ctrl-C, a signal, the subject's go-home, a gaze stream that ended) resumes
at the next trial with ``wamctl hmi-session --resume RUN_DIR`` (:func:`.run.resume`). The virtual subject of each
trial is seeded from (subject seed, trial number), so a resumed block runs the same trials as an uninterrupted
one (the arm's state at the start pose may differ by the tracking error); see :func:`.planning.trial_seed`.

Time: one clock, the arm's (control ticks of 2 ms since the block started). The virtual subject samples at 30 Hz
on it; a replayed or serial stream is mapped onto it by its first sample (the tracker's ``t_s``), and the
simulation waits for samples that have not arrived yet, never running ahead of the tracker by more than the wall
time elapsed (so a stalled stream stalls in real time and the 200 ms watchdog holds the hand).

Tables of the run directory
---------------------------
``trials``: ``trial, subject, condition, strategy, filter, profile, location, attempt, hit, time_s, outcome
(hit | miss | timeout), error_m, target_x_m, target_y_m, hand_x_m, hand_y_m, t_start_s, n_blinks,
n_voluntary_blinks, n_stalls, path_m, max_tilt_deg, subject_seed``; ``time_s`` is empty for a time-out.
The first six of the thesis columns are those of :data:`wamctl.analysis.hmi_results.TRIAL_COLUMNS`.

``hmi_events``: ``trial, location, attempt, t_s, t_trial_s, kind, detail``; trial 0 is outside trials. Kinds:
gaze events (``blink``, ``voluntary_blink``, ``gripper_close``, ``gripper_open``, ``go_home``), ``command``
(the motion, level or hold changed), arm events (``start``, ``stop``, ``stall``, ``bound``, ``gripper_closing``,
``gripper_closed``, ``gripper_opening``, ``gripper_opened``, ``gripper_ignored``, ``joint_move``,
``joint_move_done``, ``going_home``, ``home_reached``), and ``session_start``, ``stream_start``, ``trial_start``,
``grasp``, ``timeout``, ``end_session_blinks``, ``session_end``.

``trajectory``: one row per gaze sample during trials (``t_s`` arm time, ``gaze_t_s`` the tracker's time of the
sample, NaN for a corrupt line): ``trial, t_s, t_trial_s, gaze_t_s, gaze_x_px, gaze_y_px,
gaze_flags, motion, level, vx_cmd_m_s, vy_cmd_m_s, hold, arm_hold, hand_x_m, hand_y_m, hand_z_m, tilt_deg,
ref_x_m, ref_y_m, gripper`` and ``q_1_rad .. q_7_rad`` (measured). Codes: ``motion`` indexes
:data:`.tables.MOTION_CODES`, ``hold`` :data:`.tables.HOLD_CODES`, ``arm_hold`` :data:`.tables.ARM_HOLD_CODES`.

With a tracker stream (``serial`` or ``replay-raw`` source), beside the tables: ``gaze_capture.txt`` (every read of
the port, raw, with its arrival time), ``gaze_samples.csv`` (every decoded frame: ``arrival_s, t_s, x_px, y_px,
flags, raw_x, raw_y, pupil, status, counter``) and ``gaze_stream.json`` (the decoder's counts and first examples of
each framing/decode error); see :mod:`.feeds` and docs/gaze-streams.md. A stream that gives no usable sample within
``source.start_timeout_s`` ends the run as failed, with what arrived and what to try.

What lives here
---------------
The plan (:mod:`.planning`: poses solved palm down, trials, seeds), the gaze feeds on the arm clock
(:mod:`.feeds`), the supervisor's start (:mod:`.supervisor`), the driver of the block and its trials
(:mod:`.block`), the run directory's tables (:mod:`.tables`), and the runner's entry points ``plan`` / ``execute``
/ ``resume`` (:mod:`.run`), with ``set_supervisor_prompt`` for the CLI. The spec is :mod:`wamctl.specs.hmi_block`;
the gaze controller, the hand on the arm and the virtual subject are :mod:`wamctl.hmi`.

May import: the rest of wamctl.experiments (common, runner) and every layer below (backends, specs, hmi, runs,
control, model, errors). Never report, commands or the CLI.
"""

from __future__ import annotations

from wamctl.experiments.hmi_block.planning import plan
from wamctl.experiments.hmi_block.run import execute, resume
from wamctl.experiments.hmi_block.supervisor import set_supervisor_prompt

__all__ = ["execute", "plan", "resume", "set_supervisor_prompt"]
