"""The configuration of a ``tof-fpn clean`` run: which stages, their settings, the file options.

A run is described by a :class:`CleanConfig`, read from a small TOML file (:func:`load_config`,
Python's ``tomllib``), from command-line flags, or both (flags win). The resolved configuration is
saved beside the output as ``clean.toml`` together with the package version
(:func:`config_to_toml`); a saved file is itself a valid ``--config``. Format (every key optional,
the defaults shown)::

    [pipeline]
    stage = "auto"        # the defaults of the three keys below: auto | paper
                          #   auto:  destripe = auto, notch = data, fusion = data (all measured)
                          #   paper: destripe = off, notch = design, fusion = camera (CamCube)
    destripe = "auto"     # broadband column / row offsets: off | columns | rows | both | auto
    notch = "data"        # periodic stripes (FPNSuppression): off | design | data
    fusion = "data"       # eq. (11) amplitude fusion: off | camera | data | manual
                          #   (default: data with notch = data, camera with design, else off)
    denoise = "none"      # none or a denoiser of tof_fpn_torch.clean.DENOISERS (nlm, bm3d, ...)
    pattern = "wall.npz"  # a fixed pattern from tof-fpn calibrate, removed first (default: none)
    temporal = false      # the temporal filter over the frames of each multi-frame file, last
    flying = "off"        # flying (mixed) pixels at depth edges, after the FPN stage and before
                          #   the denoiser: off | mark (counted only) | invalidate | reassign
    flying_confidence = false  # write the stage's confidence map beside each output
                          #   (<output stem>.flying_confidence.npy, float32 frames x H x W)

    [notch]
    order = 20            # filter order
    rho = 0.14            # transition half-width / pi (notch = data: chosen from the notches)
    gate = true           # the per-frame stripe gate: stripe-free frames pass unchanged

    [fusion]
    camera = "camcube"    # profile whose thresholds (amplitude units) fusion = camera uses
                          #   (default: the camera the files say they come from, else camcube)
    low = 70.0            # fusion = manual: the thresholds, in the camera's amplitude units
    high = 350.0

    [temporal]            # tof_fpn_torch.runtime.TemporalFilter (clean/temporal.py)
    alpha = 0.2           # EMA weight of the new frame
    guard = 3.0           # motion guard, sd of the innovation
    persistence = 0       # frames an invalid pixel shows its last estimate

    [calibration]
    frames = 8            # frames (the first in file order) that the data-driven stages measure

    [denoise]             # keyword arguments of the denoiser, e.g. for nlm:
    patch_size = 7        #   patch_size, patch_distance, h, k, kernel

    [files]
    batch = 8             # files per group and frames per compute batch
    depth_scale = 0.001   # metres per stored depth unit (default: mm for integer files, m for
                          #   floating ones, an HDF5 dataset's scale_m attribute)
    height = 424          # frame size of raw .bin / .raw files, pixels
    width = 512
    rounding = "dither"   # integer outputs: dither (the correction survives in the mean) |
                          #   nearest (plain rounding: corrections under half a unit vanish)
    output_scale = 0.0001 # integer outputs: metres per stored unit (default: the input's)

``auto`` / ``data`` stages are measured on the calibration frames when the run starts
(:mod:`tof_fpn_torch.build`: ``broadband_from_data``, ``suppression_from_data``,
``fusion_from_data``); ``[tof_fpn_torch]`` (the version a saved file records) is accepted and not
used. A key given explicitly wins over the ``stage`` preset.

**Integer outputs.** A uint16-mm file cannot hold a correction of 0.3 mm by rounding to the
nearest millimetre: it rounds back to the input. ``rounding = "dither"`` (default) rounds each
valid pixel up with probability equal to its fractional part (a uniform dither from a generator
seeded by the frame's own bytes, so the same input gives the same bytes): every column, row and
region keeps the corrected mean, at the price of a rounding noise of variance ``f (1 - f)``
(<= 1/4 unit^2, 1/6 on average) instead of nearest rounding's 1/12 (and pixels the stage did not
move keep their value exactly). ``output_scale`` stores the depth in finer units instead (e.g.
0.1 mm: a uint16 then reaches 6.5535 m); the files then no longer hold millimetres, so a reader
must be told the scale (the manifest records it, and a PNG gets a ``depth_scale_m`` text chunk).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from pathlib import Path

try:
    import tomllib
except ModuleNotFoundError:  # Python 3.10: the same parser as a package
    import tomli as tomllib

from .. import __version__, cameras
from .. import constants as K

__all__ = [
    "BATCH",
    "FLYING",
    "CALIBRATION_FRAMES",
    "CHOICES",
    "CleanConfig",
    "config_from_dict",
    "config_to_toml",
    "load_config",
]

#: Files per group and frames per compute batch (``batch``): the batches are fixed by the sorted
#: file list, so that a resumed run or the Ray engine computes every frame in the same batch
#: (batched torch kernels differ in the last bits between batch sizes).
BATCH: int = 8
#: Frames (the first in file order) on which ``auto`` / ``data`` stages are measured when the run
#: starts (``calibration_frames``).
CALIBRATION_FRAMES: int = 8

#: the allowed values of the ``[pipeline]`` keys (``denoise``: ``none`` or a registered name)
CHOICES: dict[str, tuple[str, ...]] = {
    "stage": ("auto", "paper"),
    "destripe": ("off", "columns", "rows", "both", "auto"),
    "notch": ("off", "design", "data"),
    "fusion": ("off", "camera", "data", "manual"),
    "rounding": ("dither", "nearest"),
}
#: the allowed values of ``flying`` (absent: off, and left out of the saved file)
FLYING: tuple[str, ...] = ("off", "mark", "invalidate", "reassign")
#: the fusion that goes with each notch choice when ``fusion`` is not given
FUSION_FOR_NOTCH: dict[str, str] = {"off": "off", "design": "camera", "data": "data"}
#: what each ``stage`` preset sets (a key given explicitly wins)
PRESETS: dict[str, dict[str, str]] = {
    "auto": {"destripe": "auto", "notch": "data"},
    "paper": {"destripe": "off", "notch": "design", "camera": "camcube"},
}
#: TOML table -> {key: CleanConfig field}
_TABLES: dict[str, dict[str, str]] = {
    "pipeline": {
        k: k
        for k in (
            "stage",
            "destripe",
            "notch",
            "fusion",
            "denoise",
            "pattern",
            "temporal",
            "flying",
            "flying_confidence",
        )
    },
    "notch": {"order": "order", "rho": "rho", "gate": "gate"},
    "fusion": {"camera": "camera", "low": "low", "high": "high"},
    "calibration": {"frames": "calibration_frames"},
    "temporal": {k: f"temporal_{k}" for k in ("alpha", "guard", "persistence")},
    "files": {
        k: k for k in ("batch", "depth_scale", "height", "width", "rounding", "output_scale")
    },
}


@dataclass
class CleanConfig:
    """What a ``tof-fpn clean`` run does (the TOML keys: module docstring).

    Attributes:
        stage: the preset of ``destripe``, ``notch``, ``fusion`` (and ``camera``) where those are
            None (:data:`PRESETS`): ``"auto"`` measures every piece on the calibration frames,
            ``"paper"`` is the paper's CamCube stage (gated).
        destripe, notch, fusion: stage choices (:data:`CHOICES`); ``fusion=None`` resolves to
            ``"data"`` with ``notch="data"``, ``"camera"`` with ``"design"`` and ``"off"`` without
            a notch.
        denoise: ``"none"`` or a name of :data:`tof_fpn_torch.clean.DENOISERS`.
        pattern: a pattern file of ``tof-fpn calibrate`` (:mod:`.pattern`), removed from every
            frame before the other stages (and before they are measured), or None.
        order, rho, gate: the notch filter (``rho=None``: 0.14 for ``design``, from the notch
            frequencies for ``data``).
        camera, low, high: fusion thresholds, in the camera's amplitude units (``camera=None``:
            the profile of the camera the files come from, else CamCube's).
        calibration_frames: frames measured by ``auto`` / ``data`` stages.
        denoise_options: keyword arguments of the denoiser.
        batch: files per group and frames per compute batch (fixes the batches, so that a
            resumed or a Ray run computes every frame in the same batch as an uninterrupted one).
        depth_scale: metres per stored depth unit, or None (file default).
        height, width: pixels of raw ``.bin`` / ``.raw`` frames.
        rounding: integer outputs: ``"dither"`` or ``"nearest"`` (module docstring).
        output_scale: integer outputs: metres per stored unit, or None (the input's).
        temporal: the temporal filter over the frames of each multi-frame file (off by default).
        temporal_alpha, temporal_guard, temporal_persistence: its settings.
        flying: the flying-pixel stage (:class:`~tof_fpn_torch.runtime.FlyingPixels`):
            None or ``"off"``, ``"mark"`` (counted in the record, depth unchanged), ``"invalidate"`` or
            ``"reassign"``.
        flying_confidence: write the flying-pixel stage's confidence map (float32, 1: a surface
            explains the pixel, < 0.5: flagged, 0: invalid) beside each output as
            ``<output stem>.flying_confidence.npy`` (frames x H x W); needs ``flying`` on. None:
            absent (off, and left out of the saved file).
    """

    stage: str = "auto"
    destripe: str | None = None
    notch: str | None = None
    fusion: str | None = None
    denoise: str = "none"
    pattern: str | None = None
    order: int = K.DEFAULT_ORDER
    rho: float | None = None
    gate: bool = True
    camera: str | None = None
    low: float | None = None
    high: float | None = None
    calibration_frames: int = CALIBRATION_FRAMES
    denoise_options: dict = field(default_factory=dict)
    batch: int = BATCH
    depth_scale: float | None = None
    height: int | None = None
    width: int | None = None
    rounding: str = "dither"
    output_scale: float | None = None
    temporal: bool = False
    temporal_alpha: float = K.TEMPORAL_ALPHA
    temporal_guard: float = K.TEMPORAL_GUARD
    temporal_persistence: int = 0
    flying: str | None = None
    flying_confidence: bool | None = None

    def __post_init__(self) -> None:
        if self.stage not in CHOICES["stage"]:
            raise ValueError(f"stage must be one of {list(CHOICES['stage'])}, got {self.stage!r}")
        for key, value in PRESETS[self.stage].items():
            if getattr(self, key) is None:
                setattr(self, key, value)
        if self.fusion is None:
            self.fusion = FUSION_FOR_NOTCH.get(self.notch)
        for key, allowed in CHOICES.items():
            v = getattr(self, key)
            if v not in allowed:
                raise ValueError(f"{key} must be one of {list(allowed)}, got {v!r}")
        if self.camera is not None:
            cameras.profile(self.camera)  # ValueError naming the known profiles
        if self.notch == "off" and self.fusion != "off":
            raise ValueError(
                f"fusion = {self.fusion!r} blends the notch filter's output: it needs notch = "
                "'design' or 'data' (got notch = 'off')"
            )
        if self.pattern is not None and (not isinstance(self.pattern, str) or not self.pattern):
            raise ValueError(f"pattern must be a file name or absent, got {self.pattern!r}")
        if not isinstance(self.denoise, str) or not self.denoise:
            raise ValueError(f"denoise must be 'none' or a denoiser name, got {self.denoise!r}")
        if self.flying is not None and self.flying not in FLYING:
            raise ValueError(f"flying must be one of {list(FLYING)}, got {self.flying!r}")
        if self.flying_confidence is not None and not isinstance(self.flying_confidence, bool):
            raise ValueError(
                f"flying_confidence must be true or false, got {self.flying_confidence!r}"
            )
        if self.flying_confidence and self.flying in (None, "off"):
            raise ValueError(
                "flying_confidence needs the flying stage: flying = mark, invalidate or reassign"
            )
        _int("order", self.order, 1)
        _int("calibration_frames", self.calibration_frames, 1)
        _int("batch", self.batch, 1)
        for name in ("height", "width"):
            if getattr(self, name) is not None:
                _int(name, getattr(self, name), 1)
        for name in ("rho", "low", "high", "depth_scale", "output_scale"):
            v = getattr(self, name)
            if v is not None:
                if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
                    raise ValueError(f"{name} must be a finite number or absent, got {v!r}")
                if v <= 0 and name != "low":
                    raise ValueError(f"{name} must be > 0, got {v!r}")
                setattr(self, name, float(v))
        if self.fusion == "manual" and (self.low is None or self.high is None):
            raise ValueError(
                "fusion = 'manual' needs low and high (amplitude units of the camera), got "
                f"low={self.low!r}, high={self.high!r}"
            )
        for name in ("gate", "temporal"):
            if not isinstance(getattr(self, name), bool):
                raise ValueError(f"{name} must be true or false, got {getattr(self, name)!r}")
        _temporal_settings(self)
        if not isinstance(self.denoise_options, dict):
            raise ValueError(f"denoise_options must be a table, got {self.denoise_options!r}")

    def replace(self, **changes) -> CleanConfig:
        """A copy with ``changes`` (checked again); ``None`` values are ignored (flag not given)."""
        changes = {k: v for k, v in changes.items() if v is not None}
        if "stage" in changes and changes["stage"] != self.stage:  # a new preset: its defaults
            for key in ("destripe", "notch", "fusion", "camera"):
                changes.setdefault(key, None)
            return dataclasses.replace(self, **changes)
        same = self.fusion == FUSION_FOR_NOTCH[self.notch]
        if "notch" in changes and "fusion" not in changes and same:
            changes["fusion"] = None  # the fusion that goes with the new notch
        return dataclasses.replace(self, **changes)

    def identity(self) -> str:
        """What decides the output bytes (everything here): two runs into one OUTPUT must agree."""
        return config_to_toml(self, version=False)


def _temporal_settings(config: CleanConfig) -> None:
    """The ``[temporal]`` settings, checked as the filter checks them (floats and an int)."""
    for name in ("temporal_alpha", "temporal_guard"):
        v = getattr(config, name)
        if isinstance(v, bool) or not isinstance(v, (int, float)):
            raise ValueError(f"{name} must be a number, got {v!r}")
        setattr(config, name, float(v))
    _int("temporal_persistence", config.temporal_persistence, 0)
    from .temporal import temporal_module

    temporal_module(config.temporal_alpha, config.temporal_guard, config.temporal_persistence)


def _int(name: str, v, lo: int) -> None:
    if isinstance(v, bool) or not isinstance(v, int) or v < lo:
        raise ValueError(f"{name} must be an int >= {lo}, got {v!r}")


def config_from_dict(data: dict, where: str = "config") -> CleanConfig:
    """A :class:`CleanConfig` from parsed TOML; unknown tables or keys raise ``ValueError``."""
    kwargs: dict = {}
    for table, values in data.items():
        if table == "tof_fpn_torch":
            continue
        if table == "denoise":
            if not isinstance(values, dict):
                raise ValueError(f"{where}: [denoise] must be a table, got {values!r}")
            kwargs["denoise_options"] = dict(values)
            continue
        if table not in _TABLES or not isinstance(values, dict):
            raise ValueError(
                f"{where}: unknown table {table!r}; allowed: {sorted([*_TABLES, 'denoise'])}"
            )
        for key, value in values.items():
            if key not in _TABLES[table]:
                raise ValueError(
                    f"{where}: unknown key {key!r} in [{table}]; allowed: {sorted(_TABLES[table])}"
                )
            kwargs[_TABLES[table][key]] = value
    try:
        return CleanConfig(**kwargs)
    except ValueError as exc:
        raise ValueError(f"{where}: {exc}") from None


def load_config(path) -> CleanConfig:
    """Read a TOML configuration file (format: module docstring)."""
    p = Path(path)
    if not p.is_file():
        raise ValueError(f"config file not found: {path}")
    try:
        data = tomllib.loads(p.read_text())
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise ValueError(f"config {path}: not valid TOML: {exc}") from None
    return config_from_dict(data, f"config {path}")


def _toml_value(v) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, (int, float)):
        return repr(v)
    if isinstance(v, str):
        return '"' + v.replace("\\", "\\\\").replace('"', '\\"') + '"'
    raise ValueError(f"cannot write {v!r} ({type(v).__name__}) to TOML")


def config_to_toml(config: CleanConfig, version: bool = True) -> str:
    """The configuration as TOML (absent values left out), headed by ``[tof_fpn_torch] version``
    when ``version``; :func:`load_config` reads it back to an equal :class:`CleanConfig`."""
    lines = []
    if version:
        lines += ["[tof_fpn_torch]", f"version = {_toml_value(__version__)}", ""]
    for table, keys in _TABLES.items():
        lines.append(f"[{table}]")
        for key, name in keys.items():
            v = getattr(config, name)
            if v is not None:
                lines.append(f"{key} = {_toml_value(v)}")
        lines.append("")
    lines.append("[denoise]")
    for key in sorted(config.denoise_options):
        lines.append(f"{key} = {_toml_value(config.denoise_options[key])}")
    return "\n".join(lines) + "\n"
