"""Estimators and statistics: friction identification (:mod:`.friction_id`), the residual diagnosis
(:mod:`.diagnosis`), IFT maths (:mod:`.ift`), rotation-test figures (:mod:`.rotation`), ANOVA and the HMI results
(:mod:`.anova`, :mod:`.hmi_results`). No I/O, but for :mod:`.hmi_csv`, which reads and checks a results file.

Estimators look like scikit-learn's: keyword-only ``__init__`` that stores, ``fit(data) -> self``, fitted
attributes ending in ``_``. May import: specs, runs (data types), control, model, io, errors. Never backends,
experiments, report or the CLI: whatever needs a simulator is handed one by its caller.
"""
