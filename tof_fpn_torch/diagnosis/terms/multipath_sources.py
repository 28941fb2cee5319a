"""``multipath`` from free sources: the relay within the scene with a free share of light per
surface patch (a flexible member of the ``multipath`` effect).

The catalogue's relay (:class:`~tof_fpn_torch.sim.Multipath`, ``scene_relay``) lets every scene
point relay its light with one Lambertian efficiency. A real room is not so even: a glossy floor
mirrors the emitter onto the walls, one bright patch lights its surroundings, a diffuse wall
hardly relays at all. This member keeps the geometry of a second bounce and frees the sources:
the scene, back-projected through the camera, is sampled at source patches
(:func:`~tof_fpn_torch.sim.multipath.source_step` px apart) and patch ``q`` relays its light with
its own weight ``w_q >= 0``. Pixel ``p`` then reads, besides its direct phasor ``X_p``,

    R_p = rho_p sum_q w_q F_pq X_q e^{j psi_pq},

``F_pq`` the Lambertian form factor with both obliquities (:mod:`tof_fpn_torch.sim.relay`,
``cosines=True``: a floor lights the walls, not itself), ``psi_pq`` the phase of the extra
path ``r_pq + d_p - d_q``. Its signature is what a second bounce does and a neighbour does not:
light is added (``w >= 0``), over a path longer than the direct one (the phase lags: the depth
moves away), from where surfaces face each other (smooth in space, strongest near the relaying
surface, the same relative change for dark and bright pixels of one place: a gain or pixel
offset follows the pixel, a column pattern the column).

Fit, in closed form between the L-BFGS rounds: the observed mean phasor minus the model's
direct one (the model without the relay), rotated into the direct phase, is linear in the
weights (``R_p`` rotated by ``-phi_p``; no linearisation of the decoder), so the weights are the
non-negative least-squares solution (:func:`nnls`, Lawson-Hanson), weighted by the radial and
tangential noise of the read-out pattern's residuals. In two steps: one weight per block of
``SOURCE_BLOCK`` x ``SOURCE_BLOCK`` patches (which also profiles the geometry, the catalogue's
fields of view with and without the cosines, when the term enters; then it is kept), then every
patch of a relaying block on its own (a glossy patch is smaller than a block: a block's weight
spreads its light over the block and misfits next to it), kept only where the patches' weights
fitted on one half of the pixels (a checkerboard of patch-sized blocks) predict the other half
better than the blocks' weights do (a patch relays sharply next to itself and can fit a local
misfit of the pixels it sees). The geometry is chosen when the term enters the model (its
first update) and kept; the groups are chosen again in every fit of all the pixels (the model's
own) and kept in the fits on the fitting half (the candidates' fits of a ranking, which refit
the groups' weights only: the check on halves and the six geometries cost most of a
diagnosis's time at 204 x 204 when they ran in every candidate's fit). The AIC counts the
positive weights and the geometry (``values["multipath_sources.dof"]``). The report names it
``multipath``.
"""

from __future__ import annotations

import math

import numpy as np
import torch

from ... import constants as K
from ...sim import Multipath
from ...sim.multipath import source_step
from ...sim.relay import mirror_gains, mirror_planes, relay_matrix
from ..nnls import nnls
from ..prediction import predict
from ..readout import rotated_residuals
from .base import ClosedFormMapTerm, r4
from .multipath import FIELDS_OF_VIEW, relay_cached

__all__ = [
    "GEOMETRIES",
    "NEAR_FIELD_M",
    "SOURCE_BLOCK",
    "MultipathSourcesTerm",
    "source_map",
]

#: source patches per side of a block with one weight in the first step of the fit
SOURCE_BLOCK: int = 3
#: near-field length (m) of the form factor (it keeps the relay between close points finite)
NEAR_FIELD_M: float = 0.2
#: the geometries profiled: the catalogue's fields of view, each with the form factor with both
#: obliquities (a floor lights the walls, not itself) and without (a glossy or rough surface that
#: lights its own plane)
GEOMETRIES: tuple[tuple[float, bool], ...] = tuple(
    (fov, c) for fov in FIELDS_OF_VIEW for c in (True, False)
)
_KEY = "multipath_sources"  # profiles: the source weights (SY, SX) and the (H, W) map
_MAP = "multipath_sources_map"
_GROUPS = "multipath_sources_groups"  # (SY, SX): the group of each source (one weight each)
_MIRRORS = "multipath_sources_mirrors"  # (M, 5): the scene's planes (n, c) and their weights


