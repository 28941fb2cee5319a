"""The recording format: T frames of one camera, real or simulated, as a versioned ``.npz``.

Contract (``format_version`` 1; docs/io.md), arrays in the file:

* ``depth``: float32 (T, H, W), metres, NaN for every invalid pixel (no 0, negative or inf);
* ``amplitude``: float32 (T, H, W), camera units (``meta["amplitude_unit"]`` says which);
* ``raw`` (optional): float32 (T, N, H, W) correlation samples, N = ``meta["n_phases"]``;
* ``timestamps_s`` (optional): float64 (T,), seconds, finite and strictly increasing;
* ``content`` = ``"tof_fpn_torch.recording"``, ``format_version`` (int), ``meta``: a JSON object
  with at least ``modulation_frequency_hz`` (> 0, a list of them, or null if unknown),
  ``integration_time_us`` (> 0 or null) and ``n_phases`` (int >= 1 or null); ``camera``, if
  given, names a profile of :mod:`tof_fpn_torch.cameras`.

In memory a :class:`Recording` holds the package's (B, C, H, W) tensors: depth and amplitude
(T, 1, H, W), raw (T, N, H, W). Simulated and real captures are the same type:
:func:`recording_from_simulation` converts a simulator result (read by attribute, without
importing :mod:`tof_fpn_torch.sim`), the Azure Kinect reader returns one.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from .. import cameras
from ..runtime.validity import valid_mask
from ._common import FormatError, check_not_empty
from ._container import jsonable, read_container, write_container

__all__ = [
    "FORMAT_VERSION",
    "RECORDING_CONTENT",
    "REQUIRED_META",
    "Recording",
    "check_meta",
    "read_recording",
    "recording_from_simulation",
    "write_recording",
    "write_recording_like",
]

#: the version this code writes (and the newest it reads)
FORMAT_VERSION: int = 1
RECORDING_CONTENT = "tof_fpn_torch.recording"
#: meta keys every recording states (a value may be null: unknown for that camera)
REQUIRED_META: tuple[str, ...] = ("modulation_frequency_hz", "integration_time_us", "n_phases")


def _positive(value, key: str, allow_list: bool = False) -> None:
    if value is None:
        return
    if allow_list and isinstance(value, (list, tuple)):
        if not value:
            raise ValueError(f"meta[{key!r}] must not be an empty list")
        for v in value:
            _positive(v, key)
        return
    ok = not isinstance(value, bool) and isinstance(value, (int, float))
    if not ok or not (math.isfinite(value) and value > 0):
        what = "a number > 0, a list of them, or None" if allow_list else "a number > 0 or None"
        raise ValueError(f"meta[{key!r}] must be {what}, got {value!r}")


def check_meta(meta: dict) -> dict:
    """Check a recording's meta dict; return it as JSON data (tensors -> numbers)."""
    meta = jsonable(meta) if isinstance(meta, dict) else meta
    if not isinstance(meta, dict):
        raise ValueError(f"meta must be a dict, got {type(meta).__name__}")
    missing = [k for k in REQUIRED_META if k not in meta]
    if missing:
        raise ValueError(
            f"meta lacks {missing}; a recording states {list(REQUIRED_META)} (None if unknown)"
        )
    _positive(meta["modulation_frequency_hz"], "modulation_frequency_hz", allow_list=True)
    _positive(meta["integration_time_us"], "integration_time_us")
    n = meta["n_phases"]
    if n is not None and (isinstance(n, bool) or not isinstance(n, int) or n < 1):
        raise ValueError(f"meta['n_phases'] must be an int >= 1 or None, got {n!r}")
    if meta.get("camera") is not None:
        cameras.profile(meta["camera"])  # ValueError listing the known profiles
    return meta


def _float_frames(x, name: str, channels: int | None = 1) -> torch.Tensor:
    """(T, H, W) or (T, C, H, W) floating tensor / array -> float32 (T, C, H, W) CPU tensor."""
    if isinstance(x, np.ndarray):
        x = torch.from_numpy(x)
    if not isinstance(x, torch.Tensor):
        raise ValueError(f"{name} must be a torch.Tensor or numpy.ndarray, got {type(x).__name__}")
    if not x.is_floating_point():
        raise ValueError(f"{name} must be floating point, got dtype {x.dtype}")
    if x.dim() == 3 and channels == 1:
        x = x.unsqueeze(1)
    if x.dim() != 4 or (channels is not None and x.shape[1] != channels) or 0 in x.shape:
        want = "(T, H, W) or (T, 1, H, W)" if channels == 1 else "(T, N, H, W)"
        raise ValueError(f"{name} must have shape {want}, got {list(x.shape)}")
    return x.detach().to("cpu", torch.float32)


