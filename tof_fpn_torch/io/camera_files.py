"""Camera files by name: the recordings of camera tools and the vendor-named raw files, read (and,
for ``tof-fpn clean``, written back) like the frame files of :mod:`.stored`.

* ``<name>.mkv``: an Azure Kinect recording (:mod:`.matroska`), camera ``azure_kinect``;
* ``<name>.bag``: a ROS 1 bag (:mod:`.rosbag`), camera ``realsense`` for librealsense recordings;
* a folder with a rosbag2 ``metadata.yaml``, ``<name>.mcap``, ``<name>.db3``: a ROS 2 bag;
* ``<name>_depth_u16le_<H>x<W>.bin`` + ``<name>_ir_u16le_<H>x<W>.bin`` (``.raw`` too, any case):
  ADI ADTF3175 depth (mm) + IR (counts), raw uint16 LE, camera ``adtf3175``;
* ``<name>_interleaved_<H>x<W>.bin``: ADI ADTF3175 interleaved, 5 bytes per pixel (depth u16 LE
  mm, confidence u8, AB u16 LE), camera ``adtf3175``;
* a ``.h5`` / ``.hdf5`` of ESPROS's epc-tofcam-toolkit, found by its content (:mod:`.espros`): a
  point cloud read as depth = z and its amplitude, camera ``espros_tofcam635``; its other
  recordings (amplitude only, ...) are refused with the reason.

``<H>x<W>`` is rows x columns, any size.

Each is a format of the table of formats (:mod:`.formats`), which chooses its reader and writer;
this module answers the folder tools' questions by name.

A recording container (``.mkv``, a bag, an ESPROS ``.h5``) is read whole into a :class:`~.recording.Recording`; as
a :class:`~.stored.FrameSet` it is float32 metres with NaN (``depth_scale`` 1) and keeps the
reader's meta and timestamps, and :func:`~.stored.write_like` writes it as the package's recording
``.npz`` (there is no faithful writer for these containers). A vendor raw file keeps its own
layout: the size comes from its name (``--height`` / ``--width`` are for other raw files), the IR
file of a pair is the amplitude, and an interleaved file is written back with only the depth
bytes replaced (confidence and AB byte for byte).
"""

from __future__ import annotations

import os
import zipfile
from pathlib import Path

import numpy as np

from .. import cameras
from .captures import VendorName, vendor_name, vendor_partner
from .formats import CAMERA_FILE, PAIR_MEMBER, RECORDING, format_for, format_of_name, suffixes
from .formats import get_format as _get_format
from .recording import Recording, read_recording
from .rosbag import ROS2_METADATA, is_ros2_bag_dir, ros2_bag_files
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
CONTAINER_SUFFIXES: tuple[str, ...] = suffixes(RECORDING)
#: what the folder tools take, for their error messages
ACCEPTED = (
    "<name>.npz / .h5 / .hdf5 (depth + amplitude); <name>_depth.<ext> + <name>_amplitude.<ext> "
    "(.png .tif .tiff .npy .bin .raw); Azure Kinect .mkv; ROS 1 .bag (RealSense too); ROS 2 bag "
    "(a folder with metadata.yaml, or .mcap / .db3); ADI <name>_depth_u16le_<H>x<W>.bin + "
    "<name>_ir_u16le_<H>x<W>.bin and <name>_interleaved_<H>x<W>.bin; ESPROS epc-tofcam-toolkit "
    "point cloud .h5"
)


def is_camera_recording(path) -> bool:
    """A recording container: a ``.mkv`` / ``.bag`` / ``.mcap`` / ``.db3`` file, a ROS 2 bag
    folder or an ESPROS toolkit ``.h5`` (by its content)."""
    fmt = format_for(path)
    return fmt is not None and fmt.holds == RECORDING


def recording_stem(file_name) -> str:
    """The name a frame file's recording gets (without ``.npz``): ``<name>`` of a vendor file,
    of ``<name>_depth.<ext>`` and of ``<name>.<ext>``; a folder's own name."""
    base = os.path.basename(os.path.normpath(os.fspath(file_name)))
    v = vendor_name(base)
    if v is not None:
        return v.name
    stem, _ = os.path.splitext(base)
    fmt = format_of_name(base, by_name=False)
    if fmt is not None and fmt.holds == PAIR_MEMBER:
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
    (always mm: ``depth_scale`` and the topics do not apply), a bag -> :func:`read_ros_bag`
    (a folder too, which the bag reader checks)."""
    p = Path(path)
    fmt = format_for(p)
    if fmt is None and p.is_dir():
        fmt = _get_format("ros2_bag")  # its reader says what the folder lacks
    if fmt is None or fmt.holds != RECORDING:
        raise ValueError(
            f"{p} is not a recording container ({list(CONTAINER_SUFFIXES)}, a ROS 2 bag)"
        )
    return fmt.read(
        p,
        depth_topic=depth_topic,
        amplitude_topic=amplitude_topic,
        depth_scale=depth_scale,
        allow_empty=allow_empty,
    )


def camera_sets(depth_path, amplitude_path=None, depth_scale=None) -> list[FrameSet] | None:
    """The :class:`FrameSet` of a camera file (table above), or None for any other file (which
    :func:`~.stored.read_frame_sets` reads too)."""
    if not isinstance(depth_path, (str, os.PathLike)):
        return None
    fmt = format_for(depth_path)
    if fmt is None or fmt.holds not in (RECORDING, CAMERA_FILE):
        return None
    return fmt.read_stored(depth_path, amplitude_path, depth_scale=depth_scale)


def write_camera_like(src, dst, arrays: dict[str, np.ndarray], by_key: dict) -> bool:
    """:func:`~.stored.write_like` for a camera file: a container's cleaned depth as a recording
    ``.npz`` (the reader's meta and timestamps, its amplitude), an interleaved file with only
    its depth bytes replaced, an ADI pair's depth file as raw uint16. Returns False (nothing
    written) for any other file."""
    fmt = format_for(src)
    if fmt is None or fmt.holds not in (RECORDING, CAMERA_FILE):
        return False
    fmt.write_like(Path(src), Path(dst), arrays, by_key)
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
    fmt = format_for(p)
    holds = None if fmt is None else fmt.holds
    if not frame_files and holds not in (RECORDING, CAMERA_FILE):
        return read_recording(p, allow_empty=allow_empty)
    partner = vendor_partner(p.name)
    if amplitude_path is None and partner is not None and (p.parent / partner).is_file():
        amplitude_path = p.parent / partner  # the other file of an ADI pair, beside it
    if holds == RECORDING:
        return fmt.read(
            p,
            depth_topic=depth_topic,
            amplitude_topic=amplitude_topic,
            depth_scale=depth_scale,
            allow_empty=allow_empty,
        )
    if fmt is not None and fmt.name == "npz" and amplitude_path is None and _holds_recording(p):
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
