"""Raw-level simulator: eq. (1) decoder, physical terms, noise laws, FPN, validation."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
import torch

from tof_fpn_torch.sim import (
    ADC,
    SPEED_OF_LIGHT_AIR,
    Camera,
    DepthFromSamples,
    ImpulsivePixels,
    Photons,
    ReadoutFPN,
    Scene,
    ShotNoise,
    Simulation,
    depth_from_samples,
    depth_noise_vs_amplitude,
    fpn_error_vs_amplitude,
    loglog_slope,
    noise_lambda,
    simulate,
    synthetic_scene,
    unambiguous_range,
)

# ----------------------------------------------------------------------------- eq. (1) decoder


@pytest.mark.parametrize("n", [4, 5, 8])
def test_decoder_matches_numpy_fft(n):
    rng = np.random.default_rng(n)
    r = rng.uniform(0, 1000, size=(2, n, 7, 9))
    depth, amp, off = depth_from_samples(torch.from_numpy(r), 20e6)
    x1 = np.fft.fft(r, axis=1)[:, 1:2]  # sum_n R_n e^{-j 2 pi n / N}
    phase = np.mod(np.angle(x1), 2 * np.pi)
    np.testing.assert_allclose(amp.numpy(), 2.0 / n * np.abs(x1), rtol=1e-12, atol=1e-9)
    np.testing.assert_allclose(off.numpy(), r.mean(axis=1, keepdims=True), rtol=1e-12)
    np.testing.assert_allclose(
        depth.numpy(), SPEED_OF_LIGHT_AIR * phase / (4 * np.pi * 20e6), rtol=1e-10, atol=1e-9
    )


def test_decoder_inverts_ideal_samples():
    g = torch.Generator().manual_seed(0)
    n, f = 6, 20e6
    d = torch.rand((3, 1, 5, 5), generator=g, dtype=torch.float64) * 0.99 * unambiguous_range(f)
    a = 1 + 99 * torch.rand((3, 1, 5, 5), generator=g, dtype=torch.float64)
    b = a + 50 * torch.rand((3, 1, 5, 5), generator=g, dtype=torch.float64)
    phi = 4 * math.pi * f * d / SPEED_OF_LIGHT_AIR
    t = torch.arange(n, dtype=torch.float64).view(1, n, 1, 1) * 2 * math.pi / n
    r = b + a * torch.cos(phi + t)
    dd, aa, bb = depth_from_samples(r, f)
    torch.testing.assert_close(dd, d, rtol=0, atol=1e-9)
    torch.testing.assert_close(aa, a)
    torch.testing.assert_close(bb, b)


def test_decoder_torchscript_matches_eager():
    r = torch.rand((2, 4, 8, 8), generator=torch.Generator().manual_seed(3)) * 100
    fn = torch.jit.script(depth_from_samples)
    mod = DepthFromSamples(4, 20e6)
    smod = torch.jit.script(mod)
    for got, want in zip(fn(r, 20e6), depth_from_samples(r, 20e6), strict=True):
        torch.testing.assert_close(got, want)
    for got, want in zip(smod(r), mod(r), strict=True):
        torch.testing.assert_close(got, want)
    for got, want in zip(mod(r), depth_from_samples(r, 20e6), strict=True):
        torch.testing.assert_close(got, want)


def test_decoder_errors():
    with pytest.raises(ValueError, match="N >= 4"):
        depth_from_samples(torch.zeros(1, 3, 4, 4))
    with pytest.raises(ValueError, match="shape"):
        depth_from_samples(torch.zeros(4, 4, 4))
    with pytest.raises(ValueError, match="modulation_frequency"):
        depth_from_samples(torch.zeros(1, 4, 4, 4), 0.0)
    with pytest.raises(ValueError, match="N = 4"):
        DepthFromSamples(4)(torch.zeros(1, 5, 4, 4))
    dead = depth_from_samples(torch.full((1, 4, 2, 2), 7.0))
    assert float(dead[0].abs().max()) == 0 and float(dead[1].max()) == 0


# ----------------------------------------------------------------------------- noise laws


def test_depth_noise_follows_inverse_amplitude():
    """sigma_D ~ 1/A (eq. 2) where the per-sample noise does not grow with A (ambient-dominated)."""
    cam = Camera(
        integration_time=1e-3,
        ambient_irradiance=20.0,
        full_well=4e6,
        conversion_gain=100.0,
        adc_bits=16,
    )
    curve = depth_noise_vs_amplitude(Simulation(cam).without("readout_fpn"), seed=1)
    amp, sigma = curve.amplitude, curve.value
    assert float(amp.max() / amp.min()) > 8  # about a decade of amplitudes
    slope = np.polyfit(np.log(amp.numpy()), np.log(sigma.numpy()), 1)[0]  # independent fit
    assert -1.1 < slope < -0.9, slope
    assert abs(curve.slope - slope) < 1e-6
    # and the level matches the derived lambda of eq. (2)
    predicted = torch.sqrt(noise_lambda(cam, curve.offset)) / amp
    ratio = predicted / sigma
    assert float(ratio.min()) > 0.9 and float(ratio.max()) < 1.1, ratio


def test_shot_limited_noise_is_not_inverse_amplitude():
    """With only the active light's shot noise, sigma_D ~ 1/sqrt(A): the 1/A law is regime-bound."""
    cam = Camera(
        integration_time=200e-6, ambient_irradiance=0.0, read_noise=0.0, full_well=2e6, adc_bits=16
    )
    curve = depth_noise_vs_amplitude(Simulation(cam).without("readout_fpn"), seed=2)
    assert -0.6 < curve.slope < -0.4, curve.slope


