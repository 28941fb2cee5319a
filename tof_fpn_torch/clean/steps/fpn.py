"""The FPN stage of ``tof-fpn clean``: notch filter, eq. (11) fusion, stripe gate, then the
broadband destriper (:class:`~tof_fpn_torch.runtime.FPNSuppression`), each optional.

``stage = "auto"`` (default) measures every piece on the calibration frames with the builders of
:mod:`tof_fpn_torch.build` (``suppression_from_data``, ``fusion_from_data``,
``broadband_from_data``); ``"paper"`` is the paper's CamCube stage (notch from the design, fusion
70 / 350, no destriping). A key given explicitly wins over the preset.
"""

from __future__ import annotations

import dataclasses
import math

import torch
from torch import nn

from ... import cameras
from ... import constants as K
from ...build import (
    DesignRefused,
    broadband_from_data,
    filter_from_design,
    fusion_from_data,
    suppression_from_data,
    suppression_from_design,
)
from ...runtime import Destripe, FPNSuppression, PatternCorrection
from ...runtime.stage import Setting
from .base import Context, Option, Step

__all__ = ["FUSION_FOR_NOTCH", "PRESETS", "STAGES", "STEP"]

#: the ``stage`` presets
STAGES: tuple[str, ...] = ("auto", "paper")
DESTRIPE: tuple[str, ...] = ("off", "columns", "rows", "both", "auto")
NOTCH: tuple[str, ...] = ("off", "design", "data")
FUSION: tuple[str, ...] = ("off", "camera", "data", "manual")
#: the fusion that goes with each notch choice when ``fusion`` is not given
FUSION_FOR_NOTCH: dict[str, str] = {"off": "off", "design": "camera", "data": "data"}
#: what each ``stage`` preset sets (a key given explicitly wins)
PRESETS: dict[str, dict[str, str]] = {
    "auto": {"destripe": "auto", "notch": "data"},
    "paper": {"destripe": "off", "notch": "design", "camera": "camcube"},
}
_DESTRIPE_DIMS = {"columns": -1, "rows": -2, "both": (-2, -1)}
_POSITIVE = dict(low=0.0, open_low=True)

OPTIONS: tuple[Option, ...] = (
    Option(
        Setting(
            "stage",
            str,
            "auto",
            "auto: notch, fusion and destriping measured on the data; paper: the paper's CamCube "
            "notch stage with its 70 / 350 fusion",
            choices=STAGES,
        ),
        "pipeline",
        "stage",
    ),
    Option(
        Setting("destripe", str, None, "broadband offsets", choices=DESTRIPE),
        "pipeline",
        "destripe",
    ),
    Option(Setting("notch", str, None, "periodic stripes", choices=NOTCH), "pipeline", "notch"),
    Option(
        Setting("fusion", str, None, "eq. (11) amplitude fusion", choices=FUSION),
        "pipeline",
        "fusion",
    ),
    Option(Setting("order", int, K.DEFAULT_ORDER, "notch filter order", low=1), "notch", "order"),
    Option(Setting("rho", float, None, "transition half-width / pi", **_POSITIVE), "notch", "rho"),
    Option(
        Setting(
            "gate", bool, True, "the per-frame stripe gate (stripe-free frames pass unchanged)"
        ),
        "notch",
        "gate",
    ),
    Option(
        Setting("camera", str, None, "camera profile of --fusion camera (e.g. adtf3175)"),
        "fusion",
        "camera",
    ),
    Option(Setting("low", float, None, "--fusion manual: low threshold", low=0.0), "fusion", "low"),
    Option(
        Setting("high", float, None, "--fusion manual: high threshold", **_POSITIVE),
        "fusion",
        "high",
    ),
)


def _resolve(v: dict) -> None:
    """The preset's defaults, the fusion that goes with the notch, and the checks across keys."""
    if v["stage"] not in STAGES:
        raise ValueError(f"stage must be one of {list(STAGES)}, got {v['stage']!r}")
    for key, value in PRESETS[v["stage"]].items():
        if v[key] is None:
            v[key] = value
    if v["fusion"] is None:
        v["fusion"] = FUSION_FOR_NOTCH.get(v["notch"])
    if v["camera"] is not None:
        cameras.profile(v["camera"])  # ValueError naming the known profiles
    if v["notch"] == "off" and v["fusion"] != "off":
        raise ValueError(
            f"fusion = {v['fusion']!r} blends the notch filter's output: it needs notch = "
            "'design' or 'data' (got notch = 'off')"
        )
    if v["fusion"] == "manual" and (v["low"] is None or v["high"] is None):
        raise ValueError(
            "fusion = 'manual' needs low and high (amplitude units of the camera), got "
            f"low={v['low']!r}, high={v['high']!r}"
        )


def _replace(old: dict, changes: dict) -> None:
    """A new ``stage`` takes its preset's defaults; a new ``notch`` the fusion that goes with it
    (unless the fusion was chosen)."""
    if "stage" in changes and changes["stage"] != old["stage"]:
        for key in ("destripe", "notch", "fusion", "camera"):
            changes.setdefault(key, None)
        return
    same = old["fusion"] == FUSION_FOR_NOTCH[old["notch"]]
    if "notch" in changes and "fusion" not in changes and same:
        changes["fusion"] = None


def _camera(ctx: Context) -> str:
    """The profile of ``fusion = camera``: the configured one, else the files', else CamCube."""
    if ctx.config.camera is not None:
        return ctx.config.camera
    return ctx.frames().camera or "camcube"


