"""The baseline's read-out pattern beyond the periodic part: the random column offsets and gains
of the simulator's default :class:`~tof_fpn_torch.sim.ReadoutFPN`, estimated in closed form.

The default read-out chain adds to sample ``n`` of column ``x`` an offset ``o_n(x)`` and scales
it by a gain ``g_n(x)`` that both have a random part per column and sample (``random_offset``,
``random_gain``) besides the periodic one (``2 pi / 3``, ``pi``). What reaches the decoded phasor
``(2/N) X_1`` of pixel ``p`` (amplitude ``A_p``, phase ``phi_p``, offset level ``B_p``, DN) is

    O(x) + G(x) B_p

a column offset ``O`` (the first harmonic over ``n`` of the offsets) and a column gain ``G`` of
the offset level (the first harmonic of the gains). (The gains' mean and second harmonic also
scale the amplitude, by ``1e-4`` of it for the default's ``random_gain``: not modelled.) Both are
random effects per column, estimated from the residuals of both channels (the phasor's
tangential component ``k A_p (m_p - mu_p)`` from the depth, its radial component from the
amplitude): per column the 4 real coefficients by weighted least squares, the variance of each
by moments over the columns, and every column its best linear unbiased prediction (empirical
Bayes shrinkage: a column whose coefficients are noise is pulled to zero). The trace of the shrinkage
is the effective number of parameters the AIC counts (``values["readout_fpn.columns_dof"]``).
The fit alternates these estimates with L-BFGS.
"""

from __future__ import annotations

import math

import torch

from .. import constants as K

__all__ = [
    "OUTLIER_SIGMA",
    "READOUT_KEYS",
    "apply_readout",
    "random_effect_variance",
    "readout_maps",
    "rotated_residuals",
    "update_readout",
]

#: Pixels whose residual in either channel is beyond this many sd (outliers, wraps, a clip the
#: model does not know yet) are left out of the column estimates.
OUTLIER_SIGMA: float = 5.0
#: keys of ``DiagnosisModel.profiles`` the baseline's read-out pattern owns: the column offsets
#: ``O`` (2, W: real and imaginary part, DN), gains ``G`` of the offset level (2, W) and the
#: gains of the amplitude (2, W: the mean gain ``M`` and the second harmonic ``q``)
READOUT_KEYS: tuple[str, str, str] = ("readout_offset", "readout_gain", "readout_amp_gain")


def _harmonic(prof_re, prof_im, n: int, k: int, scale: float = 1.0) -> torch.Tensor:
    """``scale Re(P(x) e^{j k theta_n})`` as (N, W)."""
    th = torch.arange(n, dtype=torch.float64) * (2 * math.pi * k / n)
    c, s = torch.cos(th).view(n, 1), torch.sin(th).view(n, 1)
    return scale * (c * prof_re.view(1, -1) - s * prof_im.view(1, -1))


def _maps(model, n: int):
    """``(offset map (N, W) in DN, gain map (N, W))`` of the model's column pattern, or None."""
    off = model.profiles.get(READOUT_KEYS[0])
    if off is None:
        return None
    gain = model.profiles[READOUT_KEYS[1]]
    gm = _harmonic(gain[0], gain[1], n, 1)
    amp = model.profiles.get(READOUT_KEYS[2])
    if amp is not None:
        zero = torch.zeros_like(amp[1])
        gm = gm + amp[0].view(1, -1) + _harmonic(amp[1], zero, n, 2)
    return _harmonic(off[0], off[1], n, 1), gm


def apply_readout(samples: torch.Tensor, model, gain_e) -> torch.Tensor:
    """The noise-free samples (e-) with the column offsets and gains of ``model`` (none: as
    they are); ``gain_e``: the conversion gain (e-/DN) the offsets in DN are scaled with."""
    maps = _maps(model, samples.shape[1])
    if maps is None:
        return samples
    n, w = samples.shape[1], samples.shape[3]
    om, gm = (x.to(samples.dtype).view(1, n, 1, w) for x in maps)
    return samples * (1.0 + gm) + gain_e * om


def readout_maps(model, n: int, gain_e: float):
    """``(offset_map (N, W) e-, gain_map (N, W))`` for :class:`~tof_fpn_torch.sim.ReadoutFPN`,
    or ``(None, None)`` without profiles."""
    maps = _maps(model, n)
    if maps is None:
        return None, None
    return gain_e * maps[0], maps[1]


def random_effect_variance(beta: torch.Tensor, cov: torch.Tensor) -> float:
    """Moment estimate of the variance of random effects ``beta`` (C, k) whose estimation
    variances are ``cov`` (C, k), weighted towards the well-determined ones (3 iterations)."""
    ok = torch.isfinite(beta) & torch.isfinite(cov) & (cov > 0) & (cov < 1e20)
    b, c = beta[ok], cov[ok]
    if b.numel() == 0:
        return 0.0
    s2 = max(float((b * b - c).mean()), 0.0)
    for _ in range(3):
        wt = 1.0 / (s2 + c) ** 2
        s2 = max(float((wt * (b * b - c)).sum() / wt.sum()), 0.0)
    return s2


#: the coefficient groups sharing a variance: offsets O, offset-level gains G, the amplitude's
#: mean gain M, its second-harmonic gain q
_GROUPS = ((0, 1), (2, 3), (4,), (5,))
_NC = 6


