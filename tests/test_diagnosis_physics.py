"""The diagnosis names the physics whatever its form: a real sensor's per-pixel phase-offset map
(``fpn_pattern``), a clip of the raw samples seen in the samples themselves (``saturation``), a
delay carried by the weakest pixels only (``amplitude_bias``); and a structure that no single
term explains is reported as ``unexplained`` with how sure the verdict is."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import torch

from tof_fpn_torch import constants as K
from tof_fpn_torch.diagnosis import diagnose
from tof_fpn_torch.io import Recording, read_kinect_v2_p0

DATA = Path(__file__).parent / "data" / "real"
P0 = DATA / "kinect_v2_p0" / "p0tables_3x424x512_u16le.dat"


def _p0_fine_map(h: int, w: int, frequency: float, rms_m: float) -> torch.Tensor:
    """The fine structure of a real Kinect v2 phase-offset table (80 MHz plane, one row parity:
    the two parities differ by half a turn), a crop of ``h x w`` with its smooth part (31 x 31
    px mean of the phasor) removed, as delays (m) at ``frequency`` scaled to ``rms_m``."""
    t = read_kinect_v2_p0(P0)[0, 0].double().numpy()[0::2]  # (212, 512) rad
    z = np.exp(1j * t)
    r0, c0 = (t.shape[0] - h) // 2, (t.shape[1] - w) // 2
    pad = 15
    big = z[r0 - pad : r0 + h + pad, c0 - pad : c0 + w + pad]
    k = np.ones(2 * pad + 1) / (2 * pad + 1)
    sm = np.apply_along_axis(lambda x: np.convolve(x, k, "valid"), 0, big)
    sm = np.apply_along_axis(lambda x: np.convolve(x, k, "valid"), 1, sm)
    fine = np.angle(z[r0 : r0 + h, c0 : c0 + w] * np.conj(sm))
    m = fine * K.SPEED_OF_LIGHT_AIR / (4 * math.pi * frequency)
    m = m - m.mean()
    return torch.from_numpy(m * (rms_m / m.std()))


@pytest.mark.slow
def test_a_real_per_pixel_phase_map_is_named_fpn_pattern():
    """A real per-pixel phase-offset map (the Kinect v2 table's fine structure, 6 mm rms),
    added to the depths, is named ``fpn_pattern`` alone, its per-pixel member holding the pixel
    part at about its size."""
    from test_diagnosis import META, _recording

    rec, scene = _recording(seed=6)
    f = float(META["modulation_frequency_hz"])
    m = _p0_fine_map(*rec.depth.shape[-2:], f, 6e-3)
    col = m.mean(0)  # the map has a column part and a larger part per pixel
    pix = m - col.view(1, -1) - m.mean(1).view(-1, 1) + m.mean()
    assert float(col.std()) > 0.1 * float(m.std()) and float(pix.std()) > 0.5 * float(m.std())
    depth = rec.depth + m.view(1, 1, *m.shape).to(rec.depth.dtype)
    out = diagnose(Recording(depth, rec.amplitude, rec.meta), scene, replicates=0)
    assert out.report["verdict"] == ["fpn_pattern"], out.report["verdict"]
    e = out.report["effects"][0]
    assert "fpn_pixel_delays" in e["terms"]
    assert 3.0 < e["params"]["pixel_delay_rms_mm"] < 9.0


def _weak_bias(rec, delay_m: float, quantile: float) -> torch.Tensor:
    """``delay_m exp(-A / A0)`` per pixel, ``A`` the pixel's median amplitude and ``A0`` its
    ``quantile`` over the pixels: a bias the weakest few per cent of the pixels carry."""
    a = rec.amplitude.double().nanmedian(0).values[0]
    a0 = float(torch.quantile(a[torch.isfinite(a)], quantile))
    return delay_m * torch.exp(-a / a0)


def test_the_shape_member_starts_from_a_bias_of_the_weakest_pixels():
    """A delay ``b exp(-A / A0)`` (30 mm as A -> 0, ``A0`` the 5th percentile of the amplitude:
    the weakest few per cent of the pixels carry it) on the test recording: the shape member's
    best start (least squares on the depth residuals of the baseline) has its knots in the
    weakest pixels and fits the bias better than the starts spread over the amplitudes."""
    from test_diagnosis import _recording

    from tof_fpn_torch.diagnosis.data import observe
    from tof_fpn_torch.diagnosis.fit import init_model
    from tof_fpn_torch.diagnosis.likelihood import make_context
    from tof_fpn_torch.diagnosis.prediction import predict
    from tof_fpn_torch.diagnosis.terms.amplitude_bias_shape import (
        AmplitudeBiasShapeTerm,
        node_delays,
    )
    from tof_fpn_torch.diagnosis.terms.base import depth_residuals

    rec, scene = _recording(seed=6)
    b = _weak_bias(rec, 0.03, 0.05)
    depth = rec.depth + b.view(1, 1, *b.shape).to(rec.depth.dtype)
    obs = observe(Recording(depth, rec.amplitude, rec.meta), scene)
    model = init_model(obs, obs.scene())
    with torch.no_grad():
        p = predict(model, obs)
    ctx = make_context(obs, p.a0 / p.s)
    term = AmplitudeBiasShapeTerm()
    rd, wd = depth_residuals(obs, ctx, p)
    a_e = (p.a0 * model.values["camera.conversion_gain"])[ctx.mask_d]
    sse = []
    for v in term.initial_values(model, obs, ctx, p):
        fit = term.simulator_term(v, model).bias(a_e)
        sse.append((float((wd * (rd - fit) ** 2).sum()), v))
        assert node_delays(v)[0] == pytest.approx(v["amplitude_bias_shape.delay"])
    best = min(sse, key=lambda t: t[0])
    weakest = float(torch.quantile(a_e, 0.005))
    assert best[1]["amplitude_bias_shape.knot0"] == pytest.approx(weakest, rel=1e-6)
    spread = [e for e, v in sse if v["amplitude_bias_shape.knot0"] > 1.001 * weakest]
    assert spread and best[0] < min(spread)


def _stat(key: str, significant: bool):
    from tof_fpn_torch.diagnosis.locate import Stat

    s = Stat(key, 100.0 if significant else 1.0, 1.0)
    s.significant = significant
    s.p = 1e-9 if significant else 0.5
    return s


def test_a_term_that_does_not_explain_its_own_structure_is_held_back_as_unexplained():
    """Three effects named at once: the first is named; a further one whose own statistic is
    as far above its null after the refit as before (it removed none of it) stood in for a part
    of a structure it does not explain, and goes under ``unexplained`` (the verdict says so, and
    how sure it is); one that cleared its own statistic is named."""
    from tof_fpn_torch.diagnosis.summary import confidence, hold_back, on_its_own

    keys = ("depth_mean|pixels", "depth_mean|depth_mod", "amp_mean|radius", "depth_mean|edge")
    before = {k: _stat(k, True) for k in keys}
    after = {
        "depth_mean|pixels": _stat("depth_mean|pixels", False),  # fpn_pixel_delays' axis
        "depth_mean|depth_mod": _stat("depth_mean|depth_mod", True),  # cyclic_error's: still
        "amp_mean|radius": _stat("amp_mean|radius", False),  # vignetting's: cleared
        "depth_mean|edge": _stat("depth_mean|edge", True),
    }
    effects = [
        {"name": "fpn_pattern", "terms": ["fpn_pixel_delays"], "score": 900.0},
        {"name": "cyclic_error", "terms": ["cyclic_error"], "score": 40.0},
        {"name": "vignetting", "terms": ["vignetting"], "score": 30.0},
    ]
    assert not on_its_own(effects[1], before, after)
    assert on_its_own(effects[2], before, after)
    named, held = hold_back(effects, before, after)
    assert [e["name"] for e in named] == ["fpn_pattern", "vignetting"]
    assert [e["name"] for e in held] == ["cyclic_error"]
    first = [
        {"name": "fpn_pixel_delays", "score": 900.0},
        {"name": "multipath", "score": 300.0},
        {"name": "cyclic_error", "score": 200.0},
    ]
    conf = confidence(named, held, [first], before, after)
    assert conf["runner_up"] == "multipath" and conf["runner_up_share"] == pytest.approx(
        1 / 3, abs=1e-4
    )
    assert conf["held_back"] == ["cyclic_error"]
    assert conf["level"] == "moderate"  # its structure explained, something else left
    # a close runner-up makes it low; a clear one with nothing left makes it high
    first[1]["score"] = 850.0
    assert confidence(named, [], [first], before, after)["level"] == "low"
    first[1]["score"] = 100.0
    clean = {k: _stat(k, False) for k in keys}
    assert confidence(named[:1], [], [first], before, clean)["level"] == "high"
    # a single effect is never held back
    assert hold_back(effects[1:2], before, after) == (effects[1:2], [])


def _stat_at(key: str, excess: float, significant: bool):
    """A located statistic of 12 bins ``excess`` null sds above its (analytic) null mean."""
    from tof_fpn_torch.diagnosis.locate import Stat

    s = Stat(key, 12.0 + excess * math.sqrt(24.0), 12.0)
    s.significant = significant
    s.p = 1e-9 if significant else 0.5
    return s


def test_a_term_that_removes_most_of_a_structure_is_named_though_some_is_left():
    """A glossy patch's light against the catalogue's relay (the excess of the located
    statistics, in null sds, of a planted patch's diagnosis): the multipath term removes about
    three quarters of the amplitude misfit along the amplitude that is there without it; the
    rest (its form's misfit) stays significant. It explains that structure on its own and is
    named. A term on an axis whose structure another named term removed (it is barely there
    with that term in the model and the stand-in dropped) is credited with nothing and held
    back, though the axis went from significant to cleared since the baseline."""
    from tof_fpn_torch.diagnosis.summary import (
        OWN_SHARE,
        confidence,
        explained_share,
        hold_back,
        on_its_own,
    )

    before = {
        "depth_mean|depth": _stat_at("depth_mean|depth", 1030.0, True),
        "depth_mean|depth_mod": _stat_at("depth_mean|depth_mod", 169.0, True),
        "amp_mean|amplitude": _stat_at("amp_mean|amplitude", 732.0, True),
        "depth_mean|amplitude": _stat_at("depth_mean|amplitude", 465.0, True),
        "amp_mean|pixels": _stat_at("amp_mean|pixels", 199.0, True),
    }
    after = {
        "depth_mean|depth": _stat_at("depth_mean|depth", 106.0, True),
        "depth_mean|depth_mod": _stat_at("depth_mean|depth_mod", 83.0, True),
        "amp_mean|amplitude": _stat_at("amp_mean|amplitude", 21.0, True),
        "depth_mean|amplitude": _stat_at("depth_mean|amplitude", 427.0, True),
        "amp_mean|pixels": _stat_at("amp_mean|pixels", -0.2, False),
    }
    # the final model without multipath (the rest refitted): the amplitude misfit is back
    without_mp = dict(after)
    without_mp["amp_mean|amplitude"] = _stat_at("amp_mean|amplitude", 91.0, True)
    without_mp["depth_mean|depth"] = _stat_at("depth_mean|depth", 110.0, True)
    without_mp["depth_mean|amplitude"] = _stat_at("depth_mean|amplitude", 365.0, True)
    mp = {"name": "multipath", "terms": ["multipath_sources"], "score": 1068.0}
    share = explained_share(mp, without_mp, after)
    assert share == pytest.approx((91.0 - 21.0) / 91.0, rel=1e-6)
    assert share >= OWN_SHARE
    assert on_its_own(mp, before, after, without_mp)
    # ... without it, the depth along the depth: multipath removes 4 % of it (cyclic_error
    # does the rest); alone it would not make multipath's own structure
    assert explained_share(mp, without_mp, after, {"depth_mean|depth"}) < 0.05
    # a stand-in on the depth along the depth: cleared since the baseline, but the cyclic
    # error removed it (not significant without the stand-in): held back, as a stand-in that
    # removes a small part of what is there without it
    after["depth_mean|depth"] = _stat_at("depth_mean|depth", 1.0, False)
    without_ab = dict(after)
    without_ab["depth_mean|depth"] = _stat_at("depth_mean|depth", 1.5, False)
    ab = {"name": "phase_wrapping", "terms": ["phase_wrapping"], "score": 40.0}
    assert on_its_own(ab, before, after)  # against the baseline it took the whole structure
    assert not on_its_own(ab, before, after, without_ab)
    part = dict(after, **{"depth_mean|depth": _stat_at("depth_mean|depth", 25.0, True)})
    without_part = dict(part, **{"depth_mean|depth": _stat_at("depth_mean|depth", 30.0, True)})
    assert not on_its_own(ab, before, part, without_part)  # a sixth of it
    ce = {"name": "cyclic_error", "terms": ["cyclic_error_series", "cyclic_error"], "score": 1336}
    pg = {"name": "pixel_gain", "terms": ["pixel_gain"], "score": 651.0}
    effects = [ce, mp, pg, ab]
    without = {"multipath": without_mp, "phase_wrapping": without_ab}
    named, held = hold_back(effects, before, after, without)
    assert [e["name"] for e in named] == ["cyclic_error", "multipath", "pixel_gain"]
    assert [e["name"] for e in held] == ["phase_wrapping"]
    first = [{"name": "cyclic_error_series", "score": 1336.0}, {"name": "multipath", "score": 993}]
    conf = confidence(named, held, [first], before, after, without)
    assert conf["explains_its_structure"] and conf["level"] == "moderate"


def test_the_report_says_unexplained_and_how_sure():
    """``report.md`` gives the verdict with its confidence and the structure held back."""
    from tof_fpn_torch.diagnosis.report import markdown

    rep = {
        "recording": {
            "frames": 2,
            "height": 4,
            "width": 4,
            "scene_estimated": False,
            "notes": [],
            "depth_pixels": 16,
            "amplitude_pixels": 16,
        },
        "bootstrap_replicates": 0,
        "seconds": 1.0,
        "verdict": ["fpn_pattern", "unexplained"],
        "confidence": {
            "level": "moderate",
            "runner_up": "multipath",
            "runner_up_share": 0.33,
            "explains_its_structure": True,
            "residual_statistics": ["depth_mean|depth_mod"],
            "held_back": ["cyclic_error"],
        },
        "held_back": [
            {
                "stood_in_by": "cyclic_error",
                "terms": ["cyclic_error"],
                "score": 40.0,
                "structure": [],
            }
        ],
        "effects": [],
        "fit": {
            "before": dict.fromkeys(
                (
                    "heldout_nll",
                    "heldout_nll_per_observation",
                    "aic",
                    "parameters",
                    "residual_rms_depth_mm",
                    "residual_rms_amplitude_percent",
                ),
                1.0,
            ),
        },
        "unexplained": [],
        "located_before": [],
        "candidates": [],
        "not_implemented": [],
    }
    rep["fit"]["after"] = rep["fit"]["before"]
    md = markdown(rep, [])
    assert "**Verdict: fpn_pattern, unexplained**" in md
    assert "Confidence: moderate (runner-up `multipath` gains 33% as much" in md
    assert "## Unexplained: structure no single term explains" in md
    assert "stood in for by `cyclic_error`" in md


def _clipped_recording(share: float, spread: float, raw: bool, seed: int = 7):
    """The test recording's samples (DN) clipped at a full well of each pixel's own: the level
    the largest noise-free sample of a ``share`` of the pixels passes, times ``exp(spread z)``
    per pixel (``z`` standard normal), decoded again (``share`` 0: not clipped); with ``raw`` the
    samples go along."""
    from test_diagnosis import META, H, W, _sim

    from tof_fpn_torch.io import SceneData
    from tof_fpn_torch.sim import synthetic_scene
    from tof_fpn_torch.sim.camera import depth_from_samples

    scene = synthetic_scene(H, W, seed=seed, depth_range=(0.6, 5.0))
    out = _sim().run(scene, 10, seed=seed)
    s = out.samples.double()
    peak = s.mean(0).amax(0)  # (H, W) the largest mean sample
    level = float(torch.quantile(peak.flatten(), 1 - share))
    g = torch.Generator().manual_seed(seed)
    lv = torch.round(level * torch.exp(spread * torch.randn(H, W, generator=g, dtype=s.dtype)))
    if share > 0:
        s = torch.minimum(s, lv)
    depth, amp, _ = depth_from_samples(s, float(META["modulation_frequency_hz"]))
    depth = torch.where(depth > 0, depth, torch.full_like(depth, math.nan))
    rec = Recording(
        depth.float(), amp.float(), dict(META, amplitude_unit="DN"), s.float() if raw else None
    )
    sd = SceneData(scene.depth[0, 0], scene.reflectance[0, 0], meta={"source": "test"})
    return rec, sd, level


def test_raw_piles_find_the_clip_level_and_the_pixels_clipped_at_their_own():
    """The raw samples' direct evidence of a clip: a common level where samples pile up, and
    pixels whose largest sample repeats; none in an unclipped recording."""
    from tof_fpn_torch.diagnosis.data import observe
    from tof_fpn_torch.diagnosis.terms.saturation import raw_piles

    rec, sd, level = _clipped_recording(0.1, 0.0, raw=True)
    p = raw_piles(observe(rec, sd))
    assert p["level"] == pytest.approx(round(level))
    assert 0.05 < p["pixel_share"] < 0.3
    rec, sd, level = _clipped_recording(0.1, 0.05, raw=True)
    p = raw_piles(observe(rec, sd))
    assert 0.05 < p["pixel_share"] < 0.3  # each at its own level
    assert p["pixel_levels"][1] == pytest.approx(level, rel=0.1)
    rec, sd, _ = _clipped_recording(0.0, 0.0, raw=True)  # nothing clipped
    p = raw_piles(observe(rec, sd))
    assert p["level"] is None and p["pixel_share"] < 0.01
    assert raw_piles(observe(*_clipped_recording(0.1, 0.0, raw=False)[:2])) is None


@pytest.mark.slow
def test_a_full_well_of_each_pixel_is_named_saturation_from_the_raw_samples():
    """A full well that varies from pixel to pixel (5 % rms), reached by the brightest tenth of
    the pixels, with the raw samples in the recording: named ``saturation``, its level where
    the samples pile up and the piles stated in the report."""
    rec, sd, level = _clipped_recording(0.1, 0.05, raw=True)
    out = diagnose(rec, sd, replicates=0)
    assert out.report["verdict"][:1] == ["saturation"], out.report["verdict"]
    p = out.report["effects"][0]["params"]
    assert p["raw_share_of_pixels_piled_at_their_top"] > 0.05
    assert p["level_amplitude_units"] == pytest.approx(level, rel=0.1)
