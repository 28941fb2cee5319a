"""``multipath`` from free sources: the relay within the scene with a free share of light per
surface patch (a flexible member of the ``multipath`` effect).

The catalogue's relay (:class:`~tof_fpn_torch.sim.Multipath`, ``scene_relay``) lets every scene
point relay its light with one Lambertian efficiency. A real room is not so even: a glossy floor
mirrors the emitter onto the walls, one bright patch lights its surroundings, a diffuse wall
hardly relays at all. This member keeps the geometry of a second bounce and frees the sources:
the scene, back-projected through the camera, is cut into blocks of ``SOURCE_BLOCK`` x
``SOURCE_BLOCK`` source patches (:func:`~tof_fpn_torch.sim.optics.source_step` px apart) and
block ``b`` relays its light with its own weight ``w_b >= 0``. Pixel ``p`` then reads, besides
its direct phasor ``X_p``,

    R_p = rho_p sum_b w_b sum_{q in b} F_pq X_q e^{j psi_pq},

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
non-negative least-squares solution (coordinate descent), weighted by the radial and tangential
noise of the read-out pattern's residuals; the geometry (the catalogue's fields of view, with
and without the cosines) is profiled when the term enters and then kept. The AIC counts the
positive weights and the geometry (``values["multipath_sources.dof"]``). The report names it
``multipath``.
"""

from __future__ import annotations

import math

import numpy as np
import torch

from ... import constants as K
from ...sim import Multipath
from ...sim.optics import source_step
from ...sim.relay import relay_matrix
from ..readout import rotated_residuals
from .base import Term, r4
from .multipath import FIELDS_OF_VIEW, relay_cached

__all__ = [
    "GEOMETRIES",
    "NEAR_FIELD_M",
    "NNLS_SWEEPS",
    "SOURCE_BLOCK",
    "MultipathSourcesTerm",
    "source_map",
]

#: source patches per side of a block with its own weight (8 px apart: 24 px blocks)
SOURCE_BLOCK: int = 3
#: near-field length (m) of the form factor (it keeps the relay between close points finite)
NEAR_FIELD_M: float = 0.2
#: the geometries profiled: the catalogue's fields of view, each with the form factor with both
#: obliquities (a floor lights the walls, not itself) and without (a glossy or rough surface that
#: lights its own plane)
GEOMETRIES: tuple[tuple[float, bool], ...] = tuple(
    (fov, c) for fov in FIELDS_OF_VIEW for c in (True, False)
)
#: sweeps of the non-negative coordinate descent (stopped earlier once converged)
NNLS_SWEEPS: int = 500
_KEY = "multipath_sources"  # profiles: the block weights (BY, BX) and the (H, W) map
_MAP = "multipath_sources_map"