@dataclass
class Recording:
    """T frames of one ToF camera (real or simulated) with its settings.

    Args:
        depth: (T, 1, H, W) or (T, H, W) floating, metres; invalid pixels (per
            :func:`~tof_fpn_torch.runtime.valid_mask`) are stored as NaN.
        amplitude: same shape, camera units.
        meta: dict with ``modulation_frequency_hz``, ``integration_time_us``, ``n_phases`` (each
            may be None where unknown) and anything JSON can hold (``camera``: a profile name;
            ``amplitude_unit``; ``source``).
        raw: optional (T, N, H, W) correlation samples (N = ``meta["n_phases"]``).
        timestamps_s: optional (T,) seconds, finite and strictly increasing.

    Everything is converted to float32 CPU tensors (``timestamps_s`` float64); the inputs are not
    modified. ``ValueError`` names the field, what it got and what is allowed.
    """

    depth: torch.Tensor
    amplitude: torch.Tensor
    meta: dict
    raw: torch.Tensor | None = None
    timestamps_s: torch.Tensor | None = None

    def __post_init__(self) -> None:
        depth = _float_frames(self.depth, "depth")
        self.depth = torch.where(valid_mask(depth), depth, torch.full_like(depth, math.nan))
        self.amplitude = _float_frames(self.amplitude, "amplitude")
        if self.amplitude.shape != self.depth.shape:
            raise ValueError(
                f"amplitude must have the shape of depth {list(self.depth.shape)}, got "
                f"{list(self.amplitude.shape)}"
            )
        self.meta = check_meta(self.meta)
        t, _, h, w = self.depth.shape
        if self.raw is not None:
            self.raw = _float_frames(self.raw, "raw", channels=None)
            n = self.meta["n_phases"]
            if self.raw.shape[0] != t or self.raw.shape[2:] != (h, w):
                raise ValueError(
                    f"raw must have shape (T, N, H, W) = ({t}, N, {h}, {w}), got "
                    f"{list(self.raw.shape)}"
                )
            if n is not None and self.raw.shape[1] != n:
                raise ValueError(
                    f"raw has {self.raw.shape[1]} samples per frame, meta n_phases {n}"
                )
        if self.timestamps_s is not None:
            ts = self.timestamps_s
            if isinstance(ts, torch.Tensor):
                ts = ts.detach().cpu().numpy()
            ts = torch.from_numpy(np.array(ts, dtype=np.float64))
            if ts.shape != (t,) or not bool(torch.isfinite(ts).all()):
                raise ValueError(f"timestamps_s must be {t} finite seconds, got {list(ts.shape)}")
            if t > 1 and not bool((ts[1:] > ts[:-1]).all()):
                raise ValueError("timestamps_s must be strictly increasing")
            self.timestamps_s = ts

    @property
    def frames(self) -> int:
        """T, the number of frames."""
        return self.depth.shape[0]

    def replace(self, **changes) -> Recording:
        """A validated copy with some fields changed (``rec.replace(depth=cleaned)``)."""
        return dataclasses.replace(self, **changes)


def write_recording(
    path, recording: Recording, *, compress: bool = False, allow_empty: bool = False
) -> Path:
    """Write a :class:`Recording` as a version-1 recording ``.npz`` (deterministic bytes).

    ``allow_empty``: accept frames with no valid pixel (refused by default). ``compress``:
    deflate the arrays (NaN-heavy depth and raw samples shrink)."""
    if not isinstance(recording, Recording):
        raise ValueError(f"recording must be a Recording, got {type(recording).__name__}")
    check_not_empty(recording.depth, recording.amplitude, "write_recording", allow_empty)
    arrays = {
        "depth": recording.depth[:, 0].numpy(),
        "amplitude": recording.amplitude[:, 0].numpy(),
    }
    if recording.raw is not None:
        arrays["raw"] = recording.raw.numpy()
    if recording.timestamps_s is not None:
        arrays["timestamps_s"] = recording.timestamps_s.numpy()
    return write_container(
        path, RECORDING_CONTENT, FORMAT_VERSION, recording.meta, arrays, compress
    )


_DTYPES = {"depth": np.float32, "amplitude": np.float32, "raw": np.float32}


