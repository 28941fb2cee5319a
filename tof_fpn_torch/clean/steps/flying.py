"""``--flying``: flying (mixed) pixels at depth edges, after the FPN stage and before the denoiser
(:class:`~tof_fpn_torch.runtime.FlyingPixels`): ``mark`` (counted only), ``invalidate`` or
``reassign``; ``--flying-confidence`` writes its confidence map beside each output."""

from __future__ import annotations

from torch import nn

from ...runtime import FlyingPixels
from ...runtime.flying import ACTIONS
from ...runtime.stage import Setting
from .base import Context, Option, Step

__all__ = ["ACTIONS_OR_OFF", "STEP"]

#: the allowed values of ``flying`` (absent: off, and left out of the saved file)
ACTIONS_OR_OFF: tuple[str, ...] = ("off", *ACTIONS)


def _resolve(v: dict) -> None:
    if v["flying_confidence"] and v["flying"] in (None, "off"):
        raise ValueError(
            "flying_confidence needs the flying stage: flying = mark, invalidate or reassign"
        )


def _build(ctx: Context) -> nn.Module | None:
    action = ctx.config.flying
    return None if action in (None, "off") else FlyingPixels(action)


def _describe(module: nn.Module | None) -> dict:
    return {"flying": None if module is None else module.action}


def _phrase(info: dict) -> list[str]:
    return [] if info.get("flying") is None else [f"flying pixels: {info['flying']}"]


def _file_record(frames: list[dict]) -> dict | None:
    counts = [(f["flagged"], f["valid"]) for f in frames if "flagged" in f]
    if not counts:
        return None
    flagged, valid = sum(int(n[0]) for n in counts), sum(int(n[1]) for n in counts)
    return {"flagged": flagged, "valid": valid, "share": flagged / max(valid, 1)}


def _summary(records: list[dict]) -> list[str]:
    reports = [r["report"] for r in records if r.get("report")]
    flying = [r["flying"] for r in reports if r.get("flying")]
    if not flying:
        return []
    flagged, valid = sum(f["flagged"] for f in flying), sum(f["valid"] for f in flying)
    return [
        f"flying pixels: {flagged} flagged, {100 * flagged / max(valid, 1):.2f} % of the "
        f"valid pixels of {len(flying)} file(s)"
    ]


STEP = Step(
    name="flying",
    options=(
        Option(
            Setting("flying", str, None, "mixed pixels at depth edges", choices=ACTIONS_OR_OFF),
            "pipeline",
            "flying",
        ),
        Option(
            Setting(
                "flying_confidence",
                bool,
                None,
                "write the flying-pixel confidence map beside each output "
                "(<output stem>.flying_confidence.npy, float32 frames x H x W)",
            ),
            "pipeline",
            "flying_confidence",
        ),
    ),
    build=_build,
    describe=_describe,
    phrase=_phrase,
    file_record=_file_record,
    summary=_summary,
    resolve=_resolve,
    keep_maps=lambda config: ("confidence",) if config.flying_confidence else (),
)
