"""The angle of incidence in the baseline's photon model: how much of the camera's light a surface
catches.

A matte (Lambertian) surface lit by a source beside the lens receives the source's light in
proportion to the cosine of the angle between its normal and the ray, ``cos theta_inc``: the
modulated photo-charge of a pixel is ``k rho cos(theta_inc) / d^2`` (Lange, PhD thesis, Siegen
2000, ch. 2; Hansard et al., *Time-of-Flight Cameras*, Springer 2013, ch. 1). A given scene's
``reflectance`` is then the surface's albedo, and a floor seen at a grazing angle returns a
fraction of what a wall facing the camera returns at the same distance. Other scenes (the
package's simulator among them) state a reflectance that already holds the angle: ``k rho /
d^2``. The baseline holds either: ``photons.incidence`` = ``gamma`` (1 or 0), the active light
``k rho cos(theta_inc)^gamma / d^2`` (ambient light, which comes from every direction, keeps
``rho``).

Without the angle, a scene given as albedo leaves the amplitude of every tilted surface below the
model's, by up to an order of magnitude at a grazing floor; the only candidate that takes such a
misfit anywhere in the frame is a random gain per pixel (``pixel_gain``), which is then named for
a camera that has none.

``cos theta_inc`` comes from the scene's depth map: back-projected through a pinhole of horizontal
field of view ``photons.field_of_view`` (degrees), the surface normals from differences that cross
neither a depth edge nor a corner (:func:`_tangent`). Neither value is fitted by the likelihood (a
free power of the cosine would take up a share of any other smooth amplitude misfit: a vignette, a
clip, a bias): :func:`choose_incidence` decides them once, before the fit, from the amplitude means
against the model without the angle, by the median absolute deviation of the log ratio (robust to
the pixels whose normal a depth map cannot give, edges and surfaces a few pixels wide, and to
clipped or otherwise spoilt pixels). Lambert's law (``gamma = 1``, at the field of view that
explains the amplitude best, settled by weighted least squares) is taken when it leaves at most
:data:`LAMBERT_SHARE` of that deviation; else the reflectance holds the angle (``gamma = 0``).
Where the scene is estimated from the recording, its reflectance is taken from the amplitude itself
and holds the angle already: ``gamma = 0``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import torch

from ..sim import Photons
from ..sim.relay import back_project

__all__ = [
    "COS_FLOOR",
    "FIELDS_OF_VIEW",
    "FOV_KEY",
    "FOV_SETTLE_STEP",
    "FOV_STEP",
    "INCIDENCE_KEY",
    "LAMBERT_SHARE",
    "OPEN_BEND",
    "PLAIN_SPREAD",
    "RADIAL_TOLERANCE",
    "SMOOTH_BEND",
    "IncidentPhotons",
    "choose_incidence",
    "incidence_cosine",
    "incidence_factor",
    "incidence_open",
    "incidence_sd",
    "incidence_spread",
    "open_light",
]

#: the baseline's power of the incidence cosine (0: a reflectance that holds the angle, 1: an
#: albedo, Lambert's law); chosen from the data, not fitted
INCIDENCE_KEY: str = "photons.incidence"
#: the horizontal field of view (degrees) the normals are computed with; chosen, not fitted
FOV_KEY: str = "photons.field_of_view"
#: Horizontal fields of view (degrees) the choice tries (ToF cameras' lenses span about 30-130
#: degrees); the best is then refined in steps of ``FOV_STEP`` degrees around it (a normal's
#: angle moves with the field of view: 55 instead of 70 degrees errs by 10-20 % in the cosine of
#: a floor).
FIELDS_OF_VIEW: tuple[float, ...] = tuple(float(x) for x in range(30, 131, 10))
FOV_STEP: float = 2.0
#: ... and settled in steps of this many degrees by weighted least squares (:func:`_settle`).
FOV_SETTLE_STEP: float = 0.25
#: The pixels whose log-cosine spread is below this enter the least squares of :func:`_settle`.
PLAIN_SPREAD: float = 0.005
#: The smallest cosine taken: a surface seen at a grazing angle (or a normal from a depth map
#: too noisy to trust) does not take the pixel's light to zero.
COS_FLOOR: float = 0.05
#: A pixel's surface is open along an axis when the second difference on its chosen side exceeds
#: this share of the step (a plane seen in perspective bends its steps by some 10-15 % at a
#: grazing angle, a sphere ten pixels across by some 10 %; an edge or a corner by the whole step).
OPEN_BEND: float = 0.5
#: ... and smooth where the second differences on both sides are below this share of their steps:
#: the normal from the central difference there.
SMOOTH_BEND: float = 0.1
#: Lambert's law is taken when the median absolute deviation of the log amplitude ratio with the
#: angle is at most this share of that without it (a power of the field angle such as a cos^4
#: vignette on a wall facing the camera leaves 3/4 of it).
LAMBERT_SHARE: float = 0.5
#: The field of view chosen from the log amplitude ratios as they are is replaced by the one
#: chosen with a radial fall-off removed when, with that fall-off removed, it leaves a median
#: absolute deviation more than this share above the least (:func:`choose_incidence`).
RADIAL_TOLERANCE: float = 0.25
#: The amplitude ratios of pixels darker than this share of the median amplitude do not enter the
#: choice (their noise dominates the log ratio).
_DIM_SHARE: float = 0.2

#: the last ``(depth map, fov, (cosines, spreads))``: the cosines of a scene are computed once
#: per field of view (every prediction needs them); the entry holds the depth map, so no other
#: map can take its address while it lives
_COS: list = [None]


def incidence_cosine(depth: torch.Tensor, fov_deg: float) -> torch.Tensor:
    """``cos theta_inc`` (H, W), float64, in ``[COS_FLOOR, 1]`` of the radial ``depth`` map
    (H, W) seen through a pinhole of horizontal field of view ``fov_deg``."""
    return _cosines(depth, fov_deg)[0]


def incidence_spread(depth: torch.Tensor, fov_deg: float) -> torch.Tensor:
    """How far (H, W) the log cosine of :func:`incidence_cosine` can be off where the depth map
    leaves a pixel's surface open: the range of ``log cos`` over the normals from the forward and
    the backward differences along either axis. 0 inside a plane (every difference lies in it);
    on a curved surface about the change of the normal from one pixel to the next; at a corner
    or an edge, the pixel may lie on either side; where neither side lies on a surface with the
    pixel (:func:`_tangent`), ``-log COS_FLOOR``: any angle."""
    return _cosines(depth, fov_deg)[1]


def _cosines(depth: torch.Tensor, fov_deg: float) -> tuple[torch.Tensor, torch.Tensor]:
    entry = _COS[0]  # one read: another thread may replace the entry meanwhile
    if entry is not None and entry[1] == fov_deg and (entry[0] is depth or _same(entry[0], depth)):
        return entry[2]
    d = depth.detach().to(torch.float64)
    pts = back_project(d, fov_deg)
    ray = pts / pts.norm(dim=-1, keepdim=True).clamp_min(1e-12)

    def cos(tx: torch.Tensor, ty: torch.Tensor) -> torch.Tensor:
        n = torch.linalg.cross(tx, ty)
        n = n / n.norm(dim=-1, keepdim=True).clamp_min(1e-12)
        c = (n * ray).sum(-1).abs().clamp(COS_FLOOR, 1.0)
        return torch.where(torch.isfinite(c), c, torch.ones_like(c))

    (tx, fx, bx, ox), (ty, fy, by, oy) = _tangent(pts, 1), _tangent(pts, 0)
    c = cos(tx, ty)
    logs = torch.stack([torch.log(cos(a, b)) for a in (fx, bx) for b in (fy, by)])
    spread = logs.max(0).values - logs.min(0).values
    # a pixel whose surface the depth map does not give: any angle
    unknown = ox | oy | ~torch.isfinite(spread)
    spread = torch.where(unknown, torch.full_like(spread, -math.log(COS_FLOOR)), spread)
    out = (c, spread)
    _COS[0] = (depth, fov_deg, out)
    return out


def _tangent(pts: torch.Tensor, axis: int):
    """``(step, forward, backward, open)`` along ``axis`` (0: rows, 1: columns) of the points
    (H, W, 3): the step to the next pixel on the pixel's own surface; the two differences it is
    chosen from (at the border of the frame the missing one extrapolated from the two steps
    inside, so that their spread shows a curved surface there too); and where neither of them
    lies on a surface with the pixel (``open``).

    The step is the difference that the difference beyond it continues (the smaller second
    difference): a difference across an occluding edge jumps, and one across a corner bends; the
    side that does neither lies on the pixel's surface (a floor seen at a grazing angle has large
    steps, so the smaller step of the two would cross the corner to the wall). Where even that
    side's second difference exceeds :data:`OPEN_BEND` times the step (a surface a pixel wide,
    a pixel between two edges), the depth map does not give the pixel's surface. Where both
    sides continue smoothly (second differences below :data:`SMOOTH_BEND` times their steps),
    the step is the central difference, their mean."""
    n = pts.shape[axis]
    fwd = torch.roll(pts, -1, axis) - pts
    if n < 3:
        fwd = fwd if n > 1 else torch.zeros_like(pts)
        return fwd, fwd, fwd, torch.zeros(pts.shape[:2], dtype=torch.bool)
    fwd2 = torch.roll(fwd, -1, axis)
    bwd = torch.roll(fwd, 1, axis)
    bwd2 = torch.roll(fwd, 2, axis)
    ef = (fwd2 - fwd).norm(dim=-1)
    eb = (bwd - bwd2).norm(dim=-1)
    idx = torch.arange(n)
    shape = (-1, 1) if axis == 0 else (1, -1)
    ef = torch.where((idx >= n - 2).view(shape), torch.inf, ef)  # no second step ahead
    eb = torch.where((idx <= 1).view(shape), torch.inf, eb)  # ... or behind
    first, last = (idx == 0).view(shape), (idx == n - 1).view(shape)
    use_fwd = ((ef <= eb) & ~last) | first
    fwd = torch.where(last.unsqueeze(-1), 2 * bwd - bwd2, fwd)  # no wrap at the border
    bwd = torch.where(first.unsqueeze(-1), 2 * fwd - fwd2, bwd)
    step = torch.where(use_fwd.unsqueeze(-1), fwd, bwd)
    # where both sides continue smoothly (a curved surface), the central difference: a one-sided
    # difference holds the normal half a pixel off, the same way on every pixel of a sphere
    smooth = (ef <= SMOOTH_BEND * fwd.norm(dim=-1)) & (eb <= SMOOTH_BEND * bwd.norm(dim=-1))
    step = torch.where(smooth.unsqueeze(-1), 0.5 * (fwd + bwd), step)
    bend = torch.where(use_fwd, ef, eb)
    bend = torch.where(first, (fwd2 - fwd).norm(dim=-1), torch.where(last, eb, bend))
    return step, fwd, bwd, bend > OPEN_BEND * step.norm(dim=-1)


def _same(a: torch.Tensor, b: torch.Tensor) -> bool:
    return a.shape == b.shape and a.dtype == b.dtype and bool(torch.equal(a, b))


def incidence_factor(scene, v: dict):
    """The factor ``cos(theta_inc)^gamma`` (1, 1, H, W) of the active light of ``scene`` (a
    simulator :class:`~tof_fpn_torch.sim.Scene` of one image) for the values ``v``; None where
    the model holds no angle (``gamma`` absent or 0)."""
    gamma = float(v.get(INCIDENCE_KEY, 0.0))
    fov = v.get(FOV_KEY)
    if gamma == 0.0 or fov is None:
        return None
    c = incidence_cosine(scene.depth[0, 0], float(fov))
    out = c if gamma == 1.0 else torch.exp(gamma * torch.log(c))
    return out.to(scene.depth.dtype).view(1, 1, *out.shape)


def incidence_open(scene, v: dict):
    """Where (H, W) the depth map gives no surface for the pixel (:func:`incidence_spread` is
    ``-log COS_FLOOR``): the model cannot say how much of the light it catches, nor, with it,
    the noise of its depth; None where the model holds no angle. These pixels do not enter the
    likelihood (their prediction is any value)."""
    gamma = float(v.get(INCIDENCE_KEY, 0.0))
    fov = v.get(FOV_KEY)
    if gamma == 0.0 or fov is None:
        return None
    return incidence_spread(scene.depth[0, 0], float(fov)) >= -math.log(COS_FLOOR) - 1e-9


def open_light(scene, v: dict, obs, mu_a):
    """The light (H, W) that a pixel whose surface the depth map leaves open catches, relative to
    the model's: the observed amplitude mean over ``mu_a``, within ``exp(+-spread)``
    (:func:`incidence_spread`), 1 where the surface is plain or nothing was observed; None where
    the model holds no angle. The depth noise of such a pixel follows its own light (eq. 2), not
    the model's guess of it: the angle is a nuisance of the pixel, estimated from its amplitude
    (the amplitude mean itself keeps the random effect of :func:`incidence_sd`)."""
    gamma = float(v.get(INCIDENCE_KEY, 0.0))
    fov = v.get(FOV_KEY)
    if gamma == 0.0 or fov is None:
        return None
    sp = gamma * incidence_spread(scene.depth[0, 0], float(fov)).to(torch.float64)
    mu = mu_a.detach().to(torch.float64)
    ratio = obs.m_a / mu.clamp_min(1e-12)
    seen = (obs.n > 0) & (mu > 0) & torch.isfinite(ratio) & (ratio > 0)
    ratio = torch.where(seen, ratio, torch.ones_like(ratio))
    return torch.minimum(torch.maximum(ratio, torch.exp(-sp)), torch.exp(sp))


def incidence_sd(scene, v: dict, mu_a):
    """The sd (H, W) of the amplitude means ``mu_a`` that the angle leaves open where the depth
    map cannot tell a pixel's surface (:func:`incidence_spread`, a random effect fixed in time
    like a pixel's gain); None where the model holds no angle."""
    gamma = float(v.get(INCIDENCE_KEY, 0.0))
    fov = v.get(FOV_KEY)
    if gamma == 0.0 or fov is None:
        return None
    return gamma * incidence_spread(scene.depth[0, 0], float(fov)).to(mu_a.dtype) * mu_a


