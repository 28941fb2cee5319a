"""The form-shifted generator (benchmarks/form_shifted_generator.py) plants what it states."""

from __future__ import annotations

import math

import form_shifted_generator as g
import numpy as np
import pytest

H, W, T = 48, 64, 8


def _scene(kind="steps", seed=3):
    return g.scene_model(kind, H, W, seed)


def _diff(effect, form, m, kind="steps", seed=3, frames=T, **kw):
    """Noise-free (effect, null) pair on the same scene and seed, without the base column FPN
    (its fixed phasor would bend the comparison on dark pixels)."""
    kw.setdefault("fpn", (0.0, 0.0))
    d, r, info = _scene(kind, seed)
    a = g.noise_free(
        d, r, effect=effect, form=form, magnitude=m, frames=frames, seed=seed, info=info, **kw
    )
    n = g.noise_free(d, r, frames=frames, seed=seed, info=info, **kw)
    return a, n, d, r


def _wrap(x):
    r = g.Camera().range_m
    return np.mod(x + r / 2, r) - r / 2


@pytest.mark.parametrize("kind", g.SCENES)
def test_scene_models_are_valid_and_deterministic(kind):
    r_max = g.Camera().range_m
    for seed in (0, 1, 2):
        d, rho, info = g.scene_model(kind, H, W, seed)
        assert d.shape == rho.shape == (H, W)
        assert np.isfinite(d).all() and d.min() > 0.3 and d.max() < 0.9 * r_max
        assert rho.min() >= 0.05 and rho.max() <= 0.95
        assert np.isclose(np.linalg.norm(info["floor_normal"]), 1.0)
        assert np.std(d) > 0.2  # not a flat card
        assert g._edge_neighbour(d)[1].mean() > 0.003  # depth edges for flying pixels
        d2, rho2, _ = g.scene_model(kind, H, W, seed)
        assert np.array_equal(d, d2) and np.array_equal(rho, rho2)
    other = g.scene_model(kind, H, W, 7)[0]
    assert not np.array_equal(other, g.scene_model(kind, H, W, 0)[0])


def test_generate_is_deterministic_and_null_reads_the_scene():
    d, r, info = _scene("corner", 1)
    a = g.generate(d, r, frames=T, seed=5, info=info)
    b = g.generate(d, r, frames=T, seed=5, info=info)
    c = g.generate(d, r, frames=T, seed=6, info=info)
    assert np.array_equal(a["raw"], b["raw"]) and np.array_equal(
        a["depth"], b["depth"], equal_nan=True
    )
    assert not np.array_equal(a["raw"], c["raw"])
    assert a["raw"].shape == (T, 4, H, W) and a["truth"]["effect"] is None
    err = np.nanmedian(a["depth"], axis=0) - d
    assert np.median(np.abs(err)) < 0.05  # the null reads the scene (only noise and base FPN)
    assert a["meta"]["modulation_frequency_hz"] == 20e6 and a["meta"]["n_phases"] == 4


@pytest.mark.parametrize("kind", g.SCENES)
def test_null_recordings_read_every_scene(kind):
    d, r, info = _scene(kind, 4)
    out = g.generate(d, r, frames=T, seed=2, info=info)
    assert np.isnan(out["depth"]).mean() < 0.001
    err = np.nanmedian(out["depth"], axis=0) - d
    assert np.median(np.abs(err)) < 0.05 and np.abs(err).max() < 0.75
    assert out["truth"]["effect"] is None and "snr" not in out["truth"]


@pytest.mark.parametrize("form", g.FORMS)
def test_amplitude_bias_follows_its_form_and_falls_with_amplitude(form):
    a, n, d, r = _diff("amplitude_bias", form, 40.0)
    bias = _wrap(a["depth"] - n["depth"]).mean(0) * 1e3
    cam = g.Camera()
    amp = cam.contrast * cam.k_sig * r / d**2  # active amplitude, e-
    if form == "A":
        want = 40.0 * np.exp(-amp / np.quantile(amp, 0.2))
    else:
        lo, hi = np.log(np.quantile(amp, 0.05)), np.log(np.quantile(amp, 0.6))
        want = 40.0 * np.clip((hi - np.log(amp)) / (hi - lo), 0, 1)
    assert np.abs(bias - want).max() < 0.01  # mm
    weak, strong = amp < np.quantile(amp, 0.05), amp > np.quantile(amp, 0.7)
    assert bias[weak].mean() > 5 * max(bias[strong].mean(), 0.1)
    assert bias.max() > (25 if form == "A" else 39)


