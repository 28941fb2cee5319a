"""The flexible member of vignetting: its basis never lets the light rise outwards, its closed
form recovers a fall-off in its span, and a vignette of neither form (a dark corner sector) is
named ``vignetting`` through it."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from tof_fpn_torch.diagnosis.terms.vignetting_field import RAMPS, SECTORS, loss_basis


def test_every_basis_function_rises_along_every_ray():
    """Along rays from the frame centre (200 points each, 37 directions), every basis function
    is non-decreasing; the angular hats sum to one (the ramps of all sectors together are
    radial); the pixels' basis is the basis at the pixel centres."""
    h, w = 61, 84
    basis = loss_basis(h, w)
    assert basis.shape == (len(RAMPS) * SECTORS, h, w)
    assert float(basis.min()) >= 0.0
    cy, cx = (h - 1) / 2, (w - 1) / 2
    t = torch.linspace(0, math.hypot(cy, cx), 200, dtype=torch.float64)
    for ang in np.linspace(0, 2 * np.pi, 37):
        ray = torch.stack([cy + t * math.sin(ang), cx + t * math.cos(ang)])
        prof = loss_basis(h, w, ray)
        assert float(prof.diff(dim=1).min()) >= -1e-12
        assert float(prof[:, -1].max()) > 0.5  # and they do rise
    radial = basis[:SECTORS].sum(0)
    yy = torch.arange(h, dtype=torch.float64).view(h, 1) - cy
    xx = torch.arange(w, dtype=torch.float64).view(1, w) - cx
    r2 = (xx * xx + yy * yy) / (cy * cy + cx * cx)
    assert torch.allclose(radial, r2, atol=1e-12)
    pix = torch.stack(torch.meshgrid(torch.arange(h), torch.arange(w), indexing="ij")).double()
    assert torch.equal(loss_basis(h, w, pix), basis)


@pytest.mark.slow
def test_dark_corner_sector_is_named_vignetting_through_the_member():
    """A mechanical vignette (a 40 deg sector of one corner losing 25 % of its light beyond 0.7
    half-diagonals; neither the catalogue's round lens nor the member's basis) is named
    ``vignetting`` alone, through the member, whose map is darkest in that corner."""
    from test_diagnosis import H, W, _recording

    from tof_fpn_torch.diagnosis import diagnose
    from tof_fpn_torch.sim import Vignetting

    yy = torch.arange(H, dtype=torch.float64).view(H, 1) - (H - 1) / 2
    xx = torch.arange(W, dtype=torch.float64).view(1, W) - (W - 1) / 2
    rc = math.hypot((H - 1) / 2, (W - 1) / 2)
    r = torch.sqrt(xx * xx + yy * yy)
    cos = (yy * (H - 1) / 2 + xx * (W - 1) / 2) / (r.clamp_min(1e-9) * rc)  # bottom right
    sector = torch.sigmoid((cos - math.cos(math.radians(20))) / 0.02)
    g = 1 - 0.25 * torch.sigmoid((r / rc - 0.7) / 0.04) * sector
    rec, sd = _recording(Vignetting(gain_map=g), seed=6)
    diag = diagnose(rec, sd, replicates=0)
    assert diag.report["verdict"] == ["vignetting"], diag.report["effects"]
    eff = diag.report["effects"][0]
    assert "vignetting_field" in eff["terms"]
    corners = eff["params"]["corners_relative_illumination_percent"]
    assert int(np.argmin(corners)) == 3 and corners[3] < 90.0


def test_a_fall_off_in_the_span_is_recovered():
    """A relative illumination ``exp(-sum w_k phi_k)`` with three positive weights (an
    off-axis fall-off): the member's closed form, in the fit, gives back the map within 2 % (0.5 %
    RMS)."""
    from test_diagnosis import H, W, _recording

    from tof_fpn_torch.diagnosis.catalogue import CATALOGUE
    from tof_fpn_torch.diagnosis.fit import fit
    from tof_fpn_torch.diagnosis.run import _baseline, _fit_baseline, observe
    from tof_fpn_torch.sim import Vignetting

    basis = loss_basis(H, W)
    w = torch.zeros(len(basis), dtype=torch.float64)
    w[[2, SECTORS + 5, 3 * SECTORS + 1]] = torch.tensor([0.2, 0.3, 0.15], dtype=torch.float64)
    g = torch.exp(-torch.einsum("k,khw->hw", w, basis))
    rec, scene = _recording(Vignetting(gain_map=g), seed=6)
    obs = observe(rec, scene)
    base, ctx, _ = _fit_baseline(_baseline(obs, None), obs)
    model, _ = fit(base.with_effect(CATALOGUE["vignetting_field"], {}), obs, ctx)
    got = model.profiles["vignetting_field"]
    ratio = (got / g) / (got / g).mean()  # the light's overall scale is the responsivity's
    assert float((ratio - 1).abs().max()) < 0.02  # the planted loss reaches 21 %
    assert float((ratio - 1).pow(2).mean().sqrt()) < 0.005
    assert 3 <= model.values["vignetting_field.dof"] < len(basis)
