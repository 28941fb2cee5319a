"""The diagnosis names the effect from its signature, not its form: the flexible members of an
effect (``Term.signature``), the simulator terms they stand for, and the read-out loadings."""

from __future__ import annotations

import math

import pytest
import torch

from tof_fpn_torch import constants as K
from tof_fpn_torch.diagnosis.catalogue import CATALOGUE, TERMS, VOCABULARY
from tof_fpn_torch.diagnosis.readout import _harmonic, _loadings
from tof_fpn_torch.diagnosis.terms.amplitude_bias_shape import node_delays
from tof_fpn_torch.sim import AmplitudeBias, Camera, PixelOffset, SimState
from tof_fpn_torch.sim.camera import depth_from_samples


@pytest.mark.parametrize("n", [4, 5])
def test_readout_loadings_match_the_decoder(n):
    """Each of the 6 column coefficients, put on the samples as its map, moves the decoded
    phasor as its radial and tangential loadings say (finite differences through the decoder)."""
    f = Camera(n_phases=n).modulation_frequency
    k = 4 * math.pi * f / K.SPEED_OF_LIGHT_AIR
    d = torch.linspace(0.3, 7.0, 60, dtype=torch.float64).view(1, 60)
    amp, off = 500.0, 1500.0
    th = torch.arange(n, dtype=torch.float64).view(n, 1) * (2 * math.pi / n)
    s = off + amp * torch.cos(k * d + th)
    d0, a0, _ = depth_from_samples(s.view(1, n, 1, 60), f)
    assert torch.allclose(d0.view(-1), d.view(-1), atol=1e-9)  # the convention assumed
    one, zero = torch.ones(1, dtype=torch.float64), torch.zeros(1, dtype=torch.float64)
    eps = 1e-4
    maps = [  # (offset map DN, gain map) of a unit coefficient
        (_harmonic(one, zero, n, 1), 0.0),
        (_harmonic(zero, one, n, 1), 0.0),
        (0.0, _harmonic(one, zero, n, 1)),
        (0.0, _harmonic(zero, one, n, 1)),
        (0.0, torch.ones(n, 1, dtype=torch.float64)),
        (0.0, _harmonic(one, zero, n, 2)),
    ]
    phi = k * d
    rad, tan = _loadings(phi, torch.full_like(phi, off), torch.full_like(phi, amp), n)
    for i, (om, gm) in enumerate(maps):
        s2 = s * (1 + eps * gm) + eps * om
        d2, a2, _ = depth_from_samples(s2.view(1, n, 1, 60), f)
        r_obs = (a2 - a0).view(-1) / eps
        t_obs = (d2 - d0).view(-1) * k * a0.view(-1) / eps
        assert torch.allclose(r_obs, rad[0, :, i], atol=2e-3 * amp), i
        assert torch.allclose(t_obs, tan[0, :, i], atol=2e-3 * amp), i


def test_members_report_their_effect():
    """Every flexible member names an effect of the vocabulary that has a physical term too;
    the vocabulary lists each effect once."""
    members = [t for t in TERMS if t.signature]
    assert {t.name for t in members} >= {"amplitude_bias_shape", "fpn_pixel_offsets"}
    for t in members:
        assert t.effect in CATALOGUE and not CATALOGUE[t.effect].signature
        assert t.effect in VOCABULARY and t.name not in VOCABULARY
    assert len(VOCABULARY) == len(set(VOCABULARY))


def test_amplitude_bias_curve():
    """The curve form: the given delays at the knots, linear in ln A between, constant beyond;
    bad knots are refused."""
    ab = AmplitudeBias(knots=(10.0, 100.0, 1000.0), delays=(0.03, 0.01, 0.0))
    a = torch.tensor([1.0, 10.0, math.sqrt(1000.0), 100.0, 1000.0, 1e5], dtype=torch.float64)
    want = torch.tensor([0.03, 0.03, 0.02, 0.01, 0.0, 0.0], dtype=torch.float64)
    assert torch.allclose(ab.bias(a), want, atol=1e-12)
    hyp = AmplitudeBias(delay=0.02, reference=50.0)
    assert torch.allclose(hyp.bias(a), 0.02 * 50.0 / (a + 50.0))
    with pytest.raises(ValueError, match="increasing"):
        AmplitudeBias(knots=(10.0, 5.0), delays=(0.0, 0.0))
    with pytest.raises(ValueError, match="same length"):
        AmplitudeBias(knots=(10.0, 20.0), delays=(0.0,))


def test_shape_member_is_monotone():
    """The member's node delays start at b, end at 0 and never rise, for any weights."""
    g = torch.Generator().manual_seed(3)
    for _ in range(20):
        w = torch.rand(4, generator=g).tolist()
        v = {f"amplitude_bias_shape.w{i + 1}": x for i, x in enumerate(w)}
        v["amplitude_bias_shape.delay"] = -0.04
        d = node_delays(v)
        assert d[0] == pytest.approx(-0.04) and d[-1] == pytest.approx(0.0, abs=1e-12)
        assert all(b >= a - 1e-15 for a, b in zip(d, d[1:], strict=False))


def test_pixel_offset_moves_the_phasor():
    """PixelOffset adds a complex offset of the stated rms to (2/N) X_1, fixed by its seed."""
    n, h, w = 4, 64, 64
    cam = Camera()
    s = torch.full((1, n, h, w), 1000.0, dtype=torch.float64)
    out = PixelOffset(sd=20.0, seed=5).apply(SimState(cam, None, s.clone(), None)).samples
    th = torch.arange(n, dtype=torch.float64).view(1, n, 1, 1) * (2 * math.pi / n)
    x1 = ((out - s) * torch.exp(-1j * th)).sum(1) * (2.0 / n)
    assert float(x1.real.std()) == pytest.approx(20.0, rel=0.05)
    assert float(x1.imag.std()) == pytest.approx(20.0, rel=0.05)
    again = PixelOffset(sd=20.0, seed=5).apply(SimState(cam, None, s.clone(), None)).samples
    assert torch.equal(out, again)
    with pytest.raises(ValueError):
        PixelOffset(sd=-1.0)


def _r(name, score, sig=True):
    return {"name": name, "score": score, "significant": sig}


def test_one_effect_one_name():
    """From the second round a new effect is significant only when it gains more than every form
    of the effects already named; what it would have been is listed as consistent."""
    from tof_fpn_torch.diagnosis.run import _one_name
    from tof_fpn_torch.diagnosis.summary import also_consistent

    effects = [{"name": "amplitude_bias", "terms": ["amplitude_bias"]}]
    ranking = [
        _r("amplitude_bias_shape", 60.0),
        _r("pixel_gain", 40.0),
        _r("vignetting", 80.0),
        _r("multipath", 5.0, sig=False),
    ]
    out = _one_name([dict(r) for r in ranking], effects)
    sig = {r["name"]: r["significant"] for r in out}
    assert sig == {
        "amplitude_bias_shape": True,  # a form of the named effect: joins it
        "pixel_gain": False,  # gains less than the named effect's other form
        "vignetting": True,  # gains more: a second effect
        "multipath": False,
    }
    assert also_consistent(effects, [out]) == ["vignetting", "pixel_gain"]
    # without a form of the named effect in the ranking nothing is held back
    out = _one_name([dict(r) for r in ranking[1:]], effects)
    assert [r["significant"] for r in out] == [True, True, False]
