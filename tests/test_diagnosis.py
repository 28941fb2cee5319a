"""``tof-fpn diagnose`` / :func:`tof_fpn_torch.diagnosis.diagnose` (issue 10).

Small seeded recordings from the package's simulator with the baseline's physics only (the
2 pi / 3 and pi read-out FPN, shot and read noise, ADC), with or without one planted term:
bad input gives one clear error line and writes nothing; ``report.json`` has the issue's
shape; a planted cyclic error and a planted column-delay pattern are named first; a null
recording gives ``none``; the refitted ``model.json`` loads back as ``--baseline``; the ADI
wall capture (``tests/data/real``; missing: the test fails) shows a broadband column pattern.
"""

from __future__ import annotations

import json
import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import torch
from conftest import REAL_DATA_DIR, real_capture

from tof_fpn_torch import io as tio
from tof_fpn_torch.cli import main
from tof_fpn_torch.diagnosis import diagnose, load_model
from tof_fpn_torch.diagnosis.catalogue import CATALOGUE
from tof_fpn_torch.io import Recording, SceneData, write_recording, write_scene
from tof_fpn_torch.sim import (
    Camera,
    Multipath,
    Saturation,
    SimState,
    Simulation,
    synthetic_scene,
)
from tof_fpn_torch.sim.effects import CyclicError, FPNPattern, with_effect
from tof_fpn_torch.sim.readout import ADC, Photons, ReadNoise, ReadoutFPN, ShotNoise

H, W, T = 40, 56, 10
META = {"modulation_frequency_hz": 20e6, "integration_time_us": 300.0, "n_phases": 4}


def _sim() -> Simulation:
    """The diagnosis baseline's physics: periodic read-out FPN only (no random columns)."""
    cam = Camera(integration_time=300e-6, adc_bits=16)
    fpn = ReadoutFPN(offset_amplitudes=(30.0, 20.0), gain_amplitudes=(0.0, 0.0))
    fpn.random_offset, fpn.random_gain = 0.0, 0.0
    return Simulation(cam, [Photons(), ShotNoise(), fpn, ReadNoise(), ADC()])


def _recording(term=None, seed: int = 0, frames: int = T, sim: Simulation | None = None):
    scene = synthetic_scene(H, W, seed=seed, depth_range=(0.6, 5.0))
    sim = _sim() if sim is None else sim
    sim = sim if term is None else with_effect(sim, term)
    out = sim.run(scene, frames, seed=seed)
    depth = torch.where(out.depth > 0, out.depth, torch.full_like(out.depth, math.nan))
    rec = Recording(depth, out.amplitude, dict(META, amplitude_unit="DN"))
    sd = SceneData(scene.depth[0, 0], scene.reflectance[0, 0], meta={"source": "test"})
    return rec, sd


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    root = tmp_path_factory.mktemp("diag")
    rec, scene = _recording(CyclicError(cos_terms=(0.06, 0.0)), seed=1)
    write_recording(root / "cyclic.npz", rec)
    write_scene(root / "scene.npz", scene)
    return root


def _cli(capsys, *argv):
    status = main(["diagnose", *map(str, argv)])
    return status, capsys.readouterr()


# --- bad input: one line naming the problem, nothing written ------------------------------------