def _grid(h: int, w: int) -> tuple[int, int, int]:
    """``(step, source rows, source columns)`` of the relay's source patches."""
    step = source_step(h, w)
    return step, len(range(step // 2, h, step)), len(range(step // 2, w, step))


def _blocks(ny: int, nx: int) -> torch.Tensor:
    """The block of ``SOURCE_BLOCK`` x ``SOURCE_BLOCK`` sources each source (row-major) is in."""
    by, bx = torch.arange(ny) // SOURCE_BLOCK, torch.arange(nx) // SOURCE_BLOCK
    return (by.view(-1, 1) * (int(bx.max()) + 1) + bx.view(1, -1)).reshape(-1)


def source_map(weights: torch.Tensor, h: int, w: int) -> torch.Tensor:
    """The (H, W) share of light each scene point relays for source ``weights`` (SY, SX): each
    point takes its source patch's weight."""
    step, ny, nx = _grid(h, w)
    iy = torch.clamp(torch.arange(h) // step, max=ny - 1)
    ix = torch.clamp(torch.arange(w) // step, max=nx - 1)
    return weights[iy.view(h, 1), ix.view(1, w)].to(torch.float64)


def _loadings(scene, pred, k: float, fov: float, cosines: bool, group: torch.Tensor, cols=None):
    """Radial and tangential loadings (G, P) on ``pred``'s phasors (DN per unit weight) of the
    weights of the source groups ``group`` (the group of every source, 0 .. G - 1), for the
    ``scene``'s geometry; ``cols``: the pixels (flat indices) to compute them for (default
    all)."""
    depth = scene.depth[0, 0]
    h, w = depth.shape
    step = source_step(h, w)
    _, wc, ws, src = relay_matrix(depth, fov, NEAR_FIELD_M, step, k, cosines=bool(cosines))
    phi = (k * pred.mu_d.detach()).reshape(-1).to(torch.float64)
    a0 = pred.a0.detach().reshape(-1).to(torch.float64)
    xr, xi = a0[src] * torch.cos(phi[src]), a0[src] * torch.sin(phi[src])
    rho = scene.reflectance[0, 0].reshape(1, -1).to(torch.float64)
    if cols is not None:
        wc, ws, phi, rho = wc[:, cols], ws[:, cols], phi[cols], rho[:, cols]
    # (G, P): sum_q F X_q e^{j psi} over each group's sources, in the relay matrices' float32 (a
    # float64 copy of the (sources, P) matrices cost more than the sums of a few hundred terms);
    # as (G, Q) x (Q, P) products for a few groups, as sums of the (Q, P) rows for many
    n, q = int(group.max()) + 1, len(src)
    xr, xi = xr.to(wc.dtype), xi.to(wc.dtype)
    if n <= q // 3:
        onehot = wc.new_zeros(n, q)
        onehot[group, torch.arange(q)] = 1.0
        br, bi = onehot * xr, onehot * xi
        lr, li = br @ wc - bi @ ws, br @ ws + bi @ wc
    else:
        xr, xi = xr.view(-1, 1), xi.view(-1, 1)
        lr = wc.new_zeros(n, wc.shape[1]).index_add_(0, group, xr * wc - xi * ws)
        li = wc.new_zeros(n, wc.shape[1]).index_add_(0, group, xr * ws + xi * wc)
    lr, li = lr.to(torch.float64) * rho, li.to(torch.float64) * rho
    c, s = torch.cos(phi).view(1, -1), torch.sin(phi).view(1, -1)
    return lr * c + li * s, li * c - lr * s


def _mirror_loadings(scene, pred, k: float, planes: torch.Tensor, fov: float, cols):
    """Radial and tangential loadings (M, P) on ``pred``'s phasors of the weights of the
    specular paths off ``planes`` (M, 4): ``a0 (d / L)^2 e^{j psi}`` in the direct phasor's
    frame (:func:`~tof_fpn_torch.sim.relay.mirror_gains`)."""
    gain, psi = mirror_gains(scene.depth[0, 0], fov, planes, k)
    a0 = pred.a0.detach().reshape(1, -1).to(torch.float64)
    g, p = (a0 * gain.reshape(len(planes), -1))[:, cols], psi.reshape(len(planes), -1)[:, cols]
    return g * torch.cos(p), g * torch.sin(p)


def _systems(ctx, direct, k, geometry, group, fit, halves: bool = True) -> list[tuple]:
    """The normal equations ``(G, b)`` of the groups' weights on the rotated residuals
    ``fit = (radial, tangential, their weights, half)``, one per half of the pixels (``half``: a
    boolean checkerboard of source-patch-sized blocks; ``halves=False``: one, of all the pixels)."""
    ra, ta, wr, wt, half = fit
    # only the pixels that weigh (the others add nothing to the sums): the fitting half of a
    # candidate's fit is half of them, a half of the checkerboard half of those
    cols = torch.nonzero((wr > 0) | (wt > 0)).view(-1)
    rad, tan = _loadings(ctx.scene, direct, k, *geometry, group, cols)
    planes = ctx_planes(ctx, geometry[0])
    if len(planes):  # the specular paths off the scene's planes: more rows, one weight each
        mr, mt = _mirror_loadings(ctx.scene, direct, k, planes, geometry[0], cols)
        rad, tan = torch.cat([rad, mr]), torch.cat([tan, mt])
    # the scale of the direct light, up and down (the baseline's responsivity took up the mean
    # of the relayed light: the weights alone, refitted against it, came out a third low)
    a0 = direct.a0.detach().reshape(1, -1).to(torch.float64)[:, cols]
    rad, tan = torch.cat([rad, a0, -a0]), torch.cat([tan, torch.zeros_like(a0).repeat(2, 1)])
    ra, ta, wr, wt, half = (x[cols] for x in fit)
    out = []
    for m in (half, ~half) if halves else (slice(None),):
        r, t = rad[:, m], tan[:, m]
        ar, at = r * wr[m], t * wt[m]
        out.append(((ar @ r.T + at @ t.T).numpy(), (ar @ ra[m] + at @ ta[m]).numpy()))
    return out


def _quad(x: np.ndarray, g: np.ndarray, b: np.ndarray) -> float:
    """The weighted sum of squares the weights ``x`` remove, halved: ``b'x - x'Gx / 2``."""
    return float(b @ x - 0.5 * x @ g @ x)


def _crossed(systems) -> float:
    """The gain of the weights fitted on one half, on the other half (both ways)."""
    (ga, ba), (gb, bb) = systems
    return _quad(nnls(ga, ba), gb, bb) + _quad(nnls(gb, bb), ga, ba)


def ctx_planes(ctx, fov: float) -> torch.Tensor:
    """The scene's candidate mirror planes (M, 4) for field of view ``fov`` (cached on ``ctx``)."""
    key = (_MIRRORS, fov)
    if key not in ctx.cache:
        ctx.cache[key] = mirror_planes(ctx.scene.depth[0, 0], fov)
    return ctx.cache[key]


def _refined(block: torch.Tensor, x: np.ndarray) -> torch.Tensor:
    """Source groups: every source of a relaying block (weight > 0) on its own, the other
    blocks whole (``x``: the blocks' weights, then the mirrors')."""
    lit = torch.from_numpy(x[: int(block.max()) + 1] > 0)[block]
    key = torch.where(lit, torch.arange(len(block)) + int(block.max()) + 1, block)
    return torch.unique(key, return_inverse=True)[1]


def _two_step(ctx, direct, k, geometry, block, fit):
    """``((gain, weights, groups), geometry)``: the blocks' weights, then the
    sources of the relaying blocks on their own where that predicts the other half of the
    pixels better (a patch's weight can fit a local misfit of the half it sees: the light it
    relays next to itself is sharp)."""
    sys_b = _systems(ctx, direct, k, geometry, block, fit)
    g, b = sys_b[0][0] + sys_b[1][0], sys_b[0][1] + sys_b[1][1]
    x = nnls(g, b)
    best = (_quad(x, g, b), x, block)
    if bool((x > 0).any()):
        group = _refined(block, x)
        sys_r = _systems(ctx, direct, k, geometry, group, fit)
        if _crossed(sys_r) > _crossed(sys_b):
            g, b = sys_r[0][0] + sys_r[1][0], sys_r[0][1] + sys_r[1][1]
            x = nnls(g, b)
            best = (_quad(x, g, b), x, group)
    return best, geometry


def _weights(ctx, direct, k, geometry, group, fit):
    """``(gain, weights, groups)`` of the groups ``group``, fitted on all the pixels of ``fit``."""
    ((g, b),) = _systems(ctx, direct, k, geometry, group, fit, halves=False)
    x = nnls(g, b)
    return _quad(x, g, b), x, group


def _gain(t) -> float:
    return t[0][0]


def update_sources(model, obs, ctx, pred, sel: str = "all"):
    """``model`` with the source weights and geometry estimated in closed form from the
    residuals of ``sel`` pixels against the model without the relay (module docstring)."""
    h, w = obs.shape
    k = 4 * math.pi * float(model.camera.modulation_frequency) / K.SPEED_OF_LIGHT_AIR
    step, ny, nx = _grid(h, w)
    block = _blocks(ny, nx)
    with torch.no_grad():
        direct = predict(model.without(_KEY), obs, scene=ctx.scene)
        _, _, va, vt, _ = rotated_residuals(model, obs, pred, k)
        # the observed mean phasor minus the direct one, in the direct phasor's frame: the relay
        # is linear in the weights there (no linearisation of the decoder)
        dphi = k * (obs.m_d - direct.mu_d)
        ra = (obs.m_a * torch.cos(dphi) - direct.a0).reshape(-1).to(torch.float64)
        ta = (obs.m_a * torch.sin(dphi)).reshape(-1).to(torch.float64)
        va, vt = va.reshape(-1).to(torch.float64), vt.reshape(-1).to(torch.float64)
        ok = (ctx.mask_d & ctx.select(sel)).reshape(-1)
        ok = ok & torch.isfinite(ra) & torch.isfinite(ta) & (va > 0) & (vt > 0)
        wr = torch.where(ok, 1.0 / va.clamp_min(1e-300), torch.zeros_like(va))
        wt = torch.where(ok, 1.0 / vt.clamp_min(1e-300), torch.zeros_like(vt))
        yy, xx = torch.arange(h).view(-1, 1) // step, torch.arange(w).view(1, -1) // step
        half = ((yy + xx) % 2 == 0).reshape(-1)
        fit = (torch.where(ok, ra, 0.0), torch.where(ok, ta, 0.0), wr, wt, half)
        geometries = GEOMETRIES
        if _KEY in model.profiles:  # the geometry is chosen when the term enters; then kept
            geometries = (
                (model.values[f"{_KEY}.field_of_view"], bool(model.values[f"{_KEY}.cosines"])),
            )
        if _GROUPS in model.profiles and sel == "train":  # a candidate's fit: groups kept
            group = model.profiles[_GROUPS].reshape(-1).long()
            best = (_weights(ctx, direct, k, geometries[0], group, fit), geometries[0])
        else:
            # per geometry, one weight per block, then the relaying blocks' sources freed one by
            # one (a small glossy patch is finer than a block); the geometry that gains most
            best = max((_two_step(ctx, direct, k, g, block, fit) for g in geometries), key=_gain)
    (_, x, group), (fov, cosines) = best
    out = model.copy()
    n_groups = int(group.max()) + 1
    planes = ctx_planes(ctx, fov)
    xm = torch.from_numpy(x[n_groups:-2]).to(torch.float64).view(-1, 1)
    # the direct light's scale fitted with the weights (in the responsivity, which the L-BFGS
    # rounds refine)
    out.values["photons.responsivity"] = model.values["photons.responsivity"] * (
        1.0 + float(x[-2] - x[-1])
    )
    out.profiles.pop(_MIRRORS, None)
    if len(planes):
        out.profiles[_MIRRORS] = torch.cat([planes, xm], 1)
    x = x[:n_groups]
    weights = torch.from_numpy(x)[group].view(ny, nx)
    out.profiles[_KEY] = weights
    out.profiles[_MAP] = source_map(weights, h, w)
    out.profiles[_GROUPS] = group.view(ny, nx).to(torch.float64)
    out.values[f"{_KEY}.field_of_view"] = fov
    out.values[f"{_KEY}.cosines"] = float(cosines)
    out.values[f"{_KEY}.dof"] = float((x > 0).sum() + (xm > 0).sum()) + 2.0
    return out


class MultipathSourcesTerm(ClosedFormMapTerm):
    """No scalar parameters: the source weights (``model.profiles["multipath_sources"]``) and the
    geometry are estimated in closed form (:func:`update_sources`)."""

    name = "multipath_sources"
    signature = "multipath"
    enters = "chain"
    sim_name = "multipath"
    axes = ("depth_mean|amplitude", "depth_mean|depth", "amp_mean|amplitude")
    about = "a second bounce from free sources: each surface patch relays its own share of light"
    slow = True
    profile_keys = (_KEY, _MAP, _GROUPS, _MIRRORS)

    def simulator_term(self, v: dict, model):
        return Multipath(
            scene_relay=1.0,
            field_of_view=float(v.get(f"{_KEY}.field_of_view", K.MULTIPATH_FIELD_OF_VIEW_DEG)),
            near_field=NEAR_FIELD_M,
            source_map=model.profiles.get(_MAP),
            cosines=bool(v.get(f"{_KEY}.cosines", 1.0)),
            mirrors=model.profiles.get(_MIRRORS),
        )

    def apply_mean(self, state, v: dict, model, chain):
        if model.profiles.get(_KEY) is None:
            return state
        # the relay of the direct light, from the cached relays of the unit images (linear in
        # the photons), also after the catalogue's relay: a relay of relayed light is of third
        # order (the simulator's stage relays what reaches it; the two differ by that order)
        t = self.simulator_term(v, model)
        return relay_cached(t, state, chain.units, chain.key, chain.ambient, chain.responsivity)

    def update_closed_form(self, model, obs, ctx, pred, sel: str):
        return update_sources(model, obs, ctx, pred, sel)

    def describe(self, model, obs, pred) -> dict:
        v = model.values
        x = model.profiles.get(_KEY)
        out = {
            "field_of_view_deg": r4(v.get(f"{_KEY}.field_of_view", float("nan"))),
            "form_factor_cosines": bool(v.get(f"{_KEY}.cosines", 1.0)),
            "relaying_sources": int((x > 0).sum()) if x is not None else 0,
            "sources": list(x.shape) if x is not None else [],
            "effective_parameters": r4(v.get(f"{_KEY}.dof", 0.0)),
        }
        r = model.profiles.get(_MIRRORS)
        out["mirrors"] = [
            {"normal": [r4(float(v)) for v in m[:3]], "offset_m": r4(m[3]), "weight": r4(m[4])}
            for m in ([] if r is None else r)
            if float(m[4]) > 0
        ]
        if x is not None and bool((x > 0).any()):
            k = 4 * math.pi * float(model.camera.modulation_frequency) / K.SPEED_OF_LIGHT_AIR
            geo = (out["field_of_view_deg"], out["form_factor_cosines"])
            xs = x.reshape(-1)
            rad, tan = _loadings(obs.scene(), pred, k, *geo, torch.arange(xs.numel()))
            ratio = torch.hypot(xs @ rad, xs @ tan) / pred.a0.detach().reshape(-1)
            known = obs.known.reshape(-1)
            out["median_relay_to_direct"] = r4(float(ratio[known].median()))
            out["strongest_source_yx"] = [
                int(i) for i in np.unravel_index(int(x.argmax()), x.shape)
            ]
        return out
