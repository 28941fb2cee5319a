"""The recording and scene formats (docs/io.md): contract, exact round trips, validation, and the
simulator and the real captures going through the same code."""

from __future__ import annotations

import json
import math
import zipfile
from pathlib import Path

import numpy as np
import pytest
import torch
from conftest import REAL_DATA_DIR

from tof_fpn_torch import io as tio
from tof_fpn_torch.io import FormatError, Recording, SceneData
from tof_fpn_torch.runtime import valid_mask
from tof_fpn_torch.sim import Camera, Scene, Simulation, synthetic_scene

META = {"modulation_frequency_hz": 20e6, "integration_time_us": 100.0, "n_phases": 4}


@pytest.fixture(scope="module")
def sim_run():
    sim = Simulation(Camera(integration_time=100e-6))
    scene = synthetic_scene(24, 32, seed=0, batch=2)
    return sim, scene, sim.run(scene, frames=2, seed=0)


def _same(a, b) -> None:
    assert a.dtype == b.dtype and a.shape == b.shape
    torch.testing.assert_close(a, b, rtol=0, atol=0, equal_nan=True)


def _frames(t=3, h=5, w=7, seed=0):
    g = torch.Generator().manual_seed(seed)
    return torch.rand(t, 1, h, w, generator=g) + 0.5, torch.rand(t, 1, h, w, generator=g) * 100


# --- the simulator writes recordings -------------------------------------------------------------


def test_simulation_recording_round_trip(sim_run, tmp_path):
    sim, _, out = sim_run
    ts = torch.arange(4, dtype=torch.float64) / 30
    rec = tio.recording_from_simulation(out, sim.camera, profile="camcube", timestamps_s=ts)
    assert rec.depth.shape == rec.amplitude.shape == (4, 1, 24, 32)
    assert rec.raw.shape == (4, 4, 24, 32) and rec.raw.dtype == torch.float32
    dead = out.depth == 0  # the decoder's dead pixels are invalid: NaN in the recording
    assert int(dead.sum()) > 0 and bool(rec.depth[dead].isnan().all())
    assert torch.equal(rec.depth[~dead], out.depth[~dead]) and torch.equal(rec.raw, out.samples)
    m = rec.meta
    assert m["modulation_frequency_hz"] == sim.camera.modulation_frequency
    assert m["integration_time_us"] == pytest.approx(100.0) and m["n_phases"] == 4
    assert m["amplitude_unit"] == "DN" and m["camera"] == "camcube"
    assert m["sim_camera"]["read_noise"] == sim.camera.read_noise
    tio.write_recording(tmp_path / "sim.npz", rec)
    back = tio.read_recording(tmp_path / "sim.npz")
    for key in ("depth", "amplitude", "raw"):
        _same(getattr(back, key), getattr(rec, key))
    _same(back.timestamps_s, ts)
    assert back.meta == m


def test_recording_file_is_the_documented_contract(sim_run, tmp_path):
    sim, _, out = sim_run
    rec = tio.recording_from_simulation(out, sim.camera, include_raw=False)
    path = tio.write_recording(tmp_path / "r.npz", rec)
    with np.load(path, allow_pickle=False) as f:
        assert sorted(f.files) == ["amplitude", "content", "depth", "format_version", "meta"]
        assert f["content"].item() == "tof_fpn_torch.recording"
        assert f["format_version"].item() == tio.FORMAT_VERSION == 1
        assert f["depth"].dtype == np.float32 and f["depth"].shape == (4, 24, 32)
        assert f["amplitude"].dtype == np.float32 and f["amplitude"].shape == (4, 24, 32)
        d = f["depth"]
        assert np.all(np.isnan(d) | (np.isfinite(d) & (d > 0)))  # NaN is the only invalid code
        meta = json.loads(f["meta"].item())
    assert set(tio.REQUIRED_META) <= set(meta)
    with zipfile.ZipFile(path) as z:  # fixed timestamps: the same recording, the same bytes
        assert {i.date_time for i in z.infolist()} == {(1980, 1, 1, 0, 0, 0)}
    first = path.read_bytes()
    tio.write_recording(path, tio.read_recording(path))
    assert path.read_bytes() == first


