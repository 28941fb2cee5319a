"""The file layer: the only part of the package that reads or writes file formats.

May import: torch, NumPy, imageio, tifffile, h5py, PyAV (``av``, optional, at call time),
rosbags (optional, at call time), the standard library, :mod:`tof_fpn_torch.runtime` (the validity rule), :mod:`tof_fpn_torch.constants`
and :mod:`tof_fpn_torch.cameras` (profile names). It sits beside the simulator and never imports it:
simulator results are converted by attribute (:func:`recording_from_simulation`,
:func:`scene_from_sim`). ``tests/test_layout.py`` checks this.

Every reader returns the package's tensors, float32 (B, C, H, W) on the CPU: **depth in metres
with NaN for every invalid pixel** (:func:`tof_fpn_torch.runtime.valid_mask`), **amplitude in the
camera's own units**. Every writer takes the same and stores the file's own dtype and unit (uint16
mm with 0 for invalid by default), so integer files round-trip exactly. docs/io.md lists the
formats, their units and what each reader can and cannot do.

- :mod:`.formats` -- the table of file formats: each format's suffixes (or naming rule), what
  it holds, its reader and writer and the optional extra it needs; :func:`format_for` chooses
  the format of a file for every tool of the package.
- :mod:`.numpy_files` -- ``.npy`` / ``.npz``; :mod:`.images` -- 16-bit PNG, TIFF;
  :mod:`.hdf5` -- HDF5; :mod:`.raw` -- raw uint16 LE frames; :mod:`.pairs` -- by suffix;
  :mod:`.stored` -- files as stored, written back with another depth (``tof-fpn clean``).
- :mod:`.captures` -- ADI ADTF3175 (depth + IR, interleaved), Kinect v2 P0 tables;
  :mod:`.matroska` -- Azure Kinect ``.mkv`` (PyAV); :mod:`.rosbag` -- ROS 1 / ROS 2 bags,
  RealSense recordings (rosbags); :mod:`.espros` -- ESPROS TOFcam635 point clouds of the
  epc-tofcam-toolkit (HDF5, found by content); :mod:`.camera_files` -- camera files by name
  (containers, ADI vendor names) for the folder tools.
- :mod:`.recording` -- the recording format (:class:`Recording`); :mod:`.scene` -- the scene
  format (:class:`SceneData`).
- :mod:`.dataset` -- :class:`FrameDataset`, a folder of frames for a ``DataLoader``.
- :mod:`.patterns` -- the pattern files of ``tof-fpn calibrate`` (:func:`read_pattern_file`,
  :func:`write_pattern_file`; plain tensors, the analysis layer's patterns convert).
"""

from ._common import METRES_PER_MM, FormatError
from .camera_files import read_any_recording, read_camera_file
from .captures import (
    read_adi_depth_ir,
    read_adi_interleaved,
    read_kinect_v2_p0,
    write_adi_interleaved,
    write_kinect_v2_p0,
)
from .dataset import FrameDataset, find_frames
from .espros import read_espros_hdf5
from .formats import FileFormat, MissingExtraError, format_for
from .hdf5 import read_hdf5, write_hdf5
from .images import read_png, read_tiff, write_png, write_tiff
from .matroska import read_azure_kinect_mkv
from .numpy_files import read_npy, read_npz, write_npy, write_npz
from .pairs import read_pair, write_pair
from .patterns import read_pattern_file, write_pattern_file
from .raw import read_raw, write_raw
from .recording import (
    FORMAT_VERSION,
    REQUIRED_META,
    Recording,
    read_recording,
    recording_from_simulation,
    write_recording,
)
from .rosbag import read_realsense_bag, read_ros_bag
from .scene import SceneData, read_scene, scene_from_sim, write_scene

__all__ = [
    "FORMAT_VERSION",
    "FileFormat",
    "METRES_PER_MM",
    "REQUIRED_META",
    "FormatError",
    "FrameDataset",
    "MissingExtraError",
    "Recording",
    "SceneData",
    "find_frames",
    "format_for",
    "read_adi_depth_ir",
    "read_adi_interleaved",
    "read_any_recording",
    "read_azure_kinect_mkv",
    "read_camera_file",
    "read_espros_hdf5",
    "read_hdf5",
    "read_kinect_v2_p0",
    "read_npy",
    "read_npz",
    "read_pair",
    "read_pattern_file",
    "read_png",
    "read_raw",
    "read_realsense_bag",
    "read_recording",
    "read_ros_bag",
    "read_scene",
    "read_tiff",
    "recording_from_simulation",
    "scene_from_sim",
    "write_adi_interleaved",
    "write_hdf5",
    "write_kinect_v2_p0",
    "write_npy",
    "write_npz",
    "write_pair",
    "write_pattern_file",
    "write_png",
    "write_raw",
    "write_recording",
    "write_scene",
    "write_tiff",
]
