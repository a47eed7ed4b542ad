"""Control: references (LSPB trajectories, :mod:`.trajectory`) and libbarrett's discrete joint PID with gravity
compensation and friction feed-forward (:mod:`.controllers`, the one copy of the control law).

May import: model, io, errors.
"""