def test_real_captures_go_through_the_same_code(tmp_path):
    adi = REAL_DATA_DIR / "adi_adtf3175"
    depth, ir = tio.read_adi_depth_ir(
        adi / "wall_depth_u16le_512x512.bin", adi / "wall_ir_u16le_512x512.bin"
    )
    meta = {"camera": "adtf3175", "modulation_frequency_hz": None, "integration_time_us": None}
    rec = Recording(depth, ir, {**meta, "n_phases": None, "amplitude_unit": "AB counts"})
    tio.write_recording(tmp_path / "wall.npz", rec, compress=True)
    back = tio.read_recording(tmp_path / "wall.npz")
    _same(back.depth, depth)
    _same(back.amplitude, ir)
    assert back.raw is None and back.timestamps_s is None and back.meta == rec.meta
    kinect = tio.read_azure_kinect_mkv(REAL_DATA_DIR / "azure_kinect" / "desk_recording.mkv")
    tio.write_recording(tmp_path / "k.npz", kinect)
    back = tio.read_recording(tmp_path / "k.npz")
    _same(back.depth, kinect.depth)
    _same(back.timestamps_s, kinect.timestamps_s)
    assert back.meta["calibration"] == kinect.meta["calibration"]
    # a recording is a depth / amplitude .npz too: the pair reader and the dataset take it
    d, a = tio.read_pair(tmp_path / "wall.npz")
    _same(d, depth)
    _same(a, ir)


def test_recording_multi_frequency_and_inputs_unchanged():
    depth, amp = _frames()
    depth[0, 0, 0, 0] = 0.0
    keep = depth.clone()
    rec = Recording(depth, amp, {**META, "modulation_frequency_hz": [80e6, 16e6, 120e6]})
    assert torch.equal(depth, keep)  # the 0 is NaN in the recording, not in the caller's tensor
    assert math.isnan(float(rec.depth[0, 0, 0, 0]))
    assert rec.frames == 3
    assert rec.replace(timestamps_s=[0.0, 0.1, 0.2]).timestamps_s.dtype == torch.float64


@pytest.mark.parametrize(
    ("change", "match"),
    [
        (
            {"meta": {"n_phases": 4}},
            r"meta lacks \['modulation_frequency_hz', 'integration_time_us'\]",
        ),
        ({"meta": {**META, "modulation_frequency_hz": -1.0}}, r"a number > 0, a list of them"),
        ({"meta": {**META, "modulation_frequency_hz": []}}, "must not be an empty list"),
        (
            {"meta": {**META, "integration_time_us": 0}},
            r"integration_time_us'\] must be a number > 0",
        ),
        ({"meta": {**META, "n_phases": 4.0}}, r"n_phases'\] must be an int >= 1 or None"),
        ({"meta": {**META, "n_phases": True}}, r"n_phases'\] must be an int"),
        ({"meta": {**META, "camera": "nokia"}}, "unknown camera profile 'nokia'"),
        ({"meta": {**META, "x": object()}}, "meta values must be JSON data"),
        ({"meta": {**META, "x": math.inf}}, "JSON has no NaN / inf"),
        ({"meta": {**META, 3: 1}}, "meta keys must be str"),
        ({"raw": torch.zeros(3, 5, 5, 7)}, "raw has 5 samples per frame, meta n_phases 4"),
        ({"raw": torch.zeros(2, 4, 5, 7)}, r"raw must have shape \(T, N, H, W\) = \(3, N, 5, 7\)"),
        ({"timestamps_s": [0.0, 0.2, 0.1]}, "strictly increasing"),
        ({"timestamps_s": [0.0, 0.2]}, "timestamps_s must be 3 finite seconds"),
        ({"timestamps_s": [0.0, math.nan, 1.0]}, "finite seconds"),
        ({"depth": torch.ones(3, 1, 5, 7, dtype=torch.int32)}, "depth must be floating point"),
        ({"amplitude": torch.ones(3, 1, 5, 6)}, r"amplitude must have the shape of depth"),
        ({"depth": torch.ones(3, 2, 5, 7)}, r"depth must have shape \(T, H, W\) or \(T, 1, H, W\)"),
        ({"depth": [[1.0]]}, "depth must be a torch.Tensor or numpy.ndarray"),
    ],
)
def test_recording_validation(change, match):
    depth, amp = _frames()
    fields = {"depth": depth, "amplitude": amp, "meta": META, **change}
    with pytest.raises(ValueError, match=match):
        Recording(**fields)


