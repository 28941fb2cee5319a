"""The never-hurts benchmark (benchmarks/bench_never_hurts.py) on its quick sizes, as a test."""

from __future__ import annotations

import bench_never_hurts as bench


def test_stripe_free_frames_of_many_sizes_are_left_alone():
    res = bench.run(bench.QUICK_SIZES)
    assert res["frames"] == 2 * 2 * len(bench.NOISE) * len(bench.QUICK_SIZES)
    assert res["worst_psnr_change_db"] < 0.1, res["rows"]
    assert res["worst_mean_change"] < 5e-4, res["rows"]
