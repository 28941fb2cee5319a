"""False detections and detection rate of ``estimate_stripes`` on scenes of random sizes.

Usage::

    python benchmarks/bench_detection.py                  # 200 + 200 scenes (about 2 minutes)
    python benchmarks/bench_detection.py --scenes 40 --json out.json

Stripe-free set: ``synthetic_scene`` / ``planar_scene`` of random heights and widths (32 to 640,
odd and even, not square), eq. (2) depth noise ``sigma_D = k / A`` with a random ``k``, and in half
of them broadband random column offsets (a real sensor's non-periodic fixed pattern, which must not
be reported as a periodic stripe). One frame each. A false detection is any reported component.

Striped set: the same scenes plus one periodic stripe ``a cos(w x + phase)`` of random
orientation, frequency ``w`` uniform in ``[0.2 pi, pi]`` (one in four exactly ``2pi/3`` or ``pi``)
and amplitude ``a = SNR x sigma``, ``sigma`` the frame's median per-pixel noise. Detected
correctly: a component of the right orientation within half a DFT bin (``pi / n``) of ``w``.
"""

from __future__ import annotations

import argparse
import json
import math
import time
from pathlib import Path

import torch

from tof_fpn_torch.analysis import estimate_stripes
from tof_fpn_torch.sim import add_depth_noise, planar_scene, synthetic_scene


def _scene(rng: torch.Generator, i: int) -> tuple[torch.Tensor, torch.Tensor, float]:
    def draw(lo: int, hi: int) -> int:
        return int(torch.randint(lo, hi + 1, (1,), generator=rng))

    h, w = draw(32, 640), draw(32, 640)
    maker = synthetic_scene if i % 2 == 0 else planar_scene
    sc = maker(h, w, seed=i)
    k = 0.05 + 2.0 * float(torch.rand((), generator=rng))  # sigma_D = k / A, metres x amplitude
    g = torch.Generator().manual_seed(10_000 + i)
    amp = sc.amplitude.clamp_min(5.0)
    depth = add_depth_noise(sc.depth, amp, k * k, amplitude_floor=5.0, generator=g)
    if i % 4 in (1, 2):  # broadband column offsets, the size of the noise
        sigma = float((k / amp).median())
        depth = depth + sigma * torch.randn(1, 1, 1, w, generator=g)
    return depth, amp, float((k / amp).median())


def run(scenes: int, snr: float, seed: int) -> dict:
    rng = torch.Generator().manual_seed(seed)
    false, misses, details = 0, 0, []
    t0 = time.perf_counter()
    for i in range(scenes):
        depth, amp, sigma = _scene(rng, i)
        found = estimate_stripes(depth, amp).components
        false += bool(found)
        if found:
            details.append(
                {"scene": i, "shape": list(depth.shape), "found": [str(c) for c in found]}
            )
    for i in range(scenes):
        depth, amp, sigma = _scene(rng, scenes + i)
        cols = bool(torch.rand((), generator=rng) < 0.5)
        n = depth.shape[-1] if cols else depth.shape[-2]
        r = float(torch.rand((), generator=rng))
        w = (2 * math.pi / 3 if r < 0.125 else math.pi) if r < 0.25 else math.pi * (0.2 + 0.8 * r)
        x = torch.arange(n, dtype=depth.dtype)
        phase = 2 * math.pi * float(torch.rand((), generator=rng))
        stripe = snr * sigma * torch.cos(w * x + phase)
        depth = depth + (stripe.view(1, 1, 1, n) if cols else stripe.view(1, 1, n, 1))
        want = "columns" if cols else "rows"
        found = estimate_stripes(depth, amp).components
        ok = any(c.orientation == want and abs(c.frequency - w) <= math.pi / n for c in found)
        misses += not ok
        if not ok:
            details.append(
                {
                    "scene": scenes + i,
                    "shape": list(depth.shape),
                    "w": w,
                    "want": want,
                    "found": [str(c) for c in found],
                }
            )
    return {
        "scenes": scenes,
        "snr": snr,
        "false_detection_rate": false / scenes,
        "detection_rate": 1.0 - misses / scenes,
        "seconds": time.perf_counter() - t0,
        "failures": details,
    }


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--scenes", type=int, default=200, help="scenes per set (default 200)")
    p.add_argument("--snr", type=float, default=0.5, help="stripe amplitude / pixel noise")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--json", type=Path)
    args = p.parse_args()
    res = run(args.scenes, args.snr, args.seed)
    print(
        f"{res['scenes']} stripe-free scenes: false detections {100 * res['false_detection_rate']:.1f} %"
        f"; {res['scenes']} striped at amplitude {res['snr']} x noise: detected with the right "
        f"frequency and orientation {100 * res['detection_rate']:.1f} % ({res['seconds']:.0f} s)"
    )
    for f in res["failures"][:10]:
        print("  ", f)
    if args.json:
        args.json.write_text(json.dumps(res, indent=1))


if __name__ == "__main__":
    main()
