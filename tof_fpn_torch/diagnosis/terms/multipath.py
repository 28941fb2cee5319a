"""``multipath``: diffuse interreflection (:class:`~tof_fpn_torch.sim.Multipath`).

The relay within the visible scene from its back-projected geometry (field of view and
near-field length profiled on a grid, its efficiency fitted) plus a uniform relay of the
scene-mean return (Fuchs 2010 without geometry) for light from outside the view, each reflected
with the pixel's albedo. The scene relay is linear in the samples: the prediction relays the two
cached unit images of the photons once per scene and geometry and scales them.
"""

from __future__ import annotations

import math
from dataclasses import replace

import torch

from ... import constants as K
from ...sim import Multipath, Photons, SimState
from ..params import SCALE_CYCLIC, ParamSpec
from ..prediction import predict
from .base import Term, depth_residuals, least_squares, r4

__all__ = [
    "FIELDS_OF_VIEW",
    "NEAR_FIELDS",
    "PATH_SHARES",
    "RELAY_CACHE_SIZE",
    "MultipathTerm",
    "relay_cached",
]

#: The scene relay is profiled over these fields of view (deg) and near fields (m).
FIELDS_OF_VIEW: tuple[float, ...] = (50.0, 70.0, 90.0)
NEAR_FIELDS: tuple[float, ...] = (0.3, 1.0, 3.0)
#: Extra paths (shares of the unambiguous range) at which the uniform relay's strength starts.
PATH_SHARES: tuple[float, ...] = tuple((k + 0.5) / 8 for k in range(8))
#: The relays of the two unit images (2 x (1, N, H, W), small) are kept for this many
#: geometries: the grid above, tried in every ranking round.
RELAY_CACHE_SIZE: int = 16

_RELAY_CACHE: dict = {}
_RELAY_UNITS: list = [None]  # the unit images the cached relays belong to


def relay_cached(t, state, units, key, amb_irr, resp):
    """``state`` with ``t``'s uniform relay applied and its scene relay of the photons
    ``(act + amb_irr amb) resp`` added (``t.apply(state)`` when ``state.samples`` are still the
    photons): the scene relay is linear in the photons, so the relays of the two cached unit
    images are computed once per scene, geometry and source map and scaled (the (sources x
    pixels) products and their backward pass ran in every prediction: a third of a diagnosis
    with multipath)."""
    if isinstance(t.scene_relay, (int, float)) and t.scene_relay == 0:
        return t.apply(state)
    if _RELAY_UNITS[0] is not units:  # other unit images (another scene): the cache is stale
        _RELAY_CACHE.clear()
        _RELAY_UNITS[0] = units
    m = t.source_map
    mkey = None
    if m is not None:  # by content: the map is copied with every model
        ramp = torch.arange(m.numel(), dtype=torch.float64).view(m.shape)
        mkey = (tuple(m.shape), float(m.sum()), float((m.double() * ramp).sum()))
    r = t.mirrors
    rmk = None if r is None else tuple(float(v) for v in r.reshape(-1))
    geo = (float(t.field_of_view), float(t.near_field), int(t.relay_step), bool(t.cosines))
    rkey = (key, *geo, mkey, rmk)
    rel = _RELAY_CACHE.get(rkey)
    if rel is None:
        with torch.no_grad():
            rel = (t.relayed(units[0], state), t.relayed(units[1], state))
        if len(_RELAY_CACHE) >= RELAY_CACHE_SIZE:
            _RELAY_CACHE.clear()
        _RELAY_CACHE[rkey] = rel
    state = replace(t, scene_relay=0.0).apply(state)  # the uniform relay from outside the view
    state.samples = state.samples + t.scene_relay * resp * (rel[0] + rel[1] * amb_irr)
    return state


