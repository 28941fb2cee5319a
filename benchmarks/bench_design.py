"""Benchmark the offline FPN design: one design, and the whole Fig. 5 family.

Targets: one design <= 10 ms median for N <= 60; 13 orders x 50 values of rho in < 5 s (2 cores).
For scale, ``scipy.signal.remez`` (constant specs only, compiled C) designs a filter of the same
length in the same run; the ratio is reported.

    python benchmarks/bench_design.py
"""

from __future__ import annotations

import math
import time

import numpy as np
import scipy.signal

from tof_fpn_torch.design import design_fpn


def median_ms(fn, repeats: int = 15) -> float:
    fn()
    times = []
    for _ in range(repeats):
        t = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t)
    return 1e3 * float(np.median(times))


def main() -> None:
    print("order  rho    design [ms]  scipy.remez [ms]  ratio")
    worst = 0.0
    for order, rho in (
        (5, 0.1),
        (20, 0.14),
        (41, 0.1),
        (53, 0.12),
        (60, 0.02),
        (60, 0.1),
        (60, 1 / 6),
    ):
        ours = median_ms(lambda o=order, r=rho: design_fpn(o, r))
        edges = [0, (2 / 3 - 0.1) / 2, (2 / 3 + 0.1) / 2, 0.5]
        ref = median_ms(lambda o=order, e=edges: scipy.signal.remez(o + 1, e, [1, 0], fs=1.0))
        worst = max(worst, ours)
        print(f"{order:5d}  {rho:.3f}  {ours:10.2f}  {ref:15.2f}  {ours / ref:6.1f}")
    print(f"worst median single design above: {worst:.2f} ms (target <= 10 ms)")

    rhos = np.linspace(1 / 300, 1 / 6, 50)
    orders = (5, 9, 17, 21, 31, 41, 53, 8, 12, 20, 28, 40, 52)
    t = time.perf_counter()
    singles = []
    for n in orders:
        for rho in rhos:
            t1 = time.perf_counter()
            design_fpn(n, float(rho))
            singles.append(time.perf_counter() - t1)
    total = time.perf_counter() - t
    singles_ms = 1e3 * np.array(singles)
    print(f"Fig. 5 family ({len(orders)} orders x {rhos.size} rho): {total:.2f} s (target < 5 s)")
    print(
        f"single design over that family: median {np.median(singles_ms):.2f} ms, "
        f"95th percentile {np.percentile(singles_ms, 95):.2f} ms, max {singles_ms.max():.2f} ms"
    )
    assert math.isfinite(total)


if __name__ == "__main__":
    main()
