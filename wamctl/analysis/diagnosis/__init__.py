"""Residual diagnosis: what the declared model of the arm lacks in a measured run.

What lives here, in the order the estimator runs it (:mod:`.estimator`: ``ModelDiagnosis.fit(data)``, the
method and the public API):

* :mod:`.signals`: derivatives, smoothing, masks; :mod:`.prepare`: the rigid-body and declared torques and
  each joint's samples in folds of time blocks;
* :mod:`.candidates`: the candidate effects' regressors; :mod:`.design`: a joint's design matrices;
  :mod:`.crossval`: held-out residuals and shape parameters; :mod:`.stats`: nested tests, whiteness;
* :mod:`.joint`: forward selection at one joint, with :mod:`.headtohead` (competing candidates compared on
  held-out data before one is named, else ``ambiguous``); :mod:`.arm`: the arm's one payload and one delay;
  :mod:`.links`: ``link_parameters``, a refit of the rigid-body base parameters, against the payload;
* :mod:`.sweeps`: Stribeck on the friction map of steady segments (the friction identification's machinery);
* :mod:`.backlash`: onset detection and hidden travel; :mod:`.onsets`: a joint's onsets under its model and
  the stall residual; :mod:`.onset_tests`: backlash and Stribeck seen at onsets;
* :mod:`.parameters`: the models in physical units; :mod:`.intervals` and :mod:`.uncertainty`: 95 % intervals
  and what the data cannot determine; :mod:`.unexplained`: what the residual still follows; :mod:`.gains`: the
  controller's gains from the log; :mod:`.serialise`: ``diagnosis.json``;
  :mod:`.augmented`: the model file and the closed-loop position check.

No I/O. May import: specs, model, control, runs (the measured-run data type), io, errors. Never backends,
experiments, report or the CLI: the closed-loop check is handed a simulator by its caller.
"""
