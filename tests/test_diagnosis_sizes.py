"""The diagnosis on frames of other sizes than the benchmark's: too small ones are refused with
the size in the message; a small frame still has held-out pixels (the checkerboard split's
blocks shrink under three blocks across), so a planted effect there is named, not lost; odd
sizes work. Recordings of the package's simulator with the diagnosis baseline's physics
(``test_diagnosis._sim``), the scene a crop of a synthetic one."""

from __future__ import annotations

import dataclasses
import math

import pytest
import torch
from test_diagnosis import META, _sim

from tof_fpn_torch.diagnosis import diagnose
from tof_fpn_torch.diagnosis.data import MIN_FRAME_SIDE, observe
from tof_fpn_torch.diagnosis.likelihood import SPLIT_BLOCK, make_context
from tof_fpn_torch.io import Recording, SceneData
from tof_fpn_torch.sim import synthetic_scene
from tof_fpn_torch.sim.effects import CyclicError, with_effect


def _recording(h: int, w: int, frames: int, term=None, seed: int = 3):
    scene = synthetic_scene(max(h, 16), max(w, 16), seed=seed, depth_range=(0.6, 5.0))
    crop = {
        k: getattr(scene, k)[..., :h, :w].contiguous()
        for k in ("depth", "reflectance", "amplitude")
        if getattr(scene, k) is not None
    }
    scene = dataclasses.replace(scene, **crop)
    sim = _sim() if term is None else with_effect(_sim(), term)
    out = sim.run(scene, frames, seed=seed)
    depth = torch.where(out.depth > 0, out.depth, torch.full_like(out.depth, math.nan))
    rec = Recording(depth, out.amplitude, dict(META, amplitude_unit="DN"))
    return rec, SceneData(scene.depth[0, 0], scene.reflectance[0, 0], meta={"source": "test"})


@pytest.mark.parametrize("shape", [(1, 1), (5, 40), (40, MIN_FRAME_SIDE - 1)])
def test_frames_below_the_smallest_side_are_refused_with_their_size(shape):
    rec, scene = _recording(*shape, frames=3)
    with pytest.raises(ValueError, match=rf"{shape[0]}x{shape[1]}.*at least {MIN_FRAME_SIDE}x"):
        diagnose(rec, scene)


@pytest.mark.parametrize("shape", [(MIN_FRAME_SIDE, MIN_FRAME_SIDE), (9, 13), (17, 31), (24, 40)])
def test_every_frame_size_has_fitting_and_held_out_pixels(shape):
    rec, scene = _recording(*shape, frames=3)
    obs = observe(rec, scene)
    ctx = make_context(obs, torch.full(shape, 100.0, dtype=torch.float64))
    assert bool(ctx.test.any()) and bool(ctx.train.any())
    assert not bool((ctx.train & ctx.test).any()) and bool((ctx.train | ctx.test).all())
    # a third of the shorter side at most 8 px: from 24 px on, the benchmark's 8-px blocks
    side = max(1, min(SPLIT_BLOCK, min(shape) // 3))
    assert bool(ctx.train[0, : min(side, shape[1])].all())
    if side < shape[1]:
        assert not bool(ctx.train[0, side])
    if min(shape) >= 3 * SPLIT_BLOCK:
        assert side == SPLIT_BLOCK


@pytest.mark.slow
def test_a_cyclic_error_on_the_smallest_frame_is_named():
    """8 x 8 px, 6 frames: with one 8-px block there were no held-out pixels and nothing could be
    named; the shrunk blocks give the held-out half back."""
    term = CyclicError(cos_terms=(0.06, 0.0))
    rec, scene = _recording(MIN_FRAME_SIDE, MIN_FRAME_SIDE, frames=6, term=term)
    diag = diagnose(rec, scene, replicates=0)
    assert diag.report["verdict"][0] == "cyclic_error", diag.report["effects"]


@pytest.mark.slow
def test_a_null_recording_of_odd_size_gives_none():
    rec, scene = _recording(9, 13, frames=6)
    diag = diagnose(rec, scene, replicates=0)
    assert diag.report["verdict"] == ["none"], diag.report["effects"]
