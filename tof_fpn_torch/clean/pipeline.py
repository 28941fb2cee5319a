"""The torch side of ``tof-fpn clean``: the stages a :class:`CleanConfig` asks for, as one module.

Order (each stage optional): the FPN stage (:class:`~tof_fpn_torch.runtime.FPNSuppression`: notch
filter, eq. (11) fusion, stripe gate, then the broadband destriper), then a denoiser, then (over
the frames of each multi-frame file, by :mod:`.temporal`, not in :meth:`CleanPipeline.forward`)
the temporal filter. Denoisers come
from the one registry, :data:`tof_fpn_torch.denoise.DENOISERS` (re-exported here as
:data:`DENOISERS`: nlm, bm3d, sdct, hypbi, lpa-ici, bilateral, joint-bilateral, guided, and the
registry's aliases); :func:`register_denoiser` (:func:`tof_fpn_torch.denoise.register`) adds one,
a factory taking keyword options and returning a module ``(depth, amplitude) -> depth``.

Data-driven choices (``destripe = "auto"``, ``notch = "data"``, ``fusion = "data"``) are measured
on calibration frames (the first frames of the input in file order, read by the caller) with the
builders of :mod:`tof_fpn_torch.build`; the measured module is then fixed for the whole run.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import torch
from torch import nn

from .. import constants as K
from .. import denoise as _denoise
from ..build import (
    broadband_from_data,
    filter_from_design,
    fusion_from_data,
    suppression_from_data,
    suppression_from_design,
)
from ..runtime import Destripe, FlyingPixels, FPNSuppression, valid_mask
from .config import CleanConfig
from .pattern import load_pattern
from .temporal import temporal_module

__all__ = [
    "DENOISERS",
    "Calibration",
    "CleanPipeline",
    "build_pipeline",
    "describe",
    "register_denoiser",
    "stage_line",
]

_DESTRIPE_DIMS = {"columns": -1, "rows": -2, "both": (-2, -1)}

#: the denoiser registry (name -> factory(**options) -> module ``(depth, amplitude) -> depth``):
#: :data:`tof_fpn_torch.denoise.DENOISERS` itself
DENOISERS = _denoise.DENOISERS
#: add a denoiser by name (``denoise = "<name>"``, ``--denoise <name>``):
#: :func:`tof_fpn_torch.denoise.register`
register_denoiser = _denoise.register


def make_denoiser(name: str, options: dict) -> nn.Module | None:
    """The denoiser ``name`` built with ``options`` (None for ``"none"``) by
    :func:`tof_fpn_torch.denoise.get` (names, aliases and the options' check are the registry's)."""
    if name == "none":
        if options:
            raise ValueError(f"denoise options {sorted(options)} given, but denoise = 'none'")
        return None
    try:
        key = _denoise.canonical(name)
    except ValueError:
        raise ValueError(
            f"denoise must be 'none' or one of {sorted(DENOISERS)}, got {name!r}"
        ) from None
    return _denoise.get(key, **options)


class CleanPipeline(nn.Module):
    """A calibrated fixed pattern, the FPN stage, then the denoiser, each optional (an empty
    pipeline returns its input).

    Shape: depth and amplitude (B, 1, H, W) float, metres and camera units; output (B, 1, H, W),
    invalid pixels unchanged (every stage keeps them). Runs without autograd."""

    def __init__(
        self,
        fpn: FPNSuppression | None = None,
        denoiser: nn.Module | None = None,
        pattern: nn.Module | None = None,
        flying: nn.Module | None = None,
    ):
        super().__init__()
        self.pattern = pattern
        self.fpn = fpn
        self.flying = flying
        self.denoiser = denoiser
        self.calibration: dict | None = None  # what a data-driven stage was measured on
        self.temporal: nn.Module | None = None  # run per frame set after forward (.temporal)
        #: (B, 2) flagged and valid pixels per frame of the last call (None without the stage)
        self.last_flying: torch.Tensor | None = None
        #: keep the flying stage's confidence of the last call in ``last_confidence``
        self.keep_confidence = False
        self.last_confidence: torch.Tensor | None = None

    def gates(self, depth: torch.Tensor, amplitude: torch.Tensor) -> torch.Tensor | None:
        """(B,) the notch stage's gate per frame (None without a notch filter), for the record."""
        if self.fpn is None or self.fpn.filter is None:
            return None
        if self.pattern is not None:
            with torch.no_grad():
                depth = self.pattern(depth, amplitude)
        return self.fpn.gate_values(depth, amplitude)

    @torch.no_grad()
    def forward(self, depth: torch.Tensor, amplitude: torch.Tensor) -> torch.Tensor:
        y = depth
        if self.pattern is not None:
            y = self.pattern(y, amplitude)
        if self.fpn is not None:
            y = self.fpn(y, amplitude)
        if self.flying is not None:
            valid = valid_mask(y, amplitude)
            y, conf = self.flying(y, amplitude)
            flagged = (conf < 0.5) & valid
            self.last_flying = torch.stack([flagged.flatten(1).sum(1), valid.flatten(1).sum(1)], 1)
            self.last_confidence = conf if self.keep_confidence else None
        if self.denoiser is not None:
            y = self.denoiser(y, amplitude)
        return y