def test_poisson_shot_noise_statistics():
    cam = Camera(read_noise=0.0, conversion_gain=1.0, adc_bits=20, full_well=1e6)
    scene = Scene(torch.full((1, 1, 8, 8), 3.0), torch.full((1, 1, 8, 8), 0.2))
    sim = Simulation(cam, [Photons(), ShotNoise(exact=True), ADC(quantize=False)])
    mean = Photons().mean_samples(cam, scene)
    out = sim.run(scene, frames=400, seed=5)
    s = out.samples.view(400, 4, 8, 8)
    rel_var = s.var(dim=0) / mean[0]
    assert abs(float(rel_var.mean()) - 1.0) < 0.05
    torch.testing.assert_close(s.mean(dim=0), mean[0], rtol=0.01, atol=0)


# ----------------------------------------------------------------------------- FPN


def test_fpn_error_grows_as_amplitude_falls():
    curve = fpn_error_vs_amplitude(Simulation(Camera(integration_time=100e-6)))
    err, amp = curve.value, curve.amplitude
    assert bool((amp[1:] > amp[:-1]).all()) and float(amp[-1] / amp[0]) > 50
    assert bool((err[1:] < err[:-1]).all()), err  # strictly falls as amplitude rises
    assert float(err[0] / err[-1]) > 5


