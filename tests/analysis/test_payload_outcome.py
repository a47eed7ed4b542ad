"""Issue 28: a payload is named when it is identifiable in the issue's sense (outside what the declared link
accuracy can produce), not only beyond twice that accuracy. The rule (:func:`wamctl.analysis.diagnosis.links.
payload_outcome`) on its inputs, and the excess it reads (:func:`~wamctl.analysis.diagnosis.links.
payload_excess_floors`) on residuals of known size."""

from __future__ import annotations

import numpy as np
import pytest

from wamctl.analysis.diagnosis.links import payload_excess_floors, payload_outcome


def _residuals(floor: float, extra: float, n: int = 20000, seed: int = 0):
    """Held-out residuals of the payload model (white, RMS ``floor``) and of the links-only model (the same plus a
    structured part of RMS ``extra``), with NaN where a fold was not predictable."""
    rng = np.random.default_rng(seed)
    e_pay = rng.normal(0.0, floor, n)
    e_links = e_pay + extra * np.sqrt(2.0) * np.sin(np.linspace(0.0, 40.0 * np.pi, n))
    e_pay[:50] = np.nan
    return e_links, e_pay


def test_excess_is_what_the_links_leave_in_noise_floors():
    """1.5 floors of structure beyond a 0.02 N m floor reads 1.5; nothing beyond reads about 0."""
    a, b = _residuals(0.02, 0.03)
    c, d = _residuals(0.05, 0.0, seed=1)
    ex = payload_excess_floors({3: a, 5: c}, {3: b, 5: d})
    assert ex[3] == pytest.approx(1.5, rel=0.02)
    assert ex[5] == pytest.approx(0.0, abs=1e-12)


@pytest.mark.parametrize("passes, excess, outcome", [
    ({"beyond_links": False}, {1: 5.0}, "link_parameters"),                    # the declared accuracy explains it
    ({"beyond_links": True, "beyond_wide_links": True}, {1: 0.3}, "payload"),  # beyond twice the accuracy
    ({"beyond_links": True, "beyond_wide_links": False}, {1: 0.2, 3: 1.2}, "payload"),   # identifiable at joint 3
    ({"beyond_links": True, "beyond_wide_links": False}, {1: 0.6, 3: 0.9}, "ambiguous"),  # the grey zone
    ({"beyond_links": True, "beyond_wide_links": False}, {}, "ambiguous"),
])
def test_payload_outcome(passes, excess, outcome):
    assert payload_outcome(passes, excess) == outcome