def _bad_files(root):
    """name -> (recording path, scene path or None, expected words in the error)."""
    rec, scene = _recording(seed=2, frames=3)
    d = rec.depth[:, 0].numpy()
    a = rec.amplitude[:, 0].numpy()
    out = {}
    np.savez(root / "plain.npz", depth=d, amplitude=a)  # arrays without the header
    out["not a recording"] = (root / "plain.npz", None, "not a tof_fpn_torch recording")
    write_recording(root / "ok.npz", rec)
    with np.load(root / "ok.npz") as z:
        arrays = {k: z[k] for k in z.files}
    np.savez(root / "nokey.npz", **{k: v for k, v in arrays.items() if k != "amplitude"})
    out["missing key"] = (root / "nokey.npz", None, "amplitude")
    # amplitude of another shape than depth
    arrays["amplitude"] = arrays["amplitude"][:, :-1]
    np.savez(root / "shape.npz", **arrays)
    out["wrong shape"] = (root / "shape.npz", None, "shape")
    nan = Recording(torch.full_like(rec.depth, math.nan), rec.amplitude, dict(META))
    write_recording(root / "nan.npz", nan, allow_empty=True)
    out["all invalid"] = (root / "nan.npz", None, "no valid pixel")
    small = SceneData(scene.depth[0, 0, :-4], scene.reflectance[0, 0, :-4])
    write_scene(root / "small_scene.npz", small)
    out["scene size"] = (root / "ok.npz", root / "small_scene.npz", "must match")
    for key, value, word in (
        ("n_phases", 3, "n_phases"),
        ("modulation_frequency_hz", 5.0, "modulation_frequency_hz"),
        ("integration_time_us", 1e9, "integration_time_us"),
    ):
        r = Recording(rec.depth, rec.amplitude, dict(META, **{key: value}))
        write_recording(root / f"meta_{key}.npz", r)
        out[f"meta {key}"] = (root / f"meta_{key}.npz", None, word)
    return out


def test_bad_input_names_the_problem_and_writes_nothing(tmp_path, capsys):
    cases = _bad_files(tmp_path)
    for name, (rec, scene, word) in cases.items():
        out = tmp_path / f"out_{name.replace(' ', '_')}"
        argv = [rec, "--out", out, "--bootstrap", 0, "--no-figures"]
        if scene is not None:
            argv += ["--scene", scene]
        status, cap = _cli(capsys, *argv)
        assert status == 2, (name, cap.out, cap.err)
        lines = cap.err.strip().splitlines()
        assert len(lines) == 1 and lines[0].startswith("tof-fpn diagnose: error:"), (name, cap.err)
        assert word in lines[0], (name, lines[0])
        assert not out.exists(), name
    # no temporary directory was left beside the outputs either
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".out_")]


def test_bad_input_api():
    rec, scene = _recording(seed=3, frames=2)
    with pytest.raises(ValueError, match="recording must be a tof_fpn_torch.io.Recording or"):
        diagnose({"depth": rec.depth}, replicates=0)
    with pytest.raises(ValueError, match=r"scene is 40x50 pixels, the recording 40x56"):
        diagnose(rec, SceneData(scene.depth[0, 0, :, :50], scene.reflectance[0, 0, :, :50]))
    half = rec.depth.clone()
    half[1] = math.nan
    with pytest.raises(ValueError, match=r"frames \[1\] have no valid pixel"):
        diagnose(Recording(half, rec.amplitude, dict(META)), scene, replicates=0)


# --- findings ------------------------------------------------------------------------------------


