"""Camera files by name: the recordings of camera tools and the vendor-named raw files, read (and,
for ``tof-fpn clean``, written back) like the frame files of :mod:`.stored`.

* ``<name>.mkv``: an Azure Kinect recording (:mod:`.matroska`), camera ``azure_kinect``;
* ``<name>.bag``: a ROS 1 bag (:mod:`.rosbag`), camera ``realsense`` for librealsense recordings;
* a folder with a rosbag2 ``metadata.yaml``, ``<name>.mcap``, ``<name>.db3``: a ROS 2 bag;
* ``<name>_depth_u16le_<H>x<W>.bin`` + ``<name>_ir_u16le_<H>x<W>.bin`` (``.raw`` too, any case):
  ADI ADTF3175 depth (mm) + IR (counts), raw uint16 LE, camera ``adtf3175``;
* ``<name>_interleaved_<H>x<W>.bin``: ADI ADTF3175 interleaved, 5 bytes per pixel (depth u16 LE
  mm, confidence u8, AB u16 LE), camera ``adtf3175``.

``<H>x<W>`` is rows x columns, any size.

A recording container (``.mkv``, a bag) is read whole into a :class:`~.recording.Recording`; as
a :class:`~.stored.FrameSet` it is float32 metres with NaN (``depth_scale`` 1) and keeps the
reader's meta and timestamps, and :func:`write_camera_like` writes it as the package's recording
``.npz`` (there is no faithful writer for these containers). A vendor raw file keeps its own
layout: the size comes from its name (``--height`` / ``--width`` are for other raw files), the IR
file of a pair is the amplitude, and an interleaved file is written back with only the depth
bytes replaced (confidence and AB byte for byte).
"""

from __future__ import annotations

import os
import re
import zipfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from .. import cameras
from ._common import FormatError, check_same_shape, check_scale, existing_file
from .captures import ADI_INTERLEAVED_DTYPE
from .matroska import read_azure_kinect_mkv
from .raw import read_raw_array
from .recording import Recording, read_recording, write_recording
from .rosbag import ROS_BAG_SUFFIXES, read_ros_bag
from .stored import FrameSet, frame_set_tensors, read_frame_sets

__all__ = [
    "ACCEPTED",
    "CONTAINER_SUFFIXES",
    "ROS2_METADATA",
    "VendorName",
    "camera_sets",
    "is_camera_recording",
    "is_ros2_bag_dir",
    "read_any_recording",
    "read_camera_file",
    "recording_stem",
    "ros2_bag_files",
    "vendor_name",
    "vendor_partner",
    "write_camera_like",
]

#: files read whole as one recording (plus ROS 2 bag folders)
CONTAINER_SUFFIXES: tuple[str, ...] = (".mkv", *ROS_BAG_SUFFIXES)
#: the file that makes a folder a ROS 2 bag
ROS2_METADATA = "metadata.yaml"
#: what the folder tools take, for their error messages
ACCEPTED = (
    "<name>.npz / .h5 / .hdf5 (depth + amplitude); <name>_depth.<ext> + <name>_amplitude.<ext> "
    "(.png .tif .tiff .npy .bin .raw); Azure Kinect .mkv; ROS 1 .bag (RealSense too); ROS 2 bag "
    "(a folder with metadata.yaml, or .mcap / .db3); ADI <name>_depth_u16le_<H>x<W>.bin + "
    "<name>_ir_u16le_<H>x<W>.bin and <name>_interleaved_<H>x<W>.bin"
)
_ADI_PAIR = re.compile(
    r"^(?P<name>.+)_(?P<kind>depth|ir)_u16le_(?P<h>\d+)x(?P<w>\d+)\.(?:bin|raw)$", re.IGNORECASE
)
_ADI_INTERLEAVED = re.compile(
    r"^(?P<name>.+)_interleaved_(?P<h>\d+)x(?P<w>\d+)\.(?:bin|raw)$", re.IGNORECASE
)


@dataclass(frozen=True)
class VendorName:
    """A vendor-named raw file: ``kind`` (``"depth"``, ``"ir"``, ``"interleaved"``), the
    ``<name>`` part, the frame size from the name and the camera profile."""

    kind: str
    name: str
    height: int
    width: int
    camera: str = "adtf3175"


def vendor_name(file_name) -> VendorName | None:
    """The vendor name pattern ``file_name`` matches (table above), else None."""
    base = os.path.basename(os.fspath(file_name))
    m = _ADI_PAIR.match(base)
    if m:
        return VendorName(m["kind"].lower(), m["name"], int(m["h"]), int(m["w"]))
    m = _ADI_INTERLEAVED.match(base)
    if m:
        return VendorName("interleaved", m["name"], int(m["h"]), int(m["w"]))
    return None