def test_fpn_is_periodic_at_configured_frequencies_and_fixed():
    h, w, frames = 8, 60, 3
    scene = Scene(torch.full((1, 1, h, w), 2.0), torch.full((1, 1, h, w), 0.1))
    cam = Camera(integration_time=100e-6)
    fpn = ReadoutFPN(random_offset=0.0, random_gain=0.0)
    clean = Simulation(cam, [Photons(), ADC(quantize=False)]).run(scene, frames)
    out = Simulation(cam, [Photons(), fpn, ADC(quantize=False)]).run(scene, frames)
    err = out.depth - clean.depth
    torch.testing.assert_close(err[0], err[1])  # fixed: the same in every frame
    profile = err[0, 0].mean(dim=0).numpy()
    assert np.allclose(err[0, 0].numpy(), profile[None, :], atol=1e-6)  # column stripes
    spec = np.abs(np.fft.rfft(profile - profile.mean())) ** 2
    bins = [round(w / 3), w // 2]  # 2 pi / 3 and pi
    assert spec[bins].sum() / spec.sum() > 0.99
    rows = dataclasses.replace(fpn, axis="rows")
    out_r = Simulation(cam, [Photons(), rows, ADC(quantize=False)]).run(scene)
    err_r = (out_r.depth - clean.depth[:1])[0, 0]
    assert float(err_r.std(dim=1).max()) < 1e-6 < float(err_r.std(dim=0).max())


def test_fpn_parameters_are_differentiable():
    scene = Scene(torch.full((1, 1, 4, 12), 2.0), torch.full((1, 1, 4, 12), 0.2))
    a = torch.tensor(30.0, requires_grad=True)
    fpn = ReadoutFPN(offset_amplitudes=(a, 10.0), random_offset=0.0, random_gain=0.0)
    out = Simulation(Camera(), [Photons(), fpn, ADC(quantize=False)]).run(scene)
    out.amplitude.sum().backward()
    assert a.grad is not None and float(a.grad.abs()) > 0


# ----------------------------------------------------------------------------- terms, API


def test_impulsive_pixels_rate_and_modes():
    scene = synthetic_scene(48, 48, seed=1)
    sim = Simulation(Camera(integration_time=200e-6))
    sim.term("impulsive").rate = 0.1
    out = sim.run(scene, frames=4, seed=0)
    share = out.impulsive.float().mean().item()
    assert abs(share - 0.1) < 0.02
    sim.set_parameters(**{"impulsive.mode": "dead"})
    out = sim.run(scene, frames=2, seed=0)
    assert bool((out.depth[out.impulsive] == 0).all())
    assert bool((out.amplitude[out.impulsive] == 0).all())
    sim.term("impulsive").persistent = True
    out = sim.run(scene, frames=3, seed=0)
    assert torch.equal(out.impulsive[0], out.impulsive[2])


def test_adc_quantises_and_flags_saturation():
    cam = Camera(integration_time=2e-3, ambient_irradiance=0.0)
    near = Scene(torch.full((1, 1, 4, 4), 0.3), torch.ones((1, 1, 4, 4)))
    far = Scene(torch.full((1, 1, 4, 4), 6.0), torch.full((1, 1, 4, 4), 0.1))
    out_near = Simulation(cam).run(near)
    out_far = Simulation(cam).run(far)
    assert bool(out_near.saturated.all()) and not bool(out_far.saturated.any())
    s = out_far.samples
    assert torch.equal(s, torch.round(s)) and float(s.min()) >= 0
    assert float(out_near.samples.max()) <= cam.max_code


def test_seeded_reproducible_batched_and_dtype():
    scene = synthetic_scene(32, 40, seed=3, batch=2, dtype=torch.float64)
    a = simulate(scene, frames=3, seed=11)
    b = simulate(scene, frames=3, seed=11)
    c = simulate(scene, frames=3, seed=12)
    assert torch.equal(a.samples, b.samples) and not torch.equal(a.samples, c.samples)
    assert a.depth.shape == (6, 1, 32, 40) and a.depth.dtype == torch.float64
    # frame f of scene b sits at b * frames + f: scene 1's frames differ from scene 0's
    assert float((a.depth[3] - a.depth[0]).abs().mean()) > 0.1


def test_parameters_roundtrip():
    sim = Simulation()
    p = sim.parameters()
    assert p["camera.modulation_frequency"] == 20e6 and "readout_fpn.offset_amplitudes" in p
    sim.set_parameters(**{"camera.integration_time": 50e-6, "readout_fpn.random_offset": 3.0})
    assert sim.camera.integration_time == 50e-6 and sim.term("readout_fpn").random_offset == 3.0
    with pytest.raises(ValueError, match="unknown parameter"):
        sim.set_parameters(**{"camera.nope": 1})
    with pytest.raises(ValueError, match="no term named"):
        sim.term("wiggling")


@pytest.mark.parametrize(
    "kwargs, match",
    [
        ({"n_phases": 3}, "n_phases"),
        ({"n_phases": 4.0}, "n_phases"),
        ({"modulation_frequency": 0.0}, "modulation_frequency"),
        ({"modulation_frequency": -1e6}, "modulation_frequency"),
        ({"modulation_frequency": float("nan")}, "modulation_frequency"),
        ({"adc_bits": 0}, "adc_bits"),
        ({"integration_time": -1e-6}, "integration_time"),
        ({"integration_time": 0.0}, "integration_time"),
        ({"illumination_power": -0.1}, "illumination_power"),
        ({"ambient_irradiance": -1.0}, "ambient_irradiance"),
        ({"read_noise": -1.0}, "read_noise"),
        ({"conversion_gain": 0.0}, "conversion_gain"),
        ({"full_well": 0.0}, "full_well"),
    ],
)
def test_impossible_camera_settings(kwargs, match):
    with pytest.raises(ValueError, match=match):
        Camera(**kwargs)


def test_bad_scenes_and_terms():
    d = torch.full((1, 1, 4, 4), 2.0)
    r = torch.full((1, 1, 4, 4), 0.5)
    bad_d = d.clone()
    bad_d[0, 0, 1, 1] = float("nan")
    with pytest.raises(ValueError, match="finite"):
        Scene(bad_d, r)
    with pytest.raises(ValueError, match="> 0"):
        Scene(-d, r)
    with pytest.raises(ValueError, match="reflectance"):
        Scene(d, torch.zeros_like(r))
    with pytest.raises(ValueError, match="frames"):
        Simulation().run(Scene(d, r), frames=0)
    with pytest.raises(ValueError, match="frequencies"):
        ReadoutFPN(frequencies=(0.0, math.pi))
    with pytest.raises(ValueError, match="one entry per frequency"):
        ReadoutFPN(offset_amplitudes=(1.0,))
    with pytest.raises(ValueError, match="rate"):
        ImpulsivePixels(rate=1.5)
    with pytest.raises(ValueError, match="modulation_contrast"):
        Photons(modulation_contrast=0.0)
    with pytest.raises(ValueError, match="unique"):
        Simulation(Camera(), [Photons(), Photons()])
    with pytest.raises(ValueError, match="> 0"):
        loglog_slope(torch.tensor([1.0, 0.0]), torch.tensor([1.0, 2.0]))
