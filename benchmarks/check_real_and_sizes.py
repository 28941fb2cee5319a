"""Never hurts, spot check: the default stage (and ``from_data``) on the real ADI captures and on
tiny (5x7, 9x13), odd (191x255) and large (1024x1280) striped and stripe-free frames (docs/runtime.md).

    python benchmarks/check_real_and_sizes.py
"""

import math

import torch
from real_captures import REAL_DATA_DIR

from tof_fpn_torch.analysis.metrics import psnr
from tof_fpn_torch.build import suppression_from_data, suppression_from_design
from tof_fpn_torch.io import read_adi_depth_ir, read_adi_interleaved
from tof_fpn_torch.runtime import valid_mask
from tof_fpn_torch.sim import add_depth_noise, planar_scene, synthetic_scene

#: the real ADI captures (tests/data/real in the repository)
REAL = REAL_DATA_DIR / "adi_adtf3175"


def report(name, d, a, stages):
    v = valid_mask(d, a)
    for sn, st in stages:
        y = st(d, a)
        vy = valid_mask(y, a)
        inv_kept = torch.equal(y[~v], d[~v]) if (~v).any() else True
        print(
            f"{name:28s} {sn:9s} unchanged={torch.equal(y, d)!s:5s} invalid kept={inv_kept} valid lost={int((v & ~vy).sum())} "
            f"mean shift={float((y[v] - d[v]).mean()):+.3g} rms change={float((y[v] - d[v]).pow(2).mean().sqrt()):.3g}"
        )


# metres with 0 for invalid pixels, as the camera stores them (NaN would make torch.equal fail)
dw, ir = read_adi_depth_ir(
    REAL / "wall_depth_u16le_512x512.bin", REAL / "wall_ir_u16le_512x512.bin"
)
dw = torch.nan_to_num(dw, nan=0.0)
do, conf, ab = read_adi_interleaved(REAL / "office_mode3_interleaved_512x512.bin")
do = torch.nan_to_num(do, nan=0.0)
cam = [("default", suppression_from_design(camera="adtf3175"))]
report("ADI wall (m)", dw, ir, cam + [("from_data", suppression_from_data(dw, ir))])
report("ADI office (m)", do, ab, cam + [("from_data", suppression_from_data(do, ab))])
st = suppression_from_design()
for h, w in ((5, 7), (9, 13)):
    yy, xx = torch.meshgrid(torch.arange(h * 1.0), torch.arange(w * 1.0), indexing="ij")
    gt = (2.0 + 0.05 * xx + 0.02 * yy).view(1, 1, h, w)
    amp = torch.full_like(gt, 40.0)
    g = torch.Generator().manual_seed(1)
    for k, s in ((0.3, 0.0), (1.0, 0.1)):
        x = gt + k / 40 * torch.randn(gt.shape, generator=g) + s * torch.cos(math.pi * xx)
        y = st(x, amp)
        print(
            f"{h}x{w} ramp k={k} stripe={s}: PSNR {float(psnr(x, gt)):.2f} -> {float(psnr(y, gt)):.2f}"
        )
for h, w in ((191, 255), (1024, 1280)):
    for maker in (synthetic_scene, planar_scene):
        sc = maker(h, w, seed=3)
        gt, amp = sc.depth, sc.amplitude
        g = torch.Generator().manual_seed(1)
        for k, s in ((0.3, 0.0), (0.3, 0.03), (1.0, 0.1)):
            x = add_depth_noise(gt, amp, k * k, amplitude_floor=5.0, generator=g)
            n = torch.arange(w, dtype=torch.float32)
            x = x + s * torch.cos(math.pi * n) + 2 / 3 * s * torch.cos(2 * math.pi / 3 * n + 0.7)
            y = st(x, amp)
            print(
                f"{h}x{w} {maker.__name__[:5]} k={k} stripe={s}: PSNR {float(psnr(x, gt)):.2f} -> {float(psnr(y, gt)):.2f}"
            )
