"""``OUTPUT/report.png``: the most changed frame of all written files (named in the PNG's text
chunk), the change's colour scale at the change's own size, spectra without frequency 0, and the
panel of a learned fixed pattern."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from PIL import Image

from tof_fpn_torch import io as tio
from tof_fpn_torch.clean import CleanConfig, clean
from tof_fpn_torch.clean.figure import (
    _spectrum,
    difference_limit,
    most_changed,
    report_figure,
)
from tof_fpn_torch.clean.manifest import read_manifest
from tof_fpn_torch.clean.plan import Job

H, W = 96, 128


def _depth_mm(stripes_mm: float, seed: int) -> np.ndarray:
    """A sloped wall at 1.5 m with column stripes at pi of ``stripes_mm`` and 3 mm noise (mm)."""
    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[0:H, 0:W]
    return (
        1500.0
        + 1.0 * yy
        + 0.5 * xx
        + stripes_mm * np.cos(np.pi * xx)
        + 3.0 * rng.standard_normal((H, W))
    )


def _pair(folder, name: str, stripes_mm: float, seed: int) -> None:
    amp = np.random.default_rng(seed + 100).uniform(60, 250, (H, W))
    Image.fromarray(np.rint(_depth_mm(stripes_mm, seed)).astype(np.uint16)).save(
        folder / f"{name}_depth.png"
    )
    Image.fromarray(np.rint(amp).astype(np.uint16)).save(folder / f"{name}_amplitude.png")


def _info(path) -> dict:
    text = Image.open(path).text["Description"]
    return dict(item.split("=", 1) for item in text.split("; "))


@pytest.fixture(scope="module")
def cleaned(tmp_path_factory):
    """Two PNG pairs (stripes of 3 and 5 mm) and a 6-frame recording whose frame 4 has stripes
    of 12 mm (its others 2 mm), cleaned by the notch stage."""
    root = tmp_path_factory.mktemp("figure")
    src = root / "in"
    src.mkdir()
    _pair(src, "a", 3.0, 0)
    _pair(src, "z", 5.0, 1)
    frames = [_depth_mm(12.0 if i == 4 else 2.0, 10 + i) for i in range(6)]
    depth = torch.from_numpy(np.stack(frames) * 1e-3).float()[:, None]
    amp = torch.from_numpy(np.random.default_rng(7).uniform(60, 250, (6, 1, H, W))).float()
    meta = {"modulation_frequency_hz": None, "integration_time_us": None, "n_phases": None}
    tio.write_recording(src / "rec.npz", tio.Recording(depth, amp, meta))
    out = root / "out"
    rep = clean(str(src), str(out), CleanConfig(stage="paper"), workers=0, device="cpu")
    assert rep.status == 0 and rep.figure == str(out / "report.png")
    return out


def test_the_figure_shows_the_most_changed_frame_of_all_files(cleaned):
    records = read_manifest(str(cleaned / "manifest.jsonl"))
    recs = {r["file"]: r["report"] for r in records if "file" in r}
    # the record names each file's most changed frame: frame 4 of the recording
    assert recs["rec.npz"]["change_frame"] == {"set": "", "frame": 4}
    top = max(recs, key=lambda k: recs[k]["change_rms_mm"])
    assert top == "rec.npz"
    info = _info(cleaned / "report.png")
    assert (info["file"], info["set"], info["frame"]) == ("rec.npz", "", "4")
    assert float(info["change_rms_mm"]) == pytest.approx(recs["rec.npz"]["change_rms_mm"], 1e-3)
    # the change's colour scale is that of the removed stripes (12 mm), not of its extremes
    assert 6.0 < float(info["change_limit_mm"]) < 18.0


def test_the_ranking_follows_the_record_and_skips_what_was_not_done():
    jobs = [Job(n, n, None, "o/" + n, None) for n in ("a", "b", "c", "d", "e")]
    rep = {"change_rms_mm": None, "change_frame": None}
    records = [
        {"file": "a", "status": "done", "report": {"change_rms_mm": 0.5, "change_frame": {"set": "", "frame": 0}}},
        {"file": "b", "status": "done", "report": {"change_rms_mm": 2.0, "change_frame": {"set": "/g", "frame": 7}}},
        {"file": "c", "status": "failed", "error": "x"},
        {"file": "d", "status": "done", "report": rep},
        {"file": "e", "status": "done", "report": {"change_rms_mm": 9.0, "change_frame": {"set": "", "frame": 1}}},
        {"file": "e", "status": "failed", "error": "a later run failed"},
    ]  # fmt: skip
    ranked = [(j.name, key, i, rms) for j, key, i, rms in most_changed(jobs, records)]
    assert ranked == [("b", "/g", 7, 2.0), ("a", "", 0, 0.5), ("d", "", 0, None)]


def test_the_change_scale_follows_the_change_not_its_extremes():
    g = torch.Generator().manual_seed(0)
    for size in (1.0, 0.2, 30.0):
        change = size * torch.sign(torch.randn(200, 300, generator=g))  # +-size everywhere
        change[torch.rand(200, 300, generator=g) < 0.5] = 0.0  # half the pixels unchanged
        change[torch.rand(200, 300, generator=g) < 0.01] = 80.0 * size  # a few outliers
        change[0, :5] = float("nan")
        assert difference_limit(change) == pytest.approx(size, rel=1e-6)
    gauss = torch.randn(300, 300, generator=g)  # a 1 mm RMS change: about 2 mm at 95 %
    assert difference_limit(gauss) == pytest.approx(1.96, rel=0.05)
    sparse = torch.zeros(200, 300)
    sparse[torch.rand(200, 300, generator=g) < 0.03] = -2.0  # a few pixels changed by 2 mm
    assert difference_limit(sparse) == pytest.approx(2.0)
    assert difference_limit(torch.zeros(4, 4)) == 1e-3


def test_the_spectra_leave_out_frequency_zero():
    x = np.arange(64)
    freq, power = _spectrum(1000.0 + np.cos(np.pi * x))  # a large mean, a stripe at pi
    assert freq.size == 32 and freq.min() > 0 and freq[-1] == 1.0
    assert int(np.argmax(power)) == power.size - 1  # the stripe, not the mean
    profile = np.cos(2 * np.pi / 3 * x)
    profile[5] = np.nan  # a column without quiet pixels
    freq, power = _spectrum(profile)
    assert np.isfinite(power).all()
    assert freq[int(np.argmax(power))] == pytest.approx(2.0 / 3.0, abs=1.0 / 32)


def test_a_learned_pattern_is_one_more_panel(cleaned, tmp_path):
    jobs = [
        Job("rec.npz", str(cleaned.parent / "in" / "rec.npz"), None, str(cleaned / "rec.npz"), None)
    ]
    records = read_manifest(str(cleaned / "manifest.jsonl"))
    pattern = 0.5 * np.cos(np.pi * np.arange(W))[None, :].repeat(H, 0)
    with_pattern = report_figure(
        str(tmp_path), jobs, CleanConfig(), pattern_mm=pattern, records=records
    )
    plain = Image.open(cleaned / "report.png").size
    drawn = Image.open(with_pattern)
    assert drawn.size[0] > plain[0] * 1.2 and drawn.size[1] == plain[1]
    assert _info(with_pattern)["frame"] == "4"
    with pytest.raises(ValueError, match=r"pattern_mm must be an \(H, W\) array"):
        report_figure(str(tmp_path), jobs, CleanConfig(), pattern_mm=np.zeros(5), records=records)
    assert math.isfinite(float(_info(with_pattern)["change_limit_mm"]))
