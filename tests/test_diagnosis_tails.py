"""The heavy-tailed member of the noise floor: Student-t variates of the simulator's jitter, the
Student-t density of the likelihood (both against SciPy), and a planted heavy-tailed jitter
named ``noise_floor`` with its degrees of freedom."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from scipy import stats

from tof_fpn_torch.diagnosis import diagnose
from tof_fpn_torch.diagnosis.densities import (
    CENTRE_Z,
    gauss_log_density,
    pixel_centre,
    student_log_density,
)
from tof_fpn_torch.sim import Camera, PhaseJitter, Photons, Simulation, synthetic_scene
from tof_fpn_torch.sim.effects import student_t


@pytest.mark.parametrize("dof", [2.5, 3.0, 7.5])
def test_student_t_variates_follow_scipys_law(dof):
    gen = torch.Generator().manual_seed(11)
    x = student_t((200, 300), dof, gen, torch.zeros(1, dtype=torch.float64))
    assert x.shape == (200, 300)
    assert stats.kstest(x.reshape(-1).numpy(), stats.t(dof).cdf).pvalue > 0.01
    # and not a normal law's: the test can tell them apart at this size
    assert stats.kstest(x.reshape(-1).numpy(), stats.norm(0, x.std().item()).cdf).pvalue < 1e-6


def test_student_log_density_matches_scipy():
    rng = np.random.default_rng(3)
    r = torch.from_numpy(rng.standard_normal(50) * 0.02)
    var = torch.from_numpy(rng.uniform(1e-5, 4e-4, 50))
    for dof in (2.6, 3.0, 10.0, 50.0):
        got = student_log_density(r, var, 1.0 / dof).numpy()
        scale = np.sqrt(var.numpy() * (dof - 2) / dof)  # the law's variance is var
        want = stats.t.logpdf(r.numpy(), dof, scale=scale)
        np.testing.assert_allclose(got, want, rtol=1e-10, atol=1e-10)


def test_gauss_log_density_matches_scipy():
    rng = np.random.default_rng(4)
    r = torch.from_numpy(rng.standard_normal(50) * 0.02)
    var = torch.from_numpy(rng.uniform(1e-5, 4e-4, 50))
    want = stats.norm.logpdf(r.numpy(), scale=np.sqrt(var.numpy()))
    np.testing.assert_allclose(gauss_log_density(r, var).numpy(), want, rtol=1e-12, atol=1e-12)


def test_pixel_centre_leaves_out_only_readings_beyond_centre_z():
    """Pixel 0: no reading far from the median, the plain mean. Pixel 1: one reading beyond
    ``CENTRE_Z`` sd, the mean of the others. Pixel 2: every reading invalid, 0. Pixel 3: an
    invalid reading is not averaged in."""
    rng = np.random.default_rng(5)
    x = torch.from_numpy(rng.standard_normal((9, 4)))
    valid = torch.ones(9, 4, dtype=torch.bool)
    sd = torch.ones(1, 4, dtype=torch.float64)
    x[0, 1] = float(x[1:, 1].median()) + 1.5 * CENTRE_Z  # an outlier
    valid[:, 2] = False
    x[3, 3], valid[3, 3] = 1e6, False
    got = pixel_centre(x, valid, sd).view(-1)
    assert got.shape == (4,)
    assert float(got[0]) == pytest.approx(float(x[:, 0].mean()), abs=1e-12)
    assert float(got[1]) == pytest.approx(float(x[1:, 1].mean()), abs=1e-12)
    assert float(got[1]) != pytest.approx(float(x[:, 1].mean()), abs=1e-3)
    assert float(got[2]) == 0.0
    keep = torch.arange(9) != 3
    assert float(got[3]) == pytest.approx(float(x[keep, 3].mean()), abs=1e-12)


def test_phase_jitter_with_dof_delays_by_a_scaled_student_t():
    """Noise-free light, jitter only: the depth errors are ``sigma t_dof sqrt((dof - 2) / dof)``
    (KS against SciPy), their sd ``sigma``; a dof of 2 or less is refused."""
    scene = synthetic_scene(64, 64, seed=2, depth_range=(1.0, 3.0))
    sim = Simulation(Camera(), [Photons(), PhaseJitter(0.01, dof=3.0)])
    out = sim.run(scene, 4, seed=5)
    err = (out.depth - scene.depth).reshape(-1).double().numpy()
    scale = 0.01 * math.sqrt(1.0 / 3.0)
    assert stats.kstest(err, stats.t(3.0, scale=scale).cdf).pvalue > 0.01
    assert stats.kstest(err, stats.norm(0, 0.01).cdf).pvalue < 1e-6
    with pytest.raises(ValueError, match="dof"):
        PhaseJitter(0.01, dof=2.0)


@pytest.mark.slow
def test_planted_heavy_tailed_jitter_is_named_noise_floor_with_its_tails():
    """A Student-t jitter (3 degrees of freedom, 25 mm sd) is named ``noise_floor`` alone (not
    impulsive pixels: its readings are a few sd out, in every pixel) through the heavy-tailed
    member (finite degrees of freedom: more than 3, the shot noise is Gaussian); a Gaussian
    jitter of the same sd is named ``noise_floor`` too, with no heavy tail."""
    from test_diagnosis import _recording

    rec, sd = _recording(PhaseJitter(0.025, dof=3.0), seed=6)
    diag = diagnose(rec, sd, replicates=0)
    assert diag.report["verdict"] == ["noise_floor"], diag.report["effects"]
    eff = diag.report["effects"][0]
    assert eff["terms"] == ["noise_floor_tails"]
    assert 2.5 <= eff["params"]["degrees_of_freedom"] < 20.0
    assert eff["params"]["sigma_mm"] == pytest.approx(25.0, rel=0.2)
    rec, sd = _recording(PhaseJitter(0.025), seed=6)
    diag = diagnose(rec, sd, replicates=0)
    assert diag.report["verdict"] == ["noise_floor"], diag.report["effects"]
    eff = diag.report["effects"][0]
    # either form (they fit a Gaussian alike); the Student-t one then finds no heavy tail
    assert eff["terms"] == ["noise_floor"] or eff["params"]["degrees_of_freedom"] > 40.0


def test_the_member_is_tried_only_on_heavy_tails():
    """The far readings (beyond 4 predicted sd of their pixel's mean) of a Gaussian recording
    are about the Gaussian count, and the member is not tried there; a Student-t jitter makes
    many times as many, and it is."""
    from test_diagnosis import _recording

    from tof_fpn_torch.diagnosis.catalogue import CATALOGUE
    from tof_fpn_torch.diagnosis.prediction import predict
    from tof_fpn_torch.diagnosis.run import _baseline, _fit_baseline, observe
    from tof_fpn_torch.diagnosis.terms.noise_floor_tails import far_readings

    term = CATALOGUE["noise_floor_tails"]
    out = {}
    for name, jitter in (("gauss", PhaseJitter(0.025)), ("t", PhaseJitter(0.025, dof=3.0))):
        rec, scene = _recording(jitter, seed=6)
        obs = observe(rec, scene)
        base, ctx, _ = _fit_baseline(_baseline(obs, None), obs)
        model = base.with_effect(CATALOGUE["noise_floor"], {"noise_floor.sigma": 0.025})
        with torch.no_grad():
            pred = predict(model, obs, scene=ctx.scene)
        out[name] = (far_readings(obs, ctx, pred), term.initial_values(model, obs, ctx, pred))
    (count, expected), starts = out["gauss"]
    assert expected > 0 and count < expected + 4 * math.sqrt(expected) + 1 and starts == []
    (count, expected), starts = out["t"]
    assert count > 5 * expected and len(starts) == 2


def test_outlier_mixture_reads_tails_about_the_pixel_not_the_model_mean():
    """With the outlier mixture, Gaussian readings about pixel means the model misses by a few
    sd each (a per-pixel misfit, the same in every frame) are not a heavy tail: a Student-t law
    fits them worse than the Gaussian one. Centred on the model's mean, the misfit looks like a
    tail and the Student-t law wins."""
    from types import SimpleNamespace

    from tof_fpn_torch.diagnosis.likelihood import _nll_mixture

    gen = torch.Generator().manual_seed(3)
    t, p = 60, 400
    off = 3.0 * torch.randn(1, p, generator=gen, dtype=torch.float64)  # per-pixel misfit (sd)
    xd = off + torch.randn(t, p, generator=gen, dtype=torch.float64)
    xa = 100.0 + torch.randn(t, p, generator=gen, dtype=torch.float64)
    valid = torch.ones(t, p, dtype=torch.bool)
    idx = torch.arange(p)
    ones = torch.ones(1, p, dtype=torch.float64)
    ctx = SimpleNamespace(depth_span=50.0, amp_span=300.0)
    pred = SimpleNamespace(wrap=None, tau_d=0.0)
    depth = (xd, valid, idx, 0.0 * ones, ones)
    amp = (xa, valid, idx, 100.0 * ones, ones)

    def cost(tail):
        return float(_nll_mixture(ctx, pred, 1e-3, depth, amp, 0.0, tail))

    assert cost(1.0 / 3.0) > cost(None) + 100.0
    # the same readings with Student-t deviations about their pixel: the Student-t law wins
    tdev = torch.from_numpy(stats.t(3.0).rvs((t, p), random_state=4)) / math.sqrt(3.0)
    depth = (off + tdev, valid, idx, 0.0 * ones, ones)
    assert cost(1.0 / 3.0) < cost(None) - 100.0


def test_far_readings_leave_out_the_readings_the_outliers_explain():
    """Impulsive pixels (uniform raw codes in 1 % of the frame-pixels) put many depth readings
    far from their pixel's mean; with the outlier rate in the model they are the outliers' (their
    amplitude readings land anywhere too), not a heavy-tailed jitter's, and the tail member is
    not tried."""
    from test_diagnosis import _recording

    from tof_fpn_torch.diagnosis.catalogue import CATALOGUE
    from tof_fpn_torch.diagnosis.prediction import predict
    from tof_fpn_torch.diagnosis.run import _baseline, _fit_baseline, observe
    from tof_fpn_torch.diagnosis.terms.noise_floor_tails import far_readings
    from tof_fpn_torch.sim import ImpulsivePixels

    rec, scene = _recording(ImpulsivePixels(rate=0.01, level=0.05), seed=8)
    obs = observe(rec, scene)
    base, ctx, _ = _fit_baseline(_baseline(obs, None), obs)
    model = base.with_effect(CATALOGUE["impulsive_pixels"], {"impulsive_pixels.rate": 0.01})
    with torch.no_grad():
        pred = predict(model, obs, scene=ctx.scene)
    count, expected = far_readings(obs, ctx, pred, 0.01)
    assert count < 3 * expected
    assert CATALOGUE["noise_floor_tails"].initial_values(model, obs, ctx, pred) == []
    # without the outlier rate in the model the same readings are far more than a Gaussian
    # law's count
    assert far_readings(obs, ctx, pred)[0] > 5 * expected


def test_a_misfitting_model_gives_its_candidates_its_all_pixel_fit_as_a_start(monkeypatch):
    """With the robust starting values given (the model misfits grossly), a candidate's fit
    also starts from the current model as fitted on all pixels, not only from its refit on the
    fitting half (with hot pixels unexplained that refit can run far off: 2 358 against 7 e-/DN
    on a form-shifted recording); without them, from the fitting half's only."""
    from test_diagnosis import _recording

    from tof_fpn_torch.diagnosis import naming
    from tof_fpn_torch.diagnosis.run import _baseline, _fit_baseline, observe
    from tof_fpn_torch.sim import ImpulsivePixels

    rec, scene = _recording(ImpulsivePixels(rate=0.01, level=0.05), seed=8)
    obs = observe(rec, scene)
    base, ctx, _ = _fit_baseline(_baseline(obs, None), obs)
    off = base.copy()  # a fitting-half refit that ran off
    off.values["camera.conversion_gain"] = 300.0 * base.values["camera.conversion_gain"]
    off.values["camera.read_noise"] = 300.0 * base.values["camera.read_noise"]
    seen = []
    real_try = naming._try

    def spy(model, term, init, obs_, ctx_):
        seen.append(model.values["camera.conversion_gain"])
        return real_try(model, term, init, obs_, ctx_)

    monkeypatch.setattr(naming, "_try", spy)
    start = dict(base.values)  # robust core values other than the model's
    start["camera.conversion_gain"] = 2.0 * base.values["camera.conversion_gain"]
    naming.rank(base, obs, ctx, base_train=off, only=["impulsive_pixels"], start_values=start)
    assert base.values["camera.conversion_gain"] in seen
    seen.clear()
    naming.rank(base, obs, ctx, base_train=off, only=["impulsive_pixels"])
    assert seen and base.values["camera.conversion_gain"] not in seen
    # a refit that stayed within RUN_OFF_FACTOR of the all-pixel fit: no further start
    near = base.copy()
    near.values["camera.conversion_gain"] = 1.5 * base.values["camera.conversion_gain"]
    seen.clear()
    naming.rank(base, obs, ctx, base_train=near, only=["impulsive_pixels"], start_values=start)
    assert seen and base.values["camera.conversion_gain"] not in seen


def test_run_off_compares_every_value_of_the_noise_law_by_ratio():
    """The fitting half's refit has run off when any of responsivity, conversion gain and read
    noise differs from the all-pixel fit's by more than the factor, either way (and a value
    that went to 0 has run off); the same model never has."""
    from tof_fpn_torch.diagnosis.model import DiagnosisModel
    from tof_fpn_torch.diagnosis.naming import RUN_OFF_FACTOR, _ran_off
    from tof_fpn_torch.sim import Camera

    vals = {"photons.responsivity": 4e7, "camera.conversion_gain": 24.0, "camera.read_noise": 5.5}
    a = DiagnosisModel(Camera(), dict(vals))
    assert not _ran_off(a, a)
    for k in vals:
        for f, expect in ((0.99 * RUN_OFF_FACTOR, False), (1.01 * RUN_OFF_FACTOR, True)):
            for scale in (f, 1.0 / f):
                b = DiagnosisModel(Camera(), {**vals, k: vals[k] * scale})
                assert _ran_off(a, b) is expect, (k, scale)
        b = DiagnosisModel(Camera(), {**vals, k: 0.0})
        assert _ran_off(a, b)
