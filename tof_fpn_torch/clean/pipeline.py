"""The torch side of ``tof-fpn clean``: the stages a :class:`CleanConfig` asks for, as one module.

Order (each stage optional): the FPN stage (:class:`~tof_fpn_torch.runtime.FPNSuppression`: notch
filter, eq. (11) fusion, stripe gate, then the broadband destriper), then a denoiser. Denoisers are
a small registry by name (:data:`DENOISERS`; ``nlm`` today): :func:`register_denoiser` adds one, a
factory taking keyword options and returning a module ``(depth, amplitude) -> depth``.

Data-driven choices (``destripe = "auto"``, ``notch = "data"``, ``fusion = "data"``) are measured
on calibration frames (the first frames of the input in file order, read by the caller) with the
builders of :mod:`tof_fpn_torch.build`; the measured module is then fixed for the whole run.
"""

from __future__ import annotations

import inspect
from collections.abc import Callable

import torch
from torch import nn

from .. import constants as K
from ..build import (
    broadband_from_data,
    fusion_from_data,
    suppression_from_data,
    suppression_from_design,
)
from ..denoise import NonLocalMeans
from ..runtime import Destripe, FPNSuppression
from .config import CleanConfig

__all__ = ["DENOISERS", "CleanPipeline", "build_pipeline", "describe", "register_denoiser"]

#: denoiser name -> factory(**options) -> module ``(depth, amplitude) -> depth``
DENOISERS: dict[str, Callable[..., nn.Module]] = {"nlm": NonLocalMeans}

_DESTRIPE_DIMS = {"columns": -1, "rows": -2, "both": (-2, -1)}


def register_denoiser(name: str, factory: Callable[..., nn.Module]) -> None:
    """Add a denoiser under ``name`` (``denoise = "<name>"``, ``--denoise <name>``).

    ``factory(**options)`` gets the ``[denoise]`` table and returns a module called as
    ``module(depth, amplitude)`` on (B, 1, H, W) depth in metres (NaN invalid) and amplitude in
    camera units, returning depth with invalid pixels unchanged."""
    if not isinstance(name, str) or not name.isidentifier() or name == "none":
        raise ValueError(f"name must be an identifier other than 'none', got {name!r}")
    if not callable(factory):
        raise ValueError(f"factory must be callable, got {type(factory).__name__}")
    DENOISERS[name] = factory


def make_denoiser(name: str, options: dict) -> nn.Module | None:
    """The denoiser ``name`` built with ``options`` (None for ``"none"``)."""
    if name == "none":
        if options:
            raise ValueError(f"denoise options {sorted(options)} given, but denoise = 'none'")
        return None
    if name not in DENOISERS:
        raise ValueError(f"denoise must be 'none' or one of {sorted(DENOISERS)}, got {name!r}")
    factory = DENOISERS[name]
    try:
        params = inspect.signature(factory).parameters
    except (TypeError, ValueError):
        params = {}
    if params and not any(p.kind is p.VAR_KEYWORD for p in params.values()):
        unknown = sorted(set(options) - set(params))
        if unknown:
            raise ValueError(
                f"unknown option(s) {unknown} of denoiser {name!r}; allowed: "
                f"{sorted(k for k in params if k != 'self')}"
            )
    return factory(**options)


class CleanPipeline(nn.Module):
    """The FPN stage then the denoiser, each optional (an empty pipeline returns its input).

    Shape: depth and amplitude (B, 1, H, W) float, metres and camera units; output (B, 1, H, W),
    invalid pixels unchanged (every stage keeps them). Runs without autograd."""

    def __init__(self, fpn: FPNSuppression | None = None, denoiser: nn.Module | None = None):
        super().__init__()
        self.fpn = fpn
        self.denoiser = denoiser

    @torch.no_grad()
    def forward(self, depth: torch.Tensor, amplitude: torch.Tensor) -> torch.Tensor:
        y = depth
        if self.fpn is not None:
            y = self.fpn(y, amplitude)
        if self.denoiser is not None:
            y = self.denoiser(y, amplitude)
        return y


def _fusion_kwargs(config: CleanConfig, calib) -> dict:
    if config.fusion == "off":
        return {"adaptive": False}
    if config.fusion == "camera":
        return {"camera": config.camera}
    if config.fusion == "manual":
        return {"low": config.low, "high": config.high}
    if config.notch == "data":  # suppression_from_data measures the thresholds itself
        return {}
    fusion = fusion_from_data(*calib())
    return {"low": fusion.low, "high": fusion.high}


def build_pipeline(
    config: CleanConfig,
    calibration: Callable[[], tuple[torch.Tensor, torch.Tensor]] | None = None,
) -> CleanPipeline:
    """The :class:`CleanPipeline` of ``config``.

    Args:
        config: the stages and settings.
        calibration: called (once, only when a stage is measured on data) for
            ``(depth, amplitude)`` calibration frames, (N, 1, H, W) metres and camera units.

    Raises:
        ValueError: a data-driven stage without ``calibration``, or a setting the builders refuse.
    """
    cache: list = []

    def calib():
        if calibration is None:
            raise ValueError(
                "this configuration measures a stage on data (destripe = 'auto', notch = 'data' "
                "or fusion = 'data') but no calibration frames were given"
            )
        if not cache:
            cache.append(calibration())
        return cache[0]

    destripe = None
    if config.destripe in _DESTRIPE_DIMS:
        destripe = Destripe(dim=_DESTRIPE_DIMS[config.destripe])
    fpn: FPNSuppression | None = None
    if config.notch == "design":
        rho = K.DEFAULT_RHO if config.rho is None else config.rho
        fpn = suppression_from_design(
            config.order, rho, gate=config.gate, destripe=destripe, **_fusion_kwargs(config, calib)
        )
    elif config.notch == "data":
        kwargs = dict(order=config.order, rho=config.rho, gate=config.gate)
        kwargs.update(_fusion_kwargs(config, calib))
        if config.destripe != "auto":
            kwargs["destripe"] = destripe
        fpn = suppression_from_data(*calib(), **kwargs)
    elif destripe is not None:
        fpn = FPNSuppression(None, None, destripe=destripe)
    if config.destripe == "auto" and config.notch != "data":
        depth, amplitude = calib()
        with torch.no_grad():
            notched = depth if fpn is None else fpn(depth, amplitude)
        found = broadband_from_data(notched, amplitude)
        if fpn is None:
            fpn = None if found is None else FPNSuppression(None, None, destripe=found)
        else:
            fpn.destripe = found
    denoiser = make_denoiser(config.denoise, config.denoise_options)
    pipeline = CleanPipeline(fpn, denoiser)
    pipeline.eval()
    return pipeline


def describe(pipeline: CleanPipeline) -> dict:
    """What the pipeline does, as plain values (recorded in the manifest)."""
    fpn = pipeline.fpn
    out: dict = {"notch": None, "fusion": None, "gate": False, "destripe": None, "denoise": None}
    if fpn is not None:
        if fpn.filter is not None:
            out["notch"] = {
                "order": fpn.filter.order,
                "rho": fpn.filter.rho,
                "notches": [round(float(w), 6) for w in fpn.filter.notches],
                "dims": list(fpn.filter.dims),
            }
        if fpn.fusion is not None:
            out["fusion"] = {"low": float(fpn.fusion.low), "high": float(fpn.fusion.high)}
        out["gate"] = bool(fpn.gate)
        if fpn.destripe is not None:
            out["destripe"] = fpn.destripe.extra_repr()
    if pipeline.denoiser is not None:
        out["denoise"] = f"{type(pipeline.denoiser).__name__}({pipeline.denoiser.extra_repr()})"
    return out
