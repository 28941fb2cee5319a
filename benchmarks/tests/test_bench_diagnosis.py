"""The concealed-effect benchmark's parameter error: counted where the named terms report the
generator's quantity, not where a flexible member's parameters are of another form."""

from __future__ import annotations

import pytest
from bench_diagnosis import fitted_value


def test_the_catalogue_members_fitted_size():
    params = {"bias_at_p10_amplitude_mm": 5.0, "bias_at_p90_amplitude_mm": 1.5}
    assert fitted_value("amplitude_bias", params, {}, 24) == pytest.approx(3.5)
    assert fitted_value("saturation", {"share_of_pixels_clipped": 0.012}, {}, 24) == 0.012


def test_a_flexible_members_fit_is_not_counted():
    shape = {"delay_mm": 3.0, "knots_amplitude": [10.0, 100.0], "delays_at_knots_mm": [4.0, 1.0]}
    assert fitted_value("amplitude_bias", shape, {}, 24) is None
    rows = {"row_gain_rms_percent": 1.2, "effective_parameters": 3.0}
    assert fitted_value("pixel_gain", rows, {}, 24) is None
