"""Throughput of FPNFilter against OpenCV, SciPy and a plain memory copy, side by side in one run.

``ours`` is the module as a user calls it: argument checks and the validity check (one integer
min/max over the input) included. ``ours_kernel`` is the bare FIR kernel, ``ours_1%_holes`` the
module on the same frames with 1 % invalid pixels (mask, two FIRs, write-back; see
``bench_fpn_holes.py``).

Usage::

    python benchmarks/bench_fpn_filter.py                 # batch 32 x 424 x 512 float32, order 41, 2 threads
    python benchmarks/bench_fpn_filter.py --repeats 31 --json out.json

Every round times each method once, in the same order; the figures are medians (and minima) over
rounds, and the ratios are medians of the per-round ratios (so a load spike from other processes on the
machine hits both sides of a ratio). All methods allocate their output, as a user's call would.
The peak extra memory of one FPNFilter call is read from the kernel's peak-RSS counter
(``/proc/self/clear_refs`` reset), in units of the input size, output included, for the first
call (which includes oneDNN's one-time set-up) and the second.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import time
from pathlib import Path

import cv2
import numpy as np
import scipy.ndimage as ndi
import torch
import torch.nn.functional as F

from tof_fpn_torch.build import filter_from_design
from tof_fpn_torch.runtime.fir import fir_last


def _vm_kib(field: str) -> int:
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith(field + ":"):
            return int(line.split()[1])
    raise RuntimeError(f"{field} not in /proc/self/status")


def peak_extra_memory(fn, nbytes: int) -> float | None:
    """Peak RSS growth during ``fn()`` over ``nbytes`` (None where the kernel lacks the counter)."""
    try:
        Path("/proc/self/clear_refs").write_text("5")
    except OSError:
        return None
    before = _vm_kib("VmRSS")
    out = fn()
    peak = _vm_kib("VmHWM")
    del out
    return (peak - before) * 1024 / nbytes


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    p.add_argument("--batch", type=int, default=32)
    p.add_argument("--height", type=int, default=424)
    p.add_argument("--width", type=int, default=512)
    p.add_argument("--order", type=int, default=41)
    p.add_argument("--rho", type=float, default=0.12)
    p.add_argument("--threads", type=int, default=2)
    p.add_argument("--repeats", type=int, default=21)
    p.add_argument("--skip-slow", action="store_true", help="skip SciPy and F.conv1d")
    p.add_argument("--json", type=Path, help="write the results here")
    args = p.parse_args()

    torch.set_num_threads(args.threads)
    cv2.setNumThreads(args.threads)
    gen = torch.Generator().manual_seed(0)
    shape = (args.batch, 1, args.height, args.width)
    # depth-like frames in metres (no NaN/0): a slanted, curved surface, 1 cm noise, 5 mm stripes.
    # (Uniform random values would not be depth: their filtered output rings below 0, which the
    # module treats as invalid and answers with the input.)
    yy = torch.linspace(0.0, 1.0, args.height).view(1, 1, -1, 1)
    xx = torch.linspace(0.0, 1.0, args.width).view(1, 1, 1, -1)
    phase = 6.0 * torch.rand(args.batch, 1, 1, 1, generator=gen)
    cols = torch.arange(args.width).view(1, 1, 1, -1)
    x = 2.0 + 0.8 * yy + 0.3 * torch.sin(5.0 * xx + phase) + 0.005 * torch.cos(torch.pi * cols)
    x = (x + 0.01 * torch.randn(shape, generator=gen)).contiguous()
    xn = x.numpy()
    nbytes = x.numel() * x.element_size()

    f = filter_from_design(args.order, args.rho, compensate_delay=False, allow_shift=True)
    ops = [f._taps_op0, f._taps_op1, f._taps_op2, f._taps_op3]
    holes = x.clone()  # a real capture's case: 1 % invalid pixels take the hole path
    holes.view(-1)[torch.randperm(holes.numel(), generator=gen)[: holes.numel() // 100]] = 0.0
    taps = f.taps.numpy()
    length = taps.size
    kernel = taps[::-1].astype(np.float32).reshape(1, -1).copy()
    anchor = (length - 1 - length // 2, 0)  # cv2 correlates: this matches convolve1d's centring
    w1 = torch.from_numpy(taps[::-1].copy()).float().view(1, 1, -1)

    def ours():
        with torch.inference_mode():
            return f(x)

    def ours_kernel():  # the bare FIR kernel: no argument checks, no validity handling
        with torch.inference_mode():
            return fir_last(x, f.taps, "reflect", ops, True)

    def ours_holes():  # 1 % invalid pixels: validity mask, two FIRs, write-back
        with torch.inference_mode():
            return f(holes)

    def ours_export_path():  # the out-of-place kernel used with autograd and for export
        with torch.inference_mode():
            return fir_last(x, f.taps, "reflect", ops, False)

    def opencv():
        return [
            cv2.filter2D(xn[i, 0], -1, kernel, anchor=anchor, borderType=cv2.BORDER_REFLECT_101)
            for i in range(args.batch)
        ]

    def scipy_():
        return ndi.convolve1d(xn, taps.astype(np.float32), axis=-1, mode="mirror")

    def conv1d():
        with torch.inference_mode():
            xp = F.pad(
                x.view(-1, 1, args.width),
                (length // 2 - (length + 1) % 2, length // 2),
                mode="reflect",
            )
            return F.conv1d(xp, w1)

    def copy():
        return x.clone()

    methods = {
        "ours": ours,
        "ours_kernel": ours_kernel,
        "ours_1%_holes": ours_holes,
        "ours_export_path": ours_export_path,
        "cv2.filter2D": opencv,
        "copy": copy,
    }
    if not args.skip_slow:
        methods["scipy.convolve1d"] = scipy_
        methods["F.conv1d"] = conv1d

    # memory first, while the allocator holds no freed blocks it could reuse
    peak_memory = peak_extra_memory(ours, nbytes)  # includes oneDNN's one-time set-up
    peak_memory_warm = peak_extra_memory(ours, nbytes)  # a later call
    # correctness: same numbers as OpenCV and SciPy
    y = ours().numpy()
    err_cv2 = float(np.abs(y - np.stack(opencv())[:, None]).max())
    err_scipy = float(
        np.abs(y - ndi.convolve1d(xn.astype(np.float64), taps, axis=-1, mode="mirror")).max()
    )
    err_conv1d = float(np.abs(y - conv1d().view(shape).numpy()).max())

    load_before = os.getloadavg()[0]
    times: dict[str, list[float]] = {k: [] for k in methods}
    for fn in methods.values():  # warm-up
        fn()
    for _ in range(args.repeats):
        for name, fn in methods.items():
            t0 = time.perf_counter()
            fn()
            times[name].append(time.perf_counter() - t0)

    def ratio(a: str, b: str) -> float:
        return statistics.median(tb / ta for ta, tb in zip(times[a], times[b], strict=True))

    frames = args.batch
    result = {
        "config": {
            **{k: v for k, v in vars(args).items() if k != "json"},
            "taps": length,
            "input_MB": nbytes / 2**20,
            "torch": torch.__version__,
            "cv2": cv2.__version__,
        },
        "median_ms": {k: 1e3 * statistics.median(v) for k, v in times.items()},
        "min_ms": {k: 1e3 * min(v) for k, v in times.items()},
        "frames_per_s": {k: frames / statistics.median(v) for k, v in times.items()},
        "speedup_vs": {k: ratio("ours", k) for k in methods if k != "ours"},
        "max_abs_diff": {
            "cv2.filter2D": err_cv2,
            "scipy_float64": err_scipy,
            "F.conv1d": err_conv1d,
        },
        "peak_extra_memory_x_input": peak_memory,
        "peak_extra_memory_x_input_second_call": peak_memory_warm,
        "loadavg_1min_before_after": [load_before, os.getloadavg()[0]],
    }
    print(
        f"input {shape} float32 ({nbytes / 2**20:.1f} MiB), {length} taps, {args.threads} threads, "
        f"{args.repeats} rounds"
    )
    print(f"{'method':<20}{'median ms':>12}{'min ms':>10}{'frames/s':>12}{'ours is x faster':>18}")
    for k in methods:
        sp = "" if k == "ours" else f"{result['speedup_vs'][k]:.2f}"
        print(
            f"{k:<20}{result['median_ms'][k]:>12.2f}{result['min_ms'][k]:>10.2f}"
            f"{result['frames_per_s'][k]:>12.0f}{sp:>18}"
        )
    print("max |ours - ref|:", json.dumps(result["max_abs_diff"]))
    print(
        "peak extra memory (x input, output included): first call",
        result["peak_extra_memory_x_input"],
        "second call",
        result["peak_extra_memory_x_input_second_call"],
    )
    print("1-min load average before/after:", result["loadavg_1min_before_after"])
    if args.json:
        args.json.write_text(json.dumps(result, indent=2))


if __name__ == "__main__":
    main()