def read_recording(path, *, allow_empty: bool = False) -> Recording:
    """Read a recording ``.npz`` and check it against the contract (``FormatError`` if not).

    Returns:
        :class:`Recording`: depth / amplitude float32 (T, 1, H, W) (metres, NaN invalid / camera
        units), raw float32 (T, N, H, W) or None, timestamps_s float64 (T,) or None, meta dict.
    """
    arrays, meta = read_container(
        path,
        RECORDING_CONTENT,
        FORMAT_VERSION,
        ("depth", "amplitude"),
        ("raw", "timestamps_s"),
    )
    for key, arr in arrays.items():
        want = np.float64 if key == "timestamps_s" else _DTYPES[key]
        ndim = {"depth": 3, "amplitude": 3, "raw": 4, "timestamps_s": 1}[key]
        if arr.dtype != want or arr.ndim != ndim:
            raise FormatError(
                f"{path}: {key!r} must be {np.dtype(want)} with {ndim} dimensions, got "
                f"{arr.dtype} {arr.shape}"
            )
    d = arrays["depth"]
    with np.errstate(invalid="ignore"):
        bad = int((~np.isnan(d) & ~(np.isfinite(d) & (d > 0))).sum())
    if bad:
        raise FormatError(
            f"{path}: depth has {bad} value(s) that are neither NaN nor finite > 0 m; the "
            "recording contract stores every invalid pixel as NaN"
        )
    try:
        rec = Recording(
            torch.from_numpy(d),
            torch.from_numpy(arrays["amplitude"]),
            meta,
            raw=torch.from_numpy(arrays["raw"]) if "raw" in arrays else None,
            timestamps_s=arrays.get("timestamps_s"),
        )
    except ValueError as exc:
        raise FormatError(f"{path}: not a valid recording: {exc}") from exc
    check_not_empty(rec.depth, rec.amplitude, str(path), allow_empty)
    return rec


def recording_from_simulation(
    result,
    camera,
    *,
    profile: str | None = None,
    timestamps_s=None,
    include_raw: bool = True,
    meta: dict | None = None,
) -> Recording:
    """A :class:`Recording` of a simulator run (no import of :mod:`tof_fpn_torch.sim`).

    Args:
        result: a :class:`tof_fpn_torch.sim.SimResult` (or any object with ``depth``,
            ``amplitude`` (B, 1, H, W), ``samples`` (B, N, H, W) and ``unit``): depth in metres
            (the decoder's 0 for dead pixels becomes NaN), amplitude and samples in ``unit``
            (``"DN"`` or ``"e-"``). All B frames become the recording's T frames.
        camera: the :class:`tof_fpn_torch.sim.Camera` that produced it (``modulation_frequency``
            Hz, ``integration_time`` s, ``n_phases``, ``as_dict()``).
        profile: optional camera profile name to record as ``meta["camera"]``.
        timestamps_s: optional (T,) seconds.
        include_raw: store the correlation samples as ``raw``.
        meta: extra meta entries (e.g. ``{"parameters": sim.parameters()}``); they override.
    """
    for attr in ("depth", "amplitude", "samples", "unit"):
        if not hasattr(result, attr):
            raise ValueError(f"result must be a simulator result with .{attr}, got {result!r}")
    for attr in ("modulation_frequency", "integration_time", "n_phases", "as_dict"):
        if not hasattr(camera, attr):
            raise ValueError(f"camera must be a simulator Camera with .{attr}, got {camera!r}")
    info = {
        "modulation_frequency_hz": float(camera.modulation_frequency),
        "integration_time_us": float(camera.integration_time) * 1e6,
        "n_phases": int(camera.n_phases),
        "amplitude_unit": str(result.unit),
        "source": "tof_fpn_torch.sim",
        "sim_camera": jsonable(camera.as_dict()),
    }
    if profile is not None:
        info["camera"] = profile
    info.update(meta or {})
    return Recording(
        result.depth,
        result.amplitude,
        info,
        raw=result.samples if include_raw else None,
        timestamps_s=timestamps_s,
    )


def write_recording_like(src, dst, arrays: dict[str, np.ndarray], sets: dict, depth_scale=None):
    """Write a camera container's cleaned depth as the package's recording ``.npz`` at ``dst``
    (there is no faithful writer for the containers): ``arrays[""]`` the depth, float32 (T, H, W)
    metres, and from ``sets[""]`` (the container's :class:`~._common.FrameSet` as read) the
    amplitude, the reader's meta and timestamps. ``src`` and ``depth_scale`` are not used (the
    signature of the table's rewriters, :mod:`.formats`)."""
    fs = sets[""]
    rec = Recording(
        torch.from_numpy(arrays[""]),
        torch.from_numpy(fs.amplitude),
        fs.meta,
        timestamps_s=fs.timestamps_s,
    )
    write_recording(dst, rec, allow_empty=True)
