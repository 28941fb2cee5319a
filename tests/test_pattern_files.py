"""Pattern files (tof_fpn_torch.io.patterns): files written by earlier versions read unchanged, and a
file written now has the same layout (names, dtypes, metadata).

``tests/data/patterns/*_v1.npz`` were written by the analysis layer's own ``.npy`` writer
(``FixedPattern.save`` / ``ComplexPattern.save`` of version 0.2.0, before the file layer took the
format over) from the patterns built in :func:`_fixed` and :func:`_complex` below.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import torch

from tof_fpn_torch.analysis import ComplexPattern, FixedPattern
from tof_fpn_torch.clean.pattern import load_pattern, read_pattern, save_pattern
from tof_fpn_torch.io import FormatError
from tof_fpn_torch.io.patterns import read_pattern_file, write_pattern_file

DATA = Path(__file__).resolve().parent / "data" / "patterns"
F64 = torch.float64


def _fixed() -> FixedPattern:
    return FixedPattern(
        column_offset=torch.arange(6, dtype=F64) * 1e-3 - 2.5e-3,
        row_offset=torch.arange(4, dtype=F64) * -2e-3 + 3e-3,
        pixel_offset=(torch.arange(24, dtype=F64).reshape(4, 6) - 11.5) * 1e-4,
        column_gain=1.0 + torch.arange(6, dtype=F64) * 1e-2,
        column_se=torch.full((6,), 5e-4, dtype=F64),
        frames=12,
        groups=2,
        levels=[1.0, 2.5],
        width=31,
        flat_field=True,
    )


def _complex() -> ComplexPattern:
    return ComplexPattern(
        column_offset_re=torch.tensor([0.5, -1.0, 0.25, 0.0, 1.5], dtype=F64),
        column_offset_im=torch.tensor([-0.5, 0.0, 1.0, -0.25, 0.75], dtype=F64),
        modulation_frequency_hz=20e6,
        row_offset_re=torch.tensor([0.1, -0.1, 0.2], dtype=F64),
        row_offset_im=torch.tensor([0.0, 0.3, -0.3], dtype=F64),
        column_pixels=torch.tensor([3.0, 6.0, 6.0, 6.0, 3.0], dtype=F64),
        frames=16,
        width=51,
        amplitude_cap=2.0,
        texture_k=3.0,
        noise_sigma=0.7,
        shrink_factor=0.9,
        height=3,
    )


def _same(a, b) -> None:
    assert type(a) is type(b)
    for name, va in vars(a).items():
        vb = getattr(b, name)
        if isinstance(va, torch.Tensor):
            assert vb.dtype == F64 and torch.equal(va, vb), name
        else:
            assert va == vb, name


def test_files_of_the_earlier_writer_read_unchanged():
    _same(read_pattern(DATA / "fixed_v1.npz"), _fixed())
    _same(read_pattern(DATA / "complex_v1.npz"), _complex())
    cols = read_pattern(DATA / "fixed_columns_v1.npz")
    assert cols.pixel_offset is None and cols.column_gain is None and cols.frames == 3
    assert torch.equal(cols.column_offset, torch.tensor([0.001, -0.002, 0.001], dtype=F64))
    # the run-time modules of the old files: what the earlier version computed (its output,
    # recorded when the files were written)
    x = torch.linspace(1.0, 2.0, 24, dtype=F64).reshape(1, 1, 4, 6)
    out = load_pattern(DATA / "fixed_v1.npz")(x)
    ref = [1.00065, 1.032701248385708, 1.064124040920716, 1.0949366821443645]
    assert out.flatten()[:4].tolist() == pytest.approx(ref, rel=0, abs=1e-15)
    xc = torch.linspace(1.0, 2.0, 15, dtype=F64).reshape(1, 1, 3, 5)
    out = load_pattern(DATA / "complex_v1.npz")(xc, torch.full_like(xc, 100.0))
    ref = [1.0093096164766204, 1.0630786813056166, 1.1393819542618824, 1.2168612682302085]
    assert out.flatten()[:4].tolist() == pytest.approx(ref, rel=0, abs=1e-15)


@pytest.mark.parametrize("name", ["fixed_v1.npz", "fixed_columns_v1.npz", "complex_v1.npz"])
def test_a_file_written_now_has_the_layout_of_the_earlier_one(tmp_path, name):
    again = save_pattern(read_pattern(DATA / name), tmp_path / "sub" / name)
    with np.load(DATA / name, allow_pickle=False) as old, np.load(again) as new:
        assert old.files == new.files
        for key in old.files:
            assert old[key].dtype == new[key].dtype and old[key].shape == new[key].shape, key
            np.testing.assert_array_equal(old[key], new[key])
    with np.load(again) as new:
        meta = json.loads(new["meta_json"].tobytes().decode())
    assert meta["format"].startswith("tof_fpn_torch.") and list(meta)[0] == "format"


def test_errors(tmp_path):
    bad = tmp_path / "bad.npz"
    np.savez(bad, column_offset=np.zeros(3))
    with pytest.raises(ValueError, match="not a fixed-pattern file: missing .*meta_json"):
        read_pattern_file(bad)
    arrays, meta = _fixed().to_arrays()
    path = write_pattern_file(tmp_path / "p.npz", "fixed", arrays, meta)
    kind, back, meta_back = read_pattern_file(path)
    assert kind == "fixed" and meta_back["format"] == "tof_fpn_torch.fixed_pattern/1"
    wrong = {**arrays, "meta_json": torch.zeros(0)}
    with pytest.raises(ValueError, match="needs the arrays"):
        write_pattern_file(tmp_path / "q.npz", "complex", arrays, meta)
    with pytest.raises(ValueError, match="kind must be"):
        write_pattern_file(tmp_path / "q.npz", "other", wrong, meta)
    other = tmp_path / "other.npz"
    text = json.dumps({"format": "something/9"}).encode()
    np.savez(
        other, **{k: v.numpy() for k, v in arrays.items()}, meta_json=np.frombuffer(text, np.uint8)
    )
    with pytest.raises(ValueError, match="format 'something/9', expected"):
        read_pattern(other)
    (tmp_path / "x.npz").write_text("not a zip")
    with pytest.raises(FormatError):
        read_pattern(tmp_path / "x.npz")
    with pytest.raises(ValueError, match="not a pattern file"):
        load_pattern(tmp_path / "x.npz")
    with pytest.raises(ValueError, match="pattern file not found"):
        load_pattern(tmp_path / "none.npz")