@dataclass
class Calibration:
    """The frames data-driven stages are measured on: depth (N, 1, H, W) metres, amplitude
    (N, 1, H, W) camera units, and the camera profile the files name (None: not said)."""

    depth: torch.Tensor
    amplitude: torch.Tensor
    camera: str | None = None


def _camera(config: CleanConfig, calib) -> str:
    """The profile of ``fusion = camera``: the configured one, else the files', else CamCube."""
    if config.camera is not None:
        return config.camera
    return calib().camera or "camcube"


def _fusion_kwargs(config: CleanConfig, calib, filt) -> dict:
    if config.fusion == "off":
        return {"adaptive": False}
    if config.fusion == "camera":
        return {"camera": _camera(config, calib)}
    if config.fusion == "manual":
        return {"low": config.low, "high": config.high}
    if config.notch == "data":  # suppression_from_data measures the fusion itself
        return {"camera_hint": calib().camera}
    c = calib()
    fusion = fusion_from_data(c.depth, c.amplitude, filt())
    return {"low": fusion.low, "high": fusion.high, "floor": fusion.floor}


def build_pipeline(
    config: CleanConfig, calibration: Callable[[], Calibration] | None = None
) -> CleanPipeline:
    """The :class:`CleanPipeline` of ``config``.

    Args:
        config: the stages and settings.
        calibration: called (once, only when a stage is measured on data or the camera is asked
            for) for the :class:`Calibration` frames.

    Raises:
        ValueError: a data-driven stage without ``calibration``, or a setting the builders refuse.
    """
    cache: list = []
    pattern = None if config.pattern is None else load_pattern(config.pattern)

    def calib() -> Calibration:
        if calibration is None:
            raise ValueError(
                "this configuration measures a stage on data (destripe = 'auto', notch = 'data' "
                "or fusion = 'data') or uses the files' camera, but no calibration frames were "
                "given"
            )
        if not cache:
            c = calibration()
            if pattern is not None:  # the other stages see what the pattern leaves
                try:
                    with torch.no_grad():
                        c = Calibration(pattern(c.depth, c.amplitude), c.amplitude, c.camera)
                except ValueError as exc:
                    raise ValueError(f"pattern {config.pattern}: {exc}") from None
            cache.append(c)
        return cache[0]

    destripe = None
    if config.destripe in _DESTRIPE_DIMS:
        destripe = Destripe(dim=_DESTRIPE_DIMS[config.destripe])
    fpn: FPNSuppression | None = None
    rho = K.DEFAULT_RHO if config.rho is None else config.rho
    if config.notch == "design":
        kwargs = _fusion_kwargs(config, calib, lambda: filter_from_design(config.order, rho))
        fpn = suppression_from_design(
            config.order, rho, gate=config.gate, destripe=destripe, **kwargs
        )
    elif config.notch == "data":
        kwargs = dict(order=config.order, rho=config.rho, gate=config.gate)
        kwargs.update(_fusion_kwargs(config, calib, None))
        if config.destripe != "auto":
            kwargs["destripe"] = destripe
        c = calib()
        fpn = suppression_from_data(c.depth, c.amplitude, **kwargs)
    elif destripe is not None:
        fpn = FPNSuppression(None, None, destripe=destripe)
    if config.destripe == "auto" and config.notch != "data":
        c = calib()
        with torch.no_grad():
            notched = c.depth if fpn is None else fpn(c.depth, c.amplitude)
        found = broadband_from_data(notched, c.amplitude)
        if fpn is None:
            fpn = None if found is None else FPNSuppression(None, None, destripe=found)
        else:
            fpn.destripe = found
    if fpn is not None and fpn.filter is None and fpn.destripe is None:
        fpn = None  # measured: nothing to do
    denoiser = make_denoiser(config.denoise, config.denoise_options)
    flying = None if config.flying in (None, "off") else FlyingPixels(config.flying)
    pipeline = CleanPipeline(fpn, denoiser, pattern, flying)
    pipeline.keep_confidence = flying is not None and bool(config.flying_confidence)
    if config.temporal:
        pipeline.temporal = temporal_module(
            config.temporal_alpha, config.temporal_guard, config.temporal_persistence
        )
    if cache:
        c = cache[0]
        pipeline.calibration = {"frames": int(c.depth.shape[0]), "camera": c.camera}
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
            out["fusion"] = {
                "low": float(fpn.fusion.low),
                "high": float(fpn.fusion.high),
                "floor": float(fpn.fusion.floor),
            }
        out["gate"] = bool(fpn.gate)
        out["stripe_scale"] = float(fpn.stripe_scale)
        if fpn.destripe is not None:
            out["destripe"] = fpn.destripe.extra_repr()
    if pipeline.denoiser is not None:
        out["denoise"] = f"{type(pipeline.denoiser).__name__}({pipeline.denoiser.extra_repr()})"
    out["flying"] = None if pipeline.flying is None else pipeline.flying.action
    out["calibration"] = pipeline.calibration
    out["pattern"] = None if pipeline.pattern is None else type(pipeline.pattern).__name__
    t = pipeline.temporal
    out["temporal"] = None if t is None else {
        "alpha": t.alpha, "guard": t.guard, "persistence": t.persistence
    }  # fmt: skip
    return out


