"""What a step of ``tof-fpn clean`` declares: its options and how it is built, described and reported.

A :class:`Step` binds a run-time stage (:class:`~tof_fpn_torch.runtime.stage.Stage`) to the
command: the options it adds to :class:`~tof_fpn_torch.clean.CleanConfig` (each an
:class:`Option`: a declared :class:`~tof_fpn_torch.runtime.stage.Setting` and where it lives in
the TOML file and on the command line), a builder from the configuration (and, for a stage
measured on data, the calibration frames), and the hooks that turn the built stage and its
records into the printed stage line, the manifest and the summary. The configuration, the TOML
format, the ``clean`` flags, the stage line, the per-file record and the summary are generated
from the registered steps (:mod:`tof_fpn_torch.clean.steps`); nothing in them names a step.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from torch import nn

from ...runtime.stage import Setting

__all__ = ["Context", "Option", "Step", "TableOption", "options_of"]

SCOPES = ("frame", "sequence")


@dataclass(frozen=True)
class Option:
    """One option of :class:`~tof_fpn_torch.clean.CleanConfig`.

    Attributes:
        setting: name (the configuration's attribute), kind, default, allowed values, help.
        table, key: where it sits in the TOML file (``[table] key = value``).
        flag: the command-line flag (``""``: none; ``None``: ``--`` and the name with ``-``).
            A ``bool`` option whose default is True is switched off by ``--no-<flag>``; one
            whose default is False or None is switched on by ``--<flag>``.
        path: a file name (the command line makes it absolute).
        cli_choices: the values the command line offers, when they are known only at run time
            (e.g. the registered denoisers).
    """

    setting: Setting
    table: str
    key: str
    flag: str | None = None
    path: bool = False
    cli_choices: Callable[[], tuple] | None = None

    @property
    def name(self) -> str:
        return self.setting.name

    def cli_flag(self) -> str:
        """The flag without its leading dashes (``""``: the option has none)."""
        if self.flag is not None:
            return self.flag
        return self.name.replace("_", "-")


def options_of(stage: type, table: str, prefix: str, names: tuple[str, ...]) -> tuple[Option, ...]:
    """The options of a step taken from its stage's declared settings (``stage.settings``,
    :class:`~tof_fpn_torch.runtime.stage.Setting`): each named setting becomes the option
    ``<prefix><name>``, TOML key ``[table] <name>``, flag ``--<prefix><name>`` (``_`` as ``-``),
    with the stage's type, default, range and help: declared once, in the stage."""
    declared = {s.name: s for s in stage.settings}
    missing = [n for n in names if n not in declared]
    if missing:
        raise ValueError(
            f"{stage.__name__} declares no setting {missing}; it has {sorted(declared)}"
        )
    out = []
    for n in names:
        s = declared[n]
        renamed = Setting(
            prefix + n, s.kind, s.default, s.help, s.choices, s.low, s.high, s.open_low,
            s.open_high, s.finite,
        )  # fmt: skip
        out.append(Option(renamed, table, n))
    return tuple(out)


@dataclass(frozen=True)
class TableOption:
    """An option that is a whole TOML table of free keys (e.g. ``[denoise]``: the denoiser's own
    keyword arguments): a dict in the configuration, ``--<flag> KEY=VALUE`` (repeatable) on the
    command line.

    Attributes:
        name: the configuration's attribute (a dict).
        table: the TOML table.
        flag: the command-line flag without its dashes.
        help: one line.
        follows: the option whose change (on the command line) empties this one.
    """

    name: str
    table: str
    flag: str
    help: str
    follows: str = ""


