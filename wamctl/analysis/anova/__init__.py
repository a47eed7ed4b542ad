"""Analysis of variance for HMI results: one-way and repeated-measures ANOVA, pairwise tests, missing cells.

What lives here: the lines of an ANOVA table and the JSON/pandas forms every result shares (:mod:`.tables`),
one-way ANOVA from raw values or from per-group summaries (:mod:`.oneway`), complete cases and the units left out
(:mod:`.cells`), repeated-measures ANOVA with Mauchly's test and the Greenhouse-Geisser / Huynh-Feldt corrections
(:mod:`.repeated`) and Holm-corrected pairwise paired t-tests (:mod:`.posthoc`).

Pure library: no file I/O, no plotting, no printing. May import numpy, pandas, scipy and pingouin (lazily); nothing
of wamctl outside this package.

Conventions
-----------
* A *unit* is what was measured repeatedly: a subject (thesis Table 6.10) or an object location (Tables 6.2-6.4,
  6.8). A *condition* is a level of the within factor (filter, velocity profile, control strategy).
* Values are analysed in the unit they are given in. The thesis ANOVA tables use hit *proportions* (0-1) and
  execution times in seconds; :mod:`wamctl.analysis.hmi_results` converts percentages to proportions.
* Long-format data frames have one row per (unit, condition); the column names are passed explicitly.
* Condition order is the order of first appearance, never alphabetical.
* Missing cells are never dropped silently: :func:`.cells.complete_cases` returns the complete-case subset and the
  list of excluded units with the reason. The ANOVA functions reject NaN.
* ``p`` values are uncorrected unless the name says otherwise (``p_gg``, ``p_hf``, ``p_holm``).
* Result objects are frozen dataclasses with ``to_pandas()`` (for rendering) and ``to_dict()`` (JSON-safe:
  plain floats, ints, strings; NaN becomes ``None``).

Libraries
---------
* One-way ANOVA from raw observations: F and p from :func:`scipy.stats.f_oneway`; the sums of squares (which
  scipy does not return) from their definitions.
* One-way ANOVA from per-group summaries (n, mean, SD or SEM): hand-written sums of squares,
  ``SS_between = sum n_i (m_i - m)^2`` and ``SS_within = sum (n_i - 1) s_i^2``, p from the F distribution
  (:func:`scipy.stats.f.sf`). With exact summaries this equals the raw form.
* Repeated-measures ANOVA, Mauchly's test, Greenhouse-Geisser / Huynh-Feldt epsilon and Holm-corrected paired
  t-tests: ``pingouin`` (imported lazily, it is slow to import). The corrected p values are computed here from the
  epsilon: ``p = F.sf(F, eps * df_effect, eps * df_error)``.
"""