def _loadings(phi, bn, an, n: int):
    """Radial and tangential loadings (H, W, 6) of the 6 coefficients (O re / im; G re / im
    times ``bn``, the offset level over its median; M and q times ``an``, the amplitude over
    its median) on the rotated residual. A gain ``q cos(2 theta_n)`` on the samples adds ``c q
    conj(z)`` to the phasor ``z`` (``c = 1`` for N = 4, where the harmonics ``-1`` and ``3``
    alias, else 1/2) with the decoder's sample convention ``B + A cos(phi + theta_n)``: rotated
    by ``-phi``, ``c q A e^{-2 j phi}``. The loadings are checked against the decoder in
    ``tests/test_diagnosis_forms.py``."""
    cs, sn = torch.cos(phi), torch.sin(phi)
    c2, s2 = torch.cos(2 * phi), torch.sin(2 * phi)
    h = 1.0 if n == 4 else 0.5
    zero = torch.zeros_like(phi)
    rad = torch.stack([cs, sn, bn * cs, bn * sn, an, h * an * c2], -1)
    tan = torch.stack([-sn, cs, -bn * sn, bn * cs, zero, -h * an * s2], -1)
    return rad, tan


def rotated_residuals(model, obs, pred, k: float):
    """The rotated residuals (radial DN, tangential DN), their variances and the pixels that are
    not outliers."""
    r = obs.m_d - pred.mu_d.detach()
    if pred.wrap is not None:
        r = r - pred.wrap * torch.round(r / pred.wrap)
    sd = pred.sd_d.detach() / obs.n.clamp_min(1).sqrt()
    a0 = pred.a0.detach()
    ra = obs.m_a - pred.mu_a.detach()
    tau = pred.tau_a.detach() if isinstance(pred.tau_a, torch.Tensor) else pred.tau_a
    va = pred.sd_a.detach() ** 2 / obs.n.clamp_min(1) + tau**2
    inlier = (r.abs() < OUTLIER_SIGMA * sd) & (ra.abs() < OUTLIER_SIGMA * va.sqrt())
    return ra, r * k * a0, va, (sd * k * a0) ** 2, inlier


def update_readout(model, obs, ctx, pred, sel: str = "all"):
    """``model`` with the closed-form column pattern estimated from ``pred``'s residuals on the
    ``sel`` pixels (module docstring)."""
    h, w = obs.shape
    k = 4 * math.pi * float(model.camera.modulation_frequency) / K.SPEED_OF_LIGHT_AIR
    m = ctx.mask_d & ctx.select(sel)
    with torch.no_grad():
        b, a0 = pred.offset.detach(), pred.a0.detach()
        bref = float(b[m].median()) if bool(m.any()) else 1.0
        aref = max(float(a0[m].median()) if bool(m.any()) else 1.0, 1e-12)
        n_ph = model.camera.n_phases
        rad, tan = _loadings(k * pred.mu_d.detach(), b / max(bref, 1e-12), a0 / aref, n_ph)
        ra, ta, va, vt, inlier = rotated_residuals(model, obs, pred, k)
        m = m & inlier
        old = torch.zeros(_NC, w, dtype=torch.float64)
        if READOUT_KEYS[0] in model.profiles:
            old[:2] = model.profiles[READOUT_KEYS[0]]
            old[2:4] = model.profiles[READOUT_KEYS[1]] * bref
            if READOUT_KEYS[2] in model.profiles:
                old[4:] = model.profiles[READOUT_KEYS[2]] * aref
        # the old pattern is put back (its loadings times its coefficients)
        ra = ra + (rad * old.T.unsqueeze(0)).sum(-1)
        ta = ta + (tan * old.T.unsqueeze(0)).sum(-1)
        wr = torch.where(m & (va > 0), 1.0 / va.clamp_min(1e-300), torch.zeros_like(va))
        wt = torch.where(m & (vt > 0), 1.0 / vt.clamp_min(1e-300), torch.zeros_like(vt))
        s = torch.einsum("hwi,hwj->wij", rad * wr.unsqueeze(-1), rad)
        s = s + torch.einsum("hwi,hwj->wij", tan * wt.unsqueeze(-1), tan)
        y = torch.einsum("hwi,hw->wi", rad * wr.unsqueeze(-1), ra)
        y = y + torch.einsum("hwi,hw->wi", tan * wt.unsqueeze(-1), ta)
        eye = torch.eye(_NC, dtype=torch.float64)
        scale = s.diagonal(dim1=1, dim2=2).amax(1).clamp_min(1e-30).view(w, 1, 1)
        cov = torch.linalg.inv(s + 1e-9 * scale * eye)
        beta = (cov @ y.unsqueeze(-1)).squeeze(-1)
        dcov = cov.diagonal(dim1=1, dim2=2)
        lam = torch.full((_NC,), 1e30, dtype=torch.float64)
        s2 = []
        for idx in _GROUPS:
            v = random_effect_variance(beta[:, list(idx)], dcov[:, list(idx)])
            s2.append(v)
            if v > 0:
                lam[list(idx)] = 1.0 / v
        a = s + torch.diag(lam)
        blup = torch.linalg.solve(a, y.unsqueeze(-1)).squeeze(-1)
        dof = float(torch.linalg.solve(a, s).diagonal(dim1=1, dim2=2).sum())
    out = model.copy()
    out.profiles[READOUT_KEYS[0]] = blup[:, :2].T.contiguous()
    out.profiles[READOUT_KEYS[1]] = (blup[:, 2:4] / bref).T.contiguous()
    out.profiles[READOUT_KEYS[2]] = (blup[:, 4:] / aref).T.contiguous()
    out.values["readout_fpn.columns_dof"] = dof
    out.values["readout_fpn.random_offset_rms"] = math.sqrt(s2[0])
    out.values["readout_fpn.random_gain_rms"] = math.sqrt(s2[1]) / max(bref, 1e-12)
    out.values["readout_fpn.amplitude_gain_rms"] = math.sqrt(s2[2] + s2[3]) / aref
    return out
