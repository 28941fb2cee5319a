"""A recording of the package's own default :class:`~tof_fpn_torch.sim.Simulation` against its
scene is diagnosed ``none``: the baseline holds what the recording states about its camera (the
clip level of its full well / ADC, the simulator's read-out with random column offsets and
gains), and a reading that crosses 0 / R on a scene inside the range is the decoder's fold, not
phase wrapping. Without the statement the same clip is a finding (``saturation``)."""

from __future__ import annotations

import math

import pytest
import torch

from tof_fpn_torch.diagnosis import diagnose
from tof_fpn_torch.diagnosis.data import stated_clip_level
from tof_fpn_torch.io import Recording, recording_from_simulation, scene_from_sim
from tof_fpn_torch.sim import Camera, ReadoutFPN, SimState, Simulation, synthetic_scene

H, W, T, SEED = 48, 64, 8, 2


@pytest.fixture(scope="module")
def default_recording():
    """The default Simulation (2 ms, full well 100 000 e-: ~6 % of the pixels clip; scene up to
    7.45 m in a 7.49 m range) as a new user would write it."""
    scene = synthetic_scene(H, W, seed=SEED)
    sim = Simulation()
    out = sim.run(scene, frames=T, seed=SEED)
    assert float(out.saturated.float().mean()) > 0.02  # the default camera does clip
    return recording_from_simulation(out, sim.camera), scene_from_sim(scene)


@pytest.mark.slow
def test_default_simulation_is_diagnosed_none(default_recording):
    rec, scene = default_recording
    diag = diagnose(rec, scene)
    rep = diag.report
    assert rep["verdict"] == ["none"], rep["verdict"]
    assert rep["unexplained"] == []
    notes = " ".join(rep["recording"]["notes"])
    assert "clip level" in notes and "ReadoutFPN" in notes
    # the baseline holds the stated clip (not fitted) and the random read-out columns
    base = diag.baseline
    assert "saturation" in base.effects and "saturation.level" in base.fixed
    level_dn = base.values["saturation.level"] / base.values["camera.conversion_gain"]
    assert level_dn == pytest.approx(4000.0, rel=1e-6)
    assert base.values["readout_fpn.columns_dof"] > 10
    assert base.values["camera.conversion_gain"] == pytest.approx(25.0, rel=0.1)


@pytest.mark.slow
def test_unstated_clip_is_a_finding(default_recording):
    """The same samples without ``sim_camera`` in the meta: the clip is then physics the
    baseline lacks, and it is named."""
    rec, scene = default_recording
    meta = {k: v for k, v in rec.meta.items() if k != "sim_camera"}
    bare = Recording(rec.depth, rec.amplitude, meta)
    diag = diagnose(bare, scene, replicates=0)
    assert diag.effects[:1] == ["saturation"], diag.report["verdict"]
    assert "saturation" not in diag.baseline.effects


def test_stated_clip_level():
    cam = Camera().as_dict()
    assert stated_clip_level({"sim_camera": cam}) == 4000.0  # 100 000 e- / 25 e-/DN < 4095
    cam.update(full_well=1e9)
    assert stated_clip_level({"sim_camera": cam}) == 4095.0  # the 12-bit top code
    assert stated_clip_level({"full_well_dn": 1234.5}) == 1234.5
    assert stated_clip_level({}) is None
    with pytest.raises(ValueError, match="clip level"):
        stated_clip_level({"full_well_dn": -1.0})


def test_readout_fpn_explicit_maps():
    """Explicit per-sample column offsets and gains add to the periodic and random parts."""
    n, w = 4, 6
    off = torch.arange(n * w, dtype=torch.float64).reshape(n, w)
    gain = torch.full((n, w), 0.5, dtype=torch.float64)
    plain = ReadoutFPN(offset_amplitudes=(0.0, 0.0), gain_amplitudes=(0.0, 0.0))
    plain.random_offset, plain.random_gain = 0.0, 0.0
    fpn = ReadoutFPN(
        offset_amplitudes=(0.0, 0.0),
        gain_amplitudes=(0.0, 0.0),
        random_offset=0.0,
        random_gain=0.0,
        offset_map=off,
        gain_map=gain,
    )
    s = torch.full((1, n, 3, w), 10.0, dtype=torch.float64)
    out = fpn.apply(SimState(Camera(), None, s.clone(), None)).samples
    ref = plain.apply(SimState(Camera(), None, s.clone(), None)).samples
    assert torch.allclose(out, ref * 1.5 + off.view(1, n, 1, w))
    bad = ReadoutFPN(offset_map=torch.zeros(n, w + 1))
    with pytest.raises(ValueError, match="offset_map"):
        bad.apply(SimState(Camera(), None, s.clone(), None))
    assert math.isfinite(float(out.sum()))
