"""FPNFilter with invalid pixels: its own hole-free time, OpenCV, and a two-filter2D normalised
convolution, side by side in one run.

For each filter order, on depth-like float32 frames (a slanted curved surface, 1 cm noise, 5 mm
column stripes, as in ``bench_fpn_filter.py``) with 0 %, 1 % and 10 % of the pixels invalid at
random (seeded), marked as 0 and, the same pixels, as NaN (how ROS ``32FC1``, Open3D and float
pipelines mark them):

- ``ours_<p>%`` (0 holes), ``ours_nan_<p>%`` (NaN holes): ``FPNFilter(x)`` as a user calls it
  (checks, validity, filter, write-back);
- ``cv2``: ``cv2.filter2D`` with the same taps as a 1 x L kernel, ``BORDER_REFLECT_101`` (our
  ``reflect``), on the hole-free frames;
- ``cv2_nc_<p>%``: a normalised convolution from two ``cv2.filter2D`` calls per frame on the holed
  frames (0 holes): the zero-filled frame and the validity mask are filtered, then divided.

Every round times every method once, in the same order; the ratios are medians of per-round ratios
(a load spike from other processes hits both sides of a ratio), the times medians and minima.
Threads: torch and OpenCV both get ``--threads``.

Usage::

    python benchmarks/bench_fpn_holes.py --json docs/figures/fpn_holes_bench.json
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import time
from pathlib import Path

import cv2
import numpy as np
import torch

from tof_fpn_torch.build import filter_from_design

FRACTIONS = (0.0, 0.01, 0.1)


def frames(batch: int, height: int, width: int, seed: int) -> torch.Tensor:
    gen = torch.Generator().manual_seed(seed)
    yy = torch.linspace(0.0, 1.0, height).view(1, 1, -1, 1)
    xx = torch.linspace(0.0, 1.0, width).view(1, 1, 1, -1)
    phase = 6.0 * torch.rand(batch, 1, 1, 1, generator=gen)
    cols = torch.arange(width).view(1, 1, 1, -1)
    x = 2.0 + 0.8 * yy + 0.3 * torch.sin(5.0 * xx + phase) + 0.005 * torch.cos(torch.pi * cols)
    x = x + 0.01 * torch.randn((batch, 1, height, width), generator=gen)
    return x.contiguous()


def with_holes(x: torch.Tensor, fraction: float, seed: int, code: float = 0.0) -> torch.Tensor:
    out = x.clone()
    n = int(round(fraction * x.numel()))
    gen = torch.Generator().manual_seed(seed)
    out.view(-1)[torch.randperm(x.numel(), generator=gen)[:n]] = code
    return out


def bench_order(args, order: int, rho: float) -> dict:
    f = filter_from_design(order, rho, compensate_delay=False, allow_shift=True)
    taps = f.taps.numpy()
    length = taps.size
    kernel = taps[::-1].astype(np.float32).reshape(1, -1).copy()
    anchor = (length - 1 - length // 2, 0)  # cv2 correlates: convolve1d's centring

    def filt2d(a: np.ndarray) -> np.ndarray:
        return cv2.filter2D(a, -1, kernel, anchor=anchor, borderType=cv2.BORDER_REFLECT_101)

    x = frames(args.batch, args.height, args.width, args.seed)
    inputs = {f"{p:.0%}": with_holes(x, p, args.seed + 1) for p in FRACTIONS}
    for p in FRACTIONS[1:]:
        inputs[f"nan_{p:.0%}"] = with_holes(x, p, args.seed + 1, float("nan"))
    methods = {}
    for name, xp in inputs.items():

        def ours(xp=xp):
            with torch.inference_mode():
                return f(xp)

        methods[f"ours_{name}"] = ours
    xn = x.numpy()
    methods["cv2"] = lambda: [filt2d(xn[i, 0]) for i in range(args.batch)]
    for p in FRACTIONS[1:]:
        hn = inputs[f"{p:.0%}"].numpy()

        def normalised(hn=hn):
            out = []
            for i in range(args.batch):
                frame = hn[i, 0]
                valid = (frame > 0).astype(np.float32)
                with np.errstate(divide="ignore", invalid="ignore"):
                    out.append(filt2d(frame * valid) / filt2d(valid))
            return out

        methods[f"cv2_nc_{p:.0%}"] = normalised

    # correctness on the hole-free frames: the same numbers as OpenCV; NaN and 0 holes: the same
    err = float(np.abs(methods["ours_0%"]().numpy()[:, 0] - np.stack(methods["cv2"]())).max())
    for p in FRACTIONS[1:]:
        a, b = methods[f"ours_{p:.0%}"](), methods[f"ours_nan_{p:.0%}"]()
        same = torch.equal(a, torch.where(torch.isnan(b), torch.zeros_like(b), b))
        if not same:
            raise RuntimeError(f"NaN and 0 holes ({p:.0%}) gave different outputs")
    times: dict[str, list[float]] = {k: [] for k in methods}
    for fn in methods.values():  # warm-up
        fn()
    for _ in range(args.repeats):
        for name, fn in methods.items():
            t0 = time.perf_counter()
            fn()
            times[name].append(time.perf_counter() - t0)

    def ratio(a: str, b: str) -> float:
        """median over rounds of time(b) / time(a): how many times faster a is than b"""
        return statistics.median(tb / ta for ta, tb in zip(times[a], times[b], strict=True))

    holes = [f"{p:.0%}" for p in FRACTIONS[1:]]
    return {
        "order": order,
        "rho": rho,
        "taps": length,
        "median_ms": {k: 1e3 * statistics.median(v) for k, v in times.items()},
        "min_ms": {k: 1e3 * min(v) for k, v in times.items()},
        "hole_free_x_faster_than_cv2": ratio("ours_0%", "cv2"),
        "own_time_with_holes_x_hole_free": {h: ratio("ours_0%", f"ours_{h}") for h in holes},
        "own_time_with_nan_holes_x_hole_free": {
            h: ratio("ours_0%", f"ours_nan_{h}") for h in holes
        },
        "x_faster_than_cv2_normalised_convolution": {
            h: ratio(f"ours_{h}", f"cv2_nc_{h}") for h in holes
        },
        "max_abs_diff_hole_free_vs_cv2": err,
    }


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    p.add_argument("--batch", type=int, default=32)
    p.add_argument("--height", type=int, default=424)
    p.add_argument("--width", type=int, default=512)
    p.add_argument("--orders", type=int, nargs="+", default=[41, 20])
    p.add_argument("--threads", type=int, default=2)
    p.add_argument("--repeats", type=int, default=21)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--json", type=Path, help="write the results here")
    args = p.parse_args()
    torch.set_num_threads(args.threads)
    cv2.setNumThreads(args.threads)
    rho = {41: 0.12, 20: 0.14}
    load = os.getloadavg()[0]
    results = [bench_order(args, order, rho.get(order, 0.12)) for order in args.orders]
    out = {
        "command": "python " + " ".join(sys.argv),
        "config": {
            **{k: v for k, v in vars(args).items() if k != "json"},
            "dtype": "float32",
            "OMP_NUM_THREADS": os.environ.get("OMP_NUM_THREADS"),
            "torch": torch.__version__,
            "cv2": cv2.__version__,
        },
        "results": results,
        "loadavg_1min_before_after": [load, os.getloadavg()[0]],
    }
    shape = (args.batch, 1, args.height, args.width)
    print(f"input {shape} float32, {args.threads} threads, {args.repeats} rounds")
    for r in results:
        print(f"order {r['order']} ({r['taps']} taps)")
        for k in r["median_ms"]:
            print(f"  {k:<14}{r['median_ms'][k]:>9.2f} ms median {r['min_ms'][k]:>9.2f} ms min")
        print(f"  hole-free: {r['hole_free_x_faster_than_cv2']:.2f}x faster than cv2.filter2D")
        for h, v in r["own_time_with_holes_x_hole_free"].items():
            nc = r["x_faster_than_cv2_normalised_convolution"][h]
            vn = r["own_time_with_nan_holes_x_hole_free"][h]
            print(
                f"  {h} invalid: {v:.2f}x (0) / {vn:.2f}x (NaN) its hole-free time, "
                f"{nc:.2f}x faster than cv2 NC"
            )
        print(f"  max |ours - cv2| hole-free: {r['max_abs_diff_hole_free_vs_cv2']:.2e}")
    print("1-min load average before/after:", out["loadavg_1min_before_after"])
    if args.json:
        args.json.write_text(json.dumps(out, indent=2) + "\n")


if __name__ == "__main__":
    main()
