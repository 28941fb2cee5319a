"""The detection benchmark (benchmarks/bench_detection.py) on a small sample, as a test.

The full figure (200 + 200 scenes) is in docs/runtime.md; here 30 + 30 scenes of random sizes must
give at most one false detection and at least 27 correct detections at amplitude 1.5 x noise.
"""

from __future__ import annotations

import bench_detection as bench
import pytest


@pytest.mark.slow
def test_false_detections_and_detection_rate_on_random_sizes():
    res = bench.run(30, 1.5, seed=1)
    assert res["false_detection_rate"] <= 1 / 30, res["failures"]
    assert res["detection_rate"] >= 27 / 30, res["failures"]
