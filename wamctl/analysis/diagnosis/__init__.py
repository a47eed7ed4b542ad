"""Residual diagnosis: what the declared model of the arm lacks in a measured run.

What lives here: the estimator (:mod:`.estimator`: ``ModelDiagnosis.fit(data)``), the signals it works on
(:mod:`.signals`: derivatives, segments, held-out blocks), the candidate effects' regressors
(:mod:`.candidates`), the statistics (:mod:`.stats`: nested tests, information criteria), backlash
(:mod:`.backlash`) and the augmented model file (:mod:`.sim`). No I/O.

May import: specs, model, control, runs (the measured-run data type), io, errors. Never backends, experiments,
report or the CLI: the closed-loop check is handed a simulator by its caller.
"""