@pytest.mark.slow
def test_cli_names_a_planted_cyclic_error_and_the_model_reloads(files, tmp_path, capsys):
    out = tmp_path / "out"
    rec, scene = files / "cyclic.npz", files / "scene.npz"
    status, cap = _cli(capsys, rec, "--scene", scene, "--out", out, "--bootstrap", 0)
    assert status == 0, cap.err
    assert cap.out.startswith("verdict: cyclic_error")
    names = sorted(p.name for p in out.iterdir())
    assert {"report.json", "report.md", "model.json"} <= set(names)
    assert any(n.endswith(".png") for n in names)
    rep = json.loads((out / "report.json").read_text())
    assert set(rep) >= {"effects", "fit"} and set(rep["fit"]) == {"before", "after"}
    assert rep["effects"] and rep["effects"][0]["name"] == "cyclic_error"
    for e in rep["effects"]:
        assert set(e) == {"name", "terms", "score", "delta_aic", "params", "where"}
        assert e["terms"] and all(CATALOGUE[t].effect == e["name"] for t in e["terms"])
        assert e["score"] > 0 and e["delta_aic"] < 0 and isinstance(e["params"], dict)
        assert isinstance(e["where"], list)
    md = (out / "report.md").read_text()
    assert "| `cyclic_error` | `cyclic_error` |" in md  # the effect and the form that modelled it
    assert "the evidence" in md
    assert isinstance(rep["also_consistent_with"], list)
    cyc = rep["effects"][0]["params"]
    # 6 % third harmonic at N = 4: phase error 0.06 sin(4 phi) rad, peak to peak
    # 2 * 0.06 * c / (4 pi f) ~ 143 mm
    want = 2 * 0.06 * 299.7e6 / (4 * math.pi * 20e6) * 1e3
    assert cyc["peak_to_peak_mm"] == pytest.approx(want, rel=0.15)
    before, after = rep["fit"]["before"], rep["fit"]["after"]
    assert after["heldout_nll"] < before["heldout_nll"] - 10
    assert after["aic"] < before["aic"]
    assert after["residual_rms_depth_mm"] < before["residual_rms_depth_mm"]
    # the refitted model loads and, as the baseline, leaves nothing to add
    model = load_model(out / "model.json")
    assert "cyclic_error" in model.effects
    out2 = tmp_path / "again"
    status, cap = _cli(
        capsys,
        rec,
        "--scene",
        scene,
        "--out",
        out2,
        "--baseline",
        out / "model.json",
        "--bootstrap",
        0,
        "--no-figures",
    )
    assert status == 0, cap.err
    rep2 = json.loads((out2 / "report.json").read_text())
    assert "cyclic_error" not in [e["name"] for e in rep2["effects"]]
    assert rep2["fit"]["before"]["heldout_nll"] <= before["heldout_nll"] - 10


def test_planted_column_pattern_is_named_fpn_pattern():
    # (seed 4's scene saturates 1.2 % of its pixels, which the diagnosis names impulsive_pixels:
    # docs/diagnosis.md; seed 7 does not saturate)
    rec, scene = _recording(FPNPattern(rms_columns=3e-3, seed=5), seed=7)
    diag = diagnose(rec, scene, replicates=0)
    assert diag.effects[:1] == ["fpn_pattern"], diag.report["verdict"]
    p = diag.report["effects"][0]["params"]
    assert p["rms_columns_mm"] == pytest.approx(3.0, rel=0.3)


@pytest.mark.slow
def test_planted_saturation_is_named_saturation():
    """A full-well clip of every sample (the camera's own full well out of the way) on the
    brightest ~1.8 % of the pixels is named ``saturation``, not ``impulsive_pixels``: the
    saturation level starts where the clip touches samples (docs/diagnosis.md)."""
    scene = synthetic_scene(H, W, seed=7, depth_range=(0.6, 5.0))
    sim = _sim()
    sim = Simulation(replace(sim.camera, full_well=1e7), sim.terms)
    peak = Photons().mean_samples(sim.camera, scene).amax(1).flatten().double()
    levels = torch.unique(peak).flip(0)
    shares = torch.stack([(peak > lv).double().mean() for lv in levels])
    level = float(levels[int(torch.nonzero(shares > 0.01)[0])])
    share = float((peak > level).double().mean())
    assert 0.01 < share < 0.025
    rec, sd = _recording(Saturation(level), seed=7, sim=sim)
    diag = diagnose(rec, sd, replicates=0)
    assert diag.effects[:1] == ["saturation"], diag.report["verdict"]
    p = diag.report["effects"][0]["params"]
    assert p["level_e"] == pytest.approx(level, rel=0.15)
    assert 0.5 * share < p["share_of_pixels_clipped"] < 2 * share