def choose_incidence(obs, a0: torch.Tensor, ok: torch.Tensor) -> dict:
    """``{INCIDENCE_KEY, FOV_KEY}`` from the observed amplitude means against the model's ``a0``
    without the angle (H, W) on the pixels ``ok`` (module docstring): the median absolute
    deviation of ``log(m_a / a0)`` from its median, as it is and with ``log cos`` taken off at
    each field of view of :data:`FIELDS_OF_VIEW` (then refined around the best).

    A fall-off with the field angle (a lens's vignette, the source's radiation pattern) is a
    smooth misfit even in the distance from the frame's centre, which the cosines at a wrong
    field of view take up in part (an LED pattern moved the choice from 70 to about 43 degrees,
    the tilted surfaces' light then misfit pixel by pixel). So the deviations are also taken
    with such a fall-off removed (:func:`_radial_basis`); where the field of view chosen as it
    is leaves more than :data:`RADIAL_TOLERANCE` above the least of those, the field of view is
    the one that leaves the least (a scene with surfaces of several angles tells it; a wall
    facing the camera alone does not, and keeps the first choice). Lambert's law is taken when
    either way leaves at most :data:`LAMBERT_SHARE` of the deviation without the angle."""
    none = {INCIDENCE_KEY: 0.0, FOV_KEY: FIELDS_OF_VIEW[len(FIELDS_OF_VIEW) // 2]}
    ok = ok & (a0 > 0) & (obs.m_a > 0) & obs.known
    if int(ok.sum()) < 16:
        return none
    ok = ok & (obs.m_a > _DIM_SHARE * obs.m_a[ok].median())
    y = torch.log(obs.m_a[ok] / a0[ok])
    radial = _radial_basis(obs.m_a.shape, ok)

    def deviation(r: torch.Tensor, flat: bool = False) -> float:
        if flat:
            r = _without_radial(r, radial)
        return float((r - r.median()).abs().median())

    def lambert(fov: float, flat: bool = False) -> tuple[float, float]:
        return deviation(y - torch.log(incidence_cosine(obs.scene_depth, fov))[ok], flat), fov

    def search(flat: bool) -> tuple[float, float]:
        best = min(lambert(f, flat) for f in FIELDS_OF_VIEW)
        step = FIELDS_OF_VIEW[1] - FIELDS_OF_VIEW[0]
        fine = [best[1] - step + FOV_STEP * i for i in range(int(round(2 * step / FOV_STEP)) + 1)]
        lo, hi = FIELDS_OF_VIEW[0], FIELDS_OF_VIEW[-1]
        return min([best, *(lambert(f, flat) for f in fine if lo <= f <= hi)])

    best = search(False)
    flat = search(True)
    plain_law = best[0] <= LAMBERT_SHARE * deviation(y)
    flat_law = flat[0] <= LAMBERT_SHARE * deviation(y, True)
    if not (plain_law or flat_law):
        return none
    if lambert(best[1], True)[0] > (1.0 + RADIAL_TOLERANCE) * flat[0]:
        return {INCIDENCE_KEY: 1.0, FOV_KEY: _settle(obs, y, ok, flat[1], radial)}
    return {INCIDENCE_KEY: 1.0, FOV_KEY: _settle(obs, y, ok, best[1])}


def _settle(obs, y: torch.Tensor, ok: torch.Tensor, fov: float, radial=None) -> float:
    """The field of view near ``fov`` (within ``FOV_STEP + 1`` degrees, in steps of
    :data:`FOV_SETTLE_STEP`) whose cosines leave the least weighted sum of squares of ``y`` (the
    log amplitude ratios of the pixels ``ok``) on the pixels whose surface the depth map gives
    (spread below :data:`PLAIN_SPREAD` at ``fov``) and whose ratio is not an outlier there (within
    3.5 sd by the median absolute deviation): the median absolute deviation that decided the
    law is robust but wastes most of the information, and a field of view 2 degrees off leaves a
    misfit growing towards the frame's corners that a bright recording shows. Weights ``m_a``
    (the shot-noise variance of ``log A`` falls as ``1 / A``). With ``radial``
    (:func:`_radial_basis` on the pixels ``ok``), a fall-off even in the distance from the
    frame's centre is taken off by the same weighted least squares at each field of view."""
    logc = torch.log(incidence_cosine(obs.scene_depth, fov))[ok]
    r = y - logc
    dev = (r - r.median()).abs()
    keep = (incidence_spread(obs.scene_depth, fov)[ok] < PLAIN_SPREAD) & (
        dev <= 3.5 * 1.4826 * dev.median()
    )
    if int(keep.sum()) < 16:
        return fov
    w = obs.m_a[ok][keep]
    yk = y[keep]
    n = int(round((FOV_STEP + 1.0) / FOV_SETTLE_STEP))
    best = (math.inf, fov)
    for i in range(-n, n + 1):
        f = fov + i * FOV_SETTLE_STEP
        if not FIELDS_OF_VIEW[0] <= f <= FIELDS_OF_VIEW[-1]:
            continue
        rk = yk - torch.log(incidence_cosine(obs.scene_depth, f))[ok][keep]
        if radial is None:
            rk = rk - (w * rk).sum() / w.sum()
        else:
            rk = _without_radial(rk, radial[keep], w)
        best = min(best, (float((w * rk**2).sum()), f))
    return best[1]


def _radial_basis(shape, ok: torch.Tensor) -> torch.Tensor:
    """``(n, 3)``: 1, ``q^2`` and ``q^4`` at the pixels ``ok`` of an image of ``shape`` (H, W),
    ``q`` the distance from the frame's centre over half its width: a fall-off of the light
    with the field angle (a lens's vignette, the source's radiation pattern) is smooth and even
    in it, and an angle of incidence at the wrong field of view would take it up (on a wall
    facing the camera, ``cos theta_inc`` is itself the cosine of the field angle)."""
    h, w = shape
    yy = torch.arange(h, dtype=torch.float64) - (h - 1) / 2
    xx = torch.arange(w, dtype=torch.float64) - (w - 1) / 2
    q2 = (yy[:, None] ** 2 + xx[None, :] ** 2) / (w / 2) ** 2
    q2 = q2[ok]
    return torch.stack([torch.ones_like(q2), q2, q2**2], 1)


def _without_radial(r: torch.Tensor, basis: torch.Tensor, w=None) -> torch.Tensor:
    """``r`` less its (weighted, ``w``) least-squares fit on ``basis`` (:func:`_radial_basis`),
    refitted once without the values beyond 3.5 sd (by the median absolute deviation) of the
    first fit: a few spoilt pixels (a hot pixel's amplitude) must not bend the fall-off."""
    r = r.to(torch.float64)
    sw = torch.ones_like(r) if w is None else w.to(torch.float64).sqrt()
    coef = torch.linalg.lstsq(basis * sw[:, None], (r * sw)[:, None]).solution
    e = r - (basis @ coef)[:, 0]
    dev = (e - e.median()).abs()
    keep = dev <= 3.5 * 1.4826 * dev.median()
    if int(keep.sum()) >= 16:
        sk = sw[keep]
        coef = torch.linalg.lstsq(basis[keep] * sk[:, None], (r[keep] * sk)[:, None]).solution
        e = r - (basis @ coef)[:, 0]
    return e


@dataclass
class IncidentPhotons(Photons):
    """The simulator's :class:`~tof_fpn_torch.sim.Photons` with the active light of every pixel
    times ``cos(theta_inc)^incidence`` (module docstring), the cosines from the scene's depth
    through a pinhole of horizontal field of view ``field_of_view`` (degrees): the baseline's
    photon model as a simulator term (its parametric bootstrap, ``model.json``)."""

    incidence: float = 0.0
    field_of_view: float = 70.0
    name: str = field(default="photons", init=False)

    def mean_samples(self, camera, scene) -> torch.Tensor:
        if float(self.incidence) == 0.0:
            return Photons.mean_samples(self, camera, scene)
        ambient = Photons.mean_samples(self, replace(camera, illumination_power=0.0), scene)
        active = Photons.mean_samples(self, replace(camera, ambient_irradiance=0.0), scene)
        gamma, fov = float(self.incidence), float(self.field_of_view)
        cos = [incidence_cosine(d[0], fov) for d in scene.depth]
        factor = torch.stack([c if gamma == 1.0 else torch.exp(gamma * torch.log(c)) for c in cos])
        return ambient + active * factor[:, None].to(active.dtype)
