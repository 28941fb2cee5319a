"""The concealed-effect generator of the diagnosis benchmark (benchmarks/concealed_generator.py)."""

from __future__ import annotations

import math

import concealed_generator
import numpy as np


def _generator():
    return concealed_generator


def test_generator_cyclic_waveform_has_no_phase_staircase():
    # runs 1-7 read the correlation table at the nearest of 1024 phases: a noise-free pure
    # sinusoid then decoded to a 7.3 mm staircase (+-3.7 mm); interpolated it decodes exactly
    g = _generator()
    f, n = 20e6, 4
    d = np.linspace(1.0, 1.05, 2001)
    arg = 4 * np.pi * f * d / g.C_AIR
    arg = arg[:, None] + 2 * np.pi * np.arange(n)[None] / n
    q = g._wave(g._correlation(0.0), arg).T.reshape(1, n, 1, -1)
    depth, _ = g._decode(q, f)
    assert np.abs(depth[0, 0] - d).max() < 1e-4
    nearest = np.round(np.mod(arg, 2 * np.pi) / (2 * np.pi) * 1024).astype(int) % 1024
    q_old = g._correlation(0.0, 1024)[nearest].T.reshape(1, n, 1, -1)
    old, _ = g._decode(q_old, f)
    assert np.abs(old[0, 0] - d).max() > 3e-3  # the artefact this test guards against


def test_generator_cyclic_truth_is_the_decoded_peak_to_peak():
    g = _generator()
    f, n = 20e6, 4
    r = g.C_AIR / (2 * f)
    d = np.linspace(0.0, r, 4096, endpoint=False)
    arg = 4 * np.pi * f * d[:, None] / g.C_AIR + 2 * np.pi * np.arange(n)[None] / n
    q = g._wave(g._correlation(0.04), arg).T.reshape(1, n, 1, -1)
    depth, _ = g._decode(q, f)
    err = np.mod(depth[0, 0] - d + r / 2, r) - r / 2
    assert math.isclose(err.max() - err.min(), g._cyclic_truth(0.04, f, n), rel_tol=0.02)
    assert err.max() - err.min() > 5e-3  # 8.5 mm p-p at share 0.04