def test_recording_nan_only_frame_refused_on_write_and_read(tmp_path):
    depth, amp = _frames()
    depth[1] = 0.0  # all invalid
    rec = Recording(depth, amp, META)
    with pytest.raises(ValueError, match=r"frame\(s\) \[1\] of 3 have no valid pixel"):
        tio.write_recording(tmp_path / "e.npz", rec)
    tio.write_recording(tmp_path / "e.npz", rec, allow_empty=True)
    with pytest.raises(ValueError, match=r"frame\(s\) \[1\] of 3"):
        tio.read_recording(tmp_path / "e.npz")
    assert bool(tio.read_recording(tmp_path / "e.npz", allow_empty=True).depth[1].isnan().all())


def _rewrite(path: Path, **changes) -> None:
    """Re-save a recording's archive with some entries changed (None: removed)."""
    with np.load(path, allow_pickle=False) as f:
        arrays = {k: f[k] for k in f.files}
    for k, v in changes.items():
        if v is None:
            arrays.pop(k)
        else:
            arrays[k] = v
    np.savez(path, **arrays)


@pytest.mark.parametrize(
    ("changes", "match"),
    [
        ({"content": np.array("tof_fpn_torch.scene")}, "holds 'tof_fpn_torch.scene', expected"),
        ({"format_version": np.array(2)}, "format_version 2; this reader knows versions 1 .. 1"),
        ({"format_version": None}, "no 'format_version' entry"),
        ({"meta": np.array("{not json")}, "meta is not valid JSON"),
        ({"meta": np.array("[1, 2]")}, "meta must be a JSON object, got list"),
        ({"meta": np.array('{"n_phases": 4}')}, "not a valid recording: meta lacks"),
        ({"depths": np.zeros(3)}, r"unknown array\(s\) \['depths'\]"),
        ({"amplitude": None}, r"missing array\(s\) \['amplitude'\]"),
        ({"depth": np.ones((3, 5, 7))}, "'depth' must be float32 with 3 dimensions, got float64"),
        ({"depth": np.zeros((3, 5, 7), np.float32)}, "neither NaN nor finite > 0"),
        ({"raw": np.ones((3, 4, 5, 7), np.float32)[:, :, None]}, "'raw' must be float32 with 4"),
        ({"timestamps_s": np.arange(3, dtype=np.float32)}, "'timestamps_s' must be float64"),
    ],
)
def test_recording_file_violations_raise_format_errors(tmp_path, changes, match):
    depth, amp = _frames()
    path = tio.write_recording(tmp_path / "r.npz", Recording(depth, amp, META))
    _rewrite(path, **changes)
    with pytest.raises(FormatError, match=match):
        tio.read_recording(path)


def test_recording_corrupt_and_foreign_files(tmp_path):
    depth, amp = _frames()
    path = tio.write_recording(tmp_path / "r.npz", Recording(depth, amp, META))
    path.write_bytes(path.read_bytes()[:-40])
    with pytest.raises(FormatError, match="cannot read .*r.npz"):
        tio.read_recording(path)
    tio.write_npz(tmp_path / "pair.npz", depth, amp)  # a plain pair is not a recording
    with pytest.raises(FormatError, match="no 'content' entry"):
        tio.read_recording(tmp_path / "pair.npz")
    with pytest.raises(ValueError, match="recording must be a Recording"):
        tio.write_recording(tmp_path / "x.npz", {"depth": depth})


def test_recording_from_simulation_argument_errors(sim_run):
    sim, _, out = sim_run
    with pytest.raises(ValueError, match=r"simulator result with .depth"):
        tio.recording_from_simulation(object(), sim.camera)
    with pytest.raises(ValueError, match=r"simulator Camera with .modulation_frequency"):
        tio.recording_from_simulation(out, object())
    with pytest.raises(ValueError, match="unknown camera profile"):
        tio.recording_from_simulation(out, sim.camera, profile="nope")
    rec = tio.recording_from_simulation(out, sim.camera, meta={"parameters": sim.parameters()})
    assert rec.meta["parameters"]["camera.n_phases"] == 4


