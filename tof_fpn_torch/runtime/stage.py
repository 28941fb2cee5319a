r"""The stage contract: one way to write a run-time stage ``(depth, amplitude) -> depth``.

Every stage of the package (fixed pattern, destripe, the FPN suppression with its notch, fusion and
gate, flying pixels, the denoisers, temporal filtering) is written the same way, as librealsense
writes its processing blocks and kornia its filters:

1. **declared settings**: the class attribute ``settings`` lists each option as a :class:`Setting`
   (type, default, allowed range or values, a one-line description). The constructor checks its
   arguments against them (:meth:`Setting.check`); the command line, the TOML file and the manifest
   of ``tof-fpn clean`` are generated from them.
2. **a pure functional kernel** (``destripe``, ``flying_pixels``, ``fpn_filter`` ...) that the
   module calls; it never modifies its inputs and returns invalid pixels unchanged
   (:func:`~tof_fpn_torch.runtime.valid_mask`).
3. **a module** (:class:`Stage`): :meth:`Stage.run` returns the frame and a small record of what
   the stage did, a ``Dict[str, Tensor]`` whose entries the class declares in ``record``
   (:class:`RecordField`: per frame ``(B,)`` or per pixel ``(B, 1, H, W)``), computed in the same
   pass as the frame (nothing is computed twice to report it). :meth:`Stage.forward` returns the
   frame alone, so a stage drops into a network, ``nn.Sequential`` or an export unchanged
   (TorchScript scripts both; an ONNX export traces ``forward``).
4. where a stage can be measured on data, a ``from_data`` builder in :mod:`tof_fpn_torch.build`.

Depth in metres needs float32 (bfloat16 keeps about 8 mm at 2 m): under ``torch.autocast`` a stage
computes in float32 with autocast off and returns its input's dtype.

Example (a toy stage: a constant offset, recording how many pixels it moved):

    >>> from tof_fpn_torch.runtime import valid_mask
    >>> class Offset(Stage):
    ...     settings = (Setting("offset", float, 0.0, "metres added to valid pixels"),)
    ...     record = (RecordField("moved", "valid pixels moved"),)
    ...     def __init__(self, offset: float = 0.0) -> None:
    ...         super().__init__()
    ...         self.offset = check_settings(type(self), offset=offset)["offset"]
    ...     def _run(self, depth, amplitude=None):
    ...         valid = valid_mask(depth, amplitude)
    ...         out = torch.where(valid, depth + self.offset, depth)
    ...         return out, {"moved": (valid & (out != depth)).flatten(1).sum(1).float()}
    >>> y, rec = Offset(0.5).run(torch.ones(2, 1, 4, 4))
    >>> float(y[0, 0, 0, 0]), rec["moved"].tolist()
    (1.5, [16.0, 16.0])
"""

import math
from dataclasses import dataclass
from typing import Any

import torch
from torch import nn

from ._checks import check_tensor_type

__all__ = [
    "RecordField",
    "RecordOutputs",
    "Setting",
    "Stage",
    "check_settings",
    "empty_record",
]

_KINDS = (bool, int, float, str)


@dataclass(frozen=True)
class Setting:
    """One declared option of a stage.

    Attributes:
        name: the keyword (constructor argument, TOML key, command-line flag ``--name`` with ``_``
            as ``-`` unless a generator says otherwise).
        kind: ``bool``, ``int``, ``float`` or ``str``.
        default: the value when not given (``None``: absent, the stage chooses).
        help: one line: what it does, with its unit.
        choices: the allowed values of a ``str`` setting (empty: any).
        low, high: the allowed range of a number (``None``: unbounded), inclusive unless
            ``open_low`` / ``open_high``.
        finite: a ``float`` setting must be finite (False: ``inf`` is allowed, e.g. "no limit").
    """

    name: str
    kind: type
    default: Any
    help: str
    choices: tuple = ()
    low: float | None = None
    high: float | None = None
    open_low: bool = False
    open_high: bool = False
    finite: bool = True

    def __post_init__(self) -> None:
        if self.kind not in _KINDS:
            raise ValueError(
                f"Setting {self.name!r}: kind must be one of {_KINDS}, got {self.kind}"
            )
        if not self.name.isidentifier():
            raise ValueError(f"Setting name must be an identifier, got {self.name!r}")
        if self.default is not None:
            self.check(self.default)

    def allowed(self) -> str:
        """What :meth:`check` accepts, in words (for messages and help texts)."""
        if self.choices:
            return f"one of {list(self.choices)}"
        if self.kind is bool:
            return "true or false"
        number = "a finite number" if self.finite else "a number"
        word = "an int" if self.kind is int else (number if self.kind is float else "a string")
        bounds = []
        if self.low is not None:
            bounds.append(f"{'>' if self.open_low else '>='} {self.low:g}")
        if self.high is not None:
            bounds.append(f"{'<' if self.open_high else '<='} {self.high:g}")
        return word + (" " + " and ".join(bounds) if bounds else "")

    def check(self, value: Any, where: str = "") -> Any:
        """``value`` converted to the setting's kind (an int is a float where a float is
        asked); ``ValueError`` naming the setting, what was given and what is allowed."""
        ok = True
        if self.kind is bool:
            ok = isinstance(value, bool)
        elif self.kind is int:
            ok = isinstance(value, int) and not isinstance(value, bool)
        elif self.kind is float:
            ok = isinstance(value, (int, float)) and not isinstance(value, bool)
            ok = ok and not math.isnan(value) and (math.isfinite(value) or not self.finite)
            value = float(value) if ok else value
        else:
            ok = isinstance(value, str)
        if ok and self.choices:
            ok = value in self.choices
        if ok and self.kind in (int, float):
            if self.low is not None:
                ok = value > self.low if self.open_low else value >= self.low
            if ok and self.high is not None:
                ok = value < self.high if self.open_high else value <= self.high
        if not ok:
            raise ValueError(f"{where}{self.name} must be {self.allowed()}, got {value!r}")
        return value


