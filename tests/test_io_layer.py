"""The file layer's place in the layers: importing it loads no simulator, no PyAV and no rosbags
(imported when a Matroska file or a bag is read); the package's lazy index reaches it."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import tof_fpn_torch

REPO = Path(__file__).resolve().parents[1]


def test_importing_io_loads_no_simulator_and_no_pyav():
    code = (
        "import sys, tof_fpn_torch.io; "
        "print([m for m in sys.modules if m.split('.')[0] in ('av', 'rosbags') "
        "or m.startswith(('tof_fpn_torch.sim', 'tof_fpn_torch.design', 'tof_fpn_torch.build'))])"
    )
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=True, cwd=REPO
    )
    assert out.stdout.strip() == "[]", out.stdout


def test_package_index_exports_the_io_names():
    from tof_fpn_torch import io

    assert tof_fpn_torch.io is io and "io" in tof_fpn_torch.__all__
    for name in ("Recording", "read_recording", "write_recording", "FrameDataset", "read_pair"):
        assert getattr(tof_fpn_torch, name) is getattr(io, name)
