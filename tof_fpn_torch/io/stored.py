"""Files as stored: read the depth / amplitude arrays in the file's own dtype and write a file back
**as it came**, with only the depth replaced (what ``tof-fpn clean`` needs).

The other readers of this layer return the package's tensors (metres, camera units); here the
stored values and the file's layout are kept, so that a tool can write an output that has the
input's dtype, units, shape, name and metadata:

=================  ===============================================================================
format             kept when :func:`write_like` writes the file back
=================  ===============================================================================
16-bit PNG         mode (8- / 16-bit grey), the text chunks (``tEXt``) before the image data
TIFF               dtype, (H, W) or (T, H, W), compression, the image description, resolution
``.npy``           dtype, (H, W) or (T, H, W)
``.npz``           every other array byte for byte; each entry's name, date and compression
HDF5               the whole file (every other dataset, group and attribute, the depth dataset's
                   dtype, chunks, filters and attributes): it is copied and the depth values
                   are overwritten in place
raw ``.bin``       little-endian uint16, frames back to back
=================  ===============================================================================

A file holds one or more :class:`FrameSet`: one for every format but HDF5, where every group
holding a ``depth`` and an ``amplitude`` dataset (the root included) is one, keyed by its path.
:func:`frame_set_tensors` turns a set into the package's tensors (depth metres, NaN invalid;
amplitude camera units) and :func:`~.encode.encode_depth` turns cleaned depth (metres) back into the stored
dtype, leaving the stored value of every invalid input pixel as it was. Decoding errors raise
:class:`FormatError` naming the file. Camera files (an Azure Kinect ``.mkv``, ROS bags, ADI
vendor-named raw files) are read and written through :mod:`.camera_files`.
"""

from __future__ import annotations

import json
import shutil
import zipfile
from dataclasses import dataclass
from pathlib import Path

import h5py
import numpy as np
import tifffile
import torch
from PIL import Image, PngImagePlugin

from ._common import (
    FormatError,
    amplitude_from_stored,
    check_depth_bits,
    check_not_empty,
    check_same_shape,
    check_scale,
    decoding,
    depth_from_stored,
    existing_file,
    stored_frames,
)
from .numpy_files import load_npz
from .raw import RAW_DTYPE, read_raw_array

__all__ = [
    "PNG_SCALE_KEY",
    "FrameSet",
    "frame_set_tensors",
    "read_frame_sets",
    "write_like",
]

_HDF5 = (".h5", ".hdf5")


@dataclass
class FrameSet:
    """Depth and amplitude frames of one file (or one HDF5 group), as stored.

    Attributes:
        key: ``""`` for single-set files; the HDF5 group path (``""`` for the root).
        depth: (T, H, W) stored depth, the file's dtype (units of ``depth_scale`` m).
        amplitude: (T, H, W) stored amplitude, the file's dtype (camera units).
        depth_scale: metres per stored depth unit.
        shape: the stored shape of the depth, (H, W) or (T, H, W), written back as it was.
        camera: the camera profile (:mod:`tof_fpn_torch.cameras`) the file comes from, where
            its format or name tells (``azure_kinect``, ``realsense``, ``adtf3175``, a
            recording's ``meta["camera"]``), else None.
        meta, timestamps_s: a recording container's meta and (T,) timestamps, else None.
    """

    key: str
    depth: np.ndarray
    amplitude: np.ndarray
    depth_scale: float
    shape: tuple[int, ...]
    camera: str | None = None
    meta: dict | None = None
    timestamps_s: np.ndarray | None = None


def _scale(arr: np.ndarray, depth_scale) -> float:
    if depth_scale is not None:
        return check_scale(depth_scale)
    return 1e-3 if arr.dtype.kind in "ui" else 1.0  # io._common: mm for integer, m for floating


def _recording_camera(arrays: dict) -> str | None:
    """``meta["camera"]`` of a recording ``.npz`` (:mod:`.recording`), else None."""
    try:
        meta = json.loads(str(arrays["meta"].item())) if "content" in arrays else None
    except (KeyError, ValueError):
        return None
    camera = meta.get("camera") if isinstance(meta, dict) else None
    return camera if isinstance(camera, str) else None


