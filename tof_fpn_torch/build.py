r"""Builders: run-time modules from an offline design or from data (the layer above both).

The run-time package (:mod:`tof_fpn_torch.runtime`) takes filter taps and knows nothing of how they
were designed; the design package (:mod:`tof_fpn_torch.design`) produces taps and knows nothing of
torch. These factories join them: they design the taps (NumPy / SciPy), or first estimate the
stripes in data (:mod:`tof_fpn_torch.analysis`), then build the torch modules and record on them
what the design was (``order``, ``rho``, ``notches``, which TorchScript and ONNX exports keep).

Example:
    >>> stage = suppression_from_design(20, 0.14)
    >>> stage.filter.order, stage.filter.rho, stage.filter.taps.shape, stage.gate
    (20, 0.14, torch.Size([21]), True)
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import torch
from torch import nn

from . import constants as K
from .analysis.stripes import StripeEstimate, estimate_stripes
from .design import compensate_half_sample, design_fpn, max_rho
from .runtime import AmplitudeFusion, FPNFilter, FPNSuppression

__all__ = [
    "MAX_RIPPLE_DB",
    "filter_from_design",
    "suppression_from_data",
    "suppression_from_design",
]


#: The builders refuse designs whose passband ripple is worse than this (dB): such a "notch filter"
#: changes the scene more than it removes stripes (e.g. 0 dB ripple with H(0) = 2 doubles depth).
MAX_RIPPLE_DB = -20.0


def _design(order, rho, notches, band_weights, compensate_delay, unit_dc, max_ripple_db):
    design = design_fpn(order, rho, notches=notches, band_weights=band_weights, unit_dc=unit_dc)
    if max_ripple_db is not None and not design.ripple_db <= max_ripple_db:
        raise ValueError(
            f"the design {{order {order}, rho {rho:g}}} for notches "
            f"{[round(w, 4) for w in design.notches]} has a passband ripple of "
            f"{design.ripple_db:.1f} dB (DC gain {design.dc_gain:.3f}); the stage needs "
            f"<= {max_ripple_db:g} dB: use a higher order or a larger rho (max_ripple_db=None "
            "accepts it anyway)"
        )
    taps = design.taps
    compensated = bool(compensate_delay) and taps.size % 2 == 0
    if compensated:
        # the interpolator's band reaches the top passband edge (at most 0.95 pi)
        taps = compensate_half_sample(
            taps, band_edge=float(min(design.bands[-1, 1], 0.95 * math.pi))
        )
    meta = {
        "order": design.order,
        "rho": design.rho,
        "notches": design.notches,
        "compensated": compensated,
    }
    return design, torch.from_numpy(taps), meta


def filter_from_design(
    order: int = K.DEFAULT_ORDER,
    rho: float = K.DEFAULT_RHO,
    *,
    notches: Sequence[float] = K.DEFAULT_NOTCHES,
    band_weights: Sequence[float] | None = None,
    compensate_delay: bool = True,
    unit_dc: bool = True,
    max_ripple_db: float | None = MAX_RIPPLE_DB,
    **kwargs,
) -> FPNFilter:
    """Design taps with :func:`tof_fpn_torch.design.design_fpn` and build an :class:`FPNFilter`.

    ``compensate_delay`` (default) convolves the taps of an odd order with a half-sample
    interpolator (:func:`tof_fpn_torch.design.compensate_half_sample`), so the output stays on the
    input grid; with False an odd order needs ``allow_shift=True`` (the paper's filters).
    ``unit_dc`` constrains ``H(0) = 1`` (default; the paper's design with False). A design whose
    ripple is worse than ``max_ripple_db`` is refused with a ``ValueError``. ``kwargs`` go to
    :class:`FPNFilter` (``dim``, ``border``, ``trainable``, ``allow_shift``). The design is kept
    in ``module.design``.
    """
    design, taps, meta = _design(
        order, rho, notches, band_weights, compensate_delay, unit_dc, max_ripple_db
    )
    module = FPNFilter(taps, **kwargs, **meta)
    module.design = design
    return module


def suppression_from_design(
    order: int = K.DEFAULT_ORDER,
    rho: float = K.DEFAULT_RHO,
    *,
    notches: Sequence[float] = K.DEFAULT_NOTCHES,
    dim: int | tuple[int, ...] = -1,
    adaptive: bool = True,
    low: float = K.FUSION_LOW,
    high: float = K.FUSION_HIGH,
    floor: float = K.FUSION_FLOOR,
    gate: bool = True,
    destripe: nn.Module | None = None,
    band_weights: Sequence[float] | None = None,
    compensate_delay: bool = True,
    unit_dc: bool = True,
    max_ripple_db: float | None = MAX_RIPPLE_DB,
    **kwargs,
) -> FPNSuppression:
    """Design taps and build an :class:`FPNSuppression`: notch filter, eq. (11) fusion (when
    ``adaptive``; thresholds ``low``, ``high``, ``floor`` in the camera's amplitude units, CamCube's
    by default), the stripe gate (when ``gate``), and an optional ``destripe`` module first.

    Defaults: Table I's best adaptive filter ``{20, 0.14}`` with notches at ``2pi/3`` and ``pi``,
    unit DC gain, gated. The paper's stage is ``suppression_from_design(unit_dc=False,
    gate=False)``. ``compensate_delay``, ``unit_dc``, ``max_ripple_db`` and ``kwargs`` (``border``,
    ``trainable``, ``allow_shift``) as in :func:`filter_from_design`.
    """
    filt = filter_from_design(
        order,
        rho,
        notches=notches,
        band_weights=band_weights,
        compensate_delay=compensate_delay,
        unit_dc=unit_dc,
        max_ripple_db=max_ripple_db,
        dim=dim,
        **kwargs,
    )
    fusion = AmplitudeFusion(low, high, floor) if adaptive else None
    return FPNSuppression(filt, fusion, destripe=destripe, gate=gate)


def suppression_from_data(
    frames: torch.Tensor,
    amplitudes: torch.Tensor | None = None,
    order: int = K.DEFAULT_ORDER,
    rho: float | None = None,
    min_confidence: float = 0.5,
    estimate_kwargs: dict | None = None,
    **kwargs,
) -> FPNSuppression:
    """Design notches for the stripes :func:`~tof_fpn_torch.analysis.estimate_stripes` finds.

    Components with ``confidence >= min_confidence`` are kept; their frequencies become the
    notches, the orientations found set ``dim`` (both orientations share one notch set). ``rho``
    defaults to ``min(DEFAULT_RHO, 0.9 max_rho)``. The estimate is kept in ``module.estimate``.

    Raises:
        ValueError: bad input, or no stripe found (the message lists the best candidates).
    """
    est: StripeEstimate = estimate_stripes(frames, amplitudes, **(estimate_kwargs or {}))
    comps = [c for c in est.components if c.confidence >= min_confidence]
    if not comps:
        raise ValueError(
            "no periodic stripes found with confidence >= "
            f"{min_confidence} (components: {list(est.components)}); nothing to notch"
        )
    freqs = sorted({math.pi if abs(c.frequency - math.pi) < 1e-3 else c.frequency for c in comps})
    merged: list[float] = []
    for f in freqs:  # one notch for peaks closer than 0.02 rad
        if merged and f - merged[-1] < 0.02:
            continue
        merged.append(f)
    dims = sorted({c.dim for c in comps})
    if rho is None:
        rho = min(K.DEFAULT_RHO, 0.9 * max_rho(merged))
    kwargs.setdefault("dim", tuple(dims) if len(dims) > 1 else dims[0])
    module = suppression_from_design(order, rho, notches=tuple(merged), **kwargs)
    module.estimate = est
    return module
