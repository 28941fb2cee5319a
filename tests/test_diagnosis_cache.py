"""The prediction's cache of unit photon images is never served for another scene.

A worker process that diagnoses many recordings in a row builds a scene, predicts, frees it and
builds the next: the interpreter may give the next scene the address of the freed one. The cache
must not take the new scene for the old (a key on ``id(scene)`` did).
"""

from __future__ import annotations

import math
from dataclasses import replace

import torch

from tof_fpn_torch.diagnosis.data import observe
from tof_fpn_torch.diagnosis.fit import init_model
from tof_fpn_torch.diagnosis.prediction import predict
from tof_fpn_torch.io import Recording, SceneData
from tof_fpn_torch.sim import Camera, Simulation, synthetic_scene
from tof_fpn_torch.sim.readout import ADC, Photons, ReadNoise, ShotNoise

H, W, T = 16, 20, 3
META = {"modulation_frequency_hz": 20e6, "integration_time_us": 300.0, "n_phases": 4}


def _obs(seed: int):
    scene = synthetic_scene(H, W, seed=seed, depth_range=(0.6, 5.0))
    sim = Simulation(Camera(integration_time=300e-6, adc_bits=16), [Photons(), ShotNoise()])
    sim.terms += [ReadNoise(), ADC()]
    out = sim.run(scene, T, seed=seed)
    depth = torch.where(out.depth > 0, out.depth, torch.full_like(out.depth, math.nan))
    rec = Recording(depth, out.amplitude, dict(META, amplitude_unit="DN"))
    return observe(rec, SceneData(scene.depth[0, 0], scene.reflectance[0, 0], meta={}))


def test_freed_scenes_address_is_reused_by_the_interpreter():
    """What the test below relies on: a freed scene's address is soon given to a new one (were
    it never, the test below could not see a cache keyed on the address)."""
    obs = _obs(1)
    kept, first = [], obs.scene()
    address = id(first)
    del first
    for _ in range(1000):
        s = obs.scene()
        if id(s) == address:
            return
        kept.append(s)
    raise AssertionError("no new scene took the address of a freed one in 1000 tries")


def test_a_scene_built_after_another_was_freed_gets_its_own_photons():
    obs_a, obs_b = _obs(1), _obs(2)
    # the wanted predictions: from two scenes alive together (two addresses)
    scene_a, scene_b = obs_a.scene(), obs_b.scene()
    assert not torch.equal(scene_a.depth, scene_b.depth)
    model = init_model(obs_a, scene_a)
    with torch.no_grad():
        want_a = predict(model, obs_a, scene=scene_a)
        want_b = predict(model, obs_b, scene=scene_b)
        assert not torch.allclose(want_a.a0, want_b.a0)
        del scene_a, scene_b
        for _ in range(20):  # one after another, each freed before the next is built
            for obs, want in ((obs_a, want_a), (obs_b, want_b)):
                got = predict(model, obs, scene=obs.scene())
                assert torch.equal(got.a0, want.a0) and torch.equal(got.offset, want.offset)
                assert torch.equal(got.mu_d, want.mu_d)


def test_the_cache_serves_the_scene_and_an_equal_one_but_not_another():
    """Still a cache: the same scene or one of equal content (``obs.scene()`` called again) gets
    the stored unit images; another scene or another camera setting gets its own."""
    from tof_fpn_torch.diagnosis.prediction import _photon_units

    obs_a, obs_b = _obs(1), _obs(2)
    cam = obs_a.camera()
    scene = obs_a.scene()
    units, _ = _photon_units(cam, scene)
    assert _photon_units(cam, scene)[0] is units
    assert _photon_units(cam, obs_a.scene())[0] is units
    other, _ = _photon_units(cam, obs_b.scene())
    assert other is not units and not torch.equal(other[0], units[0])
    brighter = replace(cam, illumination_power=2.0 * cam.illumination_power)
    again, _ = _photon_units(brighter, obs_b.scene())
    assert torch.allclose(again[0], 2.0 * other[0], rtol=1e-5)
