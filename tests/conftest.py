"""Shared fixtures: the real ToF captures (``tests/data/real``, README there: files, licences).

The captures are part of the test data, not an optional extra: when they are missing the tests
that need them FAIL with a message saying where they were looked for (never skip), so a broken
checkout cannot pass as green. Test modules take the folder and the check from here
(``from conftest import REAL_DATA_DIR, real_capture``); the benchmarks and examples, which do not
import the tests, name the same folder in ``benchmarks/real_captures.py``.
"""

from __future__ import annotations

import shutil
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest
import torch
from hypothesis import settings

# property tests are seeded: the same examples on every run (no example database)
settings.register_profile("seeded", derandomize=True, database=None)
settings.load_profile("seeded")

#: the repository root is the parent of tests/; the real captures are in the repository
REPO_ROOT = Path(__file__).resolve().parents[1]
REAL_DATA_DIR = REPO_ROOT / "tests" / "data" / "real"

ADI_SIZE = 512
ADI_FILES = (
    "adi_adtf3175/wall_depth_u16le_512x512.bin",
    "adi_adtf3175/wall_ir_u16le_512x512.bin",
    "adi_adtf3175/office_mode3_interleaved_512x512.bin",
)


def real_capture(rel: str) -> Path:
    """``REAL_DATA_DIR / rel``; fails the calling test (never skips) when it does not exist."""
    path = REAL_DATA_DIR / rel
    if not path.exists():
        pytest.fail(f"real capture missing: {path} (tests/data/real in the repository)")
    return path


#: the three camera file formats of the real captures (ADI pair and interleaved file, Azure
#: Kinect .mkv) with the Kinect v2 P0 table (not a frame) and the README beside them, as a user
#: hands a folder over; the ESPROS HDF5 files (no depth image) are left out
CAMERA_FILES = (
    *ADI_FILES,
    "azure_kinect/desk_recording.mkv",
    "kinect_v2_p0/p0tables_3x424x512_u16le.dat",
    "README.md",
)


def handed_over(dst: Path, rels=CAMERA_FILES) -> Path:
    """Copies of the real captures ``rels`` under ``dst``, in their folders; returns ``dst``."""
    for rel in rels:
        (dst / rel).parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(real_capture(rel), dst / rel)
    return dst


@dataclass(frozen=True)
class RealData:
    """Loaders of the real captures (formats: ``REAL_DATA_DIR / "README.md"``)."""

    root: Path

    def _u16(self, rel: str, count: int) -> np.ndarray:
        raw = np.fromfile(self.root / rel, dtype="<u2")
        if raw.size != count:
            pytest.fail(f"{self.root / rel}: expected {count} uint16 values, found {raw.size}")
        return raw

    def adi_wall(self) -> tuple[torch.Tensor, torch.Tensor]:
        """ADTF3175 wall frame: (depth mm, IR) as float32 (1, 1, 512, 512); depth 0 = invalid."""
        n = ADI_SIZE * ADI_SIZE
        depth = self._u16(ADI_FILES[0], n).astype(np.float32).reshape(1, 1, ADI_SIZE, ADI_SIZE)
        ir = self._u16(ADI_FILES[1], n).astype(np.float32).reshape(1, 1, ADI_SIZE, ADI_SIZE)
        return torch.from_numpy(depth), torch.from_numpy(ir)

    def adi_office(self) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """ADTF3175 office frame: (depth mm, confidence, active brightness) as float32
        (1, 1, 512, 512), decoded from 5 interleaved bytes per pixel (depth u16 LE, confidence
        u8, AB u16 LE)."""
        raw = np.fromfile(self.root / ADI_FILES[2], dtype=np.uint8)
        if raw.size != ADI_SIZE * ADI_SIZE * 5:
            pytest.fail(f"{self.root / ADI_FILES[2]}: expected {ADI_SIZE**2 * 5} bytes")
        px = raw.reshape(ADI_SIZE, ADI_SIZE, 5)
        depth = px[..., 0].astype(np.uint16) | (px[..., 1].astype(np.uint16) << 8)
        ab = px[..., 3].astype(np.uint16) | (px[..., 4].astype(np.uint16) << 8)

        def t(a):
            return torch.from_numpy(a.astype(np.float32).reshape(1, 1, ADI_SIZE, ADI_SIZE))

        return t(depth), t(px[..., 2]), t(ab)


@pytest.fixture(scope="session")
def real_data() -> RealData:
    """The real captures; fails (does not skip) when the folder or a file is missing."""
    if not REAL_DATA_DIR.is_dir():
        pytest.fail(
            f"real ToF captures not found: expected the folder {REAL_DATA_DIR} "
            "(tests/data/real in the repository); the real-data tests need it"
        )
    missing = [f for f in ADI_FILES if not (REAL_DATA_DIR / f).is_file()]
    if missing:
        pytest.fail(f"real ToF captures incomplete in {REAL_DATA_DIR}: missing {missing}")
    return RealData(REAL_DATA_DIR)
