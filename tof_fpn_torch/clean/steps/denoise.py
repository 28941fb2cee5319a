"""``--denoise NAME``: a denoiser after the FPN stage, from the one registry
(:data:`tof_fpn_torch.denoise.DENOISERS`: nlm, bm3d, sdct, hypbi, lpa-ici, bilateral,
joint-bilateral, guided and the registry's aliases); ``[denoise]`` / ``--denoise-opt KEY=VALUE``
are its keyword arguments. :func:`tof_fpn_torch.denoise.register` adds a denoiser: a factory taking
keyword options and returning a module ``(depth, amplitude) -> depth``."""

from __future__ import annotations

import torch
from torch import nn

from ... import denoise as _denoise
from ...runtime.stage import Setting, Stage, empty_record
from .base import Context, Option, Step, TableOption

__all__ = ["STEP", "ModuleStage", "make_denoiser"]


class ModuleStage(Stage):
    """A module ``(depth, amplitude) -> depth`` that is not a
    :class:`~tof_fpn_torch.runtime.stage.Stage` (a registered denoiser of one's own), run as one
    with an empty record."""

    def __init__(self, module: nn.Module) -> None:
        super().__init__()
        self.module = module

    def _run(
        self, depth: torch.Tensor, amplitude: torch.Tensor | None = None
    ) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
        return self.module(depth, amplitude), empty_record()


def make_denoiser(name: str, options: dict) -> Stage | None:
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
            f"denoise must be 'none' or one of {sorted(_denoise.DENOISERS)}, got {name!r}"
        ) from None
    module = _denoise.get(key, **options)
    return module if isinstance(module, Stage) else ModuleStage(module)


def _resolve(v: dict) -> None:
    if not isinstance(v["denoise"], str) or not v["denoise"]:
        raise ValueError(f"denoise must be 'none' or a denoiser name, got {v['denoise']!r}")
    if not isinstance(v["denoise_options"], dict):
        raise ValueError(f"denoise_options must be a table, got {v['denoise_options']!r}")


def _build(ctx: Context) -> nn.Module | None:
    return make_denoiser(ctx.config.denoise, ctx.config.denoise_options)


def _describe(module: nn.Module | None) -> dict:
    if isinstance(module, ModuleStage):
        module = module.module
    return {
        "denoise": None if module is None else f"{type(module).__name__}({module.extra_repr()})"
    }


def _phrase(info: dict) -> list[str]:
    return [] if info.get("denoise") is None else [f"denoise {info['denoise']}"]


STEP = Step(
    name="denoise",
    options=(
        Option(
            Setting("denoise", str, "none", "denoiser after the FPN stage (none or a name)"),
            "pipeline",
            "denoise",
            cli_choices=lambda: ("none", *sorted(_denoise.DENOISERS)),
        ),
        TableOption(
            "denoise_options",
            "denoise",
            "denoise-opt",
            "a denoiser option, e.g. h=0.8 (repeatable)",
            follows="denoise",
        ),
    ),
    build=_build,
    describe=_describe,
    phrase=_phrase,
    resolve=_resolve,
)