#: the PNG text chunk that records the depth's metres per stored unit (when not 1 mm)
PNG_SCALE_KEY = "depth_scale_m"


def _png(path: Path) -> tuple[np.ndarray, float | None]:
    """The image and the ``depth_scale_m`` text chunk's value (None where absent)."""
    with decoding(path, "a PNG image"), Image.open(path) as im:
        if im.format != "PNG":
            raise TypeError(f"a {im.format} image, not a PNG")
        arr = np.asarray(im)
        text = im.info.get(PNG_SCALE_KEY)
    if arr.ndim != 2 or arr.dtype.kind not in "ui":
        raise FormatError(
            f"{path}: expected a single-channel integer (16-bit grey) PNG, got shape {arr.shape} "
            f"dtype {arr.dtype}"
        )
    try:
        scale = None if text is None else check_scale(float(text), PNG_SCALE_KEY)
    except ValueError as exc:
        raise FormatError(f"{path}: text chunk {PNG_SCALE_KEY}={text!r}: {exc}") from None
    return arr, scale


def _tiff(path: Path) -> np.ndarray:
    with decoding(path, "a TIFF image"), tifffile.TiffFile(path) as tif:
        axes = tif.series[0].axes
        arr = tif.series[0].asarray()
    if "S" in axes or not axes.endswith("YX") or len(axes) > 3:
        raise FormatError(f"{path}: expected grey frames (axes YX or IYX), got axes {axes!r}")
    return arr


def _single(path: Path, kind: str, height, width, depth_scale=None) -> tuple[np.ndarray, float]:
    """The stored array of one file of a pair and its metres per unit (``depth_scale`` if given,
    else a PNG's ``depth_scale_m`` chunk, else the dtype's default). An 8-bit depth PNG is refused
    unless ``depth_scale`` is given: 0-255 mm is not a depth map (an exported preview)."""
    if path.suffix.lower() == ".png":
        arr, text_scale = _png(path)
        if kind == "depth":
            check_depth_bits(arr, path, depth_scale)
        if depth_scale is None and text_scale is not None:
            depth_scale = text_scale
    else:
        arr = _single_array(path, kind, height, width)
    return arr, _scale(arr, depth_scale)


def _single_array(path: Path, kind: str, height, width) -> np.ndarray:
    s = path.suffix.lower()
    if s in (".tif", ".tiff"):
        return _tiff(path)
    if s == ".npy":
        with decoding(path, "an .npy array"):
            arr = np.load(path, allow_pickle=False)
            if not isinstance(arr, np.ndarray):
                raise TypeError("an .npz archive, not an .npy array")
        return arr
    if s in (".bin", ".raw"):
        if height is None or width is None:
            raise ValueError(
                f"raw file {path}: its frame size is not in the file; give height and width "
                "(pixels; tof-fpn: --height / --width)"
            )
        return read_raw_array(path, height, width, what=f"raw {kind}")
    raise ValueError(f"unsupported suffix {s!r} of {path}")


def _hdf5_sets(path: Path, depth_scale) -> list[FrameSet]:
    sets = []
    with decoding(path, "an HDF5 file"), h5py.File(path, "r") as f:
        groups = [("", f)]
        f.visititems(
            lambda name, obj: groups.append((name, obj)) if isinstance(obj, h5py.Group) else None
        )
        for key, g in groups:
            if "depth" not in g or "amplitude" not in g:
                continue
            where = f"{path} [{key + '/' if key else ''}depth]"
            dset, aset = g["depth"], g["amplitude"]
            for name, ds in (("depth", dset), ("amplitude", aset)):
                if not isinstance(ds, h5py.Dataset) or ds.dtype.kind not in "uif":
                    raise FormatError(
                        f"{path}: {key + '/' if key else ''}{name} is "
                        f"{'a dataset of dtype ' + str(ds.dtype) if isinstance(ds, h5py.Dataset) else 'a group'}"
                        "; depth / amplitude must be integer (mm, counts) or floating datasets"
                    )
            scale = depth_scale
            if scale is None and "scale_m" in dset.attrs:
                scale = float(np.asarray(dset.attrs["scale_m"]))
            d, a = dset[()], aset[()]
            shape = tuple(d.shape)
            d, a = stored_frames(d, where), stored_frames(a, where.replace("depth]", "amplitude]"))
            sets.append(FrameSet(key, d, a, _scale(d, scale), shape))
    if not sets:
        raise FormatError(f"{path}: no group holds both a 'depth' and an 'amplitude' dataset")
    return sets