def _design_stage(ctx: Context, rho: float, destripe: nn.Module | None) -> FPNSuppression:
    c = ctx.config
    if c.fusion == "off":
        return suppression_from_design(c.order, rho, adaptive=False, gate=c.gate, destripe=destripe)
    if c.fusion == "camera":
        camera = _camera(ctx)
        return suppression_from_design(c.order, rho, camera=camera, gate=c.gate, destripe=destripe)
    if c.fusion == "manual":
        return suppression_from_design(
            c.order, rho, low=c.low, high=c.high, gate=c.gate, destripe=destripe
        )
    frames = ctx.frames()
    fusion = fusion_from_data(frames.depth, frames.amplitude, filter_from_design(c.order, rho))
    return suppression_from_design(
        c.order,
        rho,
        low=fusion.low,
        high=fusion.high,
        floor=fusion.floor,
        gate=c.gate,
        destripe=destripe,
    )


#: the single-frame measurements (stripes, fusion, broadband offsets) look at most this many
#: pixels of the calibration frames (whole frames, spread over them; at least one): a camera's
#: stripes show in every frame, and the measurement is the run's fixed cost
MEASURE_PIXELS: int = 1 << 19


def _measure_frames(ctx: Context):
    """The calibration frames the single-frame measurements use (:data:`MEASURE_PIXELS`)."""
    frames = ctx.frames()
    n, _, h, w = frames.depth.shape
    k = max(1, min(n, MEASURE_PIXELS // max(h * w, 1)))
    if k == n:
        return frames
    pick = torch.linspace(0, n - 1, k).round().long()
    return dataclasses.replace(frames, depth=frames.depth[pick], amplitude=frames.amplitude[pick])


def _data_stage(ctx: Context, destripe: nn.Module | None) -> FPNSuppression:
    c = ctx.config
    frames = _measure_frames(ctx)
    keep = c.destripe != "auto"  # else suppression_from_data measures the destriper itself
    d, a = frames.depth, frames.amplitude
    if c.fusion == "off":
        fusion = dict(adaptive=False)
    elif c.fusion == "camera":
        fusion = dict(camera=_camera(ctx))
    elif c.fusion == "manual":
        fusion = dict(low=c.low, high=c.high)
    else:
        fusion = dict(camera_hint=frames.camera)
    return suppression_from_data(
        d, a, order=c.order, rho=c.rho, gate=c.gate, destripe=destripe if keep else "auto", **fusion
    )


def _build(ctx: Context) -> FPNSuppression | None:
    c = ctx.config
    learned = ctx.built.get("pattern")
    if isinstance(learned, PatternCorrection) and learned.learned and _measured_only(c):
        ctx.note(
            "the single-frame stages were not measured: the pattern the frames share is "
            "removed instead (a stage measured on one frame can take a scene for stripes)"
        )
        return None
    destripe = None
    if c.destripe in _DESTRIPE_DIMS:
        destripe = Destripe(dim=_DESTRIPE_DIMS[c.destripe])
    fpn: FPNSuppression | None = None
    measured_notch = c.notch == "data"
    if c.notch == "design":
        fpn = _design_stage(ctx, K.DEFAULT_RHO if c.rho is None else c.rho, destripe)
    elif c.notch == "data":
        try:
            fpn = _data_stage(ctx, destripe)
        except DesignRefused as exc:  # the stripes it measured need a filter it cannot make
            if c.rho is not None:  # a rho the user chose: their setting, their error
                raise
            ctx.note(f"the notch fell back to none: {exc.args[0].split(': use')[0]}")
            measured_notch = False
    if fpn is None and destripe is not None:
        fpn = FPNSuppression(None, None, destripe=destripe)
    if c.destripe == "auto" and not measured_notch:
        frames = _measure_frames(ctx)
        with torch.no_grad():
            notched = frames.depth if fpn is None else fpn(frames.depth, frames.amplitude)
        found = broadband_from_data(notched, frames.amplitude)
        if fpn is None:
            fpn = None if found is None else FPNSuppression(None, None, destripe=found)
        else:
            fpn.destripe = found
    if fpn is not None and fpn.filter is None and fpn.destripe is None:
        return None  # measured: nothing to do
    return fpn


def _measured_only(c) -> bool:
    """Whether every FPN piece of the configuration is measured on data (the auto preset's), so
    that none was asked for by the user."""
    return c.destripe in ("auto", "off") and c.notch in ("data", "off")


def _describe(fpn: nn.Module | None) -> dict:
    out: dict = {"notch": None, "fusion": None, "gate": False, "destripe": None}
    if fpn is None:
        return out
    assert isinstance(fpn, FPNSuppression)
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
    return out


def _phrase(info: dict) -> list[str]:
    parts = []
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
    return parts


def _file_record(frames: list[dict]) -> dict | None:
    """The notch gate over the file's frames: its mean and how many frames it opened for."""
    gates = [f["gate"] for f in frames if "gate" in f and not math.isnan(f["gate"])]
    if not gates:  # no notch
        return None
    return {"mean": sum(gates) / len(gates), "open_frames": sum(g > 0 for g in gates)}


def _summary(records: list[dict]) -> list[str]:
    reports = [r["report"] for r in records if r.get("report")]
    gated = [r["gate"] for r in reports if r.get("gate") is not None]
    if not gated:
        return []
    return [f"notch gate opened for {sum(g['open_frames'] for g in gated)} frame(s)"]


STEP = Step(
    name="fpn",
    report_name="gate",
    on_replace=_replace,
    options=OPTIONS,
    build=_build,
    describe=_describe,
    phrase=_phrase,
    file_record=_file_record,
    summary=_summary,
    resolve=_resolve,
)
