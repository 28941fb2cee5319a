"""The steps of ``tof-fpn clean``, in the order they run: one file each, registered here.

Each file declares one :class:`~.base.Step`: its options, its builder and its reports
(docs/adding-a-stage.md shows how to add one). :func:`register` adds a step (a plug-in, or a test's
toy step); the configuration, the TOML file, the ``clean`` flags, the stage line, the manifest and
the summary of every later run include it.
"""

from __future__ import annotations

from .base import Context, Option, Step, TableOption, options_of
from .denoise import STEP as DENOISE
from .files import FILE_OPTIONS
from .flying import STEP as FLYING
from .fpn import STEP as FPN
from .pattern import STEP as PATTERN
from .temporal import STEP as TEMPORAL

__all__ = [
    "FILE_OPTIONS",
    "Context",
    "Option",
    "Step",
    "TableOption",
    "options_of",
    "options",
    "register",
    "steps",
    "unregister",
]

_STEPS: list[Step] = [PATTERN, FPN, FLYING, DENOISE, TEMPORAL]


def steps() -> list[Step]:
    """The registered steps in the order they run (frame steps, then sequence steps)."""
    return list(_STEPS)


def options() -> list[Option]:
    """Every registered step's options, in step order."""
    return [o for s in _STEPS for o in s.options]


def register(step: Step, before: str | None = None) -> None:
    """Add ``step`` (before the step named ``before``; default: after the last frame step, or
    last for a sequence step). ``ValueError`` when its name or an option's name, TOML key or flag
    is taken, or the order would put a frame step after a sequence step."""
    if not isinstance(step, Step):
        raise ValueError(f"register takes a Step, got {type(step).__name__}")
    taken = {s.name for s in _STEPS}
    if step.name in taken:
        raise ValueError(f"a step named {step.name!r} is registered already")
    known = options() + list(FILE_OPTIONS)  # the run's own options share the name spaces
    for o in step.options:
        for other in known:
            if o.name == other.name or _place(o) == _place(other):
                raise ValueError(
                    f"option {o.name!r} of step {step.name!r} clashes with {other.name!r}"
                )
            if _flag(o) and _flag(o) == _flag(other):
                raise ValueError(f"flag --{_flag(o)} of step {step.name!r} is taken")
    names = [s.name for s in _STEPS]
    if before is not None:
        if before not in names:
            raise ValueError(f"before must be one of {names}, got {before!r}")
        i = names.index(before)
    elif step.scope == "sequence":
        i = len(_STEPS)
    else:
        i = sum(s.scope == "frame" for s in _STEPS)
    order = [s.scope for s in _STEPS[:i]] + [step.scope] + [s.scope for s in _STEPS[i:]]
    if order != sorted(order, key=lambda sc: sc == "sequence"):
        raise ValueError(f"step {step.name!r}: frame steps run before sequence steps")
    _STEPS.insert(i, step)


def _place(o: Option | TableOption) -> tuple[str, str]:
    """Where an option sits in the TOML file: (table, key); a whole table for a TableOption."""
    return (o.table, "*") if isinstance(o, TableOption) else (o.table, o.key)


def _flag(o: Option | TableOption) -> str:
    return o.flag if isinstance(o, TableOption) else o.cli_flag()


def unregister(name: str) -> None:
    """Remove the step ``name`` (``ValueError`` when there is none)."""
    for i, s in enumerate(_STEPS):
        if s.name == name:
            del _STEPS[i]
            return
    raise ValueError(f"no step named {name!r}; registered: {[s.name for s in _STEPS]}")