def read_frame_sets(
    depth_path,
    amplitude_path=None,
    *,
    height: int | None = None,
    width: int | None = None,
    depth_scale: float | None = None,
) -> list[FrameSet]:
    """Read the stored frames of one frame file (the suffixes of :func:`~.pairs.read_pair`).

    Args:
        depth_path: the depth file, or the ``.npz`` / ``.h5`` holding both.
        amplitude_path: the amplitude file (None for ``.npz`` / ``.h5``).
        height, width: frame size of raw ``.bin`` / ``.raw`` files, pixels.
        depth_scale: metres per stored depth unit (default 1 mm for integer data, 1 m for
            floating data, an HDF5 dataset's ``scale_m`` attribute).

    Returns:
        the file's :class:`FrameSet` s (several for an HDF5 file with several groups).

    Camera files (an Azure Kinect ``.mkv``, ROS bags, ADI vendor-named raw files) are read by
    :func:`~.camera_files.camera_sets` (docs/io.md).

    Raises:
        FormatError: a file that cannot be decoded, an array of another dtype or rank.
        ValueError: depth and amplitude of different shapes.
    """
    from .camera_files import camera_sets  # imported here: camera_files imports this module

    camera = camera_sets(depth_path, amplitude_path, depth_scale)
    if camera is not None:
        return camera
    p = existing_file(depth_path, "depth")
    s = p.suffix.lower()
    if s in _HDF5:
        sets = _hdf5_sets(p, depth_scale)
    elif s == ".npz":
        arrays = load_npz(p, "a depth / amplitude .npz")
        missing = [k for k in ("depth", "amplitude") if k not in arrays]
        if missing:
            raise FormatError(f"{p}: no array(s) {missing}; it holds {sorted(arrays)}")
        d = stored_frames(arrays["depth"], f"{p} [depth]")
        a = stored_frames(arrays["amplitude"], f"{p} [amplitude]")
        shape = tuple(arrays["depth"].shape)
        sets = [FrameSet("", d, a, _scale(d, depth_scale), shape, _recording_camera(arrays))]
    else:
        if amplitude_path is None:
            raise ValueError(f"{p} holds depth only; pass amplitude_path too")
        q = existing_file(amplitude_path, "amplitude")
        raw_d, scale = _single(p, "depth", height, width, depth_scale)
        raw_a, _ = _single(q, "amplitude", height, width)
        d, a = stored_frames(raw_d, str(p)), stored_frames(raw_a, str(q))
        check_same_shape(d, a, f"{p} / {q}")
        sets = [FrameSet("", d, a, scale, tuple(raw_d.shape))]
    for fs in sets:
        check_same_shape(fs.depth, fs.amplitude, f"{p}{' [' + fs.key + ']' if fs.key else ''}")
    return sets


def frame_set_tensors(
    fs: FrameSet, where: str = "frame set", allow_empty: bool = False
) -> tuple[torch.Tensor, torch.Tensor]:
    """``(depth, amplitude)``: float32 (T, 1, H, W), depth in metres with NaN for every invalid
    pixel, amplitude in the camera's units. A frame with no valid pixel raises ``ValueError``
    unless ``allow_empty``."""
    depth = depth_from_stored(fs.depth, fs.depth_scale)
    amplitude = amplitude_from_stored(fs.amplitude)
    check_not_empty(depth, amplitude, where, allow_empty)
    return depth, amplitude


def _png_write(src: Path, dst: Path, arr: np.ndarray, depth_scale: float | None = None) -> None:
    with Image.open(src) as im:
        text = {k: v for k, v in im.info.items() if isinstance(k, str) and isinstance(v, str)}
    if depth_scale is not None:
        text[PNG_SCALE_KEY] = repr(float(depth_scale))
    info = PngImagePlugin.PngInfo()
    for k, v in text.items():
        info.add_text(k, v)
    Image.fromarray(arr).save(dst, format="PNG", pnginfo=info if text else None)


