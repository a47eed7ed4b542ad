"""Identification of the WAM's own inertial parameters (``wamctl excite``, ``wamctl identify``; issue 18).

* :mod:`.base`: the standard regressor (rigid body from pinocchio + armature + classic per-direction friction),
  the numerical base parameters, and what given data determine. A stable API other analyses build on.
* :mod:`.consistency`: pseudo-inertia, physical consistency of a link.
* :mod:`.excitation`: finite Fourier series excitations designed under the arm's limits.
* :mod:`.data`: measured runs -> filtered identification rows (the diagnosis' filter, twice, in parallel).
* :mod:`.estimator`: instrumental variables, HAC intervals, the physically consistent estimate (an SDP).
* :mod:`.model_file`: the identified arm as a model file (``wamctl-model/1``).
* :mod:`.payload`: a wrist payload from loaded and bare runs of one trajectory, or held poses (issue 29).

No I/O. May import: model, control, specs, runs (the measured-run data type), io, errors, and the diagnosis'
signal preparation (one filter for both analyses).
"""