class MultipathTerm(Term):
    """Strength of the uniform relay, its extra path (m) and the scene relay's efficiency; the
    field of view and near field of the scene relay (``multipath.field_of_view``,
    ``multipath.near_field``) are profiled on a grid, not fitted."""

    name = "multipath"
    specs = (
        ParamSpec("multipath.strength", "abs", SCALE_CYCLIC),
        ParamSpec("multipath.extra_path", "abs", 1.0, "m"),
        ParamSpec("multipath.scene_relay", "abs", SCALE_CYCLIC),
    )
    enters = "chain"
    sim_name = "multipath"
    axes = ("depth_mean|amplitude", "depth_mean|depth", "amp_mean|amplitude")
    about = (
        "diffuse interreflection: light relayed within the visible scene (its 3-D geometry, "
        "inverse square, own paths) plus a uniform relay of the scene-mean return from "
        "outside the view, each reflected with the pixel's albedo"
    )
    slow = True

    def simulator_term(self, v: dict, model):
        return Multipath(
            v["multipath.strength"],
            v["multipath.extra_path"],
            scene_relay=v.get("multipath.scene_relay", 0.0),
            field_of_view=v.get("multipath.field_of_view", K.MULTIPATH_FIELD_OF_VIEW_DEG),
            near_field=v.get("multipath.near_field", K.MULTIPATH_NEAR_FIELD_M),
        )

    def apply_mean(self, state, v: dict, model, chain):
        t = self.simulator_term(v, model)
        if state.samples is chain.photons:
            return relay_cached(t, state, chain.units, chain.key, chain.ambient, chain.responsivity)
        return t.apply(state)

    def initial_values(self, model, obs, ctx, pred) -> list[dict]:
        return self._uniform_starts(model, obs, ctx, pred) + self._scene_starts(
            model, obs, ctx, pred
        )

    def _uniform_starts(self, model, obs, ctx, p) -> list[dict]:
        # a weak second return X_m turns pixel p's phasor X_p by Im(X_m / X_p): the depth moves
        # by strength * x_p, linear in the strength for each extra path on a grid
        rd, wd = depth_residuals(obs, ctx, p)
        f = float(model.camera.modulation_frequency)
        k = 4 * math.pi * f / K.SPEED_OF_LIGHT_AIR
        rho = ctx.scene.reflectance[0, 0].to(torch.float64)
        phi = p.mu_d * k
        ok = torch.isfinite(phi) & torch.isfinite(p.a0)
        m = torch.complex(p.a0 * torch.cos(phi), p.a0 * torch.sin(phi))[ok].mean()
        ratio = (rho / rho.mean()) / torch.complex(p.a0 * torch.cos(phi), p.a0 * torch.sin(phi))
        out = []
        for share in PATH_SHARES:
            d_x = share * 2 * math.pi / k
            x = torch.imag(ratio * m * complex(math.cos(k * d_x), math.sin(k * d_x))) / k
            b = least_squares(x[ctx.mask_d], rd, wd)
            if b > 0:
                out.append(
                    {
                        "multipath.strength": min(b, 0.5),
                        "multipath.extra_path": d_x,
                        "multipath.scene_relay": 0.0,
                    }
                )
        return out

    def _scene_starts(self, model, obs, ctx, p) -> list[dict]:
        # the relay within the scene: its depth shift per unit efficiency (a small one, linear)
        # on a grid of fields of view and near-field lengths, least squares for the efficiency
        rd, wd = depth_residuals(obs, ctx, p)
        md = ctx.mask_d
        eps = SCALE_CYCLIC * 0.1
        out = []
        for fov in FIELDS_OF_VIEW:
            for near in NEAR_FIELDS:
                geo = {
                    "multipath.strength": 0.0,
                    "multipath.extra_path": 0.0,
                    "multipath.scene_relay": eps,
                    "multipath.field_of_view": fov,
                    "multipath.near_field": near,
                }
                with torch.no_grad():
                    pg = predict(model.with_effect(self, geo), obs, scene=ctx.scene)
                x = ((pg.mu_d - p.mu_d) / eps)[md]
                b = least_squares(x, rd, wd)
                if b > 0 and math.isfinite(b):
                    out.append(dict(geo, **{"multipath.scene_relay": b}))
        return out

    def describe(self, model, obs, pred) -> dict:
        """Relayed / direct active light of every pixel (offsets: no phasor cancellation)."""
        v = model.values
        cam = replace(model.camera, ambient_irradiance=0.0)
        scene = obs.scene()
        with torch.no_grad():
            act = Photons(responsivity=1.0).mean_samples(cam, scene).to(torch.float64)
            term = self.simulator_term(v, model)
            direct = act.mean(1)[0]
            rho = scene.reflectance[0, 0].to(torch.float64)
            uniform = v["multipath.strength"] * (rho / rho.mean()) * direct.mean()
            geo = v.get("multipath.scene_relay", 0.0)
            inner = geo * term.relayed(act, SimState(cam, scene, act, None)).mean(1)[0]
        ratio = (uniform + inner) / direct
        return {
            "strength_percent": r4(v["multipath.strength"] * 100),
            "extra_path_m": r4(v["multipath.extra_path"]),
            "scene_relay_efficiency_percent": r4(geo * 100),
            "field_of_view_deg": r4(
                v.get("multipath.field_of_view", K.MULTIPATH_FIELD_OF_VIEW_DEG)
            ),
            "near_field_m": r4(v.get("multipath.near_field", K.MULTIPATH_NEAR_FIELD_M)),
            "median_relay_to_direct": r4(float(ratio[obs.known].median())),
            "median_scene_relay_to_direct": r4(float((inner / direct)[obs.known].median())),
        }