@dataclass
class Context:
    """What a builder sees: the resolved configuration and the calibration frames.

    Attributes:
        config: the :class:`~tof_fpn_torch.clean.CleanConfig`.
        calibration: a callable returning the :class:`~tof_fpn_torch.clean.Calibration` frames
            (measured once, when first called; the stages built before this one already
            applied), or raising ``ValueError`` when the run has none.
        measured: set by a builder that used the calibration frames.
        notes: what the builder says about what it found (:meth:`note`).
        built: the stages the earlier steps built, by step name.
    """

    config: Any
    calibration: Callable[[], Any]
    measured: bool = False
    notes: list[str] = field(default_factory=list)
    #: the stages the earlier steps built (step name -> stage)
    built: dict = field(default_factory=dict)

    def frames(self):
        """The calibration frames (and note that a stage was measured on them)."""
        self.measured = True
        return self.calibration()

    def note(self, text: str) -> None:
        """One line for the stage line and the manifest: what was found, or why nothing was
        built (a builder that returns None says why here)."""
        self.notes.append(text)


def _nothing(*_args) -> list:
    return []


@dataclass(frozen=True)
class Step:
    """One step of ``tof-fpn clean`` (module docstring).

    Attributes:
        name: the key of its part of the manifest's ``pipeline`` record and of its per-file
            record.
        options: its :class:`Option` s (their names are unique across the registered steps).
        build: ``build(context) -> module or None`` (None: the step does nothing in this run).
            The module is a :class:`~tof_fpn_torch.runtime.stage.Stage`; its :meth:`run` gives
            the frame and the record.
        describe: ``describe(module or None) -> dict``: plain values recorded in the manifest's
            ``pipeline`` (merged into one dict over the steps).
        phrase: ``phrase(info) -> list of str``: its part of the printed stage line, from the
            merged ``describe`` dict.
        scope: ``"frame"``: the module runs on batches of frames (frames of different files);
            ``"sequence"``: on the frames of one frame set in order, after every frame step,
            through ``run_sequence``.
        run_sequence: ``run_sequence(module, depth, amplitude, timestamps) -> (depth, record)``
            for a sequence step.
        file_record: ``file_record(per_frame) -> value``: its entry in a file's report, from the
            per-frame records (a list of ``{field: float}``, one per frame of the file) of a
            frame step, or from the per-set records of a sequence step.
        summary: ``summary(records) -> lines``: what the command prints, from the ``done``
            manifest records of the run (a frame step's ``file_record`` is in their
            ``report``).
        resolve: ``resolve(values) -> None``: fills in presets and checks the step's options
            together (``ValueError``), on the dict of every option's value.
        record_key: where ``file_record`` goes: ``"report"`` (the file's report) or ``"file"``
            (the file's manifest record itself).
        report_name: the key of ``file_record`` there (default: ``name``).
        keep_maps: ``keep_maps(config) -> names``: the per-pixel record fields written beside
            each output as ``<output stem>.<step>_<field>.npy`` (float32, frames x H x W) and
            listed in the file's manifest record under ``<step>_<field>``.
        on_replace: ``on_replace(old, changes) -> None``: how a change of some of its options
            given on the command line over a configuration file moves the others (e.g. a new
            preset resets what it sets); edits ``changes``.
    """

    name: str
    options: tuple[Option | TableOption, ...]
    build: Callable[[Context], nn.Module | None]
    describe: Callable[[nn.Module | None], dict]
    phrase: Callable[[dict], list[str]] = _nothing
    scope: str = "frame"
    run_sequence: Callable | None = None
    file_record: Callable[[list], Any] | None = None
    summary: Callable[[list[dict]], list[str]] = _nothing
    resolve: Callable[[dict], None] | None = None
    record_key: str = "report"
    report_name: str = ""
    keep_maps: Callable[[Any], tuple[str, ...]] | None = None
    on_replace: Callable[[dict, dict], None] | None = None

    @property
    def report_key(self) -> str:
        return self.report_name or self.name

    def __post_init__(self) -> None:
        if self.scope not in SCOPES:
            raise ValueError(
                f"Step {self.name!r}: scope must be one of {SCOPES}, got {self.scope!r}"
            )
        if self.scope == "sequence" and self.run_sequence is None:
            raise ValueError(f"Step {self.name!r}: a sequence step needs run_sequence")
        if self.record_key not in ("report", "file"):
            raise ValueError(f"Step {self.name!r}: record_key must be 'report' or 'file'")
