"""Accuracy figures of the run-time FPN stage quoted in docs/runtime.md (no timing).

Usage::

    python benchmarks/bench_fpn_filter_figures.py [--onnx]

Prints: stripe suppression (dB) at 2pi/3 and pi away from the borders, measured vs designed
passband ripple, float32/float16/bfloat16 error against a float64 SciPy reference, and (with
``--onnx``) the TorchScript and ONNX Runtime agreement with eager.
"""

from __future__ import annotations

import argparse
import math
import tempfile
from pathlib import Path

import numpy as np
import scipy.ndimage as ndi
import torch

from tof_fpn_torch.build import filter_from_design, suppression_from_design


def scene(b: int, h: int, w: int) -> torch.Tensor:
    g = torch.Generator().manual_seed(0)
    yy, xx = torch.meshgrid(
        torch.linspace(0, 1, h, dtype=torch.float64),
        torch.linspace(0, 1, w, dtype=torch.float64),
        indexing="ij",
    )
    noise = 0.01 * torch.randn(b, 1, h, w, generator=g, dtype=torch.float64)
    return 2.0 + 0.8 * torch.sin(2.5 * xx) * torch.cos(1.7 * yy) + 0.3 * yy + noise


def main() -> None:
    p = argparse.ArgumentParser()
    p.add_argument("--onnx", action="store_true", help="also export and run ONNX (slow, ~15 s)")
    args = p.parse_args()
    torch.set_num_threads(2)
    h, w = 64, 384
    n = torch.arange(w, dtype=torch.float64)
    stripes = 0.05 * torch.cos(2 * math.pi / 3 * n + 0.4) + 0.03 * torch.cos(math.pi * n)
    base = scene(2, h, w)
    print("stripe energy after filtering, relative to before, interior columns:")
    for order, rho in ((20, 0.14), (41, 0.12)):
        f = filter_from_design(order, rho)
        m = f.taps.numel()
        for dtype in (torch.float64, torch.float32):
            with torch.inference_mode():
                res = (f((base + stripes).to(dtype)) - f(base.to(dtype))).double()[..., m:-m]
            db = 10 * math.log10(res.pow(2).mean() / stripes.pow(2).mean())
            print(f"  order {order:2d} rho {rho}: {str(dtype):14s} {db:8.1f} dB")
    print("passband ripple: probe sinusoids (25 per band) through FPNFilter vs design:")
    for order, rho in ((20, 0.14), (28, 0.13), (41, 0.12)):
        f = filter_from_design(order, rho)
        m = f.taps.numel()
        worst = 0.0
        for lo, hi in f.design.bands:
            for omega in np.linspace(lo, hi, 25):
                x = torch.cos(omega * n).expand(1, 1, 2, w).contiguous()
                y = f(x + 3.0) - 3.0 * float(f.taps.sum())
                gain = (y[0, 0, 0, m:-m] * torch.cos(omega * (n + f.delay))[m:-m]).sum() / (
                    torch.cos(omega * (n + f.delay))[m:-m].pow(2).sum()
                )
                worst = max(worst, abs(float(gain) - 1.0))
        print(
            f"  order {order} rho {rho}: measured {20 * math.log10(worst):6.2f} dB, "
            f"designed {f.design.ripple_db:6.2f} dB"
        )
    f = filter_from_design(41, 0.12)
    x64 = scene(4, 60, 256)
    ref = ndi.convolve1d(x64.numpy(), f.design.taps, axis=-1, mode="mirror")
    print("max |FPNFilter(x) - float64 SciPy reference| (depth ~1.5-3.5 m):")
    for dtype in (torch.float32, torch.float16, torch.bfloat16):
        with torch.inference_mode():
            y = f(x64.to(dtype)).double().numpy()
        print(f"  {str(dtype):15s} {np.abs(y - ref).max():.3g}  (eps {torch.finfo(dtype).eps:.3g})")
    if args.onnx:
        import onnxruntime as ort

        from tof_fpn_torch.export import export_onnx, export_torchscript

        mod = suppression_from_design(41, 0.12)
        d = 1.0 + torch.rand(2, 1, 64, 80)
        a = 400.0 * torch.rand(2, 1, 64, 80)
        d[0, 0, 3, 4] = float("nan")
        ref = mod(d, a).numpy()
        with tempfile.TemporaryDirectory() as tmp:
            ts = export_torchscript(mod, Path(tmp) / "m.pt")
            path = export_onnx(mod, Path(tmp) / "m.onnx", opset=17)
            sess = ort.InferenceSession(str(path))
            for shape in ((2, 1, 64, 80), (1, 1, 424, 512)):
                dd = 1.0 + torch.rand(shape)
                aa = 400.0 * torch.rand(shape)
                dd[0, 0, 3, 4] = float("nan")
                r = mod(dd, aa).numpy()
                (o,) = sess.run(None, {"depth": dd.numpy(), "amplitude": aa.numpy()})
                s = ts(dd, aa).numpy()
                print(
                    f"  {shape}: max |onnx - eager| {np.nanmax(np.abs(o - r)):.3g}, "
                    f"max |torchscript - eager| {np.nanmax(np.abs(s - r)):.3g}"
                )
        del ref


if __name__ == "__main__":
    main()
