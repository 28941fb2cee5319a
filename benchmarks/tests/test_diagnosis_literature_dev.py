"""The diagnosis on small recordings of the literature generator's dev part
(benchmarks/literature_generator.py): its plain camera (a Lambertian scene given as albedo,
auto-exposure, a black level, Poisson electrons at 0.5 DN/e-, ambient light, textured
reflectance) is the diagnosis' baseline, so a null is named ``none``; a planted per-pixel gain
is still named ``pixel_gain``.

A baseline without the angle of incidence takes the shading of every tilted surface of these
scenes for a pixel gain and names ``pixel_gain`` on the nulls."""

from __future__ import annotations

import bench_literature as bl
import literature_generator as lg
import pytest

from tof_fpn_torch.diagnosis import diagnose
from tof_fpn_torch.diagnosis.incidence import FOV_KEY, INCIDENCE_KEY
from tof_fpn_torch.diagnosis.prediction import predict
from tof_fpn_torch.diagnosis.run import _baseline, _fit_baseline, observe
from tof_fpn_torch.diagnosis.signature import defect_pixels, dense_share

#: small recordings: H, W, frames
SIZE = (48, 64, 8)


def _inputs(family, form, seed):
    return bl.to_inputs(lg.generate(family, form, seed, SIZE))


@pytest.mark.parametrize("seed", [27, 28])
def test_the_baseline_takes_the_generators_scene_as_albedo(seed):
    """The generator's light is ``K rho cos(theta_inc) / r^2`` through a 70 degree pinhole: the
    baseline holds the angle at about that field of view."""
    rec, scene = _inputs("none", "null", seed)
    v = _baseline(observe(rec, scene), None).values
    assert v[INCIDENCE_KEY] == 1.0
    assert abs(v[FOV_KEY] - lg.HFOV_DEG) <= 6.0


@pytest.mark.slow
@pytest.mark.parametrize("seed", [27, 28])
def test_a_null_of_the_generator_is_named_none(seed):
    """Seed 27: a table top, 28: a field of objects; nothing planted, nothing named."""
    rec, scene = _inputs("none", "null", seed)
    d = diagnose(rec, scene, seed=0)
    assert d.effects == [], d.report["effects"]


@pytest.mark.slow
def test_a_planted_pixel_gain_is_still_named():
    """White PRNU of about 3 % rms on a corridor (the weakest of the form's range): named first."""
    r = lg.generate("pixel_gain", "prnu_white", 13, SIZE)
    assert 0.03 <= r["truth"]["size"]["prnu_rms"] <= 0.04
    rec, scene = bl.to_inputs(r)
    d = diagnose(rec, scene, seed=0)
    assert d.effects[:1] == ["pixel_gain"], d.report["effects"]


def test_a_source_pattern_does_not_move_the_field_of_view():
    """The LED's radiation pattern (``cos^m`` of the field angle, about 40 % fall-off in the
    corners) on a field of objects: the field of view of the angle of incidence stays the
    camera's (a choice that lets the cosines take up the fall-off lands near 41 degrees)."""
    rec, scene = _inputs("vignetting", "led_lambertian", 18)
    v = _baseline(observe(rec, scene), None).values
    assert v[INCIDENCE_KEY] == 1.0
    assert abs(v[FOV_KEY] - lg.HFOV_DEG) <= 6.0


@pytest.mark.slow
def test_a_source_pattern_is_named_vignetting_alone():
    """... and the recording is named ``vignetting`` alone (not ``pixel_gain`` for the tilted
    surfaces' light misfit at a wrong field of view)."""
    rec, scene = _inputs("vignetting", "led_lambertian", 18)
    d = diagnose(rec, scene, seed=0)
    assert d.effects == ["vignetting"], d.report["effects"]


def _shares(family, form, seed):
    """The baseline fitted to a small recording: its defect pixels and the dense share."""
    rec, scene = _inputs(family, form, seed)
    obs = observe(rec, scene)
    base, ctx, _ = _fit_baseline(_baseline(obs, None), obs)
    pred = predict(base, obs, scene=ctx.scene)
    return defect_pixels(obs, ctx, pred), dense_share(obs, ctx, pred)


def test_hot_pixels_are_isolated_defects_not_a_dense_offset():
    """Hot pixels (a dark current of 2-20 ke- in a tap of about 0.4 % of the pixels, fixed in
    time) are far outside the spread of the other pixels' means and alone among their
    neighbours: most of the means' excess spread sits on them, so a random offset, delay or
    gain of every pixel is credited with little of it; on a null nothing is a defect."""
    hot, dense = _shares("impulsive_pixels", "hot_pixels", 15)
    assert 3 <= int(hot.sum()) <= 30
    assert dense is not None and dense < 0.2
    none, dense0 = _shares("none", "null", 27)
    assert int(none.sum()) <= 1
    assert dense0 is None or dense0 > 0.9


@pytest.mark.slow
@pytest.mark.parametrize(("form", "seed"), [("hot_pixels", 15), ("dark_rts", 16)])
def test_defect_and_telegraph_pixels_are_named_impulsive(form, seed):
    """Hot pixels fixed in time (named ``fpn_pattern`` when a random offset of every pixel was
    credited with them) and dark-current telegraph pixels that jump between two levels from
    frame to frame (named ``noise_floor``): ``impulsive_pixels`` first."""
    rec, scene = _inputs("impulsive_pixels", form, seed)
    d = diagnose(rec, scene, seed=0)
    assert d.effects[:1] == ["impulsive_pixels"], d.report["effects"]