def _tiff_write(src: Path, dst: Path, arr: np.ndarray) -> None:
    with tifffile.TiffFile(src) as tif:
        page = tif.pages[0]
        kw = {"compression": page.compression if page.compression != 1 else None}
        desc = page.description
        shaped = desc.startswith("{") and '"shape"' in desc
        if desc and not shaped:
            kw.update(description=desc, metadata=None)
        if "XResolution" in page.tags and "YResolution" in page.tags:
            kw["resolution"] = (page.tags["XResolution"].value, page.tags["YResolution"].value)
    tifffile.imwrite(dst, arr, photometric="minisblack", **kw)


def _npz_write(src: Path, dst: Path, arr: np.ndarray) -> None:
    """Copy every entry (name, date, compression, zip64 or not), the depth's content replaced."""
    with zipfile.ZipFile(src) as zin, zipfile.ZipFile(dst, "w", allowZip64=True) as zout:
        for old in zin.infolist():
            info = zipfile.ZipInfo(old.filename, date_time=old.date_time)
            info.compress_type = old.compress_type
            info.external_attr = old.external_attr
            zip64 = old.extract_version >= zipfile.ZIP64_VERSION  # written with zip64 headers
            with zout.open(info, "w", force_zip64=zip64) as fh:
                if old.filename == "depth.npy":
                    np.lib.format.write_array(fh, arr, allow_pickle=False)
                else:
                    fh.write(zin.read(old))


def write_like(
    src,
    dst,
    depths: dict[str, np.ndarray],
    sets: list[FrameSet],
    depth_scale: float | None = None,
) -> Path:
    """Write ``dst`` as a copy of the depth file ``src`` with the depth of each frame set
    replaced by ``depths[key]`` ((T, H, W) arrays of the stored dtype, from :func:`~.encode.encode_depth`).

    What is kept of each format: the module docstring. ``dst`` must not be ``src``; its folder
    must exist (the caller writes to a temporary name there and renames). ``depth_scale``: the
    metres per unit of ``depths`` where it differs from the input's (``encode_depth``'s
    ``output_scale``): recorded as a PNG's ``depth_scale_m`` text chunk and as an HDF5 depth
    dataset's ``scale_m`` attribute; the other formats have no place for it."""
    src, dst = Path(src), Path(dst)
    if src.resolve() == dst.resolve():
        raise ValueError(f"write_like: dst must differ from src, got {src} twice")
    by_key = {fs.key: fs for fs in sets}
    if set(depths) != set(by_key):
        raise ValueError(f"write_like: depths for {sorted(depths)}, the file has {sorted(by_key)}")
    arrays = {}
    for key, arr in depths.items():
        fs = by_key[key]
        if arr.dtype != fs.depth.dtype or arr.shape != fs.depth.shape:
            raise ValueError(
                f"write_like: depth {key!r} must be {fs.depth.dtype} {fs.depth.shape}, got "
                f"{arr.dtype} {arr.shape}"
            )
        arrays[key] = np.ascontiguousarray(arr.reshape(fs.shape))
    from .camera_files import write_camera_like  # imported here: it imports this module

    if write_camera_like(src, dst, arrays, by_key):
        return dst
    s = src.suffix.lower()
    if s in _HDF5:
        shutil.copyfile(src, dst)
        with h5py.File(dst, "r+") as f:
            for key, arr in arrays.items():
                dset = f[f"{key}/depth" if key else "depth"]
                dset[...] = arr
                if depth_scale is not None:
                    dset.attrs["scale_m"] = float(depth_scale)
    elif s == ".npz":
        _npz_write(src, dst, arrays[""])
    elif s == ".png":
        _png_write(src, dst, arrays[""], depth_scale)
    elif s in (".tif", ".tiff"):
        _tiff_write(src, dst, arrays[""])
    elif s == ".npy":
        with open(dst, "wb") as fh:
            np.lib.format.write_array(fh, arrays[""], allow_pickle=False)
    elif s in (".bin", ".raw"):
        arrays[""].astype(RAW_DTYPE).tofile(dst)
    else:
        raise ValueError(f"write_like: unsupported suffix {s!r} of {src}")
    return dst
