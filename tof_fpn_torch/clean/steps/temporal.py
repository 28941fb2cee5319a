"""``--temporal``: the temporal filter over the frames of each multi-frame file, last
(:class:`~tof_fpn_torch.runtime.TemporalFilter`, run by :func:`~tof_fpn_torch.clean.temporal.apply_temporal`
frame after frame, its state carried within one frame set)."""

from __future__ import annotations

from torch import nn

from ...runtime import TemporalSequence
from ...runtime.stage import Setting
from ..temporal import apply_temporal, temporal_lines, temporal_module
from .base import Context, Option, Step, options_of

__all__ = ["STEP"]


def _resolve(v: dict) -> None:
    if v["temporal"] is None:
        v["temporal"] = False
    temporal_module(v["temporal_alpha"], v["temporal_guard"], v["temporal_persistence"])


def _build(ctx: Context) -> nn.Module | None:
    c = ctx.config
    if not c.temporal:
        return None
    return temporal_module(c.temporal_alpha, c.temporal_guard, c.temporal_persistence)


def _describe(t: nn.Module | None) -> dict:
    if t is None:
        return {"temporal": None}
    return {"temporal": {"alpha": t.alpha, "guard": t.guard, "persistence": t.persistence}}


def _phrase(info: dict) -> list[str]:
    t = info.get("temporal")
    if t is None:
        return []
    return [
        f"temporal (alpha {t['alpha']:g}, guard {t['guard']:g}, persistence "
        f"{t['persistence']}) over the frames of each multi-frame file"
    ]


STEP = Step(
    name="temporal",
    options=(
        Option(
            Setting("temporal", bool, False, "filter each recording over time"),
            "pipeline",
            "temporal",
        ),
        *options_of(TemporalSequence, "temporal", "temporal_", ("alpha", "guard", "persistence")),
    ),
    build=_build,
    describe=_describe,
    phrase=_phrase,
    scope="sequence",
    run_sequence=apply_temporal,
    file_record=list,
    summary=temporal_lines,
    resolve=_resolve,
    record_key="file",
)
