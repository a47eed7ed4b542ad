"""Estimators and statistics, no I/O but reading a results file: friction identification (:mod:`.friction_id`), the residual diagnosis
(:mod:`.diagnosis`), IFT maths (:mod:`.ift`), rotation-test figures (:mod:`.rotation`), ANOVA and the HMI results
(:mod:`.anova`, :mod:`.hmi_results`; :mod:`.hmi_csv` reads and checks the results files).

Estimators look like scikit-learn's: keyword-only ``__init__`` that stores, ``fit(data) -> self``, fitted
attributes ending in ``_``. May import: specs, runs (data types), control, model, io, errors. Never backends,
experiments, report or the CLI: whatever needs a simulator is handed one by its caller.
"""