def vendor_partner(file_name) -> str | None:
    """The other file of a vendor pair (depth <-> IR), same case and suffix; None otherwise."""
    base = os.path.basename(os.fspath(file_name))
    m = _ADI_PAIR.match(base)
    if m is None:
        return None
    other = {"depth": "ir", "ir": "depth"}[m["kind"].lower()]
    if m["kind"].isupper():
        other = other.upper()
    return base[: m.start("kind")] + other + base[m.end("kind") :]


def is_ros2_bag_dir(path) -> bool:
    """A folder holding a rosbag2 ``metadata.yaml`` (its first 64 KiB name
    ``rosbag2_bagfile_information``)."""
    meta = Path(path) / ROS2_METADATA
    try:
        with open(meta, "rb") as fh:
            return b"rosbag2_bagfile_information" in fh.read(1 << 16)
    except OSError:
        return False


def ros2_bag_files(path) -> tuple[str, ...]:
    """The files of a ROS 2 bag folder (``metadata.yaml`` and the storage files), sorted."""
    return tuple(sorted(str(p) for p in Path(path).iterdir() if p.is_file()))


def is_camera_recording(path) -> bool:
    """A recording container: a ``.mkv`` / ``.bag`` / ``.mcap`` / ``.db3`` file or a ROS 2 bag
    folder."""
    p = Path(path)
    if p.is_dir():
        return is_ros2_bag_dir(p)
    return p.suffix.lower() in CONTAINER_SUFFIXES


def recording_stem(file_name) -> str:
    """The name a frame file's recording gets (without ``.npz``): ``<name>`` of a vendor file,
    of ``<name>_depth.<ext>`` and of ``<name>.<ext>``; a folder's own name."""
    base = os.path.basename(os.path.normpath(os.fspath(file_name)))
    v = vendor_name(base)
    if v is not None:
        return v.name
    stem, suffix = os.path.splitext(base)
    if suffix.lower() in (".npy", ".png", ".tif", ".tiff", ".bin", ".raw"):
        for ending in ("_depth", "_amplitude"):
            if stem.endswith(ending):
                return stem[: -len(ending)]
    return stem


def read_camera_file(
    path,
    *,
    depth_topic: str | None = None,
    amplitude_topic: str | None = None,
    depth_scale: float | None = None,
    allow_empty: bool = False,
) -> Recording:
    """A recording container as a :class:`Recording`: ``.mkv`` -> :func:`read_azure_kinect_mkv`
    (always mm: ``depth_scale`` and the topics do not apply), a bag -> :func:`read_ros_bag`."""
    p = Path(path)
    if p.is_dir() or p.suffix.lower() in ROS_BAG_SUFFIXES:
        return read_ros_bag(
            p,
            depth_topic=depth_topic,
            amplitude_topic=amplitude_topic,
            depth_scale=depth_scale,
            allow_empty=allow_empty,
        )
    if p.suffix.lower() == ".mkv":
        return read_azure_kinect_mkv(p, allow_empty=allow_empty)
    raise ValueError(f"{p} is not a recording container ({list(CONTAINER_SUFFIXES)}, a ROS 2 bag)")


def _scale(depth_scale) -> float:
    return 1e-3 if depth_scale is None else check_scale(depth_scale)


def _vendor_raw(path, v: VendorName, what: str, dtype=None) -> np.ndarray:
    kw = {} if dtype is None else {"dtype": dtype}
    try:
        return read_raw_array(path, v.height, v.width, what=what, **kw)
    except FormatError as exc:
        raise FormatError(f"{exc} (the size {v.height} x {v.width} is from its name)") from exc


def camera_sets(depth_path, amplitude_path=None, depth_scale=None) -> list[FrameSet] | None:
    """The :class:`FrameSet` of a camera file (table above), or None for any other file (which
    :func:`~.stored.read_frame_sets` reads itself)."""
    if not isinstance(depth_path, (str, os.PathLike)):
        return None
    p = Path(depth_path)
    if is_camera_recording(p):
        if amplitude_path is not None:
            raise ValueError(f"{p} holds depth and amplitude; amplitude_path must be None")
        rec = read_camera_file(p, depth_scale=depth_scale)
        ts = None if rec.timestamps_s is None else rec.timestamps_s.numpy()
        d, a = rec.depth[:, 0].numpy(), rec.amplitude[:, 0].numpy()
        return [FrameSet("", d, a, 1.0, tuple(d.shape), rec.meta.get("camera"), rec.meta, ts)]
    v = vendor_name(p.name)
    if v is None:
        return None
    what = f"ADTF3175 {v.kind}"
    if v.kind == "interleaved":
        if amplitude_path is not None:
            raise ValueError(f"{p} holds depth and AB interleaved; amplitude_path must be None")
        arr = _vendor_raw(p, v, what, ADI_INTERLEAVED_DTYPE)
        d, a = arr["depth"].astype(np.uint16), arr["ab"].astype(np.uint16)
        return [FrameSet("", d, a, _scale(depth_scale), tuple(d.shape), v.camera)]
    if v.kind != "depth" or amplitude_path is None:
        raise ValueError(
            f"{p}: pass the depth file of an ADI pair as depth_path and its "
            f"{vendor_partner(p.name) if v.kind == 'depth' else 'IR'} file as amplitude_path"
        )
    q = existing_file(amplitude_path, "amplitude")
    d, a = _vendor_raw(p, v, what), _vendor_raw(q, v, "ADTF3175 IR")
    check_same_shape(d, a, f"{p} / {q}")
    return [FrameSet("", d, a, _scale(depth_scale), tuple(d.shape), v.camera)]