def _grid(h: int, w: int) -> tuple[int, torch.Tensor, torch.Tensor]:
    """``(step, block row of every source row, block column of every source column)``."""
    step = source_step(h, w)
    ny, nx = len(range(step // 2, h, step)), len(range(step // 2, w, step))
    return step, torch.arange(ny) // SOURCE_BLOCK, torch.arange(nx) // SOURCE_BLOCK


def source_map(weights: torch.Tensor, h: int, w: int) -> torch.Tensor:
    """The (H, W) share of light each scene point relays for block ``weights`` (BY, BX)."""
    step, by, bx = _grid(h, w)
    iy = torch.clamp(torch.arange(h) // step, max=len(by) - 1)
    ix = torch.clamp(torch.arange(w) // step, max=len(bx) - 1)
    return weights[by[iy].view(h, 1), bx[ix].view(1, w)].to(torch.float64)


def _nnls(g: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``argmin_{x >= 0} x'Gx / 2 - b'x`` by cyclic coordinate descent."""
    x = np.zeros_like(b)
    d = np.maximum(np.diag(g), 1e-300)
    scale = float(np.abs(b).max()) or 1.0
    for _ in range(NNLS_SWEEPS):
        moved = 0.0
        for i in range(len(b)):
            new = max(0.0, x[i] + (b[i] - g[i] @ x) / d[i])
            moved = max(moved, abs(new - x[i]) * d[i])
            x[i] = new
        if moved < 1e-9 * scale:
            break
    return x


def _loadings(scene, pred, k: float, fov: float, cosines: bool) -> tuple[torch.Tensor, ...]:
    """Radial and tangential loadings (blocks, P) of the block weights (DN per unit weight) on
    ``pred``'s phasors, for the ``scene``'s geometry."""
    depth = scene.depth[0, 0]
    h, w = depth.shape
    step, by, bx = _grid(h, w)
    _, wc, ws, src = relay_matrix(depth, fov, NEAR_FIELD_M, step, k, cosines=bool(cosines))
    phi = (k * pred.mu_d.detach()).reshape(-1).to(torch.float64)
    a0 = pred.a0.detach().reshape(-1).to(torch.float64)
    xr, xi = a0[src] * torch.cos(phi[src]), a0[src] * torch.sin(phi[src])
    block = (by.view(-1, 1) * (int(bx.max()) + 1) + bx.view(1, -1)).reshape(-1)
    onehot = torch.zeros(int(block.max()) + 1, len(src), dtype=torch.float64)
    onehot[block, torch.arange(len(src))] = 1.0
    wc, ws = wc.to(torch.float64), ws.to(torch.float64)
    lr = (onehot * xr) @ wc - (onehot * xi) @ ws  # (blocks, P): sum_q F X_q e^{j psi}
    li = (onehot * xr) @ ws + (onehot * xi) @ wc
    rho = scene.reflectance[0, 0].reshape(1, -1).to(torch.float64)
    lr, li = lr * rho, li * rho
    c, s = torch.cos(phi).view(1, -1), torch.sin(phi).view(1, -1)
    return lr * c + li * s, li * c - lr * s


def update_sources(model, obs, ctx, pred, sel: str = "all"):
    """``model`` with the block weights and geometry estimated in closed form from the
    residuals of ``sel`` pixels against the model without the relay (module docstring)."""
    from ..model import predict  # late: the model imports the catalogue

    h, w = obs.shape
    k = 4 * math.pi * float(model.camera.modulation_frequency) / K.SPEED_OF_LIGHT_AIR
    _, by, bx = _grid(h, w)
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
        ra, ta = torch.where(ok, ra, 0.0), torch.where(ok, ta, 0.0)
        best = None
        geometries = GEOMETRIES
        if _KEY in model.profiles:  # profiled once, when the term enters; then kept
            geometries = (
                (model.values[f"{_KEY}.field_of_view"], bool(model.values[f"{_KEY}.cosines"])),
            )
        for fov, cosines in geometries:
            rad, tan = _loadings(ctx.scene, direct, k, fov, cosines)
            g = (rad * wr) @ rad.T + (tan * wt) @ tan.T
            b = (rad * wr) @ ra + (tan * wt) @ ta
            x = _nnls(g.numpy(), b.numpy())
            gain = float(b.numpy() @ x - 0.5 * x @ g.numpy() @ x)
            if best is None or gain > best[0]:
                best = (gain, fov, cosines, x)
    _, fov, cosines, x = best
    out = model.copy()
    weights = torch.from_numpy(x).view(int(by.max()) + 1, int(bx.max()) + 1)
    out.profiles[_KEY] = weights
    out.profiles[_MAP] = source_map(weights, h, w)
    out.values[f"{_KEY}.field_of_view"] = fov
    out.values[f"{_KEY}.cosines"] = float(cosines)
    out.values[f"{_KEY}.dof"] = float((x > 0).sum()) + 2.0
    return out


class MultipathSourcesTerm(Term):
    """No scalar parameters: the block weights (``model.profiles["multipath_sources"]``) and the
    geometry are estimated in closed form (:func:`update_sources`)."""

    name = "multipath_sources"
    signature = "multipath"
    enters = "chain"
    sim_name = "multipath"
    axes = ("depth_mean|amplitude", "depth_mean|depth", "amp_mean|amplitude")
    about = "a second bounce from free sources: each surface patch relays its own share of light"
    closed_form = True
    slow = True
    profile_keys = (_KEY, _MAP)

    def simulator_term(self, v: dict, model):
        return Multipath(
            scene_relay=1.0,
            field_of_view=float(v.get(f"{_KEY}.field_of_view", K.MULTIPATH_FIELD_OF_VIEW_DEG)),
            near_field=NEAR_FIELD_M,
            source_map=model.profiles.get(_MAP),
            cosines=bool(v.get(f"{_KEY}.cosines", 1.0)),
        )

    def apply_mean(self, state, v: dict, model, chain):
        if model.profiles.get(_KEY) is None:
            return state
        t = self.simulator_term(v, model)
        if state.samples is chain.photons:  # linear in the photons: the cached unit relays
            return relay_cached(t, state, chain.units, chain.key, chain.ambient, chain.responsivity)
        return t.apply(state)

    def initial_values(self, model, obs, ctx, pred) -> list[dict]:
        return [{}]

    def update_closed_form(self, model, obs, ctx, pred, sel: str):
        return update_sources(model, obs, ctx, pred, sel)

    def effective_parameters(self, values: dict) -> float:
        return float(values.get(f"{_KEY}.dof", 0.0))

    def describe(self, model, obs, pred) -> dict:
        v = model.values
        x = model.profiles.get(_KEY)
        out = {
            "field_of_view_deg": r4(v.get(f"{_KEY}.field_of_view", float("nan"))),
            "form_factor_cosines": bool(v.get(f"{_KEY}.cosines", 1.0)),
            "relaying_blocks": int((x > 0).sum()) if x is not None else 0,
            "blocks": list(x.shape) if x is not None else [],
            "effective_parameters": r4(v.get(f"{_KEY}.dof", 0.0)),
        }
        if x is not None and bool((x > 0).any()):
            k = 4 * math.pi * float(model.camera.modulation_frequency) / K.SPEED_OF_LIGHT_AIR
            geo = (out["field_of_view_deg"], out["form_factor_cosines"])
            rad, tan = _loadings(obs.scene(), pred, k, *geo)
            xs = x.reshape(-1)
            ratio = torch.hypot(xs @ rad, xs @ tan) / pred.a0.detach().reshape(-1)
            known = obs.known.reshape(-1)
            out["median_relay_to_direct"] = r4(float(ratio[known].median()))
            out["strongest_block_yx"] = [int(i) for i in np.unravel_index(int(x.argmax()), x.shape)]
        return out
