"""Never hurts: the default stage and ``suppression_from_data`` on stripe-free scenes of many sizes.

Usage::

    python benchmarks/bench_never_hurts.py                 # 2 scene kinds x 13 sizes x 3 noise levels
    python benchmarks/bench_never_hurts.py --quick         # fewer sizes (what tests/ runs)
    python benchmarks/bench_never_hurts.py --striped       # striped frames: gated vs ungated stage
    python benchmarks/bench_never_hurts.py --striped --large   # the same on 1024 x 1280

Scenes: ``synthetic_scene`` (Fig. 7-like: edges, thin bars, a Siemens star, a grating) and
``planar_scene`` (Sec. IV-A boards), heights and widths from 32 to 640, odd and even, with eq. (2)
noise ``sigma_D = k / A`` at three levels (and one noise-free). No stripes. For each frame: the
PSNR change (eq. 9) of the output against the input, both against the ground truth, and the
relative change of the mean valid depth. Must stay under 0.1 dB and 0.05 %.
"""

from __future__ import annotations

import argparse
import itertools
import json
import time
from pathlib import Path

import torch

from tof_fpn_torch.analysis.metrics import psnr
from tof_fpn_torch.build import suppression_from_data, suppression_from_design
from tof_fpn_torch.sim import add_depth_noise, planar_scene, synthetic_scene

SIZES = [
    (32, 32),
    (33, 47),
    (48, 64),
    (63, 63),
    (64, 127),
    (128, 96),
    (160, 255),
    (204, 204),
    (255, 320),
    (320, 240),
    (424, 512),
    (511, 385),
    (480, 640),
]
QUICK_SIZES = [(32, 32), (33, 47), (63, 63), (204, 204), (255, 320)]
NOISE = (0.0, 0.3, 1.0, 3.0)  # k of sigma_D = k / A, metres x amplitude


def run(sizes, noise=NOISE) -> dict:
    stage = suppression_from_design()
    rows = []
    for h, w in sizes:
        for maker in (synthetic_scene, planar_scene):
            sc = maker(h, w, seed=h + w)
            gt, amp = sc.depth, sc.amplitude
            for k in noise:
                g = torch.Generator().manual_seed(h * w)
                x = add_depth_noise(gt, amp, k * k, amplitude_floor=5.0, generator=g) if k else gt
                for name, module in (("default", stage), ("from_data", None)):
                    if module is None:
                        module = suppression_from_data(x, amp)
                    y = module(x, amp)
                    p_in = float(psnr(x, gt)) if k else float("inf")
                    p_out = float(psnr(y, gt)) if k else float("inf")
                    change = 0.0 if torch.equal(x, y) else p_out - p_in
                    mean = float(
                        ((y.double().mean() - x.double().mean()) / x.double().mean()).abs()
                    )
                    rows.append(
                        {
                            "size": [h, w],
                            "scene": maker.__name__,
                            "k": k,
                            "stage": name,
                            "psnr_change_db": change,
                            "mean_change": mean,
                            "unchanged": bool(torch.equal(x, y)),
                        }
                    )
    worst_db = max(abs(r["psnr_change_db"]) for r in rows)
    worst_mean = max(r["mean_change"] for r in rows)
    return {
        "frames": len(rows),
        "worst_psnr_change_db": worst_db,
        "worst_mean_change": worst_mean,
        "unchanged_share": sum(r["unchanged"] for r in rows) / len(rows),
        "rows": rows,
    }


STRIPED_SIZES = [(191, 255), (64, 127), (204, 204), (33, 511)]
STRIPES = (0.0, 0.01, 0.03, 0.1)  # amplitude (m) at pi; 2/3 of it at 2 pi / 3


def run_striped(sizes=STRIPED_SIZES) -> dict:
    """Frames with column stripes at pi and 2 pi / 3 (0 to 10 cm) on the two scene kinds, four
    sizes, four noise levels: the PSNR change of the default (gated) stage and of the paper's
    ungated one. The gated stage must not lose where the notch costs more than it gains."""
    import math

    gated, ungated = suppression_from_design(), suppression_from_design(gate=False)
    rows = []
    for (h, w), maker, k, a in itertools.product(
        sizes, (synthetic_scene, planar_scene), (0.1, 0.3, 1.0, 3.0), STRIPES
    ):
        sc = maker(h, w, seed=h + w)
        gt, amp = sc.depth, sc.amplitude
        g = torch.Generator().manual_seed(h * w)
        x = add_depth_noise(gt, amp, k * k, amplitude_floor=5.0, generator=g)
        n = torch.arange(w, dtype=torch.float32)
        x = x + a * torch.cos(math.pi * n) + (2 / 3) * a * torch.cos(2 * math.pi / 3 * n + 0.7)
        p0 = float(psnr(x, gt))
        rows.append(
            {
                "size": [h, w],
                "scene": maker.__name__,
                "k": k,
                "stripe": a,
                "gated_db": float(psnr(gated(x, amp), gt)) - p0,
                "ungated_db": float(psnr(ungated(x, amp), gt)) - p0,
            }
        )
    return {"frames": len(rows), "rows": rows}


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--quick", action="store_true", help="5 sizes")
    p.add_argument("--striped", action="store_true", help="striped frames, gated vs ungated")
    p.add_argument("--large", action="store_true", help="with --striped: 1024 x 1280 only")
    p.add_argument("--json", type=Path)
    args = p.parse_args()
    t0 = time.perf_counter()
    if args.striped:
        res = run_striped([(1024, 1280)] if args.large else STRIPED_SIZES)
        for key in ("gated_db", "ungated_db"):
            v = [r[key] for r in res["rows"]]
            hurt = [r for r in res["rows"] if r[key] < -0.01]
            print(
                f"{key[:-3]:8s}: {res['frames']} striped frames, worst {min(v):+.2f} dB, "
                f"{len(hurt)} lose > 0.01 dB, {sum(x > 0.05 for x in v)} gain > 0.05 dB, "
                f"mean {sum(v) / len(v):+.2f} dB"
            )
            for r in hurt if key == "gated_db" else []:
                print(f"   loses: {r}")
        print(f"({time.perf_counter() - t0:.0f} s)")
        if args.json:
            args.json.write_text(json.dumps(res, indent=1))
        return
    res = run(QUICK_SIZES if args.quick else SIZES)
    print(
        f"{res['frames']} stripe-free frames (sizes {'quick' if args.quick else 'all'}): "
        f"worst |PSNR change| {res['worst_psnr_change_db']:.3g} dB, worst mean-depth change "
        f"{100 * res['worst_mean_change']:.3g} %, returned bit for bit "
        f"{100 * res['unchanged_share']:.1f} % ({time.perf_counter() - t0:.0f} s)"
    )
    if args.json:
        args.json.write_text(json.dumps(res, indent=1))


if __name__ == "__main__":
    main()