@pytest.mark.slow
def test_fully_clipped_pixels_are_named_saturation_with_their_level():
    """A full well below the darkest sample of ~1.8 % of the pixels (all N samples clipped; ~6 %
    clipped in some sample) is named ``saturation`` with its level within 10 %: the model clips
    the noisy samples (mean and variance of the clip; docs/diagnosis.md). The soft-knee model
    before it put the level 22 % high."""
    scene = synthetic_scene(H, W, seed=7, depth_range=(0.6, 5.0))
    sim = _sim()
    sim = Simulation(replace(sim.camera, full_well=1e7), sim.terms)
    lo = Photons().mean_samples(sim.camera, scene).amin(1).flatten().double()
    level = float(torch.quantile(lo, 0.98))
    rec, sd = _recording(Saturation(level), seed=7, sim=sim)
    diag = diagnose(rec, sd, replicates=0)
    assert diag.effects[:1] == ["saturation"], diag.report["verdict"]
    assert diag.report["effects"][0]["params"]["level_e"] == pytest.approx(level, rel=0.1)


@pytest.mark.slow
def test_planted_scene_relay_is_named_multipath_with_its_relayed_light():
    """Multipath with the scene's own geometry (``Multipath(scene_relay=...)``: 60 deg field,
    1 m near field, neither on the diagnosis' grid) is named ``multipath`` and the relayed /
    direct light of the median pixel is recovered within 25 %."""
    term = Multipath(scene_relay=0.05, field_of_view=60.0, near_field=1.0)
    rec, sd = _recording(term, seed=7)
    diag = diagnose(rec, sd, replicates=0)
    assert diag.effects[:1] == ["multipath"], diag.report["verdict"]
    cam = replace(_sim().camera, ambient_irradiance=0.0)
    scene = synthetic_scene(H, W, seed=7, depth_range=(0.6, 5.0))
    act = Photons().mean_samples(cam, scene).double()
    relayed = term.relayed(act, SimState(cam, scene, act, None)).mean(1)[0] * 0.05
    truth = float((relayed / act.mean(1)[0]).median())
    got = diag.report["effects"][0]["params"]["median_relay_to_direct"]
    assert got == pytest.approx(truth, rel=0.25)


@pytest.mark.slow
def test_planted_multipath_is_named_and_recovered():
    """A 1 % diffuse second return delayed by 2.5 m (``Multipath``) is named ``multipath`` with
    its strength and extra path recovered."""
    rec, sd = _recording(Multipath(strength=0.01, extra_path=2.5), seed=7)
    diag = diagnose(rec, sd, replicates=0)
    assert diag.effects[:1] == ["multipath"], diag.report["verdict"]
    p = diag.report["effects"][0]["params"]
    assert p["strength_percent"] == pytest.approx(1.0, rel=0.2)
    assert p["extra_path_m"] == pytest.approx(2.5, abs=0.3)
    assert diag.report["fit"]["after"]["heldout_nll"] < diag.report["fit"]["before"]["heldout_nll"]


@pytest.mark.slow
def test_null_recording_gives_none():
    rec, scene = _recording(seed=6)
    diag = diagnose(rec, scene, replicates=0)
    assert diag.report["verdict"] == ["none"], diag.report["effects"]
    assert diag.report["effects"] == []


# --- real data -----------------------------------------------------------------------------------

ADI_WALL = ("adi_adtf3175/wall_depth_u16le_512x512.bin", "adi_adtf3175/wall_ir_u16le_512x512.bin")


@pytest.mark.slow
def test_adi_wall_column_pattern_is_broadband_and_modelled():
    """One frame of the ADI wall (a 128 x 160 crop of its centre), scene estimated: the column
    pattern is found, its spectrum is broadband (not 2 pi / 3 / pi), and modelling it improves
    the held-out fit (the whole frame: docs/diagnosis.md)."""
    depth, ir = tio.read_adi_depth_ir(real_capture(ADI_WALL[0]), real_capture(ADI_WALL[1]))
    crop = (..., slice(192, 320), slice(176, 336))
    meta = {"modulation_frequency_hz": None, "integration_time_us": None, "n_phases": None}
    diag = diagnose(tio.Recording(depth[crop], ir[crop], meta), None, replicates=0)
    assert diag.effects[:1] == ["fpn_pattern"], diag.report["verdict"]
    assert diag.obs.scene_estimated
    col = next(
        w for w in diag.report["effects"][0]["where"] if w["statistic"] == "depth_mean|column"
    )
    assert col["excess_sigma"] > 20
    spec = col["spectrum"]
    assert spec["verdict"] == "broadband"
    assert sum(spec["excess_power_share_near"].values()) < 0.2
    before, after = diag.report["fit"]["before"], diag.report["fit"]["after"]
    assert after["heldout_nll"] < before["heldout_nll"] - 100