@dataclass(frozen=True)
class RecordField:
    """One entry of a stage's record: ``per="frame"``: a (B,) tensor, ``"pixel"``: (B, 1, H, W)."""

    name: str
    help: str
    per: str = "frame"


def check_settings(stage: type, **values: Any) -> dict:
    """``values`` checked against ``stage.settings`` (:meth:`Setting.check`); a name that is not a
    declared setting raises ``ValueError`` listing the declared ones. ``None`` passes for a setting
    whose default is ``None``."""
    declared = {s.name: s for s in stage.settings}
    out = {}
    for name, value in values.items():
        if name not in declared:
            raise ValueError(
                f"{stage.__name__} has no setting {name!r}; its settings: {sorted(declared)}"
            )
        s = declared[name]
        out[name] = None if value is None and s.default is None else s.check(value)
    return out


def empty_record() -> dict[str, torch.Tensor]:
    """The record of a stage that reports nothing (typed for TorchScript)."""
    return torch.jit.annotate(dict[str, torch.Tensor], {})


class Stage(nn.Module):
    """The base of every run-time stage (module docstring): a subclass declares ``settings`` and
    ``record`` and defines ``_run(depth, amplitude) -> (frame, record)``.

    Shape:
        - depth: (B, C, H, W) float (most stages take C = 1), metres; invalid pixels (NaN, inf,
          <= 0, or an invalid amplitude) are returned unchanged.
        - amplitude: (B, C, H, W) float or None.
        - :meth:`run`: ``(frame, record)``; :meth:`forward`: the frame, (B, C, H, W).
    """

    __jit_ignored_attributes__ = ["settings", "record", "sequence"]

    #: the declared options (:class:`Setting`)
    settings: tuple = ()
    #: the declared entries of :meth:`run`'s record (:class:`RecordField`)
    record: tuple = ()
    #: the batch is one recording's frames in time order (a causal stage), not independent frames
    sequence: bool = False

    def forward(self, depth: torch.Tensor, amplitude: torch.Tensor | None = None) -> torch.Tensor:
        return self.run(depth, amplitude)[0]

    @torch.jit.export
    def run(
        self, depth: torch.Tensor, amplitude: torch.Tensor | None = None
    ) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
        """The frame and the record of what the stage did to it (one pass)."""
        if not torch.jit.is_scripting():
            check_tensor_type(depth, "depth")
            check_tensor_type(amplitude, "amplitude", optional=True)
            if torch.is_autocast_enabled(depth.device.type):
                return self._full_precision(depth, amplitude)
        return self._run(depth, amplitude)

    @torch.jit.unused
    def _full_precision(
        self, depth: torch.Tensor, amplitude: torch.Tensor | None = None
    ) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
        with torch.autocast(depth.device.type, enabled=False):
            return self._run(depth, amplitude)

    def _run(
        self, depth: torch.Tensor, amplitude: torch.Tensor | None = None
    ) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
        raise NotImplementedError("a Stage subclass defines _run(depth, amplitude)")


class RecordOutputs(nn.Module):
    """A stage whose ``forward`` returns its frame and the named entries of its record, for an
    export that keeps them (ONNX outputs ``output`` and the names; tracing only).

    Example:
        >>> from tof_fpn_torch.runtime import FlyingPixels
        >>> m = RecordOutputs(FlyingPixels("mark"), ("confidence",))
        >>> [t.shape for t in m(torch.full((1, 1, 8, 8), 2.0), torch.full((1, 1, 8, 8), 50.0))]
        [torch.Size([1, 1, 8, 8]), torch.Size([1, 1, 8, 8])]
    """

    def __init__(self, stage: Stage, names: tuple[str, ...]) -> None:
        super().__init__()
        declared = [f.name for f in type(stage).record]
        for n in names:
            if n not in declared:
                raise ValueError(
                    f"{type(stage).__name__} records {declared}, not {n!r}; choose from those"
                )
        self.stage = stage
        self.names = tuple(names)
        #: names of the graph's outputs in an ONNX export
        self.onnx_outputs = ["output", *names]

    def forward(self, depth: torch.Tensor, amplitude: torch.Tensor | None = None):
        y, record = self.stage.run(depth, amplitude)
        return (y, *[record[n] for n in self.names])