# --- the scene format ----------------------------------------------------------------------------


def test_scene_round_trip_from_and_to_the_simulator(sim_run, tmp_path):
    _, scene, _ = sim_run
    sd = tio.scene_from_sim(scene, index=1, meta={"name": "fig7"})
    assert sd.depth.shape == sd.reflectance.shape == (1, 1, 24, 32) and sd.mask is None
    assert torch.equal(sd.depth, scene.depth[1:2]) and sd.meta["source"] == "tof_fpn_torch.sim"
    tio.write_scene(tmp_path / "s.npz", sd)
    back = tio.read_scene(tmp_path / "s.npz")
    _same(back.depth, sd.depth)
    _same(back.reflectance, sd.reflectance)
    assert back.meta == {"name": "fig7", "source": "tof_fpn_torch.sim"}
    again = Scene(back.depth, back.reflectance)  # the simulator takes it back
    assert torch.equal(again.depth, scene.depth[1:2])
    with np.load(tmp_path / "s.npz") as f:
        assert f["content"].item() == "tof_fpn_torch.scene" and f["depth"].shape == (24, 32)
        assert f["depth"].dtype == f["reflectance"].dtype == np.float32


def test_scene_mask_allows_unknown_pixels(tmp_path):
    depth = torch.full((4, 5), 2.0)
    refl = torch.full((4, 5), 0.5)
    mask = torch.ones(4, 5, dtype=torch.bool)
    depth[0, 0], refl[0, 0], mask[0, 0] = math.nan, 7.0, False
    sd = SceneData(depth, refl, mask)
    tio.write_scene(tmp_path / "m.npz", sd)
    back = tio.read_scene(tmp_path / "m.npz")
    assert torch.equal(back.mask, sd.mask) and back.mask.dtype == torch.bool
    _same(back.depth, sd.depth)
    with pytest.raises(ValueError, match=r"depth must be finite and > 0 m where known, got 1"):
        SceneData(depth, refl)
    with pytest.raises(ValueError, match=r"reflectance must be finite in \(0, 1\]"):
        SceneData(depth.nan_to_num(1.0), refl)


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"mask": torch.ones(4, 5)}, "mask must be a bool map"),
        ({"mask": torch.ones(4, 4, dtype=torch.bool)}, "mask must have the shape of depth"),
        ({"reflectance": torch.full((4, 6), 0.5)}, "reflectance must have the shape of depth"),
        ({"depth": torch.ones(2, 1, 4, 5)}, r"shape \(H, W\) or \(1, 1, H, W\)"),
        ({"reflectance": torch.zeros(4, 5)}, r"reflectance must be finite in \(0, 1\]"),
        ({"meta": [1]}, "meta must be a dict"),
    ],
)
def test_scene_validation(kwargs, match):
    fields = {"depth": torch.ones(4, 5), "reflectance": torch.full((4, 5), 0.5), **kwargs}
    with pytest.raises(ValueError, match=match):
        SceneData(**fields)


def test_scene_file_errors(sim_run, tmp_path):
    _, scene, _ = sim_run
    with pytest.raises(ValueError, match=r"index must be an int in \[0, 2\)"):
        tio.scene_from_sim(scene, index=2)
    with pytest.raises(ValueError, match=r"simulator Scene with a .depth tensor"):
        tio.scene_from_sim(object())
    depth, amp = _frames()
    tio.write_recording(tmp_path / "r.npz", Recording(depth, amp, META))
    with pytest.raises(FormatError, match="holds 'tof_fpn_torch.recording', expected"):
        tio.read_scene(tmp_path / "r.npz")
    path = tio.write_scene(tmp_path / "s.npz", tio.scene_from_sim(scene))
    _rewrite(path, reflectance=np.full((24, 32), 2.0, np.float32))
    with pytest.raises(FormatError, match="not a valid scene: reflectance must be finite"):
        tio.read_scene(path)
    _rewrite(path, mask=np.ones((24, 32), np.uint8))
    with pytest.raises(FormatError, match="'mask' must be bool"):
        tio.read_scene(path)
    assert valid_mask(tio.scene_from_sim(scene).depth).all()
