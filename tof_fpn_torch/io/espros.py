"""ESPROS TOFcam635 recordings of ESPROS's epc-tofcam-toolkit (HDF5, ``h5py``), found by their
content, not their name.

What the toolkit's recorder writes (one file per recording): root attributes with the camera's
settings (``image_type``, ``mod_frequency`` in Hz, ``integration_time_3d`` in us, ``roi``,
``roi_height``, ``roi_width``, ``chip_infos``, ...), a ``timestamps`` dataset (T,) of Unix
seconds and the frames, ``frames_0``, ``frames_1``, ... , one dataset per part of a frame:

* ``image_type`` ``"Point Cloud"``: ``frames_0`` (T, 3, N) float, the x, y, z of every pixel in
  mm, and ``frames_1`` (T, N) the amplitude, N = ``roi_height`` x ``roi_width``;
* ``"Amplitude"``, ``"Grayscale"``, ``"Distance"``, ``"DCS"``: ``frames_0`` alone, one image per
  frame. These hold no depth + amplitude pair and are refused with the reason
  (``amplitude only, no depth: ...``).

A point cloud is read as a frame set: **depth = z, the optical-axis depth** (the coordinate along
the optical axis, like the depth of an Azure Kinect or a Kinect v2; not the radial distance the
camera measures), in metres; amplitude = ``frames_1`` as stored (the camera's units, never
rescaled); invalid where z is not finite or <= 0 (the toolkit stores NaN beyond its maximum depth).
x and y are not read.

Pixel order. Toolkit versions differ: older ones store the point cloud of the image turned by
90 degrees (``np.rot90``), so its N pixels are the columns of the image one after the other, last
column first; newer ones store the image row by row. The reader tells the two apart by the point
cloud itself (the ray directions x / z and y / z change smoothly from pixel to pixel only in the
right order) and returns the image **in the sensor's orientation**, the orientation of the
toolkit's amplitude and distance recordings of the same camera (the plain column-major reading,
reshape to (W, H) and transpose, gives it mirrored left-right). ``meta["pixel_order"]`` says which
order the file had.

Units. The toolkit writes x, y, z in mm; ``depth_scale`` (metres per stored unit) overrides.
Without it, a point cloud whose every finite z lies below the camera's unambiguous range in
metres (c / 2f, 7.5 m at 20 MHz) cannot be in mm (the whole scene within 7.5 mm of the lens) and
is read as metres; ``meta["depth_unit"]`` says which.

The camera is ``espros_tofcam635`` (:mod:`tof_fpn_torch.cameras`) when the region of interest
fits the epc635's 160 x 60 pixels; the toolkit records other ESPROS cameras the same way, whose
larger frames leave ``camera`` None. ``tof-fpn clean`` writes a cleaned point cloud as the
package's recording ``<name>.npz`` (its amplitude, meta and timestamps; the HDF5 file is not
rewritten), like the other camera containers.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import h5py
import numpy as np
import torch

from .. import constants as K
from ._common import FormatError, FrameSet, check_not_empty, check_scale, decoding, existing_file
from ._container import jsonable
from .recording import Recording

__all__ = [
    "ESPROS_AMPLITUDE_UNIT",
    "ESPROS_CAMERA",
    "EPC635_SIZE",
    "espros_frame_sets",
    "espros_frame_sizes",
    "is_espros_hdf5",
    "read_espros_hdf5",
]

#: the camera profile of the files this module reads
ESPROS_CAMERA = "espros_tofcam635"
#: the epc635 sensor's pixels, (rows, columns)
EPC635_SIZE: tuple[int, int] = (60, 160)
ESPROS_AMPLITUDE_UNIT = "ESPROS epc635 amplitude as the epc-tofcam-toolkit records it (LSB)"
_SUFFIXES = (".h5", ".hdf5")
#: without ``mod_frequency``: the epc635's lowest modulation frequency, 10 MHz
_LOWEST_FREQUENCY_HZ = 10e6
#: image types holding one amplitude-like image per frame
_AMPLITUDE_TYPES = ("amplitude", "grayscale")


def _text(value) -> str:
    if isinstance(value, bytes):
        return value.decode("utf-8", "replace")
    return str(value)


def _attribute(value):
    """A root attribute as JSON data for the meta (text for what JSON cannot hold)."""
    if isinstance(value, bytes):
        return _text(value)
    try:
        out = jsonable(value)
        json.dumps(out, allow_nan=False)
        return out
    except (TypeError, ValueError):
        return str(value)


def _is_toolkit_file(f: h5py.File) -> bool:
    """The toolkit's layout: a root attribute ``image_type``, root datasets ``frames_0`` and
    ``timestamps`` (and no ``depth`` dataset of this package's own HDF5 files)."""
    return (
        "image_type" in f.attrs
        and isinstance(f.get("frames_0"), h5py.Dataset)
        and isinstance(f.get("timestamps"), h5py.Dataset)
        and "depth" not in f
    )


def is_espros_hdf5(path) -> bool:
    """Whether ``path`` is an existing ``.h5`` / ``.hdf5`` file (any case) written by the
    epc-tofcam-toolkit (module docstring). Reads the file's structure only; never raises."""
    p = Path(path)
    if p.suffix.lower() not in _SUFFIXES:
        return False
    try:
        if not p.is_file():
            return False
        with h5py.File(p, "r") as f:
            return _is_toolkit_file(f)
    except Exception:  # noqa: BLE001 -- not readable as HDF5: not this format
        return False


def _size(f: h5py.File, where: str) -> tuple[int, int]:
    """The frame size (rows, columns) the root attributes state: ``roi_height`` /
    ``roi_width``, else ``roi`` (x1, y1, x2, y2)."""
    a = f.attrs
    try:
        if "roi_height" in a and "roi_width" in a:
            return int(np.asarray(a["roi_height"])), int(np.asarray(a["roi_width"]))
        if "roi" in a:
            x1, y1, x2, y2 = (int(v) for v in np.asarray(a["roi"]).ravel())
            return y2 - y1, x2 - x1
    except (TypeError, ValueError) as exc:
        raise FormatError(
            f"{where}: the region of interest attributes are unreadable: {exc}"
        ) from exc
    raise FormatError(
        f"{where}: no frame size: the point cloud's root attributes state neither roi_height / "
        "roi_width nor roi"
    )


def _is_point_cloud(f: h5py.File) -> bool:
    f0, f1 = f["frames_0"], f.get("frames_1")
    return (
        len(f0.shape) == 3
        and f0.shape[1] == 3
        and isinstance(f1, h5py.Dataset)
        and f1.shape == (f0.shape[0], f0.shape[2])
    )


def _refusal(f: h5py.File, where: str) -> FormatError:
    """Why a toolkit file that is no point cloud cannot be read (one line)."""
    kind = _text(f.attrs["image_type"])
    frames = sorted(k for k in f if k.startswith("frames_"))
    shapes = ", ".join(f"{k} {tuple(f[k].shape)}" for k in frames)
    what = f"an ESPROS epc-tofcam-toolkit {kind!r} recording ({shapes})"
    advice = "record a 'Point Cloud' (x, y, z and amplitude) to have depth and amplitude"
    one_image = len(frames) == 1 and len(f["frames_0"].shape) == 3
    if one_image and kind.lower() in _AMPLITUDE_TYPES:
        return FormatError(f"{where}: amplitude only, no depth: {what}; {advice}")
    if one_image and kind.lower() == "distance":
        return FormatError(f"{where}: distance only, no amplitude: {what}; {advice}")
    return FormatError(
        f"{where}: not a point cloud of depth and amplitude: {what}; a point cloud has frames_0 "
        f"(T, 3, N) and frames_1 (T, N); {advice}"
    )


def _to_image(flat: np.ndarray, h: int, w: int, order: str) -> np.ndarray:
    """(..., N) pixels in the file's ``order`` -> (..., h, w) in the sensor's orientation."""
    lead = flat.shape[:-1]
    if order == "row-major":
        return flat.reshape(*lead, h, w)
    turned = flat.reshape(*lead, w, h)  # np.rot90 of the image: turned[i, j] = image[j, w-1-i]
    return np.swapaxes(turned[..., ::-1, :], -1, -2)


def _roughness(points: np.ndarray, h: int, w: int, order: str) -> float:
    """How much the ray directions x / z and y / z jump between neighbouring pixels when the
    pixels are taken in ``order``: small for the file's own order, large for the other."""
    z = _to_image(points[:, 2], h, w, order)
    with np.errstate(invalid="ignore", divide="ignore"):
        ok = np.isfinite(z) & (z > 0)
        total = 0.0
        for c in (0, 1):
            ray = np.where(ok, _to_image(points[:, c], h, w, order) / z, np.nan)
            for axis in (-1, -2):
                d = np.abs(np.diff(ray, axis=axis))
                d = d[np.isfinite(d)]
                if d.size == 0:
                    return math.nan
                total += float(d.mean())
    return total


def _pixel_order(points: np.ndarray, h: int, w: int) -> tuple[str, str]:
    """``(order, how it was found)`` of a (T, 3, N) point cloud (module docstring)."""
    if h == 1 or w == 1:
        return "rot90", "a single row or column: the orders differ only in direction; assumed"
    turned = _roughness(points, h, w, "rot90")
    rows = _roughness(points, h, w, "row-major")
    if math.isnan(turned) or math.isnan(rows):
        return "rot90", "assumed: too few valid pixels to tell the order from the rays"
    order = "rot90" if turned <= rows else "row-major"
    return order, f"from the rays' smoothness ({turned:.3g} turned, {rows:.3g} row by row)"


def _positive(value) -> float | None:
    try:
        v = float(np.asarray(value))
    except (TypeError, ValueError):
        return None
    return v if math.isfinite(v) and v > 0 else None


def _depth_unit(z: np.ndarray, frequency: float | None, depth_scale) -> tuple[float, str]:
    """Metres per stored unit of x, y, z and what says so (module docstring)."""
    if depth_scale is not None:
        return check_scale(depth_scale), "depth_scale given"
    with np.errstate(invalid="ignore"):
        good = z[np.isfinite(z) & (z > 0)]
    if good.size == 0:
        return 1e-3, "mm (the toolkit's unit)"
    reach = K.SPEED_OF_LIGHT / (2 * (frequency or _LOWEST_FREQUENCY_HZ))
    if float(good.max()) < reach:
        return 1.0, (
            f"m: every z is below {reach:.3g}, the unambiguous range in metres; in mm the whole "
            "scene would lie within millimetres of the lens"
        )
    return 1e-3, "mm (the toolkit's unit)"


def _read(path, depth_scale=None):
    """``(depth metres (T, H, W) float32 NaN-invalid, amplitude (T, H, W) float32, meta,
    timestamps (T,) float64 from 0 or None)`` of a point-cloud file."""
    p = existing_file(path, "ESPROS HDF5")
    with decoding(p, "an ESPROS epc-tofcam-toolkit HDF5 file"), h5py.File(p, "r") as f:
        if not _is_toolkit_file(f):
            raise FormatError(
                f"{p}: not an ESPROS epc-tofcam-toolkit recording (a root attribute image_type, "
                f"datasets frames_0 and timestamps); the file holds {sorted(f.keys())}"
            )
        if not _is_point_cloud(f):
            raise _refusal(f, str(p))
        h, w = _size(f, str(p))
        points, amp = f["frames_0"], f["frames_1"]
        for name, ds in (("frames_0", points), ("frames_1", amp)):
            if ds.dtype.kind not in "uif":
                raise FormatError(
                    f"{p}: {name} has dtype {ds.dtype}; x, y, z and amplitude are numbers"
                )
        if h < 1 or w < 1 or h * w != points.shape[2]:
            raise FormatError(
                f"{p}: the point cloud has {points.shape[2]} pixels per frame, the region of "
                f"interest {h} x {w} = {h * w}"
            )
        points, amp = points[()].astype(np.float64), amp[()]
        stamps = np.asarray(f["timestamps"][()], dtype=np.float64).ravel()
        attrs = {str(k): _attribute(v) for k, v in f.attrs.items()}
        image_type = _text(f.attrs["image_type"])
        frequency = _positive(f.attrs.get("mod_frequency"))
        integration = _positive(f.attrs.get("integration_time_3d"))
    t = points.shape[0]
    if t == 0:
        raise FormatError(f"{p}: the point cloud holds no frame")
    order, how = _pixel_order(points, h, w)
    scale, unit = _depth_unit(points[:, 2], frequency, depth_scale)
    z = _to_image(points[:, 2], h, w, order) * scale
    with np.errstate(invalid="ignore"):
        depth = np.where(np.isfinite(z) & (z > 0), z, np.nan).astype(np.float32)
    amplitude = np.ascontiguousarray(_to_image(amp, h, w, order), dtype=np.float32)
    depth = np.ascontiguousarray(depth)
    timestamps, start = None, None
    stamp_note = f"left out: {stamps.size} timestamps for {t} frames, or not strictly increasing"
    if (
        stamps.shape == (t,)
        and np.isfinite(stamps).all()
        and (t == 1 or (np.diff(stamps) > 0).all())
    ):
        start, timestamps = float(stamps[0]), stamps - stamps[0]
        stamp_note = "the file's timestamps (Unix s)"
    fits = h <= EPC635_SIZE[0] and w <= EPC635_SIZE[1]
    meta = {
        "camera": ESPROS_CAMERA if fits else None,
        "modulation_frequency_hz": frequency,
        "integration_time_us": integration,
        "n_phases": None,
        "amplitude_unit": ESPROS_AMPLITUDE_UNIT,
        "source": p.name,
        "source_format": "espros_hdf5",
        "image_type": image_type,
        "depth": "z of the point cloud: the optical-axis depth, not the radial distance",
        "depth_unit": unit,
        "pixel_order": order,
        "pixel_order_source": how,
        "start_time_s": start,
        "timestamp_source": stamp_note,
        "espros_attributes": attrs,
    }
    return depth, amplitude, meta, timestamps


def read_espros_hdf5(
    path,
    *,
    depth_topic=None,
    amplitude_topic=None,
    depth_scale: float | None = None,
    allow_empty: bool = False,
) -> Recording:
    """Read an ESPROS epc-tofcam-toolkit point cloud (module docstring) as a recording.

    Args:
        path: the ``.h5`` file.
        depth_topic, amplitude_topic: not used (the signature of the table's recording readers).
        depth_scale: metres per stored unit of x, y, z (default: mm, module docstring).
        allow_empty: accept frames with no valid pixel (refused by default).

    Returns:
        :class:`~tof_fpn_torch.io.Recording`: depth = z float32 (T, 1, H, W) in metres (NaN
        where z is not finite or <= 0), amplitude float32 (T, 1, H, W) as stored, both in the
        sensor's orientation; ``timestamps_s`` from the first frame (its Unix time in
        ``meta["start_time_s"]``); meta: ``camera`` (``espros_tofcam635``),
        ``modulation_frequency_hz`` (the ``mod_frequency`` attribute), ``integration_time_us``
        (``integration_time_3d``), ``n_phases`` None, ``pixel_order``, ``depth_unit``,
        ``espros_attributes`` (every root attribute).

    Raises:
        FormatError: not a toolkit file, or one with no depth + amplitude pair (an
            amplitude-only recording: ``"amplitude only, no depth: ..."``), a size that does not
            match the region of interest.
    """
    depth, amplitude, meta, ts = _read(path, depth_scale)
    rec = Recording(torch.from_numpy(depth), torch.from_numpy(amplitude), meta, timestamps_s=ts)
    check_not_empty(rec.depth, rec.amplitude, str(path), allow_empty)
    return rec


def espros_frame_sets(path, amplitude_path=None, *, depth_scale=None) -> list[FrameSet]:
    """The point cloud as one :class:`FrameSet`: float32 metres with NaN (``depth_scale`` 1), the
    reader's meta and timestamps (the stored reader of the table of formats)."""
    if amplitude_path is not None:
        raise ValueError(f"{Path(path)} holds depth and amplitude; amplitude_path must be None")
    depth, amplitude, meta, ts = _read(path, depth_scale)
    return [FrameSet("", depth, amplitude, 1.0, tuple(depth.shape), meta["camera"], meta, ts)]


def espros_frame_sizes(path) -> list[tuple[int, int]]:
    """The frame size a toolkit file's header states: the region of interest of a point cloud,
    the last two axes of a one-image-per-frame recording (nothing is decoded)."""
    with h5py.File(path, "r") as f:
        if not _is_toolkit_file(f):
            return []
        if _is_point_cloud(f):
            return [_size(f, str(path))]
        shape = f["frames_0"].shape
        return [tuple(int(n) for n in shape[-2:])] if len(shape) == 3 else []
