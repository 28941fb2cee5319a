"""The form-shifted benchmark's totals: counts per effect, recordings naming the planted effect
alone, and the Clopper-Pearson bounds (checked against the binomial tail they invert)."""

from __future__ import annotations

import pytest
from bench_form_shifted import lower_bound, summary, totals, upper_bound
from scipy.stats import binom


@pytest.mark.parametrize(("k", "n"), [(306, 312), (22, 24), (1, 12), (11, 12)])
def test_lower_bound_leaves_five_percent_above_k(k, n):
    p = lower_bound(k, n)
    # at the bound, k or more successes in n have probability 5 %
    assert binom.sf(k - 1, n, p) == pytest.approx(0.05, rel=1e-6)


@pytest.mark.parametrize(("k", "n"), [(0, 60), (3, 60), (10, 24)])
def test_upper_bound_leaves_five_percent_below_k(k, n):
    p = upper_bound(k, n)
    assert binom.cdf(k, n, p) == pytest.approx(0.05, rel=1e-6)


def test_bounds_at_the_ends():
    assert lower_bound(0, 10) == 0.0
    assert upper_bound(10, 10) == 1.0
    assert upper_bound(0, 60) == pytest.approx(1 - 0.05 ** (1 / 60))


def _rec(effect, form, found, expected=None):
    return {
        "effect": effect,
        "form": form,
        "factor": 1.0,
        "scene": "steps",
        "seconds": 1.0,
        "found": found,
        "top1": found[0] if found else "none",
        "expected": expected or effect or "none",
        "truth": {},
    }


def test_totals_count_top1_alone_and_false_alarms():
    results = [
        _rec("cyclic_error", "A", ["cyclic_error"]),
        _rec("cyclic_error", "B", ["cyclic_error", "fpn_pattern"]),  # top-1, not alone
        _rec("multipath", "A", ["pixel_gain", "multipath"]),  # miss
        _rec("multipath", "B", []),  # miss, nothing named
        _rec("readout_pattern", "A", ["fpn_pattern"], expected="fpn_pattern"),
        _rec(None, None, []),
        _rec(None, None, ["multipath"]),  # false alarm
    ]
    t = totals(summary(results))
    assert (t["recordings"], t["top1"], t["alone"]) == (5, 3, 2)
    assert t["per_effect"] == {
        "cyclic_error": [2, 2],
        "multipath": [0, 2],
        "readout_pattern": [1, 1],
    }
    assert t["worst_effect"] == "multipath"
    assert (t["nulls"], t["false_alarms"]) == (2, 1)
    assert t["top1_lower"] == pytest.approx(lower_bound(3, 5))