def stage_line(info: dict, stage: str) -> str:
    """One line saying what the pipeline of :func:`describe` does (what the command prints)."""
    parts = []
    if info.get("pattern") is not None:
        parts.append(f"fixed pattern ({info['pattern']})")
    notch = info.get("notch")
    if notch is not None:
        where = {-1: "columns", -2: "rows"}
        freqs = ", ".join(f"{w / math.pi:.3g} pi" for w in notch["notches"])
        dims = " and ".join(where[d] for d in notch["dims"])
        parts.append(f"notch at {freqs} ({dims}, order {notch['order']})")
        fusion = info.get("fusion")
        if fusion is not None:
            parts.append(
                f"fusion {fusion['low']:.4g} / {fusion['high']:.4g} / floor {fusion['floor']:.2f}"
            )
        parts.append("gated" if info.get("gate") else "ungated")
    if info.get("destripe") is not None:
        parts.append(f"destripe {info['destripe']}")
    if info.get("flying") is not None:
        parts.append(f"flying pixels: {info['flying']}")
    if info.get("denoise") is not None:
        parts.append(f"denoise {info['denoise']}")
    if info.get("temporal") is not None:
        t = info["temporal"]
        parts.append(
            f"temporal (alpha {t['alpha']:g}, guard {t['guard']:g}, persistence "
            f"{t['persistence']}) over the frames of each multi-frame file"
        )
    calib = info.get("calibration")
    source = ""
    if calib is not None:
        camera = f", camera {calib['camera']}" if calib.get("camera") else ""
        source = f", measured on {calib['frames']} calibration frame(s){camera}"
    if not parts:
        nothing = "no periodic stripes or broadband offsets found" if calib else "every stage off"
        return f"stage {stage}{source}: nothing to do ({nothing}); the outputs equal the inputs"
    return f"stage {stage}{source}: " + "; ".join(parts)
