r"""A camera's fixed pattern learned from its own frames of different scenes.

Every frame ``i`` of one camera's folder is ``D_i = S_i + P + n_i``: a scene ``S_i`` that changes
from frame to frame, the camera's fixed pattern ``P`` (the same in every frame) and noise. The
pattern is modelled as column, row and pixel offsets,

    ``P(y, x) = c(x) + r(y) + p(y, x)``,

and estimated under one assumption about scenes: they are piecewise smooth, so their second
differences along a row or a column are small except at edges and kinks, while a fixed pattern's
are not. Per part, in order (columns, then rows on what the columns leave, then pixels on what both
leave), the pattern is the maximum a-posteriori estimate

    ``min_P  sum_i sum rho((D2 (D_i - P)) / s_i) + |P|^2 / sigma_P^2``

with ``D2`` the second difference along x (columns) or along x and y (pixels), summed with the
same term for the third difference at a gap of 2 or 4 pixels where the folder's scenes allow it
(:data:`GAP_SETS`, chosen per axis by how well a fit on one half of the scenes predicts the other:
a third difference vanishes on a scene's steady curvature too and sees the pattern's low
frequencies, which the scenes' slopes hide from neighbours' second differences, but a wide one
lets more of a kink in), ``s_i`` the noise
of a second difference (a per-frame ``k_i / A`` model fitted from the data, or one level per frame
without amplitudes), ``rho`` quadratic first and then Tukey's biweight (edges, kinks and flying
pixels get weight 0; the least-squares start already leaves out differences far beyond the
frame's spread, :data:`START_CLIP`), and the white prior's ``sigma_P^2`` re-estimated from the
solution (an empirical Bayes iteration: the estimate's power, measured by its roughness, a white
profile's second differences having 6 times its variance, plus its posterior variance in the
diagonal approximation; without a pattern it goes to zero). The profiles are solved exactly
(a banded system), the pixel part by conjugate gradients.

What a scene can never be told apart from is left out: a smooth pattern (the low frequencies,
shrunk by the prior) and anything every frame shares because every frame shows the same scene.
Frames of one scene are found first (two frames whose difference is white noise, the pattern
cancelling in it, show one scene: :data:`SAME_SCENE`) and averaged; with fewer than
:data:`MIN_SCENES` scenes nothing is learned (a still camera: its scene would be taken for the
pattern).

**Evidence.** The scenes are split into two halves (alternating) and each part is learned on each
half alone. A part is kept only when the halves agree: ``z = <a, b> / (sqrt(n) v)`` of at least
:data:`MIN_Z` (``v``: the halves' error variance ``mean((a - b)^2) / 2``, ``n`` the part's
values) -- a scene's structure that is not in every frame falls apart between the halves, noise
does not correlate. The kept part is scaled by ``S / (S + v / 2)`` (``S = <a, b> / n``: the
pattern's power the halves share; the Wiener factor of the whole folder's estimate), a profile in
each of its frequency bands (:data:`BANDS`) on its own: the curvature of scenes that one half has
and the other not falls into the low bands and is shrunk there without weakening stripes above.

References: the second-difference (smoothness) prior of Tikhonov regularisation and the robust
(Tukey) M-estimator of Beaton & Tukey, Technometrics 16(2), 1974; stripe / fixed-pattern models of
column-parallel read-out (EMVA Standard 1288, DSNU).
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field

import torch

from .. import constants as K
from ..runtime import PatternCorrection, valid_mask
from ..runtime._phasor import metres_per_radian, ray_norm
from .calibrate import FixedPattern
from .calibrate_complex import ComplexPattern

__all__ = [
    "MIN_SCENES",
    "MIN_Z",
    "SAME_SCENE",
    "LearnedPattern",
    "learn_folder_pattern",
]

#: at least this many distinct scenes are needed to learn a pattern
MIN_SCENES = 4
#: two frames show one scene when the spread of their difference is below this many times the
#: spread of its white part (:func:`_scenes`)
SAME_SCENE = 2.0
#: the shortest side of a frame a pattern is learned on (fewer columns or rows cannot show
#: their agreement between two halves)
MIN_SIDE = 8
#: a part is kept when its two halves' agreement reaches this significance
MIN_Z = 6.0
#: Tukey's biweight cut-off, in noise standard deviations of a second difference
TUKEY_C = 3.0
#: the gaps of the column and row models' differences: gap 1 sees a pattern's high frequencies,
#: a wider gap its low ones (a plane's differences vanish at any gap) but lets more of a kink in;
#: each folder takes the set whose profiles predict the other half of its scenes best
#: (:func:`_choose_gaps`)
GAP_SETS: tuple[tuple[int, ...], ...] = ((1,), (1, 2), (1, 4))
#: the gaps used where none were chosen
GAPS: tuple[int, ...] = (1,)
#: the difference taken at each gap: the second (gap 1); the third at wider gaps, which also
#: vanishes on a scene's steady curvature (a slanted plane's depth is not linear in x)
_KERNELS: dict[int, tuple[float, ...]] = {1: (1.0, -2.0, 1.0)}
_WIDE_KERNEL = (1.0, -3.0, 3.0, -1.0)


def _kernel(gap: int) -> tuple[float, ...]:
    return _KERNELS.get(gap, _WIDE_KERNEL)


#: the gaps of a read-out offset's fit: its depth effect follows the scene's phase and amplitude,
#: so a wide gap's differences also carry what a curved scene's shading leaves in them (the gaps
#: chosen for the offsets' columns lifted the complex read-out's boxes by 0.41 dB, but cost a
#: cylinders frame with stripes as a complex offset 0.40 dB, its record claiming 13 dB). Second
#: differences of neighbours alone hardly see the profile's lowest frequencies: below a tenth of
#: the Nyquist frequency nothing of a white complex offset's profile is recovered
READOUT_GAPS: tuple[int, ...] = (1,)
#: the least-squares start leaves out second differences beyond this many robust spreads
START_CLIP = 5.0
#: empirical Bayes iterations (the first one least squares)
ITERATIONS = 6
#: conjugate-gradient iterations of the pixel part per outer iteration
CG_ITERATIONS = 60
#: parts below this RMS (mm) are not worth applying
MIN_RMS_MM = 0.05
PARTS = ("columns", "rows", "pixels")


@dataclass
class LearnedPattern:
    """What :func:`learn_folder_pattern` found.

    Attributes:
        pattern: the kept parts as a :class:`~tof_fpn_torch.analysis.FixedPattern` (depth units
            of the input), or None when no part was confirmed.
        frames: frames given (valid ones); scenes: distinct scenes among them.
        parts: per part (``columns``, ``rows``, ``pixels``): ``rms_mm`` (as applied), ``z``
            (halves' agreement), ``factor`` (the Wiener factor applied, 0: not kept).
        reason: why nothing was learned (None when a part was kept).
        readout: the column part as a read-out offset (``~ 1 / A``), a
            :class:`~tof_fpn_torch.analysis.ComplexPattern` removed after ``pattern``, when the
            held-out half preferred it (then ``pattern`` holds no column offsets).
        evidence: the read-out test: the frequency that fitted best and both models'
            held-out losses.
    """

    pattern: FixedPattern | None
    frames: int
    scenes: int
    parts: dict = field(default_factory=dict)
    reason: str | None = None
    readout: ComplexPattern | None = None
    evidence: dict = field(default_factory=dict)

    def module(self) -> PatternCorrection:
        """The run-time stage: the offsets, then the read-out offset where there is one
        (:class:`~tof_fpn_torch.runtime.PatternCorrection`). ValueError when nothing was
        learned."""
        if self.pattern is None:
            raise ValueError(f"nothing to apply: {self.reason}")
        parts = [self.pattern.module()]
        if self.readout is not None:
            parts.append(self.readout.module(wrap=False))  # the frequency may be a guess
        return PatternCorrection(parts, source="learned", learned=json.dumps(self.record()))

    def record(self) -> dict:
        """What it was learned from, as plain values (frames, scenes, parts, the read-out test)."""
        return {
            "frames": self.frames,
            "scenes": self.scenes,
            "parts": self.parts,
            **self.evidence,
        }

    def to_arrays(self) -> tuple[dict[str, torch.Tensor], dict]:
        """``(arrays, meta)`` of the pattern file format ``learned``
        (:mod:`tof_fpn_torch.io.patterns`). ValueError when nothing was learned."""
        if self.pattern is None:
            raise ValueError(f"nothing to save: {self.reason}")
        h, w = self.pattern.shape
        p = self.pattern
        zero = torch.zeros(w, dtype=torch.float64)
        ro = self.readout
        arrays = {
            "column_offset": p.column_offset,
            "row_offset": p.row_offset,
            "pixel_offset": torch.zeros(h, w) if p.pixel_offset is None else p.pixel_offset,
            "readout_re": zero if ro is None else ro.column_offset_re,
            "readout_im": zero if ro is None else ro.column_offset_im,
        }
        meta = {
            "modulation_frequency_hz": None if ro is None else ro.modulation_frequency_hz,
            "focal_length_px": None if ro is None else ro.focal_length_px,
            "amplitude_floor": None if ro is None else ro.amplitude_floor,
            "has_pixel": p.pixel_offset is not None,
            "learned": self.record(),
        }
        return {k: t.detach().double().cpu() for k, t in arrays.items()}, meta

    @classmethod
    def from_arrays(cls, arrays: dict[str, torch.Tensor], meta: dict) -> LearnedPattern:
        """The pattern of :meth:`to_arrays`' ``(arrays, meta)``."""
        rec = meta["learned"]
        h = arrays["row_offset"].numel()
        pattern = FixedPattern(
            column_offset=arrays["column_offset"],
            row_offset=arrays["row_offset"],
            pixel_offset=arrays["pixel_offset"] if meta["has_pixel"] else None,
            frames=rec["frames"],
            groups=rec["scenes"],
        )
        f = meta["modulation_frequency_hz"]
        readout = None
        if f is not None:
            readout = ComplexPattern(
                column_offset_re=arrays["readout_re"],
                column_offset_im=arrays["readout_im"],
                modulation_frequency_hz=float(f),
                frames=rec["frames"],
                height=h,
                focal_length_px=meta.get("focal_length_px"),
                amplitude_floor=meta.get("amplitude_floor"),
            )
        evidence = {k: v for k, v in rec.items() if k not in ("frames", "scenes", "parts")}
        return cls(pattern, rec["frames"], rec["scenes"], rec["parts"], None, readout, evidence)

    def summary(self) -> str:
        """One line: what was learned from what, or why nothing was."""
        if self.pattern is None:
            return f"no fixed pattern learned from {self.frames} frame(s): {self.reason}"
        kept = [
            f"{name} {p['rms_mm']:.2f} mm (z {p['z']:.0f})"
            for name, p in self.parts.items()
            if p["factor"] > 0
        ]
        if self.readout is not None:
            f = self.readout.modulation_frequency_hz / 1e6
            fov = self.evidence.get("field_of_view_deg")
            ray = "" if fov is None else f", depth along the axis of a {fov:g} degree field"
            kept[0] += f", a read-out offset ~ 1/A (best fit at {f:g} MHz{ray})"
        return (
            f"fixed pattern learned from {self.frames} frames of {self.scenes} scenes: "
            + ", ".join(kept)
        )


# --------------------------------------------------------------------------------------------
# second differences and their adjoints (NaN propagates: a difference touching an invalid pixel
# is not an observation)


def _diff(x: torch.Tensor, dim: int, gap: int = 1) -> torch.Tensor:
    """The difference :func:`_kernel` of ``gap`` along ``dim`` (second at gap 1, else third)."""
    kernel = _kernel(gap)
    m = x.shape[dim] - (len(kernel) - 1) * gap
    return sum(c * x.narrow(dim, k * gap, m) for k, c in enumerate(kernel))


def _diff_t(e: torch.Tensor, dim: int, n: int, gap: int = 1, squared: bool = False):
    """The adjoint of :func:`_diff` (back to length ``n`` along ``dim``); with ``squared``, the
    diagonal of ``D^T diag(e) D``."""
    kernel = _kernel(gap)
    shape = list(e.shape)
    shape[dim] = n
    out = e.new_zeros(shape)
    m = e.shape[dim]
    for k, c in enumerate(kernel):
        out.narrow(dim, k * gap, m).add_((c * c if squared else c) * e)
    return out


def _diff_var(var: torch.Tensor, dim: int, gap: int = 1) -> torch.Tensor:
    """The variance of :func:`_diff` of independent pixels of variance ``var``."""
    kernel = _kernel(gap)
    m = var.shape[dim] - (len(kernel) - 1) * gap
    return sum(c * c * var.narrow(dim, k * gap, m) for k, c in enumerate(kernel))


def _d2(x: torch.Tensor, dim: int) -> torch.Tensor:
    return _diff(x, dim, 1)


def _first_prior(weights: torch.Tensor) -> float:
    """The first iteration's prior weight: 1 % of the typical observation weight (of the
    observed unknowns: a column with no valid pixel does not count), > 0."""
    seen = weights[weights > 0]
    return 1e-2 * float(seen.median()) if seen.numel() else 1.0


def _spd_solve(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """``a^-1 b`` for a symmetric positive definite ``a`` (Cholesky); zeros if it is not."""
    chol, info = torch.linalg.cholesky_ex(a)
    if int(info) != 0:
        return torch.zeros_like(b)
    return torch.cholesky_solve(b[:, None], chol)[:, 0]


def _tukey(u: torch.Tensor) -> torch.Tensor:
    return torch.where(u < 1, (1 - u * u) ** 2, torch.zeros_like(u))


def _start_weights(e0: torch.Tensor, w0: torch.Tensor, sd: torch.Tensor) -> torch.Tensor:
    """The first (least-squares) iteration's weights: ``w0`` without the second differences
    beyond :data:`START_CLIP` robust spreads (MAD) of the frame's ``e0 / sd``. An edge or kink
    that every frame shows at the same place (a still scene, one object that spans the frame) would
    otherwise be fitted by the least-squares start and, once fitted, never look like an outlier to
    the Tukey iterations."""
    u = (e0 / sd).abs()
    out = w0.clone()
    for i in range(u.shape[0]):
        seen = u[i][w0[i] > 0]
        if seen.numel():
            out[i] = torch.where(u[i] <= START_CLIP * 1.4826 * seen.median(), w0[i], 0.0)
    return out


def _noise_var(d: torch.Tensor, amp: torch.Tensor | None) -> torch.Tensor:
    """(N, H, W) noise variance: ``(k_i / A)^2`` with ``k_i`` from the MAD of the frame's second
    differences, each divided by its model sd ``sqrt(1/A_{x-1}^2 + 4/A_x^2 + 1/A_{x+1}^2)`` (one
    level per frame without amplitudes); edges are outliers the MAD ignores."""
    a = torch.ones_like(d) if amp is None else amp
    med = torch.nanmedian(a.flatten(1).where(torch.isfinite(d.flatten(1)), math.nan), 1).values
    a = torch.maximum(a, 0.05 * med.clamp_min(1e-12)[:, None, None])
    inv = 1.0 / (a * a)
    e = (_d2(d, -1) / _diff_var(inv, -1).sqrt()).flatten(1)  # sd k where the model holds
    k = torch.nanmedian(e.abs(), 1).values * 1.4826
    k = torch.nan_to_num(k, nan=1.0).clamp_min(1e-6)
    return (k[:, None, None] / a) ** 2


#: modulation frequencies (Hz) tried for a read-out offset when the camera's is not known: the
#: common continuous-wave ToF frequencies (PMD, Kinect v2, ESPROS, ADI, Melexis data sheets)
FREQUENCIES_HZ: tuple[float, ...] = (
    10e6, 12e6, 15e6, 16e6, K.CAMCUBE_MODULATION_FREQUENCY_HZ, 24e6, 30e6, 40e6, 50e6, 60e6,
    80e6, 100e6,
)  # fmt: skip
#: the read-out model (two more profiles) is chosen when its held-out loss is below the offset
#: model's by this share (its two more profiles also fit what a scene's edges and curvature leave
#: in the second differences: camera folders whose read-out model predicted 17 % (boxes) and
#: 18 % (staircases, with every profile shrunk band by band) better were made worse by it, by up
#: to 1.6 dB; true read-out offsets predicted 30-50 % better, some as little as 16-22 %)
READOUT_MARGIN = 0.25
#: rows (columns) of each frame a column (row) profile is fitted on, at most
PROFILE_LINES = 128
#: the amplitude floor of the ``1 / A`` basis, as a share of the median amplitude
AMPLITUDE_FLOOR = 0.2
#: iterations of the fits that choose the frequency and the field of view (the first least
#: squares, then Tukey: edges must not choose)
SELECT_ITERATIONS = 3


#: horizontal fields of view (degrees) tried for a read-out offset: the phase is that of the
#: radial distance ``Z |ray|`` of a camera that writes depth ``Z`` along its optical axis (None:
#: the depth is the radial distance); CamCube 40, ESPROS 50, Kinect v2 70, Azure 75 / 120 degrees
FIELDS_OF_VIEW_DEG: tuple[float | None, ...] = (None, 40.0, 55.0, 70.0, 90.0, 120.0)


def _focal_px(width: int, fov_deg: float | None) -> float | None:
    """The focal length (pixels) of a horizontal field of view over ``width`` pixels."""
    return None if fov_deg is None else (width / 2) / math.tan(math.radians(fov_deg) / 2)


def _ray(h: int, w: int, focal_px: float | None) -> torch.Tensor | None:
    """(H, W) ray lengths per unit of depth (None: radial distance)."""
    if focal_px is None:
        return None
    return ray_norm(h, w, focal_px, torch.float64, torch.device("cpu"))


def _basis(
    d: torch.Tensor, amp: torch.Tensor, f_hz: float, ray: torch.Tensor | None = None
) -> tuple[torch.Tensor, float]:
    """(3, N, H, W) channels of a column's depth effect: ``1`` (an offset) and
    ``A_ref cos(phi) / A``, ``A_ref sin(phi) / A`` (a complex read-out offset ``c``: the depth
    moves by ``scale Im(c e^{-j phi}) / A``, eq. (10)); ``phi`` from the depth in mm (times the
    rays' lengths ``ray`` (H, W) when given); ``A_ref`` the median amplitude (returned)."""
    scale_mm = 1000.0 * metres_per_radian(f_hz)
    ok = torch.isfinite(d)
    a_ref = float(amp[ok].median()) if bool(ok.any()) else 1.0
    a = amp.clamp_min(AMPLITUDE_FLOOR * a_ref)
    phi = torch.nan_to_num(d) / scale_mm
    if ray is not None:
        phi = phi * ray
    return torch.stack(
        [torch.ones_like(d), a_ref * torch.cos(phi) / a, a_ref * torch.sin(phi) / a]
    ), a_ref


def _column_terms(
    d: torch.Tensor, var: torch.Tensor, basis: torch.Tensor, gaps: tuple[int, ...] | None = None
) -> list[tuple]:
    """The observations of the column model, one set per gap ``g`` of :data:`GAPS` (or
    ``gaps``): the differences :func:`_diff` along x (the second at gap 1, the third at wider
    gaps), their weights and sds, the basis at the ``L`` pixels of each difference
    ``(L, K, N, H, W - (L - 1) g)``, and ``g``."""
    w = d.shape[-1]
    out = []
    for g in GAPS if gaps is None else gaps:
        kappa = _kernel(g)
        m = w - (len(kappa) - 1) * g
        if m < 1:
            continue
        e = _diff(d, -1, g)
        s2 = _diff_var(var, -1, g)
        ok = torch.isfinite(e) & torch.isfinite(s2)
        e0 = torch.where(ok, e, 0.0)
        w0 = torch.where(ok, 1.0 / torch.where(ok, s2, 1.0), 0.0)
        sd = torch.where(ok, s2, 1.0).sqrt()
        b = torch.nan_to_num(basis)
        shifted = torch.stack([b[..., k * g : k * g + m] for k in range(len(kappa))])  # (L,K,N,H,m)
        out.append((e0, w0, sd, shifted, g))
    return out


def _column_model(theta: torch.Tensor, shifted: torch.Tensor, gap: int = 1) -> torch.Tensor:
    """The second difference (of gap ``gap``) of the pattern ``sum_a theta_a(x) B_a`` at each
    observation."""
    m = shifted.shape[-1]
    out = torch.zeros_like(shifted[0, 0])
    for k, c in enumerate(_kernel(gap)):
        th = theta[:, k * gap : k * gap + m]  # (K, m)
        out = out + c * (shifted[k] * th[:, None, None, :]).sum(0)
    return out


def _tukey_loss(u: torch.Tensor) -> torch.Tensor:
    return torch.where(u < 1, 1 - (1 - u * u) ** 3, torch.ones_like(u))


def _columns(terms: list[tuple], iterations: int = ITERATIONS):
    """Column profiles ``theta`` (K, W) of the channels (module docstring) and the robust loss
    of the fit: the normal equations of the weighted second differences (every gap's), solved
    densely, with one white prior per kind of channel (offsets; the read-out offset's two
    channels)."""
    k_ch = terms[0][3].shape[1]
    w = terms[0][3].shape[-1] + (terms[0][3].shape[0] - 1) * terms[0][4]
    theta = terms[0][3].new_zeros(k_ch, w)
    post = theta.new_zeros(k_ch * w)  # the posterior variances, from the first solve on
    for it in range(iterations):
        mat = theta.new_zeros(k_ch * w, k_ch * w)
        rhs = theta.new_zeros(k_ch * w)
        seen = False
        for e0, w0, sd, shifted, gap in terms:
            m = shifted.shape[-1]
            if it == 0:
                wt = _start_weights(e0, w0, sd)
            else:
                u = (e0 - _column_model(theta, shifted, gap)).abs() / (TUKEY_C * sd)
                wt = w0 * _tukey(u)
            if not bool(wt.gt(0).any()):
                continue
            seen = True
            # every (shift, channel) pair at once: a batched product over the pixels of a column
            taps = shifted.shape[0]
            flat = shifted.reshape(taps * k_ch, -1, m).permute(2, 0, 1)  # (m, LK, N*H)
            kappa = torch.tensor(_kernel(gap), dtype=flat.dtype).repeat_interleave(k_ch)
            weighted = flat * wt.reshape(1, -1, m).permute(2, 0, 1)
            g = torch.bmm(weighted, flat.transpose(1, 2)) * (kappa[:, None] * kappa[None, :])
            r = (weighted * e0.reshape(1, -1, m).permute(2, 0, 1)).sum(2) * kappa  # (m, 3K)
            # (shift k, channel a) of observation x is unknown a * W + x + k * gap
            shift = torch.arange(taps).repeat_interleave(k_ch) * gap
            pos = torch.arange(k_ch).repeat(taps) * w + shift
            unknown = pos[None, :] + torch.arange(m)[:, None]  # (m, 3K)
            mat.index_put_(
                (
                    unknown[:, :, None].expand_as(g).flatten(),
                    unknown[:, None, :].expand_as(g).flatten(),
                ),
                g.flatten(),
                accumulate=True,
            )
            rhs.index_add_(0, unknown.flatten(), r.flatten())
        if not seen:
            return theta.new_zeros(k_ch, w), float("inf")
        diag = torch.diagonal(mat)
        if it == 0:
            lam = [_first_prior(diag[:w])] * k_ch
        else:
            # the white prior's variance from the estimate's roughness: a white profile's second
            # differences have 6 times its variance, while a smooth shape a scene leaves (which
            # the data can hardly tell from a pattern) has almost none and cannot weaken it
            power = _d2(theta, -1).pow(2).mean(1) / 6.0  # (K,)
            lam = [1.0 / max(float(power[0] + post[:w].mean()), 1e-8)]
            if k_ch > 1:
                prior = float(power[1:].mean() + post[w:].mean())
                lam += [1.0 / max(prior, 1e-8)] * (k_ch - 1)
        mat = mat + torch.diag(torch.tensor(lam, dtype=mat.dtype).repeat_interleave(w))
        theta = _spd_solve(mat, rhs).view(k_ch, w)
        post = 1.0 / torch.diagonal(mat)  # the posterior variances (diagonal approximation)
        theta = theta - theta.mean(1, keepdim=True)
    return theta, _loss(terms, theta)


def _loss(terms: list[tuple], theta: torch.Tensor) -> float:
    """The robust (Tukey) loss of ``theta`` on the observations ``terms``."""
    total = 0.0
    for e0, w0, sd, shifted, gap in terms:
        u = (e0 - _column_model(theta, shifted, gap)).abs() / (TUKEY_C * sd)
        total += float(_tukey_loss(u)[w0 > 0].sum())
    return total


def _pixels(
    d: torch.Tensor,
    var: torch.Tensor,
    gaps: tuple[int, ...] = GAPS,
    iterations: int = ITERATIONS,
) -> torch.Tensor:
    """Per-pixel offsets of (N, H, W) frames (module docstring), zero-mean: the differences of
    every gap of ``gaps`` along x and along y."""
    _, h, w = d.shape
    terms = []
    for dim, n in ((-1, w), (-2, h)):
        for gap in gaps:
            if n - (len(_kernel(gap)) - 1) * gap < 1:
                continue
            e = _diff(d, dim, gap)
            s2 = _diff_var(var, dim, gap)
            ok = torch.isfinite(e) & torch.isfinite(s2)
            terms.append(
                (
                    dim,
                    n,
                    gap,
                    torch.where(ok, e, 0.0),
                    torch.where(ok, 1.0 / torch.where(ok, s2, 1.0), 0.0),
                    torch.where(ok, s2, 1.0).sqrt(),
                )
            )
    p = d.new_zeros(h, w)
    if not terms:
        return p
    lam = None
    post = torch.zeros_like(p)  # the posterior variances, from the first solve on
    for it in range(iterations):
        rhs = torch.zeros_like(p)
        counts = []
        for dim, n, gap, e0, w0, sd in terms:
            if it == 0:
                wt = _start_weights(e0, w0, sd)
            else:
                wt = w0 * _tukey((e0 - _diff(p[None], dim, gap)).abs() / (TUKEY_C * sd))
            cnt = wt.sum(0)
            rhs += _diff_t((wt * e0).sum(0), dim, n, gap)
            counts.append((dim, n, gap, cnt))
        if lam is None:
            lam = _first_prior(torch.cat([c.flatten() for *_, c in counts]))
        else:  # the white prior's variance from the map's roughness (as in :func:`_columns`)
            power = sum(float(_d2(p, dim).pow(2).mean()) for dim in (-1, -2)) / 12.0
            lam = 1.0 / max(power + float(post.mean()), 1e-8)
        if lam <= 0:
            return torch.zeros_like(p)

        def op(x: torch.Tensor, lam: float = lam, counts: list = counts) -> torch.Tensor:
            out = lam * x
            for dim, n, gap, cnt in counts:
                out = out + _diff_t(cnt * _diff(x, dim, gap), dim, n, gap)
            return out

        p = _cg(op, rhs, p)
        diag = torch.full_like(p, lam)
        for dim, n, gap, cnt in counts:
            diag += _diff_t(cnt, dim, n, gap, squared=True)
        post = 1.0 / diag  # the posterior variances (diagonal approximation)
    return p - p.mean()


def _cg(op, b: torch.Tensor, x: torch.Tensor) -> torch.Tensor:
    x = x.clone()
    r = b - op(x)
    z = r.clone()
    rr = float((r * r).sum())
    stop = 1e-20 * max(float((b * b).sum()), 1e-300)
    for _ in range(CG_ITERATIONS):
        if rr <= stop:
            break
        az = op(z)
        alpha = rr / max(float((z * az).sum()), 1e-300)
        x += alpha * z
        r -= alpha * az
        rr_new = float((r * r).sum())
        z = r + (rr_new / rr) * z
        rr = rr_new
    return x


def _learn(
    d: torch.Tensor, var: torch.Tensor, basis: torch.Tensor | None, gaps: dict | None = None
) -> dict[str, torch.Tensor]:
    """Columns (the channels of ``basis``, offsets only when None), rows on what the columns
    leave, pixels on what both leave; ``columns`` is (K, W). A profile is the same down its
    columns (along its rows): it is fitted on at most :data:`PROFILE_LINES` rows (columns) of
    each frame. ``gaps``: per axis (``columns``, ``rows``) the gaps of the differences
    (default :data:`GAPS`; a read-out's columns always :data:`READOUT_GAPS`); the pixels take
    both axes' gaps."""
    gaps = gaps or {}
    g_col = READOUT_GAPS if basis is not None else gaps.get("columns", GAPS)
    g_row = gaps.get("rows", GAPS)
    b = torch.ones_like(d)[None] if basis is None else basis
    rows = slice(None, None, max(1, d.shape[1] // PROFILE_LINES))
    theta, _ = _columns(_column_terms(d[:, rows], var[:, rows], b[:, :, rows], g_col))
    d = d - (theta[:, None, None, :] * b).sum(0)
    cols = slice(None, None, max(1, d.shape[2] // PROFILE_LINES))
    dt, vt = d[:, :, cols].transpose(1, 2), var[:, :, cols].transpose(1, 2)  # rows as columns
    row = _columns(_column_terms(dt, vt, torch.ones_like(dt)[None], g_row))[0][0]
    d = d - row[None, :, None]
    g_pix = tuple(sorted(set(gaps.get("columns", GAPS)) | set(g_row)))
    return {"columns": theta, "rows": row, "pixels": _pixels(d, var, g_pix)}


def _choose_gaps(d: torch.Tensor, var: torch.Tensor) -> dict[str, tuple[int, ...]]:
    """Per axis, the set of :data:`GAP_SETS` whose offset profile, fitted on one half of the
    scenes, predicts the other half's differences of every gap best (the robust loss of
    :func:`_columns`, both ways): wide gaps see a pattern's low frequencies where the scenes are
    smooth over them and let kinks and curvature in where they are not."""
    halves = (slice(0, None, 2), slice(1, None, 2))
    union = tuple(sorted({g for s in GAP_SETS for g in s}))
    out = {}
    for axis in ("columns", "rows"):
        x, v = (d, var) if axis == "columns" else (d.transpose(1, 2), var.transpose(1, 2))
        lines = slice(None, None, max(1, x.shape[1] // PROFILE_LINES))
        x, v = x[:, lines], v[:, lines]
        ones = torch.ones_like(x)[None]
        held = [_column_terms(x[h], v[h], ones[:, h], union) for h in halves]
        best = None
        for gaps in GAP_SETS:
            fit = [_columns(_column_terms(x[h], v[h], ones[:, h], gaps))[0] for h in halves]
            loss = _loss(held[1], fit[0]) + _loss(held[0], fit[1])
            if best is None or loss < best[0]:
                best = (loss, gaps)
        out[axis] = best[1]
    return out


def _readout_model(
    d: torch.Tensor, var: torch.Tensor, amp: torch.Tensor, frequencies: tuple[float, ...]
) -> tuple[float | None, float | None, dict]:
    """Whether the column pattern is a read-out offset (``~ 1 / A``) rather than a depth offset:
    the three frequencies whose bases fit best (robust fits on ~32 rows), each with every field
    of view (:data:`FIELDS_OF_VIEW_DEG`), scored by how well a fit on one half of the scenes
    predicts the other; then both models learned on each half and scored on the other half (on
    ~128 rows) (the robust loss of :func:`_columns`); the read-out model is chosen only when it
    predicts the held-out half better by :data:`READOUT_MARGIN`. ``(f or None, focal length (px)
    or None, evidence)``."""
    sub = slice(None, None, max(1, d.shape[1] // 32))  # ~32 rows: the frequency's choice
    ds, vs, amps = d[:, sub], var[:, sub], amp[:, sub]
    h, w = d.shape[-2:]

    halves = (slice(0, None, 2), slice(1, None, 2))

    def sub_basis(f: float, fov: float | None) -> torch.Tensor:  # of the ~32 rows
        ray = _ray(h, w, _focal_px(w, fov))
        return _basis(ds, amps, f, None if ray is None else ray[sub])[0]

    def fit(f: float, fov: float | None) -> float:
        terms = _column_terms(ds, vs, sub_basis(f, fov), gaps=READOUT_GAPS)
        return _columns(terms, iterations=SELECT_ITERATIONS)[1]

    def held_out(f: float, fov: float | None) -> float:
        b = sub_basis(f, fov)
        terms = [_column_terms(ds[h_], vs[h_], b[:, h_], gaps=READOUT_GAPS) for h_ in halves]
        theta = [_columns(t, iterations=SELECT_ITERATIONS)[0] for t in terms]
        return _loss(terms[1], theta[0]) + _loss(terms[0], theta[1])

    ranked = sorted((fit(f, None), f) for f in frequencies)
    cands = [(held_out(f, fov), i, f, fov)
             for _, f in ranked[:3] for i, fov in enumerate(FIELDS_OF_VIEW_DEG)]  # fmt: skip
    _, _, best_f, best_fov = min(cands)
    focal = _focal_px(w, best_fov)
    b_full, _ = _basis(d, amp, best_f, _ray(h, w, focal))
    ones = torch.ones_like(d)[None]
    held = {}
    for name, basis in (("offset", ones), ("readout", b_full)):
        rows = slice(None, None, max(1, d.shape[1] // 128))  # ~128 rows: the model's choice
        terms = [
            _column_terms(d[h_, rows], var[h_, rows], basis[:, h_, rows], gaps=READOUT_GAPS)
            for h_ in halves
        ]
        theta = [_columns(t, iterations=5)[0] for t in terms]
        held[name] = _loss(terms[1], theta[0]) + _loss(terms[0], theta[1])
    chosen = held["readout"] < (1 - READOUT_MARGIN) * held["offset"]
    return (
        (best_f if chosen else None),
        (focal if chosen else None),
        {
            "frequency_hz": best_f,
            "field_of_view_deg": best_fov,
            "held_out_loss": {k: round(v, 2) for k, v in held.items()},
        },
    )


def _scenes(d: torch.Tensor) -> list[list[int]]:
    """Frames grouped by scene. The difference of two frames of one scene is their noise alone
    (the pattern cancels): white, so its spread (MAD about its median) is that of its second
    differences along x divided by ``sqrt(6)``; a scene that moved adds smooth structure that
    raises the first and hardly the second. ``i`` and ``j`` show one scene when the ratio is
    below :data:`SAME_SCENE`."""
    n = d.shape[0]
    parent = list(range(n))

    def root(i: int) -> int:
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return i

    step = max(1, d.shape[1] // 64)  # whole rows: the second differences stay along x
    ds = d[:, ::step]
    for i in range(n):
        for j in range(i + 1, n):
            diff = ds[i] - ds[j]
            flat = diff[torch.isfinite(diff)]
            curv = _d2(diff, -1)
            curv = curv[torch.isfinite(curv)]
            if flat.numel() < 16 or curv.numel() < 16:
                continue
            spread = float((flat - flat.median()).abs().median())
            noise = float(curv.abs().median()) / math.sqrt(6.0)
            if spread < SAME_SCENE * noise:
                parent[root(j)] = root(i)
    groups: dict[int, list[int]] = {}
    for i in range(n):
        groups.setdefault(root(i), []).append(i)
    return list(groups.values())


def _merge(d: torch.Tensor, var: torch.Tensor, amp: torch.Tensor | None, groups: list[list[int]]):
    """One frame per scene: the inverse-variance mean of its frames (and their mean
    amplitude)."""
    out_d, out_v = [], []
    out_a = None if amp is None else torch.stack([amp[g].mean(0) for g in groups])
    for g in groups:
        x, v = d[g], var[g]
        ok = torch.isfinite(x)
        wt = torch.where(ok, 1.0 / v, 0.0)
        sw = wt.sum(0)
        m = torch.where(
            sw > 0, (wt * torch.where(ok, x, 0.0)).sum(0) / sw.clamp_min(1e-300), math.nan
        )
        out_d.append(m)
        out_v.append(torch.where(sw > 0, 1.0 / sw.clamp_min(1e-300), math.inf))
    return torch.stack(out_d), torch.stack(out_v), out_a


def _agreement(a: torch.Tensor, b: torch.Tensor) -> tuple[float, float, float]:
    """``(z, S, v)`` of two independent estimates of one part (module docstring)."""
    a, b = a.flatten() - a.mean(), b.flatten() - b.mean()
    n = a.numel()
    v = float(((a - b) ** 2).mean()) / 2
    ab = float(a @ b)
    if v <= 0 or n == 0:
        return 0.0, 0.0, v
    return ab / (math.sqrt(n) * v), ab / n, v


#: upper edges of the frequency bands of a profile (fractions of the Nyquist frequency): the halves
#: are compared, and the estimate shrunk, in each band on its own (octaves up to a quarter)
BANDS = (1 / 16, 1 / 8, 1 / 4, 1 / 2, 1.0)
#: a band holds at least this many frequencies (narrower ones join the next): the halves'
#: agreement on fewer is too noisy to shrink by
BAND_MIN_BINS = 8


def _bands(theta: torch.Tensor) -> list[torch.Tensor]:
    """``theta`` (..., W) split along its last axis into the frequency bands of :data:`BANDS`
    (at least :data:`BAND_MIN_BINS` frequencies each, the last takes the rest; they sum to
    ``theta``)."""
    n = theta.shape[-1]
    spec = torch.fft.rfft(theta, dim=-1)
    f = torch.arange(spec.shape[-1], dtype=torch.float64) * (2.0 / n)  # fraction of Nyquist
    out, start = [], 0
    for hi in BANDS[:-1]:
        stop = int((f < hi).sum())
        if stop - start >= BAND_MIN_BINS and f.numel() - stop >= BAND_MIN_BINS:
            m = torch.zeros_like(f)
            m[start:stop] = 1.0
            out.append(torch.fft.irfft(spec * m, n=n, dim=-1))
            start = stop
    m = torch.zeros_like(f)
    m[start:] = 1.0
    out.append(torch.fft.irfft(spec * m, n=n, dim=-1))
    return out


def _confirmed(
    d: torch.Tensor,
    var: torch.Tensor,
    basis: torch.Tensor | None,
    min_z: float,
    gaps: dict | None = None,
):
    """Each part learned on all scenes and on each half; ``(parts, kept)``: per part its RMS
    (the columns' depth effect over the frames), the halves' agreement ``z`` and the factor
    applied, and the kept (scaled) estimates (module docstring)."""
    full = _learn(d, var, basis, gaps)
    halves = [slice(0, None, 2), slice(1, None, 2)]
    half_a, half_b = (
        _learn(d[h], var[h], None if basis is None else basis[:, h], gaps) for h in halves
    )
    parts, kept = {}, {}
    b = torch.ones_like(d)[None] if basis is None else basis
    seen = torch.isfinite(d)

    def effect(name: str, x: torch.Tensor) -> torch.Tensor:
        """What a part's estimate does to the depth: a read-out's channels can trade off where
        the phase hardly varies, so its columns are compared on the depth of every frame."""
        if name == "columns" and basis is not None:
            return torch.nan_to_num((x[:, None, None, :] * b).sum(0)[seen])
        return x

    for name in PARTS:
        z, _, _ = _agreement(effect(name, half_a[name]), effect(name, half_b[name]))
        est = torch.zeros_like(full[name])
        if z >= min_z:
            if name == "pixels":
                split = [(full[name], half_a[name], half_b[name])]
            else:  # per band: a scene's smooth leak agrees less between the halves than stripes
                split = zip(*(_bands(h[name]) for h in (full, half_a, half_b)), strict=True)
            for f_b, a_b, b_b in split:
                _, s, v = _agreement(effect(name, a_b), effect(name, b_b))
                if s > 0:
                    est = est + s / (s + v / 2) * f_b
        full_rms = float(effect(name, full[name]).pow(2).mean().sqrt())
        rms = float(effect(name, est).pow(2).mean().sqrt()) if est.numel() else 0.0
        factor = rms / full_rms if full_rms > 0 else 0.0
        if rms < MIN_RMS_MM:
            factor, rms = 0.0, 0.0
        parts[name] = {"rms_mm": round(rms, 4), "z": round(z, 2), "factor": round(factor, 4)}
        if factor > 0:
            kept[name] = est
    return parts, kept


def learn_folder_pattern(
    depth: torch.Tensor,
    amplitude: torch.Tensor | None = None,
    *,
    min_scenes: int = MIN_SCENES,
    min_z: float = MIN_Z,
    modulation_frequency_hz: float | None = None,
) -> LearnedPattern:
    """Learn the fixed pattern shared by (N, 1, H, W) ``depth`` frames of different scenes
    (module docstring).

    Args:
        depth: frames of one camera (metres or any depth unit; invalid pixels by
            :func:`~tof_fpn_torch.runtime.valid_mask` are left out).
        amplitude: optional (N, 1, H, W): extends the validity rule and weights each pixel by
            its noise (``~ 1 / A``).
        min_scenes: at least this many distinct scenes (int >= 2).
        min_z: the halves' agreement a part needs (> 0).
        modulation_frequency_hz: the camera's, for the read-out model (None: the one of
            :data:`FREQUENCIES_HZ` that fits best).

    Returns:
        a :class:`LearnedPattern` (its ``pattern`` None, with the reason, when nothing was
        confirmed).

    Raises:
        ValueError: bad shapes or arguments.
    """
    if not isinstance(depth, torch.Tensor) or depth.dim() != 4 or depth.shape[1] != 1:
        raise ValueError(
            f"depth must be a (N, 1, H, W) tensor, got {getattr(depth, 'shape', type(depth))}"
        )
    if not depth.is_floating_point():
        raise ValueError(f"depth must be floating point, got dtype {depth.dtype}")
    if amplitude is not None and (
        not isinstance(amplitude, torch.Tensor) or amplitude.shape != depth.shape
    ):
        raise ValueError(
            f"amplitude must be a tensor of depth's shape {list(depth.shape)}, got "
            f"{getattr(amplitude, 'shape', type(amplitude))}"
        )
    if isinstance(min_scenes, bool) or not isinstance(min_scenes, int) or min_scenes < 2:
        raise ValueError(f"min_scenes must be an int >= 2, got {min_scenes!r}")
    if isinstance(min_z, bool) or not isinstance(min_z, (int, float)) or not min_z > 0:
        raise ValueError(f"min_z must be a number > 0, got {min_z!r}")
    f = modulation_frequency_hz
    if f is not None and (isinstance(f, bool) or not isinstance(f, (int, float)) or not f > 0):
        raise ValueError(f"modulation_frequency_hz must be a number > 0 (Hz) or None, got {f!r}")
    n, _, h, w = depth.shape
    valid = valid_mask(depth, amplitude)[:, 0]
    keep = valid.flatten(1).any(1)
    # millimetres for the model's thresholds; the pattern goes back in the input's unit
    unit = 1000.0
    d = torch.where(valid, depth[:, 0].double() * unit, math.nan)[keep].cpu()
    amp = None if amplitude is None else amplitude[:, 0].double()[keep].cpu()
    frames = int(d.shape[0])
    if min(h, w) < MIN_SIDE:
        return LearnedPattern(
            None, frames, 0, reason=f"frames of {h} x {w} are too small (< {MIN_SIDE} a side)"
        )
    var = _noise_var(d, amp)
    groups = _scenes(d)
    scenes = len(groups)
    if scenes < min_scenes:
        still = "a still scene: " if scenes == 1 and frames > 1 else ""
        return LearnedPattern(
            None,
            frames,
            scenes,
            reason=f"{still}{scenes} distinct scene(s), a pattern needs >= {min_scenes}",
        )
    d, var, amp = _merge(d, var, amp, groups)
    # offsets first; with amplitudes the read-out model too, kept when the held-out half prefers
    # it and the halves confirm it (tried even where the offsets' columns do not agree between
    # the halves: a read-out's depth effect changes sign with the scene's phase, and periodic
    # stripes ~ 1 / A on slanted planes showed none as offsets, z < 3)
    gaps = _choose_gaps(d, var)
    parts, kept = _confirmed(d, var, None, min_z, gaps)
    f_hz, focal, evidence, a_ref = None, None, {}, 1.0
    if amp is not None and w >= 5:
        freqs = FREQUENCIES_HZ if modulation_frequency_hz is None else (modulation_frequency_hz,)
        f_hz, focal, evidence = _readout_model(d, var, amp, freqs)
        if f_hz is not None:
            basis, a_ref = _basis(d, amp, f_hz, _ray(h, w, focal))
            parts_ro, kept_ro = _confirmed(d, var, basis, min_z, gaps)
            if "columns" in kept_ro:
                parts, kept = parts_ro, kept_ro
            else:
                evidence["readout_not_confirmed"] = parts_ro["columns"]
                f_hz = None
    if not kept:
        return LearnedPattern(
            None,
            frames,
            scenes,
            parts,
            reason=f"no part of a pattern agreed between two halves of the scenes (z < {min_z:g})",
            evidence=evidence,
        )
    zero_c, zero_r = torch.zeros(w, dtype=torch.float64), torch.zeros(h, dtype=torch.float64)
    columns = kept.get("columns")
    readout = None
    if columns is not None and f_hz is not None:
        # the read-out channels: depth (mm) moves by (u cos phi + v sin phi) A_ref / A, i.e.
        # scale Im(c e^{-j phi}) / A with c = (-v + j u) A_ref / scale (scale: mm per radian)
        scale_mm = 1000.0 * metres_per_radian(f_hz)
        readout = ComplexPattern(
            column_offset_re=-columns[2] * a_ref / scale_mm,
            column_offset_im=columns[1] * a_ref / scale_mm,
            modulation_frequency_hz=f_hz,
            frames=frames,
            height=h,
            focal_length_px=focal,
            amplitude_floor=AMPLITUDE_FLOOR * a_ref,  # the model's floored 1 / A
        )
    pattern = FixedPattern(
        column_offset=(zero_c if columns is None else columns[0]) / unit,
        row_offset=kept.get("rows", zero_r * unit) / unit,
        pixel_offset=None if "pixels" not in kept else kept["pixels"] / unit,
        frames=frames,
        groups=scenes,
        flat_field=False,
    )
    return LearnedPattern(pattern, frames, scenes, parts, readout=readout, evidence=evidence)