def write_camera_like(src, dst, arrays: dict[str, np.ndarray], by_key: dict) -> bool:
    """:func:`~.stored.write_like` for a camera file: a container's cleaned depth as a recording
    ``.npz`` (the reader's meta and timestamps, its amplitude), an interleaved file with only
    its depth bytes replaced. Returns False (nothing written) for any other file."""
    src = Path(src)
    if is_camera_recording(src):
        fs = by_key[""]
        rec = Recording(
            torch.from_numpy(arrays[""]),
            torch.from_numpy(fs.amplitude),
            fs.meta,
            timestamps_s=fs.timestamps_s,
        )
        write_recording(dst, rec, allow_empty=True)
        return True
    v = vendor_name(src.name)
    if v is None or v.kind != "interleaved":
        return False
    depth = arrays[""]
    out = np.fromfile(src, dtype=ADI_INTERLEAVED_DTYPE).reshape(depth.shape)
    out["depth"] = depth
    out.tofile(dst)
    return True


def _holds_recording(p: Path) -> bool:
    try:
        with zipfile.ZipFile(p) as z:
            return "content.npy" in z.namelist()
    except (OSError, zipfile.BadZipFile):
        return False


def read_any_recording(
    depth_path,
    amplitude_path=None,
    *,
    height: int | None = None,
    width: int | None = None,
    depth_scale: float | None = None,
    depth_topic: str | None = None,
    amplitude_topic: str | None = None,
    allow_empty: bool = False,
    frame_files: bool = True,
) -> Recording:
    """Any frame file the folder tools take (``ACCEPTED``) as a :class:`Recording`.

    Containers through their readers; a recording ``.npz`` as it is; every other file through
    :func:`~.stored.read_frame_sets` (one set: an HDF5 file with several groups is refused), with
    ``meta["camera"]`` the camera its name tells (``adtf3175`` for ADI names) and the other
    settings unknown (None). ``frame_files=False``: only a camera's own files (containers,
    vendor-named raw files) are read so; anything else must be a recording ``.npz``
    (:func:`~.recording.read_recording`, with its errors). The IR file of an ADI depth file is
    found beside it when ``amplitude_path`` is not given."""
    p = Path(depth_path)
    if not frame_files and not is_camera_recording(p) and vendor_name(p.name) is None:
        return read_recording(p, allow_empty=allow_empty)
    partner = vendor_partner(p.name)
    if amplitude_path is None and partner is not None and (p.parent / partner).is_file():
        amplitude_path = p.parent / partner  # the other file of an ADI pair, beside it
    if is_camera_recording(p):
        return read_camera_file(
            p,
            depth_topic=depth_topic,
            amplitude_topic=amplitude_topic,
            depth_scale=depth_scale,
            allow_empty=allow_empty,
        )
    if p.suffix.lower() == ".npz" and amplitude_path is None and _holds_recording(p):
        return read_recording(p, allow_empty=allow_empty)
    sets = read_frame_sets(p, amplitude_path, height=height, width=width, depth_scale=depth_scale)
    if len(sets) != 1:
        raise ValueError(
            f"{p} holds {len(sets)} depth / amplitude groups {[fs.key for fs in sets]}; a "
            "recording holds one"
        )
    fs = sets[0]
    depth, amplitude = frame_set_tensors(fs, str(p), allow_empty)
    unit = cameras.profile(fs.camera).amplitude_unit if fs.camera else "as stored"
    meta = {
        "camera": fs.camera,
        "modulation_frequency_hz": None,
        "integration_time_us": None,
        "n_phases": None,
        "amplitude_unit": unit,
        "source": p.name,
    }
    return Recording(depth, amplitude, meta, timestamps_s=fs.timestamps_s)