@pytest.mark.slow
def test_readme_diagnose_command_works_as_written(tmp_path, monkeypatch, capsys):
    import re
    import shlex

    text = (Path(__file__).resolve().parents[1] / "README.md").read_text()
    line = re.search(r"^tof-fpn diagnose .*$", text, re.M)
    assert line, "README shows no tof-fpn diagnose command"
    words = shlex.split(line.group(0), comments=True)
    rec, scene = _recording(seed=6)
    monkeypatch.chdir(tmp_path)
    write_recording(words[2], rec)
    write_scene(words[words.index("--scene") + 1], scene)
    status, cap = _cli(capsys, *words[2:])
    assert status == 0, cap.err
    out = Path(words[words.index("--out") + 1])
    assert json.loads((out / "report.json").read_text())["effects"] == []
    assert (out / "report.md").is_file() and (out / "model.json").is_file()


@pytest.mark.slow
def test_cli_takes_a_cameras_own_file(tmp_path, capsys):
    """An ADI depth / IR pair as the camera writes it (uint16 mm and counts, the size in the
    name; a 64 x 64 crop of the wall capture) is diagnosed as it is, its IR file found beside
    it and the scene estimated from it (a plain array .npz is refused: the bad-input test)."""
    h, w = 64, 64
    for kind, src in zip(("depth", "ir"), ADI_WALL, strict=True):
        full = np.fromfile(REAL_DATA_DIR / src, dtype="<u2").reshape(512, 512)
        full[200 : 200 + h, 200 : 200 + w].copy().tofile(tmp_path / f"cap_{kind}_u16le_{h}x{w}.bin")
    out = tmp_path / "out"
    depth_file = tmp_path / f"cap_depth_u16le_{h}x{w}.bin"
    status, cap = _cli(capsys, depth_file, "--out", out, "--bootstrap", 0, "--no-figures")
    assert status == 0, cap.err
    assert cap.out.startswith("verdict:")
    report = json.loads((out / "report.json").read_text())
    got = report["recording"]
    assert (got["height"], got["width"], got["frames"]) == (h, w, 1)
    assert got["scene_estimated"]
    assert got["depth_pixels"] > 0.5 * h * w


@pytest.mark.slow
def test_a_single_frame_holds_the_conversion_gain():
    """One frame has no temporal spread: the shot-noise share of the noise cannot be told from
    the read noise, and the fit drifted along the conversion gain (to 1e32 e-/DN on the Azure
    Kinect desk frame with two threads, until a bootstrap replicate had no pixel left). The gain
    is held at its start from the data's noise level, the report says so, and one or two threads
    give the same baseline."""
    from tof_fpn_torch.diagnosis.data import observe
    from tof_fpn_torch.diagnosis.run import _baseline

    rec, scene = _recording(seed=3, frames=1)
    start = _baseline(observe(rec, scene), None).values["camera.conversion_gain"]
    outs = [diagnose(rec, scene, replicates=0, threads=t) for t in (1, 2)]
    for out in outs:
        assert out.baseline.values["camera.conversion_gain"] == start
        assert any("single frame" in n for n in out.report["recording"]["notes"])
    a, b = (o.baseline.values["camera.read_noise"] for o in outs)
    assert abs(a - b) <= 1e-6 * abs(a)