@pytest.mark.parametrize("form", g.FORMS)
def test_cyclic_error_peak_to_peak_over_a_depth_sweep(form):
    r = g.Camera().range_m
    d = np.tile(np.linspace(0.5, 0.5 + r, 400, endpoint=False), (4, 1))
    rho = np.full_like(d, 0.9)
    kw = dict(effect="cyclic_error", form=form, magnitude=30.0, frames=1, seed=4)
    a = g.noise_free(d, rho, **kw)
    n = g.noise_free(d, rho, frames=1, seed=4)
    err = _wrap(a["depth"] - n["depth"])[0, 0] * 1e3
    assert math.isclose(np.ptp(err), 30.0, rel_tol=0.08)
    spec = np.abs(np.fft.rfft(err - err.mean()))
    top = int(np.argmax(spec))
    assert top == (4 if form == "A" else 2)  # A: 4 periods over the range (N = 4); B: R / 2
    if form == "A":
        assert math.isclose(a["truth"]["peak_to_peak_mm"], 30.0, rel_tol=0.02)


def test_fpn_pattern_forms_have_their_structure():
    a, n, *_ = _diff("fpn_pattern", "A", 10.0)
    delta = _wrap(a["depth"] - n["depth"]).mean(0) * 1e3
    assert np.abs(delta - delta.mean(0)).max() < 0.05  # one delay per column
    assert math.isclose(np.sqrt(np.mean(delta[0] ** 2)), 10.0, rel_tol=0.05)
    p = np.abs(np.fft.rfft(delta[0])) ** 2
    assert p[1:5].mean() > 4 * p[-8:].mean()  # 1/f: low frequencies dominate
    a, n, *_ = _diff("fpn_pattern", "B", 10.0)
    delta = _wrap(a["depth"] - n["depth"]).mean(0) * 1e3
    for y0 in (0, H // 2):
        for x0 in range(0, W, 8):
            blk = delta[y0 : y0 + H // 2, x0 : x0 + 8]
            assert np.ptp(blk) < 0.05  # one offset per 8-column group and half
    assert np.abs(delta[: H // 2].mean() - delta[H // 2 :].mean()) > 0.01


@pytest.mark.parametrize("form", g.FORMS)
def test_readout_pattern_is_fixed_additive_and_not_scaled_by_light(form):
    d, r, info = _scene("solids", 2)
    kw = dict(effect="readout_pattern", form=form, magnitude=20.0, frames=3, seed=9, info=info)
    off = (
        g.noise_free(d, r, **kw)["samples"]
        - g.noise_free(d, r, frames=3, seed=9, info=info)["samples"]
    )
    assert np.allclose(off, off[:1])  # the same in every frame
    dark = (
        g.noise_free(d, r * 0.2, **kw)["samples"]
        - g.noise_free(d, r * 0.2, frames=3, seed=9, info=info)["samples"]
    )
    assert np.allclose(off, dark)  # additive, not scaling with the light
    z = np.tensordot(np.exp(1j * g.Camera().thetas), off[0], axes=(0, 0)) * 2 / 4
    assert math.isclose(np.sqrt(np.mean(np.abs(z) ** 2)), 20.0, rel_tol=1e-6)
    smooth = z.mean(0, keepdims=True) if form == "A" else z
    if form == "A":  # column part + strong pixel part
        share = np.mean(np.abs(z - smooth) ** 2) / np.mean(np.abs(z) ** 2)
        assert 0.3 < share < 0.7
    else:  # blobs + pixel part: neighbouring pixels differ by about the pixel part
        step = np.mean(np.abs(np.diff(z, axis=1)) ** 2) / np.mean(np.abs(z) ** 2)
        assert 0.5 < step < 1.5


def test_pixel_gain_forms():
    a, n, *_ = _diff("pixel_gain", "A", 0.05)
    ratio = (a["amplitude"] / n["amplitude"]).mean(0)
    assert math.isclose(ratio.std(), 0.05, rel_tol=0.35)
    x, y = ratio[:, :-1] - 1, ratio[:, 1:] - 1
    assert np.corrcoef(x.ravel(), y.ravel())[0, 1] > 0.8  # smooth blotches, not i.i.d.
    a, n, *_ = _diff("pixel_gain", "B", 0.3)
    ratio = (a["amplitude"] / n["amplitude"]).mean(0)
    levels = np.unique(np.round(ratio, 6))
    assert set(levels) <= {0.7, 1.0} and len(levels) == 2
    weak = ratio < 0.85
    assert weak.any(axis=1).sum() >= 2 and weak.mean() == pytest.approx(a["truth"]["weak_share"])


@pytest.mark.parametrize("form", g.FORMS)
def test_impulsive_pixels(form):
    d, r, info = _scene("corner", 0)
    kw = dict(frames=16, seed=11, info=info)
    out = g.generate(d, r, effect="impulsive_pixels", form=form, magnitude=0.01, **kw)
    null = g.generate(d, r, **kw)
    assert math.isclose(out["truth"]["share_frame_pixels"], 0.01, rel_tol=0.4)
    changed = np.any(out["raw"] != null["raw"], axis=1)  # same noise stream until the impulses
    assert math.isclose(changed.mean(), out["truth"]["share_frame_pixels"], rel_tol=0.1)
    if form == "A":  # salt: fixed pixels, a constant code when they fire
        hot = changed.any(axis=0)
        assert math.isclose(hot.mean(), out["truth"]["hot_pixel_share"], rel_tol=0.1)
        y, x = np.argwhere(changed.sum(0) >= 2)[0]
        fired = out["raw"][changed[:, y, x], :, y, x]
        assert np.all(fired == fired[0])
    else:  # bursts: line segments in single frames
        t, y, x = np.argwhere(changed)[0]
        assert changed[t, y, x : x + 4].all() or changed[t, y : y + 4, x].all()


@pytest.mark.parametrize("form", g.FORMS)
def test_saturation_share_and_it_rises_with_reflectance(form):
    d, r, info = _scene("steps", 4)
    out = g.generate(
        d, r, effect="saturation", form=form, magnitude=0.03, frames=T, seed=2, info=info
    )
    tr = out["truth"]
    assert math.isclose(tr["share_pixel_frames_over"], 0.03, rel_tol=0.5)
    over = (
        g.noise_free(
            d, r, effect="saturation", form=form, magnitude=0.03, frames=1, seed=2, info=info
        )["samples"][0].max(0)
        >= tr["level_e"] * 0.999
    )
    assert r[over].mean() > r.mean() and d[over].mean() < d.mean()  # bright, near surfaces
    top = out["raw"].max() * g.Camera().gain
    if form == "A":
        assert top <= tr["level_e"] + g.Camera().gain
    else:
        assert top <= tr["level_e"] * (1 + g.KNEE_SOFT) + g.Camera().gain
        assert top > tr["level_e"]  # compressed, not clipped


def test_flying_pixels_a_lies_between_the_two_sides():
    a, n, d, r = _diff("flying_pixels", "A", 1.0, kind="solids", seed=1)
    nb, edge, _ = g._edge_neighbour(d)
    dd = a["depth"][0]
    own, other = d, d.reshape(-1)[nb]
    lo, hi = np.minimum(own, other) - 1e-3, np.maximum(own, other) + 1e-3
    moved = np.abs(_wrap(dd - n["depth"][0])) > 1e-4
    assert moved.any() and not (moved & ~edge).any()  # only edge pixels move
    assert ((dd >= lo) & (dd <= hi))[moved].all()
    assert math.isclose(a["truth"]["mixed_share"], edge.mean(), rel_tol=0.05)  # magnitude 1: all


def test_flying_pixels_b_footprint_area_fractions():
    w = g._box_weights(1.0, 0.0)
    assert np.allclose(w, [0.25, 0.5, 0.25])
    w = g._box_weights(0.5, 0.25)
    assert np.allclose(w, np.array([0.0, 1.0, 0.5]) / 1.5)
    a, n, d, r = _diff("flying_pixels", "B", 0.6, kind="steps", seed=2)
    _, edge, _ = g._edge_neighbour(d)
    delta = np.abs(_wrap(a["depth"] - n["depth"]))[0]
    assert delta[edge].mean() > 8 * delta[~edge].mean()  # the footprint shows at depth edges


def test_multipath_forms():
    a, n, d, r = _diff("multipath", "A", 0.2, kind="corner", seed=1)
    delta = _wrap(a["depth"] - n["depth"])[0]
    info = g.scene_model("corner", H, W, 1)[2]
    p = d[..., None] * g.rays(H, W)
    on_floor = np.abs(p @ np.asarray(info["floor_normal"]) - info["floor_m"]) < 0.01
    assert np.abs(delta[on_floor]).max() < 1e-6 and np.abs(delta[~on_floor]).max() > 0.01
    assert (delta[~on_floor] > -1e-6).mean() > 0.95  # a longer path: reads farther
    a, n, d, r = _diff("multipath", "B", 0.05, kind="steps", seed=2)
    relay = (a["samples"] - n["samples"]).mean(axis=(0, 1))  # relayed offset, e- per sample
    sig = g.Camera().k_sig * r / d**2
    y0, x0 = a["truth"]["patch_yx"]
    out = np.ones_like(d, bool)
    out[y0 : y0 + g.PATCH_PX, x0 : x0 + g.PATCH_PX] = False
    assert math.isclose(np.median((relay / sig)[out]), 0.05, rel_tol=1e-6)


def test_noise_floor_raises_the_depth_noise_as_stated():
    d, r, info = _scene("polygons", 3)
    kw = dict(frames=40, seed=8, info=info)
    null = g.generate(d, r, **kw)["depth"]
    for form in g.FORMS:
        out = g.generate(d, r, effect="noise_floor", form=form, magnitude=60.0, **kw)
        excess = np.nanvar(out["depth"], axis=0) - np.nanvar(null, axis=0)
        assert math.isclose(np.sqrt(max(np.nanmedian(excess), 0)) * 1e3, 60.0, rel_tol=0.35)
        if form == "B":
            col = np.nanmedian(excess, axis=0) * 1e6  # mm^2
            want = np.asarray(out["truth"]["column_sd_mm"]) ** 2
            assert np.corrcoef(col, want)[0, 1] > 0.8  # the noise floor follows the columns
            assert np.ptp(want) > np.median(want)


def test_noise_floor_a_is_heavy_tailed():
    x = g._jitter({"frames": 200, "d": np.ones((20, 20))}, "A", 10.0, np.random.default_rng(0))[0]
    x = x.ravel() * 1e3
    assert math.isclose(x.std(), 10.0, rel_tol=0.15)
    kurt = np.mean((x - x.mean()) ** 4) / x.var() ** 2
    assert kurt > 5  # Gaussian: 3


@pytest.mark.parametrize("form", g.FORMS)
def test_phase_wrapping_share_beyond_range_reads_near(form):
    d, r, info = _scene("corner", 2)
    out = g.generate(
        d, r, effect="phase_wrapping", form=form, magnitude=0.05, frames=T, seed=1, info=info
    )
    rng_m = g.Camera().range_m
    sd = out["scene_depth"]
    assert math.isclose((sd >= rng_m).mean(), 0.05, rel_tol=0.15)
    beyond = sd >= rng_m + 0.3
    reads = np.nanmedian(out["depth"], axis=0)
    assert np.nanmedian(reads[beyond]) < 0.5 * rng_m  # folded to the near side
    assert (sd < rng_m).mean() > 0.9


@pytest.mark.parametrize("form", g.FORMS)
def test_temporal_drift_shapes(form):
    a, n, *_ = _diff("temporal_drift", form, 12.0, frames=24)
    frame = _wrap(a["depth"] - n["depth"]).mean(axis=(1, 2)) * 1e3
    assert math.isclose(np.ptp(frame), 12.0, rel_tol=0.02)
    if form == "B":
        k = a["truth"]["step_frame"]
        assert 8 <= k <= 16 and np.allclose(frame[:k], 0, atol=1e-3)
        assert np.allclose(frame[k:], 12.0, atol=1e-3)
    else:  # 1.5 periods: three turning points' worth of sign changes in the slope
        slope = np.sign(np.diff(frame))
        assert 2 <= np.sum(slope[1:] != slope[:-1]) <= 3


@pytest.mark.parametrize("form", g.FORMS)
def test_vignetting_forms(form):
    a, n, *_ = _diff("vignetting", form, 0.2)
    ratio = (a["amplitude"] / n["amplitude"]).mean(0)
    assert math.isclose(ratio.min(), 0.8, abs_tol=0.01) and ratio.max() <= 1 + 1e-9
    lossy = ratio < 0.99
    if form == "A":
        assert lossy.mean() > 0.5  # a broad fall-off
    else:  # one dark corner sector
        assert lossy.mean() < 0.2
        corners = [
            lossy[:5, :5].any(),
            lossy[:5, -5:].any(),
            lossy[-5:, :5].any(),
            lossy[-5:, -5:].any(),
        ]
        assert sum(corners) == 1


def test_snr_scales_with_magnitude_and_truth_is_complete():
    d, r, info = _scene("steps", 1)
    for e in ("fpn_pattern", "cyclic_error", "vignetting"):
        m = 0.05 if e == "vignetting" else 10.0
        one, two = (
            g.generate(d, r, effect=e, form="B", magnitude=k * m, frames=T, seed=3, info=info)
            for k in (1, 2)
        )
        assert math.isclose(two["truth"]["snr"], 2 * one["truth"]["snr"], rel_tol=0.1)
        keys = {"effect", "form", "magnitude", "effect_size", "effect_size_unit", "expected_name"}
        assert keys <= set(one["truth"])
    assert g.EXPECTED["readout_pattern"] == "fpn_pattern"
    with pytest.raises(ValueError):
        g.generate(d, r, effect="nonsense", magnitude=1.0)
    with pytest.raises(ValueError):
        g.generate(d, r, effect="multipath", form="C", magnitude=1.0)
