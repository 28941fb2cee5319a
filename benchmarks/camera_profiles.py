"""Fusion thresholds of the camera profiles, measured on the public captures (tof_fpn_torch.cameras).

Usage::

    python benchmarks/camera_profiles.py

Prints, for every capture with an amplitude channel in tests/data/real, the fitted noise law
``sigma_D = k / A`` and the thresholds :func:`tof_fpn_torch.build.fusion_from_noise` places at 4 %
and 0.8 % relative depth noise, and checks the rule on the paper's own synthetic data (it must give
about 70 and 350 there).
"""

from __future__ import annotations

import math

import numpy as np
import torch
from real_captures import REAL_DATA_DIR

from tof_fpn_torch import io as tio
from tof_fpn_torch.build import fusion_from_noise
from tof_fpn_torch.denoise import estimate_noise_k
from tof_fpn_torch.paper_data import make_synthetic_data
from tof_fpn_torch.runtime import valid_mask

REAL = REAL_DATA_DIR


def _report(name: str, depth: torch.Tensor, amp: torch.Tensor, unit: str) -> None:
    valid = valid_mask(depth, amp)
    k = float(estimate_noise_k(depth, amp, valid=valid).mean())
    fusion = fusion_from_noise(depth, amp)
    print(
        f"{name:28s} k = {k:9.3f} {unit} x amplitude, median depth {float(depth[valid].median()):8.3f}"
        f" {unit}: low {fusion.low:8.2f}, high {fusion.high:8.2f}"
    )


def main() -> None:
    data = make_synthetic_data((0, 1, 2), 204)
    noise_only = data.inputs["fpn+noise"] - data.inputs["fpn"] + data.depth  # eq. 2 noise alone
    _report("paper synthetic (Table I)", noise_only, data.amplitude, "m")
    print(f"  (lambda per seed {[round(math.sqrt(v), 2) for v in data.lam]} = k)")
    adi = REAL / "adi_adtf3175"
    d = np.fromfile(adi / "wall_depth_u16le_512x512.bin", "<u2").reshape(1, 1, 512, 512)
    a = np.fromfile(adi / "wall_ir_u16le_512x512.bin", "<u2").reshape(1, 1, 512, 512)
    _report(
        "ADTF3175 wall (depth, IR)",
        torch.from_numpy(d.astype(np.float64)),
        torch.from_numpy(a.astype(np.float64)),
        "mm",
    )
    raw = np.fromfile(adi / "office_mode3_interleaved_512x512.bin", np.uint8).reshape(-1, 5)
    dep = (raw[:, 0].astype(np.uint16) | (raw[:, 1].astype(np.uint16) << 8)).reshape(512, 512)
    ab = (raw[:, 3].astype(np.uint16) | (raw[:, 4].astype(np.uint16) << 8)).reshape(512, 512)
    _report(
        "ADTF3175 office (depth, AB)",
        torch.from_numpy(dep.astype(np.float64))[None, None],
        torch.from_numpy(ab.astype(np.float64))[None, None],
        "mm",
    )

    rec = tio.read_azure_kinect_mkv(REAL / "azure_kinect" / "desk_recording.mkv")
    depth, ir = rec.depth.double(), rec.amplitude.double()
    depth = torch.where(ir < 65535, depth, torch.nan)  # saturated IR: no measurement
    _report("Azure Kinect desk (depth, IR)", depth, ir, "m")


if __name__ == "__main__":
    main()
